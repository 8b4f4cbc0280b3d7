//! The status LED (LD2 on the B-L475E-IOT01A): what the device is doing, at a glance. STATUS
//! reports the state's code; the blink patterns below are the device's and the host's one
//! table (`nanocal device status` prints [`LedState`]'s meaning).
//!
//! | state | code | LED |
//! |---|---:|---|
//! | compensating | 1 | on |
//! | bypass | 2 | slow blink (1 s on, 1 s off) |
//! | no model | 3 | short flash every 2 s |
//! | fault (moves refused: sensor failed, stale or warming up, or another stage than the model's) | 4 | fast blink (5 Hz) |
//! | model stale (still compensating; `MODEL_STALE`) | 5 | on, dark for 0.2 s every second |

code_enum! {
    /// What the LED shows.
    pub enum LedState: u8 {
        /// A model is in service and moves are corrected.
        Compensating = 1 => "compensating (on)",
        /// Compensation bypassed: commands pass untouched.
        Bypass = 2 => "bypass (slow blink)",
        /// No model loaded.
        NoModel = 3 => "no model (short flash)",
        /// Moves are refused (a sensor failed, the fold is stale, sensors are warming up, or the
        /// controller is another stage than the model was fitted on, `STAGE_MISMATCH`).
        Fault = 4 => "fault (fast blink)",
        /// A model is in service and moves are corrected, but it has gone stale (the status's
        /// `MODEL_STALE`): refit or re-measure.
        Stale = 5 => "compensating with a stale model (on, dark 0.2 s every second)",
    }
}

impl LedState {
    /// The state for the device's conditions (bypass shows even with a fault: it is what the
    /// stage gets; a fault shows over a stale model: moves are refused).
    pub fn of(model: bool, bypass: bool, moves_refused: bool, model_stale: bool) -> Self {
        if bypass {
            LedState::Bypass
        } else if !model {
            LedState::NoModel
        } else if moves_refused {
            LedState::Fault
        } else if model_stale {
            LedState::Stale
        } else {
            LedState::Compensating
        }
    }

    /// The blink pattern: (period, lit for the first … of it), ms; `None`: steadily on.
    fn blink_ms(self) -> Option<(u32, u32)> {
        match self {
            LedState::Compensating => None,
            LedState::Bypass => Some((2000, 1000)),
            LedState::NoModel => Some((2000, 100)),
            LedState::Fault => Some((200, 100)),
            // mostly on (it compensates), with a gap no other state has
            LedState::Stale => Some((1000, 800)),
        }
    }

    /// Whether the LED is lit `t_ms` into the pattern.
    pub fn lit(self, t_ms: u32) -> bool {
        self.blink_ms()
            .is_none_or(|(period, on)| t_ms % period < on)
    }

    /// Milliseconds from `t_ms` until [`Self::lit`] next changes (`None`: a steady pattern), so
    /// the supervisor need not wake more often than the LED changes.
    pub fn next_edge_ms(self, t_ms: u32) -> Option<u32> {
        let (period, on) = self.blink_ms()?;
        let phase = t_ms % period;
        Some(if phase < on {
            on - phase
        } else {
            period - phase
        })
    }
}
