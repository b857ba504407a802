"""A humanoid as data: :class:`RobotDescription` and its parts.

A description names what the emergency-stop stack needs to know about a
humanoid and cannot read from its model file: which bodies carry the soles and
how large the soles are, which joints are the legs (by function), the arms,
torso and head, the nominal walking COG height, gait defaults and servo gains.
Everything the model file does say (masses, joint ranges, velocity and effort
limits) is read from the model (:mod:`drake_estop.robots.plant`); the
description only fills in a velocity or effort limit the model leaves out.

The classes are frozen dataclasses whose sequences are tuples, so a
description is hashable (the measurements of :mod:`drake_estop.robots.measure`
are cached by it). :func:`drake_estop.robots.parameters.load_robot` reads them
from YAML with Drake's ``yaml_load_typed``. Every class validates its values on
construction and raises a ``ValueError`` naming the field.

Conventions: x forward, y left, z up; lengths in m, angles in rad unless the
field name says ``_deg``, times in s, gains in N m/rad and N m s/rad.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from drake_estop.planning.gait import Sole

#: The leg joints' functions, in the order :attr:`LegJoints.names` lists them.
LEG_FUNCTIONS = ("hip_yaw", "hip_roll", "hip_pitch", "knee", "ankle_pitch", "ankle_roll")
SIDES = ("left", "right")


def _check_positive(name: str, value) -> None:
    """Raise ``ValueError`` naming ``name`` unless ``value`` is a positive finite number."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")


def _check_finite(name: str, value) -> None:
    """Raise ``ValueError`` naming ``name`` unless ``value`` is a finite number."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")


def _check_name(name: str, value) -> None:
    """Raise ``ValueError`` naming ``name`` unless ``value`` is a non-empty string."""
    if not isinstance(value, str) or not value.strip():
        raise ValueError(f"{name} must be a non-empty name, got {value!r}")


def _check_vector(name: str, value, size: int = 3) -> None:
    """Raise ``ValueError`` naming ``name`` unless ``value`` is ``size`` finite numbers."""
    if len(value) != size or not all(isinstance(x, (int, float)) and math.isfinite(x) for x in value):
        raise ValueError(f"{name} must be {size} finite numbers, got {value!r}")


@dataclass(frozen=True)
class Foot:
    """One sole: the frame at its ground-contact point and its rectangle around that point.

    The sole frame is ``body``'s frame moved by ``translation`` and turned by
    ``rpy_deg``; its origin is on the sole plane (the ground-contact surface),
    straight below the ankle, z up and x forward when the foot stands flat.
    The rectangle is measured from the sole frame's origin along its axes.

    Attributes
    ----------
    body : str
        The model's body (link) the sole belongs to.
    translation : tuple of float
        Sole frame origin in ``body``'s frame [m].
    rpy_deg : tuple of float
        Roll, pitch, yaw of the sole frame in ``body``'s frame [deg].
    toe, heel : float
        Distance from the sole frame's origin to the toe and to the heel edge [m].
    inner, outer : float
        Distance from the origin to the edge towards the robot's centre line and to the edge away from
        it [m].
    """

    body: str = ""
    translation: tuple[float, ...] = (0.0, 0.0, 0.0)
    rpy_deg: tuple[float, ...] = (0.0, 0.0, 0.0)
    toe: float = 0.0
    heel: float = 0.0
    inner: float = 0.0
    outer: float = 0.0

    def __post_init__(self):
        _check_name("body", self.body)
        _check_vector("translation", self.translation)
        _check_vector("rpy_deg", self.rpy_deg)
        for name in ("toe", "heel", "inner", "outer"):
            _check_positive(name, getattr(self, name))

    @property
    def has_offset(self) -> bool:
        """Whether the sole frame differs from ``body``'s frame."""
        return any(self.translation) or any(self.rpy_deg)


