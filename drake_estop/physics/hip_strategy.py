"""The hip strategy: the trunk bows into a fore-aft push to buy the stop time.

The stop plans the COG with the linear inverted pendulum (eq. 4), whose only control is the ZMP: once a
push sends the divergent component of motion (DCM, ``xi = x + x' / omega``) past the sole's toe, the ankle
can no longer hold it and the robot turns about that edge as one body until a foot lands. The centroidal
angular momentum ``L`` is the other control a humanoid has (Horak and Nashner's hip strategy; Stephens
2007; the centroidal moment pivot of Popovic et al. 2005):

    x'' = omega^2 (x - p) - L_y' / (m h)

so an upper body that accelerates forward about the hip (``L_y' > 0``) decelerates the COG as a ZMP
``L_y' / (m g)`` further ahead would, beyond the toe. The trunk's travel is short (the joint's range,
and the torso may tilt only so far), so the effect is an impulse: the return gives it back, later, when
the landing foot carries the robot. What it buys is time, while the ankle is saturated and the foot is in
the air (Pratt et al. 2006 count it as a flywheel in the capture region).

:class:`HipStrategy` sits between the stop planner and the whole-body IK. In the stop (the planner's
``mode`` past walking, before standing), when a push from behind is under way it bows the trunk's pitch joint forward by
``amplitude`` [rad] (within the joint's range and speed limit) along :func:`bow_profile`; the IK keeps the
whole-body COG on the plan, so the pelvis moves back as the trunk goes forward. A push is two things
measured along the feet's heading: the estimated DCM runs ahead of the reference's by more than
``trigger`` [m], and its rate exceeds the LIPM's divergence from the reference ZMP by more than
``min_rate`` [m/s] (:func:`push_rate`: an external force ``F`` adds ``F / (m omega)``, 0.6 m/s for 121 N on
the 58 kg robot; the CoP moving under the push takes part of it: measured when the deviation passed 4 cm,
0.33 m/s for a 17 N s push, 0.70-0.98 m/s for 30-35 N s ones). A deviation alone also follows a
re-plan's new reference, a rebound or a landing; the rate alone, the stop's own ZMP transfer. One bow at
a time; another may follow once it has returned. The bow counts in the torso's tilt (a fall criterion
past 0.26 rad). ``backward`` bows back as well, against a push from the front: off by default (the
default humanoid's trunk bows 0.087 rad back at most, and on the campaign its backward bows fired on
landing impacts, which brake the DCM as a push does, and lost runs).

Measured on the default humanoid, with it against without: a 30 N s forward push in double support
(3.55 s) stops in one recovery step, where without it two are taken and the rear sole slips 12.6 mm
(tests/test_online_pushes.py); a 35 N s one early in single support (2.95 s) stops without it in two steps
(the N-step capture, :func:`drake_estop.planning.capture_landing.capture_step`) and with it takes three, the rear
sole slipping and the CoP leaving its support. With ``benchmarks/robustness.py --controller-option
hip_strategy={}``: the sweep 40/40 and the matrix 44/44. Pushes sideways are not helped: the
default model's trunk has no roll joint. Off by default (``ControllerOptions.hip_strategy``): on the
campaign's first 120 runs it lost 2 that stop without it (forward bows after a sideways or a backward
push, when the robot ran forward on its own: runs 11 and 34, both falls) and gained 1.
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.systems.framework import EventStatus, LeafSystem

from drake_estop.planning import lipm
from drake_estop.systems.decision import StopMode
from drake_estop.systems.ik import quaternion_to_matrix, yaw_of
from drake_estop.timing import timed

#: The default humanoid's hip strategy: trigger [m], least push rate [m/s], amplitude [rad], rise / hold /
#: return times [s].
HIP_STRATEGY = {"trigger": 0.04, "min_rate": 0.6, "amplitude": 0.12, "rise_time": 0.2, "hold_time": 0.3,
                "return_time": 0.6, "backward": False}
#: Ticks over which the deviation's rate is measured (20 ms at the 5 ms servo tick).
RATE_TICKS = 4

_SMOOTHER_PEAK = float(lipm.poly_eval(lipm.SMOOTHSTEP, 0.5, 1))  # the smootherstep's largest slope, 1.875


def _smootherstep(s: float) -> tuple[float, float]:
    """:data:`~drake_estop.planning.lipm.SMOOTHSTEP` and its slope at ``s`` clipped to [0, 1] (zero slope
    and curvature at both ends: the bow starts and stops without a jerk in the joint's acceleration)."""
    s = min(max(s, 0.0), 1.0)
    return float(lipm.poly_eval(lipm.SMOOTHSTEP, s)), float(lipm.poly_eval(lipm.SMOOTHSTEP, s, 1))


def bow_profile(t: float, *, start: float, amplitude: float, rise_time: float, hold_time: float,
                return_time: float) -> tuple[float, float]:
    """The trunk's bow [rad] and its rate [rad/s] at ``t`` [s]: zero before ``start``, up to ``amplitude``
    over ``rise_time`` (smootherstep), held ``hold_time``, back to zero over ``return_time``; zero for a
    non-finite ``start`` (no bow)."""
    if not math.isfinite(start) or t <= start:
        return 0.0, 0.0
    up, up_rate = _smootherstep((t - start) / rise_time)
    down, down_rate = _smootherstep((t - start - rise_time - hold_time) / return_time)
    return amplitude * (up - down), amplitude * (up_rate / rise_time - down_rate / return_time)


def bow_duration(*, rise_time: float, hold_time: float, return_time: float, **_) -> float:
    """How long [s] one bow lasts."""
    return rise_time + hold_time + return_time


def push_rate(history, span: float, divergence: float) -> float:
    """The estimated DCM's rate [m/s] along the heading over ``span`` [s] (``history``: its positions [m],
    oldest first) less ``divergence`` [m/s], the LIPM's ``omega (xi - p)`` from the reference ZMP ``p``
    (eq. 6-9): what an external force adds, ``F / (m omega)``. NaN before the history is full."""
    return float((history[-1] - history[0]) / span - divergence)


def heading_of(*feet) -> np.ndarray:
    """The unit vector (xy) of the mean heading of sole poses ``[x, y, z, qw, qx, qy, qz]``."""
    total = np.zeros(2)
    for foot in feet:
        yaw = yaw_of(quaternion_to_matrix(foot[3:7]))
        total += (math.cos(yaw), math.sin(yaw))
    norm = float(np.linalg.norm(total))
    return total / norm if norm > 1e-9 else np.array([1.0, 0.0])


class HipStrategy(LeafSystem):
    """Bows the trunk into a fore-aft push in the stop (see the module docstring).

    .. pydrake_system::

        name: HipStrategy
        input_ports:
        - upper_body
        - com
        - com_vel
        - zmp
        - left_foot
        - right_foot
        - mode
        - measured_com
        - measured_com_vel
        output_ports:
        - upper_body
        - bow

    Ports:
      - ``upper_body`` in (n): the planner's upper-body joint targets [rad] (its layout's order).
      - ``com``, ``com_vel`` (3): the reference COG [m] and its velocity [m/s]; ``zmp`` (2): the
        reference ZMP [m]; ``left_foot``,
        ``right_foot`` (7): the reference soles ``[x, y, z, qw, qx, qy, qz]`` (their heading);
        ``mode`` (2): the planner's ``[StopMode, landings left]`` (the strategy acts in a stop, past
        ``WALKING`` and before ``STANDING``).
      - ``measured_com``, ``measured_com_vel`` (3): the estimated COG and its velocity.
      - ``upper_body`` out (n): the targets with the bow added to joint ``joint_index``.
      - ``bow`` (2): the bow [rad] and its rate [rad/s].

    State: the bow's start time (NaN: none yet) and signed amplitude [rad]; the estimated DCM along the
    heading over the last :data:`RATE_TICKS` ticks. The update (every ``servo_period``) starts a bow where
    none is under way, the DCM deviation along the heading exceeds ``trigger`` (ahead; behind too with
    ``backward``) and the push rate (:func:`push_rate`) that way exceeds ``min_rate``: ``amplitude``
    towards it, clipped to
    ``[lower, upper]`` less the planner's target (the joint's range; ``direction`` +1 where a positive
    angle bows forward, -1 where it bows back).

    Raises ``ValueError`` naming a non-positive ``trigger``, ``min_rate``, ``amplitude``, time or ``omega``, a
    negative ``hold_time``, a ``joint_index`` outside ``upper_body``, ``direction`` not +-1, or a bow faster than
    ``max_speed`` [rad/s] (``amplitude`` over ``rise_time`` or ``return_time``).
    """

    def __init__(self, *, upper_body_size: int, joint_index: int, omega: float, servo_period: float = 0.005,
                 direction: float = 1.0, lower: float = -math.inf, upper: float = math.inf,
                 max_speed: float = math.inf, trigger: float = HIP_STRATEGY["trigger"],
                 min_rate: float = HIP_STRATEGY["min_rate"],
                 amplitude: float = HIP_STRATEGY["amplitude"], rise_time: float = HIP_STRATEGY["rise_time"],
                 hold_time: float = HIP_STRATEGY["hold_time"], return_time: float = HIP_STRATEGY["return_time"],
                 backward: bool = HIP_STRATEGY["backward"], timer=None):
        super().__init__()
        for name, value in (("trigger", trigger), ("min_rate", min_rate), ("amplitude", amplitude),
                            ("rise_time", rise_time),
                            ("return_time", return_time), ("omega", omega), ("servo_period", servo_period)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive and finite, got {value!r}")
        if not (isinstance(hold_time, (int, float)) and math.isfinite(hold_time) and hold_time >= 0):
            raise ValueError(f"hold_time must be finite and non-negative [s], got {hold_time!r}")
        if not (isinstance(joint_index, int) and 0 <= joint_index < upper_body_size):
            raise ValueError(f"joint_index must index the {upper_body_size} upper-body joints, got {joint_index!r}")
        if direction not in (1.0, -1.0):
            raise ValueError(f"direction must be +1 or -1, got {direction!r}")
        for name, time in (("rise_time", rise_time), ("return_time", return_time)):
            if _SMOOTHER_PEAK * amplitude / time > max_speed:
                raise ValueError(f"{name} {time} s bows {amplitude} rad at {_SMOOTHER_PEAK * amplitude / time:.2f} "
                                 f"rad/s, past the joint's {max_speed} rad/s")
        self._profile = {"rise_time": float(rise_time), "hold_time": float(hold_time),
                         "return_time": float(return_time)}
        self._duration = bow_duration(**self._profile)
        self._joint, self._omega, self._direction = joint_index, float(omega), float(direction)
        self._lower, self._upper = float(lower), float(upper)
        self._trigger, self._amplitude = float(trigger), float(amplitude)
        self._min_rate, self._servo_period = float(min_rate), float(servo_period)
        self._backward = bool(backward)
        self.upper_body_in_port = self.DeclareVectorInputPort("upper_body", upper_body_size)
        self.com_port = self.DeclareVectorInputPort("com", 3)
        self.com_vel_port = self.DeclareVectorInputPort("com_vel", 3)
        self.zmp_port = self.DeclareVectorInputPort("zmp", 2)
        self.feet_ports = [self.DeclareVectorInputPort(f"{side}_foot", 7) for side in ("left", "right")]
        self.mode_port = self.DeclareVectorInputPort("mode", 2)
        self.measured_com_port = self.DeclareVectorInputPort("measured_com", 3)
        self.measured_com_vel_port = self.DeclareVectorInputPort("measured_com_vel", 3)
        self._bow_state = self.DeclareDiscreteState(np.array([math.nan, 0.0]))
        # the estimated DCM along the heading [m] at the last RATE_TICKS + 1 ticks, oldest first (NaN: none yet)
        self._history = self.DeclareDiscreteState(np.full(RATE_TICKS + 1, math.nan))
        self.upper_body_port = self.DeclareVectorOutputPort(
            "upper_body", upper_body_size, self._calc_upper_body,
            prerequisites_of_calc={self.upper_body_in_port.ticket(), self.xd_ticket(), self.time_ticket()})
        self.bow_port = self.DeclareVectorOutputPort(
            "bow", 2, self._calc_bow, prerequisites_of_calc={self.xd_ticket(), self.time_ticket()})
        self.DeclarePeriodicDiscreteUpdateEvent(servo_period, 0.0, timed(self._update, timer))

    def _dcm(self, context, com_port, com_vel_port) -> np.ndarray:
        return com_port.Eval(context)[:2] + com_vel_port.Eval(context)[:2] / self._omega

    def heading(self, context) -> np.ndarray:
        """The reference soles' mean heading (unit xy)."""
        return heading_of(*(port.Eval(context) for port in self.feet_ports))

    def deviation(self, context) -> float:
        """The estimated DCM ahead of the reference's [m] along the feet's heading (negative: behind)."""
        return self._deviation(context, self.heading(context),
                               self._dcm(context, self.measured_com_port, self.measured_com_vel_port))

    def _deviation(self, context, heading, dcm) -> float:
        value = float(heading @ (dcm - self._dcm(context, self.com_port, self.com_vel_port)))
        return value if math.isfinite(value) else 0.0

    def _update(self, context, discrete_state):
        heading = self.heading(context)
        dcm = self._dcm(context, self.measured_com_port, self.measured_com_vel_port)
        history = np.append(context.get_discrete_state(self._history).value()[1:], float(heading @ dcm))
        discrete_state.set_value(self._history, history)
        start, _ = context.get_discrete_state(self._bow_state).value()
        t = context.get_time()
        if math.isfinite(start) and t < start + self._duration - 1e-9:
            return EventStatus.Succeeded()  # a bow is under way
        mode = int(round(float(self.mode_port.Eval(context)[0])))
        deviation = self._deviation(context, heading, dcm)
        in_the_stop = StopMode.WALKING < mode < StopMode.STANDING
        if not in_the_stop or abs(deviation) <= self._trigger or (deviation < 0 and not self._backward):
            return EventStatus.Succeeded()
        push = push_rate(history, RATE_TICKS * self._servo_period,
                         self._omega * float(heading @ (dcm - self.zmp_port.Eval(context))))
        if not math.copysign(1.0, deviation) * push > self._min_rate:
            return EventStatus.Succeeded()  # a drift (a rebound, the walk's own error), not a push
        target = float(self.upper_body_in_port.Eval(context)[self._joint])
        amplitude = math.copysign(self._amplitude, deviation) * self._direction  # the joint's sign
        amplitude = min(max(amplitude, self._lower - target), self._upper - target)
        if abs(amplitude) >= 1e-3:  # (the joint's range may leave no bow that way)
            discrete_state.set_value(self._bow_state, np.array([t, amplitude]))
        return EventStatus.Succeeded()

    def bow(self, context) -> tuple[float, float]:
        """The bow [rad] and its rate [rad/s] at the context's time."""
        start, amplitude = context.get_discrete_state(self._bow_state).value()
        return bow_profile(context.get_time(), start=start, amplitude=amplitude, **self._profile)

    def _calc_upper_body(self, context, output):
        targets = np.array(self.upper_body_in_port.Eval(context), dtype=float)
        targets[self._joint] += self.bow(context)[0]
        output.SetFromVector(targets)

    def _calc_bow(self, context, output):
        output.SetFromVector(np.array(self.bow(context)))


def trunk_pitch_setup(plant, robot, layout) -> dict | None:
    """The :class:`HipStrategy` keywords of ``robot``'s ``trunk_pitch_joint`` on ``plant`` (its index in
    ``layout.upper_body``, the sign that bows forward, its range [rad] and speed limit [rad/s]); None where
    the robot names none."""
    name = robot.trunk_pitch_joint
    if name is None:
        return None
    joint = plant.GetJointByName(name)
    context = plant.CreateDefaultContext()
    frame = joint.frame_on_parent()
    axis = frame.CalcPoseInWorld(context).rotation().matrix() @ np.asarray(joint.revolute_axis(), float)
    return {"joint_index": layout.upper_body.index(name), "direction": 1.0 if axis[1] >= 0 else -1.0,
            "lower": float(joint.position_lower_limits()[0]), "upper": float(joint.position_upper_limits()[0]),
            "max_speed": float(joint.velocity_upper_limits()[0])}


def add_hip_strategy(builder, *, reference, estimator, plant, robot, layout, omega, servo_period, timer=None,
                     **settings):
    """A :class:`HipStrategy` for ``robot``'s trunk pitch joint on ``plant`` (None where the robot names
    none), fed ``reference``'s (the planner's) upper body, COG, feet and mode and ``estimator``'s COG.
    Its ``upper_body`` output goes to the IK (``connect_reference(..., upper_body=system)``)."""
    setup = trunk_pitch_setup(plant, robot, layout)
    if setup is None:
        return None
    system = builder.AddNamedSystem("hip_strategy", HipStrategy(
        upper_body_size=len(layout.upper_body), omega=omega, servo_period=servo_period, timer=timer,
        **setup, **settings))
    for name in ("upper_body", "com", "com_vel", "zmp", "left_foot", "right_foot", "mode"):
        builder.Connect(reference.GetOutputPort(name), system.GetInputPort(name))
    builder.Connect(estimator.com_port, system.measured_com_port)
    builder.Connect(estimator.com_vel_port, system.measured_com_vel_port)
    return system
