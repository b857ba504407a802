"""The stop controller's decision on its own (decision.decide, decision.stop_mode) and the planner system's
``mode`` output: the mode sequence of the paper's stops, a late signal (III.C), a push in the air and in
double support, a re-plan that found no stop, the settings' checks."""

import dataclasses

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from drake_estop.planning.gait import GaitParameters, NominalPattern
from drake_estop.planning.planner import StopParameters, plan_stop
from drake_estop.systems.decision import (
    Action,
    ActionKind,
    Observation,
    StopMode,
    StopPlannerConfig,
    decide,
    halt_replans,
    stop_mode,
)
from drake_estop.systems.plan_sequence import PlanHandle
from drake_estop.systems.stop_controller import StopPlannerSystem

PARAMS = StopParameters()
DT = PARAMS.servo_period
CONFIG = StopPlannerConfig()


@pytest.fixture(scope="module")
def pattern():
    return NominalPattern()


@pytest.fixture(scope="module")
def plan_3_4(pattern):
    return plan_stop(pattern, 3.4, PARAMS)


@pytest.fixture(scope="module")
def plan_3_2(pattern):
    """A stop whose landing (3.465 s) can still move until 3.365 s."""
    return plan_stop(pattern, 3.2, PARAMS)


def _modes(pattern, signal_time, until):
    """The planner system's ``mode`` output after each tick from 20 ms before ``signal_time`` to ``until``,
    a signal latched at ``signal_time``: ``[(t, mode name, landings left)]`` where it changes."""
    planner = StopPlannerSystem(pattern=pattern, params=PARAMS)
    simulator = Simulator(planner)
    context = simulator.get_mutable_context()
    planner.stop_port.FixValue(context, [0.0, np.nan])
    context.SetTime(signal_time - 0.02)
    simulator.Initialize()
    changes, tick = [], int(round((signal_time - 0.02) / DT))
    while tick * DT < until:
        if tick * DT >= signal_time - 1e-9:
            planner.stop_port.FixValue(context, [1.0, signal_time])
        simulator.AdvanceTo((tick + 1) * DT)  # runs the update of tick `tick`
        mode, left = planner.mode_port.Eval(context)
        if not changes or changes[-1][1:] != (StopMode(int(mode)).name, int(left)):
            changes.append((round(tick * DT, 3), StopMode(int(mode)).name, int(left)))
        tick += 1
    return changes, planner.plan(context)


def test_the_papers_stop_in_single_support_goes_through_every_phase(pattern):
    """3.4 s (single support): walking, the stop's landing, double support from the touchdown, the halt from
    the slowdown's end, standing from the halt's end, each from the first tick at or after it."""
    changes, plan = _modes(pattern, 3.4, 4.4)
    assert [name for _, name, _ in changes] == ["WALKING", "SINGLE_SUPPORT_STOP", "DOUBLE_SUPPORT_STOP", "HALT",
                                                "STANDING"]
    assert [left for *_, left in changes] == [0, 1, 0, 0, 0]
    first_tick = [next(k * DT for k in range(2000) if k * DT >= t)
                  for t in (3.4, plan.landing_time, plan.slowdown_end, plan.halt_end)]
    np.testing.assert_allclose([t for t, *_ in changes[1:]], first_tick, atol=1e-9)


def test_the_papers_stop_in_double_support_has_no_landing(pattern):
    """3.5 s (double support, III.B): no landing; the ZMP transition and slowdown, the halt, standing."""
    changes, plan = _modes(pattern, 3.5, 4.2)
    assert [name for _, name, _ in changes] == ["WALKING", "DOUBLE_SUPPORT_STOP", "HALT", "STANDING"]
    assert plan.landing_foot is None


def test_a_late_signal_is_latched_until_the_walks_own_step_lands():
    """III.C: a 0.7 s walk early in single support cannot stop in this step; the stop is latched (one
    landing left: the walk's own) until that touchdown, then a double-support stop."""
    pattern = NominalPattern(GaitParameters(step_time=0.7))
    signal = pattern.steps[2]["liftoff"] + 0.15
    plan = plan_stop(pattern, signal, PARAMS)
    assert plan.case == "next-step"
    assert plan.start_time == pattern.steps[2]["touchdown"]
    assert stop_mode(plan, signal, latched=True) == (StopMode.LATCHED, 1)
    assert stop_mode(plan, plan.start_time - DT, latched=True) == (StopMode.LATCHED, 1)
    assert stop_mode(plan, plan.start_time, latched=True) == (StopMode.DOUBLE_SUPPORT_STOP, 0)
    assert stop_mode(None, signal, latched=True) == (StopMode.LATCHED, 0)
    assert stop_mode(None, signal, latched=False) == (StopMode.WALKING, 0)


