"""``piezopress compare``: two or more bundles played on one press, interleaved and repeated,
each Table 6.13 row (and the tracking rows) judged beyond the spread of the repeats.

The same references (the validation plan and the tracking plan, or the user's plans) are
compensated with every bundle and checked against the press's limits before anything is
played; then, for each repeat, each plan is played with every bundle in turn, the order
reversed on every other repeat (A B, B A, A B, ...: a drift or a warm-up of the press falls on
every bundle alike). The rows of each play are those of ``validate``
(:func:`piezopress.pipelines.gain.row_values`); each bundle after the first is judged against
the first (:func:`piezopress.analysis.ab.judge`).

Files in the output directory: ``rep<k>/<label>/<plan>/`` (the runs, as ``validate`` writes
them), ``repeats.csv`` (every row's value in every repeat), ``compare.csv`` (per row and
bundle: mean, spread, difference from the first bundle, Welch's p and the verdict) and
``compare.json`` (the bundles, the press, the order played, the status: ``running`` until
every play is done, ``interrupted`` or ``failed`` with the reason).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from piezopress import runformat
from piezopress.acquisition.backend import Backend
from piezopress.analysis import ab
from piezopress.errors import PiezopressError
from piezopress.pipelines.characterize import DEFAULT_RIG, ProgressEvent, backend_from, rig_description
from piezopress.pipelines.files import new_output_dir, utc_now, write_json_atomic
from piezopress.pipelines.gain import ROW_BY_ID, ROWS, TRACKING_PLAN, row_values
from piezopress.pipelines.validate import DEFAULT_VALIDATION_PLAN, PreparedValidation, prepare_validation

__all__ = [
    "COMPARE_CSV",
    "COMPARE_JSON",
    "REPEATS_CSV",
    "DEFAULT_PLANS",
    "Comparison",
    "Play",
    "compare",
    "read_comparison",
    "format_table",
]

COMPARE_CSV = "compare.csv"
COMPARE_JSON = "compare.json"
REPEATS_CSV = "repeats.csv"
DEFAULT_PLANS: tuple[Path, ...] = (DEFAULT_VALIDATION_PLAN, TRACKING_PLAN)
MAX_REPEATS = 50


class CompareError(PiezopressError, ValueError):
    """A comparison that cannot be made as asked (one bundle, labels that repeat, ...)."""


@dataclass(frozen=True)
class Play:
    """One plan played with one bundle in one repeat (for progress)."""

    index: int  # 1-based, over the whole comparison
    total: int
    repeat: int
    label: str
    plan: str
    done: bool = False
    out_dir: Path | None = None


@dataclass
class Comparison:
    """What ``compare`` measured: the table (one row per row id and bundle) and where it is."""

    out_dir: Path
    labels: list[str]
    bundles: list[Path]
    repeats: int
    table: pd.DataFrame  # compare.csv
    values: pd.DataFrame  # repeats.csv
    warnings: list[str] = field(default_factory=list)

    def judged(self, label: str, against: str | None = None) -> dict[str, ab.Judged]:
        """Each row of ``label`` against the first bundle (or ``against``), from the repeats,
        the rows judged together (:func:`piezopress.analysis.ab.judge_rows`)."""
        return _judged_rows(self.values, against or self.labels[0], label)

    def verdicts(self, label: str, against: str | None = None) -> dict[str, str]:
        """Each row's verdict for ``label`` against the first bundle (or ``against``, judged
        from the same repeats by the same rule)."""
        if against is None or against == self.labels[0]:
            t = self.table[self.table["bundle"] == label]
            return dict(zip(t["row"], t["verdict"]))
        return {row: j.verdict for row, j in self.judged(label, against).items()}


def _judged_rows(values: pd.DataFrame, against: str, label: str) -> dict[str, ab.Judged]:
    a: dict[str, list[float]] = {}
    b: dict[str, list[float]] = {}
    for row, of in values.groupby("row", sort=False):
        va = of[of["bundle"] == against]["value"].tolist()
        vb = of[of["bundle"] == label]["value"].tolist()
        if va and vb:
            a[str(row)], b[str(row)] = va, vb
    return ab.judge_rows(a, b)


def _labels(bundles: Sequence[Path], labels: Sequence[str] | None) -> list[str]:
    if labels:
        if len(labels) != len(bundles):
            raise CompareError(
                f"{len(labels)} label(s) for {len(bundles)} bundles; expected one --label per bundle, in order"
            )
        out = [str(x) for x in labels]
    else:
        out = [b.stem for b in bundles]
        if len(set(out)) < len(out):  # two bundles of one name in different folders
            out = [f"{b.parent.name}/{b.stem}" for b in bundles]
        if len(set(out)) < len(out):
            out = [f"{i + 1}:{b.stem}" for i, b in enumerate(bundles)]
    dirs = [_dir_name(x) for x in out]
    if not all(x.strip() for x in out) or len(set(dirs)) < len(dirs):
        raise CompareError(
            f"labels {', '.join(map(repr, out))}; expected one distinct, non-empty name per bundle (its runs' folder "
            "is named after it)"
        )
    return out


def _dir_name(label: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in label)


def compare(
    bundle_paths: Sequence[str | Path],
    out_dir: str | Path,
    *,
    rig_path: str | Path | None = DEFAULT_RIG,
    backend: Backend | None = None,
    backend_name: str | None = None,
    repeats: int = 3,
    plans: Sequence[str | Path] | None = None,
    labels: Sequence[str] | None = None,
    on_play: Callable[[Play], None] | None = None,
    on_progress: Callable[[ProgressEvent], None] | None = None,
    on_warning: Callable[[str], None] | None = None,
) -> Comparison:
    """Play the plans with every bundle on one press, interleaved, ``repeats`` times; see the module."""
    bundles = [Path(b) for b in bundle_paths]
    if len(bundles) < 2:
        raise CompareError(f"{len(bundles)} bundle given; expected two or more to compare (the first is the reference)")
    if not 1 <= int(repeats) <= MAX_REPEATS:
        raise CompareError(f"--repeats {repeats}; expected 1 to {MAX_REPEATS} (3 gives a spread to judge against)")
    names = _labels(bundles, labels)
    plan_paths = [Path(p) for p in (plans or DEFAULT_PLANS)]
    stems = [p.stem for p in plan_paths]
    if len(set(stems)) < len(stems):
        raise CompareError(f"plans {', '.join(map(str, plan_paths))}: two plans of one name; expected distinct names")
    backend, made_from = backend_from(backend, backend_name, rig_path)
    warnings: list[str] = []

    def warn(text: str) -> None:
        if text not in warnings:
            warnings.append(text)
            if on_warning:
                on_warning(text)

    # every drive of every bundle computed and checked against the press before anything is played
    prepared: dict[tuple[str, str], PreparedValidation] = {}
    for label, b in zip(names, bundles):
        for plan in plan_paths:
            prepared[label, plan.stem] = prepare_validation(
                b, backend, plan_path=plan, rig_path=rig_path, on_warning=lambda w, b=b: warn(f"{b}: {w}")
            )
    out = new_output_dir(out_dir)
    doc: dict[str, Any] = {
        "status": "running",
        "created_utc": utc_now(),
        "bundles": [{"label": n, "file": str(b), "sha256": runformat.sha256_file(b)} for n, b in zip(names, bundles)],
        "plans": [{"file": str(p), "sha256": runformat.sha256_file(p)} for p in plan_paths],
        "repeats": int(repeats),
        "rig": rig_description(backend, made_from),
        "order": [],
        "rule": (
            f"each bundle against the first: lower is better; a difference counts when every repeat of one beats "
            f"every repeat of the other, Welch's t-test gives p < {ab.ALPHA:g} with Holm's correction over the rows "
            f"and it is at least {ab.MIN_CHANGE_PCT:g} % of the first bundle's value"
        ),
    }
    write_json_atomic(out / COMPARE_JSON, doc, null_nonfinite=True)
    total = int(repeats) * len(plan_paths) * len(names)
    index = 0
    records: list[dict[str, Any]] = []
    try:
        for rep in range(1, int(repeats) + 1):
            order = names if rep % 2 else names[::-1]
            for plan in plan_paths:
                for label in order:
                    index += 1
                    where = out / f"rep{rep}" / _dir_name(label) / _dir_name(plan.stem)
                    if on_play:
                        on_play(Play(index, total, rep, label, plan.stem))
                    prepared[label, plan.stem].play(where, backend, on_progress, rig_path=made_from)
                    doc["order"].append({"repeat": rep, "bundle": label, "plan": plan.stem, "dir": str(where)})
                    write_json_atomic(out / COMPARE_JSON, doc, null_nonfinite=True)
                    if on_play:
                        on_play(Play(index, total, rep, label, plan.stem, done=True, out_dir=where))
            for label in names:
                dirs = [out / f"rep{rep}" / _dir_name(label) / _dir_name(p.stem) for p in plan_paths]
                for row, value in row_values(dirs).items():
                    records.append({"repeat": rep, "bundle": label, "row": row, "value": value})
    except BaseException as exc:
        doc["status"] = "interrupted" if isinstance(exc, KeyboardInterrupt) else "failed"
        doc["reason"] = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
        doc["finished_utc"] = utc_now()
        write_json_atomic(out / COMPARE_JSON, doc, null_nonfinite=True)
        raise
    values = pd.DataFrame(records, columns=["repeat", "bundle", "row", "value"])
    values.to_csv(out / REPEATS_CSV, index=False, float_format="%.6g")
    table = judge_table(values, names)
    table.to_csv(out / COMPARE_CSV, index=False, float_format="%.6g")
    doc["status"] = "complete"
    doc["finished_utc"] = utc_now()
    doc["warnings"] = warnings
    write_json_atomic(out / COMPARE_JSON, doc, null_nonfinite=True)
    return Comparison(out, names, bundles, int(repeats), table, values, warnings)


def judge_table(values: pd.DataFrame, labels: Sequence[str]) -> pd.DataFrame:
    """``compare.csv``: per row (in the table's order) and bundle, the mean, spread (standard
    deviation of the repeats), number of repeats, and against the first bundle the
    difference, its percentage, Welch's p and the verdict."""
    order = [r.id for r in ROWS]
    rows = sorted(set(values["row"]), key=lambda r: (order.index(r) if r in order else len(order), r))
    out = []
    ref = labels[0]
    judged = {label: _judged_rows(values, ref, label) for label in labels}  # each bundle's rows together
    for row in rows:
        of = values[values["row"] == row]
        a = of[of["bundle"] == ref]["value"].tolist()
        for label in labels:
            b = of[of["bundle"] == label]["value"].tolist()
            info = ROW_BY_ID.get(row)
            base = {
                "row": row,
                "label": info.label if info else row.replace("_", " "),
                "unit": info.unit if info else "%",
                "bundle": label,
                "n": len(b),
            }
            if not b or not a:
                out.append({**base, "mean": math.nan, "spread": math.nan, "verdict": "not measured"})
                continue
            j = judged[label].get(str(row)) or ab.judge(a, b)
            if label == ref:
                out.append({**base, "mean": j.mean_b, "spread": j.spread_b, "verdict": "reference"})
                continue
            out.append(
                {
                    **base,
                    "mean": j.mean_b,
                    "spread": j.spread_b,
                    "difference": j.difference,
                    "change_pct": j.change_pct,
                    "p_value": j.p_value,
                    "verdict": j.verdict,
                }
            )
    cols = ["row", "label", "unit", "bundle", "n", "mean", "spread", "difference", "change_pct", "p_value", "verdict"]
    return pd.DataFrame(out, columns=cols)


