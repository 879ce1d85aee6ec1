"""``piezopress report``."""

from __future__ import annotations

from pathlib import Path

import click

from piezopress.piezocli.main import cli, reports_errors
from piezopress.pipelines import report as rep


@cli.command("report")
@click.option(
    "--characterization",
    "char_dir",
    type=click.Path(path_type=Path),
    help="Characterization run directory (from `piezopress characterize`), or a run file (from `piezopress import`).",
)
@click.option(
    "--validation",
    "val_dir",
    type=click.Path(file_okay=False, path_type=Path),
    help="Validation run directory (from `piezopress validate`).",
)
@click.option(
    "--bundle",
    "bundle_path",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Parameter bundle (from `piezopress fit`).",
)
@click.option(
    "--diagnosis",
    "diag_dir",
    type=click.Path(file_okay=False, path_type=Path),
    help="Diagnosis directory (from `piezopress diagnose`).",
)
@click.option(
    "--comparison",
    "cmp_dir",
    type=click.Path(file_okay=False, path_type=Path),
    help="Comparison directory (from `piezopress compare`).",
)
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="New (or empty) directory for the report.",
)
@click.option(
    "--replace",
    is_flag=True,
    help="Replace an existing report in --out (the old one is kept as <out>.replaced-<UTC time>).",
)
@reports_errors
def report_cmd(char_dir, val_dir, bundle_path, diag_dir, cmp_dir, out_dir, replace) -> None:
    """Write the report: Table 6.13 beside the thesis, the detailed tables, model quality, figures.

    Every input is optional; what is missing is said in the report. The output directory
    gets metrics.csv (one row per figure, the same bytes for the same inputs), report.md,
    report.html (one self-contained page) and the figures as PNG. It must be new or empty;
    --replace moves an old report to <out>.replaced-<UTC time> first.

    \b
    Example:
      piezopress report --characterization runs/press-2026-11-21 --validation runs/validation \\
          --bundle build/bundle.json --out build/report
    """
    result = rep.generate(
        out_dir,
        characterization=char_dir,
        validation=val_dir,
        bundle=bundle_path,
        diagnosis=diag_dir,
        comparison=cmp_dir,
        replace=replace,
    )
    report = result.report
    if report.verdict is not None:
        click.echo("\n".join(report.verdict.lines()) + "\n")
    if report.missing:
        click.echo("Missing pieces:")
        for line in report.missing:
            click.echo(f"  - {line}")
        click.echo("")
    click.echo("Table 6.13: uncontrolled and controlled, beside the thesis\n")
    click.echo(report.comparison_markdown())
    if result.previous is not None:
        click.echo(f"\nThe old report was moved to {result.previous}")
    click.echo(f"\n{len(result.files)} files written to {result.out_dir}")
    click.echo(f"Report: {result.html_path}")
