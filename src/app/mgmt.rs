//! The management task: status, chunked upload with two-slot commit, KMZ, bypass.

use super::{read_some, Comp, Shared};
use embassy_time::Instant;
use embedded_io_async::{Read, Write};
use nanocal_compensator::mgmt::{self, flags, kind, Decoder, Reader, Status, Writer};
use nanocal_compensator::proxy::Gate;
use nanocal_compensator::slots::{self, SlotStorage};
use nanocal_compensator::upload::Upload;
use nanocal_model::{blob, MAX_AXES};

/// Load the newest valid model from storage into service (at start-up).
pub fn load_from_storage<S: SlotStorage>(storage: &mut S, buf: &mut [u8], sh: &Shared) {
    let found = slots::load_newest(storage, buf, |b| blob::decode(b).is_ok());
    match found {
        Some(a) => match blob::decode(&buf[..a.len]) {
            Ok(model) => {
                info!(
                    "model {=u32} loaded from slot {=usize} (seq {=u32})",
                    model.id(),
                    a.slot,
                    a.seq
                );
                sh.install(model, Some(a));
            }
            Err(_) => warn!("stored model vanished between checks"),
        },
        None => info!("no stored model"),
    }
}

/// Run the management channel. `buf` receives uploads (at least the largest blob).
pub async fn management<R: Read, W: Write, S: SlotStorage>(
    mut rx: R,
    mut tx: W,
    mut storage: S,
    buf: &mut [u8],
    sh: &Shared,
) -> ! {
    load_from_storage(&mut storage, buf, sh);
    let mut dec = Decoder::new();
    let mut upload = Upload::new();
    let mut inbuf = [0u8; 64];
    let mut reply = [0u8; mgmt::MAX_PAYLOAD];
    let mut frame = [0u8; mgmt::MAX_FRAME];
    loop {
        let n = read_some(&mut rx, &mut inbuf).await;
        for &b in &inbuf[..n] {
            match dec.feed(b) {
                Some(Ok(())) => {
                    let f = dec.frame();
                    let (k, seq) = (f.kind, f.seq);
                    let len = handle(
                        f.kind,
                        f.payload,
                        &mut reply,
                        &mut upload,
                        &mut storage,
                        buf,
                        sh,
                    );
                    if let Ok(m) = mgmt::encode(k | kind::REPLY, seq, &reply[..len], &mut frame) {
                        let _ = tx.write_all(&frame[..m]).await;
                        let _ = tx.flush().await;
                    }
                }
                Some(Err(_)) => warn!("management frame dropped (CRC or length)"),
                None => {}
            }
        }
    }
}

fn handle<S: SlotStorage>(
    k: u8,
    payload: &[u8],
    reply: &mut [u8],
    upload: &mut Upload,
    storage: &mut S,
    buf: &mut [u8],
    sh: &Shared,
) -> usize {
    let mut w = Writer::new(reply);
    let mut r = Reader::new(payload);
    let code = match k {
        kind::HELLO => {
            let _ = w.u8(mgmt::RESULT_OK);
            let _ = w.u16(mgmt::PROTOCOL);
            let _ = w.u16(blob::FORMAT_VERSION);
            let _ = w.u16(mgmt::MAX_CHUNK as u16);
            return w.len();
        }
        kind::STATUS => {
            let s = status(sh, upload);
            let _ = w.u8(mgmt::RESULT_OK);
            let _ = s.encode(&mut w);
            return w.len();
        }
        kind::UPLOAD_BEGIN => match (r.u32(), r.u32(), r.u16()) {
            (Ok(len), Ok(crc), Ok(ver)) => match upload.begin(len, crc, ver, buf.len()) {
                Ok(()) => mgmt::RESULT_OK,
                Err(e) => reject(sh, e.code()),
            },
            _ => mgmt::RESULT_BAD_REQUEST,
        },
        kind::UPLOAD_CHUNK => match r.u32() {
            Ok(offset) => match upload.chunk(buf, offset, r.rest()) {
                Ok(received) => {
                    let _ = w.u8(mgmt::RESULT_OK);
                    let _ = w.u32(received);
                    return w.len();
                }
                Err(e) => {
                    upload.abort();
                    reject(sh, e.code())
                }
            },
            Err(_) => mgmt::RESULT_BAD_REQUEST,
        },
        kind::UPLOAD_COMMIT => match upload.finish(buf) {
            Ok((model, len)) => {
                let current = sh.model.lock(|m| m.borrow().active);
                match slots::commit(storage, current, &buf[..len]) {
                    Ok(active) => {
                        let id = model.id();
                        sh.install(model, Some(active));
                        sh.model.lock(|m| {
                            let mut m = m.borrow_mut();
                            m.uploads_ok = m.uploads_ok.wrapping_add(1);
                        });
                        info!("model {=u32} committed to slot {=usize}", id, active.slot);
                        let _ = w.u8(mgmt::RESULT_OK);
                        let _ = w.u32(id);
                        let _ = w.u8(active.slot as u8);
                        let _ = w.u32(active.seq);
                        return w.len();
                    }
                    Err(_) => reject(sh, mgmt::RESULT_STORAGE),
                }
            }
            Err(e) => reject(sh, e.code()),
        },
        kind::UPLOAD_ABORT => {
            upload.abort();
            mgmt::RESULT_OK
        }
        kind::SET_KMZ => {
            let mut q = [0.0; MAX_AXES];
            let mut x = [0.0; MAX_AXES];
            let mut ok = true;
            for v in q.iter_mut().chain(x.iter_mut()) {
                match r.f64() {
                    Ok(f) if f.is_finite() => *v = f,
                    _ => ok = false,
                }
            }
            if !ok {
                mgmt::RESULT_BAD_REQUEST
            } else {
                let dir = [0i8; MAX_AXES];
                let kmz = sh.model.lock(|m| {
                    let mut m = m.borrow_mut();
                    let m = &mut *m;
                    let slow = m.slow;
                    let model = m.model.as_mut()?;
                    model.set_kmz_from_reference(&q, &x, &dir, &slow);
                    let mut k = [0.0; MAX_AXES];
                    for (a, v) in k.iter_mut().enumerate().take(model.axes()) {
                        *v = model.kmz_offset_um(a);
                    }
                    // the next command already uses the new offset
                    Some((k, Comp::new(model, &slow)))
                });
                match kmz {
                    Some((k, comp)) => {
                        sh.core.lock(|c| c.borrow_mut().comp = Some(comp));
                        sh.refold.signal(());
                        let persisted = persist(storage, sh);
                        let _ = w.u8(mgmt::RESULT_OK);
                        for v in k {
                            let _ = w.f64(v);
                        }
                        let _ = w.u8(u8::from(persisted));
                        return w.len();
                    }
                    None => mgmt::RESULT_NO_MODEL,
                }
            }
        }
        kind::BYPASS => match r.u8() {
            Ok(on) => {
                sh.core.lock(|c| c.borrow_mut().proxy.bypass = on != 0);
                mgmt::RESULT_OK
            }
            Err(_) => mgmt::RESULT_BAD_REQUEST,
        },
        _ => mgmt::RESULT_UNKNOWN_KIND,
    };
    let _ = w.u8(code);
    w.len()
}

