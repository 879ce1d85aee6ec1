"""Two effects at once: the greedy search names both where each falls short alone but each is a
finding of its own once the other is in the model (``search._together``), and nothing where
one of them adds too little beside the other.

Toy causes over a fixed run: each cause's held-out gain is set by which of the two is already
in the model (marked in the model's ``hum`` with an identity no run has, so the predictions do
not change), so the search's logic is tested apart from any fit.
"""

from dataclasses import replace

import numpy as np
import pytest

from piezopress.analysis import diagnosis as dg
from piezopress.analysis.diagnosis import search
from piezopress.analysis.diagnosis.cause import Cause
from piezopress.analysis.diagnosis.judging import MIN_GAIN_PCT
from piezopress.analysis.hysteresis import PIModel

BASE = dg.Model(PIModel((0.0, 8.0), (1.0, 0.5), (0.0,), (1.2,), y0=20.0))


def _run() -> dg.RunData:
    fs = 1000.0
    t = np.arange(2000) / fs
    x = 75.0 * (1 - np.abs(((t * 2.0) % 1.0) * 2 - 1))
    y = BASE.predict(dg.RunData("", "triangle", t, x, np.zeros_like(t), fs))
    return dg.RunData("tri", "triangle", t, x, y + np.random.default_rng(0).normal(0, 0.5, t.size), fs)


def _has(model: dg.Model, cid: str) -> bool:
    return any(h[0] == f"toy:{cid}" for h in model.hum)


def _toy(cid: str, other: str, alone: float, beside: float, calls: list[str], refused: str = "") -> Cause:
    """Cause ``cid``: held-out gain ``alone`` %, or ``beside`` % with ``other`` in the model;
    alone refused by its signature check (``refused``: "runs" on held-out runs it predicts
    worse, "own" on its own parameters)."""

    def run(ctx: dg.Context) -> dg.Finding | None:
        if _has(ctx.model, cid):
            return None
        calls.append(cid + ("|" + other if _has(ctx.model, other) else ""))
        gain = beside if _has(ctx.model, other) else alone
        ext = replace(ctx.model, hum=ctx.model.hum + ((f"toy:{cid}", 1.0, 0.0, 0.0),))
        f = dg.Finding(cid, f"toy {cid}", 1.0, 1.0 - gain / 100.0, gain, {}, ["tri"], ["tri"], 100.0, 0.01, ext)
        if refused and not _has(ctx.model, other):
            f = replace(f, refused=f"toy refusal ({refused})", refused_by_runs=refused == "runs")
        return f

    return Cause(cid, "toy", "toy", run)


def _diagnose(
    monkeypatch, a: tuple[float, float], b: tuple[float, float], refused: str = ""
) -> tuple[dg.Diagnosis, list[str]]:
    calls: list[str] = []
    toys = {"a": _toy("a", "b", *a, calls, refused), "b": _toy("b", "a", *b, calls)}
    monkeypatch.setattr(search, "CAUSES", toys)
    return search.diagnose(BASE, [_run()]), calls


def test_two_effects_each_short_alone_are_named_together(monkeypatch):
    # each alone below the bar (a compromise fit), each a finding beside the other
    d, calls = _diagnose(monkeypatch, (12.0, 26.0), (9.0, 31.0))
    assert sorted(f.cause for f in d.findings) == ["a", "b"], d.summary
    assert _has(d.model, "a") and _has(d.model, "b")  # the model carries both
    by = {f.cause: f for f in d.findings}
    assert by["a"].gain_pct == pytest.approx(26.0)  # its gain with the other in the model
    assert by["b"].gain_pct == pytest.approx(31.0)
    assert all(f.accepted for f in d.findings)
    assert "named together with b: alone it predicted 12 % better" in by["a"].evidence
    assert calls[:4] == ["a", "b", "b|a", "a|b"]


@pytest.mark.parametrize("beside", [(26.0, 15.0), (15.0, 26.0)])
def test_a_pair_where_one_adds_too_little_beside_the_other_names_nothing(monkeypatch, beside):
    d, _ = _diagnose(monkeypatch, (12.0, beside[0]), (9.0, beside[1]))
    assert d.findings == [], d.summary


def test_candidates_too_weak_alone_are_not_tried_together(monkeypatch):
    d, calls = _diagnose(monkeypatch, (12.0, 40.0), (4.0, 40.0))  # b predicts under 5 % better alone
    assert 4.0 < search.PAIR_MIN_GAIN_PCT
    assert d.findings == [] and calls == ["a", "b"], calls


def test_a_cause_named_alone_is_named_in_its_round(monkeypatch):
    d, calls = _diagnose(monkeypatch, (MIN_GAIN_PCT + 10.0, 30.0), (9.0, 25.0))
    assert [f.cause for f in d.findings] == ["a", "b"]  # a, then b beside it in the next round
    assert "named together" not in d.findings[0].evidence
    assert calls == ["a", "b", "b|a"]


def test_a_cause_refused_on_held_out_runs_is_tried_with_the_other(monkeypatch):
    # the third test press, a FIFO delay with a coupled drive: the coupling alone predicted 21 %
    # better but the 5 Hz triangle 145 % worse (the delay it did not model lagged it), so its
    # signature check refused it; beside the delay it predicts every sweep better
    d, calls = _diagnose(monkeypatch, (21.0, 49.0), (18.0, 57.0), refused="runs")
    assert sorted(f.cause for f in d.findings) == ["a", "b"], d.summary
    assert calls[:4] == ["a", "b", "b|a", "a|b"]  # a predicted best alone: b is fitted beside it first


def test_a_cause_refused_on_its_own_parameters_is_not_tried_in_a_pair(monkeypatch):
    # a slew whose steps' own slews grow with the step is no rate limit, whatever is beside it
    d, calls = _diagnose(monkeypatch, (29.0, 49.0), (18.0, 57.0), refused="own")
    assert d.findings == [] and calls == ["a", "b"], calls
