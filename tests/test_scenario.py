"""Scenarios as data: YAML through Drake's yaml_load_typed, the CLI on top of it,
the plant from MultibodyPlantConfig, and the shipped scenario files."""

import json
from dataclasses import replace
from pathlib import Path

import pytest
from pydrake.multibody.plant import ContactModel, DiscreteContactApproximation
from pydrake.systems.framework import DiagramBuilder

from drake_estop.cli import main
from drake_estop.physics.controller_options import ControllerOptions, HipStrategyConfig, SwingTiltConfig
from drake_estop.physics.perturbations import Perturbations, Push
from drake_estop.physics.plant import PhysicsParameters, add_physics_plant, plant_config
from drake_estop.planning.gait import GaitParameters, NominalPattern, Sole
from drake_estop.planning.planner import StopParameters, plan_stop
from drake_estop.scenario import Scenario, dump_scenario, load_scenario
from drake_estop.systems.decision import StopPlannerConfig

SCENARIOS = sorted((Path(__file__).resolve().parents[1] / "diagrams" / "scenarios").glob("*.yaml"))


def _unusual():
    return Scenario(
        gait=GaitParameters(step_length=0.22, num_steps=6, sole=Sole(toe=0.14)),
        stop=StopParameters(zmp_margin=0.02, halt_durations=(0.9, 1.4), crouch=False),
        estop_time=3.3, simulation="physics",
        controller=ControllerOptions(true_state=True, swing_tilt=None,
                                     planner=StopPlannerConfig(foothold_replan=True, max_replan_solves=3)),
        perturbations=Perturbations(pushes=(Push(3.3, 100.0, -20.0, 0.1), Push(3.5, 0.0, 50.0, 0.05)),
                                    mass_scale=1.1, friction=0.6, latency_ticks=2, sensor_noise=True, seed=7),
        after_halt=2.0)


def test_dump_and_load_round_trip():
    scenario = _unusual()
    loaded = load_scenario(text=dump_scenario(scenario))
    assert loaded.gait == scenario.gait and loaded.stop == scenario.stop
    assert loaded.perturbations == scenario.perturbations
    assert (loaded.estop_time, loaded.simulation, loaded.after_halt) == (3.3, "physics", 2.0)
    assert loaded.controller == scenario.controller
    assert isinstance(loaded.stop.halt_durations, tuple) and isinstance(loaded.perturbations.pushes[0], Push)


@pytest.mark.parametrize("estop_time, max_replan_solves", [(None, 2), (3.4, None), (3.4, 3), (None, None)])
def test_optional_fields_round_trip_null_included(estop_time, max_replan_solves):
    """A None (the Meshcat button's stop, an unbounded re-plan in the controller section) is written as null:
    left out it would read back as the default (3.4 s, 2 solves)."""
    planner = StopPlannerConfig(max_replan_solves=max_replan_solves)
    scenario = Scenario(estop_time=estop_time, controller=ControllerOptions(planner=planner))
    loaded = load_scenario(text=dump_scenario(scenario))
    assert (loaded.estop_time, loaded.controller.planner.max_replan_solves) == (estop_time, max_replan_solves)
    assert loaded.controller == scenario.controller


def test_a_partial_document_keeps_the_defaults():
    scenario = load_scenario(text="{gait: {step_length: 0.2}, plant: {time_step: 0.002}}")
    assert scenario.gait == GaitParameters(step_length=0.2)
    assert scenario.stop == StopParameters() and scenario.perturbations == Perturbations()
    assert scenario.plant.time_step == 0.002 and scenario.plant.contact_model == "point"


@pytest.mark.parametrize("text,named", [
    ("{gait: {stp_length: 0.3}}", "stp_length"),
    ("{speed: 3}", "speed"),
    ("{perturbations: {mass_scale: -1}}", "--mass-scale"),
    ("{perturbations: {pushes: [{time: 3.4, force_x: 1, force_y: 0, duration: 0}]}}", "duration"),
    ("{simulation: walking}", "simulation"),
    ("{after_halt: 0.5}", "after_halt"),
    ("{controller: {planner: {max_replan_solves: 0}}}", "max_replan_solves"),
    ("{controller: {kind: walking}}", "controller.kind"),
    ("{controller: {swing_tlt: false}}", "swing_tlt"),
    ("{controller: {foot_compliance: 3}}", "foot_compliance"),
    ("{controller: online}", "controller must be a mapping"),
    ("{max_replan_solves: 2}", "max_replan_solves"),  # a controller field, not a scenario one
    ("{controller: {planner: {max_replan_solves: two}}}",
     "controller.planner.max_replan_solves must be a whole number or null"),
    ("{controller: {max_steps: 2}}", "controller.max_steps is now controller.planner.max_steps"),
    ("{controller: {swing_tilt: true}}", r"controller.swing_tilt must be a mapping of its settings \({} for the"),
    ("{estop_time: abc}", "estop_time must be a number or null"),
    ("{gait: {num_steps: 2.5}}", "gait.num_steps must be a whole number"),
    ("{gait: 3}", "gait must be a mapping"),
    ("{plant: {contact_model: hydroelastic}}", "plant.contact_model"),
    ("{stop: {min_landing_time: 2.0}}", "landing_time"),
])
def test_bad_documents_name_what_is_wrong(text, named):
    with pytest.raises(ValueError, match=named):
        load_scenario(text=text)


