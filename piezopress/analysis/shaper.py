"""Input shaping against the press's dominant mode (thesis Section 3.1.3, Section 6.4).

The press rings like one lightly damped second-order mode (thesis Eq. 6.2:
``wn = 6.44e3 rad/s``, ``zeta = 0.115``, a 1.02 kHz ring). An input shaper is a short
sequence of impulses ``A_i`` at times ``t_i``; convolving the reference with it makes the
ringing excited by each impulse cancel that of the others.

Residual vibration
------------------
A unit impulse at ``t_i`` excites ``h(t - t_i)``, with
``h(t) = wn / sqrt(1 - zeta^2) * exp(-zeta wn t) * sin(wd t)``, ``wd = wn sqrt(1 - zeta^2)``.
Writing ``exp(-zeta wn (t - t_i)) sin(wd (t - t_i)) = Im[exp(s t) exp(-s t_i)]`` with
``s = -zeta wn + j wd``, the ringing after the last impulse is a single damped sinusoid of
amplitude ``wn/sqrt(1-zeta^2) * exp(-zeta wn t) * |sum A_i exp(zeta wn t_i) exp(-j wd t_i)|``.
Dividing by the ringing a single impulse of the same total area would leave at the same
time gives the standard percentage residual vibration (Singer & Seering 1990, Singhose):

    V = exp(-zeta wn t_last) |sum A_i exp(zeta wn t_i) exp(j wd t_i)| / |sum A_i|

(the sign of ``j`` does not change the modulus). The same ratio holds for steps instead
of impulses (the oscillating part of a step response is the same complex exponential), so
``V`` is also the residual of a shaped step, and of a sampled-and-held shaped step whose
impulses sit on the sample instants: :func:`residual_vibration` of a *discretized* shaper
(times ``k / fs``) is exact for the real, continuous press driven through a DAC.

The ZV family
-------------
ZV (two impulses half a damped period apart) has ``V = 0`` at the design point. ZV
convolved with itself ``p - 1`` times (ZVD, ZVDD, ...: the thesis's family, Eq. 3.45-3.47)
has ``p`` impulses ``A_i = C(p-1, i-1) K^(i-1) / (1+K)^(p-1)``,
``K = exp(-pi zeta / sqrt(1 - zeta^2))``, spaced by *half* the damped period (the thesis's
Eq. 3.46 writes a whole period, which cancels nothing). Each extra factor puts another zero
of the shaper on the mode's pole, which flattens ``V`` around the design frequency (it is
robust to modelling error) at the cost of half a period of delay per factor.

Digitisation
------------
Impulses between samples must be split between neighbours. Linear splitting keeps the
area and the centroid but not the phase at the mode's frequency, so a ZV shaper split that
way leaves a residual. For the ZV family the split is exact: the shaped input
``sum a_k x[n - k]`` cancels the discretised mode, poles ``p = exp((-zeta wn +/- j wd) / fs)``,
iff ``H(p) = sum a_k p^-k = 0``. ZV with a half period of ``N = fs Td / 2`` samples
(``n = floor(N)``) puts impulses at samples ``0, n, n + 1`` and solves the three real linear
equations ``sum a_k = 1``, ``Re H(p) = 0``, ``Im H(p) = 0``; because ``p^-n`` and ``p^-(n+1)``
lie on either side of the negative real axis all three are positive. ZV^m is that discrete
ZV convolved with itself (an ``m``-fold zero at ``p``).

The mode itself in discrete time is :mod:`piezopress.analysis.mode`, and its identification
from step responses :mod:`piezopress.analysis.mode_fit`.

Shapers are data: :data:`SHAPERS` maps a name to its design function and notes, and drives
:func:`design_shaper` and :func:`choose_shaper` alike. Pure numpy/scipy: no file I/O, no
plotting. Invalid arguments raise :class:`~piezopress.errors.FitError` naming the value and
the range expected.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import root

from piezopress.analysis.mode import check_fs as _check_fs
from piezopress.analysis.mode import check_mode as _check_mode
from piezopress.analysis.mode import damped as _damped
from piezopress.errors import FitError

__all__ = [
    "Shaper",
    "ShaperSpec",
    "ShaperChoice",
    "SHAPERS",
    "THESIS_TABLE_6_8",
    "EI_VTOL",
    "residual_vibration",
    "zv_family",
    "ei_shaper",
    "design_shaper",
    "choose_shaper",
    "thesis_shaper_residual",
]

#: Tolerable vibration of the EI shaper (Singhose's usual 5 %), and the default threshold
#: of :func:`choose_shaper`.
EI_VTOL = 0.05
#: Tolerance on ``sum(amplitudes) == 1`` (the thesis's 4-decimal table sums to 1 exactly).
_SUM_TOL = 1e-6
#: Impulses smaller than this (after an exact discrete design) are rounding, not impulses.
_TINY = 1e-14


# ---------------------------------------------------------------------------------------
# Residual vibration
# ---------------------------------------------------------------------------------------


def residual_vibration(times_s, amplitudes, wn: float, zeta: float) -> float:
    """Percentage residual vibration (as a fraction) of an impulse sequence on one mode.

    ``V = exp(-zeta wn t_last) |sum A_i exp(zeta wn t_i) exp(j wd t_i)| / |sum A_i|``: the
    amplitude of the ringing left after the last impulse, relative to that of a single
    impulse (or step) of the same total area (derivation in the module docstring).

    Parameters
    ----------
    times_s : array_like
        Impulse times (s), any order, finite.
    amplitudes : array_like
        Impulse amplitudes, same length; their sum must not be 0.
    wn : float
        Natural frequency of the mode (rad/s), > 0.
    zeta : float
        Damping ratio, in [0, 1).

    Returns
    -------
    float
        ``V``: 0 for perfect cancellation, 1 for no reduction at all.

    Examples
    --------
    >>> K = math.exp(-math.pi * 0.115 / math.sqrt(1 - 0.115**2))
    >>> td = 2 * math.pi / (6.44e3 * math.sqrt(1 - 0.115**2))
    >>> residual_vibration([0, td / 2], [1 / (1 + K), K / (1 + K)], 6.44e3, 0.115) < 1e-12
    True
    """
    wn, zeta = _check_mode(wn, zeta)
    t = np.asarray(times_s, dtype=float)
    a = np.asarray(amplitudes, dtype=float)
    if t.ndim != 1 or a.ndim != 1 or t.size != a.size or t.size == 0:
        raise FitError(
            f"times_s and amplitudes: expected two 1-D arrays of the same nonzero length, got shapes {t.shape} and "
            f"{a.shape}"
        )
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(a))):
        raise FitError("times_s and amplitudes: expected finite values (found NaN or inf)")
    total = float(np.sum(a))
    if total == 0.0:
        raise FitError("amplitudes: their sum is 0; the residual is relative to the sum")
    sigma, wd = _damped(wn, zeta)
    # exp(zeta wn t_i) / exp(zeta wn t_last), written so it never overflows
    phasor = np.sum(a * np.exp(-sigma * (t.max() - t)) * np.exp(1j * wd * t))
    return float(abs(phasor) / abs(total))


# ---------------------------------------------------------------------------------------
# Shapers
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Shaper:
    """An input shaper: impulses at ``times_s`` with ``amplitudes`` (positive, summing to 1).

    Attributes
    ----------
    name : str
        Registry name (``"zv"``, ``"zvd"``, ...) or a label (``"thesis-table-6.8"``).
    times_s : tuple of float
        Impulse times (s), non-decreasing, the first >= 0.
    amplitudes : tuple of float
        Impulse amplitudes, all > 0, summing to 1 (within 1e-6).
    wn, zeta : float
        The mode the shaper was designed for (rad/s, damping ratio).
    zv_power : int or None
        ``m`` when the shaper is ZV^m designed for ``(wn, zeta)``: :meth:`discretize` then
        designs the sampled shaper exactly. ``None``: impulses are split linearly.
    delay_s : float
        Time of the last impulse (property).
    centroid_s : float
        Amplitude-weighted mean time (property): the average delay the shaper adds.

    Examples
    --------
    >>> s = design_shaper("zvd", 6.44e3, 0.115)
    >>> len(s.amplitudes), round(s.delay_s * 1e3, 3)
    (3, 0.982)
    """

    name: str
    times_s: tuple[float, ...]
    amplitudes: tuple[float, ...]
    wn: float
    zeta: float
    zv_power: int | None = None

    def __post_init__(self):
        t = tuple(float(v) for v in self.times_s)
        a = tuple(float(v) for v in self.amplitudes)
        object.__setattr__(self, "times_s", t)
        object.__setattr__(self, "amplitudes", a)
        wn, zeta = _check_mode(self.wn, self.zeta)
        object.__setattr__(self, "wn", wn)
        object.__setattr__(self, "zeta", zeta)
        if len(t) == 0 or len(t) != len(a):
            raise FitError(
                f"Shaper {self.name!r}: expected as many times as amplitudes (>= 1), got {len(t)} and {len(a)}"
            )
        if not all(math.isfinite(v) for v in t + a):
            raise FitError(f"Shaper {self.name!r}: times_s and amplitudes must be finite")
        if t[0] < 0 or any(t1 < t0 for t0, t1 in zip(t, t[1:])):
            raise FitError(f"Shaper {self.name!r}: times_s={t} must be non-decreasing and start at >= 0 s")
        if min(a) <= 0:
            raise FitError(f"Shaper {self.name!r}: amplitudes={a} must all be > 0")
        if abs(sum(a) - 1.0) > _SUM_TOL:
            raise FitError(f"Shaper {self.name!r}: amplitudes sum to {sum(a)!r}; expected 1 (within {_SUM_TOL:g})")
        if self.zv_power is not None and not (isinstance(self.zv_power, int) and self.zv_power >= 1):
            raise FitError(f"Shaper {self.name!r}: zv_power={self.zv_power!r}; expected None or an int >= 1")

    @property
    def delay_s(self) -> float:
        return self.times_s[-1]

    @property
    def centroid_s(self) -> float:
        return float(np.dot(self.times_s, self.amplitudes) / np.sum(self.amplitudes))

    def residual(self, wn: float | None = None, zeta: float | None = None) -> float:
        """Continuous residual vibration on a mode (the design mode by default)."""
        return residual_vibration(
            self.times_s, self.amplitudes, self.wn if wn is None else wn, self.zeta if zeta is None else zeta
        )

    def discretize(self, fs_hz: float) -> tuple[np.ndarray, np.ndarray]:
        """Impulses on the sample grid: ``(sample_offsets, amplitudes)``.

        ZV^m shapers are designed exactly for the sampled mode (module docstring): the
        discrete shaper has a ``m``-fold zero on the mode's z-pole, so a held, sampled
        shaped signal leaves no residual vibration at all on the design mode; its delay is
        up to ``m`` samples longer than :attr:`delay_s`. Other shapers (EI, a printed
        table) are split linearly: an impulse at ``(k + f) / fs`` becomes ``1 - f`` at ``k``
        and ``f`` at ``k + 1`` (area and centroid kept, phase at the mode only to second
        order in ``wd / fs``). For EI, whose nominal residual is 5 % by design rather than
        0, that error is a small change to a plateau and is acceptable.

        Returns
        -------
        sample_offsets : numpy.ndarray of int
            Strictly increasing, starting at 0 (or later if ``times_s[0] > 0``).
        amplitudes : numpy.ndarray of float
            All > 0, summing to 1.
        """
        fs_hz = _check_fs(fs_hz)
        if self.zv_power is not None:
            off, amp = _discrete_zv(self.wn, self.zeta, fs_hz)
            dense = np.zeros(off[-1] + 1)
            dense[off] = amp
            full = np.array([1.0])
            for _ in range(self.zv_power):
                full = np.convolve(full, dense)
            keep = np.abs(full) > _TINY
            offsets, amps = np.flatnonzero(keep), full[keep]
            if np.any(amps <= 0):  # cannot happen (see _discrete_zv); guard the invariant
                raise FitError(f"Shaper {self.name!r}: exact discretization at fs_hz={fs_hz} gave a negative impulse")
            return offsets.astype(int), amps / amps.sum()
        return _linear_split(self.times_s, self.amplitudes, fs_hz)

    def apply(self, x, fs_hz: float) -> np.ndarray:
        """Shape ``x`` (sampled at ``fs_hz``): causal convolution with :meth:`discretize`.

        ``y[n] = sum_k a_k x[n - k]``, with ``x`` held at ``x[0]`` before its start. Same
        length as ``x``; a constant stays constant (the amplitudes sum to 1).
        """
        return self._convolve(x, fs_hz, advance=False)

    def apply_centered(self, x, fs_hz: float) -> np.ndarray:
        """:meth:`apply`, advanced by the rounded centroid of the discretized impulses.

        The whole reference of an open-loop run is known before it starts, so the shaper
        may be non-causal: advancing by ``round(sum a_k k)`` samples (within a sample of
        ``centroid_s * fs``) removes its average delay. ``x`` is held at ``x[0]`` before
        the start and at ``x[-1]`` after the end; same length as ``x``.
        """
        return self._convolve(x, fs_hz, advance=True)

    def _convolve(self, x, fs_hz: float, *, advance: bool) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        if x.ndim != 1 or x.size == 0:
            raise FitError(f"x: expected a non-empty 1-D signal, got shape {x.shape}")
        if not np.all(np.isfinite(x)):
            raise FitError("x: expected finite values (found NaN or inf)")
        offsets, amps = self.discretize(fs_hz)
        taps = np.zeros(int(offsets[-1]) + 1)
        taps[offsets] = amps
        lead = taps.size - 1
        c = int(round(float(np.dot(offsets, amps)))) if advance else 0
        ext = np.concatenate([np.full(lead, x[0]), x, np.full(c, x[-1])])
        y = np.convolve(ext, taps, mode="valid")  # y[n] = sum_k taps[k] x[n - k], len(x) + c
        return y[c:]


def _linear_split(times_s, amplitudes, fs_hz: float) -> tuple[np.ndarray, np.ndarray]:
    pos = np.asarray(times_s, dtype=float) * fs_hz
    pos = np.where(np.abs(pos - np.round(pos)) < 1e-9, np.round(pos), pos)  # on a sample: no split
    k = np.floor(pos).astype(int)
    f = pos - k
    a = np.asarray(amplitudes, dtype=float)
    dense = np.zeros(int(k.max()) + 2)
    np.add.at(dense, k, a * (1.0 - f))
    np.add.at(dense, k + 1, a * f)
    keep = dense > _TINY
    return np.flatnonzero(keep).astype(int), dense[keep] / dense[keep].sum()


def _discrete_zv(wn: float, zeta: float, fs_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact sampled ZV: impulses at 0, n, n+1 whose z-transform vanishes on the mode's pole."""
    sigma, wd = _damped(wn, zeta)
    half = math.pi * fs_hz / wd  # half damped period, in samples
    n = math.floor(half)
    if n < 1:
        raise FitError(
            f"fs_hz={fs_hz:g}: the half damped period ({math.pi / wd:.3g} s) must span at least one sample; "
            f"expected fs_hz >= {wd / math.pi:.4g} Hz"
        )
    q = np.exp((sigma - 1j * wd) / fs_hz)  # p^-1
    q1, q2 = q**n, q ** (n + 1)
    m = np.array([[1.0, 1.0, 1.0], [1.0, q1.real, q2.real], [0.0, q1.imag, q2.imag]])
    a = np.linalg.solve(m, np.array([1.0, 0.0, 0.0]))
    # p^-n and p^-(n+1) lie either side of the negative real axis (n theta <= pi < (n+1) theta),
    # so a1, a2 >= 0; a2 is 0 (to rounding) when the half period is a whole number of samples.
    offsets = np.array([0, n, n + 1])
    keep = np.abs(a) > _TINY
    return offsets[keep], a[keep]


