//! End to end on the emulated B-L475E-IOT01A: the shipped STM32 image (`nanocal-fw`, release,
//! default features) between a USB host and the simulated stage controller on UART4, with the
//! MAX31856 register models on SPI1 (DMA), the LPS22HB on I2C2 and the force input on ADC1 —
//! the same chips and controller the QEMU e2e tests use (tests/e2e_qemu.rs).
//!
//! The host enumerates the board, a client opens the management port (CDC-ACM interface 2) and
//! `nanocal device upload` stores a model, the sensors' first conversions fold it, and a GCS
//! client on the GCS port (interface 0) sends moves that reach the controller corrected.

mod stm32_sim;

use nanocal::device::Client;
use nanocal::published::published_1dof;
use nanocal::virtual_bench::StageSim;
use nanocal_compensator::mgmt::flags;
use nanocal_model::{blob, SlowInputs, MAX_AXES};
use std::io::{Read, Write};
use std::os::unix::net::UnixStream;
use std::time::{Duration, Instant};
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

/// A client on CDC port `k`, once the host has the board configured.
fn open_port(b: &Stm32, k: usize) -> UnixStream {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        if b.usb.with(|h| h.configured) {
            if let Ok(s) = UnixStream::connect(b.usb.port_path(k)) {
                return s;
            }
        }
        assert!(
            Instant::now() < deadline,
            "USB port {k} never opened: {:#?}",
            b.status()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn mgmt(b: &Stm32) -> Client {
    let s = open_port(b, 1);
    s.set_read_timeout(Some(Duration::from_millis(50))).ok();
    let mut c = Client::new(Box::new(s), &b.usb.port_spec(1), Duration::from_secs(10));
    c.timeout = Duration::from_secs(2);
    let deadline = Instant::now() + Duration::from_secs(30);
    while c.hello().is_err() {
        assert!(Instant::now() < deadline, "management port never answered");
    }
    c.timeout = Duration::from_secs(10);
    c
}

/// The GCS host on the GCS port.
struct Gcs {
    s: UnixStream,
    buf: Vec<u8>,
}

impl Gcs {
    fn send(&mut self, line: &str) {
        self.s.write_all(format!("{line}\n").as_bytes()).unwrap();
    }
    fn read_line(&mut self) -> String {
        let deadline = Instant::now() + Duration::from_secs(10);
        loop {
            if let Some(p) = self.buf.iter().position(|&b| b == b'\n') {
                let l: Vec<u8> = self.buf.drain(..=p).collect();
                return String::from_utf8_lossy(&l[..l.len() - 1]).into_owned();
            }
            assert!(Instant::now() < deadline, "no reply from the compensator");
            self.s
                .set_read_timeout(Some(Duration::from_millis(100)))
                .unwrap();
            let mut b = [0u8; 256];
            if let Ok(n) = self.s.read(&mut b) {
                assert!(n > 0, "the compensator closed the GCS port");
                self.buf.extend_from_slice(&b[..n]);
            }
        }
    }
    fn ask(&mut self, line: &str) -> String {
        self.send(line);
        self.read_line().trim_end().to_string()
    }
}

fn stage_value(line: &str, axis: &str) -> f64 {
    let t: Vec<&str> = line.split_whitespace().collect();
    assert_eq!(t.first(), Some(&"MOV"), "forwarded line {line:?}");
    let i = t.iter().position(|a| *a == axis).unwrap();
    t[i + 1].parse().unwrap()
}

#[test]
fn e2e_stm32_upload_sensors_and_corrected_moves() {
    let mut b = Stm32::start(default_buses(&TEMPS_C));
    let stage = StageSim::start(b.stage(), 1);
    b.usb.attach();

    let mut c = mgmt(&b);
    let s = c.status().unwrap();
    assert_eq!(s.flags & flags::MODEL, 0, "no model before the upload");
    let id = c.identify().unwrap();
    assert_eq!(
        id.reset_cause,
        nanocal_compensator::identity::ResetCause::PowerOn,
        "RCC_CSR says power-on (BORRSTF)"
    );
    drop(c);

    // upload with the CLI over the management port's socket, as a user would
    let model = published_1dof().unwrap();
    let mut blob_bytes = vec![0u8; blob::MAX_BLOB_LEN];
    let n = blob::encode(&model, &mut blob_bytes).unwrap();
    let path = std::env::temp_dir().join(format!("nanocal-e2e-stm32-{}.blob", std::process::id()));
    std::fs::write(&path, &blob_bytes[..n]).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_nanocal"))
        .args(["device", "upload", "--port", &b.usb.port_spec(1)])
        .arg(&path)
        .output()
        .unwrap();
    let _ = std::fs::remove_file(&path);
    assert!(
        out.status.success(),
        "nanocal device upload failed: {}{}\n{:#?}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
        b.status()
    );

    // the sensors' first conversions (MAX31856 over SPI1 + DMA) fold the model
    let mut c = mgmt(&b);
    let deadline = Instant::now() + Duration::from_secs(120);
    let s = loop {
        let s = c.status().unwrap();
        if s.flags & flags::MODEL != 0 && s.flags & flags::SENSOR_BLOCK == 0 && s.folds >= 2 {
            break s;
        }
        assert!(
            Instant::now() < deadline,
            "no fold: {s:?}\n{:#?}",
            b.status()
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    assert_eq!(s.model_id, model.id());
    for (i, t) in TEMPS_C.iter().enumerate() {
        assert_eq!(s.temps_c[i], *t, "sensor {i} read over SPI1");
    }
    drop(c);

    // a GCS session on interface 0: the move reaches the controller on UART4 corrected
    let mut gcs = Gcs {
        s: open_port(&b, 0),
        buf: vec![],
    };
    gcs.send("MOV 1 100");
    assert_eq!(stage.next_line(Duration::from_secs(20)), "CSV?");
    assert_eq!(stage.next_line(Duration::from_secs(20)), "PUN? 1");
    let fwd = stage.next_line(Duration::from_secs(20));
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
