//! A GCS 2.0 line client for the campaign: what the lab's own software would send to the stage
//! controller, through the compensator's GCS port (PI GCS 2.0: a line per command, LF-terminated;
//! a multi-line reply continues while a line ends with a space before its LF).

use crate::device::{DeviceError, Port};
use std::io::{Read, Write};
use std::time::{Duration, Instant};

/// Errors of the GCS link.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum GcsError {
    /// The port could not be opened.
    #[error("GCS port: {0}")]
    Open(#[from] DeviceError),
    /// Writing or reading failed.
    #[error("GCS port {port}: {cause}")]
    Io {
        /// The port.
        port: String,
        /// The error.
        cause: std::io::Error,
    },
    /// No (complete) reply in time.
    #[error("GCS port {port}: no reply to `{command}` within {waited:?} (compensator or controller not answering)")]
    Timeout {
        /// The port.
        port: String,
        /// What was asked.
        command: String,
        /// How long we waited.
        waited: Duration,
    },
    /// A reply that is not what the command returns.
    #[error("GCS port {port}: unexpected reply `{reply}` to `{command}`")]
    Unexpected {
        /// The port.
        port: String,
        /// What was asked.
        command: String,
        /// What came back.
        reply: String,
    },
}

/// The host's end of a GCS link.
pub struct GcsLink {
    port: Box<dyn Port>,
    name: String,
    buf: Vec<u8>,
    /// Longest wait for a reply.
    pub timeout: Duration,
}

impl GcsLink {
    /// Open `spec` (`tcp:HOST:PORT`, `unix:PATH` or a serial device, as [`crate::device::open`]).
    pub fn open(spec: &str) -> Result<Self, GcsError> {
        let port = crate::device::open(spec, Duration::from_millis(20))?;
        Ok(Self::new(port, spec))
    }

    /// A link over an open port (reads must time out, as [`crate::device::open`]'s do).
    pub fn new(port: Box<dyn Port>, name: &str) -> Self {
        Self {
            port,
            name: name.to_string(),
            buf: Vec::new(),
            timeout: Duration::from_secs(10),
        }
    }

    fn io(&self, cause: std::io::Error) -> GcsError {
        GcsError::Io {
            port: self.name.clone(),
            cause,
        }
    }

    /// Send one command line (the LF is added).
    pub fn send(&mut self, line: &str) -> Result<(), GcsError> {
        let mut b = Vec::with_capacity(line.len() + 1);
        b.extend_from_slice(line.as_bytes());
        b.push(b'\n');
        self.port.write_all(&b).map_err(|e| self.io(e))?;
        self.port.flush().map_err(|e| self.io(e))
    }

    fn read_line(&mut self, command: &str, deadline: Instant) -> Result<String, GcsError> {
        loop {
            if let Some(p) = self.buf.iter().position(|&b| b == b'\n') {
                let line: Vec<u8> = self.buf.drain(..=p).collect();
                return Ok(String::from_utf8_lossy(&line[..line.len() - 1]).into_owned());
            }
            if Instant::now() > deadline {
                return Err(GcsError::Timeout {
                    port: self.name.clone(),
                    command: command.to_string(),
                    waited: self.timeout,
                });
            }
            let mut b = [0u8; 256];
            match self.port.read(&mut b) {
                Ok(0) => {
                    return Err(self.io(std::io::Error::new(
                        std::io::ErrorKind::UnexpectedEof,
                        "the port closed",
                    )))
                }
                Ok(n) => self.buf.extend_from_slice(&b[..n]),
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::TimedOut
                            | std::io::ErrorKind::WouldBlock
                            | std::io::ErrorKind::Interrupted
                    ) => {}
                Err(e) => return Err(self.io(e)),
            }
        }
    }

    /// Send a query and read its reply (lines joined with LF, continuation spaces removed).
    pub fn ask(&mut self, line: &str) -> Result<String, GcsError> {
        self.send(line)?;
        let deadline = Instant::now() + self.timeout;
        let mut out = String::new();
        loop {
            let l = self.read_line(line, deadline)?;
            let more = l.ends_with(' ');
            out += l.trim_end();
            if !more {
                return Ok(out);
            }
            out.push('\n');
        }
    }

    /// `ERR?`: the error code the controller (or the compensator) holds, 0 for none.
    pub fn error(&mut self) -> Result<i32, GcsError> {
        let r = self.ask("ERR?")?;
        r.trim().parse::<i32>().map_err(|_| GcsError::Unexpected {
            port: self.name.clone(),
            command: "ERR?".into(),
            reply: r,
        })
    }

    /// A per-axis query (`TMN?`, `TMX?`, `POS?`, …) for `axes`: the values in that order.
    pub fn axis_values(&mut self, query: &str, axes: &[String]) -> Result<Vec<f64>, GcsError> {
        let command = format!("{query} {}", axes.join(" "));
        let r = self.ask(&command)?;
        let unexpected = || GcsError::Unexpected {
            port: self.name.clone(),
            command: command.clone(),
            reply: r.clone(),
        };
        let mut out = Vec::with_capacity(axes.len());
        for (line, axis) in r.lines().zip(axes) {
            let (a, v) = line.split_once('=').ok_or_else(unexpected)?;
            // a reply may carry an address prefix ("0 1 1=…")
            if a.split_whitespace().last() != Some(axis.as_str()) {
                return Err(unexpected());
            }
            out.push(v.trim().parse::<f64>().map_err(|_| unexpected())?);
        }
        if out.len() != axes.len() {
            return Err(unexpected());
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Cursor;

    struct Scripted {
        replies: Cursor<Vec<u8>>,
        sent: Vec<u8>,
    }
    impl Read for Scripted {
        fn read(&mut self, b: &mut [u8]) -> std::io::Result<usize> {
            match self.replies.read(b)? {
                0 => Err(std::io::ErrorKind::WouldBlock.into()),
                n => Ok(n),
            }
        }
    }
    impl Write for Scripted {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.sent.extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    fn link(replies: &str) -> GcsLink {
        GcsLink::new(
            Box::new(Scripted {
                replies: Cursor::new(replies.as_bytes().to_vec()),
                sent: Vec::new(),
            }),
            "test",
        )
    }

    #[test]
    fn multi_line_replies_and_axis_values() {
        let mut g = link("1=-20.000000 \n2=-20.000000\n0\n");
        let v = g
            .axis_values("TMN?", &["1".to_string(), "2".to_string()])
            .unwrap();
        assert_eq!(v, vec![-20.0, -20.0]);
        assert_eq!(g.error().unwrap(), 0);
    }

    #[test]
    fn silence_is_a_timeout_naming_the_command() {
        let mut g = link("");
        g.timeout = Duration::from_millis(30);
        let e = g.error().unwrap_err();
        assert!(e.to_string().contains("no reply to `ERR?`"), "{e}");
        let mut g = link("x=1\n");
        let e = g.axis_values("TMX?", &["1".to_string()]).unwrap_err();
        assert!(e.to_string().contains("unexpected reply"), "{e}");
    }
}
