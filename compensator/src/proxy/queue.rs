//! What the controller's replies answer: a first-in first-out record of the queries in flight.
//!
//! GCS is request/response and a controller answers its queries in the order it received them,
//! so several queries may be in flight (`POS? 1\nPOS? 2\n` sent back to back, or PIPython's
//! `ERR?` appended to a command) and each reply belongs to the oldest query not yet answered.
//! The proxy's own answers (`ERR?` with an error of its own) are queued among them, so the host
//! reads every answer in the order it asked.
//!
//! A controller answers nothing to a query it rejects — an unknown command, an axis it does not
//! have, a bad argument: it only sets its error code (PI's controllers as PIPython and the
//! simulators of PI's own and Odemis's drivers know them). The proxy knows which queries are
//! always answered (`ERR?`, `*IDN?`, `SAI?`, and the position queries whose axes are all
//! among the controller's, checked against `SAI?`). Every other query may go unanswered: it is
//! marked `maybe` and followed by a *marker*, the proxy's own `*IDN?`, whose reply the proxy
//! knows byte for byte (read once per controller). The first reply after a `maybe` query is
//! either its reply or the marker's — the proxy tells them apart by content, so pairing never
//! depends on time.

use crate::gcs::LineBuf;
use nanocal_interface::GcsErrorCode;

/// Host queries the proxy keeps track of at once.
pub const MAX_IN_FLIGHT: usize = 16;

/// Entries of the queue: every host query may bring its marker, and the proxy's own queries
/// (the controller's identity, version, axes, units, travel, the targets a move needs, each
/// with its marker) need room of their own.
pub(crate) const QUEUE_LEN: usize = 2 * MAX_IN_FLIGHT + 16;

/// What the proxy reads from a reply for itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Info {
    /// `*IDN?`: the controller's identification line, the reply a marker is recognised by.
    Idn,
    /// `CSV?`: the GCS syntax version.
    Version,
    /// `PUN?` of the model axes: the position unit of each.
    Units,
    /// `SAI?`: the controller's axis identifiers.
    Axes,
    /// `TMN?` of the model axes: the lower travel limits.
    TravelMin,
    /// `TMX?` of the model axes: the upper travel limits.
    TravelMax,
    /// `MOV?` of the model axes for the line held under this generation: the bases of its move.
    Targets(u8),
    /// The host's `ERR?` answered by the controller: a non-zero code may mean the controller
    /// refused a move the proxy forwarded, so the proxy forgets its targets.
    Error,
    /// The proxy's `MOV?` of the model axes before it re-issues a held target (`follow`),
    /// asked after this many host moves (mod 256): does the controller hold the commands the
    /// proxy recorded for the target?
    FollowHeld(u8),
    /// The proxy's `ERR?` before it re-issues a held target (`follow`), asked after this many
    /// host moves (mod 256): one read after a later move is not for the target it checked.
    FollowCheck(u8),
    /// The proxy's `ERR?` after a re-issued `MOV` (`follow`), sent after this many host moves
    /// (mod 256).
    FollowDone(u8),
}

/// The proxy's own answer to the host's `ERR?`: the code, after the address prefix a
/// daisy-chained controller would answer with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Answer {
    /// The reply prefix (sender and target swapped), `len` bytes of it.
    prefix: [u8; 11],
    len: u8,
    /// The code; `None`: the controller's error that the proxy's own `ERR?` in flight before
    /// it reads (`follow`), 0 when it reads none — filled in when the answer goes out.
    code: Option<i32>,
}

impl Answer {
    /// The answer to an `ERR?` sent with address prefix `prefix` (see
    /// [`crate::gcs::reply_prefix`]; a prefix longer than any address pair is dropped).
    pub(crate) fn new(prefix: &[u8], code: GcsErrorCode) -> Self {
        Self::with_code(prefix, Some(code.code()))
    }
    /// The answer to an `ERR?` with the code `code` (`None`: filled in later, see
    /// [`Answer::resolve`]).
    pub(crate) fn with_code(prefix: &[u8], code: Option<i32>) -> Self {
        let mut p = LineBuf::<16>::new();
        crate::gcs::reply_prefix(prefix, &mut p);
        let mut a = Self {
            prefix: [0; 11],
            len: 0,
            code,
        };
        if let Some(d) = a.prefix.get_mut(..p.len()) {
            d.copy_from_slice(p.as_bytes());
            a.len = p.len() as u8;
        }
        a
    }
    /// The answer with its code filled in by `f` when it has none yet.
    pub(crate) fn resolve(mut self, f: impl FnOnce() -> i32) -> Self {
        if self.code.is_none() {
            self.code = Some(f());
        }
        self
    }
    /// The answer's bytes, LF included.
    pub(crate) fn write(&self, out: &mut LineBuf<{ super::HOST_OUT }>) -> bool {
        out.room() >= 24
            && out.extend(&self.prefix[..usize::from(self.len)]).is_ok()
            && out.push_int(i64::from(self.code.unwrap_or(0))).is_ok()
            && out.push(b'\n').is_ok()
    }
}

