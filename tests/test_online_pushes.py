"""The online controller's pushed and perturbed stops in physics (cells of the robustness matrix), each
against the counterfactual without the measure that saves it."""

import math
from dataclasses import replace

import numpy as np
import pytest

from drake_estop.physics.controller_options import ControllerOptions, HipStrategyConfig
from drake_estop.physics.online import (
    build_online_diagram,
    controller_stop_parameters,
    robot_stop_parameters,
    run_online,
)
from drake_estop.physics.perturbations import Perturbations, Push
from drake_estop.physics.plant import actuated_indices
from drake_estop.planning.capture import MAX_STEP_WIDTH
from drake_estop.planning.gait import GaitParameters, NominalPattern
from drake_estop.planning.landing import PAPER_A_DS
from drake_estop.systems.decision import StopPlannerConfig


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
    rocking = run_online(estop_time=2.85, pattern=pattern, controller=ControllerOptions(foot_compliance=None))
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
    straight = run_online(estop_time=3.55, pattern=pattern, perturbations=pushes,
                          controller=ControllerOptions(foot_compliance=None))
    assert not straight.criteria["cop_in_support"]
    assert not np.all(np.isfinite(straight.cop_margin_plan[1:]))  # a tick with no contact


@pytest.mark.slow
def test_foot_edge_compliance_keeps_the_backward_pushed_robot_on_the_floor():
    """17 N s backward at 3.55 s (double support), a cell of the matrix: with the ankles' foot-edge
    compliance (the default) every criterion is met and the ankles moved. Without it and without the feet's
    force control the feet rock on their heels and the CoP leaves the planned support; the force control
    alone (compliance off) also keeps the robot on its feet."""
    pattern = NominalPattern()
    pushes = Perturbations(pushes=(Push(3.55, -170.0, 0.0, 0.1),))
    compliant = run_online(estop_time=3.55, pattern=pattern, perturbations=pushes)
    assert compliant.success, [name for name, ok in compliant.criteria.items() if not ok]
    assert compliant.online["ankle_offset_max"] > 1e-3
    stiff = run_online(estop_time=3.55, pattern=pattern, perturbations=pushes,
                       controller=ControllerOptions(foot_compliance=None, foot_force=None))
    assert not stiff.criteria["cop_in_support"]
    assert stiff.online["ankle_offset_max"] == 0.0
    loaded = run_online(estop_time=3.55, pattern=pattern, perturbations=pushes,
                        controller=ControllerOptions(foot_compliance=None))
    assert loaded.success, [name for name, ok in loaded.criteria.items() if not ok]


