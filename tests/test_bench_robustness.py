"""benchmarks/robustness.py: which runs it re-runs alone for their tick time, and how it reports them
(the runs themselves are physics, minutes: a benchmark)."""

import json

import pytest
from scripts import load_script


@pytest.fixture(scope="module")
def bench():
    return load_script("benchmarks/robustness.py")


def _row(p99, worst, success=True, slowest=None, **options):
    return {"t": 2.95, "options": options, "success": success, "numbers": {"offset": 0.001}, "replans": 1,
            "failed": [], "tick_compute_cpu": {"median": 1e-3, "p99": p99, "max": worst},
            "tick_compute_slowest": slowest or [{"t": 3.175, "total": worst, "blocks": {
                "StopPlannerSystem._update": 0.7 * worst, "WholeBodyIK._update": 0.2 * worst,
                "StateEstimator._calc_estimate": 0.1 * worst}}]}


def _one_worker_pool(monkeypatch, bench, again):
    """The benchmark's process pool replaced by one in this process whose every run returns ``again``;
    returns the list of jobs it was given."""
    seen = []

    class Pool:
        def __init__(self, workers):
            assert workers == 1  # alone: the other core idle

        def __enter__(self):
            return self

        def __exit__(self, *args):
            return False

        def map(self, function, items):
            seen.extend(items)
            return [again for _ in items]

    monkeypatch.setattr(bench, "ProcessPoolExecutor", Pool)
    return seen


def test_slow_runs_are_those_over_issue_13s_p99_or_max(bench):
    rows = [_row(3e-3, 9e-3), _row(5.2e-3, 8e-3), _row(3e-3, 10.5e-3), {"t": 3.0, "options": {}, "success": False,
                                                                         "error": "InfeasibleStop: none"}]
    assert bench.slow_runs(rows) == [1, 2]  # a run that raised has no tick time


def test_recheck_reruns_the_slow_runs_alone_and_says_whether_they_did_the_same(bench, monkeypatch):
    rows = [_row(3e-3, 9e-3), _row(3e-3, 12e-3, push=[0.0, 170.0])]
    jobs = ["fast job", "slow job"]
    seen = _one_worker_pool(monkeypatch, bench, dict(_row(2.5e-3, 5.8e-3, push=[0.0, 170.0]),
                                                      numbers={"offset": 0.002}))
    bench.recheck(rows, jobs)
    assert seen == ["slow job"] and "recheck" not in rows[0]
    again = rows[1]["recheck"]
    assert again["tick_compute_cpu"]["max"] == 5.8e-3
    assert again["same_run"] is False  # its final offset differs: not the same run (the report says NO)
    lines = bench.recheck_lines(rows)
    row = next(line for line in lines if line.startswith("| 2.950 s push"))
    assert row == ("| 2.950 s push [0.0, 170.0] | 3.00 / 12.00 | 3.175 s: 12.00 (StopPlannerSystem._update 8.40, "
                   "WholeBodyIK._update 2.40) | 2.50 / 5.80 | 3.175 s: 5.80 (StopPlannerSystem._update 4.06, "
                   "WholeBodyIK._update 1.16) | NO |")
    assert bench.recheck_lines([_row(3e-3, 9e-3)]) == []


def test_a_fallen_run_rerun_alone_is_the_same_run_though_its_rest_time_is_nan(bench, monkeypatch):
    fallen = dict(_row(3e-3, 12e-3), success=False, numbers={"rest_after_halt": float("nan"), "offset": 0.3})
    _one_worker_pool(monkeypatch, bench, dict(fallen, numbers=dict(fallen["numbers"]),
                                              tick_compute_cpu={"median": 1e-3, "p99": 3e-3, "max": 6e-3}))
    rows = [fallen]
    bench.recheck(rows, ["job"])
    assert rows[0]["recheck"]["same_run"] is True


# -- the ablation: its table, and each kind of run keeping the other's part of the report ------------------


