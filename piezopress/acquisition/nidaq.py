"""The NI-DAQmx backend: a real press on a National Instruments board.

It implements :class:`piezopress.acquisition.backend.Backend`, like the virtual rig, for a
board configured by a hardware rig file (:mod:`piezopress.acquisition.daq_config`,
``rigs/nidaq-example.toml``). The ``nidaqmx`` package is optional (the ``nidaq`` extra:
``pip install '.[nidaq]'`` from the piezopress folder) and imported only when a backend is
created without a fake driver.

Timing: one sample clock, one start trigger
-------------------------------------------
The drive is precomputed (open-loop control), so one run is one hardware-timed *finite*
generation of the drive (``command_v / gain`` in DAQ volts) and one finite acquisition of the
inputs (load cell, then the optional displacement and amplifier-monitor channels), both
``len(command_v)`` samples long:

* the analog input task runs on the board's own sample clock at ``sample_rate_hz``;
* the analog output task takes ``/Dev/ai/SampleClock`` as its sample clock and
  ``/Dev/ai/StartTrigger`` as its start trigger, so it has no clock of its own: output
  sample ``k`` is updated on the very clock edge on which input sample ``k`` is converted;
* the output task is written and started first (armed: it waits for the input's start
  trigger and clock), then the input task is started, which starts both.

So output and input cannot drift or slip against each other, and a run is exactly
``len(command_v)`` samples of each. Input sample ``k`` is converted on the edge that
updates output sample ``k``: it sees the drive of sample ``k - 1`` (plus the settling of
the output), a one-sample lag the models' delay absorbs. The board must coerce the
requested rate exactly (a rate that divides its timebase); otherwise the run is refused
before anything is output, since run files assume ``t_s = k / sample_rate_hz``.

Safety interlocks
-----------------
Before a run: :func:`drive_problems` (actuator, amplifier and output ranges, slew limit)
and :func:`check_preload` on a short acquisition of the load cell
(:meth:`NidaqBackend.read_preload_n`). During a run: the inputs are read back in chunks of
``[daq] chunk_s`` and :func:`over_force` aborts the run. However a run ends (normal end,
over-force, Ctrl-C, an exception, a driver error) the tasks are stopped and closed, the
drive ramps from the last value output back to 0 V at ``[safety] ramp_down_v_per_s``
(:func:`ramp_to_zero`, a hardware-timed ramp, never a jump) and 0 V is written. What was
measured is returned as a :class:`Measurement` with ``complete=False`` and the reason; a
Ctrl-C is re-raised after the ramp as :class:`RunInterrupted`, which carries that
measurement so the caller can keep it.

The driver boundary
-------------------
Every nidaqmx call goes through :class:`DaqDriver`/:class:`DaqTask`, a thin layer with
nidaqmx's own method names (:class:`NidaqmxDriver` is the real one). Tests replace it by a
fake that records the exact sequence of calls (``tests/test_nidaq.py``).
"""

from __future__ import annotations

import math
import signal
from collections.abc import Callable, Mapping
from typing import Any, Protocol

import numpy as np

from piezopress.acquisition.backend import Measurement
from piezopress.acquisition.daq_config import TERMINALS, DaqRigConfig, SafetySection, parse_daq_rig
from piezopress.acquisition.drive_check import drive_problems as shared_drive_problems
from piezopress.acquisition.plan import DriveLimits
from piezopress.errors import BackendError, PiezopressError

INSTALL_HINT = (
    "pip install nidaqmx into piezopress's environment (or reinstall piezopress with its extra: pip install "
    "'PATH-TO-PIEZOPRESS[nidaq]'), and the NI-DAQmx driver from ni.com"
)
#: Added to the expected duration of every blocking driver call before it times out.
TIMEOUT_MARGIN_S = 2.0
#: Relative difference allowed between the requested and the board's coerced sample rate.
RATE_RTOL = 1e-6


# --------------------------------------------------------------------------------------
# The driver boundary
# --------------------------------------------------------------------------------------


