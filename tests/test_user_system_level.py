"""A new user's system-level test, written only against the public API (``from drake_estop import ...``).

It is the example the README points to: build a diagram with the emergency stop,
simulate a stop in late single support (the paper's 3.4 s), and check the
physics a user cares about on the per-tick log: the robot stops within one step,
the ZMP of the commanded COG (linear inverted pendulum, eq. 4) stays inside the
support polygon of the feet on the ground, and the COG of the posed robot comes
to rest over the middle of its feet.
"""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from scipy.spatial import ConvexHull

from drake_estop import AddEmergencyStop, GaitParameters, StopParameters, one_step_feasible, plan_stop

GRAVITY = 9.8  # [m/s^2]; the package sets the plant's gravity to this value


@pytest.fixture(scope="module")
def stopped():
    gait, stop = GaitParameters(), StopParameters()
    builder = DiagramBuilder()
    estop = AddEmergencyStop(builder, gait=gait, stop=stop, estop_time=3.4)
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(3.5)
    context = simulator.get_context()
    simulator.AdvanceTo(estop.stop_time(context, after_halt=1.0))
    return estop, context, estop.log(context), estop.summary(context), gait


def _sole_box(foot_xy, side, sole):
    """(x_min, x_max, y_min, y_max) of a sole rectangle [m]."""
    inner, outer = sole.inner, sole.outer
    y_low, y_high = (foot_xy[1] - inner, foot_xy[1] + outer) if side == "left" else \
        (foot_xy[1] - outer, foot_xy[1] + inner)
    return foot_xy[0] - sole.heel, foot_xy[0] + sole.toe, y_low, y_high


def _margin(point, boxes):
    """Signed distance [m] of ``point`` inside the convex hull of the boxes' corners (the support polygon)."""
    corners = np.array([(x, y) for x0, x1, y0, y1 in boxes for x in (x0, x1) for y in (y0, y1)])
    hull = ConvexHull(corners)  # facets: normal . p + offset <= 0 inside, unit normals
    return float(-np.max(hull.equations[:, :2] @ point + hull.equations[:, 2]))


def test_the_robot_stops_within_one_step(stopped):
    _, _, log, summary, _ = stopped
    assert summary["case"] == "one-step" and summary["support"] == "single"
    assert summary["steps_after_signal"] == 1
    assert log.phase[-1] == "stopped"
    assert summary["phase_times"]["halt_end"] - summary["estop_time"] < 2.0  # time to rest [s]


def test_lipm_zmp_stays_inside_the_support_polygon(stopped):
    _, _, log, _, gait = stopped
    dt = log.times[1] - log.times[0]
    acc = np.gradient(log.com_vel[:, :2], dt, axis=0)
    zmp = log.com[:, :2] - (log.com[:, 2:3] / GRAVITY) * acc  # eq. 4 (crouch acceleration neglected)
    signal = np.searchsorted(log.times, 3.4)
    checked = 0
    for k in range(signal, len(log.times) - 1):
        boxes = [_sole_box(foot[k, :2], side, gait.sole)
                 for side, foot in (("left", log.left_foot), ("right", log.right_foot)) if foot[k, 2] <= 1e-6]
        assert boxes, f"no foot on the ground at t = {log.times[k]:.3f} s"
        margin = _margin(zmp[k], boxes)
        assert margin > 0.0, f"ZMP {zmp[k]} {-margin:.4f} m outside the support polygon at {log.times[k]:.3f} s"
        checked += 1
    assert checked > 100


def test_the_posed_robot_comes_to_rest_over_its_feet(stopped):
    estop, _, log, summary, _ = stopped
    plant = estop.plant
    plant_context = plant.CreateDefaultContext()
    com = []
    for q in log.q[-40:]:  # the last 0.2 s of IK solutions
        plant.SetPositions(plant_context, q)
        com.append(plant.CalcCenterOfMassPositionInWorld(plant_context))
    com = np.array(com)
    speed = np.linalg.norm(np.diff(com[:, :2], axis=0), axis=1) / (log.times[1] - log.times[0])
    assert speed.max() < 1e-3  # [m/s]
    feet = summary["final_feet"]
    midpoint = 0.5 * (np.array(feet["left"][:2]) + np.array(feet["right"][:2]))
    assert np.linalg.norm(com[-1, :2] - midpoint) < 5e-3  # [m]
    assert max(log.ik_foot_error) < 1e-3 and max(log.ik_com_error) < 1e-3  # [m]


def test_the_log_says_at_every_tick_whether_a_stop_then_would_take_one_step(stopped):
    """Before the signal, row k of ``one_step_feasible`` is whether a stop signal at that tick would
    stop within one step (what ``plan_stop`` then does); from the latch on, the latched stop's case."""
    estop, _, log, summary, _ = stopped
    column = log.one_step_feasible
    assert column.shape == log.times.shape and np.all(np.isin(column[:-1], (0.0, 1.0)))
    before = log.times <= summary["estop_time"] + 1e-9
    expected = [plan_stop(estop.pattern, t).case == "one-step" for t in log.times[before]]
    np.testing.assert_array_equal(column[before], np.array(expected, float))
    assert 0 < sum(expected) < len(expected)
    assert np.all(column[~before][:-1] == 1.0)  # the 3.4 s stop is one-step
    assert all(one_step_feasible(estop.pattern, t) == e for t, e in zip(log.times[before][-200:], expected[-200:]))
