"""``diagnose`` and ``simulate``: runs and a bundle in; predictions, findings and an extended bundle out."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from piezopress import plotting, runformat, units
from piezopress.analysis import diagnosis as dg
from piezopress.analysis import identification
from piezopress.analysis.bundle import (
    Bundle,
    creep_for_compensator,  # noqa: F401 (moved there)
    extend_document,
)
from piezopress.analysis.diagnosis.residuals import unexplained_groups
from piezopress.errors import PiezopressError
from piezopress.pipelines import next_plan
from piezopress.pipelines.bundle import collect_runs, read_bundle, read_document, write_document  # noqa: F401 (read_document: for callers)
from piezopress.pipelines.files import check_output, new_output_dir, utc_now, write_json_atomic, write_output
from piezopress.pipelines.profiles import read_measured


def base_model(bundle: dict[str, Any]) -> dg.Model:
    """The forward model a bundle describes (hysteresis, and creep and mode if present)."""
    return Bundle.from_dict(bundle).forward_model()


def fitted_run_names(bundle: dict[str, Any]) -> list[str]:
    """The runs the bundle's models were fitted on."""
    return sorted({r["name"] for sec in ("hysteresis", "creep", "shaper") for r in bundle.get(sec, {}).get("runs", [])})


@dataclass(frozen=True)
class JudgedRows:
    """The rows a command judges, given by the user (``--skip-s``/``--rows``) instead of the
    bundle's record: ``skip_s`` seconds, or rows ``start`` to ``stop - 1``, of every run."""

    skip_s: float | None = None
    rows: tuple[int | None, int | None] | None = None

    @property
    def given(self) -> bool:
        return self.skip_s is not None or self.rows is not None

    def of(self, run: runformat.Run) -> tuple[int, int]:
        """``(judged_from, stop)`` for the run, checked as ``fit`` checks them (the error names
        the value and the run's length)."""
        from piezopress.analysis.identification import fitted_rows

        stops, skips = fitted_rows([run], self.skip_s, self.rows)
        return (skips[0] if skips else None) or 0, stops[0]


def run_data(
    run: runformat.Run, bundle: Bundle | None = None, sha256: str | None = None, judged: JudgedRows | None = None
) -> dg.RunData:
    """The run as the diagnosis sees it; with the bundle it was fitted on, judged from the row
    ``fit`` judged it from (the start before it, a rest of unknown state, is not misfit).
    ``judged`` (the user's ``--skip-s``/``--rows``) overrides the bundle's record: rows from its
    stop on are dropped, rows before its start carry the state and are not judged; the bundle's
    held-out rows are kept where they lie inside. ``sha256``: the run file's, when the caller has it already."""
    start, held = 0, None
    if bundle is not None:
        if sha256 is None and run.path is not None:
            sha256 = runformat.sha256_file(run.path)
        rows = bundle.judged_rows(sha256, run.name)
        if rows is not None:
            start, held = rows[0], (rows[1], rows[2])
    stop = run.t_s.size
    if judged is not None and judged.given:
        start, stop = judged.of(run)
        if held is not None:
            held = (max(held[0], start), min(held[1], stop))
            held = held if held[1] - held[0] >= 2 else None
    monitor = run.column("monitor_v")
    return dg.RunData(
        run.name,
        run.kind,
        run.t_s[:stop],
        run.command_v[:stop],
        run.output[:stop],
        run.sample_rate_hz,
        None if monitor is None else monitor[:stop],
        dict(run.meta),
        judged_from=start,
        held_out=held,
    )


