"""Plans: the default plan is valid and complete; every problem is reported at once."""

from pathlib import Path

import numpy as np
import pytest

from piezopress.acquisition.plan import DriveLimits, load_plan, parse_plan
from piezopress.errors import PlanError

ROOT = Path(__file__).resolve().parents[1]
LIMITS = DriveLimits()


def test_default_plan_covers_thesis_tests():
    plan = load_plan(ROOT / "protocols" / "characterize.toml", LIMITS)
    by = {p.name: p for p in plan.protocols}
    freqs = sorted(
        p.params["freq_hz"]
        for p in plan.protocols
        if p.kind == "triangle" and p.params.get("peaks_v") is None and p.params.get("random_peaks") is None
    )
    assert freqs == [0.1, 1.0, 5.0, 10.0, 50.0, 100.0]
    assert by["creep-150v"].params["hold_s"] == 120.0 and by["creep-150v"].params["level_v"] == 150.0
    levels = sorted((p.params["level_v"], p.sample_rate_hz) for p in plan.protocols if p.kind == "step")
    # the thesis's four at 20 kHz, and the 50 V step again at 50 kHz: a chain's delay in samples
    assert levels == [(20.0, 2e4), (50.0, 2e4), (50.0, 5e4), (100.0, 2e4), (150.0, 2e4)]
    # steps resolve a 1 kHz mode: at least 10 samples per period
    assert all(p.sample_rate_hz >= 10_000 for p in plan.protocols if p.kind == "step")
    assert by["triangle-increasing-0.1hz"].params["peaks_v"] == [30.0, 60.0, 90.0, 120.0, 150.0]
    assert by["triangle-random-0.1hz"].params["random_peaks"]["count"] == 6
    assert all(p.preload_n == 50.0 for p in plan.protocols)


def test_the_default_plan_rests_before_its_first_drive_and_after_its_last_to_pin_a_wander():
    """The default plan (stop 76) rests 120 s before the first drive as well as after the last: the two
    rests' starts far enough apart (and no further) for diagnose to fit a wander of the offset between
    them, whether the rig plays the runs back to back or pauses between them as the virtual rig does.
    ``tests/plans/characterize-one-rest.toml`` (``bench_diagnose --plan``: the baseline it is measured
    against) is the plan before, the same less the first rest."""
    import tomllib

    from piezopress.acquisition.virtual_rig import PAUSE_S
    from piezopress.analysis.diagnosis.slow import CLOCK_REST_APART_S, CLOCK_WINDOW_MAX_S

    path = ROOT / "protocols" / "characterize.toml"
    plan = load_plan(path, LIMITS)
    for rest in (plan.protocols[0], plan.protocols[-1]):
        _, v = rest.waveform()
        assert rest.kind == "custom" and not np.any(v) and rest.duration_s >= 120.0, rest.name
    assert not any(p.kind == "custom" for p in plan.protocols[1:-1])
    apart = sum(p.duration_s for p in plan.protocols[:-1])
    pauses = PAUSE_S * (len(plan.protocols) - 1)
    assert CLOCK_REST_APART_S <= apart and apart + pauses <= CLOCK_WINDOW_MAX_S, (apart, pauses)
    default = tomllib.loads(path.read_text(encoding="utf-8"))
    one_rest = tomllib.loads((ROOT / "tests" / "plans" / "characterize-one-rest.toml").read_text(encoding="utf-8"))
    assert one_rest["protocol"] == default["protocol"][1:]
    assert {k: v for k, v in one_rest["plan"].items() if k != "description"} == {
        k: v for k, v in default["plan"].items() if k != "description"
    }


def test_triangle_waveform_reaches_peaks_and_is_deterministic():
    doc = {
        "plan": {"name": "x"},
        "protocol": [
            {
                "name": "t",
                "kind": "triangle",
                "freq_hz": 1.0,
                "sample_rate_hz": 100.0,
                "random_peaks": {"count": 3, "min_v": 10.0, "max_v": 20.0, "seed": 4},
            }
        ],
    }
    p1 = parse_plan(doc, LIMITS).protocols[0]
    t, v = p1.waveform()
    _, v2 = parse_plan(doc, LIMITS).protocols[0].waveform()
    np.testing.assert_array_equal(v, v2)
    assert len(t) == 301 and t[-1] == pytest.approx(3.0)
    peaks = [v[50], v[150], v[250]]
    assert all(10.0 <= pk <= 20.0 for pk in peaks) and v[0] == 0.0 and v[-1] == pytest.approx(0.0)


