"""Issue 22: a lab's own record, end to end, in the record's own terms: import -> fit (the drive
range the record drove, the rest and the reach printed) -> compensate (a reference on the
record's scale) -> simulate the drive -> the predicted output follows the reference within the
model's held-out error. The same on our own force bundle (references above the rest)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner
from conftest import import_args, needs_datasets

from piezopress.piezocli.main import cli

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[1]
BUNDLE = ROOT / "sample_runs" / "bundle.json"
CHAR_SWEEP = ROOT / "sample_runs" / "characterization" / "triangle-0.1hz.parquet"
SMART = "smarthysteresis/hysteresis_v_150_1hz.csv"
AYE_MODEL = "aye-ang-2018/Model_Vi_Do.dat"


def invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def _triangle(path: Path, column: str, lo: float, hi: float, fs: float, freq: float = 0.1, cycles: int = 2) -> Path:
    t = np.arange(0, cycles / freq, 1 / fs)
    ph = (t * freq) % 1.0
    tri = np.where(ph < 0.5, 2 * ph, 2 - 2 * ph)  # 0 -> 1 -> 0
    pd.DataFrame({"t_s": t, column: lo + (hi - lo) * tri}).to_csv(path, index=False)
    return path


def _chain(tmp_path: Path, run: Path, ref: Path) -> tuple[dict, pd.DataFrame, str]:
    bundle = tmp_path / "b.json"
    res = invoke("fit", run, "--out", bundle)
    assert res.exit_code == 0, res.output
    fit_out = res.output
    drive = tmp_path / "drive.csv"
    res = invoke("compensate", "--bundle", bundle, "--reference", ref, "--out", drive)
    assert res.exit_code == 0, res.output
    assert "Warning" not in res.output  # nothing clipped
    pred = tmp_path / "pred.csv"
    res = invoke("simulate", drive, "--bundle", bundle, "--out", pred)
    assert res.exit_code == 0, res.output
    return json.loads(bundle.read_text()), pd.read_csv(pred), fit_out + res.output


@needs_datasets(SMART)
def test_smarthysteresis_record_to_a_checked_drive_on_its_own_scale(tmp_path):
    run = tmp_path / "smart.parquet"
    res = invoke(*import_args("smart", run))
    assert res.exit_code == 0, res.output
    ref = _triangle(tmp_path / "ref.csv", "reference_um", -15.0, 15.0, 5000.0)  # inside the record's -19.7..19.7
    doc, pred, out = _chain(tmp_path, run, ref)
    # the drive range is the record's (it drove -150..150 V), not the default rig's -30..150 V
    assert doc["compensation"]["drive_min_v"] == pytest.approx(-150, abs=0.5)
    assert "the range the record drove" in out and "the model's rest output is" in out
    held = doc["hysteresis"]["fit"]["holdout_rms_um"]
    assert "rest_um" in pred.columns  # the absolute zero, written beside the reference
    err = pred["predicted_um"] - pred["reference_um"]
    assert float(np.sqrt(np.mean(err**2))) <= held
    assert pred["predicted_um"].min() == pytest.approx(-15.0, abs=3 * held)


@needs_datasets(AYE_MODEL)
def test_aye_ang_record_to_a_checked_drive(tmp_path):
    run = tmp_path / "aye.parquet"
    res = invoke(*import_args("aye", run))
    assert res.exit_code == 0, res.output
    rec = pd.read_parquet(run)["displacement_um"]
    lo, hi = np.quantile(rec, [0.2, 0.8])  # well inside the record's range
    ref = _triangle(tmp_path / "ref.csv", "reference_um", float(lo), float(hi), 200.0)
    doc, pred, _ = _chain(tmp_path, run, ref)
    held = doc["hysteresis"]["fit"]["holdout_rms_um"]
    err = pred["predicted_um"] - pred["reference_um"]
    assert float(np.sqrt(np.mean(err**2))) <= held


def test_a_european_labview_export_to_a_checked_drive(tmp_path):
    """Decimal commas, semicolons, a BOM, CRLF and units in the header: a sine through a
    known hysteretic model (the project's own forward model, so the truth is known)."""
    from piezopress.pipelines.bundle import read_bundle

    model = read_bundle(ROOT / "sample_runs" / "base-bundle.json").hysteresis
    fs = 1000.0
    t = np.arange(0, 20, 1 / fs)
    x = 75 - 75 * np.cos(2 * np.pi * 0.2 * t) * np.minimum(1, t / 2)
    y, _ = model.forward(x)
    y = y + np.random.default_rng(0).normal(0, 0.05, y.size)
    lines = ["Zeit [s];Spannung [V];Kraft [N]"] + [
        f"{a:.4f};{b:.4f};{c:.4f}".replace(".", ",") for a, b, c in zip(t, x, y)
    ]
    src = tmp_path / "labview.csv"
    src.write_bytes(b"\xef\xbb\xbf" + "\r\n".join(lines).encode() + b"\r\n")
    run = tmp_path / "lv.parquet"
    res = invoke(
        "import", src, "--out", run, "--col", "t_s=1", "--col", "command_v=2", "--col", "force_n=3", "--kind", "sine"
    )
    assert res.exit_code == 0, res.output
    lo, hi = np.quantile(y, [0.2, 0.8])
    ref = _triangle(tmp_path / "ref.csv", "reference_n", float(lo), float(hi), fs)
    doc, pred, _ = _chain(tmp_path, run, ref)
    held = doc["hysteresis"]["fit"]["holdout_rms_n"]
    err = pred["predicted_n"] - pred["reference_n"]
    assert float(np.sqrt(np.mean(err**2))) <= held
    # the report of a model without validation runs: MODEL ONLY, the import's provenance, the loop
    # of the sweep there is with the model over it, and no advice the data cannot follow
    res = invoke("report", "--characterization", run, "--bundle", tmp_path / "b.json", "--out", tmp_path / "rep")
    assert res.exit_code == 0, res.output
    md = (tmp_path / "rep" / "report.md").read_text()
    assert f"the model's held-out error is {held:.3g} N" in md
    assert "MODEL ONLY" in md and "INCOMPLETE" not in md
    import hashlib

    digest = hashlib.sha256(src.read_bytes()).hexdigest()[:12]
    assert f"imported from labview.csv (sha256 {digest}" in md and "Rig ?" not in md
    assert "hysteresis loop is missing" not in md  # the 0.2 Hz sine's loop stands in for the 0.1 Hz triangle's
    assert (tmp_path / "rep" / "hysteresis_loops.png").is_file()
    assert "run `piezopress validate`" not in md


@pytest.mark.parametrize("peak", [50.0, 150.0, 250.0])
def test_compensate_then_simulate_round_trips_on_our_own_bundle(tmp_path, peak):
    """Property: a reference within reach, compensated and played through the bundle's own model,
    comes back within the model's held-out error (references above the rest, the default)."""
    ref = _triangle(tmp_path / "ref.csv", "reference_n", 0.0, peak, 1000.0, freq=0.5, cycles=2)
    drive = tmp_path / "drive.csv"
    res = invoke("compensate", "--bundle", BUNDLE, "--reference", ref, "--out", drive)
    assert res.exit_code == 0 and "above the model's rest" in res.output
    res = invoke("simulate", drive, "--bundle", BUNDLE, "--out", tmp_path / "p.csv")
    assert res.exit_code == 0, res.output
    pred = pd.read_csv(tmp_path / "p.csv")
    assert "rest_n" not in pred.columns
    held = json.loads(BUNDLE.read_text())["hysteresis"]["fit"]["holdout_rms_n"]
    # the creep compensator and the shaper's transients: within twice the held-out error over the sweep
    err = pred["error_n"].to_numpy()[200:]
    assert float(np.sqrt(np.mean(err**2))) <= 2 * held + 0.01 * peak


def test_compensate_with_a_rig_uses_its_range_and_says_so(tmp_path):
    rig = tmp_path / "rig.toml"
    text = (ROOT / "sample_runs" / "rig.toml").read_text()
    assert "drive_min_v" in text
    import re

    rig.write_text(re.sub(r"drive_min_v\s*=\s*[-0-9.]+", "drive_min_v = 0.0", text, count=1))
    ref = _triangle(tmp_path / "ref.csv", "reference_n", 30.0, 100.0, 1000.0, freq=0.5, cycles=1)
    res = invoke("compensate", "--bundle", BUNDLE, "--reference", ref, "--out", tmp_path / "d.csv", "--rig", rig)
    assert res.exit_code == 0, res.output
    assert "the drive range is the rig's, 0 to 150 V" in res.output and "not the bundle's -30 to 150 V" in res.output
    assert pd.read_csv(tmp_path / "d.csv")["command_v"].min() >= 0.0


@needs_datasets(SMART)
@pytest.mark.parametrize("base", [False, True], ids=["fit", "fit --base"])
def test_fit_simulate_and_diagnose_judge_one_model_on_the_same_rows(tmp_path, base):
    """One model, one error: the held-out error fit prints, simulate's on the same rows, and
    diagnose's base fit, within 5 %; the record's start (a rest of unknown state) is reported
    apart, never as misfit."""
    from piezopress import runformat

    run = tmp_path / "smart.parquet"
    assert invoke(*import_args("smart", run)).exit_code == 0
    bundle = tmp_path / "b.json"
    res = invoke("fit", run, "--out", bundle, *(["--base"] if base else []))
    assert res.exit_code == 0, res.output
    fit = json.loads(bundle.read_text())["hysteresis"]["fit"]
    held_fit = fit["holdout_rms_um"]
    res = invoke("simulate", run, "--bundle", bundle, "--out", tmp_path / "sim.parquet")
    assert res.exit_code == 0 and "not counted" in res.output, res.output
    sim = runformat.read_run(tmp_path / "sim.parquet")
    rows = sim.meta["simulated_with"]["judged_rows"]
    assert rows["fitted_from"] > 0  # the record's start is skipped
    held_sim = float(np.sqrt(np.mean(sim.data["residual"].to_numpy()[rows["held_out_from"] : rows["stop"]] ** 2)))
    res = invoke("diagnose", run, "--bundle", bundle, "--out", tmp_path / "diag")
    assert res.exit_code == 0, res.output
    doc = json.loads((tmp_path / "diag" / "diagnosis.json").read_text())
    held_diag = doc["base_fit"]["holdout_rms_um"]
    for other in (held_sim, held_diag):
        assert other == pytest.approx(held_fit, rel=0.05)
    # the headline residual is judged on the same rows (no 3.4 µm from the start's unknown state)
    assert doc["residual_rms_um"] < 3 * held_fit


def test_inspect_a_bundle_shows_its_rest_reach_and_error():
    from piezopress.pipelines.bundle import read_bundle

    b = read_bundle(BUNDLE)
    lo, hi = b.reach()
    res = invoke("inspect", BUNDLE)
    assert res.exit_code == 0, res.output
    assert f"rest: {b.hysteresis.y0:.4g} N" in res.output and f"({lo:.4g} to {hi:.4g} above the rest)" in res.output
    held = json.loads(BUNDLE.read_text())["hysteresis"]["fit"]["holdout_rms_n"]
    assert f"held-out error {held:.4g} N RMS" in res.output
    # the reach is the model's: driving its inverse to the reach's ends needs the range's ends
    drive, _ = b.hysteresis.inverse(np.array([b.hysteresis.y0, b.hysteresis.y0 + hi]))
    assert drive[-1] == pytest.approx(b.settings.drive_max_v, abs=1.0)
    res = invoke("inspect", BUNDLE, "--json")
    doc = json.loads(res.stdout)
    assert doc["runs"][0]["reach_above_rest_n"] == pytest.approx([lo, hi])


def test_the_report_says_the_rest_and_the_reach(tmp_path):
    res = invoke("report", "--bundle", BUNDLE, "--out", tmp_path / "rep")
    assert res.exit_code == 0, res.output
    rest = json.loads(BUNDLE.read_text())["hysteresis"]["model"]["y0_n"]
    assert 49.0 < rest < 51.0  # the sample rig's preload, about 50 N
    assert (
        f"Rest and reach: the model's rest output is {rest:.4g} N; references are read above it."
        in (tmp_path / "rep" / "report.md").read_text()
    )


@needs_datasets(SMART)
def test_diagnose_on_a_displacement_record_warns_nothing_and_plans_for_its_own_press(tmp_path):
    """No numpy warning on an ordinary diagnose; the next plan for a record that measures
    displacement is for the press that recorded it, never the virtual rig (which measures force)."""
    import warnings

    from piezopress.pipelines import bundle as bundle_mod
    from piezopress.pipelines import diagnose as D
    from piezopress.pipelines import fit as F

    run = tmp_path / "smart.parquet"
    assert invoke(*import_args("smart", run)).exit_code == 0
    bundle_mod.write_document(F.fit_bundle([run], base=True).doc, tmp_path / "base.json")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        D.diagnose([run], tmp_path / "base.json", tmp_path / "diag")
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)], [str(w.message) for w in caught]
    plan = (tmp_path / "diag" / "next-plan.toml").read_text()
    assert "--rig YOUR-PRESS.toml" in plan and "never" in plan and "thesis-press.toml --out" not in plan


