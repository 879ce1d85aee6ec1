"""Benchmark of diagnose: detection over many seeds (issue 6 targets).

For every cause of the catalogue, and for the clean rig, ``--seeds`` rigs are drawn: the
clean rig with that one effect on at a magnitude drawn from its documented detectable range
(`rig_config.DETECTABLE`) and a random noise seed. Each is characterized with the default
plan, the thesis's base model is fitted, and diagnose runs. Prints the confusion matrix
(hidden cause against the top finding, "none" when there is none) and the median held-out
gain of the hidden cause's finding. Targets: every cause found in at least 95 % of seeds,
no finding on clean rigs.

``--rig second`` does the same on the second test press, ``tests/independent_press.py`` (written
apart from the virtual rig: the same causes in other forms), with magnitudes drawn from its
own documented ranges (``independent_press.DETECTABLE``), its nuisances (mode frequency and
damping) drawn per seed, and the drift hidden in a plan without the rest run.

``--gain`` measures instead the gain on the press of every cause whose extension enters the
compensator (``pipelines/gain.py``): the table per cause, base bundle against extended on every
validation row, with each row's noise, beside the finding's prediction gain; ``--gain-out``
writes it as ``compensated_gain.csv``.

Run: .venv/bin/python bench/bench_diagnose.py [--rig ours|second] [--seeds 20] [--workers 2]
     .venv/bin/python bench/bench_diagnose.py --gain [--gain-seeds 3] [--gain-out compensated_gain.csv]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import piezopress  # noqa: E402,F401


def _second_press(effect: str, seed: int):
    """The second test press with ``effect`` hidden (``none``: clean), and the plan to run on it."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    import independent_press as ip

    rng = np.random.default_rng([seed, 98])
    press = ip.clean_press(rng) if effect == "none" else ip.hidden_press(effect, rng)
    return press, (None if effect == "none" else ip.plan_for(effect))


def one(args: tuple[str, str, int]) -> tuple[str, str, float]:
    from piezopress.acquisition.rig_config import RigConfig, hidden_effect
    from piezopress.acquisition.virtual_rig import VirtualRig
    from piezopress.pipelines import bundle as B
    from piezopress.pipelines import characterize as char
    from piezopress.pipelines import diagnose as D
    from piezopress.pipelines import fit as F

    rig, effect, seed = args
    plan = None
    if rig == "second":
        backend, plan = _second_press(effect, seed)
    else:
        rng = np.random.default_rng([seed, 99])
        backend = VirtualRig(RigConfig.clean().replace(rig={"seed": int(rng.integers(0, 2**31))}) if effect == "none" else hidden_effect(effect, rng))
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        try:
            char.characterize(tmp / "char", backend=backend, **({"plan_path": plan} if plan else {}))
            B.write_document(F.fit_bundle([tmp / "char"], base=True).doc, tmp / "base.json")  # `piezopress fit --base`
            result, _ = D.diagnose([tmp / "char"], tmp / "base.json", tmp / "diag")
        except Exception as exc:  # noqa: BLE001 - a failure is a row of the matrix, not a crash
            return effect, (f"error: {type(exc).__name__}",), float("nan")
    named = tuple(f.cause for f in result.findings) or ("none",)
    gain = next((f.gain_pct for f in result.findings if f.cause == effect), float("nan"))
    return effect, named, gain


