"""Characterization plans: human-editable TOML files describing scripted protocols.

A plan is a ``[plan]`` table and a list of ``[[protocol]]`` tables::

    [plan]
    name = "thesis-characterization"
    preload_n = 50.0            # default for every protocol

    [[protocol]]
    name = "triangle-0.1hz"
    kind = "triangle"
    freq_hz = 0.1
    cycles = 3
    peak_v = 150.0
    sample_rate_hz = 1000.0

The keys each kind accepts are data (:data:`KINDS`): the same table drives validation,
defaults, documentation (``piezopress protocols``) and waveform generation. A plan is
checked completely before anything runs, and every problem is reported at once with the
file, the protocol and the key.
"""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from piezopress.acquisition import waveforms
from piezopress.errors import PlanError


@dataclass(frozen=True)
class DriveLimits:
    """What a backend can safely do; plans are checked against it before anything runs."""

    drive_min_v: float = 0.0
    drive_max_v: float = 150.0
    max_sample_rate_hz: float = 100_000.0
    max_force_n: float = 800.0
    max_duration_s: float = 3600.0
    max_samples: int = 50_000_000
    #: fastest change of the drive the actuator (or amplifier) allows; ``inf``: no limit stated
    slew_limit_v_per_s: float = math.inf
    #: samples of all the protocols of one plan together (each is held in memory while it runs, then written)
    max_plan_samples: int = 200_000_000


#: Bytes a sample costs in memory along the chain (drive, time, 2-4 measured channels, the
#: run frame and its Parquet buffer): used to state the memory a plan implies.
BYTES_PER_SAMPLE = 64
#: Longest protocol name: it names a file (``NAME.incomplete.parquet``) on every file system.
MAX_NAME_CHARS = 100


def memory_text(samples: float) -> str:
    """The memory ``samples`` imply, e.g. ``about 3.2 GB``."""
    b = samples * BYTES_PER_SAMPLE
    for unit, size in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if b >= size:
            return f"about {b / size:.3g} {unit}"
    return f"about {b / 1e3:.3g} kB"


@dataclass(frozen=True)
class Key:
    """One key of a protocol table: its type, default (``REQUIRED`` if none) and meaning."""

    type: type | tuple[type, ...]
    default: Any
    help: str
    unit: str = ""


REQUIRED = object()
DRIVE_MAX = object()  # default resolved to the backend's maximum drive
DRIVE_MIN = object()  # default resolved to the backend's lowest drive
_NUM = (int, float)

COMMON_KEYS: dict[str, Key] = {
    "name": Key(str, REQUIRED, "unique name of the protocol; names the run file"),
    "kind": Key(str, REQUIRED, "protocol kind"),
    "sample_rate_hz": Key(_NUM, REQUIRED, "sample rate of drive and measurement", "Hz"),
    "preload_n": Key(_NUM, None, "preload of the stack against the load cell (default: [plan] preload_n)", "N"),
    "description": Key(str, "", "free text"),
}


@dataclass(frozen=True)
class KindSpec:
    """A protocol kind: its run kind, its keys, a waveform builder and an extra check."""

    run_kind: str
    keys: dict[str, Key]
    build: Callable[[Mapping[str, Any], float], np.ndarray]
    check: Callable[[Mapping[str, Any], float], list[str]]
    summary: str


def _triangle_peaks(p: Mapping[str, Any]) -> np.ndarray:
    if p.get("peaks_v") is not None:
        return np.asarray(p["peaks_v"], dtype=np.float64)
    rp = p.get("random_peaks")
    if rp is not None:
        rng = np.random.default_rng(int(rp["seed"]))
        return rng.uniform(float(rp["min_v"]), float(rp["max_v"]), int(rp["count"]))
    return np.full(int(p["cycles"]), float(p["peak_v"]))


def _build_triangle(p: Mapping[str, Any], fs: float) -> np.ndarray:
    return waveforms.triangle(p["freq_hz"], _triangle_peaks(p), p["low_v"], fs)


