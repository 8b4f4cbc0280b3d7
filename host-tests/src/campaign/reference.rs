//! The external reference instrument (interferometer, capacitive probe): where the stage really
//! is. Three ways in, one sample type:
//!
//! **Line protocol** over TCP (`tcp:HOST:PORT`) or a serial port (`serial:/dev/ttyUSB0[:BAUD]`,
//! 115 200 baud by default): the instrument sends one line per sample,
//!
//! ```text
//! <t> <pos_1> [<pos_2> [<pos_3>]]\n
//! ```
//! `t` in seconds on the instrument's clock (any origin, increasing), one position per stage
//! axis in the order of the plan's axes, in µm (`--reference-unit nm|mm` for other units);
//! fields separated by spaces, tabs, commas or semicolons; CR before LF allowed; empty lines and
//! lines starting with `#` are ignored. A line that does not parse is an error naming the line.
//!
//! **CSV file** that the instrument's own software is appending to (`file:PATH`, or a path
//! ending in `.csv`): a header row, then rows; the time column is the first one named `t`,
//! `time…` or `timestamp…` (else the first column), the positions are the `meas_<axis>` columns
//! if there are any, else the columns after the time column, in order. Rows already in the file
//! when the campaign starts are skipped (they belong to an earlier run); a row is taken once its
//! line is complete.
//!
//! The instrument's clock is not the campaign's: [`ClockMap`] maps it (see there).

use std::collections::VecDeque;
use std::io::{BufRead, Read, Seek, SeekFrom};
use std::net::TcpStream;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// One reading of the reference instrument.
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    /// Time on the instrument's clock, s.
    pub t_s: f64,
    /// Position per axis, µm.
    pub pos_um: Vec<f64>,
}

/// Errors of the reference instrument.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReferenceError {
    /// The instrument could not be reached or opened.
    #[error("reference {source_name}: cannot open: {cause}")]
    Open {
        /// The source as given.
        source_name: String,
        /// Why.
        cause: String,
    },
    /// The instrument sent nothing for too long.
    #[error("reference {source_name} sent no sample for {waited:?}{last} — is the instrument running and connected?")]
    Silent {
        /// The source.
        source_name: String,
        /// How long we waited.
        waited: Duration,
        /// The last sample's time, if any (", last at t = … s").
        last: String,
    },
    /// The connection closed.
    #[error("reference {source_name}: the instrument closed the connection")]
    Closed {
        /// The source.
        source_name: String,
    },
    /// A line or row that is not a sample.
    #[error("reference {source_name}, line {line}: {problem} (`{text}`)")]
    Malformed {
        /// The source.
        source_name: String,
        /// 1-based line of the stream or file.
        line: usize,
        /// What is wrong.
        problem: String,
        /// The line (truncated).
        text: String,
    },
    /// An I/O error.
    #[error("reference {source_name}: {cause}")]
    Io {
        /// The source.
        source_name: String,
        /// The error.
        cause: std::io::Error,
    },
    /// The specification is not understood.
    #[error(
        "reference `{0}`: expected tcp:HOST:PORT, serial:DEVICE[:BAUD], file:PATH or a .csv path"
    )]
    BadSpec(String),
}

/// Where samples come from.
pub trait ReferenceSource: Send {
    /// Samples that arrived, waiting up to `wait` for the first one (none after that: empty).
    fn poll(&mut self, wait: Duration) -> Result<Vec<Sample>, ReferenceError>;
    /// The source as given.
    fn name(&self) -> &str;
}

