//! `explain`: find, name and model the physics a model (or a simulation) left out.
//!
//! 1. **Prepare** — quantised readings, channels held between slower reports and glitches are
//!    found first ([`robust`]); glitches are excluded from every fit and reported with their
//!    rows.
//! 2. **Baseline** — the published static model (cubic in the commanded position, linear in
//!    every temperature, an offset) fitted to the recording; or, with a simulation, the
//!    difference to it.
//! 3. **Locate** — where the residual is structured (time, position, direction, other axes,
//!    temperature rate, auxiliary channels) against a noise floor estimated from the data
//!    (never below the quantisation's step/√12).
//! 4. **Name** — every candidate in [`crate::effects`] proposes an extension of the current
//!    model, its nonlinear parameters (τ per sensor, t0, a play-operator bank) searched against
//!    it ([`search`]); it is accepted only if it lowers an information criterion (BIC with an
//!    effective sample size for autocorrelated residuals) by more than
//!    [`Settings::min_bic_drop`] AND predicts held-out blocks better in most folds. Candidates
//!    that explain through recorded channels are preferred: a time-only explanation
//!    (`unexplained_drift`) is tried only when none of them passes, and is judged on held-out
//!    gaps longer than its own time scale. The best accepted candidate joins the model and the
//!    search repeats.
//! 5. **Model and show** — held-out RMS (and ISO 9283 figures where poses are revisited)
//!    before/after, residual plots; the headline says whether nothing significant remains or
//!    structure remains that no candidate explains, and where.

pub mod contract;
pub mod data;
pub mod error;
pub mod estimate;
pub mod events;
pub mod faults;
pub mod fit;
pub mod jackknife;
pub mod locate;
pub mod misspec;
pub mod nnls;
pub mod parallel;
pub mod plot;
pub mod report;
pub mod robust;
pub mod search;
pub mod stats;
pub mod targeted;
pub mod units;

use crate::effects::candidates;
use contract::{Candidate, Fitted, Proposal};
use estimate::Estimate;

pub use data::Data;
pub use error::ExplainError;
pub use faults::{DataFault, FaultKind};
pub use locate::{Finding, NoiseFloor};
pub(crate) use parallel::in_parallel;
pub use report::{ChannelReport, EffectReport, Report};

use fit::{Cv, Design, Fit};

/// Thresholds of the naming step.
#[derive(Clone, Debug)]
pub struct Settings {
    /// Minimum drop of BIC for a candidate to count, with the sample size counted as the
    /// independent rows behind its evidence ([`fit::bartlett_n_eff`]): 6 = "strong" (Kass &
    /// Raftery, JASA 90, 1995, on the 2 ln B scale).
    pub min_bic_drop: f64,
    /// Minimum relative drop of held-out RMS.
    pub min_rms_gain: f64,
    /// Minimum number of cross-validation folds (of 5) that must improve.
    pub min_folds_better: usize,
    /// Most effects named per channel.
    pub max_effects: usize,
    /// Smallest effect worth a name, as a fraction of the noise floor: the held-out variance
    /// it explains must be at least (this × floor)². Below, it may be detectable in a long
    /// record, but it is not physics anyone could use.
    pub min_effect_of_floor: f64,
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            min_bic_drop: 6.0,
            min_rms_gain: 0.01,
            min_folds_better: 4,
            max_effects: 4,
            min_effect_of_floor: 0.2,
        }
    }
}

/// A candidate tried on a channel, and how it scored.
#[derive(Clone, Debug)]
pub struct Trial {
    /// Candidate name.
    pub name: &'static str,
    /// Its first nonlinear parameter, if any.
    pub theta: Option<f64>,
    /// BIC change (negative = better).
    pub delta_bic: f64,
    /// Held-out RMS with the extension, µm (NaN when not cross-validated).
    pub cv_rms_um: f64,
    /// Folds that improved.
    pub folds_better: usize,
    /// Folds of its held-out design.
    pub folds: usize,
    /// Whether it passed the thresholds.
    pub passed: bool,
}

/// Most rows the naming step fits on: longer logs are thinned evenly (a 1 kHz log over-samples
/// everything explain looks at; lag filters and play operators still run over every sample).
pub const EVAL_ROWS: usize = 100_000;

struct Model {
    cols: Vec<Vec<f64>>,
}

impl Model {
    fn with<'a>(&'a self, extra: &'a [Vec<f64>]) -> Vec<&'a [f64]> {
        self.cols
            .iter()
            .chain(extra.iter())
            .map(|c| c.as_slice())
            .collect()
    }
}

fn unexplained_drift_name() -> &'static str {
    crate::effects::unexplained_drift::NAME
}

