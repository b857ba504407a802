"""drake-estop simulate: log, summary, help and clear errors."""

import csv
import json

import pytest
from html_checks import external_fetches, missing_from_replay

from drake_estop.cli import main
from drake_estop.planning.planner import PHASES

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
    assert data["steps"] == [{"time": pytest.approx(data["phase_times"]["landing_end"]), "foot": "right",
                              "kind": "stop landing"}]
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
    # one_step_feasible: every tick of the third step's stride would stop in one step (no fallback on the
    # default gait; both answers: tests/test_one_step_feasible.py); from 3.5 s the latched stop's case
    feasible = {round(float(row["t"]), 3): row["one_step_feasible"] for row in rows}
    assert {value for t, value in feasible.items() if 2.85 <= t < 3.5} == {"1"}
    assert (feasible[3.5], feasible[3.6]) == ("1", "1")
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
                                                "cop_in_support", "joint_speed_within_limits"}
    rows = list(csv.DictReader(open(log)))
    for column in ("cop_x", "cop_y", "pelvis_z", "com_meas_x", "com_meas_y", "com_meas_z"):
        assert column in rows[0]
    assert float(rows[-1]["t"]) >= data["phase_times"]["halt_end"] + 2.5 - 1e-9
    assert data["physics"]["success"] and data["physics"]["cop_exit"] is None


@pytest.mark.slow
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
    from drake_estop.physics import sweep as sweep_module

    def fake_sweep(gait, stop, **kwargs):
        return [{"signal_time": 3.05, "case": "one-step", "success": True},
                {"signal_time": 3.25, "case": "one-step", "success": False, "no_fall": False},
                {"signal_time": 3.45, "success": False, "error": "InfeasibleStop: test"}]

    monkeypatch.setattr(sweep_module, "sweep", fake_sweep)
    monkeypatch.setattr(sweep_module, "write_sweep", lambda *args: None)
    assert main(["sweep", "--no-progress", "--csv", str(tmp_path / "s.csv"), "--png", str(tmp_path / "m.png")]) == 1
    out, err = capsys.readouterr()
    assert "1/3 stops met every criterion" in out
    assert "3.250" in err and "3.450" in err and "3.050" not in err
    assert "3.250 s: no_fall" in out and "3.450 s: InfeasibleStop: test" in out


def test_sweep_runs_the_scenarios_controller_section(monkeypatch, tmp_path):
    """Every sweep run gets the scenario's controller options, and the stop parameters its braked landing."""
    from drake_estop.physics import sweep as sweep_module
    from drake_estop.physics.controller_options import ControllerOptions

    seen = {}

    def fake_sweep(gait, stop, **kwargs):
        seen.update(kwargs, stop=stop)
        return [{"signal_time": 3.05, "case": "one-step", "success": True}]

    monkeypatch.setattr(sweep_module, "sweep", fake_sweep)
    monkeypatch.setattr(sweep_module, "write_sweep", lambda *args: None)
    assert main(["sweep", "--no-progress", "--scenario-text",
                 "{controller: {swing_tilt: null, braked_landing: false}}",
                 "--csv", str(tmp_path / "s.csv"), "--png", str(tmp_path / "m.png")]) == 0
    assert seen["run"].keywords["controller"] == ControllerOptions(swing_tilt=None, braked_landing=False)
    assert seen["stop"].landing_approach_slope == 0.0  # the paper's landing swing


def test_sweep_rejects_online_features_for_the_offline_filter(capsys):
    assert main(["sweep", "--controller", "offline-filter",
                 "--scenario-text", "{controller: {swing_tilt: null}}"]) == 2
    assert "controller.swing_tilt: only with controller.kind online" in capsys.readouterr().err


def test_sweep_rejects_bad_spacing(capsys):
    assert main(["sweep", "--every", "0"]) == 2
    assert "every" in capsys.readouterr().err


