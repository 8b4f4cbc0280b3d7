//! The device client: talks to the inline compensator's management channel (a second USB
//! CDC-ACM interface, e.g. `/dev/ttyACM1`, or a TCP socket for the QEMU board) and its GCS
//! stream. The protocol itself (frames, status layout) lives in `nanocal_compensator::mgmt`, shared
//! with the firmware.

use nanocal_compensator::mgmt::{self, kind, Decoder, Reader, Status};
use nanocal_model::{blob, MAX_AXES};
use std::io::{self, Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

/// Errors of the device client.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DeviceError {
    /// The port could not be opened or an I/O operation failed.
    #[error("device I/O on {port}: {source}")]
    Io {
        /// Port specification.
        port: String,
        /// Cause.
        source: io::Error,
    },
    /// The device did not answer in time.
    #[error("no reply from the device within {0:?} (request kind {1:#04x})")]
    Timeout(Duration, u8),
    /// The device refused the request.
    #[error("device refused request kind {kind:#04x}: code {code} ({meaning})")]
    Refused {
        /// Request kind.
        kind: u8,
        /// Result code.
        code: u8,
        /// What the code means.
        meaning: &'static str,
    },
    /// The reply was malformed.
    #[error("malformed reply to request kind {0:#04x}: {1}")]
    Protocol(u8, String),
    /// The blob is not valid (checked on the host before sending).
    #[error("blob rejected before upload: {0}")]
    Blob(String),
}

pub use nanocal_compensator::mgmt::result_meaning;

/// A byte stream to the device.
pub trait Port: Read + Write + Send {}
impl<T: Read + Write + Send> Port for T {}

/// Open `spec`: `tcp:HOST:PORT` (or `HOST:PORT`) for a socket, otherwise a serial device path.
/// Reads time out after `timeout` (a read that times out returns `TimedOut`/`WouldBlock`).
pub fn open(spec: &str, timeout: Duration) -> Result<Box<dyn Port>, DeviceError> {
    let io_err = |source| DeviceError::Io {
        port: spec.to_string(),
        source,
    };
    let addr = spec.strip_prefix("tcp:");
    let looks_tcp = addr.is_some() || (!spec.starts_with('/') && spec.contains(':'));
    if looks_tcp {
        let addr = addr.unwrap_or(spec);
        let s = TcpStream::connect(addr).map_err(io_err)?;
        s.set_nodelay(true).map_err(io_err)?;
        s.set_read_timeout(Some(timeout)).map_err(io_err)?;
        Ok(Box::new(s))
    } else {
        let p = serialport::new(spec, 115_200)
            .timeout(timeout)
            .open()
            .map_err(|e| io_err(io::Error::other(e)))?;
        Ok(Box::new(p))
    }
}

/// Management client.
pub struct Client {
    port: Box<dyn Port>,
    name: String,
    seq: u8,
    dec: Decoder,
    /// How long to wait for each reply.
    pub timeout: Duration,
}

/// Result of a committed upload.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Committed {
    /// Model id now in service.
    pub model_id: u32,
    /// Flash slot written.
    pub slot: u8,
    /// Commit sequence number.
    pub seq: u32,
}

impl Client {
    /// Open the management channel at `spec` (see [`open`]).
    pub fn open(spec: &str) -> Result<Self, DeviceError> {
        let timeout = Duration::from_secs(5);
        Ok(Self::new(
            open(spec, Duration::from_millis(50))?,
            spec,
            timeout,
        ))
    }

    /// A client over an already open port.
    pub fn new(port: Box<dyn Port>, name: &str, timeout: Duration) -> Self {
        Self {
            port,
            name: name.to_string(),
            seq: 0,
            dec: Decoder::new(),
            timeout,
        }
    }

    fn io(&self, source: io::Error) -> DeviceError {
        DeviceError::Io {
            port: self.name.clone(),
            source,
        }
    }

