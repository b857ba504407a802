"""CapturabilityMonitor: the verdict at every servo tick from the measured state, tested in isolation (fixed
inputs, Simulator.AdvanceTo); in the online run: tests/test_online.py."""

import math

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from drake_estop.physics.perturbations import Push
from drake_estop.planning.capturability import SteppingLimits, capturability, swing_touchdown_time
from drake_estop.planning.gait import Sole
from drake_estop.planning.plan import StopParameters
from drake_estop.systems.capturability_monitor import (
    FIELDS,
    CapturabilityMonitor,
    capturability_summary,
    report_time,
)

OMEGA = math.sqrt(9.81 / 0.814)
PARAMS = StopParameters()
LIMITS = SteppingLimits.from_parameters(PARAMS, Sole())
LEFT, RIGHT = np.array([0.0, 0.095]), np.array([0.3, -0.095])
SOLE_FLAT = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]


def run_monitor(com, com_vel, loaded, swing_height=0.03, *, report=0.0, until=0.012, left_yaw=0.0):
    monitor = CapturabilityMonitor(omega=OMEGA, limits=LIMITS, params=PARAMS, report_time=report)
    context = monitor.CreateDefaultContext()
    monitor.measured_com_port.FixValue(context, [*com, 0.814])
    monitor.measured_com_vel_port.FixValue(context, [*com_vel, 0.0])
    monitor.measured_feet_port.FixValue(context, [*LEFT, *RIGHT, *loaded])
    lifted = list(SOLE_FLAT)
    lifted[2] = swing_height
    turned = [*SOLE_FLAT[:3], math.cos(left_yaw / 2), 0.0, 0.0, math.sin(left_yaw / 2)]
    monitor.foot_ports["left"].FixValue(context, turned if loaded[0] else lifted)
    monitor.foot_ports["right"].FixValue(context, SOLE_FLAT if loaded[1] else lifted)
    simulator = Simulator(monitor, context)
    simulator.AdvanceTo(until)
    return monitor, context


def test_single_support_verdict_is_the_functions_on_the_loaded_sole():
    """The left sole loaded, the DCM 2 cm past its outer edge: a crossover step catches it (one step), as
    capturability() says on the same state with the swing's least touchdown from its commanded height."""
    dcm_y = LEFT[1] + Sole().outer + 0.02
    com, com_vel = [0.05, dcm_y - 0.1], [0.0, 0.1 * OMEGA]
    monitor, context = run_monitor(com, com_vel, loaded=(2.0, 0.0))
    output = monitor.capturability_port.Eval(context)
    expected = capturability([0.05, dcm_y], omega=OMEGA, stance_ankle=LEFT, stance_side="left", limits=LIMITS,
                             first_step_time=swing_touchdown_time(PARAMS, 0.03), swing_foot=RIGHT)
    assert expected.steps == 1
    assert output == pytest.approx([expected.steps, expected.margin, expected.margin_speed])
    reported = monitor.reported(context)
    assert reported.steps == 1 and reported.witness[0].side == "right"
    assert reported.witness[0].region == "crossover ahead"


def test_both_soles_loaded_is_double_support_over_the_hull():
    """Between the feet, outside either sole: captured in 0 steps with both loaded, not with one."""
    com = (LEFT + RIGHT) / 2
    both = run_monitor(com, [0.0, 0.0], loaded=(2.0, 2.0))
    one = run_monitor(com, [0.0, 0.0], loaded=(2.0, 0.0))
    assert both[0].capturability_port.Eval(both[1])[0] == 0
    assert one[0].capturability_port.Eval(one[1])[0] >= 1


def test_the_stance_soles_commanded_heading_turns_its_rectangle():
    """A COG at rest 12 cm to the left of the left ankle: past the sole's outer edge (8.1 cm) when the sole
    heads along x, inside its toe (13.5 cm) when it is turned a quarter turn to the left."""
    com = [LEFT[0], LEFT[1] + 0.12]
    straight = run_monitor(com, [0.0, 0.0], loaded=(2.0, 0.0))
    turned = run_monitor(com, [0.0, 0.0], loaded=(2.0, 0.0), left_yaw=math.pi / 2)
    assert straight[0].capturability_port.Eval(straight[1])[0] != 0
    assert turned[0].capturability_port.Eval(turned[1])[0] == 0


def test_report_waits_for_its_time():
    monitor, context = run_monitor([0.0, 0.095], [0.0, 0.0], loaded=(2.0, 2.0), report=0.5, until=0.1)
    assert monitor.reported(context) is None


def test_report_time_is_the_later_of_signal_and_last_push():
    assert report_time(3.4, [Push(3.2, 0.0, 290.0, 0.1)]) == pytest.approx(3.4)
    assert report_time(3.0, [Push(3.2, 0.0, 290.0, 0.1), Push(2.0, 10.0, 0.0, 0.1)]) == pytest.approx(3.3)
    assert report_time(None) == math.inf


def test_summary_gives_the_worst_tick_from_the_signal_on():
    rows = np.array([[1, 0.01, 0.03], [-1, -0.5, -1.7], [0, 0.02, 0.07], [1, 0.005, 0.017], [np.nan] * 3])
    summary = capturability_summary(None, rows, 0.005, since=0.01)  # the signal at tick 2
    assert summary["steps"] is None and summary["witness"] == []
    assert summary["worst"] == {"time": pytest.approx(0.015), "steps": 1, "margin": 0.005, "margin_speed": 0.017}
    assert len(FIELDS) == rows.shape[1]
    # a fall at 0.014 s: the ticks from then on are left out (tick 3's margin would be the least otherwise)
    rows[3, 1] = -0.9
    assert capturability_summary(None, rows, 0.005, since=0.01, until=0.014)["worst"]["margin"] == 0.02
    assert capturability_summary(None, rows, 0.005, since=0.01, until=0.01)["worst"] is None


def test_fall_time_is_the_first_tilt_past_the_limit():
    from types import SimpleNamespace

    from drake_estop.physics.criteria import fall_time
    from drake_estop.physics.plant import PhysicsParameters

    physics = PhysicsParameters()
    times = np.arange(5) * 0.1
    tilted = SimpleNamespace(times=times, torso_tilt=np.array([0.0, 0.1, physics.max_torso_tilt, 0.1, 0.5]))
    assert fall_time(tilted, physics) == pytest.approx(0.2)
    assert fall_time(SimpleNamespace(times=times, torso_tilt=np.zeros(5)), physics) == math.inf