class DaqTask(Protocol):
    """One DAQmx task, through the few calls piezopress makes (nidaqmx's names)."""

    name: str

    def add_ai_voltage_chan(
        self, physical_channel: str, min_val: float, max_val: float, terminal_config: str
    ) -> None: ...

    def add_ao_voltage_chan(self, physical_channel: str, min_val: float, max_val: float) -> None: ...

    def cfg_samp_clk_timing(self, rate: float, samps_per_chan: int, source: str = "") -> None:
        """Finite, hardware-timed: ``samps_per_chan`` samples at ``rate`` on ``source`` ('' : the task's own clock)."""
        ...

    def cfg_dig_edge_start_trig(self, trigger_source: str) -> None: ...

    def samp_clk_rate(self) -> float:
        """The sample rate the board actually runs at (after coercion)."""
        ...

    def write(self, data: np.ndarray, auto_start: bool = False) -> int:
        """Output samples (DAQ volts); an untimed task with ``auto_start`` writes at once (on demand)."""
        ...

    def start(self) -> None: ...

    def read(self, number_of_samples_per_channel: int, timeout: float) -> np.ndarray:
        """The next samples of every input channel, shape ``(channels, samples)``, in volts."""
        ...

    def wait_until_done(self, timeout: float) -> None: ...

    def total_samp_per_chan_generated(self) -> int: ...

    def stop(self) -> None: ...

    def close(self) -> None: ...


class DaqDriver(Protocol):
    """Makes tasks: the only way the backend reaches the hardware."""

    def task(self, name: str) -> DaqTask: ...


def import_nidaqmx() -> Any:
    """The ``nidaqmx`` module, or a one-line :class:`BackendError` saying how to install it."""
    try:
        import nidaqmx  # noqa: PLC0415  (optional dependency, imported only when asked for)
    except ImportError:
        raise BackendError(
            f"the nidaq backend needs the nidaqmx package, which is not installed: {INSTALL_HINT}"
        ) from None
    return nidaqmx


class NidaqmxTask:
    """:class:`DaqTask` over a ``nidaqmx.Task``."""

    def __init__(self, nidaqmx: Any, name: str):
        self._nidaqmx = nidaqmx
        self.name = name
        try:
            self._task = nidaqmx.Task()
        except Exception as exc:  # DaqNotFoundError: the package is there, the NI-DAQmx driver is not
            if type(exc).__name__ == "DaqNotFoundError":
                raise BackendError(
                    "NI-DAQmx (the driver under the nidaqmx package) is not installed: install it from ni.com or run "
                    f"`python -m nidaqmx installdriver` ({exc})"
                ) from None
            raise
        self._n_inputs = 0

    def add_ai_voltage_chan(self, physical_channel: str, min_val: float, max_val: float, terminal_config: str) -> None:
        tc = self._nidaqmx.constants.TerminalConfiguration(TERMINALS[terminal_config])
        self._task.ai_channels.add_ai_voltage_chan(
            physical_channel, terminal_config=tc, min_val=min_val, max_val=max_val
        )
        self._n_inputs += 1

    def add_ao_voltage_chan(self, physical_channel: str, min_val: float, max_val: float) -> None:
        self._task.ao_channels.add_ao_voltage_chan(physical_channel, min_val=min_val, max_val=max_val)

    def cfg_samp_clk_timing(self, rate: float, samps_per_chan: int, source: str = "") -> None:
        c = self._nidaqmx.constants
        self._task.timing.cfg_samp_clk_timing(
            rate,
            source=source,
            active_edge=c.Edge.RISING,
            sample_mode=c.AcquisitionType.FINITE,
            samps_per_chan=int(samps_per_chan),
        )

    def cfg_dig_edge_start_trig(self, trigger_source: str) -> None:
        self._task.triggers.start_trigger.cfg_dig_edge_start_trig(
            trigger_source, trigger_edge=self._nidaqmx.constants.Edge.RISING
        )

    def samp_clk_rate(self) -> float:
        return float(self._task.timing.samp_clk_rate)

    def write(self, data: np.ndarray, auto_start: bool = False) -> int:
        data = np.ascontiguousarray(data, dtype=np.float64)
        return int(
            self._task.write(
                float(data[0]) if data.size == 1 else data, auto_start=auto_start, timeout=TIMEOUT_MARGIN_S + 10.0
            )
        )

    def start(self) -> None:
        self._task.start()

    def read(self, number_of_samples_per_channel: int, timeout: float) -> np.ndarray:
        from nidaqmx.stream_readers import AnalogMultiChannelReader  # noqa: PLC0415

        out = np.zeros((self._n_inputs, int(number_of_samples_per_channel)), dtype=np.float64)
        AnalogMultiChannelReader(self._task.in_stream).read_many_sample(
            out, number_of_samples_per_channel=int(number_of_samples_per_channel), timeout=timeout
        )
        return out

    def wait_until_done(self, timeout: float) -> None:
        self._task.wait_until_done(timeout=timeout)

    def total_samp_per_chan_generated(self) -> int:
        return int(self._task.out_stream.total_samp_per_chan_generated)

    def stop(self) -> None:
        self._task.stop()

    def close(self) -> None:
        self._task.close()


