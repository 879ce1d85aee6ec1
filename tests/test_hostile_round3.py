"""Issue 24, round three: plans (negative seeds, inverted sweeps, a preload that leaves no room,
a TOML with a byte-order mark), references beyond reach (refused unless ``--allow-clip``, the
clipped samples marked), a rate limit that stops the drive, a NaN in a reference named by its
row, imports with blank or short lines, ``report --replace`` aimed at a run directory."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from piezopress.acquisition.plan import DriveLimits, load_plan
from piezopress.acquisition.virtual_rig import VirtualRig
from piezopress.errors import PlanError
from piezopress.piezocli.main import cli

ROOT = Path(__file__).resolve().parents[1]
BUNDLE = ROOT / "sample_runs" / "bundle.json"
CHAR = ROOT / "sample_runs" / "characterization"

TRIANGLE = """
[plan]
name = "p"
{head}
[[protocol]]
name = "t"
kind = "triangle"
freq_hz = 1.0
cycles = 2
sample_rate_hz = 1000.0
{extra}
"""


def invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def _plan(tmp_path: Path, extra: str = "", head: str = "", bom: bool = False) -> Path:
    p = tmp_path / "plan.toml"
    text = TRIANGLE.format(extra=extra, head=head)
    p.write_bytes((b"\xef\xbb\xbf" if bom else b"") + text.encode())
    return p


@pytest.mark.parametrize(
    "extra, named",
    [
        ("random_peaks = {count = 2, min_v = 10.0, max_v = 100.0, seed = -1}", "random_peaks.seed' = -1"),
        ("low_v = 120.0\npeak_v = 60.0", "low_v' = 120 is not below peak_v = 60"),
        ("low_v = 50.0\npeaks_v = [40.0, 90.0]", "peaks_v': 40 is not above low_v = 50"),
        ("low_v = 50.0\nrandom_peaks = {count = 2, min_v = 10.0, max_v = 100.0, seed = 1}", "min_v = 10.0 is not"),
    ],
)
def test_a_plan_that_cannot_play_as_written_is_refused_by_name(tmp_path, extra, named):
    with pytest.raises(PlanError) as err:
        load_plan(_plan(tmp_path, extra), DriveLimits())
    assert named in str(err.value)


def test_a_random_trajectory_with_a_negative_seed_is_refused(tmp_path):
    p = tmp_path / "plan.toml"
    p.write_text(
        '[plan]\nname = "p"\n[[protocol]]\nname = "r"\nkind = "random"\nduration_s = 10.0\n'
        "sample_rate_hz = 1000.0\nseed = -5\n"
    )
    with pytest.raises(PlanError, match=r"key 'seed' = -5 is negative"):
        load_plan(p, DriveLimits())


def test_a_plan_saved_with_a_byte_order_mark_reads_as_without(tmp_path):
    with_bom = load_plan(_plan(tmp_path, bom=True), DriveLimits())
    assert [p.name for p in with_bom.protocols] == ["t"]


def test_the_virtual_rig_stops_a_run_at_the_stacks_force_limit():
    rig = VirtualRig()
    fs = 1000.0
    t = np.arange(int(2 * fs)) / fs
    drive = 150.0 * np.sin(np.pi * t / 2.0) ** 2  # 0 -> 150 V over 1 s, back over the next
    limit = rig.limits.max_force_n
    m = rig.run(drive, fs, preload_n=limit - 1.0, label="near-limit")
    assert not m.complete
    assert "over-force" in m.reason and f"{limit:g} N" in m.reason
    assert m.channels["force_n"].size < drive.size
    assert np.all(m.channels["force_n"] <= limit)  # every kept sample is below the limit
    assert rig.output_v == 0.0
    ok = rig.run(drive, fs, preload_n=50.0, label="normal")
    assert ok.complete and ok.channels["force_n"].size == drive.size


def _reference(path: Path, peak: float, nan_at: int | None = None) -> Path:
    t = np.arange(0, 10, 1e-3)
    r = peak * 0.5 * (1 - np.cos(2 * np.pi * 0.1 * t))
    if nan_at is not None:
        r[nan_at] = np.nan
    pd.DataFrame({"t_s": t, "reference_n": r}).to_csv(path, index=False)
    return path


@pytest.mark.parametrize("peak", [400.0, 4000.0])
def test_a_reference_beyond_reach_is_refused_unless_allowed_and_the_clipped_samples_are_marked(tmp_path, peak):
    ref = _reference(tmp_path / "ref.csv", peak)
    out = tmp_path / "drive.csv"
    res = invoke("compensate", "--bundle", BUNDLE, "--reference", ref, "--out", out)
    assert res.exit_code != 0
    assert "cannot be reached" in res.output and "--allow-clip" in res.output
    assert not out.exists()  # nothing written
    res = invoke("compensate", "--bundle", BUNDLE, "--reference", ref, "--out", out, "--allow-clip")
    assert res.exit_code == 0, res.output
    drive = pd.read_csv(out)
    share = drive["clipped"].mean()
    assert share > 0.25  # a third of a 400 N cosine is beyond a ~300 N press, more of a 4000 N one
    # the marked samples are where the drive sits at the range's top (within the reachability's settling)
    top = drive["command_v"] >= drive["command_v"].max() - 0.5
    assert (drive["clipped"].astype(bool) & top).sum() >= 0.9 * drive["clipped"].sum()
    assert f"{int(drive['clipped'].sum())} clipped" in res.output
    # a requested range is printed only when it lies beyond the allowed one (never -5.7 to 150 against -30 to 150)
    import re

    m = re.search(r"outside (-?[\d.]+) to (-?[\d.]+) V(?: \(requested (-?[\d.]+) to (-?[\d.]+) V\))?", res.output)
    assert m, res.output
    lo, hi = float(m[1]), float(m[2])
    if m[3] is not None:
        assert float(m[3]) < lo or float(m[4]) > hi, res.output


def test_a_reference_within_reach_has_no_clipped_column(tmp_path):
    ref = _reference(tmp_path / "ref.csv", 200.0)
    out = tmp_path / "drive.csv"
    res = invoke("compensate", "--bundle", BUNDLE, "--reference", ref, "--out", out)
    assert res.exit_code == 0, res.output
    assert "Warning" not in res.output
    assert list(pd.read_csv(out).columns) == ["t_s", "reference_n", "command_v"]


def test_a_rate_limit_that_holds_the_drive_back_is_said(tmp_path):
    doc = json.loads(BUNDLE.read_text())
    doc["compensation"]["max_rate_n_per_s"] = 1e-9
    bundle = tmp_path / "slow.json"
    bundle.write_text(json.dumps(doc))
    ref = _reference(tmp_path / "ref.csv", 200.0)
    res = invoke("compensate", "--bundle", bundle, "--reference", ref, "--out", tmp_path / "d.csv")
    assert res.exit_code == 0
    assert "the rate limit (1e-09 N/s) keeps the drive from following the reference" in res.output


def test_a_nan_in_a_reference_is_named_by_its_row(tmp_path):
    ref = _reference(tmp_path / "ref.csv", 200.0, nan_at=2500)
    res = invoke("compensate", "--bundle", BUNDLE, "--reference", ref, "--out", tmp_path / "d.csv")
    assert res.exit_code != 0
    assert "at row 2502 (the header is row 1)" in res.output


def _csv(path: Path, lines: list[str]) -> Path:
    path.write_text("\n".join(lines) + "\n")
    return path


def _sine_lines(n: int = 2000) -> list[str]:
    t = np.arange(n) / 1000.0
    x = 75 + 75 * np.sin(2 * np.pi * t)
    return [f"{a:.4f},{b:.4f},{0.2 * b:.4f}" for a, b in zip(t, x)]


def test_a_blank_line_among_the_data_is_left_out_and_said(tmp_path):
    lines = ["t_s,voltage_v,force_n", *_sine_lines()]
    lines.insert(500, "")
    src = _csv(tmp_path / "blank.csv", lines)
    out = tmp_path / "run.parquet"
    res = invoke(
        "import", src, "--out", out, "--col", "t_s=t_s", "--col", "command_v=voltage_v", "--col", "force_n=force_n"
    )
    assert res.exit_code == 0, res.output
    assert "1 blank line(s) among the data left out" in res.output
    from piezopress import runformat

    run = runformat.read_run(out)
    assert len(run.data) == 2000
    assert run.meta["import"]["blank_lines_dropped"] == 1


def test_a_short_line_is_named_not_a_traceback(tmp_path):
    lines = _sine_lines()
    lines[700] = "0.7000,1.0"
    src = _csv(tmp_path / "short.csv", lines)
    res = invoke(
        "import", src, "--out", tmp_path / "r.parquet", "--col", "t_s=1", "--col", "command_v=2", "--col", "force_n=3"
    )
    assert res.exit_code == 1
    assert "empty cell at data row 700 (line 701), column 3 (force_n)" in res.output
    assert "Traceback" not in res.output


def test_report_replace_never_moves_a_run_directory_aside(tmp_path):
    runs = tmp_path / "runs"
    shutil.copytree(CHAR, runs)
    (runs / "report.md").write_text("an old report written into the run directory\n")
    res = invoke("report", "--characterization", runs, "--out", runs, "--replace")
    assert res.exit_code != 0
    assert "holds runs" in res.output
    assert sorted(p.name for p in runs.iterdir()) == sorted([*(p.name for p in CHAR.iterdir()), "report.md"])
    assert not list(tmp_path.glob("runs.replaced-*"))


# --------------------------------------------------------------------------- diagnose: short runs, interruptions


def _short_runs(tmp_path: Path, n: int) -> Path:
    from piezopress import runformat

    d = tmp_path / "short"
    d.mkdir()
    run = runformat.read_run(CHAR / "triangle-1hz.parquet")
    runformat.write_run(runformat.Run(run.data.iloc[:n].reset_index(drop=True), run.meta), d / "tiny.parquet")
    return d


def test_diagnose_refuses_a_two_sample_run_before_writing_anything(tmp_path):
    runs = _short_runs(tmp_path, 2)
    out = tmp_path / "diag"
    res = invoke("diagnose", runs, "--bundle", ROOT / "sample_runs" / "base-bundle.json", "--out", out)
    assert res.exit_code == 1
    assert "(2 samples) too short to diagnose; expected at least 50 samples" in res.output
    assert not out.exists()


def test_diagnose_gain_on_runs_from_elsewhere_is_refused_before_the_diagnosis(tmp_path):
    from piezopress import runformat

    d = tmp_path / "foreign"
    d.mkdir()
    run = runformat.read_run(CHAR / "triangle-1hz.parquet")
    meta = {k: run.meta[k] for k in ("schema_version", "kind", "name", "sample_rate_hz")}
    runformat.write_run(runformat.Run(run.data, meta), d / "t.parquet")
    out = tmp_path / "diag"
    res = invoke("diagnose", d, "--bundle", ROOT / "sample_runs" / "base-bundle.json", "--out", out, "--gain")
    assert res.exit_code == 1
    assert "virtual rig" in res.output
    assert not out.exists()  # nothing ran, nothing written


class _Stop(Exception):
    pass


@pytest.mark.parametrize("after", [0, 1, 3])
def test_a_diagnosis_stopped_at_any_cause_leaves_a_directory_the_report_calls_incomplete(tmp_path, after):
    """Ctrl-C (or SIGTERM, turned into it) after ``after`` causes: status.json says interrupted,
    and the report leaves the diagnosis out, naming the directory."""
    from piezopress.pipelines import diagnose as diag
    from piezopress.pipelines import report as rep

    seen = []

    def progress(p):
        seen.append(p)
        if len(seen) > after:
            raise KeyboardInterrupt("interrupted by SIGTERM")

    out = tmp_path / "diag"
    with pytest.raises(KeyboardInterrupt):
        diag.diagnose([CHAR], ROOT / "sample_runs" / "base-bundle.json", out, on_progress=progress)
    assert diag.read_status(out) == (diag.INTERRUPTED, "interrupted by SIGTERM")
    report = rep.build_report(None, None, None, out)
    md = report.markdown()
    assert "the diagnosis did not finish (interrupted: interrupted by SIGTERM)" in md
    assert "Diagnosis: what the model gets wrong" not in md


def test_a_diagnosis_killed_outright_stays_running_and_is_not_taken_for_finished(tmp_path):
    """SIGKILL leaves no chance to write: whatever files are there, status.json still says running."""
    from piezopress.pipelines import diagnose as diag
    from piezopress.pipelines import report as rep

    out = tmp_path / "diag"
    shutil.copytree(ROOT / "sample_runs" / "diagnosis", out)
    diag.mark_status(out, diag.RUNNING, "started")
    md = rep.build_report(None, None, None, out).markdown()
    assert "the diagnosis did not finish (running: started)" in md
    shutil.rmtree(out)
    shutil.copytree(ROOT / "sample_runs" / "diagnosis", out)  # written before status.json existed: complete
    assert diag.read_status(out)[0] == diag.COMPLETE


@pytest.mark.integration
def test_a_sigterm_during_diagnose_marks_the_directory_interrupted(tmp_path):
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "diag"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "from piezopress.piezocli.main import cli; cli(prog_name='piezopress')",
            "diagnose",
            str(CHAR),
            "--bundle",
            str(ROOT / "sample_runs" / "base-bundle.json"),
            "--out",
            str(out),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    deadline = time.monotonic() + 60
    while not (out / "status.json").is_file() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.1)
    time.sleep(1.0)
    proc.send_signal(signal.SIGTERM)
    output, _ = proc.communicate(timeout=60)
    from piezopress.pipelines import diagnose as diag

    status, reason = diag.read_status(out)
    if proc.returncode == 0:  # finished before the signal came (a fast machine): complete, never half
        assert status == diag.COMPLETE
    else:
        assert proc.returncode == 128 + signal.SIGTERM, output
        assert (status, reason) == (diag.INTERRUPTED, "interrupted by SIGTERM")


# --------------------------------------------------------------------------- a saturated sensor


def test_a_reading_pinned_at_the_adcs_limit_is_named_a_held_quantised_one_is_not():
    from piezopress import runformat
    from piezopress.analysis import profile as prof

    run = runformat.read_run(CHAR / "triangle-0.1hz.parquet")
    for q in (0.01, 0.5, 0.7):
        pinned = np.minimum(run.output, np.quantile(run.output, q))
        share, at = prof.saturation(pinned, run.command_v)
        assert share == pytest.approx(1 - q, abs=0.02) and at == pytest.approx(np.quantile(run.output, q))
    # every sample set of the project's own runs: steps and holds read on one code are not saturation
    for f in sorted((ROOT / "sample_runs").glob("*/*.parquet")):
        r = runformat.read_run(f)
        assert prof.saturation(r.output, r.command_v) == (0.0, None), f.name


def test_fit_says_when_the_force_is_pinned_at_the_sensors_limit(tmp_path):
    from piezopress import runformat

    d = tmp_path / "runs"
    d.mkdir()
    for name in ("triangle-0.1hz", "triangle-1hz"):
        run = runformat.read_run(CHAR / f"{name}.parquet")
        data = run.data.copy()
        data["force_n"] = np.minimum(data["force_n"], np.quantile(data["force_n"], 0.01))
        runformat.write_run(runformat.Run(data, run.meta), d / f"{name}.parquet")
    res = invoke("fit-hysteresis", d, "--out", tmp_path / "h.json")
    assert "force_n sits at" in res.output and "a saturated sensor or ADC" in res.output


def test_a_whole_bundle_given_as_a_section_is_named_as_one(tmp_path):
    res = invoke("bundle", "--hysteresis", BUNDLE, "--out", tmp_path / "b.json")
    assert res.exit_code == 1
    assert "is a whole bundle, not a hysteresis section" in res.output and "None" not in res.output
    creep_only = tmp_path / "creep.json"
    creep_only.write_text(
        json.dumps({"bundle_version": json.loads(BUNDLE.read_text())["bundle_version"], "section": "creep"})
    )
    res = invoke("bundle", "--hysteresis", creep_only, "--out", tmp_path / "b.json")
    assert "has section 'creep'; expected a hysteresis section" in res.output


# --------------------------------------------------------------------------- runs of two presses


def _other_press(tmp_path: Path, names: list[str], change: str = "stiffness") -> Path:
    """Copies of some runs, as if recorded on another press (one number of its configuration changed),
    or on the same press with another noise seed (``change='seed'``)."""
    import copy

    from piezopress import runformat

    d = tmp_path / f"other-{change}"
    d.mkdir()
    for n in names:
        run = runformat.read_run(CHAR / f"{n}.parquet")
        meta = copy.deepcopy(run.meta)
        cfg = meta["rig"]["config"]
        if change == "seed":
            cfg["rig"]["seed"] = int(cfg["rig"].get("seed", 0)) + 7
        else:
            section = next(k for k, v in cfg.items() if isinstance(v, dict) and k != "rig")
            key = next(k for k, v in cfg[section].items() if isinstance(v, float))
            cfg[section][key] = cfg[section][key] * 1.1 + 1.0
        runformat.write_run(runformat.Run(run.data, meta), d / f"{n}.parquet")
    return d


def test_fit_refuses_runs_of_two_presses_naming_each_unless_allowed(tmp_path):
    other = _other_press(tmp_path, ["triangle-1hz"])
    args = ["fit-hysteresis", CHAR / "triangle-0.1hz.parquet", other / "triangle-1hz.parquet"]
    res = invoke(*args, "--out", tmp_path / "h.json")
    assert res.exit_code == 1
    assert "come from 2 presses" in res.output and "--allow-mixed-rigs" in res.output
    assert "triangle-0.1hz.parquet" in res.output and "triangle-1hz.parquet" in res.output
    res = invoke(*args, "--out", tmp_path / "h.json", "--allow-mixed-rigs")
    assert res.exit_code == 0, res.output


def test_another_noise_seed_or_a_run_from_elsewhere_is_the_same_press(tmp_path):
    from piezopress import runformat
    from piezopress.pipelines.sources import check_one_rig

    same = _other_press(tmp_path, ["triangle-1hz"], change="seed")
    run = runformat.read_run(CHAR / "triangle-0.1hz.parquet")
    foreign = runformat.Run(run.data, {k: run.meta[k] for k in ("schema_version", "kind", "name", "sample_rate_hz")})
    check_one_rig([run, runformat.read_run(same / "triangle-1hz.parquet"), foreign])  # no error


def test_diagnose_refuses_runs_of_two_presses(tmp_path):
    other = _other_press(tmp_path, ["triangle-1hz"])
    res = invoke(
        "diagnose", CHAR, other, "--bundle", ROOT / "sample_runs" / "base-bundle.json", "--out", tmp_path / "d"
    )
    assert res.exit_code == 1 and "come from 2 presses" in res.output
    assert not (tmp_path / "d").exists()


def test_report_refuses_a_validation_of_another_press_unless_allowed(tmp_path):
    other = _other_press(tmp_path, ["triangle-1hz", "triangle-0.1hz"])
    res = invoke("report", "--characterization", CHAR, "--validation", other, "--out", tmp_path / "rep")
    assert res.exit_code == 1 and "come from 2 presses" in res.output
    res = invoke(
        "report", "--characterization", CHAR, "--validation", other, "--out", tmp_path / "rep", "--allow-mixed-rigs"
    )
    assert "come from 2 presses" not in res.output


def test_validate_says_when_the_bundle_was_fitted_on_another_press(tmp_path):
    from piezopress.acquisition.virtual_rig import VirtualRig
    from piezopress.pipelines.validate import other_press_note

    rig = VirtualRig()
    here = {"rig": rig.describe()}
    from piezopress.pipelines.sources import rig_identity

    ident = rig_identity(here)
    own = {"hysteresis": {"runs": [{"name": "t", "rig": ident.digest}]}}
    assert other_press_note(own, rig, "b.json") == ""
    elsewhere = {"hysteresis": {"runs": [{"name": "t", "rig": None}]}}
    assert "fitted on runs from elsewhere" in other_press_note(elsewhere, rig, "b.json")
    other = {"hysteresis": {"runs": [{"name": "t", "rig": "0123456789ab"}]}}
    assert "on another press (rig 0123456789ab)" in other_press_note(other, rig, "b.json")
    legacy = {"hysteresis": {"runs": [{"name": "t"}]}}  # fitted before presses were recorded: nothing to say
    assert other_press_note(legacy, rig, "b.json") == ""


def test_a_stale_lock_is_reported_before_the_work_not_after(tmp_path):
    import os
    import time

    out = tmp_path / "h.json"
    lock = tmp_path / ".h.json.lock"
    lock.write_text("")
    old = time.time() - 120
    os.utime(lock, (old, old))
    t0 = time.monotonic()
    res = invoke("fit-hysteresis", CHAR / "triangle-0.1hz.parquet", "--out", out)
    assert res.exit_code == 1 and "a lock file" in res.output and "remove it if no piezopress is running" in res.output
    assert time.monotonic() - t0 < 10  # refused before the fit, not after it
    lock.unlink()
    assert invoke("fit-hysteresis", CHAR / "triangle-0.1hz.parquet", "--out", out).exit_code == 0


def test_one_sign_reversed_run_beside_a_normal_one_is_named(tmp_path):
    from piezopress import runformat

    d = tmp_path / "runs"
    d.mkdir()
    for name, sign in (("triangle-0.1hz", 1.0), ("triangle-increasing-0.1hz", -1.0)):
        run = runformat.read_run(CHAR / f"{name}.parquet")
        data = run.data.copy()
        data["force_n"] = sign * data["force_n"] + (0.0 if sign > 0 else 2 * float(data["force_n"].mean()))
        runformat.write_run(runformat.Run(data, run.meta), d / f"{name}.parquet")
    res = invoke("fit-hysteresis", d, "--out", tmp_path / "h.json")
    assert res.exit_code == 1
    assert "in triangle-increasing-0.1hz the output falls as the input rises" in res.output and "--scale" in res.output


@pytest.mark.parametrize("seed", range(6))
def test_mixes_of_presses_generated_are_refused_exactly_when_two_presses_meet(seed):
    """The class, generated: runs drawn from up to three presses (a configuration value changed),
    each measured with its own noise seed, some stripped of metadata (from elsewhere): refused
    exactly when two known presses meet, and the message names each press's runs."""
    import copy

    from piezopress import runformat
    from piezopress.pipelines.sources import MixedRigsError, allow_mixed_rigs, check_one_rig

    rng = np.random.default_rng(seed)
    base = runformat.read_run(CHAR / "triangle-1hz.parquet")
    runs, presses = [], set()
    for i in range(int(rng.integers(2, 6))):
        meta = copy.deepcopy(base.meta)
        meta["name"] = f"run{i}"
        press = int(rng.integers(0, 3))
        meta["rig"]["config"]["rig"]["seed"] = int(rng.integers(0, 1000))  # the noise, not the press
        meta["rig"]["config"]["actuator"]["drive_max_v"] = 150.0 - press  # the press
        if rng.random() < 0.3:  # a run from elsewhere: no press recorded
            meta = {k: meta[k] for k in ("schema_version", "kind", "name", "sample_rate_hz")}
        else:
            presses.add(press)
        runs.append(runformat.Run(base.data, meta))
    if len(presses) > 1:
        with pytest.raises(MixedRigsError) as err:
            check_one_rig(runs)
        assert f"come from {len(presses)} presses" in str(err.value)
        allow_mixed_rigs(True)
        try:
            check_one_rig(runs)  # told: joined
        finally:
            allow_mixed_rigs(False)
    else:
        check_one_rig(runs)


