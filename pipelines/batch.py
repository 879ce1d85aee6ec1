"""``batch``: many presses at once, each one task running the single-press pipeline functions.

A press is a run set (a run directory, run files, or several, with an optional rig file and
bundle). :func:`run_batch` runs one stage (``fit``, ``diagnose``, ``validate``, ``report``, or
``all`` of them in a row) for every press, on a Dask cluster when Dask is installed (a local
one sized to the machine, or an existing scheduler), else one press after the other. Each
press writes into its own folder under the output; ``fleet.csv`` gets one row per press: its
status (done, failed and why, skipped as unchanged), the bundle's key figures, the validated
Table 6.13 rows, the findings and the wall time. A press that fails is its row, never the
batch's end; a rerun skips a press whose inputs (the runs' bytes, the rig file, the bundle,
the stage, the software) are unchanged. There is no scheduler here: Dask schedules.
"""

from __future__ import annotations

import csv
import glob
import hashlib
import json
import math
import os
import shutil
import tempfile
import time
import traceback
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import piezopress
from piezopress import runformat
from piezopress.errors import PiezopressError

STAGES = ("fit", "diagnose", "validate", "report", "all")
FLEET_CSV = "fleet.csv"
PRESS_RECORD = "batch.json"  # in each press's folder: the inputs' digest and the row

#: fleet.csv's columns, in order (figures in the press's own output unit).
COLUMNS = (
    "press",
    "stage",
    "status",
    "why",
    "wall_s",
    "output_unit",
    "model_family",
    "plays",
    "dead_zones",
    "holdout_rms",
    "holdout_pct",
    "creep_form",
    "mode_rad_s",
    "damping",
    "shaper",
    "max_static_hysteresis_pct",
    "creep_pct",
    "overshoot_pct",
    "tracking_error_pct",
    "findings",
    "out",
)

#: The key figures the fleet report compares across presses.
FIGURES = (
    "holdout_pct",
    "mode_rad_s",
    "damping",
    "max_static_hysteresis_pct",
    "creep_pct",
    "overshoot_pct",
    "tracking_error_pct",
)


class BatchError(PiezopressError, ValueError):
    """A press list that cannot be read (a manifest without its columns, a glob matching nothing)."""


@dataclass(frozen=True)
class Press:
    """One press of the fleet: its name, its runs (directories, run files or fsspec URLs), and
    optionally the rig file it is validated on and a bundle to use instead of fitting one."""

    name: str
    runs: tuple[str, ...]
    rig: str | None = None
    bundle: str | None = None


# --------------------------------------------------------------------------- the press list


def read_presses(spec: str | Path) -> list[Press]:
    """The presses a spec names: a manifest CSV (columns ``press``, ``runs``; optional ``rig``,
    ``bundle``; ``runs`` may hold several paths separated by ``;``; relative paths are from the
    CSV's folder), or a glob of run directories (each one press, named by its folder)."""
    text = str(spec)
    if text.lower().endswith(".csv") and Path(text).is_file():
        return _from_manifest(Path(text))
    found = sorted(p for p in glob.glob(text) if Path(p).is_dir() or p.endswith(".parquet"))
    if not found:
        raise BatchError(f"{text}: matches no run directory; expected a glob of run directories or a manifest CSV")
    presses, seen = [], {}
    for p in found:
        name = Path(p.rstrip("/")).name or p
        seen[name] = seen.get(name, 0) + 1
        presses.append(Press(name if seen[name] == 1 else f"{name}-{seen[name]}", (p,)))
    return presses


