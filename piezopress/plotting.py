"""Figures of the report: each function takes prepared curves and returns a Figure.

Nothing here computes a metric or normalises data: the caller (``piezopress.pipelines.report``) hands
over the arrays to draw, already scaled. Figures are drawn on the non-interactive Agg
canvas (no pyplot, no global backend switch, no window) and are only written where the
caller asks (:func:`to_png`).

Examples
--------
>>> import numpy as np
>>> fig = step_responses([Curve(np.arange(3.0), np.ones(3), "a")], [])
>>> to_png(fig)[:4] == b"\\x89PNG"
True
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from piezopress import units

#: Resolution of the PNGs: 100 dpi, so a 10 x 4 in figure is 1000 x 400 px (a laptop screen's width).
DPI = 100
#: Width of every figure (in), fitting the report page (1100 px).
WIDTH_IN = 10.0

#: Colours: uncompensated runs in warm tones, compensated runs in cool ones.
BEFORE_COLOURS = ("#c0392b", "#e67e22", "#8e44ad", "#d35400", "#a93226", "#f39c12")
AFTER_COLOURS = ("#1f77b4", "#17becf", "#2ca02c", "#0b5394", "#76b7b2", "#59a14f")


@dataclass(frozen=True)
class Curve:
    """One line to draw: ``y`` against ``x``, with its legend label."""

    x: np.ndarray
    y: np.ndarray
    label: str = ""


def _figure(height_in: float) -> Figure:
    fig = Figure(figsize=(WIDTH_IN, height_in), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _no_data(ax, message: str) -> None:
    ax.text(0.5, 0.5, message, ha="center", va="center", transform=ax.transAxes, fontsize=10, color="0.4", wrap=True)


def _lines(ax, curves: Sequence[Curve], colours: Sequence[str], **kw) -> None:
    for i, c in enumerate(curves):
        ax.plot(c.x, c.y, color=colours[i % len(colours)], label=c.label or None, **kw)
    if any(c.label for c in curves):
        ax.legend(fontsize=8, loc="best")


def to_png(fig: Figure) -> bytes:
    """The figure as PNG bytes (no timestamp or software tag in the file)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, metadata={"Software": None})
    return buf.getvalue()


def hysteresis_loops(before: Curve | None, after: Curve | None, *, before_title: str = "", after_title: str = "",
                     unit: str = "N", after_unit: str | None = None) -> Figure:
    """Output against drive before compensation, and output against reference after it, side by side.

    ``before``: drive (V) against the measured output (force in N, or displacement in µm:
    ``unit``); ``after``: reference against measured output (``after_unit``, default
    ``unit``), drawn with the ideal line ``output = reference``.
    """
    fig = _figure(4.2)
    ax_b, ax_a = fig.subplots(1, 2)
    qb, ub = units.quantity(unit), units.label(unit)
    qa, ua = units.quantity(after_unit or unit), units.label(after_unit or unit)
    ax_b.set(title=before_title or "Before: uncompensated", xlabel="drive command_v (V)", ylabel=f"measured {qb} ({ub})")
    ax_a.set(title=after_title or "After: compensated", xlabel=f"reference {qa} ({ua})", ylabel=f"measured {qa} ({ua})")
    if before is not None:
        ax_b.plot(before.x, before.y, color=BEFORE_COLOURS[0], lw=0.8, label=before.label or None)
        if before.label:
            ax_b.legend(fontsize=8, loc="upper left")
    else:
        _no_data(ax_b, "no uncompensated 0.1 Hz triangle")
    if after is not None:
        lo, hi = float(np.nanmin(after.x)), float(np.nanmax(after.x))
        ax_a.plot([lo, hi], [lo, hi], color="0.6", ls="--", lw=0.8, label=f"ideal: {qa} = reference")
        ax_a.plot(after.x, after.y, color=AFTER_COLOURS[0], lw=0.8, label=after.label or "measured")
        ax_a.legend(fontsize=8, loc="upper left")
    else:
        _no_data(ax_a, "no compensated 0.1 Hz triangle")
    for ax in (ax_b, ax_a):
        ax.grid(True, alpha=0.3)
    fig.suptitle("Hysteresis loops (0.1 Hz triangles)")
    return fig


