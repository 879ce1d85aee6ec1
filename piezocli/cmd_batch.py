"""``piezopress batch``: many presses at once (Dask when installed)."""

from __future__ import annotations

from pathlib import Path

import click

from piezopress.piezocli.main import cli, next_command, reports_errors
from piezopress.pipelines import batch as batch_mod


@cli.command("batch")
@click.argument("stage", type=click.Choice(batch_mod.STAGES))
@click.argument("presses")
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="Folder for one sub-folder per press, fleet.csv and the fleet report.",
)
@click.option(
    "--workers",
    type=click.IntRange(1, 512),
    default=None,
    help="Workers of the local Dask cluster  [default: the CPUs this process may use].",
)
@click.option("--scheduler", default=None, help="Address of an existing Dask scheduler (tcp://host:8786).")
@click.option("--serial", is_flag=True, help="One press after the other in this process (no Dask).")
@reports_errors
def batch_cmd(stage: str, presses: str, out_dir: Path, workers: int | None, scheduler: str | None, serial: bool):
    """Run STAGE (fit, diagnose, validate, report, or all of them) for every press of PRESSES.

    PRESSES is a glob of run directories (each one press, named by its folder; quote it) or a
    manifest CSV with columns press, runs (a run directory or files, several separated by
    ';'; fsspec URLs the workers can read), and optionally rig (the rig file it is validated
    on; default: the virtual rig its runs recorded) and bundle (used instead of fitting one).
    Each press runs the same functions as the single-press commands into OUT/<press>; a press
    that fails is its row in OUT/fleet.csv, never the batch's end; a rerun skips a press whose
    inputs are unchanged. With Dask installed (pip install 'piezopress[fleet]') the presses run
    on a local cluster (--workers) or an existing one (--scheduler); without it, one after the
    other. The fleet report (fleet.md, fleet.html) flags presses outside the fleet's spread.

    \b
    Examples:
      piezopress batch all 'runs/press-*' --out fleet --workers 2
      piezopress batch fit presses.csv --out fleet --scheduler tcp://cluster:8786
    """
    from piezopress.pipelines.fleet_report import write_fleet_report

    found = batch_mod.read_presses(presses)

    def started(engine: str, dashboard: str | None) -> None:
        click.echo(f"{len(found)} presses, stage {stage}, on {engine}")
        if dashboard:
            click.echo(f"Dask dashboard: {dashboard}")

    def done(i: int, n: int, row: dict) -> None:
        why = f": {row.get('why')}" if row.get("why") else ""
        wall = f" in {float(row.get('wall_s') or 0):.1f} s" if row.get("status") == "done" else ""
        click.echo(f"[{i:>{len(str(n))}}/{n}] {row['press']}: {row['status']}{wall}{why}")

    res = batch_mod.run_batch(
        found, stage, out_dir, workers=workers, scheduler=scheduler, serial=serial, on_start=started, on_done=done
    )
    for note in res.notes:
        click.echo(f"Note: {note}", err=True)
    rep = write_fleet_report(res.fleet_csv)
    statuses = [r["status"] for r in res.rows]
    click.echo(
        f"\n{statuses.count('done')} done, {statuses.count('skipped')} skipped as unchanged, "
        f"{statuses.count('failed')} failed, in {res.wall_s:.1f} s; wrote {res.fleet_csv}, {rep.markdown}, {rep.html}"
    )
    for o in rep.outliers:
        value = o.value if isinstance(o.value, str) else f"{o.value:.4g}"
        click.echo(f"Outside the fleet's spread: {o.press}: {o.figure} = {value} ({o.why})")
    next_command(f"open {rep.html}")
    if statuses.count("failed"):
        raise SystemExit(1)
