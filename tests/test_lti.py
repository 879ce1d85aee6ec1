"""The press's linear parts through python-control (piezopress.analysis.lti): the mode, the
creep model and its compensator, a measured frequency response, a shaper's sensitivity."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from piezopress.analysis import lti
from piezopress.analysis import shaper as S
from piezopress.analysis.creep import CreepModel
from piezopress.analysis.mode import mode_response
from piezopress.errors import FitError


@settings(max_examples=40, deadline=None)
@given(wn=st.floats(100.0, 1e5), zeta=st.floats(0.01, 0.9))
def test_the_mode_has_unit_dc_gain_and_peaks_at_one_over_two_zeta(wn, zeta):
    g = lti.mode_system(wn, zeta)
    b = lti.bode(g, np.array([wn / 2 / math.pi * 1e-4, wn / 2 / math.pi, wn / 2 / math.pi * 1e3]))
    assert b.magnitude[0] == pytest.approx(1.0, rel=1e-6)
    assert b.magnitude[1] == pytest.approx(1.0 / (2.0 * zeta), rel=1e-9)
    assert b.phase_deg[1] == pytest.approx(-90.0, abs=1e-6)
    assert b.magnitude[2] == pytest.approx(1e-6, rel=1e-2)  # -40 dB per decade


creep_models = st.one_of(
    st.builds(CreepModel.log, st.floats(0.5, 2.0), st.floats(0.0, 0.05)),
    st.builds(
        lambda kc, k, tz: CreepModel.poles(kc, k, tz, 46.223, 1.5618, 0.001),
        st.floats(0.5, 2.0),
        st.floats(0.0, 0.1),
        st.floats(0.0, 40.0),
    ),
)


@settings(max_examples=40, deadline=None)
@given(model=creep_models)
def test_the_creep_compensator_is_the_models_exact_inverse(model):
    f = np.geomspace(1e-6, 100.0, 40)
    plant, comp = lti.creep_system(model), lti.creep_compensator_system(model)
    both = lti.bode(plant * comp, f)
    assert np.max(np.abs(both.magnitude - 1.0)) < 1e-9 and np.max(np.abs(both.phase_deg)) < 1e-7
    b = lti.bode(plant, np.array([1e-9, 1e4]))
    assert b.magnitude[0] == pytest.approx(model.dc_gain, rel=1e-4)  # creep settled
    assert b.magnitude[1] == pytest.approx(model.static_gain, rel=1e-4)  # the instant after a step
    assert np.all(np.linalg.eigvals(comp.A).real < 0)


def test_a_non_minimum_phase_creep_model_has_no_compensator():
    model = CreepModel("poles", 1.0, (1.0,), (-2.0,))  # 1 - 2 / (1 + s) = (s - 1) / (s + 1): a zero at +1
    with pytest.raises(FitError, match="unstable pole at 1"):
        lti.creep_compensator_system(model)


@pytest.mark.parametrize("wn, zeta", [(6400.0, 0.17), (3000.0, 0.05), (12000.0, 0.3)])
def test_a_step_response_gives_back_the_mode_it_was_made_with(wn, zeta):
    """A ramped step up and down through the mode (the amplifier monitor's shape), with noise:
    the measured response follows the mode within 6 % and 3 deg from 0.03 to 2 times its frequency
    (below a tenth of the sample rate: beyond it, the sampled records fold the ramps' spectrum back; and
    6 %: each point averages +/-2 % of its frequency, which blunts a sharp peak by that much)."""
    fs = 20000.0
    t = np.arange(int(0.16 * fs)) / fs
    drive = np.clip((t - 0.01) / 0.0005, 0, 1) - np.clip((t - 0.11) / 0.0005, 0, 1)
    y = 1.8 * mode_response(drive, fs, wn, zeta, hold="foh") + np.random.default_rng(1).normal(0, 1e-4, t.size)
    fn = wn / 2 / math.pi
    f = np.geomspace(0.03 * fn, min(2 * fn, 0.1 * fs), 30)
    m = lti.measured_response(drive, y, fs, f)
    model = lti.bode(lti.mode_system(wn, zeta), f)
    assert m.gain == pytest.approx(1.8, rel=0.01) and m.coherent.sum() >= 25
    k = m.coherent
    assert np.max(np.abs(m.magnitude[k] / model.magnitude[k] - 1)) < 0.06
    assert np.max(np.abs(m.phase_deg[k] - model.phase_deg[k])) < 3.0


def test_measured_response_refuses_what_it_cannot_use():
    with pytest.raises(FitError, match="same length"):
        lti.measured_response(np.zeros(100), np.zeros(99), 1000.0, [1.0, 2.0])
    with pytest.raises(FitError, match="below Nyquist"):
        lti.measured_response(np.zeros(100), np.zeros(100), 1000.0, [1.0, 600.0])
    with pytest.raises(FitError, match="no energy"):
        lti.measured_response(np.zeros(100), np.zeros(100), 1000.0, [10.0, 20.0])
    with pytest.raises(FitError, match="freq_hz"):
        lti.bode(lti.mode_system(100.0, 0.1), [0.0, 1.0])


@settings(max_examples=30, deadline=None)
@given(wn=st.floats(1000.0, 20000.0), zeta=st.floats(0.0, 0.3), name=st.sampled_from(["zv", "zvd", "zvdd"]))
def test_a_shaper_cancels_its_design_mode_and_tolerates_less_further_from_it(wn, zeta, name):
    sh = S.design_shaper(name, wn, zeta)
    r = lti.shaper_sensitivity(sh, [0.7, 0.85, 1.0, 1.15, 1.3])
    assert r[2] < 1e-9
    assert r[1] > r[2] and r[3] > r[2] and r[0] > r[1] and r[4] > r[3]
    assert r[0] == pytest.approx(sh.residual(0.7 * wn, zeta), abs=1e-12)
    with pytest.raises(FitError, match="ratios"):
        lti.shaper_sensitivity(sh, [0.0, 1.0])
