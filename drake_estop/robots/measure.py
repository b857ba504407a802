"""What follows from a robot's model: mass and leg length, gait defaults, leg reach, the standing posture.

Measurements are made on the robot alone in a plant without geometry
(:func:`drake_estop.robots.plant.robot_plant`) and cached by description (a
frozen, hashable dataclass); the reach, which takes some inverse-kinematics
solves, is also kept on disk under :func:`drake_estop.robots.meshes.cache_dir`.

**Gait defaults** (:func:`gait_defaults`) scale the project's HRP-2-class gait
(0.3 m steps of 0.8 s, ankles 0.19 m apart, leg length 0.705 m) to the robot
by dynamic similarity (equal Froude number v^2 / (g L)): with s = L / 0.705
for the robot's leg length L, the step length scales as s, the step time as
sqrt(s) (pendulum time sqrt(L / g)), and the step width is the standing width
2 ``hip_half_width`` plus the default's 0.07 m spread beyond its hips, scaled
by s. A description's own numbers win.

**Leg reach** (:func:`measure_reach`), found with Drake's
``InverseKinematics`` (SNOPT) in a double-support stance: the floating base
upright, the upper body at its nominal posture (every joint but the legs held,
named in the description or not, as the whole-body IK holds them), the COG at the walking height
over (0, 0), the ankles at y = +-step_width / 2, both soles flat on the floor.

* fore reach: the support (right) sole under the COG at x = 0, the landing
  (left) sole at x = r with its knee bent by at least 0.4 rad (a straight
  landing knee makes the knee speed unbounded); r as large as the IK still
  solves;
* rear reach: the COG at rest over the feet's midpoint, the soles at x = +-r,
  the knees bent by at least 0.0 rad (up to straight); r as large as solves;
* widest step: the support (right) sole where it stands, the landing (left)
  sole moved out sideways to y = step_width / 2 + r with its knee bent by at
  least 0.4 rad, the COG over (0, 0); the width is step_width + r.

r is grown from 0 in 5 cm steps, each solve warm-started from the last, and
the step halved on a failure down to 1 mm: the reach is as far as the IK
still converges, which near a straight knee may be a few millimetres short of
the geometric limit. The default humanoid's planner numbers (fore 0.195 m,
rear 0.26 m, widest step 0.30 m, measured by hand with the project's whole-body
IK) stay in its description; this measurement gives it fore 0.198 m, rear
0.250 m and widest step 0.338 m, the G1 0.186 / 0.228 / 0.383 m, TALOS
0.241 / 0.300 / 0.465 m.

**Standing posture** (:func:`nominal_standing_configuration`): the same IK
with the soles at (0, +-hip_half_width) and the COG at the walking height over
(0, 0): 15 equations (two sole poses, the COG) in 15 unknowns (the base
position, twelve leg joints), the base orientation fixed, so the posture is
an isolated solution; the initial guess (knees bent by 0.6 rad) picks the
bent-knee one.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
import tempfile
from dataclasses import asdict, dataclass

import numpy as np
from pydrake.math import RigidTransform
from pydrake.multibody.inverse_kinematics import ComPositionConstraint, InverseKinematics
from pydrake.solvers import Solve

from drake_estop.planning.lipm import GRAVITY
from drake_estop.robots.description import SIDES, RobotDescription
from drake_estop.robots.loading import model_file
from drake_estop.robots.meshes import cache_dir
from drake_estop.robots.plant import joint_limits, robot_plant, sole_frame

#: The gait the defaults are scaled from (the project's default humanoid's): leg length [m], step
#: length [m], step time [s], step width beyond the standing width [m].
REFERENCE_LEG_LENGTH = 0.705
REFERENCE_STEP_LENGTH = 0.3
REFERENCE_STEP_TIME = 0.8
REFERENCE_STEP_SPREAD = 0.07
#: Reach measurement: least landing-knee bend at touchdown, least knee bend at rest [rad].
FORE_KNEE_BEND = 0.4
REST_KNEE_BEND = 0.0
#: Reach search: first step, resolution [m].
REACH_STEP = 0.05
REACH_RESOLUTION = 0.001
#: A solved stance meets its sole and COG targets to this [m].
STANCE_TOLERANCE = 1e-6
#: Knee bend of the initial guess of a stance [rad].
GUESS_KNEE = 0.6
_REACH_CACHE_VERSION = 3


@dataclass(frozen=True)
class RobotFacts:
    """A robot's numbers read from its model (SI units).

    Attributes
    ----------
    mass : float
        Total mass [kg].
    leg_length : float
        Height of the hip-pitch axis above the sole plane at the zero configuration (both soles
        flat on the floor) [m].
    hip_half_width : float
        The description's, else the sole frames' lateral distance from the centre line at the zero
        configuration [m].
    straight_com_height : float
        COG height at the zero configuration [m].
    ankle_height : float
        Height of the ankle-roll axis above the sole plane [m].
    limits : dict
        Joint name -> :class:`~drake_estop.robots.plant.JointLimits`.
    """

    mass: float
    leg_length: float
    hip_half_width: float
    straight_com_height: float
    ankle_height: float
    limits: dict


@dataclass(frozen=True)
class GaitDefaults:
    """Step length [m], step width (between the ankles) [m], step time [s]."""

    step_length: float
    step_width: float
    step_time: float


@dataclass(frozen=True)
class Reach:
    """Leg reach from the COG to the landing ankle at touchdown (``fore``) and to the rear ankle at
    rest (``rear``), and the widest step, ankle to ankle (``width``) [m]."""

    fore: float
    rear: float
    width: float


# -- facts --------------------------------------------------------------------------------------------


@functools.cache
def _plant(description: RobotDescription):
    return robot_plant(description)


def _zero_stance(plant, instance, description):
    """A context at the zero configuration (upper body at its nominal posture), base upright, the soles'
    midpoint at the origin."""
    context = plant.CreateDefaultContext()
    q = plant.GetPositions(context)
    _set_upper_body(plant, instance, description, q)
    plant.SetPositions(context, q)
    mid = np.mean([sole_frame(plant, description, s, instance=instance).CalcPoseInWorld(context).translation()
                   for s in SIDES], axis=0)
    base = plant.GetBodyByName(description.floating_base, instance)
    plant.SetFreeBodyPose(context, base, RigidTransform(base.EvalPoseInWorld(context).translation() - mid))
    return context


def _set_upper_body(plant, instance, description, q):
    for entry in description.nominal_posture:
        q[plant.GetJointByName(entry.joint, instance).position_start()] = entry.angle


@functools.cache
def robot_facts(description: RobotDescription) -> RobotFacts:
    """The robot's mass, leg length, standing width, straight-leg COG height, ankle height and joint
    limits (see :class:`RobotFacts`)."""
    plant, instance = _plant(description)
    context = _zero_stance(plant, instance, description)
    soles = [sole_frame(plant, description, s, instance=instance).CalcPoseInWorld(context).translation() for s in SIDES]

    def height(joint_name):
        return plant.GetJointByName(joint_name, instance).frame_on_child().CalcPoseInWorld(context).translation()[2]

    leg = np.mean([height(description.leg(s).hip_pitch) for s in SIDES])
    ankle = np.mean([height(description.leg(s).ankle_roll) for s in SIDES])
    half_width = description.hip_half_width or float(np.mean([abs(p[1]) for p in soles]))
    return RobotFacts(mass=float(plant.CalcTotalMass(context)), leg_length=float(leg),
                      hip_half_width=float(half_width),
                      straight_com_height=float(plant.CalcCenterOfMassPositionInWorld(context)[2]),
                      ankle_height=float(ankle), limits=joint_limits(plant, instance, description))


def gait_defaults(description: RobotDescription) -> GaitDefaults:
    """Step length, width and time: the description's, else scaled from the leg length (module
    docstring); lengths rounded to 1 mm, the time to 10 ms."""
    if None not in (description.step_length, description.step_width, description.step_time):
        return GaitDefaults(description.step_length, description.step_width, description.step_time)
    facts = robot_facts(description)
    scale = facts.leg_length / REFERENCE_LEG_LENGTH
    return GaitDefaults(
        step_length=description.step_length or round(REFERENCE_STEP_LENGTH * scale, 3),
        step_width=description.step_width or round(2 * facts.hip_half_width + REFERENCE_STEP_SPREAD * scale, 3),
        step_time=description.step_time or round(REFERENCE_STEP_TIME * math.sqrt(scale), 2))


# -- stances by inverse kinematics --------------------------------------------------------------------


class _Stance:
    """Double-support stances of one robot by Drake's ``InverseKinematics`` (module docstring)."""

    def __init__(self, plant, instance, description):
        self.plant, self.instance, self.description = plant, instance, description
        self.world = plant.world_frame()
        self.soles = {s: sole_frame(plant, description, s, instance=instance) for s in SIDES}
        base = plant.GetBodyByName(description.floating_base, instance)
        self.quaternion = base.floating_positions_start()
        self.knees = {s: plant.GetJointByName(description.leg(s).knee, instance).position_start() for s in SIDES}
        # other models in the plant keep their positions; their mass shifts the plant's COG target
        count = plant.num_positions()
        own = plant.GetPositionsFromArray(instance, np.arange(count, dtype=float)).astype(int)
        self.others = np.setdiff1d(np.arange(count), own)
        # the stance solves for the base and the legs; every other joint of the robot, named in the description
        # or not, stays where the guess puts it (as in the whole-body IK, which moves the base and legs only)
        legs = [plant.GetJointByName(j, instance).position_start() for j in description.leg_joints]
        self.fixed = np.setdiff1d(own, np.concatenate([np.arange(self.quaternion, self.quaternion + 7), legs]))
        context = plant.CreateDefaultContext()
        self.mass, self.robot_mass = plant.CalcTotalMass(context), plant.CalcTotalMass(context, [instance])

    def guess(self, com_height: float) -> np.ndarray:
        """Knees bent by :data:`GUESS_KNEE` (hip and ankle pitch by half of it the other way), base upright at
        about the right height."""
        plant = self.plant
        context = _zero_stance(plant, self.instance, self.description)
        q = plant.GetPositions(context)
        for side in SIDES:
            leg = self.description.leg(side)
            for name, angle in ((leg.knee, GUESS_KNEE), (leg.hip_pitch, -GUESS_KNEE / 2),
                                (leg.ankle_pitch, -GUESS_KNEE / 2)):
                q[plant.GetJointByName(name, self.instance).position_start()] = angle
        plant.SetPositions(context, q)
        lift = np.mean([self.soles[s].CalcPoseInWorld(context).translation()[2] for s in SIDES])
        q[self.quaternion + 6] -= lift
        return q

    def _flat_sole(self, ik, side, x, y):
        """The sole frame's origin at (x, y, 0), its x axis along world x, its y axis level: six independent
        equations."""
        inf = math.inf
        frame = self.soles[side]
        ik.AddPositionConstraint(frame, [0, 0, 0], self.world, [x, y, 0], [x, y, 0])
        ik.AddPositionConstraint(frame, [0.1, 0, 0], self.world, [-inf, y, 0], [inf, y, 0])
        ik.AddPositionConstraint(frame, [0, 0.1, 0], self.world, [-inf, -inf, 0], [inf, inf, 0])

    def solve(self, *, feet: dict, com, knee_bend: dict, guess: np.ndarray):
        """q of the stance with the soles flat at ``feet`` (side -> (x, y)) and the COG at ``com``, each
        knee bent at least ``knee_bend[side]`` [rad]; None if the IK finds none."""
        plant = self.plant
        ik = InverseKinematics(plant, with_joint_limits=True)
        q, prog = ik.q(), ik.get_mutable_prog()
        for side, (x, y) in feet.items():
            self._flat_sole(ik, side, x, y)
        prog.AddBoundingBoxConstraint([1, 0, 0, 0], [1, 0, 0, 0], q[self.quaternion:self.quaternion + 4])
        com_var = prog.NewContinuousVariables(3, "com")
        prog.AddConstraint(ComPositionConstraint(plant, None, self.world, ik.context()),
                           np.concatenate([q, com_var]))
        target = self._plant_com(com, guess)
        prog.AddBoundingBoxConstraint(target, target, com_var)
        for index in np.concatenate([self.fixed, self.others]).astype(int):
            prog.AddBoundingBoxConstraint(guess[index], guess[index], q[index])
        for side, bend in knee_bend.items():
            upper = plant.GetPositionUpperLimits()[self.knees[side]]
            prog.AddBoundingBoxConstraint(bend, upper, q[self.knees[side]])
        prog.AddQuadraticErrorCost(1e-3 * np.eye(len(guess)), guess, q)
        prog.SetInitialGuess(q, guess)
        prog.SetInitialGuess(com_var, target)
        result = Solve(prog)
        solution = result.GetSolution(q)
        return solution if result.is_success() and self._met(solution, feet, com) else None

    def _plant_com(self, com, q) -> np.ndarray:
        """The COG of every model in the plant when the robot's is at ``com`` and the others are as in ``q``."""
        if self.mass == self.robot_mass:
            return np.asarray(com, float)
        context = self.plant.CreateDefaultContext()
        self.plant.SetPositions(context, q)
        everything = self.mass * self.plant.CalcCenterOfMassPositionInWorld(context)
        robot = self.robot_mass * self.plant.CalcCenterOfMassPositionInWorld(context, [self.instance])
        return (everything - robot + self.robot_mass * np.asarray(com, float)) / self.mass

    def _met(self, q, feet, com) -> bool:
        """Whether ``q`` puts the soles flat at ``feet`` and the robot's COG at ``com`` within the tolerance."""
        context = self.plant.CreateDefaultContext()
        self.plant.SetPositions(context, q)
        error = np.linalg.norm(self.plant.CalcCenterOfMassPositionInWorld(context, [self.instance]) - com)
        for side, (x, y) in feet.items():
            pose = self.soles[side].CalcPoseInWorld(context)
            error = max(error, np.linalg.norm(pose.translation() - [x, y, 0]),
                        np.linalg.norm(pose.rotation().matrix() - np.eye(3)))
        return error < STANCE_TOLERANCE * 10


