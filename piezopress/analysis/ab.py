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

The rows of one comparison are judged together (:func:`judge_rows`): Welch's ``p`` must clear
Holm's step-down threshold over the rows, so that two bundles that are the same differ on no
row but one time in twenty, however many rows there are. Judged one by one, ten rows with the
second test press's spreads (1-15 % of the mean) differ somewhere in one A/A comparison in six,
and ``bench/bench_adopt.py`` found a bundle "worse" than itself (+8 % on a loop's width).

Adopting asks more of a loss than of no difference: a bundle may be worse on a row
(:attr:`Judged.possibly_worse`) when its mean is worse by a felt amount and Welch's ``p`` is
below :data:`DOUBT_ALPHA` unadjusted, a loss the repeats do not exclude; :func:`recommend`
leaves such a bundle out.

>>> v = judge([1.00, 1.02, 0.99], [0.50, 0.52, 0.49])
>>> v.verdict, round(v.difference, 3)
('better', -0.5)
>>> judge([1.0, 1.2, 0.9], [1.1, 0.95, 1.05]).verdict
'no difference beyond the spread'
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

__all__ = [
    "BETTER",
    "WORSE",
    "SAME",
    "UNJUDGED",
    "Judged",
    "judge",
    "judge_rows",
    "ALPHA",
    "MIN_CHANGE_PCT",
    "DOUBT_ALPHA",
]

BETTER = "better"
WORSE = "worse"
SAME = "no difference beyond the spread"
UNJUDGED = "not judged (one repeat: no spread)"

#: Welch's test's level: a difference with ``p`` at or above it is within the spread.
ALPHA = 0.05
#: The smallest change (percent of the first bundle's value) called better or worse: below it a
#: row is the same to whoever uses the press, however steady the repeats.
MIN_CHANGE_PCT = 5.0
#: A felt change for the worse with Welch's ``p`` below this (unadjusted) is a loss the repeats do
#: not exclude (:attr:`Judged.possibly_worse`). On the second test press bundles built on the
#: base fit tracked a staircase 11-13 % worse than the fitted one, p = 0.08-0.10 over three
#: repeats, "no difference" by the verdict's rule, and a fresh comparison then found them worse.
DOUBT_ALPHA = 0.2


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

    @property
    def felt(self) -> bool:
        """Whether the difference is one a user would feel (:data:`MIN_CHANGE_PCT` of a's mean)."""
        if not math.isfinite(self.difference):
            return False
        return (
            abs(self.difference) >= MIN_CHANGE_PCT / 100.0 * abs(self.mean_a) if self.mean_a else self.difference != 0
        )

    @property
    def possibly_worse(self) -> bool:
        """``b`` may be worse: worse, or its mean worse by a felt amount with Welch's ``p`` below
        :data:`DOUBT_ALPHA` (a loss the repeats do not exclude)."""
        if self.verdict == WORSE:
            return True
        return self.difference > 0 and self.felt and math.isfinite(self.p_value) and self.p_value < DOUBT_ALPHA

    def doubt(self) -> str:
        """A possible loss in words: the change and its ``p``."""
        return f"{self.change_pct:+.0f} %, p {self.p_value:.2g}"


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


def judge_rows(
    a: Mapping[str, Sequence[float]], b: Mapping[str, Sequence[float]], *, alpha: float = ALPHA
) -> dict[str, Judged]:
    """Each row ``b[row]`` against ``a[row]`` (rows in both), the rows judged together: a row is
    better or worse only when it is by :func:`judge`'s rule **and** its Welch ``p`` clears Holm's
    step-down threshold over the rows judged (``alpha / m`` for the smallest of ``m``, then
    ``alpha / (m - 1)``, ...), so that the chance of any row of two equal bundles being called
    different stays below ``alpha``.

    >>> same = {"loop": [1.0, 1.1, 0.9], "creep": [0.5, 0.52, 0.51]}
    >>> rows = judge_rows(same, {"loop": [0.7, 0.72, 0.69], "creep": [0.2, 0.21, 0.2]})
    >>> [rows[r].verdict for r in ("loop", "creep")]
    ['better', 'better']
    >>> judge([1.0, 1.02, 0.99], [1.1, 1.12, 1.09]).verdict  # one row alone: p = 0.0013
    'worse'
    >>> rows = {f"r{i}": [1.0, 1.02, 0.99] for i in range(120)}
    >>> judge_rows(rows, {**rows, "r0": [1.1, 1.12, 1.09]})["r0"].verdict  # one of 120 rows: needs p < 0.05 / 120
    'no difference beyond the spread'
    """
    rows = [r for r in a if r in b]
    out = {r: judge(a[r], b[r], alpha=alpha) for r in rows}
    tested = sorted((j.p_value, r) for r, j in out.items() if math.isfinite(j.p_value))
    cleared: set[str] = set()
    for k, (p, r) in enumerate(tested):  # Holm: step down until a p misses its threshold
        if p >= alpha / (len(tested) - k):
            break
        cleared.add(r)
    return {
        r: j if j.verdict not in (BETTER, WORSE) or r in cleared else replace(j, verdict=SAME) for r, j in out.items()
    }


@dataclass(frozen=True)
class Candidate:
    """A bundle measured against the base on the press: the extensions it carries, each row's
    verdict against the base, and the rows where it may be worse though not beyond the spread
    (each with its change and ``p``: a loss the repeats do not exclude)."""

    label: str
    causes: tuple[str, ...]
    verdicts: dict[str, str]
    doubts: dict[str, str] = field(default_factory=dict)

    @classmethod
    def judged(cls, label: str, causes: tuple[str, ...], rows: Mapping[str, Judged]) -> Candidate:
        """From each row's :class:`Judged` (:func:`judge_rows`)."""
        doubts = {r: j.doubt() for r, j in rows.items() if j.possibly_worse and j.verdict != WORSE}
        return cls(label, causes, {r: j.verdict for r, j in rows.items()}, doubts)

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
    bundle in use) and on no row is worse or may be worse (:attr:`Candidate.doubts`; fewer
    extensions on a tie); the reference
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
    ok = [c for c in candidates if c.wins and not c.losses and not c.doubts]
    best = max(ok, key=lambda c: (len(c.wins), -len(c.causes)), default=None)
    reasons: dict[str, str] = {}
    for c in candidates:
        if best is not None and c.label == best.label:
            reasons[c.label] = (
                f"adopted: better than {reference} on {', '.join(c.wins)}, on no row worse or possibly worse"
            )
        elif c.losses:
            reasons[c.label] = f"left out: worse than {reference} on {', '.join(c.losses)}"
        elif c.doubts:
            may = ", ".join(f"{r} ({why})" for r, why in c.doubts.items())
            reasons[c.label] = f"left out: may be worse than {reference} on {may}: a loss the repeats do not exclude"
        elif not c.wins:
            reasons[c.label] = f"left out: no row better than {reference} beyond the spread"
        else:
            reasons[c.label] = f"left out: better on {', '.join(c.wins)}, but {best.label if best else '?'} wins more"
    return Recommendation(best.label if best else None, best.causes if best else (), reasons)


__all__ += ["Candidate", "Recommendation", "recommend"]
