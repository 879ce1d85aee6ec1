"""File helpers every stage shares: timestamps, atomic JSON, new output directories and
files, run directories and their manifests.

Nothing is ever overwritten silently: :func:`new_output_dir` refuses a directory that holds
anything, :func:`check_output` refuses an existing file unless the caller was asked to
replace it, and JSON is written beside its target and renamed into place.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import platform
from pathlib import Path
from typing import Any

import piezopress
from piezopress import runformat
from piezopress.errors import OutputExistsError, PiezopressError

#: The file that lists a run directory's runs, plan, rig and status.
MANIFEST = "manifest.json"
MANIFEST_VERSION = 1


def utc_now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def software_versions() -> dict[str, str]:
    import numpy, pandas, pyarrow, scipy  # noqa: E401

    return {
        "piezopress": piezopress.__version__,
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "scipy": scipy.__version__,
        "pandas": pandas.__version__,
        "pyarrow": pyarrow.__version__,
    }


def write_json_atomic(path: Path, obj: Any) -> None:
    """Write JSON beside ``path`` and rename it into place (never a half-written file)."""
    tmp = path.with_name(f".{path.name}.partial")
    tmp.write_text(json.dumps(obj, indent=2, default=runformat._json_default) + "\n", encoding="utf-8")
    os.replace(tmp, path)


def new_output_dir(out_dir: str | Path) -> Path:
    """Create ``out_dir``; refuse if it exists and holds anything (no data is ever overwritten)."""
    out = Path(out_dir)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise OutputExistsError(f"{out}: already exists and is not empty; choose a new directory (runs are never overwritten)")
    out.mkdir(parents=True, exist_ok=True)
    return out


def read_manifest(run_dir: str | Path) -> dict[str, Any]:
    """The manifest of a run directory, checked to be readable."""
    path = Path(run_dir) / MANIFEST
    if not path.is_file():
        raise PiezopressError(f"{run_dir}: no {MANIFEST}; expected a directory written by `piezopress characterize`")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise PiezopressError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None


def run_files(run_dir: str | Path) -> list[Path]:
    """The complete runs of a directory: those its manifest lists, else every ``*.parquet``."""
    run_dir = Path(run_dir)
    if (run_dir / MANIFEST).is_file():
        return [run_dir / r["file"] for r in read_manifest(run_dir)["runs"] if r.get("status", runformat.STATUS_COMPLETE) == runformat.STATUS_COMPLETE]
    return sorted(run_dir.glob("*.parquet"))


def check_output(path: str | Path, *, replace: bool = False) -> None:
    """Refuse, before any work, an output file that exists (without ``replace``) or a
    directory in its place."""
    path = Path(path)
    if path.is_dir():
        raise OutputExistsError(f"{path}: is a directory; expected a file name for the JSON document")
    if path.exists() and not replace:
        raise OutputExistsError(f"{path}: already exists; refusing to overwrite it (pass --replace to replace it, keeping the old one as .prev.json)")


__all__ = ["MANIFEST", "MANIFEST_VERSION", "utc_now", "software_versions", "write_json_atomic", "new_output_dir", "read_manifest", "run_files", "check_output"]
