"""A described robot's parameters for the stop stack: its gait, its stop limits, its COG range, its posture.

:func:`gait_parameters` and :func:`stop_parameters` are the planner's
:class:`~drake_estop.planning.gait.GaitParameters` and
:class:`~drake_estop.planning.plan.StopParameters` for a robot: the walking COG
height, the sole rectangle, the gait defaults and the leg reach of its
description (:func:`~drake_estop.robots.measure.gait_defaults`,
:func:`~drake_estop.robots.measure.reach_limits`), its arm swing, and the
swing-foot lift and the crouch depth, each the description's or the default
humanoid's scaled by the leg length (s = L / 0.705 m). For the ``default``
robot they equal ``GaitParameters()`` and ``StopParameters()``.

:func:`load_robot` reads a built-in robot's or a YAML file's description
(:mod:`drake_estop.robots.loading`) and checks it against its model
(:func:`~drake_estop.robots.plant.check_description`); :func:`as_robot` turns a
robot argument (None, a built-in name, a description file, a
:class:`~drake_estop.robots.description.RobotDescription`) into a
description; :func:`standing_seed` is the posture the whole-body IK starts from.
"""

from __future__ import annotations

from dataclasses import replace
from functools import cache
from pathlib import Path

import numpy as np

from drake_estop import model
from drake_estop.planning.arms import ArmSwing
from drake_estop.planning.gait import GaitParameters, NominalPattern
from drake_estop.planning.plan import StopParameters
from drake_estop.robots.description import RobotDescription
from drake_estop.robots.loading import built_in_path, model_file, read_description
from drake_estop.robots.measure import (
    REFERENCE_LEG_LENGTH,
    gait_defaults,
    nominal_standing_configuration,
    reach_limits,
    robot_facts,
)
from drake_estop.robots.plant import check_description

#: The default humanoid's swing-foot apex [m], crouch depth [m], straight-leg and lowest COG heights [m]
#: (models/README.md) and standing height [m]: what the other robots' are scaled from.
REFERENCE_LIFT_HEIGHT = 0.05
REFERENCE_CROUCH_DEPTH = 0.04
REFERENCE_STRAIGHT_COM_HEIGHT = 0.863
REFERENCE_LOWEST_COM_HEIGHT = 0.54
REFERENCE_HEIGHT = 1.54


@cache
def default_robot() -> RobotDescription:
    """The ``default`` robot's description (read once)."""
    return load_robot("default")


def as_robot(value=None) -> RobotDescription:
    """The description a robot argument names.

    Parameters
    ----------
    value : None, str, pathlib.Path or RobotDescription
        None: the ``default`` robot; a built-in name (``default``, ``g1``, ``talos``) or the path of a
        description YAML file (:func:`load_robot`); a description as it is.

    Raises
    ------
    TypeError
        For any other type.
    ValueError
        Naming the field of a bad description (see :func:`load_robot`).
    """
    if value is None or value == "default":
        return default_robot()
    if isinstance(value, RobotDescription):
        return value
    if isinstance(value, (str, Path)):
        return load_robot(value)
    raise TypeError(f"robot must be a robot name, a description file or a RobotDescription, got {value!r}")


def load_robot(name_or_path: str | Path, *, check_model: bool = True) -> RobotDescription:
    """The description of a built-in robot or of a description YAML file, checked against its model.

    Parameters
    ----------
    name_or_path : str or pathlib.Path
        ``default`` (the project's HRP-2-class humanoid), ``g1`` (Unitree G1, 29 DOF), ``talos``
        (PAL TALOS) or the path of a ``.yaml`` description file.
    check_model : bool, optional
        Parse the model (without geometry) and check every body, frame and joint the description
        names (default True).

    Returns
    -------
    RobotDescription
        Lengths in [m], angles in [rad] unless a field's name says ``_deg``.

    Raises
    ------
    ValueError
        Naming the field: an unknown robot name, an unreadable model file, a body or joint that is
        not in the model, a sole rectangle of zero size, ...;
        :class:`~drake_estop.robots.loading.MissingRobotPackage` (a ``ValueError``) names the extra to
        install when a package's distribution is missing.
    """
    text = str(name_or_path)
    is_file = text.endswith((".yaml", ".yml")) or Path(text).is_file()
    description = read_description(filename=text) if is_file else read_description(filename=built_in_path(text))
    if check_model:
        check_description(description)
    return description


def leg_scale(description: RobotDescription) -> float:
    """The robot's leg length over the default humanoid's (dimensionless)."""
    return robot_facts(description).leg_length / REFERENCE_LEG_LENGTH


def _scaled(description: RobotDescription, name: str, reference: float) -> float:
    """The description's ``name``, else ``reference`` scaled by the leg length, to 1 mm [m]."""
    value = getattr(description, name)
    return value if value is not None else round(reference * leg_scale(description), 3)


def arm_swing(description: RobotDescription) -> ArmSwing:
    """The description's arm swing as the gait's :class:`~drake_estop.planning.arms.ArmSwing`."""
    joints = description.arm_swing
    return ArmSwing(joints=tuple(j.joint for j in joints), neutral=tuple(float(j.neutral) for j in joints),
                    gains=tuple(float(j.gain) for j in joints))


