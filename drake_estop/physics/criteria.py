"""Success criteria of a physics stop, measured from the logs of the simulated robot.

:func:`analyse` turns the 5 ms logs of a run into a :class:`PhysicsResult`:
no fall (pelvis height, torso tilt), no slip, comes to rest, rests at the
feet's midpoint, centre of pressure inside the support (:data:`CRITERIA`);
:meth:`PhysicsResult.cop_exit` says where the centre of pressure left it.
:func:`multibody_zmp` is the whole-body ZMP of a joint trajectory.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from pydrake.trajectories import PiecewisePolynomial

from drake_estop.physics.plant import (
    SIDES,
    SOLE_CONTACT_INSET,
    PhysicsHandles,
    PhysicsParameters,
    actuated_indices,
    sole_frames,
)
from drake_estop.planning.gait import rotation
from drake_estop.planning.geometry import SupportPolygon
from drake_estop.planning.lipm import GRAVITY  # the one gravity value
from drake_estop.planning.planner import StopPlan
from drake_estop.robots.parameters import as_robot


def joint_velocity_violations(plant, states: np.ndarray) -> np.ndarray:
    """Per logged tick, the number of joints whose measured speed exceeds the model's velocity limit."""
    v = states[:, plant.num_positions():]
    limit = plant.GetVelocityUpperLimits()
    finite = np.isfinite(limit)
    return np.sum(np.abs(v[:, finite]) > limit[finite], axis=1)


def fall_time(result, physics) -> float:
    """The first time [s] the torso of ``result`` (:class:`PhysicsResult`) tilts past ``physics.max_torso_tilt``
    (the cut of :func:`analyse`'s "before any fall"); inf where it never does."""
    fallen = np.flatnonzero(np.asarray(result.torso_tilt) >= physics.max_torso_tilt)
    return float(result.times[fallen[0]]) if len(fallen) else math.inf


def joint_velocity_peak(plant, states: np.ndarray, times: np.ndarray) -> dict:
    """The joint closest to (or furthest over) its velocity limit: name, speed / limit, time."""
    v = np.abs(states[:, plant.num_positions():])
    limit = plant.GetVelocityUpperLimits()
    ratio = np.where(np.isfinite(limit), v / np.where(np.isfinite(limit), limit, 1.0), 0.0)
    tick, index = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
    names = {plant.get_joint(j).velocity_start(): plant.get_joint(j).name() for j in plant.GetJointIndices()
             if plant.get_joint(j).num_velocities() == 1}
    return {"joint": names.get(int(index), str(index)), "ratio": float(ratio[tick, index]),
            "time": float(times[tick])}


