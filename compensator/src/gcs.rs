//! PI General Command Set (GCS) line handling: line assembly, command splitting, axis/value
//! parsing and fixed-point number formatting — the pure part of the inline compensator's proxy.
//!
//! GCS is ASCII: a command line ends with LF; a multi-line reply ends every non-final line with
//! a space before the LF. Single-character commands (`#5` = 0x05, `#7`, `#24` = 0x18, …) are one
//! byte with no LF. An optional address prefix (`<target> [<sender>] `) may precede a command
//! (daisy chains); it is preserved untouched.
//!
//! Numbers are parsed without `core`'s float parser (smaller code on the microcontroller):
//! up to 18 significant digits, an optional fraction and exponent.

use core::fmt;

/// Longest line the proxy handles (bytes, LF excluded). Longer lines are an error.
pub const MAX_LINE: usize = 200;

/// Longest GCS axis identifier (bytes).
pub const MAX_AXIS_ID: usize = 8;

/// Errors of GCS parsing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum GcsError {
    /// A line was longer than [`MAX_LINE`] bytes.
    LineTooLong,
    /// A number could not be parsed (bad characters, too many digits, or out of range).
    BadNumber,
    /// An axis/value list had an axis without a value.
    MissingValue,
    /// The same axis appeared twice in one command.
    DuplicateAxis,
    /// More axis/value pairs than the proxy can hold.
    TooManyAxes,
    /// The output buffer was too small for the rewritten line.
    OutputFull,
}

impl fmt::Display for GcsError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            GcsError::LineTooLong => "GCS line longer than the proxy's line buffer",
            GcsError::BadNumber => "expected a decimal number",
            GcsError::MissingValue => "expected a value after the axis identifier",
            GcsError::DuplicateAxis => "axis given twice in one command",
            GcsError::TooManyAxes => "too many axis/value pairs in one command",
            GcsError::OutputFull => "rewritten line does not fit the output buffer",
        })
    }
}

/// A fixed-capacity byte buffer for one line (or one multi-line reply).
#[derive(Clone)]
pub struct LineBuf<const N: usize> {
    buf: [u8; N],
    len: usize,
}

impl<const N: usize> Default for LineBuf<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> LineBuf<N> {
    /// An empty buffer.
    pub const fn new() -> Self {
        Self {
            buf: [0; N],
            len: 0,
        }
    }
    /// Remove all bytes.
    pub fn clear(&mut self) {
        self.len = 0;
    }
    /// The bytes written so far.
    pub fn as_bytes(&self) -> &[u8] {
        &self.buf[..self.len]
    }
    /// Number of bytes written.
    pub fn len(&self) -> usize {
        self.len
    }
    /// True when nothing was written.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
    /// Append bytes, or fail without writing anything when they do not fit.
    pub fn extend(&mut self, bytes: &[u8]) -> Result<(), GcsError> {
        let end = self.len + bytes.len();
        if end > N {
            return Err(GcsError::OutputFull);
        }
        self.buf[self.len..end].copy_from_slice(bytes);
        self.len = end;
        Ok(())
    }
    /// Append one byte.
    pub fn push(&mut self, b: u8) -> Result<(), GcsError> {
        self.extend(&[b])
    }
    /// Append an integer in decimal.
    pub fn push_int(&mut self, v: i64) -> Result<(), GcsError> {
        let mut tmp = [0u8; 20];
        let mut i = tmp.len();
        let neg = v < 0;
        let mut u = v.unsigned_abs();
        loop {
            i -= 1;
            tmp[i] = b'0' + (u % 10) as u8;
            u /= 10;
            if u == 0 {
                break;
            }
        }
        if neg {
            self.push(b'-')?;
        }
        self.extend(&tmp[i..])
    }
    /// Append `v` with exactly `decimals` (≤ 9) digits after the point, rounded half away from
    /// zero. One f64 multiply and one 64-bit division; the digits are produced in 32 bits.
    pub fn push_fixed(&mut self, v: f64, decimals: u32) -> Result<(), GcsError> {
        let decimals = decimals.min(9) as usize;
        let scaled = v * POW10[decimals];
        if scaled.is_nan() || scaled.abs() >= 9.0e18 {
            return Err(GcsError::BadNumber);
        }
        let r = if scaled >= 0.0 {
            (scaled + 0.5) as i64
        } else {
            (scaled - 0.5) as i64
        };
        let u = r.unsigned_abs();
        let p = POW10_U32[decimals];
        let (int, frac) = if u < u64::from(u32::MAX) {
            let u = u as u32;
            (u64::from(u / p), u % p)
        } else {
            let int = u / u64::from(p);
            (int, (u - int * u64::from(p)) as u32)
        };
        if r < 0 {
            self.push(b'-')?;
        }
        if let Ok(i) = u32::try_from(int) {
            self.push_u32(i)?;
        } else {
            self.push_int(int as i64)?;
        }
        if decimals > 0 {
            self.push(b'.')?;
            let mut digits = [b'0'; 9];
            let mut f = frac;
            for d in digits[..decimals].iter_mut().rev() {
                *d = b'0' + (f % 10) as u8;
                f /= 10;
            }
            self.extend(&digits[..decimals])?;
        }
        Ok(())
    }

