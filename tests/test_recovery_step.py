"""The recovery step: a re-plan after the landing that finds no double-support stop steps the rear foot
forward (planner.replan_stop(recovery_step=True), StopPlannerSystem(recovery_step=...))."""

import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from planner_helpers import forward_push_state, latched_stop_planner
from pydrake.systems.analysis import Simulator

from drake_estop.planning.capture import MAX_STEP_WIDTH
from drake_estop.planning.gait import SIDES
from drake_estop.planning.plan import landing_swing
from drake_estop.planning.planner import InfeasibleStop, plan_stop, replan_stop
from drake_estop.planning.recovery import RECOVERY_ZMP_MARGIN, recovery_dcm_ahead, recovery_landing_width
from drake_estop.systems.plan_sequence import PlanSequence

DT = 0.005


def _tick(t):
    return round(t / DT) * DT


def _pushed_after_landing(pattern, params, push=0.3, after=0.05):
    """The paper's 3.4 s stop, ``after`` s past its landing, with the COG ``push`` m/s faster forward than
    the plan's: its DCM is past the landed (fore) foot's ankle and no double-support stop exists."""
    plan = plan_stop(pattern, 3.4, params)
    t = _tick(plan.landing_time + after)
    pos, vel, _, _ = plan.com([t])
    return plan, t, pos[0], vel[0] + np.array([push, 0.0])


def test_a_forward_push_no_double_support_stop_holds_is_caught_by_a_recovery_step(pattern, params):
    plan, t, pos, vel = _pushed_after_landing(pattern, params)
    with pytest.raises(InfeasibleStop):  # the double-support stop alone (the default)
        replan_stop(plan, t, pos, vel)
    new = replan_stop(plan, t, pos, vel, recovery_step=True)
    fore = plan.landing_foot
    rear = next(side for side in SIDES if side != fore)
    assert new.recovery_step and new.start_support == "single" and new.start_time == pytest.approx(t)
    assert new.landing_foot == rear
    np.testing.assert_allclose(new.final_feet[fore], plan.final_feet[fore], atol=1e-12)  # the fore foot stays
    assert new.final_feet[rear][0] > plan.final_feet[fore][0]  # the rear foot steps past it
    # the swing leaves the floor where the rear foot stands and lifts it the gait's full swing height
    np.testing.assert_allclose(new.feet(t)[rear], [*plan.final_feet[rear], 0.0], atol=1e-9)
    lift = max(new.feet(s)[rear][2] for s in np.linspace(t, new.landing_time, 41))
    assert lift == pytest.approx(pattern.params.lift_height, abs=2e-3)
    # the COG continues from the measured state (eq. 10-11) and ends at rest at the feet's midpoint (eq. 27-28)
    start_pos, start_vel, _, start_zmp = new.com([t])
    np.testing.assert_allclose(start_pos[0], pos, atol=1e-9)
    np.testing.assert_allclose(start_vel[0], vel, atol=1e-9)
    end_pos, end_vel, _, _ = new.com([new.halt_end + 0.2])
    np.testing.assert_allclose(end_pos[0], 0.5 * (new.final_feet["left"] + new.final_feet["right"]), atol=1e-6)
    np.testing.assert_allclose(end_vel[0], 0.0, atol=1e-6)
    # sagittally the ZMP starts under the measured DCM, on the fore sole (held there until the landing)
    dcm = pos + vel / pattern.w
    assert start_zmp[0][0] == pytest.approx(dcm[0], abs=1e-9)
    # the ZMP stays inside the support polygon of every tick, with the recovery step's margin
    margin = min(params.zmp_margin, RECOVERY_ZMP_MARGIN)
    assert new.min_zmp_margin >= margin - 1e-9
    for s in np.arange(t, new.halt_end, 0.02):
        assert new.polygon(s).margin(new.com([s])[3])[0] >= margin - 1e-6, s
    # laterally the ZMP sends the DCM towards the feet's midline: between the feet at the touchdown
    pos_t, vel_t, _, _ = new.com([new.landing_time])
    dcm_y = pos_t[0][1] + vel_t[0][1] / pattern.w
    low, high = sorted(new.final_feet[side][1] for side in SIDES)
    assert low < dcm_y < high


