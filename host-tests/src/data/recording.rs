//! Recordings in the shared CSV layout (the README's "The tools"; `data/` holds real examples).
//!
//! A recording is a header row followed by one row per sample. Columns are recognised by their
//! name prefix ([`ColumnRole`]): `t` (time, s), `cmd_<axis>` (command sent to the stage, µm),
//! `meas_<axis>` (external reference measurement, µm), `temp_<name>` (°C) and anything else as
//! an auxiliary channel. Extra columns are always accepted.
//!
//! Storage is columnar (`Vec<f64>` per column). The reader is a hand-written, allocation-light
//! parser (exact decimal → `f64` conversion through a fast path for short decimals, falling back
//! to the standard library otherwise) and reports a missing or non-numeric value with its line
//! (1-based, counting the header as line 1) and column (1-based, with the column's name).
//!
//! ```
//! use nanocal::data::recording::Recording;
//! let rec = Recording::parse(b"t,cmd_x,meas_x,temp_a\n0,0,0.1,22.0\n1,30,30.2,22.1\n").unwrap();
//! assert_eq!(rec.rows(), 2);
//! assert_eq!(rec.axes(), vec!["x".to_string()]);
//! assert_eq!(rec.meas("x").unwrap(), &[0.1, 30.2]);
//! ```

use std::fmt::Write as _;
use std::io::{self, Write};
use std::path::{Path, PathBuf};

mod whole_rows;

/// Errors reading or building a recording.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    /// The file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: io::Error,
    },
    /// The input has no header row.
    #[error("line 1: expected a header row with column names, found an empty file")]
    Empty,
    /// A header name is empty or repeated.
    #[error("line 1, column {column}: {problem}")]
    BadHeader {
        /// 1-based column.
        column: usize,
        /// What is wrong.
        problem: String,
    },
    /// A row has fewer values than the header has columns, or an empty value.
    #[error("line {line}, column {column} (`{name}`): expected a number, found nothing")]
    MissingValue {
        /// 1-based line (the header is line 1).
        line: usize,
        /// 1-based column.
        column: usize,
        /// The column's name.
        name: String,
    },
    /// A value is not a number.
    #[error("line {line}, column {column} (`{name}`): expected a number, found `{found}`")]
    NotNumeric {
        /// 1-based line (the header is line 1).
        line: usize,
        /// 1-based column.
        column: usize,
        /// The column's name.
        name: String,
        /// The offending text (truncated to 40 characters).
        found: String,
    },
    /// A row has more values than the header has columns.
    #[error("line {line}: expected {expected} values as in the header, found more")]
    TooManyValues {
        /// 1-based line.
        line: usize,
        /// Number of header columns.
        expected: usize,
    },
    /// A column the caller needs is not in the recording.
    #[error("column `{name}` not found; the recording has: {available}")]
    MissingColumn {
        /// The requested column.
        name: String,
        /// Comma-separated list of the columns present.
        available: String,
    },
    /// Columns of different lengths were given to [`Recording::from_columns`].
    #[error("column `{name}` has {found} rows, expected {expected}")]
    LengthMismatch {
        /// The column.
        name: String,
        /// Rows of the first column.
        expected: usize,
        /// Rows of this column.
        found: usize,
    },
}

/// What a column means, from its name (shared recording layout).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ColumnRole {
    /// `t`: time since start, s.
    Time,
    /// `cmd_<axis>`: the command sent to the stage controller, µm.
    Cmd(String),
    /// `meas_<axis>`: the external reference measurement, µm.
    Meas(String),
    /// `temp_<name>`: a temperature sensor, °C.
    Temp(String),
    /// Anything else: an auxiliary channel.
    Aux(String),
}

impl ColumnRole {
    /// The role of a column with this name.
    pub fn of(name: &str) -> ColumnRole {
        if name == "t" {
            ColumnRole::Time
        } else if let Some(a) = name.strip_prefix("cmd_") {
            ColumnRole::Cmd(a.to_string())
        } else if let Some(a) = name.strip_prefix("meas_") {
            ColumnRole::Meas(a.to_string())
        } else if let Some(a) = name.strip_prefix("temp_") {
            ColumnRole::Temp(a.to_string())
        } else {
            ColumnRole::Aux(name.to_string())
        }
    }
}

/// A recording: named columns of equal length, stored column by column.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Recording {
    names: Vec<String>,
    columns: Vec<Column>,
    rows: usize,
}

/// One column's values: a vector of its own, or a range of the parser's one block of all the
/// columns ([`Block`]; shared and read-only once parsed).
#[derive(Debug, Clone)]
enum Column {
    /// Its own vector.
    Own(Vec<f64>),
    /// Values `start..start + len` of a block.
    InBlock {
        block: std::sync::Arc<Block>,
        start: usize,
        len: usize,
    },
}

impl std::ops::Deref for Column {
    type Target = [f64];
    fn deref(&self) -> &[f64] {
        match self {
            Column::Own(v) => v,
            Column::InBlock { block, start, len } => &block.as_slice()[*start..*start + *len],
        }
    }
}

impl PartialEq for Column {
    fn eq(&self, other: &Column) -> bool {
        **self == **other
    }
}

/// Zeroed memory for all of a parsed file's columns at once, in 2 MiB pages where the kernel has
/// them free. Why: 41 columns of 1.6 MB each (200,000 rows) are 16,000 fresh 4 KiB pages, each
/// faulted in and zeroed on the parser's first write: ≈ 20 ms of CPU, a tenth of `nanocal
/// stepwise` on such a file; in 33 huge pages the kernel zeroes the same bytes in ≈ 3 ms and the
/// parser's 41 streams of stores miss the TLB less. A column vector is below 2 MiB, so huge pages
/// need the one block.
struct Block {
    /// The first value (2 MiB aligned within the mapping).
    ptr: *mut f64,
    /// Values in the block.
    len: usize,
    /// The whole mapping, for `munmap`.
    map: (*mut libc::c_void, usize),
}

// SAFETY: the block owns its mapping; it is written only through `&mut self` (while parsing)
// and shared read-only afterwards.
unsafe impl Send for Block {}
// SAFETY: as for Send: no interior mutability
unsafe impl Sync for Block {}

impl std::fmt::Debug for Block {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Block({} values)", self.len)
    }
}

impl Block {
    const HUGE: usize = 2 << 20;

    /// `len` zeroed values, or `None` if the system will not map them (the caller then uses
    /// vectors).
    fn zeroed(len: usize) -> Option<Block> {
        #[cfg(target_os = "linux")]
        {
            let bytes = len.checked_mul(8)?.checked_next_multiple_of(Self::HUGE)?;
            let map_len = bytes.checked_add(Self::HUGE)?;
            // SAFETY: a fresh private anonymous mapping (zeroed by the kernel), owned by the
            // block and unmapped once, on drop
            let map = unsafe {
                libc::mmap(
                    std::ptr::null_mut(),
                    map_len,
                    libc::PROT_READ | libc::PROT_WRITE,
                    libc::MAP_PRIVATE | libc::MAP_ANONYMOUS,
                    -1,
                    0,
                )
            };
            if map == libc::MAP_FAILED {
                return None;
            }
            let start = (map as usize).next_multiple_of(Self::HUGE);
            if huge_pages_free() >= 2 * (bytes / Self::HUGE) {
                // SAFETY: advice on whole pages of our own mapping (`bytes` from `start` lie in
                // it: `map_len` has a huge page to spare for the alignment)
                unsafe { libc::madvise(start as *mut libc::c_void, bytes, libc::MADV_HUGEPAGE) };
            }
            Some(Block {
                ptr: start as *mut f64,
                len,
                map: (map, map_len),
            })
        }
        #[cfg(not(target_os = "linux"))]
        {
            let _ = len;
            None
        }
    }

    /// The block shared by `ncol` columns of `len` values: column `j` from `first + j * stride`.
    fn into_columns(self, ncol: usize, stride: usize, first: usize, len: usize) -> Vec<Column> {
        let block = std::sync::Arc::new(self);
        (0..ncol)
            .map(|j| Column::InBlock {
                block: block.clone(),
                start: first + j * stride,
                len,
            })
            .collect()
    }

    fn as_slice(&self) -> &[f64] {
        // SAFETY: `len` values from `ptr` lie in the mapping (see `zeroed`), zero-initialised
        // by the kernel, which every bit pattern of f64 allows
        unsafe { std::slice::from_raw_parts(self.ptr, self.len) }
    }

    fn as_mut_slice(&mut self) -> &mut [f64] {
        // SAFETY: as `as_slice`; `&mut self` makes this the only view
        unsafe { std::slice::from_raw_parts_mut(self.ptr, self.len) }
    }
}

impl Drop for Block {
    fn drop(&mut self) {
        #[cfg(target_os = "linux")]
        // SAFETY: our own mapping, unmapped once; no slice of it outlives the block (columns
        // hold the block through an `Arc`)
        unsafe {
            libc::munmap(self.map.0, self.map.1)
        };
    }
}

/// Free 2 MiB blocks in the kernel's free lists (`/proc/buddyinfo`, orders ≥ 9), 0 if unknown.
///
/// Why it is asked: with transparent huge pages on `madvise` (`defrag` too, the common default)
/// a fault in advised memory that finds no free 2 MiB block compacts memory on the spot — seen
/// stalling 500 ms in two of six runs on a loaded machine. Advised only when twice the pages
/// needed are free, a fault takes one from the free lists and does not compact.
fn huge_pages_free() -> usize {
    let Ok(info) = std::fs::read_to_string("/proc/buddyinfo") else {
        return 0;
    };
    info.lines()
        .map(|line| {
            // "Node 0, zone   Normal  c0 c1 … c10": the counts of free blocks of 2^k pages
            let counts = line.split_whitespace().skip(4);
            counts
                .enumerate()
                .filter(|&(order, _)| order >= 9)
                .map(|(order, c)| c.parse::<usize>().unwrap_or(0) << (order - 9))
                .sum::<usize>()
        })
        .sum()
}

impl Recording {
    /// An empty recording with no columns and no rows.
    pub fn new() -> Self {
        Self::default()
    }

    /// Builds a recording from named columns, which must all have the same length and unique names.
    pub fn from_columns(columns: Vec<(String, Vec<f64>)>) -> Result<Self, RecordingError> {
        let mut rec = Recording::new();
        for (name, data) in columns {
            rec.push_column(name, data)?;
        }
        Ok(rec)
    }

