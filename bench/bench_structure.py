"""Benchmark of the hysteresis structure search (issue 19): does the structure the search chooses
on the sweeps' held-out ends compensate the press best among the structures it nearly chose?

For the second and third test presses (``tests/independent_press.py``, ``tests/third_press.py``,
written apart from the virtual rig), clean, per seed: the default characterization, ``fit`` (the
search), then ``fit --structure`` for each of the ``--top`` structures of the search's table with
the lowest held-out error (distinct from the chosen one; or the ``--structures`` given), all
fitted on the same runs; every bundle is compensated and played on the press, interleaved
(``piezopress compare``). Prints per case each structure's held-out error (the search's
criterion, on every sample) beside its compensated rows, which of them the search chose, and
whether the held-out order is the rows' order (Spearman's rank correlation of held-out error
against the mean of the compensated rows).

Run: .venv/bin/python bench/bench_structure.py [--rig second,third] [--seeds 2] [--top 2] [--workers 2]
     [--structures 'n=8 gamma=1 m=4 plane=20; n=24 gamma=1 m=16 plane=16']  (these instead of the next best)
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import piezopress  # noqa: E402,F401

ROWS = ("static_hysteresis", "tracking_staircase", "tracking_random", "hysteresis_1hz", "hysteresis_50hz", "creep")


def one(args: tuple[str, int, int, str, tuple[str, ...]]) -> dict:
    rig, seed, top, work, given = args
    import independent_press as ip
    import third_press as tp
    from scipy.stats import spearmanr

    from piezopress.pipelines import bundle as B
    from piezopress.pipelines import characterize as char
    from piezopress.pipelines import compare
    from piezopress.pipelines import fit as F

    mod = tp if rig == "third" else ip
    press = mod.clean_press(np.random.default_rng([seed, 97 if rig == "third" else 98]))
    w = Path(work) / f"{rig}-{seed}"
    char.characterize(w / "char", backend=press)
    searched = F.fit_bundle([w / "char"], press.limits)
    fig = searched.doc["hysteresis"]["fit"]
    chosen = fig["chosen"]
    scored = [c for c in fig.get("candidates", []) if isinstance(c.get("holdout_rms"), float)]
    table = sorted(scored, key=lambda c: c["holdout_rms"])
    others = [c["candidate"] for c in table if c["candidate"] != chosen][:top] if not given else list(given)
    others = [label for label in others if label != chosen]
    labels, paths, held = ["search"], [w / "search.json"], [float(fig["holdout_rms_n"])]
    B.write_document(searched.doc, paths[0])
    for i, label in enumerate(others):
        doc = F.fit_bundle([w / "char"], press.limits, structure=label).doc
        labels.append(f"other{i + 1}")
        paths.append(w / f"other{i + 1}.json")
        held.append(float(doc["hysteresis"]["fit"]["holdout_rms_n"]))
        B.write_document(doc, paths[-1])
    t = compare.compare(paths, w / "compare", backend=press, rig_path=None, repeats=1, labels=labels).table
    rows = {(row, b): float(g["mean"].iloc[0]) for (row, b), g in t.groupby(["row", "bundle"]) if row in ROWS}
    means = [float(np.mean([rows[(r, b)] for r in ROWS if (r, b) in rows])) for b in labels]
    rho = float(spearmanr(held, means)[0]) if len(labels) > 2 else float("nan")
    return {
        "case": f"{rig}-{seed}",
        "structures": [chosen, *others],
        "labels": labels,
        "held": held,
        "rows": rows,
        "means": means,
        "rho": rho,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rig", default="second,third")
    p.add_argument("--seeds", type=int, default=2)
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument("--top", type=int, default=2, help="structures besides the chosen one (default 2)")
    p.add_argument(
        "--structures",
        default="",
        help="structures to play beside the chosen one instead of the search's next best, separated by ';' "
        "(e.g. 'n=8 gamma=1 m=4 plane=20; n=24 gamma=1 m=16 plane=16')",
    )
    p.add_argument("--workers", type=int, default=2)
    a = p.parse_args()
    from piezopress.analysis.identification import parse_structure
    from piezopress.errors import PiezopressError

    given = tuple(x.strip() for x in a.structures.split(";") if x.strip())
    try:
        given = tuple(parse_structure(x).label for x in given)
    except PiezopressError as exc:
        raise SystemExit(f"--structures: {exc}") from None
    rigs = [r for r in a.rig.split(",") if r]
    if any(r not in ("second", "third") for r in rigs):
        raise SystemExit(f"--rig {a.rig!r}; expected second, third or both, comma-separated")
    if a.top < 1:
        raise SystemExit(f"--top {a.top}; expected at least 1")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench-structure-") as work:
        seeds = range(a.first_seed, a.first_seed + a.seeds)
        jobs = [(r, s, a.top, work, given) for r in rigs for s in seeds]
        with ProcessPoolExecutor(max_workers=a.workers) as pool:
            results = list(pool.map(one, jobs))
    print(f"Structures the search nearly chose, played on the press ({time.perf_counter() - t0:.0f} s)\n")
    best_chosen = 0
    for r in results:
        print(f"{r['case']}: held-out order against the rows' order, Spearman {r['rho']:+.2f}")
        head = "".join(f"{row[:18]:>20}" for row in ROWS)
        print(f"    {'structure':<34}{'held-out N':>11}{head}{'mean %':>9}")
        for s, b, h, m in zip(r["structures"], r["labels"], r["held"], r["means"]):
            cells = "".join(f"{r['rows'].get((row, b), float('nan')):>19.3g}%" for row in ROWS)
            mark = " (chosen)" if b == "search" else ""
            print(f"    {s + mark:<34}{h:>11.4g}{cells}{m:>8.3g}%")
        best_chosen += int(int(np.argmin(r["means"])) == 0)
        print()
    print(f"the search's structure compensated best in {best_chosen} of {len(results)} cases")


if __name__ == "__main__":
    main()
