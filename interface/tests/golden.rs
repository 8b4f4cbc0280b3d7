//! Golden bytes: every management request and reply, the status, the settings and the QEMU
//! bus frames, against byte arrays written out by an independent encoder of the documented
//! layouts (`tests/golden/encode.py`: Python's `struct` and `zlib.crc32`). A round trip alone passes
//! when both sides change together; these fail when the bytes change at all.

use nanocal_interface::bus::{BusOp, BusReply, BusRequest, BusStatus};
use nanocal_interface::identity::{ResetCause, Site};
use nanocal_interface::led::LedState;
use nanocal_interface::mgmt::{
    self, Decoder, Hello, InputCode, InputWhy, Kind, Reader, Refusal, Reply, Request, Writer,
};
use nanocal_interface::settings::{AuxSource, AxisId, Chip, Mains, Settings, TcType, Wires};
use nanocal_interface::status::{
    ChannelBits, ChannelStatus, Flags, SensorFault, StageCheck, StaleReasons, Status,
};
use nanocal_interface::GcsErrorCode;
use nanocal_model::StageSerial;

include!("golden/bytes.rs");

fn status() -> Status {
    let mut temps_c = [0.0; 16];
    temps_c[..3].copy_from_slice(&[20.5, 21.25, -1.5]);
    let mut sensor_bits = [ChannelBits::default(); 16];
    sensor_bits[1] = ChannelBits {
        state: ChannelStatus::Holding,
        last_fault: Some(SensorFault::Open),
    };
    sensor_bits[2] = ChannelBits {
        state: ChannelStatus::Failed,
        last_fault: Some(SensorFault::NoResponse),
    };
    sensor_bits[3] = ChannelBits {
        state: ChannelStatus::NotRead,
        last_fault: None,
    };
    let not_read = ChannelBits {
        state: ChannelStatus::NotRead,
        last_fault: None,
    };
    Status {
        flags: Flags::MODEL
            | Flags::EXTRAPOLATING
            | Flags::HOST_CONNECTED
            | Flags::MOVE_FOLD
            | Flags::MODEL_STALE
            | Flags::STAGE_MISMATCH,
        model_id: 0x0003_0001,
        model_crc32: 0x89AB_CDEF,
        move_fold: 41,
        temps_c,
        sensor_bits,
        sensors: 4,
        slow_outside: 0x10,
        kmz_um: [0.125, -0.5, 0.0],
        host_lines: 100,
        moves: 50,
        refused: 2,
        mapped_replies: 30,
        uploads_ok: 1,
        uploads_rejected: 1,
        folds: 42,
        pending_error: Some(GcsErrorCode::RefusedWhileCompensating),
        last_upload_error: Some(Refusal::UploadCrc),
        uptime_ms: 123_456,
        uid: *b"0123456789AB",
        reset_cause: ResetCause::Watchdog,
        led: LedState::Stale,
        fold_age_ms: 250,
        flash_ecc_errors: 0,
        sensor_reconfigs: 3,
        aux: [1013.25, 0.0, 0.0, 0.0],
        aux_bits: [ChannelBits::default(), not_read, not_read, not_read],
        stale: StaleReasons::BEYOND_ENVELOPE,
        stale_since_ms: 100_000,
        kmz_residual_um: [0.25, -0.125, 0.0],
        kmz_limit_um: [0.09375, 0.0, 0.0],
        envelope_excess_c: 0.5,
        stage: StageCheck::MismatchAllowed,
        model_serial: StageSerial::new(b"0116044408"),
        controller_serial: StageSerial::new(b"0116044999"),
        follow_reissues: 17,
        follow_refused: 3,
    }
}

