"""Diagnosis: what the model gets wrong, its physical cause, the extended model, the gain.

The model judged is the bundle's forward model ("the simulation")::

    y_hat = y0 + lowpass( mode( creep( H(x) - y0 ) ) )       (a force clipped at 0 N: contact)

Everything is in the model's output unit (``hysteresis.output_unit``: N for a force run, um
for a displacement run): residuals, noise floors, the keys of :meth:`Diagnosis.as_dict`
(``residual_rms_n`` or ``residual_rms_um``) and the texts. The contact clip applies to
force only: a displacement goes negative wherever the data do.

On every run the residual ``y - y_hat`` is compared with the sensor's noise floor and
analysed (whiteness; correlation with the drive level, rate, current and time since a
step; dominant frequency). A catalogue of causes (:data:`CAUSES`) each holds a physical
explanation, an extension of the model (a parameter of :class:`Model`) and a fit of that
extension. Every extension is fitted on runs or segments and judged on others it did not
see: the gain is the held-out RMS residual of the current model against the extended one.

The search is greedy: every cause is tried on the current model, the one with the largest
held-out gain is accepted if it clears :data:`MIN_GAIN_PCT` with residuals above the noise,
the model is extended, and the remaining causes are tried again on what is left. An effect
partly mimicked by another cause is therefore not reported twice. When the residuals are at
the noise floor there are no findings; structure that no cause explains is listed as
unexplained, never named.

Judging data: runs the base model was not fitted on are preferred (the fast sweeps, the
larger steps, a rest run); the base fit's own runs are used in time segments it did not see
where a cause needs them (the end of the creep hold).

Pure math on arrays: runs come in as :class:`RunData`, models as analysis objects.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Sequence

import numpy as np
from scipy import optimize, signal

from piezopress import operators, signals, units
from piezopress.analysis import creep as creep_mod
from piezopress.analysis import hysteresis as H
from piezopress.analysis.mode import mode_response

#: A finding needs at least this held-out improvement of the RMS residual (percent) ...
MIN_GAIN_PCT = 20.0
#: ... a residual on its held-out data at least this many times the noise floor ...
MIN_RESIDUAL_TO_FLOOR = 1.5
#: ... and an improvement of at least this many noise floors (an echo of an accepted cause
#: in the last fraction of a newton above the noise is not a finding).
MIN_IMPROVEMENT_TO_FLOOR = 0.5
#: Residual structure above this many noise floors that no finding covers is "unexplained".
UNEXPLAINED_RATIO = 2.5
#: At most this many findings: the whole catalogue (each accepted one extends the model for the next round).
MAX_FINDINGS = len(("rate", "slew", "interference", "creep", "mode2", "drift", "delay", "order"))


# --------------------------------------------------------------------------- data


@dataclass(frozen=True)
class RunData:
    """One measured run as the diagnosis sees it."""

    name: str
    kind: str
    t_s: np.ndarray
    x: np.ndarray  # command (V)
    y: np.ndarray  # measured output
    fs_hz: float
    monitor: np.ndarray | None = None  # the drive actually applied, when recorded
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def freq_hz(self) -> float | None:
        f = self.meta.get("protocol", {}).get("freq_hz")
        return None if f is None else float(f)

    @property
    def step_v(self) -> float:
        return float(np.max(self.x) - np.min(self.x))

    @property
    def drive(self) -> np.ndarray:
        """The drive actually applied: the amplifier monitor when recorded, else the command."""
        return self.monitor if self.monitor is not None else self.x


@dataclass(frozen=True)
class Model:
    """The bundle's forward model, and every extension the catalogue can add to it.

    An extension at its default value is absent: the base model is ``Model(hysteresis,
    creep, wn, zeta, sensor_lowpass_hz)``.
    """

    hysteresis: H.PIModel
    creep: creep_mod.CreepModel | None = None
    wn: float | None = None
    zeta: float | None = None
    sensor_lowpass_hz: float | None = None  # the load cell's analog RC filter, a known part of the chain
    # extensions
    slew_v_per_s: float | None = None  # amplifier_slew_limit
    rate_v_per_kv_s: float = 0.0  # rate_dependent_hysteresis
    interference: tuple[float, float, float] | None = None  # (gain output unit per V/s, threshold V/s, tau s)
    mode2: tuple[float, float, float] | None = None  # (share, wn, zeta): second_resonance
    delay_s: float = 0.0  # input_delay
    drift_per_s: float = 0.0  # sensor_offset_drift, output unit per second

    @property
    def unit(self) -> str:
        """The output unit code (``N`` or ``um``)."""
        return self.hysteresis.output_unit

    def static(self, run: RunData, x: np.ndarray | None = None) -> np.ndarray:
        """``H(x) - y0`` with the slew limit and the rate dependence, if any."""
        m = self.hysteresis
        x = run.x if x is None else x
        if self.slew_v_per_s:
            x = signals.rate_limit(x, x[0], self.slew_v_per_s / run.fs_hz)
        widen = None
        if self.rate_v_per_kv_s > 0:
            rate = signals.rate_envelope(x, run.fs_hz, 5e-4)
            widen = self.rate_v_per_kv_s * rate / 1000.0
        Y = operators.play(np.asarray(x, float) - m.x0, np.array(m.r), 0.0, widen=widen)
        return H.dead_zone_superposition(Y @ np.array(m.w), np.array(m.d), np.array(m.s))

    def force(self, run: RunData, h: np.ndarray) -> np.ndarray:
        """Creep, mode(s), sensor low-pass and contact applied to the static prediction."""
        c = self.creep.response(h, run.fs_hz)[0] if self.creep is not None else h
        modes = []
        if self.wn:
            modes.append((1.0 - (self.mode2[0] if self.mode2 else 0.0), self.wn, self.zeta))
        if self.mode2:
            modes.append(self.mode2)
        out = sum(share * mode_response(c, run.fs_hz, wn, z, hold="zoh") for share, wn, z in modes) if modes else c
        if self.sensor_lowpass_hz:
            out = out[0] + signals.first_order(out - out[0], 1.0 / (2 * np.pi * self.sensor_lowpass_hz), run.fs_hz)
        y = self.hysteresis.y0 + out
        # a press only pushes: a force reads no less than 0 N; a displacement is never clipped
        return np.maximum(y, 0.0) if units.is_force(self.unit) else y

    def reading(self, run: RunData, f: np.ndarray) -> np.ndarray:
        """What the sensor reads of the force ``f``: interference, delay, drift."""
        y = f
        if self.interference:
            g, e0, tau = self.interference
            env = signals.rate_envelope(run.drive, run.fs_hz, tau)
            y = y - g * np.maximum(env - e0, 0.0)
        if self.delay_s > 0:
            t = np.arange(y.size) / run.fs_hz
            y = np.interp(t - self.delay_s, t, y, left=y[0])
        if self.drift_per_s:
            y = y + self.drift_per_s * run.t_s
        return y

    def predict(self, run: RunData) -> np.ndarray:
        return self.reading(run, self.force(run, self.static(run)))


# --------------------------------------------------------------------------- residual analysis


def noise_floor(y: np.ndarray, window: int = 64) -> float:
    """RMS of the sensor's noise: sample-to-sample scatter in the quietest stretches,
    and never below the quantization's ``q / sqrt(12)``."""
    y = np.asarray(y, float)
    if y.size < 2 * window:
        window = max(4, y.size // 4)
    n = (y.size - 1) // window
    d = np.diff(y)[: n * window].reshape(n, window)
    per = d.std(axis=1) / math.sqrt(2.0)
    scatter = float(np.percentile(per, 20)) if per.size else 0.0
    levels = np.unique(y)
    steps = np.diff(levels)
    q = float(np.min(steps)) if steps.size and np.min(steps) > 0 and levels.size < y.size / 4 else 0.0
    return max(scatter, q / math.sqrt(12.0), 1e-12)


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if np.size(x) else float("nan")


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    if a.size < 3 or np.std(a) == 0 or np.std(b) == 0:
        return 0.0
    return float(np.corrcoef(a, b)[0, 1])


@dataclass(frozen=True)
class ResidualStats:
    """How a run's residual looks: size against the noise floor, whiteness, correlations."""

    run: str
    rms: float
    floor: float
    lag1_autocorr: float
    corr_level: float
    corr_rate: float
    corr_abs_rate: float
    corr_log_time_since_step: float
    dominant_freq_hz: float
    t_max_s: float

    @property
    def ratio(self) -> float:
        return self.rms / self.floor

    def as_dict(self) -> dict[str, Any]:
        return {**self.__dict__, "ratio": self.ratio}


def residual_stats(run: RunData, residual: np.ndarray, floor: float) -> ResidualStats:
    r = residual - np.mean(residual)
    x = run.x
    rate = np.gradient(x) * run.fs_hz
    big = np.abs(np.diff(x, prepend=x[0])) > 0.05 * max(float(np.ptp(x)), 1e-9)
    idx = np.where(big, np.arange(x.size), 0)
    since = run.t_s - run.t_s[np.maximum.accumulate(idx)]
    f, p = signal.periodogram(r, run.fs_hz, window="hann")
    k = int(np.argmax(p[1:])) + 1 if p.size > 1 else 0
    return ResidualStats(
        run.name, rms(residual), floor,
        _corr(r[:-1], r[1:]), _corr(r, x), _corr(r, rate), _corr(r, np.abs(rate)), _corr(r, np.log1p(since * 1e3)),
        float(f[k]) if p.size > 1 else 0.0, float(run.t_s[int(np.argmax(np.abs(r)))]),
    )


# --------------------------------------------------------------------------- the search


Segment = tuple[RunData, slice]


@dataclass
class Context:
    """The runs, which of them the base model was fitted on, and the current model."""

    runs: list[RunData]
    model: Model
    fitted_runs: frozenset[str]
    floor: dict[str, float]
    cache: dict[str, np.ndarray] = field(default_factory=dict)

    def pred(self, run: RunData) -> np.ndarray:
        if run.name not in self.cache:
            self.cache[run.name] = self.model.predict(run)
        return self.cache[run.name]

    def independent(self, runs: list[RunData]) -> list[RunData]:
        return [r for r in runs if r.name not in self.fitted_runs]

    def steps(self) -> list[RunData]:
        return sorted([r for r in self.runs if r.kind == "step" and r.fs_hz >= 5000], key=lambda r: r.step_v)

    def sweeps(self, lo_hz: float = 0.0, hi_hz: float = np.inf) -> list[RunData]:
        """Swept runs between two drive frequencies; a run of unknown frequency (imported)
        counts as a slow sweep."""
        def freq(r):
            return r.freq_hz if r.freq_hz is not None else 0.0

        return [r for r in self.runs if r.kind in ("triangle", "sine", "custom") and np.ptp(r.x) > 0 and lo_hz <= freq(r) <= hi_hz]

    def rests(self) -> list[RunData]:
        return [r for r in self.runs if np.ptp(r.x) == 0]


@dataclass(frozen=True)
class Finding:
    """A cause that explains part of the residual, with its held-out gain (RMS, range and
    floor in the model's output unit, :attr:`unit`)."""

    cause: str
    evidence: str
    baseline_rms: float
    extended_rms: float
    gain_pct: float
    parameters: dict[str, float]
    runs: list[str]
    heldout: list[str]
    output_range: float
    floor: float
    model: Model

    @property
    def unit(self) -> str:
        return self.model.unit

    @property
    def accepted(self) -> bool:
        return (self.gain_pct >= MIN_GAIN_PCT and self.baseline_rms >= MIN_RESIDUAL_TO_FLOOR * self.floor
                and self.baseline_rms - self.extended_rms >= MIN_IMPROVEMENT_TO_FLOOR * self.floor)

    def as_dict(self) -> dict[str, Any]:
        k = units.key(self.unit)
        return {
            "cause": self.cause, "evidence": self.evidence,
            f"baseline_rms_{k}": self.baseline_rms, f"extended_rms_{k}": self.extended_rms,
            "baseline_pct_of_range": 100 * self.baseline_rms / self.output_range,
            "extended_pct_of_range": 100 * self.extended_rms / self.output_range,
            "gain_pct": self.gain_pct, "parameters": {k_: float(v) for k_, v in self.parameters.items()},
            "runs": self.runs, "heldout": self.heldout, f"noise_floor_{k}": self.floor,
        }


def _split(runs: list[RunData]) -> tuple[list[Segment], list[Segment]]:
    """Alternate whole runs into fitting and held-out sets (largest first)."""
    runs = list(runs)[::-1]
    return [(r, slice(None)) for r in runs[0::2]], [(r, slice(None)) for r in runs[1::2]]


def _time_split(runs: list[RunData], fit_fraction: float = 0.6) -> tuple[list[Segment], list[Segment]]:
    """Each run's first ``fit_fraction`` to fit, the rest held out (states carry on)."""
    fit, held = [], []
    for r in runs:
        k = int(r.t_s.size * fit_fraction)
        fit.append((r, slice(0, k)))
        held.append((r, slice(k, None)))
    return fit, held


def _err(segments: list[Segment], predict: Callable[[RunData], np.ndarray]) -> np.ndarray:
    return np.concatenate([(r.y - predict(r))[sl] for r, sl in segments]) if segments else np.zeros(0)


def _cost(segments: list[Segment], model: Model) -> float:
    return rms(_err(segments, model.predict))


def _search(objective: Callable[[float], float], lo: float, hi: float, n: int = 25, log: bool = False) -> float:
    """Grid then bounded refinement of a 1-D objective."""
    grid = np.geomspace(lo, hi, n) if log else np.linspace(lo, hi, n)
    vals = [objective(g) for g in grid]
    i = int(np.argmin(vals))
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, n - 1)]
    if b <= a:
        return float(grid[i])
    res = optimize.minimize_scalar(objective, bounds=(a, b), method="bounded", options={"xatol": (b - a) * 1e-3})
    return float(res.x) if res.fun <= vals[i] else float(grid[i])


