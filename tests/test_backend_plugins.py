"""Backends as plug-ins (issue 21): found by entry-point name or ``module:Class`` in a rig
file, made from the whole rig document, checked by the conformance kit
(:func:`piezopress.testing.check_backend`) that a lab runs on its own backend."""

from __future__ import annotations

import json
import re
import sys
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from piezopress.acquisition.backend import Measurement, registered_backends
from piezopress.acquisition.plan import DriveLimits
from piezopress.acquisition.virtual_rig import VirtualRig
from piezopress.errors import BackendError, ConfigError
from piezopress.piezocli.main import cli
from piezopress.pipelines import characterize as char
from piezopress.testing import RULES, BackendConformanceError, check_backend

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent
sys.path.insert(0, str(TESTS))

import independent_press as ip  # noqa: E402
from test_nidaq import EXAMPLE, backend_with  # noqa: E402


def _readme_example() -> str:
    """The minimal example backend of the README (the block after 'A minimal backend')."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    block = re.search(r"A minimal backend.*?```python\n(.*?)```", text, re.S)
    assert block, "README.md has no 'A minimal backend' example"
    return block.group(1)


# --------------------------------------------------------------------------- the kit on our backends


def test_the_virtual_rig_passes_the_kit():
    assert check_backend(VirtualRig()) == list(RULES)


def test_the_second_test_press_passes_the_kit():
    assert check_backend(ip.clean_press(np.random.default_rng(0))) == list(RULES)


def test_the_nidaq_backend_on_a_fake_board_passes_the_kit():
    from piezopress.acquisition.daq_config import load_daq_rig

    backend, _ = backend_with(load_daq_rig(EXAMPLE))
    assert check_backend(backend, preload_n=60.0) == list(RULES)


def test_the_readme_example_backend_passes_the_kit():
    ns: dict = {}
    exec(compile(_readme_example(), "README example", "exec"), ns)  # noqa: S102 - the documented example, run as written
    assert check_backend(ns["LinearPress"]({"press": {"n_per_v": 2.0}})) == list(RULES)


# --------------------------------------------------------------------------- broken backends fail, naming the rule


class _Good:
    """A correct backend to break one rule at a time."""

    name = "good"

    def __init__(self):
        self.output_v = 0.0

    @property
    def limits(self):
        return DriveLimits(drive_min_v=0.0, drive_max_v=100.0, max_sample_rate_hz=10_000.0)

    def describe(self):
        return {"backend": self.name}

    def run(self, command_v, sample_rate_hz, *, preload_n, label, progress=None):
        x = np.asarray(command_v, float)
        if x.max() > self.limits.drive_max_v:
            raise BackendError(f"drive {x.max():g} V above {self.limits.drive_max_v:g} V")
        n = x.size
        half = n // 2
        self.output_v = float(x.max())  # playing: the drive is up
        if progress is not None:
            try:
                progress(0.5)
            except KeyboardInterrupt as exc:
                self.zero_output()
                exc.measurement = Measurement({"force_n": 2.0 * x[:half]}, complete=False, reason="interrupted")
                raise
        self.zero_output()
        return Measurement({"force_n": 2.0 * x})

    def zero_output(self):
        self.output_v = 0.0


class _NoLimits(_Good):
    limits = None


class _BadDescribe(_Good):
    def describe(self):
        return {"when": object()}


class _ShortChannels(_Good):
    def run(self, command_v, sample_rate_hz, **kw):
        m = super().run(command_v, sample_rate_hz, **kw)
        return Measurement({"force_n": m.channels["force_n"][:-1]})


class _StaysUp(_Good):
    def zero_output(self):
        pass


class _PlaysAnything(_Good):
    def run(self, command_v, sample_rate_hz, **kw):
        self.output_v = 0.0
        return Measurement({"force_n": np.asarray(command_v, float)})


class _LosesData(_Good):
    def run(self, command_v, sample_rate_hz, *, preload_n, label, progress=None):
        if progress is not None:
            progress(0.5)  # Ctrl-C passes through: what was measured is lost
        return super().run(command_v, sample_rate_hz, preload_n=preload_n, label=label)


class _ClockStands(_Good):
    clock_s = 0.0  # a simulation whose clock never moves: its runs would be recorded at one time


class _ClockUnset(_Good):
    clock_s = None


@pytest.mark.parametrize(
    "broken, rule",
    [
        (_NoLimits, "limits"),
        (_BadDescribe, "describe"),
        (_ShortChannels, "channels"),
        (_StaysUp, "ends-at-zero"),
        (_PlaysAnything, "refused-drive"),
        (_LosesData, "cut-short"),
        (_ClockStands, "clock"),
        (_ClockUnset, "clock"),
    ],
)
def test_a_broken_backend_fails_the_kit_naming_the_rule(broken, rule):
    assert check_backend(_Good()) == list(RULES)
    with pytest.raises(BackendConformanceError) as err:
        check_backend(broken())
    assert err.value.rule == rule and f"backend rule {rule!r} broken" in str(err.value)


# --------------------------------------------------------------------------- the registry


def test_our_backends_are_registered_under_the_entry_point_group():
    names = registered_backends()
    assert names["virtual"].endswith("virtual_rig:VirtualRig") and names["nidaq"].endswith("nidaq:NidaqBackend")


def test_a_rig_file_naming_an_unknown_backend_or_a_missing_module_is_one_line(tmp_path):
    rig = tmp_path / "rig.toml"
    rig.write_text('[rig]\nbackend = "nosuchpkg.press:Press"\n')
    with pytest.raises(ConfigError) as err:
        char.make_backend(None, rig)
    assert "cannot import module 'nosuchpkg.press'" in str(err.value) and str(rig) in str(err.value)
    rig.write_text('[rig]\nbackend = "json:NoSuchClass"\n')
    with pytest.raises(ConfigError, match="module 'json' has no 'NoSuchClass'"):
        char.rig_limits(rig)


def _ok(*args) -> str:
    """``piezopress ARGS`` through the command line; its output, asserting it exited 0."""
    res = CliRunner().invoke(cli, [str(a) for a in args])
    assert res.exit_code == 0, res.output
    return res.output


def _report(tmp_path: Path, *more) -> str:
    """``piezopress report`` of the characterization, validation and bundle under ``tmp_path``."""
    return _ok(
        "report",
        "--characterization",
        tmp_path / "char",
        "--validation",
        tmp_path / "val",
        "--bundle",
        tmp_path / "b.json",
        *more,
    )


def _plugin_press(tmp_path: Path) -> Path:
    """A backend written outside the package: a module beside its rig file, wrapping the
    second test press, configured from its own [press] section."""
    (tmp_path / "labpress.py").write_text(
        textwrap.dedent(
            f"""
            import sys
            sys.path.insert(0, {str(TESTS)!r})
            from independent_press import CLEAN, IndependentPress
            from piezopress.errors import ConfigError

            class LabPress(IndependentPress):
                name = "labpress"

                def __init__(self, document):
                    press = document.get("press", {{}})
                    unknown = sorted(set(press) - {{"seed", "mode_hz", "input_delay_s"}})
                    if unknown:
                        raise ConfigError("rig file", [f"[press] {{k}}: unknown key" for k in unknown])
                    super().__init__(**{{**CLEAN, **press}})
            """
        )
    )
    rig = tmp_path / "labpress.toml"
    rig.write_text('[rig]\nbackend = "labpress:LabPress"\n\n[press]\nseed = 11\nmode_hz = 1010.0\n')
    return rig


def test_a_plugin_in_a_folder_beside_its_rig_file_is_made_from_the_document(tmp_path):
    rig = _plugin_press(tmp_path)
    backend = char.make_backend(None, rig)
    assert backend.name == "labpress" and backend.mode_hz == 1010.0
    assert char.rig_limits(rig) == backend.limits
    assert check_backend(backend) == list(RULES)
    rig.write_text('[rig]\nbackend = "labpress:LabPress"\n\n[press]\ncolour = "red"\n')
    with pytest.raises(ConfigError) as err:
        char.make_backend(None, rig)
    assert "[press] colour: unknown key" in str(err.value) and str(rig) in str(err.value)


TINY_PLAN = """
[plan]
name = "tiny"
preload_n = 50.0

