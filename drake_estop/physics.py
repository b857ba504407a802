"""Closed-loop physics of the emergency stop: the humanoid with contact on Drake.

The kinematic reference of a stop (:func:`drake_estop.rollout.rollout`, one row
per 5 ms servo tick) is turned into joint angles by the whole-body IK
(:class:`drake_estop.ik.WholeBodyIkSolver`: COG xyz, both sole poses, the arm
joints), once per run, before the simulation. The joint reference
``[q_ref, v_ref]`` of the 30 actuated joints is a first-order-hold
``PiecewisePolynomial`` through the ticks (``v_ref`` by central differences of
the tick values) played by a ``TrajectorySource`` into the plant's
``desired_state`` input port.

Physics (Drake 1.51): a discrete ``MultibodyPlant`` (1 ms step, SAP-based
``kLagged`` contact approximation, Drake's default, which is also what the
plant's implicit PD controllers need) with a rigid ground half-space. Contact
is point contact between the four 5 mm corner spheres of each sole and the
ground (the sole boxes are filtered against the ground so that no box-plane
point pair rocks between box corners); friction mu_static 1.0 / mu_dynamic 0.8,
as in the model file. ``contact="hydroelastic"`` instead uses the sole boxes'
compliant hydroelastic properties (corner spheres filtered out). The joint
servos are the plant's own PD-controlled actuators
(``JointActuator.set_controller_gains(PdControllerGains)``): they are
integrated implicitly by SAP, so the stiff gains of a position-controlled
harmonic-drive humanoid are stable at 1 ms, and the torques are clipped to the
model's effort limits.

Stiff servos alone do not suffice: the LIPM plan ignores the legs' and arms'
angular momentum and the crouch, so the whole-body ZMP of the IK motion is
off the planned ZMP by up to ~8 cm (measured), and in double-support stops the
plan puts the ZMP 1 cm behind the toe: the open-loop robot rolled onto the
front toe, lifted the rear foot and rocked for 2 s (3.5 s stop). The
stabilisation is a dynamics filter on the reference (Kajita's two-stage
preview control, :class:`ZmpPreviewFilter`): the multibody ZMP error of the IK
motion is fed through a cart-table preview controller and the resulting COG
offset is added to the COG target before the IK is solved again (two passes).
It is causal with respect to the stop: before the signal tick its preview
reads only the nominal walk. No measured-state feedback is used (no
ZMP/DCM feedback or ankle compliance); see the known gaps in the report.
:class:`CopEstimator` measures the centre of pressure (ZMP) of the ground
reaction from the plant's ``contact_results``.

:func:`run_physics` simulates one stop and checks the success criteria;
:func:`sweep` runs it for stop signals over one stride and
:func:`write_sweep` writes the stop map (CSV + PNG).
"""

from __future__ import annotations

import csv
import functools
import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import (AddContactMaterial, AddRigidHydroelasticProperties, CollisionFilterDeclaration,
                              GeometrySet, HalfSpace, ProximityProperties, Role)
from pydrake.math import RigidTransform
from pydrake.multibody.plant import (AddMultibodyPlantSceneGraph, ContactModel, ContactResults,
                                     CoulombFriction, DiscreteContactApproximation)
from pydrake.multibody.tree import PdControllerGains
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem, ValueProducer
from pydrake.systems.primitives import LogVectorOutput, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from drake_estop.gait import ARM_JOINTS, GaitParameters, NominalPattern
from drake_estop.geometry import SupportPolygon
from drake_estop.ik import WholeBodyIkSolver
from drake_estop.model import (FLOATING_BASE, LEFT_SOLE, RIGHT_SOLE, TORSO, UPPER_BODY_JOINTS,
                               load_humanoid, nominal_standing_configuration)
from drake_estop.planner import StopParameters, StopPlan, plan_stop
from drake_estop.rollout import Rollout, rollout

from drake_estop.lipm import GRAVITY  # the one gravity value
SIDES = ("left", "right")
_SOLE_FRAMES = {"left": LEFT_SOLE, "right": RIGHT_SOLE}
_LEVEL = np.array([1.0, 0.0, 0.0, 0.0])
#: The point-contact corner spheres sit 5 mm inside the sole rectangle (models/humanoid.urdf).
SOLE_CONTACT_INSET = 0.005


# --------------------------------------------------------------------------
# Parameters.


@dataclass(frozen=True)
class PhysicsParameters:
    """Simulation, servo and success-criterion settings (SI units).

    Servo gains are per joint group (the first group whose key is in the
    joint name wins); damping is ``kd = damping_ratio_time * kp`` (a 30 ms
    time constant). The legs and chest are stiff position servos (HRP-2's
    harmonic-drive joints are position controlled); below about 2e4 N m/rad
    on the legs the open-loop walk tips over (measured: 1e4 fell at the
    3.4 s stop, 3e4 tracks the COG to a few mm).
    """

    time_step: float = 1e-3  # [s] discrete plant step
    contact: str = "point"  # "point" (sole corner spheres) or "hydroelastic" (sole boxes)
    mu_static: float = 1.0
    mu_dynamic: float = 0.8
    gains: tuple = (("hip", 3e4), ("knee", 3e4), ("ankle", 3e4), ("chest", 2e4), ("head", 200.0),
                    ("shoulder", 2e3), ("elbow", 1e3), ("wrist", 100.0), ("hand", 50.0))
    damping_time: float = 0.03  # kd = damping_time * kp [s]
    log_period: float = 0.005  # per-tick logs (the servo period)
    # success criteria
    pelvis_height_bounds: tuple = (0.45, 0.80)  # [m] pelvis origin above the floor
    max_torso_tilt: float = 0.26  # [rad] (15 deg) torso z axis from the vertical
    max_slip: float = 0.01  # [m] sole travel while it stands on the ground
    rest_speed: float = 0.01  # [m/s] measured COG speed that counts as rest
    rest_within: float = 2.0  # [s] after the planned halt end
    rest_offset: float = 0.02  # [m] final COG from the feet's midpoint (xy)
    cop_tolerance: float = 0.0  # [m] CoP may leave the planned polygon by this much
    contact_force_fraction: float = 0.02  # a foot is "in contact" above this share of the weight
    filter_iterations: int = 2  # dynamics-filter passes on the COG reference (0: raw LIPM COG)

    def __post_init__(self):
        if not (self.time_step > 0 and math.isfinite(self.time_step)):
            raise ValueError(f"time_step must be positive, got {self.time_step!r}")
        if self.contact not in ("point", "hydroelastic"):
            raise ValueError(f"contact must be 'point' or 'hydroelastic', got {self.contact!r}")
        if not 0 < self.mu_dynamic <= self.mu_static:
            raise ValueError("need 0 < mu_dynamic <= mu_static")

    def gain(self, joint_name: str) -> float:
        for key, kp in self.gains:
            if key in joint_name:
                return float(kp)
        raise ValueError(f"no servo gain for joint {joint_name!r}")


# --------------------------------------------------------------------------
# Centre-of-pressure estimator.