def _refit_mode(model: Model, fit: list[Segment], extra: Callable[[Model, np.ndarray], Model] | None = None,
                extra_x0: Sequence[float] = (), extra_bounds: tuple[Sequence[float], Sequence[float]] = ((), ()),
                wide: bool = False) -> Model:
    """The main mode refitted on the fitting segments, within a factor 1.3 in frequency and 3
    in damping of the identified one (so that a mode distorted by the very effect under test
    does not decide between causes, and no cause turns the mode into something else), jointly
    with a cause's own parameters when ``extra`` maps them into the model."""
    if not model.wn:
        return model
    wn, z = model.wn, model.zeta

    def build(p):
        m = replace(model, wn=float(p[0]), zeta=float(p[1]))
        return extra(m, p[2:]) if extra is not None else m

    lo = [(0.5 if wide else 0.77) * wn, 0.01 if wide else z / 3.0, *extra_bounds[0]]
    hi = [(2.0 if wide else 1.3) * wn, 0.9 if wide else min(3.0 * z, 0.9), *extra_bounds[1]]
    x0 = np.clip([wn, z, *extra_x0], lo, hi)
    try:
        sol = optimize.least_squares(lambda p: _err(fit, build(p).predict), x0, bounds=(lo, hi), max_nfev=40,
                                     x_scale=[0.01 * wn, 0.01 * z] + [abs(v) * 0.05 + 1e-9 for v in extra_x0])
    except ValueError:
        return build(x0)
    return build(sol.x)


