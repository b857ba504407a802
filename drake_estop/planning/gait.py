"""Nominal walking pattern that the emergency stop interrupts.

Pure numpy. The ZMP reference is piecewise polynomial (constant at the support
ankle in single support, or the gait's ``zmp_offset`` ahead of it; a quintic
smoothstep between the feet in double support) and the COG is its analytic
LIPM solution (eq. 6-9), so the pattern satisfies eq. 4 exactly, to rounding.
Boundedness: the initial weight shift
carries one bump in the ZMP chosen so that the divergent component of the COG
matches the future ZMP (backward recursion); the final double support is
Harada's two-point boundary-value segment (eq. 27-28) that ends the walk at
rest between the feet, exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from drake_estop.planning import lipm
from drake_estop.planning.arms import DEFAULT_ARM_JOINTS, DEFAULT_ARM_NEUTRAL, ArmSwing
from drake_estop.planning.com_correction import ComCorrection


@dataclass(frozen=True)
class Sole:
    """Sole rectangle around the ankle (HRP-2 class, models/README.md).

    Attributes
    ----------
    toe, heel : float
        Distance from the ankle to the toe and the heel edge [m].
    inner, outer : float
        Distance from the ankle to the inner and the outer edge [m].
    """

    toe: float = 0.135
    heel: float = 0.105
    inner: float = 0.055
    outer: float = 0.081

    def lateral_edges(self, side: str) -> tuple[float, float]:
        """Distances [m] from the ankle of the ``side`` ('left'/'right') foot to its sole's edge on the
        robot's left (+y in the sole frame) and on its right: the outer edge is on the foot's own side."""
        return (self.outer, self.inner) if side == "left" else (self.inner, self.outer)

    def corners(self, ankle_xy, side: str, yaw: float = 0.0) -> np.ndarray:
        """Corners (4, 2) of the sole of the ``side`` ('left'/'right') foot, turned by ``yaw`` [rad]
        about the ankle."""
        x, y = ankle_xy
        left_edge, right_edge = self.lateral_edges(side)
        if yaw == 0.0:
            return np.array(
                [
                    [x + self.toe, y + left_edge],
                    [x - self.heel, y + left_edge],
                    [x - self.heel, y - right_edge],
                    [x + self.toe, y - right_edge],
                ]
            )
        local = np.array([[self.toe, left_edge], [-self.heel, left_edge], [-self.heel, -right_edge],
                          [self.toe, -right_edge]])
        return np.array([x, y]) + local @ rotation(yaw).T


def _positive(name: str, value: float) -> float:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return float(value)


def rotation(yaw: float) -> np.ndarray:
    """2x2 rotation by ``yaw`` [rad] about the vertical."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s], [s, c]])


MAX_TURN_DEG = 30.0  # [deg] heading change between consecutive footsteps (the hip yaw's reach)
SIDES = ("left", "right")


@dataclass(frozen=True)
class Footstep:
    """One footstep of a walk: the ``side`` foot lands with its ankle at (``x``, ``y``) [m] and its
    heading ``yaw`` [rad]; ``duration`` [s] is the step (single + double support), NaN for the
    gait's ``step_time``."""

    side: str
    x: float
    y: float
    yaw: float = 0.0
    duration: float = math.nan


