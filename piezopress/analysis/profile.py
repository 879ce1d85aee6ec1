"""What a run is, measured from its signals: the one profile every stage asks.

A run from another program carries only the run format's required metadata (``kind``,
``name``, ``sample_rate_hz``, ``schema_version``), and its ``kind`` may be wrong or
``custom``. Every decision a stage makes about a run (which sweeps are quasi-static, which
runs are steps, at which level, how long a hold lasts) is taken from :class:`RunProfile`,
computed once per run from ``t_s``, the drive and the output; recorded metadata is only
checked against it (:func:`crosscheck`).

What is measured, and how:

- **The profiled signal** is the reference (``reference_n``) of a compensated run, whose
  drive is shaped by the compensator, else the commanded drive ``command_v``.
- **Plateaus**: runs of samples whose sample-to-sample change is below the signal's own
  resolution (a millionth of its span, or four times its noise). A signal mostly on
  plateaus is piecewise constant: two levels make a ``step`` (or a ``creep`` hold when the
  level is held for :data:`HOLD_MIN_S` or more), three or more a ``staircase``.
- **Reversals**: turning points where the signal turns back by more than a tenth of its
  span (a hysteresis band, so noise does not count). Regular half-periods (most within
  :data:`PERIOD_RTOL` of their median) make a sweep, at ``1 / (2 x half-period)``; a
  triangle if its slope is constant between reversals, else a sine. Irregular reversals make
  a ``random`` drive (run kind ``custom``).
- **Glitches**: isolated samples of the output that jump away from both neighbours by more
  than 5 % of the output's span (a sample read as 0 or as the ADC's top code, as DAQs do),
  and by more than :data:`GLITCH_MIN_STEPS` of a quantized reading's steps (one step either
  way is the noise of a reading coarser than its noise: a level held near a step's edge reads
  on both codes), on an output smooth beside them and away from a drive's edge (a mode
  ringing after a step is the press, not a fault); :func:`without_glitches` replaces each with
  the mean of its neighbours.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from piezopress import signals

#: Sweeps at up to this measured frequency are quasi-static (hysteresis is fitted on them).
QUASI_STATIC_MAX_HZ = 0.5
#: How closely a measured frequency is compared with a bound (a sweep of a few cycles is
#: measured to about a sample of its half-period): 0.5 Hz measured as 0.503 Hz is 0.5 Hz.
FREQ_RTOL = 0.02
#: A level held at least this long is a creep hold, shorter a step.
HOLD_MIN_S = 5.0
#: A reversal counts when the signal turns back by more than this share of its span.
REVERSAL_BAND = 0.10
#: Half-periods within this relative distance of their median are regular (a sweep).
PERIOD_RTOL = 0.05
#: Share of regular half-periods that makes a sweep.
REGULAR_SHARE = 0.75
#: Share of samples on plateaus that makes a piecewise-constant drive.
PLATEAU_SHARE = 0.6
#: A glitch jumps away from both neighbours by more than this share of the output's span.
GLITCH_SPAN_SHARE = 0.05
#: ... and by more than this many of a quantized reading's steps (:func:`piezopress.signals.quantum`).
#: The virtual rig's 12-bit input reads 0.49 N steps with 0.07 N of noise: a rest whose level sits
#: near a step's edge flickers to the next code on single samples, and each flicker jumped more
#: than 5 % of the rest's span (one step): up to 1,883 of a 120 s rest's 12,001 samples were
#: "repaired", its mean pulled onto one code, and a level rising a fraction of a step read still.
GLITCH_MIN_STEPS = 1.5
#: No glitch is taken at a drive's edge: within this many samples after the drive jumps (the
#: third test press's 1 kHz step runs ring at their edge; 18-140 N samples there were "repaired").
GLITCH_EDGE_SAMPLES = 3
#: Relative disagreement between a recorded and a measured frequency or level that is reported.
METADATA_RTOL = 0.05

#: What the signal is -> the run-format kind it is recorded as.
SHAPES = ("rest", "step", "hold", "staircase", "sweep", "random")


@dataclass(frozen=True)
class RunProfile:
    """A run's shape measured from its signals (see the module's text for how).

    ``kind`` is the run-format kind the signals say the run is (``triangle``, ``sine``,
    ``step``, ``creep``, ``staircase`` or ``custom``); ``shape`` the finer class (``rest``,
    ``step``, ``hold``, ``staircase``, ``sweep``, ``random``). Levels, amplitude and peaks are
    in the profiled signal's unit (V for a drive, N for a reference force).
    """

    shape: str
    kind: str
    signal: str
    sample_rate_hz: float
    t0_s: float
    duration_s: float
    low: float
    high: float
    freq_hz: float | None = None
    amplitude: float | None = None
    peaks: tuple[float, ...] = ()
    varying_amplitude: bool = False
    base: float | None = None
    level: float | None = None
    step_time_s: float | None = None
    hold_s: float | None = None
    levels: tuple[float, ...] = ()
    glitches: tuple[int, ...] = field(default=())
    #: Share of the output's samples pinned at one extreme value (a saturated sensor or ADC), and which.
    saturated: float = 0.0
    saturated_at: float | None = None

    @property
    def quasi_static(self) -> bool:
        """A sweep at a measured frequency of at most :data:`QUASI_STATIC_MAX_HZ`."""
        return (
            self.shape == "sweep" and self.freq_hz is not None and freq_within(self.freq_hz, 0.0, QUASI_STATIC_MAX_HZ)
        )

    @property
    def is_sweep(self) -> bool:
        return self.shape == "sweep"

    @property
    def step_size(self) -> float | None:
        """The step's height (level minus base) of a step or hold."""
        return None if self.level is None or self.base is None else self.level - self.base

    def describe(self) -> str:
        """One line for a person: what the run is."""
        if self.shape == "sweep":
            amp = f", {2 * self.amplitude:.4g} peak to peak" if self.amplitude is not None else ""
            vary = " (varying amplitude)" if self.varying_amplitude else ""
            return f"{self.kind} sweep at {self.freq_hz:.4g} Hz{amp}{vary}"
        if self.shape in ("step", "hold"):
            return (
                f"{'creep hold' if self.shape == 'hold' else 'step'} from {self.base:.4g} to {self.level:.4g} "
                f"at {self.step_time_s:.4g} s, held {self.hold_s:.4g} s"
            )
        if self.shape == "staircase":
            return f"staircase of {len(self.levels)} levels, {self.low:.4g} to {self.high:.4g}"
        if self.shape == "rest":
            return f"rest at {self.low:.4g}"
        return f"random drive, {self.low:.4g} to {self.high:.4g}"

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["glitches"] = len(self.glitches)
        d["quasi_static"] = self.quasi_static
        return d


