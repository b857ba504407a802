"""Shared by the re-plan and recovery-step tests: StopPlannerSystem alone, the way Drake tests a
LeafSystem (a default context, FixValue inputs, Simulator.AdvanceTo), or beside its FootholdMonitor; the
re-plans' stop parameters and measured states."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import PassThrough

from drake_estop.planning.gait import NominalPattern
from drake_estop.planning.planner import StopParameters, plan_stop
from drake_estop.systems.decision import StopPlannerConfig
from drake_estop.systems.foothold_monitor import add_foothold_monitor
from drake_estop.systems.stop_controller import StopPlannerSystem

DT = 0.005


def replan_params():
    """Re-plans are the online controller's: its slowdown ZMP is at the landing ankle (the paper's eq. 20,
    ``controller_stop_parameters``), where the kinematic default puts it 5 cm ahead."""
    return StopParameters(landing_zmp_offset=0.0)


def latched_stop_planner(pattern, params, t0=3.4, **kwargs):
    """A StopPlannerSystem (re-plans up to every tick; ``kwargs`` override) whose stop latched at
    ``t0`` from the reference, then without a measurement (NaN: no re-plan). Returns the planner, its
    context, the simulator and the first plan."""
    planner = _planner(pattern, params, kwargs)
    context = planner.CreateDefaultContext()
    simulator = Simulator(planner, context)
    return planner, context, simulator, _latched(planner, context, simulator, pattern, t0)


def monitored_stop_planner(pattern, params, t0=3.4, **kwargs):
    """:func:`latched_stop_planner` with a FootholdMonitor beside the planner (``add_foothold_monitor``), both
    reading the diagram's ``measured_feet`` input. Returns the planner, its context, the diagram's simulator,
    the first plan and a function that fixes the measured soles (6)."""
    builder = DiagramBuilder()
    planner = builder.AddSystem(_planner(pattern, params, kwargs))
    feet = builder.AddSystem(PassThrough(6))
    builder.Connect(feet.get_output_port(), planner.measured_feet_port)
    add_foothold_monitor(builder, planner=planner, feet_port=feet.get_output_port())
    builder.ExportInput(feet.get_input_port(), "measured_feet")
    diagram = builder.Build()
    simulator = Simulator(diagram)
    root = simulator.get_mutable_context()
    context = planner.GetMyMutableContextFromRoot(root)
    diagram.get_input_port().FixValue(root, np.full(6, np.nan))  # no soles until a test gives them
    first = _latched(planner, context, simulator, pattern, t0)
    return planner, context, simulator, first, lambda value: diagram.get_input_port().FixValue(root, value)


def _planner(pattern, params, kwargs):
    return StopPlannerSystem(pattern=pattern, params=params, config=StopPlannerConfig(**{"replan_interval": DT,
                                                                                         **kwargs}))


def _latched(planner, context, simulator, pattern, t0):
    """Latch ``planner``'s stop at ``t0`` from the reference, then take its measurement away; the first plan."""
    pos, vel, _, _ = pattern.com([t0])
    planner.stop_port.FixValue(context, [1.0, t0])
    planner.measured_com_port.FixValue(context, [*pos[0], 0.8])
    planner.measured_com_vel_port.FixValue(context, [*vel[0], 0.0])
    simulator.get_mutable_context().SetTime(t0)
    simulator.AdvanceTo(t0 + DT / 2)
    first = planner.plan(context)
    assert first.start_time == pytest.approx(t0)
    planner.measured_com_port.FixValue(context, [np.nan] * 3)  # no measurement: no re-plan
    return first


def state_at(plan, t):
    """COG position, COG velocity and ZMP (x, y) of ``plan`` at ``t``."""
    pos, vel, _, zmp = plan.com([t])
    return pos[0], vel[0], zmp[0]


def left_push_state():
    """The plan of a signal at 2.95 s (the online controller's settings) and the state the robot measured
    at 3.175 s after a 17 N s push to the left (a physics run), its lateral speed 1 cm/s higher: the DCM over
    the left (support) foot's outer edge, where neither the held ZMP nor the whole ankle ZMP finds a stop
    and the ankle ZMP's lateral part does (with the speed as measured the ankle ZMP already does)."""
    from drake_estop.physics.online import controller_stop_parameters

    plan = plan_stop(NominalPattern(), 2.95, controller_stop_parameters())
    return plan, 3.175, np.array([0.60612853, 0.0693894]), np.array([0.23707723, 0.11288797])


def forward_push_state():
    """The plan of a signal at 2.95 s (the online controller's settings) and the state the robot measured at
    3.1 s after a 35 N s (0.6 m/s) forward push at 2.95 s (a physics run): the left foot supports with its
    CoP on the toe, the DCM 0.21 m past its ankle; no landing stops it (planning.capture_landing.capture_step)."""
    from drake_estop.physics.online import controller_stop_parameters

    plan = plan_stop(NominalPattern(), 2.95, controller_stop_parameters())
    return plan, 3.1, np.array([0.62063178, 0.04679833]), np.array([0.66055078, 0.01980075])


def count_solves(monkeypatch):
    """A list that grows by one for every stop a re-plan solves (``plan_from``, the capture landing's too)."""
    from drake_estop.planning import capture_landing, replan

    solves, real = [], replan.plan_from
    for module in (replan, capture_landing):
        monkeypatch.setattr(module, "plan_from", lambda *a, **k: solves.append(a[1].zmp.copy()) or real(*a, **k))
    return solves


def sideways_at(pattern, t, speed):
    """The measured COG of the walk at ``t`` with ``speed`` [m/s] sideways: no stop catches 3 m/s."""
    pos, vel, _, _ = pattern.com([t])
    return [*pos[0], 0.8], [vel[0][0], speed, 0.0]


def inward(side):
    """The sign of y towards the other foot."""
    return -1.0 if side == "left" else 1.0


def moved_feet(plan):
    """The landing foot 7 mm ahead and 15 mm inside its target, the support foot slid 9 mm outward."""
    landing = plan.landing_foot
    support = next(s for s in ("left", "right") if s != landing)
    return {landing: plan.final_feet[landing] + [0.007, 0.015 * inward(landing)],
            support: plan.final_feet[support] + [-0.004, -0.009 * inward(support)]}
