"""``fit --base`` on a press whose loop is of another family (issue 20: causes judged against the
press's own clean physics, not against a base that misfits it).

The base keeps the thesis's structure (12 plays, 1 dead zone) on a press of the modified PI
family, so that ``diagnose`` still finds what more operators would draw. Where the structure
search chooses a Preisach plane (it predicts the sweeps' held-out ends 30 % better than the best
modified PI model) and neither the thesis's operators nor more of them draw the loop within
BASE_THESIS_NOISE times the noise floor (the third press: 95x and 56x), the base takes the searched
structure and says so, and ``hysteresis_order`` is not tested against it (the search already
chose the operators), with the reason. On the third test press (a Preisach plane, written apart
from the project) the thesis's structure left 225 times the noise floor on the sweeps it was
fitted on and ``hysteresis_order`` was named on every clean seed.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import third_press as tp

from piezopress.pipelines import bundle as B
from piezopress.pipelines import characterize as char
from piezopress.pipelines import diagnose as D
from piezopress.pipelines import fit as F


def test_a_press_of_the_pi_family_keeps_the_thesis_structure(sample_base_bundle):
    fit = json.loads(Path(sample_base_bundle).read_text(encoding="utf-8"))["hysteresis"]
    assert fit["fit"]["chosen"] == "n=12 gamma=1 m=1" and "base_structure" not in fit["fit"]
    assert fit["model"]["family"] == "modified_pi"


@pytest.mark.integration
def test_a_loop_of_another_family_gets_the_searched_structure_and_a_base_that_fits_it(tmp_path):
    press = tp.clean_press(np.random.default_rng([0, 97]))
    char.characterize(tmp_path / "char", backend=press)
    doc = F.fit_bundle([tmp_path / "char"], base=True).doc
    h = doc["hysteresis"]
    assert h["model"]["family"] == "pi_preisach_plane"
    assert "another family than play operators" in h["fit"]["base_structure"]
    # the creep kept from the hold alone is fitted past the step's edge: elements of 0.5 s and less
    # hold what the press shows there (under 1 %), not the edge's lag (17 % of the step before)
    c = doc["creep"]["model"]
    fast = sum(g for g, tau in zip(c["gains"], c["taus_s"]) if tau <= 0.5)
    assert c["form"] == "spectrum" and fast < 0.01, c
    # the chain (a 2.5 kHz amplifier, a 1.5 kHz Bessel filter, a 1.5-sample decimation filter after a
    # held DAC): a low-pass and a delay, not a delay of 0.37 ms. With the press's anti-resonance fitted
    # (zeros at 2.3 times the mode), the low-pass reads the Bessel filter (1.49 kHz), the delay the
    # sampling's samples (2.23: the DAC's hold and the filter's 1.5) and, in seconds, about the
    # amplifier's lag (70 us; 66 us read)
    mode = doc["shaper"]["mode"]
    chain = mode["drive_chain"]
    fs = chain["steps_sample_rate_hz"]
    assert chain["form"] == "lowpass_delay" and chain["delay_samples"] < 3.0, chain
    assert 0.0 <= chain["delay_s"] - chain["delay_samples"] / fs < 1e-4, chain
    assert chain["lowpass_hz"] == pytest.approx(1500.0, rel=0.2), chain
    assert mode["antiresonance"]["natural_freq_rad_s"] / mode["natural_freq_rad_s"] == pytest.approx(2.3, rel=0.1)
    # what is beyond the sampling's own is judged on the delay read without the zeros: the sampling's
    assert chain["delay_without_antiresonance_s"] * fs < 3.0, chain
    B.write_document(doc, tmp_path / "base.json")
    res, _ = D.diagnose([tmp_path / "char"], tmp_path / "base.json", tmp_path / "diag")
    # the base fits its own sweeps within 10 noise floors (225 with the thesis's operators)
    assert res.base_fit["ratio"] < 10.0, res.base_fit
    # ... and predicts the 5 and 10 Hz triangles it was not fitted on within 1 % of their range
    # (offsets aside; 4 % with the edge's lag as creep and the chain as a delay)
    bundle = D.read_bundle(tmp_path / "base.json")
    model = bundle.forward_model()
    for r in D.diagnosis_runs(D.collect_runs([tmp_path / "char"]), bundle, None):
        if r.kind == "triangle" and 4.0 < (r.freq_hz or 0) < 20.0:
            e = r.y - model.predict(r)
            assert float(np.std(e)) < 0.01 * float(np.ptp(r.y)), (r.name, float(np.std(e)))
    # the clean press: nothing named, and a plane of 12 levels (refining past them did not help)
    assert res.findings == [], res.summary
    assert h["model"]["preisach_plane"]["levels"] == 12
    (nt,) = [t for t in res.not_tested if t.cause == "hysteresis_order"]
    assert "loop of play operators" in nt.needs


@pytest.mark.slow
def test_a_lag_of_the_force_is_not_called_interference_and_a_coupling_is(tmp_path):
    """The third test press, clean (seed 1 of bench_diagnose): against a base that fits it, a
    residual that grows with the sweep rate (3x from 10 to 100 Hz) remains, which an artefact of
    the drive current takes up at the fast sweeps by over-correcting the slow ones: refused, with
    the reason ("not its signature"). With a capacitive coupling hidden (seed 0), the artefact
    helps every sweep and is named alone."""
    for effect, seed in (("none", 1), ("drive_coupled_interference", 0)):
        rng = np.random.default_rng([seed, 97])
        press = tp.clean_press(rng) if effect == "none" else tp.hidden_press(effect, rng)
        out = tmp_path / effect
        char.characterize(out / "char", backend=press)
        B.write_document(F.fit_bundle([out / "char"], base=True).doc, out / "base.json")
        res, _ = D.diagnose([out / "char"], out / "base.json", out / "diag")
        (tested,) = [t for t in res.tested if t["cause"] == "drive_coupled_interference"]
        if effect == "none":
            assert res.findings == [], res.summary
            assert tested["result"].startswith("not found (not its signature: "), tested
        else:
            assert [f.cause for f in res.findings] == ["drive_coupled_interference"], res.summary


@pytest.mark.slow
@pytest.mark.parametrize(("seed", "fifo"), [(1, 8), (3, 4)])
def test_a_board_fifo_is_named_as_a_delay_counted_in_samples(tmp_path, seed, fifo):
    """The third test press with a FIFO of whole samples (8 or 4 here) between the board and the
    amplifier, characterized at 10, 20 and 50 kHz: in time the delay differs from run to run, so
    the base's chain absorbs it only at the steps' rate. ``input_delay`` tries a delay counted in
    samples beside one in time, refits the chain's low-pass with it (identified on steps that
    lagged by the FIFO, the low-pass took part of its lag, and the fast sweeps then showed it
    twice: with 4 samples nothing was named, with 8 interference was named beside the delay),
    names it alone, and its size is the FIFO and the converter's own 1.5 samples (its sinc
    filter), less the chain's own delay the base holds (up to two samples)."""
    rng = np.random.default_rng([seed, 97])
    press = tp.hidden_press("input_delay", rng)
    assert press.fifo_samples == fifo
    char.characterize(tmp_path / "char", backend=press)
    B.write_document(F.fit_bundle([tmp_path / "char"], base=True).doc, tmp_path / "base.json")
    res, _ = D.diagnose([tmp_path / "char"], tmp_path / "base.json", tmp_path / "diag")
    assert [f.cause for f in res.findings] == ["input_delay"], res.summary
    (f,) = res.findings
    assert "counted in samples" in f.evidence
    assert fifo - 0.5 <= f.parameters["delay_samples"] <= fifo + 3.0, f.parameters
    base_lp = json.loads((tmp_path / "base.json").read_text())["shaper"]["mode"]["drive_chain"]["lowpass_hz"]
    ext_lp = json.loads((tmp_path / "diag" / "extended_bundle.json").read_text())["shaper"]["mode"]["drive_chain"]
    assert ext_lp["lowpass_hz"] > base_lp  # less of the lag in the low-pass