# --------------------------------------------------------------------------- primitives


def freq_within(f: float, lo_hz: float, hi_hz: float) -> bool:
    """A measured frequency within ``[lo_hz, hi_hz]``, to :data:`FREQ_RTOL`."""
    return lo_hz * (1.0 - FREQ_RTOL) <= f <= hi_hz * (1.0 + FREQ_RTOL)


#: Without a sweep at up to QUASI_STATIC_MAX_HZ, the slowest sweeps count as quasi-static if
#: they are at most this fast (a record measured elsewhere often has one 1 Hz sine: a stack's
#: hysteresis changes by a few tenths of a percent per decade of rate).
SLOWEST_SWEEP_MAX_HZ = 2.0


def slow_limit_hz(freqs) -> float:
    """Up to which frequency sweeps are quasi-static among sweeps at ``freqs``:
    :data:`QUASI_STATIC_MAX_HZ`, or where none is that slow, the slowest ones (within 10 %)
    up to :data:`SLOWEST_SWEEP_MAX_HZ`."""
    freqs = [float(f) for f in freqs]
    if not freqs or any(freq_within(f, 0.0, QUASI_STATIC_MAX_HZ) for f in freqs):
        return QUASI_STATIC_MAX_HZ
    slowest = min(freqs)
    return 1.1 * slowest if slowest <= SLOWEST_SWEEP_MAX_HZ else QUASI_STATIC_MAX_HZ


def measured_sample_rate(t_s: np.ndarray) -> float:
    """The sample rate measured from the time axis (mean step)."""
    t = np.asarray(t_s, float)
    return (t.size - 1) / float(t[-1] - t[0]) if t.size > 1 and t[-1] > t[0] else float("nan")