class CopEstimator(LeafSystem):
    """Centre of pressure (ZMP) of the ground reaction from contact results.

    .. pydrake_system::

        name: CopEstimator
        input_ports:
        - contact_results
        output_ports:
        - cop
        - normal_force
        - wrench
        - body_normal_forces

    Sums every point-pair and hydroelastic contact between a ``ground`` body
    (by default the world body) and any other body into the net force ``f``
    and moment ``n`` about the world origin that the ground exerts on the
    robot, and intersects its central axis with the floor plane
    ``z = floor_height``: ``cop_x = (h f_x - n_y) / f_z``,
    ``cop_y = (h f_y + n_x) / f_z``. This is the ZMP of the ground reaction
    (moments about the point have no horizontal component).

    Ports:
      - ``contact_results`` (abstract ``ContactResults``): the plant's
        ``get_contact_results_output_port()``.
      - ``cop`` (2): x, y on the floor [m]; NaN while ``f_z`` is below
        ``min_normal_force`` (no support).
      - ``normal_force`` (1): total ``f_z`` [N].
      - ``wrench`` (6): ``[n, f]`` about the world origin, world frame.
      - ``body_normal_forces`` (len(bodies)): ``f_z`` on each of ``bodies``.

    Hydroelastic contacts need the geometry -> body map, which is built from
    ``scene_graph``'s model inspector at construction (pass ``scene_graph``
    after the plant is finalized); without it only point pairs are summed.
    """

    def __init__(self, *, plant, scene_graph=None, bodies=(), ground_bodies=None,
                 floor_height=0.0, min_normal_force=1.0):
        super().__init__()
        self._floor = float(floor_height)
        self._min_fz = float(min_normal_force)
        ground = ground_bodies if ground_bodies is not None else (plant.world_body(),)
        self._ground = {int(b.index()) for b in ground}
        self._bodies = [int(b.index()) for b in bodies]
        self._geometry_body = {}
        if scene_graph is not None:
            inspector = scene_graph.model_inspector()
            for gid in inspector.GetAllGeometryIds(Role.kProximity):
                body = plant.GetBodyFromFrameId(inspector.GetFrameId(gid))
                if body is not None:
                    self._geometry_body[gid] = int(body.index())
        self.contact_results_port = self.DeclareAbstractInputPort(
            "contact_results", AbstractValue.Make(ContactResults()))
        self._sums = self.DeclareCacheEntry(
            "ground reaction",
            ValueProducer(allocate=lambda: AbstractValue.Make(np.zeros(7 + len(self._bodies))),
                          calc=self._calc_sums),
            {self.contact_results_port.ticket()})
        ticket = {self._sums.ticket()}
        self.cop_port = self.DeclareVectorOutputPort("cop", 2, self._calc_cop, prerequisites_of_calc=ticket)
        self.normal_force_port = self.DeclareVectorOutputPort(
            "normal_force", 1, lambda c, o: o.SetAtIndex(0, self._sums.Eval(c)[5]),
            prerequisites_of_calc=ticket)
        self.wrench_port = self.DeclareVectorOutputPort(
            "wrench", 6, lambda c, o: o.SetFromVector(self._sums.Eval(c)[:6]), prerequisites_of_calc=ticket)
        self.body_normal_forces_port = self.DeclareVectorOutputPort(
            "body_normal_forces", len(self._bodies),
            lambda c, o: o.SetFromVector(self._sums.Eval(c)[7:]), prerequisites_of_calc=ticket)

    def _robot_side(self, body_a, body_b):
        """+1 if the force given on B acts on the robot, -1 if on A, 0 if not ground contact."""
        if body_a in self._ground and body_b not in self._ground:
            return 1.0, body_b
        if body_b in self._ground and body_a not in self._ground:
            return -1.0, body_a
        return 0.0, None

    def ground_reaction(self, results: ContactResults) -> np.ndarray:
        """[n (3), f (3), count, f_z per body] of the ground on the robot, about the world origin."""
        moment, force = np.zeros(3), np.zeros(3)
        per_body = np.zeros(len(self._bodies))
        count = 0
        for i in range(results.num_point_pair_contacts()):
            info = results.point_pair_contact_info(i)
            sign, body = self._robot_side(int(info.bodyA_index()), int(info.bodyB_index()))
            if sign == 0.0:
                continue
            f = sign * info.contact_force()
            p = info.contact_point()
            force += f
            moment += np.cross(p, f)
            count += 1
            if body in self._bodies:
                per_body[self._bodies.index(body)] += f[2]
        for i in range(results.num_hydroelastic_contacts()):
            info = results.hydroelastic_contact_info(i)
            surface = info.contact_surface()
            body_m = self._geometry_body.get(surface.id_M())
            body_n = self._geometry_body.get(surface.id_N())
            if body_m is None or body_n is None:
                continue
            # F_Ac_W acts on A (geometry M): towards the robot if M is the robot.
            sign, body = self._robot_side(body_n, body_m)
            if sign == 0.0:
                continue
            spatial = info.F_Ac_W()
            f = sign * spatial.translational()
            tau = sign * spatial.rotational()
            p = surface.centroid()
            force += f
            moment += np.cross(p, f) + tau
            count += 1
            if body in self._bodies:
                per_body[self._bodies.index(body)] += f[2]
        return np.concatenate([moment, force, [count], per_body])

    def _calc_sums(self, context, value):
        value.set_value(self.ground_reaction(self.contact_results_port.Eval(context)))

    def _calc_cop(self, context, output):
        s = self._sums.Eval(context)
        n, f = s[:3], s[3:6]
        if f[2] < self._min_fz:
            output.SetFromVector([np.nan, np.nan])
            return
        h = self._floor
        output.SetFromVector([(h * f[0] - n[1]) / f[2], (h * f[1] + n[0]) / f[2]])


# --------------------------------------------------------------------------
# Plant, contact, servos.


def add_ground(plant, params: PhysicsParameters):
    """Register the ground half-space (z = 0) with friction (and rigid hydroelastic)."""
    props = ProximityProperties()
    AddContactMaterial(friction=CoulombFriction(params.mu_static, params.mu_dynamic), properties=props)
    if params.contact == "hydroelastic":
        AddRigidHydroelasticProperties(props)
    return plant.RegisterCollisionGeometry(plant.world_body(), RigidTransform(), HalfSpace(), "ground", props)


def set_servo_gains(plant, params: PhysicsParameters):
    """PD gains on every joint actuator (before Finalize)."""
    for index in plant.GetJointActuatorIndices():
        actuator = plant.get_mutable_joint_actuator(index)
        kp = params.gain(actuator.joint().name())
        actuator.set_controller_gains(PdControllerGains(p=kp, d=params.damping_time * kp))


