"""The report's first section: the verdict an engineer signs.

- Each Table 6.13 row's controlled figure (its worst run) against piezopress's target and
  the thesis's controlled range: pass or fail, with the margin in percentage points.
- The warnings that qualify it, each with its runs and count: what the run metadata
  records (the shaper skipped, the drive clipped because the reference cannot be reached,
  any other compensation warning or note, a run not complete) and what the inputs show
  (a model used beyond what it was fitted on, runs validated with another bundle than the
  one given, characterization and validation on different rigs).
- One line of provenance: the rig (its name, file and the digest of its configuration as
  the runs recorded it), the backend, the dates of characterization and validation, the
  software version and the bundle's digest.
"""

from __future__ import annotations

import hashlib
import math
import re
from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from piezopress import runformat, units
from piezopress.pipelines.files import MANIFEST, read_manifest
from piezopress.pipelines.report_doc import Block, Heading, Para, Table
from piezopress.pipelines.report_inputs import _freq, _Source
from piezopress.pipelines.report_tables import _num, _Row613
from piezopress.pipelines.sources import check_one_rig, config_digest

#: piezopress's targets for the controlled Table 6.13 figures (%): the acceptance of issue 4,
#: which tests/test_compensation_acceptance.py asserts on the virtual rig (thesis beside each:
#: static hysteresis 1.55 to 2.99 %, creep 0.63 to 0.96 %, overshoot 0 to 9.28 %, the
#: staircase's relative error up to 12.08 %).
TARGETS_PCT = {
    "max_static_hysteresis": 1.0,
    "creep": 0.3,
    "overshoot": 3.0,
    "tracking_error": 3.0,
}
#: Runs with a target of their own: the 75 N triangle, where the load cell's 0.5 N
#: quantization weighs most, may keep 1.5 % of static hysteresis (issue 4).
RUN_TARGETS_PCT = {("max_static_hysteresis", "tri-75n-0.1hz"): 1.5}


def target_pct(key: str, run: str) -> float:
    """The target (%) of Table 6.13 figure ``key`` on run ``run``."""
    return RUN_TARGETS_PCT.get((key, run), TARGETS_PCT[key])


#: A reference above the hysteresis model's fitted output range by more than this share of
#: the range uses the model beyond its data (extrapolated).
EXTRAPOLATION_TOLERANCE = 0.01
#: Digests are printed to this many hex characters.
DIGEST_CHARS = 16


@dataclass(frozen=True)
class VerdictRow:
    key: str
    quantity: str
    value: float
    worst_run: str
    target: float
    thesis_ctrl: tuple[float, float]

    @property
    def margin(self) -> float:
        """Target minus the figure (percentage points): > 0 passes."""
        return self.target - self.value

    @property
    def passed(self) -> bool | None:
        return None if not math.isfinite(self.value) else self.value <= self.target


@dataclass(frozen=True)
class Warning_:
    """One kind of warning: what, the runs it concerns (with a detail each), and a count."""

    what: str
    runs: tuple[str, ...]
    count: int
    unit: str = "runs"
    detail: str = ""


def verdict_rows(rows: list[_Row613]) -> list[VerdictRow]:
    out = []
    for r in rows:
        t = r.test
        # the run closest to (or furthest past) its own target
        worst = min(r.ctrl, key=lambda v: target_pct(t.key, v[0]) - v[1]) if r.ctrl else ("", math.nan)
        out.append(VerdictRow(t.key, t.quantity, worst[1], worst[0], target_pct(t.key, worst[0]), t.thesis_ctrl))
    return out


def _all_runs(*sources: _Source | None) -> list[runformat.Run]:
    return [r for s in sources if s is not None for r in s.runs.values()]


_NUMBER = re.compile(r"-?\d+(\.\d+)?")
_SKIPPED = re.compile(r"shaper skipped: (\S+ Hz) cannot resolve (.*)$")


