//! The QEMU firmware on the virtual bench with register-level chips: what a real bench does to
//! a board that the first firmware did not survive. Each test names the defect it catches.
//!
//! Skipped with a loud message without qemu-system-arm, except in CI (`CI` set).

mod fw_sim;

use fw_sim::{wait_until, BenchClock, Qemu, SensorSim, StageSim, HANG};
use nanocal::virtual_bench::chips::Max31856;
use nanocal_interface::bench_link as bl;
use nanocal_interface::identity::ResetCause;
use nanocal_interface::mgmt::{Refusal, Request};
use nanocal_interface::settings::AuxSource;
use nanocal_interface::status::{ChannelStatus, Flags, SensorFault};
use nanocal_model::{blob, Factor, Input, Model, ModelBuilder};
use std::time::Duration;

const TEMPS_C: [f32; 4] = [22.0, 22.125, 21.875, 22.25];

fn blob_of(m: &Model) -> Vec<u8> {
    let mut b = vec![0u8; blob::MAX_BLOB_LEN];
    let n = blob::encode(m, &mut b).unwrap();
    b.truncate(n);
    b
}

/// 1 axis, temperature 0 and air pressure (aux 0).
fn pressure_model() -> Model {
    let mut b = ModelBuilder::new(1, 1, 1)
        .unwrap()
        .id(0x0002_0001)
        .trained_range(Input::Axis(0), 0.0, 500.0)
        .trained_range(Input::Temp(0), 20.0, 24.0)
        .trained_range(Input::Aux(0), 950.0, 1050.0)
        .travel_um(0, -10.0, 510.0);
    b.add_raw_term(0, [1, 0, 0], Factor::None, 0, 1.0).unwrap();
    b.add_raw_term(0, [0; 3], Factor::Temp(0), 0, 0.1).unwrap();
    b.add_raw_term(0, [0; 3], Factor::Aux(0), 0, 0.002).unwrap();
    b.build().unwrap()
}

