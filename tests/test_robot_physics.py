"""Any described humanoid through the physics path: the simulated plant, sensors, estimator, compliance,
pushes and criteria read the robot's description (``robot=``), the command line's ``--physics --robot`` and
``sweep --robot`` run it, and the G1 and TALOS stop in physics (slow)."""

import dataclasses
import math

import numpy as np
import pytest
from pydrake.systems.framework import DiagramBuilder
from robot_helpers import needs_robots

from drake_estop.cli import main
from drake_estop.physics.compliance import FootEdgeCompliance
from drake_estop.physics.criteria import CRITERIA
from drake_estop.physics.estimation import StateEstimator
from drake_estop.physics.online import build_online_diagram, robot_stop_parameters
from drake_estop.physics.perturbations import PelvisPush
from drake_estop.physics.plant import (
    DEFAULT_PELVIS_HEIGHT_BOUNDS,
    PhysicsParameters,
    add_physics_plant,
    pelvis_height_bounds,
    sole_bodies,
)
from drake_estop.planning.gait import NominalPattern
from drake_estop.robots import load_robot
from drake_estop.robots.parameters import gait_parameters

EXTERNAL = [pytest.param(name, marks=needs_robots) for name in ("g1", "talos")]


def test_the_default_robot_keeps_its_criteria_and_gains():
    """The default humanoid's pelvis bounds and servo gains are the ones its physics results were measured with."""
    assert pelvis_height_bounds() == pelvis_height_bounds("default") == DEFAULT_PELVIS_HEIGHT_BOUNDS == (0.45, 0.80)
    assert PhysicsParameters().for_robot().pelvis_height_bounds == (0.45, 0.80)
    assert PhysicsParameters(pelvis_height_bounds=(0.1, 2.0)).for_robot("default").pelvis_height_bounds == (0.1, 2.0)
    assert PhysicsParameters().gain("l_knee") == 3e4 and PhysicsParameters().gain("l_elbow") == 1e3


@pytest.mark.parametrize("name", EXTERNAL)
def test_the_physics_plant_is_the_robot_s(name):
    """The simulated plant holds the described robot with its sole contact, its servo gains and its soles
    as the CoP estimator's bodies; the pelvis bounds scale with its floating base's height."""
    robot = load_robot(name)
    plant, scene_graph, instance, _ = add_physics_plant(DiagramBuilder(), PhysicsParameters(), robot)
    assert [body.name() for body in sole_bodies(plant, robot)] == [robot.left_foot.body, robot.right_foot.body]
    knee = plant.GetJointByName(robot.left_leg.knee)
    actuator = next(plant.get_joint_actuator(i) for i in plant.GetJointActuatorIndices()
                    if plant.get_joint_actuator(i).joint().index() == knee.index())
    gains = actuator.get_controller_gains()
    assert (gains.p, gains.d) == (robot.servo_gain(robot.left_leg.knee).kp, robot.servo_gain(robot.left_leg.knee).kd)
    names = {scene_graph.model_inspector().GetName(g) for g in scene_graph.model_inspector().GetAllGeometryIds()}
    assert any(n.endswith("left_sole_toe_outer") for n in names) and any(n.endswith("right_sole_box") for n in names)
    low, high = pelvis_height_bounds(robot)
    assert 0.0 < low < high and low != 0.45


@pytest.mark.parametrize("name", EXTERNAL)
def test_the_controller_blocks_read_the_robot(name):
    """The online diagram of another robot builds, and its blocks name that robot's bodies and joints (each
    raised on the default humanoid's names before)."""
    robot = load_robot(name)
    pattern = NominalPattern(gait_parameters(robot))
    handles = build_online_diagram(pattern, robot_stop_parameters(robot), 3.3, robot=robot)
    assert handles.robot == robot and handles.physics.pelvis_height_bounds == pelvis_height_bounds(robot)
    plant = handles.plant
    base = plant.GetBodyByName(robot.floating_base)
    assert handles.push is not None and isinstance(handles.push, PelvisPush)
    assert handles.push._body_index == base.index()
    assert isinstance(handles.compliance, FootEdgeCompliance) and isinstance(handles.estimator, StateEstimator)
    assert handles.estimator._omega == pytest.approx(math.sqrt(9.81 / robot.walking_com_height), rel=1e-3)
    # the estimator starts from the robot's initial posture with its soles on the floor
    x0 = handles.estimator.initial_state(handles.initial_q)
    assert np.all(np.isfinite(x0))


