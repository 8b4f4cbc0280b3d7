//! The device client: talks to the inline compensator's management channel (a second USB
//! CDC-ACM interface, e.g. `/dev/ttyACM1`, or a TCP socket for the QEMU board) and its GCS
//! stream. The protocol itself (frames, typed requests and replies, status layout, result
//! codes) is `nanocal_interface`'s, shared with the firmware.

pub mod device_path;

pub use nanocal_interface::mgmt::Hello;
use nanocal_interface::mgmt::{self, Decoder, InputCode, Kind, Refusal, Reply, Request};
use nanocal_interface::settings::Settings;
use nanocal_interface::status::{ChannelStatus, Flags, Status};
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
    #[error("no reply from the device within {0:?} (request: {1})")]
    Timeout(Duration, Kind),
    /// The device refused the request.
    #[error("device refused request ({kind}): code {} ({refusal}){}", refusal.code(), input.map(|i| format!(": {i}")).unwrap_or_default())]
    Refused {
        /// Request kind.
        kind: Kind,
        /// Why.
        refusal: Refusal,
        /// For an upload refused for an input: which input and why.
        input: Option<InputCode>,
    },
    /// The reply was malformed, or not the one the request asks for.
    #[error("malformed reply to request ({0}): {1}")]
    Protocol(Kind, String),
    /// The blob is not valid (checked on the host before sending).
    #[error("blob rejected before upload: {0}")]
    Blob(String),
    /// The device speaks another version of the management protocol: its bytes would be
    /// misread, so nothing but `HELLO` is exchanged.
    #[error("the device on {port} speaks management protocol {device}{}, this nanocal speaks {host}: flash the firmware of this nanocal's release (`cargo run --release` at the repository root) or use the nanocal built with the device's firmware", firmware.as_ref().map(|f| format!(" (firmware {f})")).unwrap_or_default())]
    ProtocolVersion {
        /// Port specification.
        port: String,
        /// The device's protocol version.
        device: u16,
        /// This host's ([`mgmt::PROTOCOL`]).
        host: u16,
        /// The device's firmware version, when its `HELLO` could be read.
        firmware: Option<String>,
    },
    /// After an upload the device reports another content hash than the blob's: it stored
    /// other bytes than were sent.
    #[error("the device stored model {model_id:#010x} with blob CRC {device:#010x}, the uploaded blob's is {blob:#010x}")]
    StoredOtherBlob {
        /// The model's id.
        model_id: u32,
        /// The CRC the device reports.
        device: u32,
        /// The blob's own CRC.
        blob: u32,
    },
}

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
    /// The decoder's clock, ms: the time spent waiting on a silent port (see [`Self::now_ms`]).
    silent_ms: u32,
    /// The device's `HELLO` said it speaks [`mgmt::PROTOCOL`].
    protocol_checked: bool,
    /// How long to wait for each reply.
    pub timeout: Duration,
}

/// The chip UID as the USB serial number shows it (24 hex digits).
pub fn uid_hex(uid: &[u8; 12]) -> String {
    let mut b = [0u8; 24];
    nanocal_interface::identity::usb_serial(uid, &mut b);
    String::from_utf8_lossy(&b).into_owned()
}

