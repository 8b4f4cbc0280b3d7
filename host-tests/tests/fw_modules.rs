//! The firmware's pure modules, natively: GCS parsing, the proxy with the real fold, sensor
//! frames, fault policy, management frames, chunked upload and two-slot storage.

use nanocal::published::{coupled_2dof, published_1dof};
use nanocal_compensator::fault::{ChannelState, Faults, Policy};
use nanocal_compensator::gcs::{self, Feed, LineAssembler, LineBuf};
use nanocal_compensator::mgmt::{self, Decoder, FrameError, Reader, Status, Writer};
use nanocal_compensator::proxy::{codes, FoldCorrector, Gate, Out, Proxy, Route};
use nanocal_compensator::sensor::SensorFault;
use nanocal_compensator::upload::{Upload, UploadError};
use nanocal_model::blob;
use nanocal_model::{Model, SlowInputs, MAX_AXES};
use proptest::prelude::*;

fn slow(temps: &[f64]) -> SlowInputs {
    let mut s = SlowInputs::default();
    s.temps_c[..temps.len()].copy_from_slice(temps);
    s
}

fn text(b: &[u8]) -> &str {
    std::str::from_utf8(b).unwrap()
}

// ---------------------------------------------------------------- GCS

#[test]
fn numbers_parse_like_gcs_writes_them() {
    for (s, v) in [
        ("0", 0.0),
        ("12.5", 12.5),
        ("-3", -3.0),
        ("+4.25", 4.25),
        (".5", 0.5),
        ("1e-3", 1e-3),
        ("4.5E2", 450.0),
        ("123.456789", 123.456789),
        ("0.000100", 1e-4),
    ] {
        let got = gcs::parse_f64(s.as_bytes()).unwrap();
        assert!(
            (got - v).abs() <= 4.0 * f64::EPSILON * v.abs(),
            "{s}: {got}"
        );
    }
    for s in ["", "-", "1.2.3", "abc", "1e", "1e1234", "--1", "1 "] {
        assert!(gcs::parse_f64(s.as_bytes()).is_err(), "{s}");
    }
}

proptest! {
    #[test]
    fn fixed_format_round_trips(v in -1.0e6f64..1.0e6) {
        let mut b = LineBuf::<32>::new();
        b.push_fixed(v, 6).unwrap();
        let back = gcs::parse_f64(b.as_bytes()).unwrap();
        prop_assert!((back - v).abs() <= 0.5e-6 + 1e-9, "{v} -> {} -> {back}", text(b.as_bytes()));
    }

    #[test]
    fn parse_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..40)) {
        let _ = gcs::parse_f64(&bytes);
        let _ = gcs::parse_pairs(&bytes);
        let _ = gcs::parse_axis_value(&bytes);
        let _ = gcs::split(&bytes);
    }
}

#[test]
fn split_keeps_address_prefix_and_args() {
    let s = gcs::split(b"1 0 MOV 1 10.5 2 3");
    assert_eq!(s.prefix, b"1 0 ");
    assert_eq!(s.command, b"MOV");
    assert_eq!(s.args, b"1 10.5 2 3");
    let s = gcs::split(b"POS?\r");
    assert_eq!(
        (s.prefix, s.command, s.args),
        (&b""[..], &b"POS?"[..], &b""[..])
    );
    let pairs = gcs::parse_pairs(b"1 10.5 2 -3").unwrap();
    assert_eq!(pairs.as_slice(), &[(&b"1"[..], 10.5), (&b"2"[..], -3.0)]);
    assert_eq!(
        gcs::parse_pairs(b"1 2 1 3").unwrap_err(),
        gcs::GcsError::DuplicateAxis
    );
    assert_eq!(
        gcs::parse_pairs(b"1").unwrap_err(),
        gcs::GcsError::MissingValue
    );
    let av = gcs::parse_axis_value(b"0 1 2=12.5 ").unwrap();
    assert_eq!(
        (av.prefix, av.axis, av.value, av.continued),
        (&b"0 1 "[..], &b"2"[..], 12.5, true)
    );
}