@dataclass(frozen=True)
class GaitParameters:
    """Nominal gait; defaults follow the paper's simulation (Section V).

    Attributes
    ----------
    com_height : float
        COG height of the linear inverted pendulum [m] (HRP-2's 0.814).
    step_length : float
        Sagittal step length [m].
    step_width : float
        Lateral distance between the ankles [m].
    step_time : float
        One step: single + double support [s].
    double_support_ratio : float
        Share of ``step_time`` in double support (dimensionless, in (0, 1)).
    num_steps : int
        Steps of the walk, including the final one that closes the feet.
    initial_shift_time : float
        Weight shift before the first step [s].
    final_shift_time : float
        Double support that ends the walk at rest [s].
    lift_height : float
        Swing-foot apex above the floor [m].
    arm_swing : float
        Shoulder swing amplitude [rad].
    arms : ArmSwing
        The joints that swing (and that the stop halts, eq. 32-33), their neutral angles [rad] and
        shares of the swing (default: the HRP-2-class humanoid's shoulder pitches and elbows).
    sole : Sole
        The sole rectangle [m].
    turn : float
        Heading change per step [deg], positive to the left: the walk follows an
        arc (at most :data:`MAX_TURN_DEG`).
    side_step : float
        Side step [m], positive to the left: the leading foot (on that side)
        steps out by ``side_step``, widening the stance to ``step_width +
        |side_step|``, and the trailing foot closes it to ``step_width``; the
        walk moves ``side_step`` sideways per stride. With ``step_length`` 0
        the robot side-steps.
    footsteps : tuple of Footstep
        An explicit footstep list (replaces ``step_length``, ``turn``,
        ``side_step`` and ``num_steps``): the robot starts at the standing
        stance (ankles at y = +-step_width / 2, heading 0) and lands these
        steps in order, alternating feet (:func:`load_footsteps` reads a CSV).
    zmp_offset : float
        The single-support ZMP's distance ahead of the support ankle along the
        foot's heading [m] (default 0: at the ankle, the paper's pattern); for
        a sole that reaches far ahead of its ankle. It must lie inside the sole
        (``-heel < zmp_offset < toe``); the standing ZMP stays between the ankles.

    Raises
    ------
    ValueError
        On a non-physical value, or footsteps whose soles cross or overlap or
        turn more than :data:`MAX_TURN_DEG` per step; the message names the field.
    """

    com_height: float = 0.814  # HRP-2 walking pattern COG height [m]
    step_length: float = 0.3  # [m]
    step_width: float = 0.19  # lateral distance between the ankles [m]
    step_time: float = 0.8  # one step: single + double support [s]
    double_support_ratio: float = 0.2  # share of step_time in double support
    num_steps: int = 8  # including the final step that closes the feet
    initial_shift_time: float = 1.25  # weight shift before the first step [s] (see README: scenario timing)
    final_shift_time: float = 1.0  # double support that ends the walk at rest [s]
    lift_height: float = 0.05  # swing-foot apex above the floor [m]
    arm_swing: float = 0.15  # shoulder swing amplitude [rad]
    arms: ArmSwing = field(default_factory=ArmSwing)  # the swinging joints (planning/arms.py)
    sole: Sole = field(default_factory=Sole)
    turn: float = 0.0  # heading change per step [deg], positive to the left
    side_step: float = 0.0  # each foot's sideways step [m], positive to the left (widen, then close)
    footsteps: tuple = ()  # explicit Footstep list (replaces step_length / turn / side_step / num_steps)
    zmp_offset: float = 0.0  # single-support ZMP ahead of the support ankle [m]

    def __post_init__(self):
        for name in ("com_height", "step_time", "step_width", "initial_shift_time", "final_shift_time"):
            _positive(name, getattr(self, name))
        if not math.isfinite(self.step_length):
            raise ValueError(f"step_length must be finite, got {self.step_length!r}")
        if not 0.0 < self.double_support_ratio < 1.0:
            raise ValueError(f"double_support_ratio must be in (0, 1), got {self.double_support_ratio!r}")
        if int(self.num_steps) != self.num_steps or self.num_steps < 2:
            raise ValueError(f"num_steps must be an integer >= 2, got {self.num_steps!r}")
        if self.lift_height < 0 or not math.isfinite(self.lift_height):
            raise ValueError(f"lift_height must be >= 0, got {self.lift_height!r}")
        if self.step_width <= self.sole.inner * 2:
            raise ValueError(
                f"step_width {self.step_width} m makes the soles overlap (inner edges {self.sole.inner} m)"
            )
        for name in ("turn", "side_step"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name} must be finite, got {getattr(self, name)!r}")
        if not isinstance(self.arms, ArmSwing):
            raise ValueError(f"arms must be an ArmSwing (joints, neutral, gains), got {self.arms!r}")
        if not (math.isfinite(self.zmp_offset) and -self.sole.heel < self.zmp_offset < self.sole.toe):
            raise ValueError(f"zmp_offset must lie inside the sole ({-self.sole.heel}, {self.sole.toe}) m, "
                             f"got {self.zmp_offset!r}")
        if abs(self.turn) > MAX_TURN_DEG:
            raise ValueError(f"turn {self.turn} deg per step is beyond the limit of {MAX_TURN_DEG} deg")
        if self.footsteps:
            object.__setattr__(self, "footsteps", tuple(_footstep(f, i) for i, f in enumerate(self.footsteps)))
            if len(self.footsteps) < 2:
                raise ValueError(f"footsteps: a walk needs at least 2 steps, got {len(self.footsteps)}")
        check_footsteps(self)

    @property
    def walk_steps(self) -> int:
        """Steps of the walk (``num_steps``, or the length of ``footsteps``)."""
        return len(self.footsteps) if self.footsteps else int(self.num_steps)

    @property
    def single_support_time(self) -> float:
        return self.step_time * (1.0 - self.double_support_ratio)

    @property
    def double_support_time(self) -> float:
        return self.step_time * self.double_support_ratio

    @property
    def omega(self) -> float:
        return lipm.omega(self.com_height)


