"""The parameter bundle in memory: one checked home for the models a bundle describes.

A bundle document (JSON: a ``hysteresis`` section, optionally ``creep`` and ``shaper``, and
the ``compensation`` settings) is read once, by :meth:`Bundle.from_dict`, which checks it as
a run is checked: schema version, required sections, every model number finite and inside
its physical range, an invertible hysteresis model, a creep compensator with ``K_c > 0``,
shaper impulses summing to 1, sane compensation settings and one output unit across the
sections. Every problem is one line naming the file, the section and key, and what was
expected. The models are then built from it here, and nowhere else:
:meth:`Bundle.compensator`, :meth:`Bundle.forward_model`, :meth:`Bundle.remove_creep`,
:meth:`Bundle.extended`. What depends on where the bundle is used (the sample rate the
creep compensator runs at, a reference's length, the rig's drive range, a run's unit) is
checked there: :meth:`Bundle.check_reference`, :meth:`Bundle.check_drive_range`,
:meth:`Bundle.check_unit`. Files and digests are the pipeline's
(:mod:`piezopress.pipelines.bundle`).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from piezopress import units
from piezopress.analysis.compensation import RATE_TAU_S, Compensator, RateDependence
from piezopress.analysis.creep import CreepModel
from piezopress.analysis.hysteresis import (
    FAMILY_DUHEM,
    FAMILY_PLANE,
    FAMILY_TITLES,
    DuhemElements,
    PIModel,
    PreisachPlane,
    rest_offset,
)
from piezopress.analysis.mode_fit import SERIES_CHAINS, lowpass_delay_group_delay_s
from piezopress.analysis.shaper import Shaper, design_shaper
from piezopress.errors import CompensatorUnstableError, FitError, PiezopressError

BUNDLE_VERSION = 1
SECTIONS = ("hysteresis", "creep", "shaper")

#: Physical ranges every bundle number is checked against (anything beyond is a corrupted
#: file, not a press): drive voltages (V) ...
MAX_DRIVE_V = 2000.0
#: ... outputs and dead-zone thresholds, in the output unit (N or µm) ...
MAX_OUTPUT = 1e7
#: ... play and dead-zone weights (output unit per V, and per output unit) ...
MAX_WEIGHT = 1e6
#: ... creep gains (dimensionless) and time constants (s): the static gain K_c ...
MAX_CREEP_GAIN = 1e3
#: ... and each element's gain, which a fit may set large in cancelling pairs (the thesis's
#: "poles" form on a slew-limited press gave 1.8e3 with a fitted bundle that predicts well;
#: the compensator's stability is checked on its own).
MAX_CREEP_ELEMENT_GAIN = 1e6
CREEP_TAU_S = (1e-7, 1e9)
#: ... a mode's natural frequency (rad/s) and a shaper's span (s) ...
MAX_WN_RAD_S = 1e8
MAX_SHAPER_S = 1.0
#: ... reference rate limits (output unit per s) and slew limits (V/s).
MAX_RATE = 1e12
#: The drive's lead (s): the mode's delay and an input delay, milliseconds on any press.
MAX_LEAD_S = 1.0
#: The largest input delay's lead in samples a bundle may hold (a board's FIFO is a few to a few hundred).
MAX_LEAD_SAMPLES = 1e4
#: Where a reference is known, the lead must be shorter than this fraction of its duration
#: (a longer lead plays the reference's end from the start: a constant drive).
LEAD_MAX_FRACTION = 0.1
#: The shaper's impulses sum to 1 within this.
SHAPER_SUM_TOL = 1e-6
#: A stored inverse model agrees with the one computed from the forward parameters within this (relative).
INVERSE_RTOL = 1e-6
#: The most operators a model may have.
MAX_OPERATORS = 10_000


class BundleError(PiezopressError, ValueError):
    """A bundle or section file is missing, unreadable or inconsistent."""


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)


class _Checker:
    """Checks a document's values; every failure is one line ``source: section.key = value; expected ...``."""

    def __init__(self, source: str):
        self.source = source

    def fail(self, where: str, value: Any, expected: str) -> None:
        shown = repr(value)
        if len(shown) > 60:
            shown = shown[:57] + "..."
        raise BundleError(f"{self.source}: {where} = {shown}; expected {expected}")

    def mapping(self, doc: Any, where: str, what: str) -> Mapping[str, Any]:
        if not isinstance(doc, Mapping):
            kind = {list: "a JSON list", str: "a string", type(None): "null"}.get(type(doc), type(doc).__name__)
            raise BundleError(f"{self.source}: {where} is {kind}; expected {what}")
        return doc

    def get(self, d: Mapping[str, Any], where: str, key: str) -> Any:
        if key not in d:
            raise BundleError(
                f"{self.source}: {where} has no key {key!r}; expected it (a bundle made by `piezopress fit` or "
                "`bundle`)"
            )
        return d[key]

    def number(
        self, value: Any, where: str, lo: float, hi: float, what: str, *, lo_open: bool = False, hi_open: bool = False
    ) -> float:
        if not _is_number(value) or not math.isfinite(float(value)):
            self.fail(where, value, f"a finite number ({what})")
        v = float(value)
        if (v <= lo if lo_open else v < lo) or (v >= hi if hi_open else v > hi):
            self.fail(where, value, f"{what} within {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}")
        return v

    def optional(self, value: Any, where: str, lo: float, hi: float, what: str, **kw) -> float | None:
        return None if value is None else self.number(value, where, lo, hi, what, **kw)

    def numbers(
        self, value: Any, where: str, lo: float, hi: float, what: str, *, min_len: int = 1
    ) -> tuple[float, ...]:
        if not isinstance(value, (list, tuple)) or not min_len <= len(value) <= MAX_OPERATORS:
            self.fail(where, value, f"a list of {min_len} to {MAX_OPERATORS} numbers ({what})")
        return tuple(self.number(v, f"{where}[{i}]", lo, hi, what) for i, v in enumerate(value))


def _unit(c: _Checker, value: Any, where: str) -> str:
    if not isinstance(value, str) or value not in units.LABELS:  # (a list is no key of a mapping: checked first)
        c.fail(where, value, f"an output unit code, one of {', '.join(units.LABELS)}")
    return str(value)


