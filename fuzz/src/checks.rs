//! What each fuzz target checks, whatever the bytes: no panic, no hang, and the properties that
//! each decoder promises (round trips, typed refusals, limits). A failed check panics, which
//! libFuzzer reports as a crash with the input that caused it.
//!
//! Several targets take a first "mode" byte that lets the harness repair what a blind mutator
//! rarely gets right (a CRC, a frame's length), so the fuzzer reaches the code behind it too;
//! the raw mode still feeds the bytes as they are.

use crate::proxy_rig::Rig;
use nanocal::campaign::reference::{parse_line, CsvTail, LineSource, ReferenceSource, TimedRead};
use nanocal::data::recording::Recording;
use nanocal::virtual_bench::{AxisConfig, Config, Event};
use nanocal_compensator::upload::Upload;
use nanocal_interface::mgmt::{self, Decoder, Kind, Reader, Request};
use nanocal_interface::settings::Settings;
use nanocal_interface::status::Status;
use nanocal_model::blob::{self, decode, encode, FORMAT_VERSION, MAX_BLOB_LEN};
use nanocal_model::{FastInputs, HysteresisState, Input, Model, ModelBuilder};
use std::sync::OnceLock;
use std::time::Duration;

/// Bytes taken from the front of the input, then the rest.
struct Bytes<'a>(&'a [u8]);

impl<'a> Bytes<'a> {
    fn u8(&mut self) -> Option<u8> {
        let (&b, rest) = self.0.split_first()?;
        self.0 = rest;
        Some(b)
    }
    fn take(&mut self, n: usize) -> &'a [u8] {
        let (a, b) = self.0.split_at(n.min(self.0.len()));
        self.0 = b;
        a
    }
    fn u32(&mut self) -> u32 {
        let mut b = [0u8; 4];
        let t = self.take(4);
        b[..t.len()].copy_from_slice(t);
        u32::from_le_bytes(b)
    }
}

/// The coefficient blob (`nanocal_model::blob`): decoding never panics; whatever decodes
/// re-encodes to the same bytes (a version 1, 2 or 3 blob: to a version 4 blob of the same model),
/// folds, and runs the fast path and the inverse without panicking. Mode byte bit 0: the
/// harness writes the trailing CRC-32 (else the bytes go as they are).
pub fn blob(input: &[u8]) {
    let Some((&mode, rest)) = input.split_first() else {
        return;
    };
    let mut bytes = rest.to_vec();
    if mode & 1 == 1 && bytes.len() >= blob::TRAILER_LEN {
        let n = bytes.len() - blob::TRAILER_LEN;
        let crc = blob::crc32(&bytes[..n]);
        bytes[n..].copy_from_slice(&crc.to_le_bytes());
    }
    let Ok(model) = decode(&bytes) else {
        return;
    };
    let mut out = [0u8; MAX_BLOB_LEN];
    let n = encode(&model, &mut out).expect("a decoded model always encodes");
    if bytes[4..6] == FORMAT_VERSION.to_le_bytes() {
        assert_eq!(&out[..n], &bytes[..], "decode/encode is not a round trip");
    } else {
        assert_eq!(
            decode(&out[..n]).as_ref(),
            Ok(&model),
            "v1/v2/v3 → v4 changed the model"
        );
    }
    exercise(&model);
}

/// Fold a model and run the fast path and the inverse over its travel.
fn exercise(model: &Model) {
    let fold = model.fold(&Default::default());
    let mut state = HysteresisState::new();
    let fast = FastInputs::NONE.with_aux(0, 0.25);
    for x in [1.0f32, 7.5, 3.0, -2.0, 480.0] {
        let c = fold.correct(&[x, -x, x], &[1, 0, -1], &fast, &mut state);
        let _ = fold.inverse(&c.q_um, &[1, 0, -1], &fast, &state);
    }
}