# The default humanoid's upper-body joints driven by the pattern (names as in models/humanoid.urdf);
# a gait's own are ``GaitParameters.arms``.
ARM_JOINTS = DEFAULT_ARM_JOINTS
ARM_NEUTRAL = np.array(DEFAULT_ARM_NEUTRAL)


@dataclass
class PatternState:
    """Everything the stop planner reads from the pattern at one instant."""

    time: float
    support: str  # "single", "double" or "standing"
    support_foot: str | None  # "left"/"right" in single support
    com: np.ndarray  # (2,) x, y
    com_vel: np.ndarray  # (2,)
    zmp: np.ndarray  # (2,)
    zmp_rate: np.ndarray  # (2,)
    zmp_accel: np.ndarray  # (2,)
    feet: dict  # side -> (3,) ankle position xyz (ankle height not included: z is lift)
    feet_vel: dict
    feet_acc: dict
    next_landing: np.ndarray | None  # (2,) nominal landing of the swing foot
    rear_foot: str | None  # in double support: the foot the ZMP leaves
    step_index: int  # index of the current step (0 = initial shift)
    upper_body: np.ndarray  # (len(params.arms.joints),)
    upper_body_rate: np.ndarray
    feet_yaw: dict = field(default_factory=lambda: {side: 0.0 for side in SIDES})  # side -> heading [rad]
    feet_yaw_rate: dict = field(default_factory=lambda: {side: 0.0 for side in SIDES})  # [rad/s]
    next_landing_yaw: float = 0.0  # heading of the nominal landing [rad]
    # a recovery step out of a double-support stop (planning/replan.py, replan_stop): its nominal
    # touchdown [s]; the walk's footstep (steps[step_index]) does not apply to it. None: the walk's step
    recovery_touchdown: float | None = None


