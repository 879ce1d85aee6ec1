"""Modified Prandtl-Ishlinskii (PI) hysteresis model, its analytic inverse, and its fit.

Model (thesis Section 3.1.1, Eq. 3.8)::

    u = x - x0                            input relative to the rest input
    p = P[u] = sum_i w_i H_{r_i}[u]       play (backlash) operators, 0 = r_0 < r_1 < ...
    z = S[p] = sum_j s_j S_{d_j}[p]       one-sided dead zones, d_0 = 0 (the identity)
    y = y0 + z                            output (force above the preload, or displacement)

P is invertible when ``w_0 > 0`` and ``w_i >= 0``; S when its slopes (partial sums of
``s`` outward from ``d_0``) are positive. The inverse is again a PI model (Eq. 3.9),
``u = P^-1[S^-1[z]]``, with parameters derived below. The thesis's Eq. 3.28-3.36 contain
two errors corrected here (and tested): the partial sums of Eq. 3.32/3.33 run from
``l = 0`` (not 1), and Eq. 3.35/3.36 define ``d_j`` by itself; the forward thresholds are
the images of the inverse ones, ``d_j = S^-1[d'_j]``.

Derivation. On the loading curve from rest a play superposition is piecewise linear with
slope ``W_i = sum_{l<=i} w_l`` between ``r_i`` and ``r_{i+1}``; every branch after a
reversal is the loading curve scaled by 2 (Masing), so inverting the loading curve inverts
the operator: the inverse has thresholds ``r'_i = P_load(r_i) = sum_{l<=i} w_l (r_i - r_l)``
and slopes ``1/W_i``, i.e. weights ``w'_0 = 1/w_0``, ``w'_i = 1/W_i - 1/W_{i-1}
= -w_i / (W_i W_{i-1})``. A dead-zone superposition is a static piecewise-linear map with
the same structure on each side of 0, so its inverse has thresholds ``d'_j = S(d_j)`` and
weights given by the same formula with the partial sums taken outward from ``d_0``.

Fit (Section 3.1.1, improved): the thesis's quadratic program (Eq. 3.11-3.23) finds play
weights ``w`` and *inverse* dead-zone weights ``v`` minimising ``|P[u] - S^-1[z]|^2``
(linear in both), under the invertibility constraints; solved with cvxpy. A second
quadratic program then refits the *forward* dead-zone weights on the output error
``|S[P[u]] - z|^2`` (linear in ``s`` for fixed ``P``). Operator numbers and thresholds are
chosen on held-out data from a grid, operators that contribute nothing are pruned.

A second family strictly contains the first: ``p = P[u] + K[u]``, the plays plus a Preisach
plane of Krasnosel'skii-Pokrovskii hysterons ``K[u] = sum_c mu_c k_c[u]`` on a grid of the
half-plane ``beta <= alpha`` over the fitted input range, ``mu_c >= 0`` (``mu = 0`` is the
modified PI model). The plane draws what play operators cannot: minor loops whose shape
changes with where they sit (a Preisach density off the plane's diagonal band), wiping out
without congruency once ``S`` is applied. Its weights enter the first quadratic program
beside the play weights (linear in both), with a penalty on the differences of neighbouring
cells (a smooth density, as the Everett functions of measured stacks are) and the same
slope bounds. Its inverse is exact: along a monotone stretch of the reference the drive is
monotone too, and ``P + K`` from the stretch's start state is a piecewise-linear increasing
function of the drive (kinks where a play or a hysteron starts or stops moving), inverted by
interpolation stretch by stretch. The family is chosen on the held-out rows: the plane must
predict them :data:`FAMILY_MARGIN` better than the best modified PI model.

A third family strictly contains the first too: ``p = P[u] + sum_j c_j E_{r_j}[u]``, the plays
plus Duhem (Bouc-Wen, exponent 1) elements of widths ``r_j`` (:class:`DuhemElements`,
:func:`piezopress.operators.duhem`) with signed weights, ``c = 0`` being the modified PI model.
An element's minor loops do not close (no wiping out), and its branch after a reversal is
exponential, not piecewise linear: the Bouc-Wen loop ``y = k x - h`` of many stacks. The
weights enter the first quadratic program as the plane's do, bounded so that the slope stays
within the plays' bounds; the inverse solves each monotone stretch of the reference at once
(every element has a closed form in the drive along it) by bracketed Newton steps. It wins by
the same margin; where the plane and the elements both do, the better one.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from piezopress import operators
from piezopress.errors import PiezopressError


class HysteresisFitError(PiezopressError, ValueError):
    """Data that cannot be fitted (too short, flat input, no reversal, solver failure)."""


# --------------------------------------------------------------------------- inversion formulas


def invert_play_weights(r: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Thresholds and weights of ``P^-1`` for ``P = sum w_i H_{r_i}`` (``r`` increasing from 0)."""
    r = np.asarray(r, float)
    w = np.asarray(w, float)
    W = np.cumsum(w)
    if w[0] <= 0 or np.any(W <= 0):
        raise HysteresisFitError(f"play weights {w} are not invertible: expected w_0 > 0 and positive partial sums")
    r_inv = np.array([np.sum(w[: i + 1] * (r[i] - r[: i + 1])) for i in range(r.size)])
    w_inv = np.empty_like(w)
    w_inv[0] = 1.0 / w[0]
    w_inv[1:] = -w[1:] / (W[1:] * W[:-1])
    return r_inv, w_inv


def invert_play_state(w: np.ndarray, y: np.ndarray) -> np.ndarray:
    """State of ``P^-1``'s operators matching the state ``y`` of ``P``'s operators.

    The inverse's operator ``i`` holds the loading curve's image of the forward states:
    ``y'_i = sum_{l<=i} w_l y_i + sum_{l>i} w_l y_l``.
    """
    w = np.asarray(w, float)
    y = np.asarray(y, float)
    W = np.cumsum(w)
    tail = np.concatenate([np.cumsum((w * y)[::-1])[::-1][1:], [0.0]])
    return W * y + tail


def forward_play_state(w: np.ndarray, y_inv: np.ndarray) -> np.ndarray:
    """Inverse of :func:`invert_play_state` (back-substitution from the last operator)."""
    w = np.asarray(w, float)
    W = np.cumsum(w)
    y = np.empty_like(np.asarray(y_inv, float))
    acc = 0.0
    for i in range(w.size - 1, -1, -1):
        y[i] = (y_inv[i] - acc) / W[i]
        acc += w[i] * y[i]
    return y


