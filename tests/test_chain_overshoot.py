"""A drive that overshoots leaves the loop on the branch down from its peak, which the loop keeps:
each step then settles above the rising branch by what the drive overshot. The chain ``fit``
identifies with a linear press (each step's gain and offset its own) cannot see that, so the fast
causes' baseline refits the drive chain's low-pass and delay through the model's map
(``judging._fast_base``): an underdamped amplifier read as a damped low-pass is read back from the
steps' levels, a chain the model holds already is left where it is, and a longer delay than the
identified one is not taken up (``input_delay``'s to name)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from piezopress.analysis import diagnosis as dg
from piezopress.analysis.diagnosis.judging import Context, _cost, _fast_base
from piezopress.analysis.hysteresis import PIModel
from piezopress.signals import noise_floor

#: a loop whose plays keep the drive's peak (a wide one: 5-35 V of play)
MODEL = PIModel(r=(0.0, 5.0, 12.0, 22.0, 35.0), w=(1.4, 0.3, 0.25, 0.2, 0.15), d=(0.0,), s=(1.0,))
FS = 20_000.0
NOISE_N = 0.05
#: the press: an amplifier at 2.5 kHz ringing at damping 0.55 (13 % overshoot), two samples of delay
PRESS = dg.Model(MODEL, wn=2 * np.pi * 800.0, zeta=0.06, drive_lowpass=(2 * np.pi * 2500.0, 0.55), drive_delay_s=1e-4)
#: ... as a linear identification reads it: a damped low-pass (no overshoot to speak of)
IDENTIFIED = replace(PRESS, drive_lowpass=(2 * np.pi * 1800.0, 0.85))


def _steps(press: dg.Model) -> list[dg.RunData]:
    out = []
    for i, height in enumerate((20.0, 50.0, 100.0, 150.0)):
        t = np.arange(int(0.16 * FS)) / FS
        x = np.where((t >= 0.01) & (t < 0.11), height, 0.0)
        r = dg.RunData(f"step-{height:.0f}v", "step", t, x, np.zeros_like(x), FS)
        y = press.reading(r, press.force(r, press.static(r)))
        out.append(replace(r, y=y + np.random.default_rng(i).normal(0.0, NOISE_N, y.size)))
    return out


def _settled_miss(model: dg.Model, runs: list[dg.RunData]) -> float:
    """The largest miss of a step's settled level (its hold's last 60 ms, averaged)."""
    miss = []
    for r in runs:
        hold = (r.t_s >= 0.05) & (r.t_s < 0.11)
        miss.append(abs(float(np.mean(r.y[hold] - model.predict(r)[hold]))))
    return max(miss)


def _base(model: dg.Model, runs: list[dg.RunData]) -> dg.Model:
    ctx = Context(runs, model, frozenset(), {r.name: noise_floor(r.y) for r in runs})
    return _fast_base(ctx, [(r, slice(None)) for r in runs])


def test_an_overshooting_drive_is_read_back_from_the_steps_levels():
    runs = _steps(PRESS)
    assert _settled_miss(IDENTIFIED, runs) > 1.0  # the damped chain misses the levels by newtons
    m = _base(IDENTIFIED, runs)
    # the levels within a tenth of what the damped chain missed, and the amplifier's ringing read back
    assert _settled_miss(m, runs) < 0.1 * _settled_miss(IDENTIFIED, runs)
    assert m.drive_lowpass[1] == pytest.approx(0.55, abs=0.08)
    whole = [(r, slice(None)) for r in runs]
    assert _cost(whole, m) < 1.5 * _cost(whole, PRESS)


def test_a_chain_the_model_holds_already_is_left_where_it_is():
    runs = _steps(IDENTIFIED)
    m = _base(IDENTIFIED, runs)
    assert m.drive_lowpass[0] == pytest.approx(IDENTIFIED.drive_lowpass[0], rel=0.05)
    assert m.drive_lowpass[1] == pytest.approx(IDENTIFIED.drive_lowpass[1], abs=0.05)
    assert m.drive_delay_s <= IDENTIFIED.drive_delay_s + 1e-12


def test_a_longer_delay_than_identified_is_not_taken_up():
    # a FIFO of six samples beyond the chain: the delay stays within what was identified and the
    # steps still read late (input_delay's to name), the model's lag at most what was identified
    late = replace(PRESS, drive_delay_s=PRESS.drive_delay_s + 6 / FS)
    runs = _steps(late)
    m = _base(PRESS, runs)
    assert m.drive_delay_s <= PRESS.drive_delay_s + 1e-12
    whole = [(r, slice(None)) for r in runs]
    assert _cost(whole, m) > 3.0 * _cost(whole, late)
