#!/usr/bin/env bash
# What running the firmware under QEMU needs (idempotent, quick when already there): the
# thumbv7em target and QEMU >= 10 (bookworm-backports on Debian 12). Used by .ci/firmware.sh
# and tools/main-job.sh.
set -euo pipefail
cd "$(dirname "$0")/.."

as_root() { if [ "$(id -u)" = 0 ]; then "$@"; else sudo "$@"; fi; }

rustup target list --installed | grep -qx thumbv7em-none-eabihf || rustup target add thumbv7em-none-eabihf

qemu_major() { qemu-system-arm --version 2>/dev/null | sed -n 's/.*version \([0-9]*\)\..*/\1/p' | head -n1; }
if [ "$(qemu_major || true)" = "" ] || [ "$(qemu_major)" -lt 10 ]; then
    if ! grep -rqs "bookworm-backports" /etc/apt/sources.list /etc/apt/sources.list.d/; then
        bash "$(dirname "$0")/add-backports.sh"
    fi
    as_root apt-get update
    as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -t bookworm-backports qemu-system-arm
fi
qemu-system-arm --version | head -n1
