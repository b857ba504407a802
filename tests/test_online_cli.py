"""`drake-estop simulate --physics` on the command line: the perturbation and controller options reach
the online run, bad ones exit 2 naming the option, the summary reports the controller."""

import json
import math
import re

import pytest

from drake_estop.cli import main
from drake_estop.physics.controller_options import MOVED_KEYS, ControllerOptions, SwingTiltConfig, as_section
from drake_estop.physics.criteria import CRITERIA
from drake_estop.physics.perturbations import Push
from drake_estop.systems.decision import StopPlannerConfig


@pytest.mark.parametrize("args, option", [
    (["--mass-scale", "0"], "--mass-scale"),
    (["--mass-scale", "nan"], "--mass-scale"),
    (["--torso-mass-scale", "-1"], "--torso-mass-scale"),
    (["--torso-com-offset", "0.5"], "--torso-com-offset"),
    (["--friction", "0"], "--friction"),
    (["--latency", "-1"], "--latency"),
    (["--push", "3.4", "10", "0", "0"], "--push"),
    (["--push", "3.4", "nan", "0", "0.1"], "--push"),
    (["--seed", "-3"], "--seed"),
    (["--floor-drop", "0.7", "1.1", "-0.2", "0.0", "0.1"], "--floor-drop"),
])
def test_bad_perturbations_exit_2_naming_the_option(args, option, capsys):
    assert main(["simulate", "--physics", *args]) == 2
    assert option in capsys.readouterr().err


def test_perturbations_need_physics(capsys):
    assert main(["simulate", "--kinematic", "--mass-scale", "1.1"]) == 2
    assert "--physics" in capsys.readouterr().err


def _online_run_keywords(monkeypatch, args):
    """The keyword arguments `simulate --physics ARGS` passes to run_online, and its stop parameters under
    ``"stop_params"`` (the run itself is cut short)."""
    import drake_estop.physics.online as online

    seen = {}

    def fake_run_online(gait, stop, estop_time, **kwargs):
        seen.update(kwargs, stop_params=stop)
        raise RuntimeError("stop here")

    monkeypatch.setattr(online, "run_online", fake_run_online)
    assert main(["simulate", "--physics", *args]) == 2
    return seen


def _online_run_stop_parameters(monkeypatch, args):
    """The stop parameters `simulate --physics ARGS` passes to run_online (the run itself is cut short)."""
    return _online_run_keywords(monkeypatch, args)["stop_params"]


def test_the_braked_landing_reaches_the_online_run_and_turns_off(monkeypatch):
    """The controller's braked landing (BRAKED_LANDING) is in run_online's stop parameters by default,
    over the controller's margin; the scenario's ``controller: {braked_landing: false}`` gives the paper's
    landing swing; a tighter limit from the command line is kept."""
    braked = _online_run_stop_parameters(monkeypatch, [])
    paper = _online_run_stop_parameters(monkeypatch, ["--scenario-text", "{controller: {braked_landing: false}}"])
    tighter = _online_run_stop_parameters(monkeypatch, ["--max-swing-acceleration=10", "--landing-approach-slope=0.8"])
    assert braked.max_swing_acceleration == 15.0 and braked.landing_approach_slope == 0.6
    assert braked.landing_approach_when_braking  # the slope only where the braking limit bounds the landing
    assert braked.zmp_margin == paper.zmp_margin == pytest.approx(0.03)
    assert paper.max_swing_acceleration == math.inf and paper.landing_approach_slope == 0.0
    assert tighter.max_swing_acceleration == 10.0 and tighter.landing_approach_slope == 0.8
    assert not tighter.landing_approach_when_braking  # a slope given shapes every swing


