"""The report's document model and its two renderings: Markdown (for CI logs) and one
self-contained HTML page (figures as data URIs, inline CSS, no script).

A report is a list of blocks (:class:`Heading`, :class:`Para`, :class:`Bullets`,
:class:`Table`, :class:`FigureBlock`); :func:`render_markdown` and :func:`render_html` render
the same blocks, so the two files hold the same content.
"""

from __future__ import annotations

import base64
import html
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

# --------------------------------------------------------------------------- document model


@dataclass(frozen=True)
class Heading:
    text: str
    level: int = 2

    @property
    def anchor(self) -> str:
        return anchor(self.text)


def anchor(text: str) -> str:
    """The heading's anchor, as GitHub makes it (lower case; punctuation dropped; spaces to
    hyphens), so the Markdown's links work on GitHub and the HTML page's alike."""
    return re.sub(r"[^\w\- ]", "", text.strip().lower()).replace(" ", "-")


@dataclass(frozen=True)
class Contents:
    """A table of contents: a link to every heading of ``level`` (rendered from the blocks)."""

    level: int = 2


@dataclass(frozen=True)
class Para:
    text: str


@dataclass(frozen=True)
class Bullets:
    items: tuple[str, ...]


@dataclass(frozen=True)
class Table:
    header: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    #: per column: "l" or "r"
    align: tuple[str, ...] = ()


@dataclass(frozen=True)
class FigureBlock:
    name: str
    title: str
    caption: str
    png: bytes = field(repr=False)

    @property
    def file(self) -> str:
        return f"{self.name}.png"


Block = Heading | Para | Bullets | Table | FigureBlock | Contents


def _contents(blocks: Sequence[Block], level: int) -> list[Heading]:
    return [b for b in blocks if isinstance(b, Heading) and b.level == level]


# --------------------------------------------------------------------------- rendering


def _md_cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _md_table(t: Table) -> str:
    cells = [[_md_cell(c) for c in t.header]] + [[_md_cell(c) for c in row] for row in t.rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(t.header))]
    align = t.align or ("l",) * len(t.header)

    def line(row: Sequence[str]) -> str:
        return "| " + " | ".join(c.rjust(w) if a == "r" else c.ljust(w) for c, w, a in zip(row, widths, align)) + " |"

    rule = "|" + "|".join(("-" * (w + 1) + ":") if a == "r" else ("-" * (w + 2)) for w, a in zip(widths, align)) + "|"
    return "\n".join([line(cells[0]), rule] + [line(r) for r in cells[1:]])


def render_markdown(blocks: Iterable[Block]) -> str:
    blocks = list(blocks)
    parts = []
    n_fig = 0
    for b in blocks:
        if isinstance(b, Contents):
            parts.append(
                "**Contents**\n\n" + "\n".join(f"- [{h.text}](#{h.anchor})" for h in _contents(blocks, b.level))
            )
        elif isinstance(b, Heading):
            parts.append("#" * b.level + " " + b.text)
        elif isinstance(b, Para):
            parts.append(b.text)
        elif isinstance(b, Bullets):
            parts.append("\n".join(f"- {i}" for i in b.items))
        elif isinstance(b, Table):
            parts.append(_md_table(b))
        elif isinstance(b, FigureBlock):
            n_fig += 1
            parts.append(
                f"**Figure {n_fig}. {b.title}** ([{b.file}]({b.file}))\n\n![{b.title}]({b.file})\n\n_{b.caption}_"
            )
    return "\n\n".join(parts) + "\n"


_CODE = re.compile(r"`([^`]+)`")

CSS = """
body { font-family: -apple-system, "Segoe UI", Helvetica, Arial, sans-serif; max-width: 1100px; margin: 1.5em auto;
       padding: 0 1em; color: #222; line-height: 1.4; font-size: 15px; }
h1 { font-size: 1.6em; border-bottom: 2px solid #ccc; padding-bottom: .2em; }
h2 { font-size: 1.3em; margin-top: 1.6em; border-bottom: 1px solid #ddd; }
h3 { font-size: 1.1em; margin-top: 1.2em; }
.table-wrap { overflow-x: auto; }
table { border-collapse: collapse; font-size: 13px; margin: .6em 0; }
th, td { border: 1px solid #ccc; padding: 3px 7px; vertical-align: top; }
th { background: #f0f0f0; text-align: left; }
td.r { text-align: right; white-space: nowrap; font-variant-numeric: tabular-nums; }
tr:nth-child(even) td { background: #fafafa; }
code { background: #f3f3f3; padding: 0 3px; border-radius: 3px; font-size: 0.92em; }
figure { margin: 1.2em 0; }
figure img { max-width: 100%; height: auto; border: 1px solid #eee; box-sizing: border-box; }
figcaption { font-size: 13px; color: #555; }
p, li, td, figcaption { overflow-wrap: anywhere; }
nav.toc { background: #f7f7f7; border: 1px solid #ddd; padding: .4em 1em; display: inline-block; }
nav.toc ul { margin: .3em 0; padding-left: 1.2em; }
"""


_BOLD = re.compile(r"\*\*(.+?)\*\*")


def _inline(text: str) -> str:
    text = _CODE.sub(lambda m: f"<code>{m.group(1)}</code>", html.escape(text, quote=False))
    return _BOLD.sub(lambda m: f"<b>{m.group(1)}</b>", text)


def _html_table(t: Table) -> str:
    align = t.align or ("l",) * len(t.header)
    head = "".join(f"<th>{_inline(c)}</th>" for c in t.header)
    body = "\n".join(
        "<tr>"
        + "".join(
            f'<td class="r">{_inline(c)}</td>' if a == "r" else f"<td>{_inline(c)}</td>" for c, a in zip(row, align)
        )
        + "</tr>"
        for row in t.rows
    )
    return f'<div class="table-wrap"><table>\n<thead><tr>{head}</tr></thead>\n<tbody>\n{body}\n</tbody></table></div>'


def render_html(blocks: Iterable[Block]) -> str:
    blocks = list(blocks)
    parts = []
    title = "piezopress report"
    n_fig = 0
    for b in blocks:
        if isinstance(b, Contents):
            parts.append(
                '<nav class="toc"><b>Contents</b>\n<ul>\n'
                + "\n".join(f'<li><a href="#{h.anchor}">{_inline(h.text)}</a></li>' for h in _contents(blocks, b.level))
                + "\n</ul></nav>"
            )
        elif isinstance(b, Heading):
            parts.append(f'<h{b.level} id="{b.anchor}">{_inline(b.text)}</h{b.level}>')
        elif isinstance(b, Para):
            parts.append(f"<p>{_inline(b.text)}</p>")
        elif isinstance(b, Bullets):
            parts.append("<ul>\n" + "\n".join(f"<li>{_inline(i)}</li>" for i in b.items) + "\n</ul>")
        elif isinstance(b, Table):
            parts.append(_html_table(b))
        elif isinstance(b, FigureBlock):
            n_fig += 1
            data = base64.b64encode(b.png).decode("ascii")
            parts.append(
                f'<figure id="figure-{b.name}"><img alt="{html.escape(b.title)}" src="data:image/png;base64,{data}">'
                f"<figcaption><b>Figure {n_fig}. {_inline(b.title)}.</b> {_inline(b.caption)}</figcaption></figure>"
            )
    return (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
        f"<title>{title}</title>\n<style>{CSS}</style>\n</head>\n<body>\n" + "\n".join(parts) + "\n</body>\n</html>\n"
    )
