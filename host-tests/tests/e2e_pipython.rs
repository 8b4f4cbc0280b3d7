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

use fw_sim::{wait_until, Qemu, SensorSim, StageSim};
use nanocal::papers::published::published_1dof;
use nanocal_interface::status::Flags;
use nanocal_model::blob;
use pipython_session::{controller, TEMPS_C};

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
    let stage = StageSim::serve(q.connect(1), controller());
    let _sensors = SensorSim::start(q.link(), &TEMPS_C);
    let host_port = q.gcs_port();
    let mut c = q.client();
    let model = published_1dof().unwrap();
    let mut b = vec![0u8; blob::MAX_BLOB_LEN];
    let n = blob::encode(&model, &mut b).unwrap();
    c.upload(&b[..n]).unwrap();
    wait_until("sensors ready", &q.clock(), 20.0, || {
        let s = c.status().ok()?;
        (!s.flags.contains(Flags::SENSOR_BLOCK) && s.folds >= 2).then_some(())
    });

    let stdout = pipython_session::run(&py, host_port);
    pipython_session::check(&stdout, &model, stage.events(), stage.drain());
}
