"""Rate-independent hysteresis operators on sampled signals: play (backlash), dead zone, KP
hysteron and Duhem (Bouc-Wen, exponent 1) element.

Pure numpy, shared by the virtual rig (physics) and the Prandtl-Ishlinskii model (analysis).

The play operator of threshold ``r`` (thesis Eq. 3.1, 3.2)::

    y[k] = clip(y[k-1], x[k] - r, x[k] + r),   y[-1] = y0

is evaluated exactly, vectorised over samples and thresholds, by one of two algorithms:

* *monotone runs*: while ``x`` does not decrease, ``y[k] = max(y[a], x[k] - r)`` from the
  run's first sample ``a`` on (and ``min(y[a], x[k] + r)`` while it does not increase), so
  a drive with few reversals costs one vector operation per run;
* *clamp scan*: each step is the clamp ``f_k(y) = clip(y, lo_k, hi_k)``; clamps compose into
  clamps, ``f2(f1(y)) = clip(y, clip(lo1, lo2, hi2), clip(hi1, lo2, hi2))``, an associative
  operation, so a two-level scan (compose blocks of ``sqrt(n)`` steps side by side, carry the
  state across blocks, replay the blocks side by side) needs about ``3 sqrt(n)`` vector
  steps. This serves noisy inputs, where every sample is a reversal.

Both give the per-sample loop's result to rounding (see ``tests/test_operators.py``).
"""

from __future__ import annotations

import numpy as np

#: Above this fraction of reversals per sample the clamp scan is faster than the run loop.
_SCAN_ABOVE_RUN_FRACTION = 1.0 / 64.0


def _as_thresholds(r: np.ndarray | float) -> np.ndarray:
    r = np.atleast_1d(np.asarray(r, dtype=np.float64))
    if r.ndim != 1:
        raise ValueError(f"thresholds must be a scalar or a 1-D array, got shape {r.shape}")
    if np.any(r < 0) or not np.all(np.isfinite(r)):
        raise ValueError(f"thresholds must be finite and non-negative, got {r}")
    return r


def play_initial_state(x0: float, r: np.ndarray, y0: np.ndarray | float = 0.0) -> np.ndarray:
    """Thesis Eq. 3.2: the state after the first sample ``x0`` from initial state ``y0``."""
    r = _as_thresholds(r)
    return np.clip(np.broadcast_to(np.asarray(y0, dtype=np.float64), r.shape), x0 - r, x0 + r)


def monotone_runs(x: np.ndarray) -> np.ndarray:
    """Start indices of the maximal monotone runs of ``x`` (always including 0).

    A sample that does not change ``x`` belongs to the run it is in.
    """
    d = np.sign(np.diff(x))
    # carry the last non-zero direction over flat stretches
    nz = np.flatnonzero(d)
    if nz.size == 0:
        return np.array([0])
    idx = np.zeros_like(d, dtype=np.int64)
    idx[nz] = nz
    np.maximum.accumulate(idx, out=idx)
    d = d[idx]
    d[: nz[0]] = d[nz[0]]
    # d[j] is the step x[j] -> x[j+1]; a new direction at step j starts a run at sample j+1
    change = np.flatnonzero(d[1:] != d[:-1]) + 2
    return np.concatenate([[0], change])


