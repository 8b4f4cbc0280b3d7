#!/usr/bin/env bash
# The README's main job in one line on a fresh Debian machine with rustup:
#     bash tools/main-job.sh [campaign options…]
# Sets up what it needs — the thumbv7em target, QEMU >= 10 (.ci/qemu.sh), a TrueType font for
# the report's PNG plots — only where missing (a second run goes straight to the campaign),
# then runs paper 000's 1-DoF campaign on the virtual bench, cut to 20 training cycles, tests of
# 5 cycles and 3 rounds, into out/campaign/. Options after the script's name go to
# `nanocal campaign` (e.g. `--out DIR` instead of out/campaign/); `--published` runs the whole
# published procedure instead of the shortened one; `--board stm32` runs it on the emulated
# B-L475E-IOT01A with the shipped STM32 image (the `stm32-bench` program, built here first:
# GPL-2.0, it links Unicorn, which needs cmake and libclang — .ci/emulator.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)

as_root() { if [ "$(id -u)" = 0 ]; then "$@"; else sudo "$@"; fi; }

bash "$root/.ci/qemu.sh" >/dev/null
if [ -z "${NANOCAL_FONT:-}" ] && [ ! -f /usr/share/fonts/truetype/dejavu/DejaVuSans.ttf ]; then
    as_root apt-get update
    as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends fonts-dejavu-core
fi

shorten=(--shorten 20,5,3)
out=(--out "$root/out/campaign")
args=()
stm32=0
prev=
for a in "$@"; do
    case "$a" in
        --published) shorten=() ;;
        --out | --out=*) out=(); args+=("$a") ;;
        --board=stm32) stm32=1; args+=("$a") ;;
        *) [ "$prev" = --board ] && [ "$a" = stm32 ] && stm32=1; args+=("$a") ;;
    esac
    prev=$a
done

cd "$root/host-tests"
if [ "$stm32" = 1 ]; then
    bash "$root/.ci/emulator.sh" >/dev/null
    cargo build --release --quiet -p nanocal-stm32-bench
fi
exec cargo run --release --quiet -- campaign paper000-1dof --virtual "${shorten[@]}" "${out[@]}" "${args[@]}"
