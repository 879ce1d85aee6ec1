"""The characterization table: each run's thesis metric, beside the thesis's figure.

Triangles give the maximum hysteresis (Eq. 5.1), creep steps the creep after the hold
(Eq. 5.2), steps the overshoot (Eq. 5.3) and 2 % settling time. A run that does not suit
its metric gets a row saying why, never a crash.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from piezopress import runformat, thesis, units
from piezopress.analysis import metrics, profile
from piezopress.errors import MetricError
from piezopress.pipelines.files import read_manifest, run_files
from piezopress.pipelines.profiles import read_measured

COLUMNS = ["run", "kind", "metric", "value", "unit", "thesis", "thesis_source", "note"]


def _snap(value: float | None, keys, rtol: float = 0.02):
    """The key of a thesis table that ``value`` (measured) stands for, within ``rtol``."""
    if value is None:
        return None
    return next((k for k in keys if math.isclose(value, float(k), rel_tol=rtol)), None)


def _thesis_for(run: runformat.Run, metric: str) -> tuple[float, str]:
    """The thesis figure a run should be compared with, if the thesis measured that test
    (the test recognised from the run's measured profile, never from its metadata)."""
    prof = profile.of(run)
    full = math.isclose(float(np.max(run.command_v)), 150.0, abs_tol=0.5)
    if metric == "max_hysteresis":
        if prof.varying_amplitude:
            return thesis.HYSTERESIS_VARYING_0P1HZ_PCT, "Sec. 6.2.1 (varying amplitude)"
        f = _snap(prof.freq_hz, thesis.HYSTERESIS_BY_FREQ_PCT)
        if full and f is not None:
            return thesis.HYSTERESIS_BY_FREQ_PCT[f], f"Table 5.1 ({f:g} Hz)"
    if metric == "creep" and full and math.isclose(run.t_s[-1], 120.0, rel_tol=0.05, abs_tol=2.0):
        return thesis.CREEP_120S_PCT, "Sec. 5.2 (120 s)"
    if metric == "overshoot" and math.isclose(float(np.max(run.command_v)), 20.0, abs_tol=0.5):
        return thesis.OVERSHOOT_20V_PCT, "Sec. 5.3 (20 V)"
    return float("nan"), ""


def run_metrics(run: runformat.Run) -> list[dict]:
    """The table rows of one run."""
    rows: list[dict] = []
    y = run.output
    unit_out = units.label(run.output_unit)  # N or µm

    def row(metric: str, value: float, unit: str, note: str = "", with_thesis: bool = True) -> None:
        ref, src = _thesis_for(run, metric) if with_thesis else (float("nan"), "")
        rows.append(
            {
                "run": run.name,
                "kind": run.kind,
                "metric": metric,
                "value": value,
                "unit": unit,
                "thesis": ref,
                "thesis_source": src,
                "note": note,
            }
        )

    try:
        if run.kind in ("triangle", "sine"):
            x = run.column("reference_n")
            x_unit = "V" if x is None else "N"  # against the drive, or the reference force of a compensated run
            x = run.command_v if x is None else x
            h = metrics.max_hysteresis(x, y)
            row(
                "max_hysteresis",
                h.percent,
                "%",
                f"{h.n_cycles} cycles, gap {h.max_gap:.2f} {unit_out} at {h.x_at_max:.1f} {x_unit}",
            )
        elif run.kind == "creep":
            c = metrics.creep(run.t_s, y, drive=run.command_v)
            row(
                "creep",
                c.percent,
                "%",
                f"F_ss taken {c.t_ss_s:g} s after the step, F_f after {c.hold_s:.0f} s; relative to the step size",
            )
        elif run.kind == "step":
            s = metrics.overshoot(run.t_s, y, drive=run.command_v)
            note = f"step {s.step_size:.1f} {unit_out}" + ("" if s.significant else "; not above the noise")
            row("overshoot", s.percent, "%", note)
            settle_note = "2 % band below 3x noise" if s.band_below_noise else ("" if s.settled else "did not settle")
            row(
                "settling_time",
                s.settling_time_s * 1e3 if s.settled else float("nan"),
                "ms",
                settle_note,
                with_thesis=False,
            )
        elif np.ptp(run.command_v) == 0:  # a rest run: the sensor alone
            k = np.polyfit(run.t_s, y, 1)
            row(
                "noise_rms",
                float(np.std(y - np.polyval(k, run.t_s))),
                unit_out,
                f"at rest, {run.t_s[-1]:.0f} s",
                with_thesis=False,
            )
            row(
                "drift_per_min",
                float(k[0] * 60.0),
                f"{unit_out}/min",
                f"offset {np.mean(y):.2f} {unit_out} at zero drive",
                with_thesis=False,
            )
        else:
            row("-", float("nan"), "", f"no characterization metric for kind {run.kind!r}", with_thesis=False)
    except MetricError as exc:
        row("-", float("nan"), "", f"does not suit its metric: {exc}", with_thesis=False)
    return rows


def characterization_table(run_dir: str | Path) -> pd.DataFrame:
    """Metrics of every run listed in a run directory's manifest (or every ``*.parquet``)."""
    rows: list[dict] = []
    for f in run_files(run_dir):
        rows.extend(run_metrics(read_measured(f)))
    return pd.DataFrame(rows, columns=COLUMNS)


def format_table(table: pd.DataFrame, title: str = "Characterization") -> str:
    """A fixed-width text table for the terminal."""

    def num(v: float, digits: int = 2) -> str:
        return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{digits}f}"

    head = f"{'run':<28} {'metric':<15} {'value':>9} {'unit':<4} {'thesis':>8}  {'source':<30} note"
    lines = [title, head, "-" * len(head)]
    for r in table.itertuples(index=False):
        lines.append(
            f"{r.run:<28} {r.metric:<15} {num(r.value):>9} {r.unit:<4} {num(r.thesis):>8}  {r.thesis_source:<30} "
            f"{r.note}"
        )
    return "\n".join(lines)


