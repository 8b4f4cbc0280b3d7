//! Controller → host: replies matched to their queries, relayed byte for byte or mapped back.
//!
//! A reply ends at an LF that does not follow a space. Replies relayed as they are (most of
//! them, whatever their length: `HLP?`, `HPA?`, data recorder dumps) are copied through as the
//! bytes arrive. Position replies are collected line by line, each line parsed once as it
//! arrives; when the reply is complete every value of a model axis is replaced by its
//! calibrated counterpart. A position reply too long to hold (many axes) is mapped in chunks,
//! and a line too long to be a position passes unmapped. The proxy's own queries are read and
//! not relayed.

use super::queue::{Expect, Info};
use super::{Corrector, Output, ProxyState, Targets, Units, Version, MAX_CONTROLLER_AXES};
use crate::gcs::{self, AxisId, LineBuf, MAP_AXES};

/// Longest reply line the proxy parses.
const RX_LINE: usize = 256;
/// Reply lines held for mapping at once (bytes).
const RX_CHUNK: usize = 384;
/// Reply lines held for mapping at once (lines): bounds the growth when values are rewritten.
const RX_CHUNK_LINES: usize = 24;
/// Room a mapped chunk may need in the host buffer: every held line may grow by the longest
/// value the proxy prints (21 characters, for a value sent as one digit).
const HOST_CHUNK_ROOM: usize = RX_CHUNK + RX_CHUNK_LINES * 22;
/// Room needed before a position reply's line end is taken: a full chunk, then the last line.
const LF_ROOM: usize = HOST_CHUNK_ROOM + RX_LINE + 32;
const _: () = assert!(LF_ROOM <= super::HOST_OUT);

/// Where a held reply line is, and what it says.
#[derive(Debug, Clone, Copy)]
struct LineInfo {
    /// Start and length in [`ReplyRx::lines`] (LF excluded).
    start: u16,
    len: u16,
    /// Length of `prefix axis=` when the line is a position of a model axis, else 0.
    value_at: u16,
    /// The model axis.
    axis: u8,
    /// The line ends with a space: more lines of the reply follow.
    continued: bool,
}

const NO_LINE: LineInfo = LineInfo {
    start: 0,
    len: 0,
    value_at: 0,
    axis: 0,
    continued: false,
};

/// The reply being received.
pub(crate) struct ReplyRx {
    kind: Option<Expect>,
    /// Last byte of the reply so far (LF at its start).
    prev: u8,
    /// The line being received (parsed kinds).
    line: LineBuf<RX_LINE>,
    /// The current line is longer than [`RX_LINE`]: passed through unmapped.
    line_over: bool,
    /// Complete lines held (parsed kinds), each followed by LF.
    lines: LineBuf<RX_CHUNK>,
    infos: [LineInfo; RX_CHUNK_LINES],
    n_lines: usize,
    /// Values of model axes seen so far in this reply (micros), bit a of `seen` set.
    values: [i64; MAP_AXES],
    seen: u8,
    /// Model axes seen in the lines held now.
    here: u8,
}

impl ReplyRx {
    pub(crate) const fn new() -> Self {
        Self {
            kind: None,
            prev: b'\n',
            line: LineBuf::new(),
            line_over: false,
            lines: LineBuf::new(),
            infos: [NO_LINE; RX_CHUNK_LINES],
            n_lines: 0,
            values: [0; MAP_AXES],
            seen: 0,
            here: 0,
        }
    }

    /// A reply is being received.
    pub(crate) fn active(&self) -> bool {
        self.kind.is_some()
    }

    /// The reply being received answers one of the proxy's own queries.
    pub(crate) fn internal(&self) -> bool {
        matches!(self.kind, Some(Expect::Internal(_)))
    }

    fn begin(&mut self, e: Expect) {
        self.kind = Some(e);
        self.prev = b'\n';
        self.line.clear();
        self.line_over = false;
        self.lines.clear();
        self.n_lines = 0;
        self.seen = 0;
        self.here = 0;
    }
}