def _noise_sigma(x: np.ndarray) -> float:
    """Robust noise level from second differences (zero for a noise-free drive)."""
    if x.size < 4:
        return 0.0
    d2 = np.diff(x, 2)
    return float(np.median(np.abs(d2)) / 0.6745 / np.sqrt(6.0))


def plateaus(x: np.ndarray, tol: float, min_len: int) -> list[tuple[int, int, float]]:
    """Runs of at least ``min_len`` samples whose neighbours differ by at most ``tol``:
    ``(start, stop, level)`` with ``stop`` excluded and ``level`` the run's median."""
    x = np.asarray(x, float)
    if x.size < 2:
        return [(0, x.size, float(x[0]))] if x.size else []
    flat = np.abs(np.diff(x)) <= tol
    # sample i is on a plateau with i+1 when flat[i]; group consecutive flat steps
    edges = np.diff(np.concatenate(([0], flat.astype(np.int8), [0])))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    out = []
    for a, b in zip(starts, stops):  # steps a..b-1 are flat: samples a..b
        if b + 1 - a >= min_len:
            out.append((int(a), int(b + 1), float(np.median(x[a : b + 1]))))
    return out


def turning_points(x: np.ndarray, band: float) -> np.ndarray:
    """Indices where ``x`` reverses by more than ``band`` (alternating maxima and minima).

    The run's first and last samples count as turning points when they lie at an extreme
    (within ``band``) of the stretch next to them, so a single triangle 0 -> peak -> 0 has
    two half-periods.
    """
    x = np.asarray(x, float)
    n = x.size
    if n < 3 or band <= 0:
        return np.zeros(0, int)
    # candidates: local extrema of the non-flat sequence (vectorised), then the band in Python
    dx = np.diff(x)
    nz = np.flatnonzero(dx != 0)
    if nz.size < 2:
        return np.zeros(0, int)
    s = np.sign(dx[nz])
    change = np.flatnonzero(s[1:] != s[:-1])
    cand = np.concatenate(([0], nz[change] + 1, [n - 1]))
    tps: list[int] = []
    direction = 0  # +1 looking for a maximum, -1 for a minimum; 0 until the first move of a band
    i_max = i_min = int(cand[0])
    ext = i_max
    for i in cand[1:]:
        i = int(i)
        if direction == 0:
            if x[i] > x[i_max]:
                i_max = i
            if x[i] < x[i_min]:
                i_min = i
            if x[i_max] - x[i_min] > band:
                if i_min < i_max:
                    tps.append(i_min)
                    direction, ext = 1, i_max
                else:
                    tps.append(i_max)
                    direction, ext = -1, i_min
            continue
        if direction == 1:
            if x[i] >= x[ext]:
                ext = i
            elif x[ext] - x[i] > band:
                tps.append(ext)
                direction, ext = -1, i
        else:
            if x[i] <= x[ext]:
                ext = i
            elif x[i] - x[ext] > band:
                tps.append(ext)
                direction, ext = 1, i
    if direction != 0:
        tps.append(ext)
    tp = np.asarray(tps, int)
    if tp.size == 0:
        return tp
    # the ends: a turning point there counts only at an extreme (within the band) of the
    # signal beyond it; a rest before a sweep, a sweep entered or left mid-swing, is no half-period
    lo, hi = float(np.min(x)), float(np.max(x))

    def at_extreme(k: int) -> bool:
        return abs(x[k] - lo) <= band or abs(x[k] - hi) <= band

    while tp.size and not at_extreme(int(tp[0])):
        tp = tp[1:]
    while tp.size and not at_extreme(int(tp[-1])):
        tp = tp[:-1]
    return tp