def _judge(ctx: Context, cause: str, evidence: str, fit: list[Segment], held: list[Segment], extended: Model,
           params: dict[str, float], baseline: Model | None = None) -> Finding:
    base = baseline or ctx.model
    b = _cost(held, base)
    e = _cost(held, extended)
    runs = [r for r, _ in fit + held]
    return Finding(cause, evidence, b, e, 100.0 * (b - e) / b if b > 0 else 0.0, params,
                   sorted({r.name for r in runs}), sorted({r.name for r, _ in held}),
                   max(float(np.ptp(r.y)) for r in runs), float(np.median([ctx.floor[r.name] for r, _ in held])), extended)


# --------------------------------------------------------------------------- causes


def cause_input_delay(ctx: Context) -> Finding | None:
    runs = ctx.independent(ctx.steps() + ctx.sweeps(5.0))
    if len(runs) < 2:
        return None
    fit, held = _split(runs)
    steps_fit = [(r, sl) for r, sl in fit if r.kind == "step"]
    base = _refit_mode(ctx.model, steps_fit) if steps_fit else ctx.model

    d = _search(lambda d: _cost(fit, replace(ctx.model, delay_s=d)), 0.0, 5e-3, 41)
    ext = replace(ctx.model, delay_s=d)
    if steps_fit:  # the mode and the delay together, on the steps
        # a delay distorts the identified mode (the identification has no delay): refit both freely
        ext = _refit_mode(ctx.model, steps_fit, lambda m, p: replace(m, delay_s=float(p[0])), [d], ([0.0], [5e-3]), wide=True)
        d = float(ext.delay_s)
    ev = f"the whole response lags the model by {d * 1e3:.3g} ms, on steps and fast sweeps alike"
    return _judge(ctx, "input_delay", ev, fit, held, ext, {"delay_s": d}, base)


