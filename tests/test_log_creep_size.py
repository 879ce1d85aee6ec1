"""A logarithmic creep is named by its size on the press, not by its prediction gain alone.

A press whose creep spreads over the decades of its hold (the third test press) leaves a small
log-time rise beyond what a few poles draw: a log tail predicts the hold's end better (gains of
54-61 % there), but the rise is 0.13-0.18 % of the step per decade, against the 0.8-1.8 % of the
documented logarithmic creep of all three presses. ``logarithmic_creep`` is named only where
its rate reaches :data:`LOG_CREEP_MIN_PER_DECADE`; a smaller one is said under ``tested``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from piezopress.analysis import creep as C
from piezopress.analysis import diagnosis as dg
from piezopress.analysis.diagnosis.causes.logarithmic_creep import (
    LOG_CREEP_MIN_PER_DECADE,
    _beyond_next_decade,
    cause_logarithmic_creep,
)
from piezopress.analysis.diagnosis.judging import MIN_GAIN_PCT
from piezopress.analysis.hysteresis import PIModel

PI = PIModel((0.0, 20.0), (1.0, 0.3), (0.0,), (2.0,), y0=50.0)
POLES = C.CreepModel("kv", 1.0, (1.0, 10.0), (0.01, 0.01))


def _runs(per_decade: float, seed: int) -> list[dg.RunData]:
    """A 120 s hold, a rest and a slow triangle of a press whose creep is the poles plus a log
    tail of ``per_decade`` (two elements per decade from 0.05 s to 10^4 s), with noise."""
    lt = C.log_taus(0.05, 1e4)
    truth = dg.Model(
        PI, creep=C.CreepModel("kv", 1.0, POLES.taus_s + tuple(lt), POLES.gains + (0.5 * per_decade,) * lt.size)
    )
    return runs_of(truth, seed)


def runs_of(truth: dg.Model, seed: int) -> list[dg.RunData]:
    """A 120 s hold, a rest and a slow triangle of the press ``truth``, with noise."""
    rng = np.random.default_rng(seed)
    fs = 100.0
    t = np.arange(int(120 * fs)) / fs
    tt = np.arange(int(60 * fs)) / fs
    runs = [
        dg.RunData("creep-150v", "creep", t, np.where(t > 1.0, 150.0, 0.0), np.zeros_like(t), fs),
        dg.RunData("rest-120s", "rest", t, np.zeros_like(t), np.zeros_like(t), fs),
        dg.RunData(
            "triangle-0.1hz", "triangle", tt, 150.0 * (1 - np.abs((tt * 0.1) % 1 * 2 - 1)), np.zeros_like(tt), fs
        ),
    ]
    return [replace(r, y=truth.predict(r) + rng.normal(0.0, 0.05, r.t_s.size)) for r in runs]


def _context(runs: list[dg.RunData]) -> dg.Context:
    return dg.Context(
        runs, dg.Model(PI, creep=POLES), frozenset({"triangle-0.1hz"}), {r.name: dg.noise_floor(r.y) for r in runs}
    )


@pytest.mark.parametrize("seed", [0, 1])
def test_a_documented_log_creep_is_named_and_its_rate_measured(seed):
    f = cause_logarithmic_creep(_context(_runs(0.012, seed)))
    assert f is not None and f.accepted and not f.too_small
    assert f.parameters["per_decade"] == pytest.approx(0.012, rel=0.25)
    # how sure: the size is measured on a decade no run shows, and the evidence says so, with the
    # hold that tells a creep going on from one ending there
    said = f.evidence.split("beyond the model's creep it rises ", 1)[1]
    rise = float(said.split(" % of the step in the decade after the 120 s hold, which no run shows", 1)[0])
    assert rise == pytest.approx(1.2, rel=0.35)  # the documented 1.2 % per decade, against poles
    assert said.endswith("a creep that ends within that decade draws the same hold (a hold of 1200 s tells them apart)")


@pytest.mark.parametrize("seed", [0, 1])
def test_a_log_rise_too_small_to_matter_is_not_named_but_said(seed):
    runs = _runs(0.003, seed)
    f = cause_logarithmic_creep(_context(runs))
    assert f is not None and f.parameters["per_decade"] < LOG_CREEP_MIN_PER_DECADE
    assert f.gain_pct >= MIN_GAIN_PCT  # the tail predicts the hold's end better: the size alone refuses it
    assert not f.accepted and "in the decade after the hold beyond what the model's creep draws" in f.too_small
    d = dg.diagnose(dg.Model(PI, creep=POLES), runs, ["triangle-0.1hz"], causes=["logarithmic_creep"])
    assert not d.findings
    (tested,) = d.tested
    assert tested["result"].startswith("not found (too small to matter: the creep rises")


def _remanent_runs(per_decade: float, remanent: float, seed: int) -> list[dg.RunData]:
    """The runs of :func:`_runs` from a press whose creep acts on the whole stroke, a part of
    which the stack keeps at rest (``remanent``, in N): every run starts with the creep's
    elements at zero (the simulator's state is not carried from run to run), so the kept stroke
    creeps from each run's start, at rest too. Simulated element by element here, not with the
    diagnosis model's creep."""
    from scipy.signal import lfilter

    lt = C.log_taus(0.05, 1e4)
    taus = POLES.taus_s + tuple(lt)
    gains = POLES.gains + (0.5 * per_decade,) * lt.size
    rng = np.random.default_rng(seed)
    out = []
    for r in _runs(0.0, seed):
        h = dg.Model(PI).static(r)  # the stroke above the rest level (N), rate-independent
        stroke = h + remanent
        y = PI.y0 + h.copy()
        for tau, g in zip(taus, gains):
            a = np.exp(-1.0 / (r.fs_hz * tau))
            y = y + lfilter([g * (1 - a)], [1.0, -a], stroke)
        out.append(replace(r, y=y + rng.normal(0.0, 0.05, r.t_s.size)))
    return out


@pytest.mark.parametrize(("remanent", "seed"), [(5.0, 0), (5.0, 1), (40.0, 0)])
def test_a_log_creep_of_a_stroke_kept_at_rest_is_not_also_a_drift(remanent, seed):
    # the rest run rises with the creep of the stroke the stack keeps (5 or 40 N at rest): a
    # rise where the drive does nothing, for which a drift of the reading was named beside the
    # log creep (here with 5 N, and on the third test press, seeds 0-4); the log creep judged
    # with that stroke's creep from every run's start takes it, and no drift is left
    runs = _remanent_runs(0.012, remanent, seed)
    rest = next(r for r in runs if r.kind == "rest")
    assert np.mean(rest.y[-500:]) - np.mean(rest.y[:500]) > 0.02 * remanent  # the rest run rises
    d = dg.diagnose(
        dg.Model(PI, creep=POLES), runs, ["triangle-0.1hz"], causes=["logarithmic_creep", "sensor_offset_drift"]
    )
    assert [f.cause for f in d.findings] == ["logarithmic_creep"], d.summary
    assert d.findings[0].parameters["per_decade"] == pytest.approx(0.012, rel=0.3)
    assert d.model.creep_bias == pytest.approx(remanent, rel=0.3)  # the kept stroke, read on the rest run


def test_a_log_creep_puts_the_hold_that_measures_its_size_in_the_next_plan(tmp_path):
    """Issue 20, "where the runs cannot tell ..., put the experiment that would tell them apart in
    next-plan.toml": a log creep's size is measured on the decade after the hold, which no run
    shows. Named, the next plan holds the drive ten times as long (every cause was tested), and
    says why; a rise too small to be named asks for nothing."""
    from piezopress.acquisition.plan import load_plan
    from piezopress.acquisition.rig_config import load_rig
    from piezopress.pipelines import next_plan as NP

    runs = _runs(0.012, 0)
    d = dg.diagnose(dg.Model(PI, creep=POLES), runs, ["triangle-0.1hz"], causes=["logarithmic_creep"])
    (f,) = d.findings
    assert not d.not_tested and f.tell_hold_s == round(10 * (runs[0].t_s[-1] - runs[0].t_s[0])) == 1200
    assert f.as_dict()["tell_hold_s"] == f.tell_hold_s
    assert "logarithmic_creep's size is measured on the decade after the hold, which no run shows" in d.summary
    info = NP.next_plan([], _context(runs), d, tmp_path, ["runs/"])
    pair = "logarithmic_creep from a creep that ends within the decade after the hold"
    assert info is not None and info["tells_apart"] == [pair] and info["serves"] == []
    assert [g["tells"] for g in info["groups"]] == [[pair]] and info["refit_for"] == ["logarithmic_creep"]
    text = (tmp_path / "next-plan.toml").read_text()
    assert f"#   {pair}: these runs cannot tell them apart" in text and "a hold of 1200 s does" in text
    assert "piezopress fit runs/ more/ --base --out base-2.json      # logarithmic_creep need the base" in text
    (p,) = load_plan(tmp_path / "next-plan.toml", load_rig(NP.DEFAULT_RIG).limits).protocols
    t, x = p.waveform()
    assert p.run_kind == "creep" and t[-1] >= 1200.0 and float(np.ptp(x)) > 0
    small = dg.diagnose(dg.Model(PI, creep=POLES), _runs(0.003, 0), ["triangle-0.1hz"], causes=["logarithmic_creep"])
    assert not small.findings and NP.next_plan([], _context(runs), small, tmp_path / "small", ["runs/"]) is None


def test_the_long_hold_is_shortened_to_the_plans_limits_and_left_out_where_too_little_remains():
    """A hold asked for beside other groups keeps the plan within what the loader allows (the
    runs' longest hold of 1200 s asks for 3600 s, the limit of a whole plan): shortened, said so,
    and the plan loads; where what remains is under a fifth of the hold asked for, it is left out
    (the plan is never one the loader refuses)."""
    import dataclasses
    import tomllib

    from piezopress.acquisition.plan import parse_plan
    from piezopress.pipelines import next_plan as NP

    ctx = _context(_runs(0.012, 0))
    rig = NP.rig_of_runs([])
    pair = "logarithmic_creep from a creep that ends within the decade after the hold"
    wander, asked = ["logarithmic_creep from sensor_offset_drift"], {"logarithmic_creep": 3600.0}
    plan = NP.choose(ctx, [], rig, (0.0, 150.0), wander, asked)
    assert [g.id for g in plan.groups] == [NP.TELL_GROUP, NP.LONG_HOLD_GROUP]
    (hold,) = plan.groups[1].protocols
    assert 0.2 * 3600.0 <= hold["hold_s"] < 3600.0 and plan.tell_why[pair].endswith(" in part")
    assert "3600 s asked for, shortened to fit the plan's limits" in plan.groups[1].what
    text = NP.plan_text(plan, {}, ["runs/"], 50.0)
    checked = parse_plan(tomllib.loads(text), rig.limits)
    assert rig.limits.max_duration_s - 5.0 <= checked.duration_s <= rig.limits.max_duration_s
    tight = dataclasses.replace(rig, limits=dataclasses.replace(rig.limits, max_duration_s=1200.0))
    plan = NP.choose(ctx, [], tight, (0.0, 150.0), wander, asked)
    assert [g.id for g in plan.groups] == [NP.TELL_GROUP] and pair not in plan.tells_apart


def _spectrum_to(tau_max_s: float, per_decade: float) -> C.CreepModel:
    """The poles and a log creep of ``per_decade`` that ends at ``tau_max_s``: a relaxation
    spectrum fitted on a short hold, whose slowest elements only the hold's end shows."""
    lt = C.log_taus(0.05, tau_max_s)
    return C.CreepModel("kv", 1.0, POLES.taus_s + tuple(lt), POLES.gains + (0.5 * per_decade,) * lt.size)


@pytest.mark.parametrize(("tau_max_s", "asks"), [(1000.0, True), (60.0, False)])
def test_a_rise_the_models_own_spectrum_extrapolates_asks_for_the_hold_that_tells(tmp_path, tau_max_s, asks):
    """Issue 20, "the unknown is said": a model whose creep spectrum reaches 1000 s, fitted on a
    120 s hold, itself draws a rise of about 1.2 % over the decade after the hold, with elements no
    run pins. A log creep going on past them then rises too little beyond it to be named (the
    third test press, log creep seed 7: 0.16 % beyond a spectrum rising 1.1 %), but whether the
    creep goes on or ends is unknown on both sides: the finding says so and the next plan holds
    the drive ten times as long. A spectrum ending before the hold (60 s) extrapolates nothing: a
    rise beyond it of the same size is measured against a model that saturates, and is named."""
    from piezopress.pipelines import next_plan as NP

    runs = _runs(0.012, 0)
    model = dg.Model(PI, creep=_spectrum_to(tau_max_s, 0.012))
    ctx = dg.Context(runs, model, frozenset({"triangle-0.1hz"}), {r.name: dg.noise_floor(r.y) for r in runs})
    f = cause_logarithmic_creep(ctx)
    assert f is not None
    if not asks:
        assert f.accepted and f.tell_hold_s == 1200
        return
    assert not f.accepted and "elements slower than the 120 s hold (to 1000 s), which no run pins" in f.too_small
    assert f.too_small.endswith("a hold of 1200 s tells") and f.tell_hold_s == 1200
    d = dg.diagnose(model, runs, ["triangle-0.1hz"], causes=["logarithmic_creep"])
    assert not d.findings and [c.tell_hold_s for c in d.considered] == [1200]
    info = NP.next_plan([], ctx, d, tmp_path, ["runs/"])
    pair = "logarithmic_creep from a creep that ends within the decade after the hold"
    assert info is not None and info["tells_apart"] == [pair] and info["refit_for"] == ["logarithmic_creep"]


@pytest.mark.parametrize("seed", [0, 1])
def test_where_the_runs_show_a_drift_the_size_and_the_extension_are_the_tail_judged_across_them(seed):
    """With a drift of the reading in the model, the hold alone cannot tell the tail from a drift,
    so the tail is judged across every long run (``_drift_fit`` with the tail). The finding's rate,
    its size beyond the model and the creep it extends the bundle with are that tail's, on the
    model's own creep: the hold's own fit sets Kelvin-Voigt elements beside a free drift, which may
    cancel each other (third test press, current limit seed 7: an element rising 450 % of the step
    over the decade after the hold, read as a log creep's size). Measured: 1.20 % per decade for
    the 1.2 % hidden (1.08-1.10 % from the hold's own fit)."""
    runs = [replace(r, y=r.y + 1e-5 * r.t_s) for r in _runs(0.012, seed)]
    model = dg.Model(PI, creep=POLES, drift_per_s=1e-5)
    ctx = dg.Context(runs, model, frozenset({"triangle-0.1hz"}), {r.name: dg.noise_floor(r.y) for r in runs})
    f = cause_logarithmic_creep(ctx)
    assert f is not None and f.accepted and "the tail was judged across every long run" in f.evidence
    rate = f.parameters["per_decade"]
    assert rate == pytest.approx(0.012, rel=0.05)
    beyond = _beyond_next_decade(f.model.creep, POLES, 120.0)
    assert beyond == pytest.approx(rate, rel=0.05)  # the extension is the model's creep and that tail
    assert f.model.creep.taus_s[: len(POLES.taus_s)] == POLES.taus_s
