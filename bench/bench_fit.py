"""Benchmark of the hysteresis fit (issue 10 targets: 50,000 real samples under 3 s, 10^6
samples under 2 s, on 2 cores), beside the same fit before issue 10 in the same run.

Data:
* SmartHysteresis, the whole record (50,001 samples at 5 kHz: a 3.26 s rest, then a
  +/-150 V 1 Hz sine), imported as the README documents; held out: the last 30 % of the
  fitted samples;
* the virtual rig's default press under a 0.1 Hz triangle with random peaks, 10 kHz for
  100 s (10^6 samples).

The reference is the fit as it was before issue 10 (``piezopress/analysis/hysteresis.py``
at commit :data:`BEFORE`, loaded from git), on the same data in the same process; each
fit is timed after a warm-up run. Printed: seconds, the ratio new/before, and each fit's
held-out RMS (% of the output range) so a faster fit is seen not to be a worse one.

Run: .venv/bin/python bench/bench_fit.py
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import piezopress  # noqa: E402,F401  (thread settings before numpy work)
from piezopress.acquisition import waveforms  # noqa: E402
from piezopress.acquisition.virtual_rig import VirtualRig  # noqa: E402
from piezopress.analysis import hysteresis as H  # noqa: E402

#: The last commit before issue 10's changes to the hysteresis fit.
BEFORE = "f8468e7"
DATASETS = ROOT.parent / "shared" / "datasets"
TARGETS_S = {"SmartHysteresis, 50,001 samples": 3.0, "virtual rig, 1,000,000 samples": 2.0}


def before_module():
    """``hysteresis.py`` as it was at :data:`BEFORE`, or None outside a git checkout."""
    try:
        src = subprocess.run(
            ["git", "-C", str(ROOT), "show", f"{BEFORE}:piezopress/analysis/hysteresis.py"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    path = Path(tempfile.mkdtemp()) / "hysteresis_before.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location("hysteresis_before", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


def records() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    out = {}
    if DATASETS.is_dir():
        from piezopress.pipelines.importing import import_table

        run = import_table(
            DATASETS / "smarthysteresis" / "hysteresis_v_150_1hz.csv",
            header=False,
            kind="sine",
            sample_rate_hz=5000,
            columns={"t_s": 2, "displacement_um": 3, "command_v": 4},
        )
        out["SmartHysteresis, 50,001 samples"] = (run.command_v, run.output)
    fs = 10_000.0
    peaks = np.random.default_rng(3).uniform(40, 150, 10)
    v = waveforms.triangle(0.1, peaks, 0.0, fs)[:1_000_000]
    f = VirtualRig().run(v, fs, preload_n=50.0, label="bench").channels["force_n"]
    out["virtual rig, 1,000,000 samples"] = (v, f)
    return out


def timed(mod, x, y) -> tuple[float, float]:
    data = mod.prepare([("bench", x, y)], holdout_fraction=0.3)
    mod.fit_hysteresis(data)  # warm-up: solver and code paths loaded
    t0 = time.perf_counter()
    fit = mod.fit_hysteresis(data)
    return time.perf_counter() - t0, fit.holdout_rms_pct


def main() -> int:
    import cvxpy  # noqa: F401  (import time is not fit time)

    before = before_module()
    ok = True
    print(f"{'data':34s} {'now s':>7s} {'before s':>9s} {'ratio':>6s} {'held-out % now':>15s} {'before':>7s} target")
    for label, (x, y) in records().items():
        t_now, e_now = timed(H, x, y)
        t_old, e_old = timed(before, x, y) if before else (float("nan"), float("nan"))
        met = t_now < TARGETS_S[label]
        ok &= met
        print(
            f"{label:34s} {t_now:7.2f} {t_old:9.2f} {t_now / t_old:6.2f} {e_now:15.3f} {e_old:7.3f} "
            f"< {TARGETS_S[label]:g} s: {'met' if met else 'MISSED'}"
        )
    if before is None:
        print(f"(the fit before issue 10 could not be loaded: git show {BEFORE} failed)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
