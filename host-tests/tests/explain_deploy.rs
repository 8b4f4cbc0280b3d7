//! Deployable effects go into the shared model and its blob with no new code path: their term
//! shapes (and lag filters) build into a `Model`, encode into the blob and decode back; the
//! others say why the compensator cannot run them. Also: an effect explain finds carries its
//! fitted nonlinear parameter (τ) into the lag filters.

mod explain_common;
use explain_common::*;

use nanocal::effects::{candidates, thermal_lag, BlobContext, EffectSpec};
use nanocal::model::{blob, Factor, ModelBuilder};

fn build_with(
    ctx: &BlobContext,
    aux: usize,
    b: &nanocal::effects::BlobTerms,
) -> nanocal::model::Model {
    let mut mb = ModelBuilder::new(ctx.axes as usize, ctx.temps as usize, aux).unwrap();
    let mut first_lag = None;
    for &(sensor, tau) in &b.lags {
        let k = mb.lag(sensor, tau).unwrap();
        first_lag.get_or_insert(k);
    }
    for (i, t) in b.terms.iter().enumerate() {
        let mut t = *t;
        if let Factor::Lagged(k) = t.factor {
            t.factor = Factor::Lagged(k + first_lag.unwrap());
        }
        t.coeff = 1e-3 * (i + 1) as f64;
        mb.add_term(t).unwrap();
    }
    mb.build().unwrap()
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
        let b = c.blob_terms(&ctx, Some(1800.0));
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
fn a_found_lag_carries_its_tau_into_the_lag_filters() {
    let mut cfg = lively_fast_sensors();
    cfg.effects = vec![EffectSpec::ThermalLag(thermal_lag::Params {
        tau_s: 1500.0,
    })];
    let rep = explain_columns(simulate(
        cfg,
        &nanocal::twin::Trajectory::published_training_1dof(60.0, 10),
        51,
    ));
    let e = effect(&rep, "x", "thermal_lag").unwrap_or_else(|| panic!("{}", rep.to_text()));
    let b = e.blob.as_ref().unwrap();
    let tau = param(e, "tau_s");
    assert_eq!(b.lags.len(), 3);
    assert!(b.lags.iter().all(|&(_, t)| t == tau));
    let ctx = BlobContext {
        output: 0,
        axes: 1,
        temps: 3,
        pressure_aux: None,
    };
    let model = build_with(&ctx, 0, b);
    assert_eq!(model.terms().len(), 3);
}
