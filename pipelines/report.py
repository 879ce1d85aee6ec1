"""The report: characterization, validation and model quality beside the thesis, in one place.

``build_report`` reads what it is given (a characterization directory, a validation
directory, a bundle; each optional), takes every figure from the tables of
:mod:`piezopress.pipelines.summary` (nothing is measured differently here), prepares the curves of the
figures and lays out the document; ``write_report`` writes it into a new directory:

- ``metrics.csv``: long format, one row per figure (``table,test,metric,unit,value,thesis,
  thesis_source``): the Table 6.13 summary first, then every characterization row (tables
  5.1-5.3) and every validation row (6.6, 6.5, 6.9, 6.11/6.12, 6.6-tracking). Numbers as
  ``%.6g``, rows in run order, no timestamps: the same inputs give the same bytes.
- ``report.md`` and ``report.html`` (one self-contained page: figures as data URIs,
  inline CSS, no script), with the same content;
- the figures as PNG.

A missing input, run or section gives a line saying what is missing and how to get it,
never a crash. The figures are drawn by :mod:`piezopress.plotting`.
"""

from __future__ import annotations

import base64
import csv
import html
import io
import math
import os
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np
import pandas as pd

from piezopress import plotting, runformat, thesis, units
from piezopress.analysis import diagnosis as dg
from piezopress.analysis import metrics
from piezopress.errors import OutputExistsError, PiezopressError
from piezopress.pipelines import summary
from piezopress.pipelines.bundle import read_document
from piezopress.analysis.bundle import Bundle
from piezopress.pipelines.files import MANIFEST, keep_previous, read_manifest, run_files, writable_folder

COLUMNS = ["table", "test", "metric", "unit", "value", "thesis", "thesis_source"]
#: The quasi-static triangles of Table 6.13 (and the hysteresis loops) are those at this frequency (Hz).
STATIC_FREQ_HZ = 0.1
#: The uncontrolled overshoot of Table 6.13 is the step of this drive (V), thesis 25.92 %.
UNCONTROLLED_STEP_V = 20.0
#: Step figures: window around the step (ms).
STEP_WINDOW_MS = (-3.0, 15.0)
#: Creep figure: at most this many points per curve, spaced evenly in log time.
CREEP_POINTS = 3000
#: Files a report directory holds; a directory holding one of them is a report (``--replace``).
REPORT_FILES = ("metrics.csv", "report.md", "report.html")
#: Number format of metrics.csv.
CSV_FLOAT = "%.6g"


class ReportError(PiezopressError, ValueError):
    """The report's inputs or output directory are unusable."""


# --------------------------------------------------------------------------- document model


@dataclass(frozen=True)
class Heading:
    text: str
    level: int = 2


@dataclass(frozen=True)
class Para:
    text: str


@dataclass(frozen=True)
class Bullets:
    items: tuple[str, ...]


@dataclass(frozen=True)
class Table:
    header: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    #: per column: "l" or "r"
    align: tuple[str, ...] = ()


@dataclass(frozen=True)
class FigureBlock:
    name: str
    title: str
    caption: str
    png: bytes = field(repr=False)

    @property
    def file(self) -> str:
        return f"{self.name}.png"


Block = Heading | Para | Bullets | Table | FigureBlock


@dataclass
class Report:
    """Everything ``write_report`` writes; ``markdown()``/``html()`` render the same blocks."""

    metrics: pd.DataFrame
    comparison: Table
    blocks: list[Block]
    missing: list[str]

    @property
    def figures(self) -> list[FigureBlock]:
        return [b for b in self.blocks if isinstance(b, FigureBlock)]

    def metrics_csv(self) -> str:
        return metrics_csv(self.metrics)

    def comparison_markdown(self) -> str:
        return _md_table(self.comparison)

    def markdown(self) -> str:
        return render_markdown(self.blocks)

    def html(self) -> str:
        return render_html(self.blocks)


@dataclass(frozen=True)
class ReportResult:
    report: Report
    out_dir: Path
    files: tuple[Path, ...]
    previous: Path | None = None

    @property
    def html_path(self) -> Path:
        return self.out_dir / "report.html"


# --------------------------------------------------------------------------- inputs


@dataclass
class _Source:
    """One run directory: its table (from piezopress.pipelines.summary) and its runs by name."""

    path: Path
    table: pd.DataFrame
    runs: dict[str, runformat.Run]
    shaper: bool = True