def zv_family(wn: float, zeta: float, n_impulses: int, *, name: str | None = None) -> Shaper:
    """ZV convolved with itself ``n_impulses - 1`` times (thesis Eq. 3.45-3.47, corrected).

    ``A_i = C(p-1, i-1) K^(i-1) / (1+K)^(p-1)``, ``K = exp(-pi zeta / sqrt(1 - zeta^2))``,
    ``t_i = (i - 1) Td / 2`` with ``Td = 2 pi / (wn sqrt(1 - zeta^2))`` (half a damped period,
    not the whole period of Eq. 3.46). Residual vibration 0 at ``(wn, zeta)``.

    Examples
    --------
    >>> s = zv_family(6.44e3, 0.115, 5)
    >>> [round(a, 4) for a in s.amplitudes]
    [0.1211, 0.3368, 0.3511, 0.1627, 0.0283]
    """
    wn, zeta = _check_mode(wn, zeta)
    if not (isinstance(n_impulses, (int, np.integer)) and n_impulses >= 2):
        raise FitError(f"n_impulses={n_impulses!r}: expected an int >= 2")
    p = int(n_impulses)
    sigma, wd = _damped(wn, zeta)
    k = math.exp(-math.pi * zeta / math.sqrt(1.0 - zeta * zeta))
    amps = tuple(math.comb(p - 1, i) * k**i / (1.0 + k) ** (p - 1) for i in range(p))
    times = tuple(i * math.pi / wd for i in range(p))
    default = {2: "zv", 3: "zvd", 4: "zvdd", 5: "zvddd"}.get(p, f"zv^{p - 1}")
    return Shaper(name or default, times, amps, wn, zeta, zv_power=p - 1)


