//! What the stage link tells the proxy about itself: bytes from the controller were lost
//! ([`Proxy::stage_bytes_lost`]). Replies already on their way then belong to no query one can
//! name: pairing them with the next queries would hand the host (or the proxy's own `MOV?`
//! re-seed) someone else's answer. (The host's side, a session that ends, is
//! [`Proxy::new_session`].)
//!
//! The recovery is exact, not timed: the proxy gives up the replies due and sends a marker of
//! its own (`*IDN?`, whose reply it knows byte for byte); every byte before the marker's reply
//! is dropped, and the identification lines still due to the queries given up (markers, the
//! host's `*IDN?`) are counted off before one is taken for the marker's (`replies::resync`).
//! The count errs on the safe side: an identification line the loss damaged is not waited for
//! when it was the reply under way, and one damaged further on only makes the proxy wait for
//! an identification line that never comes — until the controller has been silent for
//! [`super::REPLY_TIMEOUT_MS`], when it resynchronises again with nothing given up still
//! coming. A reply is never paired with the wrong query. Host lines go on at once, after the
//! marker.
//!
//! Time is needed only where no marker can be recognised: before the controller's
//! identification line is known (it is being asked, or went unanswered). Then nothing the
//! controller sends can be told from what was due, and the proxy waits until the line has been
//! quiet for [`RESYNC_QUIET_MS`] (a controller answers within milliseconds: what was due has
//! come by then) before it pairs replies again.

use super::GcsErrorCode;
use super::{Corrector, Output, Proxy, ProxyState, Reseed};

/// Without a known identification line (no marker can be recognised), how long the
/// controller's line must stay silent after lost bytes before the proxy pairs replies with
/// queries again, ms: longer than the gap between the bytes of one reply, far shorter than
/// [`super::REPLY_TIMEOUT_MS`]. With one, the recovery is a marker's reply, not a time.
pub const RESYNC_QUIET_MS: u32 = 100;

impl Proxy {
    /// Bytes from the controller were lost (a UART overrun, a full receive buffer) at
    /// `now_ms`, after the bytes received before them were given to
    /// [`stage_bytes`](Self::stage_bytes). Which reply lost them cannot be told, and a lost LF
    /// joins two replies (a lost marker reply would pass unseen): every reply now due is
    /// suspect, and so is the pairing of the ones after. At the proxy's next call (any entry
    /// point; [`has_work`](Self::has_work) is true meanwhile) it gives up the replies that
    /// were due, resynchronises with a marker (see the module documentation), forgets the
    /// targets (a move that needs one asks `MOV?` afresh), runs a held line afresh and answers
    /// the host's next `ERR?` with [`GcsErrorCode::LinkLost`]. Without a known identification
    /// line, it first waits for the line to be quiet for [`RESYNC_QUIET_MS`], dropping what
    /// the controller sends and holding the host's lines (stops excepted).
    pub fn stage_bytes_lost(&mut self, now_ms: u32) {
        let st = &mut self.st;
        st.link_lost = true;
        st.resync_hold = true;
        st.last_rx_ms = now_ms;
        st.counters.link_losses = st.counters.link_losses.wrapping_add(1);
    }

    /// True while the proxy has not yet resynchronised after lost bytes (until its next call,
    /// or, without a known identification line, until the line is quiet).
    pub fn recovering_lost_bytes(&self) -> bool {
        self.st.link_lost
    }

    /// The hold on the host's bytes while the line resynchronises — after lost bytes, or
    /// while identification lines of queries given up are still due before the
    /// resynchronising marker's reply ([`ProxyState::resync_holds`]): `None` when not
    /// resynchronising; else how many bytes of `input` were taken — a stop (`#24`, `#27`)
    /// goes out at once, everything else waits.
    #[inline(never)]
    pub(super) fn link_lost_hold<C: Corrector>(
        &mut self,
        c: Option<&C>,
        input: &[u8],
        out: &mut Output,
    ) -> Option<usize> {
        if self.st.link_lost {
            self.st.end_link_loss(c, out);
            if !out.is_empty() {
                // the resynchronising marker goes first; the host's bytes in the next call
                return Some(0);
            }
        }
        if !self.st.link_lost && !self.st.resync_holds() {
            return None;
        }
        match input.first() {
            Some(&b @ (0x18 | 0x1B)) if out.to_stage.room() > 0 => {
                self.host_single(b, out);
                Some(1)
            }
            _ => Some(0),
        }
    }
}

impl ProxyState {
    /// While the proxy resynchronises with replies given up still coming (lost bytes, a
    /// marker that brought back something else), nothing that expects a reply goes out behind
    /// the marker: host lines (stops excepted) and a held line wait for its reply. The
    /// identification lines still due before it are counted high rather than low
    /// (`replies::resync`), and what is still coming may be damaged (a continued line's
    /// fragment swallows the next line); when the marker's reply is taken for a stale one or
    /// swallowed, a query queued behind the marker would lose its reply unseen and every later
    /// reply would pair with the query before it. With nothing behind the marker, a missed
    /// reply only leaves the controller silent: after [`super::REPLY_TIMEOUT_MS`] the proxy
    /// resynchronises again, with nothing given up still coming — then lines go out behind
    /// the marker at once (a controller silent that long has stopped: nothing late follows).
    pub(super) fn resync_holds(&self) -> bool {
        self.resyncing && self.resync_hold
    }

    /// After lost bytes: resynchronise with a marker (or, without a known identification
    /// line, once the line has been quiet for [`RESYNC_QUIET_MS`], give up what was due), forget
    /// the targets, raise [`GcsErrorCode::LinkLost`] and run a held line afresh. Nothing when
    /// no bytes were lost. The caller processes nothing more in the same call when this
    /// produced output (a marker must reach the controller before anything else is sent).
    pub(super) fn end_link_loss<C: Corrector>(&mut self, c: Option<&C>, out: &mut Output) {
        if !self.link_lost {
            return;
        }
        let exact = self.ctrl.marker_reply().is_some();
        if !exact {
            let now = self.now_ms;
            let quiet = now.wrapping_sub(self.last_rx_ms) >= RESYNC_QUIET_MS
                && now.wrapping_sub(self.last_tx_ms) >= RESYNC_QUIET_MS;
            if !quiet {
                return;
            }
        }
        self.link_lost = false;
        if exact {
            self.resync_after_loss(c, out);
        } else {
            self.give_up(c, out);
            // nothing is in flight any more: no marker to wait for
            self.resyncing = false;
            self.resync_hold = false;
        }
        // the held line is not the controller's fault: it runs again and asks what it needs
        // afresh — after the next reply (the marker's at the latest), not in this call, whose
        // marker a line held again would clear from `out`
        self.held_lost = false;
        self.held_runs = 0;
        self.reseed = Reseed::None;
        self.forget(None);
        if self.pending_error.is_none() {
            self.pending_error = Some(GcsErrorCode::LinkLost);
        }
        if !exact {
            self.try_release(c, out);
        }
    }
}
