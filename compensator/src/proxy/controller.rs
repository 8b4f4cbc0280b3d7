//! What the proxy reads from the controller, and when it asks.
//!
//! Before the first corrected move of a host session the proxy asks, in one burst, for the
//! controller's identification (`*IDN?`: the line its markers are recognised by, see `queue`),
//! GCS syntax version (`CSV?`), axis identifiers (`SAI?`), and the position unit and travel
//! limits of the model axes (`PUN?`, `TMN?`, `TMX?`). Each fact is asked once and kept until
//! something the proxy forwards may change it (`PUN` the units, `RBT` all but the identity)
//! or the model's axes change. What the proxy reads from the controller is the controller's:
//! a new host session keeps it.
//!
//! The `maybe` queries (a controller may not know `CSV?`, `PUN?`, `TMN?`, `TMX?`) carry a
//! marker: a fact the controller leaves unanswered is *known* to be unanswered. A fact whose
//! query was lost because the controller stopped answering altogether is asked again.

use super::queue::{Entry, Expect, Info};
use super::{GcsErrorCode, Output, ProxyState, MAX_CONTROLLER_AXES};
use crate::gcs::{self, AxisId, LineBuf, MAP_AXES};
use nanocal_interface::status::StageCheck;
use nanocal_model::provenance::{serial_of_idn, StageSerial};

/// Longest identification line (`*IDN?`, LF excluded) the proxy keeps as its marker's reply.
/// PI's are about 80 bytes ("(c)2015 Physik Instrumente (PI) GmbH & Co. KG, E-727, …").
pub(crate) const IDN_LEN: usize = 160;

/// Margin (µm) inside the controller's travel within which a command needs no exact check.
const FAST_MARGIN_UM: f32 = 1e-3;

/// The marker: the proxy's own `*IDN?`.
pub(crate) const MARKER: &[u8] = b"*IDN?\n";

/// One thing the proxy reads from the controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Fact<T> {
    /// Not asked (or to be asked again).
    Unknown,
    /// Asked; the answer is on its way.
    Asked,
    /// Answered.
    Known(T),
    /// The controller left the query unanswered (its marker came back alone): it does not
    /// know the command.
    Unanswered,
}

impl<T: Copy> Fact<T> {
    pub(crate) fn known(&self) -> Option<T> {
        match self {
            Fact::Known(t) => Some(*t),
            _ => None,
        }
    }
    /// Asked, answered or not: nothing more to ask.
    pub(crate) fn settled(&self) -> bool {
        matches!(self, Fact::Known(_) | Fact::Unanswered)
    }
}

/// The controller's GCS syntax version.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Version {
    /// GCS 2.0.
    Gcs2,
    /// `CSV?` unanswered: an older GCS 2 controller, which leaves the host's `CSV?`
    /// unanswered too.
    Gcs2NoCsv,
    /// GCS 3.0 (`CSV?` > 2).
    Gcs3,
}

/// The controller's axis identifiers (`SAI?`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Axes {
    pub ids: [Option<AxisId>; MAX_CONTROLLER_AXES],
    pub k: usize,
    /// More axes than the proxy keeps: an identifier not among `ids` may still be one.
    pub truncated: bool,
}

impl Axes {
    /// `Ok(k)` when `id` is the controller's `k`-th axis, `Err(true)` when it is certainly not
    /// one of them, `Err(false)` when the list is incomplete.
    pub(crate) fn find(&self, id: &[u8]) -> Result<usize, bool> {
        self.ids[..self.k]
            .iter()
            .position(|a| a.is_some_and(|a| gcs::same_axis(a.as_bytes(), id)))
            .ok_or(!self.truncated)
    }
}

