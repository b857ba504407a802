"""StopPlannerSystem alone, the way Drake tests a LeafSystem: a default context, FixValue inputs,
Simulator.AdvanceTo (shared by the re-plan and recovery-step tests)."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from drake_estop.systems.stop_controller import StopPlannerSystem

DT = 0.005


def latched_stop_planner(pattern, params, t0=3.4, **kwargs):
    """A StopPlannerSystem (no input filtering, re-plans up to every tick; ``kwargs`` override) whose stop latched at
    ``t0`` from the reference, then without a measurement (NaN: no re-plan). Returns the planner, its
    context, the simulator and the first plan."""
    kwargs = {"filter_time_constant": 1e-6, "replan_interval": DT, **kwargs}
    planner = StopPlannerSystem(pattern=pattern, params=params, **kwargs)
    context = planner.CreateDefaultContext()
    pos, vel, _, _ = pattern.com([t0])
    planner.stop_port.FixValue(context, [1.0, t0])
    planner.measured_com_port.FixValue(context, [*pos[0], 0.8])
    planner.measured_com_vel_port.FixValue(context, [*vel[0], 0.0])
    context.SetTime(t0)
    simulator = Simulator(planner, context)
    simulator.AdvanceTo(t0 + DT / 2)
    first = planner.plan(context)
    assert first.start_time == pytest.approx(t0)
    planner.measured_com_port.FixValue(context, [np.nan] * 3)  # no measurement: no re-plan
    return planner, context, simulator, first
