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
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from piezopress.acquisition.plan import DriveLimits
from piezopress.errors import ConfigError


def allowed_range(lo: float | None, hi: float | None, lo_open: bool = False) -> str:
    """``[lo, hi]``, ``(lo, hi]``, ``>= lo``, ``> lo`` or ``<= hi``: a range with a missing bound written as such."""
    if lo is not None and hi is not None:
        return f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
    if lo is not None:
        return f"{'>' if lo_open else '>='} {lo:g}"
    return f"<= {hi:g}" if hi is not None else "any value"


def param(
    default: Any, help: str, unit: str = "", lo: float | None = None, hi: float | None = None, lo_open: bool = False
) -> Any:
    """A configuration key: default, meaning, unit and allowed range ``[lo, hi]`` (``(lo, hi]`` if lo_open)."""
    return field(default=default, metadata={"help": help, "unit": unit, "lo": lo, "hi": hi, "lo_open": lo_open})


@dataclass(frozen=True)
class RigSection:
    name: str = param("thesis press (virtual)", "name of the rig, recorded with every run")
    backend: str = param("virtual", "backend that runs this rig: 'virtual' (simulation)")
    seed: int = param(20261121, "seed of the simulator's random numbers (noise); same seed, same data", lo=0)


@dataclass(frozen=True)
class ActuatorSection:
    drive_min_v: float = param(
        -30.0, "lowest allowed actuator voltage (PSt 150 stacks: -30 V, semi-bipolar)", "V", -200, 200
    )
    drive_max_v: float = param(150.0, "highest allowed actuator voltage (PSt 150: 150 V)", "V", -200, 200)
    capacitance_uf: float = param(
        4.8,
        "stack capacitance; with the current limit it sets the slew rate (calibrated to the 20 V overshoot)",
        "uF",
        0,
        1000,
        True,
    )
    max_force_n: float = param(800.0, "maximum load force of the stack (PSt 150/5/100 VS10: 800 N)", "N", 0, 1e5, True)


@dataclass(frozen=True)
class AmplifierSection:
    gain: float = param(20.0, "voltage gain of the piezo amplifier (EPA-102 set to 20)", "V/V", 0, 1000, True)
    output_min_v: float = param(-200.0, "lowest output voltage of the amplifier", "V", -1000, 1000)
    output_max_v: float = param(200.0, "highest output voltage of the amplifier", "V", -1000, 1000)
    current_limit_ma: float = param(200.0, "maximum output current (EPA-102: 200 mA)", "mA", 0, 1e5, True)
    slew_limit: bool = param(
        True, "effect amplifier_slew_limit: the current limit into the stack's capacitance limits dV/dt to I/C"
    )


@dataclass(frozen=True)
class DaqSection:
    dac_bits: int = param(12, "resolution of the analog output (PCI-DAS1001: 12 bits)", "bit", 1, 32)
    dac_range_v: float = param(10.0, "analog output range +/-", "V", 0, 100, True)
    adc_bits: int = param(12, "resolution of the analog input (PCI-DAS1001: 12 bits)", "bit", 1, 32)
    adc_range_v: float = param(10.0, "analog input range +/-", "V", 0, 100, True)
    max_sample_rate_hz: float = param(100_000.0, "highest sample rate of the board", "Hz", 0, 1e8, True)


@dataclass(frozen=True)
class LoadCellSection:
    sensitivity_v_per_n: float = param(
        0.010003, "load cell with its amplifier (thesis Eq. 4.6: 10.003 mV/N)", "V/N", 0, 100, True
    )
    noise_v: float = param(0.000578, "RMS noise at the board input (thesis Section 4.2: 0.578 mV)", "V", 0, 10)
    offset_v: float = param(0.0, "offset of the amplified load-cell signal", "V", -10, 10)
    lowpass_hz: float = param(
        9596.0, "analog RC low-pass before the board (thesis Eq. 4.5: 9.6 kHz)", "Hz", 0, 1e7, True
    )
    drift_n_per_min: float = param(
        0.0, "effect sensor_offset_drift: slow drift of the offset, in newtons per minute", "N/min", -100, 100
    )
    sensitivity_drift_per_h: float = param(
        0.0, "effect sensitivity_drift: the cell's gain drifts on the rig's clock, per hour", "1/h", -10, 10
    )
    mains_n: float = param(
        0.0, "effect mains_pickup: mains hum on the reading (amplitude, random phase per run)", "N", 0, 1000
    )
    mains_hz: float = param(50.0, "mains frequency of the hum", "Hz", 1, 1000, True)