#[test]
fn e2e_first_conversion_absent_chip_brownout_and_dead_bus() {
    let Some(mut q) = Qemu::start_or_skip("e2e_first_conversion_absent_chip_brownout_and_dead_bus")
    else {
        return;
    };
    let clk = q.clock();
    let _stage = StageSim::start(q.connect(1), 1);
    let sensors = SensorSim::start(q.link(), &TEMPS_C);
    let mut host = q.gcs_host();
    let mut c = q.client();
    let model = nanocal::papers::published::published_1dof().unwrap();
    c.upload(&blob_of(&model)).unwrap();
    // defect: moves went out before the sensors' first conversions (fold at 0 °C). A move
    // right after the upload is either refused (no fold of the new model yet) or corrected
    // with the real temperatures — whenever the first fold happens to end, which the test does
    // not race: it checks what went out against what the status says corrected it.
    host.send("MOV 1 10");
    match host.ask("ERR?").as_str() {
        "9002" | "9003" => {}
        "0" => {
            let fwd = fw_sim::next_move(&_stage);
            let s = c.status().unwrap();
            assert!(s.move_fold >= 1, "a move before the first fold: {fwd}");
            let mut slow = nanocal_model::SlowInputs::default();
            for (i, t) in TEMPS_C.iter().enumerate() {
                slow.temps_c[i] = f64::from(*t);
            }
            let want = model.eval_f64(&[10.0, 0.0, 0.0], &[0; 3], &slow)[0];
            let got = fw_sim::stage_value(&fwd, "1");
            assert!(
                (got - want).abs() < 1e-4,
                "the first move used the sensors' readings: {got} vs {want}"
            );
        }
        e => panic!("MOV 1 10 right after the upload: error {e}"),
    }
    let s = wait_until("first conversions", &clk, 20.0, || {
        let s = c.status().ok()?;
        (!s.flags.intersects(Flags::WARMING_UP | Flags::SENSOR_BLOCK) && s.folds >= 1).then_some(s)
    });
    for (i, t) in TEMPS_C.iter().enumerate() {
        assert_eq!(
            s.temps_c[i], *t,
            "sensor {i}: the first fold uses real readings"
        );
    }
    let conversions = sensors.buses().spi_mut::<Max31856>(0).conversions;
    assert!(
        conversions >= 1,
        "the simulated chip converted ({conversions})"
    );

    // defect: an absent chip (MISO pull-up: FFh) decoded as a temperature
    let chip = sensors.unplug(2).unwrap();
    let s = wait_until("absent chip fails", &clk, 30.0, || {
        let s = c.status().ok()?;
        (s.sensor_bits[2].state == ChannelStatus::Failed).then_some(s)
    });
    assert!(s.temps_c[2].is_nan());
    assert_eq!(
        s.sensor_bits[2].last_fault,
        Some(SensorFault::NoResponse),
        "no response"
    );
    assert!(s.flags.contains(Flags::SENSOR_BLOCK));
    host.send("MOV 1 20");
    assert_eq!(host.ask("ERR?"), "9002");
    // hot-plug: the chip comes back at power-on defaults and is configured again
    sensors.plug(2, chip);
    wait_until("hot-plugged chip back", &clk, 30.0, || {
        let s = c.status().ok()?;
        (!s.flags.contains(Flags::SENSOR_BLOCK)).then_some(())
    });

    // defect: configured once, never checked; a brown-out left the chip unconfigured
    let before = c.status().unwrap().sensor_reconfigs;
    sensors.brownout(1);
    wait_until("reconfiguration after a brown-out", &clk, 30.0, || {
        let s = c.status().ok()?;
        (s.sensor_reconfigs > before && s.sensor_bits[1].state == ChannelStatus::Ok).then_some(())
    });

    // defect: no SPI timeout and no hold-time check: a dead bus froze the fold for ever
    sensors.buses().dead = true;
    let s = wait_until("dead bus blocks moves", &clk, 40.0, || {
        let s = c.status().ok()?;
        (s.flags.contains(Flags::SENSOR_BLOCK)).then_some(s)
    });
    assert!(
        s.sensor_bits[..4]
            .iter()
            .all(|b| b.state == ChannelStatus::Failed),
        "{:?}",
        s.sensor_bits
    );
    host.send("MOV 1 30");
    assert_eq!(host.ask("ERR?"), "9002");
    sensors.buses().dead = false;
    wait_until("recovery", &clk, 40.0, || {
        let s = c.status().ok()?;
        (!s.flags.contains(Flags::SENSOR_BLOCK)).then_some(())
    });
}

#[test]
fn e2e_host_session_ends_when_the_port_closes() {
    // defect: when the host closed the port, what belonged to that connection (a half line,
    // a pending error, queued replies) came out on the next connection
    let Some(mut q) = Qemu::start_or_skip("e2e_host_session_ends_when_the_port_closes") else {
        return;
    };
    let clk = q.clock();
    let stage = StageSim::start(q.connect(1), 1);
    let _sensors = SensorSim::start(q.link(), &TEMPS_C);
    // the board is up (its store read, every task running) before the host opens the port
    let mut c = q.client();
    let connected = |c: &mut nanocal::device::Client| {
        c.status()
            .ok()
            .map(|st| st.flags.contains(Flags::HOST_CONNECTED))
    };
    let mut host = q.gcs_host();
    // a host raises DTR when it opens the port, before it writes anything
    q.set_dtr(true);
    wait_until("DTR seen", &clk, 10.0, || {
        connected(&mut c).filter(|&on| on)
    });
    // no model: a MOV leaves error 9003 pending for the next ERR?
    host.send("MOV 1 10");
    // and a half line
    host.send_raw(b"VEL 1 1");
    // the board has read both before the port closes (its byte count, not a wall-time guess)
    let sent = (b"MOV 1 10\n".len() + b"VEL 1 1".len()) as u32;
    wait_until("the board read the host's bytes", &clk, 10.0, || {
        (q.link().rx_bytes(0) == sent).then_some(())
    });
    q.set_dtr(false);
    wait_until("DTR fall seen", &clk, 10.0, || {
        connected(&mut c).filter(|&on| !on)
    });
    drop(host);
    q.set_dtr(true);
    wait_until("DTR seen again", &clk, 10.0, || {
        connected(&mut c).filter(|&on| on)
    });
    drop(c);
    let mut host = q.reconnect_gcs();
    host.send("SVO 1 1");
    assert_eq!(
        stage.next_line(HANG),
        "SVO 1 1",
        "the closed connection's half line did not join the new one"
    );
    assert_eq!(
        host.ask("ERR?"),
        "0",
        "no error carried over from the closed connection"
    );
}

