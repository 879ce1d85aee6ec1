"""A delay counted in samples, told from the chain's bandwidth by steps of one size at two sample
rates (``input_delay``'s rate contrast): the slower run lags by as many more seconds as its
samples are longer, and a low-pass, a mode or a delay in seconds lags both alike."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from piezopress.analysis import diagnosis as dg
from piezopress.analysis.diagnosis.causes import input_delay as ID
from piezopress.analysis.diagnosis.judging import Context
from piezopress.analysis.hysteresis import PIModel
from piezopress.signals import noise_floor

MODEL = PIModel(r=(0.0, 4.0, 10.0, 20.0, 35.0), w=(1.6, 0.15, 0.12, 0.08, 0.05), d=(0.0,), s=(1.0,))
WN, ZETA = 5000.0, 0.08
NOISE_N = 0.05


def _step(name: str, fs: float, height: float, seed: int, at_s: float = 0.01) -> dg.RunData:
    """A step of ``height`` V at ``at_s``, back 100 ms later, 200 ms sampled at ``fs`` (no reading yet)."""
    t = np.arange(int(0.2 * fs)) / fs
    x = np.where((t >= at_s) & (t < at_s + 0.1), height, 0.0)
    return dg.RunData(name, "step", t, x, np.zeros_like(x), fs)


def _read(model: dg.Model, run: dg.RunData, seed: int) -> dg.RunData:
    """``run`` as ``model`` reads it, with white noise of :data:`NOISE_N`."""
    y = model.reading(run, model.force(run, model.static(run)))
    return replace(run, y=y + np.random.default_rng(seed).normal(0.0, NOISE_N, y.size))


def _press_runs(press: dg.Model) -> list[dg.RunData]:
    """Two steps of 50 V (20 and 50 kHz), and a 100 V step at 20 kHz that has no partner."""
    runs = [_step("step-50v", 20_000.0, 50.0, 1), _step("step-50v-50khz", 50_000.0, 50.0, 2)]
    runs.append(_step("step-100v", 20_000.0, 100.0, 3))
    return [_read(press, r, i) for i, r in enumerate(runs)]


def _context(runs: list[dg.RunData], model: dg.Model) -> Context:
    return Context(runs, model, frozenset(), {r.name: noise_floor(r.y) for r in runs})


#: the model as a bundle whose chain fit told 5.2 samples (a FIFO of 3 beside the sampling's own)
BASE = dg.Model(MODEL, wn=WN, zeta=ZETA, drive_lowpass=(2 * np.pi * 1200.0, 0.8), chain_samples=5.2)


def test_the_pairs_are_steps_of_one_size_at_two_rates():
    runs = _press_runs(BASE)
    pairs = ID.rate_pairs(_context(runs, BASE))
    assert [(a.name, b.name) for a, b in pairs] == [("step-50v", "step-50v-50khz")]


@pytest.mark.parametrize("fifo", [2.0, 3.0, 6.0])
def test_a_fifo_is_read_in_samples_and_named(fifo):
    """A FIFO of ``fifo`` samples hidden behind the model's chain: found within a third of a
    sample, accepted, and the extended model reads it in samples of each run's rate."""
    runs = _press_runs(replace(BASE, delay_samples=fifo))
    f = ID._delay_by_rate_contrast(_context(runs, BASE))
    assert f is not None and f.accepted, f
    assert f.parameters["delay_samples"] == pytest.approx(fifo, abs=0.33)
    assert f.gain_pct > 50.0
    assert f.model.reading_delay_s(50_000.0) == pytest.approx(f.parameters["delay_samples"] / 50_000.0)
    assert "step-50v and step-50v-50khz" in f.evidence


@pytest.mark.parametrize(
    "lag",
    [
        {"delay_s": 1.5e-4},  # a delay in seconds: both runs lag alike
        {"drive_lowpass": (2 * np.pi * 800.0, 0.6)},  # a slower chain: both runs lag alike
        {"wn": 0.8 * WN},  # a softer mode
        {"delay_samples": 0.4},  # a fraction of a sample: the converters' timing
    ],
)
def test_a_lag_in_seconds_or_under_a_sample_is_no_delay_counted_in_samples(lag):
    runs = _press_runs(replace(BASE, **lag))
    f = ID._delay_by_rate_contrast(_context(runs, BASE))
    assert f is None or not f.accepted, f


