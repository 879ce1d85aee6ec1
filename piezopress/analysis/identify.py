"""Identification from sweeps alone: hysteresis, and creep when the record asks for it.

A measured record from another lab rarely holds a held step, yet its output drifts while
the drive repeats (creep after the drive moved away from rest). :func:`fit_sweeps` fits the
hysteresis model (:func:`piezopress.analysis.hysteresis.fit_hysteresis`, structure chosen
on the held-out end of the fitted samples), then Kelvin-Voigt creep on the hysteresis
model's static prediction (:func:`piezopress.analysis.creep.fit_sweep_creep`), and keeps the
creep only if it predicts the held-out end better by at least :data:`CREEP_MIN_GAIN`. With
creep kept, hysteresis is fitted again on the output with the creep removed (the creep
compensator applied), and creep again on that model: the two stages alternate as the
``fit`` pipeline does with a held step.

Every figure called held-out comes from models fitted without the held-out samples; the
models returned (``final``) are refitted on every fitted sample.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from piezopress.analysis import creep as C
from piezopress.analysis import hysteresis as H
from piezopress.errors import FitError

#: Creep is kept when it lowers the held-out RMS by at least this fraction (the bar
#: `diagnose` sets for any extension): a loop shape the hysteresis model misses can also
#: look like a slow trend, by a little.
CREEP_MIN_GAIN = 0.2
#: Creep time constants tried: two per decade from 0.3 s to 300 s, of which only those at
#: least :data:`CREEP_PERIODS` periods of the slowest sweep are used. A first-order element
#: of time constant ``tau`` passes a sweep of period ``T`` with a gain of about
#: ``T / (2 pi tau)`` at 90 degrees: a fast one would shape the loop (a rate effect the
#: hysteresis model should not be helped with), a slow one only follows the mean level.
CREEP_TAUS_S = (0.3, 1.0, 3.0, 10.0, 30.0, 100.0, 300.0)
CREEP_PERIODS = 5.0


def sweep_period_s(x: np.ndarray, fs_hz: float) -> float:
    """The period of the strongest component of ``x`` (its mean removed), in seconds."""
    x = np.asarray(x, float) - np.mean(x)
    spec = np.abs(np.fft.rfft(x))
    spec[0] = 0.0
    k = int(np.argmax(spec))
    return float(x.size / fs_hz / k) if k else float(x.size / fs_hz)


@dataclass(frozen=True)
class SweepFit:
    """What :func:`fit_sweeps` found.

    ``hysteresis`` is the structure search on the training rows (its ``final_model`` refitted
    on all fitted rows); ``model``/``creep`` the final models (``creep`` None when not kept);
    ``holdout_rms``/``train_rms`` in the output's unit, of the models fitted on the training
    rows; ``holdout_rms_static`` the held-out RMS without creep, for comparison; ``reason``
    says how the hysteresis structure was chosen, ``creep_reason`` why creep was kept or not.
    """

    hysteresis: H.HysteresisFit
    model: H.PIModel
    creep: C.CreepModel | None
    train_rms: float
    holdout_rms: float
    holdout_rms_static: float
    output_range: float
    reason: str
    creep_reason: str
    #: per run, ``(fitted_from, held_out_from, stop)``: the rows the figures judge
    rows: tuple[tuple[int, int, int], ...] = ()

    @property
    def holdout_rms_pct(self) -> float:
        return 100.0 * self.holdout_rms / self.output_range

    def predict(self, x: np.ndarray, fs_hz: float) -> np.ndarray:
        """The output for input ``x`` from the rest state (sample rate ``fs_hz`` for creep)."""
        return predict(self.model, self.creep, x, fs_hz)


def predict(model: H.PIModel, creep: C.CreepModel | None, x: np.ndarray, fs_hz: float) -> np.ndarray:
    """Hysteresis, then creep on its static prediction relative to the rest output ``y0``."""
    y, _ = model.forward(np.asarray(x, float))
    if creep is None:
        return y
    return model.y0 + creep.response(y - model.y0, fs_hz)[0]


def _errors(model, creep, runs, masks) -> np.ndarray:
    return np.concatenate([(predict(model, creep, x, fs) - y)[m] for (_, x, y, fs), m in zip(runs, masks)])


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e**2))) if e.size else float("nan")


def _fit_creep(model: H.PIModel, runs, masks, taus) -> tuple[C.CreepModel, H.PIModel]:
    """Creep on ``model``'s static prediction (runs concatenated, each from rest); the fitted
    output offset goes into the hysteresis model's rest output."""
    fs = {float(r[3]) for r in runs}
    if len(fs) != 1:  # runs at several rates: the elements' columns run by run, each at its rate (exact)
        creep, c = C.fit_sweep_creep_runs(
            [(model.forward(x)[0] - model.y0, yy - model.y0, f, m) for (_, x, yy, f), m in zip(runs, masks)], taus
        )
        return creep, replace(model, y0=model.y0 + c)
    u = np.concatenate([model.forward(x)[0] - model.y0 for _, x, _, _ in runs])
    y = np.concatenate([yy - model.y0 for _, _, yy, _ in runs])
    mask = np.concatenate(list(masks))
    # each run starts from rest: fit run by run would be exact; one long record is exact
    # too when runs are separated by rests, and a close approximation otherwise
    creep, c = C.fit_sweep_creep(u, y, fs.pop(), mask, taus)
    return creep, replace(model, y0=model.y0 + c)


