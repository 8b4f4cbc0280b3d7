//! The blob's bytes: golden bytes for format versions 4, 3, 2 and 1, round trips, CRC check value.

use nanocal::papers::published::{coupled_2dof, published_1dof};
use nanocal_model::blob::{self, BlobError, FORMAT_VERSION, MAX_BLOB_LEN};
use nanocal_model::bound::packed_len;
use nanocal_model::provenance::{self, Provenance, ProvenanceUnit};
use nanocal_model::reference::delta_robot_78;
use nanocal_model::{
    AuxKind, AuxSpec, AxisBound, Factor, Input, Model, ModelBuilder, Scaling, Term, MAX_AUX,
    MAX_BOUND_TERMS, MAX_LAGS, MAX_PLAY, MAX_TEMPS,
};

/// A small model with one of everything version 1 could hold, on round binary numbers so the
/// bytes read easily.
fn golden_model() -> Model {
    let mut b = ModelBuilder::new(1, 1, 0)
        .unwrap()
        .id(0xDEAD_BEEF)
        .scaling(
            Input::Axis(0),
            Scaling {
                centre: 50.0,
                half_range: 50.0,
            },
        )
        .envelope(Input::Axis(0), 0.0, 100.0)
        .scaling(
            Input::Temp(0),
            Scaling {
                centre: 22.0,
                half_range: 1.0,
            },
        )
        .envelope(Input::Temp(0), 21.0, 23.0)
        .travel_um(0, -5.0, 105.0)
        .offset_um(0, 0.5)
        .kmz_offset_um(0, -0.25);
    let lag = b.lag(0, 600.0).unwrap();
    let terms = [
        ([1, 0, 0], Factor::None, 0, 1.5),
        ([0, 0, 0], Factor::Temp(0), 0, -0.25),
        ([1, 0, 0], Factor::Lagged(lag), 0, 0.125),
        ([0, 0, 0], Factor::None, 1, 0.03125),
    ];
    for (powers, factor, direction, coeff) in terms {
        b.add_term(Term {
            output: 0,
            powers,
            factor,
            direction,
            coeff,
        })
        .unwrap();
    }
    b.build().unwrap()
}

/// Format version 1, byte for byte, as version 1 wrote it: the decoder still reads it.
const GOLDEN_V1_HEX: &str = concat!(
    "4e43414c",
    "0100",
    "0000",
    "bc000000", // magic, version 1, reserved, payload 188
    "efbeadde",
    "01010001",
    "0400",
    "0000", // id, A T X L, 4 terms, reserved
    "0000000000004940",
    "0000000000004940",
    "0000000000000000",
    "0000000000005940", // axis 0
    "0000000000003640",
    "000000000000f03f",
    "0000000000003540",
    "0000000000003740", // temp 0
    "00000000000014c0",
    "0000000000405a40", // travel −5 … 105
    "000000000000e03f",
    "000000000000d0bf", // λ 0.5, λ_KMZ −0.25
    "0000000000000000",
    "0000000000c08240", // lag: sensor 0, τ 600 s
    "0001000000000000",
    "000000000000f83f", // 1.5·u
    "0000000001000000",
    "000000000000d0bf", // −0.25·T0
    "0001000003000000",
    "000000000000c03f", // 0.125·u·lag0
    "0000000000000100",
    "000000000000a03f", // 0.03125·sign(x)
    "f533fc72",         // CRC-32/IEEE (zlib) of all bytes above
);

/// The version 1 golden model plus what version 2 added: a fast force input and a bank of two
/// play operators, each used by one term.
fn golden_model_v2() -> Model {
    let mut b = ModelBuilder::from_model(&golden_model()).id(0xC0FF_EE02);
    let force = b.add_aux(AuxSpec::fast(AuxKind::ForceN)).unwrap();
    let mut b = b
        .scaling(
            Input::Aux(force),
            Scaling {
                centre: 0.0,
                half_range: 2.0,
            },
        )
        .envelope(Input::Aux(force), -2.0, 2.0);
    b.play(0, 0.0).unwrap();
    let p1 = b.play(0, 12.5).unwrap();
    for (factor, coeff) in [(Factor::Aux(force), 0.125), (Factor::Play(p1), -0.5)] {
        b.add_term(Term {
            output: 0,
            powers: [0; 3],
            factor,
            direction: 0,
            coeff,
        })
        .unwrap();
    }
    b.build().unwrap()
}

