"""Tests of drake_estop.robots: descriptions as data, the built-in robots, parsing, meshes, IK measurements."""

import dataclasses
import importlib.metadata
import importlib.util
import logging
import math

import numpy as np
import pytest
import yaml
from pydrake.geometry import (
    AddContactMaterial,
    CollisionFilterDeclaration,
    GeometrySet,
    HalfSpace,
    ProximityProperties,
    Role,
)
from pydrake.math import RigidTransform
from pydrake.multibody.plant import (
    AddMultibodyPlant,
    AddMultibodyPlantSceneGraph,
    CoulombFriction,
    MultibodyPlant,
    MultibodyPlantConfig,
)
from pydrake.multibody.tree import RevoluteJoint
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from drake_estop import model
from drake_estop.physics.plant import PhysicsParameters
from drake_estop.planning.gait import GaitParameters, Sole
from drake_estop.planning.plan import StopParameters
from drake_estop.robots import (
    MissingRobotPackage,
    add_robot,
    gait_defaults,
    joint_limits,
    load_robot,
    measure_reach,
    nominal_standing_configuration,
    reach_limits,
    read_description,
    robot_facts,
    set_servo_gains,
    sole_frame,
    stop_parameters,
)
from drake_estop.robots.loading import built_in_path, model_file
from drake_estop.robots.measure import REFERENCE_LEG_LENGTH
from drake_estop.robots.meshes import cache_dir, mesh_sole_extents, prepare_urdf
from drake_estop.robots.plant import sole_contact_points

try:
    importlib.metadata.distribution("example-robot-data")
    HAVE_ROBOT_DATA = True
except importlib.metadata.PackageNotFoundError:
    HAVE_ROBOT_DATA = False
HAVE_TRIMESH = importlib.util.find_spec("trimesh") is not None

needs_trimesh = pytest.mark.skipif(not HAVE_TRIMESH, reason="trimesh is not installed (pip install -e '.[robots]')")
needs_robot_data = pytest.mark.skipif(
    not (HAVE_ROBOT_DATA and HAVE_TRIMESH),
    reason="the robots extra (example-robot-data, trimesh) is not installed (pip install -e '.[robots]')")
EXTERNAL = [pytest.param(name, marks=needs_robot_data) for name in ("g1", "talos")]


