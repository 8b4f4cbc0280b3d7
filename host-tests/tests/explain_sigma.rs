//! Honest uncertainties (issue 17 item 5) for creep and hysteresis: every parameter explain
//! states with a σ covers the truth within 2σ; a parameter the data determine only as a bound
//! is reported as that bound (no σ, on the right side of the truth); a σ of 0 is never stated.

mod explain_common;
use explain_common::*;

use nanocal::effects::*;
use nanocal::explain::estimate::Estimate;
use nanocal::explain::Report;

/// The parameters of the effect `name` (panics when it is not named).
fn params<'a>(rep: &'a Report, name: &str) -> &'a [Estimate] {
    &rep.effects()
        .find(|e| e.name == name)
        .unwrap_or_else(|| panic!("{name} not named:\n{}", rep.to_text()))
        .params
}

fn get<'a>(ps: &'a [Estimate], name: &str) -> &'a Estimate {
    ps.iter()
        .find(|p| p.name == name)
        .unwrap_or_else(|| panic!("no parameter {name} in {ps:?}"))
}

/// No parameter is stated with a σ of 0 (or a negative one).
fn no_zero_sigma(ps: &[Estimate], what: &str) {
    for p in ps {
        assert!(
            p.sigma.is_nan() || p.sigma > 0.0,
            "{what}: {} = {} stated with σ = {}",
            p.name,
            p.value,
            p.sigma
        );
    }
}

/// `est` is within 2 of its stated σ of `truth`.
fn covers(est: &Estimate, truth: f64, what: &str) {
    assert!(
        est.sigma.is_finite() && (est.value - truth).abs() <= 2.0 * est.sigma,
        "{what}: {} = {} ± {} against a truth of {truth}",
        est.name,
        est.value,
        est.sigma
    );
}

fn creep(seed: u64, gamma: f64, t0_s: f64) -> Report {
    explain_columns(training_1dof(
        vec![EffectSpec::Creep(creep::Params {
            axis: 0,
            gamma,
            t0_s,
        })],
        6,
        seed,
    ))
}

/// t0 inside the searched range (0.1 s … the 60 s dwell): γ and t0 both within 2σ.
#[test]
fn creep_with_t0_inside_its_range_covers_the_truth() {
    for (seed, gamma, t0_s) in [
        (1u64, 8e-4, 0.06),
        (3, 1e-3, 0.2),
        (4, 6e-4, 3.0),
        (5, 9e-4, 30.0),
    ] {
        let rep = creep(seed, gamma, t0_s);
        let ps = params(&rep, "creep");
        let what = format!("creep γ {gamma}, t0 {t0_s} s (seed {seed})");
        no_zero_sigma(ps, &what);
        covers(get(ps, "gamma"), gamma, &what);
        covers(get(ps, "t0_s"), t0_s, &what);
    }
}

/// t0 below the shortest searched (a tenth of a sample interval): t0 is an upper bound (no σ)
/// and γ — the slope in log t, which the data still show — stays an estimate within 2σ.
#[test]
fn creep_with_t0_below_its_range_is_an_upper_bound() {
    for (seed, gamma, t0_s) in [(1u64, 8e-4, 0.005), (2, 5e-4, 0.02)] {
        let rep = creep(seed, gamma, t0_s);
        let ps = params(&rep, "creep");
        let what = format!("creep γ {gamma}, t0 {t0_s} s (seed {seed})");
        no_zero_sigma(ps, &what);
        let t0 = get(ps, "t0_s");
        assert!(t0.sigma.is_nan() && t0.value >= t0_s, "{what}: {t0:?}");
        covers(get(ps, "gamma"), gamma, &what);
    }
}

/// t0 far beyond the 60 s dwells: only γ/t0 is determined. Then t0 is a lower bound and so is
/// |γ|, both without a σ — before, γ came back at 0.70 and 0.26 of the truth with σ that put
/// it 16 and 49σ away.
#[test]
fn creep_with_t0_beyond_the_dwells_gives_gamma_as_a_lower_bound() {
    for (seed, gamma, t0_s) in [(3u64, 1e-3, 200.0), (4, 6e-4, 1000.0)] {
        let rep = creep(seed, gamma, t0_s);
        let ps = params(&rep, "creep");
        let what = format!("creep γ {gamma}, t0 {t0_s} s (seed {seed})");
        no_zero_sigma(ps, &what);
        let t0 = get(ps, "t0_s");
        assert!(t0.sigma.is_nan() && t0.value <= t0_s, "{what}: {t0:?}");
        for name in ["gamma", "nm_per_um_per_decade"] {
            let p = get(ps, name);
            assert!(
                p.sigma.is_nan(),
                "{what}: {name} = {} ± {} stated as a value, t0 on its bound",
                p.value,
                p.sigma
            );
        }
        let g = get(ps, "gamma");
        assert!(
            g.value.abs() <= gamma.abs(),
            "{what}: |γ| ≥ {} is not a lower bound of {gamma}",
            g.value
        );
        let e = rep.effects().find(|e| e.name == "creep").unwrap();
        assert!(e.summary.contains("lower bound"), "{what}: {}", e.summary);
    }
}

