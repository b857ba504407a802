"""Alternative stop methods to compare the planner with (benchmarks/compare_methods.py).

* ``finish_the_step``: land where and when the nominal pattern would, then stop
  on that foothold with the ZMP anywhere inside the fore sole (the behaviour
  of hrpsys-base's emergency stop, IHMC's abort-walking and
  lipm_walking_controller's pause). Implemented as the planner with
  ``landing="nominal"``, so its double-support stop is as good as ours.
* ``zmp_planner_stop``: what a Drake user would write with Drake's own tools:
  keep the next footstep, move the ZMP reference to the midpoint between the
  feet, and let ``pydrake.planning.ZmpPlanner`` (LQR preview on the LIPM) plan
  the COG from the current state. Its actual ZMP ``x - x''/w^2`` is checked
  against the support polygon.
* ``one_step_capturable``: the capture-point bound (Koolen et al. 2012): is
  the instantaneous capture point reachable by one step within the same
  step-length, swing-time and swing-speed limits (a point-foot LIPM with the
  sole as the region where the ZMP may be)? The physical limit on one-step
  stops; it plans no motion.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from drake_estop.planning.gait import NominalPattern
from drake_estop.planning.geometry import SupportPolygon
from drake_estop.planning.lipm import GRAVITY
from drake_estop.planning.planner import StopParameters, plan_stop, snap_to_tick


def finish_the_step(pattern: NominalPattern, signal_time: float, params: StopParameters):
    return plan_stop(pattern, signal_time, replace(params, landing="nominal"))


@dataclass
class ZmpPlannerStop:
    signal_time: float
    times: np.ndarray
    com: np.ndarray  # (n, 2)
    com_vel: np.ndarray
    zmp: np.ndarray  # actual ZMP of the planned COG, x - x''/w^2
    zmp_reference: np.ndarray
    min_zmp_margin: float
    time_to_rest: float  # from the signal until the COG speed stays below 1 mm/s (inf if never)
    cog_travel: float
    compute_time: float
    steps: int  # footsteps taken after the signal (0 in double support, 1 in single)


def zmp_planner_stop(pattern: NominalPattern, signal_time: float, params: StopParameters, *,
                     horizon: float = 4.0, rest_speed: float = 1e-3, qy=None, r=None) -> ZmpPlannerStop:
    """Stop at the next footstep with Drake's ``ZmpPlanner`` (default Qy, R unless given)."""
    from pydrake.planning import ZmpPlanner
    from pydrake.trajectories import PiecewisePolynomial

    dt = params.servo_period
    t0 = snap_to_tick(signal_time, dt)
    state = pattern.state(t0)
    support, index, side = pattern.support_at(t0)
    feet = {k: v[:2].copy() for k, v in state.feet.items()}
    knots_t, knots_z = [0.0], [state.zmp.copy()]
    steps = 0
    if support == "single":
        step = pattern.steps[index]
        touchdown = step["touchdown"] - t0
        feet[step["swing"]] = step["end"].copy()
        knots_t.append(touchdown)
        knots_z.append(state.zmp.copy())
        steps = 1
        transition_start = touchdown
    else:
        transition_start = 0.0
    midpoint = 0.5 * (feet["left"] + feet["right"])
    knots_t += [transition_start + pattern.params.double_support_time, horizon]
    knots_z += [midpoint, midpoint]
    zmp_d = PiecewisePolynomial.FirstOrderHold(np.array(knots_t), np.array(knots_z).T)
    x0 = np.concatenate([state.com, state.com_vel])
    wall = time.perf_counter()
    planner = ZmpPlanner()
    kwargs = {}
    if qy is not None:
        kwargs["Qy"] = qy
    if r is not None:
        kwargs["R"] = r
    planner.Plan(zmp_d, x0, pattern.params.com_height, GRAVITY, **kwargs)
    compute = time.perf_counter() - wall
    rel = dt * np.arange(int(round(horizon / dt)) + 1)
    com_traj, comd_traj, comdd_traj = planner.get_nominal_com(), planner.get_nominal_comd(), planner.get_nominal_comdd()
    com = np.array([com_traj.value(t).ravel() for t in rel])
    com_vel = np.array([comd_traj.value(t).ravel() for t in rel])
    com_acc = np.array([comdd_traj.value(t).ravel() for t in rel])
    zmp = com - com_acc * pattern.params.com_height / GRAVITY
    sole = pattern.params.sole
    margins = []
    for t, z in zip(rel, zmp):
        on_ground = ["left", "right"]
        if support == "single" and t < knots_t[1]:
            on_ground = [side]
        poly = SupportPolygon(np.vstack([sole.corners(feet[s] if not (support == "single" and t < knots_t[1])
                                                      else state.feet[s][:2], s) for s in on_ground]))
        margins.append(float(poly.margin(z)[0]))
    speed = np.linalg.norm(com_vel, axis=1)
    moving = np.nonzero(speed >= rest_speed)[0]
    rest = math.inf if len(moving) and moving[-1] == len(rel) - 1 else (rel[moving[-1] + 1] if len(moving) else 0.0)
    travel = float(np.sum(np.linalg.norm(np.diff(com, axis=0), axis=1)))
    return ZmpPlannerStop(t0, t0 + rel, com, com_vel, zmp, np.array([zmp_d.value(t).ravel() for t in rel]),
                          min(margins), rest, travel, compute, steps)


def one_step_capturable(pattern: NominalPattern, signal_time: float, params: StopParameters,
                        samples: int = 60) -> bool:
    """Capture-point bound: can one step (or none, in double support) capture the robot?

    Single support: is there a swing time (within the landing-time limits) and
    a landing point (within the step-length and mean swing-speed limits) such
    that the capture point at touchdown lies in the double-support polygon?
    Double support: is the capture point inside the current polygon (no step)?
    """
    t0 = snap_to_tick(signal_time, params.servo_period)
    state = pattern.state(t0)
    w = pattern.w
    sole = pattern.params.sole
    dcm = state.com + state.com_vel / w
    if state.support != "single":
        poly = SupportPolygon(np.vstack([sole.corners(state.feet[s][:2], s) for s in ("left", "right")]))
        if poly.margin(dcm)[0] >= 0.0:
            return True
        # the feet are fixed; a step would start only after the next lift-off
        return False
    support_xy = state.zmp
    support_sole = sole.corners(state.feet[state.support_foot][:2], state.support_foot)
    swing = "right" if state.support_foot == "left" else "left"
    swing_xy = state.feet[swing][:2]
    landing_y = state.next_landing[1]
    landings = support_xy[0] + np.linspace(params.min_step_length, params.max_step_length, 17)
    for swing_time in np.linspace(params.min_landing_time, params.max_landing_time, samples):
        icp = support_xy + (dcm - support_xy) * math.exp(w * swing_time)
        for landing_x in landings:
            if math.hypot(landing_x - swing_xy[0], landing_y - swing_xy[1]) > params.max_swing_speed * swing_time:
                continue
            hull = SupportPolygon(np.vstack([support_sole, sole.corners((landing_x, landing_y), swing)]))
            if hull.margin(icp)[0] >= 0.0:
                return True
    return False
