"""The Bundle type (issue 12) and the bundle checked as it is read (issue 14).

Every probe of issue 14 that concerns a bundle gives one line naming the file, the section
and key, and what was expected, through every command that reads a bundle; the models the
type builds are the ones the bundle describes (compared with the models built by hand).
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from piezopress import runformat
from piezopress.analysis.bundle import LEAD_MAX_FRACTION, Bundle, BundleError
from piezopress.analysis.compensation import Compensator
from piezopress.analysis.creep import CreepModel
from piezopress.analysis.hysteresis import PIModel
from piezopress.piezocli.main import cli

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_runs"
BUNDLE = SAMPLES / "bundle.json"
STEP = SAMPLES / "characterization" / "step-20v.parquet"
TRIANGLE = SAMPLES / "characterization" / "triangle-0.1hz.parquet"


def base_doc() -> dict:
    return json.loads(BUNDLE.read_text())


N_PLAYS = len(base_doc()["hysteresis"]["model"]["play_thresholds"])  # the sample bundle's


def invoke(*args) -> tuple[int, str]:
    res = CliRunner().invoke(cli, [str(a) for a in args])
    return res.exit_code, res.output


def one_error_line(code: int, out: str) -> str:
    lines = out.strip().splitlines()
    assert code in (1, 2) and len(lines) == 1 and lines[0].startswith("Error: "), out
    assert "Traceback" not in out
    return lines[0]


@pytest.fixture(scope="module")
def ref_csv(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("ref") / "ramp.csv"
    t = np.arange(2000) / 1000.0
    pd.DataFrame({"t_s": t, "reference_n": np.linspace(0.0, 100.0, t.size)}).to_csv(path, index=False)
    return path


@pytest.fixture(scope="module")
def tiny_plan(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("plan") / "tiny.toml"
    path.write_text(
        '[plan]\nname = "tiny"\npreload_n = 50.0\n\n[[protocol]]\nname = "step-30n"\nkind = "step"\nlevel_n = 30.0\n'
        "hold_s = 0.05\nsample_rate_hz = 5000.0\n"
    )
    return path


# --------------------------------------------------------------------------- the type


def test_from_dict_and_to_dict_round_trip_and_the_models_are_the_bundles():
    doc = base_doc()
    b = Bundle.from_dict(doc, "sample")
    assert b.to_dict() == doc and b.unit == "N"
    assert b.hysteresis == PIModel.from_dict(doc["hysteresis"]["model"])
    assert b.creep == CreepModel.from_dict(doc["creep"]["model"])
    assert b.shaper.amplitudes == tuple(doc["shaper"]["shaper"]["amplitudes"])
    # to_dict is a copy: changing it does not change the bundle
    b.to_dict()["compensation"]["lead_s"] = 9.0
    assert b.settings.lead_s == doc["compensation"]["lead_s"]


def test_a_rate_law_as_a_power_of_the_rate_is_the_compensators():
    # the power law diagnose may find (a viscous lag in the square root of the rate) reaches the
    # compensator as written, and a bundle without one reads as the linear law
    doc = base_doc()
    doc["compensation"]["rate_dependence"] = {"widen_v_per_kv_s": 1.5, "exponent": 0.5, "tau_s": 0.002}
    rate = Bundle.from_dict(doc).compensator().rate
    assert (rate.widen_v_per_kv_s, rate.exponent, rate.saturation_v_per_s, rate.tau_s) == (1.5, 0.5, None, 0.002)
    ramp = 4.0 * np.arange(1000)  # 4 kV/s at 1 kHz, read as 2 kV/s once the 2 ms envelope settles
    assert rate.rate(ramp, 1000.0)[-1] == pytest.approx(2000.0, rel=1e-9)
    del doc["compensation"]["rate_dependence"]["exponent"]
    assert Bundle.from_dict(doc).compensator().rate.exponent == 1.0


def test_compensator_is_the_one_the_bundle_describes():
    """The drive equals (to 1e-12 V) the compensator assembled by hand from the bundle's numbers."""
    doc = base_doc()
    comp = doc["compensation"]
    b = Bundle.from_dict(doc)
    by_hand = Compensator(
        hysteresis=b.hysteresis,
        creep=b.creep,
        shaper=b.shaper,
        drive_min_v=comp["drive_min_v"],
        drive_max_v=comp["drive_max_v"],
        max_rate_per_s=comp["max_rate_n_per_s"],
        lead_s=comp["lead_s"],
    )
    rng = np.random.default_rng(5)
    fs = 5000.0
    for _ in range(3):  # random staircases inside the press's range
        ref = np.repeat(rng.uniform(0, 250, 6), 800)
        np.testing.assert_allclose(
            b.compensator().drive(ref, fs).command_v, by_hand.drive(ref, fs).command_v, atol=1e-12, rtol=0
        )
    no_shaper = b.compensator(use_shaper=False, use_creep=False)
    assert no_shaper.shaper is None and no_shaper.creep is None and no_shaper.lead_s == 0.0


