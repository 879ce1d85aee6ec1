"""Signatures of structure no catalogue cause explains, said in the press's own terms.

A **line independent of the drive** (mains pickup, a pump, a fan): a spectral line in the
residual where the drive does nothing (a rest run, the hold of a creep step, the flat parts of
any run, once the press has settled), found again at the same frequency, with a similar size, in
the runs that move. It is told apart from the press's own ringing (which follows the drive's
changes and has died out in the quiet stretches) and from the drive's harmonics (absent where
the drive is constant).

>>> import numpy as np
>>> fs = 1000.0
>>> t = np.arange(0, 20, 1 / fs)
>>> rng = np.random.default_rng(0)
>>> hum = 0.5 * np.sin(2 * np.pi * 50.0 * t + 1.0)
>>> rest = (t, np.zeros_like(t), hum + 0.2 * rng.standard_normal(t.size), fs, "rest")
>>> x = 75 * (1 - np.cos(2 * np.pi * 0.5 * t))
>>> moving = (t, x, hum + 0.2 * rng.standard_normal(t.size), fs, "sweep")
>>> [(round(s.freq_hz, 1), round(s.amplitude, 2), s.mains) for s in drive_independent_lines([rest, moving])]
[(50.0, 0.5, True)]
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import signal

from piezopress import signals

__all__ = [
    "Line",
    "drive_independent_lines",
    "fit_line",
    "line_of",
    "QUIET_MIN_S",
    "SETTLE_S",
    "PEAK_OVER_MEDIAN",
    "MAINS_HZ",
]

#: A quiet stretch (drive constant) counts from this long after the drive last changed (the
#: press's ringing and the sensor's filter have died out)...
SETTLE_S = 0.05
#: ... and when it lasts at least this long after that.
QUIET_MIN_S = 0.5
#: A line stands this many times above the spectrum's median around it.
PEAK_OVER_MEDIAN = 12.0
#: The mains frequencies a line is checked against (and their harmonics to the 5th).
MAINS_HZ = (50.0, 60.0)

Run = tuple[np.ndarray, np.ndarray, np.ndarray, float, str]  # t_s, drive, residual, fs_hz, name


@dataclass(frozen=True)
class Line:
    """A line in the residual where the drive does nothing, and how far it reaches."""

    freq_hz: float
    amplitude: float  # in the residual's unit, at rest (median over the quiet stretches)
    quiet_runs: tuple[str, ...]  # runs whose quiet stretches show it
    driven_runs: tuple[str, ...]  # runs under drive that show it with a similar size
    driven_tried: int  # runs under drive it could be looked for in
    mains: bool  # at a mains frequency or one of its harmonics

    def text(self, unit_label: str) -> str:
        where = f"present where the drive is constant ({', '.join(self.quiet_runs[:4])}"
        where += ", ...)" if len(self.quiet_runs) > 4 else ")"
        if self.driven_tried:
            where += f" and in {len(self.driven_runs)} of {self.driven_tried} runs under drive"
        guess = " (at the mains frequency: mains pickup on the reading?)" if self.mains else ""
        return (
            f"a {self.freq_hz:.1f} Hz component of {self.amplitude:.3g} {unit_label} in the reading, {where}: it "
            f"does not come from the drive{guess}"
        )


def quiet_stretches(t: np.ndarray, x: np.ndarray, fs: float) -> list[slice]:
    """Stretches where the drive is constant, from ``SETTLE_S`` after it last changed, at least ``QUIET_MIN_S`` long."""
    moving = np.abs(np.diff(x, prepend=x[0])) > 1e-9 * max(1.0, float(np.ptp(x)))
    moving[0] = True  # a run's start: the state before it is unknown
    settle = int(math.ceil(SETTLE_S * fs))
    need = int(math.ceil(QUIET_MIN_S * fs))
    starts = np.flatnonzero(moving)
    ends = np.append(starts[1:], x.size)
    begins = starts + 1 + settle  # each stretch from SETTLE_S after the drive's last change
    keep = ends - begins >= need
    return [slice(int(a), int(e)) for a, e in zip(begins[keep], ends[keep])]


def _spectrum(e: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """Amplitude spectrum (a sine of amplitude A reads A at its bin) of a detrended stretch."""
    n = e.size
    k = np.arange(n)
    e = e - np.polyval(np.polyfit(k, e, 1), k)  # a creep's or a drift's slope is no line
    w = np.hanning(n)
    amp = 2.0 * np.abs(np.fft.rfft(e * w)) / w.sum()
    return np.fft.rfftfreq(n, 1.0 / fs), amp


def _sine_amplitude(t: np.ndarray, e: np.ndarray, f: float) -> float:
    """Least-squares amplitude of a sine at ``f`` (with an offset and a slope) in ``e``."""
    a = np.column_stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t), np.ones_like(t), t - t.mean()])
    c, *_ = np.linalg.lstsq(a, e, rcond=None)
    return float(math.hypot(c[0], c[1]))


def _is_mains(f: float) -> bool:
    return any(abs(f - k * m) <= 0.01 * k * m for m in MAINS_HZ for k in range(1, 6))


def _peak_bins(amp: np.ndarray, idx: np.ndarray) -> list[int]:
    """The bins of ``idx`` (an ascending band of the amplitude spectrum ``amp``, its ends left out)
    that are local maxima :data:`PEAK_OVER_MEDIAN` times the band's median: a line."""
    med = float(np.median(amp[idx]))
    return [
        int(i) for i in idx[1:-1] if amp[i] > PEAK_OVER_MEDIAN * med and amp[i] >= amp[i - 1] and amp[i] >= amp[i + 1]
    ]


