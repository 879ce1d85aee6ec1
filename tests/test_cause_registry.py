"""One object per cause (issue 20): the catalogue (:data:`piezopress.analysis.diagnosis.CAUSES`)
holds each cause's physics, fit, needs, extension of the bundle and target rows, and every
other place that names causes reads it or names exactly the same set."""

from __future__ import annotations

import sys
from pathlib import Path

from piezopress.acquisition import rig_config
from piezopress.analysis import diagnosis as dg
from piezopress.pipelines import gain

sys.path.insert(0, str(Path(__file__).resolve().parent))

import independent_press as ip  # noqa: E402
import third_press as tp  # noqa: E402

#: Effects the third press simulates that the catalogue does not hold yet (said by the
#: drive-independent signatures instead: ``piezopress.analysis.signatures``).
NOT_IN_CATALOGUE: set[str] = set()


def test_every_registry_names_the_catalogue():
    causes = set(dg.CAUSES)
    assert set(rig_config.EFFECTS) == causes  # the virtual rig simulates each one
    assert set(rig_config.DETECTABLE) == causes
    assert set(gain.GAIN_MAGNITUDES) == causes  # and measures its gain on the press
    assert set(ip.DETECTABLE) == causes  # the second press hides each one in a form of its own
    assert set(tp.DETECTABLE) == causes | NOT_IN_CATALOGUE  # the third press too, and two more


def test_each_cause_is_one_module_and_the_catalogue_lists_every_one():
    """Adding a cause is one new module under ``diagnosis/causes/`` (plus its simulated effect):
    each module's ``CAUSE`` is the catalogue's entry of the same id, and no module is left out."""
    import importlib
    import pkgutil

    from piezopress.analysis.diagnosis import causes

    modules = sorted(m.name for m in pkgutil.iter_modules(causes.__path__))
    assert modules == sorted(dg.CAUSES)
    for name in modules:
        entry = importlib.import_module(f"{causes.__name__}.{name}").CAUSE
        assert entry is dg.CAUSES[name] and entry.id == name
        assert entry.run.__module__ == f"{causes.__name__}.{name}"  # its fit lives beside it


def test_the_compensator_applies_exactly_the_causes_that_extend_it():
    for c in dg.CAUSES.values():
        assert c.in_compensator == (c.extend is not None), c.id
        # an extension the compensator applies is judged on the rows it is for, and only those rows
        assert bool(c.targets) == c.in_compensator, c.id
        assert all(row in gain.ROW_BY_ID for row in c.targets), (c.id, c.targets)
    assert gain.targets() == {c.id: c.targets for c in dg.CAUSES.values() if c.in_compensator}
    assert gain.TARGETS == gain.targets()


# --------------------------------------------------------------------------- how sure


def _finding(gain: float, heldout: list[str], by_run: dict[str, float]) -> dg.Finding:
    from piezopress.analysis.hysteresis import PIModel

    model = dg.Model(PIModel((0.0,), (1.0,), (0.0,), (2.0,), y0=50.0))
    return dg.Finding("input_delay", "t", 1.0, 1 - gain / 100, gain, {}, heldout, heldout, 10.0, 0.1, model, by_run)


def test_each_finding_says_how_sure_it_is():
    strong = _finding(60.0, ["a", "b", "c"], {"a": 55.0, "b": 62.0, "c": 70.0})
    assert strong.strength == "strong" and strong.consistency == (3, 3)
    assert strong.strength_text() == "strong evidence: better on 3 of 3 held-out runs, held-out gain 60 %"
    mixed = _finding(60.0, ["a", "b", "c"], {"a": 90.0, "b": -3.0, "c": 40.0})
    assert mixed.strength == "moderate" and "(not on b)" in mixed.strength_text()
    lone = _finding(60.0, ["a", "b", "c"], {"a": 90.0, "b": -3.0, "c": -1.0})  # one run carries the gain
    assert lone.strength == "weak" and "better on 1 of 3 held-out runs (not on b, c)" in lone.strength_text()
    one_run = _finding(90.0, ["a"], {})
    assert one_run.strength == "weak" and "one held-out run only" in one_run.strength_text()
    together = _finding(25.0, ["a", "b"], {})  # judged on its runs together (the slow causes)
    assert together.strength == "moderate" and "2 runs together" in together.strength_text()
    doc = lone.as_dict()
    assert doc["evidence_strength"] == "weak" and doc["gain_by_heldout_run_pct"] == {"a": 90.0, "b": -3.0, "c": -1.0}


def test_the_summary_names_a_finding_on_weak_evidence(monkeypatch):
    from dataclasses import replace

    from test_diagnose_coverage import pi_run  # noqa: PLC0415 - the coverage tests' runs

    from piezopress.analysis.hysteresis import PIModel

    weak = _finding(60.0, ["a"], {})  # accepted (60 % gain, well above the floor), judged on one run
    monkeypatch.setitem(dg.CAUSES, "input_delay", replace(dg.CAUSES["input_delay"], run=lambda ctx: weak, needs=()))
    model = dg.Model(PIModel((0.0,), (1.0,), (0.0,), (2.0,), y0=50.0))
    result = dg.diagnose(model, [pi_run("a", 2200), pi_run("b", 1800, seed=1)], causes=["input_delay"])
    assert [f.cause for f in result.findings] == ["input_delay"]
    assert "weak evidence for input_delay (judged on one held-out run only, held-out gain 60 %)" in result.summary


