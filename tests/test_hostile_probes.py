"""Regression tests for the hostile-input probes of issue 14 that are not bundle probes:
each gives one clear ``Error:`` line (exit 1 or 2), quickly and without spending memory,
or a correct result. The drive check (piezopress.acquisition.drive_check) is tested here
too, as a property on random drives."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from piezopress.acquisition import drive_check
from piezopress.acquisition.plan import MAX_NAME_CHARS, DriveLimits, parse_plan
from piezopress.acquisition.virtual_rig import VirtualRig
from piezopress.errors import BackendError, PlanError
from piezopress.piezocli.main import cli

ROOT = Path(__file__).resolve().parents[1]
BUNDLE = ROOT / "sample_runs" / "bundle.json"
STEP = ROOT / "sample_runs" / "characterization" / "step-20v.parquet"
LIM = DriveLimits(drive_min_v=-30.0, drive_max_v=150.0, max_sample_rate_hz=100_000.0, slew_limit_v_per_s=1e5)


def invoke(*args: str, seconds: float = 20.0):
    t0 = time.perf_counter()
    res = CliRunner().invoke(cli, list(args))
    took = time.perf_counter() - t0
    assert took < seconds, f"{args[0]} took {took:.1f} s"
    return res


def one_error_line(res, code=1) -> str:
    assert res.exit_code == code, res.output
    assert res.exception is None or isinstance(res.exception, SystemExit), repr(res.exception)
    lines = [ln for ln in res.output.strip().splitlines() if ln.startswith("Error")]
    assert len(lines) == 1 and "Traceback" not in res.output, res.output
    return lines[0]


@pytest.fixture
def readonly_dir(tmp_path):
    """A folder nothing may be written in, even by root (/sys), else a chmod 555 folder."""
    if os.geteuid() == 0:
        if not Path("/sys").is_dir() or os.access("/sys", os.W_OK) and _writable("/sys"):
            pytest.skip("no read-only folder available to root here")
        yield Path("/sys")
        return
    d = tmp_path / "ro"
    d.mkdir()
    d.chmod(0o555)
    yield d
    d.chmod(0o755)


def _writable(folder: str) -> bool:
    try:
        os.mkdir(Path(folder) / "piezopress-probe")
    except OSError:
        return False
    os.rmdir(Path(folder) / "piezopress-probe")
    return True


def write_reference(path: Path, fs: float, n: int = 100, top: float = 100.0) -> Path:
    t = np.arange(n) / fs
    pd.DataFrame({"t_s": t, "reference_n": np.linspace(0.0, top, n)}).to_csv(path, index=False, float_format="%.12g")
    return path


# --------------------------------------------------------------------------- the drive check


def test_drive_check_property_on_random_drives():
    """For 300 random drives: refused exactly when a sample is outside the range, a value is
    non-finite or a step is above the slew limit; the message names the first reason."""
    rng = np.random.default_rng(14)
    for _ in range(300):
        n = int(rng.integers(2, 200))
        v = rng.uniform(-40.0, 160.0, n) if rng.random() < 0.5 else np.cumsum(rng.normal(0.0, 0.5, n))
        if rng.random() < 0.1:
            v[int(rng.integers(n))] = rng.choice([np.nan, np.inf, -np.inf])
        fs = float(rng.choice([1e3, 1e4, 1e5]))
        problems = drive_check.drive_problems(v, fs, LIM)
        finite = np.all(np.isfinite(v))
        in_range = finite and v.min() >= -30.0 - 1e-9 and v.max() <= 150.0 + 1e-9
        slow = finite and np.max(np.abs(np.diff(np.r_[0.0, v]))) * fs <= 1e5 * (1 + 1e-9)
        assert (problems == []) == (finite and in_range and slow), (v, fs, problems)
        if not finite:
            assert "NaN or infinite" in problems[0]
        elif not in_range:
            assert "outside the actuator's range -30 to 150 V" in problems[0]
        elif not slow:
            assert "above the rig's slew limit = 100000 V/s" in problems[0]


@pytest.mark.parametrize("fs", [1e6, 1e9, float("inf"), -1.0])
def test_drive_check_refuses_a_sample_rate_first(fs):
    problems = drive_check.drive_problems(np.zeros(10), fs, LIM)
    assert len(problems) == 1 and "Hz" in problems[0]


def test_every_backend_refuses_through_the_same_check():
    rig = VirtualRig()
    with pytest.raises(drive_check.DriveRefused, match="virtual rig: x: drive refused: drive holds 1 NaN"):
        rig.run(np.r_[0.0, np.nan, 1.0], 1000.0, preload_n=50.0, label="x")
    with pytest.raises(BackendError, match="above the rig's maximum sample rate of 100000 Hz"):
        rig.run(np.zeros(10), 1e6, preload_n=50.0, label="x")


def test_a_reference_at_1_mhz_is_refused_not_made_a_constant_drive(tmp_path):
    ref = write_reference(tmp_path / "ramp.csv", 1e6)
    line = one_error_line(
        invoke("compensate", "--bundle", str(BUNDLE), "--reference", str(ref), "--out", str(tmp_path / "d.csv"))
    )
    assert line == (
        f"Error: {ref}: sample rate 1e+06 Hz is above the rig's maximum sample rate of 100000 Hz; expected at most "
        "100000 Hz (resample the reference, or use a rig file that allows it)"
    )
    assert not (tmp_path / "d.csv").exists()


def test_a_reference_at_1_ghz_is_refused_quickly(tmp_path):
    ref = write_reference(tmp_path / "ramp.csv", 1e9, n=2000)
    line = one_error_line(
        invoke(
            "compensate", "--bundle", str(BUNDLE), "--reference", str(ref), "--out", str(tmp_path / "d.csv"), seconds=10
        )
    )
    assert "sample rate 1e+09 Hz is above the rig's maximum" in line


def test_compensate_refuses_a_drive_outside_the_rigs_range(tmp_path):
    """A bundle whose drive range is wider than the rig's (drive_max_v = 1e9): the drive check
    refuses the 1,047 V drive instead of writing it."""
    b = json.loads(BUNDLE.read_text())
    b["compensation"]["drive_max_v"] = 1e9
    (tmp_path / "b.json").write_text(json.dumps(b))
    ref = write_reference(tmp_path / "ramp.csv", 1000.0, n=2000, top=2000.0)
    res = invoke(
        "compensate", "--bundle", str(tmp_path / "b.json"), "--reference", str(ref), "--out", str(tmp_path / "d.csv")
    )
    if res.exit_code == 0:  # bundle validation (issue 12) may keep the drive in range itself: then it must be in range
        drive = pd.read_csv(tmp_path / "d.csv")["command_v"]
        assert drive.max() <= 150.0 + 1e-9
    else:
        line = one_error_line(res)
        assert ("outside the actuator's range -30 to 150 V" in line) or ("drive_max_v" in line)
        assert not (tmp_path / "d.csv").exists()


# --------------------------------------------------------------------------- what plans and commands cost

PLAN_HEAD = '[plan]\nname = "p"\n'


def proto(name="a", kind="creep", **keys):
    body = "".join(f"{k} = {v}\n" for k, v in keys.items())
    return f'[[protocol]]\nname = "{name}"\nkind = "{kind}"\n{body}'


@pytest.mark.parametrize(
    "keys, words",
    [
        (
            {"hold_s": "1e7", "sample_rate_hz": "100000.0"},
            "1e+12 samples (1e+07 s at 100000 Hz, about 64 TB in memory) exceed the limit of 50000000 samples per run",
        ),
        ({"hold_s": "1e300", "sample_rate_hz": "1000.0"}, "exceed the limit of 50000000 samples per run"),
    ],
)
def test_a_10_to_the_12_sample_plan_is_refused_before_anything_is_built(tmp_path, keys, words):
    p = tmp_path / "plan.toml"
    p.write_text(PLAN_HEAD + proto(**keys))
    t0 = time.perf_counter()
    res = invoke("characterize", "--plan", str(p), "--out", str(tmp_path / "runs"))
    one_error_line(res)  # the plan's problems follow it, one a line
    assert time.perf_counter() - t0 < 10 and words in res.output
    assert not (tmp_path / "runs").exists()


def test_random_peaks_with_a_huge_count_is_refused_without_drawing_them():
    doc = {
        "plan": {"name": "p"},
        "protocol": [
            {
                "name": "t",
                "kind": "triangle",
                "freq_hz": 1.0,
                "sample_rate_hz": 1000.0,
                "random_peaks": {"count": 10**12, "min_v": 10, "max_v": 100, "seed": 1},
            }
        ],
    }
    with pytest.raises(PlanError, match="1e\\+15 samples"):
        parse_plan(doc, DriveLimits())


def test_samples_per_plan_are_bounded_with_the_memory_they_imply():
    protos = [{"name": f"c{i}", "kind": "creep", "hold_s": 400.0, "sample_rate_hz": 100_000.0} for i in range(6)]
    with pytest.raises(PlanError) as err:
        parse_plan({"plan": {"name": "p"}, "protocol": protos}, DriveLimits(max_duration_s=1e9))
    assert (
        "the plan totals 2.4e+08 samples (about 15.4 GB of runs), more than the limit of 200000000 samples per plan"
        in str(err.value)
    )


def test_a_protocol_name_too_long_for_a_file_name_is_refused():
    name = "x" * (MAX_NAME_CHARS + 1)
    with pytest.raises(PlanError, match=f"name of {MAX_NAME_CHARS + 1} characters is longer than {MAX_NAME_CHARS}"):
        parse_plan(
            {
                "plan": {"name": "p"},
                "protocol": [{"name": name, "kind": "creep", "hold_s": 1.0, "sample_rate_hz": 100.0}],
            },
            DriveLimits(),
        )
    ok = {"name": "y" * MAX_NAME_CHARS, "kind": "creep", "hold_s": 1.0, "sample_rate_hz": 100.0}
    assert parse_plan({"plan": {"name": "p"}, "protocol": [ok]}, DriveLimits()).protocols[0].name == ok["name"]


def test_names_differing_only_in_case_are_refused():
    protos = [{"name": n, "kind": "creep", "hold_s": 1.0, "sample_rate_hz": 100.0} for n in ("Step-1", "step-1")]
    with pytest.raises(PlanError, match="'step-1' differs from the earlier protocol 'Step-1' only in case"):
        parse_plan({"plan": {"name": "p"}, "protocol": protos}, DriveLimits())


@pytest.mark.parametrize(
    "option, value, words",
    [
        ("--sample-rate-hz", "1e9", "--sample-rate-hz 1e+09 Hz is above the rig's maximum sample rate of 100000 Hz"),
        ("--duration-s", "1e7", "the check drive lasts 1e+07 s, more than the rig's limit of 3600 s"),
        ("--duration-s", "nan", "expected all positive and finite"),
        ("--amplitude-v", "1e6", "outside the actuator's range -30 to 150 V"),
    ],
)
def test_check_rig_is_bounded_by_the_rigs_limits(option, value, words):
    line = one_error_line(
        invoke("check-rig", "--rig", str(ROOT / "rigs" / "thesis-press.toml"), option, value, seconds=10)
    )
    assert words in line


# --------------------------------------------------------------------------- tracebacks become one line


@pytest.fixture
def extra_string_column(tmp_path):
    t = pq.read_table(STEP)
    t = t.append_column("note", pa.array(["x"] * t.num_rows))
    pq.write_table(t, tmp_path / "extra.parquet")
    return tmp_path / "extra.parquet"


def test_inspect_refuses_an_extra_string_column(extra_string_column):
    line = one_error_line(invoke("inspect", str(extra_string_column)))
    assert (
        line.endswith("extra column 'note' has type str, expected float64 (every column of a run is a number)")
        or "has type object" in line
    )


def test_simulate_refuses_an_extra_string_column(extra_string_column, tmp_path):
    line = one_error_line(
        invoke("simulate", str(extra_string_column), "--bundle", str(BUNDLE), "--out", str(tmp_path / "s.parquet"))
    )
    assert "extra column 'note'" in line


def test_simulate_under_a_missing_folder_creates_it(tmp_path):
    """Like every writer, simulate creates its output's folder (or refuses it in one line) before any work."""
    out = tmp_path / "missing" / "dir" / "s.parquet"
    res = invoke("simulate", str(STEP), "--bundle", str(BUNDLE), "--out", str(out))
    assert res.exit_code == 0, res.output
    assert out.is_file() and res.output.startswith(f"Wrote {out}")


