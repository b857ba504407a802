"""Fast warm-started whole-body inverse kinematics for the humanoid.

``WholeBodyIkSolver`` is a pure (no-System) Levenberg-Marquardt / Newton
solver; ``WholeBodyIK`` wraps it as a discrete Drake ``LeafSystem``.

Formulation.  The unknowns are the 6 floating-base velocities of the pelvis
and the 12 leg joints.  The tasks are the COG position (3), both sole poses
(6 each) and the pelvis orientation (3): an 18x18 system that is square and
regular away from stretched knees.  Upper-body joints are posture targets
that are met exactly: they are written into q (clipped to their limits)
before the legs are solved, so the COG task accounts for their mass.  Each
iteration solves the damped normal equations of Sugihara (2011),
``(J^T W J + (e^T W e + bias) I) dx = J^T W e``, integrates the floating-base
rotation with the exponential map (Drake's quaternion floating joint uses the
angular velocity expressed in the world frame), and clips the leg joints to
their position limits; joints that sit on a limit and would be pushed
further out are removed from the step.
"""

import math
from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.tree import JacobianWrtVariable
from pydrake.systems.framework import EventStatus, LeafSystem, ValueProducer

from drake_estop.model import joint_position_indices, joint_velocity_indices
from drake_estop.robots.description import SIDES
from drake_estop.robots.parameters import as_robot, standing_seed
from drake_estop.robots.plant import add_robot, sole_frame
from drake_estop.timing import timed

# --------------------------------------------------------------------------
# Small rotation helpers in numpy (much cheaper than pydrake calls).


def _skew(w):
    """Cross-product matrix of w."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]],
                     [-w[1], w[0], 0.0]])


def rotation_log(rot):
    """Rotation vector (axis * angle) of the 3x3 rotation matrix ``rot``."""
    r = np.asarray(rot).tolist()  # plain floats: the same bits, faster
    cos_angle = min(1.0, max(-1.0, 0.5 * ((r[0][0] + r[1][1] + r[2][2]) - 1.0)))
    angle = math.acos(cos_angle)
    axis = np.array([r[2][1] - r[1][2], r[0][2] - r[2][0], r[1][0] - r[0][1]])
    if angle < 1e-6:
        return 0.5 * axis
    if math.pi - angle > 1e-4:
        return axis * (0.5 * angle / math.sin(angle))
    sym = 0.5 * (rot + np.eye(3))  # angle ~ pi: axis from the symmetric part.
    k = int(np.argmax(np.diag(sym)))
    axis = sym[:, k] / math.sqrt(max(sym[k, k], 1e-12))
    return angle * axis / np.linalg.norm(axis)


def _norm(v):
    """``np.linalg.norm`` of a 1-D vector (its own formula, sqrt of the dot product) without its overhead."""
    return math.sqrt(v.dot(v))


def rotation_exp(w):
    """Rotation matrix of the rotation vector ``w`` (Rodrigues)."""
    w = np.asarray(w, dtype=float)
    angle = _norm(w)
    if angle < 1e-12:
        return np.eye(3) + _skew(w)
    k = _skew(w / angle)
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def quaternion_to_matrix(quat):
    """3x3 rotation of the (w, x, y, z) quaternion (normalised here)."""
    quat = np.asarray(quat, dtype=float)
    w, x, y, z = (quat / _norm(quat)).tolist()  # plain floats: the same bits, faster
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def matrix_to_quaternion(rot):
    """Unit (w, x, y, z) quaternion of a 3x3 rotation matrix, w >= 0."""
    quat = RotationMatrix(rot).ToQuaternion().wxyz()
    return quat if quat[0] >= 0 else -quat


def yaw_of(rot):
    """Heading angle of the rotation's x axis in the world x-y plane."""
    return math.atan2(rot[1, 0], rot[0, 0])


def mean_yaw_rotation(rot_a, rot_b):
    """Yaw-only rotation at the circular mean of two frames' headings."""
    ya, yb = yaw_of(rot_a), yaw_of(rot_b)
    yaw = math.atan2(math.sin(ya) + math.sin(yb), math.cos(ya) + math.cos(yb))
    return RotationMatrix.MakeZRotation(yaw).matrix()


