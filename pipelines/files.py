"""File helpers every stage shares: timestamps, atomic JSON, new output directories and
files, run directories and their manifests.

Nothing is ever overwritten silently: :func:`new_output_dir` refuses a directory that holds
anything, :func:`check_output` refuses an existing file unless the caller was asked to
replace it, and every output is written beside its target and renamed into place
(:func:`write_output`). Replacing never loses: the old version is first kept under a unique
timestamped name (:func:`keep_previous`), under a lock, so two replaces in a row or at once
leave every earlier version recoverable. Output places are checked (and their folders
created) before any work, with one line when the folder cannot be written.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import math
import os
import platform
import shutil
import time
import uuid
from collections.abc import Callable, Iterator
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
    return _dt.datetime.now(_dt.UTC).strftime(runformat.TIMESTAMP_FORMAT)


def software_versions() -> dict[str, str]:
    import numpy  # noqa: E401
    import pandas
    import pyarrow
    import scipy

    return {
        "piezopress": piezopress.__version__,
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "scipy": scipy.__version__,
        "pandas": pandas.__version__,
        "pyarrow": pyarrow.__version__,
    }


def _partial(path: Path) -> Path:
    """A temporary name beside ``path``, unique to this writer, keeping its suffix."""
    return path.with_name(f".{path.stem}.{os.getpid()}-{uuid.uuid4().hex[:8]}.partial{path.suffix}")


def finite_or_null(obj: Any) -> Any:
    """``obj`` with every non-finite float (NaN, infinity) as ``None``: strict JSON (``null``),
    which every JSON parser reads; bare ``NaN``/``Infinity`` are not JSON."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_or_null(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_null(v) for v in obj]
    if hasattr(obj, "item") and not isinstance(obj, (str, bytes)):  # numpy scalars
        return finite_or_null(obj.item())
    return obj


def write_json_atomic(path: Path, obj: Any, *, finite: bool = False, null_nonfinite: bool = False) -> None:
    """Write JSON beside ``path`` and rename it into place (never a half-written file).
    ``finite``: refuse a non-finite number (a model's parameters: NaN there is a defect);
    ``null_nonfinite``: write it as ``null`` (strict JSON; a figure that could not be measured)."""
    path = Path(path)
    if null_nonfinite:
        obj = finite_or_null(obj)
    try:
        text = json.dumps(obj, indent=2, default=runformat._json_default, allow_nan=not finite)
    except ValueError:
        raise PiezopressError(
            f"{path}: would hold a non-finite number (NaN or inf); expected finite values, refusing to write it"
        ) from None
    tmp = _partial(path)
    try:
        tmp.write_text(text + "\n", encoding="utf-8")
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _unwritable(folder: Path, exc: OSError | None = None) -> PiezopressError:
    why = exc.strerror if exc is not None and exc.strerror else "permission denied"
    return PiezopressError(
        f"{folder}: cannot write there ({why.lower()}); expected a folder you may write to (choose another --out)"
    )