def test_a_controller_section_reads_into_controller_options():
    scenario = load_scenario(text="controller:\n  kind: offline-filter\n  foot_compliance: null\n"
                                  "  planner: {max_replan_solves: null}\n  hip_strategy: {amplitude: 0.1}\n")
    assert scenario.controller == ControllerOptions(kind="offline-filter", foot_compliance=None,
                                                    planner=StopPlannerConfig(max_replan_solves=None),
                                                    hip_strategy=HipStrategyConfig(amplitude=0.1))
    assert load_scenario(text="{controller: {swing_tilt: null}}").controller == ControllerOptions(swing_tilt=None)
    assert load_scenario(text="{controller: {hip_strategy: {}}}").controller.hip_strategy == HipStrategyConfig()
    assert load_scenario(text=dump_scenario(scenario)).controller == scenario.controller  # None reads back as None


@pytest.mark.parametrize("fields, named", [
    ({"kind": "online-ish"}, "controller.kind"),
    ({"foot_compliance": "no"}, "controller.foot_compliance"),
    ({"foot_compliance": False}, "controller.foot_compliance must be a FootEdgeComplianceConfig or None"),
    ({"hip_strategy": True}, "controller.hip_strategy"),
    ({"planner": {"recovery_step": False}}, "controller.planner must be a StopPlannerConfig"),
    ({"true_state": 1}, "controller.true_state"),
])
def test_controller_options_reject_bad_values_naming_the_field(fields, named):
    with pytest.raises(ValueError, match=named):
        ControllerOptions(**fields)


@pytest.mark.parametrize("changes, named", [
    ({"recovery_step": False}, "controller.recovery_step is now controller.planner.recovery_step"),
    ({"foot_force_control": False}, "controller.foot_force_control is now controller.foot_force"),
    ({"planner.recovry_step": False}, r"controller.planner: unknown setting\(s\) \['recovry_step'\]"),
    ({"planner.max_replan_solves": 0}, "max_replan_solves"),
    ({"swing_tlt": None}, "controller.swing_tlt is not a controller field"),
])
def test_changes_by_dotted_name_reject_unknown_and_moved_keys_naming_them(changes, named):
    with pytest.raises(ValueError, match=named):
        ControllerOptions().with_changes(changes)


def test_changes_by_dotted_name_read_back_what_changed_reports():
    controller = ControllerOptions(planner=StopPlannerConfig(recovery_step=False), foot_compliance=None,
                                   swing_tilt=SwingTiltConfig(deadband=0.02), hip_strategy=HipStrategyConfig())
    assert controller.changed() == {"planner.recovery_step": False, "foot_compliance": None,
                                    "swing_tilt.deadband": 0.02, "hip_strategy": {}}
    assert ControllerOptions().with_changes(controller.changed()) == controller
    assert ControllerOptions().changed() == {}


def test_a_scenario_takes_only_controller_options_as_its_controller():
    with pytest.raises(ValueError, match="controller must be a ControllerOptions"):
        Scenario(controller="online")


def test_load_needs_exactly_one_source(tmp_path):
    with pytest.raises(ValueError, match="exactly one"):
        load_scenario()
    with pytest.raises(ValueError, match="exactly one"):
        load_scenario(filename=tmp_path / "x.yaml", text="{}")


def test_cli_takes_the_scenario_and_options_override_it(tmp_path):
    """Fields the command line has no option for (zmp_margin, halt_durations) reach the plan;
    an explicit option (--step-length) overrides the file."""
    path = tmp_path / "scenario.yaml"
    path.write_text("gait: {step_length: 0.3, step_time: 0.8}\n"
                    "stop: {zmp_margin: 0.02, halt_durations: [0.8, 1.0]}\n"
                    "estop_time: 3.3\nsimulation: kinematic\n")
    summary = tmp_path / "s.json"
    assert main(["simulate", "--scenario-file", str(path), "--step-length", "0.2", "--summary", str(summary)]) == 0
    data = json.loads(summary.read_text())
    gait = GaitParameters(step_length=0.2, step_time=0.8)
    plan = plan_stop(NominalPattern(gait), 3.3, StopParameters(zmp_margin=0.02, halt_durations=(0.8, 1.0)))
    assert data["phase_times"]["halt_end"] == pytest.approx(plan.halt_end, abs=1e-12)
    assert data["phase_times"]["landing_end"] == pytest.approx(plan.landing_time, abs=1e-12)
    default = plan_stop(NominalPattern(gait), 3.3, StopParameters())
    assert plan.halt_end != pytest.approx(default.halt_end, abs=1e-6)  # the file's stop parameters mattered


