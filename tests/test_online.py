"""The online controller in physics: the default `simulate --physics` diagram, perturbations, the CLI."""

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from drake_estop.cli import main
from drake_estop.physics import offline
from drake_estop.physics.criteria import CRITERIA
from drake_estop.physics.online import (
    build_online_diagram,
    controller_stop_parameters,
    joint_velocity_violations,
    online_simulator,
    run_online,
)
from drake_estop.physics.perturbations import Perturbations, Push
from drake_estop.physics.plant import actuated_indices
from drake_estop.planning.gait import GaitParameters, NominalPattern


def _online_with_nothing_ahead(estop_time):
    """The paper's stop at ``estop_time`` with the online controller, with everything computed after the
    signal forbidden: the offline joint reference (IK over the rollout), the preview filter and
    the nominal-walk error cache must never be called."""
    mp = pytest.MonkeyPatch()

    def forbidden(*args, **kwargs):
        raise AssertionError("the online controller computed a reference ahead of time")

    for name in ("reference_for", "joint_reference", "_zmp_error", "_nominal_errors", "nominal_rollout"):
        mp.setattr(offline, name, forbidden)
    mp.setattr(offline.ZmpPreviewFilter, "track", forbidden)
    try:
        return run_online(estop_time=estop_time, pattern=NominalPattern())
    finally:
        mp.undo()


@pytest.fixture(scope="module")
def paper_stop():
    """The paper's 3.4 s stop (late single support), online, nothing computed ahead of its tick."""
    return _online_with_nothing_ahead(3.4)


@pytest.mark.slow
def test_paper_stop_at_3_5_s_meets_every_criterion_online():
    """The paper's second scenario (3.5 s, just after the touchdown: double support), online."""
    result = _online_with_nothing_ahead(3.5)
    assert result.plan.support == "double"
    assert result.criteria == {name: True for name in CRITERIA}
    assert result.online["joint_velocity_violations"] == 0
    assert result.numbers()["final_cog_offset_m"] < 0.02


@pytest.mark.slow
def test_paper_stop_meets_every_criterion_online(paper_stop):
    assert paper_stop.criteria == {name: True for name in CRITERIA}
    numbers = paper_stop.numbers()
    assert numbers["final_cog_offset_m"] < 0.01
    assert numbers["torso_tilt_max_rad"] < 0.05


def test_online_controller_works_every_tick_and_reports_its_cost(paper_stop):
    online = paper_stop.online
    assert online["controller"] == "online"
    tick = online["tick_compute"]
    dt = paper_stop.plan.params.servo_period
    span = paper_stop.times[-1] - paper_stop.plan.signal_time
    # one entry per servo tick from the signal on: the estimator, planner and IK run every tick
    assert tick["ticks"] == pytest.approx(span / dt, abs=2)
    assert 0 < tick["median"] <= tick["p99"] <= tick["max"]
    cpu = online["tick_compute_cpu"]  # the same ticks in the thread's CPU time
    assert cpu["ticks"] == tick["ticks"] and 0 < cpu["median"] <= cpu["p99"] <= cpu["max"]
    blocks = online["tick_compute_by_block"]  # where that CPU time goes, block by block
    assert {"WholeBodyIK._update", "StateEstimator._calc_estimate", "StopPlannerSystem._update",
            "StopPlannerSystem.reference"} <= set(blocks)  # the planner's reference: a cache, timed as its own
    assert all(seconds > 0 for seconds in blocks.values())
    assert sum(blocks.values()) == pytest.approx(cpu["mean"], rel=1e-9)
    slowest = online["tick_compute_slowest"]  # the worst ticks, what each spent its time on
    assert len(slowest) == 3 and slowest[0]["total"] == pytest.approx(cpu["max"], rel=1e-12)
    assert slowest[0]["t"] == pytest.approx(cpu["max_at"]) and slowest[0]["t"] >= paper_stop.plan.signal_time
    assert set(slowest[0]["blocks"]) <= set(blocks)
    assert online["replans"] >= 0 and online["replan_failures"] >= 0
    assert online["joint_velocity_violations"] == 0
    assert paper_stop.criteria["joint_speed_within_limits"]  # the criterion is that count being 0


def test_every_tick_times_both_of_its_state_estimates(monkeypatch):
    """A tick estimates the state twice (:func:`drake_estop.physics.plant.plant_config`): for the
    planner's unrestricted update, from the robot before the plant's step, and in the estimator's
    discrete update after it. Both count in the tick's compute time, also where a logger's publish
    (outside every update) computes the first one."""
    import time

    from pydrake.systems.analysis import Simulator

    from drake_estop.physics.estimation import StateEstimator

    steps = []
    original = StateEstimator._step

    def slow(self, context, x, t):  # a 3 ms estimate
        steps.append(t)
        time.sleep(0.003)
        return original(self, context, x, t)
    monkeypatch.setattr(StateEstimator, "_step", slow)
    params = controller_stop_parameters()
    handles = build_online_diagram(NominalPattern(), params, None)
    simulator = Simulator(handles.diagram)
    context = simulator.get_mutable_context()
    handles.plant.SetPositions(handles.plant.GetMyMutableContextFromRoot(context), handles.initial_q)
    simulator.Initialize()
    simulator.AdvanceTo(0.2)
    ticks = np.rint(np.array(steps) / params.servo_period).astype(int)
    # ticks 0-39 two estimates each (AdvanceTo(0.2) stops after the publish of tick 40, before its updates)
    assert np.array_equal(np.bincount(ticks)[:40], np.full(40, 2))
    per_tick = handles.timer.per_tick(clock="wall")[:40]
    assert len(per_tick) == 40 and np.all(per_tick >= 0.006)


