"""One-step feasibility: every servo tick, whether a stop signal at that tick would stop
within one step. The function, the stop-planner system's ``one_step_feasible`` output (from the
reference and from a measured state, before and after the latch) and the Meshcat indicator, each
against what the planner then does (``plan_stop(...).case == "one-step"``)."""

import msgpack
import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from drake_estop.planning import planner as planner_module
from drake_estop.planning.gait import GaitParameters, NominalPattern
from drake_estop.planning.planner import InfeasibleStop, StopParameters, first_stop, one_step_feasible, plan_stop
from drake_estop.planning.rollout import stride_ticks
from drake_estop.systems import stop_controller
from drake_estop.systems.decision import StopPlannerConfig
from drake_estop.systems.stop_controller import StopPlannerSystem
from drake_estop.systems.stop_numerics import nominal_one_step_table, nominal_stop, nominal_stop_table
from drake_estop.systems.visualization import ONE_STEP_INDICATOR, StopVisualizer, make_meshcat

DT = 0.005
PARAMS = StopParameters()
# the paper's gait (every tick of its stride one-step), a faster one whose stride has both answers (0.7 s
# cycle: next-step early in single support) and landing="nominal" (every tick one-step)
GAITS = {"paper": (GaitParameters(), PARAMS), "fast": (GaitParameters(step_time=0.7), PARAMS),
         "nominal_landing": (GaitParameters(), StopParameters(landing="nominal"))}
FAST = NominalPattern(GaitParameters(step_time=0.7))


def _one_step(pattern, t, params, measured=None):
    """What the planner does for a signal at ``t``: True for a one-step stop (no stop at all: False)."""
    try:
        return plan_stop(pattern, t, params, measured=measured).case == "one-step"
    except InfeasibleStop:
        return False


@pytest.fixture(scope="module", params=list(GAITS))
def stride(request):
    gait, params = GAITS[request.param]
    pattern = NominalPattern(gait)
    ticks = stride_ticks(pattern, params)
    return request.param, pattern, params, ticks, [_one_step(pattern, t, params) for t in ticks]


def test_function_agrees_with_the_planner_at_every_tick_of_the_stride(stride):
    name, pattern, params, ticks, expected = stride
    got = [one_step_feasible(pattern, t, params) for t in ticks]
    assert got == expected
    if name == "fast":  # the comparison covers both answers
        assert 0 < sum(expected) < len(expected)


def test_function_answers_false_outside_the_walk_and_raises_on_bad_input():
    pattern = NominalPattern()
    assert plan_stop(pattern, 0.0).case == "standing" and not one_step_feasible(pattern, 0.0)
    assert plan_stop(pattern, pattern.end_time + 0.5).case == "standing"
    assert not one_step_feasible(pattern, pattern.end_time + 0.5)
    with pytest.raises(ValueError, match="finite"):
        one_step_feasible(pattern, float("nan"))


def test_the_nominal_table_is_the_function_at_every_tick(stride):
    _, pattern, params, ticks, expected = stride
    table = nominal_one_step_table(pattern, params)
    assert len(table) == int(np.ceil(pattern.end_time / DT - 1e-9)) + 1
    assert [bool(table[int(round(t / DT))]) for t in ticks] == expected
    assert not table[0] and not table[-1]  # standing before the walk and after it


def _run_ticks(planner, ticks, stop=(0.0, np.nan)):
    """The planner's ``one_step_feasible`` output after its update of each tick (one simulation)."""
    simulator = Simulator(planner)
    context = simulator.get_mutable_context()
    context.SetTime(ticks[0])
    planner.stop_port.FixValue(context, list(stop))
    simulator.Initialize()
    out = []
    for t in ticks:
        simulator.AdvanceTo(t + DT / 2)  # runs the update of tick t
        value = planner.one_step_feasible_port.Eval(context)
        assert value.shape == (1,) and value[0] in (0.0, 1.0)
        assert planner.one_step_feasible(context) == (value[0] == 1.0)
        out.append(bool(value[0] == 1.0))
    return out, context


@pytest.mark.parametrize("gait", ["paper", "fast"])
def test_port_agrees_with_the_planner_at_every_tick_of_the_stride(gait):
    gait_params, params = GAITS[gait]
    pattern = NominalPattern(gait_params)
    ticks = stride_ticks(pattern, params)
    planner = StopPlannerSystem(pattern=pattern, params=params)
    got, context = _run_ticks(planner, ticks)
    assert got == [_one_step(pattern, t, params) for t in ticks]
    assert planner.plan(context) is None  # no latch: the check plans nothing into the Context