/// Open `spec` for `axes` positions per sample, scaling positions by `to_um` (1 for µm).
pub fn open(
    spec: &str,
    axes: usize,
    to_um: f64,
) -> Result<Box<dyn ReferenceSource>, ReferenceError> {
    let open_err = |cause: String| ReferenceError::Open {
        source_name: spec.to_string(),
        cause,
    };
    if let Some(addr) = spec.strip_prefix("tcp:") {
        let s = TcpStream::connect(addr).map_err(|e| open_err(e.to_string()))?;
        s.set_nodelay(true).ok();
        return Ok(Box::new(LineSource::new(
            spec,
            Box::new(SocketReader(s)),
            axes,
            to_um,
        )));
    }
    if let Some(dev) = spec.strip_prefix("serial:") {
        let (path, baud) = match dev.rsplit_once(':') {
            Some((p, b)) if b.chars().all(|c| c.is_ascii_digit()) && !b.is_empty() => {
                (p, b.parse::<u32>().map_err(|e| open_err(e.to_string()))?)
            }
            _ => (dev, 115_200),
        };
        let port = serialport::new(path, baud)
            .timeout(Duration::from_millis(20))
            .open()
            .map_err(|e| open_err(e.to_string()))?;
        return Ok(Box::new(LineSource::new(
            spec,
            Box::new(SerialReader(port)),
            axes,
            to_um,
        )));
    }
    let path = spec
        .strip_prefix("file:")
        .or_else(|| spec.ends_with(".csv").then_some(spec));
    match path {
        Some(p) => Ok(Box::new(CsvTail::open(
            spec,
            PathBuf::from(p),
            axes,
            to_um,
        )?)),
        None => Err(ReferenceError::BadSpec(spec.to_string())),
    }
}

/// A byte stream that can wait a bounded time for data.
pub trait TimedRead: Send {
    /// Read what is there, waiting at most `wait`; Ok(0) means nothing arrived (not closed).
    fn read_timed(&mut self, buf: &mut [u8], wait: Duration) -> std::io::Result<Option<usize>>;
}

struct SocketReader(TcpStream);

impl TimedRead for SocketReader {
    fn read_timed(&mut self, buf: &mut [u8], wait: Duration) -> std::io::Result<Option<usize>> {
        if wait.is_zero() {
            // only what is there: a non-blocking read. (A socket's read timeout counts whole
            // kernel ticks, so "100 µs" waited 4-10 ms: measured 5.9 ms per step of the virtual
            // bench, a third of its wall time.)
            self.0.set_nonblocking(true)?;
            let r = self.0.read(buf);
            self.0.set_nonblocking(false)?;
            return match r {
                Ok(0) => Ok(None),
                Ok(n) => Ok(Some(n)),
                Err(e) if is_timeout(&e) => Ok(Some(0)),
                Err(e) => Err(e),
            };
        }
        self.0.set_read_timeout(Some(wait))?;
        match self.0.read(buf) {
            Ok(0) => Ok(None),
            Ok(n) => Ok(Some(n)),
            Err(e) if is_timeout(&e) => Ok(Some(0)),
            Err(e) => Err(e),
        }
    }
}

struct SerialReader(Box<dyn serialport::SerialPort>);

impl TimedRead for SerialReader {
    fn read_timed(&mut self, buf: &mut [u8], wait: Duration) -> std::io::Result<Option<usize>> {
        self.0
            .set_timeout(wait.max(Duration::from_millis(1)))
            .map_err(std::io::Error::other)?;
        match self.0.read(buf) {
            Ok(n) => Ok(Some(n)),
            Err(e) if is_timeout(&e) => Ok(Some(0)),
            Err(e) => Err(e),
        }
    }
}

fn is_timeout(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        std::io::ErrorKind::TimedOut
            | std::io::ErrorKind::WouldBlock
            | std::io::ErrorKind::Interrupted
    )
}

fn truncated(s: &str) -> String {
    s.chars().take(60).collect()
}