def test_remove_creep_is_the_exact_inverse_of_the_creep_model():
    """Creep applied to the creep-free output (above the rest level) gives the measurement back (1e-9 N)."""
    from piezopress.analysis.hysteresis import rest_offset

    b = Bundle.from_dict(base_doc())
    run = runformat.read_run(TRIANGLE)
    free = b.remove_creep(run)
    _, rest = rest_offset(run.command_v, run.output)
    back = rest + b.creep.response(free - rest, run.sample_rate_hz)[0]
    np.testing.assert_allclose(back, run.output, atol=1e-9)
    assert not np.allclose(free, run.output, atol=0.05)  # it did remove something (creep of a 0.1 Hz sweep: > 0.05 N)
    no_creep = base_doc()
    del no_creep["creep"]
    np.testing.assert_array_equal(Bundle.from_dict(no_creep).remove_creep(run), run.output)


def test_forward_model_and_extended():
    from piezopress.analysis import diagnosis as dg

    b = Bundle.from_dict(base_doc())
    m = b.forward_model()
    assert m.hysteresis == b.hysteresis and m.creep == b.creep and m.wn == b.mode[0] and m.zeta == b.mode[1]
    finding = dg.Finding(
        "amplifier_slew_limit", "test", 1.0, 0.5, 50.0, {"slew_rate_v_per_s": 12_000.0}, [], [], 1.0, 0.1, m
    )
    ext = b.extended([finding])
    assert ext.settings.slew_v_per_s == 12_000.0 and ext.compensator().slew_v_per_s == 12_000.0
    assert ext.to_dict()["extensions"] == {"amplifier_slew_limit": {"slew_rate_v_per_s": 12_000.0}}
    assert b.settings.slew_v_per_s is None  # the bundle itself is unchanged


def test_the_bundle_says_how_its_creep_was_fitted_and_a_found_log_creep_says_it_anew():
    """``creep.fit.edge_aligned`` reaches the forward model (a creep fitted again on a hold is
    fitted as this one was); a bundle written before it was recorded says nothing (None). The
    log creep a diagnosis found was fitted past the step's edge: its extended bundle says so."""
    from dataclasses import replace

    from piezopress.analysis import diagnosis as dg

    doc = base_doc()
    doc["creep"]["fit"].pop("edge_aligned", None)
    assert Bundle.from_dict(doc).forward_model().creep_edge_aligned is None
    doc["creep"]["fit"]["edge_aligned"] = False
    b = Bundle.from_dict(doc)
    assert b.creep_edge_aligned is False and b.forward_model().creep_edge_aligned is False
    m = b.forward_model()
    log = replace(m, creep=CreepModel.log(0.97, 0.012), creep_edge_aligned=True)
    finding = dg.Finding("logarithmic_creep", "test", 1.0, 0.5, 50.0, {}, [], [], 1.0, 0.1, log)
    ext = b.extended([finding])
    assert ext.to_dict()["creep"]["fit"]["edge_aligned"] is True and ext.forward_model().creep_edge_aligned is True
    assert b.to_dict()["creep"]["fit"]["edge_aligned"] is False  # the bundle itself is unchanged


# --------------------------------------------------------------------------- issue 14's probes