def drive_independent_lines(runs: Sequence[Run], *, min_hz: float = 5.0) -> list[Line]:
    """Lines in the residuals where the drive is constant, each checked in the runs that move
    (see the module). ``runs``: ``(t_s, drive, residual, fs_hz, name)``; lines below
    ``min_hz`` (a drift's, a creep's) are not looked for."""
    peaks: list[tuple[float, float, str, float]] = []  # freq, amplitude, run, resolution
    quiet_runs: dict[str, float] = {}  # run name -> its sample rate (which lines it can show)
    for t, x, e, fs, name in runs:
        for sl in quiet_stretches(np.asarray(t), np.asarray(x), fs):
            seg_t, seg_e = np.asarray(t, float)[sl], np.asarray(e, float)[sl]
            f, amp = _spectrum(seg_e, fs)
            if f.size < 16:
                continue
            quiet_runs[name] = float(fs)
            res = f[1]
            ok = (f >= max(min_hz, 4 * res)) & (f <= fs / 2.5)
            idx = np.flatnonzero(ok)
            if idx.size < 8:
                continue
            for i in _peak_bins(amp, idx):
                # the peak's frequency refined between its neighbours (a parabola through the bins)
                a0, a1, a2 = amp[i - 1], amp[i], amp[i + 1]
                den = a0 - 2 * a1 + a2
                shift = 0.5 * (a0 - a2) / den if den else 0.0
                fr = float(f[i] + shift * res)
                if seg_t[-1] - seg_t[0] >= 8 * DEMOD_BLOCK_S:
                    # refined again by demodulation: off by 0.04 Hz, a fit over two minutes turns
                    # by five periods and finds a tenth of the line
                    fr, a, b = fit_line(seg_t, seg_e, fr, fs)
                    peaks.append((fr, math.hypot(a, b), name, float(res)))
                else:
                    peaks.append((fr, _sine_amplitude(seg_t, seg_e, fr), name, float(res)))
    if not peaks:
        return []
    peaks.sort()
    groups: list[list[tuple[float, float, str, float]]] = [[peaks[0]]]
    for p in peaks[1:]:
        last = groups[-1][-1]
        if p[0] - last[0] <= 1.5 * max(p[3], last[3]):
            groups[-1].append(p)
        else:
            groups.append([p])
    lines = []
    for g in groups:
        names = sorted({p[2] for p in g})
        freq = float(np.median([p[0] for p in g]))
        amp = float(np.median([p[1] for p in g]))
        # seen in more than one quiet stretch (two runs, or one run's two stretches), or in the one quiet run
        # there is that can show it (a rest sampled at 100 Hz shows no 50 Hz line)
        if len(g) < 2 and sum(fs >= 2.5 * freq for fs in quiet_runs.values()) > 1:
            continue
        driven, tried = [], 0
        for t, x, e, fs, name in runs:
            t, x, e = np.asarray(t, float), np.asarray(x, float), np.asarray(e, float)
            if np.ptp(x) == 0 or fs < 2.5 * freq or t[-1] - t[0] < 20.0 / freq:
                continue
            tried += 1
            if 0.5 * amp <= _sine_amplitude(t, e, freq) <= 2.0 * amp:
                driven.append(name)
        if tried and len(driven) < 0.5 * tried:
            continue  # where the drive moves it is not there: the quiet stretches' own structure
        lines.append(Line(freq, amp, tuple(names), tuple(driven), tried, _is_mains(freq)))
    lines.sort(key=lambda line: -line.amplitude)
    return lines