def test_one_step_feasible_logged_every_tick_online(paper_stop):
    """The planner's one_step_feasible per servo tick from 0 (row k: a signal at tick k); it plans
    from the estimated state where that has left the reference, so only the latch is checked exactly."""
    column = paper_stop.online["one_step_feasible"]
    plan = paper_stop.plan
    dt = plan.params.servo_period
    assert len(column) >= round(paper_stop.times[-1] / dt) - 1
    assert set(np.unique(column)) == {0.0, 1.0}  # the walk before 3.4 s has next-step ticks (e.g. 3.2 s)
    latched = int(round(plan.signal_time / dt)) + 1
    first = getattr(plan, "plans", (plan,))[0]
    assert np.all(column[latched:] == float(first.case == "one-step"))


def test_joint_velocity_violations_counts_ticks_over_the_model_limit(paper_stop):
    from pydrake.multibody.plant import MultibodyPlant

    from drake_estop.model import load_humanoid

    plant = MultibodyPlant(0.001)
    load_humanoid(plant)
    plant.Finalize()
    states = np.zeros((3, plant.num_multibody_states()))
    limit = plant.GetVelocityUpperLimits()
    joint = int(np.flatnonzero(np.isfinite(limit))[0])
    states[1, plant.num_positions() + joint] = 1.01 * limit[joint]
    states[2, plant.num_positions() + joint] = -0.99 * limit[joint]
    np.testing.assert_array_equal(joint_velocity_violations(plant, states), [0, 1, 0])


def test_the_estimator_follows_the_true_cog(paper_stop):
    estimate = paper_stop.online["com_est"]
    n = min(len(estimate), len(paper_stop.times))
    true = np.column_stack([paper_stop.com_meas_x, paper_stop.com_meas_y])[:n]
    error = np.linalg.norm(estimate[:n, :2] - true, axis=1)
    assert np.max(error[10:]) < 0.01  # after the first ticks (the filter starts)


def test_pushes_go_through_the_plants_applied_spatial_force_input():
    handles = build_online_diagram(NominalPattern(), controller_stop_parameters(), 3.4,
                                   perturbations=Perturbations(pushes=(Push(3.4, 50.0, 0.0, 0.1),)))
    connections = handles.diagram.connection_map()
    port = handles.plant.get_applied_spatial_force_input_port()
    source = connections[(handles.plant, port.get_index())]
    assert source[0] is handles.push
    context = handles.push.CreateDefaultContext()
    context.SetTime(3.45)
    forces = handles.push.applied_spatial_force_port.Eval(context)
    assert len(forces) == 1
    np.testing.assert_allclose(forces[0].F_Bq_W.translational(), [50.0, 0.0, 0.0])


@pytest.mark.slow
def test_a_push_changes_the_measured_motion_and_is_absorbed():
    """17 N s backward at 3.1 s (mid single support): the stop re-plans from the measured state."""
    pattern = NominalPattern()
    pushed = run_online(estop_time=3.1, pattern=pattern, after_halt=2.5,
                        perturbations=Perturbations(pushes=(Push(3.1, -170.0, 0.0, 0.1),)))
    assert pushed.online["replans"] >= 1
    assert pushed.criteria["no_fall"]
    assert pushed.criteria["rests_at_midpoint"]


@pytest.mark.slow
def test_servo_rate_limit_keeps_the_rear_knee_within_its_velocity_limit(monkeypatch):
    """3.63 s (double support, two ticks before lift-off), with the IK's knee floor off: the IK holds
    the rear knee straight on its limit, then bends it at 8.9 rad/s (limit 6). The rate-limited servo
    command keeps the measured speed under the limit and the stop meets every criterion; without the
    limit the measured knee goes over it (the criterion is not vacuous). The default diagram has both
    the limit and the knee floor (which alone also keeps this stop within the limits)."""
    import drake_estop.physics.online as online

    monkeypatch.setattr(online, "IK_MIN_KNEE_BEND", 0.0)
    pattern = NominalPattern()
    limited = run_online(estop_time=3.63, pattern=pattern)
    assert limited.success, [name for name, ok in limited.criteria.items() if not ok]
    assert limited.online["joint_velocity_violations"] == 0
    assert limited.online["joint_velocity_peak"]["ratio"] <= 1.0
    handles = build_online_diagram(pattern, controller_stop_parameters(), 3.63)
    limits = handles.diagram.GetSubsystemByName("desired_state").velocity_limits
    plant_limits = handles.plant.GetVelocityUpperLimits()[actuated_indices(handles.plant)[1]]
    np.testing.assert_allclose(limits, online.SERVO_VELOCITY_LIMIT_FRACTION * plant_limits)
    monkeypatch.setattr(online, "SERVO_VELOCITY_LIMIT_FRACTION", None)
    unlimited = run_online(estop_time=3.63, pattern=pattern)
    assert not unlimited.criteria["joint_speed_within_limits"]
    assert unlimited.online["joint_velocity_peak"]["joint"] == "l_knee"
    assert unlimited.online["joint_velocity_peak"]["ratio"] > 1.0