#[test]
fn assembler_separates_lines_and_single_char_commands() {
    let mut a = LineAssembler::new();
    let mut got = vec![];
    for &b in b"\x05MOV 1 1\n\x18POS?\n" {
        match a.feed(b) {
            Feed::Line => got.push(text(a.line()).to_string()),
            Feed::Single(c) => got.push(format!("#{c}")),
            _ => {}
        }
    }
    assert_eq!(got, ["#5", "MOV 1 1", "#24", "POS?"]);
    let mut a = LineAssembler::new();
    let long = vec![b'A'; gcs::MAX_LINE + 10];
    assert!(long.iter().all(|&b| a.feed(b) == Feed::Pending));
    assert_eq!(a.feed(b'\n'), Feed::Overflow);
}

// ---------------------------------------------------------------- proxy

fn corrector(model: &Model, temps: &[f64]) -> FoldCorrector {
    FoldCorrector::new(model, &slow(temps))
}

fn host(p: &mut Proxy, c: Option<&FoldCorrector>, line: &str) -> (Route, String) {
    let mut out = Out::new();
    let r = p.host_line(c, line.as_bytes(), &mut out);
    (r, text(out.as_bytes()).to_string())
}

fn stage(p: &mut Proxy, c: Option<&FoldCorrector>, line: &str) -> (Route, String) {
    let mut out = Out::new();
    let r = p.stage_line(c, line.as_bytes(), &mut out);
    (r, text(out.as_bytes()).to_string())
}

fn forwarded_values(line: &str) -> Vec<(String, f64)> {
    let t: Vec<&str> = line.split_whitespace().collect();
    assert_eq!(t[0], "MOV", "{line}");
    t[1..]
        .chunks(2)
        .map(|c| (c[0].to_string(), c[1].parse().unwrap()))
        .collect()
}

#[test]
fn mov_and_mvr_are_corrected_like_the_f64_reference() {
    let model = published_1dof().unwrap();
    let temps = [22.0, 22.1, 21.9, 22.3];
    let c = corrector(&model, &temps);
    let mut p = Proxy::default();
    let mut x = 100.0;
    let (r, line) = host(&mut p, Some(&c), "MOV 1 100");
    assert_eq!(r, Route::Stage);
    let q = forwarded_values(&line)[0].1;
    let want = model.eval_f64(&[x, 0.0, 0.0], &[0; MAX_AXES], &slow(&temps))[0];
    assert!((q - want).abs() <= 1e-4, "{q} vs {want}");
    // MVR becomes an absolute MOV, moving forward
    let (r, line) = host(&mut p, Some(&c), "MVR 1 12.5");
    assert_eq!(r, Route::Stage);
    x += 12.5;
    let q = forwarded_values(&line)[0].1;
    let want = model.eval_f64(&[x, 0.0, 0.0], &[1, 0, 0], &slow(&temps))[0];
    assert!((q - want).abs() <= 1e-4, "{q} vs {want}");
    assert_eq!(p.targets_um()[0], Some(112.5));
    assert_eq!(p.pending_error(), 0);
}

