//! Faults on the emulated B-L475E-IOT01A and what the shipped image does about them (issue 16,
//! defects 3, 7, 8, 9): a double ECC error in its own flash, torn double words in the store, a
//! panic, a wedged stage link, an SPI transfer that never ends, a baud rate UART4 cannot make.
//! Every bound is board time.

mod stm32_sim;

use embassy_futures::block_on;
use nanocal::device::DeviceError;
use nanocal::published::published_1dof;
use nanocal_compensator::l4flash::L4Nor;
use nanocal_compensator::store::Store;
use nanocal_interface::identity::ResetCause;
use nanocal_interface::mgmt::{Refusal, Request};
use nanocal_interface::settings::Settings;
use nanocal_interface::status::ChannelStatus;
use nanocal_model::blob;
use nanocal_stm32_board::flash::StoreFlash;
use nanocal_stm32_board::ResetKind;
use stm32_sim::{default_buses, e727, panic_location, section, symbol_containing, Stm32};

const TEMPS_C: [f32; 4] = [22.0, 22.125, 21.875, 22.25];

/// Defect 3: a double ECC error in the firmware's constants (bank 1) is no torn write of the
/// store: nothing read there can be trusted, so the board resets — and says why and where. (The
/// NMI handler used to clear ECCD and return for every double error: the board went on with a
/// corrupt constant.)
#[test]
fn stm32_ecc_error_in_the_firmware_flash_resets_and_is_reported() {
    let b = Stm32::start(default_buses(&TEMPS_C));
    b.usb.attach();
    b.mgmt().status().expect("up");
    let (rodata, size) = section(".rodata");
    b.inject(|i| i.ecc_in = Some(rodata..rodata + size));
    let s = b.run_until("a reset after the double ECC error", 1.0, |s| {
        s.boots.len() > 1
    });
    assert_eq!(s.ecc_errors, 1, "{:?}", s.log);
    assert_eq!(
        s.boots[1].kind,
        ResetKind::Software,
        "reset at once: {:?}",
        s.log
    );
    let h = b.mgmt().identify().unwrap();
    assert_eq!(h.reset_cause, ResetCause::FlashEcc);
    let addr = u32::from_str_radix(h.reset_site.trim_start_matches("0x"), 16)
        .unwrap_or_else(|_| panic!("site {:?}", h.reset_site));
    assert!(
        (rodata..rodata + size).contains(&addr),
        "{addr:#x} is in .rodata ({rodata:#x}+{size:#x})"
    );
}

/// Defect 3: torn double words of the store (a power cut in the middle of a write) are read
/// as corrupt, the board goes on, and the status counts them (`flash_ecc_errors` was never
/// fed: always 0).
#[test]
fn stm32_torn_store_double_words_are_counted_in_the_status() {
    let model = published_1dof().unwrap();
    let mut bytes = vec![0u8; blob::MAX_BLOB_LEN];
    let n = blob::encode(&model, &mut bytes).unwrap();
    let mut base = StoreFlash::new();
    block_on(Store::new(L4Nor::<_, 8192>::new(&mut base)).save_model(&bytes[..n])).unwrap();
    // a second save cut in its middle, where the boot's reads meet the torn double word (found
    // with the store's own code on the host)
    let sim = (0..40)
        .find_map(|cut| {
            let mut sim = base.clone_sim();
            sim.ops_until_cut = Some(cut);
            let _ = block_on(Store::new(L4Nor::<_, 8192>::new(&mut sim)).save_model(&bytes[..n]));
            sim.power_on();
            let mut probe = sim.clone_sim();
            let mut st = Store::new(L4Nor::<_, 8192>::new(&mut probe));
            let mut buf = [0u8; 256];
            let _ = block_on(st.load_settings(&mut buf));
            let _ = block_on(st.load_model_with(|_| ()));
            (st.flash().ecc_errors > 0).then_some(sim)
        })
        .expect("a cut whose torn double word the boot reads");
    let b = Stm32::start_with(default_buses(&TEMPS_C), e727(), Some(Box::new(sim)));
    b.usb.attach();
    let s = b.mgmt().status().unwrap();
    assert_eq!(s.model_id, model.id(), "the complete model is in service");
    assert!(
        s.flash_ecc_errors > 0,
        "torn double words read: {}",
        s.flash_ecc_errors
    );
    let st = b.status();
    // the firmware reads a double word as two 32-bit words, and each read of a torn one raises
    // the NMI; it counts the double word once: no count without an NMI, no NMI uncounted
    let counted = u64::from(s.flash_ecc_errors);
    assert!(
        (counted..=2 * counted).contains(&st.ecc_errors),
        "{} NMIs for {counted} torn double words read",
        st.ecc_errors
    );
    assert_eq!(st.boots.len(), 1, "no reset: {:?}", st.log);
}