/// Parse one protocol line: `None` for a comment or an empty line.
pub fn parse_line(line: &str, axes: usize, to_um: f64) -> Result<Option<Sample>, String> {
    let line = line.trim_end_matches(['\r', '\n']).trim();
    if line.is_empty() || line.starts_with('#') {
        return Ok(None);
    }
    let fields: Vec<&str> = line
        .split([' ', '\t', ',', ';'])
        .filter(|f| !f.is_empty())
        .collect();
    if fields.len() != axes + 1 {
        return Err(format!(
            "expected a time and {axes} position{}, found {} field{}",
            if axes == 1 { "" } else { "s" },
            fields.len(),
            if fields.len() == 1 { "" } else { "s" }
        ));
    }
    let num = |f: &str, what: &str| -> Result<f64, String> {
        f.parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| format!("{what} `{f}` is not a number"))
    };
    let t_s = num(fields[0], "time")?;
    let pos_um = fields[1..]
        .iter()
        .enumerate()
        .map(|(a, f)| num(f, &format!("position {}", a + 1)).map(|v| v * to_um))
        .collect::<Result<Vec<f64>, String>>()?;
    Ok(Some(Sample { t_s, pos_um }))
}

/// The line protocol over a byte stream.
pub struct LineSource {
    name: String,
    r: Box<dyn TimedRead>,
    buf: Vec<u8>,
    axes: usize,
    to_um: f64,
    line: usize,
    /// A bad line met after good samples: reported at the next poll.
    pending: Option<ReferenceError>,
}

impl LineSource {
    /// Read the protocol from `r`.
    pub fn new(name: &str, r: Box<dyn TimedRead>, axes: usize, to_um: f64) -> Self {
        Self {
            name: name.to_string(),
            r,
            buf: Vec::new(),
            axes,
            to_um,
            line: 0,
            pending: None,
        }
    }

    fn take_lines(&mut self, out: &mut Vec<Sample>) -> Result<(), ReferenceError> {
        while let Some(p) = self.buf.iter().position(|&b| b == b'\n') {
            let raw: Vec<u8> = self.buf.drain(..=p).collect();
            self.line += 1;
            let text = String::from_utf8_lossy(&raw);
            match parse_line(&text, self.axes, self.to_um) {
                Ok(Some(s)) => out.push(s),
                Ok(None) => {}
                Err(problem) => {
                    let e = ReferenceError::Malformed {
                        source_name: self.name.clone(),
                        line: self.line,
                        problem,
                        text: truncated(text.trim_end()),
                    };
                    if out.is_empty() {
                        return Err(e);
                    }
                    // hand over the good samples first
                    self.pending = Some(e);
                    return Ok(());
                }
            }
        }
        Ok(())
    }
}

impl ReferenceSource for LineSource {
    fn poll(&mut self, wait: Duration) -> Result<Vec<Sample>, ReferenceError> {
        if let Some(e) = self.pending.take() {
            return Err(e);
        }
        let deadline = Instant::now() + wait;
        let mut out = Vec::new();
        let mut b = [0u8; 4096];
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let got = self
                .r
                .read_timed(&mut b, if out.is_empty() { left } else { Duration::ZERO })
                .map_err(|cause| ReferenceError::Io {
                    source_name: self.name.clone(),
                    cause,
                })?;
            match got {
                None => {
                    self.take_lines(&mut out)?;
                    if out.is_empty() {
                        return Err(ReferenceError::Closed {
                            source_name: self.name.clone(),
                        });
                    }
                    return Ok(out);
                }
                Some(0) => {
                    self.take_lines(&mut out)?;
                    if !out.is_empty() || Instant::now() >= deadline {
                        return Ok(out);
                    }
                }
                Some(n) => {
                    self.buf.extend_from_slice(&b[..n]);
                    self.take_lines(&mut out)?;
                    if self.pending.is_some() {
                        return Ok(out);
                    }
                }
            }
        }
    }

    fn name(&self) -> &str {
        &self.name
    }
}

/// A CSV file another program appends to.
pub struct CsvTail {
    name: String,
    path: PathBuf,
    pos: u64,
    partial: Vec<u8>,
    time_col: usize,
    pos_cols: Vec<usize>,
    columns: usize,
    to_um: f64,
    line: usize,
}

