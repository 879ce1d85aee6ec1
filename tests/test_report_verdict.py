"""The report's verdict on the committed sample runs: Table 6.13 against the targets, every
warning of the run metadata with its runs and count, the provenance; the mode's Bode plot
against the measured steps; the warnings the inputs themselves show."""

from __future__ import annotations

import hashlib
import json
import math
import re
from pathlib import Path

import pandas as pd
import pytest

from piezopress import runformat
from piezopress.pipelines import report as R
from piezopress.pipelines import report_frequency as RF
from piezopress.pipelines import report_verdict as RV
from piezopress.pipelines.files import read_manifest, run_files
from piezopress.pipelines.report_inputs import _load_dir
from piezopress.pipelines.report_tables import TESTS_6_13, _Row613

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_runs"


@pytest.fixture(scope="module")
def report():
    return R.build_report(
        SAMPLES / "characterization", SAMPLES / "validation", SAMPLES / "bundle.json", SAMPLES / "diagnosis"
    )


def quick_source(path: Path):
    """A run directory's runs without its summary table (the warnings need only the metadata)."""
    return _load_dir(path, "run", "validate", lambda p: pd.DataFrame(columns=["run", "kind", "metric", "value"]))


def recorded_warnings(directory: Path) -> dict[str, list[str]]:
    out = {}
    for f in run_files(directory):
        comp = runformat.read_run(f).meta.get("compensation") or {}
        texts = list(comp.get("warnings", [])) + list(comp.get("notes", []))
        if texts:
            out[f.stem] = texts
    return out


@pytest.mark.integration
def test_every_warning_of_the_run_metadata_is_in_the_verdict_with_its_runs_and_count(report):
    recorded = recorded_warnings(SAMPLES / "validation") | recorded_warnings(SAMPLES / "characterization")
    assert len(recorded) >= 10  # the sample set has them: shaper skipped on 9 runs, drive clipped on 5
    warnings = report.verdict.warnings
    by_kind = {w.what.split(":")[0]: w for w in warnings}
    skipped = [n for n, t in recorded.items() if any(x.startswith("shaper skipped") for x in t)]
    clipped = {
        n: int(runformat.read_run(SAMPLES / "validation" / f"{n}.parquet").meta["compensation"]["clipped_samples"])
        for n, t in recorded.items()
        if any("cannot be reached" in x for x in t)
    }
    assert (
        len(skipped) == 9
        and by_kind["shaper skipped"].count == 9
        and set(by_kind["shaper skipped"].runs) == set(skipped)
    )
    assert "1019 Hz mode" in by_kind["shaper skipped"].what
    assert len(clipped) == 5 and by_kind["drive clipped"].count == 5 and clipped["creep-300n"] == 989
    assert set(by_kind["drive clipped"].runs) == {
        f"{n} ({k} sample{'s' if k != 1 else ''})" for n, k in clipped.items()
    }
    assert f"{sum(clipped.values())} samples in all" == by_kind["drive clipped"].detail
    # and the page says so where it opens: every run with a warning is named before the next section
    md = report.markdown()
    verdict = md.split("\n## Verdict")[1].split("\n## ")[0]
    for name in recorded:
        assert name in verdict, name
    assert "| 9 |" in verdict.replace(" ", "").replace("|9|", "| 9 |") and "989 samples" in verdict


@pytest.mark.integration
def test_the_verdict_rows_are_the_runs_nearest_their_targets(report):
    metrics = pd.read_csv(__import__("io").StringIO(report.metrics_csv()))
    for row in report.verdict.rows:
        worst = float(
            metrics[
                (metrics.table == "6.13") & (metrics.test == row.key) & (metrics.metric == "controlled_max")
            ].value.iloc[0]
        )
        assert row.value <= worst * (1 + 1e-5)  # a run nearest its own target, never above the worst figure
        assert row.target == RV.target_pct(row.key, row.worst_run)
        assert row.margin == pytest.approx(row.target - row.value, abs=1e-12) and row.passed == (
            row.value <= row.target
        )
    # the project's targets (issue 4's acceptance), each well inside the thesis's controlled range
    assert RV.TARGETS_PCT == {"max_static_hysteresis": 1.0, "creep": 0.3, "overshoot": 3.0, "tracking_error": 3.0}
    for key, target in RV.TARGETS_PCT.items():
        row = next(r for r in report.verdict.rows if r.key == key)
        assert target < max(abs(v) for v in row.thesis_ctrl)
    assert report.verdict.summary.startswith(
        "Verdict: PASS: all 4 controlled figures within their targets, with 4 kinds of warning"
    )


def test_the_75_n_triangle_has_its_own_target():
    hyst = next(t for t in TESTS_6_13 if t.key == "max_static_hysteresis")
    rows = [_Row613(t, [], [("a", 0.1)]) for t in TESTS_6_13 if t.key != "max_static_hysteresis"]
    # 1.4 % on the 75 N triangle passes (its target is 1.5 %); 0.95 % on another is the nearest its 1.0 %
    _, verdict = RV.verdict_blocks(
        [_Row613(hyst, [], [("tri-75n-0.1hz", 1.4), ("tri-150n-0.1hz", 0.95)]), *rows], None, None, None, None
    )
    row = next(r for r in verdict.rows if r.key == "max_static_hysteresis")
    assert row.passed and row.worst_run == "tri-150n-0.1hz" and row.margin == pytest.approx(0.05)
    _, verdict = RV.verdict_blocks(
        [_Row613(hyst, [], [("tri-75n-0.1hz", 1.6), ("tri-150n-0.1hz", 0.5)]), *rows], None, None, None, None
    )
    row = next(r for r in verdict.rows if r.key == "max_static_hysteresis")
    assert (
        row.passed is False
        and row.worst_run == "tri-75n-0.1hz"
        and row.target == 1.5
        and row.margin == pytest.approx(-0.1)
    )


