"""The recovery step: a step of the rear foot out of a double-support stop that no ZMP within the feet holds.

Where a push sends the measured DCM past the fore foot's ankle (sagittally) far enough that no
double-support stop exists (III.B), the rear foot lifts and lands ahead, the stop solved as a
single-support stop (III.A, eq. 21-26) on the fore foot from the measured COG
(:func:`recovery_step`). :func:`drake_estop.planning.replan.replan_stop` tries it after its
double-support try, and :func:`drake_estop.planning.capture_landing.capture_step` plans it after a capture
landing that stops nothing (N-step capture). :func:`zmp_to_reach` and :func:`on_sole` are the ZMP
helpers the re-plans share (eq. 6-9; a point of a sole less a margin).
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from drake_estop.planning.assembly import plan_from, with_compute_time
from drake_estop.planning.capture import MAX_STEP_WIDTH
from drake_estop.planning.gait import SIDES, rotation
from drake_estop.planning.plan import InfeasibleStop, StopParameters, StopPlan


def zmp_to_reach(xi_now, xi_target, grow):
    """The ZMP ``p`` that, held while the DCM grows by ``grow = exp(w T)``, takes it from ``xi_now`` to
    ``xi_target``: ``xi(T) = p + (xi_now - p) grow`` (eq. 6-9) solved for ``p``."""
    return (xi_target - xi_now * grow) / (1.0 - grow)


def on_sole(sole, side: str, ankle, turn, local, margin: float):
    """``local`` (a point in the frame of the ``side`` sole: ankle ``ankle``, rotation ``turn``) clamped to
    the sole less ``margin`` (toe, heel, inner and outer edges), in world axes."""
    left_edge, right_edge = sole.lateral_edges(side)
    local = np.array([np.clip(local[0], -sole.heel + margin, sole.toe - margin),
                      np.clip(local[1], -right_edge + margin, left_edge - margin)])
    return ankle + turn @ local


#: ZMP margin [m] of a recovery step's plan (or the plan's own, if smaller). A recovery step is planned
#: where the controller's 3 cm stop has no solution; with 3 cm its halt had none either (30 N s forward
#: push in double support: at most 3.6 mm at the first try; measured before the step's lateral aim, with
#: which 1.5 cm finds it at that first try).
RECOVERY_ZMP_MARGIN = 0.015


#: A recovery step needs the measured DCM past the fore ankle (sagittally) by at least this share of the sole's toe
#: length (:func:`recovery_dcm_ahead`: 5 cm on the default humanoid's 13.5 cm toe, 3.5 cm on TALOS's 9.5 cm).
#: Measured on the robustness benchmark (default humanoid): steps taken from DCMs 2.5-3.5 cm past the ankle (a left
#: push late in single support, a backward push in double support whose rebound failed a double-support re-plan)
#: failed two runs that held without them; the forward pushes the steps caught had it 6.8-8.2 cm past. A share of
#: the toe, not a length: a shorter sole has less room ahead of the ankle for the ZMP that holds the DCM while the
#: rear foot swings (on TALOS's 0.3 m/s forward push at its first double-support tick the DCM lay 4.97 cm past the
#: ankle at the first re-plan; it steps there, 50 ms before a fixed 5 cm would let it, and both stop). Laterally
#: the DCM may lie no further towards the rear foot than the fore sole's inner edge less the margin (the step lifts
#: that foot) unless the robot's StopParameters.recovery_step_inward says so: in the default humanoid's campaign,
#: steps from DCMs 4.6-9.9 cm towards it (pushes forward-left and left) made a run that passed fall, another fail
#: by 0.4 mm and a third, failing already, fall; with the landing widened instead (recovery_step_inward), 2 of the
#: campaign's first 122 runs that had stopped failed (CoP 0.4 and 12 mm out) and none was gained.
RECOVERY_DCM_TOE_SHARE = 0.37


def recovery_dcm_ahead(sole) -> float:
    """How far [m] past the fore ankle the measured DCM must be for a recovery step: the
    :data:`RECOVERY_DCM_TOE_SHARE` of the ``sole``'s toe length, to the millimetre."""
    return round(RECOVERY_DCM_TOE_SHARE * sole.toe, 3)


