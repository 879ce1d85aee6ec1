"""The rate dependence keys on its signature: a widening that changes with the drive rate
across the fast sweeps, not a widening that is the same at every fast rate.

Synthetic runs (no rig): triangles at 5-50 Hz from a known model, with the loop widened (a)
in proportion to the drive rate, or (b) by one amount whenever the drive moves (as a base
loop fitted at 0.1 Hz is off at every fast rate alike). Only (a) is a rate dependence.
"""

from dataclasses import replace

import numpy as np
import pytest

from piezopress.analysis import diagnosis as dg
from piezopress.analysis.hysteresis import PIModel, PreisachPlane

FS = 10_000.0
BASE = dg.Model(PIModel((0.0, 8.0, 25.0), (1.0, 0.5, 0.4), (0.0,), (1.2,), y0=20.0))


def triangles(model: dg.Model, noise: float, seed: int) -> list[dg.RunData]:
    rng = np.random.default_rng(seed)
    runs = []
    for f in (5.0, 10.0, 20.0, 50.0):
        t = np.arange(int(FS * min(2.0, 8 / f))) / FS
        x = 75.0 * (1 - np.abs(((t * f) % 1.0) * 2 - 1)) * 2  # 0-150 V triangles
        meta = {"protocol": {"freq_hz": f}}
        y = model.predict(dg.RunData("", "triangle", t, x, np.zeros_like(t), FS)) + rng.normal(0, noise, t.size)
        runs.append(dg.RunData(f"tri-{f:g}hz", "triangle", t, x, y, FS, meta=meta))
    return runs


@pytest.mark.parametrize("seed", [0, 1])
def test_a_widening_in_proportion_to_the_rate_is_named(seed):
    truth = replace(BASE, rate_v_per_kv_s=0.4)
    result = dg.diagnose(BASE, triangles(truth, 0.1, seed), causes=["rate_dependent_hysteresis"])
    assert [f.cause for f in result.findings] == ["rate_dependent_hysteresis"], result.summary
    assert result.findings[0].gain_pct >= 50.0


@pytest.mark.parametrize("seed", [0, 1])
def test_a_widening_the_same_at_every_fast_rate_is_not_a_rate_dependence(seed):
    # the thresholds widened by 1.2 V whenever the drive moves faster than 100 V/s: every fast sweep alike
    truth = replace(BASE, rate_v_per_kv_s=12.0, rate_saturation_v_per_s=100.0)
    runs = triangles(truth, 0.1, seed)
    # the misfit is there and large (a form saturating at the slowest rate would take it up) ...
    assert dg.rms(np.concatenate([r.y - BASE.predict(r) for r in runs])) > 10 * 0.1
    result = dg.diagnose(BASE, runs, causes=["rate_dependent_hysteresis"])
    # ... but it does not change with the rate: not named
    assert result.findings == [], result.summary


def _plane_base() -> dg.Model:
    plane = PreisachPlane.grid(-10.0, 160.0, 8)
    plane = plane.with_weights(np.random.default_rng(5).uniform(0.5, 1.0, plane.n_cells) * plane.width / 8)
    chain = {"drive_lowpass": (2 * np.pi * 1500.0, 0.7), "drive_delay_s": 1e-4}
    return dg.Model(PIModel((0.0,), (0.4,), (0.0,), (1.0,), y0=20.0, plane=plane), **chain)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_widening_is_found_on_a_preisach_plane_behind_a_chain_of_its_own(seed):
    # the loop mostly on a Preisach plane (the widening must reach its hysterons, not the
    # plays alone), the drive through a low-pass and a delay (the widening's effect is taken
    # on the drive the stack feels, not on the command: on the command the chain's lag was
    # read as a widening of the wrong sign, and nothing was named on the third test press)
    base = _plane_base()
    truth = replace(base, rate_v_per_kv_s=0.4)
    result = dg.diagnose(base, triangles(truth, 0.1, seed), causes=["rate_dependent_hysteresis"])
    assert [f.cause for f in result.findings] == ["rate_dependent_hysteresis"], result.summary
    (f,) = result.findings
    assert f.gain_pct >= 50.0
    assert 0.3 <= f.parameters["rate_v_per_kv_s"] <= 0.5, f.parameters


def test_a_chain_of_its_own_is_not_taken_for_a_rate_dependence():
    base = _plane_base()
    result = dg.diagnose(base, triangles(base, 0.1, 2), causes=["rate_dependent_hysteresis"])
    assert result.findings == [], result.summary


def _viscous_lag(runs: list[dg.RunData], model: dg.Model, k: float, noise: float, seed: int) -> list[dg.RunData]:
    """``runs`` through a viscous lag in the square root of the rate, written here with numpy (not
    the diagnosis's rate terms): the stack feels ``x - k sign(r) sqrt(|r|)``, ``r`` the drive's
    derivative through a first-order lag of 1 ms."""
    rng = np.random.default_rng(seed)
    out = []
    for r in runs:
        rate = np.zeros_like(r.x)
        d = np.diff(r.x, prepend=r.x[0]) * FS
        a = np.exp(-1.0 / (FS * 1e-3))
        for i in range(1, d.size):
            rate[i] = a * rate[i - 1] + (1 - a) * d[i]
        seen = r.x - k * np.sign(rate) * np.sqrt(np.abs(rate))
        out.append(replace(r, y=model.predict(replace(r, x=seen)) + rng.normal(0, noise, r.x.size)))
    return out


@pytest.mark.parametrize("seed", [0, 1])
def test_a_lag_in_the_square_root_of_the_rate_is_drawn_at_every_rate(seed):
    # a widening saturating at 2 kV/s, fitted across 5-100 Hz, doubled the widening at 5-10 Hz
    # on the third test press (its compensated 10 Hz loop 1.28 -> 3.39 %): the law found must
    # draw the lag at each sweep's rate, and at a rate slower than any it was fitted on (the
    # compensator plays it at every rate). The saturating forms leave 0.21 of the lag at 5 Hz
    # and 0.64 at 1 Hz; the square root 0.17 and 0.26.
    k = 0.05  # V per sqrt(V/s): 2.7 V at the 5 Hz triangles' 3 kV/s, 8.7 V at 50 Hz, 1.2 V at 1 Hz
    result = dg.diagnose(
        BASE, _viscous_lag(triangles(BASE, 0.0, seed), BASE, k, 0.1, seed), causes=["rate_dependent_hysteresis"]
    )
    assert [f.cause for f in result.findings] == ["rate_dependent_hysteresis"], result.summary
    (f,) = result.findings
    t = np.arange(int(3 * FS)) / FS
    slow = dg.RunData("tri-1hz", "triangle", t, 150.0 * (1 - np.abs((t % 1.0) * 2 - 1)), np.zeros_like(t), FS)
    for r in _viscous_lag([*triangles(BASE, 0.0, seed), slow], BASE, k, 0.0, seed):  # noise-free
        steady = slice(r.x.size // 4, None)  # past the first period
        left = dg.rms((r.y - f.model.predict(r))[steady]) / dg.rms((r.y - BASE.predict(r))[steady])
        assert left <= (0.4 if r.name == "tri-1hz" else 0.2), (r.name, left, f.parameters)
