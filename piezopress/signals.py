"""Small signal operations shared by the rig physics and the compensator (pure numpy)."""

from __future__ import annotations

import math

import numpy as np
from scipy import signal


def rate_limit(u: np.ndarray, v0: float, max_step: float | np.ndarray) -> np.ndarray:
    """``v[k] = v[k-1] + clip(u[k] - v[k-1], -max_step, max_step)`` from ``v[-1] = v0``.

    A slew-rate limiter; ``max_step`` is one number or one per sample (a limit that varies
    along the signal). Vectorised: where ``v`` tracks ``u`` nothing is computed; only the
    samples after a change larger than ``max_step`` are stepped one by one until ``v`` has
    caught up.

    Examples
    --------
    >>> rate_limit(np.array([0.0, 10.0, 10.0, 10.0]), 0.0, 4.0).tolist()
    [0.0, 4.0, 8.0, 10.0]
    >>> rate_limit(np.array([0.0, 10.0, 10.0, 10.0]), 0.0, np.array([1.0, 1.0, 2.0, 9.0])).tolist()
    [0.0, 1.0, 3.0, 10.0]
    """
    u = np.asarray(u, dtype=np.float64)
    v = u.copy()
    if v.size == 0:
        return v
    step = np.broadcast_to(np.asarray(max_step, dtype=np.float64), v.shape)
    jumps = np.flatnonzero(np.abs(np.diff(u, prepend=v0)) > step)
    done = 0  # samples before `done` are final
    for j in jumps:
        if j < done:
            continue
        p = v[j - 1] if j > 0 else v0
        k = j
        while k < v.size:
            d = u[k] - p
            if abs(d) <= step[k]:
                break
            p += math.copysign(step[k], d)
            v[k] = p
            k += 1
        done = k
    return v


def first_order(x: np.ndarray, tau_s: float, fs_hz: float, y0: float = 0.0) -> np.ndarray:
    """``1 / (1 + tau s)``, exact for an input held between samples, from output ``y0``."""
    a = math.exp(-1.0 / (fs_hz * tau_s))
    y, _ = signal.lfilter([1.0 - a], [1.0, -a], x, zi=[a * y0])
    return y


def delayed(x: np.ndarray, fs_hz: float, delay_s: float) -> np.ndarray:
    """``x`` delayed by ``delay_s`` (linear between samples), held at ``x[0]`` before; ``x``
    itself for no delay."""
    if delay_s <= 0:
        return x
    t = np.arange(np.size(x)) / fs_hz
    return np.interp(t - delay_s, t, x, left=x[0])


def rate_envelope(drive: np.ndarray, fs_hz: float, tau_s: float) -> np.ndarray:
    """``|dV/dt|`` of a sampled drive (V/s), smoothed over ``tau_s``, from rest."""
    return first_order(np.abs(np.diff(drive, prepend=drive[0])) * fs_hz, tau_s, fs_hz)


def smoothed_rate(drive: np.ndarray, fs_hz: float, tau_s: float) -> np.ndarray:
    """The signed ``dV/dt`` of a sampled drive (V/s), smoothed over ``tau_s``, from rest: a
    first-order high-pass of the drive with its corner at ``1 / (2 pi tau_s)``, times ``1 / tau_s``."""
    return first_order(np.diff(drive, prepend=drive[0]) * fs_hz, tau_s, fs_hz)


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
    return max(scatter, quantum(y) / math.sqrt(12.0), 1e-12)


def quantum(y: np.ndarray) -> float:
    """The reading's quantization step (the smallest spacing of the values it takes), 0 where it
    takes too many values to be quantized (a reading in floating point, or a dithered one
    resampled)."""
    levels = np.unique(np.asarray(y, float))
    steps = np.diff(levels)
    return float(np.min(steps)) if steps.size and np.min(steps) > 0 and levels.size < np.size(y) / 4 else 0.0