@functools.cache
def _stance(description: RobotDescription) -> _Stance:
    return _Stance(*_plant(description), description)


def _standing_q(stance: _Stance, description, com_height: float, half_width: float):
    feet = {"left": (0.0, half_width), "right": (0.0, -half_width)}
    return stance.solve(feet=feet, com=[0.0, 0.0, com_height], knee_bend={}, guess=stance.guess(com_height))


def nominal_standing_configuration(plant, description: RobotDescription, *, com_height: float | None = None,
                                   instance=None) -> np.ndarray:
    """The double-support standing posture of the described robot in ``plant``.

    Both soles flat on the floor at y = +-``hip_half_width`` (x = 0), the floating base upright, the
    upper body at its nominal posture, the knees bent, the COG ``com_height`` above the floor over
    the feet's midpoint.

    Parameters
    ----------
    plant : pydrake.multibody.plant.MultibodyPlant
        A finalized plant holding the robot (and possibly other models, held at their default
        positions; the robot's own COG is placed).
    description : RobotDescription
        The robot.
    com_height : float, optional
        COG height [m] (default: ``description.walking_com_height``).
    instance : pydrake.multibody.tree.ModelInstanceIndex, optional
        The robot's model instance (default: the one that has the floating base body).

    Returns
    -------
    numpy.ndarray
        The plant's positions q.

    Raises
    ------
    ValueError
        Naming ``walking_com_height`` (or ``com_height``) when the IK finds no such posture.
    """
    height = description.walking_com_height if com_height is None else com_height
    if instance is None:
        instance = plant.GetBodyByName(description.floating_base).model_instance()
    stance = _Stance(plant, instance, description)
    q = _standing_q(stance, description, height, robot_facts(description).hip_half_width)
    if q is None:
        field = "walking_com_height" if com_height is None else "com_height"
        raise ValueError(f"{field}: no standing posture of {description.name!r} puts the COG at {height} m")
    return q


