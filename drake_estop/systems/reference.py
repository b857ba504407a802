"""The reference vector of the stop's reference sources, and the nominal walk's source.

* :func:`reference_vector` samples the nominal walk or a stop plan into the
  one vector every reference source caches; :func:`blended_reference` blends
  the COG and sole commands from a previous command into a new plan.
* :class:`ReferenceSystem` is the base of the reference sources: the cached
  vector and one output port per entry.
* :class:`WalkingPatternSource` plays the nominal walking pattern
  (:class:`drake_estop.planning.gait.NominalPattern`) at the context time.

Reference layout shared by the reference sources (all world frame, SI;
:class:`ReferenceLayout`): ``com`` (3) x, y, z of the COG; ``com_vel`` (3);
``zmp`` (2); ``left_foot`` / ``right_foot`` (7) sole-frame pose ``[x, y, z, qw,
qx, qy, qz]`` -- the sole frame lies directly below the ankle, so its xy is the
ankle xy and its z is the ankle *lift* (the sole is on the floor at z = 0),
which is what :class:`drake_estop.systems.ik.WholeBodyIK` expects;
``upper_body`` (one per upper-body joint of the robot, the IK's order) joint
targets: the gait's swinging joints (``GaitParameters.arms``) written in, every
other upper-body joint at its standing angle; ``arm_joints`` (one per swinging
joint) the same arm angles in ``arms.joints`` order; ``phase`` (1) the index of
the phase in ``PHASES``. The default robot's layout (18 upper-body joints, 4
swinging) is :data:`DEFAULT_LAYOUT`; :data:`REFERENCE_LAYOUT`,
:data:`REFERENCE_SLICES` and :data:`REFERENCE_SIZE` are its entries.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem, ValueProducer

from drake_estop.model import UPPER_BODY_JOINTS
from drake_estop.planning.gait import ARM_JOINTS, SIDES, NominalPattern
from drake_estop.planning.plan import PHASES
from drake_estop.timing import timed


@dataclass(frozen=True)
class ReferenceLayout:
    """Where each entry sits in the reference vector of a robot (module docstring).

    Attributes
    ----------
    upper_body : tuple of str
        The robot's upper-body joints, in the IK's order.
    standing : tuple of float
        Their standing angles [rad] (the joints the gait does not swing hold them).
    arms : tuple of str
        The gait's swinging joints (``GaitParameters.arms.joints``), each one of ``upper_body``.

    Raises
    ------
    ValueError
        Naming ``gait.arms.joints[i]`` for a swinging joint that is not an upper-body joint.
    """

    upper_body: tuple = UPPER_BODY_JOINTS
    standing: tuple = (0.0,) * len(UPPER_BODY_JOINTS)
    arms: tuple = ARM_JOINTS

    def __post_init__(self):
        if len(self.standing) != len(self.upper_body):
            raise ValueError(f"standing: {len(self.standing)} angles for {len(self.upper_body)} upper-body joints")
        for i, joint in enumerate(self.arms):
            if joint not in self.upper_body:
                raise ValueError(f"gait.arms.joints[{i}]: {joint!r} is not an upper-body joint of the robot "
                                 f"({', '.join(self.upper_body) or 'none'})")

    @classmethod
    def of(cls, description, arms) -> ReferenceLayout:
        """The layout of a robot description (:class:`drake_estop.robots.RobotDescription`) and the gait's
        :class:`~drake_estop.planning.arms.ArmSwing`."""
        return cls(description.upper_body_joints, description.standing_angles(), arms.joints)

    @functools.cached_property
    def entries(self) -> tuple:
        """``(name, size)`` of every entry, in the order they sit in the vector."""
        return (("com", 3), ("com_vel", 3), ("zmp", 2), ("left_foot", 7), ("right_foot", 7),
                ("upper_body", len(self.upper_body)), ("arm_joints", len(self.arms)), ("phase", 1))

    @functools.cached_property
    def slices(self) -> dict:
        """name -> slice of the vector."""
        out, start = {}, 0
        for name, size in self.entries:
            out[name] = slice(start, start + size)
            start += size
        return out

    @property
    def size(self) -> int:
        """Length of the vector."""
        return self.slices["phase"].stop

    @functools.cached_property
    def _arm_index(self) -> np.ndarray:
        return np.array([self.upper_body.index(name) for name in self.arms], dtype=int)

    def upper_body_vector(self, arm_q) -> np.ndarray:
        """The ``upper_body`` entry: ``arm_q`` (``arms`` order) written into the standing angles [rad]."""
        out = np.array(self.standing, dtype=float)
        out[self._arm_index] = arm_q
        return out

    def split(self, reference) -> dict:
        """name -> entry of a reference vector (or of an (n, size) array of them, by column)."""
        return {name: reference[..., sl] for name, sl in self.slices.items()}


#: The default robot's layout (models/humanoid.urdf's upper body, ARM_JOINTS swinging).
DEFAULT_LAYOUT = ReferenceLayout()
#: Sizes of the default layout's entries, in the order they sit in the cached vector.
REFERENCE_LAYOUT = DEFAULT_LAYOUT.entries
#: name -> slice of the default layout's vector, in REFERENCE_LAYOUT order
REFERENCE_SLICES = DEFAULT_LAYOUT.slices
REFERENCE_SIZE = DEFAULT_LAYOUT.size
LEVEL = np.array([1.0, 0.0, 0.0, 0.0])  # a level sole heading along x
#: A sole target whose z (its lift) is above this [m] is off the floor: a swinging foot.
SWING_HEIGHT = 1e-4
_WALKING = float(PHASES.index("walking"))


def upper_body_vector(arm_q):
    """The default layout's upper-body vector (UPPER_BODY_JOINTS order) with ``arm_q`` (ARM_JOINTS order)."""
    return DEFAULT_LAYOUT.upper_body_vector(arm_q)


