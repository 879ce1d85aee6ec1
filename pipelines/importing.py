"""Import a measurement stored as a CSV/TSV table as a run (see :mod:`piezopress.runformat`).

A table from another rig or a publication rarely looks like a run: columns in some order,
units of their own, a time column with clock jitter or no time column at all, an output
read one sample after the input. :func:`import_table` maps, scales, aligns and resamples
it, and records how it did so in the run's metadata (under ``"import"``), so that the run
can be traced back to the exact source file (its sha256) and options.

Conventions
-----------
* Source columns are numbered from 1, as people count them (and as the data sets'
  READMEs do); a column may also be named by its header text.
* Source rows are counted from 0 over the data rows (after any header), and a range
  ``(start, stop)`` excludes ``stop``, as Python slices do.
* A lag of ``N`` samples on an output column pairs the input of row ``i`` with the output
  of row ``i + N``; rows left without a partner at the ends are dropped.

Every problem raises :class:`~piezopress.errors.ImportFormatError` with one line naming
the file, the column or option and what was expected.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from piezopress import __version__
from piezopress.errors import ImportFormatError
from piezopress.pipelines.files import check_output, write_output
from piezopress.runformat import (
    KINDS,
    KNOWN_COLUMNS,
    OUTPUT_COLUMNS,
    UNIFORM_RTOL,
    Run,
    make_meta,
    make_run,
    sha256_file,
    write_run,
)

#: Delimiters by name; ``None`` (or ``"auto"``) picks one from the first line.
DELIMITERS = {"comma": ",", "tab": "\t", "semicolon": ";", "whitespace": r"\s+"}
#: Columns whose lag is counted against ``command_v``: everything but time and the input.
LAGGABLE_COLUMNS = tuple(c for c in KNOWN_COLUMNS if c not in ("t_s", "command_v"))
_NAN_TEXT = {"nan", "na", "n/a", "null", "none", "-nan", "+nan"}


def import_table(
    path: str | os.PathLike[str],
    *,
    columns: Mapping[str, int | str],
    kind: str = "custom",
    name: str | None = None,
    sample_rate_hz: float | None = None,
    delimiter: str | None = None,
    decimal: str | None = None,
    header: bool | None = None,
    scales: Mapping[str, float] | None = None,
    offsets: Mapping[str, float] | None = None,
    lag_samples: Mapping[str, int] | None = None,
    rows: tuple[int | None, int | None] | None = None,
    zero_time: bool = True,
    units_note: str | None = None,
) -> Run:
    """Read a CSV/TSV measurement and return it as a validated run.

    Parameters
    ----------
    path : path-like
        The table: one sample per line, numbers separated by commas, tabs, semicolons or
        whitespace.
    columns : mapping
        Run column -> source column, as a 1-based number or a header name. Needs
        ``command_v`` and ``force_n`` and/or ``displacement_um``; ``t_s`` is optional.
    kind : str
        One of :data:`piezopress.runformat.KINDS`.
    name : str, optional
        Name of the run; defaults to the file name without its suffix.
    sample_rate_hz : float, optional
        Required without a ``t_s`` column (time is then ``k / sample_rate_hz``). With one,
        a check: the rate measured from the time column must agree within 1e-3.
    delimiter : str, optional
        ``"comma"``, ``"tab"``, ``"semicolon"``, ``"whitespace"``, a single character, or
        ``None``/``"auto"`` to pick one from the first line.
    decimal : str, optional
        ``"point"`` (``.``), ``"comma"`` (``,``: a European export, with ``;`` or tab between
        fields), or ``None``/``"auto"``: a comma when the first data line's fields are numbers
        written with one and the fields are not comma-separated.
    header : bool, optional
        Whether the first line holds column names; ``None`` decides from the first line
        (all text: a header; all numbers: data; a mix: an error asking to say which).
    scales, offsets : mapping, optional
        Run column -> factor, and -> offset added after scaling, converting the source's
        units to the run's (V, N, µm, s).
    lag_samples : mapping, optional
        Run column -> samples by which it was recorded after the input (``command_v``);
        an integer, negative if it was recorded before. Not for ``t_s`` and ``command_v``.
    rows : (start, stop), optional
        Data rows of the input to keep (0-based, ``stop`` excluded, ``None`` for an open end).
    zero_time : bool
        Start ``t_s`` at 0 (the source's origin is kept in the metadata); otherwise keep
        the source's time (or ``start / sample_rate_hz`` without a time column).
    units_note : str, optional
        Free text on units and assumptions, stored as metadata ``units_note``.

    Returns
    -------
    Run
        With ``t_s`` regenerated on an exact uniform grid ``t0 + k / fs`` and metadata
        ``import`` recording the source file, its sha256 and every option.

    Raises
    ------
    ImportFormatError
        On the first problem, in one line naming the file, the column or option and what
        was expected.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> src = Path(tempfile.mkdtemp()) / "ramp.csv"
    >>> _ = src.write_text("t,u,x\\n0,0,0\\n0.001,1,0.5\\n0.002,2,1.0\\n")
    >>> run = import_table(src, columns={"t_s": "t", "command_v": "u", "displacement_um": "x"},
    ...                    scales={"displacement_um": 1000.0})
    >>> run.sample_rate_hz, run.data["displacement_um"].tolist()
    (1000.0, [0.0, 500.0, 1000.0])
    """
    path = Path(path)
    label = str(path)
    _check_options(label, columns, kind, name, sample_rate_hz)
    scales = _check_numbers(label, "scale", scales, columns, nonzero=True)
    offsets = _check_numbers(label, "offset", offsets, columns, nonzero=False)
    lags = _check_lags(label, lag_samples, columns)

    source = _read_table(
        path, delimiter, header, DECIMALS.get(decimal, decimal) if isinstance(decimal, str) else decimal
    )
    delim_name, has_header, skipped, n_cols = source.delim_name, source.header, source.skipped, source.n_cols
    first_line = skipped + (2 if has_header else 1)  # file line of data row 0

    index = {target: _resolve_column(label, target, spec, source.names, n_cols) for target, spec in columns.items()}
    numbers, n_rows = source.read_columns(sorted(set(index.values())))  # streamed: only the mapped columns, as floats
    if n_rows == 0:
        raise ImportFormatError(f"{label}: has a header but no data rows; expected rows of numbers below it")

    # Rows of the input kept: within the requested range and with a partner at every lag.
    start, stop = _check_rows(label, rows, n_rows)
    lo = max([start] + [-lag for lag in lags.values()])
    hi = min([stop] + [n_rows - lag for lag in lags.values()])
    if hi - lo < 2:
        raise ImportFormatError(
            f"{label}: rows {start}:{stop} with lag {_fmt_mapping(lags)} leave {max(hi - lo, 0)} sample(s); expected "
            "at least 2"
        )

    values: dict[str, np.ndarray] = {}
    for target in KNOWN_COLUMNS:
        if target not in index:
            continue
        lag = lags.get(target, 0)
        col = index[target]
        raw = numbers[col][lo + lag : hi + lag]
        bad = ~np.isfinite(raw)
        if bad.any():
            i = int(np.argmax(bad))
            _bad_cell(label, source.cell(lo + lag + i, col), col, target, lo + lag + i, first_line, int(bad.sum()))
        scale, offset = scales.get(target, 1.0), offsets.get(target, 0.0)
        if (scale, offset) != (1.0, 0.0):
            with np.errstate(over="ignore", invalid="ignore"):
                raw = raw * scale + offset
            if not np.isfinite(raw).all():
                raise ImportFormatError(
                    f"{label}: scale {target}={scale:g} with offset {offset:g} makes column {col + 1} overflow to "
                    "infinity; expected a scale and offset that convert to V, N, µm or s"
                )
        values[target] = raw

    time_info: dict[str, Any]
    if "t_s" in values:
        t0, step, jitter = _uniform_step(label, values["t_s"], index["t_s"], lo, first_line)
        fs = 1.0 / step
        if sample_rate_hz is not None and abs(fs - sample_rate_hz) > UNIFORM_RTOL * sample_rate_hz:
            raise ImportFormatError(
                f"{label}: sample rate {sample_rate_hz:g} Hz given but time column {index['t_s'] + 1} is sampled at "
                f"{fs:.6g} Hz; expected them to agree within {UNIFORM_RTOL:.0e}"
            )
        time_info = {"time_source": f"column {index['t_s'] + 1}", "time_step_max_jitter": jitter}
    else:
        fs = float(sample_rate_hz)  # checked by _check_options
        t0 = lo / fs
        time_info = {"time_source": "sample rate"}
    n = hi - lo
    origin = 0.0 if zero_time else t0
    values["t_s"] = origin + np.arange(n) / fs
    time_info["time_origin_s"] = float(t0)

    provenance = {
        "importer": "piezopress.pipelines.importing",
        "importer_version": __version__,
        "imported_utc": datetime.now(UTC).isoformat(timespec="seconds"),
        "source_file": path.name,
        "source_sha256": sha256_file(path),
        "source_rows": n_rows,
        "source_columns": n_cols,
        "delimiter": delim_name,
        "decimal": "comma" if source.decimal == "," else "point",
        "repeated_headers_dropped": source.repeated_headers,
        "blank_lines_dropped": source.blank_lines,
        "header": has_header,
        "columns": {t: columns[t] for t in KNOWN_COLUMNS if t in columns},
        "column_numbers": {t: index[t] + 1 for t in KNOWN_COLUMNS if t in index},
        "scales": {t: scales.get(t, 1.0) for t in KNOWN_COLUMNS if t in index},
        "offsets": {t: offsets.get(t, 0.0) for t in KNOWN_COLUMNS if t in index},
        "lag_samples": dict(lags),
        "rows": [lo, hi],
        "zero_time": zero_time,
        **time_info,
    }
    extra: dict[str, Any] = {"units_note": units_note} if units_note else {}
    meta = make_meta(kind, name or path.stem, fs, **extra, **{"import": provenance})
    ordered = {c: values[c] for c in KNOWN_COLUMNS if c in values}
    return make_run(ordered, meta, label=label)


def import_file(
    source: str | os.PathLike[str], out: str | os.PathLike[str], *, replace: bool = False, **options: Any
) -> tuple[Run, str, Path | None]:
    """Import ``source`` (see :func:`import_table`) and write it to ``out``; an existing ``out``
    is replaced only with ``replace``, its old version kept under a unique timestamped name.

    Returns the run (with its ``path``), the sha256 of the written file and where the
    replaced file was kept (``None``: nothing replaced).

    Raises
    ------
    OutputExistsError
        If ``out`` exists without ``replace`` (checked before reading and again when writing).
    ImportFormatError
        As :func:`import_table`.
    """
    out = Path(out)
    check_output(out, replace=replace)  # checked first so as not to spend time on the source
    run = import_table(source, **options)
    previous = write_output(out, lambda tmp: write_run(run, tmp), replace=replace)
    return Run(run.data, run.meta, out), sha256_file(out), previous


def parse_delimiter(text: str | None, label: str = "delimiter") -> tuple[str, str] | None:
    """``(name, pandas separator)`` for a delimiter given by name or as one character."""
    if text is None or text == "auto":
        return None
    if text in DELIMITERS:
        return text, DELIMITERS[text]
    if text in ("\\t", "\t"):
        return "tab", "\t"
    if len(text) == 1 and text not in "\"'\n\r0123456789.-+eE":
        name = next((k for k, v in DELIMITERS.items() if v == text), repr(text))
        return name, text
    raise ImportFormatError(
        f"{label}: delimiter {text!r} is not understood; expected auto, {', '.join(DELIMITERS)} or a single character"
    )


# --- helpers -------------------------------------------------------------------------


def _fmt_mapping(mapping: Mapping[str, Any]) -> str:
    return ", ".join(f"{k}={v}" for k, v in mapping.items()) or "none"


def _check_options(
    label: str, columns: Mapping[str, Any], kind: str, name: str | None, sample_rate_hz: float | None
) -> None:
    if kind not in KINDS:
        raise ImportFormatError(f"{label}: kind {kind!r} is not known; expected one of {', '.join(KINDS)}")
    if name is not None and not str(name).strip():
        raise ImportFormatError(f"{label}: name is empty; expected a non-empty name (or none for the file name)")
    for target in columns:
        if target not in KNOWN_COLUMNS:
            raise ImportFormatError(
                f"{label}: unknown run column {target!r} in column mapping {target}={columns[target]}; "
                f"expected one of {', '.join(KNOWN_COLUMNS)}"
            )
    if "command_v" not in columns or not any(c in columns for c in OUTPUT_COLUMNS):
        raise ImportFormatError(
            f"{label}: column mapping {_fmt_mapping(columns)} lacks "
            f"{'command_v' if 'command_v' not in columns else 'a measured output'}; "
            f"expected command_v=N and force_n=N and/or displacement_um=N"
        )
    if sample_rate_hz is not None and not (math.isfinite(sample_rate_hz) and sample_rate_hz > 0):
        raise ImportFormatError(f"{label}: sample rate {sample_rate_hz!r} Hz; expected a positive number")
    if "t_s" not in columns and sample_rate_hz is None:
        raise ImportFormatError(
            f"{label}: no time column mapped and no sample rate given; expected t_s=N in the column mapping or a "
            "sample rate"
        )


def _check_numbers(
    label: str, what: str, given: Mapping[str, float] | None, columns: Mapping[str, Any], *, nonzero: bool
) -> dict[str, float]:
    out: dict[str, float] = {}
    for target, value in (given or {}).items():
        if target not in columns:
            raise ImportFormatError(
                f"{label}: {what} {target}={value} for a column that is not mapped; expected one of "
                f"{', '.join(columns)}"
            )
        try:
            number = float(value)
        except (TypeError, ValueError):
            number = math.nan
        if not math.isfinite(number) or (nonzero and number == 0):
            expected = "a finite non-zero number" if nonzero else "a finite number"
            raise ImportFormatError(f"{label}: {what} {target}={value!r}; expected {expected}")
        out[target] = number
    return out


def _check_lags(label: str, given: Mapping[str, int] | None, columns: Mapping[str, Any]) -> dict[str, int]:
    out: dict[str, int] = {}
    for target, value in (given or {}).items():
        if target not in LAGGABLE_COLUMNS:
            raise ImportFormatError(
                f"{label}: lag {target}={value}; expected a lag on one of {', '.join(LAGGABLE_COLUMNS)} "
                f"(lags count against command_v)"
            )
        if target not in columns:
            raise ImportFormatError(
                f"{label}: lag {target}={value} for a column that is not mapped; expected one of {', '.join(columns)}"
            )
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise ImportFormatError(f"{label}: lag {target}={value!r}; expected a whole number of samples")
        out[target] = int(value)
    return out


def _check_rows(label: str, rows: tuple[int | None, int | None] | None, n_rows: int) -> tuple[int, int]:
    if rows is None:
        return 0, n_rows
    start, stop = rows
    start = 0 if start is None else int(start)
    stop = n_rows if stop is None else int(stop)
    if not 0 <= start < stop <= n_rows:
        raise ImportFormatError(
            f"{label}: rows {start}:{stop} are outside the file's {n_rows} data rows; "
            f"expected 0 <= start < stop <= {n_rows} (0-based, stop excluded)"
        )
    return start, stop


def _first_line(path: Path, label: str) -> tuple[str | None, int]:
    """The first non-blank line and how many blank lines precede it."""
    try:
        with open(path, encoding="utf-8-sig") as fh:
            for i, line in enumerate(fh):
                if line.strip():
                    return line.rstrip("\r\n"), i
    except UnicodeDecodeError as exc:
        raise ImportFormatError(
            f"{label}: is not UTF-8 text (byte {exc.start}); expected a CSV/TSV text file"
        ) from None
    return None, 0


def _split(line: str, sep: str) -> list[str]:
    """The fields of a line, each without the quotes a spreadsheet puts around it."""
    fields = line.split() if sep == r"\s+" else [f.strip() for f in line.split(sep)]
    return [f[1:-1].strip() if len(f) >= 2 and f[0] == f[-1] and f[0] in "\"'" else f for f in fields]


def _is_number(text: str, decimal: str = ".") -> bool:
    try:
        float(text.replace(",", ".") if decimal == "," else text)
    except ValueError:
        return False
    return True


#: A number written with a decimal comma (``0,125``, ``-1,5e-3``): a European spreadsheet's or LabVIEW's export.
_COMMA_NUMBER = __import__("re").compile(r"^[+-]?\d+,\d+([eE][+-]?\d+)?$")
DECIMALS = {"auto": None, "point": ".", "comma": ","}


def _guess_decimal(fields: list[str], sep: str) -> str:
    """``,`` when the delimiter is not a comma and the fields are numbers with a decimal comma."""
    if sep == ",":
        return "."
    comma = [bool(_COMMA_NUMBER.match(f)) for f in fields if f]
    return "," if comma and sum(comma) >= max(1, len(comma) // 2) else "."


#: Largest source file imported: above it, the reason and what to do (select a segment first).
MAX_IMPORT_BYTES = 1_000_000_000
#: Rows read at a time: the table is streamed, only the mapped columns kept, as float64.
CHUNK_ROWS = 100_000


class _Table:
    """A CSV/TSV source, read a chunk at a time: its delimiter, header and shape."""

    def __init__(self, path: Path, sep: str, delim_name: str, header: bool, skipped: int, decimal: str = "."):
        self.path, self.label, self.sep, self.delim_name, self.header, self.skipped = (
            path,
            str(path),
            sep,
            delim_name,
            header,
            skipped,
        )
        self.decimal = decimal
        self.repeated_headers = 0  # a header line repeated among the data (an export appended to): dropped
        self.blank_lines = 0  # blank lines among the data: dropped
        self.lines: np.ndarray | None = None
        first = self._read(nrows=1)
        if len(first) == 0:
            raise ImportFormatError(f"{self.label}: is empty; expected rows of numbers")
        self.n_cols = first.shape[1]
        self.names = [str(v).strip() for v in first.iloc[0]] if header else None

    def _read(self, **options: Any) -> Any:
        try:
            return pd.read_csv(
                self.path,
                sep=self.sep,
                header=None,
                dtype=str,
                keep_default_na=False,
                skip_blank_lines=False,
                encoding="utf-8-sig",
                engine="c",
                **{"skiprows": self.skipped, **options},
            )
        except pd.errors.EmptyDataError:
            raise ImportFormatError(f"{self.label}: is empty; expected rows of numbers") from None
        except pd.errors.ParserError as exc:
            raise self._parser_error(exc) from None
        except UnicodeDecodeError as exc:
            raise ImportFormatError(
                f"{self.label}: is not UTF-8 text (byte {exc.start}); expected a CSV/TSV text file"
            ) from None

    def _parser_error(self, exc: Exception) -> ImportFormatError:
        first = str(exc).strip().splitlines()[0]
        return ImportFormatError(
            f"{self.label}: cannot be split into columns with delimiter {self.delim_name} ({first}); "
            "expected the same number of fields on every line"
        )

    def read_columns(self, cols: list[int]) -> tuple[dict[int, np.ndarray], int]:
        """Columns ``cols`` (0-based) of every data row as float64 (NaN where a cell is not a
        number) and the number of data rows. Blank lines are not data (those among the data are
        counted in :attr:`blank_lines`), nor is a repeated header (:attr:`repeated_headers`)."""
        parts: dict[int, list[np.ndarray]] = {c: [] for c in cols}
        kept: list[np.ndarray] = []  # the file's line (after the skipped ones) of each kept row
        offset = 0
        try:
            for chunk in self._read(
                chunksize=CHUNK_ROWS
            ):  # every field (a line with too many is refused), one chunk at a time
                line = offset + np.arange(len(chunk))
                keep = (chunk.notna() & (chunk != "")).any(axis=1).to_numpy().copy()
                if self.header and self.names is not None:  # a header repeated among the data is not data
                    again = np.ones(len(chunk), bool)
                    for k, name in enumerate(self.names):
                        again &= chunk[k].astype(str).str.strip().to_numpy() == name
                    if offset == 0:
                        again[0] = False  # the header itself
                    self.repeated_headers += int(again.sum())
                    keep &= ~again
                offset += len(chunk)
                if not keep.any():
                    continue
                chunk = chunk[keep]
                kept.append(line[keep])
                for c in cols:
                    text = chunk[c].astype(str).str.strip()
                    if self.decimal == ",":
                        text = text.str.replace(",", ".", regex=False)
                    parts[c].append(pd.to_numeric(text, errors="coerce").to_numpy(dtype=np.float64))
        except pd.errors.ParserError as exc:
            raise self._parser_error(exc) from None
        except UnicodeDecodeError as exc:
            raise ImportFormatError(
                f"{self.label}: is not UTF-8 text (byte {exc.start}); expected a CSV/TSV text file"
            ) from None
        if not kept:
            raise ImportFormatError(f"{self.label}: is empty; expected rows of numbers")
        head = 1 if self.header else 0
        lines = np.concatenate(kept)[head:]
        # blank lines between the first and the last data row (those at the end are not counted)
        span = int(lines[-1] - lines[0] + 1) if lines.size else 0
        self.blank_lines = max(span - lines.size - self.repeated_headers, 0)
        self.lines = lines - head  # data row (counted from 0 after any header, blanks included) of each row
        columns = {c: np.concatenate(parts[c])[head:] for c in cols}
        return columns, int(lines.size)

    def cell(self, row: int, col: int) -> str:
        """The text of data row ``row``, column ``col`` (0-based), read again for a message."""
        if self.lines is not None and 0 <= row < self.lines.size:
            row = int(self.lines[row])
        found = self._read(skiprows=self.skipped + (1 if self.header else 0) + row, nrows=1)
        # a short line has no such field: an empty cell, as the message says
        return str(found.iloc[0, col]).strip() if len(found) and col < found.shape[1] else ""


def _read_table(path: Path, delimiter: str | None, header: bool | None, decimal: str | None = None) -> _Table:
    """The source, its delimiter and header decided from its first line, refused above
    :data:`MAX_IMPORT_BYTES`; its columns are read later, streamed."""
    label = str(path)
    if not path.exists():
        raise ImportFormatError(f"{label}: no such file; expected a CSV/TSV measurement")
    if not path.is_file():
        raise ImportFormatError(f"{label}: is not a file; expected a CSV/TSV measurement")
    size = path.stat().st_size
    if size > MAX_IMPORT_BYTES:
        raise ImportFormatError(
            f"{label}: is {size / 1e9:.3g} GB, above the import limit of {MAX_IMPORT_BYTES / 1e9:g} GB (a run of that "
            "length would not fit in memory); expected a smaller file: cut the segment you need first (head/tail, "
            "split)"
        )
    line, skipped = _first_line(path, label)
    if line is None:
        raise ImportFormatError(f"{label}: is empty; expected rows of numbers separated by commas, tabs or whitespace")

    chosen = parse_delimiter(delimiter, label)
    if chosen is None:
        for name in ("tab", "semicolon", "comma"):
            if DELIMITERS[name] in line:
                chosen = name, DELIMITERS[name]
                break
        else:
            chosen = "whitespace", DELIMITERS["whitespace"]
    delim_name, sep = chosen
    if decimal not in (None, ".", ","):
        raise ImportFormatError(f"{label}: decimal {decimal!r}; expected point (.) or comma (,)")
    if decimal == "," and sep == ",":
        raise ImportFormatError(
            f"{label}: a decimal comma with comma-separated fields cannot be read; expected --delimiter semicolon "
            "(or tab) with --decimal comma"
        )
    if decimal is None:
        decimal = _guess_decimal(_split(_data_line(path, line, skipped), sep), sep)

    if header is None:
        fields = [f for f in _split(line, sep) if f]
        numeric = [_is_number(f, decimal) for f in fields]
        if all(numeric):
            header = False
        elif not any(numeric):
            header = True
        else:
            raise ImportFormatError(
                f"{label}: line 1 mixes numbers and text ({line[:60]!r}); expected to be told whether it is a header "
                "(--header/--no-header)"
            )
    return _Table(path, sep, delim_name, bool(header), skipped, decimal)


def _data_line(path: Path, first: str, skipped: int) -> str:
    """The first line, or the line after it when the first holds text (a header)."""
    if any(ch.isdigit() for ch in first) and not any(ch.isalpha() and ch not in "eE" for ch in first):
        return first
    with open(path, encoding="utf-8-sig") as fh:
        lines = [ln for _, ln in zip(range(skipped + 2), fh)]
    return lines[-1].rstrip("\r\n") if len(lines) == skipped + 2 else first


def _resolve_column(label: str, target: str, spec: int | str, names: list[str] | None, n_cols: int) -> int:
    """0-based index of a source column given as a 1-based number or a header name."""
    if isinstance(spec, (int, np.integer)) and not isinstance(spec, bool):
        number = int(spec)
    elif isinstance(spec, str) and spec.strip().isdigit():
        number = int(spec.strip())
    elif isinstance(spec, str) and spec.strip():
        if names is None:
            raise ImportFormatError(
                f"{label}: column mapping {target}={spec} names a column but the file has no header; "
                f"expected a column number from 1 to {n_cols}"
            )
        if spec.strip() not in names:
            raise ImportFormatError(
                f"{label}: column mapping {target}={spec}: no such header; expected a column number from 1 to {n_cols} "
                f"or one of {', '.join(repr(n) for n in names)}"
            )
        return names.index(spec.strip())
    else:
        raise ImportFormatError(f"{label}: column mapping {target}={spec!r}; expected a column number or a header name")
    if not 1 <= number <= n_cols:
        raise ImportFormatError(
            f"{label}: column mapping {target}={number}: the file has {n_cols} column(s); "
            f"expected a column number from 1 to {n_cols} (counted from 1)"
        )
    return number - 1


def _bad_cell(label: str, cell: str, col: int, target: str, row: int, first_line: int, count: int) -> None:
    """Raise the one line for the first cell of a column that is not a finite number."""
    where = f"at data row {row} (line {row + first_line}), column {col + 1} ({target})"
    if cell == "":
        raise ImportFormatError(f"{label}: empty cell {where}; expected a number")
    value = pd.to_numeric(pd.Series([cell]), errors="coerce").iloc[0]
    if cell.lower() in _NAN_TEXT or (not np.isnan(value) and not np.isfinite(value)):
        raise ImportFormatError(f"{label}: {cell} {where} ({count} such cell(s)); expected finite numbers")
    hint = ""
    if _COMMA_NUMBER.match(cell):
        hint = " (a number with a decimal comma: give --decimal comma, with --delimiter semicolon or tab)"
    elif cell.replace(".", "", 1).replace(",", "").lstrip("+-").isdigit() and "," in cell:
        hint = " (thousands separators are not read: export without them)"
    raise ImportFormatError(f"{label}: non-numeric cell {cell[:40]!r} {where}; expected a number{hint}")


def _uniform_step(label: str, t: np.ndarray, col: int, row0: int, first_line: int) -> tuple[float, float, float]:
    """``(t0, mean step, largest relative deviation of a step)``; rejects gaps and reversals.

    Clock jitter (SmartHysteresis: 1e-4 of the step) is accepted and later replaced by an
    exact grid; a missing or repeated sample (a deviation of 100 %) is not.
    """
    dt = np.diff(t)
    where = lambda i: f"data row {row0 + i + 1} (line {row0 + i + 1 + first_line})"  # noqa: E731
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0))
        raise ImportFormatError(
            f"{label}: time column {col + 1} does not increase at {where(i)} ({t[i]!r} then {t[i + 1]!r}); "
            f"expected strictly increasing time"
        )
    step = (t[-1] - t[0]) / (len(t) - 1)
    dev = np.abs(dt - step) / step
    i = int(np.argmax(dev))
    if dev[i] > UNIFORM_RTOL:
        raise ImportFormatError(
            f"{label}: time column {col + 1} is not uniformly sampled: step {dt[i]:.6g} s at {where(i)} against a "
            "mean of "
            f"{step:.6g} s; expected every step within {UNIFORM_RTOL:.0e} of the mean (a gap? select a segment with "
            "rows)"
        )
    return float(t[0]), float(step), float(dev[i])