def _from_manifest(path: Path) -> list[Press]:
    try:
        with path.open(newline="", encoding="utf-8-sig") as f:
            rows = list(csv.DictReader(f))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise BatchError(
            f"{path}: cannot be read as CSV ({exc}); expected columns press, runs[, rig, bundle]"
        ) from None
    if not rows or not {"press", "runs"} <= set(rows[0]):
        raise BatchError(f"{path}: no rows with columns press and runs; expected columns press, runs[, rig, bundle]")
    base = path.parent
    presses, names = [], set()

    def at(p: str) -> str:
        p = p.strip()
        return p if "://" in p or Path(p).is_absolute() else str(base / p)

    for i, row in enumerate(rows, start=2):  # the header is line 1
        name = (row.get("press") or "").strip()
        runs = [at(r) for r in (row.get("runs") or "").split(";") if r.strip()]
        if not name or not runs:
            raise BatchError(f"{path}: line {i}: press {name!r}, runs {row.get('runs')!r}; expected both")
        if name in names:
            raise BatchError(f"{path}: line {i}: press {name!r} named twice; expected one row per press")
        if any(c in name for c in "/\\:") or name in (".", ".."):
            raise BatchError(f"{path}: line {i}: press {name!r}; expected a name usable as a folder name")
        names.add(name)
        rig = (row.get("rig") or "").strip() or None
        bundle = (row.get("bundle") or "").strip() or None
        presses.append(Press(name, tuple(runs), at(rig) if rig else None, at(bundle) if bundle else None))
    return presses


# --------------------------------------------------------------------------- one press


def _localise(paths: Sequence[str], work: Path) -> list[str]:
    """Local paths for the runs: a local path as it is, an fsspec URL (``s3://``, ``file://``,
    ...) copied into ``work`` first (a directory: every file under it)."""
    out = []
    for p in paths:
        if "://" not in p:
            out.append(p)
            continue
        import fsspec

        fs, root = fsspec.core.url_to_fs(p)
        dest = work / hashlib.sha256(p.encode()).hexdigest()[:12]
        if fs.isdir(root):
            dest.mkdir(parents=True, exist_ok=True)
            for f in fs.find(root):
                target = dest / Path(f).relative_to(Path(root)) if f.startswith(root) else dest / Path(f).name
                target.parent.mkdir(parents=True, exist_ok=True)
                fs.get(f, str(target))
            out.append(str(dest))
        else:
            dest.mkdir(parents=True, exist_ok=True)
            fs.get(root, str(dest / Path(root).name))
            out.append(str(dest / Path(root).name))
    return out


def _files_of(paths: Sequence[str]) -> list[Path]:
    from piezopress.pipelines.files import run_files

    files: list[Path] = []
    for p in map(Path, paths):
        files += run_files(p) if p.is_dir() else [p]
    return files


def inputs_digest(press: Press, local: Sequence[str], stage: str) -> str:
    """What a press's result depends on: the stage, every run file's bytes, the rig file's and
    the bundle's bytes, the software version. Equal digests: the press is skipped."""
    h = hashlib.sha256()
    h.update(json.dumps([stage, piezopress.__version__]).encode())
    for f in sorted(_files_of(local), key=lambda p: p.name):
        h.update(f.name.encode())
        h.update(runformat.sha256_file(f).encode())
    for extra in (press.rig, press.bundle):
        h.update((runformat.sha256_file(extra) if extra and Path(extra).is_file() else str(extra)).encode())
    return h.hexdigest()


def _bundle_figures(doc: dict[str, Any]) -> dict[str, Any]:
    from piezopress import units

    h = doc.get("hysteresis") or {}
    fit, model = h.get("fit") or {}, h.get("model") or {}
    unit = units.normalise(model.get("output_unit"))
    k = units.key(unit)
    creep = doc.get("creep") or {}
    shaper = doc.get("shaper") or {}
    mode = shaper.get("mode") or {}
    return {
        "output_unit": unit,
        "model_family": (
            f"PI + Preisach plane ({len((model.get('preisach_plane') or {}).get('weights', []))} cells)"
            if model.get("family") == "pi_preisach_plane"
            else f"PI + Duhem elements ({len((model.get('duhem_elements') or {}).get('weights', []))})"
            if model.get("family") == "pi_duhem"
            else "modified Prandtl-Ishlinskii"
        ),
        "plays": len(model.get("play_thresholds", [])),
        "dead_zones": len(model.get("dead_zone_thresholds", [])),
        "holdout_rms": fit.get(f"holdout_rms_{k}"),
        "holdout_pct": fit.get("holdout_rms_pct_of_range"),
        "creep_form": (creep.get("fit") or {}).get("chosen_form") if creep else "none",
        "mode_rad_s": mode.get("natural_freq_rad_s"),
        "damping": mode.get("damping"),
        "shaper": (shaper.get("shaper") or {}).get("name", "?") if shaper else "none",
    }


