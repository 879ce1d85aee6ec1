"""Issue 20, the unknown said: a rest that moves where nothing slow was named, and a drift of the
reading judged against the creep of a stroke the stack keeps at rest.

The runs: a slow triangle, a held step, a lower triangle and one rest at the end (the default
plan's one rest), two minutes each on one session clock. The stack creeps with equal weights per
decade from 1 to 3000 s; the model's creep is three Kelvin-Voigt elements (3, 30 and 300 s) fitted
to the held step's two minutes, as ``fit --base`` fits them, so it draws the stack's creep only
nearly. The stack keeps a stroke at rest whose creep rises from every run's start (the third test
press's remanence: 35 N there), and the reading may wander on the session's clock, two slow sines
(the third press's thermal wander moved its one rest by 0.26 N, seed 5), which the drift's one rate
for every run does not draw either.
"""

from __future__ import annotations

import dataclasses
import json
from datetime import UTC, datetime, timedelta

import numpy as np
import pytest

from piezopress.analysis import diagnosis as dg
from piezopress.analysis.creep import CreepModel
from piezopress.analysis.diagnosis import search
from piezopress.analysis.diagnosis.causes.sensor_offset_drift import cause_sensor_offset_drift
from piezopress.analysis.diagnosis.slow import REST_SWING_TO_FLOOR, TELL_DRIFT_FROM_CREEP, rest_movement
from piezopress.analysis.hysteresis import PIModel
from piezopress.pipelines import next_plan as NP

FS = 100.0  # the default plan samples its rest at 100 Hz
NOISE_N = 0.05
KEPT_N = 35.0
#: The stack's creep: equal weights per decade, 1 to 3000 s (3.6 % of the step in all).
STACK_CREEP = CreepModel("kv", 1.0, tuple(np.geomspace(1.0, 3000.0, 8)), (0.0045,) * 8)
LOOP = PIModel((0.0,), (1.0,), (0.0,), (2.0,), y0=0.0)
STACK = dg.Model(LOOP, creep=STACK_CREEP)


def _fitted_creep() -> CreepModel:
    """Three elements (3, 30, 300 s) fitted by least squares to the stack's creep over a two-minute hold."""
    taus = (3.0, 30.0, 300.0)
    held = STACK_CREEP.step_creep(int(121 * FS), FS)
    t = np.arange(1, held.size + 1) / FS
    gains, *_ = np.linalg.lstsq(-np.expm1(-t[:, None] / np.array(taus)), held, rcond=None)
    return CreepModel("kv", 1.0, taus, tuple(float(g) for g in gains))


MODEL = dg.Model(LOOP, creep=_fitted_creep())


def _wander(clock_s: np.ndarray, amplitude_n: float, phase: float = 4.0) -> np.ndarray:
    """A thermal wander of the reading: two slow sines, 17 and 41 min (the first's phase ``phase``)."""
    return amplitude_n * (np.sin(2 * np.pi * clock_s / 1020.0 + phase) + 0.6 * np.sin(2 * np.pi * clock_s / 2460.0))


