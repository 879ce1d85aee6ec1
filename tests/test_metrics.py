"""Metrics against synthetic signals with known answers (thesis Eqs. 5.1-5.3, Section 6.6).

Every tolerance states its reason. Noise is always drawn from a seeded Generator; the load
cell is modelled as 0.06 N of Gaussian noise followed by a 0.5 N quantizer.
"""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import brentq
from scipy.signal import lfilter

from piezopress.analysis.metrics import (
    creep,
    find_reversals,
    max_hysteresis,
    overshoot,
    staircase_plateaus,
    tracking_error,
)
from piezopress.errors import MetricError

Q_N = 0.5  # load-cell quantization step
NOISE_N = 0.06  # load-cell noise std

# hypothesis: an affine map of the output y -> a*y + b, both signs of a
scales = st.one_of(st.floats(0.01, 100.0), st.floats(-100.0, -0.01))
offsets = st.floats(-1000.0, 1000.0)


def load_cell(y, rng):
    return np.round((y + rng.normal(0.0, NOISE_N, y.size)) / Q_N) * Q_N


# ---------------------------------------------------------------------------------------
# Hysteresis: an exact parallelogram loop from a play (backlash) operator
# ---------------------------------------------------------------------------------------


def triangle(peaks, n_half, low=0.0):
    """low -> peak -> low for each peak, with a sample exactly on every corner."""
    parts = [np.array([low])]
    for p in peaks:
        parts += [np.linspace(low, p, n_half + 1)[1:], np.linspace(p, low, n_half + 1)[1:]]
    return np.concatenate(parts)


def play(x, r):
    """Play operator of half-width r from y = 0: branches x - r (up) and x + r (down)."""
    y = np.empty_like(x)
    prev = 0.0
    for i, xi in enumerate(x):
        prev = min(max(prev, xi - r), xi + r)
        y[i] = prev
    return y


# y = A*x + B*play(x, R): the gap between the branches is 2BR wherever both are linear; the
# output runs from B*R (at x = 0 after the first cycle) to (A+B)*p_max - B*R.
A, B, R, VMAX = 1.4, 0.6, 14.0, 150.0


def press(x):
    return A * x + B * play(x, R)


def play_percent(p_max, low=0.0):
    return 100.0 * 2 * B * R / ((A + B) * (p_max - low) - 2 * B * R)


def test_hysteresis_exact_parallelogram_loop():
    x = triangle([VMAX] * 4, 500)
    r = max_hysteresis(x, press(x))
    # Both branches are linear where the gap is largest, so bin averaging and interpolation
    # are exact; only float rounding remains.
    assert r.percent == pytest.approx(play_percent(VMAX), abs=1e-9)
    assert r.max_gap == pytest.approx(2 * B * R, abs=1e-9)
    assert r.output_range == pytest.approx((A + B) * VMAX - 2 * B * R, abs=1e-9)
    assert r.descending_at_max - r.ascending_at_max == pytest.approx(2 * B * R, abs=1e-9)
    assert 2 * R <= r.x_at_max <= VMAX - 2 * R  # where both branches are linear
    assert r.n_cycles == 3  # 4 descents, but only 3 ascents once the virgin one is dropped
    assert r.reversals.size == 7


def test_hysteresis_independent_of_bin_count_for_linear_branches():
    # Linear branches: the bin count does not matter as long as a bin is narrower than the
    # flat stretch (2R = 28 V) at the loop's corners; a bin straddling a corner mixes the flat
    # and the sloped part, which is the method's one-bin resolution (8 bins: +0.01 pp).
    x = triangle([VMAX] * 2, 400)
    y = press(x)
    got = [max_hysteresis(x, y, n_bins=n).percent for n in (12, 20, 50, 200)]
    np.testing.assert_allclose(got, play_percent(VMAX), rtol=0, atol=1e-9)


