"""Residual analysis: the sensor's noise floor and what a residual correlates with."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import signal, special

from piezopress import units
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


def steps_and_since(x: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where the drive ``x`` steps (a sample's move over 5 % of its range) and each sample's time
    since the last step (or the start)."""
    big = np.abs(np.diff(x, prepend=x[0])) > 0.05 * max(float(np.ptp(x)), 1e-9)
    return big, t - t[np.maximum.accumulate(np.where(big, np.arange(x.size), 0))]


def residual_stats(run: RunData, residual: np.ndarray, floor: float) -> ResidualStats:
    residual = judged(run, residual)
    r = residual - np.mean(residual)
    x = judged(run, run.x)
    t = judged(run, run.t_s)
    rate = np.gradient(x) * run.fs_hz
    _, since = steps_and_since(x, t)
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


# --------------------------------------------------------------------------- what unexplained structure looks like

#: A share of the residual's variance at least this large names the structure's signature.
SIGNATURE_MIN_SHARE = 0.5
#: A step's transient: the residual within this long after a step (s; a 1 kHz mode damped 3 %
#: rings out within 20 ms) ...
TRANSIENT_S = 0.02
#: ... holding at least :data:`SIGNATURE_MIN_SHARE` of its energy and this many times the share
#: of the run's time it takes.
TRANSIENT_CONCENTRATION = 2.0
#: A direction of the drive counts as a branch of the loop where the drive moves that way over at
#: least this share of the run (a step's edge is no branch: one column on a few points fits anything).
BRANCH_MIN_SHARE = 0.1
#: The residual and drive are averaged over blocks to at most this many points before the
#: signatures' regressions (the level's and branches' shapes are much slower than the samples).
SIGNATURE_POINTS = 20000

#: Each signature of a residual no cause explains: (key, what it says).
SIGNATURES = {
    "offset": "sits apart from the model by a constant (the model's level at that drive drawn wrong, or the "
    "reading's zero moved)",
    "level": "follows the drive's level (the static map drawn wrong there)",
    "loop": "follows the drive's level and direction (the loop's branches drawn wrong)",
    "transient": "sits in the first moments after each step (the step's transient: the chain's or a mode's dynamics)",
    "after_step": "settles in log time after each step or the run's start (creep or settling the model lacks)",
    "drive_line": "repeats at a frequency the drive holds, in a shape neither its level nor its direction "
    "draws (the loop's shape, a lag or a rate effect)",
    "line": "is a line the drive does not have",
    "slow": "moves slowly through the run, with no line, level, branch or step's settling to it",
    "none": "has no simple signature",
}


@dataclass(frozen=True)
class Structure:
    """Which signature a run's residual shows (:data:`SIGNATURES`), with the share of its
    variance each regression explains (the level, the level and direction, the settling after
    steps) and the line it holds (Hz, 0 without one)."""

    kind: str
    level: float
    loop: float
    after_step: float
    transient: float
    line_hz: float
    #: The residual's mean (the run's unit) and the share of its structure (its mean square less
    #: the noise floor's) that constant holds.
    offset: float = 0.0
    offset_share: float = 0.0

    @property
    def share(self) -> float | None:
        """The share of the structure (the energy, for a transient) its signature explains; else None."""
        return {
            "offset": self.offset_share,
            "level": self.level,
            "loop": self.loop,
            "after_step": self.after_step,
            "transient": self.transient,
        }.get(self.kind)

    def text(self, unit: str = "N") -> str:
        return _said(
            self.kind,
            [self.line_hz] if self.line_hz else [],
            [] if self.share is None else [self.share],
            [],
            [self.offset] if self.kind == "offset" else [],
            unit,
        )


def _blocks(a: np.ndarray, m: int) -> np.ndarray:
    n = a.size // m * m
    return a[:n].reshape(-1, m).mean(axis=1) if m > 1 else a


def _share(r: np.ndarray, cols: list[np.ndarray], noise: float = 0.0) -> float:
    """The share of ``r``'s structure (its variance about its mean, less ``noise`` squared: the
    noise is no structure) a least-squares fit on ``cols`` (and an offset) explains, in [0, 1]."""
    A = np.column_stack([np.ones_like(r), *cols])
    coef, *_ = np.linalg.lstsq(A, r, rcond=None)
    v = float(np.var(r)) - noise**2
    return min(1.0, max(0.0, (float(np.var(r)) - float(np.var(r - A @ coef))) / v)) if v > 0 else 0.0


def _fundamental(x: np.ndarray, fs: float) -> float:
    """The drive's strongest frequency (Hz; 0 where it does not move)."""
    if x.size < 8 or np.ptp(x) == 0:
        return 0.0
    f, p = signal.periodogram(x - np.mean(x), fs, window="hann")
    return float(f[int(np.argmax(p[1:])) + 1])