def test_nominal_ticks_are_looked_up_not_solved_on_the_tick(monkeypatch):
    """Without a measured state the answer is the table computed at construction: a solve on the
    tick (the function) is never called."""
    pattern = NominalPattern()
    planner = StopPlannerSystem(pattern=pattern, params=PARAMS)

    def forbidden(*args, **kwargs):
        raise AssertionError("one_step_feasible solved on the tick")

    monkeypatch.setattr(stop_controller, "one_step_feasible", forbidden)
    ticks = stride_ticks(pattern, PARAMS)[::10]
    got, _ = _run_ticks(planner, ticks)
    table = nominal_one_step_table(pattern, PARAMS)
    assert got == [bool(table[int(round(t / DT))]) for t in ticks]


def _measured_planner(pattern, t, stop, com_xy, vel_xy, **options):
    """A planner with constant measured COG inputs, its simulator at tick ``t`` (update not run yet)."""
    builder = DiagramBuilder()
    planner = builder.AddSystem(StopPlannerSystem(pattern=pattern, params=PARAMS, config=StopPlannerConfig(**options)))
    for port, value in ((planner.stop_port, stop), (planner.measured_com_port, [*com_xy, 0.8]),
                        (planner.measured_com_vel_port, [*vel_xy, 0.0])):
        builder.Connect(builder.AddSystem(ConstantVectorSource(np.asarray(value, float))).get_output_port(), port)
    simulator = Simulator(builder.Build())
    simulator.get_mutable_context().SetTime(t)
    simulator.Initialize()
    return planner, simulator, planner.GetMyContextFromRoot(simulator.get_context())


# (tick, COG velocity deviation [m/s], lateral COG deviation [m]): the deviation flips the answer
# (3.42 +15 cm/s: next-step; 3.1 +10 cm/s and 3.0 +5 cm/s: no stop at all), or not
DEVIATED = [(3.42, 0.15, 0.0), (3.1, 0.1, 0.0), (3.0, 0.05, 0.0), (3.3, 0.1, 0.0), (3.42, 0.0, -0.05),
            (3.5, 0.1, 0.0)]
FLIPPED = ((3.42, 0.15), (3.1, 0.1), (3.0, 0.05))
NO_STOP = ((3.1, 0.1), (3.0, 0.05))  # no stop from the measured state: the latch falls back to the reference


@pytest.fixture(scope="module")
def paper_pattern():
    return NominalPattern()


@pytest.mark.parametrize("t, dv, dy", DEVIATED)
def test_port_plans_from_the_measured_state_past_the_threshold(paper_pattern, t, dv, dy):
    """At a tick whose measured COG has left the reference (DCM beyond ``replan_threshold``), the
    port answers for a plan from that measured state, as the latch on that tick would make it."""
    pos, vel, _, _ = paper_pattern.com([t])
    com, com_vel = pos[0] + [0.0, dy], vel[0] + [dv, 0.0]
    planner, simulator, context = _measured_planner(paper_pattern, t, [0.0, np.nan], com, com_vel,
                                                    replan_threshold=0.005)
    simulator.AdvanceTo(t + DT / 2)
    expected = _one_step(paper_pattern, t, PARAMS, measured=(com, com_vel))
    assert planner.one_step_feasible(context) == expected
    if (t, dv) in FLIPPED:  # the measured state decides here
        assert expected != _one_step(paper_pattern, t, PARAMS)


@pytest.mark.parametrize("t, dv, dy", DEVIATED[:3])
def test_port_follows_the_reference_within_the_threshold(paper_pattern, t, dv, dy):
    """A deviation within ``replan_threshold`` (the latch would plan from the reference): the nominal answer."""
    pos, vel, _, _ = paper_pattern.com([t])
    planner, simulator, context = _measured_planner(paper_pattern, t, [0.0, np.nan], pos[0] + [0.0, dy],
                                                    vel[0] + [dv, 0.0], replan_threshold=0.05)
    simulator.AdvanceTo(t + DT / 2)
    assert planner.one_step_feasible(context) == _one_step(paper_pattern, t, PARAMS)


@pytest.mark.parametrize("t, dv, dy",
                         [d for d in DEVIATED if d[:2] not in NO_STOP] + [(3.1, 0.0, 0.0), (3.22, 0.0, 0.0)])
