"""What unexplained structure looks like (``residuals.structure_signature``): each signature hidden
in a residual drawn in its own form (a power law in the level, a play operator's branches, a
ring after the step, a log-time settling, lines), never in the regressions' own columns."""

import numpy as np
import pytest

from piezopress.analysis import diagnosis as dg
from piezopress.analysis.diagnosis.residuals import (
    SIGNATURE_MIN_SHARE,
    residual_stats,
    structure_signature,
    unexplained_text,
)

FS = 2000.0


def _triangle(f_hz: float, seconds: float, fs: float = FS, amp: float = 100.0) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(int(seconds * fs)) / fs
    return t, amp * (1.0 - np.abs(((t * f_hz) % 1.0) * 2.0 - 1.0))


def _steps(seconds: float, fs: float = FS) -> tuple[np.ndarray, np.ndarray]:
    """Up to 20, 50, 120, 80 V and back to 0, each held a fifth of the run."""
    t = np.arange(int(seconds * fs)) / fs
    return t, np.array([20.0, 50.0, 120.0, 80.0, 0.0])[np.minimum((5 * t / seconds).astype(int), 4)]


def _play(x: np.ndarray, r: float) -> np.ndarray:
    """A play operator of radius ``r`` (the loop's branches: up and down differ by ~2r)."""
    out = np.empty_like(x)
    z = x[0]
    for i, v in enumerate(x):
        z = min(max(z, v - r), v + r)
        out[i] = z
    return out


def _shape(t, x, residual, fs=FS, noise=0.02, seed=0):
    rng = np.random.default_rng(seed)
    res = residual + rng.normal(0.0, noise, t.size)
    run = dg.RunData("r", "custom", t, x, res, fs)
    return structure_signature(run, res, residual_stats(run, res, noise))


def test_a_static_map_drawn_wrong_follows_the_level():
    t, x = _steps(20.0)
    s = _shape(t, x, 0.4 * (x / 100.0) ** 1.4)
    assert s.kind == "level" and s.level >= 0.9, s


def test_a_loop_drawn_wrong_follows_level_and_direction():
    # the press's loop is wider than the model's: the residual is a play's lag behind the drive
    for f in (0.5, 3.0):
        t, x = _triangle(f, 8.0 / f)
        s = _shape(t, x, 0.05 * (_play(x, 8.0) - x))
        assert s.kind == "loop" and s.loop >= 0.8, (f, s)
        assert s.level < SIGNATURE_MIN_SHARE, s  # the level alone does not draw a loop


def test_a_ring_after_each_step_is_a_transient():
    t, x = _steps(20.0)
    edges = t[np.flatnonzero(np.diff(x)) + 1]
    ring = sum(np.exp(-np.clip(t - e, 0.0, None) / 0.004) * np.sin(2 * np.pi * 700 * (t - e)) * (t >= e) for e in edges)
    s = _shape(t, x, 5.0 * ring, noise=0.005)
    assert s.kind == "transient" and s.transient >= 0.8, s
    assert s.text().startswith("rings at 70"), s.text()  # the ring's peak is a bin or two wide
    assert "Hz in the first moments after each step" in s.text(), s.text()


def test_a_settling_at_rest_is_after_the_step():
    t = np.arange(int(120 * FS)) / FS
    x = np.zeros_like(t)
    s = _shape(t, x, -0.3 * np.log10(1.0 + t / 2.0), noise=0.01)
    assert s.kind == "after_step" and s.after_step >= 0.8, s


@pytest.mark.parametrize("hz,kind", [(37.0, "line"), (45.0, "drive_line")])
def test_lines_are_told_from_the_drives_harmonics(hz, kind):
    # on a 5 Hz triangle: 45 Hz is its 9th harmonic, which the drive holds (locked to it, a shape
    # the cubic per branch cannot draw), 37 Hz is none of them
    t, x = _triangle(5.0, 6.0)
    s = _shape(t, x, 0.5 * np.sin(2 * np.pi * hz * t + 0.3))
    assert s.kind == kind and s.line_hz == pytest.approx(hz, abs=0.3), s


