"""Planning from the measured state and re-planning (planner functions and StopPlannerSystem in isolation)."""

import math
import os
from pathlib import Path

import numpy as np
import pytest
from planner_helpers import latched_stop_planner
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from drake_estop.planning.gait import GaitParameters, NominalPattern
from drake_estop.planning.geometry import SupportPolygon
from drake_estop.planning.planner import InfeasibleStop, StopParameters, plan_stop, replan_stop
from drake_estop.systems.stop_controller import PlanSequence, StopPlannerSystem

DT = 0.005


@pytest.fixture(scope="module")
def params():
    """Re-plans are the online controller's: its slowdown ZMP is at the landing ankle (the paper's eq. 20,
    ``controller_stop_parameters``), where the kinematic default puts it 5 cm ahead."""
    return StopParameters(landing_zmp_offset=0.0)


def _state_at(plan, t):
    pos, vel, _, zmp = plan.com([t])
    return pos[0], vel[0], zmp[0]


def _slowdown_end_velocity(plan):
    _, vel, _, _ = plan.com([plan.slowdown_end])
    return vel[0]


def test_plan_from_the_reference_state_equals_the_nominal_plan(pattern, params):
    nominal = plan_stop(pattern, 3.1, params)
    pos, vel, _ = _state_at(nominal, 3.1)
    measured = plan_stop(pattern, 3.1, params, measured=(pos, vel))
    assert measured.case == nominal.case
    assert measured.step_length == pytest.approx(nominal.step_length, abs=1e-9)
    assert measured.halt_end == pytest.approx(nominal.halt_end, abs=1e-9)


def test_plan_from_a_measured_state_starts_there_and_stops(pattern, params):
    t = 3.15
    pos, vel, zmp = _state_at(plan_stop(pattern, t, params), t)
    faster = vel + np.array([0.02, 0.0])
    plan = plan_stop(pattern, t, params, measured=(pos, faster))
    assert plan.case == "one-step"
    start_pos, start_vel, start_zmp = _state_at(plan, plan.start_time)
    np.testing.assert_allclose(start_pos, pos, atol=1e-12)  # eq. 10
    np.testing.assert_allclose(start_vel, faster, atol=1e-12)  # eq. 11
    np.testing.assert_allclose(start_zmp, zmp, atol=1e-12)  # eq. 12: the ZMP stays continuous
    assert plan.step_length > plan_stop(pattern, t, params).step_length  # a faster COG needs a longer step
    assert abs(_slowdown_end_velocity(plan)[0]) < 1e-6  # eq. 17


def test_a_next_step_fallback_carries_the_measured_deviation(pattern, params):
    """Where the deviation makes a one-step stop infeasible, the fallback starts from the pattern's
    later state plus the deviation propagated by the LIPM, not from the nominal state."""
    t = 3.1
    pos, vel, _ = _state_at(plan_stop(pattern, t, params), t)
    faster = vel + np.array([0.05, 0.0])
    plan = plan_stop(pattern, t, params, measured=(pos, faster))
    assert plan.case == "next-step"
    s = plan.start_time - plan_stop(pattern, t, params).start_time
    w = pattern.w
    nominal_pos, nominal_vel, _, _ = pattern.com([plan.start_time])
    start_pos, start_vel, _ = _state_at(plan, plan.start_time)
    np.testing.assert_allclose(start_pos[0] - nominal_pos[0][0], 0.05 / w * np.sinh(w * s), atol=1e-9)
    np.testing.assert_allclose(start_vel[0] - nominal_vel[0][0], 0.05 * np.cosh(w * s), atol=1e-9)


@pytest.mark.parametrize("value", [(np.nan, 0.0), (np.inf, 1.0)])
def test_plan_stop_rejects_a_non_finite_measured_state(pattern, params, value):
    with pytest.raises(ValueError, match="measured"):
        plan_stop(pattern, 3.1, params, measured=(np.array(value), np.zeros(2)))


def test_replan_in_the_landing_phase_moves_the_landing(pattern, params):
    plan = plan_stop(pattern, 3.1, params)
    t = 3.15
    pos, vel, zmp = _state_at(plan, t)
    pushed = vel + np.array([0.02, 0.0])
    new = replan_stop(plan, t, pos, pushed)
    assert new.start_time == pytest.approx(t)
    assert new.step_length > plan.step_length
    start_pos, start_vel, start_zmp = _state_at(new, t)
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
    pos, vel, _ = _state_at(plan, t)
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
    end_pos, end_vel, _ = _state_at(new, new.halt_end + 0.2)
    np.testing.assert_allclose(end_pos, 0.5 * (new.final_feet["left"] + new.final_feet["right"]), atol=1e-6)
    np.testing.assert_allclose(end_vel, 0.0, atol=1e-6)


