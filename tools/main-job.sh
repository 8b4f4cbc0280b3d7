#!/usr/bin/env bash
# The README's main job in one line on a fresh Debian machine with rustup:
#     bash tools/main-job.sh [campaign options…]
# Sets up what it needs — the thumbv7em target, QEMU >= 10 (.ci/qemu.sh), a TrueType font for
# the report's PNG plots — only where missing (a second run goes straight to the campaign),
# then runs paper 000's 1-DoF campaign on the virtual bench — the whole published procedure
# (21,839 steps; ≈ 46 s on an idle 2-core machine, BENCHMARKS.md) — into out/campaign/. Options
# after the script's name go to `nanocal campaign` (e.g. `--out DIR` instead of out/campaign/);
# `--shortened` cuts it to 20 training cycles, tests of 5 cycles and 3 rounds; `--board stm32`
# runs it on the emulated B-L475E-IOT01A with the shipped STM32 image (the `stm32-bench`
# program, built here first: GPL-2.0, it links Unicorn, which needs cmake and libclang —
# .ci/emulator.sh), shortened unless `--published` is given (that emulation is slower).
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)

as_root() { if [ "$(id -u)" = 0 ]; then "$@"; else sudo "$@"; fi; }

bash "$root/.ci/qemu.sh" >/dev/null
if [ -z "${NANOCAL_FONT:-}" ] && [ ! -f /usr/share/fonts/truetype/dejavu/DejaVuSans.ttf ]; then
    as_root apt-get update
    as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends fonts-dejavu-core
fi

out=(--out "$root/out/campaign")
args=()
stm32=0
published=0
shortened=0
prev=
for a in "$@"; do
    case "$a" in
        --published) published=1 ;;
        --shortened) shortened=1 ;;
        --out | --out=*) out=(); args+=("$a") ;;
        --board=stm32) stm32=1; args+=("$a") ;;
        *) [ "$prev" = --board ] && [ "$a" = stm32 ] && stm32=1; args+=("$a") ;;
    esac
    prev=$a
done

shorten=()
if [ "$shortened" = 1 ] || { [ "$stm32" = 1 ] && [ "$published" = 0 ]; }; then
    shorten=(--shorten 20,5,3)
fi

cd "$root/host-tests"
if [ "$stm32" = 1 ]; then
    bash "$root/.ci/emulator.sh" >/dev/null
    cargo build --release --quiet -p nanocal-stm32-bench
fi
exec cargo run --release --quiet -- campaign paper000-1dof --virtual "${shorten[@]}" "${out[@]}" "${args[@]}"
