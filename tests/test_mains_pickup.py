"""Issue 20: mains pickup is a catalogue cause (a line at the mains frequency in the reading,
independent of the drive; extension: a line fitted in the reading run by run).

The hum is added here with ``numpy.sin`` to runs of the project's sample characterization
(a copy of them), never with the line model that detects it
(:func:`piezopress.analysis.signatures.line_of`); the third test press, written apart from the
project, carries its own hum (slow test).
"""

from __future__ import annotations

import math
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from piezopress import runformat
from piezopress.analysis import diagnosis as dg
from piezopress.analysis.diagnosis import CAUSES
from piezopress.analysis.diagnosis.judging import _level_free_err
from piezopress.analysis.hysteresis import PIModel
from piezopress.analysis.signatures import fit_line, line_of, notched

ROOT = Path(__file__).resolve().parents[1]
CHAR = ROOT / "sample_runs" / "characterization"


@pytest.mark.parametrize("df", [-0.07, -0.02, 0.0, 0.013, 0.06])
def test_a_line_is_refined_to_its_frequency_and_extrapolates_its_phase(df):
    """Fitted on the first 60 % of 40 s, the line predicts the last 40 % to within a tenth of
    its size (a frequency off by 0.01 Hz would lose a third of a turn over 16 s)."""
    fs = 2000.0
    t = np.arange(0, 40, 1 / fs)
    rng = np.random.default_rng(int(1000 * (df + 1)))
    hum = 0.6 * np.sin(2 * np.pi * (50.0 + df) * t + 2.0)
    e = hum + 0.5 * rng.standard_normal(t.size) + 0.01 * t  # noise almost the hum's size, and a drift
    k = int(0.6 * t.size)
    f, a, b = fit_line(t[:k], e[:k], 50.0, fs)
    assert f == pytest.approx(50.0 + df, abs=2e-3)
    assert math.hypot(a, b) == pytest.approx(0.6, rel=0.05)
    assert np.sqrt(np.mean((line_of(t[k:], f, a, b) - hum[k:]) ** 2)) < 0.1 * 0.6 / math.sqrt(2)


@pytest.mark.parametrize(("hz", "fs"), [(50.0, 1000.0), (60.0, 2000.0), (150.0, 10000.0)])
def test_a_notch_takes_out_its_line_and_keeps_the_rest(hz, fs):
    """A line at ``hz`` whose size wanders by 20 % over 20 s is cut below 3 % of itself; sines
    5 Hz either side keep at least 85 % of their size, one an octave away 99 %; a line at the
    Nyquist frequency is left alone."""
    t = np.arange(0, 20, 1 / fs)
    hum = (1 + 0.2 * np.sin(2 * np.pi * 0.05 * t)) * np.sin(2 * np.pi * hz * t + 1.0)
    keep = {d: np.sin(2 * np.pi * d * t + 0.3) for d in (hz - 5.0, hz + 5.0, hz / 2.0)}
    inner = slice(int(fs), -int(fs))  # a second at either end: the filter's edges
    assert np.std(notched(hum, [hz], fs)[inner]) < 0.03 * np.std(hum[inner])
    for d, s in keep.items():
        kept = np.std(notched(s, [hz], fs)[inner]) / np.std(s[inner])
        assert kept > (0.99 if d == hz / 2.0 else 0.85), (d, kept)
    assert np.array_equal(notched(hum, [fs / 2.0], fs), hum)


def test_a_hum_not_fitted_in_a_run_is_not_judged_there():
    """With the hum fitted in one run (the model's reading carries its line there), another
    run's level-free residual is judged without the same hum (notched), and the run it was
    fitted in is judged as it is: what is left is the white noise beside it."""
    fs = 1000.0
    t = np.arange(0, 6, 1 / fs)
    x = 75 * (1 - np.cos(2 * np.pi * 0.5 * t))
    model = dg.Model(PIModel((0.0,), (1.0,), (0.0,), (2.0,), y0=50.0))
    rng = np.random.default_rng(3)
    runs = []
    for name, phase in (("a", 0.4), ("b", 2.0)):
        clean = model.predict(dg.RunData(name, "sweep", t, x, np.zeros_like(t), fs))
        hum = 0.8 * np.sin(2 * np.pi * 50.02 * t + phase)
        runs.append(dg.RunData(name, "sweep", t, x, clean + hum + rng.normal(0, 0.05, t.size), fs))
    f, a, b = fit_line(t, runs[0].y - model.predict(runs[0]), 50.0, fs)
    with_hum = replace(model, hum=(("a", f, a, b),))
    assert with_hum.unfitted_lines(runs[0]) == () and with_hum.unfitted_lines(runs[1]) == (f,)
    inner = slice(int(fs), -int(fs))
    for r in runs:
        e = _level_free_err([(r, inner)], with_hum)
        assert np.std(e) < 0.08, (r.name, np.std(e))  # the hum alone is 0.57 RMS
    assert np.std(_level_free_err([(runs[1], inner)], model)) > 0.5  # without the hum found: judged with it


