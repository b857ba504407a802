"""Planning from the measured state and re-planning: the planner functions (``plan_stop`` from a measured
state, ``replan_stop``) and the plans as one sequence (``PlanSequence``)."""

import math
from dataclasses import replace

import numpy as np
import pytest
from planner_helpers import (
    DT,
    count_solves,
    forward_push_state,
    left_push_state,
    moved_feet,
    replan_params,
    sideways_at,
    state_at,
)

from drake_estop.planning import capture_landing
from drake_estop.planning.capture import MAX_STEP_WIDTH
from drake_estop.planning.gait import GaitParameters, NominalPattern
from drake_estop.planning.geometry import SupportPolygon
from drake_estop.planning.planner import InfeasibleStop, StopParameters, plan_stop, replan_stop
from drake_estop.planning.recovery import RECOVERY_ZMP_MARGIN
from drake_estop.planning.replan import replan_support
from drake_estop.systems.plan_sequence import PlanSequence


@pytest.fixture(scope="module")
def params():
    return replan_params()


def _slowdown_end_velocity(plan):
    _, vel, _, _ = plan.com([plan.slowdown_end])
    return vel[0]


def test_plan_from_the_reference_state_equals_the_nominal_plan(pattern, params):
    nominal = plan_stop(pattern, 3.1, params)
    pos, vel, _ = state_at(nominal, 3.1)
    measured = plan_stop(pattern, 3.1, params, measured=(pos, vel))
    assert measured.case == nominal.case
    assert measured.step_length == pytest.approx(nominal.step_length, abs=1e-9)
    assert measured.halt_end == pytest.approx(nominal.halt_end, abs=1e-9)


def test_plan_from_a_measured_state_starts_there_and_stops(pattern, params):
    t = 3.15
    pos, vel, zmp = state_at(plan_stop(pattern, t, params), t)
    faster = vel + np.array([0.02, 0.0])
    plan = plan_stop(pattern, t, params, measured=(pos, faster))
    assert plan.case == "one-step"
    start_pos, start_vel, start_zmp = state_at(plan, plan.start_time)
    np.testing.assert_allclose(start_pos, pos, atol=1e-12)  # eq. 10
    np.testing.assert_allclose(start_vel, faster, atol=1e-12)  # eq. 11
    np.testing.assert_allclose(start_zmp, zmp, atol=1e-12)  # eq. 12: the ZMP stays continuous
    assert plan.step_length > plan_stop(pattern, t, params).step_length  # a faster COG needs a longer step
    assert abs(_slowdown_end_velocity(plan)[0]) < 1e-6  # eq. 17


def test_a_next_step_fallback_carries_the_measured_deviation(pattern, params):
    """Where the deviation makes a one-step stop infeasible, the fallback starts from the pattern's
    later state plus the deviation propagated by the LIPM, not from the nominal state."""
    t = 3.1
    pos, vel, _ = state_at(plan_stop(pattern, t, params), t)
    faster = vel + np.array([0.05, 0.0])
    plan = plan_stop(pattern, t, params, measured=(pos, faster))
    assert plan.case == "next-step"
    s = plan.start_time - plan_stop(pattern, t, params).start_time
    w = pattern.w
    nominal_pos, nominal_vel, _, _ = pattern.com([plan.start_time])
    start_pos, start_vel, _ = state_at(plan, plan.start_time)
    np.testing.assert_allclose(start_pos[0] - nominal_pos[0][0], 0.05 / w * np.sinh(w * s), atol=1e-9)
    np.testing.assert_allclose(start_vel[0] - nominal_vel[0][0], 0.05 * np.cosh(w * s), atol=1e-9)
    # the summary lists the walk's own landing, which finishes the step before the double-support stop
    steps = plan.summary()["steps"]
    assert plan.landing_foot is None and [step["kind"] for step in steps] == ["walk"]
    assert t < steps[0]["time"] <= plan.start_time and plan.summary()["steps_after_signal"] == 1


@pytest.mark.parametrize("value", [(np.nan, 0.0), (np.inf, 1.0)])
def test_plan_stop_rejects_a_non_finite_measured_state(pattern, params, value):
    with pytest.raises(ValueError, match="measured"):
        plan_stop(pattern, 3.1, params, measured=(np.array(value), np.zeros(2)))


def test_plan_stop_bounds_its_search_by_max_solves(pattern, monkeypatch):
    """A state no stop catches (3 m/s sideways) costs plan_stop a solve at every tick of the next two steps;
    ``max_solves`` ends the search after that many tries, with a message that says so."""
    from drake_estop.planning import planner as planner_module

    t, params = 3.1, StopParameters()
    com, com_vel = sideways_at(pattern, t, 3.0)
    measured = (com[:2], com_vel[:2])
    solves = []
    solve = planner_module.plan_from
    monkeypatch.setattr(planner_module, "plan_from",
                        lambda *args, **kwargs: solves.append(1) or solve(*args, **kwargs))
    with pytest.raises(InfeasibleStop, match="within two steps"):
        plan_stop(pattern, t, params, measured=measured)
    unbounded, solves[:] = len(solves), []
    with pytest.raises(InfeasibleStop, match="no feasible stop in the first 3 tries after t=3.100 s"):
        plan_stop(pattern, t, params, measured=measured, max_solves=3)
    assert len(solves) == 3 < unbounded