/// Store the model in service (e.g. after a KMZ change) to the other slot; the blob is built
/// on the stack, so an upload in progress is not disturbed. False when it could not be stored
/// (the change stays in RAM).
fn persist<S: SlotStorage>(storage: &mut S, sh: &Shared) -> bool {
    let mut bytes = [0u8; blob::MAX_BLOB_LEN];
    let (len, current) = sh.model.lock(|m| {
        let m = m.borrow();
        let len = m
            .model
            .as_ref()
            .map(|model| blob::encode(model, &mut bytes));
        (len, m.active)
    });
    let Some(Ok(len)) = len else {
        return false;
    };
    match slots::commit(storage, current, &bytes[..len]) {
        Ok(active) => {
            sh.model.lock(|m| m.borrow_mut().active = Some(active));
            true
        }
        Err(_) => {
            warn!("KMZ change not stored");
            false
        }
    }
}

fn reject(sh: &Shared, code: u8) -> u8 {
    sh.model.lock(|m| {
        let mut m = m.borrow_mut();
        m.uploads_rejected = m.uploads_rejected.wrapping_add(1);
        m.last_upload_error = code;
    });
    warn!("upload rejected: code {=u8}", code);
    code
}

fn status(sh: &Shared, upload: &Upload) -> Status {
    let mut s = Status {
        uptime_ms: Instant::now().as_millis() as u32,
        slot: 0xFF,
        ..Default::default()
    };
    sh.model.lock(|m| {
        let m = m.borrow();
        if let Some(model) = &m.model {
            s.flags |= flags::MODEL;
            s.model_id = model.id();
            for a in 0..model.axes().min(3) {
                s.kmz_um[a] = model.kmz_offset_um(a);
            }
        }
        if let Some(a) = m.active {
            s.slot = a.slot as u8;
            s.slot_seq = a.seq;
        }
        s.sensors = m.sensors;
        for (i, ch) in m
            .faults
            .channels
            .iter()
            .enumerate()
            .take(mgmt::STATUS_SENSORS)
        {
            s.temps_c[i] = ch.value_c().unwrap_or(f32::NAN);
            s.sensor_bits[i] = ch.status_bits();
        }
        s.slow_outside = m.slow_outside;
        if m.slow_outside != 0 {
            s.flags |= flags::EXTRAPOLATING;
        }
        s.folds = m.folds;
        s.uploads_ok = m.uploads_ok;
        s.uploads_rejected = m.uploads_rejected;
        s.last_upload_error = m.last_upload_error;
    });
    sh.core.lock(|c| {
        let c = c.borrow();
        if c.proxy.bypass {
            s.flags |= flags::BYPASS;
        }
        if c.proxy.gate == Gate::SensorFault {
            s.flags |= flags::SENSOR_BLOCK;
        }
        if c.proxy.unit_mismatch() {
            s.flags |= flags::UNIT_MISMATCH;
        }
        let k = c.proxy.counters;
        s.host_lines = k.host_lines;
        s.moves = k.moves;
        s.refused = k.refused;
        s.mapped_replies = k.mapped_replies;
        s.pending_error = c.proxy.pending_error();
    });
    if upload.is_active() {
        s.flags |= flags::UPLOADING;
    }
    s
}
