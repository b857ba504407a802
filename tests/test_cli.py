"""drake-estop simulate: log, summary, help and clear errors."""

import csv
import json

import pytest
from html_checks import external_fetches, missing_from_replay

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
    page = html.read_text()
    assert missing_from_replay(page) == [] and external_fetches(page) == []


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
    assert (name in err or "--" + name.replace("_", "-") in err) and "Traceback" not in err


# every numeric option: non-finite values and values outside the physical range exit with status 2
SIMULATE_BAD = [
    ("--step-length", "-0.1"), ("--step-length", "nan"), ("--step-time", "0"), ("--step-time", "inf"),
    ("--step-width", "-0.2"), ("--step-width", "0.05"), ("--double-support-ratio", "1"),
    ("--double-support-ratio", "0"), ("--com-height", "5"), ("--com-height", "0.3"), ("--num-steps", "1"),
    ("--num-steps", "2.5"), ("--estop-time", "nan"), ("--servo-period", "0"), ("--servo-period", "0.5"),
    ("--crouch-depth", "5"), ("--crouch-depth", "0.3"), ("--crouch-depth", "-0.01"), ("--crouch-depth", "inf"),
    ("--a-ss", "-1"), ("--b-ss", "0"), ("--a-ds", "nan"), ("--b-ds", "-5"), ("--max-step-length", "0"),
    ("--max-swing-speed", "-1"), ("--meshcat-port", "-5"), ("--meshcat-port", "0"), ("--meshcat-port", "70000"),
    ("--after-halt", "0.5"), ("--after-halt", "inf"),
]


@pytest.mark.parametrize("option, value", SIMULATE_BAD)
def test_simulate_rejects_bad_numbers(option, value, capsys):
    assert main(["simulate", "--kinematic", option, value]) == 2
    err = capsys.readouterr().err
    name = option[2:].replace("-", "_")
    assert option in err or name in err, err
    assert "Traceback" not in err


@pytest.mark.parametrize("option, value", [
    ("--every", "0"), ("--every", "-0.1"), ("--every", "nan"), ("--every", "5"), ("--step-length", "inf"),
    ("--com-height", "-1"), ("--crouch-depth", "5"), ("--servo-period", "-0.005"), ("--num-steps", "x"),
    ("--max-swing-speed", "0"),
])
def test_sweep_rejects_bad_numbers(option, value, capsys):
    assert main(["sweep", "--no-progress", option, value]) == 2
    err = capsys.readouterr().err
    assert option in err or option[2:].replace("-", "_") in err, err


def test_meshcat_port_needs_meshcat(capsys):
    assert main(["simulate", "--kinematic", "--meshcat-port", "7001"]) == 2
    assert "meshcat_port" in capsys.readouterr().err


def test_crouch_depth_five_metres_rejected_not_logged(tmp_path, capsys):
    log = tmp_path / "log.csv"
    assert main(["simulate", "--kinematic", "--crouch-depth", "5", "--log", str(log)]) == 2
    assert not log.exists() and "crouch" in capsys.readouterr().err


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
    code = main(["simulate", "--physics", "--controller", "offline-filter", "--estop-time", "3.5", "--log", str(log),
                 "--summary", str(summary)])
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
    code = main(["sweep", "--every", "0.4", "--csv", str(table), "--png", str(figure), "--no-progress"])
    rows = list(csv.DictReader(open(table)))
    assert len(rows) == 2 and {"signal_time", "case", "step_length", "time_to_rest", "cog_travel",
                               "success"} <= set(rows[0])
    assert code == (0 if all(row["success"] == "True" for row in rows) else 1)  # exit 1 names the failures
    assert figure.stat().st_size > 1000
    assert "stops met every criterion" in capsys.readouterr().out


def test_sweep_exits_1_and_names_failed_signal_times(monkeypatch, tmp_path, capsys):
    from drake_estop import physics

    def fake_sweep(gait, stop, **kwargs):
        return [{"signal_time": 3.05, "case": "one-step", "success": True},
                {"signal_time": 3.25, "case": "one-step", "success": False, "no_fall": False},
                {"signal_time": 3.45, "success": False, "error": "InfeasibleStop: test"}]

    monkeypatch.setattr(physics, "sweep", fake_sweep)
    monkeypatch.setattr(physics, "write_sweep", lambda *args: None)
    assert main(["sweep", "--no-progress", "--csv", str(tmp_path / "s.csv"), "--png", str(tmp_path / "m.png")]) == 1
    out, err = capsys.readouterr()
    assert "1/3 stops met every criterion" in out
    assert "3.250" in err and "3.450" in err and "3.050" not in err
    assert "3.250 s: no_fall" in out and "3.450 s: InfeasibleStop: test" in out


def test_sweep_rejects_bad_spacing(capsys):
    assert main(["sweep", "--every", "0"]) == 2
    assert "every" in capsys.readouterr().err
