//! Test rig for the QEMU firmware: the library's virtual bench (QEMU process, simulated stage
//! controller and sensor chips), shared by the e2e tests and benchmarks, and the helpers they
//! share.
#![allow(unused_imports, dead_code)]

pub use nanocal::virtual_bench::*;
use std::time::{Duration, Instant};

/// Poll `f` every 50 ms until it gives a value; fails the test after `timeout`.
pub fn wait_until<T>(what: &str, timeout: Duration, mut f: impl FnMut() -> Option<T>) -> T {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(v) = f() {
            return v;
        }
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The value of `axis` in a forwarded `MOV` line.
pub fn stage_value(line: &str, axis: &str) -> f64 {
    let t: Vec<&str> = line.split_whitespace().collect();
    assert_eq!(t.first(), Some(&"MOV"), "forwarded line {line:?}");
    let i = t
        .iter()
        .position(|a| *a == axis)
        .unwrap_or_else(|| panic!("axis {axis} in {line:?}"));
    t[i + 1].parse().unwrap()
}

/// True for a line the compensator sends of its own: what it reads of the controller before
/// the first move (`*IDN?`, `CSV?`, `SAI?`, `PUN?`, `TMN?`, `TMX?`), the bases of a move
/// (`MOV?`) and its markers (`*IDN?`).
pub fn own_query(line: &str) -> bool {
    ["*IDN?", "CSV?", "SAI?"].contains(&line)
        || ["PUN? ", "TMN? ", "TMX? ", "MOV? "]
            .iter()
            .any(|p| line.starts_with(p))
}

/// The next `MOV` the controller receives (the compensator's own queries before it skipped).
pub fn next_move(stage: &StageSim) -> String {
    loop {
        let line = stage.next_line(Duration::from_secs(10));
        if line.starts_with("MOV ") {
            return line;
        }
        assert!(
            own_query(&line),
            "unexpected line before the move: {line:?}"
        );
    }
}

/// The next line the controller receives that is not one of the compensator's own queries.
pub fn next_host_line(stage: &StageSim) -> String {
    loop {
        let line = stage.next_line(Duration::from_secs(10));
        if !own_query(&line) {
            return line;
        }
    }
}
