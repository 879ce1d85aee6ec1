"""Physics of the virtual press: pure functions over sampled signals, with explicit state.

The signal chain, in order::

    command_v --DAC: quantize, hold--> amplifier: gain, output limits, slew limit (I/C)
      --stack: rate-dependent hysteresis h(v) --press: modes (one or two) --creep (log time)
      --contact: max(0, preload + gain * x) --load cell: + drive-current interference,
      RC low-pass, delay, offset drift, noise, ADC--> force_n

Fast stages (slew limit, drive rate, hysteresis, modes, interference) carry physical
state (:class:`FastState`) from one segment to the next, so a run can be simulated in
segments at different rates: finely (an integer multiple of the run's rate) just after a
fast drive change, on the run's own grid elsewhere. Every discretisation is exact for an
input held between samples (zero-order hold). The slow stages are linear and commute with
the modes, so they run once over the whole run on its own grid. Randomness comes only from
the ``numpy.random.Generator`` passed in; nothing sleeps.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import signal

from piezopress import operators, signals
from piezopress.acquisition.rig_config import CreepSection, HysteresisSection, RigConfig

# --------------------------------------------------------------------------- converters


def quantize(x: np.ndarray, bits: int, range_v: float) -> np.ndarray:
    """Round to the nearest level of a ``bits``-bit converter over ``+/-range_v`` and clip to it."""
    lsb = 2.0 * range_v / (2**bits)
    levels = np.clip(np.round(x / lsb), -(2 ** (bits - 1)), 2 ** (bits - 1) - 1)
    return levels * lsb


def hold(x: np.ndarray, factor: int) -> np.ndarray:
    """Zero-order hold: repeat every sample ``factor`` times (a DAC between updates)."""
    return np.repeat(x, factor) if factor > 1 else x


# --------------------------------------------------------------------------- amplifier


def slew_rate_v_per_s(cfg: RigConfig) -> float:
    """The amplifier's current limit into the stack's capacitance: ``dV/dt <= I / C``.

    EPA-102: 200 mA; a PSt 150 stack of a few uF: some 30-60 V per millisecond.
    """
    return cfg.amplifier.current_limit_ma * 1e-3 / (cfg.actuator.capacitance_uf * 1e-6)


#: ``v[k] = v[k-1] + clip(u[k] - v[k-1], -max_step, max_step)``: see :func:`piezopress.signals.rate_limit`.
slew_limit = signals.rate_limit


# --------------------------------------------------------------------------- hysteresis


def hysteresis_operators(cfg: HysteresisSection) -> tuple[np.ndarray, np.ndarray]:
    """Thresholds and weights of the play operators; weights sum to one."""
    r = np.linspace(0.0, cfg.r_max_v, cfg.n_operators + 1)[1:]
    w = np.exp(-r / cfg.r_scale_v)
    w = (1.0 - cfg.elastic_fraction) * w / w.sum()
    return np.concatenate([[0.0], r]), np.concatenate([[cfg.elastic_fraction], w])


def saturate(u: np.ndarray, k: float, full_scale_v: float) -> np.ndarray:
    """The static map ``U tanh(k u / U) / tanh(k)``: slope 1 at the bottom, flatter at the top."""
    if k <= 0:
        return u
    return full_scale_v * np.tanh(k * u / full_scale_v) / np.tanh(k)


def hysteresis(
    v: np.ndarray,
    cfg: HysteresisSection,
    full_scale_v: float,
    play_state: np.ndarray | None = None,
    rate_v_per_s: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Hysteresis of the stack: ``(h, play state after the last sample)``.

    Rate dependence (a rate-dependent Prandtl-Ishlinskii model): every threshold grows by
    ``rate_v_per_kv_s * rate / 1000`` where ``rate`` is the drive rate felt by the stack
    (V/s), the elastic operator included, so the loop widens in proportion to the drive
    rate while the static loop is unchanged.
    """
    r, w = hysteresis_operators(cfg)
    y0 = 0.0 if play_state is None else play_state
    if not cfg.enabled:
        return v, np.broadcast_to(np.asarray(y0, dtype=float), r.shape).copy()
    widen = None
    if rate_v_per_s is not None and cfg.rate_v_per_kv_s > 0:
        widen = cfg.rate_v_per_kv_s * rate_v_per_s / 1000.0
    y = operators.play(v, r, y0, widen=widen)
    return saturate(y @ w, cfg.saturation, full_scale_v), y[-1].copy()