def gait_parameters(description: RobotDescription, **changes) -> GaitParameters:
    """The robot's nominal gait: COG height, gait defaults, lift height, sole, arm swing and the walk's ZMP
    offset in the sole (lengths in m, times in s); ``changes`` override any field."""
    defaults = gait_defaults(description)
    gait = GaitParameters(com_height=description.walking_com_height, step_length=defaults.step_length,
                          step_width=defaults.step_width, step_time=defaults.step_time,
                          lift_height=_scaled(description, "lift_height", REFERENCE_LIFT_HEIGHT),
                          sole=description.sole(), arms=arm_swing(description))
    if description.walking_zmp_offset is not None:
        gait = replace(gait, zmp_offset=description.walking_zmp_offset)
    return replace(gait, **changes) if changes else gait


def walk_pattern(robot=None, gait_params: GaitParameters | None = None,
                 pattern: NominalPattern | None = None) -> NominalPattern:
    """The walk a run takes: ``pattern`` (built already), else ``NominalPattern(gait_params)``, by default
    ``robot``'s own gait (a description, a name or None: the default humanoid).

    Raises
    ------
    ValueError
        ``gait_params`` and ``pattern`` both given and disagreeing.
    """
    if pattern is not None:
        if gait_params is not None and gait_params != pattern.params:
            raise ValueError("gait_params and pattern disagree: give one of them (pattern is "
                             "NominalPattern(gait_params))")
        return pattern
    return NominalPattern(gait_params or gait_parameters(as_robot(robot)))


def stop_parameters(description: RobotDescription, **changes) -> StopParameters:
    """The robot's stop limits: its leg reach, landing widths and crouch depth [m] on the paper's weights;
    ``changes`` override any field."""
    reach = reach_limits(description)
    stop = StopParameters(max_fore_reach=reach.fore, max_rear_reach=reach.rear,
                          min_step_width=min_step_width(description), max_step_width=reach.width,
                          recovery_step_inward=description.recovery_step_inward,
                          crouch_depth=_scaled(description, "crouch_depth", REFERENCE_CROUCH_DEPTH))
    return replace(stop, **changes) if changes else stop


#: A crossover landing's reach past the stance ankle [m] for a robot without a leg model, at the default leg
#: length (scaled with the leg): the soles alone keep it apart.
REFERENCE_CROSSOVER_REACH = 0.10


def stepping_limits(description: RobotDescription, params: StopParameters | None = None, **changes):
    """Where and when the robot's feet can land, for the capturability verdict
    (:class:`drake_estop.planning.capturability.SteppingLimits`): its stop limits (``params``, default
    :func:`stop_parameters`) and sole; crossover landings as far as its legs allow. The default humanoid's legs
    (:class:`drake_estop.planning.crossover.LegGeometry`, from its URDF) allow none
    (:func:`~drake_estop.planning.crossover.clear_crossover_reach`); a robot without a leg model gets
    :data:`REFERENCE_CROSSOVER_REACH` scaled with its leg, its soles alone checked (an upper bound).
    ``changes`` override any field."""
    from drake_estop.planning.capturability import SteppingLimits
    from drake_estop.planning.crossover import LegGeometry, clear_crossover_reach

    params = params or stop_parameters(description)
    gait = gait_parameters(description)
    if description == default_robot():
        reach = clear_crossover_reach(LegGeometry(), gait.sole, height=gait.com_height)
    else:
        reach = round(REFERENCE_CROSSOVER_REACH * leg_scale(description), 3)
    return SteppingLimits.from_parameters(params, gait.sole, **{"crossover_reach": reach, **changes})


#: The least gap [m] between the soles' inner edges of a landing moved sideways (no foot collision).
STEP_WIDTH_CLEARANCE = 0.04


def min_step_width(description: RobotDescription) -> float:
    """The narrowest landing [m], ankle to ankle: the description's ``min_step_width``, else the soles'
    inner edges :data:`STEP_WIDTH_CLEARANCE` apart."""
    if description.min_step_width is not None:
        return description.min_step_width
    return round(description.left_foot.inner + description.right_foot.inner + STEP_WIDTH_CLEARANCE, 6)


def com_height_range(description: RobotDescription) -> tuple[float, float]:
    """``(lowest, highest)`` COG height the robot's legs reach [m]: knees at their limit (the description's
    ``lowest_com_height``, else the default's 0.323 m below its straight-leg COG scaled by the leg length)
    and straight (measured, to 1 mm)."""
    straight = round(robot_facts(description).straight_com_height, 3)
    if description.lowest_com_height is not None:
        return description.lowest_com_height, straight
    drop = (REFERENCE_STRAIGHT_COM_HEIGHT - REFERENCE_LOWEST_COM_HEIGHT) * leg_scale(description)
    return round(straight - drop, 3), straight


def standing_height(description: RobotDescription) -> float:
    """The robot's standing height [m]: the description's, else the default's scaled by the straight-leg
    COG height."""
    if description.height is not None:
        return description.height
    straight = robot_facts(description).straight_com_height
    return round(REFERENCE_HEIGHT * straight / REFERENCE_STRAIGHT_COM_HEIGHT, 2)


def standing_seed(plant, description: RobotDescription, *, com_height: float) -> np.ndarray:
    """A standing posture of the robot in ``plant`` with the COG ``com_height`` [m] above the floor, where
    the whole-body IK starts.

    The project's own humanoid (the model file ``models/humanoid.urdf``) starts from
    :func:`drake_estop.model.nominal_standing_configuration` (knee bend and shank lean by Newton's
    method: the posture every result of the default robot was computed from); any other robot from
    :func:`drake_estop.robots.measure.nominal_standing_configuration` (Drake's ``InverseKinematics``).
    """
    if model_file(description) == model.MODEL_PATH:
        return model.nominal_standing_configuration(plant, com_height)
    return nominal_standing_configuration(plant, description, com_height=com_height)
