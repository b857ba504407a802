"""The stop plan: parameters, the solved phase durations, and the plan the robot follows.

:class:`StopParameters` (weights and limits, defaults from the paper), :class:`PhaseSolution`
(phase durations and ZMP value of phases (i)-(iii)) and :class:`StopPlan` (COG, ZMP, feet,
crouch and upper body over time, eq. 32-33), the swing of the landing foot, the support
polygon of the soles, the servo grid (:func:`snap_to_tick`) and :class:`InfeasibleStop`.
Built by :func:`drake_estop.planning.planner.plan_stop`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from drake_estop.planning import lipm
from drake_estop.planning.gait import NominalPattern, PatternState
from drake_estop.planning.geometry import SupportPolygon

#: [s] an upper bound on signal-to-halt-end of any stop (two steps and the longest halt, re-plans
#: included): the simulations advance at most this far past the walk's end or the planned halt
LONGEST_STOP = 10.0

OBJECTIVES = ("paper", "time")
"""Values of :attr:`StopParameters.objective`."""

PHASES = ("walking", "landing", "transition", "slowdown", "halt", "stopped")
"""Phase labels; the planner's ``phase`` output port is an index into this tuple."""


@dataclass(frozen=True)
class StopParameters:
    """Weights and limits of the stop planner. Defaults reproduce the paper (V-VI).

    Attributes
    ----------
    a_ss, b_ss : float
        Weights of the mean swing speed [1/(m/s)^2] and the double-support
        time [1/s^2] in J_ss (eq. 24).
    a_ds, b_ds : float
        Weights of the ZMP displacement [1/m^2] and the double-support time
        [1/s^2] in J_ds (eq. 30).
    servo_period : float
        Control period [s]; phase boundaries fall on its ticks (HRP-2: 0.005).
    max_step_length, min_step_length : float
        Landing step from the support ankle, sagittal [m].
    min_landing_time, max_landing_time : float
        Time to touchdown [s].
    max_early_landing : float
        Single support: the landing no earlier than this before the nominal
        touchdown [s] (default inf: the paper's, as early as the other
        limits allow). Re-plans ignore it.
    max_landing_shift_per_height : float
        Single support: a swing foot coming down at height z above the floor
        lands at most z times this from its nominal landing point,
        sagittally [m/m] (default inf: the paper). A foot a few millimetres above the floor
        that is sent 7 cm further forward is dragged over the floor instead.
        Re-plans ignore it.
    min_transition_time, max_transition_time : float
        Double-support ZMP transition [s].
    min_slowdown_time, max_slowdown_time : float
        Slowdown phase [s].
    max_swing_speed : float
        Mean swing-ankle speed to the landing point [m/s].
    max_swing_descent_speed : float
        Fastest descent of the landing foot [m/s].
    max_swing_acceleration : float
        Re-plans before the landing: the landing no sooner than the landing
        swing can reach its point with at most this horizontal acceleration
        [m/s^2] (default inf: no limit).
    landing_approach_slope, landing_approach_height : float
        Landing swing: over its second half the foot stays at least
        ``landing_approach_slope`` times its horizontal distance to the
        landing point above the floor [m/m], up to ``landing_approach_height``
        [m] (default slope 0: the quintic alone).
    landing_approach_when_braking : bool
        The approach slope only on a re-planned landing swing whose landing
        ``max_swing_acceleration`` bounds (its ``StopPlan.braked_swing``);
        every other swing is the quintic alone (default False: the slope on
        every landing swing).
    zmp_margin : float
        ZMP distance kept from the sole edges [m].
    crouch : bool
        Lower the COG during the stop (IV.A).
    crouch_depth : float
        COG lowering [m].
    halt_durations : tuple of float
        Settle-segment candidates of the halt [s].
    quantisation : str
        "resolve" (re-solve the ZMP after snapping the phase times to ticks)
        or "round" (the paper's rounding).
    landing : str
        "replan" or "nominal" (keep the nominal footstep).
    objective : str
        "paper": J_ss / J_ds (eq. 24, 30), then the halt (eq. 27-28). "time": the
        paper's landing, then the shortest ZMP profile that brings the COG to rest
        at the feet's midpoint (:mod:`drake_estop.planning.brake`).
    landing_zmp_offset : float
        Single support: slowdown ZMP ahead of the landing ankle [m]. The one
        default that departs from the paper: 0.05 (the paper's eq. 20 is 0).
        The fore-leg reach that keeps the landing knee bent shortens the
        steps; with the slowdown ZMP at the ankle the COG then needs a long
        slowdown behind it. 5 cm ahead of the ankle, on the fore sole as the
        double-support stop's ZMP_max is (III.B), brings the median time to
        rest over the stride from 1.08 s to 0.85 s.
    max_fore_reach, max_rear_reach : float
        Leg reach from the COG to the landing / rear ankle [m].
    min_step_width, max_step_width : float
        Ankle-to-ankle widths [m] a landing moved sideways (the capture
        landing, the recovery step; :mod:`drake_estop.planning.capture`) may
        take: the soles clear of each other, the landing leg within its reach.
    recovery_step_inward : bool
        A re-plan's recovery step is taken while the DCM heads for the rear
        foot's side (past the fore sole's inner edge less the margin), landing
        wider (:func:`drake_estop.planning.replan.recovery_landing_width`);
        default False: no step there (a robot's measured choice).
    cost_tolerance : float
        Relative suboptimality of the interior-point solution (dimensionless).

    Raises
    ------
    ValueError
        On a non-physical value; the message names the field.
    """

    a_ss: float = 5.0  # weight of the mean swing speed in J_ss (eq. 24)
    b_ss: float = 1000.0  # weight of the double-support time in J_ss
    a_ds: float = 50.0  # weight of the ZMP displacement in J_ds (eq. 30)
    b_ds: float = 1000.0  # weight of the double-support time in J_ds
    servo_period: float = 0.005  # HRP-2 control period [s]
    max_step_length: float = 0.4  # [m] from the support ankle, sagittal
    min_step_length: float = 0.0  # [m] no stepping backwards
    min_landing_time: float = 0.1  # minimum time to touchdown [s]
    max_landing_time: float = 1.0
    # the landing no earlier than this before the nominal touchdown [s]; inf: as early as the other
    # limits allow (the paper). Re-plans (:func:`replan_stop`) ignore it: a push may need the early step
    max_early_landing: float = math.inf
    # a swing foot coming down at height z lands at most z * this from its nominal landing point [m/m];
    # inf: no limit (the paper). Re-plans ignore it
    max_landing_shift_per_height: float = math.inf
    min_transition_time: float = 0.1  # minimum double-support ZMP transition [s]
    max_transition_time: float = 0.8
    min_slowdown_time: float = 0.005
    max_slowdown_time: float = 1.5
    # mean swing-ankle speed to the landing point [m/s]; the quintic swing from rest peaks at 15/8
    # of it (2.1 m/s; the nominal swing peaks at 1.76). At 1.2 the hip and ankle pitch of the swing
    # leg went up to 5.2 rad/s against their 5 rad/s limit; 1.12 leaves every joint 4 % under its
    # limit over the stride (benchmarks/bench_joint_velocity.py)
    max_swing_speed: float = 1.12
    # fastest descent of the landing foot [m/s]: landing from swing height h takes at least
    # 15/8 h / this (the quintic's peak speed), so a foot caught high in the swing is not slammed
    # down while the landing leg is nearly straight (knee speed = leg-extension rate / sin(knee)).
    # The nominal swing descends at up to 0.27 m/s (64 h s^3 (1-s)^3 over the single support).
    max_swing_descent_speed: float = 0.30
    # re-plans before the landing: the landing no sooner than the swing from the foot's state to the plan's
    # landing point can get there with at most this horizontal acceleration [m/s^2] (inf: no limit; the
    # braked-landing option, physics.online.BRAKED_LANDING, uses 15). The nominal swing peaks at 9.6.
    # Measured on a 29 N s forward push at 2.95 s: a re-plan 0.175 s before the touchdown landed 50 ms
    # sooner and 4 cm further, a swing braking the foot from 1 m/s at up to 27 m/s^2; the servo lagged, the
    # foot struck the floor still moving at 0.8 m/s (2.4 kN) and the robot left the ground for 25 ms. An
    # ankle already accelerating harder than this gets no limit (planner.swing_braking_time)
    max_swing_acceleration: float = math.inf
    # the landing foot comes down no flatter than this slope [m/m] towards its landing point over the
    # second half of the swing, up to landing_approach_height above the floor; 0: the quintic alone. A
    # swing re-planned while the foot descends keeps its descent rate and skims the floor at 1-4 mm while
    # still moving 0.8 m/s forward: the sole caught the floor 60-90 ms early (2.3 kN, the robot airborne for
    # 40 ms, the rear foot slid 2.4 cm). The nominal swing lands at a slope of about 0.9. The height cap
    # (1 cm, about twice the servo's lag in height) keeps the bump from re-lifting a foot that must go far
    # sideways: capped at half the lift height (2.5 cm), a 17 N s push to the right slid the stance foot 12 mm
    landing_approach_slope: float = 0.0
    landing_approach_height: float = 0.01
    # the approach slope only for a re-planned landing swing whose landing the braking limit bounds (the
    # plan's braked_swing); other swings (the signal's plan, unbounded re-plans) are the quintic alone
    landing_approach_when_braking: bool = False
    zmp_margin: float = 0.01  # ZMP distance kept from the sole edges [m]
    crouch: bool = True
    crouch_depth: float = 0.04  # COG lowering during the stop [m] (IV.A)
    # settle-segment candidates [s], shortest first: the halt takes the shortest whose ZMP keeps zmp_margin
    halt_durations: tuple = (0.15, 0.2, 0.25, 0.3, 0.4, 0.5, 0.6, 0.8, 1.0, 1.2, 1.5)
    quantisation: str = "resolve"  # or "round": snap times, keep the continuous ZMP value
    landing: str = "replan"  # or "nominal": keep the nominal footstep ("finish the step" baseline)
    # "paper": J_ss / J_ds (eq. 24, 30), slowdown and halt; "time": the paper's landing, then the shortest
    # brake to rest at the feet's midpoint (planning/brake.py)
    objective: str = "paper"
    # single support: slowdown ZMP ahead of the landing ankle [m]; 0 is the paper's eq. 20, up to
    # toe - zmp_margin lets the ZMP use the fore sole as the double-support stop does (III.B). 5 cm: the
    # docstring says why
    landing_zmp_offset: float = 0.05
    # leg reach: horizontal distance from the COG to the landing ankle at touchdown (fore) and to
    # the rear ankle where the COG comes to rest (rear) [m]. Measured with the whole-body IK on
    # models/humanoid.urdf at the walking COG height 0.814 m (0.245 and 0.26; a 4 cm crouch adds
    # about 5 cm); beyond them a knee is stretched straight. Conservative: the crouch is ignored.
    # The fore reach keeps the landing knee bent at touchdown: at 0.22 the knee landed straight,
    # where the knee speed (leg-extension rate / sin(knee)) is unbounded, and the IK drove it at
    # up to 26 rad/s against its 6 rad/s limit; 0.195 lands it bent by 0.4 rad or more.
    max_fore_reach: float = 0.195
    max_rear_reach: float = 0.26
    # landing widths, ankle to ankle [m], for a landing moved sideways (planning/capture.py): 4 cm between
    # the soles' inner edges (0.055 m each), and the widest the whole-body IK lands with the hip roll
    # within its limit (models/humanoid.urdf)
    min_step_width: float = 0.15
    max_step_width: float = 0.30
    # a recovery step with the DCM heading for the rear foot's side (landing wider); off on the default
    # humanoid: on its campaign such steps lost runs that stood without them (planning/replan.py)
    recovery_step_inward: bool = False
    cost_tolerance: float = 1e-6  # relative suboptimality of the interior-point solution

    def __post_init__(self):
        for name in ("a_ss", "b_ss", "a_ds", "b_ds", "servo_period", "max_step_length",
                     "min_landing_time", "max_landing_time", "min_transition_time",
                     "max_transition_time", "min_slowdown_time", "max_slowdown_time",
                     "max_swing_speed", "cost_tolerance", "max_fore_reach", "max_rear_reach",
                     "max_swing_descent_speed", "min_step_width", "max_step_width"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")
        for low, high in (("min_landing_time", "max_landing_time"),
                          ("min_transition_time", "max_transition_time"),
                          ("min_slowdown_time", "max_slowdown_time"),
                          ("min_step_length", "max_step_length"),
                          ("min_step_width", "max_step_width")):
            if getattr(self, low) >= getattr(self, high):
                raise ValueError(f"{low} must be below {high}")
        slope = self.landing_approach_slope
        if not (isinstance(slope, (int, float)) and math.isfinite(slope) and slope >= 0):
            raise ValueError(f"landing_approach_slope must be a finite number >= 0, got {slope!r}")
        for name in ("landing_approach_height", "max_swing_acceleration"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and not math.isnan(value) and value > 0):
                raise ValueError(f"{name} must be > 0 (max_swing_acceleration: inf for no limit), got {value!r}")
        if not isinstance(self.recovery_step_inward, bool):
            raise ValueError(f"recovery_step_inward must be a bool, got {self.recovery_step_inward!r}")
        if not isinstance(self.landing_approach_when_braking, bool):
            raise ValueError("landing_approach_when_braking must be a bool, "
                             f"got {self.landing_approach_when_braking!r}")
        if not math.isfinite(self.landing_approach_height):
            raise ValueError(f"landing_approach_height must be finite, got {self.landing_approach_height!r}")
        if not (isinstance(self.max_early_landing, (int, float)) and self.max_early_landing >= 0):
            raise ValueError(f"max_early_landing must be >= 0 (inf for no limit), got {self.max_early_landing!r}")
        if not (isinstance(self.max_landing_shift_per_height, (int, float))
                and self.max_landing_shift_per_height > 0):
            raise ValueError("max_landing_shift_per_height must be > 0 (inf for no limit), "
                             f"got {self.max_landing_shift_per_height!r}")
        if self.zmp_margin < 0 or self.crouch_depth < 0:
            raise ValueError("zmp_margin and crouch_depth must be >= 0")
        if self.quantisation not in ("resolve", "round"):
            raise ValueError(f"quantisation must be 'resolve' or 'round', got {self.quantisation!r}")
        if self.landing not in ("replan", "nominal"):
            raise ValueError(f"landing must be 'replan' or 'nominal', got {self.landing!r}")
        if self.objective not in OBJECTIVES:
            raise ValueError(f"objective must be 'paper' or 'time', got {self.objective!r}")
        if not self.halt_durations or min(self.halt_durations) <= 0:
            raise ValueError("halt_durations must be positive")


@dataclass
class PhaseSolution:
    """Solved durations and ZMP value of phases (i)-(iii)."""

    landing: float
    transition: float
    slowdown: float
    target: float  # Z relative to the start ZMP: step length (single) or ZMP_max (double)
    cost: float
    iterations: int
    continuous: tuple  # durations and target before quantisation


@dataclass
class StopPlan:
    """A planned stop. Times are absolute, in seconds on the pattern's clock.

    Attributes
    ----------
    signal_time : float
        Servo tick of the stop signal [s].
    start_time : float
        Where the stop motion leaves the nominal pattern [s].
    case : str
        "one-step", "next-step" (III.C), "standing" or "already-stopping".
    support : str
        Support at the signal: "single", "double" or "standing".
    landing_time, transition_end, slowdown_end, halt_end : float
        Ends of the four phases [s]. With ``objective="time"`` the last three
        are the joints of the brake (:mod:`drake_estop.planning.brake`): the ZMP
        moves from the rear foot (or the walk's ZMP) to the first brake point
        (transition), brakes the COG between the two brake points (slowdown,
        the COG still moves at its end) and returns to the midpoint as the COG
        arrives there at rest (halt).
    step_length : float or None
        Single-support stops: the landing step from the support ankle [m].
    zmp_max : float or None
        Double-support stops: the ZMP displacement from the start [m].
    landing_foot : str or None
        "left" or "right".
    final_feet : dict
        Side -> ankle (x, y) at rest [m].
    final_yaw : dict
        Side -> foot heading at rest [rad] (the landing foot keeps its nominal heading).
    heading : float
        Heading [rad] of the frame the phase parameters were solved in: the
        landing foot's (single support) or the fore foot's (double support);
        the step length and ZMP_max are measured along it.
    recovery_step : bool
        A re-plan's step of the rear foot out of a double-support stop
        (:func:`drake_estop.planning.replan.replan_stop`).
    next_step : StopPlan or None
        A capture landing that does not stop the robot on its own (N-step capture,
        :func:`drake_estop.planning.capture_landing.capture_step`): the recovery step planned from its touchdown,
        whose COG and ZMP this plan follows after the landing; the online controller re-plans there
        from the measured state and takes this one where that finds no stop.
    capture_landing : bool
        A re-plan's landing made sooner, at the widest step, for a lateral DCM that would pass it before
        the touchdown (:func:`drake_estop.planning.replan.replan_stop`).
    late_since : float or None
        A stop re-timed because its landing sole carried no weight by the touchdown
        (:func:`drake_estop.planning.late_landing.late_landing_stop`): the first touchdown it missed [s].
    min_zmp_margin : float
        Smallest ZMP distance inside the support polygon [m].
    compute_time : float
        Wall-clock time of the plan [s].

    Notes
    -----
    ``com(times)`` returns the COG position [m], velocity [m/s],
    acceleration [m/s^2] and ZMP [m] (each (n, 2)); ``phase(t)`` the phase
    label; ``polygon(t)`` the support polygon; ``summary()`` a JSON-ready dict.
    """

    signal_time: float
    start_time: float  # where the stop motion leaves the nominal pattern
    case: str  # "one-step", "next-step", "standing", "already-stopping"
    support: str  # support at the signal: "single", "double" or "standing"
    start_support: str  # support where the planned motion starts
    landing_time: float
    transition_end: float
    slowdown_end: float
    halt_end: float
    step_length: float | None  # single-support stops: sagittal, from the support ankle
    zmp_max: float | None  # double-support stops: ZMP displacement from the start
    landing_foot: str | None
    landing_position: np.ndarray | None
    final_feet: dict
    x: lipm.LipmTrajectory | None
    y: lipm.LipmTrajectory | None
    pattern: NominalPattern
    params: StopParameters
    start_state: PatternState
    newton_iterations: int = 0
    compute_time: float = 0.0
    solve_time: float = 0.0
    cost: float = float("nan")
    min_zmp_margin: float = float("nan")
    upper_body_peak: np.ndarray | None = None  # eq. 33
    swing_start: dict = field(default_factory=dict)
    continuous_solution: tuple | None = None
    crouch_window: tuple | None = None  # (start, end): a re-plan keeps the crouch of the plan it replaces
    final_yaw: dict = field(default_factory=lambda: {"left": 0.0, "right": 0.0})  # side -> heading at rest [rad]
    heading: float = 0.0  # [rad] the frame the stop was solved in (the fore foot's heading)
    recovery_step: bool = False  # a re-plan's step out of a double-support stop (planner.replan_stop)
    # a capture landing that does not stop on its own: the recovery step planned from its touchdown
    # (capture_landing.capture_step), which the controller takes there (re-planned from the measured state first)
    next_step: StopPlan | None = None
    capture_landing: bool = False  # a re-plan's landing hurried by a sideways push (replan.replan_stop)
    crossover: bool = False  # a re-plan's landing across the support foot (crossover.crossover_stop)
    braked_swing: bool = False  # a re-plan whose landing the braking limit (max_swing_acceleration) bounds
    # a stop re-timed for a landing sole that carried no weight by the touchdown (late_landing.late_landing_stop):
    # the first touchdown it missed [s]; None: landing on its own time
    late_since: float | None = None
    # (key, polynomials) of the landing swing (_swing_polynomials); not copied by dataclasses.replace
    _swing_cache: tuple | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def walk_landings(self) -> list:
        """The walk's own landings between the signal and the plan's start: ``{"time", "foot", "kind": "walk"}``."""
        return [{"time": float(step["touchdown"]), "foot": step["swing"], "kind": "walk"}
                for step in self.pattern.steps if self.signal_time < step["touchdown"] <= self.start_time + 1e-9]

    @property
    def stop_landing(self) -> dict | None:
        """The stop's own landing ``{"time", "foot", "kind"}`` (kind: :attr:`step_kind`), and ``"late_since"``
        (the touchdown it missed [s]) for a re-timed landing; None without one."""
        if self.landing_foot is None:
            return None
        landing = {"time": float(self.landing_time), "foot": self.landing_foot, "kind": self.step_kind}
        if self.late_since is not None:
            landing["late_since"] = float(self.late_since)
        return landing

    @property
    def landings(self) -> list:
        """Every landing between the signal and rest and why: the walk's own, then the stop's."""
        return self.walk_landings + ([self.stop_landing] if self.landing_foot is not None else [])

    @property
    def steps_after_signal(self) -> int:
        """Foot landings between the signal and rest (nominal ones included)."""
        return len(self.landings)

    @property
    def step_kind(self) -> str | None:
        """Why this plan's landing is made (None without one): ``"recovery step"``, ``"capture landing"``
        or ``"stop landing"`` (the paper's)."""
        if self.landing_foot is None:
            return None
        if self.crossover:
            return "crossover step"
        return "recovery step" if self.recovery_step else "capture landing" if self.capture_landing else "stop landing"

    # -- evaluation -----------------------------------------------------
    def phase(self, t: float) -> str:
        if t < self.signal_time - 1e-9:
            return "walking"
        if self.case == "standing" or t >= self.halt_end:
            return "stopped"
        if t < self.start_time:
            return "landing"  # finishing the nominal step (marginal case)
        if t < self.landing_time:
            return "landing"
        if t < self.transition_end:
            return "transition"
        if t < self.slowdown_end:
            return "slowdown"
        return "halt"

    def com(self, times):
        """COG xy position, velocity, acceleration and ZMP, (n, 2) each, nominal before the start."""
        times = np.atleast_1d(np.asarray(times, float))
        out = [np.zeros((len(times), 2)) for _ in range(4)]
        before = times < self.start_time
        if np.any(before) or self.x is None:
            nominal = self.pattern.com(times)
            for o, n in zip(out, nominal):
                o[:] = n
        if self.x is not None and np.any(~before):
            for axis, values in enumerate(lipm.LipmTrajectory.evaluate_axes((self.x, self.y), times[~before])):
                for o, v in zip(out, values):
                    o[~before, axis] = v
        return tuple(out)

    def com_height(self, times):
        """COG height, vertical velocity and acceleration: quintic crouch (IV.A)."""
        times = np.atleast_1d(np.asarray(times, float))
        z0 = self.pattern.params.com_height
        moving = self.x is not None and self.case != "standing"
        depth = self.params.crouch_depth if (self.params.crouch and moving) else 0.0
        if depth == 0.0:
            zeros = np.zeros_like(times)
            return z0 + zeros, zeros, zeros.copy()
        start, end = self.crouch_window or (self.start_time, self.halt_end)
        duration = end - start
        if times.shape == (1,):  # one instant (every servo tick): plain floats, the same bits
            t = float(times[0])
            s = min(max((t - start) / duration, 0.0), 1.0)
            inside = 1.0 if start < t < end else 0.0
        else:
            s = np.clip((times - start) / duration, 0.0, 1.0)
            inside = (times > start) & (times < end)
        z = z0 - depth * lipm.poly_eval(lipm.SMOOTHSTEP, s)
        zd = -depth * lipm.poly_eval(lipm.SMOOTHSTEP, s, 1) / duration * inside
        zdd = -depth * lipm.poly_eval(lipm.SMOOTHSTEP, s, 2) / duration**2 * inside
        return np.atleast_1d(z), np.atleast_1d(zd), np.atleast_1d(zdd)

    def feet(self, t: float):
        """Ankle (x, y, lift) of each foot at ``t``."""
        if t < self.start_time or self.x is None:
            return self.pattern.feet_at(t)[0]
        feet = {side: np.array([*xy[:2], 0.0]) for side, xy in self.final_feet.items()}
        if self.landing_foot is not None and t < self.landing_time:
            duration = self.landing_time - self.start_time
            s = min(max((t - self.start_time) / duration, 0.0), 1.0)
            feet[self.landing_foot] = np.array([float(lipm.poly_eval(u, s)) for u in self._swing_polynomials()])
        return feet

    @property
    def _approach_slope(self) -> float:
        """The landing swing's approach slope: ``params.landing_approach_slope``, or 0 for a swing whose
        landing the braking limit does not bound when ``params.landing_approach_when_braking``."""
        if self.params.landing_approach_when_braking and not self.braked_swing:
            return 0.0
        return self.params.landing_approach_slope

    def _swing_polynomials(self) -> list:
        """:func:`landing_swing_polynomials` of this plan's landing swing, computed once (cached)."""
        s = self.swing_start  # the key holds the values (not the objects' ids, which a new object may reuse)
        key = (self.start_time, self.landing_time, *np.ravel(self.landing_position), *np.ravel(s["pos"]),
               *np.ravel(s["vel"]), *np.ravel(s["acc"]), s.get("clearance"), self._approach_slope,
               self.params.landing_approach_height, self.pattern.params.lift_height, s.get("cross_delay"))
        if self._swing_cache is None or self._swing_cache[0] != key:
            self._swing_cache = key, landing_swing_polynomials(
                s["pos"], s["vel"], s["acc"], self.landing_position, self.landing_time - self.start_time,
                self.pattern.params.lift_height, s.get("clearance"), self._approach_slope,
                self.params.landing_approach_height, s.get("cross_delay"))
        return self._swing_cache[1]

    def feet_yaw(self, t: float):
        """Heading [rad] and heading rate [rad/s] of each foot at ``t``: the landing foot turns
        from its heading (and heading rate) at the plan start to ``final_yaw``, at rest, over the
        landing phase."""
        if t < self.start_time or self.x is None:
            return self.pattern.feet_yaw_at(t)
        yaw, rate = dict(self.final_yaw), {side: 0.0 for side in self.final_yaw}
        if self.landing_foot is not None and t < self.landing_time:
            # quintic Hermite from the swing foot's heading and heading rate at the start to rest
            start = self.start_state.feet_yaw[self.landing_foot]
            start_rate = self.start_state.feet_yaw_rate[self.landing_foot]
            duration = self.landing_time - self.start_time
            s = (t - self.start_time) / duration
            shape = ((self.final_yaw[self.landing_foot] - start) * lipm.SMOOTHSTEP
                     + start_rate * duration * lipm.HERMITE_D1)
            yaw[self.landing_foot] = start + float(lipm.poly_eval(shape, s))
            rate[self.landing_foot] = float(lipm.poly_eval(shape, s, 1)) / duration
        return yaw, rate

    def upper_body(self, t: float):
        """Arm joints: cubic slowdown (eq. 32) to ``slowdown_end``, then quintic halt to neutral."""
        if t < self.start_time or self.x is None:
            return self.pattern.upper_body(t)
        q0, qd0 = self.start_state.upper_body, self.start_state.upper_body_rate
        if self.case == "standing":
            return q0.copy(), np.zeros_like(q0)
        span = self.slowdown_end - self.start_time
        if t <= self.slowdown_end:
            tau = t - self.start_time
            q = q0 + qd0 * tau - qd0 / span * tau**2 + qd0 / (3 * span**2) * tau**3  # eq. 32
            qd = qd0 * (1.0 - tau / span) ** 2
            return q, qd
        peak, neutral = self.upper_body_peak, self.pattern.params.arms.neutral_array
        s = min((t - self.slowdown_end) / (self.halt_end - self.slowdown_end), 1.0)
        sigma = float(lipm.poly_eval(lipm.SMOOTHSTEP, s))
        dsigma = float(lipm.poly_eval(lipm.SMOOTHSTEP, s, 1)) / (self.halt_end - self.slowdown_end)
        return peak + (neutral - peak) * sigma, (neutral - peak) * dsigma

    def support_sides(self, t: float, feet=None) -> list:
        """Feet on the ground at ``t`` ('left'/'right'); ``feet`` from :meth:`feet` if given."""
        feet = self.feet(t) if feet is None else feet
        on_ground = [side for side, p in feet.items() if p[2] <= 1e-9]
        if t < self.start_time:
            support, _, side = self.pattern.support_at(t)
            if support == "single":
                on_ground = [side]
        elif self.landing_foot is not None and t < self.landing_time:
            on_ground = [s for s in feet if s != self.landing_foot]
        return on_ground

    def polygon(self, t: float) -> SupportPolygon:
        """Support polygon at ``t`` (soles on the ground)."""
        feet = self.feet(t)
        yaw = self.feet_yaw(t)[0]
        return soles_polygon(self.pattern.params.sole,
                             tuple((s, float(feet[s][0]), float(feet[s][1]), float(yaw[s]))
                                   for s in self.support_sides(t, feet)))

    def summary(self) -> dict:
        sole = self.pattern.params.sole
        return {
            "estop_time": self.signal_time,
            "support": self.support,
            "case": self.case,
            "steps_after_signal": self.steps_after_signal,
            # each landing after the signal and why: the walk's own before the stop starts, then the stop's
            "steps": self.landings,
            "plan_start_time": self.start_time,
            "phase_times": {
                "landing_end": self.landing_time,
                "transition_end": self.transition_end,
                "slowdown_end": self.slowdown_end,
                "halt_end": self.halt_end,
            },
            "step_length": self.step_length,
            "zmp_max": self.zmp_max,
            "landing_foot": self.landing_foot,
            "landing_position": None if self.landing_position is None else list(map(float, self.landing_position)),
            "final_feet": {k: [float(v[0]), float(v[1]), float(self.final_yaw[k])] for k, v in self.final_feet.items()},
            "sole": {"toe": sole.toe, "heel": sole.heel, "inner": sole.inner, "outer": sole.outer},
            "newton_iterations": self.newton_iterations,
            "plan_compute_time_s": self.compute_time,
            "parameter_solve_time_s": self.solve_time,
            "cost": self.cost,
            "min_zmp_margin_m": self.min_zmp_margin,
            "upper_body_peak_rad": None if self.upper_body_peak is None else list(map(float, self.upper_body_peak)),
            "crouch": bool(self.params.crouch),
            "servo_period": self.params.servo_period,
        }


@functools.lru_cache(maxsize=512)
def soles_polygon(sole, feet: tuple) -> SupportPolygon:
    """Support polygon of the soles ``feet`` = ((side, ankle x, ankle y[, yaw]), ...) [m, rad];
    cached, since the same footholds recur from plan to plan."""
    return SupportPolygon(np.vstack([sole.corners(foot[1:3], foot[0], foot[3] if len(foot) > 3 else 0.0)
                                     for foot in feet]))


class InfeasibleStop(Exception):
    """No stop satisfies the planner's limits from this state.

    The message names the limit that made the stop infeasible.
    """


def landing_swing(pos, vel, acc, target_xy, elapsed, duration, lift_height, clearance=None, approach_slope=0.0,
                  approach_height=0.01):
    """Swing ankle from its current state to the landing point, at rest, over ``duration``.

    Quintic Hermite per axis (zero velocity and acceleration at touchdown); the
    lift gets an extra apex bump when the Hermite part alone would dip below
    the floor, and a clearance bump when the foot is leaving the floor (low and
    not descending). A foot already coming down is not lifted again: that
    re-lift, squeezed into the last 0.1 s before touchdown, drove the landing
    knee at up to 15 rad/s (its limit is 6). ``clearance`` [m], if given, is
    the bump's apex above the Hermite part instead (a recovery step lifted
    from the floor, :func:`drake_estop.planning.replan.replan_stop`).
    ``approach_slope`` [m/m] (:attr:`StopParameters.landing_approach_slope`):
    over the second half of the swing the bump also keeps the foot at least
    this times its horizontal distance to the landing point above the floor,
    up to ``approach_height`` [m], so that it comes down onto the landing
    point instead of skimming the floor towards it.
    """
    unit = landing_swing_polynomials(pos, vel, acc, target_xy, duration, lift_height, clearance, approach_slope,
                                     approach_height)
    s = min(max(elapsed / duration, 0.0), 1.0)
    return np.array([float(lipm.poly_eval(u, s)) for u in unit])


#: normalised swing time on which the landing swing is checked (its lowest point, the braking limit)
SWING_GRID = np.linspace(0, 1, 41)
_APPROACH_GRID = SWING_GRID[20:-1]  # the second half, touchdown left out (there both sides are 0)
_BUMP = 64.0 * lipm.pad(lipm.BUMP_A)  # s^3 (1 - s)^3, 1 at s = 1/2
_BUMP_ON_APPROACH = lipm.poly_eval(_BUMP, _APPROACH_GRID)


def landing_swing_polynomials(pos, vel, acc, target_xy, duration, lift_height, clearance=None,
                              approach_slope=0.0, approach_height=0.01, cross_delay=None) -> list:
    """The x, y and lift polynomials of :func:`landing_swing` in the normalised time ``s`` in [0, 1]
    (coefficients, lowest order first). ``cross_delay`` (a crossover step's,
    :func:`drake_estop.planning.crossover.crossover_delay`) moves the foot across later: the lateral shape
    ``LATE_LATERAL[cross_delay]`` instead of the quintic's."""
    target = np.array([target_xy[0], target_xy[1], 0.0])
    unit = [
        np.eye(6)[0] * pos[i] + (target[i] - pos[i]) * lipm.SMOOTHSTEP
        + vel[i] * duration * lipm.HERMITE_D1 + acc[i] * duration**2 * lipm.HERMITE_D2
        for i in range(3)
    ]
    if cross_delay is not None:
        from drake_estop.planning.crossover import LATE_LATERAL
        shape = LATE_LATERAL[cross_delay]
        unit[1] = lipm.pad(unit[1] - (target[1] - pos[1]) * lipm.SMOOTHSTEP, len(shape)) + (target[1] - pos[1]) * shape
    lowest = float(np.min(lipm.poly_eval(unit[2], SWING_GRID)))
    leaving = pos[2] < 0.5 * lift_height and vel[2] >= -1e-9
    apex = max(0.0, min(lift_height, 0.5 * lift_height - lowest)) if leaving else max(0.0, -lowest)
    if clearance is not None:
        apex = max(apex, float(clearance) - max(lowest, 0.0))
    # _BUMP, written as before it existed: the default's foot targets stay the same to the last bit
    unit[2] = lipm.pad(unit[2]) + 64.0 * apex * lipm.pad(lipm.BUMP_A)
    if approach_slope > 0:
        distance = np.hypot(lipm.poly_eval(unit[0], _APPROACH_GRID) - target[0],
                            lipm.poly_eval(unit[1], _APPROACH_GRID) - target[1])
        wanted = np.minimum(approach_slope * distance, approach_height)
        extra = float(np.max((wanted - lipm.poly_eval(unit[2], _APPROACH_GRID)) / _BUMP_ON_APPROACH))
        if extra > 0:
            unit[2] = unit[2] + extra * _BUMP
    return unit


def snap_to_tick(t: float, servo_period: float) -> float:
    """The servo tick at or after ``t`` (the stop is sampled by the servo loop)."""
    return math.ceil(t / servo_period - 1e-9) * servo_period
