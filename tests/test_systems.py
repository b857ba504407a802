"""The stop's LeafSystems (pattern source, e-stop trigger, stop planner) in isolation, Drake style."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from drake_estop.model import UPPER_BODY_JOINTS
from drake_estop.planning.gait import ARM_JOINTS, NominalPattern
from drake_estop.planning.planner import PHASES, StopParameters, plan_stop
from drake_estop.systems import stop_controller
from drake_estop.systems.decision import StopPlannerConfig
from drake_estop.systems.plan_sequence import PlanHandle
from drake_estop.systems.reference import WalkingPatternSource, blended_reference, reference_vector
from drake_estop.systems.stop_controller import StopPlannerSystem, add_stop_controller
from drake_estop.systems.stop_numerics import dcm_deviation
from drake_estop.systems.trigger import EStopTrigger

DT = 0.005


class FakeMeshcat:
    """Stands in for pydrake's Meshcat button API (clicks set by the test)."""

    def __init__(self):
        self.clicks = {}

    def AddButton(self, name, keycode=""):
        self.clicks[name] = 0

    def GetButtonClicks(self, name):
        return self.clicks[name]


@pytest.fixture(scope="module")
def pattern():
    return NominalPattern()


@pytest.fixture(scope="module")
def params():
    return StopParameters()


# -- WalkingPatternSource ----------------------------------------------------


def test_pattern_source_matches_pattern(pattern):
    source = WalkingPatternSource(pattern=pattern)
    context = source.CreateDefaultContext()
    for t in (0.0, 1.5, 3.1, 3.45, pattern.end_time + 0.3):
        context.SetTime(t)
        pos, vel, _, zmp = pattern.com([t])
        np.testing.assert_allclose(source.GetOutputPort("com").Eval(context),
                                   [*pos[0], pattern.params.com_height])
        np.testing.assert_allclose(source.GetOutputPort("com_vel").Eval(context), [*vel[0], 0.0])
        np.testing.assert_allclose(source.GetOutputPort("zmp").Eval(context), zmp[0])
        feet = pattern.feet_at(t)[0]
        for side in ("left", "right"):
            pose = source.GetOutputPort(f"{side}_foot").Eval(context)
            np.testing.assert_allclose(pose[:3], feet[side])  # sole z = lift
            np.testing.assert_allclose(pose[3:], [1, 0, 0, 0])
        arm = pattern.upper_body(t)[0]
        np.testing.assert_allclose(source.GetOutputPort("arm_joints").Eval(context), arm)
        upper = source.GetOutputPort("upper_body").Eval(context)
        for k, name in enumerate(ARM_JOINTS):
            assert upper[UPPER_BODY_JOINTS.index(name)] == pytest.approx(arm[k])
        assert source.GetOutputPort("phase").Eval(context)[0] == PHASES.index("walking")


def test_pattern_source_swing_foot_lifts(pattern):
    source = WalkingPatternSource(pattern=pattern)
    context = source.CreateDefaultContext()
    step = pattern.steps[2]
    context.SetTime(0.5 * (step["liftoff"] + step["touchdown"]))
    pose = source.GetOutputPort(f"{step['swing']}_foot").Eval(context)
    assert pose[2] == pytest.approx(pattern.params.lift_height, rel=1e-6)


# -- EStopTrigger ------------------------------------------------------------


def _update(system, context, t):
    context.SetTime(t)
    values = system.EvalUniquePeriodicDiscreteUpdate(context)
    context.SetDiscreteState(values)
    return system.stop_port.Eval(context)


def test_trigger_latches_at_scheduled_tick():
    trigger = EStopTrigger(servo_period=DT, scheduled_time=3.4)
    context = trigger.CreateDefaultContext()
    assert trigger.stop_port.Eval(context)[0] == 0.0
    assert _update(trigger, context, 3.395)[0] == 0.0
    stop = _update(trigger, context, 3.4)
    assert stop[0] == 1.0 and stop[1] == pytest.approx(3.4)
    stop = _update(trigger, context, 3.6)  # later ticks change nothing
    assert stop[1] == pytest.approx(3.4)


def test_trigger_input_port_latches_once():
    trigger = EStopTrigger(servo_period=DT)
    context = trigger.CreateDefaultContext()
    trigger.stop_request_port.FixValue(context, [0.0])
    assert _update(trigger, context, 1.0)[0] == 0.0
    trigger.stop_request_port.FixValue(context, [1.0])
    assert list(_update(trigger, context, 1.005)) == pytest.approx([1.0, 1.005])
    trigger.stop_request_port.FixValue(context, [0.0])
    assert list(_update(trigger, context, 1.5)) == pytest.approx([1.0, 1.005])