@pytest.mark.slow
@pytest.mark.parametrize("seed", [3, 6])
def test_a_loop_widening_with_the_rate_is_named_on_a_preisach_press_and_frees_the_mode(tmp_path, seed):
    """The third test press with a viscous (square-root of the rate) widening of its Preisach
    loop (seeds 3 and 6 of bench_diagnose): the steps' identification reads the slowed steps as a
    heavily damped mode of half (seed 6: a third) the press's frequency. ``rate_dependent_hysteresis``
    widens the plane's hysterons (the plays alone carry too little of this loop), on the drive the
    stack feels through the chain, its gain estimated on the sweeps alone too (seed 6: the
    distorted mode outweighs the widening on the steps and the 100 Hz sweep), with the mode
    refitted freely: named alone, and the mode it finds within 15 % of the press's."""
    rng = np.random.default_rng([seed, 97])
    press = tp.hidden_press("rate_dependent_hysteresis", rng)
    char.characterize(tmp_path / "char", backend=press)
    B.write_document(F.fit_bundle([tmp_path / "char"], base=True).doc, tmp_path / "base.json")
    base_mode = json.loads((tmp_path / "base.json").read_text())["shaper"]["mode"]
    assert base_mode["natural_freq_rad_s"] / (2 * np.pi) < 0.7 * press.mode_hz  # the distortion is there
    res, _ = D.diagnose([tmp_path / "char"], tmp_path / "base.json", tmp_path / "diag")
    assert [f.cause for f in res.findings] == ["rate_dependent_hysteresis"], res.summary
    (f,) = res.findings
    assert abs(f.model.wn / (2 * np.pi) / press.mode_hz - 1.0) < 0.15, (f.model.wn / (2 * np.pi), press.mode_hz)
    assert "main mode is" in f.evidence
    ext = json.loads((tmp_path / "diag" / "extended_bundle.json").read_text())
    assert abs(ext["shaper"]["mode"]["natural_freq_rad_s"] / f.model.wn - 1.0) < 1e-6  # the shaper is for it


