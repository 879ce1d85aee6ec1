"""Fit stages: runs in, bundle sections out (hysteresis, creep, shaper).

Each stage picks the runs that suit it from what it is given (or those named), fits, and
returns a section document with parameters in named units, fit quality and provenance.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from piezopress import runformat, units
from piezopress.analysis import creep as creep_mod
from piezopress.analysis import hysteresis as H
from piezopress.analysis import mode_fit, profile
from piezopress.analysis import shaper as shaper_mod
from piezopress.analysis.bundle import Bundle, creep_removed
from piezopress.errors import CompensatorUnstableError, FitError
from piezopress.pipelines import profiles
from piezopress.pipelines.bundle import BundleError, assemble, collect_runs, inputs_digest, section

#: Hysteresis is fitted on quasi-static sweeps: up to this drive frequency.
STATIC_MAX_FREQ_HZ = 0.5
#: Mode identification uses the low-amplitude steps: up to this fraction of the largest drive.
LOW_STEP_FRACTION = 0.25


def _freq(run: runformat.Run) -> float | None:
    """The run's sweep frequency measured from its drive (None: not a sweep)."""
    return profile.of(run).freq_hz


def hysteresis_runs(runs: list[runformat.Run], named: bool) -> list[runformat.Run]:
    """The quasi-static sweeps: sweeps at a measured frequency of at most STATIC_MAX_FREQ_HZ,
    else the slowest sweeps up to :data:`piezopress.analysis.profile.SLOWEST_SWEEP_MAX_HZ` (said on stderr)."""
    if named:
        return runs
    sweeps = [r for r in runs if profile.of(r).is_sweep]
    chosen = [r for r in sweeps if profile.of(r).quasi_static]
    if not chosen and sweeps:
        limit = profile.slow_limit_hz([_freq(r) for r in sweeps])
        chosen = [r for r in sweeps if _freq(r) <= limit]
        if chosen:
            profiles.note(
                f"no sweep at <= {STATIC_MAX_FREQ_HZ:g} Hz among the runs; hysteresis is fitted on the slowest, "
                f"{', '.join(f'{r.name} ({_freq(r):.3g} Hz)' for r in chosen)}"
            )
    if not chosen:
        kinds = ", ".join(sorted({f"{r.name} ({profile.of(r).describe()})" for r in runs})) or "none"
        raise BundleError(
            f"no quasi-static sweep among the runs (a triangle or sine at <= {STATIC_MAX_FREQ_HZ:g} Hz, "
            f"measured from the drive); runs given: {kinds}"
        )
    return chosen


def fitted_rows(
    runs: list[runformat.Run], skip_s: float | None = None, rows: tuple[int | None, int | None] | None = None
):
    """Per run, the samples kept (``stop``) and the start not fitted (``skip``, ``None``: detected).

    ``skip_s`` skips that many seconds at the start of every run; ``rows = (start, stop)``
    fits rows ``start`` to ``stop - 1`` (0-based, ``stop`` excluded) of every run. Skipped
    rows are still evaluated (they carry the model's state); rows from ``stop`` on are dropped.
    """
    stops, skips = [], []
    for r in runs:
        n = r.t_s.size
        start, stop = rows if rows is not None else (None, None)
        stop = n if stop is None else int(stop)
        if not 0 < stop <= n:
            raise BundleError(f"{r.name}: --rows stop {stop} is outside the run's {n} rows; expected 1 to {n}")
        skip = None
        if skip_s is not None:
            if not 0 <= skip_s < r.t_s[-1] - r.t_s[0]:
                raise BundleError(
                    f"{r.name}: --skip-s {skip_s:g} s; expected 0 to {r.t_s[-1] - r.t_s[0]:.4g} s (the run's length)"
                )
            skip = int(round(skip_s * r.sample_rate_hz))
        if start is not None:
            skip = max(skip or 0, int(start))
        if skip is not None and not 0 <= skip < stop - 20:
            raise BundleError(
                f"{r.name}: the fit would start at row {skip} and stop before row {stop}; expected at least 20 rows "
                "between"
            )
        stops.append(stop)
        skips.append(skip)
    return stops, (None if all(k is None for k in skips) else [k for k in skips])


def _hysteresis_body(
    out_col: str, model: H.PIModel, creep_removed: bool, fit_figures: dict[str, Any]
) -> dict[str, Any]:
    return {"output_column": out_col, "creep_removed": creep_removed, "model": model.to_dict(), "fit": fit_figures}


