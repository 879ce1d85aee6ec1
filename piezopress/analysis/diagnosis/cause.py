"""The catalogue entry: one object per cause, read by every place that names causes."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from piezopress.analysis.diagnosis.judging import Context, Finding
from piezopress.analysis.diagnosis.model import Model
from piezopress.analysis.diagnosis.needs import Need, RunSpec


@dataclass(frozen=True)
class Cause:
    """A catalogue entry, the one object every other place reads for a cause: stable id, the
    physics, the extension (in words), its fit (``run``), what it needs, how it extends the
    bundle (``extend``), and the compensated rows its extension is for (``targets``).

    ``extend(document, compensation, finding)`` writes the finding into the extended bundle
    (:func:`piezopress.analysis.bundle.extend_document` calls it); a cause with one is applied
    by the compensator (``in_compensator``), the others are recorded only: the extended bundle,
    ``diagnosis.json`` and the report all read it here. ``targets`` are the validation rows
    (:data:`piezopress.pipelines.gain.ROWS`) the extension should improve, where its gain on
    the press is judged. ``needs`` are the ways to test the cause (any one suffices): a cause
    whose needs the runs do not meet is not tried, and :func:`testability` says what it needs
    and what the runs offer.
    """

    id: str
    physics: str
    extension: str
    run: Callable[[Context], Finding | None]
    needs: tuple[Need, ...] = ()
    extend: Callable[[dict[str, Any], dict[str, Any], Finding], None] | None = None
    targets: tuple[str, ...] = ()
    #: Among the findings a round accepts, those of a higher precedence are taken first (then the
    #: largest gain): a cause judged where the press's physics cannot act (the same drive played
    #: twice reads alike whatever the loop, the creep or the mode) goes before the causes of the
    #: physics, which would otherwise take what it explains (a gain drift read as creep in a hold).
    precedence: int = 0
    #: Whether the finding's fit refits the main mode freely, because the effect distorts the
    #: mode's identification on the steps (a delay read as damping; a loop widening with the
    #: rate read as a slow, heavily damped mode): the extended bundle's shaper and lead are
    #: then designed for the diagnosis model's mode (:func:`piezopress.analysis.bundle.extend_document`).
    refits_mode: bool = False
    #: What the base model already holds of the cause (the drive chain's delay and low-pass for a
    #: delay, its slew for a slew limit), said beside "not found": the cause is looked for beyond
    #: it, and a user reading "not found" should know the press's own part was drawn, not missed.
    held: Callable[[Model], str] | None = None

    @property
    def in_compensator(self) -> bool:
        """Whether the compensator applies the extension (the cause extends the compensation)."""
        return self.extend is not None


_FAST_STEPS = RunSpec("step", min_fs_hz=5000.0)  # what Context.steps() takes