def test_hysteresis_ellipse_sine_bipolar():
    # x = A sin(th), y = k x - h cos(th): branches k x -/+ h sqrt(1 - (x/A)^2), gap 2h at x = 0,
    # output amplitude sqrt((kA)^2 + h^2), so percent = 100 h / sqrt((kA)^2 + h^2).
    amp, k, h = 100.0, 2.0, 12.0
    th = np.linspace(0, 5 * 2 * np.pi, 5 * 4000, endpoint=False)
    x = amp * np.sin(th)
    y = k * x - h * np.cos(th)
    r = max_hysteresis(x, y)
    # The branches are curved: the grid misses x = 0 by at most half a bin (gap error
    # ~ h (w/2A)^2 ~ 2e-4 h) and interpolating the curved branches adds the same order.
    assert r.percent == pytest.approx(100 * h / math.hypot(k * amp, h), abs=5e-3)
    assert abs(r.x_at_max) <= 2 * amp / 50  # within a bin of the centre
    assert r.descending_at_max - r.ascending_at_max == pytest.approx(r.max_gap)  # y lags x
    assert r.n_cycles == 5


def test_hysteresis_bipolar_triangle():
    low = -VMAX
    x = triangle([VMAX] * 3, 600, low=low)
    x = np.concatenate([np.linspace(0, low, 301)[:-1], x])  # start from 0, first go down
    r = max_hysteresis(x, press(x))
    # Exact as in the unipolar case: the branches are linear around the middle.
    assert r.percent == pytest.approx(play_percent(VMAX, low), abs=1e-9)


@pytest.mark.parametrize("peaks", [[80, 100, 120, 150], "random"])
def test_hysteresis_varying_amplitudes(peaks):
    if isinstance(peaks, str):
        peaks = np.random.default_rng(3).uniform(75, VMAX, 6)
        peaks[2] = VMAX
    x = triangle(peaks, 500)
    r = max_hysteresis(x, press(x))
    # A play loop has the same gap 2BR in every cycle over 2R <= x <= peak - 2R, so where all
    # cycles overlap (bins inside 28..47 V) the averaged gap is exactly 2BR; the range is the
    # largest cycle's. Exact as above.
    assert r.percent == pytest.approx(play_percent(max(peaks)), abs=1e-9)
    assert r.n_cycles == len(peaks) - 1


def test_hysteresis_with_load_cell_noise_and_quantization():
    rng = np.random.default_rng(11)
    x = triangle([VMAX] * 5, 10_000)
    y = press(x)
    clean = max_hysteresis(x, y)
    noisy = max_hysteresis(x, load_cell(y, rng))
    # 0.1 percentage point (brief): each bin mean averages ~2000 samples, so noise and the
    # quantizer's sawtooth (a bin spans ~12 quanta) shift a branch mean by < 0.05 N of 283 N.
    assert noisy.percent == pytest.approx(clean.percent, abs=0.1)
    # The range from averaged extremes: within one quantization step of the exact range.
    assert noisy.output_range == pytest.approx(clean.output_range, abs=Q_N)


def test_hysteresis_noisy_input_makes_no_fake_reversals():
    rng = np.random.default_rng(5)
    x_true = triangle([VMAX] * 4, 3000)
    x = x_true + rng.normal(0, 0.005 * VMAX, x_true.size)  # 0.75 V of noise on the drive
    r = max_hysteresis(x, press(x_true))
    assert r.reversals.size == 7  # exactly the true turning points
    assert r.n_cycles == 3
    # In the linear middle the blur of the bins is symmetric, so each branch mean is unbiased
    # but scattered: the output seen against a noisy input deviates by (A+B)*sigma_x per
    # sample, so the gap of a bin (n = 3 cycles * 3000/50 samples per branch) has a std of
    # (A+B)*sigma_x*sqrt(2/n) = 0.16 N; the largest of ~50 bins stays within 4 of those.
    n = 3 * 3000 / 50
    tol_n = 4 * (A + B) * 0.005 * VMAX * math.sqrt(2 / n)
    assert r.percent == pytest.approx(play_percent(VMAX), abs=100 * tol_n / r.output_range)


def test_hysteresis_drops_the_virgin_curve():
    x = triangle([VMAX] * 3, 500)
    y = press(x)
    first = np.arange(x.size) < 500  # the virgin rise, up to (not including) the first peak
    y_bad = np.where(first, y + 30.0, y)  # a virgin curve far from the loop
    assert max_hysteresis(x, y_bad).percent == pytest.approx(play_percent(VMAX), abs=1e-9)
    assert max_hysteresis(x, y_bad, skip_first_half_cycle=False).percent != pytest.approx(play_percent(VMAX), abs=1)


