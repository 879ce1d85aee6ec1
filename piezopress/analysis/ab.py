"""A/B comparison of compensations measured on one press: is one bundle's row better than
another's beyond the spread of repeated measurements?

Every row of the compensated tables is an error (a loop's width, a creep, an overshoot, a
tracking error): lower is better. A difference counts when it is beyond the spread both ways:
every repeat of one bundle beats every repeat of the other (the ranges do not overlap) **and**
Welch's t-test on the repeats gives ``p < alpha``; and it is one a user would feel, at least
:data:`MIN_CHANGE_PCT` of the first bundle's value. Each test alone is too lenient with three
repeats (non-overlapping ranges happen by chance one time in ten; a t-test on two nearly
constant samples calls a difference of a noise step significant; over ten rows a 1 % change
of a steady overshoot passes both now and then). With one repeat nothing is judged: there is
no spread to judge against.

>>> v = judge([1.00, 1.02, 0.99], [0.50, 0.52, 0.49])
>>> v.verdict, round(v.difference, 3)
('better', -0.5)
>>> judge([1.0, 1.2, 0.9], [1.1, 0.95, 1.05]).verdict
'no difference beyond the spread'
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["BETTER", "WORSE", "SAME", "UNJUDGED", "Judged", "judge", "ALPHA", "MIN_CHANGE_PCT"]

BETTER = "better"
WORSE = "worse"
SAME = "no difference beyond the spread"
UNJUDGED = "not judged (one repeat: no spread)"

#: Welch's test's level: a difference with ``p`` at or above it is within the spread.
ALPHA = 0.05
#: The smallest change (percent of the first bundle's value) called better or worse: below it a
#: row is the same to whoever uses the press, however steady the repeats.
MIN_CHANGE_PCT = 5.0


@dataclass(frozen=True)
class Judged:
    """One row, bundle ``b`` against bundle ``a`` (the first, the reference of the comparison)."""

    mean_a: float
    mean_b: float
    spread_a: float  # standard deviation of a's repeats (0 with one)
    spread_b: float
    difference: float  # mean_b - mean_a (negative: b is better, rows being errors)
    p_value: float  # Welch's t-test (NaN: not computed)
    verdict: str

    @property
    def change_pct(self) -> float:
        """The difference as a percentage of a's mean (NaN when a's mean is 0)."""
        return 100.0 * self.difference / self.mean_a if self.mean_a else math.nan


def _finite(values: Sequence[float], what: str) -> np.ndarray:
    v = np.asarray(list(values), dtype=float)
    if v.ndim != 1 or v.size == 0:
        raise ValueError(f"{what}: no repeats; expected at least one measured value")
    return v[np.isfinite(v)]


def judge(a: Sequence[float], b: Sequence[float], *, alpha: float = ALPHA) -> Judged:
    """``b`` against ``a``, each the row's value in every repeat (lower is better); see the module."""
    va, vb = _finite(a, "a"), _finite(b, "b")
    if va.size == 0 or vb.size == 0:
        nan = math.nan
        return Judged(nan, nan, nan, nan, nan, nan, "not measured")
    ma, mb = float(va.mean()), float(vb.mean())
    sa = float(va.std(ddof=1)) if va.size > 1 else 0.0
    sb = float(vb.std(ddof=1)) if vb.size > 1 else 0.0
    d = mb - ma
    if va.size < 2 or vb.size < 2:
        return Judged(ma, mb, sa, sb, d, math.nan, UNJUDGED)
    apart = vb.max() < va.min() or vb.min() > va.max()
    if sa == 0.0 and sb == 0.0:
        p = 0.0 if d != 0.0 else 1.0  # both constant: the ranges alone decide
    else:
        import warnings

        from scipy import stats

        with warnings.catch_warnings():  # nearly equal repeats: scipy warns of precision; p is ~1 or NaN there
            warnings.simplefilter("ignore", RuntimeWarning)
            p = float(stats.ttest_ind(va, vb, equal_var=False).pvalue)
        p = 1.0 if not math.isfinite(p) else p
    felt = abs(d) >= MIN_CHANGE_PCT / 100.0 * abs(ma) if ma else d != 0.0
    if apart and p < alpha and felt:
        verdict = BETTER if d < 0 else WORSE
    else:
        verdict = SAME
    return Judged(ma, mb, sa, sb, d, p, verdict)


@dataclass(frozen=True)
class Candidate:
    """A bundle measured against the base on the press: the extensions it carries and each
    row's verdict against the base."""

    label: str
    causes: tuple[str, ...]
    verdicts: dict[str, str]

    @property
    def wins(self) -> tuple[str, ...]:
        return tuple(r for r, v in self.verdicts.items() if v == BETTER)

    @property
    def losses(self) -> tuple[str, ...]:
        return tuple(r for r, v in self.verdicts.items() if v == WORSE)


@dataclass(frozen=True)
class Recommendation:
    """The bundle to adopt (``label``, ``None``: the base) and, for every extension measured,
    whether it went in and why."""

    label: str | None
    causes: tuple[str, ...]
    reasons: dict[str, str]


def recommend(candidates: Sequence[Candidate], reference: str = "the base") -> Recommendation:
    """Among the measured bundles, the one that wins the most rows against the reference (the
    bundle in use) and loses none beyond the spread (fewer extensions on a tie); the reference
    itself when none does. Only a measured bundle is ever recommended: a combination nobody
    played is not. ``reasons``: for every candidate, by its label, why it was or was not.

    >>> a = Candidate("+delay", ("input_delay",), {"tracking_random": BETTER, "creep": SAME})
    >>> b = Candidate("+slew", ("amplifier_slew_limit",), {"overshoot": BETTER, "creep": WORSE})
    >>> r = recommend([a, b])
    >>> r.label, r.causes
    ('+delay', ('input_delay',))
    >>> r.reasons["+slew"]
    'left out: worse than the base on creep'
    """
    ok = [c for c in candidates if c.wins and not c.losses]
    best = max(ok, key=lambda c: (len(c.wins), -len(c.causes)), default=None)
    reasons: dict[str, str] = {}
    for c in candidates:
        if best is not None and c.label == best.label:
            reasons[c.label] = f"adopted: better than {reference} on {', '.join(c.wins)}, worse on none"
        elif c.losses:
            reasons[c.label] = f"left out: worse than {reference} on {', '.join(c.losses)}"
        elif not c.wins:
            reasons[c.label] = f"left out: no row better than {reference} beyond the spread"
        else:
            reasons[c.label] = f"left out: better on {', '.join(c.wins)}, but {best.label if best else '?'} wins more"
    return Recommendation(best.label if best else None, best.causes if best else (), reasons)


__all__ += ["Candidate", "Recommendation", "recommend"]