def writable_folder(folder: str | Path) -> Path:
    """Create ``folder`` (and its parents) if needed and check it can be written: one line if not."""
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise PiezopressError(f"{folder}: is a file; expected a folder for the output") from None
    except OSError as exc:
        raise _unwritable(folder, exc) from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise _unwritable(folder)
    probe = folder / f".piezopress-write-test-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    try:  # os.access says yes to root on a read-only mount: a real file says what will happen
        os.close(os.open(probe, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        os.unlink(probe)
    except OSError as exc:
        raise _unwritable(folder, exc) from None
    return folder


def new_output_dir(out_dir: str | Path) -> Path:
    """Create ``out_dir``; refuse if it exists and holds anything (no data is ever overwritten),
    or if it cannot be written (one line)."""
    out = Path(out_dir)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise OutputExistsError(
            f"{out}: already exists and is not empty; choose a new directory (runs are never overwritten)"
        )
    return writable_folder(out)


def read_manifest(run_dir: str | Path) -> dict[str, Any]:
    """The manifest of a run directory, checked to be readable."""
    path = Path(run_dir) / MANIFEST
    if not path.is_file():
        raise PiezopressError(f"{run_dir}: no {MANIFEST}; expected a directory written by `piezopress characterize`")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise PiezopressError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    except UnicodeDecodeError as exc:
        raise PiezopressError(
            f"{path}: not UTF-8 text (byte 0x{exc.object[exc.start]:02x} at {exc.start}); expected a JSON manifest"
        ) from None
    _check_manifest(path, doc)
    return doc


def _check_manifest(path: Path, doc: Any) -> None:
    """A manifest as other programs may have edited it: a JSON object whose ``runs`` is a
    list of objects, each naming a ``file`` inside the manifest's own folder."""
    what = 'expected a JSON object with a list `runs` of {"file": ..., "sha256": ...}'
    if not isinstance(doc, dict):
        raise PiezopressError(f"{path}: holds a JSON {type(doc).__name__}; {what}")
    if "runs" not in doc:
        raise PiezopressError(f"{path}: has no `runs`; {what}")
    runs = doc["runs"]
    if not isinstance(runs, list):
        raise PiezopressError(f"{path}: `runs` is a JSON {type(runs).__name__}; {what}")
    folder = path.parent.resolve()
    for i, r in enumerate(runs):
        if not isinstance(r, dict):
            raise PiezopressError(f"{path}: runs[{i}] is {json.dumps(r)[:60]}; {what}")
        f = r.get("file")
        if not isinstance(f, str) or not f:
            raise PiezopressError(
                f"{path}: runs[{i}] has file = {json.dumps(f)[:60]}; expected the run file's name (text)"
            )
        target = (folder / f).resolve()
        if folder not in target.parents:
            raise PiezopressError(
                f"{path}: runs[{i}] names {f!r}, outside the manifest's folder {folder}; expected a file beside the "
                "manifest"
            )


def run_files(run_dir: str | Path, *, expect_kind: str | None = None) -> list[Path]:
    """The complete runs of a directory: those its manifest lists, else every ``*.parquet``.

    A directory whose manifest is not ``complete`` (or not of ``expect_kind``) is refused by
    :func:`check_status`, unless incomplete directories are accepted (then a note names it
    and the runs skipped)."""
    run_dir = Path(run_dir)
    if run_dir.is_file():  # one run file (an import): itself
        return [run_dir]
    if (run_dir / MANIFEST).is_file():
        check_status(run_dir, expect_kind=expect_kind)
        return [
            run_dir / r["file"]
            for r in read_manifest(run_dir).get("runs", [])
            if r.get("status", runformat.STATUS_COMPLETE) == runformat.STATUS_COMPLETE
        ]
    return sorted(run_dir.glob("*.parquet"))


def check_output(path: str | Path, *, replace: bool = False) -> None:
    """Refuse, before any work, an output file that exists (without ``replace``), a
    directory in its place, or a folder that cannot be written; create its folder."""
    path = Path(path)
    if path.is_dir():
        raise OutputExistsError(f"{path}: is a directory; expected a file name for the output")
    if path.exists() and not replace:
        raise OutputExistsError(
            f"{path}: already exists; refusing to overwrite it (pass --replace to replace it; the old one is kept "
            "under a timestamped name)"
        )
    writable_folder(path.parent)
    check_stale_lock(path)


def check_stale_lock(path: Path) -> None:
    """Refuse, before any work, an output whose lock file is older than :data:`LOCK_WAIT_S` (left
    by a writer that was killed): the work would be done, then thrown away at the write."""
    lock = Path(path).with_name(f".{Path(path).name}.lock")
    try:
        age = time.time() - lock.stat().st_mtime
    except OSError:  # no lock: the usual case
        return
    if age > LOCK_WAIT_S:
        raise PiezopressError(
            f"{path}: a lock file {lock} has been there for {age:.0f} s (a writer killed while writing?); expected "
            "none: remove it if no piezopress is running, then run this again"
        )


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
        raise PiezopressError(
            f"{run_dir / MANIFEST}: not a manifest (expected an object with a 'runs' list); expected a directory "
            "written by `piezopress characterize`"
        )
    kind = manifest.get("kind")
    if expect_kind is not None and kind != expect_kind:
        raise PiezopressError(
            f"{run_dir}: its manifest says kind {kind!r}; expected a {expect_kind} directory "
            f"(from `piezopress {'validate' if expect_kind == 'validation' else 'characterize'}`)"
        )
    runs = [r for r in manifest.get("runs", []) if isinstance(r, dict)]
    skipped = [
        str(r.get("file")) for r in runs if r.get("status", runformat.STATUS_COMPLETE) != runformat.STATUS_COMPLETE
    ]
    status = manifest.get("status")
    notes: list[str] = []
    if status != "complete":
        reason = manifest.get("status_reason") or "no reason recorded"
        done = len(runs) - len(skipped)
        accept = _ACCEPT_INCOMPLETE.get() if accept is None else accept
        if not accept:
            raise PiezopressError(
                f"{run_dir}: its manifest says status {status!r} ({reason}), with {done} complete run(s); expected a "
                "complete directory: run the plan again, or pass --accept-incomplete to use its complete runs"
            )
        notes.append(
            f"{run_dir}: accepted although its manifest says status {status!r} ({reason}); {done} complete run(s) used"
        )
    if skipped:
        notes.append(f"{run_dir}: skipped incomplete run(s) {', '.join(skipped)}")
    if notes:
        _STATUS_NOTES.set(_STATUS_NOTES.get() + tuple(n for n in notes if n not in _STATUS_NOTES.get()))
    return notes


#: How long a writer waits for another one replacing the same output.
LOCK_WAIT_S = 30.0


@contextlib.contextmanager
def _lock(path: Path) -> Iterator[None]:
    """Only one writer at a time keeps and replaces ``path`` (a lock file beside it)."""
    lock = path.with_name(f".{path.name}.lock")
    deadline = time.monotonic() + LOCK_WAIT_S
    while True:
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            break
        except FileExistsError:
            if time.monotonic() > deadline:
                raise PiezopressError(
                    f"{path}: another writer has held {lock} for over {LOCK_WAIT_S:g} s; "
                    "expected it to finish (remove the lock file if no piezopress is running)"
                ) from None
            time.sleep(0.005)
        except OSError as exc:
            raise _unwritable(path.parent, exc) from None
    try:
        yield
    finally:
        os.close(fd)
        with contextlib.suppress(OSError):
            os.unlink(lock)


def kept_name(path: str | Path) -> Path:
    """A new, unused name beside ``path`` for its old version: ``<name>.replaced-<UTC time>``
    (no longer ending in ``.parquet`` or ``.json``: a folder's runs or sections are not
    joined by their old versions)."""
    path = Path(path)
    stamp = _dt.datetime.now(_dt.UTC).strftime("%Y%m%dT%H%M%S.%fZ")
    for n in range(10_000):
        cand = path.with_name(f"{path.name}.replaced-{stamp}{f'-{n}' if n else ''}")
        if not os.path.lexists(cand):
            return cand
    raise OutputExistsError(f"{path}: no free name to keep its old version; expected fewer than 10000 kept versions")


def _keep(path: Path) -> Path:
    """Keep the file ``path``'s current version under :func:`kept_name` (the caller holds the lock)."""
    kept = kept_name(path)
    try:
        os.link(path, kept)  # the same bytes under a second name: path itself stays until it is replaced
    except OSError:
        tmp = _partial(kept)
        shutil.copy2(path, tmp)
        os.replace(tmp, kept)
    return kept


def keep_previous(path: str | Path) -> Path | None:
    """Move an existing output (a file or a directory) aside to a unique timestamped name,
    under the lock; return that name (``None``: nothing was there)."""
    path = Path(path)
    with _lock(path):
        if not os.path.lexists(path):
            return None
        kept = kept_name(path)
        os.rename(path, kept)
        return kept


def write_output(path: str | Path, write: Callable[[Path], Any], *, replace: bool = False) -> Path | None:
    """Write an output file atomically: ``write(tmp)`` writes the new content to a temporary
    name beside ``path``, which then takes ``path``'s place. An existing ``path`` is refused
    without ``replace``; with it, its old version is first kept under a unique timestamped name
    (returned), and a concurrent writer waits its turn, so no version is ever lost."""
    path = Path(path)
    check_output(path, replace=replace)
    tmp = _partial(path)
    try:
        try:
            write(tmp)
        except PermissionError as exc:
            raise _unwritable(path.parent, exc) from None
        with _lock(path):
            previous = None
            if os.path.lexists(path):
                if not replace:  # appeared meanwhile
                    raise OutputExistsError(
                        f"{path}: appeared while it was being written; refusing to overwrite it (pass --replace)"
                    )
                previous = _keep(path)
            os.replace(tmp, path)
        return previous
    finally:
        tmp.unlink(missing_ok=True)


def kept_note(previous: Path | None) -> str:
    """`` (previous version kept as ...)`` for a printed line, or nothing."""
    return f" (previous version kept as {previous})" if previous else ""


__all__ = [
    "MANIFEST",
    "MANIFEST_VERSION",
    "utc_now",
    "software_versions",
    "write_json_atomic",
    "new_output_dir",
    "read_manifest",
    "run_files",
    "check_output",
    "writable_folder",
    "kept_name",
    "keep_previous",
    "write_output",
    "kept_note",
    "accept_incomplete",
    "status_notes",
    "check_status",
]
