"""The report's figures: the curves each figure draws, prepared from the runs and the
bundle (every metric from :mod:`piezopress.analysis.metrics`, as the tables); the drawing is
:mod:`piezopress.plotting`'s."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from piezopress import plotting, runformat, units
from piezopress.analysis import creep as creep_mod
from piezopress.analysis import hysteresis as H
from piezopress.analysis import metrics
from piezopress.errors import PiezopressError
from piezopress.pipelines import summary
from piezopress.pipelines.report_doc import FigureBlock
from piezopress.pipelines.report_inputs import _is_static_triangle, _Source

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
    c = metrics.creep(run.t_s, run.output, drive=drive)
    t_after = run.t_s - c.step_time_s
    i = _log_spaced(t_after)
    return plotting.Curve(t_after[i], (run.output[i] - c.baseline) / c.step_size,
                          f"{prefix}: {run.name} (creep {c.percent:.2f} %)")


def _step_curve(run: runformat.Run, drive: np.ndarray, **kw) -> plotting.Curve:
    s = metrics.overshoot(run.t_s, run.output, drive=drive, **kw)
    t_ms = (run.t_s - s.step_time_s) * 1e3
    w = (t_ms >= STEP_WINDOW_MS[0]) & (t_ms <= STEP_WINDOW_MS[1])
    return plotting.Curve(t_ms[w], (run.output[w] - s.baseline) / s.step_size,
                          f"{run.name}: {s.step_size:.0f} {units.label(run.output_unit)}, overshoot {s.percent:.1f} %")


def _figure_block(name: str, title: str, caption: str, fig) -> FigureBlock:
    return FigureBlock(name, title, caption, plotting.to_png(fig))


def _pick_loop_before(char: _Source) -> runformat.Run | None:
    static = [r for r in char.runs.values() if _is_static_triangle(r)]
    plain = [r for r in static if not r.meta.get("protocol", {}).get("peaks_v") and not r.meta.get("protocol", {}).get("random_peaks")]
    return (plain or static or [None])[0]


def _pick_loop_after(val: _Source) -> runformat.Run | None:
    static = [r for r in val.runs.values() if _is_static_triangle(r) and r.column("reference_n") is not None]
    preferred = val.runs.get("tri-300n-0.1hz")
    if preferred is not None and any(r is preferred for r in static):
        return preferred
    plain = [r for r in static if r.meta.get("protocol", {}).get("peaks_n") is None and r.meta.get("protocol", {}).get("random_peaks") is None]
    plain.sort(key=lambda r: -float(r.meta.get("protocol", {}).get("peak_n") or 0.0))
    return (plain or static or [None])[0]


def _loops_figure(char: _Source | None, val: _Source | None, missing: list[str]) -> FigureBlock | None:
    before = _pick_loop_before(char) if char else None
    after = _pick_loop_after(val) if val else None
    if char and before is None:
        missing.append("No 0.1 Hz triangle in the characterization: the uncompensated hysteresis loop is missing.")
    if val and after is None:
        missing.append("No compensated 0.1 Hz triangle in the validation: the compensated hysteresis loop is missing.")
    if before is None and after is None:
        return None
    fig = plotting.hysteresis_loops(
        plotting.Curve(before.command_v, before.output, before.name) if before else None,
        plotting.Curve(after.column("reference_n"), after.output, after.name) if after else None,
        before_title=f"Before: {before.name} (uncompensated)" if before else "",
        after_title=f"After: {after.name} (compensated)" if after else "",
        unit=(before or after).output_unit, after_unit=after.output_unit if after else None)
    q = units.quantity((before or after).output_unit)
    return _figure_block("hysteresis_loops", "Hysteresis loops, before and after",
                         f"Left: measured {q} against the drive, uncompensated. Right: measured {q} against the reference "
                         f"{q} with the compensation; the dashed line is a perfect press.", fig)


def _creep_figure(char: _Source | None, val: _Source | None, missing: list[str]) -> FigureBlock | None:
    before, after = [], []
    for src, out, prefix in ((char, before, "uncompensated"), (val, after, "compensated")):
        if src is None:
            continue
        runs = [r for r in src.runs.values() if r.kind == "creep"]
        if not runs:
            missing.append(f"No creep run in the {'characterization' if src is char else 'validation'}: the {prefix} creep curve is missing.")
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
    fig = plotting.creep_responses(before, after)
    return _figure_block("creep", "Creep, before and after",
                         "Force after the step, relative to the step (F_0 before the step, F_ss 1 s after it), on a log time axis: "
                         "uncompensated creep keeps rising above 1, compensated creep stays at 1.", fig)


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
    return _figure_block("steps", "Step responses",
                         "Force relative to the step against time from the step. Left: the characterization's voltage steps, "
                         "uncompensated (no shaper). Right: the validation's force steps, compensated (shaper + inverse models); "
                         "the centred shaper starts them slightly before the reference's step.", fig)


def _tracking_figure(val: _Source | None, missing: list[str]) -> FigureBlock | None:
    if val is None:
        return None
    runs = [r for r in val.runs.values() if r.kind == "staircase" and r.column("reference_n") is not None]
    if not runs:
        missing.append("No staircase run in the validation: the tracking figure and the controlled tracking error are missing.")
        return None
    r = runs[0]
    ref, y = r.column("reference_n"), r.output
    err = y - ref
    evaluated = None
    preload = float(r.meta.get("preload_n", ref[0]))
    try:
        tr = metrics.tracking_error(r.t_s, ref - preload, y - preload, min_reference=summary.TRACKING_MIN_REFERENCE_N)
        evaluated = np.where(tr.mask, err, np.nan)
    except PiezopressError as exc:
        missing.append(f"{r.name}: the tracking metric does not suit it ({exc}); the full error is drawn.")
    fig = plotting.tracking(r.t_s, ref, y, err, evaluated, title=f"Staircase tracking: {r.name} (compensated)", unit=r.output_unit)
    return _figure_block("tracking", "Staircase tracking",
                         f"Reference and measured force; below, the error. The relative error is evaluated on the plateaus "
                         f"(outside the ramps) from {summary.TRACKING_MIN_REFERENCE_N:g} N above the preload up.", fig)


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
            runs.append(runformat.read_run(f))
        else:
            missing.append(f"Hysteresis fitting run {name!r} is neither in the characterization given nor at {entry.get('file')} "
                           "(unchanged): its model residuals are missing.")
    return runs


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def _residuals_figure(bundle: dict[str, Any] | None, char: _Source | None, missing: list[str]) -> FigureBlock | None:
    if bundle is None:
        return None
    model = H.PIModel.from_dict(bundle["hysteresis"]["model"])
    cm = None
    if bundle["hysteresis"].get("creep_removed") and "creep" in bundle:
        cm = creep_mod.CreepModel.from_dict(bundle["creep"]["model"])
    raw, other = [], []
    unit = units.label(bundle["hysteresis"]["model"].get("output_unit", units.FORCE))
    for r in _fitting_runs(bundle, char, missing):
        pred, _ = model.forward(r.command_v)
        res = r.output - pred
        raw.append(plotting.Curve(r.t_s, res, f"{r.name} (RMS {_rms(res):.2f} {unit})"))
        if cm is not None:
            # the fit saw the sweeps with the creep compensator applied (piezopress.pipelines.fit): the same here
            _, rest = H.rest_offset(r.command_v, r.output)
            no_creep = rest + cm.compensate(r.output - rest, r.sample_rate_hz)[0] - pred
            other.append(plotting.Curve(r.t_s, no_creep, f"{r.name} (RMS {_rms(no_creep):.2f} {unit})"))
        else:
            other.append(plotting.Curve(r.command_v, res, ""))
    if not raw:
        return None
    if cm is not None:
        fig = plotting.model_residuals(raw, other, unit=unit, left_title="measured, as recorded",
                                       right_title="creep removed, as the fit saw it",
                                       title="Hysteresis model: measured minus predicted, on its fitting runs")
        note = (" The model was fitted on the sweeps with the creep removed (the creep model's compensator applied first): "
                "left, the raw measurement, whose residual holds the creep; right, what the fit saw.")
    else:
        fig = plotting.model_residuals(raw, other, unit=unit, left_title="against time", right_title="against the drive",
                                       right_xlabel="drive command_v (V)",
                                       title="Hysteresis model: measured minus predicted, on its fitting runs")
        note = ""
    return _figure_block("model_residuals", "Hysteresis model residuals",
                         "Measured output minus the hysteresis model's prediction from the drive, on the runs it was fitted on." + note, fig)

