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
    // the compensator's own codes, 9001..=9009, each with its own meaning
    let own: Vec<i32> = GcsErrorCode::ALL
        .iter()
        .filter(|e| e.is_compensators())
        .map(|e| e.code())
        .collect();
    assert_eq!(own, (9001..=9009).collect::<Vec<_>>());
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
    assert_eq!(GcsErrorCode::from_code(9010), None);
}