def test_a_bound_that_the_search_does_not_reach_gives_the_same_plan(pattern, params):
    """A next-step stop (III.C) found at the second try is the same plan with max_solves=2 (a 0.7 s walk
    early in single support: the default walk has no next-step tick)."""
    pattern = NominalPattern(GaitParameters(step_time=0.7))
    t = next(t for t in np.arange(2.6, 3.4, DT) if plan_stop(pattern, t, params).case == "next-step")
    pos, vel, _, _ = pattern.com([t])
    measured = (pos[0], vel[0] + np.array([0.01, 0.0]))
    plan = plan_stop(pattern, t, params, measured=measured)
    assert plan.case == "next-step"
    bounded = plan_stop(pattern, t, params, measured=measured, max_solves=2)
    assert (bounded.start_time, bounded.landing_time, bounded.halt_end) == (plan.start_time, plan.landing_time,
                                                                           plan.halt_end)
    with pytest.raises(InfeasibleStop, match="first 1 tries"):
        plan_stop(pattern, t, params, measured=measured, max_solves=1)


@pytest.mark.parametrize("value", [0, -1, 1.5, True])
def test_plan_stop_rejects_a_bad_max_solves(pattern, params, value):
    with pytest.raises(ValueError, match="max_solves"):
        plan_stop(pattern, 3.1, params, max_solves=value)


def test_controller_stop_parameters_keep_the_user_settings():
    from drake_estop.physics.online import controller_stop_parameters
    params = controller_stop_parameters(StopParameters(a_ss=7.0, zmp_margin=0.05))
    assert params.a_ss == 7.0
    assert params.zmp_margin == 0.05  # a larger margin than the controller's is kept
    assert controller_stop_parameters().zmp_margin == pytest.approx(0.03)
    assert min(controller_stop_parameters().halt_durations) >= 1.0
    assert StopParameters is type(params)
    assert isinstance(params, StopParameters)
    assert params != StopParameters()


# -- re-plans from the measured state -----------------------------------------------------------------


def test_replan_in_the_landing_phase_moves_the_landing(pattern, params):
    plan = plan_stop(pattern, 3.1, params)
    t = 3.15
    pos, vel, zmp = state_at(plan, t)
    pushed = vel + np.array([0.02, 0.0])
    new = replan_stop(plan, t, pos, pushed)
    assert new.start_time == pytest.approx(t)
    assert new.step_length > plan.step_length
    start_pos, start_vel, start_zmp = state_at(new, t)
    np.testing.assert_allclose(start_vel, pushed, atol=1e-12)
    np.testing.assert_allclose(start_zmp, zmp, atol=1e-9)
    # the swing foot continues from where the old plan had it, at the same velocity
    np.testing.assert_allclose(new.feet(t)[new.landing_foot], plan.feet(t)[plan.landing_foot], atol=1e-12)
    h = 1e-4
    v_old = (plan.feet(t + h)[plan.landing_foot] - plan.feet(t - h)[plan.landing_foot]) / (2 * h)
    v_new = (new.feet(t + h)[new.landing_foot] - new.feet(t)[new.landing_foot]) / h
    np.testing.assert_allclose(v_new, v_old, atol=2e-3)
    assert abs(_slowdown_end_velocity(new)[0]) < 1e-6
    assert new.min_zmp_margin >= params.zmp_margin - 1e-9


def test_replan_after_the_landing_may_stop_the_cog_over_the_rear_foot(pattern, params):
    """III.B keeps ZMP_max on the fore sole; a re-plan after a backward push may use the whole polygon."""
    plan = plan_stop(pattern, 3.4, params)
    t = plan.landing_time + 0.05
    pos, vel, _ = state_at(plan, t)
    slowed = np.array([0.05, vel[1]])
    new = replan_stop(plan, t, pos, slowed)
    assert new.start_support == "double"
    rear = next(s for s in new.final_feet if s != plan.landing_foot)
    fore_heel = plan.final_feet[plan.landing_foot][0] - pattern.params.sole.heel
    target = new.start_state.zmp[0] + new.zmp_max
    assert target < fore_heel  # behind the fore sole: between the feet or on the rear foot
    assert target > new.final_feet[rear][0] - pattern.params.sole.heel
    assert abs(_slowdown_end_velocity(new)[0]) < 1e-6
    # the COG ends at rest at the feet's midpoint (eq. 27-28)
    end_pos, end_vel, _ = state_at(new, new.halt_end + 0.2)
    np.testing.assert_allclose(end_pos, 0.5 * (new.final_feet["left"] + new.final_feet["right"]), atol=1e-6)
    np.testing.assert_allclose(end_vel, 0.0, atol=1e-6)