def _same_output(runs: list[runformat.Run]) -> str:
    out_col = runs[0].output_column
    if any(r.output_column != out_col for r in runs):
        raise BundleError("the runs measure different outputs (force_n and displacement_um); fit them separately")
    return out_col


def fit_hysteresis_section(
    paths: Iterable[str | Path],
    *,
    names: Iterable[str] = (),
    holdout_fraction: float = 0.3,
    grid=None,
    creep: dict[str, Any] | None = None,
    skip_s: float | None = None,
    rows: tuple[int | None, int | None] | None = None,
) -> tuple[dict[str, Any], H.HysteresisFit]:
    """Fit the PI model on the quasi-static sweeps; the section holds the model refitted on
    all samples, and the held-out error of the model fitted without the held-out part.

    With a ``creep`` section, creep is first removed from each measured output (the creep
    compensator applied to it), so the hysteresis model holds only the static part and the
    creep compensator does not remove the same creep a second time. ``skip_s``/``rows``: see
    :func:`fitted_rows` (by default the start that is not part of the sweep is detected:
    :func:`piezopress.analysis.hysteresis.settled_start`).
    """
    runs = select_hysteresis_runs(paths, names)
    out_col = _same_output(runs)
    stops, skips = fitted_rows(runs, skip_s, rows)
    cm = creep_mod.CreepModel.from_dict(creep["model"]) if creep is not None else None
    outputs = [creep_removed(cm, r.command_v, r.output, r.sample_rate_hz) for r in runs]
    data = H.prepare(
        [(r.name, r.command_v[:n], y[:n]) for r, y, n in zip(runs, outputs, stops)],
        holdout_fraction=holdout_fraction,
        skip=skips,
    )
    fit = H.fit_hysteresis(data, grid)
    unit = units.unit_of_column(out_col)  # "N" or "um": keys below are train_rms_n / train_rms_um
    final = fit.final_model or fit.model
    model = replace(final, input_unit="V", output_unit=unit)
    figures = {
        "chosen": fit.chosen,
        "family": model.family,
        "family_reason": fit.family_reason,
        "reason": fit.reason,
        f"train_rms_{unit.lower()}": fit.train_rms,
        f"holdout_rms_{unit.lower()}": fit.holdout_rms,
        "holdout_rms_pct_of_range": fit.holdout_rms_pct,
        f"output_range_{unit.lower()}": fit.output_range,
        "holdout_fraction": holdout_fraction,
        "fitted_from_row": [int(np.argmax(t)) for t in data.train],
        # the rows every command judges the model on (fit, simulate, diagnose, the report): per run, the
        # held-out rows from this one to the stop; the start before fitted_from_row is never counted as misfit
        "held_out_from_row": [int(np.argmax(h)) if h.any() else int(h.size) for h in data.holdout],
        "stop_row": [int(n) for n in stops],
        "pruned_operators": fit.pruned,
        "candidates": fit.candidates,
    }
    digest = hysteresis_digest(runs, creep, holdout_fraction, grid, skip_s=skip_s, rows=rows)
    return section("hysteresis", _hysteresis_body(out_col, model, creep is not None, figures), runs, digest), fit