def _runs(
    wander_n: float, kept_n: float = KEPT_N, rests_before: int = 0, seed: int = 0, phase: float = 4.0
) -> dg.Context:
    """The runs of the module's docstring (``rests_before`` more rests first, as a next plan's),
    each starting 5 s after the one before ended and recording its start time; the reading wanders
    by ``wander_n`` (:func:`_wander`, of ``phase``) on the session's clock and the stack keeps ``kept_n`` at rest."""
    t = np.arange(0.0, 120.0, 1.0 / FS)
    tri = 2.0 * np.abs(((t * 0.1) % 1.0) - 0.5)
    drives = [(f"rest-{i}", "rest", np.zeros_like(t)) for i in range(rests_before)] + [
        ("triangle", "triangle", 150.0 * tri),
        ("hold", "creep", np.where(t >= 1.0, 150.0, 0.0)),
        ("triangle-low", "triangle", 10.0 + 40.0 * tri),
        ("rest", "rest", np.zeros_like(t)),
    ]
    rng = np.random.default_rng(seed)
    t0 = datetime(2026, 12, 3, 8, 0, tzinfo=UTC)
    runs = []
    for i, (name, kind, x) in enumerate(drives):
        c0 = 125.0 * i
        run = dg.RunData(
            name, kind, t, x, np.zeros_like(t), FS, meta={"started_utc": (t0 + timedelta(seconds=c0)).isoformat()}
        )
        y = STACK.predict(run) + kept_n * STACK_CREEP.step_creep(t.size, FS) + _wander(c0 + t, wander_n, phase)
        runs.append(dataclasses.replace(run, y=y + rng.normal(0.0, NOISE_N, t.size)))
    return dg.Context(runs, MODEL, frozenset(), {r.name: dg.noise_floor(r.y) for r in runs})


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_rest_that_only_a_kept_stroke_moves_does_not_move_beyond_it(seed):
    """The kept stroke's creep moves the rest far beyond the bar against the model's creep alone
    (what a rest that moves would read without it), and not beyond it once it is taken; the model
    draws the kept stroke's rise over the rest within 15 %."""
    from piezopress.analysis.diagnosis.slow import _slow_residual

    ctx = _runs(0.0, seed=seed)
    mv = rest_movement(ctx)
    assert mv is not None and not mv.moves, mv
    rest = ctx.runs[-1]
    rise = KEPT_N * STACK_CREEP.step_creep(rest.t_s.size, FS)
    drawn = mv.kept * MODEL.creep_transient(rest)
    assert drawn[-1] - drawn[0] == pytest.approx(rise[-1] - rise[0], rel=0.15)
    _, averaged = _slow_residual(rest, rest.y - MODEL.predict(rest), 5.0)
    assert np.ptp(averaged) > 5 * REST_SWING_TO_FLOOR * mv.floor  # the kept stroke alone would have read as moving


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_rest_the_reading_drifts_through_moves_beyond_the_kept_stroke(seed):
    """A wander of 0.4 N moves the two-minute rest 0.3 N, as the third press's wander moved
    its rest: the kept stroke's saturating creep cannot draw that steady rise, and the rest moves;
    without the kept stroke too."""
    for kept in (KEPT_N, 0.0):
        mv = rest_movement(_runs(0.4, kept_n=kept, seed=seed))
        assert mv is not None and mv.moves, (kept, mv)


def _nothing_named() -> dict[str, dg.Cause]:
    """The two slow causes with the catalogue's ids and needs, neither finding anything (the third
    press's drift seeds 5 and 9: one rate for every run predicts worse than none)."""
    return {
        c: dataclasses.replace(dg.CAUSES[c], run=lambda ctx: None) for c in ("logarithmic_creep", "sensor_offset_drift")
    }


def test_a_rest_that_moves_where_nothing_slow_is_named_is_said_and_the_next_plan_tells_it(monkeypatch, tmp_path):
    """Nothing named, one rest that moves: the summary says so with the experiment that tells a
    wander of the reading from creep, and ``next-plan.toml`` holds it (a rest, the drive held, a
    rest again); where only the kept stroke moves the rest, neither."""
    monkeypatch.setattr(search, "CAUSES", _nothing_named())
    causes = list(search.CAUSES)
    moving = _runs(0.4)
    result = search.diagnose(MODEL, moving.runs, causes=causes)
    assert result.findings == []
    (sig,) = [s for s in result.signatures if s["kind"] == dg.MOVES_AT_REST]
    assert sig["run"] == "rest" and "at rest (rest, 120 s) the reading moves" in result.summary
    assert TELL_DRIFT_FROM_CREEP in sig["text"]
    info = NP.next_plan([], moving, result, tmp_path, ["runs/"])
    assert info is not None and info["tells_apart"] == [NP.MOVES_AT_REST_PAIR]
    assert [g["protocols"] for g in info["groups"]] == [["rest-before-drive", "hold-150v", "rest-after-drive"]]

    still = _runs(0.0)
    quiet = search.diagnose(MODEL, still.runs, causes=causes)
    assert not [s for s in quiet.signatures if s["kind"] == dg.MOVES_AT_REST]
    assert NP.next_plan([], still, quiet, tmp_path / "still", ["runs/"]) is None  # nothing written


def test_a_rest_that_moves_is_not_said_where_two_rests_on_the_clock_tried_the_wander(monkeypatch):
    """With a rest before the drive as well (more than 300 s before the last), the drift's wander
    was tried: a rest that moves is then no question the runs leave open."""
    monkeypatch.setattr(search, "CAUSES", _nothing_named())
    result = search.diagnose(MODEL, _runs(0.4, rests_before=1).runs, causes=list(search.CAUSES))
    assert not [s for s in result.signatures if s["kind"] == dg.MOVES_AT_REST]