#: A line within a few bins of one of the drive's first this many harmonics is the drive's, whether
#: or not the drive holds it: a loop's nonlinearity makes them from the fundamental alone (the
#: Aye-Ang record's 1 Hz sine leaves a 2 Hz residual). Beyond them (a 37 Hz line on a 0.5 Hz
#: cosine is its 74th) only a line the drive holds is.
DRIVE_HARMONICS = 10


#: The drive holds a frequency where its spectrum there stands this many times over its median ...
DRIVE_LINE_OVER_MEDIAN = 1e3
#: ... and reaches this share of its peak (a triangle's 9th harmonic 1.5e-4, its 51st 1.5e-7; a
#: 16-bit command's floor about 1e-10; a cosine holds no harmonic, the Hann window's leak at 2 Hz
#: from a 5 Hz triangle's 7th harmonic is 1e-30).
DRIVE_LINE_OF_PEAK = 1e-8


def drive_holds(x: np.ndarray, fs: float, hz: float) -> bool:
    """Whether the drive ``x`` itself holds a line at ``hz`` (within a bin): its Hann-windowed
    periodogram there at least :data:`DRIVE_LINE_OVER_MEDIAN` times its median and
    :data:`DRIVE_LINE_OF_PEAK` of its peak."""
    if x.size < 8 or np.ptp(x) == 0 or not hz:
        return False
    f, p = signal.periodogram(x - np.mean(x), fs, window="hann")
    k = int(np.argmin(np.abs(f - hz)))
    near = float(p[max(k - 1, 0) : k + 2].max())
    return near > DRIVE_LINE_OVER_MEDIAN * float(np.median(p[1:])) and near >= DRIVE_LINE_OF_PEAK * float(p.max())