def creep_responses(before: Sequence[Curve], after: Sequence[Curve]) -> Figure:
    """Held steps against time after the step (log axis), force normalised by the step.

    Curves: ``x`` time after the step (s, > 0), ``y`` ``(F - F_0) / (F_ss - F_0)``.
    """
    fig = _figure(4.2)
    ax = fig.subplots()
    _lines(ax, list(before), BEFORE_COLOURS, lw=0.9)
    for i, c in enumerate(after):
        ax.plot(c.x, c.y, color=AFTER_COLOURS[i % len(AFTER_COLOURS)], lw=0.9, label=c.label or None)
    if before or after:
        ax.set_xscale("log")
        ax.axhline(1.0, color="0.5", lw=0.8, ls=":")
        ax.legend(fontsize=8, loc="lower right")
    else:
        _no_data(ax, "no creep run")
    ax.set(title="Creep: held step, before and after compensation", xlabel="time after the step (s)",
           ylabel="(F - F_0) / (F_ss - F_0)  (1)")
    ax.grid(True, which="both", alpha=0.3)
    return fig


def step_responses(uncompensated: Sequence[Curve], compensated: Sequence[Curve]) -> Figure:
    """Step responses side by side: uncompensated and compensated, normalised by the step.

    Curves: ``x`` time from the step (ms), ``y`` ``(F - F_0) / step size``.
    """
    fig = _figure(4.2)
    ax_u, ax_c = fig.subplots(1, 2, sharey=True)
    for ax, curves, colours, title, missing in (
        (ax_u, uncompensated, BEFORE_COLOURS, "uncompensated (no shaper)", "no uncompensated step run"),
        (ax_c, compensated, AFTER_COLOURS, "compensated (shaper + inverse models)", "no compensated step run"),
    ):
        if curves:
            for band in (0.98, 1.02):
                ax.axhline(band, color="0.6", lw=0.7, ls=":")
            _lines(ax, list(curves), colours, lw=0.9)
        else:
            _no_data(ax, missing)
        ax.set(title=title, xlabel="time from the step (ms)")
        ax.grid(True, alpha=0.3)
    ax_u.set_ylabel("(F - F_0) / step size  (1)")
    fig.suptitle("Step responses (dotted: 2 % settling band)")
    return fig


def tracking(t_s: np.ndarray, reference: np.ndarray, measured: np.ndarray, error: np.ndarray,
             evaluated_error: np.ndarray | None = None, *, title: str = "Staircase tracking", unit: str = "N") -> Figure:
    """Reference and measured output (force, or displacement: ``unit``) against time, with the
    error ``measured - reference`` below.

    ``evaluated_error``: the error where the metric evaluates it (NaN elsewhere), drawn
    over the full error.
    """
    q, u = units.quantity(unit), units.label(unit)
    fig = _figure(5.6)
    ax_f, ax_e = fig.subplots(2, 1, sharex=True, height_ratios=(2, 1))
    ax_f.plot(t_s, reference, color="0.3", lw=1.0, ls="--", label="reference")
    ax_f.plot(t_s, measured, color=AFTER_COLOURS[0], lw=0.8, label="measured (compensated)")
    ax_f.set(title=title, ylabel=f"{q} ({u})")
    ax_f.legend(fontsize=8, loc="upper left")
    ax_e.plot(t_s, error, color="0.7", lw=0.6, label="error")
    if evaluated_error is not None:
        ax_e.plot(t_s, evaluated_error, color=BEFORE_COLOURS[0], lw=0.5, label="error where evaluated (plateaus)")
    ax_e.axhline(0.0, color="0.4", lw=0.6)
    ax_e.set(xlabel="time (s)", ylabel=f"{q} - reference ({u})")
    ax_e.legend(fontsize=8, loc="upper left")
    for ax in (ax_f, ax_e):
        ax.grid(True, alpha=0.3)
    return fig


