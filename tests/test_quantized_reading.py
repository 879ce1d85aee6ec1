"""A reading coarser than its noise: the floor of its averages.

A 12-bit input reading a load cell in steps of 0.49 N with 0.07 N of noise (the thesis's
PCI-DAS1001, the virtual rig's input) is under-dithered: a level held still reads as the same
step every time, and averaging does not bring its error down as the white noise's would. The
slow judging (a drift, a log creep, a stroke kept at rest) compares cycle averages of held
steps and rest runs against a floor; with the white noise's floor divided by the root of the
samples averaged, a wander of 0.1-0.2 N that is the quantizer's was judged 50 times the floor,
and a drifting sensitivity read through it was named beside a log creep or an offset drift
(virtual rig, seeds 7, 12, 15 and 18 of 20).

The readings here are quantized with numpy (``np.round(y / q) * q``), not with the rig's code.
"""

from __future__ import annotations

import numpy as np
import pytest

from piezopress.analysis.diagnosis.residuals import average_floor, noise_floor, noise_under_steps, quantum


def _averages_error(level: np.ndarray, noise: float, q: float, n: int, rng: np.random.Generator) -> float:
    """RMS over many draws of the error of an ``n``-sample average of ``level`` read with
    ``noise`` through a quantizer of step ``q`` (0: none), and one such reading."""
    errs = []
    for _ in range(200):
        shift = rng.uniform(0.0, q or 1.0)  # where the level sits between two steps
        y = level + shift + rng.normal(0.0, noise, level.size)
        if q:
            y = np.round(y / q) * q
        errs.append(np.mean(y[:n]) - np.mean(level[:n] + shift))
    return float(np.sqrt(np.mean(np.square(errs)))), y


@pytest.mark.parametrize(
    ("noise", "q", "under"),
    [(0.07, 0.49, True), (0.5, 0.49, False), (0.07, 0.0, False), (0.07, 0.01, False)],
)
def test_the_floor_of_a_still_levels_average_is_the_error_it_keeps(noise, q, under):
    rng = np.random.default_rng(3)
    n = 5000
    measured, y = _averages_error(np.full(n, 50.0), noise, q, n, rng)
    floor = average_floor(y, n)
    # within a factor 2 of the error the averages keep (measured over 200 draws of where the level sits)
    assert measured / 2.0 <= floor <= 2.0 * measured, (floor, measured)
    white = noise_floor(y) / np.sqrt(n)
    if under:  # the quantizer's error does not average: tens of times the white floor
        assert floor >= 5.0 * white
    else:  # a dithered or unquantized reading: the white floor
        assert floor == pytest.approx(white)


@pytest.mark.parametrize("noise", [0.07, 0.1, 0.15])
def test_the_noise_under_the_steps_is_read_where_it_reaches_a_step_either_side(noise):
    # a level at a step's centre, read with noise of 14-31 % of the 0.49 N step: three values
    rng = np.random.default_rng(6)
    y = np.round((49.98 + rng.normal(0.0, noise, 20_000)) / 0.49) * 0.49
    assert np.unique(y).size == 3
    assert noise_under_steps(y, 0.49) == pytest.approx(noise, rel=0.15)
    # two values say only that it is under a quarter step: the worst case (0)
    assert noise_under_steps(np.round((50.2 + rng.normal(0.0, 0.03, 20_000)) / 0.49) * 0.49, 0.49) == 0.0


def test_a_sweep_through_many_steps_averages_its_quantization_down():
    # a 0.1 Hz triangle over 300 N read in 0.49 N steps: a cycle's average visits ~1200 steps
    rng = np.random.default_rng(4)
    fs, n = 500.0, 5000
    t = np.arange(2 * n) / fs
    level = 150.0 * (1.0 - np.abs((t * 0.1) % 1.0 * 2.0 - 1.0)) + 50.0
    measured, y = _averages_error(level, 0.07, 0.49, n, rng)
    floor = average_floor(y, n)
    assert floor <= 0.15 * 0.49 / np.sqrt(12.0)  # far under a still level's q / sqrt(12)
    assert floor >= measured  # and not under the error the averages keep


def test_the_quantum_is_the_readings_step_or_none():
    rng = np.random.default_rng(5)
    y = rng.normal(0.0, 1.0, 10_000)
    assert quantum(y) == 0.0  # floating point: as many values as samples
    assert quantum(np.round(y / 0.25) * 0.25) == pytest.approx(0.25)
    fine = np.round(y / 0.005) * 0.005  # quantized, and dithered by its noise: the white floor
    assert quantum(fine) == pytest.approx(0.005)
    assert average_floor(fine, 1000) == pytest.approx(noise_floor(fine) / np.sqrt(1000))