def metadata_warnings(char: _Source | None, val: _Source | None) -> list[Warning_]:
    """Every warning and note the runs' metadata records, grouped by kind."""
    clipped: dict[str, int] = {}
    groups: dict[str, list[str]] = defaultdict(list)
    texts: dict[str, set[str]] = defaultdict(set)
    for r in _all_runs(char, val):
        if r.meta.get("status", "complete") != "complete":
            groups[f"run not complete ({r.meta.get('status')})"].append(r.name)
            texts[f"run not complete ({r.meta.get('status')})"].add(str(r.meta.get("status_reason", "")))
        comp = r.meta.get("compensation") or {}
        n = int(comp.get("clipped_samples") or 0)
        if n:
            clipped[r.name] = n
        for text in list(comp.get("warnings", [])) + list(comp.get("notes", [])):
            if "cannot be reached" in text and n:
                continue  # counted with the clipped samples
            skipped = _SKIPPED.match(text)
            key = (
                f"shaper skipped: the run's sample rate cannot resolve {skipped.group(2)}"
                if skipped
                else _NUMBER.sub("#", text)
            )
            groups[key].append(r.name)
            texts[key].add(text)
    out = []
    if clipped:
        total = sum(clipped.values())
        out.append(
            Warning_(
                "drive clipped: the reference cannot be reached within the actuator's drive range",
                tuple(f"{k} ({v} sample{'s' if v != 1 else ''})" for k, v in clipped.items()),
                len(clipped),
                detail=f"{total} samples in all",
            )
        )
    for key, names in groups.items():
        variants = sorted(texts[key])
        if key.startswith("shaper skipped"):
            rates = sorted({m.group(1) for m in map(_SKIPPED.match, variants) if m}, key=lambda x: float(x.split()[0]))
            detail = (
                f"sample rates {', '.join(rates)}: below twice the mode's frequency, the shaper is left out "
                "(the drive's steps are too slow to ring the mode)"
            )
        else:
            detail = "; ".join(variants) if len(variants) <= 3 else f"{len(variants)} variants, e.g. {variants[0]}"
        out.append(Warning_(key, tuple(dict.fromkeys(names)), len(set(names)), detail=detail))
    return out


def _fitted_runs(bundle: dict[str, Any], section: str, char: _Source | None) -> list[runformat.Run]:
    names = [e.get("name") for e in bundle.get(section, {}).get("runs", [])]
    return [char.runs[n] for n in names if char is not None and n in char.runs]


def extrapolation_warnings(bundle: dict[str, Any] | None, char: _Source | None, val: _Source | None) -> list[Warning_]:
    """Where the validation uses a model beyond the data it was fitted on."""
    if bundle is None or val is None or "hysteresis" not in bundle:
        return []
    out = []
    h = bundle["hysteresis"]
    code = h.get("model", {}).get("output_unit", units.FORCE)
    u, k = units.label(code), units.key(code)
    y0 = h.get("model", {}).get(f"y0_{k}")
    span = h.get("fit", {}).get(f"output_range_{k}")
    if y0 is not None and span:
        top = float(y0) + float(span)
        beyond = []
        for r in val.runs.values():
            ref = r.column("reference_n")
            if ref is not None and float(np.max(ref)) > top + EXTRAPOLATION_TOLERANCE * float(span):
                beyond.append(f"{r.name} (to {float(np.max(ref)):.1f} {u})")
        if beyond:
            out.append(
                Warning_(
                    f"hysteresis model extrapolated: reference above its fitted output range ({float(y0):.1f} to "
                    f"{top:.1f} {u})",
                    tuple(beyond),
                    len(beyond),
                )
            )
    fitted = [f for f in (_freq(r) for r in _fitted_runs(bundle, "hysteresis", char)) if f is not None]
    if fitted:
        fmax = max(fitted)
        faster = [
            f"{r.name} ({_freq(r):g} Hz)"
            for r in val.runs.values()
            if r.kind in ("triangle", "sine") and _freq(r) is not None and _freq(r) > 1.5 * fmax
        ]
        if faster:
            out.append(
                Warning_(
                    f"hysteresis model extrapolated in rate: fitted on sweeps up to {fmax:g} Hz, used faster "
                    "(the model is rate-independent)",
                    tuple(faster),
                    len(faster),
                )
            )
    if "creep" in bundle:
        fitted_s = [float(r.t_s[-1] - r.t_s[0]) for r in _fitted_runs(bundle, "creep", char)]
        if fitted_s:
            longer = [
                f"{r.name} ({float(r.t_s[-1] - r.t_s[0]):.0f} s)"
                for r in val.runs.values()
                if float(r.t_s[-1] - r.t_s[0]) > 1.05 * max(fitted_s)
            ]
            if longer:
                out.append(
                    Warning_(
                        f"creep model extrapolated in time: fitted on {max(fitted_s):.0f} s, runs longer",
                        tuple(longer),
                        len(longer),
                    )
                )
    return out


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def consistency_warnings(bundle_path: Path | None, char: _Source | None, val: _Source | None) -> list[Warning_]:
    """Runs validated with another bundle than the one given; runs from different rigs."""
    out = []
    if bundle_path is not None and val is not None and bundle_path.is_file():
        digest = _sha256(bundle_path)
        other = [
            r.name
            for r in val.runs.values()
            if (r.meta.get("compensation") or {}).get("bundle_sha256") not in (None, digest)
        ]
        if other:
            out.append(
                Warning_(
                    f"validated with another bundle than {bundle_path} (sha256 {digest[:DIGEST_CHARS]}): the model "
                    "quality shown is not that of these runs",
                    tuple(other),
                    len(other),
                )
            )
    runs = _all_runs(char, val)
    check_one_rig(runs, "the characterization and validation runs")  # refused unless --allow-mixed-rigs
    rigs: dict[str, list[str]] = defaultdict(list)
    for r in runs:
        rigs[config_digest(runformat.meta_get(r.meta, "rig", "config"))[:DIGEST_CHARS]].append(r.name)
    if len(rigs) > 1:
        out.append(
            Warning_(
                f"the runs come from {len(rigs)} rig configurations",
                tuple(f"{d}: {', '.join(n[:3])}" + (" ..." if len(n) > 3 else "") for d, n in rigs.items()),
                sum(len(n) for n in rigs.values()),
            )
        )
    return out