@settings(max_examples=40, deadline=None)
@given(a=scales, b=offsets)
def test_hysteresis_percent_invariant_to_output_offset_and_scale(a, b):
    x = triangle([VMAX] * 3, 200)
    y = load_cell(press(x), np.random.default_rng(2))
    # Means and ranges are affine-equivariant; only float rounding differs.
    assert max_hysteresis(x, a * y + b).percent == pytest.approx(max_hysteresis(x, y).percent, rel=1e-9)


def test_find_reversals_on_sine():
    th = np.linspace(0, 4 * np.pi, 801)
    rev = find_reversals(np.sin(th))
    np.testing.assert_array_equal(rev, [100, 300, 500, 700])  # the 4 extrema of 2 periods


@pytest.mark.parametrize(
    "x, y, match",
    [
        (np.arange(5.0), np.arange(5.0), "has 5 sample"),
        (np.arange(10.0), np.arange(11.0), "x has 10 samples but y has 11"),
        (np.arange(20.0), np.arange(20.0), "no reversal"),
        (triangle([1, 1], 10), np.ones(41), "y is flat"),
        (triangle([1, 1], 10), np.r_[np.nan, np.ones(40)], "NaN"),
        (np.zeros(20), np.arange(20.0), "x is constant"),
        (triangle([1], 10), triangle([1], 10), "only descending"),
    ],
)
def test_hysteresis_rejects_unsuitable_signals(x, y, match):
    with pytest.raises(MetricError, match=match):
        max_hysteresis(x, y)


def test_hysteresis_rejects_bad_bin_count():
    x = triangle([1, 1], 10)
    with pytest.raises(MetricError, match="n_bins is 2"):
        max_hysteresis(x, x, n_bins=2)


# ---------------------------------------------------------------------------------------
# Creep: fast first-order rise plus a slow first-order drift
# ---------------------------------------------------------------------------------------

FS_CREEP = 1000.0
T_STEP = 1.0
F0, FAST, SLOW, TAU_FAST, TAU_SLOW = 50.0, 240.0, 8.0, 0.01, 20.0


def creep_force(t):
    tau = np.clip(t - T_STEP, 0, None)
    return F0 + FAST * (1 - np.exp(-tau / TAU_FAST)) + SLOW * (1 - np.exp(-tau / TAU_SLOW))


def creep_run(hold_s=20.0, back_s=0.0):
    t = np.arange(int((T_STEP + hold_s + back_s) * FS_CREEP)) / FS_CREEP
    drive = np.where((t >= T_STEP) & (t < T_STEP + hold_s), 150.0, 0.0)
    y = creep_force(t)
    y[t >= T_STEP + hold_s] = F0 + 3.0  # stepped back
    return t, y, drive


def creep_expected(hold_s, after=1.0, final_window=0.1):
    f_ss = float(creep_force(np.array([T_STEP + after]))[0])
    # The final window's mean equals the value at its centre for a smooth drift.
    f_f = float(creep_force(np.array([T_STEP + hold_s - final_window / 2]))[0])
    return 100 * (f_f - f_ss) / (f_ss - F0), 100 * (f_f - f_ss) / f_ss


@pytest.mark.parametrize("how", ["step_time_s", "drive", "output"])
def test_creep_first_order_known_values(how):
    t, y, drive = creep_run()
    kw = {"step_time_s": T_STEP} if how == "step_time_s" else {"drive": drive} if how == "drive" else {}
    r = creep(t, y, **kw)
    hold_s = t[-1] - T_STEP
    pct, pct_reading = creep_expected(hold_s)
    # Window means differ from the centre values only by the drift's curvature,
    # SLOW * (w / TAU_SLOW)^2 / 24 ~ 1e-5 N, and by a sample of placement (~1e-4 N).
    assert r.percent == pytest.approx(pct, abs=1e-3)
    assert r.percent_of_reading == pytest.approx(pct_reading, abs=1e-3)
    assert r.baseline == pytest.approx(F0, abs=1e-9)
    assert r.t_ss_s == 1.0
    assert r.located_by == how
    # Located from the output, the step time is the last sample before 10 % of the rise,
    # which this response reaches 1.05 ms (one sample) after the step.
    assert r.step_time_s == pytest.approx(T_STEP, abs=1.5 / FS_CREEP)
    assert r.hold_s == pytest.approx(t[-1] - r.step_time_s, abs=1e-9)


