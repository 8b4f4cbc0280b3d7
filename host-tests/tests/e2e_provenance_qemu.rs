//! The provenance check through the QEMU firmware (issue 19): a model whose blob records the
//! stage it was fitted on (its controller's `*IDN?` serial) is not applied to another stage.
//! The simulated controller reports another serial → moves refused with GCS error 9015, the
//! status says `STAGE_MISMATCH` with both serials (and `nanocal device status` in words), the
//! LED shows a fault; `nanocal device config --allow-other-stage on` → moves corrected, the
//! mismatch still reported; a model fitted on the controller's own serial → moves corrected,
//! no mismatch.
//!
//! Without qemu-system-arm the test is skipped with a loud message, except in CI.

mod fw_sim;

use fw_sim::{
    in_service, nanocal_cli, stage_value, upload_with_cli, Config, Qemu, SensorSim, StageSim, HANG,
};
use nanocal::papers::published::published_1dof;
use nanocal_interface::led::LedState;
use nanocal_interface::status::{Flags, StageCheck};
use nanocal_interface::GcsErrorCode;
use nanocal_model::provenance::{serial_of_idn, ProvenanceUnit};
use nanocal_model::{Model, Provenance, SlowInputs, StageSerial, MAX_AXES};

/// Temperatures inside the published model's envelope, exact on the MAX31856's grid.
const TEMPS_C: [f32; 4] = [22.0, 22.125, 21.875, 22.25];

/// The stage the model was fitted on, as PI's E-727 manual prints its `*IDN?` reply.
const FITTED_IDN: &str =
    "(c)2015 Physik Instrumente (PI) GmbH & Co. KG, E-727, 0116044408, 13.21.00.09";
/// Another stage's controller.
const OTHER_SERIAL: &str = "0116044999";

fn slow() -> SlowInputs {
    let mut s = SlowInputs::default();
    for (i, t) in TEMPS_C.iter().enumerate() {
        s.temps_c[i] = f64::from(*t);
    }
    s
}

/// The published 1-DoF model, fitted on the stage of [`FITTED_IDN`].
fn fitted_model() -> Model {
    let mut m = nanocal_model::ModelBuilder::from_model(&published_1dof().unwrap())
        .id(0x0019_0401)
        .build()
        .unwrap();
    m.set_provenance(Provenance {
        stage_serial: serial_of_idn(FITTED_IDN.as_bytes()),
        unit: ProvenanceUnit::Um,
        fit_date_s: 1_700_000_000,
        ..Provenance::UNKNOWN
    });
    m
}

fn serial(s: &str) -> Option<StageSerial> {
    StageSerial::new(s.as_bytes())
}

