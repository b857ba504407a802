"""N-step capturability (drake_estop.planning.capturability): Koolen's closed forms, the lateral numbers
worked by hand for the default humanoid, symmetry, the boundary, bad input and the unpushed stride."""

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from drake_estop.planning.capturability import (
    MAX_STEPS,
    SteppingLimits,
    capturability,
    largest_push_speed,
    state_capturability,
)
from drake_estop.planning.gait import NominalPattern, Sole
from drake_estop.planning.plan import StopParameters

OMEGA = math.sqrt(9.81 / 0.814)  # the default humanoid's walking COG height
STEP_TIME = 0.3


def koolen_limits(reach: float, half_length: float, step_time: float = STEP_TIME) -> SteppingLimits:
    """One sagittal region [-reach, reach], a sole half_length long each way and wide laterally (so that
    the lateral axis never binds), steps of exactly step_time: Koolen et al.'s 1-D model."""
    return SteppingLimits(sole=Sole(toe=half_length, heel=half_length, inner=1.0, outer=1.0), forward=reach,
                          backward=reach, min_width=-0.5, max_width=0.5, crossover_reach=0.0,
                          min_step_time=step_time, max_step_time=step_time)


def koolen_bound(steps: int, reach: float, half_length: float, step_time: float = STEP_TIME) -> float:
    """Koolen et al. 2012 (Part 1), LIPM with a finite foot: d_N = r + l sum_{i=1..N} b^i, b = exp(-w dt)."""
    b = math.exp(-OMEGA * step_time)
    return half_length + reach * sum(b**i for i in range(1, steps + 1))


@pytest.mark.parametrize("steps, half_length", [(0, 0.1), *((n, r) for n in (1, 2, 3) for r in (0.0, 0.1))])
def test_koolen_closed_form_bound(steps, half_length):
    """Point foot (r = 0) and finite foot; the point foot's 0-step region is the ankle alone."""
    limits, bound = koolen_limits(0.4, half_length), koolen_bound(steps, 0.4, half_length)
    for offset in (1e-6, -1e-6):  # just inside, just outside
        dcm = [bound - offset, 0.0]
        verdict = capturability(dcm, omega=OMEGA, stance_ankle=[0.0, 0.0], stance_side="right", limits=limits,
                                first_step_time=STEP_TIME, max_steps=steps)
        if offset > 0:
            assert verdict.steps == steps  # and no fewer: the bounds grow strictly with N
            assert verdict.margin == pytest.approx(offset, abs=1e-9)
        else:
            assert verdict.steps == -1
            assert verdict.margin == pytest.approx(offset, abs=1e-9)
        assert verdict.margin_speed == pytest.approx(verdict.margin * OMEGA)


def default_limits(**changes) -> SteppingLimits:
    return SteppingLimits.from_parameters(StopParameters(), Sole(), **changes)


def inward(offset: float, *, limits=None, max_steps=MAX_STEPS, first_step_time=STEP_TIME, side="right"):
    """A DCM ``offset`` [m] beyond the ``side`` stance sole's outer edge, 0.1 m ahead of its ankle."""
    sign = -1.0 if side == "right" else 1.0
    return capturability([0.1, sign * (Sole().outer + offset)], omega=OMEGA, stance_ankle=[0.0, 0.0],
                         stance_side=side, limits=limits or default_limits(min_step_time=STEP_TIME),
                         first_step_time=first_step_time, max_steps=max_steps)


def hand_bound(steps: int, crossover: float = 0.10) -> float:
    """The largest DCM offset beyond the stance sole's outer edge that a crossover landing ``crossover`` past
    the stance ankle catches in ``steps`` steps of 0.3 s, the widest step 0.30 m after it (worked by hand:
    D_k = c_k + (D_{k+1} - c_k) b, from the final sole's outer edge)."""
    sole, b = Sole(), math.exp(-OMEGA * STEP_TIME)
    crossed_edge = crossover + sole.inner  # the crossed foot's inner edge faces the push
    final = crossed_edge if steps == 1 else crossover + 0.30 + sole.outer
    if steps == 2:
        final = crossed_edge + (final - crossed_edge) * b
    return sole.outer + (final - sole.outer) * b - sole.outer


