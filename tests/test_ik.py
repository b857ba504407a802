"""Tests of drake_estop.systems.ik (pure solver and LeafSystem)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.analysis import Simulator

from drake_estop.model import (
    ALL_JOINTS,
    UPPER_BODY_JOINTS,
    joint_position_indices,
    load_humanoid,
    nominal_standing_configuration,
)
from drake_estop.systems.ik import WholeBodyIK, WholeBodyIkSolver, pose_vector, rotation_exp, rotation_log

PERIOD = 0.005


@pytest.fixture(scope="module")
def plant():
    plant = MultibodyPlant(0.0)
    load_humanoid(plant)
    plant.Finalize()
    return plant


@pytest.fixture(scope="module")
def solver(plant):
    return WholeBodyIkSolver(plant)


@pytest.fixture(scope="module")
def q_nominal(plant):
    return nominal_standing_configuration(plant)


def walking_targets(steps, *, speed=0.25, cycle=1.6, turn=0.1):
    """Walking-like COG / foot targets: sway, forward drift, swing, turning."""
    for k in range(steps):
        t = k * PERIOD
        phase = (t % cycle) / cycle
        x = speed * t
        com = np.array([x, 0.06 * math.sin(2 * math.pi * t / cycle),
                        0.814 + 0.01 * math.sin(4 * math.pi * t / cycle)])
        lift = max(0.0, 0.06 * math.sin(2 * math.pi * phase))
        yaw = turn * math.sin(2 * math.pi * t / cycle)
        left = RigidTransform(RollPitchYaw(0.0, 0.1 * lift, yaw),
                              [x + 0.08 * math.sin(2 * math.pi * phase),
                               0.095, lift])
        right = RigidTransform(RotationMatrix.MakeZRotation(-0.5 * yaw),
                               [x - 0.03, -0.095, 0.0])
        upper = {"l_shoulder_pitch": 0.3 * math.sin(2 * math.pi * t / cycle),
                 "r_shoulder_pitch": -0.3 * math.sin(2 * math.pi * t / cycle),
                 "l_elbow": -0.4, "r_elbow": -0.4, "chest_yaw": 0.5 * yaw}
        yield com, left, right, upper


def _limits_ok(plant, q):
    idx = joint_position_indices(plant, ALL_JOINTS)
    return (np.all(q[idx] >= plant.GetPositionLowerLimits()[idx])
            and np.all(q[idx] <= plant.GetPositionUpperLimits()[idx]))


def _check_solution(plant, result, com, left, right):
    """Independently verify the reported errors with the plant."""
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, result.q)
    assert np.linalg.norm(plant.CalcCenterOfMassPositionInWorld(context) - com) < 1e-3
    for name, target in (("l_sole", left), ("r_sole", right)):
        pose = plant.GetFrameByName(name).CalcPoseInWorld(context)
        assert np.linalg.norm(pose.translation() - target.translation()) < 1e-3
        rel = target.rotation().inverse() @ pose.rotation()
        assert rel.ToAngleAxis().angle() < 1e-2


def test_walking_sequence_meets_error_bounds(plant, solver, q_nominal):
    q = q_nominal
    for k, (com, left, right, upper) in enumerate(walking_targets(300)):
        result = solver.solve(q, com, left, right, None, upper)
        assert result.success, (k, result)
        assert result.com_error < 1e-3
        assert result.foot_position_error < 1e-3
        assert result.foot_rotation_error < 1e-2
        assert result.joint_limit_ok and _limits_ok(plant, result.q)
        assert result.iterations <= 5
        if k % 50 == 0:
            _check_solution(plant, result, com, left, right)
        for name, angle in upper.items():
            assert result.q[plant.GetJointByName(name).position_start()] == angle
        q = result.q


def test_quaternion_stays_normalised(plant, solver, q_nominal):
    left = RigidTransform(RotationMatrix.MakeZRotation(0.4), [0.0, 0.07, 0.0])
    right = RigidTransform(RotationMatrix.MakeZRotation(0.4), [0.04, -0.1, 0.0])
    result = solver.solve(q_nominal, [0.0, -0.01, 0.80], left, right)
    assert result.success
    assert np.linalg.norm(result.q[:4]) == pytest.approx(1.0, abs=1e-12)
    base = RotationMatrix(Quaternion(result.q[:4]))
    assert RollPitchYaw(base).yaw_angle() == pytest.approx(0.4, abs=1e-2)


def test_accepts_pose_vectors_and_base_rotation(plant, solver, q_nominal):
    left = pose_vector(RigidTransform([0.0, 0.06, 0.0]))
    right = pose_vector(RigidTransform([0.0, -0.06, 0.0]))
    rot = RotationMatrix(RollPitchYaw(0.0, 0.05, 0.0))
    result = solver.solve(q_nominal, [0.0, 0.0, 0.80], left, right, rot)
    assert result.success and result.orientation_error < 1e-2


@pytest.mark.parametrize("com_z", [1.4, 0.3])
def test_unreachable_com_reports_failure(plant, solver, q_nominal, com_z):
    left = RigidTransform([0.0, 0.06, 0.0])
    right = RigidTransform([0.0, -0.06, 0.0])
    result = solver.solve(q_nominal, [0.0, 0.0, com_z], left, right)
    assert not result.success
    assert np.all(np.isfinite(result.q))
    assert result.com_error + result.foot_position_error > 0.01
    assert result.joint_limit_ok and _limits_ok(plant, result.q)


def test_unreachable_foot_reports_failure(plant, solver, q_nominal):
    left = RigidTransform([0.0, 0.9, 0.0])
    right = RigidTransform([0.0, -0.06, 0.0])
    result = solver.solve(q_nominal, [0.0, 0.0, 0.814], left, right)
    assert not result.success and np.all(np.isfinite(result.q))
    assert result.joint_limit_ok


def test_upper_body_targets_clipped_to_limits(plant, solver, q_nominal):
    result = solver.solve(q_nominal, [0.0, 0.0, 0.814],
                          RigidTransform([0.0, 0.06, 0.0]),
                          RigidTransform([0.0, -0.06, 0.0]), None,
                          {"r_elbow": 1.0, "head_yaw": -5.0})
    assert result.success
    q = result.q
    assert q[plant.GetJointByName("r_elbow").position_start()] == pytest.approx(
        plant.GetJointByName("r_elbow").position_upper_limits()[0])
    assert q[plant.GetJointByName("head_yaw").position_start()] == pytest.approx(
        plant.GetJointByName("head_yaw").position_lower_limits()[0])


def test_bad_inputs_raise_value_error(solver, q_nominal):
    feet = (RigidTransform([0.0, 0.06, 0.0]), RigidTransform([0.0, -0.06, 0.0]))
    with pytest.raises(ValueError, match="non-finite"):
        solver.solve(q_nominal, [np.nan, 0.0, 0.8], *feet)
    with pytest.raises(ValueError, match="unknown upper-body joint"):
        solver.solve(q_nominal, [0.0, 0.0, 0.8], *feet, None, {"l_knee": 0.1})
    with pytest.raises(ValueError, match="q_guess"):
        solver.solve(q_nominal[:10], [0.0, 0.0, 0.8], *feet)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-3.1, 3.1), min_size=3, max_size=3))
def test_rotation_log_exp_roundtrip(w):
    w = np.array(w)
    if np.linalg.norm(w) > 3.1:
        w *= 3.1 / np.linalg.norm(w)
    np.testing.assert_allclose(rotation_log(rotation_exp(w)), w, atol=1e-7)


# ---------------------------------------------------------------- System


def _fix_inputs(system, context, com, left, right, upper=None):
    system.com_port.FixValue(context, com)
    system.left_foot_port.FixValue(context, pose_vector(left))
    system.right_foot_port.FixValue(context, pose_vector(right))
    system.upper_body_port.FixValue(
        context, np.zeros(len(UPPER_BODY_JOINTS)) if upper is None else upper)


@pytest.fixture(scope="module")
def ik_system(plant, q_nominal):
    return WholeBodyIK(plant=plant, servo_period=PERIOD, initial_q=q_nominal)


def test_system_ports(ik_system, plant):
    names = [ik_system.get_input_port(i).get_name()
             for i in range(ik_system.num_input_ports())]
    assert names == ["com", "left_foot", "right_foot", "upper_body"]
    outputs = [ik_system.get_output_port(i).get_name()
               for i in range(ik_system.num_output_ports())]
    assert outputs == ["q", "ik_com_error", "ik_foot_error",
                       "velocity_limit_violations"]
    assert ik_system.q_port.size() == plant.num_positions()
    assert ik_system.upper_body_port.size() == 18
    assert not ik_system.HasDirectFeedthrough(0, 0)


def test_system_discrete_update(ik_system, plant, q_nominal):
    context = ik_system.CreateDefaultContext()
    np.testing.assert_array_equal(ik_system.q_port.Eval(context), q_nominal)
    com = np.array([0.001, 0.0, 0.813])
    left = RigidTransform([0.0, 0.06, 0.0])
    right = RigidTransform([0.0, -0.06, 0.0])
    _fix_inputs(ik_system, context, com, left, right)
    update = ik_system.EvalUniquePeriodicDiscreteUpdate(context)
    q_new = update.get_vector(0).value()
    assert not np.allclose(q_new, q_nominal)
    context.SetDiscreteState(0, q_new)
    context.SetDiscreteState(1, update.get_vector(1).value())
    assert ik_system.com_error_port.Eval(context)[0] < 1e-3
    assert ik_system.foot_error_port.Eval(context)[0] < 1e-3
    assert ik_system.violations_port.Eval(context)[0] == 0
    plant_context = plant.CreateDefaultContext()
    plant.SetPositions(plant_context, ik_system.q_port.Eval(context))
    np.testing.assert_allclose(
        plant.CalcCenterOfMassPositionInWorld(plant_context), com, atol=1e-3)


def test_system_simulation_tracks_walking(ik_system, plant, solver, q_nominal):
    context = ik_system.CreateDefaultContext()
    targets = list(walking_targets(60))
    com, left, right, upper = targets[0]
    start = solver.solve(q_nominal, com, left, right, None, upper)
    context.SetDiscreteState(0, start.q)
    simulator = Simulator(ik_system, context)
    upper_index = {n: i for i, n in enumerate(UPPER_BODY_JOINTS)}
    for k, (com, left, right, upper) in enumerate(targets):
        vector = np.zeros(len(UPPER_BODY_JOINTS))
        for name, angle in upper.items():
            vector[upper_index[name]] = angle
        _fix_inputs(ik_system, context, com, left, right, vector)
        simulator.AdvanceTo((k + 1) * PERIOD)
        assert ik_system.com_error_port.Eval(context)[0] < 1e-3
        assert ik_system.foot_error_port.Eval(context)[0] < 1e-3
        assert ik_system.violations_port.Eval(context)[0] == 0
    assert _limits_ok(plant, ik_system.q_port.Eval(context))


def test_system_flags_velocity_violation(ik_system):
    context = ik_system.CreateDefaultContext()
    _fix_inputs(ik_system, context, [0.0, 0.0, 0.70],
                RigidTransform([0.0, 0.06, 0.0]), RigidTransform([0.0, -0.06, 0.0]))
    Simulator(ik_system, context).AdvanceTo(PERIOD / 2)
    assert ik_system.violations_port.Eval(context)[0] >= 2  # both knees


def test_system_state_lives_in_context(ik_system, q_nominal):
    a, b = ik_system.CreateDefaultContext(), ik_system.CreateDefaultContext()
    feet = (RigidTransform([0.0, 0.06, 0.0]), RigidTransform([0.0, -0.06, 0.0]))
    _fix_inputs(ik_system, a, [0.0, 0.0, 0.78], *feet)
    _fix_inputs(ik_system, b, [0.0, 0.0, 0.80], *feet)
    Simulator(ik_system, a).AdvanceTo(0.02)
    np.testing.assert_array_equal(ik_system.q_port.Eval(b), q_nominal)
    Simulator(ik_system, b).AdvanceTo(0.02)
    assert not np.allclose(ik_system.q_port.Eval(a), ik_system.q_port.Eval(b))


def test_system_non_finite_input_holds_q(ik_system, q_nominal):
    context = ik_system.CreateDefaultContext()
    _fix_inputs(ik_system, context, [np.nan, 0.0, 0.8],
                RigidTransform([0.0, 0.06, 0.0]), RigidTransform([0.0, -0.06, 0.0]))
    Simulator(ik_system, context).AdvanceTo(0.01)
    np.testing.assert_array_equal(ik_system.q_port.Eval(context), q_nominal)
    assert np.isinf(ik_system.com_error_port.Eval(context)[0])
    assert np.isinf(ik_system.foot_error_port.Eval(context)[0])


def _knees(plant, q):
    return np.array([q[plant.GetJointByName(name).position_start()] for name in ("l_knee", "r_knee")])


def test_task_jacobian_is_taken_where_the_errors_were_even_if_the_context_moved(plant, q_nominal):
    """The solver computes a step's Jacobian only when it steps (the last iterate needs none), at the
    errors' q: also when its scratch context was moved in between; and only once per iterate."""
    solver = WholeBodyIkSolver(plant)
    com, left, right, _ = next(walking_targets(1))
    targets = solver._targets(com, left, right, None)
    bent = q_nominal.copy()
    bent[joint_position_indices(plant, ["l_knee"])] += 0.3
    context = plant.CreateDefaultContext()
    err = solver._errors(context, q_nominal, targets)
    assert err.jac is None  # errors alone
    plant.SetPositions(context, bent)  # someone moved the context
    jacobian = solver._jacobian(context, err)
    fresh = solver._errors(plant.CreateDefaultContext(), q_nominal, targets)
    np.testing.assert_array_equal(jacobian, solver._jacobian(plant.CreateDefaultContext(), fresh))
    moved = solver._errors(plant.CreateDefaultContext(), bent, targets)
    assert not np.allclose(jacobian, solver._jacobian(plant.CreateDefaultContext(), moved))  # q matters
    assert solver._jacobian(context, err) is jacobian  # computed once