def _load_dir(path: str | Path, what: str, command: str, table_of: Callable[[Path], pd.DataFrame]) -> _Source:
    path = Path(path)
    if not path.is_dir():
        raise ReportError(f"{path}: no such directory; expected a {what} run directory (from `piezopress {command}`)")
    files = run_files(path)
    runs: dict[str, runformat.Run] = {}
    for f in files:
        r = runformat.read_run(f)
        runs[r.name] = r
    table = table_of(path) if files else pd.DataFrame(columns=summary.COLUMNS)
    shaper = True
    if (path / MANIFEST).is_file():
        shaper = bool(read_manifest(path).get("compensation_options", {}).get("shaper", True))
    return _Source(path, table, runs, shaper)


def _freq(run: runformat.Run | None) -> float | None:
    f = run.meta.get("protocol", {}).get("freq_hz") if run is not None else None
    return float(f) if f is not None else None


def _is_static_triangle(run: runformat.Run | None) -> bool:
    f = _freq(run)
    return run is not None and run.kind in ("triangle", "sine") and f is not None and math.isclose(f, STATIC_FREQ_HZ, rel_tol=1e-6)


def _is_uncontrolled_step(run: runformat.Run | None) -> bool:
    return run is not None and run.kind == "step" and math.isclose(float(np.max(run.command_v)), UNCONTROLLED_STEP_V, abs_tol=0.5)


# --------------------------------------------------------------------------- Table 6.13 and metrics.csv


@dataclass(frozen=True)
class _Test:
    key: str
    quantity: str
    unc_metric: str | None
    unc_select: Callable[[runformat.Run | None], bool] | None
    ctrl_metric: str
    ctrl_select: Callable[[runformat.Run | None], bool] | None
    thesis_unc: tuple[float, float] | None
    thesis_ctrl: tuple[float, float]
    source: str


TESTS_6_13 = (
    _Test("max_static_hysteresis", "Maximum static hysteresis, 0.1 Hz triangles (%)", "max_hysteresis", _is_static_triangle,
          "max_hysteresis", _is_static_triangle, thesis.TABLE_6_13["max_static_hysteresis_pct"]["uncontrolled"],
          thesis.TABLE_6_13["max_static_hysteresis_pct"]["controlled"], "Table 6.13"),
    _Test("creep", "Creep after the hold (%)", "creep", None, "creep", None,
          thesis.TABLE_6_13["creep_pct"]["uncontrolled"], thesis.TABLE_6_13["creep_pct"]["controlled"], "Table 6.13"),
    _Test("overshoot", "Step overshoot (%): 20 V step / compensated steps", "overshoot", _is_uncontrolled_step, "overshoot", None,
          thesis.TABLE_6_13["overshoot_pct"]["uncontrolled"], thesis.TABLE_6_13["overshoot_pct"]["controlled"], "Table 6.13"),
    _Test("tracking_error", "Staircase tracking error, relative (%)", None, None, "tracking_relative", None,
          None, thesis.TRACKING_RELATIVE_ERROR_PCT, "Sec. 6.6"),
)


def _picked(src: _Source | None, metric: str | None, select: Callable | None) -> list[tuple[str, float]]:
    """(run, value) of the table rows of ``metric`` whose run passes ``select``, finite values only."""
    if src is None or metric is None:
        return []
    out = []
    for r in src.table.itertuples(index=False):
        if r.metric == metric and (select is None or select(src.runs.get(r.run))) and _finite(r.value):
            out.append((str(r.run), float(r.value)))
    return out


def _finite(v: Any) -> bool:
    return v is not None and isinstance(v, (int, float, np.floating)) and math.isfinite(float(v))


def _range(vals: list[tuple[str, float]]) -> tuple[float, float]:
    if not vals:
        return (math.nan, math.nan)
    v = [x for _, x in vals]
    return (min(v), max(v))


@dataclass(frozen=True)
class _Row613:
    test: _Test
    unc: list[tuple[str, float]]
    ctrl: list[tuple[str, float]]


def _rows_6_13(char: _Source | None, val: _Source | None) -> list[_Row613]:
    return [_Row613(t, _picked(char, t.unc_metric, t.unc_select), _picked(val, t.ctrl_metric, t.ctrl_select)) for t in TESTS_6_13]


def _char_table_id(kind: str) -> str:
    return {"triangle": "5.1", "sine": "5.1", "creep": "5.2", "step": "5.3"}.get(kind, "5")


def _val_table_id(run: runformat.Run | None, kind: str, shaper: bool) -> str:
    if kind == "triangle":
        return "6.6" if _is_static_triangle(run) else ("6.11" if shaper else "6.12")
    return {"creep": "6.5", "step": "6.9", "staircase": "6.6-tracking"}.get(kind, "6")


