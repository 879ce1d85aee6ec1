"""A logarithmic creep's size is its tail's: the elements fitted beside the tail do not count.

The extension of ``logarithmic_creep`` fits Kelvin-Voigt elements (from a grid reaching ten
records) beside its log tail on the hold. Where the press's own creep spreads over the decades of
the hold and ends within the next one (the third test press: a Prony series to 300 s) and the
base's poles end sooner, an element slower than the hold takes part of that creep and rises over
the decade after the hold with nothing in the hold to pin it. Counted in the finding's size, it
named a log creep on the third press's input delay seed 18 (0.41 % beyond the model, 0.39 % of
it the tail's) and slew-limited seed 5 (0.41 and 0.35 %). The size is now at most what the tail
alone draws there: a documented log creep keeps its name (its tail alone rises 0.60-1.82 % on the
third press's seeds 0-9).

The press here is simulated by its own Prony series, not by the code under test; the base's
poles are set by hand where ``fit --base`` put them on the third press (ending by 35 s).
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from test_log_creep_size import PI, runs_of  # the loop; a 120 s hold, a rest and a slow triangle, with noise

from piezopress.analysis import creep as C
from piezopress.analysis import diagnosis as dg
from piezopress.analysis.diagnosis.causes.logarithmic_creep import (
    LOG_CREEP_MIN_PER_DECADE,
    cause_logarithmic_creep,
)

#: the base's creep: two poles ending by 35 s
POLES = C.CreepModel("kv", 0.983, (35.0, 1.5), (0.010, 0.007))


def _press(share: float, log_per_decade: float = 0.0) -> dg.Model:
    """A press whose creep is ``share`` of the step spread over time constants two per decade
    from 10 ms to 300 s with weights rising as tau^0.15 (the third test press's form), plus a
    log creep of ``log_per_decade`` (two elements per decade to 10^5 s)."""
    taus = 10.0 ** np.arange(-2.0, np.log10(300.0) + 1e-9, 0.5)
    w = taus**0.15
    w = w / w.sum() * share
    lt = 10.0 ** np.arange(-2.0, 5.0 + 1e-9, 0.5) if log_per_decade else np.array([])
    gains = tuple(w) + (0.5 * log_per_decade,) * lt.size
    return dg.Model(PI, creep=C.CreepModel("kv", 1.0, tuple(taus) + tuple(lt), gains))


def _context(truth: dg.Model, seed: int) -> dg.Context:
    """A 120 s hold, a rest and a slow triangle of ``truth`` with noise, against the base."""
    runs = runs_of(truth, seed)
    return dg.Context(
        runs, dg.Model(PI, creep=POLES), frozenset({"triangle-0.1hz"}), {r.name: dg.noise_floor(r.y) for r in runs}
    )


def _size_pct(f) -> float:
    return float(re.search(r"rises ([0-9.]+) % of the step in the decade after", f.evidence).group(1))


@pytest.mark.parametrize("seed", [0, 2])
def test_a_creep_spread_to_minutes_is_not_a_log_creep_by_the_elements_beside_the_tail(seed):
    # 2 % of the step over 10 ms-300 s: the tail reads about 0.34 % per decade, and with the
    # elements fitted beside it the extension rose 0.49-0.50 % beyond the poles (named before)
    f = cause_logarithmic_creep(_context(_press(0.02), seed))
    assert f is not None and f.gain_pct > 50.0  # the tail does predict the hold's end better
    tail = 100.0 * f.parameters["per_decade"]
    assert tail < 100.0 * LOG_CREEP_MIN_PER_DECADE
    # the size said is the tail's (its rise over the decade is its rate, to 0.02 point)
    assert _size_pct(f) == pytest.approx(tail, abs=0.02)
    assert f.too_small and not f.accepted


@pytest.mark.parametrize("seed", [0, 2])
def test_a_documented_log_creep_beside_that_creep_is_still_named(seed):
    # the smallest documented log creep of the third press (0.6 % per decade) on the same press
    f = cause_logarithmic_creep(_context(_press(0.02, 0.006), seed))
    assert f is not None and f.accepted and not f.too_small
    assert _size_pct(f) >= 100.0 * LOG_CREEP_MIN_PER_DECADE
