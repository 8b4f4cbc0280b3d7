//! The coded enums: every code maps back to its variant, no two variants share a code, and the
//! GCS errors say what the compensator means by them.

use nanocal_interface::bus::{BusOp, BusStatus};
use nanocal_interface::identity::ResetCause;
use nanocal_interface::led::LedState;
use nanocal_interface::mgmt::{InputWhy, Kind, Refusal};
use nanocal_interface::status::{ChannelStatus, Flags, SensorFault};
use nanocal_interface::GcsErrorCode;
use std::collections::HashSet;

macro_rules! codes_are_a_bijection {
    ($($t:ty),+) => {$(
        let mut seen = HashSet::new();
        for v in <$t>::ALL {
            assert_eq!(<$t>::from_code(v.code()), Some(*v), "{}", stringify!($t));
            assert!(seen.insert(v.code()), "{}: code {} twice", stringify!($t), v.code());
            assert!(!v.meaning().is_empty());
        }
    )+};
}

#[test]
fn every_code_maps_back() {
    codes_are_a_bijection!(
        GcsErrorCode,
        Refusal,
        InputWhy,
        Kind,
        LedState,
        ResetCause,
        SensorFault,
        ChannelStatus,
        BusOp,
        BusStatus
    );
    assert_eq!(Refusal::from_code(0), None, "0 is success, not a refusal");
    let mut bits = 0u16;
    for (f, _) in Flags::ALL {
        assert_eq!(f.bits().count_ones(), 1);
        assert_eq!(bits & f.bits(), 0, "flag bit used twice");
        bits |= f.bits();
    }
}

#[test]
fn gcs_errors_mean_what_the_proxy_raises_them_for() {
    // the compensator's own codes, 9001..=9016, each with its own meaning
    let own: Vec<i32> = GcsErrorCode::ALL
        .iter()
        .filter(|e| e.is_compensators())
        .map(|e| e.code())
        .collect();
    assert_eq!(own, (9001..=9016).collect::<Vec<_>>());
    // the two the campaign once mislabelled (9006 as a unit mismatch)
    assert_eq!(
        GcsErrorCode::from_code(9006),
        Some(GcsErrorCode::TooManyQueries)
    );
    assert!(GcsErrorCode::TooManyQueries
        .to_string()
        .contains("too many queries"));
    assert_eq!(
        GcsErrorCode::from_code(9007),
        Some(GcsErrorCode::UnitMismatch)
    );
    assert!(GcsErrorCode::UnitMismatch.to_string().contains("unit"));
    assert_eq!(
        GcsErrorCode::from_code(9008),
        Some(GcsErrorCode::RefusedWhileCompensating)
    );
    assert!(GcsErrorCode::RefusedWhileCompensating
        .to_string()
        .contains("refused while compensating"));
    // main's stage-link code keeps 9010; the proxy's refusals follow it
    assert_eq!(GcsErrorCode::from_code(9010), Some(GcsErrorCode::LinkLost));
    assert_eq!(
        GcsErrorCode::from_code(9011),
        Some(GcsErrorCode::NotPrintable)
    );
    assert!(GcsErrorCode::NotPrintable.to_string().contains("printable"));
    assert_eq!(GcsErrorCode::from_code(9014), Some(GcsErrorCode::NoAnswer));
    assert_eq!(
        GcsErrorCode::from_code(9015),
        Some(GcsErrorCode::StageMismatch)
    );
    assert_eq!(GcsErrorCode::from_code(9016), Some(GcsErrorCode::SplitMove));
    // PI's own "axis identifier specified more than once", as the controller gives it
    assert_eq!(GcsErrorCode::from_code(22), Some(GcsErrorCode::DoubleAxis));
    assert_eq!(GcsErrorCode::from_code(9017), None);
}

#[test]
fn reset_sites_read_as_text() {
    use nanocal_interface::identity::Site;
    assert_eq!(Site::None.text().as_str(), "");
    assert_eq!(Site::Address(0x0800_1a2c).text().as_str(), "0x08001a2c");
    let line = Site::Line {
        file: "src/app/mod.rs",
        line: 1207,
    };
    assert_eq!(line.text().as_str(), "src/app/mod.rs:1207");
    // cut to the buffer, never past it
    let mut short = [0u8; 6];
    assert_eq!(line.write(&mut short), 6);
    assert_eq!(&short, b"src/ap");
    // the new causes keep their codes
    assert_eq!(ResetCause::from_code(8), Some(ResetCause::Panic));
    assert_eq!(ResetCause::from_code(9), Some(ResetCause::FlashEcc));
    assert_eq!(ResetCause::from_code(10), Some(ResetCause::Fault));
}