def test_min_knee_bend_lowers_the_cog_instead_of_straightening_a_knee(plant, q_nominal):
    """A COG 0.25 m ahead of the rear ankle at the walking height needs a straight rear knee: the
    default solver straightens it onto its 0 rad limit; with ``min_knee_bend`` both knees stay bent by
    0.15 rad or more and the COG is lowered instead (the remaining error is about 1 mm)."""
    rear, fore = RigidTransform([0.0, 0.095, 0.0]), RigidTransform([0.3, -0.095, 0.0])
    target = np.array([0.25, 0.0, 0.814])
    straight = WholeBodyIkSolver(plant).solve(q_nominal, target, rear, fore)
    bent = WholeBodyIkSolver(plant, min_knee_bend=0.15).solve(q_nominal, target, rear, fore)
    assert straight.success and _knees(plant, straight.q).min() < 0.05
    assert np.all(_knees(plant, bent.q) >= 0.15 - 1e-12) and bent.joint_limit_ok
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, bent.q)
    com = plant.CalcCenterOfMassPositionInWorld(context)
    assert np.linalg.norm(com[:2] - target[:2]) < 3e-3
    assert com[2] < target[2] - 5e-4  # the height gave way
    assert bent.com_error < 3e-3 and bent.foot_position_error < 2e-3