def test_replan_keeps_the_crouch_of_the_plan_it_replaces(pattern, params):
    plan = plan_stop(pattern, 3.1, params)
    t = 3.15
    pos, vel, _ = state_at(plan, t)
    new = replan_stop(plan, t, pos, vel + np.array([0.02, 0.0]))
    z_old = plan.com_height([t])[0][0]
    z_new = new.com_height([t])[0][0]
    assert z_new == pytest.approx(z_old, abs=1e-12)


def test_ankle_strategy_replans_what_a_held_support_zmp_cannot(monkeypatch):
    from drake_estop.planning import replan

    plan, t, com, vel = left_push_state()
    new = replan_stop(plan, t, com, vel)
    old_zmp = np.array([traj.evaluate_at(t)[3] for traj in (plan.x, plan.y)])
    start_pos, start_vel, start_zmp = state_at(new, t)
    np.testing.assert_allclose(start_pos, com, atol=1e-12)  # eq. 10
    np.testing.assert_allclose(start_vel, vel, atol=1e-12)  # eq. 11
    assert start_zmp[1] > old_zmp[1] + 0.03  # the ZMP moved out under the support foot
    # held there until the landing, inside the support sole less the margin
    _, _, _, zmp = new.com(np.linspace(t, new.landing_time - 1e-6, 20))
    np.testing.assert_allclose(zmp, np.tile(start_zmp, (20, 1)), atol=1e-9)
    sole = plan.pattern.params.sole
    ankle = plan.feet(t)["left"][:2]
    margin = new.params.zmp_margin
    assert -sole.heel + margin - 1e-9 <= start_zmp[0] - ankle[0] <= sole.toe - margin + 1e-9
    assert -sole.inner + margin - 1e-9 <= start_zmp[1] - ankle[1] <= sole.outer - margin + 1e-9
    assert new.min_zmp_margin >= margin - 1e-9
    assert abs(_slowdown_end_velocity(new)[0]) < 1e-6  # eq. 17 (laterally the target sits on the fore sole's edge)
    assert np.linalg.norm(new.com([new.halt_end])[1]) < 1e-6  # at rest after the halt
    monkeypatch.setattr(replan, "ankle_zmp", lambda *args: None)
    with pytest.raises(InfeasibleStop):
        replan_stop(plan, t, com, vel)


def test_ankle_strategy_builds_the_replans_start_once_for_all_its_tries(monkeypatch):
    """The ankle strategy's tries differ only in the stance ZMP: the measured start (the feet's motion and
    the swing's braking time) is built once, and every try solves from it with its own ZMP."""
    from drake_estop.planning import replan

    plan, t, com, vel = left_push_state()
    braking, solved = [], []
    real_braking, real_plan_from = replan.swing_braking_time, replan.plan_from
    monkeypatch.setattr(replan, "swing_braking_time", lambda *a: braking.append(a) or real_braking(*a))
    monkeypatch.setattr(replan, "plan_from",
                        lambda pattern, state, *a, **k: solved.append(state.zmp.copy()) or real_plan_from(
                            pattern, state, *a, **k))
    new = replan_stop(plan, t, com, vel)
    assert len(braking) == 1 and len(solved) >= 2  # the held ZMP failed, an ankle-strategy ZMP held
    np.testing.assert_allclose(solved[0], [traj.evaluate_at(t)[3] for traj in (plan.x, plan.y)])
    np.testing.assert_allclose(state_at(new, t)[2], solved[-1], atol=1e-12)  # the last try is the plan
    assert not np.allclose(solved[0], solved[-1])


def test_ankle_zmp_brings_the_dcm_back_onto_the_plan_at_the_landing():
    from drake_estop.planning.replan import ankle_zmp

    plan, t, _, _ = left_push_state()
    pos, vel, _ = state_at(plan, t)
    assert ankle_zmp(plan, t, pos, vel) is None  # on the plan: nothing to take back
    w = plan.pattern.w
    slower = vel - np.array([0.01, 0.0])  # small: the answer lies inside the sole
    zmp = ankle_zmp(plan, t, pos, slower)
    grow = math.exp(w * (plan.landing_time - t))
    xi = zmp + (pos + slower / w - zmp) * grow  # eq. 6-9 with the ZMP held at zmp
    landing_pos, landing_vel, _ = state_at(plan, plan.landing_time)
    np.testing.assert_allclose(xi, landing_pos + landing_vel / w, atol=1e-9)
    assert zmp[0] < plan.feet(t)["left"][0]  # behind the ankle: the COG is let go forward
    far = ankle_zmp(plan, t, pos, vel + np.array([0.0, 0.5]))  # clamped to the sole's outer edge less the margin
    outer = plan.feet(t)["left"][1] + plan.pattern.params.sole.outer - plan.params.zmp_margin
    assert far[1] == pytest.approx(outer, abs=1e-12)