@pytest.mark.parametrize("rests_before", [1, 2])
def test_a_kept_stroke_creeping_from_every_runs_start_is_no_drift_of_the_reading(monkeypatch, rests_before):
    """The kept stroke's creep rises from every run's start, as a warm-up of the reading would;
    with a rest before the drive as well (the next plan's, beside the first runs' one) it shows in
    two rests or more. Judged against the model's creep alone, a warm-up or a wander takes part of it
    up (the third test press, clean, after the next plan: 20.9 %, named); judged against the kept
    stroke's creep as well, it predicts worse than none. A wander of the reading beside the kept
    stroke is still named, and says what it was judged against. With one rest the stroke is not
    read for the drift (that rest's rise may be the drift's own): the drift is judged as before."""
    from piezopress.analysis.diagnosis.causes import sensor_offset_drift as S

    still = cause_sensor_offset_drift(_runs(0.0, rests_before=rests_before))
    assert still is not None and still.gain_pct <= 0.0, still.gain_pct
    drifting = cause_sensor_offset_drift(_runs(2.0, rests_before=2, phase=2.0))
    assert drifting is not None and drifting.accepted and drifting.model.drift_clock is not None, drifting
    assert "kept at rest" in drifting.evidence
    one_rest = cause_sensor_offset_drift(_runs(0.0))
    monkeypatch.setattr(S, "kept_stroke_model", lambda ctx: ctx)  # the drift judged as before
    unkept = cause_sensor_offset_drift(_runs(0.0, rests_before=rests_before))
    # judged against the model's creep alone the stroke's rise reads as a drift (a warm-up or a wander:
    # 17 and 2 % held out on the witnesses of a drift, stop 77; 14-15 % on every long run before), far
    # better than against the stroke
    assert unkept.gain_pct >= still.gain_pct + 40.0, (unkept.gain_pct, still.gain_pct)
    # one rest: judged as before, and no stroke said
    assert one_rest.gain_pct == pytest.approx(cause_sensor_offset_drift(_runs(0.0)).gain_pct, abs=1e-9)
    assert "kept at rest" not in one_rest.evidence


def _unclocked(ctx: dg.Context) -> dg.Context:
    """The same runs with no start time recorded (runs from another program: no clock)."""
    runs = [dataclasses.replace(r, meta={}) for r in ctx.runs]
    return dg.Context(runs, ctx.model, ctx.fitted_runs, ctx.floor)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_two_rests_on_no_clock_read_a_wander_at_each_rests_own_rate(seed):
    """Two rests and no start time recorded: a wander of the reading that rises through one rest
    and falls through the other (the wander's phase puts its turn between them) is named at each
    rest's own rate, each of the wander's sign there; a kept stroke's creep alone, rising alike in
    both from their starts, is not a drift. With one rest the wander form is not tried."""
    from piezopress.analysis.diagnosis.slow import wander_untried

    ctx = _unclocked(_runs(2.0, rests_before=1, seed=seed, phase=2.0))
    assert not wander_untried(ctx)
    f = cause_sensor_offset_drift(ctx)
    assert f is not None and f.accepted, None if f is None else (f.gain_pct, f.evidence)
    assert "at each rest's own rate, on no recorded clock" in f.evidence, f.evidence
    rates = {ident: a1 for ident, _, a1, *_ in f.model.drift_clock}
    for r in ctx.runs:
        if r.kind == "rest":  # the wander's slope at that rest's middle (its start 0 or 500 s on the session's clock)
            c = (0.0 if r.name == "rest-0" else 500.0) + 60.0
            slope = (_wander(np.array([c + 1.0]), 2.0, 2.0) - _wander(np.array([c - 1.0]), 2.0, 2.0))[0] / 2.0
            assert np.sign(rates[r.ident]) == np.sign(slope), (r.name, rates[r.ident], slope)
    still = cause_sensor_offset_drift(_unclocked(_runs(0.0, rests_before=1, seed=seed)))
    assert still is None or not still.accepted, still.gain_pct
    assert wander_untried(_unclocked(_runs(0.0, seed=seed)))


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("rate_n_per_min", [0.0, 0.3, 1.0])
def test_a_drift_from_each_runs_start_is_judged_against_a_kept_stroke_whose_size_is_fitted_beside_it(
    seed, rate_n_per_min, monkeypatch
):
    """The reading drifts at one rate from every run's start (the virtual rig's drift), beside the
    stroke the stack keeps at rest, with a rest before the first drive and one after the last. Read on
    the rests alone, the kept stroke takes the drift's rise (63-130 N against the stack's 35 N): judged
    against that stroke fixed, the drift read 37-40 % (the default plan's two rests on the virtual rig:
    13 %, nothing named). With the stroke's size fitted beside the drift, the drift is named at least
    60 % better on the held-out ends, the stroke read within 40 % of the stack's, and a drift judged
    against the fixed stroke reads at least 30 points less; with no drift nothing is named."""
    from piezopress.analysis.diagnosis.slow import _drift_fit, kept_stroke_model

    ctx = _runs(0.0, rests_before=1, seed=seed)
    runs = [dataclasses.replace(r, y=r.y + rate_n_per_min / 60.0 * r.t_s) for r in ctx.runs]
    ctx = dg.Context(runs, ctx.model, frozenset(), {r.name: dg.noise_floor(r.y) for r in runs})
    found = cause_sensor_offset_drift(ctx)
    if not rate_n_per_min:
        assert found is None or not found.accepted, found.gain_pct
        return
    assert found is not None and found.accepted and found.gain_pct >= 60.0, found and found.gain_pct
    assert abs(found.model.creep_bias - KEPT_N) <= 0.4 * KEPT_N, found.model.creep_bias
    assert "its size fitted beside the drift" in found.evidence
    from piezopress.analysis.diagnosis import slow

    monkeypatch.setattr(slow, "HOLD_SHAPE", False)  # the stroke read with the model's creep alone
    kept = kept_stroke_model(ctx)
    assert kept.model.creep_bias > 1.5 * KEPT_N  # on the rests alone it takes the drift's rise
    fixed = _drift_fit(kept, clock=dg.run_starts(kept.runs))
    assert fixed.gain_pct <= found.gain_pct - 30.0, (fixed.gain_pct, found.gain_pct)


