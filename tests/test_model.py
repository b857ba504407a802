"""Tests of models/humanoid.urdf and drake_estop.model."""

import itertools

import numpy as np
import pytest
from pydrake.geometry import Box, Role
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph, MultibodyPlant
from pydrake.multibody.tree import BodyIndex, RevoluteJoint
from pydrake.systems.framework import DiagramBuilder

from drake_estop.model import (
    ALL_JOINTS,
    LEFT_LEG_JOINTS,
    LEG_JOINTS,
    MODEL_PATH,
    RIGHT_LEG_JOINTS,
    SOLE,
    UPPER_BODY_JOINTS,
    WALKING_COM_HEIGHT,
    joint_position_indices,
    load_humanoid,
    nominal_standing_configuration,
)

EXPECTED_LEG = ["hip_yaw", "hip_roll", "hip_pitch", "knee", "ankle_pitch",
                "ankle_roll"]
EXPECTED_ARM = ["shoulder_pitch", "shoulder_roll", "shoulder_yaw", "elbow",
                "wrist_yaw", "wrist_pitch", "hand"]


@pytest.fixture(scope="module")
def robot():
    """(diagram, plant, scene_graph) with the humanoid, finalized."""
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 0.0)
    load_humanoid(plant, MODEL_PATH)
    plant.Finalize()
    return builder.Build(), plant, scene_graph


@pytest.fixture(scope="module")
def plant(robot):
    return robot[1]


def _standing_context(plant, q=None):
    """Plant context at the zero posture with the soles on the floor."""
    context = plant.CreateDefaultContext()
    if q is None:
        q = plant.GetDefaultPositions().copy()
        q[:7] = [1, 0, 0, 0, 0, 0, 0]
        plant.SetPositions(context, q)
        sole_z = plant.GetFrameByName("l_sole").CalcPoseInWorld(context)
        q[6] -= sole_z.translation()[2]
    plant.SetPositions(context, q)
    return context


def test_model_path_is_absolute_file():
    assert MODEL_PATH.is_absolute()
    assert MODEL_PATH.is_file()
    assert MODEL_PATH.parent.name == "models"


def test_joint_name_tuples():
    expected = ([f"{s}_{n}" for s in "lr" for n in EXPECTED_LEG]
                + ["chest_yaw", "chest_pitch", "head_yaw", "head_pitch"]
                + [f"{s}_{n}" for s in "lr" for n in EXPECTED_ARM])
    assert list(ALL_JOINTS) == expected
    assert len(LEG_JOINTS) == 12 and len(UPPER_BODY_JOINTS) == 18
    assert set(LEG_JOINTS) == set(LEFT_LEG_JOINTS + RIGHT_LEG_JOINTS)


def test_thirty_actuated_revolute_joints(plant):
    assert plant.num_positions() == 37 and plant.num_velocities() == 36
    assert plant.num_actuators() == 30
    actuated = {plant.get_joint_actuator(i).joint().name()
                for i in plant.GetJointActuatorIndices()}
    assert actuated == set(ALL_JOINTS)
    for name in ALL_JOINTS:
        assert isinstance(plant.GetJointByName(name), RevoluteJoint)


def test_floating_base_is_pelvis(plant):
    pelvis = plant.GetBodyByName("pelvis")
    assert pelvis.is_floating_base_body()
    for name in ("torso", "l_sole", "r_sole"):
        plant.GetBodyByName(name)


def test_limits_present_on_every_joint(plant):
    for name in ALL_JOINTS:
        joint = plant.GetJointByName(name)
        lower, upper = joint.position_lower_limits()[0], joint.position_upper_limits()[0]
        assert np.isfinite(lower) and np.isfinite(upper) and lower < upper
        assert np.isfinite(joint.velocity_upper_limits()[0])
        assert 1.0 <= joint.velocity_upper_limits()[0] <= 10.0
        assert joint.velocity_lower_limits()[0] == -joint.velocity_upper_limits()[0]
    for index in plant.GetJointActuatorIndices():
        assert 0 < plant.get_joint_actuator(index).effort_limit() < 1000


def test_leg_conventions_and_limits(plant):
    for side in "lr":
        knee = plant.GetJointByName(f"{side}_knee")
        assert -0.1 <= knee.position_lower_limits()[0] <= 0.0
        assert 2.2 <= knee.position_upper_limits()[0] <= 2.6
        for name in ("hip_pitch", "knee", "ankle_pitch"):
            axis = plant.GetJointByName(f"{side}_{name}").revolute_axis()
            np.testing.assert_allclose(axis, [0, 1, 0])
        assert 3.0 <= plant.GetJointByName(f"{side}_knee").velocity_upper_limits()[0] <= 6.5


def test_knee_flexion_moves_ankle_backward(plant):
    context = _standing_context(plant)
    before = plant.GetFrameByName("l_sole").CalcPoseInWorld(context).translation()
    q = plant.GetPositions(context)
    q[joint_position_indices(plant, ["l_knee"])] = 0.5
    plant.SetPositions(context, q)
    after = plant.GetFrameByName("l_sole").CalcPoseInWorld(context).translation()
    assert after[0] < before[0] - 0.05 and after[2] > before[2]


def test_total_and_leg_mass(plant):
    context = plant.CreateDefaultContext()
    assert 55.0 <= plant.CalcTotalMass(context) <= 61.0
    for side in "lr":
        bodies = [plant.GetJointByName(j).child_body() for j in
                  [f"{side}_{n}" for n in EXPECTED_LEG]]
        leg_mass = sum(b.default_mass() for b in bodies)
        assert 9.0 <= leg_mass <= 11.0


