"""``piezopress demo``: the whole chain on the virtual rig, one command (what ``make demo`` runs)."""

from __future__ import annotations

import time
from datetime import UTC, datetime
from pathlib import Path

import click

from piezopress.errors import OutputExistsError
from piezopress.piezocli.main import cli, reports_errors


def demo_steps(d: Path) -> list[tuple[str, list[str]]]:
    """The chain, as the commands a user would type: (title, arguments)."""
    return [
        ("characterize the virtual press", ["characterize", "--out", str(d / "characterization")]),
        ("fit the bundle", ["fit", str(d / "characterization"), "--out", str(d / "bundle.json")]),
        ("validate the compensation", ["validate", "--bundle", str(d / "bundle.json"), "--out", str(d / "validation")]),
        (
            "fit the thesis's base model",
            ["fit", str(d / "characterization"), "--base", "--out", str(d / "base-bundle.json")],
        ),
        (
            "diagnose the base model",
            [
                "diagnose",
                str(d / "characterization"),
                "--bundle",
                str(d / "base-bundle.json"),
                "--out",
                str(d / "diagnosis"),
            ],
        ),
        (
            "write the report",
            [
                "report",
                "--characterization",
                str(d / "characterization"),
                "--validation",
                str(d / "validation"),
                "--bundle",
                str(d / "bundle.json"),
                "--diagnosis",
                str(d / "diagnosis"),
                "--out",
                str(d / "report"),
            ],
        ),
    ]


@cli.command("demo")
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="New directory for everything (default: demo-YYYYMMDDTHHMMSSZ here).",
)
@reports_errors
def demo_cmd(out_dir: Path | None) -> None:
    """Run the whole chain on the virtual rig: characterize, fit, validate, fit --base,
    diagnose, report (what `make demo` runs; no make needed, e.g. on Windows).

    Each step is the command you would type, printed before it runs; the report's path is
    printed at the end. Nothing is overwritten: --out must be new.

    \b
    Example:
      piezopress demo
      piezopress demo --out demo-run
    """
    d = out_dir or Path(f"demo-{datetime.now(UTC).strftime('%Y%m%dT%H%M%SZ')}")
    if d.exists() and any(d.iterdir()):
        raise OutputExistsError(f"{d}: exists and is not empty; expected a new directory for the demo")
    d.mkdir(parents=True, exist_ok=True)
    steps = demo_steps(d)
    started = time.monotonic()
    for i, (title, args) in enumerate(steps, start=1):
        click.echo(f"\n== {i}/{len(steps)} {title}: piezopress {' '.join(args)}")
        cli.main(args, prog_name="piezopress", standalone_mode=False)
    # the report step printed its path ("Report: ..."), the last line a person reads
    click.echo(f"\nThe demo took {time.monotonic() - started:.0f} s; open {d / 'report' / 'report.html'}")
