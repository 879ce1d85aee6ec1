"""``diagnose`` and ``simulate``: runs and a bundle in; predictions, findings and an extended bundle out."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from piezopress import runformat, units
from piezopress.analysis import diagnosis as dg
from piezopress.analysis.creep import CreepModel
from piezopress.analysis.hysteresis import PIModel
from piezopress import plotting
from pipelines.bundle import collect_runs, read_document, write_document
from pipelines.characterize import new_output_dir, write_json_atomic


def base_model(bundle: dict[str, Any]) -> dg.Model:
    """The forward model a bundle describes (hysteresis, and creep and mode if present)."""
    h = PIModel.from_dict(bundle["hysteresis"]["model"])
    c = CreepModel.from_dict(bundle["creep"]["model"]) if "creep" in bundle else None
    mode = bundle.get("shaper", {}).get("mode", {})
    return dg.Model(h, c, mode.get("natural_freq_rad_s"), mode.get("damping"), mode.get("sensor_lowpass_hz"))


def fitted_run_names(bundle: dict[str, Any]) -> list[str]:
    """The runs the bundle's models were fitted on."""
    return sorted({r["name"] for sec in ("hysteresis", "creep", "shaper") for r in bundle.get(sec, {}).get("runs", [])})


def run_data(run: runformat.Run) -> dg.RunData:
    return dg.RunData(run.name, run.kind, run.t_s, run.command_v, run.output, run.sample_rate_hz, run.column("monitor_v"), dict(run.meta))


def simulate_file(bundle_path: str | Path, run_path: str | Path, out: str | Path) -> runformat.Run:
    """The bundle's model on a run's measured drive, written beside the measurement
    (columns ``predicted`` and ``residual`` added, in the run's output unit)."""
    bundle = read_document(bundle_path, "bundle")
    run = runformat.read_run(run_path)
    pred = base_model(bundle).predict(run_data(run))
    cols = {c: run.data[c].to_numpy() for c in run.data.columns}
    cols["predicted"] = pred
    cols["residual"] = run.output - pred
    meta = {**run.meta, "simulated_with": {"bundle": str(bundle_path), "sha256": runformat.sha256_file(bundle_path)}}
    sim = runformat.make_run(cols, meta)
    runformat.write_run(sim, out)
    return sim


def extend_bundle(bundle: dict[str, Any], findings: list[dg.Finding]) -> dict[str, Any]:
    """The bundle with every finding's extension recorded; those that belong in the
    compensator change it (creep form, drive rate limit, lead)."""
    ext = copy.deepcopy(bundle)
    ext["extensions"] = {f.cause: f.parameters for f in findings}
    # what the compensator applies of them, and what it only records
    applied = {"amplifier_slew_limit", "input_delay", "logarithmic_creep", "hysteresis_order"}
    ext["extensions_applied_by_compensator"] = sorted(f.cause for f in findings if f.cause in applied)
    ext["extensions_recorded_only"] = sorted(f.cause for f in findings if f.cause not in applied)
    comp = ext.setdefault("compensation", {})
    for f in findings:
        if f.cause == "amplifier_slew_limit":
            # keep the drive at half the slew limit: the reference rate times the press's
            # largest output per volt (the model's steepest slope over the drive range) must stay below it
            model = PIModel.from_dict(bundle["hysteresis"]["model"])
            hi = float(comp.get("drive_max_v", model.x0 + 150.0))
            v = np.linspace(model.x0, hi if hi > model.x0 else model.x0 + 150.0, 1501)  # rest to the top of the drive range
            gain = float(np.max(np.diff(model.forward(v)[0]) / np.diff(v)))
            key = f"max_rate_{units.key(model.output_unit)}_per_s"
            comp[key] = min(comp.get(key) or np.inf, 0.5 * f.parameters["slew_rate_v_per_s"] * gain)
        elif f.cause == "input_delay":
            comp["lead_s"] = comp.get("lead_s", 0.0) + f.parameters["delay_s"]
        elif f.cause == "hysteresis_order":
            ext["hysteresis"]["model"] = f.model.hysteresis.to_dict()
            ext["hysteresis"]["extended_by"] = "diagnose: hysteresis_order"
        elif f.cause == "logarithmic_creep" and "creep" in ext:
            log = CreepModel.log(f.parameters["static_gain"], f.parameters["per_decade"])
            ext["creep"]["model"] = log.to_dict()
            ext["creep"]["extended_by"] = "diagnose: logarithmic_creep"
    return ext