class NidaqmxDriver:
    """:class:`DaqDriver` over the real ``nidaqmx`` package (imported here, lazily)."""

    def __init__(self) -> None:
        self._nidaqmx = import_nidaqmx()

    def task(self, name: str) -> DaqTask:
        return NidaqmxTask(self._nidaqmx, name)


# --------------------------------------------------------------------------------------
# Interlocks: small pure functions, each tested on its own and through a run
# --------------------------------------------------------------------------------------


def drive_problems(
    command_v: np.ndarray, sample_rate_hz: float, config: DaqRigConfig, *, start_v: float = 0.0
) -> list[str]:
    """Every reason the drive may not be played, before anything is output (empty: fine).

    Checks: a finite 1-D waveform of at least 2 samples, a sample rate the board can run,
    every sample within the actuator's range, the amplifier's output range and the analog
    output range times the gain, and the slew limit ``max |diff| * fs`` over the drive
    including the move from ``start_v`` (the output before the run) to its first sample.
    """
    a, amp, d = config.actuator, config.amplifier, config.daq
    return shared_drive_problems(
        command_v,
        sample_rate_hz,
        config.limits,
        start_v=start_v,
        ranges=[
            ("the actuator's range ([actuator] drive_min_v/drive_max_v)", a.drive_min_v, a.drive_max_v),
            (
                "the amplifier's output range ([amplifier] output_min_v/output_max_v)",
                amp.output_min_v,
                amp.output_max_v,
            ),
            (
                f"the analog output range x gain ([daq] ao_min_v/ao_max_v x {amp.gain:g})",
                amp.gain * d.ao_min_v,
                amp.gain * d.ao_max_v,
            ),
        ],
        rate_key="[daq] max_sample_rate_hz",
        slew_key="the slew limit [actuator] slew_limit_v_per_s",
    )


def check_preload(force_n: float, safety: SafetySection) -> None:
    """Refuse to start unless the force read at rest is between the minimum preload and the safe force.

    Below ``preload_min_n`` the stack is not pressed firmly enough (thesis Section 6.1: at
    least 50 N; a stack without preload can be pulled apart by its own dynamics); above
    ``safe_force_n`` something already presses too hard, or the load cell is miswired.
    """
    if not math.isfinite(force_n):
        raise BackendError(f"nidaq: preload read as {force_n!r}; expected a finite force: check the load cell channel")
    if force_n < safety.preload_min_n:
        raise BackendError(
            f"nidaq: run refused: preload reads {force_n:.2f} N, below [safety] preload_min_n = "
            f"{safety.preload_min_n:g} N "
            "(thesis Section 6.1); tighten the preload"
        )
    if force_n > safety.safe_force_n:
        raise BackendError(
            f"nidaq: run refused: force at rest reads {force_n:.2f} N, above [safety] safe_force_n = "
            f"{safety.safe_force_n:g} N"
        )


