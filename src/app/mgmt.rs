//! The management task: identity, status, chunked upload into the store, KMZ, bypass,
//! settings, reset.

use super::supervisor::led_state;
use super::{now_ms, read_some, task, Comp, Shared};
use core::sync::atomic::Ordering;
use embassy_futures::select::{select, select3, Either, Either3};
use embedded_io_async::{Read, Write};
use embedded_storage_async::nor_flash::NorFlash;
use nanocal_compensator::gcs::AxisMap;
use nanocal_compensator::inputs;
use nanocal_compensator::l4flash::EccErrors;
use nanocal_compensator::proxy::Gate;
use nanocal_compensator::stale::KmzCheck;
use nanocal_compensator::store::Store;
use nanocal_compensator::upload::Upload;
use nanocal_interface::mgmt::InputCode;
use nanocal_interface::mgmt::{self, Decoder, Hello, Kind, Refusal, Reply, Request, Writer};
use nanocal_interface::settings::{self, Settings};
use nanocal_interface::status::{Flags, Status, STATUS_AUX, STATUS_SENSORS};
use nanocal_model::{blob, MAX_AXES};

/// How long a reply may wait for the host to read it, ms.
const REPLY_STALL_MS: u64 = 1_000;

/// Firmware version reported in HELLO.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");

/// The settings stored, or the defaults (logged) when none are stored or they do not decode.
pub async fn load_settings<F: NorFlash>(store: &mut Store<F>) -> Settings {
    let mut b = [0u8; settings::LEN];
    match store.load_settings(&mut b).await {
        Ok(Some(n)) => match Settings::decode(&b[..n]) {
            Ok(s) => return s,
            Err(_) => warn!("stored settings do not decode; defaults in force"),
        },
        Ok(None) => info!("no stored settings; defaults in force"),
        Err(_) => warn!("settings unreadable; defaults in force"),
    }
    Settings::default()
}

/// Put the stored model (with its stored KMZ) in service, or none if none is stored or it does
/// not decode. The blob is decoded where the store read it (its scratch), outside any future.
async fn load_model<F: NorFlash>(store: &mut Store<F>, sh: &Shared) {
    let id = match store.load_model_with(|b| stage_blob(sh, b)).await {
        Ok(Some(Some(id))) => id,
        Ok(Some(None)) => {
            warn!("stored model does not decode");
            sh.clear_model();
            return;
        }
        Ok(None) => {
            info!("no stored model");
            sh.clear_model();
            return;
        }
        Err(_) => {
            warn!("model store unreadable");
            sh.clear_model();
            return;
        }
    };
    if let Ok(Some(k)) = store.load_kmz(id).await {
        sh.model.lock(|m| {
            if let Some(model) = m.borrow_mut().model.as_mut() {
                for (a, v) in k.iter().enumerate().take(model.axes()) {
                    model.set_kmz_offset_um(a, *v);
                }
            }
        });
    }
    info!("model {=u32:#x} loaded", id);
    sh.release();
}

/// Decode a stored blob and stage it; its id.
fn stage_blob(sh: &Shared, bytes: &[u8]) -> Option<u32> {
    let model = blob::decode(bytes).ok()?;
    let crc = blob::stored_crc(bytes)?;
    let id = model.id();
    sh.stage(model, crc);
    Some(id)
}

/// Why a finished upload is not staged.
enum Refused {
    Upload(Refusal),
    Input(InputCode),
}

/// Verify and decode a finished upload (in `buf`), check that the board supplies its inputs
/// and stage it; its id and λ_KMZ. Synchronous, so the decoded model never lives in the
/// management task's future.
fn stage_upload(
    sh: &Shared,
    upload: &mut Upload,
    buf: &[u8],
) -> Result<(u32, [f64; MAX_AXES]), Refused> {
    let (model, len) = upload.finish(buf).map_err(|e| Refused::Upload(e.code()))?;
    // decoded, so its CRC was checked (and it is longer than one)
    let crc = blob::stored_crc(&buf[..len]).unwrap_or(0);
    let settings = sh.settings.lock(|s| *s.borrow());
    let board = sh.board.lock(|b| *b.borrow());
    inputs::check(&model, &settings, &board).map_err(|e| Refused::Input(e.code()))?;
    let mut kmz = [0.0; MAX_AXES];
    for (a, v) in kmz.iter_mut().enumerate().take(model.axes()) {
        *v = model.kmz_offset_um(a);
    }
    let id = model.id();
    sh.stage(model, crc);
    Ok((id, kmz))
}

