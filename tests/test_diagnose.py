"""diagnose: an effect hidden in the virtual rig must be found, named, and shown to help on held-out data.

Each test characterizes a clean rig with one effect switched on at a magnitude drawn
(seeded) from its documented detectable range (`rig_config.DETECTABLE`), fits the thesis's
base model, runs diagnose, and asserts that the top finding names the hidden cause with a
held-out gain above `MIN_TEST_GAIN_PCT`. The clean rig must give no findings; two hidden
effects at once must both be found.

Each diagnosis takes 15-45 s: the integration tests (``make test-integration``, which CI runs after
the fast suite) keep one hidden effect on this rig (the delay, through the CLI:
:func:`test_cli_diagnose_json_progress_and_simulate`) and one on the second press
(``tests/test_diagnose_second_rig.py``); the rest are marked slow (``make test-all``),
and ``bench/bench_diagnose.py`` is the full measurement over 20 seeds.
"""

import json
import re

import independent_press as ip
import numpy as np
import pytest
from click.testing import CliRunner

from piezopress.acquisition.rig_config import EFFECTS, RigConfig, hidden_effect
from piezopress.acquisition.virtual_rig import VirtualRig
from piezopress.analysis import diagnosis as dg
from piezopress.piezocli.main import cli
from piezopress.pipelines import bundle as B
from piezopress.pipelines import characterize as char
from piezopress.pipelines import diagnose as D
from piezopress.pipelines import fit as F

#: The held-out gain a test demands of the named cause (the finding threshold is 20 %).
MIN_TEST_GAIN_PCT = 20.0
SEED = 20261121


#: A drifting sensitivity shows only between two runs of one drive apart in time: the default
#: plan with its slowest triangle played again at the end.
REPEAT_PLAN = ip.PLAN_WITH_REPEAT


def run_diagnosis(tmp, cfg, plan=None):
    char.characterize(tmp / "char", backend=VirtualRig(cfg), **({"plan_path": plan} if plan else {}))
    B.write_document(F.fit_bundle([tmp / "char"], base=True).doc, tmp / "base.json")  # `fit --base`
    result, _ = D.diagnose([tmp / "char"], tmp / "base.json", tmp / "diag")
    return result


@pytest.mark.slow
@pytest.mark.parametrize("effect", list(EFFECTS))
def test_a_hidden_effect_is_found_and_named(tmp_path, effect):
    rng = np.random.default_rng([SEED, list(EFFECTS).index(effect)])
    result = run_diagnosis(tmp_path, hidden_effect(effect, rng), REPEAT_PLAN if effect == "sensitivity_drift" else None)
    assert result.findings, result.summary
    top = result.findings[0]
    assert top.cause == effect, result.summary
    assert top.gain_pct >= MIN_TEST_GAIN_PCT
    assert top.extended_rms < top.baseline_rms
    doc = json.loads((tmp_path / "diag" / "diagnosis.json").read_text())
    assert doc["findings"][0]["cause"] == effect and doc["findings"][0]["heldout"]


@pytest.mark.slow
def test_clean_rig_gives_no_findings_and_says_so(tmp_path):
    result = run_diagnosis(tmp_path, RigConfig.clean())
    assert result.findings == [], result.summary
    assert result.summary.startswith("No")
    assert f"{result.noise_floor:.3g} N" in result.summary  # the two numbers: residual and noise floor


@pytest.mark.slow
def test_two_hidden_effects_are_both_found(tmp_path):
    cfg = RigConfig.only("input_delay", delay_s=3e-4).replace(mode2={"enabled": True}, rig={"seed": 7})
    result = run_diagnosis(tmp_path, cfg)
    named = [f.cause for f in result.findings]
    assert {"input_delay", "second_resonance"} <= set(named), result.summary
    assert all(
        f.gain_pct >= MIN_TEST_GAIN_PCT for f in result.findings if f.cause in ("input_delay", "second_resonance")
    )


@pytest.mark.slow
def test_a_delay_of_half_the_modes_period_is_named_alone(tmp_path):
    # 0.5 ms, half the 1 kHz mode's period: the steps' identification finds the mode at under
    # half its frequency, heavily damped; the delay's refit must reach the mode again (once a
    # spurious rate dependence, then a spurious interference, took up what it could not)
    result = run_diagnosis(tmp_path, RigConfig.only("input_delay", delay_s=5e-4).replace(rig={"seed": 1}))
    assert [f.cause for f in result.findings] == ["input_delay"], result.summary
    assert result.findings[0].parameters["delay_s"] == pytest.approx(5e-4, rel=0.05)


