"""The default humanoid's J_ds ZMP weight in physics (eq. 30): ``a_ds`` 1000 /m^2, and the paper's 50 as a retry.

With the paper's 50 a double-support stop takes the shortest transition and a ZMP near the fore toe; the
COG stops far behind that ZMP, and the halt (eq. 27-28) swings the ZMP back onto the rear foot while the
COG runs backwards. On the physics robot that rocks it from the fore toe to the rear heel. The heavier
weight stops the COG nearer its ZMP; where its longer stop's halt finds no room, the planner solves again
with the paper's weight rather than fall back to the next step (III.C).
"""

from dataclasses import replace

import numpy as np
import pytest
from checks import plan_lipm_error

from drake_estop.physics.online import controller_stop_parameters
from drake_estop.planning.landing import PAPER_A_DS, retry_limits
from drake_estop.planning.planner import StopParameters, plan_stop
from drake_estop.robots.parameters import default_robot


def _halt_reversal(plan):
    """(ZMP ahead of the COG at the slowdown end [m], the COG's largest backward speed in the halt [m/s])."""
    times = np.arange(plan.slowdown_end, plan.halt_end, plan.params.servo_period)
    pos, vel, _, zmp = plan.com(times)
    return zmp[0, 0] - pos[0, 0], -vel[:, 0].min()


def _slowed_state(pattern, t, share):
    """The walk's COG at ``t`` moving at ``share`` of its speed: what a double-support re-plan measures after
    a landing that took speed out of the robot."""
    state = pattern.state(t)
    return np.array(state.com), np.array(state.com_vel) * share


def test_the_default_humanoid_gives_its_own_weight_and_other_robots_keep_the_given_one():
    robot = default_robot()
    assert StopParameters().a_ds == PAPER_A_DS == 50.0
    assert robot.stop_zmp_weight == controller_stop_parameters().a_ds == 1000.0
    assert controller_stop_parameters(StopParameters(a_ds=5000.0)).a_ds == 1000.0  # the robot's own replaces it
    other = replace(robot, stop_zmp_weight=None)
    assert controller_stop_parameters(robot=other).a_ds == PAPER_A_DS
    assert controller_stop_parameters(StopParameters(a_ds=5000.0), robot=other).a_ds == 5000.0


@pytest.mark.parametrize("signal", [3.5, 3.6])
def test_a_slowed_double_support_stop_ends_its_slowdown_nearer_its_zmp(pattern, signal):
    params = controller_stop_parameters()
    measured = _slowed_state(pattern, signal, 0.5)
    paper = plan_stop(pattern, signal, replace(params, a_ds=PAPER_A_DS), measured=measured)
    heavier = plan_stop(pattern, signal, params, measured=measured)
    assert paper.support == heavier.support == "double"
    assert paper.case == heavier.case == "one-step"
    (paper_gap, paper_back), (gap, back) = _halt_reversal(paper), _halt_reversal(heavier)
    # 3.5 s: ZMP 26.3 cm ahead of the stopped COG with the paper's weight, 14.2 with the controller's; the
    # halt's backward COG speed 0.137 against 0.074 m/s
    assert gap < paper_gap - 0.05
    assert back < 0.8 * paper_back
    assert back < 0.1
    # still the paper's stop: LIPM-consistent, at rest between the feet at the halt's end
    assert plan_lipm_error(heavier, after_halt=0.5, lead=0.0) < 1e-3
    _, vel, _, _ = heavier.com([heavier.halt_end])
    assert np.linalg.norm(vel[0]) < 1e-6


def test_where_the_heavier_weight_finds_no_halt_the_paper_weight_stops_in_one_step(pattern):
    """At 3.55 s the heavier weight's stop leaves its halt 21.6 mm from the polygon's edge (3 cm wanted):
    the retry with the paper's weight keeps the stop within one step, as every tick of the stride is."""
    params = controller_stop_parameters()
    plan = plan_stop(pattern, 3.55, params)
    assert plan.support == "double" and plan.case == "one-step"
    assert plan.params.a_ds == params.a_ds  # the plan keeps its own limits
    no_retry = replace(params, a_ds=params.a_ds)
    state = pattern.state(3.55)
    assert [limits.a_ds for limits in retry_limits(pattern, state, no_retry)] == [PAPER_A_DS]
    assert list(retry_limits(pattern, state, replace(params, a_ds=PAPER_A_DS))) == []