def play(
    x: np.ndarray, r: np.ndarray | float, y0: np.ndarray | float = 0.0, widen: np.ndarray | None = None
) -> np.ndarray:
    """Play (backlash) operators of thresholds ``r`` driven by ``x``.

    Parameters
    ----------
    x : array_like, shape (n,)
        Input samples.
    r : float or array_like, shape (m,)
        Non-negative thresholds (half-widths of the deadband).
    widen : array_like, shape (n,), optional
        Per-sample amount added to every threshold (rate-dependent hysteresis: the deadband
        at sample ``k`` is ``r + widen[k]``). Must not be negative.
    y0 : float or array_like, shape (m,)
        State before the first sample (thesis: 0, the de-energised actuator). Carry
        ``y[-1]`` of one chunk as ``y0`` of the next to evaluate a signal in chunks.

    Returns
    -------
    y : ndarray, shape (n, m)

    Examples
    --------
    >>> play(np.array([0.0, 2.0, 1.0, 3.0]), 0.5)[:, 0].tolist()
    [0.0, 1.5, 1.5, 2.5]
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 1:
        raise ValueError(f"x must be 1-D, got shape {x.shape}")
    r = _as_thresholds(r)
    n = x.size
    if n == 0:
        return np.zeros((0, r.size))
    if widen is not None:
        widen = np.asarray(widen, dtype=np.float64)
        if widen.shape != x.shape or np.any(widen < 0):
            raise ValueError(f"widen must be non-negative with the shape of x {x.shape}, got shape {widen.shape}")
    y_start = play_initial_state(x[0], r if widen is None else r + widen[0], y0)
    starts = monotone_runs(x)
    if starts.size <= max(8, _SCAN_ABOVE_RUN_FRACTION * n):
        y = _play_runs(x, r, y_start, starts, widen)
        if y is not None:
            return y
    return _play_scan(x, r, y_start, widen)


def _play_runs(
    x: np.ndarray, r: np.ndarray, y_start: np.ndarray, starts: np.ndarray, widen: np.ndarray | None = None
) -> np.ndarray | None:
    # Rising run: y[k] = max(y[k-1], lo[k]) while the upper bound hi[k] never binds, i.e.
    # a running maximum of lo (falling: a running minimum of hi). With constant thresholds
    # the bound never binds; with widened ones it is checked, and None returned if it does
    # (the caller then uses the exact scan).
    n = x.size
    y = np.empty((n, r.size))
    y[0] = y_start
    bounds = np.append(starts, n)
    prev = y_start
    for a, b in zip(bounds[:-1], bounds[1:]):
        lo_a = a if a > 0 else 1  # sample 0 is already set
        if lo_a >= b:
            continue
        width = r if widen is None else r + widen[lo_a:b, None]
        lo = x[lo_a:b, None] - width
        hi = x[lo_a:b, None] + width
        first = np.clip(prev, lo[0], hi[0])
        rising = x[b - 1] >= x[lo_a - 1]
        if widen is None:  # lo (hi) is monotone over the run: the running extreme is plain max (min)
            seg = np.maximum(first, lo) if rising else np.minimum(first, hi)
        elif rising:
            seg = np.maximum.accumulate(np.concatenate([first[None], lo[1:]]), axis=0)
            if np.any(seg > hi):
                return None
        else:
            seg = np.minimum.accumulate(np.concatenate([first[None], hi[1:]]), axis=0)
            if np.any(seg < lo):
                return None
        y[lo_a:b] = seg
        prev = seg[-1]
    return y


def _clamp(v: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    # clip(v, lo, hi) for lo <= hi, without np.clip's overhead
    return np.minimum(np.maximum(v, lo), hi)


def _blocks(steps: int) -> tuple[int, int, int]:
    """Blocks of the two-level scan: ``(B blocks, L steps each, padding)`` for ``steps`` steps."""
    L = max(1, int(np.ceil(np.sqrt(steps))))
    B = -(-steps // L)
    return B, L, B * L - steps


def _two_level_scan(start: np.ndarray, steps: int, B: int, L: int, bounds) -> np.ndarray:
    # Two-level scan of the clamps f_k(y) = clip(y, lo_k, hi_k), k = 1 .. steps, where
    # ``bounds(j)`` gives step j of every block, ``(B, m)`` each (padding: -inf, inf):
    # (1) compose the clamps of each block of L steps, all blocks at once (L vector steps);
    # (2) carry the state from block to block through the composites (B small steps);
    # (3) replay each block from its start state, all blocks at once (L vector steps).
    m = start.size
    comp_lo = np.full((B, m), -np.inf)
    comp_hi = np.full((B, m), np.inf)
    for j in range(L):
        lo, hi = bounds(j)
        comp_lo = _clamp(comp_lo, lo, hi)
        comp_hi = _clamp(comp_hi, lo, hi)
    state = np.empty((B, m))
    s = start
    for b in range(B):
        state[b] = s
        s = _clamp(s, comp_lo[b], comp_hi[b])
    out = np.empty((B, L, m))
    for j in range(L):
        lo, hi = bounds(j)
        state = _clamp(state, lo, hi)
        out[:, j] = state
    return out.reshape(B * L, m)[:steps]


def _play_scan(x: np.ndarray, r: np.ndarray, y_start: np.ndarray, widen: np.ndarray | None = None) -> np.ndarray:
    # the clamps of the play: f_k(y) = clip(y, x[k] - r, x[k] + r), bounds made block column by
    # block column (never the n x m arrays)
    steps = x.size - 1
    y = np.empty((x.size, r.size))
    y[0] = y_start
    if steps == 0:
        return y
    B, L, pad = _blocks(steps)
    xs = np.concatenate([x[1:], np.full(pad, np.nan)]).reshape(B, L)
    wd = None if widen is None else np.concatenate([widen[1:], np.zeros(pad)]).reshape(B, L)
    valid = ~np.isnan(xs)

    def bounds(j):
        col = xs[:, j, None]
        w = r if wd is None else r + wd[:, j, None]
        return np.where(valid[:, j, None], col - w, -np.inf), np.where(valid[:, j, None], col + w, np.inf)

    y[1:] = _two_level_scan(y_start, steps, B, L, bounds)
    return y


def play_loop(
    x: np.ndarray, r: np.ndarray | float, y0: np.ndarray | float = 0.0, widen: np.ndarray | None = None
) -> np.ndarray:
    """Reference implementation: the per-sample loop of Eq. 3.1 (slow; for tests and benchmarks)."""
    x = np.asarray(x, dtype=np.float64)
    r = _as_thresholds(r)
    widen = np.zeros(x.size) if widen is None else np.asarray(widen, dtype=np.float64)
    y = np.empty((x.size, r.size))
    state = play_initial_state(x[0], r + widen[0], y0) if x.size else None
    for k in range(x.size):
        if k:
            for i in range(r.size):
                s = state[i]
                lo = x[k] - r[i] - widen[k]
                hi = x[k] + r[i] + widen[k]
                state[i] = lo if s < lo else hi if s > hi else s
        y[k] = state
    return y


def dead_zone(y: np.ndarray, d: np.ndarray | float) -> np.ndarray:
    """One-sided dead-zone operators (thesis Eq. 3.6) of thresholds ``d`` applied to ``y``.

    ``max(y - d, 0)`` for ``d > 0``, ``y`` for ``d = 0``, ``min(y - d, 0)`` for ``d < 0``.

    Returns
    -------
    ndarray, shape ``y.shape + (m,)``
    """
    y = np.asarray(y, dtype=np.float64)[..., None]
    d = np.atleast_1d(np.asarray(d, dtype=np.float64))
    # one pass: clip y - d to [0, inf) where d > 0, (-inf, 0] where d < 0, untouched where d = 0
    lower = np.where(d > 0, 0.0, -np.inf)
    upper = np.where(d < 0, 0.0, np.inf)
    out = y - d
    return np.clip(out, lower, upper, out=out)


# --------------------------------------------------------------------------- Krasnosel'skii-Pokrovskii hysterons
#
# A KP hysteron (Krasnosel'skii & Pokrovskii, "Systems with Hysteresis", 1989; Banks, Kurdila &
# Webb, "Identification of hysteretic control influence operators representing smart actuators",
# 1997) is a relay with ramps instead of jumps: its state ``s`` in [0, 1] follows
#
#     s[k] = clip(s[k-1], a(x[k]), b(x[k])),  a(x) = clip((x - alpha) / h, 0, 1),
#                                              b(x) = clip((x - beta) / h, 0, 1),
#
# rising along the ramp from ``alpha`` to ``alpha + h`` and falling along the one from ``beta + h``
# down to ``beta`` (``beta <= alpha``). Weighted over a grid of the Preisach half-plane it is a
# discretised Preisach model whose output is continuous in the input, so its inverse is too. The
# update is a clamp like the play's (whose bounds are ``x -+ r``), so the same two algorithms
# evaluate it exactly: monotone runs (the bounds move with ``x``) and the clamp scan.

#: Samples per chunk when evaluating hysterons (bounds are ``chunk x cells`` arrays).
_KP_CHUNK = 16_384


def kp_bounds(
    x: np.ndarray, alpha: np.ndarray, beta: np.ndarray, h: float, widen: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The clamp bounds ``a(x)``, ``b(x)`` of hysterons ``(alpha, beta)`` of ramp width ``h``: ``(n, m)`` each
    (``widen``, per sample: the thresholds pushed apart, up at ``alpha + widen``, down at ``beta - widen``)."""
    x = np.asarray(x, dtype=np.float64)[:, None]
    w = 0.0 if widen is None else np.asarray(widen, dtype=np.float64)[:, None]
    lo = np.clip((x - w - alpha) / h, 0.0, 1.0)
    hi = np.clip((x + w - beta) / h, 0.0, 1.0)
    return lo, hi


