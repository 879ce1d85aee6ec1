"""Issue 20, signatures over forms: where the model's creep ends sooner than the press's, the stroke a
stack keeps at rest goes on creeping through every rest beyond what the model draws, and that reads as
a drift of the reading unless the creep the model misses is measured where it shows most: the held step.

The press (simulated here by its own sums of exponentials, not by the diagnosis's model): a stroke of
30 N kept at rest in every run, and the whole force creeping from each run's start as a spectrum of
relaxation times two per decade from 10 ms to 300 s with weights rising as tau^0.15 (5 % in all: a
power-law creep to the hold's time scale). The model's creep is three poles of 1-60 s fitted on the held
step, as ``fit --base`` keeps the thesis's poles where they fit: past 60 s they have stopped and the press
has not (the third test press, input delay seed 5: a drift of -0.14 N per minute named at 37 %).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import signal

from piezopress.analysis import diagnosis as dg
from piezopress.analysis.creep import CreepModel
from piezopress.analysis.diagnosis import slow
from piezopress.analysis.diagnosis.causes.sensor_offset_drift import cause_sensor_offset_drift
from piezopress.analysis.hysteresis import PIModel

FS = 100.0
LOOP = PIModel((0.0,), (1.0,), (0.0,), (2.0,), y0=0.0)
KEPT_N = 30.0
SPECTRUM = 10.0 ** np.arange(-2.0, np.log10(300.0) + 1e-9, 0.5)
WEIGHTS = SPECTRUM**0.15 / np.sum(SPECTRUM**0.15) * 0.05
SCHEDULE = (("rest-before", 0.0, 120.0), ("triangle", 125.0, 30.0), ("hold", 369.0, 121.0), ("rest", 521.0, 120.0))


def _drive(name: str, t: np.ndarray) -> np.ndarray:
    if name.startswith("rest"):
        return np.zeros_like(t)
    if name == "hold":
        return np.where(t >= 1.0, 300.0, 0.0)
    return 300.0 * 2.0 * np.abs(((t * 0.1) % 1.0) - 0.5)


def _press(f: np.ndarray) -> np.ndarray:
    """The force ``f`` creeping from the run's start (each element from rest), exact for a held input."""
    out = f.copy()
    for tau, w in zip(SPECTRUM, WEIGHTS):
        a = np.exp(-1.0 / (FS * tau))
        out += w * signal.lfilter([1.0 - a], [1.0, -a], f)
    return out


def _ctx(drift_n_per_min: float, seed: int, wander: bool = False) -> dg.Context:
    """The runs, read through a drift of ``drift_n_per_min`` on the session's clock (with ``wander``: a
    thermal wander of two slow sines, 17 and 41 min, as large); the model's creep fitted on the held step."""
    rng = np.random.default_rng(seed)
    runs = []
    for name, c0, dur in SCHEDULE:
        t = np.arange(0.0, dur, 1.0 / FS)
        x = _drive(name, t)
        c = c0 + t
        w = 1020.0 / (2 * np.pi) * (np.sin(2 * np.pi * c / 1020.0) + 0.6 * np.sin(2 * np.pi * c / 2460.0 + 1.0))
        drift = drift_n_per_min / 60.0 * (w if wander else c)
        y = _press(KEPT_N + x) - KEPT_N + drift
        runs.append(dg.RunData(name, "custom", t, x, y + rng.normal(0.0, 0.05, t.size), FS))
    hold = next(r for r in runs if r.name == "hold")
    after = hold.t_s >= 1.0
    rise = (hold.y - hold.x)[after]
    taus = np.array([0.1, 1.0, 15.0])
    A = np.column_stack([np.ones(rise.size), -np.expm1(-(hold.t_s[after, None] - 1.0) / taus)])
    coef, *_ = np.linalg.lstsq(A, rise, rcond=None)
    model = dg.Model(LOOP, creep=CreepModel("kv", 1.0, tuple(taus), tuple(float(g) / 300.0 for g in coef[1:])))
    return dg.Context(runs, model, frozenset(), {r.name: dg.noise_floor(r.y) for r in runs})


@pytest.mark.parametrize("seed", [0, 1])
def test_the_kept_strokes_creep_past_the_models_poles_is_no_drift(seed, monkeypatch):
    """The rests rise beyond the model's creep as the held step does, in proportion to the stroke each
    keeps: judged against that, nothing is left for a drift. Judged against the model's poles alone
    (as before), the same rise was named a drift at 30 % or more."""
    ctx = _ctx(0.0, seed)
    assert slow.kept_stroke_model(ctx) is not ctx, "the rests evidence the kept stroke"
    found = cause_sensor_offset_drift(ctx)
    assert found is None or not found.accepted, found.gain_pct
    monkeypatch.setattr(slow, "HOLD_SHAPE", False)
    before = cause_sensor_offset_drift(ctx)
    assert before is not None and before.accepted and before.gain_pct >= 30.0, before and before.gain_pct


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("wander", [False, True])
def test_a_drift_beside_the_kept_strokes_creep_is_still_named(seed, wander):
    """A drift of the reading moves every run alike, the held step no more than the rests: the hold's
    misfit, at the stroke kept at rest, cannot draw it (0.5 N per minute, steady, or a wander of two slow
    sines whose fastest rate is about that)."""
    ctx = _ctx(0.5, seed, wander)
    found = cause_sensor_offset_drift(ctx)
    assert found is not None and found.accepted and found.gain_pct >= 50.0, found and found.gain_pct
    assert "with the creep beyond the model's that hold shows, in proportion to the stroke" in found.evidence


@pytest.mark.parametrize("release_s", [None, 119.0])
def test_the_holds_misfit_is_per_unit_of_its_held_step_from_its_edge_to_its_release(release_s):
    """The misfit is the hold's residual averaged over 5 s per unit of the step it holds (not of where its
    drive ends: the virtual rig's hold lets go a second before the run ends, leaving a remanence of 3 %
    of the step), against the time since the edge, from 5 s past it to the release."""
    t = np.arange(0.0, 121.0, 1.0 / FS)
    x = np.where(t >= 1.0, 300.0, 0.0)
    if release_s is not None:
        x = np.where(t >= release_s, 0.0, x)
    creep = 0.6 * np.log1p(np.maximum(t - 1.0, 0.0))  # a residual of known shape while held
    run = dg.RunData("hold", "custom", t, x, np.zeros_like(t), FS)
    model = dg.Model(LOOP)
    step = float(np.median(model.static(run)[(t >= 1.0) & (x > 0)]))
    run = dataclasses.replace(run, y=model.predict(run) + np.where(x > 0, creep, 0.0))
    ctx = dg.Context([run], model, frozenset(), {"hold": 0.01})
    tau, per_unit, name = slow.hold_misfit(ctx)
    assert name == "hold" and 5.0 <= tau[0] <= 6.0
    assert tau[-1] <= (release_s or 121.0) - 1.0 + 1e-9
    want = np.array([np.mean(0.6 * np.log1p(np.arange(round((s - 5.0) * FS), round(s * FS)) / FS)) for s in tau])
    assert per_unit * step == pytest.approx(want, abs=0.01)