#[test]
fn refused_moves_forward_nothing_and_surface_on_err() {
    let model = published_1dof().unwrap();
    let c = corrector(&model, &[22.0; 4]);
    let mut p = Proxy::default();
    // outside the training envelope (0..480)
    assert_eq!(
        host(&mut p, Some(&c), "MOV 1 490"),
        (Route::None, String::new())
    );
    assert_eq!(
        host(&mut p, Some(&c), "ERR?"),
        (Route::Host, "9001\n".into())
    );
    // the next ERR? goes to the controller again
    assert_eq!(host(&mut p, Some(&c), "ERR?").0, Route::Stage);
    // no model
    assert_eq!(host(&mut p, None, "MOV 1 10").0, Route::None);
    assert_eq!(
        host(&mut p, None, "ERR?").1,
        format!("{}\n", codes::NO_MODEL)
    );
    // sensor gate
    p.gate = Gate::SensorFault;
    assert_eq!(host(&mut p, Some(&c), "MOV 1 10").0, Route::None);
    assert_eq!(
        host(&mut p, Some(&c), "ERR?").1,
        format!("{}\n", codes::SENSOR_FAULT)
    );
    p.gate = Gate::Open;
    // MVR without a known target, bad number
    assert_eq!(host(&mut p, Some(&c), "MVR 1 1").0, Route::None);
    assert_eq!(
        host(&mut p, Some(&c), "ERR?").1,
        format!("{}\n", codes::TARGET_UNKNOWN)
    );
    assert_eq!(host(&mut p, Some(&c), "MOV 1 x").0, Route::None);
    assert_eq!(
        host(&mut p, Some(&c), "ERR?").1,
        format!("{}\n", codes::PARAM_SYNTAX)
    );
    assert_eq!(p.counters.refused, 5);
    assert_eq!(p.counters.moves, 0);
}

#[test]
fn travel_limit_is_checked_in_command_space() {
    // inside the envelope but the command leaves a narrow travel
    let model = published_1dof().unwrap();
    let mut c = corrector(&model, &[22.0; 4]);
    c.travel_um[0] = (0.0, 100.0);
    let mut p = Proxy::default();
    assert_eq!(host(&mut p, Some(&c), "MOV 1 300").0, Route::None);
    assert_eq!(host(&mut p, Some(&c), "ERR?").1, "7\n");
}

#[test]
fn everything_else_passes_untouched_and_replies_are_relayed() {
    let model = published_1dof().unwrap();
    let c = corrector(&model, &[22.0; 4]);
    let mut p = Proxy::default();
    for l in ["*IDN?", "SVO 1 1", "VEL 1 10", "1 0 ONT? 1"] {
        assert_eq!(host(&mut p, Some(&c), l), (Route::Stage, format!("{l}\n")));
    }
    let mut out = Out::new();
    assert_eq!(p.host_single(0x05, &mut out), Route::Stage);
    assert_eq!(out.as_bytes(), b"\x05");
    for l in ["PI E-709 fake", "1=1", "1=1", "0 1 1=1", "0"] {
        assert_eq!(stage(&mut p, Some(&c), l), (Route::Host, format!("{l}\n")));
    }
    // bypass forwards moves untouched
    p.bypass = true;
    assert_eq!(
        host(&mut p, Some(&c), "MOV 1 10"),
        (Route::Stage, "MOV 1 10\n".into())
    );
}