def _ei_dimensionless(zeta: float, vtol: float) -> np.ndarray:
    """EI design in units of 1/wn: returns [A1, A2, A3, tau2, tau3] (tau = wn t)."""
    wdr = math.sqrt(1.0 - zeta * zeta)
    c = zeta + 1j * wdr  # exp(zeta wn t) exp(j wd t) = exp(r c tau) at frequency r wn

    def s(a, tau, r):
        return np.sum(a * np.exp(r * c * tau))

    def eqs(x):
        a1, a2, t2, t3, r_lo, r_hi = x
        a = np.array([a1, a2, 1.0 - a1 - a2])
        tau = np.array([0.0, t2, t3])
        s_lo, s_hi, s1 = s(a, tau, r_lo), s(a, tau, r_hi), s(a, tau, 1.0)
        ds1 = np.sum(a * c * tau * np.exp(c * tau))
        return [
            s_lo.real,
            s_lo.imag,  # V = 0 at r_lo wn
            s_hi.real,
            s_hi.imag,  # V = 0 at r_hi wn
            math.exp(-zeta * t3) * abs(s1) - vtol,  # V = Vtol at wn
            (ds1 * np.conj(s1)).real - zeta * t3 * abs(s1) ** 2,  # dV/dwn = 0 at wn (hump's top)
        ]

    # start: the undamped EI ((1+V)/4, (1-V)/2, (1+V)/4 at 0, T/2, T; zeros where
    # cos(pi r) = -(1-V)/(1+V)) with Klipper's damping correction of the amplitudes
    k = math.exp(-math.pi * zeta / wdr)
    a0 = np.array([0.25 * (1 + vtol), 0.5 * (1 - vtol) * k, 0.25 * (1 + vtol) * k * k])
    a0 /= a0.sum()
    r0 = math.acos(-(1 - vtol) / (1 + vtol)) / math.pi
    x0 = [a0[0], a0[1], math.pi / wdr, 2 * math.pi / wdr, r0, 2 - r0]
    sol = root(eqs, x0, method="hybr", options={"xtol": 1e-14})
    a1, a2, t2, t3, r_lo, r_hi = sol.x
    a = np.array([a1, a2, 1.0 - a1 - a2])
    if np.max(np.abs(eqs(sol.x))) > 1e-10 or np.any(a <= 0) or not (0 < t2 < t3) or not (r_lo < 1 < r_hi):
        raise FitError(
            f"EI shaper: no valid design for zeta={zeta:g}, vtol={vtol:g}; expected zeta in [0, 0.5], vtol in (0, 0.2]"
        )
    return np.array([a[0], a[1], a[2], t2, t3])


