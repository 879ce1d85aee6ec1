"""Creep model, fits and compensation (thesis Section 3.1.2, Eqs. 3.37-3.39; Section 6.3, Eq. 6.1).

Synthetic records come from ``CreepModel.response`` itself (exact for a held input), so a fit
is judged against known parameters. The load cell is modelled as 0.06 N of Gaussian noise
followed by a 0.49 N quantizer (the rig's 12-bit ADC over +/-10 V at 10.003 mV/N), seeded.
Every tolerance states its reason.
"""

import json
import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from piezopress.analysis.creep import CreepModel, fit_creep, fit_log, fit_poles, log_taus
from piezopress.errors import CompensatorUnstableError, FitError, PiezopressError

Q_N = 0.49  # load-cell quantization step
NOISE_N = 0.06  # load-cell noise std
STEP_N = 300.0  # the thesis's creep test: a 300 N step held 120 s (Section 6.3.1)
HOLD_S = 120.0

THESIS = {"K": 0.0246, "T_z_s": 29.074, "T1_s": 46.223, "T2_s": 1.5618, "T3_s": 0.001}  # Eq. 6.1
LOG_CREEP = CreepModel.log(1.0, 0.011, 0.05, 1e4)  # like the virtual rig: 12 taus, 0.05 s .. 1e4 s
SATURATING = CreepModel("poles", 1.0, (1.5, 40.0), (0.012, 0.012))  # the rig's "poles" creep


def step_record(fs_hz, hold_s=HOLD_S, step_at_s=1.0):
    """Time and a 300 N step after ``step_at_s`` of rest (the hysteresis model's prediction)."""
    t = np.arange(0.0, step_at_s + hold_s, 1.0 / fs_hz)
    return t, np.where(t >= step_at_s, STEP_N, 0.0)


def load_cell(y, rng, quantize=True):
    y = y + rng.normal(0.0, NOISE_N, y.size)
    return np.round(y / Q_N) * Q_N if quantize else y


def creep_percent(t, f, step_at_s=1.0, after_s=1.0, window_s=1.0):
    """Creep after the step (Eq. 5.2 relative to the step): mean over the last ``window_s``
    against the mean over ``window_s`` centred ``after_s`` after the step."""
    ss = np.abs(t - (step_at_s + after_s)) <= window_s / 2
    end = t >= t[-1] - window_s
    return 100.0 * (f[end].mean() - f[ss].mean()) / STEP_N


# ---------------------------------------------------------------------------------------
# The model
# ---------------------------------------------------------------------------------------


def test_thesis_partial_fractions_match_eq_6_1():
    m = CreepModel.thesis()
    s = 1j * np.logspace(-4, 4, 81)
    eq61 = 1.0 + 0.0246 * (1 + 29.074 * s) / ((1 + 46.223 * s) * (1 + 1.5618 * s) * (1 + 0.001 * s))
    ours = m.static_gain + sum(g / (1 + tau * s) for tau, g in zip(m.taus_s, m.gains))
    # partial fractions are an exact rewriting: only rounding differs
    np.testing.assert_allclose(ours, eq61, rtol=1e-12)
    assert m.params == THESIS
    assert m.dc_gain == pytest.approx(1.0246, rel=1e-12)


def test_response_to_a_held_step_is_the_continuous_step_response():
    # u[n] is held over the period ending at sample n: a step on from n = 0 has been on for
    # (n + 1) samples at sample n, so y[n] is the continuous step response at (n + 1) / fs
    m, fs = CreepModel.thesis(), 50.0
    y, _ = m.response(np.ones(3000), fs)
    t = np.arange(1, 3001) / fs
    exact = m.static_gain + sum(g * (1 - np.exp(-t / tau)) for tau, g in zip(m.taus_s, m.gains))
    np.testing.assert_allclose(y, exact, rtol=1e-12, atol=1e-14)  # exact discretisation: rounding only


