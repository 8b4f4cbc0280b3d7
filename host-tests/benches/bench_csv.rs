//! Benchmark: CSV recording parsing throughput (MB/s), in memory and from a file.
//!
//! Two inputs of the shared layout (t, cmd_x, meas_x, four temp_*, pressure):
//! values written as instruments write them (6 decimals, like the digital twin), and values
//! written with full round-trip precision (17 significant digits; the slower exact path).
//!
//! Run: `cargo bench --bench bench_csv -- [--rows N]`

use std::fmt::Write as _;
use std::time::Instant;

use nanocal::data::recording::Recording;

fn arg(name: &str) -> Option<String> {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1).cloned())
}

fn make(rows: usize, full_precision: bool) -> Vec<u8> {
    let mut s = String::with_capacity(rows * 90);
    s.push_str("t,cmd_x,meas_x,temp_base,temp_stage,temp_air,temp_frame,pressure\n");
    let mut state = 0x1234_5678_9abc_def1u64;
    let mut u = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    for i in 0..rows {
        let t = i as f64;
        let cmd = 30.0 * ((i / 60) % 17) as f64;
        let vals = [
            t,
            cmd,
            cmd + 0.3 * u() - 0.15,
            20.1 + 0.3 * u(),
            20.3 + 0.3 * u(),
            19.9 + 0.3 * u(),
            20.0 + 0.3 * u(),
            1013.0 + 5.0 * u(),
        ];
        for (k, v) in vals.iter().enumerate() {
            if k > 0 {
                s.push(',');
            }
            if full_precision {
                let _ = write!(s, "{v}");
            } else {
                let f = format!("{v:.6}");
                s.push_str(f.trim_end_matches('0').trim_end_matches('.'));
            }
        }
        s.push('\n');
    }
    s.into_bytes()
}

fn best_of(bytes: &[u8], runs: usize) -> (f64, usize) {
    let mut best = f64::INFINITY;
    let mut rows = 0;
    for _ in 0..runs {
        let t = Instant::now();
        let rec = Recording::parse(bytes).expect("valid CSV");
        best = best.min(t.elapsed().as_secs_f64());
        rows = rec.rows();
    }
    (best, rows)
}

fn main() {
    let rows: usize = arg("--rows").map_or(2_000_000, |v| v.parse().expect("--rows N"));
    for (label, full) in [
        ("instrument precision (6 decimals)", false),
        ("full precision (17 digits)", true),
    ] {
        let bytes = make(rows, full);
        let (s, n) = best_of(&bytes, 3);
        let mb = bytes.len() as f64 / 1e6;
        println!(
            "parse {label}: {mb:.0} MB, {n} rows in {s:.3} s = {:.0} MB/s",
            mb / s
        );
        let path = std::env::temp_dir().join(format!("nanocal-bench-{}.csv", std::process::id()));
        std::fs::write(&path, &bytes).expect("write temp file");
        let t = Instant::now();
        let rec = Recording::read_path(&path).expect("read");
        let s = t.elapsed().as_secs_f64();
        std::fs::remove_file(&path).ok();
        println!(
            "  read_path from file (page cache): {} rows in {s:.3} s = {:.0} MB/s",
            rec.rows(),
            mb / s
        );
    }
}
