"""The forward model a diagnosis judges (the bundle's, with every extension a cause adds), and
the runs as it sees them."""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from datetime import datetime
from typing import Any

import numpy as np

from piezopress import signals, units
from piezopress.analysis import creep as creep_mod
from piezopress.analysis import hysteresis as H
from piezopress.analysis import profile
from piezopress.analysis.mode import mode_response
from piezopress.analysis.signatures import line_of

# --------------------------------------------------------------------------- data


@dataclass(frozen=True)
class RunData:
    """One measured run as the diagnosis sees it.

    ``t_s`` counts seconds from the run's first sample: a run whose times start elsewhere (a
    file from another program stamped with its clock, 1000 s into a session say) is moved to
    start at 0, for every judgement keys on the time since the run began (the held-out end of a
    hold, a drift's ramp, a creep's decades). Unmoved, such a run was diagnosed otherwise than
    the same run from 0: on the sample runs, a log creep and a coupling went unnamed. Where its
    first sample was stamped, ``clock_start_s`` keeps that time (:func:`run_starts` reads runs
    stamped on one session clock as that clock)."""

    name: str
    kind: str
    t_s: np.ndarray
    x: np.ndarray  # command (V)
    y: np.ndarray  # measured output
    fs_hz: float
    monitor: np.ndarray | None = None  # the drive actually applied, when recorded
    meta: dict[str, Any] = field(default_factory=dict)
    key: str = ""  # what identifies the run (its file's sha256, say): names may repeat, keys may not
    judged_from: int = 0  # rows before it (a rest of unknown state the fit skipped) are not judged as misfit
    held_out: tuple[int, int] | None = None  # the rows the fit held out (its held-out error's rows)
    clock_start_s: float | None = None  # the time the file stamped the first sample with, where not 0

    def __post_init__(self) -> None:
        t = np.asarray(self.t_s, dtype=float)
        if t.size and t[0] != 0.0:
            object.__setattr__(self, "t_s", t - t[0])
            if self.clock_start_s is None and math.isfinite(float(t[0])):
                object.__setattr__(self, "clock_start_s", float(t[0]))

    @property
    def ident(self) -> str:
        """The run's identity: its key, else its name."""
        return self.key or self.name

    @functools.cached_property
    def drive_profile(self) -> profile.RunProfile:
        """The drive's shape measured from its signal (a rest, a held step, a sweep...); what the
        run's metadata records is never used for a decision."""
        return profile.profile_signals(self.t_s, self.x)

    @property
    def freq_hz(self) -> float | None:
        """The sweep frequency measured from the drive's reversals (None: the drive is no
        regular sweep)."""
        p = self.drive_profile
        return p.freq_hz if p.is_sweep else None

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0]) + 1.0 / self.fs_hz if self.t_s.size else 0.0

    def estimated_freq_hz(self) -> float:
        """The drive's frequency: the measured sweep frequency, else estimated from the
        drive's crossings of its middle band (for texts, on drives that are no regular sweep)."""
        if self.freq_hz is not None:
            return self.freq_hz
        x = np.asarray(self.x, float)
        if x.size < 3 or np.ptp(x) == 0:
            return 0.0
        mid = 0.5 * (np.max(x) + np.min(x))
        band = 0.1 * np.ptp(x)
        side = np.where(x > mid + band, 1, np.where(x < mid - band, -1, 0))
        idx = np.flatnonzero(side)
        flips = idx[1:][np.diff(side[idx]) != 0]  # where the drive has crossed its middle band
        if flips.size < 2:
            return 0.0
        return (flips.size - 1) / 2.0 / float(self.t_s[flips[-1]] - self.t_s[flips[0]])

    @property
    def step_v(self) -> float:
        return float(np.max(self.x) - np.min(self.x))

    @property
    def drive(self) -> np.ndarray:
        """The drive actually applied: the amplifier monitor when recorded, else the command."""
        return self.monitor if self.monitor is not None else self.x

    def prefix(self, stop: int) -> RunData:
        """The run's first ``stop`` samples, as one run (the same identity); the same object
        for the same ``stop`` while it is recent, so that predictions of it are memoised."""
        if stop >= self.t_s.size:
            return self

        def cut() -> RunData:
            return replace(
                self,
                t_s=self.t_s[:stop],
                x=self.x[:stop],
                y=self.y[:stop],
                monitor=None if self.monitor is None else self.monitor[:stop],
                judged_from=min(self.judged_from, stop),
                held_out=None,
            )

        return memo(_PREFIX_MEMO, (id(self), stop), self, cut)