@pytest.mark.slow
def test_lift_off_signal_stops_without_rocking(monkeypatch):
    """2.85 s, the third step's lift-off: with the landing at most 50 ms before the nominal touchdown
    (the controller's ``max_early_landing``) the stop meets every criterion; the paper's free landing
    (0.16 s early) rocks the robot from foot to foot and it comes to rest late.
    The counterfactual runs without the foot-edge compliance, which on its own also stops that rocking
    (measured: the free landing with it meets every criterion)."""
    import drake_estop.physics.online as online

    pattern = NominalPattern()
    bounded = run_online(estop_time=2.85, pattern=pattern)
    assert bounded.success, [name for name, ok in bounded.criteria.items() if not ok]
    assert bounded.numbers()["torso_tilt_max_rad"] < 0.03
    free = replace(online.CONTROLLER_STOP_PARAMETERS, max_early_landing=math.inf)
    monkeypatch.setattr(online, "CONTROLLER_STOP_PARAMETERS", free)
    rocking = run_online(estop_time=2.85, pattern=pattern, foot_compliance=False)
    assert rocking.plan.plans[0].landing_time < bounded.plan.plans[0].landing_time - 0.1
    assert not rocking.criteria["comes_to_rest"]
    assert rocking.numbers()["torso_tilt_max_rad"] > 0.05


@pytest.mark.slow
def test_double_support_forward_push_keeps_both_feet_on_the_floor(monkeypatch):
    """17 N s forward at 3.55 s (double support), a cell of the matrix: with the IK's knee floor
    (``IK_MIN_KNEE_BEND``) every criterion is met; without it the re-plan's COG stretched the rear knee
    straight, bending it back dropped the pelvis and the robot left the floor for a tick (no CoP). The
    counterfactual runs without the foot-edge compliance, which on its own also keeps this robot on the
    floor (measured)."""
    import drake_estop.physics.online as online

    pattern = NominalPattern()
    pushes = Perturbations(pushes=(Push(3.55, 170.0, 0.0, 0.1),))
    bent = run_online(estop_time=3.55, pattern=pattern, perturbations=pushes)
    assert bent.success, [name for name, ok in bent.criteria.items() if not ok]
    assert bent.online["replans"] >= 1
    assert np.all(np.isfinite(bent.cop_margin_plan[1:]))
    monkeypatch.setattr(online, "IK_MIN_KNEE_BEND", 0.0)
    straight = run_online(estop_time=3.55, pattern=pattern, perturbations=pushes, foot_compliance=False)
    assert not straight.criteria["cop_in_support"]
    assert not np.all(np.isfinite(straight.cop_margin_plan[1:]))  # a tick with no contact


@pytest.mark.slow
def test_foot_edge_compliance_keeps_the_backward_pushed_robot_on_the_floor():
    """17 N s backward at 3.55 s (double support), a cell of the matrix: with the ankles' foot-edge
    compliance (the default) every criterion is met and the ankles moved; without it the feet rock on their
    heels and the robot leaves the floor for a tick (no CoP)."""
    pattern = NominalPattern()
    pushes = Perturbations(pushes=(Push(3.55, -170.0, 0.0, 0.1),))
    compliant = run_online(estop_time=3.55, pattern=pattern, perturbations=pushes)
    assert compliant.success, [name for name, ok in compliant.criteria.items() if not ok]
    assert compliant.online["ankle_offset_max"] > 1e-3
    stiff = run_online(estop_time=3.55, pattern=pattern, perturbations=pushes, foot_compliance=False)
    assert not stiff.criteria["cop_in_support"]
    assert stiff.online["ankle_offset_max"] == 0.0


@pytest.mark.slow
def test_a_low_swing_foot_is_not_dragged_to_a_far_landing(monkeypatch):
    """A 0.2385 m step, signal at 3.45 s (the swing foot 0.6 mm above the floor, coming down): with the
    controller's landing-shift limit the foot lands on its nominal footstep and every criterion is met;
    the paper's plan sends it 6.6 cm further and the robot falls with no push at all (found as campaign
    runs 219, 300 and 472). The double-support re-plan on the measured footholds also
    recovers the dragged landing (the plan then stands where the foot came down); without either the robot
    falls."""
    import drake_estop.physics.online as online

    pattern = NominalPattern(GaitParameters(step_length=0.2385))
    limited = run_online(estop_time=3.45, pattern=pattern)
    assert limited.success, [name for name, ok in limited.criteria.items() if not ok]
    free = replace(online.CONTROLLER_STOP_PARAMETERS, max_landing_shift_per_height=math.inf)
    monkeypatch.setattr(online, "CONTROLLER_STOP_PARAMETERS", free)
    dragged = run_online(estop_time=3.45, pattern=pattern, planner_options={"measured_footholds": False})
    assert not dragged.criteria["no_fall"]
    rescued = run_online(estop_time=3.45, pattern=pattern)
    assert rescued.success, [name for name, ok in rescued.criteria.items() if not ok]
    assert rescued.online["replans"] >= 1