# -- reach ----------------------------------------------------------------------------------------------


def _grow(feasible, start_q):
    """The largest r (to :data:`REACH_RESOLUTION`) for which ``feasible(r, guess)`` returns a q, grown from 0."""
    reach, q, step = 0.0, start_q, REACH_STEP
    while step >= REACH_RESOLUTION:
        found = feasible(reach + step, q)
        if found is None:
            step /= 2
        else:
            reach, q = reach + step, found
    return reach


def _measure(description: RobotDescription) -> Reach:
    stance = _stance(description)
    height = description.walking_com_height
    half = gait_defaults(description).step_width / 2
    com = [0.0, 0.0, height]
    start = _standing_q(stance, description, height, half)
    if start is None:
        raise ValueError(f"walking_com_height: no stance of {description.name!r} puts the COG at {height} m")

    def fore(r, guess):
        return stance.solve(feet={"left": (r, half), "right": (0.0, -half)}, com=com,
                            knee_bend={"left": FORE_KNEE_BEND}, guess=guess)

    def rear(r, guess):
        return stance.solve(feet={"left": (r, half), "right": (-r, -half)}, com=com,
                            knee_bend={s: REST_KNEE_BEND for s in SIDES}, guess=guess)

    def wide(r, guess):
        return stance.solve(feet={"left": (0.0, half + r), "right": (0.0, -half)}, com=com,
                            knee_bend={"left": FORE_KNEE_BEND}, guess=guess)

    start_fore = fore(0.0, start)
    if start_fore is None:
        raise ValueError(f"walking_com_height: {height} m leaves no knee bend of {FORE_KNEE_BEND} rad "
                         f"in {description.name!r}'s standing posture")
    return Reach(fore=_grow(fore, start_fore), rear=_grow(rear, start), width=2 * half + _grow(wide, start_fore))


