"""Benchmark of diagnose: detection over many seeds (issue 6 targets).

For every cause of the catalogue, and for the clean rig, ``--seeds`` rigs are drawn: the
clean rig with that one effect on at a magnitude drawn from its documented detectable range
(`rig_config.DETECTABLE`) and a random noise seed. Each is characterized with the default
plan, the thesis's base model is fitted, and diagnose runs. Prints the confusion matrix
(hidden cause against the top finding, "none" when there is none) and the median held-out
gain of the hidden cause's finding. Targets: every cause found in at least 95 % of seeds,
no finding on clean rigs.

Run: .venv/bin/python bench/bench_diagnose.py [--seeds 20] [--workers 2]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import piezopress  # noqa: E402,F401


def one(args: tuple[str, int]) -> tuple[str, str, float]:
    from piezopress.acquisition.rig_config import RigConfig, hidden_effect
    from piezopress.acquisition.virtual_rig import VirtualRig
    from pipelines import bundle as B
    from pipelines import characterize as char
    from pipelines import diagnose as D
    from pipelines import fit as F

    effect, seed = args
    rng = np.random.default_rng([seed, 99])
    cfg = RigConfig.clean().replace(rig={"seed": int(rng.integers(0, 2**31))}) if effect == "none" else hidden_effect(effect, rng)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        try:
            char.characterize(tmp / "char", backend=VirtualRig(cfg))
            h, _, c, _ = F.fit_hysteresis_and_creep([tmp / "char"], base=True)
            s, _ = F.fit_shaper_section([tmp / "char"])
            secs = {"hysteresis": h, "creep": c, "shaper": s}
            B.write_document(B.assemble(secs, F.compensation_settings(secs)), tmp / "base.json")
            result, _ = D.diagnose([tmp / "char"], tmp / "base.json", tmp / "diag")
        except Exception as exc:  # noqa: BLE001 - a failure is a row of the matrix, not a crash
            return effect, f"error: {type(exc).__name__}", float("nan")
    top = result.findings[0].cause if result.findings else "none"
    gain = next((f.gain_pct for f in result.findings if f.cause == effect), float("nan"))
    return effect, top, gain


def main() -> None:
    from piezopress.acquisition.rig_config import EFFECTS

    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--effects", nargs="*", help="only these rows (effect ids, or none)")
    a = ap.parse_args()
    hidden = a.effects or (list(EFFECTS) + ["none"])
    jobs = [(e, s) for e in hidden for s in range(a.seeds)]
    with ProcessPoolExecutor(a.workers) as pool:
        results = list(pool.map(one, jobs))
    named = sorted({r[1] for r in results} | set(hidden), key=lambda n: (n not in hidden, hidden.index(n) if n in hidden else 0, n))
    width = max(len(n) for n in named)
    print(f"Confusion matrix over {a.seeds} seeds per row: hidden effect (rows) against the top finding (columns)")
    short = {n: n[:10] for n in named}
    print(" " * (width + 2) + " ".join(f"{short[n]:>10}" for n in named) + f" {'found %':>8} {'median gain %':>14}")
    ok = True
    for h in hidden:
        rows = [r for r in results if r[0] == h]
        counts = [sum(1 for r in rows if r[1] == n) for n in named]
        found = 100.0 * sum(1 for r in rows if r[1] == h) / len(rows)
        gains = [r[2] for r in rows if np.isfinite(r[2])]
        med = f"{np.median(gains):14.0f}" if gains and h != "none" else f"{'-':>14}"
        print(f"{h:<{width}}  " + " ".join(f"{c:>10}" for c in counts) + f" {found:8.0f} {med}")
        ok &= found >= 95.0
    print("targets met" if ok else "targets NOT met (see rows below 95 %)")


if __name__ == "__main__":
    main()
