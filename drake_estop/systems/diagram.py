"""The Drake diagram: trigger -> stop planner -> whole-body IK -> humanoid -> Meshcat.

::

    EStopTrigger --stop--> StopPlannerSystem --com, feet, upper_body--> WholeBodyIK
        WholeBodyIK --q--> MultibodyPositionToGeometryPose --> SceneGraph --> MeshcatVisualizer
        StopPlannerSystem --com, zmp, phase, plan, one_step_feasible--> StopVisualizer (Meshcat traces)
        loggers: planner com / com_vel / zmp / feet / phase / one_step_feasible, IK q and IK errors

The robot (the ``default`` humanoid, or any described one: ``robot=``) is
kinematic: the plant is registered with the SceneGraph for its geometry only
(the model's own meshes, :func:`drake_estop.robots.add_robot`) and posed by
the IK's positions (no dynamics, no contact).
The MultibodyPlant itself is not a System of the diagram; the handles keep it
alive (MultibodyPositionToGeometryPose references it).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np
from pydrake.geometry import MeshcatVisualizer, MeshcatVisualizerParams, Role, SceneGraph
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, EventStatus
from pydrake.systems.primitives import LogVectorOutput
from pydrake.systems.rendering import MultibodyPositionToGeometryPose

from drake_estop.model import joint_position_indices
from drake_estop.planning.gait import NominalPattern
from drake_estop.planning.plan import LONGEST_STOP
from drake_estop.planning.planner import PHASES
from drake_estop.robots.description import SIDES
from drake_estop.robots.parameters import as_robot, standing_height, stop_parameters, walk_pattern
from drake_estop.robots.plant import add_robot, sole_frame
from drake_estop.systems.decision import StopPlannerConfig
from drake_estop.systems.ik import WholeBodyIK, converged_posture
from drake_estop.systems.multibody_zmp import multibody_zmp, support_margins
from drake_estop.systems.reference import ReferenceLayout, connect_reference, pattern_layout, reference_vector
from drake_estop.systems.stop_controller import add_stop_controller

#: Bounds every IK tick must meet (COG and sole position [m], sole rotation [rad]).
IK_COM_BOUND = 1e-3
IK_FOOT_BOUND = 1e-3
IK_FOOT_ROT_BOUND = 1e-2


@dataclass
class DiagramHandles:
    """The built diagram and the systems/loggers a caller reads."""

    diagram: object
    plant: MultibodyPlant
    scene_graph: SceneGraph
    pattern: NominalPattern
    trigger: object
    planner: object
    ik: WholeBodyIK
    loggers: dict
    meshcat: object = None
    visualizer: object = None
    stop_visualizer: object = None
    robot: object = None  # the RobotDescription
    layout: ReferenceLayout = None


def robot_layout(robot, pattern) -> ReferenceLayout:
    """The reference layout of ``robot`` (a description, a name or None: the default) walking ``pattern``.

    Raises
    ------
    ValueError
        Naming ``gait.arms.joints`` when the pattern swings joints the robot's upper body lacks.
    """
    return pattern_layout(pattern, ReferenceLayout.of(as_robot(robot), pattern.params.arms))


def initial_configuration(plant, pattern, *, attempts=20, robot=None):
    """IK solution for the pattern at t = 0 (the first tick starts converged).

    The standing posture has the feet under the hips; the walk starts with
    the feet ``step_width`` apart, so the IK is solved offline here instead
    of letting the first servo tick jump. ``robot``: the robot in ``plant``
    (default: the ``default`` humanoid).
    """
    layout = robot_layout(robot, pattern)
    parts = layout.split(reference_vector(0.0, pattern=pattern, layout=layout))
    return converged_posture(plant, parts["com"], parts["left_foot"], parts["right_foot"],
                             dict(zip(layout.upper_body, parts["upper_body"])), attempts=attempts, robot=robot)


def _add_plant(builder, robot):
    """SceneGraph in the diagram, the robot's plant registered for geometry (its visuals, no contact)."""
    scene_graph = builder.AddNamedSystem("scene_graph", SceneGraph())
    plant = MultibodyPlant(0.0)
    plant.RegisterAsSourceForSceneGraph(scene_graph)
    add_robot(plant, robot, contact=False)
    plant.Finalize()
    return plant, scene_graph