#: One value off its default for every field of the controller section but ``kind``, by dotted name.
CHANGED = {"true_state": True, "whole_body_walk": True, "braked_landing": False,
           "swing_tilt": None, "foot_force": None, "foot_compliance": None, "hip_strategy": {},
           "touchdown": None,
           "swing_tilt.deadband": 0.02, "foot_compliance.edge_margin": 0.02, "foot_force.damping": 3000.0,
           **{f"planner.{name}": value for name, value in {
               "replan_threshold": 0.06, "landed_replan_threshold": 0.09, "replan_interval": 0.1, "blend_time": 0.3,
               "measured_footholds": False, "foothold_ticks": 3, "foothold_replan": True, "foothold_tolerance": 0.01,
               "relanded_footholds": False, "recovery_step": False, "capture_landing": False, "crossover_step": True,
               "max_steps": 2, "max_replan_solves": None, "max_latch_solves": 3, "reference_fallback": False,
               "plan_ahead": False, "late_landing": True, "max_late_landing": 0.1, "halt_footholds": True}.items()}}


def _controller_text(name, value) -> str:
    """``--scenario-text`` setting one field of the controller section, dotted inside a sub-section (JSON is
    YAML)."""
    return json.dumps({"controller": as_section({name: value})})


def test_every_controller_field_has_a_changed_value_here():
    names = {name.partition(".")[0] for name in CHANGED}
    assert names == {name for name in ControllerOptions.__dataclass_fields__} - {"kind", "planner"} | {"planner"}
    assert {name.partition(".")[2] for name in CHANGED if name.startswith("planner.")} == set(
        StopPlannerConfig.field_names())


@pytest.mark.parametrize("old, new", MOVED_KEYS.items())
def test_a_key_of_the_former_flat_controller_section_exits_2_naming_its_new_place(old, new, capsys):
    assert main(["simulate", "--physics", "--scenario-text", f"{{controller: {{{old}: false}}}}"]) == 2
    assert f"controller.{old} is now controller.{new}" in capsys.readouterr().err


def test_a_reflex_given_true_or_false_exits_2_asking_for_its_settings_or_null(capsys):
    assert main(["simulate", "--physics", "--scenario-text", "{controller: {foot_compliance: false}}"]) == 2
    assert "controller.foot_compliance must be a mapping of its settings ({} for the defaults) or null" in (
        capsys.readouterr().err)


def test_the_scenarios_controller_section_reaches_the_online_run(monkeypatch, tmp_path):
    """A scenario file's controller section is what run_online receives, with --true-state on top."""
    path = tmp_path / "scenario.yaml"
    path.write_text("controller:\n  kind: online\n  foot_compliance: null\n  planner:\n    recovery_step: false\n"
                    "    max_replan_solves: 5\n  swing_tilt: {deadband: 0.02}\n")
    seen = _online_run_keywords(monkeypatch, ["--scenario-file", str(path), "--true-state"])
    planner = StopPlannerConfig(recovery_step=False, max_replan_solves=5)
    assert seen["controller"] == ControllerOptions(foot_compliance=None, true_state=True, planner=planner,
                                                   swing_tilt=SwingTiltConfig(deadband=0.02))
    assert _online_run_keywords(monkeypatch, [])["controller"] == ControllerOptions()


@pytest.mark.parametrize("name", CHANGED)
def test_each_controller_field_reaches_the_online_run(monkeypatch, name):
    seen = _online_run_keywords(monkeypatch, ["--scenario-text", _controller_text(name, CHANGED[name])])
    assert seen["controller"].changed() == {name: CHANGED[name]}  # the others at their defaults
    assert ControllerOptions().with_changes({name: CHANGED[name]}) == seen["controller"]


@pytest.mark.parametrize("name", CHANGED)
@pytest.mark.parametrize("mode", [["--kinematic"], ["--physics", "--controller", "offline-filter"]])
def test_each_controller_field_needs_the_online_physics_run(name, mode, capsys):
    assert main(["simulate", *mode, "--scenario-text", _controller_text(name, CHANGED[name])]) == 2
    err = capsys.readouterr().err
    assert f"controller.{name}: only with" in err
    assert all(not re.search(rf"controller\.{re.escape(other)}(?![.\w])", err) for other in CHANGED if other != name)


