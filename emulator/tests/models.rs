//! The register models against RM0351's figures, without firmware: the wait-state table, the
//! clock tree, ADC calibration with and without a kernel clock, the flash controller's
//! programming, ECC and data cache, the timer's compare events, the NVIC's priorities.

use nanocal_stm32_board::flash::{wait_states_needed, FlashCtl, StoreFlash, STORE_BASE};
use nanocal_stm32_board::nvic::{exc, Nvic};
use nanocal_stm32_board::rcc::Rcc;
use nanocal_stm32_board::simple::{Adc, Timer};
use nanocal_stm32_board::{usb, Io, NoChips};
use std::sync::{Arc, Mutex};

fn no_io() -> Io {
    Io::new(
        Arc::new(Mutex::new(NoChips)),
        None,
        usb::Host::placeholder(),
    )
}

const MS: u64 = 1_000_000_000;

#[test]
fn flash_wait_states_follow_rm0351_table_12() {
    // range 1: 0 WS ≤ 16 MHz, 1 ≤ 32, 2 ≤ 48, 3 ≤ 64, 4 ≤ 80
    assert_eq!(wait_states_needed(4_000_000, 1), 0);
    assert_eq!(wait_states_needed(16_000_000, 1), 0);
    assert_eq!(wait_states_needed(16_000_001, 1), 1);
    assert_eq!(wait_states_needed(48_000_000, 1), 2);
    assert_eq!(wait_states_needed(80_000_000, 1), 4);
    // range 2: 0 WS ≤ 6 MHz … 3 ≤ 26 MHz; above 26 MHz range 2 cannot run
    assert_eq!(wait_states_needed(26_000_000, 2), 3);
    assert_eq!(wait_states_needed(48_000_000, 2), u32::MAX);
}

/// The firmware's clocks: MSI 48 MHz, PLL M = 6, N = 20, R = 2 → 80 MHz SYSCLK.
fn rcc_at_80_mhz() -> Rcc {
    let mut r = Rcc::power_on();
    assert_eq!(
        r.clocks().sysclk,
        4_000_000,
        "MSI range 6 after reset (§6.4.1)"
    );
    r.write(0x00, 0x03 | (11 << 4) | (1 << 3)); // MSION, MSIRANGE 11 (48 MHz), MSIRGSEL
    r.write(0x0C, 1 | (5 << 4) | (20 << 8) | (1 << 24)); // MSI, M = 6, N = 20, REN, R = 2
    r.write(0x00, r.read(0x00) | (1 << 24)); // PLLON
    assert_ne!(r.read(0x00) & (1 << 25), 0, "PLLRDY: {:?}", r.errors);
    r.write(0x08, 3); // SW = PLL
    assert_eq!((r.read(0x08) >> 2) & 3, 3, "SWS follows SW");
    r
}

#[test]
fn clock_tree_gives_80_mhz_from_msi_through_the_pll() {
    let r = rcc_at_80_mhz();
    let c = r.clocks();
    assert_eq!(c.sysclk, 80_000_000);
    assert_eq!(c.hclk, 80_000_000);
    assert!(r.errors.is_empty(), "{:?}", r.errors);
}

#[test]
fn pll_with_its_input_below_4_mhz_never_locks() {
    let mut r = Rcc::power_on();
    r.write(0x0C, 1 | (20 << 8) | (1 << 24)); // 4 MHz × 20 = 80 MHz VCO: fine
    r.write(0x00, r.read(0x00) | (1 << 24));
    assert!(r.errors.is_empty(), "{:?}", r.errors);
    let mut r = Rcc::power_on();
    r.write(0x0C, 1 | (3 << 4) | (20 << 8)); // 4 MHz / 4 = 1 MHz input: below 4 MHz
    r.write(0x00, r.read(0x00) | (1 << 24));
    assert_eq!(r.read(0x00) & (1 << 25), 0, "PLLRDY stays clear");
    assert_eq!(r.errors.len(), 1, "{:?}", r.errors);
}

