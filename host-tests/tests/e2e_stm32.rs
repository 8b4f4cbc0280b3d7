//! End to end on the emulated B-L475E-IOT01A: the shipped STM32 image (`nanocal-fw`, release,
//! default features) between a USB host and the simulated stage controller on UART4, with the
//! MAX31856 register models on SPI1 (DMA), the LPS22HB on I2C2 and the force input on ADC1 —
//! the same chips and controller as the QEMU e2e test (tests/e2e_qemu.rs), whose session this
//! one repeats on the real image.
//!
//! The host enumerates the board, a client on the management port (CDC-ACM interface 2)
//! uploads a model, the sensors' first conversions fold it, and a GCS client on the GCS port
//! (interface 0) sends moves that reach the controller corrected; then rejected uploads, a
//! sensor fault and its recovery, bypass, KMZ and a reset that brings the model back from
//! flash. Every wait is a bound in board time.

mod stm32_sim;

use nanocal::device::DeviceError;
use nanocal::papers::published::published_1dof;
use nanocal_compensator::sensor::max31856;
use nanocal_interface::identity::ResetCause;
use nanocal_interface::mgmt::Refusal;
use nanocal_interface::status::{ChannelStatus, Flags, SensorFault};
use nanocal_model::{blob, SlowInputs, MAX_AXES};
use nanocal_stm32_board::ResetKind;
use stm32_sim::{default_buses, stage_value, Stm32, FOLD_S};

/// Temperatures the simulated sensors report (exact in MAX31856 LSBs), inside 21–23 °C.
const TEMPS_C: [f32; 4] = [22.0, 22.125, 21.875, 22.25];

fn slow() -> SlowInputs {
    let mut s = SlowInputs::default();
    for (i, t) in TEMPS_C.iter().enumerate() {
        s.temps_c[i] = f64::from(*t);
    }
    s
}