@pytest.mark.slow
def test_ankle_strategy_replans_the_sideways_pushed_single_support_stop(monkeypatch):
    """17 N s left at 2.95 s (early single support, left foot supporting), a cell of the matrix.
    The push moves the DCM over the support foot's outer edge: no landing stops that with the ZMP held at
    the ankle (eq. 19), so every single-support re-plan failed, the robot landed late and stood on one toe
    with the CoP 27.9 mm outside the planned support. With the re-plan's ankle strategy
    (``replan.ankle_zmp``) it re-plans, and every criterion is met."""
    from drake_estop.planning import replan

    pattern = NominalPattern()
    pushes = Perturbations(pushes=(Push(2.95, 0.0, 170.0, 0.1),))
    ankle = run_online(estop_time=2.95, pattern=pattern, perturbations=pushes)
    assert ankle.success, [name for name, ok in ankle.criteria.items() if not ok]
    assert ankle.online["replans"] >= 1 and ankle.online["replan_failures"] == 0
    monkeypatch.setattr(replan, "ankle_zmp", lambda *args: None)
    held = run_online(estop_time=2.95, pattern=pattern, perturbations=pushes)
    assert held.online["replan_failures"] > 0
    assert not held.criteria["cop_in_support"]


@pytest.mark.slow
def test_swing_tilt_compensation_lands_the_foot_of_a_robot_pushed_towards_it():
    """17 N s right at 3.15 s (mid single support, left foot supporting, the push towards the swing
    side), a cell of the matrix. The push rolls the body about 0.04 rad; without the swing foot's
    tilt compensation the foot comes down rolled and low, strikes the floor early and short on its outer
    edge, the stance foot unloads and slides and the CoP leaves the planned support (-16.1 mm);
    with it every criterion is met."""
    pattern = NominalPattern()
    pushes = Perturbations(pushes=(Push(3.15, 0.0, -170.0, 0.1),))
    compensated = run_online(estop_time=3.15, pattern=pattern, perturbations=pushes)
    assert compensated.success, [name for name, ok in compensated.criteria.items() if not ok]
    assert compensated.online["swing_tilt_max"] > 0.02
    tilted = run_online(estop_time=3.15, pattern=pattern, perturbations=pushes, swing_tilt=False)
    assert tilted.online["swing_tilt_max"] == 0.0
    assert not tilted.criteria["cop_in_support"]


@pytest.mark.slow
def test_measured_footholds_keep_the_cop_of_a_robot_pushed_towards_its_swing_foot_in_support():
    """17 N s right at 2.95 s (early single support, left foot supporting), a cell of the
    matrix. The swing foot lands 1.9 cm inside and 7 mm ahead of its re-planned
    target, the landing impact unloads the support foot and it slides 9 mm; the double-support re-plans on
    the plan's feet put the ZMP at the landed foot's outer edge and the CoP left the planned support by
    4.2 mm. Re-planned on the estimated footholds (sole targets blended onto them) every criterion is met."""
    pattern = NominalPattern()
    pushes = Perturbations(pushes=(Push(2.95, 0.0, -170.0, 0.1),))
    measured = run_online(estop_time=2.95, pattern=pattern, perturbations=pushes)
    assert measured.success, [name for name, ok in measured.criteria.items() if not ok]
    assert measured.online["replans"] >= 2
    landed = measured.plan.final_feet["right"]
    assert abs(landed[1] - measured.plan.plans[1].final_feet["right"][1]) > 0.01  # re-planned where it landed
    planned = run_online(estop_time=2.95, pattern=pattern, perturbations=pushes,
                         planner_options={"measured_footholds": False})
    assert not planned.criteria["cop_in_support"]


@pytest.mark.slow
def test_a_foot_landed_off_its_foothold_replans_the_stop_on_the_measured_feet():
    """15 N s left at 2.95 s (early single support): the DCM stays within the landed re-plan threshold,
    so no DCM re-plan comes, but the pushed swing foot lands off its target. Without a re-plan (the
    default) the CoP, inside the measured soles, leaves the planned ones by 0.2 mm; the foothold re-plan
    option makes the stop on the measured feet and every criterion is met."""
    pattern = NominalPattern()
    pushes = Perturbations(pushes=(Push(2.95, 0.0, 150.0, 0.1),))
    replanned = run_online(estop_time=2.95, pattern=pattern, perturbations=pushes,
                           planner_options={"foothold_replan": True})
    assert replanned.success, [name for name, ok in replanned.criteria.items() if not ok]
    first, replan = replanned.plan.plans
    assert replanned.online["replans"] == 1 and replan.start_time > first.landing_time  # after the landing
    kept = run_online(estop_time=2.95, pattern=pattern, perturbations=pushes)
    assert kept.online["replans"] == 0
    assert not kept.criteria["cop_in_support"]


