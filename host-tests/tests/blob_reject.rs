//! The decoder rejects anything malformed with a typed error and never panics, whatever the bytes.

use nanocal::published::{coupled_2dof, published_1dof};
use nanocal_model::blob::{self, BlobError, HEADER_LEN, MAX_BLOB_LEN};
use nanocal_model::{Model, ModelError};
use proptest::prelude::*;

fn encode(model: &Model) -> Vec<u8> {
    let mut buf = vec![0u8; MAX_BLOB_LEN];
    let n = blob::encode(model, &mut buf).unwrap();
    buf.truncate(n);
    buf
}

fn valid_blob() -> Vec<u8> {
    encode(&coupled_2dof().unwrap())
}

/// Re-seals a hand-edited blob with a correct CRC, so the semantic checks are what rejects it.
fn reseal(mut bytes: Vec<u8>) -> Vec<u8> {
    let body = bytes.len() - 4;
    let crc = blob::crc32(&bytes[..body]);
    bytes[body..].copy_from_slice(&crc.to_le_bytes());
    bytes
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(20_000))]

    #[test]
    fn random_bytes_never_decode_and_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..3000)) {
        prop_assert!(blob::decode(&bytes).is_err());
    }

    #[test]
    fn random_bytes_behind_a_valid_header_never_panic(
        counts in proptest::array::uniform4(0u8..12),
        terms in 0u16..200,
        tail in proptest::collection::vec(any::<u8>(), 0..3000),
    ) {
        // Valid magic, version, length and CRC: only the payload's semantics can reject it.
        let mut bytes = b"NCAL\x01\x00\x00\x00".to_vec();
        let payload_len = 12 + tail.len();
        bytes.extend_from_slice(&(payload_len as u32).to_le_bytes());
        bytes.extend_from_slice(&[0, 0, 0, 0]);
        bytes.extend_from_slice(&counts);
        bytes.extend_from_slice(&terms.to_le_bytes());
        bytes.extend_from_slice(&[0, 0]);
        bytes.extend_from_slice(&tail);
        bytes.extend_from_slice(&[0; 4]);
        let _ = blob::decode(&reseal(bytes));
    }

    #[test]
    fn any_single_byte_change_is_rejected(position in 0usize..10_000, xor in 1u8..=255) {
        let mut bytes = valid_blob();
        let i = position % bytes.len();
        bytes[i] ^= xor;
        prop_assert!(blob::decode(&bytes).is_err(), "byte {i} ^ {xor:#x} accepted");
    }

    #[test]
    fn any_truncation_or_extension_is_rejected(cut in 0usize..10_000, extra in proptest::collection::vec(any::<u8>(), 1..64)) {
        let bytes = valid_blob();
        let cut = cut % bytes.len();
        prop_assert!(blob::decode(&bytes[..cut]).is_err());
        let mut longer = bytes.clone();
        longer.extend_from_slice(&extra);
        prop_assert!(blob::decode(&longer).is_err());
    }

    #[test]
    fn resealed_mutations_are_rejected_or_decode_to_a_valid_model(position in HEADER_LEN..10_000, value in any::<u8>()) {
        let mut bytes = valid_blob();
        let i = HEADER_LEN + position % (bytes.len() - HEADER_LEN - 4);
        bytes[i] = value;
        if let Ok(model) = blob::decode(&reseal(bytes)) {
            // Whatever passes the checks is a usable model: it re-encodes to itself and folds.
            prop_assert_eq!(blob::decode(&encode(&model)).unwrap(), model.clone());
            let _ = model.fold(&Default::default());
        }
    }
}

#[test]
fn each_header_fault_has_its_own_error() {
    let good = encode(&published_1dof().unwrap());
    assert_eq!(
        blob::decode(&good[..10]),
        Err(BlobError::TooShort { len: 10 })
    );

    let mut bad = good.clone();
    bad[0] = b'X';
    assert_eq!(blob::decode(&bad), Err(BlobError::BadMagic));

    let mut bad = good.clone();
    bad[4] = 2;
    assert_eq!(
        blob::decode(&bad),
        Err(BlobError::UnsupportedVersion { found: 2 })
    );

    let mut bad = good.clone();
    bad.push(0);
    assert!(matches!(
        blob::decode(&bad),
        Err(BlobError::LengthMismatch { .. })
    ));

    let mut bad = good.clone();
    bad[HEADER_LEN + 20] ^= 0x01;
    assert!(matches!(
        blob::decode(&bad),
        Err(BlobError::CrcMismatch { .. })
    ));

    let mut bad = good.clone();
    bad[6] = 1;
    assert_eq!(
        blob::decode(&reseal(bad)),
        Err(BlobError::ReservedNotZero { offset: 6 })
    );
}

#[test]
fn payload_faults_with_a_valid_crc_have_typed_errors() {
    let good = encode(&published_1dof().unwrap());
    let counts = HEADER_LEN + 4;

    let mut bad = good.clone();
    bad[counts] = 0; // no axes
    assert!(matches!(
        blob::decode(&reseal(bad)),
        Err(BlobError::PayloadSizeMismatch { .. })
    ));

    let mut bad = good.clone();
    bad[counts + 1] = 9; // nine temperatures
    assert_eq!(
        blob::decode(&reseal(bad)),
        Err(BlobError::InvalidModel(ModelError::TooManyInputs))
    );

    // First term starts after fixed part, 5 inputs × 32, travel + offsets (32), no lags.
    let term0 = HEADER_LEN + 12 + 5 * 32 + 32;
    let mut bad = good.clone();
    bad[term0] = 1; // output axis 1 of a 1-axis model
    assert_eq!(
        blob::decode(&reseal(bad)),
        Err(BlobError::InvalidModel(ModelError::TermOutOfRange {
            term: 0
        }))
    );
    let mut bad = good.clone();
    bad[term0 + 4] = 7; // factor kind 7
    assert_eq!(
        blob::decode(&reseal(bad)),
        Err(BlobError::UnknownFactor { term: 0, kind: 7 })
    );
    let mut bad = good.clone();
    bad[term0 + 1] = 10; // x¹⁰
    assert_eq!(
        blob::decode(&reseal(bad)),
        Err(BlobError::InvalidModel(ModelError::DegreeTooHigh {
            term: 0
        }))
    );
    let mut bad = good.clone();
    bad[term0 + 8..term0 + 16].copy_from_slice(&f64::NAN.to_le_bytes());
    assert_eq!(
        blob::decode(&reseal(bad)),
        Err(BlobError::InvalidModel(ModelError::NonFinite))
    );

    // Half range of the axis scaling set to −1.
    let half_range = HEADER_LEN + 12 + 8;
    let mut bad = good.clone();
    bad[half_range..half_range + 8].copy_from_slice(&(-1.0f64).to_le_bytes());
    assert_eq!(
        blob::decode(&reseal(bad)),
        Err(BlobError::InvalidModel(ModelError::InvalidScaling {
            input: 0
        }))
    );
}

#[test]
fn errors_explain_themselves() {
    let msg = BlobError::CrcMismatch {
        stored: 1,
        computed: 2,
    }
    .to_string();
    assert!(msg.contains("CRC") && msg.contains("0x00000001"), "{msg}");
    let msg = BlobError::InvalidModel(ModelError::TermOutOfRange { term: 3 }).to_string();
    assert!(msg.contains("term 3"), "{msg}");
}
