"""The mode with an anti-resonance above it (a pair of zeros): its exact discretisation, its
identification from steps (through a monitor, or with the drive chain), and its place in the
bundle, the forward model and the compensator's lead.

Properties rather than golden numbers: the discretisation equals scipy's for both holds and
every rate; zeros far above the mode give the mode back; the zeros' frequency is a notch;
the DC gain is one. The identification is judged on steps drawn here with other chains and
modes than any test press's, and it must not name zeros on steps that have none.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import cont2discrete, freqz, lsim

from piezopress.analysis import bundle as bundle_mod
from piezopress.analysis import identification, mode_fit
from piezopress.analysis.bundle import Bundle, BundleError, antiresonance_lead_s, mode_lag_s
from piezopress.analysis.mode import antiresonant, mode_foh, mode_response, mode_zoh
from piezopress.errors import FitError

WN, ZETA = 2 * math.pi * 800.0, 0.06


def _tf(wn, zeta, wz, zz):
    return [wn * wn / (wz * wz), 2 * zz * wn * wn / wz, wn * wn], [1.0, 2 * zeta * wn, wn * wn]


@pytest.mark.parametrize("hold", ["zoh", "foh"])
@pytest.mark.parametrize(("fs", "ratio", "zz"), [(20e3, 2.3, 0.15), (5e3, 1.4, 0.02), (50e3, 6.0, 0.6)])
def test_the_discretisation_is_scipys_for_every_hold_and_rate(hold, fs, ratio, zz):
    b, a = antiresonant(WN, ZETA, (ratio * WN, zz), fs, hold=hold)
    b_ref, a_ref, _ = cont2discrete(_tf(WN, ZETA, ratio * WN, zz), 1 / fs, method=hold)
    np.testing.assert_allclose(b, b_ref.ravel(), atol=1e-12)
    np.testing.assert_allclose(a, a_ref, atol=1e-12)
    assert sum(b) / sum(a) == pytest.approx(1.0, abs=1e-9)  # unit DC gain


def test_foh_is_exact_for_a_drive_linear_between_samples():
    fs = 20e3
    t = np.arange(400) / fs
    drive = np.interp(t, [0, 1e-3, 1.6e-3, 20e-3], [0, 0, 20, 20])
    wz, zz = 2.3 * WN, 0.15
    _, y_ref, _ = lsim(_tf(WN, ZETA, wz, zz), drive, t)
    np.testing.assert_allclose(mode_response(drive, fs, WN, ZETA, hold="foh", zeros=(wz, zz)), y_ref, atol=1e-7)


@pytest.mark.parametrize("hold", ["zoh", "foh"])
def test_zeros_far_above_give_the_mode_back(hold):
    b, a = antiresonant(WN, ZETA, (1e6 * WN, 0.1), 20e3, hold=hold)  # its lead: 2 zeta_z / wz, 4e-11 s
    b_m, a_m = {"zoh": mode_zoh, "foh": mode_foh}[hold](WN, ZETA, 20e3)
    np.testing.assert_allclose(a, a_m, atol=1e-15)
    np.testing.assert_allclose(b, b_m, atol=1e-7)


def test_the_zeros_are_a_notch_and_lead():
    fs, wz = 50e3, 2.3 * WN
    b, a = antiresonant(WN, ZETA, (wz, 0.01), fs, hold="zoh")
    _, h = freqz(b, a, worN=[wz / (2 * math.pi), 0.5 * WN / (2 * math.pi)], fs=fs)
    assert abs(h[0]) < 0.05  # at the anti-resonance: a notch (1 % damping)
    # below the mode: the mode's gain times the zeros' (1 - (w / wz)^2)
    assert abs(h[1]) == pytest.approx((1 - (0.5 / 2.3) ** 2) / (1 - 0.25), rel=0.01)
    # the low-frequency delay: 2 zeta / wn less the zeros' lead 2 zeta_z / wz
    mode = {"natural_freq_rad_s": WN, "damping": ZETA, "antiresonance": {"natural_freq_rad_s": wz, "damping": 0.3}}
    assert mode_lag_s(mode) == pytest.approx(2 * ZETA / WN - 2 * 0.3 / wz)
    assert antiresonance_lead_s(None) == 0.0
    assert mode_lag_s({**mode, "antiresonance": None}) == pytest.approx(2 * ZETA / WN)


def _steps(make, zeros, fs=20_000.0, noise=0.05, sizes=(20.0, 50.0, 100.0, 150.0)):
    """Steps through the drive chain ``make(command, fs)``, then the mode (with ``zeros``)."""
    ts, cmds, ys = [], [], []
    for v in sizes:
        t = np.arange(int(0.05 * fs)) / fs
        c = np.where(t >= 0.005, v, 0.0)
        y = 50.0 + 2.0 * mode_response(make(c, fs), fs, WN, ZETA, hold="foh", zeros=zeros)
        ts.append(t), cmds.append(c), ys.append(y + np.random.default_rng(int(v)).normal(0, noise, t.size))
    return ts, cmds, ys


def _series(c, fs):
    return mode_fit.lowpass_delayed(c, fs, (2 * math.pi * 1500.0, 0.7, 1.0e-4))


@pytest.mark.integration
@pytest.mark.parametrize(("ratio", "zz"), [(2.3, 0.15), (3.5, 0.05)])
def test_an_antiresonance_is_named_through_the_drive_chain(ratio, zz):
    """Steps through a low-pass and a delay in series, the mode with zeros above it: the series
    chain and the zeros are named, the zeros within 5 % in frequency, the mode within 2 %, and
    the chain's low-frequency delay within 10 us (without the zeros it takes their lead)."""
    ts, cmds, ys = _steps(_series, (ratio * WN, zz))
    found = mode_fit.identify_mode_chain(ts, cmds, ys)
    assert found.chain == "lowpass_delay", found.candidates
    assert found.mode.zeros is not None, found.candidates
    assert found.mode.zeros[0] == pytest.approx(ratio * WN, rel=0.05)
    assert found.mode.wn == pytest.approx(WN, rel=0.02)
    true_lag = 2 * 0.7 / (2 * math.pi * 1500.0) + 1.0e-4
    assert mode_fit.lowpass_delay_group_delay_s(*found.parameter) == pytest.approx(true_lag, abs=1e-5)
    shown = found.candidates["lowpass_delay+antiresonance"]
    assert shown < (1 - mode_fit.ANTIRESONANCE_MARGIN) * found.candidates["lowpass_delay"]