def metrics_table(char: _Source | None, val: _Source | None) -> pd.DataFrame:
    """The long table of metrics.csv: Table 6.13 first, then every row of the summary tables."""
    rows: list[dict[str, Any]] = []
    for r in _rows_6_13(char, val):
        t = r.test
        for side, vals, ref in (("uncontrolled", r.unc, t.thesis_unc), ("controlled", r.ctrl, t.thesis_ctrl)):
            lo, hi = _range(vals)
            for end, v, th in (("min", lo, ref[0] if ref else math.nan), ("max", hi, ref[1] if ref else math.nan)):
                rows.append({"table": "6.13", "test": t.key, "metric": f"{side}_{end}", "unit": "%", "value": v,
                             "thesis": th, "thesis_source": t.source if ref else ""})
    for src, table_id in ((char, lambda s, r: _char_table_id(r.kind)), (val, lambda s, r: _val_table_id(s.runs.get(r.run), r.kind, s.shaper))):
        if src is None:
            continue
        for r in src.table.itertuples(index=False):
            rows.append({"table": table_id(src, r), "test": str(r.run), "metric": str(r.metric), "unit": str(r.unit),
                         "value": float(r.value), "thesis": float(r.thesis), "thesis_source": str(r.thesis_source)})
    return pd.DataFrame(rows, columns=COLUMNS)


def _csv_num(v: Any) -> str:
    return CSV_FLOAT % float(v) if _finite(v) else ""