def sole_pose(ankle, yaw: float = 0.0):
    """Sole pose 7-vector ``[x, y, z, qw, qx, qy, qz]`` from an ankle ``(x, y, lift)`` and the foot's
    heading ``yaw`` [rad]: the sole is level at z = lift, turned about the vertical."""
    if yaw == 0.0:
        return np.concatenate([np.asarray(ankle, float)[:3], LEVEL])
    return np.concatenate([np.asarray(ankle, float)[:3], [math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw)]])


def reference_vector(t, *, pattern, plan=None, layout=DEFAULT_LAYOUT):
    """All reference outputs at time ``t`` as one vector of ``layout`` (default: the default robot's).

    Before the plan starts (or without a plan) this is the nominal pattern;
    the plan's evaluation functions return the nominal pattern before its
    start, so the switch is continuous.
    """
    source = plan if plan is not None else pattern
    pos, vel, _, zmp = source.com([t])
    if plan is not None:
        z, zd, _ = plan.com_height([t])
        feet = plan.feet(t)
        yaw = plan.feet_yaw(t)[0]
        phase = float(PHASES.index(plan.phase(t)))
    else:
        z, zd = [pattern.params.com_height], [0.0]
        feet = pattern.feet_at(t)[0]
        yaw = pattern.feet_yaw_at(t)[0]
        phase = _WALKING
    arm_q = source.upper_body(t)[0]
    return np.concatenate([
        pos[0], [z[0]], vel[0], [zd[0]], zmp[0], sole_pose(feet["left"], yaw["left"]),
        sole_pose(feet["right"], yaw["right"]), layout.upper_body_vector(arm_q), arm_q, [phase]])


def blended_reference(reference, blend, t):
    """``reference`` with the COG command blended from the previous command into a new plan.

    ``blend`` is ``(start, dp, dv, duration[, dfeet])`` (None: no blend). A
    plan from the measured state starts where the robot is, not where its
    command was; stepping the command there would step the joint targets
    (the stiff servos then strike the floor). The COG command is the plan
    plus a quintic that starts at the old command's offset ``dp`` and rate
    ``dv`` and fades to zero, at rest, over ``duration``. The fifth entry
    ``dfeet`` (2 x 3, left then right; optional) does the same for the sole
    positions, which a plan on measured footholds moves (a 1-2 cm step of a
    loaded foot's target kicked the robot off the floor). The COG and the
    soles sit where :data:`REFERENCE_SLICES` says in every robot's layout.
    """
    if blend is None:
        return reference
    start, dp, dv, duration = blend[:4]
    s = (t - start) / duration
    if not 0.0 <= s < 1.0:
        return reference
    h0 = 1 - 10 * s**3 + 15 * s**4 - 6 * s**5
    h1 = s - 6 * s**3 + 8 * s**4 - 3 * s**5
    d0 = (-30 * s**2 + 60 * s**3 - 30 * s**4) / duration
    d1 = 1 - 18 * s**2 + 32 * s**3 - 15 * s**4
    out = reference.copy()
    out[REFERENCE_SLICES["com"]][:2] += dp * h0 + dv * duration * h1
    out[REFERENCE_SLICES["com_vel"]][:2] += dp * d0 + dv * d1
    if len(blend) > 4:  # sole positions moved onto measured footholds: faded the same way, at rest
        for side, offset in zip(SIDES, blend[4]):
            out[REFERENCE_SLICES[f"{side}_foot"]][:3] += offset * h0
    return out


