"""Hardware rig files (TOML) for the NI-DAQmx backend: channels, ranges, gains and safety limits.

Same schema style as :mod:`piezopress.acquisition.rig_config`: each ``[section]`` is a
frozen dataclass whose fields carry their unit, allowed range and meaning. A file is
checked completely (unknown sections and keys, types, ranges, then the relations between
keys) and every problem is reported at once with its section and key, before any driver
is loaded or any hardware touched. ``rigs/nidaq-example.toml`` documents every key.

Volts are named by where they are measured: ``ao_*``/``ai_*`` are volts at the DAQ board's
terminals, ``drive_*``/``output_*`` are volts across the actuator (after the amplifier's
``gain``), the unit of ``command_v`` in runs and plans.
"""

from __future__ import annotations

import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from piezopress.acquisition.plan import DriveLimits
from piezopress.acquisition.rig_config import SectionedConfig, _check, describe_sections, param
from piezopress.errors import ConfigError

#: ``ai_terminal`` values and the DAQmx ``TerminalConfiguration`` value of each (stable across
#: nidaqmx versions, whose enum member names changed: DIFFERENTIAL -> DIFF).
TERMINALS: dict[str, int] = {"default": -1, "rse": 10083, "nrse": 10078, "diff": 10106, "pseudo_diff": 12529}

_DEVICE = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
_AI = re.compile(r"^ai[0-9]+$")
_AO = re.compile(r"^ao[0-9]+$")


@dataclass(frozen=True)
class DaqRigSection:
    name: str = param("piezo press (NI-DAQmx)", "name of the rig, recorded with every run")
    backend: str = param("nidaq", "backend that runs this rig: 'nidaq' (National Instruments board through NI-DAQmx)")


@dataclass(frozen=True)
class BoardSection:
    """The DAQ board: one device for output and input, so both run on one sample clock."""

    device: str = param("Dev1", "NI-DAQmx device name, as NI MAX shows it (Dev1, PXI1Slot2, ...)")
    ao_channel: str = param("ao0", "analog output driving the amplifier's input (ao0, ao1, ...)")
    ao_min_v: float = param(
        -10.0, "lowest analog output voltage (the output range configured on the board)", "V", -100, 100
    )
    ao_max_v: float = param(10.0, "highest analog output voltage", "V", -100, 100)
    ai_min_v: float = param(-10.0, "lowest analog input voltage (input range of every input channel)", "V", -100, 100)
    ai_max_v: float = param(10.0, "highest analog input voltage", "V", -100, 100)
    ai_terminal: str = param("diff", "input terminal configuration: 'diff', 'rse', 'nrse', 'pseudo_diff' or 'default'")
    max_sample_rate_hz: float = param(
        100_000.0,
        "highest sample rate for output and input together on one clock (the lower of the board's AO and AI rates)",
        "Hz",
        0,
        1e8,
        True,
    )
    chunk_s: float = param(
        0.05, "input is read back in chunks this long; the over-force check runs once per chunk", "s", 0, 10, True
    )


@dataclass(frozen=True)
class ActuatorSection:
    drive_min_v: float = param(-30.0, "lowest allowed actuator voltage (PSt 150: -30 V)", "V", -1000, 1000)
    drive_max_v: float = param(150.0, "highest allowed actuator voltage (PSt 150: 150 V)", "V", -1000, 1000)
    slew_limit_v_per_s: float = param(
        3.0e6,
        "fastest allowed drive change, max |dV/dt| of command_v (3e6: a 150 V step in one sample at 20 kHz)",
        "V/s",
        0,
        1e9,
        True,
    )
    max_force_n: float = param(800.0, "maximum load force of the stack (PSt 150/5/100 VS10: 800 N)", "N", 0, 1e5, True)


@dataclass(frozen=True)
class AmplifierSection:
    gain: float = param(
        20.0, "voltage gain of the piezo amplifier: actuator volts per DAQ output volt", "V/V", 0, 1000, True
    )
    output_min_v: float = param(-200.0, "lowest output voltage of the amplifier", "V", -1000, 1000)
    output_max_v: float = param(200.0, "highest output voltage of the amplifier", "V", -1000, 1000)