def test_replan_keeps_the_crouch_of_the_plan_it_replaces(pattern, params):
    plan = plan_stop(pattern, 3.1, params)
    t = 3.15
    pos, vel, _ = _state_at(plan, t)
    new = replan_stop(plan, t, pos, vel + np.array([0.02, 0.0]))
    z_old = plan.com_height([t])[0][0]
    z_new = new.com_height([t])[0][0]
    assert z_new == pytest.approx(z_old, abs=1e-12)


def _left_push_state():
    """The plan of a signal at 2.95 s (the online controller's settings) and the state the robot measured
    at 3.175 s after a 17 N s push to the left (a physics run), its lateral speed 1 cm/s higher: the DCM over
    the left (support) foot's outer edge, where neither the held ZMP nor the whole ankle ZMP finds a stop
    and the ankle ZMP's lateral part does (with the speed as measured the ankle ZMP already does)."""
    from drake_estop.physics.online import controller_stop_parameters

    plan = plan_stop(NominalPattern(), 2.95, controller_stop_parameters())
    return plan, 3.175, np.array([0.60612853, 0.0693894]), np.array([0.23707723, 0.11288797])


def test_ankle_strategy_replans_what_a_held_support_zmp_cannot(monkeypatch):
    from drake_estop.planning import replan

    plan, t, com, vel = _left_push_state()
    new = replan_stop(plan, t, com, vel)
    old_zmp = np.array([traj.evaluate_at(t)[3] for traj in (plan.x, plan.y)])
    start_pos, start_vel, start_zmp = _state_at(new, t)
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

    plan, t, com, vel = _left_push_state()
    braking, solved = [], []
    real_braking, real_plan_from = replan.swing_braking_time, replan.plan_from
    monkeypatch.setattr(replan, "swing_braking_time", lambda *a: braking.append(a) or real_braking(*a))
    monkeypatch.setattr(replan, "plan_from",
                        lambda pattern, state, *a, **k: solved.append(state.zmp.copy()) or real_plan_from(
                            pattern, state, *a, **k))
    new = replan_stop(plan, t, com, vel)
    assert len(braking) == 1 and len(solved) >= 2  # the held ZMP failed, an ankle-strategy ZMP held
    np.testing.assert_allclose(solved[0], [traj.evaluate_at(t)[3] for traj in (plan.x, plan.y)])
    np.testing.assert_allclose(_state_at(new, t)[2], solved[-1], atol=1e-12)  # the last try is the plan
    assert not np.allclose(solved[0], solved[-1])


def test_ankle_zmp_brings_the_dcm_back_onto_the_plan_at_the_landing():
    from drake_estop.planning.replan import ankle_zmp

    plan, t, _, _ = _left_push_state()
    pos, vel, _ = _state_at(plan, t)
    assert ankle_zmp(plan, t, pos, vel) is None  # on the plan: nothing to take back
    w = plan.pattern.w
    slower = vel - np.array([0.01, 0.0])  # small: the answer lies inside the sole
    zmp = ankle_zmp(plan, t, pos, slower)
    grow = math.exp(w * (plan.landing_time - t))
    xi = zmp + (pos + slower / w - zmp) * grow  # eq. 6-9 with the ZMP held at zmp
    landing_pos, landing_vel, _ = _state_at(plan, plan.landing_time)
    np.testing.assert_allclose(xi, landing_pos + landing_vel / w, atol=1e-9)
    assert zmp[0] < plan.feet(t)["left"][0]  # behind the ankle: the COG is let go forward
    far = ankle_zmp(plan, t, pos, vel + np.array([0.0, 0.5]))  # clamped to the sole's outer edge less the margin
    outer = plan.feet(t)["left"][1] + plan.pattern.params.sole.outer - plan.params.zmp_margin
    assert far[1] == pytest.approx(outer, abs=1e-12)


def test_nothing_to_replan_in_the_halt(pattern, params):
    plan = plan_stop(pattern, 3.4, params)
    t = plan.slowdown_end + 0.1
    pos, vel, _ = _state_at(plan, t)
    assert replan_stop(plan, t, pos, vel) is None


