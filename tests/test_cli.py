"""drake-estop simulate: log, summary, help and clear errors."""

import csv
import json

import pytest

from drake_estop.cli import main
from drake_estop.planner import PHASES

REQUIRED = ["t", "com_x", "com_y", "com_z", "com_vx", "com_vy", "zmp_x", "zmp_y", "phase"]


def test_simulate_writes_log_and_summary(tmp_path):
    log, summary = tmp_path / "log.csv", tmp_path / "summary.json"
    assert main(["simulate", "--kinematic", "--estop-time", "3.4", "--log", str(log), "--summary", str(summary)]) == 0
    rows = list(csv.DictReader(open(log)))
    assert set(REQUIRED) <= set(rows[0])
    assert {row["phase"] for row in rows} == set(PHASES)
    data = json.load(open(summary))
    for key in ("estop_time", "support", "case", "phase_times", "step_length", "landing_position",
                "final_feet", "sole", "newton_iterations", "plan_compute_time_s"):
        assert key in data
    assert data["support"] == "single" and data["case"] == "one-step"
    halt_end = data["phase_times"]["halt_end"]
    assert float(rows[-1]["t"]) >= halt_end + 1.0 - 1e-9
    dt = float(rows[1]["t"]) - float(rows[0]["t"])
    assert dt == pytest.approx(0.005)
    last = rows[-1]
    assert abs(float(last["com_vx"])) < 1e-3 and abs(float(last["com_vy"])) < 1e-3


def test_diagram_run_logs_joints_and_ik_errors(tmp_path):
    log, summary, html = tmp_path / "log.csv", tmp_path / "s.json", tmp_path / "replay.html"
    assert main(["simulate", "--estop-time", "3.5", "--log", str(log), "--summary", str(summary),
                 "--html", str(html)]) == 0
    rows = list(csv.DictReader(open(log)))
    header = list(rows[0])
    assert len(header) == len(set(header))
    for column in ("q_l_knee", "q_r_knee", "q_chest_pitch", "ik_com_err", "ik_foot_err"):
        assert column in header
    assert max(float(row["ik_com_err"]) for row in rows) < 1e-3
    data = json.load(open(summary))
    assert data["ik"]["ik_ticks_over_bounds"] == {"com": 0, "foot_position": 0, "foot_rotation": 0}
    assert data["realtime_factor"] > 0
    assert html.stat().st_size > 100_000


def test_button_only_needs_meshcat(capsys):
    assert main(["simulate", "--button-only"]) == 2
    assert "button_only" in capsys.readouterr().err


def test_no_crouch_keeps_height(tmp_path):
    log = tmp_path / "log.csv"
    assert main(["simulate", "--kinematic", "--estop-time", "3.5", "--no-crouch", "--log", str(log)]) == 0
    heights = {float(row["com_z"]) for row in csv.DictReader(open(log))}
    assert heights == {0.814}


@pytest.mark.parametrize("args, name", [
    (["--com-height", "0"], "com_height"),
    (["--servo-period", "-1"], "servo_period"),
    (["--a-ss", "0"], "a_ss"),
    (["--step-time", "0"], "step_time"),
    (["--step-length", "0.9"], "step_length"),
    (["--estop-time", "99"], "estop_time"),
    (["--estop-time", "-1"], "estop_time"),
])
def test_bad_input_names_the_parameter(args, name, capsys):
    assert main(["simulate", *args]) == 2
    err = capsys.readouterr().err
    assert name in err and "Traceback" not in err


def test_help_explains_options(capsys):
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    out = capsys.readouterr().out
    for option in ("--step-length", "--step-time", "--estop-time", "--servo-period", "--no-crouch", "--log",
                   "--summary"):
        assert option in out


def test_signal_while_standing_is_trivial(tmp_path, capsys):
    summary = tmp_path / "s.json"
    assert main(["simulate", "--kinematic", "--estop-time", "0", "--summary", str(summary)]) == 0
    assert json.load(open(summary))["case"] == "standing"


def test_physics_run_logs_measurements_and_criteria(tmp_path):
    log, summary = tmp_path / "log.csv", tmp_path / "s.json"
    code = main(["simulate", "--physics", "--estop-time", "3.5", "--log", str(log), "--summary", str(summary)])
    data = json.load(open(summary))
    assert code == (0 if data["physics"]["success"] else 1)
    assert set(data["physics"]["criteria"]) == {"no_fall", "no_slip", "comes_to_rest", "rests_at_midpoint",
                                                "cop_in_support"}
    rows = list(csv.DictReader(open(log)))
    for column in ("cop_x", "cop_y", "pelvis_z", "com_meas_x", "com_meas_y", "com_meas_z"):
        assert column in rows[0]
    assert float(rows[-1]["t"]) >= data["phase_times"]["halt_end"] + 2.5 - 1e-9
    assert data["physics"]["success"]


def test_sweep_writes_table_and_stop_map(tmp_path, capsys):
    table, figure = tmp_path / "sweep.csv", tmp_path / "map.png"
    assert main(["sweep", "--every", "0.4", "--csv", str(table), "--png", str(figure), "--no-progress"]) == 0
    rows = list(csv.DictReader(open(table)))
    assert len(rows) == 2 and {"signal_time", "case", "step_length", "time_to_rest", "cog_travel",
                               "success"} <= set(rows[0])
    assert figure.stat().st_size > 1000
    assert "stops met every criterion" in capsys.readouterr().out


def test_sweep_rejects_bad_spacing(capsys):
    assert main(["sweep", "--every", "0"]) == 2
    assert "every" in capsys.readouterr().err
