"""drake-estop campaign: sampling, bad inputs, kill-and-resume, the run process, one physics run."""

import dataclasses
import json
import os
import signal
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from campaign_helpers import fake_run
from robot_helpers import needs_robots

from drake_estop.campaign.config import (
    ConfigError,
    config_from_mapping,
    default_config,
    load_config,
    run_seed,
    sample_run,
)
from drake_estop.campaign.executor import dask_client, map_tasks, pinned_environment
from drake_estop.campaign.runner import (
    RunTimeout,
    SimulateProcess,
    guarded_run,
    outcome_from_reply,
    run_campaign,
    simulate_run,
)
from drake_estop.campaign.storage import CRITERIA, TIMING_COLUMNS, ResultStore, row_table
from drake_estop.cli import build_parser, main

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent


# -- sampling


def test_one_seed_always_gives_the_same_parameters():
    config = default_config()
    seed = run_seed(7, 3)
    assert seed == run_seed(7, 3) and len({run_seed(7, i) for i in range(200)}) == 200
    assert run_seed(7, 3) != run_seed(8, 3)
    first, again = sample_run(config, seed, 3), sample_run(config, seed, 3)
    assert first == again
    # the parameters derive from the seed alone: the run index is only a label
    assert sample_run(config, seed, 99).record() == {**first.record(), "run": 99}
    assert sample_run(config, run_seed(7, 4)) != sample_run(config, seed)


def test_samples_stay_in_the_configured_ranges_and_on_the_grids():
    config = default_config()
    for i in range(100):
        params = sample_run(config, run_seed(1, i), i)
        assert config.push_impulse[0] <= params.push_impulse <= config.push_impulse[1] + 0.01
        assert config.mass_scale[0] <= params.mass_scale <= config.mass_scale[1]
        assert params.latency in (0, 1) and 0.0 <= params.signal_phase <= 1.0
        assert abs(params.estop_time / 0.005 - round(params.estop_time / 0.005)) < 1e-6  # servo tick
        assert abs(params.push_time / 0.001 - round(params.push_time / 0.001)) < 1e-6  # plant step
        assert -0.1 - 1e-9 <= params.push_onset <= 0.2 + 0.003


def test_the_reproduce_command_carries_every_sampled_value():
    params = sample_run(default_config(), run_seed(0, 0))
    args = build_parser().parse_args(params.argv())
    assert args.physics and args.estop_time == params.estop_time
    assert (args.step_length, args.step_time, args.step_width) == (params.step_length, params.step_time,
                                                                  params.step_width)
    assert args.push == [[params.push_time, params.push_fx, params.push_fy, params.push_duration]]
    assert (args.mass_scale, args.torso_mass_scale, args.torso_com_offset, args.friction, args.latency,
            args.sensor_noise, args.seed) == (params.mass_scale, params.torso_mass_scale, params.torso_com_offset,
                                              params.friction, params.latency, params.sensor_noise, params.seed)
    assert params.command().startswith("drake-estop simulate --physics --estop-time ")


def test_small_negative_values_reach_simulate_as_numbers():
    """The default campaign found it: ``--torso-com-offset -5e-05`` was read by argparse as an option."""
    params = dataclasses.replace(sample_run(default_config(), run_seed(0, 0)), torso_com_offset=-5e-05,
                                 push_fy=-0.01)
    args = build_parser().parse_args(params.argv())
    assert args.torso_com_offset == -5e-05 and args.push[0][2] == -0.01
    assert "-0.00005" in params.command()


