"""StopPlannerSystem with the measured-state inputs: the latch from the measured state or the reference,
the command's blend into a plan, re-plans at most once a tick with their tries spread over ticks, settings."""

import os
from pathlib import Path

import numpy as np
import pytest
from planner_helpers import (
    DT,
    count_solves,
    latched_stop_planner,
    left_push_state,
    replan_params,
    sideways_at,
    state_at,
)
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from drake_estop.planning.gait import NominalPattern
from drake_estop.planning.planner import StopParameters, plan_stop
from drake_estop.systems.decision import StopPlannerConfig
from drake_estop.systems.reference import REFERENCE_SIZE, REFERENCE_SLICES, blended_reference
from drake_estop.systems.stop_controller import StopPlannerSystem


@pytest.fixture(scope="module")
def params():
    return replan_params()


def _planner_diagram(pattern, params, stop, com, com_vel, **kwargs):
    builder = DiagramBuilder()
    planner = builder.AddSystem(StopPlannerSystem(pattern=pattern, params=params, config=StopPlannerConfig(**kwargs)))
    for port, value in ((planner.stop_port, stop), (planner.measured_com_port, com),
                        (planner.measured_com_vel_port, com_vel)):
        source = builder.AddSystem(ConstantVectorSource(np.asarray(value, float)))
        builder.Connect(source.get_output_port(), port)
    diagram = builder.Build()
    return diagram, planner


def test_planner_plans_from_the_reference_when_the_robot_follows_it(pattern, params):
    t = 3.1
    pos, vel, _ = state_at(plan_stop(pattern, t, params), t)
    diagram, planner = _planner_diagram(pattern, params, [1.0, t], [*pos, 0.8], [*vel, 0.0])
    simulator = Simulator(diagram)
    simulator.get_mutable_context().SetTime(t)
    simulator.Initialize()
    simulator.AdvanceTo(t + DT / 2)
    context = planner.GetMyContextFromRoot(simulator.get_context())
    plan = planner.plan(context)
    assert plan.start_time == pytest.approx(t)
    assert plan.step_length == pytest.approx(plan_stop(pattern, t, params).step_length, abs=1e-9)
    assert planner.replans(context) == (0, 0)


def test_planner_plans_from_the_measured_state_after_a_push_and_blends_the_command(pattern, params):
    t = 3.15
    pos, vel, _ = state_at(plan_stop(pattern, t, params), t)
    pushed = vel + np.array([0.02, 0.0])  # 5.8 mm of DCM: past a 5 mm threshold
    diagram, planner = _planner_diagram(pattern, params, [1.0, t], [*pos, 0.8], [*pushed, 0.0],
                                        replan_threshold=0.005)
    simulator = Simulator(diagram)
    simulator.get_mutable_context().SetTime(t)
    simulator.Initialize()
    context = planner.GetMyContextFromRoot(simulator.get_context())
    simulator.AdvanceTo(t + DT / 2)
    plan = planner.plan(context)
    np.testing.assert_allclose(plan.com([plan.start_time])[1][0], pushed, atol=1e-9)
    assert plan.step_length > plan_stop(pattern, t, params).step_length
    # the command starts where the old one was (no step for the stiff servos) and joins the plan
    tc = context.get_time()
    old_pos, old_vel, _, _ = pattern.com([tc])
    np.testing.assert_allclose(planner.GetOutputPort("com").Eval(context)[:2], old_pos[0], atol=2e-5)
    np.testing.assert_allclose(planner.GetOutputPort("com_vel").Eval(context)[:2], old_vel[0], atol=0.01)
    plan_pos, plan_vel, _, _ = plan.com([tc])
    assert np.linalg.norm(plan_vel[0] - old_vel[0]) > 0.015  # the plan itself starts at the measured 2 cm/s more


def test_a_plan_from_the_measured_state_records_no_fallback(pattern, params):
    t = 3.15
    pos, vel, _ = state_at(plan_stop(pattern, t, params), t)
    diagram, planner = _planner_diagram(pattern, params, [1.0, t], [*pos, 0.8], [*(vel + [0.02, 0.0]), 0.0],
                                        replan_threshold=0.005)
    simulator = Simulator(diagram)
    simulator.get_mutable_context().SetTime(t)
    simulator.AdvanceTo(t + DT / 2)
    assert planner.latch_fallback(planner.GetMyContextFromRoot(simulator.get_context())) is None


