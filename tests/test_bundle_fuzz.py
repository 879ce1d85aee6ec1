"""A seeded fuzz test of corrupted bundles (issue 14), in-process through click's CliRunner.

Each case corrupts the sample bundle (a number made NaN, inf, huge, negative, zero or of the
wrong type; a key or section removed or of the wrong type; a list cut short or scaled; units
swapped; the file's text cut or garbled) and runs ``compensate``, ``simulate`` and
``validate`` (a one-protocol plan) on it, and every fourth case ``diagnose`` (one cause).
Allowed outcomes: success with every written value finite, or one line ``Error: ...`` with
exit 1 or 2. Never a traceback, never a non-finite value in a written file.
"""

from __future__ import annotations

import copy
import json
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from piezopress import runformat
from piezopress.piezocli.main import cli

ROOT = Path(__file__).resolve().parents[1]
BASE = json.loads((ROOT / "sample_runs" / "bundle.json").read_text())
STEP = ROOT / "sample_runs" / "characterization" / "step-20v.parquet"
CASES = 240
SEED = 20261122
#: A guard against a hang (a solver or a loop that never ends on a corrupted bundle), not a
#: speed target (those are bench/'s): it takes about 10 s on an unloaded 2-core machine.
TIME_LIMIT_S = 120.0

BAD_VALUES = [
    float("nan"),
    float("inf"),
    float("-inf"),
    1e300,
    -1e300,
    1e-300,
    0,
    -1,
    1e9,
    -1e9,
    "12",
    None,
    True,
    [],
    {},
    [1, "x"],
]


