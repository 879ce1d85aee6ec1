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
            self.fail(f"{value!r}: expected START:STOP (counted from 0, STOP excluded), e.g. 0:8000 or 11151:", param, ctx)
        if (out[0] is not None and out[0] < 0) or (out[1] is not None and out[1] < 1) or (None not in out and out[1] <= out[0]):
            self.fail(f"{value!r}: expected 0 <= START < STOP", param, ctx)
        return out


ROWS = RowsType()


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