def _set(path: str, value):
    def change(doc):
        *parents, last = path.split(".")
        d = doc
        for p in parents:
            d = d[p]
        d[last] = value
        return doc

    return change


def _um_hysteresis(doc):
    m = doc["hysteresis"]["model"]
    m["output_unit"] = "um"
    m["y0_um"] = m.pop("y0_n")
    doc["hysteresis"]["output_column"] = "displacement_um"
    return doc


def _um_hysteresis_n_shaper(doc):
    doc = _um_hysteresis(doc)
    del doc["creep"]
    doc["compensation"]["max_rate_um_per_s"] = doc["compensation"].pop("max_rate_n_per_s")
    doc["shaper"]["mode"]["output_unit"] = "N"
    return doc


def _weight(value):
    def change(doc):
        doc["hysteresis"]["model"]["play_weights"][3] = value
        return doc

    return change


PROBES = {
    "y0 NaN": (_set("hysteresis.model.y0_n", float("nan")), "hysteresis.model.y0_n = nan; expected a finite number"),
    "drive_max_v = 1e9": (
        _set("compensation.drive_max_v", 1e9),
        "compensation.drive_max_v = 1000000000.0; expected a drive limit in V",
    ),
    "lead_s = 100": (
        _set("compensation.lead_s", 100),
        "compensation.lead_s = 100; expected the drive's lead in s within [0, 1)",
    ),
    "max_rate = -1": (
        _set("compensation.max_rate_n_per_s", -1),
        "compensation.max_rate_n_per_s = -1; expected null (no limit) or a positive rate",
    ),
    "um hysteresis, N creep": (  # a bundle from before the creep fit recorded its unit
        lambda d: (_um_hysteresis(d), d["creep"]["fit"].pop("output_unit", None), d)[2],
        f"creep.fit.rms_n = {base_doc()['creep']['fit']['rms_n']!r}; expected a creep fitted in µm (rms_um)",
    ),
    "um hysteresis, N creep (unit recorded)": (
        lambda d: (_um_hysteresis(d), d["creep"]["fit"].__setitem__("output_unit", "N"), d)[2],
        "creep.fit.output_unit = 'N'; expected 'um', the hysteresis model's output unit",
    ),
    "edge_aligned = 'yes'": (
        _set("creep.fit.edge_aligned", "yes"),
        "creep.fit.edge_aligned = 'yes'; expected true or false (was the creep fitted past the step's edge)",
    ),
    "um hysteresis, N shaper": (_um_hysteresis_n_shaper, "shaper.mode.output_unit = 'N'; expected 'um'"),
    "um hysteresis, N rate limit": (
        lambda d: (_um_hysteresis(d), d.pop("creep"), d["shaper"]["mode"].__setitem__("output_unit", "um"))[0],
        "compensation.max_rate_n_per_s = 40000.0; expected no rate limit in N/s",
    ),
    "a JSON list": (lambda d: [d], "the document is a JSON list; expected a JSON object"),
    "NaN play weight": (_weight(float("nan")), "hysteresis.model.play_weights[3] = nan; expected a finite number"),
    "inf play weight": (_weight(float("inf")), "hysteresis.model.play_weights[3] = inf; expected a finite number"),
    "1e300 play weight": (_weight(1e300), "hysteresis.model.play_weights[3] = 1e+300; expected weights in N/V within"),
    "1e300 threshold": (
        lambda d: (d["hysteresis"]["model"]["play_thresholds"].__setitem__(-1, 1e300), d)[1],
        f"hysteresis.model.play_thresholds[{N_PLAYS - 1}] = 1e+300; expected thresholds in V within",
    ),
    "not invertible": (
        _set("hysteresis.model.play_weights", [-0.5] + [0.1] * (N_PLAYS - 1)),
        "expected an invertible model",
    ),
    "shaper sum": (
        lambda d: (d["shaper"]["shaper"]["amplitudes"].__setitem__(0, 0.5), d)[1],
        "expected positive impulses summing to 1",
    ),
    "creep K_c < 0": (_set("creep.model.static_gain", -0.5), "creep.model.static_gain = -0.5; expected K_c > 0"),
    "schema 2": (_set("bundle_version", 2), "bundle_version = 2; expected 1"),
    "no hysteresis": (lambda d: (d.pop("hysteresis"), d)[1], "has no hysteresis section"),
    "section not a mapping": (_set("creep", [1, 2]), "creep is a JSON list; expected a mapping"),
    "string number": (_set("compensation.lead_s", "0.001"), "compensation.lead_s = '0.001'; expected a finite number"),
    "rate law saturating and a power": (
        _set("compensation.rate_dependence", {"widen_v_per_kv_s": 1.0, "saturation_v_per_s": 2000.0, "exponent": 0.5}),
        "compensation.rate_dependence.exponent = 0.5; expected 1 with saturation_v_per_s 2000",
    ),
}


