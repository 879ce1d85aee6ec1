"""``piezopress import``: a CSV/TSV measurement -> a Parquet run (see :mod:`piezopress.pipelines.importing`)."""

from __future__ import annotations

from pathlib import Path

import click

from piezopress.errors import ImportFormatError
from piezopress.piezocli.main import cli, next_command, reports_errors
from piezopress.pipelines.importing import import_file

# The two shared data sets, imported with one command each (also in the README's "Importing
# measured data"; the tests run exactly these commands).
HELP = """Convert a CSV/TSV measurement (SOURCE) into a run file (--out, never overwritten unless --replace,
which keeps the old one).

Map run columns to source columns with --col RUN_COLUMN=SOURCE_COLUMN, the source column
given as a number counted from 1 or as a header name. Run columns: t_s, command_v (required),
force_n and/or displacement_um (at least one), reference_n, monitor_v. Without a t_s column
give --sample-rate-hz; with one, the time column must be uniform within 1e-3 (jitter is
resampled to an exact grid, a gap is refused) and --sample-rate-hz, if given, is a check.
--scale and --offset convert units (value * scale + offset, to V, N, µm, s). --lag
RUN_COLUMN=N pairs the input of row i with that column's row i+N (dropping the ends).
--rows START:STOP keeps data rows START to STOP-1 of the input (counted from 0, after any
header). The source file's name and sha256 and every option are stored in the run's
metadata ("import"); show them with `piezopress inspect`.

Examples (data sets in ../shared/datasets, see its README.md; the README's "Importing measured data"):

\b
  # SmartHysteresis: +-150 V, 1 Hz sine, displacement in um, 5 kHz time column
  piezopress import ../shared/datasets/smarthysteresis/hysteresis_v_150_1hz.csv \\
      --out runs/smarthysteresis_150v_1hz.parquet --no-header --kind sine \\
      --col t_s=2 --col displacement_um=3 --col command_v=4 --sample-rate-hz 5000

\b
  # Aye & Ang 2018: 0-3.6 V amplifier input, raw capacitive sensor read one sample late
  piezopress import ../shared/datasets/aye-ang-2018/Model_Vi_Do.dat \\
      --out runs/aye_ang_model.parquet --no-header --delimiter tab --kind sine \\
      --col command_v=1 --col displacement_um=5 --lag displacement_um=1 --sample-rate-hz 200 \\
      --units-note "command_v: amplifier input, gain undocumented; displacement_um: raw sensor units (scale 1, arbitrary offset, about 1 um per unit)"
"""


def _pairs(option: str, items: tuple[str, ...], convert) -> dict[str, object]:
    """``("a=1", "b=2")`` -> ``{"a": convert("1"), ...}``, one-line errors naming the option."""
    out: dict[str, object] = {}
    for item in items:
        key, sep, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not sep or not key or not value:
            raise ImportFormatError(f"{option} {item!r}: expected RUN_COLUMN=VALUE, e.g. {option} displacement_um=3")
        if key in out:
            raise ImportFormatError(f"{option} {key} is given twice ({key}={out[key]} and {item}); expected it once")
        try:
            out[key] = convert(value)
        except ValueError:
            raise ImportFormatError(f"{option} {item!r}: {value!r} is not {convert.__doc__}") from None
    return out


def _source_column(text: str) -> int | str:
    """a column number or a header name"""
    return int(text) if text.isdigit() else text


def _number(text: str) -> float:
    """a number"""
    return float(text)


def _samples(text: str) -> int:
    """a whole number of samples"""
    return int(text)


def _rows(text: str | None) -> tuple[int | None, int | None] | None:
    if text is None:
        return None
    start, sep, stop = text.partition(":")
    try:
        if not sep:
            raise ValueError
        return (int(start) if start.strip() else None, int(stop) if stop.strip() else None)
    except ValueError:
        raise ImportFormatError(
            f"--rows {text!r}: expected START:STOP (counted from 0, STOP excluded), e.g. --rows 0:8000 or --rows 11151:"
        ) from None