def read_comparison(out_dir: str | Path) -> tuple[dict[str, Any], pd.DataFrame]:
    """A comparison directory's ``compare.json`` and ``compare.csv``; refused (naming the
    status and its reason) unless it is complete."""
    import json

    out = Path(out_dir)
    path = out / COMPARE_JSON
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise CompareError(f"{out}: no {COMPARE_JSON}; expected a directory written by piezopress compare") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise CompareError(f"{path}: unreadable ({exc}); expected compare's JSON") from None
    if not isinstance(doc, dict) or doc.get("status") != "complete":
        status = doc.get("status") if isinstance(doc, dict) else None
        reason = doc.get("reason", "") if isinstance(doc, dict) else ""
        raise CompareError(
            f"{out}: the comparison is {status or 'of unknown status'}{f' ({reason})' if reason else ''}; expected a "
            "complete one (run piezopress compare again into a new directory)"
        )
    try:
        table = pd.read_csv(out / COMPARE_CSV)
    except (OSError, ValueError) as exc:
        raise CompareError(f"{out / COMPARE_CSV}: unreadable ({exc})") from None
    return doc, table


def _num(v: Any, digits: int = 3) -> str:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return "-"
    return "-" if not math.isfinite(f) else f"{f:.{digits}g}"


def format_table(table: pd.DataFrame, labels: Sequence[str]) -> str:
    """The comparison as text: one line per row, each bundle's mean ± spread, and for each
    bundle after the first its change and verdict."""
    head = ["row", "unit"] + [f"{x} (mean ± sd)" for x in labels]
    head += [f"{x} vs {labels[0]}" for x in labels[1:]]
    lines = [head]
    for _row, of in table.groupby("row", sort=False):
        by = {r["bundle"]: r for _, r in of.iterrows()}
        first = of.iloc[0]
        line = [str(first["label"]), str(first["unit"])]
        for x in labels:
            r = by.get(x)
            line.append("-" if r is None else f"{_num(r['mean'])} ± {_num(r['spread'], 2)}")
        for x in labels[1:]:
            r = by.get(x)
            if r is None:
                line.append("-")
                continue
            pct = r.get("change_pct")
            change = f"{float(pct):+.0f} %" if isinstance(pct, (int, float)) and math.isfinite(pct) else ""
            line.append(f"{change} {r['verdict']}".strip())
        lines.append(line)
    widths = [max(len(r[i]) for r in lines) for i in range(len(head))]
    text = ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in lines]
    text.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(text)