class NominalPattern:
    """A walk from standing to standing: ``num_steps`` steps straight, on an arc (``turn``) or
    sideways (``side_step``), or an explicit footstep list (``footsteps``).

    Time 0 is the start of the initial weight shift; the robot stands still
    before it and after :attr:`end_time`.

    Parameters
    ----------
    params : GaitParameters, optional
        The gait (default: the paper's).
    com_correction : ComCorrection, optional
        Added to the COG (position, velocity, acceleration) and not to the ZMP: the walk's COG moved so that
        the whole body's ZMP, not the LIPM's, is the planned one
        (:func:`drake_estop.systems.whole_body_walk.whole_body_pattern`). Default none: the LIPM's COG.

    Notes
    -----
    ``com(times)`` returns the COG position [m], velocity [m/s],
    acceleration [m/s^2] and the ZMP [m], each (n, 2); ``feet_at(t)`` the
    ankles' (x, y, lift) [m]; ``steps`` the footsteps with their ``liftoff``
    and ``touchdown`` times [s]; ``stride()`` the (start, end) [s] of one
    stride (single then double support of the third step).
    """

    def __init__(self, params: GaitParameters | None = None, com_correction: ComCorrection | None = None):
        self.params = params or GaitParameters()
        self.com_correction = com_correction
        p = self.params
        self.w = p.omega
        self._build_footsteps()
        self._build_zmp_and_cog()

    # -- footsteps --------------------------------------------------------
    def _build_footsteps(self):
        p = self.params
        feet = {side: np.array(xy) for side, xy in initial_stance(p).items()}
        yaws = {side: 0.0 for side in SIDES}
        self.initial_feet = {k: v.copy() for k, v in feet.items()}
        self.initial_yaw = dict(yaws)
        self.steps = []  # dicts: swing, support, start/end xy, start/end yaw, liftoff, touchdown, step_end
        t = p.initial_shift_time
        for footstep in footstep_list(p):
            swing = footstep.side
            support = "left" if swing == "right" else "right"
            duration = p.step_time if math.isnan(footstep.duration) else footstep.duration
            target = np.array([footstep.x, footstep.y])
            single, double = duration * (1.0 - p.double_support_ratio), duration * p.double_support_ratio
            self.steps.append(
                dict(swing=swing, support=support, start=feet[swing].copy(), end=target,
                     start_yaw=yaws[swing], end_yaw=footstep.yaw, single=single, double=double,
                     liftoff=t, touchdown=t + single, step_end=t + duration)
            )
            feet[swing], yaws[swing] = target, footstep.yaw
            t += duration
        self.final_feet = feet
        self.final_yaw = yaws
        self.walk_start = p.initial_shift_time
        self.last_touchdown = self.steps[-1]["touchdown"]
        self.end_time = self.last_touchdown + p.final_shift_time
        self.turning = any(step["end_yaw"] != 0.0 for step in self.steps)

    # -- ZMP and COG -------------------------------------------------------
    def _build_zmp_and_cog(self):
        p = self.params
        mid0 = 0.5 * (self.initial_feet["left"] + self.initial_feet["right"])
        mid_end = 0.5 * (self.final_feet["left"] + self.final_feet["right"])
        self.trajectories = []
        for axis in (0, 1):
            durations, coeffs = [], []
            for i, step in enumerate(self.steps):
                zmp_xy = self._support_zmp(i)
                durations.append(step["single"])
                coeffs.append(np.array([zmp_xy[axis]]))
                if i + 1 < len(self.steps):
                    nxt = self._support_zmp(i + 1)
                    durations.append(step["double"])
                    coeffs.append(lipm.transition_coeffs(zmp_xy[axis], nxt[axis], step["double"]))
            first, last = self._support_zmp(0)[axis], self._support_zmp(len(self.steps) - 1)[axis]
            # the walk ends standing: its DCM reaches the feet's midpoint through the final shift's ZMP
            # transition (ended on the last support's ZMP, the COG would still run towards that ankle at the
            # last touchdown, and reversing it asks a ZMP outside the sole: 35 mm on the G1 and TALOS)
            settle = lipm.transition_coeffs(last, mid_end[axis], p.final_shift_time)
            dcm_needed = lipm.required_start_dcm(durations + [p.final_shift_time], coeffs + [settle],
                                                 mid_end[axis], self.w)
            base = np.eye(6)[0] * mid0[axis] + (first - mid0[axis]) * lipm.SMOOTHSTEP
            init = lipm.solve_bump_coeffs(
                base, [lipm.BUMP_A], p.initial_shift_time, mid0[axis], 0.0, self.w, [("dcm", dcm_needed)]
            )
            chain = lipm.LipmTrajectory.from_zmp(
                0.0, [p.initial_shift_time] + durations, [init] + coeffs, mid0[axis], 0.0, self.w
            )
            x_end, v_end = (float(a[0]) for a in chain.evaluate(chain.end_time)[:2])
            base = np.eye(6)[0] * last + (mid_end[axis] - last) * lipm.SMOOTHSTEP
            final = lipm.solve_bump_coeffs(
                base, [lipm.BUMP_A, lipm.BUMP_B], p.final_shift_time, x_end, v_end, self.w,
                [("x", mid_end[axis]), ("v", 0.0)],
            )
            hold = np.array([mid_end[axis]])
            traj = lipm.LipmTrajectory.from_zmp(
                0.0,
                [p.initial_shift_time] + durations + [p.final_shift_time, 1.0],
                [init] + coeffs + [final, hold],
                mid0[axis], 0.0, self.w, rest_tail=True,
            )
            self.trajectories.append(traj)

    def _support_zmp(self, i) -> np.ndarray:
        """The ZMP (x, y) of step ``i``'s single support: its support ankle, or ``zmp_offset`` ahead of it
        along the support foot's heading."""
        ankle = self._support_xy(i)
        offset = self.params.zmp_offset
        if offset == 0.0:
            return ankle
        side = self.steps[i]["support"]
        yaw = next((self.steps[j]["end_yaw"] for j in range(i - 1, -1, -1) if self.steps[j]["swing"] == side),
                   self.initial_yaw[side])
        return ankle + offset * np.array([math.cos(yaw), math.sin(yaw)])

    def _support_xy(self, i) -> np.ndarray:
        """Ankle xy of the support foot of step ``i`` (0-based)."""
        step = self.steps[i]
        side = step["support"]
        # the support foot last moved in the previous step (or never)
        for j in range(i - 1, -1, -1):
            if self.steps[j]["swing"] == side:
                return self.steps[j]["end"]
        return self.initial_feet[side]

    # -- queries -----------------------------------------------------------
    def stride(self, step_index: int = 2):
        """(start, end) of one full stride: lift-off of ``step_index`` to the next lift-off,
        single then double support (the sweeps and benchmarks use the third step)."""
        step = self.steps[step_index]
        return step["liftoff"], step["step_end"]

    def touchdown_com_offset(self, step_index: int) -> np.ndarray:
        """Step ``step_index``'s landing ankle less the COG at its touchdown (x, y) [m]; computed once
        per step (the planner asks on every solve: :func:`drake_estop.planning.landing.lateral_reach`)."""
        cache = self.__dict__.setdefault("_touchdown_com_offsets", {})
        if step_index not in cache:
            step = self.steps[step_index]
            cache[step_index] = np.asarray(step["end"], float)[:2] - self.com([step["touchdown"]])[0][0]
        return cache[step_index]

    def com(self, t):
        """COG x, y position, velocity, acceleration and ZMP at times ``t``: 4 arrays (n, 2)."""
        out = lipm.LipmTrajectory.evaluate_axes(self.trajectories, t)
        pos, vel, acc, zmp = (np.stack([out[0][i], out[1][i]], axis=-1) for i in range(4))
        if self.com_correction is not None:
            offset, rate, accel = self.com_correction.evaluate(t)
            pos, vel, acc = pos + offset, vel + rate, acc + accel
        return pos, vel, acc, zmp

    def feet_at(self, t: float):
        """Ankle positions (x, y, lift) and their velocities/accelerations at time ``t``."""
        p = self.params
        pos = {k: np.array([*v, 0.0]) for k, v in self.initial_feet.items()}
        vel = {k: np.zeros(3) for k in pos}
        acc = {k: np.zeros(3) for k in pos}
        for step in self.steps:
            side = step["swing"]
            if t >= step["touchdown"]:
                pos[side] = np.array([*step["end"], 0.0])
            elif t > step["liftoff"]:
                pos[side], vel[side], acc[side] = swing_foot(
                    step["start"], step["end"], t - step["liftoff"], step["single"], p.lift_height
                )
                break
            else:
                break
        return pos, vel, acc

    def feet_yaw_at(self, t: float):
        """Heading [rad] and its rate [rad/s] of each foot at ``t`` (the swing foot turns with a
        quintic smoothstep over the single support)."""
        yaw = dict(self.initial_yaw)
        rate = {side: 0.0 for side in SIDES}
        for step in self.steps:
            side = step["swing"]
            if t >= step["touchdown"]:
                yaw[side] = step["end_yaw"]
            elif t > step["liftoff"]:
                duration = step["single"]
                s = (t - step["liftoff"]) / duration
                turn = step["end_yaw"] - step["start_yaw"]
                yaw[side] = step["start_yaw"] + turn * float(lipm.poly_eval(lipm.SMOOTHSTEP, s))
                rate[side] = turn * float(lipm.poly_eval(lipm.SMOOTHSTEP, s, 1)) / duration
                break
            else:
                break
        return yaw, rate

    def upper_body(self, t):
        """Arm joint angles and rates (``params.arms.joints`` order) at ``t``: arm swing against the legs."""
        p = self.params
        phase = math.pi * (t - self.walk_start) / p.step_time
        envelope, envelope_rate = _window(t, self.walk_start - 0.5, self.walk_start,
                                          self.last_touchdown, self.end_time)
        swing = p.arm_swing * math.sin(phase)
        swing_rate = p.arm_swing * math.cos(phase) * math.pi / p.step_time
        sign = p.arms.gain_array
        q = p.arms.neutral_array + sign * swing * envelope
        qd = sign * (swing_rate * envelope + swing * envelope_rate)
        return q, qd

    def support_at(self, t: float):
        """('standing'|'double'|'single', step index, support side or None)."""
        if t <= 0.0 or t >= self.end_time:
            return "standing", -1, None
        if t < self.walk_start:
            return "double", 0, None
        for i, step in enumerate(self.steps):
            if t < step["touchdown"]:
                return ("single" if t >= step["liftoff"] else "double"), i, step["support"]
        return "double", len(self.steps), None

    def state(self, t: float) -> PatternState:
        axes = [traj.evaluate_at(float(t)) for traj in self.trajectories]
        pos, vel, zmp, rate, accel = (np.array([a[i] for a in axes]) for i in (0, 1, 3, 4, 5))
        if self.com_correction is not None:
            offset, velocity, _ = self.com_correction.evaluate(t)
            pos, vel = pos + offset[0], vel + velocity[0]
        support, index, side = self.support_at(t)
        feet, feet_vel, feet_acc = self.feet_at(t)
        next_landing, rear, landing_yaw = None, None, 0.0
        if support == "single":
            next_landing = self.steps[index]["end"].copy()
            landing_yaw = self.steps[index]["end_yaw"]
        elif support == "double" and 0 < index < len(self.steps):
            rear = self.steps[index - 1]["support"]
        elif support == "double" and index == 0:
            rear = None
        q, qd = self.upper_body(t)
        yaw, yaw_rate = self.feet_yaw_at(t)
        return PatternState(
            time=float(t), support=support, support_foot=side if support == "single" else None,
            com=pos, com_vel=vel, zmp=zmp, zmp_rate=rate, zmp_accel=accel,
            feet=feet, feet_vel=feet_vel, feet_acc=feet_acc, next_landing=next_landing,
            rear_foot=rear, step_index=index, upper_body=q, upper_body_rate=qd,
            feet_yaw=yaw, feet_yaw_rate=yaw_rate, next_landing_yaw=landing_yaw,
        )


