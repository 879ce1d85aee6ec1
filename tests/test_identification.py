"""Issue 10: identification that holds on records piezopress did not make.

The records here come from generators written in this file, apart from the project's
models and its virtual rig: Bouc-Wen hysteresis (a differential model, not a sum of
operators), creep as first-order Kelvin-Voigt elements on time constants other than the
fitted grid, a start-up transient and rests at levels that do not match the loop.
"""

from __future__ import annotations

import numpy as np
import pytest

from piezopress.analysis import creep as C
from piezopress.analysis import hysteresis as H
from piezopress.analysis.identify import fit_sweeps


def bouc_wen(
    x: np.ndarray,
    *,
    k: float | None = None,
    alpha: float = 0.35,
    beta: float = 0.9,
    gamma: float = 0.2,
    n: float = 1.0,
    scale: float = 1.0,
) -> np.ndarray:
    """Piezo Bouc-Wen hysteresis ``y = k x - h``, ``dh = alpha dx - beta |dx| |h|^(n-1) h - gamma dx |h|^n``
    (input scaled by ``scale`` so the loop shape does not depend on the drive's units). The
    output lags the input (the rising branch below the falling one); ``k`` defaults to 0.3
    above the steepest ``dh/dx`` (just after a reversal), so the output always rises with
    the input."""
    if k is None:
        h_sat = (alpha / max(beta + gamma, 1e-9)) ** (1 / n)
        k = alpha + abs(beta - gamma) * h_sat**n + 0.3
    u = np.asarray(x, float) / scale
    h = np.zeros_like(u)
    du = np.diff(u, prepend=u[0])
    for i in range(1, u.size):
        hp = h[i - 1]
        h[i] = hp + alpha * du[i] - beta * abs(du[i]) * abs(hp) ** (n - 1) * hp - gamma * du[i] * abs(hp) ** n
    return scale * (k * u - h)


def kelvin_voigt(y: np.ndarray, fs: float, taus=(7.0, 45.0), gains=(0.02, 0.03)) -> np.ndarray:
    """Creep added to ``y`` (relative to its first value): first-order elements from rest."""
    out = np.array(y, float)
    base = y - y[0]
    for tau, g in zip(taus, gains):
        a = np.exp(-1.0 / (fs * tau))
        acc = 0.0
        lp = np.empty_like(base)
        for i, v in enumerate(base):
            acc = a * acc + (1 - a) * v
            lp[i] = acc
        out += g * lp
    return out


