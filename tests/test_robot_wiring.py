"""Any described humanoid through the kinematic path: the gait and stop of its description, the reference
layout of its upper body, the whole-body IK on its joints and soles, the Drake diagram, Meshcat, the API, the
scenario and the command line (``--robot``); the default robot exactly as before."""

import csv
import dataclasses
import json
import warnings

import numpy as np
import pytest
import yaml
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from robot_helpers import needs_robots

from drake_estop import AddEmergencyStop
from drake_estop.cli import main
from drake_estop.planning.arms import ArmSwing
from drake_estop.planning.gait import ARM_JOINTS, ARM_NEUTRAL, GaitParameters, NominalPattern
from drake_estop.planning.plan import StopParameters
from drake_estop.robots import JointAngle, add_robot, load_robot
from drake_estop.robots.loading import built_in_path
from drake_estop.robots.parameters import (
    arm_swing,
    as_robot,
    com_height_range,
    gait_parameters,
    standing_height,
    stop_parameters,
)
from drake_estop.scenario import Scenario, dump_scenario, load_scenario
from drake_estop.systems.diagram import robot_layout, simulate_diagram
from drake_estop.systems.ik import WholeBodyIK, WholeBodyIkSolver, shared_ik
from drake_estop.systems.reference import DEFAULT_LAYOUT, REFERENCE_SIZE, ReferenceLayout

EXTERNAL = [pytest.param(name, marks=needs_robots) for name in ("g1", "talos")]
#: a late single-support tick of each robot's third step: 0.09 s before its touchdown, as the paper's 3.4 s
LATE_SINGLE_SUPPORT = {"default": 3.4, "g1": 3.37, "talos": 3.565}


# -- the default robot is today's ---------------------------------------------------------------------------


def test_the_default_robot_s_parameters_are_the_planner_s_defaults():
    default = as_robot()
    assert as_robot(None) is as_robot("default") is default
    assert gait_parameters(default) == GaitParameters()
    assert stop_parameters(default) == StopParameters()
    assert arm_swing(default) == ArmSwing() == GaitParameters().arms
    assert ArmSwing().joints == ARM_JOINTS and np.array_equal(ArmSwing().neutral_array, ARM_NEUTRAL)
    assert ReferenceLayout.of(default, ArmSwing()) == DEFAULT_LAYOUT and DEFAULT_LAYOUT.size == REFERENCE_SIZE
    assert com_height_range(default) == (0.54, 0.863)  # models/README.md
    assert standing_height(default) + 0.08 == 1.62  # the one-step indicator's height over its head


def test_the_default_ik_plant_is_the_model_s():
    plant, solver, _ = shared_ik()
    assert shared_ik(as_robot()) == shared_ik() and solver.robot == as_robot()
    assert plant.num_positions() == 37 and plant.HasFrameNamed("l_sole")


# -- the arm swing and the reference layout -----------------------------------------------------------------


@pytest.mark.parametrize("kwargs, message", [
    ({"joints": ("a", "b"), "neutral": (0.0,), "gains": (1.0, 1.0)}, "one entry per joint"),
    ({"joints": ("a", ""), "neutral": (0.0, 0.0), "gains": (1.0, 1.0)}, r"arms.joints\[1\] must be a joint name"),
    ({"joints": ("a", "a"), "neutral": (0.0, 0.0), "gains": (1.0, 1.0)}, r"arms.joints\[1\]: 'a' is listed twice"),
    ({"joints": ("a",), "neutral": (float("nan"),), "gains": (1.0,)}, r"arms.neutral\[0\] must be a finite"),
])
def test_a_bad_arm_swing_raises_naming_the_field(kwargs, message):
    with pytest.raises(ValueError, match=message):
        ArmSwing(**kwargs)


