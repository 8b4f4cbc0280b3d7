//! Paper 001's robot model through the QEMU firmware: the delta robot's stepwise model (three
//! motor outputs, ten temperatures — 7 on the structure, 3 in the air) is fitted on the twin,
//! uploaded, and every validation pose sent as one `MOV 1 … 2 … 3 …`: the forwarded commands must
//! equal the host's f64 evaluation at the same (f32) targets within 0.1 nm plus the f32 rounding
//! of the command itself (half an ULP: 0.24 nm for 4–8 mm, 0.49 nm for 8–16 mm of travel).
//!
//! Ignored until the firmware supplies ten temperature channels: today the device configures
//! eight amplifiers (`nanocal_compensator::settings::SENSORS`) and refuses, at upload, a model
//! that reads temperature 8 (`inputs::check`: "no amplifier is configured on chip-select 8").
//! Run it with `cargo test --test e2e_robot_qemu -- --ignored`.

mod fw_sim;

use fw_sim::{Qemu, SensorSim, StageSim};
use nanocal::design::DesignSpec;
use nanocal::fit::{fit_dwells, FitOptions, Selection};
use nanocal::plan::Plan;
use nanocal::procedure::ProcedureData;
use nanocal::stepwise::StepwiseOptions;
use nanocal::twin::delta::{DeltaConfig, DeltaTwin};
use nanocal::twin::execute::run_plan;
use nanocal_compensator::mgmt::flags;
use nanocal_compensator::sensor::Chip;
use nanocal_model::{blob, SlowInputs, MAX_AXES};
use std::time::{Duration, Instant};

#[test]
#[ignore = "the firmware supplies 8 temperature channels; the robot model reads 10"]
fn e2e_robot_model_under_qemu() {
    // the model: stepwise on a shortened run of paper 001's plan on the twin
    let plan = Plan::paper001_robot().shortened(12, 1, 1);
    let twin = DeltaTwin::new(DeltaConfig::paper001(1), 86_400.0, 1);
    let run = run_plan(&twin, &plan, 8.0 * 3600.0, 1, false);
    let d = ProcedureData::new(&run.recording.to_recording().unwrap(), &run.steps, 0.0).unwrap();
    let train = d.training();
    let fit = fit_dwells(
        &train,
        &FitOptions {
            spec: DesignSpec::parse(nanocal::cli::demo::ROBOT_CANDIDATES).unwrap(),
            selection: Selection::Stepwise(StepwiseOptions::default()),
            ..Default::default()
        },
    )
    .unwrap();
    let model = fit.model;
    assert_eq!(model.temps(), 10);
    // the sensors report each channel's training mean, exact in MAX31856 LSBs (1/128 °C)
    let temps: Vec<f32> = train
        .channels
        .iter()
        .filter(|c| c.0.starts_with("temp_"))
        .map(|c| {
            let m = c.1.iter().sum::<f64>() / c.1.len() as f64;
            ((m * 128.0).round() / 128.0) as f32
        })
        .collect();
    let mut slow = SlowInputs::default();
    for (i, t) in temps.iter().enumerate() {
        slow.temps_c[i] = f64::from(*t);
    }

    let Some(mut q) = Qemu::start_or_skip("e2e_robot_model_under_qemu") else {
        return;
    };
    let stage = StageSim::start(q.connect(1), 3);
    let _sensors = SensorSim::start(q.connect(2), &temps);
    let mut host = q.gcs_host();
    let mut c = q.client();
    // a type K amplifier on each of the model's ten chip-selects, as `nanocal device config` sets
    let mut settings = c.config().unwrap();
    for slot in settings.sensors.iter_mut().take(temps.len()) {
        *slot = Some(Chip::K);
    }
    c.set_config(&settings).unwrap();
    let mut b = vec![0u8; blob::MAX_BLOB_LEN];
    let n = blob::encode(&model, &mut b).unwrap();
    c.upload(&b[..n]).expect("the robot model is accepted");
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let s = c.status().unwrap();
        if s.flags & flags::MODEL != 0 && s.flags & flags::SENSOR_BLOCK == 0 && s.folds >= 2 {
            break;
        }
        assert!(Instant::now() < deadline, "sensors never ready: {s:?}");
        std::thread::sleep(Duration::from_millis(50));
    }
    for pose in &plan.validation.test.cycle_um {
        host.send(&format!("MOV 1 {} 2 {} 3 {}", pose[0], pose[1], pose[2]));
        let line = stage.next_line(Duration::from_secs(10));
        let x: [f64; MAX_AXES] = std::array::from_fn(|a| f64::from(pose[a] as f32));
        let want = model.eval_f64(&x, &[0; MAX_AXES], &slow);
        let t: Vec<&str> = line.split_whitespace().collect();
        for (a, axis) in ["1", "2", "3"].iter().enumerate() {
            let i = t.iter().position(|v| v == axis).expect("axis forwarded");
            let got: f64 = t[i + 1].parse().unwrap();
            let q32 = want[a] as f32;
            let half_ulp = 0.5 * (f64::from(q32.next_up()) - f64::from(q32));
            assert!(
                (got - want[a]).abs() <= half_ulp + 1e-4,
                "motor {axis} at {pose:?}: forwarded {got}, f64 {} (Δ = {} nm)",
                want[a],
                (got - want[a]) * 1e3
            );
        }
    }
}
