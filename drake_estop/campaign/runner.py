"""One campaign run, its result row, and the campaign itself (:func:`run_campaign`).

A run is the ``drake-estop simulate --physics`` command of its
:class:`~drake_estop.campaign.config.RunParameters`, run in the worker's
long-lived child process (:class:`SimulateProcess`,
:mod:`drake_estop.campaign.child`): the row is built from that command's own
summary, so the reproduce command in the report is what ran. A run that
outlives the timeout has its process killed (a new one starts for the next
run); a run that raises, exits with an error, dies, or gives NaN where a
number must be becomes a row with ``outcome`` ``"error"`` or ``"timeout"``
and its message. Nothing a run does stops the campaign.
"""

from __future__ import annotations

import atexit
import datetime
import json
import math
import os
import select
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from drake_estop.campaign.config import CampaignConfig, ConfigError, RunParameters, campaign_runs, default_config
from drake_estop.campaign.executor import dask_client, pinned_environment, run_tasks
from drake_estop.campaign.report import write_report
from drake_estop.campaign.storage import CRITERIA, SCHEMA, ResultStore, row_table

#: Outcome columns a runner may return (the rest of :data:`SCHEMA` are the parameters and the wall time).
OUTCOME_COLUMNS = tuple(name for name in SCHEMA.names[SCHEMA.get_field_index("outcome"):]
                        if name not in ("wall_time", "command"))
#: Numbers a physics run must produce (a null / NaN there makes the run an error row).
REQUIRED_NUMBERS = ("pelvis_z_min", "torso_tilt_max", "final_cog_offset", "cog_travel", "slip_max",
                    "cop_margin_min")
_SUMMARY_NUMBERS = {"time_to_rest": "time_to_rest_s", "rest_after_halt": "rest_after_halt_s",
                    "final_cog_offset": "final_cog_offset_m", "cog_travel": "cog_travel_m",
                    "pelvis_z_min": "pelvis_z_min_m", "torso_tilt_max": "torso_tilt_max_rad",
                    "cop_margin_min": "cop_margin_plan_min_m", "sole_off_plan_max": "sole_off_plan_max_m",
                    "sole_turn_max": "sole_turn_max_rad"}
#: Numbers of :data:`_SUMMARY_NUMBERS` that a summary written before them lacks (their columns stay null).
_LATER_NUMBERS = ("sole_off_plan_max", "sole_turn_max")


class RunTimeout(RuntimeError):
    """A run exceeded its wall-time limit (its process was killed)."""


class RunCrashed(RuntimeError):
    """The run process died (or stopped answering) during a run."""


class CampaignInterrupted(KeyboardInterrupt):
    """Ctrl-C stopped the campaign after its finished runs were merged and reported."""


# --------------------------------------------------------------------------
# The run process.


#: Runs after which a run process is replaced by a fresh one (its memory grows by about 2 MB a run, measured).
RECYCLE_RUNS = 100


class SimulateProcess:
    """A ``python -m drake_estop.campaign.child`` process that runs ``drake-estop`` commands one at a time.

    It is started on the first run, replaced after ``recycle`` runs (bounding
    its memory) and after a timeout or a crash.
    """

    def __init__(self, recycle: int = RECYCLE_RUNS):
        self.process = None
        self.log = None
        self.recycle = recycle
        self.runs = 0

    def start(self):
        """Start the child with this interpreter, the thread pins, and this process's ``drake_estop`` first
        on its path (so that it runs the same code as the worker, also from a checkout)."""
        import drake_estop

        env = pinned_environment()
        root = str(Path(drake_estop.__file__).resolve().parents[1])
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [root, env.get("PYTHONPATH")]))
        self.log = tempfile.TemporaryFile()
        self.runs = 0
        self.process = subprocess.Popen(
            [sys.executable, "-m", "drake_estop.campaign.child"], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
            stderr=self.log, env=env, text=True, bufsize=1)

    def stop(self):
        """Kill the process (if any) and wait for it."""
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            self.process.wait()
        self.process = None

    def _log_tail(self) -> str:
        self.log.seek(0)
        return self.log.read().decode(errors="replace").strip()[-500:]

    def run(self, argv: list, timeout: float) -> dict:
        """The child's reply for ``drake-estop <argv>``; RunTimeout after ``timeout`` s, RunCrashed if it dies."""
        if self.process is not None and self.runs >= self.recycle:
            self.stop()
        if self.process is None or self.process.poll() is not None:
            self.start()
        self.runs += 1
        try:
            self.process.stdin.write(json.dumps({"argv": list(argv)}) + "\n")
            self.process.stdin.flush()
        except BrokenPipeError:
            code = self.process.wait()
            self.process = None
            raise RunCrashed(f"the run process had exited (status {code}): {self._log_tail()}") from None
        ready, _, _ = select.select([self.process.stdout], [], [], timeout)
        if not ready:
            self.stop()
            raise RunTimeout(f"no result within the {timeout:g} s timeout; the run process was killed")
        line = self.process.stdout.readline()
        if not line:
            code = self.process.wait()
            self.process = None
            raise RunCrashed(f"the run process died (status {code}): {self._log_tail()}")
        return json.loads(line)