def test_a_gait_swinging_joints_the_robot_lacks_is_refused_naming_the_field():
    gait = GaitParameters(arms=ArmSwing(joints=("l_shoulder_pitch", "l_wing"), neutral=(0.0, 0.0),
                                        gains=(1.0, 1.0)))
    with pytest.raises(ValueError, match=r"gait.arms.joints\[1\]: 'l_wing' is not an upper-body joint"):
        robot_layout(None, NominalPattern(gait))


def test_no_arm_swing_holds_the_upper_body_at_its_standing_angles():
    layout = ReferenceLayout(upper_body=("a", "b"), standing=(0.1, -0.2), arms=())
    assert layout.entries[5:7] == (("upper_body", 2), ("arm_joints", 0))
    assert np.array_equal(layout.upper_body_vector(np.zeros(0)), [0.1, -0.2])
    pattern = NominalPattern(GaitParameters(arms=ArmSwing(joints=(), neutral=(), gains=())))
    assert pattern.upper_body(3.0)[0].shape == (0,)


def test_a_description_s_arm_swing_must_name_upper_body_joints(tmp_path):
    document = yaml.safe_load(built_in_path("default").read_text())
    document["arm_swing"][1]["joint"] = "l_knee"
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(document))
    with pytest.raises(ValueError, match=r"arm_swing\[1\]: 'l_knee' is not one of the upper-body joints"):
        load_robot(path)


def test_the_ik_keeps_the_knees_as_bent_as_the_robot_says():
    default = as_robot()
    plant, _, _ = shared_ik()
    knees = [plant.GetJointByName(default.leg(side).knee).position_start() for side in ("left", "right")]
    assert [WholeBodyIkSolver(plant)._lower[k] for k in knees] == [0.0, 0.0]
    bent = dataclasses.replace(default, min_knee_bend=0.2)
    assert [WholeBodyIkSolver(plant, robot=bent)._lower[k] for k in knees] == [0.2, 0.2]
    assert [WholeBodyIkSolver(plant, robot=bent, min_knee_bend=0.1)._lower[k] for k in knees] == [0.1, 0.1]
    with pytest.raises(ValueError, match="min_knee_bend must be in"):
        dataclasses.replace(default, min_knee_bend=1.2)


# -- the external robots through the diagram, the IK and Meshcat ---------------------------------------------


@pytest.fixture(scope="module", params=EXTERNAL)
def external_run(request):
    name = request.param
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return name, simulate_diagram(estop_time=LATE_SINGLE_SUPPORT[name], robot=name)


def test_an_external_robot_stops_in_one_step_with_the_ik_within_a_millimetre(external_run):
    name, result = external_run
    description = as_robot(name)
    assert result.plan.support == "single" and result.plan.case == "one-step"
    assert result.phases[-1] == "stopped" and np.linalg.norm(result.com_vel[-1]) < 1e-9
    errors = result.error_summary()
    assert errors["ik_com_err_max_m"] < 1e-3 and errors["ik_foot_err_max_m"] < 1e-3
    assert errors["velocity_limit_violations"] == 0 and errors["joint_limit_violations"] == 0
    assert set(result.q) == {f"q_{joint}" for joint in description.all_joints}
    assert result.plan.pattern.params == gait_parameters(description)


def test_an_external_robot_swings_and_halts_its_own_arm_joints(external_run):
    """The swing acts on the description's arm joints (shoulder first) and the halt brings them to their
    neutral angles; every other upper-body joint holds its standing angle throughout."""
    name, result = external_run
    description = as_robot(name)
    swing = description.arm_swing
    shoulder = result.q[f"q_{swing[0].joint}"]
    assert np.ptp(shoulder) > 0.2  # the walk's swing, +-0.15 rad
    for joint in swing:
        assert result.q[f"q_{joint.joint}"][-1] == pytest.approx(joint.neutral, abs=1e-12)
    swinging = {joint.joint for joint in swing}
    for joint, angle in zip(description.upper_body_joints, description.standing_angles()):
        if joint not in swinging:
            assert np.all(result.q[f"q_{joint}"] == angle), joint


