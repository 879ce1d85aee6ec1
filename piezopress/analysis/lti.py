"""The press's linear parts as LTI systems, and their frequency responses (python-control).

- :func:`mode_system`: the identified mode ``wn^2 / (s^2 + 2 zeta wn s + wn^2)`` (thesis Eq. 6.2);
- :func:`creep_system` and :func:`creep_compensator_system`: the creep model ``K_c + C(s)``,
  ``C(s) = sum_k g_k / (1 + tau_k s)`` (thesis Eq. 3.37), as a diagonal state-space system
  (a transfer function of the log form's twelve poles spread over six decades would lose
  its coefficients to rounding), and its inverse ``1 / (K_c + C(s))`` (Eq. 3.38, Fig. 3.9);
- :func:`bode`: magnitude and phase of any of them at given frequencies;
- :func:`measured_response`: the frequency response a recorded step shows, from the data
  alone (numpy's FFT; a measurement, not a model, so python-control has no part in it);
- :func:`shaper_sensitivity`: an input shaper's residual vibration against the error of
  the mode's frequency. Not through python-control: a shaper is a sum of pure delays,
  which no rational LTI object represents exactly (a Padé approximation would only
  approximate what :func:`piezopress.analysis.shaper.residual_vibration` gives in closed form).

Pure math; no file I/O, no plotting.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import control
import numpy as np

from piezopress.analysis.creep import CreepModel
from piezopress.analysis.mode import check_mode
from piezopress.analysis.shaper import Shaper
from piezopress.errors import FitError

__all__ = [
    "mode_system",
    "creep_system",
    "creep_compensator_system",
    "bode",
    "Bode",
    "measured_response",
    "MeasuredResponse",
    "shaper_sensitivity",
]


@dataclass(frozen=True)
class Bode:
    """A frequency response: ``freq_hz``, ``magnitude`` (a ratio, 1 = unit gain) and ``phase_deg``."""

    freq_hz: np.ndarray
    magnitude: np.ndarray
    phase_deg: np.ndarray


def mode_system(wn: float, zeta: float) -> control.TransferFunction:
    """The unit-gain mode ``wn^2 / (s^2 + 2 zeta wn s + wn^2)`` (``wn`` in rad/s).

    >>> round(float(abs(mode_system(6400.0, 0.1)(1j * 6400.0))), 6)  # 1 / (2 zeta) at wn
    5.0
    """
    wn, zeta = check_mode(wn, zeta)
    return control.tf([wn * wn], [1.0, 2.0 * zeta * wn, wn * wn])


def _creep_parts(model: CreepModel) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    taus = np.asarray(model.taus_s, dtype=float)
    g = np.asarray(model.gains, dtype=float)
    return np.diag(-1.0 / taus), np.ones((taus.size, 1)), (g / taus)[None, :], float(model.static_gain)


def creep_system(model: CreepModel) -> control.StateSpace:
    """``K_c + sum_k g_k / (1 + tau_k s)`` as a state-space system: one state per term,
    ``x_k' = (u - x_k) / tau_k``, ``y = K_c u + sum_k g_k x_k``."""
    a, b, c, d = _creep_parts(model)
    return control.ss(a, b, c, [[d]])


def creep_compensator_system(model: CreepModel) -> control.StateSpace:
    """``1 / (K_c + C(s))``: the creep compensator (thesis Eq. 3.38), the exact inverse of
    :func:`creep_system` (``A - B C / K_c``, ``B / K_c``, ``-C / K_c``, ``1 / K_c``).
    Its poles are the zeros of the creep model; one with a positive real part (a
    non-minimum-phase model) is refused."""
    a, b, c, d = _creep_parts(model)
    if d <= 0:
        raise FitError(f"creep model K_c = {d!r}: expected K_c > 0 (the compensator divides by it)")
    inv = control.ss(a - b @ c / d, b / d, -c / d, [[1.0 / d]])
    poles = np.linalg.eigvals(inv.A) if inv.nstates else np.array([])
    if np.any(poles.real > 0):
        raise FitError(
            f"creep model {model.describe()}: its compensator has an unstable pole at "
            f"{poles.real.max():.3g} 1/s; expected a minimum-phase model"
        )
    return inv


def bode(system, freq_hz) -> Bode:
    """Magnitude (ratio) and phase (degrees, unwrapped) of ``system`` at ``freq_hz`` (Hz, > 0)."""
    f = np.asarray(freq_hz, dtype=float)
    if f.ndim != 1 or f.size == 0 or not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise FitError("freq_hz: expected a 1-D array of finite frequencies > 0 Hz")
    resp = control.frequency_response(system, 2.0 * np.pi * f)
    h = np.asarray(resp.complex).reshape(-1)
    return Bode(f, np.abs(h), np.degrees(np.unwrap(np.angle(h))))


