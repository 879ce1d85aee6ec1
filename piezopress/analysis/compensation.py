"""Open-loop compensation: a reference force trajectory in, the actuator drive out.

The thesis's order (Fig. 3.1), with what the whole known reference allows::

    reference (the hysteresis model's output unit: N above the preload, or um)
      -> rate limit            keeps the drive inside the amplifier's linear range
      -> input shaper(s)       cancel the mode(s) (centred: the whole reference is known)
      -> what the drive range reaches of it (:func:`reachable`)
      -> creep compensator     F_h = F_c / (K_c + C(s))       (Eq. 3.38)
      -> inverse hysteresis    x = H^-1[F_h]                  (Eq. 3.9), at the drive's own rate
      -> lead                  the drive advanced by the chain's delay
      -> slew limit            the drive kept within the amplifier's slew
      -> drive (V), clipped to the actuator's safe range

Unlike the thesis's real-time setup, the whole reference is known before the run, so the
shaper is applied centred on its exact centroid (no average delay, a fraction of a sample
kept) and the drive is advanced by the linear model's remaining low-frequency delay
(``lead_s``, interpolated between samples): at 50 Hz these delays are what made the thesis's
compensated loops wide (Table 6.11).

Extensions that ``diagnose`` may add (each off by default; see ``pipelines/diagnose.py``):

* ``shaper2``: a second shaper for a second mode, applied after the first (the two
  convolved: every impulse of one on every impulse of the other).
* ``rate``: rate-dependent hysteresis (:class:`RateDependence`), e.g. every play threshold
  ``r + delta`` with ``delta = beta |dV/dt|`` of the drive itself. Since
  ``H_{r + delta} = H_r o H_delta``, the inverse is the rate-independent one followed by the
  inverse of a play of width ``delta``: ``x = z + delta sign(dz/dt)`` (the drive leads the
  static inverse ``z`` by ``delta`` in its direction of motion); ``delta`` depends on the
  rate of ``x``, so the drive is iterated to the rate model's fixed point
  (:func:`rate_aware_inverse`), which never leads a motion past the hold it ends in.
* ``lead_s`` includes a pure input delay: the drive is advanced by exactly that (linear
  interpolation between samples).
* ``slew_v_per_s``: the amplifier's slew limit. The drive is kept below
  :data:`SLEW_MARGIN` of it by slowing the *reference* where the drive would be too fast
  (so the shaper still shapes what the press receives); what remains too fast is slewed
  symmetrically about the demanded drive instead of behind it (:func:`centred_rate_limit`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from piezopress import signals, units
from piezopress.analysis.creep import CreepModel
from piezopress.analysis.hysteresis import PIModel, rate_law, rate_loss_output
from piezopress.analysis.shaper import Shaper
from piezopress.errors import FitError

#: The compensator slows a transition (a step become a ramp) until the drive's rate is below
#: this share of the amplifier's slew limit ...
SLEW_MARGIN = 0.85
#: ... and keeps every drive below this share of it (a sweep that asks for more is slewed
#: symmetrically about the demanded drive rather than behind it, as the amplifier would).
SLEW_PROJECTION = 0.97
#: Drive-rate envelope of the rate-dependent hysteresis (s): the diagnosis model's.
RATE_TAU_S = 5e-4


def advance(x: np.ndarray, lead_s: float, fs_hz: float) -> np.ndarray:
    """``x(t + lead_s)`` by linear interpolation, held at ``x[-1]`` after the end (a lead of
    a fraction of a sample is kept, not rounded away)."""
    if lead_s <= 0:
        return x
    t = np.arange(x.size) / fs_hz
    return np.interp(t + lead_s, t, x, right=x[-1])


def centred_rate_limit(x: np.ndarray, max_step: float) -> np.ndarray:
    """A drive within ``max_step`` per sample, erring about ``x`` symmetrically in time.

    The mean of the causal rate limit (which lags ``x``) and the same limit run backwards
    in time (which leads it): both are within the limit, so their mean is; where ``x`` is
    within the limit all three agree.
    """
    fwd = signals.rate_limit(x, x[0], max_step)
    bwd = signals.rate_limit(x[::-1], x[-1], max_step)[::-1]
    return 0.5 * (fwd + bwd)


def _direction(z: np.ndarray) -> np.ndarray:
    """The sign of ``z``'s last move at every sample (+1 before the first move)."""
    d = np.sign(np.diff(z, prepend=z[0]))
    nz = np.flatnonzero(d)
    if nz.size == 0:
        return np.ones_like(z)
    idx = np.zeros(z.size, dtype=np.int64)
    idx[nz] = nz
    np.maximum.accumulate(idx, out=idx)
    out = d[idx]
    out[: nz[0]] = d[nz[0]]
    return out


