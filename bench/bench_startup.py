"""Start-up benchmark (issue 12 target: ``piezopress --version`` and ``--help`` under 0.5 s).

Each command runs as a new process (the way a shell runs it, TAB completion included),
best of 5. The reference, measured in the same run: the same process importing every
command module up front, as the CLI did before its commands were loaded lazily.

Run: .venv/bin/python bench/bench_startup.py
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_S = 0.5

EAGER = (
    "import importlib; from piezopress.piezocli.main import COMMANDS, cli\n"
    "for m in sorted(set(m for m, _ in COMMANDS.values())): importlib.import_module('piezocli.' + m)\n"
    "cli.main(ARGS, standalone_mode=False)"
)
LAZY = "from piezopress.piezocli.main import cli; cli.main(ARGS, standalone_mode=False)"


def best_of(code: str, n: int = 5) -> float:
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, check=True)
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> int:
    ok = True
    print(f"{'command':24s} {'now s':>7s} {'eager s':>8s} {'ratio':>6s}  target < {TARGET_S} s")
    for args in (["--version"], ["--help"], ["fit", "--help"]):
        now, eager = best_of(LAZY.replace("ARGS", repr(args))), best_of(EAGER.replace("ARGS", repr(args)))
        met = now < TARGET_S or args[0] == "fit"  # a command's own help loads that command
        ok &= met
        label = "piezopress " + " ".join(args)
        print(
            f"{label:24s} {now:7.3f} {eager:8.3f} {now / eager:6.2f}  {'met' if met else 'MISSED'}"
            + ("  (loads the fit command: no target)" if args[0] == "fit" else "")
        )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
