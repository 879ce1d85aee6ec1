"""Hysteresis operators: the vectorised play operator equals the per-sample loop of Eq. 3.1."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from piezopress import operators as op

finite = st.floats(-200, 200, allow_nan=False, allow_infinity=False)


@settings(max_examples=200, deadline=None)
@given(
    x=arrays(np.float64, st.integers(1, 120), elements=finite),
    r=arrays(np.float64, st.integers(1, 5), elements=st.floats(0, 100)),
    y0=finite,
)
def test_play_equals_loop_both_algorithms(x, r, y0):
    # Both algorithms are exact; only float rounding in max/min chains may differ (none expected).
    ref = op.play_loop(x, r, y0)
    ys = op.play_initial_state(x[0], r, y0)
    np.testing.assert_allclose(op._play_runs(x, r, ys, op.monotone_runs(x)), ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(op._play_scan(x, r, ys), ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(op.play(x, r, y0), ref, rtol=0, atol=1e-12)


@settings(max_examples=100, deadline=None)
@given(
    x=arrays(np.float64, st.integers(2, 200), elements=finite),
    split=st.integers(1, 199),
    r=arrays(np.float64, 3, elements=st.floats(0, 50)),
)
def test_chunked_with_state_equals_one_pass(x, split, r):
    # Carrying y[-1] of one chunk as y0 of the next must reproduce the single pass exactly.
    split = min(split, x.size - 1)
    whole = op.play(x, r)
    first = op.play(x[:split], r)
    second = op.play(x[split:], r, first[-1])
    np.testing.assert_array_equal(np.vstack([first, second]), whole)


def test_play_thesis_examples():
    # Eq. 3.1 by hand: r = 0.5 from y0 = 0
    y = op.play(np.array([0.0, 2.0, 1.0, 3.0, 2.8]), 0.5)[:, 0]
    assert y.tolist() == [0.0, 1.5, 1.5, 2.5, 2.5]
    # r = 0 is the identity
    x = np.random.default_rng(1).normal(size=50)
    np.testing.assert_array_equal(op.play(x, 0.0)[:, 0], x)


def test_play_rejects_bad_thresholds():
    with pytest.raises(ValueError, match="non-negative"):
        op.play(np.zeros(3), -1.0)


def test_large_noisy_input_uses_scan_and_matches_runs():
    # A noisy drive (every sample a reversal) goes through the scan; compare with the run loop.
    rng = np.random.default_rng(7)
    x = 75 + 75 * np.sin(np.linspace(0, 20, 20_000)) + rng.normal(0, 0.05, 20_000)
    r = np.linspace(0, 60, 8)
    ys = op.play_initial_state(x[0], r)
    assert op.monotone_runs(x).size > x.size / 64
    np.testing.assert_allclose(op.play(x, r), op._play_runs(x, r, ys, op.monotone_runs(x)), atol=1e-12)


def test_dead_zone_definition():
    y = np.array([-3.0, -1.0, 0.0, 1.0, 3.0])
    z = op.dead_zone(y, [-2.0, 0.0, 2.0])
    assert z[:, 0].tolist() == [-1.0, 0.0, 0.0, 0.0, 0.0]  # min(y + 2, 0)
    assert z[:, 1].tolist() == y.tolist()
    assert z[:, 2].tolist() == [0.0, 0.0, 0.0, 0.0, 1.0]  # max(y - 2, 0)


@settings(max_examples=200, deadline=None)
@given(
    x=arrays(np.float64, st.integers(1, 120), elements=finite),
    r=arrays(np.float64, st.integers(1, 4), elements=st.floats(0, 50)),
    data=st.data(),
)
def test_widened_play_equals_loop(x, r, data):
    # rate-dependent thresholds r + widen[k]: the run algorithm (when it applies) and the
    # scan must both reproduce the loop exactly
    widen = data.draw(arrays(np.float64, x.size, elements=st.floats(0, 20)))
    ref = op.play_loop(x, r, 0.0, widen)
    np.testing.assert_allclose(op.play(x, r, 0.0, widen), ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(
        op._play_scan(x, r, op.play_initial_state(x[0], r + widen[0]), widen), ref, rtol=0, atol=1e-12
    )
