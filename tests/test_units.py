"""Displacement runs end to end: the unit of the run's output column (``force_n`` -> N,
``displacement_um`` -> µm) is carried into every model, bundle, printed line and diagnosis,
and ``fit`` / ``fit --base`` work from sweeps alone.

The two shared data sets are imported with the commands documented in the README
("Importing measured data"); SmartHysteresis is cut to 3-7 s (``--rows``: the end of the
rest and four periods of the sine) to keep the fits fast.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from piezopress import units
from piezopress.analysis import diagnosis as dg
from piezopress.analysis.hysteresis import PIModel
from piezopress.piezocli.main import cli
from piezopress.pipelines import bundle as B
from piezopress.pipelines import diagnose as D
from piezopress.pipelines import fit as F
from piezopress.pipelines import report as R
from piezopress.runformat import read_run

DATASETS = Path(__file__).resolve().parents[1].parent / "shared" / "datasets"
SMART = DATASETS / "smarthysteresis" / "hysteresis_v_150_1hz.csv"
AYE = DATASETS / "aye-ang-2018" / "Model_Vi_Do.dat"
_HAVE = SMART.is_file() and AYE.is_file()
if os.environ.get("CI") and not _HAVE:
    raise RuntimeError(f"CI: shared data sets not found in {DATASETS}")
needs_datasets = pytest.mark.skipif(not _HAVE, reason=f"shared data sets not found in {DATASETS}")

IMPORT_ARGS = {
    "smart": [
        str(SMART),
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
        "--rows",
        "15000:35000",
    ],
    "aye": [
        str(AYE),
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
        "--units-note",
        "command_v: amplifier input, gain undocumented; displacement_um: raw sensor units",
    ],
}
NO_CREEP = "creep: not fitted: no creep run (a step held for a long time, kind 'creep') among the runs given"
NO_SHAPER = (
    "shaper: not fitted: no low-amplitude step run (kind 'step', at most 25 % of the largest drive) "
    "among the runs given"
)
#: A figure followed by the unit N (``0.5 N``, ``3 N/ms``): must not appear for a displacement run.
FORCE_FIGURE = re.compile(r"\d N\b")


def invoke(*args: str) -> str:
    res = CliRunner().invoke(cli, list(args))
    assert res.exit_code == 0, res.output + (repr(res.exception) if res.exception else "")
    return res.output


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("units")


@pytest.fixture(scope="module")
def imported(work):
    """data set -> imported run file."""
    if not _HAVE:
        pytest.skip(f"shared data sets not found in {DATASETS}")
    out = {}
    for name, args in IMPORT_ARGS.items():
        out[name] = work / f"{name}.parquet"
        invoke("import", *args, "--out", str(out[name]))
    return out


@pytest.fixture(scope="module")
def fitted(work, imported):
    """(data set, base) -> (bundle path, printed output) of `piezopress fit` on the imported run alone."""
    out = {}
    for name, run in imported.items():
        for base in (False, True):
            path = work / f"{name}{'-base' if base else ''}.json"
            out[name, base] = path, invoke("fit", str(run), "--out", str(path), *(["--base"] if base else []))
    return out


@pytest.mark.integration
@needs_datasets
@pytest.mark.parametrize("base", [False, True], ids=["auto", "base"])
@pytest.mark.parametrize("name", ["smart", "aye"])
def test_fit_from_a_sweep_alone_carries_um(fitted, name, base):
    path, printed = fitted[name, base]
    doc = json.loads(path.read_text())
    h = doc["hysteresis"]
    assert h["output_column"] == "displacement_um"
    assert h["model"]["output_unit"] == "um" and "y0_um" in h["model"]
    assert {"train_rms_um", "holdout_rms_um", "output_range_um"} <= set(h["fit"])
    # the sections the runs do not allow are left out, and the printed lines say why; from
    # sweeps alone creep comes only from the sweeps' own drift (not with --base), in µm
    assert "shaper" not in doc and NO_SHAPER in printed.splitlines()
    if "creep" in doc:
        assert not base and doc["creep"]["fit"]["source"] == "sweeps" and doc["creep"]["model"]["form"] == "kv"
        assert doc["creep"]["fit"]["output_unit"] == "um" and "rms_um" in doc["creep"]["fit"]
        assert any(line.startswith("creep:") and "from the sweeps" in line for line in printed.splitlines())
    else:
        assert any(line.startswith(NO_CREEP) for line in printed.splitlines())
    # compensation settings in the model's unit: no force rate limit on a displacement bundle
    assert doc["compensation"]["max_rate_um_per_s"] is None
    assert not any(k.endswith("_n") or "_n_" in k for k in doc["compensation"])
    # printed figures in µm, never N
    fit_line = next(line for line in printed.splitlines() if line.startswith("hysteresis: train RMS"))
    assert fit_line.count("µm") == 3, fit_line
    assert not FORCE_FIGURE.search(printed), printed
    if base:
        assert h["fit"]["chosen"].startswith("n=12 ")  # the thesis's structure
    # the bundle is usable by the compensator with the hysteresis section alone
    comp = B.read_bundle(path).compensator()
    assert (comp.creep is None) == ("creep" not in doc) and comp.shaper is None and comp.max_rate_per_s is None


@pytest.mark.integration
@needs_datasets
@pytest.mark.parametrize("name", ["smart", "aye"])
def test_displacement_predictions_are_not_clipped_at_zero(fitted, imported, name):
    run = read_run(imported[name])
    bundle = B.read_document(fitted[name, True][0], "bundle")
    y = run.output
    assert y.min() < 0  # both data sets read below zero
    for pred in (
        PIModel.from_dict(bundle["hysteresis"]["model"]).forward(run.command_v)[0],
        D.base_model(bundle).predict(D.run_data(run)),
    ):  # the simulation diagnose judges
        # judged on the second half, where the model's state no longer depends on the rest it starts from
        half = slice(y.size // 2, None)
        neg = y[half] < -1.0
        assert neg.any() and np.all(pred[half][neg] < 0), "a displacement model's prediction was clipped at 0"
        assert pred[half].min() < 0.5 * y[half].min()
        assert np.sqrt(np.mean((pred - y)[half] ** 2)) < 0.03 * np.ptp(y)  # follows the data, within 3 % of the range


@pytest.mark.integration
@needs_datasets
def test_compensate_takes_a_reference_in_um(fitted, work):
    path = fitted["smart", False][0]
    model = PIModel.from_dict(B.read_document(path, "bundle")["hysteresis"]["model"])
    t = np.arange(5000) / 5000.0
    target_v = 60.0 + 89.0 * np.sin(2 * np.pi * 1.0 * t)  # within the default rig's -30 to 150 V
    ref = model.forward(target_v)[0] - model.y0  # the reference that drive makes (µm from the model's rest)
    assert (model.y0 + ref).min() < 0.0  # reaches negative displacements
    pd.DataFrame({"t_s": t, "reference_um": ref}).to_csv(work / "ref_um.csv", index=False)
    out = invoke(
        "compensate",
        "--bundle",
        str(path),
        "--reference",
        str(work / "ref_um.csv"),
        "--out",
        str(work / "drive.csv"),
        "--zero",
        "rest",
    )
    assert "Wrote" in out and "Warning" not in out and "above the model's rest" in out
    drive = pd.read_csv(work / "drive.csv")
    assert list(drive.columns) == ["t_s", "reference_um", "command_v"]
    np.testing.assert_allclose(drive.command_v, target_v, atol=1e-5)  # the exact inverse, no clip of the output
    # the bundle comes from an imported record: by default its references are on the record's own scale
    pd.DataFrame({"t_s": t, "reference_um": model.y0 + ref}).to_csv(work / "ref_abs.csv", index=False)
    out = invoke(
        "compensate", "--bundle", str(path), "--reference", str(work / "ref_abs.csv"), "--out", str(work / "d_abs.csv")
    )
    assert "on the record's own scale (absolute)" in out and "Warning" not in out
    np.testing.assert_allclose(pd.read_csv(work / "d_abs.csv").command_v, target_v, atol=1e-5)
    # a force reference does not fit a displacement bundle: the error names the column it needs
    pd.DataFrame({"t_s": t, "reference_n": ref}).to_csv(work / "ref_n.csv", index=False)
    res = CliRunner().invoke(
        cli,
        ["compensate", "--bundle", str(path), "--reference", str(work / "ref_n.csv"), "--out", str(work / "d2.csv")],
    )
    assert res.exit_code == 1 and "reference_um" in res.output


@pytest.mark.integration
@needs_datasets
def test_diagnose_a_displacement_run_reports_in_um(fitted, imported, work):
    out_dir = work / "diag-aye"
    printed = invoke("diagnose", str(imported["aye"]), "--bundle", str(fitted["aye", True][0]), "--out", str(out_dir))
    assert "µm RMS" in printed and not FORCE_FIGURE.search(printed), printed
    doc = json.loads((out_dir / "diagnosis.json").read_text())
    assert doc["output_unit"] == "um" and "residual_rms_um" in doc and "noise_floor_um" in doc
    assert "µm" in doc["summary"] and not FORCE_FIGURE.search(doc["summary"])

    def keys(obj):
        if isinstance(obj, dict):
            for k, v in obj.items():
                yield k
                yield from keys(v)
        elif isinstance(obj, list):
            for v in obj:
                yield from keys(v)

    assert not [k for k in keys({k: v for k, v in doc.items() if k != "causes"}) if k.endswith("_n") or "_n_" in k]
    # the hysteresis_order check refits with the model's unit: its baseline is the model's own
    # error (well under 1 µm), not a displacement clipped at 0 (about 97 µm)
    for f in doc["findings"] + doc["considered_not_found"]:
        assert f["baseline_rms_um"] < 2.0, f
    ext = json.loads((out_dir / "extended_bundle.json").read_text())
    assert ext["hysteresis"]["model"]["output_unit"] == "um"
    # simulate: the prediction beside the measurement, in µm and unclipped
    printed = invoke(
        "simulate",
        str(imported["aye"]),
        "--bundle",
        str(fitted["aye", True][0]),
        "--out",
        str(work / "sim-aye.parquet"),
    )
    assert "µm RMS" in printed and not FORCE_FIGURE.search(printed)
    sim = read_run(work / "sim-aye.parquet")
    assert sim.data["predicted"].max() < 0  # the whole Aye-Ang record reads below zero


@pytest.mark.integration
@needs_datasets
def test_report_of_a_displacement_bundle_speaks_um(fitted):
    rep = R.build_report(bundle=fitted["smart", False][0])
    text = rep.markdown()
    assert "RMS error (µm)" in text and "no rate limit" in text
    assert not FORCE_FIGURE.search(text.split("## Model quality")[1]) and "(N)" not in text.split("## Model quality")[1]


def test_validate_refuses_a_displacement_bundle(tmp_path):
    from piezopress.pipelines.validate import validate

    h = {"model": PIModel((0.0,), (1.0,), (0.0,), (1.0,), output_unit="um").to_dict(), "runs": []}
    doc = B.assemble({"hysteresis": h}, F.compensation_settings({"hysteresis": h}))
    B.write_document(doc, tmp_path / "b.json")
    with pytest.raises(B.BundleError, match="displacement"):
        validate(tmp_path / "val", tmp_path / "b.json")


def test_force_only_logic_stays_for_force_and_never_applies_to_displacement():
    t = np.arange(400) / 100.0
    x = 10 * np.sin(2 * np.pi * 0.5 * t)
    run = dg.RunData("r", "sine", t, x, x, 100.0)
    for unit, clipped in (("N", True), ("um", False)):
        m = dg.Model(PIModel((0.0,), (1.0,), (0.0,), (1.0,), output_unit=unit))
        pred = m.predict(run)
        assert bool(pred.min() >= 0.0) is clipped and bool(pred.min() == pytest.approx(-10, abs=0.1)) is not clipped
        sec = {"hysteresis": {"model": m.hysteresis.to_dict()}}
        comp = F.compensation_settings(sec)
        assert comp[f"max_rate_{units.key(unit)}_per_s"] == (F.FORCE_MAX_RATE_N_PER_S if clipped else None)
    assert units.label("um") == "µm" and units.label("N") == "N" and units.unit_of_column("force_n") == "N"
