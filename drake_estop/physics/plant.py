"""The simulated humanoid on Drake: contact plant, PD servos, centre-of-pressure sensor, servo targets.

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

:class:`CopEstimator` measures the centre of pressure (ZMP) of the ground
reaction from the plant's ``contact_results``; :class:`DesiredStateInterpolator`
turns the IK's per-tick positions into the PD ``desired_state``;
:func:`run_through_stop` advances a simulator through a stop.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, replace

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import (
    AddContactMaterial,
    AddRigidHydroelasticProperties,
    Box,
    CollisionFilterDeclaration,
    GeometrySet,
    HalfSpace,
    ProximityProperties,
    Role,
)
from pydrake.math import RigidTransform
from pydrake.multibody.plant import (
    AddMultibodyPlant,
    ContactResults,
    CoulombFriction,
    MultibodyPlantConfig,
)
from pydrake.multibody.tree import PdControllerGains
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem, ValueProducer
from pydrake.systems.primitives import ConstantVectorSource, LogVectorOutput

from drake_estop.model import PELVIS_HEIGHT_AT_ZERO
from drake_estop.planning.plan import LONGEST_STOP
from drake_estop.planning.planner import snap_to_tick
from drake_estop.robots.description import RobotDescription
from drake_estop.robots.parameters import as_robot
from drake_estop.robots.plant import CORNER_RADIUS, add_robot, robot_plant, sole_frame
from drake_estop.robots.plant import set_servo_gains as set_description_gains
from drake_estop.timing import frozen_heap

SIDES = ("left", "right")

#: The point-contact corner spheres sit 5 mm inside the sole rectangle (models/humanoid.urdf, and the
#: contact :func:`drake_estop.robots.add_robot` adds to the other robots' soles).
SOLE_CONTACT_INSET = CORNER_RADIUS

#: The default humanoid's pelvis-origin heights above the floor that count as upright [m]; another robot's
#: are these scaled by its floating base's height at the zero configuration (:func:`pelvis_height_bounds`).
DEFAULT_PELVIS_HEIGHT_BOUNDS = (0.45, 0.80)


@dataclass(frozen=True)
class FloorDrop:
    """A rectangle of the floor lower than the rest: a hole the controller does not know of.

    The planner puts every sole on ``z = 0``; a foot that lands inside ``[x_min, x_max] x [y_min, y_max]``
    [m] (world frame) meets the floor ``depth`` [m] lower. ``--floor-drop X_MIN X_MAX Y_MIN Y_MAX DEPTH``.
    ``ValueError`` (naming the option) for an empty rectangle or a depth outside (0, :data:`MAX_FLOOR_DROP`].
    """

    x_min: float
    x_max: float
    y_min: float
    y_max: float
    depth: float

    def __post_init__(self):
        values = [self.x_min, self.x_max, self.y_min, self.y_max, self.depth]
        if not all(isinstance(v, (int, float, np.floating, np.integer)) and not isinstance(v, bool)
                   and math.isfinite(v) for v in values):
            raise ValueError(f"--floor-drop needs five finite numbers, got {values!r}")
        if not (self.x_min < self.x_max and self.y_min < self.y_max):
            raise ValueError(f"--floor-drop: the rectangle needs X_MIN < X_MAX and Y_MIN < Y_MAX, got {values[:4]!r}")
        if not 0 < self.depth <= MAX_FLOOR_DROP:
            raise ValueError(f"--floor-drop: DEPTH must be in (0, {MAX_FLOOR_DROP}] m, got {self.depth!r}")

    def contains(self, xy) -> bool:
        """Whether the point ``xy`` [m] lies over the lowered floor."""
        return bool(self.x_min <= xy[0] <= self.x_max and self.y_min <= xy[1] <= self.y_max)


#: The deepest floor drop accepted [m] (a step down, not a stair).
MAX_FLOOR_DROP = 0.05
#: How far [m] the floor's boxes around a drop reach: beyond any walk.
FLOOR_EXTENT = 100.0


@dataclass(frozen=True)
class PhysicsParameters:
    """Simulation, servo and success-criterion settings (SI units).

    Servo gains are per joint group (the first group whose key is in the
    joint name wins); damping is ``kd = damping_ratio_time * kp`` (a 30 ms
    time constant). The legs and chest are stiff position servos (HRP-2's
    harmonic-drive joints are position controlled); below about 2e4 N m/rad
    on the legs the open-loop walk tips over (measured: 1e4 fell at the
    3.4 s stop, 3e4 tracks the COG to a few mm).

    Attributes
    ----------
    time_step : float
        Discrete plant step [s].
    contact : str
        "point" (sole corner spheres) or "hydroelastic" (sole boxes).
    mu_static, mu_dynamic : float
        Foot-ground friction coefficients (dimensionless).
    gains : tuple or None
        (joint-name key, kp [N m/rad]) per joint group, in place of the robot description's
        ``servo_gains``; None (default): the description's (kp and kd).
    damping_time : float
        kd = damping_time * kp [s].
    log_period : float
        Log period [s].
    pelvis_height_bounds : tuple of float or None
        Floating-base origin above the floor that counts as upright [m]; None (default): the robot's
        (:func:`pelvis_height_bounds`: (0.45, 0.80) for the default humanoid).
    max_torso_tilt : float
        Torso z axis from the vertical [rad].
    max_slip : float
        Sole travel while it stands [m].
    rest_speed : float
        Measured COG speed that counts as rest [m/s].
    rest_within : float
        Time after the planned halt end to come to rest [s].
    rest_offset : float
        Final COG distance from the feet's midpoint [m].
    cop_tolerance : float
        How far the CoP may leave the planned polygon [m].
    contact_force_fraction : float
        Share of the weight above which a foot is in contact (dimensionless).
    filter_iterations : int
        Dynamics-filter passes on the COG reference.
    floor_drop : FloorDrop or None
        A rectangle of the floor lower than the rest (:func:`add_ground`); None (default): the flat floor.
    """

    time_step: float = 1e-3  # [s] discrete plant step
    contact: str = "point"  # "point" (sole corner spheres) or "hydroelastic" (sole boxes)
    mu_static: float = 1.0
    mu_dynamic: float = 0.8
    gains: tuple | None = None  # (key, kp) per joint group; None: the robot description's servo_gains
    damping_time: float = 0.03  # kd = damping_time * kp [s]
    log_period: float = 0.005  # per-tick logs (the servo period)
    # success criteria
    pelvis_height_bounds: tuple | None = None  # [m] pelvis origin above the floor; None: the robot's
    max_torso_tilt: float = 0.26  # [rad] (15 deg) torso z axis from the vertical
    max_slip: float = 0.01  # [m] sole travel while it stands on the ground
    rest_speed: float = 0.01  # [m/s] measured COG speed that counts as rest
    rest_within: float = 2.0  # [s] after the planned halt end
    rest_offset: float = 0.02  # [m] final COG from the feet's midpoint (xy)
    cop_tolerance: float = 0.0  # [m] CoP may leave the planned polygon by this much
    contact_force_fraction: float = 0.02  # a foot is "in contact" above this share of the weight
    filter_iterations: int = 2  # dynamics-filter passes on the COG reference (0: raw LIPM COG)
    floor_drop: FloorDrop | None = None  # a rectangle of the floor lower than z = 0 (None: a flat floor)

    def __post_init__(self):
        if not (self.time_step > 0 and math.isfinite(self.time_step)):
            raise ValueError(f"time_step must be positive, got {self.time_step!r}")
        if self.contact not in ("point", "hydroelastic"):
            raise ValueError(f"contact must be 'point' or 'hydroelastic', got {self.contact!r}")
        if not 0 < self.mu_dynamic <= self.mu_static:
            raise ValueError("need 0 < mu_dynamic <= mu_static")
        if self.floor_drop is not None and not isinstance(self.floor_drop, FloorDrop):
            raise ValueError(f"floor_drop must be a FloorDrop or None, got {self.floor_drop!r}")

    def gain(self, joint_name: str, robot=None) -> float:
        """kp [N m/rad] of ``joint_name``: from ``gains``, else from ``robot``'s description (default: the
        default humanoid's)."""
        if self.gains is None:
            gain = as_robot(robot).servo_gain(joint_name)
            if gain is None:
                raise ValueError(f"no servo gain for joint {joint_name!r}")
            return float(gain.kp)
        for key, kp in self.gains:
            if key in joint_name:
                return float(kp)
        raise ValueError(f"no servo gain for joint {joint_name!r}")

    def for_robot(self, robot=None) -> PhysicsParameters:
        """These parameters with the robot's criteria filled in where they are None
        (``pelvis_height_bounds``: :func:`pelvis_height_bounds`)."""
        if self.pelvis_height_bounds is not None:
            return self
        return replace(self, pelvis_height_bounds=pelvis_height_bounds(robot))


