"""A late landing re-times the stop (planning.late_landing, decision's RETIME, the planner system's execution):
the re-timed stop's physics (the COG continuous, the ZMP held on the stance sole until the landing, the foot
at its point on the floor, the COG at rest at the end) and when the controller re-times."""

import dataclasses

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from drake_estop.planning.gait import GaitParameters, NominalPattern
from drake_estop.planning.late_landing import LATE_LANDING_DELAY, LATE_LANDING_GRACE, late_landing_stop
from drake_estop.planning.plan import InfeasibleStop
from drake_estop.planning.planner import StopParameters, plan_stop
from drake_estop.planning.zmp_check import SupportPolygon
from drake_estop.systems.decision import ActionKind, Observation, StopPlannerConfig, decide, landing_late
from drake_estop.systems.plan_sequence import PlanHandle, landings_made
from drake_estop.systems.stop_controller import StopPlannerSystem

PARAMS = StopParameters()
DT = PARAMS.servo_period
LATE = StopPlannerConfig(late_landing=True)


@pytest.fixture(scope="module")
def pattern():
    return NominalPattern(GaitParameters())


@pytest.fixture(scope="module")
def plan_3_4(pattern):
    """The paper's 3.4 s stop: the right foot lands at 3.5 s."""
    return plan_stop(pattern, 3.4, PARAMS)


def _state(plan, t):
    pos, vel, _, _ = plan.com([t])
    return pos[0], vel[0]


def _retimed(plan, t):
    return late_landing_stop(plan, t, *_state(plan, t))


def test_the_retimed_stop_lands_later_at_the_same_point_from_the_measured_cog(plan_3_4):
    t = round(plan_3_4.landing_time + LATE_LANDING_GRACE, 9)
    new = _retimed(plan_3_4, t)
    assert new.start_time == pytest.approx(t)
    assert LATE_LANDING_DELAY - 1e-9 <= new.landing_time - t <= LATE_LANDING_DELAY + DT + 1e-9
    assert np.linalg.norm(new.landing_position - plan_3_4.landing_position) < 1.5e-3
    assert new.landing_foot == plan_3_4.landing_foot and new.step_kind == plan_3_4.step_kind
    assert new.late_since == pytest.approx(plan_3_4.landing_time)
    assert new.stop_landing["late_since"] == pytest.approx(plan_3_4.landing_time)
    assert "late_since" not in plan_3_4.stop_landing
    # eq. 10-11: the COG continuous with the measurement it starts from
    pos, vel, _, _ = new.com([t])
    np.testing.assert_allclose(pos[0], _state(plan_3_4, t)[0], atol=1e-9)
    np.testing.assert_allclose(vel[0], _state(plan_3_4, t)[1], atol=1e-9)
    # the COG at rest at the end, the LIPM's ZMP (eq. 4) inside the support throughout
    _, vel_end, _, _ = new.com([new.halt_end])
    np.testing.assert_allclose(vel_end[0], 0.0, atol=1e-6)
    times = np.arange(t, new.halt_end, DT)
    pos, _, acc, zmp = new.com(times)
    np.testing.assert_allclose(zmp, pos - acc / plan_3_4.pattern.w ** 2, atol=1e-6)
    for ti, p in zip(times, zmp):
        assert new.polygon(ti).margin(p)[0] >= -1e-6, ti


def test_until_the_retimed_landing_the_zmp_stays_on_the_stance_sole_and_the_foot_at_its_point(plan_3_4):
    t = round(plan_3_4.landing_time + LATE_LANDING_GRACE, 9)
    new = _retimed(plan_3_4, t)
    stance = "left" if new.landing_foot == "right" else "right"
    sole = plan_3_4.pattern.params.sole
    ankle = new.feet(t)[stance][:2]
    stance_polygon = SupportPolygon(sole.corners(ankle, stance))
    for ti in np.arange(t, new.landing_time - 1e-9, DT):
        zmp = new.com([ti])[3][0]
        assert stance_polygon.margin(zmp)[0] >= PARAMS.zmp_margin - 1e-6, ti
        foot = new.feet(ti)[new.landing_foot]
        assert abs(foot[2]) < 1e-5 and np.linalg.norm(foot[:2] - plan_3_4.landing_position) < 1.5e-3, ti
    assert new.phase(t) == "landing" and new.phase(new.landing_time + DT) != "landing"


def test_retiming_again_keeps_the_first_missed_touchdown(plan_3_4):
    first = _retimed(plan_3_4, round(plan_3_4.landing_time + LATE_LANDING_GRACE, 9))
    again = _retimed(first, first.landing_time)
    assert again.late_since == pytest.approx(plan_3_4.landing_time)
    assert again.landing_time > first.landing_time
    # the summary counts the one landing that was made, not each re-timing of it
    history = (plan_3_4, first, again)
    walk = sum(step["time"] <= again.halt_end for step in plan_3_4.walk_landings)
    assert landings_made(history, again.halt_end) == walk + 1


