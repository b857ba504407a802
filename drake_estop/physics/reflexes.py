"""The online controller's reflexes as typed configuration, and the one function that wires them.

A reflex acts between the stop planner and the servos, on the measured state, at the servo tick: the swing
foot turned against the body's tilt, the soles' heights sharing the load in double support, the trunk's bow
into a push, the stance ankles yielding before a sole rolls. Each is a frozen dataclass of its settings, and
:class:`Reflexes` holds each one's config or None (off). :meth:`Reflexes.of` makes them from the controller's
options and the robot's description, which is the one place where a robot's own settings replace the
defaults; :func:`apply_reflexes` adds the systems of those that are on and connects the planner's reference
to the IK through them. Why each reflex exists, with the measurements: ``docs/online_controller.md``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import NamedTuple

from drake_estop.physics.compliance import add_foot_edge_compliance
from drake_estop.physics.controller_options import ControllerOptions, controller_settings
from drake_estop.physics.foot_force import add_foot_force_control
from drake_estop.physics.hip_strategy import HIP_STRATEGY, add_hip_strategy
from drake_estop.physics.swing_tilt import add_swing_tilt_compensation
from drake_estop.systems.reference import connect_reference


@dataclass(frozen=True)
class SwingTiltConfig:
    """The swing foot's tilt compensation (:class:`drake_estop.physics.swing_tilt.SwingFootTiltCompensation`).

    Attributes
    ----------
    deadband : float
        Base tilt left alone [rad] (the walk's own sway against the command is a few mrad); default 0.01.
    max_tilt : float
        The largest correction [rad] (hrpsys-base's 10 degree cap); default 0.17.
    return_time : float
        The correction's return after the touchdown [s]; default 0.3.
    contact_force : float
        Measured normal force that means contact [N]; default 50.
    """

    deadband: float = 0.01
    max_tilt: float = 0.17
    return_time: float = 0.3
    contact_force: float = 50.0


@dataclass(frozen=True)
class FootForceConfig:
    """The feet's force difference control in double support (Kajita et al. 2010,
    :class:`drake_estop.physics.foot_force.FootForceDifferenceControl`).

    Attributes
    ----------
    damping : float
        Force difference damping [N s/m] (the robot's ``foot_force_damping``).
    return_time : float
        The height difference's return once the control stops acting [s]; default 0.5.
    max_offset : float
        The largest height difference [m]; default 0.02.
    engage_time : float or None
        How long both soles stand before it acts [s] (the robot's ``foot_force_engage_time``; None: the
        system's default).
    """

    damping: float
    return_time: float = 0.5
    max_offset: float = 0.02
    engage_time: float | None = None

    def settings(self) -> dict:
        """The keyword arguments of :func:`drake_estop.physics.foot_force.add_foot_force_control`."""
        return {name: value for name, value in dataclasses.asdict(self).items()
                if not (name == "engage_time" and value is None)}


@dataclass(frozen=True)
class FootEdgeComplianceConfig:
    """The stance ankles' foot-edge compliance (:class:`drake_estop.physics.compliance.FootEdgeCompliance`).

    Attributes
    ----------
    edge_margin : float
        How near a sole edge the measured CoP makes the ankle yield [m]; default 0.015.
    damping : float
        The ankle's damping [N m s/rad]; default 80.
    return_time : float
        The ankle offset's return once the CoP is back inside [s]; default 0.3.
    max_offset : float
        The largest ankle offset [rad]; default 0.05.
    """

    edge_margin: float = 0.015
    damping: float = 80.0
    return_time: float = 0.3
    max_offset: float = 0.05


@dataclass(frozen=True)
class HipStrategyConfig:
    """The trunk's bow into a push from behind (:class:`drake_estop.physics.hip_strategy.HipStrategy`).

    Attributes
    ----------
    trigger : float
        DCM deviation ahead of the reference that starts a bow [m].
    min_rate : float
        The push rate that tells a push from a drift [m/s].
    amplitude : float
        The bow [rad].
    rise_time, hold_time, return_time : float
        The bow's profile [s].
    backward : bool
        Bow back into a push from the front too.
    """

    trigger: float = HIP_STRATEGY["trigger"]
    min_rate: float = HIP_STRATEGY["min_rate"]
    amplitude: float = HIP_STRATEGY["amplitude"]
    rise_time: float = HIP_STRATEGY["rise_time"]
    hold_time: float = HIP_STRATEGY["hold_time"]
    return_time: float = HIP_STRATEGY["return_time"]
    backward: bool = HIP_STRATEGY["backward"]


@dataclass(frozen=True)
class Reflexes:
    """Each reflex's config, or None where it is off.

    Attributes
    ----------
    swing_tilt : SwingTiltConfig or None
        The swing foot turned against the body's measured roll and pitch [rad].
    foot_force : FootForceConfig or None
        The soles' heights sharing the load [m] (only for a robot that gives its damping).
    hip_strategy : HipStrategyConfig or None
        The trunk's bow [rad] (only for a robot that names its trunk pitch joint).
    foot_compliance : FootEdgeComplianceConfig or None
        The stance ankles' yield near a sole edge [rad].
    """

    swing_tilt: SwingTiltConfig | None = SwingTiltConfig()
    foot_force: FootForceConfig | None = None
    hip_strategy: HipStrategyConfig | None = None
    foot_compliance: FootEdgeComplianceConfig | None = FootEdgeComplianceConfig()

    @classmethod
    def of(cls, controller: ControllerOptions, robot=None) -> Reflexes:
        """The reflexes ``controller`` turns on, with ``robot``'s own settings where its description gives
        them (swing-tilt dead band, edge margin, foot force damping and engage time)."""
        own = controller_settings(robot)
        swing_tilt = foot_force = compliance = None
        if controller.swing_tilt:
            swing_tilt = _with(SwingTiltConfig(), deadband=own["swing_tilt_deadband"])
        if controller.foot_force_control and own["foot_force_damping"] is not None:
            foot_force = FootForceConfig(damping=own["foot_force_damping"], engage_time=own["foot_force_engage_time"])
        if controller.foot_compliance:
            compliance = _with(FootEdgeComplianceConfig(), edge_margin=own["edge_margin"])
        return cls(swing_tilt=swing_tilt, foot_force=foot_force,
                   hip_strategy=HipStrategyConfig() if controller.hip_strategy else None, foot_compliance=compliance)


def _with(config, **own):
    """``config`` with the robot's own settings that are not None."""
    return dataclasses.replace(config, **{name: value for name, value in own.items() if value is not None})


class ReflexSystems(NamedTuple):
    """The systems :func:`apply_reflexes` added (None where the reflex is off or does not apply)."""

    swing_tilt: object
    foot_force: object
    hip_strategy: object
    foot_compliance: object


def apply_reflexes(builder, reflexes: Reflexes, *, robot, planner, estimator, ik, kin_plant, plant, omega,
                   servo_period, timer=None) -> ReflexSystems:
    """Add the reflexes that are on between ``planner``'s reference and ``ik``, reading ``estimator``'s state
    and sensors: the feet through the swing-tilt compensation, then the foot force control; the upper body
    through the hip strategy; the IK's joint targets then through the foot-edge compliance (its ``q_port``
    feeds the servos where it is on). ``kin_plant`` is the IK's model, ``plant`` the simulated robot's."""
    swing_tilt = foot_force = hip = compliance = None
    if reflexes.swing_tilt is not None:
        swing_tilt = add_swing_tilt_compensation(builder, plant=kin_plant, reference=planner, ik=ik,
                                                 estimator=estimator, servo_period=servo_period, timer=timer,
                                                 robot=robot, **dataclasses.asdict(reflexes.swing_tilt))
    feet = swing_tilt
    if reflexes.foot_force is not None:
        foot_force = add_foot_force_control(builder, feet=swing_tilt or planner, zmp_source=planner,
                                            sensors=estimator.sensors, servo_period=servo_period, timer=timer,
                                            **reflexes.foot_force.settings())
        feet = foot_force
    if reflexes.hip_strategy is not None:
        hip = add_hip_strategy(builder, reference=planner, estimator=estimator, plant=kin_plant, robot=robot,
                               layout=planner.layout, omega=omega, servo_period=servo_period, timer=timer,
                               **dataclasses.asdict(reflexes.hip_strategy))
    connect_reference(builder, planner, ik, feet=feet, upper_body=hip)
    if reflexes.foot_compliance is not None:
        compliance = add_foot_edge_compliance(builder, plant, estimator.sensors, ik, servo_period, timer=timer,
                                              robot=robot, **dataclasses.asdict(reflexes.foot_compliance))
    return ReflexSystems(swing_tilt, foot_force, hip, compliance)
