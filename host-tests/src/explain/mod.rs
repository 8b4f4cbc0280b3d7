//! `explain`: find, name and model the physics a model (or a simulation) left out.
//!
//! 1. **Baseline** — the published static model (cubic in the commanded position, linear in
//!    every temperature, an offset) fitted to the recording; or, with a simulation, the
//!    difference to it.
//! 2. **Locate** — where the residual is structured (time, position, direction, other axes,
//!    temperature rate, auxiliary channels) against a noise floor estimated from the data.
//! 3. **Name** — every candidate in [`crate::effects`] is tried as an extension of the current
//!    model, its nonlinear parameter (τ, t0, period, time scale) searched by least squares; it is
//!    accepted only if it lowers an information criterion (BIC with an effective sample size
//!    for autocorrelated residuals) by more than [`Settings::min_bic_drop`] AND improves the
//!    held-out RMS of blocked cross-validation in most folds. The best accepted candidate joins
//!    the model and the search repeats.
//! 4. **Model and show** — held-out RMS and ISO 9283 accuracy before/after, residual plots;
//!    whatever structure remains is reported as unexplained, with where it is.

pub mod data;
pub mod fit;
pub mod locate;
pub mod plot;
pub mod report;

use crate::effects::{candidates, Candidate, Estimate, Fitted};
use crate::linalg::LinalgError;
use crate::recording::RecordingError;

pub use data::Data;
pub use locate::{Finding, NoiseFloor};
pub use report::{ChannelReport, EffectReport, Report};

/// Errors of explain.
#[derive(Debug, thiserror::Error)]
pub enum ExplainError {
    /// The recording is not usable.
    #[error("{0}")]
    Input(String),
    /// Reading a recording failed.
    #[error(transparent)]
    Recording(#[from] RecordingError),
    /// A least-squares problem failed.
    #[error("least squares: {0}")]
    Linalg(#[from] LinalgError),
}

/// Thresholds of the naming step.
#[derive(Clone, Debug)]
pub struct Settings {
    /// Minimum drop of BIC (effective sample size) for a candidate to count (10 = "very strong").
    pub min_bic_drop: f64,
    /// Minimum relative drop of held-out RMS.
    pub min_rms_gain: f64,
    /// Minimum number of cross-validation folds (of 5) that must improve.
    pub min_folds_better: usize,
    /// Most effects named per channel.
    pub max_effects: usize,
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            min_bic_drop: 20.0,
            min_rms_gain: 0.01,
            min_folds_better: 4,
            max_effects: 4,
        }
    }
}

/// A candidate tried on a channel, and how it scored.
#[derive(Clone, Debug)]
pub struct Trial {
    /// Candidate name.
    pub name: &'static str,
    /// Best nonlinear parameter.
    pub theta: Option<f64>,
    /// BIC change (negative = better).
    pub delta_bic: f64,
    /// Held-out RMS with the extension, µm.
    pub cv_rms_um: f64,
    /// Folds that improved.
    pub folds_better: usize,
    /// Whether it passed the thresholds.
    pub passed: bool,
}

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

/// Half widths (s) of the delay-free temperature denoising that the baseline may use: sensor
/// noise is fast; slower smoothing would start to shape the thermal response itself.
pub const SMOOTHING_OPTIONS_S: [f64; 3] = [60.0, 150.0, 300.0];