def structure_signature(run: RunData, residual: np.ndarray, stats: ResidualStats) -> Structure:
    """What a run's residual looks like where no cause explains it: the share of its structure
    (its variance less the noise floor's) that a cubic in the drive's level explains (a static map
    drawn wrong), the share of its energy within :data:`TRANSIENT_S` of a step where it gathers
    there (the step's transient: :data:`TRANSIENT_CONCENTRATION` times the share of time), the
    share the cubic on each branch of the drive's direction explains (a loop drawn wrong), the share a logarithm of
    the time since the last step (or the run's start) explains (creep or a settling), or its line
    (:attr:`ResidualStats.dominant_freq_hz`): one of the drive's first :data:`DRIVE_HARMONICS`
    harmonics or one it holds (:func:`drive_holds`), or not. Where nothing draws how it moves, the
    share of its mean square (less the noise floor's) its mean holds: a constant apart from the model
    (its level at that drive, or the reading's zero), said before a line of lesser energy.
    Decided from the drive and the residual, never from what the run's metadata says it is."""
    r0, x0, t0 = judged(run, residual), judged(run, run.x), judged(run, run.t_s)
    mean = float(np.mean(r0))
    structure = float(np.mean(np.square(r0))) - stats.floor**2  # the noise is no structure
    offset_share = min(1.0, mean**2 / structure) if structure > 0 else 0.0
    span = max(float(np.ptp(x0)), 1e-12)
    big, since0 = steps_and_since(x0, t0)
    near = big.any() & (since0 < TRANSIENT_S)
    e0 = np.square(r0 - np.mean(r0))
    transient = float(e0[near].sum() / e0.sum()) if near.any() and e0.sum() > 0 else 0.0
    if transient < TRANSIENT_CONCENTRATION * float(near.mean()):
        transient = 0.0  # spread over the run as evenly as over the steps' moments: no transient
    m = max(1, r0.size // SIGNATURE_POINTS)
    noise = stats.floor / math.sqrt(m)  # the noise left in averages of m samples
    r, x, since = _blocks(r0, m), _blocks(x0, m), _blocks(since0, m)
    u = (x - np.mean(x)) / span
    d = np.sign(np.gradient(x)) if x.size > 1 else np.zeros_like(x)
    level = [u, u**2, u**3]
    branches = min(float(np.mean(d > 0)), float(np.mean(d < 0))) >= BRANCH_MIN_SHARE
    moves = np.ptp(x0) > 0
    shares = {
        "level": _share(r, level, noise) if moves else 0.0,
        "loop": _share(r, level + [d, d * u, d * u**2], noise) if moves and branches else 0.0,
        "after_step": _share(r, [np.log1p(since * 1e3)], noise),
    }
    line = stats.dominant_freq_hz
    f0 = _fundamental(x0, run.fs_hz)
    k = round(line / f0) if line and f0 else 0
    bins = 3.0 / max(float(t0[-1] - t0[0]), 1e-9)
    harmonic = (1 <= k <= DRIVE_HARMONICS and abs(line - k * f0) <= bins) or drive_holds(x0, run.fs_hz, line)
    if shares["level"] >= SIGNATURE_MIN_SHARE:
        kind = "level"
    elif transient >= SIGNATURE_MIN_SHARE:
        kind = "transient"
    elif shares["loop"] >= SIGNATURE_MIN_SHARE:
        kind = "loop"
    elif shares["after_step"] >= SIGNATURE_MIN_SHARE:
        kind = "after_step"
    elif offset_share >= SIGNATURE_MIN_SHARE:  # nothing draws how it moves, and a constant holds most of it
        kind = "offset"
    elif line:
        kind = "drive_line" if harmonic else "line"
    else:
        kind = "slow" if stats.lag1_autocorr >= 0.8 else "none"
    return Structure(
        kind, shares["level"], shares["loop"], shares["after_step"], transient, float(line), mean, offset_share
    )


def unexplained_groups(entries: list[dict[str, Any]], ratio_key: str = "ratio") -> list[tuple[list[str], str]]:
    """The unexplained runs grouped by their signature (``entries``: each with ``run``,
    ``signature`` (a :data:`SIGNATURES` key), ``share`` (of the structure its signature explains,
    or None), ``line_hz``, ``offset_<unit>`` (its mean, for an offset) and the ratio to the noise
    floor), in the order first met: (the runs,
    what the signature says with the group's figures, "follows the drive's level (the static map
    drawn wrong there; 77-96 % of the structure, 90-259 x the noise)"). Entries without a
    signature (a diagnosis written before there were any) are left out."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for e in entries:
        if e.get("signature") in SIGNATURES:
            groups.setdefault(e["signature"], []).append(e)
    unit = next((k.removeprefix("rms_") for e in entries for k in e if k.startswith("rms_")), "n")
    return [
        (
            [e["run"] for e in es],
            _said(
                kind,
                [float(e["line_hz"]) for e in es if e.get("line_hz")],
                [float(e["share"]) for e in es if e.get("share") is not None],
                [float(e[ratio_key]) for e in es if e.get(ratio_key) is not None],
                [float(v) for e in es if (v := e.get(f"offset_{unit}")) is not None],
                units.label(unit),
            ),
        )
        for kind, es in groups.items()
    ]


def unexplained_text(entries: list[dict[str, Any]], ratio_key: str = "ratio") -> str:
    """:func:`unexplained_groups` in one sentence: "in A, B it follows the drive's level (...); in C it ..."."""
    return "; ".join(f"in {', '.join(runs)} it {said}" for runs, said in unexplained_groups(entries, ratio_key))


def _said(
    kind: str,
    lines: list[float],
    shares: list[float],
    ratios: list[float],
    offsets: Sequence[float] = (),
    unit: str = "N",
) -> str:
    """What a signature says (:data:`SIGNATURES`), its lines named, its offsets (in ``unit``) said,
    with the figures in its parentheses."""
    what = SIGNATURES[kind]
    if kind == "offset" and offsets:
        what = what.replace("by a constant", f"by a constant {_span(list(offsets), ' ' + unit, signed=True)}", 1)
    if kind == "transient":  # a ring within the transient's moments: a line slower than a cycle there is not its
        lines = [v for v in lines if v >= 1.0 / TRANSIENT_S]
    hz = " or ".join(sorted({f"{v:.0f}" if v >= 100 else f"{v:.3g}" for v in lines}, key=float))
    if kind == "line":
        what = f"is a line at {hz} Hz the drive does not have"
    elif kind == "transient" and hz:
        what = f"rings at {hz} Hz in the first moments after each step (a mode's or the chain's dynamics)"
    figs = ", ".join(
        f for f in (_span([100 * v for v in shares], " % of the structure"), _span(ratios, " x the noise")) if f
    )
    if not figs:
        return what
    return f"{what[:-1]}; {figs})" if what.endswith(")") else f"{what} ({figs})"


def _span(values: list[float], unit: str, signed: bool = False) -> str:
    """'a-b unit' (or 'a unit' for one value, '' for none), values as whole numbers where they are
    large; ``signed``: each with its sign, 'a to b unit' ("-6.1 to +2.0 N")."""
    if not values:
        return ""
    lo, hi = min(values), max(values)
    if signed:
        fmt = lambda v: f"{v:+.0f}" if abs(v) >= 10 else f"{v:+.2g}"  # noqa: E731 - each value as large as it is
        return f"{fmt(lo)}{unit}" if fmt(lo) == fmt(hi) else f"{fmt(lo)} to {fmt(hi)}{unit}"
    fmt = (lambda v: f"{v:.0f}") if lo >= 10 else (lambda v: f"{v:.2g}")
    return f"{fmt(lo)}{unit}" if fmt(lo) == fmt(hi) else f"{fmt(lo)}-{fmt(hi)}{unit}"