impl ProxyState {
    pub(super) fn stage_bytes<C: Corrector>(
        &mut self,
        c: Option<&C>,
        input: &[u8],
        now_ms: u32,
        out: &mut Output,
    ) -> usize {
        out.clear();
        self.now_ms = now_ms;
        if !input.is_empty() {
            self.last_rx_ms = now_ms;
        }
        if !self.queue.is_empty() {
            self.emit_answers(out);
        }
        let mut i = 0;
        while i < input.len() {
            let kind = match self.rx.kind {
                Some(k) => k,
                None => {
                    let e = self.queue.pop().unwrap_or(Expect::Relay);
                    self.rx.begin(e);
                    e
                }
            };
            let rest = &input[i..];
            let lf = rest.iter().position(|&b| b == b'\n');
            if matches!(kind, Expect::Relay | Expect::Snoop(_)) {
                let room = out.to_host.room();
                if room == 0 {
                    break;
                }
                let n = lf.map_or(rest.len(), |p| p + 1).min(room);
                let chunk = &rest[..n];
                let _ = out.to_host.extend(chunk);
                i += n;
                if matches!(kind, Expect::Snoop(_)) {
                    self.collect(chunk);
                }
                let before_lf = if n >= 2 { chunk[n - 2] } else { self.rx.prev };
                self.rx.prev = chunk[n - 1];
                if chunk[n - 1] == b'\n' && before_lf != b' ' {
                    self.finish_reply(c, out);
                    if !out.to_stage.is_empty() {
                        return i;
                    }
                }
                continue;
            }
            // parsed kinds, a line at a time
            let is_map = matches!(kind, Expect::Map { .. });
            let Some(p) = lf else {
                // the line goes on in the next read
                self.take_partial(c, rest, is_map, out);
                i = input.len();
                continue;
            };
            if is_map && !self.rx.line_over && out.to_host.room() < LF_ROOM {
                break;
            }
            if !self.take_partial(c, &rest[..p], is_map, out) {
                break;
            }
            i += p + 1;
            let end = self.rx.prev != b' ';
            self.rx.prev = b'\n';
            if self.rx.line_over {
                let _ = out.to_host.push(b'\n');
                self.rx.line_over = false;
            } else {
                self.end_line(c, is_map, out);
            }
            if end {
                self.finish_reply(c, out);
                return i;
            }
        }
        i
    }

    /// Bytes of a parsed reply's line (no LF). `false` when `out` has no room for what a line
    /// too long to be a position forces out (the caller retries).
    fn take_partial<C: Corrector>(
        &mut self,
        c: Option<&C>,
        bytes: &[u8],
        is_map: bool,
        out: &mut Output,
    ) -> bool {
        if bytes.is_empty() {
            return true;
        }
        if self.rx.line_over {
            let n = bytes.len().min(out.to_host.room());
            let _ = out.to_host.extend(&bytes[..n]);
            self.rx.prev = bytes[n.max(1) - 1];
            return n == bytes.len();
        }
        if self.rx.line.extend(bytes).is_ok() {
            self.rx.prev = bytes[bytes.len() - 1];
            return true;
        }
        if !is_map {
            // the proxy's own query: the rest of an overlong line carries nothing it reads
            self.rx.prev = bytes[bytes.len() - 1];
            return true;
        }
        // too long for a position line: what came before goes out first, then this line raw
        if out.to_host.room() < LF_ROOM {
            return false;
        }
        self.map_chunk(c, out);
        let _ = out.to_host.extend(self.rx.line.as_bytes());
        self.rx.line.clear();
        self.rx.line_over = true;
        self.take_partial(c, bytes, is_map, out)
    }

    /// Feed a relayed byte run to the lines the proxy reads.
    fn collect(&mut self, chunk: &[u8]) {
        for &b in chunk {
            if b == b'\n' {
                let _ = self.rx.lines.extend(self.rx.line.as_bytes());
                let _ = self.rx.lines.push(b'\n');
                self.rx.line.clear();
            } else {
                let _ = self.rx.line.push(b);
            }
        }
    }

