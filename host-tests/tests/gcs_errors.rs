//! The GCS errors the compensator answers are explained by the host from the same table the
//! firmware raises them from (`nanocal_interface::GcsErrorCode`). The campaign once called 9006
//! a unit mismatch (it is "too many queries"; the unit mismatch is 9007) and sent 9007–9009,
//! the commonest refusal (9008) among them, to "see the manuals".

use nanocal::campaign::run::gcs_meaning;
use nanocal::device::format_status;
use nanocal_interface::status::Status;
use nanocal_interface::GcsErrorCode;

#[test]
fn the_campaign_explains_every_code_the_compensator_raises() {
    assert!(
        gcs_meaning(9006).contains("too many queries"),
        "{}",
        gcs_meaning(9006)
    );
    assert!(gcs_meaning(9007).contains("unit"), "{}", gcs_meaning(9007));
    assert!(
        gcs_meaning(9008).contains("refused while compensating"),
        "{}",
        gcs_meaning(9008)
    );
    assert!(
        gcs_meaning(9009).contains("GCS 3.0"),
        "{}",
        gcs_meaning(9009)
    );
    for e in GcsErrorCode::ALL {
        assert_eq!(gcs_meaning(e.code()), e.meaning());
        assert!(!gcs_meaning(e.code()).contains("manual"), "{e:?}");
    }
    // the controller's own codes the compensator never raises
    assert_eq!(gcs_meaning(0), "no error");
    assert_eq!(gcs_meaning(10), "stopped by command");
    assert!(gcs_meaning(555).contains("controller"));
}

#[test]
fn the_status_report_names_the_pending_error() {
    let s = Status {
        pending_error: Some(GcsErrorCode::RefusedWhileCompensating),
        ..Status::default()
    };
    let text = format_status(&s);
    assert!(
        text.contains("pending GCS error 9008 (refused while compensating"),
        "{text}"
    );
}

/// Following's counters (protocol 8) are in the report a lab reads: re-issues sent and
/// accepted, and the ones the controller refused.
#[test]
fn the_status_report_shows_followings_counters() {
    let s = Status {
        follow_reissues: 42,
        follow_refused: 3,
        ..Status::default()
    };
    let text = format_status(&s);
    assert!(
        text.contains(
            "held targets re-issued (following the fold): 42  refused by the controller: 3"
        ),
        "{text}"
    );
}
