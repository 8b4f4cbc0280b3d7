//! Firmware benchmarks (ignored by default; the figures go to BENCHMARKS.md):
//!
//! ```text
//! cd host-tests && cargo test --release --test fw_bench -- --ignored --nocapture --test-threads 1
//! ```
//! - guest instructions per fast-path correction, per MOV line through the proxy, per inverse
//!   and per fold, counted under QEMU by the TCG plugin in tools/qemu-plugin (built with gcc);
//! - latency the proxy adds to a MOV line and sustained MOV lines per second (QEMU board);
//! - flash and static RAM of both images.

mod fw_sim;

use fw_sim::{bench_elf, qemu_elf, qemu_or_skip, repo_root, Elf, Qemu, SensorSim, StageSim};
use nanocal::papers::published::published_1dof;
use nanocal_model::blob;
use std::process::Command;
use std::time::{Duration, Instant};

/// The regions of src/bin/qemu_bench.rs, in order.
const REGIONS: [&str; 22] = [
    "empty loop (overhead, subtracted)",
    "`Fold::correct`, 1-DoF, 8 terms",
    "`Fold::correct`, 2-DoF, 40 terms",
    "`MOV` line through the proxy (host bytes in, corrected line out), 1-DoF, 8 terms",
    "`Model::eval_f64`, 1-DoF (soft-float f64 reference)",
    "`Fold::inverse`, 1-DoF (POS?/MOV? replies), started at the reply",
    "`Model::fold`, 2-DoF, 40 terms (slow path; N/10 iterations)",
    "`Fold::correct`, 1-DoF, 8 terms + 16 play operators (walk with reversals)",
    "`Fold::correct`, 3-DoF, 78 terms (paper 001's robot size), 105 coefficients",
    "`Fold::correct`, 1-DoF, 8 terms + fast force input (F, x·F)",
    "`Fold::correct` + `Fold::inverse_from` of its reply started at the target, 1-DoF + 16 play operators",
    "`Fold::inverse`, 3-DoF, 78 terms",
    "`Fold::inverse_from`, 1-DoF, started at the last target (reply 3 nm off)",
    "`Model::fold`, 3-DoF, 78 terms (slow path; N/10 iterations)",
    "published 1-DoF: `MOV` line + `POS? 1` + its reply 3 nm off the command, mapped",
    "published 1-DoF: `MOV` line alone (subtracted from the two rounds)",
    "published 1-DoF: `MOV` line + `MOV? 1` + its reply equal to the command, mapped",
    "published 1-DoF: `HLT 1` + `POS? 1` + its reply, mapped with no target known",
    "published 1-DoF: `HLT 1` line alone (subtracted)",
    "8-term 1-DoF: `MOV` line + `POS? 1` + its reply 3 nm off the command, mapped",
    "published 1-DoF: `Fold::inverse` (the model's own inverse)",
    "CRC-32 of the largest management frame (324 bytes: header and 320-byte payload)",
];

/// Derived figures: (name, region, region subtracted).
const DERIVED: [(&str, usize, usize); 5] = [
    (
        "`Fold::inverse_from`, 1-DoF + 16 play operators, started at the last target (state frozen)",
        10,
        7,
    ),
    (
        "published 1-DoF: `POS?` mapping (query line + reply mapped; warm start at the target)",
        14,
        15,
    ),
    (
        "published 1-DoF: `MOV?` mapping (query line + reply equal to the command sent)",
        16,
        15,
    ),
    (
        "published 1-DoF: `POS?` mapping with no target known (cold start at the reply)",
        17,
        18,
    ),
    (
        "8-term 1-DoF: `POS?` mapping (warm start at the target)",
        19,
        3,
    ),
];
/// Regions that run N/10 iterations.
const SLOW_REGIONS: [usize; 2] = [6, 13];

