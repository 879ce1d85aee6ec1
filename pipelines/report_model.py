"""The report's model-quality text: each model's error on its fitting and held-out data,
the choices and why, and the diagnosis (what the model gets wrong, and the gain on the press)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pandas as pd

from piezopress import units
from piezopress.analysis import diagnosis as dg
from piezopress.analysis.diagnosis.residuals import unexplained_groups
from piezopress.pipelines.report_doc import Block, Bullets, FigureBlock, Heading, Para, Table
from piezopress.pipelines.report_tables import _finite, _num

# --------------------------------------------------------------------------- model quality


def _pct(part: float, whole: float) -> float:
    return 100.0 * part / whole if _finite(part) and _finite(whole) and whole else math.nan


def _unit_key(d: dict[str, Any], prefix: str) -> tuple[float, str]:
    for k, v in d.items():
        if k.startswith(prefix):
            return (float(v) if v is not None else math.nan), k[len(prefix) :]
    return math.nan, "n"


def _rest_and_reach(bundle: dict[str, Any]) -> str:
    """The zero of references and the output the drive range reaches ('' : the bundle cannot say)."""
    from piezopress.analysis.bundle import Bundle
    from piezopress.errors import PiezopressError

    try:
        b = Bundle.from_dict(bundle)
        lo, hi = b.reach()
    except (PiezopressError, KeyError, TypeError, ValueError):
        return ""
    u, rest, s = units.label(b.unit), float(b.hysteresis.y0), b.settings
    zero = (
        "references are read on the record's own scale (the bundle was fitted on imported runs)"
        if b.from_elsewhere
        else "references are read above it"
    )
    return (
        f"Rest and reach: the model's rest output is {rest:.4g} {u}; {zero}. The drive range {s.drive_min_v:g} to "
        f"{s.drive_max_v:g} V reaches {rest + lo:.4g} to {rest + hi:.4g} {u} ({lo:.4g} to {hi:.4g} {u} above the rest)."
    )


def _model_quality(bundle: dict[str, Any], bundle_path: Path, missing: list[str]) -> list[Block]:
    blocks: list[Block] = [
        Heading("Model quality"),
        Para(
            f"From the bundle `{bundle_path}`: each model's error on the data it was "
            "fitted on and on data held out of the fit."
        ),
    ]
    h = bundle["hysteresis"]
    fit, model = h.get("fit", {}), h.get("model", {})
    code = model.get("output_unit")
    train, key = _unit_key(fit, "train_rms_")
    held, _ = _unit_key(fit, "holdout_rms_")
    rng, _ = _unit_key(fit, "output_range_")
    unit = units.label(code or key)
    runs = ", ".join(r.get("name", "?") for r in h.get("runs", []))
    rest_reach = _rest_and_reach(bundle)  # a forward run of the model: once
    blocks += [Para(rest_reach)] if rest_reach else []
    plane = model.get("preisach_plane") or {}
    elements = model.get("duhem_elements") or {}
    family = model.get("family", "modified_pi")
    title = {
        "modified_pi": "modified Prandtl-Ishlinskii",
        "pi_preisach_plane": "Prandtl-Ishlinskii + Preisach plane",
        "pi_duhem": "Prandtl-Ishlinskii + Duhem (Bouc-Wen) elements",
    }
    cells = (
        f", a Preisach plane of {len(plane.get('weights', []))} KP hysterons"
        if plane
        else f", {len(elements.get('weights', []))} Duhem (Bouc-Wen, exponent 1) elements"
        if elements
        else ""
    )
    blocks += [
        Heading(f"Hysteresis ({title.get(family, family)})", 3),
        Para(
            f"Model `{fit.get('chosen', '?')}`: {len(model.get('play_thresholds', []))} play operators, "
            f"{len(model.get('dead_zone_thresholds', []))} dead zones{cells}; fitted on {runs or 'no run named'}, "
            "the last "
            f"{100 * float(fit.get('holdout_fraction', math.nan)):g} % of each run held out"
            + ("; creep removed from the sweeps first." if h.get("creep_removed") else ".")
        ),
        Table(
            ("data", f"RMS error ({unit})", "% of output range"),
            (
                ("fitting (train)", _num(train, 3), _num(_pct(train, rng), 3)),
                ("held out", _num(held, 3), _num(_pct(held, rng), 3)),
            ),
            ("l", "r", "r"),
        ),
        Para(f"Output range {_num(rng, 1)} {unit}. Why this model: {fit.get('reason', 'not recorded')}."),
    ]
    if fit.get("family_reason"):
        blocks.append(Para(f"Model family: {fit['family_reason']}."))
    if fit.get("structure_given"):  # fit --structure: the structure was not chosen by the search
        blocks.append(Para(f"Structure: {fit['structure_given']} (fit --structure)."))
    if fit.get("base_structure"):  # a `fit --base` bundle whose loop the thesis's plays could not draw
        blocks.append(Para(f"Not the thesis's structure: {fit['base_structure']}."))
    if fit.get("below_rest"):
        blocks.append(Para(f"Below the rest drive: {fit['below_rest']}."))
    if "creep" in bundle:
        c = bundle["creep"]
        cf = c.get("fit", {})
        chosen = cf.get("chosen_form")
        rows = tuple(
            (
                str(k.get("form")),
                _num(k.get("train_rms"), 3),
                _num(k.get("holdout_rms"), 3),
                "yes" if k.get("form") == chosen else "",
            )
            for k in cf.get("candidates", [])
        )
        blocks += [
            Heading("Creep", 3),
            Para(
                f"Fitted on {', '.join(r.get('name', '?') for r in c.get('runs', []))}, the end "
                f"({100 * float(cf.get('holdout_fraction', math.nan)):g} %) of the hold held out."
            ),
            Table(("form", f"train RMS ({unit})", f"held-out RMS ({unit})", "chosen"), rows, ("l", "r", "r", "l")),
            Para(f"Chosen: `{chosen}`. Why: {cf.get('reason', 'not recorded')}."),
        ]
    else:
        missing.append(
            "The bundle has no creep section: the creep model's quality is missing (run `piezopress fit` with a creep "
            "run)."
        )
    if "shaper" in bundle:
        s = bundle["shaper"]
        mode, sh, choice = s.get("mode", {}), s.get("shaper", {}), s.get("choice", {})
        wn, zeta = float(mode.get("natural_freq_rad_s", math.nan)), float(mode.get("damping", math.nan))
        mfit = mode.get("fit", {})
        resid = ", ".join(
            f"{_num(r, 3)} {unit} ({_num(p, 2)} % of the step)"
            for r, p in zip(mfit.get("rms_residual", []), mfit.get("residual_pct_of_step", []))
        )
        rows = tuple(
            (
                str(k.get("name")),
                str(k.get("impulses")),
                _num(k.get("delay_ms"), 3),
                _num(k.get("nominal_residual_pct"), 2),
                _num(k.get("worst_residual_pct"), 2),
                "yes" if k.get("name") == sh.get("name") else "",
            )
            for k in choice.get("candidates", [])
        )
        blocks += [
            Heading("Vibration mode and input shaper", 3),
            Para(
                f"Mode identified from {', '.join(r.get('name', '?') for r in s.get('runs', []))} against "
                f"`{mode.get('drive_used', '?')}`: "
                f"wn = {_num(wn, 0)} rad/s ({_num(wn / (2 * math.pi), 1)} Hz), damping {_num(zeta, 4)}; "
                f"fit residual (RMS) {resid or 'not recorded'}." + _antiresonance_text(mode)
            ),
            Table(
                (
                    "shaper",
                    "impulses",
                    "delay (ms)",
                    "residual at the mode (%)",
                    "worst residual, wn +/-15 %, zeta +/-50 % (%)",
                    "chosen",
                ),
                rows,
                ("l", "r", "r", "r", "r", "l"),
            ),
            Para(
                f"Chosen: `{sh.get('name', '?')}` ({len(sh.get('times_s', []))} impulses, delay "
                f"{_num(sh.get('delay_ms'), 3)} ms, "
                f"designed at {_num(choice.get('designed_at_hz'), 0)} Hz). Why: {choice.get('reason', 'not recorded')}."
            ),
        ]
        t68 = s.get("thesis_table_6_8")
        if t68:
            blocks.append(
                Para(
                    f"The thesis's printed Table 6.8 shaper would leave {_num(100 * t68.get('printed', math.nan), 1)} "
                    "% residual "
                    f"vibration on this mode (with its amplitudes reversed, as ZV^4 gives them: "
                    f"{_num(100 * t68.get('reversed_amplitudes', math.nan), 1)} %; at whole damped periods: "
                    f"{_num(100 * t68.get('whole_period_spacing', math.nan), 1)} %; a correct ZV^4: "
                    f"{_num(100 * t68.get('correct_zv4', math.nan), 2)} %)."
                )
            )
    else:
        missing.append(
            "The bundle has no shaper section: the mode and shaper quality are missing (run `piezopress fit` with a "
            "low-amplitude step)."
        )
    comp = bundle.get("compensation")
    if comp:
        # max_rate_n_per_s or max_rate_um_per_s (null: no limit); a bundle without a unit: the first max_rate_ key
        rate = comp.get(f"max_rate_{units.key(code)}_per_s") if code else units.keyed(comp, "max_rate_")
        rate_text = f"rate limit {_num(float(rate) / 1e3, 1)} {unit}/ms" if rate else "no rate limit"
        blocks.append(
            Para(
                f"Compensation settings: drive {_num(comp.get('drive_min_v'), 0)} to "
                f"{_num(comp.get('drive_max_v'), 0)} V, "
                f"{rate_text}, lead {_num(1e3 * float(comp.get('lead_s', math.nan)), 4)} ms"
                + (
                    f" (of which {_num(1e3 * float(comp['chain_lead_s']), 4)} ms the drive chain identified with "
                    "the mode: the reading's lag is led too)"
                    if comp.get("chain_lead_s")
                    else ""
                )
                + (
                    f", and {_num(float(comp['chain_lead_samples']), 2)} samples of the reference's rate: the "
                    "chain's own sampling delay (a converter's hold and filter), which lags by samples, not seconds."
                    if comp.get("chain_lead_samples")
                    else "."
                )
            )
        )
    return blocks


# --------------------------------------------------------------------------- building


def _gain_blocks(csv_path: Path, missing: list[str]) -> list[Block]:
    """The gain on the press (``compensated_gain.csv``, from ``diagnose --gain`` or the
    bench): compensated performance with the base bundle against the extended one."""
    if not csv_path.is_file():
        return []
    from piezopress.pipelines import gain

    try:
        df = gain.read_csv(csv_path)
    except (pd.errors.ParserError, ValueError, KeyError) as exc:
        missing.append(f"{csv_path}: unreadable ({exc}); the compensated-gain table is missing.")
        return []
    blocks: list[Block] = [
        Heading("The simulator's gain: compensated performance on the virtual rig, base bundle against extended", 3),
        Para(
            "The simulator's, not the press's: each row validated on the virtual rig with the effect on (lower is "
            "better): the base bundle, the "
            "extended one, the base pipeline without the effect (clean), and the row's noise (its range over "
            "repeated passes with other noise seeds). * marks the rows the extension is for."
        ),
    ]
    for cause, g in df.groupby("cause", sort=False):
        blocks.append(Table(gain.HEADER, tuple(gain.table_lines(g)), ("l", "l", "l", "r", "r", "r", "r", "r", "l")))
        blocks.append(
            Para(
                f"{cause or 'The runs rig'}: extensions applied {g['applied'].iloc[0] or 'none'}; verdict: "
                f"{g['why'].iloc[0]}."
            )
        )
    return blocks


def _diagnosis_blocks(path: str | Path, missing: list[str], runs: list | None = None) -> list[Block]:
    """The diagnosis section: its summary, the findings, what is unexplained, the residuals
    (refused when its runs came from another press than ``runs``, unless --allow-mixed-rigs)."""
    import json

    path = Path(path)
    doc_path = path / "diagnosis.json"
    from piezopress.pipelines.diagnose import COMPLETE, read_status

    status, reason = read_status(path)
    if status != COMPLETE:
        missing.append(
            f"{path}: the diagnosis did not finish ({status}{': ' + reason if reason else ''}); the diagnosis section "
            "is missing (run `piezopress diagnose` again into a new directory)."
        )
        return []
    if doc_path.is_file() and runs:
        from piezopress.pipelines.sources import check_same_press

        try:
            other = json.loads(doc_path.read_text(encoding="utf-8")).get("rigs")
        except (ValueError, UnicodeDecodeError):
            other = None
        check_same_press(runs, other, f"the diagnosis {path}")
    if not doc_path.is_file():
        missing.append(f"{path}: no diagnosis.json; the diagnosis section is missing (run `piezopress diagnose`).")
        return []
    import json

    try:
        d = json.loads(doc_path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        missing.append(f"{doc_path}: not valid JSON ({exc.msg}); the diagnosis section is missing.")
        return []
    code = d.get("output_unit", units.FORCE)  # diagnoses written before the unit was carried are in N
    k, un = units.key(code), units.label(code)
    nan = float("nan")
    blocks: list[Block] = [
        Heading("Diagnosis: what the model gets wrong"),
        Para(d.get("summary", "")),
        Para(
            f"Residual over all runs {d.get(f'residual_rms_{k}', nan):.3g} {un} RMS; "
            f"sensor noise floor {d.get(f'noise_floor_{k}', nan):.3g} {un} RMS. Gains are measured on runs or "
            "segments not used to fit the extension."
        ),
    ]
    findings = d.get("findings", [])
    if findings:
        # whether the compensator applies an extension: the cause catalogue says (one source of truth)
        def compensator(cause: str) -> str:
            c = dg.CAUSES.get(cause)
            return "?" if c is None else "applied" if c.in_compensator else "recorded only"

        rows = tuple(
            (
                f["cause"],
                f"{f[f'baseline_rms_{k}']:.3g}",
                f"{f[f'extended_rms_{k}']:.3g}",
                f"{f['gain_pct']:.0f}",
                ", ".join(f"{k_} = {v:.4g}" if v is not None else f"{k_} = -" for k_, v in f["parameters"].items()),
                compensator(f["cause"]),
                f["evidence"],
            )
            for f in findings
        )
        blocks.append(
            Table(
                (
                    "cause",
                    f"held-out RMS base ({un})",
                    f"extended ({un})",
                    "gain (%)",
                    "parameters",
                    "compensator",
                    "evidence",
                ),
                rows,
                ("l", "r", "r", "r", "l", "l", "l"),
            )
        )
    if d.get("tested"):
        blocks.append(
            Para(
                "Tested: "
                + "; ".join(
                    f"{t['cause']} ({t['result']}"
                    + (f", held-out gain {t['gain_pct']:.0f} %" if t.get("gain_pct") is not None else "")
                    + ")"
                    for t in d["tested"]
                )
                + "."
            )
        )
        untried = [t for t in d["tested"] if t.get("untried")]
        if untried:
            blocks.append(Bullets(tuple(f"Not tried: {t['cause']} as {t['untried']}." for t in untried)))
    if d.get("partly_tested"):
        blocks.append(
            Bullets(
                tuple(
                    f"Not ruled out: {t['cause']}, tested only on runs that show it weakly. Judged best on "
                    f"{t['needs']}; have {t['have']}."
                    for t in d["partly_tested"]
                )
            )
        )
    if d.get("not_tested"):
        blocks.append(
            Bullets(tuple(f"Not tested: {t['cause']}. Needs {t['needs']}; have {t['have']}." for t in d["not_tested"]))
        )
    plan = d.get("next_plan") or {}
    if plan.get("file"):
        blocks.append(
            Para(
                f"Next experiment: {Path(plan['file']).name} ({len(plan.get('protocols', []))} protocols, "
                f"{plan.get('duration_s', math.nan):.0f} s) "
                + "; ".join(
                    ([f"makes testable {', '.join(plan['serves'])}"] if plan.get("serves") else [])
                    + [f"tells {t}" for t in plan.get("tells_apart", [])]
                )
                + "."
            )
        )
    if d.get("signatures"):
        blocks.append(
            Bullets(tuple(f"Signature (no catalogue cause): {sig.get('text', '?')}" for sig in d["signatures"]))
        )
    if d.get("unexplained"):
        groups = unexplained_groups(d["unexplained"])
        grouped = {name for runs, _ in groups for name in runs}
        blocks.append(
            Bullets(
                tuple(f"Unexplained in {', '.join(runs)}: it {text}" for runs, text in groups)
                + tuple(  # a diagnosis written before signatures: each run with its figures
                    f"Unexplained: {u['run']}, {u[f'rms_{k}']:.3g} {un} RMS ({u['ratio']:.1f} x the noise floor), "
                    "largest at "
                    f"{u['where_s']:.4g} s, "
                    + (f"dominant frequency {u['dominant_freq_hz']:.4g} Hz" if u["dominant_freq_hz"] else "no tone")
                    for u in d["unexplained"]
                    if u["run"] not in grouped
                )
            )
        )
    from piezopress.pipelines.report_compare import recommendation_blocks

    blocks += recommendation_blocks(path, missing)
    blocks += _gain_blocks(path / "compensated_gain.csv", missing)
    png = path / "residuals.png"
    if png.is_file():
        blocks.append(
            FigureBlock(
                "diagnosis_residuals",
                "Residuals before and after the diagnosis's extensions",
                "RMS residual of every run, base model and extended, against its noise floor.",
                png.read_bytes(),
            )
        )
    png = path / "residual_traces.png"
    if png.is_file():
        blocks.append(
            FigureBlock(
                "diagnosis_residual_traces",
                "Residual traces per run kind",
                "Measured minus model for every run, on each run's own time axis; spikes clipped as each panel notes.",
                png.read_bytes(),
            )
        )
    return blocks


def _antiresonance_text(mode: dict) -> str:
    """The anti-resonance ``fit`` identified above the mode, said (empty: none)."""
    ar = mode.get("antiresonance")
    if not isinstance(ar, dict):
        return ""
    wz, wn = float(ar.get("natural_freq_rad_s", math.nan)), float(mode.get("natural_freq_rad_s", math.nan))
    return (
        f" An anti-resonance above it: zeros at {_num(wz / (2 * math.pi), 1)} Hz ({_num(wz / wn, 2)} times the "
        f"mode), damping {_num(float(ar.get('damping', math.nan)), 3)}; the forward model and the compensator's lead "
        "include it."
    )
