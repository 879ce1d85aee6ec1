"""The parameter bundle: one JSON file a technician can read and diff after a rig change.

Each fit stage writes a *section* file (``hysteresis``, ``creep``, ``shaper``) holding the
fitted parameters with units, fit quality and the runs it came from (file, sha256);
``assemble`` joins sections into the bundle. Keeping sections apart lets ``make refit``
redo only the stages whose inputs changed.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any, Iterable

import piezopress
from piezopress import runformat, units
from piezopress.analysis.compensation import RATE_TAU_S, Compensator, RateDependence
from piezopress.analysis.creep import CreepModel
from piezopress.analysis.hysteresis import PIModel
from piezopress.analysis.shaper import Shaper
from piezopress.errors import PiezopressError
from piezopress.pipelines.files import check_output, run_files, utc_now, write_json_atomic

BUNDLE_VERSION = 1
SECTIONS = ("hysteresis", "creep", "shaper")


class BundleError(PiezopressError, ValueError):
    """A bundle or section file is missing, unreadable or inconsistent."""


def collect_runs(paths: Iterable[str | Path], *, names: Iterable[str] = ()) -> list[runformat.Run]:
    """Runs from files and run directories (a directory: its manifest's complete runs, else
    every ``*.parquet``), optionally only those named."""
    files: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            files += run_files(p)
        elif p.exists():
            files.append(p)
        else:
            raise BundleError(f"{p}: no such file or directory; expected run files or a run directory")
    runs = [runformat.read_run(f) for f in files]
    wanted = list(names)
    if wanted:
        have = {r.name for r in runs}
        missing = [n for n in wanted if n not in have]
        if missing:
            raise BundleError(f"no run named {', '.join(missing)}; runs given: {', '.join(sorted(have)) or 'none'}")
        runs = [r for r in runs if r.name in wanted]
    return runs


def provenance(runs: Iterable[runformat.Run]) -> list[dict[str, Any]]:
    return [{"name": r.name, "file": str(r.path), "sha256": runformat.sha256_file(r.path) if r.path else None} for r in runs]


def inputs_digest(kind: str, runs: Iterable[runformat.Run], upstream: Iterable[dict[str, Any] | None] = (), **options: Any) -> str:
    """A digest of everything a stage's result depends on: the runs' bytes, the upstream
    sections' own digests, the options and the software version. Equal digests, equal
    results: ``--if-changed`` skips the stage."""
    import hashlib

    h = hashlib.sha256()
    parts = {
        "kind": kind,
        "software": piezopress.__version__,
        "runs": sorted(runformat.sha256_file(r.path) for r in runs if r.path is not None),
        "upstream": [u.get("inputs_digest") for u in upstream if u is not None],
        "options": {k: options[k] for k in sorted(options)},
    }
    h.update(json.dumps(parts, sort_keys=True, default=str).encode())
    return h.hexdigest()


def up_to_date(path: str | Path, digest: str) -> bool:
    """True if ``path`` holds a document made from inputs with this digest."""
    path = Path(path)
    if not path.is_file():
        return False
    try:
        return json.loads(path.read_text(encoding="utf-8")).get("inputs_digest") == digest
    except json.JSONDecodeError:
        return False


def section(kind: str, body: dict[str, Any], runs: Iterable[runformat.Run], digest: str | None = None) -> dict[str, Any]:
    """A section document: what, from which runs, by which software, when."""
    if kind not in SECTIONS:
        raise BundleError(f"section kind {kind!r} is unknown; expected one of {', '.join(SECTIONS)}")
    runs = list(runs)
    return {"section": kind, "bundle_version": BUNDLE_VERSION, "software_version": piezopress.__version__,
            "fitted_utc": utc_now(), "inputs_digest": digest or inputs_digest(kind, runs), "runs": provenance(runs), **body}


def write_document(doc: dict[str, Any], path: str | Path, *, replace: bool = False) -> Path | None:
    """Write a section or bundle; an existing file is replaced only with ``replace``, and then
    kept as ``<name>.prev.json`` (returned) so nothing is lost."""
    path = Path(path)
    previous = None
    check_output(path, replace=replace)
    if path.exists():
        previous = path.with_name(path.stem + ".prev.json")
        shutil.copy2(path, previous)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(path, doc)
    return previous


def read_document(path: str | Path, expect: str | None = None) -> dict[str, Any]:
    path = Path(path)
    if not path.is_file():
        raise BundleError(f"{path}: no such file; expected a {expect or 'bundle'} JSON file")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise BundleError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno}); expected a {expect or 'bundle'} file") from None
    if doc.get("bundle_version") != BUNDLE_VERSION:
        raise BundleError(f"{path}: bundle_version is {doc.get('bundle_version')!r}, expected {BUNDLE_VERSION}")
    if expect in SECTIONS and doc.get("section") != expect:
        raise BundleError(f"{path}: holds section {doc.get('section')!r}, expected {expect!r}")
    if expect == "bundle" and "hysteresis" not in doc:
        raise BundleError(f"{path}: has no hysteresis section; expected a bundle made by `piezopress bundle`")
    return doc


def assemble(sections: dict[str, dict[str, Any]], compensation: dict[str, Any]) -> dict[str, Any]:
    """The bundle: every section, and the compensation settings built on them."""
    if "hysteresis" not in sections:
        raise BundleError("a bundle needs at least the hysteresis section")
    digest = inputs_digest("bundle", [], [sections[k] for k in SECTIONS if k in sections], **compensation)
    return {"bundle_version": BUNDLE_VERSION, "kind": "piezopress-bundle", "software_version": piezopress.__version__,
            "created_utc": utc_now(), "inputs_digest": digest, **{k: sections[k] for k in SECTIONS if k in sections},
            "compensation": compensation}


def _rate(d: dict[str, Any] | None) -> RateDependence | None:
    """The rate dependence a bundle's ``compensation.rate_dependence`` describes (diagnose writes it)."""
    if not d:
        return None
    sat = d.get("saturation_v_per_s")
    return RateDependence(widen_v_per_kv_s=float(d.get("widen_v_per_kv_s", 0.0)), loss_per_kv_s=float(d.get("loss_per_kv_s", 0.0)),
                          saturation_v_per_s=float(sat) if sat else None, tau_s=float(d.get("tau_s", RATE_TAU_S)))