def _check_frequency(p: Mapping[str, Any], fs: float) -> list[str]:
    if p["freq_hz"] <= 0:
        return [f"key 'freq_hz' = {p['freq_hz']} must be positive"]
    if fs < 20 * p["freq_hz"]:
        return [
            f"key 'sample_rate_hz' = {fs:g} is too low for freq_hz = {p['freq_hz']:g}: "
            f"expected at least 20 samples per cycle ({20 * p['freq_hz']:g} Hz)"
        ]
    return []


def _check_periodic(p: Mapping[str, Any], fs: float) -> list[str]:
    problems = _check_frequency(p, fs)
    if p.get("cycles") is not None and (not isinstance(p["cycles"], int) or p["cycles"] < 1):
        problems.append(f"key 'cycles' = {p['cycles']!r} must be a whole number of at least 1")
    if p.get("peaks_v") is None and p.get("random_peaks") is None and p["low_v"] >= p["peak_v"]:
        problems.append(
            f"key 'low_v' = {p['low_v']:g} is not below peak_v = {p['peak_v']:g}; expected low_v < peak_v (the sweep "
            "rises from low_v to peak_v)"
        )
    return problems


def _check_below_rest(p: Mapping[str, Any], fs: float) -> list[str]:
    problems = _check_frequency(p, fs)
    peaks = p["peaks_v"]
    if (
        not isinstance(peaks, list)
        or len(peaks) < 2
        or not all(isinstance(v, _NUM) and not isinstance(v, bool) for v in peaks)
    ):
        problems.append(f"key 'peaks_v' = {peaks!r} must be a list of at least two voltages (low_v lies between peaks)")
    elif min(peaks) <= max(p["low_v"], p["rest_v"]):
        problems.append(
            f"key 'peaks_v': {min(peaks):g} is not above low_v = {p['low_v']:g} and rest_v = {p['rest_v']:g}; "
            "expected every peak above both"
        )
    depths = p.get("depths")
    if depths is not None and (
        not isinstance(depths, list)
        or not isinstance(peaks, list)
        or len(depths) != len(peaks) - 1
        or not all(isinstance(v, _NUM) and not isinstance(v, bool) and 0.0 <= v <= 1.0 for v in depths)
    ):
        n = len(peaks) - 1 if isinstance(peaks, list) else "one fewer than the peaks"
        problems.append(f"key 'depths' = {depths!r} must list {n} shares from 0 to 1, one per low between two peaks")
    if p["low_v"] > p["rest_v"]:
        problems.append(
            f"key 'low_v' = {p['low_v']:g} is above rest_v = {p['rest_v']:g}; expected the sweep to go down to or "
            "below its rest"
        )
    return problems


def _check_triangle(p: Mapping[str, Any], fs: float) -> list[str]:
    problems = _check_periodic(p, fs)
    given = [k for k in ("peaks_v", "random_peaks") if p.get(k) is not None]
    if len(given) > 1:
        problems.append("keys 'peaks_v' and 'random_peaks' exclude each other; give one")
    if p.get("peaks_v") is not None:
        peaks = p["peaks_v"]
        if (
            not isinstance(peaks, list)
            or not peaks
            or not all(isinstance(v, _NUM) and not isinstance(v, bool) for v in peaks)
        ):
            problems.append(f"key 'peaks_v' = {peaks!r} must be a non-empty list of voltages")
        elif min(peaks) <= p["low_v"]:
            problems.append(
                f"key 'peaks_v': {min(peaks):g} is not above low_v = {p['low_v']:g}; expected every peak above low_v"
            )
    rp = p.get("random_peaks")
    if rp is not None:
        need = {"count": int, "min_v": _NUM, "max_v": _NUM, "seed": int}
        if not isinstance(rp, dict):
            problems.append(f"key 'random_peaks' = {rp!r} must be a table {{count, min_v, max_v, seed}}")
        else:
            for k in sorted(set(rp) - set(need)):
                problems.append(f"key 'random_peaks.{k}' is unknown; expected count, min_v, max_v, seed")
            for k, t in need.items():
                if k not in rp:
                    problems.append(f"key 'random_peaks.{k}' is missing; expected count, min_v, max_v, seed")
                elif not isinstance(rp[k], t) or isinstance(rp[k], bool):
                    problems.append(f"key 'random_peaks.{k}' = {rp[k]!r} has the wrong type")
            if not problems and rp["count"] < 1:
                problems.append(f"key 'random_peaks.count' = {rp['count']} must be at least 1")
            if not problems and rp["min_v"] > rp["max_v"]:
                problems.append(f"key 'random_peaks': min_v = {rp['min_v']} is above max_v = {rp['max_v']}")
            if not problems and rp["min_v"] <= p["low_v"]:
                problems.append(
                    f"key 'random_peaks': min_v = {rp['min_v']} is not above low_v = {p['low_v']:g}; expected every "
                    "peak above low_v"
                )
            if not problems and rp["seed"] < 0:
                problems.append(f"key 'random_peaks.seed' = {rp['seed']} is negative; expected a whole number >= 0")
    return problems


