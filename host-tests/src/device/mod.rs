//! The device client: talks to the inline compensator's management channel (a second USB
//! CDC-ACM interface, e.g. `/dev/ttyACM1`, or a TCP socket for the QEMU board) and its GCS
//! stream. The protocol itself (frames, status layout) lives in `nanocal_compensator::mgmt`, shared
//! with the firmware.

use nanocal_compensator::identity::ResetCause;
use nanocal_compensator::mgmt::{self, kind, Decoder, Reader, Status};
use nanocal_compensator::settings::Settings;
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
    #[error("device refused request kind {kind:#04x}: code {code} ({meaning}){detail}")]
    Refused {
        /// Request kind.
        kind: u8,
        /// Result code.
        code: u8,
        /// What the code means.
        meaning: &'static str,
        /// What the reply adds, as text (empty, or ": …"): for an upload refused for an input,
        /// which input and why.
        detail: String,
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

/// Open `spec`: `tcp:HOST:PORT` (or `HOST:PORT`) for a TCP socket, `unix:PATH` for a Unix socket
/// (the QEMU board's management port), otherwise a serial device path.
/// Reads time out after `timeout` (a read that times out returns `TimedOut`/`WouldBlock`).
pub fn open(spec: &str, timeout: Duration) -> Result<Box<dyn Port>, DeviceError> {
    let io_err = |source| DeviceError::Io {
        port: spec.to_string(),
        source,
    };
    if let Some(path) = spec.strip_prefix("unix:") {
        let s = std::os::unix::net::UnixStream::connect(path).map_err(io_err)?;
        s.set_read_timeout(Some(timeout)).map_err(io_err)?;
        return Ok(Box::new(s));
    }
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

/// What HELLO tells.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Hello {
    /// Management protocol version.
    pub protocol: u16,
    /// Blob format version the firmware reads.
    pub blob_format: u16,
    /// Largest upload chunk.
    pub max_chunk: u16,
    /// Firmware version.
    pub firmware: String,
    /// Chip unique ID.
    pub uid: [u8; 12],
    /// Why the device last reset.
    pub reset_cause: ResetCause,
}

/// The chip UID as the USB serial number shows it (24 hex digits).
pub fn uid_hex(uid: &[u8; 12]) -> String {
    let mut b = [0u8; 24];
    nanocal_compensator::identity::usb_serial(uid, &mut b);
    String::from_utf8_lossy(&b).into_owned()
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
                        let detail = match (code, data.first()) {
                            (mgmt::RESULT_INPUT, Some(&input)) => {
                                match nanocal_compensator::inputs::describe_code(input) {
                                    Some((what, index)) => format!(": input {index}, {what}"),
                                    None => format!(": input code {input:#04x}"),
                                }
                            }
                            _ => String::new(),
                        };
                        return Err(DeviceError::Refused {
                            kind: k,
                            code,
                            meaning: result_meaning(code),
                            detail,
                        });
                    }
                    return Ok(data.to_vec());
                }
            }
        }
    }

    /// Protocol version, blob format version and largest chunk of the firmware.
    pub fn hello(&mut self) -> Result<(u16, u16, u16), DeviceError> {
        let h = self.identify()?;
        Ok((h.protocol, h.blob_format, h.max_chunk))
    }

    /// Everything HELLO tells: versions, firmware, chip UID, reset cause.
    pub fn identify(&mut self) -> Result<Hello, DeviceError> {
        let d = self.request(kind::HELLO, &[])?;
        let mut r = Reader::new(&d);
        let p = |e: mgmt::FrameError| DeviceError::Protocol(kind::HELLO, e.to_string());
        let (protocol, blob_format, max_chunk) = (
            r.u16().map_err(p)?,
            r.u16().map_err(p)?,
            r.u16().map_err(p)?,
        );
        let n = r.u8().map_err(p)?;
        let firmware = String::from_utf8_lossy(r.bytes(usize::from(n)).map_err(p)?).into_owned();
        let mut uid = [0u8; 12];
        uid.copy_from_slice(r.bytes(12).map_err(p)?);
        let reset_cause = ResetCause::from_code(r.u8().map_err(p)?);
        Ok(Hello {
            protocol,
            blob_format,
            max_chunk,
            firmware,
            uid,
            reset_cause,
        })
    }

    /// The device's settings.
    pub fn config(&mut self) -> Result<Settings, DeviceError> {
        let d = self.request(kind::CONFIG_GET, &[])?;
        Settings::decode(&d).map_err(|e| DeviceError::Protocol(kind::CONFIG_GET, e.to_string()))
    }

    /// Store and apply settings (checked on the host first, and again by the device).
    pub fn set_config(&mut self, s: &Settings) -> Result<(), DeviceError> {
        s.validate()
            .map_err(|e| DeviceError::Protocol(kind::CONFIG_SET, e.to_string()))?;
        self.request(kind::CONFIG_SET, &s.encode()).map(|_| ())
    }

    /// Reset the device (it answers first).
    pub fn reset(&mut self) -> Result<(), DeviceError> {
        self.request(kind::RESET, &[]).map(|_| ())
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
        "chip UID: {}  last reset: {}\n",
        uid_hex(&s.uid),
        ResetCause::from_code(s.reset_cause)
    );
    o += &format!(
        "status LED: {}  host port open: {}\n",
        match s.led {
            1 => "compensating (on)",
            2 => "bypass (slow blink)",
            3 => "no model (short flash)",
            4 => "fault (fast blink)",
            _ => "?",
        },
        flag(flags::HOST_CONNECTED)
    );
    o += &format!(
        "model: {}\n",
        if s.flags & flags::MODEL != 0 {
            format!("{:#010x}", s.model_id)
        } else {
            "none".into()
        }
    );
    o += &format!("compensation bypassed: {}\n", flag(flags::BYPASS));
    o += &format!(
        "sensors warming up (no first reading yet): {}  fold age {} ms{}\n",
        flag(flags::WARMING_UP),
        s.fold_age_ms,
        if s.flags & flags::FOLD_STALE != 0 {
            " (STALE: moves refused)"
        } else {
            ""
        }
    );
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
                format!(
                    " (last fault: {})",
                    nanocal_compensator::sensor::SensorFault::from_code(bits >> 4)
                        .map(|f| f.to_string())
                        .unwrap_or_else(|| format!("code {}", bits >> 4))
                )
            } else {
                String::new()
            }
        );
    }
    for i in 0..s.aux.len() {
        if s.aux_bits[i] & 0x0F != 4 || !s.aux[i].is_nan() {
            o += &format!("aux {i}: {:>9.4}  bits {:#04x}\n", s.aux[i], s.aux_bits[i]);
        }
    }
    o += &format!(
        "flash ECC errors read: {}  sensor reconfigurations: {}\n",
        s.flash_ecc_errors, s.sensor_reconfigs
    );
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

