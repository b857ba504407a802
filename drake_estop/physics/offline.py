"""Offline-filter mode (``simulate --physics --controller offline-filter``), kept for comparison.

The kinematic reference of a stop (:func:`drake_estop.planning.rollout.rollout`, one row
per 5 ms servo tick) is turned into joint angles by the whole-body IK
(:class:`drake_estop.systems.ik.WholeBodyIkSolver`: COG xyz, both sole poses, the arm
joints), once per run, before the simulation. The joint reference
``[q_ref, v_ref]`` of the 30 actuated joints is a first-order-hold
``PiecewisePolynomial`` through the ticks (``v_ref`` by central differences of
the tick values) played by a ``TrajectorySource`` into the plant's
``desired_state`` input port.

Stiff servos alone do not suffice: the LIPM plan ignores the legs' and arms'
angular momentum and the crouch, so the whole-body ZMP of the IK motion is
off the planned ZMP by up to ~8 cm (measured), and in double-support stops the
plan puts the ZMP 1 cm behind the toe: the open-loop robot rolled onto the
front toe, lifted the rear foot and rocked for 2 s (3.5 s stop). The
stabilisation is a dynamics filter on the reference (Kajita's two-stage
preview control, :class:`ZmpPreviewFilter`): the multibody ZMP error of the IK
motion is fed through a cart-table preview controller and the resulting COG
offset is added to the COG target before the IK is solved again (two passes).
It is causal with respect to the stop: before the signal tick its preview
reads only the nominal walk. No measured-state feedback is used (no
ZMP/DCM feedback or ankle compliance); see the known gaps in the report.
:class:`CopEstimator` measures the centre of pressure (ZMP) of the ground
reaction from the plant's ``contact_results``.

:func:`run_physics` simulates one stop this way. The online controller
(:mod:`drake_estop.physics.online`) is the default and computes nothing ahead
of the tick that uses it.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput, TrajectorySource

from drake_estop.model import WALKING_COM_HEIGHT
from drake_estop.physics.criteria import JointReference, PhysicsResult, analyse
from drake_estop.physics.plant import (
    SIDES,
    CopEstimator,
    PhysicsHandles,
    PhysicsParameters,
    add_physics_plant,
    sole_bodies,
)
from drake_estop.planning.gait import GaitParameters, NominalPattern
from drake_estop.planning.lipm import GRAVITY  # the one gravity value
from drake_estop.planning.planner import StopParameters, StopPlan, plan_stop
from drake_estop.planning.rollout import Rollout, rollout
from drake_estop.robots.parameters import as_robot
from drake_estop.systems.ik import WholeBodyIkSolver, converged_posture, shared_ik
from drake_estop.systems.multibody_zmp import multibody_zmp
from drake_estop.systems.reference import sole_pose


def _sole(ro: Rollout, side: str, i: int):
    """Sole pose 7-vector of ``side`` at tick ``i`` of ``ro`` (turned by its heading)."""
    return sole_pose(ro.feet[side][i], 0.0 if ro.feet_yaw is None else float(ro.feet_yaw[side][i]))


def _upper_body(robot, ro: Rollout, i: int) -> dict:
    """The upper-body joint targets [rad] of tick ``i``: the robot's standing angles, the swinging arm
    joints (``ro.arm_joints``) at the rollout's."""
    upper = dict(zip(robot.upper_body_joints, robot.standing_angles()))
    upper.update(zip(ro.arm_joints, ro.upper_body[i]))
    return upper


def initial_configuration(plant, ro: Rollout, *, solver=None, robot=None):
    """Converged IK posture at the first tick of ``ro`` (feet ``step_width`` apart) of ``robot`` (the
    solver's, else the default humanoid)."""
    robot = solver.robot if solver is not None and robot is None else as_robot(robot)
    left, right = (_sole(ro, side, 0) for side in SIDES)
    return converged_posture(plant, ro.com[0], left, right, _upper_body(robot, ro, 0), solver=solver,
                             robot=robot)


def _solve_tick(solver, q, ro: Rollout, i):
    feet = [_sole(ro, side, i) for side in SIDES]
    return solver.solve(q, ro.com[i], feet[0], feet[1], None, _upper_body(solver.robot, ro, i))