_LOCAL = threading.local()
_PROCESSES = []


def _process() -> SimulateProcess:
    """This thread's run process (one per worker thread, kept between runs)."""
    if getattr(_LOCAL, "process", None) is None:
        _LOCAL.process = SimulateProcess()
        _PROCESSES.append(_LOCAL.process)
    return _LOCAL.process


@atexit.register
def _stop_processes():
    for process in _PROCESSES:
        process.stop()


# --------------------------------------------------------------------------
# Rows.


def _error_outcome(message: str, outcome: str = "error") -> dict:
    return {**dict.fromkeys(OUTCOME_COLUMNS), "outcome": outcome, "error": message, "success": False}


def outcome_from_reply(reply: dict) -> dict:
    """The outcome columns of a row from the child's reply to a ``simulate --physics`` command."""
    code, summary = reply["returncode"], reply["summary"]
    if reply["exception"]:
        return _error_outcome(f"simulate raised {reply['exception']}")
    if code not in (0, 1) or summary is None:
        lines = [line for line in reply["stderr"].splitlines() if line.strip()]
        return _error_outcome(f"simulate exited with status {code}: {lines[-1] if lines else 'no message'}")
    numbers = summary["physics"]["numbers"]
    values = {name: numbers.get(key) if name in _LATER_NUMBERS else numbers[key]
              for name, key in _SUMMARY_NUMBERS.items()}
    slips = (numbers["slip_left_m"], numbers["slip_right_m"])
    values["slip_max"] = None if None in slips else max(slips)
    missing = [name for name in REQUIRED_NUMBERS if values[name] is None]
    if missing:
        return _error_outcome(f"NaN in {', '.join(missing)} (the simulation diverged)")
    success = bool(summary["success"])
    if success != (code == 0):
        return _error_outcome(f"simulate exited with status {code} but its summary says success={success}")
    return {
        "outcome": "success" if success else "failure", "error": None, "success": success,
        "case": summary["case"], "support": summary["support"],
        **{name: bool(summary["criteria"][name]) for name in CRITERIA}, **values,
        "replans": summary["replans"], "replan_failures": summary["replan_failures"],
        # landings after the signal, and those a sideways push hurried or a double-support stop added
        "steps": summary["steps_after_signal"], "capture_landings": summary.get("capture_landings", 0),
        "recovery_steps": summary.get("recovery_steps", 0),
        "joint_velocity_violations": summary["joint_velocity_violations"],
        **_cop_exit_columns(summary["physics"].get("cop_exit")),
        **_capture_columns(summary.get("capturability")),
        "tick_p99": summary["tick_compute"]["p99"], "realtime_factor": numbers["realtime_factor"],
    }


def _cop_exit_columns(cop_exit: dict | None) -> dict:
    """``cop_exit_phase`` and ``cop_exit_edge`` of a summary's ``cop_exit`` (None where the CoP stayed in)."""
    if cop_exit is None:
        return {"cop_exit_phase": None, "cop_exit_edge": None}
    return {"cop_exit_phase": cop_exit["phase"], "cop_exit_edge": cop_exit["edge"]}


def _capture_columns(capturability: dict | None) -> dict:
    """``capture_steps`` and ``capture_margin`` of a summary's ``capturability`` (null: a summary without it)."""
    if capturability is None or capturability["steps"] is None:
        return {"capture_steps": None, "capture_margin": None}
    return {"capture_steps": capturability["steps"], "capture_margin": capturability["margin"]}


def simulate_run(params: RunParameters, timeout: float) -> dict:
    """Run ``params``' ``simulate --physics`` command in this worker's run process; its outcome columns."""
    return outcome_from_reply(_process().run(params.argv(), timeout))


def _nan_column(outcome: dict):
    for name, value in outcome.items():
        if isinstance(value, float) and math.isnan(value):
            return name
    return None


def guarded_run(job) -> dict:
    """The complete row of one run: ``job`` = (runner, params, timeout [s]); never raises for the run's sake.

    ``runner(params, timeout)`` returns the outcome columns (missing ones are
    null); an exception, a timeout, an unknown column or a NaN value gives an
    error (or timeout) row instead.
    """
    runner, params, timeout = job
    start = time.perf_counter()
    try:
        outcome = runner(params, timeout)
        unknown = sorted(set(outcome) - set(OUTCOME_COLUMNS))
        nan = _nan_column(outcome)
        if unknown:
            outcome = _error_outcome(f"the runner returned unknown columns {unknown}")
        elif nan is not None:
            outcome = _error_outcome(f"NaN in {nan}")
        else:
            outcome = {**dict.fromkeys(OUTCOME_COLUMNS), **outcome}
    except RunTimeout as error:
        outcome = _error_outcome(str(error), "timeout")
    except Exception as error:  # noqa: BLE001 - the run's error row; the campaign goes on
        outcome = _error_outcome(f"{type(error).__name__}: {error}")
    return {**params.record(), **outcome, "wall_time": time.perf_counter() - start, "command": params.command()}