def _report_figures(metrics_csv: Path) -> dict[str, Any]:
    """The compensated Table 6.13 rows (each figure's worst run) from a report's metrics.csv."""
    out: dict[str, Any] = {}
    if not metrics_csv.is_file():
        return out
    with metrics_csv.open(newline="") as f:
        for row in csv.DictReader(f):
            if row.get("table") == "6.13" and row.get("metric") == "controlled_max" and row.get("value"):
                out[f"{row['test']}_pct"] = float(row["value"])
    return out


def _virtual_backend(local: Sequence[str]):
    """The virtual rig the runs were recorded on (from their metadata), or None."""
    from piezopress.acquisition.virtual_rig import VirtualRig
    from piezopress.pipelines.gain import rig_of_runs

    try:
        cfg, _ = rig_of_runs(local)
    except PiezopressError:
        return None
    return VirtualRig(cfg)


def _stage_fit(press: Press, local: list[str], out: Path, base: bool = False) -> Path:
    from piezopress.pipelines import bundle as B
    from piezopress.pipelines import characterize as char
    from piezopress.pipelines import fit as F

    act = char.rig_limits(press.rig or char.DEFAULT_RIG)
    fitted = F.fit_bundle(local, act if press.rig else None, base=base, record_range=act if press.rig is None else None)
    path = out / ("base.json" if base else "bundle.json")
    B.write_document(fitted.doc, path)
    return path


def _stage_validate(press: Press, local: list[str], out: Path, bundle: Path) -> Path | None:
    from piezopress.pipelines import validate as V

    backend = None if press.rig else _virtual_backend(local)
    if press.rig is None and backend is None:
        return None  # nothing to play it on: said in the row
    val = out / "validation"
    V.validate(val, bundle, rig_path=press.rig, backend=backend)
    return val


def _stage_diagnose(press: Press, local: list[str], out: Path) -> tuple[Path, list[str]]:
    from piezopress.pipelines import diagnose as D

    base = _stage_fit(press, local, out, base=True)
    result, diag = D.diagnose(local, base, out / "diagnosis")
    return diag, [f.cause for f in result.findings]


def _stage_report(local: list[str], out: Path, bundle: Path | None, val: Path | None, diag: Path | None) -> Path:
    from piezopress.pipelines import report as R

    char = local[0] if len(local) == 1 else None
    R.generate(
        out / "report",
        characterization=char,
        validation=val if val is not None and val.is_dir() else None,
        bundle=bundle if bundle is not None and bundle.is_file() else None,
        diagnosis=diag if diag is not None and diag.is_dir() else None,
    )
    return out / "report"