@pytest.mark.slow
def test_a_slew_limit_is_named_without_a_slow_coupling_beside_it(tmp_path):
    # the bench's draw (bench_diagnose, seed 1): with the slew taken, a 16 ms high-pass of the
    # drive (a 10 Hz corner) leading the sweeps 8-64 % better was named a coupling beside it (23 %
    # held out), and it predicted the 100 V step 51 % worse; the coupling's smoothing stops at 8 ms
    rng = np.random.default_rng([1, 99])
    result = run_diagnosis(tmp_path, hidden_effect("amplifier_slew_limit", rng))
    assert [f.cause for f in result.findings] == ["amplifier_slew_limit"], result.summary


@pytest.mark.slow
def test_found_parameters_match_the_rig(tmp_path):
    # the extension recovers the hidden physics, not just a better fit: delay and second mode
    result = run_diagnosis(tmp_path, RigConfig.only("input_delay", delay_s=2.5e-4))
    assert result.findings[0].parameters["delay_s"] == pytest.approx(2.5e-4, rel=0.1)


def test_unexplained_structure_is_listed_not_named():
    # a residual nothing in the catalogue explains (a 37 Hz tone) is listed as unexplained
    from piezopress.analysis.hysteresis import PIModel

    t = np.arange(4000) / 1000.0
    x = 75 * (1 - np.cos(2 * np.pi * 0.5 * t))
    model = dg.Model(PIModel((0.0,), (1.0,), (0.0,), (2.0,), y0=50.0))
    rng = np.random.default_rng(0)
    y = (
        model.predict(dg.RunData("r", "triangle", t, x, np.zeros_like(t), 1000.0))
        + 3.0 * np.sin(2 * np.pi * 37 * t)
        + rng.normal(0, 0.1, t.size)
    )
    run = dg.RunData("tone", "custom", t, x, y, 1000.0)
    result = dg.diagnose(model, [run])
    assert result.findings == []
    assert result.unexplained and result.unexplained[0]["run"] == "tone"
    assert result.unexplained[0]["dominant_freq_hz"] == pytest.approx(37.0, abs=0.5)
    # ... and said by its signature: a line the drive (0.5 Hz) does not have
    assert result.unexplained[0]["signature"] == "line"
    assert "tone it is a line at 37 Hz the drive does not have" in result.summary, result.summary
    from piezopress.pipelines.diagnose import format_summary

    lines = format_summary(result).splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith("    it is a line at 37 Hz"))
    assert lines[at + 1].startswith("        tone: "), lines[at : at + 2]


@pytest.mark.integration
def test_cli_diagnose_json_progress_and_simulate(tmp_path):
    """The representative hidden effect of this rig in the integration tests: a 0.3 ms delay named
    alone, its value recovered, through the CLI (--json: the document on stdout, the human
    text on stderr)."""
    runner = CliRunner()
    char.characterize(tmp_path / "char", backend=VirtualRig(RigConfig.only("input_delay", delay_s=3e-4)))
    assert (
        runner.invoke(cli, ["fit", str(tmp_path / "char"), "--base", "--out", str(tmp_path / "b.json")]).exit_code == 0
    )
    # --json: one document on stdout, the human lines on stderr
    res = runner.invoke(
        cli,
        [
            "diagnose",
            str(tmp_path / "char"),
            "--bundle",
            str(tmp_path / "b.json"),
            "--out",
            str(tmp_path / "d"),
            "--json",
        ],
    )
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert "Diagnosis: input_delay" in res.stderr and "held-out" in res.stderr and "Diagnosis:" not in res.stdout
    # piped: one progress line per cause tried, with its time, on stderr (never on --json's stdout)
    assert re.search(r"\[pass 1, 1/\d+\] \w+ +.* \(\d+\.\d s\)", res.stderr) and "[pass " not in res.stdout
    assert [f["cause"] for f in doc["findings"]] == ["input_delay"]  # named, and nothing else
    assert doc["findings"][0]["parameters"]["delay_s"] == pytest.approx(3e-4, rel=0.1)
    assert doc["findings"][0]["gain_pct"] >= MIN_TEST_GAIN_PCT
    assert doc["files"]["diagnosis"] == str(tmp_path / "d" / "diagnosis.json")
    written = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    assert set(doc) == set(written) | {"out_dir", "files"} and doc["findings"] == written["findings"]
    ext = json.loads((tmp_path / "d" / "extended_bundle.json").read_text())
    assert (
        "input_delay" in ext["extensions"] and ext["compensation"]["lead_s"] > 2e-4
    )  # the delay belongs in the compensator
    assert (tmp_path / "d" / "residuals.png").stat().st_size > 10_000
    res = runner.invoke(
        cli,
        [
            "simulate",
            str(tmp_path / "char" / "step-50v.parquet"),
            "--bundle",
            str(tmp_path / "b.json"),
            "--out",
            str(tmp_path / "sim.parquet"),
        ],
    )
    assert res.exit_code == 0, res.output
    from piezopress import runformat as rf

    sim = rf.read_run(tmp_path / "sim.parquet")
    np.testing.assert_allclose(sim.data["residual"], sim.data["force_n"] - sim.data["predicted"])


