"""The report's figures: the curves each figure draws, prepared from the runs and the
bundle (every metric from :mod:`piezopress.analysis.metrics`, as the tables); the drawing is
:mod:`piezopress.plotting`'s."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from piezopress import plotting, runformat, units
from piezopress.analysis import hysteresis as H
from piezopress.analysis import metrics, profile
from piezopress.analysis.bundle import Bundle
from piezopress.errors import PiezopressError
from piezopress.pipelines import summary
from piezopress.pipelines.profiles import read_measured
from piezopress.pipelines.report_doc import FigureBlock
from piezopress.pipelines.report_inputs import _freq, _is_static_triangle, _Source

#: Step figures: window around the step (ms).
STEP_WINDOW_MS = (-3.0, 15.0)
#: Creep figure: at most this many points per curve, spaced evenly in log time.
CREEP_POINTS = 3000


# --------------------------------------------------------------------------- figures: the curves to draw


def _log_spaced(t_after: np.ndarray, n: int = CREEP_POINTS) -> np.ndarray:
    """Indices of samples after the step (t > 0), at most ``n``, evenly spaced in log time."""
    idx = np.flatnonzero(t_after > 0)
    if idx.size > n:
        idx = idx[np.unique(np.geomspace(1, idx.size, n).astype(int) - 1)]
    return idx


def _creep_curve(run: runformat.Run, drive: np.ndarray, prefix: str) -> plotting.Curve:
    """The creep from F_ss on (``t_ss_s`` after the step), relative to the step (%)."""
    c = metrics.creep(run.t_s, run.output, drive=drive)
    t_after = run.t_s - c.step_time_s
    i = _log_spaced(t_after)
    i = i[t_after[i] >= c.t_ss_s]
    return plotting.Curve(
        t_after[i],
        100.0 * (run.output[i] - c.steady_state) / c.step_size,
        f"{prefix}: {run.name} (creep {c.percent:.2f} % after {c.hold_s:.0f} s)",
    )


def _step_curve(run: runformat.Run, drive: np.ndarray, **kw) -> plotting.Curve:
    s = metrics.overshoot(run.t_s, run.output, drive=drive, **kw)
    t_ms = (run.t_s - s.step_time_s) * 1e3
    w = (t_ms >= STEP_WINDOW_MS[0]) & (t_ms <= STEP_WINDOW_MS[1])
    return plotting.Curve(
        t_ms[w],
        (run.output[w] - s.baseline) / s.step_size,
        f"{run.name}: {s.step_size:.0f} {units.label(run.output_unit)}, overshoot {s.percent:.1f} %",
    )


def _figure_block(name: str, title: str, caption: str, fig) -> FigureBlock:
    return FigureBlock(name, title, caption, plotting.to_png(fig))


def _span(run: runformat.Run) -> float:
    """The measured span of a run's reference (or drive): the size of its test."""
    p = profile.of(run)
    return p.high - p.low


def _pick_loop_before(char: _Source) -> runformat.Run | None:
    static = [r for r in char.runs.values() if _is_static_triangle(r)]
    plain = [r for r in static if not profile.of(r).varying_amplitude]
    return (plain or static or [None])[0]


def _slowest_sweep(char: _Source) -> runformat.Run | None:
    """The slowest sweep of any frequency (a record from elsewhere: a 1 Hz sine, say)."""
    sweeps = [r for r in char.runs.values() if profile.of(r).is_sweep and profile.of(r).freq_hz]
    return min(sweeps, key=lambda r: profile.of(r).freq_hz, default=None)


def _pick_loop_after(val: _Source) -> runformat.Run | None:
    static = [r for r in val.runs.values() if _is_static_triangle(r) and r.column("reference_n") is not None]
    preferred = val.runs.get("tri-300n-0.1hz")
    if preferred is not None and any(r is preferred for r in static):
        return preferred
    plain = [r for r in static if not profile.of(r).varying_amplitude]
    plain.sort(key=lambda r: -_span(r))
    return (plain or static or [None])[0]


def _hysteresis_model(bundle: dict[str, Any] | None, missing: list[str]) -> H.PIModel | None:
    if bundle is None or "hysteresis" not in bundle:
        return None
    try:
        return Bundle.from_dict(bundle).hysteresis
    except (PiezopressError, KeyError, TypeError) as exc:
        missing.append(f"The bundle's hysteresis model is unreadable ({exc}): the model's loop is missing.")
        return None