@dataclass(frozen=True)
class LoadCellSection:
    channel: str = param("ai0", "analog input of the amplified load-cell signal")
    sensitivity_v_per_n: float = param(
        0.010003, "load cell with its amplifier, volts per newton (thesis Eq. 4.6: 10.003 mV/N)", "V/N", 0, 100, True
    )
    offset_v: float = param(
        0.0, "reading at zero force; force_n = (volts - offset_v) / sensitivity_v_per_n", "V", -100, 100
    )


@dataclass(frozen=True)
class DisplacementSection:
    channel: str = param("", "analog input of a displacement sensor ('' : none)")
    sensitivity_v_per_um: float = param(
        0.1, "volts per micrometre; displacement_um = (volts - offset_v) / sensitivity_v_per_um", "V/um", 0, 1e3, True
    )
    offset_v: float = param(0.0, "reading at zero displacement", "V", -100, 100)


@dataclass(frozen=True)
class MonitorSection:
    channel: str = param("", "analog input of the amplifier's monitor output ('' : none); recorded as monitor_v")
    scale_v_per_v: float = param(
        20.0, "actuator volts per monitor volt; monitor_v = volts * scale_v_per_v", "V/V", 0, 1e4, True
    )


@dataclass(frozen=True)
class SafetySection:
    """Interlocks (see :mod:`piezopress.acquisition.nidaq`)."""

    preload_min_n: float = param(
        50.0,
        "a run refuses to start if the preload read before it is below this (thesis Section 6.1: at least 50 N)",
        "N",
        0,
        1e5,
    )
    safe_force_n: float = param(
        200.0,
        "a run refuses to start if the force read before it is above this; plans' preload_n must be below it",
        "N",
        0,
        1e5,
        True,
    )
    over_force_n: float = param(
        500.0, "a run aborts (and the drive ramps down) as soon as the force read back exceeds this", "N", 0, 1e5, True
    )
    ramp_down_v_per_s: float = param(
        500.0, "rate of the ramp back to 0 V however a run ends (150 V in 0.3 s)", "V/s", 0, 1e6, True
    )
    ramp_sample_rate_hz: float = param(1000.0, "update rate of that ramp", "Hz", 0, 1e7, True)
    preload_read_s: float = param(
        0.1, "duration of the input acquisition that reads the preload before a run", "s", 0, 10, True
    )
    preload_sample_rate_hz: float = param(1000.0, "sample rate of that acquisition", "Hz", 0, 1e7, True)


SECTIONS: dict[str, type] = {
    "rig": DaqRigSection,
    "daq": BoardSection,
    "actuator": ActuatorSection,
    "amplifier": AmplifierSection,
    "load_cell": LoadCellSection,
    "displacement": DisplacementSection,
    "monitor": MonitorSection,
    "safety": SafetySection,
}


@dataclass(frozen=True)
class InputChannel:
    """One analog input: the run column it fills and how its volts convert to that column's unit."""

    column: str
    channel: str
    scale: float  # unit per volt
    offset_v: float

    def convert(self, volts: Any) -> Any:
        """Volts at the board to the column's unit: ``(volts - offset_v) * scale``."""
        return (volts - self.offset_v) * self.scale