#[test]
fn e2e_stm32_upload_sensors_and_corrected_moves() {
    let b = Stm32::start(default_buses(&TEMPS_C));
    b.usb.attach();

    let mut c = b.mgmt();
    let (proto, format, _) = c.hello().expect("hello");
    assert_eq!(format, blob::FORMAT_VERSION);
    assert_eq!(proto, nanocal_interface::mgmt::PROTOCOL);
    let s = c.status().unwrap();
    assert!(
        !s.flags.contains(Flags::MODEL),
        "no model before the upload"
    );
    let id = c.identify().unwrap();
    assert_eq!(
        id.reset_cause,
        ResetCause::PowerOn,
        "RCC_CSR says power-on (BORRSTF)"
    );

    // without a model, moves are refused (and nothing reaches the controller)
    let mut host = b.gcs();
    host.send("MOV 1 10");
    assert_eq!(host.ask("ERR?"), "9003");

    // upload over the management port; the model carries a prediction bound (blob version 3),
    // which the device must keep byte for byte: it re-encodes what it stores, and the upload
    // checks that the CRC it reports is the blob's
    let mut model = published_1dof().unwrap();
    let p = model.axis_terms(0);
    let r: Vec<f32> = (0..nanocal_model::bound::packed_len(p))
        .map(|k| 0.5 + k as f32)
        .collect();
    let bound =
        nanocal_model::AxisBound::new(0.02, 2.01, &vec![0.1; p], &vec![0.7; p], &r).unwrap();
    model.set_bound(0, Some(bound)).unwrap();
    let mut blob_bytes = vec![0u8; blob::MAX_BLOB_LEN];
    let n = blob::encode(&model, &mut blob_bytes).unwrap();
    let committed = c.upload(&blob_bytes[..n]).expect("upload");
    assert_eq!(committed.model_id, model.id());

    // the sensors' first conversions (MAX31856 over SPI1 + DMA) fold the model
    let s = b.status_until(&mut c, "sensors read and model folded", 5.0 + FOLD_S, |s| {
        s.flags.contains(Flags::MODEL)
            && !s.flags.contains(Flags::SENSOR_BLOCK)
            && s.sensor_bits[..4]
                .iter()
                .all(|b| b.state == ChannelStatus::Ok)
            && s.folds >= 2
    });
    assert_eq!(s.model_id, model.id());
    for (i, t) in TEMPS_C.iter().enumerate() {
        assert_eq!(s.temps_c[i], *t, "sensor {i} read over SPI1");
    }
    assert_eq!(s.move_fold, 0, "no move corrected yet");

    // MOV: the forwarded command equals the host's f64 evaluation within 0.1 nm
    let check = |got: f64, x: f64, dir: [i8; MAX_AXES]| {
        let want = model.eval_f64(&[x, 0.0, 0.0], &dir, &slow())[0];
        assert!(
            (got - want).abs() <= 1e-4,
            "x = {x} µm: forwarded {got}, f64 reference {want} (Δ = {} nm)",
            (got - want) * 1e3
        );
    };
    host.send("MOV 1 100");
    // the first move waits for what the controller tells of itself: identity (what the
    // compensator's markers bring back), GCS syntax version, axes, position unit and travel
    let mut first = Vec::new();
    while first.last().is_none_or(|l: &String| !l.starts_with("MOV ")) {
        first.push(b.stage_line(1.0));
    }
    assert_eq!(
        first[..first.len() - 1],
        [
            "*IDN?", "CSV?", "*IDN?", "SAI?", "PUN? 1", "*IDN?", "TMN? 1", "*IDN?", "TMX? 1",
            "*IDN?"
        ],
        "{first:?}"
    );
    check(
        stage_value(first.last().unwrap(), "1"),
        100.0,
        [0; MAX_AXES],
    );
    let s1 = c.status().unwrap();
    assert!(s1.move_fold != 0 && s.folds <= s1.move_fold && s1.move_fold <= s1.folds);

    // MVR becomes an absolute MOV
    host.send("MVR 1 12.5");
    // from the base the controller holds (MOV?)
    assert_eq!(b.stage_line(1.0), "MOV? 1");
    check(stage_value(&b.stage_line(1.0), "1"), 112.5, [1, 0, 0]);

    // POS? and MOV? map back to calibrated coordinates
    let reply = host.ask("POS? 1");
    let x = reply.strip_prefix("1=").unwrap().parse::<f64>().unwrap();
    assert!((x - 112.5).abs() <= 2e-4, "POS? mapped to {x}");
    let reply = host.ask("MOV?");
    let x = reply.strip_prefix("1=").unwrap().parse::<f64>().unwrap();
    assert!((x - 112.5).abs() <= 2e-4, "MOV? mapped to {x}");
    assert_eq!(
        b.stage.drain(),
        ["POS? 1", "MOV?"],
        "queries forwarded untouched"
    );

    // many targets, both directions
    let mut prev = 112.5;
    for k in 0..40 {
        let x = ((k * 7919) % 4800) as f64 / 10.0 + 0.0123;
        host.send(&format!("MOV 1 {x:.4}"));
        let dir = if x > prev { 1 } else { -1 };
        check(stage_value(&b.stage_line(1.0), "1"), x, [dir, 0, 0]);
        prev = x;
    }
    assert_eq!(host.ask("ERR?"), "0", "no error so far");
    assert_eq!(b.stage.drain(), ["ERR?"]);

    // other commands pass untouched; single-character commands too
    host.send("VEL 1 10");
    assert_eq!(b.stage_line(1.0), "VEL 1 10");
    host.send_raw(&[0x05]);
    assert_eq!(b.stage_line(1.0), "#5");
    assert_eq!(host.read_line(), "0");
    assert!(host.ask("*IDN?").contains("E-727"));
    // (a controller may not know #5: the compensator's marker followed it)
    assert_eq!(b.stage.drain(), ["*IDN?", "*IDN?"]);

    // outside the envelope: GCS error, nothing moves
    host.send("MOV 1 500");
    assert_eq!(host.ask("ERR?"), "9001");
    host.send("SVO 1 1");
    assert_eq!(b.stage_line(1.0), "SVO 1 1", "MOV 500 was not forwarded");

    // corrupt and truncated uploads are rejected; the old model stays in service
    let mut bad = blob_bytes[..n].to_vec();
    bad[24] ^= 0x10;
    let e = c
        .upload_raw(
            &bad,
            n as u32,
            blob::crc32(&bad),
            blob::FORMAT_VERSION,
            true,
        )
        .unwrap_err();
    assert!(
        matches!(
            e,
            DeviceError::Refused {
                refusal: Refusal::UploadBlob,
                ..
            }
        ),
        "{e}"
    );
    let e = c
        .upload_raw(
            &blob_bytes[..n / 2],
            n as u32,
            blob::crc32(&blob_bytes[..n]),
            blob::FORMAT_VERSION,
            true,
        )
        .unwrap_err();
    assert!(
        matches!(
            e,
            DeviceError::Refused {
                refusal: Refusal::UploadIncomplete,
                ..
            }
        ),
        "{e}"
    );
    let s = c.status().unwrap();
    assert_eq!(s.model_id, model.id());
    assert_eq!((s.uploads_ok, s.uploads_rejected), (1, 2));
    host.send("MOV 1 200");
    check(
        stage_value(&b.stage_line(1.0), "1"),
        200.0,
        [if prev < 200.0 { 1 } else { -1 }, 0, 0],
    );

    // a sensor fault: held for the hold time (5 s), then shown in the status and blocking moves
    b.set_tc_status(1, max31856::SR_OPEN);
    let s = b.status_until(&mut c, "sensor fault to block moves", 7.0, |s| {
        s.flags.contains(Flags::SENSOR_BLOCK)
    });
    assert_eq!(
        s.sensor_bits[1].state,
        ChannelStatus::Failed,
        "sensor 1 failed"
    );
    assert_eq!(
        s.sensor_bits[1].last_fault,
        Some(SensorFault::Open),
        "open thermocouple"
    );
    host.send("MOV 1 250");
    assert_eq!(host.ask("ERR?"), "9002");
    host.send("SVO 1 1");
    assert_eq!(b.stage_line(1.0), "SVO 1 1", "blocked MOV not forwarded");
    // recovery: three good readings
    b.set_tc_status(1, 0);
    b.status_until(&mut c, "sensor recovery", 2.0 + FOLD_S, |s| {
        !s.flags.contains(Flags::SENSOR_BLOCK)
    });
    host.send("MOV 1 250");
    check(stage_value(&b.stage_line(1.0), "1"), 250.0, [1, 0, 0]);

    // bypass forwards untouched
    c.bypass(true).unwrap();
    host.send("MOV 1 42");
    assert_eq!(b.stage_line(1.0), "MOV 1 42");
    c.bypass(false).unwrap();

    // KMZ from a reference: the model now maps the measured position to the command sent
    let kmz = c.set_kmz([250.0, 0.0, 0.0], [249.9, 0.0, 0.0]).unwrap();
    assert!(kmz[0].abs() > 1e-3);
    assert_eq!(c.status().unwrap().kmz_um[0], kmz[0]);
    let shifted = model.eval_f64(&[250.0, 0.0, 0.0], &[0; MAX_AXES], &slow())[0] + kmz[0];
    host.send("MOV 1 250");
    let got = stage_value(&b.stage_line(1.0), "1");
    assert!(
        (got - shifted).abs() <= 1e-4,
        "after KMZ: {got} vs {shifted}"
    );

    // a reset (AIRCR.SYSRESETREQ): the device re-enumerates, the model and its λ_KMZ come
    // back from flash, the reset cause says why
    c.reset().unwrap();
    drop(c);
    drop(host);
    let booted = b.run_until("the software reset", 1.0, |s| s.boots.len() == 2);
    assert_eq!(booted.boots[1].kind, ResetKind::Software);
    let mut c = b.mgmt();
    assert_eq!(c.identify().unwrap().reset_cause, ResetCause::Software);
    let s = b.status_until(&mut c, "model reloaded", 2.0, |s| {
        s.flags.contains(Flags::MODEL)
    });
    assert_eq!(s.model_id, model.id());
    assert_eq!(s.kmz_um[0], kmz[0], "λ_KMZ stored with the model");
    assert_eq!(
        b.usb.with(|h| h.enumerations),
        2,
        "enumerated again after the reset"
    );
    let st = b.status();
    assert_eq!(st.boots.len(), 2, "no other reset: {:?}", st.log);
    assert_eq!(st.uart_overruns, 0, "no stage-link byte lost");
    // errata ES0250: no read returned a line the data cache kept across a program or erase
    assert_eq!(st.stale_cache_reads, 0, "stale data-cache reads");
}