/// Most events (steps of the residual) located per channel.
pub const MAX_EVENTS: usize = 3;

/// Most denoising explain applies to the temperatures: sensor noise is fast; slower smoothing
/// would start to shape the thermal response itself (and hand a short lag what it took away).
pub const MAX_SMOOTHING_S: f64 = 300.0;

/// Zero-phase denoising of the temperatures, chosen by held-out prediction of the baseline:
/// none, or a ladder of half-widths from two report intervals (each 2.5× the last) up to
/// [`MAX_SMOOTHING_S`] and 1/20 of the record — the least smoothing within 1 % of the best.
/// Sensor noise in a regressor biases its coefficient (errors in variables) and would let any
/// low-pass of the readings (a short "lag") look like physics. Diagnostic only: a zero-phase
/// mean uses later readings; every term explain fits sees the same denoised readings.
fn choose_smoothing(
    d: &Data,
    ch: usize,
    design: &Design,
    rows: &[usize],
) -> Result<Data, ExplainError> {
    if d.temps.is_empty() || d.against_simulation {
        return Ok(d.clone());
    }
    let mut upd: Vec<f64> = d.temp_update_s.clone();
    let base = stats::median(&mut upd).max(d.median_dt_s);
    let mut widths = vec![0.0];
    let mut w = 2.0 * base;
    while w <= MAX_SMOOTHING_S.min(d.duration_s() / 20.0) {
        widths.push(w);
        w *= 2.5;
    }
    let mut options: Vec<(f64, f64)> = Vec::new();
    // the baseline's columns as `baseline_columns` builds them from `d.with_smoothing(w)`: the
    // position's powers do not change with w; each width brings its own temperatures (nothing
    // else of the recording is copied), every width's held-out fit on a core of its own
    let (mut cols, _) = baseline_columns(d, ch);
    cols.truncate(cols.len() - d.temps.len());
    let cvs = in_parallel(&widths, |&w| {
        let temps = d.smoothed_temps(w);
        let refs: Vec<&[f64]> = cols
            .iter()
            .chain(temps.iter().map(|(_, v)| v))
            .map(|c| c.as_slice())
            .collect();
        fit::cross_validate_score(&refs, &d.channels[ch].y_um, design, rows)
    });
    for (cv, &w) in cvs.into_iter().zip(&widths) {
        options.push((cv?.rms_um, w));
    }
    let best = options.iter().map(|o| o.0).fold(f64::INFINITY, f64::min);
    let w = options
        .iter()
        .find(|o| o.0 <= best * 1.01)
        .map_or(0.0, |o| o.1);
    Ok(d.with_smoothing(w))
}

fn baseline_columns(d: &Data, ch: usize) -> (Vec<Vec<f64>>, String) {
    if d.against_simulation {
        return (Vec::new(), "the given simulation (plus an offset)".into());
    }
    let mut cols = Vec::new();
    let mut words = Vec::new();
    if let Some(u) = &d.channels[ch].u {
        for p in 1..=3 {
            cols.push(u.iter().map(|x| x.powi(p)).collect());
        }
        words.push("cubic in position".to_string());
    }
    for (_, x) in &d.temps {
        cols.push(x.clone());
    }
    if !d.temps.is_empty() {
        words.push(format!("linear in {} temperature(s)", d.temps.len()));
    }
    words.push("an offset".into());
    (
        cols,
        format!("published static model: {}", words.join(", ")),
    )
}

/// A scored proposal.
struct Scored {
    cand: &'static dyn Candidate,
    proposal: Proposal,
    fit: Fit,
    /// Held-out results (current, with the extension) on the proposal's own design.
    cv_cur: Cv,
    cv_new: Cv,
    gap_s: f64,
    /// Independent rows behind the evidence (Bartlett, see [`fit::bartlett_n_eff`]).
    n_eff: f64,
    trial: Trial,
}

struct Round<'a> {
    y: &'a [f64],
    rows: &'a [usize],
    design: &'a Design,
    model: &'a Model,
    cur_fit: &'a Fit,
    cur_cv: &'a Cv,
    k_cur: usize,
    n_eff: f64,
    /// Noise level of an independent unit, µm.
    floor_um: f64,
    settings: &'a Settings,
}

/// An extension of the current model fitted and judged (the same thresholds for an effect and
/// for an event).
struct Evaluated {
    fit: Fit,
    delta_bic: f64,
    n_eff: f64,
    /// Held-out results on the judging design (current, with the extension); None when the
    /// BIC already failed.
    cv: Option<(Cv, Cv)>,
    folds_better: usize,
    passed: bool,
}

