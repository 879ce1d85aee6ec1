"""The output unit of a run, carried into every model, bundle, message and figure.

A run measures force (``force_n``, newtons) or displacement (``displacement_um``,
micrometres). Models and bundles store the unit *code* (``"N"``, ``"um"``: plain ASCII, as
in the JSON keys ``y0_n``, ``train_rms_um``, ``max_rate_n_per_s``); text meant for people
shows the *label* (``"N"``, ``"µm"``).

Force-only physics (the preload, a press that cannot pull so a force never reads below 0,
the amplifier-derived reference rate limit in N/ms) applies only where :func:`is_force`.

>>> unit_of_column("displacement_um"), label("um"), key("um"), key("N")
('um', 'µm', 'um', 'n')
>>> quantity("N"), is_force("um")
('force', False)
"""

from __future__ import annotations

#: Run output column -> unit code.
COLUMN_UNITS = {"force_n": "N", "displacement_um": "um"}
#: Unit code -> what a person reads.
LABELS = {"N": "N", "um": "µm"}
#: Unit code -> the measured quantity.
QUANTITIES = {"N": "force", "um": "displacement"}
FORCE = "N"


def unit_of_column(column: str) -> str:
    """Unit code of a run output column (``force_n`` -> ``N``, ``displacement_um`` -> ``um``)."""
    try:
        return COLUMN_UNITS[column]
    except KeyError:
        raise ValueError(
            f"output column {column!r} has no known unit; expected one of {', '.join(COLUMN_UNITS)}"
        ) from None


def normalise(unit: str | None) -> str:
    """A unit code from a code or a label in any case (``"n"``, ``"µm"``, ``"UM"``); ``None`` -> ``N``."""
    if unit is None:
        return FORCE
    u = str(unit).strip()
    for code, lab in LABELS.items():
        if u.lower() in (code.lower(), lab.lower()):
            return code
    return u


def label(unit: str | None) -> str:
    """The unit as a person reads it: ``um`` -> ``µm``."""
    u = normalise(unit)
    return LABELS.get(u, u)


def key(unit: str | None) -> str:
    """The unit as it appears in JSON keys and column names: ``N`` -> ``n``, ``um`` -> ``um``."""
    return normalise(unit).lower()


def quantity(unit: str | None) -> str:
    """``force`` or ``displacement`` (``output`` for anything else)."""
    return QUANTITIES.get(normalise(unit), "output")


def is_force(unit: str | None) -> bool:
    """True for a force unit: force-only physics (preload, contact clamp at 0 N) applies."""
    return normalise(unit) == FORCE


def keyed(d: dict, prefix: str, unit: str | None = None, default=None):
    """``d[prefix + key(unit)]``; without ``unit``, the first key starting with ``prefix``
    (documents written before the unit was carried hold only ``_n`` keys)."""
    if unit is not None:
        return d.get(prefix + key(unit), default)
    for k, v in d.items():
        if k.startswith(prefix):
            return v
    return default