#[test]
fn e2e_a_lockstep_board_boots_at_bench_time_zero_and_waits_for_the_bench() {
    // defect: a campaign's board booted on the free-running clock and was put in lockstep
    // later, so it booted at an instant the wall clock decided (35.4 or 35.9 ms in two runs):
    // every later sensor sample kept that phase, and two runs of one campaign recorded
    // different readings (issue 20 §5)
    let Some(q) = Qemu::start_lockstep_or_skip(
        "e2e_a_lockstep_board_boots_at_bench_time_zero_and_waits_for_the_bench",
    ) else {
        return;
    };
    let link = q.link();
    // no chips: every bus request is answered as a dead bus's, at once
    link.attach_bus(Box::new(|_, _, _, _, _| None));
    let page = link.page();
    let start = std::time::Instant::now();
    while page.u32(bl::BOOTS) == 0 {
        assert!(start.elapsed() < HANG, "the board did not boot");
        std::thread::sleep(Duration::from_millis(10));
    }
    // the wall clock runs on; the board's does not
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(page.u64(bl::BOOT_AT), 0, "booted at bench time 0");
    assert_eq!(page.u64(bl::NOW), 0, "no board time without the bench");
    let clock = BenchClock::new(link.clone());
    clock
        .advance_to(2.5, HANG)
        .expect("the board follows the bench");
    assert_eq!(page.u64(bl::NOW), bl::s_to_ticks(2.5));
}

#[test]
fn e2e_an_idle_board_spins_for_the_bench_only_when_let() {
    // what a campaign's core split relies on (`bench_link::IDLE_SPIN`, layout 7): a board let
    // spin takes the bench's next horizon awake; a board not let halts at once, as every board
    // of the test harness must (a spinning board would hold a core its bench needs)
    let Some(q) =
        Qemu::start_lockstep_or_skip("e2e_an_idle_board_spins_for_the_bench_only_when_let")
    else {
        return;
    };
    let link = q.link();
    link.attach_bus(Box::new(|_, _, _, _, _| None));
    let page = link.page();
    let clock = BenchClock::new(link.clone());
    let mut t_s = 0.1;
    clock
        .advance_to(t_s, HANG)
        .expect("the board follows the bench");
    // how often the bench found the board halted when it moved the horizon (and rang it)
    let horizon_rings_over_five_advances = |t_s: &mut f64, halted_first: bool| {
        let before = link.crossings().horizon_rings;
        for _ in 0..5 {
            if halted_first {
                let start = std::time::Instant::now();
                while page.u32(bl::HALTED) != 1 {
                    assert!(start.elapsed() < HANG, "the idle board never halted");
                    std::thread::sleep(Duration::from_millis(1));
                }
            } else {
                // far less than the spin, more than a board not let takes to halt
                std::thread::sleep(Duration::from_millis(5));
            }
            *t_s += 0.01;
            clock
                .advance_to(*t_s, HANG)
                .expect("the board follows the bench");
        }
        link.crossings().horizon_rings - before
    };
    assert_eq!(
        page.u32(bl::IDLE_SPIN),
        0,
        "a bench does not let it by default"
    );
    let not_let = horizon_rings_over_five_advances(&mut t_s, true);
    assert_eq!(not_let, 5, "idle at each horizon, it halted at once");
    // ≥ 0.1 s of spinning at each horizon (≥ 50 guest instructions a turn): more than the
    // 5 ms the bench pauses before its next advance, far less than the watchdog's 2 × 2 s of
    // QEMU's clock
    link.set_idle_spin(2_000_000);
    t_s += 0.01;
    clock
        .advance_to(t_s, HANG)
        .expect("the board follows the bench");
    let let_spin = horizon_rings_over_five_advances(&mut t_s, false);
    assert!(
        let_spin <= 1,
        "let spin, it takes the next horizons awake: rung {let_spin} times"
    );
}