def test_the_recovery_step_lands_as_planned_then_stops_in_double_support(pattern, params):
    plan, t, pos, vel = _pushed_after_landing(pattern, params)
    step = replan_stop(plan, t, pos, vel, recovery_step=True)
    later = _tick(t + 0.1)
    pos2, vel2, _, _ = step.com([later])
    # before its touchdown a deviation does not hurry it (a hurried recovery landing struck at 2.3 kN)
    assert replan_stop(step, later, pos2[0], vel2[0] + np.array([0.1, 0.0]), recovery_step=True) is None
    # after the touchdown the re-plan is a double-support stop on the new feet
    landed = _tick(step.landing_time + 0.02)
    pos3, vel3, _, _ = step.com([landed])
    stop = replan_stop(step, landed, pos3[0], vel3[0] + np.array([0.02, 0.0]), recovery_step=True)
    assert stop.start_support == "double" and not stop.recovery_step
    for side in SIDES:
        np.testing.assert_allclose(stop.final_feet[side], step.final_feet[side], atol=1e-12)


def test_no_recovery_step_where_it_cannot_help(pattern, params):
    plan, t, pos, vel = _pushed_after_landing(pattern, params)
    # a backward push: the DCM is behind the fore ankle, a forward step cannot catch it
    with pytest.raises(InfeasibleStop) as backward:
        replan_stop(plan, t, pos, vel - np.array([3.3, 0.0]), recovery_step=True)
    assert "recovery step" not in str(backward.value)
    # a DCM short of recovery_dcm_ahead past the fore ankle: the stop's own limits failed, not the feet
    fore_x = plan.final_feet[plan.landing_foot][0]
    short = vel.copy()
    short[0] = (fore_x + recovery_dcm_ahead(pattern.params.sole) - 0.01 - pos[0]) * pattern.w
    with pytest.raises(InfeasibleStop):
        replan_stop(plan, t, pos, short)
    with pytest.raises(InfeasibleStop) as near:
        replan_stop(plan, t, pos, short, recovery_step=True)
    assert "recovery step" not in str(near.value)
    # a DCM heading for the rear foot's side, past the fore sole's inner edge less the margin: lifting the
    # rear foot would drop the robot onto that side (the default); with recovery_step_inward, a DCM so fast
    # that it passes even the widest landing's ankle by the soonest touchdown
    fore_y = plan.final_feet[plan.landing_foot][1]
    rear_y = plan.final_feet[next(side for side in SIDES if side != plan.landing_foot)][1]
    inner = pattern.params.sole.inner - min(params.zmp_margin, RECOVERY_ZMP_MARGIN)
    for start, offset in ((plan, inner + 0.01), (_pushed_after_landing(pattern, replace(
            params, recovery_step_inward=True))[0], 0.2)):
        inward = vel.copy()
        inward[1] = (fore_y + math.copysign(offset, rear_y - fore_y) - pos[1]) * pattern.w
        with pytest.raises(InfeasibleStop) as sideways:
            replan_stop(start, t, pos, inward, recovery_step=True)
        assert "recovery step" not in str(sideways.value)
    # the COG so far ahead of the rear ankle that the rear leg is straight: it would drag, not lift
    rear = next(side for side in SIDES if side != plan.landing_foot)
    stretched = pos.copy()
    stretched[0] = plan.final_feet[rear][0] + params.max_rear_reach + 0.01
    with pytest.raises(InfeasibleStop) as straight:
        replan_stop(plan, t, stretched, vel, recovery_step=True)
    assert "recovery step" not in str(straight.value)
    # a push no step within the limits catches: the message names both failures
    with pytest.raises(InfeasibleStop, match="recovery step: .*single-support"):
        replan_stop(plan, t, pos, vel + np.array([2.5, 0.0]), recovery_step=True)


