"""Drake-style helper that adds the whole emergency stop to a user's ``DiagramBuilder``.

:func:`AddEmergencyStop` is to this package what ``AddMultibodyPlantSceneGraph``
is to Drake: the user brings the builder (and, optionally, the robot's plant and
scene graph), the helper adds the e-stop trigger, the four-phase stop planner and
the whole-body IK, wires them, and returns an :class:`EmergencyStop` holding the
systems, the ports a user connects or exports, and readers for the stop's plan,
summary and per-tick log.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydrake.geometry import SceneGraph
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.rendering import MultibodyPositionToGeometryPose

from drake_estop.planning.gait import NominalPattern
from drake_estop.planning.planner import PHASES
from drake_estop.planning.rollout import rollout, stop_metrics
from drake_estop.robots.parameters import as_robot, gait_parameters, stop_parameters
from drake_estop.robots.plant import add_robot
from drake_estop.systems.diagram import add_meshcat_views, add_port_loggers, initial_configuration, robot_layout
from drake_estop.systems.ik import WholeBodyIK
from drake_estop.systems.reference import connect_reference
from drake_estop.systems.stop_controller import add_stop_controller

#: Outputs logged once per servo tick by :func:`AddEmergencyStop` (``log=True``).
LOGGED_PLANNER_OUTPUTS = ("com", "com_vel", "zmp", "left_foot", "right_foot", "phase", "one_step_feasible")
LOGGED_IK_OUTPUTS = ("q", "ik_com_error", "ik_foot_error")


@dataclass
class EmergencyStopLog:
    """Per-servo-tick log of an emergency stop, read from the diagram's loggers.

    World frame (x forward, y left, z up), SI units; row ``k`` is servo tick
    ``times[k]``.

    Attributes
    ----------
    times : numpy.ndarray
        Tick times, shape (n,) [s].
    com, com_vel : numpy.ndarray
        COG position [m] and velocity [m/s] the planner commanded, shape (n, 3).
    zmp : numpy.ndarray
        Planned ZMP, shape (n, 2) [m].
    phase : list of str
        Phase label per tick, one of ``PHASES`` (walking, landing, transition,
        slowdown, halt, stopped).
    left_foot, right_foot : numpy.ndarray
        Commanded sole position (x, y, lift), shape (n, 3) [m].
    q : numpy.ndarray
        The IK's joint positions, shape (n, plant.num_positions()) [m, rad]
        (the floating base first: quaternion, then position).
    ik_com_error, ik_foot_error : numpy.ndarray
        The IK's COG and worst sole-position error per tick, shape (n,) [m].
    one_step_feasible : numpy.ndarray
        1.0 where a stop signal at ``times[k]`` would stop within one step
        (the planner's ``one_step_feasible`` output of that tick; after the
        latch, whether the latched stop is one-step), else 0.0; shape (n,),
        dimensionless. NaN on the last row when that tick's update has not
        run yet (the output is logged one tick after its update).
    """

    times: np.ndarray
    com: np.ndarray
    com_vel: np.ndarray
    zmp: np.ndarray
    phase: list
    left_foot: np.ndarray
    right_foot: np.ndarray
    q: np.ndarray
    ik_com_error: np.ndarray
    ik_foot_error: np.ndarray
    one_step_feasible: np.ndarray


@dataclass
class EmergencyStop:
    """What :func:`AddEmergencyStop` added: the systems, their ports, and readers.

    Every reader takes the *root* (diagram) context of a simulation, e.g.
    ``simulator.get_context()``.

    Attributes
    ----------
    pattern : NominalPattern
        The nominal walk the stop interrupts (times in seconds from its start).
    trigger : EStopTrigger
        Latches the stop signal at a servo tick.
    planner : StopPlannerSystem
        Plays the walk, then the four-phase stop.
    ik : WholeBodyIK
        Turns the COG / sole / posture references into joint positions.
    plant : pydrake.multibody.plant.MultibodyPlant
        The robot's plant (the IK's model).
    robot : drake_estop.robots.RobotDescription
        The robot.
    scene_graph : pydrake.geometry.SceneGraph or None
        The scene graph the robot is drawn in (None when the user's plant is a
        system of the diagram and poses itself).
    stop_request : pydrake.systems.framework.InputPort
        The trigger's ``stop_request`` input (size 1; a value > 0.5 requests
        the stop). Connect or export it for an external stop source; leave it
        unconnected to use ``estop_time`` or the Meshcat button only.
    q : pydrake.systems.framework.OutputPort
        The IK's joint positions (plant.num_positions()) [m, rad], one solve
        per servo tick: connect it to your servo targets.
    com, zmp, phase, plan_port : pydrake.systems.framework.OutputPort
        The planner's COG target (3) [m], ZMP (2) [m], phase index into
        ``PHASES`` (1) and the stored stop plan (abstract; None before the latch).
    one_step_feasible : pydrake.systems.framework.OutputPort
        The planner's ``one_step_feasible`` (1, dimensionless): 1.0 if a stop
        signal at the last servo tick would stop within one step, 0.0 if it
        would take the next step; after the latch, the latched stop's case.
    loggers : dict
        Name -> ``VectorLogSink`` for every logged output (empty with ``log=False``).
    stop_visualizer : StopVisualizer or None
        The Meshcat traces, support polygon, phase plate and follow camera.
    """

    pattern: NominalPattern
    trigger: object
    planner: object
    ik: WholeBodyIK
    plant: MultibodyPlant
    robot: object
    scene_graph: SceneGraph | None
    stop_request: object
    q: object
    com: object
    zmp: object
    phase: object
    plan_port: object
    loggers: dict = field(default_factory=dict)
    visualizer: object = None
    stop_visualizer: object = None
    one_step_feasible: object = None

    def plan(self, context):
        """The stop plan in force, or None before the stop latched.

        Parameters
        ----------
        context : pydrake.systems.framework.Context
            The root context of the simulation.

        Returns
        -------
        StopPlan or None
            Phase end times (``landing_time``, ``transition_end``,
            ``slowdown_end``, ``halt_end``) in seconds on the pattern's clock.
        """
        planner_context = self.planner.GetMyContextFromRoot(context)
        plans = self.planner.plans(planner_context)
        return plans if plans is not None and len(plans.plans) > 1 else self.planner.plan(planner_context)

    def stop_time(self, context, *, after_halt=1.0):
        """Time to simulate to: the end of the halt plus ``after_halt`` [s].

        Parameters
        ----------
        context : pydrake.systems.framework.Context
            The root context, after the stop latched.
        after_halt : float, optional
            Seconds to keep simulating after the halt ends (default 1 s).

        Raises
        ------
        RuntimeError
            If the stop has not latched yet (simulate past the signal first).
        """
        plan = self._latched_plan(context)
        return float(plan.halt_end) + float(after_halt)

    def summary(self, context):
        """The stop's summary, as ``drake-estop simulate --summary`` writes it.

        Parameters
        ----------
        context : pydrake.systems.framework.Context
            The root context, after the stop latched.

        Returns
        -------
        dict
            ``estop_time`` [s], ``support``, ``case``, ``phase_times`` [s],
            ``step_length`` or ``zmp_max`` [m], ``final_feet`` [m], ...,
            ``metrics`` (time to rest [s], COG travel [m], final speed [m/s])
            and, with ``log=True``, ``ik`` (largest COG / sole errors [m]).

        Raises
        ------
        RuntimeError
            If the stop has not latched yet.
        """
        plan = self._latched_plan(context)
        summary = plan.summary()
        summary["metrics"] = stop_metrics(plan, rollout(plan))
        if self.loggers:
            log = self.log(context)
            summary["ik"] = {"ik_com_err_max_m": float(np.max(log.ik_com_error, initial=0.0)),
                             "ik_foot_err_max_m": float(np.max(log.ik_foot_error, initial=0.0))}
        return summary

    def log(self, context):
        """The per-servo-tick log recorded so far.

        Parameters
        ----------
        context : pydrake.systems.framework.Context
            The root context of the simulation.

        Returns
        -------
        EmergencyStopLog
            Arrays over the ticks logged so far (SI units, world frame).

        Raises
        ------
        RuntimeError
            If the stop was added with ``log=False``.
        """
        if not self.loggers:
            raise RuntimeError("AddEmergencyStop(log=False) added no loggers; pass log=True to read a log")
        logs = {name: logger.FindLog(context) for name, logger in self.loggers.items()}
        n = min(entry.sample_times().size for entry in logs.values())
        data = {name: entry.data()[:, :n].T for name, entry in logs.items()}
        # the planner's update of tick k sets one_step_feasible; the logger publishes it at tick k + 1
        feasible = np.full(n, np.nan)
        later = logs["one_step_feasible"].data()[0, 1:n + 1]
        feasible[:len(later)] = later
        return EmergencyStopLog(
            times=logs["com"].sample_times()[:n].copy(), com=data["com"], com_vel=data["com_vel"],
            zmp=data["zmp"], phase=[PHASES[int(round(p))] for p in data["phase"][:, 0]],
            left_foot=data["left_foot"][:, :3], right_foot=data["right_foot"][:, :3], q=data["q"],
            ik_com_error=data["ik_com_error"][:, 0], ik_foot_error=data["ik_foot_error"][:, 0],
            one_step_feasible=feasible)

    def _latched_plan(self, context):
        plan = self.plan(context)
        if plan is None:
            raise RuntimeError(f"the emergency stop has not latched by t = {context.get_time():.3f} s; "
                               "simulate past the signal (estop_time or a stop_request) first")
        return plan


def _check_plant(plant, robot):
    """The user's plant must be finalized and hold the robot's joints."""
    if not isinstance(plant, MultibodyPlant):
        raise TypeError(f"plant must be a pydrake MultibodyPlant, got {type(plant).__name__}")
    if not plant.is_finalized():
        raise ValueError("plant must be finalized (call plant.Finalize()) before AddEmergencyStop")
    missing = [name for name in robot.all_joints if not plant.HasJointNamed(name)]
    if missing:
        raise ValueError(f"plant lacks the humanoid's joints {missing[:3]}... ({len(missing)} of "
                         f"{len(robot.all_joints)} of robot {robot.name!r}); load it with "
                         "drake_estop.robots.add_robot(plant, robot)"
                         + (" or drake_estop.load_humanoid(plant)" if robot.name == "default" else ""))


def _in_builder(builder, system):
    return any(s is system for s in builder.GetSystems())


def _robot_plant(builder, plant, scene_graph, robot):
    """``(plant, scene_graph, pose_it)``: the IK's model and whether to pose it from ``q``."""
    if plant is not None:
        _check_plant(plant, robot)
        if _in_builder(builder, plant):
            return plant, scene_graph, False  # a diagram system (e.g. physics): the user drives it
        pose_it = scene_graph is not None and plant.geometry_source_is_registered()
        return plant, scene_graph, pose_it
    if scene_graph is None:
        scene_graph = builder.AddNamedSystem("scene_graph", SceneGraph())
    elif not isinstance(scene_graph, SceneGraph):
        raise TypeError(f"scene_graph must be a pydrake SceneGraph, got {type(scene_graph).__name__}")
    plant = MultibodyPlant(0.0)
    plant.RegisterAsSourceForSceneGraph(scene_graph)
    add_robot(plant, robot, contact=False)
    plant.Finalize()
    return plant, scene_graph, True