#[test]
fn e2e_watchdog_resets_a_hung_firmware_and_settings_persist() {
    // defect: no watchdog: a hung firmware stayed hung with the last fold in use
    let Some(mut q) =
        Qemu::start_or_skip("e2e_watchdog_resets_a_hung_firmware_and_settings_persist")
    else {
        return;
    };
    // (no board-time bound here: a hung board's clock stands still; QEMU's watchdog counts)
    let _stage = StageSim::start(q.connect(1), 1);
    let _sensors = SensorSim::start(q.link(), &TEMPS_C);
    let mut c = q.client();
    let h = c.identify().unwrap();
    assert_eq!(h.reset_cause, ResetCause::PowerOn);
    assert!(!h.firmware.is_empty());
    // settings over management, stored
    let mut s = c.config().unwrap();
    s.sample_period_ms = 200;
    s.aux[0] = AuxSource::AirPressure;
    c.set_config(&s).unwrap();
    // the hang: the device never answers this one
    c.timeout = Duration::from_millis(500);
    assert!(c.request(&Request::DebugHang).is_err());
    drop(c);
    let mut c = q.client();
    let h = c.identify().unwrap();
    assert_eq!(
        h.reset_cause,
        ResetCause::Watchdog,
        "the watchdog reset the hung board"
    );
    let back = c.config().unwrap();
    assert_eq!(back, s, "settings survived the reset");
}

#[test]
fn e2e_model_inputs_must_be_supplied() {
    // issue 11: the firmware supplies every input a model uses or refuses it at upload
    let Some(mut q) = Qemu::start_or_skip("e2e_model_inputs_must_be_supplied") else {
        return;
    };
    let clk = q.clock();
    let stage = StageSim::start(q.connect(1), 1);
    let sensors = SensorSim::start(q.link(), &TEMPS_C);
    let mut host = q.gcs_host();
    let mut c = q.client();
    let model = pressure_model();
    let e = c.upload(&blob_of(&model)).unwrap_err();
    assert!(
        matches!(
            e,
            nanocal::device::DeviceError::Refused {
                refusal: Refusal::Input,
                ..
            }
        ),
        "{e}"
    );
    // the message names the input and the reason
    assert!(
        e.to_string()
            .contains(": input 0, aux input with no source"),
        "{e}"
    );
    assert!(
        !c.status().unwrap().flags.contains(Flags::MODEL),
        "nothing stored"
    );
    let mut s = c.config().unwrap();
    s.aux[0] = AuxSource::AirPressure;
    c.set_config(&s).unwrap();
    c.upload(&blob_of(&model)).unwrap();
    let st = wait_until("pressure read and folded", &clk, 30.0, || {
        let st = c.status().ok()?;
        (!st.flags.intersects(Flags::SENSOR_BLOCK | Flags::WARMING_UP) && !st.aux[0].is_nan())
            .then_some(st)
    });
    assert!(
        (st.aux[0] - 1013.25).abs() < 0.01,
        "LPS22HB pressure {}",
        st.aux[0]
    );
    host.send("MOV 1 100");
    // the first move waits for the controller's syntax version and unit (CSV?, PUN?)
    let fwd = loop {
        let l = stage.next_line(HANG);
        if l.starts_with("MOV") {
            break l;
        }
    };
    let mut slow = nanocal_model::SlowInputs::default();
    slow.temps_c[0] = f64::from(TEMPS_C[0]);
    slow.aux[0] = f64::from(st.aux[0]);
    let want = model.eval_f64(&[100.0, 0.0, 0.0], &[0; 3], &slow)[0];
    let got: f64 = fwd.split_whitespace().nth(2).unwrap().parse().unwrap();
    assert!((got - want).abs() < 1e-4, "{got} vs {want}");
    // the barometer stops answering: pressure is a failed input, moves refused (no default)
    sensors.buses().i2c.clear();
    wait_until("missing pressure blocks moves", &clk, 40.0, || {
        let st = c.status().ok()?;
        (st.flags.contains(Flags::SENSOR_BLOCK)).then_some(())
    });
}
