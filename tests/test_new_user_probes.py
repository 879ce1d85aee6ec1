"""Issue 12's "tried as a new user would" probes not covered elsewhere: each gives one clear
line or works (the others: rig-keys and seed = -1 in test_plan.py, inspect DIR in
test_import.py, fit --rig nidaq-example.toml in test_fit_pipeline.py, --replace in
test_replace.py, the wheel in test_wheel.py, start-up in test_architecture.py)."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from piezopress.piezocli.main import cli

ROOT = Path(__file__).resolve().parents[1]
BUNDLE = ROOT / "sample_runs" / "bundle.json"
STEP = ROOT / "sample_runs" / "characterization" / "step-20v.parquet"


def invoke(*args):
    res = CliRunner().invoke(cli, [str(a) for a in args])
    assert res.exception is None or isinstance(res.exception, SystemExit), repr(res.exception)
    return res.exit_code, res.output


def test_an_unknown_cause_is_one_line_naming_the_known_ones(tmp_path):
    code, out = invoke("diagnose", STEP, "--bundle", BUNDLE, "--cause", "foo", "--out", tmp_path / "d")
    errors = [ln for ln in out.splitlines() if ln.startswith("Error:")]
    assert code == 2 and len(errors) == 1 and "'foo' is not one of" in errors[0] and "input_delay" in errors[0]
    assert not (tmp_path / "d").exists()


def test_diagnose_refuses_an_existing_out_before_any_work(tmp_path, monkeypatch):
    from piezopress.pipelines import diagnose as D

    monkeypatch.setattr(D.dg, "diagnose", lambda *a, **k: pytest.fail("diagnosed although the output exists"))
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "diagnosis.json").write_text("{}")
    code, out = invoke("diagnose", STEP, "--bundle", BUNDLE, "--out", tmp_path / "d")
    assert code == 1 and out.startswith("Error: ") and "already exists and is not empty" in out


def test_simulate_prints_its_figures_with_units(tmp_path):
    """Issue 12: "residual 281 max, 21.9 RMS" had no unit."""
    code, out = invoke("simulate", STEP, "--bundle", BUNDLE, "--out", tmp_path / "sim.parquet")
    assert code == 0, out
    assert " N max, " in out and " N RMS (force_n)" in out
