"""Domain errors. Each message is one line naming the value, the place and what was expected."""


class PiezopressError(Exception):
    """Base class for every error piezopress reports to a user (no traceback needed)."""


class RunFormatError(PiezopressError, ValueError):
    """A run file (or data frame) does not follow the run format."""


class PlanError(PiezopressError, ValueError):
    """A protocol plan is invalid. ``problems`` lists every problem found, each on its own line."""

    def __init__(self, source: str, problems: list[str]):
        self.source = source
        self.problems = list(problems)
        head = f"{source}: {len(self.problems)} problem(s) in the plan"
        super().__init__(head + "\n" + "\n".join(f"  - {p}" for p in self.problems))


class ConfigError(PiezopressError, ValueError):
    """A rig configuration file is invalid."""

    def __init__(self, source: str, problems: list[str]):
        self.source = source
        self.problems = list(problems)
        head = f"{source}: {len(self.problems)} problem(s) in the rig configuration"
        super().__init__(head + "\n" + "\n".join(f"  - {p}" for p in self.problems))


class MetricError(PiezopressError, ValueError):
    """A run does not suit a metric (wrong shape of signal, too short, no step found, ...)."""


class ImportFormatError(PiezopressError, ValueError):
    """A CSV/TSV measurement cannot be imported as given."""


class OutputExistsError(PiezopressError, FileExistsError):
    """Refusing to overwrite existing data."""


class BackendError(PiezopressError, RuntimeError):
    """A backend failed while running a waveform."""