@pytest.fixture(scope="module", autouse=True)
def cache(tmp_path_factory):
    """Converted meshes and measured reach go to a fresh folder (every conversion and measurement runs)."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("DRAKE_ESTOP_CACHE", str(tmp_path_factory.mktemp("cache")))
        patch.setenv("DRAKE_ALLOW_NETWORK", "meshcat")  # offline: no package may be fetched
        yield


@pytest.fixture(scope="module")
def default():
    return load_robot("default")


def _with_scene_graph(description):
    """(plant, scene_graph, instance), finalized, the robot with its visuals and sole contact."""
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 1e-3)
    instance = add_robot(plant, description)
    set_servo_gains(plant, instance, description)
    plant.Finalize()
    return plant, scene_graph, instance


def _kinematic(description):
    plant = MultibodyPlant(0.0)
    instance = add_robot(plant, description)
    plant.Finalize()
    return plant, instance


# -- the default humanoid equals today's constants -----------------------------------------------------


def test_default_description_equals_the_model_constants(default):
    assert default.floating_base == model.FLOATING_BASE
    assert default.torso_body == model.TORSO
    assert (default.left_foot.body, default.right_foot.body) == (model.LEFT_SOLE, model.RIGHT_SOLE)
    assert not default.left_foot.has_offset and not default.right_foot.has_offset
    assert default.left_leg.names == model.LEFT_LEG_JOINTS
    assert default.right_leg.names == model.RIGHT_LEG_JOINTS
    assert default.leg_joints == model.LEG_JOINTS
    assert default.torso == model.CHEST_JOINTS and default.head == model.HEAD_JOINTS
    assert default.left_arm == model.LEFT_ARM_JOINTS and default.right_arm == model.RIGHT_ARM_JOINTS
    assert default.upper_body_joints == model.UPPER_BODY_JOINTS
    assert default.all_joints == model.ALL_JOINTS
    assert default.walking_com_height == model.WALKING_COM_HEIGHT
    assert default.hip_half_width == model.HIP_HALF_WIDTH
    assert default.sole_thickness == model.SOLE.thickness
    for foot in (default.left_foot, default.right_foot):
        assert (foot.toe, foot.heel, foot.inner, foot.outer) == (
            model.SOLE.toe, model.SOLE.heel, model.SOLE.inner, model.SOLE.outer)
    assert default.sole() == Sole()
    assert model_file(default) == model.MODEL_PATH


def test_default_description_equals_the_planner_and_gait_defaults(default):
    stop, gait = StopParameters(), GaitParameters()
    assert reach_limits(default).fore == stop.max_fore_reach
    assert reach_limits(default).rear == stop.max_rear_reach
    assert reach_limits(default).width == stop.max_step_width
    assert stop_parameters(default) == stop  # the landing widths too (0.15 / 0.30 m)
    defaults = gait_defaults(default)
    assert (defaults.step_length, defaults.step_width, defaults.step_time) == (
        gait.step_length, gait.step_width, gait.step_time)
    assert default.walking_com_height == gait.com_height


def test_default_servo_gains_equal_the_physics_gains(default):
    physics = PhysicsParameters()
    for joint in default.all_joints:
        gain = default.servo_gain(joint)
        assert gain.kp == physics.gain(joint), joint
        assert gain.kd == pytest.approx(physics.damping_time * physics.gain(joint), rel=1e-12), joint


def test_default_facts_read_from_the_model(default):
    facts = robot_facts(default)
    assert facts.mass == pytest.approx(58.0, abs=1e-9)
    assert facts.leg_length == pytest.approx(model.PELVIS_HEIGHT_AT_ZERO, abs=1e-9)
    assert facts.ankle_height == pytest.approx(model.SOLE.ankle_height, abs=1e-9)
    assert facts.straight_com_height == pytest.approx(0.863, abs=1e-3)  # models/README.md
    knee = facts.limits["l_knee"]
    assert (knee.lower, knee.upper, knee.velocity, knee.effort) == (0.0, 2.4, 6.0, 250.0)
    assert facts.limits["r_hip_roll"].lower == pytest.approx(math.radians(-45), abs=1e-4)


def test_default_parses_as_load_humanoid_does(default):
    plant, scene_graph, _ = _with_scene_graph(default)
    reference = MultibodyPlant(1e-3)
    builder = DiagramBuilder()
    reference, reference_graph = AddMultibodyPlantSceneGraph(builder, 1e-3)
    model.load_humanoid(reference)
    reference.Finalize()
    assert plant.num_positions() == reference.num_positions() == 37
    assert plant.num_actuators() == reference.num_actuators() == 30
    assert np.array_equal(plant.gravity_field().gravity_vector(), reference.gravity_field().gravity_vector())
    for role in (Role.kProximity, Role.kIllustration):
        assert (scene_graph.model_inspector().NumGeometriesWithRole(role)
                == reference_graph.model_inspector().NumGeometriesWithRole(role))


def test_default_standing_configuration_is_the_model_s(default):
    plant, _ = _kinematic(default)
    q = nominal_standing_configuration(plant, default)
    assert np.max(np.abs(q - model.nominal_standing_configuration(plant))) < 1e-5


def test_measured_reach_of_the_default_is_close_to_the_planner_s(default):
    """The IK measurement reproduces the reach limits measured by hand for the planner."""
    reach = measure_reach(default)
    assert reach.fore == pytest.approx(StopParameters().max_fore_reach, abs=0.01)
    assert reach.rear == pytest.approx(StopParameters().max_rear_reach, abs=0.015)


# -- the external robots ----------------------------------------------------------------------------------


@pytest.fixture(scope="module", params=EXTERNAL)
def external(request):
    description = load_robot(request.param)
    return description, _with_scene_graph(description)


def test_external_robot_loads_with_its_named_joints(external):
    description, (plant, _, instance) = external
    for group, joint in description.joint_groups():
        assert isinstance(plant.GetJointByName(joint, instance), RevoluteJoint), group
    actuated = {plant.get_joint_actuator(i).joint().name() for i in plant.GetJointActuatorIndices(instance)}
    assert set(description.all_joints) <= actuated
    limits = joint_limits(plant, instance, description)
    for joint, limit in limits.items():
        assert limit.lower < limit.upper, joint
        assert 0 < limit.velocity < math.inf and 0 < limit.effort < math.inf, joint
    assert plant.GetBodyByName(description.floating_base, instance).is_floating_base_body()


def test_external_robot_soles_have_positive_rectangles_and_contact(external):
    description, (plant, scene_graph, instance) = external
    inspector = scene_graph.model_inspector()
    names = sorted(inspector.GetName(g).split("::")[-1] for g in inspector.GetAllGeometryIds(Role.kProximity))
    assert len(names) == 10 and sum(n.endswith("sole_box") for n in names) == 2
    for side in ("left", "right"):
        foot = description.foot(side)
        assert min(foot.toe, foot.heel, foot.inner, foot.outer) > 0.02
        points = np.array(list(sole_contact_points(description, side).values()))
        assert np.all(points[:, 0] < foot.toe) and np.all(points[:, 0] > -foot.heel)


def test_external_robot_visuals_are_meshes_drake_shows(external):
    _, (_, scene_graph, _) = external
    inspector = scene_graph.model_inspector()
    extensions = {inspector.GetShape(g).extension() for g in inspector.GetAllGeometryIds(Role.kIllustration)
                  if hasattr(inspector.GetShape(g), "extension")}
    assert extensions == {".obj"}


def test_external_robot_stands_with_flat_soles_and_the_cog_on_target(external):
    description, (plant, _, instance) = external
    q = nominal_standing_configuration(plant, description)
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, q)
    half = robot_facts(description).hip_half_width
    for side, y in (("left", half), ("right", -half)):
        frame = sole_frame(plant, description, side, instance=instance)
        X_WS = frame.CalcPoseInWorld(context)
        for x_s, y_s in description.sole().corners((0.0, 0.0), side):  # in the sole frame
            assert abs(X_WS.multiply([x_s, y_s, 0.0])[2]) < 1e-3, side
        assert np.linalg.norm(X_WS.translation() - [0, y, 0]) < 1e-3
    com = plant.CalcCenterOfMassPositionInWorld(context)
    assert np.linalg.norm(com - [0, 0, description.walking_com_height]) < 1e-3
    knee = q[plant.GetJointByName(description.left_leg.knee, instance).position_start()]
    assert 0.5 < knee < 1.3  # bent, as the default's 0.89 rad


def test_external_robot_reach_is_plausible(external):
    description, _ = external
    reach, measured = reach_limits(description), measure_reach(description)
    assert reach.fore == (description.max_fore_reach or measured.fore)
    assert reach.rear == (description.max_rear_reach or measured.rear)  # TALOS's own: 1 cm inside
    assert measured.rear - 0.011 < reach.rear <= measured.rear
    leg = robot_facts(description).leg_length
    assert 0.2 * leg < reach.fore < 0.6 * leg
    assert 0.2 * leg < reach.rear < 0.6 * leg
    step_width = gait_defaults(description).step_width
    assert reach.width == (description.max_step_width or measured.width)
    assert step_width + 0.1 < measured.width < step_width + 0.4 * leg  # the landing leg reaches out sideways


def test_external_robot_landing_widths_come_from_its_soles_and_reach(external):
    """What makes a landing moved sideways (the capture landing, the recovery step) possible is the robot's:
    its soles' inner edges 4 cm apart at the narrowest, its measured widest step at the widest."""
    description, _ = external
    stop = stop_parameters(description)
    inner = description.left_foot.inner + description.right_foot.inner
    assert stop.min_step_width == pytest.approx(inner + 0.04)
    assert stop.max_step_width == reach_limits(description).width
    assert stop.max_step_width == (description.max_step_width or measure_reach(description).width)
    assert stop.recovery_step_inward == description.recovery_step_inward