/// Encode the staged model into `out` (the store's scratch); its length. The CRC of what is
/// stored becomes the model's content hash (what comes back from flash after a reset; the
/// same as the upload's, the encoding being canonical — the host checks).
fn encode_staged(sh: &Shared, out: &mut [u8]) -> Option<usize> {
    sh.model.lock(|m| {
        let mut m = m.borrow_mut();
        let n = blob::encode(m.model.as_ref()?, out).ok()?;
        m.model_crc32 = blob::stored_crc(&out[..n])?;
        Some(n)
    })
}

/// What woke the management task.
enum Wake {
    /// Bytes arrived.
    Bytes(usize),
    /// The frame still arriving ran out of time, or the management port was closed: the
    /// decoder has something to do without a byte.
    Decoder,
}

/// Run the management channel. The store's scratch receives uploads (a blob is either being
/// received or being written); `reset` resets the device (after the reply to a `RESET` went
/// out).
///
/// A frame that stops arriving (a connection closed mid-frame) is dropped when its time is up
/// (`mgmt::FRAME_TIMEOUT_MS` after its first byte) and the bytes after it are searched again
/// for a sync, so the requests that followed are answered, not swallowed; the management
/// port's closing (its line state, where the board has it) drops a half frame at once.
pub async fn management<R: Read, W: Write, F: NorFlash + EccErrors>(
    mut rx: R,
    mut tx: W,
    store: &mut Store<F>,
    reset: fn() -> !,
    sh: &Shared,
) -> ! {
    let mut dec = Decoder::new();
    let mut upload = Upload::new();
    let mut inbuf = [0u8; 64];
    let mut frame = [0u8; mgmt::MAX_FRAME];
    let mut load = true;
    loop {
        // at start, and after a staged model could not be stored: what the store holds runs,
        // as after the next reset
        if load {
            load_model(store, sh).await;
            load = false;
        }
        super::note_flash_ecc_errors(sh, store.flash().ecc_errors());
        let wait_ms = dec.wait_ms(now_ms()).unwrap_or(u32::MAX);
        let wake = match select3(
            read_some(&mut rx, &mut inbuf),
            embassy_time::Timer::after_millis(u64::from(wait_ms)),
            sh.mgmt_hangup.wait(),
        )
        .await
        {
            Either3::First(n) => Wake::Bytes(n),
            Either3::Second(()) => Wake::Decoder,
            Either3::Third(()) => {
                if dec.wait_ms(now_ms()).is_some() {
                    warn!("management port closed mid-frame: the frame is dropped");
                }
                // the bytes held are the closed connection's, but the next one's may have
                // followed them already: drop the half frame as if its time were up
                dec.cut(now_ms());
                Wake::Decoder
            }
        };
        let now = now_ms();
        let bytes = match wake {
            Wake::Bytes(n) => &inbuf[..n],
            Wake::Decoder => &[][..],
        };
        let mut i = 0;
        let mut ev = dec.next(now);
        loop {
            while let Some(e) = ev {
                match e {
                    Ok(()) => {
                        let f = dec.frame();
                        let (k, seq) = (f.kind, f.seq);
                        let reply = {
                            let _busy = sh.beats[task::MGMT].busy(now_ms());
                            handle(k, f.payload, &mut upload, store, sh).await
                        };
                        super::note_flash_ecc_errors(sh, store.flash().ecc_errors());
                        if answer(&mut tx, &mut frame, k, seq, reply).await {
                            embassy_time::Timer::after_millis(50).await;
                            reset();
                        }
                        load = sh.model.lock(|m| m.borrow().pending);
                    }
                    Err(mgmt::FrameError::Timeout) => {
                        warn!("management frame incomplete when its time was up: dropped")
                    }
                    Err(_) => warn!("management frame dropped (CRC or length)"),
                }
                ev = dec.next(now_ms());
            }
            let Some(&b) = bytes.get(i) else { break };
            i += 1;
            ev = dec.feed(b, now);
        }
    }
}

