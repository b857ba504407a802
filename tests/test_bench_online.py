"""benchmarks/bench_online.py: its report from runs (the runs themselves are physics, minutes: a benchmark)."""

import pytest
from scripts import load_script


@pytest.fixture(scope="module")
def bench():
    return load_script("benchmarks/bench_online.py")


def _run(rtf, median, p99, worst, blocks, success=True, replans=0):
    return {"rtf": rtf, "cpu_rtf": rtf + 0.01, "tick": {"median": median, "p99": p99, "max": worst},
            "blocks": blocks, "success": success, "replans": replans}


def test_report_gives_medians_the_worst_tick_and_the_median_runs_blocks(bench):
    runs = [_run(0.9, 1.0e-3, 3.0e-3, 4.0e-3, {"WholeBodyIK._update": 5e-4}),
            _run(1.1, 1.4e-3, 2.0e-3, 9.0e-3, {"WholeBodyIK._update": 7e-4, "StopPlannerSystem._update": 2e-4},
                 success=False, replans=2),
            _run(1.0, 1.2e-3, 5.5e-3, 3.0e-3, {"WholeBodyIK._update": 6e-4, "StopPlannerSystem._update": 3e-4},
                 replans=1)]
    text = bench.report({"pushed": runs}, 3, 12.0)
    row = next(line for line in text.splitlines() if line.startswith("| pushed"))
    # 2 of 3 succeed; the median run (real-time factor 1.0) re-planned once; medians, worst p99 and max
    assert row == "| pushed | 2/3 | 1 | 1.00 (0.90-1.10) | 1.01 | 1.20 ms | 5.50 ms | 9.00 ms |"
    assert "| WholeBodyIK._update | 0.60 ms |" in text  # the median run's blocks, largest first
    assert text.index("WholeBodyIK._update | 0.60") < text.index("StopPlannerSystem._update | 0.30")
    assert "is 0.90 ms of CPU, inside one." in text  # the median run's blocks summed: 0.6 + 0.3 ms
    slow = bench.report({"slow": [_run(0.8, 2e-3, 3e-3, 4e-3, {"WholeBodyIK._update": 1.5e-3})]}, 1, 5.0)
    assert "is 1.50 ms of CPU, so this Python controller does not fit one." in slow


def test_repeats_below_one_is_refused_naming_the_option(bench, capsys):
    with pytest.raises(SystemExit) as exit_info:
        bench.main(["--repeats", "0"])
    assert exit_info.value.code == 2
    assert "--repeats must be >= 1" in capsys.readouterr().err


def test_report_says_how_fast_the_machine_was(bench):
    runs = [_run(0.8, 2e-3, 3e-3, 4e-3, {"WholeBodyIK._update": 1e-3})]  # CPU real-time factor 0.81
    text = bench.report({"one": runs}, 1, 5.0, plant_ticks=(1.5e-3, 1.7e-3))
    assert ("the plant alone (standing, no controller) took 1.50 ms of CPU per 5 ms tick before the runs "
            "and 1.70 ms after; the whole loop took 6.17 ms a tick") in text
    assert "plant alone" not in bench.report({"one": runs}, 1, 5.0)


def test_plant_alone_times_the_standing_plant(bench):
    tick = bench.plant_alone(seconds=0.05)
    assert 0.0 < tick < 0.05  # CPU seconds per 5 ms tick: positive, and not absurd on any machine


def test_parts_report_splits_the_median_run_and_says_what_real_time_leaves_the_controller(bench):
    parts = [{"loop": 7.0e-3, "controller": 3.0e-3, "plant": 2.0e-3, "rest": 2.0e-3},
             {"loop": 6.0e-3, "controller": 2.0e-3, "plant": 2.5e-3, "rest": 1.5e-3},
             {"loop": 5.0e-3, "controller": 1.5e-3, "plant": 2.4e-3, "rest": 1.1e-3}]
    text = bench.parts_report(parts)
    assert "the run with the median loop time of 3" in text
    # the median run (6 ms) and each part's range over the three runs
    assert ("| the simulated robot alone, walking the run's motion (plant, contact, PD servos) | 2.50 ms | 42% "
            "| 2.00-2.50 ms |") in text
    assert "| the controller's own work (estimator, planner, IK, compliance, swing tilt) | 2.00 ms | 33% |" in text
    assert "| the loop | 6.00 ms | 100% | 5.00-7.00 ms |" in text
    # plant + rest of that run: 4.0 ms -> real-time factor 1.25, 1.00 ms left for the controller
    assert "would take 4.00 ms a tick (real-time factor 1.25); real time leaves the controller 1.00 ms" in text


