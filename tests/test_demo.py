"""``piezopress demo``: the chain of ``make demo`` as one command (issue 12)."""

from pathlib import Path

import pytest
from click.testing import CliRunner

from piezopress.piezocli.main import cli

ROOT = Path(__file__).resolve().parents[1]


def test_make_demo_runs_the_demo_command():
    make = (ROOT / "Makefile").read_text()
    recipe = make[make.index("\ndemo:") :].split("\n\n")[0]
    assert "$(PP) demo --out" in recipe  # one chain, two ways to start it: the same report


def test_demo_refuses_a_directory_that_holds_anything(tmp_path):
    (tmp_path / "keep.txt").write_text("data")
    res = CliRunner().invoke(cli, ["demo", "--out", str(tmp_path)])
    assert res.exit_code != 0 and "exists and is not empty" in res.output
    assert (tmp_path / "keep.txt").read_text() == "data" and len(list(tmp_path.iterdir())) == 1


@pytest.mark.slow
def test_demo_runs_the_whole_chain_to_a_report(tmp_path):
    res = CliRunner().invoke(cli, ["demo", "--out", str(tmp_path / "d")])
    assert res.exit_code == 0, res.output
    for part in (
        "characterization/manifest.json",
        "bundle.json",
        "validation/manifest.json",
        "base-bundle.json",
        "diagnosis/diagnosis.json",
        "report/report.html",
        "report/metrics.csv",
    ):
        assert (tmp_path / "d" / part).is_file(), part
    assert res.output.count("\n== ") == 6 and f"Report: {tmp_path / 'd' / 'report' / 'report.html'}" in res.output
    assert res.output.count("Report: ") == 1  # once, not twice
    assert res.output.rstrip().splitlines()[-1].startswith("The demo took ")