def _check_step(p: Mapping[str, Any], fs: float) -> list[str]:
    problems = []
    for k in ("pre_s", "post_s"):
        if p[k] < 0:
            problems.append(f"key '{k}' = {p[k]} must not be negative")
    if p["hold_s"] * fs < 10:
        problems.append(
            f"key 'hold_s' = {p['hold_s']} lasts fewer than 10 samples at {fs:g} Hz; expected a longer hold"
        )
    if p["pre_s"] > 0 and p["pre_s"] * fs < 1:
        problems.append(f"key 'pre_s' = {p['pre_s']} is shorter than one sample at {fs:g} Hz")
    return problems


def _check_staircase(p: Mapping[str, Any], fs: float) -> list[str]:
    problems = []
    if not isinstance(p["count"], int) or p["count"] < 1:
        problems.append(f"key 'count' = {p['count']!r} must be a whole number of at least 1")
    if p["ramp_s"] * fs < 1:
        problems.append(
            f"key 'ramp_s' = {p['ramp_s']} is shorter than one sample at {fs:g} Hz; expected at least {1 / fs:g} s"
        )
    if p["dwell_s"] * fs < 10:
        problems.append(f"key 'dwell_s' = {p['dwell_s']} lasts fewer than 10 samples at {fs:g} Hz")
    if p["pre_s"] < 0:
        problems.append(f"key 'pre_s' = {p['pre_s']} must not be negative")
    return problems


def _check_custom(p: Mapping[str, Any], fs: float) -> list[str]:
    pts = p["points"]
    ok = (
        isinstance(pts, list)
        and len(pts) >= 2
        and all(
            isinstance(q, list) and len(q) == 2 and all(isinstance(x, _NUM) and not isinstance(x, bool) for x in q)
            for q in pts
        )
    )
    if not ok:
        return [f"key 'points' must be a list of at least two [t_s, volts] pairs, got {pts!r}"[:200]]
    t = np.array([q[0] for q in pts], dtype=float)
    if t[0] != 0 or np.any(np.diff(t) <= 0):
        return ["key 'points': times must start at 0 and strictly increase"]
    return []


def _check_random(p: Mapping[str, Any], fs: float) -> list[str]:
    problems = []
    if not 0 < p["low_hz"] < p["high_hz"]:
        problems.append(
            f"keys 'low_hz' = {p['low_hz']:g} and 'high_hz' = {p['high_hz']:g}: expected 0 < low_hz < high_hz"
        )
    elif fs < 20 * p["high_hz"]:
        problems.append(
            f"key 'sample_rate_hz' = {fs:g} is too low for high_hz = {p['high_hz']:g}: expected at least "
            f"{20 * p['high_hz']:g} Hz"
        )
    elif p["duration_s"] * p["low_hz"] < 1:
        problems.append(
            f"key 'duration_s' = {p['duration_s']:g} is shorter than one period of low_hz = {p['low_hz']:g}"
        )
    if p["taper_s"] < 0:
        problems.append(f"key 'taper_s' = {p['taper_s']:g} must not be negative")
    if p["seed"] < 0:
        problems.append(f"key 'seed' = {p['seed']} is negative; expected a whole number >= 0")
    if p["low_v"] > p["peak_v"]:
        problems.append(f"key 'low_v' = {p['low_v']:g} is above peak_v = {p['peak_v']:g}")
    return problems


