"""Benchmark of runs from anywhere (issue 18): full metadata beside the run format's four fields.

For the virtual rig's default characterization and for the second test press
(``tests/independent_press.py``, written apart from the virtual rig), clean and with each
hidden effect, the same runs go through ``fit`` and ``fit --base`` + ``diagnose`` twice:
with the metadata our ``characterize`` writes, and with each run's metadata cut to
``schema_version``, ``kind``, ``name`` and ``sample_rate_hz`` (no manifest; ``--custom``:
every kind ``custom`` too; ``--no-monitor``: without the amplifier-monitor column, as most
rigs record). Prints, per case and side by side: the hysteresis held-out error (% of range),
the mode (rad/s, damping) against the press's own, the base fit's ratio to the noise floor,
and the findings. ``--glitch-every N`` also fits the clean press's runs with one glitched
sample in N (read as 0 or as the ADC's top code) beside the clean runs.

Run: .venv/bin/python bench/bench_foreign.py [--rig ours|second] [--cases none,input_delay,...] [--seed 0]
         [--custom] [--no-monitor] [--glitch-every 3000]
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import piezopress  # noqa: E402,F401


def _press(rig: str, effect: str, seed: int):
    from piezopress.acquisition.rig_config import RigConfig, hidden_effect
    from piezopress.acquisition.virtual_rig import VirtualRig

    if rig == "ours":
        rng = np.random.default_rng([seed, 99])
        cfg = (
            RigConfig.clean().replace(rig={"seed": int(rng.integers(0, 2**31))})
            if effect == "none"
            else hidden_effect(effect, rng)
        )
        return VirtualRig(cfg), None, (cfg.mode.wn_rad_s if hasattr(cfg.mode, "wn_rad_s") else None, None)
    import independent_press as ip

    rng = np.random.default_rng([seed, 98])
    press = ip.clean_press(rng) if effect == "none" else ip.hidden_press(effect, rng)
    return press, (None if effect == "none" else ip.plan_for(effect)), (2 * math.pi * press.mode_hz, press.mode_damping)


def _case(char_dir: Path, work: Path, diagnose: bool) -> dict:
    from piezopress.pipelines import bundle as B
    from piezopress.pipelines import diagnose as D
    from piezopress.pipelines import fit as F

    fitted = F.fit_bundle([char_dir], None)
    res = fitted.result
    h = res.fits["hysteresis"]
    out = {"hyst_pct": h.holdout_rms_pct, "hyst_rms": h.holdout_rms, "sections": sorted(res.sections)}
    m = res.sections.get("shaper", {}).get("mode", {})
    out["wn"], out["zeta"] = m.get("natural_freq_rad_s"), m.get("damping")
    if diagnose:
        B.write_document(F.fit_bundle([char_dir], base=True).doc, work / "base.json")
        result, _ = D.diagnose([char_dir], work / "base.json", work / "diag")
        out["findings"] = [f.cause for f in result.findings] or ["none"]
        out["base_ratio"] = result.base_fit.get("ratio")
    return out


def main() -> None:
    from foreign import foreign_dir

    from piezopress.pipelines import characterize as char
    from piezopress.pipelines import profiles

    ap = argparse.ArgumentParser()
    ap.add_argument("--rig", choices=("ours", "second"), default="second")
    ap.add_argument("--cases", default="none", help="comma-separated hidden effects (none: clean)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--custom", action="store_true", help="minimal metadata with every kind custom")
    ap.add_argument("--no-monitor", action="store_true", help="minimal metadata without the monitor column")
    ap.add_argument("--no-diagnose", action="store_true", help="fit only")
    ap.add_argument("--glitch-every", type=int, default=0)
    a = ap.parse_args()
    for effect in a.cases.split(","):
        press, plan, truth = _press(a.rig, effect, a.seed)
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            t0 = time.perf_counter()
            char.characterize(tmp / "full", backend=press, **({"plan_path": plan} if plan else {}))
            variants = {
                "full": tmp / "full",
                "minimal": foreign_dir(tmp / "full", tmp / "minimal", custom=a.custom, drop_monitor=a.no_monitor),
            }
            if a.glitch_every:
                variants["glitched"] = foreign_dir(tmp / "full", tmp / "glitched", glitch_every=a.glitch_every)
            rows = {}
            for name, d in variants.items():
                (tmp / f"w-{name}").mkdir()
                profiles.trust_metadata(False)
                rows[name] = _case(d, tmp / f"w-{name}", not a.no_diagnose)
            print(
                f"== {a.rig} press, hidden: {effect} (seed {a.seed}); press mode {truth[0]} rad/s, damping {truth[1]}; "
                f"{time.perf_counter() - t0:.0f} s"
            )
            for name, r in rows.items():
                wn = f"{r['wn']:.0f}" if r.get("wn") else "-"
                zeta = f"{r['zeta']:.3f}" if r.get("zeta") else "-"
                print(
                    f"  {name:9s} hysteresis held-out {r['hyst_pct']:.3f} % of range ({r['hyst_rms']:.4g})  mode {wn} "
                    f"rad/s, damping {zeta}  "
                    f"sections {','.join(r['sections'])}  base fit {r.get('base_ratio') or float('nan'):.2f}x noise  "
                    f"findings {','.join(r.get('findings', []))}"
                )


if __name__ == "__main__":
    main()
