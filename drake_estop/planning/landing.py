"""The landing's limits in single support: how soon the swing foot can land and how far the stop may reach.

The swing foot's nominal touchdown and its earliest landing (its descent and ``max_early_landing``),
and the :class:`~drake_estop.planning.plan.StopParameters` of one stop solve narrowed for the state it
starts from: the step-length bounds of a descending foot (``max_landing_shift_per_height``), the fore
and rear reach where the feet lie further apart sideways than on the straight walk, and the limits
:func:`drake_estop.planning.assembly.plan_from` tries where the given ones find no stop.
"""

from __future__ import annotations

import math
from dataclasses import replace

from drake_estop.planning.gait import NominalPattern, PatternState
from drake_estop.planning.plan import StopParameters, snap_to_tick
from drake_estop.planning.problems import descent_time


def nominal_touchdown(pattern: NominalPattern, state: PatternState) -> float:
    """The swing foot's nominal touchdown [s]: the walk's step's, or a recovery step's own."""
    if state.recovery_touchdown is not None:
        return float(state.recovery_touchdown)
    return float(pattern.steps[state.step_index]["touchdown"])


def _nominal_landing_window(pattern: NominalPattern, state: PatternState, params: StopParameters):
    """``params`` whose ``min_landing_time`` admits the nominal touchdown where that is sooner, in single
    support (None elsewhere): the swing foot lands no later than it would have. Late in single support
    the foot is a few millimetres above the floor and lands by the walk's own timing; the stop still
    moves the landing point (eq. 21-22) instead of finishing the step and stopping in the next support
    phase (III.C). Tried only where the limits as given find no stop: where a landing after
    ``min_landing_time`` stops the robot, the paper's optimum stands (at 3.4 s it postpones the
    touchdown and lengthens the step, Section V.A)."""
    if state.support != "single":
        return None
    dt = params.servo_period
    soonest = max(snap_to_tick(nominal_touchdown(pattern, state) - state.time, dt), dt)
    if soonest >= params.min_landing_time:
        return None
    return replace(params, min_landing_time=soonest)


def swing_descent_time(state: PatternState, params: StopParameters, swing: str) -> float:
    """:func:`descent_time` of the ``swing`` foot from its height, vertical velocity and acceleration."""
    return descent_time(float(state.feet[swing][2]), params, float(state.feet_vel[swing][2]),
                        float(state.feet_acc[swing][2]))


def earliest_landing(state: PatternState, params: StopParameters, swing: str, touchdown: float) -> float:
    """Shortest time to touchdown [s]: the swing foot's descent (:func:`descent_time`), and no
    earlier than ``max_early_landing`` before the nominal touchdown (at most ``max_landing_time``)."""
    descent = swing_descent_time(state, params, swing)
    early = touchdown - state.time - params.max_early_landing
    return max(descent, min(early, params.max_landing_time - params.servo_period))


#: The least landing shift :func:`landing_shift_limit` allows [m] (a foot already on the floor keeps
#: its landing to the millimetre; the step-length bounds must stay an interval).
MIN_LANDING_SHIFT = 1e-3


def landing_shift_limit(state: PatternState, params: StopParameters, swing: str) -> StopParameters:
    """``params`` with the step-length bounds narrowed to the nominal step length +- the swing foot's
    height times ``max_landing_shift_per_height``, for a swing foot coming down (unchanged when that
    is inf, and for a foot still rising: a foot leaving the floor gets a clearance bump instead,
    :func:`drake_estop.planning.plan.landing_swing`)."""
    if not math.isfinite(params.max_landing_shift_per_height) or state.feet_vel[swing][2] >= -1e-9:
        return params
    shift = max(float(state.feet[swing][2]) * params.max_landing_shift_per_height, MIN_LANDING_SHIFT)
    nominal = float(state.next_landing[0] - state.zmp[0])
    low, high = max(params.min_step_length, nominal - shift), min(params.max_step_length, nominal + shift)
    if low >= high:  # the nominal step outside the planner's own bounds: those bounds decide
        return params
    return replace(params, min_step_length=low, max_step_length=high)


LATERAL_REACH_ALLOWANCE = 0.02  # [m] lateral COG-to-landing-ankle offset beyond step_width / 2 that
# max_fore_reach already covers: on the straight walk the COG passes 0.110-0.115 m beside the landing
# ankle at touchdown (step width 0.19 m), where max_fore_reach was measured. With 0.03 the outer knee of a
# +15 deg/step turn, landing as soon as the descent limit allows, reached 6.3 rad/s (limit 6)