/// What the proxy has read from the controller.
#[derive(Debug, Clone)]
pub(crate) struct ControllerInfo {
    /// The identification line, when `idn` is known.
    pub idn_line: LineBuf<IDN_LEN>,
    /// `*IDN?`; `Unanswered` also when its reply is no usable marker (several lines, too long).
    pub idn: Fact<()>,
    /// The stage serial in the identification line, when `idn` is known and the line has one
    /// (`nanocal_model::provenance::serial_of_idn`).
    pub serial: Option<StageSerial>,
    pub version: Fact<Version>,
    pub axes: Fact<Axes>,
    /// Bit a: model axis a is in µm (`PUN?` of the model axes, read for `ProxyState::facts_n`
    /// axes).
    pub units: Fact<u8>,
    /// `TMN?`, `TMX?` of the model axes read (the values in `lo`, `hi`).
    pub tmn: Fact<()>,
    pub tmx: Fact<()>,
    /// The controller's travel per model axis, micros (`i64::MIN`, `i64::MAX` where it did not
    /// tell).
    pub lo: [i64; MAP_AXES],
    pub hi: [i64; MAP_AXES],
    /// The controller's travel per model axis as f32 bounds a little inside it (µm; ±∞ where
    /// not told): a command between them needs no exact check (`moves`).
    pub fast_lo: [f32; MAP_AXES],
    pub fast_hi: [f32; MAP_AXES],
    /// The facts allow corrected moves of this many model axes (0: not checked since they
    /// last changed): the move path's one compare.
    pub ready_n: u8,
}

impl ControllerInfo {
    pub(crate) const fn new() -> Self {
        Self {
            idn_line: LineBuf::new(),
            idn: Fact::Unknown,
            serial: None,
            version: Fact::Unknown,
            axes: Fact::Unknown,
            units: Fact::Unknown,
            tmn: Fact::Unknown,
            tmx: Fact::Unknown,
            lo: [i64::MIN; MAP_AXES],
            hi: [i64::MAX; MAP_AXES],
            fast_lo: [f32::NEG_INFINITY; MAP_AXES],
            fast_hi: [f32::INFINITY; MAP_AXES],
            ready_n: 0,
        }
    }

    /// The controller's identification line, when known (what a marker's reply is).
    pub(crate) fn marker_reply(&self) -> Option<&[u8]> {
        (self.idn == Fact::Known(())).then(|| self.idn_line.as_bytes())
    }

    /// GCS 3.0 announced.
    pub(crate) fn gcs3(&self) -> bool {
        self.version == Fact::Known(Version::Gcs3)
    }

    /// After `RBT`: the controller starts afresh; its identity stays.
    pub(crate) fn rebooted(&mut self) {
        let idn = (self.idn, self.idn_line.clone(), self.serial);
        *self = Self::new();
        (self.idn, self.idn_line, self.serial) = idn;
    }

    /// The facts about the model axes (the model's axes or their names changed).
    pub(crate) fn forget_model_axes(&mut self) {
        self.units = Fact::Unknown;
        self.tmn = Fact::Unknown;
        self.tmx = Fact::Unknown;
        self.lo = [i64::MIN; MAP_AXES];
        self.hi = [i64::MAX; MAP_AXES];
        self.fast_lo = [f32::NEG_INFINITY; MAP_AXES];
        self.fast_hi = [f32::INFINITY; MAP_AXES];
        self.ready_n = 0;
    }

    /// A fact changed: readiness is checked again.
    pub(crate) fn changed(&mut self) {
        self.ready_n = 0;
    }

    /// The controller stopped answering: facts asked and not answered are asked again later.
    pub(crate) fn lost_answers(&mut self) {
        fn again<T>(f: &mut Fact<T>) {
            if matches!(f, Fact::Asked) {
                *f = Fact::Unknown;
            }
        }
        again(&mut self.idn);
        again(&mut self.version);
        again(&mut self.axes);
        again(&mut self.units);
        again(&mut self.tmn);
        again(&mut self.tmx);
        self.ready_n = 0;
    }
}

/// How sure the proxy is that the controller answers a query.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Certainty {
    /// Always answered.
    Certain,
    /// Maybe not: a marker follows it.
    Maybe,
    /// Names an axis the controller does not have: the controller would not answer (and set
    /// error 15); the proxy answers nothing either and keeps the error.
    InvalidAxis,
}

/// Why the controller's facts do not allow a corrected move.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum NotReady {
    /// Something is still to be read: ask (or wait for the answer).
    Learn,
    /// Refused with this GCS code.
    Refuse(GcsErrorCode),
}

