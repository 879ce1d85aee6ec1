"""Benchmark of ``batch`` (issue 23): a fleet of simulated presses, serial beside Dask, in one run.

Presses: the virtual rig and the second test press (``tests/independent_press.py``), clean and
with hidden effects, different seeds, each characterized with its plan. Then:

1. ``batch STAGE`` serially (one process, one press after the other) into ``serial/``;
2. ``batch STAGE`` on a local Dask cluster of ``--workers`` into ``dask/``;
3. the same again with nothing changed (every press skipped);
4. one press's task alone in a child process, for its peak memory (max RSS).

Prints the wall times and their ratio (the reference, serial, measured in the same run), whether
``fleet.csv``'s figures and each press's bundle agree between the two (bundles but for their
timestamps), the rerun's share of the first run's time, the peak memory of one press, and
the presses the fleet report flags.

Run: .venv/bin/python bench/bench_fleet.py [--presses 12] [--workers 2] [--stage all] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import piezopress  # noqa: E402,F401  (before numpy: one BLAS thread, as in the workers and the commands)

#: The fleet: (rig, hidden effect) in turn, the seed the press's index.
KINDS = [
    ("ours", "none"),
    ("ours", "none"),
    ("second", "none"),
    ("ours", "input_delay"),
    ("ours", "none"),
    ("second", "none"),
    ("ours", "rate_dependent_hysteresis"),
    ("ours", "none"),
    ("second", "input_delay"),
    ("ours", "second_resonance"),
    ("ours", "none"),
    ("second", "none"),
]


def _characterize(rig: str, effect: str, seed: int, out: Path) -> None:
    from bench_foreign import _press

    from piezopress.pipelines import characterize as char

    press, plan, _ = _press(rig, effect, seed)
    char.characterize(out, backend=press, **({"plan_path": plan} if plan else {}))


def _strip(doc):
    if isinstance(doc, dict):
        return {k: _strip(v) for k, v in doc.items() if k not in ("fitted_utc", "created_utc", "file")}
    if isinstance(doc, list):
        return [_strip(v) for v in doc]
    return doc


def _peak_rss_mb(press_dir: Path, stage: str, out: Path) -> float:
    code = (
        "import resource, sys\n"
        "from piezopress.pipelines import batch as B\n"
        f"row = B.press_task(B.Press('mem', ({str(press_dir)!r},)), {stage!r}, {str(out)!r})\n"
        "assert row['status'] == 'done', row\n"
        "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return int(res.stdout.strip().splitlines()[-1]) / 1024.0  # Linux: kB


def main() -> None:
    import numpy as np

    from piezopress.pipelines import batch as B
    from piezopress.pipelines.fleet_report import write_fleet_report

    ap = argparse.ArgumentParser()
    ap.add_argument("--presses", type=int, default=12)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--stage", choices=B.STAGES, default="all")
    ap.add_argument("--keep", type=Path, default=None, help="work in this new folder and keep it")
    a = ap.parse_args()
    work = a.keep or Path(tempfile.mkdtemp(prefix="piezopress-fleet-"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        t0 = time.perf_counter()
        kinds = [KINDS[i % len(KINDS)] for i in range(a.presses)]
        for i, (rig, effect) in enumerate(kinds):
            _characterize(rig, effect, i, work / "runs" / f"p{i:02d}-{rig}-{effect}")
        print(f"{a.presses} presses characterized in {time.perf_counter() - t0:.0f} s ({work / 'runs'})")
        presses = B.read_presses(str(work / "runs" / "p*"))

        t = time.perf_counter()
        serial = B.run_batch(presses, a.stage, work / "serial", serial=True)
        t_serial = time.perf_counter() - t
        t = time.perf_counter()
        dask = B.run_batch(presses, a.stage, work / "dask", workers=a.workers)
        t_dask = time.perf_counter() - t
        figures = [c for c in B.COLUMNS if c not in ("wall_s", "out", "why")]
        rs = [{k: r.get(k) for k in figures} for r in B.read_fleet_csv(serial.fleet_csv)]
        rd = [{k: r.get(k) for k in figures} for r in B.read_fleet_csv(dask.fleet_csv)]
        same_rows = rs == rd
        t = time.perf_counter()
        again = B.run_batch(presses, a.stage, work / "dask", workers=a.workers)
        t_again = time.perf_counter() - t
        same_bundles = all(
            _strip(json.loads((work / "serial" / p.name / "bundle.json").read_text()))
            == _strip(json.loads((work / "dask" / p.name / "bundle.json").read_text()))
            for p in presses
            if (work / "serial" / p.name / "bundle.json").is_file()
        )
        peak = _peak_rss_mb(Path(presses[0].runs[0]), a.stage, work / "mem")
        rep = write_fleet_report(dask.fleet_csv)
        status = [r["status"] for r in dask.rows]
        print(f"batch {a.stage}, {a.presses} presses ({', '.join(sorted({f'{r}/{e}' for r, e in kinds}))})")
        print(f"  serial (reference, this run):      {t_serial:8.1f} s")
        print(f"  dask local, {a.workers} workers:            {t_dask:8.1f} s   speed-up {t_serial / t_dask:.2f}x")
        print(
            f"  dask again, nothing changed:       {t_again:8.1f} s   {100 * t_again / t_dask:.1f} % of the first "
            f"({[r['status'] for r in again.rows].count('skipped')} of {a.presses} skipped)"
        )
        print(f"  statuses: {status.count('done')} done, {status.count('failed')} failed")
        print(
            f"  fleet.csv figures identical serial vs dask: {same_rows}; bundles equal but for timestamps: "
            f"{same_bundles}"
        )
        print(f"  peak memory of one press ({a.stage}), max RSS of its process: {peak:.0f} MB")
        per = np.array([float(r.get("wall_s") or np.nan) for r in serial.rows])
        per_d = np.array([float(r.get("wall_s") or np.nan) for r in dask.rows])
        print(
            f"  per press: serial median {np.nanmedian(per):.1f} s (sum {np.nansum(per):.0f} s), on a Dask worker "
            f"median {np.nanmedian(per_d):.1f} s (sum {np.nansum(per_d):.0f} s)"
        )
        for o in rep.outliers:
            value = o.value if isinstance(o.value, str) else f"{o.value:.4g}"
            print(f"  flagged: {o.press}: {o.figure} = {value} ({o.why})")
        for r in dask.rows:
            if r["status"] == "failed":
                print(f"  failed: {r['press']}: {r.get('why')}")
    finally:
        if a.keep is None:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
