"""The online stop controller on the simulated robot: the design card's diagram with physics in the loop.

::

    WalkingPatternSource/EStopTrigger -> StopPlannerSystem --com, com_vel, zmp, feet--> BalanceController
    StopPlannerSystem --feet, upper_body--> WholeBodyIK <--com-- BalanceController
    WholeBodyIK --q--> DesiredStateInterpolator <--joint_offset (ankles)-- BalanceController
        --desired_state--> MultibodyPlant (PD servos, SAP contact)
    MultibodyPlant --state--> state estimate --com, com_vel--> BalanceController (and the planner)
    MultibodyPlant --contact_results--> FootForceSensors --wrenches--> BalanceController
                                    \\-> CopEstimator (logged CoP)

Every block is a LeafSystem updated by periodic discrete events at the servo
period; nothing is computed ahead of the tick that uses it (the nominal walk
is the pattern, built before the run).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from drake_estop.balance import BalanceController, BalanceParameters
from drake_estop.gait import GaitParameters, NominalPattern
from drake_estop.ik import WholeBodyIK, WholeBodyIkSolver
from drake_estop.physics import (_SOLE_FRAMES, SIDES, CopEstimator, JointReference, PhysicsParameters,
                                 _ik, actuated_indices, add_physics_plant, analyse, snap_time)
from drake_estop.planner import StopParameters
from drake_estop.stabilizer import CogMeasurement, DesiredStateInterpolator
from drake_estop.systems import add_stop_controller, connect_reference


@dataclass
class OnlineHandles:
    diagram: object
    plant: object
    scene_graph: object
    model_instance: object
    cop: object
    loggers: dict
    trigger: object
    planner: object
    balance: object
    ik: object
    estimator: object
    initial_q: np.ndarray


def _ankle_indices(plant):
    """Actuated-joint (desired_state) indices of each ankle's pitch and roll."""
    names = [plant.get_joint_actuator(i).joint().name() for i in plant.GetJointActuatorIndices()]
    return {side: (names.index(f"{side[0]}_ankle_pitch"), names.index(f"{side[0]}_ankle_roll"))
            for side in SIDES}


def build_online_diagram(pattern: NominalPattern, stop_params: StopParameters, estop_time: float | None, *,
                         physics: PhysicsParameters | None = None,
                         balance: BalanceParameters | None = None, pushes=(),
                         replan_threshold: float = 0.03) -> OnlineHandles:
    """The closed-loop physics diagram of the online controller (see the module docstring)."""
    from drake_estop.diagram import initial_configuration as pattern_initial_configuration

    physics = physics or PhysicsParameters()
    dt = stop_params.servo_period
    builder = DiagramBuilder()
    plant, scene_graph, instance, _ = add_physics_plant(builder, physics)
    from drake_estop.perturbations import add_pelvis_push
    add_pelvis_push(builder, plant, pushes)
    soles = [plant.GetBodyByName(_SOLE_FRAMES[side]) for side in SIDES]
    cop = builder.AddNamedSystem("cop_estimator", CopEstimator(plant=plant, scene_graph=scene_graph, bodies=soles))
    builder.Connect(plant.get_contact_results_output_port(), cop.contact_results_port)

    trigger, planner = add_stop_controller(builder, pattern=pattern, params=stop_params, estop_time=estop_time,
                                           replan_threshold=replan_threshold)
    kin_plant, _, _ = _ik()
    q0 = pattern_initial_configuration(kin_plant, pattern)
    ik = builder.AddNamedSystem("whole_body_ik", WholeBodyIK(
        plant=kin_plant, servo_period=dt, initial_q=q0, solver=WholeBodyIkSolver(kin_plant)))
    connect_reference(builder, planner, ik)
    estimator = builder.AddNamedSystem("state_estimator", CogMeasurement(plant=plant))
    builder.Connect(plant.get_state_output_port(), estimator.state_port)
    builder.Connect(estimator.com_port, planner.measured_com_port)
    builder.Connect(estimator.com_vel_port, planner.measured_com_vel_port)
    q_idx, _ = actuated_indices(plant)
    ctrl = builder.AddNamedSystem("balance_controller", BalanceController(
        servo_period=dt, sole=pattern.params.sole, num_actuated=len(q_idx), ankle_indices=_ankle_indices(plant),
        total_mass=plant.CalcTotalMass(plant.CreateDefaultContext()), params=balance))
    builder.Connect(planner.com_port, ctrl.planned_com_port)
    builder.Connect(planner.com_vel_port, ctrl.planned_com_vel_port)
    builder.Connect(planner.zmp_port, ctrl.planned_zmp_port)
    builder.Connect(planner.left_foot_port, ctrl.left_foot_port)
    builder.Connect(planner.right_foot_port, ctrl.right_foot_port)
    builder.Connect(estimator.com_port, ctrl.measured_com_port)
    builder.Connect(estimator.com_vel_port, ctrl.measured_com_vel_port)
    builder.Connect(cop.cop_port, ctrl.measured_cop_port)
    builder.Connect(cop.body_normal_forces_port, ctrl.foot_forces_port)
    builder.Disconnect(planner.com_port, ik.com_port)
    builder.Connect(ctrl.com_port, ik.com_port)
    desired = builder.AddNamedSystem("desired_state", DesiredStateInterpolator(
        q_indices=q_idx, initial_q=q0, servo_period=dt))
    builder.Connect(ik.q_port, desired.q_port)
    builder.Connect(ctrl.joint_offset_port, desired.joint_offset_port)
    builder.Connect(desired.desired_state_port, plant.get_desired_state_input_port(instance))

    period = physics.log_period
    loggers = {
        "state": LogVectorOutput(plant.get_state_output_port(), builder, period),
        "cop": LogVectorOutput(cop.cop_port, builder, period),
        "normal_force": LogVectorOutput(cop.normal_force_port, builder, period),
        "foot_forces": LogVectorOutput(cop.body_normal_forces_port, builder, period),
        "ik_q": LogVectorOutput(ik.q_port, builder, period),
        "ik_com_error": LogVectorOutput(ik.com_error_port, builder, period),
        "ik_foot_error": LogVectorOutput(ik.foot_error_port, builder, period),
        "commanded_zmp": LogVectorOutput(ctrl.commanded_zmp_port, builder, period),
        "com_offset": LogVectorOutput(ctrl.com_offset_port, builder, period),
        "dcm_error": LogVectorOutput(ctrl.dcm_error_port, builder, period),
        "joint_offset": LogVectorOutput(ctrl.joint_offset_port, builder, period),
    }
    diagram = builder.Build()
    diagram.set_name("estop_online")
    return OnlineHandles(diagram, plant, scene_graph, instance, cop, loggers, trigger, planner, ctrl, ik,
                         estimator, q0)


