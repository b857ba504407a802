"""The physics stop's controller as configuration: which controller runs, the stop planner's settings and
each reflex's, as typed data in the manner of Drake's ``examples/hardware_sim``.

:class:`ControllerOptions` is the ``controller`` section of a scenario
(:class:`drake_estop.scenario.Scenario`) and the ``controller`` argument of
:func:`drake_estop.physics.online.run_online`::

    controller:
      kind: online
      planner: {recovery_step: false, replan_threshold: 0.06}   # StopPlannerConfig
      foot_compliance: null                                     # a reflex off
      swing_tilt: {deadband: 0.02}                              # a reflex with a setting of its own

The planner's settings are :class:`drake_estop.systems.decision.StopPlannerConfig`; each reflex is its
config or None (off). A reflex setting left None is the robot's own, from its description, else the
default (:meth:`drake_estop.physics.reflexes.Reflexes.of`). The defaults are the controller as benchmarked;
the changes exist for comparison runs (``benchmarks/robustness.py --ablation`` makes one at a time).
"""

import dataclasses
from dataclasses import dataclass, field

from drake_estop.physics.hip_strategy import HIP_STRATEGY
from drake_estop.robots.parameters import as_robot
from drake_estop.systems.decision import StopPlannerConfig

#: The physics controllers: the online controller, and the offline preview filter it is compared with.
CONTROLLER_KINDS = ("online", "offline-filter")


@dataclass(frozen=True)
class SwingTiltConfig:
    """The swing foot's tilt compensation (:class:`drake_estop.physics.swing_tilt.SwingFootTiltCompensation`).

    Attributes
    ----------
    deadband : float or None
        Base tilt left alone [rad] (the walk's own sway against the command is a few mrad); None: the
        robot's ``swing_tilt_deadband``, else 0.01.
    max_tilt : float
        The largest correction [rad] (hrpsys-base's 10 degree cap); default 0.17.
    return_time : float
        The correction's return after the touchdown [s]; default 0.3.
    contact_force : float
        Measured normal force that means contact [N]; default 50.
    """

    deadband: float | None = None
    max_tilt: float = 0.17
    return_time: float = 0.3
    contact_force: float = 50.0


@dataclass(frozen=True)
class FootForceConfig:
    """The feet's force difference control in double support (Kajita et al. 2010,
    :class:`drake_estop.physics.foot_force.FootForceDifferenceControl`).

    Attributes
    ----------
    damping : float or None
        Force difference damping [N s/m]; None: the robot's ``foot_force_damping``, and where its
        description gives none the control does not act.
    return_time : float
        The height difference's return once the control stops acting [s]; default 0.5.
    max_offset : float
        The largest height difference [m]; default 0.02.
    engage_time : float or None
        How long both soles stand before it acts [s]; None: the robot's ``foot_force_engage_time``, else
        the system's default.
    planned_support : bool
        Which soles stand, and the split the ZMP asks for, from the plan's sole targets instead of the
        targets the control adjusts (after the swing-tilt compensation, whose decaying correction keeps a
        landed foot's target a few mm up); default False. Measured: on the default humanoid no verdict
        changed (the matrix 44/44, the stride sweep 40/40, the push suite's 34); with a damping of 20000 the
        push suite gains 2 runs and the halt's CoP exits move up to 3 cm inwards, but the matrix loses its
        17 N s right push at 2.95 s (a fall). TALOS, tuned without it, loses a stop at each of 20000, 40000
        (its own) and 80000, and with a 0.2 s engage time (of its 2.97 s and 3.67 s stops, and the 3.67 s
        with a 27 N s forward push).
    """

    damping: float | None = None
    return_time: float = 0.5
    max_offset: float = 0.02
    engage_time: float | None = None
    planned_support: bool = False

    def __post_init__(self):
        if not isinstance(self.planned_support, bool):
            raise ValueError(f"controller.foot_force.planned_support must be true or false, "
                             f"got {self.planned_support!r}")

    def settings(self) -> dict:
        """The keyword arguments of :func:`drake_estop.physics.foot_force.add_foot_force_control`."""
        return {name: value for name, value in dataclasses.asdict(self).items()
                if not (name == "engage_time" and value is None)}