/// Management frames (`nanocal_interface::mgmt`), both ends of the link. The device's byte
/// decoder takes any byte stream without panicking; every frame it delivers has a good CRC and
/// is bytes of the stream after the previous frame's (frames never overlap, and resynchronising
/// on a false sync may deliver a frame that arrived inside it); once the stream stops, a frame
/// still arriving is dropped when its time is up ([`mgmt::FRAME_TIMEOUT_MS`]) and the frames
/// held behind it are decoded, after which a good frame is decoded at once (issue 21, item 8);
/// and after any garbage, a frame that follows one frame's worth of filler is decoded without
/// any time passing. Each frame's payload goes through the device's request decoding (upload
/// state machine, settings, KMZ, bypass) and, as a reply, through the host's status decoding.
/// The host's client reads the same bytes as a device's replies and returns a typed result or
/// error.
///
/// Mode byte bit 0: the rest is `[kind, seq, len, payload…]*` and the harness seals each frame
/// (sync, header, CRC); else the bytes go as they are. Bit 1: the bytes arrive 4 ms apart
/// (else all at once): a frame longer than 125 bytes times out while it arrives.
pub fn mgmt_frames(input: &[u8]) {
    let Some((&mode, rest)) = input.split_first() else {
        return;
    };
    let stream = if mode & 1 == 1 {
        sealed_frames(rest)
    } else {
        rest.to_vec()
    };
    let ms_per_byte = if mode & 2 != 0 { 4 } else { 0 };
    let mut device = Device::default();
    // the decoder after the stream: once with time running out, once with filler
    for filler in [false, true] {
        let mut dec = Decoder::new();
        let mut seen = 0usize; // the stream's bytes before it are a delivered frame's or older
        let mut take = |dec: &mut Decoder, r: Result<(), mgmt::FrameError>, upto: usize| {
            if r.is_err() {
                return;
            }
            let f = dec.frame();
            let mut again = [0u8; mgmt::MAX_FRAME];
            let n = mgmt::encode(f.kind, f.seq, f.payload, &mut again)
                .expect("a decoded frame encodes");
            let at = stream[seen..upto]
                .windows(n)
                .position(|w| w == &again[..n])
                .expect("a decoded frame is bytes of the stream after the previous frame");
            seen += at + n;
            if !filler {
                device.request(f.kind, f.payload);
                let _ = Status::decode(&mut Reader::new(f.payload));
            }
        };
        let mut now = 0u32;
        for (i, &b) in stream.iter().enumerate() {
            now = i as u32 * ms_per_byte;
            let mut ev = dec.feed(b, now);
            while let Some(r) = ev {
                take(&mut dec, r, i + 1);
                ev = dec.next(now);
            }
        }
        if filler {
            // one frame's worth of bytes that are not a sync byte completes (and so ends)
            // every frame the garbage may have started
            for _ in 0..mgmt::MAX_FRAME {
                let mut ev = dec.feed(0, now);
                while let Some(r) = ev {
                    if r.is_ok() {
                        let _ = dec.frame();
                    }
                    ev = dec.next(now);
                }
            }
        } else {
            // the stream stopped: each frame still arriving is dropped when its time is up
            // (at least one byte goes each time), and what was held behind it is decoded
            let mut waits = 0;
            while let Some(wait) = dec.wait_ms(now) {
                assert!(wait <= mgmt::FRAME_TIMEOUT_MS, "a wait beyond the timeout");
                waits += 1;
                assert!(
                    waits <= mgmt::MAX_FRAME,
                    "the decoder never gives up its bytes"
                );
                now = now.wrapping_add(wait.max(1));
                while let Some(r) = dec.next(now) {
                    take(&mut dec, r, stream.len());
                }
            }
        }
        let mut good = [0u8; mgmt::MAX_FRAME];
        let n = mgmt::encode(Kind::Status.code(), 7, &[1, 2, 3], &mut good).unwrap();
        let mut got = vec![];
        for &b in &good[..n] {
            let mut ev = dec.feed(b, now);
            while let Some(r) = ev {
                got.push(r.map(|()| {
                    let f = dec.frame();
                    (f.kind, f.seq, f.payload.to_vec())
                }));
                ev = dec.next(now);
            }
        }
        assert_eq!(
            got,
            vec![Ok((Kind::Status.code(), 7, vec![1u8, 2, 3]))],
            "the decoder did not resynchronise (filler: {filler})"
        );
    }
    host_client(&stream);
}

