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
clamped to the step widths the legs can take (``StopParameters.min_step_width``,
no foot collision; ``max_step_width``, the leg's reach). A deviation whose shift is
under :data:`SHIFT_THRESHOLD` (sensor noise) keeps the nominal footstep, so an
unperturbed plan is the paper's.

**Landing in time** (:func:`capture_time`). A landing clamped at
``max_step_width`` catches the DCM only if the foot is down before the DCM
passes the landed sole's outer edge. Measured, 29 N s to the right at 2.95 s
(the left foot supporting): the plan's landing point lay 0.41 m ahead of the
swing foot, which the braked swing (15 m/s^2) reached 0.44 s after the push,
when the DCM was 0.12 m past the landed sole. The re-plan's capture landing
(:func:`drake_estop.planning.capture_landing.capture_setup`) lands sooner and nearer
instead: by the time the DCM reaches the widest landing ankle, at a landing
point the swing can still brake onto; that stop meets every criterion.

**No second lateral step** (:func:`step_out_gain`). After the landing the foot on
the push side carries the robot: a DCM beyond its outer edge could only be caught
by that foot stepping further out, with the ZMP on the other foot meanwhile (no
crossover step). In the N-step capture analysis of Koolen et al. 2012 that step
catches more than the foot standing only when it takes under 0.12 s from the ZMP
leaving the foot to its touchdown (0.18 s from a 0.15 m stance): the controller's
shortest ZMP transition and landing are 0.1 s each, so a second lateral step
catches nothing one landing does not. A push towards the support foot is the
same: the swing foot lands on the inner side, then the support foot would have
to step out. What catches those is a crossover step (an option,
:func:`drake_estop.planning.crossover.crossover_stop`: the default humanoid's legs allow none) or the upper
body's angular momentum. Measured, 29 N s to the left
at 2.95 s: the CoP reaches the support sole's outer edge within 50 ms and stays
there while the body rolls over that edge (0.1 rad by 3.3 s), which the LIPM's
DCM (0.12 m, inside the 0.176 m edge, at 3.05 s) does not show.
"""

import math

from drake_estop.planning.gait import NominalPattern, PatternState, Sole
from drake_estop.planning.plan import StopParameters

#: The default humanoid's landing widths [m], ankle to ankle (``StopParameters.min_step_width`` /
#: ``max_step_width``; a robot's own come from its description: :func:`drake_estop.robots.stop_parameters`).
MIN_STEP_WIDTH = StopParameters.min_step_width
MAX_STEP_WIDTH = StopParameters.max_step_width
SHIFT_THRESHOLD = 0.01  # [m] smaller landing shifts (estimator noise, ~1 mm DCM) keep the nominal footstep


def capture_landing_y(pattern: NominalPattern, state: PatternState, landing_duration: float, *,
                      min_width: float = MIN_STEP_WIDTH, max_width: float = MAX_STEP_WIDTH) -> float | None:
    """The lateral landing [m] of the swing foot for a single-support ``state`` whose COG may differ
    from the walk's at ``state.time``, touching down ``landing_duration`` [s] later, ``min_width`` to
    ``max_width`` [m] from the support ankle; None when the nominal landing stands (the shift is below
    :data:`SHIFT_THRESHOLD`)."""
    if state.support != "single" or state.next_landing is None or state.recovery_touchdown is not None:
        return None  # (a recovery step is aimed at the measured DCM already: recovery.recovery_step)
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
    if side * (float(state.next_landing[1]) - support_y) < 0:
        return None  # a crossover step's landing (crossover.crossover_stop) is placed already
    width = side * (nominal_y + shift - support_y)
    return support_y + side * min(max(width, min_width), max_width)


def capture_time(*, dcm: float, zmp: float, edge: float, omega: float) -> float:
    """The latest time [s] at which the DCM, diverging from a ZMP held still, has not passed ``edge``.

    One axis, eq. 6-9: ``xi(T) = p + (xi - p) exp(omega T)`` with ``xi`` = ``dcm`` [m] and ``p`` = ``zmp``
    [m], solved for ``xi(T) = edge`` [m]. ``inf`` where the DCM never passes ``edge`` (it heads away
    from it or rests on the ZMP), 0 where it lies past ``edge`` already (on the side away from ``zmp``).

    Raises
    ------
    ValueError
        If ``dcm``, ``zmp`` or ``edge`` is not finite, or ``omega`` [1/s] not positive, naming it.
    """
    for name, value in (("dcm", dcm), ("zmp", zmp), ("edge", edge), ("omega", omega)):
        if not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ValueError(f"{name} must be a finite number, got {value!r}")
    if omega <= 0:
        raise ValueError(f"omega must be positive [1/s], got {omega!r}")
    side = math.copysign(1.0, edge - zmp)
    ahead, room = side * (dcm - zmp), side * (edge - zmp)
    if ahead <= 0.0:
        return math.inf
    if ahead >= room:
        return 0.0
    return math.log(room / ahead) / omega


def step_out_gain(*, separation: float, step_time: float, omega: float, sole: Sole | None = None,
                  max_width: float = MAX_STEP_WIDTH) -> float:
    """How much further out [m] a sideways step of the loaded foot catches the DCM than that foot standing.

    Two feet ``separation`` [m] apart (ankle to ankle, at least :data:`MIN_STEP_WIDTH`), the DCM beyond the
    outer foot. Standing, that foot catches a DCM up to its outer edge (less the ZMP margin). Stepping, the
    foot must first be unloaded: the ZMP goes to the other foot's inner edge (less the margin) and stays
    there for ``step_time`` [s], until the foot lands ``max_width`` [m] from the other one. The DCM
    diverges from that ZMP (eq. 6-9), so the step catches a DCM up to
    ``inner + (max_width + outer - inner) exp(-omega step_time)`` from the other ankle against
    ``separation + outer`` standing (the margin cancels): the gain is their difference, negative where the
    step catches less. A step of the other foot towards the DCM needs a crossover step. Koolen et al. 2012
    (N-step capturability of the LIPM) with the ZMP moved at once: an upper bound.

    Raises
    ------
    ValueError
        If ``separation`` lies outside the step widths, ``step_time`` [s] is negative, ``omega`` [1/s] not
        positive, or ``max_width`` [m] below the separation, naming it.
    """
    sole = sole or Sole()
    if not (isinstance(max_width, (int, float)) and math.isfinite(max_width) and max_width >= MIN_STEP_WIDTH):
        raise ValueError(f"max_width must be at least MIN_STEP_WIDTH ({MIN_STEP_WIDTH} m), got {max_width!r}")
    if not (isinstance(separation, (int, float)) and MIN_STEP_WIDTH <= separation <= max_width):
        raise ValueError(f"separation must lie within {MIN_STEP_WIDTH}-{max_width} m, got {separation!r}")
    if not (isinstance(step_time, (int, float)) and math.isfinite(step_time) and step_time >= 0):
        raise ValueError(f"step_time must be a finite time >= 0 [s], got {step_time!r}")
    if not (isinstance(omega, (int, float)) and math.isfinite(omega) and omega > 0):
        raise ValueError(f"omega must be positive [1/s], got {omega!r}")
    stepped = (max_width + sole.outer - sole.inner) * math.exp(-omega * step_time)
    return stepped - (separation + sole.outer - sole.inner)