@needs_robots
def test_a_nominal_posture_is_held_by_the_joints_the_walk_does_not_swing():
    talos = dataclasses.replace(as_robot("talos"), nominal_posture=(JointAngle("arm_left_2_joint", 0.2),
                                                                 JointAngle("arm_right_2_joint", -0.2)))
    handles_result = simulate_diagram(estop_time=LATE_SINGLE_SUPPORT["talos"], robot=talos, after_halt=1.0)
    assert np.all(handles_result.q["q_arm_left_2_joint"] == 0.2)
    assert np.all(handles_result.q["q_arm_right_2_joint"] == -0.2)
    assert handles_result.error_summary()["ik_com_err_max_m"] < 1e-3


@needs_robots
def test_the_g1_replay_holds_its_meshes(tmp_path):
    from drake_estop.systems.visualization import html_mentions, html_scene_bytes

    html = tmp_path / "g1.html"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        simulate_diagram(estop_time=LATE_SINGLE_SUPPORT["g1"], robot="g1", html=html, after_halt=1.0)
    text = html.read_text()
    links = ("pelvis", "torso_link", "left_knee_link", "right_ankle_roll_link", "left_shoulder_pitch_link")
    assert html_mentions(text, links) == set(links)
    scene = b"\n".join(html_scene_bytes(text))
    assert scene.count(b"_meshfile_") >= 20 and scene.count(b"\nv ") > 10_000  # OBJ meshes, their vertices
    assert b"humanoid" not in scene  # not the default robot's boxes


# -- the API ------------------------------------------------------------------------------------------------


@needs_robots
def test_add_emergency_stop_runs_a_named_robot():
    builder = DiagramBuilder()
    estop = AddEmergencyStop(builder, robot="talos", estop_time=LATE_SINGLE_SUPPORT["talos"])
    assert estop.robot.name == "talos" and estop.ik.GetInputPort("upper_body").size() == 20
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(3.7)
    context = simulator.get_context()
    simulator.AdvanceTo(estop.stop_time(context, after_halt=0.5))
    summary, log = estop.summary(context), estop.log(context)
    assert summary["case"] == "one-step" and log.phase[-1] == "stopped"
    assert max(log.ik_com_error) < 1e-3


@needs_robots
def test_add_emergency_stop_takes_the_user_s_plant_of_that_robot():
    g1 = as_robot("g1")
    plant = MultibodyPlant(0.0)
    add_robot(plant, g1)
    plant.Finalize()
    estop = AddEmergencyStop(DiagramBuilder(), plant=plant, robot=g1, log=False)
    assert estop.plant is plant and estop.ik.GetInputPort("upper_body").size() == len(g1.upper_body_joints) == 17
    with pytest.raises(ValueError, match="plant lacks the humanoid's joints"):
        AddEmergencyStop(DiagramBuilder(), plant=plant, log=False)  # the default robot's joints


@needs_robots
def test_the_ik_system_refuses_a_solver_of_another_robot():
    plant, solver, _ = shared_ik("g1")
    with pytest.raises(ValueError, match="robot 'talos' is not the solver's"):
        WholeBodyIK(plant=plant, solver=solver, robot="talos", initial_q=plant.GetDefaultPositions())
    assert WholeBodyIkSolver(plant, robot="g1").robot == solver.robot


# -- the scenario -------------------------------------------------------------------------------------------


@needs_robots
def test_a_scenario_s_robot_brings_its_gait_and_stop():
    scenario = load_scenario(text="{robot: g1, gait: {step_length: 0.2}}")
    g1 = as_robot("g1")
    assert scenario.robot == "g1" and scenario.stop == stop_parameters(g1)
    assert scenario.gait == gait_parameters(g1, step_length=0.2)
    back = load_scenario(text=dump_scenario(scenario))
    assert (back.robot, back.gait, back.stop) == (scenario.robot, scenario.gait, scenario.stop)
    assert load_scenario(text="{robot: g1}", robot="talos").gait == gait_parameters(as_robot("talos"))