@pytest.mark.slow
def test_a_second_population_of_domains_gets_a_finer_plane(tmp_path):
    """The third test press with a second population of domains switching in a narrow band of the
    field (an S in the loop, 9 V wide against a 12-level plane's 12.5 V cells; seed 0 of
    bench_diagnose): the structure search refines the plane past 12 levels, since the plane wins
    and refining predicts the held-out ends better (16 levels measured; 12 on the clean press,
    test above), and the base fits the sweeps closer to the noise (6.4 floors against 8.2)."""
    press = tp.hidden_press("hysteresis_order", np.random.default_rng([0, 97]))
    char.characterize(tmp_path / "char", backend=press)
    doc = F.fit_bundle([tmp_path / "char"], base=True).doc
    assert doc["hysteresis"]["model"]["preisach_plane"]["levels"] > 12, doc["hysteresis"]["fit"]["chosen"]
    B.write_document(doc, tmp_path / "base.json")
    res, _ = D.diagnose([tmp_path / "char"], tmp_path / "base.json", tmp_path / "diag", causes=["hysteresis_order"])
    assert res.base_fit["ratio"] < 7.5, res.base_fit


@pytest.mark.slow
def test_a_coupling_above_a_threshold_is_named_on_runs_cut_to_the_required_metadata(tmp_path):
    """The virtual rig's coupling dips the reading only above a drive rate the slow sweeps never
    reach: there the extension changes nothing, and the held-out RMS of the 5 and 10 Hz sweeps
    moves a few tenths of a percent either way. On runs cut to the run format's four required
    fields (seed 0 of bench_diagnose --minimal) it moved them 0.0 to 0.5 % the wrong way and
    the signature check refused the coupling on every seed; a sweep counts as predicted worse
    only beyond SWEEP_WORSE_PCT."""
    from foreign import foreign_dir

    from piezopress.acquisition.rig_config import hidden_effect
    from piezopress.acquisition.virtual_rig import VirtualRig

    rng = np.random.default_rng([0, 99])
    char.characterize(tmp_path / "char", backend=VirtualRig(hidden_effect("drive_coupled_interference", rng)))
    runs = foreign_dir(tmp_path / "char", tmp_path / "runs")
    B.write_document(F.fit_bundle([runs], base=True).doc, tmp_path / "base.json")
    res, _ = D.diagnose([runs], tmp_path / "base.json", tmp_path / "diag", causes=["drive_coupled_interference"])
    assert [f.cause for f in res.findings] == ["drive_coupled_interference"], res.as_dict()["tested"]
    (f,) = res.findings
    assert min(f.gain_by_run.values()) > -5.0 and max(f.gain_by_run.values()) >= 20.0


@pytest.mark.slow
def test_a_coupling_that_reads_a_held_out_step_worse_is_refused(tmp_path):
    """The virtual rig with an offset drift (seed 7 of bench_diagnose): the base loop, fitted on
    drifting sweeps, leaves the 50-100 Hz sweeps a misfit that a signed term of the drive rate
    fits (26 % held out), while the 100 V step, where the drive current is largest, reads 61 %
    worse. A coupling of the current would read best there: refused, with that reason, and the
    drift named alone."""
    from piezopress.acquisition.rig_config import hidden_effect
    from piezopress.acquisition.virtual_rig import VirtualRig

    rng = np.random.default_rng([7, 99])
    char.characterize(tmp_path / "char", backend=VirtualRig(hidden_effect("sensor_offset_drift", rng)))
    B.write_document(F.fit_bundle([tmp_path / "char"], base=True).doc, tmp_path / "base.json")
    res, _ = D.diagnose([tmp_path / "char"], tmp_path / "base.json", tmp_path / "diag")
    assert [f.cause for f in res.findings] == ["sensor_offset_drift"], res.summary
    (tested,) = [t for t in res.tested if t["cause"] == "drive_coupled_interference"]
    assert tested["result"].startswith("not found (not its signature: "), tested
    assert "step-100v" in tested["result"] and "where the current is largest" in tested["result"], tested
