"""Rig configuration files (TOML): named parameters with units, defaults and allowed ranges.

Each ``[section]`` of the file is a frozen dataclass below; each key is a field whose
metadata gives its unit, allowed range and meaning. The same dataclasses are the schema
(unknown keys and out-of-range values are errors naming the key), the defaults and the
documentation (``piezopress rig-keys``).
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Mapping

from piezopress.acquisition.plan import DriveLimits
from piezopress.errors import ConfigError


def param(default: Any, help: str, unit: str = "", lo: float | None = None, hi: float | None = None, lo_open: bool = False) -> Any:
    """A configuration key: default, meaning, unit and allowed range ``[lo, hi]`` (``(lo, hi]`` if lo_open)."""
    return field(default=default, metadata={"help": help, "unit": unit, "lo": lo, "hi": hi, "lo_open": lo_open})


@dataclass(frozen=True)
class RigSection:
    name: str = param("thesis press (virtual)", "name of the rig, recorded with every run")
    backend: str = param("virtual", "backend that runs this rig: 'virtual' (simulation)")
    seed: int = param(20261121, "seed of the simulator's random numbers (noise); same seed, same data", lo=0)


@dataclass(frozen=True)
class ActuatorSection:
    drive_min_v: float = param(0.0, "lowest allowed actuator voltage", "V", -200, 200)
    drive_max_v: float = param(150.0, "highest allowed actuator voltage (PSt 150: 150 V)", "V", -200, 200)
    capacitance_uf: float = param(3.6, "electrical capacitance of the stack (PSt 150/5/100 class: a few uF)", "uF", 0, 1000, True)
    max_force_n: float = param(800.0, "maximum load force of the stack (PSt 150/5/100 VS10: 800 N)", "N", 0, 1e5, True)


@dataclass(frozen=True)
class AmplifierSection:
    gain: float = param(20.0, "voltage gain of the piezo amplifier (EPA-102 set to 20)", "V/V", 0, 1000, True)
    output_min_v: float = param(-200.0, "lowest output voltage of the amplifier", "V", -1000, 1000)
    output_max_v: float = param(200.0, "highest output voltage of the amplifier", "V", -1000, 1000)
    current_limit_ma: float = param(200.0, "maximum output current (EPA-102: 200 mA)", "mA", 0, 1e5, True)


@dataclass(frozen=True)
class DaqSection:
    dac_bits: int = param(12, "resolution of the analog output (PCI-DAS1001: 12 bits)", "bit", 1, 32)
    dac_range_v: float = param(10.0, "analog output range +/-", "V", 0, 100, True)
    adc_bits: int = param(12, "resolution of the analog input (PCI-DAS1001: 12 bits)", "bit", 1, 32)
    adc_range_v: float = param(10.0, "analog input range +/-", "V", 0, 100, True)
    max_sample_rate_hz: float = param(100_000.0, "highest sample rate of the board", "Hz", 0, 1e8, True)


@dataclass(frozen=True)
class LoadCellSection:
    sensitivity_v_per_n: float = param(0.010003, "load cell with its amplifier (thesis Eq. 4.6: 10.003 mV/N)", "V/N", 0, 100, True)
    noise_v: float = param(0.000578, "RMS noise at the board input (thesis Section 4.2: 0.578 mV)", "V", 0, 10)
    offset_v: float = param(0.0, "offset of the amplified load-cell signal", "V", -10, 10)
    lowpass_hz: float = param(9596.0, "analog RC low-pass before the board (thesis Eq. 4.5: 9.6 kHz)", "Hz", 0, 1e7, True)


@dataclass(frozen=True)
class PressSection:
    gain_n_per_v: float = param(2.0, "force per actuator volt of the stack pressing on the cell (~300 N over 150 V)", "N/V", 0, 1e4, True)


@dataclass(frozen=True)
class HysteresisSection:
    """Asymmetric, saturating, rate-independent hysteresis of the stack.

    ``h = s(sum_i w_i play_{r_i}(v))``: play operators with thresholds ``r_i`` spread up to
    ``r_max_v`` and weights falling as ``exp(-r_i / r_scale_v)`` (a Preisach-like density),
    an elastic share without deadband, then a saturating static map
    ``s(u) = U tanh(k u / U) / tanh(k)`` (``U`` the maximum drive) that flattens the top of
    the loop, which makes the loop asymmetric.
    """

    enabled: bool = param(True, "switch the hysteresis off (a linear stack)")
    elastic_fraction: float = param(0.80, "share of the response without deadband", "", 0, 1)
    r_scale_v: float = param(20.0, "decay scale of the operator weights over the threshold", "V", 0, 1000, True)
    r_max_v: float = param(75.0, "largest threshold", "V", 0, 1000, True)
    n_operators: int = param(24, "number of play operators (fidelity of the simulation)", "", 1, 500)
    saturation: float = param(0.35, "saturation k of the static map (0: none)", "", 0, 5)


@dataclass(frozen=True)
class CreepSection:
    """Creep: the response to a held step keeps growing about linearly in log time.

    Modelled as a Prony series ``1 + sum_k g/(1 + tau_k s)`` with two time constants per
    decade from ``tau_min_s`` to ``tau_max_s`` and ``g = per_decade / 2``, which rises by
    ``per_decade`` of the step for every decade of time in that span.
    """

    enabled: bool = param(True, "switch creep off")
    per_decade: float = param(0.0113, "creep per decade of time, as a fraction of the step", "", 0, 0.5)
    tau_min_s: float = param(0.01, "shortest creep time constant", "s", 0, 1e6, True)
    tau_max_s: float = param(1.0e4, "longest creep time constant", "s", 0, 1e8, True)


@dataclass(frozen=True)
class ModeSection:
    """The lightly damped mode of stack, mass and load cell (thesis Eq. 6.2)."""

    enabled: bool = param(True, "switch the mode off (an infinitely stiff press)")
    natural_freq_rad_s: float = param(6440.0, "natural frequency (thesis: 6.44e3 rad/s)", "rad/s", 0, 1e7, True)
    damping: float = param(0.115, "damping ratio (thesis: 0.115)", "", 0, 2, True)


@dataclass(frozen=True)
class SimulationSection:
    min_rate_hz: float = param(20_000.0, "simulate at least this fast (the run's rate times an integer)", "Hz", 0, 1e7, True)


SECTIONS: dict[str, type] = {
    "rig": RigSection,
    "actuator": ActuatorSection,
    "amplifier": AmplifierSection,
    "daq": DaqSection,
    "load_cell": LoadCellSection,
    "press": PressSection,
    "hysteresis": HysteresisSection,
    "creep": CreepSection,
    "mode": ModeSection,
    "simulation": SimulationSection,
}


@dataclass(frozen=True)
class RigConfig:
    """A complete, checked rig configuration."""

    rig: RigSection = RigSection()
    actuator: ActuatorSection = ActuatorSection()
    amplifier: AmplifierSection = AmplifierSection()
    daq: DaqSection = DaqSection()
    load_cell: LoadCellSection = LoadCellSection()
    press: PressSection = PressSection()
    hysteresis: HysteresisSection = HysteresisSection()
    creep: CreepSection = CreepSection()
    mode: ModeSection = ModeSection()
    simulation: SimulationSection = SimulationSection()
    source: str = "<defaults>"

    @property
    def limits(self) -> DriveLimits:
        return DriveLimits(
            drive_min_v=self.actuator.drive_min_v,
            drive_max_v=self.actuator.drive_max_v,
            max_sample_rate_hz=self.daq.max_sample_rate_hz,
            max_force_n=self.actuator.max_force_n,
        )

    def as_dict(self) -> dict[str, dict[str, Any]]:
        return {name: dataclasses.asdict(getattr(self, name)) for name in SECTIONS}

    def replace(self, **sections: Mapping[str, Any]) -> "RigConfig":
        """A copy with some keys changed, checked like a file: ``cfg.replace(mode={"damping": 0.2})``."""
        doc = self.as_dict()
        for sec, values in sections.items():
            if sec not in doc:
                raise ConfigError(self.source, [f"unknown section [{sec}]; expected one of {', '.join(SECTIONS)}"])
            doc[sec] = {**doc[sec], **values}
        return parse_rig(doc, source=self.source)


def _check(section: str, cls: type, table: Mapping[str, Any], problems: list[str]) -> Any:
    known = {f.name: f for f in fields(cls)}
    values: dict[str, Any] = {}
    for key in sorted(set(table) - set(known)):
        problems.append(f"[{section}] unknown key '{key}'; expected one of {', '.join(known)}")
    for key, f in known.items():
        if key not in table:
            continue
        v = table[key]
        where = f"[{section}] {key} = {v!r}"
        kind = f.type if isinstance(f.type, type) else {"float": float, "int": int, "bool": bool, "str": str}[f.type]
        if kind is float and isinstance(v, int) and not isinstance(v, bool):
            v = float(v)
        if kind is bool and not isinstance(v, bool) or kind is not bool and (isinstance(v, bool) or not isinstance(v, kind)):
            problems.append(f"{where}: expected {kind.__name__}")
            continue
        if kind in (float, int):
            lo, hi, lo_open = f.metadata["lo"], f.metadata["hi"], f.metadata["lo_open"]
            unit = f" {f.metadata['unit']}" if f.metadata["unit"] else ""
            if isinstance(v, float) and not math.isfinite(v):
                problems.append(f"{where}: expected a finite number")
                continue
            below = lo is not None and (v <= lo if lo_open else v < lo)
            above = hi is not None and v > hi
            if below or above:
                rng = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]{unit}"
                problems.append(f"{where}: outside the allowed range {rng}")
                continue
        values[key] = v
    return cls(**values)


def parse_rig(doc: Mapping[str, Any], source: str = "<rig>") -> RigConfig:
    """Check a rig document completely; every problem names its section and key."""
    problems: list[str] = []
    sections: dict[str, Any] = {}
    for sec in sorted(set(doc) - set(SECTIONS)):
        problems.append(f"unknown section [{sec}]; expected one of {', '.join(SECTIONS)}")
    for sec, cls in SECTIONS.items():
        table = doc.get(sec, {})
        if not isinstance(table, Mapping):
            problems.append(f"[{sec}] must be a table")
            continue
        sections[sec] = _check(sec, cls, table, problems)
    if not problems:
        a, amp = sections["actuator"], sections["amplifier"]
        if a.drive_min_v >= a.drive_max_v:
            problems.append(f"[actuator] drive_min_v = {a.drive_min_v} must be below drive_max_v = {a.drive_max_v}")
        if amp.output_min_v > a.drive_min_v or amp.output_max_v < a.drive_max_v:
            problems.append(
                f"[amplifier] output range {amp.output_min_v:g} to {amp.output_max_v:g} V does not cover the drive range "
                f"{a.drive_min_v:g} to {a.drive_max_v:g} V"
            )
        if sections["rig"].backend != "virtual":
            problems.append(f"[rig] backend = {sections['rig'].backend!r}: only 'virtual' is available")
        c = sections["creep"]
        if c.tau_min_s >= c.tau_max_s:
            problems.append(f"[creep] tau_min_s = {c.tau_min_s} must be below tau_max_s = {c.tau_max_s}")
    if problems:
        raise ConfigError(source, problems)
    return RigConfig(**sections, source=source)


def load_rig(path: str | Path | None) -> RigConfig:
    """Read and check a rig TOML file (``None``: the built-in defaults)."""
    if path is None:
        return RigConfig()
    path = Path(path)
    if not path.is_file():
        raise ConfigError(str(path), ["no such file; expected a rig TOML file (see rigs/)"])
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(str(path), [f"not valid TOML: {exc}"]) from None
    return parse_rig(doc, source=str(path))


def describe_keys() -> str:
    """Every section and key with unit, default, range and meaning."""
    lines = []
    for sec, cls in SECTIONS.items():
        lines.append(f"[{sec}]")
        for f in fields(cls):
            m = f.metadata
            unit = f" [{m['unit']}]" if m["unit"] else ""
            rng = ""
            if m["lo"] is not None:
                rng = f", range {'(' if m['lo_open'] else '['}{m['lo']:g}, {m['hi']:g}]"
            lines.append(f"  {f.name}{unit} = {f.default!r}{rng}: {m['help']}")
    return "\n".join(lines)