def test_an_unknown_cause_is_one_clear_line_before_anything_is_read(tmp_path):
    (tmp_path / "b.json").write_text("{}")
    res = CliRunner().invoke(
        cli,
        [
            "diagnose",
            str(tmp_path),
            "--bundle",
            str(tmp_path / "b.json"),
            "--out",
            str(tmp_path / "d"),
            "--cause",
            "bogus",
        ],
    )
    assert res.exit_code == 2
    lines = [ln for ln in res.output.splitlines() if ln.startswith("Error")]
    assert len(lines) == 1 and "'bogus'" in lines[0] and "input_delay" in lines[0], res.output
    assert not (tmp_path / "d").exists()
    with pytest.raises(
        D.UnknownCauseError, match="'bogus' is not in the catalogue; expected one of rate_dependent_hysteresis"
    ):
        D.diagnose([tmp_path], tmp_path / "b.json", tmp_path / "d", causes=["bogus"])
    with pytest.raises(ValueError, match="'bogus'"):
        dg.diagnose(dg.Model(dg.H.PIModel((0.0,), (1.0,), (0.0,), (1.0,))), [], causes=["input_delay", "bogus"])


def test_progress_is_reported_for_every_cause_tried_in_every_pass():
    """The analysis layer reports each cause before and after it is tried; the CLI's printer
    draws a line per cause on a terminal."""
    from piezopress.analysis.hysteresis import PIModel
    from piezopress.piezocli import cmd_diagnose

    t = np.arange(4000) / 1000.0
    x = 75 * (1 - np.cos(2 * np.pi * 0.5 * t))
    model = dg.Model(PIModel((0.0,), (1.0,), (0.0,), (2.0,), y0=50.0))
    y = model.predict(dg.RunData("r", "triangle", t, x, np.zeros_like(t), 1000.0)) + np.random.default_rng(0).normal(
        0, 0.1, t.size
    )
    events = []
    result = dg.diagnose(model, [dg.RunData("slow", "custom", t, x, y, 1000.0)], on_progress=events.append)
    tried = [t_["cause"] for t_ in result.tested]
    assert tried and [e.cause for e in events if not e.done] == tried  # one pass: nothing found
    assert [e.cause for e in events if e.done] == tried
    assert all(e.round == 1 and e.total == len(tried) for e in events)
    assert [e.index for e in events if e.done] == list(range(1, len(tried) + 1))
    assert not any(e.accepted for e in events)
    import io
    import sys

    piped = io.StringIO()  # not a terminal: a line per cause when done, nothing redrawn
    sys_stdout, sys.stdout = sys.stdout, piped
    try:
        show = cmd_diagnose._progress_printer(err=False)
        for e in events:
            show(e)
    finally:
        sys.stdout = sys_stdout
    lines = piped.getvalue().splitlines()
    assert len(lines) == len(tried) and "\r" not in piped.getvalue()
    assert all(f"] {c}" in line and line.endswith(" s)") for c, line in zip(tried, lines))