def _as_pose(pose):
    """(R, p) numpy pair of a RigidTransform or a 7-vector xyz+wxyz."""
    if isinstance(pose, RigidTransform):
        return pose.rotation().matrix(), pose.translation()
    pose = np.asarray(pose, dtype=float)
    return quaternion_to_matrix(pose[3:7]), pose[:3].copy()


def _as_matrix(rot):
    """3x3 numpy matrix of a RotationMatrix or array."""
    if isinstance(rot, RotationMatrix):
        return rot.matrix()
    return np.asarray(rot, dtype=float).reshape(3, 3)


# --------------------------------------------------------------------------
# Pure solver.


@dataclass(frozen=True)
class IkResult:
    """Outcome of one IK solve.  Errors are norms at the returned ``q``."""

    q: np.ndarray
    com_error: float
    foot_position_error: float
    foot_rotation_error: float
    orientation_error: float
    iterations: int
    success: bool
    joint_limit_ok: bool


@dataclass
class _Errors:
    """Task error vector (18) at ``q``; ``jac``, the 18 x 18 task Jacobian, is computed by
    :meth:`WholeBodyIkSolver._jacobian` only when a step is taken from ``q`` (the last
    iterate of a solve needs none)."""

    e: np.ndarray
    q: np.ndarray
    com: float
    foot_pos: float
    foot_rot: float
    orient: float
    jac: np.ndarray | None = None