def joint_reference(plant, ro: Rollout, *, solver=None) -> JointReference:
    """Solve the whole-body IK at every tick of ``ro``, warm-started tick to tick (``solver``'s robot,
    default the default humanoid)."""
    start = time.perf_counter()
    solver = solver or WholeBodyIkSolver(plant)
    q = initial_configuration(plant, ro, robot=solver.robot)
    n = len(ro.times)
    qs = np.empty((n, plant.num_positions()))
    com_err, foot_err = np.empty(n), np.empty(n)
    failures = 0
    for i in range(n):
        result = _solve_tick(solver, q, ro, i)
        q = result.q
        qs[i], com_err[i], foot_err[i] = q, result.com_error, result.foot_position_error
        failures += not result.success
    return JointReference(ro.times, qs, com_err, foot_err, failures, time.perf_counter() - start)


def nominal_rollout(pattern: NominalPattern, end: float, servo_period: float) -> Rollout:
    """Kinematic reference of the uninterrupted nominal walk, ticks 0..``end``."""
    count = int(math.floor(end / servo_period + 1e-9)) + 1
    times = servo_period * np.arange(count)
    pos, vel, acc, zmp = pattern.com(times)
    n = len(times)
    feet = {side: np.zeros((n, 3)) for side in SIDES}
    yaw = {side: np.zeros(n) for side in SIDES}
    upper = np.zeros((n, len(pattern.params.arms.joints)))
    for i, t in enumerate(times):
        for side, value in pattern.feet_at(float(t))[0].items():
            feet[side][i] = value
        for side, value in pattern.feet_yaw_at(float(t))[0].items():
            yaw[side][i] = value
        upper[i] = pattern.upper_body(float(t))[0]
    z = np.full(n, pattern.params.com_height)
    zeros = np.zeros(n)
    return Rollout(times, np.column_stack([pos, z]), np.column_stack([vel, zeros]),
                   np.column_stack([acc, zeros]), zmp, ["walking"] * n, feet, upper, yaw,
                   arm_joints=tuple(pattern.params.arms.joints))


