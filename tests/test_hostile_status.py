"""Every run directory's status is read: a stage refuses a directory whose manifest is not
``complete`` (one line: the directory, its status and reason, the flag), or with
``--accept-incomplete`` uses its complete runs and says so (stderr and the report's inputs),
naming the runs it skipped; ``report`` checks the directory is of the kind asked for."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from piezopress.errors import PiezopressError
from piezopress.piezocli.main import cli
from piezopress.pipelines import files

ROOT = Path(__file__).resolve().parents[1]
CHAR = ROOT / "sample_runs" / "characterization"
VAL = ROOT / "sample_runs" / "validation"


def copy_with_status(src: Path, dest: Path, status: str, *, incomplete_run: bool = False) -> Path:
    """A copy of a sample run directory whose manifest says ``status``; optionally its last run
    listed as incomplete (as characterize lists a run cut short)."""
    shutil.copytree(src, dest)
    m = json.loads((dest / "manifest.json").read_text())
    m["status"] = status
    if status != "complete":
        m["status_reason"] = "interrupted by SIGTERM" if status == "interrupted" else "RuntimeError: DAQ on fire"
    if incomplete_run:
        last = m["runs"][-1]
        (dest / last["file"]).rename(dest / last["file"].replace(".parquet", ".incomplete.parquet"))
        last["file"] = last["file"].replace(".parquet", ".incomplete.parquet")
        last["status"] = "incomplete"
    (dest / "manifest.json").write_text(json.dumps(m))
    return dest


@pytest.mark.parametrize("status", ["interrupted", "running", "failed"])
def test_check_status_refuses_a_directory_that_is_not_complete(tmp_path, status):
    d = copy_with_status(CHAR, tmp_path / "c", status)
    with pytest.raises(PiezopressError) as err:
        files.run_files(d)
    text = str(err.value)
    assert "\n" not in text and f"status {status!r}" in text and str(d) in text and "--accept-incomplete" in text
    assert f"{len(list(CHAR.glob('*.parquet')))} complete run(s)" in text


def test_accepting_names_the_directory_and_every_skipped_run(tmp_path):
    d = copy_with_status(CHAR, tmp_path / "c", "interrupted", incomplete_run=True)
    notes = files.check_status(d, accept=True)
    assert len(notes) == 2
    complete = len(list(CHAR.glob("*.parquet"))) - 1  # the last one listed as cut short
    assert (
        f"accepted although its manifest says status 'interrupted' (interrupted by SIGTERM); {complete} complete "
        "run(s) used" in notes[0]
    )
    assert notes[1].endswith("skipped incomplete run(s) rest-120s.incomplete.parquet")
    assert files.check_status(CHAR) == []  # complete: nothing to say


def test_report_refuses_a_validation_directory_given_as_the_characterization(tmp_path):
    res = CliRunner().invoke(cli, ["report", "--characterization", str(VAL), "--out", str(tmp_path / "r")])
    assert res.exit_code == 1
    assert res.output.strip().splitlines() == [
        f"Error: {VAL}: its manifest says kind 'validation'; expected a characterization directory (from `piezopress "
        "characterize`)"
    ]
    assert not (tmp_path / "r").exists() or not any((tmp_path / "r").iterdir())


@pytest.mark.parametrize(
    "command",
    [
        ["fit-shaper", "--out", "{tmp}/shaper.json"],
        ["fit-hysteresis", "--out", "{tmp}/h.json"],
        ["fit", "--out", "{tmp}/b.json"],
        ["diagnose", "--bundle", str(ROOT / "sample_runs" / "bundle.json"), "--out", "{tmp}/d"],
    ],
)
def test_stages_refuse_an_interrupted_directory_in_one_line(tmp_path, command):
    d = copy_with_status(CHAR, tmp_path / "c", "interrupted")
    args = [a.replace("{tmp}", str(tmp_path)) for a in command]
    res = CliRunner().invoke(cli, [args[0], str(d), *args[1:]])
    assert res.exit_code == 1, res.output
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"Error: {d}: its manifest says status 'interrupted'"), res.output
    assert not (tmp_path / "shaper.json").exists() and not (tmp_path / "b.json").exists()


def test_fit_shaper_with_accept_incomplete_uses_the_complete_runs_and_says_so(tmp_path):
    d = copy_with_status(CHAR, tmp_path / "c", "interrupted", incomplete_run=True)
    res = CliRunner().invoke(cli, ["fit-shaper", str(d), "--out", str(tmp_path / "shaper.json"), "--accept-incomplete"])
    assert res.exit_code == 0, res.output
    assert f"Note: {d}: accepted although its manifest says status 'interrupted'" in res.output
    assert "skipped incomplete run(s) rest-120s.incomplete.parquet" in res.output
    assert (tmp_path / "shaper.json").is_file()
    # the flag lasts one command: the next one refuses again
    res = CliRunner().invoke(cli, ["fit-shaper", str(d), "--out", str(tmp_path / "shaper2.json")])
    assert res.exit_code == 1 and "status 'interrupted'" in res.output