/// The version 1 golden model with a prediction bound on its axis (4 terms: 2 + 4 + 4 + 15
/// f32), on round numbers: s 0.5 µm, t 2, R with 4 on the diagonal.
fn golden_model_v3() -> Model {
    let mut model = golden_model();
    let r: Vec<f32> = (0..5)
        .flat_map(|i| (i..5).map(move |j| (i, j)))
        .map(|(i, j)| match (i, j) {
            _ if i == j => 4.0,
            (0, _) => 0.5,
            _ => 0.25,
        })
        .collect();
    let bound =
        AxisBound::new(0.5, 2.0, &[0.0, 0.5, 0.25, 0.0], &[1.0, 2.0, 0.5, 1.0], &r).unwrap();
    model.set_bound(0, Some(bound)).unwrap();
    model
}

/// The version 3 golden model with its provenance: fitted on the stage of the PI controller
/// whose `*IDN?` names serial 0116044408, axis `x` in µm.
fn golden_model_v4() -> Model {
    let mut model = golden_model_v3();
    let idn = b"(c)2015 Physik Instrumente (PI) GmbH & Co. KG, E-727, 0116044408, 13.21.00.09\n";
    model.set_provenance(Provenance {
        stage_serial: provenance::serial_of_idn(idn),
        axes: [provenance::AxisName::new(b"x"), None, None],
        unit: ProvenanceUnit::Um,
        fit_date_s: 1_700_000_000,
        data_fnv64: 0x0123_4567_89ab_cdef,
    });
    model
}

/// Format version 3, byte for byte: version 1's layout for this model (no aux inputs, no play
/// operators), the bound mask at payload byte +11, the bound after the terms. Written by
/// Python's `struct` and `zlib.crc32` from the version 1 bytes, not by the encoder. Changing
/// these bytes needs a FORMAT_VERSION bump.
const GOLDEN_V3_HEX: &str = concat!(
    "4e43414c",
    "0300",
    "0000",
    "20010000", // magic, version 3, reserved, payload 288
    "efbeadde",
    "01010001",
    "0400",
    "00",
    "01", // id, A T X L, 4 terms, 0 play operators, bound mask: axis 0
    "0000000000004940",
    "0000000000004940",
    "0000000000000000",
    "0000000000005940", // axis 0
    "0000000000003640",
    "000000000000f03f",
    "0000000000003540",
    "0000000000003740", // temp 0
    "00000000000014c0",
    "0000000000405a40", // travel −5 … 105
    "000000000000e03f",
    "000000000000d0bf", // λ 0.5, λ_KMZ −0.25
    "0000000000000000",
    "0000000000c08240", // lag: sensor 0, τ 600 s
    "0001000000000000",
    "000000000000f83f", // 1.5·u
    "0000000001000000",
    "000000000000d0bf", // −0.25·T0
    "0001000003000000",
    "000000000000c03f", // 0.125·u·lag0
    "0000000000000100",
    "000000000000a03f", // 0.03125·sign(x)
    "0000003f",
    "00000040", // bound of axis 0 (f32): s 0.5 µm, t95 2
    "00000000",
    "0000003f",
    "0000803e",
    "00000000", // mean 0, 0.5, 0.25, 0
    "0000803f",
    "00000040",
    "0000003f",
    "0000803f", // scale 1, 2, 0.5, 1
    "00008040",
    "0000003f",
    "0000003f",
    "0000003f",
    "0000003f", // R row 0: 4, 0.5, 0.5, 0.5, 0.5
    "00008040",
    "0000803e",
    "0000803e",
    "0000803e", // R row 1: 4, 0.25, 0.25, 0.25
    "00008040",
    "0000803e",
    "0000803e", // R row 2
    "00008040",
    "0000803e", // R row 3
    "00008040", // R row 4
    "78650a63", // CRC-32/IEEE (zlib) of all bytes above
);

