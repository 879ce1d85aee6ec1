"""The report's tables: Table 6.13 beside the thesis, the long table of ``metrics.csv``
(fixed columns and number format: the same inputs give the same bytes) and the detail
tables of the characterization and the validation."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from piezopress import runformat, thesis
from piezopress.pipelines import summary
from piezopress.pipelines.report_doc import Table
from piezopress.pipelines.report_inputs import _is_static_triangle, _is_uncontrolled_step, _Source

COLUMNS = ["table", "test", "metric", "unit", "value", "thesis", "thesis_source"]
#: Number format of metrics.csv.
CSV_FLOAT = "%.6g"


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
    _Test(
        "max_static_hysteresis",
        "Maximum static hysteresis, 0.1 Hz triangles (%)",
        "max_hysteresis",
        _is_static_triangle,
        "max_hysteresis",
        _is_static_triangle,
        thesis.TABLE_6_13["max_static_hysteresis_pct"]["uncontrolled"],
        thesis.TABLE_6_13["max_static_hysteresis_pct"]["controlled"],
        "Table 6.13",
    ),
    _Test(
        "creep",
        "Creep after the hold (%)",
        "creep",
        None,
        "creep",
        None,
        thesis.TABLE_6_13["creep_pct"]["uncontrolled"],
        thesis.TABLE_6_13["creep_pct"]["controlled"],
        "Table 6.13",
    ),
    _Test(
        "overshoot",
        "Step overshoot (%): 20 V step / compensated steps",
        "overshoot",
        _is_uncontrolled_step,
        "overshoot",
        None,
        thesis.TABLE_6_13["overshoot_pct"]["uncontrolled"],
        thesis.TABLE_6_13["overshoot_pct"]["controlled"],
        "Table 6.13",
    ),
    _Test(
        "tracking_error",
        "Staircase tracking error, relative (%)",
        None,
        None,
        "tracking_relative",
        None,
        None,
        thesis.TRACKING_RELATIVE_ERROR_PCT,
        "Sec. 6.6",
    ),
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
    return [
        _Row613(t, _picked(char, t.unc_metric, t.unc_select), _picked(val, t.ctrl_metric, t.ctrl_select))
        for t in TESTS_6_13
    ]


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
                rows.append(
                    {
                        "table": "6.13",
                        "test": t.key,
                        "metric": f"{side}_{end}",
                        "unit": "%",
                        "value": v,
                        "thesis": th,
                        "thesis_source": t.source if ref else "",
                    }
                )
    for src, table_id in (
        (char, lambda s, r: _char_table_id(r.kind)),
        (val, lambda s, r: _val_table_id(s.runs.get(r.run), r.kind, s.shaper)),
    ):
        if src is None:
            continue
        for r in src.table.itertuples(index=False):
            rows.append(
                {
                    "table": table_id(src, r),
                    "test": str(r.run),
                    "metric": str(r.metric),
                    "unit": str(r.unit),
                    "value": float(r.value),
                    "thesis": float(r.thesis),
                    "thesis_source": str(r.thesis_source),
                }
            )
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
    """Table 6.13 beside piezopress: quantity | uncontrolled (piezopress) | (thesis) |
    controlled (piezopress) | (thesis)."""
    body = []
    for r in rows:
        t = r.test
        body.append(
            (
                t.quantity,
                _range_text(*_range(r.unc)),
                _range_text(*t.thesis_unc) if t.thesis_unc else "n/a",
                _range_text(*_range(r.ctrl)),
                _range_text(*t.thesis_ctrl),
            )
        )
    return Table(
        (
            "quantity",
            "uncontrolled (piezopress)",
            "uncontrolled (thesis)",
            "controlled (piezopress)",
            "controlled (thesis)",
        ),
        tuple(body),
        ("l", "r", "r", "r", "r"),
    )


def _basis(rows: list[_Row613]) -> list[str]:
    out = []
    for r in rows:
        for side, vals in (("uncontrolled", r.unc), ("controlled", r.ctrl)):
            if vals:
                out.append(f"{r.test.quantity}, {side}: " + ", ".join(f"{n} ({_num(v)})" for n, v in vals))
    out.append(
        "Tracking: piezopress gives the largest |error|/reference on the stairs from "
        f"{summary.TRACKING_MIN_REFERENCE_N:g} N up (outside the ramps); the thesis prints the signed range of the "
        "relative error."
    )
    return out


def _detail_table(table: pd.DataFrame, table_id: Callable[[Any], str]) -> Table:
    rows = tuple(
        (
            table_id(r),
            str(r.run),
            str(r.metric),
            _num(r.value),
            str(r.unit),
            _num(r.thesis),
            str(r.thesis_source),
            str(r.note),
        )
        for r in table.itertuples(index=False)
    )
    return Table(
        ("table", "run", "metric", "value", "unit", "thesis", "source", "note"),
        rows,
        ("l", "l", "l", "r", "l", "r", "l", "l"),
    )