def test_a_figure_beyond_its_target_fails_the_verdict_with_its_margin():
    over = RV.TARGETS_PCT["overshoot"] + 0.25
    rows = [
        _Row613(t, [], [("a", 0.1)] if t.key != "overshoot" else [("step-x", 0.2), ("step-y", over)])
        for t in TESTS_6_13
    ]
    blocks, verdict = RV.verdict_blocks(rows, None, None, None, None)
    row = next(r for r in verdict.rows if r.key == "overshoot")
    assert row.worst_run == "step-y" and row.margin == pytest.approx(-0.25) and row.passed is False
    assert verdict.summary == "Verdict: FAIL: 1 of 4 controlled figures miss their target (overshoot), no warning."
    table = next(b for b in blocks if isinstance(b, R.Table))
    assert ("-0.25", "FAIL") == table.rows[2][4:6]
    rows[0] = _Row613(TESTS_6_13[0], [], [])
    _, verdict = RV.verdict_blocks(rows, None, None, None, None)
    assert verdict.summary.startswith("Verdict: FAIL") and verdict.rows[0].passed is None


@pytest.mark.integration
def test_the_provenance_line_names_rig_backend_dates_software_and_digests(report):
    line = report.verdict.provenance
    run = runformat.read_run(SAMPLES / "validation" / "creep-300n.parquet")
    config = RV.config_digest(run.meta["rig"]["config"])
    bundle = hashlib.sha256((SAMPLES / "bundle.json").read_bytes()).hexdigest()
    for part in (
        "Rig thesis press (virtual)",
        f"file {run.meta['rig']['source']}",
        f"configuration sha256 {config[:16]}",
        "backend virtual (simulated",
        f"characterized {read_manifest(SAMPLES / 'characterization')['created_utc']}",
        f"validated {read_manifest(SAMPLES / 'validation')['created_utc']}",
        "software piezopress 0.1.0",
        f"(sha256 {bundle[:16]})",
    ):
        assert part in line, part
    assert run.meta["compensation"]["bundle_sha256"] == bundle  # so no "another bundle" warning
    assert not any("another bundle" in w.what for w in report.verdict.warnings)


def test_runs_validated_with_another_bundle_and_models_used_beyond_their_data_are_warned(tmp_path):
    char, val = quick_source(SAMPLES / "characterization"), quick_source(SAMPLES / "validation")
    other = RV.consistency_warnings(SAMPLES / "base-bundle.json", char, val)
    assert len(other) == 1 and other[0].count == 16 and "another bundle" in other[0].what
    bundle = json.loads((SAMPLES / "bundle.json").read_text())
    bundle["hysteresis"]["fit"]["output_range_n"] = (
        200.0  # fitted up to y0 + 200 N = 250 N: the 300 N triangles go beyond
    )
    w = {x.what.split(":")[0]: x for x in RV.extrapolation_warnings(bundle, char, val)}
    beyond = w["hysteresis model extrapolated"]
    assert "250.0 N" in beyond.what and any(r.startswith("tri-300n-0.1hz (to 350.0 N)") for r in beyond.runs)
    assert w["hysteresis model extrapolated in rate"].count == 4
    bundle["hysteresis"]["fit"]["output_range_n"] = 400.0
    assert "hysteresis model extrapolated" not in {
        x.what.split(":")[0] for x in RV.extrapolation_warnings(bundle, char, val)
    }


def test_the_modes_bode_plot_shows_the_measured_points_in_the_shapers_band():
    """Acceptance (issue 13): the step runs' measured response lies on the identified mode inside
    the band the shaper was designed for (+/-15 %): within 20 % on the run the mode was identified
    from (16 % measured, at 1.05 x the mode: the measured peak stands above the identified one), within
    25 % on the larger steps (their hysteresis bends
    the response)."""
    char = quick_source(SAMPLES / "characterization")
    bundle = json.loads((SAMPLES / "bundle.json").read_text())
    missing: list[str] = []
    fig, checks = RF.mode_figure(bundle, char, missing)
    assert fig is not None and missing == [] and fig.png[:4] == b"\x89PNG"
    assert {c.run for c in checks} == {"step-20v", "step-50v", "step-100v", "step-150v"}
    identified = {r["name"] for r in bundle["shaper"]["runs"]}
    for c in checks:
        assert c.points >= 3, c
        assert c.worst_ratio_error <= (0.20 if c.run in identified else 0.25), c
    assert RF.FREQ_ERROR == 0.15 and RF.MAX_RESIDUAL == 0.05
    assert re.search(r"step-20v: \d+ points, within \d+ %", fig.caption)
    assert math.isclose(bundle["shaper"]["mode"]["natural_freq_rad_s"] / 2 / math.pi, 1019, abs_tol=1)