def swing_foot(start_xy, end_xy, elapsed, duration, lift_height):
    """Swing ankle (x, y, lift): quintic smoothstep in xy, 64 s^3 (1-s)^3 apex profile in lift."""
    s = min(max(elapsed / duration, 0.0), 1.0)
    start_xy, end_xy = np.asarray(start_xy, float), np.asarray(end_xy, float)
    sigma = lipm.poly_eval(lipm.SMOOTHSTEP, s)
    dsigma = lipm.poly_eval(lipm.SMOOTHSTEP, s, 1) / duration
    ddsigma = lipm.poly_eval(lipm.SMOOTHSTEP, s, 2) / duration**2
    lift = 64.0 * lift_height * lipm.BUMP_A
    pos = np.array([*(start_xy + (end_xy - start_xy) * sigma), lipm.poly_eval(lift, s)])
    vel = np.array([*((end_xy - start_xy) * dsigma), lipm.poly_eval(lift, s, 1) / duration])
    acc = np.array([*((end_xy - start_xy) * ddsigma), lipm.poly_eval(lift, s, 2) / duration**2])
    return pos, vel, acc


def _window(t, rise_start, rise_end, fall_start, fall_end):
    """Smooth 0-1-0 envelope and its rate (quintic smoothstep edges)."""
    if t <= rise_start or t >= fall_end:
        return 0.0, 0.0
    if t < rise_end:
        d = rise_end - rise_start
        s = (t - rise_start) / d
        return float(lipm.poly_eval(lipm.SMOOTHSTEP, s)), float(lipm.poly_eval(lipm.SMOOTHSTEP, s, 1)) / d
    if t > fall_start:
        d = fall_end - fall_start
        s = (t - fall_start) / d
        return 1.0 - float(lipm.poly_eval(lipm.SMOOTHSTEP, s)), -float(lipm.poly_eval(lipm.SMOOTHSTEP, s, 1)) / d
    return 1.0, 0.0