def _manifest_date(src: _Source | None) -> str:
    if src is None:
        return "not given"
    if (src.path / MANIFEST).is_file():
        created = read_manifest(src.path).get("created_utc")
        if created:
            return str(created)
    started = sorted(str(r.meta.get("started_utc")) for r in src.runs.values() if r.meta.get("started_utc"))
    if started:
        return started[0]
    imported = sorted(str(runformat.meta_get(r.meta, "import", "imported_utc", default="")) for r in src.runs.values())
    imported = [d for d in imported if d]
    return f"unknown (imported {imported[0]})" if imported else "unknown"


def _rig_name(meta: dict[str, Any]) -> str:
    """The rig file's ``[rig] name``; else the file's name, else the backend's, else '?'."""
    name = runformat.meta_get(meta, "rig", "config", "rig", "name", default=None)
    if isinstance(name, str) and name:
        return name
    source = runformat.meta_get(meta, "rig", "source", default=None)
    if isinstance(source, str) and source:
        return Path(source).stem
    backend = meta.get("backend")
    return str(backend) if backend else "?"


def provenance(
    char: _Source | None, val: _Source | None, bundle_path: Path | None, bundle: dict[str, Any] | None
) -> str:
    """One line: rig (name, file, configuration digest), backend, dates, software, bundle digest."""
    runs = _all_runs(char, val)
    rig_names = sorted({_rig_name(r.meta) for r in runs})
    sources = sorted({str(runformat.meta_get(r.meta, "rig", "source", default="?")) for r in runs})
    digests = sorted({config_digest(runformat.meta_get(r.meta, "rig", "config"))[:DIGEST_CHARS] for r in runs})
    backends = sorted({str(r.meta.get("backend", "?")) for r in runs})
    versions = sorted(
        {str(r.meta.get("software_version")) for r in runs if r.meta.get("software_version")}
        | ({str(bundle["software_version"])} if bundle and bundle.get("software_version") else set())
    )
    parts = []
    imported = [r for r in runs if isinstance(r.meta.get("import"), dict)]
    if imported:
        sources = sorted(
            {
                f"{r.meta['import'].get('source_file', '?')} (sha256 "
                f"{str(r.meta['import'].get('source_sha256', '?'))[:DIGEST_CHARS]})"
                for r in imported
            }
        )
        parts.append(f"imported from {', '.join(sources)} by piezopress import")
        runs = [r for r in runs if r not in imported]
    if runs:
        parts.append(
            f"Rig {', '.join(rig_names)} (file {', '.join(sources)}; configuration sha256 {', '.join(digests)})"
        )
        simulated = " (simulated: not measurements of a real press)" if backends == ["virtual"] else ""
        parts.append(f"backend {', '.join(backends)}{simulated}")
    elif not imported:
        parts.append("No runs given: rig and backend unknown")
    parts.append(f"characterized {_manifest_date(char)}")
    parts.append(f"validated {_manifest_date(val)}")
    parts.append(f"software piezopress {', '.join(versions) or 'unknown'}")
    if bundle_path is not None and bundle_path.is_file():
        parts.append(f"bundle {bundle_path} (sha256 {_sha256(bundle_path)[:DIGEST_CHARS]})")
    else:
        parts.append("no bundle given")
    return "Provenance: " + "; ".join(parts) + "."


def model_error(bundle: dict[str, Any]) -> str:
    """The bundle's hysteresis held-out error in its own unit, for the MODEL ONLY verdict."""
    h = bundle.get("hysteresis") or {}
    fit = h.get("fit") or {}
    unit = units.normalise((h.get("model") or {}).get("output_unit"))
    k = units.key(unit)
    held, pct = fit.get(f"holdout_rms_{k}"), fit.get("holdout_rms_pct_of_range")
    if not isinstance(held, (int, float)):
        return "the model's held-out error is not recorded"
    share = f" ({pct:.3g} % of its range)" if isinstance(pct, (int, float)) else ""
    runs = ", ".join(str(r.get("name")) for r in h.get("runs") or [] if isinstance(r, dict))
    return f"the model's held-out error is {held:.3g} {units.label(unit)} RMS{share} on {runs or 'its runs'}"