def test_a_config_file_overrides_the_defaults_key_by_key(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("push:\n  impulse: [0, 10]\nsensors:\n  noise_probability: 0\n")
    config = load_config(path)
    assert config.push_impulse == (0.0, 10.0) and config.noise_probability == 0.0
    assert config.step_time == default_config().step_time
    assert config_from_mapping(config.as_yaml_dict()) == config


# -- bad inputs: exit status 2, the field named, nothing written


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.mark.parametrize("text, field", [
    ("gait:\n  stp_length: [0.2, 0.3]\n", "gait.stp_length"),
    ("push:\n  onset: [0.2, -0.1]\n", "push.onset"),
    ("push:\n  impulse: [-5, 10]\n", "push.impulse"),
    ("model:\n  mass_scale: [0, 1.1]\n", "model.mass_scale"),
    ("sensors:\n  latency: [0, 1.5]\n", "sensors.latency"),
])
def test_a_bad_config_exits_2_naming_the_key_and_writes_nothing(tmp_path, capsys, text, field):
    config, out = tmp_path / "bad.yaml", tmp_path / "out"
    config.write_text(text)
    assert main(["campaign", "--runs", "3", "--out", str(out), "--config", str(config)]) == 2
    assert field in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("runs", ["0", "-2", "1.5"])
def test_runs_must_be_positive(tmp_path, capsys, runs):
    assert main(["campaign", "--runs", runs, "--out", str(tmp_path / "out")]) == 2
    assert "--runs" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_an_unreachable_scheduler_exits_2_within_seconds(tmp_path, capsys):
    start = time.perf_counter()
    code = main(["campaign", "--runs", "2", "--out", str(tmp_path / "out"),
                 "--scheduler", f"tcp://127.0.0.1:{_free_port()}", "--no-progress"])
    assert code == 2 and time.perf_counter() - start < 10.0
    assert "--scheduler" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_out_pointing_at_a_file_exits_2(tmp_path, capsys):
    target = tmp_path / "results.txt"
    target.write_text("keep me")
    assert main(["campaign", "--runs", "2", "--out", str(target)]) == 2
    assert "--out" in capsys.readouterr().err
    assert target.read_text() == "keep me" and sorted(p.name for p in tmp_path.iterdir()) == ["results.txt"]


def test_workers_and_scheduler_exclude_each_other(tmp_path):
    assert main(["campaign", "--runs", "2", "--out", str(tmp_path / "o"), "--workers", "1",
                 "--scheduler", "tcp://127.0.0.1:1"]) == 2
    assert main(["sweep", "--workers", "0"]) == 2


# -- kill and resume, through the real executor and storage (stand-in runs of 0.25 s)

KILLED_CAMPAIGN = textwrap.dedent("""
    import signal
    import sys
    # Ctrl-C as in a terminal, whatever this test inherited: a test run started in the background by a
    # non-interactive shell ignores SIGINT, and so would the campaign (it then ran to the end: exit 0)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    sys.path.insert(0, {tests!r})
    from campaign_helpers import fake_run
    from drake_estop.campaign.runner import CampaignInterrupted, run_campaign
    if __name__ == "__main__":
        try:
            run_campaign(runs={runs}, seed=11, out={out!r}, workers=2, runner=fake_run, progress=False)
        except CampaignInterrupted:
            sys.exit(130)
""")


def _parts(out: Path) -> list:
    folder = out / "results"
    return sorted(folder.glob("run-*.parquet")) if folder.exists() else []


def _start_and_kill(out: Path, runs: int, tmp_path: Path, *, interrupt: bool = False):
    """Start a campaign in its own process group, SIGKILL the group once 4 runs are on disk; parts left.

    With ``interrupt``: SIGINT to the campaign process alone instead (Ctrl-C); returns its exit status.
    """
    script = tmp_path / "campaign_script.py"
    script.write_text(KILLED_CAMPAIGN.format(tests=str(TESTS), runs=runs, out=str(out)))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
           "CAMPAIGN_FAKE_SLEEP": "0.25"}
    process = subprocess.Popen([sys.executable, str(script)], env=env, start_new_session=True)
    deadline = time.monotonic() + 90
    while len(_parts(out)) < 4 and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    if interrupt:
        process.send_signal(signal.SIGINT)
        code = process.wait(timeout=60)
        os.killpg(process.pid, signal.SIGKILL)  # any worker left behind
        return code
    os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    return len(_parts(out))


def _deterministic(table) -> list:
    return table.drop_columns(list(TIMING_COLUMNS)).to_pylist()


