"""``--json`` on inspect, fit and validate: one machine-readable document on stdout (issue 12)."""

import json
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from piezopress import runformat as rf
from piezopress.piezocli.main import cli

ROOT = Path(__file__).resolve().parents[1]


def _runner():
    try:
        return CliRunner(mix_stderr=False)
    except TypeError:  # click >= 8.2 keeps stderr apart already
        return CliRunner()


def _sweep(path: Path) -> None:
    fs = 100.0
    t = np.arange(1500) / fs
    x = 50 + 50 * np.sin(2 * np.pi * 0.5 * t - np.pi / 2)
    y = 2.0 * x + 3.0 * np.sin(2 * np.pi * 0.5 * t)  # a loop
    rf.write_run(rf.make_run({"t_s": t, "command_v": x, "force_n": y}, rf.make_meta("sine", "sweep", fs)), path)


def test_inspect_json_is_one_document_with_every_column(tmp_path):
    _sweep(tmp_path / "a.parquet")
    res = _runner().invoke(cli, ["inspect", str(tmp_path), "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    (run,) = doc["runs"]
    assert run["name"] == "sweep" and run["samples"] == 1500 and run["sample_rate_hz"] == 100.0
    assert set(run["columns"]) == {"t_s", "command_v", "force_n"} and doc["bad"] == 0


def test_fit_json_says_what_was_fitted_and_what_not_and_reports_stages(tmp_path):
    _sweep(tmp_path / "a.parquet")
    res = _runner().invoke(cli, ["fit", str(tmp_path / "a.parquet"), "--out", str(tmp_path / "b.json"), "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert doc["sections"][0] == "hysteresis" and doc["output_unit"] == "N"
    assert "shaper" in doc["not_fitted"] and doc["hysteresis"]["holdout_rms"] >= 0
    assert "fitting hysteresis" in res.stderr  # progress: each stage named before it runs
    assert Path(doc["bundle"]) == tmp_path / "b.json" and (tmp_path / "b.json").is_file()


def test_validate_json_holds_the_table_rows(tmp_path):
    res = _runner().invoke(
        cli, ["validate", "--bundle", str(ROOT / "sample_runs" / "bundle.json"), "--out", str(tmp_path / "v"), "--json"]
    )
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    metrics = {(r["run"], r["metric"]) for r in doc["rows"]}
    assert ("tri-300n-0.1hz", "max_hysteresis") in metrics and ("step-100n", "overshoot") in metrics
    assert len(doc["runs"]) >= 16
