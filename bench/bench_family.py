"""Benchmark of the hysteresis family search (issue 19): modified PI alone against the search
that may choose a Preisach plane beside the plays, fitted on the same runs and played on the
same press, interleaved (``piezopress compare``).

For the second and third test presses (``tests/independent_press.py``,
``tests/third_press.py``, both written apart from the virtual rig; the third's loop is a
Preisach plane, outside the play-operator family), clean, per seed: the default
characterization, then ``fit`` twice (today's modified PI family only, the baseline measured
in the same run; and the family search, ``fit``'s default), then both bundles compensated and
played on the press ``--repeats`` times each, A B A B. Prints per case the held-out error of
each fit against the noise floor (the output's RMS over the rest run, its drift removed), the
family chosen and why, the fit times, and the compensated rows side by side.

Run: .venv/bin/python bench/bench_family.py [--rig second,third] [--seeds 3] [--repeats 2] [--workers 2]
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

ROWS = ("static_hysteresis", "creep", "overshoot", "tracking_staircase", "tracking_random", "hysteresis_50hz")


def _noise_floor(char_dir: Path) -> float:
    from piezopress import runformat

    rest = [p for p in sorted(char_dir.glob("*.parquet")) if p.stem.startswith("rest")]
    if not rest:
        return float("nan")
    y = runformat.read_run(rest[0]).output
    t = np.arange(y.size)
    return float(np.std(y - np.polyval(np.polyfit(t, y, 2), t)))


def one(args: tuple[str, int, int, str]) -> dict:
    rig, seed, repeats, work = args
    import independent_press as ip
    import third_press as tp

    from piezopress.analysis import hysteresis as H
    from piezopress.pipelines import bundle as B
    from piezopress.pipelines import characterize as char
    from piezopress.pipelines import compare
    from piezopress.pipelines import fit as F

    mod = tp if rig == "third" else ip
    press = mod.clean_press(np.random.default_rng([seed, 97 if rig == "third" else 98]))
    w = Path(work) / f"{rig}-{seed}"
    char.characterize(w / "char", backend=press)
    out: dict = {"case": f"{rig}-{seed}", "noise": _noise_floor(w / "char")}
    levels = H.PLANE_LEVELS
    for label, planes in (("modified_pi", ()), ("family_search", levels)):
        H.PLANE_LEVELS = planes
        try:
            t0 = time.perf_counter()
            res = F.fit_bundle([w / "char"], press.limits)
            out[f"{label}_s"] = time.perf_counter() - t0
        finally:
            H.PLANE_LEVELS = levels
        B.write_document(res.doc, w / f"{label}.json")
        fig = res.doc["hysteresis"]["fit"]
        out[f"{label}_holdout"] = fig["holdout_rms_n"]
        out[f"{label}_family"] = fig.get("family", "?")
        out[f"{label}_why"] = fig.get("family_reason", "")
        out[f"{label}_creep"] = "creep" in res.doc
    cmp_ = compare.compare(
        [w / "modified_pi.json", w / "family_search.json"],
        w / "compare",
        backend=press,
        rig_path=None,
        repeats=repeats,
        labels=["modified_pi", "family_search"],
    )
    t = cmp_.table
    out["rows"] = {
        (row, label): (float(g["mean"].iloc[0]), str(g["verdict"].iloc[0]))
        for (row, label), g in t.groupby(["row", "bundle"])
        if row in ROWS
    }
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rig", default="second,third")
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--workers", type=int, default=2)
    a = p.parse_args()
    rigs = [r for r in a.rig.split(",") if r]
    if any(r not in ("second", "third") for r in rigs):
        raise SystemExit(f"--rig {a.rig!r}; expected second, third or both, comma-separated")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench-family-") as work:
        jobs = [(r, s, a.repeats, work) for r in rigs for s in range(a.seeds)]
        with ProcessPoolExecutor(max_workers=a.workers) as pool:
            results = list(pool.map(one, jobs))
    print(f"Family search against modified PI alone ({time.perf_counter() - t0:.0f} s, {a.workers} worker(s))\n")
    for r in results:
        nf = r["noise"]
        print(
            f"{r['case']}: noise floor {nf:.3g} N; held-out RMS modified PI {r['modified_pi_holdout']:.3g} N "
            f"({r['modified_pi_holdout'] / nf:.1f}x), family search {r['family_search_holdout']:.3g} N "
            f"({r['family_search_holdout'] / nf:.1f}x, {r['family_search_family']}); fit "
            f"{r['modified_pi_s']:.1f} s -> {r['family_search_s']:.1f} s; creep kept "
            f"{r['modified_pi_creep']} / {r['family_search_creep']}"
        )
        print(f"    {r['family_search_why']}")
        print(f"    {'row':<22} {'modified PI':>12} {'family search':>14}  verdict")
        for row in ROWS:
            a_ = r["rows"].get((row, "modified_pi"))
            b_ = r["rows"].get((row, "family_search"))
            if a_ and b_:
                print(f"    {row:<22} {a_[0]:>11.3g}% {b_[0]:>13.3g}%  {b_[1]}")
        print()


if __name__ == "__main__":
    main()