    /// Send one request; returns the reply's data (after a successful result code).
    pub fn request(&mut self, k: u8, payload: &[u8]) -> Result<Vec<u8>, DeviceError> {
        self.seq = self.seq.wrapping_add(1);
        let seq = self.seq;
        let mut frame = [0u8; mgmt::MAX_FRAME];
        let n = mgmt::encode(k, seq, payload, &mut frame)
            .map_err(|e| DeviceError::Protocol(k, e.to_string()))?;
        self.port.write_all(&frame[..n]).map_err(|e| self.io(e))?;
        self.port.flush().map_err(|e| self.io(e))?;
        let deadline = Instant::now() + self.timeout;
        let mut buf = [0u8; 512];
        loop {
            if Instant::now() > deadline {
                return Err(DeviceError::Timeout(self.timeout, k));
            }
            let got = match self.port.read(&mut buf) {
                Ok(0) => {
                    return Err(self.io(io::Error::new(
                        io::ErrorKind::UnexpectedEof,
                        "device closed the connection",
                    )))
                }
                Ok(n) => n,
                Err(e)
                    if matches!(
                        e.kind(),
                        io::ErrorKind::TimedOut
                            | io::ErrorKind::WouldBlock
                            | io::ErrorKind::Interrupted
                    ) =>
                {
                    continue
                }
                Err(e) => return Err(self.io(e)),
            };
            for &b in &buf[..got] {
                if let Some(Ok(())) = self.dec.feed(b) {
                    let f = self.dec.frame();
                    if f.kind != (k | kind::REPLY) || f.seq != seq {
                        continue; // a stale reply
                    }
                    let (&code, data) = f
                        .payload
                        .split_first()
                        .ok_or_else(|| DeviceError::Protocol(k, "empty reply".into()))?;
                    if code != mgmt::RESULT_OK {
                        return Err(DeviceError::Refused {
                            kind: k,
                            code,
                            meaning: result_meaning(code),
                        });
                    }
                    return Ok(data.to_vec());
                }
            }
        }
    }

    /// Protocol version, blob format version and largest chunk of the firmware.
    pub fn hello(&mut self) -> Result<(u16, u16, u16), DeviceError> {
        let d = self.request(kind::HELLO, &[])?;
        let mut r = Reader::new(&d);
        let p = |e: mgmt::FrameError| DeviceError::Protocol(kind::HELLO, e.to_string());
        Ok((
            r.u16().map_err(p)?,
            r.u16().map_err(p)?,
            r.u16().map_err(p)?,
        ))
    }

    /// The device's status.
    pub fn status(&mut self) -> Result<Status, DeviceError> {
        let d = self.request(kind::STATUS, &[])?;
        Status::decode(&mut Reader::new(&d))
            .map_err(|e| DeviceError::Protocol(kind::STATUS, e.to_string()))
    }

    /// Upload raw bytes as they are (no host-side check): the firmware verifies everything.
    /// `announced_len`/`crc` let tests lie about the blob.
    pub fn upload_raw(
        &mut self,
        bytes: &[u8],
        announced_len: u32,
        crc: u32,
        format_version: u16,
        commit: bool,
    ) -> Result<Option<Committed>, DeviceError> {
        let mut p = Vec::with_capacity(10);
        p.extend_from_slice(&announced_len.to_le_bytes());
        p.extend_from_slice(&crc.to_le_bytes());
        p.extend_from_slice(&format_version.to_le_bytes());
        self.request(kind::UPLOAD_BEGIN, &p)?;
        for (i, chunk) in bytes.chunks(mgmt::MAX_CHUNK).enumerate() {
            let mut p = Vec::with_capacity(4 + chunk.len());
            p.extend_from_slice(&((i * mgmt::MAX_CHUNK) as u32).to_le_bytes());
            p.extend_from_slice(chunk);
            self.request(kind::UPLOAD_CHUNK, &p)?;
        }
        if !commit {
            return Ok(None);
        }
        let d = self.request(kind::UPLOAD_COMMIT, &[])?;
        let mut r = Reader::new(&d);
        let p = |e: mgmt::FrameError| DeviceError::Protocol(kind::UPLOAD_COMMIT, e.to_string());
        Ok(Some(Committed {
            model_id: r.u32().map_err(p)?,
            slot: r.u8().map_err(p)?,
            seq: r.u32().map_err(p)?,
        }))
    }