def filter_sole_contact(plant, scene_graph, ground_id, params: PhysicsParameters):
    """Keep one contact representation of each sole against the ground.

    Point contact: the corner spheres only (box vs plane would give one
    point pair jumping between the box's corners). Hydroelastic: the
    compliant box only.
    """
    inspector = scene_graph.model_inspector()
    boxes, spheres = [], []
    for gid in inspector.GetAllGeometryIds(Role.kProximity):
        if gid == ground_id:
            continue
        (boxes if inspector.GetName(gid).endswith("sole_box") else spheres).append(gid)
    drop = boxes if params.contact == "point" else spheres
    if drop:
        scene_graph.collision_filter_manager().Apply(
            CollisionFilterDeclaration().ExcludeBetween(GeometrySet(drop), GeometrySet([ground_id])))


def actuated_indices(plant):
    """q and v indices of the actuated joints, in JointActuatorIndex order."""
    joints = [plant.get_joint_actuator(i).joint() for i in plant.GetJointActuatorIndices()]
    return (np.array([j.position_start() for j in joints]), np.array([j.velocity_start() for j in joints]))


# --------------------------------------------------------------------------
# Joint reference from the kinematic rollout.


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


def initial_configuration(plant, ro: Rollout, *, solver=None, attempts=20):
    """Converged IK posture at the first tick of ``ro`` (feet ``step_width`` apart)."""
    solver = solver or WholeBodyIkSolver(plant, max_iterations=50)
    q = nominal_standing_configuration(plant, float(ro.com[0, 2]))
    for _ in range(attempts):
        result = _solve_tick(solver, q, ro, 0)
        q = result.q
        if result.success and result.iterations <= 1:
            return q
    raise RuntimeError(f"the IK cannot reach the initial posture (COG error {result.com_error:.2e} m)")


def _solve_tick(solver, q, ro: Rollout, i):
    upper = dict.fromkeys(UPPER_BODY_JOINTS, 0.0)
    upper.update(zip(ARM_JOINTS, ro.upper_body[i]))
    feet = [np.concatenate([ro.feet[side][i], _LEVEL]) for side in SIDES]
    return solver.solve(q, ro.com[i], feet[0], feet[1], None, upper)


def joint_reference(plant, ro: Rollout, *, solver=None) -> JointReference:
    """Solve the whole-body IK at every tick of ``ro``, warm-started tick to tick."""
    start = time.perf_counter()
    solver = solver or WholeBodyIkSolver(plant)
    q = initial_configuration(plant, ro)
    n = len(ro.times)
    qs = np.empty((n, plant.num_positions()))
    com_err, foot_err = np.empty(n), np.empty(n)
    failures = 0
    for i in range(n):
        result = _solve_tick(solver, q, ro, i)
        q = result.q
        qs[i], com_err[i], foot_err[i] = q, result.com_error, result.foot_position_error
        failures += not result.success
    return JointReference(ro.times, qs, com_err, foot_err, failures, time.perf_counter() - start)


# --------------------------------------------------------------------------
# Dynamics filter: make the multibody ZMP of the reference follow the plan.


def nominal_rollout(pattern: NominalPattern, end: float, servo_period: float) -> Rollout:
    """Kinematic reference of the uninterrupted nominal walk, ticks 0..``end``."""
    count = int(math.floor(end / servo_period + 1e-9)) + 1
    times = servo_period * np.arange(count)
    pos, vel, acc, zmp = pattern.com(times)
    n = len(times)
    feet = {side: np.zeros((n, 3)) for side in SIDES}
    upper = np.zeros((n, len(ARM_JOINTS)))
    for i, t in enumerate(times):
        for side, value in pattern.feet_at(float(t))[0].items():
            feet[side][i] = value
        upper[i] = pattern.upper_body(float(t))[0]
    z = np.full(n, pattern.params.com_height)
    zeros = np.zeros(n)
    return Rollout(times, np.column_stack([pos, z]), np.column_stack([vel, zeros]),
                   np.column_stack([acc, zeros]), zmp, ["walking"] * n, feet, upper)


def multibody_zmp(plant, times, q, *, context=None) -> np.ndarray:
    """ZMP (n, 2) on z = 0 of the whole-body motion q(t) (rigid multibody, finite differences).

    Ground wrench about the world origin from the spatial momentum h = (L, P):
    ``f = dP/dt - m g``, ``n = dL/dt - c x m g``; ZMP = ``(-n_y, n_x) / f_z``.
    """
    context = context or plant.CreateDefaultContext()
    n = len(times)
    momentum = np.zeros((n, 6))
    com = np.zeros((n, 3))
    for i in range(n):
        a, b = max(i - 1, 0), min(i + 1, n - 1)
        plant.SetPositions(context, q[i])
        qdot = (q[b] - q[a]) / (times[b] - times[a])
        plant.SetVelocities(context, plant.MapQDotToVelocity(context, qdot))
        h = plant.CalcSpatialMomentumInWorldAboutPoint(context, np.zeros(3))
        momentum[i, :3], momentum[i, 3:] = h.rotational(), h.translational()
        com[i] = plant.CalcCenterOfMassPositionInWorld(context)
    rate = np.gradient(momentum, times, axis=0)
    weight = np.array([0.0, 0.0, -plant.CalcTotalMass(context) * GRAVITY])
    force = rate[:, 3:] - weight
    moment = rate[:, :3] - np.cross(com, weight)
    return np.column_stack([-moment[:, 1], moment[:, 0]]) / force[:, 2:3]


