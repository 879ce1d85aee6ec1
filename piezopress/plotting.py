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
from collections.abc import Sequence
from dataclasses import dataclass

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


def residual_rms_bars(
    runs: Sequence[str],
    before: Sequence[float],
    after: Sequence[float],
    floor: Sequence[float],
    *,
    unit: str = "N",
    title: str = "Residual per run: base model against the extended model",
) -> Figure:
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
    #: shaded stretches of the x axis, each ``(start, stop, label)`` (e.g. the held-out end of a fit)
    spans: Sequence[tuple[float, float, str]] = ()
    #: whether the right column shares the left's x axis (and so its spans)
    spans_right: bool = True


def residual_traces(
    rows: Sequence[ResidualRow],
    *,
    unit: str = "N",
    left_title: str = "",
    right_title: str = "",
    xlabel: str = "time / run length",
    title: str = "Residuals",
) -> Figure:
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
        for ax, curves, sub, note in (
            (ax_l, row.left, left_title, row.left_note),
            (ax_r, row.right, right_title, row.right_note),
        ):
            for j, c in enumerate(curves):
                ax.plot(
                    c.x,
                    c.y,
                    color=AFTER_COLOURS[j % len(AFTER_COLOURS)],
                    lw=0.5,
                    alpha=0.85,
                    label=(c.label or None) if len(curves) <= 6 else None,
                )
            if len(curves) <= 6 and any(c.label for c in curves) and ax is ax_r:
                ax.legend(fontsize=7, loc="upper right")
            for x0, x1, label in row.spans if ax is ax_l or row.spans_right else ():
                ax.axvspan(x0, x1, color="#f5d76e", alpha=0.35, lw=0)
                if label:
                    ax.text(
                        (x0 + x1) / 2,
                        0.97,
                        label,
                        transform=ax.get_xaxis_transform(),
                        ha="center",
                        va="top",
                        fontsize=7,
                        color="0.25",
                    )
            ax.axhline(0.0, color="0.3", lw=0.6)
            ax.set_ylim(-1.05 * row.limit, 1.05 * row.limit)
            ax.grid(True, alpha=0.3)
            if i == 0 and sub:
                ax.set_title(sub, fontsize=10)
            if i == n - 1:
                ax.set_xlabel(xlabel)
            if note:
                ax.text(
                    0.01,
                    0.02,
                    note,
                    transform=ax.transAxes,
                    fontsize=7,
                    color="0.25",
                    va="bottom",
                    bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none", "pad": 1.0},
                )
        ax_l.set_ylabel(f"{row.title}\n({units.label(unit)})", fontsize=9)
    fig.suptitle(title)
    return fig


# --------------------------------------------------------------------------- loops with their error


@dataclass(frozen=True)
class LoopPanel:
    """One column of :func:`loops_with_error`: a loop (``loop``: measured output against
    ``xlabel``'s quantity, with ``model`` drawn over it and, when ``ideal``, the line
    output = x) above its error (``error``: the deviation, zoomed to its own scale)."""

    title: str
    loop: Curve | None
    error: Curve | None
    xlabel: str
    error_label: str
    model: Curve | None = None
    ideal: bool = False
    compensated: bool = False


def loops_with_error(panels: Sequence[LoopPanel], *, unit: str = "N", title: str = "") -> Figure:
    """Loops side by side (top row) with each one's error zoomed below it (bottom row).

    The top row shares the output's unit (``unit``); each error axis has its own scale
    so a 0.05 % residual loop is as visible as a 5 % one.
    """
    n = max(len(panels), 1)
    fig = _figure(5.4 if n <= 2 else 5.0)
    axes = np.atleast_2d(fig.subplots(2, n, squeeze=False, height_ratios=(3, 2)))
    q, u = units.quantity(unit), units.label(unit)
    if not panels:
        _no_data(axes[0, 0], "no loop")
    for i, p in enumerate(panels):
        ax, ax_e = axes[0, i], axes[1, i]
        colour = AFTER_COLOURS[0] if p.compensated else BEFORE_COLOURS[0]
        if p.loop is not None:
            if p.ideal:
                lo, hi = float(np.nanmin(p.loop.x)), float(np.nanmax(p.loop.x))
                ax.plot([lo, hi], [lo, hi], color="0.55", ls="--", lw=0.8, label=f"ideal: {q} = reference")
            ax.plot(p.loop.x, p.loop.y, color=colour, lw=0.8, label=p.loop.label or "measured")
            if p.model is not None:
                ax.plot(p.model.x, p.model.y, color="k", lw=0.7, ls=(0, (4, 2)), label=p.model.label or "model")
            if i == 0 or n <= 2:
                ax.legend(fontsize=7 if n > 2 else 8, loc="upper left")
        else:
            _no_data(ax, "no run")
        if p.error is not None:
            ax_e.plot(p.error.x, p.error.y, color=colour, lw=0.7)
            ax_e.axhline(0.0, color="0.4", lw=0.6)
        else:
            _no_data(ax_e, "no run")
        ax.set_title(p.title, fontsize=9 if n > 2 else 10)
        ax_e.set_xlabel(p.xlabel, fontsize=8 if n > 2 else 10)
        ax_e.set_ylabel(p.error_label, fontsize=8 if n > 2 else 10)
        if i == 0:
            ax.set_ylabel(f"measured {q} ({u})")
        for a in (ax, ax_e):
            a.grid(True, alpha=0.3)
            if n > 2:
                a.tick_params(labelsize=7)
    if title:
        fig.suptitle(title)
    return fig