#[test]
fn pos_and_mov_replies_map_back_through_the_inverse() {
    let model = coupled_2dof().unwrap();
    let temps = [22.0, 22.5, 21.5, 23.0];
    let c = corrector(&model, &temps);
    let mut p = Proxy::default();
    // (the reference model's y offset keeps y ≥ ~40 µm inside the travel)
    let (_, line) = host(&mut p, Some(&c), "MOV 1 40 2 70");
    assert_eq!(p.pending_error(), 0);
    let fwd = forwarded_values(&line);
    assert_eq!(fwd.len(), 2);
    // a later single-axis MOV re-commands the coupled axis too
    let (_, line) = host(&mut p, Some(&c), "MOV 1 50");
    let fwd = forwarded_values(&line);
    assert_eq!(fwd.len(), 2, "{line}");
    let want = model.eval_f64(&[50.0, 70.0, 0.0], &[1, 0, 0], &slow(&temps));
    assert!((fwd[0].1 - want[0]).abs() <= 1e-4 && (fwd[1].1 - want[1]).abs() <= 1e-4);
    // the controller reports exactly those commands: the host sees its targets again
    assert_eq!(host(&mut p, Some(&c), "POS?").0, Route::Stage);
    let l1 = format!("1={:.6} ", fwd[0].1);
    let l2 = format!("2={:.6}", fwd[1].1);
    assert_eq!(stage(&mut p, Some(&c), &l1), (Route::None, String::new()));
    let (r, reply) = stage(&mut p, Some(&c), &l2);
    assert_eq!(r, Route::Host);
    let lines: Vec<&str> = reply.split('\n').collect();
    assert!(lines[0].ends_with(' '), "{reply:?}");
    let x: f64 = lines[0].trim().strip_prefix("1=").unwrap().parse().unwrap();
    let y: f64 = lines[1].strip_prefix("2=").unwrap().parse().unwrap();
    assert!(
        (x - 50.0).abs() <= 2e-4 && (y - 70.0).abs() <= 2e-4,
        "{reply}"
    );
    assert_eq!(p.counters.mapped_replies, 1);

    // a query the controller never answers (invalid: it only sets its error) does not shift
    // the attribution of the next reply
    assert_eq!(host(&mut p, Some(&c), "FOO?").0, Route::Stage);
    assert_eq!(host(&mut p, Some(&c), "POS? 1").0, Route::Stage);
    let (r, reply) = stage(&mut p, Some(&c), &format!("1={:.6}", fwd[0].1));
    assert_eq!(r, Route::Host);
    assert!(
        reply.starts_with("1=49.99") || reply.starts_with("1=50.00"),
        "{reply}"
    );
    assert_eq!(p.counters.mapped_replies, 2);
}

// ---------------------------------------------------------------- sensors and faults

#[test]
fn fault_policy_holds_then_blocks_then_recovers() {
    let policy = Policy {
        hold_ms: 1000,
        recover_count: 2,
        ..Policy::default()
    };
    let mut f = Faults::new(policy);
    assert!(f.blocks_moves(1), "never read: blocks");
    f.update(0, Ok(22.0), 0);
    assert!(!f.blocks_moves(1));
    f.update(0, Err(SensorFault::Open), 100);
    assert!(matches!(f.channels[0].state, ChannelState::Holding { .. }));
    assert_eq!(f.channels[0].value_c(), Some(22.0), "last good value held");
    assert!(!f.blocks_moves(1));
    f.update(0, Err(SensorFault::Open), 1100);
    assert!(f.blocks_moves(1), "hold time over");
    assert_eq!(f.channels[0].value_c(), None);
    f.update(0, Ok(22.5), 1200);
    assert!(f.blocks_moves(1), "one good reading is not enough");
    f.update(0, Ok(22.6), 1300);
    assert!(!f.blocks_moves(1));
    assert_eq!(f.channels[0].value_c(), Some(22.6));
    // implausible values are faults too; unused channels do not block
    f.update(0, Ok(500.0), 1400);
    assert_eq!(f.channels[0].last_fault, Some(SensorFault::Implausible));
    assert!(!f.blocks_moves(0));
}

// ---------------------------------------------------------------- management frames

#[test]
fn frames_round_trip_and_resynchronise() {
    let mut wire = vec![0x00, 0xA7, 0x13]; // garbage, including a false sync start
    let mut buf = [0u8; mgmt::MAX_FRAME];
    let n = mgmt::encode(mgmt::kind::STATUS, 7, b"", &mut buf).unwrap();
    wire.extend_from_slice(&buf[..n]);
    let n = mgmt::encode(mgmt::kind::UPLOAD_CHUNK, 8, &[1, 2, 3, 4, 5], &mut buf).unwrap();
    let mut bad = buf[..n].to_vec();
    bad[7] ^= 0xFF;
    wire.extend_from_slice(&bad);
    wire.extend_from_slice(&buf[..n]);
    let mut d = Decoder::new();
    let mut got = vec![];
    for &b in &wire {
        match d.feed(b) {
            Some(Ok(())) => {
                let f = d.frame();
                got.push(Ok((f.kind, f.seq, f.payload.to_vec())));
            }
            Some(Err(e)) => got.push(Err(e)),
            None => {}
        }
    }
    assert_eq!(
        got,
        vec![
            Ok((mgmt::kind::STATUS, 7, vec![])),
            Err(FrameError::BadCrc),
            Ok((mgmt::kind::UPLOAD_CHUNK, 8, vec![1, 2, 3, 4, 5])),
        ]
    );
}