_STEP_KEYS = {
    "level_v": Key(_NUM, DRIVE_MAX, "drive during the hold (default: maximum drive)", "V"),
    "base_v": Key(_NUM, 0.0, "drive before and after the step", "V"),
    "pre_s": Key(_NUM, 0.01, "time at base_v before the step", "s"),
    "hold_s": Key(_NUM, REQUIRED, "time at level_v", "s"),
    "post_s": Key(_NUM, 0.0, "time back at base_v after the hold", "s"),
}

_PERIODIC_KEYS = {
    "freq_hz": Key(_NUM, REQUIRED, "frequency of the sweep", "Hz"),
    "cycles": Key(int, 1, "number of cycles (ignored when peaks_v or random_peaks is given)"),
    "low_v": Key(_NUM, 0.0, "lowest drive of each cycle", "V"),
    "peak_v": Key(_NUM, DRIVE_MAX, "highest drive of each cycle (default: maximum drive)", "V"),
}

KINDS: dict[str, KindSpec] = {
    "triangle": KindSpec(
        "triangle",
        _PERIODIC_KEYS
        | {
            "peaks_v": Key(list, None, "one peak voltage per cycle (increasing amplitudes, say)", "V"),
            "random_peaks": Key(dict, None, "random peak per cycle: {count, min_v, max_v, seed}"),
        },
        _build_triangle,
        _check_triangle,
        "triangular sweeps low_v -> peak -> low_v (hysteresis, Table 5.1)",
    ),
    "below_rest": KindSpec(
        "triangle",
        {
            "freq_hz": Key(_NUM, REQUIRED, "frequency of the sweep (one peak and one low per period)", "Hz"),
            "peaks_v": Key(list, REQUIRED, "the peaks, in order", "V"),
            "low_v": Key(_NUM, DRIVE_MIN, "the drive between the peaks", "V"),
            "rest_v": Key(_NUM, 0.0, "the drive the sweep starts from and ends at, from above", "V"),
            "depths": Key(
                list, None, "per low between two peaks, how far from rest_v down to low_v it goes (0-1; default: 1)"
            ),
        },
        lambda p, fs: waveforms.below_rest(
            p["freq_hz"],
            np.asarray(p["peaks_v"], float),
            p["low_v"],
            p["rest_v"],
            fs,
            None if p.get("depths") is None else np.asarray(p["depths"], float),
        ),
        _check_below_rest,
        "triangular sweeps from rest_v up to each peak and down to low_v between them, back to rest_v from above "
        "(the stack below its rest, where a compensator pulling the press down to the preload drives)",
    ),
    "sine": KindSpec(
        "sine",
        dict(_PERIODIC_KEYS),
        lambda p, fs: waveforms.sine(p["freq_hz"], p["cycles"], p["low_v"], p["peak_v"], fs),
        _check_periodic,
        "raised-cosine cycles low_v -> peak_v -> low_v",
    ),
    "step": KindSpec(
        "step",
        dict(_STEP_KEYS),
        lambda p, fs: waveforms.step(p["base_v"], p["level_v"], p["pre_s"], p["hold_s"], p["post_s"], fs),
        _check_step,
        "an ideal step and back (overshoot, settling; Section 5.3)",
    ),
    "creep": KindSpec(
        "creep",
        dict(_STEP_KEYS),
        lambda p, fs: waveforms.step(p["base_v"], p["level_v"], p["pre_s"], p["hold_s"], p["post_s"], fs),
        _check_step,
        "a step held long (creep after 120 s; Section 5.2)",
    ),
    "staircase": KindSpec(
        "staircase",
        {
            "base_v": Key(_NUM, 0.0, "starting drive", "V"),
            "step_v": Key(_NUM, REQUIRED, "height of each stair", "V"),
            "count": Key(int, REQUIRED, "number of stairs"),
            "dwell_s": Key(_NUM, REQUIRED, "time on each stair", "s"),
            "ramp_s": Key(_NUM, REQUIRED, "duration of the linear ramp to each stair", "s"),
            "pre_s": Key(_NUM, 0.0, "time at base_v before the first ramp", "s"),
        },
        lambda p, fs: waveforms.staircase(
            p["base_v"], p["step_v"], p["count"], p["dwell_s"], p["ramp_s"], p["pre_s"], fs
        ),
        _check_staircase,
        "stairs reached by short ramps (tracking; Section 6.6)",
    ),
    "random": KindSpec(
        "custom",
        {
            "low_hz": Key(_NUM, 0.2, "lowest frequency of the flat band", "Hz"),
            "high_hz": Key(_NUM, 20.0, "highest frequency of the flat band", "Hz"),
            "duration_s": Key(_NUM, REQUIRED, "length of the trajectory", "s"),
            "low_v": Key(_NUM, 0.0, "lowest drive (also the start and the end)", "V"),
            "peak_v": Key(_NUM, DRIVE_MAX, "highest drive (default: maximum drive)", "V"),
            "seed": Key(int, 1, "seed of the random phases (same seed, same trajectory)"),
            "taper_s": Key(_NUM, 0.5, "fade in from and out to low_v over this long", "s"),
        },
        lambda p, fs: waveforms.random_band(
            p["low_hz"], p["high_hz"], p["duration_s"], p["low_v"], p["peak_v"], p["seed"], p["taper_s"], fs
        ),
        _check_random,
        "a seeded random trajectory, flat spectrum low_hz to high_hz (tracking of a random force)",
    ),
    "custom": KindSpec(
        "custom",
        {
            "points": Key(
                list, REQUIRED, "piecewise-linear drive: [[t_s, volts], ...], times from 0 strictly increasing"
            )
        },
        lambda p, fs: waveforms.piecewise_linear(
            np.array([q[0] for q in p["points"]]), np.array([q[1] for q in p["points"]]), fs
        ),
        _check_custom,
        "any piecewise-linear drive",
    ),
}