impl Round<'_> {
    /// Fit the model plus `regs` (with `k_extra` parameters beyond their coefficients: searched
    /// nonlinear parameters) and judge it: BIC with the independent rows behind the evidence,
    /// held-out prediction on `design` (the round's when None).
    fn evaluate(
        &self,
        regs: &[&[f64]],
        k_extra: usize,
        design: Option<&Design>,
        evidence_units: Option<f64>,
    ) -> Result<Evaluated, ExplainError> {
        let mut cols = self.model.with(&[]);
        cols.extend_from_slice(regs);
        let f = fit::fit_rows(&cols, self.y, self.rows)?;
        let k_new = self.k_cur + regs.len() + k_extra;
        // the evidence counts the independent rows behind the association of what the
        // extension adds with the noise that is left after it (smooth with smooth: few rows)
        let new_res = fit::gather(&f.residuals, self.rows);
        let added: Vec<f64> = fit::gather(&self.cur_fit.residuals, self.rows)
            .iter()
            .zip(&new_res)
            .map(|(a, b)| a - b)
            .collect();
        let n_eff = fit::bartlett_n_eff(&added, &new_res)
            .max(evidence_units.unwrap_or(0.0))
            .min(self.n_eff);
        let delta_bic = fit::bic(f.rss, f.n, k_new, n_eff)
            - fit::bic(self.cur_fit.rss, self.cur_fit.n, self.k_cur, n_eff);
        let mut out = Evaluated {
            fit: f,
            delta_bic,
            n_eff,
            cv: None,
            folds_better: 0,
            passed: false,
        };
        if delta_bic.is_nan() || delta_bic >= -self.settings.min_bic_drop {
            return Ok(out);
        }
        let own = design.is_some();
        let design = design.unwrap_or(self.design);
        let cv_cur = if own {
            fit::cross_validate(&self.model.with(&[]), self.y, design, self.rows)?
        } else {
            self.cur_cv.clone()
        };
        let cv_new = fit::cross_validate(&cols, self.y, design, self.rows)?;
        out.folds_better = cv_new.folds_better_than(&cv_cur);
        let explained_um = (cv_cur.rms_um.powi(2) - cv_new.rms_um.powi(2))
            .max(0.0)
            .sqrt();
        out.passed = out.folds_better >= design.folds_needed(self.settings.min_folds_better)
            && cv_new.rms_um < cv_cur.rms_um * (1.0 - self.settings.min_rms_gain)
            && explained_um >= self.settings.min_effect_of_floor * self.floor_um;
        out.cv = Some((cv_cur, cv_new));
        Ok(out)
    }

    fn score(
        &self,
        cand: &'static dyn Candidate,
        proposal: Proposal,
    ) -> Result<(Trial, Option<Scored>), ExplainError> {
        let regs: Vec<&[f64]> = proposal.regs.iter().map(|c| c.as_slice()).collect();
        let ev = self.evaluate(
            &regs,
            proposal.thetas.len(),
            proposal.design.as_ref(),
            proposal.evidence_units,
        )?;
        let design = proposal.design.as_ref().unwrap_or(self.design);
        let trial = Trial {
            name: cand.name(),
            theta: proposal.theta(),
            delta_bic: ev.delta_bic,
            cv_rms_um: ev.cv.as_ref().map_or(f64::NAN, |c| c.1.rms_um),
            folds_better: ev.folds_better,
            folds: design.folds,
            passed: ev.passed,
        };
        let gap_s = design.gap_s;
        let scored = match (ev.passed, ev.cv) {
            (true, Some((cv_cur, cv_new))) => Some(Scored {
                cand,
                proposal,
                fit: ev.fit,
                cv_cur,
                cv_new,
                gap_s,
                n_eff: ev.n_eff,
                trial: trial.clone(),
            }),
            _ => None,
        };
        Ok((trial, scored))
    }
}

/// Rows the final model misses by far more than it misses the rest: beyond 10 robust standard
/// deviations (1.4826·MAD) of its held-out residual and 5 noise floors — a start-up transient,
/// a reading taken while the stage still moved. Only a few rows (at most 0.5 %) can be
/// outliers; more is structure, and stays in.
fn model_outliers(r: &[f64], floor: &NoiseFloor) -> Vec<usize> {
    let mut v: Vec<f64> = r.iter().copied().filter(|x| x.is_finite()).collect();
    if v.len() < 50 {
        return Vec::new();
    }
    let med = stats::median(&mut v);
    let mut dev: Vec<f64> = v.iter().map(|x| (x - med).abs()).collect();
    let sigma = 1.4826 * stats::median(&mut dev);
    let thr = (10.0 * sigma).max(5.0 * floor.sample_um);
    let out: Vec<usize> = (0..r.len())
        .filter(|&i| r[i].is_finite() && (r[i] - med).abs() > thr)
        .collect();
    if out.len() * 200 > v.len() {
        Vec::new()
    } else {
        out
    }
}

