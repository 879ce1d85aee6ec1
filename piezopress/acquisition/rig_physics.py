"""Physics of the virtual press: pure functions over sampled signals.

The signal chain, in order (each stage a function below)::

    command_v --DAC (quantize, hold)--> amplifier (gain, output limits)
              --stack: hysteresis h(v), creep (Prony series in log time)
              --press: force = preload + gain_n_per_v * mode(h) (second-order mode)
              --load cell: sensitivity, RC low-pass, noise, ADC (quantize, clip) --> force_n

Every function takes explicit parameters and returns arrays; randomness comes only from
the ``numpy.random.Generator`` passed in. Nothing sleeps.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from piezopress import operators
from piezopress.acquisition.rig_config import CreepSection, HysteresisSection, ModeSection


def quantize(x: np.ndarray, bits: int, range_v: float) -> np.ndarray:
    """Round to the nearest level of a ``bits``-bit converter over ``+/-range_v`` and clip to it."""
    lsb = 2.0 * range_v / (2**bits)
    levels = np.clip(np.round(x / lsb), -(2 ** (bits - 1)), 2 ** (bits - 1) - 1)
    return levels * lsb


def hold(x: np.ndarray, factor: int) -> np.ndarray:
    """Zero-order hold: repeat every sample ``factor`` times (a DAC between updates)."""
    return np.repeat(x, factor) if factor > 1 else x


def hysteresis_operators(cfg: HysteresisSection) -> tuple[np.ndarray, np.ndarray]:
    """Thresholds and weights of the play operators; weights sum to one."""
    n_play = cfg.n_operators
    r = np.linspace(0.0, cfg.r_max_v, n_play + 1)[1:]
    w = np.exp(-r / cfg.r_scale_v)
    w = (1.0 - cfg.elastic_fraction) * w / w.sum()
    return np.concatenate([[0.0], r]), np.concatenate([[cfg.elastic_fraction], w])


def hysteresis(v: np.ndarray, cfg: HysteresisSection, full_scale_v: float) -> np.ndarray:
    """Asymmetric, saturating, rate-independent hysteresis (see :class:`HysteresisSection`).

    Output in volts-equivalent: for a linear stack (disabled) it is ``v`` itself.
    """
    if not cfg.enabled:
        return v
    r, w = hysteresis_operators(cfg)
    u = operators.play(v, r, 0.0) @ w
    k = cfg.saturation
    if k > 0:
        u = full_scale_v * np.tanh(k * u / full_scale_v) / np.tanh(k)
    return u


def creep_series(cfg: CreepSection) -> tuple[np.ndarray, float]:
    """Time constants of the Prony series and the gain of each term."""
    decades = np.log10(cfg.tau_max_s / cfg.tau_min_s)
    n = int(np.ceil(2 * decades)) + 1
    return np.logspace(np.log10(cfg.tau_min_s), np.log10(cfg.tau_max_s), n), cfg.per_decade / 2.0


def creep(h: np.ndarray, cfg: CreepSection, fs_hz: float) -> np.ndarray:
    """``h`` through ``1 + sum_k g / (1 + tau_k s)`` (exact for a held input), from rest."""
    if not cfg.enabled or cfg.per_decade == 0:
        return h
    taus, g = creep_series(cfg)
    out = h.copy()
    for tau in taus:
        a = np.exp(-1.0 / (fs_hz * tau))
        out += g * signal.lfilter([1.0 - a], [1.0, -a], h)
    return out


def mode_filter(cfg: ModeSection, fs_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """ZOH-discretised ``wn^2 / (s^2 + 2 zeta wn s + wn^2)`` at ``fs_hz``: ``(b, a)`` for lfilter."""
    import control

    wn, z = cfg.natural_freq_rad_s, cfg.damping
    sys_c = control.tf([wn**2], [1.0, 2 * z * wn, wn**2])
    sys_d = control.sample_system(sys_c, 1.0 / fs_hz, method="zoh")
    num, den = control.tfdata(sys_d)
    return np.atleast_1d(np.squeeze(num[0][0])), np.atleast_1d(np.squeeze(den[0][0]))


def mode(x: np.ndarray, cfg: ModeSection, fs_hz: float) -> np.ndarray:
    """``x`` through the mechanical mode, starting at rest at ``x[0]``."""
    if not cfg.enabled:
        return x
    b, a = mode_filter(cfg, fs_hz)
    zi = signal.lfilter_zi(b, a) * x[0]
    y, _ = signal.lfilter(b, a, x, zi=zi)
    return y


def rc_lowpass(x: np.ndarray, cutoff_hz: float, fs_hz: float) -> np.ndarray:
    """First-order RC low-pass, exact for a held input, starting settled at ``x[0]``."""
    a = np.exp(-2.0 * np.pi * cutoff_hz / fs_hz)
    y, _ = signal.lfilter([1.0 - a], [1.0, -a], x, zi=[a * x[0]])
    return y