def test_a_stepping_plan_is_its_own_mode(plan_3_4):
    """A landing that a step follows (a two-step capture) or a recovery step is STEPPING, not the
    paper's single-support stop; the step after counts as a landing left."""
    two_steps = dataclasses.replace(plan_3_4, next_step=plan_3_4)
    assert stop_mode(two_steps, 3.45, latched=True) == (StopMode.STEPPING, 2)
    assert stop_mode(dataclasses.replace(plan_3_4, recovery_step=True), 3.45, True) == (StopMode.STEPPING, 1)


# -- before the plan: walk and latch -------------------------------------------------------------------


def test_before_the_latch_the_walk_plays_and_a_latch_plans_from_the_reference_at_the_signal():
    measured = (np.zeros(2), np.zeros(2))
    walk = decide(Observation(time=3.0, measured=measured, reference_deviation=0.01), PlanHandle(), CONFIG)
    assert (walk.kind, walk.plan_time, walk.from_measured) == (ActionKind.WALK, 3.0, False)
    latch = decide(Observation(time=3.405, latched=True, signal_time=3.402, measured=measured,
                               reference_deviation=0.05), PlanHandle(), CONFIG)
    assert (latch.kind, latch.plan_time, latch.from_measured) == (ActionKind.LATCH, 3.402, False)


def test_a_latch_off_the_walk_plans_from_the_measured_state_at_its_tick():
    """The measured DCM more than ``replan_threshold`` from the walk's: plan from it, at the tick (the later
    of the tick and the signal); without a measurement, from the reference whatever the deviation."""
    observation = Observation(time=3.405, latched=True, signal_time=3.402, measured=(np.zeros(2), np.zeros(2)),
                              reference_deviation=0.0501)
    latch = decide(observation, PlanHandle(), CONFIG)
    assert (latch.kind, latch.plan_time, latch.from_measured) == (ActionKind.LATCH, 3.405, True)
    assert not decide(observation, PlanHandle(), CONFIG.replaced(replan_threshold=0.06)
                      ).from_measured
    assert not decide(dataclasses.replace(observation, measured=None), PlanHandle(),
                      CONFIG).from_measured


# -- after the latch: re-plan or hold ------------------------------------------------------------------


def _pushed(plan, t, lateral_speed):
    """The plan's COG at ``t`` with ``lateral_speed`` [m/s] added: a DCM ``lateral_speed / omega`` off."""
    pos, vel, _, _ = plan.com([t])
    return pos[0], vel[0] + np.array([0.0, lateral_speed])


def _decide(plan, t, measured, *, config=CONFIG, **handle_changes):
    handle = PlanHandle(plan).replaced(**handle_changes)
    observation = Observation(time=t, latched=True, signal_time=plan.signal_time, measured=measured)
    return decide(observation, handle, config)


def test_a_push_in_the_air_replans_the_landing_with_room_for_two_steps(plan_3_2):
    """In single support a DCM 5.8 cm off (0.2 m/s sideways) re-plans from the first try, a recovery step
    allowed (no landing made: three left of ``max_steps``); 2.9 cm (0.1 m/s) keeps the plan."""
    omega = plan_3_2.pattern.w
    assert stop_mode(plan_3_2, 3.25, True)[0] is StopMode.SINGLE_SUPPORT_STOP
    action = _decide(plan_3_2, 3.25, _pushed(plan_3_2, 3.25, 0.2))
    assert 0.2 / omega > CONFIG.replan_threshold > 0.1 / omega
    assert (action.kind, action.first_try, action.recovery_step, action.feet) == (ActionKind.REPLAN, 0, True, None)
    assert _decide(plan_3_2, 3.25, _pushed(plan_3_2, 3.25, 0.1)).kind is ActionKind.WAIT
    # one landing allowed: the re-plan may not plan a second step
    assert not _decide(plan_3_2, 3.25, _pushed(plan_3_2, 3.25, 0.2), config=CONFIG.replaced(max_steps=1)
                       ).recovery_step
    assert not _decide(plan_3_2, 3.25, _pushed(plan_3_2, 3.25, 0.2),
                       config=CONFIG.replaced(recovery_step=False)).recovery_step
    # past the landing's last move the threshold is the landed one (8 cm): 5.8 cm keeps the plan
    assert _decide(plan_3_2, 3.37, _pushed(plan_3_2, 3.37, 0.2)).kind is ActionKind.WAIT


