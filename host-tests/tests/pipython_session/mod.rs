//! The PIPython working session both boards run (tests/e2e_pipython.rs on QEMU,
//! tests/e2e_stm32_pipython.rs on the emulated B-L475E-IOT01A): PI's own PIPython (from PyPI, no
//! PI DLL: its pure-Python socket gateway) drives the compensator with a simulated C-867 behind
//! it: `qIDN`, `qSAI`, `qPUN`, `SVO`, `FRF` + `pitools.waitonreferencing`, `MOV` +
//! `pitools.waitontarget`, `MVR`, `MVE`, `HLT`, `STP`, `GOH`, `qPOS` of several axes,
//! `GetPosStatus` (`#3`), `IsMoving` (`#5`), `qERR`, lower-case raw commands through
//! `send`/`read`, commands refused while compensating, and `ERR?` sent in the same write as the
//! command (`embederr`). The simulated controller records every target it accepts; each one of
//! the model's axis is checked against the f64 reference of the calibrated target the script
//! meant.
#![allow(dead_code)]

use nanocal::virtual_bench::{Config, Event};
use nanocal_model::{Model, SlowInputs, MAX_AXES};
use std::path::PathBuf;
use std::process::Command;

/// The session; argument 1 is the TCP port of the GCS link.
pub const SCRIPT: &str = r#"
import sys
from pipython import GCSError, pitools
from pipython.pidevice.interfaces.pisocket import PISocket
from pipython.pidevice.gcsmessages import GCSMessages
from pipython.pidevice.gcscommands import GCSCommands

def show(key, value):
    print(key, value, flush=True)

def refused(call):
    try:
        call()
        return 'NOERROR'
    except GCSError as e:
        return e.val

with PISocket(host='127.0.0.1', port=int(sys.argv[1])) as gateway:
    gateway.settimeout(120000)
    msgs = GCSMessages(gateway)
    with GCSCommands(msgs) as dev:
        show('IDN', dev.qIDN().strip())
        show('AXES', ' '.join(dev.qSAI()))
        show('UNIT', dev.qPUN()['1'])
        dev.SVO(['1', '2'], [True, True])
        dev.FRF(['1', '2'])
        pitools.waitonreferencing(dev, axes=['1', '2'])
        show('REFERENCED', dev.qFRF(['1', '2'])['1'])
        dev.MOV(['1', '2'], [100.0, 50.0])
        pitools.waitontarget(dev, axes=['1', '2'])
        pos = dev.qPOS(['1', '2'])
        show('POS', '%r %r' % (pos['1'], pos['2']))
        dev.MVR('1', 20.0)
        pitools.waitontarget(dev, axes='1')
        show('MOVQ', repr(dev.qMOV('1')['1']))
        dev.MVE(['1', '2'], [150.0, 60.0])
        pitools.waitontarget(dev, axes=['1', '2'])
        # a long move, halted on the way: slow enough (125 s to its target) that the HLT
        # reaches the controller first however loaded the machine is
        dev.VEL('1', 2.0)
        dev.MOV('1', 400.0)
        dev.HLT('1', noraise=True)
        pitools.waitontarget(dev, axes='1')
        dev.VEL('1', 250.0)
        show('HALTED', repr(dev.qMOV('1')['1']))
        dev.MVR('1', 10.0)
        pitools.waitontarget(dev, axes='1')
        show('AFTERHALT', repr(dev.qMOV('1')['1']))
        dev.STP(noraise=True)
        dev.SVO(['1', '2'], [True, True])
        dev.MOV('1', 200.0)
        pitools.waitontarget(dev, axes='1')
        dev.GOH()
        pitools.waitontarget(dev, axes=['1', '2'])
        pos = dev.qPOS()
        show('HOME', '%r %r' % (pos['1'], pos['2']))
        show('POSSTATUS', repr(dev.GetPosStatus()['1']))
        show('MOVING', dev.IsMoving(['1', '2'])['1'])
        show('ERR', dev.qERR())
        dev.send('mov 1 42')
        pitools.waitontarget(dev, axes='1')
        show('LOWER', dev.read('pos? 1').strip())
        show('STE', refused(lambda: dev.STE('1', 5.0)))
        show('SVA', refused(lambda: dev.SVA('1', 10.0)))
        show('OUTSIDE', refused(lambda: dev.MOV('1', 500.0)))
        # ERR? in the same write as the command: the answers come back in order
        msgs.embederr = True
        show('EMBEDDED', refused(lambda: dev.MOV('1', 500.0)))
        dev.MOV('1', 250.0)
        msgs.embederr = False
        pitools.waitontarget(dev, axes='1')
        show('LAST', repr(dev.qPOS('1')['1']))
"#;

/// A Python that imports `pipython`: `$NANOCAL_PYTHON`, else `../target/pipython-venv/bin/python`
/// (made by `.ci/firmware.sh`), else `python3`.
pub fn python() -> Option<PathBuf> {
    let mut candidates = vec![];
    if let Some(p) = std::env::var_os("NANOCAL_PYTHON") {
        candidates.push(PathBuf::from(p));
    }
    candidates.push(nanocal::virtual_bench::repo_root().join("target/pipython-venv/bin/python"));
    candidates.push(PathBuf::from("python3"));
    candidates.into_iter().find(|p| {
        Command::new(p)
            .args(["-c", "import pipython"])
            .output()
            .map(|o| o.status.success())
            .unwrap_or(false)
    })
}

