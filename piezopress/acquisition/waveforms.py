"""Drive waveforms: pure functions from protocol parameters to sampled voltages.

Every builder returns ``command_v`` sampled at ``sample_rate_hz`` starting at ``t = 0``;
the time axis is ``numpy.arange(n) / sample_rate_hz``. A digital-to-analog converter holds
each sample until the next one (zero-order hold), which is how the backends apply them.
"""

from __future__ import annotations

import numpy as np


def n_samples(duration_s: float, sample_rate_hz: float) -> int:
    """Number of samples covering ``duration_s`` (at least 2), rounded to the nearest sample."""
    return max(2, int(round(duration_s * sample_rate_hz)))


def time_axis(n: int, sample_rate_hz: float) -> np.ndarray:
    """Uniform time axis ``t_s = k / sample_rate_hz`` for ``k = 0 .. n-1``."""
    return np.arange(n, dtype=np.float64) / float(sample_rate_hz)


def triangle(freq_hz: float, peaks_v: np.ndarray, low_v: float, sample_rate_hz: float) -> np.ndarray:
    """Triangular sweeps ``low_v -> peak -> low_v``, one period ``1/freq_hz`` per entry of ``peaks_v``.

    Examples
    --------
    >>> v = triangle(1.0, np.array([10.0]), 0.0, 4.0)
    >>> v.tolist()
    [0.0, 5.0, 10.0, 5.0, 0.0]
    """
    peaks_v = np.asarray(peaks_v, dtype=np.float64)
    n = n_samples(len(peaks_v) / freq_hz, sample_rate_hz) + 1
    t = time_axis(n, sample_rate_hz)
    cycle = np.minimum((t * freq_hz).astype(np.int64), len(peaks_v) - 1)
    phase = t * freq_hz - cycle  # 0..1 within the cycle (1 only at the very end)
    shape = 1.0 - np.abs(2.0 * phase - 1.0)  # 0 -> 1 -> 0
    return low_v + (peaks_v[cycle] - low_v) * shape


def below_rest(
    freq_hz: float,
    peaks_v: np.ndarray,
    low_v: float,
    rest_v: float,
    sample_rate_hz: float,
    depths: np.ndarray | None = None,
) -> np.ndarray:
    """Triangular sweeps that take the stack below its rest: from ``rest_v`` up to the first
    peak, down to a low, up to the next peak, ..., and from the last peak back down to
    ``rest_v``, every half-sweep ``1 / (2 freq_hz)`` long. The low between peaks ``k`` and
    ``k + 1`` lies ``depths[k]`` of the way from ``rest_v`` down to ``low_v`` (all the way
    by default). Ending from above leaves the stack as every other run leaves it at rest.

    Examples
    --------
    >>> below_rest(1.0, np.array([10.0, 6.0]), -2.0, 0.0, 4.0).tolist()
    [0.0, 5.0, 10.0, 4.0, -2.0, 2.0, 6.0, 3.0, 0.0]
    >>> below_rest(1.0, np.array([10.0, 6.0, 8.0]), -2.0, 0.0, 2.0, np.array([1.0, 0.5])).tolist()
    [0.0, 10.0, -2.0, 6.0, -1.0, 8.0, 0.0]
    """
    peaks_v = np.asarray(peaks_v, dtype=np.float64)
    depths = np.ones(max(peaks_v.size - 1, 0)) if depths is None else np.asarray(depths, dtype=np.float64)
    knots_v = [rest_v]
    for k, p in enumerate(peaks_v):
        knots_v += [float(p)] if k == 0 else [rest_v + float(depths[k - 1]) * (low_v - rest_v), float(p)]
    knots_v.append(rest_v)
    knots_t = np.arange(len(knots_v)) / (2.0 * freq_hz)
    return piecewise_linear(knots_t, np.array(knots_v), sample_rate_hz)