/// Format version 4, byte for byte: version 3's golden bytes (the payload 72 bytes longer),
/// then the provenance (stage serial 0116044408, axis `x`, µm, fit date, data hash). Written by
/// Python's `struct` and `zlib.crc32` from the version 3 bytes, not by the encoder. Changing
/// these bytes needs a FORMAT_VERSION bump.
const GOLDEN_V4_HEX: &str = concat!(
    "4e43414c",
    "0400",
    "0000",
    "68010000", // magic, version 4, reserved, payload 360
    "efbeadde",
    "01010001",
    "0400",
    "00",
    "01", // id, A T X L, 4 terms, 0 play operators, bound mask: axis 0
    "0000000000004940",
    "0000000000004940",
    "0000000000000000",
    "0000000000005940", // axis 0
    "0000000000003640",
    "000000000000f03f",
    "0000000000003540",
    "0000000000003740", // temp 0
    "00000000000014c0",
    "0000000000405a40", // travel −5 … 105
    "000000000000e03f",
    "000000000000d0bf", // λ 0.5, λ_KMZ −0.25
    "0000000000000000",
    "0000000000c08240", // lag: sensor 0, τ 600 s
    "0001000000000000",
    "000000000000f83f", // 1.5·u
    "0000000001000000",
    "000000000000d0bf", // −0.25·T0
    "0001000003000000",
    "000000000000c03f", // 0.125·u·lag0
    "0000000000000100",
    "000000000000a03f", // 0.03125·sign(x)
    "0000003f",
    "00000040", // bound of axis 0 (f32): s 0.5 µm, t95 2
    "00000000",
    "0000003f",
    "0000803e",
    "00000000", // mean 0, 0.5, 0.25, 0
    "0000803f",
    "00000040",
    "0000003f",
    "0000803f", // scale 1, 2, 0.5, 1
    "00008040",
    "0000003f",
    "0000003f",
    "0000003f",
    "0000003f", // R row 0: 4, 0.5, 0.5, 0.5, 0.5
    "00008040",
    "0000803e",
    "0000803e",
    "0000803e", // R row 1: 4, 0.25, 0.25, 0.25
    "00008040",
    "0000803e",
    "0000803e", // R row 2
    "00008040",
    "0000803e",         // R row 3
    "00008040",         // R row 4
    "00f1536500000000", // provenance: fit date 1 700 000 000 s (2023-11-14 22:13:20 UTC)
    "efcdab8967452301", // data hash (FNV-1a 64) 0x0123456789abcdef
    "0a",
    "01",
    "0000", // serial length 10, unit 1 (µm), reserved
    "303131363034343430380000000000000000000000000000", // serial "0116044408", zeros
    "01",
    "7800000000000000", // axis 0: "x"
    "00",
    "0000000000000000", // axis slot 1: none
    "00",
    "0000000000000000", // axis slot 2: none
    "00",               // reserved
    "c3db8cb5",         // CRC-32/IEEE (zlib) of all bytes above
);

/// Format version 2, byte for byte, as version 2 wrote it: the decoder still reads it. The CRC
/// was checked with an independent implementation (Python's `zlib.crc32`).
const GOLDEN_V2_HEX: &str = concat!(
    "4e43414c",
    "0200",
    "0000",
    "24010000", // magic, version 2, reserved, payload 292
    "02eeffc0",
    "01010101",
    "0600",
    "02",
    "00", // id, A T X L, 6 terms, 2 play operators, reserved
    "0000000000004940",
    "0000000000004940",
    "0000000000000000",
    "0000000000005940", // axis 0: centre 50, half range 50, envelope 0 … 100
    "0000000000003640",
    "000000000000f03f",
    "0000000000003540",
    "0000000000003740", // temp 0: 22, 1, 21 … 23
    "0000000000000000",
    "0000000000000040",
    "00000000000000c0",
    "0000000000000040", // aux 0: 0, 2, −2 … 2
    "00000000000014c0",
    "0000000000405a40", // travel −5 … 105
    "000000000000e03f",
    "000000000000d0bf", // λ 0.5, λ_KMZ −0.25
    "0201000000000000", // aux 0: kind 2 (force, N), flags 1 (fast)
    "0000000000000000",
    "0000000000c08240", // lag: sensor 0, τ 600 s
    "0000000000000000",
    "0000000000000000", // play 0: axis 0, threshold 0
    "0000000000000000",
    "0000000000002940", // play 1: axis 0, threshold 12.5 µm
    "0001000000000000",
    "000000000000f83f", // 1.5·u
    "0000000001000000",
    "000000000000d0bf", // −0.25·T0
    "0001000003000000",
    "000000000000c03f", // 0.125·u·lag0
    "0000000000000100",
    "000000000000a03f", // 0.03125·sign(x)
    "0000000002000000",
    "000000000000c03f", // 0.125·F (fast aux 0)
    "0000000004010000",
    "000000000000e0bf", // −0.5·play1
    "f1e09bcf",         // CRC-32/IEEE (zlib) of all bytes above
);

