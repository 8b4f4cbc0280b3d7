//! Blob v2 on the device, end to end through the QEMU firmware (issue 11, real-time inputs):
//!
//! - a model with a play-operator bank: the device keeps the operators' memory from command to
//!   command, so a walk with reversals forwards what the host's f64 reference
//!   (`Model::eval_f64_with_state`) gives for the same sequence of targets, within
//!   [`WALK_TOLERANCE_UM`] — and the same target approached from either side gets different
//!   commands;
//! - a model with a fast force input (an ADC channel, sampled by the firmware every 10 ms): each
//!   command is corrected with the force at the time, and a move is refused with GCS error 9002
//!   (nothing reaches the controller) while that input has no fresh sample.

mod device_models;
mod fw_sim;

use device_models::{force_model, hysteresis_model, slow, TEMP_C, WALK_UM};
use fw_sim::{
    next_move, pass_board_time, stage_value, wait_until, BenchClock, Qemu, SensorSim, StageSim,
    HANG,
};
use nanocal_interface::settings::AuxSource;
use nanocal_interface::status::Flags;
use nanocal_model::{blob, HysteresisState, Model, MAX_AXES};

/// The device's f32 fast path (δ in f32, command x + δ in integer micros) against the f64
/// reference along a hysteresis walk on a 480 µm stroke: 0.1 nm, the bound issue 11 sets for
/// the fast path (the f32 rounding of δ and of the operators' outputs is ~ 0.03 nm here).
const WALK_TOLERANCE_UM: f64 = 1e-4;

fn upload(c: &mut nanocal::device::Client, clk: &BenchClock, model: &Model) {
    let mut b = vec![0u8; blob::MAX_BLOB_LEN];
    let n = blob::encode(model, &mut b).unwrap();
    c.upload(&b[..n]).expect("model accepted");
    wait_until("sensors read and model folded", clk, 20.0, || {
        let s = c.status().ok()?;
        (s.flags.contains(Flags::MODEL) && !s.flags.contains(Flags::SENSOR_BLOCK) && s.folds >= 2)
            .then_some(())
    });
}

#[test]
fn e2e_hysteresis_walk_matches_the_f64_reference() {
    let Some(mut q) = Qemu::start_or_skip("e2e_hysteresis_walk_matches_the_f64_reference") else {
        return;
    };
    let clk = q.clock();
    let stage = StageSim::start(q.connect(1), 1);
    let _sensors = SensorSim::start(q.link(), &[TEMP_C]);
    let mut host = q.gcs_host();
    let mut c = q.client();
    let model = hysteresis_model();
    assert_eq!(model.play_operators().len(), 3);
    upload(&mut c, &clk, &model);

    let walk = WALK_UM;
    let mut reference = HysteresisState::<f64>::new();
    let mut prev: Option<f64> = None;
    let mut worst_um = 0.0f64;
    let mut at_240 = Vec::new();
    for &x in &walk {
        host.send(&format!("MOV 1 {x}"));
        let got = stage_value(&next_move(&stage), "1");
        let dir = match prev {
            Some(p) if x > p => 1,
            Some(p) if x < p => -1,
            _ => 0,
        };
        let want =
            model.eval_f64_with_state(&[x, 0.0, 0.0], &[dir, 0, 0], &slow(), &mut reference)[0];
        let err = (got - want).abs();
        worst_um = worst_um.max(err);
        assert!(
            err <= WALK_TOLERANCE_UM,
            "walk at {x} µm: device forwards {got}, f64 with state {want} (Δ = {} nm)",
            err * 1e3
        );
        if x == 240.0 {
            at_240.push(got);
        }
        prev = Some(x);
    }
    assert_eq!(host.ask("ERR?"), "0");
    // the memory is used: 240 µm approached from above and from below are commanded apart by
    // the loop's width (the operators' outputs differ by up to 2 × threshold)
    let spread = at_240.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
        - at_240.iter().cloned().fold(f64::INFINITY, f64::min);
    assert!(
        spread > 0.5,
        "240 µm commanded {at_240:?}: hysteresis memory not applied"
    );
    println!(
        "hysteresis walk under QEMU: {} moves, worst |device − f64| = {:.4} nm, 240 µm commanded over a {:.3} µm spread",
        walk.len(),
        worst_um * 1e3,
        spread
    );
}

