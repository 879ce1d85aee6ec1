"""``hysteresis_order`` judges more operators against the base's own operators fitted again."""

import numpy as np

from piezopress.analysis import diagnosis as dg
from piezopress.analysis.diagnosis.causes import hysteresis_order as HO
from piezopress.analysis.hysteresis import PIModel, play_thresholds

# the thesis's 12 plays on a 150 V sweep, five of them pruned by the fit (zero weight): the
# survivors are spaced as 12, not as 7
GRID = play_thresholds(12, 1.0, 150.0)
KEPT = (0, 1, 2, 3, 4, 6, 9)
TRUE = PIModel(
    tuple(GRID[list(KEPT)]),
    (0.49, 0.35, 0.075, 0.04, 0.03, 0.064, 0.02),
    (0.0, 70.0),
    (2.08, -0.12),
    y0=51.0,
)


def _sweeps() -> list[dg.RunData]:
    """Three slow triangles (full, growing, random amplitudes) drawn by :data:`TRUE`, 0.15 N of noise."""
    rng = np.random.default_rng(0)
    fs = 100.0
    t = np.arange(int(30 * fs)) / fs
    tri = 1 - np.abs(((t * 0.1) % 1.0) * 2 - 1)
    drives = {
        "triangle-0.1hz": 150.0 * tri,
        "triangle-increasing-0.1hz": 150.0 * tri * (0.3 + 0.7 * t / t[-1]),
        "triangle-random-0.1hz": 150.0 * tri * np.interp(t, [0, 10, 20, 30], [0.9, 0.5, 1.0, 0.7]),
    }
    out = []
    for name, x in drives.items():
        y = TRUE.forward(x)[0] + rng.normal(0.0, 0.15, t.size)
        out.append(dg.RunData(name, "triangle", t, x, y, fs))
    return out


def _order(runs: list[dg.RunData]) -> dg.Finding:
    """The cause judged with :data:`TRUE` as the base model, every run fitted."""
    ctx = dg.Context(runs, dg.Model(TRUE), frozenset(r.name for r in runs), {r.name: dg.noise_floor(r.y) for r in runs})
    HO._ORDER_MEMO.clear()
    found = HO.cause_hysteresis_order(ctx)
    assert found is not None
    return found


def test_the_base_s_own_operators_are_the_baseline_not_a_coarser_grid():
    """A base whose plays the fit pruned from a finer grid, on sweeps that base draws exactly:
    more operators predict nothing better. Judged against as many evenly spaced plays as the
    base kept (its grid coarsened), they did: on the second test press with a slew limit and a
    drift, 24 % held out (named on every seed, beside both causes) against 7 % now."""
    found = _order(_sweeps())
    assert found.gain_pct < 5.0, found.gain_pct
    assert not found.accepted


def test_a_loop_the_base_s_operators_cannot_draw_is_still_named():
    """The same base on sweeps with a saturating top (the reading flattens by 6 % of the stroke
    at full drive): more dead zones draw it and the base's own operators, refitted, do not."""
    runs = []
    for r in _sweeps():
        top = float(np.max(TRUE.forward(r.x)[0]) - TRUE.y0)
        y = r.y - 0.06 * top * (r.x / 150.0) ** 4
        runs.append(dg.RunData(r.name, r.kind, r.t_s, r.x, y, r.fs_hz))
    found = _order(runs)
    assert found.accepted and found.gain_pct > 40.0, found.gain_pct
