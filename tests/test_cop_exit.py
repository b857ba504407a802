"""Where the CoP left the planned support: the sole edge it names, the run's exit, the campaign's columns
and its report table."""

import dataclasses

import numpy as np
import pytest
from campaign_helpers import fake_run

from drake_estop.campaign.config import default_config, run_seed, sample_run
from drake_estop.campaign.report import _columns, cop_exit_counts, write_report
from drake_estop.campaign.runner import guarded_run, outcome_from_reply
from drake_estop.campaign.storage import CRITERIA, ResultStore
from drake_estop.physics.criteria import EDGE_BAND, PhysicsResult, sole_edge
from drake_estop.physics.plant import PhysicsParameters
from drake_estop.planning.gait import NominalPattern, Sole
from drake_estop.planning.planner import StopParameters, plan_stop

SOLE = Sole()


@pytest.mark.parametrize(("side", "local", "edge"), [
    ("left", (-SOLE.heel - 0.002, 0.0), "heel"),
    ("left", (SOLE.toe, SOLE.outer), "toe-outer"),  # +y is the left foot's outer side
    ("right", (SOLE.toe, SOLE.outer), "toe-inner"),  # and the right foot's inner side
    ("right", (0.0, -SOLE.outer + 0.5 * EDGE_BAND), "outer"),
    ("left", (0.0, -SOLE.inner - 0.03), "inner"),
    ("left", (-SOLE.heel + 0.5 * EDGE_BAND, -SOLE.inner), "heel-inner"),
    ("right", (0.0, 0.0), "inside"),
    ("left", (SOLE.toe - 2 * EDGE_BAND, SOLE.outer - 2 * EDGE_BAND), "inside"),
])
def test_the_sole_edge_is_named_from_the_foot_s_own_side(side, local, edge):
    assert sole_edge(local, side, SOLE) == edge


@pytest.fixture(scope="module")
def plan():
    return plan_stop(NominalPattern(), 3.4, StopParameters())


def _times(plan):
    """Three ticks: before the contact, the end of the transition and mid-halt."""
    return np.array([0.0, plan.transition_end, 0.5 * (plan.slowdown_end + plan.halt_end)])


def _result(plan, cop, forces, margins, *, yaw=0.0):
    """A three-tick PhysicsResult: the feet where the plan rests them, ``cop`` (3, 2), ``forces`` side -> (3,)."""
    n = len(margins)
    feet = {side: np.tile(plan.final_feet[side][:3], (n, 1)) for side in ("left", "right")}
    zeros = np.zeros(n)
    values = {f.name: None for f in dataclasses.fields(PhysicsResult)}
    values.update(plan=plan, times=_times(plan), cop_x=np.asarray(cop)[:, 0], cop_y=np.asarray(cop)[:, 1],
                  normal_force=forces["left"] + forces["right"], foot_forces=forces, feet_meas=feet, feet_plan=feet,
                  cop_margin_plan=np.asarray(margins, float), cop_margin_meas=zeros, criteria={},
                  params=PhysicsParameters(), feet_yaw_meas={"left": zeros + yaw, "right": zeros + yaw})
    return PhysicsResult(**values)


def test_the_exit_is_the_least_margin_on_the_loaded_sole(plan):
    """The CoP 3 mm behind the left heel with the right sole unloaded mid-halt: the exit names the
    halt, the left sole and its heel; the first tick (before the first contact solve) is never the exit."""
    left = plan.final_feet["left"]
    cop = [[-9.0, -9.0], [left[0], left[1]], [left[0] - SOLE.heel - 0.003, left[1]]]
    forces = {"left": np.array([0.0, 300.0, 500.0]), "right": np.array([0.0, 300.0, 1.0])}
    exit_ = _result(plan, cop, forces, [-1.0, 0.05, -0.003]).cop_exit()
    assert exit_ == {"time": _times(plan)[2], "margin": -0.003, "phase": "halt", "soles": "left", "edge": "heel"}