    /// Append an unsigned 32-bit integer in decimal (hardware division only).
    pub fn push_u32(&mut self, mut u: u32) -> Result<(), GcsError> {
        let mut tmp = [0u8; 10];
        let mut i = tmp.len();
        loop {
            i -= 1;
            tmp[i] = b'0' + (u % 10) as u8;
            u /= 10;
            if u == 0 {
                break;
            }
        }
        self.extend(&tmp[i..])
    }
}

const POW10_U32: [u32; 10] = [
    1,
    10,
    100,
    1_000,
    10_000,
    100_000,
    1_000_000,
    10_000_000,
    100_000_000,
    1_000_000_000,
];

/// 10^-k for k = 0..=22 (multiplying is far cheaper than dividing in soft-float f64; the error
/// stays within two ulps).
const NEG_POW10: [f64; 23] = [
    1e0, 1e-1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12, 1e-13, 1e-14,
    1e-15, 1e-16, 1e-17, 1e-18, 1e-19, 1e-20, 1e-21, 1e-22,
];

const POW10: [f64; 23] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
];

/// Parse a decimal number (`-12.5`, `+3`, `.25`, `1e-3`, `4.5E2`). The whole slice must be the
/// number. Accurate to one rounding for up to 15 significant digits and exponents within ±22.
pub fn parse_f64(s: &[u8]) -> Result<f64, GcsError> {
    let mut i = 0;
    let mut neg = false;
    if let Some(&c) = s.first() {
        if c == b'-' || c == b'+' {
            neg = c == b'-';
            i = 1;
        }
    }
    let mut mant: u64 = 0;
    let mut digits = 0u32;
    let mut exp10: i32 = 0;
    let mut any = false;
    while i < s.len() && s[i].is_ascii_digit() {
        push_digit(&mut mant, &mut digits, &mut exp10, s[i] - b'0', false)?;
        any = true;
        i += 1;
    }
    if i < s.len() && s[i] == b'.' {
        i += 1;
        while i < s.len() && s[i].is_ascii_digit() {
            push_digit(&mut mant, &mut digits, &mut exp10, s[i] - b'0', true)?;
            any = true;
            i += 1;
        }
    }
    if !any {
        return Err(GcsError::BadNumber);
    }
    if i < s.len() && (s[i] == b'e' || s[i] == b'E') {
        i += 1;
        let mut eneg = false;
        if i < s.len() && (s[i] == b'-' || s[i] == b'+') {
            eneg = s[i] == b'-';
            i += 1;
        }
        let mut e: i32 = 0;
        let mut edigits = 0;
        while i < s.len() && s[i].is_ascii_digit() {
            e = e * 10 + i32::from(s[i] - b'0');
            edigits += 1;
            if edigits > 3 {
                return Err(GcsError::BadNumber);
            }
            i += 1;
        }
        if edigits == 0 {
            return Err(GcsError::BadNumber);
        }
        exp10 += if eneg { -e } else { e };
    }
    if i != s.len() {
        return Err(GcsError::BadNumber);
    }
    // mantissas below 2^32 convert with the cheaper 32-bit routine
    let m = match u32::try_from(mant) {
        Ok(m32) => f64::from(m32),
        Err(_) => mant as f64,
    };
    let v = if mant == 0 {
        0.0
    } else if exp10 >= 0 {
        if exp10 as usize >= POW10.len() {
            return Err(GcsError::BadNumber);
        }
        m * POW10[exp10 as usize]
    } else {
        let e = (-exp10) as usize;
        if e >= POW10.len() {
            // Tiny: two steps keep it finite; precision is irrelevant at this scale.
            let e2 = e - (POW10.len() - 1);
            if e2 >= POW10.len() {
                0.0
            } else {
                m / POW10[POW10.len() - 1] / POW10[e2]
            }
        } else {
            m * NEG_POW10[e]
        }
    };
    Ok(if neg { -v } else { v })
}