# -- footstep lists -----------------------------------------------------------
def initial_stance(params: GaitParameters) -> dict:
    """Ankle (x, y) of each foot standing before the walk: heading 0, ``step_width`` apart."""
    half = params.step_width / 2
    return {"left": (0.0, half), "right": (0.0, -half)}


def footstep_list(params: GaitParameters) -> tuple:
    """The walk's footsteps: ``params.footsteps``, or the generated ones.

    Generated: the body frame advances by ``step_length`` per step in its heading halfway through
    the step's ``turn`` (an arc's chord) and turns by ``turn``; the swing foot lands
    ``step_width / 2`` beside it, heading with it. The last step closes the feet (no step_length).
    Without a turn the positions are ``k * step_length``, exactly the straight walk's.

    A side step (``side_step`` != 0) is a lateral walk: the leading foot, on the side of travel,
    swings first and steps out by ``|side_step|`` (the stance widens to ``step_width +
    |side_step|``), then the trailing foot closes it to ``step_width`` again, so the stance never
    narrows below ``step_width``. The body frame (the stance's midpoint) moves ``side_step / 2``
    sideways per step, ``side_step`` per stride; the last step closes the feet at ``step_width``.
    """
    if params.footsteps:
        return params.footsteps
    half, turn, n = params.step_width / 2, math.radians(params.turn), int(params.num_steps)
    # the foot on the side of travel; without a side step the right foot leads, as on a straight walk
    leading = "left" if params.side_step > 0.0 else "right"
    shift = 0.5 * params.side_step  # the stance midpoint's sideways advance per step
    x = y = heading = 0.0
    steps, swing, shifts = [], leading, 0
    for k in range(1, n + 1):
        closing = k == n  # the last step sets the feet step_width apart: no step_length, no turn
        # the leading foot widens the stance, the trailing one closes it: both move the midpoint
        sideways = shift if not closing or swing != leading else 0.0
        if turn == 0.0:
            if not closing:
                x = k * params.step_length
            shifts += sideways != 0.0
            y = shifts * shift
        elif not closing:
            chord = heading + 0.5 * turn
            x += params.step_length * math.cos(chord) - sideways * math.sin(chord)
            y += params.step_length * math.sin(chord) + sideways * math.cos(chord)
            heading += turn
        elif sideways:
            x -= sideways * math.sin(heading)
            y += sideways * math.cos(heading)
        offset = half if swing == "left" else -half
        if swing == leading and not closing:
            offset += shift  # out by side_step beyond the trailing foot's step_width / 2 (see above)
        foot_x = x - offset * math.sin(heading) if heading else x
        foot_y = y + offset * math.cos(heading) if heading else y + offset
        steps.append(Footstep(swing, foot_x, foot_y, heading))
        swing = "left" if swing == "right" else "right"
    return tuple(steps)


