"""Figures of merit of a run: hysteresis, creep, overshoot and settling, tracking error.

The definitions are those of the thesis (Section 5.1, Eq. 5.1; Section 5.2, Eq. 5.2;
Section 5.3, Eq. 5.3; Section 6.4.2, Table 6.9; Section 6.6), made robust to measured
data. The load cell quantizes to about 0.5 N on a ~300 N span with ~0.06 N of noise, so
a sample-wise maximum or minimum measures the noise rather than the press. Here every
level is a mean over many samples (input bins for hysteresis, time windows for creep and
steps), and each result carries the details needed to plot or explain it.

Two deliberate departures from the letter of the thesis, both stated in the results:

- Creep and overshoot are percentages of the *step size* ``F_ss - F_0``, not of the
  absolute reading ``F_ss``: the reading includes the ~50 N preload of the press, which has
  nothing to do with creep or vibration. The thesis-literal ratio is returned as well
  (``percent_of_reading``).
- Hysteresis compares branch means at the same input, bin by bin, instead of picking two
  samples; the output range is that of the lightly averaged output, not of raw extremes.

Pure math on numpy arrays: no file I/O, no plotting. Every function validates its input
first and raises :class:`~piezopress.errors.MetricError` with a message naming the value
and what was expected when a signal does not suit the metric.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import find_peaks

from piezopress.errors import MetricError

__all__ = [
    "HysteresisResult",
    "CreepResult",
    "StepResult",
    "TrackingResult",
    "Plateau",
    "max_hysteresis",
    "find_reversals",
    "creep",
    "overshoot",
    "tracking_error",
    "staircase_plateaus",
]

#: Fewest samples any metric accepts: below this nothing can be averaged.
MIN_SAMPLES = 8
#: Default reversal threshold of :func:`find_reversals`, as a fraction of the input span.
REVERSAL_FRACTION = 0.05
#: A reversal must also exceed this many input-noise standard deviations.
REVERSAL_NOISE_FACTOR = 8.0
#: A step must exceed this many noise floors to count as a step.
STEP_NOISE_FACTOR = 5.0
#: Window of the output-only step detector, as a fraction of the record (samples).
CONTRAST_FRACTION = 1 / 50


# ---------------------------------------------------------------------------------------
# Results
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class HysteresisResult:
    """Maximum hysteresis of an input/output loop (thesis Eq. 5.1).

    Attributes
    ----------
    percent : float
        ``100 * max_gap / output_range``.
    max_gap : float
        Δh: the largest absolute difference between the descending and the ascending branch
        means at the same input, in the unit of ``y``.
    output_range : float
        ΔH: the full range of the (lightly averaged) output, in the unit of ``y``.
    x_at_max : float
        Input at which ``max_gap`` occurs.
    ascending_at_max, descending_at_max : float
        Branch means at ``x_at_max`` (their difference is ``±max_gap``).
    output_min, output_max : float
        The ends of ``output_range``.
    n_cycles : int
        Complete cycles used: the smaller of the numbers of ascending and descending
        branches kept.
    n_bins_compared : int
        Input bins in which both branches had data and were compared.
    x_grid, ascending, descending : numpy.ndarray
        The compared branches: branch means interpolated at the centres of the compared
        bins (for plotting the loop and the gap ``descending - ascending``).
    reversals : numpy.ndarray
        Sample indices of the input's turning points.
    """

    percent: float
    max_gap: float
    output_range: float
    x_at_max: float
    ascending_at_max: float
    descending_at_max: float
    output_min: float
    output_max: float
    n_cycles: int
    n_bins_compared: int
    x_grid: np.ndarray = field(repr=False, compare=False)
    ascending: np.ndarray = field(repr=False, compare=False)
    descending: np.ndarray = field(repr=False, compare=False)
    reversals: np.ndarray = field(repr=False, compare=False)


@dataclass(frozen=True)
class CreepResult:
    """Creep of a held step (thesis Eq. 5.2). Levels are in the unit of ``y``.

    Attributes
    ----------
    percent : float
        ``100 * (final - steady_state) / step_size``: creep relative to the step, so the
        preload of the press does not dilute it.
    percent_of_reading : float
        The thesis-literal ratio ``100 * (final - steady_state) / steady_state`` (relative
        to the absolute reading, baseline included); NaN when ``steady_state`` is 0.
    baseline : float
        F_0, mean of the output over the baseline before the step.
    steady_state : float
        F_ss, mean over a window of ``ss_window_s`` centred ``t_ss_s`` after the step.
    final : float
        F_f, mean over the last ``final_window_s`` of the hold.
    step_size : float
        ``steady_state - baseline`` (negative for a downward step).
    step_time_s : float
        Time of the step.
    t_ss_s : float
        Time after the step at which F_ss was taken (centre of its window).
    hold_s : float
        Length of the hold: from the step to its last sample.
    ss_window_s, final_window_s : float
        The averaging windows used.
    noise_std : float
        Standard deviation of the output over the baseline.
    located_by : str
        How the step was found: ``"step_time_s"``, ``"drive"`` or ``"output"``.
    """

    percent: float
    percent_of_reading: float
    baseline: float
    steady_state: float
    final: float
    step_size: float
    step_time_s: float
    t_ss_s: float
    hold_s: float
    ss_window_s: float
    final_window_s: float
    noise_std: float
    located_by: str


@dataclass(frozen=True)
class StepResult:
    """Overshoot, settling and rise of a step response (thesis Eq. 5.3, Table 6.9).

    Levels are in the unit of ``y``; times are measured from ``step_time_s``.

    Attributes
    ----------
    percent : float
        Overshoot ``100 * (peak - steady_state) / step_size``, relative to the step so the
        preload does not dilute it. Sign-aware: positive when the response passes the
        steady state in the direction of the step, upward or downward.
    percent_of_reading : float
        The thesis-literal ``100 * (peak - steady_state) / steady_state``; NaN when
        ``steady_state`` is 0.
    significant : bool
        Whether the overshoot exceeds what noise and quantization alone produce,
        ``5 * noise_std + resolution``.
    baseline, steady_state, peak, step_size : float
        F_0 (mean before the step), F_ss (mean over the last ``ss_window_s`` of the hold),
        F_p (extreme in the step direction) and ``steady_state - baseline``.
    step_time_s : float
        Time of the step.
    peak_time_s : float
        Time from the step to the peak.
    settling_time_s : float
        Time from the step until the output stays within ``±settle_fraction * |step_size|``
        of ``steady_state`` to the end of the hold (interpolated between samples); NaN when
        the last sample of the hold is still outside the band (``settled`` is False).
    settled : bool
        Whether the output ends the hold inside the band.
    settle_fraction : float
        Half-width of the settling band, as a fraction of the step (thesis: 0.02).
    band_below_noise : bool
        True when the settling band is narrower than 3 noise floors: the settling time then
        measures the noise (e.g. a 20 N step has a 0.4 N band, below a 0.5 N quantization).
    rise_time_s : float
        10-90 % rise time (interpolated); NaN if the output never reaches 90 %.
    hold_s : float
        Length of the hold: from the step to its last sample.
    ss_window_s : float
        Window at the end of the hold over which ``steady_state`` was averaged.
    noise_std : float
        Standard deviation of the output over the baseline.
    resolution : float
        Smallest difference between distinct consecutive samples: the quantization step
        of a quantized signal.
    noise_floor : float
        ``max(noise_std, resolution / sqrt(12))``: the noise, or the quantization noise when
        the noise is too small to toggle the quantizer.
    located_by : str
        How the step was found: ``"step_time_s"``, ``"drive"`` or ``"output"``.
    """

    percent: float
    percent_of_reading: float
    significant: bool
    baseline: float
    steady_state: float
    peak: float
    step_size: float
    step_time_s: float
    peak_time_s: float
    settling_time_s: float
    settled: bool
    settle_fraction: float
    band_below_noise: bool
    rise_time_s: float
    hold_s: float
    ss_window_s: float
    noise_std: float
    resolution: float
    noise_floor: float
    located_by: str


@dataclass(frozen=True)
class Plateau:
    """A segment where a signal is constant: samples ``start`` to ``stop - 1``."""

    start: int
    stop: int
    level: float

    def __len__(self) -> int:
        return self.stop - self.start


@dataclass(frozen=True)
class TrackingResult:
    """Tracking error of a compensated run against its reference force (thesis Section 6.6).

    Attributes
    ----------
    max_error_n, min_error_n : float
        Extremes of the absolute error ``y - reference`` over the evaluated samples (the
        thesis reports the range, e.g. 5.37 N to -22.76 N).
    rms_error_n, mean_error_n : float
        RMS and mean of the absolute error.
    max_relative_percent, min_relative_percent : float
        Extremes of the relative error ``100 * (y - reference) / reference``.
    max_abs_relative_percent : float
        Largest magnitude of the relative error.
    t_at_max_abs_error_s : float
        Time of the largest absolute error.
    n_samples : int
        Samples evaluated (``mask.sum()``).
    min_reference : float
        Smallest ``|reference|`` evaluated.
    settle_s : float
        Margin skipped after the start of each plateau that follows a ramp (0 when ramps
        are not excluded).
    mask : numpy.ndarray
        Boolean mask of the evaluated samples.
    plateaus : tuple of Plateau
        The reference's plateaus that contributed samples (empty when ramps are not
        excluded).
    """

    max_error_n: float
    min_error_n: float
    rms_error_n: float
    mean_error_n: float
    max_relative_percent: float
    min_relative_percent: float
    max_abs_relative_percent: float
    t_at_max_abs_error_s: float
    n_samples: int
    min_reference: float
    settle_s: float
    mask: np.ndarray = field(repr=False, compare=False)
    plateaus: tuple[Plateau, ...] = field(repr=False, compare=False)


# ---------------------------------------------------------------------------------------
# Validation helpers
# ---------------------------------------------------------------------------------------


def _signal(fn: str, name: str, values, *, min_len: int = MIN_SAMPLES) -> np.ndarray:
    """``values`` as a finite 1-D float array of at least ``min_len`` samples."""
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise MetricError(
            f"{fn}: {name} is not numeric ({type(values).__name__}); expected a 1-D array of numbers"
        ) from None
    if arr.ndim != 1:
        raise MetricError(f"{fn}: {name} has shape {arr.shape}; expected a 1-D array")
    if arr.size < min_len:
        raise MetricError(f"{fn}: {name} has {arr.size} sample(s); expected at least {min_len}")
    bad = ~np.isfinite(arr)
    if bad.any():
        i = int(np.argmax(bad))
        raise MetricError(
            f"{fn}: {name} has {int(bad.sum())} NaN/infinite value(s), first at index {i}; expected finite numbers"
        )
    return arr


def _same_length(fn: str, **arrays: np.ndarray) -> None:
    (first, a0), *rest = arrays.items()
    for name, a in rest:
        if a.size != a0.size:
            raise MetricError(f"{fn}: {first} has {a0.size} samples but {name} has {a.size}; expected equal lengths")


def _time(fn: str, t_s) -> np.ndarray:
    t = _signal(fn, "t_s", t_s)
    dt = np.diff(t)
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0))
        raise MetricError(
            f"{fn}: t_s is not strictly increasing at index {i + 1} ({t[i]!r} then {t[i + 1]!r}); expected increasing "
            "time"
        )
    return t


def _positive(fn: str, name: str, value, *, allow_none: bool = False) -> float | None:
    if value is None and allow_none:
        return None
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise MetricError(f"{fn}: {name} is {value!r}; expected a positive number") from None
    if not math.isfinite(v) or v <= 0:
        raise MetricError(f"{fn}: {name} is {value!r}; expected a positive number")
    return v


def _not_flat(fn: str, name: str, y: np.ndarray) -> None:
    if np.ptp(y) <= 1e-12 * max(1.0, float(np.max(np.abs(y)))):
        raise MetricError(
            f"{fn}: {name} is flat (every sample {y[0]!r}); expected an output that responds to the input"
        )


def _noise_std(x: np.ndarray) -> float:
    """Robust white-noise estimate from the second difference (blind to ramps and steps).

    The second difference of white noise of std s has std s*sqrt(6); the median absolute
    deviation ignores the few large values at corners, steps and reversals.
    """
    d2 = np.diff(x, 2)
    if d2.size == 0:
        return 0.0
    mad = float(np.median(np.abs(d2 - np.median(d2))))
    return 1.4826 * mad / math.sqrt(6.0)


def _resolution(y: np.ndarray) -> float:
    """Smallest difference between distinct consecutive samples (the quantization step)."""
    d = np.abs(np.diff(y))
    d = d[d > 1e-9 * max(1.0, float(np.max(np.abs(y))))]
    return float(d.min()) if d.size else 0.0


def _moving_average(y: np.ndarray, length: int) -> np.ndarray:
    if length <= 1:
        return y
    c = np.concatenate(([0.0], np.cumsum(y - y[0])))
    return (c[length:] - c[:-length]) / length + y[0]


# ---------------------------------------------------------------------------------------
# Hysteresis
# ---------------------------------------------------------------------------------------


def find_reversals(x, *, min_swing: float | None = None) -> np.ndarray:
    """Indices of the turning points of a cyclic input, ignoring noise.

    A turning point is a maximum or minimum of ``x`` with a prominence of at least
    ``min_swing``: the input must move by that much in both directions around it, so
    noise on the input does not create fake reversals. Maxima and minima alternate.

    Parameters
    ----------
    x : array_like
        The input (drive voltage or reference force).
    min_swing : float, optional
        Smallest swing that counts as a reversal, in the unit of ``x``. Default: the larger
        of 5 % of the span of ``x`` and 8 standard deviations of its noise.

    Returns
    -------
    numpy.ndarray
        Sample indices of the turning points, in time order (the first and last samples of
        the record are never turning points).

    Raises
    ------
    MetricError
        If ``x`` is too short, not finite or constant.

    Examples
    --------
    >>> x = np.concatenate([np.linspace(0, 1, 11), np.linspace(1, 0, 11)[1:]])
    >>> find_reversals(x).tolist()
    [10]
    """
    fn = "find_reversals"
    x = _signal(fn, "x", x, min_len=3)
    span = float(np.ptp(x))
    if span == 0:
        raise MetricError(f"{fn}: x is constant ({x[0]!r}); expected a cyclic input")
    if min_swing is None:
        swing = max(REVERSAL_FRACTION * span, REVERSAL_NOISE_FACTOR * _noise_std(x))
    else:
        swing = _positive(fn, "min_swing", min_swing)
    return _reversals(x, swing)[0]


def _reversals(x: np.ndarray, swing: float) -> tuple[np.ndarray, int]:
    """Turning points and the kind of the first one (+1 maximum, -1 minimum, 0 if none)."""
    peaks, _ = find_peaks(x, prominence=swing)
    troughs, _ = find_peaks(-x, prominence=swing)
    idx = np.concatenate([peaks, troughs])
    kind = np.concatenate([np.ones(peaks.size), -np.ones(troughs.size)])
    order = np.argsort(idx, kind="stable")
    kept_i: list[int] = []
    kept_k: list[float] = []
    for i, k in zip(idx[order], kind[order]):
        if kept_k and kept_k[-1] == k:  # two maxima (or minima) in a row: keep the more extreme
            if k * x[i] > k * x[kept_i[-1]]:
                kept_i[-1] = int(i)
            continue
        kept_i.append(int(i))
        kept_k.append(float(k))
    return np.asarray(kept_i, dtype=np.intp), int(kept_k[0]) if kept_k else 0


def max_hysteresis(
    x, y, *, n_bins: int = 50, skip_first_half_cycle: bool = True, min_swing: float | None = None
) -> HysteresisResult:
    """Maximum hysteresis of an output against its input, in percent (thesis Eq. 5.1).

    ``100 * Δh / ΔH``, with Δh the largest difference between the output on the
    ascending and on the descending branch at the same input, and ΔH the full output range.

    Method: the input's turning points are found with :func:`find_reversals`; each sample
    belongs to the ascending or descending branch according to the direction of the input
    between the turning points around it. The first monotone stretch (the virgin loading
    curve, from the start of the record to the first turning point) is dropped when
    ``skip_first_half_cycle`` is set; so is a last stretch shorter than ``min_swing``.
    Each branch is averaged over all its cycles in ``n_bins`` equal input bins (mean
    input and mean output per bin); the branch means are interpolated at the centres of
    the bins where both branches have data and compared there. ΔH is the range of the
    output after a centred moving average over about 1/(20 ``n_bins``) of a half cycle,
    which removes the noise from the extremes without flattening the loop's tips.

    Noise on the output averages out in the bins. Noise on the input scatters the branch
    means (by the loop's slope times the input noise, over the square root of the samples
    in a bin), and the largest gap over the bins picks up that scatter: Δh then reads high
    by two to three scatter standard deviations; use fewer bins or more cycles.

    With cycles of different amplitudes (increasing or random peaks, minor loops) the
    branch means average every cycle that passes through a bin, so the result mixes the
    loops: it is at most the gap of the largest loop and is dominated by it near the top
    of the input range. Split the run to get one loop per amplitude.

    Parameters
    ----------
    x : array_like
        The input: drive voltage, or reference force of a compensated run.
    y : array_like
        The output (force or displacement), same length as ``x``.
    n_bins : int, default 50
        Number of input bins across the range of ``x``.
    skip_first_half_cycle : bool, default True
        Drop the virgin curve from the start of the record to the first turning point.
    min_swing : float, optional
        Reversal threshold passed to :func:`find_reversals`.

    Returns
    -------
    HysteresisResult

    Raises
    ------
    MetricError
        If the signals are too short, not finite or of different lengths, the output is
        flat, the input has no reversal, or the branches do not overlap.

    Examples
    --------
    A play operator of half-width 0.1 gives branches ``x - 0.1`` and ``x + 0.1``: the gap
    is 0.2 over an output range of 0.8.

    >>> x = np.tile(np.concatenate([np.linspace(0, 1, 101), np.linspace(1, 0, 101)[1:-1]]), 3)
    >>> y = np.empty_like(x); y[0] = 0.0
    >>> for i in range(1, x.size):
    ...     y[i] = min(max(y[i - 1], x[i] - 0.1), x[i] + 0.1)
    >>> round(max_hysteresis(x, y).percent, 6)
    25.0
    """
    fn = "max_hysteresis"
    x = _signal(fn, "x", x)
    y = _signal(fn, "y", y)
    _same_length(fn, x=x, y=y)
    if isinstance(n_bins, bool) or not isinstance(n_bins, (int, np.integer)) or n_bins < 4:
        raise MetricError(f"{fn}: n_bins is {n_bins!r}; expected an integer of at least 4")
    span = float(np.ptp(x))
    if span == 0:
        raise MetricError(f"{fn}: x is constant ({x[0]!r}); expected a cyclic input (triangle, sine, ...)")
    _not_flat(fn, "y", y)
    if min_swing is None:
        swing = max(REVERSAL_FRACTION * span, REVERSAL_NOISE_FACTOR * _noise_std(x))
    else:
        swing = _positive(fn, "min_swing", min_swing)
    rev, first_kind = _reversals(x, swing)
    if rev.size == 0:
        raise MetricError(
            f"{fn}: x has no reversal (no turn by at least min_swing={swing:.4g} over a span of {span:.4g}); "
            "expected a cyclic input that rises and falls"
        )

    # Segments between turning points; the direction is the one leading to the next turn.
    bounds = np.concatenate(([0], rev, [x.size]))
    dirs = first_kind * (-1) ** np.arange(bounds.size - 1)  # rising before a maximum
    keep = np.ones(dirs.size, dtype=bool)
    if skip_first_half_cycle:
        keep[0] = False
    ends = np.minimum(bounds[1:], x.size - 1)
    swings = np.abs(x[ends] - x[bounds[:-1]])
    keep[-1] &= bool(swings[-1] >= swing)
    keep[0] &= bool(swings[0] >= swing)
    n_up = int(np.sum(keep & (dirs > 0)))
    n_down = int(np.sum(keep & (dirs < 0)))
    if n_up == 0 or n_down == 0:
        have = "descending" if n_down else "ascending" if n_up else "no"
        raise MetricError(
            f"{fn}: after dropping the virgin curve only {have} branch data remain ({rev.size} reversal(s)); "
            "expected at least one ascending and one descending branch (record more cycles or pass "
            "skip_first_half_cycle=False)"
        )
    label = np.repeat(np.where(keep, dirs, 0), np.diff(bounds))
    used = label != 0

    lo, hi = float(x[used].min()), float(x[used].max())
    edges = np.linspace(lo, hi, n_bins + 1)
    centres = 0.5 * (edges[:-1] + edges[1:])
    b = np.clip(((x - lo) / (hi - lo) * n_bins).astype(np.intp), 0, n_bins - 1)

    def branch(sign: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        m = label == sign
        count = np.bincount(b[m], minlength=n_bins)
        has = count > 0
        sx = np.bincount(b[m], weights=x[m], minlength=n_bins)
        sy = np.bincount(b[m], weights=y[m], minlength=n_bins)
        return has, sx[has] / count[has], sy[has] / count[has]

    has_up, xu, yu = branch(1)
    has_down, xd, yd = branch(-1)
    both = has_up & has_down
    grid = centres[both]
    grid = grid[(grid >= max(xu[0], xd[0])) & (grid <= min(xu[-1], xd[-1]))]
    if grid.size < 2:
        raise MetricError(
            f"{fn}: the ascending and descending branches share {grid.size} input bin(s) of {n_bins}; "
            "expected at least 2 (do both branches cover the same input range?)"
        )
    up = np.interp(grid, xu, yu)
    down = np.interp(grid, xd, yd)
    gap = down - up
    k = int(np.argmax(np.abs(gap)))

    # Output range of the used stretch after a short centred moving average.
    i0 = int(np.argmax(used))
    i1 = int(used.size - np.argmax(used[::-1]))
    seg_len = float(np.median(np.diff(bounds)[keep]))
    smooth = _moving_average(y[i0:i1], max(1, min(int(seg_len // (20 * n_bins)), (i1 - i0) // 2)))
    y_min, y_max = float(smooth.min()), float(smooth.max())
    out_range = y_max - y_min
    if out_range <= 0:
        raise MetricError(f"{fn}: y is flat over the cycles used; expected an output that responds to the input")
    max_gap = float(abs(gap[k]))
    return HysteresisResult(
        percent=100.0 * max_gap / out_range,
        max_gap=max_gap,
        output_range=out_range,
        x_at_max=float(grid[k]),
        ascending_at_max=float(up[k]),
        descending_at_max=float(down[k]),
        output_min=y_min,
        output_max=y_max,
        n_cycles=min(n_up, n_down),
        n_bins_compared=int(grid.size),
        x_grid=grid,
        ascending=up,
        descending=down,
        reversals=rev,
    )


# ---------------------------------------------------------------------------------------
# Steps: locating the step, creep, overshoot
# ---------------------------------------------------------------------------------------


def staircase_plateaus(reference, *, tol: float | None = None, min_length: int = 2) -> tuple[Plateau, ...]:
    """Segments where a (staircase) signal is constant.

    A plateau is a maximal run of at least ``min_length`` samples whose consecutive
    differences are all within ``tol``; ramps between levels (each sample different) are
    not plateaus.

    Parameters
    ----------
    reference : array_like
        The signal, e.g. a reference force or a drive voltage.
    tol : float, optional
        Largest sample-to-sample change inside a plateau. Default: ``1e-9 * max(1, max|reference|)``
        (exact equality up to rounding, for computed references). Pass a value above the
        noise for a measured signal.
    min_length : int, default 2
        Fewest samples in a plateau.

    Returns
    -------
    tuple of Plateau
        In time order; ``level`` is the median over the plateau.

    Examples
    --------
    >>> [(p.start, p.stop, p.level) for p in staircase_plateaus([0, 0, 0, 5, 10, 10, 10, 10])]
    [(0, 3, 0.0), (4, 8, 10.0)]
    """
    fn = "staircase_plateaus"
    r = _signal(fn, "reference", reference, min_len=2)
    if isinstance(min_length, bool) or not isinstance(min_length, (int, np.integer)) or min_length < 2:
        raise MetricError(f"{fn}: min_length is {min_length!r}; expected an integer of at least 2")
    if tol is None:
        tol = 1e-9 * max(1.0, float(np.max(np.abs(r))))
    else:
        tol = float(tol)
        if not math.isfinite(tol) or tol < 0:
            raise MetricError(f"{fn}: tol is {tol!r}; expected a number >= 0")
    return _plateaus(r, tol, min_length)


def _plateaus(r: np.ndarray, tol: float, min_length: int) -> tuple[Plateau, ...]:
    change = np.flatnonzero(np.abs(np.diff(r)) > tol) + 1
    starts = np.concatenate(([0], change))
    stops = np.concatenate((change, [r.size]))
    long = stops - starts >= min_length
    return tuple(Plateau(int(a), int(b), float(np.median(r[a:b]))) for a, b in zip(starts[long], stops[long]))


@dataclass(frozen=True)
class _Step:
    k_step: int  # first sample of the response, at t_step
    t_step: float
    k_hold_end: int  # exclusive end of the hold
    k_base_start: int
    located_by: str


def _contrast(y: np.ndarray, w: int) -> np.ndarray:
    """``mean(y[i:i+w]) - mean(y[i-w:i])`` for every split i (windows truncated at the ends)."""
    n = y.size
    c = np.concatenate(([0.0], np.cumsum(y - np.median(y))))
    i = np.arange(1, n)
    lo = np.maximum(0, i - w)
    hi = np.minimum(n, i + w)
    d = np.zeros(n)
    d[1:] = (c[hi] - c[i]) / (hi - i) - (c[i] - c[lo]) / (i - lo)
    return d


def _step_back(d: np.ndarray, start: int, direction: float, size: float) -> int:
    """First split after ``start`` where the output falls back by half the step, else n."""
    back = np.flatnonzero(direction * d[start:] < -0.5 * abs(size))
    return int(start + back[0]) if back.size else d.size


#: Times a window's or a hold's edge may miss by and still count, in samples: times stamped far
#: from 0 (a file from another program, 1000 s into a session) carry rounding of about 1e-13 s,
#: which otherwise moves an edge that falls on a sample by one sample.
_ROUNDING_SAMPLES = 0.01


def _rounding_s(t: np.ndarray) -> float:
    """What a time edge may miss by and still count: :data:`_ROUNDING_SAMPLES` of a sample."""
    return _ROUNDING_SAMPLES * float(np.median(np.diff(t)))


def _locate_step(fn: str, t: np.ndarray, y: np.ndarray, drive, step_time_s, min_hold_s: float) -> _Step:
    n = y.size
    w = max(3, int(n * CONTRAST_FRACTION))
    if drive is not None:
        u = _signal(fn, "drive", drive, min_len=1)
        _same_length(fn, y=y, drive=u)
        tol = 1e-9 * max(1.0, float(np.max(np.abs(u))))
        dt = float(np.median(np.diff(t)))
        # a hold lasts its samples' span plus one period, to within rounding (a 10 ms hold
        # stamped at t = 1000 s read 9.99999999 ms, was dropped, and the step back was measured
        # instead: overshoot 1.2 % -> 9.3 %)
        span = dt + _rounding_s(t)  # the last sample's period, and the rounding
        holds = [p for p in _plateaus(u, tol, 3) if t[p.stop - 1] - t[p.start] + span >= min_hold_s]
    if step_time_s is not None:
        ts = float(step_time_s)
        if not math.isfinite(ts) or not t[0] < ts <= t[-1]:
            raise MetricError(
                f"{fn}: step_time_s is {step_time_s!r}; expected a time within the run ({t[0]:.6g} s, {t[-1]:.6g} s]"
            )
        k = int(np.searchsorted(t, ts - 1e-6 * float(np.min(np.diff(t)))))
        if drive is not None:
            after = [p for p in holds if p.stop > k and p.stop - max(p.start, k) >= 0.5 * len(p)]
            if not after:
                raise MetricError(
                    f"{fn}: drive has no hold of at least min_hold_s={min_hold_s:g} s after step_time_s={ts:g}; "
                    "expected the drive to hold after the step"
                )
            post = after[0]
            pre = [p for p in holds if p.stop <= post.start]
            return _Step(k, ts, post.stop, pre[-1].start if pre else 0, "step_time_s")
        d = _contrast(y, w)
        size = float(np.mean(y[k : min(n, k + w)]) - np.mean(y[max(0, k - w) : k])) if k > 0 else 0.0
        return _Step(k, ts, _step_back(d, min(n, k + w), math.copysign(1.0, size), size), 0, "step_time_s")
    if drive is not None:
        if len(holds) < 2:
            raise MetricError(
                f"{fn}: drive has no step: found {len(holds)} hold(s) of at least min_hold_s={min_hold_s:g} s; "
                "expected a hold before and after the step (pass step_time_s, or a smaller min_hold_s)"
            )
        jumps = [abs(b.level - a.level) for a, b in zip(holds[:-1], holds[1:])]
        j = int(np.argmax(jumps))
        if jumps[j] == 0:
            raise MetricError(
                f"{fn}: drive has no step (its holds are all at {holds[0].level:g}); expected a change of level"
            )
        pre, post = holds[j], holds[j + 1]
        return _Step(pre.stop, float(t[pre.stop]), post.stop, pre.start, "drive")

    # Output only: the first jump at least half as large as the largest one, seen by the
    # difference of the means of w samples after and before each split.
    d = _contrast(y, w)
    big = np.abs(d) >= 0.5 * float(np.max(np.abs(d)))
    i0 = int(np.argmax(big))
    run_end = i0 + (int(np.argmin(big[i0:])) if not big[i0:].all() else n - i0)
    i = i0 + int(np.argmax(np.abs(d[i0:run_end])))
    size = float(d[i])
    noise = max(_noise_std(y), _resolution(y) / math.sqrt(12.0))
    if abs(size) <= STEP_NOISE_FACTOR * noise or abs(size) <= 1e-9 * float(np.max(np.abs(y))):
        raise MetricError(
            f"{fn}: no step found in y: the largest jump is {abs(size):.4g}, within {STEP_NOISE_FACTOR:g} noise "
            f"floors ({noise:.4g}); "
            "expected a step response (pass drive or step_time_s to locate it)"
        )
    direction = math.copysign(1.0, size)
    f0 = float(np.median(y[max(0, i - w) : i])) if i > 0 else float(y[0])
    rel = direction * (y - f0)
    lo = max(0, i - w)
    cross = np.flatnonzero(rel[lo:] >= 0.5 * abs(size))
    c = lo + int(cross[0]) if cross.size else i
    quiet = np.flatnonzero(rel[:c] <= 0.1 * abs(size))
    k = int(quiet[-1]) if quiet.size else 0
    return _Step(k, float(t[k]), _step_back(d, min(n, i + w), direction, size), 0, "output")


def _step_levels(
    fn: str, t: np.ndarray, y: np.ndarray, s: _Step, baseline_s: float | None
) -> tuple[np.ndarray, float, float]:
    """Baseline samples before the step, their mean and standard deviation."""
    b0 = s.k_base_start
    if baseline_s is not None:
        b0 = max(b0, int(np.searchsorted(t, s.t_step - baseline_s)))
    base = y[b0 : s.k_step]
    if base.size < 3:
        raise MetricError(
            f"{fn}: only {base.size} sample(s) of baseline before the step at t={s.t_step:.6g} s; "
            "expected at least 3 to measure the level before the step"
        )
    if s.k_hold_end - s.k_step < 3:
        raise MetricError(
            f"{fn}: only {max(0, s.k_hold_end - s.k_step)} sample(s) of hold after the step at t={s.t_step:.6g} s; "
            "expected at least 3"
        )
    return base, float(np.mean(base)), float(np.std(base, ddof=1))


def _check_step(fn: str, size: float, noise_floor: float, scale: float) -> None:
    if abs(size) <= STEP_NOISE_FACTOR * noise_floor or abs(size) <= 1e-9 * scale:
        raise MetricError(
            f"{fn}: no step in y: the steady state differs from the baseline by {size:.4g}, within "
            f"{STEP_NOISE_FACTOR:g} noise floors ({noise_floor:.4g}); expected a step response"
        )


def _ratio(num: float, den: float) -> float:
    return 100.0 * num / den if den != 0 else math.nan


def creep(
    t_s,
    y,
    *,
    drive=None,
    step_time_s: float | None = None,
    steady_state_after_s: float = 1.0,
    ss_window_s: float | None = None,
    final_window_s: float | None = None,
    baseline_s: float | None = None,
    min_hold_s: float = 0.01,
) -> CreepResult:
    """Creep of the output during a held step, in percent of the step (thesis Eq. 5.2).

    ``100 * (F_f - F_ss) / (F_ss - F_0)``, with F_0 the mean before the step, F_ss the
    mean over a window of ``ss_window_s`` centred ``steady_state_after_s`` after the step,
    and F_f the mean over the last ``final_window_s`` of the hold. The thesis divides by
    F_ss itself; an absolute force reading includes the ~50 N preload of the press, which
    has nothing to do with creep, so the step size is the reference here. The literal
    ratio is returned as ``percent_of_reading``.

    The step is located, in order of preference, at ``step_time_s``; from ``drive``
    (the largest change between two holds of at least ``min_hold_s``; the hold ends where
    the drive changes again); or from the output (the first jump at least half as large
    as the largest; the hold ends where the output falls back by half a step). Without
    ``drive`` or ``step_time_s`` the step time is the last sample before the output has
    moved 10 % of the way, which is late by the output's dead time.

    Parameters
    ----------
    t_s : array_like
        Time, strictly increasing.
    y : array_like
        Output (force or displacement).
    drive : array_like, optional
        Drive (command voltage or reference force) used to locate the step and the hold.
    step_time_s : float, optional
        Time of the step, when known.
    steady_state_after_s : float, default 1.0
        Time after the step at which the steady state F_ss is taken.
    ss_window_s, final_window_s : float, optional
        Averaging windows of F_ss and F_f. Default: 10 % of ``steady_state_after_s``.
    baseline_s : float, optional
        Average F_0 over at most this long before the step. Default: the whole hold before
        the step (with ``drive``) or everything before the step.
    min_hold_s : float, default 0.01
        Shortest drive plateau counted as a hold (shorter ones belong to a shaped step).

    Returns
    -------
    CreepResult

    Raises
    ------
    MetricError
        If the signals are unsuitable, there is no step, or the hold ends before
        ``steady_state_after_s`` (plus the windows).

    Examples
    --------
    A 20 N step on a 50 N preload that creeps at 0.04 N/s; F_ss = 70.04 N one second after
    the step, F_f = 70.44 N at the end:

    >>> t = np.arange(0, 12, 0.01)
    >>> y = np.where(t >= 1, 70 + 0.04 * (t - 1), 50)
    >>> r = creep(t, y, step_time_s=1.0)
    >>> round(r.percent, 3), round(r.percent_of_reading, 3)
    (1.983, 0.567)
    """
    fn = "creep"
    t = _time(fn, t_s)
    y = _signal(fn, "y", y)
    _same_length(fn, t_s=t, y=y)
    _not_flat(fn, "y", y)
    after = _positive(fn, "steady_state_after_s", steady_state_after_s)
    ss_w = _positive(fn, "ss_window_s", ss_window_s, allow_none=True) or 0.1 * after
    fin_w = _positive(fn, "final_window_s", final_window_s, allow_none=True) or 0.1 * after
    base_s = _positive(fn, "baseline_s", baseline_s, allow_none=True)
    hold_min = _positive(fn, "min_hold_s", min_hold_s)
    if ss_w > 2 * after:
        raise MetricError(
            f"{fn}: ss_window_s={ss_w:g} reaches back before the step; expected at most 2 * steady_state_after_s = "
            f"{2 * after:g}"
        )
    s = _locate_step(fn, t, y, drive, step_time_s, hold_min)
    _, f0, noise = _step_levels(fn, t, y, s, base_s)

    th = t[s.k_step : s.k_hold_end] - s.t_step
    yh = y[s.k_step : s.k_hold_end]
    hold_s = float(th[-1])
    need = after + ss_w / 2 + fin_w
    if hold_s < need:
        raise MetricError(
            f"{fn}: the hold lasts {hold_s:.4g} s after the step at t={s.t_step:.6g} s; expected at least {need:.4g} s "
            f"(steady_state_after_s={after:g} plus half of ss_window_s={ss_w:g} plus final_window_s={fin_w:g})"
        )
    eps = _rounding_s(t)  # window edges on a sample, stamped far from 0
    in_ss = np.abs(th - after) <= ss_w / 2 + eps
    if not in_ss.any():
        raise MetricError(
            f"{fn}: ss_window_s={ss_w:g} holds no sample around {after:g} s after the step; expected a window longer "
            "than the sampling interval"
        )
    f_ss = float(np.mean(yh[in_ss]))
    f_f = float(np.mean(yh[th >= hold_s - fin_w - eps]))
    size = f_ss - f0
    _check_step(fn, size, max(noise, _resolution(y) / math.sqrt(12.0)), float(np.max(np.abs(y))))
    return CreepResult(
        percent=100.0 * (f_f - f_ss) / size,
        percent_of_reading=_ratio(f_f - f_ss, f_ss),
        baseline=f0,
        steady_state=f_ss,
        final=f_f,
        step_size=size,
        step_time_s=s.t_step,
        t_ss_s=after,
        hold_s=hold_s,
        ss_window_s=ss_w,
        final_window_s=fin_w,
        noise_std=noise,
        located_by=s.located_by,
    )


def _crossing_time(th: np.ndarray, r: np.ndarray, level: float) -> float:
    """First time ``r`` reaches ``level`` (interpolated), NaN if never."""
    hit = np.flatnonzero(r >= level)
    if hit.size == 0:
        return math.nan
    i = int(hit[0])
    if i == 0:
        return float(th[0])
    frac = (level - r[i - 1]) / (r[i] - r[i - 1])
    return float(th[i - 1] + frac * (th[i] - th[i - 1]))


def overshoot(
    t_s,
    y,
    *,
    drive=None,
    step_time_s: float | None = None,
    settle_fraction: float = 0.02,
    ss_window_s: float | None = None,
    baseline_s: float | None = None,
    min_hold_s: float = 0.01,
    end_margin_s: float = 0.0,
) -> StepResult:
    """Overshoot, settling time and rise time of a step response (thesis Eq. 5.3, Table 6.9).

    Overshoot ``100 * (F_p - F_ss) / (F_ss - F_0)``: F_0 is the mean before the step, F_ss
    the mean over the last ``ss_window_s`` of the hold (before any step back), F_p the
    extreme of the output in the direction of the step. As for :func:`creep`, the step
    size is the reference (the thesis divides by F_ss, which includes the preload); the
    literal ratio is ``percent_of_reading``.

    The settling time is the time from the step until the output stays within
    ``±settle_fraction`` of the step size around F_ss (the thesis's 2 %). With a 0.5 N
    quantization a 20 N step has a 0.4 N band, narrower than the quantization noise: the
    result then sets ``band_below_noise`` and the settling time measures the noise. The
    peak of pure noise on such a signal is about one quantization step above the mean,
    so ``significant`` tells whether the overshoot exceeds that.

    The step is located as in :func:`creep` (``step_time_s``, else ``drive``, else the
    output). Pass ``drive`` or ``step_time_s`` for settling and peak times: located from the
    output alone, the step time is late by the output's dead time.

    Parameters
    ----------
    t_s : array_like
        Time, strictly increasing.
    y : array_like
        Output (force or displacement).
    drive : array_like, optional
        Drive used to locate the step and the end of the hold (a shaped or ramped step is
        one step as long as its intermediate plateaus are shorter than ``min_hold_s``).
    step_time_s : float, optional
        Time of the step, when known.
    end_margin_s : float
        Leave this much of the end of the hold out: a compensator that knows the reference
        ahead starts the step back early, which is not a failure to settle.
    settle_fraction : float, default 0.02
        Half-width of the settling band as a fraction of the step.
    ss_window_s : float, optional
        Averaging window of F_ss at the end of the hold. Default: the last 20 % of the hold.
    baseline_s : float, optional
        Average F_0 over at most this long before the step.
    min_hold_s : float, default 0.01
        Shortest drive plateau counted as a hold.

    Returns
    -------
    StepResult

    Raises
    ------
    MetricError
        If the signals are unsuitable, there is no step, or no baseline before it.

    Examples
    --------
    A second-order step of 20 N on a 50 N preload, damping 0.5 (analytic overshoot 16.3 %;
    the sampled peak falls just short of the true one):

    >>> t = np.arange(0, 0.05, 5e-5)
    >>> wn, z = 6.4e3, 0.5
    >>> wd, tau = wn * np.sqrt(1 - z**2), np.clip(t - 0.01, 0, None)
    >>> s = 1 - np.exp(-z * wn * tau) * (np.cos(wd * tau) + z / np.sqrt(1 - z**2) * np.sin(wd * tau))
    >>> r = overshoot(t, 50 + 20 * s, step_time_s=0.01)
    >>> round(r.percent, 1), r.significant
    (16.2, True)
    """
    fn = "overshoot"
    t = _time(fn, t_s)
    y = _signal(fn, "y", y)
    _same_length(fn, t_s=t, y=y)
    _not_flat(fn, "y", y)
    frac = _positive(fn, "settle_fraction", settle_fraction)
    if frac >= 1:
        raise MetricError(
            f"{fn}: settle_fraction is {settle_fraction!r}; expected a fraction of the step below 1 (thesis: 0.02)"
        )
    ss_w = _positive(fn, "ss_window_s", ss_window_s, allow_none=True)
    base_s = _positive(fn, "baseline_s", baseline_s, allow_none=True)
    hold_min = _positive(fn, "min_hold_s", min_hold_s)
    s = _locate_step(fn, t, y, drive, step_time_s, hold_min)
    _, f0, noise = _step_levels(fn, t, y, s, base_s)

    k_end = s.k_hold_end
    if end_margin_s > 0:
        # a compensator that knows the reference ahead starts the step back early:
        # leave that out of the hold
        k_end = max(s.k_step + 2, k_end - int(np.searchsorted(t[s.k_step :], t[s.k_step] + end_margin_s)))
    th = t[s.k_step : k_end] - s.t_step
    yh = y[s.k_step : k_end]
    hold_s = float(th[-1])
    if ss_w is None:
        ss_w = 0.2 * hold_s
    elif ss_w > hold_s:
        raise MetricError(
            f"{fn}: ss_window_s={ss_w:g} is longer than the hold ({hold_s:.4g} s); expected a window within the hold"
        )
    eps = _rounding_s(t)
    f_ss = float(np.mean(yh[th >= hold_s - ss_w - eps]))
    size = f_ss - f0
    resolution = _resolution(y[s.k_base_start : s.k_hold_end])
    floor = max(noise, resolution / math.sqrt(12.0))
    _check_step(fn, size, floor, float(np.max(np.abs(y))))
    direction = math.copysign(1.0, size)

    kp = int(np.argmax(direction * yh))
    f_p = float(yh[kp])

    band = frac * abs(size)
    err = yh - f_ss
    outside = np.flatnonzero(np.abs(err) > band)
    settled = not (outside.size and outside[-1] == yh.size - 1)
    if not outside.size:
        settling = 0.0
    elif not settled:
        settling = math.nan
    else:
        j = int(outside[-1])
        e1, e2 = err[j], err[j + 1]
        target = math.copysign(band, e1)
        settling = float(th[j] + (e1 - target) / (e1 - e2) * (th[j + 1] - th[j]))

    rel = direction * (yh - f0) / abs(size)
    t10 = _crossing_time(th, rel, 0.1)
    t90 = _crossing_time(th, rel, 0.9)
    return StepResult(
        percent=100.0 * (f_p - f_ss) / size,
        percent_of_reading=_ratio(f_p - f_ss, f_ss),
        significant=bool(direction * (f_p - f_ss) > 5.0 * noise + resolution),
        baseline=f0,
        steady_state=f_ss,
        peak=f_p,
        step_size=size,
        step_time_s=s.t_step,
        peak_time_s=float(th[kp]),
        settling_time_s=settling,
        settled=settled,
        settle_fraction=frac,
        band_below_noise=bool(band < 3.0 * floor),
        rise_time_s=t90 - t10,
        hold_s=hold_s,
        ss_window_s=float(ss_w),
        noise_std=noise,
        resolution=resolution,
        noise_floor=floor,
        located_by=s.located_by,
    )


# ---------------------------------------------------------------------------------------
# Tracking
# ---------------------------------------------------------------------------------------


def tracking_error(
    t_s,
    reference,
    y,
    *,
    exclude_ramps: bool = True,
    settle_s: float = 0.01,
    min_reference: float | None = None,
    tol: float | None = None,
) -> TrackingResult:
    """Absolute and relative tracking error of a compensated run (thesis Section 6.6).

    The absolute error is ``y - reference`` (N), the relative error
    ``100 * (y - reference) / reference`` (%). Both are evaluated only where the reference
    is constant -- on its plateaus (:func:`staircase_plateaus`), skipping ``settle_s``
    after each ramp, where the thesis ignores the spikes due to the output's delay -- and
    where ``|reference| >= min_reference``, since a relative error near zero reference is
    meaningless.

    Parameters
    ----------
    t_s : array_like
        Time, strictly increasing.
    reference : array_like
        Reference force (N).
    y : array_like
        Measured force (N).
    exclude_ramps : bool, default True
        Evaluate only on the reference's plateaus (after ``settle_s``). When False, every
        sample with ``|reference| >= min_reference`` is evaluated.
    settle_s : float, default 0.01
        Margin skipped at the start of each plateau that follows a ramp (the thesis's
        5 ms ramps settle in about 4 ms).
    min_reference : float, optional
        Smallest ``|reference|`` evaluated. Default: 5 % of ``max|reference|``.
    tol : float, optional
        Plateau tolerance, see :func:`staircase_plateaus`.

    Returns
    -------
    TrackingResult

    Raises
    ------
    MetricError
        If the signals are unsuitable, the reference has no plateau, or no sample is left
        to evaluate.

    Examples
    --------
    >>> t = np.arange(0, 1, 0.001)
    >>> ref = 10.0 * np.floor(t / 0.25) + 10.0
    >>> r = tracking_error(t, ref, 1.05 * ref - 1.0)
    >>> round(r.max_error_n, 3), round(r.min_error_n, 3), round(r.max_abs_relative_percent, 3)
    (1.0, -0.5, 5.0)
    """
    fn = "tracking_error"
    t = _time(fn, t_s)
    ref = _signal(fn, "reference", reference)
    y = _signal(fn, "y", y)
    _same_length(fn, t_s=t, reference=ref, y=y)
    top = float(np.max(np.abs(ref)))
    if top == 0:
        raise MetricError(f"{fn}: reference is zero everywhere; expected a reference force")
    if min_reference is None:
        min_ref = 0.05 * top
    else:
        min_ref = _positive(fn, "min_reference", min_reference)
    settle = float(settle_s)
    if not math.isfinite(settle) or settle < 0:
        raise MetricError(f"{fn}: settle_s is {settle_s!r}; expected a number >= 0")

    mask = np.abs(ref) >= min_ref
    used: tuple[Plateau, ...] = ()
    if exclude_ramps:
        plateaus = staircase_plateaus(ref, tol=tol)
        if not plateaus:
            raise MetricError(
                f"{fn}: reference has no constant segment; expected a staircase (or pass exclude_ramps=False)"
            )
        on = np.zeros(ref.size, dtype=bool)
        for p in plateaus:
            start = p.start if p.start == 0 else int(np.searchsorted(t, t[p.start] + settle))
            on[start : p.stop] = True
        mask &= on
        used = tuple(p for p in plateaus if mask[p.start : p.stop].any())
    else:
        settle = 0.0
    n = int(mask.sum())
    if n == 0:
        raise MetricError(
            f"{fn}: no sample left to evaluate: the reference is never constant for more than settle_s={settle:g} s "
            f"with |reference| >= min_reference={min_ref:.4g}; expected plateaus above min_reference"
        )
    err = y[mask] - ref[mask]
    rel = 100.0 * err / ref[mask]
    k = int(np.argmax(np.abs(err)))
    return TrackingResult(
        max_error_n=float(err.max()),
        min_error_n=float(err.min()),
        rms_error_n=float(np.sqrt(np.mean(err**2))),
        mean_error_n=float(np.mean(err)),
        max_relative_percent=float(rel.max()),
        min_relative_percent=float(rel.min()),
        max_abs_relative_percent=float(np.max(np.abs(rel))),
        t_at_max_abs_error_s=float(t[mask][k]),
        n_samples=n,
        min_reference=min_ref,
        settle_s=settle,
        mask=mask,
        plateaus=used,
    )