impl ProxyState {
    /// Send a query of the proxy's own (with the first `axes` model axis identifiers); a
    /// `maybe` query is followed by its marker. False when the queue has no room.
    pub(super) fn ask(
        &mut self,
        info: Info,
        word: &[u8],
        axes: usize,
        maybe: bool,
        out: &mut Output,
    ) -> bool {
        if self.queue.room() < 2 {
            return false;
        }
        if maybe && !self.ensure_idn(out) {
            return false;
        }
        let _ = out.to_stage.extend(word);
        for a in 0..axes {
            let _ = out.to_stage.push(b' ');
            let _ = out.to_stage.extend(self.map.id(a).unwrap_or(b"?"));
        }
        let _ = out.to_stage.push(b'\n');
        self.expect(Entry::new(Expect::Internal(info), maybe, false));
        if maybe {
            self.send_marker(out);
        }
        true
    }

    /// The controller's identification is known or asked (a marker's reply can be recognised
    /// by the time it arrives: replies come in order). False when it cannot be (the queue is
    /// full, or the controller's identification is no usable marker).
    pub(super) fn ensure_idn(&mut self, out: &mut Output) -> bool {
        match self.ctrl.idn {
            Fact::Known(()) | Fact::Asked => true,
            Fact::Unanswered => false,
            Fact::Unknown => {
                if self.queue.room() < 3 {
                    return false;
                }
                let _ = out.to_stage.extend(MARKER);
                self.expect(Entry::new(Expect::Internal(Info::Idn), false, false));
                self.ctrl.idn = Fact::Asked;
                true
            }
        }
    }

    /// Send a marker (its reply is the controller's identification line).
    pub(super) fn send_marker(&mut self, out: &mut Output) {
        let _ = out.to_stage.extend(MARKER);
        self.expect(Entry::new(Expect::Marker, false, false));
    }

    /// Whether the controller's facts allow a corrected move of `n` model axes.
    #[inline(always)]
    pub(super) fn controller_ready(&mut self, n: usize) -> Result<(), NotReady> {
        if usize::from(self.ctrl.ready_n) == n {
            return Ok(());
        }
        let r = self.check_controller(n);
        if r.is_ok() {
            self.ctrl.ready_n = n as u8;
        }
        r
    }

    /// [`Self::controller_ready`] in full (the facts changed since the last move).
    #[cold]
    #[inline(never)]
    fn check_controller(&self, n: usize) -> Result<(), NotReady> {
        let ctrl = &self.ctrl;
        if ctrl.idn == Fact::Unanswered {
            return Err(NotReady::Refuse(GcsErrorCode::NoAnswer));
        }
        // the provenance check, as soon as the identification is read (before it is, the
        // move waits for it below: no move is corrected on an unchecked stage)
        if self.stage_check() == StageCheck::Mismatch {
            return Err(NotReady::Refuse(GcsErrorCode::StageMismatch));
        }
        if ctrl.gcs3() {
            return Err(NotReady::Refuse(GcsErrorCode::Gcs3));
        }
        let settled = self.facts_n == n
            && ctrl.idn.settled()
            && ctrl.version.settled()
            && ctrl.axes.settled()
            && ctrl.units.settled()
            && ctrl.tmn.settled()
            && ctrl.tmx.settled();
        if !settled {
            return Err(NotReady::Learn);
        }
        if let Fact::Known(axes) = ctrl.axes {
            if (0..n).any(|a| axes.find(self.map.id(a).unwrap_or(b"")) == Err(true)) {
                return Err(NotReady::Refuse(GcsErrorCode::NotAnAxis));
            }
        }
        match ctrl.units {
            Fact::Known(u) if u == (1u8 << n) - 1 => Ok(()),
            _ => Err(NotReady::Refuse(GcsErrorCode::UnitMismatch)),
        }
    }

    /// The provenance check: the controller's serial (its `*IDN?`) against the one the model
    /// in service was fitted on ([`ProxyState::set_stage`]). A model without a serial checks
    /// nothing; an identification without a serial field is another stage (nothing says it is
    /// the model's).
    pub fn stage_check(&self) -> StageCheck {
        let Some(model) = self.stage.serial else {
            return StageCheck::Unchecked;
        };
        match self.ctrl.idn {
            Fact::Unanswered => StageCheck::Unanswered,
            Fact::Known(()) if self.ctrl.serial == Some(model) => StageCheck::Match,
            Fact::Known(()) if self.stage.allow_other => StageCheck::MismatchAllowed,
            Fact::Known(()) => StageCheck::Mismatch,
            Fact::Unknown | Fact::Asked => StageCheck::NotRead,
        }
    }