@pytest.mark.parametrize("steps", [1, 2])
def test_inward_crossover_bounds_worked_by_hand(steps):
    bound = hand_bound(steps)
    assert bound == pytest.approx({1: 0.026, 2: 0.067}[steps], abs=1e-3)  # the table of the worked numbers
    inside, outside = inward(bound - 1e-6, max_steps=steps), inward(bound + 1e-6, max_steps=steps)
    assert inside.steps == steps and inside.margin == pytest.approx(1e-6, abs=1e-9)
    assert outside.steps == -1 and outside.margin < 0.0
    assert inside.witness[0].region == "crossover ahead"
    assert inside.witness[0].landing[1] < -Sole().inner  # the left foot lands right of the right sole


def test_without_crossover_the_inward_push_is_the_ankles_alone():
    """Landing beside the stance foot and stepping out with the loaded one catches nothing past the stance
    sole's outer edge at any N; the crossover catches 2 and 4 cm in one and two steps."""
    no_crossover = default_limits(min_step_time=STEP_TIME, crossover_reach=0.0)
    assert inward(-0.001, limits=no_crossover).steps == 0
    for offset in (0.001, 0.02, 0.04):
        assert inward(offset, limits=no_crossover).steps == -1
    assert [inward(offset).steps for offset in (0.02, 0.04)] == [1, 2]


def test_verdict_is_symmetric_and_monotone():
    limits = default_limits(min_step_time=STEP_TIME)
    steps = []
    for offset in np.linspace(-0.03, 0.09, 25):
        right, left = inward(offset, limits=limits), inward(offset, limits=limits, side="left")
        assert (right.steps, right.margin) == (left.steps, pytest.approx(right.margin, abs=1e-12))
        assert [s.landing[1] for s in right.witness] == pytest.approx([-s.landing[1] for s in left.witness])
        steps.append(right.steps if right.capturable else math.inf)
    assert steps == sorted(steps) and steps[0] == 0 and steps[-1] == math.inf  # farther needs more steps


def test_witness_captures_the_state():
    """The witness's landings and CoPs, run forward on the LIPM (eq. 6-9), end with the DCM in the last sole."""
    limits = default_limits(min_step_time=STEP_TIME)
    verdict = inward(0.05, limits=limits)
    assert verdict.steps == 2
    dcm, elapsed = np.array([0.1, -(Sole().outer + 0.05)]), 0.0
    for step in verdict.witness:
        dcm = np.array(step.cop) + (dcm - np.array(step.cop)) * math.exp(OMEGA * (step.time - elapsed))
        elapsed = step.time
    last = verdict.witness[-1]
    box = limits.cop_box(last.side)
    local = dcm - np.array(last.landing)
    assert np.all(local >= box[:, 0] - 1e-9) and np.all(local <= box[:, 1] + 1e-9)
    as_json = json.loads(json.dumps(verdict.as_dict()))  # the summary's form
    assert as_json["steps"] == 2 and [w["region"] for w in as_json["witness"]] == [s.region for s in verdict.witness]
    assert as_json["witness"][-1]["landing"] == pytest.approx(list(last.landing))


def test_swing_reach_bounds_the_first_landing():
    """A swing foot far behind cannot reach a crossover ahead in time: the same inward DCM is caught in one
    step with the foot beside the stance foot, not with it 0.5 m behind."""
    kwargs = dict(omega=OMEGA, stance_ankle=[0.0, 0.0], stance_side="right", first_step_time=STEP_TIME,
                  limits=default_limits(min_step_time=STEP_TIME))
    dcm = [0.1, -(Sole().outer + 0.02)]
    assert capturability(dcm, swing_foot=[0.0, 0.19], **kwargs).steps == 1
    assert capturability(dcm, swing_foot=[-0.5, 0.19], max_steps=1, **kwargs).steps == -1


def test_double_support_uses_the_hull_of_both_soles():
    kwargs = dict(omega=OMEGA, stance_ankle=[0.0, -0.095], stance_side="right", other_ankle=[0.3, 0.095],
                  first_step_time=STEP_TIME, limits=default_limits())
    between = capturability([0.15, 0.0], **kwargs)  # between the feet: outside either sole, inside the hull
    assert between.steps == 0 and between.margin > 0.0
    single = capturability([0.15, 0.0], **{**kwargs, "other_ankle": None})
    assert single.steps >= 1


@pytest.mark.parametrize("name, value", [("dcm", [float("nan"), 0.0]), ("stance_side", "middle"),
                                         ("omega", 0.0), ("first_step_time", float("inf")), ("max_steps", 4)])
