"""``piezopress import`` / ``inspect`` and :mod:`piezopress.pipelines.importing`.

The two shared data sets are imported with exactly the commands documented in
the README's "Importing measured data" (and in ``piezopress import --help``); everything else runs on small
synthetic tables written to ``tmp_path``.
"""

from __future__ import annotations

import hashlib
import os
import shlex
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from piezopress.errors import ImportFormatError
from piezopress.piezocli.main import cli
from piezopress.pipelines.importing import import_table
from piezopress.runformat import read_run

ROOT = Path(__file__).resolve().parents[1]
from conftest import DATASETS  # noqa: E402

DOCS = ROOT / "README.md"  # its "Importing measured data": the one documented form
DOC_PREFIX = "../shared/datasets/"  # how the documented commands name the data sets

SMART = "smarthysteresis/hysteresis_v_150_1hz.csv"
AYE_MODEL = "aye-ang-2018/Model_Vi_Do.dat"
AYE_TEST = "aye-ang-2018/Test_Vi_Do_Di.dat"

# CI always has shared/ beside the clone: there a missing data set is a failure, not a skip.
_HAVE_DATASETS = (DATASETS / SMART).is_file() and (DATASETS / AYE_MODEL).is_file()
if os.environ.get("CI") and not _HAVE_DATASETS:
    raise RuntimeError(f"CI: shared data sets not found in {DATASETS}")
needs_datasets = pytest.mark.skipif(
    not _HAVE_DATASETS,
    reason=f"shared data sets not found in {DATASETS} (they live beside the repository, in ../shared/datasets)",
)


# --- helpers ---------------------------------------------------------------------------


def commands_in(text: str) -> list[list[str]]:
    """Every ``piezopress import ...`` command in a text, continuation lines joined, split as a shell would."""
    commands, current = [], None
    for raw in text.splitlines():
        line = raw.strip()
        if current is None and line.startswith("piezopress import "):
            current = ""
        if current is None:
            continue
        current += " " + line.rstrip("\\").strip()
        if not line.endswith("\\"):
            commands.append(shlex.split(current)[1:])  # without "piezopress"
            current = None
    return commands


def documented(source: str) -> list[str]:
    """The documented command importing ``source`` (a path under the data sets folder)."""
    found = [c for c in commands_in(DOCS.read_text(encoding="utf-8")) if c[1] == DOC_PREFIX + source]
    assert len(found) == 1, f"expected one documented command for {source} in {DOCS}, found {len(found)}"
    return found[0]


def localised(args: list[str], out: Path) -> list[str]:
    """A documented command with the data set's real location and ``out`` for ``--out``."""
    args = list(args)
    assert args[1].startswith(DOC_PREFIX)
    args[1] = str(DATASETS / args[1][len(DOC_PREFIX) :])
    args[args.index("--out") + 1] = str(out)
    return args


def invoke(args: list[str]):
    return CliRunner().invoke(cli, [str(a) for a in args])


def assert_one_line_error(result, *mentions: str) -> str:
    """Failed, with one ``Error:`` line mentioning each of ``mentions``, and no traceback."""
    assert result.exit_code != 0, result.output
    assert isinstance(result.exception, SystemExit), f"unexpected {result.exception!r}"
    lines = result.output.strip().splitlines()
    assert len(lines) == 1, result.output
    assert lines[0].startswith("Error: "), lines[0]
    assert "Traceback" not in result.output
    for text in mentions:
        assert text in lines[0], f"{text!r} not in {lines[0]!r}"
    return lines[0]


def write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def table(t: np.ndarray, u: np.ndarray, x: np.ndarray, header: str | None = "t,u,x", sep: str = ",") -> str:
    lines = [header] if header else []
    lines += [sep.join(repr(float(v)) for v in row) for row in zip(t, u, x)]
    return "\n".join(lines) + "\n"


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# --- the shared data sets, imported as documented ----------------------------------------


@pytest.fixture(scope="module")
def smart_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("smart") / "smart.parquet"
    result = invoke(localised(documented(SMART), out))
    assert result.exit_code == 0, result.output
    lines = result.output.strip().splitlines()
    assert "50001 samples at 5000 Hz" in lines[0]
    assert lines[1:] == ["Next:", f"  piezopress fit {out} --out {out.with_suffix('.json')}"]  # the next command
    return read_run(out)


@pytest.fixture(scope="module")
def aye_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("aye") / "aye.parquet"
    result = invoke(localised(documented(AYE_MODEL), out))
    assert result.exit_code == 0, result.output
    return read_run(out)


