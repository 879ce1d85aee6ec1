"""Fit stages: runs in, bundle sections out (hysteresis, creep, shaper).

Each stage picks the runs that suit it from what it is given (or those named), fits, and
returns a section document with parameters in named units, fit quality and provenance.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from piezopress import runformat
from piezopress.analysis import creep as creep_mod
from piezopress.analysis import hysteresis as H
from piezopress.analysis import shaper as shaper_mod
from pipelines.bundle import BundleError, collect_runs, inputs_digest, section

#: Hysteresis is fitted on quasi-static sweeps: up to this drive frequency.
STATIC_MAX_FREQ_HZ = 0.5
#: Mode identification uses the low-amplitude steps: up to this fraction of the largest drive.
LOW_STEP_FRACTION = 0.25


def _freq(run: runformat.Run) -> float | None:
    f = run.meta.get("protocol", {}).get("freq_hz")
    return float(f) if f is not None else None


def hysteresis_runs(runs: list[runformat.Run], named: bool) -> list[runformat.Run]:
    if named:
        return runs
    chosen = [r for r in runs if r.kind in ("triangle", "sine", "custom") and (_freq(r) is None or _freq(r) <= STATIC_MAX_FREQ_HZ)
              and np.ptp(r.command_v) > 0]  # a rest run (no drive) shows no hysteresis
    if not chosen:
        kinds = ", ".join(sorted({f"{r.name} ({r.kind})" for r in runs})) or "none"
        raise BundleError(f"no quasi-static sweep among the runs (triangle/sine at <= {STATIC_MAX_FREQ_HZ:g} Hz); runs given: {kinds}")
    return chosen


def fit_hysteresis_section(paths: Iterable[str | Path], *, names: Iterable[str] = (), holdout_fraction: float = 0.3,
                           grid=None, creep: dict[str, Any] | None = None) -> tuple[dict[str, Any], H.HysteresisFit]:
    """Fit the PI model on the quasi-static sweeps; the section holds the model refitted on
    all samples, and the held-out error of the model fitted without the held-out part.

    With a ``creep`` section, creep is first removed from each measured output (the creep
    compensator applied to it), so the hysteresis model holds only the static part and the
    creep compensator does not remove the same creep a second time.
    """
    runs = select_hysteresis_runs(paths, names)
    out_col = runs[0].output_column
    if any(r.output_column != out_col for r in runs):
        raise BundleError("the runs measure different outputs (force_n and displacement_um); fit them separately")
    outputs = [r.output for r in runs]
    if creep is not None:
        cm = creep_mod.CreepModel.from_dict(creep["model"])
        outputs = []
        for r in runs:
            _, rest = H.rest_offset(r.command_v, r.output)
            outputs.append(rest + cm.compensate(r.output - rest, r.sample_rate_hz)[0])
    data = H.prepare([(r.name, r.command_v, y) for r, y in zip(runs, outputs)], holdout_fraction=holdout_fraction)
    fit = H.fit_hysteresis(data, grid)
    unit = "N" if out_col == "force_n" else "um"
    final = fit.final_model or fit.model
    model = H.PIModel(final.r, final.w, final.d, final.s, final.x0, final.y0, "V", unit)
    body = {
        "output_column": out_col,
        "creep_removed": creep is not None,
        "model": model.to_dict(),
        "fit": {
            "chosen": fit.chosen,
            "reason": fit.reason,
            f"train_rms_{unit.lower()}": fit.train_rms,
            f"holdout_rms_{unit.lower()}": fit.holdout_rms,
            "holdout_rms_pct_of_range": fit.holdout_rms_pct,
            f"output_range_{unit.lower()}": fit.output_range,
            "holdout_fraction": holdout_fraction,
            "pruned_operators": fit.pruned,
            "candidates": fit.candidates,
        },
    }
    digest = hysteresis_digest(runs, creep, holdout_fraction, grid)
    return section("hysteresis", body, runs, digest), fit


def select_hysteresis_runs(paths: Iterable[str | Path], names: Iterable[str] = ()) -> list[runformat.Run]:
    names = list(names)
    return hysteresis_runs(collect_runs(paths, names=names), bool(names))


def hysteresis_digest(runs, creep, holdout_fraction, grid=None) -> str:
    return inputs_digest("hysteresis", runs, [creep], holdout_fraction=holdout_fraction, grid=None if grid is None else [c.label for c in grid])


#: The thesis's model structure (Section 6.2.1: 12 evenly spaced plays, one dead zone;
#: Section 6.3.1: three poles and one zero): the base model that ``diagnose`` extends.
THESIS_GRID = (H.Candidate(12, 1.0, 1),)
THESIS_CREEP_FORMS = ("poles",)


def fit_hysteresis_and_creep(paths: Iterable[str | Path], *, passes: int = 2, holdout_fraction: float = 0.3, base: bool = False):
    """Alternate: hysteresis on the sweeps, creep on the held step given the hysteresis
    model, hysteresis again on the sweeps with that creep removed, ... (``passes`` rounds).

    ``base`` fits the thesis's structure instead of choosing one (:data:`THESIS_GRID`,
    :data:`THESIS_CREEP_FORMS`). Returns the last hysteresis and creep sections and fits.
    """
    paths = list(paths)
    grid = THESIS_GRID if base else None
    forms = THESIS_CREEP_FORMS if base else creep_mod.FORMS
    h, hfit = fit_hysteresis_section(paths, holdout_fraction=holdout_fraction, grid=grid)
    c, cfit = fit_creep_section(paths, h, holdout_fraction=holdout_fraction, forms=forms)
    for _ in range(passes - 1):
        h, hfit = fit_hysteresis_section(paths, holdout_fraction=holdout_fraction, creep=c, grid=grid)
        c, cfit = fit_creep_section(paths, h, holdout_fraction=holdout_fraction, forms=forms)
    return h, hfit, c, cfit


def _rest_level(y: np.ndarray, x: np.ndarray) -> float:
    """Mean output while the drive is still at its first value (before the step)."""
    still = np.flatnonzero(np.abs(x - x[0]) > 1e-9)
    n = int(still[0]) if still.size else x.size
    return float(np.mean(y[: max(n, 1)]))


#: Creep is fitted below this rate: faster dynamics (slew, ringing) are filtered out of both signals.
CREEP_FIT_RATE_HZ = 50.0


def _slow_part(t_s: np.ndarray, u: np.ndarray, y: np.ndarray, fs_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Input and output through the same low-pass (so an LTI relation between them holds
    unchanged) and decimated to ``CREEP_FIT_RATE_HZ``: the millisecond step transient (the
    amplifier's slew, the mode's ringing) is not creep and must not be fitted as creep."""
    from scipy import signal

    step = max(1, int(round(fs_hz / CREEP_FIT_RATE_HZ)))
    if step == 1:
        return t_s, u, y
    sos = signal.butter(4, 0.8 / step, output="sos")  # below the new Nyquist frequency
    zi = signal.sosfilt_zi(sos)
    uf = signal.sosfilt(sos, u, zi=zi * u[0])[0]
    yf = signal.sosfilt(sos, y, zi=zi * y[0])[0]
    return t_s[::step], uf[::step], yf[::step]


