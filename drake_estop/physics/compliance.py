"""Foot-edge compliance: the stance ankles yield to the part of the ground moment that would roll a foot.

On stiff position servos a push is not absorbed by the body: the whole robot turns as one rigid
body about a sole edge (measured, 17 N s sideways early in single support: the stance foot rolled on
its outer edge for 0.5 s, its frame moved 1 cm, and the swing foot then landed 3 cm off its target
and the robot rocked from foot to foot). HRP-2's stabiliser (Kajita et al. 2010) puts a damping
controller on the ankles for this: the ankle angle moves with the measured foot moment.

Here the law acts only on the moment's part beyond a safe region of the sole (the sole shrunk by
``edge_margin``), so in the walk, with the centre of pressure inside that region, nothing changes.
(An ankle damping law on the whole moment towards the LIPM ZMP was tried earlier and made the walk
fall: the swing leg's momentum puts the multibody ZMP up to 12 cm off the LIPM's.) Per foot in
contact, with ``p`` its centre of pressure in the sole frame (from its force/torque sensor) and
``p_safe`` the nearest point of the safe region::

    m = (p - p_safe) x f_z                 # the moment that rolls the foot, sole frame
    d(offset)/dt = m / damping - offset / return_time

and ``offset`` (roll about the sole's x axis, pitch about its y axis) is added to the ankle roll and
pitch commands: the foot turns with the moment relative to the shin, so it stays flat and the body
above yields instead; the return term brings the ankles back to the IK's posture. A foot off the
ground only returns.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import EventStatus, LeafSystem

from drake_estop.robots.parameters import as_robot
from drake_estop.timing import timed


class FootEdgeCompliance(LeafSystem):
    """Adds ankle roll / pitch offsets to the servo command while a foot's CoP nears a sole edge.

    .. pydrake_system::

        name: FootEdgeCompliance
        input_ports:
        - q
        - foot_ft
        output_ports:
        - q
        - offsets

    Ports:
      - ``q`` in (nq): the IK's positions (the servo reference).
      - ``foot_ft`` (12): the soles' force/torque sensors, left then right, each ``[n, f]`` about the
        sole frame's origin in the sole frame (:class:`drake_estop.physics.sensors.FootForceTorqueSensors`
        through :class:`drake_estop.physics.sensors.RobotSensors`, so with the sensors' latency).
      - ``q`` out (nq): ``q`` with the offsets added to the ankle joints.
      - ``offsets`` (4): ``[left roll, left pitch, right roll, right pitch]`` [rad].

    Parameters (keyword-only): ``plant`` (the humanoid's MultibodyPlant), ``servo_period`` [s],
    ``edge_margin`` [m] (the safe region's inset from the sole edges), ``damping`` [N m s/rad],
    ``return_time`` [s], ``max_offset`` [rad], ``min_normal_force`` [N] (a foot below it is off the
    ground), ``timer`` (a :class:`drake_estop.timing.TickTimer`), ``robot`` (a
    :class:`~drake_estop.robots.RobotDescription`, a name or None: the default humanoid; its ankle
    joints and sole rectangles).
    """

    def __init__(self, *, plant, servo_period=0.005, edge_margin=0.02, damping=20.0, return_time=0.3,
                 max_offset=0.15, min_normal_force=50.0, timer=None, robot=None):
        super().__init__()
        robot = as_robot(robot)
        sole = robot.sole()  # the planner's rectangle: the smaller of the two feet's on each side
        for name, value in (("servo_period", servo_period), ("damping", damping), ("return_time", return_time),
                            ("max_offset", max_offset)):
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive, got {value!r}")
        if not (np.isfinite(edge_margin) and 0 <= edge_margin < sole.inner):
            raise ValueError(f"edge_margin must be in [0, {sole.inner}) m, got {edge_margin!r}")
        self._dt, self._damping, self._return, self._max = servo_period, damping, return_time, max_offset
        self._min_fz = float(min_normal_force)
        legs = [robot.leg(side) for side in ("left", "right")]
        self._ankles = np.array([[plant.GetJointByName(leg.ankle_roll).position_start(),
                                  plant.GetJointByName(leg.ankle_pitch).position_start()] for leg in legs])
        m = edge_margin  # safe region [x_low, x_high, y_low, y_high] per sole, left then right
        self._safe = np.array([[-sole.heel + m, sole.toe - m, -right + m, left - m]
                               for left, right in map(sole.lateral_edges, ("left", "right"))])
        nq = plant.num_positions()
        self.q_in_port = self.DeclareVectorInputPort("q", nq)
        self.foot_ft_port = self.DeclareVectorInputPort("foot_ft", 12)
        self._offsets = self.DeclareDiscreteState(4)
        self.q_port = self.DeclareVectorOutputPort(
            "q", nq, self._calc_q, prerequisites_of_calc={self.q_in_port.ticket(), self.xd_ticket()})
        self.offsets_port = self.DeclareStateOutputPort("offsets", self._offsets)
        self.DeclarePeriodicDiscreteUpdateEvent(servo_period, 0.0, timed(self._update, timer))

    def rolling_moments(self, context) -> np.ndarray:
        """``[left m_x, left m_y, right m_x, right m_y]`` [N m]: each sole's ground moment beyond its safe
        region, in the sole frame (zero for a foot off the ground)."""
        sensors = self.foot_ft_port.Eval(context).reshape(2, 6)
        out = np.zeros(4)
        for k in range(2):
            n_sole, f_sole = sensors[k, :3], sensors[k, 3:]  # about the sole origin, sole frame
            if f_sole[2] < self._min_fz:
                continue
            p = np.array([-n_sole[1] / f_sole[2], n_sole[0] / f_sole[2]])  # CoP on the sole plane
            x_low, x_high, y_low, y_high = self._safe[k]
            excess = p - np.array([np.clip(p[0], x_low, x_high), np.clip(p[1], y_low, y_high)])
            out[2 * k:2 * k + 2] = [excess[1] * f_sole[2], -excess[0] * f_sole[2]]  # (p - p_safe) x f_z
        return out

    def _update(self, context, discrete_state):
        offsets = context.get_discrete_state(self._offsets).value()
        rate = self.rolling_moments(context) / self._damping - offsets / self._return
        discrete_state.set_value(self._offsets, np.clip(offsets + self._dt * rate, -self._max, self._max))
        return EventStatus.Succeeded()

    def _calc_q(self, context, output):
        q = np.array(self.q_in_port.Eval(context))
        q[self._ankles.ravel()] += context.get_discrete_state(self._offsets).value()
        output.SetFromVector(q)


def add_foot_edge_compliance(builder, plant, sensors, ik, servo_period, *, timer=None, robot=None, **settings):
    """A :class:`FootEdgeCompliance` between ``ik.q_port`` and the servo targets, reading the feet's
    force/torque sensors from ``sensors`` (:class:`drake_estop.physics.sensors.RobotSensors`, e.g.
    ``estimator.sensors``). Returns the system (its ``q_port`` feeds the servo targets)."""
    compliance = builder.AddNamedSystem("foot_edge_compliance", FootEdgeCompliance(
        plant=plant, servo_period=servo_period, timer=timer, robot=robot, **settings))
    builder.Connect(ik.q_port, compliance.q_in_port)
    builder.Connect(sensors.foot_ft_port, compliance.foot_ft_port)
    return compliance
