"""Shared by the paper-scenario scripts: one stop run through the public API, and paper-style figures.

The scripts import it from their own folder (Python puts a script's folder on
``sys.path``); everything else comes from ``from drake_estop import ...``.
"""

import time
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from pydrake.systems.analysis import Simulator  # noqa: E402
from pydrake.systems.framework import DiagramBuilder  # noqa: E402

from drake_estop import AddEmergencyStop, make_meshcat  # noqa: E402


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


def _phase_lines(ax, plan):
    ax.axvline(plan.signal_time, color="k", lw=1.0, ls="--", label="stop signal")
    for t in (plan.landing_time, plan.transition_end, plan.slowdown_end, plan.halt_end):
        ax.axvline(t, color="0.6", lw=0.8, ls=":")


def plot_cog_zmp(run, path, title):
    """COG and ZMP vs time, x and y (paper Fig. 9 / Fig. 12)."""
    fig, axes = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    for axis, ax in enumerate(axes):
        ax.plot(run.log.times, run.log.com[:, axis], "b-", label="COG")
        ax.plot(run.log.times, run.log.zmp[:, axis], "r--", label="ZMP")
        _phase_lines(ax, run.plan)
        ax.set_ylabel(f"{'xy'[axis]} [m]")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper left")
    axes[0].set_title(title)
    axes[1].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_knees(runs, path, title):
    """Knee angles of both legs for several runs (paper Fig. 10)."""
    fig, ax = plt.subplots(figsize=(7, 4))
    for label, run in runs.items():
        for side, style in (("left", "-"), ("right", "--")):
            ax.plot(run.log.times, np.degrees(run.knees[side]), style, label=f"{side} knee, {label}")
    _phase_lines(ax, next(iter(runs.values())).plan)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("knee angle [deg]")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
