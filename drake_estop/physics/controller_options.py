"""The physics stop's controller as configuration: which controller runs, and which features of the online
controller are on.

:class:`ControllerOptions` is the ``controller`` section of a scenario
(:class:`drake_estop.scenario.Scenario`, YAML ``controller: {kind: online, foot_compliance: false}``) and the
``controller`` argument of :func:`drake_estop.physics.online.run_online`. The features default to the
controller as benchmarked; the switches exist for comparison runs (``benchmarks/robustness.py --ablation``
turns each off in turn).
"""

import dataclasses
from dataclasses import dataclass

from drake_estop.planning.replan import MAX_REPLAN_SOLVES, MAX_STOP_STEPS, check_solve_bound, check_step_bound
from drake_estop.robots.parameters import as_robot

#: The physics controllers: the online controller, and the offline preview filter it is compared with.
CONTROLLER_KINDS = ("online", "offline-filter")

#: The fields that are :class:`drake_estop.systems.stop_controller.StopPlannerSystem` options.
PLANNER_FEATURES = ("measured_footholds", "relanded_footholds", "recovery_step", "capture_landing",
                    "reference_fallback", "foothold_replan", "max_replan_solves", "max_steps", "crossover_step")


@dataclass
class ControllerOptions:
    """The controller of a physics stop and the online controller's features.

    Every feature but ``kind`` acts on the online controller only; the defaults are the controller the
    benchmarks and the campaign measure.

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
    foot_compliance : bool
        The stance ankles' foot-edge compliance (:data:`drake_estop.physics.online.FOOT_EDGE_COMPLIANCE`): an
        ankle yields when the measured CoP nears a sole edge, so a pushed robot does not rock on its heels
        or toes and leave the floor (default on; off for comparison).
    swing_tilt : bool
        The swing foot's tilt compensation (:data:`drake_estop.physics.online.SWING_TILT_COMPENSATION`): the
        swing sole turned against the body's measured roll and pitch, so a foot lands flat under a tilted
        body (default on; off for comparison).
    measured_footholds : bool
        Re-plans after the landing stand on the estimated footholds, where the soles are, rather than on
        the plan's feet (default on; off for comparison).
    relanded_footholds : bool
        A sole that lost contact after the landing and landed again off the plan's foothold re-plans the
        stop where it stands (default on; off for comparison).
    recovery_step : bool
        A re-plan after the landing that finds no double-support stop steps the rear foot forward; and a
        single-support re-plan whose capture landing does not stop the robot takes that step right after
        its touchdown (N-step capture, :func:`drake_estop.planning.capture_landing.capture_step`; default on; off
        keeps the plan, for comparison).
    capture_landing : bool
        A single-support re-plan whose other tries find no stop lands sooner, at the widest step, where a
        sideways push sends the lateral DCM past it before the plan's touchdown
        (:func:`drake_estop.planning.replan.replan_stop`; default on; off for comparison).
    crossover_step : bool
        A single-support re-plan whose lateral DCM lies over the support sole's outer edge (a sideways push
        towards the foot standing alone) first tries a crossover step: the swing foot lands beyond the support
        foot, in front of its leg, where the legs' geometry allows
        (:func:`drake_estop.planning.crossover.crossover_stop`; default off: on the default humanoid the support
        knee bars every landing the falling pushes asked for, and its runs are unchanged).
    braked_landing : bool
        The controller's braked landing (:data:`drake_estop.physics.online.BRAKED_LANDING`): a
        single-support re-plan lands no sooner than the swing can brake to its point at 15 m/s^2, and then
        comes down at a slope (default on; off lands the paper's quintic swing, for comparison). It acts
        through the stop parameters: :func:`drake_estop.physics.online.controller_stop_parameters`; stop
        parameters given to :func:`~drake_estop.physics.online.run_online` that disagree with it raise.
    reference_fallback : bool
        Where no stop exists from the measured state at the signal, the latch plans the paper's stop from
        the reference and re-plans from the measured state (default on; off ends the run with
        :class:`drake_estop.planning.plan.InfeasibleStop`, exit status 2 on the command line, for comparison).
    foothold_replan : bool
        A loaded sole measured more than 5 mm off the plan's foot after the landing re-plans the stop on
        the measured feet, again each time it moves that far (default off: on the seed-0 campaign 382/500
        against 376, but 49 falls against 43; on for comparison).
    foot_force_control : bool
        The feet's force difference control in double support (Kajita et al. 2010,
        :class:`drake_estop.physics.foot_force.FootForceDifferenceControl`) at the robot's
        ``foot_force_damping``: the soles' heights share the load as the plan's ZMP asks, so a pushed robot
        does not rock from one sole edge to the other after its landing (default on; acts only where the
        robot's description gives a damping; off for comparison).
    max_replan_solves : int or None
        Stop solves a re-plan may do in one servo tick, dimensionless (default 2: the tries left go on at
        the next tick, which bounds a tick's work); None puts every try on one tick (for comparison).
    max_steps : int
        The most landings a stop takes after its signal, the walk's own included (default
        :data:`drake_estop.planning.replan.MAX_STOP_STEPS`, 3): a re-plan takes a recovery step, or the two
        steps of an N-step capture, only within it.
    whole_body_walk : bool
        Walk the pattern with its COG corrected for the limbs' momentum
        (:func:`drake_estop.systems.whole_body_walk.whole_body_pattern`: the whole-body ZMP of the IK's
        walk is the planned one), computed before the run (5-8 s; once per robot and gait in a process);
        a given pattern that carries a correction already is walked as it is. Default off: on 70 hard runs
        of the campaign it stopped 35 (33 without) with 6 falls (11 without), but the perturbation matrix
        drops to 43/44 with it (a fall: the 17 N s push to the right early in single support); not
        measured on the whole campaign.
    hip_strategy : bool
        The trunk bows forward into a push from behind in the stop
        (:class:`drake_estop.physics.hip_strategy.HipStrategy`, :data:`drake_estop.physics.hip_strategy.HIP_STRATEGY`):
        its angular momentum decelerates the COG
        while the ankle is saturated; acts only where the robot's description names its ``trunk_pitch_joint``.
        Default off: a 30 N s forward push in double support stops with it in one recovery step (without:
        two, the rear sole slipping 12.6 mm), but on the first 120 runs of the campaign it lost 2 that stop
        without it (forward bows after a sideways or backward push, when the robot ran forward on its own) and
        gained 1.
    """

    kind: str = "online"
    true_state: bool = False
    foot_compliance: bool = True
    swing_tilt: bool = True
    measured_footholds: bool = True
    relanded_footholds: bool = True
    recovery_step: bool = True
    capture_landing: bool = True
    crossover_step: bool = False
    braked_landing: bool = True
    reference_fallback: bool = True
    foothold_replan: bool = False
    foot_force_control: bool = True
    max_replan_solves: int | None = MAX_REPLAN_SOLVES
    whole_body_walk: bool = False
    hip_strategy: bool = False
    max_steps: int = MAX_STOP_STEPS

    def __post_init__(self):
        if self.kind not in CONTROLLER_KINDS:
            raise ValueError(f"controller.kind must be one of {CONTROLLER_KINDS}, got {self.kind!r}")
        for f in dataclasses.fields(self):
            if f.type is bool and not isinstance(getattr(self, f.name), bool):
                raise ValueError(f"controller.{f.name} must be true or false, got {getattr(self, f.name)!r}")
        check_solve_bound(self.max_replan_solves, "controller.max_replan_solves")
        check_step_bound(self.max_steps, "controller.max_steps")

    def planner_options(self) -> dict:
        """The features that are :class:`drake_estop.systems.stop_controller.StopPlannerSystem` keyword
        arguments (:data:`PLANNER_FEATURES`), by name."""
        return {name: getattr(self, name) for name in PLANNER_FEATURES}

    def changed(self) -> dict:
        """The fields other than ``kind`` that differ from their defaults, by name: what only the online
        controller takes."""
        default = ControllerOptions()
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                if f.name != "kind" and getattr(self, f.name) != getattr(default, f.name)}


def controller_settings(robot=None) -> dict:
    """The robot's own settings of the physics controller, each None where it keeps the controller's, from
    its description: ``zmp_margin`` (the stop plan's [m], ``stop_zmp_margin``), ``zmp_weight`` (its J_ds
    ``a_ds`` [1/m^2], ``stop_zmp_weight``), ``swing_tilt_deadband`` ([rad],
    :class:`~drake_estop.physics.reflexes.SwingTiltConfig`), ``edge_margin`` ([m], ``foot_edge_margin``,
    :class:`~drake_estop.physics.reflexes.FootEdgeComplianceConfig`), ``foot_force_damping`` ([N s/m], the feet's
    force difference control, :class:`~drake_estop.physics.reflexes.FootForceConfig`, only for a robot that
    gives it) and ``foot_force_engage_time`` ([s]: how long both soles stand before that control acts)."""
    description = as_robot(robot)
    return {"zmp_margin": description.stop_zmp_margin, "zmp_weight": description.stop_zmp_weight,
            "swing_tilt_deadband": description.swing_tilt_deadband,
            "edge_margin": description.foot_edge_margin, "foot_force_damping": description.foot_force_damping,
            "foot_force_engage_time": description.foot_force_engage_time}