    /// Appends a column (same length as the others, unique name).
    pub fn push_column(
        &mut self,
        name: impl Into<String>,
        data: Vec<f64>,
    ) -> Result<(), RecordingError> {
        let name = name.into();
        if name.is_empty() || self.names.contains(&name) {
            return Err(RecordingError::BadHeader {
                column: self.names.len() + 1,
                problem: format!("column name `{name}` is empty or repeated"),
            });
        }
        if self.columns.is_empty() {
            self.rows = data.len();
        } else if data.len() != self.rows {
            return Err(RecordingError::LengthMismatch {
                name,
                expected: self.rows,
                found: data.len(),
            });
        }
        self.names.push(name);
        self.columns.push(Column::Own(data));
        Ok(())
    }

    /// Reads a CSV file in the shared layout.
    pub fn read_path(path: impl AsRef<Path>) -> Result<Self, RecordingError> {
        let path = path.as_ref();
        let bytes = FileBytes::open(path).map_err(|source| RecordingError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let mapped = matches!(bytes, FileBytes::Mapped { .. });
        Self::parse_with(&bytes, mapped)
    }

    /// Parses CSV bytes in the shared layout (header row, comma separated, `\n` or `\r\n` line ends;
    /// blank lines are skipped; spaces around values are ignored).
    pub fn parse(bytes: &[u8]) -> Result<Self, RecordingError> {
        Self::parse_with(bytes, false)
    }

    /// [`Self::parse`]; `mapped`: `bytes` are a read-only private file mapping, whose pages the
    /// parser threads may map in and drop from the page tables (see [`Pages`]).
    fn parse_with(bytes: &[u8], mapped: bool) -> Result<Self, RecordingError> {
        let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
        // header
        let pos = 0;
        let line_no = 1usize;
        let header_end = memchr_nl(bytes, 0);
        let header = trim_cr(&bytes[..header_end]);
        if header.iter().all(|b| b.is_ascii_whitespace()) {
            return Err(RecordingError::Empty);
        }
        let mut names: Vec<String> = Vec::new();
        // a set beside the list: a header of many columns is checked in linear time
        let mut seen = std::collections::HashSet::new();
        for (i, field) in header.split(|&b| b == b',').enumerate() {
            let name = column_name(field).map_err(|problem| RecordingError::BadHeader {
                column: i + 1,
                problem,
            })?;
            if !seen.insert(name.clone()) {
                return Err(RecordingError::BadHeader {
                    column: i + 1,
                    problem: format!("column name `{name}` is repeated"),
                });
            }
            names.push(name);
        }
        let body = &bytes[(pos + header_end + 1).min(bytes.len())..];
        let columns = parse_body_parallel(body, &names, line_no, mapped)?;
        let rows = columns.first().map_or(0, |c| c.len());
        Ok(Recording {
            names,
            columns,
            rows,
        })
    }

    /// Writes the recording as CSV (header row; values with the shortest representation that
    /// round-trips exactly).
    pub fn write<W: Write>(&self, mut w: W) -> io::Result<()> {
        let mut line = String::with_capacity(32 * self.names.len().max(1));
        line.push_str(&self.names.join(","));
        line.push('\n');
        w.write_all(line.as_bytes())?;
        for r in 0..self.rows {
            line.clear();
            for (c, col) in self.columns.iter().enumerate() {
                if c > 0 {
                    line.push(',');
                }
                let _ = write!(line, "{}", col[r]);
            }
            line.push('\n');
            w.write_all(line.as_bytes())?;
        }
        Ok(())
    }

    /// Writes the recording to a CSV file.
    pub fn write_path(&self, path: impl AsRef<Path>) -> Result<(), RecordingError> {
        let path = path.as_ref();
        let io_err = |source| RecordingError::Io {
            path: path.to_path_buf(),
            source,
        };
        let f = std::fs::File::create(path).map_err(io_err)?;
        let mut w = io::BufWriter::new(f);
        self.write(&mut w).map_err(io_err)?;
        w.flush().map_err(io_err)
    }

    /// Number of rows (samples).
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Column names in file order.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// Index of a column by name.
    pub fn index(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    /// A column by name, if present.
    pub fn column(&self, name: &str) -> Option<&[f64]> {
        self.index(name).map(|i| &*self.columns[i])
    }

    /// A column by index.
    pub fn column_at(&self, index: usize) -> &[f64] {
        &self.columns[index]
    }

    /// A column by name, or an error listing the columns that are present.
    pub fn require(&self, name: &str) -> Result<&[f64], RecordingError> {
        self.column(name)
            .ok_or_else(|| RecordingError::MissingColumn {
                name: name.to_string(),
                available: self.names.join(", "),
            })
    }

    /// The time column `t` in s, if present.
    pub fn time_s(&self) -> Option<&[f64]> {
        self.column("t")
    }

    /// The command column `cmd_<axis>` in µm, if present.
    pub fn cmd(&self, axis: &str) -> Option<&[f64]> {
        self.column(&format!("cmd_{axis}"))
    }

    /// The measurement column `meas_<axis>` in µm, if present.
    pub fn meas(&self, axis: &str) -> Option<&[f64]> {
        self.column(&format!("meas_{axis}"))
    }

    /// Axis names that have a `cmd_` or `meas_` column, in order of first appearance.
    pub fn axes(&self) -> Vec<String> {
        let mut out: Vec<String> = Vec::new();
        for n in &self.names {
            if let ColumnRole::Cmd(a) | ColumnRole::Meas(a) = ColumnRole::of(n) {
                if !out.contains(&a) {
                    out.push(a);
                }
            }
        }
        out
    }

    /// Column names with the given role predicate, in file order.
    fn names_where(&self, f: impl Fn(&ColumnRole) -> bool) -> Vec<&str> {
        self.names
            .iter()
            .filter(|n| f(&ColumnRole::of(n)))
            .map(|s| s.as_str())
            .collect()
    }

    /// Full names of the temperature columns (`temp_*`), in file order.
    pub fn temp_columns(&self) -> Vec<&str> {
        self.names_where(|r| matches!(r, ColumnRole::Temp(_)))
    }

    /// Full names of the auxiliary columns (not `t`, `cmd_`, `meas_`, `temp_`), in file order.
    pub fn aux_columns(&self) -> Vec<&str> {
        self.names_where(|r| matches!(r, ColumnRole::Aux(_)))
    }
}

/// A file's bytes: a large regular file is mapped (read-only; the parser's threads map its
/// pages in from the page cache, each its own part: [`Pages`]), anything else read into memory. Reading 80 MB copies them from the page
/// cache into a fresh buffer whose every 4 KiB page faults on first touch: about a tenth of
/// `nanocal stepwise` on a 200,000 × 40 design; the mapping costs neither.
enum FileBytes {
    /// A mapping of `len` bytes at `ptr` (unmapped on drop).
    Mapped { ptr: *mut libc::c_void, len: usize },
    /// The file read into memory.
    Read(Vec<u8>),
}

impl FileBytes {
    /// Below this size the mapping does not pay for its system calls.
    const MAP_FROM: u64 = 1 << 20;

    fn open(path: &Path) -> io::Result<Self> {
        #[cfg(target_os = "linux")]
        {
            use std::os::unix::io::AsRawFd;
            let file = std::fs::File::open(path)?;
            let meta = file.metadata()?;
            if meta.is_file() && meta.len() >= Self::MAP_FROM {
                let len = usize::try_from(meta.len()).map_err(io::Error::other)?;
                // SAFETY: a fresh read-only private mapping of an open file; it stays valid
                // after the descriptor closes. If another process truncated the file while it
                // is mapped, reading past the new end would raise SIGBUS: a risk the tools
                // that map their inputs (ripgrep, git) take too, for a file being rewritten
                // under them.
                let ptr = unsafe {
                    libc::mmap(
                        std::ptr::null_mut(),
                        len,
                        libc::PROT_READ,
                        // not MAP_POPULATE: mapping 80 MB of page cache took ≈ 16 ms on this
                        // one thread while the other core waited; the parser's threads map
                        // their own parts (`Pages::map_in`)
                        libc::MAP_PRIVATE,
                        file.as_raw_fd(),
                        0,
                    )
                };
                if ptr != libc::MAP_FAILED {
                    return Ok(FileBytes::Mapped { ptr, len });
                }
                // a file system that cannot map: read it instead
            }
        }
        std::fs::read(path).map(FileBytes::Read)
    }
}

impl std::ops::Deref for FileBytes {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        match self {
            // SAFETY: the mapping is `len` readable bytes until drop (see `open`)
            FileBytes::Mapped { ptr, len } => unsafe {
                std::slice::from_raw_parts(*ptr as *const u8, *len)
            },
            FileBytes::Read(v) => v,
        }
    }
}

impl Drop for FileBytes {
    fn drop(&mut self) {
        if let FileBytes::Mapped { ptr, len } = self {
            // SAFETY: our own mapping, unmapped once; no slice of it outlives `self`
            unsafe { libc::munmap(*ptr, *len) };
        }
    }
}

/// What the parser's threads do to the page tables of a part of a file mapping: map its pages
/// in before reading it, and drop them once parsed. Both are the kernel's work for every 4 KiB
/// page of the file (≈ 0.8 µs each: 16 ms to map 80 MB, 6.5 ms to unmap); done by one thread
/// before and after the parse, the other core waited; per part, both cores share it.
struct Pages;

impl Pages {
    /// The whole pages inside `part`, as (start, length); `None` if there are none.
    fn inner(part: &[u8]) -> Option<(usize, usize)> {
        // SAFETY: sysconf only reads a constant of the system
        let page = usize::try_from(unsafe { libc::sysconf(libc::_SC_PAGESIZE) }).ok()?;
        let start = (part.as_ptr() as usize).checked_next_multiple_of(page)?;
        let end = (part.as_ptr() as usize + part.len()) / page * page;
        (end > start).then(|| (start, end - start))
    }

    /// Maps the pages of `part` (of a file mapping) in ahead of reading them: one system call
    /// instead of a fault per 64 KiB. Nothing happens where the kernel cannot (before 5.14).
    fn map_in(part: &[u8]) {
        #[cfg(target_os = "linux")]
        if let Some((start, len)) = Self::inner(part) {
            // SAFETY: advice on pages of a mapping we hold; MADV_POPULATE_READ only faults
            // them in (readable, contents unchanged); an error leaves them to fault on demand
            unsafe { libc::madvise(start as *mut libc::c_void, len, libc::MADV_POPULATE_READ) };
        }
    }

