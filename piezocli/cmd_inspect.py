"""``piezopress inspect``: validate run files and print what they hold."""

from __future__ import annotations

import json
from pathlib import Path

import click

from piezopress.errors import PiezopressError
from piezopress.piezocli.main import cli, emit_json, json_option, reports_errors
from piezopress.pipelines import profiles
from piezopress.runformat import REQUIRED_METADATA, Run, read_run

# Provenance shown for imported runs, in this order (the rest is in the file).
_IMPORT_KEYS = (
    "source_file",
    "source_sha256",
    "columns",
    "scales",
    "offsets",
    "lag_samples",
    "rows",
    "time_source",
    "importer_version",
    "imported_utc",
)


def _value(value: object) -> str:
    text = value if isinstance(value, str) else json.dumps(value, ensure_ascii=False, default=str)
    return text if len(text) <= 160 else text[:157] + "..."


def _describe(run: Run) -> list[str]:
    data = run.data
    t = run.t_s
    meta = run.meta
    lines = [
        str(run.path),
        f"  kind {run.kind}, name {run.name!r}, {len(data)} samples at {run.sample_rate_hz:.6g} Hz, "
        f"{t[-1] - t[0]:.6g} s (t_s {t[0]:.6g}..{t[-1]:.6g}), status {meta.get('status', 'complete')}",
        f"  {'column':<16} {'min':>12} {'max':>12} {'mean':>12}",
    ]
    stats = data.agg(["min", "max", "mean"])
    for col in data.columns:
        lo, hi, mean = stats[col]
        lines.append(f"  {col:<16} {lo:>12.6g} {hi:>12.6g} {mean:>12.6g}")
    prof, disagreements = profiles.examine(run)
    glitches = f"; {len(prof.glitches)} glitched sample(s) of {run.output_column}" if prof.glitches else ""
    lines.append(f"  measured: {prof.describe()} (kind {prof.kind}, from {prof.signal}){glitches}")
    lines.extend(f"  disagrees: {line}" for line in disagreements)
    for key, value in meta.items():
        if key in REQUIRED_METADATA or key in ("status", "import"):
            continue
        lines.append(f"  {key}: {_value(value)}")
    imported = meta.get("import")
    if isinstance(imported, dict):
        lines.append("  imported:")
        lines.extend(f"    {key}: {_value(imported[key])}" for key in _IMPORT_KEYS if key in imported)
    return lines


def _as_dict(run: Run) -> dict:
    stats = run.data.agg(["min", "max", "mean"])
    t = run.t_s
    return {
        "path": run.path,
        "kind": run.kind,
        "name": run.name,
        "samples": len(run.data),
        "sample_rate_hz": run.sample_rate_hz,
        "duration_s": float(t[-1] - t[0]),
        "status": run.meta.get("status", "complete"),
        "columns": {
            c: {"min": float(stats[c]["min"]), "max": float(stats[c]["max"]), "mean": float(stats[c]["mean"])}
            for c in run.data.columns
        },
        "meta": run.meta,
        "profile": profiles.examine(run)[0].as_dict(),
        "disagreements": profiles.examine(run)[1],
    }


@cli.command("inspect")
@click.argument("runs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--allow-incomplete", is_flag=True, help="Also show runs marked incomplete (interrupted, aborted).")
@json_option
@reports_errors
def inspect_command(runs: tuple[Path, ...], allow_incomplete: bool, as_json: bool) -> None:
    """Validate run files and print a summary of each.

    For each RUN (a run file, or a directory: every run file in it): kind, name, sample rate,
    duration and number of samples; what its signals show (the measured profile); minimum,
    maximum and mean of every column; the other metadata (units note, protocol, ...) and,
    for imported runs, the source file, its sha256 and the import options. A file that
    is not a valid run gets one line on stderr; the others are still shown, and the
    exit status is 1 if any file was bad.

    \b
    Example:
      piezopress inspect runs/smarthysteresis_150v_1hz.parquet runs/aye_ang_model.parquet
      piezopress inspect sample_runs/characterization
    """
    files: list[Path] = []
    bad = 0
    for path in runs:
        if path.is_dir():
            found = sorted(path.glob("*.parquet"))
            if not found:
                bad += 1
                click.echo(f"Error: {path}: a directory with no run files (*.parquet)", err=True)
            files.extend(found)
        else:
            files.append(path)
    docs = []
    for i, path in enumerate(files):
        try:
            run = read_run(path, allow_incomplete=allow_incomplete)
        except PiezopressError as exc:
            bad += 1
            click.echo(f"Error: {exc}", err=True)
            docs.append({"path": path, "error": str(exc)})
            continue
        if as_json:
            docs.append(_as_dict(run))
            continue
        if i:
            click.echo()
        click.echo("\n".join(_describe(run)))
    if as_json:
        emit_json({"runs": docs, "bad": bad})
    if bad:
        raise SystemExit(1)