#[test]
fn backup_domain_needs_dbp() {
    let mut r = Rcc::power_on();
    r.write(0x90, 1); // LSEON without PWR_CR1.DBP: lost
    assert_eq!(r.read(0x90), 0);
    r.pwr_write(0x00, r.pwr_read(0x00) | (1 << 8));
    r.write(0x90, 1);
    assert_eq!(r.read(0x90) & 3, 3, "LSEON, LSERDY");
}

/// Calibrate the ADC (regulator on, ADCAL) with the RCC as given; whether ADCAL cleared after
/// 1 ms.
fn calibrates(rcc: &Rcc) -> bool {
    let mut adc = Adc::default();
    let mut io = no_io();
    adc.write(0x08, 1 << 28, 0, rcc, &mut io); // DEEPPWD off, ADVREGEN
    adc.write(0x08, (1 << 28) | (1 << 31), 0, rcc, &mut io); // ADCAL
    adc.read(0x08, MS, &mut io) & (1 << 31) == 0
}

#[test]
fn adc_calibrates_only_with_a_kernel_clock() {
    let mut rcc = rcc_at_80_mhz();
    rcc.write(0x4C, 1 << 13); // AHB2ENR.ADCEN
                              // CCIPR.ADCSEL = 00: "no clock selected" (§6.4.28), ADC_CCR.CKMODE = 00 (asynchronous)
    assert!(!calibrates(&rcc), "ADCAL must stay set without a clock");
    rcc.write(0x88, 3 << 28); // ADCSEL = SYSCLK
    assert!(calibrates(&rcc), "116 ADC cycles at 80 MHz are 1.45 µs");
    // the bus clock off: nothing progresses either
    rcc.write(0x4C, 0);
    assert!(!calibrates(&rcc));
}

fn unlock(f: &mut FlashCtl, store: &mut StoreFlash) {
    f.write(0x08, 0x4567_0123, 0, store);
    f.write(0x08, 0xCDEF_89AB, 0, store);
    assert_eq!(f.read(0x14, 0) & (1 << 31), 0, "unlocked");
    f.write(0x14, 1, 0, store); // PG
}

#[test]
fn flash_programs_double_words_and_tears_on_a_power_cut() {
    let mut f = FlashCtl::reset();
    let mut store = Box::new(StoreFlash::new());
    f.write(0x00, 0x200, 0, &mut store); // DCEN off: read the array
    unlock(&mut f, &mut store);
    f.program_word(STORE_BASE, 0x1122_3344, 0, &mut store);
    f.program_word(STORE_BASE + 4, 0x5566_7788, 0, &mut store);
    assert_ne!(f.read(0x10, 0) & (1 << 16), 0, "BSY while programming");
    assert_eq!(f.read(0x10, MS) & (1 << 16), 0, "done after 82 µs");
    let (v, fx) = f.read_store(STORE_BASE, 4, &mut store);
    assert_eq!(v, 0x1122_3344);
    assert!(!fx.nmi);
    // programming the same double word again: PROGERR
    f.program_word(STORE_BASE, 1, MS, &mut store);
    f.program_word(STORE_BASE + 4, 2, MS, &mut store);
    assert_ne!(f.read(0x10, 2 * MS) & (1 << 3), 0, "PROGERR");
    // a power cut during the next programming tears its double word: reading it is a double
    // ECC error with the NMI and its address in ECCR (§3.3.4)
    store.ops_until_cut = Some(0);
    f.program_word(STORE_BASE + 8, 0xAAAA_5555, 2 * MS, &mut store);
    f.program_word(STORE_BASE + 12, 0x5555_AAAA, 2 * MS, &mut store);
    assert!(f.power_lost);
    let (_, fx) = f.read_store(STORE_BASE + 8, 4, &mut store);
    assert!(fx.nmi, "double ECC error raises the NMI");
    assert_ne!(f.read(0x18, 3 * MS) & (1 << 31), 0, "ECCR.ECCD");
    assert_eq!(
        f.read(0x18, 3 * MS) & 0x7_FFFF,
        STORE_BASE + 8 - 0x0808_0000
    );
}