def test_nothing_to_replan_in_the_halt(pattern, params):
    plan = plan_stop(pattern, 3.4, params)
    t = plan.slowdown_end + 0.1
    pos, vel, _ = state_at(plan, t)
    assert replan_stop(plan, t, pos, vel) is None


def test_replan_raises_when_no_stop_exists(pattern, params):
    plan = plan_stop(pattern, 3.4, params)
    t = plan.landing_time + 0.02
    pos, _, _ = state_at(plan, t)
    with pytest.raises(InfeasibleStop):
        replan_stop(plan, t, pos, np.array([3.0, 0.0]))  # 3 m/s: no ZMP in the feet stops it


def test_replan_after_the_landing_stands_on_measured_footholds(pattern, params):
    plan = plan_stop(pattern, 3.4, params)
    t = plan.landing_time + 0.02
    pos, vel, _ = state_at(plan, t)
    feet = moved_feet(plan)
    new = replan_stop(plan, t, pos, vel + np.array([0.05, 0.0]), feet=feet)
    assert new.start_support == "double"
    for side in feet:
        np.testing.assert_allclose(new.final_feet[side][:2], feet[side], atol=1e-12)
        np.testing.assert_allclose(new.feet(t)[side][:2], feet[side], atol=1e-12)  # the sole targets
    # the ZMP stays in the polygon of the feet where they are, with the plan's margin (III.B)
    assert new.min_zmp_margin >= params.zmp_margin - 1e-9
    sole = pattern.params.sole
    polygon = SupportPolygon(np.vstack([sole.corners(feet[s], s, 0.0) for s in feet]))
    zmp = new.com(np.linspace(t, new.halt_end, 60))[3]
    assert polygon.margin(zmp).min() >= params.zmp_margin - 1e-6
    # and the COG comes to rest at their midpoint (eq. 27-28)
    end_pos, end_vel, _ = state_at(new, new.halt_end + 0.2)
    np.testing.assert_allclose(end_pos, 0.5 * (feet["left"] + feet["right"]), atol=1e-6)
    np.testing.assert_allclose(end_vel, 0.0, atol=1e-6)
    # without them the re-plan keeps the plan's feet
    kept = replan_stop(plan, t, pos, vel + np.array([0.05, 0.0]))
    for side in feet:
        np.testing.assert_allclose(kept.final_feet[side], plan.final_feet[side], atol=1e-12)


def test_measured_footholds_are_ignored_before_the_landing(pattern, params):
    plan = plan_stop(pattern, 3.1, params)
    t = 3.15
    pos, vel, _ = state_at(plan, t)
    new = replan_stop(plan, t, pos, vel + np.array([0.02, 0.0]), feet=moved_feet(plan))
    plain = replan_stop(plan, t, pos, vel + np.array([0.02, 0.0]))
    for side in ("left", "right"):
        np.testing.assert_allclose(new.final_feet[side], plain.final_feet[side], atol=1e-12)


@pytest.mark.parametrize("feet, message", [
    ({"left": (np.nan, 0.1)}, "feet\\['left'\\]"),
    ({"right": (0.9,)}, "feet\\['right'\\]"),
    ({"middle": (0.9, 0.0)}, "feet: sides"),
])
def test_replan_rejects_bad_footholds(pattern, params, feet, message):
    plan = plan_stop(pattern, 3.4, params)
    t = plan.landing_time + 0.05
    pos, vel, _ = state_at(plan, t)
    with pytest.raises(ValueError, match=message):
        replan_stop(plan, t, pos, vel, feet=feet)


# -- a re-plan's tries bounded per call --------------------------------------------------------------


def _hopeless_left_push():
    """The 2.95 s plan and the state measured at 3.05 s after a 29 N s push to the left (a physics
    run): no try gives a stop (the held ZMP and the ankle strategy's three each fail at the halt)."""
    from drake_estop.physics.online import controller_stop_parameters

    plan = plan_stop(NominalPattern(), 2.95, controller_stop_parameters())
    return plan, 3.05, np.array([0.57120388, 0.05304342]), np.array([0.32019992, 0.22598745])


def test_replan_support_names_what_a_replan_would_solve(pattern, params):
    from drake_estop.planning.replan import replan_support

    plan = plan_stop(pattern, 3.15, params)
    assert replan_support(plan, 3.15) == "single"
    assert replan_support(plan, plan.landing_time - params.min_landing_time - DT) == "single"
    assert replan_support(plan, plan.landing_time - params.min_landing_time) is None  # the landing is set
    assert replan_support(plan, plan.landing_time) == "double"
    assert replan_support(plan, plan.slowdown_end) is None  # the halt
    assert replan_support(plan, 3.1) is None  # before the plan


