"""Issue 4 acceptance, end to end on the default (thesis-like) virtual rig, and on real data.

characterize -> fit (hysteresis, creep, shaper) -> validate, then every figure the issue
asks for is checked against its bound. One module-scoped pipeline run (~10 s) serves all.
"""

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from piezopress import runformat as rf
from piezopress.analysis import hysteresis as H
from piezopress.piezocli.main import cli
from piezopress.pipelines import summary

ROOT = Path(__file__).resolve().parents[1]
from conftest import DATASETS, needs_datasets  # noqa: E402

pytestmark = pytest.mark.integration


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("accept")
    runner = CliRunner()
    for args in (
        ["characterize", "--out", str(tmp / "char")],
        ["fit", str(tmp / "char"), "--out", str(tmp / "bundle.json")],
        ["validate", "--bundle", str(tmp / "bundle.json"), "--out", str(tmp / "val")],
    ):
        res = runner.invoke(cli, args)
        assert res.exit_code == 0, res.output
    table = summary.validation_table(tmp / "val")
    return tmp, {(r.run, r.metric): r.value for r in table.itertuples()}


@pytest.mark.parametrize(
    "run", ["tri-150n-0.1hz", "tri-225n-0.1hz", "tri-300n-0.1hz", "tri-increasing-0.1hz", "tri-random-0.1hz"]
)
def test_static_hysteresis_at_most_1_percent(pipeline, run):
    assert pipeline[1][(run, "max_hysteresis")] <= 1.0  # thesis Table 6.6: 1.33 to 2.99 %


def test_static_hysteresis_75n_at_most_1_5_percent(pipeline):
    # 0.5 N quantization weighs most on the smallest loop
    assert pipeline[1][("tri-75n-0.1hz", "max_hysteresis")] <= 1.5  # thesis: 1.55 %


def test_creep_after_120_s_at_most_0_3_percent(pipeline):
    assert abs(pipeline[1][("creep-300n", "creep")]) <= 0.3  # thesis: 0.63 to 0.96 %


@pytest.mark.parametrize("level", [30, 100, 150, 200])
def test_overshoot_at_most_3_percent(pipeline, level):
    assert pipeline[1][(f"step-{level}n", "overshoot")] <= 3.0  # thesis Table 6.9: 0 to 9.28 %


def test_staircase_tracking(pipeline):
    assert pipeline[1][("staircase-10n", "tracking_relative")] <= 3.0  # thesis: 12.08 %
    assert pipeline[1][("staircase-10n", "tracking_absolute")] <= 1.5  # thesis: 22.76 N


def test_50_hz_hysteresis_with_compensation_at_most_6_percent(pipeline):
    assert pipeline[1][("tri-300n-50hz", "max_hysteresis")] <= 6.0  # thesis: 59.95 % with its shaper


def test_validation_runs_carry_the_reference_and_the_bundle(pipeline):
    tmp, _ = pipeline
    manifest = json.loads((tmp / "val" / "manifest.json").read_text())
    assert manifest["kind"] == "validation" and manifest["status"] == "complete"
    assert manifest["bundle"]["sha256"] == rf.sha256_file(tmp / "bundle.json")
    run = rf.read_run(tmp / "val" / "step-100n.parquet")
    ref = run.column("reference_n")
    assert ref is not None and ref.max() == pytest.approx(150.0) and ref.min() == pytest.approx(50.0)


def test_bundle_is_readable_with_units_and_provenance(pipeline):
    tmp, _ = pipeline
    b = json.loads((tmp / "bundle.json").read_text())
    assert b["bundle_version"] == 1 and b["software_version"]
    assert {"hysteresis", "creep", "shaper", "compensation"} <= set(b)
    assert all(r["sha256"] for s in ("hysteresis", "creep", "shaper") for r in b[s]["runs"])
    assert b["creep"]["fit"]["chosen_form"] == "log"  # the rig creeps in log time
    assert "natural_freq_rad_s" in b["shaper"]["mode"] and "holdout_rms_pct_of_range" in b["hysteresis"]["fit"]
    assert b["shaper"]["thesis_table_6_8"]["printed"] > 0.1  # the thesis's printed shaper leaves > 10 %


# ------------------------------------------------------------------ real data


def _import(tmp, args):
    res = CliRunner().invoke(cli, ["import", *args])
    assert res.exit_code == 0, res.output


@needs_datasets("smarthysteresis")
def test_smarthysteresis_fitted_on_first_5_s_predicts_last_5_s_within_1_percent(tmp_path):
    out = tmp_path / "smart.parquet"
    _import(
        tmp_path,
        [
            str(DATASETS / "smarthysteresis" / "hysteresis_v_150_1hz.csv"),
            "--out",
            str(out),
            "--no-header",
            "--kind",
            "sine",
            "--col",
            "t_s=2",
            "--col",
            "displacement_um=3",
            "--col",
            "command_v=4",
            "--sample-rate",
            "5000",
        ],
    )
    run = rf.read_run(out)
    data = H.prepare([(run.name, run.command_v, run.output)], holdout_fraction=0.5)  # train: 0-5 s, test: 5-10 s
    fit = H.fit_hysteresis(data, refit_all=False)
    assert fit.holdout_rms_pct <= 1.0  # a straight line scores about 5.4 %
    x, y = run.command_v, run.output
    line = np.polyval(np.polyfit(x[: x.size // 2], y[: x.size // 2], 1), x[x.size // 2 :]) - y[x.size // 2 :]
    assert 100 * np.sqrt(np.mean(line**2)) / fit.output_range > 5.0  # the baseline really is that bad


@needs_datasets("aye-ang-2018")
def test_aye_ang_data_fits_far_better_than_a_line(tmp_path):
    out = tmp_path / "aye.parquet"
    _import(
        tmp_path,
        [
            str(DATASETS / "aye-ang-2018" / "Model_Vi_Do.dat"),
            "--out",
            str(out),
            "--no-header",
            "--delimiter",
            "tab",
            "--kind",
            "sine",
            "--col",
            "command_v=1",
            "--col",
            "displacement_um=5",
            "--lag",
            "displacement_um=1",
            "--sample-rate",
            "200",
        ],
    )
    res = CliRunner().invoke(cli, ["fit-hysteresis", str(out), "--out", str(tmp_path / "h.json")])
    assert res.exit_code == 0, res.output
    fit = json.loads((tmp_path / "h.json").read_text())["fit"]
    # the sensor starts with a settling transient and lags 4-7 samples (dynamics a static
    # model cannot hold); a straight line leaves 6.2 % of the range
    assert fit["holdout_rms_pct_of_range"] < 2.5