def test_no_stop_from_the_measured_state_plans_from_the_reference_and_keeps_trying(pattern):
    """A state no stop catches at the signal (3 m/s sideways) does not end the controller: the latch
    plans the paper's stop from the reference, as without a measurement (continuous with the command, no
    blend), says why, and the measured state is then re-planned from every tick (each try fails here)."""
    t, params = 3.1, StopParameters()
    com, com_vel = sideways_at(pattern, t, 3.0)
    diagram, planner = _planner_diagram(pattern, params, [1.0, t], com, com_vel,
                                        replan_interval=DT)
    simulator = Simulator(diagram)
    simulator.get_mutable_context().SetTime(t)
    simulator.AdvanceTo(t + DT / 2)
    context = planner.GetMyContextFromRoot(simulator.get_context())
    plan, reference = planner.plan(context), plan_stop(pattern, t, params)
    assert (plan.start_time, plan.landing_time, plan.step_length) == (
        reference.start_time, reference.landing_time, reference.step_length)
    assert "no feasible stop in the first 4 tries" in planner.latch_fallback(context)  # MAX_LATCH_SOLVES
    tc = context.get_time()  # the command is the plan's own, not blended towards the measured state
    np.testing.assert_allclose(planner.GetOutputPort("com").Eval(context)[:2], plan.com([tc])[0][0], atol=1e-9)
    simulator.AdvanceTo(t + 5 * DT + DT / 2)
    replans, failures = planner.replans(context)
    # re-plans from the measured state on every later tick: each one's four single-support tries take two
    # ticks (MAX_REPLAN_SOLVES = 2), so five ticks end two of them, both without a stop
    assert (replans, failures) == (0, 2)


def test_an_infeasible_stop_raises_instead_of_crashing_the_simulator():
    """Without the reference fallback (``reference_fallback=False``), a state no stop can catch (here
    3 m/s sideways at the signal) makes the planner raise InfeasibleStop out of AdvanceTo. Returning
    EventStatus.Failed instead crashed the process (pydrake formats the failure with the GIL released:
    SIGSEGV); run in a child process so that such a crash fails this test instead of the suite."""
    import subprocess
    import sys

    code = (
        "import numpy as np\n"
        "from pydrake.systems.analysis import Simulator\n"
        "from test_replan_system import _planner_diagram\n"
        "from drake_estop.planning.gait import NominalPattern\n"
        "from drake_estop.planning.planner import InfeasibleStop, StopParameters\n"
        "pattern = NominalPattern(); t = 3.1\n"
        "pos, vel, _, _ = pattern.com([t])\n"
        "diagram, planner = _planner_diagram(pattern, StopParameters(), [1.0, t], [*pos[0], 0.8],\n"
        "                                    [vel[0][0], 3.0, 0.0], reference_fallback=False)\n"
        "simulator = Simulator(diagram)\n"
        "simulator.get_mutable_context().SetTime(t)\n"
        "try:\n"
        "    simulator.AdvanceTo(t + 0.02)\n"
        "except InfeasibleStop as error:\n"
        "    print('raised:', error)\n"
    )
    tests = str(Path(__file__).parent)
    path = os.pathsep.join([tests, str(Path(tests).parent)])
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          cwd=tests, env={**os.environ, "PYTHONPATH": path})
    assert done.returncode == 0, done.stderr[-2000:]
    assert "raised: stop planning failed at t = 3.10" in done.stdout


# -- the command blended into a plan from the measured state ------------------------------------------


def test_blend_starts_at_the_old_command_and_ends_on_the_plan_at_rest():
    reference = np.zeros(REFERENCE_SIZE)
    dp, dv, duration = np.array([0.02, -0.01]), np.array([0.1, 0.05]), 0.2
    blend = (1.0, dp, dv, duration)

    def command(t):
        out = blended_reference(reference, blend, t)
        return out[REFERENCE_SLICES["com"]][:2], out[REFERENCE_SLICES["com_vel"]][:2]

    np.testing.assert_allclose(command(1.0)[0], dp)
    np.testing.assert_allclose(command(1.0)[1], dv)
    h = 1e-6
    np.testing.assert_allclose((command(1.1 + h)[0] - command(1.1 - h)[0]) / (2 * h), command(1.1)[1], atol=1e-6)
    np.testing.assert_allclose(command(1.0 + duration - 1e-9)[0], 0.0, atol=1e-9)
    np.testing.assert_allclose(command(1.0 + duration - 1e-9)[1], 0.0, atol=1e-6)
    np.testing.assert_allclose(command(1.5)[0], 0.0)
    np.testing.assert_allclose(command(0.9)[0], 0.0)


def test_blend_fades_the_sole_offsets_to_the_new_plan_at_rest():
    reference = np.zeros(REFERENCE_SIZE)
    dfeet = np.array([[0.01, -0.02, 0.0], [-0.005, 0.015, 0.0]])
    blend = (1.0, np.zeros(2), np.zeros(2), 0.2, dfeet)

    def feet(t):
        out = blended_reference(reference, blend, t)
        return np.array([out[REFERENCE_SLICES[f"{side}_foot"]][:3] for side in ("left", "right")])

    np.testing.assert_allclose(feet(1.0), dfeet)
    h = 1e-6
    np.testing.assert_allclose((feet(1.0 + h) - feet(1.0)) / h, 0.0, atol=1e-4)  # starts at rest
    np.testing.assert_allclose(feet(1.2 - 1e-9), 0.0, atol=1e-9)
    assert np.all(np.abs(feet(1.1)) < np.abs(dfeet) + 1e-12)


