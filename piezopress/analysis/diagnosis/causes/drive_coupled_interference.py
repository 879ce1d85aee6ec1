"""The catalogue's cause ``drive_coupled_interference``: its fit (the signature it keys on, the extension judged
on held-out data) and its entry in the catalogue (:data:`CAUSE`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

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
)
from piezopress.analysis.diagnosis.model import Model
from piezopress.analysis.diagnosis.needs import Need, RunSpec
from piezopress.analysis.diagnosis.residuals import rms

#: Time constants of the drive current's envelope tried for the interference ...
INTERFERENCE_TAUS_S = (0.1e-3, 0.25e-3, 0.5e-3, 1e-3, 2e-3, 4e-3)
#: ... of which a coupling that follows the current's sign takes at most this one (it passes
#: the sensor's amplifier directly; only a rectified envelope is slower).
SIGNED_TAU_MAX_S = 0.5e-3


def _regress(fit, res: np.ndarray, drives: dict[int, np.ndarray], best: tuple) -> tuple:
    """The interference's gains fitted by least squares on the residual ``res`` of the fitting
    segments, for each envelope time constant and threshold; ``best`` improved where one does
    better: ``(rms, (g, threshold, tau, g_signed) or None)``."""
    for tau in INTERFERENCE_TAUS_S:
        envs = [signals.rate_envelope(drives[id(r)], r.fs_hz, tau)[sl] for r, sl in fit]
        # a coupling that follows the current's sign is as fast as the sensor's amplifier
        signed = np.concatenate(
            [
                signals.first_order(
                    np.diff(drives[id(r)], prepend=drives[id(r)][0]) * r.fs_hz, min(tau, SIGNED_TAU_MAX_S), r.fs_hz
                )[sl]
                for r, sl in fit
            ]
        )
        peak = max(float(e.max()) for e in envs)
        for frac in (0.0, 0.1, 0.2, 0.35, 0.5, 0.7):
            A = -np.column_stack([np.concatenate([np.maximum(e - frac * peak, 0.0) for e in envs]), signed])
            (g, gs), *_ = np.linalg.lstsq(A, res, rcond=None)
            if g < 0:  # the unsigned term is a dip: a negative gain is the signed term's job
                g, gs = 0.0, float(A[:, 1] @ res) / float(A[:, 1] @ A[:, 1])
            e = rms(res - A @ np.array([g, gs]))
            if e < best[0]:
                best = (e, (float(g), frac * peak, tau, float(gs)))
    return best


def _delay_text(key: str, d: float) -> str:
    return f"{d:.3g} samples" if key == "delay_samples" else f"{d * 1e3:.3g} ms"


#: A held-out sweep counts as predicted worse by the interference when its held-out RMS grows by more
#: than this (%): a slow sweep whose current stays under a threshold is not changed by it, and reads
#: a few tenths of a percent either way (on the virtual rig, runs cut to the required metadata:
#: 0.0 to -0.5 % at 5 and 10 Hz refused the coupling on 5 of 5 seeds); a lag of the force read as a coupling
#: makes the slow sweeps 8-16 % worse (the third test press, clean).
SWEEP_WORSE_PCT = 5.0
#: A delay found already is fitted again with the interference at these fractions of itself: found
#: alone, it took up part of the artefact's lag (a coupling through a 0.2 ms filter, delayed too).
DELAY_REFIT_FRACTIONS = (0.5, 0.75, 1.0, 1.25)


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
    delays = [own * f for f in DELAY_REFIT_FRACTIONS] if found_delay else [own]
    forces = _forces(base, [r for r, _ in fit])  # a delay changes only the reading

    def at(d: float) -> Model:
        return replace(base, **{key: d})

    res = {d: _err(fit, lambda r, d=d: at(d).reading(r, forces[id(r)])) for d in delays}
    plain = min((rms(e), d) for d, e in res.items())  # the delay alone at its best: the baseline
    best, delay = (rms(res[own]), None), own
    for d in delays:
        m = at(d)
        drives = {id(r): signals.delayed(r.drive, r.fs_hz, m.reading_delay_s(r.fs_hz)) for r, _ in fit}
        tried = _regress(fit, res[d], drives, best)
        if tried is not best:
            best, delay = tried, d
    if best[1] is None:
        return None
    g, e0, tau, gs = best[1]
    ext = replace(at(delay), interference=(g, e0, tau, gs))
    base = at(plain[1])
    u = ctx.model.unit
    parts = []
    if g:
        parts.append(
            f"dips {g * 1e3:.3g} {units.label(u)} per kV/s of drive rate above {e0 / 1e3:.3g} kV/s (envelope "
            f"{tau * 1e3:.3g} ms)"
        )
    if gs:
        parts.append(f"moves {-gs * 1e3:+.3g} {units.label(u)} per kV/s of the signed drive rate (the current's sign)")
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
        },
        base,
    )
    # the signature: an artefact of the drive current is in every sweep the current flows in. A
    # residual that grows with the sweep rate faster than the current (a lag of the force: creep
    # of milliseconds, the chain's dynamics) is taken up at the fast sweeps and over-corrected at
    # the slow ones (the third test press, clean: -8 to -16 % at 5 Hz, +63 % at 100 Hz; with a
    # coupling 30 to 46 % at every rate)
    worse = {
        name: gain
        for name, gain in found.gain_by_run.items()
        if gain < -SWEEP_WORSE_PCT and any(r.name == name and r.kind != "step" for r, _ in held)
    }
    if worse:
        found = replace(
            found,
            refused="an artefact of the drive current shows in every sweep the current flows in, and it predicts "
            + ", ".join(f"{n} {-g:.0f} % worse" for n, g in sorted(worse.items()))
            + ": the residual grows with the sweep rate faster than the drive current (a lag of the force, creep "
            "of milliseconds or the chain's own dynamics, reads so)",
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
