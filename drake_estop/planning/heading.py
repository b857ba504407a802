"""Stops of turning and side-stepping walks: the planner works in the fore foot's heading frame.

The paper's planner (III.A-B) is written for a straight walk: the sagittal plane runs
along the soles and the lateral plane across them, and the stop's ZMP limits are the
fore sole's toe, heel and edges. On a turning walk the feet point in different
directions. The LIPM (eq. 4) is linear and the same in every horizontal direction, so
the planner solves the stop in axes turned to the heading of the foot that carries the
stop (the landing foot in single support, the fore foot in double support). There that
sole is axis-aligned and the paper's limits are exact; the other sole is turned by the
step's heading change and enters the plan only through the support polygon, which is
always the true polygon of the turned soles (:func:`~drake_estop.planning.plan.soles_polygon`),
for the halt and for the planner's tick-by-tick ZMP check. The plan is then turned back:
the COG and ZMP chains with :meth:`~drake_estop.planning.lipm.LipmTrajectory.rotated`, the feet as points.

A straight walk has heading 0: the frame is the world's and nothing is turned, so its
plans are the paper planner's to the last bit.
"""

from __future__ import annotations

import functools
from dataclasses import replace

import numpy as np

from drake_estop.planning.gait import NominalPattern, PatternState, rotation
from drake_estop.planning.lipm import LipmTrajectory


def stop_heading(state: PatternState) -> float:
    """Heading [rad] of the foot that carries the stop: the nominal landing's (single support)
    or the fore foot's (double support: the foot the ZMP moves to)."""
    if state.support == "single":
        return float(state.next_landing_yaw)
    rear = state.rear_foot or "right"
    fore = "left" if rear == "right" else "right"
    return float(state.feet_yaw[fore])


class HeadingFrame:
    """Axes turned by ``yaw`` [rad] about the vertical through the world origin."""

    def __init__(self, yaw: float):
        self.yaw = float(yaw)
        self._to_world = rotation(self.yaw)

    def local(self, xy) -> np.ndarray:
        """World (x, y[, z]) -> local; a third entry (height, lift) is kept."""
        xy = np.asarray(xy, float)
        out = xy.copy()
        out[..., :2] = xy[..., :2] @ self._to_world  # R^T v, row-wise
        return out

    def world(self, xy) -> np.ndarray:
        """Local (x, y[, z]) -> world."""
        xy = np.asarray(xy, float)
        out = xy.copy()
        out[..., :2] = xy[..., :2] @ self._to_world.T
        return out

    def state(self, state: PatternState) -> PatternState:
        """``state`` seen in this frame."""
        def feet(values):
            return {side: self.local(value) for side, value in values.items()}

        return replace(
            state, com=self.local(state.com), com_vel=self.local(state.com_vel), zmp=self.local(state.zmp),
            zmp_rate=self.local(state.zmp_rate), zmp_accel=self.local(state.zmp_accel),
            feet=feet(state.feet), feet_vel=feet(state.feet_vel), feet_acc=feet(state.feet_acc),
            next_landing=None if state.next_landing is None else self.local(state.next_landing),
            feet_yaw={side: yaw - self.yaw for side, yaw in state.feet_yaw.items()},
            next_landing_yaw=state.next_landing_yaw - self.yaw)


class FramedPattern:
    """A :class:`~drake_estop.planning.gait.NominalPattern` seen in a :class:`HeadingFrame`: the
    queries the planner makes (``com``, ``steps``, ``touchdown_com_offset``, ``state``, ``feet_at``,
    ``feet_yaw_at``) in local axes; times, parameters and everything else are the pattern's own."""

    def __init__(self, pattern: NominalPattern, frame: HeadingFrame):
        self._pattern = pattern
        self._frame = frame

    def __getattr__(self, name):
        return getattr(self._pattern, name)

    @functools.cached_property
    def steps(self):
        local = self._frame.local
        return [{**step, "start": local(step["start"]), "end": local(step["end"]),
                 "start_yaw": step["start_yaw"] - self._frame.yaw, "end_yaw": step["end_yaw"] - self._frame.yaw}
                for step in self._pattern.steps]

    def com(self, times):
        return tuple(self._frame.local(value) for value in self._pattern.com(times))

    def touchdown_com_offset(self, step_index):
        return self._frame.local(self._pattern.touchdown_com_offset(step_index))  # a vector: turned only

    def state(self, t):
        return self._frame.state(self._pattern.state(t))

    def feet_at(self, t):
        return tuple({side: self._frame.local(v) for side, v in values.items()}
                     for values in self._pattern.feet_at(t))

    def feet_yaw_at(self, t):
        yaw, rate = self._pattern.feet_yaw_at(t)
        return {side: value - self._frame.yaw for side, value in yaw.items()}, rate


def solve_turned(plan_local, pattern: NominalPattern, state: PatternState):
    """Run ``plan_local(pattern_view, state_view)`` in the stop's heading frame and return its plan
    in world axes. With heading 0 the planner runs on the world's pattern and state unchanged."""
    yaw = stop_heading(state)
    if yaw == 0.0:
        return plan_local(pattern, state)
    frame = HeadingFrame(yaw)
    plan = plan_local(FramedPattern(pattern, frame), frame.state(state))
    return to_world(plan, frame, pattern, state)


def to_world(plan, frame: HeadingFrame, pattern: NominalPattern, state: PatternState):
    """A plan solved in ``frame`` (from the local view of ``state``), in world axes."""
    x, y = (None, None) if plan.x is None else LipmTrajectory.rotated(plan.x, plan.y, frame.yaw)
    world = replace(
        plan, x=x, y=y, pattern=pattern, start_state=state, heading=frame.yaw,
        final_feet={side: frame.world(xy) for side, xy in plan.final_feet.items()},
        final_yaw={side: yaw + frame.yaw for side, yaw in plan.final_yaw.items()},
        landing_position=None if plan.landing_position is None else frame.world(plan.landing_position))
    if plan.landing_foot is not None:
        side = plan.landing_foot
        world.swing_start = {"pos": state.feet[side], "vel": state.feet_vel[side], "acc": state.feet_acc[side]}
    return world