def check_hysteresis(c: _Checker, sec: Mapping[str, Any]) -> PIModel:
    """The hysteresis section's model, checked: ranges, the model's structure, invertibility."""
    m = c.mapping(c.get(sec, "hysteresis", "model"), "hysteresis.model", "a mapping (the PI model)")
    w = "hysteresis.model"
    if c.get(m, w, "input_unit") != "V":
        c.fail(f"{w}.input_unit", m["input_unit"], "'V' (the drive is in volts)")
    ou = _unit(c, c.get(m, w, "output_unit"), f"{w}.output_unit")
    col = sec.get("output_column")
    if col is not None and units.COLUMN_UNITS.get(col) != ou:
        c.fail(
            "hysteresis.output_column",
            col,
            f"the column of the model's unit {ou!r} "
            f"({', '.join(k for k, v in units.COLUMN_UNITS.items() if v == ou)}): one unit across the section",
        )
    r = c.numbers(c.get(m, w, "play_thresholds"), f"{w}.play_thresholds", 0.0, MAX_DRIVE_V, "thresholds in V")
    pw = c.numbers(
        c.get(m, w, "play_weights"), f"{w}.play_weights", -MAX_WEIGHT, MAX_WEIGHT, f"weights in {units.label(ou)}/V"
    )
    d = c.numbers(
        c.get(m, w, "dead_zone_thresholds"),
        f"{w}.dead_zone_thresholds",
        -MAX_OUTPUT,
        MAX_OUTPUT,
        f"thresholds in {units.label(ou)}",
    )
    s = c.numbers(
        c.get(m, w, "dead_zone_weights"), f"{w}.dead_zone_weights", -MAX_WEIGHT, MAX_WEIGHT, "dimensionless weights"
    )
    if len(r) != len(pw):
        c.fail(f"{w}.play_weights", list(pw), f"one weight per play threshold ({len(r)})")
    if len(d) != len(s):
        c.fail(f"{w}.dead_zone_weights", list(s), f"one weight per dead-zone threshold ({len(d)})")
    if r[0] != 0.0 or any(b <= a for a, b in zip(r, r[1:])):
        c.fail(f"{w}.play_thresholds", list(r), "thresholds starting at 0 and increasing")
    if 0.0 not in d or any(b <= a for a, b in zip(d, d[1:])):
        c.fail(f"{w}.dead_zone_thresholds", list(d), "increasing thresholds that contain 0")
    x0 = c.number(c.get(m, w, "x0_v"), f"{w}.x0_v", -MAX_DRIVE_V, MAX_DRIVE_V, "the rest drive in V")
    yk = f"y0_{units.key(ou)}"
    y0 = c.number(c.get(m, w, yk), f"{w}.{yk}", -MAX_OUTPUT, MAX_OUTPUT, f"the rest output in {units.label(ou)}")
    partial = np.cumsum(pw)
    if pw[0] <= 0 or np.any(partial <= 0):
        c.fail(f"{w}.play_weights", list(pw), "an invertible model: the first weight and every partial sum > 0")
    i0 = d.index(0.0)
    slopes_up = np.cumsum(s[i0:])
    slopes_down = np.cumsum(s[i0::-1])
    if s[i0] <= 0 or np.any(slopes_up <= 0) or np.any(slopes_down <= 0):
        c.fail(
            f"{w}.dead_zone_weights",
            list(s),
            "an invertible model: the weight at threshold 0 and every slope outward from it > 0",
        )
    family = m.get("family", "modified_pi")
    if not isinstance(family, str) or family not in FAMILY_TITLES:  # (``[]`` raised TypeError: unhashable)
        c.fail(f"{w}.family", family, f"a model family, one of {', '.join(FAMILY_TITLES)}")
    plane = check_plane(c, m, w, ou) if family == FAMILY_PLANE else None
    duhem = check_duhem(c, m, w, ou) if family == FAMILY_DUHEM else None
    for key, owner in (("preisach_plane", FAMILY_PLANE), ("duhem_elements", FAMILY_DUHEM)):
        if family != owner and m.get(key) is not None:
            c.fail(f"{w}.{key}", "...", f"no {key} in the {family!r} family (or family {owner!r})")
    model = PIModel(r, pw, d, s, x0, y0, "V", ou, plane, duhem)
    if plane is not None and plane.max_slope() + sum(pw) <= 0:
        c.fail(f"{w}.play_weights", list(pw), "an increasing model")
    if duhem is not None and duhem.least_slope() >= pw[0]:
        c.fail(
            f"{w}.duhem_elements.weights",
            list(duhem.weights),
            f"an increasing model: twice the negative weights' sum below the first play weight {pw[0]:g}",
        )
    inv = model.inverse_parameters()
    if not all(np.all(np.isfinite(v)) for v in inv.values()):
        c.fail(f"{w}.play_weights", list(pw), "weights whose inverse is finite")
    stored = m.get("inverse")
    if stored is not None:  # written for people to read; the compensator recomputes it, so it must agree
        stored = c.mapping(stored, f"{w}.inverse", "a mapping (the inverse model's thresholds and weights)")
        for key, value in inv.items():
            got = c.numbers(
                c.get(stored, f"{w}.inverse", key),
                f"{w}.inverse.{key}",
                -MAX_OUTPUT * MAX_WEIGHT,
                MAX_OUTPUT * MAX_WEIGHT,
                "a number of the inverse model",
            )
            if len(got) != len(value) or not np.allclose(
                got, value, rtol=INVERSE_RTOL, atol=INVERSE_RTOL * float(np.max(np.abs(value)))
            ):
                c.fail(
                    f"{w}.inverse.{key}",
                    list(got),
                    f"the inverse of the forward model's parameters (within {INVERSE_RTOL:g}: "
                    f"{', '.join(f'{v:.6g}' for v in value[:4])}{', ...' if len(value) > 4 else ''}); the file was "
                    "edited or corrupted",
                )
    # the model maps the rest drive and the drive range's ends to finite outputs, and back
    y, _ = model.forward(np.array([x0, x0 + r[-1] + 1.0, x0]))
    if not np.all(np.isfinite(y)) or not np.all(np.isfinite(model.inverse(y)[0])):
        c.fail(w, "...", "a model whose forward and inverse outputs are finite")
    return model


def check_plane(c: _Checker, m: Mapping[str, Any], w: str, ou: str) -> PreisachPlane:
    """The Preisach plane of a ``pi_preisach_plane`` model: cells with ``beta <= alpha``, a positive
    ramp width and non-negative weights (the model stays monotone, so its inverse exists)."""
    where = f"{w}.preisach_plane"
    pl = c.mapping(c.get(m, w, "preisach_plane"), where, "a mapping (the plane's cells and weights)")
    h = c.number(c.get(pl, where, "ramp_width"), f"{where}.ramp_width", 0.0, MAX_DRIVE_V, "V", lo_open=True)
    a = c.numbers(c.get(pl, where, "alpha"), f"{where}.alpha", -MAX_DRIVE_V, MAX_DRIVE_V, "rising ramps' starts in V")
    b = c.numbers(c.get(pl, where, "beta"), f"{where}.beta", -MAX_DRIVE_V, MAX_DRIVE_V, "falling ramps' ends in V")
    mu = c.numbers(
        c.get(pl, where, "weights"), f"{where}.weights", 0.0, MAX_WEIGHT, f"non-negative weights in {units.label(ou)}"
    )
    if not len(a) == len(b) == len(mu):
        c.fail(f"{where}.weights", list(mu), f"one alpha, beta and weight per cell ({len(a)} alphas, {len(b)} betas)")
    bad = [i for i, (x, y) in enumerate(zip(a, b)) if y > x]
    if bad:
        c.fail(
            f"{where}.beta[{bad[0]}]", b[bad[0]], f"at most alpha[{bad[0]}] = {a[bad[0]]:g} (a cell of the half-plane)"
        )
    levels = pl.get("levels", 0)
    if not isinstance(levels, int) or isinstance(levels, bool) or levels < 0:
        c.fail(f"{where}.levels", levels, "a non-negative integer")
    return PreisachPlane(a, b, h, mu, levels)


def check_duhem(c: _Checker, m: Mapping[str, Any], w: str, ou: str) -> DuhemElements:
    """The Duhem elements of a ``pi_duhem`` model: positive widths, finite weights, rest states
    within their widths."""
    where = f"{w}.duhem_elements"
    el = c.mapping(c.get(m, w, "duhem_elements"), where, "a mapping (the elements' widths, weights and rest states)")
    r = c.numbers(c.get(el, where, "widths"), f"{where}.widths", 0.0, MAX_DRIVE_V, "widths in V")
    if min(r) <= 0:
        c.fail(f"{where}.widths", list(r), "positive widths in V")
    cw = c.numbers(
        c.get(el, where, "weights"), f"{where}.weights", -MAX_WEIGHT, MAX_WEIGHT, f"weights in {units.label(ou)}/V"
    )
    rest = c.numbers(c.get(el, where, "rest_states"), f"{where}.rest_states", -MAX_DRIVE_V, MAX_DRIVE_V, "states in V")
    if not len(r) == len(cw) == len(rest):
        c.fail(f"{where}.weights", list(cw), f"one width, weight and rest state per element ({len(r)} widths)")
    bad = [i for i, (e, x) in enumerate(zip(rest, r)) if abs(e) > x]
    if bad:
        c.fail(f"{where}.rest_states[{bad[0]}]", rest[bad[0]], f"within +- its width {r[bad[0]]:g} V")
    return DuhemElements(r, cw, rest)


