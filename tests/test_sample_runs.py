"""CI regenerates the report's metrics from the committed sample runs and compares them with
the committed expected table, within the tolerance stated on each row.

The runs are committed, so these figures move only when the code computing them changes;
a move beyond the tolerance fails CI until `sample_runs/expected_metrics.csv` is updated on
purpose (README in sample_runs/ says how).
"""

import io
from pathlib import Path

import pandas as pd
import pytest

from piezopress.pipelines import report as R

SAMPLES = Path(__file__).resolve().parents[1] / "sample_runs"


@pytest.fixture(scope="module")
def regenerated():
    rep = R.build_report(
        SAMPLES / "characterization", SAMPLES / "validation", SAMPLES / "bundle.json", SAMPLES / "diagnosis"
    )
    return rep, pd.read_csv(io.StringIO(rep.metrics_csv()))


@pytest.mark.integration
def test_every_expected_metric_is_within_its_tolerance(regenerated):
    _, got = regenerated
    expected = pd.read_csv(SAMPLES / "expected_metrics.csv")
    key = ["table", "test", "metric"]
    merged = expected.merge(got[key + ["value"]], on=key, how="left", suffixes=("_expected", "_now"))
    missing = merged[merged.value_now.isna()]
    assert missing.empty, f"metrics no longer produced:\n{missing[key].to_string()}"
    moved = merged[(merged.value_now - merged.value_expected).abs() > merged.tolerance]
    assert moved.empty, (
        "metrics moved beyond tolerance:\n" + moved[key + ["value_expected", "value_now", "tolerance"]].to_string()
    )


@pytest.mark.integration
def test_metrics_csv_is_byte_identical_for_the_same_inputs(regenerated):
    rep, _ = regenerated
    again = R.build_report(
        SAMPLES / "characterization", SAMPLES / "validation", SAMPLES / "bundle.json", SAMPLES / "diagnosis"
    )
    assert again.metrics_csv() == rep.metrics_csv()


def test_sample_runs_stay_small():
    size = sum(p.stat().st_size for p in SAMPLES.rglob("*") if p.is_file())
    assert size < 20e6  # well under 20 MB
