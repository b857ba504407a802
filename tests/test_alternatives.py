"""The comparison methods (issue: benchmarks against the alternatives), smoke-tested on a few instants."""


import alternatives
import numpy as np
import pytest
from scripts import load_script

from drake_estop.planning.planner import StopParameters, plan_stop


def _compare_module():
    return load_script("benchmarks/compare_methods.py")


def test_finish_the_step_keeps_the_nominal_footstep(pattern, params):
    plan = alternatives.finish_the_step(pattern, 3.0, params)
    step = pattern.steps[2]
    assert plan.start_time == pytest.approx(step["touchdown"])
    np.testing.assert_allclose(plan.final_feet[step["swing"]], step["end"])
    assert plan.steps_after_signal == 1
    assert np.linalg.norm(plan.com([plan.halt_end + 0.5])[1]) < 1e-6


def test_zmp_planner_baseline_reports_its_zmp(pattern, params):
    result = alternatives.zmp_planner_stop(pattern, 3.5, params)
    assert result.steps == 0
    # the actual ZMP of the LQR plan is x - x''/w^2, generally not the reference
    assert np.abs(result.zmp - result.zmp_reference).max() > 1e-3
    assert np.isfinite(result.min_zmp_margin)


def test_capture_point_bound(pattern, params):
    assert alternatives.one_step_capturable(pattern, 3.0, params)
    tight = StopParameters(max_step_length=0.05, max_swing_speed=0.3)
    assert not alternatives.one_step_capturable(pattern, 3.4, tight)


def test_compare_script_on_a_few_instants(pattern, params, tmp_path):
    module = _compare_module()
    rows, summaries = module.main(["--every", "40", "--scipy-every", "2", "--no-diagrams", "--out", str(tmp_path)])
    assert len(rows) == 4
    assert set(summaries) == {"planner", "planner_eq20", "planner_toe", "planner_time", "finish_step",
                              "zmp_planner", "zmp_planner_tuned"}
    text = (tmp_path / "RESULTS.md").read_text()
    assert "this planner" in text and "capture-point bound" in text
    assert "| paper objective, slowdown ZMP at the landing ankle (eq. 20) | 4/4 (0) | yes |" in text
    assert 'objective="time"' in text and "ZmpPlanner, stop at next footstep, tuned" in text
    assert (tmp_path / "compare_methods.png").stat().st_size > 1000


def test_landing_zmp_offset_moves_the_slowdown_zmp_into_the_fore_sole(pattern):
    offset = 0.08
    plan = plan_stop(pattern, 3.0, StopParameters(landing_zmp_offset=offset))
    zmp = plan.com([plan.slowdown_end - 0.01])[3][0, 0]
    assert zmp == pytest.approx(plan.landing_position[0] + offset, abs=1e-9)
    with pytest.raises(ValueError, match="landing_zmp_offset"):
        plan_stop(pattern, 3.0, StopParameters(landing_zmp_offset=0.5))
