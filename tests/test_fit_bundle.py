"""``fit_bundle(runs, limits)``: the one pipeline function behind `piezopress fit`, the
benchmarks and `diagnose --gain`'s base fit (issue 12)."""

from __future__ import annotations

import json
from pathlib import Path

from click.testing import CliRunner

from piezopress.analysis.bundle import Bundle
from piezopress.piezocli.main import cli
from piezopress.pipelines import characterize as char
from piezopress.pipelines import fit as F

ROOT = Path(__file__).resolve().parents[1]
SWEEP = ROOT / "sample_runs" / "characterization" / "triangle-0.1hz.parquet"
NIDAQ = ROOT / "rigs" / "nidaq-example.toml"


def test_fit_bundle_is_what_fit_writes_with_the_rigs_drive_range(tmp_path):
    limits = char.rig_limits(NIDAQ)
    fitted = F.fit_bundle([SWEEP], limits, shaper=False)
    comp = fitted.doc["compensation"]
    assert (comp["drive_min_v"], comp["drive_max_v"]) == (limits.drive_min_v, limits.drive_max_v)
    assert "shaper" not in fitted.doc and fitted.result.not_fitted["shaper"] == "left out (shaper=False)"
    assert isinstance(fitted.bundle, Bundle) and fitted.bundle.unit == "N"
    res = CliRunner().invoke(cli, ["fit", str(SWEEP), "--rig", str(NIDAQ), "--out", str(tmp_path / "b.json")])
    assert res.exit_code == 0, res.output
    written = json.loads((tmp_path / "b.json").read_text())
    assert written["compensation"] == comp
    assert written["hysteresis"]["model"] == fitted.doc["hysteresis"]["model"]  # the same fit, to the last digit
    assert ("creep" in written) == ("creep" in fitted.doc)