impl CsvTail {
    /// Open `path`: read its header, skip the rows already there.
    pub fn open(
        name: &str,
        path: PathBuf,
        axes: usize,
        to_um: f64,
    ) -> Result<Self, ReferenceError> {
        let open_err = |cause: String| ReferenceError::Open {
            source_name: name.to_string(),
            cause,
        };
        let f = std::fs::File::open(&path).map_err(|e| open_err(e.to_string()))?;
        let mut r = std::io::BufReader::new(f);
        let mut header = String::new();
        r.read_line(&mut header)
            .map_err(|e| open_err(e.to_string()))?;
        if !header.ends_with('\n') {
            return Err(open_err("no complete header row yet".into()));
        }
        let names: Vec<String> = header
            .trim_end()
            .split(',')
            .map(|s| s.trim().trim_matches('"').to_string())
            .collect();
        let lower: Vec<String> = names.iter().map(|s| s.to_ascii_lowercase()).collect();
        let time_col = lower
            .iter()
            .position(|n| n == "t" || n.starts_with("time"))
            .unwrap_or(0);
        let meas: Vec<usize> = (0..names.len())
            .filter(|&i| lower[i].starts_with("meas_"))
            .collect();
        let pos_cols: Vec<usize> = if !meas.is_empty() {
            meas
        } else {
            (0..names.len()).filter(|&i| i != time_col).collect()
        };
        if pos_cols.len() < axes {
            return Err(open_err(format!(
                "the header has {} position column{} ({}), the plan has {axes} axes",
                pos_cols.len(),
                if pos_cols.len() == 1 { "" } else { "s" },
                names.join(",")
            )));
        }
        let mut rest = Vec::new();
        r.read_to_end(&mut rest)
            .map_err(|e| open_err(e.to_string()))?;
        // rows already there are an earlier run's; an unfinished last line is finished later
        let complete = rest.iter().rposition(|&b| b == b'\n').map_or(0, |p| p + 1);
        let lines_before = 1 + rest[..complete].iter().filter(|&&b| b == b'\n').count();
        Ok(Self {
            name: name.to_string(),
            pos: header.len() as u64 + complete as u64,
            partial: Vec::new(),
            time_col,
            pos_cols: pos_cols[..axes].to_vec(),
            columns: names.len(),
            to_um,
            line: lines_before,
            path,
        })
    }

    fn row(&self, text: &str) -> Result<Option<Sample>, String> {
        let text = text.trim_end_matches(['\r', '\n']);
        if text.trim().is_empty() {
            return Ok(None);
        }
        let f: Vec<&str> = text.split(',').map(str::trim).collect();
        if f.len() < self.columns {
            return Err(format!(
                "expected {} values, found {}",
                self.columns,
                f.len()
            ));
        }
        let num = |i: usize| -> Result<f64, String> {
            f[i].trim_matches('"')
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| format!("column {}: `{}` is not a number", i + 1, f[i]))
        };
        Ok(Some(Sample {
            t_s: num(self.time_col)?,
            pos_um: self
                .pos_cols
                .iter()
                .map(|&i| num(i).map(|v| v * self.to_um))
                .collect::<Result<_, _>>()?,
        }))
    }
}

