"""Residual analysis: the sensor's noise floor and what a residual correlates with."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import signal, special

from piezopress.analysis.diagnosis.model import RunData
from piezopress.signals import noise_floor, quantum  # noqa: F401 - the residuals' floor, used here and by the causes

# --------------------------------------------------------------------------- residual analysis


def noise_under_steps(y: np.ndarray, q: float, moved: float = 0.0) -> float:
    """The Gaussian noise before a quantizer of step ``q``, read from a stretch of its reading
    whose level moves over ``moved`` steps; 0 where the stretch cannot tell (the worst case
    for the error its mean keeps: :func:`average_floor`). A level held still whose noise
    reaches a step on either side (three values) gives it from how often it does; one whose
    noise spreads over four steps or more, from its scatter less the quantizer's own
    ``q^2 / 12``; two values bound it under a quarter step and say no more (a level near a
    step's edge reads half its samples on either side whatever the noise)."""
    vals, counts = np.unique(np.asarray(y, float), return_counts=True)
    if moved < 1.0 and vals.size == 3:
        p = counts / counts.sum()
        return q / float(special.ndtri(1.0 - p[2]) - special.ndtri(p[0]))
    if vals.size - moved > 3.5:
        return math.sqrt(max(float(np.var(np.diff(y))) / 2.0 - q * q / 12.0, 0.0))
    return 0.0


def average_floor(y: np.ndarray, n: float, noise: float | None = None, window: int = 64) -> float:
    """The noise floor of an average of ``n`` samples of the reading ``y`` whose noise per
    sample is ``noise`` (None: :func:`noise_floor`).

    The sensor's noise averages down by ``sqrt(n)``; a quantized reading's mean error may not.
    Under a quantizer of step ``q`` with Gaussian noise ``s`` before it, the mean reading of a
    level held still errs from the level by ``q / pi exp(-2 pi^2 s^2 / q^2)`` times a sine of
    where the level sits between two steps (the quantizer's first harmonic; Widrow & Kollar,
    *Quantization Noise*, 2008, ch. 5): ``q / (pi sqrt 2)`` in RMS when ``s`` is much finer
    than ``q`` (under-dithered), nothing once ``s`` passes ``q / 2``. However long it is
    averaged, a level held still keeps that error; one that moves over ``L`` steps within the
    average spreads it over them (taken as ``1 / sqrt(1 + L)``). ``s`` is read per stretch
    of ``n`` samples (:func:`noise_under_steps`), the median error taken. The virtual rig's
    12-bit input reads 0.49 N steps with 0.07 N of noise: its rest runs take two values, a
    level falling 0.16 N over 120 s reads as one falling 0.08 N and then still, and the held
    step's 5 s averages wander 0.08 N about a smooth creep where the white floor says 0.002 N."""
    y = np.asarray(y, float)
    white = (noise_floor(y, window) if noise is None else noise) / math.sqrt(max(n, 1.0))
    q = quantum(y)
    if not q:
        return white
    k = max(4, min(int(n), y.size))
    b = max(1, k // 20)  # the level over a twentieth of the average: how many steps it moves over
    errs = []
    for i in range(0, y.size - k + 1, k):
        g = y[i : i + k]
        moved = float(np.ptp(g[: k // b * b].reshape(-1, b).mean(axis=1))) / q
        s = noise_under_steps(g, q, moved)
        errs.append(q / (math.pi * math.sqrt(2.0)) * math.exp(-2.0 * math.pi**2 * s**2 / q**2) / math.sqrt(1.0 + moved))
    return max(white, float(np.median(errs)))


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
