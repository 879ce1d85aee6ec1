"""Domain errors. Each message is one line naming the value, the place and what was expected."""


class PiezopressError(Exception):
    """Base class for every error piezopress reports to a user (no traceback needed)."""


class RunFormatError(PiezopressError, ValueError):
    """A run file (or data frame) does not follow the run format."""


def _problem_list(source: str, what: str, problems: list[str]) -> str:
    # one problem: one line; several: a count, then one line each
    if len(problems) == 1:
        return f"{source}: {problems[0]}"
    return f"{source}: {len(problems)} problem(s) in the {what}\n" + "\n".join(f"  - {p}" for p in problems)


class PlanError(PiezopressError, ValueError):
    """A protocol plan is invalid. ``problems`` lists every problem found."""

    def __init__(self, source: str, problems: list[str]):
        self.source = source
        self.problems = list(problems)
        super().__init__(_problem_list(source, "plan", self.problems))


class ConfigError(PiezopressError, ValueError):
    """A rig configuration file is invalid. ``problems`` lists every problem found."""

    def __init__(self, source: str, problems: list[str]):
        self.source = source
        self.problems = list(problems)
        super().__init__(_problem_list(source, "rig configuration", self.problems))


class MetricError(PiezopressError, ValueError):
    """A run does not suit a metric (wrong shape of signal, too short, no step found, ...)."""


class ImportFormatError(PiezopressError, ValueError):
    """A CSV/TSV measurement cannot be imported as given."""


class OutputExistsError(PiezopressError, FileExistsError):
    """Refusing to overwrite existing data."""


class BackendError(PiezopressError, RuntimeError):
    """A backend failed while running a waveform."""


class FitError(PiezopressError, ValueError):
    """Data do not suit a model fit (lengths differ, too short, no step, NaN), or a model's parameters are invalid."""


class CompensatorUnstableError(PiezopressError, ValueError):
    """An inverse (compensator) would be unstable: a closed-loop discrete eigenvalue has ``|z| >= 1``."""


class OutputError(PiezopressError, OSError):
    """An output cannot be written where asked (missing or read-only folder, full disk)."""


def output_error(path: object, exc: OSError, what: str = "write it") -> OutputError:
    """One line for an :class:`OSError` met writing ``path``: the path, the system's reason and what to do."""
    import os

    reason = os.strerror(exc.errno) if exc.errno else (exc.strerror or type(exc).__name__)
    return OutputError(f"{path}: cannot {what} ({reason}); expected a folder that exists and that you may write to")
