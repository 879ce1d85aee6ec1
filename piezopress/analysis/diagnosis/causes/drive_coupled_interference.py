"""The catalogue's cause ``drive_coupled_interference``: its fit (the signature it keys on, the extension judged
on held-out data) and its entry in the catalogue (:data:`CAUSE`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from piezopress import signals, units
from piezopress.analysis.diagnosis.cause import _FAST_STEPS, Cause
from piezopress.analysis.diagnosis.judging import Context, Finding, _err, _fast_base, _fast_split, _judge_dynamics
from piezopress.analysis.diagnosis.needs import Need, RunSpec
from piezopress.analysis.diagnosis.residuals import rms

#: Time constants of the drive current's envelope tried for the interference ...
INTERFERENCE_TAUS_S = (0.1e-3, 0.25e-3, 0.5e-3, 1e-3, 2e-3, 4e-3)
#: ... of which a coupling that follows the current's sign takes at most this one (it passes
#: the sensor's amplifier directly; only a rectified envelope is slower).
SIGNED_TAU_MAX_S = 0.5e-3


def cause_drive_coupled_interference(ctx: Context) -> Finding | None:
    runs = ctx.independent(ctx.steps() + ctx.sweeps(50.0))
    if len(runs) < 2:
        return None
    fit, held = _fast_split(ctx)
    base = _fast_base(ctx, fit)
    res = _err(fit, base.predict)
    # the artefact is additive at the sensor, so linear in its gains: the signed drive current
    # (a coupling that follows the current's sign) and the unsigned current's envelope above a
    # threshold (a dip whatever the sign), each smoothed over tau, fitted together
    best = (rms(res), None)
    for tau in INTERFERENCE_TAUS_S:
        envs = [signals.rate_envelope(r.drive, r.fs_hz, tau)[sl] for r, sl in fit]
        # a coupling that follows the current's sign is as fast as the sensor's amplifier
        signed = np.concatenate(
            [
                signals.first_order(
                    np.diff(r.drive, prepend=r.drive[0]) * r.fs_hz, min(tau, SIGNED_TAU_MAX_S), r.fs_hz
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
    if best[1] is None:
        return None
    g, e0, tau, gs = best[1]
    ext = replace(base, interference=(g, e0, tau, gs))
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
    return _judge_dynamics(
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


#: The catalogue's entry for this cause (read by every place that names causes).
CAUSE = Cause(
    "drive_coupled_interference",
    "the drive current couples into the load-cell amplifier (the thesis's notch, Section 5.3)",
    "an additive artefact of the reading: the signed drive current, and its envelope above a threshold",
    cause_drive_coupled_interference,
    needs=(Need((_FAST_STEPS, RunSpec("sweep", min_freq_hz=50.0)), 2, independent=True),),
)