/// Guest instructions of one `MOV` line on the shipped image, the whole path: the USB OUT
/// packet taken by the OTG driver, the host link task, the proxy (parse, correct, format), the
/// stage link writing UART4 byte by byte (TXE interrupts) until the controller has the line.
/// The minimum over 200 lines (a line whose window no sensor cycle or supervisor tick
/// shared) and the median. Not comparable one to one with fw_bench's QEMU figure, which counts
/// the proxy's work alone between markers of a bench image.
/// `cd host-tests && cargo test --test e2e_stm32 -- --ignored --nocapture stm32_mov_line_instructions`
#[test]
#[ignore = "benchmark: prints the figure for BENCHMARKS.md"]
fn stm32_mov_line_instructions() {
    let b = Stm32::start(default_buses(&TEMPS_C));
    b.usb.attach();
    let mut c = b.mgmt();
    let model = published_1dof().unwrap();
    let mut blob_bytes = vec![0u8; blob::MAX_BLOB_LEN];
    let n = blob::encode(&model, &mut blob_bytes).unwrap();
    c.upload(&blob_bytes[..n]).expect("upload");
    b.status_until(&mut c, "model folded", 5.0 + FOLD_S, |s| {
        s.flags.contains(Flags::MODEL) && !s.flags.contains(Flags::SENSOR_BLOCK) && s.folds >= 2
    });
    let mut host = b.gcs();
    host.send("MOV 1 100");
    while !b.stage_line(1.0).starts_with("MOV ") {}
    b.run_for(0.05);
    let mut counts = vec![];
    for k in 0..200 {
        let x = 100.0 + f64::from(k % 50) * 1.5;
        let before = b.status().instructions;
        host.send(&format!("MOV 1 {x:.4}"));
        let line = b.stage_line(1.0);
        assert!(line.starts_with("MOV 1 "), "{line}");
        counts.push(b.status().instructions - before);
        b.run_for(0.01);
    }
    counts.sort_unstable();
    println!(
        "MOV line on the shipped image (USB OUT to the line at the controller): min {} median {} max {} guest instructions over {} lines",
        counts[0],
        counts[counts.len() / 2],
        counts[counts.len() - 1],
        counts.len()
    );
    assert!(counts[0] > 0);
}