def ei_shaper(wn: float, zeta: float, vtol: float = EI_VTOL) -> Shaper:
    """Extra-insensitive (EI) shaper: three impulses, residual ``vtol`` at the design mode.

    Designed numerically (Singhose's EI conditions, exact for the damped mode rather than
    his curve fits): with ``zeta`` fixed and the frequency ``r wn`` varied, solve six
    equations in ``A1, A2`` (``A3 = 1 - A1 - A2``), ``t2, t3``, ``r_lo, r_hi``:
    ``V(r_lo) = V(r_hi) = 0`` (complex zeros, two equations each), ``V(1) = vtol`` and
    ``dV/dr(1) = 0``. The residual is thus a hump of height ``vtol`` centred on the design
    frequency between two exact zeros, so it stays below ``vtol`` over a band about twice
    as wide as ZVD's for the same delay (one damped period). Started from the undamped EI
    (``(1+V)/4, (1-V)/2, (1+V)/4`` at ``0, Td/2, Td``), solved by ``scipy.optimize.root``;
    the design depends on ``zeta`` and ``vtol`` only and scales with ``1 / wn``.
    Found for ``zeta`` up to 0.5 (``FitError`` otherwise).
    """
    wn, zeta = _check_mode(wn, zeta, zeta_max=0.5 + 1e-12)
    vtol = float(vtol)
    if not (0.0 < vtol <= 0.2):
        raise FitError(f"vtol={vtol!r}: expected a tolerable vibration in (0, 0.2]")
    a1, a2, a3, t2, t3 = _ei_dimensionless(zeta, vtol)
    amps = np.array([a1, a2, a3])
    amps /= amps.sum()
    return Shaper("ei", (0.0, t2 / wn, t3 / wn), tuple(amps), wn, zeta, zv_power=None)