def test_help_shows_the_documented_commands():
    result = invoke(["import", "--help"])
    assert result.exit_code == 0
    assert commands_in(result.output) == [documented(SMART), documented(AYE_MODEL)]


@needs_datasets
def test_smarthysteresis_shape_rate_and_ranges(smart_run):
    data = smart_run.data
    assert list(data.columns) == ["t_s", "command_v", "displacement_um"]
    assert len(data) == 50_001
    assert smart_run.kind == "sine"
    assert smart_run.sample_rate_hz == pytest.approx(5000.0, rel=1e-6)
    # t_s is regenerated on the exact grid (the file's steps jitter by 1e-4 of a step)...
    np.testing.assert_allclose(data["t_s"], np.arange(50_001) / 5000.0, rtol=0, atol=1e-12)
    # ...without moving any sample by more than that jitter (2e-8 s; tolerance 1e-7 s).
    raw_t = pd.read_csv(DATASETS / SMART, header=None)[1].to_numpy()
    assert np.max(np.abs(data["t_s"].to_numpy() - raw_t)) < 1e-7
    # Ranges from the README: +-150 V drive (read verbatim), displacement about +-19.7 um.
    assert data["command_v"].min() == pytest.approx(-150.0, abs=1e-9)
    assert data["command_v"].max() == pytest.approx(150.0, abs=1e-9)
    assert data["displacement_um"].min() == pytest.approx(-19.7, abs=0.05)
    assert data["displacement_um"].max() == pytest.approx(19.7, abs=0.05)
    # Column 4 really is the 1 Hz drive: its spectrum peaks at 1 Hz (resolution 0.1 Hz).
    u = data["command_v"].to_numpy()
    freqs = np.fft.rfftfreq(len(u), 1 / 5000.0)
    assert freqs[np.argmax(np.abs(np.fft.rfft(u - u.mean())))] == pytest.approx(1.0, abs=0.1)


@needs_datasets
def test_smarthysteresis_provenance(smart_run):
    imported = smart_run.meta["import"]
    assert imported["source_file"] == "hysteresis_v_150_1hz.csv"
    assert imported["source_sha256"] == sha256(DATASETS / SMART)
    assert imported["columns"] == {"t_s": 2, "command_v": 4, "displacement_um": 3}
    assert imported["rows"] == [0, 50_001]
    assert imported["lag_samples"] == {}
    assert imported["time_source"] == "column 2"
    assert 0 < imported["time_step_max_jitter"] < 1e-3
    assert imported["importer_version"] and imported["imported_utc"].endswith("+00:00")


@needs_datasets
def test_aye_ang_shape_rate_ranges_and_lag(aye_run):
    data = aye_run.data
    raw = pd.read_csv(DATASETS / AYE_MODEL, sep="\t", header=None).to_numpy()
    assert raw.shape == (8027, 7)
    assert len(data) == 8026  # one row lost to the one-sample lag
    assert aye_run.sample_rate_hz == pytest.approx(200.0, rel=1e-6)
    assert data["t_s"].iloc[-1] == pytest.approx(8025 / 200.0, abs=1e-9)
    # Input row i is paired with sensor row i + 1, values verbatim.
    np.testing.assert_array_equal(data["command_v"], raw[:-1, 0])
    np.testing.assert_array_equal(data["displacement_um"], raw[1:, 4])
    assert data["command_v"].min() == pytest.approx(0.0, abs=1e-9)
    assert data["command_v"].max() == pytest.approx(3.6, abs=1e-9)
    # README: sensor about -123 to -74; row 0 (-123.06) is dropped by the lag.
    assert data["displacement_um"].min() == pytest.approx(-120.15, abs=0.01)
    assert data["displacement_um"].max() == pytest.approx(-73.64, abs=0.01)
    # Sign kept: the reading rises with the input (correlation 0.98 in this file).
    assert np.corrcoef(data["command_v"], data["displacement_um"])[0, 1] > 0.95


@needs_datasets
def test_aye_ang_provenance_and_units_note(aye_run):
    imported = aye_run.meta["import"]
    assert imported["source_sha256"] == sha256(DATASETS / AYE_MODEL)
    assert imported["lag_samples"] == {"displacement_um": 1}
    assert imported["columns"] == {"command_v": 1, "displacement_um": 5}
    assert imported["time_source"] == "sample rate"
    assert "gain undocumented" in aye_run.meta["units_note"]


