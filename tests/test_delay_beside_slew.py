"""A delay found beside a slew must lag the runs the slew does not reach too (``input_delay``'s
:func:`~piezopress.analysis.diagnosis.causes.input_delay.slew_shape`): a delay lags every run
alike, a slew whose form is not the press's leaves a lag only on the runs it acts on."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from piezopress.analysis import diagnosis as dg
from piezopress.analysis.diagnosis.causes import input_delay as ID
from piezopress.analysis.diagnosis.judging import Context
from piezopress.analysis.hysteresis import PIModel
from piezopress.signals import noise_floor

MODEL = PIModel(r=(0.0, 4.0, 10.0, 20.0, 35.0), w=(1.6, 0.15, 0.12, 0.08, 0.05), d=(0.0,), s=(1.0,))
FS = 20_000.0
SLEW = 11e3  # V/s: the 50 and 100 Hz triangles of 150 V (15 and 30 V/ms) slew, the 5 and 10 Hz do not
#: the model as fit would leave it with the slew named: a chain, a mode and the slew
BASE = dg.Model(MODEL, wn=5000.0, zeta=0.08, drive_lowpass=(2 * np.pi * 1200.0, 0.8), slew_v_per_s=SLEW)
DELAY_S = 2e-4


def _runs() -> list[dg.RunData]:
    out = []
    for h in (50.0, 100.0, 150.0):
        t = np.arange(int(0.2 * FS)) / FS
        x = np.where((t >= 0.01) & (t < 0.11), h, 0.0)
        out.append(dg.RunData(f"step-{h:g}v", "step", t, x, np.zeros_like(x), FS))
    for f in (5.0, 10.0, 50.0, 100.0):
        t = np.arange(int(max(1.0, 10.0 / f) * FS)) / FS
        x = 75.0 - 75.0 * (2.0 / np.pi) * np.arcsin(np.cos(2 * np.pi * f * t))  # 0-150 V
        out.append(dg.RunData(f"triangle-{f:g}hz", "triangle", t, x, np.zeros_like(x), FS))
    return out


def _read(runs: list[dg.RunData], press_of) -> list[dg.RunData]:
    """Each run as ``press_of(run)`` reads it, with 0.05 N of white noise."""
    rng = np.random.default_rng(3)
    out = []
    for r in runs:
        m = press_of(r)
        y = m.reading(r, m.force(r, m.static(r)))
        out.append(replace(r, y=y + rng.normal(0.0, 0.05, y.size)))
    return out


def _context(runs: list[dg.RunData]) -> Context:
    return Context(runs, BASE, frozenset(), {r.name: noise_floor(r.y) for r in runs})


def test_which_runs_the_slew_reaches():
    by = {r.name: ID._slewed(r, SLEW) for r in _runs()}
    assert by == {
        "step-50v": True,
        "step-100v": True,
        "step-150v": True,
        "triangle-5hz": False,
        "triangle-10hz": False,
        "triangle-50hz": True,
        "triangle-100hz": True,
    }


@pytest.mark.integration
def test_a_delay_that_lags_every_run_is_named_beside_the_slew():
    runs = _read(_runs(), lambda r: replace(BASE, delay_s=DELAY_S))
    f = ID.cause_input_delay(_context(runs))
    assert f is not None and f.accepted, f
    assert not f.refused
    assert f.parameters["delay_s"] == pytest.approx(DELAY_S, rel=0.25)


def _found_beside_the_slew() -> tuple[Context, object]:
    ctx = _context(_read(_runs(), lambda r: replace(BASE, delay_s=DELAY_S)))
    found = ID._delay_on_fast_runs(ctx)
    assert found is not None and found.accepted and found.gain_by_run, found
    return ctx, found


@pytest.mark.integration
@pytest.mark.parametrize(
    ("gains", "refused"),
    [
        # third press, current limit seed 13 (11 V/ms): the gains on the held-out runs as measured
        (
            {
                "step-100v": 12.3,
                "triangle-5hz": 0.3,
                "triangle-10hz": 1.8,
                "triangle-50hz": 38.2,
                "triangle-100hz": 65.2,
            },
            True,
        ),
        # the runs too slow to slew show it too: a delay
        ({"step-100v": 12.3, "triangle-5hz": 14.0, "triangle-10hz": 25.0, "triangle-50hz": 38.2}, False),
        # one of them only, at the bar's median
        ({"step-100v": 30.0, "triangle-5hz": 2.0, "triangle-10hz": 18.0, "triangle-50hz": 38.2}, False),
        # no run the slew does not reach: nothing tells them apart, and it is refused
        ({"step-100v": 30.0, "triangle-50hz": 38.2, "triangle-100hz": 50.0}, True),
        # every held-out run too slow to slew: the slew's shape cannot be the reason
        ({"triangle-5hz": 25.0, "triangle-10hz": 30.0}, False),
    ],
)
def test_the_runs_too_slow_to_slew_decide(gains, refused):
    ctx, found = _found_beside_the_slew()
    why = ID.slew_shape(ctx, replace(found, gain_by_run=gains))
    assert bool(why) is refused, why
    if refused and any(not ID._slewed(r, SLEW) for r in ctx.runs if r.name in gains):
        assert "too slow to slew" in why and "triangle-5hz 0.3 %" in why


def test_without_a_slew_in_the_model_nothing_is_refused():
    ctx, found = _found_beside_the_slew()
    ctx = replace(ctx, model=replace(BASE, slew_v_per_s=None))
    seed13 = {"step-100v": 12.3, "triangle-5hz": 0.3, "triangle-10hz": 1.8, "triangle-50hz": 38.2}
    assert ID.slew_shape(ctx, replace(found, gain_by_run=seed13)) == ""