def test_an_actuator_only_rig_file_sets_the_range_compensate_uses_and_runs_nothing(tmp_path):
    from piezopress.errors import BackendError, ConfigError
    from piezopress.pipelines import characterize as char

    rig = tmp_path / "act.toml"
    res = invoke("rig-keys", "--template", rig, "--backend", "none")
    assert res.exit_code == 0 and "piezopress compensate" in res.output, res.output
    text = rig.read_text().replace("drive_min_v = -30.0", "drive_min_v = 0.0")
    rig.write_text(text.replace("slew_v_per_ms = 0.0", "slew_v_per_ms = 50.0"))
    lim = char.rig_limits(rig)
    assert (lim.drive_min_v, lim.drive_max_v, lim.slew_limit_v_per_s) == (0.0, 150.0, 50000.0)
    ref = _triangle(tmp_path / "ref.csv", "reference_n", 30.0, 100.0, 1000.0, freq=0.5, cycles=1)
    res = invoke("compensate", "--bundle", BUNDLE, "--reference", ref, "--out", tmp_path / "d.csv", "--rig", rig)
    assert res.exit_code == 0, res.output
    assert "the drive range is the rig's, 0 to 150 V" in res.output
    with pytest.raises(BackendError, match="has no board to play a drive on"):
        char.make_backend(None, rig).run(np.zeros(10), 1000.0, preload_n=50.0, label="t")
    rig.write_text(rig.read_text().replace("slew_v_per_ms = 50.0", "slew_v_per_ms = 0.0"))  # the plan's steps pass
    res = invoke("characterize", "--rig", rig, "--out", tmp_path / "runs")
    assert res.exit_code == 1 and "has no board" in res.output
    rig.write_text('[rig]\nbackend = "none"\n[actuator]\ndrive_min_v = 200.0\ndrive_max_v = 150.0\ncolour = 3\n')
    with pytest.raises(ConfigError) as err:
        char.rig_limits(rig)
    assert "drive_min_v = 200" in str(err.value) and "[actuator] colour is unknown" in str(err.value)


