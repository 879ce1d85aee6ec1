"""Identifying the press's mode from step responses (thesis Section 6.4).

A second-order mode (:mod:`piezopress.analysis.mode`) is fitted to one or several steps by
output-error least squares, started from the ringing's peak spacing and logarithmic
decrement. Pure numpy/scipy: no file I/O.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import find_peaks

from piezopress import signals
from piezopress.analysis.mode import HOLDS, mode_response
from piezopress.errors import FitError

__all__ = ["ModeFit", "identify_mode", "identify_mode_runs"]


@dataclass(frozen=True)
class ModeFit:
    """A second-order mode fitted to one or several step responses (:func:`identify_mode`).

    Model per run ``r``: ``y ≈ offset[r] + gain[r] * G[drive]``,
    ``G = wn^2 / (s^2 + 2 zeta wn s + wn^2)`` (discretised exactly for ``hold``), at rest at
    ``drive[0]``.

    Attributes
    ----------
    wn : float
        Natural frequency (rad/s), shared by all runs.
    zeta : float
        Damping ratio, shared.
    gain, offset : tuple of float
        Per run: output per unit of drive (e.g. N/V) and output at zero drive.
    rms_residual : tuple of float
        Per run: RMS of ``y - model`` (unit of ``y``).
    residual_pct_of_step : tuple of float
        Per run: ``100 * rms_residual / |gain * (drive_end - drive_start)|``.
    initial_wn, initial_zeta : float
        The guesses read off the ringing (peak spacing, logarithmic decrement).
    hold : str
        The drive's assumed behaviour between samples (``"foh"`` or ``"zoh"``).
    nfev : int
        Model evaluations used by the least-squares fit.
    zeros : tuple of float, optional
        An anti-resonance above the mode, ``(wz rad/s, damping)``: ``G`` times
        ``(s^2 + 2 zeta_z wz s + wz^2) / wz^2`` (:func:`~piezopress.analysis.mode.antiresonant`);
        None: the mode alone.
    """

    wn: float
    zeta: float
    gain: tuple[float, ...]
    offset: tuple[float, ...]
    rms_residual: tuple[float, ...]
    residual_pct_of_step: tuple[float, ...]
    initial_wn: float
    initial_zeta: float
    hold: str
    nfev: int
    zeros: tuple[float, float] | None = None

    @property
    def freq_hz(self) -> float:
        """Undamped natural frequency ``wn / 2 pi`` (Hz)."""
        return self.wn / (2.0 * math.pi)

    @property
    def damped_period_s(self) -> float:
        return 2.0 * math.pi / (self.wn * math.sqrt(1.0 - self.zeta**2))


@dataclass(frozen=True)
class _Run:
    fs_hz: float
    drive: np.ndarray
    y: np.ndarray
    step: float  # drive_end - drive_start
    settle: int  # first sample after the drive has settled


def _prepare_run(i: int, t_s, drive, y, step_time_s) -> _Run:
    where = f"run {i}"
    t = np.asarray(t_s, dtype=float)
    d = np.asarray(drive, dtype=float)
    yy = np.asarray(y, dtype=float)
    if not (t.ndim == d.ndim == yy.ndim == 1) or not (t.size == d.size == yy.size):
        raise FitError(
            f"{where}: t_s, drive and y must be 1-D of equal length, got shapes {t.shape}, {d.shape}, {yy.shape}"
        )
    if t.size < 32:
        raise FitError(f"{where}: {t.size} samples; expected at least 32")
    for label, v in (("t_s", t), ("drive", d), ("y", yy)):
        if not np.all(np.isfinite(v)):
            raise FitError(f"{where}: {label} holds NaN or inf at sample {int(np.flatnonzero(~np.isfinite(v))[0])}")
    dt = np.diff(t)
    mean_dt = float(np.mean(dt))
    if not (mean_dt > 0) or np.max(np.abs(dt - mean_dt)) > 1e-3 * mean_dt:
        raise FitError(f"{where}: t_s must be uniform and increasing (steps within 1e-3 of their mean {mean_dt:g} s)")
    fs = 1.0 / mean_dt
    n = t.size
    i0 = 0
    if step_time_s is not None:
        if not (t[0] <= step_time_s < t[-1]):
            raise FitError(f"{where}: step_time_s={step_time_s!r} outside the record [{t[0]:g}, {t[-1]:g}] s")
        i0 = int(np.searchsorted(t, step_time_s))
    d_start = float(np.mean(d[:i0])) if i0 > 0 else float(d[0])
    tail = max(4, n // 10)
    d_end = float(np.mean(d[-tail:]))
    step = d_end - d_start
    if not (abs(step) > 5.0 * float(np.std(d[-tail:])) and abs(step) > 1e-12 * max(1.0, abs(d_end))):
        raise FitError(
            f"{where}: no step in drive (change {step:g} against tail noise {float(np.std(d[-tail:])):g}); expected "
            "one step"
        )
    away = np.flatnonzero(np.abs(d[i0:] - d_end) > 0.05 * abs(step))
    settle = i0 + (int(away[-1]) + 1 if away.size else 0)
    if n - settle < 16:
        raise FitError(
            f"{where}: the drive settles {n - settle} samples before the end; expected a recorded ringing after it"
        )
    return _Run(fs, d, yy, step, settle)


def _ringing_guess(run: _Run) -> tuple[float, float] | None:
    """(wn, zeta) from the extrema of the ringing after the drive has settled, or None."""
    y = run.y[run.settle :]
    tail = max(8, y.size // 5)
    e = y - float(np.mean(y[-tail:]))
    noise = float(np.std(np.diff(y[-tail:]))) / math.sqrt(2.0)
    thr = max(4.0 * noise, 0.05 * float(np.max(np.abs(e))))
    hi, _ = find_peaks(e, prominence=thr)
    lo, _ = find_peaks(-e, prominence=thr)
    ext = sorted([(int(k), 1) for k in hi] + [(int(k), -1) for k in lo])
    ext = [(k, s) for k, s in ext if abs(e[k]) > thr]
    alt: list[tuple[int, int]] = []  # keep alternating maxima and minima
    for k, s in ext:
        if alt and alt[-1][1] == s:
            if abs(e[k]) > abs(e[alt[-1][0]]):
                alt[-1] = (k, s)
        else:
            alt.append((k, s))
    if len(alt) < 2:
        return None
    idx = np.array([k for k, _ in alt], dtype=float)
    half_period_s = float(np.median(np.diff(idx))) / run.fs_hz
    wd = math.pi / half_period_s
    amp = np.abs(e[idx.astype(int)])
    sigma = -float(np.polyfit(idx / run.fs_hz, np.log(amp), 1)[0]) if amp.size >= 2 else 0.1 * wd
    sigma = min(max(sigma, 1e-3 * wd), 3.0 * wd)
    wn = math.hypot(wd, sigma)
    return wn, min(max(sigma / wn, 1e-3), 0.9)


def identify_mode(t_s, drive, y, *, step_time_s: float | None = None, hold: str = "foh") -> ModeFit:
    """Fit ``y ≈ offset + gain * G[drive]``, ``G = wn^2/(s^2 + 2 zeta wn s + wn^2)``, to one step.

    ``drive`` must be the drive *actually applied* (the amplifier's monitor channel when it
    is recorded): the amplifier slews a commanded step at about 42 V/ms, half a damped
    period for a 20 V step, and fitting against the ideal command biases ``wn`` and
    ``zeta`` badly (a slower, better damped mode explains the softened ringing).

    Output-error least squares (``scipy.optimize.least_squares``) over
    ``(wn, zeta, gain, offset)`` on an exact discretisation of ``G``, started from the
    ringing: the median spacing of alternating extrema gives ``wd``, the slope of their log
    amplitudes (logarithmic decrement) ``zeta wn``; ``gain`` and ``offset`` start from a
    linear least-squares fit at those.

    Parameters
    ----------
    t_s, drive, y : array_like
        Uniform time (s), applied drive and measured output (e.g. N), equal lengths.
    step_time_s : float, optional
        Time of the step (the mean drive before it is the start level); default: the
        drive's first sample is the start level.
    hold : {"foh", "zoh"}
        How the drive behaves between its samples, so the discretisation is exact:
        ``"foh"`` (default) linear, right for a sampled monitor of the amplifier's
        continuous output (a slew-limited ramp); ``"zoh"`` held, right for a DAC command.
        A held model of a sampled 42 V/ms ramp lags it by half a sample while it slews,
        which shifts the ringing's phase and biases ``wn`` by about +2 % and ``zeta`` by
        about -5 % (Eq. 6.2's mode at 20 kHz).

    Raises
    ------
    FitError
        Unequal lengths, NaN, non-uniform time, no step in ``drive``, no ringing.

    Examples
    --------
    >>> fs = 20e3; t = np.arange(400) / fs; d = np.where(t >= 2e-3, 20.0, 0.0)
    >>> y = 50 + 2 * mode_response(d, fs, 6.44e3, 0.115)
    >>> fit = identify_mode(t, d, y, hold="zoh")
    >>> round(fit.wn), round(fit.zeta, 3), round(fit.gain[0], 3)
    (6440, 0.115, 2.0)
    """
    return identify_mode_runs(
        [t_s], [drive], [y], step_times_s=None if step_time_s is None else [step_time_s], hold=hold
    )


def identify_mode_runs(
    t_s_list,
    drive_list,
    y_list,
    *,
    step_times_s=None,
    hold: str = "foh",
    zeros: tuple[float, float] | None = None,
    antiresonance: bool = False,
) -> ModeFit:
    """:func:`identify_mode` over several runs: one ``(wn, zeta)``, a gain and offset per run.

    Meant for several low-amplitude steps (the press is most nearly linear there). The
    initial ``(wn, zeta)`` is the median of the runs' ringing guesses; every sample of
    every run weighs the same. ``step_times_s``: one value (or None) per run.

    ``zeros``: an anti-resonance ``(wz rad/s, damping)`` the mode is fitted with, held fixed;
    ``antiresonance=True``: one fitted with it (``wz`` between :data:`ANTIRESONANCE_RATIOS` times
    ``wn``, started at :data:`ANTIRESONANCE_START`; whether the steps show one is the caller's
    to judge, :func:`antiresonance_shown`).
    """
    if hold not in HOLDS:
        raise FitError(f"hold={hold!r}: expected one of {sorted(HOLDS)}")
    t_s_list, drive_list, y_list = list(t_s_list), list(drive_list), list(y_list)
    if not t_s_list or not (len(t_s_list) == len(drive_list) == len(y_list)):
        raise FitError(
            f"t_s_list, drive_list, y_list: expected the same number (>= 1) of runs, got {len(t_s_list)}, "
            f"{len(drive_list)}, {len(y_list)}"
        )
    steps = [None] * len(t_s_list) if step_times_s is None else list(step_times_s)
    if len(steps) != len(t_s_list):
        raise FitError(f"step_times_s: expected {len(t_s_list)} values (one per run), got {len(steps)}")
    runs = [_prepare_run(i, t, d, y, s) for i, (t, d, y, s) in enumerate(zip(t_s_list, drive_list, y_list, steps))]

    guesses = [g for g in (_ringing_guess(r) for r in runs) if g is not None]
    if not guesses:
        raise FitError(
            "no ringing found after the step in any run (fewer than two alternating extrema above the noise)"
        )
    wn0 = float(np.median([g[0] for g in guesses]))
    zeta0 = float(np.median([g[1] for g in guesses]))
    wn_max = 0.99 * math.pi * min(r.fs_hz for r in runs)  # below Nyquist
    wn0 = min(wn0, 0.9 * wn_max)

    if zeros is not None and antiresonance:
        raise FitError("zeros and antiresonance=True: expected zeros held fixed or fitted, not both")

    def zeros_of(x) -> tuple[float, float] | None:
        return (float(x[0] * x[2]), float(x[3])) if antiresonance else zeros

    def unit_responses(x):
        z = zeros_of(x)
        return [mode_response(r.drive, r.fs_hz, x[0], x[1], hold=hold, zeros=z) for r in runs]

    def linear(us) -> list[tuple[float, float]]:
        """Each run's gain and offset, the least-squares best for the unit responses ``us``."""
        out = []
        for r, u in zip(runs, us):
            su, n = float(u.sum()), u.size
            suu, sy, suy = float(u @ u), float(r.y.sum()), float(u @ r.y)
            det = n * suu - su * su
            if det <= 1e-300 * max(1.0, n * suu):  # a flat response: the offset alone
                out.append((0.0, sy / n))
            else:
                out.append(((n * suy - su * sy) / det, (suu * sy - su * suy) / det))
        return out

    # variable projection: the gains and offsets enter linearly, so for every (wn, zeta) they
    # are solved exactly and only (wn, zeta) is searched (the same optimum as searching all of
    # them, at a fraction of the cost: two responses per Jacobian instead of 2 + 2 runs)
    def residuals(x):
        us = unit_responses(x)
        return np.concatenate([r.y - (c + g * u) for r, u, (g, c) in zip(runs, us, linear(us))])

    lower, upper = [1e-6 * wn0, 1e-4], [wn_max, 0.95]
    x0 = [wn0, zeta0]
    if antiresonance:
        lower += [ANTIRESONANCE_RATIOS[0], ANTIRESONANCE_DAMPING[0]]
        upper += [ANTIRESONANCE_RATIOS[1], ANTIRESONANCE_DAMPING[1]]
        x0 += list(ANTIRESONANCE_START)
    x0 = np.clip(x0, np.array(lower) + 1e-12, np.array(upper) - 1e-12)
    sol = least_squares(residuals, x0, bounds=(lower, upper), x_scale="jac", method="trf", xtol=1e-12, ftol=1e-12)
    wn, zeta = float(sol.x[0]), float(sol.x[1])
    lin = linear(unit_responses(sol.x))
    gains = tuple(float(g) for g, _ in lin)
    offsets = tuple(float(c) for _, c in lin)
    res = residuals(sol.x)
    rms, pct, start = [], [], 0
    for r, g in zip(runs, gains):
        part = res[start : start + r.y.size]
        start += r.y.size
        rms.append(float(np.sqrt(np.mean(part**2))))
        size = abs(g * r.step)
        pct.append(100.0 * rms[-1] / size if size > 0 else math.inf)
    return ModeFit(wn, zeta, gains, offsets, tuple(rms), tuple(pct), wn0, zeta0, hold, int(sol.nfev), zeros_of(sol.x))


# --------------------------------------------------------------------------- the drive chain

#: Drive chains tried when the applied drive is not recorded: the command as it is, a slew
#: limit (an amplifier's current limit into the stack's capacitance: dV/dt <= I/C), a
#: first-order amplifier bandwidth, a pure delay (a board's output FIFO, a converter's group
#: delay: the mode identified without it reads the delay as a lower, more damped mode).
#: ``lowpass_delay``: a second-order low-pass and a pure delay in series (an amplifier's and a
#: load cell filter's bandwidth, a converter's group delay and a board's latency together,
#: which no one-parameter chain draws), named only where it is :data:`LOWPASS_DELAY_MARGIN`
#: better than the best one-parameter chain. ``slew_lowpass_delay``: a slew limit before that
#: series (a current-limited amplifier of its own bandwidth, read through a filtered load cell:
#: the slew alone draws a large step's rise but not the chain's lag, and the mode fitted
#: through it takes the lag as damping), named where it is :data:`SLEW_SERIES_MARGIN` better
#: than the best of the others, or where it reads the steps no worse than the slew alone and
#: only its mode is the one the steps' ringing shows (:func:`_rings_as`).
CHAINS = ("none", "slew", "first_order", "delay", "lowpass_delay", "slew_lowpass_delay")
#: The ``lowpass_delay`` chain (three parameters) must lower the steps' residual by this much
#: (fraction) against the best one-parameter chain to be chosen. On the third test press (a
#: 2.5 kHz amplifier, a 1.5 kHz Bessel filter, a 1.5-sample decimation filter) it lowers it
#: 7x; where a one-parameter chain is the press's own, three parameters gain a few percent.
LOWPASS_DELAY_MARGIN = 0.3
#: The ``slew_lowpass_delay`` chain is named where it lowers the steps' residual by this much
#: (fraction) against the best of the others. It is tried only where a slew alone reads the
#: steps better than the plain command; without a slew limit its slew ends where it never acts
#: and it draws what ``lowpass_delay`` draws. On a chain of another form (a current-limited
#: second-order amplifier, a Bessel load-cell filter: tests/test_shaper.py) it lowers the
#: residual 20-40x against the slew alone. On the third test press, whose loop and
#: antiresonance no chain draws, a floor of about 0.9 N squeezes it to 18 % (seed 0: 1.12 to
#: 0.91 N) or 3 % (seed 1: 0.97 to 0.94 N); there the ringing decides (the slew alone leaves
#: the mode at 532 Hz, damping 0.52, and 522 Hz, 0.63; the series 753 Hz, 0.024, and 816 Hz,
#: 0.013; the presses' 749 Hz, 0.052, and 863 Hz, 0.064).
SLEW_SERIES_MARGIN = 0.1
#: The chains with a second-order low-pass and a delay in series (their lead, their low-pass).
SERIES_CHAINS = ("lowpass_delay", "slew_lowpass_delay")


@dataclass(frozen=True)
class ChainFit:
    """The mode identified through an identified drive chain (:func:`identify_mode_chain`).

    ``chain`` is one of :data:`CHAINS`; ``slew_v_per_s`` (``slew``), ``tau_s``
    (``first_order``) or ``delay_s`` (``delay``) its parameter; ``candidates`` the mean RMS
    residual of every chain tried.
    """

    mode: ModeFit
    chain: str
    slew_v_per_s: float | None
    tau_s: float | None
    candidates: dict[str, float]
    delay_s: float | None = None
    lowpass: tuple[float, float] | None = None  # ``lowpass_delay``: (natural frequency rad/s, damping)
    # ``slew_lowpass_delay``: the chain's low-frequency delay (s), which steps that all slew do not
    # give from its parts (see identify_mode_chain)
    lag_s: float | None = None
    # a series chain identified on steps at two sample rates: its delay's part in samples of each
    # run's rate; ``delay_s`` is then the part in seconds, which may be negative (None: one rate)
    delay_samples: float | None = None
    # where an anti-resonance was named with a series chain: the chain's delay as the steps read it
    # without the zeros, ``(seconds, samples)`` (see ``bundle.chain_own_delay``)
    delay_without_zeros: tuple[float, float] | None = None

    @property
    def parameter(self) -> float | tuple[float, ...] | None:
        k = () if self.delay_samples is None else (float(self.delay_samples),)
        if self.chain == "lowpass_delay" and self.lowpass is not None:
            return (*self.lowpass, float(self.delay_s or 0.0), *k)
        if self.chain == "slew_lowpass_delay" and self.lowpass is not None and self.slew_v_per_s:
            return (*self.lowpass, float(self.delay_s or 0.0), float(self.slew_v_per_s), *k)
        return {"slew": self.slew_v_per_s, "first_order": self.tau_s, "delay": self.delay_s}.get(self.chain)


def slew_limited(command: np.ndarray, fs_hz: float, slew_v_per_s: float) -> np.ndarray:
    """The command as an amplifier that slews at most ``slew_v_per_s`` delivers it, sampled
    (starting from the command's first value)."""
    c = np.asarray(command, float)
    return signals.rate_limit(c, float(c[0]), slew_v_per_s / fs_hz)


def first_order(command: np.ndarray, fs_hz: float, tau_s: float) -> np.ndarray:
    """The held command through a first-order lag of time constant ``tau_s`` (exact for a held input)."""
    from scipy.signal import lfilter

    c = np.asarray(command, float)
    a = math.exp(-1.0 / (fs_hz * tau_s))
    return c[0] + lfilter([1.0 - a], [1.0, -a], c - c[0])


def delayed(command: np.ndarray, fs_hz: float, delay_s: float) -> np.ndarray:
    """The command delayed by ``delay_s`` (linear between samples; the first value before it)."""
    c = np.asarray(command, float)
    return signals.delayed(c, fs_hz, delay_s)


def lowpass_delayed(command: np.ndarray, fs_hz: float, p: tuple[float, ...]) -> np.ndarray:
    """The held command through a unit second-order low-pass ``p[:2] = (wn rad/s, damping)``
    (exact for a held input), then delayed by ``p[2]`` s (linear between samples); with a
    fourth ``p[3]``, by ``p[2] + p[3] / fs_hz`` (never below 0): ``p[3]`` samples of the run's
    own rate (:func:`sampled_delay_s`)."""
    wc, zc, d = p[:3]
    out = mode_response(np.asarray(command, float), fs_hz, wc, zc, hold="zoh")
    return signals.delayed(out, fs_hz, sampled_delay_s(d, p[3] if len(p) > 3 else 0.0, fs_hz))


def sampled_delay_s(delay_s: float, samples: float, fs_hz: float) -> float:
    """A delay of ``delay_s`` seconds and ``samples`` samples at ``fs_hz``, never below 0 (the
    seconds part of a delay identified at two rates may be negative: a low-pass that holds part
    of the sampling's lag)."""
    return max(0.0, float(delay_s) + float(samples) / float(fs_hz))


def slew_lowpass_delayed(command: np.ndarray, fs_hz: float, p: tuple[float, ...]) -> np.ndarray:
    """The command slewing at most ``p[3]`` V/s, then through :func:`lowpass_delayed`
    ``(p[0], p[1], p[2], *p[4:])``."""
    return lowpass_delayed(slew_limited(command, fs_hz, p[3]), fs_hz, (*p[:3], *p[4:]))


def lowpass_delay_group_delay_s(wc: float, zc: float, delay_s: float) -> float:
    """The low-frequency delay of the ``lowpass_delay`` chain: ``2 zeta / wn`` and the pure delay
    (what the compensator leads, ``bundle.chain_delay_s``)."""
    return 2.0 * zc / wc + delay_s


#: How each chain makes the applied drive of a command: ``(command, fs_hz, parameter)``.
CHAIN_DRIVES = {
    "slew": slew_limited,
    "first_order": first_order,
    "delay": delayed,
    "lowpass_delay": lowpass_delayed,
    "slew_lowpass_delay": slew_lowpass_delayed,
}


#: An anti-resonance (a pair of zeros above the mode: a stack pushing a platen on a compliant
#: frame, read at the platen) is searched with its frequency between these multiples of the
#: mode's ...
ANTIRESONANCE_RATIOS = (1.1, 8.0)
#: ... its damping in this range ...
ANTIRESONANCE_DAMPING = (0.005, 0.9)
#: ... started from this ratio and damping ...
ANTIRESONANCE_START = (2.5, 0.2)
#: ... and named where it lowers the steps' mean RMS residual by this fraction, its frequency
#: inside the range searched (one at a bound is the search's edge, not the press's notch). On the
#: third test press (zeros at 2.3 times the mode, damping 0.15) the series chain fitted again with
#: them lowers the steps' residual by 13 % (seed 0: 0.437 to 0.379 N, seed 1: 0.406 to 0.353 N),
#: the zeros read at 2.35 and 2.37 times the mode, their damping at the range's floor (the chain's
#: one low-pass stands for the amplifier's and the load cell's filters, and a deeper notch takes up
#: what it misses). Steps drawn without zeros (``tests/test_antiresonance.py``), the virtual rig's
#: and the second test press's read no zeros.
ANTIRESONANCE_MARGIN = 0.08


def antiresonance_shown(plain: ModeFit, zeroed: ModeFit) -> bool:
    """Whether the steps show an anti-resonance: the mode fitted with zeros (``zeroed``) reads
    them :data:`ANTIRESONANCE_MARGIN` better than the mode alone (``plain``), with its zeros
    inside the range searched."""
    if zeroed.zeros is None:
        return False
    ratio, damping = zeroed.zeros[0] / zeroed.wn, zeroed.zeros[1]
    lo, hi = ANTIRESONANCE_RATIOS
    inside = 1.01 * lo < ratio < 0.99 * hi and damping < 0.99 * ANTIRESONANCE_DAMPING[1]
    return inside and float(np.mean(zeroed.rms_residual)) < (1.0 - ANTIRESONANCE_MARGIN) * float(
        np.mean(plain.rms_residual)
    )


#: Steps whose sample rates differ by at least this ratio tell a delay in samples from one in
#: seconds (:func:`_fit_lowpass_delay`).
TWO_RATES_RATIO = 1.5
#: The most samples of its own rate a chain's delay is searched over at two rates.
MAX_DELAY_SAMPLES = 32.0


def _fit_lowpass_delay(
    t_s_list,
    command_list,
    y_list,
    start: ModeFit,
    lag_s: float,
    slew: tuple[float, float, float] | None = None,
    antiresonance: bool = False,
) -> tuple[float, ...]:
    """The ``lowpass_delay`` chain's ``(wc, zc, delay)`` fitted jointly with the mode by output
    error (the runs' gains and offsets solved exactly at every step, as in
    :func:`identify_mode_runs`), started from ``start`` (the mode through the best
    one-parameter chain) with the low-pass and the delay each carrying half of ``lag_s``, its
    low-frequency delay; the low-pass is kept above the mode (above 0.3 times it with a slew,
    which shapes the rise with it) and below Nyquist. ``slew``:
    ``(start, low, high)`` V/s of a slew limit fitted with them (``slew_lowpass_delay``, whose
    ``(wc, zc, delay, slew)`` is returned).

    Steps at sample rates :data:`TWO_RATES_RATIO` apart or more tell the delay's parts: a lag
    that scales with the sample period (a DAC's hold, a decimating converter's filter, a FIFO)
    from one in seconds. The delay is then ``delay + samples / fs`` at each run's rate, and
    ``samples`` is returned last (``(wc, zc, delay, samples)``, ``(wc, zc, delay, slew,
    samples)``); ``delay`` may be negative (a low-pass that holds part of the sampling's lag), the
    delay at every rate of the runs is not. On the third test press (a held DAC and a 1.5-sample
    decimation filter) steps at 20 and 50 kHz read 2.23 samples and -28 us (seed 0; seed 1: 2.23,
    -40 us), with a 50 V step at 5 kHz instead 2.59 samples; with a FIFO of 6 samples, 8.23.

    ``antiresonance``: the mode is fitted with a pair of zeros above it (:func:`antiresonance_shown`),
    which changes how the chain's lag splits between its low-pass and its delay (on the third test
    press the low-pass moves from 920 to 1487 Hz and the seconds above from -28 to +66 us, seed
    0); only the chain's parameters are returned, the zeros are fitted again through it."""
    runs = [_prepare_run(i, t, c, y, None) for i, (t, c, y) in enumerate(zip(t_s_list, command_list, y_list))]
    fs = min(r.fs_hz for r in runs)
    fs_top = max(r.fs_hz for r in runs)
    two_rates = fs_top >= TWO_RATES_RATIO * fs
    wn_max = 0.99 * math.pi * fs
    n_slew = 0 if slew is None else 1

    def chain(q):
        """The chain's parameters (the delay is ``q[4]`` at the fastest rate)."""
        k = float(q[5 + n_slew]) if two_rates else 0.0
        delay = float(q[4]) - k / fs_top
        return (*q[2:4], delay, *([math.exp(q[5])] if slew is not None else []), *([k] if two_rates else []))

    def drive(r, q):
        p = chain(q)
        return lowpass_delayed(r.drive, r.fs_hz, p) if slew is None else slew_lowpass_delayed(r.drive, r.fs_hz, p)

    n_chain = 5 + n_slew + (1 if two_rates else 0)

    def residuals(q):
        wn, zeta = q[:2]
        zeros = (float(wn * q[n_chain]), float(q[n_chain + 1])) if antiresonance else None
        out = []
        for r in runs:
            u = mode_response(drive(r, q), r.fs_hz, wn, zeta, hold="foh", zeros=zeros)
            a = np.column_stack([u, np.ones_like(u)])
            coef, *_ = np.linalg.lstsq(a, r.y, rcond=None)
            out.append(r.y - a @ coef)
        return np.concatenate(out)

    lag = max(lag_s, 1.0 / fs)
    zc0 = 0.7
    wc0 = min(max(2.0 * zc0 / (0.5 * lag), 1.05 * start.wn), 0.9 * wn_max)
    lower = [0.2 * start.wn, 1e-4, start.wn if slew is None else 0.3 * start.wn, 0.2, 0.0]
    upper = [min(5.0 * start.wn, wn_max), 0.95, wn_max, 0.99, max(4.0 * lag, 2.0 / fs)]
    x0 = [start.wn, start.zeta, wc0, zc0, 0.5 * lag]
    if slew is not None:
        lower.append(math.log(slew[1]))
        upper.append(math.log(slew[2]))
        x0.append(math.log(slew[0]))
    if two_rates:  # the delay at the fastest rate, and the samples a lag read at the slowest would take
        lower.append(0.0)
        upper.append(MAX_DELAY_SAMPLES)
        x0[4] = 0.5 * lag * fs / fs_top
        x0.append(0.5 * lag * fs)
    if antiresonance:
        lower += [ANTIRESONANCE_RATIOS[0], ANTIRESONANCE_DAMPING[0]]
        upper += [ANTIRESONANCE_RATIOS[1], ANTIRESONANCE_DAMPING[1]]
        x0 += list(ANTIRESONANCE_START)
    x0 = np.clip(x0, np.array(lower) + 1e-9, np.array(upper) - 1e-9)
    sol = least_squares(residuals, x0, bounds=(lower, upper), x_scale="jac", method="trf", max_nfev=400)
    return tuple(float(v) for v in chain(sol.x))


def _told_samples(name: str, p: tuple[float, ...]) -> bool:
    """Whether a series chain's parameters ``p`` end with the delay's part in samples (steps at two rates)."""
    return len(p) == (5 if name == "slew_lowpass_delay" else 4)


def _series_lag_s(name: str, p: tuple[float, ...], fs_hz: float) -> float:
    """The low-frequency delay of a series chain's parameters ``p`` (:func:`chain` of
    :func:`_fit_lowpass_delay`) in a run sampled at ``fs_hz``."""
    samples = p[-1] if _told_samples(name, p) else 0.0
    return 2.0 * p[1] / p[0] + sampled_delay_s(p[2], samples, fs_hz)


def _rings_as(m: ModeFit, ringing: ModeFit) -> bool:
    """Whether the mode ``m`` is the one the steps' ringing shows (read off the steps after the
    slewed drive has settled: ``ringing``'s peak spacing and logarithmic decrement,
    ``initial_wn`` and ``initial_zeta``): within 20 % in frequency and at most three times as
    damped. A chain that leaves the mode far more damped than the ringing has put its own lag
    into the mode's damping."""
    return abs(m.wn / ringing.initial_wn - 1.0) < 0.2 and m.zeta < 3.0 * ringing.initial_zeta + 0.02


def _slewed_lag_s(slewed: ModeFit, mode: ModeFit) -> float:
    """The low-frequency delay the mode fitted through a slew alone (``slewed``) takes beyond
    ``mode``'s own: the chain's, for a small signal."""
    return max(0.0, 2.0 * slewed.zeta / slewed.wn - 2.0 * mode.zeta / mode.wn)


def identify_mode_chain(t_s_list, command_list, y_list, chain_from=None) -> ChainFit:
    """The mode from steps whose applied drive was not recorded: the drive chain between the
    command and the stack (a slew limit or a first-order bandwidth) is identified with it.

    For each chain of :data:`CHAINS`, its parameter is searched (bounded, on a log scale) for
    the lowest mean RMS residual of :func:`identify_mode_runs` on the drive that chain makes
    of the command (sampled, so modelled as linear between samples); the chain with the
    lowest residual wins, the plain command unless another lowers it by 10 % or more (so a
    chain is named only where the steps show it), and a bandwidth rather than a delay unless
    the delay is 10 % better (a lag a low-pass explains is no delay). The series chains
    (``lowpass_delay``, ``slew_lowpass_delay``) are fitted jointly with the mode and named
    under their own rules (:data:`LOWPASS_DELAY_MARGIN`, :data:`SLEW_SERIES_MARGIN`).

    ``chain_from``: other steps ``(t_s_list, command_list, y_list)`` to choose the chain on
    (steps of every size: a slew limit lengthens a large step's rise, a bandwidth does not,
    which the small steps alone cannot tell apart); the mode is then fitted on the given
    (small) steps through the chain chosen there.
    """
    from scipy.optimize import minimize_scalar

    if chain_from is not None:
        chosen = identify_mode_chain(*chain_from)
        p = chosen.parameter
        fs_own = [1.0 / float(np.mean(np.diff(np.asarray(t, float)))) for t in t_s_list]
        zeros = chosen.mode.zeros  # the anti-resonance the steps of every size showed, held
        if chosen.chain == "none":
            mode = identify_mode_runs(t_s_list, command_list, y_list, hold="zoh", zeros=zeros)
        else:
            make = CHAIN_DRIVES[chosen.chain]
            mode = identify_mode_runs(
                t_s_list, [make(c, f, p) for c, f in zip(command_list, fs_own)], y_list, hold="foh", zeros=zeros
            )
        if chosen.chain == "slew_lowpass_delay":  # the small signal's delay on these steps (below)
            slewed = identify_mode_runs(
                t_s_list,
                [slew_limited(c, f, float(chosen.slew_v_per_s)) for c, f in zip(command_list, fs_own)],
                y_list,
                hold="foh",
            )
            return replace(chosen, mode=mode, lag_s=_slewed_lag_s(slewed, mode))
        return replace(chosen, mode=mode)

    t_s_list, command_list, y_list = list(t_s_list), list(command_list), list(y_list)
    fs = [1.0 / float(np.mean(np.diff(np.asarray(t, float)))) for t in t_s_list]
    steps = [float(np.ptp(c)) for c in command_list]

    def fit(drives, hold):
        return identify_mode_runs(t_s_list, drives, y_list, hold=hold)

    def cost(f: ModeFit) -> float:
        return float(np.mean(f.rms_residual))

    plain = fit(command_list, "zoh")
    results: dict[str, tuple[float, ModeFit, float | None]] = {"none": (cost(plain), plain, None)}
    period = 2.0 * math.pi / plain.wn
    # a slew that takes from a twentieth of a sample to ten mode periods for the smallest step
    lo_slew, hi_slew = min(steps) / (10.0 * period), min(steps) * 20.0 * max(fs)

    def chain_cost(name: str) -> Callable[[float], float]:
        """The mean residual of the mode fitted through chain ``name`` of parameter ``exp(log_p)``."""
        make = CHAIN_DRIVES[name]

        def cost_of(log_p: float) -> float:
            p = math.exp(log_p)
            try:
                return cost(fit([make(c, f, p) for c, f in zip(command_list, fs)], "foh"))
            except FitError:
                return math.inf

        return cost_of

    for name, lo, hi in (
        ("slew", lo_slew, hi_slew),
        ("first_order", 0.05 / max(fs), 2.0 * period),
        ("delay", 0.05 / max(fs), 2.0 * period),
    ):
        func = chain_cost(name)
        grid = np.linspace(math.log(lo), math.log(hi), 9)
        costs = [func(g) for g in grid]
        i = int(np.argmin(costs))
        a, b = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
        sol = minimize_scalar(func, bounds=(a, b), method="bounded", options={"xatol": 0.01})
        best = float(sol.x) if sol.fun <= costs[i] else float(grid[i])
        p = math.exp(best)
        drives = [CHAIN_DRIVES[name](c, f, p) for c, f in zip(command_list, fs)]
        m = fit(drives, "foh")
        results[name] = (cost(m), m, p)
    best_name = min(results, key=lambda k: results[k][0])
    if best_name == "delay" and results["first_order"][0] <= 1.1 * results["delay"][0]:
        best_name = "first_order"  # a lag a bandwidth explains as well is no delay (an amplifier's, a filter's)
    if results[best_name][0] > 0.9 * results["none"][0]:
        best_name = "none"
    # the low-pass and delay in series, started from the best lag of one parameter
    lag = {"first_order": results["first_order"][2], "delay": results["delay"][2]}
    one = min(("first_order", "delay"), key=lambda k: results[k][0])
    try:
        q = _fit_lowpass_delay(t_s_list, command_list, y_list, results[one][1], float(lag[one] or 0.0))
        m = fit([lowpass_delayed(c, f, q) for c, f in zip(command_list, fs)], "foh")
        results["lowpass_delay"] = (cost(m), m, q)
        if cost(m) < (1.0 - LOWPASS_DELAY_MARGIN) * results[best_name][0]:
            best_name = "lowpass_delay"
    except (FitError, ValueError, np.linalg.LinAlgError):
        pass  # the series chain is a refinement: without it the one-parameter chains stand
    if results["slew"][0] < results["none"][0] and np.isfinite(results["slew"][0]):
        # a slew limit with the chain's own lag: started from the slew the steps read alone, and
        # from the mode read off the ringing (the mode fitted through the slew alone takes the
        # chain's lag as damping), the chain's lag a few samples
        slewed = results["slew"][1]
        ringing = replace(slewed, wn=slewed.initial_wn, zeta=slewed.initial_zeta)
        for start, lag_s in ((slewed, float(lag[one] or 0.0)), (ringing, 4.0 / max(fs))):
            try:
                q = _fit_lowpass_delay(
                    t_s_list,
                    command_list,
                    y_list,
                    start,
                    lag_s,
                    slew=(float(results["slew"][2]), lo_slew, hi_slew),
                )
                m = fit([slew_lowpass_delayed(c, f, q) for c, f in zip(command_list, fs)], "foh")
            except (FitError, ValueError, np.linalg.LinAlgError):
                continue  # a refinement, as the series chain
            if cost(m) < results.get("slew_lowpass_delay", (math.inf,))[0]:
                results["slew_lowpass_delay"] = (cost(m), m, q)
        series_cost = results.get("slew_lowpass_delay", (math.inf,))[0]
        if series_cost < (1.0 - SLEW_SERIES_MARGIN) * results[best_name][0] or (
            best_name == "slew"
            and series_cost <= results["slew"][0]
            and _rings_as(results["slew_lowpass_delay"][1], results["slew"][1])
            and not _rings_as(results["slew"][1], results["slew"][1])
        ):
            best_name = "slew_lowpass_delay"
    c, m, p = results[best_name]
    series = best_name in SERIES_CHAINS
    without_zeros = None
    # the mode with an anti-resonance, through the chain chosen (a series chain fitted again with
    # the zeros, which move its lag between the low-pass and the delay)
    try:
        if series:
            slew_range = (float(p[3]), lo_slew, hi_slew) if best_name == "slew_lowpass_delay" else None
            series_lag = _series_lag_s(best_name, p, min(fs))
            q = _fit_lowpass_delay(t_s_list, command_list, y_list, m, series_lag, slew=slew_range, antiresonance=True)
        else:
            q = p
        make = CHAIN_DRIVES.get(best_name)
        drives = command_list if make is None else [make(cc, f, q) for cc, f in zip(command_list, fs)]
        zeroed = identify_mode_runs(t_s_list, drives, y_list, hold="zoh" if make is None else "foh", antiresonance=True)
        results[best_name + "+antiresonance"] = (cost(zeroed), zeroed, q)
        if antiresonance_shown(m, zeroed):
            if series:
                without_zeros = (float(p[2]), float(p[-1]) if _told_samples(best_name, p) else 0.0)
            c, m, p = results[best_name + "+antiresonance"]
    except (FitError, ValueError, np.linalg.LinAlgError):
        pass  # a refinement, as the series chains
    lag_s = None
    if best_name == "slew_lowpass_delay":
        # steps that all slew give the delay of their slewed rise, not how it splits between the
        # chain's low-pass and the mode: a small signal's delay is read off the mode fitted through
        # the slew alone, which takes all of the lag (2 zeta / wn) less the mode's own. On the
        # third test press (seed 0, a 20 V/ms limit: every step slews) the series' own low-pass
        # put 0.58 ms on the compensator's lead and the 5, 10 and 50 Hz loops read 1.23, 1.89
        # and 7.9 %; with the slew alone's 0.29 ms, 0.70, 0.82 and 1.84 %. On a chain of
        # another form (tests/test_shaper.py) it reads half the small-signal delay: a ramp's
        # delay leaves out the amplifier loop's own
        lag_s = _slewed_lag_s(results["slew"][1], m)
    return ChainFit(
        m,
        best_name,
        p if best_name == "slew" else p[3] if best_name == "slew_lowpass_delay" else None,
        p if best_name == "first_order" else None,
        {k: v[0] for k, v in results.items()},
        p[2] if series else p if best_name == "delay" else None,
        (p[0], p[1]) if series else None,
        lag_s,
        p[-1] if series and _told_samples(best_name, p) else None,
        without_zeros,
    )