def pelvis_height_bounds(robot=None) -> tuple:
    """The floating-base heights above the floor [m] that count as upright for ``robot`` (a description, a
    name or None: the default humanoid): :data:`DEFAULT_PELVIS_HEIGHT_BOUNDS` for the default humanoid, for
    another robot those scaled by its floating base's height over the soles at the zero configuration
    against the default's 0.705 m (to 1 mm)."""
    description = as_robot(robot)
    if description == as_robot(None):
        return DEFAULT_PELVIS_HEIGHT_BOUNDS
    scale = _base_height_at_zero(description) / PELVIS_HEIGHT_AT_ZERO
    return tuple(float(round(bound * scale, 3)) for bound in DEFAULT_PELVIS_HEIGHT_BOUNDS)


@functools.cache
def _base_height_at_zero(description: RobotDescription) -> float:
    """Height of the floating base's origin above the lower sole plane at the zero configuration [m]."""
    plant, instance = robot_plant(description)
    context = plant.CreateDefaultContext()  # every joint at zero
    base = plant.GetBodyByName(description.floating_base, instance)
    plant.SetFreeBodyPose(context, base, RigidTransform())
    soles = [sole_frame(plant, description, side, instance=instance).CalcPoseInWorld(context).translation()[2]
             for side in SIDES]
    return -min(soles)


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
        - body_wrenches

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
      - ``body_wrenches`` (6 len(bodies)): ``[n, f]`` of the ground on each of
        ``bodies`` about the world origin, world frame (a foot's force/torque
        sensor, expressed in the world).

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
        # (body A, body B) of a point pair -> (sign, index in ``bodies`` or -1): a function of the model
        # alone, tabulated once for every pair of the plant's bodies
        self._pair_sides = {}
        for body_a in range(plant.num_bodies()):
            for body_b in range(plant.num_bodies()):
                sign, body = self._robot_side(body_a, body_b)
                self._pair_sides[body_a, body_b] = (sign, self._bodies.index(body) if body in self._bodies else -1)
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
            ValueProducer(allocate=lambda: AbstractValue.Make(np.zeros(7 + 7 * len(self._bodies))),
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
            lambda c, o: o.SetFromVector(self._sums.Eval(c)[7:7 + len(self._bodies)]),
            prerequisites_of_calc=ticket)
        self.body_wrenches_port = self.DeclareVectorOutputPort(
            "body_wrenches", 6 * len(self._bodies),
            lambda c, o: o.SetFromVector(self._sums.Eval(c)[7 + len(self._bodies):]), prerequisites_of_calc=ticket)

    def _robot_side(self, body_a, body_b):
        """+1 if the force given on B acts on the robot, -1 if on A, 0 if not ground contact."""
        if body_a in self._ground and body_b not in self._ground:
            return 1.0, body_b
        if body_b in self._ground and body_a not in self._ground:
            return -1.0, body_a
        return 0.0, None

    def ground_reaction(self, results: ContactResults) -> np.ndarray:
        """[n (3), f (3), count, f_z per body, [n, f] per body] of the ground on the robot, about the
        world origin."""
        n_bodies = len(self._bodies)
        # point pairs: summed in plain floats (numpy's per-call cost on 3-vectors was most of this)
        total = [0.0] * 6  # [n, f]
        per_body = [[0.0] * 6 for _ in range(n_bodies)]
        count = 0
        pair_sides = self._pair_sides
        for i in range(results.num_point_pair_contacts()):
            info = results.point_pair_contact_info(i)
            sign, owner = pair_sides[int(info.bodyA_index()), int(info.bodyB_index())]
            if sign == 0.0:
                continue
            px, py, pz = info.contact_point().tolist()
            fx, fy, fz = info.contact_force().tolist()
            fx, fy, fz = sign * fx, sign * fy, sign * fz  # sign is +-1: exact, as numpy's product was
            wrench = (py * fz - pz * fy, pz * fx - px * fz, px * fy - py * fx, fx, fy, fz)
            total = [a + b for a, b in zip(total, wrench)]
            if owner >= 0:
                per_body[owner] = [a + b for a, b in zip(per_body[owner], wrench)]
            count += 1
        moment, force = np.array(total[:3]), np.array(total[3:])
        body_wrench = np.array(per_body, dtype=float).reshape(n_bodies, 6)
        for i in range(results.num_hydroelastic_contacts()):
            info = results.hydroelastic_contact_info(i)
            surface = info.contact_surface()
            body_m = self._geometry_body.get(surface.id_M())
            body_n = self._geometry_body.get(surface.id_N())
            if body_m is None or body_n is None:
                continue
            # F_Ac_W acts on A (geometry M): towards the robot if M is the robot.
            sign, owner = self._pair_sides[body_n, body_m]
            if sign == 0.0:
                continue
            spatial = info.F_Ac_W()
            f = sign * spatial.translational()
            tau = sign * spatial.rotational()
            p = surface.centroid()
            force += f
            moment += np.cross(p, f) + tau
            count += 1
            if owner >= 0:
                body_wrench[owner] += np.concatenate([np.cross(p, f) + tau, f])
        return np.concatenate([moment, force, [count], body_wrench[:, 5], body_wrench.ravel()])

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