def check_creep(c: _Checker, sec: Mapping[str, Any], unit: str) -> CreepModel:
    m = c.mapping(c.get(sec, "creep", "model"), "creep.model", "a mapping (the creep model)")
    w = "creep.model"
    c.get(m, w, "form")  # present (the model's own check names a form it does not know)
    kc = c.number(
        c.get(m, w, "static_gain"),
        f"{w}.static_gain",
        0.0,
        MAX_CREEP_GAIN,
        "K_c > 0 (a stable creep compensator)",
        lo_open=True,
    )
    taus = c.numbers(c.get(m, w, "taus_s"), f"{w}.taus_s", *CREEP_TAU_S, "time constants in s", min_len=0)
    gains = c.numbers(
        c.get(m, w, "gains"),
        f"{w}.gains",
        -MAX_CREEP_ELEMENT_GAIN,
        MAX_CREEP_ELEMENT_GAIN,
        "dimensionless gains",
        min_len=0,
    )
    if len(taus) != len(gains):
        c.fail(f"{w}.gains", list(gains), f"one gain per time constant ({len(taus)})")
    params = m.get("params") or {}
    c.mapping(params, f"{w}.params", "a mapping of names to numbers")
    for k, v in params.items():
        c.number(v, f"{w}.params.{k}", -MAX_OUTPUT, MAX_OUTPUT, "a finite parameter")
    if kc + sum(gains) <= 0:
        c.fail(f"{w}.gains", list(gains), f"a positive long-time gain K_c + sum(gains) (K_c = {kc:g})")
    fit = sec.get("fit") if isinstance(sec.get("fit"), Mapping) else {}
    if "edge_aligned" in fit and not isinstance(fit["edge_aligned"], bool):
        c.fail(
            "creep.fit.edge_aligned", fit["edge_aligned"], "true or false (was the creep fitted past the step's edge)"
        )
    fit_unit = fit.get("output_unit")
    if fit_unit is not None and units.normalise(fit_unit) != unit:
        c.fail(
            "creep.fit.output_unit",
            fit_unit,
            f"{unit!r}, the hysteresis model's output unit (one unit across the sections)",
        )
    for other in units.LABELS:  # a section written before the unit was recorded: its figures' keys say it
        key = f"rms_{units.key(other)}"
        if fit_unit is None and other != unit and key in fit:
            c.fail(
                f"creep.fit.{key}",
                fit[key],
                f"a creep fitted in {units.label(unit)} (rms_{units.key(unit)}), the hysteresis "
                "model's output unit (one unit across the sections)",
            )
    try:
        return CreepModel.from_dict(m)
    except FitError as exc:
        raise BundleError(f"{c.source}: creep.model: {exc}") from None


def _check_frequency_damping(c: _Checker, m: Mapping[str, Any], where: str) -> tuple[float, float]:
    """``(natural_freq_rad_s, damping)`` of a mode, a shaper's design or an anti-resonance, checked."""
    wn = c.number(
        c.get(m, where, "natural_freq_rad_s"),
        f"{where}.natural_freq_rad_s",
        0.0,
        MAX_WN_RAD_S,
        "a natural frequency in rad/s",
        lo_open=True,
    )
    return wn, c.number(c.get(m, where, "damping"), f"{where}.damping", 0.0, 1.0, "a damping ratio", hi_open=True)


def _check_shaper(c: _Checker, s: Any, where: str) -> Shaper:
    s = c.mapping(s, where, "a mapping (the input shaper)")
    name = c.get(s, where, "name")
    if not isinstance(name, str):
        c.fail(f"{where}.name", name, "the shaper's name (text)")
    t = c.numbers(c.get(s, where, "times_s"), f"{where}.times_s", 0.0, MAX_SHAPER_S, "impulse times in s")
    a = c.numbers(c.get(s, where, "amplitudes"), f"{where}.amplitudes", 0.0, 1.0, "impulse amplitudes")
    if len(t) != len(a):
        c.fail(f"{where}.amplitudes", list(a), f"one amplitude per impulse time ({len(t)})")
    if min(a) <= 0 or abs(sum(a) - 1.0) > SHAPER_SUM_TOL:
        c.fail(
            f"{where}.amplitudes",
            list(a),
            f"positive impulses summing to 1 (within {SHAPER_SUM_TOL:g}; they sum to {sum(a):.9g})",
        )
    if any(t1 < t0 for t0, t1 in zip(t, t[1:])):
        c.fail(f"{where}.times_s", list(t), "non-decreasing impulse times")
    wn, zeta = _check_frequency_damping(c, s, where)
    zp = s.get("zv_power")
    if zp is not None and not (isinstance(zp, int) and not isinstance(zp, bool) and 1 <= zp <= 20):
        c.fail(f"{where}.zv_power", zp, "null or an integer 1 to 20")
    try:
        return Shaper(name=name, times_s=t, amplitudes=a, wn=wn, zeta=zeta, zv_power=zp)
    except FitError as exc:
        raise BundleError(f"{c.source}: {where}: {exc}") from None


def check_antiresonance(c: _Checker, ar: Any) -> tuple[float, float] | None:
    """``shaper.mode.antiresonance``: null, or the zeros above the mode ``fit`` identified,
    ``{"natural_freq_rad_s", "damping"}`` (:func:`~piezopress.analysis.mode.antiresonant`)."""
    if ar is None:
        return None
    where = "shaper.mode.antiresonance"
    ar = c.mapping(ar, where, "null or a mapping (the anti-resonance's natural_freq_rad_s and damping)")
    return _check_frequency_damping(c, ar, where)


def check_shaper(
    c: _Checker, sec: Mapping[str, Any], unit: str
) -> tuple[Shaper, Shaper | None, tuple[float, float, float | None]]:
    mode = c.mapping(c.get(sec, "shaper", "mode"), "shaper.mode", "a mapping (the identified mode)")
    wn, zeta = _check_frequency_damping(c, mode, "shaper.mode")
    lp = c.optional(mode.get("sensor_lowpass_hz"), "shaper.mode.sensor_lowpass_hz", 1.0, 1e9, "null or a cut-off in Hz")
    mu = mode.get("output_unit")
    if mu is not None and units.normalise(mu) != unit:
        c.fail(
            "shaper.mode.output_unit",
            mu,
            f"{unit!r}, the hysteresis model's output unit (one unit across the sections)",
        )
    check_antiresonance(c, mode.get("antiresonance"))
    sh = _check_shaper(c, c.get(sec, "shaper", "shaper"), "shaper.shaper")
    sh2 = _check_shaper(c, sec["shaper2"], "shaper.shaper2") if sec.get("shaper2") else None
    return sh, sh2, (wn, zeta, lp)


@dataclass(frozen=True)
class Settings:
    """The bundle's ``compensation`` section, checked."""

    drive_min_v: float = 0.0
    drive_max_v: float = 150.0
    max_rate_per_s: float | None = None
    lead_s: float = 0.0
    delay_lead_s: float = 0.0
    slew_v_per_s: float | None = None
    rate: RateDependence | None = None
    #: the part of ``lead_s`` that is the identified drive chain's delay (led without a shaper too)
    chain_lead_s: float = 0.0
    #: an input delay counted in samples of the reference's rate (a board's FIFO), led besides ``lead_s``
    delay_lead_samples: float = 0.0
    #: the drive chain's own delay in samples of the reference's rate (the sampling's: a DAC's hold, a
    #: decimating ADC's filter), led besides ``lead_s``, without a shaper too (:func:`chain_leads`)
    chain_lead_samples: float = 0.0