def _cli_physics_keywords(monkeypatch, args):
    """The keyword arguments `simulate --physics ARGS` gives run_online (the run itself is cut short), and
    the command's stderr is not a refusal."""
    import drake_estop.physics.online as online

    seen = {}

    def fake_run_online(gait, stop, estop_time, **kwargs):
        seen.update(kwargs, gait=gait)
        raise RuntimeError("stop here")

    monkeypatch.setattr(online, "run_online", fake_run_online)
    main(["simulate", "--physics", *args])
    return seen


@needs_robots
def test_simulate_physics_takes_another_robot(monkeypatch, capsys):
    """``simulate --physics --robot g1`` (and a scenario's ``robot: talos``) runs the online controller on that
    robot with its gait, instead of exiting 2 naming ``robot``."""
    seen = _cli_physics_keywords(monkeypatch, ["--estop-time", "3.3", "--robot", "g1"])
    assert "robot: " not in capsys.readouterr().err
    assert seen["robot"].name == "g1" and seen["gait"].com_height == load_robot("g1").walking_com_height
    seen = _cli_physics_keywords(monkeypatch, ["--estop-time", "3.4", "--scenario-text", "{robot: talos}"])
    assert seen["robot"].name == "talos"


@needs_robots
def test_sweep_takes_another_robot(monkeypatch, tmp_path, capsys):
    """``sweep --robot g1`` gives every run the robot (it exited 2 naming ``robot`` before)."""
    import drake_estop.physics.sweep as sweep_module

    seen = {}

    def fake_sweep(gait, stop, **kwargs):
        seen.update(kwargs, gait=gait)
        return [{"signal_time": 3.0, "success": True}]

    monkeypatch.setattr(sweep_module, "sweep", fake_sweep)
    code = main(["sweep", "--no-progress", "--robot", "g1", "--csv", str(tmp_path / "s.csv"), "--png",
                 str(tmp_path / "s.png")])
    assert "robot: " not in capsys.readouterr().err
    assert code == 0 and seen["robot"].name == "g1" and seen["gait"].step_width == load_robot("g1").step_width


def _criteria_report(result) -> str:
    numbers = result.numbers()
    return (f"{result.criteria}, pelvis {numbers['pelvis_z_min_m']:.3f}-{numbers['pelvis_z_max_m']:.3f} m, "
            f"tilt {numbers['torso_tilt_max_rad']:.3f}, slip {max(result.slip.values()):.4f} m, rest after halt "
            f"{numbers['rest_after_halt_s']:.2f} s, offset {numbers['final_cog_offset_m']:.4f} m, CoP margin "
            f"{numbers['cop_margin_plan_min_m']:.4f} m, violations {result.online['joint_velocity_violations']}")


def _assert_stops(result, support):
    assert result.plan.support == support
    assert set(result.criteria) == set(CRITERIA)
    assert result.success, _criteria_report(result)
    assert result.online["joint_velocity_violations"] == 0


#: The G1 that walks its stride in physics: 1.0 s steps, the walk's ZMP 3 cm ahead of the ankle, the feet's
#: force difference control at 8000 N s/m (its description's gait falls in its second step; g1.yaml says why
#: these are not its own).
G1_WALKING = {"step_time": 1.0, "walking_zmp_offset": 0.03, "foot_force_damping": 8000.0}

#: The G1 on its own gait (0.79 s, 0.27 m steps): the walk's COG corrected for the limbs' momentum (the
#: controller's whole_body_walk), the feet's force control at 8000 N s/m and a 10 mrad swing-tilt dead band.
G1_OWN_WALK = {"foot_force_damping": 8000.0, "swing_tilt_deadband": 0.01}


def _run(name, estop_time, push=None, controller=None, **changes):
    """run_online of robot ``name`` (its description with ``changes``) with its own gait and stop parameters;
    ``push`` (fx, fy sign) pushes the floating base at the signal with 0.3 m/s times the robot's mass [N s]
    over 0.1 s; ``controller``: ControllerOptions fields."""
    from drake_estop.physics.online import run_online
    from drake_estop.physics.perturbations import Perturbations, Push
    from drake_estop.robots.measure import robot_facts

    robot = dataclasses.replace(load_robot(name), **changes)
    perturbations = None
    if push is not None:
        force = 0.3 * robot_facts(robot).mass / 0.1  # [N] over 0.1 s: a 0.3 m/s change of the COG velocity
        perturbations = Perturbations(pushes=(Push(estop_time, push[0] * force, push[1] * force, 0.1),))
    from drake_estop.physics.controller_options import ControllerOptions

    return run_online(estop_time=estop_time, robot=robot, perturbations=perturbations,
                      controller=ControllerOptions(**(controller or {})))


@pytest.mark.slow
@needs_robots
@pytest.mark.parametrize("estop_time, support", [(3.4, "single"), (0.8, "double"), (2.97, "single"),
                                                 (3.67, "double")])
