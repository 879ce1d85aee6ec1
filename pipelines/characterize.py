"""Characterization: run a plan through a backend into a new run directory.

The directory gets one Parquet run per protocol and a ``manifest.json`` listing each run's
file and sha256, the plan, the rig configuration and the software version. The manifest
is rewritten atomically after every run, with ``status`` ``running``, then ``complete``,
or ``interrupted``/``failed`` with the reason: a directory that was cut short never looks
complete. Existing data is never overwritten.
"""

from __future__ import annotations

import json
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import piezopress
from piezopress import runformat
from piezopress.acquisition import drive_check
from piezopress.acquisition.backend import (
    BUILTIN_BACKENDS,
    Backend,
    Measurement,
    backend_class,
    backend_limits,
    registered_backends,
    started_utc,
    stop_signals_interrupt,
)
from piezopress.acquisition.daq_config import read_rig_document, rig_backend
from piezopress.acquisition.plan import DriveLimits, Plan, Protocol, load_plan
from piezopress.acquisition.rig_config import load_rig
from piezopress.acquisition.virtual_rig import VirtualRig
from piezopress.errors import BackendError, ConfigError, PiezopressError, PlanError, output_error
from piezopress.pipelines.files import (
    MANIFEST,
    MANIFEST_VERSION,
    new_output_dir,
    software_versions,
    utc_now,
    write_json_atomic,
)
from piezopress.resources import shipped

DEFAULT_PLAN = shipped("protocols", "characterize.toml")
DEFAULT_RIG = shipped("rigs", "thesis-press.toml")
#: The backends piezopress brings; others are found by name (entry points) or import path.
BACKENDS = tuple(BUILTIN_BACKENDS)


def _rig_class(rig_path: str | Path) -> tuple[dict[str, Any], str, type]:
    """The rig document, the backend it names and that backend's class (registry or import path)."""
    doc = read_rig_document(rig_path)
    in_file = rig_backend(doc)
    return doc, in_file, backend_class(in_file, str(rig_path), search=Path(rig_path).resolve().parent)


def _in_file(rig_path: str | Path, make: Callable[[], Any]) -> Any:
    """``make()``, with a rig configuration error naming the rig file (a backend class names
    its document "rig file": it is given the document, not its path)."""
    try:
        return make()
    except ConfigError as exc:
        if exc.source == str(rig_path):
            raise
        raise ConfigError(str(rig_path), exc.problems) from None


def rig_limits(rig_path: str | Path | None) -> DriveLimits:
    """The limits (drive range, sample rate, force) a rig file states, whichever backend it
    names, checked completely and without loading a driver (no rig file: the virtual rig's)."""
    if rig_path is None:
        return load_rig(None).limits
    doc, _, cls = _rig_class(rig_path)
    return _in_file(rig_path, lambda: backend_limits(cls, doc))


def make_backend(name: str | None, rig_path: str | Path | None) -> Backend:
    """The backend the rig file names in ``[rig] backend``, made from that file.

    The backend is a name registered under the entry-point group ``piezopress.backends``
    (``virtual`` and ``nidaq`` are piezopress's own) or an import path ``module:ClassName``
    (a module beside the rig file is found too); the class is called with the whole parsed
    rig file (``ClassName(document)``) and checks its own sections. ``name`` (``--backend``),
    when given, must match the file's backend (``None``: take the file's). No rig file means
    the virtual rig's built-in defaults. The ``nidaq`` backend without the ``nidaqmx``
    package is a one-line error saying how to install it.
    """
    if name is not None and ":" not in name and name not in registered_backends():
        raise BackendError(f"backend {name!r} is unknown; expected one of {', '.join(sorted(registered_backends()))}")
    if rig_path is None:
        if name not in (None, "virtual"):
            raise BackendError(
                f"backend {name!r} needs a rig file (--rig) describing the hardware; see rigs/nidaq-example.toml"
            )
        return VirtualRig(load_rig(None))
    doc, in_file, cls = _rig_class(rig_path)
    if name is not None and name != in_file:
        raise BackendError(
            f"{rig_path}: the rig file is for backend {in_file!r} ([rig] backend) but backend {name!r} was asked for; "
            f"pass --backend {in_file} or a rig file for {name!r}"
        )
    if cls is VirtualRig:
        return VirtualRig(load_rig(rig_path))  # its messages name the file
    return _in_file(rig_path, lambda: cls(doc))


