"""Benchmark of the virtual rig (issue 3 targets: >= 200x real time, peak memory < 1 GB).

Prints, all measured in this run:
  * the complete default plan through the virtual rig: simulated rig time, wall time, ratio
    (physics alone, and the whole `characterize` pipeline with Parquet files and manifest);
  * the vectorised play operators against the plain per-sample Python loop of thesis
    Eq. 3.1 (the reference implementation), on a clean drive and on a noisy one;
  * the peak resident memory of this process.

Run: .venv/bin/python bench/bench_rig.py
"""

from __future__ import annotations

import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from piezopress import operators  # noqa: E402
from piezopress.acquisition import rig_physics  # noqa: E402
from piezopress.acquisition.plan import load_plan  # noqa: E402
from piezopress.acquisition.rig_config import load_rig  # noqa: E402
from piezopress.acquisition.virtual_rig import VirtualRig  # noqa: E402
from piezopress.pipelines import characterize  # noqa: E402


def best_of(fn, repeat=3):
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> None:
    rig = VirtualRig(load_rig(characterize.DEFAULT_RIG))
    plan = load_plan(characterize.DEFAULT_PLAN, rig.limits)
    waves = [(p, p.waveform()[1]) for p in plan.protocols]
    rig_time = sum(len(v) / p.sample_rate_hz for p, v in waves)

    def physics():
        for p, v in waves:
            rig.run(v, p.sample_rate_hz, preload_n=p.preload_n, label=p.name)

    physics()  # warm-up (imports, caches)
    wall = best_of(physics)
    print(
        f"default plan, physics only : rig time {rig_time:8.1f} s  wall {wall:6.3f} s  ratio {rig_time / wall:7.0f}x "
        "real time"
    )

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        characterize.characterize(Path(tmp) / "runs")
        wall_io = time.perf_counter() - t0
    print(
        f"default plan, characterize : rig time {rig_time:8.1f} s  wall {wall_io:6.3f} s  ratio "
        f"{rig_time / wall_io:7.0f}x real time"
    )

    r, _ = rig_physics.hysteresis_operators(rig.config.hysteresis)
    n = 20_000
    clean = 75 - 75 * np.cos(np.linspace(0, 6 * np.pi, n))
    noisy = clean + np.random.default_rng(0).normal(0, 0.05, n)
    for label, x in (("clean drive (monotone runs)", clean), ("noisy drive (clamp scan)  ", noisy)):
        loop = best_of(lambda x=x: operators.play_loop(x, r), repeat=1)
        vec = best_of(lambda x=x: operators.play(x, r))
        assert np.allclose(operators.play(x, r), operators.play_loop(x, r))
        print(
            f"play operators, {label}: {n} samples x {r.size} thresholds  loop {loop:7.3f} s  vectorised "
            f"{vec * 1e3:7.2f} ms  ratio {loop / vec:7.0f}x"
        )

    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f"peak resident memory of this process: {peak_mb:.0f} MB (target < 1024 MB)")


if __name__ == "__main__":
    main()
