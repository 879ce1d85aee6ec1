"""``import`` streams its source (only the mapped columns kept, as float64, a chunk of rows at
a time) and refuses a file above its stated size with the reason, before reading it."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from piezopress.errors import ImportFormatError
from piezopress.pipelines import importing

ROOT = Path(__file__).resolve().parents[1]


def write_csv(path: Path, n: int, *, extra_cols: int = 0, seed: int = 1) -> Path:
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 1000.0
    cols = [t, rng.uniform(0, 100, n), rng.uniform(0, 200, n)] + [rng.normal(size=n) for _ in range(extra_cols)]
    np.savetxt(
        path,
        np.column_stack(cols),
        fmt="%.10g",
        delimiter=",",
        header=",".join(f"c{i}" for i in range(len(cols))),
        comments="",
    )
    return path


COLUMNS = {"t_s": "c0", "command_v": "c1", "force_n": "c2"}


@pytest.mark.parametrize("chunk", [1, 7, 100, 10**6])
def test_streaming_gives_the_same_run_whatever_the_chunk(tmp_path, monkeypatch, chunk):
    src = write_csv(tmp_path / "m.csv", 503, extra_cols=2)
    want = pd.read_csv(src)
    monkeypatch.setattr(importing, "CHUNK_ROWS", chunk)
    run = importing.import_table(src, columns=COLUMNS, lag_samples={"force_n": 3}, rows=(5, 400))
    np.testing.assert_array_equal(run.data["command_v"].to_numpy(), want["c1"].to_numpy()[5:400])
    np.testing.assert_array_equal(run.data["force_n"].to_numpy(), want["c2"].to_numpy()[8:403])
    assert run.meta["import"]["source_rows"] == 503 and run.meta["import"]["source_columns"] == 5


def test_a_bad_cell_past_the_first_chunk_is_named_by_row_and_line(tmp_path, monkeypatch):
    src = write_csv(tmp_path / "m.csv", 50)
    lines = src.read_text().splitlines()
    lines[41] = lines[41].split(",")[0] + ",volts?," + lines[41].split(",")[2]  # data row 40
    src.write_text("\n".join(lines) + "\n\n\n")  # blank lines at the end are not data
    monkeypatch.setattr(importing, "CHUNK_ROWS", 8)
    with pytest.raises(ImportFormatError) as err:
        importing.import_table(src, columns=COLUMNS)
    assert (
        str(err.value)
        == f"{src}: non-numeric cell 'volts?' at data row 40 (line 42), column 2 (command_v); expected a number"
    )
    # outside the rows kept, it does not matter
    assert len(importing.import_table(src, columns=COLUMNS, rows=(0, 40)).data) == 40


def test_a_file_above_the_stated_size_is_refused_with_the_reason_before_reading(tmp_path, monkeypatch):
    src = write_csv(tmp_path / "m.csv", 100)
    monkeypatch.setattr(importing, "MAX_IMPORT_BYTES", 1000)
    monkeypatch.setattr(importing, "_first_line", lambda *a: pytest.fail("the file was read"))
    with pytest.raises(
        ImportFormatError, match=r"m\.csv: is [0-9.e+-]+ GB, above the import limit of 1e-06 GB .*cut the segment"
    ):
        importing.import_file(src, tmp_path / "r.parquet", columns=COLUMNS)
    assert importing.MAX_IMPORT_BYTES == 1000 and not (tmp_path / "r.parquet").exists()


def test_a_2_gb_file_is_refused_quickly_and_without_memory(tmp_path):
    src = tmp_path / "huge.csv"
    with open(src, "wb") as fh:  # sparse: 2.1 GB on paper, nothing on disk
        fh.truncate(2_100_000_000)
    with pytest.raises(ImportFormatError, match="is 2.1 GB, above the import limit of 1 GB"):
        importing.import_file(
            src, tmp_path / "r.parquet", columns={"command_v": 1, "force_n": 2}, sample_rate_hz=1000.0
        )


def test_import_memory_grows_with_the_mapped_columns_not_the_text(tmp_path):
    """Peak memory of an import in a fresh process, above what the imports cost, stays under
    4 x the size of the source (the whole table as text took about 9 x: 869 MB for 91 MB)."""
    src = write_csv(tmp_path / "m.csv", 400_000, extra_cols=3)
    size = src.stat().st_size
    code = textwrap.dedent(f"""
        import resource, sys
        from piezopress.pipelines import importing
        import pandas, pyarrow.parquet
        base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        importing.import_file({str(src)!r}, {str(tmp_path / "r.parquet")!r}, columns={COLUMNS!r})
        print(base, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
    """)
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    base_kb, peak_kb = map(int, out.stdout.split())
    assert (peak_kb - base_kb) * 1024 < 4 * size, f"{(peak_kb - base_kb) / 1024:.0f} MB for a {size / 1e6:.0f} MB file"
