"""Lateral landing from the measured state: step to where the lateral capture point goes.

The paper keeps the nominal footstep laterally (only the sagittal step length is
free, eq. 21-26). After a sideways push the lateral divergent component of motion
(DCM, ``xi = y + y' / w``) leaves the walk's, and in single support, with the ZMP
held under the support foot, that deviation grows as ``exp(w t)`` until the
landing (eq. 6-9: the LIPM is linear, so the deviation evolves on its own). The
lateral stop after the landing then needs a ZMP beyond the landing sole, so the
plan loses its margin or falls back to the next step, and on the robot the foot
rolls or slips.

The rule here (a capture-point step, as in Pratt et al. 2006 and IHMC's push
recovery) moves the landing foot laterally by the DCM deviation it will have at
the touchdown, so that the lateral geometry of the stop relative to the landing
foot is the nominal one:

    landing_y = nominal_y + (xi_measured - xi_nominal) * exp(w * landing_duration)

less ``(p - p_nominal) * (exp(w * landing_duration) - 1)`` where a re-plan's ankle
strategy holds the support ZMP at ``p`` instead of the walk's ``p_nominal``
(:func:`drake_estop.planning.replan.ankle_zmp`; the same LIPM solution),
clamped to the step widths the legs can take (:data:`MIN_STEP_WIDTH`, no foot
collision; :data:`MAX_STEP_WIDTH`, the hip's reach). A deviation whose shift is
under :data:`SHIFT_THRESHOLD` (sensor noise) keeps the nominal footstep, so an
unperturbed plan is the paper's.
"""

import math

from drake_estop.planning.gait import NominalPattern, PatternState

MIN_STEP_WIDTH = 0.15  # [m] ankle to ankle: 4 cm between the soles' inner edges (0.055 m each)
MAX_STEP_WIDTH = 0.30  # [m] ankle to ankle: the IK keeps the hip roll within its limit
SHIFT_THRESHOLD = 0.01  # [m] smaller landing shifts (estimator noise, ~1 mm DCM) keep the nominal footstep


def capture_landing_y(pattern: NominalPattern, state: PatternState, landing_duration: float) -> float | None:
    """The lateral landing [m] of the swing foot for a single-support ``state`` whose COG may differ
    from the walk's at ``state.time``, touching down ``landing_duration`` [s] later; None when the
    nominal landing stands (the shift is below :data:`SHIFT_THRESHOLD`)."""
    if state.support != "single" or state.next_landing is None or state.recovery_touchdown is not None:
        return None  # (a recovery step is aimed at the measured DCM already: replan._recovery_step)
    w = pattern.w
    nominal_pos, nominal_vel, _, nominal_zmp = pattern.com([state.time])
    deviation = (state.com[1] - nominal_pos[0][1]) + (state.com_vel[1] - nominal_vel[0][1]) / w
    grow = math.exp(w * max(landing_duration, 0.0))
    # a support ZMP moved off the walk's (a re-plan's ankle strategy) pulls the DCM the other way:
    # xi(T) = p + (xi(t) - p) exp(w T) for both, so the deviation at T loses (p - p_walk)(exp(w T) - 1)
    shift = deviation * grow - (float(state.zmp[1]) - float(nominal_zmp[0][1])) * (grow - 1.0)
    if not math.isfinite(shift) or abs(shift) < SHIFT_THRESHOLD:
        return None
    nominal_y = float(pattern.steps[state.step_index]["end"][1])  # the walk's own footstep, not a re-plan's
    support_y = float(state.feet[state.support_foot][1])
    side = math.copysign(1.0, nominal_y - support_y)  # the swing foot's side
    width = side * (nominal_y + shift - support_y)
    return support_y + side * min(max(width, MIN_STEP_WIDTH), MAX_STEP_WIDTH)