def find_glitches(y: np.ndarray, x: np.ndarray | None = None) -> np.ndarray:
    """Indices of isolated samples that jump away from both neighbours (see the module text).

    A lost or saturated reading is a fault of one sample on a smooth record. The press's own
    motion is never one: a sample is not taken where the output on either side of it (the
    samples beside it, not it) bends by half its jump or more (a mode ringing, aliased at a
    slow sample rate, alternates from sample to sample), nor, given the drive ``x``, within
    :data:`GLITCH_EDGE_SAMPLES` of a drive jump of more than :data:`GLITCH_SPAN_SHARE` of its
    span (the output's first samples after a step's edge are the press's response)."""
    y = np.asarray(y, float)
    if y.size < 5:
        return np.zeros(0, int)
    span = float(np.percentile(y, 99.5) - np.percentile(y, 0.5))
    if span <= 0:
        span = float(np.ptp(y))
    thr = max(GLITCH_SPAN_SHARE * span, 8.0 * _noise_sigma(y), GLITCH_MIN_STEPS * signals.quantum(y))
    if thr <= 0:
        return np.zeros(0, int)
    mid = y[1:-1]
    d1, d2 = mid - y[:-2], mid - y[2:]
    neighbours = np.abs(y[2:] - y[:-2])
    jump = np.minimum(np.abs(d1), np.abs(d2))
    hit = (np.sign(d1) == np.sign(d2)) & (jump > thr) & (neighbours < 0.5 * jump)
    k = np.flatnonzero(hit) + 1
    if not k.size:
        return k
    # the bend of the output beside each candidate, from samples that leave it out
    bend = np.abs(np.diff(y, 2))  # bend[j] is centred on sample j + 1
    n = y.size
    beside = np.zeros(k.size)
    for off in (-3, -2, 2, 3):
        c = k + off - 1
        ok = (c >= 0) & (c < bend.size)
        beside[ok] = np.maximum(beside[ok], bend[c[ok]])
    keep = beside < 0.5 * jump[k - 1]
    if x is not None and np.shape(x) == (n,):
        x = np.asarray(x, float)
        dx = np.abs(np.diff(x, prepend=x[0]))
        edge = dx > GLITCH_SPAN_SHARE * max(float(np.ptp(x)), 1e-300)
        near = np.convolve(edge.astype(float), np.ones(GLITCH_EDGE_SAMPLES + 1), mode="full")[:n] > 0
        keep &= ~near[k]
    return k[keep]


#: An output that repeats its extreme value exactly on more than this share of its samples is
#: taken as saturated (a sensor or ADC at its limit; a noisy measurement reaches its extreme once).
SATURATED_MIN_SHARE = 0.02


#: ... and the drive, over those samples, spans more than this share of its range (a held level
#: read on one code of a quantised sensor, or a compensated hold, spans a few %).
SATURATED_DRIVE_SHARE = 0.1


def saturation(y: np.ndarray, x: np.ndarray | None = None) -> tuple[float, float | None]:
    """``(share, value)``: the share of ``y``'s samples exactly at its maximum or minimum, the
    larger of the two, when the reading is pinned there: on more than :data:`SATURATED_MIN_SHARE`
    of the samples while the drive ``x`` spans more than :data:`SATURATED_DRIVE_SHARE` of its
    range (a sensor or ADC at its limit while the press is driven on); else ``(0.0, None)``."""
    y = np.asarray(y, float)
    ok = np.isfinite(y)
    if y.size < 10 or not ok.any() or np.ptp(y[ok]) == 0:
        return 0.0, None
    x = np.asarray(x, float) if x is not None and np.asarray(x).shape == y.shape else None
    best: tuple[float, float | None] = (0.0, None)
    for v in (float(np.max(y[ok])), float(np.min(y[ok]))):
        at = y == v
        share = float(np.count_nonzero(at)) / y.size
        if share <= max(SATURATED_MIN_SHARE, best[0]):
            continue
        lo_x, hi_x = np.percentile(x[at], [5, 95]) if x is not None else (0.0, np.inf)
        if x is not None and hi_x - lo_x <= SATURATED_DRIVE_SHARE * max(float(np.ptp(x)), 1e-12):
            continue
        best = (share, v)
    return best


def without_glitches(y: np.ndarray, glitches: np.ndarray) -> np.ndarray:
    """A copy of ``y`` with each glitched sample replaced by the mean of its neighbours."""
    out = np.array(y, float, copy=True)
    g = np.asarray(glitches, int)
    g = g[(g > 0) & (g < out.size - 1)]
    out[g] = 0.5 * (out[g - 1] + out[g + 1])
    return out


# --------------------------------------------------------------------------- the profile


