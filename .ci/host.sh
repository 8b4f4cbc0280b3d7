#!/usr/bin/env bash
# Host-workflow prerequisites for the host tests (issue 3): GNU Octave + statistics package,
# needed by the differential stepwise test (tests/stepwise_octave.rs, which FAILS when CI=true
# and octave-cli is missing). Idempotent; called by .ci/test-all.sh before the host tests.
set -euo pipefail
if command -v octave-cli >/dev/null 2>&1; then
  echo "host.sh: octave-cli present: $(octave-cli --version | head -n1)"
  exit 0
fi
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
echo "host.sh: installing octave + octave-statistics (Debian packages)"
$SUDO apt-get update
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y --no-install-recommends octave octave-statistics
octave-cli --version | head -n1