def test_talos_stops_in_physics(estop_time, support):
    """TALOS walks its own gait on the contact plant (its description's servo gains and foot force control)
    and stops from single support of its third step (2.97 s, its first tick), from its double support (3.67 s,
    its first tick) and from double support while it shifts its weight before the first step, meeting
    every criterion, no joint over its velocity limit. Without the feet's force difference control 2.97 and
    3.67 s fell, and the double support's other stops passed with 0.1-0.2 mm of CoP margin (5.8-6.8 mm with
    it)."""
    _assert_stops(_run("talos", estop_time), support)


@pytest.mark.slow
@needs_robots
def test_talos_stops_after_a_forward_push_at_the_signal():
    """A forward push of 0.3 m/s times TALOS's 90.3 kg (27.1 N s) on its base at a single-support signal: it
    still stops meeting every criterion."""
    _assert_stops(_run("talos", 3.4, push=(1.0, 0.0)), "single")


@pytest.mark.slow
@needs_robots
def test_talos_steps_out_of_a_forward_push_at_its_first_double_support_tick():
    """27.1 N s forward at 3.67 s, the touchdown of the third step: no double-support stop exists (the COG
    would come to rest 0.39 m ahead of the rear ankle, past its 0.29 m reach), and the DCM, 5 cm past the
    fore ankle, lies 5.3 cm towards the rear foot, past the fore sole's inner edge less the margin (4 cm),
    as the weight moves onto the fore foot. TALOS's description takes the recovery step there
    (``recovery_step_inward``), landing where the LIPM's DCM is between the feet at its touchdown; with the
    default humanoid's rule (no step) it falls."""
    result = _run("talos", 3.67, push=(1.0, 0.0))
    _assert_stops(result, "double")
    summary = result.plan.summary()
    assert summary["recovery_steps"] == 1 and summary["steps_after_signal"] == 1
    assert result.plan.final_feet["left"][0] > result.plan.final_feet["right"][0]  # the rear foot stepped
    standing = _run("talos", 3.67, push=(1.0, 0.0), recovery_step_inward=False)
    assert standing.plan.summary()["recovery_steps"] == 0 and not standing.criteria["no_fall"]


@pytest.mark.slow
@needs_robots
def test_g1_stops_after_a_forward_push_in_the_weight_shift():
    """A forward push of 0.3 m/s times the G1's 33.3 kg (10.0 N s) on its pelvis at a double-support signal."""
    _assert_stops(_run("g1", 0.8, push=(1.0, 0.0)), "double")


@pytest.mark.slow
@needs_robots
def test_g1_stops_in_physics_from_the_weight_shift():
    """The G1 on the contact plant (its description's gains, its 0.167 x 0.056 m soles) stops from double
    support while it shifts its weight before the first step, meeting every criterion."""
    _assert_stops(_run("g1", 0.8), "double")


@pytest.mark.slow
@needs_robots
@pytest.mark.parametrize("estop_time", [1.5, 1.7])
def test_g1_stops_in_physics_from_single_support(estop_time):
    """The G1 stops from single support of its first step (lift-off 1.25 s, touchdown 1.88 s) meeting every
    criterion with no joint over its velocity limit: on its measured soles (0.167 x 0.056 m) with its own
    ZMP margin, swing-tilt dead band and foot-edge band (it fell after the landing before, its open-loop
    walk rolling onto the 2 cm stance-foot edge)."""
    _assert_stops(_run("g1", estop_time), "single")


@pytest.mark.slow
@needs_robots
@pytest.mark.parametrize("estop_time, support", [(3.6, "single"), (4.15, "double")])
def test_g1_walks_and_stops_in_its_third_step(estop_time, support):
    """The G1 with 1.0 s steps, its walk's ZMP 3 cm ahead of the ankle and the feet's force difference
    control (:data:`G1_WALKING`) walks its stride in physics and stops from its third step's single support
    (3.25-4.05 s) and double support (4.05-4.25 s) meeting every criterion, no joint over its velocity
    limit. Without the force control it falls at both signals; its own 0.79 s walk falls in the second
    step (the landed foot hovered over the floor through the double support, the robot then rolled out
    over the new stance foot's outer edge)."""
    _assert_stops(_run("g1", estop_time, **G1_WALKING), support)


def test_the_default_robot_keeps_the_controller_s_settings():
    """The default humanoid's stop parameters and the controller blocks' settings are the controller's
    constants and its gait's ZMP is at the ankle; its only settings of its own are the feet's force control
    (its damping and engage time) and J_ds's ZMP weight."""
    from drake_estop.physics.online import controller_settings, controller_stop_parameters
    from drake_estop.robots.parameters import default_robot

    own = {name: value for name, value in controller_settings().items() if value is not None}
    assert own == {"foot_force_damping": 80000.0, "foot_force_engage_time": 0.2, "zmp_weight": 1000.0}
    assert gait_parameters(default_robot()).zmp_offset == 0.0
    assert robot_stop_parameters() == controller_stop_parameters() == controller_stop_parameters(robot="default")