impl ReferenceSource for CsvTail {
    fn poll(&mut self, wait: Duration) -> Result<Vec<Sample>, ReferenceError> {
        let deadline = Instant::now() + wait;
        let io = |cause| ReferenceError::Io {
            source_name: self.name.clone(),
            cause,
        };
        loop {
            let mut f = std::fs::File::open(&self.path).map_err(io)?;
            let len = f.metadata().map_err(io)?.len();
            let mut out = Vec::new();
            if len > self.pos {
                f.seek(SeekFrom::Start(self.pos)).map_err(io)?;
                let mut more = Vec::with_capacity((len - self.pos) as usize);
                f.take(len - self.pos).read_to_end(&mut more).map_err(io)?;
                self.pos += more.len() as u64;
                self.partial.extend_from_slice(&more);
                while let Some(p) = self.partial.iter().position(|&b| b == b'\n') {
                    let raw: Vec<u8> = self.partial.drain(..=p).collect();
                    self.line += 1;
                    let text = String::from_utf8_lossy(&raw).into_owned();
                    match self.row(&text) {
                        Ok(Some(s)) => out.push(s),
                        Ok(None) => {}
                        Err(problem) => {
                            return Err(ReferenceError::Malformed {
                                source_name: self.name.clone(),
                                line: self.line,
                                problem,
                                text: truncated(text.trim_end()),
                            })
                        }
                    }
                }
            } else if len < self.pos {
                return Err(ReferenceError::Malformed {
                    source_name: self.name.clone(),
                    line: self.line,
                    problem: "the file became shorter (rewritten by its program?)".into(),
                    text: String::new(),
                });
            }
            if !out.is_empty() || Instant::now() >= deadline {
                return Ok(out);
            }
            std::thread::sleep(Duration::from_millis(20).min(deadline - Instant::now()));
        }
    }

    fn name(&self) -> &str {
        &self.name
    }
}

/// How the instrument's time maps to the campaign's.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ClockMode {
    /// The instrument stamps samples on the campaign's clock already (the virtual bench's
    /// interferometer; an instrument synchronised to the host).
    Synchronized,
    /// The instrument has its own clock: campaign time = instrument time + an offset, the
    /// smallest (arrival − stamp) seen over the last [`ClockMap::WINDOW`] samples, so that
    /// transport delays do not shift samples and the two clocks may drift apart slowly.
    Instrument,
}

/// Maps instrument time to campaign time.
#[derive(Debug, Clone)]
pub struct ClockMap {
    mode: ClockMode,
    recent: VecDeque<f64>,
}

impl ClockMap {
    /// Samples over which the offset is the minimum.
    pub const WINDOW: usize = 600;

    /// A map of `mode`.
    pub fn new(mode: ClockMode) -> Self {
        Self {
            mode,
            recent: VecDeque::new(),
        }
    }