def pattern_layout(pattern: NominalPattern, layout: ReferenceLayout | None = None) -> ReferenceLayout:
    """``layout`` checked against the pattern's swinging joints; None: the default robot's upper body with
    the pattern's swinging joints.

    Raises
    ------
    ValueError
        Naming ``gait.arms.joints`` when the layout's swinging joints are not the pattern's.
    """
    arms = pattern.params.arms.joints
    if layout is None:
        return ReferenceLayout(arms=arms)
    if layout.arms != arms:
        raise ValueError(f"gait.arms.joints {list(arms)} are not the swinging joints of the robot's reference "
                         f"layout {list(layout.arms)}: build the gait for this robot")
    return layout


class ReferenceSystem(LeafSystem):
    """Base of the reference sources: a cached reference vector and one output port per entry."""

    def _declare_reference_outputs(self, prerequisites, timer=None, layout=DEFAULT_LAYOUT):
        """Cache the reference per context and declare its output ports (``timer``: the cache's
        computation timed as ``"<class>.reference"``; ``layout``: the robot's :class:`ReferenceLayout`)."""
        self._layout = layout
        self._reference = self.DeclareCacheEntry(
            "reference",
            ValueProducer(allocate=lambda: AbstractValue.Make(np.zeros(layout.size)),
                          calc=timed(self._calc_reference_value, timer, f"{type(self).__name__}.reference")),
            prerequisites)
        for name, size in layout.entries:  # one output port per entry, looked up by name
            self.DeclareVectorOutputPort(name, size, self._output_calc(layout.slices[name]),
                                         prerequisites_of_calc={self._reference.ticket()})

    @property
    def layout(self) -> ReferenceLayout:
        """Where each entry sits in the reference vector."""
        return self._layout

    def _calc_reference_value(self, context, value):
        value.set_value(self._calc_reference(context))

    def _output_calc(self, entries):
        def calc(context, output):
            reference = self._reference.Eval(context)
            output.SetFromVector(reference[entries])
        return calc

    def _calc_reference(self, context):
        raise NotImplementedError

    def reference(self, context):
        """The whole cached reference vector (:attr:`layout` order)."""
        return self._reference.Eval(context)


class WalkingPatternSource(ReferenceSystem):
    """The nominal walking pattern sampled at the context time (no state).

    .. pydrake_system::

        name: WalkingPatternSource
        output_ports:
        - com
        - com_vel
        - zmp
        - left_foot
        - right_foot
        - upper_body
        - arm_joints
        - phase

    Parameters
    ----------
    pattern : NominalPattern
        The walk to play; its clock is the context time [s].
    layout : ReferenceLayout, optional
        The robot's reference layout (default: the default robot's upper body, the pattern's swinging
        joints).

    Notes
    -----
    Output ports (world frame, SI units): ``com`` (3) COG position [m];
    ``com_vel`` (3) [m/s]; ``zmp`` (2) [m]; ``left_foot`` / ``right_foot``
    (7) sole pose ``[x, y, z, qw, qx, qy, qz]`` ([m], unit quaternion, z is
    the foot's lift above the floor); ``upper_body`` (18 for the default
    robot) joint targets in ``layout.upper_body`` order [rad];
    ``arm_joints`` (4 for the default robot) the arm angles in
    ``layout.arms`` order [rad]; ``phase`` (1) always the index of "walking"
    in ``PHASES``.
    """

    def __init__(self, *, pattern: NominalPattern, layout: ReferenceLayout | None = None):
        super().__init__()
        self._pattern = pattern
        self._declare_reference_outputs({self.time_ticket()}, layout=pattern_layout(pattern, layout))

    @property
    def pattern(self):
        return self._pattern

    def _calc_reference(self, context):
        return reference_vector(context.get_time(), pattern=self._pattern, layout=self._layout)


def connect_reference(builder, source, ik, *, feet=None, upper_body=None):
    """Connect a reference source's com / feet / upper_body to WholeBodyIK; the feet from ``feet``
    (a system with ``left_foot`` / ``right_foot`` outputs, e.g. a swing-foot compensation) and the
    upper body from ``upper_body`` (a system with an ``upper_body`` output, e.g. the hip strategy) if given."""
    for name in ("com", "left_foot", "right_foot", "upper_body"):
        origin = feet if feet is not None and name.endswith("_foot") else source
        if name == "upper_body" and upper_body is not None:
            origin = upper_body
        builder.Connect(origin.GetOutputPort(name), ik.GetInputPort(name))
