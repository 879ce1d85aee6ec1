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

import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from piezopress import units
from piezopress.errors import OutputExistsError
from piezopress.pipelines import report_frequency, summary
from piezopress.pipelines.bundle import read_document
from piezopress.pipelines.files import keep_previous, status_notes, writable_folder
from piezopress.pipelines.report_doc import (
    CSS,
    Block,
    Bullets,
    Contents,
    FigureBlock,
    Heading,
    Para,
    Table,
    _md_table,
    render_html,
    render_markdown,
)
from piezopress.pipelines.report_figures import (
    _creep_figure,
    _drive_figure,
    _frequency_loops_figure,
    _loops_figure,
    _residuals_figure,
    _steps_figure,
    _tracking_figure,
)
from piezopress.pipelines.report_inputs import STATIC_FREQ_HZ, UNCONTROLLED_STEP_V, ReportError, _load_dir, _Source
from piezopress.pipelines.report_model import _diagnosis_blocks, _model_quality
from piezopress.pipelines.report_tables import (
    COLUMNS,
    CSV_FLOAT,
    TESTS_6_13,
    _basis,
    _char_table_id,
    _detail_table,
    _rows_6_13,
    _val_table_id,
    comparison_table,
    metrics_csv,
    metrics_table,
)
from piezopress.pipelines.report_verdict import Verdict, verdict_blocks

#: Files a report directory holds; a directory holding one of them is a report (``--replace``).
REPORT_FILES = ("metrics.csv", "report.md", "report.html")


@dataclass
class Report:
    """Everything ``write_report`` writes; ``markdown()``/``html()`` render the same blocks."""

    metrics: pd.DataFrame
    comparison: Table
    blocks: list[Block]
    missing: list[str]
    verdict: Verdict | None = None

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


def build_report(
    characterization: str | Path | None = None,
    validation: str | Path | None = None,
    bundle: str | Path | None = None,
    diagnosis: str | Path | None = None,
    compared: str | Path | None = None,
) -> Report:
    """Read the inputs given and lay out the report (nothing is written)."""
    if all(x is None for x in (characterization, validation, bundle, diagnosis, compared)):
        raise ReportError(
            "nothing to report: give at least one of --characterization, --validation, --bundle, --diagnosis, "
            "--comparison"
        )
    missing: list[str] = []
    char = (
        _load_dir(characterization, "characterization", "characterize", summary.characterization_table)
        if characterization is not None
        else None
    )
    val = _load_dir(validation, "validation", "validate", summary.validation_table) if validation is not None else None
    bundle_doc = read_document(bundle, "bundle") if bundle is not None else None

    if char is None:
        missing.append(
            "No characterization runs given: uncontrolled figures are missing (run `piezopress characterize`)."
        )
    elif not char.runs:
        missing.append(
            f"The characterization directory {char.path} holds no complete run: uncontrolled figures are missing."
        )
    if val is None:
        foreign = bundle_doc is not None and not units.is_force(
            units.normalise((bundle_doc.get("hysteresis") or {}).get("model", {}).get("output_unit"))
        )
        imported = char is not None and any(isinstance(r.meta.get("import"), dict) for r in char.runs.values())
        if foreign or imported:  # validate plays force references on a press it drives: not this record's
            missing.append(
                "No validation runs given (a model of a record from elsewhere): check a drive with "
                "`piezopress compensate` and `piezopress simulate`, then play it on that press and import the run."
            )
        else:
            missing.append("No validation runs given: controlled figures are missing (run `piezopress validate`).")
    elif not val.runs:
        missing.append(f"The validation directory {val.path} holds no complete run: controlled figures are missing.")
    if bundle_doc is None:
        missing.append(
            "No bundle given: the model-quality section and the model residuals are missing (run `piezopress fit`)."
        )
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

    verdict_section, verdict = verdict_blocks(rows, char, val, bundle, bundle_doc)
    blocks: list[Block] = [
        Heading("piezopress report", 1),
        Contents(),
        *verdict_section,
        Heading("Inputs"),
        Bullets(tuple(_inputs_lines(char, val, bundle, bundle_doc))),
    ]
    blocks += [
        Heading("Table 6.13: uncontrolled and controlled, beside the thesis"),
        comparison,
        Bullets(tuple(_basis(rows))),
    ]

    figures = [
        f
        for f in (
            _loops_figure(char, val, missing, bundle_doc),
            _frequency_loops_figure(val, missing),
            _creep_figure(char, val, missing),
            _steps_figure(char, val, missing),
            _tracking_figure(val, missing),
            _drive_figure(val, missing),
        )
        if f is not None
    ]
    if figures:
        blocks += [Heading("Before and after: the figures"), *figures]
    mode_fig, _ = report_frequency.mode_figure(bundle_doc, char, missing)
    spectral = [
        f
        for f in (
            mode_fig,
            report_frequency.shaper_figure(bundle_doc, missing),
            report_frequency.creep_figure(bundle_doc, missing),
        )
        if f is not None
    ]
    if spectral:
        blocks += [Heading("The frequency domain"), *spectral]
    if char is not None and len(char.table):
        blocks += [
            Heading("Characterization (uncontrolled; Tables 5.1-5.3)"),
            _detail_table(char.table, lambda r: _char_table_id(r.kind)),
        ]
    if val is not None and len(val.table):
        blocks += [
            Heading("Validation (compensated; Tables 6.5-6.12, Sec. 6.6)"),
            _detail_table(val.table, lambda r: _val_table_id(val.runs.get(r.run), r.kind, val.shaper)),
        ]
    if bundle_doc is not None:
        blocks += _model_quality(bundle_doc, Path(bundle), missing)
        residuals = _residuals_figure(bundle_doc, char, missing)
        if residuals is not None:
            blocks.append(residuals)
    if diagnosis is not None:
        runs = [r for s in (char, val) if s is not None for r in s.runs.values()]
        blocks += _diagnosis_blocks(diagnosis, missing, runs)
    if compared is not None:
        from piezopress.pipelines.report_compare import comparison_blocks

        blocks += [Heading("Comparison on the press")] + comparison_blocks(compared, missing)
    blocks += [Heading("Missing pieces"), Bullets(tuple(missing)) if missing else Para("Nothing missing.")]
    return Report(metrics_table(char, val), comparison, blocks, missing, verdict)


