"""Benchmark of the whole chain `make demo` runs (issue 5 target: under 90 s on 2 cores).

Runs the stages of `make demo` (characterize, fit, validate, fit --base, diagnose, report)
on the virtual rig into a temporary directory, through the command line in one process,
and prints the wall time of each stage and the total (`make demo` adds the start-up of a
Python process per stage, a few seconds in all).

Run: .venv/bin/python bench/bench_demo.py
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

from click.testing import CliRunner

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from piezopress.piezocli.main import cli  # noqa: E402


def main() -> None:
    runner = CliRunner()
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        stages = [
            ("characterize", ["characterize", "--out", str(d / "characterization")]),
            ("fit", ["fit", str(d / "characterization"), "--out", str(d / "bundle.json")]),
            ("validate", ["validate", "--bundle", str(d / "bundle.json"), "--out", str(d / "validation")]),
        ]
        stages += [
            ("fit --base", ["fit", str(d / "characterization"), "--base", "--out", str(d / "base-bundle.json")]),
            (
                "diagnose",
                [
                    "diagnose",
                    str(d / "characterization"),
                    "--bundle",
                    str(d / "base-bundle.json"),
                    "--out",
                    str(d / "diagnosis"),
                ],
            ),
            (
                "report",
                [
                    "report",
                    "--characterization",
                    str(d / "characterization"),
                    "--validation",
                    str(d / "validation"),
                    "--bundle",
                    str(d / "bundle.json"),
                    "--diagnosis",
                    str(d / "diagnosis"),
                    "--out",
                    str(d / "report"),
                ],
            ),
        ]
        total = 0.0
        for name, args in stages:
            t0 = time.perf_counter()
            res = runner.invoke(cli, args)
            dt = time.perf_counter() - t0
            total += dt
            if res.exit_code != 0:
                print(res.output)
                raise SystemExit(f"stage {name} failed")
            print(f"{name:<13} {dt:6.1f} s")
        print(f"{'total':<13} {total:6.1f} s (target < 90 s)")


if __name__ == "__main__":
    main()
