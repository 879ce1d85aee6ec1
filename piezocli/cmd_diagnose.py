"""``piezopress simulate`` and ``piezopress diagnose``."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from piezopress import units
from piezopress.piezocli.main import ROWS, cli, emit_json, json_option, next_command, reports_errors
from piezopress.pipelines import diagnose as diag
from piezopress.pipelines.files import kept_note


def _judged_opts(verb: str):
    """``--skip-s`` and ``--rows``: the rows judged in every run, instead of the bundle's record."""

    def add(f):
        f = click.option(
            "--rows",
            type=ROWS,
            default=None,
            help=f"{verb} only rows START to STOP-1 of each run (from 0); earlier rows still carry the model's "
            "state, later rows are dropped. Default: the rows fit judged (recorded in the bundle), else all.",
        )(f)
        return click.option(
            "--skip-s",
            "skip_s",
            type=click.FloatRange(min=0.0),
            default=None,
            metavar="SECONDS",
            help=f"Do not {verb.lower()} the first SECONDS of each run (a rest of unknown state, a start-up "
            "transient); they still carry the model's state and are reported apart. Default: as fit skipped them "
            "(recorded in the bundle), else none.",
        )(f)

    return add


@cli.command("simulate")
@click.argument("run", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option(
    "--bundle", "bundle_path", type=click.Path(dir_okay=False, path_type=Path), required=True, help="Parameter bundle."
)
@click.option(
    "--out",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="File to write: for a run, the run with columns predicted and residual added; for a drive CSV, a CSV "
    "with the predicted output (and its error against the reference).",
)
@click.option(
    "--replace", is_flag=True, help="Replace an existing output (the old one is kept as <name>.replaced-<UTC time>)."
)
@_judged_opts("Judge")
@reports_errors
def simulate_cmd(run, bundle_path, out, replace, skip_s, rows) -> None:
    """Run the bundle's model on a run's measured drive, beside the measurement; or on a
    drive file before it goes to the press.

    This is "the simulation" diagnose judges: hysteresis, creep, mode and the sensor's
    low-pass applied to the drive the run applied. Given a CSV (compensate's output, or any
    file with t_s and command_v), it writes the predicted output above the model's rest,
    the zero compensate's references use, and its error against the file's reference column.

    \b
    Examples:
      piezopress simulate runs/char/step-100v.parquet --bundle build/bundle.json --out sim.parquet
      piezopress compensate --bundle build/bundle.json --reference ramp.csv --out drive.csv
      piezopress simulate drive.csv --bundle build/bundle.json --out predicted.csv
      piezopress simulate smart.parquet --bundle build/smart.json --skip-s 3.3 --out sim.parquet
    """
    judged = diag.JudgedRows(skip_s, rows)
    if run.suffix.lower() in (".csv", ".txt", ".tsv"):  # a drive file: compensate's output, or any t_s, command_v
        if judged.given:
            raise click.UsageError(
                "--skip-s/--rows judge a measured run; a drive file has no measurement to judge (leave them out)"
            )
        ds, previous = diag.simulate_drive_file(bundle_path, run, out, replace=replace)
        u = units.label(ds.unit)
        pred = ds.frame.iloc[:, list(ds.frame.columns).index(f"predicted_{units.key(ds.unit)}")]
        zero = (
            f"on the record's own scale (the model's rest: {ds.rest:.4g} {u})"
            if ds.absolute
            else f"above the model's rest ({ds.rest:.4g} {u}, the zero of compensate's references)"
        )
        line = f"Wrote {out}: predicted {pred.min():.4g} to {pred.max():.4g} {u} {zero}"
        if ds.error_rms is not None:
            held = f"; the model's held-out error {ds.holdout_rms:.3g} {u} RMS" if ds.holdout_rms is not None else ""
            line += f"; against the reference: {ds.error_rms:.3g} {u} RMS, {ds.error_max:.3g} {u} max{held}"
        click.echo(line + kept_note(previous))
        return
    sim, previous = diag.simulate_file(bundle_path, run, out, replace=replace, judged=judged)
    res = sim.data["residual"].to_numpy()
    u = units.label(sim.output_unit)
    rows_done = sim.meta["simulated_with"].get("judged_rows")
    if rows_done:  # judged on the rows fit judged (or the user's --skip-s/--rows), the start apart
        a, h, b = rows_done["fitted_from"], rows_done["held_out_from"], rows_done["stop"]
        held, fitted = res[h:b], res[a:b]
        how = "as given" if judged.given else "as fit judged them"
        line = f"Wrote {out}: "
        if h < b and (h > a or not judged.given):
            line += f"residual on the held-out rows {h}:{b} ({how}) {(held**2).mean() ** 0.5:.3g} {u} RMS; "
        line += f"on rows {a}:{b} {(fitted**2).mean() ** 0.5:.3g} {u} RMS, {abs(fitted).max():.3g} {u} max"
        if b < res.size:
            line += f"; rows {b}: on not judged"
        if a:
            start = res[:a]
            line += (
                f"; the start (rows 0:{a}, not fitted: a rest of unknown state) {(start**2).mean() ** 0.5:.3g} {u} "
                "RMS, not counted"
            )
        click.echo(f"{line} ({sim.output_column}){kept_note(previous)}")
        return
    click.echo(
        f"Wrote {out}: residual {abs(res).max():.3g} {u} max, {(res**2).mean() ** 0.5:.3g} {u} RMS "
        f"({sim.output_column})"
        f"{kept_note(previous)}"
    )


def _progress_printer(err: bool):
    """Progress per cause (stdout, or stderr under ``--json``): on a terminal a line per cause
    tried, redrawn in place while it runs; piped (a log, CI), one line per cause when it is done,
    with its time, so a long diagnosis is never silent."""
    import time

    stream = sys.stderr if err else sys.stdout
    tty = stream.isatty()
    started = {"t": time.monotonic()}

    def show(ev: diag.dg.CauseProgress) -> None:
        head = f"[pass {ev.round}, {ev.index:>{len(str(ev.total))}}/{ev.total}] {ev.cause:<28}"
        if not ev.done:
            started["t"] = time.monotonic()
            if tty:
                click.echo(f"\r{head} ...", nl=False, err=err)
            return
        if ev.gain_pct is None:
            what = "nothing to fit"
        else:
            what = f"held-out gain {ev.gain_pct:.0f} %" + (" (a finding)" if ev.accepted else "")
        took = f" ({time.monotonic() - started['t']:.1f} s)"
        click.echo(f"\r{head} {what}{took}" if tty else f"{head} {what}{took}", err=err)

    return show


@cli.command("diagnose")
@click.argument("runs", nargs=-1, required=True, type=click.Path(exists=True, path_type=Path))
@click.option(
    "--bundle",
    "bundle_path",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="Parameter bundle whose model is judged.",
)
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="New directory: diagnosis.json, extended_bundle.json, residual plots.",
)
@click.option(
    "--cause",
    "causes",
    multiple=True,
    type=click.Choice(sorted(diag.dg.CAUSES)),
    metavar="CAUSE",
    help="Only these causes (repeatable; default: the whole catalogue; an unknown name lists the known ones).",
)
@click.option(
    "--gain",
    "gain",
    is_flag=True,
    help="Also measure the gain on the press the runs came from (--rig; virtual-rig runs: their rig): the base "
    "bundle, each extension alone and the extended bundle played there, interleaved and repeated (compare); "
    "writes gain-on-press/compare.csv and recommended_bundle.json (only what wins). Takes minutes.",
)
@click.option(
    "--rig",
    "rig_path",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    default=None,
    help="With --gain: the press's rig file (any backend); default: the virtual rig the runs' metadata names.",
)
@click.option(
    "--backend",
    "backend_name",
    default=None,
    help="With --gain --rig: a registered backend name or module:ClassName (default: the rig file's).",
)
@click.option(
    "--fitted",
    "fitted_path",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    default=None,
    help="With --gain: the bundle in use (from fit): played too, with each extension on it; the recommended bundle "
    "is then never worse than it on any row beyond the spread.",
)
@click.option(
    "--gain-repeats",
    type=click.IntRange(1, 20),
    default=3,
    show_default=True,
    help="With --gain: times each bundle is played on the press (the spread the verdicts are judged against).",
)
@click.option(
    "--gain-seeds",
    type=click.IntRange(1, 10),
    default=2,
    show_default=True,
    help="With --gain on virtual-rig runs without --rig: also the simulator's gain, the whole chain this many times "
    "with other noise seeds (compensated_gain.csv).",
)
@_judged_opts("Judge")
@json_option
@reports_errors
def diagnose_cmd(
    runs,
    bundle_path,
    out_dir,
    causes,
    gain,
    rig_path,
    backend_name,
    fitted_path,
    gain_repeats,
    gain_seeds,
    skip_s,
    rows,
    as_json,
) -> None:
    """Find what the model gets wrong, name the physical cause, extend the model, measure the gain.

    Every run is simulated with the bundle's model; the residuals are analysed against the
    sensor's noise floor, and each cause of the catalogue is fitted as an extension of the
    model on some runs or segments and judged on others it did not see. Findings are sorted
    by held-out gain; residual structure no cause explains is listed as unexplained. A cause
    the runs cannot test (each declares the runs it needs) is listed with what it needs and
    what the runs offer, and next-plan.toml in the output directory is the experiment that
    would test it. Several run directories may be given (the first runs and the next plan's).
    On a terminal a line per cause tried shows the progress. With --json, one document on
    stdout: diagnosis.json's content and the files written (the usual lines go to stderr).

    \b
    Example:
      piezopress fit runs/char --base --out build/base.json
      piezopress diagnose runs/char --bundle build/base.json --out runs/diagnosis
      piezopress characterize --plan runs/diagnosis/next-plan.toml --out runs/more
      piezopress diagnose runs/char runs/more --bundle build/base.json --out runs/diagnosis-2
      piezopress diagnose runs/char --bundle build/base.json --out runs/diagnosis-3 --gain
      piezopress diagnose lab/char --bundle build/base.json --out lab/diag --gain --rig my-press.toml \\
          --fitted build/bundle.json
    """

    def say(text: str) -> None:
        click.echo(text, err=as_json)

    from piezopress.acquisition.backend import stop_signals_interrupt

    press = None
    if (rig_path or backend_name or fitted_path) and not gain:
        raise click.UsageError(
            "--rig, --backend and --fitted say where and against what --gain measures; give --gain too (or leave them "
            "out)"
        )
    if gain:  # the press checked (and made) before the diagnosis's minutes of work, not after
        from piezopress.pipelines import characterize as char
        from piezopress.pipelines import gain as gain_mod

        if rig_path is not None:
            press = char.make_backend(backend_name, rig_path)
        else:
            from piezopress.acquisition.virtual_rig import VirtualRig

            press = VirtualRig(gain_mod.rig_of_runs(runs)[0])
    with stop_signals_interrupt():  # SIGTERM/SIGHUP as Ctrl-C: the directory is marked interrupted
        result, out = diag.diagnose(
            runs,
            bundle_path,
            out_dir,
            causes or None,
            on_progress=_progress_printer(as_json),
            judged=diag.JudgedRows(skip_s, rows),
        )
    plan = diag.next_plan_info(out)
    say(diag.format_summary(result, plan))
    files = {
        "diagnosis": out / "diagnosis.json",
        "extended_bundle": out / "extended_bundle.json",
        "residuals_figure": out / "residuals.png",
        "residual_traces_figure": out / "residual_traces.png",
    }
    if plan and plan.get("file"):
        files["next_plan"] = Path(plan["file"])
    say(f"\nWrote {', '.join(str(f) for f in files.values())}")
    gain_rows = None
    adoption = None
    if gain:
        from piezopress.pipelines import adopt
        from piezopress.pipelines import compare as cmp
        from piezopress.pipelines import gain as gain_mod

        where = str(rig_path) if rig_path is not None else "the virtual rig the runs came from"

        def on_play(p: cmp.Play) -> None:
            if p.done:
                say(f"  [{p.index}/{p.total}] repeat {p.repeat}, {p.plan}, {p.label}: played")

        say(f"\nMeasuring the gain on the press ({where}), {gain_repeats} repeat(s) of each bundle:")
        adoption = adopt.measure_on_press(
            out,
            bundle_path,
            result.findings,
            backend=press,
            rig_path=rig_path,
            repeats=gain_repeats,
            press_label=where,
            fitted_path=fitted_path,
            on_play=on_play,
            on_warning=lambda w: click.echo(f"  warning: {w}", err=True),
        )
        if adoption.comparison is not None:
            say(
                f"\nThe gain on the press ({where}; mean ± standard deviation over {gain_repeats} repeat(s), each "
                "bundle against the base):\n"
            )
            say(cmp.format_table(adoption.comparison.table, adoption.comparison.labels))
            files["gain_on_press"] = adoption.comparison.out_dir / cmp.COMPARE_CSV
        say("\n" + adopt.format_adoption(adoption))
        files["recommended_bundle"] = adoption.recommended_path
        if rig_path is None:  # virtual-rig runs: the simulator's ground truth too (the whole chain reseeded)
            _, csv = gain_mod.gain_for_runs(
                runs, bundle_path, out / "extended_bundle.json", out, seeds=gain_seeds, causes=causes or None
            )
            gain_rows = gain_mod.read_csv(csv)
            say(
                "\nThe simulator's gain (the virtual rig, the whole chain with other noise seeds, base against "
                "extended):\n"
            )
            say(gain_mod.format_table(gain_rows, {f.cause: f.gain_pct for f in result.findings}))
            files["compensated_gain"] = csv
        say(f"\nWrote {', '.join(str(files[k]) for k in ('gain_on_press', 'recommended_bundle') if k in files)}")
    nxt = []
    if plan and plan.get("file"):
        own = (plan.get("output_column") or "force_n") != "force_n" and not (plan.get("rig") or {}).get("from_runs")
        nxt.append(
            f"piezopress characterize --plan {plan['file']}{' --rig YOUR-PRESS.toml' if own else ''} "
            f"--out {out.parent / (out.name + '-more')}"
        )
    first = runs[0] if runs else "RUNS"
    nxt.append(
        f"piezopress report --characterization {first} --bundle {out / 'extended_bundle.json'} --diagnosis {out} "
        f"--out {out.parent / (out.name + '-report')}"
    )
    next_command(*nxt, err=as_json)
    if as_json:
        import json

        doc = json.loads(files["diagnosis"].read_text(encoding="utf-8"))
        emit_json(
            {
                "out_dir": out,
                "files": files,
                **doc,
                **({"compensated_gain": gain_rows.to_dict(orient="records")} if gain_rows is not None else {}),
            }
        )