def test_a_recovery_step_lands_wider_where_the_dcm_heads_for_the_rear_foot(pattern, params):
    """The fore sole cannot hold a DCM heading for the rear foot's side (past the sole's inner edge less the
    margin): with ``recovery_step_inward`` the step lands wider, so that by the touchdown the DCM lies
    between the feet (eq. 6-9); without it (the default humanoid's) no step is taken there."""
    params = replace(params, recovery_step_inward=True)
    plan, t, pos, vel = _pushed_after_landing(pattern, params)
    fore = plan.landing_foot
    rear = next(side for side in SIDES if side != fore)
    fore_y, rear_y = plan.final_feet[fore][1], plan.final_feet[rear][1]
    toward = math.copysign(1.0, rear_y - fore_y)
    inner = pattern.params.sole.inner - min(params.zmp_margin, RECOVERY_ZMP_MARGIN)
    inward = vel.copy()
    inward[1] = (fore_y + toward * (inner + 0.04) - pos[1]) * pattern.w
    nominal = replan_stop(plan, t, pos, vel, recovery_step=True)
    wide = replan_stop(plan, t, pos, inward, recovery_step=True)
    assert wide.recovery_step and wide.landing_foot == rear
    nominal_width, wide_width = (abs(p.final_feet[rear][1] - fore_y) for p in (nominal, wide))
    assert nominal_width == pytest.approx(abs(rear_y - fore_y), abs=1e-9)  # the rear foot's own width
    assert nominal_width + 0.02 < wide_width <= MAX_STEP_WIDTH + 1e-9
    # the ZMP holds the fore sole's inner edge (less the margin) until the touchdown
    assert toward * (wide.com([t])[3][0][1] - fore_y) == pytest.approx(inner, abs=1e-6)
    pos_t, vel_t, _, _ = wide.com([wide.landing_time])
    dcm_y = pos_t[0][1] + vel_t[0][1] / pattern.w
    low, high = sorted(wide.final_feet[side][1] for side in SIDES)
    assert low < dcm_y < high
    end_pos, end_vel, _, _ = wide.com([wide.halt_end + 0.2])
    np.testing.assert_allclose(end_vel[0], 0.0, atol=1e-6)
    # the default: no step while the DCM heads for the rear foot's side
    standing, _, _, _ = _pushed_after_landing(pattern, replace(params, recovery_step_inward=False))
    with pytest.raises(InfeasibleStop) as held:
        replan_stop(standing, t, pos, inward, recovery_step=True)
    assert "recovery step" not in str(held.value)
    # a robot whose widest step is narrower lands at it (StopParameters.max_step_width)
    narrow, _, _, _ = _pushed_after_landing(pattern, replace(params, max_step_width=nominal_width + 0.01))
    capped = replan_stop(narrow, t, pos, inward, recovery_step=True)
    assert abs(capped.final_feet[rear][1] - fore_y) == pytest.approx(nominal_width + 0.01, abs=1e-9)


def test_recovery_landing_width():
    # the DCM reaches no further than the rear foot's midline by the touchdown: its width stands
    assert recovery_landing_width(0.02, 0.03, 0.2, math.exp(1.0)) == pytest.approx(0.2)
    assert recovery_landing_width(-0.02, -0.03, -0.2, math.exp(1.0)) == pytest.approx(-0.2)
    # past it: twice its reach, the DCM at the new midline (xi(T) = p + (xi - p) exp(w T), eq. 6-9)
    reach = 0.04 + (0.07 - 0.04) * math.exp(1.0)
    assert recovery_landing_width(0.07, 0.04, 0.19, math.exp(1.0)) == pytest.approx(2 * reach)
    assert recovery_landing_width(-0.07, -0.04, -0.19, math.exp(1.0)) == pytest.approx(-2 * reach)
    # at most the widest step; a DCM past that landing's ankle: none
    assert recovery_landing_width(0.09, 0.04, 0.19, math.exp(1.0)) == pytest.approx(MAX_STEP_WIDTH)
    assert recovery_landing_width(0.14, 0.04, 0.19, math.exp(1.0)) is None


