"""The catalogue's cause ``input_delay``: its fit (the signature it keys on, the extension judged
on held-out data) and its entry in the catalogue (:data:`CAUSE`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from piezopress import signals
from piezopress.analysis import bundle as _bundle
from piezopress.analysis import hysteresis as H
from piezopress.analysis.diagnosis.cause import _FAST_STEPS, Cause
from piezopress.analysis.diagnosis.judging import (
    CHAIN_LAG_S,
    Context,
    Finding,
    _cost,
    _fast_base,
    _fast_split,
    _forces,
    _judge,
    _judge_dynamics,
    _reading_cost,
    _refit_mode,
    _search,
)
from piezopress.analysis.diagnosis.model import Model
from piezopress.analysis.diagnosis.needs import Need, RunSpec, lag_visible

#: The delay on slow sweeps refits the operators a dozen times: on at most this many samples.
DELAY_FIT_MAX_SAMPLES = 8000


def _delay_on_sweeps(ctx: Context) -> Finding | None:
    """A delay judged on swept runs the base model may itself have been fitted on (a slow
    sine, say), where a lag of a few samples shows (:func:`lag_visible`).

    A lag there is partly taken up by the hysteresis fit (a wider loop), so the delay alone
    cannot be judged against the base model: the operators (the base model's thresholds) are
    refitted on each run's first 60 % twice, on the drive as recorded and on the drive
    delayed (the delay chosen on those samples: whole samples up to 8, then half a sample
    either side; long records decimated to :data:`DELAY_FIT_MAX_SAMPLES`), and both refits are
    judged on the last 40 %, which neither saw."""
    runs = [r for r in ctx.sweeps() if lag_visible(r, ctx)]
    if not runs:
        return None
    m = ctx.model.hysteresis
    outs = []
    for r in runs:  # the output as the hysteresis sees it: accepted drift and the creep removed, as the fit does
        y = r.y - ctx.model.drift_per_s * r.t_s - ctx.model.clock_drift(r)
        if ctx.model.creep is not None:
            y = m.y0 + ctx.model.creep.compensate(y - m.y0, r.fs_hz)[0]
        outs.append(y)
    skip = [H.settled_start(r.x) for r in runs]

    # fitted on a decimated copy of a long record: plays are rate-independent, and the delayed
    # drive is computed on the full grid first, so a fraction of a sample still shows
    step = int(np.ceil(sum(r.x.size for r in runs) / DELAY_FIT_MAX_SAMPLES))

    def prep(delay: float) -> H.HysteresisData:
        xs = [np.interp(r.t_s - delay, r.t_s, r.x, left=r.x[0]) for r in runs]
        return H.prepare(
            [(r.name, x, y) for r, x, y in zip(runs, xs, outs)], holdout_fraction=0.4, x0=m.x0, y0=m.y0, skip=skip
        )

    def refit(k: float) -> tuple[float, H.PIModel]:
        data = prep(k / fs)
        data = H.decimate(data, step) if step > 1 else data
        cache: dict = {}
        model = H.refit(data, m, cache=cache)  # the base model's structure (plays, dead zones, plane or elements)
        return H.rms_error(model, data, H.columns_for(data, np.array(m.r), m.extra, cache), "train"), model

    fs = min(r.fs_hz for r in runs)
    fits = {k: refit(k) for k in range(0, 9)}  # whole samples, then half a sample either side
    k0 = min(fits, key=lambda k: fits[k][0])
    fits.update({k: refit(k) for k in (k0 - 0.5, k0 + 0.5) if k >= 0})
    k = min(fits, key=lambda k: fits[k][0])
    d, ext_h, base_h = k / fs, fits[k][1], fits[0][1]
    data = prep(0.0)  # the fitted and held-out rows
    cuts = [int(np.argmax(h)) for h in data.holdout]
    firsts = [int(np.argmax(t)) for t in data.train]
    fit = [(r, slice(a, b)) for r, a, b in zip(runs, firsts, cuts)]
    held = [(r, slice(b, None)) for r, b in zip(runs, cuts)]
    ext = replace(ctx.model, hysteresis=ext_h, delay_s=float(d))
    ev = (
        f"the output lags the drive by {d * 1e3:.3g} ms ({d * fs:.2g} samples) beyond what the hysteresis takes up: "
        "the operators "
        f"refitted on the delayed drive predict the held-out end of {', '.join(r.name for r in runs)} better than "
        "refitted on the "
        f"drive as recorded (both fitted on the first 60 %)"
    )
    return _judge(
        ctx,
        "input_delay",
        ev,
        fit,
        held,
        ext,
        {"delay_s": float(d), "operators_refitted": 1.0},
        replace(ctx.model, hysteresis=base_h),
    )


def cause_input_delay(ctx: Context) -> Finding | None:
    runs = ctx.independent(ctx.steps() + ctx.sweeps(5.0))
    if len(runs) < 2:
        return _delay_on_sweeps(
            ctx
        )  # no fast runs the base was not fitted on: swept runs where a lag of a few samples shows
    found = _delay_on_fast_runs(ctx)
    if found is not None and found.accepted:
        why = slew_shape(ctx, found)
        return replace(found, refused=why) if why else found
    # where the fast runs' shape cannot tell the delay from the chain's bandwidth, two steps of one
    # size at two sample rates tell a delay counted in samples apart from any lag in seconds
    by_rate = _delay_by_rate_contrast(ctx)
    return by_rate if by_rate is not None and by_rate.accepted else found


#: Beside a slew in the model, a delay must predict the runs the slew does not reach at least this
#: much better (median of their held-out gains, %): a delay lags every run alike, and a slew whose
#: form differs from the press's (a rate limit before the chain's low-pass, where the third test
#: press clips the velocity of its amplifier's own state) leaves a lag only where it acts. Third
#: press, current limit seed 13 (11 V/ms): a delay of 0.187 ms gained 65 and 38 % on the 100 and
#: 50 Hz triangles (15 and 30 V/ms: slewed) and 12 % on the steps, 0.3 and 1.8 % on the 5 and 10 Hz
#: ones, which the slew does not reach.
SLEW_FREE_GAIN_PCT = 10.0


def _slewed(r, slew_v_per_s: float) -> bool:
    """Whether a rate limit at ``slew_v_per_s`` moves run ``r``'s drive by more than 1 % of its range."""
    x = np.asarray(r.x, dtype=float)
    span = float(np.ptp(x)) if x.size else 0.0
    if span <= 0.0 or float(np.max(np.abs(np.diff(x)))) <= slew_v_per_s / r.fs_hz:
        return False  # (no sample outruns the limit: nothing to step through)
    lim = signals.rate_limit(x, float(x[0]), slew_v_per_s / r.fs_hz)
    return bool(np.max(np.abs(lim - x)) > 0.01 * span)


def slew_shape(ctx: Context, found: Finding) -> str:
    """Why a delay found beside the model's slew is the slew's shape, not a delay ('' where the
    runs the slew does not reach show it too, or where the model has no slew): see
    :data:`SLEW_FREE_GAIN_PCT`."""
    s = ctx.model.slew_v_per_s
    if not s or not found.gain_by_run:
        return ""
    by_name = {r.name: r for r in ctx.runs}
    free = [n for n in found.gain_by_run if n in by_name and not _slewed(by_name[n], s)]
    slewed = [n for n in found.gain_by_run if n not in free]
    if not slewed:
        return ""
    gains = [found.gain_by_run[n] for n in free]
    if gains and float(np.median(gains)) >= SLEW_FREE_GAIN_PCT:
        return ""
    on = ", ".join(f"{n} {found.gain_by_run[n]:.0f} %" for n in slewed)
    if not gains:
        return (
            f"every held-out run it gains on is one the model's slew of {s / 1e3:.3g} V/ms acts on ({on}): "
            "a slew whose form is not the press's leaves such a lag, and no run too slow to slew tells them apart"
        )
    off = ", ".join(f"{n} {found.gain_by_run[n]:.1f} %" for n in free)
    return (
        f"it gains on the held-out runs the model's slew of {s / 1e3:.3g} V/ms acts on ({on}) and not on those too "
        f"slow to slew ({off}; median under {SLEW_FREE_GAIN_PCT:g} %): a delay lags every run alike, a slew "
        "whose form is not the press's leaves a lag only where it acts"
    )


def _delay_on_fast_runs(ctx: Context) -> Finding | None:
    """The delay fitted with the mode (and the chain's low-pass) on the fast runs the base was
    not fitted on, judged on their held-out part against a baseline with the same freedom."""
    fit, held = _fast_split(ctx)
    steps_fit = [(r, sl) for r, sl in fit if r.kind == "step"]
    # the baseline: the mode refitted within its bounds, and the chain's own lag (CHAIN_LAG_S)
    base = _fast_base(ctx, fit)
    delayed = _reading_cost(fit, _forces(ctx.model, [r for r, _ in fit]))  # a delay changes only the reading
    d = _search(lambda d: delayed(replace(ctx.model, delay_s=d)), 0.0, 5e-3, 41)
    # a delay counted in samples (a board's FIFO, a converter's filter) is another delay in time at
    # each sample rate: where the runs have several, both are tried and the better kept
    rates = sorted({r.fs_hz for r, _ in fit})
    per_sample = rates[-1] > SAMPLE_RATES_APART * rates[0]
    key, hi = "delay_s", 5e-3
    if per_sample:
        n_hi = 5e-3 * rates[0]
        k = _search(lambda k: delayed(replace(ctx.model, delay_samples=k)), 0.0, n_hi, 41)
        if delayed(replace(ctx.model, delay_samples=k)) < delayed(replace(ctx.model, delay_s=d)):
            key, hi, d = "delay_samples", n_hi, k
    ext = replace(ctx.model, **{key: d})
    lp = ctx.model.drive_lowpass
    if steps_fit:  # the mode and the delay together, on the steps and the sweeps (which pin the delay down)
        # a delay distorts the identified mode (the identification has no delay): refit both
        # freely, and give the baseline the same freedom of the mode with the chain's lag
        # the drive chain's low-pass too, where the base has one: identified on steps that lagged by
        # the delay, it took part of the delay as its own lag (which the sweeps then show twice)
        lp_x0, lp_lo, lp_hi = ([lp[0], lp[1]], [0.5 * lp[0], 0.2], [4.0 * lp[0], 0.99]) if lp else ([], [], [])

        def chain(m, p, k):
            return replace(m, **{k: float(p[0])}, **({"drive_lowpass": (float(p[1]), float(p[2]))} if lp else {}))

        ext = _refit_mode(
            ctx.model, fit, lambda m, p: chain(m, p, key), [d, *lp_x0], ([0.0, *lp_lo], [hi, *lp_hi]), wide=True
        )
        d = float(getattr(ext, key))
        wide = _refit_mode(
            ctx.model,
            fit,
            lambda m, p: chain(m, p, "delay_s"),
            [base.delay_s, *lp_x0],
            ([0.0, *lp_lo], [CHAIN_LAG_S, *lp_hi]),
            wide=True,
        )
        base = min((base, wide), key=lambda m: _cost(fit, m))
    now = ext.drive_lowpass
    moved = (
        f"; the drive chain's low-pass refitted with it, {lp[0] / (2 * np.pi):.3g} Hz (damping {lp[1]:.2g}) -> "
        f"{now[0] / (2 * np.pi):.3g} Hz ({now[1]:.2g})"
        if lp and now and not np.allclose(lp, now)
        else ""
    )
    if key == "delay_samples":
        return _judge_samples(ctx, fit, held, ext, d, base, rates, moved)
    if d <= CHAIN_LAG_S:
        return None  # no longer than the chain's own lag: nothing to test beyond it
    ev = f"the whole response lags the model by {d * 1e3:.3g} ms, on steps and fast sweeps alike{moved}"
    return _judge_dynamics(ctx, "input_delay", ev, fit, held, ext, {"delay_s": d}, base)


#: Runs whose sample rates differ by more than this factor can tell a delay counted in samples
#: from one in time.
SAMPLE_RATES_APART = 1.2

#: Two steps are of one size where their heights differ by less than this fraction.
SAME_STEP = 0.05

#: A delay counted in samples is named from this many samples beyond what the model holds: the
#: rate contrast reads a fraction of a sample that the converters' timing leaves on every press
#: (third test press, clean, seeds 0-1: 0.5 samples, held-out gain 19 and 24 %; second press, clean:
#: 0.25 samples, 59 %), and a board's FIFO or a converter's latency is whole samples. The fast
#: runs' own fit of a delay in samples (:func:`_judge_samples`) is held to it too (third test press,
#: a coupling of the drive voltage, seed 4: 0.66 samples, 22 %, once the coupling was in the model).
MIN_CONTRAST_SAMPLES = 1.0


def _step_edges(r) -> np.ndarray:
    """The first sample of each edge of a step run's command (a jump of a fifth of its height)."""
    jump = np.abs(np.diff(r.x))
    idx = np.flatnonzero(jump > 0.2 * max(float(np.max(np.abs(r.x - r.x[0]))), 1e-12)) + 1
    return idx[np.r_[True, np.diff(idx) > 1]] if idx.size else idx


def rate_pairs(ctx: Context) -> list[tuple]:
    """Step runs of one size (within :data:`SAME_STEP`) at two sample rates (more than
    :data:`SAMPLE_RATES_APART` apart), each with a rise and a fall, none the base was fitted on:
    ``(slower, faster)``, each run in one pair at most."""
    steps = [r for r in ctx.independent(ctx.steps()) if _step_edges(r).size >= 2]
    pairs, used = [], set()
    for a in sorted(steps, key=lambda r: r.fs_hz):
        for b in sorted(steps, key=lambda r: -r.fs_hz):
            if id(a) in used or id(b) in used or b.fs_hz <= SAMPLE_RATES_APART * a.fs_hz:
                continue
            if abs(a.step_v - b.step_v) <= SAME_STEP * max(abs(a.step_v), abs(b.step_v)):
                pairs.append((a, b))
                used.update((id(a), id(b)))
    return pairs


def rate_contrast(
    model, pairs: list[tuple], edge: int, window_s: float, forces: dict[int, np.ndarray], edges: dict[int, np.ndarray]
) -> float:
    """RMS of what two runs of each pair leave of the model differently, about the step's
    ``edge``-th edge (0: the rise, 1: the fall), from half a millisecond before it to ``window_s``
    after it: each run's residual on the time since its own edge, the faster run's interpolated
    onto the slower one's samples, their difference less its mean. The static map, the creep and
    the mode leave both runs alike (one drive, one press, in time), so they cancel; a lag counted
    in samples does not. (Each on its own edge: two runs whose steps come at other times, or a
    sample apart, compare the same part of the response.) ``edges``: each run's :func:`_step_edges`."""
    out = []
    for a, b in pairs:
        ea = a.y - model.reading(a, forces[id(a)])
        eb = b.y - model.reading(b, forces[id(b)])
        ta = a.t_s - a.t_s[edges[id(a)][edge]]
        tb = b.t_s - b.t_s[edges[id(b)][edge]]
        sel = (ta >= -5e-4) & (ta <= window_s)
        d = ea[sel] - np.interp(ta[sel], tb, eb)
        out.append(d - d.mean())
    return float(np.sqrt(np.mean(np.concatenate(out) ** 2))) if out else float("nan")


def _delay_by_rate_contrast(ctx: Context) -> Finding | None:
    """A delay counted in samples, read off steps of one size at two sample rates
    (:func:`rate_pairs`): the slower run lags by as many more seconds as its samples are longer.
    A low-pass, a mode or a delay in seconds lags both alike, and the static map's misfit is the
    same in both, so the difference of their residuals (:func:`rate_contrast`) shows the delay
    alone where the fast runs' shape cannot tell it from the chain's bandwidth (third test press,
    a FIFO of 3 samples: the drive chain's low-pass refitted 1250 -> 810 Hz took the lag of the
    steps at 20 kHz as well as the delay did). The samples are fitted on the rises and judged on
    the falls."""
    m = ctx.model
    pairs = rate_pairs(ctx) if m.chain_samples - _bundle.SAMPLING_DELAY_SAMPLES >= MIN_CONTRAST_SAMPLES else []
    if not pairs:
        # the contrast checks what the chain identified from steps at two rates (fit) told: where
        # it read no more samples than the sampling's own, or told none, a contrast is an
        # unmodelled edge's (third test press: a coupling of the drive voltage, seed 1, 1.0 sample
        # and a held-out gain of 29 % where the chain read 2.23; a current limit, seed 14, whose
        # chain is a slew's and tells no samples, 1.6 samples and 78 %: the model slews the sampled
        # command, and its staircase lags by a part of a sample that depends on the rate)
        return None
    runs = [r for p in pairs for r in p]
    forces = _forces(m, runs)  # a delay changes only the reading
    edges = {id(r): _step_edges(r) for r in runs}  # found once: the search reads them at every trial
    gaps = [min(float(r.t_s[edges[id(r)][1]] - r.t_s[edges[id(r)][0]]) for r in p) for p in pairs]
    # the mode's ring-down (four time constants), within half the time between the edges
    window = min(0.5 * min(gaps), 4.0 / (m.zeta * m.wn) if m.wn and m.zeta else 0.02)
    slow = min(a.fs_hz for a, _ in pairs)
    n = _search(
        lambda k: rate_contrast(replace(m, delay_samples=m.delay_samples + k), pairs, 0, window, forces, edges),
        0.0,
        5e-3 * slow,
        41,
    )
    if n < MIN_CONTRAST_SAMPLES or n / slow <= CHAIN_LAG_S:
        return None
    ext = replace(m, delay_samples=m.delay_samples + n)
    cut = {id(r): int(edges[id(r)][1]) - int(5e-4 * r.fs_hz) for r in runs}  # half a millisecond before the fall
    held = [(r, slice(cut[id(r)], None)) for r in runs]
    fit = [(r, slice(0, cut[id(r)])) for r in runs]
    at = ", ".join(f"{1e6 * n / r:.3g} us at {r / 1e3:g} kHz" for r in sorted({r.fs_hz for r in runs}))
    names = "; ".join(f"{a.name} and {b.name}" for a, b in pairs)
    ev = (
        f"steps of one size at two sample rates ({names}) lag each other by {n:.2g} samples more than the "
        f"model draws ({at}): a delay counted in samples (a board's FIFO, a converter's filter), which a "
        "low-pass or a mode of the chain, lagging both alike in seconds, cannot explain (fitted on the rises, "
        "judged on the falls)"
    )

    def cost(segments, model):
        held_pairs = [(a, b) for a, b in pairs if {id(a), id(b)} <= {id(r) for r, _ in segments}]
        return rate_contrast(model, held_pairs, 1, window, forces, edges) if held_pairs else float("nan")

    f = _judge(ctx, "input_delay", ev, fit, held, ext, {"delay_samples": n, "delay_s": n / slow}, m, cost=cost)
    return replace(f, gain_by_run={})  # judged on pairs of runs, never on one alone


def _judge_samples(ctx: Context, fit, held, ext, n: float, base, rates: list[float], moved: str = "") -> Finding | None:
    """The finding of a delay of ``n`` samples at every rate (what each run's rate makes of it),
    read in time at the steps' slowest rate, where it is longest (the rate of the first step
    before stop 93, which the order of the steps decided)."""
    steps = ctx.steps()
    fs = min(r.fs_hz for r in steps) if steps else rates[0]
    if n / fs <= CHAIN_LAG_S:
        return None  # no longer than the chain's own lag at the steps' slowest rate
    at = ", ".join(f"{1e3 * n / r:.3g} ms at {r / 1e3:g} kHz" for r in rates)
    ev = (
        f"the whole response lags the model by {n:.3g} samples at every sample rate ({at}): a delay counted "
        "in samples (a board's FIFO, a converter's filter) fits the runs of different rates better than one "
        f"delay in time{moved}"
    )
    found = _judge_dynamics(ctx, "input_delay", ev, fit, held, ext, {"delay_samples": n, "delay_s": n / fs}, base)
    beyond = n - ctx.model.delay_samples
    if found is None or beyond >= MIN_CONTRAST_SAMPLES:
        return found
    return replace(
        found,
        refused=(
            f"{beyond:.2g} samples beyond the model's, under {MIN_CONTRAST_SAMPLES:g}: a board's FIFO or a "
            "converter's latency is whole samples, and a fraction of one is the converters' timing, which every "
            "press leaves and the chain's low-pass and mode refitted with it take up"
        ),
    )


#: The catalogue's entry for this cause (read by every place that names causes).
def held_by_chain(model: Model) -> str:
    """The drive chain the base holds, the lag a delay is looked for beyond ('' where it holds none)."""
    parts = []
    if model.drive_lowpass is not None:
        wn, z = model.drive_lowpass
        parts.append(f"a {wn / (2 * np.pi) / 1e3:.3g} kHz low-pass (damping {z:.2g})")
    if model.drive_tau_s > 0:
        parts.append(f"a first-order lag of {model.drive_tau_s * 1e3:.3g} ms")
    if model.drive_delay_s > 0:
        at = (
            f" ({model.drive_delay_samples:.3g} samples at {model.drive_delay_rate_hz / 1e3:.3g} kHz)"
            if model.drive_delay_samples and model.drive_delay_rate_hz
            else ""
        )
        parts.append(f"a delay of {model.drive_delay_s * 1e3:.3g} ms{at}")
    return f"the drive chain identified on the steps, {' and '.join(parts)}" if parts else ""


CAUSE = Cause(
    "input_delay",
    "a pure delay between command and response (board latency, filters)",
    "the prediction delayed",
    cause_input_delay,
    needs=(
        Need((_FAST_STEPS, RunSpec("sweep", min_freq_hz=5.0)), 2, independent=True),
        Need((RunSpec("sweep", lag_visible=True),), 1),
    ),
    extend=_bundle.extend_input_delay,
    targets=("tracking_random", "hysteresis_50hz"),
    refits_mode=True,
    held=held_by_chain,
)