class WholeBodyIkSolver:
    """Damped-Newton whole-body IK on a finalized humanoid ``plant``.

    ``robot`` (a :class:`drake_estop.robots.RobotDescription`, a built-in
    robot's name or a description file; default: the ``default`` humanoid)
    names the floating base, the sole frames, the leg and upper-body joints
    of ``plant`` (built with :func:`drake_estop.robots.add_robot`, or for
    the default robot :func:`drake_estop.model.load_humanoid`).

    Tolerances ``com_tolerance`` / ``foot_position_tolerance`` [m] and
    ``foot_rotation_tolerance`` / ``orientation_tolerance`` [rad] decide
    ``success``; iterations stop early once every error is below
    ``convergence_ratio`` times its tolerance.

    ``min_knee_bend`` [rad] (default: the robot description's, 0 for the
    built-in robots: the knee no straighter than its zero) raises the
    knees' lower limit in the solve: a leg-extension limit.
    Near a straight knee its speed (the leg's extension rate / sin(knee))
    is unbounded, and a straight knee that must bend again drops the pelvis
    at once. With the floor the COG target that would stretch a leg is met
    as far as the bent leg reaches: the COG height gives way first (the
    height error then counts against ``com_tolerance``).

    ``stall_iterations`` (default 2; ``None`` runs every iteration) stops
    the solve once that many consecutive iterations have each lowered the
    weighted error of the iterate before by less than ``min_improvement``
    (relative, default 1 %): the iteration budget of an unreachable target.
    (An iterate that gets worse, as when a joint lands on a limit, and is
    then improved on, does not stop the solve.) Measured on the
    78 solves that ran all 30 iterations after a 17 N s push in double
    support: each reached its plateau within 3 iterations (the error of
    the last 27 equal to 3 digits), so those 27 were 5 ms of a 5 ms tick
    spent on nothing. A converging solve (quadratic near the solution) never
    improves by less than 1 % an iteration before it meets the tolerances.
    """

    def __init__(self, plant, *, max_iterations=30, com_tolerance=1e-3,
                 foot_position_tolerance=1e-3, foot_rotation_tolerance=1e-2,
                 orientation_tolerance=1e-2, convergence_ratio=0.01,
                 rotation_weight=0.3, damping_bias=1e-9, min_knee_bend=None,
                 stall_iterations=2, min_improvement=0.01, robot=None):
        self._plant = plant
        self._robot = as_robot(robot)
        self._context = plant.CreateDefaultContext()
        self.max_iterations = max_iterations
        self._tol = np.array([com_tolerance, foot_position_tolerance,
                              foot_rotation_tolerance, orientation_tolerance])
        self._stop = convergence_ratio * self._tol
        self._stop_values = tuple(float(v) for v in self._stop)  # plain floats: compared every iteration
        self._bias = damping_bias
        self._init_indices(plant)
        self._init_weights(rotation_weight)
        self._raise_knee_limits(plant, self._robot.min_knee_bend if min_knee_bend is None else min_knee_bend)
        self._init_stall(stall_iterations, min_improvement)

    # -- set-up -------------------------------------------------------------

    def _init_indices(self, plant):
        """Cache frames and q/v indices used every iteration."""
        robot = self._robot
        base = plant.GetBodyByName(robot.floating_base)
        self._base_q = base.floating_positions_start()
        base_v = base.floating_velocities_start_in_v()
        self._v_sel = np.concatenate([np.arange(base_v, base_v + 6),
                                      joint_velocity_indices(plant, robot.leg_joints)])
        self._leg_q = joint_position_indices(plant, robot.leg_joints)
        upper_body = robot.upper_body_joints
        self._upper_q = dict(zip(upper_body, joint_position_indices(plant, upper_body)))
        self._lower = plant.GetPositionLowerLimits()
        self._upper = plant.GetPositionUpperLimits()
        self._all_q = joint_position_indices(plant, robot.all_joints)
        self._world = plant.world_frame()
        self._soles = tuple(sole_frame(plant, robot, side) for side in SIDES)
        self._base_frame = base.body_frame()
        self._nv = plant.num_velocities()

    def _raise_knee_limits(self, plant, min_knee_bend):
        """Knees no straighter than ``min_knee_bend`` [rad] in the solve."""
        if not (math.isfinite(min_knee_bend) and 0.0 <= min_knee_bend < 1.0):
            raise ValueError(f"min_knee_bend must be in [0, 1) rad, got {min_knee_bend!r}")
        self._lower = self._lower.copy()
        for side in SIDES:
            index = plant.GetJointByName(self._robot.leg(side).knee).position_start()
            self._lower[index] = max(self._lower[index], min_knee_bend)

    def _init_stall(self, stall_iterations, min_improvement):
        """Validated stagnation stop (``None``: off)."""
        if stall_iterations is not None and not (isinstance(stall_iterations, int) and stall_iterations >= 1):
            raise ValueError(f"stall_iterations must be an int >= 1 or None, got {stall_iterations!r}")
        if not (isinstance(min_improvement, (int, float)) and 0.0 <= min_improvement < 1.0):
            raise ValueError(f"min_improvement must be in [0, 1), got {min_improvement!r}")
        self.stall_iterations = stall_iterations
        self._keep = 1.0 - min_improvement

    def _init_weights(self, rotation_weight):
        """Row weights: metres count 1, radians count ``rotation_weight``."""
        w_rot = rotation_weight ** 2
        self._w = np.array([1, 1, 1] + [w_rot] * 3 + [1] * 3 + [w_rot] * 3
                           + [1] * 3 + [w_rot] * 3)

    @property
    def plant(self):
        """The MultibodyPlant this solver works on."""
        return self._plant

    @property
    def robot(self):
        """The robot's :class:`~drake_estop.robots.RobotDescription`."""
        return self._robot

    # -- kinematics ---------------------------------------------------------

    def _errors(self, context, q, targets):
        """Task errors at ``q`` (``context`` is left at ``q`` for :meth:`_jacobian`)."""
        plant = self._plant
        plant.SetPositions(context, q)
        com_t, feet_t, rot_base_t = targets
        e = np.empty(18)
        e[0:3] = com_t - plant.CalcCenterOfMassPositionInWorld(context)
        rot_err, pos_err = 0.0, 0.0
        for k, (frame, (rot_t, p_t)) in enumerate(zip(self._soles, feet_t)):
            pose = frame.CalcPoseInWorld(context)
            row = 3 + 6 * k
            e[row:row + 3] = rotation_log(rot_t @ pose.rotation().matrix().T)
            e[row + 3:row + 6] = p_t - pose.translation()
            rot_err = max(rot_err, _norm(e[row:row + 3]))
            pos_err = max(pos_err, _norm(e[row + 3:row + 6]))
        rot_base = quaternion_to_matrix(q[self._base_q:self._base_q + 4])
        e[15:18] = rotation_log(rot_base_t @ rot_base.T)
        return _Errors(e, q, _norm(e[0:3]), pos_err, rot_err, _norm(e[15:18]))

    def _jacobian(self, context, err):
        """``err.jac``: the 18 x 18 task Jacobian at ``err.q`` (computed once)."""
        if err.jac is None:
            plant, world, kv = self._plant, self._world, JacobianWrtVariable.kV
            if not np.array_equal(plant.GetPositions(context), err.q):  # a solve leaves it there already;
                plant.SetPositions(context, err.q)  # setting it again would recompute the kinematics
            jac = np.empty((18, self._nv))
            jac[0:3] = plant.CalcJacobianCenterOfMassTranslationalVelocity(context, kv, world, world)
            for k, frame in enumerate(self._soles):
                jac[3 + 6 * k:9 + 6 * k] = plant.CalcJacobianSpatialVelocity(
                    context, kv, frame, np.zeros(3), world, world)
            jac[15:18] = plant.CalcJacobianAngularVelocity(context, kv, self._base_frame, world, world)
            err.jac = jac[:, self._v_sel]
        return err.jac

    # -- stepping -----------------------------------------------------------

    def _step(self, err, q, jac):
        """Damped least-squares step dx (18) honouring active joint limits (``jac``: ``err``'s
        Jacobian)."""
        jw = jac.T * self._w
        hess = jw @ jac
        grad = jw @ err.e
        hess[np.diag_indices(18)] += err.e @ (self._w * err.e) + self._bias
        dx = np.linalg.solve(hess, grad)
        free = self._free_mask(q, dx)
        if free.all():  # no joint at a limit pushed past it: that solve is the step
            return dx
        dx = np.zeros(18)
        dx[free] = np.linalg.solve(hess[np.ix_(free, free)], grad[free])
        return dx

    def _free_mask(self, q, dx):
        """Variables not blocked by a leg joint already at a limit."""
        legs = q[self._leg_q]
        eps = 1e-9
        blocked = (((legs <= self._lower[self._leg_q] + eps) & (dx[6:] < 0))
                   | ((legs >= self._upper[self._leg_q] - eps) & (dx[6:] > 0)))
        return np.concatenate([np.ones(6, dtype=bool), ~blocked])

    def _integrate(self, q, dx):
        """q advanced by the velocity-space step dx (exact base rotation)."""
        q = q.copy()
        b = self._base_q
        rot = rotation_exp(dx[0:3]) @ quaternion_to_matrix(q[b:b + 4])
        q[b:b + 4] = matrix_to_quaternion(rot)
        q[b + 4:b + 7] += dx[3:6]
        q[self._leg_q] = np.clip(q[self._leg_q] + dx[6:],
                                 self._lower[self._leg_q],
                                 self._upper[self._leg_q])
        return q

    # -- public API ---------------------------------------------------------

    def prepare_guess(self, q_guess, upper_body_targets=None):
        """Copy of ``q_guess`` with upper-body targets written in, clipped."""
        q = np.array(q_guess, dtype=float)
        if q.shape != (self._plant.num_positions(),):
            raise ValueError(f"q_guess must have {self._plant.num_positions()}"
                             f" entries, got shape {q.shape}")
        for name, angle in (upper_body_targets or {}).items():
            if name not in self._upper_q:
                raise ValueError(f"unknown upper-body joint {name!r}")
            q[self._upper_q[name]] = angle
        b = self._base_q
        q[b:b + 4] /= np.linalg.norm(q[b:b + 4])
        q[self._all_q] = np.clip(q[self._all_q], self._lower[self._all_q],
                                 self._upper[self._all_q])
        return q

    def solve(self, q_guess, com_target, left_foot_pose, right_foot_pose,
              base_rotation=None, upper_body_targets=None, *, context=None):
        """Solve the whole-body IK, warm-started from ``q_guess``.

        Foot poses are RigidTransforms of the sole frames (or 7-vectors
        xyz + quaternion wxyz); ``base_rotation`` is the pelvis orientation
        (RotationMatrix or 3x3; default: level, heading at the feet's mean
        yaw); ``upper_body_targets`` maps upper-body joint names to angles.
        ``context`` is an optional scratch context of the plant.  Never
        raises for unreachable targets: returns the best q found with
        ``success=False``.  Raises ValueError for non-finite inputs.
        """
        targets = self._targets(com_target, left_foot_pose, right_foot_pose,
                                base_rotation)
        context = context if context is not None else self._context
        q = self.prepare_guess(q_guess, upper_body_targets)
        if not np.isfinite(q).all():
            raise ValueError("q_guess contains non-finite values")
        best_q, best = q, self._errors(context, q, targets)
        err, iterations, stalled = best, 0, 0
        cost = best_cost = self._cost(best)
        while iterations < self.max_iterations and not self._converged(err) and not self._stalled(stalled):
            q_new = self._integrate(q, self._step(err, q, self._jacobian(context, err)))
            iterations += 1
            if not np.all(np.isfinite(q_new)):
                break
            q, err, previous_cost = q_new, self._errors(context, q_new, targets), cost
            cost = self._cost(err)
            stalled = 0 if cost < self._keep * previous_cost else stalled + 1
            if cost < best_cost:
                best_q, best, best_cost = q, err, cost
        return self._result(best_q, best, iterations)

    def _stalled(self, stalled):
        """True once ``stall_iterations`` iterations in a row improved too little."""
        return self.stall_iterations is not None and stalled >= self.stall_iterations

    # -- helpers for solve --------------------------------------------------

    def _targets(self, com_target, left_foot_pose, right_foot_pose,
                 base_rotation):
        """Validated numpy targets (com, ((R, p), (R, p)), R_base)."""
        com = np.asarray(com_target, dtype=float).reshape(3)
        feet = (_as_pose(left_foot_pose), _as_pose(right_foot_pose))
        if base_rotation is None:
            rot_base = mean_yaw_rotation(feet[0][0], feet[1][0])
        else:
            rot_base = _as_matrix(base_rotation)
        values = [com, rot_base] + [a for pose in feet for a in pose]
        if not all(np.isfinite(v).all() for v in values):
            raise ValueError("IK targets contain non-finite values")
        return com, feet, rot_base

    def _converged(self, err):
        """True once every error is far below its tolerance."""
        stop = self._stop_values
        return err.com <= stop[0] and err.foot_pos <= stop[1] and err.foot_rot <= stop[2] and err.orient <= stop[3]

    def _cost(self, err):
        """Weighted squared task error (for keeping the best iterate)."""
        return float(err.e @ (self._w * err.e))

    @staticmethod
    def _error_vector(err):
        """(com, foot position, foot rotation, base orientation) errors."""
        return np.array([err.com, err.foot_pos, err.foot_rot, err.orient])

    def _result(self, q, err, iterations):
        """Package an IkResult for ``q``."""
        idx = self._all_q
        limits_ok = bool(np.all(q[idx] >= self._lower[idx] - 1e-12)
                         and np.all(q[idx] <= self._upper[idx] + 1e-12))
        within = bool(np.all(self._error_vector(err) <= self._tol))
        return IkResult(q=q, com_error=err.com,
                        foot_position_error=err.foot_pos,
                        foot_rotation_error=err.foot_rot,
                        orientation_error=err.orient, iterations=iterations,
                        success=within and limits_ok,
                        joint_limit_ok=limits_ok)