def test_a_scenario_s_description_file_is_relative_to_the_scenario(tmp_path):
    folder = tmp_path / "robots"
    folder.mkdir()
    document = yaml.safe_load(built_in_path("default").read_text())
    document["model"] = str(load_robot("default").model)
    document.update(name="mine", walking_com_height=0.8)
    (folder / "mine.yaml").write_text(yaml.safe_dump(document))
    (tmp_path / "scenario.yaml").write_text("robot: robots/mine.yaml\nestop_time: 3.3\n")
    scenario = load_scenario(filename=tmp_path / "scenario.yaml")
    assert scenario.robot == str(folder / "mine.yaml") and scenario.gait.com_height == 0.8


def test_a_scenario_naming_an_unknown_robot_names_it():
    with pytest.raises(ValueError, match="robot 'asimo': unknown robot name"):
        load_scenario(text="{robot: asimo}")
    with pytest.raises(ValueError, match="robot must be"):
        Scenario(robot="")


# -- the command line ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", EXTERNAL)
def test_simulate_runs_a_robot_through_the_diagram(name, tmp_path, capsys):
    summary, log = tmp_path / "summary.json", tmp_path / "log.csv"
    code = main(["simulate", "--robot", name, "--estop-time", str(LATE_SINGLE_SUPPORT[name]),
                 "--summary", str(summary), "--log", str(log)])
    assert code == 0, capsys.readouterr().err
    data = json.loads(summary.read_text())
    assert data["robot"] == name and data["case"] == "one-step"
    assert data["ik"]["ik_com_err_max_m"] < 1e-3 and data["ik"]["velocity_limit_violations"] == 0
    header = next(csv.reader(open(log)))
    description = as_robot(name)
    assert f"q_{description.leg('left').knee}" in header and f"qref_{description.arm_swing[0].joint}" in header


def test_simulate_prints_the_robot_s_scenario(capsys):
    assert main(["simulate", "--robot", "default", "--print-scenario"]) == 0
    assert yaml.safe_load(capsys.readouterr().out)["robot"] == "default"


@needs_robots
def test_the_com_height_range_is_the_robot_s(capsys):
    assert main(["simulate", "--kinematic", "--robot", "g1", "--com-height", "0.8"]) == 2
    assert "com_height must be in (0.387, 0.703] m for robot 'g1'" in capsys.readouterr().err
    assert main(["simulate", "--kinematic", "--robot", "talos", "--estop-time", "3.565"]) == 0  # 0.87 m


def _bad_robot(tmp_path, change):
    document = yaml.safe_load(built_in_path("default").read_text())
    document["model"] = str(load_robot("default").model)
    change(document)
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(document))
    return path


@pytest.mark.parametrize("change, message", [
    (lambda d: d["left_foot"].update(body="l_sole_frame"), "left_foot.body: body 'l_sole_frame' is not in the model"),
    (lambda d: d["right_leg"].update(knee="r_knee_joint"), "right_leg.knee: joint 'r_knee_joint' is not in the model"),
    (lambda d: d["left_foot"].update(toe=0.0), "left_foot: toe must be a positive"),
    (lambda d: d.update(model="missing.urdf"), "model: cannot read the model file"),
])
def test_a_bad_robot_description_exits_2_naming_the_field(tmp_path, capsys, change, message):
    path = _bad_robot(tmp_path, change)
    assert main(["simulate", "--kinematic", "--robot", str(path)]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_an_unparseable_model_file_exits_2_naming_the_model(tmp_path, capsys):
    (tmp_path / "broken.urdf").write_text("<robot name='x'><link name='a'>")
    path = _bad_robot(tmp_path, lambda d: d.update(model=str(tmp_path / "broken.urdf")))
    assert main(["simulate", "--robot", str(path)]) == 2
    assert "model: cannot read the model file" in capsys.readouterr().err