def fit_sweep_sections(
    paths: Iterable[str | Path],
    *,
    names: Iterable[str] = (),
    holdout_fraction: float = 0.3,
    grid=None,
    skip_s: float | None = None,
    rows: tuple[int | None, int | None] | None = None,
):
    """Hysteresis and, when the sweeps show it, creep, from the sweeps alone (no held step):
    :func:`piezopress.analysis.identify.fit_sweeps`. Returns the hysteresis section, the
    creep section (``None`` when creep did not predict the held-out ends better) and the fit."""
    from piezopress.analysis import identify

    runs = select_hysteresis_runs(paths, names)
    out_col = _same_output(runs)
    stops, skips = fitted_rows(runs, skip_s, rows)
    found = identify.fit_sweeps(
        [(r.name, r.command_v[:n], r.output[:n], r.sample_rate_hz) for r, n in zip(runs, stops)],
        holdout_fraction=holdout_fraction,
        grid=grid,
        skip=skips,
    )
    unit = units.unit_of_column(out_col)
    final = found.model
    model = replace(final, input_unit="V", output_unit=unit)
    k = unit.lower()
    figures = {
        "chosen": found.hysteresis.chosen,
        "family": model.family,
        "family_reason": found.hysteresis.family_reason,
        "reason": found.reason,
        f"train_rms_{k}": found.train_rms,
        f"holdout_rms_{k}": found.holdout_rms,
        f"holdout_rms_without_creep_{k}": found.holdout_rms_static,
        "holdout_rms_pct_of_range": found.holdout_rms_pct,
        f"output_range_{k}": found.output_range,
        "holdout_fraction": holdout_fraction,
        "fitted_from_row": [a for a, _, _ in found.rows],
        "held_out_from_row": [h for _, h, _ in found.rows],
        "stop_row": [n for _, _, n in found.rows],
        "pruned_operators": found.hysteresis.pruned,
        "candidates": found.hysteresis.candidates,
    }
    digest = inputs_digest(
        "sweeps",
        runs,
        [],
        holdout_fraction=holdout_fraction,
        grid=None if grid is None else [c.label for c in grid],
        skip_s=skip_s,
        rows=rows,
    )
    h = section("hysteresis", _hysteresis_body(out_col, model, found.creep is not None, figures), runs, digest)
    c = None
    if found.creep is not None:
        body = {
            "model": found.creep.to_dict(),
            "fit": {
                "chosen_form": "kv",
                "source": "sweeps",
                "reason": found.creep_reason,
                f"rms_{units.key(unit)}": found.train_rms,
                "output_unit": unit,
                "holdout_fraction": holdout_fraction,
                "candidates": [],
            },
        }
        c = section("creep", body, runs, digest)
    return h, c, found


def select_hysteresis_runs(paths: Iterable[str | Path], names: Iterable[str] = ()) -> list[runformat.Run]:
    names = list(names)
    return hysteresis_runs(collect_runs(paths, names=names), bool(names))


def hysteresis_digest(runs, creep, holdout_fraction, grid=None, skip_s=None, rows=None) -> str:
    extra = {} if skip_s is None and rows is None else {"skip_s": skip_s, "rows": rows}
    return inputs_digest(
        "hysteresis",
        runs,
        [creep],
        holdout_fraction=holdout_fraction,
        grid=None if grid is None else [c.label for c in grid],
        **extra,
    )


#: The thesis's model structure (Section 6.2.1: 12 evenly spaced plays, one dead zone;
#: Section 6.3.1: three poles and one zero): the base model that ``diagnose`` extends.
THESIS_GRID = (H.Candidate(12, 1.0, 1),)
THESIS_CREEP_FORMS = ("poles",)


#: A creep form agrees with the quasi-static sweeps when its pair (the hysteresis model fitted
#: with its creep removed, followed by the creep) predicts the sweeps' held-out ends within
#: this fraction of the best prediction: the best pair's, or the first hysteresis model's alone.
CREEP_SWEEP_TOLERANCE = 0.20
#: Where no creep form agrees with the sweeps, the form kept from the hold alone (stable by construction).
CREEP_FALLBACK_FORM = "spectrum"


def sweep_holdout_rms(
    sweeps: list[runformat.Run],
    hysteresis: H.PIModel,
    creep: creep_mod.CreepModel | None,
    holdout_fraction: float = 0.3,
) -> float:
    """RMS error of ``creep`` after ``hysteresis`` (both simulated from rest over each whole
    sweep) on the held-out end of each sweep, in the output's unit; ``creep=None``: the
    hysteresis model alone."""
    errors = []
    for r in sweeps:
        y, _ = hysteresis.forward(r.command_v)
        if creep is not None:
            y = hysteresis.y0 + creep.response(y - hysteresis.y0, r.sample_rate_hz)[0]
        start = int(round((1.0 - holdout_fraction) * y.size)) if holdout_fraction > 0 else 0
        errors.append(r.output[start:] - y[start:])
    e = np.concatenate(errors)
    return float(np.sqrt(np.mean(e**2)))