@pytest.fixture(scope="module")
def probe_files(tmp_path_factory) -> dict[str, Path]:
    work = tmp_path_factory.mktemp("probes")
    files = {}
    for i, (name, (change, _)) in enumerate(PROBES.items()):
        files[name] = work / f"probe-{i}.json"
        files[name].write_text(json.dumps(change(base_doc())))
    return files


@pytest.mark.parametrize("name", list(PROBES))
def test_a_corrupted_bundle_is_one_line_in_every_command_that_reads_it(name, probe_files, ref_csv, tiny_plan, tmp_path):
    path, expected = probe_files[name], PROBES[name][1]
    commands = {
        "compensate": ["compensate", "--bundle", path, "--reference", ref_csv, "--out", tmp_path / "drive.csv"],
        "simulate": ["simulate", STEP, "--bundle", path, "--out", tmp_path / "sim.parquet"],
        "validate": ["validate", "--bundle", path, "--plan", tiny_plan, "--out", tmp_path / "val"],
        "diagnose": ["diagnose", STEP, "--bundle", path, "--cause", "input_delay", "--out", tmp_path / "diag"],
        "report": ["report", "--bundle", path, "--out", tmp_path / "report"],
    }
    for command, args in commands.items():
        line = one_error_line(*invoke(*args))
        assert str(path) in line and expected in line, f"{command}: {line}"
    assert not any(tmp_path.iterdir()), "nothing is written from a refused bundle"


def test_the_sound_bundle_passes_the_same_commands(ref_csv, tiny_plan, tmp_path):
    code, out = invoke("compensate", "--bundle", BUNDLE, "--reference", ref_csv, "--out", tmp_path / "drive.csv")
    assert code == 0, out
    drive = pd.read_csv(tmp_path / "drive.csv")
    assert np.all(np.isfinite(drive.command_v)) and 0.0 <= drive.command_v.min() and drive.command_v.max() <= 150.0
    code, out = invoke("validate", "--bundle", BUNDLE, "--plan", tiny_plan, "--out", tmp_path / "val")
    assert code == 0, out


def test_a_lead_longer_than_a_tenth_of_the_reference_is_refused(tmp_path):
    """Issue 14: a 99 µs reference gave a constant drive; the bundle's 52 µs lead is more than a tenth of it."""
    lead = base_doc()["compensation"]["lead_s"]
    fs = 1e5
    t = np.arange(10) / fs
    pd.DataFrame({"t_s": t, "reference_n": np.linspace(0, 100, t.size)}).to_csv(tmp_path / "short.csv", index=False)
    line = one_error_line(
        *invoke("compensate", "--bundle", BUNDLE, "--reference", tmp_path / "short.csv", "--out", tmp_path / "d.csv")
    )
    assert (
        f"compensation.lead_s = {lead:.6g} s; expected less than {LEAD_MAX_FRACTION:g} of the reference's 9e-05 s"
        in line
    )
    # a reference ten leads long and more passes
    n = int(np.ceil(lead / LEAD_MAX_FRACTION * fs)) + 2
    t = np.arange(n) / fs
    pd.DataFrame({"t_s": t, "reference_n": np.linspace(0, 1, n)}).to_csv(tmp_path / "ok.csv", index=False)
    code, out = invoke(
        "compensate", "--bundle", BUNDLE, "--reference", tmp_path / "ok.csv", "--out", tmp_path / "d.csv"
    )
    assert code == 0, out


