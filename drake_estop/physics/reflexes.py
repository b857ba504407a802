"""The online controller's reflexes as they act on one robot, and the one function that wires them.

A reflex acts between the stop planner and the servos, on the measured state, at the servo tick: the swing
foot turned against the body's tilt, the soles' heights sharing the load in double support, the trunk's bow
into a push, the stance ankles yielding before a sole rolls. Each is configured by a frozen dataclass of its
settings (:mod:`drake_estop.physics.controller_options`), and :class:`Reflexes` holds each one's config, every
setting resolved, or None (off). :meth:`Reflexes.of` makes them from the controller's
options and the robot's description, which is the one place where a robot's own settings replace the
defaults; :func:`apply_reflexes` adds the systems of those that are on and connects the planner's reference
to the IK through them. Why each reflex exists, with the measurements: ``docs/online_controller.md``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import NamedTuple

from drake_estop.physics.compliance import add_foot_edge_compliance
from drake_estop.physics.controller_options import (
    ControllerOptions,
    FootEdgeComplianceConfig,
    FootForceConfig,
    HipStrategyConfig,
    SwingTiltConfig,
    TouchdownConfig,
    controller_settings,
)
from drake_estop.physics.foot_force import add_foot_force_control
from drake_estop.physics.hip_strategy import add_hip_strategy
from drake_estop.physics.swing_tilt import add_swing_tilt_compensation
from drake_estop.physics.touchdown import add_touchdown_by_contact
from drake_estop.systems.reference import connect_reference

#: The swing-tilt dead band [rad] and the foot-edge compliance's edge margin [m] of a robot that gives none.
SWING_TILT_DEADBAND = 0.01
EDGE_MARGIN = 0.015


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
    touchdown : TouchdownConfig or None
        A landed sole's descent until it carries weight [m].
    """

    swing_tilt: SwingTiltConfig | None = SwingTiltConfig(deadband=SWING_TILT_DEADBAND)
    foot_force: FootForceConfig | None = None
    hip_strategy: HipStrategyConfig | None = None
    foot_compliance: FootEdgeComplianceConfig | None = FootEdgeComplianceConfig(edge_margin=EDGE_MARGIN)
    touchdown: TouchdownConfig | None = TouchdownConfig()

    @classmethod
    def of(cls, controller: ControllerOptions, robot=None) -> Reflexes:
        """The reflexes ``controller`` turns on, each setting it leaves None the robot's own where its
        description gives one (swing-tilt dead band, edge margin, foot force damping and engage time), else
        the default. The foot force control needs a damping: without one from either it is off."""
        own = controller_settings(robot)
        swing_tilt = foot_force = compliance = None
        if controller.swing_tilt is not None:
            swing_tilt = _resolved(controller.swing_tilt, deadband=(own["swing_tilt_deadband"], SWING_TILT_DEADBAND))
        if controller.foot_force is not None:
            foot_force = _resolved(controller.foot_force, damping=(own["foot_force_damping"], None),
                                   engage_time=(own["foot_force_engage_time"], None))
            foot_force = foot_force if foot_force.damping is not None else None
        if controller.foot_compliance is not None:
            compliance = _resolved(controller.foot_compliance, edge_margin=(own["edge_margin"], EDGE_MARGIN))
        return cls(swing_tilt=swing_tilt, foot_force=foot_force, hip_strategy=controller.hip_strategy,
                   foot_compliance=compliance, touchdown=controller.touchdown)


def _resolved(config, **fallbacks):
    """``config`` with each setting it leaves None replaced by the robot's own, else the default:
    ``fallbacks`` maps a setting to ``(robot's own or None, default)``."""
    changes = {}
    for name, (own, default) in fallbacks.items():
        if getattr(config, name) is None:
            changes[name] = own if own is not None else default
    return dataclasses.replace(config, **changes)


class ReflexSystems(NamedTuple):
    """The systems :func:`apply_reflexes` added (None where the reflex is off or does not apply)."""

    swing_tilt: object
    foot_force: object
    hip_strategy: object
    foot_compliance: object
    touchdown: object = None


def apply_reflexes(builder, reflexes: Reflexes, *, robot, planner, estimator, ik, kin_plant, plant, omega,
                   servo_period, timer=None) -> ReflexSystems:
    """Add the reflexes that are on between ``planner``'s reference and ``ik``, reading ``estimator``'s state
    and sensors: the feet through the swing-tilt compensation, the foot force control, then the touchdown
    by contact; the upper body
    through the hip strategy; the IK's joint targets then through the foot-edge compliance (its ``q_port``
    feeds the servos where it is on). ``kin_plant`` is the IK's model, ``plant`` the simulated robot's."""
    swing_tilt = foot_force = hip = compliance = touchdown = None
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
    if reflexes.touchdown is not None:
        touchdown = add_touchdown_by_contact(builder, feet=feet or planner, estimator=estimator,
                                             servo_period=servo_period, timer=timer,
                                             **dataclasses.asdict(reflexes.touchdown))
        feet = touchdown
    if reflexes.hip_strategy is not None:
        hip = add_hip_strategy(builder, reference=planner, estimator=estimator, plant=kin_plant, robot=robot,
                               layout=planner.layout, omega=omega, servo_period=servo_period, timer=timer,
                               **dataclasses.asdict(reflexes.hip_strategy))
    connect_reference(builder, planner, ik, feet=feet, upper_body=hip)
    if reflexes.foot_compliance is not None:
        compliance = add_foot_edge_compliance(builder, plant, estimator.sensors, ik, servo_period, timer=timer,
                                              robot=robot, **dataclasses.asdict(reflexes.foot_compliance))
    return ReflexSystems(swing_tilt, foot_force, hip, compliance, touchdown)
