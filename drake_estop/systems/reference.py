"""The reference vector of the stop's reference sources, and the nominal walk's source.

* :func:`reference_vector` samples the nominal walk or a stop plan into the
  one vector every reference source caches; :func:`blended_reference` blends
  the COG and sole commands from a previous command into a new plan.
* :class:`ReferenceSystem` is the base of the reference sources: the cached
  vector and one output port per entry.
* :class:`WalkingPatternSource` plays the nominal walking pattern
  (:class:`drake_estop.planning.gait.NominalPattern`) at the context time.

Reference layout shared by the reference sources (all world frame, SI):
``com`` (3) x, y, z of the COG; ``com_vel`` (3); ``zmp`` (2);
``left_foot`` / ``right_foot`` (7) sole-frame pose ``[x, y, z, qw, qx, qy,
qz]`` -- the sole frame lies directly below the ankle, so its xy is the ankle
xy and its z is the ankle *lift* (the sole is on the floor at z = 0), which is
what :class:`drake_estop.systems.ik.WholeBodyIK` expects; ``upper_body`` (18) joint
targets in ``UPPER_BODY_JOINTS`` order (the IK's order: the pattern's
``ARM_JOINTS`` written in, every other upper-body joint at 0); ``arm_joints``
(4) the same arm angles in ``ARM_JOINTS`` order; ``phase`` (1) the index of
the phase in ``PHASES``.
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem, ValueProducer

from drake_estop.model import UPPER_BODY_JOINTS
from drake_estop.planning.gait import ARM_JOINTS, SIDES, NominalPattern
from drake_estop.planning.plan import PHASES
from drake_estop.timing import timed

#: Sizes of the reference outputs, in the order they sit in the cached vector.
REFERENCE_LAYOUT = (("com", 3), ("com_vel", 3), ("zmp", 2), ("left_foot", 7),
                    ("right_foot", 7), ("upper_body", len(UPPER_BODY_JOINTS)),
                    ("arm_joints", len(ARM_JOINTS)), ("phase", 1))
#: name -> slice of the reference vector, in REFERENCE_LAYOUT order
REFERENCE_SLICES = {}
_start = 0
for _name, _size in REFERENCE_LAYOUT:
    REFERENCE_SLICES[_name] = slice(_start, _start + _size)
    _start += _size
REFERENCE_SIZE = _start
_ARM_IN_UPPER = np.array([UPPER_BODY_JOINTS.index(name) for name in ARM_JOINTS])
LEVEL = np.array([1.0, 0.0, 0.0, 0.0])  # a level sole heading along x
_WALKING = float(PHASES.index("walking"))


def upper_body_vector(arm_q):
    """18-vector in UPPER_BODY_JOINTS order with ``arm_q`` (ARM_JOINTS order)."""
    out = np.zeros(len(UPPER_BODY_JOINTS))
    out[_ARM_IN_UPPER] = arm_q
    return out


def sole_pose(ankle, yaw: float = 0.0):
    """Sole pose 7-vector ``[x, y, z, qw, qx, qy, qz]`` from an ankle ``(x, y, lift)`` and the foot's
    heading ``yaw`` [rad]: the sole is level at z = lift, turned about the vertical."""
    if yaw == 0.0:
        return np.concatenate([np.asarray(ankle, float)[:3], LEVEL])
    return np.concatenate([np.asarray(ankle, float)[:3], [math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw)]])


def reference_vector(t, *, pattern, plan=None):
    """All reference outputs at time ``t`` as one REFERENCE_SIZE vector.

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
        sole_pose(feet["right"], yaw["right"]), upper_body_vector(arm_q), arm_q, [phase]])


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
    loaded foot's target kicked the robot off the floor).
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

class ReferenceSystem(LeafSystem):
    """Base of the reference sources: a cached reference vector and one output port per entry."""

    def _declare_reference_outputs(self, prerequisites, timer=None):
        """Cache the reference per context and declare its output ports (``timer``: the cache's
        computation timed as ``"<class>.reference"``)."""
        self._reference = self.DeclareCacheEntry(
            "reference",
            ValueProducer(allocate=lambda: AbstractValue.Make(np.zeros(REFERENCE_SIZE)),
                          calc=timed(self._calc_reference_value, timer, f"{type(self).__name__}.reference")),
            prerequisites)
        for name, size in REFERENCE_LAYOUT:  # one output port per entry, looked up by name
            self.DeclareVectorOutputPort(name, size, self._output_calc(REFERENCE_SLICES[name]),
                                         prerequisites_of_calc={self._reference.ticket()})

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
        """The whole cached reference vector (REFERENCE_LAYOUT order)."""
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

    Notes
    -----
    Output ports (world frame, SI units): ``com`` (3) COG position [m];
    ``com_vel`` (3) [m/s]; ``zmp`` (2) [m]; ``left_foot`` / ``right_foot``
    (7) sole pose ``[x, y, z, qw, qx, qy, qz]`` ([m], unit quaternion, z is
    the foot's lift above the floor); ``upper_body`` (18) joint targets in
    ``UPPER_BODY_JOINTS`` order [rad]; ``arm_joints`` (4) the arm angles in
    ``ARM_JOINTS`` order [rad]; ``phase`` (1) always the index of "walking"
    in ``PHASES``.
    """

    def __init__(self, *, pattern: NominalPattern):
        super().__init__()
        self._pattern = pattern
        self._declare_reference_outputs({self.time_ticket()})

    @property
    def pattern(self):
        return self._pattern

    def _calc_reference(self, context):
        return reference_vector(context.get_time(), pattern=self._pattern)