def random_record(seed: int, n: int = 1500):
    """A random swept record: uni- or bipolar drive, sines/triangles of varying amplitude,
    optional rest at a level the loop does not explain and a start-up transient."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 100.0
    bipolar = rng.random() < 0.5
    lo, hi = (-rng.uniform(50, 150), rng.uniform(50, 150)) if bipolar else (0.0, rng.uniform(20, 150))
    mid, amp = (lo + hi) / 2, (hi - lo) / 2
    f = rng.uniform(0.3, 1.5)
    env = 1.0 - rng.uniform(0, 0.5) * (np.sin(2 * np.pi * 0.07 * t) ** 2)
    wave = np.sin(2 * np.pi * f * t) if rng.random() < 0.5 else 2 / np.pi * np.arcsin(np.sin(2 * np.pi * f * t))
    x = mid + amp * env * wave
    if not bipolar:
        x = np.clip(x, lo, hi)
    rest = int(rng.integers(0, n // 5))
    x[:rest] = mid
    y = 2.5 * bouc_wen(
        x, alpha=rng.uniform(0.1, 0.5), beta=rng.uniform(0.3, 1.5), gamma=rng.uniform(-0.2, 0.4), scale=amp
    )
    if rest:
        y[:rest] += rng.normal(0, 0.05 * np.ptp(y))  # a rest level the loop does not explain
    y[:10] -= rng.uniform(0, 0.3 * np.ptp(y)) * np.exp(-np.arange(10) / 3.0)  # a start-up transient
    y = y + rng.uniform(-100, 100) + rng.normal(0, 0.003 * np.ptp(y), n)
    return x, y


# --------------------------------------------------------------------------- rest state and start


def test_settled_start_keeps_a_record_from_rest_at_its_lowest_drive():
    x = np.concatenate([np.zeros(50), np.linspace(0, 100, 100), np.linspace(100, 0, 100)])
    assert H.settled_start(x) == 0


def test_settled_start_skips_until_the_input_has_swept_its_range():
    t = np.arange(1000) / 100.0
    x = 50 + 40 * np.sin(2 * np.pi * 0.5 * t)  # starts mid-range: state unknown
    first = H.settled_start(x)
    # up at 0.5 s, then down to within 2 % of the span of the lowest point (sin <= -0.96) at about 1.41 s
    assert 140 <= first <= 145
    assert x[: first + 1].max() >= 88.4 and x[first] <= 11.6 < x[:first].min()


def test_settled_start_of_a_growing_sweep_falls_back_to_half_its_span():
    t = np.arange(2000) / 100.0
    x = 50 + (5 + 2.2 * t) * np.sin(2 * np.pi * 0.5 * t)  # from mid-range, amplitude growing to 49
    first = H.settled_start(x)
    assert first < x.size // 2
    assert np.ptp(x[: first + 1]) >= 0.5 * np.ptp(x) > np.ptp(x[:first])


def test_a_start_transient_and_an_offset_are_estimated_not_assumed():
    """A mid-range start, a start-up transient and an unknown sensor offset: the fitted
    model predicts the held-out end as well as on a clean record of the same press."""
    t = np.arange(3000) / 100.0
    x = 1.8 + 1.8 * np.sin(2 * np.pi * t)
    clean = 20 * bouc_wen(x, scale=1.8)
    dirty = clean - 123.0
    dirty[:12] -= 25 * np.exp(-np.arange(12) / 3.0)  # sensor settling from rest
    runs = []
    for y in (clean, dirty):
        data = H.prepare([("r", x, y)], holdout_fraction=0.3)
        fit = H.fit_hysteresis(data, [H.Candidate(8, 2.0, 2)])
        runs.append(fit.holdout_rms_pct)
    assert runs[1] <= runs[0] + 0.02  # within 0.02 % of range of the clean record
    assert runs[1] < 0.5


@pytest.mark.parametrize("skip", [0, 300])
def test_skip_excludes_the_start_from_the_fit_but_carries_the_state(skip):
    x = np.concatenate([np.zeros(100), 50 + 50 * np.sin(np.linspace(-np.pi / 2, 12 * np.pi, 1900))])
    data = H.prepare([("r", x, 2 * x)], holdout_fraction=0.25, skip=skip)
    assert not data.train[0][:skip].any() and data.train[0][skip]
    n_fit = x.size - skip
    assert data.holdout[0].sum() == n_fit - int(round(n_fit * 0.75))


def test_skip_out_of_range_is_refused_naming_the_value():
    with pytest.raises(H.HysteresisFitError, match="skip of 5000 samples; expected 0 to 199"):
        H.prepare([("r", np.linspace(0, 1, 200), np.linspace(0, 1, 200))], skip=5000)


def test_a_falling_output_is_refused_with_the_fix():
    x = np.concatenate([np.linspace(0, 100, 200), np.linspace(100, 0, 200)] * 3)
    with pytest.raises(H.HysteresisFitError, match="--scale"):
        H.fit_hysteresis(H.prepare([("r", x, -2 * x)]), [H.Candidate(4, 1.0, 1)])


# --------------------------------------------------------------------------- a well-conditioned map


def _loading_slopes(model: H.PIModel, span: float) -> np.ndarray:
    x = model.x0 + np.linspace(0, span, 4001)
    y, _ = model.forward(x)
    return np.diff(y) / np.diff(x)


def test_the_inverse_moves_wherever_the_reference_moves_on_200_random_fitted_models():
    """Property: on 200 models fitted to random records (Bouc-Wen presses, rests at odd
    levels, start-up transients), the inverse's drive moves at least ``1/upper`` and at
    most ``1/lower`` per unit of reference, with ``(lower, upper) = slope_bounds``: here at
    least 1/16 and at most 40 times the mean inverse gain. No plateau, no jump."""
    rng = np.random.default_rng(10)
    worst_low, worst_high = np.inf, 0.0
    grid = [H.Candidate(n, g, m) for n in (4, 8, 12) for g in (1.0, 2.0) for m in (1, 4, 16)]
    for seed in range(200):
        x, y = random_record(seed)
        data = H.prepare([("r", x, y)], holdout_fraction=0.3)
        fit = H.fit_hysteresis(data, [grid[seed % len(grid)]], refit_all=False)
        model = fit.model
        lower, upper = H.slope_bounds(data)
        g = H._mean_gain(data)
        assert lower == pytest.approx(g / 40) and upper == pytest.approx(16 * g)
        # a random reference inside the output range: steps, ramps and reversals
        z_lo, z_hi = data.z_range
        ref = data.y0 + z_lo + (z_hi - z_lo) * np.clip(np.cumsum(rng.normal(0, 0.03, 3000)) % 2.0, 0, None) / 2.0
        ref[rng.integers(0, 3000, 30)] += rng.normal(0, 0.1 * (z_hi - z_lo), 30)
        xd, _ = model.inverse(ref)
        dy, dx = np.abs(np.diff(ref)), np.abs(np.diff(xd))
        moving = dy > 1e-9 * (z_hi - z_lo)
        ratio = dx[moving] / dy[moving]
        worst_low = min(worst_low, float(ratio.min() * g))
        worst_high = max(worst_high, float(ratio.max() * g))
        assert ratio.min() >= (1 - 1e-6) / upper, (
            f"seed {seed}: the drive moves {ratio.min():.3g} per unit of reference"
        )
        assert ratio.max() <= (1 + 1e-6) / lower, (
            f"seed {seed}: the drive jumps {ratio.max():.3g} per unit of reference"
        )
        # and the inverse is exact: the forward model gives the reference back
        back, _ = model.forward(xd)
        np.testing.assert_allclose(back, ref, atol=1e-6 * (z_hi - z_lo))
    assert worst_low >= 1 / 16 and worst_high <= 40


def test_a_rest_at_an_odd_level_makes_no_step_in_the_static_map():
    """SmartHysteresis's failure: a rest whose level the loop does not explain made the
    fit put a near-step in the map. The loading curve's slope now stays within bounds."""
    t = np.arange(5000) / 500.0
    x = np.where(t < 3.26, 0.0, 150 * np.sin(2 * np.pi * (t - 3.26)))
    y = 0.13 * bouc_wen(x, scale=150.0)
    y[t < 3.26] = -1.65
    data = H.prepare([("r", x, y)], holdout_fraction=0.3)
    fit = H.fit_hysteresis(data)
    lower, upper = H.slope_bounds(data)
    slopes = _loading_slopes(fit.final_model, 300.0)
    assert slopes.min() >= lower * (1 - 1e-6) and slopes.max() <= upper * (1 + 1e-6)
    ref = np.linspace(-18, 18, 2001)
    xd, _ = fit.final_model.inverse(ref)
    assert np.diff(xd).min() > 0  # the drive never stalls


