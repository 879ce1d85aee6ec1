"""Slow judging: residuals averaged over drive cycles, the long runs, and the drift fit (sensor drift and log creep)."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy import linalg

from piezopress import signals
from piezopress.analysis.diagnosis.judging import Context
from piezopress.analysis.diagnosis.model import Model, RunData, memo, run_starts
from piezopress.analysis.diagnosis.residuals import average_floor, rms

_FLOOR_MEMO: dict[tuple, tuple] = {}  # a run's floor of averages, by (id(run), samples averaged, its noise)


def _average_floor(ctx: Context, run: RunData, window_s: float) -> float:
    """The floor of ``run``'s averages over ``window_s`` (:func:`residuals.average_floor`: a
    reading coarser than its noise keeps an error its averages do not bring down), with the
    context's noise floor of the run; kept per run."""
    n, noise = window_s * run.fs_hz, ctx.floor[run.name]
    return memo(_FLOOR_MEMO, (id(run), n, noise), run, lambda: average_floor(run.y, n, noise))


def _pooled(floors: list[float], counts: list[int]) -> float:
    """Runs' floors of averages pooled as their residuals are (the RMS over the ``counts``
    averages judged in each run): what a perfect model's held-out RMS would read."""
    return math.sqrt(float(np.average(np.square(floors), weights=counts)))