def test_the_signature_does_not_depend_on_how_finely_the_run_is_sampled():
    # the regressions run on block averages; the same physics sampled 10x finer reads the same
    shapes = []
    for fs in (FS, 10 * FS):
        t, x = _triangle(1.0, 8.0, fs=fs)
        shapes.append(_shape(t, x, 0.05 * (_play(x, 8.0) - x), fs=fs))
    assert [s.kind for s in shapes] == ["loop", "loop"], shapes
    assert shapes[1].loop == pytest.approx(shapes[0].loop, abs=0.02), shapes
    assert shapes[1].level == pytest.approx(shapes[0].level, abs=0.02), shapes


def test_the_summary_groups_runs_by_signature_with_their_figures():
    entries = [
        {"run": "step-20v", "signature": "level", "share": 0.77, "line_hz": 0.0, "ratio": 90.0},
        {"run": "step-50v", "signature": "level", "share": 0.95, "line_hz": 0.0, "ratio": 259.0},
        {"run": "hum", "signature": "line", "share": None, "line_hz": 50.0, "ratio": 4.0},
    ]
    text = unexplained_text(entries)
    assert text.startswith("in step-20v, step-50v it follows the drive's level"), text
    assert "77-95 % of the structure, 90-259 x the noise)" in text, text
    assert "in hum it is a line at 50 Hz the drive does not have (4 x the noise)" in text, text


def test_a_line_on_a_multiple_of_a_smooth_drives_frequency_is_not_the_drives():
    # a 0.5 Hz cosine holds no harmonics: a 37 Hz line (74 times its frequency) is not the drive's
    t = np.arange(int(8 * FS)) / FS
    x = 75.0 * (1.0 - np.cos(2 * np.pi * 0.5 * t))
    s = _shape(t, x, 0.5 * np.sin(2 * np.pi * 37.0 * t))
    assert s.kind == "line", s


@pytest.mark.parametrize("k,kinds", [(2, {"loop", "level"}), (7, {"drive_line"})])
def test_a_sines_harmonics_are_the_drives_though_it_holds_none(k, kinds):
    # a loop's nonlinearity makes harmonics from a pure sine (the Aye-Ang record's 1 Hz sine
    # leaves a 2 Hz residual): its 2nd is drawn by the level and direction, its 7th is the drive's
    # line, never one from elsewhere; the residual only 3 times the noise, as on that record
    t = np.arange(int(20 * 200.0)) / 200.0
    x = 1.5 + 1.5 * np.sin(2 * np.pi * 1.0 * t)
    res = 0.3 * np.sin(2 * np.pi * k * t + 0.7)
    s = _shape(t, x, res, fs=200.0, noise=0.3 / np.sqrt(2) / 3.0)
    assert s.kind in kinds, s
    if k == 2:  # the share is of the structure above the noise: the noise does not dilute it
        quiet = _shape(t, x, res, fs=200.0, noise=1e-4)
        loud = _shape(t, x, res, fs=200.0, noise=0.3 / np.sqrt(2))  # as much noise as structure
        assert s.loop >= 0.8, s
        for other in (s, loud):  # read diluted, the loud one's share would halve
            assert other.loop == pytest.approx(quiet.loop, abs=0.12), (other, quiet)


def _entry(run, signature=None, share=None, ratio=5.0):
    e = {"run": run, "rms_n": 1.0, "noise_floor_n": 0.2, "ratio": ratio, "where_s": 0.1, "dominant_freq_hz": 0.0}
    return e | ({"signature": signature, "share": share, "line_hz": 0.0} if signature else {})


