"""The online stop controller on the simulated robot: the design card's diagram with physics in the loop.

::

    EStopTrigger -> StopPlannerSystem --com, com_vel, upper_body--> WholeBodyIK --q-->
        StopPlannerSystem --feet--> SwingFootTiltCompensation (base tilt, feet's F/T) --feet--> WholeBodyIK
        FootEdgeCompliance (ankle offsets from the feet's F/T) --q-->
        DesiredStateInterpolator (rate limit) --desired_state--> MultibodyPlant (PD servos, SAP contact)
    MultibodyPlant --state, IMU (Gyroscope, Accelerometer), contact results (CopEstimator)-->
        RobotSensors (noise, latency) --> StateEstimator --com, com_vel--> StopPlannerSystem
        StateEstimator --q--> SwingFootTiltCompensation
    PelvisPush --applied_spatial_force--> MultibodyPlant (perturbations of the simulated robot only)

Every controller block (sensors, estimator, planner, IK, servo targets) is a
LeafSystem updated by a periodic discrete event at the servo period. After
the signal nothing is computed ahead of the tick that uses it: the planner
plans on the signal's tick and re-plans on later ticks from the estimated
state (:class:`drake_estop.systems.stop_controller.StopPlannerSystem`); the IK solves each
tick's targets on that tick. The nominal walk is the pattern, built before
the run.

How the controller balances, each mechanism with the measurements behind it (and what it does not do):
``docs/online_controller.md``. The
:class:`~drake_estop.systems.capturability_monitor.CapturabilityMonitor` observes the measured state's
N-step capturability every tick.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from drake_estop.physics.controller_options import ControllerOptions, controller_settings
from drake_estop.physics.criteria import (
    JointReference,
    analyse,
    fall_time,
    joint_velocity_peak,
    joint_velocity_violations,
)
from drake_estop.physics.estimation import add_state_estimation
from drake_estop.physics.perturbations import (
    Perturbations,
    add_pelvis_push,
    apply_model_errors,
    finite_number,
    perturbed_ground,
)
from drake_estop.physics.plant import (
    CopEstimator,
    PhysicsParameters,
    add_online_loggers,
    add_physics_plant,
    add_servo_targets,
    run_through_stop,
    sole_bodies,
)
from drake_estop.physics.reflexes import FootEdgeComplianceConfig, Reflexes, SwingTiltConfig, apply_reflexes
from drake_estop.planning.gait import GaitParameters, NominalPattern
from drake_estop.planning.planner import StopParameters
from drake_estop.robots.parameters import as_robot, stepping_limits
from drake_estop.systems.capturability_monitor import add_capturability_monitor, monitor_results, report_time
from drake_estop.systems.decision import mode_changes
from drake_estop.systems.foothold_monitor import add_foothold_monitor
from drake_estop.systems.ik import WholeBodyIK, WholeBodyIkSolver, shared_ik
from drake_estop.systems.measured_com_filter import MeasuredComFilter
from drake_estop.systems.stop_controller import add_stop_controller
from drake_estop.timing import TickTimer, per_tick

#: Planner settings for the physics controller: 3 cm ZMP margin, halts of 1.0-1.5 s, the slowdown ZMP at the
#: landing ankle (the paper's eq. 20). With the kinematic default's 5 cm ahead of it, the robustness benchmark's
#: 17 N s push to the right early and mid single support left the CoP 10.4 and 1.6 mm outside its support, and
#: the 29 N s forward push in double support fell; at the ankle all three stop.
#: J_ds's ZMP weight ``a_ds`` (eq. 30) is the paper's unless the robot's description gives its own
#: (``stop_zmp_weight``: the default humanoid's 1000, drake_estop/robots/default.yaml says why).
CONTROLLER_STOP_PARAMETERS = StopParameters(zmp_margin=0.03, halt_durations=(1.0, 1.2, 1.5), max_early_landing=0.05,
                                            max_landing_shift_per_height=10.0, landing_zmp_offset=0.0)


#: The controller's braked landing (on by default; ``braked_landing=False`` in
#: :func:`controller_stop_parameters` or :class:`ControllerOptions`, the scenario's
#: ``controller: {braked_landing: false}``, for comparison). A
#: single-support re-plan lands no sooner than the swing can brake to the landing point at 15 m/s^2
#: (``max_swing_acceleration``, planner.swing_braking_time); where that limit bounds the landing, the
#: re-planned swing also comes down onto its point no flatter than a slope of 0.6, up to 1 cm above the
#: floor (``landing_approach_slope`` with ``landing_approach_when_braking``; StopParameters says why). Every
#: other swing is the paper's quintic. Measured (README): the 0.5 m/s target forward and backward at every
#: phase benchmarked, the matrix 44/44, the stride sweep 40/40. Putting the approach slope on
#: every landing swing (the signal's plan too) passed 60 of the campaign's first 99 runs against the
#: default's 68, so it is only an option (an approach slope given explicitly, ``simulate --physics
#: --landing-approach-slope 0.6``, applies to every swing).
BRAKED_LANDING = {"max_swing_acceleration": 15.0, "landing_approach_slope": 0.6}

#: The whole-body IK keeps the knees bent by at least this much [rad] (a leg-extension limit; the module
#: docstring says why).
IK_MIN_KNEE_BEND = 0.15

#: Settings of the stance ankles' foot-edge compliance (:class:`drake_estop.physics.compliance.FootEdgeCompliance`).
FOOT_EDGE_COMPLIANCE = FootEdgeComplianceConfig()

#: The servo command's rate limit, as a fraction of the model's joint velocity limits: the stiff PD servo
#: overshoots a command at the limit by about 1 % (measured 6.08 rad/s on a knee commanded at 6).
SERVO_VELOCITY_LIMIT_FRACTION = 0.95

#: Settings of the swing foot's tilt compensation (:class:`drake_estop.physics.swing_tilt.SwingFootTiltCompensation`):
#: a 0.01 rad dead band (the walk's own base sway against the command is a few mrad), hrpsys-base's
#: 10 degree cap, a 0.3 s return after the touchdown, and 50 N of measured force for contact.
SWING_TILT_COMPENSATION = SwingTiltConfig()


def controller_stop_parameters(params: StopParameters | None = None, *, braked_landing: bool = True,
                               robot=None) -> StopParameters:
    """The stop parameters the online controller plans with.

    ``params`` (default: the paper's) with the controller's ZMP margin, halt durations, earliest
    landing, landing-shift limit and slowdown ZMP (:data:`CONTROLLER_STOP_PARAMETERS`), and with ``braked_landing`` the
    braked landing (:data:`BRAKED_LANDING`: its approach slope only on swings whose landing the braking limit bounds,
    unless ``params`` gives a slope of its own, which then shapes every swing); a larger margin, a later
    landing, a tighter shift or swing-acceleration limit, a slowdown ZMP further back or a steeper approach
    in ``params`` is kept.

    Parameters
    ----------
    params : StopParameters, optional
        Stop parameters to start from (lengths [m], times [s]); default the paper's.
    braked_landing : bool, optional
        Add the braked landing (15 m/s^2 swing braking, approach slope 0.6, dimensionless); default True.
    robot : RobotDescription or str, optional
        A robot whose description gives its own ``stop_zmp_margin`` [m] or ``stop_zmp_weight`` [1/m^2]: that
        replaces the controller's margin (a robot with smaller soles than the default humanoid's) or the given
        ``a_ds`` (:func:`controller_settings`). Default None: the default humanoid (the controller's margin,
        its own weight).

    Returns
    -------
    StopParameters
        ZMP margin at least 0.03 [m] (or the robot's own), J_ds's ``a_ds`` the robot's own where it gives one
        [1/m^2] (the default humanoid: 1000), halt durations (1.0, 1.2, 1.5) [s], earliest landing 0.05 [s].
    """
    params = _controller_stop_parameters(params, braked_landing)
    own = controller_settings(robot)
    for field, name in (("zmp_margin", "zmp_margin"), ("a_ds", "zmp_weight")):
        if own[name] is not None:
            params = replace(params, **{field: own[name]})
    return params


def has_braked_landing(params: StopParameters) -> bool:
    """Whether ``params`` carry the braked landing (:data:`BRAKED_LANDING`: a swing braking limit and an
    approach slope at least as strict)."""
    return (params.max_swing_acceleration <= BRAKED_LANDING["max_swing_acceleration"]
            and params.landing_approach_slope >= BRAKED_LANDING["landing_approach_slope"])


def _run_stop_parameters(stop_params: StopParameters | None, controller: ControllerOptions, robot) -> StopParameters:
    """:func:`run_online`'s stop parameters: ``stop_params`` where they agree with ``controller.braked_landing``
    (a feature that acts through the stop parameters is never silently dropped; ValueError naming both where
    they do not), else the robot's with the braked landing as the controller asks."""
    if stop_params is None:
        return robot_stop_parameters(robot, braked_landing=controller.braked_landing)
    if has_braked_landing(stop_params) == controller.braked_landing:
        return stop_params
    has = "have the" if has_braked_landing(stop_params) else "have no"
    raise ValueError(
        f"controller.braked_landing is {controller.braked_landing} but stop_params {has} braked landing "
        f"(max_swing_acceleration {stop_params.max_swing_acceleration:g} m/s^2, landing_approach_slope "
        f"{stop_params.landing_approach_slope:g}): give stop_params=controller_stop_parameters(params, "
        f"braked_landing={controller.braked_landing}), or leave stop_params out")


def _controller_stop_parameters(params, braked_landing):
    base = params or StopParameters()
    controller = CONTROLLER_STOP_PARAMETERS
    params = replace(base, zmp_margin=max(base.zmp_margin, controller.zmp_margin),
                     halt_durations=controller.halt_durations,
                     max_early_landing=min(base.max_early_landing, controller.max_early_landing),
                     max_landing_shift_per_height=min(base.max_landing_shift_per_height,
                                                      controller.max_landing_shift_per_height),
                     landing_zmp_offset=min(base.landing_zmp_offset, controller.landing_zmp_offset))
    if not braked_landing:
        return params
    return replace(params,
                   max_swing_acceleration=min(base.max_swing_acceleration, BRAKED_LANDING["max_swing_acceleration"]),
                   landing_approach_slope=max(base.landing_approach_slope, BRAKED_LANDING["landing_approach_slope"]),
                   landing_approach_when_braking=base.landing_approach_when_braking or base.landing_approach_slope == 0)


@dataclass
class OnlineHandles:
    """Systems of :func:`build_online_diagram`."""

    diagram: object
    plant: object
    scene_graph: object
    model_instance: object
    cop: object
    loggers: dict
    trigger: object
    planner: object
    ik: object
    estimator: object
    compliance: object  # FootEdgeCompliance, or None without it
    swing_tilt: object  # SwingFootTiltCompensation, or None without it
    push: object
    initial_q: np.ndarray
    timer: TickTimer
    physics: PhysicsParameters
    robot: object = None  # the RobotDescription
    foot_force: object = None  # FootForceDifferenceControl, or None (the robot gives no foot_force_damping)
    capturability: object = None  # the CapturabilityMonitor (observes the measured state; does not act)


def build_online_diagram(pattern: NominalPattern, stop_params: StopParameters, estop_time: float | None, *,
                         physics: PhysicsParameters | None = None, perturbations: Perturbations | None = None,
                         controller: ControllerOptions | None = None, robot=None) -> OnlineHandles:
    """The closed-loop physics diagram of the online controller (see the module docstring).

    ``perturbations`` change the simulated robot only (friction here, pushes through the plant's
    applied-spatial-force input, sensor noise and latency in the sensors; the masses in
    :func:`run_online`'s context). ``controller`` (default ``ControllerOptions()``) says which features
    are on: ``true_state`` feeds the estimator's outputs from the true plant state (debugging); the
    reflexes (:func:`~drake_estop.physics.reflexes.apply_reflexes`) sit between the planner and the IK;
    ``controller.planner`` is the planner's :class:`~drake_estop.systems.decision.StopPlannerConfig`.
    ``controller.braked_landing`` acts through
    ``stop_params`` (:func:`controller_stop_parameters`).

    Parameters
    ----------
    pattern : NominalPattern
        The walk (lengths in m, times in s).
    stop_params : StopParameters
        The stop planner's parameters; its ``servo_period`` [s] is the controller's tick.
    estop_time : float or None
        Time of the stop signal [s], latched at the next servo tick; None: no scheduled stop.
    physics, perturbations, controller
        As described above.
    robot : RobotDescription or str, optional
        The robot (a description, a built-in name or a description file; default the default
        humanoid): the simulated plant (its sole contact and servo gains), the sensors, estimator,
        compliance and criteria read its bodies, sole frames and joints, and the controller's IK its
        kinematic model. ``pattern`` and ``stop_params`` must be for it
        (:func:`drake_estop.robots.gait_parameters`, :func:`drake_estop.robots.stop_parameters`).

    Returns
    -------
    OnlineHandles
        The built diagram and its systems (plant, estimator, planner, IK, loggers, ...).
    """
    from drake_estop.systems.diagram import initial_configuration as pattern_initial_configuration

    robot = as_robot(robot)
    controller = _checked_controller(controller)
    perturbations = perturbations or Perturbations()
    physics = perturbed_ground(perturbations, physics or PhysicsParameters()).for_robot(robot)
    dt = stop_params.servo_period
    timer = TickTimer(dt)
    builder = DiagramBuilder()
    plant, scene_graph, instance, _ = add_physics_plant(builder, physics, robot)
    push = add_pelvis_push(builder, plant, perturbations.pushes, robot=robot)
    soles = sole_bodies(plant, robot)
    cop = builder.AddNamedSystem("cop_estimator", CopEstimator(plant=plant, scene_graph=scene_graph, bodies=soles))
    builder.Connect(plant.get_contact_results_output_port(), cop.contact_results_port)

    kin_plant, _, _ = shared_ik(robot)
    q0 = pattern_initial_configuration(kin_plant, pattern, robot=robot)
    estimator = add_state_estimation(builder, plant, cop, servo_period=dt, perturbations=perturbations,
                                     initial_q=q0, timer=timer, robot=robot,
                                     true_state=controller.true_state)
    trigger, planner, monitor = _add_planner(builder, pattern=pattern, stop_params=stop_params,
                                             estop_time=estop_time, robot=robot, estimator=estimator,
                                             pushes=perturbations.pushes, timer=timer,
                                             config=controller.planner)
    solver = WholeBodyIkSolver(kin_plant, min_knee_bend=IK_MIN_KNEE_BEND, robot=robot)
    ik = builder.AddNamedSystem("whole_body_ik", WholeBodyIK(
        plant=kin_plant, servo_period=dt, initial_q=q0, solver=solver, timer=timer))
    reflexes = apply_reflexes(builder, Reflexes.of(controller, robot), robot=robot, planner=planner,
                              estimator=estimator, ik=ik, kin_plant=kin_plant, plant=plant, omega=pattern.w,
                              servo_period=dt, timer=timer)
    swing_tilt_system, foot_force, hip, compliance, _ = reflexes
    add_servo_targets(builder, plant, instance, compliance or ik, q0, dt,
                      velocity_limit_fraction=SERVO_VELOCITY_LIMIT_FRACTION)
    loggers = _add_loggers(builder, plant=plant, cop=cop, ik=ik, estimator=estimator, planner=planner,
                           monitor=monitor, reflexes=reflexes, period=physics.log_period, servo_period=dt)
    diagram = builder.Build()
    diagram.set_name("estop_online")
    return OnlineHandles(diagram, plant, scene_graph, instance, cop, loggers, trigger, planner, ik, estimator,
                         compliance, swing_tilt_system, push, q0, timer, physics, robot, foot_force, monitor)


def _add_planner(builder, *, pattern, stop_params, estop_time, config, robot, estimator, pushes, timer) -> tuple:
    """The e-stop trigger and the stop planner on the estimator's COG (through a
    :class:`~drake_estop.systems.measured_com_filter.MeasuredComFilter`) and soles (and, with
    ``relanded_footholds``, a :class:`~drake_estop.systems.foothold_monitor.FootholdMonitor` on them), and the
    capturability monitor beside them: ``(trigger, planner, monitor)``."""
    from drake_estop.systems.diagram import robot_layout

    trigger, planner = add_stop_controller(builder, pattern=pattern, params=stop_params, estop_time=estop_time,
                                           timer=timer, config=config, layout=robot_layout(robot, pattern))
    com_filter = builder.AddNamedSystem("measured_com_filter", MeasuredComFilter(
        pattern=pattern, servo_period=stop_params.servo_period, timer=timer))
    builder.Connect(estimator.com_port, com_filter.measured_com_port)
    builder.Connect(estimator.com_vel_port, com_filter.measured_com_vel_port)
    builder.Connect(trigger.stop_port, com_filter.stop_port)
    builder.Connect(com_filter.com_port, planner.measured_com_port)
    builder.Connect(com_filter.com_vel_port, planner.measured_com_vel_port)
    builder.Connect(estimator.feet_port, planner.measured_feet_port)
    if config.relanded_footholds:
        add_foothold_monitor(builder, planner=planner, feet_port=estimator.feet_port, timer=timer)
    monitor = add_capturability_monitor(
        builder, estimator=estimator, reference=planner, omega=pattern.w, params=stop_params,
        limits=stepping_limits(robot, stop_params), report_time=report_time(estop_time, pushes), timer=timer)
    return trigger, planner, monitor


def _add_loggers(builder, *, plant, cop, ik, estimator, planner, monitor, reflexes, period, servo_period) -> dict:
    """The run's loggers by name: the plant's and the IK's every ``period``, the planner's and the
    monitor's every servo tick, the reflexes' where they run."""
    dt = servo_period
    loggers = {
        **add_online_loggers(builder, plant, cop, ik, period),
        "com_est": LogVectorOutput(estimator.com_port, builder, period),
        "com_vel_est": LogVectorOutput(estimator.com_vel_port, builder, period),
        # every servo tick, whatever log_period: its update of tick k is published at tick k + 1
        "one_step_feasible": LogVectorOutput(planner.one_step_feasible_port, builder, dt),
        "mode": LogVectorOutput(planner.mode_port, builder, dt),
        "capturability": LogVectorOutput(monitor.capturability_port, builder, dt),
    }
    reflex_logs = (("swing_tilt", reflexes.swing_tilt, "tilt_port"),
                   ("hip_strategy_bow", reflexes.hip_strategy, "bow_port"),
                   ("ankle_offsets", reflexes.foot_compliance, "offsets_port"),
                   ("foot_height_difference", reflexes.foot_force, "height_difference_port"),
                   ("touchdown_depth", reflexes.touchdown, "touchdown_depth_port"))
    for name, system, port in reflex_logs:
        if system is not None:
            loggers[name] = LogVectorOutput(getattr(system, port), builder, period)
    return loggers


def online_simulator(handles: OnlineHandles, perturbations: Perturbations | None = None) -> Simulator:
    """An initialized ``Simulator`` of :func:`build_online_diagram`'s diagram: the robot in its start
    pose (``handles.initial_q``) with ``perturbations``' mass and torso errors written into the plant's
    context (the controller keeps the nominal model), ready to walk from t = 0."""
    simulator = Simulator(handles.diagram)
    plant_context = handles.plant.GetMyMutableContextFromRoot(simulator.get_mutable_context())
    handles.plant.SetPositions(plant_context, handles.initial_q)
    apply_model_errors(handles.plant, plant_context, perturbations or Perturbations(), handles.robot)
    simulator.Initialize()
    return simulator


def _checked_pattern(gait_params, pattern, robot=None, whole_body: bool = False) -> NominalPattern:
    """The walk of :func:`run_online` (:func:`drake_estop.robots.parameters.walk_pattern`); with
    ``whole_body``, its COG corrected for the limbs' momentum unless it carries a correction already."""
    from drake_estop.robots.parameters import walk_pattern
    from drake_estop.systems.whole_body_walk import whole_body_pattern

    pattern = walk_pattern(robot, gait_params, pattern)
    if not whole_body or pattern.com_correction is not None:
        return pattern
    return whole_body_pattern(robot, pattern.params)


def robot_stop_parameters(robot=None, *, braked_landing: bool = True) -> StopParameters:
    """:func:`controller_stop_parameters` of the robot's own stop parameters
    (:func:`drake_estop.robots.stop_parameters`: its leg reach and crouch; the paper's for the default)."""
    from drake_estop.robots.parameters import stop_parameters

    description = as_robot(robot)
    return controller_stop_parameters(stop_parameters(description), braked_landing=braked_landing,
                                      robot=description)


def mode_results(log, servo_period: float) -> dict:
    """The planner's ``mode`` log by tick (``mode``: rows ``[StopMode, landings left]``) and its changes
    (``modes``: :func:`drake_estop.systems.decision.mode_changes`)."""
    modes = per_tick(log, servo_period)
    return {"mode": modes, "modes": mode_changes(modes, servo_period)}


def _checked_controller(controller) -> ControllerOptions:
    """``controller`` (default ``ControllerOptions()``) where it is the online controller's; ValueError naming
    it where it cannot be."""
    controller = ControllerOptions() if controller is None else controller
    if not isinstance(controller, ControllerOptions):
        raise ValueError(f"controller must be a ControllerOptions, got {controller!r}")
    if controller.kind != "online":
        raise ValueError(f"controller.kind must be 'online' here, got {controller.kind!r} (the offline filter: "
                         "drake_estop.physics.offline.run_physics)")
    return controller


def _check_run_arguments(pattern, estop_time, after_halt):
    """ValueError naming the first of :func:`run_online`'s times that cannot run (its ``controller`` and
    is checked before the walk is made: :func:`_checked_controller`)."""
    if isinstance(estop_time, bool) or not (finite_number(estop_time) and 0.0 <= float(estop_time) <= pattern.end_time):
        raise ValueError(f"estop_time must be a time within the walk, 0 to {pattern.end_time:g} s, got {estop_time!r}")
    if isinstance(after_halt, bool) or not (finite_number(after_halt) and float(after_halt) >= 1.0):
        raise ValueError(f"after_halt must be at least 1 s, as simulate's --after-halt, got {after_halt!r}")


def _ik_reference(handles: OnlineHandles, context) -> JointReference:
    """The IK's joint targets of a run and its COG and sole errors (a failure: past their bounds)."""
    from drake_estop.systems.diagram import IK_COM_BOUND, IK_FOOT_BOUND  # (the diagram module imports this one)

    q_log = handles.loggers["ik_q"].FindLog(context)
    com_err = handles.loggers["ik_com_error"].FindLog(context).data()[0]
    foot_err = handles.loggers["ik_foot_error"].FindLog(context).data()[0]
    failures = int(np.sum((com_err > IK_COM_BOUND) | (foot_err > IK_FOOT_BOUND)))
    return JointReference(q_log.sample_times(), q_log.data().T, com_err, foot_err, failures, 0.0)


def _online_results(handles: OnlineHandles, context, plan, result, cpu: float, perturbations) -> dict:
    """``result.online`` of a run (``cpu``: its CPU seconds):

    ``tick_compute`` (median / p99 / max wall-clock seconds [s] of the controller's own work per
    servo tick after the signal), ``tick_compute_cpu`` (the same in the thread's CPU time: without
    preemption by other processes), ``tick_compute_by_block`` (those ticks' mean CPU seconds per
    block, ``"WholeBodyIK._update"``: :meth:`TickTimer.breakdown`), ``tick_compute_slowest`` (the
    three slowest of those ticks in CPU time, each with its blocks: :meth:`TickTimer.slowest`),
    ``replans``, ``replan_failures``, ``latch_fallback`` (None, or why the latch planned from the
    reference: no stop from the measured state), ``joint_velocity_violations`` (ticks with a joint over its
    velocity limit, measured), ``ankle_offset_max`` (the foot-edge compliance's largest ankle
    offset [rad]), ``swing_tilt_max`` (the swing-foot tilt compensation's largest correction
    [rad]), ``hip_strategy_bow_max`` (the hip strategy's largest bow of the trunk [rad]),
    ``touchdown_depth_max`` (the touchdown by contact's deepest descent below the reference [m]), the
    estimator's COG log and ``one_step_feasible`` (per servo tick ``k * servo_period``
    from 0: 1.0 if a stop signal at that tick would stop in one step, from the planner's output, the
    state it planned from included; after the latch the latched stop's case; NaN for a tick whose
    update had not run).
    ``mode`` (per tick ``[StopMode, landings left]``) and ``modes`` (where it changed:
    :func:`drake_estop.systems.decision.mode_changes`); ``capture`` and ``capturability`` (the measured
    state's N-step capturability: :func:`drake_estop.systems.capturability_monitor.monitor_results`).
    """
    planner_context = handles.planner.GetMyContextFromRoot(context)
    dt = handles.planner.params.servo_period
    states = handles.loggers["state"].FindLog(context).data().T
    replans, replan_failures = handles.planner.replans(planner_context)
    return {
        "controller": "online",
        "tick_compute": handles.timer.summary(since=plan.signal_time),
        # the same ticks in the controller thread's CPU time: its own work, without preemption by other
        # processes (which the wall clock above includes on a shared machine)
        "tick_compute_cpu": handles.timer.summary(since=plan.signal_time, clock="cpu"),
        # where those ticks' CPU time goes: each block's own share, mean seconds a tick
        "tick_compute_by_block": handles.timer.breakdown(since=plan.signal_time, clock="cpu"),
        # the three slowest of those ticks (CPU) and each one's blocks: what the worst tick did
        "tick_compute_slowest": handles.timer.slowest(since=plan.signal_time, clock="cpu", count=3),
        "replans": int(replans),
        "replan_failures": int(replan_failures),
        # why the latch planned from the reference (no stop from the measured state), or None
        "latch_fallback": handles.planner.latch_fallback(planner_context),
        "joint_velocity_violations": int(np.count_nonzero(joint_velocity_violations(handles.plant, states))),
        "joint_velocity_peak": joint_velocity_peak(handles.plant, states, handles.loggers["state"]
                                                   .FindLog(context).sample_times()),
        "com_est": handles.loggers["com_est"].FindLog(context).data().T,
        "one_step_feasible": per_tick(handles.loggers["one_step_feasible"].FindLog(context), dt),
        # the stop's mode after each tick's update ([StopMode, landings left]) and where it changed
        **mode_results(handles.loggers["mode"].FindLog(context), dt),
        # the measured state's N-step capturability: per tick (steps, -1 for none; margin [m], [m/s]) and summary
        **monitor_results(handles.capturability, handles.loggers["capturability"], context, plan.signal_time,
                          fall_time(result, handles.physics)),
        # simulated seconds per CPU second of the loop (plant, contact, controller): the real-time
        # factor on a core of its own, little changed by other processes (unlike the wall-clock one)
        "cpu_realtime_factor": result.sim_time / cpu if cpu > 0 else float("nan"),
        "perturbations": perturbations,
        # the largest ankle offset of the foot-edge compliance [rad] (0 without it)
        "ankle_offset_max": float(np.max(np.abs(handles.loggers["ankle_offsets"].FindLog(context).data())))
        if handles.compliance is not None else 0.0,
        # the largest correction of the swing foot's tilt compensation [rad] (0 without it)
        "swing_tilt_max": float(np.max(np.linalg.norm(
            handles.loggers["swing_tilt"].FindLog(context).data().reshape(2, 3, -1), axis=1)))
        if handles.swing_tilt is not None else 0.0,
        # the hip strategy's largest bow of the trunk [rad] (0 without it, or where it never bowed)
        "hip_strategy_bow_max": float(np.max(np.abs(
            handles.loggers["hip_strategy_bow"].FindLog(context).data()[0])))
        if "hip_strategy_bow" in handles.loggers else 0.0,
        # the touchdown by contact's deepest descent below the reference [m] (0 without it)
        "touchdown_depth_max": float(np.max(handles.loggers["touchdown_depth"].FindLog(context).data()))
        if "touchdown_depth" in handles.loggers else 0.0,
    }


def run_online(gait_params: GaitParameters | None = None, stop_params: StopParameters | None = None,
               estop_time: float = 3.4, *, after_halt: float = 2.5, physics: PhysicsParameters | None = None,
               perturbations: Perturbations | None = None, pattern: NominalPattern | None = None,
               controller: ControllerOptions | None = None, robot=None):
    """Walk, stop at ``estop_time`` with the online controller on the simulated robot, and check the
    success criteria: ``drake-estop simulate --physics`` from Python.

    The humanoid walks in physics (SAP ``MultibodyPlant``, 1 ms) under :func:`build_online_diagram`'s
    closed loop; the signal latches at ``estop_time``; the run ends ``after_halt`` past the plan's halt.

    Parameters
    ----------
    gait_params : GaitParameters, optional
        The walk (step length [m], step time [s], ...); default the robot's
        (:func:`drake_estop.robots.gait_parameters`; the paper's for the default humanoid). Give this or
        ``pattern``.
    stop_params : StopParameters, optional
        Used as given, with the braked landing or without it as ``controller.braked_landing`` says (build them
        with ``controller_stop_parameters(params, braked_landing=...)``); default :func:`robot_stop_parameters`.
    estop_time : float, optional
        Time of the stop signal [s], within the walk (0 to the pattern's end); default 3.4 (the paper's).
    after_halt : float, optional
        Seconds simulated past the plan's halt [s], at least 1 (as ``simulate --after-halt``); default 2.5.
    physics : PhysicsParameters, optional
        The plant (time step [s], contact model, servo gains); default ``PhysicsParameters()``.
    perturbations : Perturbations, optional
        Pushes [N, s], mass and torso errors, friction, latency, sensor noise: the simulated robot only.
    pattern : NominalPattern, optional
        A walk built already (``NominalPattern(gait_params)``; it must agree with ``gait_params``).
    controller : ControllerOptions, optional
        The online controller (``kind`` must be ``"online"``): its planner's settings and its reflexes;
        default ``ControllerOptions()``, as benchmarked (``ControllerOptions(foot_compliance=None)`` leaves
        out the stance ankles' foot-edge compliance, ``ControllerOptions(planner=StopPlannerConfig(
        recovery_step=False))`` the recovery step, ``true_state=True`` feeds the controller the true COG).
    robot : RobotDescription or str, optional
        The humanoid (a description, ``"default"``, ``"g1"``, ``"talos"`` or a description file; default
        the default humanoid). A push's impulse [N s] is the robot's mass times its COG velocity change.

    Returns
    -------
    drake_estop.physics.criteria.PhysicsResult
        Per-tick (5 ms) arrays [m, s, rad], ``success`` and ``criteria`` (no fall, no slip, rest near
        the feet's midpoint, CoP in the support, joint speeds within limits), and ``online``: the
        controller's own record (:func:`_online_results`: tick times [s], re-plans, the stop's modes,
        one-step feasibility and capturability per tick, the reflexes' largest corrections [rad]).

    Raises
    ------
    ValueError
        Naming the argument: ``estop_time`` outside the walk, ``after_halt`` under 1 s, ``gait_params`` and
        ``pattern`` that disagree, a ``controller`` that is not an online ``ControllerOptions``.
    drake_estop.planning.plan.InfeasibleStop
        When no stop can be planned at the signal from the reference either, or, with
        ``controller.planner.reference_fallback`` False, from the measured state (by default the latch
        then plans from the reference: ``online["latch_fallback"]``).
    """
    robot = as_robot(robot)
    controller = _checked_controller(controller)
    pattern = _checked_pattern(gait_params, pattern, robot, controller.whole_body_walk)
    _check_run_arguments(pattern, estop_time, after_halt)
    perturbations = perturbations or Perturbations()
    stop_params = _run_stop_parameters(stop_params, controller, robot)
    handles = build_online_diagram(pattern, stop_params, estop_time, physics=physics, perturbations=perturbations,
                                   controller=controller, robot=robot)
    simulator = online_simulator(handles, perturbations)
    context = simulator.get_mutable_context()
    cpu = time.process_time()
    plan, wall = run_through_stop(simulator, handles.planner, estop_time, stop_params.servo_period, after_halt,
                                  handles.planner.plans)  # the plan and its re-plans, each from its start
    reference = _ik_reference(handles, context)
    cpu = time.process_time() - cpu
    result = analyse(handles, context, plan, reference, handles.physics, wall, robot)
    result.online = _online_results(handles, context, plan, result, cpu, perturbations)
    return result
