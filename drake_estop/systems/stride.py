"""A stop signal at every servo tick of a stride, each through the kinematic Drake diagram.

:func:`sweep_stride` builds the diagram of :func:`drake_estop.systems.diagram.build_diagram`
once, with no scheduled signal, and runs it once per signal time: the walk up
to the signal with the exported ``stop_request`` input at 0, then at 1 from
the signal's servo tick on (the trigger latches there, as a scheduled
``estop_time`` at that tick does), to ``after_halt`` past the halt. Each run
gives a :class:`StrideStop`: the stop's case and the whole-body IK's worst
errors and joint-limit counts; :func:`stride_summary` sums them up (the
one-step share, the worst IK COG error, the joint-speed violations).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import asdict, dataclass

import numpy as np
from pydrake.systems.analysis import Simulator

from drake_estop.planning.rollout import stride_ticks
from drake_estop.systems.diagram import DiagramResult, build_diagram, collect_result, end_time


@dataclass(frozen=True)
class StrideStop:
    """One signal of a stride sweep (lengths in m, angles in rad, times in s).

    Attributes
    ----------
    signal_time : float
        The servo tick of the signal [s].
    support, case : str
        The plan's support at the signal and its case ("one-step", "next-step", ...).
    time_to_rest : float
        Signal to the end of the halt [s].
    final_phase : str
        The phase at the run's last tick ("stopped" once the halt has ended).
    final_speed : float
        The commanded COG speed at the last tick [m/s].
    ik_com_error, ik_foot_error, ik_foot_rotation_error : float
        The IK's worst COG and sole position error [m] and sole rotation error [rad] over the run.
    ik_ticks_over_bounds : int
        Ticks where one of them is over its bound (1 mm, 1 mm, 0.01 rad).
    velocity_limit_violations, joint_limit_violations : int
        Joint-ticks over a joint's speed limit; joints outside their position range, summed over ticks.
    wall_time : float
        Wall-clock time of the run [s].
    stop_multibody_zmp_margin : float or None
        The whole body's ZMP's least margin in the soles on the floor from the signal on [m] (negative:
        outside; :func:`drake_estop.systems.multibody_zmp.multibody_zmp`, the limbs' momentum included).
    """

    signal_time: float
    support: str
    case: str
    time_to_rest: float
    final_phase: str
    final_speed: float
    ik_com_error: float
    ik_foot_error: float
    ik_foot_rotation_error: float
    ik_ticks_over_bounds: int
    velocity_limit_violations: int
    joint_limit_violations: int
    wall_time: float
    stop_multibody_zmp_margin: float | None = None

    @classmethod
    def of(cls, result: DiagramResult) -> StrideStop:
        """The row of one run's :class:`~drake_estop.systems.diagram.DiagramResult`."""
        plan, errors = result.plan, result.error_summary()
        return cls(signal_time=float(plan.signal_time), support=plan.support, case=plan.case,
                   time_to_rest=float(plan.halt_end - plan.signal_time), final_phase=result.phases[-1],
                   final_speed=float(np.linalg.norm(result.com_vel[-1])),
                   ik_com_error=errors["ik_com_err_max_m"], ik_foot_error=errors["ik_foot_err_max_m"],
                   ik_foot_rotation_error=errors["ik_foot_rot_err_max_rad"],
                   ik_ticks_over_bounds=int(max(errors["ik_ticks_over_bounds"].values())),
                   velocity_limit_violations=errors["velocity_limit_violations"],
                   joint_limit_violations=errors["joint_limit_violations"], wall_time=result.wall_time,
                   stop_multibody_zmp_margin=errors["stop_multibody_zmp_margin_min_m"])


def run_signal(handles, signal_time: float, *, after_halt: float = 1.0) -> DiagramResult:
    """One run of a diagram built without a scheduled signal, the stop requested at ``signal_time`` [s].

    Parameters
    ----------
    handles : drake_estop.systems.diagram.DiagramHandles
        From ``build_diagram(estop_time=None)``.
    signal_time : float
        A servo tick of the walk [s].
    after_halt : float, optional
        Seconds simulated past the halt [s].

    Returns
    -------
    DiagramResult
    """
    simulator = Simulator(handles.diagram)
    context = simulator.get_mutable_context()
    request = handles.diagram.GetInputPort("stop_request")
    request.FixValue(context, [0.0])
    start = time.perf_counter()
    simulator.Initialize()
    simulator.AdvanceTo(signal_time)  # the updates of the signal's tick run at the next step: they see the request
    request.FixValue(context, [1.0])
    simulator.AdvanceTo(signal_time + 2 * handles.planner.params.servo_period)  # latched, then planned
    # the first tick at or after the end, where the monitor of drake_estop.systems.diagram.run stops
    period = handles.planner.params.servo_period
    simulator.AdvanceTo(np.ceil(end_time(handles, context, after_halt) / period - 1e-6) * period)
    wall = time.perf_counter() - start
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the misses are in the result
        return collect_result(handles, context, wall_time=wall)


def sweep_stride(*, robot=None, gait=None, stop=None, every: int = 1, step_index: int = 2, after_halt: float = 1.0,
                 progress=None) -> list[StrideStop]:
    """A stop signal at every ``every``-th servo tick of a stride of ``robot``'s walk, each through the diagram.

    Parameters
    ----------
    robot : RobotDescription or str, optional
        The robot (default: the ``default`` humanoid).
    gait, stop : GaitParameters, StopParameters, optional
        Default: the robot's (:mod:`drake_estop.robots.parameters`).
    every : int, optional
        Signal spacing in servo ticks (default 1: every tick).
    step_index : int, optional
        The stride: single then double support of this step (default 2, the third).
    after_halt : float, optional
        Seconds simulated past each halt [s].
    progress : callable, optional
        Called with each :class:`StrideStop` as it is done.

    Returns
    -------
    list of StrideStop
    """
    if not (isinstance(every, int) and every >= 1):
        raise ValueError(f"every must be a whole number of servo ticks >= 1, got {every!r}")
    # a sweep measures the stops, not the latch's latency: no plan ahead of the latch on every walking tick
    handles = build_diagram(gait_params=gait, stop_params=stop, estop_time=None, robot=robot, plan_ahead=False)
    rows = []
    for signal in stride_ticks(handles.pattern, handles.planner.params, step_index)[::every]:
        rows.append(StrideStop.of(run_signal(handles, float(signal), after_halt=after_halt)))
        if progress is not None:
            progress(rows[-1])
    return rows


def stride_summary(rows: list[StrideStop]) -> dict:
    """Signals, one-step share, worst IK errors [m, rad], ticks over the IK's bounds, joint-speed and
    joint-range violations, the time to rest (median, worst) [s] and the whole body's ZMP in the stops (the
    least margin [m], the signals whose stop puts it outside the soles) of a sweep."""
    one_step = sum(row.case == "one-step" for row in rows)
    rest = np.array([row.time_to_rest for row in rows])
    margins = [row.stop_multibody_zmp_margin for row in rows if row.stop_multibody_zmp_margin is not None]
    return {
        "signals": len(rows), "one_step": one_step, "one_step_share": one_step / len(rows),
        "stopped": sum(row.final_phase == "stopped" for row in rows),
        "final_speed_max_m_s": max(row.final_speed for row in rows),
        "ik_com_error_max_m": max(row.ik_com_error for row in rows),
        "ik_foot_error_max_m": max(row.ik_foot_error for row in rows),
        "ik_foot_rotation_error_max_rad": max(row.ik_foot_rotation_error for row in rows),
        "ik_ticks_over_bounds": sum(row.ik_ticks_over_bounds for row in rows),
        "signals_with_ik_misses": sum(row.ik_ticks_over_bounds > 0 for row in rows),
        "velocity_limit_violations": sum(row.velocity_limit_violations for row in rows),
        "signals_with_velocity_violations": sum(row.velocity_limit_violations > 0 for row in rows),
        "joint_limit_violations": sum(row.joint_limit_violations for row in rows),
        "time_to_rest_median_s": float(np.median(rest)), "time_to_rest_max_s": float(rest.max()),
        "stop_multibody_zmp_margin_min_m": min(margins) if margins else None,
        "signals_with_multibody_zmp_outside": sum(margin < 0 for margin in margins),
    }


def rows_as_dicts(rows: list[StrideStop]) -> list[dict]:
    """The rows as plain dicts (for JSON or CSV)."""
    return [asdict(row) for row in rows]