def test_help_shows_the_whole_path_and_fit_says_each_stage_with_its_time(tmp_path):
    res = invoke("--help")
    text = res.output
    order = ["piezopress import", "piezopress fit run.parquet", "piezopress compensate", "piezopress simulate"]
    order += ["piezopress diagnose run.parquet", "piezopress report --characterization run.parquet"]
    at = [text.find(s) for s in order]
    assert all(i >= 0 for i in at) and at == sorted(at), at
    res = invoke("fit", CHAR_SWEEP, "--out", tmp_path / "b.json")
    assert res.exit_code == 0, res.output
    assert re.search(r"fitting hysteresis.* \.\.\. \(\d+\.\d s so far\)", res.output)
    assert re.search(r"fitted in \d+\.\d s", res.output)
    assert "Next:" in res.output and f"piezopress validate --bundle {tmp_path / 'b.json'}" in res.output


def test_a_residuals_dominant_frequency_is_a_tone_never_the_runs_length():
    from piezopress.analysis import diagnosis as dg

    fs, n = 20000.0, 3200  # a 0.16 s step run: 1 / length = 6.25 Hz
    t = np.arange(n) / fs
    run = dg.RunData("step", "step", t, np.where(t > 0.01, 100.0, 0.0), np.zeros(n), fs)
    rng = np.random.default_rng(0)
    drift = 0.5 * t / t[-1] + rng.normal(0, 0.01, n)
    tone = np.sin(2 * np.pi * 500.0 * t) + rng.normal(0, 0.01, n)
    assert dg.residual_stats(run, drift, 0.01).dominant_freq_hz == 0.0  # a drift is no 6.25 Hz tone
    assert dg.residual_stats(run, rng.normal(0, 0.01, n), 0.01).dominant_freq_hz == 0.0  # nor is noise
    assert dg.residual_stats(run, tone, 0.01).dominant_freq_hz == pytest.approx(500.0, abs=fs / n)


