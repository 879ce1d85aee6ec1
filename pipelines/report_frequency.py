"""The report's frequency domain: the identified mode's Bode plot over the step runs'
measured response, the shaper's residual vibration against the mode's frequency error,
and the creep model's and its compensator's responses.

The LTI math is :mod:`piezopress.analysis.lti`'s (python-control); the drawing is
:mod:`piezopress.plotting`'s; here the bundle and the runs are turned into what they need.
"""

from __future__ import annotations

import inspect
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from piezopress import plotting, units
from piezopress.analysis import lti
from piezopress.analysis import shaper as S
from piezopress.analysis.bundle import Bundle
from piezopress.errors import PiezopressError
from piezopress.pipelines.report_doc import FigureBlock
from piezopress.pipelines.report_inputs import _Source

#: The shaper's residual curve spans this frequency error either side of the design (fraction).
SENSITIVITY_SPAN = 0.30
#: The mode's Bode plot: from this fraction of the mode's frequency to this multiple of it.
BODE_SPAN = (0.03, 5.0)
#: Points (bands) of the measured response.
BODE_POINTS = 60
#: The creep plot's frequencies (Hz): from a day's period to 10 Hz.
CREEP_FREQ_HZ = (1e-5, 10.0)

_CHOICE = inspect.signature(S.choose_shaper).parameters
#: The frequency error (fraction) and residual limit the bundle's shaper was chosen over
#: (:func:`piezopress.analysis.shaper.choose_shaper`'s defaults, which `fit` uses).
FREQ_ERROR = float(_CHOICE["freq_error"].default)
MAX_RESIDUAL = float(_CHOICE["max_residual"].default)


def _block(name: str, title: str, caption: str, fig) -> FigureBlock:
    return FigureBlock(name, title, caption, plotting.to_png(fig))


@dataclass(frozen=True)
class ModeCheck:
    """How the measured response compares with the mode inside the shaper's design band:
    per step run, the largest ratio |measured| / |model| - 1 and the number of points."""

    run: str
    points: int
    worst_ratio_error: float


def _response(b: lti.Bode, label: str) -> plotting.Response:
    return plotting.Response(b.freq_hz, b.magnitude, b.phase_deg, label)


def mode_figure(
    bundle: dict[str, Any] | None, char: _Source | None, missing: list[str]
) -> tuple[FigureBlock | None, list[ModeCheck]]:
    """The mode's Bode plot (python-control) with the step runs' measured response as points."""
    if bundle is None or "shaper" not in bundle:
        return None, []
    try:
        checked = Bundle.from_dict(bundle).mode
        if checked is None:
            raise PiezopressError("the shaper section holds no mode")
        wn, zeta = checked[0], checked[1]
        mode = bundle["shaper"].get("mode", {})  # how it was identified (the drive used)
        system = lti.mode_system(wn, zeta)
    except (KeyError, TypeError, ValueError, PiezopressError) as exc:
        missing.append(f"The bundle's mode is unreadable ({exc}): the mode's Bode plot is missing.")
        return None, []
    fn = wn / (2 * math.pi)
    drive_col = mode.get("drive_used") or "command_v"
    steps = [r for r in (char.runs.values() if char else []) if r.kind == "step"]
    top = min(BODE_SPAN[1] * fn, 0.45 * min((r.sample_rate_hz for r in steps), default=np.inf))
    f = np.geomspace(BODE_SPAN[0] * fn, top, BODE_POINTS)
    measured, checks = [], []
    band = (fn * (1 - FREQ_ERROR), fn * (1 + FREQ_ERROR))
    model = lti.bode(system, f)
    if char is not None and not steps:
        missing.append(
            "No step run in the characterization: the mode's measured response is missing from its Bode plot."
        )
    for r in steps:
        drive = r.column(drive_col) if r.column(drive_col) is not None else r.command_v
        try:
            m = lti.measured_response(drive, r.output, r.sample_rate_hz, f)
        except PiezopressError as exc:
            missing.append(f"{r.name}: no measured frequency response ({exc}).")
            continue
        k = m.coherent
        # the phase aligned with the model's at the lowest band, then wrapped into [-270, 90) deg
        phase = (m.phase_deg[k] - (m.phase_deg[k][0] - model.phase_deg[k][0]) + 270.0) % 360.0 - 270.0
        measured.append(plotting.Response(f[k], m.magnitude[k], phase, f"{r.name} (measured, {drive_col})"))
        inside = k & (f >= band[0]) & (f <= band[1])
        if np.any(inside):
            checks.append(
                ModeCheck(
                    r.name,
                    int(np.sum(inside)),
                    float(np.max(np.abs(m.magnitude[inside] / model.magnitude[inside] - 1))),
                )
            )
    fig = plotting.bode(
        [_response(model, f"mode: {fn:.0f} Hz, damping {zeta:.3f} (python-control)")],
        measured,
        band_hz=band,
        band_label=f"shaper's design band: +/-{100 * FREQ_ERROR:g} % of the mode",
        marks_hz=[(fn, f"{fn:.0f} Hz")],
        title="The identified mode over the step runs' measured response",
        magnitude_label="|output/drive| / low-f gain (1)",
    )
    inside = (
        "; ".join(f"{c.run}: {c.points} points, within {100 * c.worst_ratio_error:.0f} %" for c in checks)
        or "no measured point"
    )
    caption = (
        f"The mode identified from the steps ({fn:.0f} Hz, damping {zeta:.3f}) as a transfer function, and as points "
        "the "
        f"response each characterization step shows (output over {drive_col} from the runs' FFT, each normalised to "
        "its "
        f"gain at {f[0]:.0f} Hz, phase aligned there). The shaded band is the frequency error the shaper was chosen to "
        f"tolerate: look for the points to follow the line inside it (in the band, |measured/model| - 1: {inside}); "
        "a resonance outside the band would ring through the shaper."
    )
    return _block("mode_bode", "The mode in the frequency domain", caption, fig), checks