fn unhex(text: &str) -> Vec<u8> {
    (0..text.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&text[i..i + 2], 16).unwrap())
        .collect()
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn encode(model: &Model) -> Vec<u8> {
    let mut buf = vec![0u8; MAX_BLOB_LEN];
    let n = blob::encode(model, &mut buf).unwrap();
    buf.truncate(n);
    buf
}

#[test]
fn crc32_matches_the_standard_check_value() {
    assert_eq!(blob::crc32(b"123456789"), 0xCBF4_3926);
    assert_eq!(
        blob::crc32_update(blob::crc32(b"12345"), b"6789"),
        0xCBF4_3926
    );
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig {
        // the same cases on every run (deterministic tests; a new case goes in by its seed)
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x6e61_6e6f_6361_6c00),
        failure_persistence: None,
        cases: 512,
        ..proptest::prelude::ProptestConfig::default()
    })]
    /// The nibble-table CRC against an implementation nobody here wrote (`crc32fast`, the
    /// PNG encoder's), over every length up to a management frame's and beyond, and split
    /// anywhere through `crc32_update`.
    #[test]
    fn crc32_agrees_with_crc32fast(bytes in proptest::collection::vec(proptest::num::u8::ANY, 0..700), cut in 0usize..700) {
        proptest::prop_assert_eq!(blob::crc32(&bytes), crc32fast::hash(&bytes));
        let cut = cut.min(bytes.len());
        proptest::prop_assert_eq!(
            blob::crc32_update(blob::crc32(&bytes[..cut]), &bytes[cut..]),
            crc32fast::hash(&bytes)
        );
    }
}

#[test]
fn golden_bytes_of_format_version_4() {
    assert_eq!(FORMAT_VERSION, 4, "a version bump needs new golden bytes");
    assert_eq!(hex(&encode(&golden_model_v4())), GOLDEN_V4_HEX);
    let model = blob::decode(&unhex(GOLDEN_V4_HEX)).unwrap();
    assert_eq!(model, golden_model_v4());
    let p = model.provenance();
    assert_eq!(p.stage_serial.unwrap().as_str(), "0116044408");
    assert_eq!(p.axes[0].unwrap().as_str(), "x");
    assert_eq!((p.unit, p.fit_date_s), (ProvenanceUnit::Um, 1_700_000_000));
}

#[test]
fn version_3_blobs_still_decode_with_the_provenance_unknown() {
    let v3 = unhex(GOLDEN_V3_HEX);
    let model = blob::decode(&v3).unwrap();
    assert!(
        model.provenance().is_unknown(),
        "version 3 carries no provenance"
    );
    // re-encoded: version 4, the same bytes but the version, the payload length and the CRC,
    // then an all-unknown provenance (zeros)
    let v4 = encode(&model);
    assert_eq!(&v4[4..6], &4u16.to_le_bytes());
    assert_eq!(v4.len(), v3.len() + blob::PROVENANCE_LEN);
    assert_eq!(&v4[12..v3.len() - 4], &v3[12..v3.len() - 4]);
    assert!(v4[v3.len() - 4..v4.len() - 4].iter().all(|&b| b == 0));
    assert_eq!(blob::decode(&v4).unwrap(), model);
}

/// The golden version 4 blob with byte `at` (an offset into its provenance) set to `v`, the
/// CRC made right again.
fn v4_with(at: usize, v: u8) -> Vec<u8> {
    let mut b = unhex(GOLDEN_V4_HEX);
    let n = b.len() - 4;
    b[n - blob::PROVENANCE_LEN + at] = v;
    let crc = blob::crc32(&b[..n]);
    b[n..].copy_from_slice(&crc.to_le_bytes());
    b
}