    /// The stage serial in the controller's identification (`None`: not read yet, or the line
    /// has none).
    pub fn controller_serial(&self) -> Option<StageSerial> {
        self.ctrl.idn.known().and(self.ctrl.serial)
    }

    /// Ask whatever the controller has not told yet for `n` model axes. False when the queue
    /// has no room.
    pub(super) fn learn(&mut self, n: usize, out: &mut Output) -> bool {
        if self.facts_n != n {
            // read for other model axes
            self.ctrl.forget_model_axes();
            self.facts_n = n;
        }
        self.ctrl.changed();
        let mut ok = self.ensure_idn(out);
        // a fact is marked asked only when its query went out: one the full queue kept back
        // stays unknown and is asked at the next held line — marked asked without its query,
        // nothing would ever answer it and every held line would wait for it for ever
        // (the `gcs_proxy` fuzz target's `learn-with-a-full-queue` input: the proxy stopped
        // taking the host's bytes)
        if self.ctrl.version == Fact::Unknown {
            ok &= self.ask_fact(Info::Version, b"CSV?", 0, true, out, |c| &mut c.version);
        }
        if self.ctrl.axes == Fact::Unknown {
            ok &= self.ask_fact(Info::Axes, b"SAI?", 0, false, out, |c| &mut c.axes);
        }
        if self.ctrl.units == Fact::Unknown {
            ok &= self.ask_fact(Info::Units, b"PUN?", n, true, out, |c| &mut c.units);
        }
        if self.ctrl.tmn == Fact::Unknown {
            ok &= self.ask_fact(Info::TravelMin, b"TMN?", n, true, out, |c| &mut c.tmn);
        }
        if self.ctrl.tmx == Fact::Unknown {
            ok &= self.ask_fact(Info::TravelMax, b"TMX?", n, true, out, |c| &mut c.tmx);
        }
        ok
    }

    /// [`ask`](Self::ask) for one fact, marked asked only if its query went out.
    fn ask_fact<T>(
        &mut self,
        info: Info,
        word: &[u8],
        axes: usize,
        maybe: bool,
        out: &mut Output,
        fact: fn(&mut ControllerInfo) -> &mut Fact<T>,
    ) -> bool {
        let sent = self.ask(info, word, axes, maybe, out);
        if sent {
            *fact(&mut self.ctrl) = Fact::Asked;
        }
        sent
    }

    /// True while a fact a held move needs is on its way.
    pub(super) fn learning(&self) -> bool {
        let c = &self.ctrl;
        [
            c.idn == Fact::Asked,
            c.version == Fact::Asked,
            c.axes == Fact::Asked,
            c.units == Fact::Asked,
            c.tmn == Fact::Asked,
            c.tmx == Fact::Asked,
        ]
        .iter()
        .any(|&b| b)
    }

    /// How sure the proxy is that a query (`key`, the command word's) with arguments `args`
    /// and address prefix `prefix` is answered.
    pub(super) fn certainty(
        &self,
        s: &gcs::Split<'_>,
        action: crate::command::Action,
    ) -> Certainty {
        use crate::command::Action as A;
        if !s.prefix.is_empty() {
            // addressed, perhaps to another controller of a chain
            return Certainty::Maybe;
        }
        let answered = match action {
            A::ErrorQuery | A::IdnQuery => return Certainty::Certain,
            A::AxesQuery => {
                return if s.args.is_empty() || s.args.eq_ignore_ascii_case(b"ALL") {
                    Certainty::Certain
                } else {
                    Certainty::Maybe
                }
            }
            A::PositionQuery { .. } => true,
            A::VersionQuery => matches!(
                self.ctrl.version.known(),
                Some(Version::Gcs2 | Version::Gcs3)
            ),
            A::UnitQuery => self.ctrl.units.known().is_some(),
            A::TravelQuery => self.ctrl.tmn.known().is_some() && self.ctrl.tmx.known().is_some(),
            _ => false,
        };
        if !answered {
            return Certainty::Maybe;
        }
        let Fact::Known(axes) = self.ctrl.axes else {
            return Certainty::Maybe;
        };
        // every argument one of the controller's axes, none twice
        let mut seen = 0u32;
        for id in gcs::tokens(s.args) {
            match axes.find(id) {
                Ok(k) if seen >> k & 1 == 0 => seen |= 1 << k,
                Err(true) => return Certainty::InvalidAxis,
                _ => return Certainty::Maybe,
            }
        }
        Certainty::Certain
    }

