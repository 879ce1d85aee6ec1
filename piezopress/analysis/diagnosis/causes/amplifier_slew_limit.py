"""The catalogue's cause ``amplifier_slew_limit``: its fit (the signature it keys on, the extension judged
on held-out data) and its entry in the catalogue (:data:`CAUSE`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from piezopress.analysis import bundle as _bundle
from piezopress.analysis.diagnosis.cause import _FAST_STEPS, Cause
from piezopress.analysis.diagnosis.judging import (
    CHAIN_LAG_S,
    Context,
    Finding,
    _cost,
    _fast_split,
    _judge,
    _refit_mode,
    _search,
    _split,
)
from piezopress.analysis.diagnosis.model import RunData
from piezopress.analysis.diagnosis.needs import Need


def _monitor_slew(runs: list[RunData]) -> float | None:
    """Largest |dV/dt| of the amplifier monitor on runs whose command jumps further than it."""
    rates = []
    for r in runs:
        if r.monitor is None:
            continue
        jump = np.max(np.abs(np.diff(r.x))) * r.fs_hz
        mon = np.max(np.abs(np.diff(r.monitor))) * r.fs_hz
        if mon < 0.8 * jump:
            rates.append(mon)
    return max(rates) if rates else None


def cause_amplifier_slew_limit(ctx: Context) -> Finding | None:
    steps = ctx.steps()
    if len(steps) < 2:
        return None
    if any(r.monitor is not None for r in steps) and _monitor_slew(steps) is None:
        return None  # the applied drive follows the command: whatever the residual is, it is not the slew
    fit, held = _split(ctx.independent(steps) or steps)
    s = _search(lambda v: _cost(fit, replace(ctx.model, slew_v_per_s=v)), 2e3, 2e6, 31, log=True)
    if ctx.model.drive_lowpass is None:
        base = _refit_mode(ctx.model, fit)
        ext = _refit_mode(
            ctx.model, fit, lambda m, p: replace(m, slew_v_per_s=float(p[0])), [s], ([0.5 * s], [2.0 * s])
        )
    else:
        # the drive chain's low-pass and delay were identified on steps that all slewed, which give
        # a slewed rise's delay and not a small signal's: both sides refit them with the mode, on the
        # fitting steps and the fast sweeps' fitting part (slow enough not to slew: they pin the
        # small-signal lag down), so the gain is the slew's and what the chain's lag still misses is
        # not left over for a delay or an interference to take up
        (w, z), d = ctx.model.drive_lowpass, ctx.model.drive_delay_s
        both = fit + [seg for seg in _fast_split(ctx)[0] if seg[0].kind != "step"]
        lo_c, hi_c = [0.25 * w, 0.2, 0.0], [4.0 * w, 0.99, max(2.0 * d, CHAIN_LAG_S)]

        def chain(m, p):
            return replace(m, drive_lowpass=(float(p[0]), float(p[1])), drive_delay_s=float(p[2]))

        base = _refit_mode(ctx.model, both, chain, [w, z, d], (lo_c, hi_c))
        ext = _refit_mode(
            ctx.model,
            both,
            lambda m, p: replace(chain(m, p), slew_v_per_s=float(p[3])),
            [w, z, d, s],
            (lo_c + [0.5 * s], hi_c + [2.0 * s]),
        )
    s = float(ext.slew_v_per_s)
    mon = _monitor_slew(steps)
    ev = f"large steps rise slower than small ones: the drive behaves as if limited to {s / 1e3:.3g} V/ms"
    if mon is not None:
        ev += f"; the amplifier monitor itself slews at {mon / 1e3:.3g} V/ms while the command jumps"
    return _judge(ctx, "amplifier_slew_limit", ev, fit, held, ext, {"slew_rate_v_per_s": s}, base)


#: The catalogue's entry for this cause (read by every place that names causes).
CAUSE = Cause(
    "amplifier_slew_limit",
    "the amplifier's current limit into the stack's capacitance caps dV/dt at I/C",
    "the drive passed through a rate limiter before the model",
    cause_amplifier_slew_limit,
    needs=(Need((_FAST_STEPS,), 2),),
    extend=_bundle.extend_slew_limit,
    targets=("overshoot", "hysteresis_50hz"),
)
