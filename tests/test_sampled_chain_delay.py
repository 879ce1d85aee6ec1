"""The drive chain's delay counted in samples, where the steps (all at one sample rate) could not
tell it from one in seconds: the fast causes' baseline fits it on the runs sampled faster than the
steps (``judging._with_sampled_chain_delay``), up to the sampling's own two samples, and leaves
the model as it is where steps at two rates told it or nothing is sampled faster."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from piezopress.analysis import diagnosis as dg
from piezopress.analysis.diagnosis.judging import Context, _cost, _fast_base, _with_sampled_chain_delay
from piezopress.analysis.hysteresis import PIModel
from piezopress.signals import noise_floor

MODEL = PIModel(r=(0.0, 4.0, 10.0, 20.0, 35.0), w=(1.6, 0.15, 0.12, 0.08, 0.05), d=(0.0,), s=(1.0,))
STEPS_HZ = 20_000.0
ONE_RATE = {STEPS_HZ}  # every step's sample rate
NOISE_N = 0.05
#: the model as a bundle holds a series chain identified on steps at one rate: its whole delay in
#: seconds at the steps' rate (two samples of 20 kHz)
BASE = dg.Model(MODEL, wn=5000.0, zeta=0.08, drive_lowpass=(2 * np.pi * 1500.0, 0.8), drive_delay_s=2.0 / STEPS_HZ)


def _step(name: str, fs: float, height: float) -> dg.RunData:
    t = np.arange(int(0.2 * fs)) / fs
    x = np.where((t >= 0.01) & (t < 0.11), height, 0.0)
    return dg.RunData(name, "step", t, x, np.zeros_like(x), fs)


def _triangle(name: str, fs: float, freq: float) -> dg.RunData:
    t = np.arange(int(3.0 / freq * fs)) / fs
    x = 120.0 * (1.0 - np.abs((t * freq) % 1.0 * 2.0 - 1.0))
    return dg.RunData(name, "triangle", t, x, np.zeros_like(x), fs)


def _runs(press: dg.Model) -> list[dg.RunData]:
    """Steps at 20 kHz; triangles at 10 kHz (slower than the steps), 20 kHz and 50 kHz (faster), as
    ``press`` reads them, with white noise."""
    runs = [
        _step("step-150v", STEPS_HZ, 150.0),
        _step("step-50v", STEPS_HZ, 50.0),
        _triangle("triangle-5hz", 10_000.0, 5.0),
        _triangle("triangle-10hz", STEPS_HZ, 10.0),
        _triangle("triangle-50hz", 50_000.0, 50.0),
        _triangle("triangle-100hz", 50_000.0, 100.0),
    ]
    out = []
    for i, r in enumerate(runs):
        y = press.reading(r, press.force(r, press.static(r)))
        out.append(replace(r, y=y + np.random.default_rng(i).normal(0.0, NOISE_N, y.size)))
    return out


def _whole(runs: list[dg.RunData]) -> list[tuple[dg.RunData, slice]]:
    return [(r, slice(None)) for r in runs]


def _press(samples: float) -> dg.Model:
    """A press whose chain lags two samples at the steps' rate, ``samples`` of them counted in samples."""
    return replace(BASE, drive_delay_samples=samples, drive_delay_rate_hz=STEPS_HZ) if samples else BASE


@pytest.mark.parametrize("samples", [0.6, 1.3, 2.0])
def test_the_samples_of_the_chains_delay_are_read_off_the_runs_sampled_faster(samples):
    """The inverse of the forward model: a chain whose delay is ``samples`` counted in samples (and
    the rest of two samples of the steps' rate in seconds) is read back to within 0.05 sample; the
    faster triangles then read within 10 % of the RMS the press's own model leaves (its noise), and
    at half or less of what the delay in seconds left; the slower triangle reads as the model held it."""
    fit = _whole(_runs(_press(samples)))
    m = _with_sampled_chain_delay(BASE, fit, ONE_RATE)
    assert m.drive_delay_rate_hz == STEPS_HZ
    assert m.drive_delay_samples == pytest.approx(samples, abs=0.05)
    faster = [(r, sl) for r, sl in fit if r.fs_hz > STEPS_HZ]
    assert _cost(faster, m) < 1.1 * _cost(faster, _press(samples))
    assert _cost(faster, m) < 0.5 * _cost(faster, BASE)  # the lag the seconds drew is gone
    slow = [(r, sl) for r, sl in fit if r.fs_hz < STEPS_HZ]
    assert _cost(slow, m) == pytest.approx(_cost(slow, BASE))


def test_a_delay_in_seconds_is_left_in_seconds():
    fit = _whole(_runs(BASE))
    assert _with_sampled_chain_delay(BASE, fit, ONE_RATE) is BASE


def test_what_steps_at_two_rates_told_or_runs_no_faster_than_the_steps_leave_it_as_it_is():
    runs = _runs(_press(1.5))
    told = replace(BASE, drive_delay_samples=0.5, drive_delay_rate_hz=STEPS_HZ)
    assert _with_sampled_chain_delay(told, _whole(runs), ONE_RATE) is told
    slower = [r for r in runs if r.fs_hz <= STEPS_HZ]
    assert _with_sampled_chain_delay(BASE, _whole(slower), ONE_RATE) is BASE
    # steps at two rates among the runs (a held-out one too): their chain told the samples, or kept
    # them in seconds on purpose (a slew limit's); nothing is fitted
    assert _with_sampled_chain_delay(BASE, _whole(runs), {STEPS_HZ, 50_000.0}) is BASE
    # a delay counted in samples found already (input_delay's): it split the lag between the rates
    found = replace(BASE, delay_samples=4.0)
    assert _with_sampled_chain_delay(found, _whole(runs), ONE_RATE) is found
    # no series chain (a first-order lag, or a monitor recorded): nothing in samples to move
    lag = dg.Model(MODEL, wn=5000.0, zeta=0.08, drive_tau_s=1e-4)
    assert _with_sampled_chain_delay(lag, _whole(runs), ONE_RATE) is lag


def test_the_fast_causes_baseline_holds_it():
    """``_fast_base`` (the baseline of the delay, the rate dependence and the coupling) fits it where
    every step is at one rate, and not where a held-out step is at another."""
    runs = _runs(_press(1.5))
    ctx = Context(runs, BASE, frozenset(), {r.name: noise_floor(r.y) for r in runs})
    base = _fast_base(ctx, _whole(runs))
    assert base.drive_delay_samples == pytest.approx(1.5, abs=0.05) and base.drive_delay_rate_hz == STEPS_HZ
    held = _step("step-50v-50khz", 50_000.0, 50.0)
    two = Context([*runs, held], BASE, frozenset(), {**ctx.floor, held.name: NOISE_N})
    assert _fast_base(two, _whole(runs)).drive_delay_rate_hz is None