#[test]
fn e2e_fast_force_input_is_used_per_command_and_its_loss_refuses_moves() {
    let Some(mut q) = Qemu::start_or_skip("e2e_fast_force_input_is_used_per_command") else {
        return;
    };
    let clk = q.clock();
    let stage = StageSim::start(q.connect(1), 1);
    let sensors = SensorSim::start(q.link(), &[TEMP_C]);
    let mut host = q.gcs_host();
    let mut c = q.client();
    // a force sensor on ADC channel 0: 1 mN per count, 0 N at mid-scale
    const SCALE_N_PER_COUNT: f32 = 0.001;
    const OFFSET_N: f32 = -2.048;
    let mut settings = c.config().unwrap();
    settings.aux[0] = AuxSource::Force {
        channel: 0,
        scale_n_per_count: SCALE_N_PER_COUNT,
        offset_n: OFFSET_N,
    };
    c.set_config(&settings).unwrap();
    let model = force_model();
    upload(&mut c, &clk, &model);

    // the force as the firmware computes it from a code (f32), and the f64 reference with it
    let force_n = |code: u16| OFFSET_N + SCALE_N_PER_COUNT * f32::from(code);
    let set_code = |code: Option<u16>| {
        sensors.buses().adc[0] = code;
        // several sampling periods (10 ms) of the firmware's fast sampler, in the board's time
        pass_board_time(&clk, 0.1);
    };
    let check = |x: f64, code: u16, got: f64| {
        let mut s = slow();
        s.aux[0] = f64::from(force_n(code));
        let want = model.eval_f64(&[x, 0.0, 0.0], &[0; MAX_AXES], &s)[0];
        assert!(
            (got - want).abs() <= 1e-4,
            "x = {x} µm at code {code}: forwarded {got}, f64 {want} (Δ = {} nm)",
            (got - want) * 1e3
        );
        got
    };

    let mut commanded = Vec::new();
    for code in [2048u16, 3548, 848] {
        set_code(Some(code));
        host.send("MOV 1 50");
        commanded.push(check(50.0, code, stage_value(&next_move(&stage), "1")));
    }
    assert_eq!(host.ask("ERR?"), "0");
    assert_eq!(
        stage.drain(),
        ["ERR?"],
        "no error answered by the controller"
    );
    // +1.5 N and −1.2 N against 0 N: (0.6 + 0.004 · 50) µm/N
    assert!(
        (commanded[1] - commanded[0] - 1.5 * 0.8).abs() < 1e-3,
        "{commanded:?}"
    );
    assert!(
        (commanded[2] - commanded[0] + 1.2 * 0.8).abs() < 1e-3,
        "{commanded:?}"
    );

    // the force sensor stops answering: once the last good sample is older than the freshness
    // limit (5 sampling periods + one 300 ms bus timeout, `src/app/sensors.rs`), a move is
    // refused with a sensor fault and nothing moves. A second of the board's time is well past
    // it (the board's, not the wall's: the emulated clock runs behind under load).
    set_code(None);
    pass_board_time(&clk, 1.0);
    host.send("MOV 1 60");
    assert_eq!(
        host.ask("ERR?"),
        "9002",
        "MOV 1 60 a second after the force input's last sample"
    );
    host.send("VEL 1 5");
    assert_eq!(
        stage.next_line(HANG),
        "VEL 1 5",
        "MOV 1 60 was not forwarded"
    );
    // back: moves go out again, with the force of now
    set_code(Some(2548));
    wait_until("inputs usable again", &clk, 20.0, || {
        let s = c.status().ok()?;
        (!s.flags.contains(Flags::SENSOR_BLOCK)).then_some(())
    });
    let mut errors = Vec::new();
    wait_until("moves taken again", &clk, 10.0, || {
        host.send("MOV 1 60");
        let e = host.ask("ERR?");
        errors.push(e.clone());
        (e == "0").then_some(())
    });
    assert!(
        errors[..errors.len() - 1].iter().all(|e| e == "9002"),
        "refused only for the sensor: {errors:?}"
    );
    let seen = stage.drain();
    assert!(seen[0].starts_with("MOV"), "{seen:?}");
    check(60.0, 2548, stage_value(&seen[0], "1"));
}
