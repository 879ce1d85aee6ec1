"""Benchmark of issue 19's acceptance on the presses written apart: the whole chain a new user
runs, today's code beside a reference commit's, in the same run.

For the second and third test presses (``tests/independent_press.py``, ``tests/third_press.py``),
clean, per seed: the default characterization (each code's own default plan), ``fit``, and the
bundle's compensated drives played on the same press (``piezopress compare``'s validation and
tracking plans, one repeat). Each code runs in its own process with its tree first on
``PYTHONPATH`` (the reference taken from git, as ``bench/bench_chain.py`` does); the presses are
today's test presses for both. Prints per press the held-out error of the fit against the
noise floor (the rest run's RMS, its drift removed) and every compensated row: the mean over
the seeds and the range, reference beside now, beside issue 19's targets.

Beside them, each row's floor on that press: the row measured on the reference itself plus the
press's own noise (stretches of the same seed's rest run, its drift removed), through the same
metrics -- what a compensator that tracks perfectly would read on one repeat. A row whose
floor is above its target cannot meet the target on that press, whatever the compensation
(the max-based rows read the noise's peaks: the overshoot of a 30 N step, the staircase's
error relative to 30 N).

With ``--repeats R`` (R > 1) the drives are played R times (``compare --repeats``): the rows are
then the mean over the repeats, and a second table gives the rows of the outputs averaged over
the repeats sample by sample (the same drive and reference each time, the press's noise new each
time: its part falls by sqrt(R), what the compensation leaves does not), beside the floor of R
noise stretches averaged alike. Where a row's one-repeat floor is above its target, that table
says how much of the row is the compensation's; the target stays the one-repeat row's.

Run: .venv/bin/python bench/bench_presses.py [--against COMMIT] [--rig second,third] [--seeds 3] [--workers 2]
         [--repeats 1]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

from bench_chain import _env, code_tree  # noqa: E402

#: The last commit before this benchmark's issue 19 work of stop 30.
REFERENCE = "f92532c"

#: Issue 19's acceptance on the second and third presses (compensated, %).
TARGETS = {
    "static_hysteresis": 1.0,
    "creep": 0.3,
    "tracking_staircase": 3.0,
    "overshoot": 3.0,
    "tracking_random": 0.5,
}
ROWS = (*TARGETS, "hysteresis_1hz", "hysteresis_10hz", "hysteresis_50hz")

#: Run in the child process: one press through the chain with the code on PYTHONPATH.
DRIVER = r"""
import json, shutil, sys
from pathlib import Path
import numpy as np
tests, rig, seed, work, repeats = sys.argv[1], sys.argv[2], int(sys.argv[3]), Path(sys.argv[4]), int(sys.argv[5])
sys.path.insert(0, tests)
import independent_press as ip
import third_press as tp
from piezopress import runformat
from piezopress.pipelines import bundle as B, characterize as char, compare, fit as F
mod = tp if rig == "third" else ip
press = mod.clean_press(np.random.default_rng([seed, 97 if rig == "third" else 98]))
char.characterize(work / "char", backend=press)
res = F.fit_bundle([work / "char"], press.limits)
B.write_document(res.doc, work / "bundle.json")
shutil.copy(work / "bundle.json", work / "same.json")
c = compare.compare([work / "bundle.json", work / "same.json"], work / "cmp", backend=press, rig_path=None,
                    repeats=repeats, labels=["a", "b"])
t = c.table
rows = {r: float(g["mean"].iloc[0]) for r, g in t[t["bundle"] == "a"].groupby("row")}
rest = [p for p in sorted((work / "char").glob("*.parquet")) if p.stem.startswith("rest")]
y = runformat.read_run(rest[0]).output
k = np.arange(y.size)
noise = float(np.std(y - np.polyval(np.polyfit(k, y, 2), k)))
fit = res.doc["hysteresis"]["fit"]
import piezopress
print(json.dumps({"code": piezopress.__file__, "rows": rows, "holdout": fit["holdout_rms_n"], "noise": noise,
                  "family": res.doc["hysteresis"]["model"].get("family", "modified_pi"),
                  "creep": "creep" in res.doc}))