@dataclass(frozen=True)
class ShaperSpec:
    """A registry entry: how to design a shaper and what to expect of it.

    Attributes
    ----------
    name : str
    impulses : int
        Number of (continuous) impulses.
    design : callable
        ``design(wn, zeta) -> Shaper``.
    delay_periods : float
        Delay in damped periods ``Td``.
    exact_discretization : bool
        Whether :meth:`Shaper.discretize` cancels the sampled mode exactly.
    zeta_range : tuple of float
        Damping ratios the design supports, ``[low, high)``.
    description, robustness : str
        What it is and how it tolerates modelling error (5 % insensitivity: the relative
        frequency band over which ``V <= 5 %``, undamped).
    """

    name: str
    impulses: int
    design: Callable[[float, float], Shaper] = field(repr=False)
    delay_periods: float
    exact_discretization: bool
    zeta_range: tuple[float, float]
    description: str
    robustness: str


#: The shapers, as data: name -> :class:`ShaperSpec`.
SHAPERS: dict[str, ShaperSpec] = {
    spec.name: spec
    for spec in (
        ShaperSpec(
            "zv",
            2,
            lambda wn, zeta: zv_family(wn, zeta, 2),
            0.5,
            True,
            (0.0, 1.0),
            "Zero vibration: two impulses half a damped period apart (thesis Eq. 3.45, p = 2).",
            "Zero residual at the design mode only; V <= 5 % within +/-3.2 % of wn.",
        ),
        ShaperSpec(
            "zvd",
            3,
            lambda wn, zeta: zv_family(wn, zeta, 3),
            1.0,
            True,
            (0.0, 1.0),
            "ZV convolved with itself: a double zero on the mode (zero vibration and derivative).",
            "Flat zero: V <= 5 % within +/-14 % of wn for one damped period of delay.",
        ),
        ShaperSpec(
            "zvdd",
            4,
            lambda wn, zeta: zv_family(wn, zeta, 4),
            1.5,
            True,
            (0.0, 1.0),
            "ZV^3: a triple zero on the mode.",
            "V <= 5 % within +/-24 % of wn; 1.5 damped periods of delay.",
        ),
        ShaperSpec(
            "zvddd",
            5,
            lambda wn, zeta: zv_family(wn, zeta, 5),
            2.0,
            True,
            (0.0, 1.0),
            "ZV^4: the thesis's 5-impulse shaper (Table 6.8 as it should have been).",
            "V <= 5 % within +/-31 % of wn; two damped periods of delay.",
        ),
        ShaperSpec(
            "ei",
            3,
            lambda wn, zeta: ei_shaper(wn, zeta),
            1.0,
            False,
            (0.0, 0.5),
            "Extra-insensitive: three impulses over one damped period, V = 5 % at the mode, "
            "0 at two frequencies either side.",
            "V <= 5 % within +/-20 % of wn for the delay of ZVD (never below 5 % near wn); split linearly when "
            "sampled.",
        ),
    )
}