def simulate_file(
    bundle_path: str | Path,
    run_path: str | Path,
    out: str | Path,
    *,
    replace: bool = False,
    judged: JudgedRows | None = None,
) -> tuple[runformat.Run, Path | None]:
    """The bundle's model on a run's measured drive, written beside the measurement
    (columns ``predicted`` and ``residual`` added, in the run's output unit); returns the
    run and where a replaced file was kept. The rows judged (``simulated_with.judged_rows``
    in the metadata): the user's ``judged`` when given, else the bundle's record of the run."""
    check_output(out, replace=replace)
    bundle = read_bundle(bundle_path)
    run = read_measured(run_path)
    bundle.check_unit(run.output_unit, f"{run_path} ({run.output_column})")
    pred = bundle.forward_model().predict(run_data(run))
    cols = {c: run.data[c].to_numpy() for c in run.data.columns}
    cols["predicted"] = pred
    cols["residual"] = run.output - pred
    rows = bundle.judged_rows(runformat.sha256_file(run.path) if run.path is not None else None, run.name)
    if judged is not None and judged.given:
        start, stop = judged.of(run)
        held = None if rows is None else (max(rows[1], start), min(rows[2], stop))
        rows = (start, held[0] if held and held[1] - held[0] >= 2 else stop, stop)
    meta = {**run.meta, "simulated_with": {"bundle": str(bundle_path), "sha256": runformat.sha256_file(bundle_path)}}
    if rows is not None:
        meta["simulated_with"]["judged_rows"] = {"fitted_from": rows[0], "held_out_from": rows[1], "stop": rows[2]}
    sim = runformat.make_run(cols, meta)
    previous = write_output(out, lambda tmp: runformat.write_run(sim, tmp), replace=replace)
    return sim, previous


@dataclass(frozen=True)
class DriveSimulation:
    """``simulate`` on a drive file: the model's output for the drive, on the reference's zero."""

    frame: Any  # pandas DataFrame written to the output
    unit: str
    rest: float  # the model's rest output (the zero of references and of ``predicted``, unless absolute)
    absolute: bool  # predicted (and the reference) on the record's own scale
    error_rms: float | None  # against the file's reference column, when it has one
    error_max: float | None
    holdout_rms: float | None  # the bundle's own held-out error, for comparison


def simulate_drive_file(
    bundle_path: str | Path, drive_path: str | Path, out: str | Path, *, replace: bool = False
) -> tuple[DriveSimulation, Path | None]:
    """The bundle's model on a drive file (``compensate``'s CSV, or any CSV with ``t_s`` and
    ``command_v``), written as CSV: the drive, the predicted output above the model's rest
    (``predicted_n``/``predicted_um``: the zero ``compensate``'s references use) and, when the
    file has the reference column, ``error_...`` = predicted - reference."""
    import pandas as pd

    from piezopress.errors import ImportFormatError
    from piezopress.pipelines.compensate import read_reference, reference_column

    check_output(out, replace=replace)
    bundle = read_bundle(bundle_path)
    drive_path = Path(drive_path)
    t, x, fs = read_reference(drive_path, "command_v")
    ref_col = reference_column(bundle)
    k = units.key(bundle.unit)
    try:
        header = list(pd.read_csv(drive_path, nrows=0).columns)
    except Exception:  # read_reference read it: cannot happen
        header = []
    ref = read_reference(drive_path, ref_col)[1] if ref_col in header else None
    for other in units.LABELS:
        col = f"reference_{units.key(other)}"
        if col in header and col != ref_col:
            raise ImportFormatError(
                f"{drive_path}: column {col} is a {units.quantity(other)} reference; {bundle_path} models "
                f"{units.quantity(bundle.unit)} (expected {ref_col})"
            )
    model = bundle.forward_model()
    rest = float(bundle.hysteresis.y0)
    absolute = f"rest_{k}" in header  # compensate --zero absolute wrote the reference on the record's scale
    pred = model.predict(dg.RunData(drive_path.stem, "custom", t, x, np.zeros_like(x), fs)) - (
        0.0 if absolute else rest
    )
    cols: dict[str, np.ndarray] = {"t_s": t, "command_v": x}
    err_rms = err_max = None
    if ref is not None:
        cols[ref_col] = ref
    cols[f"predicted_{k}"] = pred
    if absolute:
        cols[f"rest_{k}"] = np.full(t.size, rest)
    if ref is not None:
        err = pred - ref
        cols[f"error_{k}"] = err
        err_rms, err_max = float(np.sqrt(np.mean(err**2))), float(np.max(np.abs(err)))
    frame = pd.DataFrame(cols)
    fit = (bundle.to_dict().get("hysteresis") or {}).get("fit") or {}
    held = fit.get(f"holdout_rms_{k}")
    previous = write_output(out, lambda tmp: frame.to_csv(tmp, index=False, float_format="%.9g"), replace=replace)
    sim = DriveSimulation(
        frame, bundle.unit, rest, absolute, err_rms, err_max, float(held) if isinstance(held, (int, float)) else None
    )
    return sim, previous