class ZmpPreviewFilter:
    """Preview control of the cart-table model (Kajita et al. 2003), used as a COG correction.

    ``correct(before, after, switch)`` returns the COG offset (n, 2) whose
    cart-table ZMP tracks ``-error``: fed the multibody-minus-planned ZMP
    error of a reference, it is the second stage of Kajita's two-stage
    preview control. The preview window of tick k reads ``before`` for
    k < ``switch`` and ``after`` from ``switch`` on, so a correction computed
    for a stop plan uses only the nominal walk before the stop signal
    (causal): the stop is not anticipated.
    """

    def __init__(self, *, servo_period=0.005, com_height=0.814, preview_time=1.6, q_error=1.0,
                 r_jerk=1e-6):
        from scipy.linalg import solve_discrete_are
        dt = servo_period
        self.dt = dt
        self.steps = int(round(preview_time / dt))
        a = np.array([[1.0, dt, dt * dt / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
        b = np.array([[dt ** 3 / 6], [dt * dt / 2], [dt]])
        c = np.array([[1.0, 0.0, -com_height / GRAVITY]])
        at = np.block([[np.eye(1), c @ a], [np.zeros((3, 1)), a]])
        bt = np.vstack([c @ b, b])
        qt = np.diag([q_error, 0.0, 0.0, 0.0])
        p = solve_discrete_are(at, bt, qt, np.array([[r_jerk]]))
        inv = 1.0 / (r_jerk + (bt.T @ p @ bt).item())
        k = inv * (bt.T @ p @ at)
        self.gain_integral = k[0, 0]
        self.gain_state = k[0, 1:]
        closed = at - bt @ k
        x = -closed.T @ p @ np.array([[1.0], [0.0], [0.0], [0.0]])
        preview = np.zeros(self.steps)  # gain on the reference j + 1 ticks ahead
        preview[0] = self.gain_integral
        for j in range(1, self.steps):
            preview[j] = -(inv * (bt.T @ x)).item()
            x = closed.T @ x
        self.gain_preview = preview
        self._a, self._b, self._c = a, b[:, 0], c[0]

    def track(self, before, after=None, switch=None) -> np.ndarray:
        """COG trajectory (n,) whose cart-table ZMP tracks the reference (see class doc)."""
        before = np.asarray(before, float)
        after = before if after is None else np.asarray(after, float)
        n = len(after)
        switch = n if switch is None else int(switch)
        windows = tuple(np.concatenate([r, np.full(self.steps + 1, r[-1])]) for r in (before, after))
        state = np.array([after[0], 0.0, 0.0])
        integral = 0.0
        out = np.empty(n)
        for k in range(n):
            src = windows[0] if k < switch else windows[1]
            ref_now = src[k]
            out[k] = state[0]
            integral += self._c @ state - ref_now
            u = (-self.gain_integral * integral - self.gain_state @ state
                 + self.gain_preview @ src[k + 1:k + 1 + self.steps])
            state = self._a @ state + self._b * u
        return out

    def correct(self, error_before, error_after=None, switch=None) -> np.ndarray:
        """COG offsets (n, 2) cancelling the ZMP errors (n, 2)."""
        error_after = error_before if error_after is None else error_after
        return np.column_stack([
            self.track(-np.asarray(error_before)[:, k], -np.asarray(error_after)[:, k], switch)
            for k in range(2)])


# --------------------------------------------------------------------------
# Diagram.


@dataclass
class PhysicsHandles:
    diagram: object
    plant: object
    scene_graph: object
    model_instance: object
    cop: CopEstimator
    reference_source: object
    loggers: dict
    ground_id: object


def add_physics_plant(builder, params: PhysicsParameters):
    """The humanoid on the ground: discrete plant (SAP-based contact), servo gains, sole contact
    filtered to the corner spheres. Returns ``(plant, scene_graph, model_instance, ground_id)``."""
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, params.time_step)
    instance = load_humanoid(plant)
    ground_id = add_ground(plant, params)
    plant.set_contact_model(ContactModel.kPoint if params.contact == "point"
                            else ContactModel.kHydroelasticWithFallback)
    plant.set_discrete_contact_approximation(DiscreteContactApproximation.kLagged)
    set_servo_gains(plant, params)
    plant.Finalize()
    filter_sole_contact(plant, scene_graph, ground_id, params)
    return plant, scene_graph, instance, ground_id


def build_physics_diagram(reference: JointReference | None = None, params: PhysicsParameters | None = None,
                          *, desired_state_source=None) -> PhysicsHandles:
    """Humanoid + ground + PD servos + CoP estimator + 5 ms loggers.

    The desired joint state comes from ``reference`` (a TrajectorySource of its
    first-order hold) or, if given, from ``desired_state_source``, a function
    ``(builder, plant) -> OutputPort`` (e.g. a stabiliser).
    """
    params = params or PhysicsParameters()
    builder = DiagramBuilder()
    plant, scene_graph, instance, ground_id = add_physics_plant(builder, params)
    source = None
    if desired_state_source is not None:
        port = desired_state_source(builder, plant)
    else:
        source = builder.AddNamedSystem("joint_reference", TrajectorySource(
            reference.desired_state_trajectory(plant)))
        port = source.get_output_port()
    builder.Connect(port, plant.get_desired_state_input_port(instance))
    soles = [plant.GetBodyByName(_SOLE_FRAMES[side]) for side in SIDES]
    cop = builder.AddNamedSystem("cop_estimator", CopEstimator(
        plant=plant, scene_graph=scene_graph, bodies=soles))
    builder.Connect(plant.get_contact_results_output_port(), cop.contact_results_port)
    loggers = {
        "state": LogVectorOutput(plant.get_state_output_port(), builder, params.log_period),
        "cop": LogVectorOutput(cop.cop_port, builder, params.log_period),
        "normal_force": LogVectorOutput(cop.normal_force_port, builder, params.log_period),
        "foot_forces": LogVectorOutput(cop.body_normal_forces_port, builder, params.log_period),
    }
    diagram = builder.Build()
    diagram.set_name("estop_physics")
    return PhysicsHandles(diagram, plant, scene_graph, instance, cop, source, loggers, ground_id)


# --------------------------------------------------------------------------
# One run.


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


def _max_abs(reference, name):
    value = None if reference is None else getattr(reference, name)
    return None if value is None else float(np.max(np.abs(value)))


def run_physics(gait_params: GaitParameters | None = None, stop_params: StopParameters | None = None,
                estop_time: float = 3.4, *, after_halt: float = 2.5,
                physics: PhysicsParameters | None = None, pattern: NominalPattern | None = None) -> PhysicsResult:
    """Walk the nominal pattern on the simulated humanoid, stop at ``estop_time``, check the criteria.

    The run starts at t = 0 (standing, before the initial weight shift) from
    the IK posture of the first tick, and ends ``after_halt`` seconds after the
    planned halt end. ``pattern`` (built from ``gait_params`` if omitted) may
    be shared between runs.
    """
    physics = physics or PhysicsParameters()
    stop_params = stop_params or StopParameters()
    pattern = pattern or NominalPattern(gait_params or GaitParameters())
    plan = plan_stop(pattern, estop_time, stop_params)
    ro = rollout(plan, after_halt=after_halt)
    reference = reference_for(ro, plan, filter_iterations=physics.filter_iterations)
    handles = build_physics_diagram(reference, physics)
    simulator = Simulator(handles.diagram)
    context = simulator.get_mutable_context()
    handles.plant.SetPositions(handles.plant.GetMyMutableContextFromRoot(context), reference.q[0])
    simulator.Initialize()
    start = time.perf_counter()
    simulator.AdvanceTo(float(ro.times[-1]))
    wall = time.perf_counter() - start
    return analyse(handles, context, plan, reference, physics, wall)


_IK = {}
_NOMINAL = {}


def _ik():
    """Kinematic-only plant and IK solver (built once per process)."""
    if "plant" not in _IK:
        from pydrake.multibody.plant import MultibodyPlant
        plant = MultibodyPlant(0.0)
        load_humanoid(plant)
        plant.Finalize()
        _IK["plant"], _IK["solver"] = plant, WholeBodyIkSolver(plant)
        _IK["context"] = plant.CreateDefaultContext()
    return _IK["plant"], _IK["solver"], _IK["context"]


def _shifted(ro: Rollout, offset) -> Rollout:
    com = ro.com.copy()
    com[:, :2] += offset
    return replace(ro, com=com)


def _zmp_error(ro: Rollout, offset):
    """(JointReference, multibody - planned ZMP) of ``ro`` with the COG shifted by ``offset``."""
    plant, solver, context = _ik()
    reference = joint_reference(plant, _shifted(ro, offset), solver=solver)
    return reference, multibody_zmp(plant, ro.times, reference.q, context=context) - ro.zmp


def _nominal_errors(pattern: NominalPattern, dt: float, iterations: int, flt: ZmpPreviewFilter):
    """Per-iteration multibody ZMP errors of the filtered nominal walk (cached per pattern)."""
    key = (id(pattern), dt, iterations)
    if key not in _NOMINAL:
        ro = nominal_rollout(pattern, pattern.end_time + 1.0, dt)
        offset = np.zeros((len(ro.times), 2))
        errors = []
        for _ in range(iterations):
            error = _zmp_error(ro, offset)[1]
            errors.append(error)
            offset = offset + flt.correct(error)
        _NOMINAL[key] = (pattern, errors)  # keep the pattern alive: its id stays unique
    return _NOMINAL[key][1]


def reference_for(ro: Rollout, plan: StopPlan | None = None, *, filter_iterations: int = 0) -> JointReference:
    """Joint reference of ``ro``; with ``filter_iterations`` > 0, dynamics-filtered (causal at the signal).

    The filter (:class:`ZmpPreviewFilter`) shifts the COG target so that the
    whole-body ZMP of the IK motion follows the plan's ZMP (the LIPM ignores
    the legs' and arms' angular momentum and the crouch). Before the stop
    signal the preview reads only the nominal walk's errors.
    """
    start = time.perf_counter()
    plant, solver, context = _ik()
    if filter_iterations <= 0:
        return joint_reference(plant, ro, solver=solver)
    dt = float(ro.times[1] - ro.times[0])
    flt = ZmpPreviewFilter(servo_period=dt, com_height=plan.pattern.params.com_height)
    nominal = _nominal_errors(plan.pattern, dt, filter_iterations, flt)
    switch = int(np.searchsorted(ro.times, plan.signal_time - 1e-9))
    n = len(ro.times)
    offset = np.zeros((n, 2))
    raw = None
    for before in nominal:
        before = before[:n] if len(before) >= n else np.vstack([before, np.zeros((n - len(before), 2))])
        _, error = _zmp_error(ro, offset)
        raw = error if raw is None else raw
        offset = offset + flt.correct(before, error, switch)
    reference, error = _zmp_error(ro, offset)
    reference.com_offset, reference.zmp_error_raw, reference.zmp_error = offset, raw, error
    reference.wall_time = time.perf_counter() - start
    return reference


def _sole_polygon_corners(sole, xy, yaw, side):
    """Sole rectangle corners (4, 2) at ankle ``xy`` rotated by ``yaw``."""
    local = sole.corners((0.0, 0.0), side)
    c, s = math.cos(yaw), math.sin(yaw)
    return local @ np.array([[c, s], [-s, c]]) + np.asarray(xy)[:2]


def _planned_support(plan: StopPlan, t: float):
    """Feet the plan stands on at ``t`` (the sides of :meth:`StopPlan.polygon`)."""
    return plan.support_sides(t)


def _intervals(mask):
    """(start, stop) index pairs of the True runs of ``mask``."""
    edges = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))