#[test]
fn a_malformed_provenance_is_refused_with_its_offset() {
    let start = unhex(GOLDEN_V4_HEX).len() - 4 - blob::PROVENANCE_LEN;
    for (at, v, why) in [
        (16, 25, "serial longer than its field"),
        (17, 2, "unknown unit"),
        (20, b',', "a comma in the serial"),
        (20, b' ', "a space at the serial's start"),
        (30, b'9', "a byte after the serial's end"),
        (44, 9, "axis name longer than its field"),
        (53, 1, "a name for an axis slot past the model's axes"),
        (46, b'y', "a byte after an axis name's end"),
    ] {
        match blob::decode(&v4_with(at, v)) {
            Err(BlobError::InvalidProvenance { offset }) => {
                assert!(
                    offset >= start && offset < start + blob::PROVENANCE_LEN,
                    "{why}: {offset}"
                )
            }
            other => panic!("{why}: {other:?}"),
        }
    }
    assert_eq!(
        blob::decode(&v4_with(18, 1)),
        Err(BlobError::ReservedNotZero { offset: start + 18 })
    );
    assert_eq!(
        blob::decode(&v4_with(71, 1)),
        Err(BlobError::ReservedNotZero { offset: start + 71 })
    );
}

#[test]
fn golden_bytes_of_format_version_3() {
    let model = blob::decode(&unhex(GOLDEN_V3_HEX)).unwrap();
    assert_eq!(model, golden_model_v3());
    let bound = model.bound(0).unwrap();
    assert_eq!(
        (bound.s_um(), bound.t95(), bound.regressors()),
        (0.5, 2.0, 4)
    );
    assert_eq!(bound.r_packed().len(), packed_len(4));
}

#[test]
fn version_2_blobs_still_decode_and_re_encode_as_version_4() {
    let v2 = unhex(GOLDEN_V2_HEX);
    let model = blob::decode(&v2).unwrap();
    assert_eq!(model, golden_model_v2());
    assert!(model.bound(0).is_none(), "version 2 carries no bound");
    let v4 = encode(&model);
    // A model without a bound: the same bytes but the version, the payload length (the
    // provenance added) and the CRC.
    assert_eq!(&v4[4..6], &4u16.to_le_bytes());
    assert_eq!(v4.len(), v2.len() + blob::PROVENANCE_LEN);
    assert_eq!(&v4[12..v2.len() - 4], &v2[12..v2.len() - 4]);
    assert_eq!(blob::decode(&v4).unwrap(), model);
}

#[test]
fn a_version_2_blob_with_a_bound_mask_is_refused() {
    // byte +11 of the payload was reserved before version 3
    let mut v2 = unhex(GOLDEN_V2_HEX);
    v2[12 + 11] = 1;
    let n = v2.len() - 4;
    let crc = blob::crc32(&v2[..n]);
    v2[n..].copy_from_slice(&crc.to_le_bytes());
    assert_eq!(
        blob::decode(&v2),
        Err(BlobError::ReservedNotZero { offset: 12 + 11 })
    );
}

#[test]
fn golden_bytes_decode_to_the_golden_model() {
    let model = golden_model_v2();
    assert_eq!(blob::decode(&unhex(GOLDEN_V2_HEX)).unwrap(), model);
    assert_eq!(model.aux_kind(0), Some(AuxKind::ForceN));
    assert!(model.is_fast(0));
    assert_eq!(model.aux_kind(1), None);
    assert!(!model.is_fast(1));
    assert_eq!(model.fast_aux_mask(), 1);
    assert_eq!(model.play_operators().len(), 2);
}

#[test]
fn version_1_blobs_still_decode_and_re_encode_as_version_4() {
    let v1 = unhex(GOLDEN_V1_HEX);
    let model = blob::decode(&v1).unwrap();
    assert_eq!(model, golden_model());
    assert_eq!(model.aux_spec(0), None);
    let v2 = encode(&model);
    assert_eq!(&v2[4..6], &4u16.to_le_bytes());
    // Versions 2 and 3 add the play count (0) and the bound mask (0) where version 1 had
    // reserved zeros, and nothing else for a model without aux inputs, play operators or
    // bounds; version 4 the provenance at the end: same bytes but version, payload length
    // and CRC, then the (unknown) provenance.
    assert_eq!(v2.len(), v1.len() + blob::PROVENANCE_LEN);
    assert_eq!(&v2[12..v1.len() - 4], &v1[12..v1.len() - 4]);
    assert_eq!(blob::decode(&v2).unwrap(), model);
}

