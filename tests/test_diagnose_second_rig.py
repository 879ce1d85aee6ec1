"""diagnose on a press it did not simulate: ``tests/independent_press.py``.

The detectors key on signatures (where in time, at which rates and frequencies, with which
sign the residual appears), not on the virtual rig's forms. The second press hides every
cause of the catalogue in another form (``independent_press.DETECTABLE``: a saturating rate
dependence scaling the loop, a slew limit ahead of the amplifier's bandwidth, interference in
proportion to the signed drive current, a broad irregular creep spectrum, a second mode with
its own damping, a warm-up drift with no rest run in the plan, a delay ahead of the stack, an
S-shaped static map). Each test characterizes the press with one effect at a magnitude drawn
(seeded) from its documented detectable range, fits the thesis's base model (the ``fit --base``
path), runs diagnose, and asserts that the hidden cause, and nothing else, is named; the clean
press gives no finding. ``bench/bench_diagnose.py --rig second`` runs the same over 20 seeds.
"""

import json
import tomllib
from pathlib import Path

import independent_press as ip
import numpy as np
import pytest

from piezopress.analysis import diagnosis as dg
from piezopress.pipelines import bundle as B
from piezopress.pipelines import characterize as char
from piezopress.pipelines import diagnose as D
from piezopress.pipelines import fit as F
from piezopress.resources import shipped

HERE = Path(__file__).resolve().parent
SEED = 20261122
#: One representative runs with the integration tests (CI); the rest are marked slow (``make test-all``).
FAST = ("rate_dependent_hysteresis",)


def run_diagnosis(tmp: Path, press: ip.IndependentPress, plan: Path | None = None) -> dg.Diagnosis:
    char.characterize(tmp / "char", backend=press, **({"plan_path": plan} if plan else {}))
    B.write_document(F.fit_bundle([tmp / "char"], press.limits, base=True).doc, tmp / "base.json")  # `fit --base`
    result, _ = D.diagnose([tmp / "char"], tmp / "base.json", tmp / "diag")
    return result


def test_the_second_press_hides_every_cause_of_the_catalogue():
    assert set(ip.DETECTABLE) == set(dg.CAUSES)
    clean = vars(ip.clean_press(np.random.default_rng(0)))
    for effect in dg.CAUSES:
        hidden = vars(ip.hidden_press(effect, np.random.default_rng(0)))
        changed = {k for k in clean if clean[k] != hidden[k]} - {"stiffness_n", "seed", *ip.NUISANCE}
        assert changed == set(ip.DETECTABLE[effect]), (effect, changed)
    assert ip.plan_for("sensor_offset_drift") == ip.PLAN_WITHOUT_REST and ip.plan_for("input_delay") is None


def test_the_plan_without_rest_is_the_default_plan_less_its_rest_runs():
    default = tomllib.loads(shipped("protocols", "characterize.toml").read_text(encoding="utf-8"))
    no_rest = tomllib.loads(ip.PLAN_WITHOUT_REST.read_text(encoding="utf-8"))
    assert {k: v for k, v in no_rest["plan"].items() if k != "description"} == {
        k: v for k, v in default["plan"].items() if k != "description"
    }
    rests = [p for p in default["protocol"] if p["kind"] == "custom" and all(v == 0.0 for _, v in p["points"])]
    assert rests and no_rest["protocol"] == [p for p in default["protocol"] if p not in rests]


@pytest.mark.slow
def test_the_clean_second_press_gives_no_finding(tmp_path):
    result = run_diagnosis(tmp_path, ip.clean_press(np.random.default_rng([SEED, 99])))
    assert result.findings == [], result.summary
    assert result.summary.startswith("No")


@pytest.mark.integration
@pytest.mark.parametrize("effect", [pytest.param(e, marks=() if e in FAST else pytest.mark.slow) for e in dg.CAUSES])
def test_a_cause_hidden_in_the_second_press_is_named_alone(tmp_path, effect):
    rng = np.random.default_rng([SEED, list(dg.CAUSES).index(effect)])
    result = run_diagnosis(tmp_path, ip.hidden_press(effect, rng), ip.plan_for(effect))
    assert [f.cause for f in result.findings] == [effect], result.summary
    assert result.findings[0].gain_pct >= dg.MIN_GAIN_PCT


