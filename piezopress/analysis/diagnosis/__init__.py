"""Diagnosis: what the model gets wrong, its physical cause, the extended model, the gain.

The model judged is the bundle's forward model ("the simulation")::

    y_hat = y0 + lowpass( mode( creep( H(x) - y0 ) ) )       (a force clipped at 0 N: contact)

Everything is in the model's output unit (``hysteresis.output_unit``: N for a force run, um
for a displacement run): residuals, noise floors, the keys of :meth:`Diagnosis.as_dict`
(``residual_rms_n`` or ``residual_rms_um``) and the texts. The contact clip applies to
force only: a displacement goes negative wherever the data do.

On every run the residual ``y - y_hat`` is compared with the sensor's noise floor and
analysed (whiteness; correlation with the drive level, rate, current and time since a
step; dominant frequency). A catalogue of causes (:data:`CAUSES`) each holds a physical
explanation, an extension of the model (a parameter of :class:`Model`) and a fit of that
extension. Every extension is fitted on runs or segments and judged on others it did not
see: the gain is the held-out RMS residual of the current model against the extended one.

The search is greedy: every cause is tried on the current model, the one with the largest
held-out gain is accepted if it clears :data:`MIN_GAIN_PCT` with residuals above the noise,
the model is extended, and the remaining causes are tried again on what is left. An effect
partly mimicked by another cause is therefore not reported twice. When the residuals are at
the noise floor there are no findings; structure that no cause explains is listed as
unexplained, never named.

Judging data: runs the base model was not fitted on are preferred (the fast sweeps, the
larger steps, a rest run); the base fit's own runs are used in time segments it did not see
where a cause needs them (the end of the creep hold).

Pure math on arrays: runs come in as :class:`RunData`, models as analysis objects.
"""

from __future__ import annotations

from piezopress.analysis import creep as creep_mod  # noqa: F401
from piezopress.analysis import hysteresis as H  # noqa: F401
from piezopress.analysis.diagnosis.cause import (  # noqa: F401
    _FAST_STEPS,
    Cause,
)
from piezopress.analysis.diagnosis.causes import CAUSES  # noqa: F401
from piezopress.analysis.diagnosis.causes.amplifier_slew_limit import (  # noqa: F401
    _monitor_slew,
    cause_amplifier_slew_limit,
)
from piezopress.analysis.diagnosis.causes.drive_coupled_interference import (  # noqa: F401
    INTERFERENCE_TAUS_S,
    SIGNED_TAU_MAX_S,
    SIGNED_TAUS_S,
    cause_drive_coupled_interference,
)
from piezopress.analysis.diagnosis.causes.hysteresis_order import (  # noqa: F401
    _ORDER_MEMO,
    cause_hysteresis_order,
)
from piezopress.analysis.diagnosis.causes.input_delay import (  # noqa: F401
    DELAY_FIT_MAX_SAMPLES,
    _delay_on_sweeps,
    cause_input_delay,
)
from piezopress.analysis.diagnosis.causes.logarithmic_creep import (  # noqa: F401
    _creep_fit,
    _slow,
    cause_logarithmic_creep,
)
from piezopress.analysis.diagnosis.causes.mains_pickup import (  # noqa: F401
    MAINS_DRIVE_SHARE,
    MAINS_FIT_FRACTION,
    _band,
    _mains_lines,
    cause_mains_pickup,
)
from piezopress.analysis.diagnosis.causes.rate_dependent_hysteresis import (  # noqa: F401
    RATE_GATE_PCT,
    RATE_SATURATIONS_V_PER_S,
    _rate_forms,
    cause_rate_dependent_hysteresis,
)
from piezopress.analysis.diagnosis.causes.second_resonance import (  # noqa: F401
    cause_second_resonance,
)
from piezopress.analysis.diagnosis.causes.sensitivity_drift import (  # noqa: F401
    REPEAT_FROM,
    cause_sensitivity_drift,
    repeats,
    run_starts,
)
from piezopress.analysis.diagnosis.causes.sensor_offset_drift import (  # noqa: F401
    cause_sensor_offset_drift,
)
from piezopress.analysis.diagnosis.judging import (  # noqa: F401
    CHAIN_LAG_S,
    MIN_GAIN_PCT,
    MIN_IMPROVEMENT_TO_FLOOR,
    MIN_MODE2_SHARE,
    MIN_RESIDUAL_TO_FLOOR,
    UNEXPLAINED_RATIO,
    Context,
    Finding,
    Segment,
    _cost,
    _err,
    _fast_base,
    _fast_split,
    _forces,
    _judge,
    _judge_dynamics,
    _level_free,
    _refit_mode,
    _search,
    _split,
    _time_split,
    _with_chain_lag,
)
from piezopress.analysis.diagnosis.model import (  # noqa: F401
    _CREEP_MEMO,
    _PLAY_MEMO,
    _STATIC_MEMO,
    Model,
    RunData,
    interference_reading,
)
from piezopress.analysis.diagnosis.needs import (  # noqa: F401
    _KIND_WORDS,
    LAG_SAMPLES,
    LAG_VISIBLE_FLOORS,
    MODEL_PARTS,
    POOR_FIT_RATIO,
    SWEEP_KINDS,
    Need,
    RunSpec,
    Testability,
    _hz,
    describe_runs,
    lag_visible,
    testability,
)
from piezopress.analysis.diagnosis.residuals import (  # noqa: F401
    TONE_OVER_MEDIAN,
    ResidualStats,
    _corr,
    judged,
    noise_floor,
    residual_stats,
    rms,
)
from piezopress.analysis.diagnosis.search import (  # noqa: F401
    MOVES_AT_REST,
    CauseProgress,
    Diagnosis,
    _base_fit,
    _held_out_rms,
    _unique_names,
    diagnose,
)
from piezopress.analysis.diagnosis.slow import (  # noqa: F401
    DRIFT_CREEP_TAUS_S,
    DRIFT_MAX_OF_RANGE,
    DRIFT_WARMUP_TAU_S,
    _drift_fit,
    _DriftFit,
    _long_runs,
    _slow_judge,
    _slow_residual,
)
