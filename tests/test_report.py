"""`piezopress report`: files, determinism, a self-contained page, missing pieces, safe output.

The inputs are built once for the module from small plans (a few seconds on the virtual
rig): a two-cycle 0.1 Hz triangle, a 20 s creep hold, a 20 V step; then `fit`; then a
small validation with a 0.1 Hz triangle that suits its metric, one that does not (one
cycle: only a descending branch is left after the virgin half cycle), a creep hold, a step
and a five-stair staircase.
"""

import csv
import io
import math

import pytest
from click.testing import CliRunner

from piezopress import thesis
from piezopress.piezocli.main import cli
from piezopress.pipelines import characterize as char
from piezopress.pipelines import report as rep
from piezopress.pipelines import summary
from piezopress.pipelines import validate as val

CHAR_PLAN = """
[plan]
name = "report-small"
preload_n = 50.0
[[protocol]]
name = "triangle-0.1hz"
kind = "triangle"
freq_hz = 0.1
peaks_v = [150.0, 150.0]
sample_rate_hz = 100.0
[[protocol]]
name = "creep-150v"
kind = "creep"
level_v = 150.0
pre_s = 1.0
hold_s = 20.0
sample_rate_hz = 200.0
[[protocol]]
name = "step-20v"
kind = "step"
level_v = 20.0
pre_s = 0.01
hold_s = 0.05
post_s = 0.01
sample_rate_hz = 20000.0
"""

VAL_PLAN = """
[plan]
name = "report-small-validation"
preload_n = 50.0
[[protocol]]
name = "tri-300n-0.1hz"
kind = "triangle"
freq_hz = 0.1
cycles = 2
peak_n = 300.0
sample_rate_hz = 100.0
[[protocol]]
name = "tri-75n-0.1hz"
kind = "triangle"
freq_hz = 0.1
cycles = 1
peak_n = 75.0
sample_rate_hz = 100.0
[[protocol]]
name = "creep-300n"
kind = "creep"
level_n = 300.0
pre_s = 1.0
hold_s = 20.0
sample_rate_hz = 200.0
[[protocol]]
name = "step-100n"
kind = "step"
level_n = 100.0
pre_s = 0.02
hold_s = 0.05
post_s = 0.01
sample_rate_hz = 20000.0
[[protocol]]
name = "staircase-10n"
kind = "staircase"
base_n = 0.0
step_n = 10.0
count = 5
dwell_s = 0.5
ramp_s = 0.005
pre_s = 0.5
sample_rate_hz = 2000.0
"""


def invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("report-inputs")
    (tmp / "plan.toml").write_text(CHAR_PLAN)
    (tmp / "val.toml").write_text(VAL_PLAN)
    char.characterize(tmp / "char", plan_path=tmp / "plan.toml")
    res = invoke("fit", tmp / "char", "--out", tmp / "bundle.json")
    assert res.exit_code == 0, res.output
    val.validate(tmp / "val", tmp / "bundle.json", plan_path=tmp / "val.toml")
    return {"char": tmp / "char", "val": tmp / "val", "bundle": tmp / "bundle.json"}


@pytest.fixture(scope="module")
def full(inputs, tmp_path_factory):
    out = tmp_path_factory.mktemp("reports") / "full"
    res = invoke(
        "report",
        "--characterization",
        inputs["char"],
        "--validation",
        inputs["val"],
        "--bundle",
        inputs["bundle"],
        "--out",
        out,
    )
    assert res.exit_code == 0, res.output
    return out, res.output


def read_metrics(path):
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.integration
def test_writes_every_file_and_prints_the_table_and_the_page(full):
    out, output = full
    for name in (
        "metrics.csv",
        "report.md",
        "report.html",
        "hysteresis_loops.png",
        "creep.png",
        "steps.png",
        "tracking.png",
        "model_residuals.png",
        "compensated_drive.png",
        "mode_bode.png",
        "shaper_sensitivity.png",
        "creep_bode.png",
    ):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    assert "| quantity" in output and "controlled (thesis)" in output
    assert output.rstrip().splitlines()[-1].endswith(str(out / "report.html"))
    md = (out / "report.md").read_text()
    for section in (
        "Table 6.13",
        "Characterization",
        "Validation",
        "Model quality",
        "Hysteresis",
        "Creep",
        "shaper",
        "Table 6.8",
        "held out",
        "](steps.png)",
    ):
        assert section in md, section


@pytest.mark.integration
def test_metrics_csv_is_byte_identical_for_the_same_inputs(inputs, full, tmp_path):
    out, _ = full
    res = invoke(
        "report",
        "--characterization",
        inputs["char"],
        "--validation",
        inputs["val"],
        "--bundle",
        inputs["bundle"],
        "--out",
        tmp_path / "again",
    )
    assert res.exit_code == 0, res.output
    assert (tmp_path / "again" / "metrics.csv").read_bytes() == (out / "metrics.csv").read_bytes()