def _matrix_row(success=True, failed=(), **numbers):
    return {"t": 2.95, "options": {}, "success": success, "failed": list(failed),
            "numbers": {"tilt": 0.4, "slip": 0.0, "rest_after_halt": float("nan"), "offset": 0.3,
                        "cop_margin": -0.0012, "airborne_ticks": 0, **numbers}}


PHASE_TIMES = {"early single support": 2.95, "double support": 3.55}


def test_the_ablation_covers_every_controller_feature_and_the_2_ms_plant(bench):
    from drake_estop.physics.controller_options import ControllerOptions

    assert bench.ABLATION[0] == {}  # the defaults first
    controller = [change["controller"] for change in bench.ABLATION if "controller" in change]
    # each off its default
    assert all(ControllerOptions().with_changes(fields).changed() == fields for fields in controller)
    features = set(ControllerOptions.__dataclass_fields__) - {"kind", "true_state", "planner"} | {
        "planner.measured_footholds", "planner.relanded_footholds", "planner.recovery_step", "planner.capture_landing",
        "planner.reference_fallback", "planner.foothold_replan", "planner.max_replan_solves", "planner.max_steps",
        "planner.crossover_step", "planner.late_landing", "planner.halt_footholds",
        "foot_force.planned_support"}  # the planner's and reflexes' features, not their thresholds and times
    assert {name for fields in controller for name in fields} == features
    assert len(controller) == len(features)  # one row per feature
    assert {"touchdown": None} in controller and {"planner.late_landing": True} in controller
    assert {"plant": {"time_step": 0.002}} in bench.ABLATION
    keys = [bench.change_key(change) for change in bench.ABLATION]
    assert len(set(keys)) == len(keys) == 21 and keys[0] == "defaults"
    assert bench.change_label({"controller": {"planner.max_replan_solves": None}}) == (
        "controller.planner.max_replan_solves: null")
    assert bench.change_settings({"plant": {"time_step": 0.002}})["time_step"] == 0.002


def test_an_ablation_row_counts_passes_falls_and_names_the_failing_cells(bench):
    rows = [_matrix_row(), _matrix_row(False, ["no_fall", "comes_to_rest"]),
            _matrix_row(False, ["cop_in_support"]), {"t": 3.55, "options": {}, "success": False,
                                                     "error": "InfeasibleStop: no stop"}]
    row = bench.ablation_row({"controller": {"swing_tilt": None}}, rows, ["push left 17 N s", "mass x1.1"],
                             PHASE_TIMES)
    assert (row["passed"], row["runs"], row["falls"], row["errors"]) == (1, 4, 1, 1)
    assert [(f["cell"], f["phase"]) for f in row["failed"]] == [
        ("push left 17 N s", "double support"), ("mass x1.1", "early single support"), ("mass x1.1", "double support")]
    assert row["failed"][0]["result"] == "no_fall (tilt 0.40 rad), comes_to_rest (never)"
    assert row["failed"][1]["result"] == "cop_in_support (-1.2 mm)"
    assert row["failed"][2]["result"] == "InfeasibleStop: no stop"


def _ablation_data(bench, cells=None, phases=None):
    cells = cells or list(bench.MATRIX_CELLS)
    phases = phases or {name: 3.0 for name in bench.PHASES}
    runs = len(cells) * len(phases)
    fallen = [_matrix_row(False, ["no_fall"])] + [_matrix_row()] * (runs - 1)
    table = [bench.ablation_row({}, [_matrix_row()] * runs, cells, phases),
             bench.ablation_row({"controller": {"foot_compliance": None}}, fallen, cells, phases)]
    return {"rows": table, "cells": cells, "phases": phases, "runs": 2 * runs, "wall_s": 120.0, "workers": 2}


