"""The whole body's ZMP of a joint trajectory, and its margin in the soles on the floor.

The pattern and the stop plan are made on the linear inverted pendulum (the paper's eq. 4): the body is
a point mass at the COG height and its ZMP is the plan's. The robot's limbs move besides, and their
angular momentum about the COG shifts the ZMP the floor must carry. On the default humanoid's walk that is
a few mm; where a double-support stop brakes at 3 m/s^2, or where the legs weigh 43 % of the robot (the G1)
and swing a 0.27 m step in 0.63 s, it is several cm and can leave the sole. This module measures it on
the IK's joint trajectory (the kinematic diagram's ``q``), before any physics: the floor's ZMP of a rigid
multibody on flat ground at height 0 is::

    p_x = c_x - (c_z m a_x + dL_y/dt) / (m (g + a_z))
    p_y = c_y - (c_z m a_y - dL_x/dt) / (m (g + a_z))

with ``c`` the COG, ``a`` its acceleration and ``L`` the angular momentum about it
(``MultibodyPlant.CalcSpatialMomentumInWorldAboutPoint``), velocities by central differences of the
configurations and the rates averaged over ``AVERAGING_WINDOW``. With ``L`` constant this is the LIPM's
ZMP.
"""

from __future__ import annotations

import numpy as np

from drake_estop.planning.plan import soles_polygon
from drake_estop.systems.ik import quaternion_to_matrix, yaw_of
from drake_estop.systems.reference import SWING_HEIGHT

#: The window [s] the COG's acceleration and the momentum's rate are averaged over: a swing foot braking to
#: its touchdown within a few ticks swings the instantaneous ZMP by decimetres, but the body cannot tip
#: on a moment that lasts 20 ms (the averaged ZMP is where the floor carries the window's moment).
AVERAGING_WINDOW = 0.05


def multibody_zmp(plant, q: np.ndarray, dt: float, window: float = AVERAGING_WINDOW, *, com=None) -> np.ndarray:
    """(n, 2) ZMP [m] of ``plant`` moving through the configurations ``q`` (n, nq), one every ``dt`` [s]
    (n >= 3), its rates averaged over ``window`` [s] (one tick each side at least); the module docstring
    gives the formula. ``com`` (n, 3): the plant's COG at each ``q`` [m] where the caller has it already
    (computed here otherwise)."""
    q = np.asarray(q, float)
    if q.ndim != 2 or q.shape[0] < 3 or q.shape[1] != plant.num_positions():
        raise ValueError(f"q must be (n >= 3, {plant.num_positions()}) configurations, got shape {q.shape}")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be positive, got {dt!r}")
    if not (np.isfinite(window) and window >= 0):
        raise ValueError(f"window must be finite and non-negative, got {window!r}")
    context = plant.CreateDefaultContext()
    mass = plant.CalcTotalMass(context)
    gravity = -float(plant.gravity_field().gravity_vector()[2])  # the plant's own (the LIPM's, robots/plant.py)
    if com is not None and np.shape(com) != (len(q), 3):
        raise ValueError(f"com must be ({len(q)}, 3), got shape {np.shape(com)}")
    qdot = np.gradient(q, dt, axis=0)
    given = com is not None
    com = np.asarray(com, float) if given else np.empty((len(q), 3))
    momentum = np.empty((len(q), 3))
    for i in range(len(q)):
        plant.SetPositions(context, q[i])
        plant.SetVelocities(context, plant.MapQDotToVelocity(context, qdot[i]))
        if not given:
            com[i] = plant.CalcCenterOfMassPositionInWorld(context)
        momentum[i] = plant.CalcSpatialMomentumInWorldAboutPoint(context, com[i]).rotational()
    span = max(1, int(round(window / (2.0 * dt))))
    acceleration = _rate(np.gradient(com, dt, axis=0), dt, span)
    momentum_rate = _rate(momentum, dt, span)
    vertical = mass * (gravity + acceleration[:, 2])
    zmp_x = com[:, 0] - (com[:, 2] * mass * acceleration[:, 0] + momentum_rate[:, 1]) / vertical
    zmp_y = com[:, 1] - (com[:, 2] * mass * acceleration[:, 1] - momentum_rate[:, 0]) / vertical
    return np.stack([zmp_x, zmp_y], axis=1)


def support_margins(zmp: np.ndarray, feet: dict, sole) -> np.ndarray:
    """(n,) distance [m] of each ``zmp`` (n, 2) inside the polygon of the soles on the floor at that tick
    (negative outside; NaN where no sole target is on the floor). ``feet``: side -> (n, 7) sole targets
    ``[x, y, z, qw, qx, qy, qz]``; ``sole``: the rectangle (:class:`drake_estop.planning.gait.Sole`)."""
    margins = np.full(len(zmp), np.nan)
    for i, point in enumerate(np.asarray(zmp, float)):
        standing = tuple((side, float(target[i][0]), float(target[i][1]), yaw_of(quaternion_to_matrix(target[i][3:7])))
                         for side, target in feet.items() if target[i][2] <= SWING_HEIGHT)
        if standing:
            margins[i] = float(soles_polygon(sole, standing).margin(point[None, :])[0])
    return margins


def _rate(values: np.ndarray, dt: float, span: int) -> np.ndarray:
    """The rate of ``values`` (n, k) over ``2 span`` ticks centred on each (fewer at the ends): its mean
    over that window."""
    index = np.arange(len(values))
    ahead, behind = np.minimum(index + span, len(values) - 1), np.maximum(index - span, 0)
    return (values[ahead] - values[behind]) / (dt * (ahead - behind))[:, None]