#: :func:`reachable` stops after this many passes (each settles at least one clipped stretch).
REACHABLE_PASSES = 12


def reachable(
    model: PIModel, creep: CreepModel | None, r: np.ndarray, fs_hz: float, lo_v: float, hi_v: float
) -> np.ndarray:
    """The reference ``r`` (above ``y0``, before the creep compensator) where the drive range
    ``lo_v`` to ``hi_v`` reaches it, else what the clipped drive delivers.

    Clipping the drive afterwards leaves the inverse's play operators, and the creep
    compensator's state, where the unclipped drive would have taken them: after a clipped
    stretch (the top of a 300 N loop) the drive is wrong until they meet the real ones again.
    Each pass replaces the reference over the clipped stretches by what the model delivers for
    the clipped drive (hysteresis, then creep) and compensates again, until the drive stays in
    range. A stretch the reference holds on after (a 300 N creep hold the drive reaches only
    as the press creeps) is left to the clip: the hold's figure is its drift from its level a
    second after the step (thesis Eq. 5.2), which the clipped state keeps flat.
    """
    r = np.asarray(r, float)
    r0 = r
    done = np.zeros(r.size, bool)
    for _ in range(REACHABLE_PASSES):
        fh = creep.compensate(r, fs_hz)[0] if creep is not None else r
        x, _ = model.inverse(model.y0 + fh)
        out = ((x < lo_v) | (x > hi_v)) & ~done
        # a stretch the reference holds on after (a creep hold at the range's edge: the press creeps
        # up to it) is left as it was; where the reference moves on (over a loop's top) it is settled
        for a, b in _segments(out):
            tail = r0[b : b + (b - a) + 1]
            if tail.size < 2 or np.ptp(tail) == 0:
                out[a:b] = False
                done[a:b] = True
        if not out.any():
            break
        h = model.forward(np.clip(x, lo_v, hi_v))[0] - model.y0
        r = np.where(out, creep.response(h, fs_hz)[0] if creep is not None else h, r)
    return r


@dataclass(frozen=True)
class RateDependence:
    """Rate-dependent hysteresis as ``diagnose`` models it (``rate_dependent_hysteresis``).

    The stack feels the drive rate ``rho = env(|dx/dt|)`` smoothed over ``tau_s`` (and
    saturating as ``sat tanh(rho / sat)`` when ``saturation_v_per_s`` is given, or as a power law
    of it, ``exponent``; read above ``floor_v_per_s``, the rate the static loop was fitted at:
    :func:`piezopress.analysis.hysteresis.rate_law`). Either every
    play threshold widens by ``widen_v_per_kv_s * rho / 1000`` V, or the weighted plays' lag
    behind the drive grows by ``loss_per_kv_s * rho / 1000`` of itself (or both).
    """

    widen_v_per_kv_s: float = 0.0
    loss_per_kv_s: float = 0.0
    saturation_v_per_s: float | None = None
    tau_s: float = RATE_TAU_S
    exponent: float = 1.0
    floor_v_per_s: float = 0.0

    @property
    def active(self) -> bool:
        return self.widen_v_per_kv_s > 0 or self.loss_per_kv_s > 0

    def rate(self, x: np.ndarray, fs_hz: float) -> np.ndarray:
        """The rate the stack feels (V/s) under the drive ``x``."""
        return self.law(signals.rate_envelope(x, fs_hz, self.tau_s))

    def law(self, rho: np.ndarray) -> np.ndarray:
        """The rate law read on a rate ``rho`` (V/s) the stack feels."""
        return rate_law(rho, self.saturation_v_per_s, self.exponent, self.floor_v_per_s)

    def forward(self, model: PIModel, x: np.ndarray, fs_hz: float) -> np.ndarray:
        """The model's output (absolute, ``y0`` included) for the drive ``x``, at the drive's own rate."""
        rho = self.rate(x, fs_hz)
        u = np.asarray(x, float) - model.x0
        widen = self.widen_v_per_kv_s * rho / 1000.0 if self.widen_v_per_kv_s > 0 else None
        plays, extra = model.outputs(u, widen=widen)
        loss = self.loss_per_kv_s * rho / 1000.0 if self.loss_per_kv_s > 0 else 0.0
        return model.y0 + rate_loss_output(model, u, plays, extra, loss)