fn custom_settings() -> Settings {
    let mut s = Settings {
        stage_baud: 57_600,
        mains: Mains::Hz60,
        sample_period_ms: 500,
        fold_period_ms: 8_000,
        stale_k: 2.5,
        extrapolation_c: 0.25,
        allow_other_stage: true,
        follow_nm: 5,
        follow_interval_ms: 2_000,
        follow_step_nm: 20,
        ..Settings::default()
    };
    s.sensors = [None; 16];
    s.sensors[0] = Some(Chip::K);
    s.sensors[1] = Some(Chip::Max31856 { tc: TcType::T });
    s.sensors[2] = Some(Chip::PT100_3W);
    s.sensors[3] = Some(Chip::Max31865 {
        r_ref_ohm: 4300.0,
        r0_ohm: 1000.0,
        wires: Wires::Four,
    });
    s.axis_names = [
        AxisId::new(b"X").unwrap(),
        AxisId::new(b"Y").unwrap(),
        AxisId::new(b"3").unwrap(),
    ];
    s.aux[0] = AuxSource::AirPressure;
    s.aux[1] = AuxSource::Force {
        channel: 0,
        scale_n_per_count: 0.01,
        offset_n: -20.48,
    };
    s
}

/// Decode a whole frame with the byte-wise decoder (garbage in front, to resynchronise).
fn deframe(bytes: &[u8]) -> (u8, u8, Vec<u8>) {
    let mut d = Decoder::new();
    let mut got = None;
    for &b in [0x00, 0xA7, 0x00].iter().chain(bytes) {
        let mut ev = d.feed(b, 0);
        while let Some(r) = ev {
            r.unwrap();
            let f = d.frame();
            got = Some((f.kind, f.seq, f.payload.to_vec()));
            ev = d.next(0);
        }
    }
    got.expect("a complete frame")
}

/// The request encodes to `golden` and `golden` decodes to the request.
fn request_is(req: Request<'_>, seq: u8, golden: &[u8]) {
    let mut out = [0u8; mgmt::MAX_FRAME];
    let n = req.frame(seq, &mut out).unwrap();
    assert_eq!(&out[..n], golden, "{req:?} encodes to its golden bytes");
    let (kind, s, payload) = deframe(golden);
    assert_eq!((kind, s), (req.kind().code(), seq));
    assert_eq!(Request::decode(kind, &payload).unwrap(), req);
}

/// The reply to `kind` encodes to `golden` and `golden` decodes to the reply.
fn reply_is(reply: Reply, kind: u8, seq: u8, golden: &[u8]) {
    let mut out = [0u8; mgmt::MAX_FRAME];
    let mut w = Writer::new(&mut out[mgmt::PAYLOAD_AT..][..mgmt::MAX_PAYLOAD]);
    reply.encode(&mut w).unwrap();
    let len = w.len();
    let n = mgmt::seal(kind | mgmt::REPLY, seq, len, &mut out).unwrap();
    assert_eq!(&out[..n], golden, "{reply:?} encodes to its golden bytes");
    let (k, s, payload) = deframe(golden);
    assert_eq!((k, s), (kind | mgmt::REPLY, seq));
    let kind = Kind::from_code(kind).unwrap();
    assert_eq!(Reply::decode(kind, &payload).unwrap(), reply);
}

#[test]
fn crc32_is_iso_hdlc() {
    // the published check value of CRC-32/ISO-HDLC (Greg Cook's catalogue; zlib's crc32)
    assert_eq!(nanocal_interface::crc32(b"123456789"), 0xCBF4_3926);
    assert_eq!(nanocal_interface::crc32(b""), 0);
}

#[test]
fn status_bytes() {
    let mut b = [0u8; Status::LEN];
    let mut w = Writer::new(&mut b);
    status().encode(&mut w).unwrap();
    assert_eq!(w.len(), Status::LEN);
    assert_eq!(b, STATUS_BYTES);
    assert_eq!(
        Status::decode(&mut Reader::new(&STATUS_BYTES)).unwrap(),
        status()
    );
}