def _sweep_shape(x: np.ndarray, tp: np.ndarray) -> str:
    """``triangle`` when the drive is straight between reversals (RMS distance from the
    straight line below 3 % of the swing; a half sine's is 8 %), else ``sine``. Robust to a
    quantized drive, whose sample-to-sample slope jumps between codes."""
    dev = []
    for a, b in zip(tp[:-1], tp[1:]):
        seg = x[a : b + 1]
        if seg.size >= 8:
            line = np.linspace(seg[0], seg[-1], seg.size)
            dev.append(float(np.sqrt(np.mean((seg - line) ** 2))) / max(abs(seg[-1] - seg[0]), 1e-300))
    return "triangle" if not dev or float(np.median(dev)) < 0.03 else "sine"


def profile_signals(
    t_s: np.ndarray, x: np.ndarray, output: np.ndarray | None = None, *, signal: str = "command_v"
) -> RunProfile:
    """The profile of a run from its time axis, its drive (or reference) ``x`` and its output."""
    t = np.asarray(t_s, float)
    x = np.asarray(x, float)
    fs = measured_sample_rate(t)
    t0 = float(t[0]) if t.size else 0.0
    duration = float(t[-1] - t[0]) + (1.0 / fs if np.isfinite(fs) else 0.0) if t.size else 0.0
    glitches = tuple(int(i) for i in find_glitches(output, x)) if output is not None else ()
    lo, hi = (float(np.min(x)), float(np.max(x))) if x.size else (0.0, 0.0)
    span = hi - lo
    sat, sat_at = saturation(output, x) if output is not None else (0.0, None)
    common = dict(
        signal=signal,
        sample_rate_hz=fs,
        t0_s=t0,
        duration_s=duration,
        low=lo,
        high=hi,
        glitches=glitches,
        saturated=sat,
        saturated_at=sat_at,
    )
    if x.size < 3 or span <= max(1e-3, 1e-9 * max(abs(lo), abs(hi))):
        return RunProfile("rest", "custom", level=lo, base=lo, **common)
    tol = max(1e-6 * span, 4.0 * _noise_sigma(x))
    min_len = max(3, int(round(1e-3 * fs)) if np.isfinite(fs) else 3)
    plats = plateaus(x, tol, min_len)
    if len(plats) > 2 and np.median(np.abs(np.diff([v for _, _, v in plats]))) < 0.02 * span:
        plats = []  # plateaus a quantum apart: a quantized continuous drive (a DAC's codes), not a staircase
    on = sum(b - a for a, b, _ in plats)
    if plats and on >= PLATEAU_SHARE * x.size:
        return _piecewise(t, x, plats, span, common)
    tp = turning_points(x, REVERSAL_BAND * span)
    if tp.size >= 3 or (tp.size == 2 and tp[0] <= 1):
        half = np.diff(t[tp])
        med = float(np.median(half))
        regular = np.abs(half - med) <= PERIOD_RTOL * med
        if med > 0 and np.mean(regular) >= REGULAR_SHARE:
            # the mean half-period over the regular stretch: exact to a sample over the whole sweep
            idx = np.flatnonzero(regular)
            freq = 1.0 / (2.0 * float(np.mean(half[idx])))
            swings = np.abs(np.diff(x[tp]))
            ups = x[tp][x[tp] > 0.5 * (lo + hi)]
            peaks = tuple(float(v) for v in ups)
            vary = bool(ups.size > 1 and np.ptp(ups) > 0.05 * span)
            return RunProfile(
                "sweep",
                _sweep_shape(x, tp),
                freq_hz=freq,
                amplitude=float(np.median(swings)) / 2.0,
                peaks=peaks,
                varying_amplitude=vary,
                **common,
            )
    if plats and on >= 0.3 * x.size and tp.size < 3:
        return _piecewise(t, x, plats, span, common)
    return RunProfile("random", "custom", **common)