def creep_relative(before: Sequence[Curve], after: Sequence[Curve], *, t_ss_s: float = 1.0) -> Figure:
    """Creep after ``t_ss_s`` on a log time axis, relative to the step (%): curves ``x``
    time after the step (s), ``y`` ``100 (F - F_ss) / (F_ss - F_0)``, so a 2 % creep fills
    the axis instead of a sliver on top of the step."""
    fig = _figure(4.2)
    ax = fig.subplots()
    for curves, colours in ((before, BEFORE_COLOURS), (after, AFTER_COLOURS)):
        for i, c in enumerate(curves):
            ax.plot(c.x, c.y, color=colours[i % len(colours)], lw=0.9, label=c.label or None)
    if before or after:
        ax.set_xscale("log")
        ax.axhline(0.0, color="0.4", lw=0.7)
        ax.legend(fontsize=8, loc="upper left")
    else:
        _no_data(ax, "no creep run")
    ax.set(
        title=f"Creep from {t_ss_s:.2g} s after the step",
        xlabel="time after the step (s, log)",
        ylabel="(F - F_ss) / (F_ss - F_0)  (%)",
    )
    ax.grid(True, which="both", alpha=0.3)
    return fig


@dataclass(frozen=True)
class Stair:
    """One stair of :func:`tracking_stairs`: its reference level and the error on it."""

    level: float
    mean: float
    low: float
    high: float


def tracking_stairs(
    t_s: np.ndarray,
    reference: np.ndarray,
    measured: np.ndarray,
    stairs: Sequence[Stair],
    *,
    title: str = "Staircase tracking",
    unit: str = "N",
    evaluated_from: float | None = None,
) -> Figure:
    """Reference and measured output against time (top), and per stair the mean error
    with whiskers from its minimum to its maximum (bottom): one bar per stair instead of a
    barcode of samples."""
    q, u = units.quantity(unit), units.label(unit)
    fig = _figure(5.8)
    ax_f, ax_e = fig.subplots(2, 1, height_ratios=(3, 2))
    ax_f.plot(t_s, reference, color="0.3", lw=1.0, ls="--", label="reference")
    ax_f.plot(t_s, measured, color=AFTER_COLOURS[0], lw=0.8, label="measured (compensated)")
    ax_f.set(title=title, xlabel="time (s)", ylabel=f"{q} ({u})")
    ax_f.legend(fontsize=8, loc="upper left")
    if stairs:
        x = np.arange(len(stairs))
        mean = np.array([s.mean for s in stairs])
        # a stair read on one code has mean == min == max, but for the mean's last bit: never a negative whisker
        err = np.clip(np.array([[s.mean - s.low for s in stairs], [s.high - s.mean for s in stairs]]), 0.0, None)
        ax_e.bar(x, mean, width=0.6, color=AFTER_COLOURS[0], alpha=0.8, label="mean error on the stair")
        ax_e.errorbar(x, mean, yerr=err, fmt="none", ecolor="k", capsize=3, lw=0.8, label="min to max")
        ax_e.set_xticks(x, [f"{s.level:.0f}" for s in stairs], fontsize=8)
        ax_e.axhline(0.0, color="0.4", lw=0.6)
        ax_e.legend(fontsize=8, loc="best")
    else:
        _no_data(ax_e, "no stair evaluated")
    where = f" (evaluated from {evaluated_from:g} {u} above the preload)" if evaluated_from is not None else ""
    ax_e.set(xlabel=f"stair: reference {q} ({u}){where}", ylabel=f"{q} - reference ({u})")
    for ax in (ax_f, ax_e):
        ax.grid(True, alpha=0.3)
    return fig