def lateral_reach(pattern, state: PatternState, params: StopParameters) -> StopParameters:
    """``params`` with ``max_fore_reach`` shortened where the landing ankle lies further to the side of
    the COG at the nominal touchdown than on the straight walk (the outer foot of a turn, a side-step,
    a slow gait's wider sway): the horizontal COG-to-ankle distance ``hypot(dx, dy)`` then stays within
    the straight walk's ``hypot(max_fore_reach, step_width / 2 + LATERAL_REACH_ALLOWANCE)``, which keeps
    the landing knee bent (at +15 deg per step the outer knee otherwise reached 14 rad/s, limit 6).
    Measured on the walk's nominal footstep and COG: a capture-point landing (planning/capture.py)
    moves the foot by the COG's own deviation, which leaves their lateral offset as it was."""
    if state.recovery_touchdown is not None:  # no walk footstep: the step is aimed from the measured DCM
        return params
    # the walk's own footstep: a capture-point shift follows the COG
    lateral = abs(float(pattern.touchdown_com_offset(state.step_index)[1]))
    allowed = 0.5 * pattern.params.step_width + LATERAL_REACH_ALLOWANCE
    if lateral <= allowed:
        return params
    return replace(params, max_fore_reach=_sideways_reach(params.max_fore_reach, allowed, lateral))


def _sideways_reach(reach: float, allowed: float, lateral: float) -> float:
    """The sagittal reach [m] that keeps ``hypot(reach, allowed)`` with the ankle ``lateral`` [m] to the
    side of the COG instead of ``allowed`` (at least half of ``reach``)."""
    return math.sqrt(max(reach**2 + allowed**2 - lateral**2, 0.25 * reach**2))


def rear_lateral_reach(pattern, state: PatternState, params: StopParameters) -> StopParameters:
    """``params`` with ``max_rear_reach`` shortened where the walk's own footstep leaves the feet further
    apart sideways than on the straight walk (in the stop's frame: the outer foot of a turn): the COG
    comes to rest between them, so the horizontal COG-to-rear-ankle distance ``hypot(dx, separation / 2)``
    then stays within the straight walk's ``hypot(max_rear_reach, step_width / 2)``. Measured on a
    +15 deg/step turn (feet 0.226 m apart in the stop's frame, 0.19 m on the straight walk): with the full
    sagittal reach the rear knee straightened in the slowdown and the IK drove it at 10.8 rad/s (limit 6).
    The walk's footstep, not a capture-point landing (planning/capture.py): a sideways push that widens the
    step moves the COG with it, and its stops keep the full reach."""
    if state.recovery_touchdown is not None:  # no walk footstep: the step is aimed from the measured DCM
        return params
    separation = float(pattern.steps[state.step_index]["end"][1]) - float(state.feet[state.support_foot][1])
    lateral = 0.5 * abs(separation)
    allowed = 0.5 * pattern.params.step_width
    if lateral <= allowed + 1e-9:
        return params
    return replace(params, max_rear_reach=_sideways_reach(params.max_rear_reach, allowed, lateral))


#: J_ds's ZMP weight (eq. 30) as the paper has it: the double-support retry of :func:`retry_limits`.
PAPER_A_DS = StopParameters().a_ds


def retry_limits(pattern: NominalPattern, state: PatternState, params: StopParameters):
    """The limits :func:`drake_estop.planning.assembly.plan_from` tries, in order, after the given ones
    found no stop. Double support: J_ds with the paper's ZMP weight (:data:`PAPER_A_DS`) where ``a_ds``
    is another (a heavier weight takes a longer, gentler stop whose halt may not fit the margin where the
    paper's quick one does). Single support: the nominal landing window, then the slowdown ZMP at the
    landing ankle (eq. 20), without and with that window."""
    if state.support != "single":
        if params.a_ds != PAPER_A_DS:
            yield replace(params, a_ds=PAPER_A_DS)
        return
    window = _nominal_landing_window(pattern, state, params)
    if window is not None:
        yield window
    if params.landing_zmp_offset != 0.0:
        yield replace(params, landing_zmp_offset=0.0)
        if window is not None:
            yield replace(window, landing_zmp_offset=0.0)