def add_port_loggers(builder, ports: dict, period: float, prefix: str = "log_") -> dict:
    """A ``LogVectorOutput`` per ``ports`` entry (name -> output port), sampled every ``period`` [s]
    and named ``prefix + name``; returns name -> logger."""
    loggers = {}
    for name, port in ports.items():
        logger = LogVectorOutput(port, builder, publish_period=period)
        logger.set_name(f"{prefix}{name}")
        loggers[name] = logger
    return loggers


def _add_loggers(builder, planner, ik, period):
    """Vector loggers of the planner outputs and the IK outputs, one per tick."""
    ports = {name: planner.GetOutputPort(name) for name in
             ("com", "com_vel", "zmp", "left_foot", "right_foot", "phase", "arm_joints", "one_step_feasible")}
    ports.update(q=ik.q_port, ik_com_error=ik.com_error_port,
                 ik_foot_error=ik.foot_error_port,
                 velocity_limit_violations=ik.violations_port)
    return add_port_loggers(builder, ports, period)


def build_diagram(*, gait_params=None, stop_params=None, estop_time=None, meshcat=None,
                  button_name="Emergency stop", publish_period=1.0 / 64.0, robot=None, plan_ahead=True,
                  pattern=None):
    """Build the e-stop diagram; returns :class:`DiagramHandles`.

    ``estop_time`` schedules the stop (None: only the Meshcat button or the
    exported ``stop_request`` input stop the walk).  With ``meshcat`` the
    robot (MeshcatVisualizer), traces and phase (StopVisualizer) are drawn
    and an "Emergency stop" button is added. ``robot`` (a
    :class:`~drake_estop.robots.RobotDescription`, a built-in name or a
    description file; default the ``default`` humanoid) is the robot; the
    gait and stop parameters default to its own
    (:func:`drake_estop.robots.parameters.gait_parameters`, ``stop_parameters``).
    ``plan_ahead``: :class:`~drake_estop.systems.stop_controller.StopPlannerSystem`'s (every tick
    plans the stop of a signal at it, so the latch takes it ready). ``pattern``: a walk built already
    (e.g. :func:`drake_estop.systems.whole_body_walk.whole_body_pattern`'s), instead of
    ``NominalPattern(gait_params)``; give one of the two.
    """
    robot = as_robot(robot)
    pattern = walk_pattern(robot, gait_params, pattern)
    stop_params = stop_params or stop_parameters(robot)
    layout = robot_layout(robot, pattern)
    builder = DiagramBuilder()
    plant, scene_graph = _add_plant(builder, robot)
    trigger, planner = add_stop_controller(
        builder, pattern=pattern, params=stop_params, estop_time=estop_time,
        meshcat=meshcat, button_name=button_name, layout=layout,
        config=StopPlannerConfig(plan_ahead=plan_ahead))
    builder.ExportInput(trigger.stop_request_port, "stop_request")
    ik = builder.AddNamedSystem("whole_body_ik", WholeBodyIK(
        plant=plant, servo_period=stop_params.servo_period, robot=robot,
        initial_q=initial_configuration(plant, pattern, robot=robot)))
    connect_reference(builder, planner, ik)
    to_pose = builder.AddNamedSystem("q_to_pose", MultibodyPositionToGeometryPose(plant))
    builder.Connect(ik.q_port, to_pose.get_input_port())
    builder.Connect(to_pose.get_output_port(),
                    scene_graph.get_source_pose_port(plant.get_source_id()))
    loggers = _add_loggers(builder, planner, ik, stop_params.servo_period)
    visualizer = stop_visualizer = None
    if meshcat is not None:
        visualizer, stop_visualizer = add_meshcat_views(builder, meshcat=meshcat, scene_graph=scene_graph,
                                                        planner=planner, pattern=pattern,
                                                        publish_period=publish_period, robot=robot)
    diagram = builder.Build()
    diagram.set_name("estop_diagram")
    return DiagramHandles(diagram, plant, scene_graph, pattern, trigger, planner, ik,
                          loggers, meshcat, visualizer, stop_visualizer, robot, layout)