#[test]
fn settings_bytes() {
    assert_eq!(Settings::default().encode(), SETTINGS_DEFAULT);
    assert_eq!(
        Settings::decode(&SETTINGS_DEFAULT).unwrap(),
        Settings::default()
    );
    assert_eq!(custom_settings().encode(), SETTINGS_CUSTOM);
    assert_eq!(
        Settings::decode(&SETTINGS_CUSTOM).unwrap(),
        custom_settings()
    );
    use nanocal_interface::settings::{
        DEFAULT_EXTRAPOLATION_C, DEFAULT_FOLD_PERIOD_MS, DEFAULT_FOLLOW_INTERVAL_MS,
        DEFAULT_STALE_K,
    };
    // records before layout 6 decode with other stages refused and following off
    let unfollowed = Settings {
        allow_other_stage: false,
        follow_nm: 0,
        follow_interval_ms: DEFAULT_FOLLOW_INTERVAL_MS,
        follow_step_nm: 0,
        ..custom_settings()
    };
    assert_eq!(Settings::decode(&SETTINGS_CUSTOM_V5).unwrap(), unfollowed);
    // a layout 4 record (stored by a firmware before the stage unit was dropped, here mm, a unit
    // the firmware never applied) decodes to the same settings
    assert_eq!(Settings::decode(&SETTINGS_CUSTOM_V4).unwrap(), unfollowed);
    // a layout 3 record (stored by a firmware before the stale check) decodes with its defaults
    assert_eq!(
        Settings::decode(&SETTINGS_CUSTOM_V3).unwrap(),
        Settings {
            stale_k: DEFAULT_STALE_K,
            extrapolation_c: DEFAULT_EXTRAPOLATION_C,
            ..unfollowed
        }
    );
    // a layout 2 record (stored by a firmware before the fold period) decodes with the defaults
    assert_eq!(
        Settings::decode(&SETTINGS_CUSTOM_V2).unwrap(),
        Settings {
            fold_period_ms: DEFAULT_FOLD_PERIOD_MS,
            stale_k: DEFAULT_STALE_K,
            extrapolation_c: DEFAULT_EXTRAPOLATION_C,
            ..unfollowed
        }
    );
}

#[test]
fn every_request_frame() {
    request_is(Request::Hello, 1, &REQ_HELLO);
    request_is(Request::Status, 2, &REQ_STATUS);
    request_is(
        Request::UploadBegin {
            total_len: 1234,
            crc32: 0xDEAD_BEEF,
            format_version: 2,
        },
        3,
        &REQ_UPLOAD_BEGIN,
    );
    request_is(
        Request::UploadChunk {
            offset: 256,
            bytes: &[1, 2, 3, 4],
        },
        4,
        &REQ_UPLOAD_CHUNK,
    );
    request_is(Request::UploadCommit, 5, &REQ_UPLOAD_COMMIT);
    request_is(Request::UploadAbort, 6, &REQ_UPLOAD_ABORT);
    request_is(
        Request::SetKmz {
            q_cmd_um: [250.0, 0.0, 0.0],
            x_meas_um: [249.9, 0.0, 0.0],
        },
        7,
        &REQ_SET_KMZ,
    );
    request_is(Request::Bypass { on: true }, 8, &REQ_BYPASS);
    request_is(Request::ConfigGet, 9, &REQ_CONFIG_GET);
    request_is(Request::ConfigSet(custom_settings()), 10, &REQ_CONFIG_SET);
    request_is(Request::Reset, 11, &REQ_RESET);
    request_is(Request::DebugHang, 12, &REQ_DEBUG_HANG);
    // every kind has its golden request above
    assert_eq!(Kind::ALL.len(), 12);
}