def test_all_problems_reported_at_once_with_key_names():
    doc = {
        "plan": {"name": "bad", "colour": "red"},
        "protocol": [
            {"name": "a", "kind": "step", "level_v": 200.0, "hold_s": 1.0, "sample_rate_hz": 1000.0},
            {"name": "b", "kind": "triangle", "freq_hz": 10.0, "sample_rate_hz": 50.0},
            {"name": "c", "kind": "wobble", "sample_rate_hz": 1000.0},
            {"name": "d", "kind": "creep", "hold_s": 1.0, "sample_rate_hz": 1e9, "speed": 3},
            {"name": "a", "kind": "step", "hold_s": 1.0, "sample_rate_hz": 1000.0},
        ],
    }
    with pytest.raises(PlanError) as err:
        parse_plan(doc, LIMITS, source="bad.toml")
    text = str(err.value)
    assert text.startswith("bad.toml: ")
    assert "[plan]: unknown key 'colour'" in text
    assert "protocol[1] 'a': drive reaches 200 V, outside the actuator's range 0 to 150 V" in text
    assert "protocol[2] 'b': key 'sample_rate_hz' = 50 is too low" in text
    assert "protocol[3] 'c': key 'kind' = 'wobble' is unknown" in text
    assert "protocol[4] 'd': unknown key 'speed'" in text
    assert "protocol[5] 'a': name 'a' is used by an earlier protocol" in text
    assert len(err.value.problems) == 6


def test_sample_rate_above_backend_limit():
    doc = {"plan": {"name": "x"}, "protocol": [{"name": "s", "kind": "step", "hold_s": 0.1, "sample_rate_hz": 2e6}]}
    with pytest.raises(PlanError, match="sample_rate_hz' = 2e\\+06 is outside 0 to 100000 Hz"):
        parse_plan(doc, LIMITS)


def test_limits_come_from_the_rig():
    # the same plan is fine on a rig allowing 200 V and refused on the default 150 V one
    doc = {
        "plan": {"name": "x"},
        "protocol": [{"name": "s", "kind": "step", "level_v": 180.0, "hold_s": 0.1, "sample_rate_hz": 1000.0}],
    }
    parse_plan(doc, DriveLimits(drive_max_v=200.0))
    with pytest.raises(PlanError, match="180 V"):
        parse_plan(doc, LIMITS)


def test_invalid_toml_is_one_problem(tmp_path):
    f = tmp_path / "p.toml"
    f.write_text("[plan\nname=")
    with pytest.raises(PlanError, match="not valid TOML"):
        load_plan(f, LIMITS)


# --------------------------------------------------------------------------- rig file keys and range errors (issue 12)


def test_rig_keys_lists_every_key_including_those_with_one_bound():
    from click.testing import CliRunner

    from piezopress.piezocli.main import cli

    res = CliRunner().invoke(cli, ["rig-keys"])
    assert res.exit_code == 0, res.output
    assert "seed = 20261121, range >= 0:" in res.output  # a lower bound only: once a TypeError


@pytest.mark.parametrize(
    "text, message",
    [
        ("[rig]\nseed = -1\n", "[rig] seed = -1: outside the allowed range >= 0"),
        ("[rig]\nseed = 1.5\n", "[rig] seed = 1.5: expected int"),
    ],
)
def test_a_rig_value_outside_its_range_is_one_line_naming_it(tmp_path, text, message):
    from click.testing import CliRunner

    from piezopress.piezocli.main import cli

    (tmp_path / "rig.toml").write_text(text)
    res = CliRunner().invoke(cli, ["check-rig", "--rig", str(tmp_path / "rig.toml")])
    assert res.exit_code != 0 and message in res.output and "Traceback" not in res.output, res.output