def extend_bundle(bundle: dict[str, Any], findings: list[dg.Finding], model: dg.Model | None = None) -> dict[str, Any]:
    """The bundle document with every finding's extension recorded (:func:`piezopress.analysis.bundle.extend_document`;
    :meth:`Bundle.extended` is the same, checked)."""
    return extend_document(bundle, findings, model)


def fitted_run_keys(bundle: dict[str, Any]) -> list[str]:
    """The runs the bundle's models were fitted on, by file (sha256; the name where the bundle
    recorded no file): two runs may share a name, never a file."""
    return sorted(
        {
            r.get("sha256") or r["name"]
            for sec in ("hysteresis", "creep", "shaper")
            for r in bundle.get(sec, {}).get("runs", [])
        }
    )


def diagnosis_runs(
    loaded: list[runformat.Run], bundle: Bundle | None = None, judged: JudgedRows | None = None
) -> list[dg.RunData]:
    """The runs as the diagnosis sees them, each keyed by its file's sha256; a name that
    repeats (two imports of one source, or two directories) is told apart by its file.
    ``judged``: the user's rows (:class:`JudgedRows`), else the bundle's record."""
    keys = [runformat.sha256_file(r.path) if r.path is not None else "" for r in loaded]  # each file read once
    runs = [run_data(r, bundle, k or None, judged) for r, k in zip(loaded, keys)]
    count: dict[str, int] = {}
    for r in runs:
        count[r.name] = count.get(r.name, 0) + 1
    out = []
    for r, src, key in zip(runs, loaded, keys):
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
        raise UnknownCauseError(
            f"cause {', '.join(map(repr, unknown))} is not in the catalogue; expected one of {', '.join(dg.CAUSES)}"
        )
    return causes


def diagnose(
    paths: Iterable[str | Path],
    bundle_path: str | Path,
    out_dir: str | Path,
    causes: Iterable[str] | None = None,
    on_progress: Callable[[dg.CauseProgress], None] | None = None,
    judged: JudgedRows | None = None,
) -> tuple[dg.Diagnosis, Path]:
    """Diagnose the runs (files or run directories, several at once) against the bundle;
    write ``diagnosis.json``, ``extended_bundle.json``, the residual figures and, when some
    causes could not be tested, ``next-plan.toml``: the experiment that would test them.
    ``on_progress`` hears of every cause tried (:class:`~piezopress.analysis.diagnosis.CauseProgress`);
    ``judged``: the rows judged in every run (``--skip-s``/``--rows``) instead of the bundle's record."""
    causes = check_causes(causes)
    paths = list(paths)
    checked = read_bundle(bundle_path)
    bundle = checked.to_dict()
    loaded = collect_runs(paths)
    below = identification.below_rest_runs(loaded)  # the base model is judged on the range it was fitted on
    loaded = [r for r in loaded if all(r is not b for b in below)]
    for r in loaded:  # one unit: a displacement run is not judged by a force model
        checked.check_unit(r.output_unit, f"{r.path} ({r.output_column})")
    runs = diagnosis_runs(loaded, checked, judged)
    if not runs:
        raise dg.H.HysteresisFitError("no runs to diagnose")
    short = [f"{r.name} ({r.y.size} samples)" for r in runs if r.y.size < MIN_RUN_SAMPLES]
    if short:
        raise PiezopressError(
            f"run {', '.join(short[:5])}{' ...' if len(short) > 5 else ''} too short to diagnose; expected at least "
            f"{MIN_RUN_SAMPLES} samples per run (a noise floor and a residual need them): leave such runs out"
        )
    base = checked.forward_model()
    fitted = fitted_run_keys(bundle)
    out = new_output_dir(out_dir)  # refused (or created) before the diagnosis's minutes of work
    mark_status(out, RUNNING, "started; a diagnosis that stays 'running' did not finish (killed or crashed)")
    try:
        result = _diagnose_into(
            out, paths, bundle_path, checked, loaded, runs, base, fitted, causes, on_progress, left_out=below
        )
    except KeyboardInterrupt as exc:
        mark_status(out, INTERRUPTED, str(exc) or "interrupted by the user (Ctrl-C)")
        raise
    except Exception as exc:
        mark_status(out, FAILED, f"{type(exc).__name__}: {exc}")
        raise
    mark_status(out, COMPLETE, "")
    return result, out