def add_meshcat_views(builder, *, meshcat, scene_graph, planner, pattern, publish_period, robot=None):
    """The robot (``MeshcatVisualizer``, its illustration geometry) and the stop's traces, polygon, phase,
    one-step indicator over the robot's head and follow camera (``StopVisualizer``).

    Parameters
    ----------
    builder : pydrake.systems.framework.DiagramBuilder
        Where to add them.
    meshcat, scene_graph, planner, pattern
        The Meshcat, the scene graph the robot is registered in, the :class:`StopPlannerSystem` and its
        pattern.
    publish_period : float
        Meshcat publish period [s].
    robot : RobotDescription or str, optional
        The robot (its height places the indicator and the camera; default the ``default`` humanoid).

    Returns
    -------
    tuple
        ``(MeshcatVisualizer, StopVisualizer)``.
    """
    from drake_estop.systems.visualization import INDICATOR_CLEARANCE, StopVisualizer, follow_camera_paths

    visualizer = MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat, MeshcatVisualizerParams(
        publish_period=publish_period, role=Role.kIllustration, prefix="robot"))
    stop_visualizer = builder.AddNamedSystem("stop_visualizer", StopVisualizer(
        meshcat=meshcat, pattern=pattern, publish_period=publish_period, follow=follow_camera_paths(),
        indicator_height=standing_height(as_robot(robot)) + INDICATOR_CLEARANCE))
    for name in ("com", "zmp", "phase", "plan", "one_step_feasible"):
        builder.Connect(planner.GetOutputPort(name), stop_visualizer.GetInputPort(name))
    return visualizer, stop_visualizer


# --------------------------------------------------------------------------
# Simulation and results.