#[test]
fn status_round_trips() {
    let s = Status {
        flags: 5,
        model_id: 0x1234,
        slot: 1,
        slot_seq: 9,
        temps_c: [22.5; 8],
        sensor_bits: [0, 1, 2, 0, 0, 0, 0, 4],
        sensors: 4,
        slow_outside: 0x10,
        kmz_um: [0.1, -0.2, 0.0],
        host_lines: 1,
        moves: 2,
        refused: 3,
        mapped_replies: 4,
        uploads_ok: 5,
        uploads_rejected: 6,
        folds: 7,
        pending_error: 9001,
        last_upload_error: 8,
        uptime_ms: 12345,
        uid: *b"0123456789AB",
        reset_cause: 4,
        led: 3,
        fold_age_ms: 250,
        flash_ecc_errors: 2,
        sensor_reconfigs: 1,
        aux: [1013.25, f32::NAN, 0.0, -1.0],
        aux_bits: [0, 4, 0, 0],
    };
    let mut buf = [0u8; 320];
    let mut w = Writer::new(&mut buf);
    s.encode(&mut w).unwrap();
    assert_eq!(w.len(), Status::LEN);
    let n = w.len();
    let back = Status::decode(&mut Reader::new(&buf[..n])).unwrap();
    assert_eq!(back.aux[1].to_bits(), s.aux[1].to_bits());
    assert_eq!(
        Status {
            aux: [0.0; 4],
            ..back
        },
        Status { aux: [0.0; 4], ..s }
    );
}

// ---------------------------------------------------------------- upload and slots

fn blob_of(model: &Model) -> Vec<u8> {
    let mut b = vec![0u8; blob::MAX_BLOB_LEN];
    let n = blob::encode(model, &mut b).unwrap();
    b.truncate(n);
    b
}

fn upload_all(bytes: &[u8], announced_crc: u32, chunk: usize) -> Result<Model, UploadError> {
    let mut buf = vec![0u8; blob::MAX_BLOB_LEN];
    let mut u = Upload::new();
    u.begin(
        bytes.len() as u32,
        announced_crc,
        blob::FORMAT_VERSION,
        buf.len(),
    )?;
    for (i, c) in bytes.chunks(chunk).enumerate() {
        u.chunk(&mut buf, (i * chunk) as u32, c)?;
    }
    u.finish(&buf).map(|(m, _)| m)
}

#[test]
fn upload_accepts_a_good_blob_and_rejects_everything_else() {
    let model = published_1dof().unwrap();
    let b = blob_of(&model);
    let crc = blob::crc32(&b);
    assert_eq!(upload_all(&b, crc, 100).unwrap().id(), model.id());
    assert!(matches!(
        upload_all(&b, crc ^ 1, 100),
        Err(UploadError::CrcMismatch { .. })
    ));
    // a corrupted byte with a matching whole-blob CRC is still caught by the blob's own checks
    let mut bad = b.clone();
    bad[20] ^= 0x40;
    assert!(matches!(
        upload_all(&bad, blob::crc32(&bad), 64),
        Err(UploadError::Blob(_))
    ));
    // truncated
    let mut buf = vec![0u8; blob::MAX_BLOB_LEN];
    let mut u = Upload::new();
    u.begin(b.len() as u32, crc, blob::FORMAT_VERSION, buf.len())
        .unwrap();
    u.chunk(&mut buf, 0, &b[..50]).unwrap();
    assert!(matches!(
        u.finish(&buf),
        Err(UploadError::Incomplete { .. })
    ));
    // version, order, retransmission, overrun
    assert!(matches!(
        u.begin(10, 0, blob::FORMAT_VERSION + 1, buf.len()),
        Err(UploadError::VersionMismatch { .. })
    ));
    u.begin(b.len() as u32, crc, blob::FORMAT_VERSION, buf.len())
        .unwrap();
    assert_eq!(u.chunk(&mut buf, 0, &b[..50]), Ok(50));
    assert_eq!(u.chunk(&mut buf, 0, &b[..50]), Ok(50), "retransmission");
    assert_eq!(
        u.chunk(&mut buf, 0, &b[1..51]),
        Err(UploadError::ChunkMismatch)
    );
    assert!(matches!(
        u.chunk(&mut buf, 60, &b[60..70]),
        Err(UploadError::OutOfOrder { .. })
    ));
    assert_eq!(u.chunk(&mut buf, 50, &b[50..]), Ok(b.len() as u32));
    assert_eq!(
        u.chunk(&mut buf, b.len() as u32, &[0]),
        Err(UploadError::Overrun)
    );
    assert!(u.finish(&buf).is_ok());
    assert_eq!(u.finish(&buf).unwrap_err(), UploadError::NotStarted);
}

