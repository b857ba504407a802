"""benchmarks/floor_drop.py: the patch under the planned landing point, the verdicts and the table (the runs
themselves are the benchmark's, minutes)."""

import pytest
from scripts import load_script


def test_the_drop_lies_under_the_planned_landing_point():
    bench = load_script("benchmarks/floor_drop.py")
    drop, plan = bench.drop_under_landing(3.4, 0.01)
    assert drop.depth == 0.01 and drop.contains(plan.landing_position)
    stance = "left" if plan.landing_foot == "right" else "right"
    assert not drop.contains(plan.feet(3.4)[stance][:2])  # the stance foot on the plan's floor


def test_verdicts_cells_and_the_table():
    bench = load_script("benchmarks/floor_drop.py")
    good = {"no_fall": True, "cop_in_support": True}
    assert bench.verdict(good) == "stop"
    assert bench.verdict({**good, "cop_in_support": False}) == "upright"
    assert bench.verdict({**good, "no_fall": False}) == "fall"
    rows = [{"signal": s, "depth": d, "column": c, "verdict": "upright", "failed": ["cop_in_support"],
             "late_ms": 95.0} for s in bench.SIGNALS for d in bench.DEPTHS for c in bench.CONTROLLERS]
    rows[0] = {**rows[0], "verdict": "fall", "failed": ["no_fall"], "late_ms": None}
    assert bench.cell(rows[0]) == "fall"
    assert bench.cell(rows[1]) == "upright (cop_in_support), loaded +95 ms"
    text = bench.report(rows, 120.0, 2)
    assert text.count("## Signal at") == len(bench.SIGNALS) and "in 2.0 min on 2 workers" in text
    assert text.count("| 10 |") == len(bench.SIGNALS)  # one row per depth [mm]


@pytest.mark.parametrize("column", ["touchdown off", "default", "late landing on"])
def test_each_column_is_a_valid_controller(column):
    from drake_estop.physics.controller_options import ControllerOptions

    bench = load_script("benchmarks/floor_drop.py")
    options = ControllerOptions().with_changes(bench.CONTROLLERS[column])
    assert (options.touchdown is None) == (column == "touchdown off")
    assert options.planner.late_landing == (column == "late landing on")