/// `[kind, seq, len, payload…]*` → sealed frames.
fn sealed_frames(rest: &[u8]) -> Vec<u8> {
    let mut r = Bytes(rest);
    let mut out = Vec::new();
    while let (Some(k), Some(seq), Some(len)) = (r.u8(), r.u8(), r.u8()) {
        let payload = r.take(usize::from(len));
        let mut f = [0u8; mgmt::MAX_FRAME];
        let n = mgmt::encode(k, seq, payload, &mut f).expect("short payloads fit");
        out.extend_from_slice(&f[..n]);
    }
    out
}

/// The device's side of the pure request decoding: what `src/app/mgmt.rs` does with a payload
/// before it touches the store.
struct Device {
    upload: Upload,
    buf: Vec<u8>,
}

impl Default for Device {
    fn default() -> Self {
        Self {
            upload: Upload::new(),
            buf: vec![0u8; MAX_BLOB_LEN],
        }
    }
}

impl Device {
    fn request(&mut self, k: u8, payload: &[u8]) {
        // the device decodes every payload into a typed request first (what
        // `src/app/mgmt.rs` does); a payload that does not decode is refused there
        let Ok(req) = Request::decode(k, payload) else {
            return;
        };
        match req {
            Request::UploadBegin {
                total_len,
                crc32,
                format_version,
            } => {
                let _ = self
                    .upload
                    .begin(total_len, crc32, format_version, self.buf.len());
            }
            Request::UploadChunk { offset, bytes } => {
                let before = self.upload.received();
                match self.upload.chunk(&mut self.buf, offset, bytes) {
                    Ok(received) => assert!(received >= before, "received went back"),
                    Err(_) => self.upload.abort(),
                }
            }
            Request::UploadCommit => {
                if let Ok((model, len)) = self.upload.finish(&self.buf) {
                    assert_eq!(decode(&self.buf[..len]).as_ref(), Ok(&model));
                    exercise(&model);
                }
            }
            Request::UploadAbort => self.upload.abort(),
            Request::ConfigSet(s) => {
                s.validate_stored()
                    .expect("decoded settings are valid as a stored record");
                settings(&[0].into_iter().chain(s.encode()).collect::<Vec<u8>>());
            }
            Request::SetKmz {
                q_cmd_um,
                x_meas_um,
            } => assert!(
                q_cmd_um.iter().chain(&x_meas_um).all(|v| v.is_finite()),
                "a decoded SET_KMZ is finite"
            ),
            _ => {}
        }
    }
}

/// A port that hands out fixed bytes, then reports the device gone.
struct Replay {
    bytes: Vec<u8>,
    at: usize,
    chunk: usize,
}

impl std::io::Read for Replay {
    fn read(&mut self, b: &mut [u8]) -> std::io::Result<usize> {
        let n = self.chunk.min(b.len()).min(self.bytes.len() - self.at);
        b[..n].copy_from_slice(&self.bytes[self.at..self.at + n]);
        self.at += n;
        Ok(n)
    }
}

