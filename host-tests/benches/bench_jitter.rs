//! Benchmark of the command jitter the device's thermal fold puts on commands, through the QEMU
//! firmware on the virtual bench (`nanocal::virtual_bench::jitter`): one reading a fold (the
//! firmware before issue 18 folded each 250 ms reading) against the readings of a fold period
//! averaged. Run: `cargo bench --bench bench_jitter` in host-tests/ (needs QEMU ≥ 10,
//! `bash .ci/firmware.sh`).

use nanocal::virtual_bench::jitter::{measure, Periods};

fn main() {
    if !nanocal::virtual_bench::have_qemu() {
        eprintln!("bench_jitter: SKIPPED — qemu-system-arm ≥ 10 not found (bash .ci/firmware.sh)");
        return;
    }
    let moves = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(200);
    let periods = [
        Periods {
            sample_ms: 1000,
            fold_ms: 1000,
        },
        Periods {
            sample_ms: 250,
            fold_ms: 1000,
        },
        Periods {
            sample_ms: 250,
            fold_ms: 5000,
        },
        Periods {
            sample_ms: 250,
            fold_ms: 10000,
        },
    ];
    let t0 = std::time::Instant::now();
    match measure(&periods, moves, 11.0, 1) {
        Ok(rows) => {
            println!(
                "paper 000's static model (Table 1) on the QEMU firmware, four type K / MAX31856 (16 mK a reading), room constant, MOV 1 240 every 11 s:"
            );
            println!("sample ms  fold ms  readings/fold  moves  jitter nm (σ)  ‖b‖·σ_T/√n nm");
            for j in rows {
                let n = (f64::from(j.periods.fold_ms) / f64::from(j.periods.sample_ms)).max(1.0);
                println!(
                    "{:>9} {:>8} {:>14.0} {:>6} {:>14.1} {:>14.1}",
                    j.periods.sample_ms, j.periods.fold_ms, n, j.moves, j.sigma_nm, j.expected_nm
                );
            }
            println!("wall {:.1} s", t0.elapsed().as_secs_f64());
        }
        Err(e) => {
            eprintln!("bench_jitter: {e}");
            std::process::exit(1);
        }
    }
}
