"""The chain on a press it did not make: ``tests/independent_press.py``.

characterize (default plan) -> fit (the ``fit`` command's path) -> validate (default plan)
on a press written apart from the virtual rig, clean, with a 0.5 ms input delay and with
rate-dependent hysteresis. Neither effect matters at 0.1 Hz, so neither may raise the
compensated 0.1 Hz hysteresis by more than 0.3 percentage points (issue 10).
"""

import ast
from pathlib import Path

import numpy as np
import pytest
from independent_press import IndependentPress

from piezopress.acquisition.backend import Backend
from piezopress.acquisition.plan import DriveLimits
from piezopress.analysis import metrics
from piezopress.pipelines import bundle as bundle_mod
from piezopress.pipelines import characterize as char
from piezopress.pipelines import fit as fit_mod
from piezopress.pipelines import summary
from piezopress.pipelines import validate as val_mod

HERE = Path(__file__).resolve().parent
FORBIDDEN = ("rig_physics", "virtual_rig", "rig_config")


def test_the_press_is_written_apart_from_the_virtual_rig():
    tree = ast.parse((HERE / "independent_press.py").read_text(encoding="utf-8"))
    names = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            names += [node.module or ""] + [f"{node.module}.{a.name}" for a in node.names]
    bad = [n for n in names if any(f in n.split(".") for f in FORBIDDEN)]
    assert not bad, bad
    assert any(n.startswith("piezopress.acquisition.backend") for n in names)  # it is a backend, nothing more


def test_the_press_is_a_deterministic_backend():
    press = IndependentPress()
    assert isinstance(press, Backend) and isinstance(press.limits, DriveLimits)
    assert press.describe()["backend"] == press.name
    fs = 500.0
    t = np.arange(0, 20, 1 / fs)
    tri = 150.0 * (1 - np.abs((t * 0.1) % 1 * 2 - 1))
    a = press.run(tri, fs, preload_n=50.0, label="tri")
    b = IndependentPress().run(tri, fs, preload_n=50.0, label="tri")  # the same run on the same press, anew
    c = press.run(tri, fs, preload_n=50.0, label="other")
    again = press.run(tri, fs, preload_n=50.0, label="tri")  # a repeat on this press: new noise, as on a real one
    assert set(a.channels) == {"force_n", "monitor_v"} and a.channels["force_n"].size == tri.size
    np.testing.assert_array_equal(a.channels["force_n"], b.channels["force_n"])
    assert not np.array_equal(a.channels["force_n"], c.channels["force_n"])
    assert not np.array_equal(a.channels["force_n"], again.channels["force_n"])
    assert np.std(a.channels["force_n"] - again.channels["force_n"]) < 3 * press.noise_n  # only the noise differs
    f = a.channels["force_n"]
    assert abs(f[0] - 50.0) < 2.0 and 320.0 < f.max() < 380.0  # ~300 N above a 50 N preload at 150 V
    assert 5.0 <= metrics.max_hysteresis(tri, f).percent <= 12.0


def test_the_press_creeps_and_rings_near_1_khz():
    press = IndependentPress()
    fs = 1000.0
    t = np.arange(0, 60, 1 / fs)
    f = press.run(np.where(t >= 1.0, 150.0, 0.0), fs, preload_n=50.0, label="creep").channels["force_n"]
    early, late = f[int(1.5 * fs) : int(1.6 * fs)].mean(), f[-int(fs) :].mean()
    assert 0.01 < (late - early) / (early - 50.0) < 0.06  # a few % over a minute
    fs = 50_000.0
    t = np.arange(0, 0.05, 1 / fs)
    f = press.run(np.where(t >= 0.005, 20.0, 0.0), fs, preload_n=50.0, label="step").channels["force_n"]
    ring = f[int(0.006 * fs) : int(0.03 * fs)] - f[int(0.04 * fs) :].mean()
    spectrum = np.abs(np.fft.rfft(ring * np.hanning(ring.size), 8 * ring.size))
    peak_hz = np.fft.rfftfreq(8 * ring.size, 1 / fs)[np.argmax(spectrum)]
    assert 850.0 < peak_hz < 1200.0


def _chain(press: IndependentPress, tmp: Path) -> tuple[dict[str, float], dict[str, float]]:
    """Uncompensated and compensated 0.1 Hz max hysteresis (%), by run name."""
    char.characterize(tmp / "char", backend=press)
    fitted = fit_mod.fit_bundle([tmp / "char"], press.limits)  # what `piezopress fit` does
    assert set(fitted.result.sections) == {"hysteresis", "creep", "shaper"}, fitted.result.not_fitted
    bundle_mod.write_document(fitted.doc, tmp / "bundle.json")
    val_mod.validate(tmp / "val", tmp / "bundle.json", backend=press)

    def static(table):
        return {r.run: r.value for r in table.itertuples() if r.metric == "max_hysteresis" and r.run.endswith("0.1hz")}

    return static(summary.characterization_table(tmp / "char")), static(summary.validation_table(tmp / "val"))


EFFECTS = {"clean": {}, "delay": {"input_delay_s": 5e-4}, "rate": {"rate_dependence": 1.0}}


@pytest.fixture(scope="module")
def chains(tmp_path_factory):
    return {name: _chain(IndependentPress(**kw), tmp_path_factory.mktemp(name)) for name, kw in EFFECTS.items()}


@pytest.mark.integration
def test_the_chain_works_on_a_press_it_did_not_make(chains):
    uncompensated, compensated = chains["clean"]
    # measured: uncompensated 9.91 / 8.16 / 9.29 % (full, increasing, random);
    # compensated 1.73 (75 N), 0.83, 0.43, 0.47, 0.44 (increasing), 0.38 % (random)
    assert len(uncompensated) == 4 and len(compensated) == 6  # the default plan's 0.1 Hz runs, one below rest
    assert min(uncompensated.values()) > 7.0
    assert max(compensated.values()) <= 0.3 * min(uncompensated.values())
    assert max(v for k, v in compensated.items() if k != "tri-75n-0.1hz") <= 1.0


@pytest.mark.integration
@pytest.mark.parametrize("effect", ["delay", "rate"])
def test_fast_effects_do_not_leak_into_the_static_compensation(chains, effect):
    # Compensated 0.1 Hz max hysteresis, % (75, 150, 225, 300 N, increasing, random):
    #   clean              1.73 0.83 0.43 0.47 0.44 0.38
    #   delay 0.5 ms       1.74 0.83 0.43 0.47 0.45 0.38   (before the fix: the same)
    #   rate dependence    1.79 0.85 0.40 0.47 0.46 0.37   (before: 3.11 1.12 0.65 0.58 0.54 0.70, the
    #   held step's fast transient fitted as creep by two cancelling poles, passed by the
    #   hysteresis/creep alternation into the static model)
    clean = chains["clean"][1]
    with_effect = chains[effect][1]
    assert set(with_effect) == set(clean)
    worse = {k: round(with_effect[k] - clean[k], 2) for k in clean if with_effect[k] > clean[k] + 0.3}
    assert not worse, f"{effect}: compensated 0.1 Hz hysteresis rose by more than 0.3 points: {worse}"