/// Send `reply` to request `k`/`seq`; true when the device must reset now.
async fn answer<W: Write>(
    tx: &mut W,
    frame: &mut [u8; mgmt::MAX_FRAME],
    k: u8,
    seq: u8,
    reply: Reply,
) -> bool {
    let resets = matches!(reply, Reply::Reset);
    let mut w = Writer::new(&mut frame[mgmt::PAYLOAD_AT..][..mgmt::MAX_PAYLOAD]);
    // every reply fits the payload (the golden-byte tests encode each)
    let _ = reply.encode(&mut w);
    let len = w.len();
    drop(reply);
    if let Ok(m) = mgmt::seal(k | mgmt::REPLY, seq, len, frame) {
        // a host that does not read its reply loses it, not the device its management channel
        let sent = select(
            embassy_time::Timer::after_millis(REPLY_STALL_MS),
            tx.write_all(&frame[..m]),
        )
        .await;
        if let Either::First(()) = sent {
            warn!("management reply not read for 1 s: dropped");
        }
        let _ = tx.flush().await;
    }
    resets
}

/// Answer one request (kind byte `k`, `payload`).
async fn handle<F: NorFlash>(
    k: u8,
    payload: &[u8],
    upload: &mut Upload,
    store: &mut Store<F>,
    sh: &Shared,
) -> Reply {
    if matches!(Kind::from_code(k), Some(Kind::SetKmz | Kind::ConfigSet)) && upload.is_active() {
        // the store's scratch holds the upload: writing anything else overwrites it
        upload.abort();
        warn!("upload aborted by a store write");
    }
    let request = match Request::decode(k, payload) {
        Ok(r) => r,
        Err(e) => return Reply::refused(e.refusal()),
    };
    match request {
        Request::Hello => Reply::Hello(hello(sh)),
        Request::Status => Reply::Status(status(sh, upload)),
        Request::UploadBegin {
            total_len,
            crc32,
            format_version,
        } => match upload.begin(total_len, crc32, format_version, store.buffer().len()) {
            Ok(()) => Reply::UploadBegin,
            Err(e) => reject(sh, e.code()),
        },
        Request::UploadChunk { offset, bytes } => {
            match upload.chunk(store.buffer(), offset, bytes) {
                Ok(received) => Reply::UploadChunk { received },
                Err(e) => {
                    upload.abort();
                    reject(sh, e.code())
                }
            }
        }
        Request::UploadCommit => match stage_upload(sh, upload, store.buffer()) {
            Ok((id, kmz)) => {
                // the model, then its own λ_KMZ (an older KMZ item for the same id must not
                // come back at the next boot); the model is encoded again from its decoded
                // form, since the scratch that received it is the store's working buffer
                let stored = match store.save_model_with(|out| encode_staged(sh, out)).await {
                    Ok(()) => store.save_kmz(id, &kmz).await.is_ok(),
                    Err(_) => false,
                };
                if !stored {
                    // still pending: the management loop puts what the store holds back in
                    // service
                    return reject(sh, Refusal::Storage);
                }
                sh.release();
                let (uploads_accepted, model_crc32) = sh.model.lock(|m| {
                    let mut m = m.borrow_mut();
                    m.uploads_ok = m.uploads_ok.wrapping_add(1);
                    (m.uploads_ok, m.model_crc32)
                });
                info!(
                    "model {=u32:#x} (blob CRC {=u32:#x}) stored and installed",
                    id, model_crc32
                );
                Reply::UploadCommit {
                    model_id: id,
                    model_crc32,
                    uploads_accepted,
                }
            }
            Err(Refused::Upload(code)) => reject(sh, code),
            Err(Refused::Input(input)) => {
                warn!(
                    "upload refused: model input not supplied (code {=u8})",
                    input.code()
                );
                let _ = reject(sh, Refusal::Input);
                Reply::Refused {
                    refusal: Refusal::Input,
                    input: Some(input),
                }
            }
        },
        Request::UploadAbort => {
            upload.abort();
            Reply::UploadAbort
        }
        Request::SetKmz {
            q_cmd_um,
            x_meas_um,
        } => match apply_kmz(sh, &q_cmd_um, &x_meas_um) {
            Some((kmz_um, id)) => {
                let stored = store.save_kmz(id, &kmz_um).await.is_ok();
                if !stored {
                    warn!("KMZ change not stored");
                }
                Reply::SetKmz { kmz_um, stored }
            }
            None => Reply::refused(Refusal::NoModel),
        },
        Request::Bypass { on } => {
            sh.core.lock(|c| c.borrow_mut().proxy.bypass = on);
            Reply::Bypass
        }
        Request::ConfigGet => Reply::ConfigGet(sh.settings.lock(|s| *s.borrow())),
        // decoded as stored records are, then held to today's ranges (a stored record may come
        // from a firmware with other limits; a new one may not)
        Request::ConfigSet(s) if s.validate().is_err() => Reply::refused(Refusal::Settings),
        Request::ConfigSet(s) => match store.save_settings(&s.encode()).await {
            Ok(()) => {
                apply_settings(sh, s);
                Reply::ConfigSet
            }
            Err(_) => Reply::refused(Refusal::Storage),
        },
        Request::Reset => Reply::Reset,
        #[cfg(feature = "qemu")]
        Request::DebugHang => loop {
            // a hung firmware, for the watchdog test: only the watchdog gets out of here
            core::hint::spin_loop();
        },
        #[cfg(not(feature = "qemu"))]
        Request::DebugHang => Reply::refused(Refusal::UnknownKind),
    }
}

