"""``piezopress fit-hysteresis``, ``fit-creep``, ``fit-shaper``, ``bundle``, ``fit``, ``compensate``."""

from __future__ import annotations

import math
import time
from pathlib import Path

import click

from piezopress import units
from piezopress.piezocli.main import ROWS, cli, emit_json, json_option, next_command, reports_errors
from piezopress.pipelines import bundle as bundle_mod
from piezopress.pipelines import characterize as char
from piezopress.pipelines import files as files_mod
from piezopress.pipelines import fit as fit_mod

_runs_arg = click.argument("runs", nargs=-1, required=True, type=click.Path(exists=True, path_type=Path))
_names_opt = click.option("--run", "names", multiple=True, help="Use only the run(s) of this name (repeatable).")
_replace_opt = click.option(
    "--replace", is_flag=True, help="Replace an existing output (the old one is kept as <name>.replaced-<UTC time>)."
)
_skip_opt = click.option(
    "--skip-s",
    "skip_s",
    type=click.FloatRange(min=0.0),
    default=None,
    metavar="SECONDS",
    help="Do not fit the first SECONDS of each sweep (a rest, a start-up transient); they still carry the model's "
    "state. "
    "Default: detected (the sweep's start until its input has reached both ends of its range).",
)
_rows_opt = click.option(
    "--rows",
    type=ROWS,
    default=None,
    help="Fit only rows START to STOP-1 of each sweep (from 0); earlier rows still carry the state.",
)
_structure_opt = click.option(
    "--structure",
    default=None,
    metavar="LABEL",
    help="Fit this hysteresis structure instead of searching for one, as fit prints it after 'hysteresis:' "
    "(e.g. 'n=8 gamma=2 m=4 plane=20'): keep a structure validated on the press through refits, or fit two and "
    "let `piezopress compare` judge them on the press.",
)
_if_changed_opt = click.option(
    "--if-changed",
    is_flag=True,
    help="Do nothing if the output was made from the same inputs; else replace it (keeping the old one, timestamped).",
)


def _skip(out: Path, digest: str, if_changed: bool) -> bool:
    if if_changed and bundle_mod.up_to_date(out, digest):
        click.echo(f"{out} is up to date (its inputs have not changed)")
        return True
    return False


def _wrote(path: Path, previous: Path | None) -> None:
    click.echo(f"Wrote {path}{files_mod.kept_note(previous)}")


@cli.command("fit-hysteresis")
@_runs_arg
@click.option(
    "--out", type=click.Path(dir_okay=False, path_type=Path), required=True, help="Section file to write (JSON)."
)
@_names_opt
@click.option(
    "--holdout-fraction",
    type=click.FloatRange(0.05, 0.9),
    default=0.3,
    show_default=True,
    help="End of each run held out to choose the model.",
)
@click.option(
    "--creep",
    "creep_path",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Creep section: remove creep from the outputs first.",
)
@_structure_opt
@_skip_opt
@_rows_opt
@_replace_opt
@_if_changed_opt
@reports_errors
def fit_hysteresis_cmd(
    runs, out, names, holdout_fraction, creep_path, structure, skip_s, rows, replace, if_changed
) -> None:
    """Fit the modified Prandtl-Ishlinskii model and its inverse on quasi-static sweeps.

    RUNS are run files or run directories; without --run, every triangle/sine run at up to
    0.5 Hz is used. With --creep, creep is removed from the outputs first (fit hysteresis,
    then creep, then hysteresis again with --creep: `piezopress fit` does this). Operator
    numbers and thresholds are chosen on the held-out end of each run's fitted rows (never a
    random subset); operators that contribute nothing are pruned. A start that is not part
    of the sweep (a rest, a start-up transient) is detected, or set with --skip-s / --rows.
    The fit error printed is the chosen model's on its training rows and on the held-out
    end, in the run's own unit; the model written is refitted on all fitted rows.

    \b
    Example:
      piezopress fit-hysteresis runs/char --out build/hysteresis.json
      piezopress fit-hysteresis smart.parquet --skip-s 3.3 --out build/smart.json
    """
    files_mod.check_output(out, replace=replace or if_changed)  # before any fitting
    grid = fit_mod.structure_grid(structure)
    creep = bundle_mod.read_document(creep_path, "creep") if creep_path else None
    digest = fit_mod.hysteresis_digest(
        fit_mod.select_hysteresis_runs(runs, names), creep, holdout_fraction, grid, skip_s=skip_s, rows=rows
    )
    if _skip(out, digest, if_changed):
        return
    doc, fit = fit_mod.fit_hysteresis_section(
        runs, names=names, holdout_fraction=holdout_fraction, grid=grid, creep=creep, skip_s=skip_s, rows=rows
    )
    click.echo(f"Runs: {', '.join(r['name'] for r in doc['runs'])}")
    click.echo(f"Chosen: {fit.reason}")
    click.echo(f"Fit error: {_fit_error(fit, doc['model']['output_unit'])}")
    _wrote(out, bundle_mod.write_document(doc, out, replace=replace or if_changed))


