"""The ``piezopress`` command: a thin click layer over :mod:`pipelines`.

Each command parses its options, calls one pipeline function and prints. Library errors
(:class:`piezopress.errors.PiezopressError`) become one clear line and exit status 1;
no command holds any math.
"""

from __future__ import annotations

import functools
import sys

import click

from piezopress import __version__
from piezopress.errors import PiezopressError

#: Whether a progress line was started without its end (``[1/2] tri ... ``): an error then starts a new line.
_PROGRESS_LINE = {"open": False}


def progress_line(open_: bool) -> None:
    """Say whether a progress line is open (printed without its newline)."""
    _PROGRESS_LINE["open"] = open_


def reports_errors(func):
    """Turn library errors into a clean ``Error: ...`` and a non-zero exit, never a traceback."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        progress_line(False)
        try:
            return func(*args, **kwargs)
        except PiezopressError as exc:
            if _PROGRESS_LINE["open"]:  # the error on a line of its own, not after "... "
                click.echo()
            progress_line(False)
            if kwargs.get("as_json"):  # a script reading --json gets a document on failure too
                emit_json({"error": str(exc), "type": type(exc).__name__})
            raise click.ClickException(str(exc)) from None
        except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM/SIGHUP during a plan (signum: which)
            signum = getattr(exc, "signum", 2)
            click.echo(f"\nInterrupted{f' by signal {signum}' if signum != 2 else ''}.", err=True)
            sys.exit(128 + signum)

    return wrapper


def json_option(func):
    """``--json``: print one machine-readable document on stdout; the human lines go to stderr."""
    return click.option(
        "--json", "as_json", is_flag=True, help="Print one JSON document on stdout (the usual lines go to stderr)."
    )(func)


def press_options(what: str):
    """``--rig`` (the press's rig file, default the thesis press) and ``--backend`` (a registered
    name or ``module:ClassName``), as every command that plays on a press takes them; ``what``
    ends the backend's help ("Which rig runs the plan")."""
    from pathlib import Path

    from piezopress.resources import shipped

    def add(func):
        func = click.option(
            "--backend",
            "backend_name",
            default=None,
            help=f"Which rig {what}: a registered name or module:ClassName (default: the rig file's [rig] backend).",
        )(func)
        return click.option(
            "--rig",
            "rig_path",
            type=click.Path(dir_okay=False, path_type=Path),
            default=shipped("rigs", "thesis-press.toml"),
            show_default="rigs/thesis-press.toml",
            help="The press's rig file.",
        )(func)

    return add


