"""``diagnose`` and ``simulate``: runs and a bundle in; predictions, findings and an extended bundle out."""

from __future__ import annotations

import copy
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np

from piezopress import runformat, units
from piezopress.analysis import diagnosis as dg
from piezopress.analysis.creep import CreepModel
from piezopress.analysis.hysteresis import PIModel
from piezopress.analysis.shaper import design_shaper
from piezopress.errors import FitError, PiezopressError
from piezopress import plotting
from piezopress.pipelines.bundle import collect_runs, read_document, write_document
from piezopress.pipelines import next_plan
from piezopress.pipelines.files import new_output_dir, write_json_atomic


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


def second_shaper(parameters: dict[str, float]) -> dict[str, Any]:
    """A ZVD shaper for a second mode (``natural_freq_rad_s``, ``damping``), as a bundle's
    ``shaper.shaper2`` (the compensator applies it after the first shaper)."""
    sh = design_shaper("zvd", float(parameters["natural_freq_rad_s"]), float(parameters["damping"]))
    return {"name": sh.name, "times_s": list(sh.times_s), "amplitudes": list(sh.amplitudes), "natural_freq_rad_s": sh.wn,
            "damping": sh.zeta, "zv_power": sh.zv_power, "delay_ms": 1e3 * sh.delay_s, "centroid_ms": 1e3 * sh.centroid_s,
            "for": "diagnose: second_resonance"}


#: Findings whose fit refits the main mode freely because the effect distorts its
#: identification (a delay is read as damping, and the base lead ``2 zeta / wn`` then holds
#: part of the delay): with one of them, the extended bundle's shaper and lead are designed
#: for the diagnosis model's mode. (A second mode is not among them: its joint refit moves
#: the main mode little, and the base lead, which the refit would shorten, also stands for
#: the delays the lead formula leaves out - the load cell's low-pass, the DAC's hold - so a
#: shorter lead loses more at 50 Hz than the better shaper gains.)
MODE_REFIT_CAUSES = ("input_delay",)


def rate_dependence(model: dg.Model) -> dict[str, Any]:
    """A model's rate dependence as the bundle's ``compensation.rate_dependence``."""
    sat = getattr(model, "rate_saturation_v_per_s", None)
    return {"widen_v_per_kv_s": float(model.rate_v_per_kv_s), "loss_per_kv_s": float(getattr(model, "rate_loss_per_kv_s", 0.0)),
            "saturation_v_per_s": float(sat) if sat and np.isfinite(sat) else None, "tau_s": float(getattr(model, "rate_tau_s", 5e-4))}


#: Creep elements (not the log tail) faster than this are folded into the compensator's
#: instantaneous gain (see :func:`creep_for_compensator`).
FAST_CREEP_S = 1.0


def creep_for_compensator(model: CreepModel) -> CreepModel:
    """The found creep model as the compensator inverts it.

    The log-creep finding fits a few Kelvin-Voigt elements and a log tail (equal gains, two
    per decade from 0.05 s) on the hold read at 50 Hz. An element faster than
    :data:`FAST_CREEP_S` there is not told apart from the step's own transient and the tail's
    first terms (it lands on the grid's floor, 0.2 s, taking what the tail's fit left): as
    a dynamic term its compensator drives every step too hard for a fraction of a second
    (an overshoot the press does not have). It is folded into the instantaneous gain: the
    creep at long times is kept, the fast part is the tail's.
    """
    gamma = model.params.get("per_decade")
    if model.form != "kv" or gamma is None:
        return model
    tail_gain = 0.5 * float(gamma)
    fast = [i for i, (t, g) in enumerate(zip(model.taus_s, model.gains)) if t < FAST_CREEP_S and not np.isclose(g, tail_gain, rtol=1e-9)]
    if not fast:
        return model
    keep = [i for i in range(len(model.taus_s)) if i not in fast]
    return CreepModel("kv", model.static_gain + sum(model.gains[i] for i in fast), tuple(model.taus_s[i] for i in keep),
                      tuple(model.gains[i] for i in keep), dict(model.params))


