//! What the links tell the proxy about themselves: the host closed its session
//! ([`Proxy::end_host_session`]), bytes from the controller were lost
//! ([`Proxy::stage_bytes_lost`]). In both, replies already on their way belong to no query any
//! more: pairing them with the next queries would hand the host (or the proxy's own `MOV?`
//! re-seed) someone else's answer.

use super::GcsErrorCode;
use super::{Corrector, Output, Proxy, ProxyState};

/// How long the controller's line must stay silent after lost bytes before the proxy pairs
/// replies with queries again, ms: longer than the gap between the bytes of one reply, far
/// shorter than [`super::REPLY_TIMEOUT_MS`].
pub const RESYNC_QUIET_MS: u32 = 100;

impl Proxy {
    /// The host closed its session (USB DTR fell): everything of that session goes — the line
    /// being received, a line waiting for the controller, a pending error, the targets (the
    /// proxy starts as fresh) — except that replies still due from the controller are read to
    /// their end and dropped, never paired with the next session's queries. Bypass, the move
    /// gate and the counters stay.
    pub fn end_host_session(&mut self) {
        let mut fresh = Proxy::new(self.st.map);
        fresh.st.bypass = self.st.bypass;
        fresh.st.gate = self.st.gate;
        fresh.st.counters = self.st.counters;
        fresh.st.resync = self.st.resync;
        fresh.st.last_rx_ms = self.st.last_rx_ms;
        fresh.st.last_tx_ms = self.st.last_tx_ms;
        fresh.st.now_ms = self.st.now_ms;
        fresh.st.queue = core::mem::replace(&mut self.st.queue, super::queue::Queue::new());
        fresh.st.queue.discard_all();
        if self.st.rx.active() {
            fresh.st.rx.continue_as_discard(&self.st.rx);
        }
        *self = fresh;
    }

    /// Bytes from the controller were lost (a UART overrun, a full receive buffer) at
    /// `now_ms`. Which reply lost them cannot be told, and a lost LF joins two replies: every
    /// reply now due is suspect, and so is the pairing of the ones after. Until the line has
    /// been quiet for [`RESYNC_QUIET_MS`] the proxy drops what the controller sends and holds
    /// the host's lines (stops excepted); then it gives up the replies that were due, forgets
    /// the targets (a move that needs one asks `MOV?` afresh) and answers the host's next
    /// `ERR?` with [`GcsErrorCode::LinkLost`].
    pub fn stage_bytes_lost(&mut self, now_ms: u32) {
        let st = &mut self.st;
        st.resync = true;
        st.last_rx_ms = now_ms;
        st.counters.link_losses = st.counters.link_losses.wrapping_add(1);
    }

    /// True while the proxy waits for the controller's line to go quiet after lost bytes.
    pub fn resyncing(&self) -> bool {
        self.st.resync
    }

    /// [`Self::stage_bytes_lost`]'s hold on the host's bytes while the line resynchronises:
    /// `None` when not resynchronising; else how many bytes of `input` were taken — a stop
    /// (`#24`, `#27`) goes out at once, everything else waits.
    pub(super) fn resync_hold(&mut self, input: &[u8], out: &mut Output) -> Option<usize> {
        if !self.st.resync {
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
    /// After lost bytes: once the line has been quiet for [`RESYNC_QUIET_MS`], give up the
    /// replies that were due, forget the targets, and raise [`GcsErrorCode::LinkLost`].
    pub(super) fn try_end_resync<C: Corrector>(&mut self, c: Option<&C>, out: &mut Output) {
        let now = self.now_ms;
        let quiet = now.wrapping_sub(self.last_rx_ms) >= RESYNC_QUIET_MS
            && now.wrapping_sub(self.last_tx_ms) >= RESYNC_QUIET_MS;
        if !self.resync || !quiet {
            return;
        }
        self.resync = false;
        self.give_up_replies(c, out);
        self.forget(None);
        self.reseed = super::Targets::default();
        if self.pending_error.is_none() {
            self.pending_error = Some(GcsErrorCode::LinkLost);
        }
        self.try_release(c, out);
    }
}