/// Result of a committed upload.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Committed {
    /// Model id now in service.
    pub model_id: u32,
    /// The CRC-32 of its blob as the device stored it (its content hash).
    pub model_crc32: u32,
    /// Uploads the device accepted since it started.
    pub uploads_accepted: u32,
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
            silent_ms: 0,
            protocol_checked: false,
            timeout,
        }
    }

    /// Milliseconds on the decoder's clock (it wraps after 49 days, as the decoder expects). It
    /// counts only the time reads waited on a silent port: the decoder drops a reply still
    /// incomplete [`mgmt::FRAME_TIMEOUT_MS`] after its first byte, and that must mean the device
    /// went quiet mid-frame (reset, cable), never that this process was off the CPU between two
    /// reads of one reply (seen on a loaded machine: the reply dropped, the request timed out).
    fn now_ms(&self) -> u32 {
        self.silent_ms
    }

    fn io(&self, source: io::Error) -> DeviceError {
        DeviceError::Io {
            port: self.name.clone(),
            source,
        }
    }

    /// Send one request; its reply, or the device's refusal as [`DeviceError::Refused`]. The
    /// first request of a client asks `HELLO` first: a device of another protocol version is
    /// [`DeviceError::ProtocolVersion`], before any bytes of its are misread.
    pub fn request(&mut self, req: &Request<'_>) -> Result<Reply, DeviceError> {
        if !matches!(req, Request::Hello) && !self.protocol_checked {
            self.identify()?;
        }
        let k = req.kind();
        let payload = self.exchange(req)?;
        match Reply::decode(k, &payload) {
            Ok(Reply::Refused { refusal, input }) => Err(DeviceError::Refused {
                kind: k,
                refusal,
                input,
            }),
            Ok(reply) => Ok(reply),
            Err(e) => Err(DeviceError::Protocol(k, e.to_string())),
        }
    }

    /// Send one request; the payload of its reply.
    fn exchange(&mut self, req: &Request<'_>) -> Result<Vec<u8>, DeviceError> {
        let k = req.kind();
        self.seq = self.seq.wrapping_add(1);
        let seq = self.seq;
        let mut frame = [0u8; mgmt::MAX_FRAME];
        let n = req
            .frame(seq, &mut frame)
            .map_err(|e| DeviceError::Protocol(k, e.to_string()))?;
        self.port.write_all(&frame[..n]).map_err(|e| self.io(e))?;
        self.port.flush().map_err(|e| self.io(e))?;
        let deadline = Instant::now() + self.timeout;
        let mut buf = [0u8; 512];
        loop {
            if Instant::now() > deadline {
                return Err(DeviceError::Timeout(self.timeout, k));
            }
            let waited = Instant::now();
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
                    let ms = waited.elapsed().as_millis().min(u128::from(u32::MAX)) as u32;
                    self.silent_ms = self.silent_ms.wrapping_add(ms);
                    continue;
                }
                Err(e) => return Err(self.io(e)),
            };
            let now = self.now_ms();
            for &b in &buf[..got] {
                let mut ev = self.dec.feed(b, now);
                while let Some(e) = ev {
                    if e.is_ok() {
                        let f = self.dec.frame();
                        if f.kind == k.reply_code() && f.seq == seq {
                            // (a later reply in the same read belongs to no request)
                            return Ok(f.payload.to_vec());
                        }
                        // else a stale reply
                    }
                    ev = self.dec.next(now);
                }
            }
        }
    }

    /// The reply to `req`, which must be `want`'s.
    fn expect<T>(
        &mut self,
        req: &Request<'_>,
        want: impl FnOnce(Reply) -> Option<T>,
    ) -> Result<T, DeviceError> {
        let reply = self.request(req)?;
        let text = format!("{reply:?}");
        want(reply).ok_or_else(|| DeviceError::Protocol(req.kind(), format!("unexpected {text}")))
    }

    /// Protocol version, blob format version and largest chunk of the firmware.
    pub fn hello(&mut self) -> Result<(u16, u16, u16), DeviceError> {
        let h = self.identify()?;
        Ok((h.protocol, h.blob_format, h.max_chunk))
    }

    /// Everything HELLO tells: versions, firmware, chip UID, reset cause. A device of another
    /// protocol version is [`DeviceError::ProtocolVersion`] (HELLO's first field is the
    /// version in every protocol).
    pub fn identify(&mut self) -> Result<Hello, DeviceError> {
        let k = Kind::Hello;
        let payload = self.exchange(&Request::Hello)?;
        let reply = Reply::decode(k, &payload);
        if let [0, lo, hi, ..] = payload[..] {
            let device = u16::from_le_bytes([lo, hi]);
            if device != mgmt::PROTOCOL {
                let firmware = match &reply {
                    Ok(Reply::Hello(h)) => Some(h.firmware.to_string()),
                    _ => None,
                };
                self.protocol_checked = false;
                return Err(DeviceError::ProtocolVersion {
                    port: self.name.clone(),
                    device,
                    host: mgmt::PROTOCOL,
                    firmware,
                });
            }
        }
        match reply {
            Ok(Reply::Hello(h)) => {
                self.protocol_checked = true;
                Ok(h)
            }
            Ok(Reply::Refused { refusal, input }) => Err(DeviceError::Refused {
                kind: k,
                refusal,
                input,
            }),
            Ok(r) => Err(DeviceError::Protocol(k, format!("unexpected {r:?}"))),
            Err(e) => Err(DeviceError::Protocol(k, e.to_string())),
        }
    }

    /// The device's settings.
    pub fn config(&mut self) -> Result<Settings, DeviceError> {
        self.expect(&Request::ConfigGet, |r| match r {
            Reply::ConfigGet(s) => Some(s),
            _ => None,
        })
    }

    /// Store and apply settings (checked on the host first, and again by the device).
    pub fn set_config(&mut self, s: &Settings) -> Result<(), DeviceError> {
        s.validate()
            .map_err(|e| DeviceError::Protocol(Kind::ConfigSet, e.to_string()))?;
        self.expect(&Request::ConfigSet(*s), |r| {
            matches!(r, Reply::ConfigSet).then_some(())
        })
    }

    /// Reset the device (it answers first).
    pub fn reset(&mut self) -> Result<(), DeviceError> {
        self.expect(&Request::Reset, |r| matches!(r, Reply::Reset).then_some(()))
    }

    /// The device's status.
    pub fn status(&mut self) -> Result<Status, DeviceError> {
        self.expect(&Request::Status, |r| match r {
            Reply::Status(s) => Some(s),
            _ => None,
        })
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
        let begin = Request::UploadBegin {
            total_len: announced_len,
            crc32: crc,
            format_version,
        };
        self.expect(&begin, |r| matches!(r, Reply::UploadBegin).then_some(()))?;
        for (i, chunk) in bytes.chunks(mgmt::MAX_CHUNK).enumerate() {
            let req = Request::UploadChunk {
                offset: (i * mgmt::MAX_CHUNK) as u32,
                bytes: chunk,
            };
            self.expect(&req, |r| {
                matches!(r, Reply::UploadChunk { .. }).then_some(())
            })?;
        }
        if !commit {
            return Ok(None);
        }
        self.expect(&Request::UploadCommit, |r| match r {
            Reply::UploadCommit {
                model_id,
                model_crc32,
                uploads_accepted,
            } => Some(Some(Committed {
                model_id,
                model_crc32,
                uploads_accepted,
            })),
            _ => None,
        })
    }

    /// Upload a blob: decoded on the host first (so a bad file never reaches the device), then
    /// sent in chunks with its CRC and format version, verified and committed by the firmware,
    /// which must report the blob's own CRC as the content hash of what it stored
    /// ([`DeviceError::StoredOtherBlob`] otherwise).
    pub fn upload(&mut self, blob_bytes: &[u8]) -> Result<Committed, DeviceError> {
        blob::decode(blob_bytes).map_err(|e| DeviceError::Blob(e.to_string()))?;
        let blob_crc = blob::stored_crc(blob_bytes)
            .ok_or_else(|| DeviceError::Blob("shorter than a header".into()))?;
        let version = u16::from_le_bytes([blob_bytes[4], blob_bytes[5]]);
        let c = self.upload_raw(
            blob_bytes,
            blob_bytes.len() as u32,
            nanocal_interface::crc32(blob_bytes),
            version,
            true,
        )?;
        let c =
            c.ok_or_else(|| DeviceError::Protocol(Kind::UploadCommit, "no commit reply".into()))?;
        if c.model_crc32 != blob_crc {
            return Err(DeviceError::StoredOtherBlob {
                model_id: c.model_id,
                device: c.model_crc32,
                blob: blob_crc,
            });
        }
        Ok(c)
    }

    /// Set λ_KMZ so that the model maps the measured reference `x_meas_um` to the command
    /// `q_cmd_um` that was sent; the device stores it with its model. Returns the new λ_KMZ
    /// per axis.
    pub fn set_kmz(
        &mut self,
        q_cmd_um: [f64; MAX_AXES],
        x_meas_um: [f64; MAX_AXES],
    ) -> Result<[f64; MAX_AXES], DeviceError> {
        let req = Request::SetKmz {
            q_cmd_um,
            x_meas_um,
        };
        self.expect(&req, |r| match r {
            Reply::SetKmz { kmz_um, .. } => Some(kmz_um),
            _ => None,
        })
    }

    /// Bypass (`true`) or enable (`false`) compensation.
    pub fn bypass(&mut self, on: bool) -> Result<(), DeviceError> {
        self.expect(&Request::Bypass { on }, |r| {
            matches!(r, Reply::Bypass).then_some(())
        })
    }
}

