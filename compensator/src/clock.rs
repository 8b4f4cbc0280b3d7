//! STM32L4 clock rules the boot depends on (RM0351), as checkable facts.

/// Flash wait states needed for an HCLK in voltage range 1 (RM0351 §3.3.3, Table 12
/// "Number of wait states according to CPU clock (HCLK) frequency": 0 WS ≤ 16 MHz, 1 ≤ 32,
/// 2 ≤ 48, 3 ≤ 64, 4 ≤ 80).
pub fn wait_states_range1(hclk_hz: u32) -> u8 {
    match hclk_hz {
        0..=16_000_000 => 0,
        16_000_001..=32_000_000 => 1,
        32_000_001..=48_000_000 => 2,
        48_000_001..=64_000_000 => 3,
        _ => 4,
    }
}

/// Wait states the firmware programs before embassy-stm32 touches any clock: enough for the
/// fastest clock init ever runs at (80 MHz); raising wait states is always safe, and
/// embassy-stm32 then writes the exact value for the final clocks (RM0351 §3.3.3: "increasing
/// the CPU frequency: program the new number of wait states … then modify the clock source").
pub const BOOT_WAIT_STATES: u8 = 4;

/// One step of a clock bring-up, as the L4's flash interface sees it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ClockStep {
    /// FLASH_ACR.LATENCY written (and read back).
    SetLatency(u8),
    /// HCLK changes to this frequency (a system-clock switch, or a range change of the MSI
    /// that is the system clock).
    Hclk(u32),
}

/// Replay `steps` from reset (MSI 4 MHz, 0 wait states) and return the first step at which
/// the core would run faster than the programmed wait states allow, if any.
pub fn first_violation(steps: &[ClockStep]) -> Option<usize> {
    let (mut ws, mut hclk) = (0u8, 4_000_000u32);
    for (i, s) in steps.iter().enumerate() {
        match *s {
            ClockStep::SetLatency(n) => ws = n,
            ClockStep::Hclk(f) => hclk = f,
        }
        if wait_states_range1(hclk) > ws {
            return Some(i);
        }
    }
    None
}

/// Timer tick error of embassy-time's tick `tick_hz` from a timer clocked at `timer_hz`, in
/// parts per million: the timer prescaler is an integer, so a tick that does not divide the
/// timer clock runs fast or slow (32 768 Hz from 80 MHz: prescaler 2441, 32 773.4 Hz,
/// +165 ppm ≈ 14 s/day).
pub fn tick_error_ppm(timer_hz: u32, tick_hz: u32) -> f64 {
    let psc = (timer_hz / tick_hz).max(1);
    let actual = f64::from(timer_hz) / f64::from(psc);
    (actual / f64::from(tick_hz) - 1.0) * 1e6
}
