"""Issue 24, round two: foreign metadata of any type, malformed manifests, a base bundle
without a mode, ``--json`` on failure. Each probe of the issue, plus a generator of the
class (metadata of every JSON type at every key; manifests broken every way)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from piezopress import runformat
from piezopress.errors import PiezopressError
from piezopress.piezocli.main import cli
from piezopress.pipelines import files

ROOT = Path(__file__).resolve().parents[1]
CHAR = ROOT / "sample_runs" / "characterization"

#: JSON values of every type, as other programs write them where we expect objects or numbers.
ODD_VALUES = [
    "string",
    "fast",
    5,
    -1,
    0,
    1e308,
    True,
    None,
    [],
    [1, 2],
    {},
    {"config": "x"},
    {"config": {"actuator": "high"}},
    {"config": {"actuator": {"drive_max_v": "high"}}},
    {"freq_hz": "fast"},
    {"freq_hz": None},
    {"level_v": [1]},
]


def invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def _copy_runs(tmp_path: Path, names: list[str], meta_update: dict | None = None) -> Path:
    d = tmp_path / "runs"
    d.mkdir()
    for n in names:
        run = runformat.read_run(CHAR / f"{n}.parquet")
        meta = {**run.meta, **(meta_update or {})}
        runformat.write_run(runformat.Run(run.data, meta), d / f"{n}.parquet")
    return d


@pytest.mark.parametrize("key", ["protocol", "rig"])
@pytest.mark.parametrize("value", ODD_VALUES, ids=[json.dumps(v)[:24] for v in ODD_VALUES])
def test_metadata_of_any_type_at_any_key_never_raises_in_the_readers(key, value):
    """Every reader of a run's metadata (the profile's cross-check, the safe getters) takes a
    value of any JSON type at ``protocol`` and ``rig`` without raising."""
    from piezopress.analysis import profile

    run = runformat.read_run(CHAR / "step-20v.parquet")
    meta = {**run.meta, key: value}
    profile.crosscheck(meta, profile.profile_run(run), "r")
    assert runformat.meta_number(meta, "rig", "config", "actuator", "drive_max_v") in (None, 150.0)
    assert runformat.meta_get(meta, "protocol", "freq_hz", "deeper") is None


@pytest.mark.parametrize(
    "meta",
    [
        {"protocol": "string"},
        {"protocol": {"freq_hz": "fast"}},
        {"rig": "thesis"},
        {"rig": {"config": "x"}},
        {"rig": {"config": {"actuator": {"drive_max_v": "high"}}}},
    ],
)
def test_fit_shaper_takes_foreign_metadata_without_a_traceback(tmp_path, meta):
    d = _copy_runs(tmp_path, ["step-20v", "step-50v", "step-150v"], meta)
    res = invoke("fit-shaper", d, "--out", tmp_path / "s.json")
    assert res.exit_code == 0, res.output
    assert res.exception is None or isinstance(res.exception, SystemExit)


def _manifest_dir(tmp_path: Path, manifest: bytes) -> Path:
    d = tmp_path / "m"
    d.mkdir()
    shutil.copy(CHAR / "step-20v.parquet", d / "step-20v.parquet")
    (d / "manifest.json").write_bytes(manifest)
    return d


@pytest.mark.parametrize(
    "manifest, says",
    [
        (b'{"status": "complete"}', "has no `runs`"),
        (b'{"status": "complete", "runs": "step-20v.parquet"}', "`runs` is a JSON str"),
        (b'{"status": "complete", "runs": ["step-20v.parquet"]}', "runs[0] is"),
        (b'{"status": "complete", "runs": [{"sha256": "x"}]}', "runs[0] has file = null"),
        (b'{"status": "complete", "runs": [{"file": 5}]}', "runs[0] has file = 5"),
        (b'{"status": "complete", "runs": [{"file": "../../etc/passwd"}]}', "outside the manifest's folder"),
        (b'{"status": "complete", "runs": [{"file": "\xff"}]}', "not UTF-8"),
        (b"[1, 2]", "holds a JSON list"),
    ],
)
def test_a_malformed_manifest_is_refused_in_one_line(tmp_path, manifest, says):
    d = _manifest_dir(tmp_path, manifest)
    with pytest.raises(PiezopressError) as err:
        files.run_files(d)
    assert says in str(err.value) and "manifest.json" in str(err.value) and "\n" not in str(err.value)
    res = invoke("fit-shaper", d, "--out", tmp_path / "s.json")
    assert res.exit_code == 1 and says in res.output and "Traceback" not in res.output


def test_manifests_broken_every_way_never_raise_anything_but_the_projects_error(tmp_path):
    """A generator of the class: a valid manifest with one field replaced by a value of
    every odd type, at every level."""
    good = {
        "status": "complete",
        "kind": "characterization",
        "runs": [{"file": "step-20v.parquet", "sha256": "x", "status": "complete"}],
    }
    cases = []
    for v in ODD_VALUES:
        cases += [{**good, "runs": v}, {**good, "runs": [v]}, {**good, "runs": [{**good["runs"][0], "file": v}]}]
    for i, doc in enumerate(cases):
        d = tmp_path / f"c{i}"
        d.mkdir()
        shutil.copy(CHAR / "step-20v.parquet", d / "step-20v.parquet")
        (d / "manifest.json").write_text(json.dumps(doc))
        try:
            files.run_files(d)
        except PiezopressError:
            pass


def test_json_prints_an_error_object_on_failure(tmp_path):
    (tmp_path / "empty").mkdir()
    res = invoke("fit", tmp_path / "empty", "--out", tmp_path / "b.json", "--json")
    assert res.exit_code == 1
    doc = json.loads(res.stdout[: res.stdout.rindex("}") + 1])
    assert "empty" in doc["error"] and doc["type"], res.output


@pytest.mark.integration
def test_diagnose_with_a_base_bundle_without_a_mode_tests_every_cause_without_a_traceback(tmp_path):
    """Issue 24: `fit --base` on steps of 50-150 V only prints "shaper: not fitted"; diagnose
    with that bundle crashed in the slew limit's fit (`ext.slew_v_per_s` None)."""
    d = _copy_runs(tmp_path, ["triangle-0.1hz", "step-100v", "step-150v"])
    res = invoke("fit", d, "--base", "--out", tmp_path / "base.json")
    assert res.exit_code == 0, res.output
    assert "shaper" not in json.loads((tmp_path / "base.json").read_text())
    res = invoke("diagnose", d, "--bundle", tmp_path / "base.json", "--out", tmp_path / "diag", "--json")
    assert res.exit_code == 0, res.output
    doc = json.loads((tmp_path / "diag" / "diagnosis.json").read_text())
    tried = {t["cause"]: t["result"] for t in doc["tested"]}
    assert "amplifier_slew_limit" in tried and "not fitted (TypeError" not in tried["amplifier_slew_limit"]