def test_latch_on_the_same_tick_makes_the_plan_the_port_announced(paper_pattern, t, dv, dy):
    """The same inputs on the same tick: the port of an unlatched planner announces the case of the
    plan a latched one makes (both through ``_plan_request``); after the latch the port holds that case."""
    pos, vel, _, _ = paper_pattern.com([t])
    com, com_vel = pos[0] + [0.0, dy], vel[0] + [dv, 0.0]
    announced = _measured_planner(paper_pattern, t, [0.0, np.nan], com, com_vel, replan_threshold=0.005)
    announced[1].AdvanceTo(t + DT / 2)
    planner, simulator, context = _measured_planner(paper_pattern, t, [1.0, t], com, com_vel,
                                                    replan_threshold=0.005)
    simulator.AdvanceTo(t + DT / 2)
    plan = planner.plan(context)
    assert announced[0].one_step_feasible(announced[2]) == (plan.case == "one-step")
    assert planner.one_step_feasible(context) == (plan.case == "one-step")
    simulator.AdvanceTo(t + 0.2)  # re-plans or not, the port keeps the latched stop's case
    assert planner.one_step_feasible(context) == (plan.case == "one-step")


@pytest.mark.parametrize("fast, signal, one_step", [(False, 3.1, True), (True, 2.8, False), (False, 3.5, True)])
def test_port_after_the_latch_reports_the_latched_plan(paper_pattern, fast, signal, one_step):
    """The trigger's latch reaches the planner one tick after the signal: the port shows the answer
    for the signal's tick, then the case of the plan made for it."""
    pattern = FAST if fast else paper_pattern
    ticks = signal + DT * np.arange(-2, 30)
    planner = StopPlannerSystem(pattern=pattern, params=PARAMS)
    simulator = Simulator(planner)
    context = simulator.get_mutable_context()
    context.SetTime(ticks[0])
    planner.stop_port.FixValue(context, [0.0, np.nan])
    simulator.Initialize()
    values = []
    for t in ticks:
        if t > signal + DT / 2:
            planner.stop_port.FixValue(context, [1.0, signal])
        simulator.AdvanceTo(t + DT / 2)
        values.append(planner.one_step_feasible(context))
    plan = planner.plan(context)
    assert plan is not None and plan.signal_time == pytest.approx(signal)
    expected = plan.case == "one-step"
    assert values[2] == expected  # the signal's tick, before the latch
    assert values[3:] == [expected] * (len(ticks) - 3)
    assert expected == one_step


def test_a_broken_search_is_caught():
    """The agreement tests bite: a feasibility that ignored the first attempt's failure (answering
    one-step for the next-step fallback) disagrees with the planner on the stride."""
    pattern = FAST
    ticks = stride_ticks(pattern, PARAMS)
    expected = [_one_step(pattern, t, PARAMS) for t in ticks]

    def broken(pattern, signal_time, params=None, *, measured=None):
        plan = planner_module._search(pattern, signal_time, params, measured, first_only=False)
        return plan.case in ("one-step", "next-step")

    assert [broken(pattern, t, PARAMS) for t in ticks] != expected


# -- Meshcat -----------------------------------------------------------------------------------


def _visible(meshcat, path):
    return msgpack.unpackb(meshcat._GetPackedProperty(path, "visible"))["value"]


def test_meshcat_indicator_shows_the_port_value(paper_pattern):
    meshcat = make_meshcat()
    visualizer = StopVisualizer(meshcat=meshcat, pattern=paper_pattern, publish_period=0.01)
    simulator = Simulator(visualizer)
    context = simulator.get_mutable_context()
    visualizer.com_port.FixValue(context, [0.4, 0.0, 0.8])
    visualizer.zmp_port.FixValue(context, [0.4, 0.0])
    visualizer.phase_port.FixValue(context, [0.0])
    visualizer.plan_port.FixValue(context, None)
    visualizer.one_step_feasible_port.FixValue(context, [1.0])
    simulator.Initialize()
    simulator.AdvanceTo(0.015)
    green, amber = (f"/estop/one_step/{ONE_STEP_INDICATOR[v][0]}" for v in (True, False))
    for path in (green, amber):
        assert meshcat.HasPath(f"{path}/sphere") and meshcat.HasPath(f"{path}/plate")
    assert _visible(meshcat, green) is True and _visible(meshcat, amber) is False
    visualizer.one_step_feasible_port.FixValue(context, [0.0])
    simulator.AdvanceTo(0.025)
    assert _visible(meshcat, green) is False and _visible(meshcat, amber) is True
    # the sphere sits over the robot: above the COG's floor point
    frame = msgpack.unpackb(meshcat._GetPackedTransform("/estop/one_step"))["matrix"][12:15]
    sphere = msgpack.unpackb(meshcat._GetPackedTransform(f"{amber}/sphere"))["matrix"][12:15]
    np.testing.assert_allclose(np.add(frame, sphere), [0.4, 0.0, 1.62], atol=1e-9)


