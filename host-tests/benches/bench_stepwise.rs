//! Benchmark: stepwise regression on n × p candidates already in memory (default 1,000,000 × 60),
//! side by side with the Octave reference implementation (`ms_stepwisefit`, timed inside Octave
//! on the same data), with the peak memory of this process (VmHWM) against the design matrix.
//!
//! Run: `cargo bench --bench bench_stepwise -- [--rows N] [--cols P] [--no-octave]`

#![allow(clippy::needless_range_loop)] // column-wise data generation reads best with indices

use std::io::Write;
use std::path::Path;
use std::process::Command;
use std::time::Instant;

use nanocal::numerics::stepwise::{stepwise, StepwiseOptions};

/// Peak resident set size of this process, bytes (Linux `/proc/self/status` VmHWM).
fn vm_hwm_bytes() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// CPU time (user + system) of this process so far, s (`/proc/self/stat`, 100 ticks/s).
fn cpu_s() -> f64 {
    let s = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let after = s.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = after.split_whitespace().collect();
    let tick = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (tick(11) + tick(12)) / 100.0
}

/// 1-minute load average (other processes competing for the cores).
fn load_avg() -> String {
    std::fs::read_to_string("/proc/loadavg").map_or("?".into(), |s| {
        s.split_whitespace().next().unwrap_or("?").to_string()
    })
}

struct Rng(u64);
impl Rng {
    fn next_u64(&mut self) -> u64 {
        // xorshift64*
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f64 {
        // sum of 4 uniforms, centred and scaled: cheap, smooth enough for a benchmark design
        (self.uniform() + self.uniform() + self.uniform() + self.uniform() - 2.0)
            * 1.7320508075688772
    }
}

fn arg(name: &str) -> Option<String> {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1).cloned())
}

fn main() {
    let n: usize = arg("--rows").map_or(1_000_000, |v| v.parse().expect("--rows N"));
    let p: usize = arg("--cols").map_or(60, |v| v.parse().expect("--cols P"));
    let octave = !std::env::args().any(|a| a == "--no-octave");
    let hwm0 = vm_hwm_bytes().unwrap_or(0);

    // Design: columns with offsets and scales like position powers, temperatures and aux
    // channels, a few correlated; the response depends on 24 of them with decreasing weights.
    let t = Instant::now();
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let mut x: Vec<Vec<f64>> = Vec::with_capacity(p);
    for j in 0..p {
        let scale = 10f64.powf(2.0 * rng.uniform() - 1.0);
        let offset = 50.0 * rng.uniform();
        let mut col = Vec::with_capacity(n);
        if j >= 3 && j % 7 == 0 {
            let (a, b) = (j - 1, j - 3);
            for i in 0..n {
                col.push(0.6 * x[a][i] + 0.3 * x[b][i] + scale * 0.2 * rng.normal());
            }
        } else {
            for _ in 0..n {
                col.push(offset + scale * rng.normal());
            }
        }
        x.push(col);
    }
    let mut y = vec![0.0; n];
    for (k, j) in (0..p).step_by(p.div_ceil(24).max(1)).enumerate() {
        let sd = (x[j].iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt();
        let w = 0.5f64.powi(k as i32 / 2) / sd;
        for i in 0..n {
            y[i] += w * x[j][i];
        }
    }
    for v in y.iter_mut() {
        *v += 0.05 * rng.normal();
    }
    let design_bytes = (n * p * 8) as u64;
    eprintln!(
        "generated {n} × {p} design ({:.0} MB) in {:.2} s",
        design_bytes as f64 / 1e6,
        t.elapsed().as_secs_f64()
    );

    let xr: Vec<&[f64]> = x.iter().map(|c| c.as_slice()).collect();
    let t = Instant::now();
    let c0 = cpu_s();
    let res = stepwise(&xr, &y, &StepwiseOptions::default()).expect("stepwise");
    let rust_s = t.elapsed().as_secs_f64();
    let rust_cpu_s = cpu_s() - c0;
    let hwm = vm_hwm_bytes().unwrap_or(0);
    let selected: Vec<usize> = (0..p).filter(|&j| res.inmodel[j]).map(|j| j + 1).collect();
    println!(
        "nanocal stepwise: {n} × {p}: {rust_s:.3} s wall, {rust_cpu_s:.2} s CPU, {} steps, {} selected, R² {:.6} (load average {})",
        res.history.len(),
        selected.len(),
        res.r_squared,
        load_avg()
    );
    println!(
        "peak memory (VmHWM): {:.0} MB = {:.2} × design matrix ({:.0} MB); before generating data: {:.0} MB",
        hwm as f64 / 1e6,
        hwm as f64 / design_bytes as f64,
        design_bytes as f64 / 1e6,
        hwm0 as f64 / 1e6
    );

    if !octave {
        return;
    }
    if Command::new("octave-cli")
        .arg("--version")
        .output()
        .is_err()
    {
        println!("octave-cli not found: install with .ci/host.sh to compare");
        return;
    }
    let peer = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/peers/octave-stepwise");
    if !peer.join("ms_stepwisefit.m").is_file() {
        println!(
            "the Octave stepwise reference ({}) is not on this machine: no comparison",
            peer.display()
        );
        return;
    }
    // same data, column-major raw f64 [X y], read with fread; the fit alone is timed in Octave
    let dir = std::env::temp_dir().join(format!("nanocal-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let bin = dir.join("design.f64");
    {
        let mut f = std::io::BufWriter::new(std::fs::File::create(&bin).expect("create"));
        for col in x.iter().chain(std::iter::once(&y)) {
            let bytes: Vec<u8> = col.iter().flat_map(|v| v.to_le_bytes()).collect();
            f.write_all(&bytes).expect("write");
        }
    }
    drop(x);
    let script = format!(
        "addpath('{}'); fid = fopen('{}', 'r'); D = fread(fid, [{n}, {}], 'double'); fclose(fid); \
         X = D(:, 1:{p}); y = D(:, end); clear D; \
         t0 = tic(); [b, se, pval, inm, st] = ms_stepwisefit(X, y, 'display', 'off'); el = toc(t0); \
         printf('OCTAVE %.6f %s\\n', el, sprintf('%d,', find(inm)));",
        peer.display(),
        bin.display(),
        p + 1
    );
    let out = Command::new("octave-cli")
        .args([
            "--norc",
            "--no-history",
            "--no-window-system",
            "-q",
            "--eval",
            &script,
        ])
        .output()
        .expect("octave");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let line = stdout.lines().find(|l| l.starts_with("OCTAVE "));
    std::fs::remove_dir_all(&dir).ok();
    match line {
        Some(l) => {
            let mut it = l.split_whitespace().skip(1);
            let oct_s: f64 = it.next().and_then(|v| v.parse().ok()).unwrap_or(f64::NAN);
            let oct_sel: Vec<usize> = it
                .next()
                .unwrap_or("")
                .split(',')
                .filter_map(|v| v.parse().ok())
                .collect();
            println!("octave ms_stepwisefit (fit alone, timed in Octave): {oct_s:.3} s");
            println!(
                "speed-up: {:.1}×; selected sets identical: {}",
                oct_s / rust_s,
                oct_sel == selected
            );
        }
        None => println!("octave failed: {}", String::from_utf8_lossy(&out.stderr)),
    }
}