// ---------------------------------------------------------------- no panics on external input

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2_000))]

    #[test]
    fn proxy_never_panics_on_any_bytes(
        host_lines in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..60), 0..8),
        stage_lines in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..60), 0..8),
        prefix in prop_oneof![Just("MOV 1 "), Just("MVR 1 "), Just("POS? "), Just("1=")],
    ) {
        let model = published_1dof().unwrap();
        let c = corrector(&model, &[22.0; 4]);
        let mut p = Proxy::default();
        let mut out = Out::new();
        let mut asm = LineAssembler::new();
        for (h, s) in host_lines.iter().zip(stage_lines.iter().chain(std::iter::repeat(&vec![]))) {
            let mut line = prefix.as_bytes().to_vec();
            line.extend_from_slice(h);
            line.push(b'\n');
            for &b in &line {
                let feed = asm.feed(b);
                let _ = p.host_feed(Some(&c), feed, asm.line(), &mut out);
            }
            let _ = p.stage_line(Some(&c), s, &mut out);
            let _ = p.host_line(None::<&FoldCorrector>, h, &mut out);
        }
    }

    #[test]
    fn management_decoder_and_upload_never_panic(
        bytes in proptest::collection::vec(any::<u8>(), 0..2000),
        offsets in proptest::collection::vec(0u32..4000, 0..20),
    ) {
        let mut d = Decoder::new();
        for &b in &bytes {
            if let Some(Ok(())) = d.feed(b) {
                let f = d.frame();
                let _ = Status::decode(&mut Reader::new(f.payload));
            }
        }
        let mut buf = vec![0u8; blob::MAX_BLOB_LEN];
        let mut u = Upload::new();
        let _ = u.begin(bytes.len() as u32, 0, blob::FORMAT_VERSION, buf.len());
        for o in offsets {
            let end = (o as usize % (bytes.len() + 1)).min(bytes.len());
            let _ = u.chunk(&mut buf, o, &bytes[..end]);
        }
        let _ = u.finish(&buf);
    }
}

#[test]
fn every_upload_error_code_has_a_meaning() {
    use nanocal_model::blob::BlobError;
    let errors = [
        UploadError::NotStarted,
        UploadError::VersionMismatch {
            found: 2,
            expected: 1,
        },
        UploadError::BadLength { len: 0, max: 1 },
        UploadError::OutOfOrder {
            expected: 0,
            found: 1,
        },
        UploadError::Overrun,
        UploadError::ChunkMismatch,
        UploadError::Incomplete {
            expected: 2,
            received: 1,
        },
        UploadError::CrcMismatch {
            expected: 1,
            computed: 2,
        },
        UploadError::Blob(BlobError::BadMagic),
    ];
    for e in errors {
        assert_ne!(mgmt::result_meaning(e.code()), "unknown code", "{e}");
        assert_ne!(e.code(), mgmt::RESULT_OK);
    }
}
