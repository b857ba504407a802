"""Humanoid model helpers: file location, joint names, sole geometry, loading.

The model is ``models/humanoid.urdf``, an HRP-2-class humanoid written for this
project (see ``models/README.md`` for where every number comes from).  The
repository keeps ``models/`` at its top level; a wheel ships the same folder as
``drake_estop/models/`` (package data), found through :mod:`importlib.resources`.
It is always loaded by file path, never through ``package://`` URLs, and with
an empty PackageMap, so no network access is needed and the project runs with
``DRAKE_ALLOW_NETWORK=meshcat`` (or ``none``) set.
"""

import os
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np
from pydrake.multibody.parsing import Parser

from drake_estop.planning.gait import Sole
from drake_estop.planning.lipm import GRAVITY

MODEL_FILE = "humanoid.urdf"


def _models_dir():
    """The folder holding ``humanoid.urdf``.

    An installed wheel has it as package data, ``drake_estop/models/``; a
    repository checkout (also an editable install) has it at the top level,
    next to the package.
    """
    packaged = resources.files("drake_estop") / "models"
    if packaged.is_dir() and (packaged / MODEL_FILE).is_file():
        # the wheel is installed unpacked, so this is a real folder
        return Path(str(packaged)).resolve()
    return Path(__file__).resolve().parents[1] / "models"


MODEL_PATH = _models_dir() / MODEL_FILE

FLOATING_BASE = "pelvis"
TORSO = "torso"
LEFT_SOLE = "l_sole"
RIGHT_SOLE = "r_sole"

_LEG = ("hip_yaw", "hip_roll", "hip_pitch", "knee", "ankle_pitch", "ankle_roll")
_ARM = ("shoulder_pitch", "shoulder_roll", "shoulder_yaw", "elbow",
        "wrist_yaw", "wrist_pitch", "hand")

LEFT_LEG_JOINTS = tuple(f"l_{name}" for name in _LEG)
RIGHT_LEG_JOINTS = tuple(f"r_{name}" for name in _LEG)
LEG_JOINTS = LEFT_LEG_JOINTS + RIGHT_LEG_JOINTS
CHEST_JOINTS = ("chest_yaw", "chest_pitch")
HEAD_JOINTS = ("head_yaw", "head_pitch")
LEFT_ARM_JOINTS = tuple(f"l_{name}" for name in _ARM)
RIGHT_ARM_JOINTS = tuple(f"r_{name}" for name in _ARM)
UPPER_BODY_JOINTS = (CHEST_JOINTS + HEAD_JOINTS + LEFT_ARM_JOINTS
                     + RIGHT_ARM_JOINTS)
ALL_JOINTS = LEG_JOINTS + UPPER_BODY_JOINTS

#: Nominal walking COG height of Morisawa et al. 2005 [m].
WALKING_COM_HEIGHT = 0.814
#: Lateral distance of each hip-yaw axis from the centre line [m].
HIP_HALF_WIDTH = 0.06
#: Pelvis-origin height above the floor at the zero configuration [m].
PELVIS_HEIGHT_AT_ZERO = 0.705


@dataclass(frozen=True)
class SoleGeometry(Sole):
    """The model's sole: :class:`drake_estop.planning.gait.Sole` (toe, heel, inner, outer
    around the ankle; the planner's numbers) plus the ankle height and the sole
    thickness. ``inner`` is towards the robot's centre line, ``outer`` away
    from it. All values in metres.
    """

    ankle_height: float = 0.105
    thickness: float = 0.01

    @property
    def length(self):
        """Sole length along x [m]."""
        return self.toe + self.heel

    @property
    def width(self):
        """Sole width along y [m]."""
        return self.inner + self.outer

    def local_corners(self, side):
        """Sole corners (4x2, x/y in the sole frame) for ``side`` 'l' or 'r'."""
        return self.corners((0.0, 0.0), "left" if side == "l" else "right")


SOLE = SoleGeometry()


def _check_model_file(path):
    """Raise a clear error naming ``path`` if it is missing or not XML."""
    if not path.is_file():
        raise FileNotFoundError(f"humanoid model file not found: {path}")
    try:
        root = ElementTree.parse(path).getroot()
    except ElementTree.ParseError as err:
        raise ValueError(f"malformed humanoid model file {path}: {err}") from err
    if root.tag != "robot" and path.suffix == ".urdf":
        raise ValueError(
            f"malformed humanoid model file {path}: root element is "
            f"<{root.tag}>, expected <robot>")


def offline_parser(plant):
    """A :class:`Parser` for ``plant`` whose PackageMap is empty.

    Drake's default PackageMap registers the remote ``drake_models`` package,
    which throws when ``DRAKE_ALLOW_NETWORK`` denies ``package_map`` (e.g.
    ``DRAKE_ALLOW_NETWORK=meshcat``), even for a model that references no
    package.  pydrake 1.51 offers no Parser constructor taking a PackageMap, so
    the variable is lifted only while the Parser is constructed (registering a
    remote package downloads nothing) and every package is then removed from
    the parser's map: nothing can be fetched while parsing.  The humanoid
    needs no ``package://`` URL.
    """
    allow = os.environ.pop("DRAKE_ALLOW_NETWORK", None)
    try:
        parser = Parser(plant)
    finally:
        if allow is not None:
            os.environ["DRAKE_ALLOW_NETWORK"] = allow
    package_map = parser.package_map()
    for name in package_map.GetPackageNames():
        package_map.Remove(name)
    return parser


