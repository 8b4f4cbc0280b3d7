//! PIPython's working session (tests/pipython_session/) through the shipped STM32 image on the
//! emulated B-L475E-IOT01A: the model is uploaded with the `nanocal` CLI over the management
//! port, as a user would, then PI's PIPython drives the GCS port (CDC-ACM interface 0, served
//! on a local TCP port for PIPython's socket gateway) with a simulated C-867 on UART4.
//!
//! Both are external processes the rig cannot step, so here — and only here — the board is
//! paced by the wall clock ([`stm32_sim::Stm32::paced`], real time): the halted move would last
//! 125 s of board time, which leaves PIPython's HLT ample time on a loaded machine.
//!
//! Python as in tests/e2e_pipython.rs; without it the test is skipped loudly — except in CI
//! (`CI` set), where it fails.

mod pipython_session;
mod stm32_sim;

use nanocal::papers::published::published_1dof;
use nanocal_interface::status::Flags;
use nanocal_model::blob;
use pipython_session::{controller, TEMPS_C};
use stm32_sim::{default_buses, Stm32, FOLD_S};

#[test]
fn e2e_stm32_pipython_session_through_the_compensator() {
    let Some(py) = pipython_session::python() else {
        assert!(
            std::env::var_os("CI").is_none(),
            "PIPython missing in CI (run .ci/firmware.sh first)"
        );
        eprintln!("\n**********\ne2e_stm32_pipython: SKIPPED — no Python with `pipython` (pip install pipython, or run .ci/firmware.sh)\n**********\n");
        return;
    };
    let b = Stm32::start_with(default_buses(&TEMPS_C), controller(), None);
    b.usb.attach();
    b.enumerated(2.0);

    // upload with the CLI, exactly as a user would
    let model = published_1dof().unwrap();
    let mut bytes = vec![0u8; blob::MAX_BLOB_LEN];
    let n = blob::encode(&model, &mut bytes).unwrap();
    let path = std::env::temp_dir().join(format!("nanocal-e2e-stm32-{}.blob", std::process::id()));
    std::fs::write(&path, &bytes[..n]).unwrap();
    let out = b.paced(1.0, || {
        std::process::Command::new(env!("CARGO_BIN_EXE_nanocal"))
            .args(["device", "upload", "--port", &b.usb.port_spec(1)])
            .arg(&path)
            .output()
            .unwrap()
    });
    let _ = std::fs::remove_file(&path);
    assert!(
        out.status.success(),
        "nanocal device upload failed: {}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("in service"));
    let mut c = b.mgmt();
    b.status_until(&mut c, "sensors ready", 5.0 + FOLD_S, |s| {
        !s.flags.contains(Flags::SENSOR_BLOCK) && s.folds >= 2
    });
    drop(c);

    let port = b.usb.tcp_port(0);
    let stdout = b.paced(1.0, || pipython_session::run(&py, port));
    pipython_session::check(&stdout, &model, b.stage_events(), b.stage.all());
    assert_eq!(b.status().boots.len(), 1, "no reset: {:?}", b.status().log);
}
