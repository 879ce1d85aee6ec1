"""Rig check: does the force follow a small drive, and how quiet is it at rest?

Pure numpy over one measured run: a rest segment (drive at 0 V) followed by a small,
slow drive. Used by ``piezopress check-rig`` before a characterization, to tell a
technician that the load cell is wired, scaled and polarised right.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from piezopress.errors import MetricError


@dataclass(frozen=True)
class RigCheck:
    """What a rig check found.

    Attributes
    ----------
    correlation : float
        Pearson correlation between drive and force over the driven segment (1: the
        force follows the drive exactly; hysteresis and noise lower it a little).
    gain_n_per_v : float
        Least-squares slope of force against drive over the driven segment, N per
        actuator volt (the virtual thesis press: about 1.5-2 N/V; negative: the load cell
        reads backwards).
    noise_rms_n : float
        RMS of the force about its mean at rest: the noise floor.
    offset_n : float
        Mean force at rest (the preload plus any offset of the load cell).
    follows : bool
        ``correlation >= min_correlation`` and a positive gain.
    min_correlation : float
        The threshold used for ``follows``.
    """

    correlation: float
    gain_n_per_v: float
    noise_rms_n: float
    offset_n: float
    follows: bool
    min_correlation: float


def rig_check(
    command_v: np.ndarray, force_n: np.ndarray, rest_samples: int, *, min_correlation: float = 0.9
) -> RigCheck:
    """Analyse a rig-check run: ``rest_samples`` at rest, then the drive.

    Parameters
    ----------
    command_v, force_n : numpy.ndarray
        Drive (actuator volts) and measured force, same length.
    rest_samples : int
        How many samples at the start are at rest (drive at 0 V): noise floor and offset.
    min_correlation : float
        Below this correlation the force is said not to follow the drive.

    Examples
    --------
    >>> v = np.r_[np.zeros(100), np.sin(np.linspace(0, 6, 300)) + 1]
    >>> r = rig_check(v, 50 + 2 * v, 100)
    >>> round(r.gain_n_per_v, 6), round(r.offset_n, 6), r.follows
    (2.0, 50.0, True)
    """
    v = np.asarray(command_v, dtype=np.float64)
    f = np.asarray(force_n, dtype=np.float64)
    if v.shape != f.shape or v.ndim != 1:
        raise MetricError(
            f"rig check: drive of shape {v.shape} and force of shape {f.shape}; expected two 1-D arrays of one length"
        )
    if not 10 <= rest_samples <= len(v) - 10:
        raise MetricError(
            f"rig check: rest_samples = {rest_samples} of {len(v)}; expected at least 10 at rest and 10 driven"
        )
    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(f))):
        raise MetricError("rig check: drive or force holds NaN or infinite values; expected finite numbers")
    rest, drive, force = f[:rest_samples], v[rest_samples:], f[rest_samples:]
    dv = drive - drive.mean()
    df = force - force.mean()
    if not np.any(dv):
        raise MetricError("rig check: the drive does not vary after the rest; expected a moving drive")
    gain = float(np.dot(dv, df) / np.dot(dv, dv))
    denom = float(np.sqrt(np.dot(dv, dv) * np.dot(df, df)))
    corr = float(np.dot(dv, df) / denom) if denom > 0 else 0.0
    return RigCheck(
        correlation=corr,
        gain_n_per_v=gain,
        noise_rms_n=float(np.sqrt(np.mean((rest - rest.mean()) ** 2))),
        offset_n=float(rest.mean()),
        follows=bool(corr >= min_correlation and gain > 0),
        min_correlation=float(min_correlation),
    )