def test_every_gait_and_stop_option_reaches_the_plan(tmp_path):
    """Options no other test passes, with valid values: the summary equals a plan made from the
    same parameters directly, and each option shows where it acts."""
    import numpy as np

    from drake_estop.planning.gait import GaitParameters, NominalPattern
    from drake_estop.planning.planner import StopParameters, plan_stop

    log, summary = tmp_path / "log.csv", tmp_path / "s.json"
    args = ["simulate", "--kinematic", "--estop-time", "3.1", "--step-width", "0.22",
            "--double-support-ratio", "0.25", "--num-steps", "6", "--crouch-depth", "0.03", "--a-ss", "6",
            "--b-ss", "800", "--a-ds", "40", "--b-ds", "900", "--max-step-length", "0.38",
            "--max-swing-speed", "1.1", "--quantisation", "round", "--after-halt", "1.5",
            "--log", str(log), "--summary", str(summary)]
    assert main(args) == 0
    data = json.load(open(summary))
    gait = GaitParameters(step_width=0.22, double_support_ratio=0.25, num_steps=6)
    stop = StopParameters(crouch_depth=0.03, a_ss=6.0, b_ss=800.0, a_ds=40.0, b_ds=900.0, max_step_length=0.38,
                          max_swing_speed=1.1, quantisation="round")
    pattern = NominalPattern(gait)
    plan = plan_stop(pattern, 3.1, stop)
    assert data["support"] == "single" and plan.case == "one-step"
    assert data["phase_times"] == pytest.approx(plan.summary()["phase_times"], abs=1e-12)
    assert data["step_length"] == pytest.approx(plan.step_length, abs=1e-12)
    assert plan_stop(NominalPattern(), 3.1).summary()["phase_times"] != data["phase_times"]
    # --step-width: final feet 0.22 m apart; --num-steps: a 6-step walk (its last step at 5.89 s)
    feet = data["final_feet"]
    assert feet["left"][1] - feet["right"][1] == pytest.approx(0.22, abs=1e-9)
    assert pattern.steps[-1]["touchdown"] == pytest.approx(1.25 + 5 * 0.8 + 0.8 * 0.75, abs=1e-9)
    # --max-step-length, --max-swing-speed: honoured
    duration = data["phase_times"]["landing_end"] - data["plan_start_time"]
    swing = np.linalg.norm(np.array(data["landing_position"]) - plan.swing_start["pos"][:2])
    assert data["step_length"] <= 0.38 + 1e-12 and swing / duration <= 1.1 + 1e-9
    # --crouch-depth: the COG goes down by exactly 3 cm; --after-halt: 1.5 s logged past the halt
    rows = list(csv.DictReader(open(log)))
    heights = [float(row["com_z"]) for row in rows]
    assert min(heights) == pytest.approx(0.814 - 0.03, abs=1e-9)
    assert float(rows[-1]["t"]) >= data["phase_times"]["halt_end"] + 1.5 - 1e-9
    assert float(rows[-1]["t"]) < data["phase_times"]["halt_end"] + 1.5 + 0.01
    # --quantisation round: times snapped, ZMP kept -> the COG is not exactly at rest (paper Fig. 12)
    assert abs(data["metrics"]["sagittal_velocity_at_slowdown_end_mps"]) > 1e-6


def test_summary_fields_have_their_values(tmp_path):
    """metrics (eq. 5 crouch ZMP error), zmp_max, landing_foot, min_zmp_margin_m and
    upper_body_peak_rad, checked against the log and the plan, single and double support."""
    import numpy as np

    from drake_estop.planning.gait import NominalPattern
    from drake_estop.planning.planner import plan_stop

    for estop, support in ((3.4, "single"), (3.5, "double")):
        log, summary = tmp_path / f"log{estop}.csv", tmp_path / f"s{estop}.json"
        assert main(["simulate", "--kinematic", "--estop-time", str(estop), "--log", str(log),
                     "--summary", str(summary)]) == 0
        data = json.load(open(summary))
        rows = list(csv.DictReader(open(log)))
        plan = plan_stop(NominalPattern(), estop)
        assert data["support"] == support
        if support == "single":
            assert data["landing_foot"] == "right" and data["zmp_max"] is None  # the 3rd step swings the right foot
            assert data["landing_position"][0] == pytest.approx(plan.landing_position[0], abs=1e-12)
        else:
            assert data["landing_foot"] is None and data["step_length"] is None
            fore = max(data["final_feet"].values(), key=lambda xy: xy[0])
            times = data["phase_times"]
            slowdown = [float(r["zmp_x"]) for r in rows
                        if times["transition_end"] - 1e-9 <= float(r["t"]) < times["slowdown_end"] - 1e-9]
            # ZMP_max: the (constant) slowdown ZMP relative to the ZMP at the signal, on the fore sole
            start = plan.start_state.zmp[0]
            assert slowdown and max(slowdown) - min(slowdown) < 1e-7
            assert data["zmp_max"] == pytest.approx(slowdown[0] - start, abs=1e-7)
            assert fore[0] - 0.105 + 0.01 - 1e-9 <= start + data["zmp_max"] <= fore[0] + 0.135 - 0.01 + 1e-9
        assert 0.01 - 1e-9 <= data["min_zmp_margin_m"] < 0.2
        assert data["min_zmp_margin_m"] == pytest.approx(plan.min_zmp_margin, abs=1e-12)
        # eq. 33: the arm angles at the slowdown end
        q, qd = plan.upper_body(plan.slowdown_end)
        np.testing.assert_allclose(data["upper_body_peak_rad"], q, atol=1e-12)
        np.testing.assert_allclose(qd, 0.0, atol=1e-12)
        # metrics, recomputed from the log
        metrics = data["metrics"]
        t = np.array([float(r["t"]) for r in rows])
        com = np.array([[float(r["com_x"]), float(r["com_y"])] for r in rows])
        assert metrics["time_to_rest_s"] == pytest.approx(data["phase_times"]["halt_end"] - plan.signal_time)
        after = t >= plan.signal_time - 1e-9
        travel = np.sum(np.linalg.norm(np.diff(com[after], axis=0), axis=1))
        assert metrics["cog_travel_after_signal_m"] == pytest.approx(travel, rel=1e-6)  # log rounding
        # final_feet: [x, y, yaw] of each foot (level soles heading along x on this walk)
        assert data["final_feet"]["left"][2] == data["final_feet"]["right"][2] == 0.0
        mid = 0.5 * (np.array(data["final_feet"]["left"][:2]) + np.array(data["final_feet"]["right"][:2]))
        assert metrics["final_cog_offset_from_midpoint_m"] == pytest.approx(np.linalg.norm(com[-1] - mid), abs=1e-8)
        assert metrics["final_cog_speed_mps"] < 1e-6
        # eq. 5: x ZMP error of the crouch, (ax (z0 zdd - dz g)) / (g (zdd + g)), zdd by differences
        z = np.array([float(r["com_z"]) for r in rows])
        vz = np.array([float(r["com_vz"]) for r in rows])
        ax = np.array([float(r["com_ax"]) for r in rows])
        zdd = np.gradient(vz, t)
        g, z0 = 9.80665, 0.814
        error = np.abs(ax * (z0 * zdd - (z - z0) * g) / (g * (zdd + g)))
        assert 1e-4 < metrics["crouch_zmp_error_max_m"] < 0.03
        assert metrics["crouch_zmp_error_max_m"] == pytest.approx(error.max(), rel=0.05)