def modal_delay_s(model: dg.Model) -> float:
    """The low-frequency delay of a model's mode(s): ``2 zeta / wn``, each mode weighted by its share."""
    share2 = model.mode2[0] if model.mode2 else 0.0
    d = (1.0 - share2) * 2.0 * float(model.zeta) / float(model.wn)
    if model.mode2:
        d += share2 * 2.0 * float(model.mode2[2]) / float(model.mode2[1])
    return d


def extend_bundle(bundle: dict[str, Any], findings: list[dg.Finding], model: dg.Model | None = None) -> dict[str, Any]:
    """The bundle with every finding's extension recorded; those that belong in the
    compensator change it (creep form, lead, slew, rate-aware inverse, second shaper).

    ``model`` is the diagnosis's final model (all findings applied): when a finding refitted
    the main mode (:data:`MODE_REFIT_CAUSES`), the main shaper is designed again for it and
    the lead is its low-frequency delay plus the input delay found (the base bundle's lead
    had absorbed part of that delay into the mode's damping; adding the delay to it would
    lead twice)."""
    ext = copy.deepcopy(bundle)
    ext["extensions"] = {f.cause: f.parameters for f in findings}
    # what the compensator applies of them, and what it only records: the catalogue says
    # (Cause.in_compensator, the one place; a branch below must change the compensator for exactly those)
    applied = {c.id for c in dg.CAUSES.values() if c.in_compensator}
    ext["extensions_applied_by_compensator"] = sorted(f.cause for f in findings if f.cause in applied)
    ext["extensions_recorded_only"] = sorted(f.cause for f in findings if f.cause not in applied)
    comp = ext.setdefault("compensation", {})
    for f in findings:
        if f.cause == "amplifier_slew_limit":
            # the compensator keeps its drive below the slew (slowing the reference where the drive would outrun it)
            comp["slew_v_per_s"] = float(f.parameters["slew_rate_v_per_s"])
        elif f.cause == "input_delay":
            comp["lead_s"] = comp.get("lead_s", 0.0) + f.parameters["delay_s"]
            if f.parameters.get("operators_refitted"):  # found on slow sweeps: the lag had widened the fitted loop
                ext["hysteresis"]["model"] = f.model.hysteresis.to_dict()
                ext["hysteresis"]["extended_by"] = "diagnose: input_delay (operators refitted on the delayed drive)"
            comp["delay_lead_s"] = comp.get("delay_lead_s", 0.0) + f.parameters["delay_s"]
        elif f.cause == "rate_dependent_hysteresis":
            comp["rate_dependence"] = rate_dependence(f.model)  # the inverse at the drive's own rate
        elif f.cause == "second_resonance" and "shaper" in ext:
            ext["shaper"]["shaper2"] = second_shaper(f.parameters)
        elif f.cause == "hysteresis_order":
            ext["hysteresis"]["model"] = f.model.hysteresis.to_dict()
            ext["hysteresis"]["extended_by"] = "diagnose: hysteresis_order"
        elif f.cause == "logarithmic_creep" and "creep" in ext:
            # the creep model the finding fitted and judged (its elements and log tail), not a log form rebuilt
            # from two of its numbers: the compensator inverts what was found
            log = f.model.creep if f.model.creep is not None else CreepModel.log(f.parameters["static_gain"], f.parameters["per_decade"])
            ext["creep"]["model"] = creep_for_compensator(log).to_dict()
            ext["creep"]["extended_by"] = "diagnose: logarithmic_creep"
    refit_by = [f.cause for f in findings if f.cause in MODE_REFIT_CAUSES]
    if model is not None and model.wn and model.zeta and refit_by and "shaper" in ext:
        sh = ext["shaper"]
        try:
            new = design_shaper(sh["shaper"]["name"], float(model.wn), float(model.zeta))
        except FitError:
            new = None  # the design does not hold at the refitted damping: the base shaper stays
        if new is not None:
            sh["shaper"] = {**sh["shaper"], "times_s": list(new.times_s), "amplitudes": list(new.amplitudes),
                            "natural_freq_rad_s": new.wn, "damping": new.zeta, "zv_power": new.zv_power,
                            "delay_ms": 1e3 * new.delay_s, "centroid_ms": 1e3 * new.centroid_s}
            sh["mode"] = {**sh["mode"], "natural_freq_rad_s": float(model.wn), "damping": float(model.zeta)}
            sh["extended_by"] = f"diagnose: the mode refitted with {', '.join(refit_by)}"
            # the lead's modal part (2 zeta / wn of the base mode) replaced by the refitted modes' low-frequency delay
            old_modal = 2.0 * float(bundle["shaper"]["mode"]["damping"]) / float(bundle["shaper"]["mode"]["natural_freq_rad_s"])
            comp["lead_s"] = float(bundle.get("compensation", {}).get("lead_s", old_modal)) - old_modal + modal_delay_s(model) \
                + comp.get("delay_lead_s", 0.0)
    return ext