def test_the_progress_printer_draws_a_line_per_cause_on_a_terminal(monkeypatch):
    import io
    import sys

    from piezopress.piezocli import cmd_diagnose

    class Tty(io.StringIO):
        def isatty(self):
            return True

    out = Tty()
    monkeypatch.setattr(sys, "stderr", out)
    show = cmd_diagnose._progress_printer(err=True)
    for ev in (
        dg.CauseProgress(1, 1, 2, "input_delay", False),
        dg.CauseProgress(1, 1, 2, "input_delay", True, 91.6, True),
        dg.CauseProgress(1, 2, 2, "second_resonance", False),
        dg.CauseProgress(1, 2, 2, "second_resonance", True),
    ):
        show(ev)
    lines = out.getvalue().split("\n")
    assert "held-out gain 92 % (a finding) (" in lines[0] and "[pass 1, 1/2] input_delay" in lines[0]
    assert "nothing to fit (" in lines[1] and "[pass 1, 2/2] second_resonance" in lines[1] and lines[2] == ""


from conftest import DATASETS, needs_datasets  # noqa: E402


@pytest.mark.slow  # test_diagnose_coverage.py diagnoses both shared data sets in the integration tests
@needs_datasets("smarthysteresis")
def test_diagnose_runs_on_real_data_and_reports_in_its_unit(tmp_path):
    runner = CliRunner()
    run = tmp_path / "smart.parquet"
    assert (
        runner.invoke(
            cli,
            [
                "import",
                str(DATASETS / "smarthysteresis" / "hysteresis_v_150_1hz.csv"),
                "--out",
                str(run),
                "--no-header",
                "--kind",
                "sine",
                "--col",
                "t_s=2",
                "--col",
                "displacement_um=3",
                "--col",
                "command_v=4",
                "--sample-rate",
                "5000",
            ],
        ).exit_code
        == 0
    )
    assert runner.invoke(cli, ["fit-hysteresis", str(run), "--out", str(tmp_path / "h.json")]).exit_code == 0
    assert (
        runner.invoke(
            cli, ["bundle", "--hysteresis", str(tmp_path / "h.json"), "--out", str(tmp_path / "b.json")]
        ).exit_code
        == 0
    )
    res = runner.invoke(cli, ["diagnose", str(run), "--bundle", str(tmp_path / "b.json"), "--out", str(tmp_path / "d")])
    assert res.exit_code == 0, res.output
    assert " µm RMS" in res.output and " N RMS" not in res.output
    doc = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    # what it finds is reported either way: findings, or structure listed as unexplained
    assert doc["findings"] or doc["unexplained"] or doc["summary"].startswith("No findings")


@pytest.mark.slow
def test_a_log_creep_is_named_alone_where_its_hold_lags_the_command(tmp_path):
    """The draw of ``bench_diagnose --rig ours``, seed 0. The log creep's forms were fitted on the
    hold's step as it is: the output's lag behind the command at the edge (the mode's rise, the
    chain) went into Kelvin-Voigt elements of 0.05-0.5 s, 3 % of the step; the extension read the
    5-100 Hz triangles 23-45 % worse (level-free) and a coupling was named beside the creep to take
    that up, on 10 of 20 seeds. Fitted past the edge, as ``fit`` fits a held step, it reads every
    run better and is named alone (its size then read as what it adds to the model's creep over
    the decade after the hold: the tail's own rate trades off with the elements beside it)."""
    result = run_diagnosis(tmp_path, hidden_effect("logarithmic_creep", np.random.default_rng([0, 99])))
    assert [f.cause for f in result.findings] == ["logarithmic_creep"], [(f.cause, f.evidence) for f in result.findings]


def test_a_cause_whose_fit_raises_in_a_later_round_is_said_not_fitted(monkeypatch):
    """A cause that returned a finding in the first round and whose fit raises in the second is
    reported under ``tested`` as not fitted, with the error, not by the first round's result."""
    from dataclasses import replace as _replace

    from piezopress.analysis.diagnosis import search
    from piezopress.analysis.hysteresis import PIModel

    t = np.arange(4000) / 1000.0
    x = 75 * (1 - np.cos(2 * np.pi * 0.5 * t))
    model = dg.Model(PIModel((0.0,), (1.0,), (0.0,), (2.0,), y0=50.0))
    y = model.predict(dg.RunData("r", "triangle", t, x, np.zeros_like(t), 1000.0))
    run = dg.RunData("slow", "custom", t, x, y + np.random.default_rng(0).normal(0, 0.1, t.size), 1000.0)
    calls = {"b": 0}

    def finding(cause, ctx, gain):
        return dg.Finding(cause, "test", 1.0, 1.0 - gain / 100, gain, {}, ["slow"], ["slow"], 100.0, 0.01, ctx.model)

    def fit_a(ctx):
        return finding("input_delay", ctx, 50.0)

    def fit_b(ctx):
        calls["b"] += 1
        if calls["b"] > 1:
            raise RuntimeError("second round broke")
        return finding("sensor_offset_drift", ctx, 20.0)

    causes = dict(search.CAUSES)
    causes["input_delay"] = _replace(causes["input_delay"], run=fit_a, needs=())
    causes["sensor_offset_drift"] = _replace(causes["sensor_offset_drift"], run=fit_b, needs=())
    monkeypatch.setattr(search, "CAUSES", causes)
    result = dg.diagnose(model, [run], causes=["input_delay", "sensor_offset_drift"])
    tested = {t["cause"]: t["result"] for t in result.tested}
    assert calls["b"] == 2
    assert tested["input_delay"] == "found"
    assert tested["sensor_offset_drift"].startswith("not fitted (RuntimeError: second round broke")