    /// Drops the page-table entries of `part`, which must lie in a read-only private file
    /// mapping: its contents stay the same (read again from the page cache if touched).
    fn drop_out(part: &[u8]) {
        #[cfg(target_os = "linux")]
        if let Some((start, len)) = Self::inner(part) {
            // SAFETY: on a read-only private file mapping MADV_DONTNEED only unmaps pages that
            // were never written; a later read maps the same file contents again. (On
            // anonymous memory it would zero them: callers pass only file mappings.)
            unsafe { libc::madvise(start as *mut libc::c_void, len, libc::MADV_DONTNEED) };
        }
    }
}

/// Lines in `bytes` (a last line without its newline counts): at least the rows they hold.
fn count_lines(bytes: &[u8]) -> usize {
    let mut newlines = 0usize;
    #[cfg(target_arch = "x86_64")]
    let rest = {
        // 16 bytes per compare (SSE2, in every x86-64): the compiler's own vectorisation of a
        // byte count widened every byte to 64 bits and ran at a third of the parser's speed
        use std::arch::x86_64::*;
        let mut blocks = bytes.chunks_exact(16);
        for block in &mut blocks {
            // SAFETY: SSE2 is part of x86-64; the load reads the 16 bytes of `block`
            let mask = unsafe {
                let v = _mm_loadu_si128(block.as_ptr() as *const __m128i);
                _mm_movemask_epi8(_mm_cmpeq_epi8(v, _mm_set1_epi8(b'\n' as i8)))
            };
            newlines += mask.count_ones() as usize;
        }
        blocks.remainder()
    };
    #[cfg(not(target_arch = "x86_64"))]
    let rest = bytes;
    newlines += rest.iter().filter(|&&b| b == b'\n').count();
    newlines + (!bytes.is_empty() && bytes[bytes.len() - 1] != b'\n') as usize
}

/// Where `body` is cut for `threads` parts: each bound just after a newline (or at the end).
fn part_bounds(body: &[u8], threads: usize) -> Vec<usize> {
    let mut bounds = vec![0usize];
    for t in 1..threads {
        let guess = body.len() * t / threads;
        let b = memchr_nl(body, guess.max(*bounds.last().expect("non-empty")));
        bounds.push((b + 1).min(body.len()));
    }
    bounds.push(body.len());
    bounds.dedup();
    bounds
}

/// Room for the rows of `part`: its lines estimated from the lines in its first 128 KiB, with
/// a margin of 1/32 and 64 rows. An estimate only — a part with more rows finds out while it
/// is parsed ([`Short::Room`]) and the caller falls back to counting.
fn room_for_lines(part: &[u8]) -> usize {
    const SAMPLE: usize = 128 << 10;
    let sample = &part[..part.len().min(SAMPLE)];
    let lines = count_lines(sample) as u128;
    let estimate = (part.len() as u128 * lines / sample.len().max(1) as u128) as usize;
    estimate + estimate / 32 + 64
}

/// Parses two parts of the body on two threads without counting their lines first: the first
/// part from its last row down, the second from its first row up, each into its side of one
/// meeting point per column ([`parse_backward`], [`parse_forward`]). The rows then meet with
/// no gap, whatever the blank lines, and the room on either side is an estimate
/// ([`room_for_lines`]) that is checked row by row.
///
/// Why: counting the lines first read the whole file from memory once more before the parse
/// (≈ 8 ms of the ≈ 0.1 s of `nanocal stepwise` on an 80 MB file, both cores). `None` when the
/// estimate was short, a value or row is bad (the caller's counted parse in file order then
/// reports it with its line), or the block cannot be mapped: nothing is returned half-parsed.
fn parse_two_way(parts: [&[u8]; 2], names: &[String], mapped: bool) -> Option<Vec<Column>> {
    let ncol = names.len();
    let room = [room_for_lines(parts[0]), room_for_lines(parts[1])];
    let per_column = room[0].checked_add(room[1])?;
    let values = per_column.checked_mul(ncol)?;
    // as the counted parse: one block only where it is large enough for huge pages
    if ncol == 0 || values < Block::HUGE / 8 {
        return None;
    }
    let mut block = Block::zeroed(values)?;
    let (mut down, mut up) = (Vec::with_capacity(ncol), Vec::with_capacity(ncol));
    for col in block.as_mut_slice().chunks_exact_mut(per_column) {
        let (d, u) = col.split_at_mut(room[0]);
        down.push(d);
        up.push(u);
    }
    let (first, second) = std::thread::scope(|s| {
        let second = s.spawn(move || {
            if mapped {
                Pages::map_in(parts[1]);
            }
            let rows = parse_forward(parts[1], names, 0, up);
            if mapped {
                Pages::drop_out(parts[1]);
            }
            rows
        });
        if mapped {
            Pages::map_in(parts[0]);
        }
        let first = parse_backward(parts[0], names, down);
        if mapped {
            Pages::drop_out(parts[0]);
        }
        (first, second.join().expect("parser thread panicked"))
    });
    let (Ok(first), Ok(second)) = (first, second) else {
        return None;
    };
    Some(block.into_columns(ncol, per_column, room[0] - first, first + second))
}

/// Parses the rows after the header, splitting large inputs at line boundaries across threads.
/// `header_line` is the line number of the header (rows start on the next line).
///
/// On two threads (two cores, the common case) see [`parse_two_way`]: no count of the lines.
/// Otherwise, and where that falls back: each thread writes its rows straight into its own
/// range of the final columns (sized by a count of the lines first): no per-thread columns to
/// concatenate afterwards — that copy and the page faults of its fresh memory were a tenth of
/// reading an 80 MB file. Blank lines make fewer rows than lines; the ranges are then closed
/// up (a rare file, a cheap move).
/// `mapped`: `body` lies in a read-only private file mapping (each thread maps its part in and
/// drops it after, [`Pages`]).
fn parse_body_parallel(
    body: &[u8],
    names: &[String],
    header_line: usize,
    mapped: bool,
) -> Result<Vec<Column>, RecordingError> {
    // the size first: asking for the parallelism reads the cgroup's files (tens of µs, more
    // than a small file's whole parse)
    let threads = if body.len() < (1 << 20) {
        1
    } else {
        std::thread::available_parallelism()
            .map_or(1, |t| t.get())
            .min(8)
    };
    let bounds = part_bounds(body, threads);
    let chunks: Vec<&[u8]> = bounds.windows(2).map(|w| &body[w[0]..w[1]]).collect();
    if let [first, second] = chunks[..] {
        if let Some(columns) = parse_two_way([first, second], names, mapped) {
            return Ok(columns);
        }
    }
    let lines: Vec<usize> = if chunks.len() == 1 {
        vec![count_lines(chunks[0])]
    } else {
        std::thread::scope(|s| {
            let handles: Vec<_> = chunks
                .iter()
                .map(|&c| {
                    s.spawn(move || {
                        if mapped {
                            Pages::map_in(c);
                        }
                        count_lines(c)
                    })
                })
                .collect();
            handles
                .into_iter()
                .map(|h| h.join().expect("line counter panicked"))
                .collect()
        })
    };
    let total: usize = lines.iter().sum();
    // one block for all columns when it is large enough to hold huge pages
    let mut block = if total * names.len() >= Block::HUGE / 8 {
        Block::zeroed(total * names.len())
    } else {
        None
    };
    let mut owned: Vec<Vec<f64>> = Vec::new();
    let mut columns: Vec<&mut [f64]> = match &mut block {
        Some(b) if total > 0 => b.as_mut_slice().chunks_exact_mut(total).collect(),
        _ => {
            owned = names.iter().map(|_| vec![0.0; total]).collect();
            owned.iter_mut().map(|c| c.as_mut_slice()).collect()
        }
    };
    // per chunk, its range of every column
    let mut per_chunk: Vec<Vec<&mut [f64]>> = chunks.iter().map(|_| Vec::new()).collect();
    for col in columns.iter_mut() {
        let mut rest: &mut [f64] = &mut col[..];
        for (dst, &l) in per_chunk.iter_mut().zip(&lines) {
            let (head, tail) = rest.split_at_mut(l);
            dst.push(head);
            rest = tail;
        }
    }
    let results: Vec<Result<usize, RecordingError>> = if chunks.len() == 1 {
        let out = per_chunk.pop().expect("one chunk");
        vec![parse_body(chunks[0], names, header_line, out)]
    } else {
        std::thread::scope(|s| {
            let handles: Vec<_> = chunks
                .iter()
                .zip(per_chunk)
                .map(|(&chunk, out)| {
                    s.spawn(move || {
                        let rows = parse_body(chunk, names, 0, out);
                        if mapped {
                            Pages::drop_out(chunk);
                        }
                        rows
                    })
                })
                .collect();
            handles
                .into_iter()
                .map(|h| h.join().expect("parser thread panicked"))
                .collect()
        })
    };
    let mut rows = Vec::with_capacity(results.len());
    for (k, part) in results.into_iter().enumerate() {
        match part {
            Ok(r) => rows.push(r),
            Err(e) if chunks.len() == 1 => return Err(e),
            Err(e) => {
                // local line numbers: add the lines of the earlier chunks and the header
                let before =
                    header_line + body[..bounds[k]].iter().filter(|&&b| b == b'\n').count();
                return Err(shift_line(e, before));
            }
        }
    }
    // close up the gaps left by blank lines
    let n: usize = rows.iter().sum();
    if n < total {
        for col in columns.iter_mut() {
            let (mut from, mut to) = (0, 0);
            for (&r, &l) in rows.iter().zip(&lines) {
                col.copy_within(from..from + r, to);
                from += l;
                to += r;
            }
        }
    }
    drop(columns);
    Ok(match block {
        Some(b) if total > 0 => b.into_columns(names.len(), total, 0, n),
        _ => owned
            .into_iter()
            .map(|mut c| {
                c.truncate(n);
                Column::Own(c)
            })
            .collect(),
    })
}

fn shift_line(e: RecordingError, by: usize) -> RecordingError {
    match e {
        RecordingError::MissingValue { line, column, name } => RecordingError::MissingValue {
            line: line + by,
            column,
            name,
        },
        RecordingError::NotNumeric {
            line,
            column,
            name,
            found,
        } => RecordingError::NotNumeric {
            line: line + by,
            column,
            name,
            found,
        },
        RecordingError::TooManyValues { line, expected } => RecordingError::TooManyValues {
            line: line + by,
            expected,
        },
        other => other,
    }
}

/// Why a part of the input could not be parsed into the room it was given.
enum Short {
    /// More rows than the room: the estimate of the lines was short.
    Room,
    /// A bad value or row (the caller parses again in file order for the error and its line).
    Bad(RecordingError),
}

impl From<RecordingError> for Short {
    fn from(e: RecordingError) -> Short {
        Short::Bad(e)
    }
}

/// Parses rows into `columns` (one slice per column, each with room for every line of
/// `bytes`); returns the number of rows. Line numbers in errors are `line_before + 1` for the
/// first row.
fn parse_body(
    bytes: &[u8],
    names: &[String],
    line_before: usize,
    columns: Vec<&mut [f64]>,
) -> Result<usize, RecordingError> {
    match parse_forward(bytes, names, line_before, columns) {
        Ok(rows) => Ok(rows),
        Err(Short::Bad(e)) => Err(e),
        Err(Short::Room) => unreachable!("the columns have room for every line"),
    }
}

/// [`parse_body`] into columns that may be too short: `Short::Room` when a row finds no room.
/// Rows of the common form go through the fast path of whole rows ([`whole_rows`]), the rest
/// (and the errors) row by row.
fn parse_forward(
    bytes: &[u8],
    names: &[String],
    line_before: usize,
    mut columns: Vec<&mut [f64]>,
) -> Result<usize, Short> {
    let room = columns.first().map_or(0, |c| c.len());
    let mut rows = 0usize;
    let n = bytes.len();
    let mut pos = 0usize;
    let mut line_no = line_before;
    let mut window = Window::default();
    let mut whole = whole_rows::WholeRows::new();
    let mut backoff = Backoff::default();
    while pos < n {
        if backoff.ready() {
            let (taken, next) = whole.take(bytes, pos, &mut columns, rows, room - rows);
            backoff.taken(taken);
            rows += taken;
            line_no += taken;
            pos = next;
            if pos >= n {
                break;
            }
        }
        line_no += 1;
        let q = skip_blank(bytes, pos);
        if q >= n || bytes[q] == b'\n' {
            pos = q + 1;
            continue;
        }
        if rows == room {
            return Err(Short::Room);
        }
        pos = parse_row(bytes, pos, names, line_no, &mut columns, rows, &mut window)?;
        rows += 1;
    }
    Ok(rows)
}

/// When to try the fast path of whole rows ([`whole_rows`]) again after a try took none: at
/// once after a try that took some (a row it cannot take is rare in a file it suits), else
/// after twice as many rows parsed the general way as the time before (at most 4096: a file
/// it does not suit costs little indexing thrown away).
struct Backoff {
    /// Rows (or batches) to parse the general way before the next try.
    wait: usize,
    /// The wait after the next try that takes none.
    next: usize,
}

impl Default for Backoff {
    fn default() -> Backoff {
        Backoff { wait: 0, next: 1 }
    }
}

impl Backoff {
    /// Whether to try now; if not, counts one general row (or batch).
    #[inline]
    fn ready(&mut self) -> bool {
        if self.wait == 0 {
            return true;
        }
        self.wait -= 1;
        false
    }