def add_ground(plant, params: PhysicsParameters):
    """Register the ground with friction (and rigid hydroelastic): the half-space ``z = 0``, or with
    ``params.floor_drop`` the half-space at ``z = -depth`` and four boxes whose tops at ``z = 0`` leave
    the drop's rectangle open (every ground geometry is the world body's: :func:`ground_geometries`).
    Returns the half-space's geometry id."""
    props = ProximityProperties()
    AddContactMaterial(friction=CoulombFriction(params.mu_static, params.mu_dynamic), properties=props)
    if params.contact == "hydroelastic":
        AddRigidHydroelasticProperties(props)
    world = plant.world_body()
    drop = params.floor_drop
    if drop is None:
        return plant.RegisterCollisionGeometry(world, RigidTransform(), HalfSpace(), "ground", props)
    ground = plant.RegisterCollisionGeometry(world, RigidTransform([0.0, 0.0, -drop.depth]), HalfSpace(),
                                             "ground", props)
    far, thick = FLOOR_EXTENT, drop.depth + 0.05  # each box reaches below the lowered floor
    around = {"behind": ((-far, drop.x_min), (-far, far)), "ahead": ((drop.x_max, far), (-far, far)),
              "right": ((drop.x_min, drop.x_max), (-far, drop.y_min)),
              "left": ((drop.x_min, drop.x_max), (drop.y_max, far))}
    for name, ((x0, x1), (y0, y1)) in around.items():
        plant.RegisterCollisionGeometry(world, RigidTransform([(x0 + x1) / 2, (y0 + y1) / 2, -thick / 2]),
                                        Box(x1 - x0, y1 - y0, thick), f"ground_{name}", props)
    return ground


