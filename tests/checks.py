"""Independent physics checks on logged trajectories (used by tests and benchmarks)."""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

from drake_estop.planning.geometry import SupportPolygon


def lipm_tracking_error(times, com, com_vel, zmp, w, window: float = 0.5) -> float:
    """Largest COG error of a numerical LIPM integration driven by the logged ZMP.

    ``x'' = w^2 (x - p(t))`` (eq. 4) is integrated with scipy's RK45 from the
    logged COG state at the start of each ``window`` (the LIPM is unstable, so
    one open-loop integration over seconds would amplify rounding by
    ``exp(w T)``), with the ZMP linearly interpolated between log samples, and
    compared with the logged COG. Independent of the analytic solution.
    """
    times = np.asarray(times, float)
    worst = 0.0
    starts = np.arange(times[0], times[-1], window)
    for start in starts:
        sel = (times >= start - 1e-12) & (times <= start + window + 1e-12)
        t = times[sel]
        if len(t) < 2:
            continue
        p = zmp[sel]
        sol = solve_ivp(lambda s, y, t=t, p=p: [y[1], w * w * (y[0] - np.interp(s, t, p))], (t[0], t[-1]),
                        [com[sel][0], com_vel[sel][0]], t_eval=t, rtol=1e-10, atol=1e-12,
                        max_step=t[1] - t[0])
        worst = max(worst, float(np.abs(sol.y[0] - com[sel]).max()))
    return worst


def plan_lipm_error(plan, *, after_halt: float, lead: float = 0.1) -> float:
    """Largest :func:`lipm_tracking_error` of a stop plan's rollout, over both horizontal axes, from
    ``lead`` seconds before its signal to ``after_halt`` seconds past its halt."""
    from drake_estop.planning.rollout import rollout

    data = rollout(plan, after_halt=after_halt)
    sel = data.times >= plan.signal_time - lead
    return max(lipm_tracking_error(data.times[sel], data.com[sel, axis], data.com_vel[sel, axis],
                                   data.zmp[sel, axis], plan.pattern.w) for axis in (0, 1))


def independent_polygon(plan, t) -> SupportPolygon:
    """The soles on the ground at ``t``, turned by their headings (not the planner's polygon)."""
    sole = plan.pattern.params.sole
    feet, yaw = plan.feet(t), plan.feet_yaw(t)[0]
    corners = []
    for side in plan.support_sides(t, feet):
        c, s = math.cos(yaw[side]), math.sin(yaw[side])
        local = sole.corners((0.0, 0.0), side)
        corners.append(feet[side][:2] + local @ np.array([[c, s], [-s, c]]))
    return SupportPolygon(np.vstack(corners))
