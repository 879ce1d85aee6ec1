"""``bench/bench_diagnose.py --record`` keeps, beside each diagnosis, the creep form ``fit --base``
kept and whether its poles agreed with the sweeps: the base a row ran on decides what a slow
residual is measured against (third test press: the press's own minutes of creep is named a log
creep beside poles that saturate, and a hidden log creep is not named beside a spectrum)."""

from __future__ import annotations

import importlib.util
import json
import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _bench():
    spec = importlib.util.spec_from_file_location("bench_diagnose_under_test", ROOT / "bench" / "bench_diagnose.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _base(path: Path, form: str, failed: list[str], candidates: list[dict]) -> Path:
    """A bundle's creep section as ``fit --base`` records its check of the thesis's poles."""
    fit = {"reason": "...", "sweep_check": {"failed": failed}, "candidates": candidates}
    path.write_text(json.dumps({"creep": {"model": {"form": form}, "fit": fit}}), encoding="utf-8")
    return path


def test_the_record_says_which_creep_the_base_kept_and_why(tmp_path):
    bd = _bench()
    label = bd._base_creep
    agree = [{"form": "poles", "agrees_with_sweeps": True}]
    assert label(_base(tmp_path / "a.json", "poles", [], agree)) == "poles"
    disagree = [{"form": "poles", "agrees_with_sweeps": False}]
    assert label(_base(tmp_path / "b.json", "poles", [], disagree)) == "poles (the poles disagree with the sweeps)"
    unfit = ["poles: fit_creep: no creep form gives a stable compensator with plausible elements"]
    spectrum = [{"form": "spectrum", "agrees_with_sweeps": True}]
    assert label(_base(tmp_path / "c.json", "spectrum", unfit, spectrum)) == "spectrum (the poles could not be fitted)"
    assert label(tmp_path / "missing.json") is None
    (tmp_path / "bundle.json").write_text("{}", encoding="utf-8")  # no creep section: nothing to say
    assert label(tmp_path / "bundle.json") is None


def test_a_recorded_row_carries_the_base_creep_of_a_real_base_fit(tmp_path):
    """On the virtual rig's sample runs the thesis's poles fit and agree with the sweeps: the
    row says ``poles``, read from the bundle ``fit --base`` wrote."""
    from piezopress.pipelines import bundle as B
    from piezopress.pipelines import fit as F

    bd = _bench()
    runs = tmp_path / "runs"
    runs.mkdir()
    for n in ("triangle-0.1hz", "creep-150v"):
        shutil.copy(ROOT / "sample_runs" / "characterization" / f"{n}.parquet", runs / f"{n}.parquet")
    B.write_document(F.fit_bundle([runs], base=True).doc, tmp_path / "base.json")
    record = tmp_path / "rows.jsonl"
    bd._record(
        record, ("ours", "none", 3), ("none", ("none",), float("nan")), False, bd._base_creep(tmp_path / "base.json")
    )
    (row,) = [json.loads(line) for line in record.read_text(encoding="utf-8").splitlines()]
    assert row == {
        "rig": "ours",
        "effect": "none",
        "seed": 3,
        "named": ["none"],
        "gain_pct": None,
        "base_creep": "poles",
    }


def test_a_followed_row_reads_back_as_what_the_user_got():
    """``--follow`` records, beside the first diagnosis, the one after the next plan was played;
    ``--matrix-from --follow`` reads that back. Where no plan was written the first diagnosis
    stands (nothing more to run); a row recorded without ``--follow`` has no such matrix."""
    bd = _bench()
    first = {"rig": "third", "effect": "sensor_offset_drift", "seed": 0, "gain_pct": None}
    played = {
        **first,
        "named": ["logarithmic_creep"],
        "followed": {"played": ["rest"], "named": ["sensor_offset_drift"]},
    }
    played["followed"]["gain_pct"] = 41.0
    assert bd._followed_of(played) == ("sensor_offset_drift", ("sensor_offset_drift",), 41.0)
    none = {**first, "named": ["sensor_offset_drift"], "gain_pct": 55.0, "followed": {"played": None}}
    assert bd._followed_of(none) == ("sensor_offset_drift", ("sensor_offset_drift",), 55.0)
    assert bd._followed_of({**first, "named": ["none"]}) is None
    failed = {**first, "named": ["error: ValueError"], "followed": {"played": None}}  # a first diagnosis that failed
    assert bd._followed_of(failed)[1] == ("error: ValueError",)


def test_follow_plays_the_next_plan_on_the_same_press_and_refits_only_where_asked(tmp_path, monkeypatch):
    """:func:`bench_diagnose._follow` does what the plan's own "Then:" lines say: characterize the
    plan on the press the first runs were measured on (not a new draw of it), refit the base on
    both run sets only where the plan lists causes in ``refit_for``, diagnose both run sets."""
    from piezopress.pipelines import bundle as B
    from piezopress.pipelines import diagnose as D
    from piezopress.pipelines import fit as F

    bd = _bench()
    press = object()
    calls: dict[str, list] = {"played": [], "fit": [], "diagnosed": []}

    class Result:
        findings = [type("F", (), {"cause": "sensor_offset_drift", "gain_pct": 40.0})()]

    def played(out, backend, plan, minimal):
        calls["played"].append((backend, plan, minimal))
        return out

    monkeypatch.setattr(bd, "_played", played)
    monkeypatch.setattr(
        F, "fit_bundle", lambda dirs, base: calls["fit"].append(list(dirs)) or type("R", (), {"doc": {}})
    )
    monkeypatch.setattr(B, "write_document", lambda doc, path: None)
    monkeypatch.setattr(
        D, "diagnose", lambda dirs, bundle, out: calls["diagnosed"].append((list(dirs), bundle)) or (Result, None)
    )
    for refit in ([], ["logarithmic_creep"]):
        monkeypatch.setattr(
            D, "next_plan_info", lambda d, r=refit: {"file": "plan.toml", "protocols": ["rest"], "refit_for": r}
        )
        got = bd._follow(tmp_path, press, tmp_path / "char", False, "sensor_offset_drift")
        assert got["named"] == ["sensor_offset_drift"] and got["gain_pct"] == 40.0 and got["refit"] == bool(refit)
    assert [c[0] for c in calls["played"]] == [press, press] and calls["played"][0][1] == "plan.toml"
    assert calls["fit"] == [[tmp_path / "char", tmp_path / "more"]]  # only the second plan asked for a refit
    assert [c[1].name for c in calls["diagnosed"]] == ["base.json", "base-2.json"]
    assert all(c[0] == [tmp_path / "char", tmp_path / "more"] for c in calls["diagnosed"])
    monkeypatch.setattr(D, "next_plan_info", lambda d: {"file": None})
    assert bd._follow(tmp_path, press, tmp_path / "char", False, "x") == {"played": None}
    assert len(calls["played"]) == 2  # no plan: nothing played


@pytest.mark.integration
def test_keep_diagnoses_the_kept_runs_and_base_again_without_characterizing_or_fitting(tmp_path, monkeypatch):
    """``--keep``: the first bench characterizes and fits into the kept case; a later one (changed
    diagnosis code) diagnoses those very runs against that very base, and names what the first did.
    Each case is kept apart by its press, effect, seed, cut metadata and plan."""
    from piezopress.pipelines import fit as F

    bd = _bench()
    runs = tmp_path / "runs"
    runs.mkdir()
    for n in ("triangle-0.1hz", "creep-150v"):
        shutil.copy(ROOT / "sample_runs" / "characterization" / f"{n}.parquet", runs / f"{n}.parquet")
    characterized = []

    def played(out, rig, effect, seed, minimal):
        characterized.append(out)
        return runs, None

    monkeypatch.setattr(bd, "_characterized_on", played)
    case = ("ours", "none", 3, False, False, str(tmp_path / "keep"))
    first = bd.one(case)
    assert len(characterized) == 1 and not first[1][0].startswith("error"), first
    kept = bd.kept_case(tmp_path / "keep", "ours", "none", 3, False)
    assert (kept / "base.json").is_file() and (kept / "runs").read_text(encoding="utf-8") == str(runs)

    def refit(*a, **k):
        raise AssertionError("a kept case is not fitted again")

    monkeypatch.setattr(F, "fit_bundle", refit)
    again = bd.one(case)
    assert len(characterized) == 1 and again[:2] == first[:2] and again[3] == first[3]
    cases = {bd.kept_case(tmp_path / "keep", "ours", "none", 3, m) for m in (False, True, "stamped")} | {
        bd.kept_case(tmp_path / "keep", "ours", "none", 4, False),
        bd.kept_case(tmp_path / "keep", "second", "none", 3, False),
    }
    monkeypatch.setenv(bd.PLAN_ENV, str(ROOT / "tests" / "plans" / "characterize-one-rest.toml"))
    cases.add(bd.kept_case(tmp_path / "keep", "ours", "none", 3, False))
    assert len(cases) == 6


@pytest.mark.integration
def test_a_case_stopped_part_way_is_characterized_again_into_a_fresh_directory(tmp_path, monkeypatch):
    """A bench stopped while a case was characterizing leaves its runs without a base: the next bench
    with ``--keep`` plays that case again, and ``characterize`` refuses a directory that exists (so the
    case read ``error: OutputExistsError`` on every later bench). The partial runs are cleared first."""
    bd = _bench()
    runs = tmp_path / "runs"
    runs.mkdir()
    for n in ("triangle-0.1hz", "creep-150v"):
        shutil.copy(ROOT / "sample_runs" / "characterization" / f"{n}.parquet", runs / f"{n}.parquet")
    kept = bd.kept_case(tmp_path / "keep", "ours", "none", 3, True)
    for part in ("char", "char-minimal"):  # what the stopped bench had written
        (kept / part).mkdir()
        (kept / part / "rest-before-120s.parquet").write_bytes(b"cut short")

    def played(out, rig, effect, seed, minimal):
        assert not out.exists() and not out.with_name(out.name + "-minimal").exists()
        return runs, None

    monkeypatch.setattr(bd, "_characterized_on", played)
    result = bd.one(("ours", "none", 3, True, False, str(tmp_path / "keep")))
    assert not result[1][0].startswith("error"), result
    assert (kept / "base.json").is_file()


def test_an_effect_the_press_cannot_hide_is_refused_before_any_case_runs(monkeypatch, capsys):
    """A misspelt ``--effects`` stops the bench at once, naming the value and the press's
    catalogue, instead of recording an error for every seed after minutes of characterizing."""
    import pytest

    bd = _bench()
    ran = []
    monkeypatch.setattr(bd, "one", lambda args: ran.append(args))
    argv = ["bench_diagnose.py", "--rig", "third", "--no-batch", "--effects"]
    monkeypatch.setattr("sys.argv", [*argv, "sensor_input_delay+drive_coupled_interference"])
    with pytest.raises(SystemExit) as stop:
        bd.main()
    said = str(stop.value)
    assert "sensor_input_delay not hidden by --rig third" in said and "input_delay" in said
    assert "mains_pickup" in said and not ran  # the third press's own catalogue, and nothing run
    monkeypatch.setattr("sys.argv", ["bench_diagnose.py", "--rig", "ours", "--no-batch", "--effects", "none", "hum"])
    with pytest.raises(SystemExit, match="hum not hidden by --rig ours"):
        bd.main()
    assert not ran


def _paired_fakes(bd, monkeypatch, tmp_path):
    """``--paired`` on fakes: characterize copies two sample runs and cuts them as ``--minimal``
    does; ``fit --base`` records the runs it fitted; ``diagnose`` names a delay on the cut runs and
    a delay and a log creep on the full ones, and checks that it meets the base of its own runs."""
    import sys

    from piezopress.pipelines import bundle as B
    from piezopress.pipelines import diagnose as D
    from piezopress.pipelines import fit as F

    sys.path.insert(0, str(ROOT / "tests"))
    from foreign import foreign_dir

    calls: dict[str, list] = {"characterized": [], "fitted": [], "diagnosed": []}

    def played(out, rig, effect, seed, minimal):
        assert minimal is True  # the pair is characterized once, the cut made from it
        calls["characterized"].append(out)
        out.mkdir(parents=True)
        for n in ("triangle-0.1hz", "creep-150v"):
            shutil.copy(ROOT / "sample_runs" / "characterization" / f"{n}.parquet", out / f"{n}.parquet")
        return foreign_dir(out, out.with_name(out.name + "-minimal")), None

    def fit(dirs, base):
        calls["fitted"].append([Path(d) for d in dirs])
        return type("R", (), {"doc": {"runs": [str(d) for d in dirs]}})

    def diagnose(dirs, bundle, out):
        calls["diagnosed"].append(Path(dirs[0]))
        assert json.loads(Path(bundle).read_text(encoding="utf-8"))["runs"] == [str(dirs[0])]  # its own base
        cut = Path(dirs[0]).name.endswith("-minimal")
        causes = ("input_delay",) if cut else ("input_delay", "logarithmic_creep")

        class Result:
            findings = [type("F", (), {"cause": c, "gain_pct": 50.0})() for c in causes]

        return Result, None

    monkeypatch.setattr(bd, "_characterized_on", played)
    monkeypatch.setattr(F, "fit_bundle", fit)
    monkeypatch.setattr(B, "write_document", lambda doc, path: Path(path).write_text(json.dumps(doc)))
    monkeypatch.setattr(D, "diagnose", diagnose)
    return calls


def test_paired_diagnoses_one_characterization_with_its_metadata_and_cut(tmp_path, monkeypatch):
    """``--paired``: the case is characterized once; the runs as characterize wrote them and their
    cut copy are each fitted and diagnosed, each against its own base, and returned (full, cut).
    Kept, a later bench diagnoses both again without characterizing or fitting; a kept full case
    whose runs are not the cut case's is no pair and says so instead of being counted as one."""
    bd = _bench()
    calls = _paired_fakes(bd, monkeypatch, tmp_path)
    keep = tmp_path / "keep"
    full, cut = bd.one_paired(("ours", "input_delay", 3, str(keep)))
    assert full[1] == ("input_delay", "logarithmic_creep") and cut[1] == ("input_delay",)
    assert len(calls["characterized"]) == 1
    char = calls["characterized"][0]
    assert calls["fitted"] == [[char.with_name("char-minimal")], [char]]
    assert calls["diagnosed"] == [char.with_name("char-minimal"), char]
    full_case = bd.kept_case(keep, "ours", "input_delay", 3, False)
    assert Path((full_case / "runs").read_text(encoding="utf-8")) == char and (full_case / "base.json").is_file()

    again = bd.one_paired(("ours", "input_delay", 3, str(keep)))
    assert [r[1] for r in again] == [full[1], cut[1]]
    assert len(calls["characterized"]) == 1 and len(calls["fitted"]) == 2 and len(calls["diagnosed"]) == 4

    (full_case / "runs").write_text(str(tmp_path / "other-runs"), encoding="utf-8")  # runs of another draw
    other, cut_again = bd.one_paired(("ours", "input_delay", 3, str(keep)))
    assert other[1][0].startswith("error: not a pair") and "other-runs" in other[1][0]
    assert cut_again[1] == cut[1]

    none_kept = bd.one_paired(("ours", "none", 4, None))  # without --keep: a temporary pair, as many calls
    assert [r[1] for r in none_kept] == [full[1], cut[1]] and len(calls["characterized"]) == 2


class _InProcess:
    """A process pool that runs its map in this process (the fakes are patched here)."""

    def __init__(self, workers):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def map(self, fn, cases):
        return map(fn, cases)


def test_paired_prints_both_matrices_and_the_rows_more_than_5_points_apart(tmp_path, monkeypatch, capsys):
    """The bench prints the matrix with the metadata, the matrix of the same runs cut, and each
    row's two figures and difference, naming a row more than 5 points apart; both diagnoses are
    recorded, and ``--matrix-from --paired`` prints the same comparison from the record."""
    import pytest

    bd = _bench()
    named = {  # (effect, seed): (with the metadata, cut)
        ("input_delay", 0): (("input_delay",), ("input_delay",)),
        ("input_delay", 1): (("input_delay",), ("input_delay", "logarithmic_creep")),
        ("none", 0): (("none",), ("none",)),
        ("none", 1): (("none",), ("none",)),
    }

    def paired(args):
        rig, effect, seed, keep = args
        return tuple(
            (effect, n, 60.0 if effect != "none" else float("nan"), "poles", None) for n in named[effect, seed]
        )

    monkeypatch.setattr(bd, "one_paired", paired)
    monkeypatch.setattr(bd, "ProcessPoolExecutor", _InProcess)
    record = tmp_path / "rows.jsonl"
    argv = ["bench_diagnose.py", "--rig", "ours", "--no-batch", "--paired", "--seeds", "2"]
    monkeypatch.setattr("sys.argv", [*argv, "--effects", "input_delay", "none", "--record", str(record)])
    bd.main()
    out = capsys.readouterr().out
    assert "with the metadata characterize wrote" in out and "the same runs with the metadata cut" in out
    table = out[out.index("Each row with the metadata and cut") :]
    lines = {ln.split()[0]: ln for ln in table.splitlines()[2:] if ln.strip()}
    assert (
        lines["input_delay"].split()[1:4] == ["100", "50", "-50"] and "more than 5 points apart" in lines["input_delay"]
    )
    assert lines["none"].split()[1:4] == ["100", "100", "+0"] and "apart" not in lines["none"]
    assert "NOT within 5 points on every row: input_delay" in table
    rows = [json.loads(ln) for ln in record.read_text(encoding="utf-8").splitlines()]
    assert len(rows) == 8 and sum(bool(r.get("minimal")) for r in rows) == 4

    monkeypatch.setattr(
        "sys.argv", [*argv[:3], "--paired", "--effects", "input_delay", "none", "--matrix-from", str(record)]
    )
    bd.main()
    again = capsys.readouterr().out
    assert again[again.index("Each row with the metadata and cut") :] == table
    assert "2 seeds (0-1)" in again

    # a record of some rows: the rows it holds within 5 points, the others said as not measured
    monkeypatch.setattr(
        "sys.argv", [*argv[:3], "--paired", "--effects", "none", "amplifier_slew_limit", "--matrix-from", str(record)]
    )
    bd.main()
    part = capsys.readouterr().out
    assert (
        "within 5 points on the 1 of 2 rows diagnosed both ways; not diagnosed both ways: amplifier_slew_limit" in part
    )
    assert "NOT within" not in part

    for bad in (["--minimal"], ["--follow"]):
        monkeypatch.setattr("sys.argv", [*argv, *bad])
        with pytest.raises(SystemExit, match="--paired"):
            bd.main()
    monkeypatch.setattr("sys.argv", ["bench_diagnose.py", "--paired"])  # the Dask batch path: not paired
    with pytest.raises(SystemExit, match="with --no-batch"):
        bd.main()