@pytest.mark.slow
@pytest.mark.parametrize("seed", [3, 5, 7])
def test_interference_is_named_beside_a_delay_it_shares_a_lag_with(tmp_path, seed):
    """Issue 20, two effects at once, on the second press (its interference follows the delayed
    drive through a 0.2 ms filter): the delay is found first and took up part of the artefact's
    lag; the interference, fitted on the drive as the model delays it and with the delay fitted
    again, is named too (seed 3: the delay alone was named before, interference 16 %; seeds 5
    and 7, the bench's: the delay alone was named while the delay was refitted on a grid of its
    fractions only; refined between them, the coupling gains 31 % held out). Seed 3 again (stops
    68-73): a rate dependence and a second mode were named beside the pair, for the misfit the
    coupling's filter left on the grid's 0.1 ms (the press's is 0.2 ms); refined, the pair alone."""
    press = ip.hidden_press("input_delay+drive_coupled_interference", np.random.default_rng([seed, 98]))
    char.characterize(tmp_path / "char", backend=press)
    B.write_document(F.fit_bundle([tmp_path / "char"], base=True).doc, tmp_path / "base.json")
    res, _ = D.diagnose([tmp_path / "char"], tmp_path / "base.json", tmp_path / "diag")
    assert {f.cause for f in res.findings} == {"input_delay", "drive_coupled_interference"}, res.summary


@pytest.mark.slow
@pytest.mark.parametrize("seed", [2, 3])
def test_a_drift_alone_is_not_taken_for_a_log_creep(tmp_path, seed):
    """The draws of ``bench_diagnose --rig second`` (a warm-up drift of 5-7 N/min in every run, no
    rest run, no log creep). On the hold alone the log creep's forms, each fitted with a drift of
    its own, cancelled a slow Kelvin-Voigt element of up to 74 % of the step against that drift,
    and a log creep was named beside the drift on 5 seeds of 20. Judged across the long runs at
    other drive levels against the drift (a drift moves every run alike, a creep each with its
    own drive), the tail adds nothing and the drift is named alone."""
    press = ip.hidden_press("sensor_offset_drift", np.random.default_rng([seed, 98]))
    result = run_diagnosis(tmp_path, press, ip.plan_for("sensor_offset_drift"))
    assert [f.cause for f in result.findings] == ["sensor_offset_drift"], result.summary


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 10])
def test_a_slew_limit_and_a_drift_are_named_and_nothing_beside_them(tmp_path, seed):
    """Issue 20, two effects at once (the draws of ``bench_diagnose --rig second --pairs``): both
    were named, and ``hysteresis_order`` beside them on 7 seeds of 20 (these two among them):
    more operators were judged against as many evenly spaced plays as the base kept (the
    thesis's 12 pruned to 7, spaced as 12), whose misfit counted as their gain (24 % on seed 0;
    7 % against the base's own operators fitted again)."""
    press = ip.hidden_press("amplifier_slew_limit+sensor_offset_drift", np.random.default_rng([seed, 98]))
    result = run_diagnosis(tmp_path, press, ip.plan_for("amplifier_slew_limit+sensor_offset_drift"))
    assert {f.cause for f in result.findings} == {"amplifier_slew_limit", "sensor_offset_drift"}, result.summary


@pytest.mark.slow
def test_an_s_curve_the_thesis_structure_misfits_past_its_bound_is_still_named(tmp_path):
    """Issue 20 (seed 2 of ``bench_diagnose --rig second --effects hysteresis_order``): the S-curve
    took the thesis's structure past BASE_THESIS_NOISE times the sweeps' noise floor (22x), the
    Duhem elements won the search, and the base was searched: ``hysteresis_order`` was not tested,
    on 11 of 20 seeds. More play operators draw it within the bound (4.6x), so the base keeps the
    thesis's structure, and more operators are named."""
    press = ip.hidden_press("hysteresis_order", np.random.default_rng([2, 98]))
    result = run_diagnosis(tmp_path, press, ip.plan_for("hysteresis_order"))
    assert [f.cause for f in result.findings] == ["hysteresis_order"], result.summary
    assert result.findings[0].gain_pct >= 50.0  # 85.8 % measured
    base = json.loads((tmp_path / "base.json").read_text(encoding="utf-8"))["hysteresis"]
    assert base["model"]["family"] == "modified_pi" and "base_structure" not in base["fit"]