@pytest.mark.integration
@pytest.mark.parametrize(
    "make",
    [
        _series,
        lambda c, fs: mode_fit.delayed(c, fs, 3.7e-4),
        lambda c, fs: mode_fit.first_order(c, fs, 2e-4),
        lambda c, fs: c,
    ],
    ids=["series", "delay", "first_order", "none"],
)
def test_steps_without_zeros_are_given_none(make):
    found = mode_fit.identify_mode_chain(*_steps(make, None))
    assert found.mode.zeros is None, found.candidates


def test_the_mode_on_small_steps_keeps_the_zeros_the_steps_of_every_size_showed():
    zeros = (2.3 * WN, 0.15)
    small = _steps(_series, zeros, sizes=(20.0, 30.0))
    every = _steps(_series, zeros)
    found = mode_fit.identify_mode_chain(*small, chain_from=every)
    assert found.mode.zeros is not None
    assert found.mode.zeros[0] == pytest.approx(zeros[0], rel=0.05)


def test_with_a_monitor_the_zeros_are_fitted_with_the_mode():
    fs = 20e3
    t = np.arange(int(0.05 * fs)) / fs
    ts, drives, ys = [], [], []
    for v in (10.0, 20.0, 30.0):
        d = np.interp(t, [0, 5e-3, 5.5e-3, 1], [0, 0, v, v])  # a slewed, monitored drive
        y = 50 + 2 * mode_response(d, fs, WN, ZETA, hold="foh", zeros=(2.3 * WN, 0.15))
        ts.append(t), drives.append(d), ys.append(y + np.random.default_rng(int(v)).normal(0, 0.05, t.size))
    plain = mode_fit.identify_mode_runs(ts, drives, ys)
    zeroed = mode_fit.identify_mode_runs(ts, drives, ys, antiresonance=True)
    assert mode_fit.antiresonance_shown(plain, zeroed)
    assert zeroed.zeros[0] == pytest.approx(2.3 * WN, rel=0.02)
    assert zeroed.zeros[1] == pytest.approx(0.15, abs=0.03)
    assert zeroed.wn == pytest.approx(WN, rel=0.005)
    # fixed zeros fit the mode alone through them
    held = mode_fit.identify_mode_runs(ts, drives, ys, zeros=zeroed.zeros)
    assert held.zeros == zeroed.zeros and held.wn == pytest.approx(zeroed.wn, rel=1e-3)
    with pytest.raises(FitError, match="not both"):
        mode_fit.identify_mode_runs(ts, drives, ys, zeros=zeroed.zeros, antiresonance=True)


