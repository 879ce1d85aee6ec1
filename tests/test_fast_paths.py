"""The diagnosis's and the fit's fast paths (issue 23: a cheaper press) give the results of the
plain computation they replace: a run simulated only as far as it is judged equals the whole
run's simulation cut there, for every causal stage of the model; memoised plays equal plays
computed afresh; the dead-zone sum through its corners equals the operator sum; creep through
one FFT convolution equals the terms one by one; and a quadratic program compiled once and
solved with new data equals one built for that data alone."""

from __future__ import annotations

import dataclasses
import threading

import numpy as np
import pytest

from piezopress import operators
from piezopress.analysis import creep as C
from piezopress.analysis import diagnosis as dg
from piezopress.analysis import hysteresis as H
from piezopress.analysis.diagnosis import judging as J

FS = 10_000.0


def _run(n: int = 6000, seed: int = 0, monitor: bool = True) -> dg.RunData:
    """A drive with triangles, a step and noise (reversals of every size), and a reading of it."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FS
    x = 60.0 + 50.0 * np.abs(((t * 17.0) % 2.0) - 1.0) + np.where(t > 0.3, 25.0, 0.0) + rng.normal(0, 0.3, n)
    y = 2.0 * x + rng.normal(0, 0.1, n)
    return dg.RunData("r", "custom", t, x, y, FS, monitor=x + 0.01 if monitor else None, key=f"run-{seed}")


def _full_model() -> dg.Model:
    """Every causal extension at once: slew, lag, a rate dependence, creep of many terms, two
    modes, the sensor's filter, interference, a delay, drift and hum."""
    pi = H.PIModel((0.0, 5.0, 15.0), (1.0, 0.4, 0.2), (-20.0, 0.0, 30.0), (0.8, 1.0, 0.6), x0=10.0, y0=40.0)
    return dg.Model(
        pi,
        creep=C.CreepModel.log(0.95, 0.011),
        wn=2 * np.pi * 900.0,
        zeta=0.08,
        sensor_lowpass_hz=3000.0,
        slew_v_per_s=4e4,
        drive_tau_s=3e-5,
        rate_loss_per_kv_s=0.02,
        rate_saturation_v_per_s=8e3,
        rate_tau_s=2e-3,
        interference=(1e-4, 50.0, 5e-4, 2e-5),
        mode2=(0.2, 2 * np.pi * 2500.0, 0.05),
        delay_s=2.5e-4,
        drift_per_s=0.3,
        drift_warmup=(0.5, 2.0),
        hum=(("run-0", 50.0, 0.2, -0.1),),
    )


@pytest.mark.parametrize("stop", [1, 700, 2999, 5999])
@pytest.mark.parametrize("widen", [False, True])
def test_a_run_simulated_as_far_as_it_is_judged_equals_the_whole_runs_simulation_cut_there(stop, widen):
    run = _run()
    model = _full_model()
    if widen:  # the rate dependence as thresholds widened with the rate (plays computed afresh)
        model = dataclasses.replace(model, rate_v_per_kv_s=0.5, rate_loss_per_kv_s=0.0)
    assert model.causal
    whole = model.predict(run)
    part = model.predict_until(run, stop)
    assert part.shape == (stop,)
    # the same operations on the same samples: equal to rounding of the FFT's creep (1e-12 of the range)
    np.testing.assert_allclose(part, whole[:stop], rtol=0, atol=1e-12 * np.ptp(whole))
    assert run.prefix(stop) is run.prefix(stop)  # one object per cut: its predictions are memoised


def test_a_drifting_gain_is_judged_over_the_whole_run_so_it_is_never_cut():
    run = _run()
    model = dataclasses.replace(_full_model(), gain_drift=(1e-4, 0.0, (("run-0", 30.0, False),)))
    assert not model.causal  # its gain depends on the run's length
    np.testing.assert_array_equal(model.predict_until(run, 2000), model.predict(run)[:2000])


def test_the_cost_of_segments_equals_the_cost_of_the_whole_runs_on_the_same_rows():
    runs = [_run(seed=0), _run(n=4000, seed=1, monitor=False)]
    model = _full_model()
    segments = [(runs[0], slice(0, 3600)), (runs[1], slice(None)), (runs[0], slice(4000, None))]
    plain = np.concatenate([(r.y - model.predict(r))[sl] for r, sl in segments])
    np.testing.assert_allclose(J._model_err(segments, model), plain, rtol=0, atol=1e-10)
    mask = np.zeros(6000, bool)
    mask[::7] = True  # a mask of rows (the slow sweeps' held-out rows): the whole run, then the mask
    np.testing.assert_allclose(
        J._cost([(runs[0], mask)], model), np.sqrt(np.mean((runs[0].y - model.predict(runs[0]))[mask] ** 2))
    )


