#!/usr/bin/env bash
# Every test nanocal has, from a fresh Debian machine with rustup: installs what it needs,
# builds the firmware, lints both workspaces, runs the host tests (model, blob, host tools).
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)
step() { printf '\n==> %s\n' "$*"; }

step "toolchain"
rustup component add clippy rustfmt >/dev/null 2>&1 || true
rustup target add thumbv7em-none-eabihf

step "firmware: QEMU 10, both boards in release, clippy -D warnings, fmt"
bash "$root/.ci/firmware.sh"

step "emulated STM32 board prerequisites (cmake, libclang for the unicorn-engine crate)"
bash "$root/.ci/emulator.sh"

step "host workspace: format and lints"
cd "$root/host-tests"
cargo fmt --all --check
cargo clippy --all-targets -- -D warnings

step "shared no_std crates build for the firmware target (with and without defmt)"
for crate in nanocal-model nanocal-interface nanocal-compensator; do
    cargo clippy -p "$crate" --target thumbv7em-none-eabihf -- -D warnings
    cargo clippy -p "$crate" --target thumbv7em-none-eabihf --features defmt -- -D warnings
done

step "fuzzing: every decoder of outside input, 25 s per target from the committed seeds (stable, no sanitizer)"
bash "$root/.ci/fuzz.sh"

step "host prerequisites (GNU Octave for the differential stepwise test)"
bash "$root/.ci/host.sh"

step "host tests: every crate of the host workspace (model, compensator, host tools), unit and integration"
cd "$root/host-tests"
cargo test --workspace --no-fail-fast
