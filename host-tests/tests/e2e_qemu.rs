//! End to end: the QEMU firmware between a host and a simulated stage controller.
//!
//! Builds the QEMU image (`cargo build --release --no-default-features --features qemu` at the
//! repository root), starts `qemu-system-arm -M mps2-an386` with four TCP serial ports on free
//! 127.0.0.1 ports, plays a GCS stage controller on serial1 and MAX31856 sensors on serial2,
//! uploads a model with `nanocal device upload` (serial3), then checks MOV/MVR/POS? against the
//! host's f64 evaluation, rejected uploads, and the sensor fault policy.
//!
//! Without qemu-system-arm the test is skipped with a loud message, except in CI (`CI` set),
//! where it fails.

mod fw_sim;

use fw_sim::{stage_value, wait_until, Qemu, SensorSim, StageSim, HANG};
use nanocal::device::DeviceError;
use nanocal::papers::published::published_1dof;
use nanocal_compensator::sensor::max31856;
use nanocal_interface::mgmt::Refusal;
use nanocal_interface::status::{ChannelStatus, Flags, SensorFault};
use nanocal_model::{blob, SlowInputs, MAX_AXES};

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
fn e2e_compensator_under_qemu() {
    let Some(mut q) = Qemu::start_or_skip("e2e_compensator_under_qemu") else {
        return;
    };
    let clk = q.clock();
    let stage = StageSim::start(q.connect(1), 1);
    let sensors = SensorSim::start(q.link(), &TEMPS_C);
    let mut host = q.gcs_host();

    // the device answers on its management port
    let mut c = q.client();
    let (proto, format, _) = c.hello().expect("hello");
    assert_eq!(format, blob::FORMAT_VERSION);
    assert_eq!(proto, nanocal_interface::mgmt::PROTOCOL);
    let s = c.status().unwrap();
    assert!(
        !s.flags.contains(Flags::MODEL),
        "no model before the upload"
    );
    drop(c);

    // without a model, moves are refused (and nothing reaches the controller)
    host.send("MOV 1 10");
    assert_eq!(host.ask("ERR?"), "9003");

    // upload with the CLI, exactly as a user would
    let model = published_1dof().unwrap();
    let mut b = vec![0u8; blob::MAX_BLOB_LEN];
    let n = blob::encode(&model, &mut b).unwrap();
    let path = std::env::temp_dir().join(format!("nanocal-e2e-{}.blob", std::process::id()));
    std::fs::write(&path, &b[..n]).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_nanocal"))
        .args(["device", "upload", "--port", &q.cli_spec()])
        .arg(&path)
        .output()
        .unwrap();
    let _ = std::fs::remove_file(&path);
    assert!(
        out.status.success(),
        "nanocal device upload failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("in service"));

    let mut c = q.client();
    let s = wait_until("sensors read and model folded", &clk, 20.0, || {
        let s = c.status().ok()?;
        let ok = s.flags.contains(Flags::MODEL)
            && !s.flags.contains(Flags::SENSOR_BLOCK)
            && s.sensor_bits[..4]
                .iter()
                .all(|b| b.state == ChannelStatus::Ok)
            && s.folds >= 2;
        ok.then_some(s)
    });
    assert_eq!(s.model_id, model.id());
    for (i, t) in TEMPS_C.iter().enumerate() {
        assert_eq!(s.temps_c[i], *t);
    }
    assert!(
        s.flags.contains(Flags::MOVE_FOLD),
        "the status reports move_fold"
    );
    assert_eq!(
        s.move_fold, 0,
        "no move corrected yet (the one without a model was refused)"
    );

    // MOV: the forwarded command equals the host's f64 evaluation within 0.1 nm
    let dir0 = [0i8; MAX_AXES];
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
    let first = stage.drain_until(|l| l.starts_with("MOV "), HANG);
    assert_eq!(
        first[..first.len() - 1],
        [
            "*IDN?", "CSV?", "*IDN?", "SAI?", "PUN? 1", "*IDN?", "TMN? 1", "*IDN?", "TMX? 1",
            "*IDN?"
        ],
        "{first:?}"
    );
    let fwd = first.last().unwrap().clone();
    check(stage_value(&fwd, "1"), 100.0, dir0);

    // the status names the fold that corrected the move; it stays while later folds run, and
    // the next move takes the fold then in service
    let s1 = c.status().unwrap();
    assert!(
        s1.move_fold != 0 && s.folds <= s1.move_fold && s1.move_fold <= s1.folds,
        "move_fold {} outside the folds around the move ({}..={})",
        s1.move_fold,
        s.folds,
        s1.folds
    );
    let s2 = wait_until("two more folds", &clk, 20.0, || {
        let x = c.status().ok()?;
        (x.folds >= s1.folds + 2).then_some(x)
    });
    assert_eq!(s2.move_fold, s1.move_fold, "no move since: the same fold");
    host.send("MOV 1 100");
    let _ = stage.next_line(HANG);
    let s3 = c.status().unwrap();
    assert!(
        s2.folds <= s3.move_fold && s3.move_fold <= s3.folds,
        "move_fold {} outside {}..={}",
        s3.move_fold,
        s2.folds,
        s3.folds
    );

    // MVR becomes an absolute MOV, from the base the controller holds (MOV?)
    host.send("MVR 1 12.5");
    assert_eq!(stage.next_line(HANG), "MOV? 1");
    let fwd = stage.next_line(HANG);
    check(stage_value(&fwd, "1"), 112.5, [1, 0, 0]);

    // POS? maps back to calibrated coordinates
    let reply = host.ask("POS? 1");
    let x = reply.strip_prefix("1=").unwrap().parse::<f64>().unwrap();
    assert!((x - 112.5).abs() <= 2e-4, "POS? mapped to {x}");
    let reply = host.ask("MOV?");
    let x = reply.strip_prefix("1=").unwrap().parse::<f64>().unwrap();
    assert!((x - 112.5).abs() <= 2e-4, "MOV? mapped to {x}");
    assert_eq!(
        stage.drain(),
        ["POS? 1", "MOV?"],
        "queries forwarded untouched"
    );

    // many targets, both directions
    let mut prev = 112.5;
    for k in 0..40 {
        let x = ((k * 7919) % 4800) as f64 / 10.0 + 0.0123;
        host.send(&format!("MOV 1 {x:.4}"));
        let fwd = stage.next_line(HANG);
        let dir = if x > prev { 1 } else { -1 };
        check(stage_value(&fwd, "1"), x, [dir, 0, 0]);
        prev = x;
    }
    assert_eq!(
        host.ask("ERR?"),
        "0",
        "no error so far (the controller answers)"
    );
    assert_eq!(stage.drain(), ["ERR?"]);

    // other commands pass untouched; single-character commands too
    host.send("VEL 1 10");
    assert_eq!(stage.next_line(HANG), "VEL 1 10");
    host.send_raw(&[0x05]);
    assert_eq!(stage.next_line(HANG), "#5");
    assert_eq!(host.read_line(HANG), "0");
    assert!(host.ask("*IDN?").contains("E-727"));
    // (a controller may not know #5: the compensator's marker followed it)
    assert_eq!(stage.drain(), ["*IDN?", "*IDN?"]);

    // outside the envelope: GCS error, nothing moves
    host.send("MOV 1 500");
    assert_eq!(host.ask("ERR?"), "9001");
    host.send("SVO 1 1");
    assert_eq!(
        stage.next_line(HANG),
        "SVO 1 1",
        "MOV 500 was not forwarded"
    );

    // corrupt and truncated uploads are rejected; the old model stays in service
    let mut bad = b[..n].to_vec();
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
            &b[..n / 2],
            n as u32,
            blob::crc32(&b[..n]),
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
    let e = c
        .upload_raw(
            &b[..n],
            n as u32,
            blob::crc32(&b[..n]) ^ 1,
            blob::FORMAT_VERSION,
            true,
        )
        .unwrap_err();
    assert!(
        matches!(
            e,
            DeviceError::Refused {
                refusal: Refusal::UploadCrc,
                ..
            }
        ),
        "{e}"
    );
    let s = c.status().unwrap();
    assert_eq!(s.model_id, model.id());
    assert_eq!(s.uploads_rejected, 3);
    assert_eq!(s.uploads_ok, 1);
    host.send("MOV 1 200");
    let fwd = stage.next_line(HANG);
    check(
        stage_value(&fwd, "1"),
        200.0,
        [if prev < 200.0 { 1 } else { -1 }, 0, 0],
    );

    // a sensor fault: held for the hold time, then shown in status and blocking moves
    sensors.set_status(1, max31856::SR_OPEN);
    let s = wait_until("sensor fault to block moves", &clk, 30.0, || {
        let s = c.status().ok()?;
        (s.flags.contains(Flags::SENSOR_BLOCK)).then_some(s)
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
    assert_eq!(
        stage.next_line(HANG),
        "SVO 1 1",
        "blocked MOV not forwarded"
    );
    // recovery
    sensors.set_status(1, 0);
    wait_until("sensor recovery", &clk, 30.0, || {
        let s = c.status().ok()?;
        (!s.flags.contains(Flags::SENSOR_BLOCK)).then_some(())
    });
    host.send("MOV 1 250");
    let fwd = stage.next_line(HANG);
    check(stage_value(&fwd, "1"), 250.0, [1, 0, 0]);

    // bypass forwards untouched
    c.bypass(true).unwrap();
    host.send("MOV 1 42");
    assert_eq!(stage.next_line(HANG), "MOV 1 42");
    c.bypass(false).unwrap();

    // KMZ from a reference: the model now maps the measured position to the command sent
    let before = c.status().unwrap();
    let kmz = c.set_kmz([250.0, 0.0, 0.0], [249.9, 0.0, 0.0]).unwrap();
    assert!(kmz[0].abs() > 1e-3);
    let s = c.status().unwrap();
    assert_eq!(s.kmz_um[0], kmz[0]);
    assert_eq!(before.model_id, s.model_id);
    // and it is in service: the same target now gets a command shifted by Δλ_KMZ
    let shifted = model.eval_f64(&[250.0, 0.0, 0.0], &[0; MAX_AXES], &slow())[0] + kmz[0];
    host.send("MOV 1 250");
    let got = stage_value(&stage.next_line(HANG), "1");
    assert!(
        (got - shifted).abs() <= 1e-4,
        "after KMZ: {got} vs {shifted}"
    );

    // the CLI's status report
    drop(c);
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_nanocal"))
        .args(["device", "status", "--port", &q.cli_spec()])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains("model: 0x00010001"), "{text}");
    assert!(text.contains("sensor 1:"), "{text}");
    assert!(text.contains("uploads ok 1  rejected 3"), "{text}");
    assert!(text.contains("chip UID"), "{text}");

    // a reset: the model and its λ_KMZ come back from flash, the reset cause says why
    let mut c = q.client();
    let boots = q.link().boots();
    c.reset().unwrap();
    drop(c);
    // the board answers first, then resets: ask the new boot, not the old one
    wait_until("the reset", &clk, 10.0, || {
        (q.link().boots() > boots).then_some(())
    });
    let mut c = q.client();
    let h = c.identify().unwrap();
    assert_eq!(
        h.reset_cause,
        nanocal_interface::identity::ResetCause::Software
    );
    let s = wait_until("model reloaded", &clk, 20.0, || {
        let s = c.status().ok()?;
        (s.flags.contains(Flags::MODEL)).then_some(s)
    });
    assert_eq!(s.model_id, model.id());
    assert_eq!(s.kmz_um[0], kmz[0], "λ_KMZ stored with the model");
}

/// A coupled 2-DoF model through the firmware: both axes re-commanded, and a multi-line `POS?`
/// reply collected whole and mapped back through the 2-D inverse.
#[test]
fn e2e_coupled_2dof_under_qemu() {
    let Some(mut q) = Qemu::start_or_skip("e2e_coupled_2dof_under_qemu") else {
        return;
    };
    let clk = q.clock();
    let stage = StageSim::start(q.connect(1), 2);
    let _sensors = SensorSim::start(q.link(), &TEMPS_C);
    let mut host = q.gcs_host();
    let mut c = q.client();
    let model = nanocal::papers::published::coupled_2dof().unwrap();
    let mut b = vec![0u8; blob::MAX_BLOB_LEN];
    let n = blob::encode(&model, &mut b).unwrap();
    c.upload(&b[..n]).unwrap();
    wait_until("sensors ready", &clk, 20.0, || {
        let s = c.status().ok()?;
        (!s.flags.contains(Flags::SENSOR_BLOCK) && s.folds >= 2).then_some(())
    });

    // a single-axis MOV before any full target: the coupled axis' target is read from the
    // controller first (MOV?), then both axes are commanded
    host.send("MOV 1 40");
    assert_eq!(host.ask("ERR?"), "0");
    let mut seen = stage.drain();
    assert_eq!(seen.pop().as_deref(), Some("ERR?"));
    let (last, own) = seen.split_last().unwrap();
    assert!(own.iter().all(|l| fw_sim::own_query(l)), "{seen:?}");
    assert!(own.contains(&"MOV? 1 2".to_string()), "{seen:?}");
    assert!(
        last.starts_with("MOV 1 ") && last.contains(" 2 "),
        "{seen:?}"
    );

    host.send("MOV 1 40 2 70");
    let fwd = stage.next_line(HANG);
    let want = model.eval_f64(&[40.0, 70.0, 0.0], &[0; MAX_AXES], &slow());
    for (a, axis) in ["1", "2"].iter().enumerate() {
        let got = stage_value(&fwd, axis);
        assert!(
            (got - want[a]).abs() <= 1e-4,
            "axis {axis}: {got} vs {}",
            want[a]
        );
    }
    // moving x alone re-commands y too (coupling), kept where the controller holds it
    host.send("MOV 1 50");
    assert_eq!(stage.next_line(HANG), "MOV? 1 2");
    let fwd = stage.next_line(HANG);
    let want = model.eval_f64(&[50.0, 70.0, 0.0], &[1, 0, 0], &slow());
    for (a, axis) in ["1", "2"].iter().enumerate() {
        let got = stage_value(&fwd, axis);
        assert!(
            (got - want[a]).abs() <= 1e-4,
            "axis {axis}: {got} vs {}",
            want[a]
        );
    }
    // the controller answers POS? on two lines; the host gets both mapped back
    let reply = host.ask("POS?");
    let xy: Vec<f64> = reply
        .lines()
        .map(|l| l.split('=').nth(1).unwrap().parse().unwrap())
        .collect();
    assert_eq!(xy.len(), 2, "{reply}");
    assert!(
        (xy[0] - 50.0).abs() <= 2e-4 && (xy[1] - 70.0).abs() <= 2e-4,
        "{reply}"
    );
}