def press_task(press: Press, stage: str, out_root: str) -> dict[str, Any]:
    """One press, one stage (``all``: fit, validate, diagnose, report): the same functions as
    the single-press commands, into ``out_root/<press>``. Returns the press's fleet row; never
    raises (a failure is the row's status and reason)."""
    started = time.monotonic()
    out = Path(out_root) / press.name
    row: dict[str, Any] = {"press": press.name, "stage": stage, "out": str(out)}
    work = Path(tempfile.mkdtemp(prefix="piezopress-batch-"))
    try:
        local = _localise(press.runs, work)
        for p in local:
            if not Path(p).exists():
                raise BatchError(f"{p}: no such run file or directory")
        digest = inputs_digest(press, local, stage)
        record = out / PRESS_RECORD
        if record.is_file():
            try:
                prev = json.loads(record.read_text(encoding="utf-8"))
            except (ValueError, UnicodeDecodeError):
                prev = {}
            if prev.get("digest") == digest and (prev.get("row") or {}).get("status") == "done":
                return {**prev["row"], "status": "skipped", "why": "unchanged since the last batch", "wall_s": 0.0}
        if out.exists():  # inputs changed (or a failed attempt): the old results are kept aside, never lost
            from piezopress.pipelines.files import kept_name

            os.replace(out, kept_name(out))
        out.mkdir(parents=True)
        notes: list[str] = []
        bundle = Path(press.bundle) if press.bundle else None
        val = diag = None
        findings: list[str] = []
        if stage in ("fit", "all") and bundle is None:
            bundle = _stage_fit(press, local, out)
        if stage in ("validate", "all"):
            if bundle is None:
                raise BatchError("validate needs a bundle: give the press one (column bundle) or run batch all")
            val = _stage_validate(press, local, out, bundle)
            if val is None:
                notes.append("not validated: no rig file and the runs are not from the virtual rig")
        if stage in ("diagnose", "all"):
            diag, findings = _stage_diagnose(press, local, out)
            row["findings"] = ";".join(findings) or "none"
        if stage in ("report", "all"):
            rep = _stage_report(local, out, bundle, val, diag)
            row.update(_report_figures(rep / "metrics.csv"))
        if bundle is not None and bundle.is_file():
            row.update(_bundle_figures(json.loads(bundle.read_text(encoding="utf-8"))))
        row.update(status="done", why="; ".join(notes))
        row["wall_s"] = round(time.monotonic() - started, 2)
        from piezopress.pipelines.files import write_json_atomic

        write_json_atomic(record, {"digest": digest, "row": row}, null_nonfinite=True)
        return row
    except PiezopressError as exc:
        return {**row, "status": "failed", "why": str(exc), "wall_s": round(time.monotonic() - started, 2)}
    except Exception as exc:  # noqa: BLE001 - a press that fails is its row, never the batch's end
        where = traceback.extract_tb(exc.__traceback__)[-1]
        why = f"{type(exc).__name__}: {exc} (at {Path(where.filename).name}:{where.lineno})"
        return {**row, "status": "failed", "why": why, "wall_s": round(time.monotonic() - started, 2)}
    finally:
        shutil.rmtree(work, ignore_errors=True)


# --------------------------------------------------------------------------- the fleet


@dataclass
class BatchResult:
    rows: list[dict[str, Any]]
    fleet_csv: Path
    wall_s: float
    engine: str  # "serial", "dask local (N workers)", "dask <address>"
    dashboard: str | None = None
    notes: list[str] = field(default_factory=list)


def dask_available() -> bool:
    try:
        import dask.distributed  # noqa: F401
    except ImportError:
        return False
    return True