fn choose_smoothing(d: &Data, ch: usize, folds: &[u8]) -> Result<Data, ExplainError> {
    if d.temps.is_empty() || d.against_simulation {
        return Ok(d.clone());
    }
    let mut best: Option<(f64, Data)> = None;
    let mut first_rms = f64::NAN;
    for &w in SMOOTHING_OPTIONS_S
        .iter()
        .filter(|&&w| w == SMOOTHING_OPTIONS_S[0] || w <= d.duration_s() / 20.0)
    {
        let dw = d.with_smoothing(w);
        let (cols, _) = baseline_columns(&dw, ch);
        let refs: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
        let cv = fit::cross_validate(&refs, &dw.channels[ch].y_um, folds)?;
        if first_rms.is_nan() {
            first_rms = cv.rms_um;
        }
        if best.as_ref().is_none_or(|b| cv.rms_um < b.0 * 0.99) {
            best = Some((cv.rms_um, dw));
        }
    }
    Ok(best.map(|b| b.1).unwrap_or_else(|| d.clone()))
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

/// Most rows used while searching a nonlinear parameter.
pub const SEARCH_ROWS: usize = 100_000;

/// A fitted extension: (θ, regressors, fit).
type Extension = (Option<f64>, Vec<Vec<f64>>, fit::Fit);

/// The best candidate of a round so far.
struct Best {
    /// −ΔBIC of the candidate.
    gain: f64,
    cand: &'static dyn Candidate,
    theta: Option<f64>,
    regs: Vec<Vec<f64>>,
    fit: fit::Fit,
    cv: fit::Cv,
    trial: Trial,
}

/// Fit a candidate's extension on top of `model`: search θ, return (θ, regressors, fit).
fn best_theta(
    d: &Data,
    ch: usize,
    cand: &dyn Candidate,
    model: &Model,
) -> Result<Extension, ExplainError> {
    let y = &d.channels[ch].y_um;
    let grid = cand.theta_grid(d, ch);
    if grid.is_empty() {
        let regs = cand.regressors(d, ch, None);
        let f = fit::fit(&model.with(&regs), y)?;
        return Ok((None, regs, f));
    }
    // Long recordings: search θ on every k-th row (≤ SEARCH_ROWS rows; the regressors, e.g.
    // lag filters, still run over every sample), then refit the best θ on all rows.
    let k = d.rows().div_ceil(SEARCH_ROWS).max(1);
    let y_search: Vec<f64> = if k > 1 {
        y.iter()
            .enumerate()
            .map(|(i, &v)| if i % k == 0 { v } else { f64::NAN })
            .collect()
    } else {
        Vec::new()
    };
    let ys: &[f64] = if k > 1 { &y_search } else { y };
    let eval = |th: f64| -> Result<(f64, Vec<Vec<f64>>, fit::Fit), ExplainError> {
        let regs = cand.regressors(d, ch, Some(th));
        let f = fit::fit(&model.with(&regs), ys)?;
        Ok((f.rss, regs, f))
    };
    let mut best: Option<(usize, f64, Vec<Vec<f64>>, fit::Fit)> = None;
    let mut rss_grid = Vec::with_capacity(grid.len());
    for (i, &th) in grid.iter().enumerate() {
        let (rss, regs, f) = eval(th)?;
        rss_grid.push(rss);
        if best.as_ref().is_none_or(|b| rss < b.1) {
            best = Some((i, rss, regs, f));
        }
    }
    let (bi, mut brss, mut bregs, mut bfit) = best.expect("grid is not empty");
    let mut bth = grid[bi];
    if cand.continuous() && grid.len() >= 3 {
        // golden-section search on log θ between the neighbours of the best grid point
        let lo = grid[bi.saturating_sub(1)].ln();
        let hi = grid[(bi + 1).min(grid.len() - 1)].ln();
        let g = 0.618_033_988_75;
        let (mut a, mut b) = (lo, hi);
        let mut x1 = b - g * (b - a);
        let mut x2 = a + g * (b - a);
        let mut f1 = eval(x1.exp())?;
        let mut f2 = eval(x2.exp())?;
        for _ in 0..10 {
            if f1.0 < f2.0 {
                b = x2;
                x2 = x1;
                f2 = f1;
                x1 = b - g * (b - a);
                f1 = eval(x1.exp())?;
            } else {
                a = x1;
                x1 = x2;
                f1 = f2;
                x2 = a + g * (b - a);
                f2 = eval(x2.exp())?;
            }
        }
        let (xm, fm) = if f1.0 < f2.0 { (x1, f1) } else { (x2, f2) };
        if fm.0 < brss {
            brss = fm.0;
            bth = xm.exp();
            bregs = fm.1;
            bfit = fm.2;
        }
    }
    let _ = brss;
    if k > 1 {
        bregs = cand.regressors(d, ch, Some(bth));
        bfit = fit::fit(&model.with(&bregs), y)?;
    }
    Ok((Some(bth), bregs, bfit))
}

/// 1σ of a continuous θ from the RSS profile: where n_eff·ln(RSS/RSS_min) rises by 1.
fn theta_sigma(
    d: &Data,
    ch: usize,
    cand: &dyn Candidate,
    model: &Model,
    th: f64,
    f: &fit::Fit,
    n_eff: f64,
) -> Result<f64, ExplainError> {
    let y = &d.channels[ch].y_um;
    let rss0 = f.rss;
    let g = |lt: f64| -> Result<f64, ExplainError> {
        let regs = cand.regressors(d, ch, Some(lt.exp()));
        let ff = fit::fit(&model.with(&regs), y)?;
        Ok(n_eff * (ff.rss / rss0).ln() - 1.0)
    };
    let l0 = th.ln();
    let mut bounds = [f64::NAN; 2];
    for (s, sign) in [1.0f64, -1.0].iter().enumerate().map(|(i, s)| (i, *s)) {
        let mut inner = 0.0;
        let mut outer = f64::NAN;
        for step in [0.02, 0.05, 0.1, 0.2, 0.4, 0.8, 1.6] {
            if g(l0 + sign * step)? > 0.0 {
                outer = step;
                break;
            }
            inner = step;
        }
        if outer.is_nan() {
            continue;
        }
        for _ in 0..5 {
            let mid = 0.5 * (inner + outer);
            if g(l0 + sign * mid)? > 0.0 {
                outer = mid;
            } else {
                inner = mid;
            }
        }
        bounds[s] = 0.5 * (inner + outer);
    }
    let width = match (bounds[0].is_finite(), bounds[1].is_finite()) {
        (true, true) => 0.5 * (bounds[0] + bounds[1]),
        (true, false) => bounds[0],
        (false, true) => bounds[1],
        _ => return Ok(f64::INFINITY),
    };
    Ok(th * width)
}

/// Explain one channel.
pub fn explain_channel(
    d: &Data,
    ch: usize,
    settings: &Settings,
) -> Result<ChannelReport, ExplainError> {
    let folds = fit::folds(d.rows());
    // Sensor noise in the temperatures would make any low-pass filter (a short "lag") look like
    // physics: pick the delay-free denoising of the temperatures that predicts held-out data
    // best (the least smoothing within 1 %), so a lag must earn its place by its delay.
    let mut d = choose_smoothing(d, ch, &folds)?;
    let (base_cols, mut baseline) = baseline_columns(&d, ch);
    if !d.temps.is_empty() && !d.against_simulation {
        baseline.push_str(&format!(
            " (temperatures denoised by a centred ±{:.0} s mean, chosen by cross-validation)",
            d.smooth_half_window_s
        ));
    }
    let mut model = Model { cols: base_cols };
    let base_fit = fit::fit(&model.with(&[]), &d.channels[ch].y_um)?;
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
    let base_cv = fit::cross_validate(&model.with(&[]), y, &folds)?;
    let floor = locate::noise(d, ch, &base_fit.residuals);
    let located = locate::locate(d, ch, &base_fit.residuals, floor);
    let mut cur_fit = base_fit.clone();
    let mut cur_cv = base_cv.clone();
    let mut effects = Vec::new();
    let mut trials_all = Vec::new();
    let mut accepted: Vec<&'static str> = Vec::new();
    let k_base = model.cols.len() + 1;
    let mut k_cur = k_base;
    let units = locate::unit_count(d, ch);
    for _round in 0..settings.max_effects {
        let n_eff = fit::round_effective_n(&cur_fit.residuals, units);
        let mut best: Option<Best> = None;
        let mut trials = Vec::new();
        for cand in candidates() {
            if accepted.contains(&cand.name()) || !cand.applies(d, ch) {
                continue;
            }
            let (theta, regs, f) = best_theta(d, ch, cand, &model)?;
            let k_new = k_cur + regs.len() + usize::from(theta.is_some());
            let delta_bic =
                fit::bic(f.rss, f.n, k_new, n_eff) - fit::bic(cur_fit.rss, cur_fit.n, k_cur, n_eff);
            let mut trial = Trial {
                name: cand.name(),
                theta,
                delta_bic,
                cv_rms_um: f64::NAN,
                folds_better: 0,
                passed: false,
            };
            if delta_bic < -settings.min_bic_drop {
                let cv = fit::cross_validate(&model.with(&regs), y, &folds)?;
                let folds_better = cv
                    .fold_mse
                    .iter()
                    .zip(&cur_cv.fold_mse)
                    .filter(|(a, b)| a < b)
                    .count();
                trial.cv_rms_um = cv.rms_um;
                trial.folds_better = folds_better;
                trial.passed = folds_better >= settings.min_folds_better
                    && cv.rms_um < cur_cv.rms_um * (1.0 - settings.min_rms_gain);
                if trial.passed {
                    // among the candidates that predict held-out data better, the information
                    // criterion picks the winner: the most evidence per parameter
                    let gain = -delta_bic;
                    if best.as_ref().is_none_or(|b| gain > b.gain) {
                        best = Some(Best {
                            gain,
                            cand,
                            theta,
                            regs,
                            fit: f,
                            cv,
                            trial: trial.clone(),
                        });
                    }
                }
            }
            trials.push(trial);
        }
        trials_all.push(trials);
        let Some(Best {
            cand,
            theta,
            regs,
            fit: f,
            cv,
            trial,
            ..
        }) = best
        else {
            break;
        };
        // parameters
        let m = model.cols.len();
        let n_eff_after = fit::round_effective_n(&f.residuals, units);
        let infl = (f.n as f64 / n_eff_after.max(1.0)).sqrt();
        let se_all = f.ls.std_errors();
        let coeffs: Vec<f64> = f.ls.coeffs[m..].to_vec();
        let se: Vec<f64> = se_all[m..].iter().map(|s| s * infl).collect();
        let th_sigma = match (theta, cand.continuous()) {
            (Some(th), true) => theta_sigma(d, ch, cand, &model, th, &f, n_eff_after)?,
            _ => f64::NAN,
        };
        let mut params: Vec<Estimate> = cand.params(
            d,
            ch,
            &Fitted {
                theta,
                theta_sigma: th_sigma,
                coeffs: &coeffs,
                se: &se,
            },
        );
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
        let rms_before_um = cur_cv.rms_um;
        let grid = cand.theta_grid(d, ch);
        let edge_note = match (theta, grid.first(), grid.last()) {
            (Some(th), Some(_), Some(&hi)) if cand.continuous() && th >= hi * 0.99 => {
                format!(
                    "; {} at the top of the searched range ({}): a lower bound",
                    cand.theta_name().unwrap_or("θ"),
                    sig3(hi)
                )
            }
            (Some(th), Some(&lo), Some(_)) if cand.continuous() && th <= lo * 1.01 => {
                format!(
                    "; {} at the bottom of the searched range ({}): an upper bound",
                    cand.theta_name().unwrap_or("θ"),
                    sig3(lo)
                )
            }
            _ => String::new(),
        };
        let evidence = format!(
            "held-out RMS {:.1} → {:.1} nm ({} of {} folds better), ΔBIC {:.0}, in-sample RMS {:.1} → {:.1} nm",
            rms_before_um * 1e3,
            cv.rms_um * 1e3,
            trial.folds_better,
            fit::CV_FOLDS,
            trial.delta_bic,
            fit::rms(&cur_fit.residuals) * 1e3,
            fit::rms(&f.residuals) * 1e3
        ) + &edge_note;
        effects.push(EffectReport {
            name: cand.name(),
            channel: d.channels[ch].name.clone(),
            description: cand.description(),
            deploy: cand.deploy(),
            blob: cand.blob_terms(&blob_context(d, ch), theta),
            params,
            rms_before_nm: rms_before_um * 1e3,
            rms_after_nm: cv.rms_um * 1e3,
            evidence,
        });
        accepted.push(cand.name());
        k_cur += regs.len() + usize::from(theta.is_some());
        model.cols.extend(regs);
        cur_fit = f;
        cur_cv = cv;
    }
    let final_floor = locate::noise(d, ch, &cur_fit.residuals);
    let mut unexplained = locate::locate(d, ch, &cur_cv.residuals, final_floor);
    // the clearest places first, at most eight per channel
    unexplained.sort_by(|a, b| b.z.total_cmp(&a.z));
    unexplained.truncate(8);
    // everything left well above the noise floor without a place: say so
    let final_rms = cur_cv.rms_um;
    if unexplained.is_empty()
        && final_rms > 3.0 * final_floor.unit_um.max(final_floor.sample_um)
        && final_rms > 0.0
    {
        unexplained.push(Finding {
            place: "throughout the recording (no single place)".into(),
            dimension: "all".into(),
            rms_nm: final_rms * 1e3,
            mean_nm: 0.0,
            z: final_rms / final_floor.unit_um.max(1e-12),
        });
    }
    Ok(ChannelReport {
        channel: d.channels[ch].name.clone(),
        baseline,
        rows: d.rows(),
        noise_floor: floor,
        baseline_rms_nm: base_cv.rms_um * 1e3,
        baseline_in_sample_rms_nm: fit::rms(&base_fit.residuals) * 1e3,
        final_rms_nm: final_rms * 1e3,
        located,
        effects,
        unexplained,
        trials: trials_all,
        iso_before: report::iso_accuracy(d, ch, &base_cv.residuals),
        iso_after: report::iso_accuracy(d, ch, &cur_cv.residuals),
        residual_before_um: base_cv.residuals,
        residual_after_um: cur_cv.residuals,
    })
}

fn sig3(v: f64) -> String {
    if v.abs() >= 1e4 {
        format!("{v:.0}")
    } else {
        format!("{v:.3}")
    }
}

/// Where channel `ch` sits in a shared model built from this recording.
pub fn blob_context(d: &Data, ch: usize) -> crate::effects::BlobContext {
    crate::effects::BlobContext {
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
    Ok(Report { channels })
}