@pytest.mark.slow
def test_a_low_swing_foot_is_not_dragged_to_a_far_landing(monkeypatch):
    """A 0.2385 m step, signal at 3.45 s (the swing foot 0.6 mm above the floor, coming down): with the
    controller's landing-shift limit the foot lands on its nominal footstep and every criterion is met;
    the paper's plan sends it 6.6 cm further, and with no push at all the CoP leaves its support (with the
    paper's double-support ZMP weight the robot fell: campaign runs 219, 300 and 472). The double-support
    re-plan on the measured footholds also recovers the dragged landing (the plan then stands where the
    foot came down): with the paper's weight every criterion holds; with the default humanoid's
    heavier weight the robot stays up and rests, the CoP 1.5 mm past the sole's edge."""
    import drake_estop.physics.online as online

    pattern = NominalPattern(GaitParameters(step_length=0.2385))
    limited = run_online(estop_time=3.45, pattern=pattern)
    assert limited.success, [name for name, ok in limited.criteria.items() if not ok]
    free = replace(online.CONTROLLER_STOP_PARAMETERS, max_landing_shift_per_height=math.inf)
    monkeypatch.setattr(online, "CONTROLLER_STOP_PARAMETERS", free)
    dragged = run_online(estop_time=3.45, pattern=pattern,
                         controller=ControllerOptions(planner=StopPlannerConfig(measured_footholds=False)))
    assert not dragged.criteria["cop_in_support"]
    rescued = run_online(estop_time=3.45, pattern=pattern,
                         stop_params=replace(robot_stop_parameters(), a_ds=PAPER_A_DS))
    assert rescued.success, [name for name, ok in rescued.criteria.items() if not ok]
    assert rescued.online["replans"] >= 1
    heavier = run_online(estop_time=3.45, pattern=pattern)
    assert heavier.criteria["no_fall"] and heavier.criteria["comes_to_rest"], heavier.criteria
    assert heavier.numbers()["cop_margin_plan_min_m"] > -0.005
    assert heavier.cop_exit()["margin"] == heavier.numbers()["cop_margin_plan_min_m"]
    assert limited.cop_exit() is None and rescued.cop_exit() is None


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
    tilted = run_online(estop_time=3.15, pattern=pattern, perturbations=pushes,
                        controller=ControllerOptions(swing_tilt=None))
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
                         controller=ControllerOptions(planner=StopPlannerConfig(measured_footholds=False)))
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
                           controller=ControllerOptions(planner=StopPlannerConfig(foothold_replan=True)))
    assert replanned.success, [name for name, ok in replanned.criteria.items() if not ok]
    first, replan = replanned.plan.plans
    assert replanned.online["replans"] == 1 and replan.start_time > first.landing_time  # after the landing
    kept = run_online(estop_time=2.95, pattern=pattern, perturbations=pushes)
    assert kept.online["replans"] == 0
    assert not kept.criteria["cop_in_support"]


@pytest.mark.slow
def test_a_recovery_step_catches_a_forward_push_in_double_support():
    """25 N s forward at 3.55 s (double support, 0.43 m/s): every double-support re-plan is infeasible.
    Without a recovery step the robot stands on the fore toe and the CoP leaves the planned support by
    13 mm; with one the rear foot steps past the fore foot and the stop meets every criterion. At 30 N s
    (0.52 m/s), measured without the feet's force control, one recovery step meets every criterion and
    without it the robot falls (with the force control, the default, it takes two and its rear sole slips
    12.6 mm: a known limit)."""
    pattern = NominalPattern()
    for impulse, options in ((250.0, {}), (300.0, {"foot_force": None})):
        pushes = Perturbations(pushes=(Push(3.55, impulse, 0.0, 0.1),))
        stepped = run_online(estop_time=3.55, pattern=pattern, perturbations=pushes,
                             controller=ControllerOptions(**options))
        assert stepped.success, (impulse, [name for name, ok in stepped.criteria.items() if not ok])
        summary = stepped.plan.summary()
        assert summary["recovery_steps"] == 1 and summary["steps_after_signal"] == 1
        assert stepped.plan.final_feet["left"][0] > stepped.plan.final_feet["right"][0]  # the rear foot stepped
        held = run_online(estop_time=3.55, pattern=pattern, perturbations=pushes,
                          controller=ControllerOptions(planner=StopPlannerConfig(recovery_step=False), **options))
        assert not held.criteria["cop_in_support"]
        assert held.criteria["no_fall"] == (impulse < 300.0)


@pytest.mark.slow
def test_the_braked_landing_stops_a_half_metre_per_second_forward_push_early_in_single_support():
    """29 N s forward at 2.95 s (0.5 m/s; early single support, the swing foot 0.57 m from its landing).
    With the paper's landing swing (``ControllerOptions(braked_landing=False)``) the re-plans hurry the
    landing and the foot skims the floor: the CoP leaves the planned support and the robot falls. The
    controller's braked landing (BRAKED_LANDING, the default: a re-plan's landing is bounded by the braking
    limit and its swing approaches the floor at the slope) meets every criterion."""
    pattern = NominalPattern()
    pushes = Perturbations(pushes=(Push(2.95, 290.0, 0.0, 0.1),))
    stopped = run_online(estop_time=2.95, pattern=pattern, perturbations=pushes)
    assert stopped.success, [name for name, ok in stopped.criteria.items() if not ok]
    hurried = run_online(estop_time=2.95, pattern=pattern, perturbations=pushes,
                         controller=ControllerOptions(braked_landing=False))
    assert not hurried.criteria["cop_in_support"] and not hurried.criteria["no_fall"]
    assert any(plan.braked_swing for plan in stopped.plan.plans)