# --------------------------------------------------------------------------- in the bundle

ROOT = Path(__file__).resolve().parents[1]
ZEROS = {"natural_freq_rad_s": 2.3 * 5000.0, "damping": 0.15}


def _sample_doc(zeros=ZEROS, chain=None):
    doc = json.loads((ROOT / "sample_runs" / "bundle.json").read_text())
    doc["shaper"]["mode"]["antiresonance"] = zeros
    if chain is not None:
        doc["shaper"]["mode"]["drive_chain"] = chain
    return doc


def test_the_bundle_records_the_zeros_and_the_forward_model_draws_them():
    b = Bundle.from_dict(_sample_doc())
    assert b.antiresonance == (ZEROS["natural_freq_rad_s"], ZEROS["damping"])
    assert b.forward_model().antiresonance == b.antiresonance
    assert Bundle.from_dict(_sample_doc(None)).forward_model().antiresonance is None
    for bad, key in (({"damping": 0.1}, "natural_freq_rad_s"), ({**ZEROS, "damping": 1.5}, "damping"), ([1, 2], "")):
        with pytest.raises(BundleError, match=f"shaper.mode.antiresonance.*{key}"):
            Bundle.from_dict(_sample_doc(bad))


def test_the_lead_is_the_mode_s_delay_less_the_zeros_lead():
    mode = {"natural_freq_rad_s": 5000.0, "damping": 0.1, "drive_chain": None}
    plain = identification.compensation_settings({"shaper": {"mode": mode}})["lead_s"]
    zeroed = identification.compensation_settings({"shaper": {"mode": {**mode, "antiresonance": ZEROS}}})["lead_s"]
    assert plain == pytest.approx(2 * 0.1 / 5000.0)
    assert plain - zeroed == pytest.approx(2 * 0.15 / (2.3 * 5000.0))


@pytest.mark.parametrize(
    ("delay_s", "without_s", "own_s"),
    [
        (177e-6, 83e-6, 177e-6),  # the zeros moved lag from the low-pass to the delay: all the chain's own
        (477e-6, 411e-6, 166e-6),  # a FIFO of 6 samples beyond the sampling's 2 (20 kHz) stays beyond
        (177e-6, None, 100e-6),  # no zeros fitted with the chain: up to the sampling's 2 samples
    ],
)
def test_what_is_beyond_the_sampling_s_delay_is_judged_without_the_zeros(delay_s, without_s, own_s):
    chain = {
        "form": "lowpass_delay",
        "lowpass_hz": 1500.0,
        "lowpass_damping": 0.9,
        "delay_s": delay_s,
        "steps_sample_rate_hz": 20_000.0,
        "delay_without_antiresonance_s": without_s,
    }
    assert bundle_mod.chain_own_delay(chain) == pytest.approx((own_s, 20_000.0))
    model = Bundle.from_dict(_sample_doc(chain=chain)).forward_model()
    assert model.drive_delay_s == pytest.approx(own_s)


def test_the_report_names_the_zeros_and_says_nothing_without_them(tmp_path):
    from piezopress.pipelines.report_doc import render_markdown
    from piezopress.pipelines.report_model import _model_quality

    doc = _sample_doc()
    wn = doc["shaper"]["mode"]["natural_freq_rad_s"]
    md = render_markdown(_model_quality(doc, tmp_path / "bundle.json", []))
    hz = ZEROS["natural_freq_rad_s"] / (2 * math.pi)
    assert f"An anti-resonance above it: zeros at {hz:.1f} Hz ({ZEROS['natural_freq_rad_s'] / wn:.2f} times" in md
    assert "anti-resonance" not in render_markdown(_model_quality(_sample_doc(None), tmp_path / "b.json", []))