impl std::io::Write for Replay {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        Ok(b.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// The host's client reading `stream` as the device's replies (the requests' sequence numbers
/// are 1, 2, 3 in order): identify, status, settings; each ends in a value or a typed error.
fn host_client(stream: &[u8]) {
    let port = Replay {
        bytes: stream.to_vec(),
        at: 0,
        chunk: 7,
    };
    let mut c = nanocal::device::Client::new(Box::new(port), "fuzz", Duration::from_secs(5));
    if let Ok(h) = c.identify() {
        assert!(
            h.firmware.len() <= 255 * 3,
            "firmware name from a u8 length"
        );
    }
    let _ = c.status();
    if let Ok(s) = c.config() {
        s.validate_stored()
            .expect("decoded settings are valid as a stored record");
    }
}

/// Settings (`nanocal_interface::settings`): decoding never panics; what decodes is valid (as
/// a stored record: `validate_stored`) and
/// encodes to bytes that decode to the same settings, and encoding them again gives the same
/// bytes. (Not the input's bytes: the decoder ignores the fields of an empty slot and the
/// axis-name bytes past a name's length, which encode as zeros.) Mode byte bit 0: the harness
/// writes the CRC for the layout the version byte names.
pub fn settings(input: &[u8]) {
    let Some((&mode, rest)) = input.split_first() else {
        return;
    };
    let mut b = rest.to_vec();
    if mode & 1 == 1 && b.len() >= 9 {
        let n = b.len() - 4;
        let crc = nanocal_interface::crc32(&b[..n]);
        b[n..].copy_from_slice(&crc.to_le_bytes());
    }
    let Ok(s) = Settings::decode(&b) else {
        return;
    };
    s.validate_stored()
        .expect("decoded settings are valid as a stored record");
    let again = s.encode();
    assert_eq!(Settings::decode(&again), Ok(s), "encode/decode round trip");
    let back = Settings::decode(&again).unwrap();
    assert_eq!(back.encode(), again, "encoding is canonical");
}

/// The upload state machine (`nanocal_compensator::upload`) driven by a sequence of requests
/// against a valid blob: begin (with the blob's or a fuzzed length, CRC and version), chunks at
/// fuzzed offsets and lengths, corrupted chunks, retransmissions, commits and aborts. Checks:
/// `received` never exceeds the announced length and never goes back within an upload; a
/// commit succeeds only with every byte of the announced blob received and its CRC right, and
/// then yields the model the bytes hold.
pub fn upload(input: &[u8]) {
    // built once: a run is many thousand inputs a second
    static GOOD: OnceLock<(Model, Vec<u8>, u32)> = OnceLock::new();
    let (model, good, good_crc) = GOOD.get_or_init(|| {
        let model = nanocal::papers::published::published_1dof().expect("published model");
        let mut good = vec![0u8; MAX_BLOB_LEN];
        let n = encode(&model, &mut good).unwrap();
        good.truncate(n);
        let crc = blob::crc32(&good);
        (model, good, crc)
    });
    let (model, n, good_crc) = (model.clone(), good.len(), *good_crc);
    let mut buf = vec![0u8; MAX_BLOB_LEN];
    let mut up = Upload::new();
    let mut r = Bytes(input);
    let mut announced: Option<(u32, u32)> = None;
    let mut poisoned = false; // a byte other than the blob's was stored
    while let Some(op) = r.u8() {
        match op % 6 {
            0 => {
                // begin with the blob's parameters, or fuzzed ones
                let (len, crc, ver) = if op & 0x80 == 0 {
                    (n as u32, good_crc, FORMAT_VERSION)
                } else {
                    (
                        r.u32() % (2 * MAX_BLOB_LEN as u32),
                        r.u32(),
                        FORMAT_VERSION ^ (op as u16 & 0x40) >> 6,
                    )
                };
                let cap = if op & 0x20 == 0 { buf.len() } else { n / 2 };
                if up.begin(len, crc, ver, cap).is_ok() {
                    assert!(up.is_active() && up.received() == 0);
                    assert!(len as usize <= cap && len > 0);
                    announced = Some((len, crc));
                    poisoned = false;
                } else {
                    assert!(!up.is_active(), "a refused begin leaves no upload");
                    announced = None;
                }
            }
            1 | 2 => {
                // a chunk of the good blob at a fuzzed offset and length
                let off = usize::from(r.u8().unwrap_or(0)) * 4
                    + if op & 0x80 != 0 {
                        up.received() as usize
                    } else {
                        0
                    };
                let len = usize::from(r.u8().unwrap_or(0)) * 2;
                let (o, e) = (off.min(n), (off + len).min(n));
                let mut data = good[o..e].to_vec();
                if op & 0x40 != 0 && !data.is_empty() {
                    data[0] ^= 0x5A;
                }
                let before = up.received();
                let active = up.is_active();
                match up.chunk(&mut buf, o as u32, &data) {
                    Ok(got) => {
                        assert!(active && got >= before, "received went back");
                        let (len, _) = announced.expect("chunk accepted without begin");
                        assert!(got <= len, "received past the announced length");
                        if o as u32 == before && op & 0x40 != 0 && !data.is_empty() {
                            poisoned = true;
                        }
                    }
                    Err(_) => {
                        assert_eq!(up.received(), before, "a refused chunk changed the count")
                    }
                }
            }
            3 => {
                let active = up.is_active();
                let received = up.received();
                if let Ok((m, len)) = up.finish(&buf) {
                    let (alen, crc) = announced.expect("finish without begin");
                    assert!(active && received == alen && len == alen as usize);
                    assert_eq!(blob::crc32(&buf[..len]), crc, "CRC not checked");
                    if !poisoned && len == n {
                        assert_eq!(m, model, "the committed model is the blob's");
                    }
                }
                assert!(!up.is_active(), "an upload ends at commit, either way");
            }
            4 => {
                up.abort();
                assert!(!up.is_active());
            }
            _ => {
                // a chunk of fuzzed bytes
                let off = r.u32() % (MAX_BLOB_LEN as u32 + 8);
                let len = usize::from(r.u8().unwrap_or(0));
                let data = r.take(len).to_vec();
                let before = up.received();
                if let Ok(got) = up.chunk(&mut buf, off, &data) {
                    assert!(got >= before);
                    if off == before && !data.is_empty() {
                        poisoned = true;
                    }
                }
            }
        }
    }
}

/// Lines a host sends often, for the proxy target's dictionary op (with the two controllers'
/// axes `1`, `2`, `3`).
pub const GCS_LINES: &[&[u8]] = &[
    b"MOV 1 100",
    b"MOV 1 0",
    b"MOV 1 500",
    b"MOV 1 250.5 2 40",
    b"MOV 2 10",
    b"MVR 1 5",
    b"MVR 1 -19.29",
    b"MVR 2 3",
    b"MVE 1 50 2 20",
    b"HLT 1",
    b"HLT",
    b"STP",
    b"\x18",
    b"\x05",
    b"\x07",
    b"POS?",
    b"POS? 1",
    b"POS? 1 2",
    b"POS? 5",
    b"MOV?",
    b"MOV? 1",
    b"ONT? 1",
    b"ERR?",
    b"GOH",
    b"GOH 1",
    b"SVO 1 0",
    b"SVO 1 1",
    b"FRF 1",
    b"FRF",
    b"CSV?",
    b"PUN? 1",
    b"PUN? 2",
    b"SAI?",
    b"*IDN?",
    b"TMN? 1",
    b"TMX? 1",
    b"VEL 1 10",
    b"OMA 1 5",
    b"SVA 1 10",
    b"STE 1 5",
    b"WGO 1 1",
    b"MAC START x",
    b"RBT",
    b"1 MOV 1 120",
    b"mov 1 42",
    b"MOV 1 100 2 0.6",
    b"MOV\r1 300",
    b"\rMOV 1 200",
    b"MVR 1 1\n\x18",
    b"DFH 1",
    b"POS 1 30",
    b"MOV 1 1e3",
    b"MVR 1 1",
];

/// Controller targets on a model axis of [`proxy_model`] lie in this range (the correction of
/// every target inside the training envelope 0…500 µm, with the coupling's share).
const CORRECTED_UM: (f64, f64) = (999.0, 1501.0);

/// A model whose correction cannot be mistaken for a host's target: `q = x + 1000 µm` on each
/// axis (axis 2 also takes 0.001 · x₁), trained on 0…500 µm. An uncorrected move lands outside
/// [`CORRECTED_UM`].
pub fn proxy_model(axes: usize) -> Model {
    let mut b = ModelBuilder::new(axes, 0, 0).expect("axes").id(0x00F0_0001);
    for a in 0..axes {
        b = b
            .trained_range(Input::Axis(a as u8), 0.0, 500.0)
            .travel_um(a, -20.0, 2000.0)
            .offset_um(a, 1000.0);
    }
    for a in 0..axes {
        let mut p = [0u8; 3];
        p[a] = 1;
        b.add_raw_term(a as u8, p, nanocal_model::Factor::None, 0, 1.0)
            .unwrap();
    }
    if axes > 1 {
        b.add_raw_term(1, [1, 0, 0], nanocal_model::Factor::None, 0, 0.001)
            .unwrap();
    }
    b.build().expect("proxy model")
}

/// The simulated controller for the proxy target: every command the proxy treats, `axes`
/// axes, servo on and referenced, travel wide enough for the corrected targets, reference
/// switch inside the corrected range.
fn proxy_controller(axes: usize) -> Config {
    let mut cfg = crate::proxy_rig::everything(axes);
    for a in &mut cfg.axes {
        *a = AxisConfig {
            min: -20.0,
            max: 2000.0,
            reference: Some(1250.0),
            start: 1250.0,
            ..a.clone()
        };
    }
    cfg
}

/// GCS lines through the proxy against a simulated controller, as sequences: fuzzed byte
/// chunks (any split of lines, control characters, no LF), lines from a dictionary, time
/// passing (the proxy's reply timeout, motions), and `forget_targets` (what the firmware does
/// at a new model). First byte: model axes (1 or 2; the controller has one more, relayed) or
/// no model. Checks after every step: no panic; the proxy always takes the host's bytes (the
/// rig fails after 10,000 idle rounds); while compensating, the controller never accepts a
/// closed-loop target on a model axis that is not a correction (outside [`CORRECTED_UM`]), and
/// never receives an open-loop, wave, macro or step command for a model axis.
pub fn gcs_proxy(input: &[u8]) {
    let Some((&setup, rest)) = input.split_first() else {
        return;
    };
    // built once: a run is many thousand inputs a second
    static MODELS: OnceLock<[Model; 2]> = OnceLock::new();
    static CONTROLLERS: OnceLock<[Config; 2]> = OnceLock::new();
    let axes = 1 + usize::from(setup & 1);
    let model = (setup & 2 == 0)
        .then(|| &MODELS.get_or_init(|| [proxy_model(1), proxy_model(2)])[axes - 1]);
    let cfg =
        CONTROLLERS.get_or_init(|| [proxy_controller(2), proxy_controller(3)])[axes - 1].clone();
    let mut rig = Rig::new(cfg, model, &[]);
    let mut r = Bytes(rest);
    let mut line = Vec::new();
    let mut sent = Vec::new();
    while let Some(op) = r.u8() {
        match op % 8 {
            0..=3 => {
                let n = usize::from(op >> 3);
                let b = r.take(n);
                sent.extend_from_slice(b);
                rig.host(b);
            }
            4 | 5 => {
                let i = usize::from(r.u8().unwrap_or(0)) % GCS_LINES.len();
                line.clear();
                line.extend_from_slice(GCS_LINES[i]);
                line.push(b'\n');
                sent.extend_from_slice(&line);
                rig.host(&line);
            }
            6 => rig.wait_ms(u32::from(op >> 3) * 20),
            _ => {
                if op & 0x80 != 0 {
                    rig.proxy.forget_targets();
                } else {
                    rig.settle();
                }
            }
        }
        let events = rig.events();
        if model.is_some() && !(ISSUE_21_CONTROL_BYTES && hides_a_command(&sent)) {
            check_events(&events, axes);
        }
    }
    rig.settle();
    let events = rig.events();
    if model.is_some() && !(ISSUE_21_CONTROL_BYTES && hides_a_command(&sent)) {
        check_events(&events, axes);
    }
}

/// Issue 21, finding 4: a byte outside GCS's printable set inside a line (`\rMOV 1 200`,
/// ` \xA0MOV 1 100`) once hid a command, which went out uncorrected to a controller that takes
/// it as white space. The proxy now refuses such a line (9011), so the target checks every
/// input; `true` would skip the checks after such a byte again (kept for bisecting).
pub const ISSUE_21_CONTROL_BYTES: bool = false;

/// True when `sent` has a byte that can hide a command: one outside GCS's printable ASCII
/// that is not tab, LF, a CR ending a line or one of GCS's single-character commands (the
/// fuzz target found `0xA0`, a no-break space in PI's code page, hiding one too).
pub fn hides_a_command(sent: &[u8]) -> bool {
    const SINGLE: &[u8] = &[3, 4, 5, 6, 7, 8, 11, 24, 27];
    sent.iter().enumerate().any(|(i, &b)| match b {
        b'\r' => sent.get(i + 1) != Some(&b'\n'),
        b'\t' | b'\n' | 0x20..=0x7E => false,
        _ => !SINGLE.contains(&b),
    })
}

fn check_events(events: &[Event], model_axes: usize) {
    for e in events {
        match e {
            Event::Target { axis, value, by } if *axis < model_axes => assert!(
                (CORRECTED_UM.0..=CORRECTED_UM.1).contains(value),
                "the controller accepted target {value} on model axis {axis} by {by}: not a correction"
            ),
            Event::RawMotion { command, axes } => assert!(
                !axes.is_empty() && axes.iter().all(|&a| a >= model_axes),
                "a raw motion reached the controller: {command:?} (axes {axes:?})"
            ),
            _ => {}
        }
    }
}

/// A reader that hands out the input in chunks, then reports the instrument gone.
struct Chunks {
    bytes: Vec<u8>,
    at: usize,
    sizes: Vec<usize>,
    k: usize,
}

impl TimedRead for Chunks {
    fn read_timed(&mut self, buf: &mut [u8], _wait: Duration) -> std::io::Result<Option<usize>> {
        if self.at >= self.bytes.len() {
            return Ok(None);
        }
        let size = self.sizes[self.k % self.sizes.len()];
        self.k += 1;
        let n = size.min(buf.len()).min(self.bytes.len() - self.at);
        buf[..n].copy_from_slice(&self.bytes[self.at..self.at + n]);
        self.at += n;
        Ok(Some(n))
    }
}

/// The reference instrument's line protocol (`nanocal::campaign::reference`): over a stream cut
/// into fuzzed chunks (with pauses), and as a CSV file the instrument's software appends to.
/// First byte: axes (1–3) and the unit. Checks: no panic; every sample has one finite time and
/// one finite position per axis; the stream ends in `Closed` or a `Malformed` error naming a
/// line that exists; the samples are those of [`parse_line`] applied to each line in turn.
pub fn reference_lines(input: &[u8]) {
    let Some((&setup, rest)) = input.split_first() else {
        return;
    };
    let axes = 1 + usize::from(setup % 3);
    let to_um = [1.0, 1e-3, 1e3][usize::from(setup / 3 % 3)];
    let sizes: Vec<usize> = vec![
        usize::from(setup >> 4) % 7,
        1 + usize::from(setup >> 2) % 13,
        4096,
    ];
    let mut src = LineSource::new(
        "fuzz",
        Box::new(Chunks {
            bytes: rest.to_vec(),
            at: 0,
            sizes,
            k: 0,
        }),
        axes,
        to_um,
    );
    // the reference: parse_line per complete line, in order, up to the first bad one
    let mut want = Vec::new();
    let mut lines = 0;
    let mut bad_line = None;
    for raw in rest.split_inclusive(|&b| b == b'\n') {
        if raw.last() != Some(&b'\n') {
            break; // unfinished: never a sample
        }
        lines += 1;
        match parse_line(&String::from_utf8_lossy(raw), axes, to_um) {
            Ok(Some(s)) => want.push(s),
            Ok(None) => {}
            Err(_) => {
                bad_line = Some(lines);
                break;
            }
        }
    }
    let mut got = Vec::new();
    let end = loop {
        match src.poll(Duration::ZERO) {
            Ok(v) => got.extend(v),
            Err(e) => break e,
        }
        assert!(got.len() <= rest.len(), "more samples than bytes");
    };
    for s in &got {
        assert!(s.t_s.is_finite() && s.pos_um.len() == axes);
        assert!(s.pos_um.iter().all(|p| p.is_finite()));
    }
    assert_eq!(got, want, "the stream's samples are the lines' samples");
    use nanocal::campaign::reference::ReferenceError as E;
    match (end, bad_line) {
        (E::Closed { .. }, None) => {}
        (E::Malformed { line, .. }, Some(bad)) => assert_eq!(line, bad, "the bad line's number"),
        (e, bad) => panic!("stream ended with {e} (first bad line {bad:?})"),
    }
    csv_tail(rest, axes, to_um);
}

/// The same bytes as a CSV file: its header opens the source (or is refused), its rows are
/// read by one poll.
fn csv_tail(bytes: &[u8], axes: usize, to_um: f64) {
    // tmpfs where there is one: a file per input
    let shm = std::path::Path::new("/dev/shm");
    let dir = if shm.is_dir() {
        shm.to_path_buf()
    } else {
        std::env::temp_dir()
    };
    let path = dir.join(format!("nanocal-fuzz-csv-{}", std::process::id()));
    // the header and the rows already there when the campaign starts, then what is appended
    let split = bytes
        .iter()
        .position(|&b| b == b'\n')
        .map_or(bytes.len(), |p| p + 1);
    std::fs::write(&path, &bytes[..split]).expect("temp file");
    if let Ok(mut tail) = CsvTail::open("fuzz", path.clone(), axes, to_um) {
        use std::io::Write;
        let mut f = std::fs::OpenOptions::new()
            .append(true)
            .open(&path)
            .unwrap();
        f.write_all(&bytes[split..]).unwrap();
        drop(f);
        if let Ok(v) = tail.poll(Duration::ZERO) {
            for s in &v {
                assert!(s.t_s.is_finite() && s.pos_um.len() == axes);
                assert!(s.pos_um.iter().all(|p| p.is_finite()));
            }
        }
    }
    let _ = std::fs::remove_file(&path);
}

/// Recording CSV (`nanocal::data::recording`): parsing never panics; what parses has named, distinct
/// columns of equal length and writes back to CSV that parses to the same values (bit for
/// bit; NaN stays NaN).
/// The rows of a recording the plainest way (for [`recording_csv`]): lines split at `\n`,
/// lines of only spaces, tabs and `\r` skipped, fields split at `,`, one `\r` at a field's end
/// dropped (the parser reads `\r` before any delimiter as it reads it before `\n`), spaces and
/// tabs trimmed, each field read by `str::parse::<f64>`. Panics on a field that does not read
/// (called only on input the parser took).
fn plain_reading(input: &[u8]) -> Vec<Vec<f64>> {
    fn trim(mut s: &[u8]) -> &[u8] {
        while let [b' ' | b'\t', rest @ ..] = s {
            s = rest;
        }
        while let [rest @ .., b' ' | b'\t'] = s {
            s = rest;
        }
        s
    }
    let input = input.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(input);
    input
        .split(|&b| b == b'\n')
        .skip(1)
        .filter(|line| !line.iter().all(|b| matches!(b, b' ' | b'\t' | b'\r')))
        .map(|line| {
            line.split(|&b| b == b',')
                .map(|field| {
                    let field = field.strip_suffix(b"\r").unwrap_or(field);
                    let text =
                        std::str::from_utf8(trim(field)).expect("a field the parser took is UTF-8");
                    text.parse::<f64>().unwrap_or_else(|_| {
                        panic!("the parser took {text:?}, the standard library does not")
                    })
                })
                .collect()
        })
        .collect()
}

pub fn recording_csv(input: &[u8]) {
    let Ok(rec) = Recording::parse(input) else {
        return;
    };
    // every value as the standard library reads its field, line by line: the parser's fast
    // paths (whole rows, the window, the exact decimal) against the plainest reading
    let reference = plain_reading(input);
    assert_eq!(reference.len(), rec.rows(), "rows against a plain reading");
    for (r, values) in reference.iter().enumerate() {
        assert_eq!(values.len(), rec.names().len(), "row {r}: values");
        for (c, v) in values.iter().enumerate() {
            let got = rec.column_at(c)[r];
            assert!(
                got.to_bits() == v.to_bits() || (got.is_nan() && v.is_nan()),
                "row {r} column {c}: {got} read, {v} by the standard library"
            );
        }
    }
    let names = rec.names().to_vec();
    for (i, n) in names.iter().enumerate() {
        assert!(!n.is_empty() && !names[..i].contains(n), "column names");
        assert_eq!(rec.column_at(i).len(), rec.rows());
    }
    let mut out = Vec::new();
    rec.write(&mut out).unwrap();
    let back = Recording::parse(&out).expect("a written recording parses");
    assert_eq!(back.names(), rec.names());
    assert_eq!(back.rows(), rec.rows());
    for (i, name) in names.iter().enumerate() {
        let (a, b) = (rec.column_at(i), back.column_at(i));
        assert!(
            a.iter()
                .zip(b)
                .all(|(x, y)| x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan())),
            "column {name} changed in the round trip"
        );
    }
}