@pytest.mark.parametrize("with_drive", [True, False])
def test_creep_hold_ends_at_the_step_back(with_drive):
    t, y, drive = creep_run(hold_s=10.0, back_s=2.0)
    r = creep(t, y, drive=drive if with_drive else None)
    if with_drive:
        # The drive marks the end of the hold exactly.
        assert r.hold_s == pytest.approx(10.0 - 1 / FS_CREEP, abs=1e-9)
        assert r.percent == pytest.approx(creep_expected(r.hold_s)[0], abs=1e-3)
    else:
        # Detected from the output, the hold ends up to half a detector window (1/100 of
        # the record) early; the drift over that is 8 N * 0.12 s / 20 s * e^-0.5.
        assert 10.0 - 0.15 < r.hold_s < 10.0
        assert r.percent == pytest.approx(creep_expected(r.hold_s)[0], abs=1e-3)


def test_creep_downward_step():
    t, y, drive = creep_run()
    r_up = creep(t, y, drive=drive)
    r_down = creep(t, 400.0 - y, drive=drive)
    # Relative to the step, a mirrored run creeps by the same percentage (float rounding only).
    assert r_down.percent == pytest.approx(r_up.percent, rel=1e-9)
    assert r_down.step_size == pytest.approx(-r_up.step_size, rel=1e-9)


def test_creep_with_load_cell():
    t, y, drive = creep_run()
    r = creep(t, load_cell(y, np.random.default_rng(4)), drive=drive)
    pct, _ = creep_expected(t[-1] - T_STEP)
    # Noise of 0.06 N barely dithers a 0.5 N quantizer, so each window mean can be off by up
    # to half a step: F_f - F_ss by up to one step, i.e. 100 * 0.5 / 240 = 0.21 pp.
    assert r.percent == pytest.approx(pct, abs=100 * Q_N / FAST)


@settings(max_examples=30, deadline=None)
@given(a=scales, b=offsets)
def test_creep_percent_invariant_to_output_offset_and_scale(a, b):
    t, y, drive = creep_run(hold_s=3.0)
    y = load_cell(y, np.random.default_rng(8))
    ref = creep(t, y, drive=drive).percent
    # Window means are affine-equivariant; only float rounding differs.
    assert creep(t, a * y + b, drive=drive).percent == pytest.approx(ref, rel=1e-9)
    assert creep(t, a * y + b).percent == pytest.approx(creep(t, y).percent, rel=1e-9)


def test_creep_rejects_a_run_that_ends_too_soon():
    t, y, _ = creep_run(hold_s=0.8)
    with pytest.raises(MetricError, match=r"hold lasts 0.799 s .*\(steady_state_after_s=1 "):
        creep(t, y, step_time_s=T_STEP)


@pytest.mark.parametrize(
    "y, kw, match",
    [
        (np.full(3000, 50.0), {}, "y is flat"),
        (50 + np.random.default_rng(0).normal(0, 0.06, 3000), {}, "no step found in y"),
        (creep_force(np.arange(3000) / FS_CREEP), {"drive": np.zeros(3000)}, "drive has no step"),
        (creep_force(np.arange(3000) / FS_CREEP), {"drive": np.zeros(10)}, "y has 3000 samples but drive has 10"),
        (creep_force(np.arange(3000) / FS_CREEP), {"step_time_s": 0.001}, "only 1 sample.* of baseline"),
        (creep_force(np.arange(3000) / FS_CREEP), {"steady_state_after_s": -1}, "steady_state_after_s is -1"),
        (np.r_[creep_force(np.arange(2999) / FS_CREEP), np.inf], {}, "y has 1 NaN/infinite value"),
    ],
)
def test_creep_rejects_unsuitable_signals(y, kw, match):
    t = np.arange(3000) / FS_CREEP
    with pytest.raises(MetricError, match=match):
        creep(t, y, **kw)


# ---------------------------------------------------------------------------------------
# Steps: the thesis's identified second-order model (Eq. 6.2)
# ---------------------------------------------------------------------------------------

FS = 20_000.0
DT = 1 / FS
WN, ZETA = 6.4e3, 0.115
K_STEP = 200  # step at 10 ms
MP = math.exp(-math.pi * ZETA / math.sqrt(1 - ZETA**2))  # analytic overshoot fraction