"""


def one(tree: Path | None, rig: str, seed: int, work: Path, repeats: int = 1) -> dict:
    work.mkdir(parents=True)
    args = [str(ROOT / "tests"), rig, str(seed), str(work), str(repeats)]
    # run from the job's folder: from the checkout, "" on sys.path would import today's code for both
    out = subprocess.run(
        [sys.executable, "-c", DRIVER, *args], env=_env(tree), cwd=work, capture_output=True, text=True
    )
    if out.returncode != 0:
        raise SystemExit(f"{rig}-{seed} failed ({'reference' if tree else 'now'}):\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _rest_noise(work: Path) -> np.ndarray:
    """The press's noise: the rest run of ``work``'s characterization, its slow drift (a quadratic) removed."""
    from piezopress import runformat

    rest = [p for p in sorted((work / "char").glob("*.parquet")) if p.stem.startswith("rest")]
    y = runformat.read_run(rest[0]).output
    k = np.arange(y.size)
    return y - np.polyval(np.polyfit(k, y, 2), k)


def _rows_of(work: Path, out: Path, output_of) -> dict[str, float]:
    """The rows of ``work``'s compensated runs (one press, one seed) with every output replaced
    by ``output_of(run, path relative to the repeat's folder)``, written under ``out``."""
    from piezopress import runformat
    from piezopress.pipelines import gain
    from piezopress.pipelines.files import run_files

    dirs = []
    for sub in sorted((work / "cmp" / "rep1" / "a").iterdir()):
        (out / sub.name).mkdir(parents=True)
        dirs.append(out / sub.name)
        for f in run_files(sub):
            run = runformat.read_run(f)
            data = run.data.copy()
            data[run.output_column] = output_of(run, f.relative_to(work / "cmp" / "rep1"))
            runformat.write_run(dataclasses.replace(run, data=data), out / sub.name / f.name)
    return gain.row_values(dirs)


def floor_rows(work: Path, seed: int, average: int = 1) -> dict[str, float]:
    """The rows of ``work``'s compensated runs (one press, one seed) with every output replaced
    by its reference plus the press's noise: stretches of the rest run of ``work``'s
    characterization, its slow drift (a quadratic) removed, taken at random places; with
    ``average``, that many stretches averaged (the noise of outputs averaged over as many repeats)."""
    noise = _rest_noise(work)
    rng = np.random.default_rng(seed)

    def output_of(run, _rel) -> np.ndarray:
        n = len(run.data)
        parts = []
        for _ in range(average):  # a run longer than the rest run takes it again, from a random place
            start = int(rng.integers(0, noise.size - n)) if noise.size > n else int(rng.integers(0, noise.size))
            parts.append(np.resize(np.roll(noise, -start), n))
        return run.data["reference_n"].to_numpy() + np.mean(parts, axis=0)

    return _rows_of(work, work / f"floor-{average}", output_of)


def averaged_rows(work: Path, repeats: int) -> dict[str, float]:
    """The rows of ``work``'s compensated outputs averaged over its ``repeats`` repeats, sample by sample."""
    from piezopress import runformat

    def output_of(run, rel) -> np.ndarray:
        # ``run`` is repeat 1's (:func:`_rows_of` walks rep1): the others read alongside it
        ys = [run.output] + [runformat.read_run(work / "cmp" / f"rep{k}" / rel).output for k in range(2, repeats + 1)]
        if any(y.size != run.output.size for y in ys):
            raise SystemExit(f"{rel}: the repeats differ in length; they cannot be averaged")
        return np.mean(ys, axis=0)

    return _rows_of(work, work / "averaged", output_of)


def _cell(values: list[float]) -> str:
    return f"{np.mean(values):6.2f} ({min(values):.2f}-{max(values):.2f})"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--against", default=REFERENCE, help=f"the reference commit (default {REFERENCE})")
    p.add_argument("--rig", default="second,third")
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument(
        "--repeats", type=int, default=1, help="plays of the drives per case (> 1: the averaged outputs' rows too)"
    )
    a = p.parse_args()
    if not 1 <= a.repeats <= 10:
        raise SystemExit(f"--repeats {a.repeats}; expected 1 to 10")
    rigs = [r for r in a.rig.split(",") if r]
    if not rigs or any(r not in ("second", "third") for r in rigs):
        raise SystemExit(f"--rig {a.rig!r}; expected second, third or both, comma-separated")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench-presses-") as tmp:
        work = Path(tmp)
        tree = code_tree(work, a.against)
        if tree is None:
            raise SystemExit(f"cannot take {a.against} from git; run inside the checkout or pass --against")
        jobs = [(label, t, r, s) for r in rigs for s in range(a.seeds) for label, t in (("ref", tree), ("now", None))]
        with ThreadPoolExecutor(max_workers=a.workers) as pool:
            futures = {j: pool.submit(one, j[1], j[2], j[3], work / f"{j[0]}-{j[2]}{j[3]}", a.repeats) for j in jobs}
            results = {(label, r, s): f.result() for (label, _, r, s), f in futures.items()}
        wrong = [k for k, v in results.items() if (k[0] == "ref") != v["code"].startswith(str(tree))]
        if wrong:
            raise SystemExit(f"{wrong[0]} ran the wrong code ({results[wrong[0]]['code']}): no comparison")
        # the presses' noise is the same for both codes: one floor per press and seed
        floors = {(r, s): floor_rows(work / f"now-{r}{s}", s) for r in rigs for s in range(a.seeds)}
        averaged = {}
        if a.repeats > 1:
            for r in rigs:
                for s in range(a.seeds):
                    averaged["floor", r, s] = floor_rows(work / f"now-{r}{s}", s, a.repeats)
                    for label in ("ref", "now"):
                        averaged[label, r, s] = averaged_rows(work / f"{label}-{r}{s}", a.repeats)
    print(
        f"Issue 19 on the presses written apart: {a.against} beside now, {a.seeds} seed(s), {a.repeats} repeat(s), "
        f"{time.perf_counter() - t0:.0f} s on {a.workers} worker(s)\n"
    )
    for r in rigs:
        ref = [results["ref", r, s] for s in range(a.seeds)]
        now = [results["now", r, s] for s in range(a.seeds)]
        print(f"{r} press (mean over seeds, range in brackets; compensated rows in %)")
        print(f"  {'':28s} {a.against:>20s} {'now':>20s} {'floor (noise)':>20s}  target")
        rv = [x["holdout"] / x["noise"] for x in ref]
        nv = [x["holdout"] / x["noise"] for x in now]
        print(f"  {'fit held-out / noise floor':28s} {_cell(rv):>20s} {_cell(nv):>20s}  <= 3x")
        print(
            f"  {'family / creep kept':28s} {ref[0]['family'] + ' ' + str(all(x['creep'] for x in ref)):>20s} "
            f"{now[0]['family'] + ' ' + str(all(x['creep'] for x in now)):>20s}"
        )
        for row in ROWS:
            rv = [abs(x["rows"][row]) for x in ref if row in x["rows"]]
            nv = [abs(x["rows"][row]) for x in now if row in x["rows"]]
            fv = [abs(floors[r, s][row]) for s in range(a.seeds) if row in floors[r, s]]
            if rv and nv:
                target = f"<= {TARGETS[row]:g}" if row in TARGETS else ""
                if target and fv and np.mean(fv) > TARGETS[row]:
                    target += " (the floor is above it)"
                print(f"  {row:28s} {_cell(rv):>20s} {_cell(nv):>20s} {_cell(fv) if fv else '':>20s}  {target}")
        print()
        if a.repeats > 1:
            print(
                f"{r} press, the outputs averaged over the {a.repeats} repeats sample by sample (the noise's part "
                f"down by sqrt({a.repeats}); what the compensation leaves; the targets are the one-repeat rows')"
            )
            print(f"  {'':28s} {a.against:>20s} {'now':>20s} {'floor (noise)':>20s}")
            for row in ROWS:
                cells = [
                    [abs(averaged[label, r, s][row]) for s in range(a.seeds) if row in averaged[label, r, s]]
                    for label in ("ref", "now", "floor")
                ]
                if cells[0] and cells[1]:
                    print(f"  {row:28s} " + " ".join(f"{_cell(c) if c else '':>20s}" for c in cells))
            print()


if __name__ == "__main__":
    main()
