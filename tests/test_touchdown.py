"""Touchdown by contact (drake_estop.physics.touchdown): a sole the reference has on the floor that reaches it
and finds none keeps coming down until it carries weight, and stays there. The depth's law, the LeafSystem in
isolation (a default context, FixValue inputs, EvalUniquePeriodicDiscreteUpdate), its place in the online
diagram, and a floor lower than the plan's in physics."""

import numpy as np
import pytest

from drake_estop.physics.controller_options import ControllerOptions, TouchdownConfig
from drake_estop.physics.touchdown import TouchdownByContact, next_depth

SETTINGS = {"dt": 0.005, "descent_speed": 0.1, "max_depth": 0.015, "return_time": 0.1, "grace_time": 0.02}
LEVEL = [1.0, 0.0, 0.0, 0.0]


def test_a_landing_sole_that_carries_no_weight_past_the_grace_time_comes_down_to_the_most_depth():
    depth, landed, down_time, depths = 0.0, False, 0.0, []
    for _ in range(44):
        depth, landed, down_time = next_depth(depth, landed, down_time, planned_down=True, loaded=False,
                                              floor_missing=True, **SETTINGS)
        depths.append(depth)
    assert not landed and down_time == pytest.approx(0.22)
    assert depths[3] == 0.0 and depths[4] == pytest.approx(0.0005)  # 20 ms of grace, then 0.1 m/s
    assert depths[13] == pytest.approx(0.005) and max(depths) == depths[-1] == 0.015  # capped
    depth, landed, _ = next_depth(0.004, False, 0.1, planned_down=True, loaded=True, floor_missing=True, **SETTINGS)
    assert landed and depth == 0.004  # the touchdown: the floor is there, the depth is held


def test_a_sole_held_above_the_floor_is_not_lowered():
    """Unloaded past its grace but estimated above the plan's floor: the body's tilt holds it up, not a
    lower floor."""
    depth, landed, down_time = next_depth(0.0, False, 0.1, planned_down=True, loaded=False, floor_missing=False,
                                          **SETTINGS)
    assert depth == 0.0 and not landed and down_time == pytest.approx(0.105)


def test_a_landed_sole_that_unloads_is_not_pushed_down_and_a_lifted_one_starts_again():
    depth, landed, _ = next_depth(0.004, True, 0.5, planned_down=True, loaded=False, floor_missing=True,
                                  **SETTINGS)  # rocking
    assert landed and depth == 0.004
    depth, landed, down_time = next_depth(0.004, True, 0.5, planned_down=False, loaded=True, floor_missing=True,
                                          **SETTINGS)
    assert depth == pytest.approx(0.004 * 0.95) and not landed and down_time == 0.0  # the swing


def _system_context(left_force, right_lift=0.0, left_height=-0.002):
    """The system with the left foot put down after a swing (not landed yet, estimated ``left_height`` above
    the floor) and the right one standing."""
    system = TouchdownByContact(servo_period=0.005)
    context = system.CreateDefaultContext()
    system.sole_heights_port.FixValue(context, [left_height, 0.0])
    system.feet_in_ports[0].FixValue(context, [0.3, 0.1, 0.05, *LEVEL])
    system.feet_in_ports[1].FixValue(context, [0.0, -0.1, right_lift, *LEVEL])
    system.foot_ft_port.FixValue(context, [0, 0, 0, 0, 0, left_force, 0, 0, 0, 0, 0, 300.0])
    _advance(system, context, 1)  # the left foot swings
    system.feet_in_ports[0].FixValue(context, [0.3, 0.1, 0.0, *LEVEL])  # and is put down
    return system, context


def _advance(system, context, ticks):
    for _ in range(ticks):
        context.SetDiscreteState(system.EvalUniquePeriodicDiscreteUpdate(context))


def test_the_system_lowers_the_landing_sole_only():
    """The left sole is put down in the reference but reads 10 N: after the 20 ms grace its target goes down
    0.5 mm a tick; the right one, standing, carries 300 N and stays."""
    system, context = _system_context(left_force=10.0)
    _advance(system, context, 10)
    np.testing.assert_allclose(system.touchdown_depth_port.Eval(context), [0.003, 0.0], atol=1e-12)
    left = system.feet_out_ports[0].Eval(context)
    assert left[2] == pytest.approx(-0.003) and list(left[:2]) == [0.3, 0.1] and list(left[3:]) == LEVEL
    assert system.feet_out_ports[1].Eval(context)[2] == 0.0


def test_the_system_leaves_a_sole_the_body_holds_above_the_floor():
    system, context = _system_context(left_force=10.0, left_height=0.008)
    _advance(system, context, 10)
    np.testing.assert_array_equal(system.touchdown_depth_port.Eval(context), [0.0, 0.0])
    system.sole_heights_port.FixValue(context, [-0.002, 0.0])  # it came down past the floor: found nothing
    _advance(system, context, 2)
    assert system.touchdown_depth_port.Eval(context)[0] == pytest.approx(0.001)