def test_external_robot_gait_defaults_scale_with_the_leg(external):
    """What the description leaves out is scaled; what it gives (the G1's step length and width) is its own."""
    description, _ = external
    facts, gait = robot_facts(description), gait_defaults(description)
    scale = facts.leg_length / REFERENCE_LEG_LENGTH
    scaled = {"step_length": (0.3 * scale, 5e-4), "step_time": (0.8 * math.sqrt(scale), 5e-3),
              "step_width": (2 * facts.hip_half_width + 0.07 * scale, 5e-4)}
    for name, (value, tolerance) in scaled.items():
        own = getattr(description, name)
        assert getattr(gait, name) == (own if own is not None else pytest.approx(value, abs=tolerance)), name
    assert gait.step_width > description.left_foot.inner + description.right_foot.inner
    assert description.name != "g1" or (gait.step_length, gait.step_width) == (0.27, 0.25)


@pytest.mark.parametrize("name, mesh, offset", [
    pytest.param("g1", "g1_description/meshes/left_ankle_roll_link.STL", 0.001, marks=needs_robot_data),
    pytest.param("talos", "talos_data/meshes/v2/ankle_X_collision.stl", 0.003, marks=needs_robot_data),
])
def test_external_sole_rectangle_lies_on_the_foot_mesh_s_bottom(name, mesh, offset):
    """The sole rectangle is inside the flat bottom face of the foot mesh, and the sole plane is its bottom."""
    from scipy.spatial import ConvexHull

    description = load_robot(name)
    share = importlib.metadata.distribution("example-robot-data").locate_file(
        "cmeel.prefix/share/example-robot-data/robots")
    path = share / mesh
    extents = mesh_sole_extents(path, band=offset)
    foot = description.left_foot
    sole_z = foot.translation[2] - (0.107 if name == "talos" else 0.0)
    assert extents["bottom"] == pytest.approx(sole_z, abs=1e-3)
    import trimesh

    vertices = trimesh.load(str(path), force="mesh").vertices
    face = vertices[vertices[:, 2] <= extents["bottom"] + offset][:, :2]
    hull = ConvexHull(face)
    corners = np.array(description.sole().corners((0.0, 0.0), "left"))
    inside = corners @ hull.equations[:, :2].T + hull.equations[:, 2]
    assert np.all(inside <= 1e-9)


