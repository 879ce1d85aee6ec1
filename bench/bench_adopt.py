"""Benchmark of adopting only what wins on the press (issue 21), on the second test press
(``tests/independent_press.py``, written apart from the virtual rig).

For each hidden effect (and the clean press) and each seed: ``characterize`` on that press,
``fit`` (the fitted bundle) and ``fit --base``, ``diagnose`` the base, then ``diagnose --gain``'s
measurement on the press (:func:`piezopress.pipelines.adopt.measure_on_press`: the base, each
extension alone, the extended bundle, the fitted bundle and each extension on it, interleaved,
``--repeats`` times) and its recommended bundle; finally ``compare`` the fitted bundle against
the recommended one on the same press again, fresh repeats (the check is not the measurement
that chose). Prints per case: the findings, what was adopted and
what left out (and why), the extended bundle's rows better and worse than the base, and the
recommended bundle's rows better and worse than the fitted one (the acceptance: never worse
beyond the spread). ``--table CASE`` also prints the whole comparison of one case.

Run: .venv/bin/python bench/bench_adopt.py [--rig second|third] [--cases none,input_delay,...] [--seeds 3]
         [--repeats 3] [--workers 2]
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

CASES = (
    "none",
    "rate_dependent_hysteresis",
    "amplifier_slew_limit",
    "drive_coupled_interference",
    "logarithmic_creep",
    "second_resonance",
    "sensor_offset_drift",
    "input_delay",
    "hysteresis_order",
)


def one(args: tuple[str, int, int, str, str]) -> dict:
    effect, seed, repeats, work, rig = args
    import independent_press as ip
    import third_press as tp

    from piezopress.pipelines import adopt, compare
    from piezopress.pipelines import bundle as B
    from piezopress.pipelines import characterize as char
    from piezopress.pipelines import diagnose as D
    from piezopress.pipelines import fit as F

    t0 = time.perf_counter()
    mod = tp if rig == "third" else ip
    rng = np.random.default_rng([seed, 97 if rig == "third" else 98])
    press = mod.clean_press(rng) if effect == "none" else mod.hidden_press(effect, rng)
    w = Path(work) / f"{effect}-{seed}"
    plan = ip.plan_for(effect) if effect != "none" and rig == "second" else None
    char.characterize(w / "char", plan_path=plan or char.DEFAULT_PLAN, backend=press)
    B.write_document(F.fit_bundle([w / "char"], press.limits).doc, w / "fitted.json")
    B.write_document(F.fit_bundle([w / "char"], press.limits, base=True).doc, w / "base.json")
    result, _ = D.diagnose([w / "char"], w / "base.json", w / "diag")
    a = adopt.measure_on_press(
        w / "diag", w / "base.json", result.findings, backend=press, repeats=repeats, fitted_path=w / "fitted.json"
    )
    final = compare.compare(
        [w / "fitted.json", a.recommended_path],
        w / "final",
        backend=press,
        rig_path=None,
        repeats=repeats,
        labels=["fitted", "recommended"],
    )
    ext = next((c for c in a.candidates if c.label == adopt.EXTENDED_LABEL), None)
    v = final.verdicts("recommended")
    return {
        "effect": effect,
        "seed": seed,
        "findings": [f.cause for f in result.findings],
        "adopted": list(a.recommendation.causes),
        "reasons": a.recommendation.reasons,
        "ext_better": list(ext.wins) if ext else [],
        "ext_worse": list(ext.losses) if ext else [],
        "rec_better": [r for r, x in v.items() if x == "better"],
        "rec_worse": [r for r, x in v.items() if x == "worse"],
        "final_table": compare.format_table(final.table, final.labels),
        "gain_table": compare.format_table(a.comparison.table, a.comparison.labels) if a.comparison else "",
        "s": time.perf_counter() - t0,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rig", choices=("second", "third"), default="second")
    p.add_argument("--cases", default=",".join(CASES))
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--table", default="", help="print the whole comparisons of this case (effect-seed)")
    a = p.parse_args()
    cases = [c for c in a.cases.split(",") if c]
    bad = [c for c in cases if c not in CASES]
    if bad:
        raise SystemExit(f"unknown case {', '.join(bad)}; expected some of {', '.join(CASES)}")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench-adopt-") as work:
        jobs = [(c, s, a.repeats, work, a.rig) for c in cases for s in range(a.seeds)]
        with ProcessPoolExecutor(max_workers=a.workers) as pool:
            results = list(pool.map(one, jobs))
    print(
        f"{a.rig.capitalize()} test press, {a.seeds} seed(s) per case, {a.repeats} repeats per bundle on the press "
        f"({time.perf_counter() - t0:.0f} s on {a.workers} worker(s))\n"
    )
    head = ("case", "findings", "adopted", "extended vs base: better / worse", "recommended vs fitted: better / worse")
    print(" | ".join(head))
    worse_cases = 0
    for r in results:
        worse_cases += bool(r["rec_worse"])
        print(
            f"{r['effect']}-{r['seed']} | {', '.join(r['findings']) or '-'} | "
            f"{', '.join(r['adopted']) or 'none (fitted)'} | "
            f"{', '.join(r['ext_better']) or '-'} / {', '.join(r['ext_worse']) or '-'} | "
            f"{', '.join(r['rec_better']) or '-'} / {', '.join(r['rec_worse']) or '-'}  ({r['s']:.0f} s)"
        )
        for cause, why in r["reasons"].items():
            print(f"      {cause}: {why}")
        if a.table == f"{r['effect']}-{r['seed']}" or r["rec_worse"]:  # a case that failed: its tables
            print("\n" + r["gain_table"] + "\n\n" + r["final_table"] + "\n")
    print(f"\nRecommended worse than fitted on some row beyond the spread: {worse_cases} of {len(results)} cases")


if __name__ == "__main__":
    main()
