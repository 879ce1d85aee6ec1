"""Fit stages: runs read, identified, and written as bundle sections (hysteresis, creep, shaper).

Every fit is :mod:`piezopress.analysis.identification`'s (``fit`` and ``fit --base`` call its
one entry point, :func:`~piezopress.analysis.identification.identify`); this module reads the
runs, hands them over, and adds to each section its provenance: the run files it came from
(sha256), the digest of its inputs (``--if-changed``), the software version and the time.
The single-section stages (``fit-hysteresis``, ``fit-creep``, ``fit-shaper``, ``make refit``)
call the same section functions one at a time.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from piezopress import runformat
from piezopress.analysis import creep as creep_mod
from piezopress.analysis import identification as ident
from piezopress.analysis.bundle import Bundle
from piezopress.analysis.identification import (  # noqa: F401  (the pipeline's names for them)
    CREEP_FALLBACK_FORM,
    FORCE_MAX_RATE_N_PER_S,
    LOW_STEP_FRACTION,
    STATIC_MAX_FREQ_HZ,
    THESIS_CREEP_FORMS,
    THESIS_GRID,
    compensation_settings,
    fitted_rows,
)
from piezopress.pipelines import profiles
from piezopress.pipelines.bundle import assemble, collect_runs, inputs_digest, section


def hysteresis_runs(runs: list[runformat.Run], named: bool) -> list[runformat.Run]:
    """The quasi-static sweeps among ``runs`` (:func:`~piezopress.analysis.identification.quasi_static_sweeps`),
    the choice of the slowest said on stderr."""
    return ident.quasi_static_sweeps(runs, named, note=profiles.note)


def select_hysteresis_runs(paths: Iterable[str | Path], names: Iterable[str] = ()) -> list[runformat.Run]:
    names = list(names)
    return hysteresis_runs(collect_runs(paths, names=names), bool(names))


def select_creep_run(paths: Iterable[str | Path], names: Iterable[str] = ()) -> runformat.Run:
    names = list(names)
    return ident.creep_run(collect_runs(paths, names=names), bool(names))


def select_shaper_runs(paths: Iterable[str | Path], names: Iterable[str] = ()) -> list[runformat.Run]:
    names = list(names)
    return ident.shaper_runs(collect_runs(paths, names=names), bool(names))


def structure_grid(structure: str | None) -> list | None:
    """The hysteresis structures ``fit-hysteresis --structure`` fits (one; ``None``: the search's),
    read from the label fit prints (:func:`~piezopress.analysis.identification.parse_structure`)."""
    return None if structure is None else [ident.parse_structure(structure)]


def hysteresis_digest(runs, creep, holdout_fraction, grid=None, skip_s=None, rows=None) -> str:
    extra = {} if skip_s is None and rows is None else {"skip_s": skip_s, "rows": rows}
    return inputs_digest(
        "hysteresis",
        runs,
        [creep],
        holdout_fraction=holdout_fraction,
        grid=None if grid is None else [c.label for c in grid],
        **extra,
    )


def creep_digest(run, hysteresis, holdout_fraction, forms=creep_mod.FORMS) -> str:
    return inputs_digest("creep", [run], [hysteresis], holdout_fraction=holdout_fraction, forms=list(forms))


def shaper_digest(runs, fs_hz) -> str:
    return inputs_digest("shaper", runs, [], fs_hz=fs_hz)


def fit_hysteresis_section(
    paths: Iterable[str | Path],
    *,
    names: Iterable[str] = (),
    holdout_fraction: float = 0.3,
    grid=None,
    creep: dict[str, Any] | None = None,
    skip_s: float | None = None,
    rows: tuple[int | None, int | None] | None = None,
):
    """``fit-hysteresis``: :func:`~piezopress.analysis.identification.hysteresis_section` on
    the quasi-static sweeps among ``paths`` (or those named), with a ``creep`` section's
    model removed first; returns the section and the fit."""
    runs = select_hysteresis_runs(paths, names)
    cm = creep_mod.CreepModel.from_dict(creep["model"]) if creep is not None else None
    body, fit = ident.hysteresis_section(
        runs, holdout_fraction=holdout_fraction, grid=grid, creep=cm, skip_s=skip_s, rows=rows
    )
    if grid is not None and len(grid) == 1:  # one structure given (--structure): the bundle says so
        body["fit"]["structure_given"] = ident.given_structure(grid[0])
    digest = hysteresis_digest(runs, creep, holdout_fraction, grid, skip_s=skip_s, rows=rows)
    return section("hysteresis", body, runs, digest), fit


def fit_creep_section(
    paths: Iterable[str | Path],
    hysteresis: dict[str, Any],
    *,
    names: Iterable[str] = (),
    holdout_fraction: float = 0.3,
    forms: tuple[str, ...] = creep_mod.FORMS,
):
    """``fit-creep``: :func:`~piezopress.analysis.identification.creep_section` on the longest
    held step among ``paths`` (or the one named), given the ``hysteresis`` section."""
    run = select_creep_run(paths, names)
    body, fit = ident.creep_section(run, hysteresis, holdout_fraction=holdout_fraction, forms=forms)
    return section("creep", body, [run], creep_digest(run, hysteresis, holdout_fraction, forms)), fit


def fit_shaper_section(paths: Iterable[str | Path], *, names: Iterable[str] = (), fs_hz: float | None = None):
    """``fit-shaper``: :func:`~piezopress.analysis.identification.shaper_section` on the
    low-amplitude steps among ``paths`` (or those named), the drive chain told apart on every step."""
    names = list(names)
    given = collect_runs(paths, names=names)
    runs = ident.shaper_runs(given, bool(names))
    steps = [r for r in given if ident.kind_of(r) == "step"] if not names else runs
    body, fit = ident.shaper_section(runs, steps, fs_hz=fs_hz)
    return section("shaper", body, runs, shaper_digest(runs, fs_hz)), fit


# --------------------------------------------------------------------------- every stage the runs allow


@dataclass
class FitAll:
    """What ``fit`` made of the runs: the sections it could fit (with their provenance) and
    their fits, and for every other section why it could not be fitted."""

    sections: dict[str, dict[str, Any]]
    fits: dict[str, Any]
    not_fitted: dict[str, str]
    unit: str
    drive_v: tuple[float, float]


def fit_all(
    paths: Iterable[str | Path],
    *,
    base: bool = False,
    skip_s: float | None = None,
    rows: tuple[int | None, int | None] | None = None,
    on_stage: Callable[[str], None] | None = None,
    shaper: bool = True,
    structure: str | None = None,
) -> FitAll:
    """Read the runs under ``paths`` and fit every section they allow
    (:func:`piezopress.analysis.identification.identify`; ``structure``: the hysteresis structure
    to fit instead of searching for one); each section gets the runs it came from and the digest of
    its inputs. ``on_stage`` is told each stage's name (progress)."""
    if structure is not None:
        ident.parse_structure(structure)  # a structure that cannot be read is said before the runs are read
    runs = collect_runs(paths)
    found = ident.identify(
        runs,
        base=base,
        skip_s=skip_s,
        rows=rows,
        shaper=shaper,
        structure=structure,
        on_stage=on_stage,
        note=profiles.note,
    )
    sections = {
        kind: section(kind, body, found.used[kind], inputs_digest(kind, found.used[kind], [], **found.settings[kind]))
        for kind, body in found.sections.items()
    }
    return FitAll(sections, found.fits, found.not_fitted, found.unit, found.drive_v)


@dataclass
class FittedBundle:
    """A bundle fitted from runs: the document (checked: :class:`~piezopress.analysis.bundle.Bundle`)
    and what :func:`fit_all` made of the runs."""

    doc: dict[str, Any]
    result: FitAll

    @property
    def bundle(self) -> Bundle:
        return Bundle.from_dict(self.doc, "the fitted bundle")


def runs_from_elsewhere(res: FitAll) -> bool:
    """True when every run the hysteresis was fitted on names no press (imported, another program's)."""
    runs = (res.sections.get("hysteresis") or {}).get("runs") or []
    return bool(runs) and all(isinstance(r, dict) and r.get("rig", 0) is None for r in runs)


def fit_bundle(
    runs: Iterable[str | Path],
    limits: Any = None,
    *,
    base: bool = False,
    shaper: bool = True,
    skip_s: float | None = None,
    rows: tuple[int | None, int | None] | None = None,
    max_rate_per_s: float | None = None,
    on_stage: Callable[[str], None] | None = None,
    record_range: Any = None,
    structure: str | None = None,
) -> FittedBundle:
    """``piezopress fit``: every stage the runs allow (:func:`fit_all`), assembled with the
    compensation settings into a bundle, which is checked as any bundle read from a file.

    ``limits``: the rig's drive range (``drive_min_v``, ``drive_max_v``; e.g.
    :func:`piezopress.pipelines.characterize.rig_limits`), ``None``: 0 to 150 V. With
    ``record_range`` (limits to fall back on) and no ``limits``, runs from elsewhere (no press
    recorded) give the range the record drove, and our own runs ``record_range``. ``shaper=False``
    leaves the shaper section out (a model of the press's static and slow behaviour only);
    ``structure``: the hysteresis structure to fit (:func:`~piezopress.analysis.identification.parse_structure`).
    """
    res = fit_all(runs, base=base, skip_s=skip_s, rows=rows, on_stage=on_stage, shaper=shaper, structure=structure)
    if record_range is not None and runs_from_elsewhere(res):
        # no rig named, runs from elsewhere: the actuator's range is the one the record drove
        limits = None
        drive = {"drive_min_v": float(res.drive_v[0]), "drive_max_v": float(res.drive_v[1])}
    else:
        limits = record_range if limits is None and record_range is not None else limits
        drive = (
            {}
            if limits is None
            else {"drive_min_v": float(limits.drive_min_v), "drive_max_v": float(limits.drive_max_v)}
        )
    doc = assemble(res.sections, compensation_settings(res.sections, max_rate_per_s=max_rate_per_s, **drive))
    Bundle.from_dict(doc, "the fitted bundle")  # a bundle that would not be read back is never written
    return FittedBundle(doc, res)