@dataclass(frozen=True)
class LegJoints:
    """One leg's joints by function (model joint names).

    Attributes
    ----------
    hip_yaw, hip_roll, hip_pitch, knee, ankle_pitch, ankle_roll : str
        The single-DOF revolute joints. The knee flexes with a positive angle; the hip and ankle
        pitch joints turn about the robot's y axis.
    """

    hip_yaw: str = ""
    hip_roll: str = ""
    hip_pitch: str = ""
    knee: str = ""
    ankle_pitch: str = ""
    ankle_roll: str = ""

    def __post_init__(self):
        for name in LEG_FUNCTIONS:
            _check_name(name, getattr(self, name))

    @property
    def names(self) -> tuple[str, ...]:
        """The joint names in the order hip yaw, roll, pitch, knee, ankle pitch, ankle roll."""
        return tuple(getattr(self, name) for name in LEG_FUNCTIONS)


@dataclass(frozen=True)
class ServoGain:
    """PD servo gains of a joint group: every joint whose name contains ``key``.

    Attributes
    ----------
    key : str
        Part of the joint names of the group (the first gain whose key is in a joint's name wins).
    kp : float
        Position gain [N m/rad].
    kd : float
        Velocity gain [N m s/rad].
    """

    key: str = ""
    kp: float = 0.0
    kd: float = 0.0

    def __post_init__(self):
        _check_name("key", self.key)
        _check_positive("kp", self.kp)
        _check_positive("kd", self.kd)


@dataclass(frozen=True)
class LimitOverride:
    """A velocity or effort limit for a joint whose model file gives none.

    Attributes
    ----------
    joint : str
        The joint name.
    velocity : float or None
        Velocity limit [rad/s]; None keeps the model's.
    effort : float or None
        Effort limit [N m]; None keeps the model's.
    """

    joint: str = ""
    velocity: float | None = None
    effort: float | None = None

    def __post_init__(self):
        _check_name("joint", self.joint)
        for name in ("velocity", "effort"):
            if getattr(self, name) is not None:
                _check_positive(name, getattr(self, name))
        if self.velocity is None and self.effort is None:
            raise ValueError(f"limit override of {self.joint!r} gives neither velocity nor effort")


@dataclass(frozen=True)
class JointAngle:
    """A joint held at an angle.

    Attributes
    ----------
    joint : str
        The joint name.
    angle : float
        Its position [rad].
    """

    joint: str = ""
    angle: float = 0.0

    def __post_init__(self):
        _check_name("joint", self.joint)
        _check_finite("angle", self.angle)


@dataclass(frozen=True)
class SwingJoint:
    """A joint of the walk's arm swing: at ``neutral + gain * swing`` for the shoulder's swing ``swing``.

    Attributes
    ----------
    joint : str
        The joint name (one of the description's upper-body joints).
    neutral : float
        Its angle with the arms at rest [rad].
    gain : float
        Its angle change per radian of swing (dimensionless; the sign says which way it turns).
    """

    joint: str = ""
    neutral: float = 0.0
    gain: float = 0.0

    def __post_init__(self):
        _check_name("joint", self.joint)
        for name in ("neutral", "gain"):
            _check_finite(name, getattr(self, name))


@dataclass(frozen=True)
class PackagePath:
    """Where a ``package://NAME/`` URI of the model points.

    Exactly one source: ``path`` (a folder), or ``distribution`` (an installed Python distribution,
    e.g. ``example-robot-data``) with ``subdirectory`` inside its install prefix.

    Attributes
    ----------
    name : str
        The package name in ``package://NAME/...``.
    path : str or None
        The package's folder (a relative path is relative to the description file's folder).
    distribution : str or None
        An installed Python distribution that holds the package.
    subdirectory : str
        The package's folder relative to the distribution's install location.
    extra : str or None
        The project's optional extra that installs ``distribution`` (named in the error when it is
        missing).
    """

    name: str = ""
    path: str | None = None
    distribution: str | None = None
    subdirectory: str = ""
    extra: str | None = None

    def __post_init__(self):
        _check_name("name", self.name)
        if (self.path is None) == (self.distribution is None):
            raise ValueError(f"package {self.name!r}: give exactly one of path and distribution")