@pytest.mark.parametrize("fs", [1e6, 1e9])
def test_a_reference_faster_than_the_rig_is_refused_at_once(fs, tmp_path):
    """Issue 14: 100 rows at 1 MHz gave a constant drive; a reference at 1 GHz ran past 600 s."""
    t = np.arange(100) / fs
    pd.DataFrame({"t_s": t, "reference_n": np.linspace(0, 100, t.size)}).to_csv(tmp_path / "fast.csv", index=False)
    line = one_error_line(
        *invoke("compensate", "--bundle", BUNDLE, "--reference", tmp_path / "fast.csv", "--out", tmp_path / "d.csv")
    )
    assert (
        f"sample rate {fs:.6g} Hz is above the rig's maximum sample rate of 100000 Hz; expected at most 100000 Hz"
        in line
    )


def test_a_long_lead_is_refused_by_validate_before_anything_runs(tmp_path):
    doc = base_doc()
    doc["compensation"]["lead_s"] = 0.5  # inside the physical range, longer than a tenth of the 2 s 5 Hz triangle
    (tmp_path / "b.json").write_text(json.dumps(doc))
    line = one_error_line(*invoke("validate", "--bundle", tmp_path / "b.json", "--out", tmp_path / "val"))
    assert "compensation.lead_s = 0.5 s; expected less than 0.1 of the reference's" in line and "protocol" in line
    assert not (tmp_path / "val").exists()


def test_a_drive_range_outside_the_rigs_is_refused(tmp_path, ref_csv, tiny_plan):
    doc = base_doc()
    doc["compensation"]["drive_max_v"] = 500.0
    (tmp_path / "b.json").write_text(json.dumps(doc))
    rig = ROOT / "rigs" / "thesis-press.toml"
    # validate and compensate --rig apply the rig's range (issue 22) and say that it differs from the bundle's
    code, out = invoke("validate", "--bundle", tmp_path / "b.json", "--plan", tiny_plan, "--out", tmp_path / "v")
    assert code == 0, out
    assert "the drive range is the rig's, -30 to 150 V" in out and "not the bundle's -30 to 500 V" in out
    # compensate --rig applies the rig's range (issue 22) and says that it differs from the bundle's
    code, out = invoke(
        "compensate", "--bundle", tmp_path / "b.json", "--rig", rig, "--reference", ref_csv, "--out", tmp_path / "d.csv"
    )
    assert code == 0, out
    assert "the drive range is the rig's, -30 to 150 V" in out and "not the bundle's -30 to 500 V" in out
    assert pd.read_csv(tmp_path / "d.csv")["command_v"].max() <= 150.0


def _displacement_run(path: Path) -> Path:
    run = runformat.read_run(STEP)
    cols = {"t_s": run.t_s, "command_v": run.command_v, "displacement_um": 0.1 * run.command_v}
    runformat.write_run(runformat.make_run(cols, runformat.make_meta("step", "step-um", run.sample_rate_hz)), path)
    return path


def test_a_run_in_another_unit_than_the_bundle_is_refused(tmp_path):
    """Issue 14: simulate and diagnose compared a displacement run with a newton bundle."""
    run = _displacement_run(tmp_path / "um.parquet")
    expected = "(displacement_um): is in µm (displacement), the bundle"
    line = one_error_line(*invoke("simulate", run, "--bundle", BUNDLE, "--out", tmp_path / "sim.parquet"))
    assert expected in line and "in N (force); expected one unit" in line
    assert expected in one_error_line(*invoke("diagnose", run, "--bundle", BUNDLE, "--out", tmp_path / "diag"))
    assert not (tmp_path / "sim.parquet").exists() and not (tmp_path / "diag").exists()


def test_a_reference_in_another_unit_names_the_column_it_needs(tmp_path):
    t = np.arange(500) / 1000.0
    pd.DataFrame({"t_s": t, "reference_um": np.linspace(0, 10, t.size)}).to_csv(tmp_path / "um.csv", index=False)
    line = one_error_line(
        *invoke("compensate", "--bundle", BUNDLE, "--reference", tmp_path / "um.csv", "--out", tmp_path / "d.csv")
    )
    assert "is in µm (displacement)" in line and "expected one unit: a force reference, column reference_n" in line