@dataclass
class DiagramResult:
    """Per-tick arrays of one simulated stop (rows = servo ticks)."""

    times: np.ndarray
    com: np.ndarray  # (n, 3) COG target the IK was given at the tick
    com_vel: np.ndarray  # (n, 3)
    zmp: np.ndarray  # (n, 2)
    phases: list  # PHASES labels
    feet: dict  # side -> (n, 3) sole xyz targets
    q: dict  # "q_<joint>" -> (n,) for every joint the robot's description names
    q_full: np.ndarray  # (n, nq) plant positions
    ik_com_err: np.ndarray  # (n,) recomputed with the plant at the logged q [m]
    ik_foot_err: np.ndarray  # (n,) worst sole position error [m]
    ik_foot_rot_err: np.ndarray  # (n,) worst sole rotation error [rad]
    ik_reported_com_err: np.ndarray  # (n,) as reported by WholeBodyIK
    ik_reported_foot_err: np.ndarray
    velocity_limit_violations: np.ndarray  # (n,) joints over their velocity limit
    joint_limit_violations: np.ndarray  # (n,) joints outside their position limits
    plan: object
    wall_time: float  # seconds of Simulator.AdvanceTo
    plan_wall_time: float  # seconds the latch took inside the planner's update (a look-up where planned ahead)
    html: object = None
    ik_failures: dict = field(default_factory=dict)
    logged_reference: dict = field(default_factory=dict)  # planner outputs as logged
    #: (n,) 1.0 if a stop signal at the tick would stop in one step (after the latch: the latched plan's case)
    one_step_feasible: np.ndarray = None
    #: (n, 2) the whole body's ZMP of the IK's q [m] (:func:`drake_estop.systems.multibody_zmp.multibody_zmp`:
    #: the limbs' angular momentum included, which the plan's LIPM ZMP leaves out)
    multibody_zmp: np.ndarray = None
    #: (n,) its distance inside the soles the targets put on the floor [m] (negative outside)
    multibody_zmp_margin: np.ndarray = None

    @property
    def sim_time(self):
        return float(self.times[-1] - self.times[0])

    @property
    def realtime_factor(self):
        """Simulated seconds per wall-clock second."""
        return self.sim_time / self.wall_time if self.wall_time > 0 else float("inf")

    def columns(self):
        """Extra per-tick CSV columns (name -> (n,) array) for rollout.write_log."""
        cols = dict(self.q)
        cols.update(ik_com_err=self.ik_com_err, ik_foot_err=self.ik_foot_err,
                    ik_foot_rot_err=self.ik_foot_rot_err,
                    velocity_limit_violations=self.velocity_limit_violations,
                    one_step_feasible=self.one_step_feasible)
        return cols

    def error_summary(self):
        """Maxima and counts of ticks over the IK bounds (never silent)."""
        return {
            "ik_com_err_max_m": float(self.ik_com_err.max()),
            "ik_foot_err_max_m": float(self.ik_foot_err.max()),
            "ik_foot_rot_err_max_rad": float(self.ik_foot_rot_err.max()),
            "ik_ticks_over_bounds": dict(self.ik_failures),
            "velocity_limit_violations": int(self.velocity_limit_violations.sum()),
            "joint_limit_violations": int(self.joint_limit_violations.sum()),
            "ticks": int(len(self.times)),
            **self.multibody_zmp_summary(),
        }

    def multibody_zmp_summary(self) -> dict:
        """The whole body's ZMP margin in the soles on the floor [m], least over the run and over the stop
        (from the signal): below 0 the plan asks the floor for a ZMP outside the feet (None: not computed)."""
        margins = self.multibody_zmp_margin
        if margins is None or not np.any(np.isfinite(margins)):
            return {"multibody_zmp_margin_min_m": None, "stop_multibody_zmp_margin_min_m": None}
        stop = margins[self.times >= self.plan.signal_time] if self.plan is not None else margins[:0]
        return {"multibody_zmp_margin_min_m": float(np.nanmin(margins)),
                "stop_multibody_zmp_margin_min_m": float(np.nanmin(stop)) if np.any(np.isfinite(stop)) else None}


def _sole_errors(plant, robot, q_log, left, right):
    """COG and worst sole position / rotation error at every logged q (plant FK)."""
    context = plant.CreateDefaultContext()
    frames = tuple(sole_frame(plant, robot, side) for side in SIDES)
    n = q_log.shape[0]
    com = np.empty((n, 3))
    pos_err = np.zeros(n)
    rot_err = np.zeros(n)
    for i in range(n):
        plant.SetPositions(context, q_log[i])
        com[i] = plant.CalcCenterOfMassPositionInWorld(context)
        for frame, target in zip(frames, (left[i], right[i])):
            pose = frame.CalcPoseInWorld(context)
            pos_err[i] = max(pos_err[i], np.linalg.norm(pose.translation() - target[:3]))
            quat = target[3:7] / np.linalg.norm(target[3:7])
            angle = 2.0 * np.arccos(min(1.0, abs(float(
                quat @ pose.rotation().ToQuaternion().wxyz()))))
            rot_err[i] = max(rot_err[i], angle)
    return com, pos_err, rot_err


def _logged(handles, context):
    """(times, data) of every logger, trimmed to the common tick count."""
    logs = {name: logger.FindLog(context) for name, logger in handles.loggers.items()}
    n = min(log.sample_times().size for log in logs.values())
    times = logs["com"].sample_times()[:n]
    return times, {name: log.data()[:, :n].T for name, log in logs.items()}