/// Defect 8: a panic is reported as a panic, with its source line (it was "independent
/// watchdog", the UDF it ends in looping until the IWDG fired). The panic is a bounds check
/// failing at a real panic site of the image (`core::panicking::panic_bounds_check` called
/// with that site's `Location`).
#[test]
fn stm32_panic_is_reported_with_its_site() {
    let b = Stm32::start(default_buses(&TEMPS_C));
    b.usb.attach();
    b.mgmt().status().expect("up");
    let (loc, line) = panic_location("src/bin/stm32.rs");
    let panic_bounds_check = symbol_containing("panic_bounds_check");
    b.inject(|i| i.call = Some((panic_bounds_check, [5, 3, loc, 0])));
    let s = b.run_until("the reset after the panic", 1.0, |s| s.boots.len() > 1);
    assert_eq!(
        s.boots[1].kind,
        ResetKind::Software,
        "reset at once: {:?}",
        s.log
    );
    let h = b.mgmt().identify().unwrap();
    assert_eq!(h.reset_cause, ResetCause::Panic);
    assert_eq!(h.reset_site.as_str(), format!("src/bin/stm32.rs:{line}"));
    // the record is read once: the next reset reports its own cause
    b.mgmt().reset().unwrap();
    b.run_until("the software reset", 1.0, |s| s.boots.len() > 2);
    let h = b.mgmt().identify().unwrap();
    assert_eq!(
        (h.reset_cause, h.reset_site.as_str()),
        (ResetCause::Software, "")
    );
}

/// Defect 8: a wedged link task is caught. UART4's transmitter stops (TXE never sets again):
/// the stage link's write waits for ever, the host link behind it too; the supervisor sees
/// the stage link busy past its limit, stops petting the IWDG, and the board resets with
/// RCC_CSR saying so (it stayed wedged, moves never reaching the controller, the watchdog fed
/// by a healthy sensor task).
#[test]
fn stm32_wedged_stage_link_resets_through_the_watchdog() {
    let b = Stm32::start(default_buses(&TEMPS_C));
    b.usb.attach();
    let mut host = b.gcs();
    host.send("*IDN?");
    assert!(host.read_line().contains("E-727"));
    b.inject(|i| i.uart_tx_stall = true);
    for _ in 0..60 {
        host.send("POS? 1");
    }
    let s = b.run_until("a watchdog reset of the wedged board", 10.0, |s| {
        s.boots.len() > 1
    });
    assert_eq!(s.boots[1].kind, ResetKind::Watchdog, "{:?}", s.log);
    drop(host);
    let h = b.mgmt().identify().unwrap();
    assert_eq!(h.reset_cause, ResetCause::Watchdog);
    // and the link works again after the reset
    let mut host = b.gcs();
    assert!(host.ask("*IDN?").contains("E-727"));
}

/// Defect 7: an SPI transfer that never ends (SCK stopped) times out after 20 ms; the
/// chip-select it pulled low must go high again, or the next transaction selects two chips at
/// once (the dropped future left the pin low).
#[test]
fn stm32_spi_timeout_releases_the_chip_select() {
    let b = Stm32::start(default_buses(&TEMPS_C));
    b.usb.attach();
    let mut c = b.mgmt();
    b.status_until(&mut c, "the first conversions", 2.0, |s| {
        s.sensor_bits[..4]
            .iter()
            .all(|x| x.state == ChannelStatus::Ok)
    });
    b.inject(|i| i.spi_stall = true);
    // several sample periods: every transaction times out
    let s = b.run_for(1.0);
    assert_eq!(s.cs_conflicts, 0, "chip-selects low together: {:?}", s.log);
    // the stalled chips fail after the fault policy's hold time; nothing else breaks
    b.status_until(&mut c, "the sensors failed", 7.0, |s| {
        s.sensor_bits[..4]
            .iter()
            .all(|x| x.state == ChannelStatus::Failed)
    });
    assert_eq!(b.status().cs_conflicts, 0);
    assert_eq!(b.status().boots.len(), 1);
}

/// Defect 9: UART4 divides its 80 MHz kernel clock by at most 65 535 and has no prescaler:
/// 1 200 Bd is out of its reach. The device refuses it (it accepted it, and the next boot
/// could not configure the UART: a panic at every boot); 2 400 Bd works after the reset.
#[test]
fn stm32_stage_baud_rates_the_uart_cannot_make_are_refused() {
    let b = Stm32::start(default_buses(&TEMPS_C));
    b.usb.attach();
    let mut c = b.mgmt();
    let mut s: Settings = c.config().unwrap();
    s.stage_baud = 1200;
    // bypass the host's own check: the device must refuse by itself
    let e = c.request(&Request::ConfigSet(s)).unwrap_err();
    assert!(
        matches!(
            e,
            DeviceError::Refused {
                refusal: Refusal::Settings,
                ..
            }
        ),
        "{e}"
    );
    assert_eq!(c.config().unwrap().stage_baud, 115_200, "nothing stored");
    s.stage_baud = 2400;
    c.set_config(&s).unwrap();
    c.reset().unwrap();
    drop(c);
    b.run_until("the reset", 1.0, |st| st.boots.len() > 1);
    let mut host = b.gcs();
    assert!(host.ask("*IDN?").contains("E-727"));
    let baud = b.status().stage_baud;
    assert!((2376..=2424).contains(&baud), "UART4 at {baud} Bd");
}