def test_validate_refuses_a_drive_plan_read_as_references(tmp_path):
    """Issue 14: `validate --plan protocols/characterize.toml` read the `_v` keys as newtons."""
    line = one_error_line(
        *invoke(
            "validate", "--bundle", BUNDLE, "--plan", ROOT / "protocols" / "characterize.toml", "--out", tmp_path / "v"
        )
    )
    assert "is in volts (_v); a reference plan's keys end in _n" in line and "expected a validation plan" in line
    assert not (tmp_path / "v").exists()


def test_section_files_are_checked_as_they_are_read(tmp_path):
    doc = base_doc()
    section = doc["hysteresis"]
    section["model"]["play_weights"][0] = float("nan")
    (tmp_path / "h.json").write_text(json.dumps(section))
    line = one_error_line(*invoke("bundle", "--hysteresis", tmp_path / "h.json", "--out", tmp_path / "b.json"))
    assert "h.json: hysteresis.model.play_weights[0] = nan; expected a finite number" in line


def test_from_dict_names_the_source():
    with pytest.raises(BundleError, match=r"^my-file.json: compensation.lead_s = -1; expected"):
        doc = base_doc()
        doc["compensation"]["lead_s"] = -1
        Bundle.from_dict(copy.deepcopy(doc), "my-file.json")


def test_a_creep_compensator_unstable_at_the_references_rate_is_refused(tmp_path, ref_csv, tiny_plan):
    """K_c > 0 and a positive long-time gain, but K_c + C(s) has zeros in the right half-plane
    (1 - 16 s + 10 s^2): its compensator diverges at every rate it would run."""
    doc = base_doc()
    doc["creep"]["model"] = {
        "form": "poles",
        "static_gain": 1.0,
        "taus_s": [1.0, 10.0],
        "gains": [-3.0, 3.0],
        "params": {},
    }
    (tmp_path / "b.json").write_text(json.dumps(doc))
    Bundle.from_dict(doc)  # nothing wrong with the numbers themselves
    line = one_error_line(
        *invoke("compensate", "--bundle", tmp_path / "b.json", "--reference", ref_csv, "--out", tmp_path / "d.csv")
    )
    assert (
        "b.json: creep.model: creep compensator 1/(K_c + C) is unstable at fs_hz=1000" in line
        and "ramp.csv's rate 1000 Hz" in line
    )
    line = one_error_line(
        *invoke("validate", "--bundle", tmp_path / "b.json", "--plan", tiny_plan, "--out", tmp_path / "v")
    )
    assert "is unstable at fs_hz=5000" in line and "protocol step-30n's rate 5000 Hz" in line
    code, out = invoke(
        "validate", "--bundle", tmp_path / "b.json", "--plan", tiny_plan, "--out", tmp_path / "v2", "--no-creep"
    )
    assert code == 0, out  # without the creep compensator nothing diverges


def test_creep_elements_may_cancel_with_large_gains_but_not_absurd_ones():
    """A fit of the thesis's "poles" creep form can set an element's gain in the thousands,
    cancelled by its neighbour (seen on a slew-limited press: 1.8e3): such a bundle is read;
    a gain beyond MAX_CREEP_ELEMENT_GAIN is one line."""
    from piezopress.analysis.bundle import MAX_CREEP_ELEMENT_GAIN

    doc = base_doc()
    doc["creep"]["model"] = {
        "form": "poles",
        "static_gain": 1.0,
        "taus_s": [0.5, 0.6],
        "gains": [1797.5, -1797.49],
        "params": {},
    }
    b = Bundle.from_dict(doc, "b.json")
    assert b.creep.gains == (1797.5, -1797.49)
    doc["creep"]["model"]["gains"] = [10 * MAX_CREEP_ELEMENT_GAIN, 0.01]
    with pytest.raises(
        BundleError,
        match=r"b.json: creep.model.gains\[0\] = 10000000.0; expected dimensionless gains within \[-1e\+06, 1e\+06\]",
    ):
        Bundle.from_dict(doc, "b.json")
