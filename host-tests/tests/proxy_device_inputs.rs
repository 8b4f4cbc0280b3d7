//! Blob v2 in the GCS proxy, natively (the firmware's `Proxy` in front of the simulated
//! controller, on a hand-driven clock): the hysteresis memory the proxy keeps, stepped only by
//! commands that go out and frozen for replies, against the f64 reference with state; fast
//! inputs per command, and the refusal of a move while one has no fresh sample.

mod device_models;
mod proxy_rig;

use device_models::{force_model, hysteresis_model, slow, TEMP_C, WALK_UM};
use nanocal_model::{FastInputs, HysteresisState, MAX_AXES};
use proxy_rig::{everything, value, Rig};

/// The f32 fast path against the f64 reference: 0.1 nm (issue 11).
const TOLERANCE_UM: f64 = 1e-4;

/// The value of axis 1 in the last `MOV` the controller received since the last call.
fn forwarded(rig: &mut Rig) -> Option<f64> {
    rig.received()
        .iter()
        .rev()
        .find(|l| l.starts_with("MOV"))
        .map(|l| l.split_whitespace().nth(2).unwrap().parse().unwrap())
}

fn direction(prev: Option<f64>, x: f64) -> i8 {
    match prev {
        Some(p) if x > p => 1,
        Some(p) if x < p => -1,
        _ => 0,
    }
}

#[test]
fn the_proxy_keeps_the_hysteresis_memory_of_the_commands_it_sent() {
    let model = hysteresis_model();
    let mut rig = Rig::new(everything(1), Some(&model), &[f64::from(TEMP_C)]);
    let mut reference = HysteresisState::<f64>::new();
    let mut prev = None;
    let mut at_240 = Vec::new();
    for &x in &WALK_UM {
        rig.line(&format!("MOV 1 {x}"));
        let got = forwarded(&mut rig).expect("MOV forwarded");
        let dir = [direction(prev, x), 0, 0];
        let want = model.eval_f64_with_state(&[x, 0.0, 0.0], &dir, &slow(), &mut reference)[0];
        assert!(
            (got - want).abs() <= TOLERANCE_UM,
            "{x} µm: forwarded {got}, f64 with state {want} (Δ = {} nm)",
            (got - want) * 1e3
        );
        // a query between moves maps the reply back with the memory frozen (the stage did not
        // move): the next command still follows the reference
        rig.wait_ms(5_000);
        let back = value(&rig.line("POS? 1"), "1");
        assert!((back - x).abs() <= 2e-4, "POS? at {x} mapped to {back}");
        if x == 240.0 {
            at_240.push(got);
        }
        prev = Some(x);
    }
    assert_eq!(rig.line("ERR?").trim(), "0");
    let spread = at_240.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
        - at_240.iter().cloned().fold(f64::INFINITY, f64::min);
    assert!(spread > 0.5, "240 µm commanded {at_240:?}");
    assert!(rig.proxy.hysteresis().is_primed());

    // a stop: the stage halts where the proxy did not send it, the memory starts afresh and the
    // next command is primed at its target, like a fresh reference
    rig.line("STP");
    rig.settle();
    rig.line("ERR?");
    assert!(!rig.proxy.hysteresis().is_primed(), "STP resets the memory");
    rig.line("MOV 1 200");
    let got = forwarded(&mut rig).expect("MOV forwarded");
    let want = model.eval_f64_with_state(
        &[200.0, 0.0, 0.0],
        &[0; MAX_AXES],
        &slow(),
        &mut HysteresisState::new(),
    )[0];
    assert!((got - want).abs() <= TOLERANCE_UM, "{got} vs {want}");
}

#[test]
fn a_fast_input_is_used_per_command_and_a_stale_one_refuses_the_move() {
    let model = force_model();
    let mut rig = Rig::new(everything(1), Some(&model), &[f64::from(TEMP_C)]);
    for force_n in [0.0f32, 1.5, -1.25] {
        let c = rig.comp.as_mut().unwrap();
        c.fast = FastInputs::NONE.with_aux(0, force_n);
        c.fast_fresh = 0b1;
        rig.line("MOV 1 50");
        let got = forwarded(&mut rig).expect("MOV forwarded");
        let mut s = slow();
        s.aux[0] = f64::from(force_n);
        let want = model.eval_f64(&[50.0, 0.0, 0.0], &[0; MAX_AXES], &s)[0];
        assert!(
            (got - want).abs() <= TOLERANCE_UM,
            "{force_n} N: forwarded {got}, f64 {want}"
        );
    }
    assert_eq!(rig.line("ERR?").trim(), "0");
    rig.received();

    // the sample is stale: refused with a sensor fault, nothing reaches the controller
    rig.comp.as_mut().unwrap().fast_fresh = 0;
    rig.line("MOV 1 60");
    assert_eq!(rig.line("ERR?").trim(), "9002");
    assert!(
        !rig.received().iter().any(|l| l.starts_with("MOV")),
        "a refused move reaches the controller"
    );
    // a force outside its training range: refused as outside the envelope
    let c = rig.comp.as_mut().unwrap();
    c.fast = FastInputs::NONE.with_aux(0, 3.0);
    c.fast_fresh = 0b1;
    rig.line("MOV 1 60");
    assert_eq!(rig.line("ERR?").trim(), "9001");
    assert!(!rig.received().iter().any(|l| l.starts_with("MOV")));
}
