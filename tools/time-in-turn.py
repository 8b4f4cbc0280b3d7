#!/usr/bin/env python3
"""Time commands in turn, round after round, so that a shared machine's drift falls on each alike.

Usage: time-in-turn.py ROUNDS 'NAME=COMMAND' ['NAME=COMMAND' ...]

Each round runs every command once, in the order given (output discarded; a failing command
stops the script). Wall time comes from `time.perf_counter`, CPU time (user + system of the
command and its children) from `getrusage`. Prints, per command: wall best, first quartile and
median, CPU and system-time medians, in ms. Used for BENCHMARKS.md's A/B tables, e.g.
  time-in-turn.py 60 'old=./nanocal-old stepwise design.csv --response y' \\
                     'new=./nanocal-new stepwise design.csv --response y'
"""
import resource
import shlex
import statistics
import subprocess
import sys
import time


def main():
    if len(sys.argv) < 3 or "=" not in sys.argv[2]:
        sys.exit(__doc__)
    rounds = int(sys.argv[1])
    commands = [arg.split("=", 1) for arg in sys.argv[2:]]
    runs = {name: [] for name, _ in commands}
    for _ in range(rounds):
        for name, command in commands:
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            start = time.perf_counter()
            subprocess.run(shlex.split(command), stdout=subprocess.DEVNULL, check=True)
            wall = time.perf_counter() - start
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            user = after.ru_utime - before.ru_utime
            system = after.ru_stime - before.ru_stime
            runs[name].append((wall, user + system, system))
    for name, rs in runs.items():
        wall = sorted(r[0] for r in rs)
        print(
            f"{name}: n={len(rs)} wall best {wall[0] * 1e3:.1f} q1 {wall[len(wall) // 4] * 1e3:.1f}"
            f" median {statistics.median(wall) * 1e3:.1f} ms; CPU median"
            f" {statistics.median(r[1] for r in rs) * 1e3:.1f} ms, system median"
            f" {statistics.median(r[2] for r in rs) * 1e3:.1f} ms"
        )


if __name__ == "__main__":
    main()