# --------------------------------------------------------------------------- frequency domain


@dataclass(frozen=True)
class Response:
    """A frequency response to draw: ``freq_hz``, ``magnitude`` (ratio) and ``phase_deg``."""

    freq_hz: np.ndarray
    magnitude: np.ndarray
    phase_deg: np.ndarray
    label: str = ""


def bode(
    models: Sequence[Response],
    measured: Sequence[Response] = (),
    *,
    band_hz: tuple[float, float] | None = None,
    band_label: str = "",
    marks_hz: Sequence[tuple[float, str]] = (),
    title: str = "",
    magnitude_label: str = "magnitude (1)",
    log_magnitude: bool = True,
) -> Figure:
    """Magnitude (log) and phase against frequency (log): models as lines, measured
    responses as points; ``band_hz`` shaded (e.g. the band a shaper was designed for),
    ``marks_hz`` vertical lines with their labels."""
    fig = _figure(5.6)
    ax_m, ax_p = fig.subplots(2, 1, sharex=True)
    for i, m in enumerate(models):
        c = "k" if i == 0 else AFTER_COLOURS[i % len(AFTER_COLOURS)]
        ax_m.plot(m.freq_hz, m.magnitude, color=c, lw=1.2, label=m.label or None)
        ax_p.plot(m.freq_hz, m.phase_deg, color=c, lw=1.2)
    for i, m in enumerate(measured):
        c = BEFORE_COLOURS[i % len(BEFORE_COLOURS)]
        ax_m.plot(m.freq_hz, m.magnitude, "o", ms=3.5, color=c, label=m.label or None)
        ax_p.plot(m.freq_hz, m.phase_deg, "o", ms=3.5, color=c)
    for ax in (ax_m, ax_p):
        if band_hz is not None:
            ax.axvspan(*band_hz, color="#f5d76e", alpha=0.35, lw=0, label=(band_label or None) if ax is ax_m else None)
        for f, text in marks_hz:
            ax.axvline(f, color="0.3", lw=0.8, ls=":")
            if ax is ax_m:
                ax.annotate(
                    text,
                    (f, 1.0),
                    xycoords=("data", "axes fraction"),
                    xytext=(3, -12),
                    textcoords="offset points",
                    fontsize=8,
                    color="0.2",
                )
        ax.set_xscale("log")
        ax.grid(True, which="both", alpha=0.3)
    if log_magnitude:
        ax_m.set_yscale("log")
    ax_m.set(ylabel=magnitude_label, title=title)
    ax_p.set(xlabel="frequency (Hz)", ylabel="phase (deg)")
    if models or measured:
        ax_m.legend(fontsize=8, loc="lower left")
    return fig


def shaper_sensitivity(
    curves: Sequence[Curve],
    *,
    chosen: str,
    band: tuple[float, float] | None = None,
    limit_pct: float | None = None,
    title: str = "",
) -> Figure:
    """Residual vibration (%) against the mode's frequency relative to the design
    frequency (%): one curve per shaper, the chosen one bold; ``band`` (relative, %)
    shaded: the frequency error the choice was judged over; ``limit_pct`` a dotted line."""
    fig = _figure(4.2)
    ax = fig.subplots()
    for i, c in enumerate(curves):
        bold = c.label.split(" ")[0] == chosen
        ax.plot(
            c.x,
            c.y,
            color="k" if bold else AFTER_COLOURS[(i + 1) % len(AFTER_COLOURS)],
            lw=2.0 if bold else 0.9,
            label=(c.label + " (chosen)") if bold else c.label,
        )
    if band is not None:
        ax.axvspan(*band, color="#f5d76e", alpha=0.35, lw=0, label=f"judged over {band[0]:+g} to {band[1]:+g} %")
    if limit_pct is not None:
        ax.axhline(limit_pct, color="0.4", ls=":", lw=0.9, label=f"{limit_pct:g} % limit")
    ax.axvline(0.0, color="0.5", lw=0.6)
    ax.set(xlabel="mode frequency error, relative to the design (%)", ylabel="residual vibration (%)", title=title)
    ax.grid(True, alpha=0.3)
    if curves:
        ax.legend(fontsize=8, loc="upper center")
    else:
        _no_data(ax, "no shaper")
    return fig


@dataclass(frozen=True)
class DrivePanel:
    """One panel of :func:`drive_and_reference`: the reference (left axis, ``unit``) and
    the compensated drive (right axis, V) against time (``time_unit``)."""

    title: str
    t: np.ndarray
    reference: np.ndarray
    drive: np.ndarray
    time_unit: str = "s"
    measured: np.ndarray | None = None


