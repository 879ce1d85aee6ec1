"""Issue 19: identification is one analysis entry point.

``fit`` and ``fit --base`` call :func:`piezopress.analysis.identification.identify` (runs in,
sections and a :class:`~piezopress.analysis.bundle.Bundle` out); ``pipelines/fit.py`` only
reads runs and writes sections with their provenance. The runs handed over here are read
in memory with their metadata cut to the run format's four required fields and every kind
``custom``: the entry point must decide which run informs which section from the signals.
"""

from __future__ import annotations

import ast
import shutil
from pathlib import Path

import numpy as np
import pytest

from piezopress import runformat
from piezopress.analysis import identification as ident
from piezopress.analysis.bundle import Bundle, BundleError
from tests.foreign import foreign_run

ROOT = Path(__file__).resolve().parents[1]
CHAR = ROOT / "sample_runs" / "characterization"
SUBSET = ("triangle-0.1hz", "triangle-10hz", "creep-150v", "step-20v", "step-150v")


@pytest.fixture(scope="module")
def foreign_runs():
    return [foreign_run(runformat.read_run(CHAR / f"{n}.parquet"), custom=True) for n in SUBSET]


@pytest.fixture(scope="module")
def identified(foreign_runs):
    stages = []
    found = ident.identify(foreign_runs, on_stage=stages.append)
    return found, stages


@pytest.mark.integration
def test_each_section_is_informed_by_the_runs_its_signals_suit(identified):
    found, stages = identified
    assert set(found.sections) == {"hysteresis", "creep", "shaper"} and not found.not_fitted
    names = {k: [r.name for r in v] for k, v in found.used.items()}
    assert names == {
        "hysteresis": ["triangle-0.1hz"],  # the 10 Hz triangle is no quasi-static sweep
        "creep": ["creep-150v"],
        "shaper": ["step-20v"],  # only the low-amplitude step (<= 25 % of the largest drive)
    }
    assert len(stages) == 2 and all(isinstance(s, str) and s for s in stages)  # progress told per stage
    assert found.drive_v[0] == pytest.approx(0.0, abs=1.0) and found.drive_v[1] == pytest.approx(150.0, abs=1.0)


@pytest.mark.integration
def test_the_entry_point_returns_a_checked_bundle_that_compensates(identified):
    found, _ = identified
    bundle = found.bundle()
    assert isinstance(bundle, Bundle) and bundle.unit == "N"
    assert bundle.creep is not None and bundle.shaper is not None
    # the model it holds inverts: the forward model of the drive for a slow reference returns the reference
    t = np.arange(0, 10, 1e-3)
    ref = 50.0 + 60.0 * (1 - np.cos(2 * np.pi * 0.2 * t))
    drive = bundle.hysteresis.inverse(ref)[0]
    back = bundle.hysteresis.forward(drive)[0]
    assert np.max(np.abs(back - ref)) < 0.05  # N, on a 120 N swing


@pytest.mark.integration
def test_the_pipeline_writes_the_sections_the_entry_point_fits(tmp_path, identified):
    """`fit` (pipelines.fit.fit_all) adds provenance only: its models are the entry point's."""
    from piezopress.pipelines import fit as F

    found, _ = identified
    runs = tmp_path / "runs"
    runs.mkdir()
    for n in SUBSET:
        shutil.copy(CHAR / f"{n}.parquet", runs / f"{n}.parquet")
    res = F.fit_all([runs])
    for kind, body in found.sections.items():
        sec = res.sections[kind]
        assert sec["model" if kind != "shaper" else "shaper"] == body["model" if kind != "shaper" else "shaper"], kind
        assert [r["name"] for r in sec["runs"]] == [r.name for r in found.used[kind]], kind
        assert sec["inputs_digest"] and sec["fitted_utc"]


def test_no_sweep_among_the_runs_is_refused_naming_each_run(foreign_runs):
    steps = [r for r in foreign_runs if r.name.startswith("step")]
    with pytest.raises(BundleError, match=r"no quasi-static sweep.*step-150v \(step from 0 to 150.*step-20v \(step"):
        ident.identify(steps)


def test_a_section_left_out_is_said_with_the_reason(foreign_runs):
    sweep = [r for r in foreign_runs if r.name == "triangle-0.1hz"]
    found = ident.identify(sweep, shaper=False)
    assert set(found.sections) <= {"hysteresis", "creep"}
    assert "left out" in found.not_fitted["shaper"]
    if "creep" not in found.sections:  # no held step: creep from the sweep only when it predicts better
        assert "no creep run" in found.not_fitted["creep"] and "from the sweeps" in found.not_fitted["creep"]


def test_the_fit_pipeline_does_no_signal_processing():
    """Imports go one way and math stays apart from I/O: pipelines/fit.py imports no numerical library."""
    tree = ast.parse((ROOT / "pipelines" / "fit.py").read_text(encoding="utf-8"))
    mods = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    mods |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    assert not {m for m in mods if m.split(".")[0] in ("numpy", "scipy", "cvxpy", "control", "pandas")}, mods