[[protocol]]
name = "triangle-2hz"
kind = "triangle"
freq_hz = 2.0
cycles = 1
sample_rate_hz = 1000.0
"""


def test_runs_of_a_plugin_press_name_the_rig_file_that_made_it(tmp_path):
    """A plug-in's describe() knows nothing of its rig file: the runs recorded the press as
    "Rig ? (file ?" in the report, with no digest to tell one press from another."""
    from piezopress import runformat
    from piezopress.pipelines.report_verdict import _rig_name
    from piezopress.pipelines.sources import rig_identity

    rig = _plugin_press(tmp_path)
    plan = tmp_path / "tiny.toml"
    plan.write_text(TINY_PLAN)
    char.characterize(tmp_path / "char", plan_path=plan, rig_path=rig)
    (run,) = [runformat.read_run(f) for f in sorted((tmp_path / "char").glob("*.parquet"))]
    assert run.meta["rig"]["source"] == str(rig) and run.meta["rig"]["backend"] == "labpress"
    own = char.make_backend(None, rig).describe()
    assert run.meta["rig"]["config"] == own["config"]  # the press's own description kept where it has one
    assert _rig_name(run.meta) == "labpress" and rig_identity(run.meta) is not None
    # where it has none, the rig file's document is the configuration
    del own["config"]
    doc = {"rig": {"backend": "labpress:LabPress"}, "press": {"seed": 11, "mode_hz": 1010.0}}
    assert char.rig_description(type("Bare", (), {"describe": lambda self: dict(own)})(), rig)["config"] == doc
    manifest = json.loads((tmp_path / "char" / "manifest.json").read_text())
    assert manifest["rig"]["source"] == str(rig)
    # a backend handed over in code was made from no file: nothing is said of one
    char.characterize(tmp_path / "given", plan_path=plan, backend=char.make_backend(None, rig))
    (given,) = [runformat.read_run(f) for f in sorted((tmp_path / "given").glob("*.parquet"))]
    assert "source" not in given.meta["rig"] and _rig_name(given.meta) == "labpress"


@pytest.mark.slow
def test_a_backend_written_outside_the_package_runs_the_whole_chain(tmp_path):
    """Issue 21's acceptance: check-rig, characterize, fit, validate and report through a
    module in a temporary folder named in a rig file."""
    rig = _plugin_press(tmp_path)

    _ok("check-rig", "--rig", rig)
    _ok("characterize", "--rig", rig, "--out", tmp_path / "char")
    _ok("fit", tmp_path / "char", "--rig", rig, "--out", tmp_path / "b.json")
    _ok("validate", "--bundle", tmp_path / "b.json", "--rig", rig, "--out", tmp_path / "val")
    _ok("fit", tmp_path / "char", "--rig", rig, "--base", "--out", tmp_path / "base.json")
    out = _ok("compare", tmp_path / "base.json", tmp_path / "b.json", "--rig", rig, "--out", tmp_path / "cmp")
    assert "b vs base" in out and (tmp_path / "cmp" / "compare.csv").is_file()
    out = _ok(
        "diagnose",
        tmp_path / "char",
        "--bundle",
        tmp_path / "base.json",
        "--gain",
        "--rig",
        rig,
        "--out",
        tmp_path / "diag",
    )
    assert "Recommended:" in out
    rec = json.loads((tmp_path / "diag" / "recommended_bundle.json").read_text())["recommendation"]
    found = json.loads((tmp_path / "diag" / "diagnosis.json").read_text())["findings"]
    if found:  # measured on the press; never worse than the base on any row beyond the spread
        assert "The gain on the press" in out
        assert rec["measured"] is True and rec["press"] == str(rig)
        table = pd.read_csv(tmp_path / "diag" / "gain-on-press" / "compare.csv")
        if rec["bundle"] != "base":
            assert "worse" not in set(table[table["bundle"] == rec["bundle"]]["verdict"])
    else:
        assert rec["measured"] is False and rec["bundle"] == "base" and "nothing to extend" in out
    out = _report(
        tmp_path,
        "--diagnosis",
        tmp_path / "diag",
        "--comparison",
        tmp_path / "cmp",
        "--out",
        tmp_path / "rep",
    )
    assert (tmp_path / "rep" / "report.html").is_file(), out
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "## Comparison on the press" in md


@pytest.mark.slow
def test_the_third_press_runs_the_chain_through_a_rig_file(tmp_path):
    """Issue 21: the third test press (a Preisach stack, written apart from both others) as a
    lab's plug-in named in a rig file: characterize, fit (the family search picks the plane),
    validate and report from the command line, the report naming the model family."""
    (tmp_path / "preisachpress.py").write_text(
        textwrap.dedent(
            f"""
            import sys
            sys.path.insert(0, {str(TESTS)!r})
            from third_press import ThirdPress
            from piezopress.errors import ConfigError

            class PreisachPress(ThirdPress):
                def __init__(self, document):
                    press = document.get("press", {{}})
                    unknown = sorted(set(press) - {{"seed"}})
                    if unknown:
                        raise ConfigError("rig file", [f"[press] {{k}}: unknown key" for k in unknown])
                    super().__init__(**press)
            """
        )
    )
    rig = tmp_path / "preisach.toml"
    rig.write_text('[rig]\nbackend = "preisachpress:PreisachPress"\n\n[press]\nseed = 5\n')

    assert check_backend(char.make_backend(None, rig)) == list(RULES)
    _ok("characterize", "--rig", rig, "--out", tmp_path / "char")
    out = _ok("fit", tmp_path / "char", "--rig", rig, "--out", tmp_path / "b.json")
    # no monitor channel: the chain read from the steps (its filters' lags in series, and a delay) is
    # said, and the default plan's steps at two rates tell the delay's part in samples (its decimation filter's)
    assert "the drive chain identified from the steps is a second-order low-pass at" in out, out
    assert "steps at two sample rates told its delay apart: 2." in out, out
    doc = json.loads((tmp_path / "b.json").read_text())
    assert doc["hysteresis"]["model"]["family"] == "pi_preisach_plane", doc["hysteresis"]["fit"]["family_reason"]
    _ok("validate", "--bundle", tmp_path / "b.json", "--rig", rig, "--out", tmp_path / "val")
    _report(tmp_path, "--out", tmp_path / "rep")
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "Hysteresis (Prandtl-Ishlinskii + Preisach plane)" in md
    assert "Model family: Prandtl-Ishlinskii plus a Preisach plane" in md


@pytest.mark.slow
def test_fit_names_a_slew_limit_inside_the_chain_of_a_press_without_monitor(tmp_path):
    """The third test press with a 100 mA current limit into its 6 uF stack (16.7 V/ms: every
    step slews), no monitor channel: `fit` says the chain it identified, the slew before the
    chain's low-pass, and the mode the steps' ringing shows (the press's 780 Hz; through the
    slew alone 500-550 Hz at damping 0.5-0.6)."""
    from third_press import ThirdPress

    out_dir = tmp_path / "char"
    char.characterize(out_dir, backend=ThirdPress(seed=5, current_limit_ma=100.0))
    out = _ok("fit", out_dir, "--out", tmp_path / "b.json")
    assert "the drive chain identified from the steps is a slew limit of" in out, out
    assert "before a second-order low-pass" in out, out
    mode = json.loads((tmp_path / "b.json").read_text())["shaper"]["mode"]
    # its delay's part in samples is not split off: the slew alone's lag is led, as before
    assert "steps at two sample rates told" not in out and mode["drive_chain"].get("delay_samples") is None, out
    assert mode["drive_chain"]["form"] == "slew_lowpass_delay"
    assert mode["drive_chain"]["slew_v_per_s"] == pytest.approx(100e-3 / 6e-6, rel=0.2)
    assert mode["natural_freq_rad_s"] == pytest.approx(2 * np.pi * 780.0, rel=0.05)
    assert mode["damping"] < 0.1
