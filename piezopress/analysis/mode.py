"""A lightly damped second-order mode in discrete time (the press's ring, thesis Eq. 6.2).

``G(s) = wn^2 / (s^2 + 2 zeta wn s + wn^2)`` discretised exactly for a drive held between
samples (``zoh``: a DAC's command) or linear between them (``foh``: a sampled continuous
voltage such as the amplifier monitor), and its response to a sampled drive. Used by the
mode identification (:mod:`piezopress.analysis.mode_fit`), the input shapers
(:mod:`piezopress.analysis.shaper`) and the diagnosis's forward model. Invalid arguments
raise :class:`~piezopress.errors.FitError` naming the value and the range expected.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import lfilter

from piezopress.errors import FitError

__all__ = [
    "HOLDS",
    "mode_zoh",
    "mode_foh",
    "mode_response",
    "antiresonant",
    "check_mode",
    "check_fs",
    "damped",
]


def check_mode(wn: float, zeta: float, *, zeta_max: float = 1.0) -> tuple[float, float]:
    wn, zeta = float(wn), float(zeta)
    if not (math.isfinite(wn) and wn > 0):
        raise FitError(f"wn={wn!r} rad/s: expected a finite natural frequency > 0")
    if not (math.isfinite(zeta) and 0.0 <= zeta < zeta_max):
        raise FitError(f"zeta={zeta!r}: expected a damping ratio in [0, {zeta_max:g})")
    return wn, zeta


def check_fs(fs_hz: float) -> float:
    fs_hz = float(fs_hz)
    if not (math.isfinite(fs_hz) and fs_hz > 0):
        raise FitError(f"fs_hz={fs_hz!r}: expected a finite sample rate > 0 Hz")
    return fs_hz


def damped(wn: float, zeta: float) -> tuple[float, float]:
    """(sigma, wd): decay rate and damped angular frequency (rad/s)."""
    return zeta * wn, wn * math.sqrt(1.0 - zeta * zeta)


def mode_zoh(wn: float, zeta: float, fs_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation ``(b, a)`` of ``wn^2 / (s^2 + 2 zeta wn s + wn^2)``.

    From the sampled unit-step response ``1 - exp(-sigma k T) (cos(wd k T) + sigma/wd sin(wd k T))``
    times ``(1 - z^-1)``: with ``alpha = exp(-sigma T)``, ``beta = wd T``,
    ``b = [0, 1 - alpha (cos beta + sigma/wd sin beta), alpha^2 + alpha (sigma/wd sin beta - cos beta)]``,
    ``a = [1, -2 alpha cos beta, alpha^2]``. Unit DC gain; exact for a drive held between
    samples (a DAC's output).
    """
    wn, zeta = check_mode(wn, zeta)
    fs_hz = check_fs(fs_hz)
    sigma, wd = damped(wn, zeta)
    dt = 1.0 / fs_hz
    alpha, beta = math.exp(-sigma * dt), wd * dt
    ratio = sigma / wd
    cb, sb = math.cos(beta), math.sin(beta)
    b = np.array([0.0, 1.0 - alpha * (cb + ratio * sb), alpha * alpha + alpha * (ratio * sb - cb)])
    a = np.array([1.0, -2.0 * alpha * cb, alpha * alpha])
    return b, a