def ground_geometries(plant) -> list:
    """The ground's collision geometries: every one of the world body's (:func:`add_ground`)."""
    return list(plant.GetCollisionGeometriesForBody(plant.world_body()))


def set_servo_gains(plant, params: PhysicsParameters, instance=None, robot=None):
    """PD gains on every joint actuator (before Finalize): ``robot``'s description's
    (:func:`drake_estop.robots.set_servo_gains`, kp and kd), or with ``params.gains`` those kp and
    ``kd = params.damping_time * kp``. ``instance``: the robot's model instance (needed for the
    description's gains)."""
    if params.gains is None:
        set_description_gains(plant, instance, as_robot(robot))
        return
    for index in plant.GetJointActuatorIndices():
        actuator = plant.get_mutable_joint_actuator(index)
        kp = params.gain(actuator.joint().name())
        actuator.set_controller_gains(PdControllerGains(p=kp, d=params.damping_time * kp))


def filter_sole_contact(plant, scene_graph, ground_id, params: PhysicsParameters):
    """Keep one contact representation of each sole against the ground (every ground geometry:
    :func:`ground_geometries`; ``ground_id`` is one of them).

    Point contact: the corner spheres only (box vs plane would give one
    point pair jumping between the box's corners). Hydroelastic: the
    compliant box only.
    """
    inspector = scene_graph.model_inspector()
    ground = set(ground_geometries(plant)) | {ground_id}
    boxes, spheres = [], []
    for gid in inspector.GetAllGeometryIds(Role.kProximity):
        if gid in ground:
            continue
        (boxes if inspector.GetName(gid).endswith("sole_box") else spheres).append(gid)
    drop = boxes if params.contact == "point" else spheres
    if drop:
        scene_graph.collision_filter_manager().Apply(
            CollisionFilterDeclaration().ExcludeBetween(GeometrySet(drop), GeometrySet(list(ground))))