@dataclass(frozen=True)
class ProgressEvent:
    """Reported before each protocol (``done`` false, ``fraction`` None), while it runs (the
    backend's progress: ``fraction`` of its samples measured) and after it (``done``).
    ``plan_s`` is the whole plan's drive time and ``remaining_s`` the drive time from this
    protocol's start to the plan's end."""

    index: int
    total: int
    protocol: Protocol
    done: bool
    elapsed_s: float = 0.0
    path: Path | None = None
    fraction: float | None = None
    plan_s: float = 0.0
    remaining_s: float = 0.0


@dataclass
class CharacterizeResult:
    out_dir: Path
    manifest_path: Path
    runs: list[Path] = field(default_factory=list)
    plan: Plan | None = None


@dataclass(frozen=True)
class Drive:
    """What to play for one protocol: the drive, extra columns and metadata for its run."""

    t_s: np.ndarray
    command_v: np.ndarray
    columns: dict[str, np.ndarray] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)


def plain_drive(proto: Protocol) -> Drive:
    """A drive plan's protocol played as it is."""
    return Drive(*proto.waveform())


def run_protocol(
    backend: Backend,
    proto: Protocol,
    plan: Plan,
    extra_meta: dict[str, Any],
    drive_for: Callable[[Protocol], Drive] = plain_drive,
    progress: Callable[[float], None] | None = None,
) -> runformat.Run:
    """Play one protocol through ``backend`` and return it as a run (complete or not);
    ``progress`` receives the fraction measured, as the backend reports it."""
    drive = drive_for(proto)
    command_v = drive.command_v
    started = started_utc(backend)  # a simulated press's own clock where it has one
    try:
        m = backend.run(command_v, proto.sample_rate_hz, preload_n=proto.preload_n, label=proto.name, progress=progress)
    except KeyboardInterrupt as exc:
        # a backend may re-raise Ctrl-C after its ramp-down with what it measured: keep it
        partial = getattr(exc, "measurement", None)
        if isinstance(partial, Measurement):
            try:
                exc.run = _measured_run(backend, proto, plan, extra_meta, drive, partial, started)  # type: ignore[attr-defined]
            except PiezopressError:  # fewer than 2 samples: nothing to keep
                pass
        raise
    return _measured_run(backend, proto, plan, extra_meta, drive, m, started)


def _measured_run(
    backend: Backend,
    proto: Protocol,
    plan: Plan,
    extra_meta: dict[str, Any],
    drive: Drive,
    m: Measurement,
    started: str,
) -> runformat.Run:
    t_s, command_v = drive.t_s, drive.command_v
    columns = {"t_s": t_s, "command_v": command_v, **drive.columns}
    n = min((len(v) for v in m.channels.values()), default=0) if not m.complete else len(t_s)
    if not m.complete and n < 2:
        raise BackendError(
            f"{proto.name}: the backend stopped the run before 2 samples were measured ({m.reason}); nothing to keep"
        )
    columns = {k: v[:n] for k, v in columns.items()}
    columns.update({k: np.asarray(v[:n], dtype=np.float64) for k, v in m.channels.items()})
    meta = runformat.make_meta(
        proto.run_kind,
        proto.name,
        proto.sample_rate_hz,
        status=runformat.STATUS_COMPLETE if m.complete else runformat.STATUS_INCOMPLETE,
        status_reason=m.reason,
        protocol=proto.as_dict(),
        plan=plan.name,
        preload_n=proto.preload_n,
        backend=backend.name,
        backend_info=m.info,
        started_utc=started,
        **extra_meta,
        **drive.meta,
    )
    return runformat.make_run(columns, meta)


def backend_from(
    backend: Backend | None, backend_name: str | None, rig_path: str | Path | None
) -> tuple[Backend, str | Path | None]:
    """``(backend, the rig file it was made from)``: the one given (made from no file), else
    :func:`make_backend`'s from ``rig_path``; the file goes to :func:`rig_description`."""
    if backend is not None:
        return backend, None
    return make_backend(backend_name, rig_path), rig_path