def s2(tau):
    tau = np.clip(tau, 0, None)
    wd = WN * math.sqrt(1 - ZETA**2)
    return 1 - np.exp(-ZETA * WN * tau) * (np.cos(wd * tau) + ZETA / math.sqrt(1 - ZETA**2) * np.sin(wd * tau))


def exact_settling(frac=0.02):
    """Last time |s2 - 1| = frac, found on a 0.1 us grid and refined."""
    tau = np.linspace(0, 0.02, 200_001)
    out = np.flatnonzero(np.abs(s2(tau) - 1) > frac)[-1]
    return brentq(lambda x: abs(float(s2(np.array([x]))[0]) - 1) - frac, tau[out], tau[out + 1])


def exact_crossing(level):
    tau = np.linspace(0, 0.001, 100_001)
    i = np.flatnonzero(s2(tau) >= level)[0]
    return brentq(lambda x: float(s2(np.array([x]))[0]) - level, tau[i - 1], tau[i])


def step_run(size=20.0, base=50.0, hold_s=0.05, back_s=0.0):
    n_hold, n_back = int(hold_s * FS), int(back_s * FS)
    k = np.arange(K_STEP + n_hold + n_back)
    t = k * DT
    tau = t - K_STEP * DT
    y = base + size * s2(tau)
    drive = np.where((k >= K_STEP) & (k < K_STEP + n_hold), 20.0, 0.0)
    if n_back:  # step back: superpose a negative step at the end of the hold
        y -= size * s2(tau - n_hold * DT)
    return t, y, drive


# The sampled peak can miss the true one by half a sample; at the peak |y''| <= wn^2 Mp /
# sqrt(1 - zeta^2) per unit step, so the overshoot can be low by up to this (pp).
PEAK_TOL_PP = 100 * 0.5 * WN**2 * (DT / 2) ** 2 * MP / math.sqrt(1 - ZETA**2)


@pytest.mark.parametrize("size", [20.0, -20.0])
def test_overshoot_second_order_analytic(size):
    t, y, drive = step_run(size=size)
    r = overshoot(t, y, drive=drive)
    assert r.percent == pytest.approx(100 * MP, abs=PEAK_TOL_PP)
    assert r.percent <= 100 * MP  # a sampled peak never exceeds the true one
    assert r.steady_state == pytest.approx(50 + size, abs=1e-9)  # ringing is e^-29 by then
    assert r.percent_of_reading == pytest.approx(100 * (r.peak - r.steady_state) / r.steady_state, rel=1e-12)
    assert r.step_time_s == pytest.approx(K_STEP * DT, abs=1e-12)
    # Settling and rise are interpolated between samples: a tenth of a sample covers the
    # curvature of the response over one sample.
    assert r.settled
    assert r.settling_time_s == pytest.approx(exact_settling(), abs=0.1 * DT)
    assert r.rise_time_s == pytest.approx(exact_crossing(0.9) - exact_crossing(0.1), abs=0.1 * DT)
    # The peak is sampled within half a sample of pi / wd.
    assert r.peak_time_s == pytest.approx(math.pi / (WN * math.sqrt(1 - ZETA**2)), abs=0.5 * DT)
    assert r.significant and not r.band_below_noise


def test_overshoot_located_three_ways_agree():
    t, y, drive = step_run(back_s=0.03)
    by_drive = overshoot(t, y, drive=drive)
    by_time = overshoot(t, y, step_time_s=K_STEP * DT)
    by_output = overshoot(t, y)
    assert (by_drive.located_by, by_time.located_by, by_output.located_by) == ("drive", "step_time_s", "output")
    # Same F_ss (the step back is excluded every way) and same peak: same overshoot.
    assert by_time.percent == pytest.approx(by_drive.percent, abs=1e-9)
    assert by_output.percent == pytest.approx(by_drive.percent, abs=1e-6)
    assert by_drive.hold_s == pytest.approx(0.05 - DT, abs=1e-12)
    # From the output alone the step time is the last sample before 10 % of the rise, which a
    # second-order response reaches ~1.4 samples after the true step.
    assert 0 <= by_output.step_time_s - K_STEP * DT <= 2 * DT