def _monitor_slew(runs: list[RunData]) -> float | None:
    """Largest |dV/dt| of the amplifier monitor on runs whose command jumps further than it."""
    rates = []
    for r in runs:
        if r.monitor is None:
            continue
        jump = np.max(np.abs(np.diff(r.x))) * r.fs_hz
        mon = np.max(np.abs(np.diff(r.monitor))) * r.fs_hz
        if mon < 0.8 * jump:
            rates.append(mon)
    return max(rates) if rates else None


def cause_amplifier_slew_limit(ctx: Context) -> Finding | None:
    steps = ctx.steps()
    if len(steps) < 2:
        return None
    if any(r.monitor is not None for r in steps) and _monitor_slew(steps) is None:
        return None  # the applied drive follows the command: whatever the residual is, it is not the slew
    fit, held = _split(ctx.independent(steps) or steps)
    base = _refit_mode(ctx.model, fit)
    s = _search(lambda v: _cost(fit, replace(ctx.model, slew_v_per_s=v)), 2e3, 2e6, 31, log=True)
    ext = _refit_mode(ctx.model, fit, lambda m, p: replace(m, slew_v_per_s=float(p[0])), [s], ([0.5 * s], [2.0 * s]))
    s = float(ext.slew_v_per_s)
    mon = _monitor_slew(steps)
    ev = f"large steps rise slower than small ones: the drive behaves as if limited to {s / 1e3:.3g} V/ms"
    if mon is not None:
        ev += f"; the amplifier monitor itself slews at {mon / 1e3:.3g} V/ms while the command jumps"
    return _judge(ctx, "amplifier_slew_limit", ev, fit, held, ext, {"slew_rate_v_per_s": s}, base)