def test_the_test_presses_hide_two_effects_at_once():
    """Pairs for the two-effects matrices (``bench/bench_diagnose.py --pairs``): both effects
    on, each within its documented range; a drift pair runs the plan without the rest run."""
    import numpy as np

    for mod in (ip, tp):
        pair = "input_delay+drive_coupled_interference"
        press = mod.hidden_press(pair, np.random.default_rng(3))
        params = press.describe()["parameters"]
        for one in pair.split("+"):
            for key, (lo, hi) in mod.DETECTABLE[one].items():
                assert lo <= abs(params[key]) <= hi, (mod.__name__, key, params[key])
    assert ip.plan_for("amplifier_slew_limit+sensor_offset_drift") == ip.PLAN_WITHOUT_REST
    assert ip.plan_for("input_delay+drive_coupled_interference") is None


def test_a_finding_names_the_cause_it_could_be_when_that_one_explained_the_same_residual(monkeypatch):
    """Issue 20, how sure: a cause that cleared the bar beside the one taken, and that nothing
    was left for once it was taken, is said as what the finding could also be (with its gain);
    a cause named after it (a second effect) is not."""
    from dataclasses import replace

    import numpy as np

    from piezopress.analysis.diagnosis import search
    from piezopress.analysis.hysteresis import PIModel

    model = dg.Model(PIModel((0.0,), (1.0,), (0.0,), (2.0,), y0=50.0))
    t = np.arange(0, 10, 1e-3)
    x = 50 + 50 * np.sin(2 * np.pi * 0.5 * t)
    run = dg.RunData("sweep", "sine", t, x, np.zeros_like(t), 1000.0)
    y = model.predict(run) + 3.0 * np.sin(2 * np.pi * 7 * t) + np.random.default_rng(0).normal(0, 0.1, t.size)
    run = replace(run, y=y)

    def fake(cause: str, first: float, after_a: float):
        def fit(ctx):
            g = after_a if ctx.model.delay_s > 0 else first
            ext = replace(ctx.model, delay_s=1e-3) if cause == "a" else ctx.model
            return dg.Finding(cause, "t", 1.0, 1 - g / 100, g, {}, ["sweep"], ["sweep"], 10.0, 0.1, ext)

        return fit

    causes = {
        "a": dg.Cause("a", "p", "e", fake("a", 60.0, 60.0)),
        "b": dg.Cause("b", "p", "e", fake("b", 50.0, 5.0)),  # took nothing once a was in the model
        "c": dg.Cause("c", "p", "e", fake("c", 40.0, 40.0)),  # a second effect: named after a
    }
    monkeypatch.setattr(search, "CAUSES", causes)
    res = search.diagnose(model, [run], causes=list(causes))
    assert [f.cause for f in res.findings] == ["a", "c"]
    a, c = res.findings
    assert a.could_also_be == {"b": 50.0} and c.could_also_be == {}
    assert "a could also be b (held-out gain 50 % before a was taken)" in res.summary
    assert a.as_dict()["could_also_be_gain_pct"] == {"b": 50.0}


def test_a_cause_judged_on_other_runs_is_not_what_a_finding_could_also_be(monkeypatch):
    """A rival must have explained what the finding explains: on the same held-out runs. A cause
    judged on the fast sweeps that cleared the bar beside a log creep judged on the hold is no
    rival of it, though it has nothing left once the creep is taken (the third test press, rate
    dependence and log creep hidden together, seed 2)."""
    from dataclasses import replace

    import numpy as np

    from piezopress.analysis.diagnosis import search
    from piezopress.analysis.hysteresis import PIModel

    model = dg.Model(PIModel((0.0,), (1.0,), (0.0,), (2.0,), y0=50.0))
    t = np.arange(0, 10, 1e-3)
    x = 50 + 50 * np.sin(2 * np.pi * 0.5 * t)
    runs = [dg.RunData(n, "sine", t, x, model.predict(dg.RunData(n, "sine", t, x, x, 1e3)), 1000.0) for n in ("h", "f")]

    def fake(cause: str, first: float, after_a: float, judged: str):
        def fit(ctx):
            g = after_a if ctx.model.delay_s > 0 else first
            ext = replace(ctx.model, delay_s=1e-3) if cause == "a" else ctx.model
            return dg.Finding(cause, "t", 1.0, 1 - g / 100, g, {}, [judged], [judged], 10.0, 0.1, ext)

        return fit

    for judged_b, rival in (("f", {}), ("h", {"b": 50.0})):
        causes = {
            "a": dg.Cause("a", "p", "e", fake("a", 60.0, 60.0, "h")),
            "b": dg.Cause("b", "p", "e", fake("b", 50.0, 5.0, judged_b)),
        }
        monkeypatch.setattr(search, "CAUSES", causes)
        (a,) = search.diagnose(model, runs, causes=list(causes)).findings
        assert a.could_also_be == rival, judged_b
