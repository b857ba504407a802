"""The feet's force difference control (physics/foot_force.py): the load split the plan's ZMP asks for, and
the sign of the height correction (an underloaded foot is pressed down, the other raised)."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from drake_estop.physics.foot_force import FootForceDifferenceControl, desired_force_difference

LEFT = [0.0, 0.1, 0.0, 1.0, 0.0, 0.0, 0.0]
RIGHT = [0.3, -0.1, 0.0, 1.0, 0.0, 0.0, 0.0]


def test_the_desired_split_follows_the_zmp_between_the_ankles():
    assert desired_force_difference([LEFT, RIGHT], [0.0, 0.1], 300.0) == pytest.approx(300.0)
    assert desired_force_difference([LEFT, RIGHT], [0.3, -0.1], 300.0) == pytest.approx(-300.0)
    assert desired_force_difference([LEFT, RIGHT], [0.15, 0.0], 300.0) == pytest.approx(0.0)
    assert desired_force_difference([LEFT, RIGHT], [0.5, -0.3], 300.0) == pytest.approx(-300.0)  # clipped
    swinging = [0.3, -0.1, 0.02, 1.0, 0.0, 0.0, 0.0]
    assert desired_force_difference([LEFT, swinging], [0.15, 0.0], 300.0) == pytest.approx(300.0)


def _run(forces, zmp, ticks=20, left=LEFT, planned=None, **settings):
    """The control after ``ticks`` servo ticks with the soles reading ``forces`` (left, right) [N], the
    left sole target ``left`` and, given, the plan's sole targets ``planned`` (left, right); its feet
    outputs and height difference."""
    control = FootForceDifferenceControl(**settings)
    context = control.CreateDefaultContext()
    control.feet_in_ports[0].FixValue(context, left)
    control.feet_in_ports[1].FixValue(context, RIGHT)
    for port, foot in zip(control.planned_feet_ports, planned or ()):
        port.FixValue(context, foot)
    control.zmp_port.FixValue(context, zmp)
    ft = np.zeros(12)
    ft[5], ft[11] = forces
    control.foot_ft_port.FixValue(context, ft)
    Simulator(control, context).AdvanceTo((ticks - 0.5) * 0.005)  # the ticks at 0, 5, ... ms
    feet = [port.Eval(context) for port in control.feet_out_ports]
    return feet, float(control.height_difference_port.Eval(context)[0])


def test_an_underloaded_foot_is_pressed_down():
    """The plan's ZMP midway, all the load on the left foot: the right sole target goes down, the left up,
    by half the height difference each; x, y and the orientation pass through."""
    feet, dz = _run((300.0, 0.0), [0.15, 0.0], damping=8000.0)
    assert dz > 0.0
    assert feet[0][2] == pytest.approx(0.5 * dz) and feet[1][2] == pytest.approx(-0.5 * dz)
    np.testing.assert_array_equal(feet[0][[0, 1, 3, 4, 5, 6]], np.array(LEFT)[[0, 1, 3, 4, 5, 6]])
    # the split as asked: no correction; a bound on the difference
    assert _run((150.0, 150.0), [0.15, 0.0])[1] == 0.0
    assert _run((3000.0, 0.0), [0.15, 0.0], ticks=400, max_offset=0.004)[1] == pytest.approx(0.004)


def test_with_an_engage_time_the_control_waits_for_both_soles_to_stand_that_long():
    """0.2 s to engage: after 20 ticks (0.1 s) on both feet the overloaded left foot is not yet corrected;
    after 60 ticks it is, by the control's own rate from the 40th tick on (0.2 s of standing counted at
    it). A swinging foot holds it off."""
    assert _run((300.0, 0.0), [0.15, 0.0], ticks=20, damping=8000.0, engage_time=0.2)[1] == 0.0
    engaged = _run((300.0, 0.0), [0.15, 0.0], ticks=60, damping=8000.0, engage_time=0.2)[1]
    always = _run((300.0, 0.0), [0.15, 0.0], ticks=21, damping=8000.0)[1]
    assert engaged == pytest.approx(always, rel=1e-12)  # 21 engaged ticks either way
    swinging = [0.0, 0.1, 0.02, 1.0, 0.0, 0.0, 0.0]
    # the left foot swings and carries nothing, as the plan asks: nothing to correct, never engaged
    assert _run((0.0, 300.0), [0.3, -0.1], ticks=60, left=swinging, damping=8000.0, engage_time=0.2)[1] == 0.0
    # a swinging foot loaded against the plan: without an engage time the control acts at once
    assert _run((300.0, 0.0), [0.3, -0.1], ticks=20, left=swinging, damping=8000.0)[1] != 0.0
    assert _run((300.0, 0.0), [0.3, -0.1], ticks=60, left=swinging, damping=8000.0, engage_time=0.2)[1] == 0.0


def test_the_plan_says_which_soles_stand_not_the_adjusted_targets():
    """A landed left foot whose target the swing-tilt compensation still holds 3 mm up (its correction
    decaying) stands in the plan: the control engages after the engage time and presses the underloaded
    left foot down; read from the adjusted targets alone it would wait, and ask for the whole load on
    the right foot. The plan's own feet pass through unchanged: only ``dz`` is added to the inputs."""
    raised = [0.0, 0.1, 0.003, 1.0, 0.0, 0.0, 0.0]
    feet, dz = _run((0.0, 300.0), [0.15, 0.0], ticks=60, left=raised, planned=(LEFT, RIGHT), damping=8000.0,
                    engage_time=0.2)
    assert dz < 0.0  # the right foot raised, the left pressed down
    assert feet[0][2] == pytest.approx(0.003 + 0.5 * dz)
    assert _run((0.0, 300.0), [0.15, 0.0], ticks=60, left=raised, damping=8000.0, engage_time=0.2)[1] == 0.0


