"""Rig check: drive a small, safe signal and report whether the wiring is right.

The drive is ``rest_s`` at 0 V (noise floor and offset), then raised-cosine cycles from
0 V up to ``amplitude_v`` and back at ``freq_hz`` (a 2 V, 1 Hz sine on top of 0 V for 3 s
by default: a few newtons on the thesis press). It goes through the backend like any run,
so on hardware every interlock applies (drive limits, preload read, over-force, ramp-down).
The analysis is :func:`piezopress.analysis.rigcheck.rig_check`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from piezopress.acquisition import drive_check, waveforms
from piezopress.acquisition.backend import Backend, stop_signals_interrupt
from piezopress.acquisition.plan import DriveLimits
from piezopress.analysis.rigcheck import RigCheck, rig_check
from piezopress.errors import BackendError, PiezopressError
from piezopress.pipelines.characterize import make_backend


@dataclass(frozen=True)
class RigCheckReport:
    """The rig check's findings with what was played and how fast it was sampled."""

    rig: str
    backend: str
    amplitude_v: float
    freq_hz: float
    duration_s: float
    rest_s: float
    sample_rate_hz: float
    #: the rate the board actually ran at (``None``: simulated, exactly the requested rate)
    sample_rate_achieved_hz: float | None
    samples_planned: int
    samples_measured: int
    preload_measured_n: float | None
    check: RigCheck

    def as_dict(self) -> dict[str, Any]:
        d = {k: getattr(self, k) for k in self.__dataclass_fields__ if k != "check"}
        return {**d, **{f"check_{k}": v for k, v in self.check.__dict__.items()}}


def check_drive(
    amplitude_v: float,
    freq_hz: float,
    duration_s: float,
    rest_s: float,
    sample_rate_hz: float,
    limits: DriveLimits | None = None,
) -> tuple[np.ndarray, int]:
    """``(command_v, rest_samples)``: rest at 0 V, then raised-cosine cycles 0 -> ``amplitude_v`` -> 0.

    With ``limits`` (the rig's), the sample rate, the number of samples and the duration are
    checked against them before anything is built, and the drive itself by the shared
    drive check."""
    values = (amplitude_v, freq_hz, duration_s, rest_s, sample_rate_hz)
    if not all(math.isfinite(v) and v > 0 for v in values):
        raise PiezopressError(
            f"check-rig: amplitude_v = {amplitude_v:g}, freq_hz = {freq_hz:g}, duration_s = {duration_s:g}, rest_s = "
            f"{rest_s:g}, "
            f"sample_rate_hz = {sample_rate_hz:g}; expected all positive and finite"
        )
    if sample_rate_hz < 20 * freq_hz:
        raise PiezopressError(
            f"check-rig: sample_rate_hz = {sample_rate_hz:g} is too low for freq_hz = {freq_hz:g}; expected at least "
            "20 samples per cycle"
        )
    cycles = max(1, int(round(duration_s * freq_hz)))
    if limits is not None:
        problems = drive_check.sample_rate_problems(sample_rate_hz, limits, "--sample-rate-hz")
        samples = (rest_s + cycles / freq_hz) * sample_rate_hz
        problems += drive_check.sample_count_problems(samples, sample_rate_hz, limits, "the check drive")
        if rest_s + cycles / freq_hz > limits.max_duration_s:
            problems.append(
                f"the check drive lasts {rest_s + cycles / freq_hz:.4g} s, more than the rig's limit of "
                f"{limits.max_duration_s:g} s"
            )
        if problems:
            raise drive_check.DriveRefused(
                f"check-rig: {'; '.join(problems)}; expected a short, small drive within the rig's limits"
            )
    rest = np.zeros(max(10, int(round(rest_s * sample_rate_hz))))
    sine = waveforms.sine(freq_hz, cycles, 0.0, amplitude_v, sample_rate_hz)
    return np.concatenate([rest, sine[1:]]), len(rest)