#[test]
fn data_cache_left_on_across_programming_reads_stale_data() {
    let mut f = FlashCtl::reset(); // ICEN, DCEN on at reset
    let mut store = Box::new(StoreFlash::new());
    let (v, _) = f.read_store(STORE_BASE, 4, &mut store);
    assert_eq!(v, 0xFFFF_FFFF, "erased, now cached");
    unlock(&mut f, &mut store);
    f.program_word(STORE_BASE, 0, 0, &mut store);
    f.program_word(STORE_BASE + 4, 0, 0, &mut store);
    let (v, _) = f.read_store(STORE_BASE, 4, &mut store);
    assert_eq!(
        v, 0xFFFF_FFFF,
        "ES0250: the line cached before programming is stale"
    );
    assert_eq!(f.stale_reads, 1);
    // DCEN off, DCRST: the next read sees the array
    f.write(0x00, 0x200, MS, &mut store);
    f.write(0x00, 0x200 | (1 << 12), MS, &mut store);
    f.write(0x00, 0x600, MS, &mut store);
    let (v, _) = f.read_store(STORE_BASE, 4, &mut store);
    assert_eq!(v, 0);
}

#[test]
fn timer_compare_and_update_events_at_the_prescaled_clock() {
    let mut t = Timer::default();
    let clk = 80_000_000; // 1 MHz ticks with PSC 79
    t.write(0x28, 79, 0, clk, true);
    t.write(0x14, 1, 0, clk, true); // UG loads PSC
    t.write(0x10, 0, 0, clk, true);
    t.write(0x34, 0x8000, 0, clk, true);
    t.write(0x0C, 0b11, 0, clk, true); // UIE, CC1IE
    t.write(0x00, 1, 0, clk, true); // CEN
    let tick_ps = 1_000_000;
    assert_eq!(t.read(0x24, 1000 * tick_ps, clk, true), 1000);
    assert_eq!(t.next_event(clk, true), Some(0x8000 * tick_ps));
    assert_eq!(t.read(0x10, 0x7FFF * tick_ps, clk, true) & 2, 0);
    assert_ne!(
        t.read(0x10, 0x8000 * tick_ps, clk, true) & 2,
        0,
        "CC1IF at CNT = CCR1"
    );
    assert_ne!(
        t.read(0x10, 0x1_0000 * tick_ps, clk, true) & 1,
        0,
        "UIF at the wrap"
    );
    assert!(t.irq());
}

#[test]
fn nvic_takes_the_highest_priority_that_beats_the_running_one() {
    let mut n = Nvic::default();
    let (a, b) = (exc::IRQ0 + 24, exc::IRQ0 + 67);
    n.enabled[a] = true;
    n.enabled[b] = true;
    n.priority[a] = 0x20;
    n.priority[b] = 0x10;
    n.pending[a] = true;
    n.pending[b] = true;
    assert_eq!(n.next_exception(false, 0), Some(b), "0x10 beats 0x20");
    assert_eq!(n.next_exception(true, 0), None, "PRIMASK masks both");
    assert_eq!(
        n.next_exception(false, 0x20),
        Some(b),
        "BASEPRI 0x20 masks 0x20, not 0x10"
    );
    n.active.push(b);
    n.pending[b] = false;
    assert_eq!(
        n.next_exception(false, 0),
        None,
        "0x20 does not preempt 0x10"
    );
    n.pending[exc::NMI] = true;
    assert_eq!(
        n.next_exception(true, 0),
        Some(exc::NMI),
        "NMI ignores PRIMASK"
    );
    assert!(n.wfi_wake(0));
}

