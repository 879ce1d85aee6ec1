"""Adopt only what wins on the press: a diagnosis's extensions measured with ``compare`` on the
press the runs came from, and the recommended bundle.

The base bundle, each finding's extension alone (when there are several) and the extended
bundle (every finding) are played on the press, interleaved and repeated
(:func:`piezopress.pipelines.compare.compare`); the recommended bundle is the measured one
that wins the most rows against the base and on no row is, or may be, worse
(:func:`piezopress.analysis.ab.recommend`), the base itself when no extension does. A
combination that was not played is never recommended.

Files, in the diagnosis's directory: ``gain-on-press/`` (the comparison: its runs,
``compare.csv``), ``gain-on-press-bundles/`` (each finding's bundle alone),
``recommended_bundle.json`` (with a ``recommendation`` section: what went in and why), and
``extended_bundle.json``'s ``gain_on_press`` section (measured or not, and the verdicts).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from piezopress import runformat
from piezopress.acquisition.backend import Backend
from piezopress.analysis import ab
from piezopress.pipelines.bundle import read_bundle, read_document, write_document
from piezopress.pipelines.compare import Comparison, Play, compare
from piezopress.pipelines.files import write_json_atomic

__all__ = [
    "GAIN_DIR",
    "BUNDLES_DIR",
    "RECOMMENDED",
    "UNVERIFIED",
    "Adoption",
    "measure_on_press",
    "unverified_note",
]

GAIN_DIR = "gain-on-press"
BUNDLES_DIR = "gain-on-press-bundles"
RECOMMENDED = "recommended_bundle.json"
BASE_LABEL = "base"
EXTENDED_LABEL = "extended"
FITTED_LABEL = "fitted"

#: What an extended bundle whose gain was not measured on the press says of itself.
UNVERIFIED = (
    "unverified on the press: its gain was not measured there (piezopress diagnose --gain --rig YOUR-PRESS.toml, or "
    "piezopress compare BASE.json extended_bundle.json --rig YOUR-PRESS.toml); a gain shown for the virtual rig is the "
    "simulator's, not the press's"
)


def unverified_note() -> dict[str, Any]:
    """``extended_bundle.json``'s ``gain_on_press`` section before anything was measured."""
    return {"measured": False, "note": UNVERIFIED}


@dataclass(frozen=True)
class Adoption:
    """What the press said: the comparison, the recommendation and where it was written."""

    comparison: Comparison | None  # None: no finding, nothing to measure
    recommendation: ab.Recommendation
    recommended_path: Path
    candidates: tuple[ab.Candidate, ...]
    reference: str = BASE_LABEL  # what the candidates were judged against: the bundle in use


