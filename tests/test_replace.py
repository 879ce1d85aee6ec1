"""``--replace`` never loses (issue 14), one spelling on every writer (issue 12), and output
places are checked before any work, with one line when they cannot be written."""

from __future__ import annotations

import json
import multiprocessing
import os
import threading
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from piezopress.errors import OutputExistsError, PiezopressError
from piezopress.piezocli.main import cli
from piezopress.pipelines import files

ROOT = Path(__file__).resolve().parents[1]
BUNDLE = ROOT / "sample_runs" / "bundle.json"
STEP = ROOT / "sample_runs" / "characterization" / "step-20v.parquet"


def invoke(*args):
    res = CliRunner().invoke(cli, [str(a) for a in args])
    return res.exit_code, res.output


def _text_writer(text: str):
    return lambda tmp: Path(tmp).write_text(text)


def versions(path: Path) -> list[str]:
    """The current text of ``path`` and of every kept version."""
    return sorted([path.read_text()] + [p.read_text() for p in path.parent.glob(path.name + ".replaced-*")])


def test_two_replaces_in_a_row_keep_every_version(tmp_path):
    out = tmp_path / "doc.json"
    assert files.write_output(out, _text_writer("v1")) is None
    with pytest.raises(OutputExistsError, match="already exists; refusing to overwrite it"):
        files.write_output(out, _text_writer("lost?"))
    kept2 = files.write_output(out, _text_writer("v2"), replace=True)
    kept3 = files.write_output(out, _text_writer("v3"), replace=True)
    assert kept2 != kept3 and kept2.read_text() == "v1" and kept3.read_text() == "v2" and out.read_text() == "v3"
    assert kept2.name.startswith("doc.json.replaced-") and not kept2.name.endswith(
        ".json"
    )  # not picked up as a document
    assert versions(out) == ["v1", "v2", "v3"]
    assert not [p for p in tmp_path.iterdir() if "partial" in p.name or p.name.endswith(".lock")]