    /// A try took `rows` rows.
    #[inline]
    fn taken(&mut self, rows: usize) {
        if rows > 0 {
            self.next = 1;
        } else {
            self.wait = self.next;
            self.next = (self.next * 2).min(4096);
        }
    }
}

/// Parses the rows of `bytes` from the last to the first, writing the last row at the end of
/// each column and the earlier ones below it; returns the number of rows (they fill the last
/// `rows` places of each column). Why: two threads then fill one range of each column from
/// the middle outwards — this one down, the next part's up — so neither needs the other's
/// count of lines, and the columns need no count of them before (see [`parse_two_way`]).
/// Errors carry no line number: the caller parses again in file order for them.
///
/// It goes back a batch of lines at a time (a segment of [`whole_rows`]), each batch parsed in
/// file order by the fast path of whole rows into the places below the rows already done, or
/// row by row from its end where the fast path does not take it all.
fn parse_backward(
    bytes: &[u8],
    names: &[String],
    mut columns: Vec<&mut [f64]>,
) -> Result<usize, Short> {
    let room = columns.first().map_or(0, |c| c.len());
    let mut rows = 0usize;
    let mut end = bytes.len();
    let mut window = Window::default();
    let mut whole = whole_rows::WholeRows::new();
    let mut backoff = Backoff::default();
    while end > 0 {
        // a batch of whole lines before `end`: those that start in its last segment's worth
        // of bytes, or the last line alone if it is longer than that
        let line_end = if bytes[end - 1] == b'\n' {
            end - 1
        } else {
            end
        };
        let from = if end <= whole_rows::SEGMENT {
            0
        } else {
            let x = end - whole_rows::SEGMENT;
            if bytes[x - 1] == b'\n' {
                x
            } else {
                memchr_nl(bytes, x) + 1
            }
        };
        let from = if from >= end {
            line_start(bytes, line_end)
        } else {
            from
        };
        // the fast path, in file order into the places below the rows already parsed, one
        // place per line: the batch is done if it takes every line (none of them blank). The
        // batch at the end of the input (the fast path's loads would reach past it) is not
        // a miss.
        if end + whole_rows::REACH <= bytes.len() && backoff.ready() {
            let taken = whole.take_below(bytes, from, end, &mut columns, room - rows);
            backoff.taken(taken.unwrap_or(0));
            if let Some(lines) = taken {
                rows += lines;
                end = from;
                continue;
            }
        }
        // otherwise row by row from the batch's end, each into the place it belongs in (what
        // the fast path wrote below those is written again by the batches before, or lies
        // outside the rows returned)
        while end > from {
            // the last line before `end`: from just after the newline before it (or the start)
            let line_end = if bytes[end - 1] == b'\n' {
                end - 1
            } else {
                end
            };
            let start = line_start(bytes, line_end);
            end = start;
            let q = skip_blank(bytes, start);
            if q >= line_end {
                continue;
            }
            if rows == room {
                return Err(Short::Room);
            }
            let next = parse_row(
                bytes,
                start,
                names,
                0,
                &mut columns,
                room - 1 - rows,
                &mut window,
            )?;
            debug_assert!(next >= line_end, "a row ends at its line's end");
            rows += 1;
        }
    }
    Ok(rows)
}

/// The first position after spaces, tabs and carriage returns from `pos`.
#[inline(always)]
fn skip_blank(bytes: &[u8], mut pos: usize) -> usize {
    while pos < bytes.len() && matches!(bytes[pos], b' ' | b'\t' | b'\r') {
        pos += 1;
    }
    pos
}

/// Where the line that ends at `end` (its newline, or the end of the input) starts: just after
/// the newline before it, or 0.
#[inline(always)]
fn line_start(bytes: &[u8], end: usize) -> usize {
    let mut e = end;
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::*;
        // 16 bytes per compare (SSE2, in every x86-64), from the end down
        while e >= 16 {
            // SAFETY: SSE2 is part of x86-64; the load reads bytes[e - 16..e]
            let mask = unsafe {
                let v = _mm_loadu_si128(bytes.as_ptr().add(e - 16) as *const __m128i);
                _mm_movemask_epi8(_mm_cmpeq_epi8(v, _mm_set1_epi8(b'\n' as i8))) as u32
            };
            if mask != 0 {
                // the highest set bit is the newline nearest the end
                return e - 16 + (31 - mask.leading_zeros()) as usize + 1;
            }
            e -= 16;
        }
    }
    bytes[..e]
        .iter()
        .rposition(|&b| b == b'\n')
        .map_or(0, |p| p + 1)
}

/// Parses the row that starts at `pos` (a line that is not blank) into place `row` of every
/// column; returns where the next line starts. `line_no` is for errors. Out of line: one copy
/// for both directions, called once a row; compiled for SSSE3 too, taken where the CPU has it
/// (every x86-64 since 2006; a flag read once a row).
#[inline(always)]
fn parse_row(
    bytes: &[u8],
    pos: usize,
    names: &[String],
    line_no: usize,
    columns: &mut [&mut [f64]],
    row: usize,
    window: &mut Window,
) -> Result<usize, RecordingError> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("ssse3") {
        // SAFETY: the CPU has SSSE3
        return unsafe { parse_row_ssse3(bytes, pos, names, line_no, columns, row, window) };
    }
    parse_row_plain(bytes, pos, names, line_no, columns, row, window)
}

/// [`parse_row`] without SSSE3.
#[inline(never)]
fn parse_row_plain(
    bytes: &[u8],
    pos: usize,
    names: &[String],
    line_no: usize,
    columns: &mut [&mut [f64]],
    row: usize,
    window: &mut Window,
) -> Result<usize, RecordingError> {
    parse_row_in::<false>(bytes, pos, names, line_no, columns, row, window)
}

/// [`parse_row`] compiled for SSSE3 ([`mantissa_ssse3`]).
///
/// # Safety
/// The CPU has SSSE3.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "ssse3")]
#[inline(never)]
unsafe fn parse_row_ssse3(
    bytes: &[u8],
    pos: usize,
    names: &[String],
    line_no: usize,
    columns: &mut [&mut [f64]],
    row: usize,
    window: &mut Window,
) -> Result<usize, RecordingError> {
    parse_row_in::<true>(bytes, pos, names, line_no, columns, row, window)
}

/// The body of [`parse_row`]; `SSSE3`: take [`mantissa_ssse3`] (only where compiled for it).
#[inline(always)]
fn parse_row_in<const SSSE3: bool>(
    bytes: &[u8],
    mut pos: usize,
    names: &[String],
    line_no: usize,
    columns: &mut [&mut [f64]],
    row: usize,
    window: &mut Window,
) -> Result<usize, RecordingError> {
    let ncol = names.len();
    let n = bytes.len();
    let missing = |line: usize, c: usize| RecordingError::MissingValue {
        line,
        column: c + 1,
        name: names[c].clone(),
    };
    for (c, col) in columns.iter_mut().enumerate() {
        // (a match, not `Option::or_else`: the compiler left that call out of line, a third
        // of the parse's time)
        let fast = match window.field::<SSSE3>(bytes, pos) {
            Some(hit) => Some(hit),
            None => scan_number(bytes, pos),
        };
        let (value, end) = match fast {
            Some((v, e)) => (v, e),
            None => {
                // slow path: the whole field, exact parse or a precise error
                let e = bytes[pos..]
                    .iter()
                    .position(|&b| b == b',' || b == b'\n')
                    .map_or(n, |k| pos + k);
                let field = trim(trim_cr(&bytes[pos..e]));
                if field.is_empty() {
                    return Err(missing(line_no, c));
                }
                match slow_parse(field) {
                    Some(v) => (v, e),
                    None => {
                        let mut found = String::from_utf8_lossy(field).into_owned();
                        if found.len() > 40 {
                            let mut cut = 40;
                            while !found.is_char_boundary(cut) {
                                cut -= 1;
                            }
                            found.truncate(cut);
                        }
                        return Err(RecordingError::NotNumeric {
                            line: line_no,
                            column: c + 1,
                            name: names[c].clone(),
                            found,
                        });
                    }
                }
            }
        };
        col[row] = value;
        let last = c + 1 == ncol;
        // end is at a delimiter: ',' or '\n' (after an optional '\r') or the end of input
        let mut e = end;
        if e < n && bytes[e] == b'\r' {
            e += 1;
        }
        if e >= n || bytes[e] == b'\n' {
            if !last {
                return Err(missing(line_no, c + 1));
            }
            pos = e + 1;
        } else if bytes[e] == b',' {
            if last {
                return Err(RecordingError::TooManyValues {
                    line: line_no,
                    expected: ncol,
                });
            }
            pos = e + 1;
        } else {
            unreachable!("scan_number and the slow path stop at a delimiter");
        }
    }
    Ok(pos)
}

