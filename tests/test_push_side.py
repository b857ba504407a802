"""How a campaign run's push meets the walk (campaign/report.py: push_side), and the report's table of it."""

import math

import numpy as np
import pytest
from campaign_helpers import fake_run

from drake_estop.campaign.config import default_config, run_seed, sample_run
from drake_estop.campaign.report import PUSH_SIDES, _columns, push_side, push_side_counts, push_sides, write_report
from drake_estop.campaign.runner import guarded_run
from drake_estop.campaign.storage import ResultStore
from drake_estop.planning.gait import NominalPattern
from drake_estop.robots import gait_parameters
from drake_estop.robots.parameters import as_robot

EARLY_SINGLE = 2.95  # the default walk: the left foot stands alone, the right swings
DOUBLE = 3.55  # both feet down (the right foot has just landed)


@pytest.fixture(scope="module")
def pattern():
    return NominalPattern(gait_parameters(as_robot(None)))


def test_the_walk_is_as_the_cases_below_take_it(pattern):
    assert pattern.support_at(EARLY_SINGLE)[0::2] == ("single", "left")
    assert pattern.support_at(DOUBLE)[0] == "double"


@pytest.mark.parametrize(("force", "side"), [
    ((0.0, 290.0), "towards the stance foot"),  # left, onto the left foot standing alone
    ((0.0, -290.0), "towards the swing foot"),
    ((290.0, 0.0), "sagittal"), ((-290.0, 0.0), "sagittal"),
    ((290.0, 200.0), "sagittal"),  # 35 deg off the walking axis
    ((200.0, 290.0), "towards the stance foot"),  # 55 deg
    ((-200.0, -290.0), "towards the swing foot"),
    ((0.0, 0.0), "no push"), ((math.nan, 10.0), "no push"),
])
def test_a_push_in_single_support_is_told_by_its_side(pattern, force, side):
    assert push_side(pattern, EARLY_SINGLE, *force) == side


def test_with_both_feet_down_the_side_does_not_count(pattern):
    for force in ((0.0, 290.0), (0.0, -290.0), (290.0, 0.0)):
        assert push_side(pattern, DOUBLE, *force) == "both feet down"
    assert push_side(pattern, 0.0, 0.0, 100.0) == "both feet down"  # standing before the walk


def test_each_run_is_told_on_its_own_walk():
    # one walk slower than the default: at 2.95 s it still has both feet down (its step time 1.2 s)
    data = {"step_length": np.array([0.3, 0.3, 0.3]), "step_time": np.array([0.8, 1.2, 0.8]),
            "step_width": np.array([0.19, 0.19, 0.19]), "push_time": np.array([EARLY_SINGLE, EARLY_SINGLE, math.nan]),
            "push_fx": np.array([0.0, 0.0, 0.0]), "push_fy": np.array([290.0, 290.0, 0.0])}
    slow = NominalPattern(gait_parameters(as_robot(None), step_time=1.2))
    assert push_sides(data).tolist() == ["towards the stance foot",
                                         push_side(slow, EARLY_SINGLE, 0.0, 290.0), "no push"]
    assert push_sides(data)[1] != "towards the stance foot"


def test_the_report_tables_runs_successes_and_falls_by_side(tmp_path):
    store = ResultStore(tmp_path / "c")
    store.parts.mkdir(parents=True)
    pushes = [(EARLY_SINGLE, 0.0, 290.0, True, True), (EARLY_SINGLE, 0.0, 290.0, False, False),
              (EARLY_SINGLE, 0.0, 250.0, False, True), (EARLY_SINGLE, 0.0, -290.0, True, True),
              (DOUBLE, 290.0, 0.0, False, False)]
    for i, (onset, fx, fy, success, upright) in enumerate(pushes):
        row = guarded_run((fake_run, sample_run(default_config(), run_seed(5, i), i), 1.0))
        store.write({**row, "error": None, "outcome": "success" if success else "failure", "success": success,
                     "no_fall": upright, "step_length": 0.3, "step_time": 0.8, "step_width": 0.19,
                     "push_time": onset, "push_fx": fx, "push_fy": fy})
    table = store.read()
    counts = push_side_counts(_columns(table))
    assert counts == {"towards the stance foot": {"runs": 3, "success": 1, "falls": 1},
                      "towards the swing foot": {"runs": 1, "success": 1, "falls": 0},
                      "both feet down": {"runs": 1, "success": 0, "falls": 1}}
    assert list(counts) == [side for side in PUSH_SIDES if side in counts]  # the report's order
    text = write_report(table, store.folder, manifest={"seed": 5, "config": {}, "sessions": []}).read_text()
    section = text.split("Where the push came from")[1].split("<h2>")[0]
    assert "<tr><td>towards the stance foot</td><td>3</td><td>1 (33 %)</td><td>1</td></tr>" in section
    assert "<tr><td>both feet down</td><td>1</td><td>0 (0 %)</td><td>1</td></tr>" in section
    assert "sagittal" not in section.split("<table>")[1]  # no sagittal run: no row