def test_characterize_into_a_read_only_folder_is_one_line_before_the_rig_is_touched(readonly_dir):
    out = readonly_dir / "runs"
    line = one_error_line(invoke("characterize", "--out", str(out)))
    assert line.startswith(f"Error: {out}: cannot write there (")
    assert "expected a folder you may write to" in line


def test_import_into_a_read_only_folder_is_one_line_before_the_source_is_read(readonly_dir, tmp_path):
    src = tmp_path / "m.csv"
    src.write_text("0,0\n1,1\n2,2\n")
    out = readonly_dir / "run.parquet"
    line = one_error_line(
        invoke(
            "import",
            str(src),
            "--out",
            str(out),
            "--col",
            "command_v=1",
            "--col",
            "force_n=2",
            "--sample-rate-hz",
            "10",
        )
    )
    assert line.startswith(f"Error: {readonly_dir}: cannot write there (")


def test_rig_seed_minus_one_is_one_line(tmp_path):
    rig = tmp_path / "rig.toml"
    rig.write_text("[rig]\nseed = -1\n")
    assert (
        one_error_line(invoke("check-rig", "--rig", str(rig)))
        == f"Error: {rig}: [rig] seed = -1: outside the allowed range >= 0"
    )


def test_diagnose_with_an_unknown_cause_is_one_line_exit_2(tmp_path):
    res = invoke(
        "diagnose",
        str(ROOT / "sample_runs" / "characterization"),
        "--bundle",
        str(BUNDLE),
        "--cause",
        "bogus",
        "--out",
        str(tmp_path / "d"),
    )
    line = one_error_line(res, code=2)
    assert "Invalid value for '--cause': 'bogus' is not one of 'amplifier_slew_limit'" in line
    assert not (tmp_path / "d").exists()