# --------------------------------------------------------------------------- validation


def _validation_thesis(run: runformat.Run, metric: str, shaper: bool) -> tuple[float, str]:
    prof = profile.of(run)  # the test recognised from the reference's measured profile
    f = prof.freq_hz
    if metric == "max_hysteresis":
        if prof.varying_amplitude:
            rising = len(prof.peaks) > 1 and bool(np.all(np.diff(prof.peaks) > 0))
            key = "increasing" if rising else "random"
            return thesis.HYSTERESIS_COMPENSATED_PCT[key], f"Table 6.6 (test {5 if rising else 6})"
        peak = round(prof.high - prof.low)
        if _snap(f, (0.1,)) is not None and f"{peak:g}N" in thesis.HYSTERESIS_COMPENSATED_PCT:
            return thesis.HYSTERESIS_COMPENSATED_PCT[f"{peak:g}N"], f"Table 6.6 ({peak:g} N)"
        table = (
            thesis.HYSTERESIS_COMPENSATED_BY_FREQ_WITH_SHAPER_PCT
            if shaper
            else thesis.HYSTERESIS_COMPENSATED_BY_FREQ_NO_SHAPER_PCT
        )
        f = _snap(f, table)
        if f is not None:
            return table[f], f"Table {'6.11' if shaper else '6.12'} ({f:g} Hz)"
    if metric == "creep":
        return thesis.TABLE_6_13["creep_pct"]["controlled"][0], "Sec. 6.5 (0.63 %; 0.96 % in 6.3.2)"
    level = None if prof.step_size is None else round(prof.step_size)
    if metric == "overshoot" and level is not None and int(level) in thesis.OVERSHOOT_SHAPED_PCT:
        return thesis.OVERSHOOT_SHAPED_PCT[int(level)], f"Table 6.9 ({level:g} N)"
    if metric == "settling_time" and level is not None and int(level) in thesis.SETTLING_SHAPED_MS:
        return thesis.SETTLING_SHAPED_MS[int(level)], f"Table 6.9 ({level:g} N)"
    if metric == "tracking_relative":
        return thesis.TRACKING_RELATIVE_ERROR_PCT[1], "Sec. 6.6 (12.08 %)"
    if metric == "tracking_absolute":
        return 22.76, "Sec. 6.6 (22.76 N)"
    return float("nan"), ""


#: A compensated step starts back early (centred shaper, lead): that much of the hold's end is left out.
STEP_END_MARGIN_S = 0.005
#: Tracking: relative error counted where the reference is at least this far above the preload (N).
TRACKING_MIN_REFERENCE_N = 30.0


