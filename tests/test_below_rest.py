"""Below the rest drive (issue 19): a stack whose remanence rests it above the preload is pulled
below its rest drive by a compensator asked for the preload.

* The Preisach plane's rest is a driven stack's (the drive came down to rest from above): the
  relays that switch down below rest are up, the model's output at rest is its rest output,
  and a fit on runs that stay above rest keeps a density below it instead of zeroing it.
* The default characterization measures the stack there (``kind = "below_rest"``): from rest up
  to each peak, down to the actuator's lowest drive between them, back to rest from above.
* A held step's creep is fitted with the step edge aligned: the chain's milliseconds of lag are
  not creep.
* The compensator leads the drive chain identified with the mode.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from piezopress.acquisition import waveforms
from piezopress.acquisition.plan import DriveLimits, PlanError, load_plan, parse_plan
from piezopress.analysis import bundle as bundle_mod
from piezopress.analysis import creep as C
from piezopress.analysis import hysteresis as H
from piezopress.analysis import identification
from piezopress.analysis import profile as prof
from piezopress.analysis.bundle import Bundle, BundleError

sys.path.insert(0, str(Path(__file__).resolve().parent))
ROOT = Path(__file__).resolve().parents[1]
LIMITS = DriveLimits(drive_min_v=-30.0, drive_max_v=150.0)


def _plane_model(seed: int = 3) -> H.PIModel:
    rng = np.random.default_rng(seed)
    plane = H.PreisachPlane.grid(-30.0, 150.0, 9)
    plane = plane.with_weights(rng.uniform(0.2, 1.0, plane.n_cells) * 2.0)
    return H.PIModel((0.0, 10.0), (0.4, 0.1), (0.0, 80.0), (1.0, -0.2), 0.0, 60.0, plane=plane)


# --------------------------------------------------------------------------- the plane's rest


def test_the_plane_rests_as_a_driven_stack_and_outputs_its_rest_level_there():
    m = _plane_model()
    a, b, _ = m.plane.arrays()
    rest = m.plane.rest_state()
    h = m.plane.width
    assert np.all(rest[b + h <= 0.0] == 1.0)  # switch down only below rest: up
    assert np.all(rest[b >= 0.0] == 0.0)  # switch down at or above rest: down
    assert m.plane.rest_output() > 0.0  # weights on the cells up at rest
    y, _ = m.forward(np.zeros(50))
    np.testing.assert_allclose(y, m.y0, atol=1e-12)  # the columns are relative to the rest
    np.testing.assert_allclose(m.plane.columns(np.zeros(3)), 0.0, atol=0.0)


def test_below_rest_forward_chunks_equal_one_shot_and_the_inverse_returns_the_drive():
    m = _plane_model(5)
    t = np.linspace(0.0, 6.0, 6000)
    x = 50.0 * np.sin(2 * np.pi * 0.7 * t) + 40.0 * np.sin(2 * np.pi * 0.23 * t)  # -90..90 V, below rest often
    y, state = m.forward(x)
    y1, s1 = m.forward(x[:2345])
    y2, s2 = m.forward(x[2345:], s1)
    np.testing.assert_allclose(np.concatenate([y1, y2]), y, atol=1e-10)
    np.testing.assert_allclose(s2, state, atol=1e-12)
    assert np.all((state[m.n_play :] >= 0.0) & (state[m.n_play :] <= 1.0))  # a state, not a column
    xi, si = m.inverse(y)
    np.testing.assert_allclose(xi, x, atol=1e-8)
    np.testing.assert_allclose(si, state, atol=1e-8)


def test_a_fit_above_rest_keeps_a_density_below_it():
    """A Preisach stack (tests/third_press.py, an Everett function) that has been driven before:
    its runs start at rest with the relays below rest up and never switch them. A plane whose
    rest had every relay down switched them on every run's first rise, which the runs never
    show, and the fit zeroed them (measured: under 5 % of the weight of the cells just above
    rest); a compensator pulling below rest then found no slope there."""
    import third_press as tp

    ev = tp.ThirdPress()._everett
    mem = tp.PreisachMemory(ev)
    mem.run(np.concatenate([np.linspace(0.0, 150.0, 500), np.linspace(150.0, 0.0, 500)]))  # a used stack
    t = np.arange(0, 20.0, 0.01)
    tri = 1 - np.abs((t * 0.1) % 1 * 2 - 1)
    runs = [
        (n, v, 50.0 + 1.6 * mem.run(v))
        for n, v in (("tri-150", 150 * tri), ("tri-75", 75 * tri), ("tri-inc", 150 * tri * t / t[-1]))
    ]
    fit = H.fit_hysteresis(H.prepare(runs, holdout_fraction=0.3))
    assert fit.model.family == H.FAMILY_PLANE, fit.family_reason
    a, b, mu = fit.final_model.plane.arrays()
    h = fit.final_model.plane.width
    below = (b < -0.5 * h) & (a >= 0.0) & (a < 3 * h)  # switch down below rest, up near it
    above = (b >= 0.0) & (b < h) & (a < 3 * h)  # their neighbours just above rest
    assert below.any() and above.any()
    assert mu[below].mean() >= 0.25 * mu[above].mean(), (mu[below].mean(), mu[above].mean())


# --------------------------------------------------------------------------- the protocol


def test_the_below_rest_waveform_goes_from_rest_to_each_peak_and_below_rest_between_them():
    v = waveforms.below_rest(0.1, np.array([150.0, 90.0, 30.0]), -30.0, 0.0, 500.0)
    half = int(500.0 / 0.2)
    assert v.size == 3 * 2 * half + 1  # one period per peak
    assert v[0] == 0.0 and v[-1] == 0.0
    np.testing.assert_allclose(v[[half, 3 * half, 5 * half]], [150.0, 90.0, 30.0])
    np.testing.assert_allclose(v[[2 * half, 4 * half]], [-30.0, -30.0])
    assert np.all(np.diff(v[5 * half :]) < 0)  # back to rest from above
    assert v.min() == -30.0 and v.max() == 150.0


def _doc(**keys):
    proto = {"name": "below", "kind": "below_rest", "freq_hz": 0.1, "sample_rate_hz": 500.0, **keys}
    return {"plan": {"name": "x"}, "protocol": [proto]}


def test_the_lowest_drive_defaults_to_the_actuators_and_the_plan_checks_the_shape():
    plan = parse_plan(_doc(peaks_v=[150.0, 60.0]), LIMITS)
    p = plan.protocols[0]
    assert p.params["low_v"] == -30.0 and p.params["rest_v"] == 0.0
    _, drive = p.waveform()
    assert drive.min() == -30.0 and drive[0] == 0.0 and drive[-1] == 0.0
    unipolar = parse_plan(_doc(peaks_v=[150.0, 90.0]), DriveLimits(drive_min_v=0.0, drive_max_v=150.0))
    assert unipolar.protocols[0].params["low_v"] == 0.0  # a stack that cannot go below rest: plain sweeps
    with pytest.raises(PlanError, match="low_v' = 5 is above rest_v = 0"):
        parse_plan(_doc(peaks_v=[150.0, 90.0], low_v=5.0), LIMITS)
    with pytest.raises(PlanError, match="peaks_v': -40 is not above"):
        parse_plan(_doc(peaks_v=[150.0, -40.0]), LIMITS)
    with pytest.raises(PlanError, match="-40 V, outside the actuator's range -30 to 150 V"):
        parse_plan(_doc(peaks_v=[150.0, 90.0], low_v=-40.0), LIMITS)
    with pytest.raises(PlanError, match="at least two voltages"):
        parse_plan(_doc(peaks_v=[150.0]), LIMITS)
    with pytest.raises(PlanError, match="'depths' = \\[1.0\\] must list 2 shares from 0 to 1"):
        parse_plan(_doc(peaks_v=[150.0, 90.0, 30.0], depths=[1.0]), LIMITS)
    with pytest.raises(PlanError, match="must list 1 shares"):
        parse_plan(_doc(peaks_v=[150.0, 90.0], depths=[1.5]), LIMITS)
    _, v = parse_plan(_doc(peaks_v=[150.0, 90.0, 30.0], depths=[1.0, 0.5]), LIMITS).protocols[0].waveform()
    half = int(500.0 / 0.2)
    np.testing.assert_allclose(v[[2 * half, 4 * half]], [-30.0, -15.0])  # each low as deep as asked


def test_the_default_plan_measures_below_rest_and_fit_takes_it_as_a_quasi_static_sweep():
    from piezopress.acquisition import plan as plan_mod

    plan = load_plan(ROOT / "protocols" / "characterize.toml", LIMITS)
    below = [p for p in plan.protocols if p.kind == "below_rest"]
    assert len(below) == 1 and below[0].params["low_v"] == LIMITS.drive_min_v
    assert below[0].run_kind == "triangle"
    t, v = below[0].waveform()
    turns = v[np.flatnonzero(np.diff(np.sign(np.diff(v))) > 0) + 1]  # the lows between the peaks
    np.testing.assert_allclose(turns, [-30.0, -20.1, -9.9, -30.0], atol=1e-9)  # minor loops below rest too
    p = prof.profile_signals(t, v)
    assert p.quasi_static and p.kind == "triangle", p.describe()
    assert plan_mod.estimated_duration_s("below_rest", below[0].params) == pytest.approx(t[-1], abs=0.01)


# --------------------------------------------------------------------------- the held step's edge


def test_a_held_steps_creep_is_not_the_chains_lag_at_its_edge():
    """A 1 % creep of seconds behind a step whose reading lags 3 ms (a chain of filters):
    fitted with the edge aligned, the instantaneous gain is the step's and no fast element
    takes the lag (unaligned: 5 % of the step in elements under 0.2 s on the third test press)."""
    fs = 1000.0
    t = np.arange(0, 60.0, 1.0 / fs)
    u = np.where(t >= 1.0, 300.0, 0.0)
    truth = C.CreepModel("spectrum", 0.99, (2.0, 20.0), (0.004, 0.006), {})  # creep of seconds only
    y, _ = truth.response(u, fs)
    lag = 3
    y = np.concatenate([np.zeros(lag), y[:-lag]])
    y = y + np.random.default_rng(0).normal(0, 0.05, y.size)
    fit = C.fit_held_step(t, u, np.where(t >= 1.0, 150.0, 0.0), y, fs, forms=("spectrum",))
    m = fit.model
    fast = sum(g for g, tau in zip(m.gains, m.taus_s) if tau < 0.2)
    assert fast < 0.002, (fast, m.describe())  # measured 0.03 unaligned
    k = np.searchsorted(t, 1.1)
    assert m.static_gain + fast == pytest.approx(y[k] / 300.0, rel=0.003)


def test_the_edge_is_aligned_only_for_a_step():
    u = np.where(np.arange(1000) >= 100, 10.0, 0.0)
    y = np.concatenate([np.zeros(4), u[:-4]])
    np.testing.assert_array_equal(C.edge_aligned(u, y, 1000.0), y)
    ramp = np.linspace(0.0, 10.0, 1000)  # no edge: left alone
    np.testing.assert_array_equal(C.edge_aligned(ramp, np.roll(ramp, 5), 1000.0), ramp)


# --------------------------------------------------------------------------- the chain's lead


def _sections(chain):
    mode = {"natural_freq_rad_s": 5000.0, "damping": 0.1, "drive_chain": chain}
    return {"shaper": {"mode": mode}}


@pytest.mark.parametrize(
    ("chain", "expected"),
    [
        ({"form": "delay", "delay_s": 4e-4, "tau_s": None, "slew_v_per_s": None}, 4e-4),
        ({"form": "first_order", "delay_s": None, "tau_s": 1e-4, "slew_v_per_s": None}, 1e-4),
        ({"form": "slew", "delay_s": None, "tau_s": None, "slew_v_per_s": 1e5}, 0.0),
        (None, 0.0),
    ],
)
def test_the_lead_includes_the_identified_chains_low_frequency_delay(chain, expected):
    comp = identification.compensation_settings(_sections(chain))
    assert comp["lead_s"] == pytest.approx(2 * 0.1 / 5000.0 + expected, rel=1e-12)
    assert comp.get("chain_lead_s", 0.0) == pytest.approx(expected, rel=1e-12)


def test_a_series_chains_own_delay_is_led_in_samples_of_the_references_rate():
    # a low-pass (1 kHz, damping 0.7) and 3 samples of delay at the steps' 20 kHz: 2 of them the
    # sampling's own, led in samples of the reference's rate; the rest, with the low-pass, in seconds
    import json

    chain = {"form": "lowpass_delay", "lowpass_hz": 1000.0, "lowpass_damping": 0.7, "delay_s": 1.5e-4}
    gd = 2 * 0.7 / (2 * math.pi * 1000.0)
    comp = identification.compensation_settings(_sections({**chain, "steps_sample_rate_hz": 20_000.0}))
    assert comp["chain_lead_s"] == pytest.approx(gd + 0.5e-4, rel=1e-12)
    assert comp["chain_lead_samples"] == pytest.approx(2.0, rel=1e-12)
    doc = json.loads((ROOT / "sample_runs" / "bundle.json").read_text())
    doc["compensation"].update(comp)
    b = Bundle.from_dict(doc)
    for fs in (500.0, 20_000.0, 50_000.0):
        assert b.compensator().lead_at(fs) == pytest.approx(2 * 0.1 / 5000.0 + gd + 0.5e-4 + 2.0 / fs, rel=1e-12)
        assert b.compensator(use_shaper=False).lead_at(fs) == pytest.approx(gd + 0.5e-4 + 2.0 / fs, rel=1e-12)
    # without the steps' rate (a bundle written before it was recorded): all of it in seconds, as before
    comp = identification.compensation_settings(_sections(chain))
    assert comp["chain_lead_s"] == pytest.approx(gd + 1.5e-4, rel=1e-12) and "chain_lead_samples" not in comp
    for bad in (-1.0, 1e5, float("nan"), "2"):
        doc["compensation"]["chain_lead_samples"] = bad
        with pytest.raises(BundleError, match="chain_lead_samples"):
            Bundle.from_dict(doc)


def test_a_delay_in_samples_steps_at_two_rates_told_is_led_as_told():
    """Steps at two rates told the chain's delay: 2.5 samples and -30 us (a low-pass holding part
    of the sampling's lag), recorded as 95 us at the steps' 20 kHz. The 2.5 samples are led in
    samples of each reference's rate, the rest (the low-pass's lag, less 30 us) in seconds; the
    two-sample rule of one rate is not applied. Found with an input delay by diagnose, the part in
    samples goes with the finding, and the old rule stands for what the chain keeps."""
    import json

    gd = 2 * 0.7 / (2 * math.pi * 1000.0)
    chain = {
        "form": "lowpass_delay",
        "lowpass_hz": 1000.0,
        "lowpass_damping": 0.7,
        "delay_s": -3e-5 + 2.5 / 20_000.0,
        "delay_samples": 2.5,
        "steps_sample_rate_hz": 20_000.0,
    }
    comp = identification.compensation_settings(_sections(chain))
    assert comp["chain_lead_samples"] == pytest.approx(2.5, rel=1e-12)
    assert comp["chain_lead_s"] == pytest.approx(gd - 3e-5, rel=1e-12)
    doc = json.loads((ROOT / "sample_runs" / "bundle.json").read_text())
    doc["compensation"].update(comp)
    b = Bundle.from_dict(doc)
    for fs in (500.0, 20_000.0, 50_000.0):
        assert b.compensator(use_shaper=False).lead_at(fs) == pytest.approx(gd - 3e-5 + 2.5 / fs, rel=1e-12)
    # what diagnose's forward model holds is the one-rate rule's, at the steps' rate (up to 2 samples)
    assert bundle_mod.chain_own_delay(chain) == pytest.approx((9.5e-5, 20_000.0))
    assert bundle_mod.chain_leads({**chain, "delay_samples": None}) == pytest.approx((gd, 1.9))
    # ... and of it, what is in samples (1.9 of the 2.5 told) lasts fewer seconds in a faster run
    doc["shaper"]["mode"]["drive_chain"] = chain
    model = Bundle.from_dict(doc).forward_model()
    assert model.drive_delay_s == pytest.approx(9.5e-5) and model.drive_delay_samples == pytest.approx(1.9)
    assert model.chain_samples == pytest.approx(2.5)  # the whole told delay: input_delay's contrast checks on it
    assert model.drive_delay_at(50_000.0) == pytest.approx(9.5e-5 - 1.9 * (1 / 20_000.0 - 1 / 50_000.0))
    assert model.drive_delay_at(20_000.0) == model.drive_delay_at(500.0) == pytest.approx(9.5e-5)
    assert model.drive_delay_at(1e9) >= 0.0
    doc["shaper"]["mode"]["drive_chain"] = {**chain, "delay_samples": None}  # one rate: seconds at every rate
    assert Bundle.from_dict(doc).forward_model().drive_delay_at(50_000.0) == pytest.approx(9.5e-5)
    assert Bundle.from_dict(doc).forward_model().chain_samples == 0.0  # not told: the contrast is not checked


def test_without_a_shaper_the_chain_is_still_led_and_a_chain_beyond_the_lead_is_refused():
    import json

    doc = json.loads((ROOT / "sample_runs" / "bundle.json").read_text())
    doc["compensation"].update(lead_s=5e-4, chain_lead_s=3e-4, delay_lead_s=1e-4)
    b = Bundle.from_dict(doc)
    assert b.compensator(use_shaper=False).lead_s == pytest.approx(4e-4)
    assert b.compensator().lead_s == pytest.approx(5e-4)
    doc["compensation"]["chain_lead_s"] = 6e-4
    with pytest.raises(BundleError, match="chain_lead_s"):
        Bundle.from_dict(doc)
    assert math.isfinite(b.settings.chain_lead_s)


# --------------------------------------------------------------------------- which fits use the run


@pytest.fixture(scope="module")
def third_char(tmp_path_factory):
    """The third test press (a Preisach stack resting above its preload) through the default plan."""
    import third_press as tp

    from piezopress import runformat
    from piezopress.pipelines import characterize as char

    out = tmp_path_factory.mktemp("third") / "char"
    char.characterize(out, backend=tp.clean_press(np.random.default_rng([0, 97])))
    return out, [runformat.read_run(p) for p in sorted(out.glob("*.parquet"))]


@pytest.mark.integration
def test_the_below_rest_run_is_told_from_the_signals_and_kept_where_the_model_draws_both(third_char, monkeypatch):
    _, runs = third_char
    sweeps = identification.quasi_static_sweeps(runs)
    below = identification.below_rest_runs(runs)
    assert [r.name for r in below] == ["triangle-below-rest-0.1hz"]
    names = {r.name for r in below}
    assert identification.below_rest_runs([r for r in runs if r.name not in names]) == []
    kept, why, _ = identification.below_rest_choice(sweeps, below)
    # measured: the other sweeps' held-out ends 0.579 N with it, 0.627 N without
    assert len(kept) == len(sweeps) and "kept" in why, why
    monkeypatch.setattr(identification, "BELOW_REST_TOLERANCE", -0.5)  # a rule it cannot pass: left out
    kept, why, _ = identification.below_rest_choice(sweeps, below)
    assert [r.name for r in kept] == [r.name for r in sweeps if r.name not in names] and "left out" in why, why


@pytest.mark.integration
def test_base_and_diagnose_keep_to_the_range_the_thesis_model_was_fitted_on(third_char, tmp_path):
    from piezopress.pipelines import bundle as B
    from piezopress.pipelines import diagnose as D
    from piezopress.pipelines import fit as F
    from piezopress.pipelines import profiles

    char_dir, _ = third_char
    profiles.trust_metadata(False)  # a new list of the notes fit makes (the default: decide from the signals)
    doc = F.fit_bundle([char_dir], base=True).doc
    notes = profiles.profile_notes()
    assert any("fit --base leaves out triangle-below-rest-0.1hz" in n for n in notes), notes
    assert "triangle-below-rest-0.1hz" not in [r["name"] for r in doc["hysteresis"]["runs"]]
    B.write_document(doc, tmp_path / "base.json")
    result, _ = D.diagnose([char_dir], tmp_path / "base.json", tmp_path / "diag", causes=["input_delay"])
    assert ". Left out: triangle-below-rest-0.1hz" in result.summary, result.summary  # a sentence of its own
    full = F.fit_bundle([char_dir]).doc
    assert "triangle-below-rest-0.1hz" in full["hysteresis"]["fit"]["below_rest"]


def test_the_report_says_what_the_fit_did_below_rest_and_how_much_of_the_lead_is_the_chain(tmp_path):
    import json

    from piezopress.pipelines.report_doc import render_markdown
    from piezopress.pipelines.report_model import _model_quality

    doc = json.loads((ROOT / "sample_runs" / "bundle.json").read_text())
    doc["hysteresis"]["fit"]["below_rest"] = "triangle-below-rest-0.1hz kept (the stack below its rest): ..."
    doc["compensation"].update(lead_s=4.1e-4, chain_lead_s=3.74e-4)
    md = render_markdown(_model_quality(doc, tmp_path / "bundle.json", []))
    assert "Below the rest drive: triangle-below-rest-0.1hz kept" in md
    assert "lead 0.4100 ms (of which 0.3740 ms the drive chain identified with the mode" in md
    # the rate limit is read under its unit's key (max_rate_n_per_s): it read "no rate limit" before
    assert "rate limit 40.0 N/ms" in md
    doc["compensation"]["chain_lead_samples"] = 1.64
    md = render_markdown(_model_quality(doc, tmp_path / "bundle.json", []))
    assert "with the mode: the reading's lag is led too), and 1.64 samples of the reference's rate" in md, md
    doc["compensation"].pop("chain_lead_s")
    doc["compensation"].pop("chain_lead_samples")
    assert "lead 0.4100 ms." in render_markdown(_model_quality(doc, tmp_path / "bundle.json", []))