def test_protocols_copy_writes_the_shipped_plans_and_never_overwrites(tmp_path):
    from click.testing import CliRunner

    from piezopress.piezocli.main import cli

    root = Path(__file__).resolve().parents[1]
    res = CliRunner().invoke(cli, ["protocols", "--copy", str(tmp_path / "plans")])
    assert res.exit_code == 0, res.output
    for name in ("characterize.toml", "validate.toml"):
        assert (tmp_path / "plans" / name).read_text() == (root / "protocols" / name).read_text()
    (tmp_path / "plans" / "characterize.toml").write_text("# edited")
    res = CliRunner().invoke(cli, ["protocols", "--copy", str(tmp_path / "plans")])
    assert res.exit_code != 0 and "already exist" in res.output
    assert (tmp_path / "plans" / "characterize.toml").read_text() == "# edited"


@pytest.mark.parametrize("backend, source", [("virtual", "thesis-press.toml"), ("nidaq", "nidaq-example.toml")])
def test_rig_keys_template_writes_an_editable_rig_file(tmp_path, backend, source):
    from click.testing import CliRunner

    from piezopress.piezocli.main import cli

    root = Path(__file__).resolve().parents[1]
    out = tmp_path / "my-press.toml"
    res = CliRunner().invoke(cli, ["rig-keys", "--template", str(out), "--backend", backend])
    assert res.exit_code == 0, res.output
    assert out.read_text() == (root / "rigs" / source).read_text()
    res = CliRunner().invoke(cli, ["rig-keys", "--template", str(out)])
    assert res.exit_code != 0 and "already exists" in res.output


def test_the_thesis_only_plan_is_the_default_plan_without_its_four_additions():
    """``tests/plans/characterize-thesis-only.toml`` (``bench_diagnose --plan``: the runs a lab with the
    thesis's own protocol brings) is the default plan less the sweep below rest, the 50 kHz step and the
    two rests, every other protocol as the default plan has it (in step with it)."""
    import tomllib

    default = tomllib.loads((ROOT / "protocols" / "characterize.toml").read_text(encoding="utf-8"))
    path = ROOT / "tests" / "plans" / "characterize-thesis-only.toml"
    thesis = tomllib.loads(path.read_text(encoding="utf-8"))
    added = {"rest-before-120s", "triangle-below-rest-0.1hz", "step-50v-50khz", "rest-120s"}
    assert added <= {p["name"] for p in default["protocol"]}
    assert thesis["protocol"] == [p for p in default["protocol"] if p["name"] not in added]
    plan = load_plan(path, LIMITS)
    assert len(plan.protocols) == len(default["protocol"]) - 4
    assert not any(p.kind in ("below_rest", "custom") for p in plan.protocols)


def test_the_foreign_forms_plan_shares_no_form_with_the_default_plan():
    """``tests/plans/characterize-foreign-forms.toml`` (``bench_diagnose --plan``: diagnose judged on runs
    in forms none of our code was written beside) loads within the default limits, names no run as the
    default plan does, sweeps with sines at none of the default's frequencies, and samples its steps at
    one rate none of the default's steps use; its hold returns to rest, and its rest comes first."""
    default = load_plan(ROOT / "protocols" / "characterize.toml", LIMITS)
    plan = load_plan(ROOT / "tests" / "plans" / "characterize-foreign-forms.toml", LIMITS)
    assert not {p.name for p in plan.protocols} & {p.name for p in default.protocols}
    sweeps = [p for p in plan.protocols if p.kind in ("triangle", "sine", "below_rest")]
    assert sweeps and all(p.kind == "sine" for p in sweeps)
    default_hz = {p.params["freq_hz"] for p in default.protocols if "freq_hz" in p.params}
    assert not {p.params["freq_hz"] for p in sweeps} & default_hz
    steps = [p for p in plan.protocols if p.kind == "step"]
    default_step_rates = {p.sample_rate_hz for p in default.protocols if p.kind == "step"}
    assert len({p.sample_rate_hz for p in steps}) == 1 and not {p.sample_rate_hz for p in steps} & default_step_rates
    (hold,) = [p for p in plan.protocols if p.kind == "creep"]
    _, v = hold.waveform()
    assert v[-1] == 0.0 and hold.params["post_s"] > 0
    _, first = plan.protocols[0].waveform()
    assert plan.protocols[0].kind == "custom" and not np.any(first)