fn push_digit(
    mant: &mut u64,
    digits: &mut u32,
    exp10: &mut i32,
    d: u8,
    fraction: bool,
) -> Result<(), GcsError> {
    if *digits == 0 && d == 0 {
        // leading zeros carry no precision
        if fraction {
            *exp10 -= 1;
        }
        return Ok(());
    }
    if *digits >= 18 {
        // further digits are below f64 precision: drop them (but keep the magnitude)
        if !fraction {
            *exp10 += 1;
        }
        return Ok(());
    }
    *mant = *mant * 10 + u64::from(d);
    *digits += 1;
    if fraction {
        *exp10 -= 1;
    }
    Ok(())
}

/// What one byte fed to a [`LineAssembler`] completed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Feed {
    /// Nothing complete yet.
    Pending,
    /// A line is complete: read it with [`LineAssembler::line`] (LF excluded), then `clear`.
    Line,
    /// A single-character command (a control byte at the start of a line).
    Single(u8),
    /// The line overflowed [`MAX_LINE`]; it is discarded up to its LF.
    Overflow,
}

/// Assembles bytes into LF-terminated lines; recognises GCS single-character commands.
pub struct LineAssembler {
    buf: LineBuf<MAX_LINE>,
    overflow: bool,
    complete: bool,
    singles: bool,
}

impl Default for LineAssembler {
    fn default() -> Self {
        Self::new()
    }
}

impl LineAssembler {
    /// An empty assembler for the host stream (recognises single-character commands).
    pub const fn new() -> Self {
        Self {
            buf: LineBuf::new(),
            overflow: false,
            complete: false,
            singles: true,
        }
    }

    /// An empty assembler for the controller's replies (control bytes are data).
    pub const fn replies() -> Self {
        Self {
            buf: LineBuf::new(),
            overflow: false,
            complete: false,
            singles: false,
        }
    }

    /// Feed one byte.
    pub fn feed(&mut self, b: u8) -> Feed {
        if self.complete {
            self.buf.clear();
            self.complete = false;
        }
        if b == b'\n' {
            if self.overflow {
                self.overflow = false;
                self.buf.clear();
                return Feed::Overflow;
            }
            self.complete = true;
            return Feed::Line;
        }
        if self.singles && self.buf.is_empty() && !self.overflow && is_single_char_command(b) {
            return Feed::Single(b);
        }
        if self.overflow {
            return Feed::Pending;
        }
        if self.buf.push(b).is_err() {
            self.overflow = true;
        }
        Feed::Pending
    }

    /// The completed line (valid after [`Feed::Line`], until the next `feed`).
    pub fn line(&self) -> &[u8] {
        self.buf.as_bytes()
    }
}

/// True for the control bytes that are GCS single-character commands (#4..#9, #24, #27).
pub fn is_single_char_command(b: u8) -> bool {
    matches!(b, 0x04..=0x09 | 0x18 | 0x1B)
}