def test_trigger_meshcat_button_latches_once_and_ignores_later_presses():
    meshcat = FakeMeshcat()
    trigger = EStopTrigger(servo_period=DT, meshcat=meshcat, button_name="Stop!")
    simulator = Simulator(trigger)
    context = simulator.get_mutable_context()
    simulator.AdvanceTo(1.0)
    assert trigger.stop_port.Eval(context)[0] == 0.0
    meshcat.clicks["Stop!"] = 1
    simulator.AdvanceTo(1.2)
    latched, latch_time = EStopTrigger.latched(trigger.stop_port.Eval(context))
    # AdvanceTo(1.0) leaves the tick-1.0 update pending: the press is seen there
    assert latched and 1.0 <= latch_time <= 1.0 + 2 * DT
    meshcat.clicks["Stop!"] = 5
    simulator.AdvanceTo(2.0)
    assert trigger.stop_port.Eval(context)[1] == latch_time


def test_trigger_ignores_clicks_before_initialization():
    meshcat = FakeMeshcat()
    trigger = EStopTrigger(servo_period=DT, meshcat=meshcat)
    meshcat.clicks["Emergency stop"] = 3  # e.g. a reused button
    simulator = Simulator(trigger)
    simulator.AdvanceTo(0.5)
    assert trigger.stop_port.Eval(simulator.get_context())[0] == 0.0


def test_trigger_with_real_meshcat_adds_button():
    from drake_estop.systems.visualization import make_meshcat
    meshcat = make_meshcat()
    EStopTrigger(servo_period=DT, meshcat=meshcat)
    assert "Emergency stop" in meshcat.GetButtonNames()
    assert meshcat.GetButtonClicks("Emergency stop") == 0


# -- StopPlannerSystem -------------------------------------------------------


def _planner_context(pattern, params, t, stop, **options):
    planner = StopPlannerSystem(pattern=pattern, params=params, config=StopPlannerConfig(**options))
    simulator = Simulator(planner)
    context = simulator.get_mutable_context()
    context.SetTime(t)
    planner.stop_port.FixValue(context, stop)
    simulator.Initialize()
    return planner, simulator, context


def test_planner_plays_nominal_until_latched(pattern, params):
    planner, simulator, context = _planner_context(pattern, params, 3.0, [0.0, np.nan])
    simulator.AdvanceTo(3.5)
    assert planner.plan(context) is None
    pos = pattern.com([3.5])[0][0]
    np.testing.assert_allclose(planner.GetOutputPort("com").Eval(context)[:2], pos)
    assert planner.GetOutputPort("phase").Eval(context)[0] == PHASES.index("walking")


def test_planner_stores_plan_in_context_once(pattern, params):
    planner, simulator, context = _planner_context(pattern, params, 3.395, [1.0, 3.4])
    assert planner.plan(context) is None
    simulator.AdvanceTo(3.405)
    plan = planner.plan(context)
    assert plan is not None and plan.signal_time == pytest.approx(3.4)
    assert planner.plan_wall_time(context) > 0.0
    expected = plan_stop(pattern, 3.4, params)
    assert plan.halt_end == pytest.approx(expected.halt_end)
    assert planner.plan_port.Eval(context).plan is plan
    planner.stop_port.FixValue(context, [1.0, 3.6])  # a second latch changes nothing
    simulator.AdvanceTo(3.7)
    assert planner.plan(context) is plan
    # the plan lives in the Context: a fresh context has none
    assert planner.plan(planner.CreateDefaultContext()) is None


def _same_bits(plan, other):
    times = np.linspace(plan.start_time, plan.halt_end + 0.5, 97)
    return plan.halt_end == other.halt_end and all(
        np.array_equal(a, b) for a, b in zip(plan.com(times), other.com(times)))