@pytest.mark.slow
def test_a_rear_sole_that_relands_off_its_foothold_replans_the_stop_where_it_stands():
    """17 N s forward at 2.95 s (a matrix cell) with the approach slope given explicitly (on every landing
    swing), without the feet's force control: in the halt the robot rocks onto the fore foot, the rear sole
    leaves the floor for 35 ms and comes down 6 mm behind its foothold; the CoP then runs to the rear heel,
    inside the measured sole but 0.4 mm outside the plan's without the re-landed footholds. With them (the
    default) the stop is re-planned where the sole stands. The force control (the default) keeps the rear
    sole down: then the stop meets every criterion without the re-landed footholds too."""
    from drake_estop.physics.online import BRAKED_LANDING
    from drake_estop.planning.planner import StopParameters

    pattern = NominalPattern()
    pushes = Perturbations(pushes=(Push(2.95, 170.0, 0.0, 0.1),))
    braked = controller_stop_parameters(replace(StopParameters(), **BRAKED_LANDING))
    unloaded = ControllerOptions(foot_force=None)
    stopped = run_online(estop_time=2.95, pattern=pattern, perturbations=pushes, stop_params=braked,
                         controller=unloaded)
    assert stopped.success, [name for name, ok in stopped.criteria.items() if not ok]
    on_the_plan = run_online(estop_time=2.95, pattern=pattern, perturbations=pushes, stop_params=braked,
                             controller=replace(unloaded, planner=StopPlannerConfig(relanded_footholds=False)))
    assert not on_the_plan.criteria["cop_in_support"]
    assert np.nanmin(on_the_plan.cop_margin_plan[1:]) > -0.002  # a near miss, not a fall
    assert stopped.online["replans"] > on_the_plan.online["replans"]
    loaded = run_online(estop_time=2.95, pattern=pattern, perturbations=pushes, stop_params=braked,
                        controller=ControllerOptions(planner=StopPlannerConfig(relanded_footholds=False)))
    assert loaded.success, [name for name, ok in loaded.criteria.items() if not ok]


@pytest.mark.slow
def test_a_capture_landing_stops_a_half_metre_per_second_push_towards_the_swing_foot():
    """29 N s (0.5 m/s) to the right at 2.95 s, early in single support on the left foot: the capture
    landing (planning/replan.py) brings the swing foot down at the widest step 0.2 s after the push instead
    of at the plan's far landing point 0.44 s after it, and the stop meets every criterion. Without it
    the DCM is 0.12 m past the landed sole at the touchdown and the robot falls."""

    push = Perturbations(pushes=(Push(2.95, 0.0, -290.0, 0.1),))
    caught = run_online(estop_time=2.95, perturbations=push)
    assert caught.success, [name for name, ok in caught.criteria.items() if not ok]
    assert caught.plan.landing_foot == "right" and caught.plan.landing_time < 3.4
    assert caught.plan.landing_position[1] == pytest.approx(0.095 - MAX_STEP_WIDTH)
    assert caught.plan.summary()["steps"][-1]["kind"] == "capture landing"
    fell = run_online(estop_time=2.95, perturbations=push,
                      controller=ControllerOptions(planner=StopPlannerConfig(capture_landing=False)))
    assert not fell.criteria["no_fall"]