def test_the_catalogue_holds_mains_pickup_as_a_reading_artefact():
    c = CAUSES["mains_pickup"]
    assert not c.in_compensator and not c.targets  # the force is not affected: the extension is the reading's
    assert "mains" in c.physics and "line" in c.extension


def _with_hum(src: Path, dst: Path, amp: float, hz: float, seed: int = 0) -> Path:
    """The runs of ``src`` with a hum of ``amp`` at ``hz``, random phase per run, added to the reading."""
    dst.mkdir(parents=True)
    rng = np.random.default_rng(seed)
    for f in sorted(src.glob("*.parquet")):
        run = runformat.read_run(f)
        cols = {c: run.data[c].to_numpy() for c in run.data.columns}
        if amp and run.sample_rate_hz >= 2.5 * hz:
            cols[run.output_column] = cols[run.output_column] + amp * np.sin(
                2 * np.pi * hz * run.t_s + rng.uniform(0, 2 * np.pi)
            )
        runformat.write_run(runformat.make_run(cols, dict(run.meta)), dst / f.name)
    return dst


@pytest.mark.integration
@pytest.mark.parametrize("hz", [50.0, 60.0])
def test_diagnose_names_a_hum_added_to_the_reading(tmp_path, sample_base_bundle, hz):
    from piezopress.pipelines import diagnose as D

    runs = _with_hum(CHAR, tmp_path / "runs", 0.6, hz)
    res, _ = D.diagnose([runs], sample_base_bundle, tmp_path / "diag", causes=["mains_pickup"])
    (f,) = [f for f in res.findings if f.cause == "mains_pickup"]
    assert f.parameters["line1_hz"] == pytest.approx(hz, abs=0.05)
    assert f.parameters["line1_amplitude_n"] == pytest.approx(0.6, rel=0.2)
    assert f.gain_pct >= 50.0 and f.extended_rms < f.baseline_rms
    assert f"{hz:.1f} Hz" in f.evidence and "mains pickup" in f.evidence
    assert not res.signatures  # named, so no longer said as structure no cause explains


def test_no_hum_no_mains_finding(tmp_path, sample_base_bundle):
    from piezopress.pipelines import diagnose as D

    runs = tmp_path / "runs"
    shutil.copytree(CHAR, runs)
    res, _ = D.diagnose([runs], sample_base_bundle, tmp_path / "diag", causes=["mains_pickup"])
    assert "mains_pickup" not in [f.cause for f in res.findings]


@pytest.mark.slow
@pytest.mark.parametrize("effect", ["mains_pickup", "clean"])
def test_the_third_press_hum_is_named_and_its_clean_press_is_not(tmp_path, effect):
    import third_press as tp

    from piezopress.pipelines import bundle as B
    from piezopress.pipelines import characterize as char
    from piezopress.pipelines import diagnose as D
    from piezopress.pipelines import fit as F

    rng = np.random.default_rng([1, 97])
    press = tp.clean_press(rng) if effect == "clean" else tp.hidden_press(effect, rng)
    char.characterize(tmp_path / "char", backend=press)
    B.write_document(F.fit_bundle([tmp_path / "char"], press.limits, base=True).doc, tmp_path / "base.json")
    res, _ = D.diagnose([tmp_path / "char"], tmp_path / "base.json", tmp_path / "diag")
    named = [f.cause for f in res.findings]
    assert ("mains_pickup" in named) == (effect == "mains_pickup"), named
