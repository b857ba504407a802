"""The paper's two simulated scenarios (Section V) end to end through the diagram.

One simulation per scenario (module-scoped), with a Meshcat recording written
to an HTML replay.  Meshcat is created by ``make_meshcat``, which sets
``DRAKE_ALLOW_NETWORK=meshcat`` only while the server starts: set for the
whole process it makes Drake 1.51's Parser refuse the local URDF.
"""

import math
import warnings

import numpy as np
import pytest
from html_checks import ROBOT_LINKS, external_fetches, missing_from_replay

from drake_estop.model import ALL_JOINTS
from drake_estop.planning.gait import GaitParameters
from drake_estop.planning.planner import StopParameters, plan_stop
from drake_estop.systems.diagram import IK_COM_BOUND, IK_FOOT_BOUND, IK_FOOT_ROT_BOUND, simulate_diagram
from drake_estop.systems.visualization import html_mentions, make_meshcat


def _simulate(tmp_path_factory, signal, stop_params):
    html = tmp_path_factory.mktemp("replay") / f"stop_{signal}.html"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = simulate_diagram(GaitParameters(step_length=0.3, step_time=0.8), stop_params,
                                  signal, html=html, after_halt=1.0)
    result.caught = [w for w in caught if issubclass(w.category, RuntimeWarning)
                     and "IK missed" in str(w.message)]
    return result


@pytest.fixture(scope="module")
def single(tmp_path_factory):
    """V.A: signal at 3.4 s (late single support), a_ss=5, b_ss=1000, crouch."""
    return _simulate(tmp_path_factory, 3.4, StopParameters(a_ss=5.0, b_ss=1000.0, crouch=True))


@pytest.fixture(scope="module")
def double(tmp_path_factory):
    """V.B: signal at 3.5 s (double support), a_ds=50, b_ds=1000."""
    return _simulate(tmp_path_factory, 3.5, StopParameters(a_ds=50.0, b_ds=1000.0))


@pytest.fixture(params=["single", "double"])
def result(request):
    return request.getfixturevalue(request.param)


def _touchdowns_after(result, signal):
    """Number of times a sole comes down onto the floor (z = 0) after ``signal``."""
    count = 0
    for side in ("left", "right"):
        down = result.feet[side][:, 2] <= 1e-9
        landing = np.nonzero(down[1:] & ~down[:-1])[0] + 1
        count += int(np.sum(result.times[landing] >= signal))
    return count


def test_single_support_stop_takes_one_step(single):
    plan = single.plan
    assert plan.case == "one-step" and plan.support == "single"
    assert plan.landing_foot == "right"
    assert _touchdowns_after(single, 3.4) == 1  # the swing foot lands once, then stands
    k = np.searchsorted(single.times, plan.landing_time - 1e-9)
    assert single.feet["right"][k, 2] == pytest.approx(0.0, abs=1e-12)
    assert single.feet["right"][-1, 0] == pytest.approx(plan.landing_position[0])


def test_double_support_stop_takes_no_new_step(double):
    plan = double.plan
    assert plan.case == "one-step" and plan.support == "double"
    assert plan.landing_foot is None
    assert _touchdowns_after(double, 3.5) == 0
    for side in ("left", "right"):
        assert np.all(double.feet[side][double.times >= 3.5, 2] <= 1e-9)


def test_cog_at_rest_between_the_feet(result):
    plan = result.plan
    after = result.times >= plan.halt_end
    assert np.abs(result.com_vel[after, :2]).max() < 1e-6
    midpoint = 0.5 * (plan.final_feet["left"] + plan.final_feet["right"])
    np.testing.assert_allclose(result.com[-1, :2], midpoint, atol=1e-6)
    assert result.phases[-1] == "stopped"
    assert result.times[-1] >= plan.halt_end + 1.0 - 0.006


def test_every_joint_logged_and_within_limits(result):
    assert set(result.q) == {f"q_{name}" for name in ALL_JOINTS}
    assert len(result.q) == 30
    assert all(v.shape == result.times.shape for v in result.q.values())
    assert int(result.joint_limit_violations.sum()) == 0


def test_double_support_ik_meets_bounds_every_tick(double):
    assert double.ik_com_err.max() < IK_COM_BOUND
    assert double.ik_foot_err.max() < IK_FOOT_BOUND
    assert double.ik_foot_rot_err.max() < IK_FOOT_ROT_BOUND
    assert double.velocity_limit_violations.sum() == 0
    assert not double.caught


