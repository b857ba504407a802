"""Crossover steps: the swing foot lands across the support foot, where the legs' geometry allows.

A sideways push towards the foot standing alone sends the lateral divergent component of motion (DCM) over
that sole's outer edge: the ankle strategy holds it no further, and the swing foot, on the other side, catches
nothing where it lands (:func:`drake_estop.planning.capture.step_out_gain`). The step that catches it crosses
in front of the support leg and lands beyond the support foot (a crossover step; Pratt et al. 2006 and IHMC's
push recovery take them; Koolen et al. 2012 count it as one more capture step).

Whether the legs allow it is geometry, checked here on a model of each leg as two capsules (thigh, shank;
:class:`LegGeometry`), the knee bent forward in the plane of the hip, the ankle and the walking direction:

* the soles do not overlap (with :data:`SOLE_CLEARANCE`) at the touchdown;
* the legs' capsules keep apart (:func:`legs_clearance`) along the whole swing, the hips following the COG:
  the swing moves across late (:data:`LATE_LATERAL`, the least delay that keeps clear), so the swing foot
  passes in front of the support leg before it crosses;
* the landing leg reaches: hip to ankle within the leg's length with the knee bent ``min_knee_bend``, and
  the hip roll within its adduction limit.

:func:`crossover_landings` lists the landings that pass all three (in the support sole's frame), soonest and
nearest first; :func:`crossover_stop` plans the stop on them (III.A, eq. 21-26), for
:func:`drake_estop.planning.replan.replan_stop` (``crossover=True``; the online controller's
``ControllerOptions.planner.crossover_step``, off by default). Pure numpy.

Measured on the default humanoid (capsules 5.5 cm in radius, its thigh and shank boxes 11 and 10 cm deep):
for the sideways pushes it does not stop (29 N s to the left at 2.95 s, 25 N s there), the support knee,
bent forward at the walking height, lies 4-7 cm inside the crossing leg at every reachable landing's
touchdown, and no crossover is planned. Legs 3 cm in radius would allow them: such crossovers, planned in
physics for 25 and 29 N s at 2.95 s (the simulated legs pass through each other, having no collision
geometry), still fell.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from drake_estop.planning import lipm
from drake_estop.planning.assembly import plan_from, with_compute_time
from drake_estop.planning.capture_landing import (
    CAPTURE_DCM_BEHIND_LANDING,
    capture_parameters,
    capture_swing_acceleration,
    soonest_capture_landing,
    swing_reach,
)
from drake_estop.planning.gait import SIDES, Sole, rotation
from drake_estop.planning.plan import InfeasibleStop, StopPlan, snap_to_tick
from drake_estop.planning.recovery import zmp_to_reach

#: Clearance [m] between the soles' rectangles at a crossover's touchdown.
SOLE_CLEARANCE = 0.01
#: Clearance [m] between the legs' capsules (beyond their radii) along a crossover's swing.
LEG_CLEARANCE = 0.01


@dataclass(frozen=True)
class LegGeometry:
    """A leg as two capsules, from the default humanoid's ``models/humanoid.urdf``.

    Attributes
    ----------
    hip_half_width : float
        Hip joints from the pelvis centre, sideways [m] (the URDF's hip yaw origins, 0.06).
    thigh, shank : float
        Hip to knee and knee to ankle [m] (the knee and ankle pitch origins, 0.3 each).
    ankle_height : float
        Ankle above the sole [m] (the sole frames, 0.105).
    hip_below_com : float
        Hip joints below the COG at the walking COG height [m] (pelvis at 0.647 m under a 0.814 m COG).
    radius : float
        Capsule radius [m]: half the thigh's and shank's widest box side (0.11 and 0.10 m).
    max_adduction : float
        Hip roll towards the other leg [rad] (the hip roll limits, 0.4363).
    min_knee_bend : float
        The least knee bend of a landing leg [rad] (the whole-body IK's, 0.15).
    """

    hip_half_width: float = 0.06
    thigh: float = 0.3
    shank: float = 0.3
    ankle_height: float = 0.105
    hip_below_com: float = 0.167
    radius: float = 0.055
    max_adduction: float = 0.4363
    min_knee_bend: float = 0.15

    @property
    def reach(self) -> float:
        """Longest hip-to-ankle distance [m]: the knee bent ``min_knee_bend`` (law of cosines)."""
        return math.sqrt(self.thigh**2 + self.shank**2 + 2.0 * self.thigh * self.shank * math.cos(self.min_knee_bend))


def segment_distance(a0, a1, b0, b1) -> float:
    """The least distance [m] between the segments ``a0``-``a1`` and ``b0``-``b1`` (3-vectors)."""
    a0, a1, b0, b1 = (np.asarray(p, float) for p in (a0, a1, b0, b1))
    u, v, w0 = a1 - a0, b1 - b0, a0 - b0
    a, b, c, d, e = u @ u, u @ v, v @ v, u @ w0, v @ w0
    denominator = a * c - b * b
    s = 0.0 if denominator < 1e-12 else float(np.clip((b * e - c * d) / denominator, 0.0, 1.0))
    t = float(np.clip((b * s + e) / c, 0.0, 1.0)) if c > 1e-12 else 0.0
    s = float(np.clip((b * t - d) / a, 0.0, 1.0)) if a > 1e-12 else 0.0  # back to a's segment for that t
    return float(np.linalg.norm(a0 + s * u - (b0 + t * v)))


def knee(hip, ankle, forward, geometry: LegGeometry):
    """The knee [m] of a leg from ``hip`` to ``ankle`` (3-vectors), bent towards ``forward`` (a horizontal
    direction); None where the ankle lies beyond the leg's straight length."""
    hip, ankle = np.asarray(hip, float), np.asarray(ankle, float)
    axis = ankle - hip
    length = float(np.linalg.norm(axis))
    if length > geometry.thigh + geometry.shank or length < 1e-9:
        return None
    axis /= length
    bend = np.asarray([forward[0], forward[1], 0.0], float)
    bend -= (bend @ axis) * axis  # within the leg's plane, normal to the hip-ankle line
    if np.linalg.norm(bend) < 1e-9:
        return None
    bend /= np.linalg.norm(bend)
    along = (geometry.thigh**2 - geometry.shank**2 + length**2) / (2.0 * length)
    return hip + along * axis + math.sqrt(max(geometry.thigh**2 - along**2, 0.0)) * bend


def legs_clearance(hips, ankles, forward, geometry: LegGeometry) -> float:
    """The least distance [m] between two legs' capsules (thigh and shank of each), their radii taken off:
    negative where they collide. ``hips`` and ``ankles`` are pairs of 3-vectors; ``-inf`` where a leg cannot
    reach its ankle."""
    segments = []
    for hip, ankle in zip(hips, ankles):
        joint = knee(hip, ankle, forward, geometry)
        if joint is None:
            return -math.inf
        segments.append(((np.asarray(hip, float), joint), (joint, np.asarray(ankle, float))))
    return min(segment_distance(*p, *q) for p in segments[0] for q in segments[1]) - 2.0 * geometry.radius


def late_lateral(delay: int) -> np.ndarray:
    """The lateral shape of a crossover's swing: ``s^n (a + b s + c s^2)`` (lowest order first), 0 to 1 at
    rest at both ends, with ``n = delay + 3`` (``delay`` 0: the quintic smoothstep, at its middle at half the
    swing; 3: 14 % of the way at half the swing)."""
    n = delay + 3
    # s^n (a + b s + c s^2): value 1, first and second derivatives 0 at s = 1
    matrix = np.array([[1.0, 1.0, 1.0], [n, n + 1.0, n + 2.0], [n * (n - 1.0), (n + 1.0) * n, (n + 2.0) * (n + 1.0)]])
    a, b, c = np.linalg.solve(matrix, [1.0, 0.0, 0.0])
    shape = np.zeros(n + 3)
    shape[n:] = a, b, c
    return shape


#: The lateral shapes a crossover's swing may take, least delay first (:func:`late_lateral`).
LATE_LATERAL = tuple(late_lateral(delay) for delay in range(4))
_PATH_GRID = np.linspace(0.0, 1.0, 11)


def soles_apart(support_xy, swing_xy, sole: Sole, support: str, swing: str, clearance: float = SOLE_CLEARANCE) -> bool:
    """Whether the two soles' rectangles (ankles at ``support_xy`` and ``swing_xy`` in the support sole's
    frame, unturned) keep ``clearance`` [m] apart along either axis."""
    boxes = []
    for side, (x, y) in ((support, support_xy), (swing, swing_xy)):
        left, right = sole.lateral_edges(side)
        boxes.append((x - sole.heel, x + sole.toe, y - right, y + left))
    (ax0, ax1, ay0, ay1), (bx0, bx1, by0, by1) = boxes
    return bx0 >= ax1 + clearance or ax0 >= bx1 + clearance or by0 >= ay1 + clearance or ay0 >= by1 + clearance


@dataclass(frozen=True)
class CrossoverPath:
    """A crossover swing in the support sole's frame (support ankle at the origin, x its heading): the
    swing ankle's ``start`` and ``landing`` (xy) [m], the COG's ``com_start`` and ``com_landing`` (xy) [m],
    the COG ``height`` [m], the swing's ``lift`` (apex above the floor) [m] and ``swing_side`` (+1: the swing
    foot's own side is +y)."""

    start: np.ndarray
    landing: np.ndarray
    com_start: np.ndarray
    com_landing: np.ndarray
    height: float
    lift: float
    swing_side: float

    def soles_apart(self, sole: Sole) -> bool:
        """:func:`soles_apart` of the support sole and the swing sole landed at ``landing``."""
        support, swing = ("right", "left") if self.swing_side > 0 else ("left", "right")
        return soles_apart((0.0, 0.0), self.landing, sole, support, swing)


def _clearance_at(path: CrossoverPath, s: float, delay: int, geometry: LegGeometry) -> float:
    """:func:`legs_clearance` at the normalised swing time ``s`` of ``path`` (the lateral shape
    ``LATE_LATERAL[delay]``, sagittal the quintic smoothstep, the lift a bump of ``path.lift`` at mid-swing;
    the hips move with the COG)."""
    along = float(lipm.poly_eval(lipm.SMOOTHSTEP, s))
    across = float(lipm.poly_eval(LATE_LATERAL[delay], s))
    com = path.com_start + (path.com_landing - path.com_start) * along
    hip_z = path.height - geometry.hip_below_com
    foot = np.array([path.start[0] + (path.landing[0] - path.start[0]) * along,
                     path.start[1] + (path.landing[1] - path.start[1]) * across,
                     geometry.ankle_height + path.lift * 64.0 * (s * (1.0 - s)) ** 3])
    hips = [np.array([com[0], com[1] - path.swing_side * geometry.hip_half_width, hip_z]),
            np.array([com[0], com[1] + path.swing_side * geometry.hip_half_width, hip_z])]
    return legs_clearance(hips, [np.array([0.0, 0.0, geometry.ankle_height]), foot], (1.0, 0.0), geometry)


def path_clearance(path: CrossoverPath, delay: int, geometry: LegGeometry, sole: Sole) -> float:
    """The least leg clearance [m] (:func:`legs_clearance`) along ``path`` with the lateral shape
    ``LATE_LATERAL[delay]``; ``-inf`` where the soles overlap at the touchdown."""
    return _least_clearance(path, delay, geometry) if path.soles_apart(sole) else -math.inf


def _least_clearance(path: CrossoverPath, delay: int, geometry: LegGeometry) -> float:
    return min(_clearance_at(path, float(s), delay, geometry) for s in _PATH_GRID)


def landing_reachable(path: CrossoverPath, geometry: LegGeometry) -> bool:
    """Whether the swing leg reaches ``path.landing`` from its hip over ``path.com_landing``: within
    :attr:`LegGeometry.reach`, the hip rolled towards the other leg by no more than ``max_adduction``."""
    hip = np.array([*(path.com_landing + np.array([0.0, path.swing_side * geometry.hip_half_width])),
                    path.height - geometry.hip_below_com])
    ankle = np.array([*path.landing, geometry.ankle_height])
    leg = ankle - hip
    if float(np.linalg.norm(leg)) > geometry.reach:
        return False
    inward = -path.swing_side * leg[1]  # towards the support leg's side
    return math.atan2(inward, -leg[2]) <= geometry.max_adduction


def crossover_delay(path: CrossoverPath, geometry: LegGeometry, sole: Sole) -> int | None:
    """The least delay of :data:`LATE_LATERAL` whose swing keeps the legs :data:`LEG_CLEARANCE` apart, where
    the landing is reachable (:func:`landing_reachable`); None where none does."""
    if not path.soles_apart(sole) or not landing_reachable(path, geometry):
        return None
    if _clearance_at(path, 1.0, 0, geometry) < LEG_CLEARANCE:  # at the touchdown, whatever the delay
        return None
    return next((delay for delay in range(len(LATE_LATERAL))
                 if _least_clearance(path, delay, geometry) >= LEG_CLEARANCE), None)


#: How far [m] beyond the LIPM's DCM at the touchdown, or beyond the support ZMP's outer bound where the DCM lies
#: inside it, a crossover's ankle lands (outwards), nearest first: the DCM then lies between the feet, where the
#: double-support stop after the landing can hold it (a pushed body rolls on, past the LIPM's DCM).
CROSSOVER_BEYOND_DCM = (0.02, 0.04, 0.06)
#: The spacing [s, m] of the touchdown times and sagittal landing points :func:`crossover_landings` tries.
CROSSOVER_TIME_STEP = 0.02
CROSSOVER_LENGTH_STEP = 0.01


def crossover_landings(*, dcm, com, com_vel, zmp, omega: float, swing, swing_side: float, touchdowns,
                       reach, height: float, lift: float, geometry: LegGeometry, sole: Sole):
    """Crossover landings, soonest and nearest first: ``(touchdown, lateral, (low, high), com_landing)``, the
    sagittal interval ``[low, high]`` [m] of landing points on the line ``y = lateral`` whose swing keeps the
    legs apart (:func:`crossover_delay` finds a delay for each, checked every :data:`CROSSOVER_LENGTH_STEP`).

    All in the support sole's frame (its ankle at the origin, x along its heading): the measured ``dcm``,
    ``com`` and ``com_vel`` (xy) [m, m/s], the support ``zmp`` held until the touchdown (xy) [m], the swing
    ankle ``swing`` (xy) [m] on the ``swing_side`` (+1: +y), ``omega`` [1/s]. ``touchdowns`` [s] from now are
    tried in order; ``reach(touchdown, lateral)`` gives the sagittal interval of landing points the swing can
    still reach (or None). The COG and the DCM at each touchdown follow the LIPM with the ZMP held (eq. 6-9);
    the ankle lands :data:`CROSSOVER_BEYOND_DCM` beyond that DCM (or the ZMP's bound), away from the swing side.
    """
    dcm, com, com_vel, zmp = (np.asarray(v, float)[:2] for v in (dcm, com, com_vel, zmp))
    outward = -float(swing_side)
    for touchdown in touchdowns:
        grow_c, grow_s = math.cosh(omega * touchdown), math.sinh(omega * touchdown)
        com_landing = zmp + (com - zmp) * grow_c + com_vel / omega * grow_s
        dcm_landing = zmp + (dcm - zmp) * math.exp(omega * touchdown)
        for beyond in CROSSOVER_BEYOND_DCM:
            lateral = outward * (max(outward * float(dcm_landing[1]), outward * float(zmp[1])) + beyond)
            interval = reach(touchdown, lateral)
            if interval is None:
                continue
            clear = [length for length in np.arange(interval[0], interval[1] + 1e-9, CROSSOVER_LENGTH_STEP)
                     if crossover_delay(CrossoverPath(
                         start=np.asarray(swing, float)[:2], landing=np.array([length, lateral]), com_start=com,
                         com_landing=com_landing, height=height, lift=lift, swing_side=float(swing_side)),
                         geometry, sole) is not None]
            if clear:  # the first run of landings that keep clear, nearest first
                high = next((a for a, b in zip(clear, clear[1:]) if b - a > 1.5 * CROSSOVER_LENGTH_STEP), clear[-1])
                yield float(touchdown), lateral, (float(clear[0]), float(high)), com_landing


#: The lateral DCM within this [m] of the support ZMP's outer bound (the sole's outer edge less the ZMP margin)
#: takes a crossover step (:func:`crossover_stop`): beyond it the ankle strategy holds it no longer.
CROSSOVER_BAND = 0.03
#: The most stop solves a crossover re-plan makes (its landings' stops, soonest and nearest first).
CROSSOVER_SOLVES = 3


def crossover_stop(start, com_xy, com_vel_xy, geometry: LegGeometry | None = None) -> StopPlan | None:
    """The crossover step (:mod:`drake_estop.planning.crossover`): where the lateral DCM lies past the support
    sole's outer bound less :data:`CROSSOVER_BAND`, the swing foot lands beyond the support foot, in front of
    its leg, at the soonest and nearest landing the legs' geometry allows (:func:`crossover_landings`, the
    support ZMP held at that bound meanwhile), solved as a single-support stop (III.A, eq. 21-26).

    None where it does not apply or no landing passes; :class:`InfeasibleStop` where the stop solve fails for
    the landings tried.
    """
    plan, changes = start.plan, start.changes
    if plan.landing_foot is None or start.double or plan.crossover:
        return None
    params = capture_parameters(start.params)
    swing, support = plan.landing_foot, next(side for side in SIDES if side != plan.landing_foot)
    ankle, turn = np.asarray(changes["feet"][support][:2], float), rotation(float(changes["feet_yaw"][support]))
    w, sole, dt, margin = plan.pattern.w, plan.pattern.params.sole, params.servo_period, params.zmp_margin
    local = {key: turn.T @ (np.asarray(changes[key][swing][:2], float) - (ankle if key == "feet" else 0.0))
             for key in ("feet", "feet_vel", "feet_acc")}
    side = 1.0 if local["feet"][1] > 0 else -1.0  # the swing foot's side
    com, vel = turn.T @ (np.asarray(com_xy, float)[:2] - ankle), turn.T @ np.asarray(com_vel_xy, float)[:2]
    dcm = com + vel / w
    bound = -side * (sole.lateral_edges(support)[1 if side > 0 else 0] - margin)  # the outer edge, less the margin
    if -side * (float(dcm[1]) - bound) < -CROSSOVER_BAND:
        return None
    # sagittally the support ZMP sends the DCM CAPTURE_DCM_BEHIND_LANDING behind the nearest landing whose sole
    # clears the support sole, by the plan's touchdown (as the capture landing's, eq. 6-9)
    aim = sole.toe + sole.heel + SOLE_CLEARANCE - CAPTURE_DCM_BEHIND_LANDING
    grow = math.exp(w * max(plan.landing_time - float(changes["time"]), params.min_landing_time))
    zmp = np.array([float(np.clip(zmp_to_reach(float(dcm[0]), aim, grow), -sole.heel + margin, sole.toe - margin)),
                    bound])
    soonest = snap_to_tick(soonest_capture_landing(params, changes, swing), dt)
    acceleration = capture_swing_acceleration(params)
    touchdowns = np.arange(soonest, plan.landing_time - float(changes["time"]) + 0.2, CROSSOVER_TIME_STEP)
    geometry, height, lift = geometry or LegGeometry(), plan.pattern.params.com_height, plan.pattern.params.lift_height
    failure, solves = None, 0
    for touchdown, lateral, (low, high), com_landing in crossover_landings(
            dcm=dcm, com=com, com_vel=vel, zmp=zmp, omega=w, swing=local["feet"], swing_side=side,
            touchdowns=[snap_to_tick(d, dt) for d in touchdowns], height=height,
            reach=lambda d, lateral: swing_reach(local["feet"], local["feet_vel"], local["feet_acc"], lateral, d,
                                                 acceleration),
            lift=lift, geometry=geometry, sole=sole):
        farthest = max(math.hypot(x - local["feet"][0], lateral - local["feet"][1]) for x in (low, high))
        limits = replace(params, min_landing_time=max(touchdown - dt, dt), max_landing_time=touchdown + 1e-9,
                         min_step_length=low - zmp[0], max_step_length=max(high, low + 1e-3) - zmp[0],
                         max_swing_speed=max(params.max_swing_speed, farthest / touchdown + 1e-6),
                         max_swing_acceleration=acceleration)
        state = replace(plan.start_state, **dict(changes, zmp=ankle + turn @ zmp, zmp_rate=np.zeros(2),
                                                 zmp_accel=np.zeros(2), next_landing=ankle + turn @ (low, lateral)))
        wall, solves = time.perf_counter(), solves + 1
        try:
            new = plan_from(plan.pattern, state, limits, plan.signal_time, plan.case)
        except InfeasibleStop as error:
            failure = InfeasibleStop(f"crossover step at {touchdown:.3f} s: {error}")
            if solves >= CROSSOVER_SOLVES:
                break
            continue
        landed = turn.T @ (np.asarray(new.landing_position, float)[:2] - ankle)
        delay = crossover_delay(CrossoverPath(start=local["feet"], landing=landed, com_start=com,
                                              com_landing=com_landing, height=height, lift=lift, swing_side=side),
                                geometry, sole)
        if delay is None:  # (between the landings checked: the solve's own point)
            continue
        new.braked_swing = new.capture_landing = new.crossover = True
        new.params = params
        new.swing_start = dict(new.swing_start, cross_delay=delay)
        new.crouch_window = plan.crouch_window or (plan.start_time, plan.halt_end)
        return with_compute_time(new, wall)
    if failure is not None:
        raise failure
    return None


#: Lateral reaches [m] past the stance ankle that :func:`clear_crossover_reach` tries, widest first.
CROSSOVER_REACHES = (0.10, 0.08, 0.06, 0.04, 0.02, 0.0)


def clear_crossover_reach(geometry: LegGeometry | None = None, sole: Sole | None = None, *, height: float = 0.814,
                          forward: float = 0.4, lift: float = 0.05) -> float:
    """The widest lateral reach [m] past the stance ankle (of :data:`CROSSOVER_REACHES`) at which a crossover
    landing ahead keeps the legs :data:`LEG_CLEARANCE` apart at the touchdown and is reachable
    (:func:`landing_reachable`), for the capturability verdict's crossover regions
    (:class:`drake_estop.planning.capturability.SteppingLimits`); 0 where none is. Landings from the soles'
    clearance to ``forward`` [m] ahead every 2 cm, the COG ``height`` [m] over the stance ankle, the feet's
    midpoint or the landing ankle sagittally and 4 cm either side of the stance ankle laterally.

    The default humanoid's legs (capsules 5.5 cm in radius, the support knee bent forward) allow none: 0.
    """
    geometry, sole = geometry or LegGeometry(), sole or Sole()
    clear = sole.toe + sole.heel + SOLE_CLEARANCE
    for reach in CROSSOVER_REACHES:
        for x in np.arange(clear, forward + 1e-9, 0.02):
            for com_landing in ((cx, cy) for cx in (0.0, x / 2, x) for cy in (-0.04, 0.0, 0.04)):
                path = CrossoverPath(start=np.array([0.0, 0.19]), landing=np.array([x, -reach]),
                                     com_start=np.zeros(2), com_landing=np.array(com_landing), height=height,
                                     lift=lift, swing_side=1.0)  # the left foot across a right stance
                if landing_reachable(path, geometry) and _clearance_at(path, 1.0, 0, geometry) >= LEG_CLEARANCE:
                    return reach
    return 0.0