#: A line's frequency is refined within this far of where it was found (Hz): the mains wander
#: by a few hundredths of a hertz, and a line fitted at a frequency off by ``df`` loses its phase
#: by ``2 pi df`` radians a second.
REFINE_SPAN_HZ = 0.1
#: Block length of the complex demodulation that refines a line (s): the baseband sampled at 20 Hz.
DEMOD_BLOCK_S = 0.05


def fit_line(t: np.ndarray, e: np.ndarray, f0: float, fs: float) -> tuple[float, float, float]:
    """A sine near ``f0`` in ``e`` (sampled at ``fs``): its frequency refined within
    :data:`REFINE_SPAN_HZ` and its sine and cosine amplitudes, ``(f, a, b)`` with the line
    ``a sin(2 pi f t) + b cos(2 pi f t)``, by least squares with an offset and a slope.

    The frequency is refined on the baseband: ``e`` demodulated at ``f0`` and averaged over
    blocks of :data:`DEMOD_BLOCK_S`, where a line at ``f0 + df`` turns at ``df``; the ``df``
    whose turning the blocks follow best is kept (one pass over the samples, then a search on
    a few thousand blocks).

    >>> fs = 1000.0
    >>> t = np.arange(0, 30, 1 / fs)
    >>> e = 0.4 * np.sin(2 * np.pi * 50.03 * t + 0.5) + np.random.default_rng(1).normal(0, 0.3, t.size)
    >>> f, a, b = fit_line(t, e, 50.0, fs)
    >>> round(f, 2), round(math.hypot(a, b), 2)
    (50.03, 0.4)
    """
    t, e = np.asarray(t, float), np.asarray(e, float)
    e = e - np.polyval(np.polyfit(t - t[0], e, 1), t - t[0])
    n = max(1, int(round(DEMOD_BLOCK_S * fs)))
    m = e.size // n
    f = f0
    if m >= 8:
        z = (e[: m * n] * np.exp(-2j * np.pi * f0 * t[: m * n])).reshape(m, n).mean(axis=1)
        tb = t[: m * n].reshape(m, n).mean(axis=1)
        span = min(REFINE_SPAN_HZ, 0.4 / DEMOD_BLOCK_S)
        step = 0.1 / max(float(tb[-1] - tb[0]), 1e-9)  # a tenth of the record's resolution
        grid = np.arange(-span, span + step / 2, step)
        power = np.abs(np.exp(-2j * np.pi * np.outer(grid, tb)) @ z)
        i = int(np.argmax(power))
        if 0 < i < grid.size - 1:  # a parabola through the peak and its neighbours
            p0, p1, p2 = power[i - 1 : i + 2]
            den = p0 - 2 * p1 + p2
            f = f0 + grid[i] + (0.5 * (p0 - p2) / den * step if den else 0.0)
        else:
            f = f0 + grid[i]
    a = np.column_stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t)])
    c, *_ = np.linalg.lstsq(a, e, rcond=None)
    return float(f), float(c[0]), float(c[1])


def line_of(t: np.ndarray, f: float, a: float, b: float) -> np.ndarray:
    """The line ``a sin(2 pi f t) + b cos(2 pi f t)`` at the times ``t``."""
    w = 2 * np.pi * f * np.asarray(t, float)
    return a * np.sin(w) + b * np.cos(w)