@cli.command("fit-creep")
@_runs_arg
@click.option(
    "--hysteresis",
    "hyst_path",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="Hysteresis section (from fit-hysteresis).",
)
@click.option(
    "--out", type=click.Path(dir_okay=False, path_type=Path), required=True, help="Section file to write (JSON)."
)
@_names_opt
@click.option(
    "--holdout-fraction",
    type=click.FloatRange(0.05, 0.9),
    default=0.3,
    show_default=True,
    help="End of the hold kept out to choose the creep form.",
)
@_replace_opt
@_if_changed_opt
@reports_errors
def fit_creep_cmd(runs, hyst_path, out, names, holdout_fraction, replace, if_changed) -> None:
    """Fit creep (thesis form K_c + C(s) and a log-time form; chosen on held-out data).

    The hysteresis model accounts for the static part of the long step; the creep model
    maps its prediction to the measured force, and the compensator is its inverse
    multiplicative form, checked for stability.

    \b
    Example:
      piezopress fit-creep runs/char --hysteresis build/hysteresis.json --out build/creep.json
    """
    files_mod.check_output(out, replace=replace or if_changed)  # before any fitting
    hyst = bundle_mod.read_document(hyst_path, "hysteresis")
    if _skip(out, fit_mod.creep_digest(fit_mod.select_creep_run(runs, names), hyst, holdout_fraction), if_changed):
        return
    doc, fit = fit_mod.fit_creep_section(runs, hyst, names=names, holdout_fraction=holdout_fraction)
    click.echo(f"Run: {doc['runs'][0]['name']}")
    click.echo(f"Chosen: {fit.reason} (RMS in {units.label(hyst['model']['output_unit'])})")
    _wrote(out, bundle_mod.write_document(doc, out, replace=replace or if_changed))


@cli.command("fit-shaper")
@_runs_arg
@click.option(
    "--out", type=click.Path(dir_okay=False, path_type=Path), required=True, help="Section file to write (JSON)."
)
@_names_opt
@_replace_opt
@_if_changed_opt
@reports_errors
def fit_shaper_cmd(runs, out, names, replace, if_changed) -> None:
    """Identify the mode from low-amplitude steps and design the input shaper.

    The mode is fitted against the drive actually applied (the amplifier monitor when the
    runs have one). ZV shapers with 2 to 4 impulses and EI are compared by their worst
    residual vibration over +/-15 % frequency and +/-50 % damping error, and by delay.

    \b
    Example:
      piezopress fit-shaper runs/char --out build/shaper.json
    """
    files_mod.check_output(out, replace=replace or if_changed)  # before any fitting
    if _skip(out, fit_mod.shaper_digest(fit_mod.select_shaper_runs(runs, names), None), if_changed):
        return
    doc, fit = fit_mod.fit_shaper_section(runs, names=names)
    m = doc["mode"]
    click.echo(f"Runs: {', '.join(r['name'] for r in doc['runs'])} (fitted against {m['drive_used']})")
    click.echo(f"Mode: wn = {m['natural_freq_rad_s']:.4g} rad/s, damping = {m['damping']:.4g}")
    click.echo(f"Shaper: {doc['choice']['reason']}")
    _wrote(out, bundle_mod.write_document(doc, out, replace=replace or if_changed))


