"""Which press a run comes from, and the refusal to join runs of two presses unless told.

A run recorded by ``characterize`` carries its rig's whole configuration (``meta.rig.config``);
its identity is that configuration's digest (the noise seed left out: the same press measured
again). A run from elsewhere (an import, another program) names no rig: its press is unknown
and it joins any other. Stages that join runs (``fit``, ``fit-*``, ``diagnose``) refuse runs of
two known presses unless ``--allow-mixed-rigs`` (:func:`allow_mixed_rigs`), naming which run
comes from which.
"""

from __future__ import annotations

import copy
import hashlib
import json
from collections.abc import Iterable
from contextvars import ContextVar
from dataclasses import dataclass
from typing import Any

from piezopress import runformat
from piezopress.errors import PiezopressError

DIGEST_CHARS = 12

_ALLOW_MIXED: ContextVar[bool] = ContextVar("allow_mixed_rigs", default=False)


class MixedRigsError(PiezopressError, ValueError):
    """Runs of two presses joined without ``--allow-mixed-rigs``."""


def allow_mixed_rigs(allow: bool = True) -> None:
    """Let the stages that join runs join runs of several presses (``--allow-mixed-rigs``)."""
    _ALLOW_MIXED.set(bool(allow))


def mixed_rigs_allowed() -> bool:
    return _ALLOW_MIXED.get()


def config_digest(config: Any) -> str:
    """sha256 of a rig configuration as the runs recorded it (canonical JSON)."""
    return hashlib.sha256(json.dumps(config, sort_keys=True, separators=(",", ":"), default=str).encode()).hexdigest()


@dataclass(frozen=True)
class RigIdentity:
    """A press as its runs record it: the configuration's digest and a name for a person."""

    digest: str
    label: str

    def as_dict(self) -> dict[str, str]:
        return {"digest": self.digest, "label": self.label}


def rig_identity(meta: Any) -> RigIdentity | None:
    """The press a run's metadata names (``None``: it names none, as runs from elsewhere)."""
    config = runformat.meta_get(meta, "rig", "config")
    if not isinstance(config, dict) or not config:
        return None
    config = copy.deepcopy(config)
    if isinstance(config.get("rig"), dict):
        config["rig"].pop("seed", None)  # the noise of one measurement, not the press
    digest = config_digest(config)[:DIGEST_CHARS]
    name = runformat.meta_get(meta, "rig", "config", "rig", "name", default=None)
    source = runformat.meta_get(meta, "rig", "source", default=None)
    backend = runformat.meta_get(meta, "rig", "backend", default=None) or (
        meta.get("backend") if isinstance(meta, dict) else None
    )
    words = [str(w) for w in (backend, name) if isinstance(w, str) and w]
    label = f"{' rig '.join(words) if words else 'rig'} {digest}" + (f" ({source})" if isinstance(source, str) else "")
    return RigIdentity(digest, label)


def group_by_rig(runs: Iterable[runformat.Run]) -> dict[RigIdentity, list[str]]:
    """The runs' names by the press they name (runs naming none left out)."""
    by_digest: dict[str, RigIdentity] = {}  # one press, one digest: the first label names it (files may differ)
    groups: dict[RigIdentity, list[str]] = {}
    for r in runs:
        ident = rig_identity(r.meta)
        if ident is not None:
            ident = by_digest.setdefault(ident.digest, ident)
            groups.setdefault(ident, []).append(r.path.name if r.path is not None else r.name)
    return groups


def check_same_press(runs: Iterable[runformat.Run], other: Any, what: str) -> None:
    """Refuse ``what`` (a diagnosis, a bundle: its recorded presses ``other``, a list of
    ``{"digest", "label"}``) when it names presses and none is one of the runs' (unless
    :func:`allow_mixed_rigs`)."""
    if mixed_rigs_allowed() or not isinstance(other, list):
        return
    theirs = {o.get("digest"): o.get("label", o.get("digest")) for o in other if isinstance(o, dict)}
    ours = group_by_rig(runs)
    if not theirs or not ours or set(theirs) & {i.digest for i in ours}:
        return
    raise MixedRigsError(
        f"{what} is of another press ({', '.join(map(str, theirs.values()))}) than the runs "
        f"({', '.join(i.label for i in ours)}); expected one press's: give that press's diagnosis, or pass "
        "--allow-mixed-rigs to show it anyway"
    )


def check_one_rig(runs: Iterable[runformat.Run], what: str = "the runs") -> None:
    """Refuse runs of more than one known press (unless :func:`allow_mixed_rigs`), naming each."""
    if mixed_rigs_allowed():
        return
    groups = group_by_rig(runs)
    if len(groups) <= 1:
        return
    parts = [
        f"{ident.label}: {', '.join(names[:4])}{' ...' if len(names) > 4 else ''}" for ident, names in groups.items()
    ]
    raise MixedRigsError(
        f"{what} come from {len(groups)} presses ({'; '.join(parts)}); expected one press's runs (a model of two "
        "presses fits neither): give one press's runs, or pass --allow-mixed-rigs to join them anyway"
    )
