"""The conformance kit for backend authors: :func:`check_backend`.

A lab that writes its own backend (a LabJack, a Red Pitaya, a vendor's controller, a
simulation) checks it the way pymeasure's ``expected_protocol`` checks a driver: without
the rest of piezopress, in its own test suite::

    from piezopress.testing import check_backend

    def test_my_press_is_a_piezopress_backend():
        check_backend(MyPress({"rig": {"backend": "mypkg.press:MyPress"}, "press": {...}}))

Each rule has a name; a backend that breaks one fails with :class:`BackendConformanceError`
naming the rule and what was seen. The rules (:data:`RULES`):

- ``limits``: ``limits`` is a :class:`~piezopress.acquisition.plan.DriveLimits` with a drive
  range (``drive_min_v < drive_max_v``, finite) and a positive maximum sample rate;
- ``describe``: ``describe()`` returns a JSON object (it goes into every run's metadata);
- ``at-rest``: a new backend holds 0 V (``output_v``);
- ``channels``: a small drive inside the limits returns a complete
  :class:`~piezopress.acquisition.backend.Measurement` whose channels are finite 1-D arrays
  exactly as long as the drive, with an output (``force_n`` or ``displacement_um``);
- ``ends-at-zero``: after every run (finished, refused or cut short) the backend holds 0 V;
- ``refused-drive``: a drive beyond the limits is refused with a piezopress error before
  anything is played (the backend still holds 0 V, and plays the next valid drive);
- ``cut-short``: a run interrupted (Ctrl-C, raised from its ``progress`` callback) comes back
  with what was measured: either a ``Measurement`` with ``complete`` false, or the
  ``KeyboardInterrupt`` re-raised carrying ``.measurement`` (channels as long as each other,
  no longer than the drive). A backend that never reports progress cannot be cut short
  cleanly and fails this rule;
- ``clock``: a simulation that keeps a clock of its own (``clock_s``, the time on it at which
  its next run starts: run metadata records its runs on it) gives a finite number that a
  finished run advances by at least the run's duration. A backend without one passes.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np

from piezopress.acquisition.backend import Measurement, clock_of
from piezopress.acquisition.plan import DriveLimits
from piezopress.errors import PiezopressError

#: Every rule :func:`check_backend` checks, in order.
RULES = ("limits", "describe", "at-rest", "channels", "ends-at-zero", "refused-drive", "cut-short", "clock")
OUTPUTS = ("force_n", "displacement_um")


class BackendConformanceError(AssertionError):
    """A backend breaks a rule of :func:`check_backend`; ``rule`` names it."""

    def __init__(self, rule: str, what: str):
        self.rule = rule
        super().__init__(f"backend rule {rule!r} broken: {what}")


def _fail(rule: str, what: str) -> None:
    raise BackendConformanceError(rule, what)


def _held(backend: Any, rule: str, when: str) -> None:
    v = getattr(backend, "output_v", None)
    if v is None:
        _fail(rule, f"the backend has no output_v (the drive it holds now, V); expected 0 V {when}")
    if not (isinstance(v, (int, float)) and math.isfinite(v) and abs(v) <= 1e-9):
        _fail(rule, f"the backend holds {v!r} V {when}; expected 0 V (every ending ramps the drive to 0 V)")


def _probe_drive(limits: DriveLimits, duration_s: float = 0.05) -> tuple[np.ndarray, float]:
    """A small, slow drive inside the limits: 0 V -> a fifth of the range -> 0 V."""
    fs = float(min(limits.max_sample_rate_hz, 10_000.0))
    n = max(16, int(duration_s * fs))
    lo, hi = max(limits.drive_min_v, 0.0), limits.drive_max_v
    top = lo + 0.2 * (hi - lo) if hi > lo else lo
    if math.isfinite(limits.slew_limit_v_per_s):
        top = min(top, lo + 0.4 * limits.slew_limit_v_per_s * n / fs / 2)
    x = top * np.sin(np.linspace(0.0, np.pi, n)) ** 2
    return x, fs


def _check_channels(m: Any, n: int, rule: str, complete: bool) -> None:
    if not isinstance(m, Measurement):
        _fail(rule, f"run() returned {type(m).__name__}; expected a piezopress.acquisition.backend.Measurement")
    if complete and not m.complete:
        _fail(rule, f"a drive inside the limits came back incomplete ({m.reason!r}); expected a complete run")
    if not any(c in m.channels for c in OUTPUTS):
        _fail(rule, f"channels {sorted(m.channels)}; expected an output, force_n or displacement_um")
    lengths = set()
    for name, v in m.channels.items():
        a = np.asarray(v)
        if a.ndim != 1:
            _fail(rule, f"channel {name!r} has shape {a.shape}; expected a 1-D array")
        if not np.issubdtype(a.dtype, np.number) or not np.all(np.isfinite(a)):
            _fail(rule, f"channel {name!r} holds non-numbers or NaN/inf; expected finite numbers")
        lengths.add(a.size)
    if complete and lengths != {n}:
        _fail(
            rule,
            f"channel lengths {sorted(lengths)} for a drive of {n} samples; "
            "expected every channel as long as the drive",
        )
    if not complete and (len(lengths) > 1 or max(lengths, default=0) > n):
        _fail(
            rule,
            f"channel lengths {sorted(lengths)} after a cut-short run of {n} samples; expected equal lengths <= {n}",
        )


def check_backend(backend: Any, *, preload_n: float = 0.0) -> list[str]:
    """Check ``backend`` against every rule of :data:`RULES`; return the rules passed.

    Raises :class:`BackendConformanceError` at the first rule broken, naming it. The kit plays
    two small drives (a fifth of the drive range, 50 ms) and one that the backend must refuse.
    """
    passed: list[str] = []
    lim = getattr(backend, "limits", None)
    if not isinstance(lim, DriveLimits):
        _fail("limits", f"limits is {type(lim).__name__}; expected a piezopress.acquisition.plan.DriveLimits")
    if not (math.isfinite(lim.drive_min_v) and math.isfinite(lim.drive_max_v) and lim.drive_min_v < lim.drive_max_v):
        _fail("limits", f"drive range {lim.drive_min_v!r} to {lim.drive_max_v!r} V; expected finite, min below max")
    if not (lim.max_sample_rate_hz > 0 and math.isfinite(lim.max_sample_rate_hz)):
        _fail("limits", f"max_sample_rate_hz {lim.max_sample_rate_hz!r}; expected a positive number")
    passed.append("limits")

    try:
        doc = backend.describe()
        json.dumps(doc)
    except (TypeError, ValueError) as exc:
        _fail("describe", f"describe() is not JSON-serialisable ({exc})")
    if not isinstance(doc, dict):
        _fail("describe", f"describe() returned {type(doc).__name__}; expected a JSON object (dict)")
    passed.append("describe")

    _held(backend, "at-rest", "before anything was played")
    passed.append("at-rest")

    x, fs = _probe_drive(lim)
    clock0 = _clock(backend)
    m = backend.run(x, fs, preload_n=preload_n, label="conformance-channels")
    clock1 = _clock(backend)
    _check_channels(m, x.size, "channels", complete=True)
    passed.append("channels")
    _held(backend, "ends-at-zero", "after a finished run")
    passed.append("ends-at-zero")

    bad = np.full(x.size, lim.drive_max_v + 0.1 * (lim.drive_max_v - lim.drive_min_v) + 1.0)
    try:
        backend.run(bad, fs, preload_n=preload_n, label="conformance-refused")
    except PiezopressError:
        pass
    except Exception as exc:  # noqa: BLE001 - any other failure breaks the rule
        _fail(
            "refused-drive",
            f"a drive above drive_max_v raised {type(exc).__name__} ({exc}); expected a piezopress error",
        )
    else:
        _fail(
            "refused-drive",
            f"a drive at {bad[0]:g} V, above drive_max_v = {lim.drive_max_v:g} V, was played; expected it refused",
        )
    _held(backend, "refused-drive", "after a refused drive")
    _check_channels(
        backend.run(x, fs, preload_n=preload_n, label="conformance-after-refusal"), x.size, "refused-drive", True
    )
    passed.append("refused-drive")

    calls: list[float] = []

    def stop(fraction: float) -> None:
        calls.append(fraction)
        raise KeyboardInterrupt

    try:
        got = backend.run(x, fs, preload_n=preload_n, label="conformance-cut-short", progress=stop)
    except KeyboardInterrupt as exc:
        got = getattr(exc, "measurement", None)
        if got is None:
            _fail(
                "cut-short",
                "interrupted, the run re-raised Ctrl-C without what it measured; expected .measurement on it",
            )
    if not calls:
        _fail(
            "cut-short",
            "the backend never called progress(fraction); expected progress reports, where a run can be cut short",
        )
    if not isinstance(got, Measurement):
        _fail(
            "cut-short",
            f"interrupted, the run gave {type(got).__name__}; "
            "expected a Measurement (complete false) of what was measured",
        )
    _check_channels(got, x.size, "cut-short", complete=got.complete)
    _held(backend, "cut-short", "after a run cut short")
    passed.append("cut-short")
    if clock0 is not None and not (clock1 is not None and clock1 - clock0 >= x.size / fs - 1e-9):
        _fail(
            "clock",
            f"clock_s went from {clock0!r} to {clock1!r} over a run of {x.size / fs:g} s; expected it advanced by "
            "at least the run's duration (the run's recorded start is read on it)",
        )
    passed.append("clock")
    return passed


def _clock(backend: Any) -> float | None:
    """The backend's own clock (``clock_s``), None without one; a value that is no finite number breaks ``clock``."""
    if not hasattr(backend, "clock_s"):
        return None
    clock = clock_of(backend)
    if clock is None:
        _fail("clock", f"clock_s is {backend.clock_s!r}; expected a finite number of seconds (the backend's own clock)")
    return clock