def analyse(handles: PhysicsHandles, context, plan: StopPlan, reference: JointReference,
            physics: PhysicsParameters, wall_time: float) -> PhysicsResult:
    """Per-tick arrays and success criteria from the loggers of a finished run."""
    plant = handles.plant
    logs = {name: logger.FindLog(context) for name, logger in handles.loggers.items()}
    times = logs["state"].sample_times()
    states = logs["state"].data().T
    cop = logs["cop"].data().T
    normal = logs["normal_force"].data()[0]
    foot_forces = dict(zip(SIDES, logs["foot_forces"].data()))
    n = len(times)
    scratch = plant.CreateDefaultContext()
    torso = plant.GetBodyByName(TORSO)
    pelvis = plant.GetBodyByName(FLOATING_BASE)
    soles = {side: plant.GetFrameByName(_SOLE_FRAMES[side]) for side in SIDES}
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
    pos, _, _, zmp_plan = plan.com(times)
    z_plan = plan.com_height(times)[0]
    com_plan = np.column_stack([pos, z_plan])
    planned_feet = [plan.feet(float(t)) for t in times]
    feet_plan = {side: np.array([f[side] for f in planned_feet]) for side in SIDES}
    weight = plant.CalcTotalMass(scratch) * GRAVITY
    in_contact = {side: foot_forces[side] > physics.contact_force_fraction * weight for side in SIDES}
    # slip: sole travel (xy) over each planned stance interval, from its first tick in contact
    slip = {}
    for side in SIDES:
        stance = (feet_plan[side][:, 2] <= 1e-9) & in_contact[side]
        worst = 0.0
        for a, b in _intervals(stance):
            travel = np.linalg.norm(feet_meas[side][a:b, :2] - feet_meas[side][a, :2], axis=1)
            worst = max(worst, float(travel.max()))
        slip[side] = worst
    sole = plan.pattern.params.sole
    planned_support = [_planned_support(plan, float(t)) for t in times]
    margin_plan = np.full(n, np.nan)
    margin_meas = np.full(n, np.nan)
    for i, t in enumerate(times):
        if not np.all(np.isfinite(cop[i])):
            continue
        touching = [s for s in SIDES if in_contact[s][i]]
        # planned soles (planned poses) that the plan stands on, plus any foot measured in
        # contact (a swing foot touching down a few ms early stands on its planned landing spot)
        standing = [s for s in SIDES if s in touching or s in planned_support[i]]
        margin_plan[i] = SupportPolygon(np.vstack([
            sole.corners(feet_plan[s][i, :2], s) for s in standing])).margin(cop[i])[0]
        if touching:
            corners = np.vstack([_sole_polygon_corners(sole, feet_meas[s][i], feet_yaw[s][i], s)
                                 for s in touching])
            margin_meas[i] = SupportPolygon(corners).margin(cop[i])[0]
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
    }
    return PhysicsResult(
        plan=plan, times=times, cop_x=cop[:, 0], cop_y=cop[:, 1], normal_force=normal,
        foot_forces=foot_forces, pelvis_z=pelvis_z, com_meas_x=com[:, 0], com_meas_y=com[:, 1],
        com_meas_z=com[:, 2], com_meas_speed=speed, com_plan=com_plan, zmp_plan=zmp_plan,
        torso_tilt=tilt, feet_meas=feet_meas, feet_plan=feet_plan, slip=slip,
        cop_margin_plan=margin_plan, cop_margin_meas=margin_meas,
        time_to_rest=rest_time - plan.signal_time, rest_time=rest_time, final_offset=final_offset,
        final_offset_plan=float(np.linalg.norm(com[-1, :2] - mid_plan)), cog_travel=travel,
        criteria=criteria, ik_failures=reference.failures,
        ik_max_com_error=float(reference.com_error.max()), sim_time=float(times[-1] - times[0]),
        sim_wall_time=wall_time, ik_wall_time=reference.wall_time, params=physics, reference=reference)


# --------------------------------------------------------------------------
# Stride sweep and the stop map.

CRITERIA = ("no_fall", "no_slip", "comes_to_rest", "rests_at_midpoint", "cop_in_support")