# -- descriptions that are wrong -------------------------------------------------------------------------


def _default_document():
    return yaml.safe_load(built_in_path("default").read_text())


def _load(document, tmp_path):
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(document))
    return load_robot(path)


@pytest.mark.parametrize("change, message", [
    (lambda d: d["left_foot"].update(body="no_such_link"), "left_foot.body: body 'no_such_link' is not in the model"),
    (lambda d: d["right_leg"].update(knee="r_knee_spare"), "right_leg.knee: joint 'r_knee_spare' is not in the model"),
    (lambda d: d["left_arm"].__setitem__(2, "l_elbow_spare"),
     r"left_arm\[2\]: joint 'l_elbow_spare' is not in the model"),
    (lambda d: d["left_foot"].update(toe=0.0), "left_foot: toe must be a positive"),
    (lambda d: d["right_foot"].update(inner=-0.01), "right_foot: inner must be a positive"),
    (lambda d: d.update(model="/no/such/robot.urdf"), "model: cannot read the model file /no/such/robot.urdf"),
    (lambda d: d.update(model="robot.txt"), "model: .*robot.txt is not a URDF"),
    (lambda d: d.update(floating_base="l_thigh"), "floating_base: body 'l_thigh' has an inboard joint"),
    (lambda d: d.update(walking_com_height=0.0), "walking_com_height must be a positive"),
    (lambda d: d.update(max_step_width=0.12), r"min_step_width \(0.15 m\) must be below max_step_width"),
    (lambda d: d.update(min_step_width=0.1), r"min_step_width \(0.1 m\) overlaps the soles"),
    (lambda d: d.update(max_step_width=-0.3), "max_step_width must be a positive"),
    (lambda d: d.update(stop_zmp_weight=0.0), "stop_zmp_weight must be a positive"),
    (lambda d: d.update(servo_gains=[{"key": "hip", "kp": 1.0, "kd": 1.0}]), "servo_gains: no gain .*'l_knee'"),
    (lambda d: d.update(torso=["chest_yaw", "l_knee"]), r"torso\[1\]: joint 'l_knee' is also in left_leg.knee"),
    (lambda d: d.pop("left_leg"), "left_leg is missing"),
    (lambda d: d.update(sole_size=0.1), "sole_size"),
    (lambda d: d.update(limit_overrides=[{"joint": "l_knee", "velocity": 3.0}]),
     r"limit_overrides\[0\]: the model gives 'l_knee' a velocity limit"),
])
def test_a_bad_description_raises_naming_the_field(tmp_path, change, message):
    document = _default_document()
    change(document)
    with pytest.raises(ValueError, match=message):
        _load(document, tmp_path)