def fit_creep_section(paths: Iterable[str | Path], hysteresis: dict[str, Any], *, names: Iterable[str] = (),
                      holdout_fraction: float = 0.3, forms: tuple[str, ...] = creep_mod.FORMS) -> tuple[dict[str, Any], creep_mod.CreepFit]:
    """Fit the creep of the hysteresis-compensated press from a held step: the hysteresis
    model's static prediction is the input, the measured force (above the rest level) the
    output."""
    run = select_creep_run(paths, names)
    model = H.PIModel.from_dict(hysteresis["model"])
    static, _ = model.forward(run.command_v)
    u = static - model.y0
    y = run.output - _rest_level(run.output, run.command_v)
    t, u, y = _slow_part(run.t_s, u, y, run.sample_rate_hz)
    fit = creep_mod.fit_creep(t, u, y, holdout_fraction=holdout_fraction, forms=forms)
    fit.model.check_stable(run.sample_rate_hz)
    body = {
        "model": fit.model.to_dict(),
        "fit": {
            "chosen_form": fit.form,
            "reason": fit.reason,
            "rms_n": fit.rms,
            "holdout_fraction": holdout_fraction,
            "candidates": [_plain(c) for c in fit.candidates],
        },
    }
    return section("creep", body, [run], creep_digest(run, hysteresis, holdout_fraction, forms)), fit


def select_creep_run(paths: Iterable[str | Path], names: Iterable[str] = ()) -> runformat.Run:
    names = list(names)
    runs = collect_runs(paths, names=names)
    if not names:
        runs = [r for r in runs if r.kind == "creep"]
    if not runs:
        raise BundleError("no creep run (a step held for a long time, kind 'creep') among the runs given")
    return max(runs, key=lambda r: r.t_s[-1])


def creep_digest(run, hysteresis, holdout_fraction, forms=creep_mod.FORMS) -> str:
    return inputs_digest("creep", [run], [hysteresis], holdout_fraction=holdout_fraction, forms=list(forms))


def _sensor_lowpass(runs: list[runformat.Run]) -> float | None:
    """The load cell's analog low-pass, when the runs' rig configuration states it."""
    for r in runs:
        f = r.meta.get("rig", {}).get("config", {}).get("load_cell", {}).get("lowpass_hz")
        if f:
            return float(f)
    return None


def _first_hold_end(command_v: np.ndarray) -> int:
    """Samples up to the end of the first step's hold (a step protocol steps back at its end)."""
    changes = np.flatnonzero(np.abs(np.diff(command_v)) > 1e-9)
    return int(changes[1] + 1) if changes.size > 1 else command_v.size


