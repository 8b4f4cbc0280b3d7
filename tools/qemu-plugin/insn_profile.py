#!/usr/bin/env python3
"""Add up an `insn_profile.c` profile by the firmware's functions.

Usage: insn_profile.py PROFILE ELF [STEPS]

Prints the total guest instructions (and per step, given the campaign's step count) and the
functions that executed the most, with their share. Symbols come from `nm` (GNU or LLVM: both
read the ARM ELF's symbol table); a block is counted to the function whose address range holds
its start.
"""
import bisect
import subprocess
import sys


def symbols(elf):
    out = subprocess.run(
        ["nm", "-C", "--defined-only", "-S", elf], capture_output=True, text=True, check=True
    ).stdout
    syms = []
    for line in out.splitlines():
        f = line.split(None, 3)
        if len(f) == 4 and f[2] in "tTwW":
            addr, size, name = int(f[0], 16) & ~1, int(f[1], 16), f[3]
            syms.append((addr, size, name))
    syms.sort()
    return syms


def main():
    prof, elf = sys.argv[1], sys.argv[2]
    steps = int(sys.argv[3]) if len(sys.argv) > 3 else 0
    syms = symbols(elf)
    starts = [s[0] for s in syms]
    by = {}
    total = 0
    with open(prof) as f:
        for line in f:
            f = line.split()
            if f[0] == "total":
                continue
            a, b, c = f
            pc, n, execs = int(a, 16) & ~1, int(b), int(c)
            i = bisect.bisect_right(starts, pc) - 1
            name = "?"
            if i >= 0 and pc < syms[i][0] + max(syms[i][1], 1):
                name = syms[i][2]
            by[name] = by.get(name, 0) + n * execs
            total += n * execs
    print(f"total {total:,} guest instructions", end="")
    if steps:
        print(f", {total / steps:,.0f} per step ({steps} steps)")
    else:
        print()
    for name, n in sorted(by.items(), key=lambda kv: -kv[1])[:30]:
        per = f" {n / steps:12,.0f}/step" if steps else ""
        print(f"{100 * n / total:6.2f} %{per}  {name[:110]}")


if __name__ == "__main__":
    main()
