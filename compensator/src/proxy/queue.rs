//! What the controller's replies answer: a first-in first-out record of the queries in flight.
//!
//! GCS is request/response and a controller answers its queries in the order it received them,
//! so several queries may be in flight (`POS? 1\nPOS? 2\n` sent back to back, or PIPython's
//! `ERR?` appended to a command) and each reply belongs to the oldest query not yet answered.
//! The proxy's own answers (`ERR?` with an error of its own) are queued among them, so the host
//! reads every answer in the order it asked.

use crate::gcs::LineBuf;
use nanocal_interface::GcsErrorCode;

/// Queries the proxy keeps track of at once.
pub const MAX_IN_FLIGHT: usize = 16;

/// What the proxy reads from a reply for itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Info {
    /// `CSV?`: the GCS syntax version.
    Version,
    /// `PUN?`: the position unit of every model axis.
    Units,
    /// `SAI?`: the controller's axis identifiers.
    Axes,
    /// `MOV?` of the model axes: targets to re-seed from.
    Targets,
    /// The host's `ERR?` answered by the controller: a non-zero code may mean the controller
    /// refused a move the proxy forwarded, so the proxy forgets its targets.
    Error,
}

/// The proxy's own answer to the host's `ERR?`: the code, after the address prefix a
/// daisy-chained controller would answer with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Answer {
    /// The reply prefix (sender and target swapped), `len` bytes of it.
    prefix: [u8; 11],
    len: u8,
    code: GcsErrorCode,
}

impl Answer {
    /// The answer to an `ERR?` sent with address prefix `prefix` (see
    /// [`crate::gcs::reply_prefix`]; a prefix longer than any address pair is dropped).
    pub(crate) fn new(prefix: &[u8], code: GcsErrorCode) -> Self {
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
    /// The answer's bytes, LF included.
    pub(crate) fn write(&self, out: &mut LineBuf<{ super::HOST_OUT }>) -> bool {
        out.room() >= 24
            && out.extend(&self.prefix[..usize::from(self.len)]).is_ok()
            && out.push_int(i64::from(self.code.code())).is_ok()
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
}

/// A fixed-capacity ring of [`Expect`].
pub(crate) struct Queue {
    items: [Expect; MAX_IN_FLIGHT],
    head: usize,
    len: usize,
}

impl Queue {
    pub(crate) const fn new() -> Self {
        const RELAY: Expect = Expect::Relay;
        Self {
            items: [RELAY; MAX_IN_FLIGHT],
            head: 0,
            len: 0,
        }
    }
    pub(crate) fn len(&self) -> usize {
        self.len
    }
    pub(crate) fn is_empty(&self) -> bool {
        self.len == 0
    }
    pub(crate) fn is_full(&self) -> bool {
        self.len == MAX_IN_FLIGHT
    }
    /// Append; `false` (nothing stored) when full.
    pub(crate) fn push(&mut self, e: Expect) -> bool {
        if self.is_full() {
            return false;
        }
        self.items[(self.head + self.len) % MAX_IN_FLIGHT] = e;
        self.len += 1;
        true
    }
    pub(crate) fn front(&self) -> Option<&Expect> {
        (self.len > 0).then(|| &self.items[self.head])
    }
    pub(crate) fn pop(&mut self) -> Option<Expect> {
        if self.len == 0 {
            return None;
        }
        let e = self.items[self.head];
        self.head = (self.head + 1) % MAX_IN_FLIGHT;
        self.len -= 1;
        Some(e)
    }
    /// How many of the entries are the proxy's own queries for `info`.
    pub(crate) fn count_internal(&self, info: Info) -> usize {
        (0..self.len)
            .filter(|k| self.items[(self.head + k) % MAX_IN_FLIGHT] == Expect::Internal(info))
            .count()
    }
}