def _shaper(s: dict[str, Any]) -> Shaper:
    return Shaper(name=s["name"], times_s=tuple(s["times_s"]), amplitudes=tuple(s["amplitudes"]),
                  wn=float(s["natural_freq_rad_s"]), zeta=float(s["damping"]), zv_power=s.get("zv_power"))


def compensator(bundle: dict[str, Any], *, use_shaper: bool = True, use_creep: bool = True) -> Compensator:
    """The compensator a bundle describes."""
    try:
        hyst = PIModel.from_dict(bundle["hysteresis"]["model"])
        creep = CreepModel.from_dict(bundle["creep"]["model"]) if use_creep and "creep" in bundle else None
        shaper = shaper2 = None
        if use_shaper and "shaper" in bundle:
            shaper = _shaper(bundle["shaper"]["shaper"])
            # a second mode found by diagnose: its own shaper, after the first
            shaper2 = _shaper(bundle["shaper"]["shaper2"]) if bundle["shaper"].get("shaper2") else None
        comp = bundle.get("compensation", {})
        # without the shaper the mode's delay is not led; a pure input delay still is
        lead = float(comp.get("lead_s", 0.0)) if use_shaper else float(comp.get("delay_lead_s", 0.0))
        return Compensator(
            hysteresis=hyst,
            creep=creep,
            shaper=shaper,
            drive_min_v=float(comp.get("drive_min_v", 0.0)),
            drive_max_v=float(comp.get("drive_max_v", 150.0)),
            max_rate_per_s=comp.get(f"max_rate_{units.key(hyst.output_unit)}_per_s"),
            lead_s=lead,
            shaper2=shaper2,
            rate=_rate(comp.get("rate_dependence")),
            slew_v_per_s=comp.get("slew_v_per_s"),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise BundleError(f"the bundle is incomplete or inconsistent ({type(exc).__name__}: {exc})") from None