def recovery_step(plan: StopPlan, t: float, com_xy, com_vel_xy, params: StopParameters, footholds,
                   failure: InfeasibleStop) -> StopPlan:
    """:func:`~drake_estop.planning.replan.replan_stop`'s recovery step out of a double-support stop at ``t``
    (re-raises ``failure`` where it does not apply or has no stop either).

    The state: single support on the fore foot (along the feet's mean heading), the rear foot at rest
    on the floor as the swing foot (lifted from ``t``: the swing's clearance bump), both at ``footholds``
    where given. The ZMP steps, at rest, onto the fore sole less ``zmp_margin``: sagittally under the
    measured DCM (holding it, eq. 6-9; a CoP already on the toe stays there), laterally where it sends the
    DCM to the feet's midline by the soonest touchdown the swing speed allows. A DCM heading for the rear
    foot's side, past the fore sole's inner edge less the margin, takes no step (lifting that foot drops
    the robot onto its side), unless ``params.recovery_step_inward`` (a robot's measured choice): then the
    step lands as wide as the LIPM's DCM at that touchdown needs to lie between the feet
    (:func:`recovery_landing_width`, within the robot's step widths), and a DCM past even the widest
    landing's ankle takes none. Otherwise the landing keeps the rear foot's lateral offset from the fore
    foot, along the fore foot's heading; its length, the landing time and the phases after it are the
    single-support solve's (III.A, eq. 21-26), the nominal touchdown one single-support time after ``t``.
    """
    feet = plan.feet(t)
    now = {side: np.array([*np.asarray((footholds or {}).get(side, feet[side][:2]), float)[:2], 0.0])
           for side in SIDES}
    yaw, _ = plan.feet_yaw(t)
    heading = rotation(0.5 * (yaw["left"] + yaw["right"]))
    along = {side: float((heading.T @ now[side][:2])[0]) for side in SIDES}
    fore = max(SIDES, key=along.get)
    rear = next(side for side in SIDES if side != fore)
    w = plan.pattern.w
    com, vel = np.asarray(com_xy, float)[:2].copy(), np.asarray(com_vel_xy, float)[:2].copy()
    dcm = com + vel / w
    turn = rotation(float(yaw[fore]))
    local = turn.T @ (dcm - now[fore][:2])  # the DCM in the fore sole's frame
    sole = plan.pattern.params.sole
    if local[0] < recovery_dcm_ahead(sole):
        raise failure  # the DCM is not far past the fore ankle: the stop's own limits failed, not the feet
    if float((turn.T @ (com - now[rear][:2]))[0]) > params.max_rear_reach:
        raise failure  # the rear leg is stretched straight: it drags over the floor instead of lifting
    params = replace(params, zmp_margin=min(params.zmp_margin, RECOVERY_ZMP_MARGIN))
    margin = params.zmp_margin
    lateral = float((turn.T @ (now[rear][:2] - now[fore][:2]))[1])
    lateral = math.copysign(min(max(abs(lateral), params.min_step_width), params.max_step_width), lateral)
    behind = float((turn.T @ (dcm - now[rear][:2]))[0])  # the DCM ahead of the rear ankle
    if not params.recovery_step_inward and math.copysign(1.0, lateral) * local[1] > sole.inner - margin:
        raise failure  # the DCM heads for the rear foot's side: lifting that foot drops the robot onto it
    # sagittal: the ZMP under the DCM holds it (eq. 6-9); lateral: the ZMP that brings the DCM to the feet's
    # midline by the soonest touchdown the swing speed allows, xi(T) = p + (xi - p) exp(w T) (as ankle_zmp)
    soonest = max(params.min_landing_time, behind / params.max_swing_speed)
    grow = math.exp(w * soonest)
    lateral_zmp = zmp_to_reach(local[1], 0.5 * lateral, grow)
    zmp = on_sole(sole, fore, now[fore][:2], turn, np.array([local[0], lateral_zmp]), margin)
    width = recovery_landing_width(local[1], float((turn.T @ (zmp - now[fore][:2]))[1]), lateral, grow,
                                   params.max_step_width)
    if width is None:
        raise failure  # the DCM heads past the widest landing: lifting the rear foot drops the robot onto it
    gait = plan.pattern.params
    zero = np.zeros(3)
    upper, upper_rate = plan.upper_body(t)
    state = replace(
        plan.start_state, time=float(t), support="single", support_foot=fore, com=com, com_vel=vel, zmp=zmp,
        zmp_rate=np.zeros(2), zmp_accel=np.zeros(2), feet=now, feet_vel={side: zero.copy() for side in SIDES},
        feet_acc={side: zero.copy() for side in SIDES},
        next_landing=now[fore][:2] + turn @ np.array([gait.step_length, width]), rear_foot=None,
        upper_body=upper, upper_body_rate=upper_rate, feet_yaw=dict(yaw),
        feet_yaw_rate={side: 0.0 for side in SIDES}, next_landing_yaw=float(yaw[fore]),
        recovery_touchdown=float(t) + gait.single_support_time)
    wall = time.perf_counter()
    try:
        new = plan_from(plan.pattern, state, params, plan.signal_time, plan.case)
    except InfeasibleStop as error:
        raise InfeasibleStop(f"{failure}; recovery step: {error}") from error
    new.crouch_window = plan.crouch_window or (plan.start_time, plan.halt_end)
    new.recovery_step = True
    new.swing_start = dict(new.swing_start, clearance=plan.pattern.params.lift_height)  # lifted from the floor
    return with_compute_time(new, wall)


def recovery_landing_width(dcm_y: float, zmp_y: float, lateral: float, grow: float,
                           max_width: float = MAX_STEP_WIDTH) -> float | None:
    """A recovery step's landing offset [m] across the fore foot (signed as ``lateral``, the rear foot's
    offset clamped to the step widths), or None where no landing within them catches the DCM.

    ``dcm_y`` and ``zmp_y`` [m] are the measured DCM and the held ZMP across the fore sole and ``grow``
    ``= exp(w T)`` for the soonest touchdown ``T``: the DCM there is ``p + (xi - p) grow`` (eq. 6-9). The
    landing keeps ``lateral`` unless that DCM lies past its midline; then it lands twice the DCM's offset
    out (the DCM at the new feet's midline), at most ``max_width`` [m] (the robot's
    ``StopParameters.max_step_width``). None where the DCM passes even that landing's ankle.
    """
    side = math.copysign(1.0, lateral)
    reach = side * (zmp_y + (dcm_y - zmp_y) * grow)  # towards the rear foot's side
    if reach > max_width:
        return None
    if 2.0 * reach <= abs(lateral) + 1e-9:  # (a ZMP aimed at the midline reaches it to rounding: the width stands)
        return lateral
    return side * min(2.0 * reach, max_width)