#: Fewer samples than this in a run: refused by ``diagnose`` (no noise floor, no residual to read).
MIN_RUN_SAMPLES = 50

#: ``status.json`` in a diagnosis directory: written first as ``running``, last as ``complete``
#: (or ``interrupted``/``failed`` with the reason), so a directory left by a killed diagnosis is
#: never taken for a finished one (``report --diagnosis`` says it is incomplete).
STATUS_FILE = "status.json"
RUNNING, COMPLETE, INTERRUPTED, FAILED = "running", "complete", "interrupted", "failed"


def mark_status(out: Path, status: str, reason: str) -> None:
    write_json_atomic(Path(out) / STATUS_FILE, {"status": status, "reason": reason, "time_utc": utc_now()})


def read_status(out: str | Path) -> tuple[str, str]:
    """``(status, reason)`` of a diagnosis directory; one written before the status file existed,
    with its diagnosis.json, counts as complete."""
    import json

    path = Path(out) / STATUS_FILE
    if not path.is_file():
        return (COMPLETE, "") if (Path(out) / "diagnosis.json").is_file() else (RUNNING, "no status.json")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        return str(doc.get("status", RUNNING)), str(doc.get("reason", ""))
    except (ValueError, UnicodeDecodeError, AttributeError):
        return RUNNING, f"{path} unreadable"