def kp_initial_state(
    x0: float, alpha: np.ndarray, beta: np.ndarray, h: float, s0: np.ndarray | float = 0.0
) -> np.ndarray:
    """The hysterons' state after the first sample ``x0`` from the state ``s0`` (0: every relay down)."""
    lo, hi = kp_bounds(np.array([x0]), alpha, beta, h)
    s = np.broadcast_to(np.asarray(s0, dtype=np.float64), lo[0].shape)
    return np.minimum(np.maximum(s, lo[0]), hi[0])


def _check_kp(alpha: np.ndarray, beta: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    alpha = np.atleast_1d(np.asarray(alpha, dtype=np.float64))
    beta = np.atleast_1d(np.asarray(beta, dtype=np.float64))
    if alpha.shape != beta.shape or alpha.ndim != 1:
        raise ValueError(f"alpha and beta must be 1-D of one length, got shapes {alpha.shape} and {beta.shape}")
    if not (np.all(np.isfinite(alpha)) and np.all(np.isfinite(beta)) and np.all(beta <= alpha)):
        raise ValueError("hysteron thresholds must be finite with beta <= alpha")
    if not (np.isfinite(h) and h > 0):
        raise ValueError(f"the ramp width must be finite and positive, got {h}")
    return alpha, beta


def _kp_start(x, alpha, beta, h, s0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Checked inputs and the output array with its first row (the state after the first sample) set."""
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 1:
        raise ValueError(f"x must be 1-D, got shape {x.shape}")
    alpha, beta = _check_kp(alpha, beta, h)
    out = np.empty((x.size, alpha.size))
    if x.size:
        out[0] = kp_initial_state(x[0], alpha, beta, h, s0)
    return x, alpha, beta, out


def kp(
    x: np.ndarray,
    alpha: np.ndarray,
    beta: np.ndarray,
    h: float,
    s0: np.ndarray | float = 0.0,
    widen: np.ndarray | None = None,
) -> np.ndarray:
    """KP hysterons ``(alpha, beta)`` of ramp width ``h`` driven by ``x``: states ``(n, m)`` in [0, 1].

    ``s0`` is the state before the first sample (carry ``s[-1]`` of one chunk as ``s0`` of
    the next to evaluate a signal in chunks). ``widen`` (shape ``(n,)``, not negative): at
    sample ``k`` every hysteron switches up at ``alpha + widen[k]`` and down at
    ``beta - widen[k]`` (rate-dependent hysteresis, as :func:`play`'s ``widen``).

    Examples
    --------
    >>> kp(np.array([0.0, 1.0, 2.0, 1.0, 0.0]), 1.0, 0.0, 1.0)[:, 0].tolist()
    [0.0, 0.0, 1.0, 1.0, 0.0]
    """
    if widen is not None:
        return _kp_widened(x, alpha, beta, h, s0, widen)
    x, alpha, beta, out = _kp_start(x, alpha, beta, h, s0)
    if x.size == 0:
        return out
    # chunks overlap by one sample: each chunk starts from the state at its first sample
    for a in range(0, x.size - 1, _KP_CHUNK):
        seg = x[a : a + _KP_CHUNK + 1]
        starts = monotone_runs(seg)
        if starts.size <= max(8, _SCAN_ABOVE_RUN_FRACTION * seg.size):
            _kp_runs(seg, alpha, beta, h, out[a : a + seg.size], starts)
        else:
            lo, hi = kp_bounds(seg, alpha, beta, h)
            out[a + 1 : a + seg.size] = _clamp_scan(lo, hi, out[a])[1:]
    return out


#: Samples per block of :func:`kp_weighted`: a block's ``block x cells`` states stay in the cache
#: where a run's ``n x cells`` would not (a 6000-sample step into 120 cells is 5.8 MB).
_KP_WEIGHTED_BLOCK = 1024


def kp_weighted(
    x: np.ndarray,
    alpha: np.ndarray,
    beta: np.ndarray,
    h: float,
    weights: np.ndarray,
    offset: np.ndarray,
    s0: np.ndarray | float = 0.0,
    widen: np.ndarray | None = None,
) -> np.ndarray:
    """``(kp(x, alpha, beta, h, s0, widen) - offset) @ weights``, shape ``(n,)``, without the ``n x m``
    states: where only the hysterons' weighted sum is wanted (a model's output), they are made and
    weighted block by block of :data:`_KP_WEIGHTED_BLOCK` samples, while in the cache.

    The same two algorithms as :func:`kp` (monotone runs, each block of a run from the state the
    block before it ended in; the clamp scan), so the same states to the bit; the sums differ from
    one matrix product's by rounding."""
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 1:
        raise ValueError(f"x must be 1-D, got shape {x.shape}")
    alpha, beta = _check_kp(alpha, beta, h)
    weights = np.asarray(weights, dtype=np.float64)
    offset = np.asarray(offset, dtype=np.float64)
    if weights.shape != alpha.shape or offset.shape != alpha.shape:
        raise ValueError(f"weights {weights.shape} and offset {offset.shape} need one value per hysteron {alpha.shape}")
    if widen is not None:
        widen = np.asarray(widen, dtype=np.float64)
        if widen.shape != x.shape or np.any(widen < 0) or not np.all(np.isfinite(widen)):
            raise ValueError(
                f"widen must be finite, non-negative and of the shape of x {x.shape}, got shape {widen.shape}"
            )
    out = np.empty(x.size)
    if x.size == 0:
        return out
    w0 = 0.0 if widen is None else widen[0]
    state = kp_initial_state(x[0], alpha + w0, beta - w0, h, s0)
    out[0] = (state - offset) @ weights

    def emit(first: int, seg: np.ndarray) -> np.ndarray:
        """Weigh the states of samples ``first ..`` into ``out``; the last one's state (raw)."""
        last = seg[-1].copy()
        seg -= offset
        out[first : first + seg.shape[0]] = seg @ weights
        return last

    def bounds(c: int, e: int) -> tuple[np.ndarray, np.ndarray]:
        return kp_bounds(x[c:e], alpha, beta, h, None if widen is None else widen[c:e])

    B = _KP_WEIGHTED_BLOCK
    buf, other = np.empty((B, alpha.size)), np.empty((B, alpha.size))

    def ramp(into: np.ndarray, xs: np.ndarray, th: np.ndarray) -> np.ndarray:
        """:func:`kp_bounds`'s ``clip((xs - th) / h, 0, 1)``, written into ``into`` (the same values)."""
        np.subtract(xs[:, None], th, out=into)
        np.true_divide(into, h, out=into)
        np.maximum(into, 0.0, out=into)
        return np.minimum(into, 1.0, out=into)

    for a in range(0, x.size - 1, _KP_CHUNK):
        end = min(a + _KP_CHUNK + 1, x.size)
        starts = monotone_runs(x[a:end])
        if starts.size > max(8, _SCAN_ABOVE_RUN_FRACTION * (end - a)):  # the clamp scan, block by block
            for c in range(a + 1, end, B):
                lo, hi = bounds(c - 1, min(c + B, end))
                state = emit(c, _clamp_scan(lo, hi, state)[1:])
            continue
        for r1, r2 in _run_spans(starts, end - a):
            g1, g2 = a + r1, a + r2
            rising = x[g2 - 1] >= x[g1 - 1]
            if widen is None:  # the bound that binds, from the run's first clamp (as _kp_runs)
                lo, hi = bounds(g1, g1 + 1)
                first = np.minimum(np.maximum(state, lo[0]), hi[0])
                for c in range(g1, g2, B):
                    seg = ramp(buf[: min(c + B, g2) - c], x[c : min(c + B, g2)], alpha if rising else beta)
                    if rising:
                        np.maximum(first, seg, out=seg)
                    else:
                        np.minimum(first, seg, out=seg)
                    state = emit(c, seg)
                continue
            for c in range(g1, g2, B):  # widened: the running bound, checked (as _kp_widened_runs)
                e = min(c + B, g2)
                lo = ramp(buf[: e - c], x[c:e] - widen[c:e], alpha)
                hi = ramp(other[: e - c], x[c:e] + widen[c:e], beta)
                seg = lo if rising else hi
                seg[0] = np.minimum(np.maximum(state, lo[0]), hi[0])
                if rising:
                    np.maximum.accumulate(seg, axis=0, out=seg)
                    held = not np.any(seg > hi)
                else:
                    np.minimum.accumulate(seg, axis=0, out=seg)
                    held = not np.any(seg < lo)
                if not held:  # the opposite bound binds in this block: the scan, from its start state
                    lo, hi = bounds(c, e)
                    seg = _clamp_scan(np.concatenate([lo[:1], lo]), np.concatenate([hi[:1], hi]), state)[1:]
                state = emit(c, seg)
    return out


def _kp_widened(x, alpha, beta, h, s0, widen) -> np.ndarray:
    # thresholds that move with time: the bounds no longer follow x alone, so the general scan
    widen = np.asarray(widen, dtype=np.float64)
    if widen.shape != np.shape(x) or np.any(widen < 0) or not np.all(np.isfinite(widen)):
        raise ValueError(
            f"widen must be finite, non-negative and of the shape of x {np.shape(x)}, got shape {widen.shape}"
        )
    x, alpha, beta, out = _kp_start(x, alpha, beta, h, s0)
    if x.size == 0:
        return out
    out[0] = kp_initial_state(x[0], alpha + widen[0], beta - widen[0], h, s0)
    for a in range(0, x.size - 1, _KP_CHUNK):
        sl = slice(a, a + _KP_CHUNK + 1)
        seg = x[sl]
        starts = monotone_runs(seg)
        if starts.size <= max(8, _SCAN_ABOVE_RUN_FRACTION * seg.size):
            _kp_widened_runs(seg, alpha, beta, h, widen[sl], out[a : a + seg.size], starts)
        else:
            lo, hi = kp_bounds(seg, alpha, beta, h, widen[sl])
            out[a + 1 : a + lo.shape[0]] = _clamp_scan(lo, hi, out[a])[1:]
    return out


def _run_spans(starts: np.ndarray, n: int):
    """``(first, stop)`` of each monotone run of ``n`` samples starting at ``starts``, from sample 1
    on (sample 0 is the start state, set already); empty runs left out."""
    ends = np.append(starts, n)
    for a, b in zip(ends[:-1], ends[1:]):
        a1 = a if a > 0 else 1
        if a1 < b:
            yield int(a1), int(b)


def _kp_widened_runs(
    x: np.ndarray, alpha: np.ndarray, beta: np.ndarray, h: float, widen: np.ndarray, y: np.ndarray, starts: np.ndarray
) -> None:
    # thresholds that move with time: on a rising run of x the lower bound is no longer monotone
    # (the widening changes with the rate), so the state is the running maximum of it from the
    # run's first clamp, where the upper bound never binds; checked, and where it does bind (the
    # widening shrinking faster than x rises) that run alone is the clamp scan. Both select
    # values of :func:`kp_bounds`'s bounds: the scan's states to the bit.
    # ``y``: the states, row 0 the start (given), rows 1.. written
    for a1, b in _run_spans(starts, x.size):
        lo, hi = kp_bounds(x[a1:b], alpha, beta, h, widen[a1:b])
        start = y[a1 - 1]
        first = np.minimum(np.maximum(start, lo[0]), hi[0])[None]
        if x[b - 1] >= x[a1 - 1]:
            seg = np.maximum.accumulate(np.concatenate([first, lo[1:]]))
            held = not np.any(seg > hi)
        else:
            seg = np.minimum.accumulate(np.concatenate([first, hi[1:]]))
            held = not np.any(seg < lo)
        if held:
            y[a1:b] = seg
        else:  # the opposite bound binds somewhere on this run: the scan, from the run's start state
            y[a1:b] = _clamp_scan(np.concatenate([lo[:1], lo]), np.concatenate([hi[:1], hi]), start)[1:]


def _kp_runs(x: np.ndarray, alpha: np.ndarray, beta: np.ndarray, h: float, y: np.ndarray, starts: np.ndarray) -> None:
    # bounds that rise (fall) with x: on a rising run the state is the running max of the lower
    # bound from the run's first clamp (monotone in x, so a plain max), the upper bound never
    # binds; so each run makes only the bound that binds on it (:func:`kp_bounds`'s, to the bit).
    # ``y``: the states, row 0 the start (given), rows 1.. written
    for a1, b in _run_spans(starts, x.size):
        lo, hi = kp_bounds(x[a1 : a1 + 1], alpha, beta, h)
        first = np.minimum(np.maximum(y[a1 - 1], lo[0]), hi[0])
        rising = x[b - 1] >= x[a1 - 1]
        seg = y[a1:b]
        np.subtract(x[a1:b, None], alpha if rising else beta, out=seg)
        np.true_divide(seg, h, out=seg)
        np.maximum(seg, 0.0, out=seg)
        np.minimum(seg, 1.0, out=seg)
        if rising:
            np.maximum(first, seg, out=seg)
        else:
            np.minimum(first, seg, out=seg)


def _clamp_scan(lo: np.ndarray, hi: np.ndarray, start: np.ndarray) -> np.ndarray:
    # the two-level clamp scan over explicit bounds (rows 1.. of lo/hi)
    n, m = lo.shape
    steps = n - 1
    y = np.empty((n, m))
    y[0] = start
    if steps == 0:
        return y
    B, L, pad = _blocks(steps)
    los = np.concatenate([lo[1:], np.full((pad, m), -np.inf)]).reshape(B, L, m)
    his = np.concatenate([hi[1:], np.full((pad, m), np.inf)]).reshape(B, L, m)
    y[1:] = _two_level_scan(start, steps, B, L, lambda j: (los[:, j], his[:, j]))
    return y


def kp_loop(x: np.ndarray, alpha: np.ndarray, beta: np.ndarray, h: float, s0: np.ndarray | float = 0.0) -> np.ndarray:
    """Reference implementation: the per-sample clamp loop (slow; for tests)."""
    x, alpha, beta, out = _kp_start(x, alpha, beta, h, s0)
    if x.size == 0:
        return out
    state = out[0]
    for k in range(1, x.size):
        lo, hi = kp_bounds(x[k : k + 1], alpha, beta, h)
        state = np.minimum(np.maximum(state, lo[0]), hi[0])
        out[k] = state
    return out


# --------------------------------------------------------------------------- Duhem (Bouc-Wen, n = 1) elements
#
# The Bouc-Wen element of exponent 1 (Bouc 1967, Wen 1976; for piezo stacks Low & Guo, J. MEMS 1995,
# and Rakotondrabe, IEEE T-ASE 2011) in the scale where it saturates at ``+-r``: its state ``e``
# follows
#
#     de = dx - |dx| e / r,
#
# a Duhem model: along a motion of one direction ``e`` approaches ``+-r`` exponentially in the
# input, ``e(x) = +-r + (e(x0) -+ r) exp(-|x - x0| / r)``, so its slope is ``1 -+ e / r`` in [0, 2]:
# steepest just after a reversal, flat once saturated. Unlike the play and the hysteron its minor
# loops do not close, and their shape depends on where they sit. Each sample is a motion of one
# direction from the previous one, so the sampled element is the affine recurrence
#
#     e[k] = a_k e[k-1] + b_k,   a_k = exp(-|dx_k| / r),   b_k = sign(dx_k) r (1 - a_k),
#
# which is evaluated exactly and vectorised as ``e[k] = exp(-S_k / r) (e_0 + sum_i b_i exp(S_i / r))``
# with ``S`` the input's running total variation, in blocks over which ``S / r`` grows by at most
# :data:`_DUHEM_BLOCK` (so no exponential overflows).

#: The most the decay exponent ``S / r`` grows within one block of the Duhem evaluation.
_DUHEM_BLOCK = 300.0


def _as_widths(r: np.ndarray | float) -> np.ndarray:
    r = np.atleast_1d(np.asarray(r, dtype=np.float64))
    if r.ndim != 1 or not np.all(np.isfinite(r)) or np.any(r <= 0):
        raise ValueError(f"Duhem element widths must be a 1-D array of finite positive values, got {r}")
    return r


def duhem(
    x: np.ndarray, r: np.ndarray | float, e0: np.ndarray | float = 0.0, x_prev: float | None = None
) -> np.ndarray:
    """Duhem (Bouc-Wen, exponent 1) elements of saturation widths ``r`` driven by ``x``.

    ``e0``: the elements' states at the previous input ``x_prev`` (default ``x[0]``: the first
    sample does not move them). Returns the states after each sample, shape ``(len(x), len(r))``;
    chaining chunks (the last row as ``e0``, the last input as ``x_prev``) equals one call.
    """
    x = np.asarray(x, dtype=np.float64)
    r = _as_widths(r)
    if x.ndim != 1:
        raise ValueError(f"the input must be 1-D, got shape {x.shape}")
    e_start = np.broadcast_to(np.asarray(e0, dtype=np.float64), r.shape).copy()
    out = np.empty((x.size, r.size))
    if x.size == 0:
        return out
    dx = np.diff(x, prepend=x[0] if x_prev is None else float(x_prev))
    step = np.abs(dx)
    S = np.cumsum(step)
    for j, rj in enumerate(r):
        b = np.sign(dx) * rj * -np.expm1(-step / rj)
        rel = S / rj
        e, a, before = e_start[j], 0, 0.0
        while a < x.size:
            # samples a..c-1: their exponents within _DUHEM_BLOCK of the block's first
            c = max(a + 1, int(np.searchsorted(rel, rel[a] + _DUHEM_BLOCK, side="right")))
            m = rel[a]
            seg = rel[a:c]
            out[a:c, j] = np.exp(before - seg) * e + np.exp(m - seg) * np.cumsum(b[a:c] * np.exp(seg - m))
            e, before, a = out[c - 1, j], rel[c - 1], c
    return out


def duhem_along(u: np.ndarray, r: np.ndarray, e0: np.ndarray, u0: float, rising: bool) -> np.ndarray:
    """The elements' states at the inputs ``u`` reached by one motion from ``u0`` (in the
    direction ``rising``) with states ``e0`` there: ``(len(u), len(r))``, the closed form of
    :func:`duhem` along a monotone motion."""
    u = np.asarray(u, dtype=np.float64)[:, None]
    sat = r if rising else -r
    return sat + (e0 - sat) * np.exp(-np.abs(u - u0) / r)


def duhem_slope_along(u: np.ndarray, r: np.ndarray, e0: np.ndarray, u0: float, rising: bool) -> np.ndarray:
    """``d e / d u`` along the motion of :func:`duhem_along` (in [0, 2] for states within ``+-r``)."""
    e = duhem_along(u, r, e0, u0, rising)
    return 1.0 - e / r if rising else 1.0 + e / r