def test_both_loaded_soles_name_the_nearest_one_s_edge_and_a_turned_foot_turns_the_edge(plan):
    right = plan.final_feet["right"]
    cop = [[0.0, 0.0], [0.0, 0.0], [right[0], right[1] - SOLE.heel - 0.004]]  # past the right outer edge
    forces = {"left": np.full(3, 200.0), "right": np.full(3, 400.0)}
    assert _result(plan, cop, forces, [0.0, 0.01, -0.004]).cop_exit()["soles"] == "both"
    assert _result(plan, cop, forces, [0.0, 0.01, -0.004]).cop_exit()["edge"] == "outer"
    # the same point seen from soles turned 90 degrees to the left lies past their heels
    assert _result(plan, cop, forces, [0.0, 0.01, -0.004], yaw=np.pi / 2).cop_exit()["edge"] == "heel"


def test_a_cop_that_stays_in_has_no_exit(plan):
    forces = {"left": np.full(3, 300.0), "right": np.full(3, 300.0)}
    assert _result(plan, np.zeros((3, 2)), forces, [-1.0, 0.0, 0.02]).cop_exit() is None
    assert _result(plan, np.zeros((3, 2)), forces, [np.nan, np.nan, np.nan]).cop_exit() is None


def _summary(cop_exit):
    numbers = {"time_to_rest_s": 1.0, "rest_after_halt_s": 0.1, "final_cog_offset_m": 0.001,
               "cog_travel_m": 0.3, "pelvis_z_min_m": 0.6, "torso_tilt_max_rad": 0.02,
               "cop_margin_plan_min_m": -0.004, "slip_left_m": 0.001, "slip_right_m": 0.002, "realtime_factor": 1.2}
    return {"physics": {"numbers": numbers, "cop_exit": cop_exit}, "success": False, "case": "one-step",
            "support": "single", "criteria": {name: name != "cop_in_support" for name in CRITERIA}, "replans": 0,
            "replan_failures": 0, "joint_velocity_violations": 0, "tick_compute": {"p99": 0.002},
            "steps_after_signal": 1}


def test_the_campaign_row_keeps_the_exit_phase_and_edge():
    reply = {"returncode": 1, "stderr": "", "exception": None,
             "summary": _summary({"time": 4.6, "margin": -0.004, "phase": "halt", "soles": "left", "edge": "heel"})}
    row = outcome_from_reply(reply)
    assert (row["cop_exit_phase"], row["cop_exit_edge"]) == ("halt", "heel")
    reply["summary"] = _summary(None)
    assert outcome_from_reply(reply)["cop_exit_phase"] is None


def test_the_report_tables_where_the_upright_runs_left_their_support(tmp_path):
    store = ResultStore(tmp_path / "c")
    rows = [guarded_run((fake_run, sample_run(default_config(), run_seed(5, i), i), 1.0)) for i in range(5)]
    exits = [("halt", "heel"), ("halt", "heel"), ("transition", "toe-outer"), (None, None), ("halt", "toe")]
    store.parts.mkdir(parents=True)
    for i, (row, (phase, edge)) in enumerate(zip(rows, exits)):
        # run 4 fell: its exit is not the table's
        store.write({**row, "error": None, "outcome": "failure", "success": False, "no_fall": i != 4,
                     "cop_in_support": phase is None, "cop_exit_phase": phase, "cop_exit_edge": edge})
    table = store.read()
    assert cop_exit_counts(_columns(table)) == {("halt", "heel"): 2, ("transition", "toe-outer"): 1}
    text = write_report(table, store.folder, manifest={"seed": 5, "config": {}, "sessions": []}).read_text()
    section = text.split("Where the CoP left the support")[1].split("<h2>")[0]
    assert "<th>heel</th><th>toe-outer</th><th>all</th>" in section
    assert "<tr><td>transition</td><td></td><td>1</td><td>1</td></tr>" in section
    assert "<tr><td>halt</td><td>2</td><td></td><td>2</td></tr>" in section
    # a table written before these columns reads with them null: no counts
    assert cop_exit_counts(_columns(table.drop_columns(["cop_exit_phase", "cop_exit_edge"]))) == {}