@pytest.mark.integration
def test_report_refuses_another_press_diagnosis_unless_allowed(tmp_path):
    from piezopress import runformat
    from piezopress.pipelines.sources import rig_identity

    ours = rig_identity(runformat.read_run(CHAR / "triangle-1hz.parquet").meta)
    for digest, refused in (("0123456789ab", True), (ours.digest, False)):
        diag = tmp_path / f"diag-{digest}"
        shutil.copytree(ROOT / "sample_runs" / "diagnosis", diag)
        doc = json.loads((diag / "diagnosis.json").read_text())
        doc["rigs"] = [{"digest": digest, "label": f"virtual rig {digest}"}]
        (diag / "diagnosis.json").write_text(json.dumps(doc))
        res = invoke("report", "--characterization", CHAR, "--diagnosis", diag, "--out", tmp_path / f"rep-{digest}")
        if refused:
            assert res.exit_code == 1 and "is of another press (virtual rig 0123456789ab)" in res.output
            res = invoke(
                "report",
                "--characterization",
                CHAR,
                "--diagnosis",
                diag,
                "--out",
                tmp_path / f"rep-{digest}",
                "--allow-mixed-rigs",
            )
        assert res.exit_code == 0, res.output


def test_one_press_recorded_from_two_rig_files_is_one_press():
    """The same configuration read from the rig file and rebuilt from the runs' metadata (as
    validate on the runs' virtual rig does): one press, whatever the source's name."""
    import copy

    from piezopress import runformat
    from piezopress.pipelines.sources import check_one_rig, group_by_rig

    run = runformat.read_run(CHAR / "triangle-1hz.parquet")
    other = copy.deepcopy(run.meta)
    other["rig"]["source"] = "the runs' metadata"
    runs = [run, runformat.Run(run.data, other)]
    check_one_rig(runs)
    assert len(group_by_rig(runs)) == 1