@dataclass
class PhysicsResult:
    """Per-tick (5 ms) arrays of one physics run and its success criteria."""

    plan: StopPlan
    times: np.ndarray
    cop_x: np.ndarray
    cop_y: np.ndarray
    normal_force: np.ndarray
    foot_forces: dict  # side -> (n,) ground normal force on the sole [N]
    pelvis_z: np.ndarray
    com_meas_x: np.ndarray
    com_meas_y: np.ndarray
    com_meas_z: np.ndarray
    com_meas_speed: np.ndarray  # horizontal COG speed [m/s]
    com_plan: np.ndarray  # (n, 3)
    zmp_plan: np.ndarray  # (n, 2)
    torso_tilt: np.ndarray  # [rad]
    feet_meas: dict  # side -> (n, 3) sole-frame origin
    feet_plan: dict  # side -> (n, 3)
    slip: dict  # side -> max sole travel while standing [m]
    cop_margin_plan: np.ndarray  # (n,) CoP margin in the planned support polygon [m]
    cop_margin_meas: np.ndarray  # (n,) CoP margin in the soles in contact at their measured poses [m]
    time_to_rest: float  # measured: from the signal until the COG speed stays below rest_speed [s]
    rest_time: float  # absolute time of that rest (nan if never)
    final_offset: float  # final COG from the measured feet's midpoint [m]
    final_offset_plan: float  # final COG from the planned feet's midpoint [m]
    cog_travel: float  # measured horizontal COG path length after the signal [m]
    criteria: dict
    ik_failures: int
    ik_max_com_error: float
    sim_time: float
    sim_wall_time: float
    ik_wall_time: float
    params: PhysicsParameters = field(default_factory=PhysicsParameters)
    reference: JointReference | None = None
    #: the online controller's own figures (:func:`drake_estop.physics.online.run_online`), else None
    online: dict | None = None
    #: side -> (n,) measured sole yaw [rad] (None: level, unturned soles)
    feet_yaw_meas: dict | None = None
    #: side -> the farthest a loaded sole the plan stands on lay from the plan's foothold before any fall [m]
    #: (:func:`sole_deviations`; empty: not measured)
    sole_off_plan: dict = field(default_factory=dict)
    #: side -> the most such a sole turned from the plan's heading before any fall [rad] (empty: not measured)
    sole_turn: dict = field(default_factory=dict)

    @property
    def realtime_factor(self) -> float:
        """Simulated seconds per wall-clock second of the physics simulation alone."""
        return self.sim_time / self.sim_wall_time

    @property
    def realtime_factor_with_ik(self) -> float:
        return self.sim_time / (self.sim_wall_time + self.ik_wall_time)

    @property
    def success(self) -> bool:
        return all(self.criteria.values())

    def cop_exit(self) -> dict | None:
        """Where the CoP left the planned support, None where it never did (``cop_in_support`` met).

        At the tick of the least planned-support margin: ``time`` [s], ``margin`` [m] (negative), the stop's
        ``phase`` there (:meth:`drake_estop.planning.planner.StopPlan.phase`), the ``soles`` carrying load
        ("left", "right" or "both": over :data:`LOADED_SHARE` of the normal force) and the ``edge`` of the
        loaded sole nearest the CoP that it is past or within :data:`EDGE_BAND` of (:func:`sole_edge`).
        """
        margins = self.cop_margin_plan[1:]  # the first sample precedes the first contact solve
        if not np.any(np.isfinite(margins)) or np.nanmin(margins) >= -self.params.cop_tolerance:
            return None
        i = 1 + int(np.nanargmin(margins))
        t, cop, total = float(self.times[i]), np.array([self.cop_x[i], self.cop_y[i]]), float(self.normal_force[i])
        loaded = [s for s in SIDES if total > 0 and self.foot_forces[s][i] > LOADED_SHARE * total] or list(SIDES)
        sole = self.plan.pattern.params.sole
        local = {s: _sole_local(cop, self.feet_meas[s][i][:2],
                                0.0 if self.feet_yaw_meas is None else float(self.feet_yaw_meas[s][i]))
                 for s in loaded}
        nearest = max(loaded, key=lambda s: SupportPolygon(sole.corners(np.zeros(2), s)).margin(local[s])[0])
        return {"time": t, "margin": float(margins[i - 1]), "phase": self.plan.phase(t),
                "soles": loaded[0] if len(loaded) == 1 else "both", "edge": sole_edge(local[nearest], nearest, sole)}

    def numbers(self) -> dict:
        """The raw numbers behind each criterion."""
        return {
            "pelvis_z_min_m": float(np.min(self.pelvis_z)), "pelvis_z_max_m": float(np.max(self.pelvis_z)),
            "torso_tilt_max_rad": float(np.max(self.torso_tilt)),
            "slip_left_m": self.slip["left"], "slip_right_m": self.slip["right"],
            "time_to_rest_s": self.time_to_rest,
            "rest_after_halt_s": self.rest_time - self.plan.halt_end,
            "final_cog_offset_m": self.final_offset, "final_cog_offset_plan_m": self.final_offset_plan,
            "final_cog_speed_mps": float(self.com_meas_speed[-1]),
            "cop_margin_plan_min_m": float(np.nanmin(self.cop_margin_plan)),
            "cop_margin_meas_min_m": float(np.nanmin(self.cop_margin_meas)),
            "cog_travel_m": self.cog_travel,
            # where the feet stand against the plan's: a pushed sole on its edge slides and spins, and the
            # CoP criterion measures against the plan's feet
            "sole_off_plan_max_m": max(self.sole_off_plan.values(), default=float("nan")),
            "sole_turn_max_rad": max(self.sole_turn.values(), default=float("nan")),
            # time the CoP spends on the edge of the contact corners (a foot rolling on an edge):
            # the corner spheres sit SOLE_CONTACT_INSET inside the sole rectangle
            "cop_edge_time_s": float(np.sum(self.cop_margin_meas < SOLE_CONTACT_INSET + 5e-4)
                                     * self.params.log_period),
            "com_tracking_max_m": float(np.max(np.linalg.norm(
                np.column_stack([self.com_meas_x, self.com_meas_y]) - self.com_plan[:, :2], axis=1))),
            "ik_failures": self.ik_failures, "ik_max_com_error_m": self.ik_max_com_error,
            "reference_zmp_error_raw_max_m": _max_abs(self.reference, "zmp_error_raw"),
            "reference_zmp_error_max_m": _max_abs(self.reference, "zmp_error"),
            "realtime_factor": self.realtime_factor,
        }


