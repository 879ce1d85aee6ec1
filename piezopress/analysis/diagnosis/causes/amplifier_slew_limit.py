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
    with_chain,
)
from piezopress.analysis.diagnosis.model import Model, RunData
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


#: A step counts in the slew's signature check where a slew of its own predicts it this much
#: better (%): the slew acts on it (a step the limit does not reach reads any slew above its rate).
SLEW_ACTS_PCT = 10.0
#: The check's bar on how a step's own slew grows with the step's size (the slope of
#: ``log slew`` over ``log size``): a rate limit slews every step it reaches at one rate (slope
#: 0: the third test press's current limit, 26.4 -> 21.2 V/ms from 20 to 150 V, slope -0.11),
#: a lag of the chain rises in one time whatever the step (slope 1: the same press with a
#: coupled drive and a FIFO delay, 39 -> 240 V/ms, slope 0.90).
SLEW_SIZE_SLOPE_MAX = 0.5


#: A slew limit is a ramp: one that ramps every step in fewer samples than this (at the step's own
#: rate) cannot be told from a lag of half its length (a delay, the chain's bandwidth). The slews a
#: press's current limit sets ramp a 150 V step over milliseconds (the test presses: 10-67 V/ms,
#: 44 samples and more at 20 kHz); on the third test press with a frame mode hidden (seed 6), a
#: "slew" of 1990 V/ms (1.5 samples) took up 27 % of what the large steps' lag left.
MIN_RAMP_SAMPLES = 4.0


def ramp_unresolved(slew_v_per_s: float, steps: list[RunData]) -> str:
    """Why a slew of ``slew_v_per_s`` is no slew the steps can show ('' where one of them ramps
    over :data:`MIN_RAMP_SAMPLES` samples or more)."""
    if not steps or not slew_v_per_s > 0:
        return ""
    big = max(steps, key=lambda r: r.step_v / slew_v_per_s * r.fs_hz)
    ramp = big.step_v / slew_v_per_s
    n = ramp * big.fs_hz
    if n >= MIN_RAMP_SAMPLES:
        return ""
    return (
        f"a slew of {slew_v_per_s / 1e3:.3g} V/ms ramps its steps in {n:.2g} samples at most ({big.name}, "
        f"{big.step_v:.3g} V in {1e6 * ramp:.3g} us at {big.fs_hz / 1e3:g} kHz), under the {MIN_RAMP_SAMPLES:g} "
        "a ramp needs to be told from a lag of half its length (a delay, the chain's bandwidth)"
    )


def slew_by_step(model: Model, steps: list[RunData]) -> list[tuple[str, float, float, float]]:
    """Each step's own slew: ``(run, step size V, slew V/s, % better than no slew)``, the slew
    fitted on that step alone with everything else of ``model`` kept."""
    out = []
    for r in steps:
        seg = [(r, slice(None))]
        c0 = _cost(seg, model)
        s = _search(lambda v, seg=seg: _cost(seg, replace(model, slew_v_per_s=v)), 2e3, 2e6, 31, log=True)
        c1 = _cost(seg, replace(model, slew_v_per_s=s))
        out.append((r.name, float(np.ptp(r.x)), s, 100.0 * (1.0 - c1 / c0) if c0 > 0 else 0.0))
    return out


def _not_a_rate_limit(by_step: list[tuple[str, float, float, float]]) -> str:
    """Why the steps' own slews are not one rate limit's ('' where they are, or cannot tell)."""
    acting = [(size, s) for _, size, s, gain in by_step if gain >= SLEW_ACTS_PCT and size > 0]
    if len(acting) < 3 or max(a for a, _ in acting) < 2.0 * min(a for a, _ in acting):
        return ""
    slope = float(np.polyfit(np.log([a for a, _ in acting]), np.log([s for _, s in acting]), 1)[0])
    if slope <= SLEW_SIZE_SLOPE_MAX:
        return ""
    rates = ", ".join(f"{s / 1e3:.3g}" for _, s in sorted(acting))
    sizes = ", ".join(f"{a:.3g}" for a, _ in sorted(acting))
    return (
        f"a rate limit slews every step it reaches at one rate, and each step's own slew grows with the step "
        f"({rates} V/ms for steps of {sizes} V: slope {slope:.2f} in log-log, above {SLEW_SIZE_SLOPE_MAX}): a rise "
        "that takes one time whatever the step is a lag of the chain or an artefact of the reading, not a slew"
    )


def cause_amplifier_slew_limit(ctx: Context) -> Finding | None:
    steps = ctx.steps()
    if len(steps) < 2:
        return None
    mon = _monitor_slew(steps)
    if mon is None and any(r.monitor is not None for r in steps):
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

        base = _refit_mode(ctx.model, both, with_chain, [w, z, d], (lo_c, hi_c))
        ext = _refit_mode(
            ctx.model,
            both,
            lambda m, p: replace(with_chain(m, p), slew_v_per_s=float(p[3])),
            [w, z, d, s],
            (lo_c + [0.5 * s], hi_c + [2.0 * s]),
        )
    s = float(ext.slew_v_per_s)
    ev = f"large steps rise slower than small ones: the drive behaves as if limited to {s / 1e3:.3g} V/ms"
    if mon is not None:
        ev += f"; the amplifier monitor itself slews at {mon / 1e3:.3g} V/ms while the command jumps"
    found = _judge(ctx, "amplifier_slew_limit", ev, fit, held, ext, {"slew_rate_v_per_s": s}, base)
    if found.accepted and mon is None:  # a monitor that slews is the limit read directly
        why = ramp_unresolved(s, steps) or _not_a_rate_limit(slew_by_step(ctx.model, steps))
        if why:
            found = replace(found, refused=why)
    return found


#: The catalogue's entry for this cause (read by every place that names causes).
def held_slew(model: Model) -> str:
    """The slew the base's drive chain already holds ('' where none)."""
    return (
        f"the drive chain's slew of {model.slew_v_per_s / 1e3:.3g} V/ms, identified on the steps"
        if model.slew_v_per_s
        else ""
    )


CAUSE = Cause(
    "amplifier_slew_limit",
    "the amplifier's current limit into the stack's capacitance caps dV/dt at I/C",
    "the drive passed through a rate limiter before the model",
    cause_amplifier_slew_limit,
    needs=(Need((_FAST_STEPS,), 2),),
    extend=_bundle.extend_slew_limit,
    targets=("overshoot", "hysteresis_50hz"),
    held=held_slew,
)