def actuated_indices(plant):
    """q and v indices of the actuated joints, in JointActuatorIndex order."""
    joints = [plant.get_joint_actuator(i).joint() for i in plant.GetJointActuatorIndices()]
    return (np.array([j.position_start() for j in joints]), np.array([j.velocity_start() for j in joints]))


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


def plant_config(params: PhysicsParameters) -> MultibodyPlantConfig:
    """Drake's ``MultibodyPlantConfig`` of the humanoid's plant: ``params.time_step``, the
    contact model (``"point"`` or ``"hydroelastic_with_fallback"``) and SAP's lagged
    discrete contact approximation (what the plant's implicit PD servos need).

    Drake's default sampled output ports: the plant's step is an unrestricted update, applied
    before the servo tick's discrete updates, so those (estimator, IK, compliance, swing tilt)
    read the robot one plant step after the tick and their command acts from that step on (no
    latency; ``--latency`` adds ticks). The stop planner's update is unrestricted too (its plan
    is abstract state): it reads the estimate of the robot at the tick, before the step, so the
    estimate is computed twice a tick (both counted in the tick's compute time). Measured
    (the robustness benchmark's 208 runs): unsampled outputs (every block reading
    the robot at the tick: one estimate, but 1 ms from reading to command) passed 182 against
    184, the estimator's update made unrestricted (one estimate, from the readings before the
    step) 180; both lose the 17 N s right push at 2.95 s of the acceptance matrix."""
    return MultibodyPlantConfig(
        time_step=params.time_step, discrete_contact_approximation="lagged",
        contact_model="point" if params.contact == "point" else "hydroelastic_with_fallback")


def add_physics_plant(builder, params: PhysicsParameters, robot=None):
    """The robot on the ground: the plant from :func:`plant_config` (``AddMultibodyPlant``), the robot
    (``robot``: a :class:`~drake_estop.robots.RobotDescription`, a name or a description file; default
    the default humanoid) with its sole contact (:func:`drake_estop.robots.add_robot`), servo gains,
    sole contact filtered to the corner spheres.
    Returns ``(plant, scene_graph, model_instance, ground_id)``."""
    description = as_robot(robot)
    plant, scene_graph = AddMultibodyPlant(plant_config(params), builder)
    instance = add_robot(plant, description)
    ground_id = add_ground(plant, params)
    set_servo_gains(plant, params, instance, description)
    plant.Finalize()
    filter_sole_contact(plant, scene_graph, ground_id, params)
    return plant, scene_graph, instance, ground_id


def sole_frames(plant, robot=None) -> list:
    """The robot's sole frames in ``plant``, left then right (:func:`drake_estop.robots.sole_frame`)."""
    description = as_robot(robot)
    return [sole_frame(plant, description, side) for side in SIDES]


def sole_bodies(plant, robot=None) -> list:
    """The bodies that carry the robot's soles in ``plant``, left then right (the bodies a
    :class:`CopEstimator` of the state estimator is built with)."""
    return [frame.body() for frame in sole_frames(plant, robot)]