def test_the_controller_stops_every_tick_of_the_stride_in_one_step(pattern, stride_times):
    params = controller_stop_parameters()
    cases = [plan_stop(pattern, float(t), params).case for t in stride_times]
    assert len(cases) == 160
    assert cases.count("one-step") == 160


#: Two runs of the default campaign (``campaign --runs 500 --seed 0``) that failed only on the CoP with the
#: paper's weight: run 203, a 4.2 N s push in double support after a 3.6 s signal (CoP 0.3 mm out), and run
#: 464, a 6.2 N s push just after the landing of a 3.395 s signal's step, then re-planned (16.9 mm out).
CAMPAIGN_RUNS = {
    203: dict(estop_time=3.6, gait=dict(step_length=0.2463, step_time=0.835, step_width=0.2095),
              push=(3.761, -14.03, -22.88, 0.157),
              perturbations=dict(mass_scale=0.938, torso_mass_scale=1.0137, friction=0.669, latency_ticks=1,
                                 sensor_noise=True, seed=6842258285694196180)),
    464: dict(estop_time=3.395, gait=dict(step_length=0.2148, step_time=0.8, step_width=0.1849),
              push=(3.589, 21.39, -23.05, 0.198),
              perturbations=dict(mass_scale=0.9945, torso_mass_scale=0.9464, torso_com_offset=0.00807,
                                 friction=0.8332, seed=7204732744327436297)),
}


def _campaign_run(run, a_ds):
    from drake_estop.physics.online import robot_stop_parameters, run_online
    from drake_estop.physics.perturbations import Perturbations, Push
    from drake_estop.planning.gait import GaitParameters, NominalPattern

    case = CAMPAIGN_RUNS[run]
    return run_online(estop_time=case["estop_time"], pattern=NominalPattern(GaitParameters(**case["gait"])),
                      stop_params=replace(robot_stop_parameters(), a_ds=a_ds),
                      perturbations=Perturbations(pushes=(Push(*case["push"]),), **case["perturbations"]))


@pytest.mark.slow
def test_a_small_push_in_double_support_stops_without_rocking_onto_the_rear_heel():
    """Run 203: with the default humanoid's weight every criterion holds (CoP 3.5 mm inside); with the paper's
    the ZMP goes to the fore toe and back onto the rear foot, and the CoP leaves the support."""
    heavier, paper = _campaign_run(203, 1000.0), _campaign_run(203, PAPER_A_DS)
    assert heavier.success, [name for name, ok in heavier.criteria.items() if not ok]
    assert not paper.criteria["cop_in_support"]
    assert heavier.numbers()["cop_edge_time_s"] < paper.numbers()["cop_edge_time_s"]


@pytest.mark.slow
def test_a_double_support_re_plan_after_a_push_rocks_the_robot_less():
    """Run 464: the re-plan after the landing. With the paper's weight the robot rocks between the fore toe and
    the rear heel for 1.2 s (torso tilt 82 mrad, CoP 16.9 mm out); with the default humanoid's 0.24 s, 18 mrad
    and 1.9 mm (still out: this run still fails)."""
    heavier, paper = _campaign_run(464, 1000.0), _campaign_run(464, PAPER_A_DS)
    assert paper.numbers()["cop_edge_time_s"] > 0.8 and paper.numbers()["torso_tilt_max_rad"] > 0.06
    assert heavier.numbers()["cop_edge_time_s"] < 0.5 and heavier.numbers()["torso_tilt_max_rad"] < 0.04
    assert heavier.numbers()["cop_margin_plan_min_m"] > paper.numbers()["cop_margin_plan_min_m"] + 0.01
    assert heavier.criteria["no_fall"] and heavier.criteria["rests_at_midpoint"]
