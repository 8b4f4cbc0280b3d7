#!/usr/bin/env python3
"""Add up an `insn_profile.c` profile by the firmware's functions.

Usage: insn_profile.py PROFILE ELF [STEPS]
       insn_profile.py --watch ELF NAME...

Prints the total guest instructions (and per step, given the campaign's step count) and the
functions that executed the most, with their share; for a profile taken with `watch=`
arguments, the calls into each watched function by call site (the block before its entry).
`--watch` prints those arguments for the functions whose (demangled) names end with a NAME,
e.g. `--watch fw.elf __aeabi_memcpy memcpy4` (append them to the plugin's arguments). Symbols come from `nm` (GNU or LLVM: both
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


def function_of(syms, starts, pc):
    """The name of the function whose address range holds `pc` and the offset ("?" if none)."""
    i = bisect.bisect_right(starts, pc) - 1
    if i >= 0 and pc < syms[i][0] + max(syms[i][1], 1):
        return syms[i][2], pc - syms[i][0]
    return "?", 0


def watch_args(elf, names):
    """The plugin's `watch=` arguments for the functions named."""
    addrs = sorted({a for a, _, n in symbols(elf) if any(n.endswith(w) for w in names)})
    print(",".join(f"watch={a:x}" for a in addrs))


def main():
    if sys.argv[1] == "--watch":
        watch_args(sys.argv[2], sys.argv[3:])
        return
    prof, elf = sys.argv[1], sys.argv[2]
    steps = int(sys.argv[3]) if len(sys.argv) > 3 else 0
    syms = symbols(elf)
    starts = [s[0] for s in syms]
    by = {}
    total = 0
    edges = []
    with open(prof) as f:
        for line in f:
            f = line.split()
            if f[0] == "total":
                continue
            if f[0] == "edge":
                edges.append((int(f[3]), int(f[1], 16), int(f[2], 16)))
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
    if edges:
        print("calls into watched functions, by the block before (call site):")
    for n, src, dst in sorted(edges, reverse=True)[:40]:
        per = f"{n / steps:10,.1f}/step" if steps else f"{n:12,}"
        (sn, so), (dn, do) = function_of(syms, starts, src), function_of(syms, starts, dst)
        print(f"{per}  {sn[:70]}+{so:#x} -> {dn[:50]}+{do:#x}")


if __name__ == "__main__":
    main()