def fitted_run_keys(bundle: dict[str, Any]) -> list[str]:
    """The runs the bundle's models were fitted on, by file (sha256; the name where the bundle
    recorded no file): two runs may share a name, never a file."""
    return sorted({r.get("sha256") or r["name"] for sec in ("hysteresis", "creep", "shaper") for r in bundle.get(sec, {}).get("runs", [])})


def diagnosis_runs(loaded: list[runformat.Run]) -> list[dg.RunData]:
    """The runs as the diagnosis sees them, each keyed by its file's sha256; a name that
    repeats (two imports of one source, or two directories) is told apart by its file."""
    runs = [run_data(r) for r in loaded]
    count: dict[str, int] = {}
    for r in runs:
        count[r.name] = count.get(r.name, 0) + 1
    out = []
    for r, src in zip(runs, loaded):
        key = runformat.sha256_file(src.path) if src.path is not None else ""
        name = r.name
        if count[name] > 1 and src.path is not None:
            name = f"{name} [{src.path.parent.name}/{src.path.name}]"
        out.append(replace(r, name=name, key=key))
    return out


class UnknownCauseError(PiezopressError, ValueError):
    """A cause asked for is not in the catalogue (:data:`piezopress.analysis.diagnosis.CAUSES`)."""


def check_causes(causes: Iterable[str] | None) -> list[str] | None:
    """The cause ids asked for, each checked against the catalogue (``None``: all of them)."""
    causes = list(causes) if causes else None
    unknown = [c for c in causes or () if c not in dg.CAUSES]
    if unknown:
        raise UnknownCauseError(f"cause {', '.join(map(repr, unknown))} is not in the catalogue; expected one of {', '.join(dg.CAUSES)}")
    return causes