@pytest.mark.slow
def test_a_killed_campaign_resumes_to_the_uninterrupted_table(tmp_path):
    runs, out = 16, tmp_path / "killed"
    left = _start_and_kill(out, runs, tmp_path)
    assert 4 <= left < runs, "the campaign must be killed part-way"
    before = {}
    for part in _parts(out):  # every part on disk is complete
        row = pq.read_table(part).to_pylist()
        assert len(row) == 1
        before[row[0]["seed"]] = row[0]["wall_time"]
    resumed = run_campaign(runs=runs, seed=11, out=out, workers=2, runner=fake_run, progress=False)
    # the runs finished before the kill were skipped, not run again (their measured wall times are kept)
    assert {row["seed"]: row["wall_time"] for row in resumed.to_pylist() if row["seed"] in before} == before
    sessions = json.loads((out / "campaign.json").read_text())["sessions"]
    assert len(sessions) == 2 and not list(out.glob("results/.tmp-*"))
    seeds = resumed.column("seed").to_pylist()
    assert resumed.num_rows == runs and len(set(seeds)) == runs
    assert seeds == [run_seed(11, i) for i in range(runs)]
    whole = run_campaign(runs=runs, seed=11, out=tmp_path / "whole", workers=2, runner=fake_run, progress=False)
    assert _deterministic(resumed) == _deterministic(whole)
    # a run that raises or returns NaN is an error row; the others carry their outcome
    rows = resumed.to_pylist()
    assert rows[3]["outcome"] == "error" and "injected failure in run 3" in rows[3]["error"]
    assert rows[5]["outcome"] == "error" and "NaN in cog_travel" in rows[5]["error"]
    assert {row["outcome"] for i, row in enumerate(rows) if i % 7 not in (3, 5)} <= {"success", "failure"}
    # the report: self-contained, every failure with its reproduce command
    report = (out / "report.html").read_text()
    assert report.count("data:image/png;base64,") == 3 and "http" not in report.replace("http-equiv", "")
    failures = [row for row in rows if not row["success"]]
    assert failures and all(row["command"] in report for row in failures)
    assert all((out / name).stat().st_size > 10_000 for name in ("push_recovery_map.png", "success_vs_phase.png",
                                                                 "success_vs_model_error.png"))


def test_ctrl_c_merges_and_reports_the_finished_runs(tmp_path):
    out = tmp_path / "interrupted"
    assert _start_and_kill(out, 40, tmp_path, interrupt=True) == 130
    table = ResultStore(out).read()
    assert 4 <= table.num_rows < 40 and not _parts(out)  # merged into results.parquet
    assert pq.read_table(out / "results.parquet").num_rows == table.num_rows
    assert (out / "report.html").exists()


def test_resuming_with_another_seed_exits_2(tmp_path, capsys):
    out = tmp_path / "c"
    run_campaign(runs=2, seed=1, out=out, workers=1, runner=fake_run, progress=False)
    before = sorted(p.name for p in out.iterdir())
    assert main(["campaign", "--runs", "2", "--seed", "2", "--out", str(out)]) == 2
    assert "--out" in capsys.readouterr().err and sorted(p.name for p in out.iterdir()) == before


def test_map_tasks_keeps_the_order_and_raises_a_task_error():
    import math

    assert map_tasks(math.sqrt, [16.0, 1.0, 9.0], workers=1, progress=False) == [4.0, 1.0, 3.0]
    with pytest.raises(ValueError):
        map_tasks(math.sqrt, [4.0, -1.0], workers=1, progress=False)


def test_workers_run_numerical_libraries_on_one_thread():
    names = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")
    with dask_client(2) as client:
        seen = client.run(lambda: [os.environ.get(name) for name in names])
        threads = {worker["nthreads"] for worker in client.scheduler_info()["workers"].values()}
    assert len(seen) == 2 and all(values == ["1"] * 4 for values in seen.values()) and threads == {1}
    assert all(pinned_environment({})[name] == "1" for name in names)  # the run processes' environment


# -- the run process and one real physics run


def test_the_run_process_is_killed_on_timeout_and_the_next_run_starts_a_new_one():
    process = SimulateProcess()
    params = sample_run(default_config(), run_seed(0, 1))
    try:
        with pytest.raises(RunTimeout):
            process.run(params.argv(), timeout=0.5)
        assert process.process is None  # killed
        reply = process.run(["simulate", "--kinematic", "--estop-time", "3.0"], timeout=120)
        assert reply["returncode"] == 0 and reply["summary"]["case"] in ("one-step", "next-step", "two-step")
        bad = process.run([*params.argv(), "--mass-scale", "-1"], timeout=120)
        assert bad["returncode"] == 2
        row = outcome_from_reply(bad)
        assert row["outcome"] == "error" and "--mass-scale" in row["error"]
    finally:
        process.stop()