def emit_json(doc) -> None:
    """The ``--json`` document: numbers as numbers, non-finite values as null, paths as text."""
    import json
    import math

    def clean(v):
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {str(k): clean(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        if hasattr(v, "item") and not isinstance(v, (str, bytes)):  # numpy scalars
            return clean(v.item())
        return v if isinstance(v, (str, int, float, bool)) or v is None else str(v)

    click.echo(json.dumps(clean(doc), indent=2, ensure_ascii=False))


class RowsType(click.ParamType):
    """``START:STOP``: rows ``START`` to ``STOP - 1`` counted from 0; either end may be left out."""

    name = "START:STOP"

    def convert(self, value, param, ctx):
        if isinstance(value, tuple) or value is None:
            return value
        start, sep, stop = str(value).partition(":")
        try:
            if not sep:
                raise ValueError
            out = (int(start) if start.strip() else None, int(stop) if stop.strip() else None)
        except ValueError:
            self.fail(
                f"{value!r}: expected START:STOP (counted from 0, STOP excluded), e.g. 0:8000 or 11151:", param, ctx
            )
        if (
            (out[0] is not None and out[0] < 0)
            or (out[1] is not None and out[1] < 1)
            or (None not in out and out[1] <= out[0])
        ):
            self.fail(f"{value!r}: expected 0 <= START < STOP", param, ctx)
        return out


ROWS = RowsType()


#: Every command: the module that defines it and the line ``piezopress --help`` shows. Commands
#: are imported only when run (or asked for their own help), so ``--version``, ``--help`` and
#: shell completion start without numpy's, scipy's, pandas' or matplotlib's import time.
COMMANDS: dict[str, tuple[str, str]] = {
    "batch": ("cmd_batch", "Run a stage for many presses at once (Dask), with a fleet report."),
    "bundle": ("cmd_fit", "Join fitted sections into a parameter bundle."),
    "characterize": ("cmd_characterize", "Run the characterization protocols through a backend into runs."),
    "check-rig": ("cmd_check_rig", "Drive a small, safe signal and say whether the force follows."),
    "compare": ("cmd_compare", "Play two or more bundles on one press, repeated, and judge each row."),
    "compensate": ("cmd_fit", "Turn a reference trajectory into the compensated drive."),
    "demo": ("cmd_demo", "Run the whole chain on the virtual rig, as make demo does."),
    "diagnose": ("cmd_diagnose", "Find what the model gets wrong, name the cause, measure the gain."),
    "fit": ("cmd_fit", "Fit hysteresis, creep and shaper from runs and write the bundle."),
    "fit-creep": ("cmd_fit", "Fit creep on a held step given the hysteresis model."),
    "fit-hysteresis": ("cmd_fit", "Fit the Prandtl-Ishlinskii model and its inverse on sweeps."),
    "fit-shaper": ("cmd_fit", "Identify the mode from steps and design the input shaper."),
    "import": ("cmd_import", "Convert a CSV/TSV measurement into a run file."),
    "inspect": ("cmd_inspect", "Validate run files and print a summary of each."),
    "protocols": ("cmd_characterize", "List the protocol kinds a plan may use and their keys."),
    "report": ("cmd_report", "Write the report: Table 6.13 beside the thesis, figures, model quality."),
    "rig-keys": ("cmd_characterize", "List every key of a rig file with its unit, default and range."),
    "simulate": ("cmd_diagnose", "Run the bundle's model on a run's drive; write prediction and residual."),
    "validate": ("cmd_validate", "Run the thesis's chapter 6 tests with the compensation applied."),
}


#: Commands that read run directories: they refuse one whose manifest is not ``complete``
#: unless given ``--accept-incomplete`` (see piezopress.pipelines.files.check_status).
READS_RUN_DIRECTORIES = ("diagnose", "fit", "fit-creep", "fit-hysteresis", "fit-shaper", "report")


def _accept_incomplete(ctx: click.Context, param: click.Parameter, value: bool) -> None:
    """Set whether incomplete run directories are accepted; name what was accepted on stderr at the end."""
    from piezopress.pipelines import files

    files.accept_incomplete(value)

    def close() -> None:
        for note in files.status_notes():
            click.echo(f"Note: {note}", err=True)
        files.accept_incomplete(False)

    ctx.call_on_close(close)


def _eager_flag(name: str, callback, help: str) -> click.Option:
    """A flag set before the command runs (its callback sets the pipelines' switch and undoes it at the end)."""
    return click.Option([name], is_flag=True, expose_value=False, is_eager=True, callback=callback, help=help)


def accept_incomplete_option() -> click.Option:
    return _eager_flag(
        "--accept-incomplete",
        _accept_incomplete,
        "Use the complete runs of a run directory whose manifest says interrupted, failed or running "
        "(the output says so); without it such a directory is refused.",
    )


def _trust_metadata(ctx: click.Context, param: click.Parameter, value: bool) -> None:
    """Prefer recorded run kinds (or not); at the end print what the runs' measured profiles found."""
    from piezopress.pipelines import profiles

    profiles.trust_metadata(value)

    def close() -> None:
        for note in profiles.profile_notes():
            click.echo(f"Note: {note}", err=True)
        profiles.trust_metadata(False)

    ctx.call_on_close(close)


def trust_metadata_option() -> click.Option:
    return _eager_flag(
        "--trust-metadata",
        _trust_metadata,
        "Where a run's recorded kind disagrees with what its signals show, use the record "
        "(default: the measured kind; every disagreement is named on stderr).",
    )


def _allow_mixed_rigs(ctx: click.Context, param: click.Parameter, value: bool) -> None:
    from piezopress.pipelines import sources

    sources.allow_mixed_rigs(value)
    ctx.call_on_close(lambda: sources.allow_mixed_rigs(False))


def allow_mixed_rigs_option() -> click.Option:
    return _eager_flag(
        "--allow-mixed-rigs",
        _allow_mixed_rigs,
        "Join runs recorded on different presses (their rig configurations differ); without it they are "
        "refused, naming which run comes from which press.",
    )


def next_command(*lines: str, err: bool = False) -> None:
    """End a command with the next useful command(s), filled in."""
    click.echo("Next:", err=err)
    for line in lines:
        click.echo(f"  {line}", err=err)


class LazyGroup(click.Group):
    """A group whose commands are imported on first use (see :data:`COMMANDS`)."""

    def list_commands(self, ctx):
        return sorted(set(COMMANDS) | set(self.commands))

    def get_command(self, ctx, name):
        if name not in self.commands and name in COMMANDS:
            import importlib

            importlib.import_module(
                f"piezopress.piezocli.{COMMANDS[name][0]}"
            )  # its decorators add the command to this group
        cmd = self.commands.get(name)
        if (
            cmd is not None
            and name in READS_RUN_DIRECTORIES
            and not any(p.name == "accept_incomplete" for p in cmd.params)
        ):
            cmd.params.append(accept_incomplete_option())
            cmd.params.append(trust_metadata_option())
            cmd.params.append(allow_mixed_rigs_option())
        return cmd

    def format_commands(self, ctx, formatter):
        rows = [(name, COMMANDS[name][1]) for name in self.list_commands(ctx) if name in COMMANDS]
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="piezopress")
def cli() -> None:
    """Open-loop force control of piezoelectric presses.

    \b
    At the rig (the virtual one without hardware):
      piezopress characterize --out runs/char                 # scripted protocols -> Parquet runs
      piezopress fit runs/char --out build/bundle.json        # hysteresis, creep, shaper
      piezopress validate --bundle build/bundle.json --out runs/val
      piezopress fit runs/char --base --out build/base.json   # the thesis's model, for diagnose
      piezopress diagnose runs/char --bundle build/base.json --out runs/diag
      piezopress diagnose runs/char --bundle build/base.json --out runs/diag-gain --gain \\
          --fitted build/bundle.json                          # the extensions measured on the press
      piezopress compare build/bundle.json runs/diag-gain/recommended_bundle.json --out runs/compare
      piezopress report --characterization runs/char --validation runs/val --bundle build/bundle.json \\
          --diagnosis runs/diag --out build/report
    \b
    With a record from elsewhere:
      piezopress import data.csv --out run.parquet --col t_s=1 --col command_v=2 --col force_n=3
      piezopress fit run.parquet --out model.json             # prints the rest and the reach
      piezopress compensate --bundle model.json --reference ref.csv --out drive.csv
      piezopress simulate drive.csv --bundle model.json --out predicted.csv
      piezopress diagnose run.parquet --bundle model.json --out diag
      piezopress report --characterization run.parquet --bundle model.json --out report
    """
