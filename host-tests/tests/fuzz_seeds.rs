//! The fuzz targets' seed corpus (`fuzz/seeds/<target>/`) in the normal test suite: every
//! committed input — the meaningful seeds and every input a fuzz run found crashing, kept there
//! once fixed — goes through the same check its target runs (`fuzz/src/checks.rs`), so a fixed
//! crash stays fixed without cargo-fuzz. The seeds this file makes must match the committed
//! ones (a format change shows here): `NANOCAL_WRITE_FUZZ_SEEDS=1 cargo test --test fuzz_seeds`
//! writes them again.

mod proxy_rig;

#[path = "../../fuzz/src/checks.rs"]
#[allow(dead_code)]
mod checks;

use nanocal::papers::published::{coupled_2dof, published_1dof};
use nanocal_interface::mgmt::{self, Kind, Writer};
use nanocal_interface::settings::{AuxSource, Settings};
use nanocal_interface::status::Status;
use nanocal_model::blob;
use std::path::{Path, PathBuf};

/// A reply's first payload byte when the request succeeded (`nanocal_interface::mgmt`'s table).
const RESULT_OK: u8 = 0;

fn seeds_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz/seeds")
}

/// A target's check.
type Check = fn(&[u8]);

/// The targets and their checks.
const TARGETS: &[(&str, Check)] = &[
    ("blob", checks::blob),
    ("mgmt_frames", checks::mgmt_frames),
    ("settings", checks::settings),
    ("upload", checks::upload),
    ("gcs_proxy", checks::gcs_proxy),
    ("reference_lines", checks::reference_lines),
    ("recording_csv", checks::recording_csv),
];

#[test]
fn every_committed_fuzz_input_passes_its_check() {
    let mut total = 0;
    for (target, check) in TARGETS {
        let dir = seeds_dir().join(target);
        let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
            .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
            .map(|e| e.unwrap().path())
            .collect();
        files.sort();
        assert!(!files.is_empty(), "no seeds for {target}");
        for f in files {
            let bytes = std::fs::read(&f).unwrap();
            let name = f.display().to_string();
            if let Err(e) = std::panic::catch_unwind(|| check(&bytes)) {
                let msg = e
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| e.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_default();
                panic!("{name}: {msg}");
            }
            total += 1;
        }
    }
    println!("{total} committed fuzz inputs pass their checks");
}

fn blob_of(m: &nanocal_model::Model) -> Vec<u8> {
    let mut b = vec![0u8; blob::MAX_BLOB_LEN];
    let n = blob::encode(m, &mut b).unwrap();
    b.truncate(n);
    b
}

fn frame(k: u8, seq: u8, payload: &[u8]) -> Vec<u8> {
    let mut f = [0u8; mgmt::MAX_FRAME];
    let n = mgmt::encode(k, seq, payload, &mut f).unwrap();
    f[..n].to_vec()
}

/// `[kind, seq, len, payload…]` for the mgmt target's sealed mode.
fn unsealed(k: u8, seq: u8, payload: &[u8]) -> Vec<u8> {
    let mut v = vec![k, seq, payload.len() as u8];
    v.extend_from_slice(payload);
    v
}

/// The gcs_proxy target's ops: a dictionary line, raw bytes, time.
fn line(l: &[u8]) -> Vec<u8> {
    let i = checks_lines()
        .iter()
        .position(|x| *x == l)
        .expect("in the dictionary");
    vec![4, i as u8]
}
fn raw(b: &[u8]) -> Vec<u8> {
    b.chunks(31)
        .flat_map(|c| {
            let mut v = vec![(c.len() as u8) << 3];
            v.extend_from_slice(c);
            v
        })
        .collect()
}
const SETTLE: u8 = 7;
fn checks_lines() -> &'static [&'static [u8]] {
    checks::GCS_LINES
}