/// Where the delimiters (`,`, `\n`) and points are in 64 bytes of the input from `base`: one
/// bit per byte. The general path's fastest case reads fields through it (rows wholly of the
/// common form go faster still: [`whole_rows`]).
///
/// Why: a parser that finds a field's end by reading the field makes every field wait for the
/// previous one (its loads, its digit count, its delimiter test: ≈ 30 cycles a field, most of
/// the parse). Found here, the next field's start is one bit scan away, and the fields' digits
/// are read and converted independently, overlapping in the CPU.
#[derive(Default)]
struct Window {
    base: usize,
    delims: u64,
    points: u64,
}

impl Window {
    /// The input must extend this far past a field's start for the fastest path (the 64-byte
    /// window, and an eight-byte load at a point up to 62 bytes in).
    const REACH: usize = 80;

    /// Re-reads the window at `base` (at least 64 bytes there).
    #[inline(always)]
    fn fill(&mut self, b: &[u8], base: usize) {
        let bytes = &b[base..base + 64];
        let (mut delims, mut points) = (0u64, 0u64);
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::*;
            for k in 0..4 {
                // SAFETY: SSE2 is part of x86-64; the load reads 16 of the 64 bytes of `bytes`
                let (d, p) = unsafe {
                    let v = _mm_loadu_si128(bytes.as_ptr().add(16 * k) as *const __m128i);
                    let d = _mm_or_si128(
                        _mm_cmpeq_epi8(v, _mm_set1_epi8(b',' as i8)),
                        _mm_cmpeq_epi8(v, _mm_set1_epi8(b'\n' as i8)),
                    );
                    let p = _mm_cmpeq_epi8(v, _mm_set1_epi8(b'.' as i8));
                    (_mm_movemask_epi8(d) as u16, _mm_movemask_epi8(p) as u16)
                };
                delims |= (d as u64) << (16 * k);
                points |= (p as u64) << (16 * k);
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        for (k, &c) in bytes.iter().enumerate() {
            delims |= ((c == b',' || c == b'\n') as u64) << k;
            points |= ((c == b'.') as u64) << k;
        }
        *self = Window {
            base,
            delims,
            points,
        };
    }

    /// The field at `pos` if it is what instruments and the benchmark write: an optional `-`,
    /// 1–8 integer digits, a point, 1–8 decimals (15 digits at most), then `,` or `\n`. The
    /// mantissa is below 10¹⁵ < 2⁵³, so the value is Clinger's one exact division, bit for bit
    /// what [`scan_number`] returns for the same text. `None` for anything else (then
    /// `scan_number` decides), and near the end of the input.
    #[inline(always)]
    fn field<const SSSE3: bool>(&mut self, b: &[u8], pos: usize) -> Option<(f64, usize)> {
        if pos + Self::REACH > b.len() {
            return None;
        }
        // within a line `pos` only grows, and the window starts at an earlier `pos` of it; a
        // backward parse moves to an earlier line, below the window (wrapping: refilled)
        let mut rel = pos.wrapping_sub(self.base);
        if rel >= 64 || self.delims >> rel == 0 {
            self.fill(b, pos);
            rel = 0;
        }
        let ahead = self.delims >> rel;
        if ahead == 0 {
            return None;
        }
        let len = ahead.trailing_zeros() as usize;
        let point = (self.points >> rel).trailing_zeros() as usize;
        let neg = b[pos] == b'-';
        let sign = neg as usize;
        // both at least 1 (wrapping: a point before the digits is caught too), at most 8, 15
        // in all
        let nd = point.wrapping_sub(sign);
        let nf = len.wrapping_sub(point + 1);
        if !(1..=8).contains(&nd) || !(1..=8).contains(&nf) || nd + nf > 15 {
            return None;
        }
        #[cfg(target_arch = "x86_64")]
        if SSSE3 {
            // SAFETY: `SSSE3` is true only in code compiled for it and run where the CPU has
            // it ([`parse_row`]); the 16 bytes from `pos + sign` lie in `b` (`REACH`)
            let mant = unsafe { mantissa_ssse3(b.as_ptr().add(pos + sign), nd, nf) }?;
            let v = mant as i64 as f64 / POW10[nf];
            return Some((if neg { -v } else { v }, pos + len));
        }
        let int_w = u64::from_le_bytes(b[pos + sign..pos + sign + 8].try_into().ok()?);
        let frac_w = u64::from_le_bytes(b[pos + point + 1..pos + point + 9].try_into().ok()?);
        // every byte between sign, point and delimiter a digit
        if (leading_digits(int_w) as usize) < nd || (leading_digits(frac_w) as usize) < nf {
            return None;
        }
        let mant = digits_value(int_w, nd as u32) * POW10_U64[nf] + digits_value(frac_w, nf as u32);
        // below 2⁵³: the signed conversion is exact (one instruction without AVX-512). The
        // division stays: a division-free exact quotient (Eisel–Lemire's 128-bit product with a
        // reciprocal of 5^f, rounded without a branch) measured no faster on this machine
        let v = mant as i64 as f64 / POW10[nf];
        Some((if neg { -v } else { v }, pos + len))
    }
}

/// Shuffles for [`mantissa_ssse3`], by `8 · (nd − 1) + nf − 1`: the `nd` integer digits and
/// the `nf` decimals of `d…d.d…d` (the point at `nd` skipped), right-aligned in 16 bytes,
/// zeros (`0x80`: pshufb writes 0) before them.
#[cfg(target_arch = "x86_64")]
static DIGIT_SHUFFLES: [[u8; 16]; 64] = {
    let mut t = [[0x80u8; 16]; 64];
    let mut nd = 1;
    while nd <= 8 {
        let mut nf = 1;
        while nf <= 8 {
            let digits = nd + nf;
            if digits <= 15 {
                let mut k = 0;
                while k < digits {
                    // digit k of the number: before the point, or one byte later after it
                    let from = if k < nd { k } else { k + 1 };
                    t[8 * (nd - 1) + nf - 1][16 - digits + k] = from as u8;
                    k += 1;
                }
            }
            nf += 1;
        }
        nd += 1;
    }
    t
};

/// The mantissa of `d…d.d…d` at `p` (`nd` integer digits, a point, `nf` decimals; 1–8 each,
/// 15 in all) as one integer, or `None` if a byte there is not a digit: the sixteen bytes at
/// once instead of two eight-byte words each checked and converted in turn. Why: the field's
/// conversion is most of the parse, and this is fewer instructions (≈ 12 against ≈ 35) and
/// one dependency chain instead of two. The same integer as the word-wise path, so the same
/// value.
///
/// # Safety
/// The CPU has SSSE3; 16 bytes from `p` are readable.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn mantissa_ssse3(p: *const u8, nd: usize, nf: usize) -> Option<u64> {
    use std::arch::x86_64::*;
    // SAFETY: the caller's: SSSE3 present, 16 readable bytes at `p`
    unsafe {
        let v = _mm_loadu_si128(p as *const __m128i);
        let d = _mm_sub_epi8(v, _mm_set1_epi8(b'0' as i8));
        // a digit's byte is ≤ 9 after the subtraction (bytes below '0' wrap above 9)
        let digit = _mm_cmpeq_epi8(_mm_min_epu8(d, _mm_set1_epi8(9)), d);
        let want = ((1u32 << nd) - 1) | (((1u32 << nf) - 1) << (nd + 1));
        if (_mm_movemask_epi8(digit) as u32) & want != want {
            return None;
        }
        Some(digits_value_ssse3(d, 8 * (nd - 1) + nf - 1))
    }
}

/// The integer of the digits `d` (the 16 bytes of a field less `'0'`, digits checked) of shape
/// `8 · (nd − 1) + nf − 1` ([`DIGIT_SHUFFLES`]): the digits right-aligned by the shape's
/// shuffle, then summed in pairs (10·a + b), fours (100·ab + cd) and eights (10⁴·abcd + efgh).
///
/// # Safety
/// The CPU has SSSE3; `shape < 64`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn digits_value_ssse3(d: std::arch::x86_64::__m128i, shape: usize) -> u64 {
    use std::arch::x86_64::*;
    // SAFETY: the caller's: SSSE3 present; the table has the row
    unsafe {
        let shuffle = _mm_loadu_si128(DIGIT_SHUFFLES[shape].as_ptr() as *const __m128i);
        let digits = _mm_shuffle_epi8(d, shuffle);
        let pairs = _mm_maddubs_epi16(digits, _mm_set1_epi16(0x010A));
        let fours = _mm_madd_epi16(pairs, _mm_set1_epi32(0x0001_0064));
        let fours = _mm_packs_epi32(fours, fours);
        let eights = _mm_madd_epi16(fours, _mm_set1_epi32(0x0001_2710));
        let hi = _mm_cvtsi128_si32(eights) as u32 as u64;
        let lo = _mm_cvtsi128_si32(_mm_srli_si128(eights, 4)) as u32 as u64;
        hi * 100_000_000 + lo
    }
}

