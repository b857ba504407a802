"""A described robot in a ``MultibodyPlant``: parsing, sole frames and contact, actuators, limits, gains.

:func:`add_robot` parses the description's model offline (an empty
``PackageMap``: nothing is fetched, whatever ``DRAKE_ALLOW_NETWORK`` says; a
URDF is first rewritten by :func:`drake_estop.robots.meshes.prepare_urdf`),
checks the description against it, adds the sole frames that sit at an offset
from their body, one actuator for every described joint the model leaves
unactuated (with the URDF's ``<limit effort>``), the description's limits
where the model gives none, and (in a plant with a scene graph) the sole contact geometry at
the sole rectangles: a box whose bottom face is the sole plane (compliant
hydroelastic) and four 5 mm spheres at the corners, as the project's own
humanoid carries them in its model file (``models/README.md``). Drake
computes contact only on primitive shapes and OBJ/VTK/glTF meshes, so these
are boxes and spheres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydrake.geometry import (
    AddCompliantHydroelasticProperties,
    AddContactMaterial,
    Box,
    ProximityProperties,
    Sphere,
)
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.plant import CoulombFriction, MultibodyPlant
from pydrake.multibody.tree import FixedOffsetFrame, PdControllerGains, RevoluteJoint

from drake_estop.model import offline_parser
from drake_estop.planning.lipm import GRAVITY
from drake_estop.robots.description import SIDES, RobotDescription
from drake_estop.robots.loading import model_file, package_map
from drake_estop.robots.meshes import prepare_urdf

#: Names of the sole frames added where a sole sits at an offset from its body.
SOLE_FRAME_NAMES = {"left": "estop_left_sole", "right": "estop_right_sole"}
#: Corner spheres of the added sole contact: radius [m], also their inset from the rectangle's edges.
CORNER_RADIUS = 0.005
#: Friction of the added sole contact (static, dynamic; as in models/humanoid.urdf).
SOLE_FRICTION = (1.0, 0.8)
#: Compliant hydroelastic sole box: modulus [Pa], Hunt-Crossley dissipation [s/m] (as the humanoid's).
HYDROELASTIC_MODULUS = 5.0e6
HUNT_CROSSLEY_DISSIPATION = 3.0


@dataclass(frozen=True)
class JointLimits:
    """One joint's limits as the model (or a description override) gives them.

    Attributes
    ----------
    lower, upper : float
        Position range [rad].
    velocity : float
        Speed limit [rad/s] (inf when neither model nor description gives one).
    effort : float
        Torque limit [N m] (inf likewise).
    """

    lower: float
    upper: float
    velocity: float
    effort: float


def add_robot(plant: MultibodyPlant, description: RobotDescription, *, contact: bool = True):
    """Add the described robot to ``plant`` (not finalized) and return its model instance.

    Parameters
    ----------
    plant : pydrake.multibody.plant.MultibodyPlant
        A plant that is not finalized; with a scene graph the model's visuals are added (meshes
        converted as needed) and, with ``contact``, the sole contact geometry.
    description : RobotDescription
        The robot.
    contact : bool, optional
        Add the sole contact geometry (default True; ignored without a scene graph or when
        ``description.sole_contact_in_model``).

    Returns
    -------
    pydrake.multibody.tree.ModelInstanceIndex

    Raises
    ------
    ValueError
        Naming the description's field when the model cannot be read or does not have a body, frame
        or joint the description names.

    Notes
    -----
    The plant's gravity is set to :data:`drake_estop.planning.lipm.GRAVITY` [m/s^2], the value the
    planner uses.
    """
    if plant.is_finalized():
        raise ValueError("plant: add_robot needs a plant that is not finalized")
    instance, efforts = _parse(plant, description)
    _check_model(plant, instance, description)
    plant.mutable_gravity_field().set_gravity_vector([0.0, 0.0, -GRAVITY])
    _add_sole_frames(plant, instance, description)
    _add_missing_actuators(plant, instance, description, efforts)
    _apply_limit_overrides(plant, instance, description)
    if contact and plant.geometry_source_is_registered() and not description.sole_contact_in_model:
        for side in SIDES:
            add_sole_contact(plant, instance, description, side)
    return instance


def _parse(plant, description):
    """Parse the model into ``plant``; return its one model instance and the URDF's joint efforts [N m]."""
    path = model_file(description)
    parser = offline_parser(plant)
    visuals = plant.geometry_source_is_registered()
    efforts, packages = {}, package_map(description)
    try:
        if path.suffix.lower() == ".urdf" and _needs_preparation(description, path):
            prepared = prepare_urdf(path, packages=packages, visuals=visuals,
                                    collisions=description.keep_model_collisions)
            instances = parser.AddModelsFromString(prepared.text, "urdf")
            efforts = prepared.efforts
        else:
            parser.package_map().AddMap(packages)
            instances = parser.AddModels(str(path))
    except RuntimeError as error:
        raise ValueError(f"model: Drake cannot parse {path}: {error}") from error
    if len(instances) != 1:
        raise ValueError(f"model: expected one model in {path}, got {len(instances)}")
    return instances[0], efforts