def over_force(force_n: np.ndarray, first_sample: int, sample_rate_hz: float, safety: SafetySection) -> str:
    """Why the run must abort, if one chunk of force read back exceeds the over-force level ('' : fine).

    ``first_sample`` is the index of the chunk's first sample in the run (to say when).
    """
    force_n = np.asarray(force_n, dtype=np.float64)
    bad = ~(force_n <= safety.over_force_n)  # NaN counts as over-force: the reading cannot be trusted
    if not bad.any():
        return ""
    i = int(np.argmax(bad))
    k = first_sample + i
    return (
        f"over-force: {force_n[i]:.1f} N at t = {k / sample_rate_hz:.4g} s (sample {k}), "
        f"above [safety] over_force_n = {safety.over_force_n:g} N"
    )


def ramp_to_zero(from_v: float, rate_v_per_s: float, sample_rate_hz: float) -> np.ndarray:
    """Samples from ``from_v`` down (or up) to exactly 0, no step faster than ``rate_v_per_s``.

    The first sample is ``from_v`` (no jump from where the output is), the last is 0.0;
    ``[from_v]`` alone when ``from_v`` is 0.

    Examples
    --------
    >>> ramp_to_zero(1.0, 2.0, 8.0).tolist()
    [1.0, 0.75, 0.5, 0.25, 0.0]
    """
    step = rate_v_per_s / sample_rate_hz
    n_steps = int(math.ceil(abs(from_v) / step - 1e-12)) if from_v != 0 else 0
    ramp = np.linspace(from_v, 0.0, n_steps + 1)
    ramp[-1] = 0.0
    return ramp


# --------------------------------------------------------------------------------------
# The backend
# --------------------------------------------------------------------------------------


class RunInterrupted(KeyboardInterrupt):
    """Ctrl-C during a run, raised after the drive is back at 0 V.

    ``measurement`` holds what was measured (``complete`` false), so the caller keeps it.
    """

    def __init__(self, measurement: Measurement, signum: int | None = None):
        super().__init__(measurement.reason)
        self.measurement = measurement
        #: the signal that stopped the run (SIGTERM, SIGHUP), None for Ctrl-C
        self.signum = signum