#: The rate-aware inverse stops when the drive moves less than this (V) from one pass to the next ...
RATE_INVERSE_TOL_V = 1e-4
#: ... or after this many passes.
RATE_INVERSE_PASSES = 40


def rate_aware_inverse(
    model: PIModel, y_ref: np.ndarray, fs_hz: float, rate: RateDependence
) -> tuple[np.ndarray, dict[str, Any]]:
    """The drive ``x`` whose rate-dependent model output is ``y_ref``: ``(x, info)``.

    With the rate-independent inverse ``z = H^-1[y_ref]`` and ``G(x) = H^-1[F_rate(x)]`` (the
    rate-dependent forward model read back through the static inverse), ``x`` solves
    ``G(x) = z`` by the fixed point ``x <- x + z - G(x)``. For widened thresholds
    (``H_{r + delta} = H_r o H_delta``) ``G(x) = x - delta sign(dx/dt)`` away from reversals,
    so the first guess ``x = z + delta(z) sign(dz/dt)`` is already close: the drive leads
    the static inverse by ``delta`` in its direction of motion, ``delta`` taken at the
    drive's own rate. ``info``: passes made and the largest remaining ``|z - G(x)|`` (V).

    With widened thresholds the lead is then capped at the widening the static inverse's
    *instantaneous* rate gives: where the motion stops (the end of a step's ramp) the lead
    goes at once. A lead that outlasts the stack's own widening (the model's rate envelope
    decaying slower than the stack's) pushes the plays on: an offset that stays until the
    next reversal (an overshoot that never settles). A lead short of the stack's widening
    costs only a lag, made up as the widening decays.

    With either form, a motion that ends in a hold is never led past the hold's static inverse,
    nor back the other way, and the hold's drive is that inverse (:func:`_settled_at_holds`).
    """
    z, _ = model.inverse(y_ref)
    if not rate.active:
        return z, {"passes": 0, "residual_v": 0.0}
    x = z.copy()
    if rate.widen_v_per_kv_s > 0:
        x = z + rate.widen_v_per_kv_s * rate.rate(z, fs_hz) / 1000.0 * _direction(z)
    res = np.inf
    passes = 0
    for passes in range(1, RATE_INVERSE_PASSES + 1):  # noqa: B007 - the count is reported after the loop
        g, _ = model.inverse(rate.forward(model, x, fs_hz))
        err = z - g
        res = float(np.max(np.abs(err)))
        if res <= RATE_INVERSE_TOL_V:
            break
        x = x + err
    if rate.widen_v_per_kv_s > 0 and rate.loss_per_kv_s == 0:
        # the lead never outlasts the motion: at most the widening at the static inverse's own
        # instantaneous rate (see the docstring)
        rho = rate.law(np.abs(np.diff(z, prepend=z[0])) * fs_hz)
        d = _direction(z)
        x = z + d * np.clip((x - z) * d, 0.0, rate.widen_v_per_kv_s * rho / 1000.0)
    return _settled_at_holds(x, z, fs_hz, rate), {"passes": passes, "residual_v": res}


#: The static inverse holds (:func:`_settled_at_holds`) where the loss form's boost at its rate is
#: under this share of the plays' lag ...
RATE_HOLD_BOOST = 0.005
#: ... or the widening's under this (V): a hold the creep compensator lowers at 10 V/s just after
#: its step (third test press, seed 4; 0.03 V of widening) is still a hold ...
RATE_HOLD_WIDEN_V = 0.05
#: ... and a hold that lasts this many of the rate envelope's time constants is where a motion
#: ends (the boost has decayed there): the drive reaches it without passing it.
RATE_HOLD_TAUS = 5.0