def verdict_table(rows: list[VerdictRow]) -> Table:
    body = []
    for v in rows:
        verdict = "no data" if v.passed is None else ("PASS" if v.passed else "FAIL")
        lo, hi = v.thesis_ctrl
        worst_thesis = max(abs(lo), abs(hi))
        gap = worst_thesis - v.value
        vs = "-" if v.passed is None else f"{_num(abs(gap))} pp {'below' if gap >= 0 else 'above'} its worst"
        body.append(
            (
                v.quantity,
                _num(v.value),
                v.worst_run or "-",
                f"<= {_num(v.target)}",
                _num(v.margin) if v.passed is not None else "-",
                verdict,
                f"{_num(lo)} to {_num(hi)}",
                vs,
            )
        )
    return Table(
        (
            "Table 6.13 row (controlled)",
            "piezopress (%)",
            "run nearest its target",
            "target (%)",
            "margin (pp)",
            "verdict",
            "thesis (%)",
            "against the thesis",
        ),
        tuple(body),
        ("l", "r", "l", "r", "r", "l", "r", "l"),
    )


def warnings_table(warnings: Iterable[Warning_]) -> Table:
    rows = tuple((w.what, str(w.count), ", ".join(w.runs), w.detail) for w in warnings)
    return Table(("warning", "runs (count)", "runs", "detail"), rows, ("l", "r", "l", "l"))


@dataclass(frozen=True)
class Verdict:
    """The verdict: its one-line summary, the provenance line, the rows and the warnings."""

    summary: str
    provenance: str
    rows: tuple[VerdictRow, ...]
    warnings: tuple[Warning_, ...]

    def lines(self) -> list[str]:
        """The verdict as a terminal prints it: summary, provenance, one line per warning."""
        return [self.summary, self.provenance] + [f"  warning ({w.count} {w.unit}): {w.what}" for w in self.warnings]


def verdict_blocks(
    rows: list[_Row613],
    char: _Source | None,
    val: _Source | None,
    bundle_path: str | Path | None,
    bundle: dict[str, Any] | None,
) -> tuple[list[Block], Verdict]:
    """The verdict section: the rows against the targets, the warnings, the provenance."""
    path = Path(bundle_path) if bundle_path is not None else None
    vrows = verdict_rows(rows)
    warnings = (
        metadata_warnings(char, val) + extrapolation_warnings(bundle, char, val) + consistency_warnings(path, char, val)
    )
    failed = [v for v in vrows if v.passed is False]
    untested = [v for v in vrows if v.passed is None]
    if failed:
        overall = (
            f"FAIL: {len(failed)} of {len(vrows)} controlled figures miss their target "
            f"({', '.join(v.key for v in failed)})"
        )
    elif val is None and bundle is not None:
        overall = "MODEL ONLY: no validation runs, so no controlled figure is measured; " + model_error(bundle)
    elif untested:
        overall = (
            f"INCOMPLETE: {len(untested)} of {len(vrows)} controlled figures not measured "
            f"({', '.join(v.key for v in untested)})"
        )
    else:
        overall = f"PASS: all {len(vrows)} controlled figures within their targets"
    overall += (
        f", with {len(warnings)} kind{'s' if len(warnings) != 1 else ''} of warning below."
        if warnings
        else ", no warning."
    )
    prov = provenance(char, val, path, bundle)
    blocks: list[Block] = [
        Heading("Verdict"),
        Para(f"**{overall}**"),
        Para(prov),
        verdict_table(vrows),
        Para(
            "Targets: piezopress's own (static hysteresis at most 1.0 % on every 0.1 Hz triangle, 1.5 % on the 75 N "
            "one "
            "where the load cell's quantization weighs most; creep at most 0.3 % after 120 s; overshoot at most 3 %; "
            "the "
            "staircase's relative tracking error at most 3 %); margin = target - figure, in percentage points. "
            "Each figure is that of the run nearest its target (the runs are listed under Table 6.13 below)."
        ),
        Heading("Warnings that qualify the verdict", 3),
    ]
    blocks.append(
        warnings_table(warnings)
        if warnings
        else Para("None: no run records a warning, and no model is used beyond its data.")
    )
    return blocks, Verdict(f"Verdict: {overall}", prov, tuple(vrows), tuple(warnings))


__all__ = [
    "verdict_blocks",
    "Verdict",
    "TARGETS_PCT",
    "RUN_TARGETS_PCT",
    "target_pct",
    "VerdictRow",
    "Warning_",
    "metadata_warnings",
    "extrapolation_warnings",
    "consistency_warnings",
    "provenance",
    "config_digest",
]