def test_log_form_creeps_per_decade():
    fs = 10.0
    y, _ = LOG_CREEP.response(np.ones(int(1000 * fs)), fs)
    at = lambda t_s: y[int(t_s * fs) - 1]  # noqa: E731
    # 12 taus over 5.3 decades are 0.48 decade apart, so each decade gets 0.5/0.48 of the
    # per-decade gain (+3.7 %); the Prony series ripples by less than 1 % on top
    for t1 in (1.0, 10.0, 100.0):
        assert at(10 * t1) - at(t1) == pytest.approx(0.011, rel=0.05)


def test_rest_state_is_a_fixed_point():
    m = CreepModel.thesis()
    y, state = m.response(np.full(500, 7.0), 100.0, m.rest_state(7.0))
    np.testing.assert_allclose(y, 7.0 * m.dc_gain, rtol=1e-13)  # settled: nothing moves
    np.testing.assert_allclose(state, m.rest_state(7.0), rtol=1e-13)


def test_to_dict_is_json_and_round_trips():
    for m in (CreepModel.thesis(), LOG_CREEP, SATURATING):
        d = json.loads(json.dumps(m.to_dict()))
        assert set(d) == {"form", "static_gain", "taus_s", "gains", "params"}
        back = CreepModel.from_dict(d)
        assert back == m and back.params == m.params


@pytest.mark.parametrize(
    "doc, fragment",
    [
        ({"form": "poles", "static_gain": 1.0, "taus_s": [1.0], "gains": [0.1], "tau_s": 3}, "unknown key(s) tau_s"),
        ({"form": "poles", "static_gain": 1.0, "taus_s": [1.0]}, "missing key(s) gains"),
        ({"form": "linear", "static_gain": 1.0, "taus_s": [1.0], "gains": [0.1]}, "form is 'linear'"),
        (
            {"form": "poles", "static_gain": 1.0, "taus_s": [1.0, 2.0], "gains": [0.1]},
            "2 time constant(s) but 1 gain(s)",
        ),
        ({"form": "poles", "static_gain": 1.0, "taus_s": [-1.0], "gains": [0.1]}, "taus_s[0] is -1.0"),
        ({"form": "poles", "static_gain": float("nan"), "taus_s": [1.0], "gains": [0.1]}, "static_gain (K_c) is nan"),
    ],
)
def test_invalid_models_are_refused_naming_the_value(doc, fragment):
    with pytest.raises(FitError) as err:
        CreepModel.from_dict(doc)
    assert fragment in str(err.value)


def test_repeated_pole_is_refused():
    with pytest.raises(FitError, match="T1_s = T2_s = 5.0"):
        CreepModel.poles(1.0, 0.02, 3.0, 5.0, 5.0, 0.1)


# ---------------------------------------------------------------------------------------
# Compensation (Fig. 3.9, Eq. 3.38): exact inverse, chunked == one pass
# ---------------------------------------------------------------------------------------

fs_values = st.floats(3.0, 30_000.0)
signals = st.lists(st.floats(-1000.0, 1000.0), min_size=1, max_size=1000).map(np.array)


@st.composite
def creep_models(draw):
    """K_c > 0 and up to six terms anywhere from 1 ms to 1e4 s, gains of either sign."""
    n = draw(st.integers(0, 6))
    taus = [10 ** draw(st.floats(-3.0, 4.0)) for _ in range(n)]
    gains = [draw(st.floats(-0.4, 0.6)) for _ in range(n)]
    return CreepModel("poles", draw(st.floats(0.2, 5.0)), tuple(taus), tuple(gains))


def stable(m, fs):
    try:
        m.check_stable(fs)
    except CompensatorUnstableError:
        return False
    return True


def chunks(x, cuts):
    edges = sorted({0, x.size, *(c % (x.size + 1) for c in cuts)})
    return [x[a:b] for a, b in zip(edges[:-1], edges[1:])]