def test_overshoot_shaped_drive_is_one_step():
    # The thesis's 5-impulse shaper (Table 6.8): the drive climbs in 5 steps within 3.9 ms.
    amps = np.array([0.0283, 0.1627, 0.3511, 0.3368, 0.1211])
    delays = np.round(np.array([0, 0.0982, 2, 2.9, 3.9]) * 1e-3 * FS).astype(int)
    t, _, _ = step_run()
    k = np.arange(t.size)
    drive = sum(20.0 * a * (k >= K_STEP + d) for a, d in zip(amps, delays))
    y = 50.0 + sum(20.0 * a * s2(t - (K_STEP + d) * DT) for a, d in zip(amps, delays))
    r = overshoot(t, y, drive=drive)
    # The intermediate plateaus (< 2 ms) are shorter than min_hold_s: one step from the first
    # impulse, and the same answer as naming the step time.
    assert r.step_time_s == pytest.approx(K_STEP * DT, abs=1e-12)
    assert r.percent == pytest.approx(overshoot(t, y, step_time_s=K_STEP * DT).percent, abs=1e-9)
    assert r.percent < 100 * MP / 2  # the shaper removes most of the overshoot


@pytest.mark.parametrize("size, below", [(20.0, True), (200.0, False)])
def test_overshoot_with_load_cell(size, below):
    t, y, drive = step_run(size=size)
    r = overshoot(t, load_cell(y, np.random.default_rng(9)), drive=drive)
    # The peak is one sample: it carries up to a quantization step plus a noise peak, and F_ss
    # is a mean within half a step; so the error is at most (Q + 5 sigma) / size (+ sampling).
    assert r.percent == pytest.approx(100 * MP, abs=100 * (Q_N + 5 * NOISE_N) / size + PEAK_TOL_PP)
    assert r.significant
    assert r.resolution == pytest.approx(Q_N)
    # 2 % of 20 N is 0.4 N, below 3 quantization-noise floors (3 * 0.5 / sqrt(12) = 0.43 N).
    assert r.band_below_noise is below


def test_overshoot_not_significant_without_overshoot():
    # First order, no overshoot; levels off the quantization grid so the quantizer toggles.
    t = np.arange(3000) * DT
    y = 50.2 + 100.03 * (1 - np.exp(-np.clip(t - K_STEP * DT, 0, None) / 1e-3))
    r = overshoot(t, load_cell(y, np.random.default_rng(1)), step_time_s=K_STEP * DT)
    assert not r.significant
    assert abs(r.percent) < 100 * Q_N / 100  # within one quantization step of the 100 N step


def test_overshoot_not_settled_when_the_hold_is_too_short():
    t, y, _ = step_run(hold_s=0.002)
    r = overshoot(t, y, step_time_s=K_STEP * DT, ss_window_s=0.0005)
    assert not r.settled and math.isnan(r.settling_time_s)


@settings(max_examples=30, deadline=None)
@given(a=scales, b=offsets)
def test_overshoot_invariant_to_output_offset_and_scale(a, b):
    t, y, drive = step_run(hold_s=0.02)
    y = load_cell(y, np.random.default_rng(6))
    ref = overshoot(t, y, drive=drive)
    got = overshoot(t, a * y + b, drive=drive)
    # Means, extremes and band tests are affine-equivariant; only float rounding differs.
    assert got.percent == pytest.approx(ref.percent, rel=1e-9)
    assert got.settling_time_s == pytest.approx(ref.settling_time_s, rel=1e-9)
    assert got.rise_time_s == pytest.approx(ref.rise_time_s, rel=1e-9)


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"drive": np.zeros(1200)}, "drive has no step: found 1 hold"),
        ({"step_time_s": DT}, "only 1 sample.* of baseline"),
        ({"step_time_s": 1.0}, "step_time_s is 1.0; expected a time within the run"),
        ({"settle_fraction": 2.0}, "settle_fraction is 2.0"),
        ({"drive": np.zeros(5)}, "y has 1200 samples but drive has 5"),
    ],
)
def test_overshoot_rejects_unsuitable_input(kw, match):
    t, y, _ = step_run(hold_s=0.05)
    with pytest.raises(MetricError, match=match):
        overshoot(t, y, **kw)


