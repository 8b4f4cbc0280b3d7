//! Deployable effects go into the shared model and its blob with no new code path: their term
//! shapes (and lag filters) build into a `Model`, encode into the blob and decode back; the
//! others say why the compensator cannot run them. An effect explain finds carries its fitted
//! nonlinear parameters (τ per sensor) into the lag filters, and a hysteresis found hands over
//! a play-operator bank in the form the compensator's bank takes (per axis: thresholds
//! ascending ≥ 0, weights of one sign, operators fed by the axis position).

mod explain_common;
use explain_common::*;

use nanocal::effects::{candidates, hysteresis, thermal_lag, EffectSpec};
use nanocal::explain::contract::{BlobContext, Detail, Fitted, LagTerm, PlayBank, Proposal};
use nanocal::explain::estimate::Theta;
use nanocal::model::{blob, Factor, ModelBuilder};

fn build_with(
    ctx: &BlobContext,
    aux: usize,
    b: &nanocal::explain::contract::BlobTerms,
) -> nanocal::model::Model {
    let mut mb = ModelBuilder::new(ctx.axes as usize, ctx.temps as usize, aux).unwrap();
    let mut first_lag = None;
    for &(sensor, tau) in &b.lags {
        let k = mb.lag(sensor, tau).unwrap();
        first_lag.get_or_insert(k);
    }
    let mut first_play = None;
    for &(axis, r) in &b.plays {
        let k = mb.play(axis, r).unwrap();
        first_play.get_or_insert(k);
    }
    for (i, t) in b.terms.iter().enumerate() {
        let mut t = *t;
        if let Factor::Lagged(k) = t.factor {
            t.factor = Factor::Lagged(k + first_lag.unwrap());
        }
        if let Factor::Play(k) = t.factor {
            t.factor = Factor::Play(k + first_play.unwrap());
        }
        t.coeff = 1e-3 * (i + 1) as f64;
        mb.add_term(t).unwrap();
    }
    mb.build().unwrap()
}

fn tau(v: f64) -> Theta {
    Theta {
        name: "tau_s".into(),
        value: v,
        sigma: 10.0,
        lo: 10.0,
        hi: 1e5,
    }
}

/// A proposal of the shape each candidate makes, with made-up numbers.
fn representative(name: &str) -> Proposal {
    let mut p = Proposal::linear(vec![vec![0.0; 4]; 2]);
    match name {
        "thermal_lag" => {
            p.detail = Detail::Lags(vec![
                LagTerm {
                    sensor: 0,
                    tau: tau(1800.0),
                },
                LagTerm {
                    sensor: 2,
                    tau: tau(300.0),
                },
            ])
        }
        "hysteresis" => {
            p.detail = Detail::Play(PlayBank {
                axis: 0,
                drive: None,
                leading_poly: 0,
                thresholds_um: vec![0.5, 2.0],
                sense: 1.0,
                amplitude_um: 20.0,
                half_width_per_noise: 0.1,
                grid_spread_um: 0.0,
            })
        }
        _ => {}
    }
    p
}

#[test]
fn deployable_effects_build_into_the_blob_and_round_trip() {
    let ctx = BlobContext {
        output: 0,
        axes: 2,
        temps: 4,
        pressure_aux: Some(0),
    };
    let deployable = [
        "thermal_lag",
        "hysteresis",
        "thermal_position_interaction",
        "air_refraction",
        "geometric_order",
        "axis_coupling",
    ];
    for c in candidates() {
        let p = representative(c.name());
        let fitted = Fitted {
            proposal: &p,
            coeffs: &[0.1, 0.2],
            se: &[0.01, 0.01],
            noise_sigma_um: 0.01,
        };
        let b = c.blob_terms(&ctx, &fitted);
        if deployable.contains(&c.name()) {
            let b = b.unwrap_or_else(|| panic!("{} must be deployable", c.name()));
            assert!(!b.terms.is_empty());
            let model = build_with(&ctx, 1, &b);
            assert_eq!(model.terms().len(), b.terms.len(), "{}", c.name());
            let mut buf = vec![0u8; blob::MAX_BLOB_LEN];
            let n = blob::encode(&model, &mut buf).unwrap();
            let back = blob::decode(&buf[..n]).unwrap();
            assert_eq!(back, model, "{}", c.name());
        } else {
            assert!(b.is_none(), "{} has no model terms", c.name());
            assert!(
                c.deploy().starts_with("not in the blob"),
                "{}: {}",
                c.name(),
                c.deploy()
            );
        }
    }
}