#: Half the width (Hz) of the notch :func:`notched` puts at each line: a hum whose size wanders
#: over tens of seconds (sidebands within a tenth of a hertz) is taken out whole.
NOTCH_HALF_HZ = 1.0


def notched(e: np.ndarray, freqs: Sequence[float], fs: float) -> np.ndarray:
    """``e`` (sampled at ``fs``) with a zero-phase notch of :data:`NOTCH_HALF_HZ` at each of
    ``freqs``; a frequency within 5 % of the Nyquist frequency, or a record too short for the
    filter's padding, is left as it is.

    >>> fs = 1000.0
    >>> t = np.arange(0, 2, 1 / fs)
    >>> e = np.sin(2 * np.pi * 50 * t) + np.sin(2 * np.pi * 7 * t)
    >>> out = notched(e, [50.0], fs)
    >>> bool(np.std((out - np.sin(2 * np.pi * 7 * t))[500:-500]) < 0.01)  # past the notch's ringing (0.3 s)
    True
    """
    out = np.asarray(e, float)
    for f in freqs:
        if not 0.0 < f < 0.45 * fs:
            continue
        b, a = signal.iirnotch(f, f / (2.0 * NOTCH_HALF_HZ), fs)
        if out.size <= 3 * max(a.size, b.size):
            continue
        out = signal.filtfilt(b, a, out)
    return out


#: Lines are looked for in a reading's noise from this frequency up (Hz): below it a slow sweep's
#: harmonics are lines of the drive (a 0.1 Hz triangle's 200th harmonic, 20 Hz, reads a
#: thousandth of a newton on a 300 N loop).
NOISE_LINES_FROM_HZ = 20.0
#: At most this many lines are taken out (the strongest): mains and its harmonics.
NOISE_MAX_LINES = 6


def noise_floor_without_lines(y: np.ndarray, fs: float) -> float:
    """:func:`piezopress.signals.noise_floor` of ``y`` (sampled at ``fs``) with the narrow lines
    above :data:`NOISE_LINES_FROM_HZ` notched out (:func:`notched`; a peak of the amplitude
    spectrum :data:`PEAK_OVER_MEDIAN` times its median there): a hum is no noise. Its sample-to-sample
    scatter reads as noise (a 1 N line at 50 Hz sampled at 500 Hz scatters 0.3 N), and a misfit
    of several newtons would pass for a few times that. The same as ``noise_floor`` without
    lines, and never below the reading's quantization.

    >>> fs = 500.0
    >>> t = np.arange(0, 30, 1 / fs)
    >>> noise = np.random.default_rng(0).normal(0.0, 0.05, t.size)
    >>> hum = np.sin(2 * np.pi * 50 * t) + 0.3 * np.sin(2 * np.pi * 150 * t)
    >>> plain = signals.noise_floor(noise)
    >>> round(signals.noise_floor(noise + hum) / plain), round(noise_floor_without_lines(noise + hum, fs) / plain, 1)
    (9, 1.0)
    >>> noise_floor_without_lines(noise, fs) == plain
    True
    """
    y = np.asarray(y, float)
    plain = signals.noise_floor(y)
    if y.size < 64 or fs / 2.5 <= NOISE_LINES_FROM_HZ:
        return plain
    f, amp = _spectrum(y, fs)
    idx = np.flatnonzero((f >= NOISE_LINES_FROM_HZ) & (f <= fs / 2.5))
    if idx.size < 8:
        return plain
    peaks = [(float(amp[i]), float(f[i])) for i in _peak_bins(amp, idx)]
    lines: list[float] = []
    for _, fr in sorted(peaks, reverse=True):
        if len(lines) < NOISE_MAX_LINES and all(abs(fr - g) > 2.0 * NOTCH_HALF_HZ for g in lines):
            lines.append(fr)
    if not lines:
        return plain
    return max(signals.noise_floor(notched(y, lines, fs)), signals.quantum(y) / math.sqrt(12.0), 1e-12)