/// Temperatures the simulated sensors report (exact in MAX31856 LSBs).
pub const TEMPS_C: [f32; 4] = [22.0, 22.125, 21.875, 22.25];

/// A C-867 with two axes in µm: servo off and unreferenced at power-up; moves take time (the
/// script slows axis 1 to 2 µm/s for the move it halts on the way: 125 s to its target).
pub fn controller() -> Config {
    let mut cfg = Config::c867(2, "µm");
    for a in &mut cfg.axes {
        a.velocity = 250.0;
    }
    cfg
}

fn command(model: &Model, x_um: f64) -> f64 {
    let mut slow = SlowInputs::default();
    for (i, t) in TEMPS_C.iter().enumerate() {
        slow.temps_c[i] = f64::from(*t);
    }
    model.eval_f64(&[x_um, 0.0, 0.0], &[0; MAX_AXES], &slow)[0]
}

/// Run the session against `port`; its output (the script's `KEY value` lines).
pub fn run(py: &PathBuf, port: u16) -> String {
    let out = Command::new(py)
        .args(["-c", SCRIPT, &port.to_string()])
        .output()
        .expect("run python");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "PIPython script failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

/// Check what the script printed, the targets the controller accepted (`events`) and every
/// line it received (`seen`) against the f64 reference of `model`.
pub fn check(stdout: &str, model: &Model, events: Vec<Event>, seen: Vec<String>) {
    let value = |key: &str| -> String {
        stdout
            .lines()
            .find_map(|l| l.strip_prefix(&format!("{key} ")))
            .unwrap_or_else(|| panic!("{key} missing in:\n{stdout}"))
            .to_string()
    };
    let num = |key: &str| -> f64 { value(key).parse().unwrap() };
    let near = |key: &str, got: f64, want: f64| {
        assert!(
            (got - want).abs() <= 5e-4,
            "{key}: {got} vs {want} (session:\n{stdout})"
        );
    };
    assert!(value("IDN").contains("C-867"));
    assert_eq!(value("AXES"), "1 2");
    assert_eq!(value("UNIT"), "µm");
    assert_eq!(value("REFERENCED"), "True");
    let pos: Vec<f64> = value("POS")
        .split(' ')
        .map(|v| v.parse().unwrap())
        .collect();
    near("POS 1 (mapped)", pos[0], 100.0);
    near("POS 2 (not in the model, relayed)", pos[1], 50.0);
    near("MOVQ", num("MOVQ"), 120.0);
    let halted = num("HALTED");
    assert!(
        halted > 150.0 - 5e-4 && halted < 390.0,
        "HLT stopped the move on the way: {halted}"
    );
    near("AFTERHALT", num("AFTERHALT"), halted + 10.0);
    let home: Vec<f64> = value("HOME")
        .split(' ')
        .map(|v| v.parse().unwrap())
        .collect();
    near("HOME 1", home[0], 0.0);
    near("HOME 2", home[1], 0.0);
    near("POSSTATUS", num("POSSTATUS"), 0.0);
    assert_eq!(value("MOVING"), "False");
    assert_eq!(value("ERR"), "0");
    near(
        "LOWER",
        value("LOWER").strip_prefix("1=").unwrap().parse().unwrap(),
        42.0,
    );
    assert_eq!(value("STE"), "9008");
    assert_eq!(value("SVA"), "9008");
    assert_eq!(value("OUTSIDE"), "9001");
    assert_eq!(value("EMBEDDED"), "9001");
    near("LAST", num("LAST"), 250.0);

    // every target the controller accepted on the model's axis, in order, against the f64
    // reference of what the script meant
    let targets: Vec<(f64, String)> = events
        .into_iter()
        .filter_map(|e| match e {
            Event::Target { axis: 0, value, by } => Some((value, by)),
            Event::RawMotion { command, .. } => panic!("{command} reached the controller"),
            _ => None,
        })
        .collect();
    let meant = [
        100.0,
        120.0,
        150.0,
        400.0,
        halted + 10.0,
        200.0,
        0.0,
        42.0,
        250.0,
    ];
    assert_eq!(targets.len(), meant.len(), "{targets:?}");
    for ((q, by), x) in targets.iter().zip(meant) {
        let want = command(model, x);
        assert!(
            (q - want).abs() <= 5e-4,
            "target for {x} µm: controller got {q} ({by}), correction {want}"
        );
        assert!(by == "MOV" || by == "MVE", "{by}");
    }
    assert_eq!(targets[2].1, "MVE", "a vector move stays one");
    // the controller saw the script's three MOV? and the proxy's own before each of the two
    // MVR (the base of a relative move is the controller's target, after HLT as always);
    // never the lower-case line raw, never a refused command
    assert_eq!(
        seen.iter().filter(|s| *s == "MOV? 1").count(),
        5,
        "{seen:?}"
    );
    assert!(!seen.iter().any(|s| s == "mov 1 42"), "{seen:?}");
    assert!(
        !seen.iter().any(|s| {
            let s = s.to_ascii_uppercase();
            s.starts_with("STE") || s.starts_with("SVA")
        }),
        "{seen:?}"
    );
}