def test_a_bad_retiming_is_refused(pattern, plan_3_4):
    with pytest.raises(ValueError, match="before the plan's touchdown"):
        _retimed(plan_3_4, plan_3_4.landing_time - DT)
    with pytest.raises(ValueError, match="delay"):
        late_landing_stop(plan_3_4, plan_3_4.landing_time, *_state(plan_3_4, 3.5), delay=0.001)
    with pytest.raises(ValueError, match="finite"):
        late_landing_stop(plan_3_4, plan_3_4.landing_time, [np.nan, 0.0], [0.0, 0.0])
    double = plan_stop(pattern, 3.55, PARAMS)  # signalled in double support: no landing
    assert double.landing_foot is None
    with pytest.raises(ValueError, match="landing"):
        _retimed(double, 3.6)


def test_a_cog_running_away_has_no_retimed_stop(plan_3_4):
    t = plan_3_4.landing_time + 0.04
    pos, vel = _state(plan_3_4, t)
    with pytest.raises(InfeasibleStop):
        late_landing_stop(plan_3_4, t, pos + np.array([0.08, 0.0]), vel + np.array([0.6, 0.0]))


def _observation(plan, t, loaded_ticks):
    feet = np.zeros(6)
    feet[4 + ("left", "right").index(plan.landing_foot)] = loaded_ticks
    feet[4 + ("left", "right").index("left" if plan.landing_foot == "right" else "right")] = 50
    return Observation(time=t, latched=True, signal_time=plan.signal_time, measured=_state(plan, t), feet=feet)


def test_the_decision_retimes_an_unloaded_landing_sole_past_its_grace(plan_3_4):
    landing = plan_3_4.landing_time
    handle = PlanHandle(plan_3_4)
    late = landing + LATE_LANDING_GRACE
    assert decide(_observation(plan_3_4, late, 0), handle, LATE).kind is ActionKind.RETIME
    assert decide(_observation(plan_3_4, late - DT, 0), handle, LATE).kind is not ActionKind.RETIME
    assert decide(_observation(plan_3_4, late, 1), handle, LATE).kind is not ActionKind.RETIME  # it touched down
    assert decide(_observation(plan_3_4, late, 0), handle, StopPlannerConfig()).kind is not ActionKind.RETIME
    beyond = landing + LATE.max_late_landing + DT
    assert not landing_late(_observation(plan_3_4, beyond, 0), plan_3_4, LATE.max_late_landing)
    assert not landing_late(dataclasses.replace(_observation(plan_3_4, late, 0), feet=None), plan_3_4, 0.2)
    # a re-timed landing is re-timed again at its own touchdown, with no grace
    retimed = _retimed(plan_3_4, late)
    assert decide(_observation(retimed, retimed.landing_time, 0), PlanHandle(retimed), LATE).kind is ActionKind.RETIME
    assert "weight" in decide(_observation(plan_3_4, late, 0), handle, LATE).reason


@pytest.mark.parametrize("value", [0.0, -0.1, float("nan")])
def test_a_bad_max_late_landing_is_named(value):
    with pytest.raises(ValueError, match="max_late_landing"):
        StopPlannerConfig(max_late_landing=value)


def _run_planner(pattern, config, loaded_ticks, until):
    """The planner system alone: a signal at 3.4 s, the measured COG on the reference plan's, the landing
    sole loaded ``loaded_ticks`` ticks at every tick. Returns the plan in force after the tick ``until``."""
    planner = StopPlannerSystem(pattern=pattern, params=PARAMS, config=config)
    simulator = Simulator(planner)
    context = simulator.get_mutable_context()
    reference = plan_stop(pattern, 3.4, PARAMS)
    planner.stop_port.FixValue(context, [1.0, 3.4])
    tick = int(round(3.4 / DT))
    context.SetTime(tick * DT)
    simulator.Initialize()
    while tick * DT <= until + 1e-9:
        pos, vel = _state(reference, tick * DT)
        planner.measured_com_port.FixValue(context, [*pos, 0.8])
        planner.measured_com_vel_port.FixValue(context, [*vel, 0.0])
        feet = np.array([*reference.feet(tick * DT)["left"][:2], *reference.feet(tick * DT)["right"][:2], 50, 50],
                        float)
        feet[4 + ("left", "right").index(reference.landing_foot)] = loaded_ticks
        planner.measured_feet_port.FixValue(context, feet)
        simulator.AdvanceTo((tick + 1) * DT)
        tick += 1
    return planner.plan(context), planner.replans(context)


def test_the_planner_system_retimes_a_landing_whose_sole_stays_unloaded(pattern):
    plan, (replans, failures) = _run_planner(pattern, LATE, 0, 3.53)
    assert plan.late_since == pytest.approx(3.5) and plan.landing_time > 3.53
    assert replans >= 1 and failures == 0
    loaded, _ = _run_planner(pattern, LATE, 3, 3.53)
    assert loaded.late_since is None and loaded.landing_time == pytest.approx(3.5)
    off, _ = _run_planner(pattern, StopPlannerConfig(), 0, 3.53)
    assert off.late_since is None and off.landing_time == pytest.approx(3.5)