@pytest.mark.integration
def test_metrics_csv_layout(full):
    out, _ = full
    text = (out / "metrics.csv").read_text()
    assert text.splitlines()[0] == "table,test,metric,unit,value,thesis,thesis_source"
    rows = read_metrics(out / "metrics.csv")
    first = [(r["table"], r["test"], r["metric"]) for r in rows[:16]]
    assert first == [
        ("6.13", t, f"{side}_{end}")
        for t in ("max_static_hysteresis", "creep", "overshoot", "tracking_error")
        for side in ("uncontrolled", "controlled")
        for end in ("min", "max")
    ]
    tables = {r["table"] for r in rows[16:]}
    assert {"5.1", "5.2", "5.3", "6.6", "6.5", "6.9", "6.6-tracking"} <= tables
    th = {(r["test"], r["metric"]): r for r in rows[:16]}
    # the thesis's ranges, as printed (%.6g of the constants)
    assert (
        float(th["max_static_hysteresis", "uncontrolled_min"]["thesis"])
        == thesis.TABLE_6_13["max_static_hysteresis_pct"]["uncontrolled"][0]
    )
    assert float(th["overshoot", "uncontrolled_max"]["thesis"]) == thesis.OVERSHOOT_20V_PCT
    assert float(th["tracking_error", "controlled_min"]["thesis"]) == thesis.TRACKING_RELATIVE_ERROR_PCT[0]
    assert (
        th["tracking_error", "uncontrolled_min"]["value"] == ""
        and th["tracking_error", "uncontrolled_min"]["thesis"] == ""
    )


@pytest.mark.integration
def test_table_6_13_equals_the_summary_tables(inputs, full):
    """The 6.13 figures are the summary tables' values (to the %.6g of the file: rel 1e-5)."""
    out, _ = full
    rows = {(r["test"], r["metric"]): r["value"] for r in read_metrics(out / "metrics.csv") if r["table"] == "6.13"}
    c = summary.characterization_table(inputs["char"])
    v = summary.validation_table(inputs["val"])

    def value(table, run, metric):
        return float(table[(table.run == run) & (table.metric == metric)].value.iloc[0])

    expect = {
        ("max_static_hysteresis", "uncontrolled"): [value(c, "triangle-0.1hz", "max_hysteresis")],
        ("max_static_hysteresis", "controlled"): [
            value(v, "tri-300n-0.1hz", "max_hysteresis")
        ],  # tri-75n does not suit
        ("creep", "uncontrolled"): [value(c, "creep-150v", "creep")],
        ("creep", "controlled"): [value(v, "creep-300n", "creep")],
        ("overshoot", "uncontrolled"): [value(c, "step-20v", "overshoot")],
        ("overshoot", "controlled"): [value(v, "step-100n", "overshoot")],
        ("tracking_error", "controlled"): [value(v, "staircase-10n", "tracking_relative")],
    }
    for (test, side), vals in expect.items():
        assert all(math.isfinite(x) for x in vals)
        assert float(rows[test, f"{side}_min"]) == pytest.approx(min(vals), rel=1e-5, abs=1e-9)
        assert float(rows[test, f"{side}_max"]) == pytest.approx(max(vals), rel=1e-5, abs=1e-9)
    # every summary row follows, in order, with its value
    detail = [r for r in read_metrics(out / "metrics.csv") if r["table"] != "6.13"]
    assert [(r["test"], r["metric"]) for r in detail] == list(zip(c.run, c.metric)) + list(zip(v.run, v.metric))


@pytest.mark.integration
def test_html_is_self_contained(full):
    out, _ = full
    page = (out / "report.html").read_text()
    assert 'src="http' not in page and "<link" not in page and "<script" not in page and "@import" not in page
    srcs = page.split('src="')[1:]
    # every figure written as PNG is embedded, and nothing else is loaded
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert len(pngs) == 9 and len(srcs) == len(pngs) and all(s.startswith("data:image/png;base64,") for s in srcs)
    assert "max-width: 1100px" in page
    assert "Table 6.13" in page and "Model quality" in page


@pytest.mark.integration
def test_a_run_that_does_not_suit_its_metric_is_listed(full):
    out, output = full
    md = (out / "report.md").read_text()
    assert "tri-75n-0.1hz: does not suit its metric" in md and "tri-75n-0.1hz: does not suit its metric" in output