def _align_ticks(handles, context):
    """Per servo tick k: the targets the IK was given and the q it returned.

    Loggers publish at t_k *before* the updates of tick k, so the IK state
    logged at t_(k+1) is the solve of tick k.  The planner's unrestricted
    update runs before the IK's discrete update in the same tick, so the IK
    at t_k saw the reference at t_k of the plan stored by then; the plan
    evaluates to the nominal pattern before its start, so the reference of
    the final plan at t_k is exactly what the IK was given at every tick.
    The planner's ``one_step_feasible`` (discrete state set by its update of
    tick k) is likewise logged at t_(k+1).
    """
    times, data = _logged(handles, context)
    plan = handles.planner.plan(handles.planner.GetMyContextFromRoot(context))
    targets = np.array([reference_vector(t, pattern=handles.pattern, plan=plan, layout=handles.layout)
                        for t in times[:-1]])
    ref = handles.layout.split(targets)
    solved = {name: data[name][1:] for name in
              ("q", "ik_com_error", "ik_foot_error", "velocity_limit_violations", "one_step_feasible")}
    return times[:-1], ref, solved, data, plan


def collect_result(handles, context, *, wall_time, html=None):
    """Build a :class:`DiagramResult` from the loggers in ``context``."""
    plant, joint_names = handles.plant, handles.robot.all_joints
    times, ref, solved, logged, plan = _align_ticks(handles, context)
    q_log = solved["q"]
    com_fk, foot_err, rot_err = _sole_errors(plant, handles.robot, q_log, ref["left_foot"], ref["right_foot"])
    com_err = np.linalg.norm(com_fk - ref["com"], axis=1)
    idx = joint_position_indices(plant, joint_names)
    lower, upper = plant.GetPositionLowerLimits()[idx], plant.GetPositionUpperLimits()[idx]
    joints = q_log[:, idx]
    limit_viol = np.sum((joints < lower - 1e-9) | (joints > upper + 1e-9), axis=1)
    planner_context = handles.planner.GetMyContextFromRoot(context)
    failures = {"com": int(np.sum(com_err > IK_COM_BOUND)),
                "foot_position": int(np.sum(foot_err > IK_FOOT_BOUND)),
                "foot_rotation": int(np.sum(rot_err > IK_FOOT_ROT_BOUND))}
    n = len(times)
    feet = {"left": ref["left_foot"], "right": ref["right_foot"]}
    zmp = multibody_zmp(plant, q_log, float(times[1] - times[0]), com=com_fk) if n >= 3 else None
    result = DiagramResult(
        times=times, com=ref["com"], com_vel=ref["com_vel"], zmp=ref["zmp"],
        phases=[PHASES[int(round(p))] for p in ref["phase"][:, 0]],
        feet={"left": ref["left_foot"][:, :3], "right": ref["right_foot"][:, :3]},
        q={f"q_{name}": joints[:, k] for k, name in enumerate(joint_names)},
        q_full=q_log, ik_com_err=com_err, ik_foot_err=foot_err, ik_foot_rot_err=rot_err,
        ik_reported_com_err=solved["ik_com_error"][:, 0],
        ik_reported_foot_err=solved["ik_foot_error"][:, 0],
        velocity_limit_violations=solved["velocity_limit_violations"][:, 0],
        joint_limit_violations=limit_viol, plan=plan, wall_time=wall_time,
        plan_wall_time=handles.planner.plan_wall_time(planner_context), html=html,
        ik_failures=failures, one_step_feasible=solved["one_step_feasible"][:, 0], multibody_zmp=zmp,
        multibody_zmp_margin=None if zmp is None else support_margins(zmp, feet, handles.pattern.params.sole),
        logged_reference={name: logged[name][:n] for name in
                          ("com", "com_vel", "zmp", "left_foot", "right_foot", "phase")})
    _warn_failures(result)
    return result