/// The seeds: (target, file name, bytes).
fn seeds() -> Vec<(&'static str, &'static str, Vec<u8>)> {
    let m1 = published_1dof().unwrap();
    let m2 = coupled_2dof().unwrap();
    let b1 = blob_of(&m1);
    let mut s = vec![];
    // blob: mode byte (bit 0: the harness writes the CRC), then the blob
    s.push(("blob", "published-1dof", [&[0u8][..], &b1].concat()));
    s.push(("blob", "coupled-2dof", [&[0u8][..], &blob_of(&m2)].concat()));
    // a model with a prediction bound (blob version 3's bound section)
    let mut bounded = m1.clone();
    let p = bounded.axis_terms(0);
    let r: Vec<f32> = (0..nanocal_model::bound::packed_len(p))
        .map(|k| 1.0 + k as f32)
        .collect();
    let bound = nanocal_model::AxisBound::new(0.05, 2.0, &vec![0.0; p], &vec![1.0; p], &r).unwrap();
    bounded.set_bound(0, Some(bound)).unwrap();
    s.push((
        "blob",
        "published-1dof-bound",
        [&[0u8][..], &blob_of(&bounded)].concat(),
    ));
    s.push((
        "blob",
        "fix-crc-checks-proxy-model",
        [&[1u8][..], &blob_of(&checks::proxy_model(2))].concat(),
    ));

    // management frames: requests as the device meets them (sealed by the harness) …
    let mut settings = Settings {
        sample_period_ms: 200,
        ..Default::default()
    };
    settings.aux[0] = AuxSource::AirPressure;
    let mut upload = vec![1u8];
    upload.extend(unsealed(Kind::Hello.code(), 1, &[]));
    let mut begin = vec![];
    begin.extend_from_slice(&(b1.len() as u32).to_le_bytes());
    begin.extend_from_slice(&blob::crc32(&b1).to_le_bytes());
    begin.extend_from_slice(&blob::FORMAT_VERSION.to_le_bytes());
    upload.extend(unsealed(Kind::UploadBegin.code(), 2, &begin));
    for (k, c) in b1.chunks(200).enumerate() {
        let mut p = ((k * 200) as u32).to_le_bytes().to_vec();
        p.extend_from_slice(c);
        upload.extend(unsealed(Kind::UploadChunk.code(), 3 + k as u8, &p));
    }
    upload.extend(unsealed(Kind::UploadCommit.code(), 40, &[]));
    s.push(("mgmt_frames", "sealed-upload-session", upload));
    let mut other = vec![1u8];
    let kmz: Vec<u8> = [250.0f64, 0.0, 0.0, 249.9, 0.0, 0.0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    other.extend(unsealed(Kind::SetKmz.code(), 1, &kmz));
    other.extend(unsealed(Kind::Bypass.code(), 2, &[1]));
    other.extend(unsealed(Kind::ConfigSet.code(), 3, &settings.encode()));
    other.extend(unsealed(Kind::Status.code(), 4, &[]));
    other.extend(unsealed(Kind::UploadAbort.code(), 5, &[]));
    s.push(("mgmt_frames", "sealed-kmz-bypass-config", other));
    // … and a device's replies as the host reads them (raw), with a stale reply first
    let mut replies = vec![0u8];
    replies.extend(frame(Kind::Status.reply_code(), 9, &[0]));
    let mut hello = vec![RESULT_OK];
    hello.extend_from_slice(&mgmt::PROTOCOL.to_le_bytes());
    hello.extend_from_slice(&blob::FORMAT_VERSION.to_le_bytes());
    hello.extend_from_slice(&(mgmt::MAX_CHUNK as u16).to_le_bytes());
    hello.push(5);
    hello.extend_from_slice(b"0.1.0");
    hello.extend_from_slice(&[7; 12]);
    hello.push(1);
    replies.extend(frame(Kind::Hello.reply_code(), 1, &hello));
    let mut st = [0u8; mgmt::MAX_PAYLOAD];
    st[0] = RESULT_OK;
    let n = {
        let mut w = Writer::new(&mut st[1..]);
        Status::default().encode(&mut w).unwrap();
        w.len()
    };
    replies.extend(frame(Kind::Status.reply_code(), 2, &st[..1 + n]));
    replies.extend(frame(
        Kind::ConfigGet.reply_code(),
        3,
        &[&[RESULT_OK][..], &settings.encode()].concat(),
    ));
    s.push(("mgmt_frames", "raw-device-replies", replies));
    // a chunk frame announcing 260 bytes that stops after 26 (issue 21, finding 8)
    let mut cut = vec![0u8];
    let mut chunk = vec![0u8; 260];
    chunk[..4].copy_from_slice(&0u32.to_le_bytes());
    cut.extend_from_slice(&frame(Kind::UploadChunk.code(), 1, &chunk)[..26]);
    cut.extend(frame(Kind::Status.code(), 2, &[]));
    s.push(("mgmt_frames", "raw-half-frame-then-status", cut));
    // … and sealed frames arriving 4 ms a byte: a full chunk (1 s) times out between two
    // STATUS requests, which are answered
    let mut slow = vec![3u8];
    slow.extend(unsealed(Kind::Status.code(), 1, &[]));
    slow.extend(unsealed(Kind::UploadChunk.code(), 2, &[0x5A; 250]));
    slow.extend(unsealed(Kind::Status.code(), 3, &[]));
    s.push(("mgmt_frames", "sealed-slow-chunk-times-out", slow));

    // settings: mode byte (bit 0: the harness writes the CRC), then the settings
    s.push((
        "settings",
        "default",
        [&[0u8][..], &Settings::default().encode()].concat(),
    ));
    s.push((
        "settings",
        "pressure-200ms",
        [&[0u8][..], &settings.encode()].concat(),
    ));

    // upload: begin, the whole blob in chunks of 510 bytes after what was received, commit;
    // then a retransmission, a corrupt chunk and an abort
    let mut ok = vec![0u8];
    for _ in 0..b1.len().div_ceil(510) {
        ok.extend([0x81, 0, 255]);
    }
    ok.push(3);
    s.push(("upload", "whole-blob-committed", ok));
    s.push((
        "upload",
        "retransmit-corrupt-abort",
        vec![
            0, 0x81, 0, 40, 1, 0, 20, 0x41, 10, 10, 4, 3, 0, 5, 0, 0, 0, 0, 9, 0xAA, 0xBB,
        ],
    ));

    // GCS through the proxy: a 1-axis session, a 2-axis one, no model, issue 21's sequences
    let mut one = vec![0u8];
    for l in [
        &b"MOV 1 100"[..],
        b"POS? 1",
        b"MVR 1 5",
        b"ERR?",
        b"HLT 1",
        b"MVR 1 1",
        b"GOH",
        b"MOV?",
        b"\x05",
        b"SVO 1 0",
        b"SVO 1 1",
        b"MOV 1 250.5 2 40",
    ] {
        one.extend(line(l));
    }
    one.extend(raw(b"mov 1 42\nPOS?\nMOV 1 10\nERR?\n"));
    one.extend([6 | (5 << 3), SETTLE]);
    s.push(("gcs_proxy", "one-axis-session", one));
    let mut two = vec![1u8];
    for l in [
        &b"MOV 2 10"[..],
        b"MOV 1 250.5 2 40",
        b"MVE 1 50 2 20",
        b"POS? 1 2",
        b"MVR 2 3",
        b"STP",
        b"MOV? 1",
        b"FRF",
        b"ERR?",
    ] {
        two.extend(line(l));
    }
    two.push(SETTLE);
    s.push(("gcs_proxy", "two-axis-session", two));
    let mut none = vec![2u8];
    for l in [&b"MOV 1 100"[..], b"ERR?", b"OMA 1 5", b"POS?"] {
        none.extend(line(l));
    }
    s.push(("gcs_proxy", "no-model", none));
    let mut i21 = vec![0u8];
    for l in [
        &b"MOV 1 100"[..],
        b"HLT 1",
        b"MVR 1 1\n\x18",
        b"MVR 1 5",
        b"POS? 5",
        b"POS? 1",
        b"MOV 1 100 2 0.6",
        b"MVR 1 -19.29",
    ] {
        i21.extend(line(l));
    }
    s.push(("gcs_proxy", "issue-21-sequences", i21));

    // the reference line protocol: setup byte (axes, unit, chunking), then the stream
    s.push((
        "reference_lines",
        "one-axis-um",
        b"\x00# nanocal virtual interferometer\n0.000 100.5\n0.100 100.25\r\n\n0.2\t100.0\n"
            .to_vec(),
    ));
    s.push((
        "reference_lines",
        "two-axes-separators",
        b"\x31t,meas_1,meas_2\n1.5, 2.0; 3.0\n1.6,2.1,3.1\n1.7 2.2 x\n".to_vec(),
    ));
    s.push((
        "reference_lines",
        "three-axes-nm-unfinished",
        b"\x05# three axes in nm\n10 100 200 300\n11 101 201 301\n12 102".to_vec(),
    ));

    // recording CSV: the shared layout, CR LF, a BOM, and a real excerpt
    s.push((
        "recording_csv",
        "layout",
        b"t,cmd_1,meas_1,temp_a,aux_p\n0,100,100.01,22.5,1013\n1,200,199.98,22.51,1013.1\n"
            .to_vec(),
    ));
    s.push((
        "recording_csv",
        "bom-crlf-blank",
        b"\xEF\xBB\xBFt, cmd_x ,meas_x\r\n0.000,22.554000,-123.059139\r\n\r\n0.005,23.26,-120.15\r\n"
            .to_vec(),
    ));
    let real = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/spindle-thermal/recording.csv"),
    )
    .unwrap();
    let excerpt: String = real.lines().take(4).map(|l| format!("{l}\n")).collect();
    s.push(("recording_csv", "spindle-excerpt", excerpt.into_bytes()));
    s
}

#[test]
fn committed_seeds_are_the_ones_this_test_makes() {
    let write = std::env::var_os("NANOCAL_WRITE_FUZZ_SEEDS").is_some();
    for (target, name, bytes) in seeds() {
        let path = seeds_dir().join(target).join(name);
        if write {
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            std::fs::write(&path, &bytes).unwrap();
        }
        let committed = std::fs::read(&path).unwrap_or_default();
        assert!(
            committed == bytes,
            "{} differs from the seed made here: NANOCAL_WRITE_FUZZ_SEEDS=1 cargo test --test fuzz_seeds writes it",
            path.display()
        );
    }
}