def main() -> None:
    from piezopress.acquisition.rig_config import EFFECTS

    ap = argparse.ArgumentParser()
    ap.add_argument("--rig", choices=("ours", "second"), default="ours",
                    help="ours: the virtual rig; second: tests/independent_press.py, written apart from it")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--effects", nargs="*", help="only these rows (effect ids, or none)")
    ap.add_argument("--gain", action="store_true", help="the gain on the press instead: compensated performance, base bundle "
                    "against extended, per cause whose extension enters the compensator (pipelines/gain.py)")
    ap.add_argument("--gain-seeds", type=int, default=3, help="with --gain: passes of the whole chain per cause (noise seeds)")
    ap.add_argument("--gain-out", type=Path, default=None, help="with --gain: write the table here (compensated_gain.csv)")
    a = ap.parse_args()
    if a.gain:
        return gain_main(a)
    hidden = a.effects or (list(EFFECTS) + ["none"])
    jobs = [(a.rig, e, s) for e in hidden for s in range(a.seeds)]
    start = time.perf_counter()
    with ProcessPoolExecutor(a.workers) as pool:
        results = list(pool.map(one, jobs))
    wall = time.perf_counter() - start
    named = sorted({n for r in results for n in r[1]} | set(hidden), key=lambda n: (n not in hidden, hidden.index(n) if n in hidden else 0, n))
    width = max(len(n) for n in named)
    rig = "the virtual rig" if a.rig == "ours" else "the second test press (tests/independent_press.py)"
    print(f"Confusion matrix on {rig} over {a.seeds} seeds per row: hidden effect (rows) against the causes named "
          f"(columns; a seed counts in every column it names, 'none': no finding). 'alone %': the hidden cause named "
          f"and nothing else (clean: nothing named)")
    short = {n: n[:10] for n in named}
    print(" " * (width + 2) + " ".join(f"{short[n]:>10}" for n in named) + f" {'alone %':>8} {'median gain %':>14}")
    ok = True
    for h in hidden:
        rows = [r for r in results if r[0] == h]
        counts = [sum(1 for r in rows if n in r[1]) for n in named]
        found = 100.0 * sum(1 for r in rows if r[1] == (h,)) / len(rows)
        gains = [r[2] for r in rows if np.isfinite(r[2])]
        med = f"{np.median(gains):14.0f}" if gains and h != "none" else f"{'-':>14}"
        print(f"{h:<{width}}  " + " ".join(f"{c:>10}" for c in counts) + f" {found:8.0f} {med}")
        ok &= found >= 95.0
    print("targets met" if ok else "targets NOT met (see rows below 95 %)")
    print(f"wall time {wall / 60:.1f} min ({len(jobs)} diagnoses, {a.workers} workers)")


def gain_one(args: tuple[str, int]):
    from piezopress.pipelines import gain as G

    cause, seeds = args
    with tempfile.TemporaryDirectory() as tmp:
        return G.compensated_gain(G.effect_rig(cause, seed=0), Path(tmp) / "gain", cause=cause, seeds=seeds)


def gain_main(a) -> None:
    """The gain on the press: for every cause whose extension enters the compensator (the
    catalogue's ``in_compensator``), the virtual rig with that effect on at its gain
    magnitude (``piezopress.pipelines.gain.GAIN_MAGNITUDES``), the whole chain ``--gain-seeds`` times;
    the table per cause (base bundle against extended on every validation row, with the
    row's noise and the effect-free level) beside the finding's prediction gain."""
    from piezopress.analysis.diagnosis import CAUSES
    from piezopress.pipelines import gain as G

    causes = [c for c in (a.effects or list(CAUSES)) if c in CAUSES and CAUSES[c].in_compensator]
    start = time.perf_counter()
    with ProcessPoolExecutor(a.workers) as pool:
        results = list(pool.map(gain_one, [(c, a.gain_seeds) for c in causes]))
    wall = time.perf_counter() - start
    out = a.gain_out or Path(tempfile.gettempdir()) / G.GAIN_CSV
    G.write_csv(results, out)
    print(f"The gain on the press: validation on the virtual rig with each effect on (gain magnitudes: pipelines/gain.py), "
          f"base bundle (fit --base) against diagnose's extended bundle; {a.gain_seeds} passes of the whole chain per cause\n")
    print(G.format_table(G.read_csv(out)))
    met = [r.verdict()[0] for r in results]
    print(f"\nacceptance (targeted rows +{G.MIN_TARGET_GAIN_PCT:g} %, nothing worse beyond its noise): "
          f"{sum(m is True for m in met)} of {len(met)} causes met, {sum(m is None for m in met)} with nothing that large to gain")
    print(f"table written to {out}; wall time {wall / 60:.1f} min ({len(causes)} causes, {a.workers} workers)")


if __name__ == "__main__":
    main()
