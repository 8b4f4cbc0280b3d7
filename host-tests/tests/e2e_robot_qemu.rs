//! Paper 001's robot model through the QEMU firmware: the delta robot's stepwise model (three
//! motor outputs, ten temperatures — 7 on the structure, 3 in the air) is fitted on the twin,
//! uploaded, and every validation pose sent as one `MOV 1 … 2 … 3 …`: the forwarded commands must
//! equal the host's f64 evaluation at the exact targets within 0.1 nm (issue 11). The device
//! evaluates δ = q − x in f32 and forms the command as x + δ in integer micros
//! (`proxy/moves.rs`): an f32 command would round by up to half an ULP, 0.24 nm on 4–8 mm.

mod fw_sim;

use fw_sim::{next_move, wait_until, Config, Qemu, SensorSim, StageSim};
use nanocal::data::plan::Plan;
use nanocal::fit::design::DesignSpec;
use nanocal::fit::{fit_dwells, FitOptions, Selection};
use nanocal::numerics::stepwise::StepwiseOptions;
use nanocal::twin::delta::{DeltaConfig, DeltaTwin};
use nanocal::twin::execute::run_plan;
use nanocal::validate::procedure::ProcedureData;
use nanocal_compensator::sensor::Chip;
use nanocal_interface::status::Flags;
use nanocal_model::reference::{delta_robot_78, ROBOT_HALF_STROKE_UM, ROBOT_TEMPS};
use nanocal_model::{blob, Model, SlowInputs, MAX_AXES};

#[test]
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
    let poses: Vec<[f64; MAX_AXES]> = plan
        .validation
        .test
        .cycle_um
        .iter()
        .map(|p| std::array::from_fn(|a| p[a]))
        .collect();
    let Some(worst_nm) = run_under_qemu("e2e_robot_model_under_qemu", &model, &temps, &poses)
    else {
        return;
    };
    println!(
        "robot model ({} terms) under QEMU: {} poses, worst |device − f64| = {worst_nm:.4} nm",
        model.terms().len(),
        poses.len()
    );
}

/// `delta_robot_78` (paper 001's size: 78 terms, 10 temperatures, ±5 mm) through the firmware
/// at poses all over its workspace, with six fraction digits (the proxy parses them exactly;
/// the fast path sees them rounded to f32, which moves δ by far less than 0.001 nm).
#[test]
fn e2e_reference_robot_78_under_qemu() {
    let model = delta_robot_78().unwrap();
    assert_eq!(model.terms().len(), 78);
    let temps: Vec<f32> = (0..ROBOT_TEMPS).map(|i| 21.0 + 0.25 * i as f32).collect();
    let mut seed = 0x1234_5678u64;
    let mut next = || {
        seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    let poses: Vec<[f64; MAX_AXES]> = (0..60)
        .map(|_| std::array::from_fn(|_| (next() * ROBOT_HALF_STROKE_UM * 1e6).round() / 1e6))
        .collect();
    let Some(worst_nm) =
        run_under_qemu("e2e_reference_robot_78_under_qemu", &model, &temps, &poses)
    else {
        return;
    };
    println!(
        "delta_robot_78 under QEMU: {} poses over ±5 mm, worst |device − f64| = {worst_nm:.4} nm",
        poses.len()
    );
}

/// Upload `model` to the QEMU firmware with a type K amplifier per temperature reading
/// `temps`, send every pose as one `MOV 1 … 2 … 3 …`, and check each forwarded command against
/// the host's f64 evaluation at the exact pose within 0.1 nm. Returns the worst error, nm
/// (`None`: QEMU absent, test skipped).
fn run_under_qemu(
    test: &str,
    model: &Model,
    temps: &[f32],
    poses: &[[f64; MAX_AXES]],
) -> Option<f64> {
    let mut slow = SlowInputs::default();
    for (i, t) in temps.iter().enumerate() {
        slow.temps_c[i] = f64::from(*t);
    }
    let mut q = Qemu::start_or_skip(test)?;
    let clk = q.clock();
    // a controller whose travel covers the robot's motor strokes (the compensator reads
    // TMN?/TMX? and refuses commands outside them)
    let mut cfg = Config::e727(3).ready();
    for a in &mut cfg.axes {
        a.velocity = 1e12;
        a.min = -100_000.0;
        a.max = 100_000.0;
    }
    let stage = StageSim::serve(q.connect(1), cfg);
    let _sensors = SensorSim::start(q.link(), temps);
    let mut host = q.gcs_host();
    let mut c = q.client();
    // a type K amplifier on each of the model's chip-selects, as `nanocal device config` sets
    let mut settings = c.config().unwrap();
    for slot in settings.sensors.iter_mut().take(temps.len()) {
        *slot = Some(Chip::K);
    }
    c.set_config(&settings).unwrap();
    let mut b = vec![0u8; blob::MAX_BLOB_LEN];
    let n = blob::encode(model, &mut b).unwrap();
    c.upload(&b[..n]).expect("the robot model is accepted");
    wait_until("sensors ready", &clk, 30.0, || {
        let s = c.status().ok()?;
        (s.flags.contains(Flags::MODEL) && !s.flags.contains(Flags::SENSOR_BLOCK) && s.folds >= 2)
            .then_some(())
    });
    let mut worst_nm = 0.0f64;
    for x in poses {
        host.send(&format!("MOV 1 {} 2 {} 3 {}", x[0], x[1], x[2]));
        let line = next_move(&stage);
        let want = model.eval_f64(x, &[0; MAX_AXES], &slow);
        let t: Vec<&str> = line.split_whitespace().collect();
        for (a, axis) in ["1", "2", "3"].iter().enumerate() {
            let i = t.iter().position(|v| v == axis).expect("axis forwarded");
            let got: f64 = t[i + 1].parse().unwrap();
            let err_nm = (got - want[a]).abs() * 1e3;
            worst_nm = worst_nm.max(err_nm);
            assert!(
                err_nm <= 0.1,
                "motor {axis} at {x:?}: forwarded {got}, f64 {} (Δ = {err_nm} nm)",
                want[a],
            );
        }
    }
    Some(worst_nm)
}