def test_weight_stops_the_descent_and_a_swing_takes_the_depth_back():
    system, context = _system_context(left_force=10.0)
    _advance(system, context, 8)
    assert system.touchdown_depth_port.Eval(context)[0] == pytest.approx(0.002)
    system.foot_ft_port.FixValue(context, [0, 0, 0, 0, 0, 200.0, 0, 0, 0, 0, 0, 300.0])
    _advance(system, context, 1)
    system.foot_ft_port.FixValue(context, [0, 0, 0, 0, 0, 0.0, 0, 0, 0, 0, 0, 500.0])  # rocks off it
    _advance(system, context, 5)
    assert system.touchdown_depth_port.Eval(context)[0] == pytest.approx(0.002)  # held: no new descent
    system.feet_in_ports[0].FixValue(context, [0.3, 0.1, 0.02, *LEVEL])  # the reference lifts it
    _advance(system, context, 20)
    return_rate = 1.0 - 0.005 / 0.3
    assert system.touchdown_depth_port.Eval(context)[0] == pytest.approx(0.002 * return_rate ** 20)
    assert system.feet_out_ports[0].Eval(context)[2] == pytest.approx(0.02 - system.touchdown_depth_port.Eval(
        context)[0])


@pytest.mark.parametrize("name, value", [("descent_speed", 0.0), ("max_depth", -0.01), ("contact_force", np.nan),
                                         ("return_time", True), ("servo_period", 0.0),
                                         ("below_floor", -0.001)])
def test_bad_settings_raise_naming_them(name, value):
    with pytest.raises(ValueError, match=name):
        TouchdownByContact(**{name: value})


def test_the_online_diagram_has_it_unless_the_controller_turns_it_off():
    from drake_estop.physics.online import build_online_diagram, controller_stop_parameters
    from drake_estop.planning.gait import NominalPattern

    on = build_online_diagram(NominalPattern(), controller_stop_parameters(), None,
                              controller=ControllerOptions(touchdown=TouchdownConfig(max_depth=0.01)))
    system = on.diagram.GetSubsystemByName("touchdown_by_contact")
    assert system._settings["max_depth"] == 0.01 and "touchdown_depth" in on.loggers
    ik = on.diagram.GetSubsystemByName("whole_body_ik")
    context = on.diagram.CreateDefaultContext()
    estimator = on.diagram.GetSubsystemByName("state_estimator")
    np.testing.assert_array_equal(system.sole_heights_port.Eval(system.GetMyContextFromRoot(context)),
                                  estimator.sole_heights_port.Eval(estimator.GetMyContextFromRoot(context)))
    np.testing.assert_array_equal(ik.GetInputPort("left_foot").Eval(ik.GetMyContextFromRoot(context)),
                                  system.feet_out_ports[0].Eval(system.GetMyContextFromRoot(context)))
    assert build_online_diagram(NominalPattern(), controller_stop_parameters(), None).diagram.HasSubsystemNamed(
        "touchdown_by_contact")  # on by default
    off = build_online_diagram(NominalPattern(), controller_stop_parameters(), None,
                               controller=ControllerOptions(touchdown=None))
    assert not off.diagram.HasSubsystemNamed("touchdown_by_contact") and "touchdown_depth" not in off.loggers


@pytest.mark.slow
def test_a_floor_10_mm_lower_under_the_landing_spot_still_stops():
    """The paper's 3.4 s stop with the floor 10 mm lower under its landing spot (``--floor-drop``), the default
    controller (the touchdown by contact on): the landing sole finds the floor 0.1 s after the plan's
    touchdown and stays on it, and the stop meets every criterion. (Without it the foot hovers over the hole
    while the plan moves the ZMP onto it, and the robot falls: benchmarks/FLOOR_DROP.md.)"""
    from drake_estop.physics.online import run_online
    from drake_estop.physics.perturbations import Perturbations
    from drake_estop.physics.plant import FloorDrop
    from drake_estop.planning.gait import NominalPattern
    from drake_estop.planning.planner import StopParameters, plan_stop

    plan = plan_stop(NominalPattern(), 3.4, StopParameters())
    x, y = plan.landing_position
    drop = FloorDrop(x - 0.2, x + 0.2, y - 0.09, y + 0.09, 0.01)
    result = run_online(estop_time=3.4, perturbations=Perturbations(floor_drop=drop))
    assert result.success, [name for name, ok in result.criteria.items() if not ok]
    side = plan.landing_foot
    loaded = result.times[(result.foot_forces[side] > 50.0) & (result.times > plan.landing_time - 0.05)]
    assert loaded[0] > plan.landing_time + 0.05  # it found the floor late
    assert result.feet_meas[side][-1, 2] == pytest.approx(-0.01, abs=1e-3)  # and stands on it