def shaper_figure(bundle: dict[str, Any] | None, missing: list[str]) -> FigureBlock | None:
    """Residual vibration of the chosen shaper and the other candidates over +/-30 % frequency error."""
    if bundle is None or "shaper" not in bundle:
        return None
    s = bundle["shaper"]
    try:
        chosen = Bundle.from_dict(bundle).shaper
        if chosen is None:
            raise PiezopressError("the shaper section holds no shaper")
    except (KeyError, TypeError, ValueError, PiezopressError) as exc:
        missing.append(f"The bundle's shaper is unreadable ({exc}): its sensitivity curve is missing.")
        return None
    ratios = np.linspace(1 - SENSITIVITY_SPAN, 1 + SENSITIVITY_SPAN, 241)
    x = 100 * (ratios - 1)
    curves = [
        plotting.Curve(
            x,
            100 * lti.shaper_sensitivity(chosen, ratios),
            f"{chosen.name} ({len(chosen.amplitudes)} impulses, {1e3 * chosen.delay_s:.2f} ms)",
        )
    ]
    for c in s.get("choice", {}).get("candidates", []):
        name = c.get("name")
        if name == chosen.name or name not in S.SHAPERS:
            continue
        other = S.design_shaper(name, chosen.wn, chosen.zeta)
        curves.append(
            plotting.Curve(
                x,
                100 * lti.shaper_sensitivity(other, ratios),
                f"{name} ({len(other.amplitudes)} impulses, {1e3 * other.delay_s:.2f} ms)",
            )
        )
    fig = plotting.shaper_sensitivity(
        curves,
        chosen=chosen.name,
        band=(-100 * FREQ_ERROR, 100 * FREQ_ERROR),
        limit_pct=100 * MAX_RESIDUAL,
        title=f"Input shaper: residual vibration against the mode's frequency error (damping {chosen.zeta:.3f})",
    )
    return _block(
        "shaper_sensitivity",
        "The input shaper's tolerance of a frequency error",
        "Residual vibration left by each candidate shaper when the press's mode is off the identified frequency by the "
        "error on the x axis (at the identified damping; 100 % = no shaper). The bold curve is the chosen design; the "
        f"shaded band is the +/-{100 * FREQ_ERROR:g} % it was chosen over (with +/-50 % damping error), the dotted "
        "line "
        f"the {100 * MAX_RESIDUAL:g} % limit. Look for the bold curve to stay under the line across the band: a longer "
        "shaper tolerates more error at the cost of delay.",
        fig,
    )


def creep_figure(bundle: dict[str, Any] | None, missing: list[str]) -> FigureBlock | None:
    """The creep model ``K_c + C(s)`` and its compensator ``1 / (K_c + C(s))``, as Bode plots."""
    if bundle is None or "creep" not in bundle:
        return None
    try:
        model = Bundle.from_dict(bundle).creep
        plant, comp = lti.creep_system(model), lti.creep_compensator_system(model)
    except (KeyError, TypeError, ValueError, PiezopressError) as exc:
        missing.append(f"The bundle's creep model gives no LTI system ({exc}): its frequency response is missing.")
        return None
    f = np.geomspace(*CREEP_FREQ_HZ, 200)
    bp, bc = lti.bode(plant, f), lti.bode(comp, f)
    product = lti.bode(plant * comp, f)
    fig = plotting.bode(
        [
            _response(bp, f"creep model K_c + C(s) ({model.form}, {plant.nstates} states)"),
            _response(bc, "compensator 1 / (K_c + C(s))"),
            _response(product, "model x compensator"),
        ],
        title="Creep model and its compensator (python-control)",
        magnitude_label="gain (1)",
        log_magnitude=False,
    )
    u = units.label(bundle["hysteresis"]["model"].get("output_unit", units.FORCE)) if "hysteresis" in bundle else "N"
    return _block(
        "creep_bode",
        "The creep model and its compensator in the frequency domain",
        f"Gain and phase of the creep model ({u} out per {u} of the hysteresis model's static prediction) and of its "
        f"compensator, from {CREEP_FREQ_HZ[0]:g} Hz (a period of about a day) to {CREEP_FREQ_HZ[1]:g} Hz. The model's "
        f"gain falls from {bp.magnitude[0]:.4f} (creep settled) to {bp.magnitude[-1]:.4f} (K_c: the instant after a "
        "step); the compensator mirrors it, and their product stays at 1 (look for the flat line: the compensator is "
        "the model's exact inverse, with stable poles).",
        fig,
    )


__all__ = ["mode_figure", "shaper_figure", "creep_figure", "ModeCheck", "FREQ_ERROR", "MAX_RESIDUAL"]
