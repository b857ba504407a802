"""The physics stop map: one stop per signal time over a stride.

:func:`sweep` runs a physics stop (online controller or offline filter) for
signals every ``every`` seconds; :func:`write_sweep` writes the table as CSV
and the stop map figure (matplotlib).
"""

from __future__ import annotations

import csv
import functools
import math
from pathlib import Path

import numpy as np

from drake_estop.physics.criteria import CRITERIA, PhysicsResult
from drake_estop.physics.offline import run_physics
from drake_estop.physics.plant import PhysicsParameters
from drake_estop.planning.gait import GaitParameters, NominalPattern
from drake_estop.planning.planner import StopParameters


def sweep_row(result: PhysicsResult) -> dict:
    """One row of the stop map."""
    plan = result.plan
    numbers = result.numbers()
    row = {
        "signal_time": plan.signal_time, "support": plan.support, "case": plan.case,
        "step_length": plan.step_length, "zmp_max": plan.zmp_max,
        "planned_time_to_rest": plan.halt_end - plan.signal_time,
        "time_to_rest": result.time_to_rest, "cog_travel": result.cog_travel,
        **{name: bool(result.criteria[name]) for name in CRITERIA},
        "success": result.success,
        "pelvis_z_min": numbers["pelvis_z_min_m"], "torso_tilt_max": numbers["torso_tilt_max_rad"],
        "slip_max": max(result.slip.values()), "rest_after_halt": numbers["rest_after_halt_s"],
        "final_cog_offset": result.final_offset, "cop_margin_min": numbers["cop_margin_plan_min_m"],
        "cop_edge_time": numbers["cop_edge_time_s"], "realtime_factor": result.realtime_factor,
    }
    return row


def sweep(gait_params: GaitParameters | None = None, stop_params: StopParameters | None = None, *,
          every: float = 0.02, start: float | None = None, duration: float | None = None,
          progress: bool = True, physics: PhysicsParameters | None = None, after_halt: float = 2.5,
          run=None, executor=None, robot=None):
    """:func:`run_physics` for stop signals every ``every`` s over one stride (default: the
    third step, :meth:`NominalPattern.stride`, single then double support).

    Returns a list of :func:`sweep_row` dicts in signal order; a run that
    raises (e.g. an infeasible plan) gives a row with ``success`` False and
    the ``error``. ``run`` (default :func:`run_physics`, the offline-filter
    reference) is called as ``run(gait_params, stop_params, t, after_halt=...,
    physics=..., pattern=...)`` and returns a :class:`PhysicsResult`
    (e.g. :func:`drake_estop.physics.online.run_online`). ``executor(function, jobs)``
    (e.g. :func:`drake_estop.campaign.executor.map_tasks`, the campaign's Dask
    executor) maps :func:`sweep_job` over the jobs in order; without it the
    runs are serial in this process. ``robot`` (a description, a name or None: the default humanoid) is
    given to every run (``run(..., robot=robot)``), and the gait and stop parameters default to its own.
    """
    if robot is not None:
        from drake_estop.robots.parameters import as_robot, gait_parameters, stop_parameters

        robot = as_robot(robot)
        gait_params = gait_params or gait_parameters(robot)
        stop_params = stop_params or stop_parameters(robot)
        run = functools.partial(run or run_physics, robot=robot)
    gait_params = gait_params or GaitParameters()
    stop_params = stop_params or StopParameters()
    pattern = _sweep_pattern(gait_params)
    duration = gait_params.step_time if duration is None else duration
    start = pattern.stride()[0] if start is None else start
    count = int(math.floor(duration / every + 1e-9))
    jobs = [(gait_params, stop_params, float(t), after_halt, physics, run) for t in start + every * np.arange(count)]
    if executor is not None:
        return executor(sweep_job, jobs)
    from tqdm import tqdm
    return [sweep_job(job) for job in tqdm(jobs, desc="physics sweep", unit="run", disable=not progress)]


@functools.lru_cache(maxsize=8)
def _sweep_pattern(gait_params: GaitParameters) -> NominalPattern:
    """The nominal pattern of ``gait_params``, built once per process."""
    return NominalPattern(gait_params)


def sweep_job(job) -> dict:
    """One sweep run: ``job`` = (gait, stop, signal time [s], after_halt [s], physics, run); a :func:`sweep_row`."""
    gait_params, stop_params, t, after_halt, physics, run = job
    run = run or run_physics
    try:
        result = run(gait_params, stop_params, t, after_halt=after_halt, physics=physics,
                     pattern=_sweep_pattern(gait_params))
        return sweep_row(result)
    except Exception as error:  # noqa: BLE001 - recorded in the table
        return {"signal_time": t, "success": False, "error": f"{type(error).__name__}: {error}"}


def write_sweep(table, csv_path, png_path=None):
    """Write the sweep table as CSV and (optionally) the stop map figure."""
    columns = []
    for row in table:
        columns += [k for k in row if k not in columns]
    Path(csv_path).parent.mkdir(parents=True, exist_ok=True)
    with open(csv_path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns)
        writer.writeheader()
        for row in table:
            writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})
    if png_path is not None:
        _plot_stop_map(table, png_path)


def _plot_stop_map(table, png_path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def column(name):
        return np.array([np.nan if row.get(name) is None else float(row.get(name, np.nan)) for row in table])

    t = column("signal_time")
    ok = np.array([bool(row.get("success")) for row in table])
    fig, axes = plt.subplots(5, 1, figsize=(8, 11), sharex=True)
    cases = sorted({row.get("case", "error") for row in table})
    for k, case in enumerate(cases):
        mask = np.array([row.get("case", "error") == case for row in table])
        axes[0].scatter(t[mask], np.full(mask.sum(), k), label=case)
        for support, marker in (("single", "s"), ("double", "o")):
            sub = mask & np.array([row.get("support") == support for row in table])
            axes[0].scatter(t[sub], np.full(sub.sum(), k), marker=marker, facecolors="none", edgecolors="k")
    axes[0].set_yticks(range(len(cases)), cases)
    axes[0].set_title("case taken (squares: single support, circles: double support at the signal)")
    axes[1].plot(t, column("step_length"), "o-", label="step length (single support)")
    axes[1].plot(t, column("zmp_max"), "s-", label="ZMP_max (double support)")
    axes[1].set_ylabel("[m]")
    axes[1].legend(fontsize=8)
    axes[2].plot(t, column("planned_time_to_rest"), "o-", label="planned (halt end)")
    axes[2].plot(t, column("time_to_rest"), "s-", label="measured (COG < 1 cm/s)")
    axes[2].set_ylabel("time to rest [s]")
    axes[2].legend(fontsize=8)
    axes[3].plot(t, column("cog_travel"), "o-")
    axes[3].set_ylabel("COG travel [m]")
    axes[4].scatter(t[ok], np.ones(ok.sum()), c="tab:green", label="success")
    axes[4].scatter(t[~ok], np.zeros((~ok).sum()), c="tab:red", label="failure")
    axes[4].set_yticks([0, 1], ["fail", "ok"])
    axes[4].set_xlabel("stop signal time [s]")
    axes[4].legend(fontsize=8)
    fig.suptitle(f"Physics stop map: {ok.sum()}/{len(ok)} stops meet every criterion")
    fig.tight_layout()
    Path(png_path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png_path, dpi=110)
    plt.close(fig)