def _settled_at_holds(x: np.ndarray, z: np.ndarray, fs_hz: float, rate: RateDependence) -> np.ndarray:
    """The rate-aware drive ``x``, never past the static inverse ``z`` of a hold a motion ends
    in, and on ``z`` in the hold.

    Where a fast motion ends in a hold (a step, a staircase's tread, a creep hold), the rate
    model's fixed point leads the drive on the ramp and lets it fall back to ``z`` as the felt
    rate decays: a reversal of the drive the reference does not ask for. Where the press's lag
    falls short of the model's, the stack's input passes the hold's and comes back, and the
    stack stays on that minor loop for the whole hold. Measured with ``fit``'s bundle and the
    extension ``diagnose`` found (seed 3): on the second test press (the loop's width scaled by
    the rate), the worst step's overshoot went from 3.1 to 6.5 %, the 120 s creep from 0.17 to
    0.34 % and a staircase tread sat 3.8 N high; on the third (a viscous lag as the square root
    of the rate, which the model draws as a widening saturating at 2 kV/s), the staircase went
    from 2.5 to 7.3 %. Here the drive on a motion that ends in a hold goes no further than the
    hold's ``z`` (it arrives early rather than passing it), never back the other way on the way
    there, and is ``z`` in the hold: what the press still lags decays as it would without the
    extension, a lag of milliseconds and no offset. Motions that end in a reversal (a loop's
    top) keep the fixed point: that reversal is the reference's own.
    """
    dz = np.diff(z, prepend=z[0])
    rho = rate.law(np.abs(dz) * fs_hz) / 1000.0  # kV/s, as the law reads it
    still = (rho * rate.loss_per_kv_s < RATE_HOLD_BOOST) & (rho * rate.widen_v_per_kv_s < RATE_HOLD_WIDEN_V)
    long_hold = max(2, int(math.ceil(RATE_HOLD_TAUS * rate.tau_s * fs_hz)))
    out = x.copy()
    moved = np.sign(dz)
    previous_end = 0
    for h0, h1 in _segments(still):  # every hold: its first sample and the one after its last
        if h0 > 0 and h1 - h0 >= long_hold:
            d = moved[h0 - 1] or 1.0
            back = np.flatnonzero(moved[previous_end:h0] == -d)  # the motion starts after its last reversal
            s0 = previous_end + (int(back[-1]) + 1 if back.size else 0)
            seg = out[max(s0 - 1, 0) : h0] * d  # monotone from where the motion left (a fixed point can
            seg = np.maximum.accumulate(seg)[(1 if s0 > 0 else 0) :] * d  # dip back as a motion starts)
            out[s0:h0] = np.minimum(seg, z[h0]) if d > 0 else np.maximum(seg, z[h0])
            out[h0:h1] = z[h0:h1]
            previous_end = h1
    return out


@dataclass(frozen=True)
class CompensationResult:
    """The drive and what happened on the way (for the run's metadata and warnings)."""

    command_v: np.ndarray
    stages: dict[str, np.ndarray]
    clipped_samples: int
    requested_min_v: float
    requested_max_v: float
    warnings: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    #: samples whose reference the drive range cannot deliver, a hold the press creeps up to at
    #: the range's edge left out (its drive is clipped, its figure is the drift after the step)
    unreached_samples: int = 0


