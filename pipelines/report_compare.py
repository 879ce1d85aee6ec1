"""The report's comparison on the press: bundles played on one press, repeated (``compare``,
or ``diagnose --gain``), each row's verdict, and the recommendation when there is one."""

from __future__ import annotations

import json
import math
from pathlib import Path

from piezopress import plotting
from piezopress.pipelines.report_doc import Block, Bullets, FigureBlock, Heading, Para, Table

__all__ = ["comparison_blocks", "recommendation_blocks", "unverified_blocks"]


def _num(v, digits: int = 3) -> str:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return "-"
    return f"{f:.{digits}g}" if math.isfinite(f) else "-"


def comparison_blocks(path: str | Path, missing: list[str], *, title: str = "Compared on the press") -> list[Block]:
    """The comparison directory as a table (mean ± spread per bundle, change and verdict
    against the first) and a dot plot of every repeat."""
    from piezopress.pipelines.compare import CompareError, read_comparison

    path = Path(path)
    try:
        doc, table = read_comparison(path)
    except CompareError as exc:
        missing.append(f"{exc}; the comparison section is missing.")
        return []
    labels = [b["label"] for b in doc.get("bundles", [])]
    if not labels or table.empty:
        missing.append(f"{path}: the comparison measured no row; the comparison section is missing.")
        return []
    head = ("row", "unit", *(f"{x}: mean ± sd" for x in labels), *(f"{x} vs {labels[0]}" for x in labels[1:]))
    lines = []
    dots = []
    verdicts = {}
    values = None
    try:
        import pandas as pd

        values = pd.read_csv(path / "repeats.csv")
    except (OSError, ValueError):
        missing.append(f"{path / 'repeats.csv'}: unreadable; the comparison's figure is missing.")
    for _row, of in table.groupby("row", sort=False):
        by = {r["bundle"]: r for _, r in of.iterrows()}
        first = of.iloc[0]
        title = f"{first['label']} ({first['unit']})"
        cells = [str(first["label"]), str(first["unit"])]
        cells += [f"{_num(by[x]['mean'])} ± {_num(by[x]['spread'], 2)}" if x in by else "-" for x in labels]
        for x in labels[1:]:
            r = by.get(x)
            pct = r.get("change_pct") if r is not None else None
            change = f"{float(pct):+.0f} % " if pct is not None and math.isfinite(float(pct)) else ""
            cells.append(f"{change}{r['verdict']}" if r is not None else "-")
            if r is not None:
                verdicts[title, x] = str(r["verdict"])
        lines.append(tuple(cells))
        if values is not None:
            of_v = values[values["row"] == _row]
            dots.append((title, [(x, of_v[of_v["bundle"] == x]["value"].tolist()) for x in labels]))
    rig = doc.get("rig") or {}
    press = rig.get("source") or rig.get("backend") or "?"
    blocks: list[Block] = [
        Heading(title, 3),
        Para(
            f"{len(labels)} bundles played on one press ({press}, backend {rig.get('backend', '?')}), "
            f"{doc.get('repeats', '?')} repeats each, interleaved (the order reversed every other repeat); lower is "
            f"better. Rule: {doc.get('rule', '')}. From `{path}`."
        ),
        Table(head, tuple(lines), ("l", "l") + ("r",) * len(labels) + ("l",) * (len(labels) - 1)),
    ]
    if dots:
        blocks.append(
            FigureBlock(
                f"compare_{path.name}",
                f"{title}: every repeat",
                "Each row a panel, each bundle a line of dots (one per repeat) with its mean as a bar; green: better "
                "than the first bundle beyond the spread, red: worse.",
                plotting.to_png(plotting.compare_dots(dots, verdicts)),
            )
        )
    return blocks


def recommendation_blocks(diag_dir: str | Path, missing: list[str]) -> list[Block]:
    """What ``diagnose --gain`` measured on the press and recommends; a diagnosis without it
    says its extension is unverified on the press."""
    diag = Path(diag_dir)
    from piezopress.pipelines.adopt import GAIN_DIR, RECOMMENDED

    if not (diag / GAIN_DIR).is_dir():
        return unverified_blocks(diag)
    blocks = comparison_blocks(
        diag / GAIN_DIR, missing, title="The gain on the press: base, each extension, extended (measured there)"
    )
    try:
        rec = json.loads((diag / RECOMMENDED).read_text(encoding="utf-8")).get("recommendation") or {}
    except (OSError, ValueError) as exc:
        missing.append(f"{diag / RECOMMENDED}: unreadable ({exc}); the recommendation is missing.")
        return blocks
    adopted = rec.get("adopted") or []
    ref = rec.get("against", "base")
    head = (
        f"Recommended bundle: `{diag / RECOMMENDED}`, the {rec.get('bundle', '?')} bundle"
        + (f" (adopts {', '.join(adopted)})" if adopted else "")
        + f": better than the {ref} bundle on {', '.join(rec.get('better_on') or [])}, and on no row worse or "
        "possibly worse (a loss the repeats do not exclude)."
        if rec.get("bundle") != ref
        else f"Recommended bundle: `{diag / RECOMMENDED}` = the {ref} bundle: no other bundle won a row on the press "
        "without a row where it is, or may be, worse."
    )
    blocks.append(Para(head))
    reasons = rec.get("reasons") or {}
    if reasons:
        blocks.append(Bullets(tuple(f"{c}: {why}" for c, why in reasons.items())))
    return blocks


def unverified_blocks(diag: Path) -> list[Block]:
    """The extended bundle's gain was not measured on the press: said so, with how to."""
    try:
        ext = json.loads((diag / "extended_bundle.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return []
    if not ext.get("extensions"):
        return []
    return [
        Heading("The gain on the press", 3),
        Para(
            "The extended bundle is unverified on the press: it predicts the runs better, but its compensation was "
            "not measured there. Measure it with `piezopress diagnose ... --gain --rig YOUR-PRESS.toml` or "
            "`piezopress compare BASE.json extended_bundle.json --rig YOUR-PRESS.toml`; adopt only what wins."
        ),
    ]
