//! What the stage link tells the proxy about itself: bytes from the controller were lost
//! ([`Proxy::stage_bytes_lost`]). Replies already on their way then belong to no query one can
//! name: pairing them with the next queries would hand the host (or the proxy's own `MOV?`
//! re-seed) someone else's answer. (The host's side, a session that ends, is
//! [`Proxy::new_session`].)

use super::GcsErrorCode;
use super::{Corrector, Output, Proxy, ProxyState, Reseed};

/// How long the controller's line must stay silent after lost bytes before the proxy pairs
/// replies with queries again, ms: longer than the gap between the bytes of one reply, far
/// shorter than [`super::REPLY_TIMEOUT_MS`].
pub const RESYNC_QUIET_MS: u32 = 100;

impl Proxy {
    /// Bytes from the controller were lost (a UART overrun, a full receive buffer) at
    /// `now_ms`. Which reply lost them cannot be told, and a lost LF joins two replies (a lost
    /// marker reply would pass unseen): every reply now due is suspect, and so is the pairing
    /// of the ones after. Until the line has been quiet for [`RESYNC_QUIET_MS`] the proxy
    /// drops what the controller sends and holds the host's lines (stops excepted); then it
    /// gives up the replies that were due, forgets the targets (a move that needs one asks
    /// `MOV?` afresh) and answers the host's next `ERR?` with [`GcsErrorCode::LinkLost`].
    pub fn stage_bytes_lost(&mut self, now_ms: u32) {
        let st = &mut self.st;
        st.link_lost = true;
        st.last_rx_ms = now_ms;
        st.counters.link_losses = st.counters.link_losses.wrapping_add(1);
    }

    /// True while the proxy waits for the controller's line to go quiet after lost bytes.
    pub fn recovering_lost_bytes(&self) -> bool {
        self.st.link_lost
    }

    /// [`Self::stage_bytes_lost`]'s hold on the host's bytes while the line resynchronises:
    /// `None` when not resynchronising; else how many bytes of `input` were taken — a stop
    /// (`#24`, `#27`) goes out at once, everything else waits.
    pub(super) fn link_lost_hold(&mut self, input: &[u8], out: &mut Output) -> Option<usize> {
        if !self.st.link_lost {
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
    /// replies that were due (a marker awaited with them), forget the targets, raise
    /// [`GcsErrorCode::LinkLost`] and run a held line afresh.
    pub(super) fn try_end_link_loss<C: Corrector>(&mut self, c: Option<&C>, out: &mut Output) {
        let now = self.now_ms;
        let quiet = now.wrapping_sub(self.last_rx_ms) >= RESYNC_QUIET_MS
            && now.wrapping_sub(self.last_tx_ms) >= RESYNC_QUIET_MS;
        if !self.link_lost || !quiet {
            return;
        }
        self.link_lost = false;
        self.give_up(c, out);
        // nothing is in flight any more: no marker to wait for, and the held line is not the
        // silent controller's fault — it runs again and asks what it needs afresh
        self.resyncing = false;
        self.held_lost = false;
        self.held_runs = 0;
        self.reseed = Reseed::None;
        self.forget(None);
        if self.pending_error.is_none() {
            self.pending_error = Some(GcsErrorCode::LinkLost);
        }
        self.try_release(c, out);
    }
}
