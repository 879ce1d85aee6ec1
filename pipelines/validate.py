"""Validation: the thesis's chapter 6 tests with the compensation applied.

Each protocol of the validation plan is a reference force (above the preload); the
bundle's compensator turns it into a drive, the backend plays it, and the run carries the
reference as ``reference_n`` (absolute: preload + reference), written into a new run
directory with a manifest, exactly like a characterization.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

from piezopress import runformat, units
from piezopress.acquisition.backend import Backend
from piezopress.acquisition.drive_check import check_drive
from piezopress.acquisition.plan import DriveLimits, Plan, Protocol, load_plan
from piezopress.analysis.compensation import unreached_while_moving
from piezopress.pipelines.bundle import BundleError, read_bundle
from piezopress.pipelines.characterize import (
    DEFAULT_RIG,
    CharacterizeResult,
    Drive,
    ProgressEvent,
    backend_from,
    execute_plan,
)
from piezopress.pipelines.compensate import ReachError
from piezopress.pipelines.sources import rig_identity
from piezopress.resources import shipped

DEFAULT_VALIDATION_PLAN = shipped("protocols", "validate.toml")


#: Largest share of a validation reference clipped (the top of a 300 N loop at the range's edge
#: clips a few %); above it the protocol is refused before anything runs.
VALIDATE_MAX_CLIP_SHARE = 0.1


@dataclasses.dataclass(frozen=True)
class PreparedValidation:
    """A validation plan with every drive computed through the bundle and checked against the
    press, nothing played yet (:func:`prepare_validation`); :meth:`play` plays it."""

    plan: Plan
    plan_path: Path
    drives: dict[str, Drive]
    manifest_extra: dict[str, Any]

    def play(
        self,
        out_dir: str | Path,
        backend: Backend,
        on_progress: Callable[[ProgressEvent], None] | None = None,
        rig_path: str | Path | None = None,
    ) -> CharacterizeResult:
        """Play every compensated drive on ``backend`` (made from the rig file ``rig_path``, if
        from one) into a new run directory."""

        def drive_for(proto: Protocol) -> Drive:
            return self.drives[proto.name]

        return execute_plan(
            out_dir,
            self.plan,
            self.plan_path,
            backend,
            kind="validation",
            drive_for=drive_for,
            manifest_extra=self.manifest_extra,
            on_progress=on_progress,
            rig_path=rig_path,
        )


def validate(
    out_dir: str | Path,
    bundle_path: str | Path,
    *,
    plan_path: str | Path = DEFAULT_VALIDATION_PLAN,
    rig_path: str | Path | None = DEFAULT_RIG,
    backend: Backend | None = None,
    backend_name: str | None = None,
    use_shaper: bool = True,
    use_creep: bool = True,
    on_progress: Callable[[ProgressEvent], None] | None = None,
    on_warning: Callable[[str], None] | None = None,
) -> CharacterizeResult:
    """Compensate every reference of the validation plan and run it; see the module docstring."""
    backend, made_from = backend_from(backend, backend_name, rig_path)
    prepared = prepare_validation(
        bundle_path,
        backend,
        plan_path=plan_path,
        rig_path=rig_path,
        use_shaper=use_shaper,
        use_creep=use_creep,
        on_warning=on_warning,
    )
    return prepared.play(out_dir, backend, on_progress, rig_path=made_from)


def prepare_validation(
    bundle_path: str | Path,
    backend: Backend,
    *,
    plan_path: str | Path = DEFAULT_VALIDATION_PLAN,
    rig_path: str | Path | None = DEFAULT_RIG,
    use_shaper: bool = True,
    use_creep: bool = True,
    on_warning: Callable[[str], None] | None = None,
) -> PreparedValidation:
    """Every reference of the plan compensated with the bundle and checked against the press's
    limits (its reach, its drive range and slew), before anything is played or written."""
    checked = read_bundle(bundle_path)
    unit = checked.unit
    if not units.is_force(unit):
        raise BundleError(
            f"{bundle_path}: its model's output is {units.quantity(unit)} ({units.label(unit)}); validate plays the "
            "validation plan's force references (N above the preload) on a press that measures force, "
            "expected a force bundle (compensate takes references in the bundle's unit)"
        )
    lim = backend.limits
    s = checked.settings
    # the drive range is the rig's (the press it plays on), said when it differs from the bundle's
    comp = dataclasses.replace(
        checked.compensator(use_shaper=use_shaper, use_creep=use_creep),
        drive_min_v=lim.drive_min_v,
        drive_max_v=lim.drive_max_v,
    )
    if (lim.drive_min_v, lim.drive_max_v) != (s.drive_min_v, s.drive_max_v) and on_warning:
        on_warning(
            f"the drive range is the rig's, {lim.drive_min_v:g} to {lim.drive_max_v:g} V ({rig_path}), not the "
            f"bundle's {s.drive_min_v:g} to {s.drive_max_v:g} V"
        )
    # references are forces above the preload: bounded by the stack's maximum load
    ref_limits = DriveLimits(
        drive_min_v=0.0,
        drive_max_v=lim.max_force_n,
        max_sample_rate_hz=lim.max_sample_rate_hz,
        max_force_n=lim.max_force_n,
        max_duration_s=lim.max_duration_s,
        max_samples=lim.max_samples,
    )
    plan = load_plan(plan_path, ref_limits, unit="N")
    for proto in plan.protocols:  # every reference checked against the bundle before anything is played
        checked.check_reference(
            int(round(proto.duration_s * proto.sample_rate_hz)) + 1,
            proto.sample_rate_hz,
            f"{plan_path}: protocol {proto.name}",
            use_creep=use_creep,
        )
    bundle_sha = runformat.sha256_file(bundle_path)
    other = other_press_note(checked.to_dict(), backend, str(bundle_path))
    if other and on_warning:
        on_warning(other)

    rest = float(comp.hysteresis.y0)

    def compensated(proto: Protocol) -> Drive:
        t, ref = proto.waveform()
        # the reference is the force above the plan's preload: aimed at preload + reference on the
        # model's own scale, not above the model's rest (a stack whose remanence makes it rest
        # above the preload, or a rest the fit estimates a little off, would put that offset
        # into every figure); where that asks for a drive below the range, above the rest
        res = comp.drive(ref + (proto.preload_n - rest), proto.sample_rate_hz)
        if unreached_while_moving(res) > VALIDATE_MAX_CLIP_SHARE and proto.preload_n < rest:
            res = comp.drive(ref, proto.sample_rate_hz)
            res = dataclasses.replace(
                res,
                warnings=(
                    *res.warnings,
                    f"the model rests at {rest:.4g} N, {rest - proto.preload_n:.3g} N above the plan's preload "
                    f"{proto.preload_n:g} N, and the drive range cannot pull the press down to it: the reference is "
                    "aimed above the rest instead, so every figure carries that offset",
                ),
            )
        share = unreached_while_moving(res)  # a creep hold at the range's edge is reached as the press creeps
        if share > VALIDATE_MAX_CLIP_SHARE:
            raise ReachError(
                f"{plan_path}: protocol '{proto.name}': {100 * share:.0f} % of its reference moves where it cannot "
                f"be reached on this rig (drive range {lim.drive_min_v:g} to {lim.drive_max_v:g} V, {rig_path}) "
                f"with {bundle_path}; "
                f"expected at most {100 * VALIDATE_MAX_CLIP_SHARE:g} % (its figures would be a clipped drive's): "
                "lower the plan's references to what the press reaches"
            )
        check_drive(
            res.command_v, proto.sample_rate_hz, lim, f"{plan_path}: protocol '{proto.name}' through {bundle_path}"
        )
        for w in res.warnings:
            if on_warning:
                on_warning(f"{proto.name}: {w}")
        meta = {
            "compensation": {
                "bundle_sha256": bundle_sha,
                "shaper": use_shaper and comp.shaper is not None,
                "creep": use_creep and comp.creep is not None,
                "clipped_samples": res.clipped_samples,
                "warnings": list(res.warnings),
                "notes": list(res.notes),
            }
        }
        return Drive(t, res.command_v, {"reference_n": proto.preload_n + ref}, meta)

    # every drive computed and checked before the directory is made or the rig touched
    drives = {proto.name: compensated(proto) for proto in plan.protocols}
    extra = {
        "bundle": {"file": str(bundle_path), "sha256": bundle_sha},
        "compensation_options": {"shaper": use_shaper, "creep": use_creep},
    }
    return PreparedValidation(plan, Path(plan_path), drives, extra)


def other_press_note(bundle: dict, backend: Backend, bundle_label: str) -> str:
    """A line when the bundle's runs were not recorded on the press ``backend`` plays ('' : they were)."""
    try:
        here = rig_identity({"rig": backend.describe()})
    except Exception:  # a backend whose describe() fails: nothing to compare with
        return ""
    fitted = [
        r
        for sec in ("hysteresis", "creep", "shaper")
        for r in (bundle.get(sec) or {}).get("runs", []) or []
        if isinstance(r, dict)
    ]
    fitted = [r for r in fitted if "rig" in r]  # bundles fitted before the press was recorded: nothing to say
    if here is None or not fitted:
        return ""
    digests = {r.get("rig") for r in fitted}
    if here.digest in digests:
        return ""
    known = sorted(d for d in digests if isinstance(d, str))
    where = f"on another press (rig {', '.join(known)})" if known else "on runs from elsewhere (no press recorded)"
    return (
        f"{bundle_label} was fitted {where}, not on this one ({here.label}): the validation measures that model on "
        "this press, not this press's own model"
    )


__all__ = ["validate", "prepare_validation", "PreparedValidation", "DEFAULT_VALIDATION_PLAN", "other_press_note"]
