"""A late landing: the landing sole has carried no weight by the plan's touchdown, and the stop is re-timed.

On stiff position servos a landing ends on the clock. Where the floor lies lower than the plan's ``z = 0`` or
the body has rolled a few millimetres, the swing foot reaches its target above the floor and carries nothing,
while the plan moves the ZMP onto it (the ZMP transition, III.B). The robot's real centre of pressure cannot
follow onto a sole that is not there: it stays on the stance sole's edge, and the COG runs ahead of the plan.
Measured, the 3.4 s stop with the floor 10 mm lower under its landing spot: the foot hovered over the hole
for 0.1 s, the ZMP reference moved onto it, and the robot fell.

:func:`late_landing_stop` re-times such a stop at the tick ``t`` where the landing sole is late: single
support again on the stance foot, the ZMP held where the plan held it at the touchdown (eq. 19), the COG from
the measurement (eq. 10-11), and the landing, at its landing point, ``delay`` after ``t`` (the single-support
solve, III.A, eq. 21-26; the swing foot already over its landing point keeps it to the millimetre,
:func:`~drake_estop.planning.landing.landing_shift_limit`). The stop controller re-times again each time the
re-timed touchdown passes with the sole still unloaded, up to a bound, while the touchdown reflex
(:class:`~drake_estop.physics.touchdown.TouchdownByContact`) lowers the foot until it carries weight. Pure
numpy on the plan, no Drake.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from drake_estop.planning.assembly import plan_from, with_compute_time
from drake_estop.planning.gait import SIDES, rotation
from drake_estop.planning.plan import StopPlan
from drake_estop.planning.recovery import on_sole

#: How long after the plan's touchdown an unloaded landing sole counts as late [s]: longer than the force
#: sensing's delay at an ordinary landing (the walk's feet touch down 1-2 ticks after the plan's), the
#: touchdown reflex's own ``grace_time``.
LATE_LANDING_GRACE = 0.02
#: How far after the re-timing tick the re-timed stop lands [s]: four servo ticks, about the 10 mm more a
#: landing foot comes down at the touchdown reflex's 0.1 m/s (after which the controller re-times again).
LATE_LANDING_DELAY = 0.02
#: The swing foot's downward speed in the re-timed start [m/s]: a foot coming down, so the landing keeps its
#: point (:func:`~drake_estop.planning.landing.landing_shift_limit` pins a descending foot near the floor).
_DESCENDING = 1e-3


def late_landing_stop(plan: StopPlan, t: float, com_xy, com_vel_xy, *, delay: float = LATE_LANDING_DELAY) -> StopPlan:
    """``plan`` re-timed at ``t`` [s] for a landing sole that has not touched down: its landing ``delay`` [s]
    after ``t`` at the same point, the ZMP held on the stance sole until then where ``plan`` held it at its
    touchdown, from the measured COG ``com_xy``, ``com_vel_xy`` [m, m/s] (the module docstring).

    The new plan keeps ``plan``'s landing kind (stop landing, capture landing, recovery step, crossover) and
    its step after a capture landing; :attr:`~drake_estop.planning.plan.StopPlan.late_since` is the first
    touchdown the landing missed. ``ValueError`` for a plan without a landing, a ``t`` before its touchdown
    or a ``delay`` that is not at least one servo tick; :class:`~drake_estop.planning.plan.InfeasibleStop`
    where no landing at that time stops the robot.
    """
    if plan.landing_foot is None or plan.x is None:
        raise ValueError("late_landing_stop needs a plan with a landing")
    t = float(t)
    if t < plan.landing_time - 1e-9:
        raise ValueError(f"t = {t:.3f} s is before the plan's touchdown {plan.landing_time:.3f} s")
    if not (np.isfinite(delay) and delay >= plan.params.servo_period - 1e-12):
        raise ValueError(f"delay must be at least one servo tick ({plan.params.servo_period} s), got {delay!r}")
    com = np.asarray(com_xy, float)[:2].copy()
    vel = np.asarray(com_vel_xy, float)[:2].copy()
    if not (np.all(np.isfinite(com)) and np.all(np.isfinite(vel))):
        raise ValueError("the measured COG must be finite")
    swing = plan.landing_foot
    stance = next(side for side in SIDES if side != swing)
    feet = plan.feet(t)
    now = {side: np.array([float(feet[side][0]), float(feet[side][1]), 0.0]) for side in SIDES}
    now[swing][:2] = plan.landing_position
    yaw, _ = plan.feet_yaw(t)
    held = stance_zmp(plan, stance, now[stance][:2], float(yaw[stance]), com + vel / plan.pattern.w)
    upper, upper_rate = plan.upper_body(t)
    zero = np.zeros(3)
    state = replace(
        plan.start_state, time=t, support="single", support_foot=stance, com=com, com_vel=vel, zmp=held,
        zmp_rate=np.zeros(2), zmp_accel=np.zeros(2), feet=now,
        feet_vel={stance: zero.copy(), swing: np.array([0.0, 0.0, -_DESCENDING])},
        feet_acc={side: zero.copy() for side in SIDES}, next_landing=np.asarray(plan.landing_position, float).copy(),
        rear_foot=None, upper_body=upper, upper_body_rate=upper_rate, feet_yaw=dict(yaw),
        feet_yaw_rate={side: 0.0 for side in SIDES}, next_landing_yaw=float(plan.final_yaw[swing]),
        recovery_touchdown=t + delay)
    # the landing at t + delay (a tick's leeway for the solver) and, the foot at the floor's height and coming
    # down, at its point to the millimetre (any finite shift per height pins a foot at height 0)
    params = replace(plan.params, min_landing_time=delay, max_landing_time=delay + plan.params.servo_period,
                     max_early_landing=0.0, max_landing_shift_per_height=1.0)
    wall = time.perf_counter()
    new = plan_from(plan.pattern, state, params, plan.signal_time, plan.case)
    new.params = plan.params  # the plan's own limits: a later re-plan treats it as any other landing
    new.crouch_window = plan.crouch_window or (plan.start_time, plan.halt_end)
    new.recovery_step, new.capture_landing, new.crossover = plan.recovery_step, plan.capture_landing, plan.crossover
    new.next_step = plan.next_step
    new.late_since = plan.late_since if plan.late_since is not None else float(plan.landing_time)
    return with_compute_time(new, wall)


def stance_zmp(plan: StopPlan, stance: str, ankle, yaw: float, dcm) -> np.ndarray:
    """Where the re-timed stop holds the ZMP on the ``stance`` sole (ankle ``ankle``, heading ``yaw`` [rad]):
    where ``plan`` held it at its touchdown (eq. 19), moved sagittally towards the measured ``dcm`` [m] as far
    as the sole less ``zmp_margin`` allows (the ankle strategy: the CoP that slows the COG while the landing
    waits), in world axes."""
    held = np.array([traj.evaluate_at(float(plan.landing_time))[3] for traj in (plan.x, plan.y)])
    turn = rotation(yaw)
    local = turn.T @ (held - np.asarray(ankle, float))
    local[0] = float((turn.T @ (np.asarray(dcm, float) - ankle))[0])
    return on_sole(plan.pattern.params.sole, stance, np.asarray(ankle, float), turn, local, plan.params.zmp_margin)
