"""The virtual rig: the default backend, a simulation of the thesis's press.

It implements :class:`piezopress.acquisition.backend.Backend` with exactly the signature a
hardware backend has. It is deterministic: the noise of a run is drawn from a generator
seeded by the rig's seed and the run's label, so the same plan on the same rig file gives
the same data, whatever the order of the protocols. A label played again on the same rig
object (a repeat, as ``compare`` plays) draws new noise, as a real press would: its n-th
repeat adds n to the seed. It never sleeps.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from piezopress.acquisition import rig_physics as phys
from piezopress.acquisition.backend import Measurement
from piezopress.acquisition.drive_check import check_drive
from piezopress.acquisition.plan import DriveLimits
from piezopress.acquisition.rig_config import RigConfig, parse_rig


def _label_seed(label: str) -> int:
    return int.from_bytes(hashlib.sha256(label.encode()).digest()[:8], "little")


#: The pause between two runs on the virtual rig's clock (s): a drift over the test advances by it.
PAUSE_S = 5.0


class VirtualRig:
    """Simulated press. See :mod:`piezopress.acquisition.rig_physics` for the signal chain.

    Examples
    --------
    >>> rig = VirtualRig(RigConfig())
    >>> m = rig.run(np.full(200, 20.0), 20_000.0, preload_n=50.0, label="demo")
    >>> sorted(m.channels)
    ['force_n', 'monitor_v']
    """

    name = "virtual"

    def __init__(self, config: RigConfig | Mapping[str, Any] | None = None):
        # a parsed rig file (``VirtualRig(document)``, as every plug-in backend is made) or a RigConfig
        self.config = parse_rig(config, source="rig file") if isinstance(config, Mapping) else (config or RigConfig())
        self.output_v = 0.0
        self._plays: dict[str, int] = {}  # label -> times played on this rig object (a repeat's new noise)
        self.clock_s = 0.0  # the rig's own clock: every run, and a pause of PAUSE_S after each

    @classmethod
    def limits_of(cls, document: Mapping[str, Any]) -> DriveLimits:
        """The limits a rig document states (checked completely)."""
        return parse_rig(document, source="rig file").limits

    @property
    def limits(self) -> DriveLimits:
        return self.config.limits

    def describe(self) -> dict[str, Any]:
        return {"backend": self.name, "source": self.config.source, "config": self.config.as_dict()}

    def simulate(
        self, command_v: np.ndarray, sample_rate_hz: float, preload_n: float, rng: np.random.Generator
    ) -> dict[str, np.ndarray]:
        """The physics, without the backend bookkeeping: returns the measured channels."""
        return phys.simulate(command_v, sample_rate_hz, preload_n, self.config, rng, self.clock_s)

    def run(
        self,
        command_v: np.ndarray,
        sample_rate_hz: float,
        *,
        preload_n: float,
        label: str,
        progress: Callable[[float], None] | None = None,
    ) -> Measurement:
        self.check_drive(command_v, sample_rate_hz, label)
        command_v = np.asarray(command_v, dtype=np.float64)
        seed = [self.config.rig.seed, _label_seed(label)]
        repeat = self._plays.get(label, 0)
        self._plays[label] = repeat + 1
        if repeat:
            seed.append(repeat)
        rng = np.random.default_rng(np.random.SeedSequence(seed))
        try:
            self.output_v = float(command_v[0])
            channels = self.simulate(command_v, sample_rate_hz, preload_n, rng)
        finally:
            self.zero_output()
            self.clock_s += command_v.size / sample_rate_hz + PAUSE_S
        factor, segments = phys.fine_windows(command_v, sample_rate_hz, self.config)
        info = {"seed": seed, "fine_factor": factor, "fine_segments": sum(1 for s in segments if s[2] > 1)}
        measured = Measurement(channels=channels, info=info)
        reason = self._over_force(channels.get("force_n"), sample_rate_hz)
        if reason:
            # as a real rig's interlock: the run stops at the first sample above the stack's limit
            stop = int(reason[0])
            measured = Measurement(
                channels={k: v[:stop] for k, v in channels.items()}, complete=False, reason=reason[1], info=info
            )
        if progress is not None:
            try:
                progress(1.0)
            except KeyboardInterrupt as exc:  # Ctrl-C once everything is measured: the run is kept whole
                exc.measurement = measured  # type: ignore[attr-defined]
                raise
        return measured

    def _over_force(self, force_n: np.ndarray | None, sample_rate_hz: float) -> tuple[int, str] | None:
        """``(first bad sample, why)`` when the force passes the stack's ``max_force_n``, else ``None``."""
        if force_n is None:
            return None
        limit = float(self.limits.max_force_n)
        bad = ~(np.asarray(force_n, dtype=np.float64) <= limit)
        if not bad.any():
            return None
        i = int(np.argmax(bad))
        return i, (
            f"over-force: {force_n[i]:.1f} N at t = {i / sample_rate_hz:.4g} s (sample {i}), above the stack's "
            f"max_force_n = {limit:g} N; the run was stopped there (lower the drive or the preload)"
        )

    def check_drive(self, command_v: np.ndarray, sample_rate_hz: float, label: str = "drive") -> None:
        """Refuse a drive the rig may not play (the shared check of :mod:`piezopress.acquisition.drive_check`)."""
        check_drive(command_v, sample_rate_hz, self.limits, f"virtual rig: {label}", start_v=self.output_v)

    def zero_output(self) -> None:
        self.output_v = 0.0
