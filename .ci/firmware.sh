#!/usr/bin/env bash
# Firmware: install what the build and the QEMU end-to-end test need (fresh Debian bookworm, as
# root or with sudo), build both boards in release, clippy both with warnings as errors, fmt.
# The e2e tests run with the host tests (cd host-tests && cargo test); they build the QEMU
# image on their own. tests/e2e_pipython.rs uses the PIPython venv this script makes.
set -euo pipefail
cd "$(dirname "$0")/.."

as_root() { if [ "$(id -u)" = 0 ]; then "$@"; else sudo "$@"; fi; }
apt_updated=""
apt_install() {
    if [ -z "$apt_updated" ]; then as_root apt-get update; apt_updated=1; fi
    as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y "$@"
}

rustup component add clippy rustfmt
bash "$(dirname "$0")/qemu.sh"

# PIPython (PI's Python library, from PyPI) for tests/e2e_pipython.rs, in a venv under target/.
venv=target/pipython-venv
if ! "$venv/bin/python" -c "import pipython" 2>/dev/null; then
    command -v python3 >/dev/null || apt_install python3
    python3 -m venv "$venv" 2>/dev/null || { apt_install python3-venv && rm -rf "$venv" && python3 -m venv "$venv"; }
    "$venv/bin/pip" install --quiet pipython
fi

# STM32 board (default features) and QEMU board.
cargo build --release
cargo build --release --no-default-features --features qemu
# the virtual bench's board image: the `qemu` profile (optimised for speed, Cargo.toml)
cargo build --profile qemu --no-default-features --features qemu --bin nanocal-fw-qemu
cargo clippy --release -- -D warnings
cargo clippy --release --no-default-features --features qemu -- -D warnings
cargo fmt --check

# Image sizes, and the STM32 image's budget: flash = vector table + text + rodata + data
# <= 256 KiB, static RAM = data + bss + uninit <= 64 KiB (of the STM32L475VG's 1 MiB and
# 128 KiB). GNU size reads the ARM ELF's section headers (binutils is on every Debian).
command -v size >/dev/null || apt_install binutils
elf=target/thumbv7em-none-eabihf/release/nanocal-fw
size -A "$elf" target/thumbv7em-none-eabihf/qemu/nanocal-fw-qemu | grep -E '^(target/.*|\.vector_table|\.text|\.rodata|\.data|\.bss|\.uninit) '
size -A "$elf" | awk '
    $1 == ".vector_table" || $1 == ".text" || $1 == ".rodata" { flash += $2 }
    $1 == ".data" { flash += $2; ram += $2 }
    $1 == ".bss" || $1 == ".uninit" { ram += $2 }
    END {
        printf "STM32 image: flash %d B (%.1f KiB of 256), static RAM %d B (%.1f KiB of 64)\n", flash, flash / 1024, ram, ram / 1024
        if (flash > 262144 || ram > 65536) { print "STM32 image over budget" > "/dev/stderr"; exit 1 }
    }'

# The image as a raw binary for the ST-LINK's mass-storage drive (src/README.md, Flash): an
# ARM-capable objcopy first (GNU binutils' objcopy does not read ARM ELFs).
if ! command -v llvm-objcopy >/dev/null && ! command -v arm-none-eabi-objcopy >/dev/null; then
    apt_install binutils-arm-none-eabi
fi
bash tools/stm32-bin.sh
