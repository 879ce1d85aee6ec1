"""``compensate``: a reference trajectory file in (in the bundle's output unit), a drive file out."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from piezopress import units
from piezopress.acquisition.drive_check import check_drive, check_sample_rate
from piezopress.analysis.bundle import MAX_OUTPUT, Bundle, BundleError
from piezopress.analysis.compensation import CompensationResult, clipped_mask
from piezopress.errors import ImportFormatError
from piezopress.pipelines.bundle import read_bundle
from piezopress.pipelines.characterize import DEFAULT_RIG
from piezopress.pipelines.characterize import rig_limits as limits_of_rig
from piezopress.pipelines.files import check_output, write_output
from piezopress.runformat import UNIFORM_RTOL

MAX_CLIP_SHARE = 0.01
"""Largest share of a reference's samples ``compensate`` clips without ``--allow-clip``."""


class ReachError(ImportFormatError):
    """A reference the bundle's drive range cannot reach on more than :data:`MAX_CLIP_SHARE` of it."""


REST, ABSOLUTE = "rest", "absolute"


def reference_zero(bundle: Bundle, zero: str | None) -> str:
    """Where a reference's zero is: ``rest`` (the model's rest output: force above the preload,
    as the thesis's references) or ``absolute`` (the record's own scale); ``None`` chooses
    ``absolute`` for a bundle fitted on runs from elsewhere (imported), ``rest`` otherwise."""
    if zero is None or zero == "auto":
        return ABSOLUTE if bundle.from_elsewhere else REST
    if zero not in (REST, ABSOLUTE):
        raise ImportFormatError(f"zero {zero!r}; expected rest, absolute or auto")
    return zero


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
        raise ImportFormatError(
            f"{path}: missing column {', '.join(missing)}; expected columns {want} (found "
            f"{', '.join(map(str, df.columns))})"
        )
    try:
        t = df["t_s"].to_numpy(dtype=float)
        r = df[column].to_numpy(dtype=float)
    except ValueError:
        raise ImportFormatError(f"{path}: non-numeric values in t_s or {column}; expected numbers") from None
    if t.size < 2:
        raise ImportFormatError(f"{path}: {t.size} rows; expected at least 2 rows of t_s, {column}")
    for name, v in (("t_s", t), (column, r)):
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            # row numbers as a spreadsheet shows them: the header is row 1
            rows = ", ".join(str(int(i) + 2) for i in bad[:5]) + (" ..." if bad.size > 5 else "")
            raise ImportFormatError(
                f"{path}: {bad.size} empty or non-finite {name} value(s), at row {rows} (the header is row 1); "
                "expected a number on every row"
            )
    if np.max(np.abs(r)) > MAX_OUTPUT:
        raise ImportFormatError(
            f"{path}: {column} reaches {np.max(np.abs(r)):.6g}; expected values within +/-{MAX_OUTPUT:g} (a press's "
            "range)"
        )
    dt = np.diff(t)
    mean = (t[-1] - t[0]) / (t.size - 1)
    if mean <= 0 or np.max(np.abs(dt - mean)) > UNIFORM_RTOL * mean:
        raise ImportFormatError(f"{path}: t_s is not uniformly increasing; expected a uniform time column")
    return t, r, 1.0 / mean


def reference_column(bundle: Bundle) -> str:
    """The reference column a bundle's compensator takes: ``reference_n`` or ``reference_um``."""
    return f"reference_{units.key(bundle.unit)}"


def _reference_unit(path: Path, bundle: Bundle) -> None:
    """Refuse a reference in the other unit (its column names it) with one line."""
    try:
        header = pd.read_csv(path, nrows=0).columns
    except Exception:  # unreadable: read_reference says why
        return
    for unit in units.LABELS:
        col = f"reference_{units.key(unit)}"
        if col in header and unit != bundle.unit and reference_column(bundle) not in header:
            bundle.check_unit(
                unit,
                f"{path} (column {col})",
                f"a {units.quantity(bundle.unit)} reference, column {reference_column(bundle)}",
            )


