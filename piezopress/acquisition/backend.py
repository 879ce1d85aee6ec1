"""The backend interface: the single seam between piezopress and a rig.

Open-loop control needs no real-time loop, so a backend receives the complete drive
waveform and its sample rate up front and returns the measured channels. The virtual rig
(:mod:`piezopress.acquisition.virtual_rig`) and hardware backends implement the same
:class:`Backend` protocol; nothing else in piezopress knows which one it talks to.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from piezopress.acquisition.plan import DriveLimits


@dataclass(frozen=True)
class Measurement:
    """What a backend measured during one waveform.

    ``channels`` maps run-format column names (``force_n``, ``displacement_um``,
    ``monitor_v``) to arrays as long as the drive. ``complete`` is false when the run was
    cut short (then the arrays hold what was measured so far); ``info`` holds anything the
    backend wants recorded in the run's metadata.
    """

    channels: dict[str, np.ndarray]
    complete: bool = True
    reason: str = ""
    info: dict[str, Any] = field(default_factory=dict)


@runtime_checkable
class Backend(Protocol):
    """A rig that plays a drive waveform and measures the response.

    Implementations must bring the drive back to zero however :meth:`run` ends, and
    :meth:`zero_output` must be safe to call at any time, more than once.
    """

    #: short identifier recorded in run metadata (``virtual``, ``nidaq``, ...)
    name: str

    @property
    def limits(self) -> DriveLimits:
        """The drive range, sample rates, force and duration the rig allows."""
        ...

    def describe(self) -> dict[str, Any]:
        """The rig configuration, JSON-serialisable, for run metadata and manifests."""
        ...

    def run(
        self,
        command_v: np.ndarray,
        sample_rate_hz: float,
        *,
        preload_n: float,
        label: str,
        progress: Callable[[float], None] | None = None,
    ) -> Measurement:
        """Play ``command_v`` (actuator volts, one sample per ``1/sample_rate_hz``) and measure.

        ``label`` names the run (seeds a simulator's noise, tags hardware logs);
        ``progress`` is called with the fraction done, if given.
        """
        ...

    def zero_output(self) -> None:
        """Bring the drive back to zero now (after an interruption or an error)."""
        ...


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP while a rig plays: handled exactly like Ctrl-C (ramp to 0 V, runs kept,
    manifest ``interrupted``); ``signum`` says which signal."""

    def __init__(self, signum: int):
        self.signum = signum
        super().__init__(f"interrupted by {signal.Signals(signum).name}")


#: The signals turned into :class:`Terminated` while a plan runs (SIGHUP where the platform has it).
STOP_SIGNALS = tuple(getattr(signal, n) for n in ("SIGTERM", "SIGHUP") if hasattr(signal, n))


@contextlib.contextmanager
def stop_signals_interrupt() -> Iterator[None]:
    """While inside, SIGTERM and SIGHUP raise :class:`Terminated` (a ``KeyboardInterrupt``), so
    every backend's Ctrl-C path (ramp-down, partial run kept) handles them too. Outside the
    main thread (where Python cannot install handlers) nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: Any) -> None:
        raise Terminated(signum)

    previous = {}
    try:
        for sig in STOP_SIGNALS:
            previous[sig] = signal.signal(sig, handler)
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