#: Static predictions of recent (run, static map) pairs: (run, prediction) by (id(run), map parameters).
_STATIC_MEMO: dict[tuple, tuple[Any, Any]] = {}
#: The drive felt and its plays' sums, by (id(run), hysteresis, slew, lag): every rate
#: dependence of the loop's width and every later stage reuse them.
_PLAY_MEMO: dict[tuple, tuple[Any, Any]] = {}
_CREEP_MEMO: dict[tuple, tuple[Any, Any]] = {}  # (static prediction, its creep response)
_PREFIX_MEMO: dict[tuple, tuple[Any, Any]] = {}  # a run's first samples, by (id(run), samples)
_RATE_MEMO: dict[tuple, tuple[Any, Any]] = {}  # the drive rate felt, by (id(run), chain, smoothing, saturation)
_TRANSIENT_MEMO: dict[tuple, tuple[Any, Any]] = {}  # a held unit stroke's creep, by (id(run), creep)
_FELT_MEMO: dict[tuple, tuple[Any, Any]] = {}  # the command felt through the drive chain, by (id(run), chain)
_INTERFERENCE_MEMO: dict[tuple, tuple[Any, Any]] = {}  # the drive current's artefact, by (id(run), parameters)
#: Two hum lines fitted in different runs within this many hertz are one line (each run refines
#: its line's frequency within 0.1 Hz).
HUM_SAME_LINE_HZ = 0.5
#: Entries each memo keeps (the oldest leaves first).
MEMO_SIZE = 64


def run_starts(runs: list[RunData]) -> dict[str, float]:
    """Each run's start on the test's clock (seconds from the first run's start), from the start
    time its metadata records (``started_utc``); a run starts no earlier than the run before it
    ended (a simulated press is played faster than real time). Runs without one are left out.

    Where no run records one, the runs' own time columns may be the clock: a DAQ program that
    stamps every file's samples on one session clock (:attr:`RunData.clock_start_s`). They are
    read so where a run is stamped elsewhere than 0 (a run whose stamps start at 0 is at 0 on that
    clock) and, in the order of their stamps, each starts no earlier than the one before it ended
    (one session, not files that each start anywhere)."""
    timed = []
    for r in runs:
        try:
            ts = datetime.fromisoformat(str(r.meta.get("started_utc")).replace("Z", "+00:00")).timestamp()
        except ValueError:
            continue
        timed.append((ts, r))
    stamped = not timed and any(r.clock_start_s is not None for r in runs)
    if stamped:  # (a run stamped from 0 is at 0 on that clock)
        timed = [(r.clock_start_s or 0.0, r) for r in runs]
    timed.sort(key=lambda p: p[0])
    # stamps on one session clock: each run after the one before it ended, a sample's time of slack
    if stamped and (
        len(timed) < 2 or any(b[0] < a[0] + a[1].duration_s - 1.0 / a[1].fs_hz for a, b in zip(timed, timed[1:]))
    ):
        return {}
    clock: dict[str, float] = {}
    end = None
    for ts, r in timed:
        t = ts - timed[0][0] if end is None else max(ts - timed[0][0], end)
        clock[r.ident] = t
        end = t + r.duration_s
    return clock


