"""The parameter bundle: one JSON file a technician can read and diff after a rig change.

Each fit stage writes a *section* file (``hysteresis``, ``creep``, ``shaper``) holding the
fitted parameters with units, fit quality and the runs it came from (file, sha256);
``assemble`` joins sections into the bundle. Keeping sections apart lets ``make refit``
redo only the stages whose inputs changed.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import piezopress
from piezopress import runformat
from piezopress.analysis.bundle import BUNDLE_VERSION, SECTIONS, Bundle, BundleError, check_section
from piezopress.pipelines.files import run_files, utc_now, write_json_atomic, write_output
from piezopress.pipelines.profiles import read_measured
from piezopress.pipelines.sources import check_one_rig, rig_identity


def collect_runs(paths: Iterable[str | Path], *, names: Iterable[str] = ()) -> list[runformat.Run]:
    """Runs from files and run directories (a directory: its manifest's complete runs, else
    every ``*.parquet``), optionally only those named."""
    files: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found = run_files(p)
            if not found:
                raise BundleError(
                    f"{p}: a directory holding no run (no manifest, no *.parquet file); expected a run directory "
                    "(from `piezopress characterize`) or run files (from `piezopress import`)"
                )
            files += found
        elif p.exists():
            files.append(p)
        else:
            raise BundleError(f"{p}: no such file or directory; expected run files or a run directory")
    runs = [read_measured(f) for f in files]
    check_one_rig(runs)
    wanted = list(names)
    if wanted:
        have = {r.name for r in runs}
        missing = [n for n in wanted if n not in have]
        if missing:
            raise BundleError(f"no run named {', '.join(missing)}; runs given: {', '.join(sorted(have)) or 'none'}")
        runs = [r for r in runs if r.name in wanted]
    return runs


def provenance(runs: Iterable[runformat.Run]) -> list[dict[str, Any]]:
    """Each run's name, file, sha256 and, where it names one, its press (:func:`rig_identity`'s digest)."""
    out = []
    for r in runs:
        entry = {"name": r.name, "file": str(r.path), "sha256": runformat.sha256_file(r.path) if r.path else None}
        ident = rig_identity(r.meta)
        entry["rig"] = ident.digest if ident is not None else None  # None: a run from elsewhere, no press recorded
        out.append(entry)
    return out


def inputs_digest(
    kind: str, runs: Iterable[runformat.Run], upstream: Iterable[dict[str, Any] | None] = (), **options: Any
) -> str:
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


def section(
    kind: str, body: dict[str, Any], runs: Iterable[runformat.Run], digest: str | None = None
) -> dict[str, Any]:
    """A section document: what, from which runs, by which software, when."""
    if kind not in SECTIONS:
        raise BundleError(f"section kind {kind!r} is unknown; expected one of {', '.join(SECTIONS)}")
    runs = list(runs)
    return {
        "section": kind,
        "bundle_version": BUNDLE_VERSION,
        "software_version": piezopress.__version__,
        "fitted_utc": utc_now(),
        "inputs_digest": digest or inputs_digest(kind, runs),
        "runs": provenance(runs),
        **body,
    }


def write_document(doc: dict[str, Any], path: str | Path, *, replace: bool = False) -> Path | None:
    """Write a section or bundle atomically; an existing file is replaced only with
    ``replace``, its old version kept under a unique timestamped name (returned) so nothing
    is lost. A non-finite figure (a fit quality that could not be computed) is written as
    ``null``: JSON has no NaN (the models' numbers are checked finite before they get here)."""
    clean = _finite(doc)
    return write_output(path, lambda tmp: write_json_atomic(tmp, clean, finite=True), replace=replace)


def _finite(v: Any) -> Any:
    """``v`` with every non-finite float (NaN, inf) as ``None``."""
    if isinstance(v, float) or type(v).__name__ in ("float64", "float32"):
        return float(v) if math.isfinite(v) else None
    if isinstance(v, dict):
        return {k: _finite(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_finite(x) for x in v]
    return v


def _load(path: Path, expect: str) -> Any:
    if not path.is_file():
        raise BundleError(f"{path}: no such file; expected a {expect} JSON file")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise BundleError(f"{path}: not text (binary data); expected a {expect} JSON file") from None
    except RecursionError:
        raise BundleError(f"{path}: nested too deeply; expected a {expect} JSON file") from None
    except json.JSONDecodeError as exc:
        raise BundleError(
            f"{path}: not valid JSON ({exc.msg} at line {exc.lineno}); expected a {expect} file"
        ) from None


def read_bundle(path: str | Path) -> Bundle:
    """The bundle file at ``path``, checked (:meth:`Bundle.from_dict`)."""
    path = Path(path)
    return Bundle.from_dict(_load(path, "bundle"), str(path))


def read_document(path: str | Path, expect: str | None = None) -> dict[str, Any]:
    """A bundle (``expect`` ``"bundle"`` or ``None``) or section file, checked as it is read."""
    path = Path(path)
    if expect in SECTIONS:
        doc = _load(path, expect)
        check_section(expect, doc, str(path))
        return doc
    return read_bundle(path).to_dict()


def assemble(sections: dict[str, dict[str, Any]], compensation: dict[str, Any]) -> dict[str, Any]:
    """The bundle: every section, and the compensation settings built on them."""
    if "hysteresis" not in sections:
        raise BundleError("a bundle needs at least the hysteresis section")
    digest = inputs_digest("bundle", [], [sections[k] for k in SECTIONS if k in sections], **compensation)
    return {
        "bundle_version": BUNDLE_VERSION,
        "kind": "piezopress-bundle",
        "software_version": piezopress.__version__,
        "created_utc": utc_now(),
        "inputs_digest": digest,
        **{k: sections[k] for k in SECTIONS if k in sections},
        "compensation": compensation,
    }