@pytest.mark.parametrize("form", ["loss", "widen", "none"])
def test_memoised_plays_equal_plays_computed_afresh(form):
    run = _run()
    extra = {"loss": {"rate_loss_per_kv_s": 0.03}, "widen": {"rate_v_per_kv_s": 0.4}, "none": {}}[form]
    model = dataclasses.replace(_full_model(), **{"rate_loss_per_kv_s": 0.0, **extra})
    for k in (1.0, 1.5, 1.0):  # the same run again and again, the form's size changed in between
        m = dataclasses.replace(model, **{key: v * k for key, v in extra.items()})
        memo = m.static(run)
        fresh = m.static(run, run.x)  # the drive given: nothing memoised
        np.testing.assert_allclose(memo, fresh, rtol=0, atol=1e-12)
        assert not memo.flags.writeable  # a memoised array cannot be changed by a caller


def test_the_dead_zone_sum_through_its_corners_equals_the_operator_sum():
    rng = np.random.default_rng(3)
    for _ in range(200):
        n_neg, n_pos = rng.integers(0, 6), rng.integers(0, 6)
        d = np.concatenate([np.sort(-rng.uniform(0.1, 5, n_neg)), [0.0], np.sort(rng.uniform(0.1, 5, n_pos))])
        s = rng.uniform(-0.5, 2.0, d.size)
        p = np.concatenate([rng.uniform(-9, 9, 500), d, [d[0] - 100.0, d[-1] + 100.0]])
        np.testing.assert_allclose(
            H.dead_zone_superposition(p, d, s), operators.dead_zone(p, d) @ s, rtol=1e-12, atol=1e-12
        )
    # thresholds out of order, an empty input and gaps keep the operator sum's meaning
    d, s = np.array([2.0, 0.0, -1.0]), np.array([0.5, 1.0, 0.7])
    p = np.array([-3.0, 0.5, 4.0, np.nan])
    np.testing.assert_array_equal(H.dead_zone_superposition(p, d, s), operators.dead_zone(p, d) @ s)
    np.testing.assert_array_equal(
        H.dead_zone_superposition(p, d[::-1], s[::-1])[:3], (operators.dead_zone(p, d) @ s)[:3]
    )
    assert H.dead_zone_superposition(np.zeros(0), d[::-1], s[::-1]).shape == (0,)


@pytest.mark.parametrize("n", [10, C.FFT_MIN_SAMPLES - 1, C.FFT_MIN_SAMPLES, 50_000])
def test_creep_through_one_convolution_equals_the_terms_one_by_one(n):
    rng = np.random.default_rng(n)
    u = np.cumsum(rng.normal(size=n)) + 5.0
    for model in (C.CreepModel.log(0.95, 0.011), C.CreepModel.thesis()):
        by_terms = model.response(u, FS)[0]
        np.testing.assert_allclose(model.output(u, FS), by_terms, rtol=0, atol=1e-12 * np.max(np.abs(by_terms)))
    assert len(C.CreepModel.log(0.95, 0.011).taus_s) >= C.FFT_MIN_TERMS  # the long case above took the FFT


def _fit_data(seed: int) -> H.HysteresisData:
    rng = np.random.default_rng(seed)
    t = np.arange(4000) / 100.0
    x = 50.0 + 45.0 * np.abs(((t * 0.1 * (1 + 0.1 * seed)) % 2.0) - 1.0)
    true = H.PIModel((0.0, 6.0, 18.0), (0.8, 0.3, 0.2), (-10.0, 0.0, 25.0), (0.9, 1.1, 0.7), x0=0.0, y0=5.0)
    y = true.forward(x)[0] + rng.normal(0, 0.05, x.size)
    return H.prepare([("sweep", x, y)], holdout_fraction=0.3, x0=0.0, y0=5.0)


def _fit(data: H.HysteresisData) -> H.PIModel:
    r = H.play_thresholds(6, 1.5, data.u_span)
    d_inv = H.dead_zone_thresholds(2, *data.z_range)
    return H.fit_structure(data, r, d_inv, H.columns_for(data, r, None))


def test_a_program_compiled_once_solves_new_data_as_one_built_for_it():
    a, b = _fit_data(0), _fit_data(1)
    H._PROGRAMS.__dict__.clear()  # this thread's programs: none yet
    first = _fit(a)
    assert H._PROGRAMS.by_shape  # compiled and kept
    other = _fit(b)  # the same shape, other data
    again = _fit(a)
    assert other.w != first.w  # the parameters took the new data
    # the same data, the same result: a fit never depends on what the process fitted before it
    assert (again.r, again.w, again.d, again.s, again.y0) == (first.r, first.w, first.d, first.s, first.y0)
    # a fit in another thread compiles its own programs (a program's parameters are its state)
    out = {}
    worker = threading.Thread(target=lambda: out.setdefault("m", _fit(b)))
    worker.start()
    worker.join()
    assert out["m"] == other