def test_a_bounded_replan_goes_on_with_its_tries_where_it_stopped(monkeypatch):
    """max_solves=2: the held ZMP and the ankle ZMP fail and the call says where to go on (the ankle ZMP's
    lateral part); resumed there from the same measurement it gives the unbounded call's plan, to the bit."""
    from drake_estop.planning.replan import ReplanPending

    plan, t, com, vel = left_push_state()
    solves = count_solves(monkeypatch)
    whole = replan_stop(plan, t, com, vel)
    assert len(solves) == 3  # the held ZMP, the ankle ZMP, its lateral part
    solves.clear()
    with pytest.raises(ReplanPending) as pending:
        replan_stop(plan, t, com, vel, max_solves=2)
    assert len(solves) == 2
    assert (pending.value.support, pending.value.next_try) == ("single", 2)
    resumed = replan_stop(plan, t, com, vel, first_try=pending.value.next_try, max_solves=2)
    assert len(solves) == 3
    times = np.linspace(t, whole.halt_end, 50)
    np.testing.assert_array_equal(resumed.com(times)[0], whole.com(times)[0])
    assert resumed.landing_time == whole.landing_time


def test_a_replan_with_no_stop_spreads_its_four_solves_and_then_fails(monkeypatch):
    from drake_estop.planning.replan import ReplanPending

    plan, t, com, vel = _hopeless_left_push()
    solves = count_solves(monkeypatch)
    with pytest.raises(InfeasibleStop) as whole:
        replan_stop(plan, t, com, vel)
    assert not isinstance(whole.value, ReplanPending) and len(solves) == 4
    solves.clear()
    with pytest.raises(ReplanPending) as pending:
        replan_stop(plan, t, com, vel, max_solves=2)
    assert len(solves) == 2 and pending.value.next_try == 2
    with pytest.raises(InfeasibleStop) as last:
        replan_stop(plan, t, com, vel, first_try=2, max_solves=2)
    assert not isinstance(last.value, ReplanPending) and len(solves) == 4
    assert str(last.value) == str(whole.value)  # the same last try failed the same way


def test_a_bounded_double_support_replan_takes_its_recovery_step_on_the_next_call():
    """A forward push in double support (3.55 s signal, measured at 3.665 s): the held ZMP has no stop;
    with one solve a call the recovery step is the next call's."""
    from drake_estop.physics.online import controller_stop_parameters
    from drake_estop.planning.replan import ReplanPending

    plan = plan_stop(NominalPattern(), 3.55, controller_stop_parameters())
    t, com, vel = 3.665, np.array([0.80341699, -0.01403402]), np.array([0.61912665, -0.21738769])
    whole = replan_stop(plan, t, com, vel, recovery_step=True)
    assert whole.recovery_step
    with pytest.raises(ReplanPending) as pending:
        replan_stop(plan, t, com, vel, recovery_step=True, max_solves=1)
    assert (pending.value.support, pending.value.next_try) == ("double", 1)
    step = replan_stop(plan, t, com, vel, recovery_step=True, first_try=1, max_solves=1)
    assert step.recovery_step and step.landing_time == whole.landing_time
    with pytest.raises(InfeasibleStop) as no_step:  # without the step nothing is left to try
        replan_stop(plan, t, com, vel, max_solves=1)
    assert not isinstance(no_step.value, ReplanPending)


@pytest.mark.parametrize("kwargs, name", [({"max_solves": 0}, "max_solves"), ({"max_solves": True}, "max_solves"),
                                          ({"max_solves": 1.5}, "max_solves"), ({"first_try": 5}, "first_try"),
                                          ({"first_try": -1}, "first_try"), ({"first_try": 1.0}, "first_try")])
def test_replan_rejects_bad_try_settings(kwargs, name):
    plan, t, com, vel = left_push_state()
    with pytest.raises(ValueError, match=name):
        replan_stop(plan, t, com, vel, **kwargs)


# -- the plans as one sequence ------------------------------------------------------------------------


def test_plan_sequence_evaluates_each_plan_from_its_start(pattern, params):
    first = plan_stop(pattern, 3.1, params)
    t = 3.15
    pos, vel, _ = state_at(first, t)
    second = replan_stop(first, t, pos, vel + np.array([0.02, 0.0]))
    sequence = PlanSequence([first, second])
    times = np.array([3.12, 3.149, 3.16, 3.5])
    got = sequence.com(times)[0]
    np.testing.assert_allclose(got[:2], first.com(times[:2])[0])
    np.testing.assert_allclose(got[2:], second.com(times[2:])[0])
    assert sequence.signal_time == first.signal_time
    assert sequence.halt_end == second.halt_end
    np.testing.assert_allclose(sequence.feet(3.12)[first.landing_foot], first.feet(3.12)[first.landing_foot])
    np.testing.assert_allclose(sequence.feet(3.3)[second.landing_foot], second.feet(3.3)[second.landing_foot])