def test_replan_raises_when_no_stop_exists(pattern, params):
    plan = plan_stop(pattern, 3.4, params)
    t = plan.landing_time + 0.02
    pos, _, _ = _state_at(plan, t)
    with pytest.raises(InfeasibleStop):
        replan_stop(plan, t, pos, np.array([3.0, 0.0]))  # 3 m/s: no ZMP in the feet stops it


def test_plan_sequence_evaluates_each_plan_from_its_start(pattern, params):
    first = plan_stop(pattern, 3.1, params)
    t = 3.15
    pos, vel, _ = _state_at(first, t)
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


# -- StopPlannerSystem with the measured-state inputs ---------------------------------------------


def _planner_diagram(pattern, params, stop, com, com_vel, **kwargs):
    builder = DiagramBuilder()
    planner = builder.AddSystem(StopPlannerSystem(pattern=pattern, params=params, **kwargs))
    for port, value in ((planner.stop_port, stop), (planner.measured_com_port, com),
                        (planner.measured_com_vel_port, com_vel)):
        source = builder.AddSystem(ConstantVectorSource(np.asarray(value, float)))
        builder.Connect(source.get_output_port(), port)
    diagram = builder.Build()
    return diagram, planner


def test_planner_plans_from_the_reference_when_the_robot_follows_it(pattern, params):
    t = 3.1
    pos, vel, _ = _state_at(plan_stop(pattern, t, params), t)
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
    pos, vel, _ = _state_at(plan_stop(pattern, t, params), t)
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


def test_blend_starts_at_the_old_command_and_ends_on_the_plan_at_rest():
    from drake_estop.systems.stop_controller import REFERENCE_SIZE, REFERENCE_SLICES
    reference = np.zeros(REFERENCE_SIZE)
    dp, dv, duration = np.array([0.02, -0.01]), np.array([0.1, 0.05]), 0.2
    blend = (1.0, dp, dv, duration)

    def command(t):
        out = StopPlannerSystem._blended(reference, blend, t)
        return out[REFERENCE_SLICES["com"]][:2], out[REFERENCE_SLICES["com_vel"]][:2]

    np.testing.assert_allclose(command(1.0)[0], dp)
    np.testing.assert_allclose(command(1.0)[1], dv)
    h = 1e-6
    np.testing.assert_allclose((command(1.1 + h)[0] - command(1.1 - h)[0]) / (2 * h), command(1.1)[1], atol=1e-6)
    np.testing.assert_allclose(command(1.0 + duration - 1e-9)[0], 0.0, atol=1e-9)
    np.testing.assert_allclose(command(1.0 + duration - 1e-9)[1], 0.0, atol=1e-6)
    np.testing.assert_allclose(command(1.5)[0], 0.0)
    np.testing.assert_allclose(command(0.9)[0], 0.0)


def test_planner_replans_at_most_once_a_tick_while_the_measured_state_deviates(pattern, params):
    t = 3.0
    pos, vel, _ = _state_at(plan_stop(pattern, t, params), t)
    # the measured state stays frozen at the signal's: it leaves every new plan again
    diagram, planner = _planner_diagram(pattern, params, [1.0, t], [*pos, 0.8], [*vel, 0.0],
                                        filter_time_constant=1e-6, replan_threshold=0.005, replan_interval=DT)
    simulator = Simulator(diagram)
    simulator.get_mutable_context().SetTime(t)
    simulator.Initialize()
    simulator.AdvanceTo(t + 0.1)
    context = planner.GetMyContextFromRoot(simulator.get_context())
    replans, failures = planner.replans(context)
    ticks = int(round(0.1 / DT))
    assert 1 <= replans + failures <= ticks
    assert len(planner.plans(context).plans) == replans + 1


def test_plan_stop_bounds_its_search_by_max_solves(pattern, monkeypatch):
    """A state no stop catches (3 m/s sideways) costs plan_stop a solve at every tick of the next two steps;
    ``max_solves`` ends the search after that many tries, with a message that says so."""
    from drake_estop.planning import planner as planner_module

    t, params = 3.1, StopParameters()
    com, com_vel = _sideways_at(pattern, t, 3.0)
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


@pytest.mark.parametrize("value", [0, 2.5, False])
def test_planner_rejects_a_bad_max_latch_solves(pattern, params, value):
    with pytest.raises(ValueError, match="max_latch_solves"):
        StopPlannerSystem(pattern=pattern, params=params, max_latch_solves=value)


@pytest.mark.parametrize("name", ["replan_threshold", "bias_time_constant", "filter_time_constant", "blend_time",
                                  "replan_interval", "landed_replan_threshold", "foothold_tolerance"])
