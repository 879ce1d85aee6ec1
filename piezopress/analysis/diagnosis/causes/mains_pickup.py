"""The catalogue's cause ``mains_pickup``: its fit (the signature it keys on, the extension judged
on held-out data) and its entry in the catalogue (:data:`CAUSE`)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy import signal

from piezopress import units
from piezopress.analysis.diagnosis.cause import Cause
from piezopress.analysis.diagnosis.judging import Context, Finding
from piezopress.analysis.diagnosis.needs import Need, RunSpec
from piezopress.analysis.diagnosis.residuals import judged, noise_floor, rms
from piezopress.analysis.signatures import drive_independent_lines, fit_line, line_of, quiet_stretches

#: A mains line is fitted in a run only where the drive puts less than this share of the line's
#: size at its frequency (through the model's gain): where the drive moves there (a 10 Hz
#: triangle's 5th harmonic is at 50 Hz), the residual at that frequency is the model's.
MAINS_DRIVE_SHARE = 0.2
#: Each run's first share fits its lines, the rest judges them (a hum keeps its phase).
MAINS_FIT_FRACTION = 0.6


def _mains_lines(ctx: Context) -> list:
    """The lines of the current residual at a mains frequency or harmonic, independent of the
    drive (:func:`piezopress.analysis.signatures.drive_independent_lines`)."""
    found = drive_independent_lines(
        [(judged(r, r.t_s), judged(r, r.x), judged(r, r.y - ctx.pred(r)), r.fs_hz, r.name) for r in ctx.runs]
    )
    return [ln for ln in found if ln.mains]


def _band(e: np.ndarray, f: float, fs: float, half_hz: float = 2.0) -> np.ndarray:
    """``e`` within ``half_hz`` of ``f`` (a zero-phase second-order band-pass)."""
    sos = signal.butter(2, [max(f - half_hz, 0.1), min(f + half_hz, 0.45 * fs)], btype="bandpass", fs=fs, output="sos")
    return signal.sosfiltfilt(sos, e)


def cause_mains_pickup(ctx: Context) -> Finding | None:
    """Mains pickup keys on a frequency, not on the drive: a line at 50 or 60 Hz (or a harmonic)
    in the residual where the drive is constant (a rest, a hold), found again with a similar
    size where it moves. Its extension is a line in the reading, fitted run by run (its
    frequency refined within 0.1 Hz, its phase free: the hum is not locked to the drive) on the
    run's first 60 %, judged on the quiet stretches of the rest (each stretch's trend removed:
    creep and drift are other causes'), against the same stretches without it. Runs under
    drive with no quiet stretch held out are judged within 2 Hz of each line (their loop misfit
    is another cause's); they count for the finding's consistency, and for its gain only where
    no run has a quiet stretch. A run whose drive moves at a line's frequency is left out."""
    lines = _mains_lines(ctx)
    if not lines:
        return None
    xs = [float(np.ptp(r.x)) for r in ctx.runs if np.ptp(r.x) > 0]
    gain = max(float(np.ptp(r.y)) for r in ctx.runs) / max(xs) if xs else 0.0
    hum, held_base, held_ext, by_run, used, judged_by = [], [], [], {}, [], []
    band_base: list[np.ndarray] = []
    band_ext: list[np.ndarray] = []
    floors: list[float] = []
    band_floors: list[float] = []
    for r in ctx.runs:
        t, x, e = judged(r, r.t_s), judged(r, r.x), judged(r, r.y - ctx.pred(r))
        freqs = []
        for ln in lines:
            if r.fs_hz < 2.5 * ln.freq_hz or t[-1] - t[0] < 20.0 / ln.freq_hz:
                continue
            if np.ptp(x) > 0:
                _, da, db = fit_line(t, x, ln.freq_hz, r.fs_hz)
                if math.hypot(da, db) * gain > MAINS_DRIVE_SHARE * ln.amplitude:
                    continue  # the drive moves at this frequency: the residual there is the model's
            freqs.append(ln.freq_hz)
        if not freqs:
            continue
        k = int(MAINS_FIT_FRACTION * t.size)
        if t.size - k < 5.0 * r.fs_hz / min(freqs):
            continue
        used.append(r.name)
        early = [fit_line(t[:k], e[:k], f, r.fs_hz) for f in freqs]
        whole = [fit_line(t, e, f, r.fs_hz) for f in freqs]
        hum.extend((r.ident, f, a, b) for f, a, b in whole)
        quiet = [
            slice(max(sl.start, k), sl.stop)
            for sl in quiet_stretches(t, x, r.fs_hz)
            if sl.stop - max(sl.start, k) >= 5.0 * r.fs_hz / min(freqs)  # five periods held out at least
        ]
        fitted_lines = sum(line_of(t, f, a, b) for f, a, b in early)
        if quiet:  # where the drive is constant: what is left of the reading, each stretch's trend removed
            base_r, ext_r = [], []
            for sl in quiet:
                tt, ee = t[sl], e[sl]
                ee = ee - np.polyval(np.polyfit(tt - tt[0], ee, 1), tt - tt[0])
                base_r.append(ee)
                ext_r.append(ee - fitted_lines[sl])
            b_, x_ = np.concatenate(base_r), np.concatenate(ext_r)
            held_base.append(b_)
            held_ext.append(x_)
            floors.append(noise_floor(x_))  # the hum inflates the run's own floor: judged without it
        else:  # under drive: the held-out end within 2 Hz of each line (the rest is the loop model's)
            b_ = np.concatenate([_band(e, f, r.fs_hz)[k:] for f in freqs])
            x_ = np.concatenate([_band(e - fitted_lines, f, r.fs_hz)[k:] for f in freqs])
            band_base.append(b_)
            band_ext.append(x_)
            # white noise within the bands: the floor times sqrt(total bandwidth / Nyquist)
            band_floors.append(noise_floor(e - fitted_lines) * math.sqrt(2.0 * 4.0 * len(freqs) / r.fs_hz))
        judged_by.append(r.name)
        by_run[r.name] = 100.0 * (rms(b_) - rms(x_)) / rms(b_) if rms(b_) > 0 else 0.0
    if not held_base:  # no quiet stretch held out: judged within 2 Hz of the lines under drive
        held_base, held_ext, floors = band_base, band_ext, band_floors
    if not held_base:
        return None
    baseline, extended = rms(np.concatenate(held_base)), rms(np.concatenate(held_ext))
    u = ctx.model.unit
    what = " and ".join(f"{ln.freq_hz:.1f} Hz of {ln.amplitude:.3g} {units.label(u)}" for ln in lines)
    ev = (
        f"a line in the reading at {what}, present where the drive is constant "
        f"({', '.join(lines[0].quiet_runs[:4])}{', ...' if len(lines[0].quiet_runs) > 4 else ''}) and with the same "
        f"size where it moves: mains pickup, independent of the drive; a line fitted per run on its first "
        f"{100 * MAINS_FIT_FRACTION:.0f} % (frequency refined, phase free), judged on the quiet stretches of the rest"
    )
    params: dict[str, float] = {}
    for i, ln in enumerate(lines, 1):
        params[f"line{i}_hz"] = ln.freq_hz
        params[f"line{i}_amplitude_{units.key(u)}"] = ln.amplitude
    return Finding(
        "mains_pickup",
        ev,
        baseline,
        extended,
        100.0 * (baseline - extended) / baseline if baseline > 0 else 0.0,
        params,
        used,
        judged_by,
        max(float(np.ptp(r.y)) for r in ctx.runs),
        float(np.median(floors)),
        replace(ctx.model, hum=ctx.model.hum + tuple(hum)),
        by_run if len(by_run) > 1 else {},
    )


#: The catalogue's entry for this cause (read by every place that names causes).
CAUSE = Cause(
    "mains_pickup",
    "hum from the mains (50 or 60 Hz and harmonics) picked up by the load-cell lead or amplifier, "
    "independent of the drive",
    "a line in the reading at each mains line found, fitted run by run (a notch on the reading)",
    cause_mains_pickup,
    needs=(Need((RunSpec("rest"), RunSpec("creep"), RunSpec("step")), 1),),
)
