"""Scaling of ``drake-estop campaign`` on this machine, measured in one run.

    python benchmarks/bench_campaign.py [--runs 4] [--noop 400]

1. **Runs per minute with 1 and 2 workers**: the same ``--runs`` campaign runs
   (default config, seed 123; the real physics runner, each in its worker's
   run process) on a local Dask cluster of 1 worker, then the same runs twice
   over on 2 workers (so both measure the same work per run). Each worker's
   run process is started and warmed up first (a kinematic ``simulate``), as
   it is after the first run of a long campaign.
   The CPU seconds of the run processes are measured too (psutil): on a
   shared machine the wall-time ratio shows the cores other jobs leave free;
   the CPU seconds per run show whether running two at once costs more work.
2. **Scheduler overhead per run**: ``--noop`` tasks that do nothing, submitted
   and collected through the same executor (``run_tasks``: submit,
   ``as_completed``, the callback), on the 1-worker cluster: wall time per task.
3. **10,000 runs on a 64-core cluster**, from those figures: 64 workers each
   at the per-worker rate measured with both cores of this machine busy,
   plus the scheduler overhead of every run as if it were serial (an upper
   bound: the scheduler overlaps it with the runs).

The machine is shared; the load average is printed with the numbers.
"""

from __future__ import annotations

import argparse
import os
import time

from drake_estop.campaign.config import campaign_runs, default_config
from drake_estop.campaign.executor import dask_client, run_tasks
from drake_estop.campaign.runner import _process, guarded_run, simulate_run

TIMEOUT = 900.0  # [s] per run: generous, the machine is shared


def warm(_):
    """Start this worker's run process and load Drake in it (a kinematic run)."""
    reply = _process().run(["simulate", "--kinematic", "--estop-time", "3.0"], TIMEOUT)
    if reply["returncode"] != 0:
        raise RuntimeError(f"warm-up run failed: {reply}")
    return os.getpid()


def noop(_):
    return None


def run_process_cpu_seconds() -> float:
    """User + system CPU seconds used so far by this worker's run processes (Dask ``client.run`` target)."""
    import psutil

    from drake_estop.campaign import runner

    total = 0.0
    for process in runner._PROCESSES:
        if process.process is not None and process.process.poll() is None:
            times = psutil.Process(process.process.pid).cpu_times()
            total += times.user + times.system
    return total


def _cpu(client) -> float:
    return sum(client.run(run_process_cpu_seconds).values())


def _warm_every_worker(client):
    workers = list(client.scheduler_info()["workers"])
    futures = [client.submit(warm, address, workers=[address], pure=False) for address in workers]
    pids = client.gather(futures)
    if len(set(pids)) != len(workers):
        raise RuntimeError(f"warm-up did not reach every worker: {pids}")


def _timed(client, function, items) -> tuple:
    """(wall time [s], results) of ``items`` through :func:`run_tasks`."""
    results = []
    start = time.perf_counter()
    run_tasks(client, function, items, on_result=lambda i, value, error: results.append((value, error)),
              progress=False)
    elapsed = time.perf_counter() - start
    errors = [error for _, error in results if error is not None]
    if errors:
        raise errors[0]
    return elapsed, [value for value, _ in results]


def measure(workers: int, params: list, repeat: int) -> dict:
    """Runs per minute of ``params`` x ``repeat`` on ``workers`` local workers (warmed up)."""
    with dask_client(workers) as client:
        _warm_every_worker(client)
        jobs = [(simulate_run, p, TIMEOUT) for p in params * repeat]
        cpu = _cpu(client)
        elapsed, rows = _timed(client, guarded_run, jobs)
        cpu = _cpu(client) - cpu
        outcomes = sorted({row["outcome"] for row in rows})
        figures = {"workers": workers, "runs": len(jobs), "elapsed_s": elapsed,
                   "runs_per_min": 60.0 * len(jobs) / elapsed, "outcomes": outcomes,
                   "cpu_per_run_s": cpu / len(jobs), "cpu_share": cpu / (elapsed * workers),
                   "run_wall_median_s": sorted(row["wall_time"] for row in rows)[len(rows) // 2]}
    return figures


def overhead(count: int) -> float:
    """Seconds per no-op task through the executor on a 1-worker local cluster."""
    with dask_client(1) as client:
        _timed(client, noop, range(20))  # connections up
        elapsed, _ = _timed(client, noop, range(count))
    return elapsed / count


def projection(per_worker_rate: float, task_overhead: float, runs: int = 10_000, cores: int = 64) -> dict:
    """Wall time [min] and core-hours of ``runs`` runs on ``cores`` single-threaded workers."""
    compute = runs / (cores * per_worker_rate)  # [min]
    scheduler = runs * task_overhead / 60.0  # [min], as if serial (upper bound)
    wall = compute + scheduler
    return {"compute_min": compute, "scheduler_min": scheduler, "wall_min": wall, "core_hours": cores * wall / 60.0}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=4, help="physics runs on 1 worker (2 workers run each twice)")
    parser.add_argument("--noop", type=int, default=400, help="no-op tasks for the scheduler overhead")
    args = parser.parse_args(argv)
    params = campaign_runs(default_config(), 123, args.runs)
    print(f"load average before: {os.getloadavg()}")
    one = measure(1, params, 1)
    two = measure(2, params, 2)
    per_task = overhead(args.noop)
    ratio = two["runs_per_min"] / one["runs_per_min"]
    plan = projection(two["runs_per_min"] / 2, per_task)
    print(f"1 worker : {one['runs']} runs in {one['elapsed_s']:.1f} s = {one['runs_per_min']:.2f} runs/min "
          f"(median run {one['run_wall_median_s']:.1f} s; outcomes {one['outcomes']})")
    print(f"2 workers: {two['runs']} runs in {two['elapsed_s']:.1f} s = {two['runs_per_min']:.2f} runs/min "
          f"(median run {two['run_wall_median_s']:.1f} s; outcomes {two['outcomes']})")
    print(f"ratio 2/1 workers: {ratio:.2f}x (target >= 1.7x)")
    for figures in (one, two):
        print(f"  {figures['workers']} worker(s): run-process CPU {figures['cpu_per_run_s']:.1f} s per run, "
              f"{100 * figures['cpu_share']:.0f} % of {figures['workers']} core(s) over the wall time")
    print(f"  CPU-bound ratio (the same CPU seconds per run on cores of their own): "
          f"{2 * one['cpu_per_run_s'] / two['cpu_per_run_s']:.2f}x")
    print(f"scheduler overhead: {per_task * 1e3:.2f} ms per task ({args.noop} no-op tasks, 1 worker)")
    print(f"10,000 runs on 64 cores (per-worker rate {two['runs_per_min'] / 2:.2f} runs/min with every core busy): "
          f"compute {plan['compute_min']:.1f} min + scheduler <= {plan['scheduler_min']:.2f} min = "
          f"{plan['wall_min']:.1f} min wall, {plan['core_hours']:.1f} core-hours")
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