def test_the_recovery_dcm_threshold_scales_with_the_toe(pattern):
    sole = pattern.params.sole
    assert recovery_dcm_ahead(sole) == pytest.approx(0.05, abs=1e-4)  # the default humanoid's 13.5 cm toe
    assert recovery_dcm_ahead(replace(sole, toe=0.095)) == pytest.approx(0.035, abs=2e-4)  # TALOS's 9.5 cm


def test_landing_swing_clearance_lifts_a_foot_from_the_floor_to_it():
    rest = np.zeros(3)
    heights = {clearance: max(landing_swing(rest, rest, rest, (0.4, 0.0), s, 1.0, 0.05, clearance)[2]
                              for s in np.linspace(0.0, 1.0, 101))
               for clearance in (None, 0.05)}
    assert heights[None] == pytest.approx(0.025, abs=1e-3)  # a leaving foot's default bump: half the lift
    assert heights[0.05] == pytest.approx(0.05, abs=1e-3)


def test_plan_sequence_summary_counts_the_landings_and_recovery_steps(pattern, params):
    plan, t, pos, vel = _pushed_after_landing(pattern, params)
    step = replan_stop(plan, t, pos, vel, recovery_step=True)
    summary = PlanSequence([plan, step]).summary()
    assert summary["steps_after_signal"] == 2 and summary["recovery_steps"] == 1
    assert summary["phase_times"]["landing_end"] == step.landing_time
    plain = PlanSequence([plan]).summary()
    assert plain["steps_after_signal"] == 1 and plain["recovery_steps"] == 0
    # a landing re-planned before its touchdown is made once, by the re-plan
    early = plan_stop(pattern, 3.1, params)
    before = _tick(3.15)
    early_pos, early_vel, _, _ = early.com([before])
    moved = replan_stop(early, before, early_pos[0], early_vel[0] + np.array([0.02, 0.0]))
    assert moved.landing_foot == early.landing_foot
    assert PlanSequence([early, moved]).summary()["steps_after_signal"] == 1


# -- StopPlannerSystem alone ------------------------------------------------------------------------


def _pushed_planner(pattern, params, push, feet=None, after=0.05, **kwargs):
    """StopPlannerSystem (FixValue inputs, Simulator.AdvanceTo) latched at 3.4 s from the reference; no
    measurement until ``after`` s past the landing, then the plan's COG ``push`` m/s faster forward and, if
    given, ``feet`` (6) on ``measured_feet``. Returns the planner, its context, the first plan and that tick."""
    planner, context, simulator, first = latched_stop_planner(pattern, params, **kwargs)
    t = _tick(first.landing_time + after)
    simulator.AdvanceTo(t - DT / 2)
    pos, vel, _, _ = first.com([t])
    planner.measured_com_port.FixValue(context, [*pos[0], 0.8])
    planner.measured_com_vel_port.FixValue(context, [*(vel[0] + np.array([push, 0.0])), 0.0])
    if feet is not None:
        planner.measured_feet_port.FixValue(context, feet)
    simulator.AdvanceTo(t + DT / 2)
    return planner, context, first, t