def test_the_settings_are_checked():
    with pytest.raises(ValueError, match="damping"):
        FootForceDifferenceControl(damping=0.0)
    with pytest.raises(ValueError, match="engage_time"):
        FootForceDifferenceControl(engage_time=-0.1)
    import dataclasses

    from drake_estop.robots import load_robot

    with pytest.raises(ValueError, match="foot_force_engage_time"):
        dataclasses.replace(load_robot("default"), foot_force_engage_time=-0.2)
    # an engage time times a control that is on: without a damping it is refused
    with pytest.raises(ValueError, match="foot_force_engage_time is given without foot_force_damping"):
        dataclasses.replace(load_robot("default"), foot_force_damping=None)
    DiagramBuilder().AddSystem(FootForceDifferenceControl())


def test_the_default_robot_runs_the_control_and_the_switch_turns_it_off():
    """The default humanoid's description gives a damping: the online diagram puts the control between the
    swing-tilt compensation and the IK, logs its height difference, and ``foot_force=None``
    leaves it out. With ``planned_support`` the plan's feet feed its ``planned_*_foot`` inputs; without,
    they are left unconnected."""
    from drake_estop.physics.controller_options import ControllerOptions
    from drake_estop.physics.online import build_online_diagram, controller_stop_parameters
    from drake_estop.planning.gait import NominalPattern
    from drake_estop.robots import load_robot

    robot = load_robot("default")
    damping, engage = robot.foot_force_damping, robot.foot_force_engage_time
    assert damping is not None and damping > 0 and engage is not None and engage > 0
    pattern, params = NominalPattern(), controller_stop_parameters()
    handles = build_online_diagram(pattern, params, 3.4)
    assert handles.foot_force is not None and handles.foot_force._damping == damping
    assert handles.foot_force._engage == engage
    assert "foot_height_difference" in handles.loggers
    planned = handles.foot_force.planned_feet_ports
    context = handles.foot_force.GetMyContextFromRoot(handles.diagram.CreateDefaultContext())
    assert not any(port.HasValue(context) for port in planned)  # the adjusted targets say which soles stand
    handles = build_online_diagram(pattern, params, 3.4, controller=ControllerOptions().with_changes(
        {"foot_force.planned_support": True}))
    planned = handles.foot_force.planned_feet_ports
    root = handles.diagram.CreateDefaultContext()
    context = handles.foot_force.GetMyContextFromRoot(root)
    assert all(port.HasValue(context) for port in planned)
    np.testing.assert_array_equal(planned[0].Eval(context), handles.planner.GetOutputPort("left_foot").Eval(
        handles.planner.GetMyContextFromRoot(root)))
    handles = build_online_diagram(pattern, params, 3.4, controller=ControllerOptions(foot_force=None))
    assert handles.foot_force is None and "foot_height_difference" not in handles.loggers
    with pytest.raises(ValueError, match="planned_support"):
        ControllerOptions().with_changes({"foot_force.planned_support": "yes"})


#: A campaign run (seed 0, run 280) that rocked: 26.5 N s to the right at 2.956 s, a capture landing, then in
#: the halt the robot stood on its rear heel with the fore sole lifted.
ROCKING_RUN = ["simulate", "--physics", "--estop-time", "3.035", "--step-length", "0.2861", "--step-time", "0.79",
               "--step-width", "0.1959", "--push", "2.956", "41.93", "-262.43", "0.113", "--mass-scale", "0.9584",
               "--torso-mass-scale", "1.0477", "--torso-com-offset", "-0.01665", "--friction", "0.9417",
               "--latency", "1", "--seed", "4655102860825302358"]


@pytest.mark.slow
def test_the_force_control_stops_a_pushed_robot_rocking_off_its_planned_support(tmp_path):
    """The campaign run above meets every criterion with the force control (the default); without it a
    sole the plan stands on unloads in the halt and the CoP leaves the planned support."""
    import json

    from drake_estop.cli import main

    with_control, without = tmp_path / "with.json", tmp_path / "without.json"
    assert main([*ROCKING_RUN, "--summary", str(with_control)]) == 0
    assert main([*ROCKING_RUN, "--summary", str(without),
                 "--scenario-text", "{controller: {foot_force: null}}"]) == 1
    rocked = json.loads(without.read_text())["physics"]
    assert [name for name, ok in rocked["criteria"].items() if not ok] == ["cop_in_support"]
    assert rocked["numbers"]["cop_margin_plan_min_m"] < 0.0
    assert json.loads(with_control.read_text())["physics"]["numbers"]["cop_margin_plan_min_m"] > 0.0