@dataclass(frozen=True)
class Compensator:
    """A reference-to-drive map built from a parameter bundle's models.

    Parameters
    ----------
    hysteresis : PIModel
        Maps drive (V) to the output (force in N, or displacement in um: its
        ``output_unit``, the unit of the reference); its inverse is the last stage.
    creep : CreepModel or None
        Creep of the hysteresis-compensated press; ``None`` skips the stage.
    shaper : Shaper or None
        Input shaper for the press's mode; ``None`` skips the stage.
    drive_min_v, drive_max_v : float
        The actuator's safe range; the drive is clipped to it, with a warning.
    max_rate_per_s : float or None
        Largest reference rate passed on, in the output unit per second (a step becomes a
        ramp). Keeps the drive current below the amplifier's limit, where the press is linear.
    lead_s : float
        Advance of the drive to cancel the linear model's remaining delay (and a pure
        input delay, when one was found).
    lead_samples : float
        Advance of the drive counted in samples of the reference's rate (an input delay
        ``diagnose`` found counted in samples: a board's FIFO), added to ``lead_s``.
    shaper2 : Shaper or None
        A second shaper, for a second mode (applied after ``shaper``).
    rate : RateDependence or None
        Rate-dependent hysteresis: the inverse at the drive's own rate (``None``: the
        rate-independent inverse).
    slew_v_per_s : float or None
        The amplifier's slew limit (V/s): the drive is kept below :data:`SLEW_MARGIN` of it.
    """

    hysteresis: PIModel
    creep: CreepModel | None = None
    shaper: Shaper | None = None
    drive_min_v: float = 0.0
    drive_max_v: float = 150.0
    max_rate_per_s: float | None = None
    lead_s: float = 0.0
    options: dict[str, Any] = field(default_factory=dict)
    shaper2: Shaper | None = None
    rate: RateDependence | None = None
    slew_v_per_s: float | None = None
    lead_samples: float = 0.0

    def lead_at(self, fs_hz: float) -> float:
        """The drive's whole lead in seconds at the rate ``fs_hz``."""
        return self.lead_s + self.lead_samples / fs_hz

    def _to_drive(
        self,
        r: np.ndarray,
        fs_hz: float,
        max_step: float | np.ndarray | None,
        k: str,
        stages: dict[str, np.ndarray],
        notes: list[str],
    ) -> np.ndarray:
        """Rate limit, shapers, creep compensator, inverse and lead: the drive before clipping."""
        if max_step is not None:
            r = signals.rate_limit(r, r[0], max_step)
            stages[f"rate_limited_{k}"] = r
        for name, sh in (("shaped", self.shaper), ("shaped2", self.shaper2)):
            if sh is None:
                continue
            try:
                # centred on the discrete shaper's exact centroid (a fraction of a sample kept)
                offsets, amps = sh.discretize(fs_hz)
                r = advance(sh.apply(r, fs_hz), float(np.dot(offsets, amps)) / fs_hz, fs_hz)
                stages[f"{name}_{k}"] = r
            except FitError:
                # too slow to resolve the mode: the drive's steps are too small to ring it
                note = f"shaper skipped: {fs_hz:g} Hz cannot resolve the {sh.wn / (2 * np.pi):.0f} Hz mode"
                if note not in notes:
                    notes.append(note)
        # what the drive range cannot reach is asked for as the clipped drive delivers it, so the inverse's
        # operators and the creep compensator follow the drive the press gets (the top of a loop at the range's edge)
        stages[f"requested_{k}"] = r
        r = reachable(self.hysteresis, self.creep, r, fs_hz, self.drive_min_v, self.drive_max_v)
        stages[f"reachable_{k}"] = r
        if self.creep is not None:
            r, _ = self.creep.compensate(r, fs_hz)
            stages[f"creep_compensated_{k}"] = r
        if self.rate is not None and self.rate.active:
            x, info = rate_aware_inverse(self.hysteresis, self.hysteresis.y0 + r, fs_hz, self.rate)
            stages["rate_independent_inverse_v"] = self.hysteresis.inverse(self.hysteresis.y0 + r)[0]
            if info["residual_v"] > 0.01:
                note = (
                    f"rate-aware inverse: {info['residual_v']:.3g} V from the rate model's solution "
                    f"after {info['passes']} passes"
                )
                if note not in notes:
                    notes.append(note)
        else:
            x, _ = self.hysteresis.inverse(self.hysteresis.y0 + r)
        return advance(x, self.lead_at(fs_hz), fs_hz)

    def _slew_feasible(
        self, r: np.ndarray, fs_hz: float, k: str, stages: dict[str, np.ndarray], notes: list[str]
    ) -> np.ndarray:
        """The drive with the reference slowed where the drive would outrun the slew limit.

        Each pass measures how far the drive's rate exceeds ``SLEW_MARGIN * slew``, maps the
        excess back to the reference's time (the lead, and the shapers' span either side)
        and lowers the reference's rate limit there by that factor; a few passes settle.
        What is still too fast (a reference that itself asks for more than the press can
        do) is slewed symmetrically by :func:`centred_rate_limit`.
        """
        limit = SLEW_MARGIN * float(self.slew_v_per_s) / fs_hz  # V per sample
        base = np.full(r.size, self.max_rate_per_s / fs_hz if self.max_rate_per_s else np.inf)
        step = base.copy()
        span = (
            sum(
                int(sh.discretize(fs_hz)[0][-1]) if fs_hz > 2 * sh.wn / (2 * np.pi) else 0
                for sh in (self.shaper, self.shaper2)
                if sh is not None
            )
            + 1
        )
        n_lead = int(np.ceil(self.lead_at(fs_hz) * fs_hz))
        x = self._to_drive(r, fs_hz, None if np.all(np.isinf(step)) else step, k, stages, notes)
        for _ in range(int(self.options.get("slew_passes", 8))):
            rate = np.abs(np.diff(x, prepend=x[0]))
            over = rate / limit
            if np.max(over) <= 1.0 + 1e-9:
                break
            factor = np.where(over > 1.0, 1.0 / np.maximum(over, 1e-300), 1.0)
            # drive sample i comes from reference samples i + n_lead - span .. i + n_lead + span
            factor = np.concatenate([np.ones(n_lead), factor])[: r.size] if n_lead else factor
            factor = -_max_filter(-factor, 2 * span + 1)
            # only a transition the rate limit shapes (a step become a ramp) is slowed: a
            # trajectory that asks for its own rate (a sweep) would only lag behind itself.
            # A transition is slowed as a whole, from the jump that starts it to the
            # reference's next change (its ramp lengthens into the hold that follows).
            limited = stages.get(f"rate_limited_{k}", r)
            at_limit = np.abs(np.diff(limited, prepend=limited[0])) >= 0.97 * step
            changes = np.flatnonzero(np.diff(r) != 0) + 1  # samples where the reference itself moves
            slowed = False
            for a, b in _segments(at_limit):
                f = float(np.min(factor[a:b]))
                if f >= 1.0:
                    continue
                nxt = changes[changes > a]
                end = int(nxt[0]) if nxt.size else r.size
                end = max(end, b)
                step[a:end] = np.minimum(step[a:end], 0.98 * f * step[a])
                slowed = True
            if not slowed:
                break
            stages.clear()
            stages[f"reference_{k}"] = r
            x = self._to_drive(r, fs_hz, step, k, stages, notes)
        hard = SLEW_PROJECTION * float(self.slew_v_per_s) / fs_hz
        if np.max(np.abs(np.diff(x))) > hard * (1 + 1e-9):
            x = centred_rate_limit(x, hard)
            notes.append("the reference asks for more than the slew limit allows: the rest is slewed symmetrically")
        stages["slew_limited_v"] = x
        return x

    def drive(self, reference: np.ndarray, fs_hz: float) -> CompensationResult:
        """The drive for ``reference`` (in the model's output unit: force above the preload,
        or displacement from the model's rest, sampled at ``fs_hz``).

        ``stages`` names each intermediate signal with the unit's key (``reference_n``,
        ``shaped_um``, ...) and the drive ``unclipped_v``.
        """
        r = np.asarray(reference, dtype=np.float64)
        if r.ndim != 1 or r.size < 2 or not np.all(np.isfinite(r)):
            raise ValueError(
                f"reference of shape {r.shape} with non-finite values or fewer than 2 samples; expected a finite 1-D "
                "trajectory"
            )
        k = units.key(self.hysteresis.output_unit)
        stages: dict[str, np.ndarray] = {f"reference_{k}": r}
        notes: list[str] = []
        if self.slew_v_per_s:
            x = self._slew_feasible(r, fs_hz, k, stages, notes)
        else:
            x = self._to_drive(r, fs_hz, self.max_rate_per_s / fs_hz if self.max_rate_per_s else None, k, stages, notes)
        stages["unclipped_v"] = x
        lo, hi = float(x.min()), float(x.max())
        clipped = int(np.count_nonzero((x < self.drive_min_v) | (x > self.drive_max_v)))
        warnings = []
        unit = self.hysteresis.output_unit
        unreached, short = _unreached(stages.get(f"requested_{k}", r), stages.get(f"reachable_{k}", r))
        clipped = max(clipped, unreached)
        if clipped:
            low_v, high_v = self.drive_min_v, self.drive_max_v
            asked = f" (requested {lo:.1f} to {hi:.1f} V)" if lo < low_v or hi > high_v else ""
            warnings.append(
                f"the reference cannot be reached everywhere: {clipped} of {x.size} samples "
                f"({100.0 * clipped / x.size:.1f} %) need a drive outside {low_v:g} to {high_v:g} V{asked}"
                + (f", up to {short:.4g} {unit} short of the reference" if short > 0 else "")
                + "; clipped"
            )
        lag = _rate_lag(r, stages.get(f"rate_limited_{k}"))
        if lag is not None:
            warnings.append(
                f"the rate limit ({self.max_rate_per_s:.4g} {unit}/s) keeps the drive from following the reference: "
                f"{lag:.1f} % of its range behind it (RMS); raise max_rate or slow the reference"
            )
        return CompensationResult(
            np.clip(x, self.drive_min_v, self.drive_max_v),
            stages,
            clipped,
            lo,
            hi,
            tuple(warnings),
            tuple(notes),
            unreached,
        )