# --------------------------------------------------------------------------- creep from sweeps


def test_kelvin_voigt_creep_is_found_from_sweeps_and_kept_only_when_it_predicts_better():
    fs = 50.0
    t = np.arange(3000) / fs
    x = 75 + 75 * np.sin(2 * np.pi * 0.5 * t - np.pi / 2)  # from rest at the lowest drive
    static = 2.0 * bouc_wen(x, scale=75.0)
    rng = np.random.default_rng(1)
    crept = kelvin_voigt(static, fs) + rng.normal(0, 0.05, t.size)
    plain = static + rng.normal(0, 0.05, t.size)
    grid = [H.Candidate(12, 2.0, 2)]
    with_creep = fit_sweeps([("c", x, crept, fs)], grid=grid)
    without = fit_sweeps([("p", x, plain, fs)], grid=grid)
    assert with_creep.creep is not None and without.creep is None
    assert with_creep.holdout_rms <= 0.5 * with_creep.holdout_rms_static
    # the creep found matches the true creep over the record's time scale: a held step's
    # creep after 60 s, 0.02 (1 - e^-60/7) + 0.03 (1 - e^-60/45) = 0.0419, within a third
    step = np.ones(int(60 * fs))
    found = with_creep.creep.response(step, fs)[0][-1] / with_creep.creep.static_gain - 1
    assert found == pytest.approx(0.0419, rel=0.33)
    # its compensator inverts it: the response to the compensated drive is the reference
    ref = np.full(2000, 100.0)
    drive, _ = with_creep.creep.compensate(ref, fs)
    np.testing.assert_allclose(with_creep.creep.response(drive, fs)[0], ref, rtol=1e-9)