def estimated_duration_s(kind: str, p: Mapping[str, Any]) -> float:
    """How long a checked protocol lasts, from its keys alone (nothing built): the cost of a
    protocol is known before any memory is spent on it."""
    if kind in ("triangle", "sine"):
        if kind == "triangle" and p.get("peaks_v") is not None:
            cycles = len(p["peaks_v"])
        elif kind == "triangle" and p.get("random_peaks") is not None:
            cycles = p["random_peaks"]["count"]
        else:
            cycles = p["cycles"]
        return float(cycles) / float(p["freq_hz"])
    if kind in ("step", "creep"):
        return float(p["pre_s"]) + float(p["hold_s"]) + float(p["post_s"])
    if kind == "staircase":
        return float(p["pre_s"]) + float(p["count"]) * (float(p["ramp_s"]) + float(p["dwell_s"]))
    if kind == "random":
        return float(p["duration_s"])
    if kind == "below_rest":
        return float(len(p["peaks_v"])) / float(p["freq_hz"])
    return float(p["points"][-1][0])


PLAN_KEYS: dict[str, Key] = {
    "name": Key(str, REQUIRED, "name of the plan"),
    "description": Key(str, "", "free text"),
    "preload_n": Key(_NUM, 50.0, "default preload for every protocol (thesis Section 6.1: at least 50 N)", "N"),
}


