"""The ZMP margin of a plan: its smallest distance to the support polygon over every servo tick of the
stop, against the support sole before the landing and both soles after it."""

from __future__ import annotations

import numpy as np

from drake_estop.planning import lipm
from drake_estop.planning.geometry import SupportPolygon
from drake_estop.planning.plan import StopPlan, soles_polygon


def verify_zmp(plan: StopPlan, final_polygon: SupportPolygon | None = None) -> float:
    """Smallest ZMP margin to the support polygon over every servo tick of the stop.

    ``final_polygon``: the polygon of both feet at their final positions, if the
    caller has it (else built by :meth:`StopPlan.polygon`).
    """
    dt = plan.params.servo_period
    ticks = plan.start_time + dt * np.arange(int(round((plan.halt_end - plan.start_time) / dt)) + 1)
    zmp = np.stack([_zmp_at(plan.x, ticks), _zmp_at(plan.y, ticks)], axis=1)  # ticks >= start: no nominal part
    worst = np.inf
    split = int(np.searchsorted(ticks, plan.landing_time, side="left"))  # ticks before the landing
    if split > 0:
        worst = min(worst, float(start_polygon(plan).margin(zmp[:split]).min()))
    if split < len(ticks):
        polygon = final_polygon if final_polygon is not None else plan.polygon(plan.halt_end)
        worst = min(worst, float(polygon.margin(zmp[split:]).min()))
    return worst


def start_polygon(plan: StopPlan) -> SupportPolygon:
    """:meth:`StopPlan.polygon` at the plan start: before the landing only the support sole."""
    if plan.landing_foot is None:
        return plan.polygon(plan.start_time)
    side = next(s for s in plan.final_feet if s != plan.landing_foot)
    xy = plan.final_feet[side]
    return soles_polygon(plan.pattern.params.sole, ((side, float(xy[0]), float(xy[1]), plan.final_yaw[side]),))


def _zmp_at(traj: lipm.LipmTrajectory, times: np.ndarray) -> np.ndarray:
    """ZMP of a trajectory at sorted times (the ZMP part of :meth:`LipmTrajectory.evaluate`)."""
    k = np.clip(np.searchsorted(traj.breaks, times, side="right") - 1, 0, len(traj.zmp) - 1)
    tau = times - traj.breaks[k]
    coeffs = traj.zmp[k]
    value = coeffs[:, -1].copy()
    for i in range(lipm.N_COEFFS - 2, -1, -1):  # Horner, vectorised over the ticks
        value *= tau
        value += coeffs[:, i]
    return value