@needs_datasets
def test_aye_ang_test_file_segment(tmp_path):
    if not (DATASETS / AYE_TEST).is_file():
        pytest.skip(f"{AYE_TEST} not found in {DATASETS}")
    args = documented(AYE_MODEL)
    args[1] = DOC_PREFIX + AYE_TEST
    args += ["--rows", "11900:14100", "--keep-time"]
    out = tmp_path / "segment.parquet"
    result = invoke(localised(args, out))
    assert result.exit_code == 0, result.output
    run = read_run(out)
    raw = pd.read_csv(DATASETS / AYE_TEST, sep="\t", header=None).to_numpy()
    assert len(run.data) == 2200
    assert run.data["t_s"].iloc[0] == pytest.approx(11900 / 200.0, abs=1e-9)
    np.testing.assert_array_equal(run.data["command_v"], raw[11900:14100, 0])
    np.testing.assert_array_equal(run.data["displacement_um"], raw[11901:14101, 4])


@needs_datasets
def test_inspect_shows_both_runs(smart_run, aye_run):
    result = invoke(["inspect", smart_run.path, aye_run.path])
    assert result.exit_code == 0, result.output
    assert "50001 samples at 5000 Hz" in result.output and "8026 samples at 200 Hz" in result.output
    assert sha256(DATASETS / SMART) in result.output
    assert "units_note:" in result.output


# --- errors: one line naming the file and option, no traceback ---------------------------


@pytest.fixture
def good_csv(tmp_path) -> Path:
    k = np.arange(20)
    return write(tmp_path / "good.csv", table(k / 1000.0, np.sin(k / 3.0), 2.0 * k, header=None))


def test_error_missing_column_index(good_csv, tmp_path):
    result = invoke(
        [
            "import",
            good_csv,
            "--out",
            tmp_path / "r.parquet",
            "--col",
            "t_s=1",
            "--col",
            "command_v=2",
            "--col",
            "displacement_um=7",
        ]
    )
    assert_one_line_error(result, "good.csv", "displacement_um=7", "3 column")
    assert not (tmp_path / "r.parquet").exists()


def test_error_unknown_col_target(good_csv, tmp_path):
    result = invoke(
        [
            "import",
            good_csv,
            "--out",
            tmp_path / "r.parquet",
            "--col",
            "t_s=1",
            "--col",
            "command_v=2",
            "--col",
            "force=3",
        ]
    )
    assert_one_line_error(result, "good.csv", "'force'", "force_n")


def test_error_non_numeric_cell(tmp_path):
    src = write(tmp_path / "bad.csv", "0,1,2\n0.001,1,2\n0.002,abc,2\n0.003,1,2\n")
    result = invoke(
        [
            "import",
            src,
            "--out",
            tmp_path / "r.parquet",
            "--col",
            "t_s=1",
            "--col",
            "command_v=2",
            "--col",
            "displacement_um=3",
        ]
    )
    assert_one_line_error(result, "bad.csv", "'abc'", "data row 2 (line 3)", "column 2 (command_v)")


def test_error_nan_cell(tmp_path):
    src = write(tmp_path / "nan.csv", "t,u,x\n0,1,2\n0.001,1,NaN\n0.002,1,2\n")
    result = invoke(
        [
            "import",
            src,
            "--out",
            tmp_path / "r.parquet",
            "--col",
            "t_s=t",
            "--col",
            "command_v=u",
            "--col",
            "displacement_um=x",
        ]
    )
    assert_one_line_error(result, "nan.csv", "NaN", "line 3", "column 3 (displacement_um)")


def test_error_gap_in_time(tmp_path):
    t = np.delete(np.arange(30) / 1000.0, 17)  # one sample missing: a step of 2 ms among 1 ms
    src = write(tmp_path / "gap.csv", table(t, np.ones(29), np.ones(29)))
    result = invoke(
        [
            "import",
            src,
            "--out",
            tmp_path / "r.parquet",
            "--col",
            "t_s=t",
            "--col",
            "command_v=u",
            "--col",
            "displacement_um=x",
        ]
    )
    assert_one_line_error(result, "gap.csv", "not uniformly sampled", "time column 1")


def test_error_out_exists_leaves_it_untouched(good_csv, tmp_path):
    out = tmp_path / "existing.parquet"
    out.write_bytes(b"precious bytes")
    before = out.read_bytes()
    result = invoke(
        ["import", good_csv, "--out", out, "--col", "t_s=1", "--col", "command_v=2", "--col", "displacement_um=3"]
    )
    assert_one_line_error(result, "existing.parquet", "already exists")
    assert out.read_bytes() == before


def test_error_empty_file(tmp_path):
    src = write(tmp_path / "empty.csv", "\n\n")
    result = invoke(
        [
            "import",
            src,
            "--out",
            tmp_path / "r.parquet",
            "--col",
            "command_v=1",
            "--col",
            "force_n=2",
            "--sample-rate",
            "10",
        ]
    )
    assert_one_line_error(result, "empty.csv", "empty")