def _inputs_lines(
    char: _Source | None, val: _Source | None, bundle: str | Path | None, doc: dict[str, Any] | None
) -> list[str]:
    lines = []
    lines.append(f"Characterization: `{char.path}` ({len(char.runs)} runs)" if char else "Characterization: not given")
    if val:
        skipped = sum(
            any(str(n).startswith("shaper skipped") for n in (r.meta.get("compensation") or {}).get("notes", []))
            for r in val.runs.values()
        )
        shaper = "with the input shaper" if val.shaper else "without the input shaper"
        if val.shaper and skipped:
            shaper += (
                f" on {len(val.runs) - skipped} of them (skipped on {skipped}: "
                "their sample rate cannot resolve the mode)"
            )
        lines.append(f"Validation: `{val.path}` ({len(val.runs)} runs, {shaper})")
    else:
        lines.append("Validation: not given")
    if doc is not None:
        lines.append(
            f"Bundle: `{bundle}` (sections: {', '.join(k for k in ('hysteresis', 'creep', 'shaper') if k in doc)}; "
            f"software {doc.get('software_version', '?')})"
        )
    else:
        lines.append("Bundle: not given")
    lines += [f"Incomplete input: {note}" for note in status_notes()]  # accepted with --accept-incomplete
    return lines


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
        raise OutputExistsError(
            f"{out}: exists and is not a directory; expected a new or empty directory for the report"
        )
    writable_folder(out.parent)
    if not any(out.iterdir()):
        return
    if not replace:
        raise OutputExistsError(
            f"{out}: already exists and is not empty; choose a new directory, or pass --replace to replace "
            f"an old report (kept as {out.name}.replaced-<UTC time>)"
        )
    runs = sorted(p.name for p in out.iterdir() if p.suffix == ".parquet" or p.name == "manifest.json")
    if runs:
        raise OutputExistsError(
            f"{out}: holds runs ({', '.join(runs[:3])}{' ...' if len(runs) > 3 else ''}), not only a report; "
            "refusing to move it aside: choose another --out for the report"
        )
    if not _is_report_dir(out):
        raise OutputExistsError(
            f"{out}: is not a piezopress report (none of {', '.join(REPORT_FILES)}); refusing to replace it"
        )


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


def generate(
    out_dir: str | Path,
    *,
    characterization: str | Path | None = None,
    validation: str | Path | None = None,
    bundle: str | Path | None = None,
    diagnosis: str | Path | None = None,
    comparison: str | Path | None = None,
    replace: bool = False,
) -> ReportResult:
    """Check the output directory, build the report and write it."""
    check_output_dir(out_dir, replace)
    return write_report(
        build_report(characterization, validation, bundle, diagnosis, comparison), out_dir, replace=replace
    )


__all__ = [
    "build_report",
    "write_report",
    "generate",
    "check_output_dir",
    "metrics_csv",
    "metrics_table",
    "Report",
    "ReportResult",
    "ReportError",
    "COLUMNS",
    "CSV_FLOAT",
    "CSS",
    "STATIC_FREQ_HZ",
    "UNCONTROLLED_STEP_V",
    "TESTS_6_13",
    "Heading",
    "Para",
    "Bullets",
    "Table",
    "FigureBlock",
    "render_markdown",
    "render_html",
    "expected_table",
]