def test_the_run_process_is_replaced_after_its_run_quota():
    process = SimulateProcess(recycle=1)
    try:
        process.run(["simulate", "--kinematic", "--estop-time", "3.0"], timeout=120)
        first = process.process.pid
        assert process.run(["simulate", "--kinematic", "--estop-time", "3.0"], timeout=120)["returncode"] == 0
        assert process.process.pid != first
    finally:
        process.stop()


def test_a_timeout_becomes_a_row():
    params = sample_run(default_config(), run_seed(0, 2))
    row = guarded_run((simulate_run, params, 0.3))
    assert row["outcome"] == "timeout" and row["success"] is False and "0.3 s timeout" in row["error"]
    assert row["command"] == params.command() and row["seed"] == params.seed


def test_the_row_keeps_the_cop_margin_the_criterion_checks():
    """``cop_margin_min`` is the least CoP margin in the *planned* support (what ``cop_in_support``
    checks), not in the soles measured in contact (which physics keeps positive): a CoP 12.4 mm outside
    the plan shows as -12.4 mm (the margin in the measured soles would show +4.8 mm there)."""
    numbers = {"time_to_rest_s": 1.0, "rest_after_halt_s": 0.1, "final_cog_offset_m": 0.001,
               "cog_travel_m": 0.3, "pelvis_z_min_m": 0.6, "torso_tilt_max_rad": 0.02,
               "cop_margin_plan_min_m": -0.0124, "cop_margin_meas_min_m": 0.0048,
               "slip_left_m": 0.001, "slip_right_m": 0.002, "realtime_factor": 1.2}
    criteria = {name: name != "cop_in_support" for name in CRITERIA}
    summary = {"physics": {"numbers": numbers}, "success": False, "case": "one-step", "support": "single",
               "criteria": criteria, "replans": 0, "replan_failures": 0, "joint_velocity_violations": 0,
               "tick_compute": {"p99": 0.002}, "steps_after_signal": 2, "capture_landings": 1, "recovery_steps": 0}
    row = outcome_from_reply({"returncode": 1, "summary": summary, "stderr": "", "exception": None})
    assert row["outcome"] == "failure" and row["cop_in_support"] is False
    assert row["cop_margin_min"] == -0.0124
    assert (row["steps"], row["capture_landings"], row["recovery_steps"]) == (2, 1, 0)
    assert row["sole_off_plan_max"] is None and row["sole_turn_max"] is None  # a summary without them
    numbers.update(sole_off_plan_max_m=0.019, sole_turn_max_rad=0.05)
    row = outcome_from_reply({"returncode": 1, "summary": summary, "stderr": "", "exception": None})
    assert (row["sole_off_plan_max"], row["sole_turn_max"]) == (0.019, 0.05)
    assert (row["capture_steps"], row["capture_margin"]) == (None, None)  # a summary without the verdict
    summary["capturability"] = {"steps": -1, "margin": -0.031, "margin_speed": -0.108, "witness": [], "worst": None}
    row = outcome_from_reply({"returncode": 1, "summary": summary, "stderr": "", "exception": None})
    assert (row["capture_steps"], row["capture_margin"]) == (-1, -0.031)


@pytest.mark.slow
def test_one_real_physics_run_gives_a_complete_row():
    params = sample_run(default_config(), run_seed(0, 0))
    row = guarded_run((simulate_run, params, 600.0))
    assert row["outcome"] in ("success", "failure"), row["error"]
    assert row["success"] == all(row[name] for name in CRITERIA)
    assert row["case"] and row["support"] in ("single", "double")
    assert row["pelvis_z_min"] > 0.3 and row["cog_travel"] > 0 and row["wall_time"] > 1.0
    assert row_table(row).num_rows == 1  # the row fits the stored schema


def test_config_errors_name_the_key():
    base = default_config()
    with pytest.raises(ConfigError, match=r"push\.impulse"):
        config_from_mapping({"push": {"impulse": [-1.0, 2.0]}}, base)
    with pytest.raises(ConfigError, match=r"gait\.step_time: low 0\.9 > high 0\.7"):
        config_from_mapping({"gait": {"step_time": [0.9, 0.7]}}, base)
    with pytest.raises(ConfigError, match="unknown key 'runs'"):
        config_from_mapping({"runs": 5}, base)
    with pytest.raises(ConfigError, match=r"signal\.phase: needs a range"):
        config_from_mapping({"signal": {"phase": 0.5}}, base)


