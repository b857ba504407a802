"""MeasuredComFilter on its own (Drake's way: a context, fixed inputs, the periodic update) and in the stop
planner's place: the low-pass, the bias learnt while walking and frozen at the latch, no measurement."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from drake_estop.planning.gait import NominalPattern
from drake_estop.systems.measured_com_filter import MeasuredComFilter

DT = 0.005


@pytest.fixture(scope="module")
def pattern():
    return NominalPattern()


def _simulator(pattern, t0, com, com_vel, stop=(0.0, np.nan), **kwargs):
    system = MeasuredComFilter(pattern=pattern, servo_period=DT, **kwargs)
    simulator = Simulator(system)
    context = simulator.get_mutable_context()
    context.SetTime(t0)
    system.measured_com_port.FixValue(context, np.asarray(com, float))
    system.measured_com_vel_port.FixValue(context, np.asarray(com_vel, float))
    system.stop_port.FixValue(context, np.asarray(stop, float))
    simulator.Initialize()
    return system, simulator, context


def test_the_first_tick_passes_the_measurement_and_later_ticks_low_pass_it(pattern):
    """Tick 1: the measurement itself (no bias yet: latched). A step of 1 cm then reaches the output by
    alpha = dt / (tau + dt) per tick (eq. of a first-order low-pass), the heights pass through."""
    system, simulator, context = _simulator(pattern, 3.0, [1.0, 0.1, 0.8], [0.4, 0.0, 0.01], stop=(1.0, 2.9))
    np.testing.assert_array_equal(system.com_port.Eval(context), [1.0, 0.1, 0.8])
    simulator.AdvanceTo(3.0 + DT / 2)  # the update of tick 3.0 keeps the filtered COG
    system.measured_com_port.FixValue(context, np.array([1.01, 0.1, 0.8]))
    alpha = DT / (0.03 + DT)
    np.testing.assert_allclose(system.com_port.Eval(context), [1.0 + alpha * 0.01, 0.1, 0.8], atol=1e-15)
    np.testing.assert_array_equal(system.com_vel_port.Eval(context), [0.4, 0.0, 0.01])


def test_the_bias_is_learnt_while_walking_and_frozen_at_the_latch(pattern):
    """Walking 2 cm ahead of the pattern for 1 s (bias time constant 0.5 s; the low-pass made negligible, as
    its lag behind the moving COG would add to the offset): the bias learns 1 - (1 - beta)^n of the offset,
    and the output comes back towards the pattern by as much; once latched the bias stays."""
    t0 = 2.0
    pos, vel, _, _ = pattern.com([t0])
    system, simulator, context = _simulator(pattern, t0, [*(pos[0] + [0.02, 0.0]), 0.8], [*vel[0], 0.0],
                                            filter_time_constant=1e-9)
    for k in range(200):  # the pattern moves on; the measurement follows it 2 cm ahead
        t = t0 + k * DT
        pos, vel, _, _ = pattern.com([t])
        system.measured_com_port.FixValue(context, np.array([*(pos[0] + [0.02, 0.0]), 0.8]))
        system.measured_com_vel_port.FixValue(context, np.array([*vel[0], 0.0]))
        simulator.AdvanceTo(t + DT / 2)
    beta = DT / (0.5 + DT)
    assert system.bias(context)[0] == pytest.approx(0.02 * (1 - (1 - beta) ** 200), rel=1e-2)
    np.testing.assert_allclose(system.com_port.Eval(context)[0] - pos[0][0], 0.02 - system.bias(context)[0],
                               atol=1e-9)
    learnt = system.bias(context)
    system.stop_port.FixValue(context, np.array([1.0, 3.0]))
    simulator.AdvanceTo(t0 + 1.2)
    np.testing.assert_array_equal(system.bias(context), learnt)


def test_no_measurement_gives_nan_and_keeps_the_state(pattern):
    system, simulator, context = _simulator(pattern, 3.0, [np.nan, 0.0, 0.8], [0.0, 0.0, 0.0])
    assert np.all(np.isnan(system.com_port.Eval(context)))
    simulator.AdvanceTo(3.1)
    np.testing.assert_array_equal(system.bias(context), np.zeros(4))
    system.measured_com_port.FixValue(context, np.array([1.0, 0.1, 0.8]))
    np.testing.assert_array_equal(system.com_port.Eval(context), [1.0, 0.1, 0.8])  # still its first sample


@pytest.mark.parametrize("name", ["servo_period", "filter_time_constant", "bias_time_constant"])
@pytest.mark.parametrize("value", [0.0, -1.0, float("nan"), True])
def test_bad_settings_are_named(pattern, name, value):
    kwargs = {"pattern": pattern, "servo_period": DT, name: value}
    with pytest.raises(ValueError, match=name):
        MeasuredComFilter(**kwargs)
