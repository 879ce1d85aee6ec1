"""Open-loop compensation: a reference force trajectory in, the actuator drive out.

The thesis's order (Fig. 3.1)::

    reference (the hysteresis model's output unit: N above the preload, or um)
      -> rate limit            keeps the drive inside the amplifier's linear range
      -> input shaper          cancels the mode (centred: the whole reference is known)
      -> creep compensator     F_h = F_c / (K_c + C(s))       (Eq. 3.38)
      -> inverse hysteresis    x = H^-1[F_h]                  (Eq. 3.9)
      -> drive (V), clipped to the actuator's safe range

Unlike the thesis's real-time setup, the whole reference is known before the run, so the
shaper is applied centred on its centroid (no average delay) and the drive is advanced by
the linear model's remaining low-frequency delay (``lead_s``): at 50 Hz these delays are
what made the thesis's compensated loops wide (Table 6.11).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from piezopress import signals, units
from piezopress.analysis.creep import CreepModel
from piezopress.analysis.hysteresis import PIModel
from piezopress.analysis.shaper import Shaper
from piezopress.errors import FitError


@dataclass(frozen=True)
class CompensationResult:
    """The drive and what happened on the way (for the run's metadata and warnings)."""

    command_v: np.ndarray
    stages: dict[str, np.ndarray]
    clipped_samples: int
    requested_min_v: float
    requested_max_v: float
    warnings: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()


@dataclass(frozen=True)
class Compensator:
    """A reference-to-drive map built from a parameter bundle's models.

    Parameters
    ----------
    hysteresis : PIModel
        Maps drive (V) to the output (force in N, or displacement in um: its
        ``output_unit``, the unit of the reference); its inverse is the last stage.
    creep : CreepModel or None
        Creep of the hysteresis-compensated press; ``None`` skips the stage.
    shaper : Shaper or None
        Input shaper for the press's mode; ``None`` skips the stage.
    drive_min_v, drive_max_v : float
        The actuator's safe range; the drive is clipped to it, with a warning.
    max_rate_per_s : float or None
        Largest reference rate passed on, in the output unit per second (a step becomes a
        ramp). Keeps the drive current below the amplifier's limit, where the press is linear.
    lead_s : float
        Advance of the drive to cancel the linear model's remaining delay.
    """

    hysteresis: PIModel
    creep: CreepModel | None = None
    shaper: Shaper | None = None
    drive_min_v: float = 0.0
    drive_max_v: float = 150.0
    max_rate_per_s: float | None = None
    lead_s: float = 0.0
    options: dict[str, Any] = field(default_factory=dict)

    def drive(self, reference: np.ndarray, fs_hz: float) -> CompensationResult:
        """The drive for ``reference`` (in the model's output unit: force above the preload,
        or displacement from the model's rest, sampled at ``fs_hz``).

        ``stages`` names each intermediate signal with the unit's key (``reference_n``,
        ``shaped_um``, ...) and the drive ``unclipped_v``.
        """
        r = np.asarray(reference, dtype=np.float64)
        if r.ndim != 1 or r.size < 2 or not np.all(np.isfinite(r)):
            raise ValueError(f"reference of shape {r.shape} with non-finite values or fewer than 2 samples; expected a finite 1-D trajectory")
        k = units.key(self.hysteresis.output_unit)
        stages: dict[str, np.ndarray] = {f"reference_{k}": r}
        if self.max_rate_per_s:
            r = signals.rate_limit(r, r[0], self.max_rate_per_s / fs_hz)
            stages[f"rate_limited_{k}"] = r
        notes = []
        if self.shaper is not None:
            try:
                r = self.shaper.apply_centered(r, fs_hz)
                stages[f"shaped_{k}"] = r
            except FitError:
                # too slow to resolve the mode: the drive's steps are too small to ring it
                notes.append(f"shaper skipped: {fs_hz:g} Hz cannot resolve the {self.shaper.wn / (2 * np.pi):.0f} Hz mode")
        if self.creep is not None:
            r, _ = self.creep.compensate(r, fs_hz)
            stages[f"creep_compensated_{k}"] = r
        x, _ = self.hysteresis.inverse(self.hysteresis.y0 + r)
        n_lead = int(round(self.lead_s * fs_hz))
        if n_lead > 0:
            x = np.concatenate([x[n_lead:], np.full(n_lead, x[-1])])
        stages["unclipped_v"] = x
        lo, hi = float(x.min()), float(x.max())
        clipped = int(np.count_nonzero((x < self.drive_min_v) | (x > self.drive_max_v)))
        warnings = []
        if clipped:
            warnings.append(
                f"the reference cannot be reached everywhere: {clipped} of {x.size} samples need a drive outside "
                f"{self.drive_min_v:g} to {self.drive_max_v:g} V (requested {lo:.1f} to {hi:.1f} V); clipped"
            )
        return CompensationResult(np.clip(x, self.drive_min_v, self.drive_max_v), stages, clipped, lo, hi, tuple(warnings), tuple(notes))
