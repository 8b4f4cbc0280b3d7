//! The clock tree of the B-L475E-IOT01A firmware (RM0351 §6), and the flash wait states that
//! must be raised before any clock is (§3.3.3). Both stopped the image at boot once (issue 16):
//! an ADC without a kernel clock, wait states raised after the clock.

use embassy_stm32::Config;
use nanocal_compensator::clock;

const FLASH_ACR: usize = 0x4002_2000;

fn reg(a: usize) -> u32 {
    // SAFETY: FLASH_ACR, 32-bit access.
    unsafe { core::ptr::read_volatile(a as *const u32) }
}

fn set(a: usize, v: u32) {
    // SAFETY: as above.
    unsafe { core::ptr::write_volatile(a as *mut u32, v) }
}

/// The clock tree: 80 MHz SYSCLK from the PLL on MSI, USB and the ADC clocked.
pub fn config() -> Config {
    use embassy_stm32::rcc::*;
    let mut config = embassy_stm32::Config::default();
    // MSI 48 MHz trimmed by the 32.768 kHz LSE (MSI PLL mode) clocks USB; PLL → 80 MHz SYSCLK.
    config.rcc.ls = LsConfig::default_lse();
    config.rcc.msi = Some(MSIRange::RANGE48M);
    config.rcc.pll = Some(Pll {
        source: PllSource::MSI,
        prediv: PllPreDiv::DIV6,
        mul: PllMul::MUL20,
        divp: None,
        divq: None,
        divr: Some(PllRDiv::DIV2),
    });
    config.rcc.sys = Sysclk::PLL1_R;
    config.rcc.mux.clk48sel = mux::Clk48sel::MSI;
    // The ADC's kernel clock: CCIPR.ADCSEL resets to 00, "no clock" (RM0351 §6.4.28), and
    // embassy-stm32 leaves ADC_CCR.CKMODE at 00 (the asynchronous clock), so an unset mux
    // leaves the ADC unclocked: `Adc::new` spins on ADCAL for ever and the watchdog resets the
    // board every 2 s (issue 16; tests/stm32_boot.rs). SYSCLK (80 MHz) is within the ADC's
    // 80 MHz maximum (datasheet fADC).
    config.rcc.mux.adcsel = mux::Adcsel::SYS;
    config
}

/// Program the flash wait states for 80 MHz before embassy-stm32 touches a clock.
///
/// embassy-stm32 0.6.0 `rcc/l.rs` `init()` calls `msi_enable(RANGE48M)` while MSI is the
/// system clock and writes FLASH_ACR.LATENCY only after the PLL is configured; from reset the
/// L4 runs 0 wait states, valid to 16 MHz (RM0351 §3.3.3, Table 12), so the core would run
/// 48 MHz from flash at 0 WS. Fixed upstream after 0.6.0 (embassy-rs/embassy#6768, "set max
/// flash latency before raising the MSI range"), not released: more wait states are always
/// safe, and init then writes the exact value for the final clocks.
pub fn flash_latency_first() {
    let acr = reg(FLASH_ACR);
    let ws = u32::from(clock::BOOT_WAIT_STATES);
    set(FLASH_ACR, (acr & !0x7) | ws);
    while reg(FLASH_ACR) & 0x7 != ws {}
}
