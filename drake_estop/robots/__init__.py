"""Robots as data: the humanoid the emergency-stop stack runs, described in YAML.

A :class:`RobotDescription` says what the stack needs to know about a humanoid
beyond its model file (sole frames and rectangles, leg joints by function,
upper-body joints, walking COG height, gait defaults, servo gains);
:func:`load_robot` reads one by name (``default``, ``g1``, ``talos``) or from a
YAML file and checks it against its model; :func:`add_robot` puts the robot in
a ``MultibodyPlant``; :mod:`drake_estop.robots.measure` measures what follows
from the model (mass, leg length, reach, the standing posture);
:mod:`drake_estop.robots.parameters` makes the planner's gait and stop
parameters of a robot (:func:`gait_parameters`, :func:`stop_parameters`), with
which the Drake diagram, ``AddEmergencyStop(robot=...)``, a scenario's
``robot`` and ``drake-estop simulate --robot`` run it.

``g1`` and ``talos`` use the models of the ``example-robot-data`` package
(``pip install -e '.[robots]'``; it installs the URDFs and STL meshes under
``site-packages/cmeel.prefix/share/example-robot-data``, found through
``importlib.metadata``), and ``trimesh`` converts their STL visuals to OBJ once
(:mod:`drake_estop.robots.meshes` says why). Nothing is downloaded at run time.

The built-in robots (Drake 1.51; COG heights with both soles flat on the floor,
the upper body at zero; "knee" is the knee bend at the walking COG height):

| | ``default`` | ``g1`` | ``talos`` |
| --- | --- | --- | --- |
| model | HRP-2-class humanoid | G1 29 DOF rev 1.0 | TALOS (reduced) |
| actuated joints | 30 | 29 | 32 |
| mass [kg] | 58.00 | 33.34 | 90.27 |
| leg length [m] | 0.705 | 0.689 | 0.812 |
| ankle above the sole [m] | 0.105 | 0.035 | 0.107 |
| straight-leg COG [m] | 0.863 | 0.703 | 0.928 |
| walking COG [m] (knee [rad]) | 0.814 (0.89) | 0.655 (0.90) | 0.87 (0.89) |
| standing half width [m] | 0.060 | 0.1185 | 0.085 |
| sole toe / heel [m] | 0.135 / 0.105 | 0.125 / 0.042 | 0.095 / 0.105 |
| sole inner / outer [m] | 0.055 / 0.081 | 0.028 / 0.028 | 0.055 / 0.055 |
| step length / width [m] | 0.30 / 0.19 | 0.27 / 0.25 | 0.346 / 0.251 |
| step time [s] | 0.80 | 0.79 | 0.86 |
| swing lift / crouch [m] | 0.05 / 0.04 | 0.049 / 0.039 | 0.058 / 0.046 |
| fore / rear reach [m] | 0.195 / 0.26 | 0.186 / 0.228 | 0.241 / 0.29 |
| sideways landing widths [m] | 0.15-0.30 | 0.096-0.383 | 0.15-0.30 |
| arm swing | shoulder pitch, elbow | shoulder pitch, elbow | arm joint 1, elbow |

The default's gait and reach are its description's (the planner's defaults);
the others' are scaled and measured (:mod:`drake_estop.robots.measure`; the
default measures 0.198 / 0.250 m), but for the G1's step length and width
and TALOS's rear reach (measured 0.300 m) and widest step (measured 0.465 m),
which their descriptions set (the YAML files say why). The narrowest
sideways landing puts the soles' inner edges 4 cm apart. The walking COG heights of ``g1`` and
``talos`` put the COG 7 % of the leg length below the straight-leg COG, as the
default's 0.814 m does; their sole rectangles and gains are explained in their
YAML files.
"""

from drake_estop.robots.description import (
    Foot,
    JointAngle,
    LegJoints,
    LimitOverride,
    PackagePath,
    RobotDescription,
    ServoGain,
    SwingJoint,
)
from drake_estop.robots.loading import BUILT_IN, MissingRobotPackage, read_description
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
from drake_estop.robots.parameters import (
    as_robot,
    com_height_range,
    gait_parameters,
    load_robot,
    stepping_limits,
    stop_parameters,
)
from drake_estop.robots.plant import JointLimits, add_robot, joint_limits, set_servo_gains, sole_frame

__all__ = [
    "BUILT_IN", "Foot", "GaitDefaults", "JointAngle", "JointLimits", "LegJoints", "LimitOverride",
    "MissingRobotPackage", "PackagePath", "Reach", "RobotDescription", "RobotFacts", "ServoGain", "SwingJoint",
    "add_robot", "as_robot", "com_height_range", "gait_defaults", "gait_parameters", "joint_limits", "load_robot",
    "max_fore_reach", "max_rear_reach", "measure_reach",
    "nominal_standing_configuration", "reach_limits", "read_description", "robot_facts", "set_servo_gains",
    "sole_frame", "stepping_limits", "stop_parameters",
]