# --------------------------------------------------------------------------- linear stages


@dataclass(frozen=True)
class Modal:
    """A strictly proper transfer function as first-order complex modes: ``sum c_k / (s - p_k)``."""

    poles: np.ndarray
    residues: np.ndarray

    @classmethod
    def second_order(cls, wn: float, zeta: float) -> Modal:
        """``wn^2 / (s^2 + 2 zeta wn s + wn^2)``."""
        if abs(zeta - 1.0) < 1e-6:  # a double pole has no partial fractions; split it
            zeta = 1.0 + 1e-6
        r, p, _ = signal.residue([wn**2], [1.0, 2 * zeta * wn, wn**2])
        return cls(np.asarray(p, dtype=complex), np.asarray(r, dtype=complex))

    def run(self, u: np.ndarray, fs_hz: float, z0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Exact ZOH response ``y[n]`` (from inputs before ``n``) and the state after the last input."""
        dt = 1.0 / fs_hz
        y = np.zeros(u.size)
        z_end = np.empty_like(z0)
        for i, (p, c) in enumerate(zip(self.poles, self.residues)):
            lam = np.exp(p * dt)
            beta = c * (lam - 1.0) / p
            w, _ = signal.lfilter([beta], [1.0, -lam], u.astype(complex), zi=[lam * z0[i]])
            z = np.concatenate([[z0[i]], w[:-1]])
            y += z.real
            z_end[i] = w[-1]
        return y, z_end

    def rest_state(self, u0: float) -> np.ndarray:
        """The state at rest under a constant input ``u0``."""
        return -self.residues / self.poles * u0


@lru_cache(maxsize=64)
def _modes(
    wn1: float, z1: float, on1: bool, wn2: float, z2: float, share2: float, on2: bool
) -> tuple[Modal, np.ndarray]:
    parts, weights = [], []
    if on1:
        parts.append(Modal.second_order(wn1, z1))
        weights.append(1.0 - (share2 if on2 else 0.0))
    if on2:
        parts.append(Modal.second_order(wn2, z2))
        weights.append(share2)
    if not parts:
        return Modal(np.zeros(0, complex), np.zeros(0, complex)), np.zeros(0)
    poles = np.concatenate([m.poles for m in parts])
    residues = np.concatenate([m.residues * w for m, w in zip(parts, weights)])
    return Modal(poles, residues), np.array(weights)


def modes(cfg: RigConfig) -> Modal | None:
    """The press's modes as one modal system with unit static gain (``None``: no dynamics)."""
    m, m2 = cfg.mode, cfg.mode2
    modal, _ = _modes(
        m.natural_freq_rad_s, m.damping, m.enabled, m2.natural_freq_rad_s, m2.damping, m2.share, m2.enabled
    )
    if modal.poles.size == 0:
        return None
    if not m.enabled:  # only the second mode: give it the whole response
        modal = Modal(modal.poles, modal.residues / m2.share)
    return modal


#: ``1 / (1 + tau s)`` from a given output state: see :func:`piezopress.signals.first_order`.
first_order = signals.first_order


def creep_series(cfg: CreepSection) -> tuple[np.ndarray, np.ndarray]:
    """Time constants and gains of the creep's Prony series."""
    if cfg.form == "log":
        n = int(np.ceil(2 * np.log10(cfg.tau_max_s / cfg.tau_min_s))) + 1
        taus = np.logspace(np.log10(cfg.tau_min_s), np.log10(cfg.tau_max_s), n)
        return taus, np.full(n, cfg.per_decade / 2.0)
    return np.array([cfg.pole_fast_tau_s, cfg.pole_slow_tau_s]), np.full(2, cfg.pole_gains)


def creep(x: np.ndarray, cfg: CreepSection, fs_hz: float) -> np.ndarray:
    """``x`` through ``1 + sum_k g_k / (1 + tau_k s)``, from rest (exact for a held input)."""
    if not cfg.enabled:
        return x
    taus, gains = creep_series(cfg)
    out = x.copy()
    for tau, g in zip(taus, gains):
        out += g * first_order(x, tau, fs_hz, 0.0)
    return out


def rc_lowpass(x: np.ndarray, cutoff_hz: float, fs_hz: float) -> np.ndarray:
    """First-order RC low-pass, exact for a held input, starting settled at ``x[0]``."""
    return first_order(x, 1.0 / (2.0 * np.pi * cutoff_hz), fs_hz, x[0])


def delay(x: np.ndarray, delay_s: float, fs_hz: float) -> np.ndarray:
    """``x(t - delay_s)`` by linear interpolation; before the start, the first value."""
    if delay_s <= 0:
        return x
    t = np.arange(x.size) / fs_hz
    return np.interp(t - delay_s, t, x, left=x[0])


# --------------------------------------------------------------------------- fast segment


@dataclass(frozen=True)
class FastState:
    """Physical state of the fast stages between two samples."""

    amp_v: float  # amplifier output (slew limiter)
    rate_v_per_s: float  # drive rate felt by the stack
    play: np.ndarray  # play operator outputs
    modal: np.ndarray  # complex modal coordinates
    current_env_a: float  # envelope of the drive current (interference)

    @classmethod
    def at_rest(cls, cfg: RigConfig) -> FastState:
        r, _ = hysteresis_operators(cfg.hysteresis)
        m = modes(cfg)
        return cls(0.0, 0.0, np.zeros(r.size), np.zeros(0 if m is None else m.poles.size, complex), 0.0)


@dataclass(frozen=True)
class FastOutput:
    amp_v: np.ndarray  # voltage across the stack (monitor)
    x_v: np.ndarray  # stack response after the modes, in volts-equivalent
    interference_n: np.ndarray  # artefact added to the load-cell reading, in newtons


def fast_segment(u: np.ndarray, fs_hz: float, cfg: RigConfig, state: FastState) -> tuple[FastOutput, FastState]:
    """Simulate the fast stages over ``u`` (amplifier output demanded, held per sample)."""
    dt = 1.0 / fs_hz
    if cfg.amplifier.slew_limit:
        v = slew_limit(u, state.amp_v, slew_rate_v_per_s(cfg) * dt)
    else:
        v = np.asarray(u, dtype=np.float64)
    dv = np.diff(v, prepend=state.amp_v)
    rate = first_order(np.abs(dv) * fs_hz, cfg.hysteresis.rate_tau_s, fs_hz, state.rate_v_per_s)
    h, play_end = hysteresis(v, cfg.hysteresis, cfg.actuator.drive_max_v, state.play, rate)
    m = modes(cfg)
    if m is None:
        x, modal_end = h, state.modal
    else:
        x, modal_end = m.run(h, fs_hz, state.modal)
    i_cfg = cfg.interference
    if i_cfg.enabled:
        current = cfg.actuator.capacitance_uf * 1e-6 * np.abs(dv) * fs_hz
        env = first_order(current, i_cfg.tau_s, fs_hz, state.current_env_a)
        i_max = cfg.amplifier.current_limit_ma * 1e-3
        excess = np.maximum(env / i_max - i_cfg.threshold, 0.0) / (1.0 - i_cfg.threshold)
        interference = -i_cfg.depth_n * (i_cfg.reference_distance_mm / i_cfg.distance_mm) ** 2 * excess
        env_end = float(env[-1])
    else:
        interference, env_end = np.zeros(u.size), state.current_env_a
    new = FastState(float(v[-1]), float(rate[-1]), play_end, modal_end, env_end)
    return FastOutput(v, x, interference), new


# --------------------------------------------------------------------------- whole run


def fine_windows(u: np.ndarray, fs_hz: float, cfg: RigConfig) -> tuple[int, list[tuple[int, int, int]]]:
    """Split a run into segments ``(start, stop, factor)``: factor > 1 is simulated finely.

    A run sampled at ``min_rate_hz`` or faster is one segment on its own grid. Otherwise a
    change of more than ``fast_step_v`` in one sample opens a fine window of
    ``fine_window_s`` (the slew-limited rise and the ringing that follows).
    """
    sim = cfg.simulation
    factor = max(1, int(np.ceil(sim.min_rate_hz / fs_hz - 1e-9)))
    n = u.size
    if factor == 1:
        return 1, [(0, n, 1)]
    fast = np.flatnonzero(np.abs(np.diff(u, prepend=0.0)) > sim.fast_step_v)
    width = max(1, int(np.ceil(sim.fine_window_s * fs_hz)))
    segments: list[tuple[int, int, int]] = []
    pos = 0
    for i in fast:
        if segments and segments[-1][2] > 1 and i < segments[-1][1]:
            a, _, f = segments.pop()
            segments.append((a, min(n, i + width), f))
            pos = segments[-1][1]
            continue
        if i > pos:
            segments.append((pos, i, 1))
        segments.append((i, min(n, i + width), factor))
        pos = segments[-1][1]
    if pos < n:
        segments.append((pos, n, 1))
    return factor, segments


def simulate(
    command_v: np.ndarray,
    fs_hz: float,
    preload_n: float,
    cfg: RigConfig,
    rng: np.random.Generator,
    clock_s: float = 0.0,
) -> dict[str, np.ndarray]:
    """The whole chain for one run: the measured channels ``force_n`` and ``monitor_v``
    (``clock_s``: the run's start on the rig's clock, for a sensitivity that drifts over the test)."""
    amp, daq, lc = cfg.amplifier, cfg.daq, cfg.load_cell
    dac_v = quantize(np.asarray(command_v, dtype=np.float64) / amp.gain, daq.dac_bits, daq.dac_range_v)
    u = np.clip(dac_v * amp.gain, amp.output_min_v, amp.output_max_v)
    _, segments = fine_windows(u, fs_hz, cfg)
    state = FastState.at_rest(cfg)
    parts = []
    for a, b, k in segments:
        out, state = fast_segment(hold(u[a:b], k), fs_hz * k, cfg, state)
        parts.append(FastOutput(out.amp_v[::k], out.x_v[::k], out.interference_n[::k]))
    amp_v = np.concatenate([p.amp_v for p in parts])
    x = creep(np.concatenate([p.x_v for p in parts]), cfg.creep, fs_hz)
    force = preload_n + cfg.press.gain_n_per_v * x
    if cfg.press.contact:
        force = np.maximum(force, 0.0)
    reading_n = force + np.concatenate([p.interference_n for p in parts])
    reading_n = rc_lowpass(reading_n, lc.lowpass_hz, fs_hz)
    reading_n = delay(reading_n, cfg.press.delay_s, fs_hz)
    t = np.arange(u.size) / fs_hz
    if lc.sensitivity_drift_per_h:  # the cell's gain drifts on the rig's clock
        reading_n = reading_n * (1.0 + lc.sensitivity_drift_per_h * (clock_s + t) / 3600.0)
    reading_n = reading_n + lc.drift_n_per_min * t / 60.0
    sensed_v = lc.sensitivity_v_per_n * reading_n + lc.offset_v + lc.noise_v * rng.standard_normal(u.size)
    if lc.mains_n:  # hum picked up after the load cell, at a phase of its own in every run
        hum_n = lc.mains_n * np.sin(2 * np.pi * lc.mains_hz * t + rng.uniform(0.0, 2 * np.pi))
        sensed_v = sensed_v + lc.sensitivity_v_per_n * hum_n
    adc_v = quantize(sensed_v, daq.adc_bits, daq.adc_range_v)
    return {"force_n": (adc_v - lc.offset_v) / lc.sensitivity_v_per_n, "monitor_v": amp_v}


def fast_only(cfg: RigConfig) -> RigConfig:
    """The same rig simulated entirely at its fine rate (a reference for tests)."""
    return cfg.replace(simulation={"fast_step_v": 1e-9, "fine_window_s": 10.0})