@pytest.mark.parametrize("bend", [-0.1, 1.0, float("nan")])
def test_min_knee_bend_must_be_a_small_angle(plant, bend):
    with pytest.raises(ValueError, match="min_knee_bend"):
        WholeBodyIkSolver(plant, min_knee_bend=bend)


def test_stall_stop_ends_an_unreachable_solve_early_at_the_same_answer(plant, q_nominal):
    """An unreachable COG target (beyond the bent rear leg's reach) plateaus within a few iterations:
    the stagnation stop returns there, with the posture and errors of the full 30-iteration solve."""
    rear, fore = RigidTransform([0.0, 0.095, 0.0]), RigidTransform([0.3, -0.095, 0.0])
    target = np.array([0.25, 0.0, 0.814])
    full = WholeBodyIkSolver(plant, min_knee_bend=0.15, stall_iterations=None).solve(q_nominal, target, rear, fore)
    early = WholeBodyIkSolver(plant, min_knee_bend=0.15).solve(q_nominal, target, rear, fore)
    assert full.iterations == 30 and not full.success
    assert early.iterations <= 8
    assert np.max(np.abs(early.q - full.q)) < 1e-4
    assert abs(early.com_error - full.com_error) < 1e-5


def test_stall_stop_leaves_converging_solves_alone(plant, solver, q_nominal):
    """A reachable target is met to the tolerances with the stop on, the same as without it."""
    for com, left, right, upper in walking_targets(6):
        on = solver.solve(q_nominal, com, left, right, None, upper)
        off = WholeBodyIkSolver(plant, stall_iterations=None).solve(q_nominal, com, left, right, None, upper)
        assert on.success and on.iterations == off.iterations
        np.testing.assert_allclose(on.q, off.q, atol=1e-12)


@pytest.mark.parametrize("kwargs", [{"stall_iterations": 0}, {"stall_iterations": 1.5},
                                    {"min_improvement": 1.0}, {"min_improvement": float("nan")}])
def test_stall_settings_are_validated(plant, kwargs):
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        WholeBodyIkSolver(plant, **kwargs)