@dataclass(frozen=True)
class DaqRigConfig(SectionedConfig):
    """A complete, checked hardware rig configuration."""

    SECTION_TYPES = SECTIONS

    rig: DaqRigSection = DaqRigSection()
    daq: BoardSection = BoardSection()
    actuator: ActuatorSection = ActuatorSection()
    amplifier: AmplifierSection = AmplifierSection()
    load_cell: LoadCellSection = LoadCellSection()
    displacement: DisplacementSection = DisplacementSection()
    monitor: MonitorSection = MonitorSection()
    safety: SafetySection = SafetySection()
    source: str = "<defaults>"

    @property
    def drive_range_v(self) -> tuple[float, float]:
        """The actuator voltages every link allows: actuator, amplifier output and ``gain`` x AO range."""
        a, amp, d = self.actuator, self.amplifier, self.daq
        lo = max(a.drive_min_v, amp.output_min_v, amp.gain * d.ao_min_v)
        hi = min(a.drive_max_v, amp.output_max_v, amp.gain * d.ao_max_v)
        return lo, hi

    @property
    def limits(self) -> DriveLimits:
        lo, hi = self.drive_range_v
        return DriveLimits(
            drive_min_v=lo,
            drive_max_v=hi,
            max_sample_rate_hz=self.daq.max_sample_rate_hz,
            max_force_n=self.safety.safe_force_n,
            slew_limit_v_per_s=self.actuator.slew_limit_v_per_s,
        )

    def physical(self, channel: str) -> str:
        """``Dev1/ai0`` from ``ai0``."""
        return f"{self.daq.device}/{channel}"

    def terminal(self, name: str) -> str:
        """A device terminal for routing: ``/Dev1/ai/SampleClock`` from ``ai/SampleClock``."""
        return f"/{self.daq.device}/{name}"

    @property
    def inputs(self) -> tuple[InputChannel, ...]:
        """The analog inputs in acquisition order: the load cell first, then the optional ones."""
        out = [
            InputChannel(
                "force_n", self.load_cell.channel, 1.0 / self.load_cell.sensitivity_v_per_n, self.load_cell.offset_v
            )
        ]
        if self.displacement.channel:
            d = self.displacement
            out.append(InputChannel("displacement_um", d.channel, 1.0 / d.sensitivity_v_per_um, d.offset_v))
        if self.monitor.channel:
            out.append(InputChannel("monitor_v", self.monitor.channel, self.monitor.scale_v_per_v, 0.0))
        return tuple(out)

    @classmethod
    def _parse(cls, doc: Mapping[str, Any], source: str) -> DaqRigConfig:
        return parse_daq_rig(doc, source=source)


def _relations(s: Mapping[str, Any]) -> list[str]:
    """Problems between keys (each key is already in its own range)."""
    problems: list[str] = []
    rig, d, a, amp = s["rig"], s["daq"], s["actuator"], s["amplifier"]
    lc, disp, mon, saf = s["load_cell"], s["displacement"], s["monitor"], s["safety"]
    if rig.backend != "nidaq":
        problems.append(f"[rig] backend = {rig.backend!r}: this file is read by the 'nidaq' backend; expected 'nidaq'")
    if not _DEVICE.match(d.device):
        problems.append(f"[daq] device = {d.device!r}: expected a device name such as 'Dev1' (letters, digits, '_')")
    if not _AO.match(d.ao_channel):
        problems.append(f"[daq] ao_channel = {d.ao_channel!r}: expected an analog output such as 'ao0'")
    if d.ai_terminal not in TERMINALS:
        problems.append(f"[daq] ai_terminal = {d.ai_terminal!r}: expected one of {', '.join(TERMINALS)}")
    for sec, lo_key, hi_key, what in (
        ("daq", "ao_min_v", "ao_max_v", "analog output range"),
        ("daq", "ai_min_v", "ai_max_v", "analog input range"),
        ("actuator", "drive_min_v", "drive_max_v", "actuator range"),
        ("amplifier", "output_min_v", "output_max_v", "amplifier output range"),
    ):
        lo, hi = getattr(s[sec], lo_key), getattr(s[sec], hi_key)
        if lo >= hi:
            problems.append(f"[{sec}] {lo_key} = {lo:g} must be below {hi_key} = {hi:g}")
        elif sec != "daq" or lo_key == "ao_min_v":
            if not lo <= 0.0 <= hi:
                problems.append(
                    f"[{sec}] {what} {lo:g} to {hi:g} V must include 0 V (every run ends by ramping the drive to 0 V)"
                )
    channels = [("load_cell", lc.channel, True), ("displacement", disp.channel, False), ("monitor", mon.channel, False)]
    seen: dict[str, str] = {}
    for sec, ch, required in channels:
        if not ch and not required:
            continue
        if not _AI.match(ch):
            problems.append(
                f"[{sec}] channel = {ch!r}: expected an analog input such as "
                f"'ai0'{'' if required else ' (or empty for none)'}"
            )
        elif ch in seen:
            problems.append(f"[{sec}] channel = {ch!r} is already the [{seen[ch]}] channel; expected distinct inputs")
        else:
            seen[ch] = sec
    if not problems:
        lo, hi = (
            max(a.drive_min_v, amp.output_min_v, amp.gain * d.ao_min_v),
            min(a.drive_max_v, amp.output_max_v, amp.gain * d.ao_max_v),
        )
        if lo >= hi:
            problems.append(
                f"[amplifier] gain = {amp.gain:g} x [daq] ao range {d.ao_min_v:g} to {d.ao_max_v:g} V, the "
                "amplifier's output and the actuator's "
                f"range leave no drive range ({lo:g} to {hi:g} V)"
            )
    if not saf.preload_min_n < saf.safe_force_n:
        problems.append(
            f"[safety] preload_min_n = {saf.preload_min_n:g} N must be below safe_force_n = {saf.safe_force_n:g} N"
        )
    if not saf.safe_force_n <= saf.over_force_n:
        problems.append(
            f"[safety] safe_force_n = {saf.safe_force_n:g} N must not exceed over_force_n = {saf.over_force_n:g} N"
        )
    if saf.over_force_n > a.max_force_n:
        problems.append(
            f"[safety] over_force_n = {saf.over_force_n:g} N exceeds the stack's [actuator] max_force_n = "
            f"{a.max_force_n:g} N"
        )
    # the load cell must still read below full scale at the over-force level, else a saturated
    # input would hide the very force the interlock is there to catch
    full_scale_n = (d.ai_max_v - lc.offset_v) / lc.sensitivity_v_per_n
    if full_scale_n < saf.over_force_n:
        problems.append(
            f"[safety] over_force_n = {saf.over_force_n:g} N is above what the load cell can read: [daq] ai_max_v = "
            f"{d.ai_max_v:g} V "
            f"is {full_scale_n:.4g} N at sensitivity_v_per_n = {lc.sensitivity_v_per_n:g} and offset_v = "
            f"{lc.offset_v:g}"
        )
    for key in ("ramp_sample_rate_hz", "preload_sample_rate_hz"):
        if getattr(saf, key) > d.max_sample_rate_hz:
            problems.append(
                f"[safety] {key} = {getattr(saf, key):g} Hz exceeds [daq] max_sample_rate_hz = "
                f"{d.max_sample_rate_hz:g} Hz"
            )
    if saf.preload_read_s * saf.preload_sample_rate_hz < 10:
        problems.append(
            f"[safety] preload_read_s = {saf.preload_read_s:g} s at preload_sample_rate_hz = "
            f"{saf.preload_sample_rate_hz:g} Hz "
            "gives fewer than 10 samples; expected a longer read"
        )
    return problems