def sweep_row(result: PhysicsResult) -> dict:
    """One row of the stop map."""
    plan = result.plan
    numbers = result.numbers()
    row = {
        "signal_time": plan.signal_time, "support": plan.support, "case": plan.case,
        "step_length": plan.step_length, "zmp_max": plan.zmp_max,
        "planned_time_to_rest": plan.halt_end - plan.signal_time,
        "time_to_rest": result.time_to_rest, "cog_travel": result.cog_travel,
        **{name: bool(result.criteria[name]) for name in CRITERIA},
        "success": result.success,
        "pelvis_z_min": numbers["pelvis_z_min_m"], "torso_tilt_max": numbers["torso_tilt_max_rad"],
        "slip_max": max(result.slip.values()), "rest_after_halt": numbers["rest_after_halt_s"],
        "final_cog_offset": result.final_offset, "cop_margin_min": numbers["cop_margin_plan_min_m"],
        "cop_edge_time": numbers["cop_edge_time_s"], "realtime_factor": result.realtime_factor,
    }
    return row


def sweep(gait_params: GaitParameters | None = None, stop_params: StopParameters | None = None, *,
          every: float = 0.02, start: float | None = None, duration: float | None = None,
          progress: bool = True, physics: PhysicsParameters | None = None, after_halt: float = 2.5,
          run=None, executor=None):
    """:func:`run_physics` for stop signals every ``every`` s over one stride (default: the
    third step, :meth:`NominalPattern.stride`, single then double support).

    Returns a list of :func:`sweep_row` dicts in signal order; a run that
    raises (e.g. an infeasible plan) gives a row with ``success`` False and
    the ``error``. ``run`` (default :func:`run_physics`, the offline-filter
    reference) is called as ``run(gait_params, stop_params, t, after_halt=...,
    physics=..., pattern=...)`` and returns a :class:`PhysicsResult`
    (e.g. :func:`drake_estop.online.run_online`). ``executor(function, jobs)``
    (e.g. :func:`drake_estop.campaign.executor.map_tasks`, the campaign's Dask
    executor) maps :func:`sweep_job` over the jobs in order; without it the
    runs are serial in this process.
    """
    gait_params = gait_params or GaitParameters()
    stop_params = stop_params or StopParameters()
    pattern = _sweep_pattern(gait_params)
    duration = gait_params.step_time if duration is None else duration
    start = pattern.stride()[0] if start is None else start
    count = int(math.floor(duration / every + 1e-9))
    jobs = [(gait_params, stop_params, float(t), after_halt, physics, run) for t in start + every * np.arange(count)]
    if executor is not None:
        return executor(sweep_job, jobs)
    from tqdm import tqdm
    return [sweep_job(job) for job in tqdm(jobs, desc="physics sweep", unit="run", disable=not progress)]


@functools.lru_cache(maxsize=8)
def _sweep_pattern(gait_params: GaitParameters) -> NominalPattern:
    """The nominal pattern of ``gait_params``, built once per process."""
    return NominalPattern(gait_params)


def sweep_job(job) -> dict:
    """One sweep run: ``job`` = (gait, stop, signal time [s], after_halt [s], physics, run); a :func:`sweep_row`."""
    gait_params, stop_params, t, after_halt, physics, run = job
    run = run or run_physics
    try:
        result = run(gait_params, stop_params, t, after_halt=after_halt, physics=physics,
                     pattern=_sweep_pattern(gait_params))
        return sweep_row(result)
    except Exception as error:  # noqa: BLE001 - recorded in the table
        return {"signal_time": t, "success": False, "error": f"{type(error).__name__}: {error}"}


def write_sweep(table, csv_path, png_path=None):
    """Write the sweep table as CSV and (optionally) the stop map figure."""
    columns = []
    for row in table:
        columns += [k for k in row if k not in columns]
    Path(csv_path).parent.mkdir(parents=True, exist_ok=True)
    with open(csv_path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns)
        writer.writeheader()
        for row in table:
            writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})
    if png_path is not None:
        _plot_stop_map(table, png_path)