@cli.command("bundle")
@click.option(
    "--hysteresis",
    "hyst_path",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="Hysteresis section.",
)
@click.option(
    "--creep", "creep_path", type=click.Path(dir_okay=False, path_type=Path), help="Creep section (optional)."
)
@click.option(
    "--shaper", "shaper_path", type=click.Path(dir_okay=False, path_type=Path), help="Shaper section (optional)."
)
@click.option(
    "--rig",
    "rig_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=char.DEFAULT_RIG,
    show_default="rigs/thesis-press.toml",
    help="Rig file: the drive range.",
)
@click.option(
    "--max-rate",
    type=click.FloatRange(min=1e-9),
    default=None,
    help="Largest reference rate passed to the drive, in the model's output unit per second "
    "(N/s or µm/s; default: 40000 N/s for a force model, no limit for a displacement model).",
)
@click.option(
    "--out", type=click.Path(dir_okay=False, path_type=Path), required=True, help="Bundle file to write (JSON)."
)
@_replace_opt
@_if_changed_opt
@reports_errors
def bundle_cmd(hyst_path, creep_path, shaper_path, rig_path, max_rate, out, replace, if_changed) -> None:
    """Join fitted sections into a parameter bundle (one readable JSON file).

    \b
    Example:
      piezopress bundle --hysteresis build/hysteresis.json --creep build/creep.json \\
          --shaper build/shaper.json --out build/bundle.json
    """
    files_mod.check_output(out, replace=replace or if_changed)
    sections = {"hysteresis": bundle_mod.read_document(hyst_path, "hysteresis")}
    if creep_path:
        sections["creep"] = bundle_mod.read_document(creep_path, "creep")
    if shaper_path:
        sections["shaper"] = bundle_mod.read_document(shaper_path, "shaper")
    act = char.rig_limits(rig_path)  # the drive range of whichever backend the rig file names
    comp = fit_mod.compensation_settings(
        sections, max_rate_per_s=max_rate, drive_min_v=act.drive_min_v, drive_max_v=act.drive_max_v
    )
    doc = bundle_mod.assemble(sections, comp)
    if _skip(out, doc["inputs_digest"], if_changed):
        return
    bundle_mod.Bundle.from_dict(doc, str(out))  # a bundle that would not be read back is never written
    _wrote(out, bundle_mod.write_document(doc, out, replace=replace or if_changed))


