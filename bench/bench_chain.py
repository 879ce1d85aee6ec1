"""Benchmark of the chain's cost per press (issue 23 targets on 2 cores: ``fit`` <= 5 s,
``diagnose`` <= 10 s, ``piezopress demo`` <= 35 s), beside the code before issue 23 in the same run.

Each stage runs in a fresh Python process per code version, on the same inputs: ``fit`` and
``fit --base`` on the default characterization (``sample_runs/characterization``, or the runs of
``--characterization``), ``diagnose``
of it against the base bundle just fitted, and the whole ``piezopress demo`` (its wall time as a
user sees it, start-up included). The two versions alternate stage by stage, so that a busy
machine slows both. The reference is the tree at :data:`BEFORE` (the last commit before issue
23), taken from git into a temporary folder and put first on ``PYTHONPATH``.

Printed per stage: seconds before and now, the ratio now/before and the target; then whether the
outputs agree: each bundle's numbers (largest relative difference, timestamps and digests left
out) and the diagnosis's findings (the same causes, their gains within :data:`GAIN_TOLERANCE_PCT`),
against the reference or, with ``--outputs-against COMMIT``, against that commit's outputs (the
speed work's own starting point: other issues have changed the outputs since the reference).

Run: .venv/bin/python bench/bench_chain.py [--skip-demo] [--before COMMIT] [--outputs-against COMMIT]
     [--characterization DIR] [--repeats N]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: The last commit before issue 23 (``piezopress batch`` and the speed work came after it).
BEFORE = "ec9ef14"
CHARACTERIZATION = ROOT / "sample_runs" / "characterization"
TARGETS_S = {"fit": 5.0, "fit --base": None, "diagnose": 10.0, "demo": 35.0}
#: Findings' held-out gains may differ by this much (percentage points) between the versions.
GAIN_TOLERANCE_PCT = 0.5
#: A number below this share of the largest in its list is compared against that share.
SCALE_FLOOR = 1e-6
#: Keys whose values are expected to differ (when and where a file was written, its digest).
VOLATILE = ("created", "time", "sha256", "digest", "file", "path", "version", "git", "python", "host", "seconds")

#: Run in the child process: one stage with the code on PYTHONPATH, its time printed as JSON.
DRIVER = r"""
import json, sys, time
from click.testing import CliRunner
from piezopress.piezocli.main import cli
args = sys.argv[1:]
t0 = time.perf_counter()
res = CliRunner().invoke(cli, args)
dt = time.perf_counter() - t0
if res.exit_code != 0:
    sys.stderr.write(res.output + repr(res.exception))
    sys.exit(1)
