//! End to end on the emulated B-L475E-IOT01A: the shipped STM32 image (`nanocal-fw`, release,
//! default features) between a USB host and the simulated stage controller on UART4, with the
//! MAX31856 register models on SPI1 (DMA), the LPS22HB on I2C2 and the force input on ADC1 —
//! the same chips and controller the QEMU e2e tests use (tests/e2e_qemu.rs).
//!
//! The host enumerates the board, a client opens the management port (CDC-ACM interface 2) and
//! `nanocal device upload` stores a model, the sensors' first conversions fold it, and a GCS
//! client on the GCS port (interface 0) sends moves that reach the controller corrected.

mod stm32_sim;

use nanocal::published::published_1dof;
use nanocal_compensator::mgmt::flags;
use nanocal_model::{blob, SlowInputs, MAX_AXES};
use stm32_sim::{default_buses, Stm32};

/// Temperatures the simulated sensors report (exact in MAX31856 LSBs), inside 21–23 °C.
const TEMPS_C: [f32; 4] = [22.0, 22.125, 21.875, 22.25];

fn slow() -> SlowInputs {
    let mut s = SlowInputs::default();
    for (i, t) in TEMPS_C.iter().enumerate() {
        s.temps_c[i] = f64::from(*t);
    }
    s
}

fn stage_value(line: &str, axis: &str) -> f64 {
    let t: Vec<&str> = line.split_whitespace().collect();
    assert_eq!(t.first(), Some(&"MOV"), "forwarded line {line:?}");
    let i = t.iter().position(|a| *a == axis).unwrap();
    t[i + 1].parse().unwrap()
}

#[test]
fn e2e_stm32_upload_sensors_and_corrected_moves() {
    let b = Stm32::start(default_buses(&TEMPS_C));
    b.usb.attach();

    let mut c = b.mgmt();
    let s = c.status().unwrap();
    assert_eq!(s.flags & flags::MODEL, 0, "no model before the upload");
    let id = c.identify().unwrap();
    assert_eq!(
        id.reset_cause,
        nanocal_compensator::identity::ResetCause::PowerOn,
        "RCC_CSR says power-on (BORRSTF)"
    );

    // upload over the management port (CDC-ACM interface 2)
    let model = published_1dof().unwrap();
    let mut blob_bytes = vec![0u8; blob::MAX_BLOB_LEN];
    let n = blob::encode(&model, &mut blob_bytes).unwrap();
    let committed = c.upload(&blob_bytes[..n]).expect("upload");
    assert_eq!(committed.model_id, model.id());

    // the sensors' first conversions (MAX31856 over SPI1 + DMA) fold the model
    let mut s = c.status().unwrap();
    let t0 = b.now_s();
    while !(s.flags & flags::MODEL != 0 && s.flags & flags::SENSOR_BLOCK == 0 && s.folds >= 2) {
        assert!(
            b.now_s() - t0 < 5.0,
            "no fold within 5 s of board time: {s:?}"
        );
        b.run_for(0.1);
        s = c.status().unwrap();
    }
    assert_eq!(s.model_id, model.id());
    for (i, t) in TEMPS_C.iter().enumerate() {
        assert_eq!(s.temps_c[i], *t, "sensor {i} read over SPI1");
    }
    drop(c);

    // a GCS session on interface 0: the move reaches the controller on UART4 corrected
    let mut gcs = b.gcs();
    gcs.send("MOV 1 100");
    assert_eq!(b.stage_line(1.0), "CSV?");
    assert_eq!(b.stage_line(1.0), "PUN? 1");
    let fwd = b.stage_line(1.0);
    let want = model.eval_f64(&[100.0, 0.0, 0.0], &[0; MAX_AXES], &slow())[0];
    let got = stage_value(&fwd, "1");
    assert!(
        (got - want).abs() <= 1e-4,
        "forwarded {got}, f64 reference {want}"
    );
    // POS? maps back through the inverse
    let reply = gcs.ask("POS? 1");
    let x: f64 = reply.strip_prefix("1=").unwrap().parse().unwrap();
    assert!((x - 100.0).abs() <= 2e-4, "POS? mapped to {x}");
    assert_eq!(gcs.ask("ERR?"), "0");
    let st = b.status();
    assert_eq!(
        st.boots.len(),
        1,
        "no reset during the session: {:?}",
        st.log
    );
}