@pytest.mark.slow
def test_a_recovery_step_catches_a_forward_push_in_double_support():
    """30 N s forward at 3.55 s (double support, 0.52 m/s): the COG runs past the fore foot, the rear leg
    reaches its limit and every double-support re-plan is infeasible. Without a recovery step the robot
    stands on the fore toe, pitches forward and falls; with one the rear foot steps past the fore foot
    and the robot stops meeting every criterion."""
    pattern = NominalPattern()
    pushes = Perturbations(pushes=(Push(3.55, 300.0, 0.0, 0.1),))
    stepped = run_online(estop_time=3.55, pattern=pattern, perturbations=pushes)
    assert stepped.success, [name for name, ok in stepped.criteria.items() if not ok]
    summary = stepped.plan.summary()
    assert summary["recovery_steps"] == 1 and summary["steps_after_signal"] == 1
    assert stepped.plan.final_feet["left"][0] > stepped.plan.final_feet["right"][0]  # the rear foot stepped
    held = run_online(estop_time=3.55, pattern=pattern, perturbations=pushes,
                      planner_options={"recovery_step": False})
    assert not held.criteria["no_fall"]


@pytest.mark.slow
def test_the_braked_landing_stops_a_half_metre_per_second_forward_push_early_in_single_support():
    """29 N s forward at 2.95 s (0.5 m/s; early single support, the swing foot 0.57 m from its landing).
    With the paper's landing swing (``braked_landing=False``) the re-plans hurry the landing and the foot
    skims the floor: the CoP leaves the planned support and the robot falls. The controller's braked
    landing (BRAKED_LANDING, the default: a re-plan's landing is bounded by the braking limit and its swing
    approaches the floor at the slope) meets every criterion."""
    pattern = NominalPattern()
    pushes = Perturbations(pushes=(Push(2.95, 290.0, 0.0, 0.1),))
    stopped = run_online(estop_time=2.95, pattern=pattern, perturbations=pushes)
    assert stopped.success, [name for name, ok in stopped.criteria.items() if not ok]
    hurried = run_online(estop_time=2.95, pattern=pattern, perturbations=pushes,
                         stop_params=controller_stop_parameters(braked_landing=False))
    assert not hurried.criteria["cop_in_support"] and not hurried.criteria["no_fall"]
    assert any(plan.braked_swing for plan in stopped.plan.plans)


@pytest.mark.slow
def test_a_rear_sole_that_relands_off_its_foothold_replans_the_stop_where_it_stands():
    """17 N s forward at 2.95 s (a matrix cell) with the approach slope given explicitly (on every landing
    swing): in the halt the robot rocks onto the fore foot, the rear sole
    leaves the floor for 35 ms and comes down 6 mm behind its foothold; the CoP then runs to the rear heel,
    inside the measured sole but 0.4 mm outside the plan's without the re-landed footholds. With them (the
    default) the stop is re-planned where the sole stands."""
    from drake_estop.physics.online import BRAKED_LANDING
    from drake_estop.planning.planner import StopParameters

    pattern = NominalPattern()
    pushes = Perturbations(pushes=(Push(2.95, 170.0, 0.0, 0.1),))
    braked = controller_stop_parameters(replace(StopParameters(), **BRAKED_LANDING))
    stopped = run_online(estop_time=2.95, pattern=pattern, perturbations=pushes, stop_params=braked)
    assert stopped.success, [name for name, ok in stopped.criteria.items() if not ok]
    on_the_plan = run_online(estop_time=2.95, pattern=pattern, perturbations=pushes, stop_params=braked,
                             planner_options={"relanded_footholds": False})
    assert not on_the_plan.criteria["cop_in_support"]
    assert np.nanmin(on_the_plan.cop_margin_plan[1:]) > -0.002  # a near miss, not a fall
    assert stopped.online["replans"] > on_the_plan.online["replans"]


# -- command line ----------------------------------------------------------------------------------


@pytest.mark.parametrize("args, option", [
    (["--mass-scale", "0"], "--mass-scale"),
    (["--mass-scale", "nan"], "--mass-scale"),
    (["--torso-mass-scale", "-1"], "--torso-mass-scale"),
    (["--torso-com-offset", "0.5"], "--torso-com-offset"),
    (["--friction", "0"], "--friction"),
    (["--latency", "-1"], "--latency"),
    (["--push", "3.4", "10", "0", "0"], "--push"),
    (["--push", "3.4", "nan", "0", "0.1"], "--push"),
    (["--seed", "-3"], "--seed"),
])
def test_bad_perturbations_exit_2_naming_the_option(args, option, capsys):
    assert main(["simulate", "--physics", *args]) == 2
    assert option in capsys.readouterr().err


def test_perturbations_need_physics(capsys):
    assert main(["simulate", "--kinematic", "--mass-scale", "1.1"]) == 2
    assert "--physics" in capsys.readouterr().err