def test_the_offline_filter_needs_physics(capsys):
    assert main(["simulate", "--kinematic", "--controller", "offline-filter"]) == 2
    assert "controller.kind: only with --physics" in capsys.readouterr().err


@pytest.mark.parametrize("flag", ["--no-foot-compliance", "--no-swing-tilt", "--no-measured-footholds",
                                  "--no-braked-landing", "--no-relanded-footholds", "--no-recovery-step",
                                  "--no-reference-fallback", "--foothold-replan", "--max-replan-solves=1"])
def test_the_controller_features_are_not_command_line_options(flag, capsys):
    """They are the scenario's controller section (--scenario-file / --scenario-text)."""
    assert main(["simulate", "--physics", flag]) == 2
    assert "unrecognized arguments" in capsys.readouterr().err


@pytest.mark.parametrize("value", ["0", "-1", "1.5", "two", ".nan", "true"])
def test_a_bad_max_steps_exits_2_naming_it(value, capsys):
    text = f"{{controller: {{planner: {{max_steps: {value}}}}}}}"
    assert main(["simulate", "--physics", "--scenario-text", text]) == 2
    assert "max_steps" in capsys.readouterr().err


@pytest.mark.parametrize("value", ["0", "-1", "1.5", "two", ".nan"])
def test_a_bad_max_replan_solves_exits_2_naming_it(value, capsys):
    text = f"{{controller: {{planner: {{max_replan_solves: {value}}}}}}}"
    assert main(["simulate", "--physics", "--scenario-text", text]) == 2
    assert "max_replan_solves" in capsys.readouterr().err


@pytest.mark.parametrize("args, field, value", [
    (["--push", "3.4", "170", "0", "0.1"], "pushes", (Push(3.4, 170.0, 0.0, 0.1),)),
    (["--push", "3.4", "170", "0", "0.1", "--push", "3.6", "0", "-50", "0.2"], "pushes",
     (Push(3.4, 170.0, 0.0, 0.1), Push(3.6, 0.0, -50.0, 0.2))),
    (["--mass-scale", "1.1"], "mass_scale", 1.1),
    (["--torso-mass-scale", "0.9"], "torso_mass_scale", 0.9),
    (["--torso-com-offset", "-0.02"], "torso_com_offset", -0.02),
    (["--friction", "0.5"], "friction", 0.5),
    (["--latency", "1"], "latency_ticks", 1),
    (["--sensor-noise"], "sensor_noise", True),
    (["--seed", "7"], "seed", 7),
])
def test_each_perturbation_option_reaches_the_simulated_run(monkeypatch, tmp_path, args, field, value):
    """Every option lands in the Perturbations the online run is given (the modules' own tests show
    each one acting on the plant, the sensors and the push input)."""
    seen = _online_run_keywords(monkeypatch, args)
    assert getattr(seen["perturbations"], field) == value
    assert seen["controller"] == ControllerOptions()