def metrics_csv(table: pd.DataFrame) -> str:
    """metrics.csv's text: fixed columns, fixed number format, ``\\n`` line ends."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(COLUMNS)
    for r in table.itertuples(index=False):
        w.writerow([r.table, r.test, r.metric, r.unit, _csv_num(r.value), _csv_num(r.thesis), r.thesis_source])
    return buf.getvalue()


def _num(v: Any, digits: int = 2) -> str:
    return f"{float(v):.{digits}f}" if _finite(v) else "-"


def _range_text(lo: float, hi: float) -> str:
    if not (_finite(lo) and _finite(hi)):
        return "n/a"
    return _num(lo) if _num(lo) == _num(hi) else f"{_num(lo)} to {_num(hi)}"


def comparison_table(rows: list[_Row613]) -> Table:
    """Table 6.13 beside piezopress: quantity | uncontrolled (piezopress) | (thesis) | controlled (piezopress) | (thesis)."""
    body = []
    for r in rows:
        t = r.test
        body.append((t.quantity, _range_text(*_range(r.unc)), _range_text(*t.thesis_unc) if t.thesis_unc else "n/a",
                     _range_text(*_range(r.ctrl)), _range_text(*t.thesis_ctrl)))
    return Table(("quantity", "uncontrolled (piezopress)", "uncontrolled (thesis)", "controlled (piezopress)", "controlled (thesis)"),
                 tuple(body), ("l", "r", "r", "r", "r"))


def _basis(rows: list[_Row613]) -> list[str]:
    out = []
    for r in rows:
        for side, vals in (("uncontrolled", r.unc), ("controlled", r.ctrl)):
            if vals:
                out.append(f"{r.test.quantity}, {side}: " + ", ".join(f"{n} ({_num(v)})" for n, v in vals))
    out.append("Tracking: piezopress gives the largest |error|/reference on the stairs from "
               f"{summary.TRACKING_MIN_REFERENCE_N:g} N up (outside the ramps); the thesis prints the signed range of the relative error.")
    return out


def _detail_table(table: pd.DataFrame, table_id: Callable[[Any], str]) -> Table:
    rows = tuple((table_id(r), str(r.run), str(r.metric), _num(r.value), str(r.unit), _num(r.thesis), str(r.thesis_source), str(r.note))
                 for r in table.itertuples(index=False))
    return Table(("table", "run", "metric", "value", "unit", "thesis", "source", "note"), rows, ("l", "l", "l", "r", "l", "r", "l", "l"))


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


# --------------------------------------------------------------------------- model quality


def _pct(part: float, whole: float) -> float:
    return 100.0 * part / whole if _finite(part) and _finite(whole) and whole else math.nan


def _unit_key(d: dict[str, Any], prefix: str) -> tuple[float, str]:
    for k, v in d.items():
        if k.startswith(prefix):
            return (float(v) if v is not None else math.nan), k[len(prefix):]
    return math.nan, "n"


def _model_quality(bundle: dict[str, Any], bundle_path: Path, missing: list[str]) -> list[Block]:
    blocks: list[Block] = [Heading("Model quality"), Para(f"From the bundle `{bundle_path}`: each model's error on the data it was "
                                                         "fitted on and on data held out of the fit.")]
    h = bundle["hysteresis"]
    fit, model = h.get("fit", {}), h.get("model", {})
    code = model.get("output_unit")
    train, key = _unit_key(fit, "train_rms_")
    held, _ = _unit_key(fit, "holdout_rms_")
    rng, _ = _unit_key(fit, "output_range_")
    unit = units.label(code or key)
    runs = ", ".join(r.get("name", "?") for r in h.get("runs", []))
    blocks += [
        Heading("Hysteresis (modified Prandtl-Ishlinskii)", 3),
        Para(f"Model `{fit.get('chosen', '?')}`: {len(model.get('play_thresholds', []))} play operators, "
             f"{len(model.get('dead_zone_thresholds', []))} dead zones; fitted on {runs or 'no run named'}, the last "
             f"{100 * float(fit.get('holdout_fraction', math.nan)):g} % of each run held out"
             + ("; creep removed from the sweeps first." if h.get("creep_removed") else ".")),
        Table(("data", f"RMS error ({unit})", "% of output range"),
              (("fitting (train)", _num(train, 3), _num(_pct(train, rng), 3)), ("held out", _num(held, 3), _num(_pct(held, rng), 3))),
              ("l", "r", "r")),
        Para(f"Output range {_num(rng, 1)} {unit}. Why this model: {fit.get('reason', 'not recorded')}."),
    ]
    if "creep" in bundle:
        c = bundle["creep"]
        cf = c.get("fit", {})
        chosen = cf.get("chosen_form")
        rows = tuple((str(k.get("form")), _num(k.get("train_rms"), 3), _num(k.get("holdout_rms"), 3), "yes" if k.get("form") == chosen else "")
                     for k in cf.get("candidates", []))
        blocks += [
            Heading("Creep", 3),
            Para(f"Fitted on {', '.join(r.get('name', '?') for r in c.get('runs', []))}, the end "
                 f"({100 * float(cf.get('holdout_fraction', math.nan)):g} %) of the hold held out."),
            Table(("form", f"train RMS ({unit})", f"held-out RMS ({unit})", "chosen"), rows, ("l", "r", "r", "l")),
            Para(f"Chosen: `{chosen}`. Why: {cf.get('reason', 'not recorded')}."),
        ]
    else:
        missing.append("The bundle has no creep section: the creep model's quality is missing (run `piezopress fit` with a creep run).")
    if "shaper" in bundle:
        s = bundle["shaper"]
        mode, sh, choice = s.get("mode", {}), s.get("shaper", {}), s.get("choice", {})
        wn, zeta = float(mode.get("natural_freq_rad_s", math.nan)), float(mode.get("damping", math.nan))
        mfit = mode.get("fit", {})
        resid = ", ".join(f"{_num(r, 3)} {unit} ({_num(p, 2)} % of the step)" for r, p in zip(mfit.get("rms_residual", []), mfit.get("residual_pct_of_step", [])))
        rows = tuple((str(k.get("name")), str(k.get("impulses")), _num(k.get("delay_ms"), 3), _num(k.get("nominal_residual_pct"), 2),
                      _num(k.get("worst_residual_pct"), 2), "yes" if k.get("name") == sh.get("name") else "")
                     for k in choice.get("candidates", []))
        blocks += [
            Heading("Vibration mode and input shaper", 3),
            Para(f"Mode identified from {', '.join(r.get('name', '?') for r in s.get('runs', []))} against `{mode.get('drive_used', '?')}`: "
                 f"wn = {_num(wn, 0)} rad/s ({_num(wn / (2 * math.pi), 1)} Hz), damping {_num(zeta, 4)}; "
                 f"fit residual (RMS) {resid or 'not recorded'}."),
            Table(("shaper", "impulses", "delay (ms)", "residual at the mode (%)", "worst residual, wn +/-15 %, zeta +/-50 % (%)", "chosen"),
                  rows, ("l", "r", "r", "r", "r", "l")),
            Para(f"Chosen: `{sh.get('name', '?')}` ({len(sh.get('times_s', []))} impulses, delay {_num(sh.get('delay_ms'), 3)} ms, "
                 f"designed at {_num(choice.get('designed_at_hz'), 0)} Hz). Why: {choice.get('reason', 'not recorded')}."),
        ]
        t68 = s.get("thesis_table_6_8")
        if t68:
            blocks.append(Para(f"The thesis's printed Table 6.8 shaper would leave {_num(100 * t68.get('printed', math.nan), 1)} % residual "
                               f"vibration on this mode (with its amplitudes reversed, as ZV^4 gives them: "
                               f"{_num(100 * t68.get('reversed_amplitudes', math.nan), 1)} %; at whole damped periods: "
                               f"{_num(100 * t68.get('whole_period_spacing', math.nan), 1)} %; a correct ZV^4: "
                               f"{_num(100 * t68.get('correct_zv4', math.nan), 2)} %)."))
    else:
        missing.append("The bundle has no shaper section: the mode and shaper quality are missing (run `piezopress fit` with a low-amplitude step).")
    comp = bundle.get("compensation")
    if comp:
        rate = units.keyed(comp, "max_rate_", code)  # max_rate_n_per_s or max_rate_um_per_s; null: no limit
        rate_text = f"rate limit {_num(float(rate) / 1e3, 1)} {unit}/ms" if rate else "no rate limit"
        blocks.append(Para(f"Compensation settings: drive {_num(comp.get('drive_min_v'), 0)} to {_num(comp.get('drive_max_v'), 0)} V, "
                           f"{rate_text}, lead {_num(1e3 * float(comp.get('lead_s', math.nan)), 4)} ms."))
    return blocks


# --------------------------------------------------------------------------- building


def _gain_blocks(csv_path: Path, missing: list[str]) -> list[Block]:
    """The gain on the press (``compensated_gain.csv``, from ``diagnose --gain`` or the
    bench): compensated performance with the base bundle against the extended one."""
    if not csv_path.is_file():
        return []
    from piezopress.pipelines import gain

    try:
        df = gain.read_csv(csv_path)
    except (pd.errors.ParserError, ValueError, KeyError) as exc:
        missing.append(f"{csv_path}: unreadable ({exc}); the compensated-gain table is missing.")
        return []
    blocks: list[Block] = [Heading("The gain on the press: compensated performance, base bundle against extended", 3),
                           Para("Each row validated on the virtual rig with the effect on (lower is better): the base bundle, the "
                                "extended one, the base pipeline without the effect (clean), and the row's noise (its range over "
                                "repeated passes with other noise seeds). * marks the rows the extension is for.")]
    for cause, g in df.groupby("cause", sort=False):
        blocks.append(Table(gain.HEADER, tuple(gain.table_lines(g)), ("l", "l", "l", "r", "r", "r", "r", "r", "l")))
        blocks.append(Para(f"{cause or 'The runs rig'}: extensions applied {g['applied'].iloc[0] or 'none'}; verdict: {g['why'].iloc[0]}."))
    return blocks


def _diagnosis_blocks(path: str | Path, missing: list[str]) -> list[Block]:
    """The diagnosis section: its summary, the findings, what is unexplained, the residuals."""
    path = Path(path)
    doc_path = path / "diagnosis.json"
    if not doc_path.is_file():
        missing.append(f"{path}: no diagnosis.json; the diagnosis section is missing (run `piezopress diagnose`).")
        return []
    import json

    try:
        d = json.loads(doc_path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        missing.append(f"{doc_path}: not valid JSON ({exc.msg}); the diagnosis section is missing.")
        return []
    code = d.get("output_unit", units.FORCE)  # diagnoses written before the unit was carried are in N
    k, un = units.key(code), units.label(code)
    nan = float("nan")
    blocks: list[Block] = [Heading("Diagnosis: what the model gets wrong"), Para(d.get("summary", "")),
                           Para(f"Residual over all runs {d.get(f'residual_rms_{k}', nan):.3g} {un} RMS; "
                                f"sensor noise floor {d.get(f'noise_floor_{k}', nan):.3g} {un} RMS. Gains are measured on runs or "
                                "segments not used to fit the extension.")]
    findings = d.get("findings", [])
    if findings:
        # whether the compensator applies an extension: the cause catalogue says (one source of truth)
        def compensator(cause: str) -> str:
            c = dg.CAUSES.get(cause)
            return "?" if c is None else "applied" if c.in_compensator else "recorded only"

        rows = tuple((f["cause"], f"{f[f'baseline_rms_{k}']:.3g}", f"{f[f'extended_rms_{k}']:.3g}", f"{f['gain_pct']:.0f}",
                      ", ".join(f"{k_} = {v:.4g}" for k_, v in f["parameters"].items()), compensator(f["cause"]), f["evidence"])
                     for f in findings)
        blocks.append(Table(("cause", f"held-out RMS base ({un})", f"extended ({un})", "gain (%)", "parameters", "compensator", "evidence"),
                            rows, ("l", "r", "r", "r", "l", "l", "l")))
    if d.get("tested"):
        blocks.append(Para("Tested: " + "; ".join(
            f"{t['cause']} ({t['result']}" + (f", held-out gain {t['gain_pct']:.0f} %" if "gain_pct" in t else "") + ")" for t in d["tested"]) + "."))
    if d.get("not_tested"):
        blocks.append(Bullets(tuple(f"Not tested: {t['cause']}. Needs {t['needs']}; have {t['have']}." for t in d["not_tested"])))
    plan = d.get("next_plan") or {}
    if plan.get("file"):
        blocks.append(Para(f"Next experiment: {Path(plan['file']).name} ({len(plan.get('protocols', []))} protocols, "
                           f"{plan.get('duration_s', math.nan):.0f} s) makes testable {', '.join(plan.get('serves', []))}."))
    if d.get("unexplained"):
        blocks.append(Bullets(tuple(f"Unexplained: {u['run']}, {u[f'rms_{k}']:.3g} {un} RMS ({u['ratio']:.1f} x the noise floor), largest at "
                                    f"{u['where_s']:.4g} s, dominant frequency {u['dominant_freq_hz']:.4g} Hz" for u in d["unexplained"])))
    blocks += _gain_blocks(path / "compensated_gain.csv", missing)
    png = path / "residuals.png"
    if png.is_file():
        blocks.append(FigureBlock("diagnosis_residuals", "Residuals before and after the diagnosis's extensions",
                                  "RMS residual of every run, base model and extended, against its noise floor.", png.read_bytes()))
    png = path / "residual_traces.png"
    if png.is_file():
        blocks.append(FigureBlock("diagnosis_residual_traces", "Residual traces per run kind",
                                  "Measured minus model for every run, on each run's own time axis; spikes clipped as each panel notes.",
                                  png.read_bytes()))
    return blocks


def build_report(characterization: str | Path | None = None, validation: str | Path | None = None,
                 bundle: str | Path | None = None, diagnosis: str | Path | None = None) -> Report:
    """Read the inputs given and lay out the report (nothing is written)."""
    if characterization is None and validation is None and bundle is None and diagnosis is None:
        raise ReportError("nothing to report: give at least one of --characterization, --validation, --bundle, --diagnosis")
    missing: list[str] = []
    char = _load_dir(characterization, "characterization", "characterize", summary.characterization_table) if characterization is not None else None
    val = _load_dir(validation, "validation", "validate", summary.validation_table) if validation is not None else None
    bundle_doc = read_document(bundle, "bundle") if bundle is not None else None

    if char is None:
        missing.append("No characterization runs given: uncontrolled figures are missing (run `piezopress characterize`).")
    elif not char.runs:
        missing.append(f"The characterization directory {char.path} holds no complete run: uncontrolled figures are missing.")
    if val is None:
        missing.append("No validation runs given: controlled figures are missing (run `piezopress validate`).")
    elif not val.runs:
        missing.append(f"The validation directory {val.path} holds no complete run: controlled figures are missing.")
    if bundle_doc is None:
        missing.append("No bundle given: the model-quality section and the model residuals are missing (run `piezopress fit`).")
    for src in (char, val):
        if src is not None:
            for r in src.table.itertuples(index=False):
                if r.metric == "-":
                    missing.append(f"{r.run}: {r.note}")

    rows = _rows_6_13(char, val)
    for r in rows:
        if char is not None and char.runs and r.test.unc_metric and not r.unc:
            missing.append(f"Table 6.13, {r.test.quantity}: no uncontrolled value (no characterization run gives it).")
        if val is not None and val.runs and not r.ctrl:
            missing.append(f"Table 6.13, {r.test.quantity}: no controlled value (no validation run gives it).")
    comparison = comparison_table(rows)

    blocks: list[Block] = [Heading("piezopress report", 1), Bullets(tuple(_inputs_lines(char, val, bundle, bundle_doc)))]
    blocks += [Heading("Table 6.13: uncontrolled and controlled, beside the thesis"), comparison, Bullets(tuple(_basis(rows)))]
    if char is not None and len(char.table):
        blocks += [Heading("Characterization (uncontrolled; Tables 5.1-5.3)"), _detail_table(char.table, lambda r: _char_table_id(r.kind))]
    if val is not None and len(val.table):
        blocks += [Heading("Validation (compensated; Tables 6.5-6.12, Sec. 6.6)"),
                   _detail_table(val.table, lambda r: _val_table_id(val.runs.get(r.run), r.kind, val.shaper))]
    if bundle_doc is not None:
        blocks += _model_quality(bundle_doc, Path(bundle), missing)

    figures = [f for f in (_loops_figure(char, val, missing), _creep_figure(char, val, missing), _steps_figure(char, val, missing),
                           _tracking_figure(val, missing), _residuals_figure(bundle_doc, char, missing)) if f is not None]
    if figures:
        blocks += [Heading("Figures"), *figures]
    if diagnosis is not None:
        blocks += _diagnosis_blocks(diagnosis, missing)
    blocks += [Heading("Missing pieces"), Bullets(tuple(missing)) if missing else Para("Nothing missing.")]
    return Report(metrics_table(char, val), comparison, blocks, missing)


def _inputs_lines(char: _Source | None, val: _Source | None, bundle: str | Path | None, doc: dict[str, Any] | None) -> list[str]:
    lines = []
    lines.append(f"Characterization: `{char.path}` ({len(char.runs)} runs)" if char else "Characterization: not given")
    if val:
        lines.append(f"Validation: `{val.path}` ({len(val.runs)} runs, {'with' if val.shaper else 'without'} the input shaper)")
    else:
        lines.append("Validation: not given")
    if doc is not None:
        lines.append(f"Bundle: `{bundle}` (sections: {', '.join(k for k in ('hysteresis', 'creep', 'shaper') if k in doc)}; "
                     f"software {doc.get('software_version', '?')})")
    else:
        lines.append("Bundle: not given")
    return lines


# --------------------------------------------------------------------------- rendering


def _md_cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _md_table(t: Table) -> str:
    cells = [[_md_cell(c) for c in t.header]] + [[_md_cell(c) for c in row] for row in t.rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(t.header))]
    align = t.align or ("l",) * len(t.header)

    def line(row: Sequence[str]) -> str:
        return "| " + " | ".join(c.rjust(w) if a == "r" else c.ljust(w) for c, w, a in zip(row, widths, align)) + " |"

    rule = "|" + "|".join(("-" * (w + 1) + ":") if a == "r" else ("-" * (w + 2)) for w, a in zip(widths, align)) + "|"
    return "\n".join([line(cells[0]), rule] + [line(r) for r in cells[1:]])


def render_markdown(blocks: Iterable[Block]) -> str:
    parts = []
    for b in blocks:
        if isinstance(b, Heading):
            parts.append("#" * b.level + " " + b.text)
        elif isinstance(b, Para):
            parts.append(b.text)
        elif isinstance(b, Bullets):
            parts.append("\n".join(f"- {i}" for i in b.items))
        elif isinstance(b, Table):
            parts.append(_md_table(b))
        elif isinstance(b, FigureBlock):
            parts.append(f"**{b.title}** ([{b.file}]({b.file}))\n\n![{b.title}]({b.file})\n\n_{b.caption}_")
    return "\n\n".join(parts) + "\n"


_CODE = re.compile(r"`([^`]+)`")

CSS = """
body { font-family: -apple-system, "Segoe UI", Helvetica, Arial, sans-serif; max-width: 1100px; margin: 1.5em auto;
       padding: 0 1em; color: #222; line-height: 1.4; font-size: 15px; }
h1 { font-size: 1.6em; border-bottom: 2px solid #ccc; padding-bottom: .2em; }
h2 { font-size: 1.3em; margin-top: 1.6em; border-bottom: 1px solid #ddd; }
h3 { font-size: 1.1em; margin-top: 1.2em; }
.table-wrap { overflow-x: auto; }
table { border-collapse: collapse; font-size: 13px; margin: .6em 0; }
th, td { border: 1px solid #ccc; padding: 3px 7px; vertical-align: top; }
th { background: #f0f0f0; text-align: left; }
td.r { text-align: right; white-space: nowrap; font-variant-numeric: tabular-nums; }
tr:nth-child(even) td { background: #fafafa; }
code { background: #f3f3f3; padding: 0 3px; border-radius: 3px; font-size: 0.92em; }
figure { margin: 1.2em 0; }
figure img { max-width: 100%; height: auto; border: 1px solid #eee; }
figcaption { font-size: 13px; color: #555; }
"""


def _inline(text: str) -> str:
    return _CODE.sub(lambda m: f"<code>{m.group(1)}</code>", html.escape(text, quote=False))


def _html_table(t: Table) -> str:
    align = t.align or ("l",) * len(t.header)
    head = "".join(f"<th>{_inline(c)}</th>" for c in t.header)
    body = "\n".join("<tr>" + "".join(f'<td class="r">{_inline(c)}</td>' if a == "r" else f"<td>{_inline(c)}</td>" for c, a in zip(row, align)) + "</tr>"
                     for row in t.rows)
    return f'<div class="table-wrap"><table>\n<thead><tr>{head}</tr></thead>\n<tbody>\n{body}\n</tbody></table></div>'


def render_html(blocks: Iterable[Block]) -> str:
    parts = []
    title = "piezopress report"
    for b in blocks:
        if isinstance(b, Heading):
            parts.append(f"<h{b.level}>{_inline(b.text)}</h{b.level}>")
        elif isinstance(b, Para):
            parts.append(f"<p>{_inline(b.text)}</p>")
        elif isinstance(b, Bullets):
            parts.append("<ul>\n" + "\n".join(f"<li>{_inline(i)}</li>" for i in b.items) + "\n</ul>")
        elif isinstance(b, Table):
            parts.append(_html_table(b))
        elif isinstance(b, FigureBlock):
            data = base64.b64encode(b.png).decode("ascii")
            parts.append(f'<figure><img alt="{html.escape(b.title)}" src="data:image/png;base64,{data}">'
                         f"<figcaption><b>{_inline(b.title)}.</b> {_inline(b.caption)}</figcaption></figure>")
    return ("<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n"
            f"<title>{title}</title>\n<style>{CSS}</style>\n</head>\n<body>\n" + "\n".join(parts) + "\n</body>\n</html>\n")


# --------------------------------------------------------------------------- writing


def _is_report_dir(path: Path) -> bool:
    return path.is_dir() and any((path / f).is_file() for f in REPORT_FILES)


def check_output_dir(out_dir: str | Path, replace: bool = False) -> None:
    """Refuse an output that exists and holds anything, unless ``replace`` and it is an old report."""
    out = Path(out_dir)
    if not out.exists():
        writable_folder(out.parent)
        return
    if not out.is_dir():
        raise OutputExistsError(f"{out}: exists and is not a directory; expected a new or empty directory for the report")
    writable_folder(out.parent)
    if not any(out.iterdir()):
        return
    if not replace:
        raise OutputExistsError(f"{out}: already exists and is not empty; choose a new directory, or pass --replace to replace "
                                f"an old report (kept as {out.name}.replaced-<UTC time>)")
    if not _is_report_dir(out):
        raise OutputExistsError(f"{out}: is not a piezopress report (none of {', '.join(REPORT_FILES)}); refusing to replace it")


def write_report(report: Report, out_dir: str | Path, *, replace: bool = False) -> ReportResult:
    """Write the report into ``out_dir`` (new or empty; with ``replace`` an old report moves to
    ``<out_dir>.replaced-<UTC time>``, a new name each time: :func:`~piezopress.pipelines.files.keep_previous`).

    Files are written into a hidden staging directory beside ``out_dir`` and renamed into
    place, so a report is never half written and the old one is moved only once the new
    one is complete.
    """
    out = Path(out_dir)
    check_output_dir(out, replace)
    staging = out.with_name(f".{out.name}.{os.getpid()}-{id(report):x}.partial")
    if staging.exists():
        shutil.rmtree(staging)
    staging.mkdir()
    names = ["metrics.csv", "report.md", "report.html"]
    (staging / "metrics.csv").write_text(report.metrics_csv(), encoding="utf-8", newline="")
    (staging / "report.md").write_text(report.markdown(), encoding="utf-8")
    (staging / "report.html").write_text(report.html(), encoding="utf-8")
    for f in report.figures:
        (staging / f.file).write_bytes(f.png)
        names.append(f.file)
    previous = None
    if out.exists():
        if any(out.iterdir()):
            previous = keep_previous(out)
        else:
            out.rmdir()
    os.replace(staging, out)
    return ReportResult(report, out, tuple(out / n for n in names), previous)


def expected_table(report: Report) -> pd.DataFrame:
    """The report's figures as the expected table CI compares against, with a tolerance on
    each: 0.05 in the figure's own unit (percentage points, N, ms) or 1 %, whichever is larger."""
    import io

    df = pd.read_csv(io.StringIO(report.metrics_csv()))
    df = df[df.value.notna()].copy()
    df["tolerance"] = [max(0.05, 0.01 * abs(v)) for v in df.value]
    return df[["table", "test", "metric", "unit", "value", "tolerance"]]


def generate(out_dir: str | Path, *, characterization: str | Path | None = None, validation: str | Path | None = None,
             bundle: str | Path | None = None, diagnosis: str | Path | None = None, replace: bool = False) -> ReportResult:
    """Check the output directory, build the report and write it."""
    check_output_dir(out_dir, replace)
    return write_report(build_report(characterization, validation, bundle, diagnosis), out_dir, replace=replace)


__all__ = ["build_report", "write_report", "generate", "check_output_dir", "metrics_csv", "metrics_table", "Report",
           "ReportResult", "ReportError", "COLUMNS"]