def drive_and_reference(panels: Sequence[DrivePanel], *, unit: str = "N", title: str = "") -> Figure:
    """What the compensator sends: per panel the reference and the measured output (left
    axis) and the drive (right axis, V) over the same time."""
    n = max(len(panels), 1)
    fig = _figure(4.2)
    axes = np.atleast_1d(fig.subplots(1, n, squeeze=False)[0])
    q, u = units.quantity(unit), units.label(unit)
    if not panels:
        _no_data(axes[0], "no compensated run")
    for ax, p in zip(axes, panels):
        ax.plot(p.t, p.reference, color="0.3", ls="--", lw=1.0, label=f"reference ({u})")
        if p.measured is not None:
            ax.plot(p.t, p.measured, color=AFTER_COLOURS[0], lw=0.8, label=f"measured ({u})")
        ax.set(title=p.title, xlabel=f"time ({p.time_unit})", ylabel=f"{q} ({u})")
        ax.grid(True, alpha=0.3)
        ax2 = ax.twinx()
        ax2.plot(p.t, p.drive, color=BEFORE_COLOURS[1], lw=0.9, label="drive (V)")
        ax2.set_ylabel("drive command_v (V)", color=BEFORE_COLOURS[3])
        lines = ax.get_lines() + ax2.get_lines()
        ax.legend(lines, [ln.get_label() for ln in lines], fontsize=8, loc="upper left")
    if title:
        fig.suptitle(title)
    return fig


def fleet_strips(
    figures: Sequence[tuple[str, Sequence[str], Sequence[float]]], flagged: set[tuple[str, str]] | None = None
) -> Figure:
    """One strip per key figure of a fleet: each press a dot (``(title, presses, values)`` per
    figure); a press outside the fleet's spread (``flagged``: ``(press, title)``) drawn red and
    named, the median a grey line."""
    flagged = flagged or set()
    n = max(len(figures), 1)
    fig = _figure(0.9 + 0.75 * n)
    axes = fig.subplots(n, 1, squeeze=False)[:, 0]
    for ax, (title, presses, values) in zip(axes, figures):
        x = np.asarray(values, float)
        ok = np.isfinite(x)
        ax.set_yticks([])
        ax.set_title(title, fontsize=9, loc="left")
        if not ok.any():
            _no_data(ax, "no press has this figure")
            continue
        jitter = np.linspace(-0.25, 0.25, x.size) if x.size > 1 else np.zeros(1)
        ax.axvline(float(np.median(x[ok])), color="0.6", lw=1)
        for p, v, j in zip(presses, x, jitter):
            if not np.isfinite(v):
                continue
            out = (p, title) in flagged
            ax.plot(v, j, "o", ms=5, color="#c0392b" if out else "#34495e", alpha=0.9)
            if out:
                ax.annotate(p, (v, j), textcoords="offset points", xytext=(4, 4), fontsize=8, color="#c0392b")
        ax.set_ylim(-0.6, 0.6)
    return fig


def compare_dots(
    rows: Sequence[tuple[str, Sequence[tuple[str, Sequence[float]]]]],
    verdicts: dict[tuple[str, str], str] | None = None,
) -> Figure:
    """One panel per row of a comparison on the press: each bundle a line of dots (one per
    repeat) and its mean a bar, lower is better; a bundle judged better than the first drawn
    green, worse red (``verdicts``: ``(row title, bundle)`` -> ``"better"``/``"worse"``)."""
    verdicts = verdicts or {}
    colour = {"better": "#27ae60", "worse": "#c0392b"}
    n = max(len(rows), 1)
    fig = _figure(0.9 + 0.85 * n)
    axes = fig.subplots(n, 1, squeeze=False)[:, 0]
    for ax, (title, bundles) in zip(axes, rows):
        ax.set_title(title, fontsize=9, loc="left")
        labels = [b for b, _ in bundles]
        if not labels:
            _no_data(ax, "not measured")
            continue
        for i, (label, values) in enumerate(bundles):
            v = np.asarray(values, float)
            v = v[np.isfinite(v)]
            c = colour.get(verdicts.get((title, label), ""), "#34495e")
            if v.size:
                ax.plot(v, np.full(v.size, i), "o", ms=4, color=c, alpha=0.8)
                ax.plot([v.mean(), v.mean()], [i - 0.3, i + 0.3], color=c, lw=2)
        ax.set_yticks(range(len(labels)))
        ax.set_yticklabels(labels, fontsize=8)
        ax.set_ylim(len(labels) - 0.5, -0.5)
    return fig