def test_creep_is_found_from_sweeps_recorded_at_several_sample_rates():
    """Runs at 50 and 80 Hz (two protocols, two rates): the creep elements run record by record
    at each one's rate, and the creep found is the one a single-rate record gives."""
    rng = np.random.default_rng(2)
    runs = []
    for name, fs, n in (("a", 50.0, 3000), ("b", 80.0, 4000)):
        t = np.arange(n) / fs
        x = 75 + 75 * np.sin(2 * np.pi * 0.5 * t - np.pi / 2)
        runs.append((name, x, kelvin_voigt(2.0 * bouc_wen(x, scale=75.0), fs) + rng.normal(0, 0.05, n), fs))
    found = fit_sweeps(runs, grid=[H.Candidate(12, 2.0, 2)])
    assert found.creep is not None, found.creep_reason
    assert found.holdout_rms <= 0.5 * found.holdout_rms_static
    step = np.ones(int(60 * 50.0))
    creep_60s = found.creep.response(step, 50.0)[0][-1] / found.creep.static_gain - 1
    assert creep_60s == pytest.approx(0.0419, rel=0.33)  # as in the single-rate test above


def test_sweep_creep_gains_are_non_negative_and_the_compensator_stable():
    fs = 50.0
    rng = np.random.default_rng(4)
    u = np.abs(np.cumsum(rng.normal(0, 1, 3000)))
    y = kelvin_voigt(u, fs, taus=(20.0,), gains=(0.1,)) + rng.normal(0, 0.01, u.size)
    model, offset = C.fit_sweep_creep(u, y, fs, np.ones(u.size, bool))
    assert min(model.gains) >= 0 and model.static_gain > 0
    assert abs(offset) < 0.05
    model.check_stable(fs)


# --------------------------------------------------------------------------- the command line


def _sweep_run(path, *, rest_s: float = 2.0, fs: float = 200.0):
    """A displacement record: a rest at mid-range, then a sine (a start that is no sweep)."""
    import json as _json  # noqa: F401

    from piezopress import runformat as rf

    t = np.arange(int(12 * fs)) / fs
    x = np.where(t < rest_s, 75.0, 75 + 75 * np.sin(2 * np.pi * (t - rest_s)))
    y = 0.1 * bouc_wen(x, scale=75.0) + np.where(t < rest_s, 0.7, 0.0)  # the rest sits off the loop
    run = rf.make_run({"t_s": t, "command_v": x, "displacement_um": y}, rf.make_meta("sine", "sweep", fs))
    rf.write_run(run, path)
    return x


def test_fit_hysteresis_skips_the_start_on_request_and_prints_both_errors_in_the_runs_unit(tmp_path):
    import json

    from click.testing import CliRunner

    from piezopress.piezocli.main import cli

    _sweep_run(tmp_path / "sweep.parquet")
    res = CliRunner().invoke(
        cli,
        ["fit-hysteresis", str(tmp_path / "sweep.parquet"), "--rows", "600:2000", "--out", str(tmp_path / "h.json")],
    )
    assert res.exit_code == 0, res.output
    fit = json.loads((tmp_path / "h.json").read_text())["fit"]
    assert fit["fitted_from_row"] == [600]
    line = next(ln for ln in res.output.splitlines() if ln.startswith("Fit error"))
    assert "train RMS" in line and "held-out RMS" in line and line.count("µm") == 3
    res = CliRunner().invoke(
        cli, ["fit-hysteresis", str(tmp_path / "sweep.parquet"), "--skip-s", "3", "--out", str(tmp_path / "h2.json")]
    )
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "h2.json").read_text())["fit"]["fitted_from_row"] == [600]
    # by default the rest and the first half period are detected and skipped
    res = CliRunner().invoke(
        cli, ["fit-hysteresis", str(tmp_path / "sweep.parquet"), "--out", str(tmp_path / "h3.json")]
    )
    assert res.exit_code == 0, res.output
    assert 400 <= json.loads((tmp_path / "h3.json").read_text())["fit"]["fitted_from_row"][0] <= 700


@pytest.mark.parametrize(
    "args, message",
    [
        (["--rows", "5:2"], "expected 0 <= START < STOP"),
        (["--rows", "abc"], "expected START:STOP"),
        (["--rows", "0:99999"], "--rows stop 99999 is outside the run's 2400 rows"),
        (["--skip-s", "100"], "--skip-s 100 s; expected 0 to 11.99 s"),
    ],
)
def test_bad_fitted_rows_are_refused_naming_the_value(tmp_path, args, message):
    from click.testing import CliRunner

    from piezopress.piezocli.main import cli

    _sweep_run(tmp_path / "sweep.parquet")
    res = CliRunner().invoke(
        cli, ["fit-hysteresis", str(tmp_path / "sweep.parquet"), *args, "--out", str(tmp_path / "h.json")]
    )
    assert res.exit_code != 0 and message in res.output, res.output
    assert not (tmp_path / "h.json").exists()
