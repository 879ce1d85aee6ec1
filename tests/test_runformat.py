"""Run format, schema version 1: what is accepted and how bad files are refused."""

import json

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from piezopress import runformat as rf
from piezopress.errors import OutputExistsError, RunFormatError


def minimal_table(n=100, fs=1000.0, meta=None, **cols):
    data = {"t_s": np.arange(n) / fs, "command_v": np.linspace(0, 10, n), "force_n": np.linspace(50, 70, n)}
    data.update(cols)
    table = pa.Table.from_pandas(pd.DataFrame(data), preserve_index=False)
    m = {"schema_version": 1, "kind": "custom", "name": "x", "sample_rate_hz": fs} if meta is None else meta
    if m is not False:
        table = table.replace_schema_metadata({b"piezopress": json.dumps(m).encode()})
    return table


def write(tmp_path, table, name="r.parquet"):
    p = tmp_path / name
    pq.write_table(table, p)
    return p


def test_file_from_another_tool_with_only_required_fields_is_accepted(tmp_path):
    run = rf.read_run(write(tmp_path, minimal_table()))
    assert run.output_column == "force_n" and run.sample_rate_hz == 1000.0 and len(run.data) == 100


def test_displacement_only_run_is_accepted(tmp_path):
    t = minimal_table()
    t = t.drop_columns(["force_n"]).append_column("displacement_um", pa.array(np.zeros(100)))
    assert rf.read_run(write(tmp_path, t)).output_column == "displacement_um"


def test_round_trip_keeps_metadata_and_columns(tmp_path):
    meta = rf.make_meta("step", "s1", 2000.0, protocol={"level_v": 20.0}, seed=[1, 2])
    run = rf.make_run(
        {"t_s": np.arange(10) / 2000.0, "command_v": np.ones(10), "force_n": np.ones(10), "reference_n": np.ones(10)},
        meta,
    )
    sha = rf.write_run(run, tmp_path / "a.parquet")
    back = rf.read_run(tmp_path / "a.parquet")
    assert back.meta == meta
    pd.testing.assert_frame_equal(back.data, run.data)
    assert sha == rf.sha256_file(tmp_path / "a.parquet")


@pytest.mark.parametrize(
    "table, message",
    [
        (
            lambda: minimal_table().drop_columns(["command_v"]),
            "missing column command_v; expected columns t_s, command_v",
        ),
        (
            lambda: minimal_table().drop_columns(["force_n"]),
            "no measured output; expected a column force_n and/or displacement_um",
        ),
        (
            lambda: minimal_table(force_n=np.r_[np.zeros(50), np.nan, np.zeros(49)]),
            "column force_n has 1 NaN/infinite value(s), first at row 50",
        ),
        (lambda: minimal_table(t_s=np.r_[np.arange(50), np.arange(51, 101)] / 1000.0), "t_s is not uniformly sampled"),
        (
            lambda: minimal_table(t_s=np.r_[np.arange(50), np.arange(49, 99)] / 1000.0),
            "t_s is not strictly increasing at row 50",
        ),
        (
            lambda: minimal_table(meta={"schema_version": 2, "kind": "custom", "name": "x", "sample_rate_hz": 1000.0}),
            "schema_version is 2, expected 1",
        ),
        (
            lambda: minimal_table(meta={"schema_version": 1, "kind": "zigzag", "name": "x", "sample_rate_hz": 1000.0}),
            "kind is 'zigzag', expected one of triangle, step",
        ),
        (
            lambda: minimal_table(meta={"schema_version": 1, "kind": "custom", "name": "x", "sample_rate_hz": 500.0}),
            "sample_rate_hz is 500 but t_s is sampled at 1000 Hz",
        ),
        (lambda: minimal_table(meta={"schema_version": 1, "kind": "custom"}), "metadata lacks name, sample_rate_hz"),
        (lambda: minimal_table(meta=False), "has no 'piezopress' metadata"),
        (lambda: minimal_table(force_n=np.arange(100) % 2 == 0), "column force_n has type bool, expected float64"),
    ],
)
def test_bad_runs_are_refused_with_one_line_naming_the_file(tmp_path, table, message):
    p = write(tmp_path, table())
    with pytest.raises(RunFormatError) as err:
        rf.read_run(p)
    text = str(err.value)
    assert "\n" not in text
    assert text.startswith(str(p) + ": ")
    assert message in text


def test_corrupt_and_truncated_files(tmp_path):
    good = write(tmp_path, minimal_table())
    truncated = tmp_path / "t.parquet"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    garbage = tmp_path / "g.parquet"
    garbage.write_bytes(b"not a parquet file at all")
    for p in (truncated, garbage):
        with pytest.raises(RunFormatError, match="cannot be read as Parquet") as err:
            rf.read_run(p)
        assert "\n" not in str(err.value)


def test_incomplete_run_refused_unless_asked(tmp_path):
    meta = rf.make_meta("step", "s", 1000.0, status="incomplete", status_reason="over-force")
    run = rf.make_run({"t_s": np.arange(5) / 1000.0, "command_v": np.zeros(5), "force_n": np.zeros(5)}, meta)
    rf.write_run(run, tmp_path / "s.parquet")
    with pytest.raises(RunFormatError, match="marked 'incomplete' \\(over-force\\), expected a complete run"):
        rf.read_run(tmp_path / "s.parquet")
    assert rf.read_run(tmp_path / "s.parquet", allow_incomplete=True).meta["status"] == "incomplete"


def test_write_never_overwrites(tmp_path):
    p = write(tmp_path, minimal_table())
    before = p.read_bytes()
    run = rf.read_run(p)
    with pytest.raises(OutputExistsError, match="refusing to overwrite"):
        rf.write_run(run, p)
    assert p.read_bytes() == before
    assert not list(tmp_path.glob(".*partial"))