@pytest.mark.integration
@pytest.mark.parametrize(
    "given, expected, absent",
    [
        (
            ("char",),
            [
                "No validation runs given: controlled figures are missing (run `piezopress validate`).",
                "No bundle given",
            ],
            ["tracking.png", "model_residuals.png"],
        ),
        (
            ("bundle",),
            ["No characterization runs given", "No validation runs given"],
            ["steps.png", "creep.png", "tracking.png"],
        ),
        (("char", "bundle"), ["No validation runs given"], ["tracking.png"]),
    ],
)
def test_missing_pieces_are_said_not_crashed_on(inputs, tmp_path, given, expected, absent):
    opts = {"char": "--characterization", "val": "--validation", "bundle": "--bundle"}
    args = [a for k in given for a in (opts[k], inputs[k])]
    res = invoke("report", *args, "--out", tmp_path / "r")
    assert res.exit_code == 0, res.output
    md = (tmp_path / "r" / "report.md").read_text()
    page = (tmp_path / "r" / "report.html").read_text()
    for line in expected:
        assert line in md and line in res.output
    for name in absent:
        assert not (tmp_path / "r" / name).exists()
    assert "Table 6.13" in md and "Table 6.13" in page
    assert read_metrics(tmp_path / "r" / "metrics.csv")[0]["table"] == "6.13"
    if "bundle" in given:
        assert "Model quality" in md and (tmp_path / "r" / "model_residuals.png").is_file()


@pytest.mark.integration
def test_refuses_a_non_empty_out_with_one_line(inputs, tmp_path):
    out = tmp_path / "busy"
    out.mkdir()
    (out / "keep.txt").write_text("data")
    res = invoke("report", "--bundle", inputs["bundle"], "--out", out)
    assert res.exit_code == 1
    assert res.output.strip().count("\n") == 0 and res.output.startswith("Error:") and str(out) in res.output
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"]
    # --replace does not touch a directory that is not a report either
    res = invoke("report", "--bundle", inputs["bundle"], "--out", out, "--replace")
    assert res.exit_code == 1 and "not a piezopress report" in res.output
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"]


@pytest.mark.integration
def test_replace_keeps_the_old_report_under_a_timestamped_name(inputs, tmp_path):
    out = tmp_path / "r"
    assert invoke("report", "--bundle", inputs["bundle"], "--out", out).exit_code == 0
    res = invoke("report", "--bundle", inputs["bundle"], "--out", out)
    assert res.exit_code == 1  # never overwritten without --replace
    res = invoke(
        "report", "--characterization", inputs["char"], "--bundle", inputs["bundle"], "--out", out, "--replace"
    )
    assert res.exit_code == 0, res.output
    kept = list(tmp_path.glob("r.replaced-*"))  # a new timestamped name each time: nothing is lost
    assert len(kept) == 1 and str(kept[0]) in res.output
    assert "No characterization runs given" in (kept[0] / "report.md").read_text()
    assert "No characterization runs given" not in (out / "report.md").read_text()
    assert not list(tmp_path.glob(".*partial"))


@pytest.mark.integration
def test_an_empty_out_dir_is_accepted_and_inputs_are_checked(inputs, tmp_path):
    (tmp_path / "empty").mkdir()
    assert invoke("report", "--bundle", inputs["bundle"], "--out", tmp_path / "empty").exit_code == 0
    res = invoke("report", "--out", tmp_path / "none")
    assert res.exit_code == 1 and "nothing to report" in res.output
    res = invoke("report", "--characterization", tmp_path / "nope", "--out", tmp_path / "x")
    assert res.exit_code == 1 and "no such directory" in res.output and not (tmp_path / "x").exists()


def test_markdown_and_html_render_the_same_blocks():
    blocks = [rep.Heading("T", 1), rep.Para("a `code` |x|"), rep.Table(("h", "n"), (("a|b", "1.00"),), ("l", "r"))]
    md = rep.render_markdown(blocks)
    assert (
        "# T" in md and "| a\\|b | 1.00 |" in md and "|------|-----:|" in md
    )  # pipe escaped in its cell; numbers right-aligned
    page = rep.render_html(blocks)
    assert "<code>code</code>" in page and "<td>a|b</td>" in page and '<td class="r">1.00</td>' in page
    csv_text = rep.metrics_csv(rep.metrics_table(None, None))
    rows = list(csv.reader(io.StringIO(csv_text)))
    assert len(rows) == 17 and all(r[4] == "" for r in rows[1:])  # the 6.13 rows, empty without inputs


def test_the_report_says_why_a_base_is_not_the_thesis_structure(tmp_path):
    """``fit --base`` records in ``hysteresis.fit.base_structure`` why it searched the structure
    (the loop is of another family, with the figures it was decided on); the report says it, and
    says nothing of it for a base in the thesis's structure (the sample bundle's)."""
    import json
    from pathlib import Path

    from piezopress.pipelines.report_doc import render_markdown
    from piezopress.pipelines.report_model import _model_quality

    doc = json.loads((Path(__file__).resolve().parents[1] / "sample_runs" / "bundle.json").read_text())
    assert "Not the thesis's structure" not in render_markdown(_model_quality(doc, tmp_path / "b.json", []))
    why = "the structure searched as fit's is (n=8 gamma=1 m=16 plane=12 ...): the loop is of another family"
    doc["hysteresis"]["fit"]["base_structure"] = why
    assert f"Not the thesis's structure: {why}." in render_markdown(_model_quality(doc, tmp_path / "b.json", []))
