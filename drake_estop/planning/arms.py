"""The arm swing of the nominal walk: which joints swing, about which angles, how much.

The walking pattern swings the arms against the legs (:meth:`drake_estop.planning.gait.NominalPattern.upper_body`)
and the stop halts them (eq. 32-33, :meth:`drake_estop.planning.plan.StopPlan.upper_body`); both act on
the joints of an :class:`ArmSwing`, each at ``neutral + gain * swing`` for the shoulder's swing angle
``swing`` [rad]. The default is the project's HRP-2-class humanoid's (``models/humanoid.urdf``): both
shoulder pitches, the left one forward with a positive swing, and the elbows at half the swing around
-0.3 rad. Other robots' arm swings come from their descriptions
(:attr:`drake_estop.robots.description.RobotDescription.arm_swing`).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

#: The default humanoid's swinging joints (names as in models/humanoid.urdf), their neutral angles [rad]
#: and their share of the shoulder's swing (dimensionless).
DEFAULT_ARM_JOINTS = ("l_shoulder_pitch", "r_shoulder_pitch", "l_elbow", "r_elbow")
DEFAULT_ARM_NEUTRAL = (0.0, 0.0, -0.3, -0.3)
DEFAULT_ARM_GAINS = (1.0, -1.0, 0.5, -0.5)


@dataclass(frozen=True)
class ArmSwing:
    """Joints the walk swings and the stop halts (module docstring).

    Attributes
    ----------
    joints : tuple of str
        The model's joint names (possibly none: no arm swing).
    neutral : tuple of float
        Each joint's angle with the arms at rest [rad].
    gains : tuple of float
        Each joint's angle change per radian of the shoulder's swing (dimensionless; the sign
        says which way the joint turns).

    Raises
    ------
    ValueError
        Naming the field: lengths that differ, an empty or repeated name, a non-finite number.
    """

    joints: tuple = DEFAULT_ARM_JOINTS
    neutral: tuple = DEFAULT_ARM_NEUTRAL
    gains: tuple = DEFAULT_ARM_GAINS

    def __post_init__(self):
        for name in ("joints", "neutral", "gains"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        if not len(self.joints) == len(self.neutral) == len(self.gains):
            raise ValueError(f"arms: joints, neutral and gains must have one entry per joint, got "
                             f"{len(self.joints)}, {len(self.neutral)} and {len(self.gains)}")
        for i, joint in enumerate(self.joints):
            if not isinstance(joint, str) or not joint.strip():
                raise ValueError(f"arms.joints[{i}] must be a joint name, got {joint!r}")
            if joint in self.joints[:i]:
                raise ValueError(f"arms.joints[{i}]: {joint!r} is listed twice")
        for name in ("neutral", "gains"):
            for i, value in enumerate(getattr(self, name)):
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                    raise ValueError(f"arms.{name}[{i}] must be a finite number, got {value!r}")

    @functools.cached_property
    def neutral_array(self) -> np.ndarray:
        """``neutral`` as an array [rad]."""
        return np.array(self.neutral, dtype=float)

    @functools.cached_property
    def gain_array(self) -> np.ndarray:
        """``gains`` as an array (dimensionless)."""
        return np.array(self.gains, dtype=float)
