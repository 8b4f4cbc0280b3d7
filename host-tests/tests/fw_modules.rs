//! The firmware's pure modules, natively: fault policy, management frames and chunked upload.
//! (GCS and the proxy: `gcs_proxy.rs`, `proxy_property.rs`; sensors: `fw_sensors.rs`; the
//! store: `fw_store.rs`.)

use nanocal::papers::published::published_1dof;
use nanocal_compensator::fault::{ChannelState, Faults, Policy};
use nanocal_compensator::sensor::SensorFault;
use nanocal_compensator::upload::{Upload, UploadError};
use nanocal_interface::identity::ResetCause;
use nanocal_interface::led::LedState;
use nanocal_interface::mgmt::{self, Decoder, FrameError, Kind, Reader, Refusal, Writer};
use nanocal_interface::status::{ChannelBits, ChannelStatus, Flags, Status};
use nanocal_interface::GcsErrorCode;
use nanocal_model::blob;
use nanocal_model::Model;
use proptest::prelude::*;

// ---------------------------------------------------------------- sensors and faults

#[test]
fn fault_policy_holds_then_blocks_then_recovers() {
    let policy = Policy {
        hold_ms: 1000,
        recover_count: 2,
        ..Policy::default()
    };
    let mut f: Faults = Faults::new(policy);
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
    let n = mgmt::encode(Kind::Status.code(), 7, b"", &mut buf).unwrap();
    wire.extend_from_slice(&buf[..n]);
    let n = mgmt::encode(Kind::UploadChunk.code(), 8, &[1, 2, 3, 4, 5], &mut buf).unwrap();
    let mut bad = buf[..n].to_vec();
    bad[7] ^= 0xFF;
    wire.extend_from_slice(&bad);
    wire.extend_from_slice(&buf[..n]);
    let mut d = Decoder::new();
    let mut got = vec![];
    for &b in &wire {
        let mut ev = d.feed(b, 0);
        while let Some(e) = ev {
            got.push(e.map(|()| {
                let f = d.frame();
                (f.kind, f.seq, f.payload.to_vec())
            }));
            ev = d.next(0);
        }
    }
    assert_eq!(
        got,
        vec![
            Ok((Kind::Status.code(), 7, vec![])),
            Err(FrameError::BadCrc),
            Ok((Kind::UploadChunk.code(), 8, vec![1, 2, 3, 4, 5])),
        ]
    );
}

#[test]
fn status_round_trips() {
    let bits = |b: u8| ChannelBits::from_code(b).unwrap();
    let s = Status {
        flags: Flags::MODEL | Flags::SENSOR_BLOCK,
        model_id: 0x1234,
        model_crc32: 0x5678_9ABC,
        move_fold: 9,
        temps_c: core::array::from_fn(|i| 20.0 + i as f32 * 0.25),
        sensor_bits: [0, 1, 2, 0, 0, 0, 0, 4, 0, 0, 0, 0, 0, 0, 0, 0x14].map(bits),
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
        pending_error: Some(GcsErrorCode::OutsideEnvelope),
        last_upload_error: Some(Refusal::UploadCrc),
        uptime_ms: 12345,
        uid: *b"0123456789AB",
        reset_cause: ResetCause::Watchdog,
        led: LedState::NoModel,
        fold_age_ms: 250,
        flash_ecc_errors: 2,
        sensor_reconfigs: 1,
        aux: [1013.25, f32::NAN, 0.0, -1.0],
        aux_bits: [0, 4, 0, 0].map(bits),
        stale: nanocal_interface::status::StaleReasons::KMZ_OUTSIDE_INTERVAL,
        stale_since_ms: 12_000,
        kmz_residual_um: [0.2, 0.0, 0.0],
        kmz_limit_um: [0.05, 0.0, 0.0],
        envelope_excess_c: -0.5,
        stage: nanocal_interface::status::StageCheck::Mismatch,
        model_serial: nanocal_model::StageSerial::new(b"0116044408"),
        controller_serial: None,
        follow_reissues: 11,
        follow_refused: 1,
    };
    assert_eq!(s.sensor_bits[15].state, ChannelStatus::NotRead);
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
    #![proptest_config(ProptestConfig {
        // the same cases on every run (deterministic tests; a new case goes in by its seed)
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x6e61_6e6f_6361_6c00),
        ..ProptestConfig::with_cases(2_000)
    })]

    #[test]
    fn management_decoder_and_upload_never_panic(
        bytes in proptest::collection::vec(any::<u8>(), 0..2000),
        offsets in proptest::collection::vec(0u32..4000, 0..20),
    ) {
        let mut d = Decoder::new();
        for &b in &bytes {
            let mut ev = d.feed(b, 0);
            while let Some(e) = ev {
                if e.is_ok() {
                    let f = d.frame();
                    let _ = Status::decode(&mut Reader::new(f.payload));
                }
                ev = d.next(0);
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
    // each error its own result code, 1..=9 as the protocol has them (0 is success)
    let codes: Vec<u8> = errors.iter().map(|e| e.code().code()).collect();
    assert_eq!(codes, (1..=9).collect::<Vec<u8>>());
    for e in errors {
        assert_eq!(Refusal::from_code(e.code().code()), Some(e.code()), "{e}");
    }
}