@dataclass(frozen=True)
class Protocol:
    """One checked protocol: every key resolved to a value (defaults filled in).

    ``unit`` is ``"V"`` for a drive plan and ``"N"`` for a reference plan (validation),
    whose keys end in ``_n`` instead of ``_v``; ``params`` always uses the ``_v`` names.
    """

    name: str
    kind: str
    sample_rate_hz: float
    preload_n: float
    params: Mapping[str, Any]
    unit: str = "V"

    @property
    def run_kind(self) -> str:
        return KINDS[self.kind].run_kind

    def waveform(self) -> tuple[np.ndarray, np.ndarray]:
        """``(t_s, command_v)`` of this protocol."""
        command_v = KINDS[self.kind].build(self.params, self.sample_rate_hz)
        return waveforms.time_axis(len(command_v), self.sample_rate_hz), command_v

    @property
    def duration_s(self) -> float:
        return len(KINDS[self.kind].build(self.params, self.sample_rate_hz)) / self.sample_rate_hz

    def as_dict(self) -> dict[str, Any]:
        """The protocol as stored in run metadata and manifests (TOML-compatible values), with
        the key names of its plan (``_n`` for a reference plan)."""
        params = _rename_keys(dict(self.params), "_v", "_n") if self.unit == "N" else dict(self.params)
        return {
            "name": self.name,
            "kind": self.kind,
            "sample_rate_hz": self.sample_rate_hz,
            "preload_n": self.preload_n,
            **params,
        }


@dataclass(frozen=True)
class Plan:
    name: str
    description: str
    protocols: tuple[Protocol, ...]
    source: str = "<plan>"
    raw: Mapping[str, Any] = field(default_factory=dict)

    @property
    def duration_s(self) -> float:
        return sum(p.duration_s for p in self.protocols)


def _type_ok(value: Any, expected: type | tuple[type, ...]) -> bool:
    if isinstance(value, bool):
        return expected is bool
    return isinstance(value, expected)


def _type_name(expected: type | tuple[type, ...]) -> str:
    if expected == _NUM:
        return "a number"
    return {str: "a string", int: "a whole number", list: "a list", dict: "a table"}.get(expected, str(expected))


def _resolve(
    table: Mapping[str, Any], keys: Mapping[str, Key], where: str, limits: DriveLimits, problems: list[str]
) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k in sorted(set(table) - set(keys)):
        problems.append(f"{where}: unknown key '{k}'; expected one of {', '.join(keys)}")
    for k, spec in keys.items():
        if k in table:
            v = table[k]
            if not _type_ok(v, spec.type):
                problems.append(f"{where}: key '{k}' = {v!r} is not {_type_name(spec.type)}")
                continue
            if isinstance(v, float) and not math.isfinite(v):
                problems.append(f"{where}: key '{k}' = {v!r} is not a finite number")
                continue
            out[k] = float(v) if spec.type == _NUM else v
        elif spec.default is REQUIRED:
            problems.append(f"{where}: key '{k}' is missing ({spec.help})")
        elif spec.default is DRIVE_MAX:
            out[k] = float(limits.drive_max_v)
        elif spec.default is DRIVE_MIN:
            out[k] = float(limits.drive_min_v)
        else:
            out[k] = spec.default
    return out


_UNIT_WORDS = {
    "N": [
        (" V,", " N,"),
        (" V ", " N "),
        (" V)", " N)"),
        ("drive reaches", "reference reaches"),
        ("the actuator's range", "the allowed reference range"),
        ("voltages", "forces"),
        ("maximum drive", "maximum force"),
    ]
}


def _keys(obj: Any) -> list[str]:
    """Every key of a nested mapping (tables in tables, as ``random_peaks = {min_v = ...}``)."""
    if not isinstance(obj, Mapping):
        return []
    return [k for k in obj if isinstance(k, str)] + [k for v in obj.values() for k in _keys(v)]


def _rename_keys(obj: Any, old: str, new: str) -> Any:
    """Rename keys ending in ``old`` (recursively in tables): ``level_n`` <-> ``level_v``."""
    if isinstance(obj, dict):
        return {
            (k[: -len(old)] + new if isinstance(k, str) and k.endswith(old) else k): _rename_keys(v, old, new)
            for k, v in obj.items()
        }
    if isinstance(obj, list):
        return [_rename_keys(v, old, new) for v in obj]
    return obj


