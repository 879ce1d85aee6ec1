"""The plans and rig files shipped with piezopress, wherever it runs from.

Installed (``pip install .``), ``protocols/`` and ``rigs/`` are package data of the
subpackages ``piezopress.protocols`` and ``piezopress.rigs`` and are found through
:mod:`importlib.resources`; in a checkout they are the top-level folders of the tree. Either
way the result is a real directory on disk: plans and rig files are read by path, and
``piezopress protocols --copy`` / ``rig-keys --template`` copy them from there.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

#: The kinds of shipped file: the folder of each (``protocols/`` plans, ``rigs/`` rig files).
KINDS = ("protocols", "rigs")


def shipped_dir(kind: str) -> Path:
    """The directory of the shipped ``kind`` (``"protocols"`` or ``"rigs"``)."""
    if kind not in KINDS:
        raise ValueError(f"unknown kind of shipped file {kind!r}: expected one of {', '.join(KINDS)}")
    try:
        where = resources.files(f"piezopress.{kind}")
    except ModuleNotFoundError:
        where = None
    for path in _paths(where):
        if path.is_dir() and any(path.glob("*.toml")):
            return path
    checkout = Path(__file__).resolve().parents[1] / kind  # a checkout without piezopress/__init__'s path
    if checkout.is_dir():
        return checkout
    raise FileNotFoundError(
        f"the shipped {kind}/ folder is missing from this installation of piezopress "
        f"(looked in {', '.join(str(p) for p in _paths(where)) or 'the package'}); reinstall it"
    )


def shipped(kind: str, name: str) -> Path:
    """The path of the shipped file ``name`` of ``kind`` (e.g. ``shipped("rigs", "thesis-press.toml")``)."""
    return shipped_dir(kind) / name


def _paths(where) -> list[Path]:
    """The real directories behind a :mod:`importlib.resources` traversable (a namespace
    package in a checkout is a multiplexed path over its folders)."""
    if where is None:
        return []
    if isinstance(where, Path):
        return [where]
    inner = getattr(where, "_paths", None)  # importlib's MultiplexedPath (a namespace package)
    if inner is not None:
        return [Path(str(p)) for p in inner]
    return [Path(str(where))]


__all__ = ["KINDS", "shipped_dir", "shipped"]