/// A human-readable status report.
pub fn format_status(s: &Status) -> String {
    let mut o = String::new();
    let flag = |f: Flags| if s.flags.contains(f) { "yes" } else { "no" };
    o += &format!(
        "chip UID: {}  last reset: {}\n",
        uid_hex(&s.uid),
        s.reset_cause
    );
    o += &format!(
        "status LED: {}  host port open: {}\n",
        s.led,
        flag(Flags::HOST_CONNECTED)
    );
    o += &format!(
        "model: {}\n",
        if s.flags.contains(Flags::MODEL) {
            format!("{:#010x}  blob CRC {:#010x}", s.model_id, s.model_crc32)
        } else {
            "none".into()
        }
    );
    o += &format!("compensation bypassed: {}\n", flag(Flags::BYPASS));
    o += &format!(
        "sensors warming up (no first reading yet): {}  fold age {} ms{}\n",
        flag(Flags::WARMING_UP),
        s.fold_age_ms,
        if s.flags.contains(Flags::FOLD_STALE) {
            " (STALE: moves refused)"
        } else {
            ""
        }
    );
    o += &format!(
        "moves blocked by a sensor fault: {}\n",
        flag(Flags::SENSOR_BLOCK)
    );
    o += &format!(
        "moves refused, controller unit is not the model's µm: {}\n",
        flag(Flags::UNIT_MISMATCH)
    );
    o += &format!(
        "extrapolating (slow inputs outside the training envelope): {} (bits {:#06x})\n",
        flag(Flags::EXTRAPOLATING),
        s.slow_outside
    );
    o += &format_stale(s);
    o += &format_stage(s);
    for i in 0..usize::from(s.sensors).min(s.temps_c.len()) {
        let bits = s.sensor_bits[i];
        o += &format!(
            "sensor {i}: {:>9.4} °C  {}{}\n",
            s.temps_c[i],
            bits.state,
            bits.last_fault
                .map(|f| format!(" (last fault: {f})"))
                .unwrap_or_default()
        );
    }
    for i in 0..s.aux.len() {
        let bits = s.aux_bits[i];
        if bits.state != ChannelStatus::NotRead || !s.aux[i].is_nan() {
            o += &format!(
                "aux {i}: {:>9.4}  {}{}\n",
                s.aux[i],
                bits.state,
                bits.last_fault
                    .map(|f| format!(" (last fault: {f})"))
                    .unwrap_or_default()
            );
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
        "held targets re-issued (following the fold): {}  refused by the controller: {}\n",
        s.follow_reissues, s.follow_refused
    );
    o += &format!(
        "uploads ok {}  rejected {}{}\n",
        s.uploads_ok,
        s.uploads_rejected,
        s.last_upload_error
            .map(|r| format!(" (last: code {}, {r})", r.code()))
            .unwrap_or_default()
    );
    o += &format!(
        "pending GCS error {}  uptime {:.1} s\n",
        s.pending_error
            .map(|e| format!("{} ({e})", e.code()))
            .unwrap_or_else(|| "none".into()),
        f64::from(s.uptime_ms) / 1000.0
    );
    o
}

/// The model-stale lines of a status report: whether the model in service still holds, why
/// not and since when, the last KMZ check and the temperatures' distance from the envelope.
pub fn format_stale(s: &Status) -> String {
    let mut o = if s.flags.contains(Flags::MODEL_STALE) {
        format!(
            "MODEL STALE since uptime {:.1} s: {} (still compensating: refit, or re-measure)\n",
            f64::from(s.stale_since_ms) / 1000.0,
            s.stale
        )
    } else {
        "model stale: no\n".to_string()
    };
    let axes: Vec<String> = (0..3)
        .filter(|&a| !(s.kmz_residual_um[a] == 0.0 && s.kmz_limit_um[a].is_nan()))
        .map(|a| {
            let limit = if s.kmz_limit_um[a].is_nan() {
                "no prediction bound".to_string()
            } else {
                format!("limit ±{:.1} nm", 1000.0 * s.kmz_limit_um[a])
            };
            format!(
                "axis {a} {:+.1} nm ({limit})",
                1000.0 * s.kmz_residual_um[a]
            )
        })
        .collect();
    if !s.kmz_residual_um[0].is_nan() && !axes.is_empty() {
        o += &format!("last KMZ λ change: {}\n", axes.join(", "));
    }
    if !s.envelope_excess_c.is_nan() {
        o += &format!(
            "temperatures vs the training envelope: {:+.3} °C (> 0: that far outside)\n",
            s.envelope_excess_c
        );
    }
    o
}

/// The provenance check's line of a status report: is the controller the stage the model was
/// fitted on, and what happens to moves.
pub fn format_stage(s: &Status) -> String {
    let serial = |x: &Option<nanocal_model::StageSerial>| {
        x.as_ref()
            .map_or("none".to_string(), |x| x.as_str().to_string())
    };
    let mut o = format!("stage check: {}", s.stage);
    if s.flags.contains(Flags::STAGE_MISMATCH) {
        o = format!("STAGE MISMATCH — {}", s.stage);
    }
    if s.model_serial.is_some() || s.controller_serial.is_some() {
        o += &format!(
            " (model fitted on serial {}, controller reports {})",
            serial(&s.model_serial),
            serial(&s.controller_serial)
        );
    }
    o + "\n"
}

/// A human-readable settings report.
pub fn format_settings(s: &Settings) -> String {
    use nanocal_interface::settings::{AuxSource, Chip, Mains};
    let mut o = String::new();
    o += &format!(
        "stage baud: {} (8N1; applied at the next reset)\n",
        s.stage_baud
    );
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
    o += &format!(
        "model-stale check: k = {} standard errors of prediction at a KMZ, extrapolation margin {} °C\n",
        s.stale_k, s.extrapolation_c
    );
    o += &format!(
        "another stage than the model's (controller serial differs): {}\n",
        if s.allow_other_stage {
            "compensated all the same (allow_other_stage on)"
        } else {
            "moves refused (allow_other_stage off)"
        }
    );
    o += &if s.follow_nm == 0 {
        "held targets follow the model: off\n".to_string()
    } else {
        format!(
            "held targets follow the model: re-issued beyond {} nm, at most every {} ms, {}\n",
            s.follow_nm,
            s.follow_interval_ms,
            if s.follow_step_nm == 0 {
                "no step limit".to_string()
            } else {
                format!("at most {} nm a step", s.follow_step_nm)
            }
        )
    };
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