# --------------------------------------------------------------------------- what the fuzz test found


def _write_raw_run(path: Path, cols: dict, meta: bytes) -> Path:
    table = pa.table(cols).replace_schema_metadata({"piezopress": meta})
    pq.write_table(table, path)
    return path


def _step_columns(n: int = 100) -> tuple[dict, dict]:
    from piezopress import runformat

    t = np.arange(n) / 1000.0
    return (
        {"t_s": t, "command_v": np.full(n, 10.0), "force_n": np.full(n, 70.0)},
        runformat.make_meta("step", "s", 1000.0, preload_n=50.0),
    )


@pytest.mark.parametrize(
    "change, words",
    [
        (
            lambda c, m: c.update(extra=np.full(len(c["t_s"]), np.nan)),
            "extra column 'extra' has NaN/infinite values; expected finite numbers",
        ),
        (
            lambda c, m: c.update(force_n=c["force_n"] * 1e300),
            "column force_n holds 7e+301 at row 0; expected magnitudes below 1e+12 (no press measures that: a unit or "
            "scale error?)",
        ),
    ],
)
def test_runs_with_non_finite_extras_or_absurd_magnitudes_are_refused(tmp_path, change, words):
    cols, meta = _step_columns()
    change(cols, meta)
    path = _write_raw_run(tmp_path / "r.parquet", cols, json.dumps(meta).encode())
    assert one_error_line(invoke("inspect", str(path))) == f"Error: {path}: {words}"