def sine(freq_hz: float, cycles: int, low_v: float, peak_v: float, sample_rate_hz: float) -> np.ndarray:
    """Raised-cosine cycles from ``low_v`` up to ``peak_v`` and back, starting at ``low_v``."""
    n = n_samples(cycles / freq_hz, sample_rate_hz) + 1
    t = time_axis(n, sample_rate_hz)
    return low_v + (peak_v - low_v) * 0.5 * (1.0 - np.cos(2.0 * np.pi * freq_hz * t))


def step(
    base_v: float, level_v: float, pre_s: float, hold_s: float, post_s: float, sample_rate_hz: float
) -> np.ndarray:
    """``base_v`` for ``pre_s``, an ideal step to ``level_v`` held ``hold_s``, back to ``base_v`` for ``post_s``."""
    n_pre = int(round(pre_s * sample_rate_hz))
    n_hold = int(round(hold_s * sample_rate_hz))
    n_post = int(round(post_s * sample_rate_hz))
    return np.concatenate([np.full(n_pre, base_v), np.full(n_hold, level_v), np.full(max(n_post, 1), base_v)])


def staircase(
    base_v: float, step_v: float, count: int, dwell_s: float, ramp_s: float, pre_s: float, sample_rate_hz: float
) -> np.ndarray:
    """``count`` steps of ``step_v``, each reached by a linear ramp of ``ramp_s`` and held ``dwell_s``."""
    knots_t = [0.0, pre_s]
    knots_v = [base_v, base_v]
    t = pre_s
    level = base_v
    for _ in range(count):
        level += step_v
        t += ramp_s
        knots_t.append(t)
        knots_v.append(level)
        t += dwell_s
        knots_t.append(t)
        knots_v.append(level)
    return piecewise_linear(np.array(knots_t), np.array(knots_v), sample_rate_hz)


def piecewise_linear(knots_t_s: np.ndarray, knots_v: np.ndarray, sample_rate_hz: float) -> np.ndarray:
    """Linear interpolation through ``(knots_t_s, knots_v)`` from 0 to the last knot.

    Coincident knot times make a jump (the later value wins from that instant on).
    """
    knots_t_s = np.asarray(knots_t_s, dtype=np.float64)
    knots_v = np.asarray(knots_v, dtype=np.float64)
    n = n_samples(knots_t_s[-1], sample_rate_hz) + 1
    t = time_axis(n, sample_rate_hz)
    # np.interp takes the right-most of coincident knots for points at or after them
    return np.interp(t, knots_t_s, knots_v)


def random_band(
    low_hz: float,
    high_hz: float,
    duration_s: float,
    low_v: float,
    peak_v: float,
    seed: int,
    taper_s: float,
    sample_rate_hz: float,
) -> np.ndarray:
    """A seeded random trajectory with a flat spectrum from ``low_hz`` to ``high_hz``.

    Random phases on a flat band, scaled to span ``low_v`` to ``peak_v``, faded in from and
    out to ``low_v`` by raised-cosine tapers of ``taper_s`` (tracking of a random force:
    the drive's own delay and rate show in the error at every instant, not only on steps).
    """
    n = n_samples(duration_s, sample_rate_hz) + 1
    f = np.fft.rfftfreq(n, 1.0 / sample_rate_hz)
    band = (f >= low_hz) & (f <= high_hz)
    rng = np.random.default_rng(int(seed))
    spec = np.where(band, np.exp(2j * np.pi * rng.uniform(size=f.size)), 0.0)
    x = np.fft.irfft(spec, n)
    x = x / max(float(np.max(np.abs(x))), 1e-300)
    t = time_axis(n, sample_rate_hz)
    m = min(max(taper_s, 1.0 / sample_rate_hz), t[-1] / 2.0)
    w = np.minimum(1.0, np.minimum(t, t[-1] - t) / m)
    w = 0.5 - 0.5 * np.cos(np.pi * w)
    return low_v + (peak_v - low_v) * w * (0.5 + 0.5 * x)
