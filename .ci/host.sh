#!/usr/bin/env bash
# Host-workflow prerequisites for the host tests (issue 3), idempotent; called by
# .ci/test-all.sh before the host tests:
#  - GNU Octave + statistics package: the differential stepwise test
#    (host-tests/tests/stepwise_octave.rs) FAILS when CI=true and octave-cli is missing;
#  - a TrueType font for the text of PNG plots (fonts-dejavu-core).
set -euo pipefail
need=()
command -v octave-cli >/dev/null 2>&1 || need+=(octave octave-statistics)
[ -f /usr/share/fonts/truetype/dejavu/DejaVuSans.ttf ] || [ -n "${NANOCAL_FONT:-}" ] || need+=(fonts-dejavu-core)
if [ ${#need[@]} -gt 0 ]; then
  SUDO=""
  if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
  echo "host.sh: installing ${need[*]} (Debian packages)"
  $SUDO apt-get update
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y --no-install-recommends "${need[@]}"
fi
echo "host.sh: $(octave-cli --version | head -n1)"
