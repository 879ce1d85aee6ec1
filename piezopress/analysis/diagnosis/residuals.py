"""Residual analysis: the sensor's noise floor and what a residual correlates with."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import signal

from piezopress.analysis.diagnosis.model import RunData

# --------------------------------------------------------------------------- residual analysis


def noise_floor(y: np.ndarray, window: int = 64) -> float:
    """RMS of the sensor's noise: sample-to-sample scatter in the quietest stretches,
    and never below the quantization's ``q / sqrt(12)``."""
    y = np.asarray(y, float)
    if y.size < 2 * window:
        window = max(4, y.size // 4)
    n = (y.size - 1) // window
    d = np.diff(y)[: n * window].reshape(n, window)
    per = d.std(axis=1) / math.sqrt(2.0)
    scatter = float(np.percentile(per, 20)) if per.size else 0.0
    levels = np.unique(y)
    steps = np.diff(levels)
    q = float(np.min(steps)) if steps.size and np.min(steps) > 0 and levels.size < y.size / 4 else 0.0
    return max(scatter, q / math.sqrt(12.0), 1e-12)


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if np.size(x) else float("nan")


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    if a.size < 3 or np.std(a) == 0 or np.std(b) == 0:
        return 0.0
    return float(np.corrcoef(a, b)[0, 1])


@dataclass(frozen=True)
class ResidualStats:
    """How a run's residual looks: size against the noise floor, whiteness, correlations."""

    run: str
    rms: float
    floor: float
    lag1_autocorr: float
    corr_level: float
    corr_rate: float
    corr_abs_rate: float
    corr_log_time_since_step: float
    dominant_freq_hz: float
    t_max_s: float

    @property
    def ratio(self) -> float:
        return self.rms / self.floor

    def as_dict(self) -> dict[str, Any]:
        return {**self.__dict__, "ratio": self.ratio}


#: A residual's dominant frequency is reported only where its periodogram's peak is this many
#: times the spectrum's median (else 0: no tone).
TONE_OVER_MEDIAN = 20.0


def judged(run: RunData, a: np.ndarray) -> np.ndarray:
    """``a`` (a run-long array) from the row the run is judged from (the start its fit skipped left out)."""
    return a[min(run.judged_from, max(a.size - 2, 0)) :]


def residual_stats(run: RunData, residual: np.ndarray, floor: float) -> ResidualStats:
    residual = judged(run, residual)
    r = residual - np.mean(residual)
    x = judged(run, run.x)
    t = judged(run, run.t_s)
    rate = np.gradient(x) * run.fs_hz
    big = np.abs(np.diff(x, prepend=x[0])) > 0.05 * max(float(np.ptp(x)), 1e-9)
    idx = np.where(big, np.arange(x.size), 0)
    since = t - t[np.maximum.accumulate(idx)]
    f, p = signal.periodogram(r, run.fs_hz, window="hann")
    # a tone needs at least two periods in the run (the lowest bins are the run's length, not a
    # frequency) and to stand out of the spectrum (20x its median: white noise's largest bin is ~10x)
    k = int(np.argmax(p[2:])) + 2 if p.size > 2 else 0
    # ... and be a peak, not the tail of the lowest bins (a drift's spectrum falls from bin 1 on)
    if k and not (p[k] > TONE_OVER_MEDIAN * float(np.median(p[1:])) and p[k] > p[k - 1]):
        k = 0
    return ResidualStats(
        run.name,
        rms(residual),
        floor,
        _corr(r[:-1], r[1:]),
        _corr(r, x),
        _corr(r, rate),
        _corr(r, np.abs(rate)),
        _corr(r, np.log1p(since * 1e3)),
        float(f[k]) if k else 0.0,
        float(t[int(np.argmax(np.abs(r)))]),
    )