def diagnose(paths: Iterable[str | Path], bundle_path: str | Path, out_dir: str | Path,
             causes: Iterable[str] | None = None) -> tuple[dg.Diagnosis, Path]:
    """Diagnose the runs against the bundle; write ``diagnosis.json`` and ``extended_bundle.json``."""
    bundle = read_document(bundle_path, "bundle")
    runs = [run_data(r) for r in collect_runs(paths)]
    if not runs:
        raise dg.H.HysteresisFitError("no runs to diagnose")
    result = dg.diagnose(base_model(bundle), runs, fitted_run_names(bundle), list(causes) if causes else None)
    out = new_output_dir(out_dir)
    doc = {"bundle": {"file": str(bundle_path), "sha256": runformat.sha256_file(bundle_path)},
           "causes": {c.id: {"physics": c.physics, "extension": c.extension, "in_compensator": c.in_compensator} for c in dg.CAUSES.values()},
           **result.as_dict()}
    write_json_atomic(out / "diagnosis.json", doc)
    write_document(extend_bundle(bundle, result.findings), out / "extended_bundle.json")
    before = {s.run: s for s in result.before}
    after = {s.run: s for s in result.after}
    names = [r.name for r in runs]
    bars = plotting.residual_rms_bars(names, [before[n].rms for n in names], [after[n].rms for n in names], [before[n].floor for n in names],
                                      unit=result.unit)
    (out / "residuals.png").write_bytes(plotting.to_png(bars))
    (out / "residual_traces.png").write_bytes(plotting.to_png(residual_figure(runs, base_model(bundle), result)))
    return result, out


def residual_figure(runs: list[dg.RunData], base: dg.Model, result: dg.Diagnosis):
    """Residual of each run against its own time, before (base model) and after (extended)."""
    def curves(model):
        out = []
        for r in runs:
            res = r.y - model.predict(r)
            t = r.t_s / r.t_s[-1] if r.t_s[-1] > 0 else r.t_s  # every run on a 0-1 time axis
            out.append(plotting.Curve(t, res, r.name))
        return out

    return plotting.model_residuals(curves(base), curves(result.model), unit=result.unit, left_title="base model", right_title="extended by the findings",
                                    left_xlabel="time / run length", right_xlabel="time / run length",
                                    title=f"Residuals of {len(runs)} runs: measured - model")


def format_summary(result: dg.Diagnosis) -> str:
    """The diagnosis as a technician reads it (figures in the runs' unit, N or µm)."""
    u, k = units.label(result.unit), units.key(result.unit)
    lines = [f"Diagnosis: {result.summary}", ""]
    lines.append(f"Residual over all runs: {result.residual_rms:.3g} {u} RMS; sensor noise floor {result.noise_floor:.3g} {u} RMS.")
    if result.findings:
        lines.append("")
        lines.append(f"{'cause':<28} {'held-out RMS: base -> extended':>32} {'gain':>7}  parameters")
        for f in result.findings:
            params = ", ".join(f"{k} = {v:.4g}" for k, v in f.parameters.items())
            lines.append(f"{f.cause:<28} {f.baseline_rms:>14.3g} {u} -> {f.extended_rms:.3g} {u} {f.gain_pct:>6.0f} %  {params}")
            lines.append(f"    why: {dg.CAUSES[f.cause].physics}; evidence: {f.evidence}")
            lines.append(f"    judged on {', '.join(f.heldout)} (not used to fit the extension)")
    else:
        lines.append("No cause in the catalogue improves the prediction of held-out data beyond the noise: no findings.")
    if result.unexplained:
        lines.append("")
        lines.append("Unexplained (no cause in the catalogue accounts for it):")
        for u_ in result.unexplained:
            lines.append(f"    {u_['run']}: {u_[f'rms_{k}']:.3g} {u} RMS = {u_['ratio']:.1f} x the noise floor, largest at {u_['where_s']:.4g} s, "
                         f"dominant frequency {u_['dominant_freq_hz']:.4g} Hz")
    return "\n".join(lines)
