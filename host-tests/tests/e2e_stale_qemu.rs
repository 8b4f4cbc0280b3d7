//! The model-stale check through the QEMU firmware (issue 19, item 1): a KMZ re-measurement
//! inside `k` standard errors of prediction leaves the model in service; one outside raises
//! `MODEL_STALE` (status, LED, `nanocal device status`) while moves are still corrected; the
//! numbers the device reports are the host's own evaluation of the same check; temperatures
//! beyond the training envelope by more than the settings' margin raise it too, and a wider
//! margin (`nanocal device config --extrapolation-c`) does not; a new model starts afresh.
//!
//! Without qemu-system-arm the test is skipped with a loud message, except in CI.

mod fw_sim;

use fw_sim::{in_service, nanocal_cli, upload_with_cli};

use fw_sim::{stage_value, wait_until, Qemu, SensorSim, StageSim, HANG};
use nanocal::papers::published::published_1dof;
use nanocal_compensator::stale::KmzCheck;
use nanocal_interface::led::LedState;
use nanocal_interface::status::{Flags, StaleReasons};
use nanocal_model::{AxisBound, Model, SlowInputs, MAX_AXES};

/// Temperatures inside the published model's envelope (21–23 °C), exact on the MAX31856's
/// 1/128 °C grid.
const TEMPS_C: [f32; 4] = [22.0, 22.125, 21.875, 22.25];

fn slow(temps: &[f32; 4]) -> SlowInputs {
    let mut s = SlowInputs::default();
    for (i, t) in temps.iter().enumerate() {
        s.temps_c[i] = f64::from(*t);
    }
    s
}

/// The published 1-DoF model with a prediction bound on its seven terms: s = 20 nm, t = 2,
/// an orthonormal design (R = I, regressors centred at 0, scale 1: h = 1 + ‖u‖²).
fn bounded_model(id: u32) -> Model {
    let mut m = nanocal_model::ModelBuilder::from_model(&published_1dof().unwrap())
        .id(id)
        .build()
        .unwrap();
    let p = m.axis_terms(0);
    let mut r = vec![0.0f32; nanocal_model::bound::packed_len(p)];
    let mut at = 0;
    for i in 0..=p {
        r[at] = 1.0;
        at += p + 1 - i;
    }
    let b = AxisBound::new(0.020, 2.0, &vec![0.0; p], &vec![1.0; p], &r).unwrap();
    m.set_bound(0, Some(b)).unwrap();
    m
}