def test_the_ablation_section_is_one_table_row_per_change(bench):
    section = bench.ablation_section(_ablation_data(bench))
    lines = section.splitlines()
    assert lines[0] == bench.ABLATION_BEGIN and lines[-1] == bench.ABLATION_END
    assert "## Ablation: the perturbation matrix with one setting changed" in lines
    assert "88 runs on 2 workers in 2.0 min" in section and "Only part" not in section
    assert "| defaults | 44/44 | 0 | - |" in lines
    assert ("| `controller.foot_compliance: null` | 43/44 | 1 | push forward 17 N s, early single support: "
            "no_fall (tilt 0.40 rad) |") in lines
    part = bench.ablation_section(_ablation_data(bench, ["mass x1.1"], {"double support": 3.55}))
    assert "Only part of the matrix: mass x1.1 at double support." in part and "| defaults | 1/1 | 0 | - |" in part


MAIN = ("# Online stop controller: robustness (physics)\n\nMeasured by ...\n\n"
        "## Perturbation matrix\n\n44/44 cells pass.\n")


def test_a_main_run_keeps_the_ablation_section_and_rows(bench, tmp_path):
    out = tmp_path / "ROBUSTNESS.md"
    section = bench.ablation_section(_ablation_data(bench))
    bench.write_ablation(out, section, {"rows": ["ablation row"]})
    bench.write_main(out, MAIN, {"rows": ["main row"], "wall_s": 1.0})
    text = out.read_text()
    assert text.startswith(MAIN) and text.count(bench.ABLATION_BEGIN) == 1 and text.endswith(section)
    data = json.loads(out.with_suffix(".json").read_text())
    assert data == {"rows": ["main row"], "wall_s": 1.0, "ablation": {"rows": ["ablation row"]}}
    bench.write_main(out, MAIN.replace("44/44", "43/44"), {"rows": ["newer row"]})  # again: one section still
    assert out.read_text() == MAIN.replace("44/44", "43/44") + "\n" + section
    assert json.loads(out.with_suffix(".json").read_text())["ablation"] == {"rows": ["ablation row"]}


def test_an_ablation_run_keeps_the_main_report_and_replaces_its_own_section(bench, tmp_path):
    out = tmp_path / "ROBUSTNESS.md"
    bench.write_main(out, MAIN, {"rows": ["main row"]})
    bench.write_ablation(out, f"{bench.ABLATION_BEGIN}\nOLD SECTION\n{bench.ABLATION_END}\n", {})
    new = bench.ablation_section(_ablation_data(bench))
    bench.write_ablation(out, new, {"rows": ["ablation row"]})
    text = out.read_text()
    assert text == MAIN + "\n" + new and "OLD SECTION" not in text
    data = json.loads(out.with_suffix(".json").read_text())
    assert data == {"rows": ["main row"], "ablation": {"rows": ["ablation row"]}}


def test_a_main_run_without_an_ablation_writes_its_report_alone(bench, tmp_path):
    out = tmp_path / "ROBUSTNESS.md"
    bench.write_main(out, MAIN, {"rows": []})
    assert out.read_text() == MAIN and "ablation" not in json.loads(out.with_suffix(".json").read_text())