#: Share of the total normal force above which a sole counts as loaded in :meth:`PhysicsResult.cop_exit`.
LOADED_SHARE = 0.05
#: Distance [m] from a sole edge within which :func:`sole_edge` names that edge.
EDGE_BAND = 0.01


def sole_edge(local_xy, side: str, sole, band: float = EDGE_BAND) -> str:
    """The edges of the ``side`` ('left'/'right') ``sole`` (a :class:`drake_estop.planning.gait.Sole`) that a
    point ``local_xy`` in the sole's frame (x forward, y left, from the ankle) [m] lies past or within ``band``
    [m] of: "toe" or "heel", then "inner" or "outer", joined by "-" ("toe-outer"); "inside" if none."""
    x, y = (float(v) for v in local_xy)
    outward = y if side == "left" else -y
    names = [name for name, near in (("toe", x > sole.toe - band), ("heel", x < -sole.heel + band),
                                     ("inner", outward < -sole.inner + band), ("outer", outward > sole.outer - band))
             if near]
    return "-".join(names) or "inside"


def _sole_local(point, ankle, yaw: float) -> np.ndarray:
    """``point`` (x, y) in the frame of a sole at ``ankle`` (x, y) turned by ``yaw`` [rad]."""
    return rotation(yaw).T @ (np.asarray(point, float) - np.asarray(ankle, float))


def sole_deviations(feet_meas: dict, feet_yaw: dict, feet_plan: dict, planned_yaw: list, loaded: dict):
    """How far each sole stood off the plan: ``({side: metres}, {side: radians})``, the largest distance
    (xy) of the measured sole from the plan's foothold and the largest turn from the plan's heading, over
    the ticks where the plan stands on it (planned lift 0) and it is ``loaded`` (side -> (n,) bools).
    ``feet_meas`` / ``feet_plan``: side -> (n, 3) [m]; ``feet_yaw``: side -> (n,) [rad]; ``planned_yaw``:
    per tick ``{side: yaw}`` [rad]. 0 for a side never standing loaded."""
    off_plan, turn = {}, {}
    for side in SIDES:
        standing = (feet_plan[side][:, 2] <= 1e-9) & loaded[side]
        yaw_plan = np.array([yaws[side] for yaws in planned_yaw])
        distance = np.linalg.norm(feet_meas[side][:, :2] - feet_plan[side][:, :2], axis=1)
        heading = np.abs(np.angle(np.exp(1j * (feet_yaw[side] - yaw_plan))))
        off_plan[side] = float(distance[standing].max()) if np.any(standing) else 0.0
        turn[side] = float(heading[standing].max()) if np.any(standing) else 0.0
    return off_plan, turn


def _planned_support(plan: StopPlan, t: float):
    """Feet the plan stands on at ``t`` (the sides of :meth:`StopPlan.polygon`)."""
    return plan.support_sides(t)


def _intervals(mask):
    """(start, stop) index pairs of the True runs of ``mask``."""
    edges = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))


def _measured(plant, scratch, states: np.ndarray, robot):
    """Per logged state (rows of ``states``), set in ``scratch``: the COG [m] and its velocity [m/s] (n, 3), the
    pelvis height [m] and the torso tilt [rad] (n,), and per side the sole positions [m] (n, 3) and yaws [rad] (n,)."""
    n = len(states)
    torso = plant.GetBodyByName(robot.torso_body)
    pelvis = plant.GetBodyByName(robot.floating_base)
    soles = dict(zip(SIDES, sole_frames(plant, robot)))
    com = np.empty((n, 3))
    com_vel = np.empty((n, 3))
    pelvis_z, tilt = np.empty(n), np.empty(n)
    feet_meas = {side: np.empty((n, 3)) for side in SIDES}
    feet_yaw = {side: np.empty(n) for side in SIDES}
    for i, x in enumerate(states):
        plant.SetPositionsAndVelocities(scratch, x)
        com[i] = plant.CalcCenterOfMassPositionInWorld(scratch)
        com_vel[i] = plant.CalcCenterOfMassTranslationalVelocityInWorld(scratch)
        pelvis_z[i] = plant.EvalBodyPoseInWorld(scratch, pelvis).translation()[2]
        rot = plant.EvalBodyPoseInWorld(scratch, torso).rotation().matrix()
        tilt[i] = math.acos(min(1.0, max(-1.0, rot[2, 2])))
        for side, frame in soles.items():
            pose = frame.CalcPoseInWorld(scratch)
            feet_meas[side][i] = pose.translation()
            r = pose.rotation().matrix()
            feet_yaw[side][i] = math.atan2(r[1, 0], r[0, 0])
    return com, com_vel, pelvis_z, tilt, feet_meas, feet_yaw


