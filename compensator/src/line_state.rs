//! The host's line state on a USB CDC-ACM port as the firmware should see it (USB CDC PSTN 1.2
//! §6.3.12 SET_CONTROL_LINE_STATE, DTR = bit 0 of wValue).
//!
//! The USB stack answers the requests in its interrupt-driven task; the application looks at
//! the line state later, when woken. Looking at DTR as a level loses a quick close and open
//! (DTR 1 → 0 → 1 in two requests before the application looked): it sees 1 and 1, and the old
//! connection's half line and queued replies run into the new one. So the USB side counts the
//! falls as they come ([`LineWatch::request`]), and the application's look
//! ([`LineSeen::look`]) turns (falls so far, DTR now) into the changes to apply — a fall missed
//! between two looks included. Both CDC ports of the STM32 board use it (the QEMU board's bench
//! sends every change as a byte of its own and needs none of this).

/// The USB side of one port: the line state as the requests set it, falls counted.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct LineWatch {
    /// DTR as the last request set it.
    pub dtr: bool,
    /// DTR falls so far (wrapping).
    pub falls: u32,
}

impl LineWatch {
    /// DTR low, no fall yet.
    pub const fn new() -> Self {
        Self {
            dtr: false,
            falls: 0,
        }
    }

    /// A SET_CONTROL_LINE_STATE request with DTR `dtr`; true when it is a fall (the port was
    /// closed: what was queued for the old connection is the old connection's).
    pub fn request(&mut self, dtr: bool) -> bool {
        let fell = self.dtr && !dtr;
        if fell {
            self.falls = self.falls.wrapping_add(1);
        }
        self.dtr = dtr;
        fell
    }

    /// The bus was reset (or the device deconfigured): an open port is closed.
    pub fn bus_reset(&mut self) -> bool {
        self.request(false)
    }
}

/// The application side of one port: what it has applied so far.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct LineSeen {
    falls: u32,
    dtr: bool,
}

impl LineSeen {
    /// Nothing applied yet: DTR low.
    pub const fn new() -> Self {
        Self {
            falls: 0,
            dtr: false,
        }
    }

    /// A look at the USB side's `watch`: the line states to apply, oldest first — DTR low for
    /// falls not applied yet (one, however many came in between: the session ends once), then
    /// DTR now if it differs from what was applied last. Empty when nothing changed.
    pub fn look(&mut self, watch: LineWatch) -> heapless::Vec<bool, 2> {
        let mut apply = heapless::Vec::new();
        if watch.falls != self.falls {
            self.falls = watch.falls;
            // the close is applied when the port was seen open, and also when it was seen
            // closed but is open now (a fall implies a rise not seen: it was opened, closed
            // and opened again between two looks)
            if self.dtr || watch.dtr {
                let _ = apply.push(false);
            }
            self.dtr = false;
        }
        if watch.dtr != self.dtr {
            self.dtr = watch.dtr;
            let _ = apply.push(watch.dtr);
        }
        apply
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seen(s: &mut LineSeen, w: LineWatch) -> std::vec::Vec<bool> {
        s.look(w).iter().copied().collect()
    }

    #[test]
    fn an_open_and_a_close_seen_one_by_one() {
        let (mut w, mut s) = (LineWatch::new(), LineSeen::new());
        assert_eq!(seen(&mut s, w), [] as [bool; 0]);
        assert!(!w.request(true));
        assert_eq!(seen(&mut s, w), [true]);
        assert_eq!(seen(&mut s, w), [] as [bool; 0], "nothing new");
        assert!(w.request(false));
        assert_eq!(seen(&mut s, w), [false]);
        assert_eq!(seen(&mut s, w), [] as [bool; 0]);
    }

    #[test]
    fn a_quick_close_and_open_between_two_looks_ends_the_session() {
        let (mut w, mut s) = (LineWatch::new(), LineSeen::new());
        w.request(true);
        assert_eq!(seen(&mut s, w), [true]);
        assert!(w.request(false));
        assert!(!w.request(true));
        // a level alone would say "still open"
        assert_eq!(seen(&mut s, w), [false, true]);
        assert_eq!(seen(&mut s, w), [] as [bool; 0]);
    }

    #[test]
    fn an_open_close_open_before_the_first_look_starts_one_clean_session() {
        let (mut w, mut s) = (LineWatch::new(), LineSeen::new());
        w.request(true);
        w.request(false);
        w.request(true);
        assert_eq!(seen(&mut s, w), [false, true]);
    }

    #[test]
    fn many_falls_between_looks_end_the_session_once() {
        let (mut w, mut s) = (LineWatch::new(), LineSeen::new());
        w.request(true);
        assert_eq!(seen(&mut s, w), [true]);
        for _ in 0..5 {
            w.request(false);
            w.request(true);
        }
        w.request(false);
        assert_eq!(w.falls, 6);
        assert_eq!(seen(&mut s, w), [false]);
    }

    #[test]
    fn repeated_requests_with_the_same_level_are_no_change() {
        let (mut w, mut s) = (LineWatch::new(), LineSeen::new());
        assert!(!w.request(false));
        assert_eq!(seen(&mut s, w), [] as [bool; 0]);
        w.request(true);
        w.request(true);
        assert_eq!(seen(&mut s, w), [true]);
        assert!(w.bus_reset());
        assert!(!w.bus_reset());
        assert_eq!(seen(&mut s, w), [false]);
    }

    #[test]
    fn the_fall_count_wraps() {
        let mut w = LineWatch {
            dtr: true,
            falls: u32::MAX,
        };
        let mut s = LineSeen {
            falls: u32::MAX,
            dtr: true,
        };
        assert!(w.request(false));
        assert_eq!(w.falls, 0);
        assert_eq!(seen(&mut s, w), [false]);
    }
}