def cause_drive_coupled_interference(ctx: Context) -> Finding | None:
    runs = ctx.independent(ctx.steps() + ctx.sweeps(50.0))
    if len(runs) < 2:
        return None
    fit, held = _split(runs)
    res = _err(fit, ctx.pred)
    best = (rms(res), None)
    for tau in (0.5e-3, 1e-3, 1.5e-3, 2.5e-3, 4e-3):
        envs = [signals.rate_envelope(r.drive, r.fs_hz, tau)[sl] for r, sl in fit]
        peak = max(float(e.max()) for e in envs)
        for frac in (0.0, 0.1, 0.2, 0.35, 0.5, 0.7):
            A = -np.concatenate([np.maximum(e - frac * peak, 0.0) for e in envs])
            if A @ A == 0:
                continue
            g = max(0.0, float(A @ res) / float(A @ A))
            e = rms(res - g * A)
            if e < best[0]:
                best = (e, (g, frac * peak, tau))
    if best[1] is None:
        return None
    g, e0, tau = best[1]
    ext = replace(ctx.model, interference=(g, e0, tau))
    u = ctx.model.unit
    ev = (f"the reading dips while the drive current is high: {g * 1e3:.3g} {units.label(u)} per kV/s of drive rate above "
          f"{e0 / 1e3:.3g} kV/s (envelope {tau * 1e3:.3g} ms), an artefact of the reading, not {units.quantity(u)}")
    return _judge(ctx, "drive_coupled_interference", ev, fit, held, ext,
                  {f"gain_{units.key(u)}_per_v_per_s": g, "threshold_v_per_s": e0, "tau_s": tau})


def cause_rate_dependent_hysteresis(ctx: Context) -> Finding | None:
    sweeps = ctx.independent(ctx.sweeps(5.0))
    if not sweeps:
        return None
    fit, held = _time_split(sweeps)
    beta = _search(lambda b: _cost(fit, replace(ctx.model, rate_v_per_kv_s=b)), 0.0, 1.0, 21)
    ext = replace(ctx.model, rate_v_per_kv_s=beta)
    ev = f"the loops widen with the drive rate beyond the model's dynamics: every threshold grows {beta:.3g} V per kV/s"
    return _judge(ctx, "rate_dependent_hysteresis", ev, fit, held, ext, {"rate_v_per_kv_s": beta})