def _online_run_keywords(monkeypatch, args):
    """The keyword arguments `simulate --physics ARGS` passes to run_online (the run itself is cut short)."""
    import drake_estop.physics.online as online

    seen = {}

    def fake_run_online(gait, stop, estop_time, **kwargs):
        seen.update(kwargs)
        raise RuntimeError("stop here")

    monkeypatch.setattr(online, "run_online", fake_run_online)
    assert main(["simulate", "--physics", *args]) == 2
    return seen


def test_the_braked_landing_reaches_the_online_run_and_turns_off(monkeypatch):
    """The controller's braked landing (BRAKED_LANDING) is in run_online's stop parameters by default,
    over the controller's margin; ``--no-braked-landing`` gives the paper's landing swing; a tighter
    limit from the command line is kept."""
    import drake_estop.physics.online as online

    seen = []

    def fake_run_online(gait, stop, estop_time, **kwargs):
        seen.append(stop)
        raise RuntimeError("stop here")

    monkeypatch.setattr(online, "run_online", fake_run_online)
    assert main(["simulate", "--physics"]) == 2
    assert main(["simulate", "--physics", "--no-braked-landing"]) == 2
    assert main(["simulate", "--physics", "--max-swing-acceleration=10", "--landing-approach-slope=0.8"]) == 2
    braked, paper, tighter = seen
    assert braked.max_swing_acceleration == 15.0 and braked.landing_approach_slope == 0.6
    assert braked.landing_approach_when_braking  # the slope only where the braking limit bounds the landing
    assert braked.zmp_margin == paper.zmp_margin == pytest.approx(0.03)
    assert paper.max_swing_acceleration == math.inf and paper.landing_approach_slope == 0.0
    assert tighter.max_swing_acceleration == 10.0 and tighter.landing_approach_slope == 0.8
    assert not tighter.landing_approach_when_braking  # a slope given shapes every swing


@pytest.mark.parametrize("mode", [["--kinematic"], ["--physics", "--controller", "offline-filter"]])
def test_no_braked_landing_needs_the_online_physics_run(mode, capsys):
    assert main(["simulate", *mode, "--no-braked-landing"]) == 2
    assert "--no-braked-landing" in capsys.readouterr().err


@pytest.mark.parametrize("flag, given", [([], True), (["--no-foot-compliance"], False)])
def test_no_foot_compliance_reaches_the_online_run(monkeypatch, flag, given):
    assert _online_run_keywords(monkeypatch, flag)["foot_compliance"] is given


@pytest.mark.parametrize("flag, given", [([], True), (["--no-swing-tilt"], False)])
def test_no_swing_tilt_reaches_the_online_run(monkeypatch, flag, given):
    assert _online_run_keywords(monkeypatch, flag)["swing_tilt"] is given


@pytest.mark.parametrize("args", [["--kinematic", "--no-foot-compliance"],
                                  ["--physics", "--controller", "offline-filter", "--no-foot-compliance"]])
def test_no_foot_compliance_needs_the_online_physics_run(args, capsys):
    assert main(["simulate", *args]) == 2
    assert "--no-foot-compliance" in capsys.readouterr().err


#: The online controller's StopPlannerSystem options the command line turns off: flag -> option name.
PLANNER_FLAGS = {"--no-measured-footholds": "measured_footholds", "--no-recovery-step": "recovery_step",
                 "--no-relanded-footholds": "relanded_footholds", "--no-reference-fallback": "reference_fallback"}


@pytest.mark.parametrize("flag", [None, *PLANNER_FLAGS])
def test_planner_flags_reach_the_online_run(monkeypatch, flag):
    options = _online_run_keywords(monkeypatch, [flag] if flag else [])["planner_options"] or {}
    for other, name in PLANNER_FLAGS.items():
        assert options.get(name, True) is (other != flag), name


def test_foothold_replan_flag_turns_the_option_on(monkeypatch):
    assert (_online_run_keywords(monkeypatch, [])["planner_options"] or {}).get("foothold_replan", False) is False
    options = _online_run_keywords(monkeypatch, ["--foothold-replan"])["planner_options"]
    assert options == {"foothold_replan": True}  # and leaves the other options at their defaults


@pytest.mark.parametrize("args, given", [
    ([], "default"),
    (["--max-replan-solves", "1"], 1),
    (["--max-replan-solves", "unbounded"], None),
    (["--scenario-text", "{max_replan_solves: null}"], None),
    (["--scenario-text", "{max_replan_solves: 4}"], 4),
])
def test_max_replan_solves_reaches_the_online_run(monkeypatch, args, given):
    options = _online_run_keywords(monkeypatch, args)["planner_options"] or {}
    assert options.get("max_replan_solves", "default") == given
    assert set(options) <= {"max_replan_solves"}  # the other planner options stay at their defaults


@pytest.mark.parametrize("value", ["0", "-1", "1.5", "two", "nan"])
def test_a_bad_max_replan_solves_exits_2_naming_it(value, capsys):
    assert main(["simulate", "--physics", "--max-replan-solves", value]) == 2
    assert "argument --max-replan-solves" in capsys.readouterr().err