@needs_datasets(SMART)
def test_skip_s_and_rows_judge_the_same_rows_on_simulate_and_diagnose(tmp_path):
    """``--skip-s``/``--rows`` on every command that judges: given to simulate and diagnose, the
    rows judged are the user's (recorded in their outputs), checked as fit checks them, and a
    start skipped on all three gives one held-out error."""
    from piezopress import runformat

    run = tmp_path / "smart.parquet"
    assert invoke(*import_args("smart", run)).exit_code == 0
    bundle = tmp_path / "b.json"
    assert invoke("fit", run, "--base", "--skip-s", "4", "--out", bundle).exit_code == 0
    fit = json.loads(bundle.read_text())["hysteresis"]["fit"]
    src = runformat.read_run(run)
    start = int(round(4 * src.sample_rate_hz))
    assert fit["fitted_from_row"] == [start]
    res = invoke("simulate", run, "--bundle", bundle, "--skip-s", "4", "--out", tmp_path / "sim.parquet")
    assert res.exit_code == 0, res.output
    rows = runformat.read_run(tmp_path / "sim.parquet").meta["simulated_with"]["judged_rows"]
    assert rows["fitted_from"] == start and rows["held_out_from"] == fit["held_out_from_row"][0]
    # rows: the stop drops the end; the start is the user's
    stop = src.t_s.size - 1000
    res = invoke(
        "simulate", run, "--bundle", bundle, "--rows", f"{start + 100}:{stop}", "--out", tmp_path / "s2.parquet"
    )
    assert res.exit_code == 0, res.output
    rows = runformat.read_run(tmp_path / "s2.parquet").meta["simulated_with"]["judged_rows"]
    assert (rows["fitted_from"], rows["stop"]) == (start + 100, stop)
    assert f"rows {stop}: on not judged" in res.output
    res = invoke("diagnose", run, "--bundle", bundle, "--skip-s", "4", "--out", tmp_path / "diag")
    assert res.exit_code == 0, res.output
    doc = json.loads((tmp_path / "diag" / "diagnosis.json").read_text())
    (judged,) = doc["judged_rows"].values()
    assert judged["judged_from"] == start and judged["stop"] == src.t_s.size
    assert doc["base_fit"]["holdout_rms_um"] == pytest.approx(fit["holdout_rms_um"], rel=0.05)
    # checked as fit checks them: the value and the run's length named
    res = invoke("diagnose", run, "--bundle", bundle, "--skip-s", "1e6", "--out", tmp_path / "d2")
    assert res.exit_code != 0 and "--skip-s 1e+06 s; expected 0 to" in res.output
    assert not (tmp_path / "d2").exists()
    drive = tmp_path / "d.csv"
    pd.DataFrame({"t_s": np.arange(100) / 1000.0, "command_v": np.zeros(100)}).to_csv(drive, index=False)
    res = invoke("simulate", drive, "--bundle", bundle, "--rows", "1:5", "--out", tmp_path / "x.csv")
    assert res.exit_code == 2 and "a drive file has no measurement to judge" in res.output, res.output