def _slow(run: RunData, v: np.ndarray, rate_hz: float = 50.0) -> tuple[np.ndarray, np.ndarray]:
    step = max(1, int(round(run.fs_hz / rate_hz)))
    if step == 1:
        return run.t_s, v
    sos = signal.butter(4, 0.8 / step, output="sos")
    return run.t_s[::step], signal.sosfilt(sos, v, zi=signal.sosfilt_zi(sos) * v[0])[0][::step]


def cause_logarithmic_creep(ctx: Context) -> Finding | None:
    runs = [r for r in ctx.runs if r.kind == "creep"]
    if not runs or ctx.model.creep is None or ctx.model.creep.form == "log":
        return None
    run = max(runs, key=lambda r: r.t_s[-1])
    h = ctx.model.static(run)
    t, u = _slow(run, h)
    # the force as the accepted reading terms (drift) leave it
    _, y = _slow(run, run.y - ctx.model.drift_per_s * run.t_s - ctx.model.hysteresis.y0)
    k = int(t.size * 0.6)
    fs = 1.0 / (t[1] - t[0])
    try:
        poles = creep_mod.fit_poles(t[:k], u[:k], y[:k], tau_bounds_s=(5.0 / fs, 10 * t[-1]))
        log = creep_mod.fit_log(t[:k], u[:k], y[:k])
    except Exception:  # noqa: BLE001 - any fit failure means: this cause cannot be judged here
        return None
    kk = int(run.t_s.size * 0.6)
    fit, held = [(run, slice(0, kk))], [(run, slice(kk, None))]
    ev = (f"after the step the {units.quantity(ctx.model.unit)} keeps rising {100 * log.params['per_decade']:.3g} % of the step per decade of time where "
          f"the fitted poles saturate (both forms fitted on the first 60 % of the hold, judged on the rest)")
    return _judge(ctx, "logarithmic_creep", ev, fit, held, replace(ctx.model, creep=log),
                  {"per_decade": log.params["per_decade"], "static_gain": log.static_gain}, replace(ctx.model, creep=poles))


def cause_second_resonance(ctx: Context) -> Finding | None:
    steps = ctx.steps()
    if len(steps) < 2 or not ctx.model.wn:
        return None
    fit, held = _split(steps)
    base = _refit_mode(ctx.model, fit)
    f1 = base.wn / (2 * np.pi)
    peaks = []
    for r, sl in fit:
        res = (r.y - base.predict(r))[sl]
        f, p = signal.periodogram(res - res.mean(), r.fs_hz, window="hann")
        band = (f > 1.3 * f1) & (f < 0.45 * r.fs_hz)
        if band.any():
            peaks.append(f[band][np.argmax(p[band])])
    if not peaks:
        return None
    w0 = 2 * np.pi * float(np.median(peaks))
    hs = {r.name: base.static(r) for r, _ in fit + held}

    def model_for(p):
        return replace(base, wn=p[3], zeta=p[4], mode2=(p[0], p[1], p[2]))

    def res(p):
        m = model_for(p)
        return np.concatenate([(r.y - m.reading(r, m.force(r, hs[r.name])))[sl] for r, sl in fit])

    try:
        sol = optimize.least_squares(res, x0=[0.1, w0, 0.05, base.wn, base.zeta],
                                     bounds=([0.0, 1.2 * base.wn, 0.005, 0.7 * base.wn, 0.005], [0.6, 4.0 * base.wn, 0.5, 1.3 * base.wn, 1.0]),
                                     max_nfev=60, x_scale=[0.05, 0.01 * w0, 0.01, 0.01 * base.wn, 0.01])
    except ValueError:
        return None
    lo_b, hi_b = [0.0, 1.2 * base.wn, 0.005], [0.6, 4.0 * base.wn, 0.5]
    if any(np.isclose(sol.x[i], b, rtol=1e-3) for i, b in enumerate(lo_b[1:], 1)) or any(np.isclose(sol.x[i], b, rtol=1e-3) for i, b in enumerate(hi_b)):
        return None  # a fit that leans on its bounds is bending a mode to fit something else
    ext = model_for(sol.x)
    ev = (f"the step residuals ring at {sol.x[1] / (2 * np.pi):.4g} Hz, away from the {f1:.4g} Hz mode: a second mode carrying "
          f"{100 * sol.x[0]:.3g} % of the response")
    return _judge(ctx, "second_resonance", ev, fit, held, ext,
                  {"share": sol.x[0], "natural_freq_rad_s": sol.x[1], "damping": sol.x[2]}, base)