def _needs_preparation(description, path) -> bool:
    """A URDF that is not the self-contained kind Drake parses as it is (meshes, packages, dropped
    collisions)."""
    text = path.read_text()
    return "<mesh" in text or "package://" in text or "<mimic" in text or not description.keep_model_collisions


def _check_model(plant, instance, description):
    """Raise ValueError naming the field of a body or joint the model does not have."""
    model = plant.GetModelInstanceName(instance)
    for name in ("floating_base", "torso_body"):
        _body(plant, instance, getattr(description, name), name, model)
    for side in SIDES:
        _body(plant, instance, description.foot(side).body, f"{side}_foot.body", model)
    for group, joint in description.joint_groups():
        if not plant.HasJointNamed(joint, instance):
            raise ValueError(f"{group}: joint {joint!r} is not in the model {model!r}")
        if not isinstance(plant.GetJointByName(joint, instance), RevoluteJoint):
            raise ValueError(f"{group}: joint {joint!r} is not a revolute joint")
    base = plant.GetBodyByName(description.floating_base, instance)
    for index in plant.GetJointIndices(instance):
        joint = plant.get_joint(index)
        if joint.child_body().index() == base.index() and joint.num_velocities() != 6:
            raise ValueError(f"floating_base: body {description.floating_base!r} has an inboard joint "
                             f"({joint.name()!r}); it must be the root of the model's tree or float")
    for i, override in enumerate(description.limit_overrides):
        if not plant.HasJointNamed(override.joint, instance):
            raise ValueError(f"limit_overrides[{i}]: joint {override.joint!r} is not in the model {model!r}")


def _actuator_indices(plant, instance) -> list:
    """The joint actuators of ``instance`` (``GetJointActuatorIndices(instance)`` lists none before
    ``Finalize``)."""
    return [i for i in plant.GetJointActuatorIndices() if plant.get_joint_actuator(i).model_instance() == instance]


def _body(plant, instance, name, field_name, model):
    if not plant.HasBodyNamed(name, instance):
        raise ValueError(f"{field_name}: body {name!r} is not in the model {model!r}")
    return plant.GetBodyByName(name, instance)


def sole_pose_in_body(description: RobotDescription, side: str) -> RigidTransform:
    """The ``side`` sole frame's pose in its body's frame (X_BS)."""
    foot = description.foot(side)
    return RigidTransform(RollPitchYaw(np.radians(foot.rpy_deg)), np.asarray(foot.translation, float))


def _add_sole_frames(plant, instance, description):
    for side in SIDES:
        foot = description.foot(side)
        if foot.has_offset:
            body = plant.GetBodyByName(foot.body, instance)
            plant.AddFrame(FixedOffsetFrame(SOLE_FRAME_NAMES[side], body.body_frame(),
                                            sole_pose_in_body(description, side)))


def sole_frame(plant: MultibodyPlant, description: RobotDescription, side: str, *, instance=None):
    """The ``side`` ('left' or 'right') sole frame: the foot body's frame, or the one :func:`add_robot`
    added at its offset."""
    foot = description.foot(side)
    args = () if instance is None else (instance,)
    if foot.has_offset:
        return plant.GetFrameByName(SOLE_FRAME_NAMES[side], *args)
    return plant.GetBodyByName(foot.body, *args).body_frame()


def _sole_properties(*, hydroelastic: bool) -> ProximityProperties:
    properties = ProximityProperties()
    AddContactMaterial(dissipation=HUNT_CROSSLEY_DISSIPATION if hydroelastic else None,
                       friction=CoulombFriction(*SOLE_FRICTION), properties=properties)
    if hydroelastic:
        AddCompliantHydroelasticProperties(resolution_hint=1.0, hydroelastic_modulus=HYDROELASTIC_MODULUS,
                                           properties=properties)
    return properties


def sole_contact_points(description: RobotDescription, side: str) -> dict:
    """Corner-sphere centres of the ``side`` sole in the sole frame [m], by name (``toe_outer``, ...).

    The spheres lie :data:`CORNER_RADIUS` inside the rectangle and touch the sole plane.
    """
    foot, r = description.foot(side), CORNER_RADIUS
    out = 1.0 if side == "left" else -1.0  # +y is outward for the left foot
    return {"toe_outer": (foot.toe - r, out * (foot.outer - r), r),
            "toe_inner": (foot.toe - r, -out * (foot.inner - r), r),
            "heel_outer": (-foot.heel + r, out * (foot.outer - r), r),
            "heel_inner": (-foot.heel + r, -out * (foot.inner - r), r)}