/// Explain one channel. Rows that every model misses by far (see [`model_outliers`]) are
/// excluded and the channel explained once more without them; they are reported.
pub fn explain_channel(
    d: &Data,
    ch: usize,
    settings: &Settings,
) -> Result<ChannelReport, ExplainError> {
    let first = explain_channel_once(d, ch, settings)?;
    let far = model_outliers(&first.residual_after_um, &first.noise_floor);
    if far.is_empty() {
        return Ok(first);
    }
    let mut d2 = d.clone();
    {
        let c = &mut d2.channels[ch];
        for &i in &far {
            c.y_um[i] = f64::NAN;
        }
    }
    let mut rep = explain_channel_once(&d2, ch, settings)?;
    rep.model_outliers = far;
    Ok(rep)
}

fn explain_channel_once(
    d: &Data,
    ch: usize,
    settings: &Settings,
) -> Result<ChannelReport, ExplainError> {
    let rows = fit::eval_rows(&d.channels[ch].y_um, EVAL_ROWS);
    if rows.len() < 20 {
        return Err(ExplainError::Input(format!(
            "channel {}: expected at least 20 usable rows, found {}",
            d.channels[ch].name,
            rows.len()
        )));
    }
    let design = Design::standard(&d.t_s);
    let mut d = choose_smoothing(d, ch, &design, &rows)?;
    let (base_cols, mut baseline) = baseline_columns(&d, ch);
    if d.smooth_half_window_s > 0.0 {
        baseline.push_str(&format!(
            " (temperatures denoised by a zero-phase ±{} mean, chosen by held-out prediction — for diagnosis only: it uses later readings; the compensator reads the raw sensors through the same causal lag filters)",
            units::duration(d.smooth_half_window_s)
        ));
    }
    let mut model = Model { cols: base_cols };
    let base_fit = fit::fit_rows(&model.with(&[]), &d.channels[ch].y_um, &rows)?;
    {
        let c = &mut d.channels[ch];
        for ((p, m), r) in c
            .position_est_um
            .iter_mut()
            .zip(&c.meas_um)
            .zip(&base_fit.residuals)
        {
            *p = if r.is_finite() { m - r } else { *m };
        }
    }
    let d = &d;
    let y = &d.channels[ch].y_um;
    let base_cv = fit::cross_validate(&model.with(&[]), y, &design, &rows)?;
    let floor = locate::noise(d, ch, &base_fit.residuals);
    // the places locate looks at, for the baseline's residual here and the final one
    let places = locate::Places::of(d, ch);
    let located = places.locate(&base_fit.residuals, floor);
    let mut cur_fit = base_fit.clone();
    let mut cur_cv = base_cv.clone();
    let mut effects = Vec::new();
    let mut trials_all = Vec::new();
    let mut accepted: Vec<&'static str> = Vec::new();
    // model columns [start, end) and searched parameters of each named effect
    let mut effect_cols: Vec<(usize, usize, usize)> = Vec::new();
    let mut k_cur = model.cols.len() + 1;
    let units_n = locate::unit_count(d, ch);
    // events first: a residual that steps once and stays is located and modelled as an offset
    // from its row on before any effect is named, so no drift is handed the credit
    let mut found_events: Vec<events::Event> = Vec::new();
    let temp_gains: Vec<f64> = {
        let offset = if d.against_simulation || d.channels[ch].u.is_none() {
            0
        } else {
            3
        };
        (0..d.temps.len())
            .map(|i| base_fit.ls.coeffs.get(offset + i).copied().unwrap_or(0.0))
            .collect()
    };
    for _ in 0..MAX_EVENTS {
        let clean = events::without_pose_structure(d, ch, &cur_fit.residuals);
        let Some(mut ev) = events::find_step(d, ch, &clean, &floor, &temp_gains) else {
            break;
        };
        let col = events::step_column(d.rows(), ev.row);
        let n_eff = fit::round_effective_n(&fit::gather(&cur_fit.residuals, &rows), units_n);
        let round = Round {
            y,
            rows: &rows,
            design: &design,
            model: &model,
            cur_fit: &cur_fit,
            cur_cv: &cur_cv,
            k_cur,
            n_eff,
            floor_um: floor.unit_um.max(floor.sample_um),
            settings,
        };
        let e = round.evaluate(&[col.as_slice()], 1, None, None)?;
        let (true, Some((cv_cur, cv_new))) = (e.passed, e.cv) else {
            break;
        };
        let m = model.cols.len();
        let infl = (e.fit.n as f64 / e.n_eff.max(1.0)).sqrt().max(1.0);
        ev.size_um = e.fit.ls.coeffs[m];
        ev.size_sigma_um = e.fit.ls.std_errors()[m] * infl;
        ev.evidence = format!(
            "held-out RMS {} → {} ({} of {} folds better), ΔBIC {:.0}",
            units::length_um(cv_cur.rms_um),
            units::length_um(cv_new.rms_um),
            e.folds_better,
            design.folds,
            e.delta_bic
        );
        found_events.push(ev);
        model.cols.push(col);
        k_cur += 2;
        cur_fit = e.fit;
        cur_cv = cv_new;
    }
    for _round in 0..settings.max_effects {
        // the most independent rows this round can have (dwells, the residual's whiteness);
        // each candidate's own evidence counts fewer when it and the residual are smooth
        let n_eff = fit::round_effective_n(&fit::gather(&cur_fit.residuals, &rows), units_n);
        let basis = search::Basis::new(&model.with(&[]), y, rows.clone());
        let s = search::Search {
            d,
            ch,
            y,
            model: model.with(&[]),
            basis,
            n_eff,
            design: &design,
            sigmas: true,
        };
        let round = Round {
            y,
            rows: &rows,
            design: &design,
            model: &model,
            cur_fit: &cur_fit,
            cur_cv: &cur_cv,
            k_cur,
            n_eff,
            floor_um: floor.unit_um.max(floor.sample_um),
            settings,
        };
        let mut trials = Vec::new();
        let mut best: Option<Scored> = None;
        // explanations through recorded channels first; time alone only when none passes
        for time_only in [false, true] {
            let todo: Vec<&'static dyn Candidate> = candidates()
                .into_iter()
                .filter(|c| c.time_only() == time_only && !accepted.contains(&c.name()))
                .collect();
            // each candidate's proposal and score read the round and write nothing shared:
            // worked out side by side, taken in the library's order as one after the other
            type Outcome = Result<Option<(Trial, Option<Scored>)>, ExplainError>;
            let outcomes = in_parallel(&todo, |&cand| -> Outcome {
                if !cand.applies(d, ch) {
                    return Ok(None);
                }
                match cand.propose(&s)? {
                    Some(p) => round.score(cand, p).map(Some),
                    None => Ok(None),
                }
            });
            for outcome in outcomes {
                let Some((trial, scored)) = outcome? else {
                    continue;
                };
                trials.push(trial);
                if let Some(sc) = scored {
                    // among the candidates that predict held-out data better, the information
                    // criterion picks the winner: the most evidence per parameter
                    if best
                        .as_ref()
                        .is_none_or(|b| sc.trial.delta_bic < b.trial.delta_bic)
                    {
                        best = Some(sc);
                    }
                }
            }
            if best.is_some() {
                break;
            }
        }
        trials_all.push(trials);
        let Some(mut sc) = best else {
            break;
        };
        let m = model.cols.len();
        let f = sc.fit;
        // uncertainties for autocorrelated residuals: standard errors inflated by √(n/n_eff)
        // with the independent rows behind this effect's evidence; profile widths of θ (found
        // with the round's n_eff) widened by √(n_eff_round/n_eff)
        let infl = (f.n as f64 / sc.n_eff.max(1.0)).sqrt().max(1.0);
        let widen = (n_eff / sc.n_eff.max(1.0)).sqrt().max(1.0);
        sc.proposal.widen_sigmas(widen);
        let se_all = f.ls.std_errors();
        let coeffs: Vec<f64> = f.ls.coeffs[m..].to_vec();
        let se: Vec<f64> = se_all[m..].iter().map(|s| s * infl).collect();
        let fitted = Fitted {
            proposal: &sc.proposal,
            coeffs: &coeffs,
            se: &se,
            noise_sigma_um: f.ls.rmse() * infl,
        };
        let mut params: Vec<Estimate> = sc.cand.params(d, ch, &fitted);
        // where the model is nonlinear, the profile's σ assumes white residuals and holds the
        // linear coefficients to the θ found: a block jackknife over time measures the spread
        // the data allow, and the larger of the two is stated
        let mut jackknifed = false;
        if jackknife::nonlinear(&sc.proposal)
            && jackknife::affordable(d)
            && params.iter().any(|p| p.sigma.is_finite() && p.sigma > 0.0)
        {
            let spread = jackknife::sigmas(
                d,
                ch,
                &model.with(&[]),
                y,
                &rows,
                &design,
                n_eff,
                sc.cand,
                &fitted,
                &params,
            )?;
            for (p, j) in params.iter_mut().zip(spread) {
                if let Some(sj) = j.filter(|sj| *sj > p.sigma) {
                    p.sigma = sj;
                    jackknifed = true;
                }
            }
        }
        // how much the model's prediction changed by adding the effect
        let change: Vec<f64> = cur_fit
            .residuals
            .iter()
            .zip(&f.residuals)
            .map(|(a, b)| a - b)
            .collect();
        params.push(Estimate::new(
            "contribution_rms_nm",
            fit::rms(&change) * 1e3,
            f64::NAN,
        ));
        let mut new_cols = model.with(&[]);
        new_cols.extend(sc.proposal.regs.iter().map(|c| c.as_slice()));
        let cv_std = if sc.cv_new.fold_mse.len() != design.folds || sc.gap_s != design.gap_s {
            fit::cross_validate(&new_cols, y, &design, &rows)?
        } else {
            sc.cv_new.clone()
        };
        let nm = |v_um: f64| units::length_um(v_um);
        let mut evidence = format!(
            "held-out RMS {} → {} ({} of {} folds better, held-out blocks of {}), ΔBIC {:.0}, in-sample RMS {} → {}",
            nm(sc.cv_cur.rms_um),
            nm(sc.cv_new.rms_um),
            sc.trial.folds_better,
            sc.trial.folds,
            units::duration(sc.gap_s),
            sc.trial.delta_bic,
            nm(fit::rms(&cur_fit.residuals)),
            nm(fit::rms(&f.residuals))
        );
        for note in sc.proposal.thetas.iter().filter_map(|t| t.bound_note()) {
            evidence.push_str("; ");
            evidence.push_str(&note);
        }
        if jackknifed {
            evidence.push_str(&format!(
                "; σ from a jackknife over {} time blocks (the parameters searched again without each), where larger than the profile's",
                jackknife::BLOCKS
            ));
        }
        effects.push(EffectReport {
            name: sc.cand.name(),
            channel: d.channels[ch].name.clone(),
            description: sc.cand.description(),
            summary: sc.cand.summary(d, ch, &fitted),
            deploy: sc.cand.deploy(),
            blob: sc.cand.blob_terms(&blob_context(d, ch), &fitted),
            params,
            rms_before_nm: cur_cv.rms_um * 1e3,
            rms_after_nm: cv_std.rms_um * 1e3,
            evidence,
        });
        accepted.push(sc.cand.name());
        k_cur += sc.proposal.regs.len() + sc.proposal.thetas.len();
        effect_cols.push((
            model.cols.len(),
            model.cols.len() + sc.proposal.regs.len(),
            sc.proposal.thetas.len(),
        ));
        // (a column shared with the data's kept cosines is copied here, once it is named)
        model.cols.extend(
            sc.proposal
                .regs
                .into_iter()
                .map(std::sync::Arc::unwrap_or_clone),
        );
        cur_fit = f;
        cur_cv = cv_std;
    }
    // misspecification: a temperature² term per sensor against every named effect that
    // explains slow structure — a listed name stays only if the data need its form
    let mut not_in_library: Vec<misspec::Misfit> = Vec::new();
    if !d.temps.is_empty() && !d.against_simulation {
        let squares = misspec::temperature_squares(d);
        let mut withdrawn: Vec<&'static str> = Vec::new();
        for j in (0..effects.len()).rev() {
            if !misspec::SMOOTH_EFFECTS.contains(&effects[j].name) {
                continue;
            }
            let (a, b, thetas) = effect_cols[j];
            // an explanation through recorded channels is judged without the time-only ones
            // (they were tried only after it, as the last resort)
            let time_only: Vec<(usize, usize)> = if effects[j].name == unexplained_drift_name() {
                Vec::new()
            } else {
                (0..effects.len())
                    .filter(|&k| effects[k].name == unexplained_drift_name())
                    .map(|k| (effect_cols[k].0, effect_cols[k].1))
                    .collect()
            };
            let keep =
                |i: usize| (i < a || i >= b) && time_only.iter().all(|&(p, q)| i < p || i >= q);
            let without = |extra: &[Vec<f64>]| -> Model {
                let mut m = Model {
                    cols: (0..model.cols.len())
                        .filter(|&i| keep(i))
                        .map(|i| model.cols[i].clone())
                        .collect(),
                };
                m.cols.extend(extra.iter().cloned());
                m
            };
            let alt = without(&squares);
            let alt_cols = alt.with(&[]);
            let alt_cv = fit::cross_validate(&alt_cols, y, &design, &rows)?;
            // the named form's own standing on the same footing
            let named = without(&model.cols[a..b]);
            let named_cv = fit::cross_validate_score(&named.with(&[]), y, &design, &rows)?;
            if !matches!(
                alt_cv
                    .rms_um
                    .partial_cmp(&(named_cv.rms_um * misspec::AS_GOOD)),
                Some(std::cmp::Ordering::Less | std::cmp::Ordering::Equal)
            ) {
                continue;
            }
            let rest = Model {
                cols: (0..model.cols.len())
                    .filter(|&i| i < a || i >= b)
                    .map(|i| model.cols[i].clone())
                    .collect(),
            };
            // is the named form needed on top of the squares?
            let alt_fit = fit::fit_rows(&alt_cols, y, &rows)?;
            let dropped_time_only: usize = time_only.iter().map(|(p, q)| q - p).sum();
            let k_alt = k_cur - (b - a) - thetas - dropped_time_only + squares.len();
            let n_eff = fit::round_effective_n(&fit::gather(&alt_fit.residuals, &rows), units_n);
            let round = Round {
                y,
                rows: &rows,
                design: &design,
                model: &alt,
                cur_fit: &alt_fit,
                cur_cv: &alt_cv,
                k_cur: k_alt,
                n_eff,
                floor_um: floor.unit_um.max(floor.sample_um),
                settings,
            };
            let regs: Vec<&[f64]> = model.cols[a..b].iter().map(|c| c.as_slice()).collect();
            if round.evaluate(&regs, thetas, None, None)?.passed {
                continue;
            }
            // not needed: withdrawn; the model goes back to what it was without it
            withdrawn.push(effects[j].name);
            effects.remove(j);
            accepted.remove(j);
            let removed = b - a;
            effect_cols.remove(j);
            for e in effect_cols.iter_mut().skip(j) {
                e.0 -= removed;
                e.1 -= removed;
            }
            model = rest;
            k_cur -= removed + thetas;
            cur_fit = fit::fit_rows(&model.with(&[]), y, &rows)?;
            cur_cv = fit::cross_validate(&model.with(&[]), y, &design, &rows)?;
        }
        // does the square carry structure beyond what is named?
        let n_eff = fit::round_effective_n(&fit::gather(&cur_fit.residuals, &rows), units_n);
        let round = Round {
            y,
            rows: &rows,
            design: &design,
            model: &model,
            cur_fit: &cur_fit,
            cur_cv: &cur_cv,
            k_cur,
            n_eff,
            floor_um: floor.unit_um.max(floor.sample_um),
            settings,
        };
        let square_cols: Vec<&[f64]> = squares.iter().map(|c| c.as_slice()).collect();
        let ev = round.evaluate(&square_cols, 0, None, None)?;
        if ev.passed || !withdrawn.is_empty() {
            let m = model.cols.len();
            let coeffs = &ev.fit.ls.coeffs[m..];
            let sensor = misspec::main_square(d, &squares, coeffs);
            let (rms_nm, evidence) = match &ev.cv {
                Some((c0, c1)) => (
                    (c0.rms_um.powi(2) - c1.rms_um.powi(2)).max(0.0).sqrt() * 1e3,
                    format!(
                        "a temperature² term per sensor on top of the model: held-out RMS {} → {} ({} of {} folds better), ΔBIC {:.0}",
                        units::length_um(c0.rms_um),
                        units::length_um(c1.rms_um),
                        ev.folds_better,
                        design.folds,
                        ev.delta_bic
                    ),
                ),
                None => (
                    0.0,
                    format!("ΔBIC of the squares on top of what remains named: {:+.0}", ev.delta_bic),
                ),
            };
            not_in_library.push(misspec::nonlinear_thermal(
                &sensor, &withdrawn, rms_nm, evidence,
            ));
        }
    }
    // targeted tests for effects at or below the noise, with a family-wise false-alarm rate
    let targeted = targeted::run(d, ch, &model.with(&[]), y, &rows);
    let family = targeted.len();
    for t in targeted.iter().filter(|t| t.significant) {
        if accepted.contains(&t.effect) {
            continue;
        }
        let Some(cand) = candidates().into_iter().find(|c| c.name() == t.effect) else {
            continue;
        };
        let new_cols = model.with(&t.columns);
        let f = fit::fit_rows(&new_cols, y, &rows)?;
        let cv_new = fit::cross_validate(&new_cols, y, &design, &rows)?;
        let m = model.cols.len();
        let proposal = Proposal::linear(t.columns.clone());
        let se = f.ls.std_errors();
        let fitted = Fitted {
            proposal: &proposal,
            coeffs: &f.ls.coeffs[m..],
            se: &se[m..],
            noise_sigma_um: f.ls.rmse(),
        };
        let mut params = vec![];
        match t.period_nm {
            Some(p) => {
                params.push(Estimate::new("period_nm", p, f64::NAN));
                params.push(Estimate::new(
                    "amplitude_nm",
                    t.amplitude,
                    t.amplitude_sigma,
                ));
                params.push(Estimate::new("phase_rad", t.phase_rad, f64::NAN));
            }
            None => params.push(Estimate::new(
                "alpha_ppm_per_c",
                t.amplitude,
                t.amplitude_sigma,
            )),
        }
        params.push(Estimate::new("z", t.z, f64::NAN));
        effects.push(EffectReport {
            name: t.effect,
            channel: d.channels[ch].name.clone(),
            description: cand.description(),
            summary: format!(
                "found by a targeted test of {}: {} ± {} (z = {:.1}; the family of {family} targeted test(s) on this channel holds a {} % false-alarm rate together; the same in both halves of the record)",
                t.what,
                units::sig3(t.amplitude),
                units::sig3(t.amplitude_sigma),
                t.z,
                targeted::FAMILY_FALSE_ALARM * 100.0
            ),
            deploy: cand.deploy(),
            blob: cand.blob_terms(&blob_context(d, ch), &fitted),
            params,
            rms_before_nm: cur_cv.rms_um * 1e3,
            rms_after_nm: cv_new.rms_um * 1e3,
            evidence: format!(
                "targeted test: p = {:.2e} against {:.2e} for each of {family} test(s); held-out RMS {} → {}",
                t.p_value,
                targeted::FAMILY_FALSE_ALARM / family.max(1) as f64,
                units::length_um(cur_cv.rms_um),
                units::length_um(cv_new.rms_um)
            ),
        });
        accepted.push(t.effect);
        effect_cols.push((m, m + t.columns.len(), 0));
        model.cols.extend(t.columns.iter().cloned());
        cur_fit = f;
        cur_cv = cv_new;
    }
    let final_floor = locate::noise(d, ch, &cur_fit.residuals);
    let mut unexplained = places.locate(&cur_cv.residuals, final_floor);
    // the clearest places first, at most eight per channel
    unexplained.sort_by(|a, b| b.z.total_cmp(&a.z));
    unexplained.truncate(8);
    for m in &not_in_library {
        unexplained.insert(
            0,
            Finding {
                place: m.description.clone(),
                dimension: m.coordinate.clone(),
                rms_nm: m.rms_nm,
                mean_nm: 0.0,
                z: f64::NAN,
            },
        );
    }
    // everything left well above the noise floor without a place (held-out RMS over twice the
    // floor: three quarters of its variance is not noise): say so
    let final_rms = cur_cv.rms_um;
    let level = final_floor.unit_um.max(final_floor.sample_um);
    if unexplained.is_empty() && final_rms > 2.0 * level && final_rms > 0.0 {
        unexplained.push(Finding {
            place: "throughout the recording (no single place)".into(),
            dimension: "all".into(),
            rms_nm: final_rms * 1e3,
            mean_nm: 0.0,
            z: final_rms / level.max(1e-12),
        });
    }
    let c = &d.channels[ch];
    Ok(ChannelReport {
        channel: c.name.clone(),
        baseline,
        rows: d.rows(),
        noise_floor: floor,
        quant_step_um: c.quant_step_um,
        held: c.held,
        outliers: c.outliers.clone(),
        outlier_max_um: c.outlier_max_um,
        model_outliers: Vec::new(),
        baseline_rms_nm: base_cv.rms_um * 1e3,
        baseline_in_sample_rms_nm: fit::rms(&base_fit.residuals) * 1e3,
        final_rms_nm: final_rms * 1e3,
        located,
        events: found_events,
        not_in_library,
        targeted,
        effects,
        unexplained,
        trials: trials_all,
        iso_before: report::iso_accuracy(d, ch, &base_cv.residuals),
        iso_after: report::iso_accuracy(d, ch, &cur_cv.residuals),
        residual_before_um: base_cv.residuals,
        residual_after_um: cur_cv.residuals,
    })
}

/// Where channel `ch` sits in a shared model built from this recording.
pub fn blob_context(d: &Data, ch: usize) -> contract::BlobContext {
    contract::BlobContext {
        output: ch as u8,
        axes: d.channels.len() as u8,
        temps: d.temps.len().min(nanocal_model::MAX_TEMPS) as u8,
        pressure_aux: d
            .pressure_hpa
            .as_ref()
            .and_then(|(name, _)| d.aux.iter().position(|a| &a.0 == name))
            .map(|i| i as u8),
    }
}

/// Explain every measured channel of a recording.
pub fn explain(d: &Data, settings: &Settings) -> Result<Report, ExplainError> {
    let channels = (0..d.channels.len())
        .map(|ch| explain_channel(d, ch, settings))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(Report {
        channels,
        time_unit: d.time_unit(),
        duration_s: d.duration_s(),
        temp_repairs: d.temp_repairs.clone(),
        data_faults: d.faults.clone(),
    })
}