    /// A line of a parsed reply is complete (in `rx.line`): parsed once, held.
    fn end_line<C: Corrector>(&mut self, c: Option<&C>, is_map: bool, out: &mut Output) {
        let full =
            self.rx.lines.room() < self.rx.line.len() + 1 || self.rx.n_lines == RX_CHUNK_LINES;
        if full {
            if !is_map {
                // own query with a long reply: the rest is not needed
                self.rx.line.clear();
                return;
            }
            // the held lines go out before this one is held
            self.map_chunk(c, out);
        }
        let start = self.rx.lines.len();
        let line = self.rx.line.as_bytes();
        let mut info = LineInfo {
            start: start as u16,
            len: line.len() as u16,
            continued: line.last() == Some(&b' '),
            ..NO_LINE
        };
        if is_map {
            if let Some(av) = gcs::parse_axis_value(line) {
                let n = c.map_or(0, |c| c.axes()).min(MAP_AXES);
                if let Some(a) = self.map.index(av.axis).filter(|&a| a < n) {
                    if let Ok(v) = gcs::parse_micros(av.value) {
                        self.rx.values[a] = v;
                        self.rx.seen |= 1 << a;
                        self.rx.here |= 1 << a;
                        info.axis = a as u8;
                        info.value_at = (av.prefix.len() + av.axis.len() + 1) as u16;
                    }
                }
            }
        }
        let _ = self.rx.lines.extend(line);
        let _ = self.rx.lines.push(b'\n');
        self.rx.infos[self.rx.n_lines] = info;
        self.rx.n_lines += 1;
        self.rx.line.clear();
    }

    /// Map and send the lines held so far (`c` None: relayed as they are).
    fn map_chunk<C: Corrector>(&mut self, c: Option<&C>, out: &mut Output) {
        let target = matches!(self.rx.kind, Some(Expect::Map { target: true }));
        let x = match c {
            Some(c) if self.rx.here != 0 => {
                let x = self.map_values(c, target);
                if x.is_some() {
                    self.counters.mapped_replies = self.counters.mapped_replies.wrapping_add(1);
                } else {
                    self.counters.inverse_failures = self.counters.inverse_failures.wrapping_add(1);
                }
                x
            }
            _ => None,
        };
        let lines = self.rx.lines.as_bytes();
        let o = &mut out.to_host;
        for info in &self.rx.infos[..self.rx.n_lines] {
            let line = &lines[usize::from(info.start)..][..usize::from(info.len)];
            let xa = x.and_then(|x| x[usize::from(info.axis)]);
            match xa {
                Some(xa) if info.value_at > 0 => {
                    let _ = o.extend(&line[..usize::from(info.value_at)]);
                    let _ = o.push_micros(xa);
                    if info.continued {
                        let _ = o.push(b' ');
                    }
                }
                _ => {
                    let _ = o.extend(line);
                }
            }
            let _ = o.push(b'\n');
        }
        self.rx.lines.clear();
        self.rx.n_lines = 0;
        self.rx.here = 0;
    }

    /// The calibrated positions for the model-axis values seen in this reply: exactly the
    /// targets for a `MOV?` reply that reports what was sent, else through the inverse
    /// warm-started at the targets. `None` when the inverse fails.
    fn map_values<C: Corrector>(&mut self, c: &C, target: bool) -> Option<[Option<i64>; MAP_AXES]> {
        let n = c.axes().min(MAP_AXES);
        let t: &Targets = &self.targets;
        let seen = self.rx.seen;
        // MOV? reporting exactly what was sent: the targets themselves
        let exact =
            target && (0..n).all(|a| seen >> a & 1 == 0 || t.q(a) == Some(self.rx.values[a]));
        if exact {
            return Some([t.x(0), t.x(1), t.x(2)]);
        }
        let mut q = [0f32; MAP_AXES];
        for a in 0..n {
            let v = if seen >> a & 1 != 0 {
                Some(self.rx.values[a])
            } else {
                t.q(a)
            };
            q[a] = match v {
                Some(v) => gcs::micros_to_f32(v),
                // an axis neither reported nor commanded: assume the centre of its travel
                None => {
                    let (lo, hi) = c.travel_um(a);
                    0.5 * (lo + hi)
                }
            };
        }
        let all = (1u8 << n) - 1;
        let x0 = (t.known & all == all).then(|| {
            let mut x0 = [0f32; MAP_AXES];
            for a in 0..n {
                x0[a] = gcs::micros_to_f32(t.x[a]);
            }
            x0
        });
        let (_, delta) = c.inverse(&q, &self.dir, &self.hyst, x0.as_ref())?;
        // x = q − δ(x) in micros: exact reply, f32 δ (an f32 position would round by up to
        // 0.24 nm at 5 mm)
        let mut x = [None; MAP_AXES];
        for a in 0..n {
            let qa = if seen >> a & 1 != 0 {
                self.rx.values[a]
            } else {
                gcs::f32_to_micros(q[a])?
            };
            x[a] = Some(qa.saturating_sub(gcs::f32_to_micros(delta[a])?));
        }
        Some(x)
    }