def check_compensation(c: _Checker, comp: Any, unit: str) -> Settings:
    comp = c.mapping(comp, "compensation", "a mapping (drive range, rate limit, lead)")
    w = "compensation"
    lo = c.number(comp.get("drive_min_v", 0.0), f"{w}.drive_min_v", -MAX_DRIVE_V, MAX_DRIVE_V, "a drive limit in V")
    hi = c.number(comp.get("drive_max_v", 150.0), f"{w}.drive_max_v", -MAX_DRIVE_V, MAX_DRIVE_V, "a drive limit in V")
    if hi <= lo:
        c.fail(f"{w}.drive_max_v", hi, f"more than drive_min_v ({lo:g} V)")
    k = units.key(unit)
    for other in units.LABELS:
        ok = f"max_rate_{units.key(other)}_per_s"
        if other != unit and comp.get(ok) is not None:
            c.fail(
                f"{w}.{ok}",
                comp[ok],
                f"no rate limit in {units.label(other)}/s: the hysteresis model's output is in "
                f"{units.label(unit)} (max_rate_{k}_per_s; one unit across the sections)",
            )
    rate_limit = c.optional(
        comp.get(f"max_rate_{k}_per_s"),
        f"{w}.max_rate_{k}_per_s",
        0.0,
        MAX_RATE,
        f"null (no limit) or a positive rate in {units.label(unit)}/s",
        lo_open=True,
    )
    lead = c.number(comp.get("lead_s", 0.0), f"{w}.lead_s", 0.0, MAX_LEAD_S, "the drive's lead in s", hi_open=True)
    delay = c.number(
        comp.get("delay_lead_s", 0.0), f"{w}.delay_lead_s", 0.0, MAX_LEAD_S, "the input delay's lead in s", hi_open=True
    )
    chain = c.number(
        comp.get("chain_lead_s", 0.0), f"{w}.chain_lead_s", 0.0, lead, "the drive chain's part of lead_s in s"
    )

    def lead_samples(key: str, what: str) -> float:
        return c.number(
            comp.get(key, 0.0), f"{w}.{key}", 0.0, MAX_LEAD_SAMPLES, f"{what} in samples of the reference's rate"
        )

    samples = lead_samples("delay_lead_samples", "the input delay's lead")
    chain_samples = lead_samples(
        "chain_lead_samples", "the drive chain's delay (a converter's hold and filter, a FIFO)"
    )
    slew = c.optional(
        comp.get("slew_v_per_s"),
        f"{w}.slew_v_per_s",
        0.0,
        MAX_RATE,
        "null or a positive slew limit in V/s",
        lo_open=True,
    )
    rd = comp.get("rate_dependence")
    rate = None
    if rd:
        rd = c.mapping(rd, f"{w}.rate_dependence", "a mapping (the rate-dependent hysteresis)")
        q = f"{w}.rate_dependence"
        sat = c.optional(
            rd.get("saturation_v_per_s") or None, f"{q}.saturation_v_per_s", 0.0, MAX_RATE, "null or V/s", lo_open=True
        )
        rate = RateDependence(
            widen_v_per_kv_s=c.number(
                rd.get("widen_v_per_kv_s", 0.0), f"{q}.widen_v_per_kv_s", 0.0, MAX_DRIVE_V, "V per kV/s"
            ),
            loss_per_kv_s=c.number(rd.get("loss_per_kv_s", 0.0), f"{q}.loss_per_kv_s", 0.0, 1e3, "per kV/s"),
            saturation_v_per_s=sat,
            tau_s=c.number(rd.get("tau_s", RATE_TAU_S), f"{q}.tau_s", 0.0, 1e3, "a time constant in s", lo_open=True),
            exponent=c.number(
                rd.get("exponent", 1.0), f"{q}.exponent", 0.0, 1.0, "the rate law's exponent, in (0, 1]", lo_open=True
            ),
            floor_v_per_s=c.number(
                rd.get("floor_v_per_s", 0.0), f"{q}.floor_v_per_s", 0.0, MAX_RATE, "the loop's fitted rate, V/s"
            ),
        )
        if rate.saturation_v_per_s and rate.exponent != 1.0:
            c.fail(
                f"{q}.exponent",
                rate.exponent,
                f"1 with saturation_v_per_s {rate.saturation_v_per_s:g} (a rate law saturates or is a power law, "
                "not both: give one, the other null or 1)",
            )
    return Settings(lo, hi, rate_limit, lead, delay, slew, rate, chain, samples, chain_samples)


def check_section(kind: str, doc: Any, source: str) -> None:
    """Check a section file (``fit-hysteresis``'s, ``fit-creep``'s, ``fit-shaper``'s) as a bundle's section."""
    c = _Checker(source)
    doc = c.mapping(doc, "the document", f"a JSON object (a {kind} section)")
    if doc.get("bundle_version") != BUNDLE_VERSION:
        c.fail("bundle_version", doc.get("bundle_version"), f"{BUNDLE_VERSION} (this software's schema)")
    if doc.get("section") != kind:
        if doc.get("section") is None and kind in doc and "hysteresis" in doc:
            raise BundleError(
                f"{source}: is a whole bundle, not a {kind} section; expected the file `piezopress fit-{kind}` "
                f"writes (a whole bundle is used as it is: pass it as --bundle to compensate, validate or diagnose)"
            )
        what = f"section {doc.get('section')!r}" if doc.get("section") is not None else "no 'section' key"
        raise BundleError(f"{source}: has {what}; expected a {kind} section (the file `piezopress fit-{kind}` writes)")
    if kind == "hysteresis":
        check_hysteresis(c, doc)
    elif kind == "creep":
        check_creep(
            c,
            doc,
            units.normalise(doc.get("fit", {}).get("output_unit") if isinstance(doc.get("fit"), Mapping) else None),
        )
    elif kind == "shaper":
        mode = doc.get("mode")
        unit = units.normalise(mode.get("output_unit")) if isinstance(mode, Mapping) else units.FORCE
        check_shaper(c, doc, unit)