@pytest.mark.parametrize("value", [0.0, -1.0, float("nan")])
def test_planner_rejects_bad_settings(pattern, params, name, value):
    with pytest.raises(ValueError, match=name):
        StopPlannerSystem(pattern=pattern, params=params, **{name: value})


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


def test_plan_sequence_summary_keeps_the_landing_and_counts_the_replans(pattern, params):
    first = plan_stop(pattern, 3.4, params)
    t = first.landing_time + 0.05
    pos, vel, _ = _state_at(first, t)
    second = replan_stop(first, t, pos, 0.8 * vel)  # after the landing: a double-support re-plan
    summary = PlanSequence([first, second]).summary()
    assert summary["replans"] == 1
    assert summary["estop_time"] == first.signal_time
    assert summary["phase_times"]["landing_end"] == first.landing_time  # not the re-plan's start
    assert summary["phase_times"]["halt_end"] == second.halt_end
    assert summary["first_plan"]["step_length"] == first.step_length


def _sideways_at(pattern, t, speed):
    """The measured COG of the walk at ``t`` with ``speed`` [m/s] sideways: no stop catches 3 m/s."""
    pos, vel, _, _ = pattern.com([t])
    return [*pos[0], 0.8], [vel[0][0], speed, 0.0]


def test_no_stop_from_the_measured_state_plans_from_the_reference_and_keeps_trying(pattern):
    """A state no stop catches at the signal (3 m/s sideways) does not end the controller: the latch
    plans the paper's stop from the reference, as without a measurement (continuous with the command, no
    blend), says why, and the measured state is then re-planned from every tick (each try fails here)."""
    t, params = 3.1, StopParameters()
    com, com_vel = _sideways_at(pattern, t, 3.0)
    diagram, planner = _planner_diagram(pattern, params, [1.0, t], com, com_vel, filter_time_constant=1e-6,
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


def test_a_plan_from_the_measured_state_records_no_fallback(pattern, params):
    t = 3.15
    pos, vel, _ = _state_at(plan_stop(pattern, t, params), t)
    diagram, planner = _planner_diagram(pattern, params, [1.0, t], [*pos, 0.8], [*(vel + [0.02, 0.0]), 0.0],
                                        replan_threshold=0.005)
    simulator = Simulator(diagram)
    simulator.get_mutable_context().SetTime(t)
    simulator.AdvanceTo(t + DT / 2)
    assert planner.latch_fallback(planner.GetMyContextFromRoot(simulator.get_context())) is None


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
        "from test_replan import _planner_diagram\n"
        "from drake_estop.planning.gait import NominalPattern\n"
        "from drake_estop.planning.planner import InfeasibleStop, StopParameters\n"
        "pattern = NominalPattern(); t = 3.1\n"
        "pos, vel, _, _ = pattern.com([t])\n"
        "diagram, planner = _planner_diagram(pattern, StopParameters(), [1.0, t], [*pos[0], 0.8],\n"
        "                                    [vel[0][0], 3.0, 0.0], filter_time_constant=1e-6,\n"
        "                                    reference_fallback=False)\n"
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


# -- measured footholds after the landing ----------------------------------------------------------


def _inward(side):
    """The sign of y towards the other foot."""
    return -1.0 if side == "left" else 1.0


def _moved_feet(plan):
    """The landing foot 7 mm ahead and 15 mm inside its target, the support foot slid 9 mm outward."""
    landing = plan.landing_foot
    support = next(s for s in ("left", "right") if s != landing)
    return {landing: plan.final_feet[landing] + [0.007, 0.015 * _inward(landing)],
            support: plan.final_feet[support] + [-0.004, -0.009 * _inward(support)]}


def test_replan_after_the_landing_stands_on_measured_footholds(pattern, params):
    plan = plan_stop(pattern, 3.4, params)
    t = plan.landing_time + 0.02
    pos, vel, _ = _state_at(plan, t)
    feet = _moved_feet(plan)
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
    end_pos, end_vel, _ = _state_at(new, new.halt_end + 0.2)
    np.testing.assert_allclose(end_pos, 0.5 * (feet["left"] + feet["right"]), atol=1e-6)
    np.testing.assert_allclose(end_vel, 0.0, atol=1e-6)
    # without them the re-plan keeps the plan's feet
    kept = replan_stop(plan, t, pos, vel + np.array([0.05, 0.0]))
    for side in feet:
        np.testing.assert_allclose(kept.final_feet[side], plan.final_feet[side], atol=1e-12)


def test_measured_footholds_are_ignored_before_the_landing(pattern, params):
    plan = plan_stop(pattern, 3.1, params)
    t = 3.15
    pos, vel, _ = _state_at(plan, t)
    new = replan_stop(plan, t, pos, vel + np.array([0.02, 0.0]), feet=_moved_feet(plan))
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
    pos, vel, _ = _state_at(plan, t)
    with pytest.raises(ValueError, match=message):
        replan_stop(plan, t, pos, vel, feet=feet)


def _landed_replan(pattern, params, feet_input, **kwargs):
    """StopPlannerSystem alone (FixValue inputs, Simulator.AdvanceTo): the stop latched at 3.4 s from the
    reference, no measurement until 20 ms after the landing, then a COG 5 cm/s faster than the plan's
    (past a 1 cm threshold) and ``feet_input`` on ``measured_feet``. Returns the planner, its context,
    the first plan and the re-plan tick."""
    planner, context, simulator, first = latched_stop_planner(pattern, params, landed_replan_threshold=0.01,
                                                              **kwargs)
    t = round((first.landing_time + 0.02) / DT) * DT
    simulator.AdvanceTo(t - DT / 2)
    assert planner.replans(context) == (0, 0)
    pos, vel, _ = _state_at(first, t)
    planner.measured_com_port.FixValue(context, [*pos, 0.8])
    planner.measured_com_vel_port.FixValue(context, [*(vel + np.array([0.05, 0.0])), 0.0])
    if feet_input is not None:
        planner.measured_feet_port.FixValue(context, feet_input(first))
    simulator.AdvanceTo(t + DT / 2)
    assert planner.replans(context) == (1, 0)
    return planner, context, first, t


def _feet_vector(plan, ticks=(40.0, 40.0)):
    feet = _moved_feet(plan)
    return [*feet["left"], *feet["right"], *ticks]


def test_planner_replans_after_the_landing_on_the_measured_feet_and_blends_the_sole_targets(pattern, params):
    planner, context, first, t = _landed_replan(pattern, params, _feet_vector)
    feet = _moved_feet(first)
    new = planner.plan(context)
    for side in feet:
        np.testing.assert_allclose(new.final_feet[side][:2], feet[side], atol=1e-12)
    # the sole targets start at the old command (a loaded foot's target must not step) and reach the
    # footholds at rest after blend_time
    for side in feet:
        port = planner.GetOutputPort(f"{side}_foot")
        np.testing.assert_allclose(port.Eval(context)[:2], first.feet(t)[side][:2], atol=1e-6)
    planner.measured_com_port.FixValue(context, [np.nan] * 3)  # no further re-plan
    Simulator(planner, context).AdvanceTo(t + 0.2 + DT / 2)
    assert planner.replans(context) == (1, 0)
    for side in feet:
        np.testing.assert_allclose(planner.GetOutputPort(f"{side}_foot").Eval(context)[:2], feet[side],
                                   atol=1e-9)


@pytest.mark.parametrize("feet_input, kwargs", [
    (None, {}),  # not connected
    (_feet_vector, {"measured_footholds": False}),
    (lambda plan: _feet_vector(plan, ticks=(1.0, 1.0)), {}),  # loaded one tick, under foothold_ticks
    (lambda plan: [np.nan] * 6, {}),
])
def test_planner_keeps_the_plans_feet_without_usable_footholds(pattern, params, feet_input, kwargs):
    planner, context, first, _ = _landed_replan(pattern, params, feet_input, **kwargs)
    new = planner.plan(context)
    for side in ("left", "right"):
        np.testing.assert_allclose(new.final_feet[side], first.final_feet[side], atol=1e-12)


@pytest.mark.parametrize("value", [0, -1, 1.5, True, float("nan")])
def test_planner_rejects_bad_foothold_ticks(pattern, params, value):
    with pytest.raises(ValueError, match="foothold_ticks"):
        StopPlannerSystem(pattern=pattern, params=params, foothold_ticks=value)


def test_blend_fades_the_sole_offsets_to_the_new_plan_at_rest():
    from drake_estop.systems.stop_controller import REFERENCE_SIZE, REFERENCE_SLICES
    reference = np.zeros(REFERENCE_SIZE)
    dfeet = np.array([[0.01, -0.02, 0.0], [-0.005, 0.015, 0.0]])
    blend = (1.0, np.zeros(2), np.zeros(2), 0.2, dfeet)

    def feet(t):
        out = StopPlannerSystem._blended(reference, blend, t)
        return np.array([out[REFERENCE_SLICES[f"{side}_foot"]][:3] for side in ("left", "right")])

    np.testing.assert_allclose(feet(1.0), dfeet)
    h = 1e-6
    np.testing.assert_allclose((feet(1.0 + h) - feet(1.0)) / h, 0.0, atol=1e-4)  # starts at rest
    np.testing.assert_allclose(feet(1.2 - 1e-9), 0.0, atol=1e-9)
    assert np.all(np.abs(feet(1.1)) < np.abs(dfeet) + 1e-12)


def _measure_on_the_plan(planner, context, plan, t):
    """Fix the planner's measured COG (0.8 m high) and its velocity at ``plan``'s state at ``t``: the DCM
    on the plan."""
    pos, vel, _ = _state_at(plan, t)
    planner.measured_com_port.FixValue(context, [*pos, 0.8])
    planner.measured_com_vel_port.FixValue(context, [*vel, 0.0])


def _on_the_plan_after_the_landing(pattern, params, **kwargs):
    """StopPlannerSystem alone: the stop latched at 3.4 s, advanced to just before the tick ``t`` 20 ms
    after the landing, with the measured COG the plan's there (the DCM on the plan). Returns the planner,
    its context, the simulator, the first plan and t."""
    planner, context, simulator, first = latched_stop_planner(pattern, params, **kwargs)
    t = round((first.landing_time + 0.02) / DT) * DT
    simulator.AdvanceTo(t - DT / 2)
    _measure_on_the_plan(planner, context, first, t)
    return planner, context, simulator, first, t


def _feet_at_the_plan(pattern, params, shift, **kwargs):
    """:func:`_on_the_plan_after_the_landing`, then at ``t`` the measured soles are the plan's feet moved by
    ``shift`` (side -> (dx, dy)), loaded 40 ticks. Returns the planner, its context, the simulator, the first
    plan, t and the measured feet."""
    planner, context, simulator, first, t = _on_the_plan_after_the_landing(pattern, params, **kwargs)
    feet = {side: first.final_feet[side] + np.asarray(shift.get(side, (0.0, 0.0))) for side in ("left", "right")}
    planner.measured_feet_port.FixValue(context, [*feet["left"], *feet["right"], 40.0, 40.0])
    simulator.AdvanceTo(t + DT / 2)
    return planner, context, simulator, first, t, feet


def test_a_foot_measured_off_the_plan_replans_on_the_measured_feet_once_a_landing(pattern, params):
    """With the DCM on the plan, a sole measured 1 cm from the plan's foot (more than foothold_tolerance)
    re-plans the stop on the measured feet; a foot that keeps sliding is not chased."""
    planner, context, simulator, first, t, feet = _feet_at_the_plan(pattern, params, {"left": (0.0, -0.01)},
                                                                    foothold_replan=True)
    assert planner.replans(context) == (1, 0)
    new = planner.plan(context)
    assert new.start_time == pytest.approx(t) and new.recovery_step is False
    for side in feet:
        np.testing.assert_allclose(new.final_feet[side][:2], feet[side], atol=1e-12)
    # the foot slides on by another centimetre: that landing's feet were taken once, no second re-plan
    slid = feet["left"] + [0.0, -0.01]
    planner.measured_feet_port.FixValue(context, [*slid, *feet["right"], 40.0, 40.0])
    _measure_on_the_plan(planner, context, new, t + 0.1)
    simulator.AdvanceTo(t + 0.1 + DT / 2)
    assert planner.replans(context) == (1, 0)


@pytest.mark.parametrize("shift, kwargs", [
    ({"left": (0.0, -0.003)}, {"foothold_replan": True}),  # within the 5 mm tolerance
    ({"left": (0.0, -0.01)}, {}),  # the foothold re-plan off (the default)
    ({"left": (0.0, -0.01)}, {"foothold_replan": True, "foothold_tolerance": 0.02}),  # a wider tolerance
])
def test_feet_within_the_tolerance_keep_the_plan(pattern, params, shift, kwargs):
    planner, context, _, first, _, _ = _feet_at_the_plan(pattern, params, shift, **kwargs)
    assert planner.replans(context) == (0, 0)
    assert planner.plan(context) is first


def _relanding(pattern, params, shift, **kwargs):
    """StopPlannerSystem alone: the stop latched at 3.4 s; from 20 ms after the landing the measured COG is
    the plan's (the DCM on the plan) and both soles stand where the plan has them (loaded 40 ticks); then
    the left sole is unloaded for 4 ticks (the robot bounced) and loaded again moved by ``shift`` (dx, dy),
    for 1 tick, then 2. Returns the planner, its context, the first plan, the moved sole's position and the
    tick of its second loaded tick (``foothold_ticks``)."""
    planner, context, simulator, first, t = _on_the_plan_after_the_landing(pattern, params, **kwargs)
    feet = {side: first.final_feet[side][:2] for side in ("left", "right")}
    moved = feet["left"] + np.asarray(shift)
    steps = [(feet["left"], 40.0)] * 2 + [(feet["left"], 0.0)] * 4 + [(moved, 1.0), (moved, 2.0)]
    for k, (left, ticks) in enumerate(steps):
        planner.measured_feet_port.FixValue(context, [*left, *feet["right"], ticks, 40.0])
        simulator.AdvanceTo(t + k * DT + DT / 2)
        if k < len(steps) - 1:
            assert planner.replans(context) == (0, 0), f"re-planned on step {k}"
    return planner, context, first, moved, t + (len(steps) - 1) * DT


def test_a_sole_that_relands_off_its_foothold_replans_the_stop_where_it_stands(pattern, params):
    """A sole that stood, lost contact (a bounce) and landed again 1 cm away re-plans the stop on its new
    foothold on its second loaded tick, with the DCM on the plan and within the re-plan interval: the other
    sole keeps the plan's foothold."""
    planner, context, first, moved, t = _relanding(pattern, params, (-0.01, 0.0), replan_interval=0.05)
    assert planner.replans(context) == (1, 0)
    new = planner.plan(context)
    assert new.start_time == pytest.approx(t) and new.recovery_step is False
    np.testing.assert_allclose(new.final_feet["left"][:2], moved, atol=1e-12)
    np.testing.assert_allclose(new.final_feet["right"], first.final_feet["right"], atol=1e-12)
    # a second bounce 15 ms later, landing another centimetre back: re-planned at once again, within the
    # 50 ms re-plan interval (the sole's new place is a fact, not a deviation for the blend to remove)
    simulator = Simulator(planner, context)
    again = moved + np.array([-0.01, 0.0])
    for k, (left, ticks) in enumerate([(moved, 0.0), (again, 1.0), (again, 2.0)], start=1):
        planner.measured_feet_port.FixValue(context, [*left, *first.final_feet["right"][:2], ticks, 40.0])
        simulator.AdvanceTo(t + k * DT + DT / 2)
    assert planner.replans(context) == (2, 0)
    np.testing.assert_allclose(planner.plan(context).final_feet["left"][:2], again, atol=1e-12)


@pytest.mark.parametrize("shift, kwargs", [
    ((-0.003, 0.0), {}),  # re-landed within the 5 mm tolerance
    ((-0.01, 0.0), {"relanded_footholds": False}),
    ((-0.01, 0.0), {"foothold_tolerance": 0.02}),
])
def test_a_sole_that_relands_on_its_foothold_keeps_the_plan(pattern, params, shift, kwargs):
    planner, context, first, _, _ = _relanding(pattern, params, shift, **kwargs)
    assert planner.replans(context) == (0, 0)
    assert planner.plan(context) is first


@pytest.mark.parametrize("scuff_ticks", [0, 3])
def test_the_landing_itself_is_not_a_relanding(pattern, params, scuff_ticks):
    """The landing sole's touchdown 1 cm off its target does not re-plan with the DCM on the plan (that is
    the foothold re-plan's option, off by default), also when the swinging sole scuffed the floor (loaded
    ``scuff_ticks`` ticks where the plan has it in the air) before."""
    planner, context, simulator, first = latched_stop_planner(pattern, params)
    swing = first.landing_foot
    k_swing = ("left", "right").index(swing)
    feet = {side: first.final_feet[side][:2].copy() for side in ("left", "right")}
    landed = dict(feet, **{swing: feet[swing] + np.array([-0.01, 0.0])})
    ticks = [40.0, 40.0]
    for k in range(1, round((first.landing_time + 0.1 - 3.4) / DT)):
        t = 3.4 + k * DT
        _measure_on_the_plan(planner, context, first, t)
        airborne = first.feet(t)[swing][2] > 1e-9
        ticks[k_swing] = float(k) if k <= scuff_ticks else 0.0 if airborne else min(40.0, ticks[k_swing] + 1.0)
        sole = landed if t >= first.landing_time else first.feet(t)
        planner.measured_feet_port.FixValue(context, [*sole["left"][:2], *sole["right"][:2], *ticks])
        simulator.AdvanceTo(t + DT / 2)
    assert planner.replans(context) == (0, 0)


def test_a_relanding_too_late_to_move_the_landing_waits_for_the_touchdown(pattern, params):
    """The support sole re-lands 1 cm back in the last ``min_landing_time`` before the touchdown, where no
    re-plan can move the landing and the double-support stop has not begun: the re-landing is kept and the
    stop is re-planned on it at the touchdown's tick."""
    planner, context, simulator, first = latched_stop_planner(pattern, params)
    swing = first.landing_foot
    stance = next(side for side in ("left", "right") if side != swing)
    k_stance = ("left", "right").index(stance)
    home = first.final_feet[stance][:2].copy()
    moved = home + np.array([-0.01, 0.0])
    landing_tick = round(first.landing_time / DT)
    start = landing_tick - round(0.5 * params.min_landing_time / DT) - 4
    stance_ticks = [40.0, 40.0, 0.0, 0.0] + [float(n) for n in range(1, 30)]
    for k, loaded in enumerate(stance_ticks[:landing_tick - start + 2]):
        t = (start + k) * DT
        _measure_on_the_plan(planner, context, first, t)
        ticks = [0.0, 0.0]
        ticks[k_stance] = loaded
        ticks[1 - k_stance] = 0.0 if t < first.landing_time - 1e-9 else 40.0
        sole = {stance: home if k < 4 else moved, swing: first.final_feet[swing][:2]}
        planner.measured_feet_port.FixValue(context, [*sole["left"], *sole["right"], *ticks])
        simulator.AdvanceTo(t + DT / 2)
        if t < first.landing_time - 1e-9:
            assert planner.replans(context) == (0, 0), f"re-planned at {t:.3f} s, before the touchdown"
    assert planner.replans(context) == (1, 0)
    new = planner.plan(context)
    assert new.start_time == pytest.approx(landing_tick * DT)
    np.testing.assert_allclose(new.final_feet[stance][:2], moved, atol=1e-12)


def _count_solves(monkeypatch):
    """A list that grows by one for every stop a re-plan solves (``plan_from``)."""
    from drake_estop.planning import replan

    solves, real = [], replan.plan_from
    monkeypatch.setattr(replan, "plan_from", lambda *a, **k: solves.append(a[1].zmp.copy()) or real(*a, **k))
    return solves


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

    plan, t, com, vel = _left_push_state()
    solves = _count_solves(monkeypatch)
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
    solves = _count_solves(monkeypatch)
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
                                          ({"max_solves": 1.5}, "max_solves"), ({"first_try": 4}, "first_try"),
                                          ({"first_try": -1}, "first_try"), ({"first_try": 1.0}, "first_try")])