#[test]
fn reference_models_round_trip() {
    for model in [
        published_1dof().unwrap(),
        coupled_2dof().unwrap(),
        delta_robot_78().unwrap(),
        golden_model_v2(),
        golden_model_v3(),
        golden_model_v4(),
    ] {
        let bytes = encode(&model);
        assert_eq!(bytes.len(), blob::encoded_len(&model));
        assert_eq!(blob::decode(&bytes).unwrap(), model);
    }
}

#[test]
fn encode_refuses_a_buffer_that_is_too_small() {
    let model = golden_model();
    let mut small = [0u8; 64];
    assert_eq!(
        blob::encode(&model, &mut small),
        Err(BlobError::BufferTooSmall {
            needed: blob::encoded_len(&model)
        })
    );
}

#[test]
fn a_full_model_fits_the_largest_blob() {
    let mut b = ModelBuilder::new(3, MAX_TEMPS, MAX_AUX).unwrap();
    for k in 0..MAX_LAGS {
        b.lag((k % MAX_TEMPS) as u8, 100.0 * (k + 1) as f64)
            .unwrap();
    }
    for k in 0..MAX_PLAY {
        let per_axis = MAX_PLAY / 3;
        b.play((k / per_axis) as u8, (k % per_axis) as f64).unwrap();
    }
    for n in 0..MAX_AUX {
        let kind = [AuxKind::AirPressureHpa, AuxKind::ForceN][n % 2];
        b = b.aux_spec(
            n,
            AuxSpec {
                kind,
                fast: n % 2 == 1,
            },
        );
    }
    // Degree ≤ 6 in three axes: 84 monomials. Axes 0 and 1 get the first MAX_BOUND_TERMS of
    // them and a full bound, axis 2 all of them and temperature terms up to MAX_TERMS (the
    // largest blob: see blob::MAX_PAYLOAD_LEN).
    let mut monomials = Vec::new();
    for px in 0..=6u8 {
        for py in 0..=6 - px {
            for pz in 0..=6 - px - py {
                if px + py + pz != 0 {
                    monomials.push([px, py, pz]);
                }
            }
        }
    }
    let mut terms = Vec::new();
    for (i, &powers) in monomials.iter().enumerate() {
        for output in 0..3u8 {
            if output == 2 || i < MAX_BOUND_TERMS {
                terms.push((output, powers, Factor::None));
            }
        }
    }
    let mut t = 0u8;
    while terms.len() < nanocal_model::MAX_TERMS {
        terms.push((2, [0; 3], Factor::Temp(t)));
        t += 1;
    }
    for (output, powers, factor) in terms {
        b.add_term(Term {
            output,
            powers,
            factor,
            direction: 0,
            coeff: 1e-3,
        })
        .unwrap();
    }
    let mut model = b.build().unwrap();
    assert_eq!(model.terms().len(), nanocal_model::MAX_TERMS);
    let p = MAX_BOUND_TERMS;
    let r: Vec<f32> = (0..packed_len(p)).map(|k| 1.0 + k as f32).collect();
    let bound = AxisBound::new(
        0.1,
        2.0,
        &[0.0; MAX_BOUND_TERMS],
        &[1.0; MAX_BOUND_TERMS],
        &r,
    )
    .unwrap();
    for a in 0..2 {
        model.set_bound(a, Some(bound)).unwrap();
    }
    assert_eq!(
        model.set_bound(2, Some(bound)),
        Err(nanocal_model::ModelError::InvalidBound),
        "axis 2 has more terms than a bound covers"
    );
    let bytes = encode(&model);
    assert_eq!(bytes.len(), MAX_BLOB_LEN);
    assert_eq!(blob::decode(&bytes).unwrap(), model);
}

#[test]
fn a_model_whose_fold_would_not_fit_is_refused() {
    // Degree 9 in three axes on every output: 3 × 220 dense coefficients > FOLD_CAPACITY.
    let mut b = ModelBuilder::new(3, 0, 0).unwrap();
    for output in 0..3 {
        b.add_term(Term {
            output,
            powers: [3, 3, 3],
            factor: Factor::None,
            direction: 0,
            coeff: 1e-3,
        })
        .unwrap();
    }
    match b.build() {
        Err(nanocal_model::ModelError::FoldTooLarge { coefficients }) => {
            assert_eq!(coefficients, 660);
            assert!(coefficients as usize > nanocal_model::FOLD_CAPACITY);
        }
        other => panic!("expected FoldTooLarge, got {other:?}"),
    }
}