@pytest.mark.parametrize("mode", [["--kinematic"], ["--physics", "--controller", "offline-filter"]])
def test_max_replan_solves_needs_the_online_physics_run(mode, capsys):
    assert main(["simulate", *mode, "--max-replan-solves", "1"]) == 2
    assert "--max-replan-solves" in capsys.readouterr().err


@pytest.mark.parametrize("mode", [["--kinematic"], ["--physics", "--controller", "offline-filter"]])
def test_foothold_replan_flag_needs_the_online_physics_run(mode, capsys):
    assert main(["simulate", *mode, "--foothold-replan"]) == 2
    assert "--foothold-replan" in capsys.readouterr().err


@pytest.mark.parametrize("flag", PLANNER_FLAGS)
@pytest.mark.parametrize("mode", [["--kinematic"], ["--physics", "--controller", "offline-filter"]])
def test_planner_flags_need_the_online_physics_run(flag, mode, capsys):
    assert main(["simulate", *mode, flag]) == 2
    err = capsys.readouterr().err
    assert flag in err and "--no-swing-tilt" not in err
    assert all(other not in err for other in PLANNER_FLAGS if other != flag)


@pytest.mark.parametrize("args", [["--kinematic", "--no-swing-tilt"],
                                  ["--physics", "--controller", "offline-filter", "--no-swing-tilt"]])
def test_no_swing_tilt_needs_the_online_physics_run(args, capsys):
    assert main(["simulate", *args]) == 2
    assert "--no-swing-tilt" in capsys.readouterr().err


@pytest.mark.parametrize("args, field, value", [
    (["--push", "3.4", "170", "0", "0.1"], "pushes", (Push(3.4, 170.0, 0.0, 0.1),)),
    (["--push", "3.4", "170", "0", "0.1", "--push", "3.6", "0", "-50", "0.2"], "pushes",
     (Push(3.4, 170.0, 0.0, 0.1), Push(3.6, 0.0, -50.0, 0.2))),
    (["--mass-scale", "1.1"], "mass_scale", 1.1),
    (["--torso-mass-scale", "0.9"], "torso_mass_scale", 0.9),
    (["--torso-com-offset", "-0.02"], "torso_com_offset", -0.02),
    (["--friction", "0.5"], "friction", 0.5),
    (["--latency", "1"], "latency_ticks", 1),
    (["--sensor-noise"], "sensor_noise", True),
    (["--seed", "7"], "seed", 7),
])
def test_each_perturbation_option_reaches_the_simulated_run(monkeypatch, tmp_path, args, field, value):
    """Every option lands in the Perturbations the online run is given (the modules' own tests show
    each one acting on the plant, the sensors and the push input)."""
    seen = _online_run_keywords(monkeypatch, args)
    assert getattr(seen["perturbations"], field) == value
    assert seen["true_state"] is False


@pytest.mark.slow
def test_physics_summary_reports_the_online_controller(tmp_path):
    summary, log = tmp_path / "s.json", tmp_path / "log.csv"
    code = main(["simulate", "--physics", "--estop-time", "3.4", "--mass-scale", "1.1",
                 "--summary", str(summary), "--log", str(log)])
    data = json.load(open(summary))
    assert code == (0 if data["success"] else 1)
    assert data["controller"] == "online"
    assert set(data["criteria"]) == set(CRITERIA)
    assert set(data["tick_compute"]) >= {"median", "p99", "max"}
    assert data["tick_compute"]["median"] > 0
    assert set(data["tick_compute_cpu"]) >= {"median", "p99", "max"} and data["tick_compute_cpu"]["median"] > 0
    assert data["tick_compute_by_block"]["WholeBodyIK._update"] > 0
    worst = data["tick_compute_slowest"][0]  # the slowest tick after the signal, block by block
    assert worst["total"] == pytest.approx(data["tick_compute_cpu"]["max"]) and worst["blocks"]
    assert data["cpu_realtime_factor"] > 0  # how large is a benchmark (benchmarks/robustness.py), not a test
    assert isinstance(data["replans"], int) and isinstance(data["joint_velocity_violations"], int)
    assert 0.0 <= data["ankle_offset_max"] <= 0.05  # the foot-edge compliance's bound
    assert 0.0 <= data["swing_tilt_max"] <= 0.17  # the swing-tilt compensation's cap
    assert data["perturbations"]["mass_scale"] == 1.1
    header = open(log).readline().strip().split(",")
    for column in ("cop_x", "cop_y", "pelvis_z", "com_meas_x", "com_meas_y", "com_meas_z", "com_est_x",
                   "one_step_feasible"):
        assert column in header


