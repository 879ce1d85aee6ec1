"""``compensate``: a reference trajectory file in (in the bundle's output unit), a drive file out."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from piezopress import units
from piezopress.acquisition.drive_check import check_drive, check_sample_rate
from piezopress.acquisition.plan import DriveLimits
from piezopress.analysis.compensation import CompensationResult
from piezopress.errors import ImportFormatError, OutputExistsError
from piezopress.runformat import UNIFORM_RTOL
from piezopress.pipelines.bundle import compensator, read_document
from piezopress.pipelines.characterize import DEFAULT_RIG, rig_limits


def read_reference(path: str | Path, column: str = "reference_n") -> tuple[np.ndarray, np.ndarray, float]:
    """``(t_s, reference, sample_rate_hz)`` from a CSV with columns ``t_s`` and ``column``
    (``reference_n`` for a force bundle, ``reference_um`` for a displacement bundle)."""
    path = Path(path)
    want = f"t_s, {column}"
    try:
        df = pd.read_csv(path)
    except Exception as exc:  # pandas raises many types
        raise ImportFormatError(f"{path}: cannot be read as CSV ({exc}); expected columns {want}") from None
    missing = [c for c in ("t_s", column) if c not in df.columns]
    if missing:
        raise ImportFormatError(f"{path}: missing column {', '.join(missing)}; expected columns {want} (found {', '.join(map(str, df.columns))})")
    try:
        t = df["t_s"].to_numpy(dtype=float)
        r = df[column].to_numpy(dtype=float)
    except ValueError:
        raise ImportFormatError(f"{path}: non-numeric values in t_s or {column}; expected numbers") from None
    if t.size < 2 or not (np.all(np.isfinite(t)) and np.all(np.isfinite(r))):
        raise ImportFormatError(f"{path}: {t.size} rows or non-finite values; expected at least 2 finite rows")
    dt = np.diff(t)
    mean = (t[-1] - t[0]) / (t.size - 1)
    if mean <= 0 or np.max(np.abs(dt - mean)) > UNIFORM_RTOL * mean:
        raise ImportFormatError(f"{path}: t_s is not uniformly increasing; expected a uniform time column")
    return t, r, 1.0 / mean


def reference_column(bundle: dict) -> str:
    """The reference column a bundle's compensator takes: ``reference_n`` or ``reference_um``."""
    return f"reference_{units.key(bundle['hysteresis']['model'].get('output_unit', units.FORCE))}"


def compensate_file(bundle_path: str | Path, ref_path: str | Path, out: str | Path, *, use_shaper: bool = True,
                    limits: DriveLimits | None = None) -> CompensationResult:
    """Write the drive for a reference; ``limits`` (default: the shipped rig's) bound its sample rate,
    range and slew (:mod:`piezopress.acquisition.drive_check`, the check every backend makes)."""
    limits = limits or rig_limits(DEFAULT_RIG)
    out = Path(out)
    if out.exists():
        raise OutputExistsError(f"{out}: already exists; refusing to overwrite it")
    bundle = read_document(bundle_path, "bundle")
    comp = compensator(bundle, use_shaper=use_shaper)
    column = reference_column(bundle)
    t, r, fs = read_reference(ref_path, column)
    check_sample_rate(fs, limits, str(ref_path))
    result = comp.drive(r, fs)
    check_drive(result.command_v, fs, limits, f"{ref_path} through {bundle_path}")
    pd.DataFrame({"t_s": t, column: r, "command_v": result.command_v}).to_csv(out, index=False, float_format="%.9g")
    return result