def check_rig(
    rig_path: str | Path | None,
    backend_name: str | None = None,
    *,
    amplitude_v: float = 2.0,
    freq_hz: float = 1.0,
    duration_s: float = 3.0,
    rest_s: float = 1.0,
    sample_rate_hz: float = 1000.0,
    preload_n: float = 50.0,
    min_correlation: float = 0.9,
    backend: Backend | None = None,
) -> RigCheckReport:
    """Play the check drive on the rig of ``rig_path`` (its ``[rig] backend``) and analyse it.

    Raises
    ------
    BackendError
        When the backend refuses the drive or the preload, or cuts the run short (the
        reason says why); the drive is back at 0 V then.
    """
    backend = backend or make_backend(backend_name, rig_path)
    command_v, rest_samples = check_drive(amplitude_v, freq_hz, duration_s, rest_s, sample_rate_hz, backend.limits)
    drive_check.check_drive(command_v, sample_rate_hz, backend.limits, f"check-rig ({backend.name})")
    try:
        with (
            stop_signals_interrupt()
        ):  # SIGTERM/SIGHUP as Ctrl-C: the drive back to 0 V, then the CLI's exit 128 + signal
            m = backend.run(command_v, sample_rate_hz, preload_n=preload_n, label="check-rig")
    except KeyboardInterrupt:
        backend.zero_output()
        raise
    if not m.complete:
        raise BackendError(
            f"check-rig: the run was cut short after {min(map(len, m.channels.values()), default=0)} samples: "
            f"{m.reason}"
        )
    if "force_n" not in m.channels:
        raise BackendError(
            f"check-rig: the {backend.name} backend measured no force_n (channels: {', '.join(m.channels)})"
        )
    force_n = np.asarray(m.channels["force_n"], dtype=np.float64)
    achieved = m.info.get("sample_rate_achieved_hz")
    return RigCheckReport(
        rig=str(backend.describe().get("source", rig_path)),
        backend=backend.name,
        amplitude_v=amplitude_v,
        freq_hz=freq_hz,
        duration_s=duration_s,
        rest_s=rest_s,
        sample_rate_hz=sample_rate_hz,
        sample_rate_achieved_hz=None if achieved is None else float(achieved),
        samples_planned=len(command_v),
        samples_measured=len(force_n),
        preload_measured_n=m.info.get("preload_measured_n"),
        check=rig_check(command_v, force_n, rest_samples, min_correlation=min_correlation),
    )


def format_report(r: RigCheckReport) -> str:
    """The report as a technician reads it: one finding per line, the verdict last."""
    c = r.check
    achieved = (
        "simulated (exact)"
        if r.sample_rate_achieved_hz is None
        else f"{r.sample_rate_achieved_hz:g} Hz on one clock for output and input"
    )
    lines = [
        f"rig:            {r.rig} (backend {r.backend})",
        f"drive:          {r.rest_s:g} s at 0 V, then 0 -> {r.amplitude_v:g} V raised-cosine at {r.freq_hz:g} Hz for "
        f"{r.duration_s:g} s",
        f"sample rate:    asked {r.sample_rate_hz:g} Hz, achieved {achieved}; {r.samples_measured} of "
        f"{r.samples_planned} samples",
    ]
    if r.preload_measured_n is not None:
        lines.append(f"preload read:   {r.preload_measured_n:.2f} N before the run")
    lines += [
        f"offset at rest: {c.offset_n:.3f} N (mean force at 0 V: preload plus load-cell offset)",
        f"noise floor:    {c.noise_rms_n:.4f} N RMS at rest",
        f"force follows:  correlation {c.correlation:.4f} with the drive, gain {c.gain_n_per_v:.4g} N/V",
        "verdict:        "
        + (
            "OK: the force follows the drive"
            if c.follows
            else f"NOT OK: the force does not follow the drive (correlation below {c.min_correlation:g} or gain not "
            "positive); "
            "check the load cell's channel, wiring, sensitivity and sign"
        ),
    ]
    return "\n".join(lines)