#[test]
fn a_kmz_outside_the_prediction_interval_raises_model_stale_under_qemu() {
    let Some(mut q) =
        Qemu::start_or_skip("a_kmz_outside_the_prediction_interval_raises_model_stale")
    else {
        return;
    };
    let clk = q.clock();
    let stage = StageSim::start(q.connect(1), 1);
    let sensors = SensorSim::start(q.link(), &TEMPS_C);
    let mut host = q.gcs_host();
    drop(q.client()); // the board is up and answering
    let mut model = bounded_model(0x0019_0001);
    let k = nanocal_interface::settings::DEFAULT_STALE_K;
    upload_with_cli(&q, &model, "stale-a");
    let s = in_service(&mut q, model.id());
    assert!(!s.flags.contains(Flags::MODEL_STALE), "{s:?}");
    assert!(s.stale.is_empty() && s.stale_since_ms == 0);
    assert_eq!(s.led, LedState::Compensating);
    // the largest temperature is 22.25 °C, 0.75 °C inside the envelope's top
    assert_eq!(s.envelope_excess_c, -0.75);
    assert!(s.kmz_residual_um[0].is_nan(), "no KMZ yet");

    // a KMZ at 250 µm whose measurement the model misses by half its limit: in service
    let t = slow(&TEMPS_C);
    let x = [250.0, 0.0, 0.0];
    let host_check = |m: &Model, err_um: f64| {
        let mut q_cmd = m.eval_f64(&x, &[0; MAX_AXES], &t);
        q_cmd[0] += err_um;
        (q_cmd, KmzCheck::of(m, &q_cmd, &x, &t, k))
    };
    let limit_um = f64::from(host_check(&model, 0.0).1.limit_um[0]);
    assert!(limit_um > 0.06 && limit_um < 0.2, "{limit_um}");
    let mut c = q.client();
    let (q_cmd, want) = host_check(&model, 0.5 * limit_um);
    let kmz = c.set_kmz(q_cmd, x).unwrap();
    model.set_kmz_offset_um(0, kmz[0]);
    let s = c.status().unwrap();
    assert!(!s.flags.contains(Flags::MODEL_STALE), "{s:?}");
    // the device's numbers are the host's evaluation of the same check (f32 on both sides)
    assert!(
        (s.kmz_residual_um[0] - want.residual_um[0]).abs() < 1e-5,
        "{s:?}"
    );
    assert!((s.kmz_limit_um[0] - want.limit_um[0]).abs() < 1e-6, "{s:?}");

    // one that the model misses by twice its limit: stale, and still compensating
    let (q_cmd, want) = host_check(&model, -2.0 * limit_um);
    let before_ms = c.status().unwrap().uptime_ms;
    let kmz = c.set_kmz(q_cmd, x).unwrap();
    model.set_kmz_offset_um(0, kmz[0]);
    let s = c.status().unwrap();
    assert!(s.flags.contains(Flags::MODEL_STALE), "{s:?}");
    assert_eq!(s.stale, StaleReasons::KMZ_OUTSIDE_INTERVAL);
    assert!(s.stale_since_ms >= before_ms && s.stale_since_ms <= s.uptime_ms);
    assert!((s.kmz_residual_um[0] - want.residual_um[0]).abs() < 1e-5);
    assert_eq!(s.led, LedState::Stale);
    host.send("MOV 1 100");
    let fwd = stage.drain_until(|l| l.starts_with("MOV "), HANG);
    let got = stage_value(fwd.last().unwrap(), "1");
    let want_q = model.eval_f64(&[100.0, 0.0, 0.0], &[0; MAX_AXES], &t)[0];
    assert!(
        (got - want_q).abs() <= 1e-4,
        "a stale model still corrects: {got} vs {want_q}"
    );
    drop(c);
    let text = nanocal_cli(&["device", "status", "--port", &q.cli_spec()]);
    assert!(
        text.contains("MODEL STALE since uptime")
            && text.contains("a KMZ re-measurement fell outside the prediction interval"),
        "{text}"
    );
    assert!(text.contains("limit ±"), "{text}");

    // a new model starts afresh
    let warm = bounded_model(0x0019_0002);
    upload_with_cli(&q, &warm, "stale-b");
    let s = in_service(&mut q, warm.id());
    assert!(!s.flags.contains(Flags::MODEL_STALE), "{s:?}");

    // the room leaves the envelope by 0.3 °C (> the default 0.1 °C margin): stale once folded
    sensors.set_temp(3, 23.296875);
    let mut c = q.client();
    let s = wait_until("stale beyond the envelope", &clk, 30.0, || {
        let s = c.status().ok()?;
        s.flags.contains(Flags::MODEL_STALE).then_some(s)
    });
    assert_eq!(s.stale, StaleReasons::BEYOND_ENVELOPE);
    assert!((s.envelope_excess_c - 0.296875).abs() < 1e-6, "{s:?}");
    assert!(s.flags.contains(Flags::EXTRAPOLATING));
    drop(c);

    // a model shown to extrapolate 0.5 °C: the same room leaves it in service
    let cfg = nanocal_cli(&[
        "device",
        "config",
        "--port",
        &q.cli_spec(),
        "--extrapolation-c",
        "0.5",
    ]);
    assert!(cfg.contains("extrapolation margin 0.5 °C"), "{cfg}");
    let again = bounded_model(0x0019_0003);
    upload_with_cli(&q, &again, "stale-c");
    let s = in_service(&mut q, again.id());
    let folds = s.folds;
    let mut c = q.client();
    let s = wait_until("three more folds", &clk, 30.0, || {
        let s = c.status().ok()?;
        (s.folds >= folds + 3).then_some(s)
    });
    assert!(s.envelope_excess_c > 0.29, "{s:?}");
    assert!(!s.flags.contains(Flags::MODEL_STALE), "{s:?}");
}