def _leaves(obj, path=()):
    """Every (path, value) of a JSON document, lists and mappings included."""
    yield path, obj
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _leaves(v, path + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _leaves(v, path + (i,))


#: Where corruption matters most: the models and settings (other leaves are picked too).
MODEL_PREFIXES = (
    ("hysteresis", "model"),
    ("creep", "model"),
    ("shaper", "shaper"),
    ("shaper", "mode"),
    ("compensation",),
)


def _parent(doc, path):
    d = doc
    for p in path[:-1]:
        d = d[p]
    return d


def corrupt(rng: np.random.Generator) -> tuple[str, bytes]:
    """A corrupted bundle: (what was done, the file's bytes)."""
    doc = copy.deepcopy(BASE)
    leaves = [(p, v) for p, v in _leaves(doc) if p]
    model = [(p, v) for p, v in leaves if any(p[: len(m)] == m for m in MODEL_PREFIXES)]
    kind = rng.choice(["value", "value", "value", "delete", "scale", "truncate", "section", "unit", "text", "top"])
    if kind in ("value", "delete", "scale", "truncate"):
        pool = model if rng.random() < 0.85 else leaves
        if kind == "scale":
            pool = [(p, v) for p, v in pool if isinstance(v, (int, float)) and not isinstance(v, bool)]
        if kind == "truncate":
            pool = [(p, v) for p, v in pool if isinstance(v, list) and v]
        path, value = pool[int(rng.integers(len(pool)))]
        parent = _parent(doc, path)
        if kind == "value":
            new = BAD_VALUES[int(rng.integers(len(BAD_VALUES)))]
            parent[path[-1]] = new
            what = f"{'.'.join(map(str, path))} = {new!r}"
        elif kind == "delete":
            if isinstance(parent, list):
                parent.pop(path[-1])
            else:
                del parent[path[-1]]
            what = f"{'.'.join(map(str, path))} deleted"
        elif kind == "scale":
            factor = float(rng.choice([-1.0, 0.5, 2.0, 10.0, 1e3, 1e6]))
            parent[path[-1]] = value * factor
            what = f"{'.'.join(map(str, path))} x {factor:g}"
        else:
            parent[path[-1]] = value[: int(rng.integers(len(value)))]
            what = f"{'.'.join(map(str, path))} cut to {len(parent[path[-1]])}"
    elif kind == "section":
        name = str(rng.choice(["hysteresis", "creep", "shaper", "compensation"]))
        doc[name] = [None, 1, "x", {}, []][int(rng.integers(5))]
        what = f"section {name} = {doc[name]!r}"
    elif kind == "unit":
        m = doc["hysteresis"]["model"]
        m["output_unit"] = str(rng.choice(["um", "mm", "n", ""]))
        if rng.random() < 0.5 and m["output_unit"] == "um":
            m["y0_um"] = m.pop("y0_n")
        what = f"hysteresis unit {m['output_unit']!r}"
    elif kind == "top":
        doc = [[doc], 1, "bundle", None][int(rng.integers(4))]
        what = f"top level {type(doc).__name__}"
    else:
        text = json.dumps(doc).encode()
        cut = int(rng.integers(1, len(text)))
        choice = int(rng.integers(3))
        if choice == 0:
            return f"text cut at {cut}", text[:cut]
        if choice == 1:
            return "text garbled", text[:cut] + bytes(rng.integers(0, 256, 16, dtype=np.uint8)) + text[cut:]
        return "empty file", b""
    return what, json.dumps(doc).encode()  # NaN/inf written as JSON's NaN/Infinity, as a careless script would


def _finite_csv(path: Path) -> bool:
    return bool(np.all(np.isfinite(pd.read_csv(path).to_numpy(dtype=float))))


def _finite_run(path: Path) -> bool:
    run = runformat.read_run(path)
    return all(np.all(np.isfinite(run.data[c].to_numpy(dtype=float))) for c in run.data.columns)


def _finite_json(path: Path) -> bool:
    def refuse(_):
        raise ValueError

    try:
        json.loads(path.read_text(), parse_constant=refuse)
    except ValueError:
        return False
    return True


def _check(res, what: str, outputs: list[tuple[Path, callable]]) -> str:
    exc = res.exception
    assert exc is None or isinstance(exc, SystemExit), f"{what}: traceback {exc!r}\n{res.output}"
    if res.exit_code == 0:
        for path, finite in outputs:
            if path.is_file():
                assert finite(path), f"{what}: non-finite value written to {path.name}"
        return "ok"
    lines = res.output.strip().splitlines()
    assert res.exit_code in (1, 2) and lines and lines[-1].startswith("Error: "), (
        f"{what}: exit {res.exit_code}: {res.output}"
    )
    assert len([ln for ln in lines if ln.startswith("Error: ")]) == 1 and len(lines[-1]) < 600, f"{what}: {res.output}"
    return "error"


def test_corrupted_bundles_give_finite_output_or_one_line(tmp_path):
    t = np.arange(1000) / 1000.0
    ref = tmp_path / "ref.csv"
    pd.DataFrame({"t_s": t, "reference_n": 60.0 * (1 - np.cos(2 * np.pi * t))}).to_csv(ref, index=False)
    plan = tmp_path / "tiny.toml"
    plan.write_text(
        '[plan]\nname = "tiny"\npreload_n = 50.0\n\n[[protocol]]\nname = "step-30n"\nkind = "step"\nlevel_n = 30.0\n'
        "hold_s = 0.05\nsample_rate_hz = 5000.0\n"
    )
    rng = np.random.default_rng(SEED)
    runner = CliRunner()
    outcomes = {"ok": 0, "error": 0}
    start = time.perf_counter()
    for i in range(CASES):
        what, data = corrupt(rng)
        case = tmp_path / f"case{i}"
        case.mkdir()
        bundle = case / "bundle.json"
        bundle.write_bytes(data)
        label = f"case {i} ({what})"
        res = runner.invoke(
            cli, ["compensate", "--bundle", str(bundle), "--reference", str(ref), "--out", str(case / "drive.csv")]
        )
        outcomes[_check(res, f"{label} compensate", [(case / "drive.csv", _finite_csv)])] += 1
        res = runner.invoke(cli, ["simulate", str(STEP), "--bundle", str(bundle), "--out", str(case / "sim.parquet")])
        outcomes[_check(res, f"{label} simulate", [(case / "sim.parquet", _finite_run)])] += 1
        res = runner.invoke(cli, ["validate", "--bundle", str(bundle), "--plan", str(plan), "--out", str(case / "val")])
        outcomes[_check(res, f"{label} validate", [(case / "val" / "step-30n.parquet", _finite_run)])] += 1
        if i % 4 == 0:
            res = runner.invoke(
                cli,
                ["diagnose", str(STEP), "--bundle", str(bundle), "--cause", "input_delay", "--out", str(case / "diag")],
            )
            outcomes[_check(res, f"{label} diagnose", [(case / "diag" / "extended_bundle.json", _finite_json)])] += 1
    elapsed = time.perf_counter() - start
    # both outcomes occur: the generator corrupts, and not every corruption is fatal (a figure, a scaled weight)
    assert outcomes["ok"] >= 0.05 * sum(outcomes.values()) and outcomes["error"] >= 0.5 * sum(outcomes.values()), (
        outcomes
    )
    assert elapsed < TIME_LIMIT_S, f"{CASES} cases took {elapsed:.1f} s; expected under {TIME_LIMIT_S:g} s"


@pytest.mark.parametrize("seed", range(3))
def test_the_generator_corrupts(seed):
    """Cases are almost never the sample bundle unchanged (a fuzz test that fuzzes nothing cannot
    fail; scaling a zero leaves it unchanged), and every kind of corruption occurs."""
    rng = np.random.default_rng(seed)
    original = json.dumps(BASE).encode()
    cases = [corrupt(rng) for _ in range(200)]
    assert sum(data == original for _, data in cases) <= 0.05 * len(cases)
    whats = " ".join(what for what, _ in cases)
    for kind in ("= nan", "= inf", "deleted", " x ", "cut to", "section", "hysteresis unit", "top level", "text"):
        assert kind in whats, kind