def diagnose(paths: Iterable[str | Path], bundle_path: str | Path, out_dir: str | Path,
             causes: Iterable[str] | None = None,
             on_progress: Callable[[dg.CauseProgress], None] | None = None) -> tuple[dg.Diagnosis, Path]:
    """Diagnose the runs (files or run directories, several at once) against the bundle;
    write ``diagnosis.json``, ``extended_bundle.json``, the residual figures and, when some
    causes could not be tested, ``next-plan.toml``: the experiment that would test them.
    ``on_progress`` hears of every cause tried (:class:`~piezopress.analysis.diagnosis.CauseProgress`)."""
    causes = check_causes(causes)
    paths = list(paths)
    bundle = read_document(bundle_path, "bundle")
    loaded = collect_runs(paths)
    runs = diagnosis_runs(loaded)
    if not runs:
        raise dg.H.HysteresisFitError("no runs to diagnose")
    base = base_model(bundle)
    fitted = fitted_run_keys(bundle)
    result = dg.diagnose(base, runs, fitted, causes, on_progress)
    out = new_output_dir(out_dir)
    ctx = dg.Context(runs, base, frozenset(fitted), {r.name: dg.noise_floor(r.y) for r in runs})
    plan = next_plan.next_plan(loaded, ctx, result, out, [str(p) for p in paths])
    doc = {"bundle": {"file": str(bundle_path), "sha256": runformat.sha256_file(bundle_path)},
           "causes": {c.id: {"physics": c.physics, "extension": c.extension, "in_compensator": c.in_compensator,
                             "needs": "; or ".join(n.text() for n in c.needs)} for c in dg.CAUSES.values()},
           **result.as_dict(), "next_plan": plan}
    write_json_atomic(out / "diagnosis.json", doc)
    write_document(extend_bundle(bundle, result.findings, result.model), out / "extended_bundle.json")
    before = {s.run: s for s in result.before}
    after = {s.run: s for s in result.after}
    names = [r.name for r in runs]
    bars = plotting.residual_rms_bars(names, [before[n].rms for n in names], [after[n].rms for n in names], [before[n].floor for n in names],
                                      unit=result.unit)
    (out / "residuals.png").write_bytes(plotting.to_png(bars))
    (out / "residual_traces.png").write_bytes(plotting.to_png(residual_figure(runs, base, result)))
    return result, out


#: Residual traces are drawn within this percentile of |residual| (per run kind), times CLIP_MARGIN:
#: a spike (a step's edge, a start-up transient) would otherwise flatten every other trace.
CLIP_PERCENTILE = 99.5
CLIP_MARGIN = 1.5


def residual_figure(runs: list[dg.RunData], base: dg.Model, result: dg.Diagnosis):
    """Residual of each run against its own time (0-1), before (base model) and after
    (extended): one row per run kind, spikes clipped at a robust level with a note."""
    def kind_of(r: dg.RunData) -> str:
        return "rest" if np.ptp(r.x) == 0 else r.kind

    rows = []
    kinds = list(dict.fromkeys(kind_of(r) for r in runs))
    u = units.label(result.unit)
    for kind in kinds:
        rs = [r for r in runs if kind_of(r) == kind]
        res_b = [r.y - base.predict(r) for r in rs]
        res_e = [r.y - result.model.predict(r) for r in rs]
        both = np.abs(np.concatenate(res_b + res_e))
        lim = CLIP_MARGIN * float(np.percentile(both, CLIP_PERCENTILE)) if both.size else 1.0
        lim = lim if lim > 0 else max(float(both.max()) if both.size else 1.0, 1e-12)

        def note(res):
            n, total = sum(int(np.count_nonzero(np.abs(e) > lim)) for e in res), sum(e.size for e in res)
            return f"{n} of {total} samples beyond ±{lim:.3g} {u} clipped ({CLIP_MARGIN:g} x the {CLIP_PERCENTILE:g}th percentile)" if n else ""

        def curves(res):
            return [plotting.Curve(r.t_s / r.t_s[-1] if r.t_s[-1] > 0 else r.t_s, np.clip(e, -lim, lim), r.name) for r, e in zip(rs, res)]

        rows.append(plotting.ResidualRow(f"{kind} ({len(rs)} run{'s' if len(rs) > 1 else ''})", curves(res_b), curves(res_e), lim,
                                         note(res_b), note(res_e)))
    return plotting.residual_traces(rows, unit=result.unit, left_title="base model", right_title="extended by the findings",
                                    xlabel="time / run length", title=f"Residuals of {len(runs)} run{'s' if len(runs) != 1 else ''}: measured - model")


def next_plan_info(out_dir: str | Path) -> dict[str, Any] | None:
    """What ``diagnose`` wrote about the next experiment (``diagnosis.json``'s ``next_plan``)."""
    import json

    path = Path(out_dir) / "diagnosis.json"
    return json.loads(path.read_text(encoding="utf-8")).get("next_plan") if path.is_file() else None


