"""`characterize`: runs on disk with a manifest; never overwrites; interruptions are visible."""

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from piezopress import runformat as rf
from piezopress.acquisition.virtual_rig import VirtualRig
from piezopress.piezocli.main import cli
from piezopress.pipelines import characterize as char

SMALL_PLAN = """
[plan]
name = "small"
preload_n = 50.0

[[protocol]]
name = "tri"
kind = "triangle"
freq_hz = 10.0
cycles = 2
sample_rate_hz = 2000.0

[[protocol]]
name = "creep"
kind = "creep"
level_v = 150.0
pre_s = 0.5
hold_s = 3.0
sample_rate_hz = 500.0

[[protocol]]
name = "step"
kind = "step"
level_v = 20.0
hold_s = 0.05
sample_rate_hz = 20000.0
"""


@pytest.fixture
def plan(tmp_path):
    p = tmp_path / "plan.toml"
    p.write_text(SMALL_PLAN)
    return p


def test_characterize_writes_runs_and_manifest(tmp_path, plan):
    out = tmp_path / "runs"
    result = char.characterize(out, plan_path=plan)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["status"] == "complete"
    assert [r["name"] for r in manifest["runs"]] == ["tri", "creep", "step"]
    assert manifest["plan"]["sha256"] == rf.sha256_file(plan)
    assert manifest["software"]["piezopress"]
    assert manifest["rig"]["config"]["mode"]["damping"] == 0.115
    for entry in manifest["runs"]:
        path = out / entry["file"]
        assert rf.sha256_file(path) == entry["sha256"]
        run = rf.read_run(path)
        assert run.meta["protocol"]["name"] == entry["name"]
        assert run.meta["backend"] == "virtual" and run.meta["preload_n"] == 50.0
        assert {"t_s", "command_v", "force_n"} <= set(run.data.columns)
    assert len(result.runs) == 3


def test_same_plan_same_rig_gives_identical_data(tmp_path, plan):
    char.characterize(tmp_path / "a", plan_path=plan)
    char.characterize(tmp_path / "b", plan_path=plan)
    for name in ("tri", "creep", "step"):
        a = rf.read_run(tmp_path / "a" / f"{name}.parquet").data
        b = rf.read_run(tmp_path / "b" / f"{name}.parquet").data
        assert a.equals(b)


def test_refuses_non_empty_output_dir_and_leaves_it_untouched(tmp_path, plan):
    out = tmp_path / "runs"
    out.mkdir()
    keep = out / "precious.parquet"
    keep.write_bytes(b"old data")
    with pytest.raises(Exception, match="already exists and is not empty"):
        char.characterize(out, plan_path=plan)
    assert keep.read_bytes() == b"old data" and sorted(p.name for p in out.iterdir()) == ["precious.parquet"]


class FailingRig(VirtualRig):
    """Fails (or is interrupted) on the n-th run; records zero_output calls."""

    def __init__(self, fail_on, exc):
        super().__init__()
        self.fail_on, self.exc, self.calls, self.zeroed = fail_on, exc, 0, 0

    def run(self, *args, **kwargs):
        self.calls += 1
        if self.calls == self.fail_on:
            self.output_v = 42.0
            raise self.exc
        return super().run(*args, **kwargs)

    def zero_output(self):
        self.zeroed += 1
        super().zero_output()


@pytest.mark.parametrize("exc, status", [(KeyboardInterrupt(), "interrupted"), (RuntimeError("DAQ on fire"), "failed")])
def test_interruption_is_recorded_and_drive_zeroed(tmp_path, plan, exc, status):
    out = tmp_path / "runs"
    rig = FailingRig(2, exc)
    with pytest.raises((KeyboardInterrupt, Exception)):
        char.characterize(out, plan_path=plan, backend=rig)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["status"] == status
    assert [r["name"] for r in manifest["runs"]] == ["tri"]
    assert rig.output_v == 0.0 and rig.zeroed >= 1
    assert sorted(p.name for p in out.iterdir()) == ["manifest.json", "tri.parquet"]  # nothing half-written
    rf.read_run(out / "tri.parquet")  # what finished is intact