def load_humanoid(plant, model_path=MODEL_PATH):
    """Add the humanoid to ``plant`` (not finalized) and return its instance.

    Parses with :func:`offline_parser` (no network, whatever
    ``DRAKE_ALLOW_NETWORK`` says) and sets the plant's gravity to
    :data:`drake_estop.planning.lipm.GRAVITY` [m/s^2], the one value the planner and
    the controllers use (Drake's default is 9.81).

    Parameters
    ----------
    plant : pydrake.multibody.plant.MultibodyPlant
        A plant that is not finalized yet.
    model_path : str or pathlib.Path, optional
        The URDF (default: the packaged ``humanoid.urdf``; lengths in m,
        masses in kg).

    Returns
    -------
    pydrake.multibody.tree.ModelInstanceIndex
        The humanoid's model instance.

    Raises
    ------
    FileNotFoundError, ValueError
        Naming the file when it is missing or cannot be parsed, instead of a
        raw parser traceback.
    """
    path = Path(model_path)
    _check_model_file(path)
    try:
        instances = offline_parser(plant).AddModels(str(path))
    except RuntimeError as err:
        raise ValueError(
            f"could not parse humanoid model file {path}: {err}") from err
    if len(instances) != 1:
        raise ValueError(f"expected one model in {path}, got {len(instances)}")
    plant.mutable_gravity_field().set_gravity_vector([0.0, 0.0, -GRAVITY])
    return instances[0]


def joint_position_indices(plant, names):
    """Indices into q of the single-DOF joints ``names``."""
    return np.array([plant.GetJointByName(n).position_start() for n in names])


def joint_velocity_indices(plant, names):
    """Indices into v of the single-DOF joints ``names``."""
    return np.array([plant.GetJointByName(n).velocity_start() for n in names])


def _set_base(plant, q, position):
    """Write an upright pelvis pose at ``position`` into ``q``."""
    start = plant.GetBodyByName(FLOATING_BASE).floating_positions_start()
    q[start:start + 4] = [1.0, 0.0, 0.0, 0.0]
    q[start + 4:start + 7] = position


def _bent_leg_q(plant, knee, lean):
    """q with both knees at ``knee`` and the shanks leaning forward by ``lean``.

    Pelvis upright, soles flat: hip_pitch + knee + ankle_pitch = 0.
    """
    q = plant.GetDefaultPositions().copy()
    q[:] = 0.0
    for side in ("l", "r"):
        hip, kn, ank = joint_position_indices(
            plant, [f"{side}_hip_pitch", f"{side}_knee", f"{side}_ankle_pitch"])
        q[ank] = -lean
        q[kn] = knee
        q[hip] = -knee + lean
    _set_base(plant, q, [0.0, 0.0, PELVIS_HEIGHT_AT_ZERO])
    return q


def _place_on_floor(plant, context, q):
    """Shift the base so the soles are on z=0 and centred on x=y=0."""
    plant.SetPositions(context, q)
    mid = 0.5 * sum(plant.GetFrameByName(name).CalcPoseInWorld(context)
                    .translation() for name in (LEFT_SOLE, RIGHT_SOLE))
    start = plant.GetBodyByName(FLOATING_BASE).floating_positions_start()
    q[start + 4:start + 7] -= mid
    plant.SetPositions(context, q)
    return q


def _com_residual(plant, context, x, com_height):
    """COG (x, z) error of the bent-leg posture parameterised by x."""
    q = _place_on_floor(plant, context, _bent_leg_q(plant, x[0], x[1]))
    com = plant.CalcCenterOfMassPositionInWorld(context)
    return np.array([com[2] - com_height, com[0]]), q


def nominal_standing_configuration(plant, com_height=WALKING_COM_HEIGHT,
                                   *, iterations=20, tolerance=1e-9):
    """Double-support posture with the COG ``com_height`` above the floor.

    Soles flat on z=0 at y = +-0.06 m under the hips, pelvis upright, arms
    and head at zero, and the COG directly above the midpoint of the ankles.
    Solved by Newton iterations (finite differences) on knee bend and shank
    lean.  Raises ValueError if ``com_height`` is not reachable.
    """
    context = plant.CreateDefaultContext()
    knee_max = plant.GetJointByName("l_knee").position_upper_limits()[0]
    x = np.array([0.8, 0.0])
    for _ in range(iterations):
        r, q = _com_residual(plant, context, x, com_height)
        if np.max(np.abs(r)) < tolerance:
            return q
        jac = np.empty((2, 2))
        for k in range(2):
            dx = np.zeros(2)
            dx[k] = 1e-6
            jac[:, k] = (_com_residual(plant, context, x + dx, com_height)[0]
                         - r) / 1e-6
        x = x - np.linalg.solve(jac, r)
        x[0] = np.clip(x[0], 1e-3, knee_max)
    r, q = _com_residual(plant, context, x, com_height)
    if np.max(np.abs(r)) > 1e-6:
        raise ValueError(f"COG height {com_height} m is not reachable by "
                         f"bending the knees (residual {r})")
    return q