def test_sole_deviations_measure_a_loaded_planned_sole_against_the_plan():
    """The distance and turn of a sole from the plan's foothold count only where the plan stands on it
    and it carries load: a swing foot's lift, an unloaded sole's slide, are not counted."""
    from drake_estop.physics.criteria import sole_deviations

    n = 4
    plan = {"left": np.zeros((n, 3)), "right": np.zeros((n, 3))}
    plan["right"][1:3, 2] = 0.03  # the right foot swings at ticks 1-2
    measured = {side: values.copy() for side, values in plan.items()}
    measured["left"][2, :2] = [0.012, -0.005]  # 13 mm off, loaded
    measured["left"][3, :2] = [0.050, 0.0]  # 50 mm off, unloaded
    measured["right"][1, :2] = [0.2, 0.0]  # swinging
    yaw = {"left": np.array([0.0, 0.0, 0.08, 0.3]), "right": np.array([0.0, 0.5, 0.0, 2 * np.pi - 0.02])}
    planned_yaw = [{"left": 0.0, "right": 0.0}] * n
    loaded = {"left": np.array([True, True, True, False]), "right": np.ones(n, bool)}
    off_plan, turn = sole_deviations(measured, yaw, plan, planned_yaw, loaded)
    assert off_plan == pytest.approx({"left": 0.013, "right": 0.0})
    assert turn == pytest.approx({"left": 0.08, "right": 0.02})  # the heading wrapped: 2 pi - 0.02 is 0.02
    loaded["left"][:] = False
    assert sole_deviations(measured, yaw, plan, planned_yaw, loaded)[0]["left"] == 0.0


def test_the_report_tables_where_the_feet_stood_by_run_class(tmp_path):
    """The campaign's ``sole_off_plan_max`` / ``sole_turn_max`` columns, their medians per run class and the
    runs with a sole over 1 cm off; a table without them says so."""
    from drake_estop.campaign.report import OFF_PLAN, RUN_CLASSES, sole_deviation_counts

    store = ResultStore(tmp_path / "c")
    store.parts.mkdir(parents=True)
    runs = [(True, True, 0.002, 0.004), (True, True, 0.004, 0.006), (False, True, 0.019, 0.05),
            (False, True, 0.030, 0.09), (False, True, 0.008, 0.01), (False, False, 0.04, 0.2)]
    for i, (success, upright, off, turn) in enumerate(runs):
        row = guarded_run((fake_run, sample_run(default_config(), run_seed(3, i), i), 1.0))
        store.write({**row, "error": None, "outcome": "success" if success else "failure", "success": success,
                     "no_fall": upright, "sole_off_plan_max": off, "sole_turn_max": turn})
    table = store.read()
    counts = sole_deviation_counts(_columns(table))
    assert list(counts) == list(RUN_CLASSES)
    assert counts["met every criterion"] == pytest.approx(
        {"runs": 2, "off_plan_median": 0.003, "turn_median": 0.005, "off_plan_runs": 0})
    assert counts["stayed up, missed a criterion"] == pytest.approx(
        {"runs": 3, "off_plan_median": 0.019, "turn_median": 0.05, "off_plan_runs": 2})
    assert counts["fell"]["off_plan_runs"] == 1 and OFF_PLAN == 0.01
    text = write_report(table, store.folder, manifest={"seed": 3, "config": {}, "sessions": []}).read_text()
    section = text.split("Where the feet stood")[1].split("<h2>")[0]
    assert "<tr><td>stayed up, missed a criterion</td><td>3</td><td>19.0</td><td>0.050</td><td>2</td></tr>" in section
    data = _columns(table)
    data["sole_off_plan_max"][:] = np.nan  # an older table: the columns empty
    assert sole_deviation_counts(data) == {}
