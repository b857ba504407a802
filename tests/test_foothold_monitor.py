"""FootholdMonitor in isolation (a default context, FixValue inputs, EvalUniquePeriodicDiscreteUpdate's
unrestricted twin through the Simulator): each sole's stage against the plan's footholds, and the soles it
reports as landed again off them."""

import numpy as np
import pytest
from planner_helpers import DT, replan_params
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from drake_estop.planning.gait import NominalPattern
from drake_estop.planning.planner import plan_stop
from drake_estop.systems.foothold_monitor import FootholdMonitor, Relanded, add_foothold_monitor
from drake_estop.systems.plan_sequence import PlanHandle
from drake_estop.systems.stop_controller import StopPlannerSystem
from drake_estop.systems.stop_numerics import SOLE_LIFTED, SOLE_RELANDED, SOLE_STANDING


@pytest.fixture(scope="module")
def plan():
    return plan_stop(NominalPattern(), 3.4, replan_params())


def _monitor_after_the_landing(plan, **kwargs):
    """The monitor with ``plan`` in force, its clock 20 ms after the landing (both soles down in the plan)."""
    monitor = FootholdMonitor(servo_period=DT, **kwargs)
    context = monitor.CreateDefaultContext()
    monitor.plan_port.FixValue(context, PlanHandle(plan))
    context.SetTime(round((plan.landing_time + 0.02) / DT) * DT)
    return monitor, context, Simulator(monitor, context)


def _soles(plan, left_shift=(0.0, 0.0), ticks=(40.0, 40.0)):
    left = plan.final_feet["left"][:2] + np.asarray(left_shift)
    return [*left, *plan.final_feet["right"][:2], *ticks]


def _tick(monitor, context, simulator, feet):
    """Fix ``feet``, read this tick's output, then run the tick's update."""
    monitor.measured_feet_port.FixValue(context, feet)
    relanded = monitor.relanded_port.Eval(context)
    simulator.AdvanceTo(context.get_time() + DT)
    return relanded


def test_a_sole_that_bounces_and_lands_a_centimetre_back_is_reported_where_it_stands(plan):
    monitor, context, simulator = _monitor_after_the_landing(plan)
    back = (-0.01, 0.0)
    script = [((0.0, 0.0), 40.0)] * 2 + [((0.0, 0.0), 0.0)] * 3 + [(back, 1.0), (back, 2.0), (back, 3.0)]
    outputs = [_tick(monitor, context, simulator, _soles(plan, shift, (ticks, 40.0))) for shift, ticks in script]
    assert all(out == Relanded() for out in outputs[:6])  # standing, lifted, and its first loaded tick
    assert outputs[6].fresh and not outputs[7].fresh  # it landed again on its second loaded tick (foothold_ticks)
    for out in outputs[6:]:
        np.testing.assert_allclose(out.soles["left"], plan.final_feet["left"][:2] + back, atol=1e-12)
        assert set(out.soles) == {"left"}
    assert list(monitor.stages(context)) == [SOLE_RELANDED, SOLE_STANDING]


def test_a_sole_that_lands_again_on_its_foothold_is_not_reported(plan):
    monitor, context, simulator = _monitor_after_the_landing(plan)
    script = [((0.0, 0.0), 40.0)] * 2 + [((0.0, 0.0), 0.0)] * 3 + [((-0.003, 0.0), 1.0), ((-0.003, 0.0), 2.0)]
    outputs = [_tick(monitor, context, simulator, _soles(plan, shift, (ticks, 40.0))) for shift, ticks in script]
    assert all(out == Relanded() for out in outputs)  # 3 mm: within the 5 mm tolerance
    assert list(monitor.stages(context)) == [SOLE_STANDING, SOLE_STANDING]


def test_without_a_plan_or_finite_soles_it_reports_nothing_and_keeps_its_stages(plan):
    monitor, context, simulator = _monitor_after_the_landing(plan)
    _tick(monitor, context, simulator, _soles(plan))
    _tick(monitor, context, simulator, _soles(plan, ticks=(0.0, 40.0)))
    assert monitor.stages(context)[0] == SOLE_LIFTED
    assert _tick(monitor, context, simulator, [np.nan] * 6) == Relanded()
    monitor.plan_port.FixValue(context, PlanHandle())
    assert _tick(monitor, context, simulator, _soles(plan, (-0.01, 0.0), (2.0, 40.0))) == Relanded()
    assert monitor.stages(context)[0] == SOLE_LIFTED  # neither tick moved it on


@pytest.mark.parametrize("kwargs, named", [
    ({"servo_period": 0.0}, "servo_period"),
    ({"servo_period": DT, "tolerance": -0.01}, "tolerance"),
    ({"servo_period": DT, "foothold_ticks": 0}, "foothold_ticks"),
    ({"servo_period": DT, "foothold_ticks": 1.5}, "foothold_ticks"),
])
def test_bad_settings_raise_naming_them(kwargs, named):
    with pytest.raises(ValueError, match=named):
        FootholdMonitor(**kwargs)


def test_add_foothold_monitor_feeds_the_planner_its_output_at_the_planners_settings():
    from pydrake.systems.primitives import PassThrough

    from drake_estop.systems.decision import StopPlannerConfig

    builder = DiagramBuilder()
    planner = builder.AddSystem(StopPlannerSystem(pattern=NominalPattern(), params=replan_params(),
                                                  config=StopPlannerConfig(foothold_ticks=3, foothold_tolerance=0.01)))
    feet = builder.AddSystem(PassThrough(6))
    monitor = add_foothold_monitor(builder, planner=planner, feet_port=feet.get_output_port())
    builder.ExportInput(feet.get_input_port(), "feet")
    diagram = builder.Build()
    assert (monitor._foothold_ticks, monitor._tolerance) == (3, 0.01)
    context = diagram.CreateDefaultContext()
    assert planner.relanded_port.HasValue(planner.GetMyContextFromRoot(context))  # connected