def compensate_file(
    bundle_path: str | Path,
    ref_path: str | Path,
    out: str | Path,
    *,
    use_shaper: bool = True,
    replace: bool = False,
    rig_limits: Any = None,
    rig: str | None = None,
    allow_clip: bool = False,
    max_clip_share: float = MAX_CLIP_SHARE,
    zero: str | None = None,
) -> tuple[CompensationResult, Path | None]:
    """The drive for a reference file, written to ``out`` (``t_s``, the reference, ``command_v``);
    returns the result and where the replaced file was kept (``None``: nothing replaced).

    The output place is checked before anything is read; the bundle is checked as it is read
    and then against the reference (its unit, the lead against its length, the creep
    compensator at its rate) and, with ``rig_limits``, against the rig's sample rate and, when
    the rig file is named (``rig``), its drive range (``rig=None``: the limits are the virtual
    rig's defaults, which bound the rate only). The drive passes the check every backend makes
    (:mod:`piezopress.acquisition.drive_check`: finite, in range, slew, sample rate) before it is written."""
    out = Path(out)
    check_output(out, replace=replace)
    bundle = read_bundle(bundle_path)
    limits = rig_limits if rig_limits is not None else limits_of_rig(DEFAULT_RIG)
    s = bundle.settings
    range_note = ""
    if rig is None:  # no rig named: the range fixed into the bundle at fit time
        limits = dataclasses.replace(limits, drive_min_v=s.drive_min_v, drive_max_v=s.drive_max_v)
    elif (limits.drive_min_v, limits.drive_max_v) != (s.drive_min_v, s.drive_max_v):
        range_note = (
            f"the drive range is the rig's, {limits.drive_min_v:g} to {limits.drive_max_v:g} V ({rig}), not the "
            f"bundle's {s.drive_min_v:g} to {s.drive_max_v:g} V"
        )
    ref_path = Path(ref_path)
    _reference_unit(ref_path, bundle)
    column = reference_column(bundle)
    t, r_given, fs = read_reference(ref_path, column)
    zero = reference_zero(bundle, zero)
    rest = float(bundle.hysteresis.y0)
    r = r_given - rest if zero == ABSOLUTE else r_given
    check_sample_rate(fs, limits, str(ref_path))
    bundle.check_reference(t.size, fs, str(ref_path))
    comp = dataclasses.replace(
        bundle.compensator(use_shaper=use_shaper), drive_min_v=limits.drive_min_v, drive_max_v=limits.drive_max_v
    )
    result = comp.drive(r, fs)
    if range_note:
        result = dataclasses.replace(result, notes=(range_note, *result.notes))
    if not np.all(np.isfinite(result.command_v)):
        raise BundleError(
            f"{bundle_path}: its compensator gives a non-finite drive for {ref_path}; expected a finite drive (check "
            "the bundle)"
        )
    share = result.clipped_samples / max(result.command_v.size, 1)
    if share > max_clip_share and not allow_clip:
        raise ReachError(
            f"{ref_path}: {result.clipped_samples} of {result.command_v.size} samples ({100 * share:.1f} %) cannot be "
            f"reached with {bundle_path} (the drive range is {limits.drive_min_v:g} to "
            f"{limits.drive_max_v:g} V); "
            f"expected at most {100 * max_clip_share:g} % clipped. Lower the reference, or pass --allow-clip to write "
            "the clipped drive anyway"
        )
    check_drive(result.command_v, fs, limits, f"{ref_path} through {bundle_path}")
    frame = pd.DataFrame({"t_s": t, column: r_given, "command_v": result.command_v})
    if zero == ABSOLUTE:  # the reference on the record's scale: its zero written beside it (simulate reads it)
        frame[f"rest_{units.key(bundle.unit)}"] = rest
    if result.clipped_samples:
        frame["clipped"] = clipped_mask(result)
    previous = write_output(out, lambda tmp: frame.to_csv(tmp, index=False, float_format="%.9g"), replace=replace)
    return result, previous