def _side_inverse(d: np.ndarray, s0: float, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    # d: thresholds of one side ordered outward from 0 (|d| increasing), s: their weights.
    slopes = s0 + np.cumsum(s)  # slope beyond each threshold
    prev = np.concatenate([[s0], slopes[:-1]])
    if np.any(slopes <= 0):
        raise HysteresisFitError(f"dead-zone weights {s} (with s_0 = {s0}) give a non-positive slope: not invertible")
    # image of each threshold: S(d_j) = s0 d_j + sum_{l<j} s_l (d_j - d_l)
    d_img = np.array([s0 * dj + np.sum(s[:j] * (dj - d[:j])) for j, dj in enumerate(d)])
    return d_img, -s / (slopes * prev)


def invert_dead_zone_weights(d: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Thresholds and weights of ``S^-1`` for ``S = sum s_j S_{d_j}`` (``d`` sorted, containing 0)."""
    d = np.asarray(d, float)
    s = np.asarray(s, float)
    i0 = int(np.flatnonzero(d == 0.0)[0])
    s0 = s[i0]
    if s0 <= 0:
        raise HysteresisFitError(f"dead-zone weight s_0 = {s0} must be positive")
    pos_d, pos_s = d[i0 + 1 :], s[i0 + 1 :]
    neg_d, neg_s = d[:i0][::-1], s[:i0][::-1]  # outward: -small to -large
    pd, ps = _side_inverse(pos_d, s0, pos_s) if pos_d.size else (pos_d, pos_s)
    nd, ns = _side_inverse(neg_d, s0, neg_s) if neg_d.size else (neg_d, neg_s)
    d_inv = np.concatenate([nd[::-1], [0.0], pd])
    s_inv = np.concatenate([ns[::-1], [1.0 / s0], ps])
    return d_inv, s_inv


def dead_zone_superposition(p: np.ndarray, d: np.ndarray, s: np.ndarray) -> np.ndarray:
    """``sum_j s_j S_{d_j}[p]`` (thesis Eq. 3.7).

    The sum is piecewise linear in ``p`` with its corners at the thresholds: evaluated as the
    line through its values there (and its end slopes beyond them) rather than as ``m``
    operators on every sample, which costs ``m`` times as much for the same result (within
    rounding; thresholds not in increasing order are summed operator by operator)."""
    p = np.asarray(p, dtype=np.float64)
    d = np.atleast_1d(np.asarray(d, dtype=np.float64))
    s = np.atleast_1d(np.asarray(s, dtype=np.float64))
    if d.size > 1 and not np.all(np.diff(d) > 0):
        return operators.dead_zone(p, d) @ s
    if p.size == 0:
        return np.zeros(p.shape)
    # the corners, and a point beyond the input on each side (every dead zone of that side open)
    lo, hi = min(float(p.min()), d[0]) - 1.0, max(float(p.max()), d[-1]) + 1.0
    if not (math.isfinite(lo) and math.isfinite(hi)):  # a gap (NaN) stays a gap
        return operators.dead_zone(p, d) @ s
    knots = np.concatenate([[lo], d, [hi]])
    at = operators.dead_zone(knots, d) @ s
    return np.interp(p, knots, at)


#: The rate (V/s) at which a rate law's gain is stated: ``g V per kV/s`` is the widening at 1 kV/s
#: whatever the law's exponent.
RATE_LAW_REF_V_PER_S = 1000.0


def rate_law(
    rho: np.ndarray, saturation_v_per_s: float | None = None, exponent: float = 1.0, floor_v_per_s: float = 0.0
) -> np.ndarray:
    """The rate a rate-dependent loop responds to, from the drive's rate envelope ``rho`` (V/s):
    ``rho`` itself (linear), ``sat tanh(rho / sat)`` (saturating at ``saturation_v_per_s``), or
    a power law ``ref (rho / ref)^exponent`` (``ref`` = :data:`RATE_LAW_REF_V_PER_S`): a viscous
    lag growing as the rate's square root is ``exponent`` 0.5. The power law and the saturation
    are one or the other; the output is in V/s, equal to ``rho`` at ``ref`` for every exponent.

    ``floor_v_per_s``: the rate the rate-independent loop was fitted at (its slow sweeps'). That
    loop holds the widening at that rate already, so the law is read above it, ``law(rho) -
    law(floor)``, and never below 0: at 60 V/s (0.1 Hz triangles of 150 V) a square root holds a
    quarter of its widening at 1 kV/s, which counted twice made the third test press's compensated
    0.1 Hz loop 1.0 -> 2.0 %. One definition for the compensator
    (:class:`piezopress.analysis.compensation.RateDependence`) and ``diagnose``'s forward model.

    >>> rate_law(np.array([0.0, 250.0, 1000.0, 4000.0]), exponent=0.5).tolist()
    [0.0, 500.0, 1000.0, 2000.0]
    >>> rate_law(np.array([0.0, 250.0, 1000.0, 4000.0]), exponent=0.5, floor_v_per_s=250.0).tolist()
    [0.0, 0.0, 500.0, 1500.0]
    """

    def law(r: np.ndarray) -> np.ndarray:
        if saturation_v_per_s and math.isfinite(saturation_v_per_s):
            return saturation_v_per_s * np.tanh(r / saturation_v_per_s)
        if exponent != 1.0:
            return RATE_LAW_REF_V_PER_S * (np.abs(r) / RATE_LAW_REF_V_PER_S) ** exponent
        return r

    read = law(np.asarray(rho, float))
    return np.maximum(read - law(np.asarray(float(floor_v_per_s))), 0.0) if floor_v_per_s > 0 else read


def rate_loss_output(
    model: PIModel, u: np.ndarray, plays: np.ndarray, extra: np.ndarray | None, loss: np.ndarray | float
) -> np.ndarray:
    """The model's output above ``y0`` under the loss form of rate dependence: ``plays`` (the
    weighted plays' sum for the input ``u``, relative to the model's rest input) lag behind
    ``u`` by ``plays - sum(w) u``, and ``loss`` (a share, sample by sample: 0 is the
    rate-independent model) scales that lag; the Duhem elements' term ``extra`` is all lag and
    is scaled as a whole, a plane's is not. One definition for the compensator
    (:class:`piezopress.analysis.compensation.RateDependence`) and ``diagnose``'s forward model."""
    lossy = not np.isscalar(loss) or loss != 0.0
    p = plays + loss * (plays - float(np.sum(model.w)) * u) if lossy else plays
    if extra is not None:
        p = p + (extra * (1.0 + loss) if lossy and model.duhem is not None else extra)
    return dead_zone_superposition(p, np.array(model.d), np.array(model.s))


# --------------------------------------------------------------------------- the model


@dataclass(frozen=True)
class PreisachPlane:
    """KP hysterons on a grid of the Preisach half-plane (``beta <= alpha``) and their weights.

    Levels ``N`` over the input range ``[lo, hi]`` give ``N (N + 1) / 2`` cells of ramp width
    ``h = (hi - lo) / N``: cell ``(i, j)``, ``j <= i``, rises along ``[lo + i h, lo + (i + 1) h]``
    and falls along ``[lo + j h, lo + (j + 1) h]``; the diagonal cells (``i = j``) are
    reversible ramps. Inputs are relative to the model's rest input.
    """

    alpha: tuple[float, ...]
    beta: tuple[float, ...]
    width: float
    weights: tuple[float, ...]
    levels: int = 0

    def __post_init__(self) -> None:
        if not (len(self.alpha) == len(self.beta) == len(self.weights)) or not self.alpha:
            raise HysteresisFitError("a Preisach plane needs one alpha, beta and weight per cell, at least one cell")
        if not (math.isfinite(self.width) and self.width > 0):
            raise HysteresisFitError(f"the plane's ramp width {self.width} must be finite and positive")
        if any(b > a for a, b in zip(self.alpha, self.beta)) or not all(
            math.isfinite(v) for v in (*self.alpha, *self.beta, *self.weights)
        ):
            raise HysteresisFitError("the plane's cells need finite alpha >= beta and finite weights")
        if any(m < 0 for m in self.weights):
            raise HysteresisFitError("the plane's weights must not be negative (the model must stay monotone)")

    @classmethod
    def grid(cls, lo: float, hi: float, levels: int) -> PreisachPlane:
        """The cells of ``levels`` levels over ``[lo, hi]``, weights 0."""
        if levels < 1 or not hi > lo:
            raise HysteresisFitError(f"a plane needs levels >= 1 and a range hi > lo, got {levels} over {lo}..{hi}")
        h = (hi - lo) / levels
        ij = [(i, j) for i in range(levels) for j in range(i + 1)]
        return cls(tuple(lo + i * h for i, _ in ij), tuple(lo + j * h for _, j in ij), h, (0.0,) * len(ij), levels)

    @property
    def n_cells(self) -> int:
        return len(self.alpha)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return np.array(self.alpha), np.array(self.beta), np.array(self.weights)

    def rest_state(self) -> np.ndarray:
        """The hysterons at the rest input as a stack that has been driven leaves them: the drive
        came down to rest from above, so every relay that switches down below the rest input
        (``beta < 0``) is up, every other down.

        Runs start at rest after earlier runs, never on a virgin stack: a plane whose rest had
        every relay down would switch the relays ``beta < 0 <= alpha`` up on every run's first
        rise, which the press never shows, and a fit would zero them; a compensator pulling
        the press below its rest would then find the plane's slope gone there. Up at rest, the
        data never switch them, and the smoothness penalty continues the density into them."""
        a, b, _ = self.arrays()
        return operators.kp_initial_state(0.0, a, b, self.width, 1.0)

    def rest_output(self) -> float:
        """The plane's output at rest (its columns are taken relative to it)."""
        return float(np.array(self.weights) @ self.rest_state())

    def states(self, u: np.ndarray, state: np.ndarray | None = None, widen: np.ndarray | None = None) -> np.ndarray:
        a, b, _ = self.arrays()
        return operators.kp(u, a, b, self.width, self.rest_state() if state is None else state, widen=widen)

    def columns(self, u: np.ndarray, state: np.ndarray | None = None, widen: np.ndarray | None = None) -> np.ndarray:
        """The hysterons' states for ``u`` relative to their rest states: 0 at rest, so the
        model's output at rest is its rest output ``y0``. ``widen``: every hysteron's
        thresholds pushed apart by it, sample by sample (rate-dependent hysteresis)."""
        out = self.states(u, state, widen)  # a new array: made relative in place
        out -= self.rest_state()
        return out

    def output(self, u: np.ndarray, state: np.ndarray | None = None, widen: np.ndarray | None = None) -> np.ndarray:
        """``columns(u, state, widen) @ weights``, block by block of samples
        (:func:`~piezopress.operators.kp_weighted`): the same to rounding, without the ``n x cells`` array."""
        a, b, w = self.arrays()
        rest = self.rest_state()
        return operators.kp_weighted(u, a, b, self.width, w, rest, rest if state is None else state, widen)

    def _membership(self) -> tuple[np.ndarray, np.ndarray]:
        """Rows: cells sharing a rising ramp (one alpha); and sharing a falling ramp (one beta)."""
        a, b, _ = self.arrays()
        ua, ub = np.unique(a), np.unique(b)
        return (a[None, :] == ua[:, None]).astype(float), (b[None, :] == ub[:, None]).astype(float)

    def max_slope(self) -> float:
        """The steepest the plane's output can rise or fall per unit input (one ramp's cells all moving)."""
        ra, rb = self._membership()
        mu = np.array(self.weights)
        return float(max((ra @ mu).max(), (rb @ mu).max()) / self.width)

    def smoothness(self) -> np.ndarray:
        """Differences of neighbouring cells' weights, as a matrix on the weights."""
        a, b, _ = self.arrays()
        i = np.rint((a - min(b)) / self.width).astype(int)
        j = np.rint((b - min(b)) / self.width).astype(int)
        index = {(int(x), int(y)): k for k, (x, y) in enumerate(zip(i, j))}
        rows = []
        for (x, y), k in index.items():
            for nb in ((x + 1, y), (x + 1, y + 1)):
                if nb in index:
                    row = np.zeros(len(index))
                    row[k], row[index[nb]] = 1.0, -1.0
                    rows.append(row)
        return np.array(rows) if rows else np.zeros((0, len(index)))

    def with_weights(self, mu: np.ndarray) -> PreisachPlane:
        return replace(self, weights=tuple(map(float, mu)))

    def to_dict(self) -> dict[str, Any]:
        return {
            "levels": self.levels,
            "ramp_width": self.width,
            "alpha": list(self.alpha),
            "beta": list(self.beta),
            "weights": list(self.weights),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PreisachPlane:
        return cls(
            tuple(map(float, d["alpha"])),
            tuple(map(float, d["beta"])),
            float(d["ramp_width"]),
            tuple(map(float, d["weights"])),
            int(d.get("levels", 0)),
        )


@dataclass(frozen=True)
class DuhemElements:
    """Duhem (Bouc-Wen, exponent 1) elements beside the plays: saturation widths, signed weights
    and the elements' states at rest (:func:`piezopress.operators.duhem`).

    An element's slope is in [0, 2], steepest just after a reversal; weighed negatively it is the
    Bouc-Wen form ``y = k x - h`` of a piezo stack (the loop's branch shallow after a reversal and
    steepening exponentially, its minor loops not closing). The plays' slope just after a
    reversal (``w_0``) bounds the negative weights (:meth:`least_slope`), so the model stays monotone.
    """

    widths: tuple[float, ...]
    weights: tuple[float, ...]
    rest: tuple[float, ...]

    def __post_init__(self) -> None:
        if not (len(self.widths) == len(self.weights) == len(self.rest)) or not self.widths:
            raise HysteresisFitError("Duhem elements need one width, weight and rest state each, at least one")
        if not all(math.isfinite(v) and v > 0 for v in self.widths):
            raise HysteresisFitError(f"Duhem element widths {self.widths} must be finite and positive")
        if not all(math.isfinite(v) for v in (*self.weights, *self.rest)):
            raise HysteresisFitError("Duhem element weights and rest states must be finite")
        if any(abs(e) > w * (1 + 1e-9) for e, w in zip(self.rest, self.widths)):
            raise HysteresisFitError("a Duhem element's rest state must lie within +- its width")

    @classmethod
    def grid(cls, span: float, count: int, rest: str = "relaxed") -> DuhemElements:
        """``count`` widths log-spaced over :data:`DUHEM_WIDTHS` of the input ``span``, weights 0,
        at rest as :data:`DUHEM_RESTS` names (``relaxed``: every element at 0, the stack's domains
        relaxed over the rest between runs; ``descended``: as a descent over the span from the top
        leaves them, nothing relaxed)."""
        if count < 1 or not (math.isfinite(span) and span > 0):
            raise HysteresisFitError(f"Duhem elements need count >= 1 and a positive span, got {count} over {span}")
        if rest not in DUHEM_RESTS:
            raise HysteresisFitError(f"Duhem rest state {rest!r}; expected one of {', '.join(DUHEM_RESTS)}")
        r = span * np.geomspace(DUHEM_WIDTHS[0], DUHEM_WIDTHS[1], count)
        at_rest = -r + 2 * r * np.exp(-span / r) if rest == "descended" else np.zeros(count)
        return cls(tuple(map(float, r)), (0.0,) * count, tuple(map(float, at_rest)))

    @property
    def n_cells(self) -> int:
        return len(self.widths)

    def rest_state(self) -> np.ndarray:
        return np.array(self.rest)

    def rest_output(self) -> float:
        return float(np.array(self.weights) @ self.rest_state())

    def columns(
        self, u: np.ndarray, state: np.ndarray | None = None, widen: np.ndarray | None = None, u_prev: float = 0.0
    ) -> np.ndarray:
        """The elements' states for ``u`` relative to their rest states (``u_prev``: the input the
        ``state`` was left at; ``widen`` does not act on them: a rate law widens the plays)."""
        st = self.rest_state() if state is None else np.asarray(state, float)
        return operators.duhem(np.asarray(u, float), np.array(self.widths), st, u_prev) - self.rest_state()

    def least_slope(self) -> float:
        """The most the elements can lower the model's slope (all just after a reversal)."""
        return 2.0 * float(np.sum(np.maximum(-np.array(self.weights), 0.0)))

    def most_slope(self) -> float:
        """The most the elements can raise it."""
        return 2.0 * float(np.sum(np.maximum(np.array(self.weights), 0.0)))

    def smoothness(self) -> np.ndarray:
        """Differences of neighbouring widths' weights."""
        n = self.n_cells
        return np.eye(n)[:-1] - np.eye(n, k=1)[:-1] if n > 1 else np.zeros((0, n))

    def with_weights(self, c: np.ndarray) -> DuhemElements:
        return replace(self, weights=tuple(map(float, c)))

    def to_dict(self) -> dict[str, Any]:
        return {"widths": list(self.widths), "weights": list(self.weights), "rest_states": list(self.rest)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> DuhemElements:
        return cls(tuple(map(float, d["widths"])), tuple(map(float, d["weights"])), tuple(map(float, d["rest_states"])))


#: The Duhem elements' widths, as shares of the input span (log-spaced between).
DUHEM_WIDTHS = (0.005, 0.5)
#: The elements' states at the start of a run that the search tries (each run starts at rest;
#: which state the rest leaves the stack in, relaxed or as the last descent left it, the
#: held-out rows decide: on the second test press relaxed predicted them 3-4x better).
DUHEM_RESTS = ("relaxed", "descended")


#: The model families, as the bundle names them.
FAMILY_PI = "modified_pi"
FAMILY_PLANE = "pi_preisach_plane"
FAMILY_DUHEM = "pi_duhem"
FAMILY_TITLES = {
    FAMILY_PI: "modified Prandtl-Ishlinskii (play operators and dead zones)",
    FAMILY_PLANE: "Prandtl-Ishlinskii plus a Preisach plane of KP hysterons",
    FAMILY_DUHEM: "Prandtl-Ishlinskii plus Duhem (Bouc-Wen, exponent 1) elements",
}


@dataclass(frozen=True)
class PIModel:
    """A fitted modified PI model; ``forward`` maps input to output, ``inverse`` back.

    Parameters are plain tuples so the model is immutable and JSON-friendly; ``state``
    arguments carry the play operators' states between chunks of a signal.
    """

    r: tuple[float, ...]
    w: tuple[float, ...]
    d: tuple[float, ...]
    s: tuple[float, ...]
    x0: float = 0.0
    y0: float = 0.0
    input_unit: str = "V"
    output_unit: str = "N"
    #: the Preisach plane beside the plays (None: the modified PI family)
    plane: PreisachPlane | None = None
    #: or the Duhem elements beside them
    duhem: DuhemElements | None = None

    def __post_init__(self) -> None:
        if len(self.r) != len(self.w) or len(self.d) != len(self.s):
            raise HysteresisFitError("thresholds and weights must have the same lengths")
        if self.r[0] != 0.0 or any(b <= a for a, b in zip(self.r, self.r[1:])):
            raise HysteresisFitError(f"play thresholds {self.r} must start at 0 and increase")
        if 0.0 not in self.d or any(b <= a for a, b in zip(self.d, self.d[1:])):
            raise HysteresisFitError(f"dead-zone thresholds {self.d} must increase and contain 0")
        if self.plane is not None and self.duhem is not None:
            raise HysteresisFitError("a model holds a Preisach plane or Duhem elements beside its plays, not both")

    @property
    def n_play(self) -> int:
        return len(self.r)

    @property
    def n_dead_zone(self) -> int:
        return len(self.d)

    @property
    def family(self) -> str:
        return FAMILY_PLANE if self.plane is not None else FAMILY_DUHEM if self.duhem is not None else FAMILY_PI

    @property
    def extra(self) -> PreisachPlane | DuhemElements | None:
        """The operators beside the plays (a plane's hysterons or Duhem elements; None: none)."""
        return self.plane if self.plane is not None else self.duhem

    def rest_state(self) -> np.ndarray:
        """The state at rest: the plays' (0), then the plane's hysterons' or the Duhem elements'."""
        if self.extra is None:
            return np.zeros(self.n_play)
        return np.concatenate([np.zeros(self.n_play), self.extra.rest_state()])

    def play(self, u: np.ndarray, state: np.ndarray | None = None) -> np.ndarray:
        """The play operators' outputs (``n`` x ``n_play``) for relative input ``u``."""
        st = self.rest_state() if state is None else np.asarray(state, float)
        return operators.play(u, np.array(self.r), st[: self.n_play])

    def columns(self, u: np.ndarray, state: np.ndarray | None = None, widen: np.ndarray | None = None) -> np.ndarray:
        """The operators' outputs side by side: plays, then the plane's hysterons (the
        thresholds of both widened by ``widen``) or the Duhem elements (relative to their rest
        states, as the plane's); :meth:`column_weights` weighs them into the superposition."""
        st = self.rest_state() if state is None else np.asarray(state, float)
        Y = operators.play(u, np.array(self.r), st[: self.n_play], widen=widen)
        if self.plane is not None:
            return np.hstack([Y, self.plane.columns(u, st[self.n_play :], widen)])
        if self.duhem is not None:  # the threshold-0 play's state is the last input the elements saw
            # widened thresholds are the plays behind a play of the widening (H_{r+d} = H_r o H_d):
            # the elements see that play's output too
            seen = u if widen is None else Y[:, 0]
            return np.hstack([Y, self.duhem.columns(seen, st[self.n_play :], u_prev=float(st[0]))])
        return Y

    def outputs(
        self, u: np.ndarray, state: np.ndarray | None = None, widen: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """``(plays, extra)``: the plays' weighted sum and the plane's or the Duhem elements' (None
        without), as :meth:`columns` weighed by :meth:`column_weights` in two parts; a plane's
        hysterons block by block of samples (:meth:`PreisachPlane.output`), never all at once."""
        if self.plane is None:
            Y = self.columns(u, state, widen)
            extra = Y[:, self.n_play :] @ np.array(self.duhem.weights) if self.duhem is not None else None
            return Y[:, : self.n_play] @ np.array(self.w), extra
        st = self.rest_state() if state is None else np.asarray(state, float)
        plays = operators.play(u, np.array(self.r), st[: self.n_play], widen=widen) @ np.array(self.w)
        return plays, self.plane.output(u, st[self.n_play :], widen)

    def column_weights(self) -> np.ndarray:
        w = np.array(self.w)
        return w if self.extra is None else np.concatenate([w, np.array(self.extra.weights)])

    def forward(self, x: np.ndarray, state: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Model output ``y`` for input ``x``, and the operators' state after the last sample."""
        x = np.asarray(x, float)
        Y = self.columns(x - self.x0, state)
        p = Y @ self.column_weights()
        last = Y[-1].copy()
        if self.extra is not None:  # the extra columns are relative to their rest: the state is not
            last[self.n_play :] += self.extra.rest_state()
        return self.y0 + dead_zone_superposition(p, np.array(self.d), np.array(self.s)), last

    def inverse(self, y_ref: np.ndarray, state: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Input ``x`` that makes the model output ``y_ref``: analytic (Eq. 3.9) for the modified
        PI family, exact piecewise-linear inversion stretch by stretch with a Preisach plane, and
        stretch by stretch to :data:`DUHEM_INVERSE_TOL` (relative) with Duhem elements.

        ``state`` is the *forward* model's state (as returned by :meth:`forward`);
        the state returned is the forward state after the last sample, so forward and
        inverse can be chained in chunks.
        """
        y_ref = np.asarray(y_ref, float)
        if self.extra is not None:
            d_inv, s_inv = invert_dead_zone_weights(np.array(self.d), np.array(self.s))
            p = dead_zone_superposition(y_ref - self.y0, d_inv, s_inv)
            st = self.rest_state() if state is None else np.asarray(state, float)
            invert = _invert_with_plane if self.plane is not None else _invert_with_duhem
            u, last = invert(self, p + self.extra.rest_output(), st)
            return self.x0 + u, last
        w = np.array(self.w)
        r_inv, w_inv = invert_play_weights(np.array(self.r), w)
        d_inv, s_inv = invert_dead_zone_weights(np.array(self.d), np.array(self.s))
        p = dead_zone_superposition(y_ref - self.y0, d_inv, s_inv)
        st = self.rest_state() if state is None else np.asarray(state, float)
        Yi = operators.play(p, r_inv, invert_play_state(w, st))
        return self.x0 + Yi @ w_inv, forward_play_state(w, Yi[-1])

    def inverse_parameters(self) -> dict[str, list[float]]:
        """The inverse model's thresholds and weights (thesis Table 6.2 / 6.4)."""
        r_inv, w_inv = invert_play_weights(np.array(self.r), np.array(self.w))
        d_inv, s_inv = invert_dead_zone_weights(np.array(self.d), np.array(self.s))
        return {"r_inv": r_inv.tolist(), "w_inv": w_inv.tolist(), "d_inv": d_inv.tolist(), "s_inv": s_inv.tolist()}

    def to_dict(self) -> dict[str, Any]:
        if self.extra is not None:
            # no closed-form inverse to print: the compensator inverts numerically
            key = "preisach_plane" if self.plane is not None else "duhem_elements"
            return {
                "family": self.family,
                **{k: v for k, v in self._pi_dict().items() if k != "inverse"},
                key: self.extra.to_dict(),
            }
        return {"family": self.family, **self._pi_dict()}

    def _pi_dict(self) -> dict[str, Any]:
        return {
            "input_unit": self.input_unit,
            "output_unit": self.output_unit,
            f"x0_{self.input_unit.lower()}": self.x0,
            f"y0_{self.output_unit.lower()}": self.y0,
            "play_thresholds": list(self.r),
            "play_weights": list(self.w),
            "dead_zone_thresholds": list(self.d),
            "dead_zone_weights": list(self.s),
            "inverse": self.inverse_parameters(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PIModel:
        iu, ou = d["input_unit"], d["output_unit"]
        return cls(
            r=tuple(d["play_thresholds"]),
            w=tuple(d["play_weights"]),
            d=tuple(d["dead_zone_thresholds"]),
            s=tuple(d["dead_zone_weights"]),
            x0=float(d[f"x0_{iu.lower()}"]),
            y0=float(d[f"y0_{ou.lower()}"]),
            input_unit=iu,
            output_unit=ou,
            plane=PreisachPlane.from_dict(d["preisach_plane"]) if d.get("preisach_plane") else None,
            duhem=DuhemElements.from_dict(d["duhem_elements"]) if d.get("duhem_elements") else None,
        )


def _invert_with_plane(model: PIModel, p: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The relative input ``u`` whose plays-plus-plane output is ``p``, from the forward ``state``.

    Along a monotone stretch of ``p`` the input moves one way; from the stretch's start state
    the superposition is ``g(u) = sum w_i max(y_i, u - r_i) + sum mu_c max(s_c, a_c(u))`` rising,
    piecewise linear and strictly monotone (the threshold-0 play has weight ``w_0 > 0``); it is
    evaluated at its kinks and inverted by interpolation, exact to rounding (:func:`_rising`).
    A falling stretch is a rising one mirrored: ``u -> -u``, ``y -> -y``, ``s -> 1 - s``, the
    falling ramps' ends ``beta -> -(beta + h)``, ``p -> sum mu - p``. The threshold-0 play holds
    the last input.
    """
    r, w = np.array(model.r), np.array(model.w)
    al, be, mu = model.plane.arrays()
    h = model.plane.width
    n_play = r.size
    y, s = state[:n_play].copy(), state[n_play:].copy()
    st = [y, s]

    def stretch(target: np.ndarray, rising: bool) -> np.ndarray:
        y, s = st
        if rising:
            seg, st[0], st[1] = _rising(target, y, s, r, w, al, h, mu)
            return seg
        seg, ym, sm = _rising(mu.sum() - target, -y, 1.0 - s, r, w, -(be + h), h, mu)
        st[0], st[1] = -ym, 1.0 - sm
        return -seg

    u = _by_stretches(np.asarray(p, float), float(w @ y + mu @ s), float(y[0]), stretch)
    return u, np.concatenate(st)


def _by_stretches(p: np.ndarray, p_now: float, u_now: float, stretch: Callable) -> np.ndarray:
    """The inputs for the reference ``p`` (the output now ``p_now`` at the input ``u_now``),
    monotone stretch by monotone stretch: ``stretch(target, rising)`` inverts one from the state
    the last one left (which it keeps)."""
    pp = np.concatenate([[p_now], p])
    out = np.empty(pp.size)
    out[0] = u_now
    bounds = np.append(operators.monotone_runs(pp), pp.size)
    for a, b in zip(bounds[:-1], bounds[1:]):
        a1 = a if a > 0 else 1
        if a1 < b:
            out[a1:b] = stretch(pp[a1:b], bool(pp[b - 1] >= pp[a1 - 1]))
    return out[1:]


def _rising(target, y, s, r, w, al, h, mu) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A rising stretch of the plays-plus-plane output to ``target`` from the state ``(y, s)``
    (the threshold-0 play ``y[0]`` is the last input): the inputs, and the state at its end."""
    u0 = float(y[0])
    kinks = np.concatenate([y + r, al + h * s, al + h])
    U = np.concatenate([[u0], np.unique(kinks[kinks > u0])])
    G = np.maximum(y, U[:, None] - r) @ w + np.maximum(s, np.clip((U[:, None] - al) / h, 0.0, 1.0)) @ mu
    reach = float(target.max()) - G[-1]
    if reach > 0:  # beyond the last kink every play moves and every hysteron is up: slope sum(w)
        U = np.append(U, U[-1] + reach / w.sum() + 1.0)
        G = np.append(G, G[-1] + (U[-1] - U[-2]) * w.sum())
    seg = np.interp(target, G, U)
    u_end = float(seg[-1])
    return seg, np.maximum(y, u_end - r), np.maximum(s, np.clip((u_end - al) / h, 0.0, 1.0))


# --------------------------------------------------------------------------- data and fit


#: The Duhem family's inverse stops when the model output is this close to the reference
#: (relative to the reference's size, at least 1) ...
DUHEM_INVERSE_TOL = 1e-10
#: ... or after this many safeguarded Newton steps.
DUHEM_INVERSE_STEPS = 60
#: Points of the first look along a stretch (the guess Newton's steps start from).
_DUHEM_GRID = 64


def _invert_with_duhem(model: PIModel, p: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The relative input ``u`` whose plays-plus-Duhem output is ``p``, from the forward ``state``.

    Along a monotone stretch of ``p`` the input moves one way; from the stretch's start state
    every element follows its closed form in ``u`` (:func:`piezopress.operators.duhem_along`), so
    the superposition ``g(u)`` is a function of ``u`` alone, rising with slope at least
    ``w_0 - 2 sum(max(-c, 0)) > 0``; each sample's ``u`` is found at once, vectorised over the
    stretch, by Newton steps kept inside a bracket (:func:`_rising_duhem`). A falling stretch is a
    rising one mirrored (``u -> -u``, states and output negated: both operators are odd).
    """
    r, w = np.array(model.r), np.array(model.w)
    R, c = np.array(model.duhem.widths), np.array(model.duhem.weights)
    n_play = r.size
    y, e = state[:n_play].copy(), state[n_play:].copy()
    least = float(w[0]) - model.duhem.least_slope()
    if not least > 0:
        raise HysteresisFitError(
            f"the model's least slope {least:g} (the threshold-0 play's weight less twice the Duhem elements' "
            "negative weights) must be positive for an inverse; expected a model fitted by fit_structure"
        )
    st = [y, e]

    def stretch(target: np.ndarray, rising: bool) -> np.ndarray:
        sign = 1.0 if rising else -1.0  # both operators are odd: a falling stretch is a rising one mirrored
        seg, ym, em = _rising_duhem(sign * target, sign * st[0], sign * st[1], r, w, R, c, least)
        st[0], st[1] = sign * ym, sign * em
        return sign * seg

    u = _by_stretches(np.asarray(p, float), float(w @ y + c @ e), float(y[0]), stretch)
    return u, np.concatenate(st)


def _rising_duhem(target, y, e, r, w, R, c, least) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A rising stretch of the plays-plus-Duhem output to ``target`` from the state ``(y, e)``
    (``y[0]``: the last input), its slope at least ``least``: the inputs, and the state at its end."""
    u0 = float(y[0])
    sat = e - R  # each element's distance below its saturation at u0

    def g_and_slope(U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        shift = U[:, None] - r
        decay = np.exp(-(U[:, None] - u0) / R) * sat
        return np.maximum(y, shift) @ w + (R + decay) @ c, (shift > y) @ w - (decay / R) @ c

    g0 = float(w @ y + c @ e)
    reach = max(float(target.max()) - g0, 0.0)
    top = u0 + reach / least * (1 + 1e-9) + 1e-12
    if target.size > _DUHEM_GRID:  # a long stretch: a first look along it, then Newton from there
        kinks = y + r
        U = np.unique(np.concatenate([np.linspace(u0, top, _DUHEM_GRID), kinks[(kinks > u0) & (kinks < top)]]))
        G = np.maximum.accumulate(g_and_slope(U)[0])
        k = np.clip(np.searchsorted(G, target), 1, U.size - 1)
        lo, hi = U[k - 1], U[k]
        x = np.clip(np.interp(target, G, U), lo, hi)
    else:
        lo, hi = np.full(target.size, u0), np.full(target.size, top)
        start = float(g_and_slope(np.array([u0]))[1][0])  # the slope just after u0
        x = np.minimum(u0 + (target - g0) / max(start, least), top)
    scale = max(1.0, float(np.max(np.abs(target))))
    for _ in range(DUHEM_INVERSE_STEPS):
        gx, dg = g_and_slope(x)
        f = gx - target
        if np.max(np.abs(f)) <= DUHEM_INVERSE_TOL * scale:
            break
        lo = np.where(f < 0, x, lo)
        hi = np.where(f > 0, x, hi)
        step = x - f / np.maximum(dg, least)
        x = np.where((step > lo) & (step < hi), step, 0.5 * (lo + hi))
    x = np.maximum(x, u0)
    u_end = float(x[-1])
    return x, np.maximum(y, u_end - r), R + sat * np.exp(-(u_end - u0) / R)


@dataclass(frozen=True)
class HysteresisData:
    """Runs prepared for fitting: relative input/output and which samples train or test.

    Play operators are evaluated over each whole run (their state carries on), then rows
    are picked by ``train`` and ``holdout`` masks, so holding out the end of a run tests
    the model on data it did not fit, from the state the run left it in.
    """

    names: tuple[str, ...]
    u: tuple[np.ndarray, ...]
    z: tuple[np.ndarray, ...]
    train: tuple[np.ndarray, ...]
    holdout: tuple[np.ndarray, ...]
    x0: float
    y0: float

    @property
    def u_span(self) -> float:
        return float(max(np.max(u) for u in self.u) - min(np.min(u) for u in self.u))

    @property
    def u_absmax(self) -> float:
        return float(max(np.max(np.abs(u)) for u in self.u))

    @property
    def z_range(self) -> tuple[float, float]:
        return float(min(np.min(z) for z in self.z)), float(max(np.max(z) for z in self.z))


def rest_offset(x: np.ndarray, y: np.ndarray, fraction: float = 0.03) -> tuple[float, float]:
    """Rest input ``x0 = x[0]`` and the output at rest ``y0``, robust to noise.

    ``y0`` is the intercept at ``x0`` of a straight line through the output over the first
    stretch where the input stays within ``fraction`` of its span of ``x0`` (at least 3
    samples; a noisy sample at rest would bias the offset by the noise).
    """
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    x0 = float(x[0])
    span = float(np.ptp(x)) or 1.0
    near = np.abs(x - x0) <= fraction * span
    n = int(np.argmin(near)) if not near.all() else x.size
    n = max(n, 3)
    dx = x[:n] - x0
    if np.ptp(dx) > 0:
        k, c = np.polyfit(dx, y[:n], 1)
        return x0, float(c)
    return x0, float(np.mean(y[:n]))


def settled_start(x: np.ndarray, rel_tol: float = 0.02) -> int:
    """First sample from which the model's state no longer depends much on the unknown state
    before the record.

    A record that starts at its lowest input (within ``rel_tol`` of its span) starts in the
    model's rest state (the relaxed actuator at its lowest drive): every sample counts (0).
    Any other start (mid-range, after a rest at some level, in a sensor's start-up
    transient) leaves the play operators' states unknown until the input has moved over
    their width (the wiping-out property: a play of threshold ``r`` forgets its past once the
    input has covered a range of ``2 r``; every threshold is below half the span). The
    settled start is the first sample by which the input has reached both its lowest and
    its highest value (within ``rel_tol`` of the span: every play settled), or, when that
    leaves less than a quarter of the record (a growing amplitude), by which it has covered
    half its span (the plays that carry most weight settled). Samples before are evaluated
    (they carry the state) but not fitted.
    """
    x = np.asarray(x, float)
    lo, hi = float(np.min(x)), float(np.max(x))
    tol = rel_tol * (hi - lo)
    if x[0] <= lo + tol:
        return 0
    first = max(int(np.argmax(x <= lo + tol)), int(np.argmax(x >= hi - tol)))
    if first > 3 * x.size // 4:
        covered = np.maximum.accumulate(x) - np.minimum.accumulate(x)
        first = int(np.argmax(covered >= 0.5 * (hi - lo)))
    return first


def prepare(
    runs: Sequence[tuple[str, np.ndarray, np.ndarray]],
    *,
    holdout_fraction: float = 0.3,
    burn_in_fraction: float = 0.0,
    x0: float | None = None,
    y0: float | None = None,
    skip: Sequence[int] | int | None = None,
) -> HysteresisData:
    """Prepare ``(name, input, output)`` runs: the last ``holdout_fraction`` of each run's
    fitted samples is held out (the end of the record, never a random subset).

    ``x0``/``y0`` default to the rest input and output estimated from the first run
    (:func:`rest_offset`); every run is taken relative to them. The rest output is only a
    starting value: the fit estimates the output offset with the weights. A first run that
    does not start at its lowest input (see :func:`settled_start`) has its rest state
    taken as the relaxed actuator at the lowest input of the runs.

    ``skip`` gives, per run (or one for all), the samples at the start that are not fitted
    (a rest, a start-up transient); by default :func:`settled_start` decides. Skipped
    samples are still evaluated, so the operators' states carry on into the fitted ones.
    """
    if not runs:
        raise HysteresisFitError("no runs to fit; expected at least one run with a swept input")
    if not 0 <= holdout_fraction < 1:
        raise HysteresisFitError(f"holdout_fraction = {holdout_fraction}; expected 0 <= fraction < 1")
    if skip is not None and not isinstance(skip, (int, np.integer)) and len(skip) != len(runs):
        raise HysteresisFitError(f"skip holds {len(skip)} values for {len(runs)} runs; expected one per run")
    ex0, ey0 = rest_offset(runs[0][1], runs[0][2])
    first0 = settled_start(np.asarray(runs[0][1], float)) if skip is None else int(np.atleast_1d(skip)[0])
    if first0 > 0 and first0 < len(runs[0][2]):
        # not from rest: the rest state is the relaxed actuator at the lowest drive (the
        # start is then a jump from it), and the rest output is fitted from a starting value
        ex0 = float(min(np.min(r[1]) for r in runs))
        ey0 = float(np.min(np.asarray(runs[0][2], float)[first0:]))
    x0 = ex0 if x0 is None else x0
    y0 = ey0 if y0 is None else y0
    names, us, zs, tr, ho = [], [], [], [], []
    for i, (name, x, y) in enumerate(runs):
        x = np.asarray(x, float)
        y = np.asarray(y, float)
        if x.shape != y.shape or x.ndim != 1:
            raise HysteresisFitError(
                f"{name}: input and output have shapes {x.shape} and {y.shape}; expected equal 1-D arrays"
            )
        if x.size < 20:
            raise HysteresisFitError(f"{name}: {x.size} samples; expected at least 20")
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
            raise HysteresisFitError(
                f"{name}: the input or output holds NaN or infinite values; expected finite samples"
            )
        if np.ptp(x) <= 0:
            raise HysteresisFitError(f"{name}: the input does not move; expected a sweep")
        n = x.size
        if skip is None:
            first = settled_start(x)
        else:
            first = int(skip if isinstance(skip, (int, np.integer)) else skip[i])
            if not 0 <= first < n:
                raise HysteresisFitError(f"{name}: skip of {first} samples; expected 0 to {n - 1} (the run has {n})")
        first = max(first, int(round(n * burn_in_fraction)))
        cut = first + int(round((n - first) * (1 - holdout_fraction)))
        t = np.zeros(n, bool)
        t[first:cut] = True
        h = np.zeros(n, bool)
        h[cut:] = True
        names.append(name)
        us.append(x - x0)
        zs.append(y - y0)
        tr.append(t)
        ho.append(h)
    if sum(int(t.sum()) for t in tr) < 10:
        raise HysteresisFitError(
            "fewer than 10 samples left to fit after the skipped start; expected a longer record or a shorter skip"
        )
    return HysteresisData(tuple(names), tuple(us), tuple(zs), tuple(tr), tuple(ho), float(x0), float(y0))


def play_thresholds(n: int, gamma: float, span: float) -> np.ndarray:
    """``n`` play thresholds from 0 to below ``span / 2`` (a play of threshold ``r`` moves only
    when the input sweeps more than ``2 r``), spaced as ``(i/n)^gamma`` so that ``gamma > 1``
    packs them near 0, where the thesis notes the largest changes."""
    i = np.arange(n)
    return 0.5 * span * (i / n) ** gamma


def dead_zone_thresholds(m: int, z_lo: float, z_hi: float) -> np.ndarray:
    """Thresholds of the inverse dead zones on the output: ``m`` evenly inside each side that
    the output reaches, plus 0."""
    pos = z_hi * np.arange(1, m + 1) / (m + 1) if z_hi > 0 and m else np.zeros(0)
    neg = z_lo * np.arange(m, 0, -1) / (m + 1) if z_lo < 0 and m else np.zeros(0)
    return np.concatenate([neg, [0.0], pos])


def _gram(rows: Sequence[Sequence[np.ndarray]]) -> np.ndarray:
    """``M^T M`` for ``M = [[X_11 X_12 ...], [X_21 X_22 ...], ...]`` (row blocks of column
    blocks), computed block by block: ``M`` itself, large for long records, is never built."""
    sizes = [x.shape[1] for x in rows[0]]
    edges = np.concatenate([[0], np.cumsum(sizes)])
    G = np.zeros((edges[-1], edges[-1]))
    for blocks in rows:
        for i, a in enumerate(blocks):
            for j in range(i, len(blocks)):
                g = a.T @ blocks[j]
                G[edges[i] : edges[i + 1], edges[j] : edges[j + 1]] += g
                if j != i:
                    G[edges[j] : edges[j + 1], edges[i] : edges[i + 1]] += g.T
    return G


def _solve(problem, what: str) -> None:
    import warnings

    import cvxpy as cp

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # "may be inaccurate": the status is checked below
            problem.solve(solver=cp.CLARABEL)
    except cp.error.SolverError as exc:
        raise HysteresisFitError(f"{what}: the quadratic program failed ({exc})") from None
    if problem.status not in ("optimal", "optimal_inaccurate"):
        raise HysteresisFitError(
            f"{what}: the quadratic program ended {problem.status}; the data may not suit the model"
        )


def _factor(G: np.ndarray) -> np.ndarray:
    """``L^T`` with ``G ~= L L^T`` (a tiny ridge keeps a rank-deficient Gram matrix factorable)."""
    scale = np.trace(G) / G.shape[0] if G.size else 1.0
    return np.linalg.cholesky(G + 1e-10 * scale * np.eye(G.shape[0])).T


@dataclass(frozen=True)
class Candidate:
    n_play: int
    gamma: float
    m_dead_zone: int
    #: levels of a Preisach plane beside the plays (0: none, the modified PI family)
    plane_levels: int = 0
    #: Duhem elements beside the plays (0: none), and their state at rest (:data:`DUHEM_RESTS`)
    duhem_elements: int = 0
    duhem_rest: str = DUHEM_RESTS[0]

    @property
    def label(self) -> str:
        plane = f" plane={self.plane_levels}" if self.plane_levels else ""
        duhem = f" duhem={self.duhem_elements}" if self.duhem_elements else ""
        duhem += f" rest={self.duhem_rest}" if self.duhem_elements and self.duhem_rest != DUHEM_RESTS[0] else ""
        return f"n={self.n_play} gamma={self.gamma:g} m={self.m_dead_zone}{plane}{duhem}"

    @property
    def family(self) -> str:
        return FAMILY_PLANE if self.plane_levels else FAMILY_DUHEM if self.duhem_elements else FAMILY_PI


def plane_for(data: HysteresisData, levels: int) -> PreisachPlane | None:
    """The plane grid of ``levels`` levels over the data's input range, continued below it by
    :data:`PLANE_BELOW` of the levels (None for 0 levels).

    A compensator that pulls the press below its rest (a stack whose remanence rests it above
    the preload) drives below the fitted drives; there plays alone would go on at their last
    slope and a plane ending at the data would go flat. The cells below, which the data never
    switch, take their neighbours' weights through the smoothness penalty: the density goes on.
    Measured on the third test press (a Preisach stack resting 23 N above the preload): the
    75 N loop compensated to 2.2 % with the plane ending at the data, 1.6 % continued by a
    quarter; the 10 N staircase 8.1 % and 5.7 %."""
    if not levels:
        return None
    lo = float(min(np.min(u) for u in data.u))
    hi = float(max(np.max(u) for u in data.u))
    h = (hi - lo) / levels
    extra = math.ceil(PLANE_BELOW * levels)
    return replace(PreisachPlane.grid(lo - extra * h, hi, levels + extra), levels=levels)


#: How far the plane's grid continues below the fitted input range, as a share of its levels.
PLANE_BELOW = 0.25


#: Smoothness penalty on neighbouring plane cells, relative to the plane columns' mean energy.
#: At 1e-3 the third test press's plane, fitted again with the hold's creep removed, drew a
#: wiggle of 1 N over 6 V of the loop (cells of 7.5 V each fitted to the sweeps' noise) that
#: the compensator played into a 75 N triangle: 1.44 % on seed 2. At 3e-3, 3 seeds
#: (``bench/bench_presses.py``): the fit's held-out error 2.77 -> 2.56 times the noise floor,
#: the compensated 0.1 Hz loop 0.98 (0.72-1.44) -> 0.60 (0.59-0.62) %; 1e-2 smooths the
#: density's own peaks (seed 2: 0.99 %).
PLANE_SMOOTHING = 3e-3
#: The same penalty on neighbouring Duhem elements' weights (the second test press, Bouc-Wen
#: elements, is fitted best at this value: at 3e-3 its compensated 0.1 Hz loop read 0.65 -> 0.73 %).
DUHEM_SMOOTHING = 1e-3


#: Bounds that keep the static map well conditioned, so its inverse never plateaus (a
#: forward slope far above the mean: the drive almost stops while the reference moves) or
#: jumps (a slope near zero). The play superposition is normalised to a mean loading slope
#: of about 1 (``P(u_max) = u_max`` on the loading curve); its slope just after a reversal
#: (``w_0``) is at least :data:`PLAY_SLOPE_MIN` of that and its steepest (``sum w``) at most
#: :data:`PLAY_SLOPE_MAX`. A piezo stack's branch starts at roughly half its mean slope and
#: never flat, and its steepest part is within about twice the mean (thesis Fig. 5.2, and
#: the 5-15 % hysteresis of the stacks it cites), so these bounds leave real loops free and
#: exclude only the near-vertical or flat pieces that over-fitting makes. The dead-zone
#: slopes (the static gain) stay within a factor :data:`DEAD_ZONE_SLOPE_RATIO` of the mean
#: gain (output span over input span).
PLAY_SLOPE_MIN = 0.1
PLAY_SLOPE_MAX = 4.0
DEAD_ZONE_SLOPE_RATIO = 4.0


def slope_bounds(data: HysteresisData) -> tuple[float, float]:
    """The fitted loading curve's slope bounds (output per input) for ``data``:
    ``(PLAY_SLOPE_MIN * g / DEAD_ZONE_SLOPE_RATIO, PLAY_SLOPE_MAX * g * DEAD_ZONE_SLOPE_RATIO)``
    with ``g`` the mean gain; the inverse's drive moves at least ``1 / upper`` per unit of
    reference."""
    g = _mean_gain(data)
    return PLAY_SLOPE_MIN * g / DEAD_ZONE_SLOPE_RATIO, PLAY_SLOPE_MAX * g * DEAD_ZONE_SLOPE_RATIO


def _mean_gain(data: HysteresisData) -> float:
    z_lo, z_hi = data.z_range
    return (z_hi - z_lo) / (data.u_span or 1.0)


def _partial_sums(idx0: int, n_neg: int, n_pos: int) -> np.ndarray:
    """Rows: the slopes of a dead-zone superposition beyond each threshold (partial sums of
    the weights outward from index ``idx0``, the ``d = 0`` weight), as a matrix on the weights."""
    size = n_neg + 1 + n_pos
    M = np.zeros((size, size))
    M[0, idx0] = 1.0
    for j in range(1, n_pos + 1):
        M[j, idx0 : idx0 + j + 1] = 1.0
    for j in range(1, n_neg + 1):
        M[n_pos + j, idx0 - j : idx0 + 1] = 1.0
    return M


@dataclass(frozen=True)
class _Program:
    """A quadratic program compiled once (cvxpy's parametrized form) and solved again with new
    values of its parameters: the structure search solves programs of a few shapes many times,
    and building each anew cost cvxpy more than solving it."""

    problem: Any
    params: dict[str, Any]
    variables: dict[str, Any]


#: Compiled programs by shape, one set per thread (a program's parameters are its state).
_PROGRAMS = threading.local()
#: Shapes kept per thread (the oldest leaves first).
PROGRAMS_KEPT = 64


def _template(key: tuple, build: Callable[[], _Program]) -> _Program:
    """The program of this shape, compiled on first use and solved once then with placeholder
    values (a feasible identity problem), so that every solve of real data takes the same path:
    cvxpy's first solve of a program builds its data another way, and the solution moves by the
    solver's tolerance, so a fit would depend on what was fitted before it in the process."""
    import cvxpy as cp

    programs = _PROGRAMS.__dict__.setdefault("by_shape", {})
    if key not in programs:
        if len(programs) >= PROGRAMS_KEPT:
            programs.pop(next(iter(programs)))
        program = build()
        for param in program.params.values():
            param.value = np.eye(*param.shape) if len(param.shape) == 2 else np.ones(param.shape)
        try:
            program.problem.solve(solver=cp.CLARABEL)
        except cp.error.SolverError:  # the real data's solve says what went wrong
            pass
        programs[key] = program
    return programs[key]


def _plays_program(nr: int, nd: int, M: np.ndarray) -> _Program:
    """QP 1 of :func:`fit_structure` without a plane: ``min |L theta|^2`` over ``theta = (w, c, v)``
    with the plays' and the inverse dead zones' slope bounds and the loading curve through ``u_max``."""
    import cvxpy as cp

    n = nr + 1 + nd
    params = {
        "L": cp.Parameter((n, n)),
        "load": cp.Parameter(nr, nonneg=True),
        "u_max": cp.Parameter(),
        "lo": cp.Parameter(),
        "hi": cp.Parameter(),
    }
    theta = cp.Variable(n)
    w, v = theta[:nr], theta[nr + 1 :]
    cons = [
        w[0] >= PLAY_SLOPE_MIN,
        w[1:] >= 0,
        M @ v >= params["lo"],
        M @ v <= params["hi"],
        cp.sum(w) <= PLAY_SLOPE_MAX,
        params["load"] @ w == params["u_max"],
    ]
    return _Program(cp.Problem(cp.Minimize(cp.sum_squares(params["L"] @ theta)), cons), params, {"theta": theta})


def _dead_zone_program(M: np.ndarray) -> _Program:
    """QP 2 of :func:`fit_structure`: ``min |L (s, offset, 1)|^2`` with the dead zones' slopes in ``[lo, hi]``."""
    import cvxpy as cp

    params = {"L": cp.Parameter((M.shape[0] + 2, M.shape[0] + 2)), "lo": cp.Parameter(), "hi": cp.Parameter()}
    s, offset = cp.Variable(M.shape[0]), cp.Variable(1)
    obj = cp.sum_squares(params["L"] @ cp.hstack([s, offset, np.ones(1)]))
    problem = cp.Problem(cp.Minimize(obj), [M @ s >= params["lo"], M @ s <= params["hi"]])
    return _Program(problem, params, {"s": s, "offset": offset})


def _check_rising(data: HysteresisData) -> None:
    """Refuse runs whose output falls as the input rises: each run on its own (one reversed run
    beside normal ones would be drowned in the whole), then all together."""
    fix = "the model expects a rising output: import the output with --scale COLUMN=-1 (and say so in --units-note)"
    falling = [
        name
        for name, u, z, m in zip(data.names, data.u, data.z, data.train)
        if m.sum() > 2 and np.ptp(u[m]) > 0 and np.ptp(z[m]) > 0 and np.corrcoef(u[m], z[m])[0, 1] < 0
    ]
    if falling:
        raise HysteresisFitError(f"in {', '.join(falling)} the output falls as the input rises; {fix}")
    u = np.concatenate([u[m] for u, m in zip(data.u, data.train)])
    z = np.concatenate([z[m] for z, m in zip(data.z, data.train)])
    if u.size > 2 and np.ptp(u) > 0 and np.ptp(z) > 0 and np.corrcoef(u, z)[0, 1] < 0:
        raise HysteresisFitError(f"the output falls as the input rises; {fix}")


def fit_structure(
    data: HysteresisData,
    r: np.ndarray,
    d_inv: np.ndarray,
    plays: Sequence[np.ndarray],
    rows: str = "train",
    plane: PreisachPlane | None = None,
    duhem: DuhemElements | None = None,
) -> PIModel:
    """Fit weights for fixed play thresholds ``r`` and inverse dead-zone thresholds ``d_inv``
    (and the weights of ``plane``'s cells, or of the ``duhem`` elements, when given).

    ``plays`` are the play outputs of each run for thresholds ``r`` (whole runs), followed by
    the plane's hysterons' or the Duhem elements' (:func:`columns_for`); ``rows``
    selects the samples fitted (``train``, or ``all``: training and held-out rows, never
    the skipped start). Both quadratic programs estimate the output offset with the weights,
    and bound the slopes (:data:`PLAY_SLOPE_MIN`, :data:`PLAY_SLOPE_MAX`,
    :data:`DEAD_ZONE_SLOPE_RATIO`).
    """
    import cvxpy as cp

    masks = data.train if rows == "train" else tuple(t | h for t, h in zip(data.train, data.holdout))
    A = [Y[m] for Y, m in zip(plays, masks)]
    B = [operators.dead_zone(z[m], d_inv) for z, m in zip(data.z, masks)]
    if sum(a.shape[0] for a in A) < 10:
        raise HysteresisFitError("fewer than 10 samples to fit; expected more data")
    idx0 = int(np.flatnonzero(d_inv == 0.0)[0])
    n_neg, n_pos = idx0, d_inv.size - idx0 - 1
    M = _partial_sums(idx0, n_neg, n_pos)
    nr = r.size
    if plane is not None and duhem is not None:
        raise HysteresisFitError("a model holds a Preisach plane or Duhem elements beside its plays, not both")
    extra = plane if plane is not None else duhem
    nc = extra.n_cells if extra is not None else 0
    if A[0].shape[1] != nr + nc:
        raise HysteresisFitError(
            f"expected {nr + nc} operator columns (plays, then plane cells or Duhem elements), got {A[0].shape[1]}"
        )
    u_max = data.u_absmax
    g = _mean_gain(data)
    k = DEAD_ZONE_SLOPE_RATIO
    # QP 1 (thesis Eq. 3.11-3.23): min |A w + K mu + c - B v|^2 over play weights w, plane
    # weights mu, inverse dead-zone weights v and an offset c (the rest level is an estimate)
    G = _gram([(a, np.ones((a.shape[0], 1)), -b) for a, b in zip(A, B)])
    L = _factor(G)
    kind = "plane cells" if plane is not None else "Duhem elements"
    what = (
        f"play/dead-zone fit ({nr} plays, {nc} {kind}, {d_inv.size} dead zones)"
        if nc
        else f"play/dead-zone fit ({nr} plays, {d_inv.size} dead zones)"
    )
    if extra is None:  # one compiled program per shape, its data as parameters
        qp = _template(("plays", nr, d_inv.size, idx0), lambda: _plays_program(nr, d_inv.size, M))
        for name, value in (("L", L), ("load", np.maximum(u_max - r, 0.0)), ("u_max", u_max)):
            qp.params[name].value = value
        qp.params["lo"].value, qp.params["hi"].value = 1.0 / (k * g), k / g
        _solve(qp.problem, what)
        theta = qp.variables["theta"]
    else:
        theta = cp.Variable(nr + nc + 1 + d_inv.size)
        w, v = theta[:nr], theta[nr + nc + 1 :]
        load = np.maximum(u_max - r, 0.0) @ w
        objective = cp.sum_squares(L @ theta)
        cons = [w[0] >= PLAY_SLOPE_MIN, w[1:] >= 0, M @ v >= 1.0 / (k * g), M @ v <= k / g]
        mu = theta[nr : nr + nc]
        load = load + extra.columns(np.array([0.0, u_max]))[-1] @ mu
        energy = float(np.trace(G[nr : nr + nc, nr : nr + nc])) / nc
        D = extra.smoothness()
        if D.size:
            weight = PLANE_SMOOTHING if plane is not None else DUHEM_SMOOTHING
            objective = objective + weight * energy * cp.sum_squares(D @ mu)
        if plane is not None:
            rows_a, rows_b = plane._membership()
            cons += [
                mu >= 0,
                cp.sum(w) + rows_a @ mu / plane.width <= PLAY_SLOPE_MAX,
                cp.sum(w) + rows_b @ mu / plane.width <= PLAY_SLOPE_MAX,
            ]
        else:  # an element's slope is in [0, 2]: the model's slope stays within the plays' bounds
            cons += [
                w[0] - 2 * cp.sum(cp.neg(mu)) >= PLAY_SLOPE_MIN,
                cp.sum(w) + 2 * cp.sum(cp.pos(mu)) <= PLAY_SLOPE_MAX,
            ]
        cons.append(load == u_max)
        _solve(cp.Problem(cp.Minimize(objective), cons), what)
    w, v = theta[:nr], theta[nr + nc + 1 :]
    w_val = np.maximum(np.asarray(w.value, float), 0.0)
    w_val[0] = max(w_val[0], PLAY_SLOPE_MIN)
    mu_val = np.asarray(theta.value[nr : nr + nc], float)
    if plane is not None:
        mu_val = np.maximum(mu_val, 0.0)
    elif duhem is not None:  # the solver's tolerance must not cost the inverse its least slope
        neg = np.maximum(-mu_val, 0.0).sum()
        if 2 * neg > w_val[0] - 0.5 * PLAY_SLOPE_MIN:
            mu_val = np.where(mu_val < 0, mu_val * (w_val[0] - 0.5 * PLAY_SLOPE_MIN) / (2 * neg), mu_val)
    cw = np.concatenate([w_val, mu_val])
    c1 = float(theta.value[nr + nc])
    d_img, _ = invert_dead_zone_weights(d_inv, np.asarray(v.value, float))
    # QP 1 found z = S(P[u] + c1): the forward dead zones sit at S^-1's images shifted by
    # -c1; with 0 (the identity) added they span every continuous piecewise-linear map with
    # those corners, which QP 2 fits on the output error |S[P[u]] + c - z|^2
    span = max(float(np.ptp(np.concatenate([a @ cw for a in A]))), 1e-12)
    shifted = np.sort(np.concatenate([d_img[d_img != 0.0] - c1, [0.0]]))
    d_fwd = shifted[(shifted == 0.0) | (np.abs(shifted) > 1e-6 * span)]
    idx0 = int(np.flatnonzero(d_fwd == 0.0)[0])
    M = _partial_sums(idx0, idx0, d_fwd.size - idx0 - 1)
    P = [a @ cw for a in A]
    D = [operators.dead_zone(p, d_fwd) for p in P]
    zt = [z[m] for z, m in zip(data.z, masks)]
    # columns: dead zones, a free output offset (the rest level is only an estimate), -z
    L2 = _factor(_gram([(dm, np.ones((dm.shape[0], 1)), -zz[:, None]) for dm, zz in zip(D, zt)]))
    qp = _template(("dead zones", d_fwd.size, idx0), lambda: _dead_zone_program(M))
    qp.params["L"].value = L2
    qp.params["lo"].value, qp.params["hi"].value = g / k, g * k
    _solve(qp.problem, "forward dead-zone refit")
    s, offset = qp.variables["s"], qp.variables["offset"]
    s_val = np.asarray(s.value, float)
    if not np.all(np.isfinite(s_val)) or not np.isfinite(offset.value[0]):
        raise HysteresisFitError(
            f"forward dead-zone refit ({d_fwd.size} dead zones): the solver returned non-finite weights"
        )
    return PIModel(
        tuple(map(float, r)),
        tuple(map(float, w_val)),
        tuple(map(float, d_fwd)),
        tuple(map(float, s_val)),
        x0=data.x0,
        y0=data.y0 + float(offset.value[0]),
        plane=plane.with_weights(mu_val) if plane is not None else None,
        duhem=duhem.with_weights(mu_val) if duhem is not None else None,
    )


def predict_rows(
    model: PIModel, plays: Sequence[np.ndarray], masks: Sequence[np.ndarray], y0: float = 0.0
) -> list[np.ndarray]:
    """Model output relative to ``y0`` (the data's rest level) on the masked rows of each run,
    from precomputed plays."""
    w = model.column_weights()
    shift = model.y0 - y0
    return [
        shift + dead_zone_superposition(Y[m] @ w, np.array(model.d), np.array(model.s)) for Y, m in zip(plays, masks)
    ]


def rms_error(model: PIModel, data: HysteresisData, plays: Sequence[np.ndarray], which: str) -> float:
    masks = data.train if which == "train" else data.holdout
    pred = predict_rows(model, plays, masks, data.y0)
    err = np.concatenate([p - z[m] for p, z, m in zip(pred, data.z, masks)])
    return float(np.sqrt(np.mean(err**2))) if err.size else float("nan")


@dataclass(frozen=True)
class HysteresisFit:
    """The selected model and how it was chosen."""

    model: PIModel
    candidates: list[dict[str, Any]]
    chosen: str
    reason: str
    train_rms: float
    holdout_rms: float
    output_range: float
    pruned: int
    final_model: PIModel | None = None
    #: which model family won on the held-out rows, and why
    family_reason: str = ""
    #: the structure chosen (before pruning)
    candidate: Candidate | None = None
    #: the held-out RMS of the best modified PI candidate (in the default search, among those of at
    #: least :data:`MIN_PI_PLAYS` plays), whichever family won, on the rows the candidates were
    #: scored on (a decimated copy above :data:`SELECT_MAX_SAMPLES`); NaN where none was fitted
    pi_holdout_rms: float = float("nan")

    @property
    def holdout_rms_pct(self) -> float:
        return 100.0 * self.holdout_rms / self.output_range


#: Stage 1 of the default search: play operators (number, spacing) at a moderate dead-zone count.
PLAY_GRID = tuple(Candidate(n, g, 4) for n in (2, 4, 6, 8, 12, 16, 24) for g in (1.0, 2.0))
#: Stage 2: dead zones per side for the chosen plays.
DEAD_ZONE_COUNTS = (0, 1, 2, 4, 8, 16)


def _plays_for(data: HysteresisData, r: np.ndarray, cache: dict) -> list[np.ndarray]:
    key = tuple(np.round(r, 12))
    if key not in cache:
        cache[key] = [operators.play(u, r) for u in data.u]
    return cache[key]


def columns_for(
    data: HysteresisData,
    r: np.ndarray,
    extra: PreisachPlane | DuhemElements | None,
    cache: dict | None = None,
) -> list[np.ndarray]:
    """Each run's operator columns: the plays of thresholds ``r``, then ``extra``'s (a plane's
    hysterons or Duhem elements; a model's :attr:`PIModel.extra`)."""
    cache = {} if cache is None else cache
    plays = _plays_for(data, r, cache)
    if extra is None:
        return plays
    if isinstance(extra, PreisachPlane):
        key = ("plane", extra.levels, extra.width, extra.alpha[0])
    else:
        key = ("duhem", extra.widths, extra.rest)
    if key not in cache:
        cache[key] = [extra.columns(u) for u in data.u]
    return [np.hstack([p, k]) for p, k in zip(plays, cache[key])]


def refit(data: HysteresisData, model: PIModel, rows: str = "train", cache: dict | None = None) -> PIModel:
    """``model``'s structure (plays, dead zones, plane cells) fitted again on ``data``."""
    d_inv, _ = invert_dead_zone_weights(np.array(model.d), np.array(model.s))
    r = np.array(model.r)
    fitted = fit_structure(
        data, r, d_inv, columns_for(data, r, model.extra, cache), rows=rows, plane=model.plane, duhem=model.duhem
    )
    return replace(fitted, input_unit=model.input_unit, output_unit=model.output_unit)


def decimate(data: HysteresisData, step: int) -> HysteresisData:
    """Every ``step``-th sample of each run (for choosing the model on large data)."""
    sl = slice(None, None, step)
    return HysteresisData(
        data.names,
        tuple(u[sl] for u in data.u),
        tuple(z[sl] for z in data.z),
        tuple(m[sl] for m in data.train),
        tuple(m[sl] for m in data.holdout),
        data.x0,
        data.y0,
    )


#: Above this many samples the model is chosen on a decimated copy, then fitted on all.
SELECT_MAX_SAMPLES = 20_000


def fit_hysteresis(
    data: HysteresisData,
    grid: Sequence[Candidate] | None = None,
    *,
    tolerance: float = 0.01,
    prune_below: float = 1e-3,
    refit_all: bool = True,
    plane_family: bool = True,
    duhem_family: bool = True,
) -> HysteresisFit:
    """Choose operator numbers and thresholds on held-out data, prune, refit.

    Each candidate is fitted on the training rows and scored by its RMS output error on
    the held-out rows. The chosen one is the smallest (fewest operators) whose held-out
    error is within ``tolerance`` (relative) of the best. Without ``grid`` the search has
    three stages: the play operators (:data:`PLAY_GRID`), the number of dead zones for
    them (:data:`DEAD_ZONE_COUNTS`), and the play operators again for that number. Operators
    whose weight is below ``prune_below`` of the largest are dropped if that does not worsen
    the held-out error beyond the tolerance.
    With ``plane_family`` (and no ``grid``) a fourth stage tries Preisach planes
    (:data:`PLANE_LEVELS`, the finer ones only while the plane family wins and refining helps:
    :data:`PLANE_LEVELS_FIRST`) beside the chosen plays; with ``duhem_family`` a fifth tries Duhem
    elements (:data:`DUHEM_COUNTS`) beside them and beside the threshold-0 play alone. Another
    family than the modified PI wins only by :data:`FAMILY_MARGIN`, the best of those that do.
    With ``refit_all`` the final model is refitted on all rows (``final_model``);
    ``model`` is the one scored on held-out data.
    """
    if not any(h.any() for h in data.holdout):
        raise HysteresisFitError("no held-out samples; expected holdout_fraction > 0 to choose the model")
    _check_rising(data)
    z_lo, z_hi = data.z_range
    out_range = z_hi - z_lo
    full = data
    n_total = sum(u.size for u in data.u)
    if n_total > SELECT_MAX_SAMPLES:
        # the play operators are rate-independent: a quasi-static sweep sampled more finely
        # than its reversals need carries no more information about the loop's shape
        data = decimate(data, int(np.ceil(n_total / SELECT_MAX_SAMPLES)))
    cache: dict = {}
    rows: list[dict[str, Any]] = []
    fits: list[tuple[float, int, Candidate, PIModel]] = []
    planes = bool(PLANE_LEVELS) and plane_family

    def choose(pool):
        best_ = min(f[0] for f in pool)
        return best_, min((f for f in pool if f[0] <= best_ * (1 + tolerance)), key=lambda f: (f[1], f[0]))

    if grid is None:
        _score(data, PLAY_GRID, cache, rows, fits)
        if not fits:
            raise HysteresisFitError(
                "no candidate model could be fitted: " + "; ".join(r_["note"] for r_ in rows)[:400]
            )
        _, (_, _, c1, _) = choose(fits)
        _score(
            data,
            [Candidate(c1.n_play, c1.gamma, m) for m in DEAD_ZONE_COUNTS if m != c1.m_dead_zone],
            cache,
            rows,
            fits,
        )
        _, (_, _, c2, _) = choose(fits)
        if c2.m_dead_zone != PLAY_GRID[0].m_dead_zone:  # the plays again, for the chosen dead zones
            _score(
                data,
                [
                    Candidate(c.n_play, c.gamma, c2.m_dead_zone)
                    for c in PLAY_GRID
                    if (c.n_play, c.gamma) != (c2.n_play, c2.gamma)
                ],
                cache,
                rows,
                fits,
            )
        if planes:  # the other family, on the chosen plays and dead zones
            _, (_, _, c3, _) = choose(fits)
            pi_best = min(f[0] for f in fits)
            coarse = [n for n in PLANE_LEVELS if n <= PLANE_LEVELS_FIRST]
            _score(data, [Candidate(c3.n_play, c3.gamma, c3.m_dead_zone, n) for n in coarse], cache, rows, fits)
            held = [f[0] for f in fits if f[2].plane_levels]  # the planes' held-out errors, coarse to fine
            # finer planes only where the plane family wins, and while the last refinement helped
            for n in (n for n in PLANE_LEVELS if n > PLANE_LEVELS_FIRST):
                if (
                    len(held) < 2
                    or min(held) > (1.0 - FAMILY_MARGIN) * pi_best
                    or held[-1] > (1.0 - tolerance) * min(held[:-1])
                ):
                    break
                fitted = len(fits)
                _score(data, [Candidate(c3.n_play, c3.gamma, c3.m_dead_zone, n)], cache, rows, fits)
                if len(fits) == fitted:
                    break  # the finer plane could not be fitted
                held.append(fits[-1][0])
        if duhem_family and DUHEM_COUNTS:  # the Duhem family, on the chosen plays and on the threshold-0 play alone
            _, (_, _, c4, _) = choose([f for f in fits if not f[2].plane_levels])
            plays_tried = sorted({c4.n_play, 1})
            _score(
                data,
                [
                    Candidate(n, c4.gamma if n > 1 else 1.0, c4.m_dead_zone, duhem_elements=k, duhem_rest=rest)
                    for n in plays_tried
                    for k in DUHEM_COUNTS
                    for rest in DUHEM_RESTS
                ],
                cache,
                rows,
                fits,
            )
    else:
        _score(data, grid, cache, rows, fits)
    if not fits:
        raise HysteresisFitError("no candidate model could be fitted: " + "; ".join(r_["note"] for r_ in rows)[:400])
    family = _family_reason(fits, choose, MIN_PI_PLAYS if grid is None else 0)
    best, (ho, n_ops, cand, model) = family[0]
    if full is not data:  # fit the chosen structure on every sample
        cache = {}
        model = refit(full, model, cache=cache)
        ho = rms_error(model, full, columns_for(full, np.array(model.r), model.extra, cache), "holdout")
    done = _finish(
        full, model, ho, cand, best, len(fits), rows, cache, out_range, tolerance, prune_below, refit_all, family[1]
    )
    return replace(done, pi_holdout_rms=family[2])


#: Levels of the Preisach planes tried beside the chosen plays (cells: N (N + 1) / 2). A
#: plane's levels are its resolution: a stack whose domains switch over narrow bands of the
#: field (coercive fields of a few volts, log-normally spread) draws minor loops whose shape a
#: coarse grid smooths over. On the third test press (a Preisach press) 16 and 20 levels beside
#: 4-12 took the compensated 0.1 Hz loop from 1.55 to 1.05 % and the random tracking from 0.54
#: to 0.47 % (3 seeds, ``bench/bench_presses.py``; 20 levels chosen on each, with the runs' full
#: metadata or the four required fields alike; 24 levels offered changed nothing),
#: the 1 Hz loop from 0.39 to 0.57 %; the second press (plays) is unchanged.
PLANE_LEVELS = (4, 8, 12, 16, 20)
#: The planes up to this many levels are always tried; finer ones only where the plane family
#: wins (by :data:`FAMILY_MARGIN`) and each refinement still predicts the held-out rows better
#: (by the search's tolerance): on a press of the modified PI family, and on the real data sets,
#: the finer planes cost twice the fit's time for nothing.
PLANE_LEVELS_FIRST = 12
#: Duhem elements tried beside the chosen plays (and beside the threshold-0 play alone). A
#: stack's loop of the Bouc-Wen kind (the branch shallow after a reversal and steepening
#: exponentially, minor loops that do not close) is drawn by plays only as a staircase of slopes.
DUHEM_COUNTS = (4, 8, 16)
#: A plane is chosen only when it predicts the held-out rows this much better (relative RMS)
#: than the best modified PI model: a richer family must earn its cells. The held-out rows are
#: the ends of the fitted runs, and compensation plays other amplitudes: on the second test
#: press a plane that predicted the run ends 17-21 % better compensated the 0.1 Hz loop worse
#: in 2 of 3 seeds (2.7 -> 3.2 %), while on a Preisach press (72 % better) it cut the loop
#: from 7.0 to 2.5 % (``bench/bench_family.py``).
FAMILY_MARGIN = 0.30


#: The fewest play operators of the modified PI candidates the search chooses among (the
#: thesis's 12; plays of no weight are still pruned after). A PI model draws a minor loop of
#: amplitude A with the plays whose thresholds lie below A / 2 only, and the held-out rows are
#: each run's end, mostly its largest loops: they cannot see how coarsely fewer plays draw
#: the smaller ones. On the second test press 6 plays (gamma 2) predicted the held-out ends 7 % better than 24, and
#: with at least 12 the compensated 0.1 Hz loops went from 1.62 % to 0.90 % (3 seeds,
#: ``bench/bench_presses.py``), the 120 s creep from 0.23 % to 0.10 % (the hold's drive,
#: lowered by the creep compensation, is such a small loop) and the 50 Hz loop from 1.58 %
#: to 1.23 %; the third press (a plane) and the virtual rig (16 plays) are unchanged.
#: Candidates with fewer plays are still scored (they choose the dead zones, and the plays
#: a Preisach plane is tried on, whose levels give the small loops their resolution).
MIN_PI_PLAYS = 12


def _than_pi(gain: float) -> str:
    """A family's held-out RMS beside the best modified PI model's, in words ("12 % lower", "2 % higher")."""
    return f"{abs(100 * gain):.0f} % {'lower' if gain >= 0 else 'higher'}"


def _family_reason(fits, choose, min_plays: int = 0) -> tuple[Any, str, float]:
    """``(choice, why, best_pi)``: ``choose``'s ``(best, fit)`` in the family chosen, a sentence on
    which family won and why, and the best modified PI model's held-out RMS (NaN: none fitted).
    The modified PI family (among its candidates with at least ``min_plays`` plays, if any) unless
    another family predicts the held-out rows :data:`FAMILY_MARGIN` better; of those that do, the
    best."""
    pools: dict[str, list] = {}
    for f in fits:
        pools.setdefault(f[2].family, []).append(f)
    pi = pools.pop(FAMILY_PI, [])
    title = FAMILY_TITLES[FAMILY_PI]
    if not pi:
        best_family = min(pools, key=lambda k: min(f[0] for f in pools[k]))
        return choose(pools[best_family]), f"{FAMILY_TITLES[best_family]} (the only family tried)", float("nan")
    fine = [f for f in pi if f[2].n_play >= min_plays]
    best_pi, pi_choice = choose(fine or pi)
    note = ""
    if fine and len(fine) < len(pi):
        best_all, all_choice = choose(pi)
        if all_choice[2].n_play < min_plays:
            note = (
                f"; {all_choice[2].label} predicted the held-out ends {100 * (1 - best_all / best_pi):.0f} % "
                f"better, but the family is chosen among candidates of at least {min_plays} plays (held-out ends "
                "are mostly the largest loops, and fewer plays draw the smaller ones coarsely)"
            )
    if not pools:
        return (best_pi, pi_choice), f"{title} (no other family tried){note}", best_pi
    best = {k: min(f[0] for f in v) for k, v in pools.items()}
    gain = {k: (1.0 - b / best_pi if best_pi > 0 else 0.0) for k, b in best.items()}
    others = "; ".join(f"{FAMILY_TITLES[k]}: {best[k]:.4g} ({_than_pi(gain[k])})" for k in sorted(best, key=best.get))
    winners = [k for k in best if gain[k] >= FAMILY_MARGIN]
    if winners:
        won = min(winners, key=best.get)
        rest = "; ".join(
            f"{FAMILY_TITLES[k]}: {best[k]:.4g} ({_than_pi(gain[k])})" for k in sorted(best, key=best.get) if k != won
        )
        why = (
            f"{FAMILY_TITLES[won]}: held-out RMS {best[won]:.4g} against {best_pi:.4g} for the "
            f"best modified PI model ({100 * gain[won]:.0f} % lower; needs {100 * FAMILY_MARGIN:g} %)"
            + (f"; tried also: {rest}" if rest else "")
        )
        return choose(pools[won]), why, best_pi
    why = (
        f"{title}: held-out RMS {best_pi:.4g}; no other family predicts the held-out rows "
        f"{100 * FAMILY_MARGIN:g} % better, as a richer family must ({others}){note}"
    )
    return (best_pi, pi_choice), why, best_pi


def _score(data: HysteresisData, grid: Sequence[Candidate], cache: dict, rows: list, fits: list) -> None:
    """Fit and score each candidate; append to ``rows`` (table) and ``fits``."""
    z_lo, z_hi = data.z_range
    for c in grid:
        r = play_thresholds(c.n_play, c.gamma, data.u_span)
        d_inv = dead_zone_thresholds(c.m_dead_zone, z_lo, z_hi)
        try:
            plane = plane_for(data, c.plane_levels)
            duhem = DuhemElements.grid(data.u_span, c.duhem_elements, c.duhem_rest) if c.duhem_elements else None
            plays = columns_for(data, r, plane or duhem, cache)
            model = fit_structure(data, r, d_inv, plays, plane=plane, duhem=duhem)
        except HysteresisFitError as exc:
            rows.append(
                {
                    "candidate": c.label,
                    "n_operators": r.size + d_inv.size,
                    "train_rms": float("nan"),
                    "holdout_rms": float("nan"),
                    "note": str(exc),
                }
            )
            continue
        tr, ho = rms_error(model, data, plays, "train"), rms_error(model, data, plays, "holdout")
        n_ops = model.n_play + model.n_dead_zone + (model.extra.n_cells if model.extra is not None else 0)
        rows.append(
            {
                "candidate": c.label,
                "n_operators": n_ops,
                "train_rms": tr,
                "holdout_rms": ho,
                "note": "",
            }
        )
        fits.append((ho, n_ops, c, model))


def _finish(
    data, model, ho, cand, best, n_fits, rows, cache, out_range, tolerance, prune_below, refit_all, family=""
) -> HysteresisFit:
    """Prune the chosen model, score it, and refit it on all rows."""
    # prune operators that contribute nothing
    w = np.array(model.w)
    s = np.array(model.s)
    keep_r = np.array([i == 0 or w[i] >= prune_below * w.max() for i in range(w.size)])
    d = np.array(model.d)
    i0 = int(np.flatnonzero(d == 0.0)[0])
    keep_d = np.array([j == i0 or abs(s[j]) >= prune_below * abs(s[i0]) for j in range(s.size)])
    pruned = int((~keep_r).sum() + (~keep_d).sum())
    r_final = np.array(model.r)[keep_r]
    if pruned:
        d_inv_full, _ = invert_dead_zone_weights(d, s)
        plays = columns_for(data, r_final, model.extra, cache)
        try:
            pm = fit_structure(data, r_final, d_inv_full[keep_d], plays, plane=model.plane, duhem=model.duhem)
            pho = rms_error(pm, data, plays, "holdout")
            if pho <= ho * (1 + tolerance):
                model, ho = pm, pho
            else:
                pruned, r_final = 0, np.array(model.r)
        except HysteresisFitError:
            pruned, r_final = 0, np.array(model.r)
    plays = columns_for(data, np.array(model.r), model.extra, cache)
    tr = rms_error(model, data, plays, "train")
    cells = (
        f", {model.plane.n_cells} plane cells"
        if model.plane is not None
        else f", {model.duhem.n_cells} Duhem elements"
        if model.duhem is not None
        else ""
    )
    reason = (
        f"{cand.label} ({model.n_play} plays, {model.n_dead_zone} dead zones{cells} after pruning {pruned}): "
        "held-out RMS "
        f"{ho:.4g} ({100 * ho / out_range:.2f} % of range), within {100 * tolerance:g} % of the best of {n_fits} "
        "candidates "
        f"({best:.4g}) with the fewest operators" + (f"; family: {family}" if family else "")
    )
    final = refit(data, model, rows="all", cache=cache) if refit_all else None
    return HysteresisFit(model, rows, cand.label, reason, tr, ho, out_range, pruned, final, family, cand)
