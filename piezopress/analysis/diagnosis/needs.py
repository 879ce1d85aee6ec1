"""What each cause needs of the runs, and whether the runs offer it (testability and its texts)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from piezopress.analysis import profile
from piezopress.analysis.diagnosis.judging import Context
from piezopress.analysis.diagnosis.model import Model, RunData

if TYPE_CHECKING:
    from piezopress.analysis.diagnosis.cause import Cause


# --------------------------------------------------------------------------- what each cause needs


#: Run kinds whose drive sweeps (with a drive that moves).
SWEEP_KINDS = ("triangle", "sine", "custom")
#: A lag of this many samples ...
LAG_SAMPLES = 4
#: ... is visible on a run when it moves the prediction by this many noise floors (at the
#: 90th percentile of the run's rate): a delay can then be tested on it.
LAG_VISIBLE_FLOORS = 2.0
#: The base fit is called poor when the residual on the runs it was fitted on is this many noise floors.
POOR_FIT_RATIO = 5.0

_KIND_WORDS = {
    "sweep": ("a sweep (triangle/sine)", "sweeps (triangle/sine)"),
    "step": ("a step run", "step runs"),
    "creep": ("a creep run (a step held long)", "creep runs"),
    "rest": ("a rest run (zero drive)", "rest runs"),
    "any": ("a run", "runs"),
    "repeat": (
        "a run played again later in the test (the same drive; its start time recorded gives the rate per hour)",
        "runs played again later in the test (the same drive; their start times recorded give the rate per hour)",
    ),
}


def same_drive(a: RunData, b: RunData) -> bool:
    """Whether ``a`` and ``b`` were driven alike (the same moving drive, rate and length: a repeat)."""
    if a is b or a.fs_hz != b.fs_hz or a.x.size != b.x.size or np.ptp(a.x) <= 0:
        return False
    return bool(np.max(np.abs(a.x - b.x)) <= 1e-6 * float(np.ptp(a.x)))


def _hz(f: float) -> str:
    """A frequency for a person, to three digits (a measured one carries more)."""
    return f"{f / 1e3:.3g} kHz" if f >= 1e3 else f"{f:.3g} Hz"


@dataclass(frozen=True)
class RunSpec:
    """Which runs serve a need: their kind and the least each must offer.

    ``kind``: ``sweep`` (triangle, sine or custom with a moving drive), ``step`` (step runs),
    ``creep``, ``rest`` (a drive that does not move) or ``any``. A sweep's frequency is
    measured from its drive; a moving drive that is no regular sweep counts as a slow sweep,
    as :meth:`Context.sweeps` takes it.
    """

    kind: str
    min_freq_hz: float = 0.0
    max_freq_hz: float = math.inf
    min_fs_hz: float = 0.0
    min_duration_s: float = 0.0  # the run's last time stamp
    channels: tuple[str, ...] = ()  # columns besides command and output ("monitor_v")
    lag_visible: bool = False  # a lag of LAG_SAMPLES samples moves the prediction by LAG_VISIBLE_FLOORS noise floors

    def matches(self, run: RunData, ctx: Context) -> bool:
        moving = bool(np.ptp(run.x) > 0)
        if self.kind == "sweep":
            ok = run.kind in SWEEP_KINDS and moving
            f = run.freq_hz if run.freq_hz is not None else 0.0
            hi = (
                ctx.slow_hz if self.max_freq_hz == profile.QUASI_STATIC_MAX_HZ else self.max_freq_hz
            )  # "slow", as fit takes it
            ok = ok and profile.freq_within(f, self.min_freq_hz, hi)
        elif self.kind == "rest":
            ok = not moving
        elif self.kind == "any":
            ok = True
        elif self.kind == "repeat":
            # two runs of one drive (decided from the drives; start times, where recorded, give the clock)
            ok = any(same_drive(o, run) for o in ctx.runs)
        else:
            ok = run.kind == self.kind
        ok = ok and run.fs_hz >= self.min_fs_hz and float(run.t_s[-1]) >= self.min_duration_s
        if "monitor_v" in self.channels:
            ok = ok and run.monitor is not None
        return bool(ok and (not self.lag_visible or lag_visible(run, ctx)))

    def text(self, plural: bool = False) -> str:
        word = _KIND_WORDS.get(self.kind, (self.kind, self.kind))[int(plural)]
        parts = []
        if self.min_freq_hz > 0:
            parts.append(f"at >= {_hz(self.min_freq_hz)}")
        if math.isfinite(self.max_freq_hz):
            parts.append(f"at <= {_hz(self.max_freq_hz)}")
        if self.min_fs_hz > 0:
            parts.append(f"sampled at >= {_hz(self.min_fs_hz)}")
        if self.min_duration_s > 0:
            parts.append(f"lasting >= {self.min_duration_s:g} s")
        if self.channels:
            parts.append("with " + ", ".join(self.channels))
        if self.lag_visible:
            parts.append(f"whose output moves by {LAG_VISIBLE_FLOORS:g} noise floors within {LAG_SAMPLES} samples")
        return " ".join([word, *parts])


#: Parts of the base model a need may ask of the bundle: what they are, and whether a model has them.
MODEL_PARTS: dict[str, tuple[str, Callable[[Model], bool]]] = {
    "creep": (
        "a creep model of poles in the bundle (fitted with a creep run)",
        lambda m: m.creep is not None and m.creep.form != "log",
    ),
    "mode": ("a mode in the bundle (fitted with a low-amplitude step)", lambda m: bool(m.wn)),
    # a searched plane holds the order too: on the third test press with a second population of
    # domains hidden (its hysteresis_order) the searched base took 16 levels on seeds 0 and 1 (12 on
    # the clean press's seed 0) and drew its sweeps within 6.4-6.7 noise floors (clean 8.5); on seeds
    # 0-3 planes of 16-28 levels beside 12 predicted the sweeps' held-out ends 3-10 % better with the
    # population and 5-6 % better without it: no finer plane tells it from the clean press
    "operators": (
        "a loop of play operators in the bundle (a Preisach plane or Duhem elements are there because the "
        "structure search chose them: what more operators would draw, they hold)",
        lambda m: m.hysteresis.extra is None,
    ),
}


@dataclass(frozen=True)
class Need:
    """One way to test a cause: ``count`` runs, each matching one of ``runs``, not used by
    the base fit if ``independent``, and the parts of the base model listed in ``model``."""

    runs: tuple[RunSpec, ...]
    count: int = 1
    independent: bool = False
    model: tuple[str, ...] = ()

    def select(self, ctx: Context) -> list[RunData]:
        """The runs that serve this need (possibly fewer than ``count``)."""
        runs = [r for r in ctx.runs if any(s.matches(r, ctx) for s in self.runs)]
        return ctx.independent(runs) if self.independent else runs

    def missing_model(self, model: Model) -> list[str]:
        return [MODEL_PARTS[p][0] for p in self.model if not MODEL_PARTS[p][1](model)]

    def met(self, ctx: Context) -> bool:
        return len(self.select(ctx)) >= self.count and not self.missing_model(ctx.model)

    def text(self) -> str:
        if self.count > 1 and len(self.runs) > 1:
            what = f"{self.count} runs among " + " and ".join(s.text(plural=True) for s in self.runs)
        elif self.count > 1:
            what = f"{self.count} {self.runs[0].text(plural=True)}"
        else:
            what = " or ".join(s.text() for s in self.runs)
        if self.independent:
            what += ", not used by the base fit"
        for p in self.model:
            what += f", and {MODEL_PARTS[p][0]}"
        return what


def lag_visible(run: RunData, ctx: Context) -> bool:
    """Whether a lag of :data:`LAG_SAMPLES` samples moves ``run``'s prediction by
    :data:`LAG_VISIBLE_FLOORS` noise floors (90th percentile over the run): a delay of a few
    samples then shows in its residual."""
    p = ctx.pred(run)
    if p.size <= LAG_SAMPLES:
        return False
    move = float(np.percentile(np.abs(p[LAG_SAMPLES:] - p[:-LAG_SAMPLES]), 90))
    return move >= LAG_VISIBLE_FLOORS * ctx.floor.get(run.name, np.inf)


def describe_runs(runs: Sequence[RunData], ctx: Context | None = None, limit: int = 6) -> str:
    """The runs in a few words: kind, drive frequency, sampling, length, and whether the base
    model was fitted on them ("one sine at ~1 Hz (not recorded), 200 Hz sampling, 40.1 s, used by the base fit")."""
    if not runs:
        return "no run"
    groups: dict[tuple, list[RunData]] = {}
    for r in runs:
        moving = bool(np.ptp(r.x) > 0)
        if r.kind in SWEEP_KINDS and moving:
            f = r.estimated_freq_hz()
            freq = f"at {_hz(r.freq_hz)}" if r.freq_hz is not None else f"at ~{f:.2g} Hz (irregular)"
            label = r.kind
        elif not moving:
            freq, label = "", "rest"
        elif r.kind in ("step", "creep"):
            freq, label = f"of {r.step_v:.3g} V", r.kind
        else:
            freq, label = "", r.kind
        long = r.kind in ("creep",) or not moving or r.freq_hz is None
        dur = f"{r.t_s[-1]:.3g} s" if long else ""
        fitted = ctx is not None and ctx.is_fitted(r)
        groups.setdefault((label, freq if r.kind not in ("step",) else "", r.fs_hz, dur, fitted), []).append(r)
    words = []
    for (label, freq, fs, dur, fitted), rs in groups.items():
        n = len(rs)
        noun = label if n == 1 else (f"{label}es" if label.endswith("h") else f"{label}s")
        head = f"{'one' if n == 1 else n} {noun}"
        if label == "step" and n > 1:
            head += " of " + ", ".join(f"{r.step_v:.3g}" for r in sorted(rs, key=lambda r: r.step_v)) + " V"
        elif label == "step":
            head += f" of {rs[0].step_v:.3g} V"
        elif freq:
            head += f" {freq}"
        bits = [head, f"{_hz(fs)} sampling"] + ([dur] if dur else []) + (["used by the base fit"] if fitted else [])
        words.append(", ".join(bits))
    if len(words) > limit:
        words = words[:limit] + [f"and {len(words) - limit} more kinds of run"]
    return "; ".join(words)


@dataclass(frozen=True)
class Testability:
    """Whether a cause can be tested on the runs; if not, what it needs and what the runs offer.

    ``partly``: testable only by a later way of its needs (a drift of the reading on runs whose
    drive moves, where no run rests): its first way, the one that shows it best, is ``best``, and
    ``have`` says what the runs offer against it (a cause not found that way is not ruled out: the
    next plan provides the first way, as for a cause not tested)."""

    cause: str
    testable: bool
    runs: list[str]
    needs: str
    have: str
    partly: bool = False
    best: str = ""

    def as_dict(self) -> dict[str, Any]:
        if self.partly:
            return {"cause": self.cause, "needs": self.best, "have": self.have, "tested_on": self.runs}
        return {"cause": self.cause, "needs": self.needs, "have": self.have}


def testability(cause: Cause, ctx: Context) -> Testability:
    """Whether ``cause`` can be tested on ``ctx``'s runs and model: any of its needs met.

    ``needs`` says every way to test it ("or"), ``have`` what the runs and the bundle offer
    against the first way (the one the next plan provides): where a later way is met and the first
    is not, the cause is testable ``partly``."""
    needs = "; or ".join(n.text() for n in cause.needs) or "nothing"
    for i, n in enumerate(cause.needs):
        if n.met(ctx):
            runs = [r.name for r in n.select(ctx)]
            if i == 0:
                return Testability(cause.id, True, runs, needs, "")
            first = cause.needs[0]
            return Testability(cause.id, True, runs, needs, _have(first, ctx), True, first.text())
    if not cause.needs:
        return Testability(cause.id, True, [r.name for r in ctx.runs], needs, "")
    return Testability(cause.id, False, [], needs, _have(cause.needs[0], ctx))


def _have(first: Need, ctx: Context) -> str:
    """What ``ctx``'s runs and model offer against the need ``first`` (which they do not meet)."""
    have = [describe_runs(ctx.runs, ctx)]
    ok = first.select(ctx)
    kinds = [r for r in ctx.runs if any(s.matches(r, ctx) for s in first.runs)]
    if len(ok) < first.count:
        if kinds and first.independent and len(ok) < len(kinds):
            used = [r.name for r in kinds if ctx.is_fitted(r)]
            have.append(
                f"{', '.join(used)} {'is' if len(used) == 1 else 'are'} of the right kind but used by the base fit"
            )
        elif kinds:
            have.append(f"{len(kinds)} of the {first.count} runs needed")
    have += [f"no {m.split(' (')[0].removeprefix('a ')}" for m in first.missing_model(ctx.model)]
    return "; ".join(have)
