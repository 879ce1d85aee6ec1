"""One object per cause (issue 20): the catalogue (:data:`piezopress.analysis.diagnosis.CAUSES`)
holds each cause's physics, fit, needs, extension of the bundle and target rows, and every
other place that names causes reads it or names exactly the same set."""

from __future__ import annotations

import sys
from pathlib import Path

from piezopress.acquisition import rig_config
from piezopress.analysis import diagnosis as dg
from piezopress.pipelines import gain

sys.path.insert(0, str(Path(__file__).resolve().parent))

import independent_press as ip  # noqa: E402
import third_press as tp  # noqa: E402

#: Effects the third press simulates that the catalogue does not hold yet (said by the
#: drive-independent signatures instead: ``piezopress.analysis.signatures``).
NOT_IN_CATALOGUE = {"mains_pickup", "sensitivity_drift"}


def test_every_registry_names_the_catalogue():
    causes = set(dg.CAUSES)
    assert set(rig_config.EFFECTS) == causes  # the virtual rig simulates each one
    assert set(rig_config.DETECTABLE) == causes
    assert set(gain.GAIN_MAGNITUDES) == causes  # and measures its gain on the press
    assert set(ip.DETECTABLE) == causes  # the second press hides each one in a form of its own
    assert set(tp.DETECTABLE) == causes | NOT_IN_CATALOGUE  # the third press too, and two more


def test_the_compensator_applies_exactly_the_causes_that_extend_it():
    for c in dg.CAUSES.values():
        assert c.in_compensator == (c.extend is not None), c.id
        # an extension the compensator applies is judged on the rows it is for, and only those rows
        assert bool(c.targets) == c.in_compensator, c.id
        assert all(row in gain.ROW_BY_ID for row in c.targets), (c.id, c.targets)
    assert gain.targets() == {c.id: c.targets for c in dg.CAUSES.values() if c.in_compensator}
    assert gain.TARGETS == gain.targets()