def _decreep(model: H.PIModel, creep: C.CreepModel, runs) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """The outputs with creep removed (the creep compensator applied), as the fit does with a held step."""
    return [(name, x, model.y0 + creep.compensate(y - model.y0, fs)[0]) for name, x, y, fs in runs]


def fit_sweeps(
    runs: Sequence[tuple[str, np.ndarray, np.ndarray, float]],
    *,
    holdout_fraction: float = 0.3,
    grid: Sequence[H.Candidate] | None = None,
    skip: Sequence[int] | int | None = None,
    creep: bool = True,
) -> SweepFit:
    """Fit ``(name, input, output, sample_rate_hz)`` sweeps: hysteresis, and creep if it helps.

    ``holdout_fraction``, ``skip`` and ``grid`` are as in :func:`hysteresis.prepare` and
    :func:`hysteresis.fit_hysteresis`; ``creep=False`` never tries creep.
    """
    hruns = [(name, x, y) for name, x, y, _ in runs]
    data = H.prepare(hruns, holdout_fraction=holdout_fraction, skip=skip)
    hfit = H.fit_hysteresis(data, grid)
    static_ho = _rms(_errors(hfit.model, None, runs, data.holdout))
    out = SweepFit(
        hfit,
        hfit.final_model or hfit.model,
        None,
        hfit.train_rms,
        static_ho,
        static_ho,
        hfit.output_range,
        hfit.reason,
        "creep not tried",
        judged_rows(data),
    )
    if not creep:
        return out
    period = max(sweep_period_s(x[m], fs) for (_, x, _, fs), m in zip(runs, data.train))
    taus = tuple(t for t in CREEP_TAUS_S if t >= CREEP_PERIODS * period)
    if not taus:
        return replace(
            out,
            creep_reason=f"creep not tried: the sweeps' period ({period:.3g} s) leaves no time "
            f"constant of at least {CREEP_PERIODS:g} periods up to {CREEP_TAUS_S[-1]:g} s",
        )
    try:
        cm, hm = _fit_creep(hfit.model, runs, data.train, taus)
        # alternate once: hysteresis on the creep-free output, creep again on that model
        data2 = H.prepare(_decreep(hm, cm, runs), holdout_fraction=holdout_fraction, skip=skip, x0=data.x0, y0=hm.y0)
        hfit2 = H.fit_hysteresis(data2, [H.Candidate(*_candidate(hfit.chosen))])
        cm2, hm2 = _fit_creep(hfit2.model, runs, data.train, taus)
    except (FitError, H.HysteresisFitError) as exc:
        return replace(out, creep_reason=f"creep not fitted ({exc})")
    creep_ho = _rms(_errors(hm2, cm2, runs, data.holdout))
    if not creep_ho <= (1 - CREEP_MIN_GAIN) * static_ho:
        return replace(
            out,
            creep_reason=f"creep not kept: held-out RMS {creep_ho:.4g} against {static_ho:.4g} "
            f"without (needs {100 * CREEP_MIN_GAIN:g} % less)",
        )
    # final: the same alternation on every fitted sample
    all_rows = [t | h for t, h in zip(data.train, data.holdout)]
    cmf, hmf = _fit_creep(hfit.final_model or hfit.model, runs, all_rows, taus)
    hf = H.refit(
        H.prepare(_decreep(hmf, cmf, runs), holdout_fraction=holdout_fraction, skip=skip, x0=data.x0, y0=hmf.y0),
        hfit2.model,
        rows="all",
    )
    cmf, hmf = _fit_creep(hf, runs, all_rows, taus)
    train = _rms(_errors(hm2, cm2, runs, data.train))
    why = (
        f"Kelvin-Voigt creep from the sweeps ({cmf.describe()}): held-out RMS {creep_ho:.4g} with it against "
        f"{static_ho:.4g} without"
    )
    hfit2 = replace(hfit2, family_reason=hfit.family_reason)  # the family was chosen by the first search
    return SweepFit(hfit2, hmf, cmf, train, creep_ho, static_ho, hfit.output_range, hfit.reason, why, judged_rows(data))


def judged_rows(data: H.HysteresisData) -> tuple[tuple[int, int, int], ...]:
    """Per run, ``(fitted_from, held_out_from, stop)`` of prepared data."""
    return tuple(
        (int(np.argmax(t)), int(np.argmax(h)) if h.any() else int(h.size), int(t.size))
        for t, h in zip(data.train, data.holdout)
    )


def _candidate(label: str) -> tuple[int, float, int, int, int, str]:
    """``Candidate`` fields from its label ``n=.. gamma=.. m=.. [plane=..] [duhem=.. [rest=..]]``."""
    parts = dict(p.split("=") for p in label.split())
    n, g, m = int(parts["n"]), float(parts["gamma"]), int(parts["m"])
    return n, g, m, int(parts.get("plane", 0)), int(parts.get("duhem", 0)), parts.get("rest", H.DUHEM_RESTS[0])