def test_plan_sequence_summary_keeps_the_landing_and_counts_the_replans(pattern, params):
    first = plan_stop(pattern, 3.4, params)
    t = first.landing_time + 0.05
    pos, vel, _ = state_at(first, t)
    second = replan_stop(first, t, pos, 0.8 * vel)  # after the landing: a double-support re-plan
    summary = PlanSequence([first, second]).summary()
    assert summary["replans"] == 1
    assert summary["estop_time"] == first.signal_time
    assert summary["phase_times"]["landing_end"] == first.landing_time  # not the re-plan's start
    assert summary["phase_times"]["halt_end"] == second.halt_end
    assert summary["first_plan"]["step_length"] == first.step_length


# -- the capture landing ----------------------------------------------------------------------------------

def _right_push_state():
    """The 2.95 s plan and the state the robot measured at 3.145 s after a 29 N s (0.5 m/s) push to the
    right (a physics run): the left foot supports, the DCM runs towards the swing (right) foot's side."""
    from drake_estop.physics.online import controller_stop_parameters

    plan = plan_stop(NominalPattern(), 2.95, controller_stop_parameters())
    return plan, 3.145, np.array([0.59922757, 0.01460026]), np.array([0.27166543, -0.26427723])


def test_a_push_towards_the_swing_foot_lands_sooner_at_the_widest_step(monkeypatch):
    from drake_estop.planning import replan

    plan, t, com, vel = _right_push_state()
    caught = replan_stop(plan, t, com, vel)
    assert caught.landing_time < plan.landing_time - 0.1  # 3.345 s against 3.455 s
    support_y, sole = 0.095, plan.pattern.params.sole
    assert caught.landing_position[1] == pytest.approx(support_y - MAX_STEP_WIDTH)
    # the LIPM's DCM at the touchdown (eq. 6-9) lies within 5 cm of the landed ankle and inside its sole's
    # outer edge less the margin: in the support polygon the landing makes
    pos, speed, _, _ = caught.com([caught.landing_time])
    dcm = pos[0] + speed[0] / plan.pattern.w
    landed_y = caught.landing_position[1]
    assert landed_y - sole.outer + caught.params.zmp_margin < dcm[1] < landed_y + 0.05
    assert caught.min_zmp_margin >= caught.params.zmp_margin - 1e-9
    _, end_speed, _, _ = caught.com([caught.halt_end + 0.5])
    assert np.max(np.abs(end_speed)) < 1e-6  # at rest
    # the swing brakes onto the landing within the capture landing's acceleration
    start = caught.swing_start
    soonest = replan.swing_braking_time(start["pos"], start["vel"], start["acc"], caught.landing_position,
                                        replace(caught.params, min_landing_time=DT,
                                                max_swing_acceleration=capture_landing.CAPTURE_SWING_ACCELERATION))
    assert soonest <= caught.landing_time - t + 1e-9
    monkeypatch.setattr(replan, "capture_setup", lambda *args: None)
    with pytest.raises(InfeasibleStop):
        replan_stop(plan, t, com, vel)


def test_the_capture_landing_is_not_tried_for_a_push_towards_the_support_foot(monkeypatch):
    from drake_estop.planning import replan

    tried = []
    monkeypatch.setattr(replan, "capture_landing_plan", lambda *args: tried.append(args))
    capture = replan.REPLAN_TRIES["single"].index("capture")
    for plan, t, com, vel in (_hopeless_left_push(), left_push_state()):  # 29 N s at 3.05 s, 17 N s at 3.175 s
        with pytest.raises(InfeasibleStop):
            replan_stop(plan, t, com, vel, first_try=capture)
    assert tried == []


def test_swing_reach_grows_with_the_time_to_land():
    from drake_estop.planning.capture_landing import swing_reach

    rest = np.zeros(2)
    near = swing_reach(rest, rest, rest, 0.0, 0.2, 15.0)
    far = swing_reach(rest, rest, rest, 0.0, 0.4, 15.0)
    assert near[0] == pytest.approx(-near[1], abs=5e-3) and far[1] > 2 * near[1]
    # quintic from rest: peak acceleration 5.77 D / T^2 (10 / sqrt(3))
    assert near[1] == pytest.approx(15.0 * 0.2**2 / (10 / math.sqrt(3)), abs=5e-3)
    # a foot at 2 m/s cannot stop within 5 cm of anywhere in 0.1 s
    assert swing_reach(rest, np.array([2.0, 0.0]), rest, 0.0, 0.1, 15.0) is None