def test_planner_takes_a_recovery_step_after_a_forward_push(pattern, params):
    planner, context, first, t = _pushed_planner(pattern, params, 0.3)
    assert planner.replans(context) == (1, 0)
    step = planner.plan(context)
    assert step.recovery_step and step.start_time == pytest.approx(t)
    rear = next(side for side in SIDES if side != first.landing_foot)
    # the sole target of the rear foot starts where it stands and rises
    port = planner.GetOutputPort(f"{rear}_foot")
    np.testing.assert_allclose(port.Eval(context)[:2], first.final_feet[rear], atol=1e-6)
    Simulator(planner, context).AdvanceTo(t + 0.1)
    assert port.Eval(context)[2] > 0.01
    # without it the re-plan fails and the plan stays
    planner, context, _, _ = _pushed_planner(pattern, params, 0.3, recovery_step=False)
    assert planner.replans(context) == (0, 1)
    kept = planner.plan(context)
    assert not kept.recovery_step and kept.start_time == pytest.approx(first.start_time)


def test_every_replan_after_a_landing_stands_on_the_measured_feet(pattern, params):
    """Not only the first: a double-support re-plan (no landing foot of its own) takes the feet again."""
    first = plan_stop(pattern, 3.4, params)
    fore, rear = first.landing_foot, next(side for side in SIDES if side != first.landing_foot)

    def vector(slide):
        feet = {fore: first.final_feet[fore] + [slide, 0.0], rear: first.final_feet[rear]}
        return [*feet["left"], *feet["right"], 40.0, 40.0]

    planner, context, _, t = _pushed_planner(pattern, params, 0.05, feet=vector(0.004), after=0.02,
                                             landed_replan_threshold=0.01)
    assert planner.replans(context) == (1, 0)
    assert planner.plan(context).final_feet[fore][0] == pytest.approx(first.final_feet[fore][0] + 0.004)
    # the fore foot slides 5 mm more; a second deviation re-plans on it
    planner.measured_com_port.FixValue(context, [np.nan] * 3)  # no measurement until then
    later = _tick(t + 0.1)
    Simulator(planner, context).AdvanceTo(later - DT / 2)
    planner.measured_feet_port.FixValue(context, vector(0.009))
    plan = planner.plan(context)
    pos, vel, _, _ = plan.com([later])
    planner.measured_com_vel_port.FixValue(context, [*vel[0], 0.0])
    planner.measured_com_port.FixValue(context, [*(pos[0] + np.array([0.0, 0.012])), 0.8])  # 1.2 cm aside
    Simulator(planner, context).AdvanceTo(later + DT / 2)
    assert planner.replans(context) == (2, 0)
    assert planner.plan(context).landing_foot is None
    assert planner.plan(context).final_feet[fore][0] == pytest.approx(first.final_feet[fore][0] + 0.009)


def _pushed_forward_at_3_1(**kwargs):
    """StopPlannerSystem (``kwargs`` over the defaults) latched at 2.95 s from the reference (the online
    controller's parameters), given at 3.1 s the state measured after a 35 N s forward push (no landing
    stops it: planning.capture_landing.capture_step). Returns the planner, its context and simulator."""
    from drake_estop.physics.online import controller_stop_parameters
    from drake_estop.planning.gait import NominalPattern

    planner, context, simulator, _ = latched_stop_planner(NominalPattern(), controller_stop_parameters(), t0=2.95,
                                                          max_replan_solves=None, **kwargs)  # every try at 3.1 s
    simulator.AdvanceTo(3.1 - DT / 2)
    _, t, com, vel = forward_push_state()
    planner.measured_com_port.FixValue(context, [*com, 0.8])
    planner.measured_com_vel_port.FixValue(context, [*vel, 0.0])
    simulator.AdvanceTo(t + DT / 2)
    return planner, context, simulator