def _diagnose_into(
    out: Path,
    paths: list,
    bundle_path: str | Path,
    checked: Bundle,
    loaded: list[runformat.Run],
    runs: list[dg.RunData],
    base: dg.Model,
    fitted: list[str],
    causes: list[str] | None,
    on_progress: Callable[[dg.CauseProgress], None] | None,
    left_out: list[runformat.Run] = (),
) -> dg.Diagnosis:
    result = dg.diagnose(base, runs, fitted, causes, on_progress)
    if left_out:
        result = replace(
            result,
            summary=result.summary.rstrip(".")  # the analysis's summary is one sentence without its stop
            + f". Left out: {', '.join(r.name for r in left_out)} (below the rest drive the other sweeps keep to: "
            "measured for the compensator; the base model is judged on the range it was fitted on).",
        )
    ctx = dg.Context(runs, base, frozenset(fitted), {r.name: dg.noise_floor(r.y) for r in runs})
    plan = next_plan.next_plan(loaded, ctx, result, out, [str(p) for p in paths])
    from piezopress.pipelines.sources import group_by_rig

    doc = {
        "bundle": {"file": str(bundle_path), "sha256": runformat.sha256_file(bundle_path)},
        "rigs": [ident.as_dict() for ident in group_by_rig(loaded)],
        "judged_rows": {
            r.name: {"judged_from": r.judged_from, "stop": int(r.y.size), "held_out": list(r.held_out or []) or None}
            for r in runs
        },
        "causes": {
            c.id: {
                "physics": c.physics,
                "extension": c.extension,
                "in_compensator": c.in_compensator,
                "needs": "; or ".join(n.text() for n in c.needs),
            }
            for c in dg.CAUSES.values()
        },
        **result.as_dict(),
        "next_plan": plan,
    }
    write_json_atomic(out / "diagnosis.json", doc, null_nonfinite=True)  # strict JSON: an unmeasured figure is null
    from piezopress.pipelines.adopt import unverified_note

    extended = checked.extended(result.findings, result.model).to_dict()
    extended["gain_on_press"] = unverified_note()  # until diagnose --gain (or compare) measures it on the press
    write_document(extended, out / "extended_bundle.json")
    before = {s.run: s for s in result.before}
    after = {s.run: s for s in result.after}
    names = [r.name for r in runs]
    bars = plotting.residual_rms_bars(
        names,
        [before[n].rms for n in names],
        [after[n].rms for n in names],
        [before[n].floor for n in names],
        unit=result.unit,
    )
    (out / "residuals.png").write_bytes(plotting.to_png(bars))
    (out / "residual_traces.png").write_bytes(plotting.to_png(residual_figure(runs, base, result)))
    return result


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

        def note(res, lim=lim):
            n, total = sum(int(np.count_nonzero(np.abs(e) > lim)) for e in res), sum(e.size for e in res)
            return (
                f"{n} of {total} samples beyond ±{lim:.3g} {u} clipped ({CLIP_MARGIN:g} x the {CLIP_PERCENTILE:g}th "
                "percentile)"
                if n
                else ""
            )

        def curves(res, lim=lim, rs=rs):
            return [
                plotting.Curve(r.t_s / r.t_s[-1] if r.t_s[-1] > 0 else r.t_s, np.clip(e, -lim, lim), r.name)
                for r, e in zip(rs, res)
            ]

        rows.append(
            plotting.ResidualRow(
                f"{kind} ({len(rs)} run{'s' if len(rs) > 1 else ''})",
                curves(res_b),
                curves(res_e),
                lim,
                note(res_b),
                note(res_e),
            )
        )
    return plotting.residual_traces(
        rows,
        unit=result.unit,
        left_title="base model",
        right_title="extended by the findings",
        xlabel="time / run length",
        title=f"Residuals of {len(runs)} run{'s' if len(runs) != 1 else ''}: measured - model",
    )


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
    lines.append(
        f"Residual over all runs: {result.residual_rms:.3g} {u} RMS; sensor noise floor {result.noise_floor:.3g} {u} "
        "RMS."
    )
    bf = result.base_fit
    if bf:
        verdict = "poor" if bf["poor"] else "fair"
        lines.append(
            f"Base fit ({verdict}): {bf[f'rms_{k}']:.3g} {u} RMS on the slow sweeps it was fitted on "
            f"({', '.join(bf['runs'])}"
            + (f"; {bf[f'holdout_rms_{k}']:.3g} {u} on the rows its fit held out" if f"holdout_rms_{k}" in bf else "")
            + (", the start the fit skipped not counted" if bf.get("judged_from_row") else "")
            + "), "
            f"{bf['ratio']:.1f} x the noise floor; largest in {bf['worst_run']} at {bf['worst_at_s']:.4g} s."
            + (" Every cause the runs allow was still tried against it." if bf["poor"] else "")
        )
    if result.findings:
        lines.append("")
        lines.append(f"{'cause':<28} {'held-out RMS: base -> extended':>32} {'gain':>7}  parameters")
        for f in result.findings:
            params = ", ".join(f"{k} = {v:.4g}" for k, v in f.parameters.items())
            lines.append(
                f"{f.cause:<28} {f.baseline_rms:>14.3g} {u} -> {f.extended_rms:.3g} {u} {f.gain_pct:>6.0f} %  {params}"
            )
            lines.append(f"    why: {dg.CAUSES[f.cause].physics}; evidence: {f.evidence}")
            lines.append(f"    judged on {', '.join(f.heldout)} (not used to fit the extension); {f.strength_text()}")
        lines.append("")
        lines.append(
            "The extended bundle predicts these runs better; whether it compensates better is "
            "unverified on the press until measured there (diagnose --gain --rig YOUR-PRESS.toml, or compare)."
        )
    elif result.tested:
        lines.append(
            f"None of the {len(result.tested)} causes tried improves the prediction of held-out data beyond the "
            "noise: no findings."
        )
    if result.tested:
        lines.append("")
        lines.append(f"Tested ({len(result.tested)}):")
        for t in result.tested:
            gain = ""
            if "gain_pct" in t:
                params = ", ".join(f"{k_} = {v:.3g}" for k_, v in t["parameters"].items())
                gain = f", held-out gain {t['gain_pct']:.0f} %" + (
                    f" (finding: >= {dg.MIN_GAIN_PCT:.0f} %)" if t["result"] != "found" else ""
                )
                gain += f", {params}" if params else ""
            lines.append(
                f"    {t['cause']}: {t['result']}{gain}; on "
                f"{', '.join(t['runs'][:6])}{', ...' if len(t['runs']) > 6 else ''}"
            )
            if t.get("untried"):
                lines.append(f"        not tried: {t['untried']}")
    # the causes tested only where they show weakly (not found there), then those not tested: each
    # with the runs it needs (its first way, for the former) and what the runs offer
    for heading, causes in (
        ("Not ruled out ({n}): tested only on runs that show it weakly", result.partly_tested),
        ("Not tested ({n}): the runs or the base model do not allow it", result.not_tested),
    ):
        if causes:
            lines += ["", heading.format(n=len(causes))]
            for t in causes:
                lines += [f"    {t.cause}: " + (f"judged best on {t.best}" if t.partly else f"needs {t.needs}")]
                lines += [f"        have: {t.have}"]
    if result.signatures:
        lines.append("")
        lines.append("Structure no cause in the catalogue explains, by its signature:")
        for sig in result.signatures:
            lines.append(f"    {sig['text']}")
    if result.unexplained:
        lines.append("")
        lines.append(
            f"Unexplained ({'no cause tried' if result.not_tested else 'no cause in the catalogue'} accounts for it):"
        )
        by_run = {u_["run"]: u_ for u_ in result.unexplained}
        for runs, said in unexplained_groups(result.unexplained):  # runs of one signature together
            lines.append(f"    it {said}:")
            for name in runs:
                u_ = by_run[name]
                lines.append(
                    f"        {name}: {u_[f'rms_{k}']:.3g} {u} RMS = {u_['ratio']:.1f} x the noise floor, largest at "
                    f"{u_['where_s']:.4g} s, "
                    + (f"dominant frequency {u_['dominant_freq_hz']:.4g} Hz" if u_["dominant_freq_hz"] else "no tone")
                )
    if plan:
        lines.append("")
        if plan.get("file"):
            does = ([f"makes testable: {', '.join(plan['serves'])}"] if plan.get("serves") else []) + [
                f"tells {t}" for t in plan.get("tells_apart", [])
            ]
            lines.append(
                f"Next experiment: {plan['file']} ({len(plan['protocols'])} protocols, {plan['duration_s']:.0f} s) "
                + "; ".join(does)
            )
            for g in plan.get("groups", []):
                what = ([f"serves {', '.join(g['serves'])}"] if g.get("serves") else []) + [
                    f"tells {t}" for t in g.get("tells", [])
                ]
                lines.append(f"    {', '.join(g['protocols'])}: {'; '.join(what)}")
            lines.append(
                "    run it with `piezopress characterize --plan` (the file says how), then diagnose both directories"
            )
            if plan.get("refit_for"):
                lines.append(
                    "    refit the base model with the new runs first (`fit ... --base`): "
                    f"{', '.join(plan['refit_for'])} need it"
                )
        if plan.get("unservable"):
            lines.append(f"No protocol on this rig makes testable: {', '.join(plan['unservable'])}")
    return "\n".join(lines)