@dataclass(frozen=True)
class PressSection:
    """The stack pressing on the load cell.

    Contact: the stack pushes on the cell only while pressed against it, so the cell reads
    ``max(0, preload + gain * x)``; a negative preload is a gap (no contact at rest).
    """

    gain_n_per_v: float = param(
        2.0, "force per actuator volt of the stack pressing on the cell (~300 N over 150 V)", "N/V", 0, 1e4, True
    )
    contact: bool = param(True, "model contact: the cell reads no tension (off: force may go negative)")
    delay_s: float = param(0.0, "effect input_delay: pure delay between command and response", "s", 0, 1.0)


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
    elastic_fraction: float = param(0.78, "share of the response without deadband", "", 0, 1)
    r_scale_v: float = param(20.0, "decay scale of the operator weights over the threshold", "V", 0, 1000, True)
    r_max_v: float = param(75.0, "largest threshold", "V", 0, 1000, True)
    n_operators: int = param(24, "number of play operators (fidelity of the simulation)", "", 1, 500)
    saturation: float = param(0.35, "effect hysteresis_order: saturation k of the static map (0: none)", "", 0, 5)
    rate_v_per_kv_s: float = param(
        0.10,
        "effect rate_dependent_hysteresis: every threshold grows this much per kV/s of drive rate",
        "V/(kV/s)",
        0,
        100,
    )
    rate_tau_s: float = param(5e-4, "time constant over which the drive rate is felt", "s", 0, 1, True)


@dataclass(frozen=True)
class CreepSection:
    """Creep: the response to a held step keeps growing about linearly in log time.

    Two forms, both a Prony series ``1 + sum_k g_k / (1 + tau_k s)`` (linear, so it
    commutes with the mode and is simulated on the run's own time grid):

    * ``log`` (effect logarithmic_creep): two time constants per decade from ``tau_min_s``
      to ``tau_max_s``, each ``g = per_decade / 2``, so the response to a held step rises by
      ``per_decade`` of the step for every decade of time: a few-pole model fitted on 120 s
      extrapolates badly;
    * ``poles``: two poles, ``pole_gains`` at ``pole_taus_s``; it saturates, as the
      thesis's creep model (Eq. 6.1) assumes.
    """

    enabled: bool = param(True, "switch creep off")
    form: str = param("log", "'log' (creep grows with log time) or 'poles' (saturating, two poles)")
    per_decade: float = param(0.0112, "log form: creep per decade of time, as a fraction of the step", "", 0, 0.5)
    tau_min_s: float = param(0.05, "log form: shortest creep time constant", "s", 0, 1e6, True)
    tau_max_s: float = param(1.0e4, "log form: longest creep time constant", "s", 0, 1e8, True)
    pole_gains: float = param(0.012, "poles form: gain of the fast and of the slow pole (each)", "", 0, 0.5)
    pole_fast_tau_s: float = param(1.5, "poles form: fast time constant", "s", 0, 1e6, True)
    pole_slow_tau_s: float = param(40.0, "poles form: slow time constant", "s", 0, 1e6, True)


@dataclass(frozen=True)
class ModeSection:
    """The lightly damped mode of stack, mass and load cell (thesis Eq. 6.2)."""

    enabled: bool = param(True, "switch the mode off (an infinitely stiff press)")
    natural_freq_rad_s: float = param(6440.0, "natural frequency (thesis: 6.44e3 rad/s)", "rad/s", 1.0, 1e7)
    damping: float = param(0.115, "damping ratio (thesis: 0.115)", "", 0, 2, True)


