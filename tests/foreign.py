"""Runs as other programs write them: the test helpers that make a run directory foreign.

A lab's runs mostly come from elsewhere (LabVIEW exports, another group's script,
``import``ed CSVs): they carry only the run format's four required metadata fields, and
their ``kind`` may be ``custom``. These helpers copy a run directory into that form (no
manifest, no protocol, no rig configuration, no monitor column if asked), so that a test
can check that every stage decides from the signals and gets the same answers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from piezopress import runformat


def foreign_run(
    run: runformat.Run,
    *,
    custom: bool = False,
    drop_monitor: bool = False,
    glitch_every: int | None = None,
    seed: int = 0,
    t0_s: float | None = None,
) -> runformat.Run:
    """``run`` with its metadata cut to the required fields (``custom``: every kind ``custom``),
    optionally without its ``monitor_v`` column and with one glitched output sample in
    ``glitch_every`` (read as 0 or as the ADC's top code, alternately, at seeded places);
    with ``t0_s``, its times moved to start there (a file stamped with another clock)."""
    meta = {k: run.meta[k] for k in runformat.REQUIRED_METADATA}
    if custom:
        meta["kind"] = "custom"
    cols = {c: run.data[c].to_numpy() for c in run.data.columns if not (drop_monitor and c == "monitor_v")}
    if glitch_every:
        y = cols[run.output_column].copy()
        rng = np.random.default_rng(seed)
        n = max(1, y.size // glitch_every)
        where = np.sort(rng.choice(np.arange(2, y.size - 2), size=n, replace=False))
        top = float(np.max(y)) + 0.5 * float(np.ptp(y)) + 1.0
        y[where] = np.where(np.arange(n) % 2 == 0, 0.0, top)
        cols[run.output_column] = y
    if t0_s is not None:
        cols["t_s"] = cols["t_s"] - cols["t_s"][0] + t0_s
    return runformat.make_run(cols, meta)


#: The pause between two runs on the session clock of :func:`foreign_dir` (s).
SESSION_PAUSE_S = 5.0


def foreign_dir(src: str | Path, dst: str | Path, *, session_clock_s: float | None = None, **options) -> Path:
    """Every run of the directory ``src`` (its manifest's complete runs, else every
    ``*.parquet``) written to the new directory ``dst`` as :func:`foreign_run` makes it;
    no manifest is written (other programs write none). With ``session_clock_s`` every run's
    times are stamped on one session clock starting there, in the source's order, each run
    :data:`SESSION_PAUSE_S` after the one before it ended (as a DAQ program stamps its files)."""
    from piezopress.pipelines.files import run_files

    dst = Path(dst)
    dst.mkdir(parents=True, exist_ok=False)
    clock = session_clock_s
    for f in run_files(src):
        run = foreign_run(runformat.read_run(f), t0_s=clock, **options)
        if clock is not None:
            t = run.t_s
            clock += float(t[-1] - t[0]) + 1.0 / run.sample_rate_hz + SESSION_PAUSE_S
        runformat.write_run(run, dst / Path(f).name)
    return dst