def design_shaper(name: str, wn: float, zeta: float) -> Shaper:
    """Design the registered shaper ``name`` (a key of :data:`SHAPERS`) for ``(wn, zeta)``.

    Examples
    --------
    >>> design_shaper("zv", 6.44e3, 0.115).amplitudes[0] > 0.5
    True
    """
    if name not in SHAPERS:
        raise FitError(f"shaper {name!r}: unknown; expected one of {sorted(SHAPERS)}")
    spec = SHAPERS[name]
    _check_mode(wn, zeta, zeta_max=spec.zeta_range[1])
    return spec.design(wn, zeta)


# ---------------------------------------------------------------------------------------
# Choosing a shaper
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ShaperChoice:
    """The outcome of :func:`choose_shaper`.

    Attributes
    ----------
    shaper : Shaper
        The chosen shaper (apply it with :meth:`Shaper.apply` at the same ``fs_hz``).
    table : list of dict
        One row per candidate: ``name``, ``impulses`` (discretized), ``delay_ms``
        (discretized), ``nominal_residual_pct``, ``worst_residual_pct``.
    reason : str
        One line: why this one.
    """

    shaper: Shaper
    table: list[dict]
    reason: str


def choose_shaper(
    wn: float,
    zeta: float,
    fs_hz: float,
    *,
    freq_error: float = 0.15,
    damping_error: float = 0.5,
    candidates: Sequence[str] = ("zv", "zvd", "zvdd", "ei"),
    max_residual: float = EI_VTOL,
    delay_weight: float = 1.0,
    grid: tuple[int, int] = (61, 7),
) -> ShaperChoice:
    """Choose the shaper that tolerates the modelling error with the least delay.

    Each candidate is designed for ``(wn, zeta)``, discretized at ``fs_hz`` (what the press
    will actually receive) and its residual vibration evaluated on a grid of
    ``wn * (1 +/- freq_error)`` x ``zeta * (1 +/- damping_error)`` (``grid`` points each,
    edges included). Rule: among the candidates whose worst residual is at most
    ``max_residual``, the one with the smallest delay (ties: smaller worst residual); if
    none qualifies, the one with the smallest ``worst_residual_pct + delay_weight *
    delay_ms`` (``delay_weight`` in percentage points per ms; 1 by default: one ms of extra
    delay is worth one point of residual).

    Examples
    --------
    >>> choose_shaper(6.44e3, 0.115, 20e3, freq_error=0.0, damping_error=0.0).shaper.name
    'zv'
    """
    wn, zeta = _check_mode(wn, zeta)
    fs_hz = _check_fs(fs_hz)
    if not (0.0 <= freq_error < 1.0):
        raise FitError(f"freq_error={freq_error!r}: expected a fraction in [0, 1)")
    if not (0.0 <= damping_error and zeta * (1.0 + damping_error) < 1.0):
        raise FitError(
            f"damping_error={damping_error!r}: expected >= 0 with zeta * (1 + damping_error) < 1 (zeta={zeta:g})"
        )
    if not (0.0 < max_residual < 1.0):
        raise FitError(f"max_residual={max_residual!r}: expected a fraction in (0, 1)")
    if not (delay_weight >= 0.0):
        raise FitError(f"delay_weight={delay_weight!r}: expected >= 0 (percentage points per ms)")
    if not candidates:
        raise FitError("candidates: expected at least one shaper name")
    unknown = [c for c in candidates if c not in SHAPERS]
    if unknown:
        raise FitError(f"candidates: unknown shaper(s) {unknown}; expected names from {sorted(SHAPERS)}")
    wns = wn * np.linspace(1.0 - freq_error, 1.0 + freq_error, grid[0] if freq_error else 1)
    zetas = zeta * np.linspace(1.0 - damping_error, 1.0 + damping_error, grid[1] if damping_error else 1)

    rows, shapers = [], {}
    for name in candidates:
        shaper = design_shaper(name, wn, zeta)
        offsets, amps = shaper.discretize(fs_hz)
        t = offsets / fs_hz
        worst = max(residual_vibration(t, amps, w, z) for w in wns for z in zetas)
        shapers[name] = shaper
        rows.append(
            {
                "name": name,
                "impulses": int(offsets.size),
                "delay_ms": float(t[-1] * 1e3),
                "nominal_residual_pct": 100.0 * residual_vibration(t, amps, wn, zeta),
                "worst_residual_pct": 100.0 * worst,
            }
        )

    band = f"wn +/-{100 * freq_error:g} %, zeta +/-{100 * damping_error:g} %"
    ok = [r for r in rows if r["worst_residual_pct"] <= 100.0 * max_residual]
    if ok:
        best = min(ok, key=lambda r: (r["delay_ms"], r["worst_residual_pct"]))
        reason = (
            f"{best['name']}: shortest delay ({best['delay_ms']:.3f} ms) among shapers whose worst residual over "
            f"{band} is <= {100 * max_residual:g} % ({best['worst_residual_pct']:.2f} %)"
        )
    else:
        best = min(rows, key=lambda r: (r["worst_residual_pct"] + delay_weight * r["delay_ms"], r["delay_ms"]))
        reason = (
            f"{best['name']}: no shaper keeps the residual <= {100 * max_residual:g} % over {band}; smallest "
            f"worst residual + {delay_weight:g} %/ms x delay ({best['worst_residual_pct']:.2f} % at "
            f"{best['delay_ms']:.3f} ms)"
        )
    return ShaperChoice(shapers[best["name"]], rows, reason)