def test_glitch_free_and_boolean_free_run_metadata_reads_as_numbers():
    """``sample_rate_hz: true`` and ``schema_version: true`` are refused (true == 1 in Python)."""
    t = np.arange(10) / 10.0
    import pandas as pd

    data = pd.DataFrame({"t_s": t, "command_v": t, "force_n": t})
    for key in ("sample_rate_hz", "schema_version"):
        with pytest.raises(runformat.RunFormatError, match=key):
            runformat.validate(
                data, {"schema_version": 1, "kind": "custom", "name": "r", "sample_rate_hz": 10.0, key: True}, "r"
            )


def _strict(text: str):
    def refuse(name):
        raise ValueError(f"bare {name} is not JSON")

    return json.loads(text, parse_constant=refuse)


def test_diagnosis_json_is_strict_json_in_the_sample_runs_and_when_written(tmp_path):
    """Issue 24: diagnosis.json held bare NaN/Infinity (not JSON), the committed one too."""
    _strict((ROOT / "sample_runs" / "diagnosis" / "diagnosis.json").read_text())
    d = _copy_runs(tmp_path, ["triangle-0.1hz", "rest-120s"])
    assert invoke("fit", d, "--base", "--out", tmp_path / "base.json").exit_code == 0
    res = invoke("diagnose", d, "--bundle", tmp_path / "base.json", "--out", tmp_path / "diag")
    assert res.exit_code == 0, res.output
    doc = _strict((tmp_path / "diag" / "diagnosis.json").read_text())
    assert doc["tested"]