def _footstep(value, index: int) -> Footstep:
    """A :class:`Footstep` from a Footstep, a mapping or a (side, x, y[, yaw[, duration]]) sequence."""
    if isinstance(value, Footstep):
        fields = dict(side=value.side, x=value.x, y=value.y, yaw=value.yaw, duration=value.duration)
    elif isinstance(value, dict):
        fields = dict(value)
    else:
        fields = dict(zip(("side", "x", "y", "yaw", "duration"), value))
    name = f"footsteps[{index}]"
    if fields.get("side") not in SIDES:
        raise ValueError(f"{name}.side must be 'left' or 'right', got {fields.get('side')!r}")
    for key in ("x", "y", "yaw"):
        try:
            fields[key] = float(fields.get(key, 0.0 if key == "yaw" else math.nan))
        except (TypeError, ValueError):
            raise ValueError(f"{name}.{key} must be a number, got {fields.get(key)!r}") from None
        if not math.isfinite(fields[key]):
            raise ValueError(f"{name}.{key} must be finite, got {fields[key]!r}")
    duration = fields.get("duration", math.nan)
    duration = math.nan if duration is None or duration == "" else float(duration)
    if not math.isnan(duration) and not (math.isfinite(duration) and duration > 0):
        raise ValueError(f"{name}.duration must be positive (or empty), got {duration!r}")
    return Footstep(fields["side"], fields["x"], fields["y"], fields["yaw"], duration)


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def _separated(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two convex polygons (corners in order) are apart (separating-axis test)."""
    for poly in (a, b):
        edges = np.roll(poly, -1, axis=0) - poly
        for normal in np.stack([edges[:, 1], -edges[:, 0]], axis=1):
            if (a @ normal).max() < (b @ normal).min() or (b @ normal).max() < (a @ normal).min():
                return True
    return False


def check_footsteps(params: GaitParameters) -> None:
    """Raise ValueError (naming the field) if the walk's footsteps alternate badly, turn more than
    :data:`MAX_TURN_DEG` per step, or leave a stance whose soles cross or overlap."""
    explicit = bool(params.footsteps)
    field_name = "footsteps" if explicit else "step_width / side_step / turn"
    feet = {side: np.array(xy) for side, xy in initial_stance(params).items()}
    yaws = {side: 0.0 for side in SIDES}
    previous = None
    for i, step in enumerate(footstep_list(params)):
        where = f"footsteps[{i}]" if explicit else f"step {i + 1}"
        if explicit and previous == step.side:
            raise ValueError(f"{where}.side: the feet must alternate ({step.side!r} twice in a row)")
        support = "left" if step.side == "right" else "right"
        turn = math.degrees(abs(_wrap(step.yaw - yaws[support])))
        if turn > MAX_TURN_DEG + 1e-9:
            raise ValueError(f"{where}: turns {turn:.1f} deg from the support foot, beyond the limit of "
                             f"{MAX_TURN_DEG} deg ({'footsteps' if explicit else 'turn'})")
        feet[step.side], yaws[step.side] = np.array([step.x, step.y]), step.yaw
        corners = {side: params.sole.corners(feet[side], side, yaws[side]) for side in SIDES}
        if not _separated(corners["left"], corners["right"]):
            raise ValueError(f"{field_name}: the soles overlap at {where}")
        heading = math.atan2(math.sin(yaws["left"]) + math.sin(yaws["right"]),
                             math.cos(yaws["left"]) + math.cos(yaws["right"]))
        lateral = float((feet["left"] - feet["right"]) @ np.array([-math.sin(heading), math.cos(heading)]))
        if lateral <= 0.0:
            raise ValueError(f"{field_name}: the feet cross at {where} (left ankle {-lateral:.3f} m right "
                             f"of the right one)")
        previous = step.side


FOOTSTEP_COLUMNS = ("side", "x", "y", "yaw")  # required; "duration" is optional


def load_footsteps(path) -> tuple:
    """Footsteps from a CSV file with a header: ``side`` (left/right), ``x``, ``y`` [m], ``yaw``
    [rad] and an optional ``duration`` [s] (empty: the gait's step time), one row per step.

    Raises
    ------
    ValueError
        On a missing column, a non-numeric or NaN value, or a bad side (names the row and column).
    """
    import csv

    with open(path, newline="") as stream:
        reader = csv.DictReader(stream)
        header = [name.strip() for name in (reader.fieldnames or [])]
        missing = [name for name in FOOTSTEP_COLUMNS if name not in header]
        if missing:
            raise ValueError(f"footsteps file {path}: missing column(s) {', '.join(missing)} "
                             f"(needs {', '.join(FOOTSTEP_COLUMNS)}[, duration])")
        rows = [{key.strip(): (value or "").strip() for key, value in row.items() if key} for row in reader]
    if not rows:
        raise ValueError(f"footsteps file {path}: no rows")
    steps = []
    for i, row in enumerate(rows):
        try:
            steps.append(_footstep(row, i))
        except ValueError as error:
            raise ValueError(f"footsteps file {path}, row {i + 1}: {error}") from None
    return tuple(steps)