    /// A complete reply to `info` (its lines in `lines`, each with its LF) from the controller.
    pub(super) fn read_fact(&mut self, info: Info, lines: &[u8], n_lines: usize) {
        let n = self.facts_n;
        self.ctrl.changed();
        match info {
            Info::Idn => {
                let line = lines.strip_suffix(b"\n").unwrap_or(lines);
                let mut l = LineBuf::new();
                if n_lines == 1 && !line.is_empty() && l.extend(line).is_ok() {
                    self.ctrl.idn_line = l;
                    self.ctrl.idn = Fact::Known(());
                    self.ctrl.serial = serial_of_idn(line);
                } else {
                    // several lines, or too long: no usable marker
                    self.ctrl.idn = Fact::Unanswered;
                }
            }
            Info::Version => {
                let v = lines_of(lines)
                    .next()
                    .map(trim)
                    .and_then(|t| gcs::parse_f64(t).ok());
                self.ctrl.version = Fact::Known(match v {
                    // PIPython's own test (`isgcs30_by_qcsv`): a version above 2.0 is GCS 3.0
                    Some(v) if v > 2.0 => Version::Gcs3,
                    _ => Version::Gcs2,
                });
            }
            Info::Axes => {
                let mut axes = Axes {
                    ids: [None; MAX_CONTROLLER_AXES],
                    k: 0,
                    truncated: false,
                };
                for l in lines_of(lines) {
                    let t = trim(l);
                    if t.is_empty() {
                        continue;
                    }
                    match AxisId::new(t) {
                        Some(id) if axes.k < MAX_CONTROLLER_AXES => {
                            axes.ids[axes.k] = Some(id);
                            axes.k += 1;
                        }
                        _ => axes.truncated = true,
                    }
                }
                self.ctrl.axes = Fact::Known(axes);
            }
            Info::Units => {
                let mut mask = 0u8;
                for (a, v) in self.axis_values(lines, n).iter().enumerate() {
                    if v.is_some_and(super::replies::is_micrometre) {
                        mask |= 1 << a;
                    }
                }
                self.ctrl.units = Fact::Known(mask);
            }
            Info::TravelMin | Info::TravelMax => {
                let min = info == Info::TravelMin;
                let values = self.axis_values(lines, n);
                for (a, v) in values.iter().enumerate() {
                    let m = v.and_then(|v| gcs::parse_micros(v).ok());
                    let ctrl = &mut self.ctrl;
                    if min {
                        ctrl.lo[a] = m.unwrap_or(i64::MIN);
                        ctrl.fast_lo[a] = m.map_or(f32::NEG_INFINITY, |m| {
                            gcs::micros_to_f32(m) + FAST_MARGIN_UM
                        });
                    } else {
                        ctrl.hi[a] = m.unwrap_or(i64::MAX);
                        ctrl.fast_hi[a] =
                            m.map_or(f32::INFINITY, |m| gcs::micros_to_f32(m) - FAST_MARGIN_UM);
                    }
                }
                if min {
                    self.ctrl.tmn = Fact::Known(());
                } else {
                    self.ctrl.tmx = Fact::Known(());
                }
            }
            Info::Targets(_)
            | Info::Error
            | Info::FollowHeld(_)
            | Info::FollowCheck(_)
            | Info::FollowDone(_) => {}
        }
    }