def rig_description(backend: Backend, rig_path: str | Path | None = None) -> dict[str, Any]:
    """``backend.describe()`` for a run's metadata, with the rig file the backend was made from
    where the description does not name it: ``source`` (the file's path) and ``config`` (its
    parsed document). A plug-in press's runs then say which file made them, and the report's
    provenance and the check that a bundle was fitted on this press have its digest."""
    described = dict(backend.describe())
    if rig_path is None:
        return described
    described.setdefault("source", str(rig_path))
    if "config" not in described:
        try:
            doc = read_rig_document(rig_path)
            json.dumps(doc)
        except (ConfigError, TypeError, ValueError):  # a document JSON cannot hold (TOML dates): the path only
            return described
        described["config"] = doc
    return described


def characterize(
    out_dir: str | Path,
    *,
    plan_path: str | Path = DEFAULT_PLAN,
    rig_path: str | Path | None = DEFAULT_RIG,
    backend: Backend | None = None,
    backend_name: str | None = None,
    on_progress: Callable[[ProgressEvent], None] | None = None,
) -> CharacterizeResult:
    """Run every protocol of a plan and write the runs and a manifest into ``out_dir``.

    The plan and rig are checked completely before the directory is created or the rig
    touched. On any interruption (Ctrl-C, an error) the backend is told to bring the drive
    to zero, the runs finished so far stay listed, and the manifest says how it ended.
    """
    backend, made_from = backend_from(backend, backend_name, rig_path)
    plan = load_plan(plan_path, backend.limits)
    check_drives(plan, backend)
    return execute_plan(
        out_dir,
        plan,
        Path(plan_path),
        backend,
        kind="characterization",
        on_progress=on_progress,
        rig_path=made_from,
    )


def execute_plan(
    out_dir: str | Path,
    plan: Plan,
    plan_file: Path,
    backend: Backend,
    *,
    kind: str,
    drive_for: Callable[[Protocol], Drive] = plain_drive,
    manifest_extra: dict[str, Any] | None = None,
    on_progress: Callable[[ProgressEvent], None] | None = None,
    rig_path: str | Path | None = None,
) -> CharacterizeResult:
    """Play every protocol of a checked plan into a new run directory with a manifest
    (``rig_path``: the rig file ``backend`` was made from, see :func:`rig_description`)."""
    try:  # the folder is made (and written to) before the rig is touched: a read-only one is one line
        out = new_output_dir(out_dir)
    except OSError as exc:
        if isinstance(exc, PiezopressError):
            raise
        raise output_error(out_dir, exc, "create this run directory") from None
    manifest: dict[str, Any] = {
        "manifest_version": MANIFEST_VERSION,
        "kind": kind,
        "status": "running",
        "created_utc": utc_now(),
        "software": software_versions(),
        "plan": {
            "file": str(plan_file),
            "sha256": runformat.sha256_file(plan_file),
            "name": plan.name,
            "description": plan.description,
            "document": plan.raw,
        },
        "rig": rig_description(backend, rig_path),
        **(manifest_extra or {}),
        "runs": [],
    }
    manifest_path = out / MANIFEST
    try:
        write_json_atomic(manifest_path, manifest)
    except OSError as exc:
        raise output_error(manifest_path, exc) from None
    result = CharacterizeResult(out, manifest_path, plan=plan)
    extra = {"software_version": piezopress.__version__, "rig": manifest["rig"]}
    total = len(plan.protocols)
    plan_s = plan.duration_s
    remaining = plan_s
    stop_signals = stop_signals_interrupt()
    try:
        stop_signals.__enter__()  # SIGTERM/SIGHUP: like Ctrl-C (ramp to 0 V, runs kept, manifest interrupted)
        for i, proto in enumerate(plan.protocols, start=1):
            at = {"plan_s": plan_s, "remaining_s": remaining}
            if on_progress:
                on_progress(ProgressEvent(i, total, proto, done=False, **at))
            t0 = time.perf_counter()

            def progress(fraction: float, i=i, proto=proto, at=at) -> None:
                if on_progress:
                    on_progress(ProgressEvent(i, total, proto, done=False, fraction=float(fraction), **at))

            try:
                run = run_protocol(backend, proto, plan, extra, drive_for, progress)
            except KeyboardInterrupt as exc:
                if getattr(exc, "run", None) is not None:  # Ctrl-C with a partial run: kept as incomplete
                    _keep_run(out, manifest_path, manifest, proto, exc.run, force_incomplete=True)  # type: ignore[attr-defined]
                raise
            path, complete = _keep_run(out, manifest_path, manifest, proto, run)
            if not complete:
                raise BackendError(
                    f"{proto.name}: the backend stopped the run early ({run.meta['status_reason']}); kept as "
                    f"{path.name}"
                )
            result.runs.append(path)
            remaining -= proto.duration_s
            if on_progress:
                on_progress(
                    ProgressEvent(
                        i,
                        total,
                        proto,
                        done=True,
                        elapsed_s=time.perf_counter() - t0,
                        path=path,
                        plan_s=plan_s,
                        remaining_s=remaining,
                    )
                )
    except BaseException as exc:
        try:
            backend.zero_output()
        except Exception as zero_exc:  # the manifest must still say how it ended
            manifest["zero_output_error"] = f"{type(zero_exc).__name__}: {zero_exc}"
        interrupted = isinstance(exc, KeyboardInterrupt)
        manifest["status"] = "interrupted" if interrupted else "failed"
        manifest["status_reason"] = (
            f"interrupted by {signal.Signals(exc.signum).name}"
            if getattr(exc, "signum", None)
            else "interrupted by the user"
            if interrupted
            else f"{type(exc).__name__}: {exc}"
        )
        manifest["finished_utc"] = utc_now()
        write_json_atomic(manifest_path, manifest)
        if isinstance(exc, (PiezopressError, KeyboardInterrupt)):
            raise
        raise BackendError(
            f"characterization stopped: {type(exc).__name__}: {exc} (runs so far kept in {out})"
        ) from exc
    finally:
        stop_signals.__exit__(None, None, None)
    manifest["status"] = "complete"
    manifest["finished_utc"] = utc_now()
    write_json_atomic(manifest_path, manifest)
    return result