def test_run_metadata_that_is_not_utf8_is_one_line(tmp_path):
    cols, _ = _step_columns()
    path = _write_raw_run(tmp_path / "r.parquet", cols, b'{"name": "\xff\xfe"}')
    assert "'piezopress' metadata is not UTF-8 text (byte" in one_error_line(invoke("inspect", str(path)))


@pytest.mark.parametrize("kind", [[], {}, 3, True])
def test_a_protocol_kind_of_the_wrong_type_is_a_plan_problem(kind):
    doc = {"plan": {"name": "p"}, "protocol": [{"name": "a", "kind": kind, "hold_s": 1.0, "sample_rate_hz": 100.0}]}
    with pytest.raises(PlanError, match="key 'kind' = .* is unknown; expected one of triangle"):
        parse_plan(doc, DriveLimits())


def test_an_import_scale_that_overflows_is_one_line(tmp_path):
    src = tmp_path / "m.csv"
    src.write_text("0,1e300\n1,2\n2,3\n")
    res = invoke(
        "import",
        str(src),
        "--out",
        str(tmp_path / "r.parquet"),
        "--col",
        "command_v=1",
        "--col",
        "force_n=2",
        "--sample-rate-hz",
        "10",
        "--scale",
        "force_n=1e308",
    )
    assert "scale force_n=1e+308 with offset 0 makes column 2 overflow to infinity" in one_error_line(res)
    assert not (tmp_path / "r.parquet").exists()