def cause_sensor_offset_drift(ctx: Context) -> Finding | None:
    long_runs = [r for r in ctx.independent(ctx.runs) if r.t_s[-1] >= 10.0] or [r for r in ctx.rests()]
    if not long_runs:
        return None
    fit, held = _time_split(long_runs)
    T = np.concatenate([r.t_s[sl] for r, sl in fit])
    R = _err(fit, ctx.pred)
    T1 = np.column_stack([T, np.ones_like(T)])  # drift and a run offset; only the drift carries over
    (b, _), *_ = np.linalg.lstsq(T1, R, rcond=None)
    ext = replace(ctx.model, drift_per_s=float(b))
    u = ctx.model.unit
    ev = f"the reading drifts {b * 60:.3g} {units.label(u)} per minute whatever the drive does (seen on runs the model was not fitted on)"
    return _judge(ctx, "sensor_offset_drift", ev, fit, held, ext, {f"drift_{units.key(u)}_per_s": float(b)})


def cause_hysteresis_order(ctx: Context) -> Finding | None:
    sweeps = ctx.sweeps(0.0, 0.5)
    if not sweeps:
        return None
    m = ctx.model.hysteresis
    outs = []
    for r in sweeps:
        y = r.y
        if ctx.model.creep is not None:  # creep removed from the outputs, as the fit does
            y = m.y0 + ctx.model.creep.compensate(r.y - m.y0, r.fs_hz)[0]
        outs.append((r.name, r.x, y))
    data = H.prepare(outs, holdout_fraction=0.4, x0=m.x0, y0=m.y0)
    n_dz = max(0, len([d for d in m.d if d > 0]))
    try:
        base_fit = H.fit_hysteresis(data, [H.Candidate(max(2, len(m.r)), 1.0, n_dz)], refit_all=False)
        rich_fit = H.fit_hysteresis(data, refit_all=False)
    except H.HysteresisFitError:
        return None
    fit = [(r, data.train[i]) for i, r in enumerate(sweeps)]
    held = [(r, data.holdout[i]) for i, r in enumerate(sweeps)]
    # the refitted models measure what the base model measures (a displacement model must not
    # be taken for a force and clipped at 0 N)
    rich = replace(rich_fit.model, input_unit=m.input_unit, output_unit=m.output_unit)
    base_model = replace(base_fit.model, input_unit=m.input_unit, output_unit=m.output_unit)
    ev = (f"on the slow sweeps the residual follows the drive level: {rich.n_play} plays and {rich.n_dead_zone} dead zones (chosen on "
          f"held-out data) capture asymmetry and saturation that {len(m.r)} plays and {len(m.d)} dead zones miss")
    return _judge(ctx, "hysteresis_order", ev, fit, held, replace(ctx.model, hysteresis=rich),
                  {"n_play": rich.n_play, "n_dead_zone": rich.n_dead_zone}, replace(ctx.model, hysteresis=base_model))


@dataclass(frozen=True)
class Cause:
    """A catalogue entry: stable id, the physics, the extension, and its fit."""

    id: str
    physics: str
    extension: str
    run: Callable[[Context], Finding | None]
    in_compensator: bool = False


CAUSES: dict[str, Cause] = {c.id: c for c in (
    Cause("rate_dependent_hysteresis", "the stack's loop widens with the drive rate (domain walls lag a fast field)",
          "play thresholds r_i + beta |dV/dt|", cause_rate_dependent_hysteresis, True),
    Cause("amplifier_slew_limit", "the amplifier's current limit into the stack's capacitance caps dV/dt at I/C",
          "the drive passed through a rate limiter before the model", cause_amplifier_slew_limit, True),
    Cause("drive_coupled_interference", "the drive current couples into the load-cell amplifier (the thesis's notch, Section 5.3)",
          "an additive artefact of the reading driven by the drive-current envelope", cause_drive_coupled_interference),
    Cause("logarithmic_creep", "creep grows with log time (a spectrum of relaxation times) where a poles model saturates",
          "the creep model in log-time form", cause_logarithmic_creep, True),
    Cause("second_resonance", "a second, weaker mechanical mode of the press", "a second mode in parallel", cause_second_resonance),
    Cause("sensor_offset_drift", "the load-cell offset drifts slowly (temperature, supply), independent of the drive",
          "a drift term of the reading", cause_sensor_offset_drift),
    Cause("input_delay", "a pure delay between command and response (board latency, filters)", "the prediction delayed",
          cause_input_delay, True),
    Cause("hysteresis_order", "asymmetry or saturation the fitted operator set cannot represent",
          "more play and dead-zone operators, chosen on held-out data", cause_hysteresis_order, True),
)}


