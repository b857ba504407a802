"""The halt (eq. 27-28): the shortest candidate whose ZMP keeps the margin, found the same way whether the
candidates are solved one at a time or together."""

import numpy as np
import pytest

from drake_estop.planning import halt, lipm
from drake_estop.planning.gait import NominalPattern
from drake_estop.planning.plan import soles_polygon
from drake_estop.planning.planner import StopParameters, plan_stop
from drake_estop.planning.rollout import stride_ticks


def _one_by_one(ends, midpoint, polygon, params, w):
    """The halt by its definition: every candidate in order, solved alone (:func:`halt.halt_axis`)."""
    best = None
    for shift, settle in halt.halt_candidates(params):
        axes = [halt.halt_axis(x3, v3, zmp3, midpoint[a], shift, settle, w) for a, (x3, v3, zmp3) in enumerate(ends)]
        margin = float(polygon.margin(np.stack([axes[0][1], axes[1][1]], axis=1)).min())
        if best is None or margin > best[2]:
            best = ([shift, settle], [axis[0] for axis in axes], margin)
        if margin >= params.zmp_margin:
            break
    return best


@pytest.mark.parametrize("offset", [0.0, 0.05, 0.10, 0.16])
def test_batched_candidates_choose_the_halt_that_one_by_one_does(offset):
    """Slowdown ends of the default stride's stops, pushed ``offset`` [m] further ahead so that long halts
    (solved together) are needed too: the same durations, coefficients and margin as solving every
    candidate alone in order."""
    pattern = NominalPattern()
    params = StopParameters()
    sole, w = pattern.params.sole, pattern.w
    chosen = set()
    for t in stride_ticks(pattern, params)[::8]:
        plan = plan_stop(pattern, t, params)
        feet = plan.final_feet
        polygon = soles_polygon(sole, tuple((s, float(feet[s][0]), float(feet[s][1]), 0.0) for s in ("left", "right")))
        pos, vel, _, zmp = plan.com([plan.slowdown_end])
        ends = [(pos[0, a] + (offset if a == 0 else 0.0), vel[0, a], zmp[0, a]) for a in (0, 1)]
        midpoint = 0.5 * (feet["left"] + feet["right"])
        durations, coeffs, margin = halt.choose_halt(ends, midpoint, polygon, params, w)
        expected = _one_by_one(ends, midpoint, polygon, params, w)
        assert durations == pytest.approx(expected[0]) and margin == pytest.approx(expected[2], abs=1e-8)
        for axis, mix in zip(coeffs, expected[1]):  # the same ZMP to 1e-6 mm (a long settle's solve is
            # ill-conditioned: batched and alone differed by 3.4e-7 mm on one machine)
            for segment, alone, duration in zip(axis, halt.halt_coeffs(mix, *durations, w), durations):
                tau = np.linspace(0.0, duration, 21)
                np.testing.assert_allclose(lipm.poly_eval(segment, tau), lipm.poly_eval(alone, tau), atol=1e-9)
        chosen.add(halt.halt_candidates(params).index(tuple(durations)))
    if offset >= 0.1:  # the batch is what chooses here
        assert max(chosen) >= halt.HALT_ONE_BY_ONE