@cli.command("import", help=HELP, short_help="Convert a CSV/TSV measurement into a run file.")
@click.argument("source", type=click.Path(path_type=Path))
@click.option(
    "--out",
    "-o",
    required=True,
    type=click.Path(dir_okay=False, path_type=Path),
    help="Run file to write (.parquet); refused if it exists (see --replace).",
)
@click.option(
    "--col",
    "cols",
    multiple=True,
    metavar="RUN_COLUMN=SOURCE",
    help="Map a run column to a source column (number from 1, or header name). Repeat.",
)
@click.option(
    "--scale",
    "scales",
    multiple=True,
    metavar="RUN_COLUMN=FACTOR",
    help="Multiply a column to get V, N, µm or s. Repeat.",
)
@click.option(
    "--offset", "offsets", multiple=True, metavar="RUN_COLUMN=VALUE", help="Add to a column after scaling. Repeat."
)
@click.option(
    "--lag",
    "lags",
    multiple=True,
    metavar="RUN_COLUMN=SAMPLES",
    help="The column was recorded SAMPLES after the input (command_v). Repeat.",
)
@click.option(
    "--kind", default="custom", show_default=True, help="Run kind: triangle, step, creep, staircase, sine or custom."
)
@click.option("--name", default=None, help="Run name  [default: the source file name without suffix]")
@click.option(
    "--sample-rate-hz",
    "--sample-rate",
    "sample_rate_hz",
    type=float,
    default=None,
    metavar="HZ",
    help="Sample rate; required without a t_s column, checked against it otherwise.",
)
@click.option(
    "--delimiter", default="auto", show_default=True, help="auto, comma, tab, semicolon, whitespace or one character."
)
@click.option(
    "--decimal",
    type=click.Choice(["auto", "point", "comma"]),
    default="auto",
    show_default=True,
    help="Decimal mark of the numbers: auto detects a decimal comma (0,125) with ; or tab separators.",
)
@click.option(
    "--header/--no-header", default=None, help="Whether line 1 holds column names  [default: guessed from line 1]"
)
@click.option(
    "--rows",
    "rows_text",
    default=None,
    metavar="START:STOP",
    help="Keep these data rows of the input (from 0, STOP excluded; either end may be left out).",
)
@click.option("--keep-time", is_flag=True, help="Keep the source's time origin instead of starting t_s at 0.")
@click.option("--units-note", default=None, help="Note on units and assumptions, stored in the metadata.")
@click.option(
    "--replace", is_flag=True, help="Replace an existing --out (the old one is kept as <name>.replaced-<UTC time>)."
)
@reports_errors
def import_command(
    source: Path,
    out: Path,
    cols: tuple[str, ...],
    scales: tuple[str, ...],
    offsets: tuple[str, ...],
    lags: tuple[str, ...],
    kind: str,
    name: str | None,
    sample_rate_hz: float | None,
    delimiter: str,
    decimal: str,
    header: bool | None,
    rows_text: str | None,
    keep_time: bool,
    units_note: str | None,
    replace: bool,
) -> None:
    run, _sha, previous = import_file(
        source,
        out,
        replace=replace,
        columns=_pairs("--col", cols, _source_column),
        scales=_pairs("--scale", scales, _number),
        offsets=_pairs("--offset", offsets, _number),
        lag_samples=_pairs("--lag", lags, _samples),
        kind=kind,
        name=name,
        sample_rate_hz=sample_rate_hz,
        delimiter=None if delimiter == "auto" else delimiter,
        decimal=decimal,
        header=header,
        rows=_rows(rows_text),
        zero_time=not keep_time,
        units_note=units_note,
    )
    data = run.data
    t = data["t_s"].to_numpy()
    ranges = ", ".join(f"{c} {data[c].min():.6g}..{data[c].max():.6g}" for c in data.columns if c != "t_s")
    rows = run.meta["import"]["rows"]
    click.echo(
        f"Wrote {out}: {len(data)} samples at {run.sample_rate_hz:.6g} Hz ({t[-1] - t[0]:.6g} s), kind {run.kind}, "
        f"from rows {rows[0]}:{rows[1]} of {source.name}; {ranges}"
    )
    dropped = [
        f"{n} {what}"
        for n, what in (
            (run.meta["import"].get("blank_lines_dropped", 0), "blank line(s)"),
            (run.meta["import"].get("repeated_headers_dropped", 0), "repeated header line(s)"),
        )
        if n
    ]
    if dropped:
        click.echo(f"Note: {' and '.join(dropped)} among the data left out (not samples)", err=True)
    if previous is not None:
        click.echo(f"previous version kept as {previous}")
    next_command(f"piezopress fit {out} --out {out.with_suffix('.json')}")
