#!/usr/bin/env bash
# Adds Debian's bookworm-backports suite to apt's sources, on whatever mirror this machine's
# own sources already use: the line is derived from the existing bookworm entry (deb822
# `.sources` or one-line `.list`), so no mirror host is written in the repository.
set -euo pipefail
as_root() { if [ "$(id -u)" = 0 ]; then "$@"; else sudo "$@"; fi; }

uri=""
# deb822: the URIs of the stanza whose Suites name plain "bookworm".
for f in /etc/apt/sources.list.d/*.sources; do
    [ -f "$f" ] || continue
    uri=$(awk '
        /^[[:space:]]*$/ { if (suite && u) { print u; exit } suite = 0; u = "" }
        /^URIs:/ { u = $2 }
        /^Suites:/ { for (i = 2; i <= NF; i++) if ($i == "bookworm") suite = 1 }
        END { if (suite && u) print u }' "$f" | head -n1)
    [ -n "$uri" ] && break
done
# one-line format: "deb [options] URI bookworm components".
if [ -z "$uri" ]; then
    uri=$(cat /etc/apt/sources.list /etc/apt/sources.list.d/*.list 2>/dev/null |
        sed -n 's/^deb[[:space:]]\+\(\[[^]]*\][[:space:]]\+\)\?\([^[:space:]]\+\)[[:space:]]\+bookworm[[:space:]].*/\2/p' |
        head -n1)
fi
if [ -z "$uri" ]; then
    echo "add-backports: no bookworm entry in apt's sources to derive bookworm-backports from" >&2
    exit 1
fi
echo "add-backports: bookworm-backports from $uri"
echo "deb $uri bookworm-backports main" | as_root tee /etc/apt/sources.list.d/bookworm-backports.list >/dev/null