def test_an_unreadable_model_file_raises_naming_the_model(tmp_path):
    broken = tmp_path / "broken.urdf"
    broken.write_text("<robot name='x'><link name='a'>")
    document = _default_document()
    document["model"] = "broken.urdf"  # relative to the description file
    with pytest.raises(ValueError, match=r"model: cannot read the model file .*broken.urdf"):
        _load(document, tmp_path)


def test_an_unknown_robot_name_raises():
    with pytest.raises(ValueError, match="unknown robot name 'asimo'.*default, g1, talos"):
        load_robot("asimo")


def test_a_missing_robot_data_package_names_the_extra(monkeypatch):
    real = importlib.metadata.distribution

    def distribution(name):
        if name == "example-robot-data":
            raise importlib.metadata.PackageNotFoundError(name)
        return real(name)

    monkeypatch.setattr(importlib.metadata, "distribution", distribution)
    with pytest.raises(MissingRobotPackage, match=r"example-robot-data.*pip install -e '\.\[robots\]'"):
        load_robot("g1")


def test_a_limit_override_fills_in_what_the_model_lacks(tmp_path):
    """A URDF joint without velocity and effort limits takes the description's."""
    urdf = (model.MODEL_PATH.read_text()
            .replace('<limit lower="0.0000" upper="2.4000" velocity="6" effort="250"/>',
                     '<limit lower="0.0000" upper="2.4000"/>', 1))
    assert urdf != model.MODEL_PATH.read_text()
    (tmp_path / "humanoid.urdf").write_text(urdf)
    document = _default_document()
    document["model"] = "humanoid.urdf"
    document["limit_overrides"] = [{"joint": "l_knee", "velocity": 7.0, "effort": 260.0}]
    description = _load(document, tmp_path)
    limits = robot_facts(description).limits
    assert (limits["l_knee"].velocity, limits["l_knee"].effort) == (7.0, 260.0)
    assert (limits["r_knee"].velocity, limits["r_knee"].effort) == (6.0, 250.0)


def test_a_description_from_text_resolves_paths_against_its_folder(tmp_path):
    text = built_in_path("default").read_text().replace(
        "package://drake_estop_models/humanoid.urdf", "models/humanoid.urdf")
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "humanoid.urdf").write_text(model.MODEL_PATH.read_text())
    description = read_description(text=text, folder=tmp_path)
    assert model_file(description) == (tmp_path / "models" / "humanoid.urdf").resolve()


# -- meshes -------------------------------------------------------------------------------------------------

_URDF = """<robot name="tiny">
  <link name="base">
    <inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
    <visual><geometry><mesh filename="{visual}"/></geometry></visual>
    <collision><geometry><box size="0.1 0.2 0.3"/></geometry></collision>
  </link>
  <link name="finger">
    <inertial><mass value="0.1"/><inertia ixx="0.001" iyy="0.001" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial>
  </link>
  <joint name="finger_joint" type="fixed"><parent link="base"/><child link="finger"/>
    <mimic joint="other" multiplier="1"/></joint>
</robot>"""