def test_replan_rejects_bad_try_settings(kwargs, name):
    plan, t, com, vel = _left_push_state()
    with pytest.raises(ValueError, match=name):
        replan_stop(plan, t, com, vel, **kwargs)


def _pushed_planner(monkeypatch, **kwargs):
    """A latched 2.95 s stop (the controller's settings) at 3.175 s, with the left-push measurement fixed:
    returns the planner, its context, the simulator and the per-tick solve counter."""
    from drake_estop.physics.online import controller_stop_parameters

    planner, context, simulator, first = latched_stop_planner(NominalPattern(), controller_stop_parameters(),
                                                              t0=2.95, **kwargs)
    _, t, com, vel = _left_push_state()
    simulator.AdvanceTo(t - DT / 2)
    planner.measured_com_port.FixValue(context, [*com, 0.8])
    planner.measured_com_vel_port.FixValue(context, [*vel, 0.0])
    return planner, context, simulator, _count_solves(monkeypatch), t


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
    pos, vel, _ = _state_at(planner.plan(context), t + DT)
    planner.measured_com_port.FixValue(context, [*pos, 0.8])
    planner.measured_com_vel_port.FixValue(context, [*vel, 0.0])
    simulator.AdvanceTo(t + DT + DT / 2)
    assert len(solves) == 2 and planner.replans(context) == (0, 0)
    assert context.get_abstract_state(0).get_value().pending is None


@pytest.mark.parametrize("value", [0, -1, 1.5, True, "2"])
def test_planner_rejects_a_bad_solve_bound(pattern, params, value):
    with pytest.raises(ValueError, match="max_replan_solves"):
        StopPlannerSystem(pattern=pattern, params=params, max_replan_solves=value)