@pytest.mark.parametrize("signal", [3.2, 3.4, 3.5])
def test_planner_plans_ahead_of_the_latch_and_the_latch_takes_that_plan(pattern, params, signal):
    """Every tick before the latch plans the stop of a signal at that tick (``plan_ahead``); the latch,
    which sees the signal a tick later, takes that very plan: the bits of planning on the latch's tick."""
    planner, simulator, context = _planner_context(pattern, params, signal - 0.01, [0.0, np.nan])
    simulator.AdvanceTo(signal + 0.002)  # the signal's tick ran unlatched
    ahead = planner.ahead_plan(context)
    assert ahead.signal_time == pytest.approx(signal, abs=1e-12) and ahead.plan is not None
    assert _same_bits(ahead.plan, plan_stop(pattern, signal, params))
    planner.stop_port.FixValue(context, [1.0, signal])
    simulator.AdvanceTo(signal + 0.007)
    assert planner.plan(context) is ahead.plan
    # without it the latch plans on its own tick: a new plan, the same bits
    other, simulator, context = _planner_context(pattern, params, signal - 0.01, [0.0, np.nan], plan_ahead=False)
    simulator.AdvanceTo(signal + 0.002)
    assert other.ahead_plan(context).plan is None
    other.stop_port.FixValue(context, [1.0, signal])
    simulator.AdvanceTo(signal + 0.007)
    assert other.plan(context) is not ahead.plan and _same_bits(other.plan(context), ahead.plan)


def test_a_latch_of_another_tick_plans_its_own_stop(pattern, params):
    """The plan made ahead is for its own tick only: a latch of an earlier signal plans that one."""
    planner, simulator, context = _planner_context(pattern, params, 3.39, [0.0, np.nan])
    simulator.AdvanceTo(3.402)
    planner.stop_port.FixValue(context, [1.0, 3.395])
    simulator.AdvanceTo(3.407)
    plan = planner.plan(context)
    assert plan is not planner.ahead_plan(context).plan
    assert plan.signal_time == pytest.approx(3.395) and _same_bits(plan, plan_stop(pattern, 3.395, params))


@pytest.mark.parametrize("signal", [3.4, 3.5])
def test_planner_outputs_continuous_across_latch(pattern, params, signal):
    planner, simulator, context = _planner_context(
        pattern, params, signal - 10 * DT, [0.0, np.nan])
    rows = []
    for k in range(-9, 12):
        t = signal + k * DT
        if k == 1:  # the trigger's latch becomes visible one tick after the signal
            planner.stop_port.FixValue(context, [1.0, signal])
        simulator.AdvanceTo(t)
        rows.append(np.concatenate([planner.GetOutputPort("com").Eval(context),
                                    planner.GetOutputPort("zmp").Eval(context),
                                    planner.GetOutputPort("left_foot").Eval(context)[:3],
                                    planner.GetOutputPort("right_foot").Eval(context)[:3],
                                    planner.GetOutputPort("upper_body").Eval(context)]))
    jumps = np.abs(np.diff(np.array(rows), axis=0))
    assert planner.plan(context) is not None
    # rows[9] is at the signal tick, where the plan starts from the nominal
    # state: it equals the nominal pattern there (no jump) ...
    source = WalkingPatternSource(pattern=pattern)
    nominal_context = source.CreateDefaultContext()
    nominal_context.SetTime(signal)
    np.testing.assert_allclose(rows[9][:3], source.GetOutputPort("com").Eval(nominal_context), atol=1e-9)
    # ... and the ticks around the switch show no isolated spike: each step is
    # bounded by the steps one tick before and two ticks after the signal.
    bound = np.maximum(jumps[8], jumps[11]) + 1e-4
    assert np.all(jumps[9] <= bound) and np.all(jumps[10] <= bound), (jumps[8:12])
    phase = PHASES[int(planner.GetOutputPort("phase").Eval(context)[0])]
    assert phase == ("landing" if signal == 3.4 else "transition")


def test_planner_reference_is_made_once_per_plan_and_tick(pattern, params, monkeypatch):
    """The reference is a function of the plan handle and the time: made once a tick although the planner's
    unrestricted update invalidates its cache, equal to a fresh evaluation, read-only, and made again when
    the handle changes at the same time."""
    planner, simulator, context = _planner_context(pattern, params, 3.395, [1.0, 3.4])
    for t in (3.40, 3.405, 3.45, 3.6):
        simulator.AdvanceTo(t)
        handle = planner.plan_port.Eval(context)
        fresh = blended_reference(reference_vector(t, pattern=pattern, plan=handle.plan), handle.blend, t)
        reference = planner.reference(context)
        assert np.array_equal(reference, fresh) and not reference.flags.writeable
    made = []
    monkeypatch.setattr(stop_controller, "reference_vector",
                        lambda *a, **k: made.append(1) or reference_vector(*a, **k))
    same = planner.plan_port.Eval(context)
    context.SetAbstractState(0, same)  # the state written again, as the update commits it: the cache is stale
    assert np.array_equal(planner.reference(context), reference) and made == []
    other = plan_stop(pattern, 3.35, params)
    context.SetAbstractState(0, PlanHandle(plan=other))  # another plan, the same time
    assert planner.plan(context) is other
    changed = planner.reference(context)
    assert np.array_equal(changed, reference_vector(3.6, pattern=pattern, plan=other)) and made == [1]
    assert not np.array_equal(changed[:3], reference[:3])


