"""benchmarks/push_suite.py: which runs make the push suite (a fixed rule over the committed campaign) and how
a run's outcome becomes its verdict; one case run end to end is left to the benchmark (minutes)."""

import json
import shlex

from scripts import load_script


def _row(run, outcome="failure", no_fall=True, impulse=10.0, exit_phase=None):
    return {"run": run, "outcome": outcome, "success": outcome == "success", "no_fall": no_fall,
            "push_impulse": impulse, "cop_exit_phase": exit_phase,
            "command": f"drake-estop simulate --physics --estop-time 3.{run:03d}"}


def test_the_campaign_cases_follow_the_rule():
    """Every fourth fall by impulse, every eighth halt CoP exit and other upright failure, the five strongest
    stops; errors never."""
    suite = load_script("benchmarks/push_suite.py")
    rows = ([_row(k, no_fall=False, impulse=30.0 - k) for k in range(9)]
            + [_row(100 + k, exit_phase="halt") for k in range(9)]
            + [_row(200 + k, exit_phase="landing") for k in range(3)]
            + [_row(300 + k, outcome="success", impulse=float(k)) for k in range(7)] + [_row(400, outcome="error")])
    cases = suite.campaign_cases(rows)
    names = [(kind, name) for name, kind, _ in cases]
    assert names[:3] == [("fall", "campaign run 8"), ("fall", "campaign run 4"), ("fall", "campaign run 0")]
    assert [n for k, n in names if k == "halt CoP exit"] == ["campaign run 100", "campaign run 108"]
    assert [n for k, n in names if k == "upright failure"] == ["campaign run 200"]
    assert [n for k, n in names if k == "strong stop"] == [f"campaign run {k}" for k in (306, 305, 304, 303, 302)]
    assert cases[0][2] == ["simulate", "--physics", "--estop-time", "3.008"]  # the command less the program


def test_the_matrix_cases_and_the_verdicts():
    suite = load_script("benchmarks/push_suite.py")
    cases = suite.matrix_cases(2.85)
    assert len(cases) == 7
    name, _, argv = cases[0]
    assert name == "29 N s left, early single support"
    assert argv == ["simulate", "--physics", "--estop-time", "2.95", "--push", "2.95", "0.0", "290.0", "0.1"]
    assert suite.verdict({"outcome": "success", "success": True, "no_fall": True}) == "stop"
    assert suite.verdict({"outcome": "failure", "success": False, "no_fall": True}) == "upright"
    assert suite.verdict({"outcome": "failure", "success": False, "no_fall": False}) == "fall"
    assert suite.verdict({"outcome": "error", "success": False, "no_fall": None}) == "error"


def test_the_committed_result_is_the_suite_of_the_committed_campaign():
    """PUSH_SUITE.json holds one verdict for each case the rule picks today, with its command."""
    suite = load_script("benchmarks/push_suite.py")
    kept = json.loads(suite.RESULT.read_text())
    cases = suite.suite()
    assert [c["name"] for c in kept["cases"]] == [name for name, _, _ in cases]
    assert [shlex.split(c["command"])[1:] for c in kept["cases"]] == [argv for _, _, argv in cases]
    assert sum(kept["counts"].values()) == len(cases)


def test_a_controller_option_goes_into_every_command():
    suite = load_script("benchmarks/push_suite.py")
    cases = [("a", "fall", ["simulate", "--physics"])]
    assert suite.with_controller(cases, []) == cases
    options = ["planner.crossover_step=true", "planner.max_steps=2", "hip_strategy={}"]
    assert suite.with_controller(cases, options)[0][2] == [
        "simulate", "--physics", "--scenario-text",
        '{"controller": {"planner": {"crossover_step": true, "max_steps": 2}, "hip_strategy": {}}}']