#[test]
fn found_lags_carry_their_time_constants_into_the_lag_filters() {
    let mut cfg = lively_fast_sensors();
    cfg.effects = vec![EffectSpec::ThermalLag(thermal_lag::Params::common(1500.0))];
    let rep = explain_columns(simulate(
        cfg,
        &nanocal::twin::Trajectory::published_training_1dof(60.0, 10),
        51,
    ));
    let e = effect(&rep, "x", "thermal_lag").unwrap_or_else(|| panic!("{}", rep.to_text()));
    let b = e.blob.as_ref().unwrap();
    assert!(!b.lags.is_empty() && b.lags.len() <= 3 * 2);
    // every lag filter is one of the reported per-sensor time constants
    let names = ["air", "stage", "base"];
    for &(sensor, t) in &b.lags {
        let n = names[sensor as usize];
        let reported: Vec<f64> = ["tau_s_", "tau2_s_"]
            .iter()
            .filter_map(|p| e.param(&format!("{p}{n}")).map(|x| x.value))
            .collect();
        assert!(reported.contains(&t), "lag ({sensor}, {t}) not reported");
    }
    let ctx = BlobContext {
        output: 0,
        axes: 1,
        temps: 3,
        pressure_aux: None,
    };
    let model = build_with(&ctx, 0, b);
    assert_eq!(model.terms().len(), b.lags.len());
}

/// The operators explain hands over, stepped through the compensator's own play function,
/// reproduce the hysteresis explain fitted (up to the linear part the polynomial carries).
#[test]
fn a_found_hysteresis_hands_over_a_play_operator_bank() {
    let cols = continuous_drive(
        vec![EffectSpec::Hysteresis(hysteresis::Params {
            axis: 0,
            play_thresholds_um: vec![1.0, 4.0, 9.0],
            play_weights: vec![0.02, 0.015, 0.01],
            ..Default::default()
        })],
        7,
    );
    let cmd = cols.get("cmd_x").unwrap().to_vec();
    let rep = explain_columns(cols);
    let e = effect(&rep, "x", "hysteresis").unwrap_or_else(|| panic!("{}", rep.to_text()));
    let blob_terms = e.blob.as_ref().unwrap();
    // declared in the blob (v2): thresholds on the axis, one Factor::Play term each
    assert_eq!(
        blob_terms.plays,
        blob_terms
            .play
            .iter()
            .map(|o| (o.axis, o.threshold_um))
            .collect::<Vec<_>>()
    );
    let ctx = BlobContext {
        output: 0,
        axes: 1,
        temps: 4,
        pressure_aux: None,
    };
    let model = build_with(&ctx, 0, blob_terms);
    assert_eq!(model.play_operators().len(), blob_terms.plays.len());
    let mut buf = vec![0u8; blob::MAX_BLOB_LEN];
    let n = blob::encode(&model, &mut buf).unwrap();
    assert_eq!(blob::decode(&buf[..n]).unwrap(), model);
    let ops = &blob_terms.play;
    assert!(!ops.is_empty() && ops.len() <= 16);
    assert!(ops
        .windows(2)
        .all(|w| w[0].threshold_um < w[1].threshold_um));
    assert!(ops.iter().all(|o| o.threshold_um >= 0.0 && o.axis == 0));
    assert!(
        ops.iter().all(|o| o.weight > 0.0),
        "counter-clockwise: {ops:?}"
    );
    // the bank's output on the recorded command vs the hidden one
    let bank = |rs: &[f64], ws: &[f64]| -> Vec<f64> {
        let mut out = vec![0.0; cmd.len()];
        for (r, w) in rs.iter().zip(ws) {
            let mut state = cmd[0];
            for (o, &x) in out.iter_mut().zip(&cmd) {
                state = nanocal::model::play::play(state, x, *r);
                *o += w * (state - x);
            }
        }
        out
    };
    let found = bank(
        &ops.iter().map(|o| o.threshold_um).collect::<Vec<_>>(),
        &ops.iter().map(|o| o.weight).collect::<Vec<_>>(),
    );
    let hidden = bank(&[1.0, 4.0, 9.0], &[0.02, 0.015, 0.01]);
    // the two banks may differ by what the baseline's cubic in position carries (an operator
    // that never reverses is a line in x): compare what is left beyond it
    let lo = cmd.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = cmd.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let u: Vec<f64> = cmd
        .iter()
        .map(|x| (2.0 * x - lo - hi) / (hi - lo))
        .collect();
    let poly: Vec<Vec<f64>> = (1..=3)
        .map(|p| u.iter().map(|v| v.powi(p)).collect())
        .collect();
    let refs: Vec<&[f64]> = poly.iter().map(|c| c.as_slice()).collect();
    let d: Vec<f64> = found.iter().zip(&hidden).map(|(a, b)| a - b).collect();
    let diff = nanocal::numerics::linalg::lstsq(&refs, &d, true)
        .unwrap()
        .residuals;
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
    assert!(
        rms(&diff) < 0.15 * rms(&hidden),
        "bank differs by {} of {} µm RMS",
        rms(&diff),
        rms(&hidden)
    );
}
