"""The catalogue's cause ``rate_dependent_hysteresis``: its fit (the signature it keys on, the extension judged
on held-out data) and its entry in the catalogue (:data:`CAUSE`)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from piezopress import signals, units
from piezopress.analysis import bundle as _bundle
from piezopress.analysis.diagnosis.cause import Cause
from piezopress.analysis.diagnosis.judging import (
    MIN_IMPROVEMENT_TO_FLOOR,
    Context,
    Finding,
    Segment,
    _cost,
    _cut,
    _fast_base,
    _fast_split,
    _judge_dynamics,
    _refit_mode,
    _search,
    one_widening,
)
from piezopress.analysis.diagnosis.model import Model
from piezopress.analysis.diagnosis.needs import Need, RunSpec
from piezopress.analysis.diagnosis.residuals import rms
from piezopress.analysis.hysteresis import rate_law

#: A rate dependence must predict the fast sweeps' held-out ends this much better (percent)
#: than one widening for every fast rate. On the second test press a constant widening does
#: as well as any rate form on clean seeds (-1 %), and 17-25 % worse where the loop's width
#: grows by 30 % between 5 and 50 Hz.
RATE_GATE_PCT = 10.0
#: Rates at which the rate dependence's widening may saturate (None: it does not).
RATE_SATURATIONS_V_PER_S = (None, 2e3, 4e3, 8e3, 2e4)
#: Power laws of the rate tried beside them (exponents below 1; ``hysteresis.rate_law``). A
#: viscous lag in the square root of the rate (the third test press's) drawn as a widening
#: saturating at 2 kV/s, the best of the saturating forms, doubles the widening at 5-10 Hz where
#: it is fitted to 50 Hz: compensated with it, the 10 Hz loop went from 1.28 to 3.39 % (seeds 3-4).
RATE_EXPONENTS = (0.5, 0.75)
#: The laws whose best linearised candidates are refined on the model itself (as many as the
#: candidates refined before the laws were compared: the refinement is the cause's cost; on the
#: third test press, seeds 3-4, the square root ranked second and third linearised).
RATE_LAWS_REFINED = 3
#: Every law tried: ``(saturation V/s or None, exponent)``.
RATE_LAWS = tuple((sat, 1.0) for sat in RATE_SATURATIONS_V_PER_S) + tuple((None, p) for p in RATE_EXPONENTS)


def _rate_forms(model: Model, fit: list[Segment]) -> list[tuple[float, Model]]:
    """Every form of rate dependence tried, each with its gain fitted: the widening as play
    thresholds growing with the rate, or as the loop's width scaled with it; the rate smoothed
    over 0.5 or 2 ms; linear in the rate, saturating (tanh) at 2 to 20 kV/s or a power law of it
    (:data:`RATE_LAWS`). The gain of
    each is fitted on the response linearised about the model (a small uniform widening's
    effect, scaled sample by sample by the form's rate and passed through creep, mode and
    sensor), then the best forms are refined on the model itself. Returns (cost, model),
    best first."""
    if model.causal:  # every sample after a segment's end is work for nothing
        fit = _cut(fit)
    runs = list({id(r): r for r, _ in fit}.values())
    h0 = {id(r): model.static(r) for r in runs}
    p0 = {id(r): model.reading(r, model.force(r, h0[id(r)])) for r in runs}
    res = np.concatenate([(r.y - p0[id(r)])[sl] for r, sl in fit])
    sweep = np.concatenate([np.full(r.y[sl].size, r.kind != "step") for r, sl in fit])
    # the drive the stack feels (through the model's chain: its lag, delay and slew limit), on
    # which both the static prediction and the widening act
    felt = {id(r): model.felt(r, r.x) for r in runs}
    shapes = {}
    for key, eps in (("rate_v_per_kv_s", 0.5), ("rate_loss_per_kv_s", 0.05)):
        # the static map's response to a uniform widening (eps V, or eps of the loop)
        m = replace(model, **{key: eps}, rate_saturation_v_per_s=None, rate_exponent=1.0, rate_floor_v_per_s=0.0)
        sens = {}
        for r in runs:  # a uniform rate of 1 kV/s
            sens[id(r)] = (m.static_at_rate(felt[id(r)], np.full(r.x.size, 1000.0)) - h0[id(r)]) / eps
        shapes[key] = sens
    cands = []
    for tau in (5e-4, 2e-3):
        rates = {id(r): signals.rate_envelope(felt[id(r)], r.fs_hz, tau) for r in runs}
        for sat, p in RATE_LAWS:
            for key, sens in shapes.items():
                cols = []
                for r, sl in fit:
                    g = rate_law(rates[id(r)], sat, p, model.rate_floor_v_per_s)
                    dh = g / 1000.0 * sens[id(r)]
                    cols.append((model.reading(r, model.force(r, h0[id(r)] + dh)) - p0[id(r)])[sl])
                a = np.concatenate(cols)
                if a @ a <= 0:
                    continue
                b = float(a @ res) / float(a @ a)
                # and on the sweeps alone: a mode the widening distorted (read on the steps) can
                # outweigh the widening on the steps and the fastest sweep, while the slower
                # sweeps show it plainly (the mode is freed after, _with_mode_freed)
                on = a[sweep] @ a[sweep]
                b_sweeps = float(a[sweep] @ res[sweep]) / float(on) if on > 0 else 0.0
                for bb in {b, b_sweeps}:
                    if bb > 0:
                        cands.append((rms(res - bb * a), key, bb, tau, sat, p))
    cands.sort(key=lambda c: c[0])
    # the best of each law, the first few refined on the model itself: linearised about the
    # model, a widening of several volts is misjudged most where the laws differ (the slow end),
    # so the refinement compares laws, not one law's variants (third test press, seed 4: the
    # three best linearised were one law saturating at 4 kV/s, 2.48 N refined; the square root,
    # further down among the candidates and third among the laws, 2.12 N)
    best_of_law = {}
    for c in cands:
        best_of_law.setdefault((c[1], c[4], c[5]), c)
    out = []
    for _, key, b, tau, sat, p in list(best_of_law.values())[:RATE_LAWS_REFINED]:

        def model_of(v, key=key, tau=tau, sat=sat, p=p):
            return replace(model, **{key: v}, rate_tau_s=tau, rate_saturation_v_per_s=sat, rate_exponent=p)

        v = _search(lambda v: _cost(fit, model_of(v)), 0.3 * b, 2.0 * b, 9)
        out.append((_cost(fit, model_of(v)), model_of(v)))
    return sorted(out, key=lambda c: c[0])


#: The mode is freed only where that predicts the fitting steps this much better (a share).
MODE_FREED_GAIN = 0.05


def _with_mode_freed(base: Model, ext: Model, fit: list[Segment], ext_cost: float) -> tuple[Model, Model, float, float]:
    """``(baseline, extended, their costs on fit)`` (``ext_cost``: ``ext``'s, known already), the
    main mode refitted freely where that predicts the fitting
    segments better: a stack whose loop widens with the rate rises slower on a step than its
    mode lets it (the drive it feels lags by the widening), and the steps' identification reads
    that as a slow, heavily damped mode (on the third test press, 368 Hz at damping 0.95 for a
    mode of 780 Hz at 0.06). The mode is refitted on the fitting steps (where it shows) with the
    rate dependence, the law read again on the freed mode (:func:`_rate_forms`), then judged on
    every fitting segment; the baseline gets the same freedom
    without the rate dependence, so that what the freed mode alone explains is no finding."""
    steps = [(r, sl) for r, sl in fit if r.kind == "step"]
    base_cost = _cost(fit, base)
    if not base.wn or not steps:
        return base, ext, base_cost, ext_cost
    key = "rate_v_per_kv_s" if ext.rate_v_per_kv_s else "rate_loss_per_kv_s"
    v = float(getattr(ext, key))
    freed = _refit_mode(ext, steps, wide=True)
    if _cost(steps, freed) > (1.0 - MODE_FREED_GAIN) * _cost(steps, ext):
        return base, ext, base_cost, ext_cost  # the steps' mode was not distorted: nothing to free
    # the rate's gain again on every fitting segment, with the freed mode (the sweeps pin it down)
    v = _search(lambda g: _cost(fit, replace(freed, **{key: g})), 0.1 * v, 10.0 * v, 13, log=True)
    freed = replace(freed, **{key: v})
    freed_cost = _cost(fit, freed)
    # the law again with the mode freed: the distorted mode took up part of the widening where the
    # first law was chosen, so the law that draws it best is read on the freed mode (third test press,
    # seed 3: a square root, held out 1.9 N, beside 4.0 N for the form saturating at 2 kV/s that the
    # distorted mode chose). Read whether or not the first law gained with the freed mode: with a log
    # creep taken first (rate dependence and a log creep, seed 4), the distorted mode chose a form
    # saturating at 2 kV/s that the freed mode did not improve (6.5 N on the fitting runs), where the
    # square root on the freed mode reads 2.8 N
    again = _rate_forms(replace(freed, rate_v_per_kv_s=0.0, rate_loss_per_kv_s=0.0), fit)
    if again and again[0][0] < freed_cost:
        freed_cost, freed = again[0]
    if freed_cost >= ext_cost:
        return base, ext, base_cost, ext_cost
    freed_base = _refit_mode(base, steps, wide=True)
    freed_base_cost = _cost(fit, freed_base)
    if freed_base_cost < base_cost:
        return freed_base, freed, freed_base_cost, freed_cost
    return base, freed, base_cost, freed_cost


#: A run the base was fitted on is a sweep where its drive moves over this share of its samples ...
SWEEP_MOVING_SHARE = 0.5
#: ... faster than this share of its fastest rate (a step's hold, a creep hold and a rest are
#: still there: their rate envelope decays from the step's to nothing).
SWEEP_MOVING_RATE = 0.01


def fitted_rate(ctx: Context, tau_s: float = 2e-3) -> float:
    """The drive rate (V/s) the base model's loop was fitted at: the median rate envelope of
    the runs it was fitted on that are sweeps by their drive (it moves most of the time; a step,
    a creep hold and a rest do not), 0 without one. The loop fitted there holds the widening at
    that rate already; the rate law is read above it (``hysteresis.rate_law``)."""
    moving = []
    for r in ctx.runs:
        if not ctx.is_fitted(r):
            continue
        env = signals.rate_envelope(r.x, r.fs_hz, tau_s)
        fast = env > SWEEP_MOVING_RATE * float(np.max(env, initial=0.0))
        if env.size and fast.mean() > SWEEP_MOVING_SHARE:
            moving.append(env[fast])
    return float(np.median(np.concatenate(moving))) if moving else 0.0


def cause_rate_dependent_hysteresis(ctx: Context) -> Finding | None:
    if not ctx.independent(ctx.sweeps(5.0)):
        return None
    fit, held = _fast_split(ctx)
    base = replace(_fast_base(ctx, fit), rate_floor_v_per_s=fitted_rate(ctx))
    forms = _rate_forms(base, fit)
    if not forms:
        return None
    ext_cost, ext = forms[0]
    mode_before = (base.wn, base.zeta)
    # freed before the form is judged: a mode distorted far enough (the third test press's
    # strongest widening read a 880 Hz mode as 278 Hz at damping 0.95) hides the widening from
    # a model that keeps it
    base, ext, base_cost, ext_cost = _with_mode_freed(base, ext, fit, ext_cost)
    if ext_cost >= base_cost:
        return None
    # Rate dependence is a widening that changes with the rate across the fast sweeps. A loop
    # fitted at 0.1 Hz can be off by one width at every fast rate (a creep element of a
    # second lags a 1 Hz sweep as much as a 100 Hz one), which a form saturating below the
    # slowest fast sweep's rate takes up: the widening must beat that one on held-out data
    # (by RATE_GATE_PCT: a check of the signature, not the finding's gain) before its gain is
    # judged against the baseline the other fast causes have.
    refused = ""
    constant = one_widening(base, fit)
    if constant is not None:
        gate = _judge_dynamics(ctx, "rate_dependent_hysteresis", "", fit, held, ext, {}, constant)
        if (
            gate.gain_pct < RATE_GATE_PCT
            or gate.baseline_rms - gate.extended_rms < MIN_IMPROVEMENT_TO_FLOOR * gate.floor
        ):
            u = units.label(ctx.model.unit)
            # refused with the reason, not dropped: the gate is the cause's signature check, and
            # ``tested`` says why (third test press, rate dependence and a log creep, seed 2: 10.1 %
            # before the log creep was taken, 9.4 % after; dropped, the earlier round's 50 % held
            # out was all ``tested`` said)
            short = (
                f"under the {RATE_GATE_PCT:g} % a widening that changes with the rate needs"
                if gate.gain_pct < RATE_GATE_PCT
                else f"{gate.baseline_rms - gate.extended_rms:.3g} {u}, under {MIN_IMPROVEMENT_TO_FLOOR:g} noise floors"
            )
            refused = (
                "one widening for every fast rate predicts the fast sweeps' held-out ends nearly as well "
                f"({gate.baseline_rms:.3g} {u} RMS against {gate.extended_rms:.3g} {u} with the rate: "
                f"{gate.gain_pct:.0f} % better, {short})"
            )
    sat, p = ext.rate_saturation_v_per_s, ext.rate_exponent
    if sat:
        form = f"saturating above {sat / 1e3:.3g} kV/s"
    elif p != 1.0:
        form = "as the square root of it" if p == 0.5 else f"as its power {p:g}"
    else:
        form = "in proportion to it"
    at = " at 1 kV/s" if p != 1.0 else " per kV/s"
    if ext.rate_v_per_kv_s:
        how = f"every threshold grows {ext.rate_v_per_kv_s:.3g} V{at}"
    else:
        how = f"the loop's width grows {100 * ext.rate_loss_per_kv_s:.3g} %{at}"
    ev = (
        f"the loops widen with the drive rate beyond the model's dynamics, {form}: {how} "
        f"(rate smoothed over {ext.rate_tau_s * 1e3:.3g} ms"
        + (
            f"; read above the {ext.rate_floor_v_per_s:.3g} V/s the base loop was fitted at, whose widening it holds)"
            if ext.rate_floor_v_per_s > 0
            else ")"
        )
    )
    if mode_before[0] and ext.wn and abs(ext.wn / mode_before[0] - 1.0) > 0.1:
        ev += (
            f"; with it the main mode is {ext.wn / (2 * np.pi):.4g} Hz at damping {ext.zeta:.2g}, where the steps "
            f"alone read {mode_before[0] / (2 * np.pi):.4g} Hz at {mode_before[1]:.2g} (the widening slows a step)"
        )
    found = _judge_dynamics(
        ctx,
        "rate_dependent_hysteresis",
        ev,
        fit,
        held,
        ext,
        {
            "rate_v_per_kv_s": ext.rate_v_per_kv_s,
            "rate_loss_per_kv_s": ext.rate_loss_per_kv_s,
            "rate_saturation_v_per_s": sat or math.inf,
            "rate_tau_s": ext.rate_tau_s,
            "rate_exponent": p,
            "rate_floor_v_per_s": ext.rate_floor_v_per_s,
        },
        base,
    )
    return replace(found, refused=refused) if refused else found


#: The catalogue's entry for this cause (read by every place that names causes).
CAUSE = Cause(
    "rate_dependent_hysteresis",
    "the stack's loop widens with the drive rate (domain walls lag a fast field)",
    "play thresholds r_i + beta |dV/dt|, or the loop's width scaled by 1 + k |dV/dt| (the rate smoothed, "
    "linear, saturating or a power law of it)",
    cause_rate_dependent_hysteresis,
    needs=(Need((RunSpec("sweep", min_freq_hz=5.0),), 1, independent=True),),
    extend=_bundle.extend_rate_dependence,
    targets=("hysteresis_5hz", "hysteresis_10hz", "hysteresis_50hz"),
    refits_mode=True,
)
