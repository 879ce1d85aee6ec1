"""The catalogue's cause ``drive_coupled_interference``: its fit (the signature it keys on, the extension judged
on held-out data) and its entry in the catalogue (:data:`CAUSE`)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import numpy as np
from scipy import optimize

from piezopress import signals, units
from piezopress.analysis.diagnosis.cause import _FAST_STEPS, Cause
from piezopress.analysis.diagnosis.judging import (
    CHAIN_LAG_S,
    Context,
    Finding,
    _err,
    _fast_base,
    _fast_split,
    _forces,
    _judge_dynamics,
    _level_free_err,
    grid_then_refine,
    one_widening,
)
from piezopress.analysis.diagnosis.model import Model, RunData
from piezopress.analysis.diagnosis.needs import Need, RunSpec
from piezopress.analysis.diagnosis.residuals import rms

#: Time constants of the drive current's envelope tried for the interference (a rectified
#: current, smoothed by the sensor amplifier's input stage) ...
INTERFERENCE_TAUS_S = (0.1e-3, 0.25e-3, 0.5e-3, 1e-3, 2e-3, 4e-3)
#: ... and of the signed term, which follows the drive's own sign: ``first_order(dV/dt, tau)`` is
#: a first-order high-pass of the drive voltage with its corner at ``1 / (2 pi tau)``, ``tau``
#: times its gain. A current coupled straight into the amplifier passes it within the sensor's
#: bandwidth (up to :data:`SIGNED_TAU_MAX_S`); a voltage coupled capacitively into a lead is
#: high-passed by that capacitance and the input's resistance: a step of the drive then reads as
#: a step of the reading that decays over milliseconds. Capped at 0.5 ms, the third test press's
#: coupling through a 30 Hz high-pass (5.3 ms) beside an input delay was not named on 2 of 2
#: seeds. The grid stops at 8 ms (a 20 Hz corner): a corner lower still is a derivative over
#: most of the 5-100 Hz sweeps a coupling is judged on, and 16 ms took up a lead of the virtual
#: rig's sweeps once its slew limit was taken (23 % held out, its 100 V step 51 % worse; named
#: beside the slew on 1 of 5 seeds).
SIGNED_TAUS_S = (0.1e-3, 0.25e-3, 0.5e-3, 1e-3, 2e-3, 4e-3, 8e-3)
#: Below its corner a slow high-pass is a derivative of the drive, which is what a lag of the
#: output reads as (the residual of a reading late by ``dt`` is ``-dt dy/dt``): a signed term
#: smoothed over more than the sensor's own bandwidth is taken only where it leads the output,
#: as no lag does. One that lagged it was named on 3 of 5 clean seeds of the second test press
#: (16 ms, held-out sweeps 21-33 % better); a coupling of the other polarity through a slow
#: high-pass is then not told from a lag, and goes unnamed.
SIGNED_TAU_MAX_S = 0.5e-3


def _regress(
    fit, res: np.ndarray, drives: dict[int, np.ndarray], best: tuple, lead: float = 1.0, signed_taus=SIGNED_TAUS_S
) -> tuple:
    """The interference's gains fitted by least squares on the residual ``res`` of the fitting
    segments, for each envelope time constant and threshold and each signed term's time
    constant (of ``signed_taus``); ``best`` improved where one does better:
    ``(rms, (g, threshold, tau, g_signed, tau_signed) or None)``. ``lead``: the sign of the
    output's gain on the drive (+1: it rises with the drive); a signed term smoothed over more
    than :data:`SIGNED_TAU_MAX_S` must lead the output (``-g_signed * lead > 0``)."""
    signed = {
        tau_s: np.concatenate([signals.smoothed_rate(drives[id(r)], r.fs_hz, tau_s)[sl] for r, sl in fit])
        for tau_s in signed_taus
    }
    res_sq = float(res @ res)
    for tau in INTERFERENCE_TAUS_S:
        envs = [signals.rate_envelope(drives[id(r)], r.fs_hz, tau)[sl] for r, sl in fit]
        peak = max(float(e.max()) for e in envs)
        for frac in (0.0, 0.1, 0.2, 0.35, 0.5, 0.7):
            env = np.concatenate([np.maximum(e - frac * peak, 0.0) for e in envs])
            ee, er = float(env @ env), float(env @ res)
            for tau_s, sg in signed.items():
                # the least squares of res ~ -(g env + gs sg), by its 2x2 normal equations
                ss, es, sr = float(sg @ sg), float(env @ sg), float(sg @ res)
                det = ee * ss - es * es
                solvable = det > 1e-12 * ee * ss
                g, gs = ((-er * ss + sr * es) / det, (-sr * ee + er * es) / det) if solvable else (0.0, 0.0)
                if g < 0 or not solvable:  # the unsigned term is a dip: a negative gain is the signed term's job
                    g, gs = 0.0, (-sr / ss if ss > 0 else 0.0)
                if tau_s > SIGNED_TAU_MAX_S and -gs * lead <= 0:
                    continue  # below its corner it is a derivative that lags: a lag of the output
                # the residual left: |res + g env + gs sg|^2
                left = res_sq + g * g * ee + gs * gs * ss + 2 * (g * er + gs * sr + g * gs * es)
                e = math.sqrt(max(left, 0.0) / res.size)
                if e < best[0]:
                    best = (e, (float(g), frac * peak, tau, float(gs), tau_s))
    return best


#: The signed term's time constant is refined between its grid neighbours (a bounded search on its
#: logarithm) to within this factor of itself: a coupling's own filter lies anywhere. The second
#: test press's coupling follows the drive current through a 0.2 ms filter, between the grid's 0.1
#: and 0.25 ms; beside an input delay (seed 3) the grid's 0.1 ms left the pair a misfit that a rate
#: dependence (25 %) and a second mode at 7 kHz (21 %) took up, both named beside it.
SIGNED_TAU_REFINE_TOL = 0.02


def _refine_signed_tau(fit, res: np.ndarray, drives: dict[int, np.ndarray], best: tuple, lead: float) -> tuple:
    """``best`` (:func:`_regress`'s) with its signed term's time constant refined between the
    neighbours of :data:`SIGNED_TAUS_S` around it (all else fitted again at each), where that does
    better; ``best`` itself without a signed term."""
    if best[1] is None or not best[1][3]:
        return best
    grid = list(SIGNED_TAUS_S)
    i = grid.index(best[1][4])
    lo, hi = math.log(grid[max(i - 1, 0)]), math.log(grid[min(i + 1, len(grid) - 1)])
    seen: dict[float, tuple] = {}

    def cost(log_tau: float) -> float:  # finite where no term is allowed there (a slow one that lags)
        seen[log_tau] = _regress(fit, res, drives, (math.inf, None), lead, signed_taus=(math.exp(log_tau),))
        return min(seen[log_tau][0], 2.0 * best[0])

    optimize.minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": SIGNED_TAU_REFINE_TOL})
    return min([best, *seen.values()], key=lambda b: b[0])


def _delay_text(key: str, d: float) -> str:
    return f"{d:.3g} samples" if key == "delay_samples" else f"{d * 1e3:.3g} ms"


#: A held-out sweep counts as predicted worse by the interference when its held-out RMS grows by more
#: than this (%): a slow sweep whose current stays under a threshold is not changed by it, and reads
#: a few tenths of a percent either way (on the virtual rig, runs cut to the required metadata:
#: 0.0 to -0.5 % at 5 and 10 Hz refused the coupling on 5 of 5 seeds); a lag of the force read as a coupling
#: makes the slow sweeps 8-16 % worse (the third test press, clean).
SWEEP_WORSE_PCT = 5.0
#: A held-out step counts as predicted worse by the interference when its held-out RMS grows by
#: more than this (%). The drive current is largest in a step, and a coupling of it reads well
#: there: held-out steps 21-83 % better where one was hidden on the virtual rig (seeds 0-2) and the
#: second test press (seeds 0-2, and beside an input delay), 11 % worse on the third (seed 4: its
#: coupling is a 30 Hz high-pass of the drive voltage, the term's corner another). A drift of the
#: reading the base loop took up left the virtual rig's 50-100 Hz sweeps a misfit a signed term
#: of the drive rate fits, 26 % held out, with the 100 V step 61 % worse (offset drift, seed 7):
#: it was named beside the drift.
STEP_WORSE_PCT = 30.0
#: A delay found already is fitted again with the interference, from these fractions of itself
#: (found alone, it took up part of the artefact's lag: a coupling through a 0.2 ms filter,
#: delayed too), then refined around the best of them by a bounded scalar search to within
#: :data:`DELAY_REFIT_TOL` of itself. On the second test press a delay and a coupling together
#: fit best at 0.9 of the delay found alone; on the grid alone (0.75 or 1.0) the coupling gained
#: 18 % held out and went unnamed (8 of 19 seeds named both).
DELAY_REFIT_FRACTIONS = (0.5, 0.75, 1.0, 1.25)
DELAY_REFIT_TOL = 0.01


#: A held-out sweep on which the interference draws an artefact at least this share of the
#: residual it is judged against (and above the noise floor) must be predicted better, not merely
#: no more than :data:`SWEEP_WORSE_PCT` worse: a real artefact that large takes a visible part of
#: the residual away. On the third test press, beside a log creep, a mains line or a drifting
#: sensitivity, a coupling through an 8 ms high-pass took up the fast sweeps' misfit and was named
#: on the 4 seeds run, drawing a third of the 5 Hz triangle's residual and predicting that
#: triangle 3-4 % worse (log creep and mains, seed 0); its hidden couplings predict it 45-57 %
#: better (seeds 0 and 1).
ARTEFACT_VISIBLE_OF_RESIDUAL = 0.3


def _visible_on_sweeps(ctx: Context, held: list, without: Model, with_it: Model) -> dict[str, bool]:
    """For each held-out sweep: does the interference (``with_it`` less ``without``, which differ
    in it only) draw an artefact above the noise floor and :data:`ARTEFACT_VISIBLE_OF_RESIDUAL`
    of ``without``'s level-free residual there?"""
    sweeps = [(r, sl) for r, sl in held if r.kind != "step"]
    forces = _forces(without, [r for r, _ in sweeps])  # the force once: the two differ in the reading only
    out: dict[str, bool] = {}
    for r, sl in sweeps:
        reading = without.reading(r, forces[id(r)])
        artefact = rms((with_it.reading(r, forces[id(r)]) - reading)[sl])
        residual = rms(_level_free_err([(r, sl)], without, lambda _r, y=reading: y))
        out[r.name] = out.get(r.name, False) or (
            artefact >= ctx.floor[r.name] and artefact >= ARTEFACT_VISIBLE_OF_RESIDUAL * residual
        )
    return out


#: A coupling must predict the held-out runs this much better (percent) than the baseline with
#: its sweeps read with one time shift, either way, fitted on the fitting sweeps
#: (:func:`_shifted_sweeps`): on the sweeps a coupling through a fast high-pass is a derivative of
#: the drive, as is a lag of the model, and the chain identified on the steps may lag the sweeps.
#: On the third test press (seed 4, the run format's four fields) the model lagged its 5-100 Hz
#: sweeps by 70-90 us, and a coupling through a 1 ms high-pass took that up, 51 % held out (its
#: steps 65 % worse); the shift alone predicted the held-out sweeps as well (0.70 against 0.68 N).
#: Hidden couplings predicted the sweeps 25-75 % better than the shift (the three presses, seed 3:
#: 0.26, 0.58 and 0.75 of its RMS), and a coupling of the steps' current only (the virtual rig's
#: default, above half the current limit) leaves the sweeps to the baseline.
SHIFT_GATE_PCT = 10.0
#: A coupling must predict the held-out runs this much better (percent) than the baseline with one
#: widening of its loop at every fast rate (:func:`judging.one_widening`). On the third test press,
#: a rate dependence beside a log creep (seed 2, the thesis's runs alone, metadata cut): its rate
#: refused by its own gate, a coupling through a 0.5 ms filter that lags the output took up part of
#: the fast loops' width, 20 % held out, and was named; it predicted those runs 34 % worse than
#: one widening (3.12 N held out against 2.33 N). Hidden couplings (seeds 0-6) beat it by 56-78 %:
#: no widening helps there.
WIDENING_GATE_PCT = 10.0
#: The time shifts tried (s): a chain's lag misjudged by up to a few hundred microseconds.
SHIFTS_S = tuple(k * 1e-5 for k in range(-30, 31))  # 10 us apart, 0 exactly among them


def _shifted_sweeps(fit: list, held: list, base: Model) -> tuple[float, float, float, float] | None:
    """The time shift of ``base``'s reading of the sweeps (s; negative: the sweeps read earlier
    than the model) that best predicts the fitting sweeps' level-free residual, and the held-out
    runs' level-free RMS with it: all of them (the steps read by ``base`` as it is) and the sweeps
    alone, and the held-out sweeps' without it; None without sweeps both to fit and to judge."""
    fs_, hs_ = ([(r, sl) for r, sl in segs if r.kind != "step"] for segs in (fit, held))
    if not fs_ or not hs_:
        return None
    pred = {id(r): base.predict(r) for r, _ in fit + held}

    def shifted(s: float) -> Callable[[RunData], np.ndarray]:
        return lambda r: pred[id(r)] if r.kind == "step" else np.interp(r.t_s - s, r.t_s, pred[id(r)])

    s = min(SHIFTS_S, key=lambda s: rms(_level_free_err(fs_, base, shifted(s))))
    sweeps_at = (rms(_level_free_err(hs_, base, shifted(d))) for d in (s, 0.0))
    return s, rms(_level_free_err(held, base, shifted(s))), *sweeps_at


def cause_drive_coupled_interference(ctx: Context) -> Finding | None:
    runs = ctx.independent(ctx.steps() + ctx.sweeps(50.0))
    if len(runs) < 2:
        return None
    fit, held = _fast_split(ctx)
    base = _fast_base(ctx, fit)
    # the artefact is additive at the sensor, so linear in its gains: the signed drive current
    # (a coupling that follows the current's sign) and the unsigned current's envelope above a
    # threshold (a dip whatever the sign), each smoothed over tau, fitted together. The model
    # delays the whole reading, this artefact included: the drive it follows is read as delayed
    # (by the chain's own lag, or a delay found already, which is fitted again with it)
    # (a delay found counted in samples is another delay in time in each run)
    key = "delay_samples" if base.delay_samples > 0 else "delay_s"
    found_delay = key == "delay_samples" or ctx.model.delay_s > CHAIN_LAG_S
    own = getattr(base, key)
    forces = _forces(base, [r for r, _ in fit])  # a delay changes only the reading
    # the sign of the output's gain on the drive: a slow signed term must lead the output
    lead = float(np.sign(sum(float(np.dot(r.x - r.x.mean(), forces[id(r)] - forces[id(r)].mean())) for r, _ in fit)))

    def at(d: float) -> Model:
        return replace(base, **{key: d})

    res: dict[float, np.ndarray] = {}  # the fitting segments' residual with the delay at d
    tried: dict[float, tuple] = {}  # the interference fitted on it: (rms, parameters or None)
    drives_at: dict[float, dict[int, np.ndarray]] = {}  # the drive the artefact follows, as the model delays it

    def with_delay(f: float) -> float:
        d = own * f
        if d not in tried:
            m = at(d)
            res[d] = _err(fit, lambda r: m.reading(r, forces[id(r)]))
            drives_at[d] = {
                id(r): signals.delayed(m.stack_drive(r), r.fs_hz, m.reading_delay_s(r.fs_hz)) for r, _ in fit
            }
            tried[d] = _regress(fit, res[d], drives_at[d], (math.inf, None), lead or 1.0)
        return tried[d][0]

    with_delay(1.0)  # the delay as found
    if found_delay:
        grid_then_refine(with_delay, DELAY_REFIT_FRACTIONS, DELAY_REFIT_TOL)
    plain = min((rms(e), d) for d, e in res.items())  # the delay alone at its best: the baseline
    delay = min(tried, key=lambda d: tried[d][0])
    best = _refine_signed_tau(fit, res[delay], drives_at[delay], tried[delay], lead or 1.0)
    if best[1] is None or best[0] >= rms(res[own]):
        return None  # no interference predicts the fitting segments better than the delay as found
    g, e0, tau, gs, tau_s = best[1]
    ext = replace(at(delay), interference=(g, e0, tau, gs, tau_s))
    base = at(plain[1])
    u = ctx.model.unit
    parts = []
    if g:
        parts.append(
            f"dips {g * 1e3:.3g} {units.label(u)} per kV/s of drive rate above {e0 / 1e3:.3g} kV/s (envelope "
            f"{tau * 1e3:.3g} ms)"
        )
    if gs:
        parts.append(
            f"moves {-gs * 1e3:+.3g} {units.label(u)} per kV/s of the signed drive rate (the current's sign; "
            f"smoothed over {tau_s * 1e3:.3g} ms: a high-pass of the drive voltage at "
            f"{1 / (2 * math.pi * tau_s):.3g} Hz)"
        )
    ev = (
        f"while the drive current flows the reading {' and '.join(parts)}, at the sensor: "
        f"it does not ring with the mode, an artefact of the reading, not {units.quantity(u)}"
    )
    if found_delay:
        ev += (
            f" (the delay found fitted again with it: {_delay_text(key, delay)}, against "
            f"{_delay_text(key, plain[1])} fitted without it)"
        )
    found = _judge_dynamics(
        ctx,
        "drive_coupled_interference",
        ev,
        fit,
        held,
        ext,
        {
            f"gain_{units.key(u)}_per_v_per_s": g,
            "threshold_v_per_s": e0,
            "tau_s": tau,
            f"signed_gain_{units.key(u)}_per_v_per_s": gs,
            "signed_tau_s": tau_s,
        },
        base,
    )
    # the signature: an artefact of the drive current is in every sweep the current flows in. A
    # residual that grows with the sweep rate faster than the current (a lag of the force: creep
    # of milliseconds, the chain's dynamics) is taken up at the fast sweeps and over-corrected at
    # the slow ones (the third test press, clean: -8 to -16 % at 5 Hz, +63 % at 100 Hz; with a
    # coupling 30 to 46 % at every rate)
    sweeps = {r.name for r, _ in held if r.kind != "step"}
    worse_on = {name: gain for name, gain in found.gain_by_run.items() if name in sweeps and gain < 0.0}
    # whether the artefact is visible is simulated only where a held-out sweep is predicted worse
    visible = _visible_on_sweeps(ctx, held, at(delay), ext) if worse_on else {}
    worse = {n: g for n, g in worse_on.items() if g < -SWEEP_WORSE_PCT or visible.get(n, False)}
    shift = _shifted_sweeps(fit, held, base) if not worse and found.gain_pct > 0 else None
    if shift is not None and shift[0] != 0.0 and found.extended_rms > (1.0 - SHIFT_GATE_PCT / 100.0) * shift[1]:
        s, with_shift, sweeps_shifted, sweeps_as_is = shift
        u = units.label(ctx.model.unit)
        way = "earlier" if s < 0 else "later"
        # the lag is said only where the shift itself predicts the held-out sweeps better by the
        # gate (third test press, rate dependence found, seed 3: 1.69 N as they are, 1.68 N
        # shifted 10 us: no lag to speak of)
        lag = sweeps_shifted < (1.0 - SHIFT_GATE_PCT / 100.0) * sweeps_as_is
        why = (
            f"the force reads the sweeps {abs(s) * 1e6:.0f} us {way} than the model's chain, identified on the steps, "
            "draws. On the sweeps a coupling through a fast high-pass is a derivative of the drive, as is a lag, and "
            "the runs cannot tell them apart: the chain's lag on the sweeps is off, not the reading"
            if lag
            else f"neither changes the held-out sweeps much ({sweeps_as_is:.3g} {u} as they are, {sweeps_shifted:.3g} "
            f"{u} shifted {abs(s) * 1e6:.0f} us): what the coupling takes up is no artefact of the drive current"
        )
        return replace(
            found,
            refused=f"one time shift of the model's sweeps predicts the held-out runs as well ({with_shift:.3g} {u} "
            f"against {found.extended_rms:.3g} {u} with the coupling): {why}",
            refused_by_runs=True,
            signature=f"the fast sweeps read {abs(s) * 1e6:.0f} us {way} than the model's drive chain, identified "
            f"on the steps, draws (held-out sweeps {sweeps_as_is:.3g} {u} RMS, "
            f"{sweeps_shifted:.3g} {u} shifted): the chain's lag on the sweeps is off; no cause in the catalogue, "
            "and a coupling through a fast high-pass cannot be told from it there"
            if lag
            else "",
        )
    # and in the steps most of all, whose current is the largest: a term that a held-out step
    # reads worse took up a misfit of the sweeps (:data:`STEP_WORSE_PCT`; after the shift, which
    # says more where one time shift of the sweeps explains what it took up)
    steps = {r.name for r, _ in held if r.kind == "step"}
    worse.update({n: g for n, g in found.gain_by_run.items() if n in steps and g < -STEP_WORSE_PCT})
    if worse:
        found = replace(
            found,
            refused="an artefact of the drive current shows in every run the current flows in, and it predicts "
            + ", ".join(f"{n} {-g:.0f} % worse" for n, g in sorted(worse.items()))
            + (
                ": the residual grows with the sweep rate faster than the drive current (a lag of the force, creep "
                "of milliseconds or the chain's own dynamics, reads so)"
                if set(worse) - steps
                else ": a step, where the current is largest, is read worse; what it takes up on the sweeps is a "
                "misfit of the model there, not the current"
            ),
            refused_by_runs=True,
        )
        return found
    # and it is no widening of the loop: a coupling that lags the output (a signed term against
    # the output's gain) reads on a triangle as a loop drawn wider in proportion to the rate, and
    # takes up part of a loop drawn too narrow at every fast rate (a rate dependence its own gate
    # refused, a creep of milliseconds): it must predict the held-out runs better than one
    # widening of the loop at every fast rate does (:data:`WIDENING_GATE_PCT`); checked only where
    # it decides (a coupling that would be named: the widening is fitted, a model run per point)
    widened = one_widening(base, fit) if found.accepted else None
    if widened is not None:
        gate = _judge_dynamics(ctx, "drive_coupled_interference", "", fit, held, ext, {}, widened)
        if gate.gain_pct < WIDENING_GATE_PCT:
            u = units.label(ctx.model.unit)
            found = replace(
                found,
                refused=f"one widening of the loop at every fast rate predicts the held-out runs as well "
                f"({gate.baseline_rms:.3g} {u} against {gate.extended_rms:.3g} {u} with the coupling: "
                f"{gate.gain_pct:.0f} % better, under the {WIDENING_GATE_PCT:g} % an artefact of the drive current "
                "needs): what it takes up is the loop drawn too narrow at speed, not the current",
            )
    return found


#: The catalogue's entry for this cause (read by every place that names causes).
CAUSE = Cause(
    "drive_coupled_interference",
    "the drive current couples into the load-cell amplifier (the thesis's notch, Section 5.3)",
    "an additive artefact of the reading: the signed drive current, and its envelope above a threshold",
    cause_drive_coupled_interference,
    needs=(Need((_FAST_STEPS, RunSpec("sweep", min_freq_hz=50.0)), 2, independent=True),),
)
