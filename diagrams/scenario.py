"""Shared by the paper-scenario scripts: one stop run through the public API, and paper-style figures.

The scripts import it from their own folder (Python puts a script's folder on
``sys.path``); everything else comes from ``from drake_estop import ...``.
"""

import time
from dataclasses import dataclass
from pathlib import Path

from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

import drake_estop
from drake_estop import AddEmergencyStop, make_meshcat


@dataclass
class StopRun:
    """One simulated stop: its summary (dict), per-tick log, plan and knee angles [rad]."""

    summary: dict
    log: object
    plan: object
    knees: dict
    wall_time: float


def run_stop(gait, stop, signal, *, html=None, after_halt=1.0):
    """Simulate the stop signalled at ``signal`` [s]; with ``html``, write the Meshcat replay there."""
    meshcat = make_meshcat() if html is not None else None
    builder = DiagramBuilder()
    estop = AddEmergencyStop(builder, gait=gait, stop=stop, estop_time=signal, meshcat=meshcat)
    simulator = Simulator(builder.Build())
    if meshcat is not None:
        meshcat.StartRecording(frames_per_second=64.0, set_visualizations_while_recording=True)
    start = time.perf_counter()
    simulator.AdvanceTo(signal + 2 * stop.servo_period)  # the stop latches and is planned at its tick
    context = simulator.get_context()
    simulator.AdvanceTo(estop.stop_time(context, after_halt=after_halt))
    wall = time.perf_counter() - start
    if meshcat is not None:
        meshcat.StopRecording()
        meshcat.PublishRecording()
        Path(html).parent.mkdir(parents=True, exist_ok=True)
        Path(html).write_text(meshcat.StaticHtml())
    log = estop.log(context)
    knees = {side: log.q[:, estop.plant.GetJointByName(f"{side[0]}_knee").position_start()]
             for side in ("left", "right")}
    return StopRun(estop.summary(context), log, estop.plan(context), knees, wall)


def describe(run):
    """One line about a stop: case, phase ends, plan time, IK errors, real-time factor."""
    s, times = run.summary, run.summary["phase_times"]
    rate = (run.log.times[-1] - run.log.times[0]) / run.wall_time
    return (f"signal {s['estop_time']:.3f} s ({s['support']} support) -> {s['case']}; landing "
            f"{times['landing_end']:.3f}, transition {times['transition_end']:.3f}, slowdown "
            f"{times['slowdown_end']:.3f}, halt {times['halt_end']:.3f} s; plan "
            f"{s['plan_compute_time_s'] * 1e3:.2f} ms; IK max COG {s['ik']['ik_com_err_max_m'] * 1e3:.3f} mm, "
            f"foot {s['ik']['ik_foot_err_max_m'] * 1e3:.3f} mm; real-time factor {rate:.1f}")


def plot_cog_zmp(run, path, title):
    """COG and ZMP vs time, x and y (paper Fig. 9 / Fig. 12)."""
    return drake_estop.plot_cog_zmp(run.log.times, run.log.com, run.log.zmp, run.plan, path, title)


def plot_knees(runs, path, title):
    """Knee angles of both legs for several runs (paper Fig. 10)."""
    knees = {label: (run.log.times, run.knees) for label, run in runs.items()}
    return drake_estop.plot_knees(knees, next(iter(runs.values())).plan, path, title)