@needs_robots
def test_the_g1_controller_settings_come_from_its_description():
    """The G1's description sets its stop plan's ZMP margin, the swing-tilt dead band and the foot-edge band
    (its soles are 0.056 m wide against the default's 0.136 m); TALOS keeps the controller's."""
    from drake_estop.physics.online import FOOT_EDGE_COMPLIANCE, SWING_TILT_COMPENSATION, controller_stop_parameters

    robot = load_robot("g1")
    assert robot.stop_zmp_margin is not None and robot.stop_zmp_margin < min(robot.sole().inner, robot.sole().outer)
    assert robot_stop_parameters(robot).zmp_margin == robot.stop_zmp_margin
    assert robot_stop_parameters("talos").zmp_margin == 0.03
    # J_ds's ZMP weight: the default humanoid's own, the paper's on the G1 and TALOS
    assert robot.stop_zmp_weight is None and robot_stop_parameters(robot).a_ds == 50.0
    assert robot_stop_parameters("talos").a_ds == 50.0 != controller_stop_parameters().a_ds
    handles = build_online_diagram(NominalPattern(gait_parameters(robot)), robot_stop_parameters(robot), 1.5,
                                   robot=robot)
    assert handles.swing_tilt._deadband == robot.swing_tilt_deadband != SWING_TILT_COMPENSATION.deadband
    assert robot.foot_edge_margin != FOOT_EDGE_COMPLIANCE.edge_margin
    assert handles.compliance._safe[0][0] == pytest.approx(-robot.sole().heel + robot.foot_edge_margin)
    assert handles.foot_force is None and gait_parameters(robot).zmp_offset == 0.0
    # a description's foot_force_damping puts the feet's force difference control between the swing-tilt
    # compensation and the IK; its walking_zmp_offset is the gait's zmp_offset
    walking = dataclasses.replace(robot, **G1_WALKING)
    handles = build_online_diagram(NominalPattern(gait_parameters(walking)), robot_stop_parameters(walking), 1.5,
                                   robot=walking)
    assert handles.foot_force is not None and handles.foot_force._damping == walking.foot_force_damping
    assert "foot_height_difference" in handles.loggers
    assert gait_parameters(walking).zmp_offset == walking.walking_zmp_offset == 0.03


@needs_robots
@pytest.mark.parametrize("field", ["walking_zmp_offset", "foot_force_damping"])
def test_the_walking_settings_are_checked(field):
    """The description's walking ZMP offset and foot force damping must be positive; an offset beyond the
    toe is refused by the gait, naming its field."""
    robot = load_robot("g1")
    with pytest.raises(ValueError, match=field):
        dataclasses.replace(robot, **{field: -1.0})
    with pytest.raises(ValueError, match="zmp_offset"):
        gait_parameters(dataclasses.replace(robot, walking_zmp_offset=robot.sole().toe + 0.01))


@pytest.mark.slow
@needs_robots
@pytest.mark.parametrize("estop_time, support", [(3.55, "double"), (5.5, "single")])
def test_g1_walks_its_own_gait_on_the_corrected_walk(estop_time, support):
    """The G1's own 0.79 s walk stands in physics once its COG is corrected for the limbs' momentum
    (``ControllerOptions(whole_body_walk=True)``) with the feet's force control and a 10 mrad swing-tilt dead
    band (:data:`G1_OWN_WALK`; at 2 mrad the compensation lowered the swing foot onto the floor 30 ms early and
    it bounced): it stops from its third step's double support (3.55 s) and its sixth step's single support
    (5.5 s) meeting every criterion. Its third step's single-support stops still fail (the stop itself is not
    corrected: the CoP leaves the support by a millimetre or the foot bounces at the landing; 3.0 s falls)."""
    _assert_stops(_run("g1", estop_time, controller={"whole_body_walk": True}, **G1_OWN_WALK), support)


@pytest.mark.slow
@needs_robots
def test_g1_own_gait_falls_on_the_lipm_cog():
    """The counterfactual: the same settings on the LIPM's COG fall in the walk, before the 5.5 s signal."""
    result = _run("g1", 5.5, **G1_OWN_WALK)
    assert not result.criteria["no_fall"]
    tilted = result.times[np.argmax(np.abs(result.torso_tilt) > 0.1)]
    assert tilted < 5.5