def test_cli_bad_plan_one_line_nonzero_exit_and_nothing_created(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(SMALL_PLAN.replace("level_v = 20.0", "level_v = 400.0"))
    out = tmp_path / "runs"
    res = CliRunner().invoke(cli, ["characterize", "--plan", str(bad), "--out", str(out)])
    assert res.exit_code == 1
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.output
    assert f"{bad}: protocol[3] 'step': drive reaches 400 V, outside the actuator's range -30 to 150 V" in lines[0]
    assert not out.exists()


def test_cli_existing_output_is_refused(tmp_path, plan):
    out = tmp_path / "runs"
    out.mkdir()
    (out / "x").write_text("keep")
    res = CliRunner().invoke(cli, ["characterize", "--plan", str(plan), "--out", str(out)])
    assert res.exit_code == 1 and "already exists and is not empty" in res.output
    assert (out / "x").read_text() == "keep"


def test_cli_prints_progress_and_table(tmp_path, plan):
    res = CliRunner().invoke(cli, ["characterize", "--plan", str(plan), "--out", str(tmp_path / "runs")])
    assert res.exit_code == 0, res.output
    assert "[1/3] tri" in res.output and "[3/3] step" in res.output
    assert "hysteresis" in res.output and "creep" in res.output and "overshoot" in res.output
    assert (tmp_path / "runs" / "characterization.csv").is_file()


# --------------------------------------------------------------------------- backend from the rig file, progress (issue
# 12)


def test_the_backend_comes_from_the_rig_file_unless_overridden(tmp_path):
    from click.testing import CliRunner

    from piezopress.piezocli.main import cli

    rig = Path(__file__).resolve().parents[1] / "rigs" / "nidaq-example.toml"
    res = CliRunner().invoke(cli, ["characterize", "--rig", str(rig), "--out", str(tmp_path / "runs")])
    # the file names the nidaq backend: it is chosen (and, without the driver, says how to install it)
    assert res.exit_code != 0 and "nidaqmx" in res.output and "was asked for" not in res.output, res.output
    res = CliRunner().invoke(
        cli, ["characterize", "--rig", str(rig), "--backend", "virtual", "--out", str(tmp_path / "runs")]
    )
    assert res.exit_code != 0 and "the rig file is for backend 'nidaq'" in res.output, res.output
    assert not (tmp_path / "runs").exists()


def test_progress_gives_the_plan_total_up_front_and_the_backend_fractions(tmp_path):
    from piezopress.pipelines import characterize as char

    events = []
    plan = tmp_path / "plan.toml"
    plan.write_text(
        '[plan]\nname = "two"\n\n[[protocol]]\nname = "a"\nkind = "triangle"\nfreq_hz = 1.0\npeak_v = 20.0\n'
        'cycles = 2\nsample_rate_hz = 1000.0\n\n[[protocol]]\nname = "b"\nkind = "triangle"\nfreq_hz = 1.0\n'
        "peak_v = 30.0\ncycles = 1\nsample_rate_hz = 1000.0\n"
    )
    char.characterize(tmp_path / "runs", plan_path=plan, on_progress=events.append)
    first = events[0]
    assert first.index == 1 and not first.done and first.fraction is None
    assert first.plan_s == pytest.approx(first.remaining_s) and first.plan_s >= 3.0
    fractions = [e.fraction for e in events if e.fraction is not None]
    assert fractions and fractions[-1] == pytest.approx(1.0)  # the virtual rig reports when done
    done = [e for e in events if e.done]
    assert len(done) == 2 and done[-1].remaining_s == pytest.approx(0.0, abs=1e-9)
    assert done[0].remaining_s == pytest.approx(first.plan_s - done[0].protocol.duration_s)


def test_a_simulated_press_records_its_runs_on_its_own_clock(tmp_path, plan):
    """The virtual rig plays a run in a fraction of its duration and pauses between runs in no
    wall time: the runs' recorded starts are its clock's (a drift over the test's hours is read on
    the time it happened in), one run's duration and the pause apart."""
    from datetime import datetime

    from piezopress.acquisition.virtual_rig import PAUSE_S

    char.characterize(tmp_path / "runs", plan_path=plan)
    runs = [rf.read_run(tmp_path / "runs" / f"{n}.parquet") for n in ("tri", "creep", "step")]
    starts = [datetime.fromisoformat(r.meta["started_utc"].replace("Z", "+00:00")).timestamp() for r in runs]
    for a, t0, t1 in zip(runs, starts, starts[1:]):
        expected = a.t_s.size / a.sample_rate_hz + PAUSE_S  # the run on the rig's clock, then its pause
        assert t1 - t0 == pytest.approx(expected, abs=1.0)  # recorded to the second


def test_a_backend_without_a_clock_records_wall_time():
    from datetime import UTC, datetime, timedelta

    from piezopress.acquisition.backend import started_utc

    class Clocked:
        clock_s = 0.0

    class Plain:
        pass

    clocked = Clocked()
    first = datetime.fromisoformat(started_utc(clocked).replace("Z", "+00:00"))
    clocked.clock_s = 3600.0
    later = datetime.fromisoformat(started_utc(clocked).replace("Z", "+00:00"))
    assert later - first == timedelta(hours=1)
    plain = datetime.fromisoformat(started_utc(Plain()).replace("Z", "+00:00"))
    assert abs(plain - datetime.now(UTC)) < timedelta(seconds=5)
