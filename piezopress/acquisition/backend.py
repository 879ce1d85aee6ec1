"""The backend interface: the single seam between piezopress and a rig.

Open-loop control needs no real-time loop, so a backend receives the complete drive
waveform and its sample rate up front and returns the measured channels. The virtual rig
(:mod:`piezopress.acquisition.virtual_rig`) and hardware backends implement the same
:class:`Backend` protocol; nothing else in piezopress knows which one it talks to.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import math
import signal
import threading
import weakref
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from piezopress import runformat
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

    A backend is found by the name a rig file gives in ``[rig] backend``: a name registered
    under the entry-point group ``piezopress.backends``, or an import path
    ``package.module:ClassName``. The class is called with the whole parsed rig file as one
    dict (``ClassName(document)``), validates its own sections and raises
    :class:`~piezopress.errors.ConfigError` for a bad one; its constructor must not touch
    hardware (``check-rig`` and ``fit --rig`` read its :attr:`limits` from it). A class may
    offer ``limits_of(document)`` (a classmethod) to state the limits without loading a driver.
    ``output_v`` is the drive the backend holds now (V): 0 at rest, and 0 again however a run
    ends. :func:`piezopress.testing.check_backend` checks all of this.

    A backend that simulates a press on a clock of its own (played faster than real time, with
    pauses between runs that take no wall time) may give ``clock_s``: the time on that clock
    at which its next run starts (s). A run's recorded start (``started_utc``) is then that
    clock's (:func:`started_utc`), so that what happens over the test's time in the
    simulation (a drift, a sensitivity changing by the hour) is read on the time it happened in.
    """

    #: short identifier recorded in run metadata (``virtual``, ``nidaq``, ...)
    name: str
    #: the drive the backend holds now (V): 0 at rest, 0 again however a run ends
    output_v: float

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


#: The wall time each clocked backend's clock started at (its first run's start, less its clock then).
_CLOCK_EPOCHS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def clock_of(backend: Any) -> float | None:
    """The backend's own clock (``clock_s``, see :class:`Backend`) in seconds; None where it has
    none, or gives something that is no finite number."""
    clock = getattr(backend, "clock_s", None)
    if isinstance(clock, bool) or not isinstance(clock, (int, float)) or not math.isfinite(clock):
        return None
    return float(clock)


def started_utc(backend: Any) -> str:
    """The start of the run ``backend`` plays next, as run metadata records it (UTC, to the
    second): now, or for a backend with a clock of its own (:func:`clock_of`) the wall time of
    its first run plus the time its clock has advanced since."""
    now = _dt.datetime.now(_dt.UTC)
    clock = clock_of(backend)
    if clock is not None:
        try:
            epoch = _CLOCK_EPOCHS.setdefault(backend, now - _dt.timedelta(seconds=clock))
        except TypeError:  # an object that cannot be weakly referenced: wall time
            pass
        else:
            now = epoch + _dt.timedelta(seconds=clock)
    return now.strftime(runformat.TIMESTAMP_FORMAT)


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


# --------------------------------------------------------------------------- the registry

#: The entry-point group a package registers its backends under (``pyproject.toml``:
#: ``[project.entry-points."piezopress.backends"] mypress = "mypkg.press:MyPress"``).
ENTRY_POINT_GROUP = "piezopress.backends"
#: piezopress's own backends, registered under the same group; found here too when the
#: package's metadata is not installed (a checkout on ``sys.path``).
BUILTIN_BACKENDS = {
    "virtual": "piezopress.acquisition.virtual_rig:VirtualRig",
    "nidaq": "piezopress.acquisition.nidaq:NidaqBackend",
    "none": "piezopress.acquisition.actuator_only:ActuatorOnly",
}


def registered_backends() -> dict[str, str]:
    """Backend name -> ``module:Class``: the entry points of :data:`ENTRY_POINT_GROUP` (and
    piezopress's own)."""
    from importlib.metadata import entry_points

    found = dict(BUILTIN_BACKENDS)
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        found[ep.name] = ep.value
    return found


def backend_class(spec: str, source: str, search: Path | None = None) -> type:
    """The backend class a rig file names in ``[rig] backend``: a registered name, or an
    import path ``package.module:ClassName`` (looked up beside the rig file, ``search``, too).

    Raises :class:`~piezopress.errors.ConfigError` naming ``source`` and what is registered.
    """
    import importlib
    import sys

    from piezopress.errors import ConfigError

    names = registered_backends()
    target = names.get(spec, spec)
    if ":" not in target:
        raise ConfigError(
            source,
            [
                f"[rig] backend = {spec!r}: no backend of that name; expected one of {', '.join(sorted(names))} "
                "(registered under the entry-point group 'piezopress.backends') "
                "or an import path 'package.module:ClassName'"
            ],
        )
    module_name, _, attr = target.partition(":")
    added = search is not None and str(search) not in sys.path
    if added:
        sys.path.insert(0, str(search))
    try:
        module = importlib.import_module(module_name)
    except Exception as exc:  # noqa: BLE001 - any failure to import is the rig file's problem, said in one line
        raise ConfigError(
            source,
            [
                f"[rig] backend = {spec!r}: cannot import module {module_name!r} ({type(exc).__name__}: {exc}); "
                "expected an installed package or a module beside the rig file"
            ],
        ) from None
    finally:
        if added:
            sys.path.remove(str(search))
    obj: Any = module
    for part in attr.split("."):
        obj = getattr(obj, part, None)
        if obj is None:
            raise ConfigError(source, [f"[rig] backend = {spec!r}: module {module_name!r} has no {attr!r}"])
    if not callable(obj):
        raise ConfigError(source, [f"[rig] backend = {spec!r}: {attr!r} is not a class; expected a Backend class"])
    return obj


def backend_limits(cls: Any, document: dict[str, Any]) -> DriveLimits:
    """The limits a rig document states for a backend class, without touching hardware:
    ``cls.limits_of(document)`` when the class offers it (a driver is then not even loaded),
    else ``cls(document).limits`` (a backend's constructor must not touch hardware)."""
    limits_of = getattr(cls, "limits_of", None)
    return limits_of(document) if callable(limits_of) else cls(document).limits