def format_summary(result: dg.Diagnosis, plan: dict[str, Any] | None = None) -> str:
    """The diagnosis as a technician reads it (figures in the runs' unit, N or µm): the
    findings, what was tested and what could not be and why, and the next experiment."""
    u, k = units.label(result.unit), units.key(result.unit)
    lines = [f"Diagnosis: {result.summary}", ""]
    lines.append(f"Residual over all runs: {result.residual_rms:.3g} {u} RMS; sensor noise floor {result.noise_floor:.3g} {u} RMS.")
    bf = result.base_fit
    if bf:
        verdict = "poor" if bf["poor"] else "fair"
        lines.append(f"Base fit ({verdict}): {bf[f'rms_{k}']:.3g} {u} RMS on the slow sweeps it was fitted on ({', '.join(bf['runs'])}), "
                     f"{bf['ratio']:.1f} x the noise floor; largest in {bf['worst_run']} at {bf['worst_at_s']:.4g} s."
                     + (" Every cause the runs allow was still tried against it." if bf["poor"] else ""))
    if result.findings:
        lines.append("")
        lines.append(f"{'cause':<28} {'held-out RMS: base -> extended':>32} {'gain':>7}  parameters")
        for f in result.findings:
            params = ", ".join(f"{k} = {v:.4g}" for k, v in f.parameters.items())
            lines.append(f"{f.cause:<28} {f.baseline_rms:>14.3g} {u} -> {f.extended_rms:.3g} {u} {f.gain_pct:>6.0f} %  {params}")
            lines.append(f"    why: {dg.CAUSES[f.cause].physics}; evidence: {f.evidence}")
            lines.append(f"    judged on {', '.join(f.heldout)} (not used to fit the extension)")
    elif result.tested:
        lines.append(f"None of the {len(result.tested)} causes tried improves the prediction of held-out data beyond the noise: no findings.")
    if result.tested:
        lines.append("")
        lines.append(f"Tested ({len(result.tested)}):")
        for t in result.tested:
            gain = ""
            if "gain_pct" in t:
                params = ", ".join(f"{k_} = {v:.3g}" for k_, v in t["parameters"].items())
                gain = f", held-out gain {t['gain_pct']:.0f} %" + (f" (finding: >= {dg.MIN_GAIN_PCT:.0f} %)" if t["result"] != "found" else "")
                gain += f", {params}" if params else ""
            lines.append(f"    {t['cause']}: {t['result']}{gain}; on {', '.join(t['runs'][:6])}{', ...' if len(t['runs']) > 6 else ''}")
    if result.not_tested:
        lines.append("")
        lines.append(f"Not tested ({len(result.not_tested)}): the runs do not allow it")
        for t in result.not_tested:
            lines.append(f"    {t.cause}: needs {t.needs}")
            lines.append(f"        have: {t.have}")
    if result.unexplained:
        lines.append("")
        lines.append(f"Unexplained ({'no cause tried' if result.not_tested else 'no cause in the catalogue'} accounts for it):")
        for u_ in result.unexplained:
            lines.append(f"    {u_['run']}: {u_[f'rms_{k}']:.3g} {u} RMS = {u_['ratio']:.1f} x the noise floor, largest at {u_['where_s']:.4g} s, "
                         f"dominant frequency {u_['dominant_freq_hz']:.4g} Hz")
    if plan:
        lines.append("")
        if plan.get("file"):
            lines.append(f"Next experiment: {plan['file']} ({len(plan['protocols'])} protocols, {plan['duration_s']:.0f} s) "
                         f"makes testable: {', '.join(plan['serves'])}")
            for g in plan.get("groups", []):
                lines.append(f"    {', '.join(g['protocols'])}: serves {', '.join(g['serves'])}")
            lines.append("    run it with `piezopress characterize --plan` (the file says how), then diagnose both directories")
            if plan.get("refit_for"):
                lines.append(f"    refit the base model with the new runs first (`fit ... --base`): {', '.join(plan['refit_for'])} need it")
        if plan.get("unservable"):
            lines.append(f"No protocol on this rig makes testable: {', '.join(plan['unservable'])}")
    return "\n".join(lines)