def test_without_a_rest_a_drift_not_found_where_the_drive_moves_is_not_ruled_out_and_the_next_plan_rests(
    monkeypatch, tmp_path
):
    """No run rests (the thesis's runs alone): the drift is tested on the runs whose drive moves
    only (its later way: any run of 25 s or more), where the creep and the loop move the reading
    too. Not found there, it is not ruled out: the summary and the tested entry say it is judged
    best on a rest, and ``next-plan.toml`` holds the runs that tell a wander from creep (a rest, the
    drive held, a rest again: no rest group beside them) and serves the drift with them. With the
    rest, the drift is tested its first way: nothing of this."""
    monkeypatch.setattr(search, "CAUSES", _nothing_named())
    causes = list(search.CAUSES)
    driven = _runs(0.4)
    driven = dg.Context(driven.runs[:-1], driven.model, driven.fitted_runs, driven.floor)
    assert all(r.kind != "rest" for r in driven.runs)
    result = search.diagnose(MODEL, driven.runs, causes=causes)
    assert result.findings == [] and not result.not_tested
    (partly,) = result.partly_tested
    assert partly.cause == "sensor_offset_drift" and partly.testable and partly.partly
    assert partly.best.startswith("a rest run") and set(partly.runs) == {"triangle", "hold", "triangle-low"}
    assert "not ruled out, tested only on runs that show it weakly: sensor_offset_drift (judged best on a rest run" in (
        result.summary
    )
    (entry,) = [t for t in result.tested if t["cause"] == "sensor_offset_drift"]
    assert "judged best on a rest run" in entry["result"]
    assert result.as_dict()["partly_tested"][0]["tested_on"] == partly.runs
    info = NP.next_plan([], driven, result, tmp_path, ["runs/"])
    assert info is not None and info["tells_apart"] == [NP.NO_REST_PAIR] and info["serves"] == ["sensor_offset_drift"]
    (group,) = info["groups"]
    assert group["protocols"] == ["rest-before-drive", "hold-150v", "rest-after-drive"]
    assert group["serves"] == ["sensor_offset_drift"] and group["tells"] == [NP.NO_REST_PAIR]
    text = (tmp_path / "next-plan.toml").read_text()
    assert "sensor_offset_drift: tested only on runs that show it weakly; judged best on a rest run" in text
    # the report says it too
    from piezopress.pipelines.report_doc import Bullets
    from piezopress.pipelines.report_model import _diagnosis_blocks

    doc = {"summary": "s", "output_unit": "N", "partly_tested": result.as_dict()["partly_tested"]}
    (tmp_path / "report").mkdir()
    (tmp_path / "report" / "diagnosis.json").write_text(json.dumps(doc))
    items = [i for b in _diagnosis_blocks(tmp_path / "report", []) if isinstance(b, Bullets) for i in b.items]
    assert [i.split(". Judged")[0] for i in items if i.startswith("Not ruled out")] == [
        "Not ruled out: sensor_offset_drift, tested only on runs that show it weakly"
    ], items

    rested = search.diagnose(MODEL, _runs(0.4).runs, causes=causes)
    assert not rested.partly_tested and "not ruled out" not in rested.summary
    (tmp_path / "rested").mkdir()
    plan = NP.next_plan([], _runs(0.4), rested, tmp_path / "rested", ["runs/"])
    assert plan is not None and plan["tells_apart"] == [NP.MOVES_AT_REST_PAIR]  # its rest moves: that pair only