# --------------------------------------------------------------------------
# Drake System wrapper.


class WholeBodyIK(LeafSystem):
    """Discrete whole-body IK: COG / sole-pose / posture targets -> q.

    Every ``servo_period`` seconds the IK is solved, warm-started from the
    previous solution held in the discrete state, and the new solution and
    its diagnostics are stored in the state.  Outputs depend on the state
    only (no direct feedthrough).

    .. pydrake_system::

        name: WholeBodyIK
        input_ports:
        - com
        - left_foot
        - right_foot
        - upper_body
        output_ports:
        - q
        - ik_com_error
        - ik_foot_error
        - velocity_limit_violations

    Ports:
      - ``com`` (3): COG target in world [m].
      - ``left_foot`` / ``right_foot`` (7): sole-frame pose in world as
        ``[x, y, z, qw, qx, qy, qz]`` (quaternion normalised internally).
      - ``upper_body`` (one per upper-body joint of the robot, 18 for the
        default): joint targets [rad] in ``robot.upper_body_joints`` order.
      - ``q`` (plant.num_positions()): full plant positions.
      - ``ik_com_error`` (1): COG error norm of the last solve [m].
      - ``ik_foot_error`` (1): worst sole position error of the last solve
        [m] (``inf`` if the last inputs were not finite).
      - ``velocity_limit_violations`` (1): number of joints whose
        (q_new - q_old) / servo_period exceeded the URDF velocity limit at
        the last update.

    The pelvis orientation target is level with the feet's mean heading.
    Non-finite inputs keep the previous q and report infinite errors.
    The solver's scratch plant context lives in a per-Context cache entry.

    Parameters
    ----------
    plant : pydrake.multibody.plant.MultibodyPlant
        Finalized plant holding the humanoid (the IK's model; it need not be
        a system of the diagram).
    servo_period : float, optional
        Solve period [s] (default 0.005).
    initial_q : array_like, optional
        Initial positions (plant.num_positions()) [m, rad]; default the
        standing posture.
    solver : WholeBodyIkSolver, optional
        A configured solver (default: one for ``plant`` and ``robot``).
    timer : drake_estop.timing.TickTimer, optional
        Records the wall-clock time of every solve [s].
    robot : RobotDescription or str, optional
        The robot in ``plant`` (default: the solver's, else the ``default``
        humanoid); see :class:`WholeBodyIkSolver`.

    Raises
    ------
    ValueError
        If ``robot`` is not the given solver's.
    """

    def __init__(self, *, plant, servo_period=0.005, initial_q=None,
                 solver=None, timer=None, robot=None):
        super().__init__()
        if solver is not None and robot is not None and as_robot(robot) != solver.robot:
            raise ValueError(f"robot {as_robot(robot).name!r} is not the solver's ({solver.robot.name!r})")
        self._solver = solver or WholeBodyIkSolver(plant, robot=robot)
        self._robot = self._solver.robot
        self._plant = plant
        self._period = servo_period
        self._declare_indices(plant)
        q0 = (standing_seed(plant, self._robot, com_height=self._robot.walking_com_height) if initial_q is None
              else np.asarray(initial_q, dtype=float))
        self._q_state = self.DeclareDiscreteState(q0)
        self._diag_state = self.DeclareDiscreteState(3)
        self._declare_ports(plant)
        self._scratch = self.DeclareCacheEntry(
            "IK scratch plant context",
            ValueProducer(allocate=self._allocate_scratch,
                          calc=lambda context, value: None),
            {self.nothing_ticket()})
        self.DeclarePeriodicDiscreteUpdateEvent(servo_period, 0.0,
                                                timed(self._update, timer))

    def _declare_indices(self, plant):
        """Joint indices and velocity limits used by the limit check."""
        self._joint_q = joint_position_indices(plant, self._robot.all_joints)
        v_idx = joint_velocity_indices(plant, self._robot.all_joints)
        self._vel_limit = np.minimum(-plant.GetVelocityLowerLimits()[v_idx],
                                     plant.GetVelocityUpperLimits()[v_idx])

    def _declare_ports(self, plant):
        """Declare input and output ports, keeping their handles."""
        self.com_port = self.DeclareVectorInputPort("com", 3)
        self.left_foot_port = self.DeclareVectorInputPort("left_foot", 7)
        self.right_foot_port = self.DeclareVectorInputPort("right_foot", 7)
        self.upper_body_port = self.DeclareVectorInputPort(
            "upper_body", len(self._robot.upper_body_joints))
        self.q_port = self.DeclareStateOutputPort("q", self._q_state)
        self.com_error_port = self._declare_diag_output("ik_com_error", 0)
        self.foot_error_port = self._declare_diag_output("ik_foot_error", 1)
        self.violations_port = self._declare_diag_output(
            "velocity_limit_violations", 2)

    def _declare_diag_output(self, name, index):
        """Scalar output port reading entry ``index`` of the diagnostics."""
        def calc(context, output):
            value = context.get_discrete_state(self._diag_state).value()[index]
            output.SetAtIndex(0, value)
        return self.DeclareVectorOutputPort(
            name, 1, calc, prerequisites_of_calc={self.xd_ticket()})

    def _allocate_scratch(self):
        """A fresh plant context, boxed for the cache."""
        return AbstractValue.Make(self._plant.CreateDefaultContext())

    @property
    def solver(self):
        """The underlying WholeBodyIkSolver."""
        return self._solver

    @property
    def servo_period(self):
        """Update period [s]."""
        return self._period

    def _scratch_context(self, context):
        """This Context's scratch plant context (workspace, no state)."""
        value = self._scratch.get_mutable_cache_entry_value(context)
        return value.GetMutableValueOrThrow()

    def _update(self, context, discrete_state):
        """Solve the IK and store q plus diagnostics in the state."""
        q_old = context.get_discrete_state(self._q_state).value()
        inputs = [port.Eval(context) for port in (
            self.com_port, self.left_foot_port, self.right_foot_port,
            self.upper_body_port)]
        if not all(np.all(np.isfinite(x)) for x in inputs):
            discrete_state.set_value(self._diag_state,
                                     [np.inf, np.inf, 0.0])
            return EventStatus.Succeeded()
        com, left, right, upper = inputs
        result = self._solver.solve(
            q_old, com, left, right, None,
            dict(zip(self._robot.upper_body_joints, upper)),
            context=self._scratch_context(context))
        discrete_state.set_value(self._q_state, result.q)
        discrete_state.set_value(self._diag_state, [
            result.com_error, result.foot_position_error,
            float(self._count_violations(q_old, result.q))])
        return EventStatus.Succeeded()

    def _count_violations(self, q_old, q_new):
        """Joints whose implied velocity exceeds its limit."""
        rate = np.abs(q_new[self._joint_q] - q_old[self._joint_q]) / self._period
        return int(np.sum(rate > self._vel_limit * (1 + 1e-9)))