def parse_daq_rig(doc: Mapping[str, Any], source: str = "<rig>") -> DaqRigConfig:
    """Check a hardware rig document completely; every problem names its section and key.

    Raises
    ------
    ConfigError
        Listing every problem found.
    """
    problems: list[str] = []
    sections: dict[str, Any] = {}
    for sec in sorted(set(doc) - set(SECTIONS)):
        problems.append(f"unknown section [{sec}]; expected one of {', '.join(SECTIONS)}")
    for sec, cls in SECTIONS.items():
        table = doc.get(sec, {})
        if not isinstance(table, Mapping):
            problems.append(f"[{sec}] must be a table")
            continue
        n_before = len(problems)
        sections[sec] = _check(sec, cls, table, problems)
        if len(problems) > n_before:
            sections[sec] = None
    if all(v is not None for v in sections.values()) and len(sections) == len(SECTIONS):
        problems.extend(_relations(sections))
    if problems:
        raise ConfigError(source, problems)
    return DaqRigConfig(**sections, source=source)


def read_rig_document(path: str | Path) -> dict[str, Any]:
    """The TOML document of a rig file, or a :class:`ConfigError` naming the file."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(str(path), ["no such file; expected a rig TOML file (see rigs/)"])
    try:
        return tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(str(path), [f"not valid TOML: {exc}"]) from None


def rig_backend(doc: Mapping[str, Any]) -> str:
    """The backend a rig document names in ``[rig] backend`` (``virtual`` when it names none)."""
    rig = doc.get("rig", {})
    backend = rig.get("backend", "virtual") if isinstance(rig, Mapping) else "virtual"
    return backend if isinstance(backend, str) else repr(backend)


def load_daq_rig(path: str | Path) -> DaqRigConfig:
    """Read and check a hardware rig TOML file."""
    return parse_daq_rig(read_rig_document(path), source=str(path))


def describe_keys() -> str:
    """Every section and key of a hardware rig file with unit, default, range and meaning."""
    return describe_sections(SECTIONS)