def _parsed_inspector(urdf_text):
    """The geometry inspector of a plant that parsed ``urdf_text`` offline."""
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 0.0)
    model.offline_parser(plant).AddModelsFromString(urdf_text, "urdf")
    plant.Finalize()
    return scene_graph.model_inspector()


def _tiny_urdf(tmp_path, visual):
    path = tmp_path / "tiny.urdf"
    path.write_text(_URDF.format(visual=visual))
    return path


@needs_trimesh
def test_an_stl_visual_becomes_a_cached_obj_drake_parses(tmp_path):
    import trimesh

    trimesh.creation.box(extents=(0.1, 0.2, 0.3)).export(str(tmp_path / "part.stl"))
    prepared = prepare_urdf(_tiny_urdf(tmp_path, "part.stl"), packages=None, visuals=True)
    assert "<collision" not in prepared.text and "<mimic" not in prepared.text
    assert prepared.fallbacks == []
    inspector = _parsed_inspector(prepared.text)
    (visual,) = inspector.GetAllGeometryIds(Role.kIllustration)
    obj = inspector.GetShape(visual).source().path()
    assert obj.suffix == ".obj" and obj.parent == cache_dir() / "meshes"
    assert len(trimesh.load(str(obj), force="mesh").faces) == 12
    again = prepare_urdf(_tiny_urdf(tmp_path, "part.stl"), packages=None, visuals=True)
    assert again.text == prepared.text  # the cached conversion is reused


def test_a_mesh_that_cannot_be_converted_falls_back_to_the_collision_shape(tmp_path, caplog):
    (tmp_path / "broken.dae").write_text("not a mesh")
    with caplog.at_level(logging.WARNING, logger="drake_estop.robots"):
        prepared = prepare_urdf(_tiny_urdf(tmp_path, "broken.dae"), packages=None, visuals=True)
    assert prepared.fallbacks == ["broken.dae"]
    assert "broken.dae" in caplog.text
    inspector = _parsed_inspector(prepared.text)
    (visual,) = inspector.GetAllGeometryIds(Role.kIllustration)
    assert type(inspector.GetShape(visual)).__name__ == "Box"
    assert inspector.GetAllGeometryIds(Role.kProximity) == []


# -- options -------------------------------------------------------------------------------------------------


def _sole_geometry(scene_graph):
    """Name (unscoped, l_/r_ as left_/right_) -> (shape type, size, pose in the body) of the proximity geometry."""
    inspector = scene_graph.model_inspector()
    out = {}
    for gid in inspector.GetAllGeometryIds(Role.kProximity):
        name = inspector.GetName(gid).split("::")[-1].replace("l_sole", "left_sole").replace("r_sole", "right_sole")
        shape = inspector.GetShape(gid)
        size = (shape.width(), shape.depth(), shape.height()) if hasattr(shape, "width") else (shape.radius(),)
        out[name] = (type(shape).__name__, size, inspector.GetPoseInFrame(gid).GetAsMatrix4())
    return out


def test_added_sole_contact_is_the_default_model_s_own(default):
    """Without the model's sole geometry, add_robot adds the same boxes and corner spheres at the same poses."""
    _, own, _ = _with_scene_graph(default)
    added = dataclasses.replace(default, sole_contact_in_model=False, keep_model_collisions=False)
    _, scene_graph, _ = _with_scene_graph(added)
    expected, got = _sole_geometry(own), _sole_geometry(scene_graph)
    assert sorted(got) == sorted(expected) and len(got) == 10
    for name, (kind, size, pose) in expected.items():
        assert got[name][0] == kind and np.allclose(got[name][1], size, atol=1e-12), name
        assert np.allclose(got[name][2], pose, atol=1e-12), name


def test_a_nominal_posture_holds_the_upper_body_while_standing(default, tmp_path):
    document = _default_document()
    document["nominal_posture"] = [{"joint": "l_elbow", "angle": -0.5}, {"joint": "r_elbow", "angle": -0.5}]
    description = _load(document, tmp_path)
    plant, instance = _kinematic(description)
    q = nominal_standing_configuration(plant, description)
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, q)
    assert q[plant.GetJointByName("l_elbow").position_start()] == -0.5
    assert np.linalg.norm(plant.CalcCenterOfMassPositionInWorld(context) - [0, 0, 0.814]) < 1e-6
    assert np.max(np.abs(q - model.nominal_standing_configuration(plant))) > 1e-3  # the arms moved the legs