def _warn_failures(result):
    """An IK that misses its bounds is reported, never silent."""
    over = {k: v for k, v in result.ik_failures.items() if v}
    if over or result.velocity_limit_violations.sum() or result.joint_limit_violations.sum():
        warnings.warn(f"whole-body IK missed its bounds: ticks over bound {over}, "
                      f"velocity-limit violations {int(result.velocity_limit_violations.sum())}, "
                      f"joint-limit violations {int(result.joint_limit_violations.sum())}",
                      RuntimeWarning, stacklevel=3)


def end_time(handles, context, after_halt):
    """Halt end of the stored plan (or end of the walk) plus ``after_halt`` [s], and the tick that logs the
    last solve."""
    plan = handles.planner.plan(handles.planner.GetMyContextFromRoot(context))
    end = plan.halt_end if plan is not None else handles.pattern.end_time
    # one and a half ticks more: the solve of the last tick is logged at the next
    return end + after_halt + 1.5 * handles.planner.params.servo_period


def run(handles, *, after_halt=1.0, realtime_rate=0.0):
    """Simulate until ``after_halt`` past the halt (or past the walk's end).

    A ``Simulator`` monitor re-reads the plan from the planner's Context after
    every step and ends the run once that time is reached, so a stop latched
    live by the Meshcat button also ends it. Returns ``(simulator, wall_time)``.
    """
    simulator = Simulator(handles.diagram)
    simulator.set_target_realtime_rate(realtime_rate)
    context = simulator.get_mutable_context()

    def monitor(root_context):
        if root_context.get_time() >= end_time(handles, root_context, after_halt) - 1e-9:
            return EventStatus.ReachedTermination(handles.diagram, "past the halt")
        return EventStatus.DidNothing()

    simulator.set_monitor(monitor)
    start = time.perf_counter()
    simulator.Initialize()
    # the bound is never reached: the walk's end (where the latest stop ends) plus the longest stop
    simulator.AdvanceTo(end_time(handles, context, after_halt) + LONGEST_STOP)
    simulator.clear_monitor()
    return simulator, time.perf_counter() - start



def simulate_diagram(gait_params=None, stop_params=None, estop_time=3.4, *, html=None,
                     meshcat=None, after_halt=1.0, realtime_rate=None, robot=None, pattern=None):
    """Build, run to ``halt_end + after_halt`` and collect a :class:`DiagramResult`.

    ``html``: write a self-contained Meshcat replay there (a Meshcat is
    created if none is given).  ``realtime_rate`` defaults to 1 for a live
    Meshcat without a replay file (so a person can press the button), else
    as fast as possible. ``robot``, ``pattern``: see :func:`build_diagram`.
    """
    from drake_estop.systems.visualization import add_floor_under, make_meshcat, start_recording, write_replay

    if html is not None and meshcat is None:
        meshcat = make_meshcat()
    if realtime_rate is None:
        realtime_rate = 1.0 if (meshcat is not None and html is None) else 0.0
    handles = build_diagram(gait_params=gait_params, stop_params=stop_params,
                            estop_time=estop_time, meshcat=meshcat, robot=robot, pattern=pattern)
    if meshcat is not None:
        add_floor_under(meshcat, handles.pattern)  # the camera: StopVisualizer
    if html is not None:
        start_recording(meshcat)
    simulator, wall = run(handles, after_halt=after_halt, realtime_rate=realtime_rate)
    if html is not None:
        html = write_replay(meshcat, html)
    return collect_result(handles, simulator.get_context(), wall_time=wall, html=html)


__all__ = ["DiagramHandles", "DiagramResult", "build_diagram", "simulate_diagram", "add_meshcat_views",
           "collect_result", "run", "initial_configuration", "robot_layout", "IK_COM_BOUND",
           "IK_FOOT_BOUND", "IK_FOOT_ROT_BOUND"]
