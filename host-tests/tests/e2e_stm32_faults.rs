//! Faults on the emulated B-L475E-IOT01A and what the shipped image does about them (issue 16,
//! defects 3, 5, 6, 7, 8, 9): a double ECC error in its own flash, torn double words in the
//! store, a stage-link byte lost to an overrun, a GCS port closed with replies on their way or
//! closed and opened again at once, a panic, a wedged stage link, an SPI transfer that never
//! ends, a baud rate UART4 cannot make. Every bound is board time.

mod stm32_sim;

use embassy_futures::block_on;
use nanocal::device::DeviceError;
use nanocal::papers::published::published_1dof;
use nanocal_compensator::l4flash::L4Nor;
use nanocal_compensator::store::Store;
use nanocal_interface::identity::ResetCause;
use nanocal_interface::mgmt::{self, Kind, Refusal, Request};
use nanocal_interface::settings::Settings;
use nanocal_interface::status::ChannelStatus;
use nanocal_interface::status::Flags;
use nanocal_model::{blob, SlowInputs, MAX_AXES};
use nanocal_stm32_board::flash::StoreFlash;
use nanocal_stm32_board::ResetKind;
use stm32_sim::{
    default_buses, e727, panic_location, section, stage_value, symbol_containing, Stm32, FOLD_S,
};

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
/// by a healthy sensor task). End to end: the starved IWDG resets the emulated chip, the boot
/// runs again, reads IWDGRSTF in RCC_CSR and reports a watchdog reset; the stored settings are
/// kept.
#[test]
fn stm32_wedged_stage_link_resets_through_the_watchdog() {
    let b = Stm32::start(default_buses(&TEMPS_C));
    b.usb.attach();
    let mut c = b.mgmt();
    let mut settings: Settings = c.config().unwrap();
    settings.fold_period_ms = 2_000;
    settings.sample_period_ms = 250;
    c.set_config(&settings).unwrap();
    drop(c);
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
    let mut c = b.mgmt();
    let h = c.identify().unwrap();
    assert_eq!(h.reset_cause, ResetCause::Watchdog);
    assert_eq!(
        c.config().unwrap(),
        settings,
        "settings kept over the reset"
    );
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

/// The published 1-DOF model uploaded and folded with the sensors' first conversions.
fn with_model(b: &Stm32) -> nanocal_model::Model {
    let model = published_1dof().unwrap();
    let mut bytes = vec![0u8; blob::MAX_BLOB_LEN];
    let n = blob::encode(&model, &mut bytes).unwrap();
    let mut c = b.mgmt();
    c.upload(&bytes[..n]).expect("model accepted");
    b.status_until(&mut c, "sensors read and model folded", 5.0 + FOLD_S, |s| {
        s.flags.contains(Flags::MODEL) && !s.flags.contains(Flags::SENSOR_BLOCK) && s.folds >= 2
    });
    model
}

/// The corrected command the f64 reference gives for target `x_um` approached in `dir`.
fn corrected(model: &nanocal_model::Model, x_um: f64, dir: i8) -> f64 {
    let mut s = SlowInputs::default();
    for (i, t) in TEMPS_C.iter().enumerate() {
        s.temps_c[i] = f64::from(*t);
    }
    let mut d = [0; MAX_AXES];
    d[0] = dir;
    model.eval_f64(&[x_um, 0.0, 0.0], &d, &s)[0]
}

/// The next `MOV` the controller receives (the first move's queries of the controller's facts
/// and their markers skipped).
fn next_move(b: &Stm32) -> String {
    loop {
        let line = b.stage_line(1.0);
        if line.starts_with("MOV ") {
            return line;
        }
        assert!(
            ["*IDN?", "CSV?", "SAI?"].contains(&line.as_str())
                || ["PUN? ", "TMN? ", "TMX? "]
                    .iter()
                    .any(|q| line.starts_with(q)),
            "unexpected {line:?}"
        );
    }
}

/// Defect 5: a stage-link byte lost to a UART overrun (RDR not read in time, RM0351 §40.5.5
/// ORE) in the reply to the proxy's own `MOV?` — the one an `MVR` takes its base from. Read as
/// it arrives, "1=100.00…" without its third byte is "1=00.00…": the move would go out from a
/// base of 0 µm (the overrun was only logged). The loss must be seen: the proxy lets the line
/// go past a marker's reply, asks `MOV?` afresh, moves from the controller's real target, and
/// the host's next `ERR?` says 9010 (LinkLost).
#[test]
fn stm32_stage_byte_lost_to_an_overrun_never_moves_from_a_wrong_base() {
    let b = Stm32::start(default_buses(&TEMPS_C));
    b.usb.attach();
    let model = with_model(&b);
    let mut host = b.gcs();
    host.send("MOV 1 100");
    let first = stage_value(&next_move(&b), "1");
    assert!((first - corrected(&model, 100.0, 0)).abs() <= 1e-4);
    // a new host session forgets the targets the old one set: the MVR asks for its base
    drop(host);
    let mut host = b.gcs();
    b.stage.drain();
    b.inject(|i| i.uart_lose_byte = Some(2));
    host.send("MVR 1 12.5");
    assert_eq!(b.stage_line(1.0), "MOV? 1");
    // the reply lost a byte: the proxy gives up what it asked, resynchronises with a marker
    // of its own (`*IDN?`: every reply before the marker's is dropped) and asks again — the
    // move goes out from the controller's real target or not at all
    let mut after = vec![];
    while after.last().is_none_or(|l: &String| !l.starts_with("MOV ")) {
        after.push(b.stage_line(1.0));
    }
    assert_eq!(after[..after.len() - 1], ["*IDN?", "MOV? 1"], "{after:?}");
    let got = stage_value(after.last().unwrap(), "1");
    let want = corrected(&model, 112.5, 1);
    assert!(
        (got - want).abs() <= 1e-4,
        "MVR from 100 µm: forwarded {got}, f64 {want}"
    );
    let st = b.status();
    assert_eq!(st.uart_overruns, 1, "{:?}", st.log);
    // the host is told the link lost bytes
    assert_eq!(host.ask("ERR?"), "9010");
    assert_eq!(host.ask("ERR?"), "0");
    assert_eq!(b.status().boots.len(), 1);
}

/// Defect 6: the host drops and raises the GCS port's DTR at once (1 → 0 → 1: two
/// SET_CONTROL_LINE_STATE requests back to back, the second right after the first's status
/// stage). The new session starts clean: the half line the old one sent is gone.
///
/// The firmware's USB task answers each request, and the line-state task looks at the result
/// when it runs next. It misses the 0 when it runs only after both requests: here a STATUS
/// request on the management port arrives in the same frame, just before the first, and the
/// executor runs the management task (a frame's decode, status and reply: ~20,000
/// instructions, ~250 µs at 80 MHz) right after the USB task answered the first — long enough
/// for the host to finish that transfer and send the second, and the USB task, woken last,
/// runs first in the executor's next round. (DTR was sampled as a level: the line-state task
/// saw 1 and 1, and the half line prefixed the new session's first query.)
#[test]
fn stm32_quick_close_and_reopen_of_the_gcs_port_starts_a_new_session() {
    use std::io::{Read, Write};
    let b = Stm32::start(default_buses(&TEMPS_C));
    b.usb.attach();
    let mut host = b.gcs();
    let mut mgmt_port = b.port(1);
    assert!(host.ask("*IDN?").contains("E-727"));
    b.stage.drain();
    host.send_raw(b"SVO 1 0");
    b.run_for(0.01);
    let before = b.usb.line_states(0);
    // while the board is paused: the management request, then the DTR pulse (both leave the
    // host in its next frame, the bulk OUT packet first)
    let mut frame = [0u8; mgmt::MAX_FRAME];
    let n = mgmt::encode(Kind::Status.code(), 7, &[], &mut frame).unwrap();
    mgmt_port.write_all(&frame[..n]).unwrap();
    b.usb.toggle_dtr(0);
    let usb = b.usb.clone();
    b.run_until("the close and the open", 1.0, move |_| {
        usb.line_states(0) >= before + 2
    });
    // the management request was answered
    let mut reply = vec![];
    while reply.len() < mgmt::OVERHEAD
        || reply.len() < mgmt::OVERHEAD + usize::from(u16::from_le_bytes([reply[4], reply[5]]))
    {
        let mut buf = [0u8; 64];
        let n = mgmt_port.read(&mut buf).expect("the STATUS reply");
        reply.extend_from_slice(&buf[..n]);
    }
    assert_eq!((reply[2], reply[3]), (Kind::Status.code() | mgmt::REPLY, 7));
    // the new session's first query reaches the controller alone, and is answered
    host.send("*IDN?");
    assert_eq!(b.stage_line(1.0), "*IDN?", "the half line was dropped");
    assert!(host.read_line().contains("E-727"));
    assert_eq!(b.stage.drain(), [] as [&str; 0]);
}

/// Defect 6: a reply the device queued on the GCS port's IN endpoint while the host was not
/// reading is the old connection's: after a close and a reopen the new connection's first
/// query gets its own reply, not the old one (the packet stayed in the endpoint's FIFO).
#[test]
fn stm32_reply_queued_at_close_is_not_read_after_reopen() {
    let b = Stm32::start(default_buses(&TEMPS_C));
    b.usb.attach();
    let mut host = b.gcs();
    assert!(host.ask("*IDN?").contains("E-727"));
    b.stage.drain();
    b.usb.set_reading(0, false);
    host.send("POS? 1");
    assert_eq!(b.stage_line(1.0), "POS? 1");
    b.run_for(0.05);
    drop(host);
    b.usb.set_reading(0, true);
    let mut host = b.gcs();
    let reply = host.ask("*IDN?");
    assert!(
        reply.contains("E-727"),
        "first reply after reopen: {reply:?}"
    );
}

/// Defect 6: the controller's reply to a query of the old connection, still on its way when
/// the host closes the port, is not the answer to the new connection's first query.
#[test]
fn stm32_reply_in_flight_at_close_is_not_paired_with_the_next_session() {
    let b = Stm32::start(default_buses(&TEMPS_C));
    b.usb.attach();
    let mut host = b.gcs();
    assert!(host.ask("*IDN?").contains("E-727"));
    host.send("POS? 1");
    // close as soon as the query has reached the controller: its reply is on the wire
    while !b.stage.all().iter().any(|l| l == "POS? 1") {
        b.run_for(0.0001);
    }
    drop(host);
    let mut host = b.gcs();
    let reply = host.ask("*IDN?");
    assert!(
        reply.contains("E-727"),
        "first reply after reopen: {reply:?}"
    );
    assert_eq!(host.ask("ERR?"), "0");
}