@dataclass(frozen=True)
class FootEdgeComplianceConfig:
    """The stance ankles' foot-edge compliance (:class:`drake_estop.physics.compliance.FootEdgeCompliance`).

    Attributes
    ----------
    edge_margin : float or None
        How near a sole edge the measured CoP makes the ankle yield [m]; None: the robot's
        ``foot_edge_margin``, else 0.015.
    damping : float
        The ankle's damping [N m s/rad]; default 80.
    return_time : float
        The ankle offset's return once the CoP is back inside [s]; default 0.3.
    max_offset : float
        The largest ankle offset [rad]; default 0.05.
    """

    edge_margin: float | None = None
    damping: float = 80.0
    return_time: float = 0.3
    max_offset: float = 0.05


@dataclass(frozen=True)
class HipStrategyConfig:
    """The trunk's bow into a push from behind (:class:`drake_estop.physics.hip_strategy.HipStrategy`); acts
    only where the robot's description names its ``trunk_pitch_joint``.

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
class TouchdownConfig:
    """Touchdown by contact (:class:`drake_estop.physics.touchdown.TouchdownByContact`): a landing sole that
    reaches the plan's floor and finds none keeps coming down past the reference until its force sensor first
    measures weight, and stays there.

    Attributes
    ----------
    descent_speed : float
        How fast a landing sole that carries no weight yet keeps coming down [m/s]; default 0.1.
    max_depth : float
        The most its target goes below the reference [m]; default 0.015.
    contact_force : float
        The normal force that means the sole carries weight [N]; default 50.
    return_time : float
        The depth's return while the reference lifts the foot [s]; default 0.3.
    grace_time : float
        How long a sole put down may carry no weight before it is lowered [s]; default 0.02.
    below_floor : float
        How far below the plan's floor the estimated sole must be before it is lowered [m]; default 0.001.
    """

    descent_speed: float = 0.1
    max_depth: float = 0.015
    contact_force: float = 50.0
    return_time: float = 0.3
    grace_time: float = 0.02
    below_floor: float = 0.001


#: The reflexes' fields of :class:`ControllerOptions` and their configs.
REFLEX_CONFIGS = {"swing_tilt": SwingTiltConfig, "foot_force": FootForceConfig,
                  "foot_compliance": FootEdgeComplianceConfig, "hip_strategy": HipStrategyConfig,
                  "touchdown": TouchdownConfig}

#: Keys of the flat form the controller section had, and where each lives now.
MOVED_KEYS = {**{name: f"planner.{name}" for name in (
    "measured_footholds", "relanded_footholds", "recovery_step", "capture_landing", "reference_fallback",
    "foothold_replan", "max_replan_solves", "max_steps", "crossover_step")},
    "foot_force_control": "foot_force"}


@dataclass
class ControllerOptions:
    """The controller of a physics stop: which one runs, the online controller's planner settings and its
    reflexes.

    Every field but ``kind`` acts on the online controller only; the defaults are the controller the
    benchmarks and the campaign measure. Why each part exists, with its measurements:
    ``docs/online_controller.md`` and the ablation in ``benchmarks/ROBUSTNESS.md``.

    Attributes
    ----------
    kind : str
        ``"online"`` (default): plans at the signal and re-plans from the estimated state tick by tick
        (:func:`drake_estop.physics.online.run_online`); ``"offline-filter"``: the whole joint reference
        computed at the signal with the ZMP preview filter (:func:`drake_estop.physics.offline.run_physics`;
        for comparison, not a real-time controller).
    true_state : bool
        Feed the controller the true COG instead of the state estimate (default off: the robot has only its
        sensors; on for debugging the estimator's share of a failure).
    whole_body_walk : bool
        Walk the pattern with its COG corrected for the limbs' momentum
        (:func:`drake_estop.systems.whole_body_walk.whole_body_pattern`), computed before the run (5-8 [s];
        once per robot and gait in a process). Default off: on 70 hard runs of the campaign it stopped 35
        (33 without) with 6 falls (11 without), but the perturbation matrix drops to 43/44 with it.
    braked_landing : bool
        A single-support re-plan lands no sooner than the swing can brake to its point at 15 [m/s^2], and then
        comes down at a slope (default on; off lands the paper's quintic swing). It acts through the stop
        parameters (:func:`drake_estop.physics.online.controller_stop_parameters`); stop parameters given to
        :func:`~drake_estop.physics.online.run_online` that disagree with it raise.
    planner : StopPlannerConfig
        The stop planner's decision: re-plan thresholds, measured footholds, the re-plan tries (capture
        landing, recovery step, crossover step), the step and solve budgets, the reference fallback
        (:class:`drake_estop.systems.decision.StopPlannerConfig`).
    swing_tilt : SwingTiltConfig or None
        The swing sole turned against the body's measured roll and pitch, so a foot lands flat under a
        tilted body (default on).
    foot_force : FootForceConfig or None
        The soles' heights share the load in double support as the plan's ZMP asks, so a pushed robot does
        not rock from one sole edge to the other (default on; acts only with a damping, the robot's own by
        default).
    foot_compliance : FootEdgeComplianceConfig or None
        A stance ankle yields when the measured CoP nears a sole edge, so a pushed robot does not rock on
        its heels or toes and leave the floor (default on).
    hip_strategy : HipStrategyConfig or None
        The trunk bows into a push from behind in the stop; its angular momentum decelerates the COG while
        the ankle is saturated. Default off: a 30 N s forward push in double support stops with it in one
        recovery step (without: two), but on the first 120 runs of the campaign it lost 2 and gained 1.
    touchdown : TouchdownConfig or None
        A landing sole that reaches the plan's floor and finds none keeps coming down until it first carries
        weight, and stays there, so a floor lower than planned does not leave the foot hovering (default on;
        on the flat floor it changed no verdict: ``docs/online_controller.md``).

    Raises
    ------
    ValueError
        Naming the field (``controller.planner``, ``controller.foot_compliance``, ...) that is not of its
        type.
    """

    kind: str = "online"
    true_state: bool = False
    whole_body_walk: bool = False
    braked_landing: bool = True
    planner: StopPlannerConfig = field(default_factory=StopPlannerConfig)
    swing_tilt: SwingTiltConfig | None = field(default_factory=SwingTiltConfig)
    foot_force: FootForceConfig | None = field(default_factory=FootForceConfig)
    foot_compliance: FootEdgeComplianceConfig | None = field(default_factory=FootEdgeComplianceConfig)
    hip_strategy: HipStrategyConfig | None = None
    touchdown: TouchdownConfig | None = field(default_factory=TouchdownConfig)

    def __post_init__(self):
        if self.kind not in CONTROLLER_KINDS:
            raise ValueError(f"controller.kind must be one of {CONTROLLER_KINDS}, got {self.kind!r}")
        for name in ("true_state", "whole_body_walk", "braked_landing"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"controller.{name} must be true or false, got {getattr(self, name)!r}")
        if not isinstance(self.planner, StopPlannerConfig):
            raise ValueError(f"controller.planner must be a StopPlannerConfig (in YAML a mapping of its "
                             f"settings), got {self.planner!r}")
        for name, config in REFLEX_CONFIGS.items():
            value = getattr(self, name)
            if value is not None and not isinstance(value, config):
                raise ValueError(f"controller.{name} must be a {config.__name__} or None (off); in YAML a "
                                 f"mapping of its settings ({{}} for the defaults) or null, got {value!r}")

    def changed(self) -> dict:
        """What differs from ``ControllerOptions()`` other than ``kind``, by dotted name
        (``{"planner.recovery_step": False, "foot_compliance": None, "hip_strategy": {}}``); a reflex turned
        on maps to its settings that differ from its config's defaults. :meth:`with_changes` reads it back."""
        default, changes = ControllerOptions(), {}
        for f in dataclasses.fields(self):
            mine, theirs = getattr(self, f.name), getattr(default, f.name)
            if f.name == "kind" or mine == theirs:
                continue
            if mine is not None and theirs is not None and dataclasses.is_dataclass(mine):
                changes.update({f"{f.name}.{name}": value for name, value in _differences(mine, theirs).items()})
            else:
                changes[f.name] = _differences(mine, type(mine)()) if dataclasses.is_dataclass(mine) else mine
        return changes

    def with_changes(self, changes: dict) -> "ControllerOptions":
        """A copy with ``changes``, by field name or dotted name (``{"planner.recovery_step": False,
        "foot_compliance": None, "swing_tilt": {"deadband": 0.02}}``; a mapping for a reflex that is off
        turns it on with those settings). ValueError naming a key that is unknown or that moved
        (``recovery_step`` -> ``planner.recovery_step``)."""
        nested = as_section(changes)
        for name in nested:
            check_key(name)
        return dataclasses.replace(self, **{name: self._changed_field(name, value) for name, value in nested.items()})

    def _changed_field(self, name, value):
        current = getattr(self, name)
        if name == "planner" or name in REFLEX_CONFIGS:
            if value is None or not isinstance(value, dict):
                return value  # None turns a reflex off; anything else is refused by __post_init__
            base = current if current is not None else REFLEX_CONFIGS[name]()
            unknown = sorted(set(value) - {f.name for f in dataclasses.fields(base)})
            if unknown:
                raise ValueError(f"controller.{name}: unknown setting(s) {unknown}; known: "
                                 f"{[f.name for f in dataclasses.fields(base)]}")
            return dataclasses.replace(base, **value)
        return value


def as_section(changes: dict) -> dict:
    """``changes`` by dotted name as the nested mapping a scenario's controller section writes:
    ``{"planner.recovery_step": False}`` -> ``{"planner": {"recovery_step": False}}``."""
    nested = {}
    for key, value in changes.items():
        name, _, setting = key.partition(".")
        if setting:
            nested.setdefault(name, {})[setting] = value
        else:
            nested[name] = {**nested.get(name, {}), **value} if isinstance(value, dict) else value
    return nested


def _differences(value, default) -> dict:
    """The fields of the dataclass ``value`` that differ from ``default``'s, by name."""
    return {f.name: getattr(value, f.name) for f in dataclasses.fields(value)
            if getattr(value, f.name) != getattr(default, f.name)}


def check_key(name: str) -> None:
    """ValueError naming ``name`` where it is not a field of :class:`ControllerOptions`: where it moved
    (:data:`MOVED_KEYS`), or the fields there are."""
    if name in MOVED_KEYS:
        raise ValueError(f"controller.{name} is now controller.{MOVED_KEYS[name]}"
                         + (" (a mapping of its settings, or null for off)" if name == "foot_force_control" else ""))
    known = [f.name for f in dataclasses.fields(ControllerOptions)]
    if name not in known:
        raise ValueError(f"controller.{name} is not a controller field; known: {known}")


def controller_settings(robot=None) -> dict:
    """The robot's own settings of the physics controller, each None where it keeps the controller's, from
    its description: ``zmp_margin`` (the stop plan's [m], ``stop_zmp_margin``), ``zmp_weight`` (its J_ds
    ``a_ds`` [1/m^2], ``stop_zmp_weight``), ``swing_tilt_deadband`` ([rad], :class:`SwingTiltConfig`),
    ``edge_margin`` ([m], ``foot_edge_margin``, :class:`FootEdgeComplianceConfig`), ``foot_force_damping``
    ([N s/m], :class:`FootForceConfig`, only for a robot that gives it) and ``foot_force_engage_time`` ([s]:
    how long both soles stand before that control acts)."""
    description = as_robot(robot)
    return {"zmp_margin": description.stop_zmp_margin, "zmp_weight": description.stop_zmp_weight,
            "swing_tilt_deadband": description.swing_tilt_deadband,
            "edge_margin": description.foot_edge_margin, "foot_force_damping": description.foot_force_damping,
            "foot_force_engage_time": description.foot_force_engage_time}