# --------------------------------------------------------------------------- the diagnosis


@dataclass(frozen=True)
class Diagnosis:
    findings: list[Finding]
    considered: list[Finding]
    unexplained: list[dict[str, Any]]
    before: list[ResidualStats]
    after: list[ResidualStats]
    residual_rms: float
    noise_floor: float
    summary: str
    model: Model

    @property
    def unit(self) -> str:
        """The output unit code of every figure (``N`` or ``um``)."""
        return self.model.unit

    def as_dict(self) -> dict[str, Any]:
        k = units.key(self.unit)
        return {
            "summary": self.summary,
            "output_unit": self.unit,
            f"residual_rms_{k}": self.residual_rms,
            f"noise_floor_{k}": self.noise_floor,
            "findings": [f.as_dict() for f in self.findings],
            "unexplained": self.unexplained,
            "considered_not_found": [f.as_dict() for f in self.considered],
            "runs_before": [s.as_dict() for s in self.before],
            "runs_after": [s.as_dict() for s in self.after],
        }


def diagnose(base: Model, runs: Sequence[RunData], fitted_runs: Sequence[str] = (), causes: Sequence[str] | None = None) -> Diagnosis:
    """Simulate every run with ``base``, analyse the residuals, extend the model cause by cause.

    ``fitted_runs`` names the runs the base model was fitted on; causes judge their gain on
    the others where they can.
    """
    runs = list(runs)
    floor = {r.name: noise_floor(r.y) for r in runs}
    ctx = Context(runs, base, frozenset(fitted_runs), floor)
    before = [residual_stats(r, r.y - ctx.pred(r), floor[r.name]) for r in runs]
    total_rms = rms(np.concatenate([r.y - ctx.pred(r) for r in runs]))
    total_floor = float(np.median(list(floor.values())))
    findings: list[Finding] = []
    last_try: dict[str, Finding] = {}
    todo = list(causes or CAUSES)
    while todo and len(findings) < MAX_FINDINGS:
        tried = []
        for cid in todo:
            try:
                f = CAUSES[cid].run(ctx)
            except (ValueError, np.linalg.LinAlgError, H.HysteresisFitError, creep_mod.FitError):
                f = None
            if f is not None and np.isfinite(f.gain_pct):
                tried.append(f)
                last_try[cid] = f
        ok = [f for f in tried if f.accepted]
        if not ok:
            break
        best = max(ok, key=lambda f: f.gain_pct)
        findings.append(best)
        todo.remove(best.cause)
        last_try.pop(best.cause, None)
        ctx = Context(runs, best.model, ctx.fitted_runs, floor)  # extend and look again
    findings.sort(key=lambda f: -f.gain_pct)
    after = [residual_stats(r, r.y - ctx.pred(r), floor[r.name]) for r in runs]
    k, u = units.key(base.unit), units.label(base.unit)
    unexplained = [
        {"run": s.run, f"rms_{k}": s.rms, f"noise_floor_{k}": s.floor, "ratio": s.ratio, "where_s": s.t_max_s, "dominant_freq_hz": s.dominant_freq_hz}
        for s in after if s.ratio > UNEXPLAINED_RATIO
    ]
    if findings:
        head = "; ".join(f"{f.cause} (held-out gain {f.gain_pct:.0f} %)" for f in findings)
    elif total_rms <= MIN_RESIDUAL_TO_FLOOR * total_floor or not unexplained:
        head = f"No findings: the residual ({total_rms:.3g} {u} RMS) is near the noise floor ({total_floor:.3g} {u})"
    else:
        head = f"No cause in the catalogue explains the residual ({total_rms:.3g} {u} RMS against a noise floor of {total_floor:.3g} {u})"
    if unexplained:
        head += "; unexplained structure in " + ", ".join(u["run"] for u in unexplained)
    return Diagnosis(findings, list(last_try.values()), unexplained, before, after, total_rms, total_floor, head, ctx.model)
