"""The run format, schema version 1: one Parquet file per run.

Columns (all float64):

==================  ========  =====================================================
``t_s``             required  seconds from the start of the run, uniform, increasing
``command_v``       required  commanded actuator voltage (after the amplifier gain)
``force_n``         output    measured force (at least one output is required)
``displacement_um`` output    measured displacement
``reference_n``     optional  reference force of a compensated run
``monitor_v``       optional  amplifier voltage monitor
==================  ========  =====================================================

File metadata under the key ``piezopress`` is a JSON object with at least
``schema_version`` (1), ``kind`` (see :data:`KINDS`), ``name`` and ``sample_rate_hz``.
Anything else that makes the run reproducible (protocol, backend, rig, seed, software
version, UTC time) is carried along untouched.

Every reader of runs goes through :func:`read_run`, which rejects a bad file with one
line naming the file, what is wrong and what was expected.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from piezopress import units
from piezopress.errors import OutputExistsError, RunFormatError, output_error

SCHEMA_VERSION = 1
METADATA_KEY = b"piezopress"
KINDS = ("triangle", "step", "creep", "staircase", "sine", "custom")
REQUIRED_COLUMNS = ("t_s", "command_v")
OUTPUT_COLUMNS = ("force_n", "displacement_um")
OPTIONAL_COLUMNS = ("reference_n", "monitor_v")
KNOWN_COLUMNS = REQUIRED_COLUMNS + OUTPUT_COLUMNS + OPTIONAL_COLUMNS
#: Largest magnitude of any value of a run (s, V, N, µm): beyond it, arithmetic on the data overflows.
MAX_MAGNITUDE = 1e12
REQUIRED_METADATA = ("schema_version", "kind", "name", "sample_rate_hz")
#: Relative tolerance on the sampling interval: a dropped or duplicated sample is a 100 %
#: deviation, clock jitter in real files (SmartHysteresis: 5e-5) is far below this.
UNIFORM_RTOL = 1e-3
#: Metadata ``status`` of a run that did not finish (interrupted, aborted). Such runs are
#: kept, never mistaken for finished ones: :func:`read_run` refuses them unless asked.
STATUS_COMPLETE = "complete"
STATUS_INCOMPLETE = "incomplete"
#: How run metadata and manifests write a time (UTC, to the second): ``started_utc``, ``created_utc``.
TIMESTAMP_FORMAT = "%Y-%m-%dT%H:%M:%SZ"


@dataclass(frozen=True)
class Run:
    """One run: its columns and its metadata.

    Parameters
    ----------
    data : pandas.DataFrame
        The columns, at least ``t_s``, ``command_v`` and one of ``force_n``/``displacement_um``.
    meta : dict
        The ``piezopress`` metadata object.
    path : pathlib.Path or None
        Where the run was read from, if it was.
    """

    data: pd.DataFrame
    meta: dict[str, Any] = field(default_factory=dict)
    path: Path | None = None
    #: What the signals say the run is (:class:`piezopress.analysis.profile.RunProfile`),
    #: attached by the stage that reads it; ``None`` until measured.
    profile: Any = field(default=None, compare=False, repr=False)

    @property
    def name(self) -> str:
        return str(self.meta["name"])

    @property
    def kind(self) -> str:
        return str(self.meta["kind"])

    @property
    def sample_rate_hz(self) -> float:
        return float(self.meta["sample_rate_hz"])

    @property
    def t_s(self) -> np.ndarray:
        return self.data["t_s"].to_numpy()

    @property
    def command_v(self) -> np.ndarray:
        return self.data["command_v"].to_numpy()

    @property
    def output_column(self) -> str:
        """The measured output: ``force_n`` when present, else ``displacement_um``."""
        return "force_n" if "force_n" in self.data.columns else "displacement_um"

    @property
    def output_unit(self) -> str:
        """Unit code of the measured output: ``N`` (force) or ``um`` (displacement)."""
        return units.unit_of_column(self.output_column)

    @property
    def output(self) -> np.ndarray:
        return self.data[self.output_column].to_numpy()

    def column(self, name: str) -> np.ndarray | None:
        return self.data[name].to_numpy() if name in self.data.columns else None

    @property
    def label(self) -> str:
        """How to name this run in a message: its file when it has one, else its name."""
        return str(self.path) if self.path is not None else f"run {self.meta.get('name', '?')!r}"


def _problem(label: str, what: str) -> RunFormatError:
    return RunFormatError(f"{label}: {what}")


def validate(data: pd.DataFrame, meta: Mapping[str, Any], label: str, *, allow_incomplete: bool = False) -> None:
    """Check a frame and its metadata against schema version 1.

    Raises
    ------
    RunFormatError
        On the first problem found, with one line naming ``label``, the problem and what
        was expected.
    """
    if not isinstance(meta, Mapping):
        raise _problem(label, f"metadata is {type(meta).__name__}, expected a JSON object")
    missing_meta = [k for k in REQUIRED_METADATA if k not in meta]
    if missing_meta:
        raise _problem(label, f"metadata lacks {', '.join(missing_meta)}; expected keys {', '.join(REQUIRED_METADATA)}")
    version = meta["schema_version"]
    if isinstance(version, bool) or version != SCHEMA_VERSION:  # true == 1 in Python, not in a schema
        raise _problem(label, f"schema_version is {version!r}, expected {SCHEMA_VERSION}")
    if meta["kind"] not in KINDS:
        raise _problem(label, f"kind is {meta['kind']!r}, expected one of {', '.join(KINDS)}")
    if not isinstance(meta["name"], str) or not meta["name"]:
        raise _problem(label, f"name is {meta['name']!r}, expected a non-empty string")
    status = meta.get("status", STATUS_COMPLETE)
    if status != STATUS_COMPLETE and not allow_incomplete:
        reason = meta.get("status_reason", "no reason recorded")
        raise _problem(label, f"run is marked {status!r} ({reason}), expected a complete run")
    if isinstance(meta["sample_rate_hz"], bool):
        raise _problem(label, f"sample_rate_hz is {meta['sample_rate_hz']!r}, expected a positive number")
    try:
        fs = float(meta["sample_rate_hz"])
    except (TypeError, ValueError):
        raise _problem(label, f"sample_rate_hz is {meta['sample_rate_hz']!r}, expected a positive number") from None
    if not np.isfinite(fs) or fs <= 0:
        raise _problem(label, f"sample_rate_hz is {fs}, expected a positive number")

    missing = [c for c in REQUIRED_COLUMNS if c not in data.columns]
    if missing:
        raise _problem(
            label,
            f"missing column {', '.join(missing)}; expected columns t_s, command_v and force_n and/or displacement_um",
        )
    if not any(c in data.columns for c in OUTPUT_COLUMNS):
        raise _problem(
            label,
            "no measured output; expected a column force_n and/or displacement_um (columns: "
            f"{', '.join(map(str, data.columns))})",
        )
    if len(data) < 2:
        raise _problem(label, f"has {len(data)} sample(s), expected at least 2")
    for col in KNOWN_COLUMNS:
        if col not in data.columns:
            continue
        values = data[col]
        if not pd.api.types.is_float_dtype(values.dtype) or values.dtype != np.float64:
            raise _problem(label, f"column {col} has type {values.dtype}, expected float64")
        arr = values.to_numpy()
        bad = ~np.isfinite(arr)
        if bad.any():
            i = int(np.argmax(bad))
            raise _problem(
                label,
                f"column {col} has {int(bad.sum())} NaN/infinite value(s), first at row {i}; expected finite numbers",
            )

    for col in data.columns:  # columns beyond the known ones are kept, but as numbers too (all float64, finite)
        if col in KNOWN_COLUMNS:
            continue
        if data[col].dtype != np.float64:
            raise _problem(
                label,
                f"extra column {str(col)[:60]!r} has type {data[col].dtype}, expected float64 (every column of a run "
                "is a number)",
            )
        if not np.isfinite(data[col].to_numpy()).all():
            raise _problem(label, f"extra column {str(col)[:60]!r} has NaN/infinite values; expected finite numbers")
    for col in data.columns:
        big = np.abs(data[col].to_numpy()) > MAX_MAGNITUDE
        if big.any():
            i = int(np.argmax(big))
            raise _problem(
                label,
                f"column {str(col)[:60]} holds {data[col].iloc[i]:g} at row {i}; expected magnitudes below "
                f"{MAX_MAGNITUDE:g} "
                "(no press measures that: a unit or scale error?)",
            )

    t = data["t_s"].to_numpy()
    dt = np.diff(t)
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0))
        raise _problem(
            label,
            f"t_s is not strictly increasing at row {i + 1} ({t[i]!r} then {t[i + 1]!r}); expected strictly "
            "increasing time",
        )
    dt_nominal = (t[-1] - t[0]) / (len(t) - 1)
    dev = np.abs(dt - dt_nominal)
    if dev.max() > UNIFORM_RTOL * dt_nominal:
        i = int(np.argmax(dev))
        raise _problem(
            label,
            f"t_s is not uniformly sampled: step {dt[i]:.6g} s at row {i + 1} against a mean of {dt_nominal:.6g} s; "
            f"expected every step within {UNIFORM_RTOL:.0e} of the mean",
        )
    fs_from_t = 1.0 / dt_nominal
    if abs(fs_from_t - fs) > 1e-3 * fs:
        raise _problem(
            label,
            f"sample_rate_hz is {fs:g} but t_s is sampled at {fs_from_t:.6g} Hz; expected them to agree within 0.1 %",
        )


def meta_get(meta: Any, *keys: str, default: Any = None) -> Any:
    """``meta[k1][k2]...``, or ``default`` where a key is missing or a level is not a JSON
    object: metadata written by other programs may hold any type at any key (a ``rig`` that
    is a string, a ``protocol`` that is a list), and reading it must never raise."""
    cur = meta
    for k in keys:
        if not isinstance(cur, Mapping) or k not in cur:
            return default
        cur = cur[k]
    return cur


def meta_number(meta: Any, *keys: str) -> float | None:
    """A finite number at ``keys`` in ``meta`` (booleans and text are not numbers), else None."""
    v = meta_get(meta, *keys)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    return float(v) if np.isfinite(v) else None


def as_float64(data: pd.DataFrame) -> pd.DataFrame:
    """Columns as other programs write them, read as the run format's float64: float32 and
    integer columns are widened (booleans and text are left for :func:`validate` to refuse).
    A ``t_s`` stored in single precision is rebuilt as the uniform axis it rounds: float32
    holds a 1 kHz time stamp to about 1e-5 s after 120 s, a hundredth of a step, which
    :func:`validate`'s uniformity check would otherwise refuse."""
    out = data
    for col in data.columns:
        dt = data[col].dtype
        if dt == np.float64 or pd.api.types.is_bool_dtype(dt) or not pd.api.types.is_numeric_dtype(dt):
            continue
        if out is data:
            out = data.copy()
        values = data[col].to_numpy().astype(np.float64)
        if col == "t_s" and dt == np.float32 and values.size > 1:
            step = (values[-1] - values[0]) / (values.size - 1)
            uniform = values[0] + step * np.arange(values.size)
            resolution = 4.0 * np.finfo(np.float32).eps * max(abs(values[0]), abs(values[-1]))
            if step > 0 and np.max(np.abs(values - uniform)) <= max(resolution, UNIFORM_RTOL * step):
                values = uniform
        out[col] = values
    return out