def test_concurrent_replaces_keep_every_version(tmp_path):
    """Eight threads replace one file at once: the original and all eight are recoverable."""
    out = tmp_path / "bundle.json"
    out.write_text("original")
    barrier = threading.Barrier(8)
    errors = []

    def replace(i):
        try:
            barrier.wait()
            files.write_output(out, _text_writer(f"writer {i}"), replace=True)
        except Exception as exc:  # noqa: BLE001 - collected and reported below
            errors.append(exc)

    threads = [threading.Thread(target=replace, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert versions(out) == sorted(["original"] + [f"writer {i}" for i in range(8)])


def _replace_in_process(path: str, text: str) -> None:
    files.write_output(Path(path), _text_writer(text), replace=True)


def test_concurrent_replaces_from_two_processes_keep_every_version(tmp_path):
    out = tmp_path / "drive.csv"
    out.write_text("original")
    ctx = multiprocessing.get_context("fork")
    procs = [ctx.Process(target=_replace_in_process, args=(str(out), f"process {i}")) for i in range(4)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(30)
    assert [p.exitcode for p in procs] == [0] * 4
    assert versions(out) == sorted(["original"] + [f"process {i}" for i in range(4)])


def test_a_failed_write_leaves_the_old_version_in_place(tmp_path):
    out = tmp_path / "doc.json"
    out.write_text("v1")

    def broken(tmp):
        Path(tmp).write_text("half")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        files.write_output(out, broken, replace=True)
    assert out.read_text() == "v1" and sorted(p.name for p in tmp_path.iterdir()) == ["doc.json"]


def test_a_directory_is_kept_whole_under_a_new_name(tmp_path):
    out = tmp_path / "report"
    for text in ("first", "second"):
        out.mkdir()
        (out / "report.md").write_text(text)
        files.keep_previous(out)
    kept = sorted(tmp_path.glob("report.replaced-*"))
    assert len(kept) == 2 and sorted((k / "report.md").read_text() for k in kept) == ["first", "second"]


def test_an_unwritable_folder_is_one_line(tmp_path, monkeypatch):
    """A read-only output folder: one line naming it, before any work (root ignores permissions, so the
    check is exercised through os.access as it reports a read-only folder)."""
    folder = tmp_path / "ro"
    folder.mkdir()
    real = os.access
    monkeypatch.setattr(os, "access", lambda p, mode, **kw: False if Path(p) == folder else real(p, mode, **kw))
    with pytest.raises(
        PiezopressError, match=r"ro: cannot write there \(permission denied\); expected a folder you may write to"
    ):
        files.check_output(folder / "out.json")
    code, out = invoke(
        "compensate", "--bundle", BUNDLE, "--reference", tmp_path / "missing.csv", "--out", folder / "d.csv"
    )
    assert code == 1 and out.count("\n") == 1 and "cannot write there" in out  # refused before the reference is read


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0, reason="root may write into a read-only folder")
def test_a_read_only_folder_is_one_line(tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        code, out = invoke("simulate", STEP, "--bundle", BUNDLE, "--out", folder / "sim.parquet")
        assert code == 1 and out.startswith("Error: ") and out.count("\n") == 1 and "cannot write there" in out
    finally:
        folder.chmod(0o700)


def test_a_file_in_place_of_the_folder_is_one_line(tmp_path):
    (tmp_path / "f").write_text("x")
    code, out = invoke("simulate", STEP, "--bundle", BUNDLE, "--out", tmp_path / "f" / "sim.parquet")
    assert code == 1 and out.startswith("Error: ") and out.count("\n") == 1 and "f: is a file; expected a folder" in out
    code, out = invoke("diagnose", STEP, "--bundle", BUNDLE, "--cause", "input_delay", "--out", tmp_path / "f" / "diag")
    assert code == 1 and out.startswith("Error: ") and out.count("\n") == 1, out


def test_missing_folders_are_created(tmp_path):
    """Issue 14: `simulate --out` under a missing folder gave a traceback."""
    code, out = invoke("simulate", STEP, "--bundle", BUNDLE, "--out", tmp_path / "a" / "b" / "sim.parquet")
    assert code == 0, out
    assert (tmp_path / "a" / "b" / "sim.parquet").is_file()


@pytest.fixture()
def ref_csv(tmp_path) -> Path:
    t = np.arange(500) / 1000.0
    pd.DataFrame({"t_s": t, "reference_n": np.linspace(0, 50, t.size)}).to_csv(tmp_path / "ref.csv", index=False)
    return tmp_path / "ref.csv"


def _kept_from(output: str) -> Path:
    line = [ln for ln in output.splitlines() if "previous version kept as" in ln][0]
    return Path(line.split("previous version kept as ")[1].rstrip(")"))


@pytest.mark.parametrize("command", ["compensate", "simulate", "import"])
def test_every_writer_refuses_then_replaces_keeping_the_old_version(command, tmp_path, ref_csv):
    src = tmp_path / "src.csv"
    pd.DataFrame(
        {"t_s": np.arange(100) / 100.0, "command_v": np.linspace(0, 1, 100), "force_n": np.linspace(0, 2, 100)}
    ).to_csv(src, index=False)
    out = tmp_path / ("out.csv" if command == "compensate" else "out.parquet")
    args = {
        "compensate": ["compensate", "--bundle", BUNDLE, "--reference", ref_csv, "--out", out],
        "simulate": ["simulate", STEP, "--bundle", BUNDLE, "--out", out],
        "import": ["import", src, "--out", out, "--col", "t_s=1", "--col", "command_v=2", "--col", "force_n=3"],
    }[command]
    out.write_bytes(b"precious")
    code, text = invoke(*args)
    assert code == 1 and "already exists" in text and "--replace" in text and out.read_bytes() == b"precious"
    kept, written = [], []
    for _ in range(2):
        code, text = invoke(*args, "--replace")
        assert code == 0, text
        kept.append(_kept_from(text))
        written.append(out.read_bytes())  # an import records its time: compare with what this replace wrote
    assert kept[0] != kept[1] and kept[0].read_bytes() == b"precious" and kept[1].read_bytes() == written[0]
    assert kept[1].read_bytes() != b"precious"


@pytest.mark.integration
def test_report_replaced_twice_keeps_both_old_reports(tmp_path):
    out = tmp_path / "r"
    assert invoke("report", "--bundle", BUNDLE, "--out", out)[0] == 0
    for _ in range(2):
        code, text = invoke("report", "--bundle", BUNDLE, "--out", out, "--replace")
        assert code == 0, text
    kept = sorted(tmp_path.glob("r.replaced-*"))
    assert len(kept) == 2 and all((k / "report.md").is_file() for k in kept)


def test_every_file_writer_has_replace_with_one_spelling():
    """`--replace` on every command that writes files it can replace (one spelling, no `--overwrite`/`--force`)."""
    import click

    ctx = click.Context(cli)
    writers = [
        "import",
        "compensate",
        "simulate",
        "report",
        "bundle",
        "fit",
        "fit-hysteresis",
        "fit-creep",
        "fit-shaper",
    ]
    for name in writers:
        opts = {o for p in cli.get_command(ctx, name).params for o in getattr(p, "opts", [])}
        assert "--replace" in opts, name
    for name in cli.list_commands(ctx):
        opts = {o for p in cli.get_command(ctx, name).params for o in getattr(p, "opts", [])}
        assert not opts & {"--overwrite", "--force", "--replace-existing"}, name


def test_a_bundle_never_holds_a_non_finite_number(tmp_path):
    from piezopress.pipelines import bundle as B

    doc = json.loads(BUNDLE.read_text())
    doc["hysteresis"]["fit"]["holdout_rms_pct_of_range"] = float("nan")
    B.write_document(doc, tmp_path / "b.json")
    text = (tmp_path / "b.json").read_text()
    assert "NaN" not in text and json.loads(text)["hysteresis"]["fit"]["holdout_rms_pct_of_range"] is None


@pytest.mark.parametrize("command", ["fit-hysteresis", "fit-shaper", "fit"])
def test_fit_commands_refuse_their_output_before_fitting(command, tmp_path, monkeypatch):
    """Issue 14: `fit-shaper` found a read-only folder only after the whole fit."""
    from piezopress.pipelines import fit as F

    for name in ("fit_hysteresis_section", "fit_shaper_section", "fit_all"):
        monkeypatch.setattr(F, name, lambda *a, **k: pytest.fail("fitted although the output is refused"))
    (tmp_path / "f").write_text("x")
    code, out = invoke(command, ROOT / "sample_runs" / "characterization", "--out", tmp_path / "f" / "out.json")
    assert code == 1 and out.startswith("Error: ") and out.count("\n") == 1 and "is a file; expected a folder" in out