def test_the_summary_says_which_landing_a_capture_landing_made():
    plan, t, com, vel = _right_push_state()
    caught = replan_stop(plan, t, com, vel)
    summary = PlanSequence([plan, caught]).summary()
    assert summary["steps"] == [{"time": caught.landing_time, "foot": "right", "kind": "capture landing"}]
    assert summary["capture_landings"] == 1 and summary["recovery_steps"] == 0 and summary["steps_after_signal"] == 1
    assert PlanSequence([plan]).summary()["steps"][0]["kind"] == "stop landing"


def test_every_capture_landing_lands_sooner_at_the_widest_step_and_stops_within_its_limits():
    """Sideways pushes towards the swing foot at 0.2-0.6 m/s, measured every 30 ms of the 2.95 s plan's
    single support: each re-plan the capture landing makes (10 of the 60 states; 23 have a stop) lands no
    later than the plan, at the widest step, with the swing braking within its acceleration, the LIPM's DCM
    on the landed side at the touchdown, the ZMP within its margin, and the COG at rest after the halt."""
    from drake_estop.physics.online import controller_stop_parameters
    from drake_estop.planning import replan

    pattern = NominalPattern()
    plan = plan_stop(pattern, 2.95, controller_stop_parameters())
    captured = 0
    for t in np.arange(3.0, 3.36, 0.03):
        pos, speed, _, _ = plan.com([t])
        for push in (-0.2, -0.3, -0.4, -0.5, -0.6):
            try:
                caught = replan_stop(plan, t, pos[0], speed[0] + np.array([0.0, push]))
            except InfeasibleStop:
                continue
            if not caught.capture_landing:
                continue
            captured += 1
            assert caught.landing_time <= plan.landing_time + 1e-9
            assert caught.landing_position[1] == pytest.approx(0.095 - MAX_STEP_WIDTH)
            start = caught.swing_start
            braking = replace(caught.params, min_landing_time=DT,
                              max_swing_acceleration=capture_landing.CAPTURE_SWING_ACCELERATION)
            assert replan.swing_braking_time(start["pos"], start["vel"], start["acc"], caught.landing_position,
                                             braking) <= caught.landing_time - t + 1e-9
            landed, landed_speed, _, _ = caught.com([caught.landing_time])
            dcm_y = landed[0][1] + landed_speed[0][1] / pattern.w
            assert dcm_y > caught.landing_position[1] - pattern.params.sole.outer + caught.params.zmp_margin
            assert caught.min_zmp_margin >= caught.params.zmp_margin - 1e-9
            _, rest, _, _ = caught.com([caught.halt_end + 0.5])
            assert np.max(np.abs(rest)) < 1e-6
    assert captured >= 8


def test_past_a_braked_plans_own_landing_bound_only_the_capture_landing_is_tried(pattern, params, monkeypatch):
    """A braked re-plan raises its ``min_landing_time`` to its braking time (here 0.3 s): its window for
    re-planning the landing still reaches to the planner's shortest landing (0.1 s) before the touchdown,
    but past its own bound only the capture landing, which lands sooner, is tried."""
    from drake_estop.planning import replan

    plan = plan_stop(pattern, 3.15, params)
    plan.params = replace(plan.params, min_landing_time=0.3)
    late = plan.landing_time - 0.2
    assert replan_support(plan, late) == "single"
    assert replan_support(plan, plan.landing_time - 0.1 + DT) is None
    solves = count_solves(monkeypatch)
    pos, vel, _ = state_at(plan, late)
    with pytest.raises(InfeasibleStop, match="tries before 'capture'"):  # the capture landing does not apply
        replan_stop(plan, late, pos, vel + np.array([0.2, 0.0]))
    assert solves == []
    early = plan.landing_time - 0.3 - DT
    assert replan_stop(plan, early, *state_at(plan, early)[:2]) is not None and len(solves) == 1  # the held ZMP
    assert replan.shortest_replanned_landing(plan) == pytest.approx(0.1)


def test_swing_reach_is_the_grid_search_of_the_braking_limit():
    """The closed-form reach equals checking every landing point of its 5 mm grid with the landing swing's
    acceleration on its check grid (the definition), over random swings, durations and limits."""
    from drake_estop.planning import lipm
    from drake_estop.planning.capture_landing import swing_reach
    from drake_estop.planning.plan import SWING_GRID

    terms = [lipm.poly_eval(c, SWING_GRID, 2) for c in (lipm.SMOOTHSTEP, lipm.HERMITE_D1, lipm.HERMITE_D2)]

    def grid_search(pos, vel, acc, lateral, duration, limit):
        xs = pos[0] + np.arange(-1.0, 1.0 + 1e-9, 0.005)
        distance = np.stack([xs - pos[0], np.full_like(xs, lateral - pos[1])], axis=1)
        swing = (terms[0][None, :, None] * distance[:, None, :] + terms[1][None, :, None] * vel * duration
                 + terms[2][None, :, None] * acc * duration**2) / duration**2
        within = np.flatnonzero(np.max(np.linalg.norm(swing, axis=2), axis=1) <= limit + 1e-9)
        return None if len(within) == 0 else (float(xs[within[0]]), float(xs[within[-1]]))

    rng = np.random.default_rng(7)
    found = 0
    for _ in range(2000):
        args = (rng.uniform(-1, 1, 2), rng.uniform(-2.5, 2.5, 2), rng.uniform(-20, 20, 2), rng.uniform(-0.5, 0.5),
                float(rng.choice(np.arange(0.05, 0.8, 0.005))), float(rng.choice([15.0, 20.0, 30.0])))
        reach = swing_reach(*args)
        assert reach == grid_search(*args)
        found += reach is not None
    assert 500 < found < 1500  # both outcomes are exercised


