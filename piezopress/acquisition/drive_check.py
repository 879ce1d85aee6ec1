"""One drive check, shared by everything that hands a drive to a rig.

``compensate``, ``validate``, ``check-rig`` and every backend (the virtual rig, NI-DAQmx)
call :func:`drive_problems` / :func:`check_drive` on the drive they are about to write or
play: a finite 1-D waveform of at least 2 samples, at a sample rate the rig can run
(checked first, and alone, so a reference at 1 GHz is refused before any work), no more
samples than the rig allows, every sample inside the rig's drive range, and no step faster
than the slew limit (including the move from the output at rest to the first sample).

The limits are a :class:`~piezopress.acquisition.plan.DriveLimits`: what the rig file
states. A hardware backend may add ranges of its own (amplifier, analog output).
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from piezopress.acquisition.plan import BYTES_PER_SAMPLE, DriveLimits, memory_text
from piezopress.errors import BackendError


class DriveRefused(BackendError):
    """A drive was refused before anything was output (one line: where, what, the limit)."""


def sample_rate_problems(sample_rate_hz: float, limits: DriveLimits, key: str = "sample rate") -> list[str]:
    """Why ``sample_rate_hz`` cannot be played on a rig with ``limits`` (empty: fine)."""
    try:
        fs = float(sample_rate_hz)
    except (TypeError, ValueError):
        return [f"{key} {sample_rate_hz!r}; expected a number of Hz"]
    if not math.isfinite(fs) or fs <= 0:
        return [f"{key} {fs:g} Hz; expected a positive, finite rate"]
    if fs > limits.max_sample_rate_hz * (1 + 1e-12):
        return [f"{key} {fs:.6g} Hz is above the rig's maximum sample rate of {limits.max_sample_rate_hz:g} Hz"]
    return []


def sample_count_problems(samples: float, sample_rate_hz: float, limits: DriveLimits, what: str = "drive") -> list[str]:
    """Why a waveform of ``samples`` samples is too long for the rig (empty: fine)."""
    if samples > limits.max_samples:
        return [
            f"{what} of {samples:.4g} samples ({samples / sample_rate_hz:.4g} s at {sample_rate_hz:g} Hz, "
            f"{memory_text(samples)} "
            f"in memory) exceeds the rig's limit of {limits.max_samples} samples; lower the sample rate or shorten it"
        ]
    return []


def drive_problems(
    command_v: np.ndarray,
    sample_rate_hz: float,
    limits: DriveLimits,
    *,
    start_v: float = 0.0,
    ranges: Iterable[tuple[str, float, float]] | None = None,
    rate_key: str = "the rig's maximum sample rate",
    slew_key: str = "the rig's slew limit",
) -> list[str]:
    """Every reason ``command_v`` (actuator volts at ``sample_rate_hz``) may not be played (empty: fine).

    ``ranges`` are ``(what, lo, hi)`` the drive must stay inside (default: the rig's drive
    range); ``rate_key``/``slew_key`` name where the limits come from, for the message.
    """
    problems = sample_rate_problems(sample_rate_hz, limits)
    if problems:
        return [problems[0].replace("the rig's maximum sample rate", rate_key)]
    v = np.asarray(command_v)
    if v.ndim != 1 or v.size < 2:
        return [f"drive of shape {v.shape}; expected a 1-D waveform of at least 2 samples"]
    problems += sample_count_problems(v.size, sample_rate_hz, limits)
    if not np.issubdtype(v.dtype, np.number) or np.issubdtype(v.dtype, np.complexfloating):
        return problems + [f"drive of type {v.dtype}; expected real volts"]
    v = v.astype(np.float64, copy=False)
    finite = np.isfinite(v)
    if not finite.all():
        k = int(np.argmin(finite))
        return problems + [
            f"drive holds {int((~finite).sum())} NaN or infinite value(s) (first at sample {k}: {v[k]!r}); expected "
            "finite volts"
        ]
    lo, hi = float(v.min()), float(v.max())
    if ranges is None:
        ranges = [("the actuator's range", limits.drive_min_v, limits.drive_max_v)]
    for what, rlo, rhi in ranges:
        if lo < rlo - 1e-9 or hi > rhi + 1e-9:
            problems.append(f"drive spans {lo:g} to {hi:g} V, outside {what} {rlo:g} to {rhi:g} V")
    if not problems and math.isfinite(limits.slew_limit_v_per_s):
        steps = np.abs(np.diff(np.concatenate([[float(start_v)], v])))
        k = int(np.argmax(steps))
        slew = float(steps[k]) * float(sample_rate_hz)
        if slew > limits.slew_limit_v_per_s * (1 + 1e-9):
            where = "from the output at rest to the first sample" if k == 0 else f"at sample {k - 1} to {k}"
            problems.append(
                f"drive changes at {slew:.4g} V/s ({steps[k]:g} V in one sample at {sample_rate_hz:g} Hz, {where}), "
                f"above {slew_key} = {limits.slew_limit_v_per_s:g} V/s"
            )
    return problems


def check_sample_rate(sample_rate_hz: float, limits: DriveLimits, who: str) -> None:
    """Refuse a sample rate the rig cannot run, before any work: ``who`` names the file or step."""
    problems = sample_rate_problems(sample_rate_hz, limits)
    if problems:
        raise DriveRefused(
            f"{who}: {problems[0]}; expected at most {limits.max_sample_rate_hz:g} Hz (resample the reference, or use "
            "a rig file that allows it)"
        )


def check_drive(
    command_v: np.ndarray, sample_rate_hz: float, limits: DriveLimits, who: str, *, start_v: float = 0.0
) -> None:
    """Raise :class:`DriveRefused` (one line, every problem) unless the drive may be played."""
    problems = drive_problems(command_v, sample_rate_hz, limits, start_v=start_v)
    if problems:
        raise DriveRefused(f"{who}: drive refused: " + "; ".join(problems))


__all__ = [
    "BYTES_PER_SAMPLE",
    "DriveRefused",
    "memory_text",
    "sample_rate_problems",
    "sample_count_problems",
    "drive_problems",
    "check_sample_rate",
    "check_drive",
]
