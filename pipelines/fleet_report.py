"""The fleet report: each key figure's distribution over the presses (a table and a strip
plot), every press outside the fleet's spread with its figure and how far out, the failures;
Markdown and one HTML page, as the single report (:mod:`piezopress.pipelines.report_doc`)."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from piezopress import plotting
from piezopress.analysis import fleet
from piezopress.pipelines.batch import FIGURES, read_fleet_csv
from piezopress.pipelines.report_doc import FigureBlock, Heading, Para, Table, render_html, render_markdown

LABELS = {
    "holdout_pct": "hysteresis held-out error (% of range)",
    "mode_rad_s": "mode (rad/s)",
    "damping": "mode damping",
    "max_static_hysteresis_pct": "compensated static hysteresis (%)",
    "creep_pct": "compensated creep after 120 s (%)",
    "overshoot_pct": "compensated overshoot (%)",
    "tracking_error_pct": "compensated staircase tracking error (%)",
}


@dataclass
class FleetReport:
    markdown: Path
    html: Path
    outliers: list[fleet.Outlier]


def _num(v: Any) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def _fmt(v: float) -> str:
    return "-" if not math.isfinite(v) else f"{v:.4g}"


def write_fleet_report(fleet_csv: str | Path, out_dir: str | Path | None = None) -> FleetReport:
    """``fleet.md``, ``fleet.html`` and ``fleet_strips.png`` beside ``fleet.csv`` (or in ``out_dir``)."""
    fleet_csv = Path(fleet_csv)
    out = Path(out_dir) if out_dir is not None else fleet_csv.parent
    rows = read_fleet_csv(fleet_csv)
    ok = [r for r in rows if r.get("status") in ("done", "skipped")]
    failed = [r for r in rows if r.get("status") == "failed"]
    presses = [r["press"] for r in ok]
    values = {f: [_num(r.get(f)) for r in ok] for f in FIGURES}
    findings = [r.get("findings") or "" for r in ok] if any(r.get("findings") for r in ok) else None
    flags = fleet.outliers(presses, values, findings)
    spreads = [fleet.spread(f, values[f]) for f in FIGURES]
    blocks: list = [
        Heading("Fleet report", 1),
        Para(
            f"{len(rows)} presses: {sum(r.get('status') == 'done' for r in rows)} done, "
            f"{sum(r.get('status') == 'skipped' for r in rows)} skipped as unchanged, {len(failed)} failed "
            f"(from {fleet_csv.name}). A press is outside the fleet's spread when its robust z (from the median "
            f"and the median absolute deviation) passes {fleet.OUTLIER_Z:g}, with at least {fleet.MIN_PRESSES} "
            "presses having the figure; a finding of diagnose is flagged when at most a quarter of the diagnosed "
            "presses share it."
        ),
        Heading("Presses outside the fleet's spread"),
    ]
    if flags:
        blocks.append(
            Table(
                ("press", "figure", "value", "robust z", "why"),
                tuple(
                    (
                        o.press,
                        LABELS.get(o.figure, o.figure),
                        o.value if isinstance(o.value, str) else _fmt(o.value),
                        "-" if not isinstance(o.z, float) or math.isnan(o.z) else f"{o.z:+.1f}",
                        o.why,
                    )
                    for o in flags
                ),
                ("l", "l", "r", "r", "l"),
            )
        )
    else:
        blocks.append(Para("None: every press is inside the fleet's spread on every figure."))
    blocks.append(Heading("Failures"))
    blocks.append(
        Table(("press", "why"), tuple((r["press"], r.get("why") or "?") for r in failed), ("l", "l"))
        if failed
        else Para("None.")
    )
    blocks += [
        Heading("Key figures over the fleet"),
        Table(
            ("figure", "presses", "median", "MAD", "lowest", "highest"),
            tuple(
                (LABELS[s.figure], str(s.n), _fmt(s.median), _fmt(s.mad), _fmt(s.low), _fmt(s.high)) for s in spreads
            ),
            ("l", "r", "r", "r", "r", "r"),
        ),
    ]
    shown = [(LABELS[f], presses, values[f]) for f in FIGURES if any(math.isfinite(v) for v in values[f])]
    if shown:
        flagged = {(o.press, LABELS.get(o.figure, o.figure)) for o in flags}
        blocks.append(
            FigureBlock(
                "fleet_strips",
                "Key figures, one dot per press",
                "Each press a dot; the grey line is the fleet's median; a press outside the spread is red and named.",
                plotting.to_png(plotting.fleet_strips(shown, flagged)),
            )
        )
    blocks += [
        Heading("Every press"),
        Table(
            ("press", "status", "held-out %", "mode rad/s", "damping", "findings", "wall s"),
            tuple(
                (
                    r["press"],
                    r.get("status", "?"),
                    _fmt(_num(r.get("holdout_pct"))),
                    _fmt(_num(r.get("mode_rad_s"))),
                    _fmt(_num(r.get("damping"))),
                    r.get("findings") or "-",
                    _fmt(_num(r.get("wall_s"))),
                )
                for r in rows
            ),
            ("l", "l", "r", "r", "r", "l", "r"),
        ),
    ]
    out.mkdir(parents=True, exist_ok=True)
    for b in blocks:
        if isinstance(b, FigureBlock):
            (out / b.file).write_bytes(b.png)
    md, page = out / "fleet.md", out / "fleet.html"
    for path, text in ((md, render_markdown(blocks)), (page, render_html(blocks))):
        tmp = path.with_name(f".{path.name}.partial")
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)
    return FleetReport(md, page, flags)
