"""A second test press, written apart from :mod:`piezopress.acquisition.rig_physics`.

The virtual rig and the fitted models come from the same hands: a pipeline can pass every
test on the virtual rig because it models exactly what the rig simulates. This press is
built from other physics, in other forms, so that a test on it asks whether the chain
works on a press it did not make. It must never import the virtual rig's physics or its
configuration (``rig_physics``, ``virtual_rig``, ``rig_config``); ``tests/test_independent_press.py``
checks that with :mod:`ast`. It implements the :class:`piezopress.acquisition.backend.Backend`
protocol only, so ``piezopress.pipelines.characterize.characterize(..., backend=press)`` and
``piezopress.pipelines.validate.validate(..., backend=press)`` run the default plans through it.

The signal chain, per run, on the run's own sample grid::

    command_v --DAC (16 bit over +/-10 V, gain 15)--> amplifier (first-order 20 kHz
      bandwidth; optional slew limit) = monitor_v
      --optional input delay (fractional, by linear interpolation)
      --two Bouc-Wen elements (n = 1, irregular scales; integrated exactly in the drive,
        so the loop is rate independent unless rate_dependence widens it with a
        smoothed, saturating drive rate)
      --softening static map (slope 1 at zero drive, 1 - saturation at the top)
      --creep: a chain of Kelvin-Voigt elements (parallel spring/dashpot in series)
      --press: one lightly damped mode near 1 kHz (optionally a second one above it),
        ZOH-discretised state space (scipy.signal), force = preload + stiffness * x
      --contact (no tension) --load cell: + drive-current interference (optional, no
        threshold), first-order anti-alias filter, drift (optional), noise, 14-bit ADC
      --> force_n

Deterministic per ``(seed, label)``: the same run on the same press gives the same data.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import signal

from piezopress.acquisition.backend import Measurement
from piezopress.acquisition.plan import DriveLimits
from piezopress.errors import BackendError


@dataclass(frozen=True)
class BoucWenElement:
    """``dz/dv = A - (beta sgn(dv z) + gamma) |z|`` (exponent 1), written with its
    saturation ``z_max = A / (beta + gamma)`` (V), the drive over which it saturates on a
    loading branch ``1 / (beta + gamma)`` (V), and ``back = (beta - gamma) / (beta + gamma)``
    (the shape of the branch right after a reversal; 0 < back <= 1). ``weight`` scales the
    element's share of the drive lost to hysteresis."""

    z_max_v: float
    scale_v: float
    back: float
    weight: float = 1.0

    @property
    def coefficients(self) -> tuple[float, float, float]:
        k_plus = 1.0 / self.scale_v
        return self.z_max_v * k_plus, k_plus, self.back * k_plus  # A, beta + gamma, beta - gamma


def _bouc_wen_step(z: float, dv: float, a: float, k_plus: float, k_minus: float) -> float:
    """Exact state after a drive change ``dv`` (the ODE is linear in z on each side of 0)."""
    if dv == 0.0:
        return z
    s = 1.0 if dv > 0.0 else -1.0
    dist = dv * s
    y = z * s  # in the frame where the drive rises
    if y < 0.0:
        y_eq = a / k_minus  # > 0: the branch after a reversal heads for it until z crosses 0
        to_zero = math.log1p(-y / y_eq) / k_minus
        if dist <= to_zero:
            return s * (y_eq + (y - y_eq) * math.exp(-k_minus * dist))
        dist -= to_zero
        y = 0.0
    y_eq = a / k_plus
    return s * (y_eq + (y - y_eq) * math.exp(-k_plus * dist))


def _first_order(x: np.ndarray, tau_s: float, fs_hz: float, x0: float) -> np.ndarray:
    """``1 / (1 + tau s)`` for an input held between samples, settled at ``x0`` before the start."""
    a = math.exp(-1.0 / (fs_hz * tau_s))
    b, den = np.array([0.0, 1.0 - a]), np.array([1.0, -a])
    return signal.lfilter(b, den, x, zi=signal.lfilter_zi(b, den) * x0)[0]