/// True when a single-character command is answered by the controller (#24 = stop is not).
pub fn single_char_has_reply(b: u8) -> bool {
    b != 0x18
}

/// A command line split into address prefix, command word and arguments.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Split<'a> {
    /// Address prefix including its trailing space (`"1 0 "`), or empty.
    pub prefix: &'a [u8],
    /// The command word (`MOV`, `POS?`, `*IDN?`).
    pub command: &'a [u8],
    /// Everything after the command word, leading spaces removed.
    pub args: &'a [u8],
}

/// Split a line (LF already removed, a trailing CR is ignored).
pub fn split(line: &[u8]) -> Split<'_> {
    let line = trim_end(line);
    let mut start = skip_spaces(line, 0);
    let prefix_start = start;
    // up to two all-digit tokens form an address prefix, when a command word follows
    let mut prefix_end = prefix_start;
    for _ in 0..2 {
        let tok_end = token_end(line, start);
        let tok = &line[start..tok_end];
        let next = skip_spaces(line, tok_end);
        if !tok.is_empty() && tok.iter().all(u8::is_ascii_digit) && next < line.len() {
            prefix_end = next;
            start = next;
        } else {
            break;
        }
    }
    // a prefix is only a prefix when what follows starts with a letter or '*'
    if prefix_end > prefix_start {
        let c = line[prefix_end];
        if !(c.is_ascii_alphabetic() || c == b'*') {
            prefix_end = prefix_start;
            start = prefix_start;
        }
    }
    let cmd_end = token_end(line, start);
    Split {
        prefix: &line[prefix_start..prefix_end],
        command: &line[start..cmd_end],
        args: &line[skip_spaces(line, cmd_end)..],
    }
}

fn trim_end(mut s: &[u8]) -> &[u8] {
    while let Some((&last, rest)) = s.split_last() {
        if last == b'\r' || last == b' ' || last == b'\t' {
            s = rest;
        } else {
            break;
        }
    }
    s
}

fn skip_spaces(s: &[u8], mut i: usize) -> usize {
    while i < s.len() && (s[i] == b' ' || s[i] == b'\t') {
        i += 1;
    }
    i
}

fn token_end(s: &[u8], mut i: usize) -> usize {
    while i < s.len() && s[i] != b' ' && s[i] != b'\t' {
        i += 1;
    }
    i
}

/// Iterator over whitespace-separated tokens.
pub fn tokens(s: &[u8]) -> impl Iterator<Item = &[u8]> {
    s.split(|&c| c == b' ' || c == b'\t')
        .filter(|t| !t.is_empty())
}

/// A GCS axis identifier (up to [`MAX_AXIS_ID`] bytes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AxisId {
    bytes: [u8; MAX_AXIS_ID],
    len: u8,
}

impl AxisId {
    /// An identifier from bytes; `None` when empty or too long.
    pub fn new(id: &[u8]) -> Option<Self> {
        if id.is_empty() || id.len() > MAX_AXIS_ID {
            return None;
        }
        let mut bytes = [0; MAX_AXIS_ID];
        bytes[..id.len()].copy_from_slice(id);
        Some(Self {
            bytes,
            len: id.len() as u8,
        })
    }
    /// The identifier's bytes.
    pub fn as_bytes(&self) -> &[u8] {
        &self.bytes[..self.len as usize]
    }
}

/// Which GCS axis identifiers are the model's axes 0, 1, 2.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AxisMap {
    ids: [AxisId; crate::gcs::MAP_AXES],
    n: usize,
}

/// Axes an [`AxisMap`] can hold (the model's maximum).
pub const MAP_AXES: usize = 3;

