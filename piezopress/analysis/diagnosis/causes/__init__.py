"""The catalogue: one module per cause, each holding its fit and its entry (``CAUSE``).

Adding a cause is one new module here (its fit, what it needs, how it extends the bundle, the
rows it targets) plus its simulated effect on the test presses; :data:`CAUSES` lists it.
"""

from __future__ import annotations

from piezopress.analysis.diagnosis.cause import Cause
from piezopress.analysis.diagnosis.causes import (
    amplifier_slew_limit,
    drive_coupled_interference,
    hysteresis_order,
    input_delay,
    logarithmic_creep,
    mains_pickup,
    rate_dependent_hysteresis,
    second_resonance,
    sensitivity_drift,
    sensor_offset_drift,
)

#: Every cause by its id, in the order the search tries them.
CAUSES: dict[str, Cause] = {
    c.id: c
    for c in (
        rate_dependent_hysteresis.CAUSE,
        amplifier_slew_limit.CAUSE,
        drive_coupled_interference.CAUSE,
        logarithmic_creep.CAUSE,
        second_resonance.CAUSE,
        sensor_offset_drift.CAUSE,
        sensitivity_drift.CAUSE,
        mains_pickup.CAUSE,
        input_delay.CAUSE,
        hysteresis_order.CAUSE,
    )
}
