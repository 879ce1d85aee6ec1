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


def reports_errors(func):
    """Turn library errors into a clean ``Error: ...`` and a non-zero exit, never a traceback."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except PiezopressError as exc:
            raise click.ClickException(str(exc)) from None
        except KeyboardInterrupt:
            click.echo("\nInterrupted.", err=True)
            sys.exit(130)

    return wrapper


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="piezopress")
def cli() -> None:
    """Open-loop force control of piezoelectric presses.

    \b
    Typical session at the rig:
      piezopress characterize --out runs/2026-11-21      # scripted protocols -> Parquet runs
      piezopress import data.csv --out run.parquet ...   # measured data from elsewhere
    """


def _register() -> None:
    # Imported here so that each command module stays small and self-contained.
    from piezocli import cmd_characterize, cmd_check_rig, cmd_diagnose, cmd_fit, cmd_import, cmd_inspect, cmd_report, cmd_validate  # noqa: F401


_register()
