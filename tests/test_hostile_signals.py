"""SIGTERM and SIGHUP during characterize/validate are handled like Ctrl-C on every backend:
the drive ramps to 0 V, the runs finished (and the one cut short) are kept, the manifest says
``interrupted`` with the signal, and the CLI exits 128 + the signal number.

The signals are real: the process sends them to itself (os.kill) from inside a backend's
run, where a rig would be playing."""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path

import pytest
from test_characterize import SMALL_PLAN
from test_nidaq import EXAMPLE, FakeBoard, NidaqBackend, assert_safe_end, load_daq_rig
from test_nidaq import PLAN as NI_PLAN

from piezopress import runformat as rf
from piezopress.acquisition.backend import STOP_SIGNALS, Terminated, stop_signals_interrupt
from piezopress.acquisition.virtual_rig import VirtualRig
from piezopress.pipelines import characterize as char

ROOT = Path(__file__).resolve().parents[1]
SIGNALS = [s for s in (getattr(signal, "SIGTERM", None), getattr(signal, "SIGHUP", None)) if s is not None]


class SignalledRig(VirtualRig):
    """Receives ``signum`` from the outside while playing its ``on``-th run (output at 42 V)."""

    def __init__(self, on: int, signum: int):
        super().__init__()
        self.on, self.signum, self.calls, self.zeroed = on, signum, 0, 0

    def run(self, *args, **kwargs):
        self.calls += 1
        if self.calls == self.on:
            self.output_v = 42.0
            os.kill(os.getpid(), self.signum)  # delivered now: the handler raises here, mid-run
            for _ in range(1000):  # give the interpreter bytecode boundaries at which to run the handler
                pass
            raise AssertionError("the signal was not handled")
        return super().run(*args, **kwargs)

    def zero_output(self):
        self.zeroed += 1
        super().zero_output()


@pytest.mark.parametrize("signum", SIGNALS, ids=lambda s: signal.Signals(s).name)
def test_a_stop_signal_on_the_virtual_rig_zeroes_the_drive_keeps_runs_and_says_interrupted(tmp_path, signum):
    plan = tmp_path / "plan.toml"
    plan.write_text(SMALL_PLAN)
    out = tmp_path / "runs"
    before = signal.getsignal(signum)
    rig = SignalledRig(2, signum)
    with pytest.raises(Terminated) as err:
        char.characterize(out, plan_path=plan, backend=rig)
    assert err.value.signum == signum
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["status"] == "interrupted"
    assert manifest["status_reason"] == f"interrupted by {signal.Signals(signum).name}"
    assert [r["name"] for r in manifest["runs"]] == ["tri"]
    rf.read_run(out / "tri.parquet")  # the finished run is intact
    assert rig.output_v == 0.0 and rig.zeroed >= 1
    assert signal.getsignal(signum) == before  # the handler is only there while the plan runs


class SignallingBoard(FakeBoard):
    """The fake NI board; the process gets ``signum`` during the ``at``-th read of the input."""

    def __init__(self, signum, at, **kw):
        super().__init__(**kw)
        self.signum, self.at, self.reads = signum, at, 0

    def hit(self, task, method, *args):
        super().hit(task, method, *args)
        if (task, method) == ("piezopress-ai", "read"):
            self.reads += 1
            if self.reads == self.at:
                os.kill(os.getpid(), self.signum)
                for _ in range(1000):
                    pass


@pytest.mark.parametrize("signum", SIGNALS, ids=lambda s: signal.Signals(s).name)
def test_a_stop_signal_on_the_fake_ni_board_ramps_down_and_keeps_the_partial_run(tmp_path, signum):
    plan = tmp_path / "plan.toml"
    plan.write_text(NI_PLAN)
    cfg = load_daq_rig(EXAMPLE)
    board = SignallingBoard(signum, 13)  # 11 reads in 'tri', then 'step'
    rig = NidaqBackend(cfg, driver=board)
    out = tmp_path / "runs"
    with pytest.raises(KeyboardInterrupt) as err:
        char.characterize(out, plan_path=plan, backend=rig)
    assert getattr(err.value, "signum", None) == signum
    manifest = json.loads((out / "manifest.json").read_text())
    assert (
        manifest["status"] == "interrupted"
        and manifest["status_reason"] == f"interrupted by {signal.Signals(signum).name}"
    )
    assert [(r["file"], r["status"]) for r in manifest["runs"]] == [
        ("tri.parquet", "complete"),
        ("step.incomplete.parquet", "incomplete"),
    ]
    run = rf.read_run(out / "step.incomplete.parquet", allow_incomplete=True)
    assert len(run.data) == 50 and signal.Signals(signum).name in run.meta["status_reason"]
    assert_safe_end(board, cfg)  # ramped (no jump, no faster than the safe rate) to exactly 0 V, every task closed


def test_the_cli_exits_128_plus_the_signal_and_says_so(tmp_path, monkeypatch):
    from click.testing import CliRunner

    from piezopress.piezocli.main import cli

    plan = tmp_path / "plan.toml"
    plan.write_text(SMALL_PLAN)
    monkeypatch.setattr(char, "make_backend", lambda name, rig: SignalledRig(1, signal.SIGTERM))
    res = CliRunner().invoke(cli, ["characterize", "--out", str(tmp_path / "runs"), "--plan", str(plan)])
    assert res.exit_code == 128 + signal.SIGTERM, res.output
    assert f"Interrupted by signal {int(signal.SIGTERM)}." in res.output
    assert json.loads((tmp_path / "runs" / "manifest.json").read_text())["status"] == "interrupted"


def test_validate_is_stopped_by_sigterm_like_characterize(tmp_path, monkeypatch):
    """validate plays through the same execute_plan: the same handler, the same manifest."""
    from piezopress.pipelines import validate as val

    bundle = ROOT / "sample_runs" / "bundle.json"
    out = tmp_path / "val"
    rig = SignalledRig(1, signal.SIGTERM)
    with pytest.raises(Terminated):
        val.validate(out, bundle, backend=rig)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["kind"] == "validation" and manifest["status"] == "interrupted"
    assert manifest["status_reason"] == "interrupted by SIGTERM" and rig.output_v == 0.0


def test_the_handlers_are_only_installed_in_the_main_thread():
    import threading

    seen = {}

    def worker():
        with stop_signals_interrupt():
            seen["handler"] = signal.getsignal(signal.SIGTERM)

    t = threading.Thread(target=worker)
    t.start()
    t.join()
    assert seen["handler"] == signal.getsignal(signal.SIGTERM)
    assert set(STOP_SIGNALS) >= {signal.SIGTERM}


@pytest.mark.parametrize("signum", SIGNALS, ids=lambda s: signal.Signals(s).name)
def test_a_stop_signal_during_check_rig_zeroes_the_drive(signum):
    from piezopress.pipelines.check_rig import check_rig

    before = signal.getsignal(signum)
    rig = SignalledRig(1, signum)
    with pytest.raises(Terminated) as err:
        check_rig(None, backend=rig)
    assert err.value.signum == signum
    assert rig.output_v == 0.0 and rig.zeroed >= 1
    assert signal.getsignal(signum) == before