def test_a_log_creep_too_small_against_an_unpinned_creep_is_said_beside_the_drift_that_took_it(monkeypatch):
    """The third test press, log creep seed 13: the log creep predicted the hold 84 % better but was
    too small beside the base's creep spectrum, whose elements slower than the hold no run pins; a
    drift of the rests was then named at 21 %, and the log creep had nothing left to fit. The drift
    is said to be possibly the log creep, and the log creep's held step stays in the next plan."""
    from dataclasses import replace as _replace

    from piezopress.analysis.diagnosis import search
    from piezopress.analysis.hysteresis import PIModel
    from piezopress.pipelines import next_plan

    t = np.arange(4000) / 1000.0
    x = 75 * (1 - np.cos(2 * np.pi * 0.5 * t))
    model = dg.Model(PIModel((0.0,), (1.0,), (0.0,), (2.0,), y0=50.0))
    y = model.predict(dg.RunData("r", "triangle", t, x, np.zeros_like(t), 1000.0))
    run = dg.RunData("slow", "custom", t, x, y + np.random.default_rng(0).normal(0, 0.1, t.size), 1000.0)

    def finding(cause, ctx, gain, **kw):
        f = dg.Finding(cause, "test", 1.0, 1.0 - gain / 100, gain, {}, ["slow"], ["slow"], 100.0, 0.01, ctx.model)
        return _replace(f, **kw)

    def log_creep(tell_s):
        def fit(ctx):  # nothing to fit once the drift is in the model (a drift of the rests in it)
            if ctx.model.drift_per_s:
                return None
            return finding("logarithmic_creep", ctx, 84.0, too_small="under the 0.4 %", tell_hold_s=tell_s)

        return fit

    def drift(ctx):
        f = finding("sensor_offset_drift", ctx, 21.0)
        return _replace(f, model=_replace(ctx.model, drift_per_s=1e-3))

    def diagnosed(tell_s):
        causes = dict(search.CAUSES)
        causes["logarithmic_creep"] = _replace(causes["logarithmic_creep"], run=log_creep(tell_s), needs=())
        causes["sensor_offset_drift"] = _replace(causes["sensor_offset_drift"], run=drift, needs=())
        monkeypatch.setattr(search, "CAUSES", causes)
        return dg.diagnose(model, [run], causes=["logarithmic_creep", "sensor_offset_drift"])

    result = diagnosed(1210.0)
    assert [f.cause for f in result.findings] == ["sensor_offset_drift"]
    assert result.findings[0].could_also_be == {"logarithmic_creep": 84.0}, result.findings[0]
    said = "sensor_offset_drift could also be logarithmic_creep (held-out gain 84 % before sensor_offset_drift"
    assert said in result.summary, result.summary
    assert next_plan.hold_findings(result) == {"logarithmic_creep": 1210.0}
    tested = {t["cause"]: t["result"] for t in result.tested}
    assert tested["logarithmic_creep"].startswith("not found (nothing to fit once sensor_offset_drift"), tested
    # the hold is asked for whatever the finding gained on the runs (the decade after the hold is
    # what no run shows): its gain across the runs against a drift they show may be none
    gained_nothing = _replace(result, considered=[_replace(f, gain_pct=0.0) for f in result.considered])
    assert next_plan.hold_findings(gained_nothing) == {"logarithmic_creep": 1210.0}
    # a log creep too small against a creep the runs do pin (no hold asked for) is no rival: nothing said
    plain = diagnosed(0.0)
    assert plain.findings[0].could_also_be == {} and "could also be" not in plain.summary
    assert next_plan.hold_findings(plain) == {}


