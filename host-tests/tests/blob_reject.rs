//! The decoder rejects anything malformed with a typed error and never panics, whatever the bytes.

use nanocal::papers::published::{coupled_2dof, published_1dof};
use nanocal_model::blob::{self, BlobError, HEADER_LEN, MAX_BLOB_LEN};
use nanocal_model::{AuxKind, AuxSpec, Factor, Input, Model, ModelBuilder, ModelError, Term};
use proptest::prelude::*;

fn encode(model: &Model) -> Vec<u8> {
    let mut buf = vec![0u8; MAX_BLOB_LEN];
    let n = blob::encode(model, &mut buf).unwrap();
    buf.truncate(n);
    buf
}

/// A model with every part of format version 2: two axes, temperatures, a slow pressure and
/// a fast force input, a lag, play-operator banks on both axes, direction terms.
fn rich_model() -> Model {
    let mut b = ModelBuilder::new(2, 2, 2)
        .unwrap()
        .trained_range(Input::Axis(0), 0.0, 100.0)
        .trained_range(Input::Axis(1), 0.0, 50.0)
        .trained_range(Input::Temp(0), 20.0, 24.0)
        .trained_range(Input::Temp(1), 20.0, 24.0)
        .trained_range(Input::Aux(0), 950.0, 1050.0)
        .trained_range(Input::Aux(1), -2.0, 2.0)
        .aux_spec(0, AuxSpec::slow(AuxKind::AirPressureHpa))
        .aux_spec(1, AuxSpec::fast(AuxKind::ForceN))
        .travel_um(0, -5.0, 105.0)
        .travel_um(1, -5.0, 55.0);
    b.add_raw_term(0, [1, 0, 0], Factor::None, 0, 1.0).unwrap();
    b.add_raw_term(1, [0, 1, 0], Factor::None, 0, 1.0).unwrap();
    let lag = b.lag(1, 300.0).unwrap();
    b.play_bank(0, &[(0.0, -0.02), (10.0, -0.03), (30.0, -0.01)])
        .unwrap();
    b.play_bank(1, &[(5.0, -0.05)]).unwrap();
    let terms = [
        (0, [2, 0, 0], Factor::None, 0, 0.3),
        (1, [1, 1, 0], Factor::Temp(0), 0, 0.1),
        (0, [0, 0, 0], Factor::Aux(0), 0, 0.2),
        (1, [1, 0, 0], Factor::Aux(1), 0, 0.4),
        (0, [0, 0, 0], Factor::Aux(1), 1, 0.05),
        (1, [0, 0, 0], Factor::Lagged(lag), 2, -0.1),
    ];
    for (output, powers, factor, direction, coeff) in terms {
        b.add_term(Term {
            output,
            powers,
            factor,
            direction,
            coeff,
        })
        .unwrap();
    }
    // and a prediction bound on axis 0 (blob version 3), so the mutations reach its bytes too
    let mut model = b.build().unwrap();
    let p = model.axis_terms(0);
    let r: Vec<f32> = (0..(p + 1) * (p + 2) / 2).map(|k| 1.0 + k as f32).collect();
    let bound = nanocal_model::AxisBound::new(0.05, 2.0, &vec![0.1; p], &vec![0.5; p], &r).unwrap();
    model.set_bound(0, Some(bound)).unwrap();
    model
}

fn valid_blob(rich: bool) -> Vec<u8> {
    if rich {
        encode(&rich_model())
    } else {
        encode(&coupled_2dof().unwrap())
    }
}

/// Re-seals a hand-edited blob with a correct CRC, so the semantic checks are what rejects it.
/// A version 4 blob's bytes without its provenance section (the payload length shortened; the
/// CRC as it was — reseal it): the layout of versions 1–3 for the same model.
fn without_provenance(mut bytes: Vec<u8>) -> Vec<u8> {
    let crc_at = bytes.len() - 4;
    bytes.drain(crc_at - blob::PROVENANCE_LEN..crc_at);
    let payload = u32::from_le_bytes(bytes[8..12].try_into().unwrap());
    bytes[8..12].copy_from_slice(&(payload - blob::PROVENANCE_LEN as u32).to_le_bytes());
    bytes
}