def test_single_support_ik_meets_bounds_every_tick(single):
    # the planner's leg-reach limits keep the landing within the IK's reach
    assert single.ik_com_err.max() < IK_COM_BOUND
    assert single.ik_foot_err.max() < IK_FOOT_BOUND
    assert single.ik_foot_rot_err.max() < IK_FOOT_ROT_BOUND
    # the landing honours the URDF joint-velocity limits at every tick (bent-knee fore reach,
    # bounded swing descent; tests/test_joint_velocity.py): 28 joint-ticks over before
    assert single.velocity_limit_violations.sum() == 0


def test_ik_misses_are_counted_and_reported_not_silent(single):
    over = ((single.ik_com_err > IK_COM_BOUND) | (single.ik_foot_err > IK_FOOT_BOUND)
            | (single.ik_foot_rot_err > IK_FOOT_ROT_BOUND))
    summary = single.error_summary()
    assert summary["ik_ticks_over_bounds"]["com"] == int(np.sum(single.ik_com_err > IK_COM_BOUND))
    if over.any() or single.velocity_limit_violations.any():
        assert single.caught, "IK misses must raise a RuntimeWarning"
    # the independent FK check agrees with what WholeBodyIK reported
    np.testing.assert_allclose(single.ik_com_err, single.ik_reported_com_err, atol=1e-7)
    np.testing.assert_allclose(single.ik_foot_err, single.ik_reported_foot_err, atol=1e-7)
    # misses only around the touchdown of the landing step
    near = np.abs(single.times - single.plan.landing_time) < 0.1
    assert not np.any(over & ~near)


def test_logged_planner_outputs_match_ik_targets(result):
    """The reference the IK was given equals the planner output logged at the tick,
    except at the one tick where the plan is stored (the log shows the pre-update
    nominal value there)."""
    logged = result.logged_reference["com"]
    diff = np.linalg.norm(logged - result.com, axis=1)
    assert np.sum(diff > 1e-12) <= 1
    assert diff.max() < 1e-4


def test_one_step_feasible_logged_at_every_tick(result):
    """Row k of the log column: the planner's answer for a stop signal at tick k (computed in its
    update of tick k, logged at k + 1), equal to plan_stop's case there; from the latch on, the
    latched stop's case."""
    plan = result.plan
    column = result.columns()["one_step_feasible"]
    assert column.shape == result.times.shape and set(np.unique(column)) == {0.0, 1.0}
    before = result.times <= plan.signal_time + 1e-9  # the latch reaches the planner one tick later
    assert np.all(column[~before] == float(plan.case == "one-step"))
    pattern = plan.pattern
    expected = [plan_stop(pattern, t, plan.params).case == "one-step" for t in result.times[before]]
    np.testing.assert_array_equal(column[before], np.array(expected, float))
    assert 0 < sum(expected) < len(expected)  # the walk before the signal has both answers


def test_replay_html_contains_robot_and_overlays(result):
    html = result.html.read_text()
    assert html.lstrip().lower().startswith("<!doctype html") or "<html" in html[:500]
    assert html_mentions(html, ROBOT_LINKS) == set(ROBOT_LINKS)
    assert missing_from_replay(html) == []  # robot, traces, phase label, animation
    assert external_fetches(html) == []  # the replay opens offline


def test_html_checks_fail_on_an_empty_page():
    """The checks above bite: an empty Meshcat page (2.2 MB, with "ws://" and "embedded")
    lacks every one of them, and a page loading a script from a CDN is caught."""
    html = make_meshcat().StaticHtml()
    assert len(html) > 1_000_000 and "ws://" in html and "embedded" in html
    assert set(missing_from_replay(html)) >= set(ROBOT_LINKS) | {"estop/phase/stopped", "estop/plan/zmp"}
    assert external_fetches(html) == []
    assert external_fetches('<script src="https://cdn.example.org/three.js"></script>')
    assert external_fetches("import * as THREE from 'https://unpkg.com/three';")


def test_plan_computed_inside_the_diagram(result):
    """The plan is made by the planner system during the run, on the walking tick of the signal (the
    planner plans ahead of the latch), and the latch takes it: both times are measured there. How
    fast, and the real-time factor, are benchmarks (benchmarks/bench_diagram.py), not tests: this
    machine's load decides them."""
    assert math.isfinite(result.plan_wall_time) and result.plan_wall_time > 0.0
    assert result.plan.compute_time > 0.0
    assert math.isfinite(result.realtime_factor) and result.realtime_factor > 0.0


def test_meshcat_port_in_use_gives_clear_error():
    first = make_meshcat()
    with pytest.raises(RuntimeError, match=f"port {first.port()}.*already running"):
        make_meshcat(port=first.port())