def test_bad_input_names_the_parameter(name, value):
    kwargs = dict(dcm=[0.0, 0.0], omega=OMEGA, stance_ankle=[0.0, 0.0], stance_side="left",
                  limits=default_limits(), first_step_time=STEP_TIME)
    kwargs[name] = value
    with pytest.raises(ValueError, match=name):
        capturability(**kwargs)


@pytest.mark.parametrize("name, value", [("forward", -0.1), ("min_width", 0.5), ("min_step_time", 0.0),
                                         ("cop_margin", 0.2), ("swing_speed", float("nan"))])
def test_bad_limits_name_the_field(name, value):
    with pytest.raises(ValueError, match=name):
        replace(default_limits(), **{name: value})


def test_every_tick_of_the_unpushed_stride_is_capturable():
    pattern, params = NominalPattern(), StopParameters()
    limits = SteppingLimits.from_parameters(params, pattern.params.sole)
    start, end = pattern.stride()
    ticks = np.arange(round(start / params.servo_period), round(end / params.servo_period)) * params.servo_period
    verdicts = [state_capturability(pattern.state(t), omega=pattern.w, limits=limits, params=params) for t in ticks]
    assert len(verdicts) == 160
    assert all(v.capturable for v in verdicts)
    assert min(v.margin for v in verdicts) > 0.0
    assert {v.steps for v in verdicts} == {0, 1}  # in the sole or one step from it


def test_largest_push_speed_inward_is_the_crossovers():
    """Early in single support (3.0 s, the left foot standing) a push towards the stance foot is caught up to
    about 0.56 m/s with a crossover and 0.33 m/s without (the worked numbers, for 0.3 s steps)."""
    pattern, params = NominalPattern(), StopParameters()
    limits = SteppingLimits.from_parameters(params, pattern.params.sole)
    state = pattern.state(3.0)
    assert state.support_foot == "left"
    kwargs = dict(omega=pattern.w, params=params)
    with_crossover = largest_push_speed(state, [0.0, 1.0], limits=limits, **kwargs)
    without = largest_push_speed(state, [0.0, 1.0], limits=replace(limits, crossover_reach=0.0), **kwargs)
    assert with_crossover == pytest.approx(0.56, abs=0.06)
    assert without == pytest.approx(0.33, abs=0.05)
    assert largest_push_speed(state, [0.0, -1.0], limits=limits, **kwargs) > with_crossover  # outward: wider


def test_double_support_depth_is_qhull_s():
    """The double-support depth (the DCM's signed distance to the hull of both soles' CoP boxes, made without
    qhull every tick) equals scipy's ConvexHull to rounding, inside and out, at any heading."""
    from scipy.spatial import ConvexHull

    from drake_estop.planning.capturability import _hull_depth

    def qhull_depth(point, corners):
        hull = ConvexHull(corners)
        distances = hull.equations[:, :2] @ point + hull.equations[:, 2]
        if np.all(distances <= 0.0):
            return float(-np.max(distances))
        vertices = corners[hull.vertices]
        edges = np.roll(vertices, -1, axis=0) - vertices
        s = np.clip(np.einsum("ij,ij->i", point - vertices, edges) / np.einsum("ij,ij->i", edges, edges), 0, 1)
        return -float(np.min(np.linalg.norm(vertices + s[:, None] * edges - point, axis=1)))

    rng = np.random.default_rng(7)
    local = np.array([[x, y] for x in (-0.1, 0.13) for y in (-0.05, 0.06)])
    inside = outside = 0
    for _ in range(2000):
        heading = rng.uniform(-math.pi, math.pi)
        rotation = np.array([[math.cos(heading), -math.sin(heading)], [math.sin(heading), math.cos(heading)]])
        first = rng.uniform(-0.3, 0.3, 2)
        corners = np.concatenate([first + local @ rotation.T, first + rng.uniform(-0.3, 0.3, 2) + local @ rotation.T])
        point = rng.uniform(-0.6, 0.6, 2)
        expected = qhull_depth(point, corners)
        assert _hull_depth(point, corners) == pytest.approx(expected, abs=1e-12)
        inside, outside = inside + (expected > 0), outside + (expected < 0)
    assert inside > 50 and outside > 50


def test_a_verdict_is_shared_not_copied():
    """A verdict is immutable: Drake's clone of the monitor's state (a deep copy) shares it."""
    import copy

    verdict = capturability(np.array([0.3, 0.0]), omega=OMEGA, stance_ankle=[0.0, 0.1], stance_side="left",
                            limits=default_limits(), first_step_time=0.3)
    assert copy.deepcopy(verdict) is verdict