UNREACHED_RTOL = 0.005
"""A sample is out of reach when what the clipped drive delivers misses the requested reference
by more than this share of the reference's range (or of its level, for a constant reference)."""

RATE_LAG_PCT = 5.0
"""The rate limit is reported when the rate-limited reference trails the reference by more
than this RMS share of its range."""


def unreached_mask(requested: np.ndarray, delivered: np.ndarray) -> np.ndarray:
    """True where what the clipped drive delivers misses the requested reference by more than
    :data:`UNREACHED_RTOL` of the reference's range (or level, for a constant one)."""
    requested = np.asarray(requested, float)
    scale = max(float(np.ptp(requested)), float(np.max(np.abs(requested))), 1e-12) if requested.size else 1.0
    return np.abs(np.asarray(delivered, float) - requested) > UNREACHED_RTOL * scale


def _unreached(requested: np.ndarray, delivered: np.ndarray) -> tuple[int, float]:
    """Samples where the reachable reference misses the requested one, and the largest miss."""
    bad = unreached_mask(requested, delivered)
    miss = np.abs(np.asarray(delivered, float) - np.asarray(requested, float))
    return int(np.count_nonzero(bad)), float(np.max(miss[bad])) if bad.any() else 0.0


def _reference_stages(result: CompensationResult) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The requested reference and the reachable one of a result (``None`` where a stage is missing)."""
    req = next((v for k, v in result.stages.items() if k.startswith("requested_")), None)
    got = next((v for k, v in result.stages.items() if k.startswith("reachable_")), None)
    return req, got


def clipped_mask(result: CompensationResult) -> np.ndarray:
    """1 where the drive was clipped or the reference is out of reach, else 0 (``compensate``'s
    ``clipped`` column)."""
    x = result.stages.get("unclipped_v", result.command_v)
    mask = (x < result.command_v - 1e-12) | (x > result.command_v + 1e-12)
    req, got = _reference_stages(result)
    if req is not None and got is not None and req.size == mask.size:
        mask |= unreached_mask(req, got)
    return mask.astype(np.int8)


def unreached_while_moving(result: CompensationResult) -> float:
    """Share of a reference's samples that move (a hold left out: a creep hold at the range's edge
    is reached only as the press creeps) and whose reference the drive range cannot deliver."""
    req, got = _reference_stages(result)
    if req is None or got is None or req.size < 2:
        return 0.0
    moving = np.abs(np.diff(req, prepend=req[0])) > 0
    return float(np.count_nonzero(unreached_mask(req, got) & moving)) / float(req.size)


def _rate_lag(r: np.ndarray, limited: np.ndarray | None) -> float | None:
    """RMS lag of the rate-limited reference (% of the reference's range), when above :data:`RATE_LAG_PCT`."""
    if limited is None:
        return None
    span = max(float(np.ptp(r)), 1e-12)
    lag = 100.0 * float(np.sqrt(np.mean((np.asarray(limited, float) - r) ** 2))) / span
    return lag if lag > RATE_LAG_PCT else None


def _segments(mask: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` of every run of True in ``mask``."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))


def _max_filter(x: np.ndarray, width: int) -> np.ndarray:
    """Running maximum over a centred window of ``width`` samples."""
    if width <= 1:
        return x
    from scipy.ndimage import maximum_filter1d

    return maximum_filter1d(x, size=width, mode="nearest")