def test_the_ablation_command_runs_the_selection_and_writes_its_section(bench, tmp_path, monkeypatch, capsys):
    """``--ablation --cells --phases --changes`` with the runs faked: the jobs carry each row's settings,
    and the report gets the table (no physics)."""
    jobs = []

    class Pool:
        def __init__(self, workers):
            assert workers == 2

        def __enter__(self):
            return self

        def __exit__(self, *args):
            return False

        def map(self, function, items):
            jobs.extend(items)
            return [_matrix_row(success=not job[2]["controller"], failed=["cop_in_support"]) for job in items]

    monkeypatch.setattr(bench, "ProcessPoolExecutor", Pool)
    out = tmp_path / "ROBUSTNESS.md"
    out.write_text(MAIN)
    bench.main(["--ablation", "--out", str(out), "--cells", "push right 17 N s", "--cells", "mass x0.9",
                "--phases", "mid single support", "--changes", "defaults", "--changes", "controller.swing_tilt",
                "--changes", "plant.time_step"])
    assert [(job[1], job[2]["controller"], job[2]["time_step"]) for job in jobs] == [
        ({"push": (0.0, -170.0)}, {}, None), ({"mass_scale": 0.9}, {}, None),
        ({"push": (0.0, -170.0)}, {"swing_tilt": None}, None), ({"mass_scale": 0.9}, {"swing_tilt": None}, None),
        ({"push": (0.0, -170.0)}, {}, 0.002), ({"mass_scale": 0.9}, {}, 0.002)]
    text = out.read_text()
    assert text.startswith(MAIN)
    assert "| `controller.swing_tilt: null` | 0/2 | 0 | push right 17 N s, mid single support: cop_in_support" in text
    assert "| `plant.time_step: 0.002` | 2/2 | 0 | - |" in text
    assert [row["label"] for row in json.loads(out.with_suffix(".json").read_text())["ablation"]["rows"]] == [
        "defaults", "controller.swing_tilt: null", "plant.time_step: 0.002"]


@pytest.mark.parametrize("argv, named", [
    (["--cells", "mass x0.9"], "only with --ablation"),
    (["--ablation", "--controller-option", "swing_tilt=null"], "--controller-option"),
    (["--ablation", "--cells", "mass x2"], "--cells"),
    (["--controller-option", "swing_tlt=null"], "controller.swing_tlt is not a controller field"),
    (["--controller-option", "recovery_step=false"], "controller.recovery_step is now controller.planner."),
    (["--controller-option", "planner.max_replan_solves=0"], "max_replan_solves"),
    (["--controller-option", "kind=offline-filter"], "--controller-option"),
])
def test_bad_benchmark_options_exit_2_naming_them(bench, argv, named, capsys):
    with pytest.raises(SystemExit) as stop:
        bench.main(argv)
    assert stop.value.code == 2 and named in capsys.readouterr().err


def test_controller_options_are_read_as_yaml(bench):
    parser = bench._parser()
    assert bench._controller_options(parser, ["foot_compliance=null", "planner.max_replan_solves=null"]) == {
        "foot_compliance": None, "planner.max_replan_solves": None}
    assert bench.settings_notes(bench.settings(controller={"foot_compliance": None}, time_step=0.002)) == [
        "Controller settings changed from the defaults (the scenario's controller section): foot_compliance: null.",
        "Plant time step: 2 ms."]


def test_a_run_of_some_rows_completes_the_previous_table_in_the_ablations_order(bench):
    cells, phases = ["mass x1.1"], {"double support": 3.55}
    rows = {label: bench.ablation_row(change, [_matrix_row()], cells, phases)
            for label, change in (("defaults", {}), ("swing", {"controller": {"swing_tilt": None}}),
                                  ("plant", {"plant": {"time_step": 0.002}}))}
    previous = {"rows": [rows["defaults"], rows["plant"]], "cells": cells, "phases": phases, "runs": 2,
                "wall_s": 20.0, "workers": 2}
    new = {"rows": [rows["swing"]], "cells": cells, "phases": phases, "runs": 1, "wall_s": 7.0, "workers": 2}
    merged = bench.with_previous_rows(new, previous)
    assert [row["label"] for row in merged["rows"]] == ["defaults", "controller.swing_tilt: null",
                                                        "plant.time_step: 0.002"]
    assert merged["runs"] == 3 and merged["wall_s"] == pytest.approx(27.0)
    rerun = bench.with_previous_rows({**new, "rows": [dict(rows["plant"])]}, previous)  # a row run again replaces it
    assert [row["label"] for row in rerun["rows"]] == ["defaults", "plant.time_step: 0.002"]
    assert rerun["runs"] == 2 and rerun["wall_s"] == pytest.approx(7.0 + 10.0)
    assert bench.with_previous_rows(new, {**previous, "cells": ["mass x0.9"]}) is new  # another part: replaced
    assert bench.with_previous_rows(new, None) is new