print(json.dumps({"seconds": dt}))
"""


def code_tree(work: Path, commit: str) -> Path | None:
    """The package tree at ``commit``, importable from ``work/code-COMMIT`` (None outside git)."""
    tree = work / f"code-{commit}"
    if tree.is_dir():  # the same commit asked for twice (timed and compared): one tree
        return tree
    tar = work / f"{commit}.tar"
    try:
        with tar.open("wb") as fh:
            subprocess.run(["git", "-C", str(ROOT), "archive", commit], stdout=fh, check=True)
    except (OSError, subprocess.CalledProcessError):
        return None
    tree.mkdir()
    with tarfile.open(tar) as tf:
        tf.extractall(tree, filter="data")
    pkg = tree / "piezopress"
    for sub in ("piezocli", "pipelines", "protocols", "rigs"):  # as pyproject maps them into the package
        if (tree / sub).is_dir() and not (pkg / sub).exists():
            (pkg / sub).symlink_to(tree / sub, target_is_directory=True)
    return tree


def _env(tree: Path | None) -> dict[str, str]:
    env = dict(os.environ)
    if tree is not None:
        env["PYTHONPATH"] = str(tree) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def run_stage(tree: Path | None, args: list[str], cwd: Path) -> float:
    """Seconds the stage took inside a fresh process (``tree``: the reference code; None: now)."""
    out = subprocess.run([sys.executable, "-c", DRIVER, *args], env=_env(tree), cwd=cwd, capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit(f"{' '.join(args[:1])} failed ({'before' if tree else 'now'}):\n{out.stderr[-2000:]}")
    return float(json.loads(out.stdout.strip().splitlines()[-1])["seconds"])


def run_demo(tree: Path | None, out: Path, cwd: Path) -> float:
    """Wall seconds of ``piezopress demo`` as a user runs it (a new process, start-up included)."""
    t0 = time.perf_counter()
    res = subprocess.run(
        [sys.executable, "-c", "from piezopress.piezocli.main import cli; cli()", "demo", "--out", str(out)],
        env=_env(tree),
        cwd=cwd,
        capture_output=True,
        text=True,
    )
    if res.returncode != 0:
        raise SystemExit(f"demo failed ({'before' if tree else 'now'}):\n{res.stderr[-2000:]}")
    return time.perf_counter() - t0


def _numbers(doc, path: str = "") -> dict[str, float]:
    """Every number of a JSON document by its path, volatile keys left out."""
    out: dict[str, float] = {}
    if isinstance(doc, dict):
        for k, v in doc.items():
            if not any(w in str(k).lower() for w in VOLATILE):
                out.update(_numbers(v, f"{path}/{k}"))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out.update(_numbers(v, f"{path}[{i}]"))
    elif isinstance(doc, bool):
        pass
    elif isinstance(doc, int | float) and math.isfinite(doc):
        out[path] = float(doc)
    return out


def compare_bundles(a: Path, b: Path) -> str:
    """The largest relative difference between the two bundles' numbers; a number is compared
    relative to the largest of its list (a weight of 1e-9 beside weights of 1 is a zero)."""
    na, nb = _numbers(json.loads(a.read_text())), _numbers(json.loads(b.read_text()))
    common = na.keys() & nb.keys()
    only = sorted(na.keys() ^ nb.keys())
    scale: dict[str, float] = {}
    for k in common:
        group = k.rsplit("[", 1)[0]
        scale[group] = max(scale.get(group, 0.0), abs(na[k]), abs(nb[k]))
    worst, where = 0.0, ""
    for k in common:
        floor = SCALE_FLOOR * scale[k.rsplit("[", 1)[0]]
        rel = abs(na[k] - nb[k]) / max(abs(na[k]), abs(nb[k]), floor, 1e-300)
        if rel > worst:
            worst, where = rel, k
    text = f"{len(common)} numbers, largest relative difference {worst:.2g}" + (f" ({where})" if worst else "")
    if only:
        text += f"; {len(only)} in one only, e.g. {only[0]}"
    return text


def compare_diagnoses(a: Path, b: Path) -> str:
    fa = {f["cause"]: f["gain_pct"] for f in json.loads((a / "diagnosis.json").read_text())["findings"]}
    fb = {f["cause"]: f["gain_pct"] for f in json.loads((b / "diagnosis.json").read_text())["findings"]}
    if set(fa) != set(fb):
        return f"DIFFERENT findings: before {sorted(fa)}, now {sorted(fb)}"
    worst = max((abs(fa[c] - fb[c]) for c in fa), default=0.0)
    verdict = "agree" if worst <= GAIN_TOLERANCE_PCT else "DIFFER"
    return (
        f"{verdict}: the same {len(fa)} findings ({', '.join(sorted(fa))}), gains within {worst:.2g} "
        f"percentage points (tolerance {GAIN_TOLERANCE_PCT})"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skip-demo", action="store_true", help="leave out the whole demo (the longest stage)")
    ap.add_argument(
        "--outputs-against",
        metavar="COMMIT",
        help="compare the outputs with this commit's (not timed; default: the timed reference, "
        f"{BEFORE}, whose outputs other issues' work has changed since)",
    )
    ap.add_argument(
        "--before",
        metavar="COMMIT",
        default=BEFORE,
        help=f"the timed reference (default {BEFORE}, the code before issue 23; e.g. a session's start, for "
        "'no slower than today')",
    )
    ap.add_argument(
        "--characterization",
        metavar="DIR",
        type=Path,
        default=CHARACTERIZATION,
        help="the runs the stages read (default: sample_runs/characterization; e.g. a run set the default "
        "plan characterizes today, `piezopress characterize --out DIR`)",
    )
    ap.add_argument(
        "--repeats",
        type=int,
        default=1,
        help="time each stage this many times per version, alternating (printed: the medians and the range of the "
        "ratios, paired repeat by repeat)",
    )
    a = ap.parse_args()
    if a.repeats < 1:
        raise SystemExit(f"--repeats {a.repeats}: expected 1 or more")
    runs = a.characterization.resolve()
    if not runs.is_dir() or not any(runs.glob("*.parquet")):
        raise SystemExit(f"--characterization {a.characterization}: expected a directory of Parquet runs")
    before = a.before
    with tempfile.TemporaryDirectory(prefix="piezopress-chain-") as tmp:
        work = Path(tmp)
        tree = code_tree(work, before)
        if tree is None:
            raise SystemExit(f"no git history here: the reference ({before}) cannot be taken; run in a checkout")
        versions = {"before": tree, "now": None}
        times: dict[str, dict[str, list[float]]] = {"before": {}, "now": {}}
        for label in versions:
            (work / label).mkdir()
        char = str(runs)
        stages = [
            ("fit", lambda d: ["fit", char, "--out", str(d / "bundle.json")]),
            ("fit --base", lambda d: ["fit", char, "--base", "--out", str(d / "base-bundle.json")]),
            (
                "diagnose",
                lambda d: ["diagnose", char, "--bundle", str(d / "base-bundle.json"), "--out", str(d / "diagnosis")],
            ),
        ]
        where = runs.relative_to(ROOT) if runs.is_relative_to(ROOT) else runs
        print(f"chain stages on {where}, before ({before}) beside now, {os.cpu_count()} cores")
        for repeat in range(a.repeats):  # the first repeat's outputs are the ones compared below
            outs = {label: work / label / (f"r{repeat}" if repeat else "") for label in versions}
            for out in outs.values():
                out.mkdir(parents=True, exist_ok=True)
            for name, args in stages:
                for label, code in versions.items():
                    times[label].setdefault(name, []).append(run_stage(code, args(outs[label]), cwd=work))
            if not a.skip_demo:
                for label, code in versions.items():
                    took = run_demo(code, outs[label] / "demo", cwd=work)
                    times[label].setdefault("demo", []).append(took)
        spread = a.repeats > 1
        head = f"{'stage':<12} {'before':>8} {'now':>8} {'now/before':>11} {'target':>8}"
        print(head + ("   (medians)" if spread else ""))
        for name in times["now"]:
            b, n = statistics.median(times["before"][name]), statistics.median(times["now"][name])
            target = TARGETS_S.get(name)
            mark = "" if target is None else (f"<= {target:g} s " + ("met" if n <= target else "NOT MET"))
            ranges = ""
            if spread:
                ratios = [x / y for x, y in zip(times["now"][name], times["before"][name], strict=True)]
                ranges = f"  ({a.repeats} repeats: now/before {min(ratios):.2f}-{max(ratios):.2f}x)"
            print(f"{name:<12} {b:7.1f}s {n:7.1f}s {n / b:10.2f}x   {mark}{ranges}")
        ref, label = work / "before", before
        if a.outputs_against:  # the same stages with that commit's code, for their outputs only
            label = a.outputs_against
            other = code_tree(work, label)
            if other is None:
                raise SystemExit(f"commit {label} cannot be taken from git")
            ref = work / "outputs"
            ref.mkdir()
            for _, args in stages:
                run_stage(other, args(ref), cwd=work)
        print(f"outputs, {label} against now:")
        for f in ("bundle.json", "base-bundle.json"):
            print(f"  {f}: {compare_bundles(ref / f, work / 'now' / f)}")
        print(f"  diagnosis: {compare_diagnoses(ref / 'diagnosis', work / 'now' / 'diagnosis')}")


if __name__ == "__main__":
    main()
