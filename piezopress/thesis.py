"""The thesis's published figures: the baseline piezopress reproduces and then beats.

Numbers as printed in ``shared/reference/force-controlled-piezo-press-thesis.txt``, with
the table they come from. Data only, no logic.
"""

from __future__ import annotations

#: Table 5.1: maximum hysteresis (%) of a 0 -> 150 V triangle, by frequency (Hz). Uncontrolled.
HYSTERESIS_BY_FREQ_PCT = {0.1: 5.63, 1.0: 5.68, 5.0: 5.72, 10.0: 5.9, 50.0: 8.37, 100.0: 11.24}

#: Section 6.2.1: maximum hysteresis (%) of the 0.1 Hz modelling data sets. Uncontrolled.
HYSTERESIS_FULL_0P1HZ_PCT = 5.5
HYSTERESIS_VARYING_0P1HZ_PCT = 6.17

#: Section 5.2 / Table 5.2: creep (%) after 120 s at maximum drive. Uncontrolled.
CREEP_120S_PCT = 2.36

#: Section 5.3 / Table 5.2: overshoot (%) of a 20 V step. Uncontrolled.
OVERSHOOT_20V_PCT = 25.92

#: Section 6.1: preload before any test (N).
PRELOAD_N = 50.0

#: Table 6.6: maximum hysteresis (%) with the second inverse model; tests 1-6 are
#: triangles of 75, 150, 225, 300 N, increasing and random amplitude, at 0.1 Hz.
HYSTERESIS_COMPENSATED_PCT = {"75N": 1.55, "150N": 1.33, "225N": 2.03, "300N": 2.74, "increasing": 1.85, "random": 2.99}

#: Table 6.9: overshoot (%) and settling time (ms) of shaped steps, by reference force (N).
OVERSHOOT_SHAPED_PCT = {30: 9.28, 100: 4.76, 150: 0.0, 200: 0.0}
SETTLING_SHAPED_MS = {30: 3.9, 100: 4.05, 150: 4.05, 200: 4.25}

#: Table 6.11 (with shaper) and 6.12 (without): hysteresis (%) by frequency, compensated.
HYSTERESIS_COMPENSATED_BY_FREQ_WITH_SHAPER_PCT = {0.1: 3.09, 1.0: 3.84, 5.0: 8.02, 10.0: 12.98, 50.0: 59.95}
HYSTERESIS_COMPENSATED_BY_FREQ_NO_SHAPER_PCT = {0.1: 3.02, 1.0: 2.59, 5.0: 3.08, 10.0: 3.23, 50.0: 5.51}

#: Table 6.13: uncontrolled and controlled ranges.
TABLE_6_13 = {
    "max_static_hysteresis_pct": {"uncontrolled": (5.5, 6.17), "controlled": (1.55, 2.99)},
    "creep_pct": {"uncontrolled": (2.35, 2.35), "controlled": (0.63, 0.96)},
    "overshoot_pct": {"uncontrolled": (25.92, 25.92), "controlled": (0.0, 9.28)},
}

#: Section 6.6: relative tracking error range (%) of the 10 N staircase.
TRACKING_RELATIVE_ERROR_PCT = (-8.08, 12.08)
