"""Runs as the stages see them: read, measured, checked against what they record.

Every stage that reads runs for a decision reads them through :func:`read_measured` (or
passes a run through :func:`measured`): the run gets its
:class:`~piezopress.analysis.profile.RunProfile`, its ``kind`` becomes the measured one
when the record disagrees (``trust_metadata`` keeps the record), and glitched output
samples are replaced by the mean of their neighbours. What was found is kept for
:func:`profile_notes` (the CLI prints it on stderr): one line per disagreement, naming the
run, the recorded value and the measured one, and one per run with glitches.
"""

from __future__ import annotations

import os
from contextvars import ContextVar
from pathlib import Path

from piezopress import runformat
from piezopress.analysis import profile as prof_mod

_TRUST_METADATA: ContextVar[bool] = ContextVar("trust_metadata", default=False)
_NOTES: ContextVar[tuple[str, ...]] = ContextVar("profile_notes", default=())


def trust_metadata(trust: bool = True) -> None:
    """Prefer each run's recorded kind over the measured one (``--trust-metadata``), and start
    a new list of :func:`profile_notes`."""
    _TRUST_METADATA.set(bool(trust))
    _NOTES.set(())


def profile_notes() -> list[str]:
    """What the measured profiles found since :func:`trust_metadata` (disagreements, glitches)."""
    return list(_NOTES.get())


def note(line: str) -> None:
    """Keep one line for :func:`profile_notes` (once)."""
    if line not in _NOTES.get():
        _NOTES.set(_NOTES.get() + (line,))


def measured(run: runformat.Run) -> runformat.Run:
    """``run`` with its profile, its measured kind and its glitched samples repaired."""
    if run.profile is not None:  # measured already
        return run
    label = run.path.name if run.path is not None else run.name
    p = prof_mod.profile_run(run)
    trust = _TRUST_METADATA.get()
    for line in prof_mod.crosscheck(run.meta, p, label):
        note(f"{line}; {'the record is used (--trust-metadata)' if trust else 'the measured value is used'}")
    meta = dict(run.meta)
    kind = prof_mod.measured_kind(run.meta, p, trust)
    if kind != run.meta.get("kind"):
        meta["recorded_kind"] = run.meta.get("kind")
        meta["kind"] = kind
    data = run.data
    if p.saturated:
        note(
            f"{label}: {run.output_column} sits at {p.saturated_at:.6g} for {100 * p.saturated:.1f} % of its samples "
            "(a saturated sensor or ADC at its limit); those samples are not measurements: lower the drive, or "
            "re-range the sensor"
        )
    if p.glitches:
        col = run.output_column
        g = list(p.glitches)
        where = ", ".join(f"{run.t_s[i]:.6g} s" for i in g[:5]) + (f" and {len(g) - 5} more" if len(g) > 5 else "")
        note(
            f"{label}: {len(g)} glitched sample(s) of {col} (isolated jumps, as a lost or saturated ADC reading), "
            f"at {where}; each replaced by the mean of its neighbours"
        )
        data = data.copy()
        data[col] = prof_mod.without_glitches(run.output, g)
    return runformat.Run(data, meta, run.path, profile=p)


def examine(run: runformat.Run) -> tuple[prof_mod.RunProfile, list[str]]:
    """The run's profile and where its metadata disagrees with it (``inspect`` prints both)."""
    p = prof_mod.profile_run(run)
    return p, prof_mod.crosscheck(run.meta, p, run.path.name if run.path is not None else run.name)


def read_measured(path: str | os.PathLike[str] | Path, *, allow_incomplete: bool = False) -> runformat.Run:
    """:func:`piezopress.runformat.read_run`, then :func:`measured`."""
    return measured(runformat.read_run(path, allow_incomplete=allow_incomplete))