def _first_order_sampled(x: np.ndarray, tau_s: float, fs_hz: float, x0: float) -> np.ndarray:
    """``1 / (1 + tau s)`` of a continuous signal known at the sample instants (linear
    between them), read at the same instants: no sample of delay, only the filter's lag."""
    h = 1.0 / fs_hz
    a = math.exp(-h / tau_s)
    c = tau_s * (1.0 - a) / h
    b, den = np.array([1.0 - c, c - a]), np.array([1.0, -a])
    return signal.lfilter(b, den, x, zi=signal.lfilter_zi(b, den) * x0)[0]


def _settled_lfilter(b: np.ndarray, a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``lfilter`` started at rest under the input's first value."""
    return signal.lfilter(b, a, x, zi=signal.lfilter_zi(b, a) * x[0])[0]


def _label_seed(label: str) -> int:
    return int.from_bytes(hashlib.blake2b(label.encode("utf-8"), digest_size=8).digest(), "big")


class IndependentPress:
    """A simulated press for tests, with optional effects switched by the constructor.

    Parameters (all optional)
    -------------------------
    seed : noise seed; with the run's label it fixes every run's noise.
    input_delay_s : pure delay between the amplifier output (monitor) and the stack, 0.3-0.6 ms typical.
    rate_dependence : the loop's width grows by this factor at high drive rates
        (``1 + rate_dependence * tanh(rate / rate_saturation_v_per_s)``, rate smoothed over ``rate_tau_s``).
    interference_n_per_a : drive-coupled interference, newtons per ampere of drive current, no threshold.
    second_mode_share : share of the response through a second mode at ``second_mode_hz``.
    second_mode_damping : its damping ratio.
    drift_n_per_min : in-run drift of the load cell's offset, its rate at the start of every run (a
        warm-up: the rate decays over ``drift_tau_s``, so the drift is not a straight line).
    slew_v_per_ms : amplifier slew limit (None: none).
    log_creep_per_decade : creep that keeps growing with log time: a broad, irregular spectrum
        of Kelvin-Voigt elements, three per decade from 0.03 s to 30 000 s, with gains rising
        slowly with their time constant (about this fraction of the force per decade).
    s_curve : an S-shaped static map on top of the softening one: slope ``1 - s_curve`` at no
        drive (a soft contact), ``1 + s_curve`` mid-range and ``1 - s_curve`` again at the top
        (the stack's polarization saturating): more bends than one dead zone can follow.
    antialias_hz : the load cell's anti-alias filter; stated in :meth:`describe` under
        ``config.load_cell.lowpass_hz`` as a rig's configuration states it.

    :data:`CLEAN` and :func:`clean_press` give the press the thesis's model describes (creep
    that saturates within the 120 s hold, a mild softening); :data:`DETECTABLE` and
    :func:`hidden_press` the same press with one effect on at a detectable magnitude.
    """

    name = "independent-test-press"

    #: hysteresis of the stack: irregular, unequal elements (drive volts)
    ELEMENTS = (BoucWenElement(3.1, 9.0, 0.35, 1.0), BoucWenElement(5.3, 47.0, 0.6, 1.0))

    def __init__(
        self,
        *,
        seed: int = 7321,
        input_delay_s: float = 0.0,
        rate_dependence: float = 0.0,
        rate_saturation_v_per_s: float = 4000.0,
        rate_tau_s: float = 0.002,
        interference_n_per_a: float = 0.0,
        second_mode_share: float = 0.0,
        second_mode_hz: float = 3400.0,
        second_mode_damping: float = 0.04,
        drift_n_per_min: float = 0.0,
        drift_tau_s: float = 600.0,
        slew_v_per_ms: float | None = None,
        log_creep_per_decade: float = 0.0,
        s_curve: float = 0.0,
        antialias_hz: float = 6000.0,
        mode_hz: float = 1030.0,
        mode_damping: float = 0.09,
        saturation: float = 0.28,
        full_force_n: float = 300.0,
        creep_taus_s: tuple[float, ...] = (0.4, 6.0, 55.0, 700.0),
        creep_gains: tuple[float, ...] = (0.007, 0.009, 0.011, 0.013),
        noise_n: float = 0.3,
        capacitance_uf: float = 5.5,
        mains_n: float = 0.0,
        mains_hz: float = 59.97,
        gain_settle: float = 0.0,
        gain_settle_s: float = 1800.0,
    ):
        self.seed = int(seed)
        self._plays: dict[str, int] = {}  # a label played again draws new noise, as on a real press
        self.input_delay_s = float(input_delay_s)
        self.rate_dependence = float(rate_dependence)
        self.rate_saturation_v_per_s = float(rate_saturation_v_per_s)
        self.rate_tau_s = float(rate_tau_s)
        self.interference_n_per_a = float(interference_n_per_a)
        self.second_mode_share = float(second_mode_share)
        self.second_mode_hz = float(second_mode_hz)
        self.second_mode_damping = float(second_mode_damping)
        self.drift_n_per_min = float(drift_n_per_min)
        self.drift_tau_s = float(drift_tau_s)
        self.log_creep_per_decade = float(log_creep_per_decade)
        self.s_curve = float(s_curve)
        self.slew_v_per_ms = slew_v_per_ms
        self.mode_hz = float(mode_hz)
        self.mode_damping = float(mode_damping)
        self.saturation = float(saturation)
        self.creep_taus_s = tuple(creep_taus_s)
        self.creep_gains = tuple(creep_gains)
        self.noise_n = float(noise_n)
        self.capacitance_uf = float(capacitance_uf)
        self.mains_n = float(mains_n)
        self.mains_hz = float(mains_hz)
        self.gain_settle = float(gain_settle)
        self.gain_settle_s = float(gain_settle_s)
        self.clock_s = 0.0  # the press's clock: every run, and 3 s between runs
        self.amp_gain = 15.0
        self.amp_bandwidth_hz = 20_000.0
        self.dac_bits, self.dac_range_v = 16, 10.0
        self.adc_bits, self.adc_range_v = 14, 10.0
        self.sensitivity_v_per_n = 0.012
        self.antialias_hz = float(antialias_hz)
        self.top_v = 150.0
        self.output_v = 0.0
        # stiffness: the first loading to the top drive gives full_force_n above the preload
        ramp = np.linspace(0.0, self.top_v, 1501)
        self.stiffness_n = 1.0
        self.stiffness_n = float(full_force_n / self._static(ramp, self._hysteretic_loss(ramp))[-1])

    # ------------------------------------------------------------------ Backend protocol

    @property
    def limits(self) -> DriveLimits:
        return DriveLimits(drive_min_v=-30.0, drive_max_v=150.0, max_sample_rate_hz=100_000.0, max_force_n=800.0)

    def describe(self) -> dict[str, Any]:
        params = {k: v for k, v in vars(self).items() if k != "output_v"}
        params["elements"] = [asdict(e) for e in self.ELEMENTS]
        # what a rig's configuration file states of its chain: the load cell's analog filter
        config = {"load_cell": {"lowpass_hz": self.antialias_hz}}
        return {
            "backend": self.name,
            "simulation": "tests/independent_press.py",
            "parameters": params,
            "config": config,
        }

    def zero_output(self) -> None:
        self.output_v = 0.0

    def run(
        self,
        command_v: np.ndarray,
        sample_rate_hz: float,
        *,
        preload_n: float,
        label: str,
        progress: Callable[[float], None] | None = None,
    ) -> Measurement:
        u = np.asarray(command_v, dtype=np.float64)
        lim = self.limits
        if u.ndim != 1 or u.size < 2 or not np.all(np.isfinite(u)):
            raise BackendError(f"{self.name}: expected a finite 1-D drive of at least 2 samples")
        if u.min() < lim.drive_min_v - 1e-9 or u.max() > lim.drive_max_v + 1e-9:
            raise BackendError(
                f"{self.name}: drive {u.min():g} to {u.max():g} V outside {lim.drive_min_v:g} to {lim.drive_max_v:g} V"
            )
        if not 0.0 < sample_rate_hz <= lim.max_sample_rate_hz:
            raise BackendError(f"{self.name}: sample rate {sample_rate_hz:g} Hz outside the board's range")
        again = self._plays.get(label, 0)
        self._plays[label] = again + 1
        rng = np.random.default_rng([self.seed, _label_seed(label)] + ([again] if again else []))
        try:
            self.output_v = float(u[0])
            channels = self.simulate(u, float(sample_rate_hz), float(preload_n), rng)
        finally:
            self.zero_output()
            self.clock_s += u.size / sample_rate_hz + 3.0
        measured = Measurement(channels=channels, info={"seed": self.seed, "label": label})
        if progress is not None:
            try:
                progress(1.0)
            except KeyboardInterrupt as exc:  # Ctrl-C once everything is measured: kept whole (the backend kit's rule)
                exc.measurement = measured
                raise
        return measured

    # ------------------------------------------------------------------ physics

    def _amplifier(self, u: np.ndarray, fs: float) -> np.ndarray:
        lsb = 2.0 * self.dac_range_v / 2**self.dac_bits
        dac = (
            np.clip(np.round(u / self.amp_gain / lsb), -(2 ** (self.dac_bits - 1)), 2 ** (self.dac_bits - 1) - 1) * lsb
        )
        v = dac * self.amp_gain
        if self.slew_v_per_ms is not None:
            step = self.slew_v_per_ms * 1e3 / fs
            out = np.empty_like(v)
            prev = v[0]
            for i, target in enumerate(v.tolist()):
                prev += min(max(target - prev, -step), step)
                out[i] = prev
            v = out
        tau = 1.0 / (2.0 * math.pi * self.amp_bandwidth_hz)
        at_instants = _first_order(v, tau, fs, float(v[0]))
        # what the stack sees over each sample interval is the amplifier's mean over it (the
        # held DAC value less what the 8 us lag still owes), not its value at the interval's
        # start: passing samples on as held values would add a whole sample of delay per stage
        owed = (at_instants - v) * (tau * fs) * (1.0 - math.exp(-1.0 / (fs * tau)))
        return at_instants, v + owed

    def _hysteretic_loss(self, v: np.ndarray) -> np.ndarray:
        """Drive lost to hysteresis, ``sum_i weight_i z_i`` (V), from rest at ``v[0]``."""
        total = np.zeros(v.size)
        dv = np.diff(v, prepend=v[0]).tolist()
        for e in self.ELEMENTS:
            a, kp, km = e.coefficients
            z = 0.0
            out = [0.0] * v.size
            for i, d in enumerate(dv):
                if d != 0.0:
                    z = _bouc_wen_step(z, d, a, kp, km)
                out[i] = z
            total += e.weight * np.asarray(out)
        return total

    def _static(self, v: np.ndarray, loss: np.ndarray) -> np.ndarray:
        """Force above the preload (before creep and modes) for a drive and its hysteretic loss."""
        x = v - loss
        k = self.saturation / (2.0 * self.top_v)  # slope 1 - saturation at the top drive
        y = np.where(x > 0.0, x - k * x * x, x)
        if self.s_curve:  # slope 1 - s cos(2 pi x / top): soft at both ends, steep mid-range
            xc = np.clip(x, 0.0, self.top_v)
            y = y - self.s_curve * self.top_v / (2.0 * math.pi) * np.sin(2.0 * math.pi * xc / self.top_v)
        return self.stiffness_n * y

    def _creep(self, f: np.ndarray, fs: float) -> np.ndarray:
        """Kelvin-Voigt chain: each element adds ``g_i`` of the force after ``tau_i`` (from rest)."""
        out = f.copy()
        for tau, g in self._creep_elements():
            out += g * _first_order(f, tau, fs, 0.0)
        return out

    def _creep_elements(self) -> list[tuple[float, float]]:
        elements = list(zip(self.creep_taus_s, self.creep_gains))
        if self.log_creep_per_decade > 0.0:
            # three per decade, irregularly placed (a fixed jitter), gains rising as tau^0.05
            exps = np.arange(np.log10(0.03), np.log10(3e4) + 1e-9, 1.0 / 3.0)
            exps = exps + 0.08 * np.sin(7.3 * np.arange(exps.size))
            taus = 10.0**exps
            gains = (taus / 10.0) ** 0.05
            gains = gains / gains.mean() * self.log_creep_per_decade / 3.0
            elements += list(zip(taus.tolist(), gains.tolist()))
        return elements

    def _modes(self, f: np.ndarray, fs: float) -> np.ndarray:
        """Unit-gain mode(s) as a ZOH-discretised state space, started at rest under ``f[0]``."""

        def mode(hz: float, zeta: float) -> tuple[np.ndarray, np.ndarray]:
            wn = 2.0 * math.pi * hz
            A = np.array([[0.0, 1.0], [-wn * wn, -2.0 * zeta * wn]])
            B = np.array([[0.0], [wn * wn]])
            C = np.array([[1.0, 0.0]])
            ad, bd, cd, dd, _ = signal.cont2discrete((A, B, C, np.zeros((1, 1))), 1.0 / fs, method="zoh")
            num, den = signal.ss2tf(ad, bd, cd, dd)
            return np.asarray(num[0]), np.asarray(den)

        share2 = self.second_mode_share
        y = (1.0 - share2) * _settled_lfilter(*mode(self.mode_hz, self.mode_damping), f)
        if share2 > 0.0:
            y += share2 * _settled_lfilter(*mode(self.second_mode_hz, self.second_mode_damping), f)
        return y

    def simulate(
        self, command_v: np.ndarray, fs: float, preload_n: float, rng: np.random.Generator
    ) -> dict[str, np.ndarray]:
        amp, held = self._amplifier(command_v, fs)
        t = np.arange(amp.size) / fs
        v = held if self.input_delay_s <= 0.0 else np.interp(t - self.input_delay_s, t, held, left=held[0])
        loss = self._hysteretic_loss(v)
        if self.rate_dependence > 0.0:
            rate = _first_order(np.abs(np.diff(v, prepend=v[0])) * fs, self.rate_tau_s, fs, 0.0)
            loss = loss * (1.0 + self.rate_dependence * np.tanh(rate / self.rate_saturation_v_per_s))
        f = self._modes(self._creep(self._static(v, loss), fs), fs)
        force = np.maximum(preload_n + f, 0.0)
        if self.interference_n_per_a:
            current_a = self.capacitance_uf * 1e-6 * np.diff(v, prepend=v[0]) * fs
            force = force - self.interference_n_per_a * _first_order(current_a, 2e-4, fs, 0.0)
        reading = _first_order_sampled(force, 1.0 / (2.0 * math.pi * self.antialias_hz), fs, float(force[0]))
        drift = (
            self.drift_n_per_min / 60.0 * self.drift_tau_s * -np.expm1(-t / self.drift_tau_s)
        )  # rate drift_n_per_min at t = 0
        if self.gain_settle:  # the bridge's gain settles by gain_settle over the test (its own clock)
            reading = reading * (1.0 - self.gain_settle * np.expm1(-(self.clock_s + t) / self.gain_settle_s))
        reading = reading + drift + self.noise_n * rng.standard_normal(amp.size)
        if self.mains_n:  # 60 Hz mains, a little off, with a third harmonic; its size wanders slowly
            phase = rng.uniform(0.0, 2.0 * math.pi, 2)
            size = self.mains_n * (1.0 + 0.2 * np.sin(2.0 * math.pi * 0.05 * t + phase[0]))
            w = 2.0 * math.pi * self.mains_hz * t + phase[1]
            reading = reading + size * (np.sin(w) + 0.4 * np.sin(3.0 * w + 1.0))
        lsb = 2.0 * self.adc_range_v / 2**self.adc_bits
        volts = (
            np.clip(
                np.round(self.sensitivity_v_per_n * reading / lsb),
                -(2 ** (self.adc_bits - 1)),
                2 ** (self.adc_bits - 1) - 1,
            )
            * lsb
        )
        monitor = amp + 0.02 * rng.standard_normal(amp.size)
        return {"force_n": volts / self.sensitivity_v_per_n, "monitor_v": monitor}


# ---------------------------------------------------------------------- clean press, hidden effects

#: The press the thesis's model describes, in this module's forms: Bouc-Wen hysteresis with a
#: mild softening, Kelvin-Voigt creep that has saturated long before the end of a 120 s hold,
#: one mode near 1 kHz, the anti-alias filter, noise and converters.
CLEAN: dict[str, Any] = {
    "creep_taus_s": (0.5, 4.0, 20.0),
    "creep_gains": (0.008, 0.012, 0.015),
    "saturation": 0.12,
}
#: What changes from press to press when nothing is wrong: drawn for every clean or hidden press.
NUISANCE: dict[str, tuple[float, float]] = {"mode_hz": (950.0, 1100.0), "mode_damping": (0.07, 0.11)}

#: Magnitudes at which ``diagnose`` is meant to find each effect of the catalogue on this press
#: (constructor keywords, each ``(low, high)``; a drift is drawn with a random sign). The
#: effects are this module's forms, not the virtual rig's:
#:
#: - ``rate_dependent_hysteresis``: the Bouc-Wen loss scaled by ``1 + r tanh(rate / 4 kV/s)``
#:   (a smoothed, saturating rate; the virtual rig widens play thresholds linearly with rate);
#: - ``amplifier_slew_limit``: a rate limiter ahead of the amplifier's 20 kHz bandwidth;
#: - ``drive_coupled_interference``: newtons per ampere of the signed drive current, no threshold
#:   (the virtual rig: a dip above a threshold of the unsigned current's envelope);
#: - ``logarithmic_creep``: a broad, irregular Kelvin-Voigt spectrum to 30 000 s on top of the
#:   saturating creep;
#: - ``second_resonance``: a second mode at 2.5-4.5 kHz with its own damping;
#: - ``sensor_offset_drift``: a warm-up drift in every run (rate decaying over 10 min), with
#:   no rest run in the plan (:data:`PLAN_WITHOUT_REST`);
#: - ``input_delay``: a delay between the amplifier and the stack (the virtual rig delays the reading);
#: - ``hysteresis_order``: an S-shaped static map (soft contact, steep middle, saturating top);
#: - ``mains_pickup``: 60 Hz mains a little off (59.97 Hz) with a third harmonic, its size
#:   wandering by 20 % over 20 s (the virtual rig: a steady 50 Hz line);
#: - ``sensitivity_drift``: the gain settles by 2-5 % over half an hour of the test's clock (the
#:   virtual rig: a steady drift), characterized with :data:`PLAN_WITH_REPEAT`.
DETECTABLE: dict[str, dict[str, tuple[float, float]]] = {
    "rate_dependent_hysteresis": {"rate_dependence": (0.3, 1.0)},
    "amplifier_slew_limit": {"slew_v_per_ms": (20.0, 60.0)},
    "drive_coupled_interference": {"interference_n_per_a": (30.0, 100.0)},
    "logarithmic_creep": {"log_creep_per_decade": (0.008, 0.02)},
    "second_resonance": {
        "second_mode_share": (0.1, 0.3),
        "second_mode_hz": (2500.0, 4500.0),
        "second_mode_damping": (0.02, 0.06),
    },
    "sensor_offset_drift": {"drift_n_per_min": (4.0, 10.0)},
    "input_delay": {"input_delay_s": (1e-4, 6e-4)},
    "hysteresis_order": {"s_curve": (0.2, 0.5)},
    "mains_pickup": {"mains_n": (0.6, 1.5)},
    "sensitivity_drift": {"gain_settle": (0.02, 0.05)},
}

#: The default characterization plan without its rest runs (``protocols/characterize.toml``
#: less ``rest-before-120s`` and ``rest-120s``): a drift has to be found inside the other runs.
PLAN_WITHOUT_REST = Path(__file__).resolve().parent / "plans" / "characterize-no-rest.toml"


def _draw(rng: np.random.Generator, ranges: dict[str, tuple[float, float]]) -> dict[str, float]:
    return {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in ranges.items()}


def clean_press(rng: np.random.Generator, **changes: Any) -> IndependentPress:
    """The clean press with its nuisances and noise seed drawn from ``rng`` (and ``changes`` applied)."""
    return IndependentPress(**{**CLEAN, **_draw(rng, NUISANCE), "seed": int(rng.integers(0, 2**31)), **changes})


def hidden_press(effect: str, rng: np.random.Generator) -> IndependentPress:
    """The clean press with ``effect`` on at a magnitude drawn from :data:`DETECTABLE`
    (``a+b``: two effects at once, each drawn so)."""
    draw: dict[str, float] = {}
    for one in effect.split("+"):
        d = _draw(rng, DETECTABLE[one])
        if one in ("sensor_offset_drift", "sensitivity_drift"):
            key = next(iter(d))
            d[key] *= float(rng.choice([-1.0, 1.0]))
        draw.update(d)
    return clean_press(rng, **draw)


#: The default characterization plan with its slowest triangle played again at the end: a
#: drifting sensitivity shows only between two runs of the same drive, apart in time.
PLAN_WITH_REPEAT = Path(__file__).resolve().parent / "plans" / "characterize-repeat.toml"


def plan_for(effect: str) -> Path | None:
    """The plan a hidden effect (or pair) is characterized with (``None``: the default plan)."""
    if "sensitivity_drift" in effect.split("+"):
        return PLAN_WITH_REPEAT
    return PLAN_WITHOUT_REST if "sensor_offset_drift" in effect.split("+") else None