# -- re-plans, at most once a tick, their tries spread over ticks --------------------------------------


def test_planner_replans_at_most_once_a_tick_while_the_measured_state_deviates(pattern, params):
    t = 3.0
    pos, vel, _ = state_at(plan_stop(pattern, t, params), t)
    # the measured state stays frozen at the signal's: it leaves every new plan again
    diagram, planner = _planner_diagram(pattern, params, [1.0, t], [*pos, 0.8], [*vel, 0.0],
                                        replan_threshold=0.005, replan_interval=DT)
    simulator = Simulator(diagram)
    simulator.get_mutable_context().SetTime(t)
    simulator.Initialize()
    simulator.AdvanceTo(t + 0.1)
    context = planner.GetMyContextFromRoot(simulator.get_context())
    replans, failures = planner.replans(context)
    ticks = int(round(0.1 / DT))
    assert 1 <= replans + failures <= ticks
    assert len(planner.plans(context).plans) == replans + 1


def _pushed_planner(monkeypatch, **kwargs):
    """A latched 2.95 s stop (the controller's settings) at 3.175 s, with the left-push measurement fixed:
    returns the planner, its context, the simulator and the per-tick solve counter."""
    from drake_estop.physics.online import controller_stop_parameters

    planner, context, simulator, first = latched_stop_planner(NominalPattern(), controller_stop_parameters(),
                                                              t0=2.95, **kwargs)
    _, t, com, vel = left_push_state()
    simulator.AdvanceTo(t - DT / 2)
    planner.measured_com_port.FixValue(context, [*com, 0.8])
    planner.measured_com_vel_port.FixValue(context, [*vel, 0.0])
    return planner, context, simulator, count_solves(monkeypatch), t


def test_the_planner_spreads_a_replans_tries_over_ticks(monkeypatch):
    """max_replan_solves=2 (the default): the held ZMP and the ankle ZMP fail on the push's tick, the ankle
    ZMP's lateral part holds on the next; unbounded (None), all three on the push's tick."""
    planner, context, simulator, solves, t = _pushed_planner(monkeypatch)
    simulator.AdvanceTo(t + DT / 2)
    assert len(solves) == 2 and planner.replans(context) == (0, 0)
    assert context.get_abstract_state(0).get_value().pending == ("single", 2)
    simulator.AdvanceTo(t + DT + DT / 2)
    assert len(solves) == 3 and planner.replans(context) == (1, 0)
    assert planner.plan(context).start_time == pytest.approx(t + DT)
    assert context.get_abstract_state(0).get_value().pending is None

    planner, context, simulator, solves, t = _pushed_planner(monkeypatch, max_replan_solves=None)
    simulator.AdvanceTo(t + DT / 2)
    assert len(solves) == 3 and planner.replans(context) == (1, 0)
    assert planner.plan(context).start_time == pytest.approx(t)


def test_the_planner_drops_a_replans_tries_when_the_robot_is_back_on_the_plan(monkeypatch):
    planner, context, simulator, solves, t = _pushed_planner(monkeypatch)
    simulator.AdvanceTo(t + DT / 2)
    assert context.get_abstract_state(0).get_value().pending == ("single", 2)
    pos, vel, _ = state_at(planner.plan(context), t + DT)
    planner.measured_com_port.FixValue(context, [*pos, 0.8])
    planner.measured_com_vel_port.FixValue(context, [*vel, 0.0])
    simulator.AdvanceTo(t + DT + DT / 2)
    assert len(solves) == 2 and planner.replans(context) == (0, 0)
    assert context.get_abstract_state(0).get_value().pending is None


# -- bad settings -------------------------------------------------------------------------------------


@pytest.mark.parametrize("value", [0, 2.5, False])
def test_planner_rejects_a_bad_max_latch_solves(pattern, params, value):
    with pytest.raises(ValueError, match="max_latch_solves"):
        StopPlannerSystem(pattern=pattern, params=params, config=StopPlannerConfig(max_latch_solves=value))


@pytest.mark.parametrize("name", ["replan_threshold", "blend_time", "replan_interval", "landed_replan_threshold",
                                  "foothold_tolerance"])
@pytest.mark.parametrize("value", [0.0, -1.0, float("nan")])
def test_planner_rejects_bad_settings(pattern, params, name, value):
    with pytest.raises(ValueError, match=name):
        StopPlannerSystem(pattern=pattern, params=params, config=StopPlannerConfig(**{name: value}))


@pytest.mark.parametrize("value", [0, -1, 1.5, True, "2"])
def test_planner_rejects_a_bad_solve_bound(pattern, params, value):
    with pytest.raises(ValueError, match="max_replan_solves"):
        StopPlannerSystem(pattern=pattern, params=params, config=StopPlannerConfig(max_replan_solves=value))