@pytest.mark.parametrize("arguments, named", [
    ({"estop_time": float("nan")}, "estop_time"),
    ({"estop_time": -0.1}, "estop_time"),
    ({"estop_time": 100.0}, "estop_time"),  # past the walk's end
    ({"estop_time": "3.4 s"}, "estop_time"),
    ({"after_halt": 0.5}, "after_halt"),
    ({"after_halt": float("inf")}, "after_halt"),
    ({"planner_options": {"replan_treshold": 0.05}}, "planner_options"),
    ({"planner_options": True}, "planner_options"),
    ({"foot_compliance": {"damp": 80.0}}, "foot_compliance"),
    ({"swing_tilt": 0.17}, "swing_tilt"),
    ({"gait_params": GaitParameters(step_length=0.2), "pattern": NominalPattern()}, "gait_params and pattern"),
])
def test_run_online_rejects_bad_arguments_naming_them(arguments, named, monkeypatch):
    import drake_estop.physics.online as online

    def no_build(*args, **kwargs):
        raise AssertionError("built a diagram from bad arguments")

    monkeypatch.setattr(online, "build_online_diagram", no_build)  # rejected before any work
    with pytest.raises(ValueError, match=named):
        online.run_online(**arguments)


def test_run_online_takes_matching_gait_params_and_pattern(monkeypatch):
    """The CLI passes both: a pattern built from the same gait is not a disagreement."""
    import drake_estop.physics.online as online

    built = {}

    def stop_after_build(pattern, *args, **kwargs):
        built["pattern"] = pattern
        raise RuntimeError("stop here")

    monkeypatch.setattr(online, "build_online_diagram", stop_after_build)
    gait = GaitParameters(step_length=0.25)
    pattern = NominalPattern(gait)
    with pytest.raises(RuntimeError, match="stop here"):
        online.run_online(gait_params=gait, pattern=pattern, estop_time=3.4)
    assert built["pattern"] is pattern


#: The campaign's run 181 (docs/campaign): a push under way at the signal that no stop from the measured state catches.
RUN_181 = ["simulate", "--physics", "--estop-time", "3.275", "--step-length", "0.2234", "--step-time", "0.875",
           "--step-width", "0.2034", "--push", "3.196", "412.98", "400.42", "0.052", "--mass-scale", "0.915",
           "--torso-mass-scale", "1.0602", "--torso-com-offset", "-0.01243", "--friction", "0.8393",
           "--latency", "1", "--seed", "1809849821110597283", "--sensor-noise"]


def test_without_the_reference_fallback_that_push_ends_the_run_with_the_planners_reason(capsys):
    assert main([*RUN_181, "--no-reference-fallback"]) == 2
    assert "stop planning failed at t = 3.280 s: no feasible stop in the first 4 tries" in capsys.readouterr().err


def test_a_push_no_stop_catches_at_the_signal_still_runs_the_stop_from_the_reference(tmp_path, capsys):
    """The campaign's run 181 (29.9 N s forward-left starting 79 ms before a 3.275 s signal,
    model error, noise, one tick of latency): at the signal no stop within two steps exists from the
    measured state, and the run used to end there with exit status 2 ("stop planning failed"). The latch
    now plans the paper's stop from the reference and re-plans from the measured state: the run goes to
    its end and the robot stays up (the CoP leaves the planned soles, so it still fails a criterion)."""
    summary = tmp_path / "summary.json"
    code = main([*RUN_181, "--summary", str(summary)])
    data = json.loads(summary.read_text())
    assert code == (0 if data["physics"]["success"] else 1)
    assert "no feasible stop in the first 4 tries" in data["latch_fallback"]  # MAX_LATCH_SOLVES
    assert "planned from the reference" in capsys.readouterr().out
    assert data["physics"]["criteria"]["no_fall"]
    assert data["replans"] >= 1


def test_reference_fallback_is_set_from_the_scenario_file_too(monkeypatch):
    options = _online_run_keywords(monkeypatch, ["--scenario-text", "{reference_fallback: false}"])["planner_options"]
    assert options == {"reference_fallback": False}


@pytest.mark.parametrize("mode", [["--kinematic"], ["--physics", "--controller", "offline-filter"]])
def test_no_reference_fallback_needs_the_online_physics_run(mode, capsys):
    assert main(["simulate", *mode, "--no-reference-fallback"]) == 2
    assert "--no-reference-fallback" in capsys.readouterr().err


def test_online_simulator_starts_the_robot_in_its_pose_with_the_model_errors_in_the_simulated_plant_only():
    handles = build_online_diagram(NominalPattern(), controller_stop_parameters(), None)
    plant = handles.plant
    simulator = online_simulator(handles, Perturbations(mass_scale=1.1))
    plant_context = plant.GetMyContextFromRoot(simulator.get_context())
    assert np.array_equal(plant.GetPositions(plant_context), handles.initial_q)
    nominal = plant.CalcTotalMass(plant.CreateDefaultContext())
    assert plant.CalcTotalMass(plant_context) == pytest.approx(1.1 * nominal)  # the simulated robot, x1.1
    assert simulator.get_context().get_time() == 0.0
    other = build_online_diagram(NominalPattern(), controller_stop_parameters(), None)
    plain = online_simulator(other)  # without perturbations: the nominal masses
    assert other.plant.CalcTotalMass(other.plant.GetMyContextFromRoot(plain.get_context())) == pytest.approx(nominal)