/// Fast path for one field starting at `pos`: optional spaces, a decimal number with at most
/// 19 significant digits and a small exponent, optional spaces, then a delimiter (`,`, `\r`,
/// `\n` or end of input). Returns the value and the delimiter's index, or `None` when the field
/// needs the slow path (or is empty / not a number).
#[inline(always)]
fn scan_number(b: &[u8], mut i: usize) -> Option<(f64, usize)> {
    let n = b.len();
    while i < n && (b[i] == b' ' || b[i] == b'\t') {
        i += 1;
    }
    let mut neg = false;
    if i < n && (b[i] == b'-' || b[i] == b'+') {
        neg = b[i] == b'-';
        i += 1;
    }
    let mut mant: u64 = 0;
    let mut exp10: i32 = 0;
    let mut any = false;
    // up to eight digits at a time while at most 19 have been read (the mantissa then cannot
    // wrap), then one at a time. `digits` counts significant digits one at a time, but every
    // digit (leading zeros too) of a run taken eight at a time: more than 19 then sends a
    // number with many leading zeros to the exact slow path, which is rare and still exact.
    let mut all_digits = 0u32;
    let (taken, v) = swar_run(b, i, all_digits);
    mant = mant * POW10_U64[taken as usize] + v;
    all_digits += taken;
    any |= taken > 0;
    i += taken as usize;
    let mut digits = taken;
    while i < n {
        let d = b[i].wrapping_sub(b'0');
        if d > 9 {
            break;
        }
        mant = mant.wrapping_mul(10).wrapping_add(d as u64);
        digits += (mant != 0) as u32;
        all_digits += 1;
        any = true;
        i += 1;
    }
    if i < n && b[i] == b'.' {
        i += 1;
        let (taken, v) = swar_run(b, i, all_digits);
        if taken > 0 {
            mant = mant * POW10_U64[taken as usize] + v;
            exp10 -= taken as i32;
            any = true;
            i += taken as usize;
            digits += taken;
        }
        while i < n {
            let d = b[i].wrapping_sub(b'0');
            if d > 9 {
                break;
            }
            mant = mant.wrapping_mul(10).wrapping_add(d as u64);
            digits += (mant != 0) as u32;
            exp10 -= 1;
            any = true;
            i += 1;
        }
    }
    if !any || digits > 19 {
        return None;
    }
    if i < n && (b[i] == b'e' || b[i] == b'E') {
        i += 1;
        let mut eneg = false;
        if i < n && (b[i] == b'-' || b[i] == b'+') {
            eneg = b[i] == b'-';
            i += 1;
        }
        let mut e: i32 = 0;
        let mut edig = false;
        while i < n && b[i].is_ascii_digit() && e < 10_000 {
            e = e * 10 + (b[i] - b'0') as i32;
            edig = true;
            i += 1;
        }
        if !edig {
            return None;
        }
        exp10 += if eneg { -e } else { e };
    }
    while i < n && (b[i] == b' ' || b[i] == b'\t') {
        i += 1;
    }
    // a CR is a delimiter only where it ends the line (CR LF, or CR at the end of the input);
    // anywhere else the field is the slow path's to refuse with its text
    if i < n {
        match b[i] {
            b',' | b'\n' => {}
            b'\r' if i + 1 == n || b[i + 1] == b'\n' => {}
            _ => return None,
        }
    }
    if mant >= (1u64 << 53) || !(-22..=22).contains(&exp10) {
        let v = exact_decimal(mant, exp10)?;
        return Some((if neg { -v } else { v }, i));
    }
    let m = mant as f64;
    let v = if exp10 >= 0 {
        m * POW10[exp10 as usize]
    } else {
        m / POW10[(-exp10) as usize]
    };
    Some((if neg { -v } else { v }, i))
}

/// 10⁰ … 10¹⁹ (a run read eight digits at a time is at most 19 digits long).
const POW10_U64: [u64; 20] = {
    let mut t = [1u64; 20];
    let mut i = 1;
    while i < 20 {
        t[i] = t[i - 1] * 10;
        i += 1;
    }
    t
};

/// The run of ASCII digits at `b[i..]`, read eight bytes at a time (SWAR) while at least eight
/// bytes remain and `before + 8 ≤ 19` digits have been read in all: (digits taken, their
/// value). Stops at the first non-digit, or where the byte-at-a-time loop must take over.
#[inline(always)]
fn swar_run(b: &[u8], mut i: usize, before: u32) -> (u32, u64) {
    let (mut taken, mut value) = (0u32, 0u64);
    while before + taken <= 11 {
        let Some(w) = b.get(i..i + 8) else { break };
        let w = u64::from_le_bytes(w.try_into().expect("eight bytes"));
        let (d, v) = eight_digits(w);
        value = value * POW10_U64[d as usize] + v;
        taken += d;
        i += d as usize;
        if d < 8 {
            break;
        }
    }
    (taken, value)
}

/// The leading ASCII digits of eight bytes (`w` little endian: the first byte lowest): how
/// many (0–8) and their value.
#[inline(always)]
fn eight_digits(w: u64) -> (u32, u64) {
    let d = leading_digits(w);
    if d == 0 {
        return (0, 0);
    }
    (d, digits_value(w, d))
}

/// How many of the eight bytes of `w` (little endian: the first byte lowest) are ASCII digits
/// before the first non-digit (0–8).
#[inline(always)]
fn leading_digits(w: u64) -> u32 {
    const ONES: u64 = 0x0101_0101_0101_0101;
    // a byte is a digit when its high nibble is 3 and stays 3 after adding 6 (low nibble ≤ 9);
    // a carry out of a byte ≥ 0xFA only disturbs later bytes, after a non-digit already
    let hi = w & (0xF0 * ONES);
    let hi6 = w.wrapping_add(6 * ONES) & (0xF0 * ONES);
    let non_digit = (hi ^ (0x30 * ONES)) | (hi6 ^ (0x30 * ONES));
    non_digit.trailing_zeros() / 8
}

/// The value of the first `d` (1–8) bytes of `w`, which are ASCII digits, the first byte the
/// most significant.
#[inline(always)]
fn digits_value(w: u64, d: u32) -> u64 {
    const ONES: u64 = 0x0101_0101_0101_0101;
    // the d digits' values in the top bytes, zeros (leading zeros of the number) below
    let mut v = w.wrapping_sub(0x30 * ONES) << (8 * (8 - d));
    // pairs, then quadruples, then all eight (the first byte is the most significant digit)
    // (Lemire's eight-digit conversion; the products wrap by design, the low 32 bits of the
    // result are the value)
    const PAIRS: u64 = 0x0000_00FF_0000_00FF;
    v = v.wrapping_mul(10).wrapping_add(v >> 8);
    v = (PAIRS & v)
        .wrapping_mul(100 + (1_000_000 << 32))
        .wrapping_add((PAIRS & (v >> 16)).wrapping_mul(1 + (10_000 << 32)))
        >> 32;
    v & 0xFFFF_FFFF
}

/// A header field as a column name: spaces and tabs around it and one pair of double quotes
/// removed. A name keeps no quote and no control character, so what the writer writes reads
/// back as the same name.
fn column_name(field: &[u8]) -> Result<String, String> {
    let mut f = trim(field);
    if let [b'"', inner @ .., b'"'] = f {
        f = trim(inner);
    }
    let name = String::from_utf8_lossy(f).into_owned();
    if name.is_empty() {
        return Err("expected a column name, found nothing".into());
    }
    // a byte-order mark too: the reader takes one off the start of the file
    if name
        .chars()
        .any(|c| c == '"' || c == '\u{feff}' || c.is_control())
    {
        return Err(format!(
            "column name {name:?} has a double quote, a byte-order mark or a control character"
        ));
    }
    Ok(name)
}

#[inline]
fn memchr_nl(bytes: &[u8], from: usize) -> usize {
    bytes[from..]
        .iter()
        .position(|&b| b == b'\n')
        .map_or(bytes.len(), |p| from + p)
}

#[inline]
fn trim_cr(line: &[u8]) -> &[u8] {
    line.strip_suffix(b"\r").unwrap_or(line)
}

#[inline]
fn trim(mut s: &[u8]) -> &[u8] {
    while let [b' ' | b'\t', rest @ ..] = s {
        s = rest;
    }
    while let [rest @ .., b' ' | b'\t'] = s {
        s = rest;
    }
    s
}

/// Exact powers of ten representable in f64.
const POW10: [f64; 23] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
];

/// Exact powers of ten as integers, 10^0 ..= 10^22.
const POW10_U128: [u128; 23] = {
    let mut t = [1u128; 23];
    let mut i = 1;
    while i < 23 {
        t[i] = t[i - 1] * 10;
        i += 1;
    }
    t
};

/// `mant × 10^exp10` correctly rounded (round half to even) for `|exp10| ≤ 22`, by exact
/// 128-bit integer arithmetic: the 17–19 digit decimals that the Clinger fast path cannot
/// take. `None` when the integer quotient would keep fewer than 54 bits (then the caller
/// falls back to the standard library).
#[inline]
fn exact_decimal(mant: u64, exp10: i32) -> Option<f64> {
    if mant == 0 {
        return Some(0.0);
    }
    if !(-22..=22).contains(&exp10) {
        return None;
    }
    // value = q · 2^e2, with `sticky` telling whether anything below q's last bit is non-zero
    let (q, e2, sticky): (u128, i32, bool) = if exp10 >= 0 {
        let p = POW10_U128[exp10 as usize];
        let q = (mant as u128).checked_mul(p)?;
        (q, 0, false)
    } else {
        let d = POW10_U128[(-exp10) as usize];
        let num = (mant as u128) << 64;
        (num / d, -64, !num.is_multiple_of(d))
    };
    let bits = 128 - q.leading_zeros() as i32;
    if bits < 54 {
        return if sticky || exp10 < 0 {
            None
        } else {
            Some(q as f64)
        };
    }
    let drop = bits - 53;
    let mut m = q >> drop;
    let half = 1u128 << (drop - 1);
    let rest = q & ((1u128 << drop) - 1);
    let round_up = rest > half || (rest == half && (sticky || m & 1 == 1));
    if round_up {
        m += 1;
    }
    // m ≤ 2^53 (exactly 2^53 after a carry): still exact as f64
    let exp = e2 + drop;
    if !(-1000..=1000).contains(&exp) {
        return None;
    }
    Some(m as f64 * f64::powi(2.0, exp))
}

