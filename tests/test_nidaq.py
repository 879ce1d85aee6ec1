"""The NI-DAQmx backend without hardware: the exact driver calls of a run, and every interlock.

In the manner of pymeasure's ``expected_protocol``: a fake of the nidaqmx task objects
records every call (configure channels, timing, triggers, write, start, read, stop, close)
and plays a simple press (force = preload + N/V x drive, read on the same clock). A correct
run must make exactly the expected sequence; every interlock is triggered and must leave
the output at 0 V, reached by a ramp no faster than the safe rate, with nothing measured
lost. Real-board tests run only with ``pytest --daq DEVICE``.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from piezopress import runformat as rf
from piezopress.acquisition import daq_config
from piezopress.acquisition.daq_config import DaqRigConfig, load_daq_rig, parse_daq_rig
from piezopress.acquisition.nidaq import (
    NidaqBackend,
    RunInterrupted,
    check_preload,
    drive_problems,
    over_force,
    ramp_to_zero,
)
from piezopress.analysis.rigcheck import rig_check
from piezopress.errors import BackendError, ConfigError, PiezopressError, PlanError
from piezopress.piezocli.main import cli
from piezopress.pipelines import characterize as char
from piezopress.pipelines import check_rig

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "rigs" / "nidaq-example.toml"
GAIN = 20.0  # amplifier gain of the example rig


# --------------------------------------------------------------------------------------
# The fake board
# --------------------------------------------------------------------------------------


class FakeDaqError(Exception):
    """Stands in for nidaqmx.DaqError."""


class FakeBoard:
    """A fake of the nidaqmx driver layer: one board, one analog output, analog inputs.

    ``calls`` records every call as ``(task, method, *args)`` (read timeouts are checked,
    not recorded). ``output`` records what the analog output really put out, in order, as
    ``(source, DAQ volts)`` segments: ``run`` (as the shared clock advances), ``ramp``,
    ``zero``. The press: ``force_n = preload_n + n_per_v * actuator volts`` of the same
    sample; the load cell reads ``sensitivity * force_n + offset``; ``ai1`` (if used) reads
    the amplifier monitor, actuator volts / 20. ``fail`` maps ``(task, method, nth call)``
    to the exception that call raises. ``lead``: samples the output runs ahead of what the
    input has returned (as on hardware, where reads lag the clock).
    """

    def __init__(
        self, *, preload_n=60.0, n_per_v=2.0, sensitivity=0.010003, offset_v=0.0, fail=None, coerce=None, lead=0
    ):
        self.preload_n, self.n_per_v, self.sensitivity, self.offset_v = preload_n, n_per_v, sensitivity, offset_v
        self.fail = dict(fail or {})
        self.coerce = coerce
        self.lead = lead
        self.calls: list[tuple] = []
        self.output: list[tuple[str, np.ndarray]] = []
        self.level = 0.0  # DAQ volts at the analog output now
        self.tasks: list[FakeTask] = []
        self._counts: Counter = Counter()

    # the DaqDriver protocol
    def task(self, name):
        self.hit(name, "Task")
        t = FakeTask(self, name)
        self.tasks.append(t)
        return t

    def hit(self, task, method, *args):
        self.calls.append((task, method, *args))
        self._counts[(task, method)] += 1
        exc = self.fail.get((task, method, self._counts[(task, method)]))
        if exc is not None:
            raise exc

    def emit(self, source, values):
        values = np.asarray(values, dtype=np.float64)
        if values.size:
            self.output.append((source, values.copy()))
            self.level = float(values[-1])

    def volts(self, physical, daq_v):
        actuator_v = np.asarray(daq_v, dtype=np.float64) * GAIN
        if physical.endswith("/ai0"):
            return self.sensitivity * (self.preload_n + self.n_per_v * actuator_v) + self.offset_v
        return actuator_v / 20.0

    def armed_output(self):
        return next((t for t in self.tasks if t.source.endswith("ai/SampleClock") and t.started and not t.closed), None)

    @property
    def open_tasks(self):
        return [t.name for t in self.tasks if not t.closed]


class FakeTask:
    def __init__(self, board, name):
        self.board, self.name = board, name
        self.ai, self.ao = [], None
        self.rate = self.n = None
        self.source = ""
        self.trigger = None
        self.data = None
        self.started = self.closed = False
        self.pos = 0  # samples clocked (input) / generated (output on the input's clock)

    def add_ai_voltage_chan(self, physical_channel, min_val, max_val, terminal_config):
        self.board.hit(self.name, "add_ai_voltage_chan", physical_channel, min_val, max_val, terminal_config)
        self.ai.append(physical_channel)

    def add_ao_voltage_chan(self, physical_channel, min_val, max_val):
        self.board.hit(self.name, "add_ao_voltage_chan", physical_channel, min_val, max_val)
        self.ao = (physical_channel, min_val, max_val)

    def cfg_samp_clk_timing(self, rate, samps_per_chan, source=""):
        self.board.hit(self.name, "cfg_samp_clk_timing", rate, samps_per_chan, source)
        self.rate, self.n, self.source = rate, samps_per_chan, source

    def cfg_dig_edge_start_trig(self, trigger_source):
        self.board.hit(self.name, "cfg_dig_edge_start_trig", trigger_source)
        self.trigger = trigger_source

    def samp_clk_rate(self):
        self.board.hit(self.name, "samp_clk_rate")
        return self.board.coerce(self.rate) if self.board.coerce else self.rate

    def write(self, data, auto_start=False):
        data = np.array(data, dtype=np.float64)
        self.board.hit(self.name, "write", data, auto_start)
        assert self.ao is not None and np.all(data >= self.ao[1]) and np.all(data <= self.ao[2]), (
            "write outside the output range"
        )
        if self.rate is None:  # on demand
            assert auto_start and data.size == 1
            self.board.emit(self.name.split("-")[-1], data)
        else:
            assert not auto_start and len(data) == self.n
            self.data = data
        return len(data)

    def start(self):
        self.board.hit(self.name, "start")
        self.started = True
        if self.ao is not None and not self.source:  # own clock: the hardware plays the whole buffer
            self.board.emit("ramp", self.data)
            self.pos = len(self.data)

    def read(self, number_of_samples_per_channel, timeout):
        k = number_of_samples_per_channel
        self.board.hit(self.name, "read", k)
        assert self.started and self.pos + k <= self.n, "read past the end of a finite acquisition"
        assert timeout >= k / self.rate, f"timeout {timeout} s shorter than the {k / self.rate} s the samples take"
        out = self.board.armed_output()
        if out is not None:
            drive = out.data[self.pos : self.pos + k]
            new = min(out.n, self.pos + k + self.board.lead)
            self.board.emit("run", out.data[out.pos : new])
            out.pos = new
        else:
            drive = np.full(k, self.board.level)
        self.pos += k
        return np.vstack([self.board.volts(ch, drive) for ch in self.ai])

    def wait_until_done(self, timeout):
        self.board.hit(self.name, "wait_until_done")
        assert self.ao is None or self.pos == self.n, "output not finished"

    def total_samp_per_chan_generated(self):
        self.board.hit(self.name, "total_samp_per_chan_generated")
        return self.pos

    def stop(self):
        self.board.hit(self.name, "stop")

    def close(self):
        self.board.hit(self.name, "close")
        self.closed = True


def same_calls(actual, expected):
    """Call lists equal, comparing arrays by value (exact)."""
    assert len(actual) == len(expected), "\n".join(map(str, actual))
    for a, e in zip(actual, expected):
        assert len(a) == len(e) and all(
            np.array_equal(x, y) if isinstance(x, np.ndarray) or isinstance(y, np.ndarray) else x == y
            for x, y in zip(a, e)
        ), f"call {a} != expected {e}"


def assert_safe_end(board, cfg):
    """The output ends at exactly 0 V, every task is closed, and every ramp starts where the
    output was and never moves faster than the safe rate (tolerance: 1e-9 relative, rounding)."""
    assert board.level == 0.0
    assert board.open_tasks == []
    assert board.output and board.output[-1][0] == "zero" and board.output[-1][1].tolist() == [0.0]
    level = 0.0
    rate_daq = cfg.safety.ramp_down_v_per_s / cfg.amplifier.gain
    for source, values in board.output:
        if source == "ramp":
            assert values[0] == pytest.approx(level, abs=1e-12), (
                "ramp does not start from the last output value (a jump)"
            )
            assert np.max(np.abs(np.diff(values))) * cfg.safety.ramp_sample_rate_hz <= rate_daq * (1 + 1e-9)
            assert values[-1] == 0.0
        level = values[-1]


@pytest.fixture
def cfg():
    return load_daq_rig(EXAMPLE)


def backend_with(cfg, **board_kwargs):
    board = FakeBoard(**board_kwargs)
    return NidaqBackend(cfg, driver=board), board


FS = 1000.0


def tri(peak_v=100.0, n=401, end_v=0.0):
    """A triangle 0 -> peak -> end over n samples."""
    half = n // 2
    return np.r_[np.linspace(0.0, peak_v, half + 1), np.linspace(peak_v, end_v, n - half)[1:]]


def preload_calls(cfg):
    n = int(round(cfg.safety.preload_read_s * cfg.safety.preload_sample_rate_hz))
    return [
        ("piezopress-preload", "Task"),
        ("piezopress-preload", "add_ai_voltage_chan", "Dev1/ai0", -10.0, 10.0, "diff"),
        ("piezopress-preload", "cfg_samp_clk_timing", cfg.safety.preload_sample_rate_hz, n, ""),
        ("piezopress-preload", "start"),
        ("piezopress-preload", "read", n),
        ("piezopress-preload", "stop"),
        ("piezopress-preload", "close"),
    ]


def zero_calls():
    return [
        ("piezopress-zero", "Task"),
        ("piezopress-zero", "add_ao_voltage_chan", "Dev1/ao0", -10.0, 10.0),
        ("piezopress-zero", "write", np.zeros(1), True),
        ("piezopress-zero", "stop"),
        ("piezopress-zero", "close"),
    ]


# --------------------------------------------------------------------------------------
# The driver boundary: the exact sequence of a correct run
# --------------------------------------------------------------------------------------


def test_correct_run_makes_exactly_the_expected_calls(cfg):
    rig, board = backend_with(cfg)
    v = tri(100.0, 401)  # ends at 0 V: no ramp needed, 0 V written all the same
    n, chunk = len(v), int(round(cfg.daq.chunk_s * FS))
    m = rig.run(v, FS, preload_n=50.0, label="tri")
    expected = preload_calls(cfg) + [
        ("piezopress-ai", "Task"),
        ("piezopress-ai", "add_ai_voltage_chan", "Dev1/ai0", -10.0, 10.0, "diff"),
        ("piezopress-ai", "cfg_samp_clk_timing", FS, n, ""),
        ("piezopress-ai", "samp_clk_rate"),
        ("piezopress-ao", "Task"),
        ("piezopress-ao", "add_ao_voltage_chan", "Dev1/ao0", -10.0, 10.0),
        ("piezopress-ao", "cfg_samp_clk_timing", FS, n, "/Dev1/ai/SampleClock"),  # one clock: the input's
        ("piezopress-ao", "cfg_dig_edge_start_trig", "/Dev1/ai/StartTrigger"),  # one start trigger
        ("piezopress-ao", "write", v / GAIN, False),
        ("piezopress-ao", "start"),  # armed first ...
        ("piezopress-ai", "start"),  # ... the input's start starts both
        *[("piezopress-ai", "read", min(chunk, n - i)) for i in range(0, n, chunk)],
        ("piezopress-ao", "wait_until_done"),
        ("piezopress-ao", "stop"),
        ("piezopress-ai", "stop"),
        ("piezopress-ao", "total_samp_per_chan_generated"),
        ("piezopress-ao", "close"),
        ("piezopress-ai", "close"),
        *zero_calls(),
    ]
    same_calls(board.calls, expected)
    assert m.complete and m.reason == ""
    # volts -> newtons with the rig's sensitivity and offset; exact but for float rounding
    np.testing.assert_allclose(m.channels["force_n"], 60.0 + 2.0 * v, rtol=0, atol=1e-9)
    assert m.info["preload_measured_n"] == pytest.approx(60.0, abs=1e-9)
    assert m.info["sample_rate_achieved_hz"] == FS and m.info["samples_measured"] == n
    assert_safe_end(board, cfg)


def test_optional_channels_are_read_on_the_same_task_and_converted(cfg):
    cfg = cfg.replace(monitor={"channel": "ai1", "scale_v_per_v": 20.0}, load_cell={"offset_v": 0.25})
    rig, board = backend_with(cfg, offset_v=0.25)
    v = tri(50.0, 201)
    m = rig.run(v, FS, preload_n=50.0, label="tri")
    adds = [c for c in board.calls if c[0] == "piezopress-ai" and c[1] == "add_ai_voltage_chan"]
    assert [c[2] for c in adds] == ["Dev1/ai0", "Dev1/ai1"]
    np.testing.assert_allclose(m.channels["force_n"], 60.0 + 2.0 * v, atol=1e-9)  # the 0.25 V offset removed
    np.testing.assert_allclose(m.channels["monitor_v"], v, atol=1e-9)  # monitor volts x 20 = actuator volts


def test_the_thin_layer_makes_the_nidaqmx_calls(monkeypatch):
    """The real layer against a stand-in nidaqmx module: the API names and arguments it uses."""
    import enum
    import types
    from unittest import mock

    from piezopress.acquisition.nidaq import NidaqmxDriver

    class TerminalConfiguration(enum.Enum):
        DEFAULT, RSE, NRSE, DIFF, PSEUDO_DIFF = -1, 10083, 10078, 10106, 12529

    class Edge(enum.Enum):
        RISING, FALLING = 10280, 10171

    class AcquisitionType(enum.Enum):
        FINITE, CONTINUOUS = 10178, 10123

    nidaqmx = mock.MagicMock(name="nidaqmx")
    nidaqmx.constants.TerminalConfiguration, nidaqmx.constants.Edge, nidaqmx.constants.AcquisitionType = (
        TerminalConfiguration,
        Edge,
        AcquisitionType,
    )
    readers = types.ModuleType("nidaqmx.stream_readers")

    class AnalogMultiChannelReader:
        def __init__(self, stream):
            assert stream is task.in_stream

        def read_many_sample(self, data, number_of_samples_per_channel, timeout):
            data[:] = 1.5
            return number_of_samples_per_channel

    readers.AnalogMultiChannelReader = AnalogMultiChannelReader
    monkeypatch.setitem(sys.modules, "nidaqmx", nidaqmx)
    monkeypatch.setitem(sys.modules, "nidaqmx.stream_readers", readers)
    task = nidaqmx.Task.return_value
    t = NidaqmxDriver().task("piezopress-ai")
    t.add_ai_voltage_chan("Dev1/ai0", -10.0, 10.0, "diff")
    task.ai_channels.add_ai_voltage_chan.assert_called_once_with(
        "Dev1/ai0", terminal_config=TerminalConfiguration.DIFF, min_val=-10.0, max_val=10.0
    )
    t.add_ao_voltage_chan("Dev1/ao0", -10.0, 10.0)
    task.ao_channels.add_ao_voltage_chan.assert_called_once_with("Dev1/ao0", min_val=-10.0, max_val=10.0)
    t.cfg_samp_clk_timing(1000.0, 500, source="/Dev1/ai/SampleClock")
    task.timing.cfg_samp_clk_timing.assert_called_once_with(
        1000.0,
        source="/Dev1/ai/SampleClock",
        active_edge=Edge.RISING,
        sample_mode=AcquisitionType.FINITE,
        samps_per_chan=500,
    )
    t.cfg_dig_edge_start_trig("/Dev1/ai/StartTrigger")
    task.triggers.start_trigger.cfg_dig_edge_start_trig.assert_called_once_with(
        "/Dev1/ai/StartTrigger", trigger_edge=Edge.RISING
    )
    out = t.read(4, 2.5)
    assert out.shape == (1, 4) and np.all(out == 1.5)
    task.write.return_value = 3
    assert t.write(np.array([0.0, 0.1, 0.2])) == 3
    args, kwargs = task.write.call_args
    assert np.array_equal(args[0], [0.0, 0.1, 0.2]) and kwargs["auto_start"] is False
    t.write(np.zeros(1), auto_start=True)  # on demand: one scalar
    args, kwargs = task.write.call_args
    assert args[0] == 0.0 and isinstance(args[0], float) and kwargs["auto_start"] is True
    task.out_stream.total_samp_per_chan_generated = 42
    task.timing.samp_clk_rate = 1000.0
    assert t.total_samp_per_chan_generated() == 42 and t.samp_clk_rate() == 1000.0
    nidaqmx.Task.side_effect = type("DaqNotFoundError", (Exception,), {})("libnidaqmx.so not found")
    with pytest.raises(BackendError, match="NI-DAQmx .* is not installed.*installdriver"):
        NidaqmxDriver().task("x")


# --------------------------------------------------------------------------------------
# Interlocks before a run: nothing is output
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "drive, key",
    [
        (tri(160.0), "[actuator] drive_min_v/drive_max_v"),  # PSt 150: 150 V at most
        (-tri(40.0), "[actuator] drive_min_v/drive_max_v"),  # -30 V at least
        (np.r_[0.0, 0.0, 150.0, 150.0, 0.0], "slew_limit_v_per_s"),  # a 150 V step in one sample at 1 kHz: 1.5e5 V/s
    ],
)
def test_drive_outside_the_actuator_limits_is_refused_before_any_call(cfg, drive, key):
    cfg = cfg.replace(actuator={"slew_limit_v_per_s": 1.0e5})
    rig, board = backend_with(cfg)
    with pytest.raises(BackendError, match="drive refused") as err:
        rig.run(drive, FS, preload_n=50.0, label="x")
    assert key in str(err.value)
    assert board.calls == [] and board.level == 0.0  # the hardware was not touched


def test_drive_outside_the_amplifier_and_output_range_is_refused_before_any_call(cfg):
    cfg = cfg.replace(amplifier={"output_max_v": 120.0, "gain": 10.0})  # 10 x 10 V: 100 V at most from the board
    rig, board = backend_with(cfg)
    with pytest.raises(BackendError) as err:
        rig.run(tri(130.0), FS, preload_n=50.0, label="x")
    assert "[amplifier] output_min_v/output_max_v" in str(err.value) and "[daq] ao_min_v/ao_max_v x 10" in str(
        err.value
    )
    assert board.calls == [] and board.level == 0.0


def test_slew_limit_counts_the_first_sample_from_rest(cfg):
    # 1 V at 1 kHz is 1000 V/s: a drive that starts at 10 V jumps 10 V from rest
    cfg = cfg.replace(actuator={"slew_limit_v_per_s": 5000.0})
    assert drive_problems(np.linspace(0, 10, 11), FS, cfg) == []
    problems = drive_problems(np.full(11, 10.0), FS, cfg)
    assert (
        len(problems) == 1
        and "from the output at rest to the first sample" in problems[0]
        and "1e+04 V/s" in problems[0]
    )


@pytest.mark.parametrize(
    "preload_n, words", [(40.0, "below [safety] preload_min_n = 50 N"), (250.0, "above [safety] safe_force_n = 200 N")]
)
def test_preload_is_read_and_the_run_refused_outside_the_safe_band(cfg, preload_n, words):
    rig, board = backend_with(cfg, preload_n=preload_n)
    with pytest.raises(BackendError, match="run refused") as err:
        rig.run(tri(100.0), FS, preload_n=50.0, label="x")
    assert words in str(err.value)
    same_calls(board.calls, preload_calls(cfg))  # only the short read of the load cell ...
    assert board.output == [] and board.level == 0.0  # ... the output never moved
    assert board.open_tasks == []


def test_check_preload_limits_are_inclusive_and_nan_refused(cfg):
    check_preload(50.0, cfg.safety)  # exactly the minimum: allowed
    check_preload(200.0, cfg.safety)
    with pytest.raises(BackendError, match="finite"):
        check_preload(float("nan"), cfg.safety)


def test_a_rate_the_board_cannot_run_exactly_is_refused_before_output(cfg):
    rig, board = backend_with(cfg, coerce=lambda r: 80e6 / round(80e6 / r) * 1.0001)
    with pytest.raises(BackendError, match="choose a sample rate"):
        rig.run(tri(100.0), FS, preload_n=50.0, label="x")
    assert not any(c[1] == "write" for c in board.calls) and board.output == [] and board.open_tasks == []


def test_a_driver_error_while_configuring_is_refused_before_output(cfg):
    rig, board = backend_with(cfg, fail={("piezopress-ao", "add_ao_voltage_chan", 1): FakeDaqError("device not found")})
    with pytest.raises(BackendError, match="nothing was output.*device not found"):
        rig.run(tri(100.0), FS, preload_n=50.0, label="x")
    assert board.output == [] and board.open_tasks == []


# --------------------------------------------------------------------------------------
# During and after a run: over-force, Ctrl-C, exceptions, driver errors, normal end
# --------------------------------------------------------------------------------------


def measured_ok(m, board, v, upto):
    """Nothing measured is lost: the measurement holds the first ``upto`` samples, exactly as read."""
    assert not m.complete and m.reason
    assert len(m.channels["force_n"]) == upto == m.info["samples_measured"]
    np.testing.assert_allclose(m.channels["force_n"], board.preload_n + board.n_per_v * v[:upto], atol=1e-9)


def test_normal_end_away_from_zero_ramps_down_at_the_safe_rate(cfg):
    rig, board = backend_with(cfg)
    v = tri(100.0, 401, end_v=100.0)  # ends at 100 V
    m = rig.run(v, FS, preload_n=50.0, label="x")
    assert m.complete
    ramp = board.output[-2]
    assert ramp[0] == "ramp" and ramp[1][0] == pytest.approx(100.0 / GAIN)
    # 100 V at 500 V/s is 0.2 s: 200 steps at 1 kHz, each 0.5 V (0.025 DAQ V)
    assert len(ramp[1]) == 201 and m.info["ramp_down"]["samples"] == 201
    assert_safe_end(board, cfg)


def test_over_force_aborts_ramps_down_and_keeps_what_was_measured(cfg):
    # 5 N/V: 60 + 5 x 100 = 560 N at the peak, above the 500 N over-force level (reached at 88 V)
    rig, board = backend_with(cfg, n_per_v=5.0, lead=7)
    v = tri(100.0, 401)
    m = rig.run(v, FS, preload_n=50.0, label="x")
    chunk = int(round(cfg.daq.chunk_s * FS))
    first_bad = int(np.argmax(60 + 5 * v > 500.0))
    upto = (first_bad // chunk + 1) * chunk  # the chunk holding the over-force sample is kept too
    assert m.reason.startswith("over-force") and "above [safety] over_force_n = 500 N" in m.reason
    measured_ok(m, board, v, upto)
    # the output ran 7 samples ahead of the reads: the ramp starts from the value it really reached
    assert m.info["last_output_v"] == pytest.approx(v[upto + 7 - 1])
    assert not any(c == ("piezopress-ao", "wait_until_done") for c in board.calls)
    assert_safe_end(board, cfg)


def test_ctrl_c_during_a_run_ramps_down_then_reraises_with_the_data(cfg):
    rig, board = backend_with(cfg, fail={("piezopress-ai", "read", 3): KeyboardInterrupt()})
    v = tri(100.0, 401)
    with pytest.raises(RunInterrupted) as err:
        rig.run(v, FS, preload_n=50.0, label="x")
    assert isinstance(err.value, KeyboardInterrupt)
    m = err.value.measurement
    assert "interrupted by the user" in m.reason
    measured_ok(m, board, v, 2 * int(round(cfg.daq.chunk_s * FS)))
    assert_safe_end(board, cfg)


def test_driver_error_during_a_run_ramps_down_and_returns_the_data(cfg):
    rig, board = backend_with(cfg, fail={("piezopress-ai", "read", 4): FakeDaqError("-200279: buffer overflow")})
    v = tri(100.0, 401)
    m = rig.run(v, FS, preload_n=50.0, label="x")
    assert "FakeDaqError: -200279: buffer overflow" in m.reason
    measured_ok(m, board, v, 3 * int(round(cfg.daq.chunk_s * FS)))
    assert_safe_end(board, cfg)


def test_an_exception_in_our_own_code_during_a_run_ramps_down_and_returns_the_data(cfg):
    rig, board = backend_with(cfg)
    v = tri(100.0, 401)

    def progress(fraction):
        if fraction > 0.3:
            raise RuntimeError("display crashed")

    m = rig.run(v, FS, preload_n=50.0, label="x", progress=progress)
    assert "RuntimeError: display crashed" in m.reason
    measured_ok(m, board, v, 150)  # 3 chunks of 50: the third brought it past 30 %
    assert_safe_end(board, cfg)


def test_ctrl_c_during_the_ramp_down_is_deferred_until_the_ramp_is_done(cfg):
    fail = {("piezopress-ramp", "wait_until_done", 1): KeyboardInterrupt()}
    rig, board = backend_with(cfg, fail=fail, n_per_v=5.0)
    v = tri(100.0, 401)
    with pytest.raises(RunInterrupted) as err:
        rig.run(v, FS, preload_n=50.0, label="x")
    waits = [c for c in board.calls if c[0] == "piezopress-ramp" and c[1] == "wait_until_done"]
    assert len(waits) == 2  # waited again: the ramp was not cut short by closing its task
    assert err.value.measurement.reason.startswith("over-force")
    assert_safe_end(board, cfg)


def test_a_failed_ramp_still_writes_zero_and_says_so(cfg):
    rig, board = backend_with(cfg, n_per_v=5.0, fail={("piezopress-ramp", "start", 1): FakeDaqError("ramp refused")})
    m = rig.run(tri(100.0, 401), FS, preload_n=50.0, label="x")
    assert "ramp-down failed, 0 V written directly" in m.reason and m.info["output_zeroed"]
    assert board.level == 0.0 and board.open_tasks == []


def test_output_not_confirmed_at_zero_is_reported_and_retried_before_the_next_run(cfg):
    rig, board = backend_with(cfg, fail={("piezopress-zero", "write", 1): FakeDaqError("device gone")})
    v = tri(100.0, 401, end_v=40.0)
    m = rig.run(v, FS, preload_n=50.0, label="x")
    assert not m.complete and "OUTPUT NOT CONFIRMED AT 0 V" in m.reason and not m.info["output_zeroed"]
    board.calls.clear()
    rig.run(tri(50.0, 201), FS, preload_n=50.0, label="y")  # 0 V written first (the ramp got there), then the run
    same_calls(board.calls[:5], zero_calls())
    assert board.calls[5] == ("piezopress-preload", "Task")
    assert_safe_end(board, cfg)


def test_zero_output_is_safe_to_call_any_time(cfg):
    rig, board = backend_with(cfg)
    rig.zero_output()
    rig.zero_output()
    assert board.calls == []  # known to be at 0 V: nothing to do


# --------------------------------------------------------------------------------------
# The pure interlock functions
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "from_v, rate, fs", [(7.5, 25.0, 1000.0), (-1.5, 25.0, 1000.0), (0.3, 1.0, 7.0), (5.0, 1e6, 1000.0)]
)
def test_ramp_to_zero_starts_where_the_output_is_ends_at_zero_and_respects_the_rate(from_v, rate, fs):
    ramp = ramp_to_zero(from_v, rate, fs)
    assert ramp[0] == from_v and ramp[-1] == 0.0
    assert np.max(np.abs(np.diff(ramp))) * fs <= rate * (1 + 1e-12)  # rounding only
    assert np.all(np.diff(ramp) * np.sign(from_v) <= 0)  # monotonic: straight down
    assert len(ramp) - 1 == int(np.ceil(abs(from_v) / (rate / fs) - 1e-12))  # no slower than needed


def test_ramp_from_zero_is_a_single_zero():
    assert ramp_to_zero(0.0, 25.0, 1000.0).tolist() == [0.0]


def test_over_force_names_the_first_sample_above_the_level_and_treats_nan_as_over(cfg):
    assert over_force(np.array([100.0, 500.0]), 0, FS, cfg.safety) == ""  # at the level: fine
    r = over_force(np.array([100.0, 501.0, 600.0]), 1000, FS, cfg.safety)
    assert "501.0 N at t = 1.001 s (sample 1001)" in r
    assert over_force(np.array([100.0, np.nan]), 0, FS, cfg.safety).startswith("over-force")


# --------------------------------------------------------------------------------------
# Through characterize: partial runs kept as NAME.incomplete.parquet
# --------------------------------------------------------------------------------------

PLAN = """
[plan]
name = "small"
preload_n = 50.0