def test_meshcat_without_the_input_draws_no_indicator(paper_pattern):
    meshcat = make_meshcat()
    visualizer = StopVisualizer(meshcat=meshcat, pattern=paper_pattern, publish_period=0.01)
    simulator = Simulator(visualizer)
    context = simulator.get_mutable_context()
    for port, value in ((visualizer.com_port, [0.4, 0.0, 0.8]), (visualizer.zmp_port, [0.4, 0.0]),
                        (visualizer.phase_port, [0.0])):
        port.FixValue(context, value)
    visualizer.plan_port.FixValue(context, None)
    simulator.Initialize()
    simulator.AdvanceTo(0.015)
    assert meshcat.HasPath("/estop/markers/cog") and not meshcat.HasPath("/estop/one_step")


def _same_bits(plan, other):
    times = np.linspace(plan.start_time, plan.halt_end + 0.5, 97)
    return plan.case == other.case and plan.halt_end == other.halt_end and all(
        np.array_equal(a, b) for a, b in zip(plan.com(times), other.com(times)))


def test_the_stops_planned_before_the_run_are_the_planner_s_own():
    """The fast gait's stride has both answers: where the search ends in the signal's own phase the table
    holds plan_stop's stop to the bit (its first attempt), elsewhere (next-step, III.C) None; a stop taken
    from the table is a copy, so changing it leaves the table alone."""
    table = nominal_stop_table(FAST, PARAMS)
    assert len(table) == len(nominal_one_step_table(FAST, PARAMS))
    cases = set()
    for t in stride_ticks(FAST, PARAMS)[::5]:
        planned = plan_stop(FAST, t, PARAMS)
        stored = table[int(round(t / DT))]
        assert (stored is None) == (planned.case == "next-step"), t
        assert stored is None or _same_bits(stored, planned), t
        first = first_stop(FAST, t, PARAMS)
        assert first is None if stored is None else _same_bits(first, planned)
        cases.add(planned.case)
    assert cases == {"one-step", "next-step"}
    taken = nominal_stop(table, 3.4, DT)
    taken.compute_time = -1.0
    assert table[int(round(3.4 / DT))].compute_time >= 0.0
    assert nominal_stop(table, -1.0, DT) is None and nominal_stop(table, FAST.end_time + 1.0, DT) is None


def test_the_plan_made_ahead_is_looked_up_not_solved_on_the_tick(monkeypatch):
    """Before the latch the planner's plan made ahead comes from the table computed at construction: where
    the table has the stop, no stop is planned on the tick; where it has none (next-step) it still is."""
    solved = []

    def counting(*args, **kwargs):
        solved.append(args[1])
        return plan_stop(*args, **kwargs)

    monkeypatch.setattr(stop_controller, "plan_stop", counting)
    planner = StopPlannerSystem(pattern=FAST, params=PARAMS)
    table = nominal_stop_table(FAST, PARAMS)
    simulator = Simulator(planner)
    context = simulator.get_mutable_context()
    ticks = stride_ticks(FAST, PARAMS)[::7]
    context.SetTime(ticks[0])
    planner.stop_port.FixValue(context, [0.0, np.nan])
    simulator.Initialize()
    for t in ticks:
        simulator.AdvanceTo(t + DT / 2)
        ahead = planner.ahead_plan(context)
        stored = table[int(round(t / DT))]
        assert ahead.plan is not None and ahead.plan is not stored
        assert _same_bits(ahead.plan, plan_stop(FAST, t, PARAMS) if stored is None else stored)
    looked_up = [t for t in ticks if table[int(round(t / DT))] is not None]
    assert looked_up and len(looked_up) < len(ticks)
    assert not set(np.round(looked_up, 6)) & set(np.round(solved, 6))


def test_a_corrected_walk_gets_its_own_stops_not_those_of_its_gait_parameters():
    """A whole-body corrected walk has the plain walk's gait parameters and another COG: its stops are its
    own, not the table cached for those parameters."""
    from drake_estop.planning.com_correction import ComCorrection

    times = np.linspace(0.0, FAST.end_time, 50)
    offset = np.column_stack([0.01 * np.sin(times), np.zeros_like(times)])
    correction = ComCorrection(times, offset, np.zeros_like(offset), np.zeros_like(offset))
    corrected = NominalPattern(FAST.params, com_correction=correction)
    plain = nominal_stop_table(FAST, PARAMS)
    own = nominal_stop_table(corrected, PARAMS)
    k = int(round(3.4 / DT))
    assert plain is nominal_stop_table(NominalPattern(FAST.params), PARAMS)  # cached by parameters
    assert own is not plain and own[k] is not None
    assert _same_bits(own[k], plan_stop(corrected, 3.4, PARAMS))
    assert not _same_bits(own[k], plain[k])
