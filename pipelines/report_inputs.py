"""The report's inputs: a run directory read once (its summary table and its runs by name),
and which runs stand for which test of Table 6.13."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from piezopress import runformat
from piezopress.analysis import profile
from piezopress.errors import PiezopressError
from piezopress.pipelines import summary
from piezopress.pipelines.files import MANIFEST, read_manifest, run_files
from piezopress.pipelines.profiles import read_measured

#: The quasi-static triangles of Table 6.13 (and the hysteresis loops) are those at this frequency (Hz).
STATIC_FREQ_HZ = 0.1
#: The uncontrolled overshoot of Table 6.13 is the step of this drive (V), thesis 25.92 %.
UNCONTROLLED_STEP_V = 20.0


class ReportError(PiezopressError, ValueError):
    """The report's inputs or output directory are unusable."""


# --------------------------------------------------------------------------- inputs


@dataclass
class _Source:
    """One run directory: its table (from piezopress.pipelines.summary) and its runs by name."""

    path: Path
    table: pd.DataFrame
    runs: dict[str, runformat.Run]
    shaper: bool = True


def _load_dir(path: str | Path, what: str, command: str, table_of: Callable[[Path], pd.DataFrame]) -> _Source:
    path = Path(path)
    if not (path.is_dir() or (path.is_file() and path.suffix.lower() == ".parquet")):
        raise ReportError(
            f"{path}: no such directory or run file; expected a {what} run directory (from `piezopress {command}`) "
            "or a run file (from `piezopress import`)"
        )
    files = run_files(path, expect_kind=what if what in ("characterization", "validation") else None)
    runs: dict[str, runformat.Run] = {}
    for f in files:
        r = read_measured(f)
        runs[r.name] = r
    table = table_of(path) if files else pd.DataFrame(columns=summary.COLUMNS)
    shaper = True
    if (path / MANIFEST).is_file():
        shaper = bool(read_manifest(path).get("compensation_options", {}).get("shaper", True))
    return _Source(path, table, runs, shaper)


def _freq(run: runformat.Run | None) -> float | None:
    """The run's sweep frequency, measured from its signals (None: not a sweep)."""
    return profile.of(run).freq_hz if run is not None else None


def _is_static_triangle(run: runformat.Run | None) -> bool:
    f = _freq(run)
    return (
        run is not None
        and run.kind in ("triangle", "sine")
        and f is not None
        and math.isclose(f, STATIC_FREQ_HZ, rel_tol=0.01)
    )


def _is_uncontrolled_step(run: runformat.Run | None) -> bool:
    return (
        run is not None
        and run.kind == "step"
        and math.isclose(float(np.max(run.command_v)), UNCONTROLLED_STEP_V, abs_tol=0.5)
    )