/// A stage controller that answers every byte with two bytes.
struct Echo;

impl nanocal_stm32_board::UartPeer for Echo {
    fn byte_from_board(&mut self, b: u8, _now_s: f64) -> Vec<u8> {
        vec![b, b'\n']
    }
}

#[test]
fn uart_bytes_take_a_frame_each_and_an_unread_byte_overruns() {
    use nanocal_stm32_board::periph::Usart;
    let mut io = Io::new(
        Arc::new(Mutex::new(NoChips)),
        Some(Box::new(Echo)),
        usb::Host::placeholder(),
    );
    let hz = 80_000_000;
    let mut u = Usart::default();
    u.write(0x0C, 694, 0, hz, &mut io); // BRR: 80 MHz / 694 = 115 274 Bd
    u.write(0x00, 1 | (1 << 2) | (1 << 3), 0, hz, &mut io); // UE, RE, TE
                                                            // baud = fCK / BRR (OVER8 = 0, RM0351 §40.5.4); a frame is 10 bits
    let frame_ps = 10 * 1_000_000_000_000u64 / (hz / 694);
    u.write(0x28, u32::from(b'A'), 0, hz, &mut io);
    // the byte is on the wire for one frame; the answer follows back to back
    assert_eq!(u.next_event(hz, &io), Some(frame_ps));
    u.update(frame_ps, hz, &mut io);
    assert_eq!(
        u.next_event(hz, &io),
        Some(2 * frame_ps),
        "first byte of the answer"
    );
    u.update(2 * frame_ps, hz, &mut io);
    assert_eq!(
        u.read(0x1C, 2 * frame_ps, hz, &mut io) & (1 << 5),
        1 << 5,
        "RXNE"
    );
    // RDR not read: the second byte of the answer overruns (ORE), RDR keeps the first
    u.update(3 * frame_ps, hz, &mut io);
    let isr = u.read(0x1C, 3 * frame_ps, hz, &mut io);
    assert_eq!(isr & (1 << 3), 1 << 3, "ORE");
    assert_eq!(u.read(0x24, 3 * frame_ps, hz, &mut io), u32::from(b'A'));
    assert_eq!(u.overruns, 1);
    // an injected overrun loses a byte that would have been read in time
    u.write(0x20, 1 << 3, 3 * frame_ps, hz, &mut io); // ORECF
    io.uart_rx.lose_in = Some(0);
    u.write(0x28, u32::from(b'B'), 3 * frame_ps, hz, &mut io);
    u.update(5 * frame_ps, hz, &mut io);
    assert_eq!(u.overruns, 2, "'B' lost");
    u.update(6 * frame_ps, hz, &mut io);
    assert_eq!(u.read(0x24, 6 * frame_ps, hz, &mut io), u32::from(b'\n'));
}

#[test]
fn the_clock_pauses_at_the_horizon_and_on_output() {
    use nanocal_stm32_board::Clock;
    let clock = Arc::new(Clock::default());
    let c = clock.clone();
    // a "board" that moves 1 ms at a time up to the horizon, and holds after 5 ms (output)
    let t = std::thread::spawn(move || {
        let mut now = 0u64;
        loop {
            if now >= c.horizon_ps() {
                if !c.pause(now, None) {
                    return now;
                }
                continue;
            }
            now += MS;
            if now == 5 * MS {
                c.hold_at(now);
            }
        }
    });
    assert_eq!(clock.wait_paused(0).now_ps, 0, "starts paused at 0");
    assert_eq!(clock.run_to(10 * MS).now_ps, 5 * MS, "paused on its output");
    assert_eq!(clock.run_to(10 * MS).now_ps, 10 * MS);
    assert_eq!(clock.run_to(3 * MS).now_ps, 10 * MS, "never back");
    clock.stop(0);
    assert_eq!(t.join().unwrap(), 10 * MS);
}