@dataclass(frozen=True)
class Bundle:
    """A checked parameter bundle: the document and the models it describes.

    Build it with :meth:`from_dict` (which checks everything that does not depend on where
    the bundle is used); :meth:`to_dict` gives the document back unchanged.
    """

    hysteresis: PIModel
    creep: CreepModel | None
    shaper: Shaper | None
    shaper2: Shaper | None
    mode: tuple[float, float, float | None] | None  # (wn rad/s, zeta, sensor low-pass Hz)
    settings: Settings
    source: str = "bundle"
    doc: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)

    # ------------------------------------------------------------------ reading and writing

    @classmethod
    def from_dict(cls, doc: Any, source: str = "bundle") -> Bundle:
        """The bundle a document describes, checked; :class:`BundleError` (one line naming
        ``source``, the section and key, and what was expected) otherwise."""
        c = _Checker(str(source))
        doc = c.mapping(doc, "the document", "a JSON object (a bundle made by `piezopress fit` or `bundle`)")
        if doc.get("bundle_version") != BUNDLE_VERSION:
            c.fail("bundle_version", doc.get("bundle_version"), f"{BUNDLE_VERSION} (this software's bundle schema)")
        if "hysteresis" not in doc:
            raise BundleError(
                f"{source}: has no hysteresis section; expected a bundle made by `piezopress fit` or `bundle`"
            )
        for name in SECTIONS:
            if name in doc:
                sec = c.mapping(doc[name], name, f"a mapping (the {name} section)")
                if "bundle_version" in sec and sec["bundle_version"] != BUNDLE_VERSION:
                    c.fail(
                        f"{name}.bundle_version", sec["bundle_version"], f"{BUNDLE_VERSION} (this software's schema)"
                    )
        hyst = check_hysteresis(c, doc["hysteresis"])
        unit = hyst.output_unit
        creep = check_creep(c, doc["creep"], unit) if "creep" in doc else None
        sh = sh2 = mode = None
        if "shaper" in doc:
            sh, sh2, mode = check_shaper(c, doc["shaper"], unit)
        settings = check_compensation(c, doc.get("compensation", {}), unit)
        return cls(hyst, creep, sh, sh2, mode, settings, str(source), copy.deepcopy(dict(doc)))

    def to_dict(self) -> dict[str, Any]:
        """The document (a copy: changing it does not change the bundle)."""
        return copy.deepcopy(self.doc)

    @property
    def unit(self) -> str:
        """The output unit code (``N`` or ``um``) of every section."""
        return self.hysteresis.output_unit

    # ------------------------------------------------------------------ checks where it is used

    def check_unit(self, unit: str, what: str, expected: str | None = None) -> None:
        """Refuse a run or reference in another unit than the bundle's (``what`` names it,
        ``expected`` says what would do)."""
        if units.normalise(unit) != self.unit:
            expected = expected or f"a {units.quantity(self.unit)} run for this bundle"
            raise BundleError(
                f"{what}: is in {units.label(unit)} ({units.quantity(unit)}), the bundle {self.source} in "
                f"{units.label(self.unit)} ({units.quantity(self.unit)}); expected one unit: {expected}"
            )

    def check_reference(self, n_samples: int, fs_hz: float, what: str, *, use_creep: bool = True) -> None:
        """What the compensator needs of a reference of ``n_samples`` at ``fs_hz``: a lead
        shorter than :data:`LEAD_MAX_FRACTION` of it, and a creep compensator stable at its rate."""
        duration = (n_samples - 1) / fs_hz if n_samples > 1 else 0.0
        leads = (
            ("lead_s", self.settings.lead_s),
            ("delay_lead_s", self.settings.delay_lead_s),
            (
                f"delay_lead_samples ({self.settings.delay_lead_samples:g} samples at {fs_hz:g} Hz)",
                self.settings.delay_lead_samples / fs_hz,
            ),
            (
                f"chain_lead_samples ({self.settings.chain_lead_samples:g} samples at {fs_hz:g} Hz)",
                self.settings.chain_lead_samples / fs_hz,
            ),
        )
        for key, lead in leads:
            if lead > LEAD_MAX_FRACTION * duration:
                raise BundleError(
                    f"{self.source}: compensation.{key} = {lead:.6g} s; expected less than "
                    f"{LEAD_MAX_FRACTION:g} of the reference's {duration:.6g} s ({what})"
                )
        if use_creep and self.creep is not None:
            try:
                self.creep.check_stable(fs_hz)
            except CompensatorUnstableError as exc:
                raise BundleError(f"{self.source}: creep.model: {exc}; at {what}'s rate {fs_hz:g} Hz") from None

    def check_drive_range(self, drive_min_v: float, drive_max_v: float, rig: str) -> None:
        """Refuse a compensation drive range outside the rig's."""
        s = self.settings
        if s.drive_min_v < drive_min_v - 1e-9 or s.drive_max_v > drive_max_v + 1e-9:
            raise BundleError(
                f"{self.source}: compensation drive range {s.drive_min_v:g} to {s.drive_max_v:g} V; expected inside "
                f"the rig's {drive_min_v:g} to {drive_max_v:g} V ({rig})"
            )

    def reach(
        self, drive_min_v: float | None = None, drive_max_v: float | None = None, points: int = 400
    ) -> tuple[float, float]:
        """The output the drive range (the bundle's, unless given) reaches, ``(lowest, highest)``
        above the model's rest: the extremes of the hysteresis model's major loop (the drive
        swept over the whole range twice, from 0 V)."""
        s = self.settings
        lo = s.drive_min_v if drive_min_v is None else drive_min_v
        hi = s.drive_max_v if drive_max_v is None else drive_max_v
        legs = [(0.0, hi), (hi, lo), (lo, hi), (hi, lo), (lo, hi)]
        x = np.concatenate([np.linspace(a, b, points) for a, b in legs])
        y, _ = self.hysteresis.forward(x)
        loop = y[2 * points :] - self.hysteresis.y0
        return float(np.min(loop)), float(np.max(loop))

    def judged_rows(self, sha256: str | None, name: str | None = None) -> tuple[int, int, int] | None:
        """``(fitted_from, held_out_from, stop)`` rows of a run the hysteresis was fitted on (found
        by its file's sha256, else its name), as ``fit`` judged it; ``None``: not one of them, or
        a bundle fitted before the rows were recorded."""
        h = self.doc.get("hysteresis") or {}
        runs = h.get("runs") or []
        fit = h.get("fit") or {}
        cols = [fit.get(k) for k in ("fitted_from_row", "held_out_from_row", "stop_row")]
        if not all(isinstance(c, list) and len(c) == len(runs) for c in cols):
            return None
        for i, r in enumerate(runs):
            if not isinstance(r, Mapping):
                continue
            if (sha256 and r.get("sha256") == sha256) or (not sha256 and name is not None and r.get("name") == name):
                try:
                    return int(cols[0][i]), int(cols[1][i]), int(cols[2][i])
                except (TypeError, ValueError):
                    return None
        return None

    @property
    def from_elsewhere(self) -> bool:
        """True when the runs the hysteresis was fitted on name no press (imported, or another
        program's): references are then read on the record's own scale by default."""
        runs = [r for r in (self.doc.get("hysteresis") or {}).get("runs", []) or [] if isinstance(r, Mapping)]
        return bool(runs) and all("rig" in r and r["rig"] is None for r in runs)

    # ------------------------------------------------------------------ the models

    def compensator(self, *, use_shaper: bool = True, use_creep: bool = True) -> Compensator:
        """The compensator the bundle describes (without the shaper, only the drive chain's
        delay and a pure input delay are led, not the mode's)."""
        s = self.settings
        return Compensator(
            hysteresis=self.hysteresis,
            creep=self.creep if use_creep else None,
            shaper=self.shaper if use_shaper else None,
            drive_min_v=s.drive_min_v,
            drive_max_v=s.drive_max_v,
            max_rate_per_s=s.max_rate_per_s,
            lead_s=s.lead_s if use_shaper else s.delay_lead_s + s.chain_lead_s,
            lead_samples=s.delay_lead_samples + s.chain_lead_samples,
            shaper2=self.shaper2 if use_shaper else None,
            rate=s.rate,
            slew_v_per_s=s.slew_v_per_s,
        )

    @property
    def antiresonance(self) -> tuple[float, float] | None:
        """The zeros above the mode ``fit`` identified, ``(wz rad/s, damping)`` (None: none, or no mode)."""
        mode = self.doc.get("shaper", {}).get("mode") if isinstance(self.doc, dict) else None
        ar = mode.get("antiresonance") if isinstance(mode, dict) else None
        return check_antiresonance(_Checker(self.source), ar) if ar is not None else None

    def forward_model(self):
        """The forward model (:class:`piezopress.analysis.diagnosis.Model`): hysteresis, and
        creep and mode when present."""
        from piezopress.analysis import diagnosis as dg

        wn, zeta, lp = self.mode if self.mode is not None else (None, None, None)
        # the drive chain's bandwidth is the press's own (a lag a low-pass chain explains is no
        # input delay, no slew limit); an identified slew stays for diagnose to name, as with a monitor
        base = dg.Model(
            self.hysteresis,
            self.creep,
            wn,
            zeta,
            lp,
            creep_edge_aligned=self.creep_edge_aligned,
            antiresonance=self.antiresonance,
        )
        series = _lowpass_delay(self._chain_doc)
        if series is not None and series[1] < 1.0:
            wc, zc, _ = series
            own_s, fs = chain_own_delay(self._chain_doc)
            samples = self._chain_doc.get("delay_samples")
            told = {}
            if _positive(samples) and own_s:  # of the delay held, what is in samples scales with each run's rate
                told = {
                    "drive_delay_samples": min(float(samples), own_s * fs),
                    "drive_delay_rate_hz": fs,
                    "chain_samples": float(samples),
                }
            return replace(base, drive_lowpass=(wc, zc), drive_delay_s=own_s, **told)
        _, tau = self.drive_chain
        return replace(base, drive_tau_s=tau or 0.0)

    @property
    def creep_edge_aligned(self) -> bool | None:
        """Whether the creep was fitted past the held step's edge (``creep.fit.edge_aligned``,
        :func:`creep.edge_aligned`); None where the bundle does not say (written before it was
        recorded). A creep fitted again on a hold is fitted as this one was."""
        fit = self.doc.get("creep", {}).get("fit") if isinstance(self.doc, dict) else None
        aligned = fit.get("edge_aligned") if isinstance(fit, dict) else None
        return aligned if isinstance(aligned, bool) else None

    @property
    def _chain_doc(self) -> dict[str, Any] | None:
        """``shaper.mode.drive_chain`` as recorded (None: none recorded)."""
        chain = self.doc.get("shaper", {}).get("mode", {}).get("drive_chain") if isinstance(self.doc, dict) else None
        return chain if isinstance(chain, dict) else None

    @property
    def drive_chain(self) -> tuple[float | None, float | None]:
        """``(slew V/s, first-order lag s)`` of the drive chain ``fit`` identified with the mode
        when no amplifier monitor was recorded (``shaper.mode.drive_chain``; ``None``: none; a
        ``delay`` chain as the lag of the same low-frequency delay)."""
        chain = self._chain_doc
        if chain is None:
            return None, None

        slew = chain.get("slew_v_per_s") if chain.get("form") in ("slew", "slew_lowpass_delay") else None
        # a chain the steps read best as a pure delay (lags in series: an amplifier, a filter)
        # enters the forward model as the first-order lag of the same low-frequency delay
        return (float(slew) if _positive(slew) else None), (chain_delay_s(chain) or None)

    def remove_creep(self, run) -> np.ndarray:
        """A run's measured output with the creep taken out (the creep compensator applied
        to it above the rest level): what the hysteresis model alone should predict. Without
        a creep model, the output as measured. ``run`` has ``command_v``, ``output`` and
        ``sample_rate_hz`` (a :class:`piezopress.runformat.Run`)."""
        return creep_removed(self.creep, run.command_v, run.output, run.sample_rate_hz)

    def extended(self, findings: Iterable[Any], model: Any = None) -> Bundle:
        """The bundle with every diagnosis finding recorded; those the compensator applies change
        it (:func:`extend_document`)."""
        return Bundle.from_dict(extend_document(self.doc, list(findings), model), self.source)


