"""Issue 21: ``compare`` (bundles played on one press, interleaved and repeated, each row
judged beyond the spread), ``diagnose --gain`` on the press, and the recommended bundle that
adopts only what wins there."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from piezopress.analysis import ab
from piezopress.piezocli.main import cli
from piezopress.pipelines import compare as cmp

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_runs"
BUNDLE = SAMPLES / "bundle.json"

#: A short plan: one slow loop and two steps (the overshoot row), played in about a second.
PLAN = textwrap.dedent(
    """
    [plan]
    name = "short"
    preload_n = 50.0

    [[protocol]]
    name = "tri-150n-1hz"
    kind = "triangle"
    freq_hz = 1.0
    cycles = 2
    peak_n = 150.0
    sample_rate_hz = 2000.0

    [[protocol]]
    name = "step-100n"
    kind = "step"
    level_n = 100.0
    pre_s = 0.02
    hold_s = 0.1
    post_s = 0.05
    sample_rate_hz = 20000.0

    [[protocol]]
    name = "step-150n"
    kind = "step"
    level_n = 150.0
    pre_s = 0.02
    hold_s = 0.1
    post_s = 0.05
    sample_rate_hz = 20000.0
    """
)


def invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


# --------------------------------------------------------------------------- the judging rule


def test_equal_presses_are_rarely_called_different_and_a_real_shift_always_is():
    """A/A with three repeats: 'better' or 'worse' in under 5 % of 2000 draws; a shift of
    ten standard deviations: 'better' in every draw."""
    rng = np.random.default_rng(0)
    n = 2000
    false = sum(ab.judge(rng.normal(1, 0.1, 3), rng.normal(1, 0.1, 3)).verdict != ab.SAME for _ in range(n))
    assert false / n < 0.05
    found = [ab.judge(rng.normal(1, 0.01, 3), rng.normal(0.9, 0.01, 3)).verdict for _ in range(200)]
    assert found.count(ab.BETTER) == 200


@pytest.mark.parametrize("seed", range(20))
def test_the_verdict_is_antisymmetric(seed):
    rng = np.random.default_rng(seed)
    a, b = rng.normal(1, 0.05, 3), rng.normal(1 + rng.normal(0, 0.1), 0.05, 3)
    flip = {ab.BETTER: ab.WORSE, ab.WORSE: ab.BETTER, ab.SAME: ab.SAME}
    assert ab.judge(b, a).verdict == flip[ab.judge(a, b).verdict]
    assert ab.judge(a, b).difference == pytest.approx(-ab.judge(b, a).difference)


def test_one_repeat_is_not_judged_and_constant_repeats_differ_when_apart():
    assert ab.judge([1.0], [0.5]).verdict == ab.UNJUDGED
    assert ab.judge([1.0, 1.0], [0.5, 0.5]).verdict == ab.BETTER
    assert ab.judge([1.0, 1.0], [1.0, 1.0]).verdict == ab.SAME
    assert ab.judge([np.nan], [1.0]).verdict == "not measured"


def test_an_extension_that_hurts_a_row_is_never_recommended():
    hurts = ab.Candidate("+slew", ("amplifier_slew_limit",), {"overshoot": ab.BETTER, "hysteresis_50hz": ab.WORSE})
    helps = ab.Candidate("+delay", ("input_delay",), {"tracking_random": ab.BETTER, "overshoot": ab.SAME})
    both = ab.Candidate("extended", ("amplifier_slew_limit", "input_delay"), {"overshoot": ab.BETTER, "x": ab.WORSE})
    rec = ab.recommend([hurts, helps, both])
    assert rec.label == "+delay" and rec.causes == ("input_delay",)
    assert rec.reasons["+slew"] == "left out: worse than the base on hysteresis_50hz"
    assert rec.reasons["extended"] == "left out: worse than the base on x"
    assert rec.reasons["+delay"].startswith("adopted")
    assert ab.recommend([hurts]).label is None  # nothing wins without a loss: the reference
    assert ab.recommend([ab.Candidate("e", ("a",), {"r": ab.SAME})]).reasons["e"].startswith("left out: no row")


@pytest.mark.integration
def test_the_rows_of_one_comparison_are_judged_together():
    """A/A over ten rows of three repeats (the second test press's spreads, 1-15 % of the mean):
    judged row by row, some row differs in about one comparison in six (16 % of 1000); judged
    together (Holm), in about one in a hundred; and a real 30 % change of a steady row is still
    found every time."""
    rng = np.random.default_rng(1)
    cv = np.geomspace(0.01, 0.15, 10)
    n, by_row, together = 1000, 0, 0
    for _ in range(n):
        a = {f"r{i}": rng.normal(1, c, 3) for i, c in enumerate(cv)}
        b = {f"r{i}": rng.normal(1, c, 3) for i, c in enumerate(cv)}
        by_row += any(ab.judge(a[r], b[r]).verdict != ab.SAME for r in a)
        together += any(j.verdict != ab.SAME for j in ab.judge_rows(a, b).values())
    assert together / n < 0.03 < 0.10 < by_row / n  # the correction is what keeps it rare
    for _ in range(100):
        a = {f"r{i}": rng.normal(1, c, 3) for i, c in enumerate(cv)}
        b = {**{f"r{i}": rng.normal(1, c, 3) for i, c in enumerate(cv)}, "r0": rng.normal(0.7, 0.01, 3)}
        assert ab.judge_rows(a, b)["r0"].verdict == ab.BETTER


def test_a_loss_the_repeats_do_not_exclude_keeps_a_bundle_out():
    """The second test press, extended bundle against the fitted one (input_delay, seed 1): a
    staircase 13 % worse, p = 0.10, no difference by the verdict's rule; a fresh comparison then
    found it 23 % worse. It is left out; a bundle better where it wins and within a few percent
    elsewhere is adopted."""
    fitted = {"tracking_staircase_abs": [1.80, 1.96, 2.12], "hysteresis_50hz": [3.65, 3.66, 3.67]}
    extended = {"tracking_staircase_abs": [2.15, 2.21, 2.27], "hysteresis_50hz": [0.94, 0.945, 0.95]}
    close = {"tracking_staircase_abs": [1.85, 1.98, 2.02], "hysteresis_50hz": [1.07, 1.06, 1.08]}
    rows = ab.judge_rows(fitted, extended)
    assert rows["tracking_staircase_abs"].verdict == ab.SAME and rows["tracking_staircase_abs"].possibly_worse
    assert rows["hysteresis_50hz"].verdict == ab.BETTER and not rows["hysteresis_50hz"].possibly_worse
    ext = ab.Candidate.judged("extended", ("input_delay",), rows)
    near = ab.Candidate.judged("fitted+input_delay", ("input_delay",), ab.judge_rows(fitted, close))
    rec = ab.recommend([ext, near], "the fitted bundle")
    assert rec.label == "fitted+input_delay"
    assert rec.reasons["extended"].startswith(
        "left out: may be worse than the fitted bundle on tracking_staircase_abs (+"
    )
    assert ab.recommend([ext], "the fitted bundle").label is None  # nothing else: the bundle in use


# --------------------------------------------------------------------------- compare on a press


def _without_shaper(tmp_path: Path) -> Path:
    doc = json.loads(BUNDLE.read_text())
    doc.pop("shaper")
    out = tmp_path / "no-shaper.json"
    out.write_text(json.dumps(doc))
    return out


def test_compare_plays_interleaved_repeats_and_judges_a_missing_shaper_worse(tmp_path):
    plan = tmp_path / "short.toml"
    plan.write_text(PLAN)
    res = cmp.compare(
        [BUNDLE, _without_shaper(tmp_path), BUNDLE],
        tmp_path / "cmp",
        rig_path=SAMPLES / "rig.toml",
        repeats=3,
        plans=[plan],
        labels=["shaped", "unshaped", "again"],
    )
    doc = json.loads((res.out_dir / cmp.COMPARE_JSON).read_text())
    assert doc["status"] == "complete"
    order = [(o["repeat"], o["bundle"]) for o in doc["order"]]
    assert order == [(1, "shaped"), (1, "unshaped"), (1, "again"), (2, "again"), (2, "unshaped"), (2, "shaped")] + [
        (3, "shaped"),
        (3, "unshaped"),
        (3, "again"),
    ]
    values = pd.read_csv(res.out_dir / cmp.REPEATS_CSV)
    assert len(values[(values["bundle"] == "shaped") & (values["row"] == "overshoot")]) == 3
    v = res.verdicts("unshaped")
    assert v["overshoot"] == ab.WORSE  # a press without its shaper rings
    assert set(res.verdicts("again").values()) == {ab.SAME}  # the same bundle again: nothing beyond the spread
    # every repeat is a run directory as validate writes it
    assert (res.out_dir / "rep2" / "unshaped" / "short" / "manifest.json").is_file()


def test_compare_refuses_a_press_the_plan_would_exceed_before_playing_anything(tmp_path):
    rig = tmp_path / "narrow.toml"
    text = (SAMPLES / "rig.toml").read_text()
    assert "drive_max_v = 150.0" in text
    rig.write_text(text.replace("drive_max_v = 150.0", "drive_max_v = 10.0"))
    res = invoke("compare", BUNDLE, BUNDLE, "--rig", rig, "--out", tmp_path / "cmp", "--repeats", "2")
    assert res.exit_code == 1, res.output
    assert "cannot be reached on this rig" in res.output and "drive range" in res.output
    assert not (tmp_path / "cmp").exists()


def test_compare_names_what_it_cannot_do(tmp_path):
    res = invoke("compare", BUNDLE, "--out", tmp_path / "c")
    assert res.exit_code == 1 and "expected two or more" in res.output
    res = invoke("compare", BUNDLE, BUNDLE, "--label", "a", "--out", tmp_path / "c")
    assert res.exit_code == 1 and "1 label(s) for 2 bundles" in res.output
    res = invoke("compare", BUNDLE, BUNDLE, "--label", "a", "--label", "a", "--out", tmp_path / "c")
    assert res.exit_code == 1 and "expected one distinct" in res.output
    assert not (tmp_path / "c").exists()


def test_compare_cli_prints_the_table_and_the_report_shows_it(tmp_path):
    plan = tmp_path / "short.toml"
    plan.write_text(PLAN)
    out = tmp_path / "cmp"
    res = invoke("compare", BUNDLE, _without_shaper(tmp_path), "--plan", plan, "--repeats", "2", "--out", out)
    assert res.exit_code == 0, res.output
    assert "no-shaper vs bundle" in res.output and "Next:" in res.output
    res = invoke("report", "--comparison", out, "--out", tmp_path / "rep")
    assert res.exit_code == 0, res.output
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "## Comparison on the press" in md and "no-shaper vs bundle" in md
    assert (tmp_path / "rep" / "compare_cmp.png").is_file()
    (out / cmp.COMPARE_JSON).write_text(json.dumps({"status": "interrupted", "reason": "KeyboardInterrupt"}))
    res = invoke("report", "--comparison", out, "--out", tmp_path / "rep2")
    assert res.exit_code == 0
    assert "the comparison is interrupted (KeyboardInterrupt)" in (tmp_path / "rep2" / "report.md").read_text()


# --------------------------------------------------------------------------- diagnose --gain on the press


@pytest.mark.integration
def test_diagnose_gain_on_the_press_leaves_out_an_extension_that_hurts_there(tmp_path):
    """On the sample press the log-creep extension halves the creep but widens the 0.1 Hz
    loop: measured on the press, it is not recommended, and the extended bundle says what the
    press said of it."""
    out = tmp_path / "diag"
    res = invoke(
        "diagnose",
        SAMPLES / "characterization",
        "--bundle",
        SAMPLES / "base-bundle.json",
        "--cause",
        "logarithmic_creep",
        "--gain",
        "--rig",
        SAMPLES / "rig.toml",
        "--out",
        out,
    )
    assert res.exit_code == 0, res.output
    table = pd.read_csv(out / "gain-on-press" / cmp.COMPARE_CSV)
    ext = table[table["bundle"] == "extended"].set_index("row")["verdict"]
    assert ext["creep"] == ab.BETTER and ext["static_hysteresis"] == ab.WORSE
    rec = json.loads((out / "recommended_bundle.json").read_text())
    assert rec["recommendation"]["adopted"] == [] and rec["recommendation"]["bundle"] == "base"
    assert rec["recommendation"]["reasons"]["extended"].startswith(
        "left out: worse than the base bundle on static_hysteresis"
    )
    assert "extensions" not in rec  # the base's own content
    gain = json.loads((out / "extended_bundle.json").read_text())["gain_on_press"]
    assert gain["measured"] is True and "static_hysteresis" in gain["worse_on"]
    assert "Recommended:" in res.output and "left out" in res.output


def test_an_unmeasured_extension_says_it_is_unverified_on_the_press(tmp_path):
    out = tmp_path / "diag"
    res = invoke(
        "diagnose",
        SAMPLES / "characterization",
        "--bundle",
        SAMPLES / "base-bundle.json",
        "--cause",
        "logarithmic_creep",
        "--out",
        out,
    )
    assert res.exit_code == 0, res.output
    assert "unverified on the press" in res.output
    ext = json.loads((out / "extended_bundle.json").read_text())
    assert ext["gain_on_press"]["measured"] is False and "unverified on the press" in ext["gain_on_press"]["note"]
    res = invoke("report", "--diagnosis", out, "--out", tmp_path / "rep")
    assert res.exit_code == 0, res.output
    assert "The extended bundle is unverified on the press" in (tmp_path / "rep" / "report.md").read_text()


def test_rig_without_gain_is_a_usage_error(tmp_path):
    res = invoke(
        "diagnose",
        SAMPLES / "characterization",
        "--bundle",
        BUNDLE,
        "--rig",
        SAMPLES / "rig.toml",
        "--out",
        tmp_path / "d",
    )
    assert res.exit_code == 2 and "give --gain too" in res.output


def test_a_steady_change_too_small_to_feel_is_no_difference():
    # apart, p < 0.05, but 1.4 % of the value: the same to whoever uses the press
    assert ab.judge([0.4760, 0.4767, 0.4775], [0.4690, 0.4698, 0.4710]).verdict == ab.SAME
    assert ab.judge([0.4760, 0.4767, 0.4775], [0.4390, 0.4398, 0.4410]).verdict == ab.BETTER