    /// Upload a blob: decoded on the host first (so a bad file never reaches the device), then
    /// sent in chunks with its CRC and format version, verified and committed by the firmware.
    pub fn upload(&mut self, blob_bytes: &[u8]) -> Result<Committed, DeviceError> {
        blob::decode(blob_bytes).map_err(|e| DeviceError::Blob(e.to_string()))?;
        let version = u16::from_le_bytes([blob_bytes[4], blob_bytes[5]]);
        let c = self.upload_raw(
            blob_bytes,
            blob_bytes.len() as u32,
            blob::crc32(blob_bytes),
            version,
            true,
        )?;
        c.ok_or_else(|| DeviceError::Protocol(kind::UPLOAD_COMMIT, "no commit reply".into()))
    }

    /// Set λ_KMZ so that the model maps the measured reference `x_meas_um` to the command
    /// `q_cmd_um` that was sent; the device stores the changed model in its other flash slot.
    /// Returns the new λ_KMZ per axis.
    pub fn set_kmz(
        &mut self,
        q_cmd_um: [f64; MAX_AXES],
        x_meas_um: [f64; MAX_AXES],
    ) -> Result<[f64; MAX_AXES], DeviceError> {
        let mut p = Vec::with_capacity(48);
        for v in q_cmd_um.iter().chain(x_meas_um.iter()) {
            p.extend_from_slice(&v.to_le_bytes());
        }
        let d = self.request(kind::SET_KMZ, &p)?;
        let mut r = Reader::new(&d);
        let mut k = [0.0; MAX_AXES];
        for v in k.iter_mut() {
            *v = r
                .f64()
                .map_err(|e| DeviceError::Protocol(kind::SET_KMZ, e.to_string()))?;
        }
        Ok(k)
    }

    /// Bypass (`true`) or enable (`false`) compensation.
    pub fn bypass(&mut self, on: bool) -> Result<(), DeviceError> {
        self.request(kind::BYPASS, &[u8::from(on)]).map(|_| ())
    }
}

/// A human-readable status report.
pub fn format_status(s: &Status) -> String {
    use mgmt::flags;
    let mut o = String::new();
    let flag = |f: u16| if s.flags & f != 0 { "yes" } else { "no" };
    o += &format!(
        "model: {}\n",
        if s.flags & flags::MODEL != 0 {
            format!("{:#010x} (slot {}, seq {})", s.model_id, s.slot, s.slot_seq)
        } else {
            "none".into()
        }
    );
    o += &format!("compensation bypassed: {}\n", flag(flags::BYPASS));
    o += &format!(
        "moves blocked by a sensor fault: {}\n",
        flag(flags::SENSOR_BLOCK)
    );
    o += &format!(
        "moves refused, controller unit is not the model's µm: {}\n",
        flag(flags::UNIT_MISMATCH)
    );
    o += &format!(
        "extrapolating (slow inputs outside the training envelope): {} (bits {:#06x})\n",
        flag(flags::EXTRAPOLATING),
        s.slow_outside
    );
    for i in 0..usize::from(s.sensors).min(s.temps_c.len()) {
        let bits = s.sensor_bits[i];
        let state = match bits & 0x0F {
            0 => "ok",
            1 => "holding last good value",
            2 => "FAILED",
            _ => "not read yet",
        };
        o += &format!(
            "sensor {i}: {:>9.4} °C  {state}{}\n",
            s.temps_c[i],
            if bits >> 4 != 0 {
                format!(" (last fault code {})", bits >> 4)
            } else {
                String::new()
            }
        );
    }
    o += &format!(
        "λ_KMZ µm: {:.6} {:.6} {:.6}\n",
        s.kmz_um[0], s.kmz_um[1], s.kmz_um[2]
    );
    o += &format!(
        "lines {}  moves {}  refused {}  mapped replies {}  folds {}\n",
        s.host_lines, s.moves, s.refused, s.mapped_replies, s.folds
    );
    o += &format!(
        "uploads ok {}  rejected {} (last code {}: {})\n",
        s.uploads_ok,
        s.uploads_rejected,
        s.last_upload_error,
        result_meaning(s.last_upload_error)
    );
    o += &format!(
        "pending GCS error {}  uptime {:.1} s\n",
        s.pending_error,
        f64::from(s.uptime_ms) / 1000.0
    );
    o
}