@dataclass(frozen=True)
class RobotDescription:
    """A humanoid for the emergency-stop stack (see the module docstring).

    Attributes
    ----------
    name : str
        Short name (``default``, ``g1``, ``talos``, ...).
    model : str
        The URDF or SDF file: a path (relative to the description file's folder) or a
        ``package://NAME/...`` URI resolved through ``packages``.
    packages : tuple of PackagePath
        The packages the model's ``package://`` URIs name.
    floating_base : str
        The body that floats (the root of the model's tree, e.g. the pelvis).
    torso_body : str
        The body whose orientation the whole-body IK keeps upright besides the floating base.
    left_foot, right_foot : Foot
        The soles.
    sole_contact_in_model : bool
        The model file already carries the sole contact geometry (a box named ``*sole_box`` and
        corner spheres on each sole body); otherwise :func:`drake_estop.robots.plant.add_robot`
        adds it at the sole rectangles.
    sole_thickness : float
        Thickness of the added sole contact box [m] (its bottom face is the sole plane).
    left_leg, right_leg : LegJoints
        The legs.
    left_arm, right_arm, torso, head : tuple of str
        The upper-body joints (possibly empty), each arm from the shoulder outwards.
    walking_com_height : float
        Nominal walking COG height above the floor [m].
    hip_half_width : float or None
        Lateral distance of each sole frame from the centre line in the standing posture [m]; None:
        measured from the model (the sole frames at the zero configuration).
    step_length, step_width, step_time : float or None
        Gait defaults (sagittal step [m], lateral distance between the ankles [m], one step [s]);
        None: scaled from the leg length (:func:`drake_estop.robots.measure.gait_defaults`).
    max_fore_reach, max_rear_reach : float or None
        Leg reach from the COG to the landing ankle at touchdown and to the rear ankle at rest [m];
        None: measured with inverse kinematics (:func:`drake_estop.robots.measure.reach_limits`).
    min_step_width, max_step_width : float or None
        Ankle-to-ankle widths a landing moved sideways may take (the capture landing, the recovery
        step) [m]; None: the soles' inner edges plus 4 cm apart, and the widest step measured with
        inverse kinematics (:func:`drake_estop.robots.measure.reach_limits`).
    recovery_step_inward : bool
        The recovery step is taken while the DCM heads for the rear foot's side, landing wider
        (``StopParameters.recovery_step_inward``; default False, the default humanoid's: measured per robot).
    servo_gains : tuple of ServoGain
        PD gains per joint group; every actuated joint must match one.
    limit_overrides : tuple of LimitOverride
        Velocity and effort limits for joints whose model gives none.
    nominal_posture : tuple of JointAngle
        Upper-body joints held away from zero in the standing posture.
    arm_swing : tuple of SwingJoint
        The joints the walk swings against the legs and the stop halts (eq. 32-33); empty: no arm
        swing. Every other upper-body joint holds its standing angle.
    lift_height : float or None
        Swing-foot apex above the floor [m]; None: the default's 0.05 m scaled by the leg length.
    crouch_depth : float or None
        COG lowering during the stop (IV.A) [m]; None: the default's 0.04 m scaled by the leg length.
    lowest_com_height : float or None
        The lowest COG height the legs reach, knees at their limit [m] (the least ``com_height`` a
        gait may ask for); None: the default's 0.323 m below its straight-leg COG, scaled.
    height : float or None
        Standing height, the top of the head [m] (Meshcat's indicator is drawn above it); None:
        the default's 1.54 m scaled by the straight-leg COG height.
    min_knee_bend : float
        The least knee angle the kinematic whole-body IK allows, in [0, 1) [rad]: a leg-extension limit
        above the model's own (default 0: no straighter than the knee's zero; near a straight knee its
        speed, the leg's extension rate over sin(knee), is unbounded).
    keep_model_collisions : bool
        Keep the model's own collision geometry (primitives and OBJ/VTK/glTF meshes only);
        otherwise only the sole contact geometry collides.
    stop_zmp_margin, swing_tilt_deadband, foot_edge_margin : float or None
        The physics controller's settings for this robot: the stop plan's ZMP margin inside the
        support [m], the swing-foot tilt compensation's dead band [rad] and the foot-edge
        compliance's edge band [m]; None (default): the controller's own
        (:mod:`drake_estop.physics.online`, measured on the default humanoid's 0.24 x 0.136 m soles).
    stop_zmp_weight : float or None
        The physics controller's J_ds ZMP-displacement weight ``a_ds`` (eq. 30) for this robot [1/m^2];
        None (default): the given stop parameters' (the paper's 50). The default humanoid's description gives
        1000 (measured on its campaign).
    foot_force_damping : float or None
        The physics controller's foot force difference control for this robot, its damping [N s/m]
        (:class:`drake_estop.physics.foot_force.FootForceDifferenceControl`); None (default): off.
    foot_force_engage_time : float or None
        With ``foot_force_damping`` (alone it is refused): the control acts once both soles have been on the
        floor this long [s] (longer than the walk's double support: only in a stop's); None (default): always.
    trunk_pitch_joint : str or None
        The trunk joint that pitches the upper body (one of ``torso``): the physics controller's hip
        strategy (``ControllerOptions.hip_strategy``) bows it into a push (:mod:`drake_estop.physics.hip_strategy`);
        None (default): no hip strategy.
    walking_zmp_offset : float or None
        The walk's single-support ZMP ahead of the support ankle [m] (the gait's ``zmp_offset``,
        inside the sole); None (default): at the ankle.
    """

    name: str = ""
    model: str = ""
    packages: tuple[PackagePath, ...] = ()
    floating_base: str = ""
    torso_body: str = ""
    left_foot: Foot | None = None
    right_foot: Foot | None = None
    sole_contact_in_model: bool = False
    sole_thickness: float = 0.01
    left_leg: LegJoints | None = None
    right_leg: LegJoints | None = None
    left_arm: tuple[str, ...] = ()
    right_arm: tuple[str, ...] = ()
    torso: tuple[str, ...] = ()
    head: tuple[str, ...] = ()
    walking_com_height: float = 0.0
    hip_half_width: float | None = None
    step_length: float | None = None
    step_width: float | None = None
    step_time: float | None = None
    max_fore_reach: float | None = None
    max_rear_reach: float | None = None
    min_step_width: float | None = None
    max_step_width: float | None = None
    recovery_step_inward: bool = False
    servo_gains: tuple[ServoGain, ...] = ()
    limit_overrides: tuple[LimitOverride, ...] = ()
    nominal_posture: tuple[JointAngle, ...] = ()
    keep_model_collisions: bool = False
    arm_swing: tuple[SwingJoint, ...] = ()
    lift_height: float | None = None
    crouch_depth: float | None = None
    lowest_com_height: float | None = None
    height: float | None = None
    min_knee_bend: float = 0.0
    stop_zmp_margin: float | None = None
    stop_zmp_weight: float | None = None
    swing_tilt_deadband: float | None = None
    foot_edge_margin: float | None = None
    walking_zmp_offset: float | None = None
    foot_force_damping: float | None = None
    foot_force_engage_time: float | None = None
    trunk_pitch_joint: str | None = None

    def __post_init__(self):
        for name in ("name", "model", "floating_base", "torso_body"):
            _check_name(name, getattr(self, name))
        for name in ("left_foot", "right_foot", "left_leg", "right_leg"):
            if getattr(self, name) is None:
                raise ValueError(f"{name} is missing")
        _check_positive("walking_com_height", self.walking_com_height)
        _check_positive("sole_thickness", self.sole_thickness)
        for name in ("hip_half_width", "step_length", "step_width", "step_time", "max_fore_reach",
                     "max_rear_reach", "min_step_width", "max_step_width", "lift_height", "crouch_depth",
                     "lowest_com_height", "height", "stop_zmp_margin", "stop_zmp_weight",
                     "swing_tilt_deadband", "foot_edge_margin", "walking_zmp_offset",
                     "foot_force_damping", "foot_force_engage_time"):
            if getattr(self, name) is not None:
                _check_positive(name, getattr(self, name))
        if not isinstance(self.recovery_step_inward, bool):
            raise ValueError(f"recovery_step_inward must be true or false, got {self.recovery_step_inward!r}")
        if None not in (self.min_step_width, self.max_step_width) and self.min_step_width >= self.max_step_width:
            raise ValueError(f"min_step_width ({self.min_step_width} m) must be below max_step_width "
                             f"({self.max_step_width} m)")
        inner = self.left_foot.inner + self.right_foot.inner
        if self.min_step_width is not None and self.min_step_width <= inner:
            raise ValueError(f"min_step_width ({self.min_step_width} m) overlaps the soles: their inner edges "
                             f"take {inner} m")
        if self.foot_force_engage_time is not None and self.foot_force_damping is None:
            raise ValueError("foot_force_engage_time is given without foot_force_damping: the foot force control "
                             "it times is off (give both, or neither)")
        bend = self.min_knee_bend
        if isinstance(bend, bool) or not isinstance(bend, (int, float)) or not 0.0 <= bend < 1.0:
            raise ValueError(f"min_knee_bend must be in [0, 1) rad, got {bend!r}")
        self._check_joint_lists()
        if self.trunk_pitch_joint is not None and self.trunk_pitch_joint not in self.torso:
            raise ValueError(f"trunk_pitch_joint {self.trunk_pitch_joint!r} is not one of the torso joints "
                             f"({', '.join(self.torso) or 'none'})")
        self._check_gains()

    def _check_joint_lists(self):
        for name in ("left_arm", "right_arm", "torso", "head"):
            for i, joint in enumerate(getattr(self, name)):
                _check_name(f"{name}[{i}]", joint)
        seen = {}
        for group, joint in self.joint_groups():
            if joint in seen:
                raise ValueError(f"{group}: joint {joint!r} is also in {seen[joint]}")
            seen[joint] = group
        for i, entry in enumerate(self.nominal_posture):
            if entry.joint not in self.upper_body_joints:
                raise ValueError(f"nominal_posture[{i}]: {entry.joint!r} is not one of the upper-body joints")
        for i, entry in enumerate(self.arm_swing):
            if entry.joint not in self.upper_body_joints:
                raise ValueError(f"arm_swing[{i}]: {entry.joint!r} is not one of the upper-body joints")
            if entry.joint in [other.joint for other in self.arm_swing[:i]]:
                raise ValueError(f"arm_swing[{i}]: {entry.joint!r} is listed twice")

    def _check_gains(self):
        if not self.servo_gains:
            raise ValueError("servo_gains is empty: every actuated joint needs a gain")
        for group, joint in self.joint_groups():
            if self.servo_gain(joint) is None:
                raise ValueError(f"servo_gains: no gain whose key is in joint {joint!r} ({group})")

    def joint_groups(self):
        """``(field name, joint name)`` of every joint the description names, legs first."""
        for side in SIDES:
            leg = getattr(self, f"{side}_leg")
            for function in LEG_FUNCTIONS:
                yield f"{side}_leg.{function}", getattr(leg, function)
        for name in ("torso", "head", "left_arm", "right_arm"):
            for i, joint in enumerate(getattr(self, name)):
                yield f"{name}[{i}]", joint

    def foot(self, side: str) -> Foot:
        """The ``side`` ('left' or 'right') sole."""
        return getattr(self, f"{_side(side)}_foot")

    def leg(self, side: str) -> LegJoints:
        """The ``side`` ('left' or 'right') leg's joints."""
        return getattr(self, f"{_side(side)}_leg")

    @property
    def leg_joints(self) -> tuple[str, ...]:
        """Left leg then right leg, each hip yaw to ankle roll."""
        return self.left_leg.names + self.right_leg.names

    @property
    def upper_body_joints(self) -> tuple[str, ...]:
        """Torso, head, left arm, right arm."""
        return self.torso + self.head + self.left_arm + self.right_arm

    @property
    def all_joints(self) -> tuple[str, ...]:
        """Legs then upper body."""
        return self.leg_joints + self.upper_body_joints

    def servo_gain(self, joint: str) -> ServoGain | None:
        """The first of ``servo_gains`` whose key is in ``joint``'s name, or None."""
        return next((gain for gain in self.servo_gains if gain.key in joint), None)

    def standing_angles(self) -> tuple[float, ...]:
        """The upper-body joints' angles in the standing posture (``nominal_posture``, else 0) [rad],
        in :attr:`upper_body_joints` order."""
        posture = {entry.joint: float(entry.angle) for entry in self.nominal_posture}
        return tuple(posture.get(joint, 0.0) for joint in self.upper_body_joints)

    def sole(self) -> Sole:
        """The planner's sole rectangle: the smaller of the two feet's distances on each side [m]."""
        left, right = self.left_foot, self.right_foot
        return Sole(toe=min(left.toe, right.toe), heel=min(left.heel, right.heel),
                    inner=min(left.inner, right.inner), outer=min(left.outer, right.outer))


def _side(side: str) -> str:
    if side not in SIDES:
        raise ValueError(f"side must be 'left' or 'right', got {side!r}")
    return side