@cli.command("fit")
@_runs_arg
@click.option(
    "--out", type=click.Path(dir_okay=False, path_type=Path), required=True, help="Bundle file to write (JSON)."
)
@click.option(
    "--rig",
    "rig_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Rig file: the drive range  [default: for imported runs the range the record drove, else "
    "rigs/thesis-press.toml].",
)
@click.option(
    "--base",
    is_flag=True,
    help="Fit the thesis's model structure (12 plays, 1 dead zone, 3-pole creep): the base model diagnose extends.",
)
@_structure_opt
@_skip_opt
@_rows_opt
@_replace_opt
@json_option
@reports_errors
def fit_all_cmd(runs, out, rig_path, base, structure, skip_s, rows, replace, as_json) -> None:
    """Fit hysteresis, creep and shaper from a characterization and write the bundle.

    The same as fit-hysteresis, fit-creep, fit-shaper and bundle in a row (their section
    files are not kept; use the separate commands, or `make refit`, for incremental fits).
    Each section is fitted if the runs allow it: sweeps alone (e.g. one imported sine) give
    a bundle with the hysteresis section only, and one line per section not fitted says why.
    Figures are in the runs' own output unit (N or µm).

    \b
    Example:
      piezopress fit runs/char --out build/bundle.json
      piezopress fit runs/smarthysteresis_150v_1hz.parquet --base --out build/smart-base.json
      piezopress fit runs/char --structure 'n=8 gamma=2 m=4 plane=20' --out build/bundle-g2.json
    """
    act = char.rig_limits(rig_path or char.DEFAULT_RIG)  # the rig file checked, and its drive range, before fitting
    files_mod.check_output(out, replace=replace)

    def say(text: str) -> None:
        click.echo(text, err=as_json)

    started = time.monotonic()
    fitted = fit_mod.fit_bundle(
        runs,
        act if rig_path is not None else None,
        base=base,
        skip_s=skip_s,
        rows=rows,
        on_stage=lambda stage: say(f"fitting {stage} ... ({time.monotonic() - started:.1f} s so far)"),
        record_range=act if rig_path is None else None,
        structure=structure,
    )
    res = fitted.result
    u = units.label(res.unit)
    hfit = res.fits["hysteresis"]
    say(f"hysteresis: {hfit.reason}")
    say(f"hysteresis: {_fit_error(hfit, res.unit)}")
    if structure is not None:
        say("hysteresis: the structure was given (--structure), not searched for")
    searched = res.sections["hysteresis"].get("fit", {}).get("base_structure")
    if searched:  # --base, and the thesis's plays could not draw the loop: say why it is not theirs
        say(f"hysteresis: not the thesis's structure: {searched}")
    if "creep" in res.sections:
        say(f"creep:      {res.fits['creep'].reason} (RMS in {u})")
    if "shaper" in res.sections:
        s = res.sections["shaper"]
        say(
            f"shaper:     wn = {s['mode']['natural_freq_rad_s']:.4g} rad/s, damping {s['mode']['damping']:.4g}; "
            f"{s['choice']['reason']}"
        )
        ar = s["mode"].get("antiresonance")
        if ar:
            wz = ar["natural_freq_rad_s"]
            say(
                f"            an anti-resonance above the mode: zeros at {wz / (2 * math.pi):.4g} Hz "
                f"({wz / s['mode']['natural_freq_rad_s']:.2f} times the mode), damping {ar['damping']:.3g} "
                "(in the forward model and the compensator's lead)"
            )
        chain = s["mode"].get("drive_chain")
        if chain:  # the applied drive was not recorded: say which chain the steps showed
            describe = {
                "none": "none (the command reaches the stack as it is)",
                "slew": f"a slew limit of {(chain.get('slew_v_per_s') or 0) / 1e3:.3g} V/ms",
                "first_order": f"a first-order lag of {(chain.get('tau_s') or 0) * 1e6:.3g} us",
                "delay": f"a delay of {(chain.get('delay_s') or 0) * 1e6:.3g} us (lags in series, a filter's group "
                "delay: the press's own, led by the compensator; diagnose names a delay beyond it)",
                "lowpass_delay": f"a second-order low-pass at {chain.get('lowpass_hz') or 0:.4g} Hz (damping "
                f"{chain.get('lowpass_damping') or 0:.2f}) and a delay of {(chain.get('delay_s') or 0) * 1e6:.3g} us "
                "in series (both led by the compensator; diagnose names a delay beyond the converters' own)",
                "slew_lowpass_delay": f"a slew limit of {(chain.get('slew_v_per_s') or 0) / 1e3:.3g} V/ms before a "
                f"second-order low-pass at {chain.get('lowpass_hz') or 0:.4g} Hz (damping "
                f"{chain.get('lowpass_damping') or 0:.2f}) and a delay of {(chain.get('delay_s') or 0) * 1e6:.3g} us "
                "(the compensator leads the small-signal delay the slew alone read, "
                f"{(chain.get('low_frequency_delay_s') or 0) * 1e6:.3g} us; diagnose names the slew)",
            }
            what = describe.get(chain.get("form"), f"of the form {chain.get('form')!r}")
            say(f"            no amplifier monitor recorded: the drive chain identified from the steps is {what}")
            own = fitted.doc.get("compensation", {}).get("chain_lead_samples")
            if own and chain.get("delay_samples"):
                seconds = (chain.get("delay_s") or 0.0) - own / chain["steps_sample_rate_hz"]
                say(
                    f"            steps at two sample rates told its delay apart: {own:.2f} samples of each run's rate "
                    "(a converter's hold and filter, a FIFO), led in samples of each reference's rate; the rest of "
                    f"the chain's lag, {fitted.doc['compensation'].get('chain_lead_s', 0.0) * 1e6:.3g} us (the "
                    f"low-pass's, and {seconds * 1e6:+.3g} us of delay), in seconds"
                )
            elif own:
                say(
                    f"            of its delay, {own:.2f} samples are taken as the sampling's own (a converter's hold "
                    "and filter, up to 2 samples of the steps' rate: the steps did not tell it): led in samples of "
                    "each reference's rate, not in seconds; steps at a second rate (the default plan's "
                    "step-50v-50khz) tell it for a chain without a slew limit"
                )
    for name, why in res.not_fitted.items():
        say(f"{name}: not fitted: {why}")
    lo, hi = res.drive_v
    comp = fitted.doc.get("compensation", {})
    if rig_path is None and fit_mod.runs_from_elsewhere(res):
        say(
            f"drive range: {comp.get('drive_min_v', lo):.4g} to {comp.get('drive_max_v', hi):.4g} V, the range the "
            "record drove (runs from elsewhere, no --rig); pass --rig with the actuator's range to change it"
        )
    elif lo < act.drive_min_v - 1e-9 or hi > act.drive_max_v + 1e-9:
        say(
            f"note: the runs drive {lo:.4g} to {hi:.4g} V, beyond the rig's drive range {act.drive_min_v:g} to "
            f"{act.drive_max_v:g} V ({rig_path or char.DEFAULT_RIG}); compensate clips the drive to that range (pass "
            "--rig with this "
            "actuator's range)"
        )
    say(f"fitted in {time.monotonic() - started:.1f} s")
    checked = bundle_mod.Bundle.from_dict(fitted.doc, str(out))
    r_lo, r_hi = checked.reach()
    y0 = checked.hysteresis.y0
    say(
        f"rest:       the model's rest output is {y0:.4g} {u} (the zero of references above the rest); the drive range "
        f"reaches {y0 + r_lo:.4g} to {y0 + r_hi:.4g} {u} ({r_lo:.4g} to {r_hi:.4g} above the rest)"
    )
    previous = bundle_mod.write_document(fitted.doc, out, replace=replace)
    if as_json:
        say(f"Wrote {out}{files_mod.kept_note(previous)}")
        emit_json(
            {
                "bundle": out,
                "previous": previous,
                "output_unit": res.unit,
                "sections": list(res.sections),
                "not_fitted": res.not_fitted,
                "hysteresis": {
                    "reason": hfit.reason,
                    "train_rms": hfit.train_rms,
                    "holdout_rms": hfit.holdout_rms,
                    "holdout_rms_pct_of_range": hfit.holdout_rms_pct,
                    "output_range": hfit.output_range,
                },
                "creep": res.fits["creep"].reason if "creep" in res.sections else None,
                "shaper": res.sections["shaper"]["choice"]["reason"] if "shaper" in res.sections else None,
                "drive_v": list(res.drive_v),
                "rig_drive_v": [act.drive_min_v, act.drive_max_v],
            }
        )
    else:
        _wrote(out, previous)
    k = units.key(res.unit)
    if units.is_force(res.unit) and not fit_mod.runs_from_elsewhere(res):
        validate = f"piezopress validate --bundle {out} --out {out.parent / (out.stem + '-validation')}"
    else:
        validate = None
    next_command(
        *([validate] if validate else []),
        f"piezopress compensate --bundle {out} --reference REFERENCE.csv (columns t_s, reference_{k}) "
        f"--out {out.parent / (out.stem + '-drive.csv')}",
        err=as_json,
    )


