"""benchmarks/robustness.py: which runs it re-runs alone for their tick time, and how it reports them
(the runs themselves are physics, minutes: a benchmark)."""

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