# ---------------------------------------------------------------------------------------
# The thesis's shaper (Table 6.8)
# ---------------------------------------------------------------------------------------

#: Table 6.8 exactly as printed: amplitudes in reverse order, delays unevenly spaced
#: (0.0982 ms reads like a misprint of 0.982 ms: the printed delays are about whole damped
#: periods, Eq. 3.46 as written). Designed for Eq. 6.2's mode.
THESIS_TABLE_6_8 = Shaper(
    "thesis-table-6.8",
    (0.0, 0.0982e-3, 2.0e-3, 2.9e-3, 3.9e-3),
    (0.0283, 0.1627, 0.3511, 0.3368, 0.1211),
    6.44e3,
    0.115,
)


def thesis_shaper_residual(wn: float = 6.44e3, zeta: float = 0.115) -> dict[str, float]:
    """Residual vibration (fraction) left on the mode ``(wn, zeta)`` by Table 6.8 and variants.

    Returns
    -------
    dict
        ``"printed"``: Table 6.8 as printed; ``"reversed_amplitudes"``: printed times with
        the amplitudes in the order ZV^4 gives them; ``"whole_period_spacing"``: printed
        amplitudes at whole damped periods (Eq. 3.46 as written, 0.0982 read as 0.982 ms);
        ``"correct_zv4"``: the 5-impulse ZV^4 at half periods (0 up to rounding).

    Examples
    --------
    >>> r = thesis_shaper_residual()
    >>> r["printed"] > 0.1 and r["correct_zv4"] < 1e-12
    True
    """
    wn, zeta = _check_mode(wn, zeta)
    t = THESIS_TABLE_6_8.times_s
    a = THESIS_TABLE_6_8.amplitudes
    td = 2.0 * math.pi / _damped(wn, zeta)[1]
    correct = zv_family(wn, zeta, 5)
    return {
        "printed": residual_vibration(t, a, wn, zeta),
        "reversed_amplitudes": residual_vibration(t, a[::-1], wn, zeta),
        "whole_period_spacing": residual_vibration([i * td for i in range(5)], a, wn, zeta),
        "correct_zv4": correct.residual(),
    }