def add_servo_targets(builder, plant, instance, ik, initial_q, servo_period, mode="interpolate",
                      velocity_limit_fraction=None):
    """The IK's positions, one solve per servo tick, as the plant's PD ``desired_state`` (a
    :class:`DesiredStateInterpolator`). With ``velocity_limit_fraction`` (in (0, 1]) its command is
    rate-limited to that fraction of the model's joint velocity limits. Returns that system."""
    q_idx, v_idx = actuated_indices(plant)
    limits = None
    if velocity_limit_fraction is not None:
        if not 0.0 < velocity_limit_fraction <= 1.0:
            raise ValueError(f"velocity_limit_fraction must be in (0, 1], got {velocity_limit_fraction!r}")
        limits = velocity_limit_fraction * np.minimum(plant.GetVelocityUpperLimits()[v_idx],
                                                      -plant.GetVelocityLowerLimits()[v_idx])
    desired = builder.AddNamedSystem("desired_state", DesiredStateInterpolator(
        q_indices=q_idx, initial_q=initial_q, servo_period=servo_period, mode=mode, velocity_limits=limits))
    builder.Connect(ik.q_port, desired.q_port)
    builder.Connect(desired.desired_state_port, plant.get_desired_state_input_port(instance))
    return desired


def add_pose_hold(builder, plant, instance, q):
    """Hold the robot's actuated joints at ``q`` (full positions) with no controller: a constant plant
    ``desired_state``, zero joint velocities. Returns the ``ConstantVectorSource``."""
    q_idx, _ = actuated_indices(plant)
    held = np.concatenate([np.asarray(q, float)[q_idx], np.zeros(len(q_idx))])
    hold = builder.AddSystem(ConstantVectorSource(held))
    builder.Connect(hold.get_output_port(), plant.get_desired_state_input_port(instance))
    return hold


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


def run_through_stop(simulator, planner, estop_time, servo_period, after_halt, current_plan):
    """Advance ``simulator`` through a stop: until ``after_halt`` past the halt end of
    ``current_plan(planner_context)``, re-read after every step (a re-plan moves that end).

    A ``Simulator`` monitor ends the run; it fails the run if no plan exists two
    ticks after the signal. Returns ``(plan, wall seconds)``; raises RuntimeError
    if no plan was made by the signal.
    """
    context = simulator.get_mutable_context()
    planner_context = planner.GetMyContextFromRoot(context)
    dt = servo_period
    planned_by = snap_to_tick(estop_time, dt) + 2 * dt
    system = simulator.get_system()

    def end_of(plan):
        return dt * math.floor((max(plan.halt_end, plan.signal_time) + after_halt) / dt + 1e-9)

    def monitor(root_context):
        t = root_context.get_time()
        # the run ends on a tick (end_of): the plant's steps between ticks need no look at the plan
        if t < planned_by - 1e-9 or abs(t / dt - round(t / dt)) > 1e-6:
            return EventStatus.DidNothing()
        plan = current_plan(planner_context)
        # no EventStatus.Failed from Python: formatting its message crashes pydrake (see
        # StopPlannerSystem._update); the missing plan ends the run and raises below
        if plan is None or t >= end_of(plan) - 1e-9:
            return EventStatus.ReachedTermination(system, "past the halt" if plan else "no plan")
        return EventStatus.DidNothing()

    simulator.set_monitor(monitor)
    start = time.perf_counter()
    try:
        with frozen_heap():  # no full garbage collection of the loaded model inside a tick
            simulator.AdvanceTo(planned_by + LONGEST_STOP + after_halt)  # the monitor ends it first
    finally:
        simulator.clear_monitor()
    plan = current_plan(planner_context)
    if plan is None:
        raise RuntimeError(f"the planner did not plan a stop by t = {context.get_time():.3f} s")
    if context.get_time() < end_of(plan) - 1e-9:
        raise RuntimeError(f"the stop did not end by t = {context.get_time():.3f} s")
    return plan, time.perf_counter() - start



