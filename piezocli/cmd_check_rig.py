"""``piezopress check-rig``: a small, safe drive to check the wiring before a characterization."""

from __future__ import annotations

from pathlib import Path

import click

from piezopress.piezocli.main import cli, reports_errors
from piezopress.pipelines import check_rig


@cli.command("check-rig")
@click.option(
    "--rig",
    "rig_path",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="Rig configuration (TOML); its [rig] backend picks the backend.",
)
@click.option(
    "--backend",
    "backend_name",
    default=None,
    help="Must match the rig file's [rig] backend (default: the file's).",
)
@click.option(
    "--amplitude-v",
    type=float,
    default=2.0,
    show_default=True,
    help="Peak of the drive, actuator volts (from 0 V up and back).",
)
@click.option("--freq-hz", type=float, default=1.0, show_default=True, help="Frequency of the drive.")
@click.option("--duration-s", type=float, default=3.0, show_default=True, help="How long the drive moves.")
@click.option(
    "--rest-s", type=float, default=1.0, show_default=True, help="Time at 0 V before it (noise floor and offset)."
)
@click.option(
    "--sample-rate-hz", type=float, default=1000.0, show_default=True, help="Sample rate of drive and measurement."
)
@click.option(
    "--preload-n",
    type=float,
    default=50.0,
    show_default=True,
    help="Preload assumed (the virtual rig simulates it; hardware reads it).",
)
@reports_errors
def check_rig_cmd(
    rig_path: Path,
    backend_name: str | None,
    amplitude_v: float,
    freq_hz: float,
    duration_s: float,
    rest_s: float,
    sample_rate_hz: float,
    preload_n: float,
) -> None:
    """Drive a small, safe signal and report whether the force follows it.

    Plays REST_S at 0 V then a raised-cosine from 0 V to AMPLITUDE_V at FREQ_HZ, through
    the rig's backend with all its interlocks, and prints the offset and noise floor at
    rest, the correlation and gain (N/V) between drive and force, and the sample rate
    achieved. Exits with status 1 if the force does not follow the drive.

    \b
    Example:
      piezopress check-rig --rig rigs/thesis-press.toml
      piezopress check-rig --rig my-press.toml --backend nidaq --amplitude-v 2 --freq-hz 1
    """
    report = check_rig.check_rig(
        rig_path,
        backend_name,
        amplitude_v=amplitude_v,
        freq_hz=freq_hz,
        duration_s=duration_s,
        rest_s=rest_s,
        sample_rate_hz=sample_rate_hz,
        preload_n=preload_n,
    )
    click.echo(check_rig.format_report(report))
    if not report.check.follows:
        raise click.exceptions.Exit(1)