def _keep_run(
    out: Path,
    manifest_path: Path,
    manifest: dict[str, Any],
    proto: Protocol,
    run: runformat.Run,
    *,
    force_incomplete: bool = False,
) -> tuple[Path, bool]:
    """Write one run (``NAME.parquet``, or ``NAME.incomplete.parquet`` if cut short) and list it in the manifest."""
    if force_incomplete and run.meta["status"] == runformat.STATUS_COMPLETE:
        run.meta["status"] = runformat.STATUS_INCOMPLETE
        run.meta["status_reason"] = run.meta.get("status_reason") or "interrupted by the user (Ctrl-C)"
    complete = run.meta["status"] == runformat.STATUS_COMPLETE
    path = out / (f"{proto.name}.parquet" if complete else f"{proto.name}.incomplete.parquet")
    sha = runformat.write_run(run, path)
    manifest["runs"].append(
        {
            "file": path.name,
            "sha256": sha,
            "name": proto.name,
            "kind": proto.run_kind,
            "status": run.meta["status"],
            "samples": len(run.data),
            "duration_s": len(run.data) / proto.sample_rate_hz,
        }
    )
    write_json_atomic(manifest_path, manifest)
    return path, complete


def check_drives(plan: Plan, backend: Backend) -> None:
    """Check every protocol's drive with the backend's own drive check, if it has one, before anything runs.

    A hardware backend checks more than the plan can (slew limits, output ranges); doing it
    for the whole plan up front keeps a characterization from stopping half-way on protocol 7.
    """
    check = getattr(backend, "check_drive", None)
    if check is None:  # a backend without its own check: the shared one, on its stated limits

        def check(command_v: np.ndarray, fs: float, label: str) -> None:
            drive_check.check_drive(command_v, fs, backend.limits, f"{backend.name}: {label}")

    problems = []
    for i, proto in enumerate(plan.protocols, start=1):
        _, command_v = proto.waveform()
        try:
            check(command_v, proto.sample_rate_hz, proto.name)
        except PiezopressError as exc:
            problems.append(f"protocol[{i}] '{proto.name}': {exc}")
    if problems:
        raise PlanError(plan.source, problems)