/// Hysteresis (step and settle): every stated σ is positive and the half-width's covers the
/// truth.
#[test]
fn hysteresis_states_no_zero_sigma() {
    for (seed, half_width_nm) in [(1u64, 20.0), (2, -12.0)] {
        let rep = explain_columns(training_1dof(
            vec![EffectSpec::Hysteresis(hysteresis::Params {
                axis: 0,
                half_width_nm,
                slope_nm: 0.0,
                ..Default::default()
            })],
            6,
            seed,
        ));
        let ps = params(&rep, "hysteresis");
        let what = format!("hysteresis {half_width_nm} nm (seed {seed})");
        no_zero_sigma(ps, &what);
        covers(get(ps, "half_width_nm"), half_width_nm.abs(), &what);
    }
}

/// γ and t0 trade off: γ's σ carries t0's share along its profile. The proof's creep on seed
/// 9001 (γ 1.1000·10⁻³, t0 8.0 s; drawn as the proof draws it) came back 1.1101·10⁻³ ± 0.3 %
/// with t0 = 8.5 ± 0.9 s — 3.3σ off with γ's σ at t0 held fixed.
#[test]
fn creep_gamma_sigma_carries_the_share_of_t0() {
    let seed = 9001;
    let mut r = rng(seed);
    let gamma = draw(&mut r, 3e-4, 1.2e-3);
    let t0_s = draw(&mut r, 0.05f64.ln(), 10f64.ln()).exp();
    let rep = creep(seed, gamma, t0_s);
    let ps = params(&rep, "creep");
    let what = format!("creep γ {gamma}, t0 {t0_s} s (seed {seed})");
    no_zero_sigma(ps, &what);
    let g = get(ps, "gamma");
    covers(g, gamma, &what);
    // and is still of use: a few per cent of γ at most
    assert!(g.sigma < 0.03 * g.value.abs(), "{what}: {g:?}");
}

/// Minor loops (the proof's worst case, seed 9003): the half-width is that of a full loop over
/// the stroke the command covered — the `stroke_um` explain states — and covers the hidden
/// bank's loop over that stroke. (Judged against the loop over the whole 30 µm travel, which
/// the random turning points do not reach, it read 6.7σ off: the proof's truth was of another
/// loop, not explain's estimate biased.)
#[test]
fn hysteresis_minor_loops_half_width_is_at_the_recorded_stroke() {
    let seed = 9003;
    let mut r = rng(seed);
    let sense = sign(&mut r);
    let thresholds: Vec<f64> = vec![
        30.0 * draw(&mut r, 0.01, 0.05),
        30.0 * draw(&mut r, 0.07, 0.17),
        30.0 * draw(&mut r, 0.2, 0.37),
    ];
    let weights: Vec<f64> = (0..3).map(|_| sense * draw(&mut r, 0.005, 0.02)).collect();
    let cols = continuous_drive(
        vec![EffectSpec::Hysteresis(hysteresis::Params {
            axis: 0,
            play_thresholds_um: thresholds.clone(),
            play_weights: weights.clone(),
            ..Default::default()
        })],
        seed,
    );
    let cmd = cols.get("cmd_x").unwrap();
    let lo = cmd.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = cmd.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let rep = explain_columns(cols);
    let ps = params(&rep, "hysteresis");
    let what = format!("minor loops (seed {seed})");
    no_zero_sigma(ps, &what);
    let stroke = get(ps, "stroke_um").value;
    assert!(
        (stroke - (hi - lo)).abs() < 1e-9,
        "{what}: stroke {stroke} against {lo}…{hi}"
    );
    let truth = 1e3 * hysteresis::full_loop_half_width_um(&thresholds, &weights, 0.5 * stroke);
    let hw = get(ps, "half_width_nm");
    covers(hw, truth, &what);
    assert!(hw.sigma < 0.05 * hw.value, "{what}: {hw:?}");
}