class ZmpPreviewFilter:
    """Preview control of the cart-table model (Kajita et al. 2003), used as a COG correction.

    ``correct(before, after, switch)`` returns the COG offset (n, 2) whose
    cart-table ZMP tracks ``-error``: fed the multibody-minus-planned ZMP
    error of a reference, it is the second stage of Kajita's two-stage
    preview control. The preview window of tick k reads ``before`` for
    k < ``switch`` and ``after`` from ``switch`` on, so a correction computed
    for a stop plan uses only the nominal walk before the stop signal
    (causal): the stop is not anticipated.
    """

    def __init__(self, *, servo_period=0.005, com_height=WALKING_COM_HEIGHT, preview_time=1.6, q_error=1.0,
                 r_jerk=1e-6):
        from scipy.linalg import solve_discrete_are
        dt = servo_period
        self.dt = dt
        self.steps = int(round(preview_time / dt))
        a = np.array([[1.0, dt, dt * dt / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
        b = np.array([[dt ** 3 / 6], [dt * dt / 2], [dt]])
        c = np.array([[1.0, 0.0, -com_height / GRAVITY]])
        at = np.block([[np.eye(1), c @ a], [np.zeros((3, 1)), a]])
        bt = np.vstack([c @ b, b])
        qt = np.diag([q_error, 0.0, 0.0, 0.0])
        p = solve_discrete_are(at, bt, qt, np.array([[r_jerk]]))
        inv = 1.0 / (r_jerk + (bt.T @ p @ bt).item())
        k = inv * (bt.T @ p @ at)
        self.gain_integral = k[0, 0]
        self.gain_state = k[0, 1:]
        closed = at - bt @ k
        x = -closed.T @ p @ np.array([[1.0], [0.0], [0.0], [0.0]])
        preview = np.zeros(self.steps)  # gain on the reference j + 1 ticks ahead
        preview[0] = self.gain_integral
        for j in range(1, self.steps):
            preview[j] = -(inv * (bt.T @ x)).item()
            x = closed.T @ x
        self.gain_preview = preview
        self._a, self._b, self._c = a, b[:, 0], c[0]

    def track(self, before, after=None, switch=None) -> np.ndarray:
        """COG trajectory (n,) whose cart-table ZMP tracks the reference (see class doc)."""
        before = np.asarray(before, float)
        after = before if after is None else np.asarray(after, float)
        n = len(after)
        switch = n if switch is None else int(switch)
        windows = tuple(np.concatenate([r, np.full(self.steps + 1, r[-1])]) for r in (before, after))
        state = np.array([after[0], 0.0, 0.0])
        integral = 0.0
        out = np.empty(n)
        for k in range(n):
            src = windows[0] if k < switch else windows[1]
            ref_now = src[k]
            out[k] = state[0]
            integral += self._c @ state - ref_now
            u = (-self.gain_integral * integral - self.gain_state @ state
                 + self.gain_preview @ src[k + 1:k + 1 + self.steps])
            state = self._a @ state + self._b * u
        return out

    def correct(self, error_before, error_after=None, switch=None) -> np.ndarray:
        """COG offsets (n, 2) cancelling the ZMP errors (n, 2)."""
        error_after = error_before if error_after is None else error_after
        return np.column_stack([
            self.track(-np.asarray(error_before)[:, k], -np.asarray(error_after)[:, k], switch)
            for k in range(2)])


def build_physics_diagram(reference: JointReference | None = None, params: PhysicsParameters | None = None,
                          *, desired_state_source=None, robot=None) -> PhysicsHandles:
    """Humanoid (``robot``: a description, a name or None, the default humanoid) + ground + PD servos +
    CoP estimator + 5 ms loggers.

    The desired joint state comes from ``reference`` (a TrajectorySource of its
    first-order hold) or, if given, from ``desired_state_source``, a function
    ``(builder, plant) -> OutputPort`` (e.g. a stabiliser).
    """
    params = params or PhysicsParameters()
    builder = DiagramBuilder()
    plant, scene_graph, instance, ground_id = add_physics_plant(builder, params, robot)
    source = None
    if desired_state_source is not None:
        port = desired_state_source(builder, plant)
    else:
        source = builder.AddNamedSystem("joint_reference", TrajectorySource(
            reference.desired_state_trajectory(plant)))
        port = source.get_output_port()
    builder.Connect(port, plant.get_desired_state_input_port(instance))
    soles = sole_bodies(plant, robot)
    cop = builder.AddNamedSystem("cop_estimator", CopEstimator(
        plant=plant, scene_graph=scene_graph, bodies=soles))
    builder.Connect(plant.get_contact_results_output_port(), cop.contact_results_port)
    loggers = {
        "state": LogVectorOutput(plant.get_state_output_port(), builder, params.log_period),
        "cop": LogVectorOutput(cop.cop_port, builder, params.log_period),
        "normal_force": LogVectorOutput(cop.normal_force_port, builder, params.log_period),
        "foot_forces": LogVectorOutput(cop.body_normal_forces_port, builder, params.log_period),
    }
    diagram = builder.Build()
    diagram.set_name("estop_physics")
    return PhysicsHandles(diagram, plant, scene_graph, instance, cop, source, loggers, ground_id)




def run_physics(gait_params: GaitParameters | None = None, stop_params: StopParameters | None = None,
                estop_time: float = 3.4, *, after_halt: float = 2.5,
                physics: PhysicsParameters | None = None, pattern: NominalPattern | None = None,
                robot=None) -> PhysicsResult:
    """Walk the nominal pattern on the simulated humanoid, stop at ``estop_time``, check the criteria.

    The run starts at t = 0 (standing, before the initial weight shift) from
    the IK posture of the first tick, and ends ``after_halt`` seconds after the
    planned halt end. ``pattern`` (built from ``gait_params`` if omitted) may
    be shared between runs. ``robot`` (a description, a name or None: the
    default humanoid) is the simulated robot and the IK's model; the gait and
    stop parameters default to its own.
    """
    from drake_estop.robots.parameters import gait_parameters, stop_parameters

    robot = as_robot(robot)
    physics = (physics or PhysicsParameters()).for_robot(robot)
    stop_params = stop_params or stop_parameters(robot)
    pattern = pattern or NominalPattern(gait_params or gait_parameters(robot))
    plan = plan_stop(pattern, estop_time, stop_params)
    ro = rollout(plan, after_halt=after_halt)
    reference = reference_for(ro, plan, filter_iterations=physics.filter_iterations, robot=robot)
    handles = build_physics_diagram(reference, physics, robot=robot)
    simulator = Simulator(handles.diagram)
    context = simulator.get_mutable_context()
    handles.plant.SetPositions(handles.plant.GetMyMutableContextFromRoot(context), reference.q[0])
    simulator.Initialize()
    start = time.perf_counter()
    simulator.AdvanceTo(float(ro.times[-1]))
    wall = time.perf_counter() - start
    return analyse(handles, context, plan, reference, physics, wall, robot)


_NOMINAL = {}


def _shifted(ro: Rollout, offset) -> Rollout:
    com = ro.com.copy()
    com[:, :2] += offset
    return replace(ro, com=com)


def _zmp_error(ro: Rollout, offset, robot=None):
    """(JointReference, multibody - planned ZMP) of ``ro`` with the COG shifted by ``offset``."""
    plant, solver, _ = shared_ik(robot)
    reference = joint_reference(plant, _shifted(ro, offset), solver=solver)
    dt = float(ro.times[1] - ro.times[0])
    return reference, multibody_zmp(plant, reference.q, dt, window=0.0) - ro.zmp


def _nominal_errors(pattern: NominalPattern, dt: float, iterations: int, flt: ZmpPreviewFilter, robot=None):
    """Per-iteration multibody ZMP errors of the filtered nominal walk (cached per pattern and robot)."""
    key = (id(pattern), dt, iterations, as_robot(robot))
    if key not in _NOMINAL:
        ro = nominal_rollout(pattern, pattern.end_time + 1.0, dt)
        offset = np.zeros((len(ro.times), 2))
        errors = []
        for _ in range(iterations):
            error = _zmp_error(ro, offset, robot)[1]
            errors.append(error)
            offset = offset + flt.correct(error)
        _NOMINAL[key] = (pattern, errors)  # keep the pattern alive: its id stays unique
    return _NOMINAL[key][1]


def reference_for(ro: Rollout, plan: StopPlan | None = None, *, filter_iterations: int = 0,
                  robot=None) -> JointReference:
    """Joint reference of ``ro``; with ``filter_iterations`` > 0, dynamics-filtered (causal at the signal).

    The filter (:class:`ZmpPreviewFilter`) shifts the COG target so that the
    whole-body ZMP of the IK motion follows the plan's ZMP (the LIPM ignores
    the legs' and arms' angular momentum and the crouch). Before the stop
    signal the preview reads only the nominal walk's errors. ``robot``: the
    IK's model (a description, a name or None: the default humanoid).
    """
    start = time.perf_counter()
    plant, solver, context = shared_ik(robot)
    if filter_iterations <= 0:
        return joint_reference(plant, ro, solver=solver)
    dt = float(ro.times[1] - ro.times[0])
    flt = ZmpPreviewFilter(servo_period=dt, com_height=plan.pattern.params.com_height)
    nominal = _nominal_errors(plan.pattern, dt, filter_iterations, flt, robot)
    switch = int(np.searchsorted(ro.times, plan.signal_time - 1e-9))
    n = len(ro.times)
    offset = np.zeros((n, 2))
    raw = None
    for before in nominal:
        before = before[:n] if len(before) >= n else np.vstack([before, np.zeros((n - len(before), 2))])
        _, error = _zmp_error(ro, offset, robot)
        raw = error if raw is None else raw
        offset = offset + flt.correct(before, error, switch)
    reference, error = _zmp_error(ro, offset, robot)
    reference.com_offset, reference.zmp_error_raw, reference.zmp_error = offset, raw, error
    reference.wall_time = time.perf_counter() - start
    return reference
