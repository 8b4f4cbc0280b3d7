#!/usr/bin/env bash
# The STM32 image as a raw binary for the B-L475E-IOT01A's ST-LINK mass-storage drive (drag and
# drop onto DIS_L4IOT, no tool needed on the machine that flashes): builds the release image
# (default features) and writes target/thumbv7em-none-eabihf/release/nanocal-fw.bin (from
# 0x0800_0000: vector table, code, constants, .data's initial values) and its SHA-256 beside it
# (nanocal-fw.bin.sha256, `sha256sum -c` format). Needs an ARM-capable objcopy: llvm-objcopy
# (Debian `llvm`), arm-none-eabi-objcopy (Debian `binutils-arm-none-eabi`) or rust-objcopy
# (`rustup component add llvm-tools`); GNU binutils' plain objcopy does not read ARM ELFs.
set -euo pipefail
cd "$(dirname "$0")/.."

cargo build --release --bin nanocal-fw
dir=target/thumbv7em-none-eabihf/release
elf=$dir/nanocal-fw
bin=$dir/nanocal-fw.bin

objcopy=""
rust_objcopy="$(rustc --print sysroot)/lib/rustlib/$(rustc -vV | sed -n 's/^host: //p')/bin/rust-objcopy"
for c in llvm-objcopy arm-none-eabi-objcopy "$rust_objcopy"; do
    if "$c" --version >/dev/null 2>&1; then objcopy=$c; break; fi
done
if [ -z "$objcopy" ]; then
    echo "no ARM-capable objcopy: apt-get install llvm (or binutils-arm-none-eabi), or rustup component add llvm-tools" >&2
    exit 1
fi
"$objcopy" -O binary "$elf" "$bin"

# the binary is the image's flash contents: its length is the loaded sections' span
# (vector table + text + rodata + data, up to 4 bytes of alignment between them)
flash=$(size -A "$elf" | awk '$1 == ".vector_table" || $1 == ".text" || $1 == ".rodata" || $1 == ".data" { n += $2 } END { print n }')
len=$(stat -c %s "$bin")
if [ "$len" -lt "$flash" ] || [ "$len" -gt $((flash + 16)) ]; then
    echo "$bin is $len B, the image's flash sections $flash B" >&2
    exit 1
fi
(cd "$dir" && sha256sum nanocal-fw.bin > nanocal-fw.bin.sha256)
echo "$bin: $len B (flash sections $flash B), written by $objcopy"
cat "$bin.sha256"