    /// The controller left the proxy's query for `info` unanswered (its marker came back
    /// alone).
    pub(super) fn fact_unanswered(&mut self, info: Info) {
        self.ctrl.changed();
        match info {
            Info::Idn => self.ctrl.idn = Fact::Unanswered,
            // an older GCS 2 controller without CSV?
            Info::Version => self.ctrl.version = Fact::Known(Version::Gcs2NoCsv),
            Info::Axes => self.ctrl.axes = Fact::Unanswered,
            Info::Units => self.ctrl.units = Fact::Unanswered,
            Info::TravelMin => self.ctrl.tmn = Fact::Unanswered,
            Info::TravelMax => self.ctrl.tmx = Fact::Unanswered,
            Info::Targets(_)
            | Info::Error
            | Info::FollowHeld(_)
            | Info::FollowCheck(_)
            | Info::FollowDone(_) => {}
        }
    }

    /// The values of the first `n` model axes in `axis=value` lines.
    fn axis_values<'a>(&self, lines: &'a [u8], n: usize) -> [Option<&'a [u8]>; MAP_AXES] {
        let mut v = [None; MAP_AXES];
        for l in lines_of(lines) {
            if let Some(av) = gcs::parse_axis_value(l) {
                if let Some(a) = self.map.index(av.axis).filter(|&a| a < n) {
                    v[a] = Some(av.value);
                }
            }
        }
        v
    }

    /// The controller's travel of model axis `a` (micros), where it told it.
    pub(super) fn controller_travel(&self, a: usize) -> (Option<i64>, Option<i64>) {
        let (lo, hi) = (self.ctrl.lo[a], self.ctrl.hi[a]);
        (
            (lo != i64::MIN).then_some(lo),
            (hi != i64::MAX).then_some(hi),
        )
    }
}

/// The lines of LF-terminated text (LF removed).
pub(crate) fn lines_of(text: &[u8]) -> impl Iterator<Item = &[u8]> {
    text.split(|&b| b == b'\n').filter(|l| !l.is_empty())
}

/// The error code in the controller's reply to `ERR?` (the last token of its first line, after
/// an address prefix if any), when it is an integer.
pub(crate) fn error_code(reply: &[u8]) -> Option<i32> {
    lines_of(reply)
        .next()
        .and_then(|l| gcs::tokens(l).last())
        .and_then(|t| gcs::parse_micros(t).ok())
        .filter(|v| v % gcs::MICROS_PER_UNIT == 0)
        .and_then(|v| i32::try_from(v / gcs::MICROS_PER_UNIT).ok())
}

/// A reply token without the spaces and CR around it.
pub(crate) fn trim(s: &[u8]) -> &[u8] {
    let s = s.strip_suffix(b"\r").unwrap_or(s);
    let start = s.iter().position(|&b| b != b' ').unwrap_or(s.len());
    let end = s.iter().rposition(|&b| b != b' ').map_or(start, |e| e + 1);
    &s[start..end.max(start)]
}

#[cfg(test)]
mod tests {
    use super::super::queue::{Entry, Expect, Info};
    use super::super::{Output, Proxy};
    use super::Fact;

    /// Whatever room the queue has left, a fact is marked asked only with its query on the
    /// way: a fact marked asked with no query for it is never answered, and a held line waits
    /// for it for ever (the `gcs_proxy` fuzz target's `learn-with-a-full-queue` input).
    #[test]
    fn a_fact_is_asked_only_with_its_query_in_the_queue() {
        for room in 0..16 {
            let mut p = Proxy::default();
            let st = &mut p.st;
            while st.queue.room() > room {
                st.expect(Entry::new(Expect::Marker, false, false));
            }
            let mut out = Output::new();
            let all_sent = st.learn(1, &mut out);
            let c = &st.ctrl;
            let asked = [
                c.idn == Fact::Asked,
                c.version == Fact::Asked,
                c.axes == Fact::Asked,
                c.units == Fact::Asked,
                c.tmn == Fact::Asked,
                c.tmx == Fact::Asked,
            ];
            let mut queued = [false; 6];
            while let Some(en) = st.queue.pop() {
                if let Expect::Internal(info) = en.e {
                    let i = match info {
                        Info::Idn => 0,
                        Info::Version => 1,
                        Info::Axes => 2,
                        Info::Units => 3,
                        Info::TravelMin => 4,
                        Info::TravelMax => 5,
                        _ => continue,
                    };
                    queued[i] = true;
                }
            }
            assert_eq!(asked, queued, "room {room}");
            assert_eq!(all_sent, queued.iter().all(|&q| q), "room {room}");
        }
    }
}