def parse_plan(doc: Mapping[str, Any], limits: DriveLimits, source: str = "<plan>", unit: str = "V") -> Plan:
    """Check a plan document completely and return it resolved.

    ``unit="N"`` reads a reference plan (validation): its keys end in ``_n`` and name
    forces above the preload; ``limits.drive_min_v``/``drive_max_v`` then bound the force.

    Raises
    ------
    PlanError
        Listing every problem found, each naming the protocol and the key.
    """
    if unit not in ("V", "N"):
        raise ValueError(f"unit = {unit!r}; expected 'V' or 'N'")
    if unit == "N":
        volts = sorted(
            {
                f"{p.get('name', i)}: {k}"
                for i, p in enumerate(doc.get("protocol") or [])
                if isinstance(p, Mapping)
                for k in _keys(p)
                if k.endswith("_v")
            }
        )
        if volts:  # a drive plan (characterize's) read as references: volts would be played as newtons
            raise PlanError(
                source,
                [
                    f"protocol {volts[0]} is in volts (_v); a reference plan's keys end in _n (N above the preload); "
                    f"expected a validation plan, not a characterization plan ({len(volts)} key(s) in V)"
                ],
            )
        translated = {k: (_rename_keys(v, "_n", "_v") if k == "protocol" else v) for k, v in doc.items()}
        try:
            plan = parse_plan(translated, limits, source, "V")
        except PlanError as exc:
            fixed = []
            for problem in exc.problems:
                problem = re.sub(r"\b(\w+)_v\b", r"\1_n", problem)
                for a, b in _UNIT_WORDS["N"]:
                    problem = problem.replace(a, b)
                fixed.append(problem)
            raise PlanError(source, fixed) from None
        return Plan(
            plan.name,
            plan.description,
            tuple(dataclasses.replace(p, unit="N") for p in plan.protocols),
            source,
            dict(doc),
        )
    problems: list[str] = []
    for k in sorted(set(doc) - {"plan", "protocol"}):
        problems.append(f"unknown top-level key '{k}'; expected [plan] and [[protocol]] tables")
    head = _resolve(
        doc.get("plan", {}) if isinstance(doc.get("plan", {}), dict) else {}, PLAN_KEYS, "[plan]", limits, problems
    )
    tables = doc.get("protocol", [])
    if not isinstance(tables, list) or not tables:
        problems.append("no [[protocol]] table; expected at least one protocol")
        tables = []
    protocols: list[Protocol] = []
    seen: set[str] = set()
    folded: dict[str, str] = {}
    total_s = 0.0
    total_samples = 0
    for i, table in enumerate(tables, start=1):
        label = table.get("name", "?") if isinstance(table, dict) else "?"
        where = f"protocol[{i}] '{label}'"
        if not isinstance(table, dict):
            problems.append(f"{where}: expected a table")
            continue
        kind = table.get("kind")
        if not isinstance(kind, str) or kind not in KINDS:
            problems.append(f"{where}: key 'kind' = {kind!r} is unknown; expected one of {', '.join(KINDS)}")
            continue
        spec = KINDS[kind]
        n_before = len(problems)
        p = _resolve(table, COMMON_KEYS | spec.keys, where, limits, problems)
        if len(problems) > n_before:
            continue
        name = p["name"]
        if name in seen:
            problems.append(f"{where}: name '{name}' is used by an earlier protocol; names must be unique")
        elif name.casefold() in folded:
            problems.append(
                f"{where}: name '{name}' differs from the earlier protocol '{folded[name.casefold()]}' only in case; "
                "expected names that differ otherwise (their run files would overwrite each other on Windows and macOS)"
            )
        seen.add(name)
        folded.setdefault(name.casefold(), name)
        if not (
            name.replace("-", "").replace("_", "").replace(".", "").isalnum() and name.isascii()
        ) or name.startswith("."):
            problems.append(
                f"{where}: name '{name[:MAX_NAME_CHARS]}' may hold only ASCII letters, digits, '-', '_' and '.', "
                "not starting with '.' (it names a file)"
            )
        elif len(name) > MAX_NAME_CHARS:
            problems.append(
                f"{where}: name of {len(name)} characters is longer than {MAX_NAME_CHARS}; expected a shorter name "
                "(it names the run file, and file systems limit names to 255 bytes)"
            )
        fs = p["sample_rate_hz"]
        if not 0 < fs <= limits.max_sample_rate_hz:
            problems.append(
                f"{where}: key 'sample_rate_hz' = {fs:g} is outside 0 to {limits.max_sample_rate_hz:g} Hz (the "
                "backend's maximum)"
            )
            continue
        preload = p["preload_n"] if p["preload_n"] is not None else head.get("preload_n", 50.0)
        if not 0 <= preload < limits.max_force_n:
            problems.append(f"{where}: key 'preload_n' = {preload:g} is outside 0 to {limits.max_force_n:g} N")
        extra = spec.check(p, fs)
        problems.extend(f"{where}: {e}" for e in extra)
        if extra:
            continue
        params = {k: v for k, v in p.items() if k not in COMMON_KEYS}
        proto = Protocol(name=name, kind=kind, sample_rate_hz=fs, preload_n=float(preload), params=params)
        estimate = estimated_duration_s(kind, params) * fs  # before anything is built
        if not estimate <= 1.01 * limits.max_samples + 10:
            problems.append(
                f"{where}: {estimate:.4g} samples ({estimate / fs:.4g} s at {fs:g} Hz, {memory_text(estimate)} in "
                "memory) "
                f"exceed the limit of {limits.max_samples} samples per run; lower sample_rate_hz or shorten it"
            )
            total_s += estimate / fs
            total_samples += int(min(estimate, 1e18))
            continue
        n = len(spec.build(params, fs))
        duration = n / fs
        total_s += duration
        total_samples += n
        if n > limits.max_samples:
            problems.append(
                f"{where}: {n} samples ({memory_text(n)} in memory) exceed the limit of {limits.max_samples} samples "
                "per run; "
                "lower sample_rate_hz or shorten it"
            )
            continue
        _, v = proto.waveform()
        lo, hi = float(v.min()), float(v.max())
        if lo < limits.drive_min_v - 1e-9 or hi > limits.drive_max_v + 1e-9:
            bad = hi if hi > limits.drive_max_v else lo
            problems.append(
                f"{where}: drive reaches {bad:g} V, outside the actuator's range {limits.drive_min_v:g} to "
                f"{limits.drive_max_v:g} V"
            )
            continue
        protocols.append(proto)
    if total_s > limits.max_duration_s:
        problems.append(f"the plan lasts {total_s:.0f} s, more than the limit of {limits.max_duration_s:.0f} s")
    if total_samples > limits.max_plan_samples:
        problems.append(
            f"the plan totals {total_samples:.4g} samples ({memory_text(total_samples)} of runs), more than the limit "
            "of "
            f"{limits.max_plan_samples} samples per plan; lower sample rates or split the plan"
        )
    if problems:
        raise PlanError(source, problems)
    return Plan(
        name=head["name"],
        description=head.get("description", ""),
        protocols=tuple(protocols),
        source=source,
        raw=dict(doc),
    )


def load_plan(path: str | Path, limits: DriveLimits, unit: str = "V") -> Plan:
    """Read and check a plan file; see :func:`parse_plan`."""
    path = Path(path)
    if not path.is_file():
        raise PlanError(str(path), ["no such file; expected a TOML plan (see protocols/)"])
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise PlanError(str(path), [f"not valid TOML: {exc}"]) from None
    return parse_plan(doc, limits, source=str(path), unit=unit)


def describe_kinds() -> str:
    """Text reference of every protocol kind and its keys (for ``--help``-like output)."""
    lines = []
    common = ", ".join(COMMON_KEYS)
    lines.append(f"Every protocol: {common}")
    for kind, spec in KINDS.items():
        lines.append(f'\nkind = "{kind}": {spec.summary}')
        for k, key in spec.keys.items():
            default = (
                "required"
                if key.default is REQUIRED
                else "max drive"
                if key.default is DRIVE_MAX
                else "lowest drive"
                if key.default is DRIVE_MIN
                else repr(key.default)
            )
            unit = f" [{key.unit}]" if key.unit else ""
            lines.append(f"  {k}{unit}: {key.help} (default: {default})")
    return "\n".join(lines)