def test_a_rig_mode_below_1_rad_s_is_refused(tmp_path):
    rig = tmp_path / "rig.toml"
    rig.write_text("[mode]\nnatural_freq_rad_s = 1e-300\n")
    assert "natural_freq_rad_s = 1e-300: outside the allowed range [1, 1e+07]" in one_error_line(
        invoke("check-rig", "--rig", str(rig))
    )


class _FailsOnSecondRun(VirtualRig):
    def __init__(self):
        super().__init__()
        self.calls = 0

    def run(self, *args, **kwargs):
        self.calls += 1
        if self.calls == 2:
            raise BackendError("rig on fire")
        return super().run(*args, **kwargs)


def test_an_error_after_a_progress_line_starts_a_line_of_its_own(tmp_path, monkeypatch):
    from piezopress.pipelines import characterize as char

    plan = tmp_path / "plan.toml"
    plan.write_text(
        PLAN_HEAD
        + proto("a", hold_s="0.05", sample_rate_hz="1000.0", level_v="10.0")
        + proto("b", hold_s="0.05", sample_rate_hz="1000.0", level_v="10.0")
    )
    monkeypatch.setattr(char, "make_backend", lambda name, rig: _FailsOnSecondRun())
    res = invoke("characterize", "--plan", str(plan), "--out", str(tmp_path / "runs"))
    assert res.exit_code == 1
    assert "\nError: rig on fire" in res.output and res.output.rstrip().endswith("Error: rig on fire")


def test_validate_refuses_references_a_weaker_rig_cannot_reach_before_the_directory_is_made(tmp_path):
    """A rig whose actuator stops at 10 V: the compensator works in the rig's range (issue 22),
    where the 50 N triangle cannot be reached; validate refuses in one line, before any drive
    is played, and creates nothing."""
    rig = tmp_path / "rig.toml"
    rig.write_text(
        (ROOT / "rigs" / "thesis-press.toml").read_text().replace("drive_max_v = 150.0", "drive_max_v = 10.0")
    )
    plan = tmp_path / "v.toml"
    plan.write_text(
        '[plan]\nname = "v"\n[[protocol]]\nname = "tri"\nkind = "triangle"\nfreq_hz = 10.0\ncycles = 1\npeak_n = 50.0\n'
        "sample_rate_hz = 1000.0\n"
    )
    out = tmp_path / "val"
    res = invoke("validate", "--bundle", str(BUNDLE), "--plan", str(plan), "--rig", str(rig), "--out", str(out))
    line = one_error_line(res)
    assert "protocol 'tri':" in line and "cannot be reached on this rig (drive range -30 to 10 V" in line
    assert not out.exists()


@pytest.mark.parametrize(
    "args",
    [
        ["check-rig", "--rig", "rigs/thesis-press.toml", "--sample-rate-hz", "1e9"],
        ["check-rig", "--rig", "rigs/thesis-press.toml", "--duration-s", "1e7"],
        ["characterize", "--plan", "{plan}", "--out", "{tmp}/runs"],
    ],
)
def test_costly_commands_are_refused_under_a_memory_cap(tmp_path, args):
    """In a fresh process whose address space is capped at 1.5 GB above what its imports take,
    the command ends with one Error line (before: killed at 24 GB or a MemoryError traceback)."""
    import subprocess
    import sys

    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN_HEAD + proto(hold_s="1e7", sample_rate_hz="100000.0"))
    args = [a.replace("{plan}", str(plan)).replace("{tmp}", str(tmp_path)) for a in args]
    code = (
        "import resource, sys\n"
        "from piezopress.piezocli.main import cli\n"
        "import piezopress.piezocli.cmd_characterize, piezopress.piezocli.cmd_check_rig, pandas, scipy.signal, "
        "pyarrow.parquet\n"
        "vm = next(int(l.split()[1]) for l in open('/proc/self/status') if l.startswith('VmSize:')) * 1024\n"
        "resource.setrlimit(resource.RLIMIT_AS, (vm + 1500 * 2**20, resource.getrlimit(resource.RLIMIT_AS)[1]))\n"
        "cli(sys.argv[1:])\n"
    )
    if not Path("/proc/self/status").exists():
        pytest.skip("needs /proc to size the cap")
    out = subprocess.run([sys.executable, "-c", code, *args], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert out.returncode == 1, out.stderr[-2000:]
    assert "Traceback" not in out.stderr and "MemoryError" not in out.stderr
    assert [ln for ln in (out.stdout + out.stderr).splitlines() if ln.startswith("Error")], out.stderr