def test_overshoot_rejects_noise_and_bad_time():
    t = np.arange(1000) * DT
    noise = load_cell(np.full(1000, 50.2), np.random.default_rng(0))
    with pytest.raises(MetricError, match="no step found in y"):
        overshoot(t, noise)
    with pytest.raises(MetricError, match="t_s is not strictly increasing at index 1"):
        overshoot(np.r_[0.0, 0.0, t[2:]], noise)


# ---------------------------------------------------------------------------------------
# Tracking: the thesis's staircase (10 N steps after 5 ms ramps)
# ---------------------------------------------------------------------------------------

FS_TRACK = 10_000.0
GAIN, OFFSET_N, TAU_LAG = 1.05, -2.0, 0.5e-3


def staircase(n_steps=10, step_n=10.0, ramp_s=0.005, plateau_s=0.05):
    n_ramp, n_plat = int(ramp_s * FS_TRACK), int(plateau_s * FS_TRACK)
    parts = [np.zeros(n_plat)]
    for i in range(n_steps):
        parts += [i * step_n + step_n * np.arange(1, n_ramp + 1) / n_ramp, np.full(n_plat - 1, (i + 1) * step_n)]
    ref = np.concatenate(parts)
    return np.arange(ref.size) / FS_TRACK, ref


def tracked(ref):
    """GAIN * ref + OFFSET through a first-order lag (exact discretisation)."""
    a = math.exp(-1 / (FS_TRACK * TAU_LAG))
    target = GAIN * ref + OFFSET_N
    return lfilter([1 - a], [1, -a], target - target[0]) + target[0]


def test_staircase_plateaus():
    _, ref = staircase(n_steps=2)
    p = staircase_plateaus(ref)
    assert [(q.start, q.stop, q.level) for q in p] == [(0, 500, 0.0), (549, 1049, 10.0), (1098, 1598, 20.0)]


def test_tracking_error_on_plateaus():
    t, ref = staircase()
    r = tracking_error(t, ref, tracked(ref))
    # On the plateaus the error is (GAIN - 1) * ref + OFFSET; the lag's ramp error has decayed
    # by e^-20 (2e-9 N) after the 10 ms settle margin.
    levels = np.arange(10.0, 101.0, 10.0)  # 0 N is below min_reference (5 N by default)
    err = (GAIN - 1) * levels + OFFSET_N
    assert r.max_error_n == pytest.approx(err.max(), abs=1e-6)
    assert r.min_error_n == pytest.approx(err.min(), abs=1e-6)
    assert r.max_relative_percent == pytest.approx(100 * (err / levels).max(), abs=1e-5)
    assert r.min_relative_percent == pytest.approx(100 * (err / levels).min(), abs=1e-5)
    assert r.max_abs_relative_percent == pytest.approx(15.0, abs=1e-5)
    assert r.min_reference == 5.0 and len(r.plateaus) == 10
    assert not r.mask[ref < 5.0].any()
    # No sample within settle_s of a plateau's start is evaluated.
    for p in r.plateaus:
        assert not r.mask[p.start : p.start + int(0.01 * FS_TRACK)].any()
        assert r.mask[p.start + int(0.01 * FS_TRACK) + 1 : p.stop].all()


def test_tracking_error_including_ramps_sees_the_lag():
    t, ref = staircase()
    y = tracked(ref)
    masked = tracking_error(t, ref, y)
    full = tracking_error(t, ref, y, exclude_ramps=False)
    # During a ramp the lag trails by tau * slope = 1 N on top of the plateau error.
    assert full.min_error_n < masked.min_error_n - 0.5
    assert full.n_samples > masked.n_samples and full.settle_s == 0.0


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"min_reference": 1000.0}, "no sample left to evaluate"),
        ({"settle_s": 1.0}, "no sample left to evaluate"),
        ({"min_reference": 0.0}, "min_reference is 0.0"),
    ],
)
def test_tracking_error_rejects_unsuitable_input(kw, match):
    t, ref = staircase(n_steps=2)
    with pytest.raises(MetricError, match=match):
        tracking_error(t, ref, ref, **kw)


def test_tracking_error_rejects_ramp_only_reference_and_mismatch():
    t = np.arange(100.0)
    with pytest.raises(MetricError, match="reference has no constant segment"):
        tracking_error(t, t + 1, t)
    with pytest.raises(MetricError, match="t_s has 100 samples but y has 99"):
        tracking_error(t, t, t[:-1])