def _add_loggers(builder, planner, ik, period):
    ports = {name: planner.GetOutputPort(name) for name in LOGGED_PLANNER_OUTPUTS}
    ports.update(q=ik.q_port, ik_com_error=ik.com_error_port, ik_foot_error=ik.foot_error_port)
    return add_port_loggers(builder, ports, period, prefix="estop_log_")


def AddEmergencyStop(builder, *, plant=None, scene_graph=None, gait=None, stop=None, estop_time=None,
                     meshcat=None, log=True, publish_period=1.0 / 64.0, robot=None):
    """Add the emergency stop (trigger, stop planner, whole-body IK) to ``builder``.

    The robot walks the nominal pattern of ``gait`` until the stop latches
    (at ``estop_time``, on the ``stop_request`` input, or from the Meshcat
    "Emergency stop" button), then follows the four-phase stop of Morisawa et
    al. (2005) to rest.

    Parameters
    ----------
    builder : pydrake.systems.framework.DiagramBuilder
        The user's builder; it is not built here.
    plant : pydrake.multibody.plant.MultibodyPlant, optional
        The robot (finalized, loaded with :func:`drake_estop.robots.add_robot`,
        or for the default humanoid :func:`load_humanoid`). If it is a
        system of ``builder`` (e.g. a physics plant), the IK's ``q`` output is
        left for the user to connect to the servos; otherwise the helper poses
        it in ``scene_graph`` from ``q`` when it is registered there.
        Default: a new geometry-only plant of the robot (its own meshes).
    scene_graph : pydrake.geometry.SceneGraph, optional
        Where the robot is drawn. Default: a new one in ``builder`` (only when
        ``plant`` is not given).
    gait : GaitParameters, optional
        The nominal walk (default: the robot's,
        :func:`drake_estop.robots.parameters.gait_parameters`; for the default
        humanoid the paper's 0.3 m steps, 0.8 s cycle).
    stop : StopParameters, optional
        Weights and limits of the stop planner, servo period [s] (default:
        the paper's, with the robot's leg reach and crouch depth).
    estop_time : float, optional
        Time of the stop signal [s], latched at the next servo tick. None:
        only ``stop_request`` or the Meshcat button stop the walk.
    meshcat : pydrake.geometry.Meshcat, optional
        Draws the robot, the COG/ZMP traces, the support polygon, the phase and
        the one-step indicator (green: a stop now stops in one step; amber: it
        takes the next step), adds the "Emergency stop" button and a camera
        that follows the robot.
    log : bool, optional
        Log the planner's outputs and the IK's at every servo tick (default
        True), read with :meth:`EmergencyStop.log`.
    publish_period : float, optional
        Meshcat publish period [s] (default 1/64 s).
    robot : RobotDescription or str, optional
        The robot: a :class:`drake_estop.robots.RobotDescription`, a built-in
        robot's name (``default``, ``g1``, ``talos``) or a description YAML
        file (default: the ``default`` HRP-2-class humanoid).

    Returns
    -------
    EmergencyStop
        The added systems, their ports, and readers of the plan, summary and log.

    Raises
    ------
    ValueError
        If ``plant`` is not finalized or lacks the robot's joints, if
        ``estop_time`` is not finite and non-negative, if ``meshcat`` is
        given without a scene graph to draw from, if the gait swings joints
        the robot lacks, or naming the field of a bad robot description.
    TypeError
        If ``plant`` or ``scene_graph`` has the wrong type.

    Examples
    --------
    >>> from pydrake.systems.framework import DiagramBuilder
    >>> builder = DiagramBuilder()
    >>> estop = AddEmergencyStop(builder, estop_time=3.4)
    >>> diagram = builder.Build()
    """
    if estop_time is not None and not (np.isfinite(estop_time) and estop_time >= 0):
        raise ValueError(f"estop_time must be a finite time >= 0 s (or None), got {estop_time!r}")
    robot = as_robot(robot)
    gait = gait or gait_parameters(robot)
    stop = stop or stop_parameters(robot)
    pattern = NominalPattern(gait)
    layout = robot_layout(robot, pattern)
    if meshcat is not None and plant is not None and scene_graph is None:
        raise ValueError("meshcat needs a scene_graph to draw the robot from: pass the plant's scene_graph too")
    plant, scene_graph, pose_it = _robot_plant(builder, plant, scene_graph, robot)
    trigger, planner = add_stop_controller(builder, pattern=pattern, params=stop, estop_time=estop_time,
                                           meshcat=meshcat, layout=layout)
    ik = builder.AddNamedSystem("whole_body_ik", WholeBodyIK(
        plant=plant, servo_period=stop.servo_period, robot=robot,
        initial_q=initial_configuration(plant, pattern, robot=robot)))
    connect_reference(builder, planner, ik)
    if pose_it:
        to_pose = builder.AddNamedSystem("q_to_pose", MultibodyPositionToGeometryPose(plant))
        builder.Connect(ik.q_port, to_pose.get_input_port())
        builder.Connect(to_pose.get_output_port(), scene_graph.get_source_pose_port(plant.get_source_id()))
    loggers = _add_loggers(builder, planner, ik, stop.servo_period) if log else {}
    visualizer = stop_visualizer = None
    if meshcat is not None:
        visualizer, stop_visualizer = add_meshcat_views(builder, meshcat=meshcat, scene_graph=scene_graph,
                                                        planner=planner, pattern=pattern,
                                                        publish_period=publish_period, robot=robot)
    return EmergencyStop(pattern=pattern, trigger=trigger, planner=planner, ik=ik, plant=plant, robot=robot,
                         scene_graph=scene_graph, stop_request=trigger.stop_request_port, q=ik.q_port,
                         com=planner.GetOutputPort("com"), zmp=planner.GetOutputPort("zmp"),
                         phase=planner.GetOutputPort("phase"),
                         plan_port=planner.plan_port, loggers=loggers, visualizer=visualizer,
                         stop_visualizer=stop_visualizer, one_step_feasible=planner.one_step_feasible_port)