    /// A sample stamped `t_instr_s` arrived at campaign time `arrival_s`: its campaign time.
    pub fn map(&mut self, t_instr_s: f64, arrival_s: f64) -> f64 {
        match self.mode {
            ClockMode::Synchronized => t_instr_s,
            ClockMode::Instrument => {
                if self.recent.len() == Self::WINDOW {
                    self.recent.pop_front();
                }
                self.recent.push_back(arrival_s - t_instr_s);
                let offset = self.recent.iter().copied().fold(f64::INFINITY, f64::min);
                t_instr_s + offset
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_parse_with_any_separator_and_unit() {
        let s = parse_line("12.5 100.25\r\n", 1, 1.0).unwrap().unwrap();
        assert_eq!(
            s,
            Sample {
                t_s: 12.5,
                pos_um: vec![100.25]
            }
        );
        let s = parse_line("1;2000;-3000", 2, 1e-3).unwrap().unwrap();
        assert_eq!(s.pos_um, vec![2.0, -3.0]);
        assert_eq!(parse_line("# SIOS SP-S 120", 1, 1.0).unwrap(), None);
        assert_eq!(parse_line("   ", 1, 1.0).unwrap(), None);
        let e = parse_line("1 2 3", 1, 1.0).unwrap_err();
        assert!(
            e.contains("expected a time and 1 position, found 3 fields"),
            "{e}"
        );
        let e = parse_line("1 abc", 1, 1.0).unwrap_err();
        assert!(e.contains("position 1 `abc`"), "{e}");
        assert!(parse_line("1 NaN", 1, 1.0).is_err());
    }

    #[test]
    fn tcp_stream_samples_malformed_lines_and_a_closed_instrument() {
        use std::io::Write;
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let port = l.local_addr().unwrap().port();
        let h = std::thread::spawn(move || {
            let (mut s, _) = l.accept().unwrap();
            s.write_all(b"# SIOS\n0.0 1.5\n1.0 2.5\r\n").unwrap();
            std::thread::sleep(Duration::from_millis(50));
            s.write_all(b"2.0 3.").unwrap(); // half a line, finished later
            std::thread::sleep(Duration::from_millis(50));
            s.write_all(b"5\n3.0 x\n").unwrap();
        });
        let mut src = open(&format!("tcp:127.0.0.1:{port}"), 1, 1.0).unwrap();
        let mut got = Vec::new();
        let err = loop {
            match src.poll(Duration::from_millis(500)) {
                Ok(s) => got.extend(s),
                Err(e) => break e,
            }
        };
        h.join().unwrap();
        assert_eq!(
            got.iter().map(|s| (s.t_s, s.pos_um[0])).collect::<Vec<_>>(),
            vec![(0.0, 1.5), (1.0, 2.5), (2.0, 3.5)]
        );
        let msg = err.to_string();
        assert!(
            msg.contains("line 5") && msg.contains("`x` is not a number"),
            "{msg}"
        );
        // nothing more: the instrument closed its end
        assert!(matches!(
            src.poll(Duration::from_millis(200)),
            Err(ReferenceError::Closed { .. })
        ));
        assert!(matches!(
            open("tcp:127.0.0.1:1", 1, 1.0),
            Err(ReferenceError::Open { .. })
        ));
        assert!(matches!(
            open("carrier-pigeon", 1, 1.0),
            Err(ReferenceError::BadSpec(_))
        ));
    }

    #[test]
    fn a_csv_file_being_appended_to_is_followed_from_where_it_was() {
        use std::io::Write;
        let dir = std::env::temp_dir().join(format!("nanocal-ref-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("sios.csv");
        std::fs::write(&p, "timestamp,meas_x,temp\n0,1.0,20\n1,1.1,20\n2,1.").unwrap();
        let mut src = open(p.to_str().unwrap(), 1, 1e-3).unwrap();
        // the complete rows already there are an earlier run's; the one being written is taken
        assert!(src.poll(Duration::from_millis(50)).unwrap().is_empty());
        let mut f = std::fs::OpenOptions::new().append(true).open(&p).unwrap();
        f.write_all(b"2,20\n3,1300,20\n4,14").unwrap();
        let got = src.poll(Duration::from_millis(200)).unwrap();
        assert_eq!(got.len(), 2);
        assert_eq!(got[1].t_s, 3.0);
        assert!((got[1].pos_um[0] - 1.3).abs() < 1e-12);
        f.write_all(b"00,20\n").unwrap();
        let got = src.poll(Duration::from_millis(200)).unwrap();
        assert_eq!(got[0].t_s, 4.0);
        assert!((got[0].pos_um[0] - 1.4).abs() < 1e-12);
        f.write_all(b"5,oops,20\n").unwrap();
        let e = src
            .poll(Duration::from_millis(200))
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 7") && e.contains("`oops`"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn instrument_clock_takes_the_fastest_arrival() {
        let mut m = ClockMap::new(ClockMode::Instrument);
        // instrument clock 1000 s ahead, arrivals delayed by 0.05..0.3 s
        assert!((m.map(1000.0, 0.3) - 0.3).abs() < 1e-12);
        assert!((m.map(1001.0, 1.05) - 1.05).abs() < 1e-12);
        // a late arrival does not move the offset
        assert!((m.map(1002.0, 2.5) - 2.05).abs() < 1e-12);
        let mut s = ClockMap::new(ClockMode::Synchronized);
        assert_eq!(s.map(5.0, 99.0), 5.0);
    }
}
