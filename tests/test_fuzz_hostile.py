"""Fuzz: corrupted runs, plans, rig files, reference CSVs and import sources, every relevant
command run on them in-process (click's CliRunner).

A seeded generator (seed 14, so a failure is reproducible: the case's label says how it was
made) writes at least 500 small hostile inputs (each under 100 kB: the per-case size bound),
and the whole loop runs with the address space capped (RLIMIT_AS: what the process uses now
plus 3 GB). The only outcomes allowed:

* success (exit 0) with every number in every file written finite, or
* one ``Error:`` line (plus, for a plan or rig file, its ``  - `` problem lines) with exit 1 or 2;

never a traceback, a non-finite value in a written file, or a case running past
:data:`CASE_SECONDS`.
"""

from __future__ import annotations

import contextlib
import copy
import json
import math
import sys
import time
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from piezopress import runformat
from piezopress.piezocli.main import cli

ROOT = Path(__file__).resolve().parents[1]
BUNDLE = ROOT / "sample_runs" / "bundle.json"
RIG = ROOT / "rigs" / "thesis-press.toml"
SEED = 14
#: Longest a case may run (generation, command and checks).
CASE_SECONDS = 10.0
#: Largest input a case may write (the per-case size bound).
CASE_BYTES = 100_000
#: Address space allowed above what the test process uses when the fuzzing starts.
MEMORY_HEADROOM = 3 << 30

HOSTILE: list[Any] = [
    0,
    -1,
    0.5,
    1e-300,
    1e300,
    -1e300,
    math.nan,
    math.inf,
    -math.inf,
    10**12,
    -(10**12),
    2**63 - 1,
    "x",
    "",
    "../../etc",
    True,
    [],
    [1.0, "a"],
    {},
    {"a": 1},
]

# --------------------------------------------------------------------------- writers


def toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(str(k))} = {toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def toml_dump(doc: dict[str, Any]) -> str:
    lines = [
        f"{json.dumps(k)} = {toml_value(v)}"
        for k, v in doc.items()
        if not isinstance(v, dict) and not (isinstance(v, list) and v and all(isinstance(x, dict) for x in v))
    ]
    for k, v in doc.items():
        if isinstance(v, dict):
            lines.append(f"[{json.dumps(k)}]")
            lines += [f"{json.dumps(str(kk))} = {toml_value(x)}" for kk, x in v.items()]
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            for table in v:
                lines.append(f"[[{json.dumps(k)}]]")
                lines += [f"{json.dumps(str(kk))} = {toml_value(x)}" for kk, x in table.items()]
    return "\n".join(lines) + "\n"


def corrupt_bytes(rng: np.random.Generator, data: bytes) -> bytes:
    how = int(rng.integers(4)) if data else 3
    if how == 0:
        return data[: int(rng.integers(len(data) + 1))]
    if how == 1:
        b = bytearray(data)
        for _ in range(int(rng.integers(1, 8))):
            b[int(rng.integers(len(b)))] = int(rng.integers(256))
        return bytes(b)
    if how == 2:
        return b""
    return bytes(rng.integers(0, 256, int(rng.integers(1, 400)), dtype=np.uint8))


# --------------------------------------------------------------------------- the cases


@dataclass
class Case:
    label: str
    args: list[str]
    outputs: list[Path]


def base_run_table() -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    fs = 1000.0
    n = 400
    t = np.arange(n) / fs
    command = np.where((t > 0.05) & (t < 0.25), 20.0, 0.0)
    force = 50.0 + 2.0 * command + 0.01 * np.sin(40 * t)
    meta = runformat.make_meta("step", "s", fs, preload_n=50.0, protocol={"name": "s", "kind": "step", "level_v": 20.0})
    return {"t_s": t, "command_v": command, "force_n": force}, meta


def write_table(path: Path, cols: dict[str, Any], meta: Any) -> None:
    table = pa.table({k: pa.array(v) for k, v in cols.items()})
    raw = meta if isinstance(meta, bytes) else json.dumps(meta, default=str).encode()
    pq.write_table(table.replace_schema_metadata({runformat.METADATA_KEY: raw}), path)


def run_case(rng: np.random.Generator, d: Path, i: int) -> list[Case]:
    cols, meta = base_run_table()
    cols = {k: v.copy() for k, v in cols.items()}
    meta = copy.deepcopy(meta)
    n = len(cols["t_s"])
    how = int(rng.integers(11))
    col = str(rng.choice(list(cols)))
    label = f"run#{i} "
    if how == 0:
        k = int(rng.integers(n))
        cols[col][k] = rng.choice([np.nan, np.inf, -np.inf, 1e300, -1e300, 1e-300])
        label += f"{col}[{k}]={cols[col][k]!r}"
    elif how == 1:
        kind = str(rng.choice(["int64", "float32", "str", "bool"]))
        cols[col] = cols[col].astype(kind) if kind != "str" else cols[col].astype(str)
        label += f"{col} as {kind}"
    elif how == 2:
        del cols[col]
        label += f"no {col}"
    elif how == 3:
        extra = rng.choice(["str", "float", "int", "nan"])
        cols["extra"] = {"str": np.full(n, "x"), "float": np.ones(n), "int": np.arange(n), "nan": np.full(n, np.nan)}[
            str(extra)
        ]
        label += f"extra {extra} column"
    elif how == 4:
        keep = int(rng.choice([0, 1, 2, 3]))
        cols = {k: v[:keep] for k, v in cols.items()}
        label += f"{keep} rows"
    elif how == 5:
        t = cols["t_s"]
        j = int(rng.integers(1, n - 1))
        t[j] = t[j - 1] if rng.random() < 0.5 else t[j] + 0.3e-3
        label += f"t_s broken at {j}"
    elif how == 6:
        key = str(rng.choice(["schema_version", "kind", "name", "sample_rate_hz", "status", "preload_n", "protocol"]))
        meta[key] = HOSTILE[int(rng.integers(len(HOSTILE)))]
        label += f"meta {key}={meta[key]!r}"
    elif how == 7:
        meta = bytes(rng.choice([b"not json", b"[1, 2]", b"null", b'{"schema_version": 1}']))
        label += f"meta bytes {meta!r}"
    elif how == 8:
        scale = float(rng.choice([1e300, -1e300, 1e-300, 1e150]))
        cols["force_n"] = cols["force_n"] * scale
        cols["command_v"] = cols["command_v"] * (scale if rng.random() < 0.5 else 1.0)
        label += f"values scaled by {scale:g}"
    elif how == 9:
        cols["t_s"] = cols["t_s"] * float(rng.choice([1e-9, 1e9, 1e-300]))
        label += "time rescaled"
    path = d / f"run{i}.parquet"
    write_table(path, cols, meta)
    if how == 10:
        path.write_bytes(corrupt_bytes(rng, path.read_bytes()))
        label += "file bytes corrupted"
    sim = d / f"sim{i}.parquet"
    return [
        Case(label + " | inspect", ["inspect", str(path)], []),
        Case(label + " | simulate", ["simulate", str(path), "--bundle", str(BUNDLE), "--out", str(sim)], [sim]),
    ]


DRIVE_PLAN = {
    "plan": {"name": "tiny", "preload_n": 50.0},
    "protocol": [
        {"name": "tri", "kind": "triangle", "freq_hz": 10.0, "cycles": 1, "peak_v": 50.0, "sample_rate_hz": 1000.0},
        {"name": "step", "kind": "step", "level_v": 20.0, "hold_s": 0.05, "sample_rate_hz": 2000.0},
    ],
}


def mutate_plan(rng: np.random.Generator, doc: dict[str, Any], suffix: str) -> tuple[dict[str, Any], str]:
    doc = copy.deepcopy(doc)
    how = int(rng.integers(7))
    protos = doc["protocol"]
    p = protos[int(rng.integers(len(protos)))]
    if how <= 1:
        key = str(rng.choice(sorted(p)))
        p[key] = HOSTILE[int(rng.integers(len(HOSTILE)))]
        return doc, f"protocol {p.get('name')!r} {key}={p[key]!r}"
    if how == 2:
        key = str(rng.choice(sorted(p)))
        del p[key]
        return doc, f"no {key}"
    if how == 3:
        name = str(rng.choice(["x" * 300, "Tri", "TRI", "a b", "../up", ".hidden", "é", "tri", ""]))
        p["name"] = name
        return doc, f"name {name[:20]!r}"
    if how == 4:
        key = str(
            rng.choice(
                ["hold_s", f"peak{suffix}", "cycles", "freq_hz", "sample_rate_hz", f"level{suffix}", "random_peaks"]
            )
        )
        value = {"random_peaks": {"count": 10**12, f"min{suffix}": 0, f"max{suffix}": 10, "seed": 1}}.get(
            key, rng.choice([1e5, 1e7, 1e-5, 10**9])
        )
        p[key] = value.item() if hasattr(value, "item") else value
        return doc, f"costly {key}={p[key]!r}"
    if how == 5:
        doc["plan"][str(rng.choice(["name", "preload_n", "bogus"]))] = HOSTILE[int(rng.integers(len(HOSTILE)))]
        return doc, "plan head"
    protos.append(copy.deepcopy(p))
    return doc, "duplicate protocol"


def plan_case(rng: np.random.Generator, d: Path, i: int) -> list[Case]:
    doc, label = mutate_plan(rng, DRIVE_PLAN, "_v")
    path = d / f"plan{i}.toml"
    text = toml_dump(doc).encode()
    if rng.random() < 0.1:
        text, label = corrupt_bytes(rng, text), "bytes corrupted"
    path.write_bytes(text)
    out = d / f"char{i}"
    return [Case(f"plan#{i} {label} | characterize", ["characterize", "--plan", str(path), "--out", str(out)], [out])]


def validation_case(rng: np.random.Generator, d: Path, i: int) -> list[Case]:
    base = json.loads(json.dumps(DRIVE_PLAN).replace("peak_v", "peak_n").replace("level_v", "level_n"))
    doc, label = mutate_plan(rng, base, "_n")
    path = d / f"vplan{i}.toml"
    path.write_text(toml_dump(doc))
    out = d / f"val{i}"
    return [
        Case(
            f"validation plan#{i} {label} | validate",
            ["validate", "--bundle", str(BUNDLE), "--plan", str(path), "--out", str(out)],
            [out],
        )
    ]


RIG_DOC = tomllib.loads(RIG.read_text())


def rig_case(rng: np.random.Generator, d: Path, i: int) -> list[Case]:
    doc = copy.deepcopy(RIG_DOC)
    section = str(rng.choice(sorted(k for k, v in doc.items() if isinstance(v, dict))))
    key = str(rng.choice(sorted(doc[section])))
    how = int(rng.integers(5))
    if how <= 2:
        doc[section][key] = (
            HOSTILE[int(rng.integers(len(HOSTILE)))]
            if how < 2
            else float(doc[section][key]) * float(rng.choice([0.0, -1.0, 1e-6, 1e6]))
            if isinstance(doc[section][key], (int, float)) and not isinstance(doc[section][key], bool)
            else "x"
        )
        label = f"[{section}] {key}={doc[section][key]!r}"
    elif how == 3:
        del doc[section][key]
        label = f"no [{section}] {key}"
    else:
        doc[str(rng.choice([section, "bogus"]))] = (
            {"bogus": 1} if rng.random() < 0.5 else doc[section] | {"bogus_key": 1.0}
        )
        label = "unknown keys"
    path = d / f"rig{i}.toml"
    text = toml_dump(doc).encode()
    if rng.random() < 0.08:
        text, label = corrupt_bytes(rng, text), "bytes corrupted"
    path.write_bytes(text)
    plan = d / "tiny-plan.toml"
    if not plan.exists():
        plan.write_text(toml_dump(DRIVE_PLAN))
    out = d / f"rigchar{i}"
    return [
        Case(
            f"rig#{i} {label} | check-rig",
            ["check-rig", "--rig", str(path), "--duration-s", "0.5", "--rest-s", "0.2"],
            [],
        ),
        Case(
            f"rig#{i} {label} | characterize",
            ["characterize", "--rig", str(path), "--plan", str(plan), "--out", str(out)],
            [out],
        ),
    ]


def csv_frame(rng: np.random.Generator, names: list[str]) -> tuple[pd.DataFrame, str]:
    fs = float(rng.choice([1000.0, 1000.0, 1000.0, 1e6, 1e9, 1e-3, 1e5]))
    n = int(rng.choice([200, 200, 1, 2, 3, 0]))
    df = pd.DataFrame({names[0]: np.arange(n) / fs, **{c: np.linspace(0.0, 50.0, n) for c in names[1:]}}).astype(object)
    label = f"fs {fs:g}, {n} rows"
    how = int(rng.integers(6))
    if how == 0 and n:
        c, k = str(rng.choice(names)), int(rng.integers(n))
        df.loc[k, c] = rng.choice(["nan", "inf", "-inf", "1e300", "x", "", "1,5", "0x10"])
        label += f", {c}[{k}]={df.loc[k, c]!r}"
    elif how == 1 and n > 3:
        df.loc[int(rng.integers(1, n)), names[0]] = 0.5
        label += ", time broken"
    elif how == 2:
        df = df.rename(columns={names[int(rng.integers(len(names)))]: "other"})
        label += ", a column renamed"
    elif how == 3:
        df[names[1]] = [1e300 * (-1) ** k for k in range(n)]
        label += ", huge values"
    return df, label


def reference_case(rng: np.random.Generator, d: Path, i: int) -> list[Case]:
    df, label = csv_frame(rng, ["t_s", "reference_n"])
    path = d / f"ref{i}.csv"
    df.to_csv(path, index=False)
    if rng.random() < 0.1:
        path.write_bytes(corrupt_bytes(rng, path.read_bytes()))
        label += ", bytes corrupted"
    out = d / f"drive{i}.csv"
    return [
        Case(
            f"reference#{i} {label} | compensate",
            ["compensate", "--bundle", str(BUNDLE), "--reference", str(path), "--out", str(out)],
            [out],
        )
    ]


def import_case(rng: np.random.Generator, d: Path, i: int) -> list[Case]:
    df, label = csv_frame(rng, ["t", "u", "f"])
    path = d / f"src{i}.csv"
    sep = str(rng.choice([",", ";", "\t"]))
    df.to_csv(path, index=False, sep=sep, header=bool(rng.random() < 0.7))
    if rng.random() < 0.1:
        path.write_bytes(corrupt_bytes(rng, path.read_bytes()))
        label += ", bytes corrupted"
    out = d / f"imported{i}.parquet"
    args = ["import", str(path), "--out", str(out), "--col", "t_s=1", "--col", "command_v=2", "--col", "force_n=3"]
    extra = [
        [],
        ["--rows", "5:2"],
        ["--rows", "0:100000"],
        ["--lag", "force_n=1000"],
        ["--lag", "force_n=-1"],
        ["--scale", "force_n=0"],
        ["--scale", "force_n=1e308"],
        ["--offset", "force_n=nan"],
        ["--sample-rate-hz", "-5"],
        ["--kind", "bogus"],
        ["--delimiter", "ab"],
    ]
    more = extra[int(rng.integers(len(extra)))]
    return [Case(f"import#{i} {label} {' '.join(more)} | import", args + more, [out])]


FAMILIES: list[tuple[Callable[[np.random.Generator, Path, int], list[Case]], int]] = [
    (run_case, 150),
    (plan_case, 110),
    (validation_case, 60),
    (rig_case, 90),
    (reference_case, 80),
    (import_case, 80),
]


# --------------------------------------------------------------------------- the checks


def non_finite_in(path: Path) -> str:
    """Where a written file holds a non-finite number ('' : nowhere)."""
    if path.is_dir():
        return next((w for p in sorted(path.rglob("*")) if p.is_file() and (w := non_finite_in(p))), "")
    if path.suffix == ".parquet":
        frame = pd.read_parquet(path)
        num = frame.select_dtypes("number").to_numpy(dtype=float)
        return f"{path.name}: non-finite value" if num.size and not np.isfinite(num).all() else ""
    if path.suffix == ".csv":  # an empty cell is no value (a metric without a thesis figure); nan/inf are wrong values
        cells = pd.read_csv(path, dtype=str, keep_default_na=False).to_numpy().ravel()
        bad = [c for c in cells if c.strip().lower().lstrip("+-") in ("nan", "inf", "infinity")]
        return f"{path.name}: non-finite value {bad[0]!r}" if bad else ""
    if path.suffix == ".json":
        text = path.read_text()
        return f"{path.name}: NaN/Infinity in JSON" if any(w in text for w in ("NaN", "Infinity")) else ""
    return ""


def problem(case: Case, res: Any, seconds: float) -> str:
    if seconds > CASE_SECONDS:
        return f"ran {seconds:.1f} s (> {CASE_SECONDS} s)"
    if res.exception is not None and not isinstance(res.exception, SystemExit):
        return f"traceback: {type(res.exception).__name__}: {str(res.exception)[:200]}"
    if res.exit_code not in (0, 1, 2):
        return f"exit {res.exit_code}"
    lines = res.output.splitlines()
    errors = [ln for ln in lines if ln.startswith("Error")]
    if res.exit_code == 0:
        if errors or "Traceback" in res.output:
            return "exit 0 with an error printed"
        return next((w for p in case.outputs if p.exists() and (w := non_finite_in(p))), "")
    if case.args[0] == "check-rig" and res.exit_code == 1 and "verdict:        NOT OK" in res.output:
        return ""  # a rig whose force does not follow the drive: the check's own verdict, a correct result
    if case.args[0] == "inspect":  # one Error line per bad file
        return "" if len(errors) == 1 else f"{len(errors)} Error lines"
    if len(errors) != 1 or "Traceback" in res.output:
        return f"{len(errors)} Error lines: {res.output[-300:]!r}"
    if errors[0] != lines[lines.index(errors[0])]:  # pragma: no cover
        return "garbled"
    return ""


@contextlib.contextmanager
def address_space_cap(headroom: int):
    """RLIMIT_AS set to what the process maps now plus ``headroom``, restored after."""
    try:
        import resource
    except ImportError:  # pragma: no cover (not POSIX)
        yield None
        return
    status = Path("/proc/self/status")
    if not status.exists():  # pragma: no cover
        yield None
        return
    vm_kb = next(int(ln.split()[1]) for ln in status.read_text().splitlines() if ln.startswith("VmSize:"))
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = vm_kb * 1024 + headroom
    if hard != resource.RLIM_INFINITY and hard < cap:
        cap = hard
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    try:
        yield cap
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


@pytest.mark.skipif(sys.platform != "linux", reason="the memory cap reads /proc")
def test_fuzz_hostile_inputs_give_a_result_or_one_error_line(tmp_path):
    rng = np.random.default_rng(SEED)
    runner = CliRunner()
    found: list[str] = []
    count = 0
    started = time.perf_counter()
    CliRunner().invoke(
        cli, ["inspect", str(ROOT / "sample_runs" / "characterization" / "step-20v.parquet")]
    )  # imports, before the cap
    with address_space_cap(MEMORY_HEADROOM):
        for family, n in FAMILIES:
            d = tmp_path / family.__name__
            d.mkdir()
            for i in range(n):
                t0 = time.perf_counter()
                cases = family(rng, d, i)
                for case in cases:
                    inputs = [Path(a) for a in case.args if a.startswith(str(d)) and Path(a).is_file()]
                    assert all(p.stat().st_size <= CASE_BYTES for p in inputs), (
                        f"{case.label}: input above the per-case bound"
                    )
                    res = runner.invoke(cli, case.args)
                    why = problem(case, res, time.perf_counter() - t0)
                    count += 1
                    if why:
                        found.append(f"{case.label}: {why}")
    took = time.perf_counter() - started
    assert count >= 500, count
    assert not found, f"{len(found)} of {count} cases failed:\n" + "\n".join(found[:40])
    assert took < 60.0, f"the fuzz test took {took:.0f} s"


def test_the_fuzz_checker_flags_every_forbidden_outcome(tmp_path):
    """The checker is not vacuous: a traceback, a bad exit, two Error lines, an error after
    exit 0, a slow case and a non-finite value written are each flagged; the allowed outcomes are not."""

    class Res:
        def __init__(self, code=0, output="", exception=None):
            self.exit_code, self.output, self.exception = code, output, exception

    nan_file = tmp_path / "x.parquet"
    pd.DataFrame({"a": [1.0, np.nan]}).to_parquet(nan_file)
    csv = tmp_path / "x.csv"
    csv.write_text("a,b\n1,inf\n")
    ok_csv = tmp_path / "ok.csv"
    ok_csv.write_text("a,b\n1,\n")
    case = Case("c", ["compensate"], [])
    assert problem(case, Res(1, "Error: x\n", ValueError("boom")), 0.1).startswith("traceback")
    assert problem(case, Res(3, ""), 0.1) == "exit 3"
    assert "2 Error lines" in problem(case, Res(1, "Error: a\nError: b\n", SystemExit(1)), 0.1)
    assert problem(case, Res(0, "Error: a\n"), 0.1) == "exit 0 with an error printed"
    assert "ran" in problem(case, Res(0, ""), CASE_SECONDS + 1)
    assert "non-finite" in problem(Case("c", ["x"], [nan_file]), Res(0, ""), 0.1)
    assert "non-finite value 'inf'" in problem(Case("c", ["x"], [csv]), Res(0, ""), 0.1)
    assert problem(Case("c", ["x"], [ok_csv]), Res(0, ""), 0.1) == ""
    assert problem(case, Res(1, "Error: p: 2 problem(s) in the plan\n  - a\n  - b\n", SystemExit(1)), 0.1) == ""