def test_the_report_groups_runs_by_signature_and_lists_an_older_diagnosis_run_by_run(tmp_path):
    import json

    from piezopress.pipelines.report_doc import Bullets
    from piezopress.pipelines.report_model import _diagnosis_blocks

    new = [_entry("step-20v", "level", 0.8), _entry("step-50v", "level", 0.9), _entry("rest", "after_step", 0.7)]
    old = [_entry("step-20v"), _entry("rest")]  # written before signatures: no signature in the entries
    texts = []
    for name, entries in (("new", new), ("old", old)):
        d = tmp_path / name
        d.mkdir()
        (d / "diagnosis.json").write_text(json.dumps({"summary": "s", "output_unit": "N", "unexplained": entries}))
        blocks = _diagnosis_blocks(d, [])
        texts.append([item for b in blocks if isinstance(b, Bullets) for item in b.items])
    assert texts[0] == [
        "Unexplained in step-20v, step-50v: it follows the drive's level (the static map drawn wrong there; "
        "80-90 % of the structure, 5 x the noise)",
        "Unexplained in rest: it settles in log time after each step or the run's start (creep or settling the "
        "model lacks; 70 % of the structure, 5 x the noise)",
    ], texts[0]
    assert [t.split(",")[0] for t in texts[1]] == ["Unexplained: step-20v", "Unexplained: rest"], texts[1]


def test_a_transient_is_said_to_ring_only_at_a_line_it_can_hold():
    # a line slower than one cycle in the transient's 20 ms (the hold's slow residual at 1.5 Hz) is not its ring
    from piezopress.analysis.diagnosis.residuals import Structure

    slow = Structure("transient", 0.0, 0.0, 0.0, 0.98, 1.5)
    assert slow.text().startswith("sits in the first moments after each step"), slow.text()
    assert Structure("transient", 0.0, 0.0, 0.0, 0.98, 1025.0).text().startswith("rings at 1025 Hz")


def test_a_rest_read_apart_from_the_model_by_a_constant_is_an_offset_not_a_slow_movement():
    """The third press's rest before its first drive reads 6 N under the model throughout (its
    virgin state at that drive, or the reading's zero): the residual hardly moves about that
    constant, so it is said as an offset with its size, not as something that "moves slowly". A
    wander of the same energy about zero is not an offset, and a settling is still a settling."""
    t = np.arange(int(120 * 100)) / 100.0
    x = np.zeros_like(t)
    wander = 0.3 * np.sin(2 * np.pi * t / 300.0 + 0.4) + 0.1 * np.sin(2 * np.pi * t / 47.0)
    s = _shape(t, x, -6.1 + wander, fs=100.0, noise=0.05)
    assert s.kind == "offset" and s.offset == pytest.approx(-6.0, abs=0.2) and s.offset_share >= 0.95, s
    assert s.text().startswith(f"sits apart from the model by a constant {s.offset:+.2g} N ("), s.text()
    moving = _shape(t, x, 6.0 * np.sin(2 * np.pi * t / 120.0), fs=100.0, noise=0.05)
    assert moving.kind == "slow" and moving.offset_share < SIGNATURE_MIN_SHARE, moving
    settling = _shape(t, x, -2.0 - 0.6 * np.log10(1.0 + t / 2.0), fs=100.0, noise=0.01)
    assert settling.kind == "after_step", settling  # its mean is most of it, but the settling draws how it moves


def test_offsets_are_grouped_with_their_signs_in_the_runs_unit():
    entries = [
        {"run": "rest-before", "signature": "offset", "share": 0.98, "line_hz": 0.0, "ratio": 112.0},
        {"run": "rest", "signature": "offset", "share": 0.9, "line_hz": 0.0, "ratio": 55.0},
    ]
    entries[0] |= {"rms_um": 6.1, "offset_um": -6.1}
    entries[1] |= {"rms_um": 3.0, "offset_um": 2.9}
    text = unexplained_text(entries)
    assert text.startswith("in rest-before, rest it sits apart from the model by a constant -6.1 to +2.9 µm"), text
    assert "90-98 % of the structure, 55-112 x the noise)" in text, text