def _slip(feet_meas: dict, feet_plan: dict, in_contact: dict) -> dict:
    """Per side, the worst slip [m] of the sole over the planned stance intervals (``{side: metres}``)."""
    # slip: sole travel (xy) over each planned stance interval, from its first tick in contact
    slip = {}
    for side in SIDES:
        stance = (feet_plan[side][:, 2] <= 1e-9) & in_contact[side]
        worst = 0.0
        for a, b in _intervals(stance):
            travel = np.linalg.norm(feet_meas[side][a:b, :2] - feet_meas[side][a, :2], axis=1)
            worst = max(worst, float(travel.max()))
        slip[side] = worst
    return slip


def _cop_margins(plan: StopPlan, times, cop, in_contact: dict, feet_meas: dict, feet_yaw: dict, feet_plan: dict,
                 planned_yaw: list):
    """Per tick, the measured centre of pressure's margin [m] (positive inside) in the planned support and in the
    soles measured in contact: ``(margin_plan, margin_meas)``; NaN without a CoP (or, measured, a contact)."""
    n = len(times)
    sole = plan.pattern.params.sole
    planned_support = [_planned_support(plan, float(t)) for t in times]
    margin_plan = np.full(n, np.nan)
    margin_meas = np.full(n, np.nan)
    for i in range(n):
        if not np.all(np.isfinite(cop[i])):
            continue
        touching = [s for s in SIDES if in_contact[s][i]]
        # planned soles (planned poses) that the plan stands on, plus any foot measured in
        # contact (a swing foot touching down a few ms early stands on its planned landing spot)
        standing = [s for s in SIDES if s in touching or s in planned_support[i]]
        margin_plan[i] = SupportPolygon(np.vstack([
            sole.corners(feet_plan[s][i, :2], s, planned_yaw[i][s]) for s in standing])).margin(cop[i])[0]
        if touching:
            corners = np.vstack([sole.corners(feet_meas[s][i][:2], s, float(feet_yaw[s][i]))
                                 for s in touching])
            margin_meas[i] = SupportPolygon(corners).margin(cop[i])[0]
    return margin_plan, margin_meas


