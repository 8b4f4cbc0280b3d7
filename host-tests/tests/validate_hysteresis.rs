//! Validation mirrors the device's hysteresis memory (`nanocal::validate`): a recording whose
//! commands are what the firmware's GCS proxy forwarded for a walk of targets, on a stage that
//! follows the model exactly (measured = target), validates to zero error — static and with a
//! KMZ re-measurement in the middle of the walk — only because the validation steps the play
//! operators with the targets that went out, as the proxy does. A fresh memory per visit (what
//! the validation did before) is off by the loop's width.

mod device_models;
mod proxy_rig;

use device_models::{hysteresis_model, TEMP_C, WALK_UM};
use nanocal::data::dwell::Dwells;
use nanocal::device::device_path::SensorStream;
use nanocal::validate::{validate, Compensation, ValidationData, ValidationOptions};
use nanocal_compensator::proxy::FoldCorrector;
use nanocal_model::{FastInputs, HysteresisState};
use proxy_rig::{everything, Rig};

/// The inverse stops at the f32 rounding of the residual (a few ulps of 480 µm).
const TOLERANCE_UM: f64 = 2e-4;

/// The walk through the proxy: (target, direction, forwarded command) per move.
fn walk_through_the_proxy() -> Vec<(f64, i8, f64)> {
    let model = hysteresis_model();
    let mut rig = Rig::new(everything(1), Some(&model), &[f64::from(TEMP_C)]);
    let mut prev: Option<f64> = None;
    WALK_UM
        .iter()
        .map(|&x| {
            rig.line(&format!("MOV 1 {x}"));
            let q = rig
                .received()
                .iter()
                .rev()
                .find(|l| l.starts_with("MOV"))
                .map(|l| l.split_whitespace().nth(2).unwrap().parse().unwrap())
                .expect("MOV forwarded");
            let dir = match prev {
                Some(p) if x > p => 1,
                Some(p) if x < p => -1,
                _ => 0,
            };
            prev = Some(x);
            (x, dir, q)
        })
        .collect()
}

fn data(walk: &[(f64, i8, f64)]) -> ValidationData {
    let n = walk.len();
    let dwells = Dwells {
        axes: vec!["1".into()],
        t_start_s: (0..n).map(|i| 10.0 * i as f64).collect(),
        t_end_s: (0..n).map(|i| 10.0 * i as f64 + 5.0).collect(),
        cmd_um: vec![walk.iter().map(|w| w.2).collect()],
        meas_um: vec![walk.iter().map(|w| w.0).collect()],
        meas_sd_um: vec![vec![0.0; n]],
        dir: vec![walk.iter().map(|w| w.1).collect()],
        channels: vec![("temp_0".into(), vec![f64::from(TEMP_C); n])],
        rows_averaged: vec![1; n],
    };
    let sensors = SensorStream::from_dwells(&dwells);
    ValidationData {
        dwells,
        sensors,
        // the poses asked for (the commands are the device's corrections of them)
        poses_um: Some(vec![walk.iter().map(|w| w.0).collect()]),
    }
}

#[test]
fn validation_steps_the_hysteresis_memory_like_the_device() {
    let model = hysteresis_model();
    let walk = walk_through_the_proxy();
    let data = data(&walk);
    let opts = ValidationOptions {
        cycles_per_test: 100,
        ..Default::default()
    };
    let report = validate(Some(&model), &data, &Compensation::Static, &opts).unwrap();
    assert_eq!(report.visits.len(), walk.len());
    assert_eq!(report.inverse_failures, 0);
    for (v, w) in report.visits.iter().zip(&walk) {
        assert!(
            v.error_um[0].abs() <= TOLERANCE_UM,
            "visit of {} µm: error {} nm",
            w.0,
            v.error_um[0] * 1e3
        );
    }

    // a KMZ re-measurement at the 6th move's command (a primed memory): λ_KMZ stays where it
    // is, and so do the errors
    let adaptive = Compensation::Adaptive {
        reference_um: vec![walk[5].2],
        interval_s: 1e9,
    };
    let report = validate(Some(&model), &data, &adaptive, &opts).unwrap();
    assert_eq!(report.kmz_updates, 1);
    // the reference visit counts too, its drift cancelled (paper 000 Eq. 18)
    let counted: Vec<_> = report.visits.iter().filter(|v| v.counted()).collect();
    assert_eq!(counted.len(), walk.len());
    for v in counted {
        assert!(
            v.error_um[0].abs() <= TOLERANCE_UM,
            "adaptive, move at {} s: error {} nm",
            v.t_move_s,
            v.error_um[0] * 1e3
        );
    }

    // the memory matters: inverting each command from a fresh memory misses targets by up to
    // the loop's half width
    let fold = FoldCorrector::new(&model, &device_models::slow()).fold;
    let fresh_worst = walk
        .iter()
        .map(|&(x, dir, q)| {
            let xh = fold
                .inverse(
                    &[q as f32, 0.0, 0.0],
                    &[dir, 0, 0],
                    &FastInputs::NONE,
                    &HysteresisState::new(),
                )
                .unwrap();
            (f64::from(xh[0]) - x).abs()
        })
        .fold(0.0, f64::max);
    assert!(fresh_worst > 0.5, "fresh memory misses by {fresh_worst} µm");
}