def test_error_missing_source(tmp_path):
    result = invoke(
        [
            "import",
            tmp_path / "nope.csv",
            "--out",
            tmp_path / "r.parquet",
            "--col",
            "command_v=1",
            "--col",
            "force_n=2",
            "--sample-rate",
            "10",
        ]
    )
    assert_one_line_error(result, "nope.csv", "no such file")


@pytest.mark.parametrize(
    "extra, mentions",
    [
        (["--col", "t_s"], ["--col", "RUN_COLUMN=VALUE"]),
        (["--lag", "displacement_um=half"], ["--lag", "whole number"]),
        (["--scale", "displacement_um=0"], ["scale displacement_um", "non-zero"]),
        (["--rows", "5"], ["--rows", "START:STOP"]),
        (["--rows", "5:99"], ["rows 5:99", "20 data rows"]),
        (["--lag", "t_s=1"], ["lag t_s=1"]),
        (["--kind", "wobble"], ["'wobble'", "sine"]),
        (["--sample-rate", "900"], ["900 Hz", "1000 Hz"]),
        (["--delimiter", "pipes"], ["good.csv", "'pipes'", "whitespace"]),
    ],
)
def test_error_bad_options(good_csv, tmp_path, extra, mentions):
    args = [
        "import",
        good_csv,
        "--out",
        tmp_path / "r.parquet",
        "--col",
        "t_s=1",
        "--col",
        "command_v=2",
        "--col",
        "displacement_um=3",
    ]
    assert_one_line_error(invoke(args + extra), *mentions)


def test_inspect_reports_bad_files_and_goes_on(good_csv, tmp_path):
    good = tmp_path / "good.parquet"
    assert (
        invoke(
            ["import", good_csv, "--out", good, "--col", "t_s=1", "--col", "command_v=2", "--col", "displacement_um=3"]
        ).exit_code
        == 0
    )
    bad = write(tmp_path / "bad.parquet", "not parquet")
    result = invoke(["inspect", bad, good])
    assert result.exit_code == 1
    assert "Traceback" not in result.output
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and "bad.parquet" in errors[0]
    assert "20 samples at 1000 Hz" in result.output  # the good file is still shown after the bad one


# --- the library on synthetic tables -------------------------------------------------------


def test_jittery_time_is_resampled_to_an_exact_grid(tmp_path):
    rng = np.random.default_rng(7)
    k = np.arange(200)
    t = 5.0 + k / 1000.0 + rng.uniform(-2e-7, 2e-7, k.size)  # jitter 4e-4 of a step at most
    src = write(tmp_path / "jitter.csv", table(t, np.sin(k / 9.0), 3.0 * k))
    run = import_table(src, columns={"t_s": "t", "command_v": "u", "displacement_um": "x"})
    # Mean step from end points: (t[-1] - t[0]) / 199, within 4e-7 s / 0.199 s of 1 ms.
    assert run.sample_rate_hz == pytest.approx(1000.0, rel=3e-6)
    np.testing.assert_allclose(np.diff(run.t_s), 1 / run.sample_rate_hz, rtol=1e-9)
    assert run.t_s[0] == 0.0
    assert run.meta["import"]["time_origin_s"] == pytest.approx(5.0, abs=3e-7)
    kept = import_table(src, columns={"t_s": "t", "command_v": "u", "displacement_um": "x"}, zero_time=False)
    assert kept.t_s[0] == pytest.approx(5.0, abs=3e-7)


def test_header_names_scale_offset_and_whitespace(tmp_path):
    k = np.arange(10)
    src = write(
        tmp_path / "ws.txt", "  time   volts   microns\n" + table(k * 0.01, 0.1 * k, k * 1e-3, header=None, sep="   ")
    )
    run = import_table(
        src,
        columns={"t_s": "time", "command_v": "volts", "force_n": "microns"},
        scales={"command_v": 100.0, "force_n": 1000.0},
        offsets={"force_n": -1.0},
    )
    assert run.meta["import"]["delimiter"] == "whitespace" and run.meta["import"]["header"] is True
    np.testing.assert_allclose(run.data["command_v"], 10.0 * k, rtol=1e-12)
    np.testing.assert_allclose(run.data["force_n"], k - 1.0, rtol=1e-12, atol=1e-12)
    assert run.sample_rate_hz == pytest.approx(100.0, rel=1e-9)


