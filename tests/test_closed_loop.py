"""The paper's two stops on the closed-loop physics diagram (everything online in the Simulator).

What runs here is the DCM feedback COMBINED WITH the OFFLINE ZmpPreviewFilter
COG feedforward (``run_closed_loop(use_preview_filter=True)``). The feedback
alone (``use_preview_filter=False``) does not pass these scenarios: the robot
falls in both (see drake_estop.physics.stabilizer, gain choice), so there is no test
for it.
"""

import numpy as np
import pytest

from drake_estop.physics.plant import CRITERIA, PhysicsParameters, run_closed_loop
from drake_estop.planning.gait import GaitParameters, NominalPattern
from drake_estop.planning.planner import StopParameters

SCENARIOS = (3.4, 3.5)


@pytest.fixture(scope="module")
def closed_loop_runs():
    pattern = NominalPattern(GaitParameters())
    return {t: run_closed_loop(GaitParameters(), StopParameters(), t, pattern=pattern, use_preview_filter=True)
            for t in SCENARIOS}


@pytest.mark.parametrize("estop_time", SCENARIOS)
@pytest.mark.parametrize("criterion", CRITERIA)
def test_closed_loop_scenario_meets_criterion(closed_loop_runs, estop_time, criterion):
    result = closed_loop_runs[estop_time]
    assert result.criteria[criterion], (criterion, result.numbers())


@pytest.mark.parametrize("estop_time", SCENARIOS)
def test_closed_loop_scenario_numbers(closed_loop_runs, estop_time):
    result = closed_loop_runs[estop_time]
    numbers = result.numbers()
    params = PhysicsParameters()
    assert set(result.criteria) == set(CRITERIA) and result.success
    assert numbers["pelvis_z_min_m"] > params.pelvis_height_bounds[0]
    assert numbers["pelvis_z_max_m"] < params.pelvis_height_bounds[1]
    assert numbers["torso_tilt_max_rad"] < params.max_torso_tilt
    assert max(result.slip.values()) < params.max_slip
    assert numbers["rest_after_halt_s"] <= params.rest_within
    assert numbers["final_cog_offset_m"] <= params.rest_offset
    assert numbers["cop_margin_plan_min_m"] >= 0.0
    assert np.allclose(np.diff(result.times), 0.005)
    assert result.times[-1] >= result.plan.halt_end + 2.5 - 0.005 - 1e-9
    # the plan was made inside the Simulator at the signal's servo tick
    assert result.plan.signal_time == pytest.approx(estop_time)
    # the online IK met its tolerances and the stabiliser acted (non-zero COG correction)
    assert result.ik_failures == 0
    offset = result.closed_loop["com_offset"]
    assert np.max(np.abs(offset)) > 1e-3
    assert np.max(np.abs(offset)) < 0.08  # never on the safety clamp
    assert result.normal_force[-1] == pytest.approx(58.0 * 9.81, rel=0.01)