/// A human-readable settings report.
pub fn format_settings(s: &Settings) -> String {
    use nanocal_compensator::sensor::{Chip, Mains};
    use nanocal_compensator::settings::AuxSource;
    let mut o = String::new();
    o += &format!(
        "stage baud: {} (8N1; applied at the next reset)\n",
        s.stage_baud
    );
    o += &format!("stage unit: {}\n", s.stage_unit.name());
    let names: Vec<String> = s
        .axis_names
        .iter()
        .map(|a| String::from_utf8_lossy(a.as_bytes()).into_owned())
        .collect();
    o += &format!("GCS axis names (model axes 0,1,2): {}\n", names.join(","));
    o += &format!(
        "mains: {} Hz  sample period: {} ms  fold period: {} ms (readings averaged)\n",
        if s.mains == Mains::Hz50 { 50 } else { 60 },
        s.sample_period_ms,
        s.fold_period_ms
    );
    for (cs, c) in s.sensors.iter().enumerate() {
        let d = match c {
            None => "none".to_string(),
            Some(Chip::Max31856 { tc }) => format!("MAX31856, type {} thermocouple", tc.letter()),
            Some(Chip::Max31865 {
                r_ref_ohm,
                r0_ohm,
                wires,
            }) => format!(
                "MAX31865, PT{} {}-wire, R_ref {} Ω",
                r0_ohm.round() as u32,
                *wires as u8,
                r_ref_ohm
            ),
        };
        o += &format!("sensor CS{cs}: {d}\n");
    }
    for (i, a) in s.aux.iter().enumerate() {
        let d = match a {
            AuxSource::None => "none".to_string(),
            AuxSource::AirPressure => "air pressure, hPa (LPS22HB)".to_string(),
            AuxSource::Force {
                channel,
                scale_n_per_count,
                offset_n,
            } => format!("force, N = {offset_n} + {scale_n_per_count} × ADC{channel}"),
        };
        o += &format!("aux {i}: {d}\n");
    }
    o
}
