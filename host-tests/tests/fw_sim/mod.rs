//! Test rig for the QEMU firmware: the library's virtual bench (QEMU process, simulated stage
//! controller and sensor chips), shared by the e2e tests and benchmarks, and the helpers they
//! share.
#![allow(unused_imports, dead_code)]

pub use nanocal::virtual_bench::*;
use std::time::{Duration, Instant};

/// Poll `f` every 20 ms until it gives a value. Fails the test when `board_s` seconds of the
/// board's clock have passed since the call — the behaviour's bound, in the time the firmware
/// lives in (free-running, it follows the wall clock only as fast as QEMU gets the CPU) — or
/// when the wall time reaches [`HANG`].
pub fn wait_until<T>(
    what: &str,
    clock: &BenchClock,
    board_s: f64,
    mut f: impl FnMut() -> Option<T>,
) -> T {
    let until_s = clock.now_s() + board_s;
    let hang = Instant::now() + HANG;
    loop {
        // the board's time first: a value that arrives after the bound still fails
        let late = clock.now_s() > until_s;
        if let Some(v) = f() {
            return v;
        }
        assert!(!late, "{what}: not within {board_s} s of the board's time");
        assert!(
            Instant::now() < hang,
            "{what}: nothing after {HANG:?} of wall time (hung?)"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Wait (up to [`HANG`] of wall time) until `done`, ringing the board in case QEMU's loop
/// sleeps on the socket: for what the board does on the bench's bytes, not on its own time.
pub fn wait_for(q: &Qemu, what: &str, mut done: impl FnMut() -> bool) {
    let hang = Instant::now() + HANG;
    while !done() {
        assert!(
            Instant::now() < hang,
            "{what}: not within {HANG:?} of wall time"
        );
        q.link().wake_for_input();
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// Let at least `s` seconds of the board's time pass (wall time is no measure of it: the board
/// runs behind the wall clock when the machine is loaded).
pub fn pass_board_time(clock: &BenchClock, s: f64) {
    let until_s = clock.now_s() + s;
    wait_until("board time to pass", clock, s + 3600.0, || {
        (clock.now_s() >= until_s).then_some(())
    });
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
        let line = stage.next_line(HANG);
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
        let line = stage.next_line(HANG);
        if !own_query(&line) {
            return line;
        }
    }
}

/// Run the `nanocal` CLI built with these tests; its stdout (the test fails on a non-zero exit,
/// with the CLI's stderr).
pub fn nanocal_cli(args: &[&str]) -> String {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_nanocal"))
        .args(args)
        .output()
        .expect("run the nanocal CLI");
    assert!(
        out.status.success(),
        "nanocal {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Upload `model` with the `nanocal device upload` CLI (through [`Qemu::cli_spec`]), `tag`
/// naming its temporary blob file; the CLI must say the model is in service.
pub fn upload_with_cli(q: &Qemu, model: &nanocal_model::Model, tag: &str) {
    let mut b = vec![0u8; nanocal_model::blob::MAX_BLOB_LEN];
    let n = nanocal_model::blob::encode(model, &mut b).unwrap();
    let path = std::env::temp_dir().join(format!("nanocal-e2e-{tag}-{}.blob", std::process::id()));
    std::fs::write(&path, &b[..n]).unwrap();
    let out = nanocal_cli(&[
        "device",
        "upload",
        "--port",
        &q.cli_spec(),
        path.to_str().unwrap(),
    ]);
    let _ = std::fs::remove_file(&path);
    assert!(out.contains("in service"), "{out}");
}

/// The status once the model `id` is in service, folded at least twice on readings of the
/// first four sensors (all of them ok) and warmed up.
pub fn in_service(q: &mut Qemu, id: u32) -> nanocal_interface::status::Status {
    use nanocal_interface::status::{ChannelStatus, Flags};
    let clk = q.clock();
    let mut c = q.client();
    wait_until("model folded on every sensor", &clk, 20.0, || {
        let s = c.status().ok()?;
        let ok = s.flags.contains(Flags::MODEL)
            && s.model_id == id
            && !s.flags.contains(Flags::WARMING_UP)
            && s.sensor_bits[..4]
                .iter()
                .all(|b| b.state == ChannelStatus::Ok)
            && s.folds >= 2;
        ok.then_some(s)
    })
}
