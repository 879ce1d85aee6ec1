"""A fleet's key figures compared across presses: robust z from the median and the MAD.

``z = 0.6745 (x - median) / MAD`` (Iglewicz and Hoaglin's modified z-score): a press beyond
:data:`OUTLIER_Z` on a figure is outside the fleet's spread. A categorical figure (the
findings of ``diagnose``) marks a press whose finding most presses do not share.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

#: |robust z| above this: a press outside the fleet's spread (Iglewicz and Hoaglin: 3.5).
OUTLIER_Z = 3.5
#: Fewest presses with a figure for its spread to mean anything.
MIN_PRESSES = 4


@dataclass(frozen=True)
class Spread:
    """A figure over the fleet: how many presses have it, its median, MAD, range."""

    figure: str
    n: int
    median: float
    mad: float
    low: float
    high: float


@dataclass(frozen=True)
class Outlier:
    press: str
    figure: str
    value: float | str
    z: float  # robust z; inf where the fleet's MAD is 0 and the press differs; nan for a categorical figure
    why: str


def robust_z(values: Sequence[float]) -> np.ndarray:
    """Modified z-scores of ``values`` (NaN where a value is missing). A MAD of 0 (most presses
    equal) gives +-inf for a press that differs, 0 for one that does not."""
    x = np.asarray(values, float)
    ok = np.isfinite(x)
    z = np.full(x.size, np.nan)
    if not ok.any():
        return z
    med = float(np.median(x[ok]))
    mad = float(np.median(np.abs(x[ok] - med)))
    if mad > 0:
        z[ok] = 0.6745 * (x[ok] - med) / mad
    else:
        d = x[ok] - med
        differs = np.abs(d) > 1e-12 * max(abs(med), 1.0)
        z[ok] = np.where(differs, np.where(d > 0, np.inf, -np.inf), 0.0)
    return z


def spread(figure: str, values: Sequence[float]) -> Spread:
    x = np.asarray(values, float)
    x = x[np.isfinite(x)]
    if not x.size:
        return Spread(figure, 0, math.nan, math.nan, math.nan, math.nan)
    med = float(np.median(x))
    return Spread(figure, int(x.size), med, float(np.median(np.abs(x - med))), float(x.min()), float(x.max()))


def outliers(
    presses: Sequence[str], figures: Mapping[str, Sequence[float]], findings: Sequence[str] | None = None
) -> list[Outlier]:
    """The presses outside the fleet's spread on each numeric figure (|robust z| > OUTLIER_Z,
    with at least MIN_PRESSES presses having it), and those with a finding that at most a
    quarter of the diagnosed presses share."""
    out = []
    for name, values in figures.items():
        x = np.asarray(values, float)
        if np.count_nonzero(np.isfinite(x)) < MIN_PRESSES:
            continue
        s = spread(name, x)
        for press, v, z in zip(presses, x, robust_z(x)):
            if np.isfinite(v) and abs(z) > OUTLIER_Z:
                side = "above" if v > s.median else "below"
                out.append(Outlier(press, name, float(v), float(z), f"{side} the fleet's median {s.median:.4g}"))
    if findings is not None:
        diagnosed = [(p, f) for p, f in zip(presses, findings) if isinstance(f, str) and f]
        if len(diagnosed) >= MIN_PRESSES:
            sets = {p: {c for c in f.split(";") if c and c != "none"} for p, f in diagnosed}
            for p, causes in sets.items():
                for c in sorted(causes):
                    share = sum(c in s for s in sets.values())
                    if share <= len(sets) / 4:
                        out.append(
                            Outlier(p, "findings", c, math.nan, f"named on {share} of {len(sets)} diagnosed presses")
                        )
    return out