def _plot_stop_map(table, png_path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def column(name):
        return np.array([np.nan if row.get(name) is None else float(row.get(name, np.nan)) for row in table])

    t = column("signal_time")
    ok = np.array([bool(row.get("success")) for row in table])
    fig, axes = plt.subplots(5, 1, figsize=(8, 11), sharex=True)
    cases = sorted({row.get("case", "error") for row in table})
    for k, case in enumerate(cases):
        mask = np.array([row.get("case", "error") == case for row in table])
        axes[0].scatter(t[mask], np.full(mask.sum(), k), label=case)
        for support, marker in (("single", "s"), ("double", "o")):
            sub = mask & np.array([row.get("support") == support for row in table])
            axes[0].scatter(t[sub], np.full(sub.sum(), k), marker=marker, facecolors="none", edgecolors="k")
    axes[0].set_yticks(range(len(cases)), cases)
    axes[0].set_title("case taken (squares: single support, circles: double support at the signal)")
    axes[1].plot(t, column("step_length"), "o-", label="step length (single support)")
    axes[1].plot(t, column("zmp_max"), "s-", label="ZMP_max (double support)")
    axes[1].set_ylabel("[m]")
    axes[1].legend(fontsize=8)
    axes[2].plot(t, column("planned_time_to_rest"), "o-", label="planned (halt end)")
    axes[2].plot(t, column("time_to_rest"), "s-", label="measured (COG < 1 cm/s)")
    axes[2].set_ylabel("time to rest [s]")
    axes[2].legend(fontsize=8)
    axes[3].plot(t, column("cog_travel"), "o-")
    axes[3].set_ylabel("COG travel [m]")
    axes[4].scatter(t[ok], np.ones(ok.sum()), c="tab:green", label="success")
    axes[4].scatter(t[~ok], np.zeros((~ok).sum()), c="tab:red", label="failure")
    axes[4].set_yticks([0, 1], ["fail", "ok"])
    axes[4].set_xlabel("stop signal time [s]")
    axes[4].legend(fontsize=8)
    fig.suptitle(f"Physics stop map: {ok.sum()}/{len(ok)} stops meet every criterion")
    fig.tight_layout()
    Path(png_path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png_path, dpi=110)
    plt.close(fig)


# --------------------------------------------------------------------------
# Closed loop: the physics mode of the diagram (planner -> stabiliser -> IK -> servos, online).


@dataclass
class ClosedLoopHandles(PhysicsHandles):
    """:class:`PhysicsHandles` plus the online controller systems of the closed loop."""

    trigger: object = None
    planner: object = None
    stabilizer: object = None
    ik: object = None
    measurement: object = None
    desired_state: object = None
    feedforward: object = None  # TrajectorySource of the offline preview COG offset (or None)


@dataclass(frozen=True)
class StabilizerParameters:
    """Gains of :class:`drake_estop.stabilizer.DcmStabilizer` (see its module docstring)."""

    k_dcm: float = 0.5  # [1/s] DCM error decay rate (see drake_estop.stabilizer: gain choice)
    zmp_margin: float = 0.01  # [m] commanded ZMP kept this far inside the planned support polygon
    k_model: float = 0.0  # share of the estimated ZMP model error cancelled by the COG
    model_error_time_constant: float = 0.02  # [s]
    dcm_filter_time_constant: float = 0.1  # [s] low-pass of the measured DCM error
    max_offset: float = 0.08  # [m] bound on the COG correction
    enabled: bool = True  # False: the same diagram with the feedback cut (open loop, online IK)
    joint_target_mode: str = "interpolate"  # DesiredStateInterpolator mode


def build_closed_loop_diagram(gait_params: GaitParameters | None = None,
                              stop_params: StopParameters | None = None, estop_time: float | None = None, *,
                              physics: PhysicsParameters | None = None,
                              stabilizer: StabilizerParameters | None = None,
                              pattern: NominalPattern | None = None,
                              com_feedforward=None) -> ClosedLoopHandles:
    """The closed-loop physics diagram; everything is computed online in the Simulator.

    ::

        EStopTrigger -> StopPlannerSystem --com, com_vel, zmp, feet--> DcmStabilizer --com--> WholeBodyIK
        StopPlannerSystem --feet, upper_body--> WholeBodyIK --q--> DesiredStateInterpolator
            --desired_state--> MultibodyPlant (PD servos, contact)
        MultibodyPlant --state--> CogMeasurement --com, com_vel--> DcmStabilizer
        MultibodyPlant --contact_results--> CopEstimator --cop--> DcmStabilizer
        loggers (5 ms): plant state, CoP, forces (as build_physics_diagram), IK q and errors,
            stabiliser commanded ZMP / COG offset / DCM error

    The stop is planned inside the Simulator on the servo tick of the signal
    (``estop_time``; None: never). ``com_feedforward`` (optional, default
    None) is a ``PiecewisePolynomial`` of a COG offset ``[dx, dy, dvx, dvy]``
    added to the planned COG and COG velocity before the stabiliser (used by
    ``run_closed_loop(use_preview_filter=True)``: an OFFLINE-computed term).
    """
    from pydrake.systems.primitives import Adder, Demultiplexer, Multiplexer

    from drake_estop.diagram import initial_configuration as pattern_initial_configuration
    from drake_estop.ik import WholeBodyIK
    from drake_estop.stabilizer import CogMeasurement, DcmStabilizer
    from drake_estop.systems import add_stop_controller, connect_reference

    physics = physics or PhysicsParameters()
    stop_params = stop_params or StopParameters()
    stabilizer = stabilizer or StabilizerParameters()
    pattern = pattern or NominalPattern(gait_params or GaitParameters())
    dt = stop_params.servo_period
    builder = DiagramBuilder()
    plant, scene_graph, instance, ground_id = add_physics_plant(builder, physics)
    soles = [plant.GetBodyByName(_SOLE_FRAMES[side]) for side in SIDES]
    cop = builder.AddNamedSystem("cop_estimator", CopEstimator(plant=plant, scene_graph=scene_graph, bodies=soles))
    builder.Connect(plant.get_contact_results_output_port(), cop.contact_results_port)

    trigger, planner = add_stop_controller(builder, pattern=pattern, params=stop_params, estop_time=estop_time)
    kin_plant, _, _ = _ik()
    q0 = pattern_initial_configuration(kin_plant, pattern)
    ik = builder.AddNamedSystem("whole_body_ik", WholeBodyIK(
        plant=kin_plant, servo_period=dt, initial_q=q0, solver=WholeBodyIkSolver(kin_plant)))
    connect_reference(builder, planner, ik)
    measurement = builder.AddNamedSystem("cog_measurement", CogMeasurement(plant=plant))
    builder.Connect(plant.get_state_output_port(), measurement.state_port)
    stab = builder.AddNamedSystem("dcm_stabilizer", DcmStabilizer(
        servo_period=dt, sole=pattern.params.sole, k_dcm=stabilizer.k_dcm, zmp_margin=stabilizer.zmp_margin,
        k_model=stabilizer.k_model, model_error_time_constant=stabilizer.model_error_time_constant,
        dcm_filter_time_constant=stabilizer.dcm_filter_time_constant, max_offset=stabilizer.max_offset))
    com_port, com_vel_port = planner.com_port, planner.com_vel_port
    feedforward = None
    if com_feedforward is not None:
        feedforward = builder.AddNamedSystem("preview_com_offset", TrajectorySource(com_feedforward))
        split = builder.AddSystem(Demultiplexer([2, 2]))
        builder.Connect(feedforward.get_output_port(), split.get_input_port())
        summed = []
        for k, port in enumerate((com_port, com_vel_port)):
            pad = builder.AddSystem(Multiplexer([2, 1]))
            builder.Connect(split.get_output_port(k), pad.get_input_port(0))
            zero = builder.AddSystem(_constant(np.zeros(1)))
            builder.Connect(zero.get_output_port(), pad.get_input_port(1))
            adder = builder.AddSystem(Adder(2, 3))
            builder.Connect(port, adder.get_input_port(0))
            builder.Connect(pad.get_output_port(), adder.get_input_port(1))
            summed.append(adder.get_output_port())
        com_port, com_vel_port = summed
    builder.Connect(com_port, stab.planned_com_port)
    builder.Connect(com_vel_port, stab.planned_com_vel_port)
    builder.Connect(planner.zmp_port, stab.planned_zmp_port)
    builder.Connect(planner.left_foot_port, stab.left_foot_port)
    builder.Connect(planner.right_foot_port, stab.right_foot_port)
    if stabilizer.enabled:
        builder.Connect(measurement.com_port, stab.measured_com_port)
        builder.Connect(measurement.com_vel_port, stab.measured_com_vel_port)
        builder.Connect(cop.cop_port, stab.measured_cop_port)
    else:  # feedback cut: the stabiliser sees a perfectly tracked plan and passes it through
        builder.Connect(com_port, stab.measured_com_port)
        builder.Connect(com_vel_port, stab.measured_com_vel_port)
        builder.Connect(planner.zmp_port, stab.measured_cop_port)
    # the IK's com input was connected to the planner by connect_reference: rebuild that edge
    builder.Disconnect(planner.com_port, ik.com_port)
    builder.Connect(stab.com_port, ik.com_port)
    desired = add_servo_targets(builder, plant, instance, ik, q0, dt, mode=stabilizer.joint_target_mode)
    period = physics.log_period
    loggers = {
        **add_online_loggers(builder, plant, cop, ik, period),
        "commanded_zmp": LogVectorOutput(stab.commanded_zmp_port, builder, period),
        "com_offset": LogVectorOutput(stab.com_offset_port, builder, period),
        "dcm_error": LogVectorOutput(stab.dcm_error_port, builder, period),
    }
    diagram = builder.Build()
    diagram.set_name("estop_closed_loop")
    handles = ClosedLoopHandles(diagram, plant, scene_graph, instance, cop, None, loggers, ground_id,
                                trigger=trigger, planner=planner, stabilizer=stab, ik=ik,
                                measurement=measurement, desired_state=desired, feedforward=feedforward)
    handles.initial_q = q0
    return handles


def add_servo_targets(builder, plant, instance, ik, initial_q, servo_period, mode="interpolate"):
    """The IK's positions, one solve per servo tick, as the plant's PD ``desired_state`` (a
    :class:`drake_estop.stabilizer.DesiredStateInterpolator`). Returns that system."""
    from drake_estop.stabilizer import DesiredStateInterpolator

    q_idx, _ = actuated_indices(plant)
    desired = builder.AddNamedSystem("desired_state", DesiredStateInterpolator(
        q_indices=q_idx, initial_q=initial_q, servo_period=servo_period, mode=mode))
    builder.Connect(ik.q_port, desired.q_port)
    builder.Connect(desired.desired_state_port, plant.get_desired_state_input_port(instance))
    return desired


def add_online_loggers(builder, plant, cop, ik, period) -> dict:
    """Loggers every online physics diagram keeps: plant state, CoP and forces, IK positions and errors."""
    return {
        "state": LogVectorOutput(plant.get_state_output_port(), builder, period),
        "cop": LogVectorOutput(cop.cop_port, builder, period),
        "normal_force": LogVectorOutput(cop.normal_force_port, builder, period),
        "foot_forces": LogVectorOutput(cop.body_normal_forces_port, builder, period),
        "ik_q": LogVectorOutput(ik.q_port, builder, period),
        "ik_com_error": LogVectorOutput(ik.com_error_port, builder, period),
        "ik_foot_error": LogVectorOutput(ik.foot_error_port, builder, period),
    }


def _constant(value):
    from pydrake.systems.primitives import ConstantVectorSource
    return ConstantVectorSource(value)


def _preview_feedforward(plan: StopPlan, after_halt: float, filter_iterations: int):
    """OFFLINE: the ZmpPreviewFilter COG offset of the whole plan as [dx, dy, dvx, dvy](t)."""
    ro = rollout(plan, after_halt=after_halt)
    reference = reference_for(ro, plan, filter_iterations=filter_iterations)
    offset = reference.com_offset
    rate = np.gradient(offset, ro.times, axis=0)
    return PiecewisePolynomial.FirstOrderHold(ro.times, np.hstack([offset, rate]).T), reference.wall_time


def _closed_loop_reference(handles: ClosedLoopHandles, context, wall_time: float) -> JointReference:
    """The IK's positions and errors as logged (the online joint reference)."""
    q_log = handles.loggers["ik_q"].FindLog(context)
    com_err = handles.loggers["ik_com_error"].FindLog(context).data()[0]
    foot_err = handles.loggers["ik_foot_error"].FindLog(context).data()[0]
    from drake_estop.diagram import IK_COM_BOUND, IK_FOOT_BOUND
    failures = int(np.sum((com_err > IK_COM_BOUND) | (foot_err > IK_FOOT_BOUND)))
    return JointReference(q_log.sample_times(), q_log.data().T, com_err, foot_err, failures, wall_time)


def run_closed_loop(gait_params: GaitParameters | None = None, stop_params: StopParameters | None = None,
                    estop_time: float = 3.4, *, after_halt: float = 2.5, use_preview_filter: bool = False,
                    physics: PhysicsParameters | None = None, stabilizer: StabilizerParameters | None = None,
                    pattern: NominalPattern | None = None) -> PhysicsResult:
    """Walk, stop at ``estop_time`` and check the criteria with the closed-loop diagram.

    Everything runs online in the Simulator (:func:`build_closed_loop_diagram`):
    the trigger latches, the planner plans at that servo tick, the stabiliser
    corrects the COG target from the measured COG / CoP, the IK solves each
    5 ms tick and the PD servos track it. The run ends ``after_halt`` s after
    the planned halt end (the plan is read from the planner's context once
    the signal has passed). The criteria are those of :func:`analyse`
    (unchanged); ``result.reference`` holds the logged IK positions.

    ``use_preview_filter=True`` adds the OFFLINE :class:`ZmpPreviewFilter` COG
    correction of the whole plan (computed before the simulation from the
    plan, as in :func:`run_physics`) as a feedforward in front of the
    stabiliser: not a purely online controller.
    """
    physics = physics or PhysicsParameters()
    stop_params = stop_params or StopParameters()
    pattern = pattern or NominalPattern(gait_params or GaitParameters())
    feedforward, offline_time = None, 0.0
    if use_preview_filter:
        iterations = max(physics.filter_iterations, 1)
        feedforward, offline_time = _preview_feedforward(
            plan_stop(pattern, estop_time, stop_params), after_halt, iterations)
    handles = build_closed_loop_diagram(gait_params, stop_params, estop_time, physics=physics,
                                        stabilizer=stabilizer, pattern=pattern, com_feedforward=feedforward)
    simulator = Simulator(handles.diagram)
    context = simulator.get_mutable_context()
    handles.plant.SetPositions(handles.plant.GetMyMutableContextFromRoot(context), handles.initial_q)
    simulator.Initialize()
    plan, wall = run_through_stop(simulator, handles.planner, estop_time, stop_params.servo_period, after_halt,
                                  handles.planner.plan)
    reference = _closed_loop_reference(handles, context, offline_time)
    result = analyse(handles, context, plan, reference, physics, wall)
    result.closed_loop = _closed_loop_logs(handles, context)
    return result


def run_through_stop(simulator, planner, estop_time, servo_period, after_halt, current_plan):
    """Advance ``simulator`` past the signal's servo tick, then to ``after_halt`` past the halt end of
    ``current_plan(planner_context)`` (again while a re-plan moves that end later).

    Returns ``(plan, wall seconds)``; raises RuntimeError if no plan was made by the signal.
    """
    context = simulator.get_mutable_context()
    planner_context = planner.GetMyContextFromRoot(context)
    dt = servo_period
    start = time.perf_counter()
    simulator.AdvanceTo(snap_time(estop_time, dt) + 2 * dt)
    plan = current_plan(planner_context)
    if plan is None:
        raise RuntimeError(f"the planner did not plan a stop by t = {context.get_time():.3f} s")
    end = 0.0
    while end < max(plan.halt_end, plan.signal_time) + after_halt - 1e-9:
        end = dt * math.floor((max(plan.halt_end, plan.signal_time) + after_halt) / dt + 1e-9)
        simulator.AdvanceTo(end)
        plan = current_plan(planner_context)
    return plan, time.perf_counter() - start


def snap_time(t: float, period: float) -> float:
    """First servo tick at or after ``t``."""
    return math.ceil(t / period - 1e-9) * period


def _closed_loop_logs(handles: ClosedLoopHandles, context) -> dict:
    out = {}
    for name in ("commanded_zmp", "com_offset", "dcm_error"):
        log = handles.loggers[name].FindLog(context)
        out[name] = log.data().T
        out["times"] = log.sample_times()
    return out
