//! PI's own PIPython (from PyPI, no PI DLL: its pure-Python socket gateway) drives the
//! simulated controller through the QEMU compensator, unchanged: MOV is corrected, qPOS is
//! mapped back, and an error the compensator raises surfaces as a GCSError on PIPython's
//! automatic `ERR?`.
//!
//! Python: `$NANOCAL_PYTHON`, else `../target/pipython-venv/bin/python` (made by
//! `.ci/firmware.sh`), else `python3`; it must import `pipython`. Without it (or without QEMU)
//! the test is skipped loudly — except in CI (`CI` set), where it fails.

mod fw_sim;

use fw_sim::{repo_root, Qemu, SensorSim, StageSim};
use nanocal::published::published_1dof;
use nanocal_compensator::mgmt::flags;
use nanocal_model::{blob, SlowInputs};
use std::path::PathBuf;
use std::process::Command;
use std::time::{Duration, Instant};

const SCRIPT: &str = r#"
import sys
from pipython import GCSError
from pipython.pidevice.interfaces.pisocket import PISocket
from pipython.pidevice.gcsmessages import GCSMessages
from pipython.pidevice.gcscommands import GCSCommands

with PISocket(host='127.0.0.1', port=int(sys.argv[1])) as gateway:
    gateway.settimeout(20000)
    with GCSCommands(GCSMessages(gateway)) as dev:
        print('IDN', dev.qIDN().strip(), flush=True)
        dev.MOV('1', 100.0)
        print('POS', repr(float(dev.qPOS('1')['1'])), flush=True)
        dev.MVR('1', 20.0)
        print('MOVQ', repr(float(dev.qMOV('1')['1'])), flush=True)
        try:
            dev.MOV('1', 500.0)
            print('NOERROR', flush=True)
        except GCSError as e:
            print('GCSERROR', e.val, flush=True)
        print('POS2', repr(float(dev.qPOS('1')['1'])), flush=True)
"#;

fn python() -> Option<PathBuf> {
    let mut candidates = vec![];
    if let Some(p) = std::env::var_os("NANOCAL_PYTHON") {
        candidates.push(PathBuf::from(p));
    }
    candidates.push(repo_root().join("target/pipython-venv/bin/python"));
    candidates.push(PathBuf::from("python3"));
    candidates.into_iter().find(|p| {
        Command::new(p)
            .args(["-c", "import pipython"])
            .output()
            .map(|o| o.status.success())
            .unwrap_or(false)
    })
}

#[test]
fn e2e_pipython_through_the_compensator() {
    let Some(py) = python() else {
        assert!(
            std::env::var_os("CI").is_none(),
            "PIPython missing in CI (run .ci/firmware.sh first)"
        );
        eprintln!("\n**********\ne2e_pipython: SKIPPED — no Python with `pipython` (pip install pipython, or run .ci/firmware.sh)\n**********\n");
        return;
    };
    let Some(mut q) = Qemu::start_or_skip("e2e_pipython") else {
        return;
    };
    let temps = [22.0f32, 22.125, 21.875, 22.25];
    let stage = StageSim::start(q.connect(1), 1);
    let _sensors = SensorSim::start(q.link(), &temps);
    let host_port = q.gcs_port();
    let mut c = q.client();
    let model = published_1dof().unwrap();
    let mut b = vec![0u8; blob::MAX_BLOB_LEN];
    let n = blob::encode(&model, &mut b).unwrap();
    c.upload(&b[..n]).unwrap();
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let s = c.status().unwrap();
        if s.flags & flags::SENSOR_BLOCK == 0 && s.folds >= 2 {
            break;
        }
        assert!(Instant::now() < deadline, "sensors never ready");
        std::thread::sleep(Duration::from_millis(50));
    }

    let out = Command::new(&py)
        .args(["-c", SCRIPT, &host_port.to_string()])
        .output()
        .expect("run python");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "PIPython script failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let value = |key: &str| -> String {
        stdout
            .lines()
            .find_map(|l| l.strip_prefix(&format!("{key} ")))
            .unwrap_or_else(|| panic!("{key} missing in:\n{stdout}"))
            .to_string()
    };
    assert!(value("IDN").contains("E-727"));
    let pos: f64 = value("POS").parse().unwrap();
    assert!(
        (pos - 100.0).abs() <= 2e-4,
        "qPOS through the compensator: {pos}"
    );
    let movq: f64 = value("MOVQ").parse().unwrap();
    assert!((movq - 120.0).abs() <= 2e-4, "qMOV after MVR: {movq}");
    assert_eq!(
        value("GCSERROR"),
        "9001",
        "compensator's own error on PIPython's ERR?"
    );
    let pos2: f64 = value("POS2").parse().unwrap();
    assert!(
        (pos2 - 120.0).abs() <= 2e-4,
        "the refused MOV moved nothing: {pos2}"
    );

    // what the controller saw: corrected MOVs, PIPython's queries, never the refused target
    let mut slow = SlowInputs::default();
    for (i, t) in temps.iter().enumerate() {
        slow.temps_c[i] = f64::from(*t);
    }
    let lines = stage.drain();
    let movs: Vec<f64> = lines
        .iter()
        .filter(|l| l.starts_with("MOV 1 "))
        .map(|l| l[6..].parse().unwrap())
        .collect();
    assert_eq!(movs.len(), 2, "{lines:?}");
    let want0 = model.eval_f64(&[100.0, 0.0, 0.0], &[0; 3], &slow)[0];
    let want1 = model.eval_f64(&[120.0, 0.0, 0.0], &[1, 0, 0], &slow)[0];
    assert!(
        (movs[0] - want0).abs() <= 1e-4 && (movs[1] - want1).abs() <= 1e-4,
        "{movs:?}"
    );
    assert!(
        lines.iter().any(|l| l == "ERR?"),
        "PIPython's own ERR? reached the controller"
    );
}