def make_meta(kind: str, name: str, sample_rate_hz: float, **extra: Any) -> dict[str, Any]:
    """Metadata for a new run, with the required keys first."""
    meta = {"schema_version": SCHEMA_VERSION, "kind": kind, "name": name, "sample_rate_hz": float(sample_rate_hz)}
    meta.update(extra)
    return meta


def make_run(columns: Mapping[str, np.ndarray], meta: Mapping[str, Any], *, label: str | None = None) -> Run:
    """Build and validate a run from arrays (converted to float64)."""
    frame = pd.DataFrame({k: np.asarray(v, dtype=np.float64) for k, v in columns.items()})
    meta = dict(meta)
    validate(frame, meta, label or f"run {meta.get('name', '?')!r}", allow_incomplete=True)
    return Run(frame, meta)


def _json_default(obj: Any) -> Any:
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating,)):
        return float(obj)
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"metadata value {obj!r} of type {type(obj).__name__} is not JSON serialisable")


def write_run(run: Run, path: str | os.PathLike[str], *, overwrite: bool = False) -> str:
    """Write ``run`` to ``path`` atomically and return the file's sha256.

    The file is written beside its destination and renamed into place, so a crash never
    leaves a half-written file under the final name. An existing file is never replaced
    unless ``overwrite`` is true.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise OutputExistsError(f"{path}: already exists; refusing to overwrite it (choose another name)")
    validate(run.data, run.meta, str(path), allow_incomplete=True)
    table = pa.Table.from_pandas(run.data, preserve_index=False)
    meta = dict(table.schema.metadata or {})
    meta[METADATA_KEY] = json.dumps(run.meta, default=_json_default, sort_keys=False).encode()
    table = table.replace_schema_metadata(meta)
    tmp = path.with_name(f".{path.name}.partial")
    try:
        pq.write_table(table, tmp, compression="zstd")
    except OSError as exc:  # a missing or read-only folder, a full disk: one line, nothing half-written left
        tmp.unlink(missing_ok=True) if tmp.parent.is_dir() else None
        raise output_error(path, exc) from None
    if path.exists() and not overwrite:  # appeared meanwhile
        tmp.unlink()
        raise OutputExistsError(f"{path}: already exists; refusing to overwrite it (choose another name)")
    os.replace(tmp, path)
    return sha256_file(path)


def read_run(path: str | os.PathLike[str], *, allow_incomplete: bool = False) -> Run:
    """Read and validate one run file.

    Raises
    ------
    RunFormatError
        With one line naming the file, what is wrong and what was expected.
    """
    path = Path(path)
    label = str(path)
    if not path.is_file():
        raise _problem(label, "no such file; expected a Parquet run file")
    try:
        table = pq.read_table(path)
    except Exception as exc:  # pyarrow raises many types for corrupt files
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise _problem(label, f"cannot be read as Parquet ({first}); expected a Parquet run file") from None
    raw = (table.schema.metadata or {}).get(METADATA_KEY)
    if raw is None:
        raise _problem(
            label,
            "has no 'piezopress' metadata; expected a run written by piezopress (convert other data with `piezopress "
            "import`)",
        )
    try:
        meta = json.loads(raw)
    except json.JSONDecodeError as exc:
        raise _problem(
            label, f"'piezopress' metadata is not valid JSON ({exc.msg} at character {exc.pos}); expected a JSON object"
        ) from None
    except UnicodeDecodeError as exc:
        raise _problem(
            label, f"'piezopress' metadata is not UTF-8 text (byte {exc.start}); expected a JSON object"
        ) from None
    try:
        data = table.to_pandas()
    except Exception as exc:  # pyarrow raises many types for columns it cannot convert
        raise _problem(label, f"columns cannot be read ({type(exc).__name__}); expected float64 columns") from None
    data = as_float64(data)
    validate(data, meta, label, allow_incomplete=allow_incomplete)
    return Run(data, meta, path)


def read_meta(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read only the metadata of a run file (cheap; no validation of the columns)."""
    path = Path(path)
    try:
        schema = pq.read_schema(path)
    except Exception as exc:
        raise _problem(
            str(path), f"cannot be read as Parquet ({type(exc).__name__}); expected a Parquet run file"
        ) from None
    raw = (schema.metadata or {}).get(METADATA_KEY)
    if raw is None:
        raise _problem(str(path), "has no 'piezopress' metadata; expected a run written by piezopress")
    return json.loads(raw)


def sha256_file(path: str | os.PathLike[str], chunk: int = 1 << 20) -> str:
    """The hex sha256 of a file, read in chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            h.update(block)
    return h.hexdigest()
