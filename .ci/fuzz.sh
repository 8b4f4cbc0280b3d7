#!/usr/bin/env bash
# Fuzzing on the stable toolchain (issue 20 §4): every target of fuzz/ for a bounded time from
# its committed seeds (fuzz/seeds/<target>/), without sanitizers (stable Rust; a Rust panic is
# what the checks report). Installs cargo-fuzz from crates.io only when it is missing.
#   FUZZ_SECONDS   time per target (default 25 s; 7 targets: about 3 min, plus the build)
#   FUZZ_TARGETS   targets to run (default: all, as `cargo fuzz list` names them)
#   FUZZ_RUNS      run this many inputs per target instead of a time (the benchmark run of
#                  BENCHMARKS.md: FUZZ_RUNS=10000000)
#   FUZZ_TIMEOUT   seconds one input may take (default 10). libFuzzer's timer counts wall time:
#                  a long run at `nice -n 19` beside busy builds can see a 1 ms input take
#                  seconds, so such runs pass a larger bound
# A crash stops the run; its input is in fuzz/artifacts/<target>/. Fix it, add a regression
# test, and keep the input in fuzz/seeds/<target>/ (host-tests/tests/fuzz_seeds.rs replays
# every seed in the normal test suite).
set -euo pipefail
cd "$(dirname "$0")/../fuzz"
command -v cargo-fuzz >/dev/null 2>&1 || cargo install cargo-fuzz --locked
secs=${FUZZ_SECONDS:-25}
if [ -n "${FUZZ_RUNS:-}" ]; then bound=(-runs="$FUZZ_RUNS"); else bound=(-max_total_time="$secs"); fi
cargo fuzz build --sanitizer none
targets=${FUZZ_TARGETS:-$(cargo fuzz list)}
for t in $targets; do
    corpus=target/corpus/$t
    mkdir -p "$corpus"
    echo "fuzz: $t (${bound[*]})"
    # -seed fixes libFuzzer's choices: a run repeats the same inputs in the same order, only
    # how far it gets depends on the machine's speed
    log=target/fuzz-$t.log
    start=$(date +%s)
    if ! cargo fuzz run --sanitizer none "$t" "$corpus" "seeds/$t" -- \
        -seed=1 "${bound[@]}" -max_len=4096 -timeout="${FUZZ_TIMEOUT:-10}" -rss_limit_mb=2048 \
        -print_final_stats=1 >"$log" 2>&1; then
        tail -n 60 "$log" >&2
        echo "fuzz: $t failed; the input is in fuzz/artifacts/$t/" >&2
        exit 1
    fi
    grep -E '^(#[0-9]+.*DONE|stat::(number_of_executed_units|average_exec_per_sec|peak_rss_mb))' "$log"
    echo "fuzz: $t done in $(( $(date +%s) - start )) s, corpus $(ls "$corpus" | wc -l) inputs"
done