#[test]
fn a_model_is_not_applied_to_another_stage_under_qemu() {
    let Some(mut q) = Qemu::start_or_skip("a_model_is_not_applied_to_another_stage") else {
        return;
    };
    // StageSim::start's E-727 (ideal, instant stage), with another stage's serial
    let mut cfg = Config::e727(1).ready();
    cfg.axes[0].velocity = 1e12;
    cfg.serial = OTHER_SERIAL.into();
    let stage = StageSim::serve(q.connect(1), cfg);
    let _sensors = SensorSim::start(q.link(), &TEMPS_C);
    let mut host = q.gcs_host();
    drop(q.client()); // the board is up and answering
    let model = fitted_model();
    upload_with_cli(&q, &model, "provenance");
    let s = in_service(&mut q, model.id());
    // nothing read of the controller yet: no move has been corrected
    assert_eq!(s.stage, StageCheck::NotRead, "{s:?}");
    assert_eq!(s.model_serial, serial("0116044408"));
    assert!(!s.flags.contains(Flags::STAGE_MISMATCH));

    // another stage: the move is refused, with its own error, and never reaches the stage
    host.send("MOV 1 100");
    assert_eq!(
        host.ask("ERR?"),
        GcsErrorCode::StageMismatch.code().to_string()
    );
    let seen = stage.drain();
    assert!(
        seen.iter().all(|l| !l.starts_with("MOV ")),
        "a move reached another stage: {seen:?}"
    );
    let mut c = q.client();
    let s = c.status().unwrap();
    assert!(s.flags.contains(Flags::STAGE_MISMATCH), "{s:?}");
    assert_eq!(s.stage, StageCheck::Mismatch);
    assert_eq!(s.controller_serial, serial(OTHER_SERIAL));
    assert_eq!(s.model_serial, serial("0116044408"));
    assert_eq!(s.led, LedState::Fault);
    assert_eq!(s.moves, 0);
    drop(c);
    let text = nanocal_cli(&["device", "status", "--port", &q.cli_spec()]);
    assert!(
        text.contains("STAGE MISMATCH")
            && text.contains("moves refused (GCS error 9015")
            && text.contains("model fitted on serial 0116044408, controller reports 0116044999"),
        "{text}"
    );

    // allowed by the setting: corrected, the mismatch still reported
    let cfg = nanocal_cli(&[
        "device",
        "config",
        "--port",
        &q.cli_spec(),
        "--allow-other-stage",
        "on",
    ]);
    assert!(cfg.contains("compensated all the same"), "{cfg}");
    let want_q = |x: f64| model.eval_f64(&[x, 0.0, 0.0], &[0; MAX_AXES], &slow())[0];
    host.send("MOV 1 100");
    let fwd = stage.drain_until(|l| l.starts_with("MOV "), HANG);
    let got = stage_value(fwd.last().unwrap(), "1");
    assert!(
        (got - want_q(100.0)).abs() <= 1e-4,
        "corrected: {got} vs {}",
        want_q(100.0)
    );
    assert_eq!(host.ask("ERR?"), "0");
    let mut c = q.client();
    let s = c.status().unwrap();
    assert!(s.flags.contains(Flags::STAGE_MISMATCH), "{s:?}");
    assert_eq!(s.stage, StageCheck::MismatchAllowed);
    assert_eq!(s.led, LedState::Compensating);
    drop(c);
    let text = nanocal_cli(&["device", "status", "--port", &q.cli_spec()]);
    assert!(
        text.contains("moves corrected all the same (setting allow_other_stage)"),
        "{text}"
    );

    // the setting off again: refused again
    nanocal_cli(&[
        "device",
        "config",
        "--port",
        &q.cli_spec(),
        "--allow-other-stage",
        "off",
    ]);
    host.send("MOV 1 150");
    assert_eq!(
        host.ask("ERR?"),
        GcsErrorCode::StageMismatch.code().to_string()
    );
    assert!(stage.drain().iter().all(|l| !l.starts_with("MOV ")));

    // a model fitted on this controller's stage: moves corrected, no mismatch
    let mut same = fitted_model();
    let mut p = *same.provenance();
    p.stage_serial = serial(OTHER_SERIAL);
    same.set_provenance(p);
    let same = nanocal_model::ModelBuilder::from_model(&same)
        .id(0x0019_0402)
        .build()
        .unwrap();
    upload_with_cli(&q, &same, "provenance");
    in_service(&mut q, same.id());
    host.send("MOV 1 200");
    let fwd = stage.drain_until(|l| l.starts_with("MOV "), HANG);
    let got = stage_value(fwd.last().unwrap(), "1");
    assert!((got - want_q(200.0)).abs() <= 1e-4, "{got}");
    assert_eq!(host.ask("ERR?"), "0");
    let s = q.client().status().unwrap();
    assert_eq!(s.stage, StageCheck::Match, "{s:?}");
    assert!(!s.flags.contains(Flags::STAGE_MISMATCH));
    assert_eq!(s.model_serial, serial(OTHER_SERIAL));
    assert_eq!(s.controller_serial, serial(OTHER_SERIAL));
    assert_eq!(s.led, LedState::Compensating);
    let text = nanocal_cli(&["device", "status", "--port", &q.cli_spec()]);
    assert!(
        text.contains("stage check: the controller is the stage the model was fitted on"),
        "{text}"
    );
}