def lost_row(params: RunParameters, error: BaseException) -> dict:
    """The row of a run whose task failed outside :func:`guarded_run` (e.g. its worker died)."""
    return {**params.record(), **_error_outcome(f"task failed: {type(error).__name__}: {error}"),
            "wall_time": None, "command": params.command()}


# --------------------------------------------------------------------------
# The campaign.


def _whole(option: str, value, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ConfigError(f"{option}: needs a whole number >= {low}, got {value!r}")
    return value


def _code_version() -> str:
    """``git describe`` of the package's checkout (``-dirty`` if modified), or ``unknown``."""
    folder = Path(__file__).resolve().parent
    try:
        done = subprocess.run(["git", "-C", str(folder), "describe", "--always", "--dirty"], capture_output=True,
                              text=True, timeout=10, check=True)
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return done.stdout.strip()


def run_campaign(*, runs: int, seed: int, out, config: CampaignConfig | None = None, workers: int | None = None,
                 scheduler: str | None = None, runner=None, progress: bool = True, robot: str = "default"):
    """Run (or resume) the campaign of ``runs`` runs from ``seed`` into the folder ``out``.

    Parameters
    ----------
    runs : int
        Runs 0 .. runs - 1 (>= 1); those whose seed ``out`` already holds are skipped.
    seed : int
        Campaign seed (>= 0); run i's seed is :func:`~drake_estop.campaign.config.run_seed` (seed, i).
    out : path
        Result folder (:class:`~drake_estop.campaign.storage.ResultStore`).
    config : CampaignConfig, optional
        Sampled ranges and the per-run timeout (default: ``default.yaml``).
    workers, scheduler
        Local worker processes, or the address of an existing Dask scheduler
        (:func:`~drake_estop.campaign.executor.dask_client`).
    runner : callable, optional
        ``runner(params, timeout) -> outcome columns``; default :func:`simulate_run` (physics).
        It must be importable by the workers.
    progress : bool
        Show the progress bar.
    robot : str
        The robot of every run (a built-in name or a description file; the manifest records it). The ranges
        are ``config``'s as given (:func:`~drake_estop.campaign.config.scaled_to_robot` makes the default ones
        the robot's).

    Writes ``out/report.html`` and its PNGs at the end (:func:`~drake_estop.campaign.report.write_report`),
    also after Ctrl-C (then raises :class:`CampaignInterrupted`, once the finished runs are merged).

    Returns
    -------
    pyarrow.Table
        One row per run of this campaign (:data:`~drake_estop.campaign.storage.SCHEMA`), by run index.

    Raises
    ------
    ConfigError
        A bad input (before anything is written).
    """
    runs, seed = _whole("--runs", runs, 1), _whole("--seed", seed, 0)
    runner = runner or simulate_run
    config = config or default_config()
    store = ResultStore(out)
    manifest = {"format": 1, "seed": seed, "config": config.as_yaml_dict(), "robot": robot}
    store.check(manifest)
    plans = campaign_runs(config, seed, runs, robot)
    with dask_client(workers, scheduler) as client:
        started = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
        store.open(manifest, {"started": started, "runs": runs, "code": _code_version(),
                              "workers": len(client.scheduler_info()["workers"])})
        done = store.seeds()
        todo = [params for params in plans if params.seed not in done]

        def record(index, row, error):
            store.write(row if error is None else lost_row(todo[index], error))

        try:
            run_tasks(client, guarded_run, [(runner, params, config.timeout) for params in todo],
                      on_result=record, progress=progress, desc="campaign", total=runs, initial=runs - len(todo))
        except KeyboardInterrupt:
            interrupted = True  # Ctrl-C: the finished runs are on disk; report them, then stop
        else:
            interrupted = False
    store.compact()
    table = campaign_table(store, plans)
    write_report(table, store.folder, manifest=json.loads(store.manifest_path.read_text()))
    if interrupted:
        raise CampaignInterrupted(f"interrupted with {table.num_rows}/{runs} runs finished; the same command "
                                  "resumes")
    return table


def campaign_table(store: ResultStore, plans) -> object:
    """The stored rows of the runs ``plans`` (by run index)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    table = store.read()
    wanted = pa.array([params.seed for params in plans], pa.int64())
    return table.filter(pc.is_in(table.column("seed"), value_set=wanted))


__all__ = ["run_campaign", "simulate_run", "guarded_run", "row_table", "SimulateProcess", "RunTimeout"]