def analyse(handles: PhysicsHandles, context, plan: StopPlan, reference: JointReference,
            physics: PhysicsParameters, wall_time: float, robot=None) -> PhysicsResult:
    """Per-tick arrays and success criteria from the loggers of a finished run of ``robot`` (a
    description, a name or None: the default humanoid; its floating base is the "pelvis" of the height
    bounds, its ``torso_body`` the tilted torso, its sole frames the feet)."""
    robot = as_robot(robot)
    physics = physics.for_robot(robot)
    plant = handles.plant
    logs = {name: logger.FindLog(context) for name, logger in handles.loggers.items()}
    times = logs["state"].sample_times()
    states = logs["state"].data().T
    cop = logs["cop"].data().T
    normal = logs["normal_force"].data()[0]
    foot_forces = dict(zip(SIDES, logs["foot_forces"].data()))
    n = len(times)
    scratch = plant.CreateDefaultContext()
    com, com_vel, pelvis_z, tilt, feet_meas, feet_yaw = _measured(plant, scratch, states, robot)
    pos, _, _, zmp_plan = plan.com(times)
    z_plan = plan.com_height(times)[0]
    com_plan = np.column_stack([pos, z_plan])
    planned_feet = [plan.feet(float(t)) for t in times]
    feet_plan = {side: np.array([f[side] for f in planned_feet]) for side in SIDES}
    planned_yaw = [plan.feet_yaw(float(t))[0] for t in times]
    weight = plant.CalcTotalMass(scratch) * GRAVITY
    in_contact = {side: foot_forces[side] > physics.contact_force_fraction * weight for side in SIDES}
    slip = _slip(feet_meas, feet_plan, in_contact)
    # until a fall (the torso past its tilt limit): the feet of a fallen robot say nothing of the stop
    upright = np.cumprod(tilt < physics.max_torso_tilt).astype(bool)
    off_plan, turn = sole_deviations(feet_meas, feet_yaw, feet_plan, planned_yaw,
                                     {side: in_contact[side] & upright for side in SIDES})
    margin_plan, margin_meas = _cop_margins(plan, times, cop, in_contact, feet_meas, feet_yaw, feet_plan, planned_yaw)
    speed = np.linalg.norm(com_vel[:, :2], axis=1)
    moving = np.flatnonzero(speed >= physics.rest_speed)
    rest_index = 0 if len(moving) == 0 else moving[-1] + 1
    rest_time = float(times[rest_index]) if rest_index < n else float("nan")
    mid_meas = 0.5 * (feet_meas["left"][-1, :2] + feet_meas["right"][-1, :2])
    mid_plan = 0.5 * (plan.final_feet["left"][:2] + plan.final_feet["right"][:2])
    final_offset = float(np.linalg.norm(com[-1, :2] - mid_meas))
    after_signal = times >= plan.signal_time - 1e-9
    travel = float(np.sum(np.linalg.norm(np.diff(com[after_signal, :2], axis=0), axis=1)))
    low, high = physics.pelvis_height_bounds
    criteria = {
        "no_fall": bool(np.all((pelvis_z > low) & (pelvis_z < high))
                        and np.max(tilt) < physics.max_torso_tilt),
        "no_slip": bool(max(slip.values()) < physics.max_slip),
        "comes_to_rest": bool(math.isfinite(rest_time)
                              and rest_time <= plan.halt_end + physics.rest_within + 1e-9),
        "rests_at_midpoint": bool(final_offset <= physics.rest_offset),
        # the first sample (t = 0) precedes the first contact solve: no contact results yet
        "cop_in_support": bool(np.all(np.isfinite(margin_plan[1:]))
                               and np.min(margin_plan[1:]) >= -physics.cop_tolerance),
        # measured joint speeds within the model's velocity limits at every logged tick (a real
        # servo trips past them): the whole run, walk included
        "joint_speed_within_limits": not np.any(joint_velocity_violations(plant, states)),
    }
    return PhysicsResult(
        plan=plan, times=times, cop_x=cop[:, 0], cop_y=cop[:, 1], normal_force=normal,
        foot_forces=foot_forces, pelvis_z=pelvis_z, com_meas_x=com[:, 0], com_meas_y=com[:, 1],
        com_meas_z=com[:, 2], com_meas_speed=speed, com_plan=com_plan, zmp_plan=zmp_plan,
        torso_tilt=tilt, feet_meas=feet_meas, feet_plan=feet_plan, slip=slip, sole_off_plan=off_plan, sole_turn=turn,
        cop_margin_plan=margin_plan, cop_margin_meas=margin_meas,
        time_to_rest=rest_time - plan.signal_time, rest_time=rest_time, final_offset=final_offset,
        final_offset_plan=float(np.linalg.norm(com[-1, :2] - mid_plan)), cog_travel=travel,
        criteria=criteria, ik_failures=reference.failures,
        ik_max_com_error=float(reference.com_error.max()), sim_time=float(times[-1] - times[0]),
        sim_wall_time=wall_time, ik_wall_time=reference.wall_time, params=physics, reference=reference,
        feet_yaw_meas=feet_yaw)


CRITERIA = ("no_fall", "no_slip", "comes_to_rest", "rests_at_midpoint", "cop_in_support", "joint_speed_within_limits")


@dataclass
class JointReference:
    """IK joint angles at every servo tick of a rollout."""

    times: np.ndarray
    q: np.ndarray  # (n, nq) full plant positions (floating base included)
    com_error: np.ndarray  # (n,) IK COG error [m]
    foot_error: np.ndarray  # (n,) IK worst sole position error [m]
    failures: int  # ticks where the IK missed its tolerances
    wall_time: float
    com_offset: np.ndarray | None = None  # (n, 2) dynamics-filter COG correction [m]
    zmp_error_raw: np.ndarray | None = None  # (n, 2) multibody - planned ZMP, unfiltered reference [m]
    zmp_error: np.ndarray | None = None  # (n, 2) the same for the filtered reference [m]

    def desired_state_trajectory(self, plant) -> PiecewisePolynomial:
        """First-order hold of [q_ref, v_ref] of the actuated joints (desired_state layout)."""
        q_idx, _ = actuated_indices(plant)
        qa = self.q[:, q_idx]
        va = np.gradient(qa, self.times, axis=0)
        return PiecewisePolynomial.FirstOrderHold(self.times, np.hstack([qa, va]).T)


def _max_abs(reference, name):
    value = None if reference is None else getattr(reference, name)
    return None if value is None else float(np.max(np.abs(value)))