# -- N-step capture: the capture landing and a recovery step ------------------------------------------------

def test_a_forward_push_no_landing_stops_is_caught_in_two_steps(monkeypatch):
    """No landing stops this state (the stop condition, eq. 22, asks for a step past the reach at every
    landing time): one step alone raises; with the recovery step the swing lands as soon as it can and the
    old support foot steps past it out of double support. The plan is one LIPM motion: the support ZMP held
    until the touchdown (eq. 19), then the recovery step's, continuous there and at rest at the end."""

    plan, t, com, vel = forward_push_state()
    with pytest.raises(InfeasibleStop, match="capture landing"):
        replan_stop(plan, t, com, vel)  # one landing only
    caught = replan_stop(plan, t, com, vel, recovery_step=True)
    step = caught.next_step
    assert caught.capture_landing and caught.landing_foot == "right" and step is not None
    assert step.recovery_step and step.landing_foot == "left"
    assert caught.landing_time < plan.landing_time - 0.05  # 3.395 s against 3.455 s
    assert step.start_time == pytest.approx(caught.landing_time)
    support_x = 0.6
    assert 0.0 < caught.landing_position[0] - support_x <= caught.params.max_step_length + 1e-9
    assert step.landing_position[0] > caught.landing_position[0]  # the rear foot steps past the landed one
    w = plan.pattern.w
    # the support ZMP stands still on the support sole until the touchdown (eq. 19; then it steps onto the
    # landed sole, under the DCM: the recovery step's)
    times = np.linspace(t, caught.landing_time - 1e-9, 7)
    pos, speed, accel, zmp = caught.com(times)
    assert zmp[0][0] == pytest.approx(support_x + plan.pattern.params.sole.toe - RECOVERY_ZMP_MARGIN)  # the toe
    np.testing.assert_allclose(zmp, np.repeat(zmp[:1], len(times), axis=0), atol=1e-12)
    np.testing.assert_allclose(accel, w**2 * (pos - zmp), atol=1e-9)  # the LIPM (eq. 4)
    # the DCM at the touchdown lies CAPTURE_STEP_DCM_AHEAD past the landed ankle (the reach allowed it)
    dcm = pos[-1] + speed[-1] / w
    assert dcm[0] - caught.landing_position[0] == pytest.approx(capture_landing.CAPTURE_STEP_DCM_AHEAD, abs=1e-6)
    # ... and laterally inside the landed sole's inner edge less the margin: the recovery step lifts the
    # other foot (the landing is narrower than the walk's 0.19 m for it)
    inner = plan.pattern.params.sole.inner - RECOVERY_ZMP_MARGIN
    assert dcm[1] - caught.landing_position[1] <= inner + 1e-9
    assert 0.15 - 1e-9 <= 0.095 - caught.landing_position[1] < 0.19
    # after the touchdown the plan is the recovery step's motion, continuous at the touchdown
    after = np.linspace(caught.landing_time, step.halt_end + 0.5, 40)
    for mine, its in zip(caught.com(after), step.com(after)):
        np.testing.assert_allclose(mine, its, atol=1e-9)
    before = caught.com([caught.landing_time - 1e-6])
    np.testing.assert_allclose(before[0][0], step.com([caught.landing_time])[0][0], atol=1e-6)
    np.testing.assert_allclose(before[1][0], step.com([caught.landing_time])[1][0], atol=1e-5)
    _, rest, _, _ = step.com([step.halt_end + 0.5])
    assert np.max(np.abs(rest)) < 1e-6
    assert min(caught.min_zmp_margin, step.min_zmp_margin) >= caught.params.zmp_margin - 1e-9
    summary = PlanSequence([plan, caught, step]).summary()
    assert [s["kind"] for s in summary["steps"]] == ["capture landing", "recovery step"]
    assert summary["steps_after_signal"] == 2 and summary["capture_landings"] == 1
    # without the recovery step's stop the two steps are not planned
    monkeypatch.setattr(capture_landing, "recovery_step_plan", lambda *args: (_ for _ in ()).throw(args[-1]))
    with pytest.raises(InfeasibleStop, match="capture step"):
        replan_stop(plan, t, com, vel, recovery_step=True)