def test_print_scenario_shows_the_effective_scenario(capsys):
    assert main(["simulate", "--scenario-text", "{gait: {step_length: 0.25}, controller: {swing_tilt: null, "
                 "planner: {max_replan_solves: null}}}", "--physics", "--mass-scale", "1.2", "--push", "3.4", "100",
                 "0", "0.1", "--true-state", "--print-scenario"]) == 0
    text = capsys.readouterr().out
    scenario = load_scenario(text=text)
    assert scenario.gait.step_length == 0.25 and scenario.simulation == "physics"
    assert scenario.perturbations.mass_scale == 1.2 and scenario.perturbations.pushes == (Push(3.4, 100.0, 0.0, 0.1),)
    assert scenario.controller == ControllerOptions(swing_tilt=None, true_state=True,
                                                    planner=StopPlannerConfig(max_replan_solves=None))
    section = text[text.index("\ncontroller:\n"):text.index("\nplant:\n")].split("\n")[2:]
    fields = [line.split(":")[0].strip() for line in section if line.startswith("  ") and not line.startswith("   ")]
    assert fields == ["kind", "true_state", "whole_body_walk", "braked_landing", "planner", "foot_force",
                      "foot_compliance", "touchdown", "swing_tilt", "hip_strategy"]  # every field (None ones last)


@pytest.mark.parametrize("args,named", [
    (["--scenario-text", "{gait: {stp: 1}}"], "stp"),
    (["--scenario-file", "/nonexistent/s.yaml"], "--scenario-file"),
    (["--scenario-file", "x.yaml", "--scenario-text", "{}"], "not both"),
])
def test_cli_bad_scenarios_exit_2(capsys, args, named):
    assert main(["simulate", "--kinematic", *args]) == 2
    assert named in capsys.readouterr().err


def test_plant_from_multibody_plant_config():
    for contact, model in (("point", ContactModel.kPoint),
                           ("hydroelastic", ContactModel.kHydroelasticWithFallback)):
        params = PhysicsParameters(time_step=2e-3, contact=contact)
        assert plant_config(params).time_step == 2e-3
        plant, *_ = add_physics_plant(DiagramBuilder(), params)
        assert plant.time_step() == 2e-3 and plant.get_contact_model() == model
        assert plant.get_discrete_contact_approximation() == DiscreteContactApproximation.kLagged


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.stem)
def test_shipped_scenarios_load_and_plan(path):
    scenario = load_scenario(filename=path)
    plan = plan_stop(NominalPattern(scenario.gait), scenario.estop_time, scenario.stop)
    assert plan.case == "one-step"


def test_paper_scenario_files_hold_the_paper_values():
    by_name = {path.stem: load_scenario(filename=path) for path in SCENARIOS}
    single = by_name["single_support_stop"]
    assert (single.gait.step_length, single.gait.step_time, single.estop_time) == (0.3, 0.8, 3.4)
    assert (single.stop.a_ss, single.stop.b_ss) == (5.0, 1000.0)
    double = by_name["double_support_stop"]
    assert (double.estop_time, double.stop.a_ds, double.stop.b_ds) == (3.5, 50.0, 1000.0)
    assert replace(by_name["hrp2_experiment"].gait, step_length=0.3) == single.gait


@pytest.mark.parametrize("option,field,value", [
    ("--zmp-margin", "zmp_margin", 0.02),
    ("--max-landing-time", "max_landing_time", 0.6),
    ("--lift-height", "lift_height", 0.07),
    ("--landing", "landing", "nominal"),
])
def test_generated_field_options_reach_the_plan(tmp_path, option, field, value):
    """Options generated from the dataclass fields act like the curated ones: the plan equals one
    made from the parameter classes with that field set."""
    summary = tmp_path / "s.json"
    assert main(["simulate", "--kinematic", "--estop-time", "3.3", option, str(value), "--summary", str(summary)]) == 0
    gait, stop = GaitParameters(), StopParameters()
    if field in {f for f in GaitParameters.__dataclass_fields__}:
        gait = replace(gait, **{field: value})
    else:
        stop = replace(stop, **{field: value})
    plan = plan_stop(NominalPattern(gait), 3.3, stop)
    data = json.loads(summary.read_text())
    assert data["phase_times"]["halt_end"] == pytest.approx(plan.halt_end, abs=1e-12)
    assert data["phase_times"]["landing_end"] == pytest.approx(plan.landing_time, abs=1e-12)


@pytest.mark.parametrize("args,named", [
    (["--zmp-margin", "-1"], "zmp_margin"),
    (["--landing", "teleport"], "landing"),
    (["--min-landing-time", "2"], "landing_time"),
])
def test_generated_field_options_reject_bad_values(capsys, args, named):
    assert main(["simulate", "--kinematic", *args]) == 2
    assert named in capsys.readouterr().err
