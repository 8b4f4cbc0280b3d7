//! The provenance check in the GCS proxy (issue 19): the controller's serial, read from its
//! `*IDN?` before the first corrected move, against the stage serial the model's blob records.
//! Another stage: moves refused with GCS error 9015 unless `allow_other_stage`; the check's
//! state is what the status reports. Run natively against the simulated controller
//! (`proxy_rig`).

mod proxy_rig;

use nanocal::papers::published::published_1dof;
use nanocal::virtual_bench::{Event, DEFAULT_SERIAL};
use nanocal_compensator::proxy::GcsErrorCode;
use nanocal_interface::status::StageCheck;
use nanocal_model::provenance::serial_of_idn;
use nanocal_model::{Model, StageSerial};
use proxy_rig::{everything, Rig};

const TEMPS: [f64; 4] = [22.0, 22.1, 21.9, 22.3];

fn serial(s: &str) -> Option<StageSerial> {
    StageSerial::new(s.as_bytes())
}

/// A rig on a 1-axis controller reporting `controller_serial`, with the published 1-DoF model
/// fitted on `model_serial`.
fn rig(controller_serial: &str, model_serial: Option<&str>, allow: bool) -> (Rig, Model) {
    let m = published_1dof().unwrap();
    let mut cfg = everything(1);
    cfg.serial = controller_serial.into();
    let mut r = Rig::new(cfg, Some(&m), &TEMPS);
    r.proxy.set_stage(model_serial.and_then(serial), allow);
    (r, m)
}

fn moves(r: &mut Rig) -> usize {
    r.events()
        .iter()
        .filter(|e| matches!(e, Event::Target { .. }))
        .count()
}

#[test]
fn the_same_stage_is_compensated() {
    let (mut r, _) = rig(DEFAULT_SERIAL, Some(DEFAULT_SERIAL), false);
    assert_eq!(r.proxy.stage_check(), StageCheck::NotRead);
    r.line("MOV 1 100");
    assert_eq!(r.line("ERR?"), "0\n");
    assert_eq!(moves(&mut r), 1);
    assert_eq!(r.proxy.stage_check(), StageCheck::Match);
    assert_eq!(r.proxy.controller_serial(), serial(DEFAULT_SERIAL));
}

#[test]
fn another_stage_is_refused_with_its_own_error() {
    let (mut r, _) = rig("0116044999", Some("0116044408"), false);
    assert_eq!(r.proxy.stage_check(), StageCheck::NotRead);
    r.line("MOV 1 100");
    assert_eq!(
        r.line("ERR?"),
        format!("{}\n", GcsErrorCode::StageMismatch.code())
    );
    assert_eq!(moves(&mut r), 0, "nothing moved");
    assert_eq!(r.proxy.stage_check(), StageCheck::Mismatch);
    assert_eq!(r.proxy.controller_serial(), serial("0116044999"));
    // every form of move, every time
    for line in ["MOV 1 50", "MVR 1 1", "mov 1 20"] {
        r.line(line);
        assert_eq!(
            r.line("ERR?"),
            format!("{}\n", GcsErrorCode::StageMismatch.code()),
            "{line}"
        );
    }
    assert_eq!(moves(&mut r), 0);
    // commands that move no model axis pass as before
    let pos = r.line("POS? 1");
    assert!(pos.starts_with("1="), "{pos}");
}

#[test]
fn allow_other_stage_compensates_and_still_reports_the_mismatch() {
    let (mut r, _) = rig("0116044999", Some("0116044408"), true);
    r.line("MOV 1 100");
    assert_eq!(r.line("ERR?"), "0\n");
    assert_eq!(moves(&mut r), 1);
    assert_eq!(r.proxy.stage_check(), StageCheck::MismatchAllowed);
    // the setting turned off at run time: the next move is refused (the move path's cached
    // readiness is decided again)
    r.proxy.set_stage(serial("0116044408"), false);
    r.line("MOV 1 120");
    assert_eq!(
        r.line("ERR?"),
        format!("{}\n", GcsErrorCode::StageMismatch.code())
    );
    assert_eq!(moves(&mut r), 0);
    // and on again
    r.proxy.set_stage(serial("0116044408"), true);
    r.line("MOV 1 120");
    assert_eq!(r.line("ERR?"), "0\n");
    assert_eq!(moves(&mut r), 1);
}

#[test]
fn a_model_without_a_serial_checks_nothing() {
    let (mut r, _) = rig("0116044999", None, false);
    assert_eq!(r.proxy.stage_check(), StageCheck::Unchecked);
    r.line("MOV 1 100");
    assert_eq!(r.line("ERR?"), "0\n");
    assert_eq!(moves(&mut r), 1);
    assert_eq!(r.proxy.stage_check(), StageCheck::Unchecked);
    // a model with a serial loaded later is checked against the identification already read
    r.proxy.set_stage(serial("0116044408"), false);
    assert_eq!(r.proxy.stage_check(), StageCheck::Mismatch);
    r.line("MOV 1 110");
    assert_eq!(
        r.line("ERR?"),
        format!("{}\n", GcsErrorCode::StageMismatch.code())
    );
}

#[test]
fn an_identification_without_a_serial_is_another_stage() {
    // nothing says it is the model's stage
    let (mut r, _) = rig("", Some("0116044408"), false);
    r.line("MOV 1 100");
    assert_eq!(
        r.line("ERR?"),
        format!("{}\n", GcsErrorCode::StageMismatch.code())
    );
    assert_eq!(r.proxy.stage_check(), StageCheck::Mismatch);
    assert_eq!(r.proxy.controller_serial(), None);
    assert_eq!(moves(&mut r), 0);
}

#[test]
fn the_hosts_own_idn_query_settles_the_check_before_any_move() {
    // PIPython asks *IDN? when it connects: the proxy reads the reply on its way to the host
    let (mut r, _) = rig("0116044999", Some("0116044408"), false);
    let reply = r.line("*IDN?");
    assert_eq!(serial_of_idn(reply.as_bytes()), serial("0116044999"));
    assert_eq!(r.proxy.stage_check(), StageCheck::Mismatch);
    assert_eq!(moves(&mut r), 0);
}

#[test]
fn the_serial_rule_on_a_pi_identification() {
    // PI's E-727 manual's example reply to *IDN?: the serial is the third comma field
    let line = b"(c)2015 Physik Instrumente (PI) GmbH & Co. KG, E-727, 0116044408, 13.21.00.09\n";
    assert_eq!(serial_of_idn(line), serial("0116044408"));
}