def _slow_residual(run: RunData, v: np.ndarray, window_s: float, step_s: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """``v`` averaged over the trailing ``window_s`` (a drive cycle: the loop's shape and the
    noise average out), every ``step_s`` from ``window_s`` on: (times, averages)."""
    n = max(1, int(round(window_s * run.fs_hz)))
    c = np.concatenate([[0.0], np.cumsum(v)])
    idx = np.arange(n, v.size + 1, max(1, int(round(step_s * run.fs_hz))))
    return run.t_s[idx - 1], (c[idx] - c[idx - n]) / n


#: A drift may settle over this time constant (a warm-up) rather than go on steadily; it is
#: also the form of the drift a log creep is judged against when the runs evidence one.
DRIFT_WARMUP_TAU_S = 300.0
#: A drift that would move the reading by more than this share of its range over the longest
#: run is not a sensor's slow drift (the documented ones move a 300 N reading by about 1 N a
#: minute): such a fit leans on terms that cancel each other.
DRIFT_MAX_OF_RANGE = 0.2
#: Time constants of the slow creep element a drift is judged against (creep that the base
#: model's creep got wrong, in proportion to the drive, is not drift).
DRIFT_CREEP_TAUS_S = (10.0, 30.0, 100.0, 300.0, 1000.0)
#: The wander form's clock unit (s): the quadratic's columns are the clock in this unit and its
#: square, so that both are of order one over a session.
CLOCK_UNIT_S = 1000.0
#: The wander form is tried only where two runs at rest lie at least this far apart on the clock
#: (s): where the drive does nothing they pin the wander at both ends; between them the sweeps'
#: cycle-averaged misfit would otherwise shape the quadratic (the third test press, the default
#: plan's one rest, seed 3: the wander's rate read -3.2 N/min at the first run where the press
#: wandered +1 N/min, and the held-out ends 5 % worse than none, where one rate read them 61 % better).
CLOCK_REST_APART_S = 300.0
#: Share of each run the forms are fitted on when the wander form competes with the others (the
#: next share, up to the held-out end, chooses): held-out rows never choose the form.
CLOCK_CHOICE_SPLIT = 0.4


@dataclass(frozen=True)
class _DriftFit:
    """The drift against the slow creep element on the long runs' cycle-averaged residuals."""

    runs: list[RunData]
    baseline: float  # held-out RMS without the drift
    extended: float  # with it
    drift_per_s: float  # at a run's start ...
    drift_tau_s: float  # ... settling over this (inf: steady)
    creep_tau_s: float
    creep_gain: float
    floor: float
    # with ``tail_taus``: held-out RMS with a log-time creep tail beside the drift and the creep
    # element, and the tail's rate (fraction of the drive's static response per decade)
    with_tail: float | None = None
    tail_per_decade: float | None = None
    # the wander on the test's clock where it won (:attr:`Model.drift_clock`'s form), else None
    clock: tuple[tuple[float, float], tuple[tuple[str, float], ...]] | None = None

    @property
    def gain_pct(self) -> float:
        return 100.0 * (self.baseline - self.extended) / self.baseline if self.baseline > 0 else 0.0


def _long_runs(ctx: Context, steady: bool = False) -> list[tuple[RunData, float]]:
    """Runs long enough to show a trend, each with its averaging window (a drive cycle, or 5 s);
    with ``steady`` only those whose drive repeats (a rest, a hold, a sweep of one amplitude):
    averaged over a cycle, the base model's loop misfit is then the same in every cycle, and a
    trend stands out (on a sweep whose amplitude changes from cycle to cycle the averaged misfit
    changes with it)."""
    out = []
    for r in ctx.runs:
        f = r.freq_hz
        window = 1.0 / f if f and np.ptp(r.x) > 0 else 5.0
        if r.t_s[-1] < max(10.0, 2.5 * window):
            continue
        _, level = _slow_residual(r, r.x, window)
        _, swing = _slow_residual(r, np.abs(r.x - np.mean(r.x)), window)
        late = r.t_s[-1] > 2.0 * window  # the hold's step and the first cycle aside
        keep = slice(1, None) if late else slice(None)
        if not steady or np.ptp(level[keep]) + np.ptp(swing[keep]) <= 0.1 * max(float(np.ptp(r.x)), 1e-9):
            out.append((r, window))
    return out


def _slow_judge(ctx: Context, model: Model) -> tuple[float, float]:
    """Held-out RMS of ``model``'s cycle-averaged residual on the steady long runs (each with an
    offset fitted on its first 60 %, judged on the rest), and the noise floor of such averages."""
    held, floors = [], []
    for r, window in _long_runs(ctx, steady=True):
        t, res = _slow_residual(r, r.y - model.predict(r), window)
        fit_m = t <= 0.6 * r.t_s[-1]
        if fit_m.sum() < 2 or (~fit_m).sum() < 2:
            continue
        held.append(res[~fit_m] - res[fit_m].mean())
        floors.append(_average_floor(ctx, r, window))
    if not held:
        return float("nan"), float("nan")
    return rms(np.concatenate(held)), _pooled(floors, [h.size for h in held])


def _run_offsets(sizes: list[int]) -> np.ndarray:
    """The columns of an offset per run for runs of ``sizes`` samples stacked one after another."""
    return linalg.block_diag(*(np.ones((n, 1)) for n in sizes))


def _rests_apart(runs: list[RunData], clock: dict[str, float] | None) -> bool:
    """Whether two of ``runs`` at rest (a drive that does not move) start
    :data:`CLOCK_REST_APART_S` apart or more on ``clock``."""
    rests = sorted(clock[r.ident] for r in runs if clock and r.ident in clock and np.ptp(r.x) == 0)
    return len(rests) >= 2 and rests[-1] - rests[0] >= CLOCK_REST_APART_S


#: What tells a drift of the reading from creep, said where one slow cause could be the other and
#: the runs cannot tell them apart (:func:`wander_untold`).
TELL_DRIFT_FROM_CREEP = (
    "what would tell them apart: a rest before the first drive as well as one after the last, each run's start "
    "time recorded (a drift of the reading moves both rests, creep recovers only after the drive)"
)
#: The slow causes one held step and one rest cannot tell apart.
SLOW_RIVALS = frozenset({"logarithmic_creep", "sensor_offset_drift"})


def wander_untold(ctx: Context, causes: set[str]) -> bool:
    """Whether ``causes`` (a finding and what it could also be) are a drift of the reading and a
    creep that the runs cannot tell apart: no two rests far apart on the recorded clock
    (:func:`_rests_apart`: the wander form of :func:`_drift_fit` is not tried)."""
    long = [r for r, _ in _long_runs(ctx)]
    return SLOW_RIVALS <= causes and not _rests_apart(long, run_starts(ctx.runs))


def _drift_fit(
    ctx: Context, tail_taus: np.ndarray | None = None, clock: dict[str, float] | None = None
) -> _DriftFit | None:
    """See :func:`cause_sensor_offset_drift`. With ``tail_taus`` (a log creep's elements, equal
    gains per half decade: :func:`creep.log_taus`), the drift is fitted again with a log-time
    creep tail beside it (its rate free): a drift moves every run alike, a creep moves each run
    with its own drive, so across runs at other drive levels the two are told apart where one
    held step alone cannot tell them.

    With ``clock`` (each run's start on the test's clock, :func:`~piezopress.analysis.diagnosis.model.run_starts`;
    every long run must have one) and two rest runs :data:`CLOCK_REST_APART_S` apart or more (a rest
    before the first drive and one after the last, say), a wander competes too: the offset a
    quadratic in the clock, so its rate changes over the session (a thermal wander of minutes, rising
    in one run and falling in a later one, where one rate for every run fits neither). It has a parameter more than the
    other forms, so it is chosen on rows the fit does not see: every form fitted on each run's
    first :data:`CLOCK_CHOICE_SPLIT`, the one that predicts the rows from there to 60 % best is
    fitted on the first 60 % and judged on the rest, as the others are."""
    rows = []  # (run, t, slow residual, slow creep responses per tau (the tail's last), floor of the averages)
    for r, window in _long_runs(ctx):
        t, res = _slow_residual(r, r.y - ctx.pred(r), window)
        h = ctx.model.static(r)
        creeps = [_slow_residual(r, signals.first_order(h, tau, r.fs_hz), window)[1] for tau in DRIFT_CREEP_TAUS_S]
        if tail_taus is not None:
            tail = 0.5 * sum(signals.first_order(h, float(tau), r.fs_hz) for tau in tail_taus)
            creeps.append(_slow_residual(r, tail, window)[1])
        rows.append((r, t, res, creeps, _average_floor(ctx, r, window)))
    if not rows:
        return None
    n_runs = len(rows)
    fit_m = np.concatenate([t <= 0.6 * r.t_s[-1] for r, t, _, _, _ in rows])
    onehot = _run_offsets([t.size for _, t, _, _, _ in rows])
    T = np.concatenate([t for _, t, _, _, _ in rows])
    R = np.concatenate([res for _, _, res, _, _ in rows])
    if fit_m.sum() < n_runs + 3 or (~fit_m).sum() < 3:
        return None
    tail = np.concatenate([c[-1] for _, _, _, c, _ in rows]) if tail_taus is not None else None

    timed = clock is not None and all(r.ident in clock for r, *_ in rows) and _rests_apart([r for r, *_ in rows], clock)
    C = np.concatenate([clock[r.ident] + t for r, t, *_ in rows]) / CLOCK_UNIT_S if timed else None

    def solve(warmups, with_tail=False, fitted=fit_m, judged=~fit_m):
        best = None
        for j, tau in enumerate(DRIFT_CREEP_TAUS_S):
            S = np.concatenate([c[j] for _, _, _, c, _ in rows])
            for w in warmups:  # None: no drift; inf: a steady one; "clock": a wander; else it settles over w
                D = [] if w is None else [C, C**2] if w == "clock" else [T if np.isinf(w) else -w * np.expm1(-T / w)]
                A = np.column_stack([onehot, S] + D + ([tail] if with_tail else []))
                coef, *_ = np.linalg.lstsq(A[fitted], R[fitted], rcond=None)
                e = rms(R[fitted] - A[fitted] @ coef)
                if best is None or e < best[0]:
                    best = (e, tau, coef, rms(R[judged] - A[judged] @ coef), w)
        return best

    warmups = [math.inf, 1000.0, DRIFT_WARMUP_TAU_S]
    _, _, _, b, _ = solve([None])
    _, tau1, coef1, e, w = solve(warmups)
    wander = None
    if timed:
        first = np.concatenate([t <= CLOCK_CHOICE_SPLIT * r.t_s[-1] for r, t, *_ in rows])
        if first.sum() >= n_runs + 4 and (fit_m & ~first).sum() >= 3:
            choose = {"fitted": first, "judged": fit_m & ~first}
            if solve(["clock"], **choose)[3] < solve([w], **choose)[3]:
                _, tau1, coef1, e, w = solve(["clock"])
                a1, a2 = (float(x) for x in coef1[-2:])
                starts = tuple(sorted((ident, float(c)) for ident, c in clock.items()))  # every timed run
                wander = ((a1 / CLOCK_UNIT_S, a2 / CLOCK_UNIT_S**2), starts)
    with_tail = per_decade = None
    if tail is not None:
        _, _, coef2, with_tail, _ = solve(warmups, with_tail=True)
        per_decade = float(coef2[-1])
    if wander is not None:  # the fastest the wander moves over the long runs, and no settling
        (a1, a2), _ = wander
        at = [c for r, *_ in rows for c in (clock[r.ident], clock[r.ident] + r.t_s[-1])]
        rate = max((a1 + 2.0 * a2 * c for c in at), key=abs)
    return _DriftFit(
        [r for r, _, _, _, _ in rows],
        b,
        e,
        float(coef1[-1]) if wander is None else float(rate),
        w if wander is None else math.inf,
        tau1,
        float(coef1[n_runs]),
        _pooled([fl for *_, fl in rows], [int((t > 0.6 * r.t_s[-1]).sum()) for r, t, *_ in rows]),
        with_tail,
        per_decade,
        wander,
    )


#: A stroke kept at rest is read only where its creep moves the rest runs' cycle averages by at
#: least this many times their noise: on the virtual rig's clean rest (no such stroke) the fit
#: reads noise; on the third test press, clean, the kept stroke's creep moves the rest 0.47 N.
KEPT_STROKE_MIN_TO_FLOOR = 5.0


def _rest_creep_bias(ctx: Context, model: Model, most: float) -> float:
    """The stroke kept at rest whose creep from every run's start (:attr:`Model.creep_bias`,
    output unit) best predicts the first 60 % of the rest runs of 10 s or more (cycle-averaged
    over 5 s, an offset each, the rest held out as :func:`_slow_judge` judges them); 0 without
    such runs or creep, or where it would be more than ``most`` either way (a stroke the
    stack keeps is less than the stroke it is driven to), or where its creep moves the rest
    runs' averages by less than :data:`KEPT_STROKE_MIN_TO_FLOOR` times their noise (none is
    evidenced). Only the rest runs: where the drive does nothing, a rise is that stroke's creep
    or a drift of the reading."""
    if model.creep is None:
        return 0.0
    m0 = replace(model, creep_bias=0.0)
    R, C, fit_m, floors = [], [], [], []
    for r in (r for r in ctx.rests() if r.t_s[-1] >= 10.0):
        t, res = _slow_residual(r, r.y - m0.predict(r), 5.0)
        _, tr = _slow_residual(r, m0.creep_transient(r), 5.0)
        R.append(res)
        C.append(tr)
        fit_m.append(t <= 0.6 * r.t_s[-1])
        floors.append(_average_floor(ctx, r, 5.0))
    if not R:
        return 0.0
    fm = np.concatenate(fit_m)
    A = np.column_stack([_run_offsets([c.size for c in C]), np.concatenate(C)])[fm]
    if fm.sum() < len(R) + 2 or np.ptp(A[:, -1]) <= 0:
        return 0.0
    coef, *_ = np.linalg.lstsq(A, np.concatenate(R)[fm], rcond=None)
    b = float(coef[-1])
    moves = abs(b) * min(float(np.ptp(c)) for c in C)
    return b if abs(b) <= most and moves >= KEPT_STROKE_MIN_TO_FLOOR * max(floors) else 0.0
