//! Sensor fault policy (pure, time passed in by the caller).
//!
//! Per channel:
//! 1. A good reading inside the plausible range is used (and resets the channel to `Ok`).
//! 2. On a fault the channel enters `Holding`: the last good temperature stays in use for at
//!    most [`Policy::hold_ms`]; moves are still allowed.
//! 3. After `hold_ms` of uninterrupted faults (or a fault with no good reading ever) the channel
//!    is `Failed`: moves are refused with an error until it recovers.
//! 4. Recovery needs [`Policy::recover_count`] consecutive good readings.
//!
//! Extrapolation (a temperature outside the model's training envelope) is a status flag, not a
//! fault: it is reported by the model's fold.

use crate::sensor::SensorFault;
use nanocal_interface::status::{ChannelBits, ChannelStatus};

/// Most channels the policy tracks (the model's temperature inputs).
pub const MAX_CHANNELS: usize = nanocal_model::MAX_TEMPS;

/// Parameters of the fault policy.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Policy {
    /// How long the last good temperature is held after a fault, ms.
    pub hold_ms: u32,
    /// Consecutive good readings needed to leave `Failed`.
    pub recover_count: u8,
    /// Plausible range, °C: readings outside it are faults.
    pub min_c: f32,
    /// Upper end of the plausible range, °C.
    pub max_c: f32,
}

impl Default for Policy {
    fn default() -> Self {
        Self {
            hold_ms: 5_000,
            recover_count: 3,
            min_c: -40.0,
            max_c: 125.0,
        }
    }
}

/// State of one channel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ChannelState {
    /// Never read successfully yet.
    Unknown,
    /// Good.
    Ok,
    /// Faulted since `since_ms`, last good value held.
    Holding {
        /// Time of the first fault of this run, ms.
        since_ms: u32,
    },
    /// Faulted for longer than the hold time: moves refused.
    Failed {
        /// Consecutive good readings seen so far toward recovery.
        good_run: u8,
    },
}

/// One channel: state, last good value and last fault.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Channel {
    /// Current state.
    pub state: ChannelState,
    /// Last good temperature, °C.
    pub last_good_c: f32,
    /// Last fault seen (kept for status after recovery), if any.
    pub last_fault: Option<SensorFault>,
    /// Number of faulty readings seen.
    pub fault_count: u32,
}

impl Default for Channel {
    fn default() -> Self {
        Self {
            state: ChannelState::Unknown,
            last_good_c: f32::NAN,
            last_fault: None,
            fault_count: 0,
        }
    }
}

impl Channel {
    /// Apply one reading taken at `now_ms`.
    pub fn update(&mut self, policy: &Policy, reading: Result<f32, SensorFault>, now_ms: u32) {
        let reading = reading.and_then(|t| {
            if t >= policy.min_c && t <= policy.max_c {
                Ok(t)
            } else {
                Err(SensorFault::Implausible)
            }
        });
        match reading {
            Ok(t) => {
                self.state = match self.state {
                    ChannelState::Failed { good_run } => {
                        let run = good_run.saturating_add(1);
                        if run >= policy.recover_count {
                            self.last_good_c = t;
                            ChannelState::Ok
                        } else {
                            ChannelState::Failed { good_run: run }
                        }
                    }
                    _ => {
                        self.last_good_c = t;
                        ChannelState::Ok
                    }
                };
            }
            Err(f) => {
                self.last_fault = Some(f);
                self.fault_count = self.fault_count.wrapping_add(1);
                self.state = match self.state {
                    ChannelState::Unknown => ChannelState::Failed { good_run: 0 },
                    ChannelState::Ok => {
                        if policy.hold_ms == 0 {
                            ChannelState::Failed { good_run: 0 }
                        } else {
                            ChannelState::Holding { since_ms: now_ms }
                        }
                    }
                    ChannelState::Holding { since_ms } => {
                        if now_ms.wrapping_sub(since_ms) >= policy.hold_ms {
                            ChannelState::Failed { good_run: 0 }
                        } else {
                            ChannelState::Holding { since_ms }
                        }
                    }
                    ChannelState::Failed { .. } => ChannelState::Failed { good_run: 0 },
                };
            }
        }
    }

    /// Re-evaluate the hold timeout without a new reading (e.g. the bus stopped answering).
    pub fn tick(&mut self, policy: &Policy, now_ms: u32) {
        if let ChannelState::Holding { since_ms } = self.state {
            if now_ms.wrapping_sub(since_ms) >= policy.hold_ms {
                self.state = ChannelState::Failed { good_run: 0 };
            }
        }
    }

    /// The temperature to use (last good, held), or `None` when the channel is not usable.
    pub fn value_c(&self) -> Option<f32> {
        match self.state {
            ChannelState::Ok | ChannelState::Holding { .. } => Some(self.last_good_c),
            _ => None,
        }
    }

    /// True when moves must be refused because of this channel.
    pub fn blocks_moves(&self) -> bool {
        matches!(
            self.state,
            ChannelState::Failed { .. } | ChannelState::Unknown
        )
    }

    /// The channel's state and last fault as the status report carries them.
    pub fn status_bits(&self) -> ChannelBits {
        ChannelBits {
            state: match self.state {
                ChannelState::Ok => ChannelStatus::Ok,
                ChannelState::Holding { .. } => ChannelStatus::Holding,
                ChannelState::Failed { .. } => ChannelStatus::Failed,
                ChannelState::Unknown => ChannelStatus::NotRead,
            },
            last_fault: self.last_fault,
        }
    }
}

/// `N` channels under one policy (the temperatures, or the aux inputs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Faults<const N: usize = MAX_CHANNELS> {
    /// The policy.
    pub policy: Policy,
    /// The channels.
    pub channels: [Channel; N],
}

impl<const N: usize> Faults<N> {
    /// All channels unknown.
    pub fn new(policy: Policy) -> Self {
        Self {
            policy,
            channels: [Channel::default(); N],
        }
    }

    /// Apply a reading of channel `i`.
    pub fn update(&mut self, i: usize, reading: Result<f32, SensorFault>, now_ms: u32) {
        let p = self.policy;
        if let Some(c) = self.channels.get_mut(i) {
            c.update(&p, reading, now_ms);
        }
    }

    /// Re-evaluate channel `i`'s hold time at `now_ms` without a reading (a cycle in which it
    /// gave none): a channel holding its last good value fails once the hold time is over, even
    /// when no new reading ever comes.
    pub fn tick(&mut self, i: usize, now_ms: u32) {
        let p = self.policy;
        if let Some(c) = self.channels.get_mut(i) {
            c.tick(&p, now_ms);
        }
    }

    /// True when every one of the first `used` channels has a usable value (moves and the
    /// model's lag filters may start).
    pub fn all_usable(&self, used: usize) -> bool {
        used <= N
            && self
                .channels
                .iter()
                .take(used)
                .all(|c| c.value_c().is_some())
    }

    /// True when any of the first `used` channels blocks moves.
    pub fn blocks_moves(&self, used: usize) -> bool {
        used > N || self.channels.iter().take(used).any(Channel::blocks_moves)
    }
}