def test_meshcat_port_and_button_only_reach_the_diagram(monkeypatch, capsys):
    """``--meshcat --meshcat-port P --button-only --after-halt S``: the port goes to Meshcat, no
    scheduled stop goes to the diagram (only the button stops), the log span goes along.
    The diagram is replaced by a stand-in (a live run walks in real time)."""
    from drake_estop.systems import diagram, visualization
    seen = {}

    class FakeMeshcat:
        def web_url(self):
            return "http://localhost:7123"

    class WalkedOn:  # nobody pressed the button: the walk ended without a stop
        plan, realtime_factor, plan_wall_time = None, 1.0, 0.0

        def error_summary(self):
            return {}

        def columns(self):
            return {}

    def fake_meshcat(port=None, *, host="localhost"):
        seen["port"], seen["host"] = port, host
        return FakeMeshcat()

    def fake_simulate(gait, stop, estop_time, **kwargs):
        seen.update(estop_time=estop_time, **kwargs)
        return WalkedOn()

    monkeypatch.setattr(visualization, "make_meshcat", fake_meshcat)
    monkeypatch.setattr(diagram, "simulate_diagram", fake_simulate)
    assert main(["simulate", "--meshcat", "--meshcat-port", "7123", "--button-only", "--after-halt", "2"]) == 0
    assert seen["port"] == 7123 and seen["estop_time"] is None and seen["after_halt"] == 2.0
    assert seen["host"] == "localhost"  # Meshcat on this machine only unless --meshcat-host says otherwise
    assert isinstance(seen["meshcat"], FakeMeshcat)
    out = capsys.readouterr().out
    assert "http://localhost:7123" in out and "walk ended without a stop signal" in out
    # without --button-only the scheduled signal goes along (whichever comes first stops)
    assert main(["simulate", "--meshcat", "--estop-time", "3.2"]) == 0
    assert seen["port"] is None and seen["estop_time"] == 3.2
    assert main(["simulate", "--meshcat", "--meshcat-host", "*", "--estop-time", "3.2"]) == 0
    assert seen["host"] == "*"


@pytest.mark.parametrize("options, note", [(["--kinematic"], "(one plan, cold)"),
                                           ([], "(made while walking; the latch ")])
def test_simulate_says_where_its_plan_time_was_measured(options, note, capsys):
    """A single plan right after the warm-up is cold; the diagram's stop is planned on the signal's walking
    tick and the latch a tick later only takes it."""
    assert main(["simulate", *options]) == 0
    line = next(text for text in capsys.readouterr().out.splitlines() if text.startswith("stop signal"))
    assert note in line, line
