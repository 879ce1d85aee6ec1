"""An actuator-only rig file (``[rig] backend = "none"``): the limits of a press whose board
piezopress does not drive — a lab's own controller, a record from elsewhere. ``compensate
--rig``, ``validate --rig`` (to check, not to play) and ``fit --rig`` read its drive range,
slew limit and sampling limit from it; nothing can be run on it.

``piezopress rig-keys --template my-actuator.toml --backend none`` writes one to edit.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from piezopress.acquisition.backend import Measurement
from piezopress.acquisition.plan import DriveLimits
from piezopress.errors import BackendError, ConfigError

#: ``[actuator]`` keys: (default, unit, lowest, highest, what).
KEYS: dict[str, tuple[float, str, float, float, str]] = {
    "drive_min_v": (-30.0, "V", -2000.0, 2000.0, "lowest allowed drive"),
    "drive_max_v": (150.0, "V", -2000.0, 2000.0, "highest allowed drive"),
    "slew_v_per_ms": (0.0, "V/ms", 0.0, 1e6, "fastest drive change the amplifier allows (0: not stated)"),
    "max_sample_rate_hz": (100_000.0, "Hz", 1.0, 1e7, "fastest sampling of the drive"),
    "max_force_n": (800.0, "N", 0.0, 1e6, "largest load force of the stack"),
}


def _check(document: Mapping[str, Any], source: str) -> dict[str, float]:
    problems = []
    rig = document.get("rig", {})
    extra = sorted(set(document) - {"rig", "actuator"})
    if extra:
        problems.append(f"unknown section [{extra[0]}]; expected [rig] and [actuator] in an actuator-only rig file")
    act = document.get("actuator", {})
    if not isinstance(act, Mapping) or not isinstance(rig, Mapping):
        raise ConfigError(source, ["[rig] and [actuator] must be tables"])
    values = {}
    for key in sorted(set(act) - set(KEYS)):
        problems.append(f"[actuator] {key} is unknown; expected one of {', '.join(KEYS)}")
    for key, (default, unit, lo, hi, _) in KEYS.items():
        v = act.get(key, default)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
            problems.append(f"[actuator] {key} = {v!r}; expected a number from {lo:g} to {hi:g} {unit}")
        else:
            values[key] = float(v)
    if {"drive_min_v", "drive_max_v"} <= set(values) and values["drive_min_v"] >= values["drive_max_v"]:
        problems.append(
            f"[actuator] drive_min_v = {values['drive_min_v']:g} must be below drive_max_v = {values['drive_max_v']:g}"
        )
    if problems:
        raise ConfigError(source, problems)
    return values


class ActuatorOnly:
    """The limits of an actuator-only rig file; :meth:`run` refuses (there is no board)."""

    name = "none"

    def __init__(self, document: Mapping[str, Any] | None = None, source: str = "rig file"):
        self.document = dict(document or {})
        self.values = _check(self.document, source)
        self.source = source
        self.output_v = 0.0

    @classmethod
    def limits_of(cls, document: Mapping[str, Any]) -> DriveLimits:
        v = _check(document, "rig file")
        slew = v["slew_v_per_ms"] * 1e3 if v["slew_v_per_ms"] > 0 else math.inf
        return DriveLimits(
            drive_min_v=v["drive_min_v"],
            drive_max_v=v["drive_max_v"],
            max_sample_rate_hz=v["max_sample_rate_hz"],
            max_force_n=v["max_force_n"],
            slew_limit_v_per_s=slew,
        )

    @property
    def limits(self) -> DriveLimits:
        return self.limits_of(self.document)

    def describe(self) -> dict[str, Any]:
        return {"backend": self.name, "source": self.source, "actuator": dict(self.values)}

    def run(
        self,
        command_v: np.ndarray,
        sample_rate_hz: float,
        *,
        preload_n: float,
        label: str,
        progress: Callable[[float], None] | None = None,
    ) -> Measurement:
        raise BackendError(
            f'{label}: an actuator-only rig file ([rig] backend = "none") has no board to play a drive on; '
            "expected a rig file of a backend that runs (virtual, nidaq, or a plug-in): compensate's drive file "
            "is what to play on this press with its own controller"
        )

    def zero_output(self) -> None:
        self.output_v = 0.0
