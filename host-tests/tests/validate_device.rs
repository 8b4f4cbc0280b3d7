//! Host validation evaluates exactly what the device evaluates.
//!
//! The published 1-DoF procedure (shortened) runs on the digital twin; the static model is
//! fitted and the validation computes, for every visit, the target `x̂` for which the device
//! would have sent the recorded command. Here, with the fold the device had in force at the time
//! of the move (`DeviceSlowPath`: fold period, f32 readings, lag filters), the compensator's own
//! GCS proxy (`nanocal_compensator::proxy::Proxy`, the firmware's code, in front of the
//! simulated C-867 of `tests/proxy_rig`) takes `MOV <pose>` exactly when the validation says the
//! move is not refused, and forwards for `MOV x̂` the recorded command within 0.1 nm.

mod proxy_rig;

use nanocal::data::plan::{Plan, TestKind};
use nanocal::device::device_path::{DeviceSlowPath, SlowPeriods};
use nanocal::fit::design::DesignSpec;
use nanocal::fit::{fit_dwells, FitOptions, Selection};
use nanocal::twin::examples::{paper000_1dof_twin, TRAINING_START_S};
use nanocal::twin::execute::run_plan;
use nanocal::validate::procedure::ProcedureData;
use nanocal_compensator::proxy::{Corrector, FoldCorrector};
use proxy_rig::{everything, Rig};

/// The value the controller received for axis 1 in the last `MOV` it got, if any.
fn forwarded(rig: &mut Rig) -> Option<f64> {
    rig.received()
        .iter()
        .rev()
        .find(|l| l.starts_with("MOV"))
        .map(|l| {
            let t: Vec<&str> = l.split_whitespace().collect();
            t[2].parse().unwrap()
        })
}

/// The shortened 1-DoF plan on the twin (`seed`, `rounds` of validation) and its static model.
fn fitted(seed: u64, rounds: usize) -> (ProcedureData, nanocal_model::Model) {
    let plan = Plan::paper000_1dof().shortened(4, 2, rounds);
    let run = run_plan(&paper000_1dof_twin(seed), &plan, TRAINING_START_S, 1, true);
    let rec = run.recording.to_recording().unwrap();
    let data = ProcedureData::new(&rec, &run.steps, 0.0).unwrap();
    let fit = fit_dwells(
        &data.training(),
        &FitOptions {
            spec: DesignSpec::published_static(),
            selection: Selection::Fixed,
            ..Default::default()
        },
    )
    .unwrap();
    (data, fit.model)
}

#[test]
fn every_validated_visit_is_what_the_gcs_proxy_forwards() {
    let (data, model) = fitted(4, 2);
    let model = &model;
    let report = data
        .validate(TestKind::Static, Some(model), None, SlowPeriods::DEVICE)
        .unwrap();
    assert_eq!(report.visits.len(), 2 * 2 * 14);
    let mut device = DeviceSlowPath::new(model.lags(), &data.data.sensors, SlowPeriods::DEVICE);
    let mut rig = Rig::new(everything(1), Some(model), &[]);
    let mut refused = 0;
    let mut edge = 0;
    for v in &report.visits {
        // the commanded pose of the visit is what the recording sent to the controller
        let recorded = v.target_um[0];
        let meas = {
            let i = data
                .data
                .dwells
                .t_start_s
                .iter()
                .position(|&t| t == v.t_move_s)
                .unwrap();
            data.data.dwells.meas_um[0][i]
        };
        // the validation's target: error = meas − x̂
        let target = meas - v.error_um[0];
        let slow = device.slow_at(v.t_move_s);
        let corrector = FoldCorrector::new(model, &slow);
        rig.comp = Some(corrector);
        // the user asks for the pose: the proxy takes the move unless the validation says refused
        rig.line(&format!("MOV 1 {recorded}"));
        let taken = forwarded(&mut rig).is_some();
        rig.line("ERR?");
        assert_eq!(taken, !v.refused, "MOV 1 {recorded}");
        if v.refused {
            refused += 1;
            continue;
        }
        // the validated target: the command the device sends for it is the recorded one
        rig.line(&format!("MOV 1 {target:.9}"));
        let q = match forwarded(&mut rig) {
            Some(q) => q,
            // a target a few nm beyond the end of the training envelope (the pose itself is
            // inside): the proxy refuses it, so check the fast path it would have called
            None => {
                rig.line("ERR?");
                edge += 1;
                let dir = [v.dir[0], 0, 0];
                // the static model has no play operators: no hysteresis memory to read
                let none = nanocal_model::HysteresisState::new();
                let c = corrector.correct(&[target as f32, 0.0, 0.0], &dir, &none);
                f64::from(c.q_um[0])
            }
        };
        assert!(
            (q - recorded).abs() <= 1e-4,
            "t = {} s: device sends {q} for target {target}, the recording has {recorded} (Δ = {} nm)",
            v.t_move_s,
            (q - recorded) * 1e3
        );
    }
    assert_eq!(refused, report.refused);
    assert_eq!(
        refused, 0,
        "every validation pose lies in the training envelope"
    );
    assert!(
        edge < report.visits.len() / 4,
        "{edge} targets at the envelope's edge"
    );
}

/// The fold in force is the one of the last tick before the move: with a 5 s fold period the
/// device lags the sensors, and the validation says so (different errors, same visits).
#[test]
fn the_fold_period_changes_what_is_evaluated() {
    let (data, model) = fitted(5, 1);
    let fast = data
        .validate(TestKind::Static, Some(&model), None, 0.25)
        .unwrap();
    let slow = data
        .validate(TestKind::Static, Some(&model), None, 10.0)
        .unwrap();
    assert_eq!(fast.visits.len(), slow.visits.len());
    let differ = fast
        .visits
        .iter()
        .zip(&slow.visits)
        .filter(|(a, b)| (a.error_um[0] - b.error_um[0]).abs() > 1e-6)
        .count();
    assert!(differ > fast.visits.len() / 2, "{differ} visits differ");
}
