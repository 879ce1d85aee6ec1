"""``fit --structure``: the hysteresis structure given instead of searched for.

The search chooses the structure on the sweeps' held-out ends, which are mostly their largest
loops; structures within a few percent there can compensate the press very differently (on the
third test press, seed 2: 'n=8 gamma=2 m=4 plane=20' held out 0.513 N and compensated the
0.1 Hz loop to 0.76 %; 'n=24 gamma=1 m=16 plane=16' held out 0.568 N and compensated it to
3.0 %). A lab keeps the structure it validated on its press through refits, or fits two and lets
``piezopress compare`` judge them on the press.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from piezopress.analysis import hysteresis as H
from piezopress.analysis import identification as ident
from piezopress.analysis.bundle import BundleError
from piezopress.piezocli.main import cli
from tests.foreign import foreign_run

ROOT = Path(__file__).resolve().parents[1]
CHAR = ROOT / "sample_runs" / "characterization"


@pytest.mark.parametrize(
    "cand",
    [
        H.Candidate(12, 1.0, 1),
        H.Candidate(8, 2.0, 4, 20),
        H.Candidate(6, 1.5, 0, 0, 8),
        H.Candidate(1, 1.0, 2, 0, 16, "descended"),
    ],
)
def test_a_structure_reads_back_from_the_label_fit_prints(cand):
    assert ident.parse_structure(cand.label) == cand
    assert ident.parse_structure("  " + cand.label.replace(" ", "   ") + " ") == cand  # spacing is free


@pytest.mark.parametrize(
    ("label", "why"),
    [
        ("n=8 gamma=2", "m missing"),
        ("n=8 gamma=2 m=4 planes=20", "unknown key 'planes'"),
        ("n=8 gamma=2 m=4 plane", "'plane' is not key=value"),
        ("n=eight gamma=2 m=4", "n=eight is not a whole number"),
        ("n=0 gamma=2 m=4", "n=0; expected at least 1"),
        ("n=8 gamma=-1 m=4", "gamma=-1; expected a number above 0"),
        ("n=8 gamma=nan m=4", "expected a number above 0"),
        ("n=8 gamma=2 m=4 plane=1", "plane=1; expected at least 2"),
        ("n=8 gamma=2 m=4 plane=8 duhem=4", "a plane and Duhem elements at once"),
        ("n=8 gamma=2 m=4 rest=relaxed", "rest= belongs to Duhem elements"),
        ("n=8 gamma=2 m=4 duhem=4 rest=sideways", "rest=sideways; expected one of relaxed, descended"),
        ("n=8 n=9 gamma=2 m=4", "n given twice"),
        ("", "n, gamma, m missing"),
    ],
)
def test_a_structure_that_cannot_be_read_is_refused_naming_the_value_and_the_form(label, why):
    with pytest.raises(BundleError) as err:
        ident.parse_structure(label)
    text = str(err.value)
    assert why in text and repr(label) in text and "n=PLAYS gamma=SPACING m=DEAD_ZONES" in text, text


@pytest.fixture(scope="module")
def runs():
    names = ("triangle-0.1hz", "creep-150v", "step-20v", "step-150v")
    from piezopress import runformat

    return [foreign_run(runformat.read_run(CHAR / f"{n}.parquet"), custom=True) for n in names]


@pytest.mark.integration
def test_the_structure_given_is_the_one_fitted_recorded_and_in_the_digest(runs):
    label = "n=6 gamma=2 m=2"
    found = ident.identify(runs, structure=label)
    fit = found.sections["hysteresis"]["fit"]
    assert fit["chosen"] == label and fit["structure_given"].startswith(label)
    assert fit["reason"].startswith(f"{label}, given, not searched for: ")
    assert [c["candidate"] for c in fit["candidates"]] == [label]  # nothing else was tried
    assert found.settings["hysteresis"]["structure"] == label == found.settings["creep"]["structure"]
    assert "structure" not in ident.identify(runs).settings["hysteresis"]  # a searched fit keeps its old digest
    with pytest.raises(BundleError, match="the base is the thesis's structure"):
        ident.identify(runs, structure=label, base=True)


def test_fit_structure_on_the_command_line(tmp_path):
    run = CHAR / "triangle-0.1hz.parquet"
    out = tmp_path / "b.json"
    res = CliRunner().invoke(cli, ["fit", str(run), "--structure", "n=6 gamma=2 m=2", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "hysteresis: n=6 gamma=2 m=2" in res.output and "given (--structure)" in res.output
    assert out.exists()
    bad = tmp_path / "bad.json"
    res = CliRunner().invoke(cli, ["fit", str(run), "--structure", "n=6 gamma=2", "--out", str(bad)])
    lines = res.output.strip().splitlines()
    assert res.exit_code == 1 and lines[-1].startswith("Error: structure 'n=6 gamma=2': m missing"), res.output
    assert "Traceback" not in res.output and not bad.exists()


def test_fit_hysteresis_keeps_the_structure_given_and_refits_when_it_changes(tmp_path):
    """``make refit STRUCTURE=...`` passes it to fit-hysteresis: the structure is part of the
    section's inputs, so --if-changed refits when it changes and not when it does not."""
    run = CHAR / "triangle-0.1hz.parquet"
    out = tmp_path / "h.json"

    def fit(*extra):
        return CliRunner().invoke(cli, ["fit-hysteresis", str(run), "--out", str(out), "--if-changed", *extra])

    res = fit("--structure", "n=6 gamma=2 m=2")
    assert res.exit_code == 0 and "Chosen: n=6 gamma=2 m=2" in res.output, res.output
    import json

    assert json.loads(out.read_text())["fit"]["structure_given"].startswith("n=6 gamma=2 m=2, given")
    assert "up to date" in fit("--structure", "n=6 gamma=2 m=2").output
    res = fit("--structure", "n=4 gamma=1 m=1")
    assert res.exit_code == 0 and "Chosen: n=4 gamma=1 m=1" in res.output, res.output
    res = fit("--structure", "n=4 gamma=1 m=1 plane=1")
    assert res.exit_code == 1 and "plane=1; expected at least 2" in res.output and "Traceback" not in res.output


def test_the_report_says_the_structure_was_given(tmp_path):
    import json

    from piezopress.pipelines.report_doc import render_markdown
    from piezopress.pipelines.report_model import _model_quality

    doc = json.loads((ROOT / "sample_runs" / "bundle.json").read_text())
    assert "fit --structure" not in render_markdown(_model_quality(doc, tmp_path / "bundle.json", []))
    doc["hysteresis"]["fit"]["structure_given"] = "n=6 gamma=2 m=2, given (structure=): not searched for"
    md = render_markdown(_model_quality(doc, tmp_path / "bundle.json", []))
    assert "Structure: n=6 gamma=2 m=2, given (structure=): not searched for (fit --structure)." in md, md