#[test]
#[ignore = "benchmark: run with --ignored --nocapture"]
fn fw_bench_instructions() {
    if !qemu_or_skip("fw_bench_instructions") {
        return;
    }
    let elf_path = bench_elf();
    let elf = Elf::read(&elf_path);
    let dir = std::env::temp_dir().join(format!("nanocal-plugin-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let so = dir.join("libinsn_count.so");
    let st = Command::new("gcc")
        .args(["-shared", "-fPIC", "-O2", "-o"])
        .arg(&so)
        .arg(repo_root().join("tools/qemu-plugin/insn_count.c"))
        .status()
        .expect("gcc (needed to build the TCG plugin)");
    assert!(st.success(), "building the TCG plugin failed");
    let counts = dir.join("counts.txt");
    let mut runs = vec![];
    for _ in 0..2 {
        let out = Command::new("qemu-system-arm")
            .args([
                "-M",
                "mps2-an386",
                "-display",
                "none",
                "-monitor",
                "none",
                "-serial",
                "null",
            ])
            .args(["-semihosting-config", "enable=on,target=native"])
            .arg("-plugin")
            .arg(format!(
                "{},start={:#x},stop={:#x},out={}",
                so.display(),
                elf.symbol("nanocal_bench_start"),
                elf.symbol("nanocal_bench_stop"),
                counts.display()
            ))
            .arg("-kernel")
            .arg(&elf_path)
            .output()
            .expect("run qemu");
        assert!(
            out.status.success(),
            "bench image failed: {}",
            String::from_utf8_lossy(&out.stdout)
        );
        let text = std::fs::read_to_string(&counts).unwrap();
        let c: Vec<u64> = text
            .lines()
            .map(|l| l.rsplit(' ').next().unwrap().parse().unwrap())
            .collect();
        assert_eq!(c.len(), REGIONS.len(), "{text}");
        runs.push(c);
    }
    assert_eq!(runs[0], runs[1], "instruction counts are deterministic");
    let c = &runs[0];
    let n = 1000.0;
    let overhead = c[0] as f64 / n;
    println!("\n| region | guest instructions per call |\n|---|---:|");
    let mut per = vec![];
    for (i, name) in REGIONS.iter().enumerate() {
        let iters = if SLOW_REGIONS.contains(&i) {
            n / 10.0
        } else {
            n
        };
        per.push(c[i] as f64 / iters - if i == 0 { 0.0 } else { overhead });
        println!("| {name} | {:.0} |", per[i]);
    }
    for (name, a, b) in DERIVED {
        println!("| {name} | {:.0} |", per[a] - per[b]);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
#[ignore = "benchmark: run with --ignored --nocapture"]
fn fw_bench_sizes() {
    let root = repo_root();
    let cargo = option_env!("CARGO").unwrap_or("cargo");
    let st = Command::new(cargo)
        .current_dir(&root)
        .args(["build", "--release"])
        .env_remove("CARGO_TARGET_DIR")
        .env_remove("CARGO_BUILD_TARGET")
        .status()
        .unwrap();
    assert!(st.success());
    let stm32 = root.join("target/thumbv7em-none-eabihf/release/nanocal-fw");
    println!("\n| image | flash (bytes) | static RAM (bytes) |\n|---|---:|---:|");
    for (name, path) in [("nanocal-fw", stm32), ("nanocal-fw-qemu", qemu_elf())] {
        let e = Elf::read(&path);
        let (flash, ram) = e.flash_ram();
        println!("| {name} | {flash} | {ram} |");
        if name == "nanocal-fw" {
            assert!(flash <= 256 * 1024, "STM32 flash {flash} B > 256 KiB");
            assert!(ram <= 64 * 1024, "STM32 RAM {ram} B > 64 KiB");
        }
    }
}

fn median_p99(mut v: Vec<f64>) -> (f64, f64) {
    v.sort_by(f64::total_cmp);
    (v[v.len() / 2], v[(v.len() * 99) / 100])
}

#[test]
#[ignore = "benchmark: run with --ignored --nocapture"]
fn fw_bench_latency_throughput() {
    if !qemu_or_skip("fw_bench_latency_throughput") {
        return;
    }
    let mut q = Qemu::start(&[]);
    let stage = StageSim::start(q.connect(1), 1);
    let _sensors = SensorSim::start(q.link(), &[22.0, 22.125, 21.875, 22.25]);
    let mut host = q.gcs_host();
    let mut c = q.client();
    let model = published_1dof().unwrap();
    let mut b = vec![0u8; blob::MAX_BLOB_LEN];
    let n = blob::encode(&model, &mut b).unwrap();
    c.upload(&b[..n]).unwrap();
    fw_sim::wait_until("sensors ready", &q.clock(), 20.0, || {
        let s = c.status().ok()?;
        (!s.flags
            .contains(nanocal_interface::status::Flags::SENSOR_BLOCK)
            && s.folds >= 2)
            .then_some(())
    });
    // the first move waits for the controller's identity, syntax version, unit and travel:
    // not measured
    host.send("MOV 1 10");
    let mut asked = vec![];
    loop {
        let l = stage.next_line(Duration::from_secs(10));
        if l.starts_with("MOV 1 ") {
            break;
        }
        assert!(l.contains('?') && asked.len() < 16, "{l} after {asked:?}");
        asked.push(l);
    }
    for want in ["*IDN?", "CSV?", "PUN? 1"] {
        assert!(asked.iter().any(|l| l == want), "{want} not in {asked:?}");
    }

    let one_way = |host: &mut fw_sim::GcsHost, k: usize| {
        let t = Instant::now();
        host.send(&format!("MOV 1 {}", 10.0 + (k % 400) as f64));
        let l = stage.next_line(Duration::from_secs(10));
        assert!(l.starts_with("MOV 1 "), "{l}");
        t.elapsed().as_secs_f64() * 1e6
    };
    let samples = 300;
    let on: Vec<f64> = (0..samples).map(|k| one_way(&mut host, k)).collect();
    c.bypass(true).unwrap();
    let off: Vec<f64> = (0..samples).map(|k| one_way(&mut host, k)).collect();
    c.bypass(false).unwrap();
    let (on_med, on_p99) = median_p99(on);
    let (off_med, off_p99) = median_p99(off);
    println!("\n| MOV line host → stage (QEMU, µs) | median | p99 |\n|---|---:|---:|");
    println!("| compensating | {on_med:.0} | {on_p99:.0} |");
    println!("| bypass (relay only) | {off_med:.0} | {off_p99:.0} |");
    println!("| added by the correction | {:.0} | |", on_med - off_med);

    // sustained rate: many lines back to back, every one must arrive, corrected
    let lines = 2000;
    let mut burst = String::new();
    for k in 0..lines {
        burst += &format!("MOV 1 {:.3}\n", 1.0 + (k % 470) as f64 + 0.001 * k as f64);
    }
    let t = Instant::now();
    host.send_raw(burst.as_bytes());
    for k in 0..lines {
        let l = stage.next_line(Duration::from_secs(60));
        assert!(l.starts_with("MOV 1 "), "line {k}: {l}");
    }
    let secs = t.elapsed().as_secs_f64();
    let s = c.status().unwrap();
    assert_eq!(s.refused, 0, "no move refused or dropped");
    println!(
        "\nsustained: {lines} MOV lines in {secs:.2} s = {:.0} lines/s, none dropped",
        lines as f64 / secs
    );
}