def _fit_error(fit, unit: str) -> str:
    """Train and held-out errors of a hysteresis fit, in the output's unit."""
    u = units.label(unit)
    return (
        f"train RMS {fit.train_rms:.4g} {u}, held-out RMS {fit.holdout_rms:.4g} {u} "
        f"= {fit.holdout_rms_pct:.3f} % of the {fit.output_range:.4g} {u} output range"
    )


@cli.command("compensate")
@click.option(
    "--bundle", "bundle_path", type=click.Path(dir_okay=False, path_type=Path), required=True, help="Parameter bundle."
)
@click.option(
    "--reference",
    "ref_path",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="CSV with columns t_s and reference_n (force above the preload; reference_um for a displacement bundle), "
    "uniformly sampled.",
)
@click.option(
    "--out",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="CSV to write: t_s, the reference column, command_v.",
)
@click.option(
    "--rig",
    "rig_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Rig file: the bundle's drive range must lie inside its drive range, the reference's rate within its maximum "
    "(default: the drive range is not checked, the rate against the virtual rig's maximum).",
)
@click.option("--no-shaper", is_flag=True, help="Leave the input shaper out.")
@click.option(
    "--allow-clip",
    is_flag=True,
    help="Write the drive even when more than 1 % of the reference is out of the drive range's reach (the output's "
    "clipped column marks those samples).",
)
@click.option(
    "--zero",
    type=click.Choice(["auto", "rest", "absolute"]),
    default="auto",
    show_default=True,
    help="The reference's zero: rest (above the model's rest output, e.g. N above the preload), absolute (the "
    "record's own scale), auto (absolute for a bundle fitted on imported runs, else rest).",
)
@_replace_opt
@reports_errors
def compensate_cmd(bundle_path, ref_path, out, rig_path, no_shaper, allow_clip, zero, replace) -> None:
    """Turn a reference force (or displacement) trajectory into the actuator drive.

    The reference is in the bundle's output unit: column reference_n (N above the preload)
    for a force bundle, reference_um (µm from the model's rest) for a displacement bundle.

    Input shaper, creep compensator and inverse hysteresis, in the thesis's order; the
    drive is limited to the actuator's safe range, with a warning where the reference
    cannot be reached. The bundle is checked first (finite numbers in their ranges, a lead
    shorter than a tenth of the reference, a creep compensator stable at its rate).

    \b
    Example:
      piezopress compensate --bundle build/bundle.json --reference ramp.csv --out drive.csv
    """
    from piezopress.pipelines import compensate as comp_mod

    result, previous = comp_mod.compensate_file(
        bundle_path,
        ref_path,
        out,
        use_shaper=not no_shaper,
        replace=replace,
        rig_limits=char.rig_limits(rig_path),
        rig=str(rig_path) if rig_path else None,
        allow_clip=allow_clip,
        zero=zero,
    )
    for w in result.warnings:
        click.echo(f"Warning: {w}", err=True)
    for n in result.notes:
        click.echo(f"Note: {n}", err=True)
    click.echo(
        f"Wrote {out}: {result.command_v.size} samples, drive {result.command_v.min():.2f} to "
        f"{result.command_v.max():.2f} V"
        + (f", {result.clipped_samples} clipped (column clipped)" if result.clipped_samples else "")
        + f"{files_mod.kept_note(previous)}"
    )
    from piezopress import units
    from piezopress.pipelines.bundle import read_bundle

    b = read_bundle(bundle_path)
    u = units.label(b.unit)
    lim = char.rig_limits(rig_path) if rig_path else None
    lo, hi = b.reach(*((lim.drive_min_v, lim.drive_max_v) if lim is not None else ()))
    rest = b.hysteresis.y0
    if comp_mod.reference_zero(b, zero) == comp_mod.ABSOLUTE:
        where = f"on the record's own scale (absolute); the model's rest is {rest:.4g} {u}, it reaches {rest + lo:.4g} "
        where += f"to {rest + hi:.4g} {u}"
    else:
        where = f"above the model's rest ({rest:.4g} {u}); it reaches {lo:.4g} to {hi:.4g} {u} above it"
    click.echo(
        f"The reference is read {where}. Check the drive on the model before the press:\n"
        f"  piezopress simulate {out} --bundle {bundle_path} --out {out.with_name(out.stem + '-predicted.csv')}"
    )
