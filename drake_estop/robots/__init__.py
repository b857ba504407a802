"""Robots as data: the humanoid the emergency-stop stack runs, described in YAML.

A :class:`RobotDescription` says what the stack needs to know about a humanoid
beyond its model file (sole frames and rectangles, leg joints by function,
upper-body joints, walking COG height, gait defaults, servo gains);
:func:`load_robot` reads one by name (``default``, ``g1``, ``talos``) or from a
YAML file and checks it against its model; :func:`add_robot` puts the robot in
a ``MultibodyPlant``; :mod:`drake_estop.robots.measure` measures what follows
from the model (mass, leg length, reach, the standing posture).

``g1`` and ``talos`` use the models of the ``example-robot-data`` package
(``pip install -e '.[robots]'``).
"""

from drake_estop.robots.description import (
    Foot,
    JointAngle,
    LegJoints,
    LimitOverride,
    PackagePath,
    RobotDescription,
    ServoGain,
)
from drake_estop.robots.loading import BUILT_IN, MissingRobotPackage, load_robot, read_description
from drake_estop.robots.measure import (
    GaitDefaults,
    Reach,
    RobotFacts,
    gait_defaults,
    max_fore_reach,
    max_rear_reach,
    measure_reach,
    nominal_standing_configuration,
    reach_limits,
    robot_facts,
)
from drake_estop.robots.plant import JointLimits, add_robot, joint_limits, set_servo_gains, sole_frame

__all__ = [
    "BUILT_IN", "Foot", "GaitDefaults", "JointAngle", "JointLimits", "LegJoints", "LimitOverride",
    "MissingRobotPackage", "PackagePath", "Reach", "RobotDescription", "RobotFacts", "ServoGain", "add_robot",
    "gait_defaults", "joint_limits", "load_robot", "max_fore_reach", "max_rear_reach", "measure_reach",
    "nominal_standing_configuration", "reach_limits", "read_description", "robot_facts", "set_servo_gains",
    "sole_frame",
]
