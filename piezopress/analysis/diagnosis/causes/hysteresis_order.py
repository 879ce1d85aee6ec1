"""The catalogue's cause ``hysteresis_order``: its fit (the signature it keys on, the extension judged
on held-out data) and its entry in the catalogue (:data:`CAUSE`)."""

from __future__ import annotations

from dataclasses import replace

from piezopress.analysis import bundle as _bundle
from piezopress.analysis import hysteresis as H
from piezopress.analysis import profile
from piezopress.analysis.diagnosis.cause import Cause
from piezopress.analysis.diagnosis.judging import Context, Finding, _judge
from piezopress.analysis.diagnosis.model import RunData
from piezopress.analysis.diagnosis.needs import Need, RunSpec

#: The last operator fits of :func:`cause_hysteresis_order` (the greedy search asks again after
#: every finding; the fits change only with the sweeps, the operators, the creep and the drift).
_ORDER_MEMO: dict[tuple, tuple[list[RunData], tuple]] = {}


def cause_hysteresis_order(ctx: Context) -> Finding | None:
    sweeps = ctx.sweeps(0.0, ctx.slow_hz)
    if not sweeps:
        return None
    m = ctx.model.hysteresis
    key = (
        tuple(id(r) for r in sweeps),
        m,
        ctx.model.creep,
        ctx.model.drift_per_s,
        ctx.model.drift_warmup,
        ctx.model.drift_clock,
    )
    hit = _ORDER_MEMO.get(key)
    if hit is not None and all(a is b for a, b in zip(hit[0], sweeps)):
        data, own, rich_fit = hit[1]  # the same fits as in the search's earlier rounds
    else:
        outs = []
        for r in sweeps:
            y = r.y - ctx.model.drift(r)  # an accepted drift removed, and the creep, as the fit does
            if ctx.model.creep is not None:
                y = m.y0 + ctx.model.creep.compensate(y - m.y0, r.fs_hz)[0]
            outs.append((r.name, r.x, y))
        data = H.prepare(outs, holdout_fraction=0.4, x0=m.x0, y0=m.y0)
        try:
            # the baseline is the base's own operators (the thresholds its fit kept) with their
            # weights fitted again on the same data: a candidate of as many evenly spaced plays as
            # the base kept is another, coarser grid (the thesis's 12 plays pruned to 7 are spaced
            # as 12, not as 7), and its misfit was counted as the gain of more operators (second
            # test press, slew + drift: 24 % against 7 % beside the base's own plays, named on
            # every seed; clean: 11 % against 5 %)
            own = H.refit(data, m)
            # more operators, not another family: a Bouc-Wen loop that Duhem elements draw and the
            # thesis's plays do not is the press's family, not an order the base misses (with the
            # elements in this search, it was named on every clean seed of the second test press)
            rich_fit = H.fit_hysteresis(data, refit_all=False, duhem_family=False)
        except H.HysteresisFitError:
            return None
        _ORDER_MEMO.clear()
        _ORDER_MEMO[key] = (list(sweeps), (data, own, rich_fit))
    fit = [(r, data.train[i]) for i, r in enumerate(sweeps)]
    held = [(r, data.holdout[i]) for i, r in enumerate(sweeps)]
    # the richer model measures what the base model measures (a displacement model must not be
    # taken for a force and clipped at 0 N; ``own``, refitted from the base, keeps its units)
    rich = replace(rich_fit.model, input_unit=m.input_unit, output_unit=m.output_unit)
    cells = (
        f" and a Preisach plane of {rich.plane.n_cells} cells"
        if rich.plane is not None
        else f" and {rich.duhem.n_cells} Duhem elements"
        if rich.duhem is not None
        else ""
    )
    ev = (
        f"on the slow sweeps the residual follows the drive level: {rich.n_play} plays and {rich.n_dead_zone} dead "
        f"zones{cells} (chosen on "
        f"held-out data) capture asymmetry and saturation that {len(m.r)} plays and {len(m.d)} dead zones miss"
    )
    return _judge(
        ctx,
        "hysteresis_order",
        ev,
        fit,
        held,
        replace(ctx.model, hysteresis=rich),
        {"n_play": rich.n_play, "n_dead_zone": rich.n_dead_zone},
        replace(ctx.model, hysteresis=own),  # refit keeps the base's units
    )


#: The catalogue's entry for this cause (read by every place that names causes).
CAUSE = Cause(
    "hysteresis_order",
    "asymmetry or saturation the fitted operator set cannot represent",
    "more play and dead-zone operators, chosen on held-out data",
    cause_hysteresis_order,
    needs=(Need((RunSpec("sweep", max_freq_hz=profile.QUASI_STATIC_MAX_HZ),), 1, model=("operators",)),),
    extend=_bundle.extend_hysteresis_order,
    targets=("static_hysteresis", "tracking_staircase", "tracking_random"),
)