@pytest.mark.slow
def test_the_hip_strategy_stops_a_forward_push_in_double_support_in_one_recovery_step():
    """30 N s forward at 3.55 s (double support, 0.52 m/s): the trunk bows into the push
    (:mod:`drake_estop.physics.hip_strategy`), one recovery step catches the robot and the stop meets every
    criterion; without the bow (the default) it takes two recovery steps and the rear sole slips 12.6 mm."""
    pattern = NominalPattern()
    pushes = Perturbations(pushes=(Push(3.55, 300.0, 0.0, 0.1),))
    bowed = run_online(estop_time=3.55, pattern=pattern, perturbations=pushes,
                       controller=ControllerOptions(hip_strategy=HipStrategyConfig()))
    assert bowed.success, [name for name, ok in bowed.criteria.items() if not ok]
    assert bowed.plan.summary()["recovery_steps"] == 1
    bow = bowed.online["hip_strategy_bow_max"]
    assert 0.1 < bow <= 0.12 + 1e-9  # the bow, within its amplitude
    upright = run_online(estop_time=3.55, pattern=pattern, perturbations=pushes)  # the default: no bow
    assert upright.plan.summary()["recovery_steps"] == 2
    assert not upright.criteria["no_slip"] and max(upright.slip.values()) > 0.012
    assert upright.online["hip_strategy_bow_max"] == 0.0


@pytest.mark.slow
def test_a_forward_push_no_single_landing_stops_takes_a_second_step():
    """35 N s forward at 2.95 s (0.6 m/s, early in single support): no landing the swing reaches stops the
    robot (the stop condition asks for a step past the reach at every landing time) and the CoP sits on the
    support toe. N-step capture (planning.capture_landing.capture_step): the swing foot lands as soon as it can,
    the old support foot steps past it, and the stop meets every criterion. Without the second step (no
    recovery step) the plan keeps its one landing, 0.57 s after the push, and the robot falls over the toe
    of the landed foot."""
    push = Perturbations(pushes=(Push(2.95, 350.0, 0.0, 0.1),))
    stepped = run_online(estop_time=2.95, perturbations=push)
    assert stepped.success, [name for name, ok in stepped.criteria.items() if not ok]
    summary = stepped.plan.summary()
    assert [step["kind"] for step in summary["steps"]] == ["capture landing", "recovery step"]
    assert summary["steps_after_signal"] == 2
    assert stepped.plan.final_feet["left"][0] > stepped.plan.final_feet["right"][0]  # the old support foot leads
    fell = run_online(estop_time=2.95, perturbations=push,
                      controller=ControllerOptions(planner=StopPlannerConfig(recovery_step=False)))
    assert not fell.criteria["no_fall"]


#: Campaign run 19 (seed 0): 28.6 N s backward and to the left 0.1 s after a signal early in single support,
#: on a robot 4 % light, friction 0.6, one tick of latency, sensor noise.
CAMPAIGN_RUN_19 = ("--estop-time 3.13 --step-length 0.2692 --step-time 0.835 --step-width 0.2004 "
                   "--push 3.226 -189.61 76.07 0.151 --mass-scale 0.9563 --torso-mass-scale 0.9975 "
                   "--torso-com-offset -0.00411 --friction 0.6015 --latency 1 --seed 7733539186331363713 "
                   "--sensor-noise").split()


@pytest.mark.slow
def test_the_halt_stands_on_the_measured_feet_where_a_sole_left_the_plans(tmp_path):
    """Campaign run 19: the landed right sole stands 1.1 cm off the plan's foot. Played on the plan's feet
    (``halt_footholds`` off) the halt's CoP leaves that plan's sole by 5.5 mm (its toe-outer corner) though
    it stays inside the sole where it stands; with the halt re-planned once on the measured feet, from the
    plan's own COG, the stop meets every criterion."""
    import json

    from drake_estop.cli import main

    summary = tmp_path / "summary.json"
    text = "{controller: {planner: {halt_footholds: true}}}"
    assert main(["simulate", "--physics", *CAMPAIGN_RUN_19, "--scenario-text", text, "--summary", str(summary)]) == 0
    result = json.loads(summary.read_text())
    assert result["success"], [name for name, ok in result["criteria"].items() if not ok]
    assert result["physics"]["cop_exit"] is None
    modes = [change["mode"] for change in result["modes"]]
    assert modes.count("halt") == 2  # the halt, re-planned once: a double-support stop and its own halt
