//! The amplifier drivers (`nanocal_compensator::sensor::Driver`) against register-level
//! simulations of the chips (`nanocal::virtual_bench::chips`, written from the datasheets), and
//! the other pure device rules of issue 9. Each test names the defect of the first firmware it
//! catches.

use nanocal::virtual_bench::chips::I2cChip;
use nanocal::virtual_bench::chips::{Lps22hb, Max31856, Max31865, SpiChip};
use nanocal_compensator::clock::{self, ClockStep};
use nanocal_compensator::fault::{ChannelState, Faults, Policy};
use nanocal_compensator::inputs::{self, Board, InputError};
use nanocal_compensator::lps22hb;
use nanocal_compensator::sensor::{
    Chip, Driver, Mains, Outcome, SensorFault, TcType, Wires, MAX_TXN,
};
use nanocal_interface::identity::{self, ResetCause};
use nanocal_interface::led::LedState;
use nanocal_interface::mgmt::{InputCode, InputWhy};
use nanocal_interface::settings::{AuxSource, Settings};

/// One SPI transaction with the chip (None: nothing on the chip-select, MISO pulled up).
fn spi(chip: Option<&mut (dyn SpiChip + '_)>, buf: &mut [u8], now_s: f64) {
    match chip {
        Some(c) => {
            c.select(now_s);
            for b in buf.iter_mut() {
                *b = c.exchange(*b);
            }
            c.deselect(now_s);
        }
        None => buf.fill(0xFF),
    }
}

/// Run the driver for one sensor cycle at `now_ms`, as the firmware's sensor task does.
#[allow(clippy::option_as_ref_deref)] // as_deref_mut would keep the borrow for the loop
fn cycle(
    d: &mut Driver,
    mut chip: Option<&mut (dyn SpiChip + '_)>,
    now_ms: u32,
) -> Option<Result<f32, SensorFault>> {
    let mut buf = [0u8; MAX_TXN];
    for _ in 0..4 {
        let txn = d.next(now_ms)?;
        let n = d.fill(txn, &mut buf);
        spi(
            chip.as_mut().map(|c| &mut **c),
            &mut buf[..n],
            f64::from(now_ms) * 1e-3,
        );
        match d.complete(txn, Ok(&buf[..n]), now_ms) {
            Outcome::Continue => continue,
            Outcome::Waiting => return None,
            Outcome::Reading(r) => return Some(r.map(|x| x.temp_c)),
        }
    }
    None
}

const PT100: Chip = Chip::Max31865 {
    r_ref_ohm: 430.0,
    r0_ohm: 100.0,
    wires: Wires::Three,
};

/// Cycles every 250 ms from `t0_ms` until a reading; (time, reading).
fn first_reading(
    d: &mut Driver,
    chip: &mut dyn SpiChip,
    t0_ms: u32,
) -> (u32, Result<f32, SensorFault>) {
    for k in 0..40 {
        let t = t0_ms + 250 * k;
        if let Some(r) = cycle(d, Some(chip), t) {
            return (t, r);
        }
    }
    panic!("no reading in 10 s");
}

#[test]
fn max31865_fault_thresholds_land_in_their_registers() {
    // defect: the configuration burst started at 80h and auto-incremented through the
    // read-only RTD registers, so HFT got 0000h and every conversion was a fault
    let mut chip = Max31865::new(21.5, 100.0, 430.0);
    let mut d = Driver::new(PT100, Mains::Hz50);
    let (_, r) = first_reading(&mut d, &mut chip, 0);
    assert_eq!(
        &chip.regs()[3..7],
        &[0xFF, 0xFF, 0x00, 0x00],
        "HFT FFFFh, LFT 0000h"
    );
    let t = r.expect("a PT100 at 21.5 °C reads without a fault");
    assert!((t - 21.5).abs() < 0.05, "{t}");

    // the old burst against the same chip model: the simulator shows the defect
    let mut old = Max31865::new(21.5, 100.0, 430.0);
    let mut burst = [0x80, 0xC1, 0xFF, 0xFF, 0x00, 0x00, 0, 0];
    spi(Some(&mut old), &mut burst, 0.0);
    assert_eq!(
        &old.regs()[3..5],
        &[0x00, 0x00],
        "old burst: high threshold 0000h"
    );
    let mut dump = [0u8; 9];
    spi(Some(&mut old), &mut dump, 1.0);
    assert_ne!(
        dump[8] & 0x80,
        0,
        "old burst: every conversion above the high threshold"
    );
}

#[test]
fn max31865_fault_latch_is_cleared_after_the_fault_goes() {
    // defect: the MAX31865's fault status latches until D1 is written; the old driver never
    // cleared it, so one open-wire glitch blocked moves until a power cycle
    let mut chip = Max31865::new(22.0, 100.0, 430.0);
    let mut d = Driver::new(PT100, Mains::Hz50);
    let (t, r) = first_reading(&mut d, &mut chip, 0);
    assert!(r.is_ok());
    chip.open = true;
    let r = cycle(&mut d, Some(&mut chip), t + 250).unwrap();
    assert_eq!(r, Err(SensorFault::Open));
    chip.open = false;
    // still latched in the chip until the driver clears it
    assert_ne!(chip.regs()[7], 0);
    let r = cycle(&mut d, Some(&mut chip), t + 500).unwrap();
    let v = r.expect("fault latch cleared, reading good again");
    assert!((v - 22.0).abs() < 0.05);
    assert_eq!(chip.regs()[7], 0);
}

#[test]
fn both_chips_notch_the_configured_mains() {
    // defect: the MAX31856 ran its 60 Hz filter while the MAX31865 ran 50 Hz
    for (mains, bit) in [(Mains::Hz50, 1u8), (Mains::Hz60, 0)] {
        let mut tc = Max31856::new(22.0);
        let mut d = Driver::new(Chip::K, mains);
        let _ = first_reading(&mut d, &mut tc, 0);
        assert_eq!(tc.regs()[0] & 1, bit, "MAX31856 CR0 notch for {mains:?}");
        assert_eq!(tc.regs()[0] & 0x80, 0x80, "auto conversion on");
        let mut rtd = Max31865::new(22.0, 100.0, 430.0);
        let mut d = Driver::new(PT100, mains);
        let _ = first_reading(&mut d, &mut rtd, 0);
        assert_eq!(rtd.regs()[0] & 1, bit, "MAX31865 notch for {mains:?}");
    }
}

#[test]
fn no_reading_before_the_first_conversion() {
    // defect: the first read came before the chip's first conversion and returned the
    // power-on zeros (0 °C), on which the lag filters primed
    let mut chip = Max31856::new(23.25);
    let mut d = Driver::new(Chip::Max31856 { tc: TcType::K }, Mains::Hz50);
    assert_eq!(cycle(&mut d, Some(&mut chip), 0), None, "configuring");
    // the chip has not converted yet: its registers still hold zeros
    assert_eq!(&chip.regs()[0x0C..0x0F], &[0, 0, 0]);
    let (t, r) = first_reading(&mut d, &mut chip, 0);
    assert!(t >= d.first_conversion_ms(), "first reading at {t} ms");
    assert!(chip.conversions >= 1);
    assert_eq!(r, Ok(23.25), "the first reading is the real temperature");
}

#[test]
fn an_absent_chip_is_a_fault_never_a_temperature() {
    // defect: an absent chip (MISO pulled up, all ones) or a dead bus (all zeros) decoded as
    // a temperature
    for chip in [Chip::K, PT100] {
        let mut d = Driver::new(chip, Mains::Hz50);
        let mut seen = vec![];
        for k in 0..20 {
            if let Some(r) = cycle(&mut d, None, 250 * k) {
                seen.push(r);
            }
        }
        assert!(!seen.is_empty());
        assert!(
            seen.iter().all(|r| *r == Err(SensorFault::NoResponse)),
            "{chip:?}: {seen:?}"
        );
    }
}

#[test]
fn a_chip_that_lost_its_configuration_is_reconfigured() {
    // defect: chips were configured once; after a brown-out or hot-plug the chip sat in its
    // power-on state (not converting) and was read as if configured
    let mut chip = Max31856::new(22.0);
    let mut d = Driver::new(Chip::K, Mains::Hz50);
    let (t, r) = first_reading(&mut d, &mut chip, 0);
    assert_eq!(r, Ok(22.0));
    chip.power_on_reset(f64::from(t) * 1e-3);
    let r = cycle(&mut d, Some(&mut chip), t + 250).unwrap();
    assert_eq!(r, Err(SensorFault::ConfigLost));
    assert_eq!(d.reconfigurations, 1);
    let (_, r) = first_reading(&mut d, &mut chip, t + 500);
    assert_eq!(r, Ok(22.0), "configured again and converting");
}

#[test]
fn max31856_faults_follow_the_input_in_comparator_mode() {
    let mut chip = Max31856::new(22.0);
    let mut d = Driver::new(Chip::K, Mains::Hz50);
    let (t, _) = first_reading(&mut d, &mut chip, 0);
    chip.open = true;
    let (t2, r) = first_reading(&mut d, &mut chip, t + 250);
    assert_eq!(r, Err(SensorFault::Open));
    chip.open = false;
    let (_, r) = first_reading(&mut d, &mut chip, t2 + 250);
    assert_eq!(r, Ok(22.0));
}

#[test]
fn lps22hb_pressure_after_its_first_conversion() {
    let mut chip = Lps22hb::new(1013.25);
    let mut id = [0u8];
    chip.write(&[lps22hb::WHO_AM_I], 0.0);
    chip.read(&mut id, 0.0);
    assert_eq!(id[0], lps22hb::ID);
    let mut burst = [0u8; lps22hb::BURST];
    chip.write(&[lps22hb::STATUS], 0.0);
    chip.read(&mut burst, 0.0);
    assert_eq!(
        lps22hb::decode(&burst, false),
        None,
        "power-down: no conversion yet"
    );
    chip.write(&[lps22hb::CTRL_REG1, lps22hb::CTRL_REG1_VALUE], 0.0);
    chip.write(&[lps22hb::STATUS], 1.5);
    chip.read(&mut burst, 1.5);
    let p = lps22hb::decode(&burst, false).expect("converted at 1 Hz");
    assert!((p - 1013.25).abs() <= 1.0 / 4096.0, "{p}");
}

#[test]
fn a_holding_channel_fails_without_new_readings() {
    // defect: Channel::tick was never called; a channel whose readings stopped coming held
    // its last value for ever
    let mut f: Faults = Faults::new(Policy {
        hold_ms: 1000,
        ..Policy::default()
    });
    f.update(0, Ok(22.0), 0);
    f.update(0, Err(SensorFault::NoResponse), 100);
    assert!(matches!(f.channels[0].state, ChannelState::Holding { .. }));
    f.tick(0, 1200);
    assert!(f.blocks_moves(1), "hold time over with no reading at all");
    assert!(!f.all_usable(1));
}

#[test]
fn boot_sets_flash_latency_before_the_msi_goes_to_48_mhz() {
    // defect: embassy-stm32 0.6.0 rcc/l.rs (init): MSI is switched to the configured range
    // (48 MHz) while it is the system clock, and FLASH_ACR.LATENCY is written only after the
    // PLL is set up, just before the final switch. Replayed against RM0351 Table 12:
    let embassy_060 = [
        ClockStep::Hclk(48_000_000), // msi_enable(RANGE48M) with MSI as SYSCLK
        ClockStep::SetLatency(4),    // latency for the final 80 MHz
        ClockStep::Hclk(80_000_000), // switch to PLL
    ];
    assert_eq!(
        clock::first_violation(&embassy_060),
        Some(0),
        "0 WS at 48 MHz"
    );
    let mut fixed = vec![ClockStep::SetLatency(clock::BOOT_WAIT_STATES)];
    fixed.extend_from_slice(&embassy_060);
    assert_eq!(clock::first_violation(&fixed), None);
    assert_eq!(clock::wait_states_range1(80_000_000), 4);
    assert_eq!(clock::wait_states_range1(16_000_000), 0);
}

#[test]
fn the_stm32_tick_divides_its_timer_clock() {
    // defect: tick-hz-32_768 on an 80 MHz timer: prescaler 2441 → 32 773 Hz, 14 s/day fast
    assert!(clock::tick_error_ppm(80_000_000, 32_768) * 86_400e-6 > 14.0);
    let manifest =
        std::fs::read_to_string(nanocal::virtual_bench::repo_root().join("Cargo.toml")).unwrap();
    let stm32 = manifest
        .split("\nstm32 = [")
        .nth(1)
        .expect("stm32 feature")
        .split(']')
        .next()
        .unwrap();
    let tick: u32 = stm32
        .split("tick-hz-")
        .nth(1)
        .expect("the stm32 feature picks a tick")
        .split('"')
        .next()
        .unwrap()
        .replace('_', "")
        .parse()
        .unwrap();
    assert_eq!(80_000_000 % tick, 0, "tick {tick} Hz must divide 80 MHz");
    assert_eq!(clock::tick_error_ppm(80_000_000, tick), 0.0);
}

#[test]
fn reset_cause_from_rcc_csr_and_serial_from_uid() {
    // RM0351 §6.4.29 RCC_CSR; a power-on sets BORRSTF and PINRSTF together
    assert_eq!(
        ResetCause::from_rcc_csr((1 << 27) | (1 << 26)),
        ResetCause::PowerOn
    );
    assert_eq!(ResetCause::from_rcc_csr(1 << 26), ResetCause::Pin);
    assert_eq!(
        ResetCause::from_rcc_csr((1 << 29) | (1 << 26)),
        ResetCause::Watchdog
    );
    assert_eq!(
        ResetCause::from_rcc_csr((1 << 28) | (1 << 26)),
        ResetCause::Software
    );
    // 8 panic, 9 double ECC error outside the store, 10 CPU fault (protocol 5)
    for c in 0..11 {
        assert_eq!(ResetCause::from_code(c).map(ResetCause::code), Some(c));
    }
    assert_eq!(ResetCause::from_code(11), None);
    // defect: every board enumerated with serial "0001"
    let (mut a, mut b) = ([0u8; 24], [0u8; 24]);
    identity::usb_serial(&[0x12, 0x34, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0x01], &mut a);
    identity::usb_serial(&[0x12, 0x34, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0x02], &mut b);
    assert_eq!(&a, b"123400000000000000000001");
    assert_ne!(a, b);
}

#[test]
fn settings_round_trip_and_reject_what_they_must() {
    let mut s = Settings {
        stage_baud: 57_600,
        mains: Mains::Hz60,
        ..Default::default()
    };
    s.sensors[5] = Some(Chip::Max31865 {
        r_ref_ohm: 4300.0,
        r0_ohm: 1000.0,
        wires: Wires::Four,
    });
    s.sensors[1] = Some(Chip::Max31856 { tc: TcType::T });
    s.axis_names[0] = nanocal_compensator::gcs::AxisId::new(b"X").unwrap();
    s.aux[0] = AuxSource::AirPressure;
    s.aux[1] = AuxSource::Force {
        channel: 0,
        scale_n_per_count: 0.01,
        offset_n: -20.48,
    };
    let b = s.encode();
    assert_eq!(Settings::decode(&b), Ok(s));
    let mut torn = b;
    torn[20] ^= 1;
    assert!(
        Settings::decode(&torn).is_err(),
        "CRC catches a changed byte"
    );
    let mut bad = s;
    bad.sample_period_ms = 10;
    assert!(
        Settings::decode(&bad.encode()).is_err(),
        "period out of range"
    );
}

/// Layout 3 added the fold period (u16 LE at 240), layout 4 the stale check's k and margin
/// (f32 LE at 242 and 246), layout 5 reserved the stage unit's byte (172, written 0), layout 6
/// added `allow_other_stage` (u8 at 250) and held targets following the model (3 × u16 LE at
/// 251, CRC at 257): golden bytes of their fields, a layout-5 record (254 bytes, CRC at 250)
/// decoding with other stages refused and following off, a fold period outside 1–10 s refused,
/// a layout-4 record with any stage unit decoding to the same settings, a layout-3 record (246
/// bytes, CRC at 242) decoding with the stale check's defaults and a layout-2 record (244 bytes,
/// CRC at 240) — settings stored by the firmware before — decoding with the default fold period
/// (5 s).
#[test]
fn settings_layout_6_carries_the_fold_period_the_stale_check_the_stage_check_and_following() {
    use nanocal_interface::settings::{
        DEFAULT_EXTRAPOLATION_C, DEFAULT_FOLD_PERIOD_MS, DEFAULT_STALE_K, LEN,
    };
    let mut s = Settings {
        fold_period_ms: 7_250,
        stale_k: 2.5,
        extrapolation_c: 0.25,
        allow_other_stage: true,
        ..Default::default()
    };
    let v6 = s.encode();
    assert_eq!(
        (v6.len(), LEN),
        (261, 261),
        "9 + 16 x 10 + 4 + 27 + 40 + 2 + 8 + 1 + 6 + 4"
    );
    assert_eq!(&v6[..5], b"NCST\x06");
    assert_eq!(&v6[240..242], &[0x52, 0x1C], "7250 ms, little endian");
    assert_eq!(&v6[242..246], &2.5f32.to_le_bytes());
    assert_eq!(&v6[246..250], &0.25f32.to_le_bytes());
    assert_eq!(v6[250], 1, "allow_other_stage");
    assert_eq!(
        &v6[251..257],
        &[0, 0, 0x10, 0x27, 0, 0],
        "following off, 10 000 ms, no step limit"
    );
    let crc = nanocal_interface::crc32(&v6[..257]);
    assert_eq!(&v6[257..], &crc.to_le_bytes());
    assert_eq!(Settings::decode(&v6), Ok(s));
    // a value other than 0 or 1 is refused, naming its byte
    let mut bad = v6;
    bad[250] = 2;
    let crc = nanocal_interface::crc32(&bad[..257]);
    bad[257..].copy_from_slice(&crc.to_le_bytes());
    assert_eq!(
        Settings::decode(&bad),
        Err(nanocal_interface::settings::SettingsError::Field(250))
    );
    // layout 5: the same bytes up to 250, then the CRC; other stages refused, following off
    let mut v5 = v6[..250].to_vec();
    v5[4] = 5;
    let crc = nanocal_interface::crc32(&v5);
    v5.extend_from_slice(&crc.to_le_bytes());
    assert_eq!(v5.len(), 254);
    assert_eq!(v5[172], 0, "reserved: the stage unit of layouts 1 to 4");
    assert_eq!(
        Settings::decode(&v5),
        Ok(Settings {
            allow_other_stage: false,
            ..s
        })
    );
    // layout 4: the same places, with a stage unit at 172 (0 µm, 1 mm, 2 nm) that no firmware
    // applied: any of them loads, to the same settings
    for unit in [0, 1, 2, 0xFF] {
        let mut old = v5.clone();
        old[4] = 4;
        old[172] = unit;
        let crc = nanocal_interface::crc32(&old[..250]);
        old[250..].copy_from_slice(&crc.to_le_bytes());
        assert_eq!(
            Settings::decode(&old),
            Ok(Settings {
                allow_other_stage: false,
                ..s
            }),
            "layout 4, stage unit {unit}"
        );
    }
    // layout 3: the same bytes up to 242, then the CRC
    let mut v3 = v6[..242].to_vec();
    v3[4] = 3;
    let crc = nanocal_interface::crc32(&v3);
    v3.extend_from_slice(&crc.to_le_bytes());
    assert_eq!(
        Settings::decode(&v3),
        Ok(Settings {
            stale_k: DEFAULT_STALE_K,
            extrapolation_c: DEFAULT_EXTRAPOLATION_C,
            allow_other_stage: false,
            ..s
        })
    );
    for bad in [999, 10_001, 0] {
        s.fold_period_ms = bad;
        assert!(Settings::decode(&s.encode()).is_err(), "{bad} ms");
    }
    // layout 2: the same bytes up to 240, then the CRC
    let mut v2 = v6[..240].to_vec();
    v2[4] = 2;
    let crc = nanocal_interface::crc32(&v2);
    v2.extend_from_slice(&crc.to_le_bytes());
    let old = Settings::decode(&v2).unwrap();
    assert_eq!(old.fold_period_ms, DEFAULT_FOLD_PERIOD_MS);
    assert_eq!(DEFAULT_FOLD_PERIOD_MS, 5_000);
    assert_eq!(
        Settings {
            fold_period_ms: 7_250,
            stale_k: 2.5,
            extrapolation_c: 0.25,
            allow_other_stage: true,
            ..old
        },
        Settings::decode(&v6).unwrap()
    );
}

/// Settings stored by a firmware with layout 1 (8 chip-selects, 164 bytes: mains at 89, axes at
/// 93, aux at 120, CRC at 160) survive the update to layout 6 (16 chip-selects, fold period,
/// stale check, no stage unit, stage check, following).
#[test]
fn settings_of_layout_1_still_decode() {
    let mut s = Settings {
        stage_baud: 38_400,
        mains: Mains::Hz60,
        sample_period_ms: 500,
        ..Default::default()
    };
    s.sensors = [None; nanocal_interface::settings::SENSORS];
    s.sensors[7] = Some(Chip::Max31856 { tc: TcType::J });
    s.axis_names[2] = nanocal_compensator::gcs::AxisId::new(b"Z").unwrap();
    s.aux[1] = AuxSource::AirPressure;
    let v2 = s.encode();
    assert_eq!(
        v2.len(),
        261,
        "layout 6: 9 + 16 x 10 + 4 + 27 + 40 + 2 + 8 + 1 + 6 + 4"
    );
    assert_eq!(v2[4], 6);
    // layout 1, byte for byte: header, 8 sensors, then the same tail at 89
    let mut v1 = Vec::new();
    v1.extend_from_slice(b"NCST\x01");
    v1.extend_from_slice(&38_400u32.to_le_bytes());
    v1.extend_from_slice(&[0; 70]); // chip-selects 0..6: none
    v1.extend_from_slice(&[1, 2, 0, 0, 0, 0, 0, 0, 0, 0]); // chip-select 7: MAX31856, type J
    assert_eq!(v1.len(), 89);
    v1.extend_from_slice(&[60, 0xF4, 0x01, 2]); // 60 Hz, 500 ms, stage unit nm (ignored)
    assert_eq!(v1.len(), 93);
    v1.extend_from_slice(&v2[169 + 4..240]); // axis names and aux sources, as layout 2 has them
    assert_eq!(v1.len(), 160);
    let crc = nanocal_interface::crc32(&v1);
    v1.extend_from_slice(&crc.to_le_bytes());
    assert_eq!(Settings::decode(&v1), Ok(s));
    // a layout-1 record cut to a layout-2 length, or with an unknown version, is refused
    assert!(Settings::decode(&v1[..163]).is_err());
    let mut v7 = v1.clone();
    v7[4] = 7;
    assert!(Settings::decode(&v7).is_err());
}

/// A model with more temperatures than the board has chip-select lines is refused at upload
/// (a board with four, as the STM32 board was before it drove 16), even with amplifiers configured
/// for all of them.
#[test]
fn a_model_needing_more_chip_selects_than_wired_is_refused() {
    let model = nanocal_model::reference::delta_robot_78().unwrap();
    let mut s = Settings::default();
    for slot in s.sensors.iter_mut().take(model.temps()) {
        *slot = Some(Chip::K);
    }
    let stm32 = Board {
        barometer: true,
        adc_channels: 1,
        chip_selects: 4,
    };
    let e = inputs::check(&model, &s, &stm32).unwrap_err();
    assert_eq!(e, InputError::NoChipSelect { index: 4 });
    assert_eq!(e.code().code(), 0x64);
    assert!(e.to_string().contains("no chip-select 4"), "{e}");
    // what a host prints for the code the device sends
    let code = InputCode::from_code(0x64).unwrap();
    assert_eq!(code.why, InputWhy::NoChipSelect);
    assert_eq!(
        code.to_string(),
        "input 4, temperature input on a chip-select the board does not wire"
    );
    assert_eq!(InputCode::from_code(0x05), None);
    let sixteen = Board {
        chip_selects: 16,
        ..stm32
    };
    assert_eq!(inputs::check(&model, &s, &sixteen), Ok(()));
}

#[test]
fn a_model_using_an_input_the_board_cannot_supply_is_refused() {
    let model = nanocal::papers::published::published_1dof().unwrap();
    let board = Board {
        barometer: true,
        adc_channels: 1,
        chip_selects: 4,
    };
    let mut s = Settings::default();
    assert_eq!(
        inputs::check(&model, &s, &board),
        Ok(()),
        "temps 0..{} configured",
        model.temps()
    );
    if model.temps() > 0 {
        s.sensors[model.temps() - 1] = None;
        assert_eq!(
            inputs::check(&model, &s, &board),
            Err(InputError::NoTemperatureSensor {
                index: model.temps() as u8 - 1
            })
        );
    }
    // an aux-using model: built by the model's own builder
    let aux_model = pressure_model();
    let s = Settings::default();
    assert_eq!(
        inputs::check(&aux_model, &s, &board),
        Err(InputError::NoAuxSource { index: 0 })
    );
    let mut s2 = s;
    s2.aux[0] = AuxSource::AirPressure;
    assert_eq!(inputs::check(&aux_model, &s2, &board), Ok(()));
    let no_baro = Board {
        barometer: false,
        adc_channels: 1,
        chip_selects: 4,
    };
    assert_eq!(
        inputs::check(&aux_model, &s2, &no_baro),
        Err(InputError::NoBarometer { index: 0 })
    );
    s2.aux[0] = AuxSource::Force {
        channel: 3,
        scale_n_per_count: 1.0,
        offset_n: 0.0,
    };
    assert_eq!(
        inputs::check(&aux_model, &s2, &board),
        Err(InputError::NoAdcChannel {
            index: 0,
            channel: 3
        })
    );
}

#[test]
fn led_shows_what_the_stage_gets() {
    assert_eq!(
        LedState::of(true, false, false, false),
        LedState::Compensating
    );
    assert_eq!(LedState::of(true, true, true, true), LedState::Bypass);
    assert_eq!(LedState::of(false, false, true, false), LedState::NoModel);
    assert_eq!(LedState::of(true, false, true, true), LedState::Fault);
    assert_eq!(LedState::of(true, false, false, true), LedState::Stale);
    // a stale model still compensates: mostly lit, dark 200 ms every second
    assert!(LedState::Stale.lit(0) && LedState::Stale.lit(799));
    assert!(!LedState::Stale.lit(800) && !LedState::Stale.lit(1999) && LedState::Stale.lit(2000));
    assert!((0..2000).all(|t| LedState::Compensating.lit(t)));
    let fast = (0..1000).filter(|&t| LedState::Fault.lit(t)).count();
    assert_eq!(fast, 500);
}

/// The supervisor sleeps until the LED's next edge: that edge must be exactly where `lit`
/// changes, for every pattern and phase (a late edge would stretch the blink; an early one only
/// costs a wake-up, but is wrong too).
#[test]
fn led_next_edge_is_where_the_pattern_changes() {
    assert_eq!(LedState::Compensating.next_edge_ms(1234), None);
    for state in [
        LedState::Bypass,
        LedState::NoModel,
        LedState::Fault,
        LedState::Stale,
    ] {
        for t in 0..4000u32 {
            let e = state.next_edge_ms(t).expect("a blinking pattern has edges");
            assert!(e >= 1, "{state:?} at {t} ms: edge {e} ms away");
            let lit = state.lit(t);
            assert!(
                (1..e).all(|d| state.lit(t + d) == lit),
                "{state:?} at {t} ms changes before its edge {e} ms away"
            );
            assert_ne!(
                state.lit(t + e),
                lit,
                "{state:?} at {t} ms: no change {e} ms on"
            );
        }
    }
}

/// A 1-axis model with one temperature and one aux input (air pressure, hPa).
fn pressure_model() -> nanocal_model::Model {
    use nanocal_model::{Factor, Input, ModelBuilder};
    let mut b = ModelBuilder::new(1, 1, 1)
        .unwrap()
        .id(0x0002_0001)
        .trained_range(Input::Axis(0), 0.0, 100.0)
        .trained_range(Input::Temp(0), 20.0, 24.0)
        .trained_range(Input::Aux(0), 950.0, 1050.0)
        .travel_um(0, -10.0, 110.0);
    b.add_raw_term(0, [1, 0, 0], Factor::None, 0, 1.0).unwrap();
    b.add_raw_term(0, [0; 3], Factor::Temp(0), 0, 0.1).unwrap();
    b.add_raw_term(0, [0; 3], Factor::Aux(0), 0, 0.002).unwrap();
    b.build().unwrap()
}