def validation_metrics(run: runformat.Run, shaper: bool = True) -> list[dict]:
    """The validation rows of one compensated run (its output against its reference)."""
    rows: list[dict] = []
    ref = run.column("reference_n")
    y = run.output
    u = units.label(run.output_unit)  # N on a force press

    def row(metric, value, unit, note="", with_thesis=True):
        th, src = _validation_thesis(run, metric, shaper) if with_thesis else (float("nan"), "")
        rows.append(
            {
                "run": run.name,
                "kind": run.kind,
                "metric": metric,
                "value": value,
                "unit": unit,
                "thesis": th,
                "thesis_source": src,
                "note": note,
            }
        )

    if ref is None:
        return [
            {
                "run": run.name,
                "kind": run.kind,
                "metric": "-",
                "value": float("nan"),
                "unit": "",
                "thesis": float("nan"),
                "thesis_source": "",
                "note": "no reference_n column: not a compensated run",
            }
        ]
    preload = float(run.meta.get("preload_n", ref[0]))
    try:
        if run.kind == "triangle":
            h = metrics.max_hysteresis(ref, y)
            row(
                "max_hysteresis",
                h.percent,
                "%",
                f"{h.n_cycles} cycles, gap {h.max_gap:.2f} {u} of {h.output_range:.1f} {u}",
            )
        elif run.kind == "creep":
            c = metrics.creep(run.t_s, y, drive=ref)
            row(
                "creep",
                c.percent,
                "%",
                f"F_ss {c.t_ss_s:g} s after the step, F_f after {c.hold_s:.0f} s; relative to the step",
            )
        elif run.kind == "step":
            st = metrics.overshoot(run.t_s, y, drive=ref, end_margin_s=STEP_END_MARGIN_S)
            row(
                "overshoot",
                st.percent,
                "%",
                f"step {st.step_size:.1f} {u}" + ("" if st.significant else "; not above the noise"),
            )
            row(
                "settling_time",
                st.settling_time_s * 1e3 if st.settled else float("nan"),
                "ms",
                "2 % band below 3x noise" if st.band_below_noise else ("" if st.settled else "did not settle"),
            )
        elif run.kind == "staircase":
            tr = metrics.tracking_error(run.t_s, ref - preload, y - preload, min_reference=TRACKING_MIN_REFERENCE_N)
            row(
                "tracking_relative",
                tr.max_abs_relative_percent,
                "%",
                f"max |error|/reference from {TRACKING_MIN_REFERENCE_N:g} {u} up, outside the ramps; range "
                f"{tr.min_relative_percent:.2f} to {tr.max_relative_percent:.2f} %",
            )
            full = metrics.tracking_error(run.t_s, ref - preload, y - preload, min_reference=1e-9)
            row(
                "tracking_absolute",
                max(abs(full.max_error_n), abs(full.min_error_n)),
                u,
                f"max |error| outside the ramps, all stairs; {full.min_error_n:.2f} to {full.max_error_n:.2f} {u}, "
                f"RMS {full.rms_error_n:.2f} {u}",
            )
        elif run.kind == "custom":  # a trajectory (random force): the RMS error over the whole run
            err = y - ref
            span = float(np.ptp(ref))
            if span <= 0:
                raise MetricError("the reference is constant: nothing to track")
            e_rms = float(np.sqrt(np.mean(err**2)))
            row(
                "tracking_rms",
                100.0 * e_rms / span,
                "%",
                f"RMS error {e_rms:.2f} {u} over a {span:.0f} {u} range; max |error| {float(np.max(np.abs(err))):.2f} "
                f"{u}",
                with_thesis=False,
            )
        else:
            row("-", float("nan"), "", f"no validation metric for kind {run.kind!r}", with_thesis=False)
    except MetricError as exc:
        row("-", float("nan"), "", f"does not suit its metric: {exc}", with_thesis=False)
    return rows


def validation_table(run_dir: str | Path) -> pd.DataFrame:
    """Metrics of every run of a validation directory, with the thesis's compensated figures."""
    run_dir = Path(run_dir)
    manifest = read_manifest(run_dir) if (run_dir / "manifest.json").is_file() else {}
    shaper = manifest.get("compensation_options", {}).get("shaper", True)
    rows: list[dict] = []
    for f in run_files(run_dir):
        rows.extend(validation_metrics(read_measured(f), shaper))
    return pd.DataFrame(rows, columns=COLUMNS)


def write_table(table: pd.DataFrame, path: str | Path) -> Path:
    """Save the table as CSV (fixed float format, so the same data gives the same bytes)."""
    path = Path(path)
    if path.exists():
        raise runformat.OutputExistsError(f"{path}: already exists; refusing to overwrite it")
    table.to_csv(path, index=False, float_format="%.6g")
    return path