def mode_foh(wn: float, zeta: float, fs_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact first-order-hold (triangle) discretisation ``(b, a)`` of the unit-gain mode.

    Exact for a drive that is linear between its samples, e.g. the sampled monitor of an
    amplifier slewing at a constant rate: ``G_foh(z) = (z - 1)^2 / (T z) Z{r(kT)}`` with the
    unit-ramp response ``r(t) = t - c0 + exp(-sigma t) (c0 cos(wd t) + c1 sin(wd t))``,
    ``c0 = 2 zeta / wn``, ``c1 = (2 zeta^2 - 1) / wd``. Over the common denominator
    ``D = z^2 - 2 alpha cos(beta) z + alpha^2`` (the poles of :func:`mode_zoh`) the numerator
    is ``D (1 - c0 (z - 1) / T) + (z - 1)^2 (c0 (z - alpha cos beta) + c1 alpha sin beta) / T``,
    whose cubic terms cancel. Same as ``scipy.signal.cont2discrete(..., method="foh")``, 300
    times faster; ``b[0] != 0`` (the output at a sample depends on the drive at it). Like
    :func:`mode_zoh` it loses about ``1e-16 / (wn / fs)^2`` to cancellation: 1e-15 for the
    press's mode at 20 kHz, 1e-9 for a mode 200 times slower.
    """
    wn, zeta = check_mode(wn, zeta)
    fs_hz = check_fs(fs_hz)
    sigma, wd = damped(wn, zeta)
    dt = 1.0 / fs_hz
    alpha, beta = math.exp(-sigma * dt), wd * dt
    cb, sb = math.cos(beta), math.sin(beta)
    c0, c1 = 2.0 * zeta / wn, (2.0 * zeta * zeta - 1.0) / wd
    a1, a2 = -2.0 * alpha * cb, alpha * alpha
    # the numerator's products written out (np.polymul on 3-term polynomials costs more than
    # the filter it feeds): a (m - k z) + (z - 1)^2 (k z + q), whose z^3 terms cancel
    k = c0 / dt
    m = 1.0 + k
    q = (c1 * alpha * sb - c0 * alpha * cb) / dt
    b = np.array([m - k * a1 + q - 2.0 * k, m * a1 - k * a2 - 2.0 * q + k, m * a2 + q])
    return b, np.array([1.0, a1, a2])


#: The drive between samples -> its exact discretisation.
HOLDS = {"zoh": mode_zoh, "foh": mode_foh}


def _rate_part(wn: float, zeta: float, fs_hz: float, hold: str) -> np.ndarray:
    """The numerator of ``s G(s)`` (``G`` the unit mode) discretised exactly for ``hold``, over
    the poles of :func:`mode_zoh` (units 1/s; zero at DC).

    ``zoh``: ``(1 - z^-1) Z{g(kT)}`` with ``g`` the mode's impulse response
    ``(wn^2 / wd) exp(-sigma t) sin(wd t)`` (``s G``'s step response);
    ``foh``: ``z (1 - z^-1)^2 / T Z{r(kT)}`` with ``r`` the mode's unit-step response (``s G``'s
    ramp response)."""
    sigma, wd = damped(wn, zeta)
    dt = 1.0 / fs_hz
    alpha, beta = math.exp(-sigma * dt), wd * dt
    cb, sb = math.cos(beta), math.sin(beta)
    if hold == "zoh":
        g = wn * wn / wd * alpha * sb
        return np.array([0.0, g, -g])
    a1, a2 = -2.0 * alpha * cb, alpha * alpha
    c = sigma / wd * alpha * sb - alpha * cb
    p, q = a1 - c + 1.0, a2 + c
    return np.array([p, q - p, -q]) / dt


def antiresonant(
    wn: float, zeta: float, zeros: tuple[float, float], fs_hz: float, *, hold: str = "zoh"
) -> tuple[np.ndarray, np.ndarray]:
    """Exact discretisation ``(b, a)`` of the unit-gain mode with a pair of zeros (an
    anti-resonance) ``zeros = (wz rad/s, damping)``:
    ``G(s) = (wn / wz)^2 (s^2 + 2 zeta_z wz s + wz^2) / (s^2 + 2 zeta wn s + wn^2)`` (a stack
    pushing a platen on a compliant frame: the force drops to a notch at ``wz`` above the mode).

    Written as ``c + (1 - c) M(s) + k s M(s)`` (``M`` the unit mode, ``c = (wn / wz)^2``,
    ``k = 2 zeta_z / wz - 2 zeta wn / wz^2``), each part exact for the hold (:func:`mode_zoh` or
    :func:`mode_foh`; :func:`_rate_part`), over the mode's own poles. Unit DC gain; the
    low-frequency delay is ``2 zeta / wn - 2 zeta_z / wz`` (the zeros lead)."""
    if hold not in HOLDS:
        raise FitError(f"hold={hold!r}: expected one of {sorted(HOLDS)}")
    wn, zeta = check_mode(wn, zeta)
    wz, zz = check_mode(*zeros)
    fs_hz = check_fs(fs_hz)
    b_m, a = HOLDS[hold](wn, zeta, fs_hz)
    c = (wn / wz) ** 2
    k = 2.0 * zz / wz - 2.0 * zeta * wn / (wz * wz)
    return c * a + (1.0 - c) * b_m + k * _rate_part(wn, zeta, fs_hz, hold), a


def mode_response(
    drive, fs_hz: float, wn: float, zeta: float, *, hold: str = "zoh", zeros: tuple[float, float] | None = None
) -> np.ndarray:
    """Output of the unit-gain mode to the sampled ``drive``, at rest at ``drive[0]``.

    ``hold="zoh"``: the drive is held between samples (a command from a DAC);
    ``hold="foh"``: it is linear between samples (a sampled continuous voltage).
    ``zeros``: an anti-resonance ``(wz rad/s, damping)`` above the mode (:func:`antiresonant`).
    """
    if hold not in HOLDS:
        raise FitError(f"hold={hold!r}: expected one of {sorted(HOLDS)}")
    d = np.asarray(drive, dtype=float)
    b, a = HOLDS[hold](wn, zeta, fs_hz) if zeros is None else antiresonant(wn, zeta, zeros, fs_hz, hold=hold)
    return d[0] + lfilter(b, a, d - d[0])