def test_without_a_pair_nothing_is_read():
    press = replace(BASE, delay_samples=4.0)
    runs = [r for r in _press_runs(press) if r.name != "step-50v-50khz"]
    assert ID._delay_by_rate_contrast(_context(runs, BASE)) is None


def test_the_whole_cause_names_the_fifo_where_the_fast_runs_shape_could_not():
    """Through ``diagnose``: the cause returns the rate contrast's finding (the fast runs' own
    judgement has the same freedom of the chain's low-pass in its baseline)."""
    press = replace(BASE, delay_samples=3.0)
    runs = _press_runs(press)
    result = dg.diagnose(BASE, runs, causes=["input_delay"])
    assert [f.cause for f in result.findings] == ["input_delay"], result.summary
    assert result.findings[0].parameters["delay_samples"] == pytest.approx(3.0, abs=0.33)


@pytest.mark.parametrize("told, named", [(0.0, False), (2.2, False), (5.2, True)])
def test_the_contrast_is_checked_against_the_samples_the_chain_was_identified_with(told, named):
    """A contrast is named only where ``fit`` identified the chain's delay in samples from steps at
    two rates and that delay is a sample or more beyond the sampling's own (two samples): else (a
    chain told in no samples, 0: a slew's, or none identified) the contrast is an unmodelled
    edge's, not a FIFO's."""
    runs = _press_runs(replace(BASE, delay_samples=3.0))
    f = ID._delay_by_rate_contrast(_context(runs, replace(BASE, chain_samples=told)))
    assert (f is not None and f.accepted) == named, f


def test_steps_at_other_times_read_as_steps_at_one_time():
    """The faster run's step 23.3 ms later than the slower one's (another program's timing): each
    residual is read on the time since its own edge, so the contrast reads what it reads of steps
    at one time. The press also lags 0.1 ms in seconds beyond the model, in both runs; the FIFO
    shifts that lag's residual too, so both read a part of a sample over the 3 (read at one time
    for both runs, the later step was compared with nothing: the slower run's residual alone,
    5 samples)."""
    press = replace(BASE, delay_samples=3.0, delay_s=1e-4)
    found = []
    for at in (0.01, 0.0333):
        runs = [_step("a-50v", 20_000.0, 50.0, 1), _step("b-50v-50khz", 50_000.0, 50.0, 2, at_s=at)]
        f = ID._delay_by_rate_contrast(_context([_read(press, r, i) for i, r in enumerate(runs)], BASE))
        assert f is not None and f.accepted, f
        found.append(f.parameters["delay_samples"])
    assert found[1] == pytest.approx(found[0], abs=0.05)
    assert 3.0 <= found[0] <= 3.6


@pytest.mark.parametrize("samples, named", [(0.8, False), (1.5, True), (3.0, True)])
def test_a_delay_in_samples_on_the_fast_runs_is_whole_samples_or_none(samples, named):
    """The fast runs' own judgement of a delay counted in samples: a fraction of a sample beyond the
    model's is refused whatever it gains (third test press, a coupling of the drive voltage, seed 4:
    0.66 samples gained 22 % once the coupling was in the model, the converters' timing), a sample or
    more is named; the refusal says why."""
    runs = _press_runs(replace(BASE, delay_samples=samples))
    ctx = _context(runs, BASE)
    fit, held = dg.judging._fast_split(ctx)
    f = ID._judge_samples(ctx, fit, held, replace(BASE, delay_samples=samples), samples, BASE, [20_000.0, 50_000.0])
    assert f is not None and f.gain_pct > 50.0, f  # it fits: what is judged is its size, not its gain
    assert f.accepted == named, f
    assert ("whole samples" in f.refused) == (not named), f.refused