def run_online(gait_params: GaitParameters | None = None, stop_params: StopParameters | None = None,
               estop_time: float = 3.4, *, after_halt: float = 2.5, physics: PhysicsParameters | None = None,
               balance: BalanceParameters | None = None, pattern: NominalPattern | None = None, pushes=(),
               replan_threshold: float = 0.03):
    """Walk, stop at ``estop_time`` with the online controller, and check the success criteria."""
    from drake_estop.diagram import IK_COM_BOUND, IK_FOOT_BOUND

    physics = physics or PhysicsParameters()
    stop_params = stop_params or StopParameters()
    pattern = pattern or NominalPattern(gait_params or GaitParameters())
    handles = build_online_diagram(pattern, stop_params, estop_time, physics=physics, balance=balance,
                                   pushes=pushes, replan_threshold=replan_threshold)
    simulator = Simulator(handles.diagram)
    context = simulator.get_mutable_context()
    handles.plant.SetPositions(handles.plant.GetMyMutableContextFromRoot(context), handles.initial_q)
    simulator.Initialize()
    dt = stop_params.servo_period
    planner_context = handles.planner.GetMyContextFromRoot(context)
    start = time.perf_counter()
    simulator.AdvanceTo(snap_time(estop_time, dt) + 2 * dt)
    plan = handles.planner.plan(planner_context)
    if plan is None:
        raise RuntimeError(f"the planner did not plan a stop by t = {context.get_time():.3f} s")
    end = dt * math.floor((max(plan.halt_end, plan.signal_time) + after_halt) / dt + 1e-9)
    simulator.AdvanceTo(end)
    wall = time.perf_counter() - start
    q_log = handles.loggers["ik_q"].FindLog(context)
    com_err = handles.loggers["ik_com_error"].FindLog(context).data()[0]
    foot_err = handles.loggers["ik_foot_error"].FindLog(context).data()[0]
    failures = int(np.sum((com_err > IK_COM_BOUND) | (foot_err > IK_FOOT_BOUND)))
    reference = JointReference(q_log.sample_times(), q_log.data().T, com_err, foot_err, failures, 0.0)
    result = analyse(handles, context, plan, reference, physics, wall)
    result.online = {name: handles.loggers[name].FindLog(context).data().T
                     for name in ("commanded_zmp", "com_offset", "dcm_error", "joint_offset")}
    result.replans = handles.planner.replans(planner_context)
    return result