def test_a_replan_waits_its_interval_unless_tries_are_left(plan_3_2):
    """Within ``replan_interval`` of the last try the plan's blend acts first (WAIT); a re-plan with tries
    left in the same support goes on at once from its next try (resumed)."""
    pushed = _pushed(plan_3_2, 3.25, 0.3)
    assert _decide(plan_3_2, 3.25, pushed, last_try=3.23).kind is ActionKind.WAIT
    assert _decide(plan_3_2, 3.25, pushed, last_try=3.19).kind is ActionKind.REPLAN
    resumed = _decide(plan_3_2, 3.25, pushed, last_try=3.245, pending=("single", 2))
    assert (resumed.kind, resumed.first_try, resumed.resumed) == (ActionKind.REPLAN, 2, True)
    # tries left from another support are dropped: after the landing they no longer apply
    assert _decide(plan_3_2, 3.6, _pushed(plan_3_2, 3.6, 0.5), last_try=3.59, pending=("single", 2)
                   ).kind is ActionKind.WAIT


def test_a_push_in_double_support_replans_on_the_measured_feet(plan_3_4):
    """After the landing the threshold is ``landed_replan_threshold`` (8 cm): 5.7 cm waits, 11 cm re-plans,
    on the soles' estimates once the landed foot has been loaded ``foothold_ticks`` ticks."""
    t = 3.6
    assert stop_mode(plan_3_4, t, True)[0] is StopMode.DOUBLE_SUPPORT_STOP
    assert _decide(plan_3_4, t, _pushed(plan_3_4, t, 0.2)).kind is ActionKind.WAIT
    feet = np.array([3.0, 0.1, 2.8, -0.1, 5.0, 5.0])
    handle = PlanHandle(plan_3_4)
    observation = Observation(time=t, latched=True, signal_time=3.4, measured=_pushed(plan_3_4, t, 0.4), feet=feet)
    action = decide(observation, handle, CONFIG)
    assert action.kind is ActionKind.REPLAN and action.recovery_step
    np.testing.assert_array_equal(action.feet["left"], feet[:2])
    np.testing.assert_array_equal(action.feet["right"], feet[2:4])
    landed_side = 4 + ("left", "right").index(plan_3_4.landing_foot)
    feet[landed_side] = 1.0  # the landed sole loaded one tick: not a foothold yet
    assert decide(dataclasses.replace(observation, feet=feet), handle,
                  CONFIG).feet is None
    assert decide(observation, handle, CONFIG.replaced(measured_footholds=False)
                  ).feet is None


def test_a_replan_that_found_no_stop_tries_again_each_interval(plan_3_4):
    """No stop found (a failed re-plan: ``replan_failures`` counted, ``last_try`` its tick): the plan stays and
    the next try comes ``replan_interval`` later, from that tick's measurement."""
    pushed = _pushed(plan_3_4, 3.45, 0.4)
    assert _decide(plan_3_4, 3.45, pushed, replan_failures=1, last_try=3.42).kind is ActionKind.WAIT
    assert _decide(plan_3_4, 3.45, pushed, replan_failures=1, last_try=3.40).kind is ActionKind.REPLAN


def test_a_sole_that_landed_again_replans_at_once(plan_3_4, plan_3_2):
    """A sole re-landed off its foothold re-plans on it on its first tick, past the interval and with no
    recovery step (the DCM on the plan); before the landing it is not looked at."""
    on_plan = _pushed(plan_3_4, 3.7, 0.0)
    relanded = {"left": np.array([3.1, 0.12])}
    observation = Observation(time=3.7, latched=True, signal_time=3.4, measured=on_plan, relanded=relanded,
                              relanded_now=True)
    handle = PlanHandle(plan_3_4).replaced(last_try=3.69)
    action = decide(observation, handle, CONFIG)
    assert action.kind is ActionKind.REPLAN and not action.recovery_step
    np.testing.assert_array_equal(action.feet["left"], relanded["left"])
    later = decide(dataclasses.replace(observation, relanded_now=False), handle,
                   CONFIG)
    assert later.kind is ActionKind.WAIT  # not on its first tick: the interval holds it
    early = dataclasses.replace(observation, time=3.25, measured=_pushed(plan_3_2, 3.25, 0.0))
    assert decide(early, PlanHandle(plan_3_2), CONFIG).kind is ActionKind.WAIT