@dataclass(frozen=True)
class Mode2Section:
    """Effect second_resonance: a second, weaker mode sharing the response."""

    enabled: bool = param(False, "switch the second mode on")
    natural_freq_rad_s: float = param(17_000.0, "natural frequency", "rad/s", 1.0, 1e7)
    damping: float = param(0.05, "damping ratio", "", 0, 2, True)
    share: float = param(0.15, "share of the response through this mode", "", 0, 1)


@dataclass(frozen=True)
class InterferenceSection:
    """Effect drive_coupled_interference: the notch of thesis Section 5.3.

    The drive current ``i = C dv/dt`` into the stack couples into the load-cell amplifier.
    Its envelope ``i_f`` (``|i|`` through a first-order low-pass of ``tau_s``) drives the
    instrumentation amplifier out of its linear range once above ``threshold`` of the
    current limit, and the reading dips by ``depth_n * (i_f/I_max - threshold) / (1 - threshold)``
    scaled by ``(reference_distance_mm / distance_mm)^2``. So it appears only for large
    steps (long pulses at the current limit) and fast ones, with or without contact, and
    fades with distance, as the thesis observed (Fig. 5.6-5.9).
    """

    enabled: bool = param(True, "switch the interference on")
    depth_n: float = param(40.0, "depth of the notch at full current, at the reference distance", "N", 0, 1e4)
    threshold: float = param(0.5, "fraction of the current limit below which nothing couples", "", 0, 0.99)
    tau_s: float = param(1.5e-3, "time constant of the current envelope", "s", 0, 1, True)
    distance_mm: float = param(5.0, "distance between stack and load cell", "mm", 0, 1e4, True)
    reference_distance_mm: float = param(5.0, "distance at which depth_n applies", "mm", 0, 1e4, True)


@dataclass(frozen=True)
class SimulationSection:
    min_rate_hz: float = param(20_000.0, "simulate fast drive changes at least this fast", "Hz", 0, 1e7, True)
    fast_step_v: float = param(
        1.0, "a drive change larger than this in one sample is simulated finely", "V", 0, 1e4, True
    )
    fine_window_s: float = param(0.02, "how long after a fast change the fine simulation goes on", "s", 0, 10, True)


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
    "mode2": Mode2Section,
    "interference": InterferenceSection,
    "simulation": SimulationSection,
}


@dataclass(frozen=True)
class Effect:
    """An effect the thesis's model leaves out (and ``diagnose`` must find): where it is set.

    ``key`` of ``[section]`` switches it: ``off`` is the value without it, ``on`` the value
    that switches it on (its magnitude). The thesis-like default rig has some on already.
    """

    section: str
    key: str
    off: Any
    on: Any
    physics: str


#: Effects beyond the core, by the id ``diagnose`` uses.
EFFECTS: dict[str, Effect] = {
    "rate_dependent_hysteresis": Effect("hysteresis", "rate_v_per_kv_s", 0.0, 0.10, "loop widens with the drive rate"),
    "amplifier_slew_limit": Effect(
        "amplifier", "slew_limit", False, True, "current limit into the capacitance: dV/dt <= I/C"
    ),
    "drive_coupled_interference": Effect(
        "interference", "enabled", False, True, "drive current couples into the load-cell reading"
    ),
    "logarithmic_creep": Effect("creep", "form", "poles", "log", "creep grows with log time instead of saturating"),
    "second_resonance": Effect("mode2", "enabled", False, True, "a second, weaker mode"),
    "sensor_offset_drift": Effect("load_cell", "drift_n_per_min", 0.0, 0.5, "slow drift of the load-cell offset"),
    "input_delay": Effect("press", "delay_s", 0.0, 2e-4, "pure delay between command and response"),
    "hysteresis_order": Effect("hysteresis", "saturation", 0.0, 0.35, "saturating, asymmetric static map"),
    "mains_pickup": Effect("load_cell", "mains_n", 0.0, 0.5, "mains hum on the load-cell reading"),
    "sensitivity_drift": Effect(
        "load_cell", "sensitivity_drift_per_h", 0.0, 0.1, "the load cell's gain drifts over the test"
    ),
}


