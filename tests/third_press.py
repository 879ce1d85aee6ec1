"""A third test press, written apart from the virtual rig (``rig_physics``) and from the second
test press (``independent_press``): it imports neither (``tests/test_third_press.py`` checks
that with :mod:`ast`), and it shares none of their forms.

It is built from what the literature reports of real stacks and rigs:

- **Hysteresis: a Preisach model** (Mayergoyz, *Mathematical Models of Hysteresis*, 1991; Hu &
  Ben Mrad, *Mechatronics* 2003, on Preisach models of piezo stacks): relays on the half plane
  ``alpha >= beta`` with a density that is log-normal in the coercivity ``(alpha - beta) / 2``
  and Gaussian in the interaction field ``(alpha + beta) / 2``, plus a reversible (linear) part.
  Its minor loops change shape with where they sit (the density is not a function of
  ``alpha - beta`` alone), which no Prandtl-Ishlinskii model draws. Evaluated exactly through
  the Everett function (tabulated by cumulative sums of the density) and the memory staircase
  of dominant extrema (wiping out).
- **Creep over decades**: the irreversible (domain) part creeps, not the whole force
  (Jung & Gweon, *Rev. Sci. Instrum.* 2000; Changhai & Lining, *Sens. Actuators A* 2004, creep
  as a spectrum of relaxation times): a Prony series with time constants two per decade from
  10 ms to 300 s and weights rising as ``tau^0.15`` (a power-law creep to the hold's time scale).
- **The drive chain**: a DAC at the run's rate, a second-order amplifier (2.5 kHz, damping
  0.55: a linear amplifier driving a capacitive load, e.g. PI E-505 class data sheets), the
  stack's drive read nowhere (no monitor channel, as most rigs record).
- **The press**: one mode with an anti-resonance above it (a stack pushing a platen on a frame),
  discretised exactly (ZOH), force = preload + k x, no tension at the contact.
- **The reading**: a strain-gauge amplifier with a second-order Bessel low-pass at 1.5 kHz, a
  sigma-delta ADC whose sinc^3 decimation filter is a 1.5-sample average (a lag that scales with
  the sample period), white and 1/f-like noise, 0.005 N steps.

Hidden effects, each in a form neither other press uses (``DETECTABLE``):

- ``rate_dependent_hysteresis``: a power-law viscous term of the smoothed drive rate,
  ``c sign(dv/dt) |dv/dt|^0.5`` (V), subtracted from the drive the Preisach plane sees;
- ``amplifier_slew_limit``: a current-limited amplifier (``I_max`` into the stack's capacitance),
  the limit acting on the amplifier's own second-order state;
- ``drive_coupled_interference``: the drive *voltage* coupled capacitively into the load-cell
  lead: the reading picks up a 30 Hz high-pass of the drive voltage (N/V);
- ``logarithmic_creep``: creep of the whole force with equal weights per decade to 10^5 s
  (it keeps growing long after the hold);
- ``second_resonance``: a frame mode at 1.4-1.65 times the main one, in series with it (the
  response passes through both), not in parallel;
- ``sensor_offset_drift``: a thermal wander of the offset, two slow sines of random phase
  (periods of 17 and 41 min) on the press's own clock, not a warm-up;
- ``input_delay``: a board FIFO latency of whole samples (3-8), so the delay in seconds is the
  run's sample period times it;
- ``hysteresis_order``: a bimodal interaction field (a second population of domains switching
  late), an S in the loop;
- ``mains_pickup`` (not in the catalogue before issue 20): 50 Hz and 150 Hz hum of random phase
  per run, on the reading, at rest too;
- ``sensitivity_drift``: the load cell's gain changes over the hours of the test (on the
  press's own clock, which advances with every run and a pause between runs).

The noise of a run is drawn from the press's seed, the run's label and how often that label was
played before on this press (a repeat is new noise, as on a real press).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy import signal

from piezopress.acquisition.backend import Measurement
from piezopress.acquisition.plan import DriveLimits
from piezopress.errors import BackendError

__all__ = ["ThirdPress", "CLEAN", "DETECTABLE", "clean_press", "hidden_press", "EFFECTS"]

#: the Preisach plane's extent and grid (volts of drive)
_LO_V, _HI_V, _GRID = -60.0, 210.0, 271


def _label_seed(label: str) -> int:
    return int.from_bytes(hashlib.blake2b(label.encode(), digest_size=8).digest(), "big")


class _Everett:
    """The Everett function of a relay density on a grid: ``E(a, b)`` = the density's integral
    over ``b <= beta <= alpha <= a``, bilinear between grid points."""

    def __init__(self, density: Callable[[np.ndarray, np.ndarray], np.ndarray]):
        g = np.linspace(_LO_V, _HI_V, _GRID)
        self.g = g
        self.step = float(g[1] - g[0])
        A, B = np.meshgrid(g, g, indexing="ij")  # A: alpha (rows), B: beta (columns)
        mu = np.where(B <= A, density(A, B), 0.0) * self.step**2
        # C[i, j] = sum over alpha <= g_i and beta >= g_j (mu is zero above the diagonal)
        self.C = np.cumsum(np.cumsum(mu[:, ::-1], axis=1)[:, ::-1], axis=0)

    def __call__(self, a, b) -> np.ndarray:
        a = np.clip(np.asarray(a, float), _LO_V, _HI_V)
        b = np.clip(np.asarray(b, float), _LO_V, _HI_V)
        fa = (a - _LO_V) / self.step
        fb = (b - _LO_V) / self.step
        ia = np.clip(np.floor(fa).astype(int), 0, _GRID - 2)
        ib = np.clip(np.floor(fb).astype(int), 0, _GRID - 2)
        ta, tb = fa - ia, fb - ib
        C = self.C
        e = (
            C[ia, ib] * (1 - ta) * (1 - tb)
            + C[ia + 1, ib] * ta * (1 - tb)
            + C[ia, ib + 1] * (1 - ta) * tb
            + C[ia + 1, ib + 1] * ta * tb
        )
        return np.where(a > b, e, 0.0)

    def scalar(self, a: float, b: float) -> float:
        """``E(a, b)`` for two numbers (the staircase's corners), without numpy's overhead."""
        a = min(max(float(a), _LO_V), _HI_V)
        b = min(max(float(b), _LO_V), _HI_V)
        if a <= b:
            return 0.0
        fa, fb = (a - _LO_V) / self.step, (b - _LO_V) / self.step
        ia, ib = min(int(fa), _GRID - 2), min(int(fb), _GRID - 2)
        ta, tb = fa - ia, fb - ib
        C = self.C
        return float(
            C[ia, ib] * (1 - ta) * (1 - tb)
            + C[ia + 1, ib] * ta * (1 - tb)
            + C[ia, ib + 1] * (1 - ta) * tb
            + C[ia + 1, ib + 1] * ta * tb
        )


class PreisachMemory:
    """The state of a Preisach plane and its output for drives played one after another: the
    memory staircase ``S`` of dominant extrema (``S[0]`` the plane's bottom, then maxima and
    minima alternating), the last drive and its direction. A stack keeps its state between
    runs (its remanence): the next run starts where the last one left the plane.

    Rising from the staircase's last minimum ``m``, ``y = P(S) + 2 E(u, m)``; falling from its
    last maximum ``M`` above ``m``, ``y = P(S[:-1]) + 2 (E(M, m) - E(M, u))``, where
    ``P(S) = -E_total + 2 sum_k (E(M_k, m_(k-1)) - E(M_k, m_k))``. Passing an older extreme
    wipes out the pair it closes. Each monotone stretch is evaluated at once; a change below
    1 nV is no reversal. A new plane has every relay down (the drive came up from below it)."""

    def __init__(self, everett: _Everett):
        self.E = everett
        self.total = everett.scalar(_HI_V, _LO_V)
        self.S = [_LO_V]
        self.P: list[float | None] = [-self.total]  # P(S[: i + 1]) where S[i] is a minimum; None at maxima
        self.last = _LO_V
        self.rising = True

    def _push(self, value: float) -> None:
        S, P, E = self.S, self.P, self.E
        S.append(value)
        if len(S) % 2 == 1:  # a minimum closes the pair (M, m) above the previous minimum
            M = S[-2]
            P.append(P[-2] + 2.0 * (E.scalar(M, S[-3]) - E.scalar(M, value)))
        else:
            P.append(None)

    def _pop2(self) -> None:
        del self.S[-2:]
        del self.P[-2:]

    def run(self, v: np.ndarray) -> np.ndarray:
        """The output for the drive ``v``, continuing from the state the last drive left."""
        v = np.asarray(v, float)
        E, S = self.E, self.S
        x = np.concatenate([[self.last], np.clip(v, _LO_V, _HI_V)])
        d = np.diff(x)
        d[np.abs(d) < 1e-9] = 0.0
        direction = np.sign(d)
        if np.any(direction):  # a flat stretch keeps the direction before it
            idx = np.maximum.accumulate(np.where(direction != 0, np.arange(direction.size), 0))
            direction = direction[idx]
        direction[direction == 0] = 1.0 if self.rising else -1.0
        turns = (np.flatnonzero(direction[1:] != direction[:-1]) + 1).tolist()
        out = np.empty(v.size)
        for s, e in zip([0] + turns, turns + [direction.size]):
            seg = x[s + 1 : e + 1]  # samples s+1..e of x are v[s..e-1]
            rising = direction[s] > 0
            if s > 0 or rising != self.rising:  # a reversal at x[s]: its extreme goes on the staircase
                self._push(float(x[s]))
            pos = 0
            while pos < seg.size:
                if rising:  # S ends with a minimum
                    limit = S[-2] if len(S) >= 3 else math.inf
                    k = seg.size - pos if not math.isfinite(limit) else int(np.searchsorted(seg[pos:], limit, "left"))
                    if k:
                        out[s + pos : s + pos + k] = self.P[-1] + 2.0 * E(seg[pos : pos + k], S[-1])
                    pos += k
                    if pos < seg.size:
                        self._pop2()
                else:  # S ends with a maximum
                    limit = S[-2] if len(S) >= 4 else -math.inf
                    k = seg.size - pos if not math.isfinite(limit) else int(np.searchsorted(-seg[pos:], -limit, "left"))
                    if k:
                        M, m = S[-1], S[-2]
                        out[s + pos : s + pos + k] = self.P[-2] + 2.0 * (E.scalar(M, m) - E(M, seg[pos : pos + k]))
                    pos += k
                    if pos < seg.size:
                        self._pop2()
        self.last = float(x[-1])
        self.rising = bool(direction[-1] > 0)
        return out


def preisach(v: np.ndarray, everett: _Everett) -> np.ndarray:
    """The output of a new Preisach plane (every relay down) for the drive ``v`` (:class:`PreisachMemory`)."""
    return PreisachMemory(everett).run(v)


def _first_order(x: np.ndarray, tau_s: float, fs: float, x0: float) -> np.ndarray:
    a = math.exp(-1.0 / (fs * tau_s))
    y, _ = signal.lfilter([1.0 - a], [1.0, -a], x, zi=[a * x0])
    return y


def _settled(b: np.ndarray, a: np.ndarray, x: np.ndarray) -> np.ndarray:
    zi = signal.lfilter_zi(b, a) * x[0]
    return signal.lfilter(b, a, x, zi=zi)[0]


def _zoh(num: list[float], den: list[float], fs: float) -> tuple[np.ndarray, np.ndarray]:
    b, a, _ = signal.cont2discrete((num, den), 1.0 / fs, method="zoh")
    return np.asarray(b).ravel(), np.asarray(a).ravel()


class ThirdPress:
    """A simulated press for tests (see the module); effects switched by the constructor."""

    name = "third-test-press"

    def __init__(
        self,
        *,
        seed: int = 11,
        mode_hz: float = 780.0,
        mode_damping: float = 0.06,
        antiresonance_ratio: float = 2.3,
        reversible_share: float = 0.45,
        full_force_n: float = 340.0,
        creep_share: float = 0.05,
        noise_n: float = 0.22,
        amp_hz: float = 2500.0,
        amp_damping: float = 0.55,
        capacitance_uf: float = 6.0,
        # hidden effects (0 / None: off)
        viscous_v: float = 0.0,
        current_limit_ma: float | None = None,
        coupling_n_per_v: float = 0.0,
        log_creep_per_decade: float = 0.0,
        frame_mode_hz: float = 0.0,
        frame_mode_ratio: float = 0.0,
        frame_mode_damping: float = 0.05,
        thermal_drift_n: float = 0.0,
        fifo_samples: int = 0,
        second_population: float = 0.0,
        mains_n: float = 0.0,
        sensitivity_drift_per_h: float = 0.0,
    ):
        self.seed = int(seed)
        self.mode_hz, self.mode_damping = float(mode_hz), float(mode_damping)
        self.antiresonance_ratio = float(antiresonance_ratio)
        self.reversible_share = float(reversible_share)
        self.creep_share = float(creep_share)
        self.noise_n = float(noise_n)
        self.amp_hz, self.amp_damping = float(amp_hz), float(amp_damping)
        self.capacitance_uf = float(capacitance_uf)
        self.viscous_v = float(viscous_v)
        self.current_limit_ma = current_limit_ma
        self.coupling_n_per_v = float(coupling_n_per_v)
        self.log_creep_per_decade = float(log_creep_per_decade)
        # a frame mode given as a multiple of the stack's mode (frame_mode_ratio) or in Hz
        self.frame_mode_hz = float(frame_mode_ratio) * self.mode_hz if frame_mode_ratio else float(frame_mode_hz)
        self.frame_mode_damping = float(frame_mode_damping)
        self.thermal_drift_n = float(thermal_drift_n)
        self.fifo_samples = int(fifo_samples)
        self.second_population = float(second_population)
        self.mains_n = float(mains_n)
        self.sensitivity_drift_per_h = float(sensitivity_drift_per_h)
        self.output_v = 0.0
        self.clock_s = 0.0  # the press's own clock: every run and a pause between runs
        self._plays: dict[str, int] = {}
        self._everett = _Everett(self._density)
        self._memory = PreisachMemory(self._everett)  # the stack's state, kept from run to run
        self._phase = np.random.default_rng([self.seed, 1]).uniform(0, 2 * math.pi, 2)
        ramp = np.linspace(0.0, 150.0, 1501)
        self.stiffness_n = 1.0
        self.stiffness_n = float(full_force_n / self._static(ramp)[-1])

    # ------------------------------------------------------------------ Backend protocol

    @property
    def limits(self) -> DriveLimits:
        return DriveLimits(drive_min_v=-30.0, drive_max_v=150.0, max_sample_rate_hz=100_000.0, max_force_n=900.0)

    def describe(self) -> dict[str, Any]:
        params = {k: v for k, v in vars(self).items() if not k.startswith("_") and k not in ("output_v", "clock_s")}
        return {"backend": self.name, "simulation": "tests/third_press.py", "parameters": params}

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
        rng = np.random.default_rng([self.seed, _label_seed(label), again])
        try:
            self.output_v = float(u[0])
            force = self.simulate(u, float(sample_rate_hz), float(preload_n), rng)
        finally:
            self.zero_output()
        self.clock_s += u.size / sample_rate_hz + 5.0
        measured = Measurement(channels={"force_n": force}, info={"seed": self.seed, "label": label, "repeat": again})
        if progress is not None:
            try:
                progress(1.0)
            except KeyboardInterrupt as exc:
                exc.measurement = measured  # type: ignore[attr-defined]
                raise
        return measured

    # ------------------------------------------------------------------ physics

    def _density(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        hc = np.maximum((a - b) / 2.0, 1e-9)
        hi = (a + b) / 2.0
        # domains switching at a higher field are harder to switch: the coercivity grows with the
        # interaction field, so a minor loop's shape depends on where it sits (no PI model does that)
        hc0 = 4.0 + 0.1 * np.clip(hi, 0.0, None)
        coerc = np.exp(-0.5 * (np.log(hc / hc0) / 0.6) ** 2) / hc
        inter = np.exp(-0.5 * ((hi - 60.0) / 48.0) ** 2)
        if self.second_population:
            inter = inter + self.second_population * np.exp(-0.5 * ((hi - 118.0) / 9.0) ** 2)
        return coerc * inter

    def _static(self, v: np.ndarray) -> np.ndarray:
        """Force above the preload of the rate-independent stack, before creep and the press."""
        irr, rev = self._parts(v)
        return self.stiffness_n * (rev + irr)

    def _parts(self, v: np.ndarray, memory: PreisachMemory | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The irreversible (Preisach, scaled to volts) and reversible parts of the stroke
        (``memory``: the plane's state to continue from; a new plane when None)."""
        p = (memory or PreisachMemory(self._everett)).run(v)
        total = float(self._everett(_HI_V, _LO_V))
        p0 = -total  # every relay down
        irr = (p - p0) / (2.0 * total) * (_HI_V - _LO_V) * (1.0 - self.reversible_share) * 0.62
        rev = self.reversible_share * v
        return irr, rev

    def _amplifier(self, u: np.ndarray, fs: float) -> np.ndarray:
        lsb = 20.0 / 2**16
        v = np.round(u / 15.0 / lsb) * lsb * 15.0  # 16-bit DAC, gain 15
        if self.fifo_samples:
            v = np.concatenate([np.full(self.fifo_samples, v[0]), v[: -self.fifo_samples]])
        wn, z = 2 * math.pi * self.amp_hz, self.amp_damping
        if self.current_limit_ma is None:
            b, a = _zoh([wn * wn], [1.0, 2 * z * wn, wn * wn], fs)
            return _settled(b, a, v)
        # current-limited: the amplifier's state integrated in fine steps, dV/dt clipped to I/C
        slew = self.current_limit_ma * 1e-3 / (self.capacitance_uf * 1e-6)
        sub = max(1, int(math.ceil(8.0 * self.amp_hz / fs)))
        h = 1.0 / (fs * sub)
        x, dx = float(v[0]), 0.0
        out = np.empty(v.size)
        for i, target in enumerate(v.tolist()):
            for _ in range(sub):
                acc = wn * wn * (target - x) - 2 * z * wn * dx
                dx = min(max(dx + acc * h, -slew), slew)
                x += dx * h
            out[i] = x
        return out

    def _creep(self, irr: np.ndarray, rev: np.ndarray, fs: float) -> np.ndarray:
        taus = 10.0 ** np.arange(-2.0, math.log10(300.0) + 1e-9, 0.5)
        w = taus**0.15
        w = w / w.sum() * self.creep_share
        out = irr.copy()
        for tau, g in zip(taus, w):
            out += g * _first_order(irr, tau, fs, 0.0)
        total = out + rev
        if self.log_creep_per_decade:
            taus = 10.0 ** np.arange(-1.0, 5.0 + 1e-9, 0.5)
            g = self.log_creep_per_decade / 2.0  # two elements per decade
            extra = np.zeros_like(total)
            for tau in taus:
                extra += g * _first_order(total, tau, fs, 0.0)
            total = total + extra
        return total

    def _press(self, f: np.ndarray, fs: float) -> np.ndarray:
        wn, z = 2 * math.pi * self.mode_hz, self.mode_damping
        wz = self.antiresonance_ratio * wn
        num = [wn * wn / (wz * wz), 2 * 0.15 * wn * wn / wz, wn * wn]  # zeros at wz, damping 0.15; unit DC gain
        b, a = _zoh(num, [1.0, 2 * z * wn, wn * wn], fs)
        y = _settled(b, a, f)
        if self.frame_mode_hz:
            w2, z2 = 2 * math.pi * self.frame_mode_hz, self.frame_mode_damping
            b2, a2 = _zoh([w2 * w2], [1.0, 2 * z2 * w2, w2 * w2], fs)
            y = _settled(b2, a2, y)
        return y

    def _reading(self, force: np.ndarray, v: np.ndarray, fs: float, t: np.ndarray, rng) -> np.ndarray:
        b, a = signal.bessel(2, 2 * math.pi * 1500.0, analog=True, norm="phase")
        bd, ad = _zoh(list(b), list(a), fs)
        r = _settled(bd, ad, force)
        if self.coupling_n_per_v:
            r = r + self.coupling_n_per_v * (v - _first_order(v, 1.0 / (2 * math.pi * 30.0), fs, float(v[0])))
        clock = self.clock_s + t
        if self.sensitivity_drift_per_h:
            r = r * (1.0 + self.sensitivity_drift_per_h * clock / 3600.0)
        if self.thermal_drift_n:
            r = r + self.thermal_drift_n * (
                np.sin(2 * math.pi * clock / (17 * 60.0) + self._phase[0])
                + 0.6 * np.sin(2 * math.pi * clock / (41 * 60.0) + self._phase[1])
            )
        if self.mains_n:
            ph = rng.uniform(0, 2 * math.pi, 2)
            r = r + self.mains_n * (
                np.sin(2 * math.pi * 50.0 * t + ph[0]) + 0.35 * np.sin(2 * math.pi * 150.0 * t + ph[1])
            )
        white = rng.standard_normal(t.size)
        slow = _first_order(rng.standard_normal(t.size), 0.05, fs, 0.0) * math.sqrt(fs * 0.05)
        r = r + self.noise_n * (white + 0.3 * slow / max(1.0, math.sqrt(fs * 0.05) ** 0.5))
        r = np.convolve(r, np.array([1.0, 3.0, 3.0, 1.0]) / 8.0)[: t.size]  # sinc^3: a 1.5-sample average
        r[:3] = r[3]
        return np.round(r / 0.005) * 0.005

    def simulate(self, command_v: np.ndarray, fs: float, preload_n: float, rng: np.random.Generator) -> np.ndarray:
        v = self._amplifier(command_v, fs)
        t = np.arange(v.size) / fs
        seen = v
        if self.viscous_v:
            rate = _first_order(np.diff(v, prepend=v[0]) * fs, 1e-3, fs, 0.0)
            seen = v - self.viscous_v * np.sign(rate) * np.sqrt(np.abs(rate))
        irr, rev = self._parts(seen, self._memory)
        x = self._creep(irr, rev, fs)
        f = self._press(self.stiffness_n * x, fs)
        force = np.maximum(preload_n + f, 0.0)
        return self._reading(force, v, fs, t, rng)


#: The clean press: what varies from press to press when nothing is wrong.
NUISANCE: dict[str, tuple[float, float]] = {"mode_hz": (700.0, 900.0), "mode_damping": (0.05, 0.09)}
CLEAN: dict[str, Any] = {}

#: Magnitudes at which each hidden effect should be found, constructor keywords ``(low, high)``.
DETECTABLE: dict[str, dict[str, tuple[float, float]]] = {
    "rate_dependent_hysteresis": {"viscous_v": (0.03, 0.08)},
    "amplifier_slew_limit": {"current_limit_ma": (60.0, 150.0)},
    "drive_coupled_interference": {"coupling_n_per_v": (0.05, 0.15)},
    "logarithmic_creep": {"log_creep_per_decade": (0.006, 0.015)},
    # a frame mode between the stack's mode and its anti-resonance (2.3 times it), where the reading
    # shows it: behind the 1.5 kHz load-cell filter, a frame mode at 2.2-4 kHz (the range until
    # stop 40) rings 0.1-2.5 N peak on a 235 N step (noise 0.22 N RMS), and what else it does (4-10 %
    # more ringing of the main mode, microseconds of lag) the base chain's identification takes up;
    # from 1.7 times the mode the anti-resonance's zeros cancel its ring (1.69 and 1.71 times: no
    # peak of the steps' response, or one a model without the zeros cannot fit)
    "second_resonance": {"frame_mode_ratio": (1.4, 1.65), "frame_mode_damping": (0.02, 0.05)},
    "sensor_offset_drift": {"thermal_drift_n": (1.5, 4.0)},
    "input_delay": {"fifo_samples": (3, 8)},
    "hysteresis_order": {"second_population": (0.5, 1.2)},
    "mains_pickup": {"mains_n": (0.4, 1.2)},
    "sensitivity_drift": {"sensitivity_drift_per_h": (0.01, 0.03)},
}
EFFECTS = tuple(DETECTABLE)


def _draw(rng: np.random.Generator, ranges: dict[str, tuple[float, float]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, (lo, hi) in ranges.items():
        out[k] = int(rng.integers(int(lo), int(hi) + 1)) if isinstance(lo, int) else float(rng.uniform(lo, hi))
    return out


def clean_press(rng: np.random.Generator, **changes: Any) -> ThirdPress:
    """The clean press, its nuisances and seed drawn from ``rng`` (and ``changes`` applied)."""
    return ThirdPress(**{**CLEAN, **_draw(rng, NUISANCE), "seed": int(rng.integers(0, 2**31)), **changes})


def hidden_press(effect: str, rng: np.random.Generator) -> ThirdPress:
    """The clean press with ``effect`` on at a magnitude drawn from :data:`DETECTABLE`
    (``a+b``: two effects at once, each drawn so)."""
    draw: dict[str, Any] = {}
    for one in effect.split("+"):
        d = _draw(rng, DETECTABLE[one])
        if one in ("sensor_offset_drift", "sensitivity_drift"):
            key = next(iter(d))
            d[key] *= float(rng.choice([-1.0, 1.0]))
        draw.update(d)
    return clean_press(rng, **draw)