def _visual_z_extent(robot, context):
    """(min z, max z) over all illustration geometry in world."""
    _, plant, scene_graph = robot
    inspector = scene_graph.model_inspector()
    z_values = []
    for index in range(plant.num_bodies()):
        body = plant.get_body(BodyIndex(index))
        frame_id = plant.GetBodyFrameIdIfExists(body.index())
        if frame_id is None:
            continue
        X_WB = plant.EvalBodyPoseInWorld(context, body)
        for gid in inspector.GetGeometries(frame_id, Role.kIllustration):
            obb = inspector.GetObbInGeometryFrame(gid)
            X_WO = X_WB @ inspector.GetPoseInFrame(gid) @ obb.pose()
            for signs in itertools.product((-1, 1), repeat=3):
                z_values.append((X_WO @ (np.array(signs) * obb.half_width()))[2])
    return min(z_values), max(z_values)


def test_height(robot):
    plant = robot[1]
    bottom, top = _visual_z_extent(robot, _standing_context(plant))
    assert abs(bottom) < 1e-6
    assert 1.50 <= top <= 1.58


def test_zero_posture_com_height(plant):
    context = _standing_context(plant)
    com = plant.CalcCenterOfMassPositionInWorld(context)
    assert 0.85 <= com[2] <= 0.88
    assert abs(com[0]) < 0.02 and abs(com[1]) < 1e-9


@pytest.mark.parametrize("height", [WALKING_COM_HEIGHT, WALKING_COM_HEIGHT - 0.04])
def test_nominal_standing_configuration(plant, height):
    q = nominal_standing_configuration(plant, height)
    context = _standing_context(plant, q)
    com = plant.CalcCenterOfMassPositionInWorld(context)
    np.testing.assert_allclose(com, [0, 0, height], atol=1e-6)
    for side, y in (("l", 0.06), ("r", -0.06)):
        pose = plant.GetFrameByName(f"{side}_sole").CalcPoseInWorld(context)
        np.testing.assert_allclose(pose.translation(), [0, y, 0], atol=1e-9)
        np.testing.assert_allclose(pose.rotation().matrix(), np.eye(3), atol=1e-9)
    knees = q[joint_position_indices(plant, ["l_knee", "r_knee"])]
    assert np.all(knees > 0.3) and np.all(knees < 2.0)
    assert np.all(q[7:] >= plant.GetPositionLowerLimits()[7:])
    assert np.all(q[7:] <= plant.GetPositionUpperLimits()[7:])


def test_nominal_unreachable_height_raises(plant):
    with pytest.raises(ValueError, match="not reachable"):
        nominal_standing_configuration(plant, 1.2)


def test_sole_collision_geometry(robot):
    _, plant, scene_graph = robot
    inspector = scene_graph.model_inspector()
    bodies = [plant.get_body(BodyIndex(i)) for i in range(plant.num_bodies())]
    colliding = [b.name() for b in bodies
                 if plant.GetCollisionGeometriesForBody(b)]
    assert sorted(colliding) == ["l_sole", "r_sole"]
    for side in "lr":
        ids = plant.GetCollisionGeometriesForBody(plant.GetBodyByName(f"{side}_sole"))
        boxes = [g for g in ids if isinstance(inspector.GetShape(g), Box)]
        assert len(boxes) == 1
        box = inspector.GetShape(boxes[0])
        assert box.width() == pytest.approx(SOLE.length)
        assert box.depth() == pytest.approx(SOLE.width)
        props = inspector.GetProximityProperties(boxes[0])
        friction = props.GetProperty("material", "coulomb_friction")
        assert 0.8 <= friction.dynamic_friction() <= 1.0


def test_sole_frame_below_ankle(plant):
    context = _standing_context(plant)
    for side in "lr":
        ankle = plant.GetBodyByName(f"{side}_foot").EvalPoseInWorld(context)
        sole = plant.GetFrameByName(f"{side}_sole").CalcPoseInWorld(context)
        np.testing.assert_allclose(ankle.translation() - sole.translation(),
                                   [0, 0, SOLE.ankle_height], atol=1e-12)


def test_sole_corners():
    corners = SOLE.local_corners("l")
    assert corners[:, 0].max() == SOLE.toe and corners[:, 0].min() == -SOLE.heel
    assert corners[:, 1].max() == SOLE.outer and corners[:, 1].min() == -SOLE.inner
    assert SOLE.local_corners("r")[:, 1].min() == -SOLE.outer


def test_missing_file_names_file(tmp_path):
    missing = tmp_path / "nope.urdf"
    with pytest.raises(FileNotFoundError, match="nope.urdf"):
        load_humanoid(MultibodyPlant(0.0), missing)


def test_malformed_file_names_file(tmp_path):
    broken = tmp_path / "broken.urdf"
    broken.write_text("<robot name='x'><link name='a'></robot")
    with pytest.raises(ValueError, match="broken.urdf"):
        load_humanoid(MultibodyPlant(0.0), broken)


def test_invalid_urdf_content_names_file(tmp_path):
    bad = tmp_path / "bad_joint.urdf"
    bad.write_text("<robot name='x'><link name='a'/>"
                   "<joint name='j' type='revolute'><parent link='a'/>"
                   "<child link='missing'/></joint></robot>")
    with pytest.raises(ValueError, match="bad_joint.urdf"):
        load_humanoid(MultibodyPlant(0.0), bad)