class DesiredStateInterpolator(LeafSystem):
    """Plant ``desired_state`` ``[q_a, v_a]`` from full positions updated once per servo tick.

    .. pydrake_system::

        name: DesiredStateInterpolator
        input_ports:
        - q
        output_ports:
        - desired_state

    ``q`` (nq) is read with direct feedthrough (connect a discrete source
    such as :class:`drake_estop.systems.ik.WholeBodyIK`, whose value changes only at
    the servo ticks). The state holds the previous tick's actuated positions
    and the tick time ``t_k``; with ``v_k = (q_k - q_{k-1}) / period``:

    * ``mode="interpolate"`` (default): ``q_a(t) = q_{k-1} + (t - t_k) v_k``,
      a first-order hold one servo period late -- continuous, no overshoot;
    * ``mode="extrapolate"``: ``q_a(t) = q_k + (t - t_k) v_k``, no delay but
      it overshoots when the reference decelerates (measured: a swing foot
      struck the floor 6 mm early and the robot bounced off the ground).
    ``q_indices`` / ``v_indices`` select the actuated joints (desired_state
    layout, e.g. :func:`drake_estop.physics.plant.actuated_indices`).

    ``velocity_limits`` (one per actuated joint [rad/s], optional) limits the
    command's rate: ``q_k`` is moved at most ``limit * period`` from the
    previous tick's command, and the rest waits for the next ticks (the
    velocity limit of hrpsys-base's SoftErrorLimiter on HRP-2). A servo
    reference that asks for more than a joint can do (a knee passing near
    straight, where its speed is the leg's extension rate / sin(knee)) is
    then slowed instead of tripping the servo; the IK's later ticks catch
    up.
    """

    def __init__(self, *, q_indices, initial_q, servo_period=0.005, mode="interpolate", velocity_limits=None):
        super().__init__()
        if mode not in ("interpolate", "extrapolate"):
            raise ValueError(f"mode must be 'interpolate' or 'extrapolate', got {mode!r}")
        self._extrapolate = mode == "extrapolate"
        self._idx = np.asarray(q_indices, int)
        self._dt = float(servo_period)
        n = len(self._idx)
        self._max_step = None
        if velocity_limits is not None:
            limits = np.asarray(velocity_limits, float)
            if limits.shape != (n,) or not np.all(limits > 0):  # NaN fails too; inf means no limit
                raise ValueError(f"velocity_limits must be {n} positive values [rad/s], got {velocity_limits!r}")
            self._max_step = limits * self._dt
        initial = np.asarray(initial_q, float)
        self.q_port = self.DeclareVectorInputPort("q", len(initial))
        # [q_a of the previous tick, time of the last tick]
        self._state = self.DeclareDiscreteState(np.concatenate([initial[self._idx], [0.0]]))
        # this tick's [hold start, velocity, tick time, command]: it changes only at the ticks, so it
        # is computed once a tick and not at every plant step between them (the update stores its command)
        self._hold = self.DeclareCacheEntry(
            "first-order hold", ValueProducer(allocate=lambda: AbstractValue.Make(np.zeros(3 * n + 1)),
                                              calc=self._calc_hold),
            {self.q_port.ticket(), self.xd_ticket()})
        self.desired_state_port = self.DeclareVectorOutputPort(
            "desired_state", BasicVector(2 * n), self._calc,
            prerequisites_of_calc={self._hold.ticket(), self.time_ticket()})
        self.DeclarePeriodicDiscreteUpdateEvent(self._dt, 0.0, self._update)

    @property
    def velocity_limits(self):
        """The command's rate limits [rad/s] per actuated joint, or None."""
        return None if self._max_step is None else self._max_step / self._dt

    def _command(self, context, previous):
        """This tick's actuated positions: the input, rate-limited from ``previous``."""
        q = self.q_port.Eval(context)[self._idx]
        if self._max_step is None:
            return q
        return previous + np.clip(q - previous, -self._max_step, self._max_step)

    def _update(self, context, discrete_state):
        q = self._hold.Eval(context)[2 * len(self._idx) + 1:]  # the input, rate-limited from the last command
        discrete_state.set_value(self._state, np.concatenate([q, [context.get_time()]]))
        return EventStatus.Succeeded()

    def _calc_hold(self, context, value):
        state = context.get_discrete_state(self._state).value()
        previous, tick = state[:-1], state[-1]
        q = self._command(context, previous)
        v = (q - previous) / self._dt
        base = q if self._extrapolate else previous
        value.set_value(np.concatenate([base, v, [tick], q]))

    def _calc(self, context, output):
        hold = self._hold.Eval(context)
        n = len(self._idx)
        v = hold[n:2 * n]
        out = output.get_mutable_value()
        out[:n] = hold[:n] + (context.get_time() - hold[2 * n]) * v
        out[n:] = v