class SectionedConfig:
    """``as_dict`` and ``replace`` for a configuration made of section dataclasses.

    Subclasses set ``SECTION_TYPES`` (section name -> dataclass) and ``_parse`` (the checked
    parser of a whole document)."""

    SECTION_TYPES: dict[str, type] = {}
    source: str

    def as_dict(self) -> dict[str, dict[str, Any]]:
        return {name: dataclasses.asdict(getattr(self, name)) for name in self.SECTION_TYPES}

    def replace(self, **sections: Mapping[str, Any]):
        """A copy with some keys changed, checked like a file: ``cfg.replace(mode={"damping": 0.2})``."""
        doc = self.as_dict()
        for sec, values in sections.items():
            if sec not in doc:
                raise ConfigError(
                    self.source, [f"unknown section [{sec}]; expected one of {', '.join(self.SECTION_TYPES)}"]
                )
            doc[sec] = {**doc[sec], **values}
        return self._parse(doc, source=self.source)

    @classmethod
    def _parse(cls, doc: Mapping[str, Any], source: str):
        raise NotImplementedError


@dataclass(frozen=True)
class RigConfig(SectionedConfig):
    """A complete, checked rig configuration."""

    SECTION_TYPES = SECTIONS

    rig: RigSection = RigSection()
    actuator: ActuatorSection = ActuatorSection()
    amplifier: AmplifierSection = AmplifierSection()
    daq: DaqSection = DaqSection()
    load_cell: LoadCellSection = LoadCellSection()
    press: PressSection = PressSection()
    hysteresis: HysteresisSection = HysteresisSection()
    creep: CreepSection = CreepSection()
    mode: ModeSection = ModeSection()
    mode2: Mode2Section = Mode2Section()
    interference: InterferenceSection = InterferenceSection()
    simulation: SimulationSection = SimulationSection()
    source: str = "<defaults>"

    @classmethod
    def clean(cls) -> RigConfig:
        """The default press with every effect of :data:`EFFECTS` switched off.

        What is left is what the thesis's model describes: rate-independent hysteresis
        without saturation, saturating creep, one mode, and the sensor's noise and
        quantization.
        """
        return cls().replace(**_effect_values({name: False for name in EFFECTS}))

    @classmethod
    def only(cls, effect: str, **magnitude: Any) -> RigConfig:
        """The clean rig with one effect on: ``RigConfig.only("input_delay", delay_s=5e-4)``.

        Keyword arguments set keys of the effect's section (its magnitude).
        """
        if effect not in EFFECTS:
            raise ConfigError("<code>", [f"effect {effect!r} is unknown; expected one of {', '.join(EFFECTS)}"])
        cfg = cls.clean().replace(**_effect_values({effect: True}))
        return cfg.replace(**{EFFECTS[effect].section: magnitude}) if magnitude else cfg

    def effects_on(self) -> list[str]:
        """The ids of the effects this configuration switches on."""
        return [n for n, e in EFFECTS.items() if getattr(getattr(self, e.section), e.key) != e.off]

    @property
    def limits(self) -> DriveLimits:
        return DriveLimits(
            drive_min_v=self.actuator.drive_min_v,
            drive_max_v=self.actuator.drive_max_v,
            max_sample_rate_hz=self.daq.max_sample_rate_hz,
            max_force_n=self.actuator.max_force_n,
        )

    @classmethod
    def _parse(cls, doc: Mapping[str, Any], source: str) -> RigConfig:
        return parse_rig(doc, source=source)


