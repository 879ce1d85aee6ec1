"""``compensate``: a reference trajectory file in, a drive file out."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from piezopress.analysis.compensation import CompensationResult
from piezopress.errors import ImportFormatError, OutputExistsError
from piezopress.runformat import UNIFORM_RTOL
from pipelines.bundle import compensator, read_document


def read_reference(path: str | Path) -> tuple[np.ndarray, np.ndarray, float]:
    """``(t_s, reference_n, sample_rate_hz)`` from a CSV with columns ``t_s`` and ``reference_n``."""
    path = Path(path)
    try:
        df = pd.read_csv(path)
    except Exception as exc:  # pandas raises many types
        raise ImportFormatError(f"{path}: cannot be read as CSV ({exc}); expected columns t_s, reference_n") from None
    missing = [c for c in ("t_s", "reference_n") if c not in df.columns]
    if missing:
        raise ImportFormatError(f"{path}: missing column {', '.join(missing)}; expected columns t_s, reference_n (found {', '.join(map(str, df.columns))})")
    try:
        t = df["t_s"].to_numpy(dtype=float)
        r = df["reference_n"].to_numpy(dtype=float)
    except ValueError:
        raise ImportFormatError(f"{path}: non-numeric values in t_s or reference_n; expected numbers") from None
    if t.size < 2 or not (np.all(np.isfinite(t)) and np.all(np.isfinite(r))):
        raise ImportFormatError(f"{path}: {t.size} rows or non-finite values; expected at least 2 finite rows")
    dt = np.diff(t)
    mean = (t[-1] - t[0]) / (t.size - 1)
    if mean <= 0 or np.max(np.abs(dt - mean)) > UNIFORM_RTOL * mean:
        raise ImportFormatError(f"{path}: t_s is not uniformly increasing; expected a uniform time column")
    return t, r, 1.0 / mean


def compensate_file(bundle_path: str | Path, ref_path: str | Path, out: str | Path, *, use_shaper: bool = True) -> CompensationResult:
    out = Path(out)
    if out.exists():
        raise OutputExistsError(f"{out}: already exists; refusing to overwrite it")
    comp = compensator(read_document(bundle_path, "bundle"), use_shaper=use_shaper)
    t, r, fs = read_reference(ref_path)
    result = comp.drive(r, fs)
    pd.DataFrame({"t_s": t, "reference_n": r, "command_v": result.command_v}).to_csv(out, index=False, float_format="%.9g")
    return result