#[test]
fn every_reply_frame() {
    let mut firmware = heapless::String::new();
    firmware.push_str("0.1.0").unwrap();
    let hello = Hello {
        protocol: 8,
        blob_format: 4,
        max_chunk: 256,
        firmware,
        uid: core::array::from_fn(|i| i as u8),
        reset_cause: ResetCause::Panic,
        reset_site: Site::Line {
            file: "src/bin/stm32.rs",
            line: 42,
        }
        .text(),
    };
    reply_is(Reply::Hello(hello), 0x01, 1, &REP_HELLO);
    reply_is(Reply::Status(status()), 0x02, 2, &REP_STATUS);
    reply_is(Reply::UploadBegin, 0x10, 3, &REP_UPLOAD_BEGIN);
    reply_is(
        Reply::UploadChunk { received: 260 },
        0x11,
        4,
        &REP_UPLOAD_CHUNK,
    );
    reply_is(
        Reply::UploadCommit {
            model_id: 0x0003_0001,
            model_crc32: 0x89AB_CDEF,
            uploads_accepted: 3,
        },
        0x12,
        5,
        &REP_UPLOAD_COMMIT,
    );
    reply_is(Reply::UploadAbort, 0x13, 6, &REP_UPLOAD_ABORT);
    reply_is(
        Reply::SetKmz {
            kmz_um: [0.125, 0.0, 0.0],
            stored: true,
        },
        0x20,
        7,
        &REP_SET_KMZ,
    );
    reply_is(Reply::Bypass, 0x21, 8, &REP_BYPASS);
    reply_is(
        Reply::ConfigGet(custom_settings()),
        0x30,
        9,
        &REP_CONFIG_GET,
    );
    reply_is(Reply::ConfigSet, 0x31, 10, &REP_CONFIG_SET);
    reply_is(Reply::Reset, 0x32, 11, &REP_RESET);
    reply_is(
        Reply::Refused {
            refusal: Refusal::Input,
            input: Some(InputCode {
                why: InputWhy::NoAuxSource,
                index: 0,
            }),
        },
        0x12,
        5,
        &REP_COMMIT_INPUT,
    );
    reply_is(Reply::refused(Refusal::UploadCrc), 0x12, 5, &REP_COMMIT_CRC);
    reply_is(
        Reply::refused(Refusal::UnknownKind),
        0x7E,
        12,
        &REP_UNKNOWN_KIND,
    );
}

#[test]
fn bus_frames() {
    let mut b = [0u8; 64];
    let req = BusRequest {
        op: BusOp::Spi,
        target: 3,
        data_out: &[0x0C, 0xFF],
        n_in: 2,
    };
    let n = req.encode(&mut b).unwrap();
    assert_eq!(b[..n], BUS_SPI_REQUEST);
    assert_eq!(BusRequest::decode(&BUS_SPI_REQUEST).unwrap(), req);
    for (reply, golden) in [
        (
            BusReply {
                op: BusOp::Spi,
                target: 3,
                status: BusStatus::Ok,
                data_in: &[0x00, 0x8A],
            },
            &BUS_SPI_REPLY[..],
        ),
        (
            BusReply {
                op: BusOp::I2c,
                target: 0x5C,
                status: BusStatus::Nack,
                data_in: &[],
            },
            &BUS_I2C_NACK[..],
        ),
        (
            BusReply {
                op: BusOp::Adc,
                target: 0,
                status: BusStatus::NoAnswer,
                data_in: &[],
            },
            &BUS_ADC_NO_ANSWER[..],
        ),
    ] {
        let n = reply.encode(&mut b).unwrap();
        assert_eq!(&b[..n], golden);
        assert_eq!(BusReply::decode(golden).unwrap(), reply);
    }
}

#[test]
fn the_stale_check_settings_are_range_checked_with_their_offsets() {
    use nanocal_interface::settings::SettingsError;
    for k in [0.0, -1.0, f32::NAN, 100.5] {
        let s = Settings {
            stale_k: k,
            ..Settings::default()
        };
        assert_eq!(s.validate(), Err(SettingsError::Field(242)), "k = {k}");
    }
    for m in [-0.01, f32::NAN, 51.0] {
        let s = Settings {
            extrapolation_c: m,
            ..Settings::default()
        };
        assert_eq!(s.validate(), Err(SettingsError::Field(246)), "margin = {m}");
    }
    let edge = Settings {
        stale_k: 100.0,
        extrapolation_c: 0.0,
        ..Settings::default()
    };
    assert_eq!(Settings::decode(&edge.encode()), Ok(edge));
}

#[test]
fn the_follow_settings_are_range_checked_with_their_offsets() {
    use nanocal_interface::settings::SettingsError;
    let s = Settings {
        follow_nm: 10_001,
        ..Settings::default()
    };
    assert_eq!(s.validate(), Err(SettingsError::Field(251)));
    for ms in [0, 99, 60_001] {
        let s = Settings {
            follow_interval_ms: ms,
            ..Settings::default()
        };
        assert_eq!(s.validate(), Err(SettingsError::Field(253)), "{ms} ms");
    }
    let edge = Settings {
        follow_nm: 10_000,
        follow_interval_ms: 100,
        follow_step_nm: u16::MAX,
        ..Settings::default()
    };
    assert_eq!(Settings::decode(&edge.encode()), Ok(edge));
}