def _piecewise(
    t: np.ndarray, x: np.ndarray, plats: list[tuple[int, int, float]], span: float, common: dict
) -> RunProfile:
    """A drive mostly on plateaus: a step, a creep hold or a staircase."""
    # merge plateaus at the same level (within 2 % of the span)
    levels: list[float] = []
    for _, _, v in plats:
        if not any(abs(v - u) <= 0.02 * span for u in levels):
            levels.append(v)
    base = plats[0][2]
    if len(levels) <= 2:
        others = [p for p in plats if abs(p[2] - base) > 0.02 * span]
        if not others:  # one plateau level and moves elsewhere: a ramp to a level held
            return RunProfile("random", "custom", **common)
        held = max(others, key=lambda p: p[1] - p[0])
        level = held[2]
        first = others[0]
        step_time = float(t[first[0]] - t[0]) if first[0] > 0 else 0.0
        hold = float(t[held[1] - 1] - t[held[0]])
        shape = "hold" if hold >= HOLD_MIN_S else "step"
        return RunProfile(
            shape,
            "creep" if shape == "hold" else "step",
            base=base,
            level=level,
            step_time_s=step_time,
            hold_s=hold,
            levels=tuple(sorted(levels)),
            **common,
        )
    return RunProfile("staircase", "staircase", base=base, levels=tuple(levels), **common)


def profile_run(run: Any) -> RunProfile:
    """The profile of a :class:`piezopress.runformat.Run` (its reference when it has one)."""
    ref = run.column("reference_n")
    if ref is not None and np.ptp(ref) > 0:
        return profile_signals(run.t_s, ref, run.output, signal="reference_n")
    return profile_signals(run.t_s, run.command_v, run.output)


def of(run: Any) -> RunProfile:
    """The run's profile: the one its reader attached, else measured now."""
    p = getattr(run, "profile", None)
    return p if p is not None else profile_run(run)


# --------------------------------------------------------------------------- metadata cross-check

#: Recorded kinds each measured kind agrees with (a sweep recorded as triangle or sine is one).
_AGREEING_KINDS = {
    "triangle": {"triangle", "sine"},
    "sine": {"triangle", "sine"},
    "step": {"step"},
    "creep": {"creep"},
    "staircase": {"staircase"},
    "custom": {"custom"},
}


def _number(v: Any) -> float | None:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    return float(v) if np.isfinite(v) else None


def crosscheck(meta: Mapping[str, Any], prof: RunProfile, label: str) -> list[str]:
    """Where the recorded metadata disagrees with the measured profile: one line each,
    naming the run, the recorded value and the measured one (empty when they agree)."""
    out: list[str] = []
    kind = meta.get("kind")
    if isinstance(kind, str) and kind not in _AGREEING_KINDS.get(prof.kind, {prof.kind}):
        out.append(f"{label}: recorded kind {kind!r}, but the signals show a {prof.describe()} (kind {prof.kind!r})")
    p = meta.get("protocol")
    p = p if isinstance(p, Mapping) else {}
    f = _number(p.get("freq_hz"))
    if (
        f is not None
        and prof.shape == "sweep"
        and prof.freq_hz is not None
        and abs(prof.freq_hz - f) > METADATA_RTOL * f
    ):
        out.append(f"{label}: recorded sweep frequency {f:g} Hz, measured {prof.freq_hz:.4g} Hz")
    lv = _number(p.get("level_v"))
    if (
        lv is not None
        and prof.signal == "command_v"
        and prof.level is not None
        and abs(prof.level - lv) > METADATA_RTOL * max(abs(lv), 1e-9)
    ):
        out.append(f"{label}: recorded step level {lv:g} V, measured {prof.level:.4g} V")
    fs = _number(meta.get("sample_rate_hz"))
    if fs is not None and np.isfinite(prof.sample_rate_hz) and abs(prof.sample_rate_hz - fs) > 1e-3 * fs:
        out.append(f"{label}: recorded sample_rate_hz {fs:g}, t_s is sampled at {prof.sample_rate_hz:.6g} Hz")
    return out


def measured_kind(meta: Mapping[str, Any], prof: RunProfile, trust_metadata: bool = False) -> str:
    """The kind a stage uses: the measured one unless it agrees with the record (then the
    record's, so a sine stays a sine) or the record is trusted."""
    kind = meta.get("kind")
    if trust_metadata and isinstance(kind, str):
        return kind
    if isinstance(kind, str) and kind in _AGREEING_KINDS.get(prof.kind, {prof.kind}):
        return kind
    return prof.kind