fn reseal(mut bytes: Vec<u8>) -> Vec<u8> {
    let body = bytes.len() - 4;
    let crc = blob::crc32(&bytes[..body]);
    bytes[body..].copy_from_slice(&crc.to_le_bytes());
    bytes
}

proptest! {
    #![proptest_config(ProptestConfig {
        // the same cases on every run (deterministic tests; a new case goes in by its seed)
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x6e61_6e6f_6361_6c00),
        ..ProptestConfig::with_cases(20_000)
    })]

    #[test]
    fn random_bytes_never_decode_and_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..3000)) {
        prop_assert!(blob::decode(&bytes).is_err());
    }

    #[test]
    fn random_bytes_behind_a_valid_header_never_panic(
        version in 1u16..=2,
        counts in proptest::array::uniform4(0u8..40),
        terms in 0u16..200,
        plays in 0u8..60,
        tail in proptest::collection::vec(any::<u8>(), 0..5000),
    ) {
        // Valid magic, version, length and CRC: only the payload's semantics can reject it.
        let mut bytes = b"NCAL".to_vec();
        bytes.extend_from_slice(&version.to_le_bytes());
        bytes.extend_from_slice(&[0, 0]);
        let payload_len = 12 + tail.len();
        bytes.extend_from_slice(&(payload_len as u32).to_le_bytes());
        bytes.extend_from_slice(&[0, 0, 0, 0]);
        bytes.extend_from_slice(&counts);
        bytes.extend_from_slice(&terms.to_le_bytes());
        bytes.extend_from_slice(&[plays, 0]);
        bytes.extend_from_slice(&tail);
        bytes.extend_from_slice(&[0; 4]);
        let _ = blob::decode(&reseal(bytes));
    }

    #[test]
    fn any_single_byte_change_is_rejected(rich: bool, position in 0usize..10_000, xor in 1u8..=255) {
        let mut bytes = valid_blob(rich);
        let i = position % bytes.len();
        bytes[i] ^= xor;
        prop_assert!(blob::decode(&bytes).is_err(), "byte {i} ^ {xor:#x} accepted");
    }

    #[test]
    fn any_truncation_or_extension_is_rejected(rich: bool, cut in 0usize..10_000, extra in proptest::collection::vec(any::<u8>(), 1..64)) {
        let bytes = valid_blob(rich);
        let cut = cut % bytes.len();
        prop_assert!(blob::decode(&bytes[..cut]).is_err());
        let mut longer = bytes.clone();
        longer.extend_from_slice(&extra);
        prop_assert!(blob::decode(&longer).is_err());
    }

    #[test]
    fn resealed_mutations_are_rejected_or_decode_to_a_valid_model(rich: bool, position in HEADER_LEN..10_000, value in any::<u8>()) {
        let mut bytes = valid_blob(rich);
        let i = HEADER_LEN + position % (bytes.len() - HEADER_LEN - 4);
        bytes[i] = value;
        if let Ok(model) = blob::decode(&reseal(bytes)) {
            // Whatever passes the checks is a usable model: it re-encodes to itself and folds.
            prop_assert_eq!(blob::decode(&encode(&model)).unwrap(), model.clone());
            // … and runs: the fast path, a walk's state and the inverse never panic either.
            let fold = model.fold(&Default::default());
            let mut state = nanocal_model::HysteresisState::new();
            let fast = nanocal_model::FastInputs::NONE.with_aux(1, 0.5);
            for x in [10.0f32, 40.0, 20.0] {
                let c = fold.correct(&[x, x, 0.0], &[1, -1, 0], &fast, &mut state);
                let _ = fold.inverse(&c.q_um, &[1, -1, 0], &fast, &state);
            }
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
    bad[4] = 5;
    assert_eq!(
        blob::decode(&bad),
        Err(BlobError::UnsupportedVersion { found: 5 })
    );
    let mut bad = good.clone();
    bad[4] = 0;
    assert_eq!(
        blob::decode(&bad),
        Err(BlobError::UnsupportedVersion { found: 0 })
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
    bad[counts + 1] = 17; // seventeen temperatures
    assert_eq!(
        blob::decode(&reseal(bad)),
        Err(BlobError::InvalidModel(ModelError::TooManyInputs))
    );
    let mut bad = good.clone();
    bad[counts + 6] = 49; // 49 play operators
    assert_eq!(
        blob::decode(&reseal(bad)),
        Err(BlobError::InvalidModel(ModelError::TooManyInputs))
    );
    let mut bad = good.clone();
    bad[counts + 7] = 2; // the bound mask names axis 1 of a 1-axis model
    assert_eq!(
        blob::decode(&reseal(bad)),
        Err(BlobError::ReservedNotZero { offset: counts + 7 })
    );
    let mut bad = good.clone();
    bad[counts + 7] = 1; // a bound for axis 0 that the payload does not hold
    let found = good.len() - HEADER_LEN - 4;
    let p = published_1dof().unwrap().axis_terms(0);
    assert_eq!(
        blob::decode(&reseal(bad)),
        Err(BlobError::PayloadSizeMismatch {
            expected: found + 4 * (2 + 2 * p + (p + 1) * (p + 2) / 2),
            found
        })
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
fn aux_descriptors_and_version_1_rules_have_typed_errors() {
    let good = encode(&rich_model());
    // Aux descriptors follow 2 axes + 2 temperatures + 2 aux inputs (32 bytes each), travel
    // and offsets (32 per axis).
    let aux0 = HEADER_LEN + 12 + 6 * 32 + 2 * 32;
    assert_eq!(good[aux0..aux0 + 2], [1, 0]); // air pressure, slow
    assert_eq!(good[aux0 + 8..aux0 + 10], [2, 1]); // force, fast
    let mut bad = good.clone();
    bad[aux0] = 3;
    assert_eq!(
        blob::decode(&reseal(bad)),
        Err(BlobError::UnknownAuxKind { aux: 0, kind: 3 })
    );
    let mut bad = good.clone();
    bad[aux0 + 1] = 2; // an undefined flag bit
    assert_eq!(
        blob::decode(&reseal(bad)),
        Err(BlobError::ReservedNotZero { offset: aux0 + 1 })
    );
    let mut bad = good.clone();
    bad[aux0 + 5] = 1;
    assert_eq!(
        blob::decode(&reseal(bad)),
        Err(BlobError::ReservedNotZero { offset: aux0 + 5 })
    );
    // Version 1 had no play operators: a play count there is a reserved byte that is not zero.
    let mut v1 = without_provenance(encode(&published_1dof().unwrap()));
    v1[4] = 1;
    let mut bad = v1.clone();
    bad[HEADER_LEN + 10] = 1;
    assert_eq!(
        blob::decode(&reseal(bad)),
        Err(BlobError::ReservedNotZero {
            offset: HEADER_LEN + 10
        })
    );
    assert_eq!(
        blob::decode(&reseal(v1)).unwrap(),
        published_1dof().unwrap()
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
    let msg = BlobError::UnsupportedVersion { found: 7 }.to_string();
    assert!(
        msg.contains('7') && msg.contains('1') && msg.contains('4'),
        "{msg}"
    );
    let msg = BlobError::UnknownAuxKind { aux: 1, kind: 9 }.to_string();
    assert!(msg.contains("aux input 1") && msg.contains('9'), "{msg}");
    let msg = ModelError::BankNotMonotone { axis: 2 }.to_string();
    assert!(msg.contains("axis 2"), "{msg}");
}