def _two_step_planner(measure_at_touchdown: bool):
    """:func:`_pushed_forward_at_3_1`'s planner (the capture landing and a recovery step), then no
    measurement until the touchdown; there the composite plan's own COG if ``measure_at_touchdown``, else
    none. Returns the planner, its context and the two-step plan."""
    planner, context, simulator = _pushed_forward_at_3_1()
    caught = planner.plan(context)
    assert caught.next_step is not None and caught.start_time == pytest.approx(3.1)
    planner.measured_com_port.FixValue(context, [np.nan] * 3)
    simulator.AdvanceTo(caught.landing_time - DT / 2)
    assert planner.plan(context) is caught  # no measurement: the swing lands as planned
    if measure_at_touchdown:
        pos, vel, _, _ = caught.com([caught.landing_time])
        planner.measured_com_port.FixValue(context, [*pos[0], 0.8])
        planner.measured_com_vel_port.FixValue(context, [*vel[0], 0.0])
    simulator.AdvanceTo(caught.landing_time + DT / 2)
    return planner, context, caught


def test_planner_takes_the_second_step_of_a_two_step_capture_at_its_touchdown():
    """At the capture landing's touchdown the planner steps on: the recovery step re-planned from the
    measured state (here the plan's own, so it lands where the planned one does), or without a measurement
    the one planned with the capture landing; the summary counts both steps."""
    planner, context, caught = _two_step_planner(measure_at_touchdown=True)
    step = planner.plan(context)
    assert step.recovery_step and step is not caught.next_step
    assert step.start_time == pytest.approx(caught.landing_time) and step.landing_foot == "left"
    np.testing.assert_allclose(step.landing_position, caught.next_step.landing_position, atol=1e-4)
    assert step.landing_time == pytest.approx(caught.next_step.landing_time, abs=0.02)  # the solve's ticks
    summary = planner.plans(context).summary()
    assert [s["kind"] for s in summary["steps"]] == ["capture landing", "recovery step"]
    planner, context, caught = _two_step_planner(measure_at_touchdown=False)
    assert planner.plan(context) is caught.next_step


def test_a_stop_takes_no_more_steps_than_max_steps():
    """``max_steps`` bounds the landings after the signal: with one, the forward push's re-plan may not plan
    a second step (the capture landing alone stops nothing: the plan stays, the re-plan counts as failed);
    with two it does. Not a positive integer: ValueError naming it."""
    from drake_estop.physics.online import controller_stop_parameters
    from drake_estop.planning.gait import NominalPattern
    from drake_estop.planning.replan import MAX_STOP_STEPS
    from drake_estop.systems.decision import StopPlannerConfig
    from drake_estop.systems.stop_controller import StopPlannerSystem

    planner, context, _ = _pushed_forward_at_3_1(max_steps=1)
    assert planner.plan(context).next_step is None and planner.replans(context) == (0, 1)
    planner, context, _ = _pushed_forward_at_3_1(max_steps=2)
    assert planner.plan(context).next_step is not None and planner.replans(context) == (1, 0)
    assert MAX_STOP_STEPS == 3
    for bad in (0, 2.0, True):
        with pytest.raises(ValueError, match="max_steps"):
            StopPlannerSystem(pattern=NominalPattern(), params=controller_stop_parameters(),
                              config=StopPlannerConfig(max_steps=bad))


def test_landings_made_counts_the_touchdowns_by_a_time():
    """The walk's own landings after the signal and the stop's, each once it has touched down (a landing
    re-planned before its touchdown is not one)."""
    from drake_estop.systems.plan_sequence import landings_made

    plan, t, com, vel = forward_push_state()
    caught = replan_stop(plan, t, com, vel, recovery_step=True)
    step = caught.next_step
    history = (plan, caught, step)
    assert landings_made((), 5.0) == 0
    assert landings_made(history, caught.landing_time - DT) == 0  # the first plan's landing was re-planned
    assert landings_made(history, caught.landing_time) == 1
    assert landings_made(history, step.landing_time) == 2
    # a stop that starts at the next support phase (III.C): the walk's own landing before it counts
    late = SimpleNamespace(walk_landings=[{"time": 3.5, "foot": "right", "kind": "walk"}], landing_foot=None,
                           start_time=3.5)
    assert [landings_made((late,), t) for t in (3.45, 3.5)] == [0, 1]