def pose_vector(pose):
    """7-vector ``[x, y, z, qw, qx, qy, qz]`` of a RigidTransform."""
    return np.concatenate([pose.translation(),
                           pose.rotation().ToQuaternion().wxyz()])


_SHARED = {}


def shared_ik(robot=None):
    """``(plant, solver, context)``: a kinematic-only plant of ``robot`` (default: the ``default``
    humanoid; a name, a description file or a :class:`~drake_estop.robots.RobotDescription`), its
    :class:`WholeBodyIkSolver` and a context, built once per process and robot and shared (the IK of every
    diagram and of the offline reference)."""
    description = as_robot(robot)
    if description not in _SHARED:
        from pydrake.multibody.plant import MultibodyPlant
        plant = MultibodyPlant(0.0)
        add_robot(plant, description, contact=False)
        plant.Finalize()
        _SHARED[description] = plant, WholeBodyIkSolver(plant, robot=description), plant.CreateDefaultContext()
    return _SHARED[description]


def converged_posture(plant, com, left_foot, right_foot, upper_body: dict, *, solver=None, attempts: int = 20,
                      robot=None):
    """The IK posture that reaches these targets from the standing posture, iterated until a solve
    starts converged (so the first servo tick does not jump).

    ``com`` [m] xyz; ``left_foot`` / ``right_foot`` sole poses ``[x, y, z, qw, qx, qy, qz]``;
    ``upper_body`` joint name -> angle [rad]; ``robot`` the robot in ``plant`` (default: the solver's,
    else the ``default`` humanoid). Raises RuntimeError if the IK cannot reach them.
    """
    solver = solver or WholeBodyIkSolver(plant, max_iterations=50, robot=robot)
    q = standing_seed(plant, solver.robot, com_height=float(com[2]))
    for _ in range(attempts):
        result = solver.solve(q, com, left_foot, right_foot, None, upper_body)
        q = result.q
        if result.success and result.iterations <= 1:
            return q
    raise RuntimeError(f"the IK cannot reach the initial posture of robot {solver.robot.name!r} "
                       f"(COG error {result.com_error:.2e} m)")
