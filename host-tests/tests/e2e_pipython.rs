//! PI's own PIPython (from PyPI, no PI DLL: its pure-Python socket gateway) drives the QEMU
//! compensator through a realistic working session with a simulated C-867 behind it: `qIDN`,
//! `qSAI`, `qPUN`, `SVO`, `FRF` + `pitools.waitonreferencing`, `MOV` + `pitools.waitontarget`,
//! `MVR`, `MVE`, `HLT`, `STP`, `GOH`, `qPOS` of several axes, `GetPosStatus` (`#3`),
//! `IsMoving` (`#5`), `qERR`, lower-case raw commands through `send`/`read`, commands refused
//! while compensating, and `ERR?` sent in the same write as the command (`embederr`). The
//! simulated controller records every target it accepts; each one of the model's axis is
//! checked against the f64 reference of the calibrated target the script meant.
//!
//! Python: `$NANOCAL_PYTHON`, else `../target/pipython-venv/bin/python` (made by
//! `.ci/firmware.sh`), else `python3`; it must import `pipython`. Without it (or without QEMU)
//! the test is skipped loudly — except in CI (`CI` set), where it fails.

mod fw_sim;
mod pipython_session;

use fw_sim::{Qemu, SensorSim, StageSim};
use nanocal::published::published_1dof;
use nanocal_compensator::mgmt::flags;
use nanocal_model::blob;
use pipython_session::{controller, TEMPS_C};
use std::time::{Duration, Instant};

#[test]
fn e2e_pipython_session_through_the_compensator() {
    let Some(py) = pipython_session::python() else {
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
    // the halted move lasts 1 s (`controller()`), so the HLT that follows it over QEMU's
    // serial ports reaches the controller in time even on a loaded machine
    let stage = StageSim::serve(q.connect(1), controller());
    let _sensors = SensorSim::start(q.link(), &TEMPS_C);
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

    let stdout = pipython_session::run(&py, host_port);
    pipython_session::check(&stdout, &model, stage.events(), stage.drain());
}