def fit_hysteresis_and_creep(
    paths: Iterable[str | Path],
    *,
    passes: int = 2,
    holdout_fraction: float = 0.3,
    base: bool = False,
    skip_s: float | None = None,
    rows: tuple[int | None, int | None] | None = None,
):
    """Alternate: hysteresis on the sweeps, creep on the held step given the hysteresis
    model, hysteresis again on the sweeps with that creep removed, ... (``passes`` rounds),
    for each creep form on its own; keep the form whose pair agrees with the sweeps.

    The held step alone cannot tell creep from the fast effects at its edge (a rate-dependent
    loop recovering, an input delay, the mode's ringing: its first tenths of a second), and a
    creep form that fits them passes them on, through the alternation, into the static
    hysteresis model: on a press with rate-dependent hysteresis, a poles form that fitted the
    step's first 0.1 s with two cancelling poles raised the compensated 0.1 Hz hysteresis of a
    75 N triangle from 1.7 % to 3.1 %. So each form's pair (the last hysteresis model fitted
    on the training part of the sweeps, then the creep) is checked on the runs that show the
    creep at the static compensation's time scale, the sweeps' held-out ends
    (:func:`sweep_holdout_rms`): a form more than :data:`CREEP_SWEEP_TOLERANCE` worse than the
    best prediction (the best pair's, or the first hysteresis model's alone) disagrees with
    them. Among the forms that agree, the hold's held-out end chooses (only the hold shows
    the creep of minutes). None agrees (the loop model itself misfits the sweeps, as on a
    press of another family): the creep is still kept, fitted on the hold alone as the
    :data:`CREEP_FALLBACK_FORM` form against the first hysteresis model, without alternation
    (so it cannot reshape the loop), and the reason says so. With ``passes=1`` the hysteresis
    model keeps the sweeps' creep, and ``base`` has one form by definition: there the check is recorded, not enforced.

    ``base`` fits the thesis's structure instead of choosing one (:data:`THESIS_GRID`,
    :data:`THESIS_CREEP_FORMS`). Returns the last hysteresis and creep sections and fits;
    the creep section's ``fit`` lists every form with its hold and sweep errors.
    """
    import dataclasses

    paths = list(paths)
    grid = THESIS_GRID if base else None
    forms = THESIS_CREEP_FORMS if base else creep_mod.FORMS
    h0, h0fit = fit_hysteresis_section(paths, holdout_fraction=holdout_fraction, grid=grid, skip_s=skip_s, rows=rows)
    sweeps = select_hysteresis_runs(paths)
    alone = sweep_holdout_rms(sweeps, h0fit.model, None, holdout_fraction)
    tried, failed = [], []
    for form in forms:
        try:
            h, hfit = h0, h0fit
            c, cfit = fit_creep_section(paths, h, holdout_fraction=holdout_fraction, forms=(form,))
            for _ in range(passes - 1):
                h, hfit = fit_hysteresis_section(
                    paths, holdout_fraction=holdout_fraction, creep=c, grid=grid, skip_s=skip_s, rows=rows
                )
                c, cfit = fit_creep_section(paths, h, holdout_fraction=holdout_fraction, forms=(form,))
        except (FitError, CompensatorUnstableError) as exc:
            failed.append(f"{form}: {exc}")
            continue
        tried.append((form, h, hfit, c, cfit, sweep_holdout_rms(sweeps, hfit.model, cfit.model, holdout_fraction)))
    fallback = ""
    if not tried:
        # not one form could be fitted (cancelling poles on a delayed step's edge, say): the
        # creep the hold shows is still kept, in the simplest stable form, and the reason said
        c, cfit = fit_creep_section(paths, h0, holdout_fraction=holdout_fraction, forms=("spectrum",))
        tried.append(
            (
                CREEP_FALLBACK_FORM,
                h0,
                h0fit,
                c,
                cfit,
                sweep_holdout_rms(sweeps, h0fit.model, cfit.model, holdout_fraction),
            )
        )
        fallback = (
            f"; the form{'s' if len(forms) > 1 else ''} asked for could not be fitted ({'; '.join(failed)}): the creep "
            f"is kept from the hold alone, as the {CREEP_FALLBACK_FORM} form without alternation"
        )
    limit = (1.0 + CREEP_SWEEP_TOLERANCE) * min([alone] + [t[5] for t in tried])
    agree = {t[0] for t in tried if t[5] <= limit}
    enforced = passes >= 2 and not base  # base: the thesis's form, whatever the check says
    pool = [t for t in tried if t[0] in agree or not enforced or fallback]  # a forced fallback is the one form
    sweeps_note = f"the sweeps' held-out RMS is {alone:.4g} from the hysteresis model alone"
    if not pool:
        # No form's pair agrees with the sweeps: the loop model misfits them (a press of another
        # family), and its misfit must not veto the creep that the hold alone measures clearly.
        # The simplest stable form is kept instead: the relaxation spectrum (non-negative
        # weights), fitted on the hold against the first hysteresis model, with no alternation
        # so that it cannot reshape the loop.
        disagreed = ", ".join(f"{t[5]:.4g} with the {t[0]} creep" for t in tried)
        c, cfit = fit_creep_section(paths, h0, holdout_fraction=holdout_fraction, forms=("spectrum",))
        spec = (
            CREEP_FALLBACK_FORM,
            h0,
            h0fit,
            c,
            cfit,
            sweep_holdout_rms(sweeps, h0fit.model, cfit.model, holdout_fraction),
        )
        tried.append(spec)
        pool = [spec]
        fallback = (
            f"; the forms alternated with the loop disagreed with the quasi-static sweeps ({sweeps_note}, "
            f"{disagreed}, more than "
            f"{100 * CREEP_SWEEP_TOLERANCE:g} % above the best), so the loop model does not fit these sweeps well: "
            "the creep "
            f"is kept from the hold alone, as the {CREEP_FALLBACK_FORM} form without alternation"
        )
    best = min(pool, key=lambda t: t[4].candidates[0].holdout_rms)
    form, h, hfit, c, cfit, rms = best
    others = (
        "; ".join(
            f"{t[0]} {t[4].candidates[0].holdout_rms:.4g}"
            + ("" if t[0] in agree else f" (disagrees with the sweeps: {t[5]:.4g})")
            for t in tried
            if t[0] != form
        )
        or "no other form"
    )
    reason = (
        f"{form}: lowest held-out RMS {cfit.candidates[0].holdout_rms:.4g} on the hold (judged after "
        f"{cfit.split_s:.4g} s) "
        f"among the forms {'that agree with the sweeps' if enforced else 'tried'}, against {others}; {sweeps_note}, "
        f"{rms:.4g} with this creep"
        + ("" if form in agree or fallback else " (disagrees with the sweeps; kept: the check is not enforced here)")
        + fallback
    )
    c["fit"]["reason"] = reason
    c["fit"]["candidates"] = [
        {**_plain(t[4].candidates[0]), "sweep_holdout_rms": t[5], "agrees_with_sweeps": t[0] in agree} for t in tried
    ]
    c["fit"]["sweep_check"] = {
        "hysteresis_alone_rms": alone,
        "with_creep_rms": rms,
        "tolerance": CREEP_SWEEP_TOLERANCE,
        "enforced": enforced,
        "fallback": bool(fallback),
        "holdout_fraction": holdout_fraction,
        "sweeps": [r.name for r in sweeps],
        "failed": failed,
    }
    cfit = dataclasses.replace(cfit, reason=reason, candidates=tuple(t[4].candidates[0] for t in tried))
    return h, hfit, c, cfit