#: Magnitudes at which each effect is meant to be found by ``diagnose`` (documented ranges;
#: tests and ``bench/bench_diagnose.py`` draw from them with a seeded generator). Keys of the
#: effect's section, each ``(low, high)``; a drift is drawn with a random sign.
DETECTABLE: dict[str, dict[str, tuple[float, float]]] = {
    "rate_dependent_hysteresis": {"rate_v_per_kv_s": (0.05, 0.2)},
    "amplifier_slew_limit": {},  # with [actuator] capacitance_uf drawn from DETECTABLE_ACTUATOR
    "drive_coupled_interference": {"depth_n": (20.0, 60.0)},
    "logarithmic_creep": {"per_decade": (0.008, 0.016)},
    "second_resonance": {"share": (0.1, 0.25), "natural_freq_rad_s": (14_000.0, 22_000.0)},
    "sensor_offset_drift": {"drift_n_per_min": (0.3, 1.5)},
    "input_delay": {"delay_s": (1e-4, 5e-4)},
    "hysteresis_order": {"saturation": (0.25, 0.6)},
    "mains_pickup": {"mains_n": (0.3, 1.0)},
    "sensitivity_drift": {"sensitivity_drift_per_h": (0.03, 0.1)},
}
#: The slew limit's magnitude lives in the actuator: I/C with C in this range is 25-67 V/ms.
DETECTABLE_ACTUATOR = {"capacitance_uf": (3.0, 8.0)}


def hidden_effect(effect: str, rng, base: RigConfig | None = None) -> RigConfig:
    """A clean rig (or ``base``) with ``effect`` on at a magnitude drawn from :data:`DETECTABLE`,
    and a noise seed drawn too: the rig a diagnosis test hides one effect in."""
    cfg = base or RigConfig.clean()
    cfg = cfg.replace(**_effect_values({effect: True}))
    draw = {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in DETECTABLE[effect].items()}
    if effect == "sensor_offset_drift":
        draw["drift_n_per_min"] *= float(rng.choice([-1.0, 1.0]))
    if effect == "sensitivity_drift":
        draw["sensitivity_drift_per_h"] *= float(rng.choice([-1.0, 1.0]))
    changes: dict[str, dict[str, Any]] = {EFFECTS[effect].section: draw} if draw else {}
    if effect == "amplifier_slew_limit":
        changes["actuator"] = {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in DETECTABLE_ACTUATOR.items()}
    changes.setdefault("rig", {})["seed"] = int(rng.integers(0, 2**31))
    return cfg.replace(**changes)


def _effect_values(switch: Mapping[str, bool]) -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for name, on in switch.items():
        e = EFFECTS[name]
        out.setdefault(e.section, {})[e.key] = e.on if on else e.off
    return out


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
        if (
            kind is bool
            and not isinstance(v, bool)
            or kind is not bool
            and (isinstance(v, bool) or not isinstance(v, kind))
        ):
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
                problems.append(f"{where}: outside the allowed range {allowed_range(lo, hi, lo_open)}{unit}")
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
                f"[amplifier] output range {amp.output_min_v:g} to {amp.output_max_v:g} V does not cover the drive "
                "range "
                f"{a.drive_min_v:g} to {a.drive_max_v:g} V"
            )
        if sections["rig"].backend != "virtual":
            problems.append(f"[rig] backend = {sections['rig'].backend!r}: only 'virtual' is available")
        c = sections["creep"]
        if c.form not in ("log", "poles"):
            problems.append(f"[creep] form = {c.form!r}: expected 'log' or 'poles'")
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
        doc = tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(str(path), [f"not valid TOML: {exc}"]) from None
    return parse_rig(doc, source=str(path))


def describe_sections(sections: Mapping[str, type]) -> str:
    """Every section and key of ``sections`` (name -> config dataclass) with unit, default,
    range and meaning."""
    lines = []
    for sec, cls in sections.items():
        lines.append(f"[{sec}]")
        for f in fields(cls):
            m = f.metadata
            unit = f" [{m['unit']}]" if m["unit"] else ""
            rng = ""
            if m["lo"] is not None or m["hi"] is not None:
                rng = f", range {allowed_range(m['lo'], m['hi'], m['lo_open'])}"
            lines.append(f"  {f.name}{unit} = {f.default!r}{rng}: {m['help']}")
    return "\n".join(lines)


def describe_keys() -> str:
    """Every section and key of a virtual rig file with unit, default, range and meaning."""
    return describe_sections(SECTIONS)
