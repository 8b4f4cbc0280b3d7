//! The supervisor task: refuses moves on a stale fold, drives the status LED, and pets the
//! watchdog only while the sensor task makes progress and no link or management task is stuck
//! in a step that should end (a stage-link write the UART never sends, a store write) — a hung
//! task or a blocked executor resets the board (IWDG on the STM32, the CMSDK watchdog on
//! QEMU). Waiting for input is no hang, nor is a host that does not read (its bytes are
//! dropped, see `links.rs`).

use super::{now_ms, task, Shared};
use core::sync::atomic::Ordering;
use embassy_time::Timer;
use nanocal_compensator::proxy::Gate;
use nanocal_interface::led::LedState;
use nanocal_interface::status::StageCheck;

/// What the supervisor drives on a board.
pub trait Board {
    /// Light (or not) the status LED.
    fn set_led(&mut self, on: bool);
    /// Reload the watchdog.
    fn pet_watchdog(&mut self);
}

/// Longest a fold may age before moves are refused, ms: two fold periods (a fold runs at the
/// first sample cycle a fold period after the last, so at most a sample period late) plus a
/// bus-timeout allowance for the chips and the aux sources.
pub fn stale_limit_ms(sh: &Shared) -> u32 {
    limits_ms(sh).0
}

/// (stale-fold limit, heartbeat limit), ms: the sensor task beats once a sample cycle, so its
/// heartbeat may age two sample periods plus the bus-timeout allowance before the watchdog is no
/// longer petted.
fn limits_ms(sh: &Shared) -> (u32, u32) {
    let (sample, fold) = sh.settings.lock(|s| {
        let s = s.borrow();
        (u32::from(s.sample_period_ms), u32::from(s.fold_period_ms))
    });
    (2 * sample.max(fold) + 4000, 2 * sample + 4000)
}

/// What the LED shows now.
pub fn led_state(sh: &Shared) -> LedState {
    let (model, stale) = sh.model.lock(|m| {
        let m = m.borrow();
        (m.model.is_some(), m.stale.is_stale())
    });
    let (bypass, refused) = sh.core.lock(|c| {
        let c = c.borrow();
        (
            c.proxy.bypass,
            // another stage than the model's (provenance check): moves refused too
            c.proxy.gate != Gate::Open
                || c.comp.is_none()
                || c.proxy.stage_check() == StageCheck::Mismatch,
        )
    });
    LedState::of(model, bypass, refused, stale)
}

/// Longest the supervisor sleeps, ms: the stale-fold gate closes at most this late (on a limit
/// of at least 6 s, [`limits_ms`]), a change of the LED's pattern shows this soon, and the
/// watchdog is petted at about half its 2 s — at most 1.88 s with the LSI at its 34 kHz
/// maximum (IWDG on the LSI, RM0351 §32.3; f_LSI 29.5–34 kHz, §6.2.6 and the datasheet) — with
/// nothing in the firmware that blocks the executor for long (the store's erases are awaited:
/// bank 2 erases while code runs from bank 1).
const SUPERVISE_MS: u32 = 1_000;

/// Run the supervisor: wakes every [`SUPERVISE_MS`], or sooner when the LED's blink pattern
/// changes. (It woke every 50 ms, then every 250 ms: four wake-ups a second were still 87
/// wake-ups of the emulated board per step of the published virtual campaign, and ≈ 30 % of
/// QEMU's CPU there — issue 20 §5 — besides the board's power.)
pub async fn supervisor<B: Board>(mut board: B, sh: &Shared) -> ! {
    let mut sleep_ms = SUPERVISE_MS;
    loop {
        Timer::after_millis(u64::from(sleep_ms)).await;
        let now = now_ms();
        let (limit, beat_limit) = limits_ms(sh);
        sh.core.lock(|c| {
            let mut c = c.borrow_mut();
            if c.comp.is_some() && now.wrapping_sub(c.folded_at_ms) > limit {
                c.proxy.gate = Gate::SensorFault;
            }
        });
        let led = led_state(sh);
        board.set_led(led.lit(now));
        sleep_ms = led
            .next_edge_ms(now)
            .map_or(SUPERVISE_MS, |e| e.clamp(1, SUPERVISE_MS));
        let beat = sh.sensor_beat_ms.load(Ordering::Relaxed);
        let sensors_alive = now.wrapping_sub(beat) <= beat_limit || now < beat_limit;
        let stuck = (0..task::COUNT).find(|&t| sh.beats[t].busy_for_ms(now) > task::LIMIT_MS[t]);
        if let Some(t) = stuck {
            warn!(
                "{=str} stuck: the watchdog will reset the board",
                task::NAMES[t]
            );
        }
        if sensors_alive && stuck.is_none() {
            board.pet_watchdog();
        }
    }
}