[[protocol]]
name = "tri"
kind = "triangle"
freq_hz = 2.0
cycles = 1
peak_v = 100.0
sample_rate_hz = 1000.0

[[protocol]]
name = "step"
kind = "step"
level_v = 20.0
hold_s = 0.2
sample_rate_hz = 1000.0
"""


@pytest.fixture
def plan(tmp_path):
    p = tmp_path / "plan.toml"
    p.write_text(PLAN)
    return p


def test_characterize_on_the_fake_board_writes_complete_runs(tmp_path, plan, cfg):
    rig, board = backend_with(cfg)
    char.characterize(tmp_path / "runs", plan_path=plan, backend=rig)
    manifest = json.loads((tmp_path / "runs" / "manifest.json").read_text())
    assert manifest["status"] == "complete" and manifest["rig"]["backend"] == "nidaq"
    run = rf.read_run(tmp_path / "runs" / "tri.parquet")
    np.testing.assert_allclose(run.data["force_n"], 60.0 + 2.0 * run.command_v, atol=1e-9)
    assert run.meta["backend_info"]["preload_measured_n"] == pytest.approx(60.0)
    assert_safe_end(board, cfg)


def test_characterize_keeps_an_over_force_run_as_incomplete_and_stops(tmp_path, plan, cfg):
    rig, board = backend_with(cfg, n_per_v=5.0)
    out = tmp_path / "runs"
    with pytest.raises(BackendError, match="over-force"):
        char.characterize(out, plan_path=plan, backend=rig)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["status"] == "failed"
    assert [(r["file"], r["status"]) for r in manifest["runs"]] == [("tri.incomplete.parquet", "incomplete")]
    run = rf.read_run(out / "tri.incomplete.parquet", allow_incomplete=True)
    assert run.meta["status"] == "incomplete" and run.meta["status_reason"].startswith("over-force")
    np.testing.assert_allclose(run.data["force_n"], 60.0 + 5.0 * run.command_v, atol=1e-9)  # every sample read is there
    assert len(run.data) == run.meta["backend_info"]["samples_measured"] == 250
    with pytest.raises(rf.RunFormatError, match="incomplete"):
        rf.read_run(out / "tri.incomplete.parquet")  # never mistaken for a finished run
    assert_safe_end(board, cfg)


def test_characterize_keeps_a_run_cut_by_ctrl_c_as_incomplete_and_says_interrupted(tmp_path, plan, cfg):
    rig, board = backend_with(
        cfg, fail={("piezopress-ai", "read", 13): KeyboardInterrupt()}
    )  # 11 reads in 'tri', then 'step'
    out = tmp_path / "runs"
    with pytest.raises(KeyboardInterrupt):
        char.characterize(out, plan_path=plan, backend=rig)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["status"] == "interrupted"
    assert [(r["file"], r["status"]) for r in manifest["runs"]] == [
        ("tri.parquet", "complete"),
        ("step.incomplete.parquet", "incomplete"),
    ]
    run = rf.read_run(out / "step.incomplete.parquet", allow_incomplete=True)
    assert len(run.data) == 50 and "interrupted by the user" in run.meta["status_reason"]
    assert_safe_end(board, cfg)


def test_characterize_checks_every_drive_before_anything_runs(tmp_path, plan, cfg):
    rig, board = backend_with(cfg.replace(actuator={"slew_limit_v_per_s": 1000.0}))  # the 20 V step is 2e4 V/s
    with pytest.raises(PlanError, match="protocol\\[2\\] 'step'.*slew limit"):
        char.characterize(tmp_path / "runs", plan_path=plan, backend=rig)
    assert board.calls == [] and not (tmp_path / "runs").exists()


# --------------------------------------------------------------------------------------
# Choosing the backend; nidaqmx missing
# --------------------------------------------------------------------------------------


@pytest.fixture
def no_nidaqmx(monkeypatch):
    """As in CI: the nidaqmx package cannot be imported (None in sys.modules makes import fail)."""
    monkeypatch.setitem(sys.modules, "nidaqmx", None)


def test_nidaq_backend_without_nidaqmx_is_one_line_with_the_install_command(no_nidaqmx):
    with pytest.raises(PiezopressError) as err:
        char.make_backend("nidaq", EXAMPLE)
    msg = str(err.value)
    assert "\n" not in msg and "pip install nidaqmx" in msg and "[nidaq]" in msg and "ni.com" in msg


def test_cli_characterize_nidaq_without_nidaqmx_one_line_and_nothing_created(tmp_path, no_nidaqmx):
    out = tmp_path / "runs"
    res = CliRunner().invoke(cli, ["characterize", "--backend", "nidaq", "--rig", str(EXAMPLE), "--out", str(out)])
    assert res.exit_code == 1 and "Traceback" not in res.output
    from piezopress.acquisition.nidaq import INSTALL_HINT

    assert res.output.strip().splitlines() == [
        f"Error: the nidaq backend needs the nidaqmx package, which is not installed: {INSTALL_HINT}"
    ]
    assert not out.exists()


def test_make_backend_follows_the_rig_file_and_refuses_a_mismatch(tmp_path):
    assert char.make_backend("virtual", char.DEFAULT_RIG).name == "virtual"
    assert char.make_backend("virtual", None).name == "virtual"
    assert char.make_backend(None, char.DEFAULT_RIG).name == "virtual"
    with pytest.raises(BackendError, match="is for backend 'nidaq'.*pass --backend nidaq"):
        char.make_backend("virtual", EXAMPLE)
    with pytest.raises(BackendError, match="is for backend 'virtual'.*pass --backend virtual"):
        char.make_backend("nidaq", char.DEFAULT_RIG)
    odd = tmp_path / "odd.toml"
    odd.write_text('[rig]\nbackend = "labjack"\n')
    unknown = "backend = 'labjack': no backend of that name; expected one of nidaq, none, virtual"
    with pytest.raises(ConfigError, match=unknown):
        char.make_backend(None, odd)


def test_a_bad_rig_file_is_reported_before_the_driver_is_loaded(tmp_path, no_nidaqmx):
    bad = tmp_path / "bad.toml"
    bad.write_text(EXAMPLE.read_text().replace("over_force_n = 500.0", "over_force_n = 5000.0"))
    with pytest.raises(ConfigError, match="over_force_n"):  # the config error, not the missing package
        char.make_backend("nidaq", bad)


# --------------------------------------------------------------------------------------
# The hardware rig file
# --------------------------------------------------------------------------------------


def test_example_rig_parses_and_documents_every_key():
    cfg = load_daq_rig(EXAMPLE)
    assert cfg.limits.drive_min_v == -30.0 and cfg.limits.drive_max_v == 150.0 and cfg.limits.max_force_n == 200.0
    text = EXAMPLE.read_text()
    for sec, cls in daq_config.SECTIONS.items():
        assert f"[{sec}]" in text
        for f in dataclasses.fields(cls):
            assert f"\n{f.name} = " in text, f"[{sec}] {f.name} is not in the example file"
    assert cfg == parse_daq_rig(DaqRigConfig().as_dict(), source=str(EXAMPLE)).replace(
        rig={"name": "press 1 (NI-DAQmx)"}
    )


def test_every_problem_of_a_rig_file_is_reported_at_once_with_section_and_key():
    doc = DaqRigConfig().as_dict()
    doc["daq"]["colour"] = "blue"
    doc["daq"]["chunk_s"] = 0.0
    doc["amplifier"]["gain"] = "twenty"
    doc["safety"]["ramp_down_v_per_s"] = -5.0
    doc["flux"] = {}
    with pytest.raises(ConfigError) as err:
        parse_daq_rig(doc, source="r.toml")
    p = err.value.problems
    assert len(p) == 5
    assert "unknown section [flux]" in p[0]
    assert any("[daq] unknown key 'colour'" in x for x in p)
    assert any("[daq] chunk_s = 0.0: outside the allowed range (0, 10] s" in x for x in p)
    assert any("[amplifier] gain = 'twenty': expected float" in x for x in p)
    assert any("[safety] ramp_down_v_per_s = -5.0: outside the allowed range (0, 1e+06] V/s" in x for x in p)


def test_relations_between_keys_are_checked():
    doc = DaqRigConfig().as_dict()
    doc["rig"]["backend"] = "virtual"
    doc["daq"]["ao_channel"] = "a0"
    doc["daq"]["ai_terminal"] = "diffy"
    doc["daq"]["ao_min_v"] = 1.0
    doc["monitor"]["channel"] = "ai0"  # already the load cell
    doc["safety"]["preload_min_n"] = 300.0
    doc["load_cell"]["sensitivity_v_per_n"] = 0.04  # 10 V is 250 N: cannot see 500 N
    with pytest.raises(ConfigError) as err:
        parse_daq_rig(doc, source="r.toml")
    text = str(err.value)
    for words in (
        "[rig] backend = 'virtual'",
        "[daq] ao_channel = 'a0'",
        "[daq] ai_terminal = 'diffy'",
        "[daq] analog output range 1 to 10 V must include 0 V",
        "[monitor] channel = 'ai0' is already the [load_cell] channel",
        "[safety] preload_min_n = 300 N must be below safe_force_n = 200 N",
        "over_force_n = 500 N is above what the load cell can read",
    ):
        assert words in text


# --------------------------------------------------------------------------------------
# check-rig
# --------------------------------------------------------------------------------------


def test_rig_check_analysis_on_known_signals():
    rng = np.random.default_rng(1)
    v = np.r_[np.zeros(1000), 1 - np.cos(np.linspace(0, 6 * np.pi, 3000))]
    noise = rng.normal(0.0, 0.05, v.size)
    r = rig_check(v, 50.0 + 2.0 * v + noise, 1000)
    assert r.follows and r.correlation > 0.99
    assert r.gain_n_per_v == pytest.approx(2.0, rel=0.01)  # 0.05 N noise over a 4 N swing: well under 1 %
    assert r.offset_n == pytest.approx(50.0, abs=0.01)  # mean of 1000 samples: 0.05/sqrt(1000) = 0.0016 N
    assert r.noise_rms_n == pytest.approx(0.05, rel=0.1)  # 1000 samples: about 2 % spread
    backwards = rig_check(v, 50.0 - 2.0 * v + noise, 1000)
    assert not backwards.follows and backwards.gain_n_per_v < 0  # load cell wired backwards
    unplugged = rig_check(v, 0.0 + noise, 1000)
    assert not unplugged.follows


def test_check_rig_on_the_virtual_rig_cli():
    res = CliRunner().invoke(cli, ["check-rig", "--rig", str(char.DEFAULT_RIG)])
    assert res.exit_code == 0, res.output
    assert "verdict:        OK" in res.output and "achieved simulated (exact)" in res.output
    r = check_rig.check_rig(char.DEFAULT_RIG)
    assert r.check.correlation > 0.95  # hysteresis and the 0.49 N ADC step bend a 4 N swing only a little
    assert 1.0 < r.check.gain_n_per_v < 2.0  # 2 N/V press, 78 % of it without deadband at this amplitude
    assert r.check.offset_n == pytest.approx(50.0, abs=0.5)  # the 50 N preload, within one ADC step
    assert r.check.noise_rms_n < 0.5  # below one ADC step


def test_check_rig_on_the_fake_board_reports_the_rates_and_the_preload(cfg):
    rig, board = backend_with(cfg)
    r = check_rig.check_rig(None, backend=rig)
    assert r.sample_rate_achieved_hz == 1000.0 and r.samples_measured == r.samples_planned
    assert r.preload_measured_n == pytest.approx(60.0)
    assert r.check.follows and r.check.gain_n_per_v == pytest.approx(2.0, rel=1e-9)  # the fake press is linear
    assert r.check.noise_rms_n == pytest.approx(0.0, abs=1e-9)
    assert "preload read:   60.00 N" in check_rig.format_report(r)
    assert_safe_end(board, cfg)


def test_check_rig_cli_without_nidaqmx_is_one_line(no_nidaqmx):
    res = CliRunner().invoke(cli, ["check-rig", "--rig", str(EXAMPLE)])
    assert (
        res.exit_code == 1
        and len(res.output.strip().splitlines()) == 1
        and "pip install nidaqmx" in res.output
        and "[nidaq]" in res.output
    )


# --------------------------------------------------------------------------------------
# A real board, only with `pytest --daq DEVICE`
# --------------------------------------------------------------------------------------


@pytest.mark.daq
def test_real_board_loopback(daq_device):
    """On a real board with ao0 wired to ai0 (a loopback wire, no amplifier, no press).

    Sensitivity 1 V/N so "force" is volts + 0.5 (an offset that makes the preload read
    0.5 > 0.1); the drive is a 0 -> 1 V -> 0 raised cosine at the board (20 V "actuator").
    """
    cfg = load_daq_rig(EXAMPLE).replace(
        daq={"device": daq_device, "ai_terminal": "rse"},
        load_cell={"sensitivity_v_per_n": 1.0, "offset_v": -0.5},
        safety={"preload_min_n": 0.1, "safe_force_n": 2.0, "over_force_n": 5.0},
    )
    rig = NidaqBackend(cfg)
    v = 10.0 * (1 - np.cos(np.linspace(0, 2 * np.pi, 2001)))  # 0 -> 20 V -> 0 actuator, 1 V at the board
    m = rig.run(v, 1000.0, preload_n=0.5, label="loopback")
    assert m.complete, m.reason
    r = rig_check(np.r_[np.zeros(10), v], np.r_[np.full(10, 0.5), m.channels["force_n"]], 10)
    assert r.correlation > 0.999  # a wire: only the board's noise and the one-sample lag
    assert r.gain_n_per_v == pytest.approx(1 / GAIN, rel=0.02)  # 1 V per 20 V, within the board's gain accuracy
    assert m.info["output_zeroed"]