    /// The reply is complete.
    fn finish_reply<C: Corrector>(&mut self, c: Option<&C>, out: &mut Output) {
        match self.rx.kind {
            Some(Expect::Map { .. }) => self.map_chunk(c, out),
            Some(Expect::Snoop(info) | Expect::Internal(info)) => self.read_info(c, info),
            _ => {}
        }
        self.rx.kind = None;
        if !self.queue.is_empty() {
            self.emit_answers(out);
        }
        self.try_release(c, out);
    }

    /// Read what the proxy wants to know from a complete reply (in `rx.lines`).
    fn read_info<C: Corrector>(&mut self, c: Option<&C>, info: Info) {
        let lines = self.rx.lines.clone();
        let lines = lines.as_bytes();
        match info {
            Info::Version => {
                let v = lines_of(lines)
                    .next()
                    .map(trim)
                    .and_then(|t| gcs::parse_f64(t).ok());
                match v {
                    // PIPython's own test (`isgcs30_by_qcsv`): a version above 2.0 is GCS 3.0
                    Some(v) if v > 2.0 => self.ctrl.version = Version::Gcs3,
                    Some(_) => self.ctrl.version = Version::Gcs2,
                    None => {
                        // not a version: the controller did not answer CSV? and this is the
                        // reply to the next query (the proxy's PUN?)
                        if self.queue.front() == Some(&Expect::Internal(Info::Units)) {
                            self.queue.pop();
                            self.ctrl.version = Version::Gcs2;
                            self.read_units(c, lines);
                        }
                    }
                }
            }
            Info::Units => self.read_units(c, lines),
            Info::Axes => {
                let mut ids = [None; MAX_CONTROLLER_AXES];
                let mut k = 0;
                for l in lines_of(lines) {
                    let t = trim(l);
                    if !t.is_empty() && k < MAX_CONTROLLER_AXES {
                        ids[k] = AxisId::new(t);
                        k += 1;
                    }
                }
                self.ctrl.axes = Some((ids, k));
            }
            Info::Targets => self.reseed(c, lines),
            Info::Error => {
                // (after an address prefix, if any)
                let code = lines_of(lines)
                    .next()
                    .and_then(|l| gcs::tokens(l).last())
                    .map(gcs::parse_micros);
                if !matches!(code, Some(Ok(0))) {
                    // the controller may have refused a move the proxy sent (servo off, not
                    // referenced, limits): the targets it holds are not the ones sent
                    self.forget(None);
                }
            }
        }
    }

    /// `PUN?` reply: every model axis must be in µm.
    fn read_units<C: Corrector>(&mut self, c: Option<&C>, lines: &[u8]) {
        let n = c.map_or(MAP_AXES, |c| c.axes()).min(MAP_AXES);
        let mut ok = [false; MAP_AXES];
        for l in lines_of(lines) {
            if let Some(av) = gcs::parse_axis_value(l) {
                if let Some(a) = self.map.index(av.axis).filter(|&a| a < n) {
                    ok[a] = is_micrometre(av.value);
                }
            }
        }
        self.ctrl.units = if ok[..n].iter().all(|&o| o) {
            Units::Micrometre(n)
        } else {
            Units::Mismatch
        };
    }

