#!/usr/bin/env bash
# Build prerequisites of the emulated B-L475E-IOT01A (emulator/, issue 16): the unicorn-engine
# crate builds the Unicorn CPU emulator from its bundled C sources with CMake, and generates its
# bindings with bindgen (libclang). Idempotent; called by .ci/test-all.sh before the host
# workspace is built (clippy --all-targets compiles the emulator as a dev-dependency).
set -euo pipefail
need=()
command -v cmake >/dev/null 2>&1 || need+=(cmake)
ls /usr/lib/x86_64-linux-gnu/libclang-14.so* >/dev/null 2>&1 || ls /usr/lib/*/libclang-14.so* >/dev/null 2>&1 || need+=(libclang1-14)
[ -d /usr/lib/llvm-14/lib/clang ] || need+=(libclang-common-14-dev)
if [ ${#need[@]} -gt 0 ]; then
  SUDO=""
  if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
  echo "emulator.sh: installing ${need[*]} (Debian packages)"
  $SUDO apt-get update
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y --no-install-recommends "${need[@]}"
fi
echo "emulator.sh: $(cmake --version | head -n1)"