def test_another_model_in_the_plant_is_held_while_the_robot_stands(default):
    """Two robots in one plant: the first stands with its own COG on target, the second keeps its pose."""
    plant = MultibodyPlant(0.0)
    first = add_robot(plant, default)
    parser = model.offline_parser(plant)
    parser.SetAutoRenaming(True)
    (second,) = parser.AddModels(str(model.MODEL_PATH))
    plant.Finalize()
    q = nominal_standing_configuration(plant, default, instance=first)
    context = plant.CreateDefaultContext()
    before = plant.GetPositions(context, second)
    plant.SetPositions(context, q)
    assert np.array_equal(plant.GetPositions(context, second), before)
    com = plant.CalcCenterOfMassPositionInWorld(context, [first])
    assert np.linalg.norm(com - [0, 0, default.walking_com_height]) < 1e-6


@needs_robot_data
def test_the_model_s_own_collisions_can_be_kept_as_converted_meshes():
    description = dataclasses.replace(load_robot("g1"), keep_model_collisions=True)
    _, scene_graph, _ = _with_scene_graph(description)
    inspector = scene_graph.model_inspector()
    shapes = [inspector.GetShape(g) for g in inspector.GetAllGeometryIds(Role.kProximity)]
    assert len(shapes) > 10
    assert {s.extension() for s in shapes if hasattr(s, "extension")} == {".obj"}


# -- physics -------------------------------------------------------------------------------------------------


def _standing_simulation(description, seconds):
    """The robot on a rigid floor, its servos holding the standing posture; (plant, context) after ``seconds``."""
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(MultibodyPlantConfig(
        time_step=1e-3, contact_model="point", discrete_contact_approximation="lagged"), builder)
    instance = add_robot(plant, description)
    floor = ProximityProperties()
    AddContactMaterial(friction=CoulombFriction(1.0, 0.8), properties=floor)
    ground = plant.RegisterCollisionGeometry(plant.world_body(), RigidTransform(), HalfSpace(), "ground", floor)
    set_servo_gains(plant, instance, description)
    plant.Finalize()
    inspector = scene_graph.model_inspector()
    boxes = [g for g in inspector.GetAllGeometryIds(Role.kProximity) if inspector.GetName(g).endswith("sole_box")]
    scene_graph.collision_filter_manager().Apply(  # point contact on the corner spheres only
        CollisionFilterDeclaration().ExcludeBetween(GeometrySet(boxes), GeometrySet([ground])))
    q = nominal_standing_configuration(plant, description)
    actuated = [plant.get_joint_actuator(i).joint().position_start() for i in plant.GetJointActuatorIndices()]
    hold = builder.AddSystem(ConstantVectorSource(np.concatenate([q[actuated], np.zeros(len(actuated))])))
    builder.Connect(hold.get_output_port(), plant.get_desired_state_input_port(instance))
    simulator = Simulator(builder.Build())
    context = plant.GetMyMutableContextFromRoot(simulator.get_mutable_context())
    plant.SetPositions(context, q)
    simulator.AdvanceTo(seconds)
    return plant, context, q


@pytest.mark.parametrize("name", ["default", *EXTERNAL])
def test_the_robot_stands_on_its_sole_contact_under_its_servos(name):
    """One second on the floor: the added sole contact carries the robot and the servo gains hold it."""
    description = load_robot(name)
    plant, context, q = _standing_simulation(description, 1.0)
    base = plant.GetBodyByName(description.floating_base)
    assert abs(base.EvalPoseInWorld(context).translation()[2] - q[6]) < 2e-3
    com = plant.CalcCenterOfMassPositionInWorld(context)
    assert np.linalg.norm(com[:2]) < 5e-3 and abs(com[2] - description.walking_com_height) < 2e-3
    assert np.linalg.norm(plant.GetVelocities(context)) < 0.05