def add_sole_contact(plant, instance, description: RobotDescription, side: str) -> None:
    """Register the ``side`` sole's contact box (``{side}_sole_box``) and corner spheres on its body."""
    foot = description.foot(side)
    body = plant.GetBodyByName(foot.body, instance)
    X_BS = sole_pose_in_body(description, side)
    out = 1.0 if side == "left" else -1.0
    thickness = description.sole_thickness
    centre = ((foot.toe - foot.heel) / 2, out * (foot.outer - foot.inner) / 2, thickness / 2)
    plant.RegisterCollisionGeometry(body, X_BS @ RigidTransform(centre),
                                    Box(foot.toe + foot.heel, foot.inner + foot.outer, thickness),
                                    f"{side}_sole_box", _sole_properties(hydroelastic=True))
    for name, point in sole_contact_points(description, side).items():
        plant.RegisterCollisionGeometry(body, X_BS @ RigidTransform(point), Sphere(CORNER_RADIUS),
                                        f"{side}_sole_{name}", _sole_properties(hydroelastic=False))


def _add_missing_actuators(plant, instance, description: RobotDescription, efforts: dict) -> list:
    """One actuator (``<joint>_motor``) on every described joint that has none; return their names.

    The effort limit is the URDF's ``<limit effort>`` (``efforts``), else the description's override,
    else none.
    """
    actuated = {plant.get_joint_actuator(i).joint().name() for i in _actuator_indices(plant, instance)}
    overrides = {o.joint: o.effort for o in description.limit_overrides if o.effort is not None}
    added = []
    for _, joint in description.joint_groups():
        if joint not in actuated:
            effort = efforts.get(joint) or overrides.get(joint) or math.inf
            plant.AddJointActuator(f"{joint}_motor", plant.GetJointByName(joint, instance), effort)
            added.append(f"{joint}_motor")
    return added


def _apply_limit_overrides(plant, instance, description: RobotDescription) -> None:
    """Write the description's velocity and effort limits where the model gives none.

    Raises
    ------
    ValueError
        Naming ``limit_overrides[i]`` when the model already gives that limit.
    """
    actuators = {plant.get_joint_actuator(i).joint().name(): plant.get_mutable_joint_actuator(i)
                 for i in _actuator_indices(plant, instance)}
    for i, override in enumerate(description.limit_overrides):
        joint = plant.GetMutableJointByName(override.joint, instance)
        if override.velocity is not None:
            if math.isfinite(joint.velocity_upper_limits()[0]):
                raise ValueError(f"limit_overrides[{i}]: the model gives {override.joint!r} a velocity limit")
            joint.set_velocity_limits([-override.velocity], [override.velocity])
        actuator = actuators.get(override.joint)
        if override.effort is not None and actuator is not None:
            if math.isfinite(actuator.effort_limit()) and actuator.effort_limit() != override.effort:
                raise ValueError(f"limit_overrides[{i}]: the model gives {override.joint!r} an effort limit")
            actuator.set_effort_limit(override.effort)


def set_servo_gains(plant, instance, description: RobotDescription) -> None:
    """The description's PD gains on the actuators of its joints (before Finalize)."""
    for index in _actuator_indices(plant, instance):
        actuator = plant.get_mutable_joint_actuator(index)
        gain = description.servo_gain(actuator.joint().name())
        if gain is None:
            raise ValueError(f"servo_gains: no gain whose key is in joint {actuator.joint().name()!r}")
        actuator.set_controller_gains(PdControllerGains(p=gain.kp, d=gain.kd))


def joint_limits(plant, instance, description: RobotDescription) -> dict:
    """Joint name -> :class:`JointLimits` of every described joint, read from ``plant``."""
    efforts = {plant.get_joint_actuator(i).joint().name(): plant.get_joint_actuator(i).effort_limit()
               for i in _actuator_indices(plant, instance)}
    limits = {}
    for _, name in description.joint_groups():
        joint = plant.GetJointByName(name, instance)
        limits[name] = JointLimits(lower=float(joint.position_lower_limits()[0]),
                                   upper=float(joint.position_upper_limits()[0]),
                                   velocity=float(joint.velocity_upper_limits()[0]),
                                   effort=float(efforts.get(name, math.inf)))
    return limits


def robot_plant(description: RobotDescription, *, time_step: float = 0.0):
    """A finalized plant (no scene graph) holding the robot alone, with its actuators and limits.

    Returns
    -------
    tuple
        ``(plant, model instance)``.
    """
    plant = MultibodyPlant(time_step)
    instance = add_robot(plant, description, contact=False)
    plant.Finalize()
    return plant, instance


def check_description(description: RobotDescription) -> None:
    """Parse the model (no geometry) and check the description against it; raise ValueError naming the
    field."""
    robot_plant(description)