def test_the_campaign_command_runs_and_prints_the_success_rate(tmp_path, monkeypatch, capsys):
    from drake_estop.campaign import runner

    monkeypatch.setattr(runner, "simulate_run", fake_run)  # the stand-in physics; the CLI path is the real one
    out = tmp_path / "c"
    assert main(["campaign", "--runs", "3", "--seed", "4", "--out", str(out), "--workers", "1", "--no-progress"]) == 0
    table = ResultStore(out).read()
    wins = table.column("success").to_pylist().count(True)
    assert f"{wins}/3 runs met every criterion" in capsys.readouterr().out
    assert (out / "report.html").exists() and not list((out / "results").glob("run-*"))  # parts merged


def test_two_campaign_processes_cannot_write_to_one_folder(tmp_path):
    import fcntl

    out = tmp_path / "c"
    out.mkdir()
    with open(out / ".lock", "w") as held:  # as another campaign process would hold it
        fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)
        with pytest.raises(ConfigError, match="another campaign process"):
            run_campaign(runs=2, seed=1, out=out, workers=1, runner=fake_run, progress=False)
    assert not _parts(out)


def test_a_run_process_that_dies_or_raises_gives_an_error_row():
    import threading

    from drake_estop.campaign import runner

    params = sample_run(default_config(), run_seed(0, 3))
    process = runner._process()  # this thread's run process, as in a worker
    timer = threading.Timer(1.5, lambda: process.process.kill())
    timer.start()
    row = guarded_run((simulate_run, params, 120.0))
    timer.join()
    assert row["outcome"] == "error" and "the run process died (status -9)" in row["error"]
    raised = outcome_from_reply({"returncode": None, "summary": None, "stderr": "",
                                 "exception": "ZeroDivisionError: division by zero"})
    assert raised["outcome"] == "error" and "ZeroDivisionError" in raised["error"] and raised["success"] is False


def test_the_report_draws_bins_with_no_success_and_all_successes(tmp_path):
    from drake_estop.campaign.report import wilson, write_report

    for n in range(1, 80):  # the interval holds its rate, also at 0 and 1 (0/11 and 6/6 did not)
        assert all(wilson(k, n)[0] <= k / n <= wilson(k, n)[1] for k in range(n + 1))
    store = ResultStore(tmp_path / "c")
    rows = [guarded_run((fake_run, sample_run(default_config(), run_seed(5, i), i), 1.0)) for i in range(11)]
    store.parts.mkdir(parents=True)
    for row in rows:  # 0/11 successes: every bin at rate 0
        store.write({**row, "success": False, "outcome": "failure"})
    path = write_report(store.read(), store.folder, manifest={"seed": 5, "config": {}, "sessions": []})
    assert path.read_text().count("data:image/png;base64,") == 3


def test_a_campaign_runs_on_an_existing_scheduler_and_equals_a_local_one(tmp_path):
    """``--scheduler ADDRESS``: the runs go to a cluster the campaign did not start (here a LocalCluster
    the test owns, with the workers' threads pinned as the campaign's own cluster pins them)."""
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None,
                      env=pinned_environment()) as cluster:
        before = cluster.scheduler.transition_counter
        remote = run_campaign(runs=3, seed=5, out=tmp_path / "remote", scheduler=cluster.scheduler_address,
                              runner=fake_run, progress=False)
        assert cluster.scheduler.transition_counter >= before + 3 * 3  # the runs went through this scheduler
        assert len(cluster.workers) == 1  # and the cluster outlives the campaign (it is not the campaign's)
    local = run_campaign(runs=3, seed=5, out=tmp_path / "local", workers=1, runner=fake_run, progress=False)
    assert remote.num_rows == 3 and _deterministic(remote) == _deterministic(local)


# -- another robot


def test_a_default_campaign_s_commands_name_no_robot():
    default = sample_run(default_config(), 7, 0)
    assert default.robot == "default" and "--robot" not in default.argv() and "robot" not in default.record()


@needs_robots
def test_a_robot_campaign_runs_that_robot():
    """The robot reaches every run's command (``--robot``) and places the signal in its own stride; the other
    sampled values are the default campaign's."""
    config = default_config()
    default = sample_run(config, 7, 0)
    talos = sample_run(config, 7, 0, robot="talos")
    argv = talos.argv()
    assert argv[argv.index("--robot") + 1] == "talos"
    assert build_parser().parse_args(argv).robot == "talos"
    assert {k: v for k, v in dataclasses.asdict(talos).items() if k not in ("robot", "estop_time", "push_time")} == \
        {k: v for k, v in dataclasses.asdict(default).items() if k not in ("robot", "estop_time", "push_time")}