def _positive(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0


#: The pure delay (in samples of the steps it was identified on) the sampling itself puts in a
#: chain: a DAC's hold (half a sample) and a decimating ADC's filter (a sinc^3's 1.5 samples).
#: The forward model ``diagnose`` judges holds the ``lowpass_delay`` chain's delay up to this
#: (the press's own); a delay beyond it is left for ``input_delay`` to name (a board's FIFO, a
#: latency). On the third test press the chain's delay is 1.6-1.9 samples clean, 8 with a FIFO
#: of 6 samples.
SAMPLING_DELAY_SAMPLES = 2.0


def _lowpass_delay(chain: Any) -> tuple[float, float, float] | None:
    """``(wc rad/s, damping, delay s)`` of a ``lowpass_delay`` drive chain (None: another form, or
    a low-pass not recorded)."""
    if not isinstance(chain, dict) or chain.get("form") not in SERIES_CHAINS:
        return None
    hz, z, d = (chain.get(k) for k in ("lowpass_hz", "lowpass_damping", "delay_s"))
    if not (_positive(hz) and _positive(z)):
        return None
    return 2.0 * math.pi * float(hz), float(z), float(d) if _positive(d) else 0.0


def chain_delay_s(chain: Any) -> float:
    """The low-frequency delay of a drive chain identified with the mode (``drive_chain``): a
    pure delay's ``delay_s``, a first-order lag's ``tau_s``, a second-order low-pass's
    ``2 zeta / wn`` with its delay; 0 for a slew limit or none."""
    if not isinstance(chain, dict):
        return 0.0
    form = chain.get("form")
    if form == "slew_lowpass_delay" and _positive(chain.get("low_frequency_delay_s")):
        return float(chain["low_frequency_delay_s"])  # steps that all slew: read off the slew alone
    if form in SERIES_CHAINS:
        series = _lowpass_delay(chain)
        return 0.0 if series is None else lowpass_delay_group_delay_s(*series)
    v = chain.get("delay_s") if form == "delay" else chain.get("tau_s") if form == "first_order" else None
    return float(v) if _positive(v) else 0.0


def chain_own_delay(chain: Any) -> tuple[float, float]:
    """``(seconds, steps' rate Hz)``: the part of a series drive chain's pure delay
    (``lowpass_delay``, ``slew_lowpass_delay``) that is the sampling's own, up to
    :data:`SAMPLING_DELAY_SAMPLES` of the steps it was identified on; ``(0, 0)`` for another form,
    or where the steps' rate is not recorded (a bundle written before it was). The forward model
    ``diagnose`` judges with holds this part, in seconds at the steps' rate and in runs sampled
    slower; where steps at two rates told the chain's delay in samples (``delay_samples``), a run
    sampled faster holds as many fewer seconds of it (:meth:`Bundle.forward_model`,
    ``Model.drive_delay_at``; the README says why not in samples in the slow runs). The
    compensator leads the chain's delay by :func:`chain_leads`."""
    series = _lowpass_delay(chain)
    fs = chain.get("steps_sample_rate_hz") if isinstance(chain, dict) else None
    if series is None or not _positive(fs):
        return 0.0, 0.0
    own = SAMPLING_DELAY_SAMPLES / float(fs)
    plain = chain.get("delay_without_antiresonance_s")
    if _positive(plain) or plain == 0:
        # an anti-resonance fitted with the chain moves lag between its low-pass and its delay (the
        # zeros' lead, a low-pass of another frequency): what is beyond the sampling's own is judged
        # on the delay the steps read without the zeros, and the rest held
        return max(0.0, series[2] - max(0.0, float(plain) - own)), float(fs)
    return min(series[2], own), float(fs)


def chain_leads(chain: Any) -> tuple[float, float]:
    """``(seconds, samples)`` the compensator leads for a drive chain identified with the mode:
    :func:`chain_delay_s` less the sampling's own delay, and that own delay in samples of the
    reference's rate, so that a reference sampled faster or slower than the steps is led by what
    the press lags at its rate. Where steps at two sample rates told the delay's part in samples
    (``delay_samples``), that part; else the rule of :func:`chain_own_delay` (up to
    :data:`SAMPLING_DELAY_SAMPLES` of the steps' rate). On the third test press, seeds 0-2
    (``bench/bench_presses.py``), all in seconds -> the two-sample rule (1.6 samples of the
    steps' 20 kHz) -> steps at 20 and 50 kHz (2.2 samples, less 28-40 us in seconds): the
    compensated 50 Hz loop read 2.38 -> 1.47 -> 1.01 %, the 1 Hz loop 0.62 -> 0.37 -> 0.33 %, the
    random 0.2-20 Hz tracking 0.43 -> 0.24 -> 0.18 %; the 0.1 Hz triangles at 500 Hz, whose loop
    the hysteresis was fitted on with that rate's lag in its width, 0.60 -> 0.70 -> 0.76 %."""
    total = chain_delay_s(chain)
    samples = chain.get("delay_samples") if isinstance(chain, dict) else None
    fs = chain.get("steps_sample_rate_hz") if isinstance(chain, dict) else None
    if _lowpass_delay(chain) is not None and _positive(samples) and _positive(fs):
        # steps at two rates told the delay's part in samples (mode_fit._fit_lowpass_delay): led
        # as identified, the rest (the low-pass's lag, a seconds part that may be negative) in seconds
        return max(0.0, total - float(samples) / float(fs)), float(samples)
    own_s, fs = chain_own_delay(chain)
    if not own_s:
        return total, 0.0
    return max(0.0, total - own_s), own_s * fs


def creep_removed(creep: CreepModel | None, command_v: np.ndarray, output: np.ndarray, fs_hz: float) -> np.ndarray:
    """``output`` with ``creep`` removed: the creep compensator applied above the output at rest."""
    output = np.asarray(output, float)
    if creep is None:
        return output
    _, rest = rest_offset(command_v, output)
    return rest + creep.compensate(output - rest, fs_hz)[0]


# ---------------------------------------------------------------------- diagnosis extensions


def shaper_document(sh: Shaper) -> dict[str, Any]:
    """A shaper as a bundle's ``shaper.shaper`` (or ``shaper2``) mapping: impulses, the mode
    it was designed for, and its delay and centroid in milliseconds."""
    return {
        "name": sh.name,
        "times_s": list(sh.times_s),
        "amplitudes": list(sh.amplitudes),
        "natural_freq_rad_s": sh.wn,
        "damping": sh.zeta,
        "zv_power": sh.zv_power,
        "delay_ms": 1e3 * sh.delay_s,
        "centroid_ms": 1e3 * sh.centroid_s,
    }


def second_shaper(parameters: Mapping[str, float]) -> dict[str, Any]:
    """A ZVD shaper for a second mode (``natural_freq_rad_s``, ``damping``), as a bundle's
    ``shaper.shaper2`` (the compensator applies it after the first shaper)."""
    sh = design_shaper("zvd", float(parameters["natural_freq_rad_s"]), float(parameters["damping"]))
    return {**shaper_document(sh), "for": "diagnose: second_resonance"}


def rate_dependence(model: Any) -> dict[str, Any]:
    """A model's rate dependence as the bundle's ``compensation.rate_dependence``."""
    sat = getattr(model, "rate_saturation_v_per_s", None)
    return {
        "widen_v_per_kv_s": float(model.rate_v_per_kv_s),
        "loss_per_kv_s": float(getattr(model, "rate_loss_per_kv_s", 0.0)),
        "saturation_v_per_s": float(sat) if sat and np.isfinite(sat) else None,
        "tau_s": float(getattr(model, "rate_tau_s", 5e-4)),
        "exponent": float(getattr(model, "rate_exponent", 1.0)),
        "floor_v_per_s": float(getattr(model, "rate_floor_v_per_s", 0.0)),
    }


#: Creep elements (not the log tail) faster than this are folded into the compensator's
#: instantaneous gain (see :func:`creep_for_compensator`).
FAST_CREEP_S = 1.0


def creep_for_compensator(model: CreepModel) -> CreepModel:
    """The found creep model as the compensator inverts it.

    The log-creep finding fits a few Kelvin-Voigt elements and a log tail (equal gains, two
    per decade from 0.05 s) on the hold read at 50 Hz. An element faster than
    :data:`FAST_CREEP_S` there is not told apart from the step's own transient and the tail's
    first terms (it lands on the grid's floor, 0.2 s, taking what the tail's fit left): as
    a dynamic term its compensator drives every step too hard for a fraction of a second
    (an overshoot the press does not have). It is folded into the instantaneous gain: the
    creep at long times is kept, the fast part is the tail's.
    """
    gamma = model.params.get("per_decade")
    if model.form != "kv" or gamma is None:
        return model
    tail_gain = 0.5 * float(gamma)
    fast = [
        i
        for i, (t, g) in enumerate(zip(model.taus_s, model.gains))
        if t < FAST_CREEP_S and not np.isclose(g, tail_gain, rtol=1e-9)
    ]
    if not fast:
        return model
    keep = [i for i in range(len(model.taus_s)) if i not in fast]
    return CreepModel(
        "kv",
        model.static_gain + sum(model.gains[i] for i in fast),
        tuple(model.taus_s[i] for i in keep),
        tuple(model.gains[i] for i in keep),
        dict(model.params),
    )


# Each cause's extension of the bundle (``Cause.extend`` in the catalogue,
# :data:`piezopress.analysis.diagnosis.CAUSES`): ``(extended document, its compensation
# section, the finding)``; the compensator applies what these write.


def extend_slew_limit(ext: dict[str, Any], comp: dict[str, Any], f: Any) -> None:
    """The compensator keeps its drive below the slew (slowing the reference where the drive would outrun it)."""
    comp["slew_v_per_s"] = float(f.parameters["slew_rate_v_per_s"])


def extend_input_delay(ext: dict[str, Any], comp: dict[str, Any], f: Any) -> None:
    """The drive leads by the delay (one counted in samples: by as many samples of the reference's
    rate); found on slow sweeps, the operators refitted on the delayed drive too."""
    if f.parameters.get("delay_samples"):
        comp["delay_lead_samples"] = comp.get("delay_lead_samples", 0.0) + f.parameters["delay_samples"]
        return
    comp["lead_s"] = comp.get("lead_s", 0.0) + f.parameters["delay_s"]
    if f.parameters.get("operators_refitted"):  # found on slow sweeps: the lag had widened the fitted loop
        ext["hysteresis"]["model"] = f.model.hysteresis.to_dict()
        ext["hysteresis"]["extended_by"] = "diagnose: input_delay (operators refitted on the delayed drive)"
    comp["delay_lead_s"] = comp.get("delay_lead_s", 0.0) + f.parameters["delay_s"]


def extend_rate_dependence(ext: dict[str, Any], comp: dict[str, Any], f: Any) -> None:
    """The inverse at the drive's own rate."""
    comp["rate_dependence"] = rate_dependence(f.model)


def extend_second_resonance(ext: dict[str, Any], comp: dict[str, Any], f: Any) -> None:
    """A second shaper for the second mode (with a shaper section to add it to); where the
    finding read the mode's zeros as the second mode's own anti-resonance (``zeros_dropped``),
    the mode's zeros are dropped with it."""
    if "shaper" in ext:
        ext["shaper"]["shaper2"] = second_shaper(f.parameters)
        mode = ext["shaper"].get("mode")
        if f.parameters.get("zeros_dropped") and isinstance(mode, dict) and mode.get("antiresonance") is not None:
            mode["antiresonance"] = None


def extend_hysteresis_order(ext: dict[str, Any], comp: dict[str, Any], f: Any) -> None:
    """The richer hysteresis model the finding chose on held-out data."""
    ext["hysteresis"]["model"] = f.model.hysteresis.to_dict()
    ext["hysteresis"]["extended_by"] = "diagnose: hysteresis_order"


def extend_logarithmic_creep(ext: dict[str, Any], comp: dict[str, Any], f: Any) -> None:
    """The creep model the finding fitted and judged (its elements and log tail), not a log form
    rebuilt from two of its numbers: the compensator inverts what was found."""
    if "creep" not in ext:
        return
    log = (
        f.model.creep
        if f.model.creep is not None
        else CreepModel.log(f.parameters["static_gain"], f.parameters["per_decade"])
    )
    ext["creep"]["model"] = creep_for_compensator(log).to_dict()
    ext["creep"]["extended_by"] = "diagnose: logarithmic_creep"
    if isinstance(ext["creep"].get("fit"), dict):  # the finding fitted its creep past the step's edge
        ext["creep"]["fit"]["edge_aligned"] = True


def antiresonance_lead_s(zeros: tuple[float, float] | None) -> float:
    """The low-frequency lead of an anti-resonance's zeros ``(wz rad/s, damping)``: ``2 zeta_z / wz`` (0: none)."""
    return 0.0 if zeros is None else 2.0 * float(zeros[1]) / float(zeros[0])


def mode_lag_s(mode: Mapping[str, Any]) -> float:
    """The low-frequency delay of a bundle's mode (``shaper.mode``): ``2 zeta / wn``, less the lead
    of an anti-resonance above it (:func:`~piezopress.analysis.mode.antiresonant`)."""
    ar = mode.get("antiresonance")
    zeros = (float(ar["natural_freq_rad_s"]), float(ar["damping"])) if isinstance(ar, Mapping) else None
    return 2.0 * float(mode["damping"]) / float(mode["natural_freq_rad_s"]) - antiresonance_lead_s(zeros)


def modal_delay_s(model: Any) -> float:
    """The low-frequency delay of a model's mode(s): ``2 zeta / wn`` (less the main mode's
    anti-resonance's lead), each mode weighted by its share (modes in series: the sum of their delays)."""
    series = bool(getattr(model, "mode2_series", False))
    share2 = model.mode2[0] if model.mode2 and not series else 0.0
    own = 2.0 * float(model.zeta) / float(model.wn) - antiresonance_lead_s(getattr(model, "antiresonance", None))
    d = (1.0 - share2) * own
    if model.mode2:
        d += (1.0 if series else share2) * 2.0 * float(model.mode2[2]) / float(model.mode2[1])
    return d


def extend_document(bundle: dict[str, Any], findings: list[Any], model: Any = None) -> dict[str, Any]:
    """The bundle document with every finding's extension recorded; those that belong in the
    compensator change it (creep form, lead, slew, rate-aware inverse, second shaper).

    ``model`` is the diagnosis's final model (all findings applied): when a finding refitted
    the main mode (``Cause.refits_mode``), the main shaper is designed again for it and
    the lead is its low-frequency delay plus the input delay found (the base bundle's lead
    had absorbed part of that delay into the mode's damping; adding the delay to it would
    lead twice)."""
    from piezopress.analysis import diagnosis as dg

    ext = copy.deepcopy(bundle)
    ext["extensions"] = {f.cause: f.parameters for f in findings}
    # what the compensator applies of them, and what it only records: the catalogue says (a cause
    # with an extension of the compensator, Cause.extend, is applied; the others are recorded)
    applied = {c.id for c in dg.CAUSES.values() if c.in_compensator}
    ext["extensions_applied_by_compensator"] = sorted(f.cause for f in findings if f.cause in applied)
    ext["extensions_recorded_only"] = sorted(f.cause for f in findings if f.cause not in applied)
    comp = ext.setdefault("compensation", {})
    # (a second mode does not refit the main mode: its joint refit moves it little, and the base
    # lead, which the refit would shorten, also stands for the delays the lead formula leaves
    # out - the load cell's low-pass, the DAC's hold - so a shorter lead loses more at 50 Hz
    # than the better shaper gains)
    refit_by = []
    for f in findings:
        cause = dg.CAUSES.get(f.cause)
        if cause is not None and cause.extend is not None:
            cause.extend(ext, comp, f)
        if cause is not None and cause.refits_mode:
            refit_by.append(f.cause)
    if model is not None and model.wn and model.zeta and refit_by and "shaper" in ext:
        sh = ext["shaper"]
        try:
            new = design_shaper(sh["shaper"]["name"], float(model.wn), float(model.zeta))
        except FitError:
            new = None  # the design does not hold at the refitted damping: the base shaper stays
        if new is not None:
            sh["shaper"] = {
                **sh["shaper"],
                "times_s": list(new.times_s),
                "amplitudes": list(new.amplitudes),
                "natural_freq_rad_s": new.wn,
                "damping": new.zeta,
                "zv_power": new.zv_power,
                "delay_ms": 1e3 * new.delay_s,
                "centroid_ms": 1e3 * new.centroid_s,
            }
            sh["mode"] = {**sh["mode"], "natural_freq_rad_s": float(model.wn), "damping": float(model.zeta)}
            sh["extended_by"] = f"diagnose: the mode refitted with {', '.join(refit_by)}"
            # the lead's modal part (2 zeta / wn of the base mode) replaced by the refitted modes' low-frequency delay
            old_modal = mode_lag_s(bundle["shaper"]["mode"])
            comp["lead_s"] = (
                float(bundle.get("compensation", {}).get("lead_s", old_modal))
                - old_modal
                + modal_delay_s(model)
                + comp.get("delay_lead_s", 0.0)
            )
    # a drive chain's low-pass refitted with them (an input delay: the identification on steps that
    # lagged by it gave the low-pass part of the delay's lag): recorded, and its lead replaced
    chain = ext.get("shaper", {}).get("mode", {}).get("drive_chain")
    old = _lowpass_delay(chain)
    if model is not None and refit_by and model.drive_lowpass is not None and old is not None:
        wc, zc = (float(v) for v in model.drive_lowpass)
        changes: dict[str, Any] = {}
        if not np.allclose((wc, zc), old[:2], rtol=1e-9):
            changes.update(lowpass_hz=wc / (2.0 * math.pi), lowpass_damping=zc)
        # An input delay found stands for the chain's pure delay beyond the sampling's own: the
        # forward model it was judged with holds the chain's delay only up to that
        # (Bundle.forward_model), so the compensator's chain keeps the same part, or the delay
        # leads twice. On the third test press (a FIFO of 4 samples, seed 3) the chain's
        # 0.28 ms at the steps' 20 kHz and 4.9 samples found led the drive 0.71 ms there where
        # the press lags 0.48 ms.
        kept = float(model.drive_delay_s)
        if "input_delay" in refit_by and old[2] > kept + 1e-12:
            changes.update(delay_s=kept, delay_before_diagnose_s=old[2])
        if "input_delay" in refit_by and chain.get("delay_samples") is not None:
            # the part in samples steps at two rates told held the delay found: led by the finding
            changes.update(delay_samples=None, delay_samples_before_diagnose=chain["delay_samples"])
        if changes:
            # what lead_s held of the chain: all of it in seconds in a bundle written before the
            # sampling's own delay was led in samples
            was = chain_leads(chain)[0] if "chain_lead_samples" in comp else chain_delay_s(chain)
            chain.update(**changes, extended_by=f"diagnose: the chain refitted with {', '.join(refit_by)}")
            now, now_samples = chain_leads(chain)
            comp["lead_s"] = comp.get("lead_s", 0.0) - comp.get("chain_lead_s", was) + now
            comp["chain_lead_s"] = now
            if now_samples:
                comp["chain_lead_samples"] = now_samples
    return ext


__all__ = [
    "Bundle",
    "BundleError",
    "Settings",
    "BUNDLE_VERSION",
    "SECTIONS",
    "LEAD_MAX_FRACTION",
    "creep_removed",
    "chain_delay_s",
    "check_section",
    "extend_document",
    "second_shaper",
    "rate_dependence",
    "creep_for_compensator",
    "modal_delay_s",
    "FAST_CREEP_S",
]
