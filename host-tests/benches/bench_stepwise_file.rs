//! Benchmark: stepwise regression from a CSV file, end to end (read + parse + fit + report), the
//! `nanocal stepwise` command against the Octave reference's command-line driver
//! (`../shared/peers/octave-stepwise/stepwise_oracle.sh`: `dlmread`, `ms_stepwisefit`, JSON out)
//! on the same file, each a whole process, timed from outside (wall and CPU of the child).
//! The reference is looked for beside the repository, or where `NANOCAL_OCTAVE_STEPWISE` says.
//!
//! Run: `cargo bench --bench bench_stepwise_file -- [--rows N]
//! [--cols P] [--runs K] [--no-octave] [--keep]` (default 200,000 × 40 candidates + the
//! response, values with 6 decimals as instruments write them, 3 runs of each side; best and
//! median printed). `--keep` leaves the design (and both JSON reports) in the temporary folder
//! it prints, to profile `nanocal stepwise` on the same file.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

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

/// CPU time (user + system) of the waited-for children so far, s.
fn children_cpu_s() -> f64 {
    // SAFETY: getrusage fills the struct we pass.
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    unsafe { libc::getrusage(libc::RUSAGE_CHILDREN, &mut ru) };
    let tv = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    tv(ru.ru_utime) + tv(ru.ru_stime)
}

fn load_avg() -> String {
    std::fs::read_to_string("/proc/loadavg").map_or("?".into(), |s| {
        s.split_whitespace().next().unwrap_or("?").to_string()
    })
}

/// Writes the design: candidates `x1..xP` with offsets and scales like positions, temperatures
/// and aux channels (every seventh a mix of two earlier ones), `y` on every third, plus noise.
fn write_design(path: &Path, n: usize, p: usize) {
    use std::io::Write;
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let params: Vec<(f64, f64)> = (0..p)
        .map(|_| (10f64.powf(2.0 * rng.uniform() - 1.0), 50.0 * rng.uniform()))
        .collect();
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).expect("create the CSV"));
    let names: Vec<String> = (1..=p).map(|j| format!("x{j}")).collect();
    writeln!(f, "{},y", names.join(",")).expect("write");
    let mut row = vec![0.0; p];
    let mut line = String::new();
    for _ in 0..n {
        line.clear();
        let mut y = 0.0;
        for j in 0..p {
            let (scale, offset) = params[j];
            row[j] = if j >= 3 && j % 7 == 0 {
                0.6 * row[j - 1] + 0.3 * row[j - 3] + scale * 0.2 * rng.normal()
            } else {
                offset + scale * rng.normal()
            };
            if j % 3 == 0 {
                y += 0.5f64.powi((j / 6) as i32) * row[j] / (offset + scale);
            }
            line.push_str(&format!("{:.6},", row[j]));
        }
        y += 0.05 * rng.normal();
        line.push_str(&format!("{y:.6}\n"));
        f.write_all(line.as_bytes()).expect("write");
    }
}

/// Runs `cmd` `runs` times; (wall s, CPU s) of each run.
fn time_runs(runs: usize, mut cmd: impl FnMut() -> Command) -> Vec<(f64, f64)> {
    (0..runs)
        .map(|_| {
            let c0 = children_cpu_s();
            let t = Instant::now();
            let out = cmd().output().expect("start the command");
            let wall = t.elapsed().as_secs_f64();
            assert!(
                out.status.success(),
                "the command failed: {}",
                String::from_utf8_lossy(&out.stderr)
            );
            (wall, children_cpu_s() - c0)
        })
        .collect()
}

fn best_median(v: &[(f64, f64)]) -> String {
    let mut w: Vec<f64> = v.iter().map(|r| r.0).collect();
    let mut c: Vec<f64> = v.iter().map(|r| r.1).collect();
    w.sort_by(f64::total_cmp);
    c.sort_by(f64::total_cmp);
    format!(
        "wall best {:.3} s, median {:.3} s; CPU best {:.3} s, median {:.3} s",
        w[0],
        w[w.len() / 2],
        c[0],
        c[c.len() / 2]
    )
}

fn selected(json: &Path) -> Vec<String> {
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(json).expect("read the JSON"))
            .expect("parse the JSON");
    v["selected"]
        .as_array()
        .expect("`selected` in the JSON")
        .iter()
        .map(|s| s.as_str().unwrap_or("?").to_string())
        .collect()
}

fn main() {
    let n: usize = arg("--rows").map_or(200_000, |v| v.parse().expect("--rows N"));
    let p: usize = arg("--cols").map_or(40, |v| v.parse().expect("--cols P"));
    let runs: usize = arg("--runs").map_or(3, |v| v.parse().expect("--runs K"));
    let octave = !std::env::args().any(|a| a == "--no-octave");
    let keep = std::env::args().any(|a| a == "--keep");
    // cargo builds the CLI, in this benchmark's profile, before it runs a benchmark
    let nanocal = PathBuf::from(env!("CARGO_BIN_EXE_nanocal"));
    let dir = std::env::temp_dir().join(format!("nanocal-bench-file-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let csv = dir.join("design.csv");
    let t = Instant::now();
    write_design(&csv, n, p);
    let size = std::fs::metadata(&csv).map_or(0, |m| m.len());
    eprintln!(
        "wrote {n} × {p} + y ({:.1} MB) in {:.1} s",
        size as f64 / 1e6,
        t.elapsed().as_secs_f64()
    );
    // warm the page cache for both sides
    let _ = std::fs::read(&csv);

    let ours_json = dir.join("nanocal.json");
    let ours = time_runs(runs, || {
        let mut c = Command::new(&nanocal);
        c.arg("stepwise")
            .arg(&csv)
            .args(["--response", "y", "--json"])
            .arg(&ours_json);
        c
    });
    let ours_sel = selected(&ours_json);
    let ours_best = ours.iter().map(|r| r.0).fold(f64::INFINITY, f64::min);
    println!(
        "nanocal stepwise (read, parse, fit, held-out refits, PI, VIF, report, JSON): {} ({} selected; load average {})",
        best_median(&ours),
        ours_sel.len(),
        load_avg()
    );
    let peer = std::env::var_os("NANOCAL_OCTAVE_STEPWISE")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/peers/octave-stepwise")
        });
    if octave && !peer.join("stepwise_oracle.sh").is_file() {
        println!(
            "the Octave stepwise reference ({}) is not on this machine: no comparison",
            peer.display()
        );
    } else if octave
        && Command::new("octave-cli")
            .arg("--version")
            .output()
            .is_err()
    {
        println!("octave-cli not found: install with .ci/host.sh to compare");
    } else if octave {
        let oct_json = dir.join("octave.json");
        let oct = time_runs(runs, || {
            let mut c = Command::new("sh");
            c.arg(peer.join("stepwise_oracle.sh"))
                .arg(&csv)
                .arg(&oct_json);
            c
        });
        let oct_sel = selected(&oct_json);
        let oct_best = oct.iter().map(|r| r.0).fold(f64::INFINITY, f64::min);
        println!(
            "octave stepwise_oracle.sh (dlmread, ms_stepwisefit, JSON): {} (load average {})",
            best_median(&oct),
            load_avg()
        );
        println!(
            "speed-up (best wall against best wall): {:.0}×; selected sets identical: {}",
            oct_best / ours_best,
            oct_sel == ours_sel
        );
    }
    if keep {
        println!("kept the design and the reports in {}", dir.display());
    } else {
        std::fs::remove_dir_all(&dir).ok();
    }
}
