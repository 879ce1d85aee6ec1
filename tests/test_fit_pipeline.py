"""Fit stages, bundle files and `compensate`: selection of runs, errors, no silent overwrite."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from piezopress.analysis.compensation import Compensator
from piezopress.analysis.hysteresis import PIModel
from piezopress.piezocli.main import cli
from piezopress.pipelines import characterize as char

PLAN = """
[plan]
name = "small"
[[protocol]]
name = "tri"
kind = "triangle"
freq_hz = 0.5
peaks_v = [60.0, 150.0, 100.0]
sample_rate_hz = 500.0
[[protocol]]
name = "creep"
kind = "creep"
level_v = 150.0
pre_s = 1.0
hold_s = 30.0
sample_rate_hz = 200.0
[[protocol]]
name = "step-20v"
kind = "step"
level_v = 20.0
pre_s = 0.02
hold_s = 0.05
post_s = 0.01
sample_rate_hz = 20000.0
[[protocol]]
name = "step-150v"
kind = "step"
level_v = 150.0
pre_s = 0.02
hold_s = 0.05
sample_rate_hz = 20000.0
"""


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("fit")
    (tmp / "plan.toml").write_text(PLAN)
    char.characterize(tmp / "char", plan_path=tmp / "plan.toml")
    return tmp


def invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def test_stages_pick_their_runs_and_record_provenance(runs, tmp_path):
    res = invoke("fit-hysteresis", runs / "char", "--out", tmp_path / "h.json")
    assert res.exit_code == 0, res.output
    h = json.loads((tmp_path / "h.json").read_text())
    assert [r["name"] for r in h["runs"]] == ["tri"]  # only the quasi-static sweep
    assert h["model"]["output_unit"] == "N" and h["fit"]["holdout_rms_pct_of_range"] < 1.0
    res = invoke("fit-creep", runs / "char", "--hysteresis", tmp_path / "h.json", "--out", tmp_path / "c.json")
    assert res.exit_code == 0, res.output
    assert [r["name"] for r in json.loads((tmp_path / "c.json").read_text())["runs"]] == ["creep"]
    res = invoke("fit-shaper", runs / "char", "--out", tmp_path / "s.json")
    assert res.exit_code == 0, res.output
    s = json.loads((tmp_path / "s.json").read_text())
    assert [r["name"] for r in s["runs"]] == ["step-20v"]  # the low-amplitude step only
    assert s["mode"]["drive_used"] == "monitor_v"
    res = invoke(
        "bundle",
        "--hysteresis",
        tmp_path / "h.json",
        "--creep",
        tmp_path / "c.json",
        "--shaper",
        tmp_path / "s.json",
        "--out",
        tmp_path / "b.json",
    )
    assert res.exit_code == 0, res.output
    b = json.loads((tmp_path / "b.json").read_text())
    assert b["compensation"]["drive_min_v"] == -30.0 and b["compensation"]["lead_s"] > 0


def test_outputs_are_never_overwritten_silently(runs, tmp_path):
    out = tmp_path / "h.json"
    out.write_text("precious")
    res = invoke("fit-hysteresis", runs / "char", "--out", out)
    assert res.exit_code == 1 and "already exists" in res.output and out.read_text() == "precious"
    res = invoke("fit-hysteresis", runs / "char", "--out", out, "--replace")
    assert res.exit_code == 0 and "previous version kept as" in res.output
    kept = list(tmp_path.glob("h.json.replaced-*"))
    assert [k.read_text() for k in kept] == ["precious"] and str(kept[0]) in res.output  # the line names where


def test_clear_errors_for_unsuitable_runs(runs, tmp_path):
    res = invoke(
        "fit-creep",
        runs / "char" / "tri.parquet",
        "--hysteresis",
        tmp_path / "missing.json",
        "--out",
        tmp_path / "c.json",
    )
    assert res.exit_code == 1 and "missing.json: no such file" in res.output
    res = invoke("fit-hysteresis", runs / "char" / "step-20v.parquet", "--out", tmp_path / "h.json")
    assert res.exit_code == 1 and "no quasi-static sweep" in res.output and "Traceback" not in res.output
    res = invoke("fit-hysteresis", runs / "char", "--run", "nope", "--out", tmp_path / "h.json")
    assert res.exit_code == 1 and "no run named nope" in res.output


def test_compensate_writes_the_drive_and_warns_when_unreachable(runs, tmp_path):
    assert invoke("fit", runs / "char", "--out", tmp_path / "b.json").exit_code == 0
    t = np.arange(2000) / 1000.0
    pd.DataFrame({"t_s": t, "reference_n": np.minimum(t * 200.0, 100.0)}).to_csv(tmp_path / "ref.csv", index=False)
    res = invoke(
        "compensate",
        "--bundle",
        tmp_path / "b.json",
        "--reference",
        tmp_path / "ref.csv",
        "--out",
        tmp_path / "drive.csv",
    )
    assert res.exit_code == 0, res.output
    drive = pd.read_csv(tmp_path / "drive.csv")
    assert list(drive.columns) == ["t_s", "reference_n", "command_v"] and drive.command_v.iloc[-1] == pytest.approx(
        50.0, abs=8
    )
    pd.DataFrame({"t_s": t, "reference_n": np.full(t.size, 2000.0)}).to_csv(tmp_path / "big.csv", index=False)
    res = invoke(
        "compensate", "--bundle", tmp_path / "b.json", "--reference", tmp_path / "big.csv", "--out", tmp_path / "d2.csv"
    )
    assert res.exit_code == 1 and "cannot be reached" in res.output and "--allow-clip" in res.output
    assert not (tmp_path / "d2.csv").exists()
    res = invoke(
        "compensate",
        "--bundle",
        tmp_path / "b.json",
        "--reference",
        tmp_path / "big.csv",
        "--out",
        tmp_path / "d2.csv",
        "--allow-clip",
    )
    assert res.exit_code == 0 and "cannot be reached" in res.output
    assert pd.read_csv(tmp_path / "d2.csv").command_v.max() <= 150.0
    pd.DataFrame({"time": t}).to_csv(tmp_path / "bad.csv", index=False)
    res = invoke(
        "compensate", "--bundle", tmp_path / "b.json", "--reference", tmp_path / "bad.csv", "--out", tmp_path / "d3.csv"
    )
    assert res.exit_code == 1 and "missing column t_s, reference_n" in res.output


def test_compensator_output_reproduces_the_reference_through_its_own_model():
    # Property: with only the hysteresis stage, model(drive) == reference wherever the
    # drive is within range (the inverse is exact; clipping is the only departure).
    model = PIModel((0.0, 5.0, 20.0), (0.7, 0.2, 0.1), (0.0, 100.0), (2.0, -0.3), y0=50.0)
    comp = Compensator(model, drive_min_v=-30.0, drive_max_v=150.0)
    ref = 120 * (1 - np.cos(np.linspace(0, 6 * np.pi, 3000))) / 2
    res = comp.drive(ref, 1000.0)
    y, _ = model.forward(res.command_v)
    assert res.clipped_samples == 0
    np.testing.assert_allclose(y - 50.0, ref, atol=1e-9)


def test_if_changed_skips_unchanged_inputs_and_refits_changed_ones(runs, tmp_path):
    out = tmp_path / "s.json"
    assert invoke("fit-shaper", runs / "char", "--out", out, "--if-changed").exit_code == 0
    first = out.read_text()
    res = invoke("fit-shaper", runs / "char", "--out", out, "--if-changed")
    assert res.exit_code == 0 and "up to date" in res.output and out.read_text() == first
    # changed inputs (an option counts): the stage runs again, keeping the previous result
    h = tmp_path / "h.json"
    assert invoke("fit-hysteresis", runs / "char", "--out", h, "--if-changed").exit_code == 0
    assert "up to date" in invoke("fit-hysteresis", runs / "char", "--out", h, "--if-changed").output
    res = invoke("fit-hysteresis", runs / "char", "--out", h, "--if-changed", "--holdout-fraction", "0.4")
    assert res.exit_code == 0 and "previous version kept" in res.output
    assert json.loads(h.read_text())["fit"]["holdout_fraction"] == 0.4


# --------------------------------------------------------------------------- command-line checks before work (issue 12)


def test_fit_refuses_an_existing_output_before_fitting(tmp_path, monkeypatch):
    from click.testing import CliRunner

    from piezopress.piezocli.main import cli
    from piezopress.pipelines import fit as fit_mod

    (tmp_path / "bundle.json").write_text("{}")
    monkeypatch.setattr(fit_mod, "fit_all", lambda *a, **k: pytest.fail("fitted although the output exists"))
    res = CliRunner().invoke(cli, ["fit", str(tmp_path), "--out", str(tmp_path / "bundle.json")])
    assert res.exit_code != 0 and "already exists" in res.output
    assert (tmp_path / "bundle.json").read_text() == "{}"


def test_fit_reads_the_drive_range_of_a_hardware_rig_file_without_its_driver():
    from piezopress.pipelines import characterize as char

    lim = char.rig_limits(Path(__file__).resolve().parents[1] / "rigs" / "nidaq-example.toml")
    assert lim.drive_min_v < lim.drive_max_v and lim.max_sample_rate_hz > 0