def run_batch(
    presses: Sequence[Press],
    stage: str,
    out_root: str | Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    serial: bool = False,
    on_done: Callable[[int, int, dict[str, Any]], None] | None = None,
    on_start: Callable[[str, str | None], None] | None = None,
) -> BatchResult:
    """Every press through ``stage``; see the module docstring. ``workers``: the local
    cluster's size (default: the CPUs this process may use); ``scheduler``: an existing Dask
    scheduler's address; ``serial`` (or Dask missing): one press after the other, here.
    ``on_start(engine, dashboard)`` and ``on_done(i, n, row)`` report progress."""
    if stage not in STAGES:
        raise BatchError(f"stage {stage!r}; expected one of {', '.join(STAGES)}")
    if not presses:
        raise BatchError("no presses to run")
    out_root = Path(out_root)
    out_root.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    notes: list[str] = []
    rows: list[dict[str, Any]] = []
    dashboard = None
    if serial or not dask_available():
        if not serial:
            notes.append(
                "Dask is not installed: the presses ran one after the other (pip install 'piezopress[fleet]' to run "
                "them on all cores or a cluster)"
            )
        engine = "serial"
        if on_start:
            on_start(engine, None)
        for i, p in enumerate(presses, 1):
            rows.append(press_task(p, stage, str(out_root)))
            if on_done:
                on_done(i, len(presses), rows[-1])
    else:
        from dask.distributed import Client, as_completed

        cluster = None
        if scheduler:
            client = Client(scheduler)
            engine = f"dask {scheduler}"
        else:
            cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
            n = workers or cpus
            cluster = local_cluster(n)
            client = Client(cluster)
            engine = f"dask local ({n} workers)"
        dashboard = getattr(client, "dashboard_link", None)
        if on_start:
            on_start(engine, dashboard)
        try:
            futures = client.map(press_task, list(presses), stage=stage, out_root=str(out_root), pure=False)
            order = {f.key: i for i, f in enumerate(futures)}
            done: dict[int, dict[str, Any]] = {}
            for k, fut in enumerate(as_completed(futures), 1):
                try:
                    row = fut.result()
                except Exception as exc:  # noqa: BLE001 - a worker lost: that press's row says so
                    p = presses[order[fut.key]]
                    row = {"press": p.name, "stage": stage, "status": "failed", "why": f"worker: {exc}"}
                done[order[fut.key]] = row
                if on_done:
                    on_done(k, len(presses), row)
            rows = [done[i] for i in range(len(presses))]
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    path = write_fleet_csv(rows, out_root / FLEET_CSV)
    return BatchResult(rows, path, time.monotonic() - started, engine, dashboard, notes)


#: One BLAS thread per worker process: n presses on n cores, not n x n threads.
ONE_THREAD = {k: "1" for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}


def local_cluster(n_workers: int):
    """A local Dask cluster of ``n_workers`` processes, one thread and one BLAS thread each.

    Dask reads ``distributed.nanny.pre-spawn-environ`` with the parent's environment first
    (``os.environ.get(key, configured)``): where this process has ``OPENBLAS_NUM_THREADS=2``
    (the user's shell, or piezopress's default before it was one thread), the workers each ran
    OpenBLAS with 2 threads on 2 cores, and a press took 16-18 s on a worker against 10-12 s
    alone. So the variables are set here while the nannies are made, and restored after.
    Dask also sets ``MALLOC_TRIM_THRESHOLD_`` by default: an explicit trim threshold turns
    off glibc's adaptive mmap threshold, so every array of a run (160 kB and more) is mapped
    and faulted in anew (a diagnosis took 12.8 s instead of 8.2 s, 4.6 s in the kernel); it
    is left out. Nor does a press's task need the workers' profiler."""
    import dask
    from dask.distributed import LocalCluster

    saved = {k: os.environ.get(k) for k in ONE_THREAD}
    os.environ.update(ONE_THREAD)
    try:
        with dask.config.set(
            {"distributed.nanny.pre-spawn-environ": ONE_THREAD, "distributed.worker.profile.enabled": False}
        ):
            return LocalCluster(
                n_workers=n_workers,
                threads_per_worker=1,
                processes=True,
                dashboard_address=":0",
                silence_logs=40,
                env=ONE_THREAD,
            )
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def write_fleet_csv(rows: Iterable[dict[str, Any]], path: Path) -> Path:
    """``fleet.csv``: one row per press, the columns of :data:`COLUMNS` (written atomically)."""
    tmp = path.with_name(f".{path.name}.partial")
    with tmp.open("w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=list(COLUMNS), extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: _cell(r.get(k)) for k in COLUMNS})
    os.replace(tmp, path)
    return path


def _cell(v: Any) -> Any:
    if isinstance(v, float):
        return "" if not math.isfinite(v) else f"{v:.6g}"
    return "" if v is None else v


def read_fleet_csv(path: str | Path) -> list[dict[str, Any]]:
    with Path(path).open(newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


__all__ = [
    "Press",
    "STAGES",
    "COLUMNS",
    "FIGURES",
    "BatchError",
    "BatchResult",
    "read_presses",
    "press_task",
    "run_batch",
    "write_fleet_csv",
    "read_fleet_csv",
    "inputs_digest",
    "dask_available",
    "local_cluster",
]
