"""Benchmark of fit-hysteresis on 10^6 samples (issue 4 target: under 5 s on 2 cores).

The data: the virtual rig's default press under a 0.1 Hz triangle with random peaks,
sampled at 10 kHz for 100 s (10^6 samples). Prints the fit time, the held-out error and,
measured in the same run, the time of the same fit on 10^5 samples (the reference) and the
ratio, which shows how the fit scales.

Run: .venv/bin/python bench/bench_fit.py
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import piezopress  # noqa: E402,F401  (thread settings before numpy work)
from piezopress.acquisition import waveforms  # noqa: E402
from piezopress.acquisition.virtual_rig import VirtualRig  # noqa: E402
from piezopress.analysis import hysteresis as H  # noqa: E402


def data(n_samples: int) -> H.HysteresisData:
    fs = n_samples / 100.0
    peaks = np.random.default_rng(3).uniform(40, 150, 10)
    v = waveforms.triangle(0.1, peaks, 0.0, fs)[:n_samples]
    f = VirtualRig().run(v, fs, preload_n=50.0, label="bench").channels["force_n"]
    return H.prepare([("bench", v, f)], holdout_fraction=0.3)


def timed_fit(d: H.HysteresisData) -> tuple[float, H.HysteresisFit]:
    t0 = time.perf_counter()
    fit = H.fit_hysteresis(d)
    return time.perf_counter() - t0, fit


def main() -> None:
    import cvxpy  # noqa: F401  (import time is not fit time)

    small, big = data(100_000), data(1_000_000)
    timed_fit(small)  # warm-up: solver and code paths loaded
    t_small, _ = timed_fit(small)
    t_big, fit = timed_fit(big)
    n = sum(u.size for u in big.u)
    print(f"fit-hysteresis on {n:,} samples: {t_big:.2f} s (target < 5 s); held-out RMS {fit.holdout_rms:.3f} N "
          f"({fit.holdout_rms_pct:.3f} % of range), model {fit.chosen}")
    print(f"reference: the same fit on 100,000 samples: {t_small:.2f} s; 10x the samples cost {t_big / t_small:.1f}x the time")


if __name__ == "__main__":
    main()