@pytest.mark.slow
def test_physics_summary_reports_the_online_controller(tmp_path):
    summary, log = tmp_path / "s.json", tmp_path / "log.csv"
    code = main(["simulate", "--physics", "--estop-time", "3.4", "--mass-scale", "1.1",
                 "--summary", str(summary), "--log", str(log)])
    data = json.load(open(summary))
    assert code == (0 if data["success"] else 1)
    assert data["controller"] == "online"
    assert set(data["criteria"]) == set(CRITERIA)
    assert set(data["tick_compute"]) >= {"median", "p99", "max"}
    assert data["tick_compute"]["median"] > 0
    assert set(data["tick_compute_cpu"]) >= {"median", "p99", "max"} and data["tick_compute_cpu"]["median"] > 0
    assert data["tick_compute_by_block"]["WholeBodyIK._update"] > 0
    worst = data["tick_compute_slowest"][0]  # the slowest tick after the signal, block by block
    assert worst["total"] == pytest.approx(data["tick_compute_cpu"]["max"]) and worst["blocks"]
    assert data["cpu_realtime_factor"] > 0  # how large is a benchmark (benchmarks/robustness.py), not a test
    assert isinstance(data["replans"], int) and isinstance(data["joint_velocity_violations"], int)
    assert 0.0 <= data["ankle_offset_max"] <= 0.05  # the foot-edge compliance's bound
    assert 0.0 <= data["swing_tilt_max"] <= 0.17  # the swing-tilt compensation's cap
    assert data["perturbations"]["mass_scale"] == 1.1
    header = open(log).readline().strip().split(",")
    for column in ("cop_x", "cop_y", "pelvis_z", "com_meas_x", "com_meas_y", "com_meas_z", "com_est_x",
                   "one_step_feasible", "capture_steps", "capture_margin", "mode", "steps_left"):
        assert column in header
    assert data["modes"][0]["mode"] == "walking" and len(data["modes"]) >= 2  # the stop's modes from the latch
    # the measured state's capturability at the signal (no push): caught in at most three steps
    assert set(data["capturability"]) == {"steps", "margin", "margin_speed", "witness", "worst"}
    assert 0 <= data["capturability"]["steps"] <= 3 and data["capturability"]["margin"] >= 0.0
    assert len(data["capturability"]["witness"]) == data["capturability"]["steps"]


#: The campaign's run 181 (docs/campaign): a push under way at the signal that no stop from the measured state catches.
RUN_181 = ["simulate", "--physics", "--estop-time", "3.275", "--step-length", "0.2234", "--step-time", "0.875",
           "--step-width", "0.2034", "--push", "3.196", "412.98", "400.42", "0.052", "--mass-scale", "0.915",
           "--torso-mass-scale", "1.0602", "--torso-com-offset", "-0.01243", "--friction", "0.8393",
           "--latency", "1", "--seed", "1809849821110597283", "--sensor-noise"]


def test_without_the_reference_fallback_that_push_ends_the_run_with_the_planners_reason(capsys):
    assert main([*RUN_181, "--scenario-text", "{controller: {planner: {reference_fallback: false}}}"]) == 2
    assert "stop planning failed at t = 3.280 s: no feasible stop in the first 4 tries" in capsys.readouterr().err


def test_a_push_no_stop_catches_at_the_signal_still_runs_the_stop_from_the_reference(tmp_path, capsys):
    """The campaign's run 181 (29.9 N s forward-left starting 79 ms before a 3.275 s signal,
    model error, noise, one tick of latency): at the signal no stop within two steps exists from the
    measured state, and the run used to end there with exit status 2 ("stop planning failed"). The latch
    now plans the paper's stop from the reference and re-plans from the measured state: the run goes to
    its end and writes its summary. The robot is not saved: its lateral DCM lies past the left sole's outer
    edge, and it falls over that edge 2.2 s after the signal (with the paper's J_ds weight, before the default
    humanoid took its own, it stayed up with the CoP outside the planned soles)."""
    summary = tmp_path / "summary.json"
    code = main([*RUN_181, "--summary", str(summary)])
    data = json.loads(summary.read_text())
    assert code == (0 if data["physics"]["success"] else 1)
    assert "no feasible stop in the first 4 tries" in data["latch_fallback"]  # MAX_LATCH_SOLVES
    assert "planned from the reference" in capsys.readouterr().out
    assert set(data["physics"]["criteria"]) == set(CRITERIA)
    assert data["replans"] >= 1
    # where the CoP left the planned soles (it did: the robot fell), at the least margin the summary gives
    exit_ = data["physics"]["cop_exit"]
    assert not data["physics"]["criteria"]["cop_in_support"]
    assert exit_["margin"] == data["physics"]["numbers"]["cop_margin_plan_min_m"] < 0
    assert exit_["phase"] in ("landing", "transition", "slowdown", "halt", "stopped") and exit_["edge"]