def test_loop_parts_add_up_and_the_replayed_robot_walks(bench):
    from drake_estop.planning.gait import NominalPattern

    parts = bench.loop_parts(NominalPattern(), estop_time=1.2, after_halt=0.05)
    assert parts["ticks"] > 200  # the walk to 1.2 s, the stop and its halt
    for key in ("loop", "controller", "plant"):
        assert 0.0 < parts[key] < 0.05, key  # CPU seconds per 5 ms tick: positive, and not absurd
    assert parts["rest"] == pytest.approx(parts["loop"] - parts["controller"] - parts["plant"])
    assert parts["replay_pelvis_z"] > 0.5  # the replayed commands walk the robot: it stands at the end


def test_parts_only_runs_just_the_loop_split(bench, monkeypatch, capsys, tmp_path):
    calls = []
    monkeypatch.setattr(bench, "run", lambda *args: calls.append("run"))
    monkeypatch.setattr(bench, "plant_alone", lambda: calls.append("plant_alone") or 1e-3)
    monkeypatch.setattr(bench, "loop_parts", lambda pattern: calls.append("parts") or
                        {"loop": 5e-3, "controller": 2e-3, "plant": 2e-3, "rest": 1e-3})
    out = tmp_path / "parts.md"
    bench.main(["--parts-only", "--repeats", "2", "--out", str(out)])
    assert calls == ["run", "parts", "parts"]  # the warm-up, then the two splits: no scenario, no plant alone
    text = capsys.readouterr().out
    assert text.startswith("Where the loop's time goes") and "| the loop | 5.00 ms | 100% |" in text
    assert out.read_text() == text


def test_profile_report_lists_the_most_own_time_first_and_sums_it_by_module(bench):
    rows = [("drake_estop/systems/ik.py:_update", 100, 0.5, 1.0), ("pydrake.systems.analysis.AdvanceTo", 1, 3.0, 9.0),
            ("drake_estop/systems/ik.py:solve", 100, 0.25, 0.4), ("drake_estop/planning/lipm.py:horner", 900, 0.4, 0.4),
            ("numpy.array", 5000, 0.1, 0.1)]
    text = bench.profile_report(rows, total=5.0, top=3)
    table = [line for line in text.splitlines() if line.startswith("| `")]
    assert table[:3] == ["| `pydrake.systems.analysis.AdvanceTo` | 3.00 s | 60% | 1 | 9.00 s |",
                         "| `drake_estop/systems/ik.py:_update` | 0.50 s | 10% | 100 | 1.00 s |",
                         "| `drake_estop/planning/lipm.py:horner` | 0.40 s | 8% | 900 | 0.40 s |"]
    # by module: ik.py's two functions together, Drake and numpy as "outside the package"
    assert table[3:] == ["| `outside the package` | 3.10 s | 62% |", "| `drake_estop/systems/ik.py` | 0.75 s | 15% |",
                         "| `drake_estop/planning/lipm.py` | 0.40 s | 8% |"]


def test_profiled_functions_are_named_by_their_place_in_the_package(bench):
    assert bench._function_name(("/x/site-packages/drake_estop/systems/ik.py", 12, "solve")) == \
        "drake_estop/systems/ik.py:solve"
    assert bench._function_name(("~", 0, "<built-in method numpy.array>")) == "numpy.array"
    assert bench._function_name(("/usr/lib/python3.11/copy.py", 128, "deepcopy")) == "copy.py:deepcopy"