#[cold]
fn slow_parse(s: &[u8]) -> Option<f64> {
    std::str::from_utf8(s).ok()?.parse::<f64>().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Reads each text as one line of a one-column recording: the reader's own path (the fast
    /// scan, the exact fallback, and the parallel split for inputs over 1 MiB).
    fn read_all<S: AsRef<str>>(texts: &[S]) -> Vec<f64> {
        let mut csv = String::from("x\n");
        for t in texts {
            csv.push_str(t.as_ref());
            csv.push('\n');
        }
        Recording::parse(csv.as_bytes())
            .unwrap()
            .column("x")
            .unwrap()
            .to_vec()
    }

    fn assert_bit_identical<S: AsRef<str>>(texts: &[S]) {
        for (text, got) in texts.iter().zip(read_all(texts)) {
            let want: f64 = text.as_ref().trim().parse().unwrap();
            assert_eq!(got.to_bits(), want.to_bits(), "{}", text.as_ref());
        }
    }

    #[test]
    fn numbers_read_bit_identical_to_std() {
        assert_bit_identical(&[
            "0",
            "-0",
            "1",
            "-1.5",
            "22.125",
            "0.1",
            "3.14159265358979",
            "1e-7",
            "-2.5E+3",
            "123456789012345678",
            "1234567890123456789012",
            "0.30000000000000004",
            "4.9e-324",
            "1.7976931348623157e308",
            "+7",
            ".5",
            "5.",
            "1e400",
            " 2 ",
        ]);
        assert!(read_all(&["NaN"])[0].is_nan());
        // 17-digit decimals (shortest round trip of random doubles) through the 128-bit path
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut texts = Vec::with_capacity(800_000);
        for k in 0..200_000 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let u = (state >> 11) as f64 / (1u64 << 53) as f64;
            let x = match k % 4 {
                0 => u * 1000.0,
                1 => -u * 25.0,
                2 => u * 1e-6,
                _ => f64::from_bits((state >> 2) | 0x3000_0000_0000_0000),
            };
            texts.push(format!("{x}"));
            texts.push(format!("{x:e}"));
            texts.push(format!("{:.17}", x * 1e-3));
            texts.push(format!("{:.3}", x * 1e12));
        }
        assert_bit_identical(&texts);
        // the eight-digits-at-a-time scan: runs of every length at either side of the point,
        // leading zeros, 19 and 20 digits, and the 6 decimals instruments write
        let mut swar: Vec<String> = [
            "12345678.87654321",
            "00000000001.5",
            "0.00000000000000000000123456789",
            "1234567890123456789",
            "12345678901234567890",
            "9999999999999999999",
            "0.9999999999999999999",
            "99999999.99999999999",
            "100000000",
            "10000000.00000001",
        ]
        .map(String::from)
        .to_vec();
        for int_len in 0..=10 {
            for frac_len in 0..=10 {
                let digits = "3141592653";
                let text = format!("{}.{}", &digits[..int_len], &digits[..frac_len]);
                if int_len + frac_len > 0 {
                    swar.push(text.clone());
                    swar.push(format!("-{text}e-3"));
                }
            }
        }
        for k in 0..20_000 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let u = (state >> 11) as f64 / (1u64 << 53) as f64;
            swar.push(format!("{:.6}", (u - 0.3) * 10f64.powi(k % 9 - 2)));
        }
        assert_bit_identical(&swar);
        assert_bit_identical(&[
            "9007199254740993",
            "9007199254740995",
            "18446744073709551615",
            "0.1000000000000000055511151231257827",
        ]);
    }

    /// The windowed fastest path (`Window::field`) in rows of several columns, as a large file
    /// is read: every shape it takes and the ones next to it that it must leave to
    /// `scan_number` (a `+`, spaces, CR LF, 16 digits, no point, an exponent, a field longer
    /// than the window), at every offset in the window, bit-identical to `str::parse`.
    #[test]
    fn fields_in_rows_read_bit_identical_to_std() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let cols = 7;
        let mut csv = (1..=cols)
            .map(|c| format!("c{c}"))
            .collect::<Vec<_>>()
            .join(",");
        csv.push('\n');
        let mut want: Vec<Vec<f64>> = vec![Vec::new(); cols];
        for row in 0..60_000 {
            let mut fields = Vec::with_capacity(cols);
            for _ in 0..cols {
                let r = next();
                let int_len = (r % 10) as usize;
                let frac_len = ((r >> 4) % 10) as usize;
                let digits: String = (0..int_len + frac_len)
                    .map(|k| char::from(b'0' + ((r >> (8 + 3 * k)) % 10) as u8))
                    .collect();
                let mut text = format!("{}.{}", &digits[..int_len], &digits[int_len..]);
                if int_len + frac_len == 0 {
                    text = "0".into();
                }
                text = match (r >> 60) % 16 {
                    0..=5 => format!("-{text}"),
                    6 => format!("+{text}"),
                    7 => format!(" {text} "),
                    8 => digits.clone().max("7".into()),
                    9 => format!("{text}e-2"),
                    10 => format!("{}.{}", "1".repeat(40), "2".repeat(40)),
                    11 => "1234567.12345678".into(),
                    12 => "12345678.1234567".into(),
                    _ => text,
                };
                fields.push(text);
            }
            for (c, f) in fields.iter().enumerate() {
                want[c].push(f.trim().parse::<f64>().unwrap());
            }
            csv.push_str(&fields.join(","));
            csv.push_str(if row % 5 == 0 { "\r\n" } else { "\n" });
        }
        // over 1 MiB: read by the parallel parser, as a large file is
        assert!(csv.len() > 1 << 20);
        let rec = Recording::parse(csv.as_bytes()).unwrap();
        for (c, w) in want.iter().enumerate() {
            let got = rec.column_at(c);
            assert_eq!(got.len(), w.len());
            for (i, (g, w)) in got.iter().zip(w).enumerate() {
                assert_eq!(g.to_bits(), w.to_bits(), "row {i} column {c}: {w}");
            }
        }
    }

    /// [`Window::field`] compiled for SSSE3, for the test below.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "ssse3")]
    unsafe fn field_ssse3(b: &[u8]) -> Option<(f64, usize)> {
        Window::default().field::<true>(b, 0)
    }

    /// The SSSE3 mantissa and the word-wise one (a machine takes one of them for every file)
    /// read every field the same way: each shape of `-?d{1,9}.d{1,9}` and a non-digit at every
    /// place of it, the values bit-identical to `str::parse` where they take the field.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn fast_field_with_and_without_ssse3_agree() {
        assert!(
            std::arch::is_x86_feature_detected!("ssse3"),
            "every x86-64 that runs these tests has SSSE3"
        );
        let digits = b"314159265358979323";
        let mut taken = 0;
        for neg in [false, true] {
            for nd in 0..=9 {
                for nf in 0..=9 {
                    let mut text = Vec::new();
                    if neg {
                        text.push(b'-');
                    }
                    text.extend_from_slice(&digits[..nd]);
                    text.push(b'.');
                    text.extend_from_slice(&digits[nd..nd + nf]);
                    let len = text.len();
                    // a non-digit at every place (the point and sign too), or none
                    for bad in (0..len).map(Some).chain([None]) {
                        for with in [b'/', b':', b'a', b' ', 0xFF, b'0'] {
                            let mut buf = text.clone();
                            if let Some(k) = bad {
                                buf[k] = with;
                            }
                            buf.push(b',');
                            buf.resize(100, b'7');
                            let plain = Window::default().field::<false>(&buf, 0);
                            // SAFETY: the CPU has SSSE3 (asserted above)
                            let simd = unsafe { field_ssse3(&buf) };
                            let bits = |r: Option<(f64, usize)>| r.map(|(v, e)| (v.to_bits(), e));
                            let shown = String::from_utf8_lossy(&buf[..=len]).into_owned();
                            assert_eq!(bits(plain), bits(simd), "`{shown}`");
                            if let Some((v, end)) = plain {
                                assert_eq!(end, len, "`{shown}`");
                                let want: f64 = std::str::from_utf8(&buf[..len])
                                    .expect("digits")
                                    .parse()
                                    .expect("a number");
                                assert_eq!(v.to_bits(), want.to_bits(), "`{shown}`");
                                taken += 1;
                            }
                        }
                    }
                }
            }
        }
        // 2 signs × 120 shapes (1–8 digits either side, 15 at most) × 6 with a digit replaced
        // by '0' at each place or none
        assert!(taken > 2 * 120, "only {taken} fields took the fast path");
    }

    /// `len` pseudo-random bytes (xorshift, fixed seed): digits, and a newline where the state
    /// is a multiple of `newline_every` — the input of the line-scanning tests below.
    fn digits_and_newlines(len: usize, newline_every: u64) -> Vec<u8> {
        let mut seed = 0x2545_F491_4F6C_DD1Du64;
        (0..len)
            .map(|_| {
                seed ^= seed << 13;
                seed ^= seed >> 7;
                seed ^= seed << 17;
                if seed.is_multiple_of(newline_every) {
                    b'\n'
                } else {
                    b'0' + (seed % 10) as u8
                }
            })
            .collect()
    }

    #[test]
    fn lines_counted_as_a_byte_loop_counts_them() {
        // every length around the 16- and 64-byte blocks, newlines at every offset, with and
        // without a last newline: the vector counts against the plain loop
        let text = digits_and_newlines(600, 5);
        for start in 0..70 {
            for end in start..text.len().min(start + 300) {
                let part = &text[start..end];
                let plain = part.iter().filter(|&&b| b == b'\n').count()
                    + (!part.is_empty() && part[part.len() - 1] != b'\n') as usize;
                assert_eq!(count_lines(part), plain, "bytes {start}..{end}");
            }
        }
    }

    /// A body of two halves for the two-way parse, each `first` lines then `then` lines (long
    /// lines: values padded with 300 spaces); a blank line every 1,000 rows and CR LF on every
    /// third. Returns the CSV body and the three columns it holds.
    fn halves(long_first: bool) -> (String, [Vec<f64>; 3]) {
        let mut body = String::new();
        let mut want: [Vec<f64>; 3] = Default::default();
        let mut i = 0usize;
        for _half in 0..2 {
            for long in [long_first, !long_first] {
                let bytes = if long { 200 << 10 } else { 1200 << 10 };
                let until = body.len() + bytes;
                while body.len() < until {
                    let pad = if long { " ".repeat(300) } else { String::new() };
                    let end = if i.is_multiple_of(3) { "\r\n" } else { "\n" };
                    body.push_str(&format!("{pad}{i}.25,{pad}-{}.5,{}{end}", i % 89, i * 7));
                    if i % 1000 == 999 {
                        body.push_str(" \r\n");
                    }
                    want[0].push(i as f64 + 0.25);
                    want[1].push(-((i % 89) as f64 + 0.5));
                    want[2].push((i * 7) as f64);
                    i += 1;
                }
            }
        }
        (body, want)
    }

    /// The two-way parse sizes its columns from an estimate of the lines: where the first lines
    /// of each half are much longer than the rest the estimate is short — it says so and the
    /// reader counts the lines instead; where they are shorter the room is too large and the
    /// rows still meet without a gap. The same values either way.
    #[test]
    fn two_way_parse_checks_its_estimate_of_the_lines() {
        let names: Vec<String> = ["a", "b", "c"].map(String::from).to_vec();
        for long_first in [true, false] {
            let (body, want) = halves(long_first);
            assert!(body.len() > 1 << 20);
            let bounds = part_bounds(body.as_bytes(), 2);
            assert_eq!(bounds.len(), 3);
            let parts = [
                &body.as_bytes()[bounds[0]..bounds[1]],
                &body.as_bytes()[bounds[1]..bounds[2]],
            ];
            let rows = want[0].len();
            let estimate_short = [0, 1].iter().any(|&k| {
                let part = std::str::from_utf8(parts[k]).expect("utf-8");
                let lines = part.lines().filter(|l| !l.trim().is_empty()).count();
                room_for_lines(parts[k]) < lines
            });
            assert_eq!(estimate_short, long_first, "long lines first: {long_first}");
            match parse_two_way(parts, &names, false) {
                None => assert!(long_first, "short lines first should fit the estimate"),
                Some(columns) => {
                    assert!(!long_first, "long lines first should overflow the estimate");
                    for (c, w) in columns.iter().zip(&want) {
                        assert_eq!(&**c, &w[..]);
                    }
                }
            }
            // and the reader (two-way or counted, as the machine's cores decide)
            let rec = Recording::parse(format!("a,b,c\n{body}").as_bytes()).expect("parse");
            assert_eq!(rec.rows(), rows);
            for (c, w) in want.iter().enumerate() {
                assert_eq!(
                    rec.column_at(c),
                    &w[..],
                    "column {c}, long first {long_first}"
                );
            }
        }
    }

    /// A bad value met by the two-way parse (in either half, backward or forward) is reported
    /// as the counted parse reports it: the first in file order, with its line.
    #[test]
    fn two_way_parse_reports_the_first_bad_value_with_its_line() {
        let names: Vec<String> = ["a", "b", "c"].map(String::from).to_vec();
        let (body, _) = halves(false);
        let lines: Vec<&str> = body.split_inclusive('\n').collect();
        let n = lines.len();
        for bad in [[n / 4, n - 3], [n * 3 / 4, n - 2], [2, n / 2 + 5]] {
            let mut text = String::from("a,b,c\n");
            for (k, l) in lines.iter().enumerate() {
                if bad.contains(&k) {
                    text.push_str("1,x2,3\n");
                } else {
                    text.push_str(l);
                }
            }
            let bounds = part_bounds(&text.as_bytes()[6..], 2);
            let body = &text.as_bytes()[6..];
            let parts = [&body[bounds[0]..bounds[1]], &body[bounds[1]..bounds[2]]];
            assert!(parse_two_way(parts, &names, false).is_none());
            let err = Recording::parse(text.as_bytes()).unwrap_err();
            // lines are 1-based and the header is line 1
            let line = bad[0] + 2;
            assert!(
                matches!(&err, RecordingError::NotNumeric { line: l, column: 2, found, .. } if *l == line && found == "x2"),
                "bad lines {bad:?}: {err}"
            );
        }
    }

    #[test]
    fn line_starts_found_backward_as_a_byte_loop_finds_them() {
        let text = digits_and_newlines(400, 23);
        for end in 0..=text.len() {
            let plain = text[..end]
                .iter()
                .rposition(|&b| b == b'\n')
                .map_or(0, |p| p + 1);
            assert_eq!(line_start(&text, end), plain, "end {end}");
        }
    }

    #[test]
    fn a_large_file_with_blank_lines_reads_into_one_block() {
        // > 1 MB (the parallel path) and enough values for the one block of columns; blank
        // and CR LF lines leave gaps in every thread's range that must close up
        let rows = 120_000usize;
        let mut text = String::from("a,b,c\n");
        for i in 0..rows {
            if i % 1000 == 7 {
                text.push_str("\n \r\n");
            }
            let end = if i % 3 == 0 { "\r\n" } else { "\n" };
            text.push_str(&format!("{i}.5,-{}.25,{}{end}", i % 97, i * 3));
        }
        assert!(text.len() > 1 << 20);
        let rec = Recording::parse(text.as_bytes()).expect("parse");
        assert_eq!(rec.rows(), rows);
        assert!(matches!(rec.columns[0], Column::InBlock { .. }));
        for i in (0..rows).step_by(997).chain([0, rows - 1]) {
            assert_eq!(rec.column_at(0)[i], i as f64 + 0.5, "a at {i}");
            assert_eq!(rec.column_at(1)[i], -((i % 97) as f64 + 0.25), "b at {i}");
            assert_eq!(rec.column_at(2)[i], (i * 3) as f64, "c at {i}");
        }
        // a clone shares the block and compares equal to the same columns in vectors
        let own = Recording::from_columns(
            rec.names()
                .iter()
                .enumerate()
                .map(|(j, n)| (n.clone(), rec.column_at(j).to_vec()))
                .collect(),
        )
        .expect("columns");
        assert_eq!(rec.clone(), own);
        // read from a file: mapped, its pages mapped in and dropped by the parser's threads
        let path = std::env::temp_dir().join(format!("nanocal-block-{}.csv", std::process::id()));
        std::fs::write(&path, &text).expect("write the file");
        let read = Recording::read_path(&path);
        std::fs::remove_file(&path).ok();
        assert_eq!(read.expect("read the file"), own);
    }

    /// A large file mostly of the common form (the fast path of whole rows, [`whole_rows`],
    /// forward and backward), interrupted now and then by what it leaves to the general path:
    /// blank lines, spaces, exponents, long mantissas, CR LF. Every value as the standard
    /// library reads it, from memory and from a file; a bad value in either half is reported
    /// with its line.
    #[test]
    fn a_large_file_mostly_of_the_common_form_reads_as_std_reads_it() {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let ncol = 6;
        let mut text = String::from("a,b,c,d,e,f\n");
        let mut want: Vec<Vec<f64>> = vec![Vec::new(); ncol];
        let mut line_of_row = Vec::new();
        let mut line = 1;
        let mut interrupted = 0;
        while text.len() < 4 << 20 {
            let r = next();
            if r % 4999 == 0 {
                text.push_str(if r % 2 == 0 { "\n" } else { " \r\n" });
                line += 1;
                continue;
            }
            let fields: Vec<String> = (0..ncol)
                .map(|c| {
                    let f = next();
                    let value = format!("{}.{:06}", f % 100_000, (f >> 20) % 1_000_000);
                    let value = if f >> 61 == 0 {
                        format!("-{value}")
                    } else {
                        value
                    };
                    let kind = (r >> (8 * c)) % 20_000;
                    interrupted += (kind < 4) as usize;
                    match kind {
                        0 => format!(" {value}"),
                        1 => format!("{value}e-3"),
                        2 => format!("{}.{}", f % 1_000_000_000, 7),
                        3 => "17".to_string(),
                        _ => value,
                    }
                })
                .collect();
            for (c, f) in fields.iter().enumerate() {
                want[c].push(f.trim().parse::<f64>().expect("a number"));
            }
            text.push_str(&fields.join(","));
            text.push_str(if r % 11 == 0 { "\r\n" } else { "\n" });
            line += 1;
            line_of_row.push(line);
        }
        // enough of the general path's rows among them (the file is the same every run)
        assert!(interrupted >= 20, "{interrupted} fields of other forms");
        let path = std::env::temp_dir().join(format!("nanocal-common-{}.csv", std::process::id()));
        std::fs::write(&path, &text).expect("write the file");
        let read = Recording::read_path(&path);
        std::fs::remove_file(&path).ok();
        let rec = Recording::parse(text.as_bytes()).expect("parse");
        assert_eq!(read.expect("read the file"), rec);
        assert!(matches!(rec.columns[0], Column::InBlock { .. }));
        assert_eq!(rec.rows(), want[0].len());
        for (c, w) in want.iter().enumerate() {
            for (i, (g, w)) in rec.column_at(c).iter().zip(w).enumerate() {
                assert_eq!(g.to_bits(), w.to_bits(), "row {i} column {c}: {w}");
            }
        }
        // the two-way parse itself (what a two-core machine takes): its first half from the
        // last row down, in batches
        let body = &text.as_bytes()[text.find('\n').expect("a header") + 1..];
        let bounds = part_bounds(body, 2);
        let parts = [&body[bounds[0]..bounds[1]], &body[bounds[1]..bounds[2]]];
        let names: Vec<String> = rec.names().to_vec();
        let two_way = parse_two_way(parts, &names, false).expect("the two-way parse");
        for (c, w) in want.iter().enumerate() {
            assert_eq!(two_way[c].len(), w.len());
            for (i, (g, w)) in two_way[c].iter().zip(w).enumerate() {
                assert_eq!(g.to_bits(), w.to_bits(), "two-way: row {i} column {c}: {w}");
            }
        }
        // a bad value in the first half, then in the second: its line, its column
        let rows = want[0].len();
        for row in [rows / 3, rows * 2 / 3] {
            let lines: Vec<&str> = text.split_inclusive('\n').collect();
            let at = line_of_row[row];
            let mut bad = String::new();
            for (k, l) in lines.iter().enumerate() {
                if k + 1 == at {
                    let mut fields: Vec<&str> = l.trim_end().split(',').collect();
                    fields[4] = "1.2.3";
                    bad.push_str(&fields.join(","));
                    bad.push('\n');
                } else {
                    bad.push_str(l);
                }
            }
            let err = Recording::parse(bad.as_bytes()).unwrap_err();
            assert!(
                matches!(&err, RecordingError::NotNumeric { line: l, column: 5, found, .. } if *l == at && found == "1.2.3"),
                "row {row} (line {at}): {err}"
            );
        }
    }

    #[test]
    fn malformed_numbers_and_empty_fields_are_refused() {
        for bad in ["abc", "1.2.3", "1e"] {
            let csv = format!("x\n{bad}\n");
            let err = Recording::parse(csv.as_bytes()).unwrap_err();
            assert!(
                matches!(
                    err,
                    RecordingError::NotNumeric {
                        line: 2,
                        column: 1,
                        ..
                    }
                ),
                "{bad}: {err}"
            );
        }
        let err = Recording::parse(b"x,y\n1,\n").unwrap_err();
        assert!(err.to_string().contains("line 2"), "{err}");
    }
}
