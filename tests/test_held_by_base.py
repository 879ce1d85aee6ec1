"""What the base already holds of a cause is said beside "not found" (``Cause.held``): a press's
own chain lag is drawn by the base's drive chain, and ``input_delay`` is looked for beyond it;
a user reading "not found" learns the lag was drawn, not missed."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from test_delay_beside_slew import _runs  # the steps and triangles of 0-150 V at 20 kHz

from piezopress.analysis import diagnosis as dg
from piezopress.analysis.diagnosis.causes.amplifier_slew_limit import held_slew
from piezopress.analysis.diagnosis.causes.input_delay import held_by_chain
from piezopress.analysis.hysteresis import PIModel

MODEL = PIModel(r=(0.0, 4.0, 10.0, 20.0, 35.0), w=(1.6, 0.15, 0.12, 0.08, 0.05), d=(0.0,), s=(1.0,))
FS = 20_000.0
#: a base as fit leaves it on a press with its own chain: a 1.2 kHz low-pass and 2.2 samples of delay
CHAINED = dg.Model(
    MODEL,
    wn=5000.0,
    zeta=0.08,
    drive_lowpass=(2 * np.pi * 1200.0, 0.8),
    drive_delay_s=2.2 / FS,
    drive_delay_samples=2.2,
    drive_delay_rate_hz=FS,
)


def test_the_chain_the_base_holds_is_said_with_its_figures():
    said = held_by_chain(CHAINED)
    assert said == (
        "the drive chain identified on the steps, a 1.2 kHz low-pass (damping 0.8) and a delay of 0.11 ms "
        "(2.2 samples at 20 kHz)"
    ), said
    assert held_by_chain(dg.Model(MODEL)) == ""
    assert (
        held_slew(replace(CHAINED, slew_v_per_s=11e3)) == "the drive chain's slew of 11 V/ms, identified on the steps"
    )
    assert held_slew(CHAINED) == ""


@pytest.mark.integration
def test_a_press_lagging_by_its_own_chain_reads_not_found_beyond_what_the_base_holds():
    rng = np.random.default_rng(5)
    runs = []
    for r in _runs():  # the press is the base: its lag is the chain's, nothing beyond
        y = CHAINED.reading(r, CHAINED.force(r, CHAINED.static(r)))
        runs.append(replace(r, y=y + rng.normal(0.0, 0.05, y.size)))
    result = dg.diagnose(CHAINED, runs)
    assert "input_delay" not in [f.cause for f in result.findings], result.summary
    entry = next(t for t in result.tested if t["cause"] == "input_delay")
    assert entry["result"].startswith("not found"), entry
    assert entry["result"].endswith("beyond what the base holds: " + held_by_chain(CHAINED)), entry
    assert entry["held_by_base"] == held_by_chain(CHAINED)