def _reach_cache_file(description: RobotDescription) -> os.PathLike:
    stat = model_file(description).stat()
    key = repr((_REACH_CACHE_VERSION, description, stat.st_size, stat.st_mtime_ns, GRAVITY))
    return cache_dir() / "reach" / f"{description.name}-{hashlib.sha256(key.encode()).hexdigest()[:16]}.json"


@functools.cache
def measure_reach(description: RobotDescription) -> Reach:
    """The robot's leg reach measured by inverse kinematics (module docstring), cached in memory and on
    disk.

    Returns
    -------
    Reach
        Fore and rear reach and the widest step [m].
    """
    path = _reach_cache_file(description)
    if path.is_file():
        return Reach(**json.loads(path.read_text()))
    reach = _measure(description)
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile("w", dir=path.parent, suffix=".tmp", delete=False) as handle:
        json.dump(asdict(reach), handle)
    os.replace(handle.name, path)
    return reach


def reach_limits(description: RobotDescription) -> Reach:
    """The planner's reach limits: the description's ``max_fore_reach`` / ``max_rear_reach`` /
    ``max_step_width``, else :func:`measure_reach`'s [m]."""
    fore, rear, width = description.max_fore_reach, description.max_rear_reach, description.max_step_width
    if None in (fore, rear, width):
        measured = measure_reach(description)
        fore, rear, width = fore or measured.fore, rear or measured.rear, width or measured.width
    return Reach(fore=fore, rear=rear, width=width)


def max_fore_reach(description: RobotDescription) -> float:
    """Fore reach of :func:`reach_limits` [m]."""
    return reach_limits(description).fore


def max_rear_reach(description: RobotDescription) -> float:
    """Rear reach of :func:`reach_limits` [m]."""
    return reach_limits(description).rear