    /// `MOV?` reply to the proxy's own query: the targets the controller holds, mapped back
    /// (the whole vector: a coupled model needs every axis), for the axes whose targets the
    /// proxy forgot.
    fn reseed<C: Corrector>(&mut self, c: Option<&C>, lines: &[u8]) {
        let Some(c) = c else { return };
        let n = c.axes().min(MAP_AXES);
        let mut q: [Option<i64>; MAP_AXES] = [None; MAP_AXES];
        for l in lines_of(lines) {
            if let Some(av) = gcs::parse_axis_value(l) {
                if let Some(a) = self.map.index(av.axis).filter(|&a| a < n) {
                    q[a] = gcs::parse_micros(av.value).ok();
                }
            }
        }
        let mut qf = [0f32; MAP_AXES];
        for a in 0..n {
            match q[a].or(self.targets.q(a)) {
                Some(v) => {
                    q[a] = Some(v);
                    qf[a] = gcs::micros_to_f32(v);
                }
                None => return,
            }
        }
        let Some((_, delta)) = c.inverse(&qf, &self.dir, &self.hyst, None) else {
            self.counters.inverse_failures = self.counters.inverse_failures.wrapping_add(1);
            return;
        };
        // the axes whose targets were forgotten take the calibrated position of the
        // controller's targets (for the held line; kept if its move goes out); the others keep
        // the targets the host set
        for a in 0..n {
            if self.targets.known >> a & 1 != 0 {
                continue;
            }
            if let (Some(d), Some(qa)) = (gcs::f32_to_micros(delta[a]), q[a]) {
                self.reseed.set(a, qa.saturating_sub(d), qa);
            }
        }
    }

    /// The controller answers no more: give up the queries in flight.
    pub(super) fn give_up_replies<C: Corrector>(&mut self, c: Option<&C>, out: &mut Output) {
        match self.rx.kind {
            Some(Expect::Map { .. }) => self.map_chunk(c, out),
            Some(Expect::Internal(info)) => self.unanswered(info),
            _ => {}
        }
        if self.rx.kind.take().is_some() {
            self.counters.unanswered = self.counters.unanswered.wrapping_add(1);
        }
        while let Some(e) = self.queue.pop() {
            match e {
                Expect::Answer(a) => {
                    a.write(&mut out.to_host);
                }
                Expect::Internal(info) => {
                    self.unanswered(info);
                    self.counters.unanswered = self.counters.unanswered.wrapping_add(1);
                }
                _ => self.counters.unanswered = self.counters.unanswered.wrapping_add(1),
            }
        }
    }

    fn unanswered(&mut self, info: Info) {
        match info {
            // an older GCS 2 controller without CSV?
            Info::Version => self.ctrl.version = Version::Gcs2,
            Info::Units => self.ctrl.units = Units::Unanswered,
            Info::Axes | Info::Targets | Info::Error => {}
        }
    }
}

/// The lines of LF-terminated text (LF removed).
fn lines_of(text: &[u8]) -> impl Iterator<Item = &[u8]> {
    text.split(|&b| b == b'\n').filter(|l| !l.is_empty())
}

fn trim(s: &[u8]) -> &[u8] {
    let s = s.strip_suffix(b"\r").unwrap_or(s);
    let start = s.iter().position(|&b| b != b' ').unwrap_or(s.len());
    let end = s.iter().rposition(|&b| b != b' ').map_or(start, |e| e + 1);
    &s[start..end.max(start)]
}

/// True for the spellings of µm a controller may report (`PUN?`): `µm` (cp1252 `B5 6D`, or
/// UTF-8), `um`, `micron`, `micrometer`, `micrometre`, in any case.
pub(crate) fn is_micrometre(unit: &[u8]) -> bool {
    let u = trim(unit);
    let mut up = [0u8; 12];
    if u.len() > up.len() {
        return false;
    }
    for (d, s) in up.iter_mut().zip(u) {
        *d = s.to_ascii_uppercase();
    }
    matches!(
        &up[..u.len()],
        b"UM" | b"\xB5M" | b"\xC2\xB5M" | b"MICRON" | b"MICRONS" | b"MICROMETER" | b"MICROMETRE"
    )
}