def test_planner_reports_phase_sequence(pattern, params):
    planner, simulator, context = _planner_context(pattern, params, 3.395, [1.0, 3.4])
    seen = [PHASES[int(planner.GetOutputPort("phase").Eval(context)[0])]]
    plan = None
    t = 3.395
    while plan is None or t < plan.halt_end + 0.1:
        t += DT
        simulator.AdvanceTo(t)
        plan = planner.plan(context)
        name = PHASES[int(planner.GetOutputPort("phase").Eval(context)[0])]
        if not seen or seen[-1] != name:
            seen.append(name)
    assert seen == ["walking", "landing", "transition", "slowdown", "halt", "stopped"]


def test_add_stop_controller_wires_trigger_to_planner(pattern, params):
    builder = DiagramBuilder()
    trigger, planner = add_stop_controller(builder, pattern=pattern, params=params,
                                           estop_time=3.4)
    builder.ExportInput(trigger.stop_request_port)
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.get_mutable_context().SetTime(3.3)
    diagram.get_input_port(0).FixValue(simulator.get_mutable_context(), [0.0])
    simulator.AdvanceTo(3.42)
    plan = planner.plan(planner.GetMyContextFromRoot(simulator.get_context()))
    assert plan is not None and plan.signal_time == pytest.approx(3.4)


def test_builder_loads_the_solver_before_the_stop():
    """The first plan of a process must not pay for loading the compiled solver on the
    servo tick of the stop: ``add_stop_controller`` warms the planner up at build time.
    Checked in a fresh process (in this one the solver is loaded already), without timing:
    before the build no compiled solver function has a loaded signature, after it some do."""
    import subprocess
    import sys

    code = (
        "import numba, sys\n"
        "from pydrake.systems.framework import DiagramBuilder\n"
        "import drake_estop.planning.planner\n"
        "from drake_estop.planning.gait import NominalPattern\n"
        "from drake_estop.planning.backend import COMPILED\n"
        "from drake_estop.planning.planner import StopParameters\n"
        "from drake_estop.systems.stop_controller import add_stop_controller\n"
        "def loaded():\n"
        "    return sum(len(f.signatures) for m in list(sys.modules.values())\n"
        "               if getattr(m, '__name__', '').startswith('drake_estop.planning')\n"
        "               for f in vars(m).values() if isinstance(f, numba.core.registry.CPUDispatcher))\n"
        "before = loaded()\n"
        "add_stop_controller(DiagramBuilder(), pattern=NominalPattern(), params=StopParameters())\n"
        "print(COMPILED, before, loaded())\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=True)
    compiled, before, after = done.stdout.split()[-3:]
    assert compiled == "True"  # numba is a dependency: the compiled solver is what runs
    assert int(before) == 0 and int(after) > 0


def test_planner_looks_the_patterns_cog_up_on_every_tick_with_the_bits_of_evaluating_it(pattern, params):
    from drake_estop.systems.stop_numerics import PatternCom

    dt = params.servo_period
    lookup = PatternCom(pattern, dt)
    ticks = np.arange(int(np.ceil(pattern.end_time / dt)) + 1) * dt
    for t in ticks[::7].tolist() + [ticks[-1]]:
        pos, vel, _, _ = pattern.com([t])
        looked_up = lookup.at(t)
        # equal to the last bit: the bias and the deviation before the latch are what they were evaluated
        assert np.array_equal(looked_up[0], pos[0]) and np.array_equal(looked_up[1], vel[0]), t
    between = 3.4 + 0.3 * dt  # not a tick: evaluated
    pos, vel, _, _ = pattern.com([between])
    assert np.array_equal(lookup.at(between)[0], pos[0])
    measured = (pos[0] + [0.01, 0.0], vel[0])
    assert lookup.deviation(between, measured) == dcm_deviation(pattern, between, measured)
    assert lookup.deviation(3.4, measured) == dcm_deviation(pattern, 3.4, measured)