def _straight_line_deviation(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``y`` minus the straight line through the loop's lowest and highest drive: the loop's width."""
    lo, hi = int(np.argmin(x)), int(np.argmax(x))
    if x[hi] == x[lo]:
        return y - y[lo]
    return y - (y[lo] + (x - x[lo]) * (y[hi] - y[lo]) / (x[hi] - x[lo]))


def _before_panel(run: runformat.Run, model: H.PIModel | None, start: int = 0) -> plotting.LoopPanel:
    """The measured loop and the model over it, from row ``start`` (the rows the fit judged: a
    start of unknown state, a rest the fit skipped, is left out of the plot and the figures)."""
    u = units.label(run.output_unit)
    s = min(max(int(start), 0), max(run.output.size - 20, 0))
    x, y = run.command_v[s:], run.output[s:]
    model_curve = None
    if model is not None:
        pred = model.forward(run.command_v)[0][s:]  # the model's state carried through the skipped start
        model_curve = plotting.Curve(x, pred, f"model (RMS {_rms(y - pred):.3g} {u})")
    h = metrics.max_hysteresis(x, y)
    skipped = f", from row {s}: the start the fit skipped left out" if s else ""
    return plotting.LoopPanel(
        f"Before: {run.name} (uncompensated, {h.percent:.2f} %{skipped})",
        plotting.Curve(x, y, "measured"),
        plotting.Curve(x, _straight_line_deviation(x, y)),
        "drive command_v (V)",
        f"measured - straight line ({u})",
        model=model_curve,
    )


def _after_panel(run: runformat.Run, title: str | None = None) -> plotting.LoopPanel:
    ref = run.column("reference_n")
    u = units.label(run.output_unit)
    try:
        pct = f", {metrics.max_hysteresis(ref, run.output).percent:.2f} %"
    except PiezopressError:
        pct = ""
    return plotting.LoopPanel(
        title or f"After: {run.name} (compensated{pct})",
        plotting.Curve(ref, run.output, "measured"),
        plotting.Curve(ref, run.output - ref),
        f"reference ({u})",
        f"measured - reference ({u})",
        ideal=True,
        compensated=True,
    )


def _loops_figure(
    char: _Source | None, val: _Source | None, missing: list[str], bundle: dict[str, Any] | None = None
) -> FigureBlock | None:
    before = _pick_loop_before(char) if char else None
    after = _pick_loop_after(val) if val else None
    title = "Hysteresis loops (0.1 Hz triangles), before and after"
    if char and before is None:
        before = _slowest_sweep(char)
        if before is None:
            missing.append("No sweep in the characterization: the uncompensated hysteresis loop is missing.")
        else:
            f = profile.of(before).freq_hz
            title = f"Hysteresis loop of {before.name} ({f:.3g} Hz {before.kind}: no 0.1 Hz triangle in the runs)"
    if val and after is None:
        missing.append("No compensated 0.1 Hz triangle in the validation: the compensated hysteresis loop is missing.")
    if before is None and after is None:
        return None
    model = _hysteresis_model(bundle, missing) if before is not None else None
    start = 0
    if model is not None and before is not None:
        rows = Bundle.from_dict(bundle).judged_rows(
            runformat.sha256_file(before.path) if before.path is not None else None, before.name
        )
        start = rows[0] if rows is not None else 0
    panels = ([_before_panel(before, model, start)] if before else []) + ([_after_panel(after)] if after else [])
    unit = (before or after).output_unit
    fig = plotting.loops_with_error(panels, unit=unit, title=title)
    q, u = units.quantity(unit), units.label(unit)
    return _figure_block(
        "hysteresis_loops",
        "Hysteresis loops, before and after",
        f"Left: measured {q} against the drive, uncompensated, with the fitted hysteresis model dashed over it "
        f"(look for the dashed line to stay on the loop); below it the loop's width, measured minus the straight "
        f"line through its ends. Right: measured {q} against the reference with the compensation; the dashed line "
        f"is a perfect press, and below it the error measured - reference ({u}) on its own zoomed scale: what "
        f"remains of the loop.",
        fig,
    )


def _frequency_loops_figure(val: _Source | None, missing: list[str]) -> FigureBlock | None:
    """Compensated loops at every validated triangle frequency (the plain triangles, one per frequency)."""
    if val is None:
        return None
    by_freq: dict[float, runformat.Run] = {}
    for r in val.runs.values():
        f = _freq(r)
        if r.kind != "triangle" or f is None or r.column("reference_n") is None or profile.of(r).varying_amplitude:
            continue
        f = float(f"{f:.3g}")  # one panel per frequency, measured to three digits
        best = by_freq.get(f)
        if best is None or _span(r) > _span(best):
            by_freq[f] = r
    if len(by_freq) < 2:
        missing.append(
            "Fewer than two triangle frequencies in the validation: the loops across frequencies are missing."
        )
        return None
    panels = []
    for f in sorted(by_freq):
        r = by_freq[f]
        try:
            pct = f"{metrics.max_hysteresis(r.column('reference_n'), r.output).percent:.2f} %"
        except PiezopressError:
            pct = "n/a"
        panels.append(_after_panel(r, f"{f:g} Hz: {r.name}\nhysteresis {pct}"))
    unit = next(iter(by_freq.values())).output_unit
    fig = plotting.loops_with_error(panels, unit=unit, title="Compensated loops at every validated frequency")
    return _figure_block(
        "loops_by_frequency",
        "Compensated loops at every validated frequency",
        "Each column one validated triangle frequency: measured against reference (top, dashed: a perfect "
        f"press) and the error measured - reference ({units.label(unit)}) below, each on its own scale. Look at "
        "how the error loop opens with frequency: the inverse hysteresis model is rate-independent, fitted "
        "on 0.1 Hz sweeps, so the fastest rows are the weakest controlled figures. A drop at the top of a loop is "
        "where the drive was clipped at the actuator's limit (see the warnings).",
        fig,
    )


def _creep_figure(char: _Source | None, val: _Source | None, missing: list[str]) -> FigureBlock | None:
    before, after = [], []
    for src, out, prefix in ((char, before, "uncompensated"), (val, after, "compensated")):
        if src is None:
            continue
        runs = [r for r in src.runs.values() if r.kind == "creep"]
        if not runs:
            missing.append(
                f"No creep run in the {'characterization' if src is char else 'validation'}: the {prefix} creep curve "
                "is missing."
            )
        for r in runs:
            drive = r.command_v if src is char else r.column("reference_n")
            if drive is None:
                missing.append(f"{r.name}: no reference_n column; its compensated creep curve is missing.")
                continue
            try:
                out.append(_creep_curve(r, drive, prefix))
            except PiezopressError as exc:
                missing.append(f"{r.name}: does not suit the creep figure ({exc}).")
    if not before and not after:
        return None
    fig = plotting.creep_relative(before, after, t_ss_s=min(float(c.x[0]) for c in before + after if c.x.size))
    return _figure_block(
        "creep",
        "Creep, before and after",
        "The force after F_ss (taken 1 s after the step) relative to the step size, (F - F_ss) / (F_ss - F_0) in %, "
        "on a "
        "log time axis: the creep metric is this curve's value at the end of the hold. Uncompensated, it rises "
        "steadily per decade of time; compensated, it should stay on the zero line (the uncompensated run's drive "
        "is a voltage step, the compensated run's reference a force step).",
        fig,
    )


def _steps_figure(char: _Source | None, val: _Source | None, missing: list[str]) -> FigureBlock | None:
    unc, comp = [], []
    if char is not None:
        steps = [r for r in char.runs.values() if r.kind == "step"]
        if not steps:
            missing.append("No step run in the characterization: the uncompensated step responses are missing.")
        for r in steps:
            try:
                unc.append(_step_curve(r, r.command_v))
            except PiezopressError as exc:
                missing.append(f"{r.name}: does not suit the step figure ({exc}).")
    if val is not None:
        steps = [r for r in val.runs.values() if r.kind == "step" and r.column("reference_n") is not None]
        if not steps:
            missing.append("No compensated step run in the validation: the compensated step responses are missing.")
        for r in steps:
            try:
                comp.append(_step_curve(r, r.column("reference_n"), end_margin_s=summary.STEP_END_MARGIN_S))
            except PiezopressError as exc:
                missing.append(f"{r.name}: does not suit the step figure ({exc}).")
    if not unc and not comp:
        return None
    fig = plotting.step_responses(unc, comp)
    return _figure_block(
        "steps",
        "Step responses",
        "Force relative to the step against time from the step. Left: the characterization's voltage steps, "
        "uncompensated (no shaper). Right: the validation's force steps, compensated (shaper + inverse models); "
        "the centred shaper starts them slightly before the reference's step.",
        fig,
    )


def _stairs(ref: np.ndarray, err: np.ndarray, mask: np.ndarray, preload: float) -> list[plotting.Stair]:
    """One :class:`~piezopress.plotting.Stair` per evaluated stretch of ``mask`` (a plateau's evaluated part)."""
    out = []
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return out
    breaks = np.flatnonzero(np.diff(idx) > 1)
    for seg in np.split(idx, breaks + 1):
        e = err[seg]
        out.append(
            plotting.Stair(float(np.median(ref[seg]) - preload), float(np.mean(e)), float(np.min(e)), float(np.max(e)))
        )
    return out


def _tracking_figure(val: _Source | None, missing: list[str]) -> FigureBlock | None:
    if val is None:
        return None
    runs = [r for r in val.runs.values() if r.kind == "staircase" and r.column("reference_n") is not None]
    if not runs:
        missing.append(
            "No staircase run in the validation: the tracking figure and the controlled tracking error are missing."
        )
        return None
    r = runs[0]
    ref, y = r.column("reference_n"), r.output
    err = y - ref
    stairs: list[plotting.Stair] = []
    preload = float(r.meta.get("preload_n", ref[0]))
    try:
        tr = metrics.tracking_error(r.t_s, ref - preload, y - preload, min_reference=summary.TRACKING_MIN_REFERENCE_N)
        stairs = _stairs(ref, err, tr.mask, preload)
    except PiezopressError as exc:
        missing.append(f"{r.name}: the tracking metric does not suit it ({exc}); its stairs are not evaluated.")
    fig = plotting.tracking_stairs(
        r.t_s,
        ref,
        y,
        stairs,
        title=f"Staircase tracking: {r.name} (compensated)",
        unit=r.output_unit,
        evaluated_from=summary.TRACKING_MIN_REFERENCE_N,
    )
    u = units.label(r.output_unit)
    return _figure_block(
        "tracking",
        "Staircase tracking",
        f"Top: reference and measured {units.quantity(r.output_unit)}. Bottom: per stair (its reference above the "
        f"preload) the mean error measured - reference ({u}) where the metric evaluates it (the plateaus, outside "
        f"the ramps, from {summary.TRACKING_MIN_REFERENCE_N:g} {u} above the preload up), whiskers from its minimum "
        "to its maximum: look for bars that grow with the stair (a gain error) or one stair apart (a local misfit).",
        fig,
    )


def _fitting_runs(bundle: dict[str, Any], char: _Source | None, missing: list[str]) -> list[runformat.Run]:
    """The bundle's hysteresis runs: from the characterization, else from the files the bundle names (same sha256)."""
    runs = []
    for entry in bundle.get("hysteresis", {}).get("runs", []):
        name = entry.get("name")
        if char is not None and name in char.runs:
            runs.append(char.runs[name])
            continue
        f = Path(entry.get("file") or "")
        if entry.get("file") and f.is_file() and runformat.sha256_file(f) == entry.get("sha256"):
            runs.append(read_measured(f))
        else:
            missing.append(
                f"Hysteresis fitting run {name!r} is neither in the characterization given nor at {entry.get('file')} "
                "(unchanged): its model residuals are missing."
            )
    return runs


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def _residuals_figure(bundle: dict[str, Any] | None, char: _Source | None, missing: list[str]) -> FigureBlock | None:
    if bundle is None:
        return None
    checked = Bundle.from_dict(bundle)
    model = checked.hysteresis
    cm = checked.creep if bundle["hysteresis"].get("creep_removed") else None
    raw, other = [], []
    unit = units.label(bundle["hysteresis"]["model"].get("output_unit", units.FORCE))
    for r in _fitting_runs(bundle, char, missing):
        pred, _ = model.forward(r.command_v)
        res = r.output - pred
        raw.append(plotting.Curve(r.t_s, res, f"{r.name} (RMS {_rms(res):.2f} {unit})"))
        if cm is not None:
            # the fit saw the sweeps with the creep compensator applied (piezopress.pipelines.fit): the same here
            no_creep = checked.remove_creep(r) - pred
            other.append(plotting.Curve(r.t_s, no_creep, f"{r.name} (RMS {_rms(no_creep):.2f} {unit})"))
        else:
            other.append(plotting.Curve(r.command_v, res, ""))
    if not raw:
        return None
    holdout = float(bundle["hysteresis"].get("fit", {}).get("holdout_fraction", 0.0) or 0.0)
    rows = []
    for left, right in zip(raw, other):
        res = [left.y, right.y]
        lim = _clip_level(res)
        t0, t1 = float(left.x[0]), float(left.x[-1])
        spans = ((t1 - holdout * (t1 - t0), t1, f"held out ({100 * holdout:g} %)"),) if holdout > 0 else ()
        rows.append(
            plotting.ResidualRow(
                left.label.split(" (")[0],
                [_clipped(left, lim)],
                [_clipped(right, lim)],
                lim,
                _clip_note([left.y], lim, unit),
                _clip_note([right.y], lim, unit),
                spans,
                spans_right=cm is not None,
            )
        )
    if cm is not None:
        fig = plotting.residual_traces(
            rows,
            unit=unit,
            left_title="measured, as recorded",
            right_title="creep removed, as the fit saw it",
            xlabel="time (s)",
            title="Hysteresis model: measured minus predicted, on its fitting runs",
        )
        note = (
            " The model was fitted on the sweeps with the creep removed (the creep model's compensator applied first): "
            "left, the raw measurement, whose residual holds the creep (the sawtooth); right, what the fit saw."
        )
    else:
        fig = plotting.residual_traces(
            rows,
            unit=unit,
            left_title="against time",
            right_title="against the drive",
            xlabel="time (s) | drive command_v (V)",
            title="Hysteresis model: measured minus predicted, on its fitting runs",
        )
        note = ""
    return _figure_block(
        "model_residuals",
        "Hysteresis model residuals",
        "Measured output minus the hysteresis model's prediction from the drive, one row per run it was fitted "
        "on; the shaded end of each run was held out of the fit that chose the model's structure (look for a "
        "residual there no larger than before it: the model predicts, it does not only fit). Spikes are clipped "
        "where a panel says so." + note,
        fig,
    )


def _clip_level(residuals: list[np.ndarray]) -> float:
    """Residuals are drawn within ``diagnose.CLIP_MARGIN`` x their ``CLIP_PERCENTILE``th
    percentile (the diagnosis's rule): one spike would otherwise flatten the trace."""
    from piezopress.pipelines.diagnose import CLIP_MARGIN, CLIP_PERCENTILE

    both = np.abs(np.concatenate(residuals))
    lim = CLIP_MARGIN * float(np.percentile(both, CLIP_PERCENTILE)) if both.size else 1.0
    return lim if lim > 0 else max(float(both.max()) if both.size else 1.0, 1e-12)


def _clipped(c: plotting.Curve, lim: float) -> plotting.Curve:
    return plotting.Curve(c.x, np.clip(c.y, -lim, lim), c.label)


def _clip_note(residuals: list[np.ndarray], lim: float, unit: str) -> str:
    n, total = sum(int(np.count_nonzero(np.abs(e) > lim)) for e in residuals), sum(e.size for e in residuals)
    return f"{n} of {total} samples beyond ±{lim:.3g} {unit} clipped" if n else ""


def _drive_figure(val: _Source | None, missing: list[str]) -> FigureBlock | None:
    """The compensated drive beside the reference: one triangle (the largest plain 0.1 Hz
    one) and one step (the largest), the step zoomed on its edge."""
    if val is None:
        return None
    tri = _pick_loop_after(val)
    steps = [r for r in val.runs.values() if r.kind == "step" and r.column("reference_n") is not None]
    steps.sort(key=lambda r: -(profile.of(r).step_size or 0.0))
    panels = []
    if tri is not None:
        panels.append(
            plotting.DrivePanel(
                f"{tri.name}: triangle", tri.t_s, tri.column("reference_n"), tri.command_v, measured=tri.output
            )
        )
    if steps:
        r = steps[0]
        ref = r.column("reference_n")
        try:
            t_step = metrics.overshoot(r.t_s, r.output, drive=ref, end_margin_s=summary.STEP_END_MARGIN_S).step_time_s
        except PiezopressError:
            t_step = float(r.t_s[int(np.argmax(np.diff(ref))) + 1])
        t_ms = (r.t_s - t_step) * 1e3
        w = (t_ms >= STEP_WINDOW_MS[0]) & (t_ms <= STEP_WINDOW_MS[1])
        panels.append(
            plotting.DrivePanel(f"{r.name}: step, around its edge", t_ms[w], ref[w], r.command_v[w], "ms", r.output[w])
        )
    if not panels:
        missing.append("No compensated triangle or step in the validation: the compensated drive figure is missing.")
        return None
    unit = (tri or steps[0]).output_unit
    return _figure_block(
        "compensated_drive",
        "The compensated drive beside its reference",
        "What the compensator sends to the amplifier (drive, right axis, V) for a reference (dashed, left axis), "
        "with the measured output. Look for the drive's shape: on the triangle, the inverse hysteresis bends each "
        "branch and jumps at the reversals; on the step, the rate limit ramps it and the shaper splits it into "
        "stairs a fraction of a millisecond apart, centred on the reference's edge so the press is not late.",
        plotting.drive_and_reference(panels, unit=unit, title="Compensated drive and reference"),
    )