def test_in_the_halt_only_a_sole_off_the_plan_replans_and_only_with_halt_footholds(plan_3_4):
    """In the halt a loaded sole 1 cm off the plan's foot re-plans on the measured feet from the plan's own
    COG (``from_plan``, no recovery step) with ``halt_footholds``, once a stop; a DCM 11 cm off and a sole
    that landed again do not re-plan there (the body rocking). Without the option the halt keeps the
    default's rows: the DCM re-plans (which finds nothing to re-plan) and the feet are not watched."""
    t = plan_3_4.slowdown_end + 0.1
    assert stop_mode(plan_3_4, t, True)[0] is StopMode.HALT
    planned = plan_3_4.feet(t)
    feet = np.array([*planned["left"][:2], *planned["right"][:2], 40.0, 40.0])
    feet[1] -= 0.01  # the left sole 1 cm inside
    on, off = CONFIG.replaced(halt_footholds=True), CONFIG.replaced(halt_footholds=False)
    observation = Observation(time=t, latched=True, signal_time=3.4, measured=_pushed(plan_3_4, t, 0.0), feet=feet)
    action = decide(observation, PlanHandle(plan_3_4), on)
    assert action.kind is ActionKind.REPLAN and action.from_plan and not action.recovery_step
    np.testing.assert_array_equal(action.feet["left"], feet[:2])
    assert decide(observation, PlanHandle(plan_3_4), off).kind is ActionKind.WAIT  # off: not watched
    # the soles on the plan's: a DCM 11 cm off or a re-landed sole waits in the halt
    on_plan = np.array([*planned["left"][:2], *planned["right"][:2], 40.0, 40.0])
    pushed = dataclasses.replace(observation, measured=_pushed(plan_3_4, t, 0.4), feet=on_plan)
    assert decide(pushed, PlanHandle(plan_3_4), on).kind is ActionKind.WAIT
    assert decide(pushed, PlanHandle(plan_3_4), off).kind is ActionKind.REPLAN
    relanded = dataclasses.replace(observation, feet=on_plan, relanded={"left": feet[:2]}, relanded_now=True)
    assert decide(relanded, PlanHandle(plan_3_4), on).kind is ActionKind.WAIT
    # a sole off the plan with the DCM 11 cm off: the plan's COG is not the robot's, the halt waits
    assert decide(dataclasses.replace(observation, measured=_pushed(plan_3_4, t, 0.4)), PlanHandle(plan_3_4),
                  on).kind is ActionKind.WAIT
    # once the halt has been re-planned, a second sole off the plan waits
    halt_replanned = dataclasses.replace(plan_3_4, start_time=t - 0.05)
    handle = PlanHandle(plan_3_4).replaced(history=(plan_3_4, halt_replanned))
    assert halt_replans(handle.history) == 1
    assert decide(observation, handle, on).kind is ActionKind.WAIT


def test_the_halt_of_a_stop_with_no_landing_stands_on_both_soles_once_both_are_loaded(pattern):
    """A stop signalled in double support (3.5 s) has no landing: in its halt the measured soles are footholds
    once both have been loaded ``foothold_ticks`` ticks, so one 1 cm off re-plans (``halt_footholds``); with
    one sole unloaded (the body rocking onto the other) the halt waits."""
    plan = plan_stop(pattern, 3.5, PARAMS)
    t = plan.slowdown_end + 0.1
    planned = plan.feet(t)
    feet = np.array([*planned["left"][:2], *planned["right"][:2], 40.0, 40.0])
    feet[2] += 0.01  # the right sole 1 cm ahead
    observation = Observation(time=t, latched=True, signal_time=3.5, measured=_pushed(plan, t, 0.0), feet=feet)
    on = CONFIG.replaced(halt_footholds=True)
    action = decide(observation, PlanHandle(plan), on)
    assert action.kind is ActionKind.REPLAN and action.from_plan
    np.testing.assert_array_equal(action.feet["right"], feet[2:4])
    feet[4] = 0.0  # the left sole unloaded
    assert decide(dataclasses.replace(observation, feet=feet), PlanHandle(plan), on).kind is ActionKind.WAIT


def test_a_capture_landing_takes_its_next_step_at_the_touchdown_and_no_measurement_holds(plan_3_4):
    two_steps = dataclasses.replace(plan_3_4, next_step=plan_3_4)
    assert _decide(two_steps, plan_3_4.landing_time, None).kind is ActionKind.NEXT_STEP
    assert _decide(two_steps, plan_3_4.landing_time - DT, None).kind is ActionKind.HOLD
    assert _decide(plan_3_4, 3.6, None).kind is ActionKind.HOLD


def test_every_action_says_why(plan_3_4):
    action = _decide(plan_3_4, 3.42, _pushed(plan_3_4, 3.42, 0.3))
    assert isinstance(action, Action) and "DCM" in action.reason


@pytest.mark.parametrize("name, value", [("replan_threshold", 0.0), ("blend_time", float("nan")),
                                         ("foothold_tolerance", -1.0), ("foothold_ticks", 1.5),
                                         ("max_steps", 0), ("max_replan_solves", True), ("max_latch_solves", 0)])
def test_a_bad_setting_is_named(name, value):
    with pytest.raises(ValueError, match=name):
        StopPlannerConfig(**{name: value})


def test_the_planner_system_takes_its_settings_as_one_config(pattern):
    with pytest.raises(ValueError, match="config"):
        StopPlannerSystem(pattern=pattern, params=PARAMS, config={"replan_threshold": 0.05})
    planner = StopPlannerSystem(pattern=pattern, params=PARAMS, config=CONFIG.replaced(plan_ahead=False))
    assert planner.config.plan_ahead is False
    context = planner.CreateDefaultContext()
    assert planner.mode(context) == (StopMode.WALKING, 0)