@dataclass(frozen=True)
class MeasuredResponse(Bode):
    """The response a record shows, point by point: ``coherent`` marks the points whose band
    the drive excited enough (its energy per FFT bin at least ``MIN_DRIVE_SHARE`` of the
    best-excited band's), ``gain`` the magnitude the response was divided by."""

    coherent: np.ndarray = None  # type: ignore[assignment]
    gain: float = math.nan


#: A band is kept when the drive's energy density in it (per FFT bin) is at least this share of its largest band's.
MIN_DRIVE_SHARE = 1e-3
#: Half-width of the band each point of a measured response averages over (fraction of its frequency).
BAND_REL_WIDTH = 0.02


def measured_response(
    drive, output, fs_hz: float, freq_hz, *, gain: float | None = None, rel_width: float = BAND_REL_WIDTH
) -> MeasuredResponse:
    """The frequency response from a drive record to an output record, at ``freq_hz``.

    The records' differences (a step becomes an impulse, so a record that starts and ends
    at rest holds the whole transient) are transformed and, in a narrow band around each
    frequency (``f (1 +/- rel_width)``, at least two FFT bins either side), the H1
    estimate ``sum(Y conj(U)) / sum(|U|^2)`` is taken: bins where the drive has no energy
    (the zeros of a step up and down) weigh nothing instead of dividing noise by zero.
    ``gain`` normalises the magnitude (default: the response's magnitude at the lowest
    frequency kept); the phase is relative to the drive. Sampled records: above a fifth of
    the sample rate, what the drive holds beyond Nyquist folds back and biases the estimate.
    """
    u = np.asarray(drive, dtype=float)
    y = np.asarray(output, dtype=float)
    if u.ndim != 1 or u.shape != y.shape or u.size < 16:
        raise FitError(
            f"drive and output: expected two 1-D records of the same length (>= 16 samples), got {u.shape} and "
            f"{y.shape}"
        )
    fs = float(fs_hz)
    if not (math.isfinite(fs) and fs > 0):
        raise FitError(f"fs_hz={fs_hz!r}: expected a finite sample rate > 0 Hz")
    f = np.asarray(freq_hz, dtype=float)
    if f.ndim != 1 or f.size < 2 or np.any(np.diff(f) <= 0) or f[0] <= 0 or f[-1] >= fs / 2:
        raise FitError(f"freq_hz: expected increasing frequencies in (0, {fs / 2:g}) Hz (below Nyquist), at least two")
    du, dy = np.diff(u), np.diff(y)
    n = 1 << int(math.ceil(math.log2(du.size * 2)))
    U, Y = np.fft.rfft(du, n), np.fft.rfft(dy, n)
    fb = np.fft.rfftfreq(n, 1.0 / fs)
    half = np.maximum(rel_width * f, 2.0 * fs / n)
    h = np.full(f.size, np.nan + 0j)
    energy = np.zeros(f.size)
    for i in range(f.size):
        m = (fb >= f[i] - half[i]) & (fb <= f[i] + half[i])
        energy[i] = float(np.mean(np.abs(U[m]) ** 2)) if np.any(m) else 0.0
        if energy[i] > 0:
            h[i] = np.sum(Y[m] * np.conj(U[m])) / np.sum(np.abs(U[m]) ** 2)
    coherent = energy >= MIN_DRIVE_SHARE * energy.max() if energy.max() > 0 else np.zeros(f.size, bool)
    if not np.any(coherent):
        raise FitError("drive: no energy in any band of freq_hz; expected a record with a step or a sweep")
    g = abs(h[np.flatnonzero(coherent)[0]]) if gain is None else float(gain)
    if not (math.isfinite(g) and g > 0):
        raise FitError(f"gain={g!r}: expected a finite gain > 0 to normalise the response")
    mag = np.abs(h) / g
    phase = np.degrees(np.angle(h))
    k = np.flatnonzero(coherent)
    phase[k] = np.degrees(np.unwrap(np.angle(h[k])))
    return MeasuredResponse(f, mag, phase, coherent, g)


def shaper_sensitivity(shaper: Shaper, ratios) -> np.ndarray:
    """Residual vibration (a fraction: 0 none, 1 as without a shaper) of ``shaper`` on a
    mode at ``ratio * wn`` (its design damping), for each ratio: how the shaper tolerates
    an error in the mode's frequency."""
    r = np.asarray(ratios, dtype=float)
    if r.ndim != 1 or not np.all(np.isfinite(r)) or np.any(r <= 0):
        raise FitError("ratios: expected a 1-D array of finite frequency ratios > 0")
    return np.array([shaper.residual(shaper.wn * x, shaper.zeta) for x in r])