/// What HELLO tells.
fn hello(sh: &Shared) -> Hello {
    let mut firmware = nanocal_interface::heapless::String::new();
    // the package version is a few bytes, far below HELLO's 255
    let _ = firmware.push_str(VERSION);
    Hello {
        protocol: mgmt::PROTOCOL,
        blob_format: blob::FORMAT_VERSION,
        max_chunk: mgmt::MAX_CHUNK as u16,
        firmware,
        uid: sh.identity.uid,
        reset_cause: sh.identity.reset_cause,
        reset_site: sh.identity.reset_site.text(),
    }
}

/// Re-measure λ_KMZ of the model in service at a reference pose (command `q` sent, `x`
/// measured); the next command already uses it (when the inputs are valid, the fast path is
/// folded again at once). The new offsets and the model's id; `None` without a model.
fn apply_kmz(
    sh: &Shared,
    q: &[f64; MAX_AXES],
    x: &[f64; MAX_AXES],
) -> Option<([f64; MAX_AXES], u32)> {
    let dir = [0i8; MAX_AXES];
    let k = sh.settings.lock(|s| s.borrow().stale_k);
    let kmz = sh.model.lock(|m| {
        let mut m = m.borrow_mut();
        let m = &mut *m;
        let slow = m.slow;
        let live = m.inputs_ready && !m.pending;
        let model = m.model.as_mut()?;
        if live {
            // the model-stale check: the λ change this re-measurement makes is the model's
            // prediction error at the KMZ point (not checked on inputs never read)
            let check = KmzCheck::of(model, q, x, &slow, k);
            if m.stale.kmz(check, now_ms()) {
                warn!(
                    "model stale: the KMZ fell outside {=f32} standard errors",
                    k
                );
            }
        }
        model.set_kmz_from_reference(q, x, &dir, &slow);
        let mut k = [0.0; MAX_AXES];
        for (a, v) in k.iter_mut().enumerate().take(model.axes()) {
            *v = model.kmz_offset_um(a);
        }
        if live {
            let comp = Comp::new(model, &slow);
            sh.core.lock(|c| c.borrow_mut().comp = Some(comp));
        }
        Some((k, model.id()))
    });
    sh.refold.signal(());
    kmz
}

/// Put new settings in force: sensors are reconfigured at once, the axis names and following
/// take effect on the next line (a new host session: nothing held is followed until the next
/// move), the stage baud rate at the next reset.
fn apply_settings(sh: &Shared, s: Settings) {
    sh.settings.lock(|x| *x.borrow_mut() = s);
    sh.core.lock(|c| {
        let mut c = c.borrow_mut();
        c.proxy.reconfigure(AxisMap::new(&s.axis_names));
        c.proxy.set_follow(super::follow_config(&s));
    });
    let serial = sh.model.lock(|m| {
        m.borrow()
            .model
            .as_ref()
            .and_then(|x| x.provenance().stage_serial)
    });
    sh.check_stage(serial);
    sh.settings_changed.signal(());
    // the stage link ticks following only while it is armed: let it look
    sh.stage_sent.signal(());
}

/// Count a rejected upload; the refusal.
fn reject(sh: &Shared, code: Refusal) -> Reply {
    sh.model.lock(|m| {
        let mut m = m.borrow_mut();
        m.uploads_rejected = m.uploads_rejected.wrapping_add(1);
        m.last_upload_error = Some(code);
    });
    warn!("upload rejected: code {=u8}", code.code());
    Reply::refused(code)
}