def measure_on_press(
    diag_dir: str | Path,
    base_path: str | Path,
    findings: Sequence[Any],
    *,
    rig_path: str | Path | None = None,
    backend: Backend | None = None,
    backend_name: str | None = None,
    repeats: int = 3,
    press_label: str = "",
    fitted_path: str | Path | None = None,
    on_play: Callable[[Play], None] | None = None,
    on_warning: Callable[[str], None] | None = None,
) -> Adoption:
    """Measure the diagnosis's extensions on the press and write the recommended bundle; see the
    module. ``fitted_path``: the bundle in use (``fit``'s): it is played too, with each extension
    on it, and the recommendation is never worse than it on any row beyond the spread."""
    diag = Path(diag_dir)
    ext_path = diag / "extended_bundle.json"
    base = read_bundle(base_path)
    bundles: list[Path] = [Path(base_path)]
    labels = [BASE_LABEL]
    causes: list[tuple[str, ...]] = [()]
    single_dir = diag / BUNDLES_DIR
    if len(findings) > 1:  # each extension alone, to adopt the ones that win and leave the others
        single_dir.mkdir(exist_ok=True)
        for f in findings:
            path = single_dir / f"{f.cause}.json"
            write_document(base.extended([f], f.model).to_dict(), path, replace=True)
            bundles.append(path)
            labels.append(f"+{f.cause}")
            causes.append((f.cause,))
    reference, reference_path = BASE_LABEL, Path(base_path)
    if fitted_path is not None:  # the bundle in use, and the extensions on it
        reference, reference_path = FITTED_LABEL, Path(fitted_path)
        fitted = read_bundle(fitted_path)
        bundles.append(Path(fitted_path))
        labels.append(FITTED_LABEL)
        causes.append(())
        if findings:
            single_dir.mkdir(exist_ok=True)
            sets = [[f] for f in findings] + ([list(findings)] if len(findings) > 1 else [])
            for fs in sets:
                name = fs[0].cause if len(fs) == 1 else "all"
                path = single_dir / f"fitted+{name}.json"
                write_document(fitted.extended(fs, fs[-1].model).to_dict(), path, replace=True)
                bundles.append(path)
                labels.append(f"{FITTED_LABEL}+{name}")
                causes.append(tuple(f.cause for f in fs))
    if not findings:  # nothing to measure: the bundle in use is the recommendation, said so
        doc = read_document(reference_path, "bundle")
        doc["recommendation"] = {
            "measured": False,
            "bundle": reference,
            "from_file": str(reference_path),
            "sha256": runformat.sha256_file(reference_path),
            "adopted": [],
            "reasons": {},
            "better_on": [],
            "note": f"the diagnosis found nothing to extend: the {reference} bundle, nothing played",
        }
        out = diag / RECOMMENDED
        write_document(doc, out, replace=True)
        return Adoption(None, ab.Recommendation(None, (), {}), out, (), reference)
    bundles.append(ext_path)
    labels.append(EXTENDED_LABEL)
    causes.append(tuple(f.cause for f in findings))
    comparison = compare(
        bundles,
        diag / GAIN_DIR,
        rig_path=rig_path,
        backend=backend,
        backend_name=backend_name,
        repeats=repeats,
        labels=labels,
        on_play=on_play,
        on_warning=on_warning,
    )
    candidates = tuple(
        ab.Candidate.judged(lbl, c, comparison.judged(lbl, reference))
        for lbl, c in zip(labels, causes)
        if lbl != reference
    )
    rec = ab.recommend(candidates, f"the {reference} bundle")
    chosen = bundles[labels.index(rec.label)] if rec.label else reference_path
    doc = read_document(chosen, "bundle")
    by_label = {c.label: c for c in candidates}
    measured = {
        "measured": True,
        "press": press_label or str(rig_path or "the runs' virtual rig"),
        "comparison": str(comparison.out_dir),
        "repeats": comparison.repeats,
        "rule": (
            "better/worse: every repeat of one beats every repeat of the other, Welch's p < "
            f"{ab.ALPHA:g} with Holm's correction over the rows and a change of at least {ab.MIN_CHANGE_PCT:g} %; "
            f"adopted only where no row may be worse (a change for the worse of {ab.MIN_CHANGE_PCT:g} % or more "
            f"with Welch's p < {ab.DOUBT_ALPHA:g})"
        ),
    }
    doc["recommendation"] = {
        **measured,
        "against": reference,
        "bundle": rec.label or reference,
        "from_file": str(chosen),
        "sha256": runformat.sha256_file(chosen),
        "adopted": list(rec.causes),
        "reasons": rec.reasons,
        "better_on": list(by_label[rec.label].wins) if rec.label else [],
    }
    out = diag / RECOMMENDED
    write_document(doc, out, replace=True)
    # the extended bundle says what the press said of it
    ext = read_document(ext_path, "bundle")
    c = ab.Candidate.judged(EXTENDED_LABEL, (), comparison.judged(EXTENDED_LABEL))  # against the base it extends
    ext["gain_on_press"] = {
        **measured,
        "verdicts": c.verdicts,
        "better_on": list(c.wins),
        "worse_on": list(c.losses),
        "may_be_worse_on": c.doubts,
    }
    write_json_atomic(ext_path, ext, null_nonfinite=True)
    return Adoption(comparison, rec, out, candidates, reference)


def format_adoption(a: Adoption) -> str:
    """What the press said, for the terminal: the recommendation and every extension's reason."""
    rec = a.recommendation
    lines = []
    if a.comparison is None:
        return (
            f"Recommended: {a.recommended_path} = the {a.reference} bundle: the diagnosis found nothing to extend, "
            "nothing played."
        )
    if rec.label:
        lines.append(
            f"Recommended: {a.recommended_path} = the {rec.label} bundle"
            + (f" ({', '.join(rec.causes)})" if rec.causes else "")
            + f", better than the {a.reference} bundle on the press on "
            f"{', '.join(next(c for c in a.candidates if c.label == rec.label).wins)} and on no row worse or "
            "possibly worse."
        )
    else:
        lines.append(
            f"Recommended: {a.recommended_path} = the {a.reference} bundle: no other bundle won a row on the press "
            "without a row where it is, or may be, worse."
        )
    for cause, why in rec.reasons.items():
        lines.append(f"  {cause}: {why}")
    return "\n".join(lines)


__all__ += ["format_adoption"]
