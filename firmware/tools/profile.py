"""Where the firmware spends its cycles: vtexp-simavr --profile samples, by function.

Usage: python firmware/tools/profile.py FIRMWARE.elf SAMPLES [N]
"""

from __future__ import annotations

import bisect
import subprocess
import sys


def main() -> None:
    elf, samples = sys.argv[1], sys.argv[2]
    top = int(sys.argv[3]) if len(sys.argv) > 3 else 25
    syms = []
    for line in subprocess.run(["avr-nm", "-n", "-S", "--defined-only", elf], capture_output=True,
                               text=True, check=True).stdout.splitlines():
        parts = line.split()
        if len(parts) >= 3 and parts[-2].lower() in ("t", "w"):
            syms.append((int(parts[0], 16), parts[-1]))
    syms.sort()
    addrs = [a for a, _ in syms]
    counts: dict[str, int] = {}
    total = 0
    for line in open(samples):
        a, n = (int(x) for x in line.split())
        total += n
        if a == 0xFFFFFFFF:
            name = "(asleep)"
        else:
            i = bisect.bisect_right(addrs, a) - 1
            name = syms[i][1] if i >= 0 else "?"
        counts[name] = counts.get(name, 0) + n
    for name, n in sorted(counts.items(), key=lambda x: -x[1])[:top]:
        print(f"{100 * n / total:6.2f} %  {name}")


if __name__ == "__main__":
    main()