impl Default for AxisMap {
    /// `1`, `2`, `3` — PI's default axis names on most controllers.
    fn default() -> Self {
        let mut ids = [AxisId {
            bytes: [0; MAX_AXIS_ID],
            len: 0,
        }; MAP_AXES];
        for (i, id) in ids.iter_mut().enumerate() {
            *id = AxisId {
                bytes: [b'1' + i as u8, 0, 0, 0, 0, 0, 0, 0],
                len: 1,
            };
        }
        Self { ids, n: MAP_AXES }
    }
}

impl AxisMap {
    /// A map from explicit identifiers (model axis i ↔ `ids[i]`).
    pub fn new(ids: &[AxisId]) -> Self {
        let n = ids.len().min(MAP_AXES);
        let mut all = Self::default().ids;
        all[..n].copy_from_slice(&ids[..n]);
        Self { ids: all, n }
    }
    /// The model axis of a GCS identifier.
    pub fn index(&self, id: &[u8]) -> Option<usize> {
        self.ids[..self.n].iter().position(|a| a.as_bytes() == id)
    }
    /// The GCS identifier of a model axis.
    pub fn id(&self, axis: usize) -> Option<&[u8]> {
        self.ids[..self.n].get(axis).map(AxisId::as_bytes)
    }
}

/// Most axis/value pairs in one command the proxy handles.
pub const MAX_PAIRS: usize = 8;

/// Axis/value pairs of a `MOV`/`MVR`-style command, in the order given.
#[derive(Debug, Clone, Copy)]
pub struct Pairs<'a> {
    /// The pairs: identifier bytes and value.
    pub items: [(&'a [u8], f64); MAX_PAIRS],
    /// How many of `items` are used.
    pub n: usize,
}

impl<'a> Pairs<'a> {
    /// The used pairs.
    pub fn as_slice(&self) -> &[(&'a [u8], f64)] {
        &self.items[..self.n]
    }
}

/// Parse `"1 10.5 2 -3"` into axis/value pairs.
pub fn parse_pairs(args: &[u8]) -> Result<Pairs<'_>, GcsError> {
    let mut p = Pairs {
        items: [(&[][..], 0.0); MAX_PAIRS],
        n: 0,
    };
    let mut it = tokens(args);
    while let Some(axis) = it.next() {
        let v = it.next().ok_or(GcsError::MissingValue)?;
        let v = parse_f64(v)?;
        if p.as_slice().iter().any(|(a, _)| *a == axis) {
            return Err(GcsError::DuplicateAxis);
        }
        if p.n == MAX_PAIRS {
            return Err(GcsError::TooManyAxes);
        }
        p.items[p.n] = (axis, v);
        p.n += 1;
    }
    Ok(p)
}

/// One reply line `"[prefix ]axis=value[ ]"`, split.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisValue<'a> {
    /// Address prefix of the reply (`"0 1 "`), or empty.
    pub prefix: &'a [u8],
    /// The axis identifier.
    pub axis: &'a [u8],
    /// The value.
    pub value: f64,
    /// True when the line ended with a space (more lines of this reply follow).
    pub continued: bool,
}

/// Parse a reply line of the form `axis=value` (LF removed); `None` when it has another form.
pub fn parse_axis_value(line: &[u8]) -> Option<AxisValue<'_>> {
    let line = line.strip_suffix(b"\r").unwrap_or(line);
    let continued = line.last() == Some(&b' ');
    let body = trim_end(line);
    let eq = body.iter().position(|&c| c == b'=')?;
    let left = &body[..eq];
    let value = parse_f64(&body[eq + 1..]).ok()?;
    // the axis is the last token before '='; anything before it is the address prefix
    let axis_start = left
        .iter()
        .rposition(|&c| c == b' ')
        .map(|i| i + 1)
        .unwrap_or(0);
    let axis = &left[axis_start..];
    if axis.is_empty() {
        return None;
    }
    Some(AxisValue {
        prefix: &left[..axis_start],
        axis,
        value,
        continued,
    })
}

/// True when a reply line is not the last of its reply (ends with a space before LF).
pub fn is_continued(line: &[u8]) -> bool {
    let line = line.strip_suffix(b"\r").unwrap_or(line);
    line.last() == Some(&b' ')
}
