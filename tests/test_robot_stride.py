"""A stop at every 8th servo tick of a stride, each through the kinematic diagram, for the G1 and TALOS
(``drake_estop.systems.stride``; ``benchmarks/bench_robots.py`` runs every tick)."""

import dataclasses
import warnings

import numpy as np
import pytest
from robot_helpers import needs_robots

from drake_estop.systems.diagram import build_diagram, simulate_diagram
from drake_estop.systems.stride import StrideStop, run_signal, stride_summary, sweep_stride


def test_a_requested_stop_runs_as_a_scheduled_one():
    """The sweep's run (one diagram, the stop requested at the signal's tick) is the scheduled stop's run."""
    handles = build_diagram(estop_time=None)
    requested = run_signal(handles, 3.4)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        scheduled = simulate_diagram(estop_time=3.4)
    assert requested.plan.signal_time == scheduled.plan.signal_time == 3.4
    assert np.array_equal(requested.times, scheduled.times)
    assert np.array_equal(requested.q_full, scheduled.q_full)
    row = StrideStop.of(requested)
    assert (row.case, row.final_phase, row.velocity_limit_violations) == ("one-step", "stopped", 0)
    # the stop's whole-body ZMP margin reaches the row and the summary (the default humanoid's: inside)
    assert row.stop_multibody_zmp_margin == requested.error_summary()["stop_multibody_zmp_margin_min_m"] > 0.02
    summary = stride_summary([row])
    assert summary["stop_multibody_zmp_margin_min_m"] == row.stop_multibody_zmp_margin
    assert summary["signals_with_multibody_zmp_outside"] == 0
    outside = dataclasses.replace(row, stop_multibody_zmp_margin=-0.004)
    summary = stride_summary([row, outside])
    assert (summary["stop_multibody_zmp_margin_min_m"], summary["signals_with_multibody_zmp_outside"]) == (-0.004, 1)


def test_the_sweep_refuses_a_bad_spacing():
    with pytest.raises(ValueError, match="every must be a whole number of servo ticks"):
        sweep_stride(every=0)


@pytest.mark.slow
@needs_robots
@pytest.mark.parametrize("name, least_one_step", [("g1", 0.85), ("talos", 0.85)])
def test_every_8th_tick_of_a_stride_stops_with_the_ik_within_a_millimetre(name, least_one_step):
    """Measured over every tick (benchmarks/bench_robots.py): G1 151/158 one-step (7 of the first 45 ms of
    single support take the next step: on its 5.6 cm wide soles no halt keeps the ZMP 10 mm inside the
    support), TALOS 161/172 (11 late double-support ticks take the next step); the IK within 0.01 mm
    of the COG at every tick of every stop, no joint over its speed or position limit."""
    rows = sweep_stride(robot=name, every=8)
    summary = stride_summary(rows)
    print(name, summary)
    assert summary["stopped"] == summary["signals"] >= 19 and summary["final_speed_max_m_s"] < 1e-9
    assert summary["ik_com_error_max_m"] < 1e-3 and summary["ik_foot_error_max_m"] < 1e-3
    assert summary["ik_ticks_over_bounds"] == 0
    assert summary["velocity_limit_violations"] == 0 and summary["joint_limit_violations"] == 0
    assert summary["one_step_share"] >= least_one_step
    assert {row.support for row in rows} == {"single", "double"}


def test_the_robots_benchmark_formats_a_robot_without_margins():
    """bench_robots.py's table: a robot none of whose stops has a sole on the floor to measure the whole-body
    ZMP in shows "none" instead of failing, and the walk's columns (LIPM -> corrected) are printed."""
    from scripts import load_script

    bench = load_script("benchmarks/bench_robots.py")
    summary = {"signals": 1, "one_step": 1, "one_step_share": 1.0, "ik_com_error_max_m": 1e-5,
               "ik_foot_error_max_m": 1e-5, "ik_ticks_over_bounds": 0, "velocity_limit_violations": 0,
               "time_to_rest_median_s": 0.5, "time_to_rest_max_s": 0.6, "stop_multibody_zmp_margin_min_m": float("nan"),
               "signals_with_multibody_zmp_outside": 0}
    walk = {"lipm": {"zmp_shift_max_m": 0.0742, "zmp_margin_min_m": -0.0142},
            "corrected": {"zmp_shift_max_m": 0.004, "zmp_margin_min_m": 0.0168}}
    text = bench.table([{"robot": "r", "summary": summary, "rows": [], "gait": {}, "stop": {}, "walk": walk,
                         "wall_time": 1.0}])
    assert "| none / 0 | 74.2 / -14.2 -> 4.0 / 16.8 | 1 |" in text