/// What one reply is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Expect {
    /// Relayed as is.
    Relay,
    /// `POS?`, `#3` (`target == false`) or `MOV?` (`true`): positions mapped back.
    Map {
        /// `MOV?`: a value equal to the command sent maps back to its target exactly.
        target: bool,
    },
    /// The host's query whose reply the proxy reads too (relayed as is).
    Snoop(Info),
    /// The proxy's own query: the reply is read and not relayed.
    Internal(Info),
    /// The proxy's own answer to the host's `ERR?`.
    Answer(Answer),
    /// The proxy's marker (`*IDN?`): its reply must be the controller's identification line;
    /// it is dropped.
    Marker,
    /// A reply nobody waits for any more (the query of a host session that ended, a re-seed a
    /// stop cancelled): read and dropped.
    Discard,
    /// Bytes no query asked for (none was in flight, or the rest of a reply the pairing was
    /// lost in): read and dropped; never waited for.
    Unsolicited,
}

/// One query in flight.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Entry {
    /// What its reply is for.
    pub e: Expect,
    /// The controller may leave it unanswered: a marker follows it.
    pub maybe: bool,
    /// The host asked it (counted against [`MAX_IN_FLIGHT`]).
    pub host: bool,
    /// Its reply is the controller's identification line (an `*IDN?` without address
    /// prefix, the host's or the proxy's own): an identification line arriving for it is its
    /// own reply, never a marker's. Kept when the entry is retagged (a host session that
    /// ended turns its `*IDN?` into [`Expect::Discard`], whose reply is still that line).
    pub idn: bool,
}

impl Entry {
    /// An entry; `idn` is set for the proxy's and the host's `*IDN?` ([`Info::Idn`]).
    pub(crate) const fn new(e: Expect, maybe: bool, host: bool) -> Self {
        let idn = matches!(e, Expect::Snoop(Info::Idn) | Expect::Internal(Info::Idn));
        Self {
            e,
            maybe,
            host,
            idn,
        }
    }
    /// The same entry, its reply the controller's identification line (see [`Entry::idn`]).
    pub(crate) const fn with_idn(mut self, idn: bool) -> Self {
        self.idn = idn;
        self
    }
}

/// A fixed-capacity ring of [`Entry`].
#[derive(Clone)]
pub(crate) struct Queue {
    items: [Entry; QUEUE_LEN],
    head: usize,
    len: usize,
    host: usize,
}

impl Queue {
    pub(crate) const fn new() -> Self {
        const NONE: Entry = Entry::new(Expect::Discard, false, false);
        Self {
            items: [NONE; QUEUE_LEN],
            head: 0,
            len: 0,
            host: 0,
        }
    }
    pub(crate) fn len(&self) -> usize {
        self.len
    }
    pub(crate) fn is_empty(&self) -> bool {
        self.len == 0
    }
    /// Room for `n` more entries.
    pub(crate) fn room(&self) -> usize {
        QUEUE_LEN - self.len
    }
    /// Host queries in flight.
    pub(crate) fn host_queries(&self) -> usize {
        self.host
    }
    /// Append; `false` (nothing stored) when full.
    pub(crate) fn push(&mut self, en: Entry) -> bool {
        if self.len == QUEUE_LEN {
            return false;
        }
        self.items[(self.head + self.len) % QUEUE_LEN] = en;
        self.len += 1;
        self.host += usize::from(en.host);
        true
    }
    /// Put an entry back at the front (its reply is still to come).
    pub(crate) fn push_front(&mut self, en: Entry) -> bool {
        if self.len == QUEUE_LEN {
            return false;
        }
        self.head = (self.head + QUEUE_LEN - 1) % QUEUE_LEN;
        self.items[self.head] = en;
        self.len += 1;
        self.host += usize::from(en.host);
        true
    }
    pub(crate) fn front(&self) -> Option<&Entry> {
        (self.len > 0).then(|| &self.items[self.head])
    }
    pub(crate) fn pop(&mut self) -> Option<Entry> {
        if self.len == 0 {
            return None;
        }
        let en = self.items[self.head];
        self.head = (self.head + 1) % QUEUE_LEN;
        self.len -= 1;
        self.host -= usize::from(en.host);
        Some(en)
    }
    /// Change every entry in place (`f` returns the new expectation), keeping the order: the
    /// replies still come, only what they are for changes.
    pub(crate) fn retag(&mut self, mut f: impl FnMut(&Entry) -> Expect) {
        for k in 0..self.len {
            let en = &mut self.items[(self.head + k) % QUEUE_LEN];
            en.e = f(en);
            if en.host && matches!(en.e, Expect::Discard) {
                en.host = false;
                self.host -= 1;
            }
        }
    }
    /// Remove the proxy's own answers (nobody will read them any more).
    pub(crate) fn drop_answers(&mut self) {
        let n = self.len;
        for _ in 0..n {
            if let Some(en) = self.pop() {
                if !matches!(en.e, Expect::Answer(_)) {
                    self.push(en);
                }
            }
        }
    }

    /// The entries, oldest first.
    pub(crate) fn iter(&self) -> impl Iterator<Item = &Entry> {
        (0..self.len).map(|k| &self.items[(self.head + k) % QUEUE_LEN])
    }
}

impl core::fmt::Debug for Queue {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_list().entries(self.iter()).finish()
    }
}