def model_residuals(left: Sequence[Curve], right: Sequence[Curve], *, unit: str = "N", left_title: str = "",
                    right_title: str = "", left_xlabel: str = "time (s)", right_xlabel: str = "time (s)",
                    title: str = "Hysteresis model residuals") -> Figure:
    """Measured minus modelled output (in ``unit``, a code or label: ``N``, ``um``/``µm``): two panels, e.g. the raw residual against
    time and the residual with the creep removed (or against the drive)."""
    fig = _figure(4.2)
    ax_l, ax_r = fig.subplots(1, 2, sharey=True)
    for ax, curves, sub, xlabel in ((ax_l, left, left_title, left_xlabel), (ax_r, right, right_title, right_xlabel)):
        if curves:
            _lines(ax, list(curves), AFTER_COLOURS, lw=0.5, alpha=0.85)
        else:
            _no_data(ax, "no fitting run")
        ax.axhline(0.0, color="0.3", lw=0.6)
        ax.set(title=sub, xlabel=xlabel)
        ax.grid(True, alpha=0.3)
    ax_l.set_ylabel(f"measured - model ({units.label(unit)})")
    fig.suptitle(title)
    return fig


def residual_rms_bars(runs: Sequence[str], before: Sequence[float], after: Sequence[float], floor: Sequence[float], *,
                      unit: str = "N", title: str = "Residual per run: base model against the extended model") -> Figure:
    """Per-run RMS residual before and after, on a log scale, with each run's noise floor."""
    fig = _figure(4.4)
    ax = fig.subplots()
    x = np.arange(len(runs))
    ax.bar(x - 0.2, before, width=0.4, color=BEFORE_COLOURS[0], label="base model")
    ax.bar(x + 0.2, after, width=0.4, color=AFTER_COLOURS[0], label="extended by the findings")
    ax.plot(x, floor, "k_", markersize=18, mew=2, label="noise floor")
    ax.set_yscale("log")
    ax.set_xticks(x, runs, rotation=35, ha="right", fontsize=8)
    ax.set(ylabel=f"RMS residual ({units.label(unit)})", title=title)
    ax.grid(True, axis="y", alpha=0.3, which="both")
    ax.legend(fontsize=8)
    return fig


@dataclass(frozen=True)
class ResidualRow:
    """One row of :func:`residual_traces`: the runs of one kind, before and after, drawn
    within ``+/-limit`` (the caller clips the curves there and says so in each panel's note)."""

    title: str
    left: Sequence[Curve]
    right: Sequence[Curve]
    limit: float
    left_note: str = ""
    right_note: str = ""


def residual_traces(rows: Sequence[ResidualRow], *, unit: str = "N", left_title: str = "", right_title: str = "",
                    xlabel: str = "time / run length", title: str = "Residuals") -> Figure:
    """Measured minus modelled output, one row per run kind (its own scale), two columns
    (e.g. the base model and the extended one); a row's note says what was clipped."""
    n = max(len(rows), 1)
    fig = _figure(1.2 + 2.0 * n)
    axes = np.atleast_2d(fig.subplots(n, 2, squeeze=False))
    if not rows:
        _no_data(axes[0, 0], "no run")
        _no_data(axes[0, 1], "no run")
    for i, row in enumerate(rows):
        ax_l, ax_r = axes[i]
        for ax, curves, sub, note in ((ax_l, row.left, left_title, row.left_note), (ax_r, row.right, right_title, row.right_note)):
            for j, c in enumerate(curves):
                ax.plot(c.x, c.y, color=AFTER_COLOURS[j % len(AFTER_COLOURS)], lw=0.5, alpha=0.85,
                        label=(c.label or None) if len(curves) <= 6 else None)
            if len(curves) <= 6 and any(c.label for c in curves) and ax is ax_r:
                ax.legend(fontsize=7, loc="upper right")
            ax.axhline(0.0, color="0.3", lw=0.6)
            ax.set_ylim(-1.05 * row.limit, 1.05 * row.limit)
            ax.grid(True, alpha=0.3)
            if i == 0 and sub:
                ax.set_title(sub, fontsize=10)
            if i == n - 1:
                ax.set_xlabel(xlabel)
            if note:
                ax.text(0.01, 0.02, note, transform=ax.transAxes, fontsize=7, color="0.25", va="bottom",
                        bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none", "pad": 1.0})
        ax_l.set_ylabel(f"{row.title}\n({units.label(unit)})", fontsize=9)
    fig.suptitle(title)
    return fig
