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
from contextvars import ContextVar
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


def run_files(run_dir: str | Path, *, expect_kind: str | None = None) -> list[Path]:
    """The complete runs of a directory: those its manifest lists, else every ``*.parquet``.

    A directory whose manifest is not ``complete`` (or not of ``expect_kind``) is refused by
    :func:`check_status`, unless incomplete directories are accepted (then a note names it
    and the runs skipped)."""
    run_dir = Path(run_dir)
    if (run_dir / MANIFEST).is_file():
        check_status(run_dir, expect_kind=expect_kind)
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


# --- the status of a run directory ------------------------------------------------------------

#: Whether stages accept a run directory whose manifest is not ``complete`` (``--accept-incomplete``).
_ACCEPT_INCOMPLETE: ContextVar[bool] = ContextVar("accept_incomplete", default=False)
#: What was accepted that way, one line each, for the command's output and the report's inputs.
_STATUS_NOTES: ContextVar[tuple[str, ...]] = ContextVar("status_notes", default=())


def accept_incomplete(accept: bool = True) -> None:
    """Accept (or refuse, the default) run directories whose manifest is not ``complete``, and
    start a new list of :func:`status_notes`."""
    _ACCEPT_INCOMPLETE.set(bool(accept))
    _STATUS_NOTES.set(())


def status_notes() -> list[str]:
    """The incomplete directories accepted (and runs skipped) since :func:`accept_incomplete`."""
    return list(_STATUS_NOTES.get())


def check_status(run_dir: str | Path, *, expect_kind: str | None = None, accept: bool | None = None) -> list[str]:
    """Refuse a run directory whose manifest is not ``complete`` or not of ``expect_kind``.

    ``accept`` (default: what :func:`accept_incomplete` set) takes an incomplete directory
    anyway: the returned notes (also kept for :func:`status_notes`) name it, its status and
    every run of its manifest that is skipped as incomplete. A directory without a manifest
    (loose run files) has no status to check.
    """
    run_dir = Path(run_dir)
    if not (run_dir / MANIFEST).is_file():
        return []
    manifest = read_manifest(run_dir)
    if not isinstance(manifest, dict) or not isinstance(manifest.get("runs", []), list):
        raise PiezopressError(f"{run_dir / MANIFEST}: not a manifest (expected an object with a 'runs' list); expected a directory written by `piezopress characterize`")
    kind = manifest.get("kind")
    if expect_kind is not None and kind != expect_kind:
        raise PiezopressError(f"{run_dir}: its manifest says kind {kind!r}; expected a {expect_kind} directory "
                              f"(from `piezopress {'validate' if expect_kind == 'validation' else 'characterize'}`)")
    runs = [r for r in manifest.get("runs", []) if isinstance(r, dict)]
    skipped = [str(r.get("file")) for r in runs if r.get("status", runformat.STATUS_COMPLETE) != runformat.STATUS_COMPLETE]
    status = manifest.get("status")
    notes: list[str] = []
    if status != "complete":
        reason = manifest.get("status_reason") or "no reason recorded"
        done = len(runs) - len(skipped)
        accept = _ACCEPT_INCOMPLETE.get() if accept is None else accept
        if not accept:
            raise PiezopressError(f"{run_dir}: its manifest says status {status!r} ({reason}), with {done} complete run(s); expected a "
                                  "complete directory: run the plan again, or pass --accept-incomplete to use its complete runs")
        notes.append(f"{run_dir}: accepted although its manifest says status {status!r} ({reason}); {done} complete run(s) used")
    if skipped:
        notes.append(f"{run_dir}: skipped incomplete run(s) {', '.join(skipped)}")
    if notes:
        _STATUS_NOTES.set(_STATUS_NOTES.get() + tuple(n for n in notes if n not in _STATUS_NOTES.get()))
    return notes


__all__ = ["MANIFEST", "MANIFEST_VERSION", "utc_now", "software_versions", "write_json_atomic", "new_output_dir", "read_manifest", "run_files",
           "check_output", "accept_incomplete", "status_notes", "check_status"]
