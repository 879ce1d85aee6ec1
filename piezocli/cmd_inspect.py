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


def _bundle_lines(path: Path) -> tuple[list[str], dict]:
    """A bundle's summary: sections, the held-out error, the rest, the reach, the drive range, its runs."""
    from piezopress import units
    from piezopress.pipelines.bundle import read_bundle

    b = read_bundle(path)
    doc = b.to_dict()
    u = units.label(b.unit)
    k = units.key(b.unit)
    fit = (doc.get("hysteresis") or {}).get("fit") or {}
    lo, hi = b.reach()
    rest = float(b.hysteresis.y0)
    s = b.settings
    runs = [r.get("name") for r in (doc.get("hysteresis") or {}).get("runs", []) if isinstance(r, dict)]
    sections = [name for name in ("hysteresis", "creep", "shaper") if doc.get(name)]
    held = fit.get(f"holdout_rms_{k}")
    info = {
        "path": path,
        "sections": sections,
        "output_unit": b.unit,
        f"holdout_rms_{k}": held,
        f"rest_{k}": rest,
        f"reach_above_rest_{k}": [lo, hi],
        "drive_v": [s.drive_min_v, s.drive_max_v],
        "fitted_on": runs,
        "from_elsewhere": b.from_elsewhere,
    }
    lines = [
        str(path),
        f"  bundle of {', '.join(sections)}; output {units.quantity(b.unit)} in {u}",
        f"  held-out error {held:.4g} {u} RMS" if isinstance(held, (int, float)) else "  held-out error not recorded",
        f"  rest: {rest:.4g} {u} (the zero of references above the rest); the drive range {s.drive_min_v:g} to "
        f"{s.drive_max_v:g} V reaches {rest + lo:.4g} to {rest + hi:.4g} {u} ({lo:.4g} to {hi:.4g} above the rest)",
        f"  fitted on {', '.join(map(str, runs)) or '?'}"
        + (" (runs from elsewhere: compensate reads references on the record's own scale)" if b.from_elsewhere else ""),
    ]
    return lines, info


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

    A parameter bundle (.json) gets its sections, held-out error, rest level, the output its
    drive range reaches and the runs it was fitted on.

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
            if path.suffix.lower() == ".json" and path.is_file():  # a bundle: what a person needs before compensate
                lines, info = _bundle_lines(path)
            else:
                run = read_run(path, allow_incomplete=allow_incomplete)
                lines, info = ([], _as_dict(run)) if as_json else (_describe(run), None)
        except PiezopressError as exc:
            bad += 1
            click.echo(f"Error: {exc}", err=True)
            docs.append({"path": path, "error": str(exc)})
            continue
        if as_json:
            docs.append(info)
        else:
            click.echo(("\n" if i else "") + "\n".join(lines))
    if as_json:
        emit_json({"runs": docs, "bad": bad})
    if bad:
        raise SystemExit(1)