@settings(max_examples=200, deadline=None)
@given(creep_models(), fs_values, signals)
def test_compensate_inverts_response(m, fs, f_c):
    assume(stable(m, fs))
    f_h, s1 = m.compensate(f_c, fs)
    y, s2 = m.response(f_h, fs)
    scale = max(1.0, float(np.max(np.abs(f_c))))
    # both are exact recursions; only rounding (modal transform, partial sums) differs: the
    # outputs agree to 1e-9; the internal states go through the eigenvector matrix, whose
    # conditioning (near-cancelling terms at a low rate) costs up to a decade more
    np.testing.assert_allclose(y, f_c, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(s1, s2, rtol=0, atol=1e-8 * scale)


@settings(max_examples=150, deadline=None)
@given(creep_models(), fs_values, signals, st.lists(st.integers(0, 400), max_size=4))
def test_chunks_with_state_equal_one_pass(m, fs, x, cuts):
    assume(stable(m, fs))
    scale = max(1.0, float(np.max(np.abs(x))))
    for run in (m.response, m.compensate):
        whole, s_whole = run(x, fs)
        parts, state = [], None
        for part in chunks(x, cuts):
            out, state = run(part, fs, state)
            parts.append(out)
        # the state carries everything; rounding differs at the borders only
        np.testing.assert_allclose(np.concatenate(parts), whole, rtol=0, atol=1e-9 * scale)
        np.testing.assert_allclose(state, s_whole, rtol=0, atol=1e-9 * scale)


def test_sample_by_sample_fallback_equals_the_modal_compensator():
    # the fallback runs only when the closed loop is nearly defective; check it on a normal one
    from piezopress.analysis.creep import _compensate_loop, _inverse

    m, fs = CreepModel.thesis(), 100.0
    f_c = np.random.default_rng(0).normal(300.0, 50.0, 2000)
    x0 = m.rest_state(120.0)
    loop, s_loop = _compensate_loop(f_c, _inverse(m.taus_s, m.gains, m.static_gain, fs), x0)
    modal, s_modal = m.compensate(f_c, fs, x0)
    np.testing.assert_allclose(loop, modal, rtol=1e-12)  # the same recursion: rounding only
    np.testing.assert_allclose(s_loop, s_modal, rtol=1e-12)


def test_thesis_model_round_trip_compensates_its_own_creep():
    m, fs = CreepModel.thesis(), 1000.0
    m.check_stable(fs)
    t, ref = step_record(fs)
    f_h, _ = m.compensate(ref, fs)
    f, _ = m.response(f_h, fs)
    np.testing.assert_allclose(f, ref, rtol=0, atol=1e-9 * STEP_N)  # Eq. 3.39: F / F_c = 1
    assert creep_percent(t, m.response(ref, fs)[0]) > 1.0  # uncompensated it creeps (1.6 %)
    # the drive starts at the step (K_c = 1; the creep has had one sample) and falls as the
    # creep rises, to about 300 / 1.024 after 120 s
    step = int(1.0 * fs)
    assert f_h[step] == pytest.approx(STEP_N, rel=1e-4)
    assert np.all(np.diff(f_h[step + 1 :]) < 0)
    assert f_h[-1] == pytest.approx(STEP_N / 1.024, rel=1e-3)


@pytest.mark.parametrize("k_c", [0.0, -0.5])
def test_instability_check_names_K_c(k_c):
    m = CreepModel.log(k_c, 0.011)
    with pytest.raises(CompensatorUnstableError) as err:
        m.check_stable(200.0)
    msg = str(err.value)
    assert f"K_c = {k_c:g} <= 0" in msg and "|z|" in msg and "fs_hz=200" in msg and "\n" not in msg
    assert isinstance(err.value, ValueError) and isinstance(err.value, PiezopressError)
    with pytest.raises(CompensatorUnstableError):
        m.compensate(np.ones(10), 200.0)


def test_non_minimum_phase_model_is_refused_with_its_eigenvalue():
    # 1 - 2 / (1 + 10 s) = (10 s - 1) / (10 s + 1): a right-half-plane zero. Discretised the
    # inverse has its pole at z = a / (2a - 1) > 1 with a = exp(-1 / (fs tau))
    m, fs = CreepModel("poles", 1.0, (10.0,), (-2.0,)), 200.0
    a = math.exp(-1.0 / (fs * 10.0))
    np.testing.assert_allclose(m.closed_loop_poles(fs), [a / (2 * a - 1)], rtol=1e-12)
    with pytest.raises(CompensatorUnstableError, match=r"largest closed-loop \|z\| = 1\.0005"):
        m.compensate(np.ones(10), fs)


# ---------------------------------------------------------------------------------------
# Fits recover known parameters
# ---------------------------------------------------------------------------------------


def test_fit_log_is_exact_without_noise():
    t, u = step_record(100.0)
    y, _ = LOG_CREEP.response(u, 100.0)
    m = fit_log(t, u, y)
    # linear least squares on the true basis (tau_min defaults to 0.05 s at 100 Hz)
    assert m.params["tau_min_s"] == 0.05 and m.taus_s == LOG_CREEP.taus_s
    assert m.static_gain == pytest.approx(1.0, rel=1e-9)
    assert m.params["per_decade"] == pytest.approx(0.011, rel=1e-9)


def test_fit_poles_recovers_the_thesis_model_without_noise():
    t, u = step_record(100.0)
    y, _ = CreepModel.thesis().response(u, 100.0)
    m = fit_poles(t, u, y)
    p = m.params
    # noise-free: limited only by the optimiser's tolerances (1e-10 on the cost)
    assert m.static_gain == pytest.approx(1.0, rel=1e-6)
    for key in ("K", "T_z_s", "T1_s", "T2_s"):
        assert p[key] == pytest.approx(THESIS[key], rel=1e-4), key
    # T3 = 1 ms is a tenth of a sample at 100 Hz: its term acts as a direct gain there, so
    # it is not asserted beyond sitting at or near the lower bound
    assert p["T3_s"] <= 2e-3
    np.testing.assert_allclose(m.response(u, 100.0)[0], y, rtol=0, atol=1e-6)


@pytest.mark.parametrize("fs", [100.0, 1000.0])
def test_fit_log_with_load_cell_noise(fs):
    t, u = step_record(fs)
    y0, _ = LOG_CREEP.response(u, fs)
    m = fit_log(t, u, load_cell(y0, np.random.default_rng(1)))
    # 7 N of creep is 15 quantization steps: the staircase error (+/-0.25 N, hardly
    # dithered by 0.06 N of noise) biases the slope by well under 1 % (seen: 0.1 %)
    assert m.params["per_decade"] == pytest.approx(0.011, rel=0.01)
    assert m.static_gain == pytest.approx(1.0, abs=5e-4)


@pytest.mark.parametrize("fs", [100.0, 1000.0])
def test_fit_poles_with_load_cell_noise(fs):
    truth = CreepModel.thesis()
    t, u = step_record(fs)
    y0, _ = truth.response(u, fs)
    m = fit_poles(t, u, load_cell(y0, np.random.default_rng(2)))
    p = m.params
    # The quantizer's staircase over 15 steps of creep is a slow, correlated error, so the
    # slow pole and the zero trade off against each other (seen: T1 53 s, T_z 33 s for
    # 46 s and 29 s); the creep they describe together stays within a fifth of a
    # quantization step of the truth (seen: 0.07 N), and K within 3 % (seen: 1.6 %).
    assert p["K"] == pytest.approx(THESIS["K"], rel=0.03)
    assert p["T2_s"] == pytest.approx(THESIS["T2_s"], rel=0.10)
    assert p["T1_s"] == pytest.approx(THESIS["T1_s"], rel=0.25)
    assert p["T_z_s"] == pytest.approx(THESIS["T_z_s"], rel=0.25)
    assert np.max(np.abs(m.response(u, fs)[0] - y0)) < Q_N / 5


# ---------------------------------------------------------------------------------------
# fit_creep: choose the form that predicts the held-out end of the record
# ---------------------------------------------------------------------------------------


def test_fit_creep_picks_log_for_log_creep():
    fs = 100.0
    t, u = step_record(fs)
    y = load_cell(LOG_CREEP.response(u, fs)[0], np.random.default_rng(3))
    fit = fit_creep(t, u, y)
    c = {x.form: x for x in fit.candidates}
    assert fit.form == "log" == fit.model.form
    # three saturating poles fitted on 85 s extrapolate badly (seen: 0.31 N against 0.15 N)
    assert c["log"].holdout_rms < c["poles"].holdout_rms
    assert f"{c['log'].holdout_rms:.4g}" in fit.reason and f"{c['poles'].holdout_rms:.4g}" in fit.reason
    assert fit.reason.startswith("log:") and "\n" not in fit.reason
    assert fit.model.params["per_decade"] == pytest.approx(0.011, rel=0.01)  # as test_fit_log_with_load_cell_noise
    assert fit.split_s == pytest.approx(0.7 * (HOLD_S + 1.0), abs=1.0 / fs)


def test_fit_creep_picks_poles_for_saturating_creep():
    # Gaussian noise only. With the 0.49 N quantizer as well, this creep (7 N, 15 steps)
    # is ambiguous: the quantizer's staircase bends the extrapolation of a 5-parameter
    # saturating fit (0.07 N from the truth on the held-out part) more than the log form's
    # structural error (0.035 N), so the held-out criterion rightly prefers log there.
    fs = 100.0
    t, u = step_record(fs)
    y = load_cell(SATURATING.response(u, fs)[0], np.random.default_rng(4), quantize=False)
    fit = fit_creep(t, u, y)
    c = {x.form: x for x in fit.candidates}
    assert fit.form == "poles" == fit.model.form
    assert c["poles"].holdout_rms < c["log"].holdout_rms  # log cannot saturate (seen: 0.060 N against 0.072 N)
    assert fit.reason.startswith("poles:")
    assert fit.model.dc_gain == pytest.approx(1.024, abs=1e-3)  # saturates at the true 2.4 %


def test_compensating_log_creep_with_the_fitted_model():
    fs = 100.0
    t, u = step_record(fs)
    y = load_cell(LOG_CREEP.response(u, fs)[0], np.random.default_rng(5))
    model = fit_creep(t, u, y).model
    f_h, _ = model.compensate(u, fs)  # reference: the same 300 N step
    f, _ = LOG_CREEP.response(f_h, fs)  # the plant: the true creep
    assert creep_percent(t, LOG_CREEP.response(u, fs)[0]) == pytest.approx(2.3, abs=0.1)  # uncompensated
    # per_decade is fitted within 1 % (0.0001 per decade, 2 decades): < 0.1 % of the step
    assert abs(creep_percent(t, f)) < 0.1


# ---------------------------------------------------------------------------------------
# Input validation
# ---------------------------------------------------------------------------------------


def good_record(n=500):
    t, u = step_record(10.0, hold_s=n / 10.0 - 1.0)
    return t, u, LOG_CREEP.response(u, 10.0)[0]


@pytest.mark.parametrize(
    "mutate, fragment",
    [
        (lambda t, u, y: (t, u, y[:-1]), "t_s has 500 samples, u 500 and y 499; expected equal lengths"),
        (lambda t, u, y: (t[:20], u[:20], y[:20]), "t_s has 20 sample(s); expected at least 50"),
        (lambda t, u, y: (t, np.full(t.size, 300.0), y), "u has no step"),
        (
            lambda t, u, y: (t, u, np.concatenate([y[:31], np.full(469, np.nan)])),
            "y has 469 NaN/infinite value(s), first at index 31",
        ),
        (lambda t, u, y: (t**1.01, u, y), "t_s is not uniform"),
        (lambda t, u, y: (t[::-1], u, y), "t_s is not strictly increasing at index 1"),
    ],
)
@pytest.mark.parametrize("fit", [fit_log, fit_poles, fit_creep])
def test_unsuitable_records_are_refused_in_one_line(fit, mutate, fragment):
    with pytest.raises(FitError) as err:
        fit(*mutate(*good_record()))
    msg = str(err.value)
    assert msg.startswith(f"{fit.__name__}: ") and fragment in msg and "\n" not in msg


@pytest.mark.parametrize("h", [0.0, 1.0, 0.95, float("nan")])
def test_fit_creep_refuses_a_bad_holdout_fraction(h):
    with pytest.raises(FitError, match="holdout_fraction"):
        fit_creep(*good_record(), holdout_fraction=h)


def test_log_taus_is_the_rig_grid():
    taus = log_taus(0.05, 1e4)
    assert taus.size == 12 and taus[0] == pytest.approx(0.05) and taus[-1] == pytest.approx(1e4)
    assert np.all(np.diff(np.log10(taus)) <= 0.5)


# ---------------------------------------------------------------------------------------
# End to end on the virtual rig
# ---------------------------------------------------------------------------------------


def test_virtual_rig_creep_is_logarithmic_and_compensated():
    # imports from acquisition are fine in a test (the analysis package itself never does)
    from piezopress.acquisition import rig_physics
    from piezopress.acquisition.rig_config import RigConfig
    from piezopress.acquisition.virtual_rig import VirtualRig

    fs, preload_n = 200.0, 50.0
    v = np.concatenate([np.zeros(int(fs)), np.full(int(HOLD_S * fs), 150.0)])  # 150 V after 1 s
    t = np.arange(v.size) / fs
    cfg = RigConfig()
    measured = VirtualRig(cfg).run(v, fs, preload_n=preload_n, label="c").channels["force_n"]
    # the same run (same label: same noise) without creep stands in for the hysteresis
    # model's prediction of the force
    no_creep = (
        VirtualRig(cfg.replace(creep={"enabled": False})).run(v, fs, preload_n=preload_n, label="c").channels["force_n"]
    )
    u, y = no_creep - preload_n, measured - preload_n

    fit = fit_creep(t, u, y)
    assert fit.form == "log", fit.reason
    # the rig's own grid (0.05 s .. 1e4 s, 12 taus) and per_decade 0.0112: both noisy
    # records are quantized to 0.49 N, so 2 % (seen: 0.2 %)
    assert fit.model.params["per_decade"] == pytest.approx(cfg.creep.per_decade, rel=0.02)
    assert fit.model.static_gain == pytest.approx(1.0, abs=1e-3)

    # compensate a 300 N step reference and run it through the rig's creep
    ref = np.where(t >= 1.0, STEP_N, 0.0)
    f_h, _ = fit.model.compensate(ref, fs)
    before = creep_percent(t, rig_physics.creep(ref, cfg.creep, fs))
    after = creep_percent(t, rig_physics.creep(f_h, cfg.creep, fs))
    assert before > 2.0  # the rig creeps like the thesis's press (2.4 %)
    assert abs(after) < 0.1  # seen: 0.005 %


@pytest.mark.parametrize(
    "model",
    [
        CreepModel.thesis(),
        CreepModel.log(0.98, 0.01),
        CreepModel("spectrum", 0.99, tuple(np.geomspace(0.04, 1000.0, 14)), tuple(np.linspace(0.0, 0.003, 14))),
    ],
    ids=["poles", "log", "spectrum"],
)
def test_the_step_creep_in_closed_form_is_the_simulated_step_less_its_instantaneous_part(model):
    for n, fs in ((100, 10.0), (60_001, 500.0)):  # the second through the FFT path of output()
        simulated = model.output(np.ones(n), fs) - model.static_gain
        np.testing.assert_allclose(model.step_creep(n, fs), simulated, rtol=0, atol=1e-12)