fn status(sh: &Shared, upload: &Upload) -> Status {
    let now = now_ms();
    let mut s = Status {
        uptime_ms: now,
        uid: sh.identity.uid,
        reset_cause: sh.identity.reset_cause,
        led: led_state(sh),
        flash_ecc_errors: sh.flash_ecc_errors.load(Ordering::Relaxed),
        ..Default::default()
    };
    sh.model.lock(|m| {
        let m = m.borrow();
        if let Some(model) = &m.model {
            s.flags |= Flags::MODEL;
            s.model_id = model.id();
            s.model_crc32 = m.model_crc32;
            s.model_serial = model.provenance().stage_serial;
            for a in 0..model.axes().min(3) {
                s.kmz_um[a] = model.kmz_offset_um(a);
            }
            if !m.inputs_ready {
                s.flags |= Flags::WARMING_UP;
            }
        }
        for (i, ch) in m.faults.channels.iter().enumerate().take(STATUS_SENSORS) {
            // the fold's input (the average of the fold period), for a usable channel
            s.temps_c[i] = match ch.value_c() {
                Some(_) => m.slow.temps_c[i] as f32,
                None => f32::NAN,
            };
            s.sensor_bits[i] = ch.status_bits();
        }
        for (i, ch) in m.aux_faults.channels.iter().enumerate().take(STATUS_AUX) {
            s.aux[i] = match ch.value_c() {
                Some(_) => m.slow.aux[i] as f32,
                None => f32::NAN,
            };
            s.aux_bits[i] = ch.status_bits();
        }
        s.slow_outside = m.slow_outside;
        if m.slow_outside != 0 {
            s.flags |= Flags::EXTRAPOLATING;
        }
        if m.model.is_some() {
            s.stale = m.stale.reasons();
            s.stale_since_ms = m.stale.since_ms();
            if m.stale.is_stale() {
                s.flags |= Flags::MODEL_STALE;
            }
            if let Some(c) = m.stale.last_kmz() {
                s.kmz_residual_um = c.residual_um;
                s.kmz_limit_um = c.limit_um;
            }
            s.envelope_excess_c = m.stale.excess_c();
        }
        s.folds = m.folds;
        s.uploads_ok = m.uploads_ok;
        s.uploads_rejected = m.uploads_rejected;
        s.last_upload_error = m.last_upload_error;
        s.sensor_reconfigs = m.sensor_reconfigs;
    });
    s.sensors = sh.settings.lock(|x| {
        let x = x.borrow();
        x.sensors
            .iter()
            .rposition(|c| c.is_some())
            .map_or(0, |i| i as u8 + 1)
    });
    let limit = super::supervisor::stale_limit_ms(sh);
    sh.core.lock(|c| {
        let c = c.borrow();
        s.flags |= Flags::MOVE_FOLD;
        s.move_fold = c.move_fold;
        if c.proxy.bypass {
            s.flags |= Flags::BYPASS;
        }
        if c.proxy.gate == Gate::SensorFault {
            s.flags |= Flags::SENSOR_BLOCK;
        }
        if c.comp.is_some() {
            s.fold_age_ms = now.wrapping_sub(c.folded_at_ms);
            if s.fold_age_ms > limit {
                s.flags |= Flags::FOLD_STALE;
            }
        }
        if c.proxy.unit_mismatch() {
            s.flags |= Flags::UNIT_MISMATCH;
        }
        s.stage = c.proxy.stage_check();
        s.controller_serial = c.proxy.controller_serial();
        if s.stage.mismatch() {
            s.flags |= Flags::STAGE_MISMATCH;
        }
        let k = c.proxy.counters;
        s.host_lines = k.host_lines;
        s.moves = k.moves;
        s.refused = k.refused;
        s.mapped_replies = k.mapped_replies;
        s.follow_reissues = k.follow_reissues;
        s.follow_refused = k.follow_refused;
        s.pending_error = c.proxy.pending_error();
    });
    if sh.host_connected.load(Ordering::Relaxed) {
        s.flags |= Flags::HOST_CONNECTED;
    }
    if upload.is_active() {
        s.flags |= Flags::UPLOADING;
    }
    s
}