@pytest.mark.parametrize(
    ("first_given_second", "second_after_first", "split"),
    [(5.0, 54.0, True), (30.0, 54.0, False), (15.0, 54.0, False), (15.0, 40.0, True)],
)
def test_a_finding_that_a_later_one_explains_is_named_as_that_one_alone(
    monkeypatch, first_given_second, second_after_first, split
):
    """One effect is not split into two names. The third test press, second resonance seed 4: a
    delay (40 %) and the second mode (36 %) both cleared the bar in the first round, the delay was
    named first and the mode after it (54 %), and the delay was never asked again. It is now asked
    with the mode's own extension in the model: no finding there (5 %), the mode is named alone, in
    its place, with its gain on the model without the delay, and the delay is tried again and said
    not found; still a finding (30 %), both stay named.

    Two effects are not merged into one either (the second test press, delay + interference seed 1,
    metadata cut): where the delay still predicts 15 % better on the mode fitted alone (at least
    ``SPLIT_RETEST_GAIN_PCT``, under the bar) and the model with both predicts 28 % better than the
    mode alone (0.46 against 0.64), both stay named, the evidence saying why; where the model with
    both predicts only 6 % better (0.60 against 0.64), the mode is named alone."""
    from dataclasses import replace as _replace

    from piezopress.analysis.diagnosis import search
    from piezopress.analysis.hysteresis import PIModel

    t = np.arange(4000) / 1000.0
    x = 75 * (1 - np.cos(2 * np.pi * 0.5 * t))
    model = dg.Model(PIModel((0.0,), (1.0,), (0.0,), (2.0,), y0=50.0))
    y = model.predict(dg.RunData("r", "triangle", t, x, np.zeros_like(t), 1000.0))
    run = dg.RunData("steps", "custom", t, x, y + np.random.default_rng(0).normal(0, 0.1, t.size), 1000.0)

    def finding(cause, ctx, gain, model):
        return dg.Finding(cause, "test", 1.0, 1.0 - gain / 100, gain, {}, ["steps"], ["steps"], 100.0, 0.01, model)

    def delay(ctx):  # the delay's extension marks the model with a chain delay
        m = ctx.model
        if m.drive_delay_s:
            return None
        gain = first_given_second if m.wn else 40.0
        return finding("input_delay", ctx, gain, _replace(m, drive_delay_s=1e-4))

    def mode(ctx):  # the mode's extension marks it with a mode
        m = ctx.model
        if m.wn:
            return None
        gain = second_after_first if m.drive_delay_s else 36.0
        return finding("second_resonance", ctx, gain, _replace(m, wn=8000.0, zeta=0.04))

    causes = dict(search.CAUSES)
    causes["input_delay"] = _replace(causes["input_delay"], run=delay, needs=())
    causes["second_resonance"] = _replace(causes["second_resonance"], run=mode, needs=())
    monkeypatch.setattr(search, "CAUSES", causes)
    result = dg.diagnose(model, [run], causes=["input_delay", "second_resonance"])
    named = {f.cause: f.gain_pct for f in result.findings}
    tested = {t["cause"]: t["result"] for t in result.tested}
    assert search.SPLIT_RETEST_GAIN_PCT <= 15.0 and first_given_second < dg.MIN_GAIN_PCT or not split
    if split:
        assert named == {"second_resonance": 36.0}, result.summary
        (f,) = result.findings
        assert "named in place of input_delay" in f.evidence and "one effect, not two" in f.evidence
        assert f.model.wn and not f.model.drive_delay_s  # the model without the delay
        assert tested["input_delay"].startswith("not found"), tested
        if first_given_second >= search.SPLIT_RETEST_GAIN_PCT:  # said how little both gain
            assert "the model with both predicts the held-out runs 6 % better than it" in f.evidence
    else:
        assert named == {"input_delay": 40.0, "second_resonance": second_after_first}, result.summary
        assert all("named in place of" not in f.evidence for f in result.findings)
        mode = next(f for f in result.findings if f.cause == "second_resonance")
        kept = "the model with both predicts the held-out runs 28 % better than second_resonance alone"
        assert (kept in mode.evidence and "two effects" in mode.evidence) == (first_given_second < dg.MIN_GAIN_PCT)