class NidaqBackend:
    """A press on an NI-DAQmx board. See the module docstring for timing and interlocks.

    Parameters
    ----------
    config : DaqRigConfig
        The checked hardware rig file.
    driver : DaqDriver, optional
        The driver layer; by default :class:`NidaqmxDriver` (needs the ``nidaqmx``
        package, else a :class:`BackendError` saying how to install it).
    """

    name = "nidaq"

    def __init__(self, config: DaqRigConfig | Mapping[str, Any], driver: DaqDriver | None = None):
        # a parsed rig file (``NidaqBackend(document)``, as every plug-in backend is made) or a DaqRigConfig
        self.config = parse_daq_rig(config, source="rig file") if isinstance(config, Mapping) else config
        self.driver = driver if driver is not None else NidaqmxDriver()
        #: last value written to the analog output, DAQ volts (0 at rest)
        self.output_daq_v = 0.0
        self._output_confirmed = True
        self._deferred_interrupt = False

    @classmethod
    def limits_of(cls, document: Mapping[str, Any]) -> DriveLimits:
        """The limits a rig document states, checked completely, without loading the driver."""
        return parse_daq_rig(document, source="rig file").limits

    @property
    def output_v(self) -> float:
        """The drive held now, actuator volts (the analog output times the amplifier's gain)."""
        return self.output_daq_v * self.config.amplifier.gain

    # -- Backend protocol ----------------------------------------------------------------

    @property
    def limits(self) -> DriveLimits:
        return self.config.limits

    def describe(self) -> dict[str, Any]:
        return {"backend": self.name, "source": self.config.source, "config": self.config.as_dict()}

    def run(
        self,
        command_v: np.ndarray,
        sample_rate_hz: float,
        *,
        preload_n: float,
        label: str,
        progress: Callable[[float], None] | None = None,
    ) -> Measurement:
        """Check the drive, read the preload, then play and measure (see the module docstring).

        Raises
        ------
        BackendError
            When the drive or the preload is refused, or the tasks cannot be configured:
            nothing has been output then.
        RunInterrupted
            On Ctrl-C during the run, after the drive is back at 0 V, with what was measured.
        """
        command_v = np.asarray(command_v, dtype=np.float64)
        if not self._output_confirmed:  # a previous run could not confirm 0 V: try again first
            self.zero_output()
        self.check_drive(command_v, sample_rate_hz, label)
        preload_measured_n = self.read_preload_n()
        check_preload(preload_measured_n, self.config.safety)
        m = self._play(
            command_v,
            float(sample_rate_hz),
            label,
            progress,
            {"preload_requested_n": float(preload_n), "preload_measured_n": preload_measured_n},
        )
        if m.info.get("interrupted"):
            raise RunInterrupted(m, getattr(signal, str(m.info.get("signal")), None))
        return m

    def zero_output(self) -> None:
        """Ramp the output from its last value to 0 V at the safe rate and write 0 V.

        Does nothing when the output is known to be at 0 V already (safe to call any time,
        more than once). Raises :class:`BackendError` if 0 V could not be confirmed.
        """
        if self.output_daq_v == 0.0 and self._output_confirmed:
            return
        errors: list[str] = []
        self._ramp_down(errors)
        self._raise_deferred_interrupt()
        if errors or not self._output_confirmed:
            raise BackendError(f"nidaq: output not confirmed at 0 V ({'; '.join(errors)}); switch the amplifier off")

    # -- interlocks that talk to the hardware ----------------------------------------------

    def check_drive(self, command_v: np.ndarray, sample_rate_hz: float, label: str = "drive") -> None:
        """Refuse a drive outside the limits (see :func:`drive_problems`), all problems in one error."""
        problems = drive_problems(
            command_v, sample_rate_hz, self.config, start_v=self.output_daq_v * self.config.amplifier.gain
        )
        if problems:
            raise BackendError(f"nidaq: {label}: drive refused: " + "; ".join(problems))

    def read_preload_n(self) -> float:
        """The mean force over a short acquisition of the load cell alone, the drive untouched."""
        cfg, s = self.config, self.config.safety
        n = max(10, int(round(s.preload_read_s * s.preload_sample_rate_hz)))
        task = self.driver.task("piezopress-preload")
        try:
            task.add_ai_voltage_chan(
                cfg.physical(cfg.load_cell.channel), cfg.daq.ai_min_v, cfg.daq.ai_max_v, cfg.daq.ai_terminal
            )
            task.cfg_samp_clk_timing(s.preload_sample_rate_hz, n)
            task.start()
            volts = np.asarray(task.read(n, n / s.preload_sample_rate_hz + TIMEOUT_MARGIN_S), dtype=np.float64)[0]
            task.stop()
        finally:
            task.close()
        return float(np.mean(cfg.inputs[0].convert(volts)))

    # -- one run -----------------------------------------------------------------------------

    def _configure(self, n: int, fs: float) -> tuple[DaqTask, DaqTask, float]:
        """Create the input task (own clock) and the output task (on the input's clock and start trigger)."""
        cfg, d = self.config, self.config.daq
        ai = self.driver.task("piezopress-ai")
        ao = None
        try:
            for ch in cfg.inputs:
                ai.add_ai_voltage_chan(cfg.physical(ch.channel), d.ai_min_v, d.ai_max_v, d.ai_terminal)
            ai.cfg_samp_clk_timing(fs, n)
            achieved = ai.samp_clk_rate()
            if abs(achieved - fs) > RATE_RTOL * fs:
                raise BackendError(
                    f"nidaq: the board runs at {achieved:.6g} Hz when asked for {fs:g} Hz; choose a sample rate that "
                    "divides "
                    "the board's timebase (run files assume exactly the requested rate)"
                )
            ao = self.driver.task("piezopress-ao")
            ao.add_ao_voltage_chan(cfg.physical(d.ao_channel), d.ao_min_v, d.ao_max_v)
            ao.cfg_samp_clk_timing(fs, n, source=cfg.terminal("ai/SampleClock"))
            ao.cfg_dig_edge_start_trig(cfg.terminal("ai/StartTrigger"))
        except BaseException:
            for task in (ao, ai):
                if task is not None:
                    self._step([], f"close {task.name}", task.close)
            raise
        return ai, ao, achieved

    def _play(
        self,
        command_v: np.ndarray,
        fs: float,
        label: str,
        progress: Callable[[float], None] | None,
        info: dict[str, Any],
    ) -> Measurement:
        cfg = self.config
        gain = cfg.amplifier.gain
        daq_v = command_v / gain
        n = len(daq_v)
        chunk = max(1, int(round(cfg.daq.chunk_s * fs)))
        try:
            ai, ao, achieved = self._configure(n, fs)
        except PiezopressError:
            raise
        except Exception as exc:  # a driver error while configuring: nothing was output
            raise BackendError(
                f"nidaq: {label}: configuring the tasks failed, nothing was output: {type(exc).__name__}: {exc}"
            ) from exc
        columns = [ch.column for ch in cfg.inputs]
        buf = np.empty((len(columns), n), dtype=np.float64)
        got = 0
        reason = ""
        interrupted = False
        signum = None
        started = False
        try:
            ao.write(daq_v, auto_start=False)
            started = True  # from here on the output may move: always ramp down
            ao.start()  # armed: waits for the input's start trigger and clock
            ai.start()  # starts both
            while got < n:
                k = min(chunk, n - got)
                volts = np.asarray(ai.read(k, k / fs + TIMEOUT_MARGIN_S), dtype=np.float64)
                for row, ch in enumerate(cfg.inputs):
                    buf[row, got : got + k] = ch.convert(volts[row, :k])
                got += k
                reason = over_force(buf[0, got - k : got], got - k, fs, cfg.safety)
                if reason:
                    break
                if progress is not None:
                    progress(got / n)
            if not reason:
                ao.wait_until_done(TIMEOUT_MARGIN_S)
        except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM/SIGHUP (backend.Terminated)
            interrupted = True
            signum = getattr(exc, "signum", None)
            reason = f"interrupted by {signal.Signals(signum).name}" if signum else "interrupted by the user (Ctrl-C)"
        except Exception as exc:  # driver errors included: the data so far is kept
            reason = f"{type(exc).__name__}: {exc}"
        errors: list[str] = []
        last_daq_v = self._stop_run(ai, ao, daq_v, got, chunk, started, errors)
        ramp = self._ramp_down(errors)
        if self._deferred_interrupt:  # Ctrl-C during the ramp-down: honoured now, the output is safe
            self._deferred_interrupt = False
            interrupted = True
            reason = reason or "interrupted by the user (Ctrl-C) during the ramp-down"
        if errors:
            reason = "; ".join([r for r in [reason] if r] + errors)
        if not self._output_confirmed:
            reason += "; OUTPUT NOT CONFIRMED AT 0 V: switch the amplifier off"
        complete = not reason and got == n
        info = {
            **info,
            "label": label,
            "device": cfg.daq.device,
            "clock": f"output on {cfg.terminal('ai/SampleClock')}, started by {cfg.terminal('ai/StartTrigger')}",
            "sample_rate_achieved_hz": achieved,
            "samples_planned": n,
            "samples_measured": got,
            "chunk_samples": chunk,
            "last_output_v": last_daq_v * gain,
            "ramp_down": ramp,
            "output_zeroed": self._output_confirmed,
            "interrupted": interrupted,
            "signal": signal.Signals(signum).name if interrupted and signum else None,
        }
        channels = {col: buf[row, :got].copy() for row, col in enumerate(columns)}
        return Measurement(channels=channels, complete=complete, reason=reason, info=info)

    def _stop_run(
        self, ai: DaqTask, ao: DaqTask, daq_v: np.ndarray, got: int, chunk: int, started: bool, errors: list[str]
    ) -> float:
        """Stop and close both tasks; return (and remember) the last value the output generated."""
        self._step(errors, "stop output", ao.stop)
        self._step(errors, "stop input", ai.stop)
        if started:
            generated = self._step(errors, "count generated samples", ao.total_samp_per_chan_generated)
            if generated is None:  # unknown: assume the output ran a chunk ahead of the input
                generated = got + chunk
            generated = int(min(max(generated, 0), len(daq_v)))
            if generated > 0:
                self.output_daq_v = float(daq_v[generated - 1])
                self._output_confirmed = False
        self._step(errors, "close output", ao.close)
        self._step(errors, "close input", ai.close)
        return self.output_daq_v

    def _ramp_down(self, errors: list[str]) -> dict[str, Any]:
        """Ramp from ``output_daq_v`` to 0 V at the safe rate (hardware-timed), then write 0 V on demand.

        If the ramp cannot be played, 0 V is still written (a jump: the last resort). Never
        raises; problems are appended to ``errors`` and ``_output_confirmed`` says whether
        0 V was written.
        """
        cfg, s = self.config, self.config.safety
        d, gain = cfg.daq, cfg.amplifier.gain
        ramp = ramp_to_zero(self.output_daq_v, s.ramp_down_v_per_s / gain, s.ramp_sample_rate_hz)
        info: dict[str, Any] = {
            "from_v": self.output_daq_v * gain,
            "samples": int(len(ramp)),
            "rate_v_per_s": s.ramp_down_v_per_s,
            "sample_rate_hz": s.ramp_sample_rate_hz,
        }
        phys = cfg.physical(d.ao_channel)
        if len(ramp) > 1:
            task = None
            try:
                task = self.driver.task("piezopress-ramp")
                task.add_ao_voltage_chan(phys, d.ao_min_v, d.ao_max_v)
                task.cfg_samp_clk_timing(s.ramp_sample_rate_hz, len(ramp))
                task.write(ramp, auto_start=False)
                task.start()
                self._wait(task, len(ramp) / s.ramp_sample_rate_hz + TIMEOUT_MARGIN_S)
                self.output_daq_v = 0.0  # the ramp ends at 0 V (confirmed by the write below)
                info["played"] = True
            except BaseException as exc:  # noqa: BLE001 (Ctrl-C too: 0 V is still written below)
                if isinstance(exc, KeyboardInterrupt):
                    self._deferred_interrupt = True
                errors.append(f"ramp-down failed, 0 V written directly: {type(exc).__name__}: {exc}")
                info["played"] = False
            finally:
                if task is not None:
                    self._step(errors, "stop ramp", task.stop)
                    self._step(errors, "close ramp", task.close)
        self._output_confirmed = False
        zero = None
        try:
            zero = self.driver.task("piezopress-zero")
            zero.add_ao_voltage_chan(phys, d.ao_min_v, d.ao_max_v)
            zero.write(np.zeros(1), auto_start=True)
            self.output_daq_v = 0.0
            self._output_confirmed = True
        except BaseException as exc:  # noqa: BLE001
            if isinstance(exc, KeyboardInterrupt):
                self._deferred_interrupt = True
            errors.append(f"writing 0 V failed: {type(exc).__name__}: {exc}")
        finally:
            if zero is not None:
                self._step(errors, "stop zero", zero.stop)
                self._step(errors, "close zero", zero.close)
        return info

    def _wait(self, task: DaqTask, timeout: float) -> None:
        """Wait for a hardware-timed generation to finish; a Ctrl-C meanwhile is deferred, not obeyed.

        Leaving early would close the task half-way down the ramp; the hardware keeps
        ramping whatever Python does, so the wait is simply resumed.
        """
        for _ in range(100):
            try:
                task.wait_until_done(timeout)
                return
            except KeyboardInterrupt:
                self._deferred_interrupt = True
        task.wait_until_done(timeout)

    def _step(self, errors: list[str], what: str, fn: Callable[[], Any]) -> Any:
        """One clean-up step: an error is recorded, never raised, so the next steps still run; Ctrl-C is deferred."""
        for _ in range(3):
            try:
                return fn()
            except KeyboardInterrupt:
                self._deferred_interrupt = True
            except Exception as exc:  # noqa: BLE001
                errors.append(f"{what} failed: {type(exc).__name__}: {exc}")
                return None
        return None

    def _raise_deferred_interrupt(self) -> None:
        if self._deferred_interrupt:
            self._deferred_interrupt = False
            raise KeyboardInterrupt