def fit_creep_section(
    paths: Iterable[str | Path],
    hysteresis: dict[str, Any],
    *,
    names: Iterable[str] = (),
    holdout_fraction: float = 0.3,
    forms: tuple[str, ...] = creep_mod.FORMS,
) -> tuple[dict[str, Any], creep_mod.CreepFit]:
    """Fit the creep of the hysteresis-compensated press from a held step: the hysteresis
    model's static prediction is the input, the measured force (above the rest level) the
    output."""
    run = select_creep_run(paths, names)
    model = H.PIModel.from_dict(hysteresis["model"])
    static, _ = model.forward(run.command_v)
    fit = creep_mod.fit_held_step(
        run.t_s,
        static - model.y0,
        run.command_v,
        run.output,
        run.sample_rate_hz,
        holdout_fraction=holdout_fraction,
        forms=forms,
    )
    fit.model.check_stable(run.sample_rate_hz)
    body = {
        "model": fit.model.to_dict(),
        "fit": {
            "chosen_form": fit.form,
            "reason": fit.reason,
            f"rms_{units.key(model.output_unit)}": fit.rms,
            "output_unit": model.output_unit,
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


def _same_output_unit(runs: list[runformat.Run]) -> str:
    """The runs' one output unit (the shaper section records it: one unit across a bundle's sections)."""
    return units.unit_of_column(_same_output(runs))


def _sensor_lowpass(runs: list[runformat.Run]) -> float | None:
    """The load cell's analog low-pass, when the runs' rig configuration states it."""
    for r in runs:
        f = runformat.meta_number(r.meta, "rig", "config", "load_cell", "lowpass_hz")
        if f:
            return float(f)
    return None


def _first_hold_end(command_v: np.ndarray) -> int:
    """Samples up to the end of the first step's hold (a step protocol steps back at its end)."""
    changes = np.flatnonzero(np.abs(np.diff(command_v)) > 1e-9)
    return int(changes[1] + 1) if changes.size > 1 else command_v.size


def fit_shaper_section(
    paths: Iterable[str | Path], *, names: Iterable[str] = (), fs_hz: float | None = None
) -> tuple[dict[str, Any], Any]:
    """Identify the mode from the low-amplitude steps against the drive actually applied
    (the amplifier monitor when recorded), then design and choose the input shaper."""
    runs = select_shaper_runs(paths, names)
    cuts = [_first_hold_end(r.command_v) for r in runs]
    monitored = all(r.column("monitor_v") is not None for r in runs)
    chain = None
    if monitored:
        drives = [r.column("monitor_v")[:n] for r, n in zip(runs, cuts)]
        args = ([r.t_s[:n] for r, n in zip(runs, cuts)], drives, [r.output[:n] for r, n in zip(runs, cuts)])
        # a DAC command is held between samples, a sampled amplifier monitor is closer to linear
        # between them; both discretisations are exact for their kind of drive: keep the better fit
        fits = [mode_fit.identify_mode_runs(*args, hold=hold) for hold in ("zoh", "foh")]
        fit = min(fits, key=lambda f: float(np.mean(f.rms_residual)))
    else:  # the applied drive is not recorded: the chain from command to stack is identified with the mode
        # the chain is told apart on steps of every size (a slew lengthens only the large steps' rise)
        steps = [r for r in collect_runs(paths) if r.kind == "step"] if not list(names) else runs
        scuts = [_first_hold_end(r.command_v) for r in steps]
        chain = mode_fit.identify_mode_chain(
            [r.t_s[:n] for r, n in zip(runs, cuts)],
            [r.command_v[:n] for r, n in zip(runs, cuts)],
            [r.output[:n] for r, n in zip(runs, cuts)],
            chain_from=(
                [r.t_s[:n] for r, n in zip(steps, scuts)],
                [r.command_v[:n] for r, n in zip(steps, scuts)],
                [r.output[:n] for r, n in zip(steps, scuts)],
            ),
        )
        fit = chain.mode
    fs = fs_hz or max(r.sample_rate_hz for r in runs)
    # only the designs valid at the identified damping (EI's closed form stops at 0.5)
    usable = tuple(n for n in ("zv", "zvd", "zvdd", "ei") if fit.zeta < shaper_mod.SHAPERS[n].zeta_range[1])
    choice = shaper_mod.choose_shaper(fit.wn, fit.zeta, fs, candidates=usable)
    sh = choice.shaper
    body = {
        "mode": {
            "natural_freq_rad_s": fit.wn,
            "damping": fit.zeta,
            "drive_used": "monitor_v" if monitored else "command_v",
            "drive_chain": None
            if chain is None
            else {
                "form": chain.chain,
                "slew_v_per_s": chain.slew_v_per_s,
                "tau_s": chain.tau_s,
                "delay_s": chain.delay_s,
                "rms_by_chain": chain.candidates,
            },
            "hold": fit.hold,
            "output_unit": _same_output_unit(runs),
            "sensor_lowpass_hz": _sensor_lowpass(runs),
            "fit": {k: v for k, v in _plain(fit).items() if k not in ("wn", "zeta")},
        },
        "shaper": {
            "name": sh.name,
            "times_s": list(sh.times_s),
            "amplitudes": list(sh.amplitudes),
            "natural_freq_rad_s": sh.wn,
            "damping": sh.zeta,
            "zv_power": sh.zv_power,
            "delay_ms": 1e3 * sh.delay_s,
            "centroid_ms": 1e3 * sh.centroid_s,
        },
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
        drive_max = max(
            [top] + [runformat.meta_number(r.meta, "rig", "config", "actuator", "drive_max_v") or 0.0 for r in steps]
        )
        runs = [r for r in steps if float(np.max(r.command_v)) <= LOW_STEP_FRACTION * drive_max + 1e-9]
    if not runs:
        raise BundleError(
            f"no low-amplitude step run (kind 'step', at most {100 * LOW_STEP_FRACTION:g} % of the largest drive) "
            "among the runs given"
        )
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


#: Default reference rate limit of a force bundle (N/s): 40 N/ms keeps the drive current of the
#: thesis's press below its amplifier's limit. A displacement bundle has no default limit.
FORCE_MAX_RATE_N_PER_S = 40_000.0


def compensation_settings(
    sections: dict[str, dict[str, Any]],
    *,
    max_rate_per_s: float | None = None,
    drive_min_v: float = 0.0,
    drive_max_v: float = 150.0,
) -> dict[str, Any]:
    """Compensation settings: drive range, reference rate limit and the drive's lead.

    The lead is the mode's low-frequency group delay ``2 zeta / wn`` (the shaper itself is
    applied centred on its centroid, so it adds none on average). A delay-like drive chain
    identified with the mode (``shaper.mode.drive_chain``) is the press's own and is not led
    here (a load cell's filter delays the reading, not the force); ``diagnose`` names a delay
    beyond it. The rate limit is in the
    hysteresis model's output unit per second, under the key ``max_rate_n_per_s`` or
    ``max_rate_um_per_s``; without ``max_rate_per_s`` a force bundle gets
    :data:`FORCE_MAX_RATE_N_PER_S` and a displacement bundle none (``null``: no limit).
    """
    unit = sections["hysteresis"]["model"].get("output_unit", units.FORCE) if "hysteresis" in sections else units.FORCE
    if max_rate_per_s is None and units.is_force(unit):
        max_rate_per_s = FORCE_MAX_RATE_N_PER_S
    lead = 0.0
    if "shaper" in sections:
        m = sections["shaper"]["mode"]
        lead = 2.0 * m["damping"] / m["natural_freq_rad_s"]
    return {
        "drive_min_v": drive_min_v,
        "drive_max_v": drive_max_v,
        f"max_rate_{units.key(unit)}_per_s": max_rate_per_s,
        "lead_s": lead,
    }


# --------------------------------------------------------------------------- every stage the runs allow


@dataclass
class FitAll:
    """What ``fit`` made of the runs: the sections it could fit (and their fits), and for
    every other section why it could not be fitted."""

    sections: dict[str, dict[str, Any]]
    fits: dict[str, Any]
    not_fitted: dict[str, str]
    unit: str
    drive_v: tuple[float, float]


def _why_runs_unfit(section: str, runs: list[runformat.Run], unit: str) -> str | None:
    other = sorted({r.output_column for r in runs if r.output_unit != unit})
    if other:
        return (
            f"the {section} run(s) {', '.join(r.name for r in runs)} measure {', '.join(other)}, the sweeps "
            f"{'force_n' if units.is_force(unit) else 'displacement_um'}; fit them separately"
        )
    return None


def fit_all(
    paths: Iterable[str | Path],
    *,
    base: bool = False,
    skip_s: float | None = None,
    rows: tuple[int | None, int | None] | None = None,
    on_stage: Callable[[str], None] | None = None,
    shaper: bool = True,
) -> FitAll:
    """Fit every stage the runs allow: hysteresis (needed: a sweep), creep (a creep run),
    shaper (low-amplitude steps); the sections that cannot be fitted are named with the
    reason instead of stopping the fit. From sweeps alone the bundle holds the hysteresis
    section, which is all the compensator needs, and a creep section fitted from the sweeps
    when their drift predicts the held-out ends better (:func:`fit_sweep_sections`; not
    with ``base``). ``skip_s``/``rows``: the sweeps' fitted rows (:func:`fitted_rows`).
    ``on_stage`` is told each stage's name before it starts (progress).

    ``base`` fits the thesis's structure (:data:`THESIS_GRID`, :data:`THESIS_CREEP_FORMS`);
    ``shaper=False`` leaves the shaper out (not fitted, and said so).
    """
    paths = list(paths)
    stage = on_stage or (lambda name: None)
    hruns = select_hysteresis_runs(paths)  # no sweep: no bundle (BundleError)
    unit = hruns[0].output_unit
    drive = (min(float(np.min(r.command_v)) for r in hruns), max(float(np.max(r.command_v)) for r in hruns))
    sections: dict[str, dict[str, Any]] = {}
    fits: dict[str, Any] = {}
    not_fitted: dict[str, str] = {}
    try:
        why = _why_runs_unfit("creep", [select_creep_run(paths)], unit)
    except BundleError as exc:
        why = str(exc)
    if why is None:
        stage("hysteresis and creep (alternating, each creep form checked against the sweeps)")
        try:
            h, hfit, c, cfit = fit_hysteresis_and_creep(paths, base=base, skip_s=skip_s, rows=rows)
            sections.update(hysteresis=h, creep=c)
            fits.update(hysteresis=hfit, creep=cfit)
        except (FitError, CompensatorUnstableError) as exc:
            why = f"the creep fit failed ({exc})"
    if why is not None and base:
        stage("hysteresis (the thesis's structure)")
        not_fitted["creep"] = why
        h, hfit = fit_hysteresis_section(paths, grid=THESIS_GRID, skip_s=skip_s, rows=rows)
        sections["hysteresis"], fits["hysteresis"] = h, hfit
    elif why is not None:  # no held step: creep from the sweeps themselves, if they show it
        stage("hysteresis, and creep from the sweeps")
        h, c, found = fit_sweep_sections(paths, skip_s=skip_s, rows=rows)
        sections["hysteresis"], fits["hysteresis"] = h, found
        if c is not None:
            sections["creep"], fits["creep"] = c, SimpleNamespace(reason=found.creep_reason)
        else:
            not_fitted["creep"] = f"{why}; from the sweeps: {found.creep_reason}"
    try:
        why = _why_runs_unfit("shaper", select_shaper_runs(paths), unit) if shaper else "left out (shaper=False)"
    except BundleError as exc:
        why = str(exc)
    if why is None:
        stage("shaper (mode from the low-amplitude steps)")
        try:
            sections["shaper"], fits["shaper"] = fit_shaper_section(paths)
        except FitError as exc:
            why = f"the mode fit failed ({exc})"
    if why is not None:
        not_fitted["shaper"] = why
    return FitAll(
        {k: sections[k] for k in ("hysteresis", "creep", "shaper") if k in sections}, fits, not_fitted, unit, drive
    )


@dataclass
class FittedBundle:
    """A bundle fitted from runs: the document (checked: :class:`~piezopress.analysis.bundle.Bundle`)
    and what :func:`fit_all` made of the runs."""

    doc: dict[str, Any]
    result: FitAll

    @property
    def bundle(self) -> Bundle:
        return Bundle.from_dict(self.doc, "the fitted bundle")


def runs_from_elsewhere(res: FitAll) -> bool:
    """True when every run the hysteresis was fitted on names no press (imported, another program's)."""
    runs = (res.sections.get("hysteresis") or {}).get("runs") or []
    return bool(runs) and all(isinstance(r, dict) and r.get("rig", 0) is None for r in runs)


def fit_bundle(
    runs: Iterable[str | Path],
    limits: Any = None,
    *,
    base: bool = False,
    shaper: bool = True,
    skip_s: float | None = None,
    rows: tuple[int | None, int | None] | None = None,
    max_rate_per_s: float | None = None,
    on_stage: Callable[[str], None] | None = None,
    record_range: Any = None,
) -> FittedBundle:
    """``piezopress fit``: every stage the runs allow (:func:`fit_all`), assembled with the
    compensation settings into a bundle, which is checked as any bundle read from a file.

    ``limits``: the rig's drive range (``drive_min_v``, ``drive_max_v``; e.g.
    :func:`piezopress.pipelines.characterize.rig_limits`), ``None``: 0 to 150 V. With
    ``record_range`` (limits to fall back on) and no ``limits``, runs from elsewhere (no press
    recorded) give the range the record drove, and our own runs ``record_range``. ``shaper=False``
    leaves the shaper section out (a model of the press's static and slow behaviour only).
    """
    res = fit_all(runs, base=base, skip_s=skip_s, rows=rows, on_stage=on_stage, shaper=shaper)
    if record_range is not None and runs_from_elsewhere(res):
        # no rig named, runs from elsewhere: the actuator's range is the one the record drove
        limits = None
        drive = {"drive_min_v": float(res.drive_v[0]), "drive_max_v": float(res.drive_v[1])}
    else:
        limits = record_range if limits is None and record_range is not None else limits
        drive = (
            {}
            if limits is None
            else {"drive_min_v": float(limits.drive_min_v), "drive_max_v": float(limits.drive_max_v)}
        )
    doc = assemble(res.sections, compensation_settings(res.sections, max_rate_per_s=max_rate_per_s, **drive))
    Bundle.from_dict(doc, "the fitted bundle")  # a bundle that would not be read back is never written
    return FittedBundle(doc, res)