def fit_shaper_section(paths: Iterable[str | Path], *, names: Iterable[str] = (), fs_hz: float | None = None) -> tuple[dict[str, Any], Any]:
    """Identify the mode from the low-amplitude steps against the drive actually applied
    (the amplifier monitor when recorded), then design and choose the input shaper."""
    runs = select_shaper_runs(paths, names)
    cuts = [_first_hold_end(r.command_v) for r in runs]
    drives = [(r.column("monitor_v") if r.column("monitor_v") is not None else r.command_v)[:n] for r, n in zip(runs, cuts)]
    args = ([r.t_s[:n] for r, n in zip(runs, cuts)], drives, [r.output[:n] for r, n in zip(runs, cuts)])
    # a DAC command is held between samples, a sampled amplifier monitor is closer to linear
    # between them; both discretisations are exact for their kind of drive: keep the better fit
    fits = [shaper_mod.identify_mode_runs(*args, hold=hold) for hold in ("zoh", "foh")]
    fit = min(fits, key=lambda f: float(np.mean(f.rms_residual)))
    fs = fs_hz or max(r.sample_rate_hz for r in runs)
    # only the designs valid at the identified damping (EI's closed form stops at 0.5)
    usable = tuple(n for n in ("zv", "zvd", "zvdd", "ei") if fit.zeta < shaper_mod.SHAPERS[n].zeta_range[1])
    choice = shaper_mod.choose_shaper(fit.wn, fit.zeta, fs, candidates=usable)
    sh = choice.shaper
    body = {
        "mode": {
            "natural_freq_rad_s": fit.wn,
            "damping": fit.zeta,
            "drive_used": "monitor_v" if all(r.column("monitor_v") is not None for r in runs) else "command_v",
            "hold": fit.hold,
            "sensor_lowpass_hz": _sensor_lowpass(runs),
            "fit": {k: v for k, v in _plain(fit).items() if k not in ("wn", "zeta")},
        },
        "shaper": {"name": sh.name, "times_s": list(sh.times_s), "amplitudes": list(sh.amplitudes),
                   "natural_freq_rad_s": sh.wn, "damping": sh.zeta, "zv_power": sh.zv_power,
                   "delay_ms": 1e3 * sh.delay_s, "centroid_ms": 1e3 * sh.centroid_s},
        "choice": {"reason": choice.reason, "designed_at_hz": fs, "candidates": choice.table},
        "thesis_table_6_8": shaper_mod.thesis_shaper_residual(fit.wn, fit.zeta),
    }
    return section("shaper", body, runs, shaper_digest(runs, fs_hz)), fit


def select_shaper_runs(paths: Iterable[str | Path], names: Iterable[str] = ()) -> list[runformat.Run]:
    names = list(names)
    runs = collect_runs(paths, names=names)
    if not names:
        steps = [r for r in runs if r.kind == "step"]
        top = max((float(np.max(r.command_v)) for r in steps), default=0.0)
        drive_max = max([top] + [float(r.meta.get("rig", {}).get("config", {}).get("actuator", {}).get("drive_max_v", 0.0)) for r in steps])
        runs = [r for r in steps if float(np.max(r.command_v)) <= LOW_STEP_FRACTION * drive_max + 1e-9]
    if not runs:
        raise BundleError(f"no low-amplitude step run (kind 'step', at most {100 * LOW_STEP_FRACTION:g} % of the largest drive) among the runs given")
    return runs


def shaper_digest(runs, fs_hz) -> str:
    return inputs_digest("shaper", runs, [], fs_hz=fs_hz)


def _plain(obj: Any) -> dict[str, Any]:
    """A dataclass's JSON-friendly fields (arrays to lists, non-finite floats to None)."""
    import dataclasses

    out = {}
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if hasattr(v, "to_dict"):
            v = v.to_dict()
        elif isinstance(v, np.ndarray):
            v = v.tolist()
        elif isinstance(v, tuple):
            v = [x.tolist() if isinstance(x, np.ndarray) else x for x in v]
        if isinstance(v, float) and not math.isfinite(v):
            v = None
        out[f.name] = v
    return out


def compensation_settings(sections: dict[str, dict[str, Any]], *, max_rate_n_per_s: float = 40_000.0,
                          drive_min_v: float = 0.0, drive_max_v: float = 150.0) -> dict[str, Any]:
    """Compensation settings: drive range, reference rate limit and the drive's lead.

    The lead is the mode's low-frequency group delay ``2 zeta / wn`` (the shaper itself is
    applied centred on its centroid, so it adds none on average).
    """
    lead = 0.0
    if "shaper" in sections:
        m = sections["shaper"]["mode"]
        lead = 2.0 * m["damping"] / m["natural_freq_rad_s"]
    return {"drive_min_v": drive_min_v, "drive_max_v": drive_max_v, "max_rate_n_per_s": max_rate_n_per_s, "lead_s": lead}