def test_lag_and_rows_pair_input_row_i_with_output_row_i_plus_lag(tmp_path):
    k = np.arange(12.0)
    src = write(tmp_path / "lag.tsv", "\n".join(f"{a}\t{10 * a}" for a in k) + "\n")
    cols = {"command_v": 1, "displacement_um": 2}
    run = import_table(src, columns=cols, sample_rate_hz=10.0, lag_samples={"displacement_um": 2})
    np.testing.assert_array_equal(run.command_v, k[:-2])
    np.testing.assert_array_equal(run.data["displacement_um"], 10 * k[2:])
    early = import_table(src, columns=cols, sample_rate_hz=10.0, lag_samples={"displacement_um": -1})
    np.testing.assert_array_equal(early.command_v, k[1:])
    np.testing.assert_array_equal(early.data["displacement_um"], 10 * k[:-1])
    # rows select input rows; the lagged output comes from beyond the segment if the file has it.
    seg = import_table(
        src, columns=cols, sample_rate_hz=10.0, lag_samples={"displacement_um": 1}, rows=(3, 7), zero_time=False
    )
    np.testing.assert_array_equal(seg.command_v, k[3:7])
    np.testing.assert_array_equal(seg.data["displacement_um"], 10 * k[4:8])
    assert seg.t_s[0] == pytest.approx(0.3, abs=1e-12) and seg.meta["import"]["rows"] == [3, 7]
    tail = import_table(src, columns=cols, sample_rate_hz=10.0, lag_samples={"displacement_um": 1}, rows=(8, None))
    np.testing.assert_array_equal(tail.command_v, k[8:11])  # row 11 has no partner: dropped


def test_semicolon_and_explicit_delimiters(tmp_path):
    src = write(tmp_path / "semi.csv", "0;1;2\n1;2;3\n2;3;4\n")
    run = import_table(src, columns={"command_v": 2, "force_n": 3}, sample_rate_hz=2.0)
    assert run.meta["import"]["delimiter"] == "semicolon"
    np.testing.assert_array_equal(run.data["force_n"], [2.0, 3.0, 4.0])
    with pytest.raises(ImportFormatError, match=r"semi\.csv.*non-numeric cell '0;1;2'"):
        import_table(src, columns={"command_v": 1, "force_n": 1}, sample_rate_hz=2.0, delimiter="comma", header=False)


@pytest.mark.parametrize(
    "text, options, pattern",
    [
        ("t,1,2\n", {}, r"line 1 mixes numbers and text"),
        ("a,b\n", {"header": True}, r"header but no data rows"),
        ("0,1\n1,2\n", {"sample_rate_hz": None}, r"no time column mapped and no sample rate"),
        ("0,1\n1,2\n", {"columns": {"command_v": 1}}, r"lacks a measured output"),
        ("0,1\n1,2\n", {"columns": {"command_v": "volts", "force_n": 2}}, r"names a column but the file has no header"),
        ("0,1\n1,2,3\n", {}, r"same number of fields"),
        ("0,1\n1,\n", {}, r"empty cell at data row 1 \(line 2\), column 2 \(force_n\)"),
        ("0,1\n1,inf\n", {}, r"inf at data row 1"),
    ],
)
def test_library_errors(tmp_path, text, options, pattern):
    src = write(tmp_path / "x.csv", text)
    kwargs = {"columns": {"command_v": 1, "force_n": 2}, "sample_rate_hz": 10.0, **options}
    with pytest.raises(ImportFormatError, match=r"x\.csv: .*" + pattern) as info:
        import_table(src, **kwargs)
    assert "\n" not in str(info.value)


def test_time_going_backwards_is_refused(tmp_path):
    src = write(tmp_path / "back.csv", "0,1,1\n0.1,1,1\n0.05,1,1\n0.3,1,1\n")
    with pytest.raises(ImportFormatError, match=r"back\.csv: time column 1 does not increase at data row 2 \(line 3\)"):
        import_table(src, columns={"t_s": 1, "command_v": 2, "force_n": 3})


def test_inspect_takes_a_directory_of_runs(good_csv, tmp_path):
    runs = tmp_path / "runs"
    runs.mkdir()
    for name in ("a", "b"):
        assert (
            invoke(
                [
                    "import",
                    good_csv,
                    "--out",
                    runs / f"{name}.parquet",
                    "--col",
                    "t_s=1",
                    "--col",
                    "command_v=2",
                    "--col",
                    "displacement_um=3",
                ]
            ).exit_code
            == 0
        )
    result = invoke(["inspect", runs])
    assert result.exit_code == 0, result.output
    assert result.output.count("20 samples at 1000 Hz") == 2
    empty = tmp_path / "empty"
    empty.mkdir()
    result = invoke(["inspect", empty])
    assert result.exit_code == 1 and "a directory with no run files" in result.output