def memo(store: dict[tuple, tuple[Any, Any]], key: tuple, owner: Any, compute: Callable[[], Any]) -> Any:
    """``compute()``, kept in ``store`` under ``key`` while ``owner`` (whose ``id`` the key
    holds) is the same object; an array kept is made read-only (a tuple's parts are the
    caller's to protect)."""
    hit = store.get(key)
    if hit is not None and hit[0] is owner:
        return hit[1]
    value = compute()
    if isinstance(value, np.ndarray):
        value.setflags(write=False)
    if len(store) >= MEMO_SIZE:
        store.pop(next(iter(store)))
    store[key] = (owner, value)
    return value


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
    # the zeros above the mode fit identified (wz rad/s, damping): the main mode's anti-resonance
    antiresonance: tuple[float, float] | None = None
    # extensions
    slew_v_per_s: float | None = None  # amplifier_slew_limit (or the identified drive chain's slew)
    drive_tau_s: float = 0.0  # the drive chain's first-order lag, identified by fit when no monitor was recorded
    # ... or its second-order low-pass (wn rad/s, damping) and the part of its pure delay that is the press's own
    drive_lowpass: tuple[float, float] | None = None
    drive_delay_s: float = 0.0
    # where steps at two rates told the chain's delay in samples: those samples and the steps' rate;
    # a run sampled faster lags by as many fewer seconds (:meth:`drive_delay_at`)
    drive_delay_samples: float = 0.0
    drive_delay_rate_hz: float | None = None
    # the chain's whole delay in samples as those steps told it (the sampling's own and any FIFO), of
    # which the model holds drive_delay_samples: what input_delay's rate contrast is checked against
    chain_samples: float = 0.0
    # rate_dependent_hysteresis: every play threshold grows by rate_v_per_kv_s V per kV/s of the
    # drive rate (smoothed over rate_tau_s), or the loop's width (the plays' lag behind the
    # drive) by rate_loss_per_kv_s of itself per kV/s; the rate saturating at
    # rate_saturation_v_per_s (None: linear) or as a power law of it, rate_exponent (1: linear;
    # the gains are then per kV/s at 1 kV/s, hysteresis.rate_law)
    rate_v_per_kv_s: float = 0.0
    rate_loss_per_kv_s: float = 0.0
    rate_saturation_v_per_s: float | None = None
    rate_exponent: float = 1.0
    rate_floor_v_per_s: float = 0.0  # the rate the static loop was fitted at: the law is read above it
    rate_tau_s: float = 5e-4
    # drive_coupled_interference: (gain output unit per V/s above a threshold of the unsigned rate
    # envelope, threshold V/s, tau s[, gain output unit per V/s of the signed rate (the drive current's sign)[,
    # the signed rate's own smoothing, s (tau when absent)]])
    interference: tuple[float, ...] | None = None
    mode2: tuple[float, float, float] | None = None  # (share, wn, zeta): second_resonance ...
    # ... in parallel with the main mode (the response shared between them), or in series (the main
    # mode's response passes through it: a frame mode behind the stack; the share is then unused)
    mode2_series: bool = False
    delay_s: float = 0.0  # input_delay ...
    delay_samples: float = 0.0  # ... or one counted in samples (a board's FIFO): delay_samples / fs in every run
    drift_per_s: float = 0.0  # sensor_offset_drift, output unit per second ...
    # ... and a warm-up: (rate at the run's start, output unit per second; time constant over which it settles, s)
    drift_warmup: tuple[float, float] | None = None
    # ... or a wander on the test's clock (where the runs record their start times): in each window
    # of the clock two rests pin (:func:`~piezopress.analysis.diagnosis.slow.wander_windows`) the
    # offset a polynomial in the window's clock, ``a1 c + a2 c^2 + a3 c^3`` (a1 per second, a2 per
    # second squared, a3 per second cubed; a3 0 for a quadratic); per run by its identity: (identity,
    # its start on its window's clock, a1, a2, a3), read from the run's start. A run in no window has
    # one rate: (identity, 0, rate, 0, 0)
    drift_clock: tuple[tuple[str, float, float, float, float], ...] | None = None
    # sensitivity_drift: the reading's gain drifts on the test's clock: (rate per second, the clock
    # at which the base model's gain holds, per run by its identity: its start on the clock, and
    # whether the drift goes on inside it: not inside the hold the base model's creep was fitted
    # on, which holds that trend already)
    gain_drift: tuple[float, float, tuple[tuple[str, float, bool], ...]] | None = None
    # mains_pickup: lines in the reading, fitted run by run: (run identity, Hz, sine, cosine amplitude)
    hum: tuple[tuple[str, float, float, float], ...] = ()
    # logarithmic_creep: the creep acts on the stroke measured from this far below the rest level
    # (output unit): a stroke the stack keeps at rest (a remanent one) creeps from every run's
    # start where the press does not carry the creep's state from run to run
    creep_bias: float = 0.0
    # not an extension: whether the bundle's creep was fitted past the held step's edge (``creep.fit.edge_aligned``,
    # :func:`creep.edge_aligned`); None: the bundle does not say (written before it was recorded)
    creep_edge_aligned: bool | None = None

    @property
    def unit(self) -> str:
        """The output unit code (``N`` or ``um``)."""
        return self.hysteresis.output_unit

    def static(self, run: RunData, x: np.ndarray | None = None) -> np.ndarray:
        """``H(x) - y0`` with the slew limit and the rate dependence, if any."""
        if x is not None:
            felt = self.felt(run, x)
            return self.static_at_rate(felt, self._rate(run, felt))
        # the search evaluates one static map on one run many times (only later stages change),
        # and many rate dependences on one drive felt (only the plays' widening changes)
        chain = (self.hysteresis, *self._chain_key())
        rate_form = (
            self.rate_v_per_kv_s,
            self.rate_loss_per_kv_s,
            self.rate_saturation_v_per_s,
            self.rate_tau_s,
            self.rate_exponent,
            self.rate_floor_v_per_s,
        )

        def compute() -> np.ndarray:
            def felt_plays() -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
                felt = self.felt_command(run)
                return felt, self._plays(felt)

            felt, plays = memo(_PLAY_MEMO, (id(run), *chain), run, felt_plays)
            rate = None
            if self.rate_v_per_kv_s > 0 or self.rate_loss_per_kv_s > 0:
                rate = memo(_RATE_MEMO, (id(run), *chain, *rate_form[2:]), run, lambda: self._rate(run, felt))
            return self.static_at_rate(felt, rate, plays=None if self.rate_v_per_kv_s else plays)

        return memo(_STATIC_MEMO, (id(run), *chain, *rate_form), run, compute)

    def felt_command(self, run: RunData) -> np.ndarray:
        """:meth:`felt` of the run's command, kept per run and drive chain (read-only): the static
        map and the voltage at the stack (:meth:`stack_drive`) share it."""
        return memo(_FELT_MEMO, (id(run), *self._chain_key()), run, lambda: self.felt(run, run.x))

    def _chain_key(self) -> tuple:
        """What :meth:`felt` depends on beside the run: the drive chain."""
        return (
            self.slew_v_per_s,
            self.drive_tau_s,
            self.drive_lowpass,
            self.drive_delay_s,
            self.drive_delay_samples,
            self.drive_delay_rate_hz,
        )

    def drive_delay_at(self, fs_hz: float) -> float:
        """The drive chain's delay in a run sampled at ``fs_hz``: ``drive_delay_s`` (the delay at
        the steps' rate), less, in a run sampled faster, the seconds its part in samples
        (``drive_delay_samples``, told by steps at two rates) no longer lasts there; never below 0.
        A run sampled slower keeps ``drive_delay_s``: the part the forward model holds of the
        chain's delay is capped at the sampling's own at the steps' rate
        (:func:`~piezopress.analysis.bundle.chain_own_delay`), and a delay beyond it is
        ``input_delay``'s to name."""
        if not (self.drive_delay_samples and self.drive_delay_rate_hz) or fs_hz <= self.drive_delay_rate_hz:
            return self.drive_delay_s
        return max(0.0, self.drive_delay_s - self.drive_delay_samples * (1.0 / self.drive_delay_rate_hz - 1.0 / fs_hz))

    def felt(self, run: RunData, x: np.ndarray) -> np.ndarray:
        """The drive the stack feels for the command ``x``: through the amplifier's own lag and
        its slew limit, when the model has them."""
        if self.drive_lowpass is not None:  # a second-order low-pass and a delay, a slew limit before them
            if self.slew_v_per_s:  # (as fit identifies them: mode_fit.slew_lowpass_delayed)
                x = signals.rate_limit(x, x[0], self.slew_v_per_s / run.fs_hz)
            x = mode_response(x, run.fs_hz, *self.drive_lowpass, hold="zoh")
            return signals.delayed(x, run.fs_hz, self.drive_delay_at(run.fs_hz))
        if self.drive_tau_s > 0:  # the amplifier's own bandwidth (a held command through a first-order lag)
            x = x[0] + signals.first_order(x - x[0], self.drive_tau_s, run.fs_hz)
        x = signals.delayed(x, run.fs_hz, self.drive_delay_s)
        if self.slew_v_per_s:
            x = signals.rate_limit(x, x[0], self.slew_v_per_s / run.fs_hz)
        return x

    def _rate(self, run: RunData, felt: np.ndarray) -> np.ndarray | None:
        """The drive rate the stack feels (smoothed and saturated; None without a rate dependence)."""
        if not (self.rate_v_per_kv_s > 0 or self.rate_loss_per_kv_s > 0):
            return None
        rate = signals.rate_envelope(felt, run.fs_hz, self.rate_tau_s)
        return H.rate_law(rate, self.rate_saturation_v_per_s, self.rate_exponent, self.rate_floor_v_per_s)

    def _plays(self, x: np.ndarray, widen: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(u, plays, plane)``: the input relative to the map's origin, the plays' weighted sum
        (thresholds widened by ``widen``) and the plane's or the Duhem elements' (0 without)."""
        m = self.hysteresis
        u = np.asarray(x, float) - m.x0
        p, plane = m.outputs(u, widen=widen)
        if plane is None:
            plane = np.zeros_like(p)
        for a in (u, p, plane):
            a.setflags(write=False)
        return u, p, plane

    def static_at_rate(
        self,
        x: np.ndarray,
        rate: np.ndarray | None,
        plays: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    ) -> np.ndarray:
        """``H(x) - y0`` for a drive ``x`` (after any slew limit) when the stack feels the drive
        rate ``rate`` (V/s, smoothed and saturated; ``None``: no rate dependence). ``plays``:
        :meth:`_plays` of ``x`` already computed (unwidened; not for a threshold widening)."""
        m = self.hysteresis
        widen = self.rate_v_per_kv_s * rate / 1000.0 if self.rate_v_per_kv_s > 0 and rate is not None else None
        if plays is None or widen is not None:
            plays = self._plays(x, widen)
        u, p, plane = plays
        loss = self.rate_loss_per_kv_s * rate / 1000.0 if self.rate_loss_per_kv_s > 0 and rate is not None else 0.0
        return H.rate_loss_output(m, u, p, plane, loss)

    def force(self, run: RunData, h: np.ndarray) -> np.ndarray:
        """Creep, mode(s), sensor low-pass and contact applied to the static prediction."""
        c = self._crept(run, h)
        series = self.mode2 is not None and self.mode2_series
        modes = []
        if self.wn:
            modes.append((1.0 - (self.mode2[0] if self.mode2 and not series else 0.0), self.wn, self.zeta))
        if self.mode2 and not series:
            modes.append(self.mode2)
        # a held command reaches the mode held, unless a low-pass in the chain has made it smooth
        hold = "foh" if self.drive_lowpass is not None else "zoh"
        zeros = [self.antiresonance] + [None] * (len(modes) - 1)  # the main mode's
        out = (
            sum(
                share * mode_response(c, run.fs_hz, wn, z, hold=hold, zeros=zz)
                for (share, wn, z), zz in zip(modes, zeros)
            )
            if modes
            else c
        )
        if series:  # what the main mode delivers is smooth: it reaches the second mode sampled, not held
            out = mode_response(out, run.fs_hz, self.mode2[1], self.mode2[2], hold="foh")
        if self.sensor_lowpass_hz:
            out = out[0] + signals.first_order(out - out[0], 1.0 / (2 * np.pi * self.sensor_lowpass_hz), run.fs_hz)
        y = self.hysteresis.y0 + out
        # a press only pushes: a force reads no less than 0 N; a displacement is never clipped
        return np.maximum(y, 0.0) if units.is_force(self.unit) else y

    def _crept(self, run: RunData, h: np.ndarray) -> np.ndarray:
        """The creep model's response to the static prediction ``h``; memoised for a read-only
        ``h`` (the static memo's): a search varies later stages on one static prediction."""
        if self.creep is None:
            return h
        if h.flags.writeable:
            out = self.creep.output(h, run.fs_hz)
        else:
            out = memo(_CREEP_MEMO, (id(h), self.creep, run.fs_hz), h, lambda: self.creep.output(h, run.fs_hz))
        if self.creep_bias:  # the stroke from below the rest level creeps too; its static part stays in y0
            out = out + self.creep_bias * self.creep_transient(run)
        return out

    def creep_transient(self, run: RunData) -> np.ndarray:
        """The creep of a unit stroke held from the run's start, less its instantaneous part: what
        a stroke kept at rest adds to the run (:attr:`creep_bias`); zeros without creep."""
        if self.creep is None:
            return np.zeros(run.t_s.size)
        creep = self.creep
        return memo(_TRANSIENT_MEMO, (id(run), creep), run, lambda: creep.step_creep(run.t_s.size, run.fs_hz))

    def reading(self, run: RunData, f: np.ndarray) -> np.ndarray:
        """What the sensor reads of the force ``f``: interference, delay, gain drift, drift, hum."""
        y = f
        if self.interference:
            y = y - interference_reading(
                run, *self.interference, drive=self.stack_drive(run), drive_key=self._chain_key()
            )
        y = signals.delayed(y, run.fs_hz, self.reading_delay_s(run.fs_hz))
        if self.gain_drift:
            y = y * self.reading_gain(run)
        y = y + self.drift(run) if self.drift_per_s or self.drift_warmup or self.drift_clock else y
        for ident, hz, a, b in self.hum:
            if ident == run.ident:
                y = y + line_of(run.t_s, hz, a, b)
        return y

    def unfitted_lines(self, run: RunData) -> tuple[float, ...]:
        """The hum's frequencies (one per line, as fitted in other runs) at which ``run`` carries
        no fitted line: where its drive moved at the line's frequency, or it was too short to fit
        it. The hum is still in its reading there."""
        own = [hz for ident, hz, _, _ in self.hum if ident == run.ident]
        out: list[float] = []
        for _, hz, _, _ in self.hum:
            if all(abs(hz - o) > HUM_SAME_LINE_HZ for o in own + out):
                out.append(hz)
        return tuple(out)

    def stack_drive(self, run: RunData) -> np.ndarray:
        """The drive voltage at the stack, whose current (``C dV/dt``) a coupling puts into the
        reading: the amplifier monitor where it was recorded, else the command through the
        model's drive chain (:meth:`felt`). The command steps at once where the amplifier's output
        rises over its bandwidth: on the third test press (no monitor; a 2.5 kHz amplifier) its
        hidden coupling itself (a 30 Hz high-pass, seed 1) drawn from the command read the held-out
        100 V step 13 % worse than no coupling at all, its artefact ahead of the reading's; drawn
        from the chain, 2 % (seed 2: 8 %)."""
        return run.monitor if run.monitor is not None else self.felt_command(run)

    def reading_delay_s(self, fs_hz: float) -> float:
        """The reading's delay at the sample rate ``fs_hz``: an input delay in time, and one
        counted in samples."""
        return self.delay_s + self.delay_samples / fs_hz

    def _gain_start(self, run: RunData) -> tuple[float, bool] | None:
        """``run``'s start on the gain drift's clock and whether the drift goes on inside it (None:
        no gain drift, or none for this run)."""
        if not self.gain_drift:
            return None
        return next(((start, inside) for ident, start, inside in self.gain_drift[2] if ident == run.ident), None)

    def reading_gain(self, run: RunData) -> np.ndarray | float:
        """The reading's gain over ``run`` relative to the base model's (1 without a gain drift)."""
        at = self._gain_start(run)
        if at is None:
            return 1.0
        rate, ref, _ = self.gain_drift
        start, inside = at
        return 1.0 + rate * (start - ref + (run.t_s if inside else 0.5 * run.duration_s))

    def gain_held_over(self, run: RunData) -> bool:
        """Whether the model's gain drift is left out of ``run`` (read at its middle): the reading
        still ramps with the drifting gain there."""
        at = self._gain_start(run)
        return at is not None and not at[1]

    def drift(self, run: RunData) -> np.ndarray | float:
        """The drift of the reading over ``run`` (0 without one)."""
        out = self.drift_per_s * run.t_s if self.drift_per_s else 0.0
        if self.drift_warmup:
            rate, tau = self.drift_warmup
            out = out - rate * tau * np.expm1(-run.t_s / tau)
        return out + self.clock_drift(run)

    def clock_drift(self, run: RunData) -> np.ndarray | float:
        """The wander on the test's clock over ``run``, from its start (0 without one, or for a
        run whose start the wander does not know)."""
        if not self.drift_clock:
            return 0.0
        at = next((e[1:] for e in self.drift_clock if e[0] == run.ident), None)
        if at is None:
            return 0.0
        c0, a1, a2, a3 = at
        c = c0 + run.t_s
        return a1 * run.t_s + a2 * (c * c - c0 * c0) + a3 * (c**3 - c0**3)

    def predict(self, run: RunData) -> np.ndarray:
        return self.reading(run, self.force(run, self.static(run)))

    @property
    def causal(self) -> bool:
        """Whether the prediction at a sample depends only on the run up to it: every stage is
        causal but a drifting gain judged over a run's middle (its whole length)."""
        return not self.gain_drift

    def predict_until(self, run: RunData, stop: int | None) -> np.ndarray:
        """The prediction of the run's first ``stop`` samples (all: ``None``), equal to the
        whole run's prediction cut there; a causal model simulates only those samples."""
        if stop is None or stop >= run.t_s.size:
            return self.predict(run)
        return self.predict(run.prefix(stop)) if self.causal else self.predict(run)[:stop]


def interference_reading(
    run: RunData,
    g: float,
    e0: float,
    tau: float,
    g_signed: float = 0.0,
    tau_signed: float | None = None,
    *,
    drive: np.ndarray | None = None,
    drive_key: tuple = (),
) -> np.ndarray:
    """The artefact the drive current puts into the reading (subtracted from it): ``g`` per V/s
    of the unsigned rate envelope above ``e0`` (smoothed over ``tau``), and ``g_signed`` per V/s
    of the signed rate smoothed over ``tau_signed`` (``tau`` when None): a first-order high-pass
    of the drive voltage. The current is ``C dV/dt`` of ``drive``, the voltage at the stack
    (:meth:`Model.stack_drive`; ``run.drive`` when None), and ``drive_key`` what it was computed
    from beside the run (the memo's key).
    Memoised per run, drive and parameters: a search varies the later stages many times on one."""
    if drive is not None and not drive_key:
        raise ValueError("interference_reading: a drive given needs its drive_key (what it was computed from)")
    v = run.drive if drive is None else drive

    def compute() -> np.ndarray:
        out = g * np.maximum(signals.rate_envelope(v, run.fs_hz, tau) - e0, 0.0) if g else 0.0
        if g_signed:
            tau_s = tau if tau_signed is None else tau_signed
            out = out + g_signed * signals.smoothed_rate(v, run.fs_hz, tau_s)
        return out * np.ones(v.size)

    return memo(_INTERFERENCE_MEMO, (id(run), drive is None, drive_key, g, e0, tau, g_signed, tau_signed), run, compute)