@needs_robots
def test_the_default_ranges_scale_to_the_robot():
    """The same campaign for another robot: its gait's ratios and the same push speeds (impulse / mass)."""
    from drake_estop.campaign.config import scaled_to_robot
    from drake_estop.robots import as_robot, gait_parameters
    from drake_estop.robots.measure import robot_facts

    config = default_config()
    assert scaled_to_robot(config, "default") == config
    g1 = scaled_to_robot(config, "g1")
    gait, base = gait_parameters(as_robot("g1")), gait_parameters(as_robot("default"))
    assert g1.step_length == pytest.approx(tuple(v * gait.step_length / base.step_length for v in config.step_length),
                                           abs=1e-4)
    mass = robot_facts(as_robot("g1")).mass / robot_facts(as_robot("default")).mass
    assert g1.push_impulse[1] == pytest.approx(config.push_impulse[1] * mass, abs=1e-4) and mass < 1.0
    assert g1.push_direction == config.push_direction and g1.friction == config.friction


def test_resuming_with_another_robot_exits_2_and_a_bad_robot_names_it(tmp_path, capsys):
    out = tmp_path / "c"
    run_campaign(runs=2, seed=1, out=out, workers=1, runner=fake_run, progress=False)
    assert json.loads((out / "campaign.json").read_text())["robot"] == "default"
    with pytest.raises(ConfigError, match="robot"):
        run_campaign(runs=2, seed=1, out=out, workers=1, runner=fake_run, progress=False, robot="talos")
    assert main(["campaign", "--runs", "1", "--out", str(tmp_path / "d"), "--robot", "no_such_robot"]) == 2
    assert "robot" in capsys.readouterr().err and not (tmp_path / "d").exists()


def test_the_report_counts_the_runs_that_took_a_capture_landing_or_a_recovery_step(tmp_path):
    from drake_estop.campaign.report import write_report

    store = ResultStore(tmp_path / "c")
    rows = [guarded_run((fake_run, sample_run(default_config(), run_seed(5, i), i), 1.0)) for i in range(4)]
    store.parts.mkdir(parents=True)
    for i, row in enumerate(rows):  # runs 0 and 1 take a capture landing, run 0 alone succeeds; none steps out
        store.write({**row, "error": None, "outcome": "success" if i == 0 else "failure", "success": i == 0,
                     "capture_landings": int(i < 2), "recovery_steps": 0, "steps": 1})
    text = write_report(store.read(), store.folder, manifest={"seed": 5, "config": {}, "sessions": []}).read_text()
    assert "runs with a capture landing: 2, of which 1 met every criterion" in text
    assert "recovery step" not in text


def test_the_report_splits_success_by_capturability(tmp_path):
    from drake_estop.campaign.report import _columns, capturability_counts, write_report

    store = ResultStore(tmp_path / "c")
    rows = [guarded_run((fake_run, sample_run(default_config(), run_seed(6, i), i), 1.0)) for i in range(5)]
    store.parts.mkdir(parents=True)
    steps = [0, 1, -1, -1, None]  # the last: a run without the verdict, counted in neither class
    for i, row in enumerate(rows):  # runs 0 and 2 succeed; run 3 falls
        store.write({**row, "error": None, "outcome": "success" if i in (0, 2) else "failure",
                     "success": i in (0, 2), "no_fall": i != 3, "capture_steps": steps[i],
                     "capture_margin": None if steps[i] is None else 0.01 * (steps[i] or 1)})
    counts = capturability_counts(_columns(store.read()))
    assert counts == {"capturable": {"runs": 2, "success": 1, "falls": 0},
                      "not capturable": {"runs": 2, "success": 1, "falls": 1}}
    text = write_report(store.read(), store.folder, manifest={"seed": 6, "config": {}, "sessions": []}).read_text()
    line = "not capturable at the signal or the push's end (N <= 3 steps): 2 runs, 1 met every criterion (50 %), 1 fell"
    assert line in text
    assert capturability_counts(_columns(store.read().drop(["capture_steps"]))) == {}

