"""Numeric rules of the stop planner system, apart from its Drake plumbing.

* :func:`nominal_stop_table` and :func:`nominal_one_step_table`: the stop of a
  signal at every servo tick of the nominal walk (the signal's own support
  phase) and its one-step feasibility, computed before the run.
* :func:`dcm_distance` / :func:`dcm_deviation`: how far a measured DCM
  ``x + v / omega`` lies from a reference's; :class:`PatternCom`, the walk's
  COG looked up on its servo ticks.
* :func:`off_foothold` and :func:`next_sole_stage`: where a measured sole
  stands against the plan's foothold, and the stages a sole goes through
  in the stop (the re-landing rule of
  :class:`drake_estop.systems.stop_controller.StopPlannerSystem`).
"""

from __future__ import annotations

import copy
import functools
import math

import numpy as np

from drake_estop.planning.gait import SIDES, NominalPattern
from drake_estop.planning.plan import snap_to_tick
from drake_estop.planning.planner import StopParameters, first_stop

#: Stages of a sole in the stop (:func:`next_sole_stage`): where the plan has it in the air; standing
#: (loaded ``foothold_ticks`` ticks where the plan has it down); lifted off the floor (unloaded) while the
#: plan still has it down; landed again off the plan's foothold, until a re-plan stands on it.
SOLE_AWAY, SOLE_STANDING, SOLE_LIFTED, SOLE_RELANDED = 0.0, 1.0, 2.0, 3.0


def nominal_stop_table(pattern: NominalPattern, params: StopParameters) -> tuple:
    """The stop of a signal at every servo tick ``k`` from 0 to the end of the walk, planned from the
    nominal walk in the signal's own support phase (III.A or III.B): ``plan_stop(pattern, k *
    servo_period, params)`` where that phase has a stop, None where the search would go on to a later
    phase (III.C). Computed before the run: without a measured state the stop depends on the tick alone.

    Cached per (gait, stop parameters) in the process for a :class:`NominalPattern` without a COG
    correction (then a function of its parameters alone); about 1.3 s and 35 MB for the default 8.5 s
    walk. The plans are shared: copy one before changing it (:func:`nominal_stop`).
    """
    if _cacheable(pattern):
        return _cached_stops(pattern.params, params)
    return _stops(pattern, params)


def tick_entry(table, t: float, servo_period: float):
    """``table``'s entry (a per-tick table from tick 0) for the servo tick at or after ``t`` [s], None
    outside it."""
    k = int(round(snap_to_tick(t, servo_period) / servo_period))
    return table[k] if 0 <= k < len(table) else None


def nominal_stop(table: tuple, t: float, servo_period: float):
    """A copy of ``table``'s stop (:func:`nominal_stop_table`) for a signal at ``t`` [s] (snapped to the
    next servo tick), or None where it has none (``t`` outside the walk, or a later phase's stop)."""
    plan = tick_entry(table, t, servo_period)
    return None if plan is None else copy.copy(plan)


def nominal_one_step_table(pattern: NominalPattern, params: StopParameters) -> np.ndarray:
    """``one_step_feasible(pattern, k * servo_period, params)`` for every servo tick ``k`` from 0 to
    the end of the walk (bool array): the nominal walk's answer, computed before the run with the stops
    of :func:`nominal_stop_table` (the stop-planner system looks it up instead of solving on the tick)."""
    return one_step_column(nominal_stop_table(pattern, params))


def _cacheable(pattern) -> bool:
    """Whether ``pattern``'s walk is a function of its gait parameters alone: a plain
    :class:`NominalPattern` (a whole-body corrected walk has the same parameters and another COG)."""
    return type(pattern) is NominalPattern and pattern.com_correction is None


@functools.lru_cache(maxsize=4)
def _cached_stops(gait_params, params):
    return _stops(NominalPattern(gait_params), params)


def _stops(pattern, params):
    dt = params.servo_period
    ticks = math.ceil(pattern.end_time / dt - 1e-9) + 1  # past the end: "standing"
    return tuple(first_stop(pattern, k * dt, params) for k in range(ticks))


def one_step_column(stops) -> np.ndarray:
    """Whether each stop of a :func:`nominal_stop_table` is one-step (bool array; False where it has none)."""
    return np.array([plan is not None and plan.case == "one-step" for plan in stops], dtype=bool)


def dcm_distance(measured, pos, vel, omega: float) -> float:
    """Distance [m] between the measured DCM ``x + v / omega`` (``measured = (com_xy, com_vel_xy)``) and the
    DCM of COG position ``pos`` and velocity ``vel`` (x, y)."""
    return float(np.linalg.norm((measured[0] + measured[1] / omega) - (pos + vel / omega)))


def dcm_deviation(reference, t, measured) -> float:
    """Distance [m] between the measured DCM ``x + v / omega`` and ``reference``'s at ``t`` (a pattern or a
    plan)."""
    pos, vel, _, _ = reference.com([t])
    omega = reference.pattern.w if hasattr(reference, "pattern") else reference.w
    return dcm_distance(measured, pos[0], vel[0], omega)


class PatternCom:
    """The pattern's COG (x, y) position [m] and velocity [m/s] at every servo tick of the walk, computed
    once (the array path gives the bits of the one-instant one): for the tracking bias and the deviation
    that every tick before the latch measures against it."""

    def __init__(self, pattern: NominalPattern, servo_period: float):
        self._pattern, self._dt = pattern, servo_period
        ticks = np.arange(int(math.ceil(pattern.end_time / servo_period)) + 1) * servo_period
        self._positions, self._velocities = pattern.com(ticks)[:2]

    def at(self, t: float):
        """The pattern's COG (x, y) position and velocity at ``t`` [m, m/s]: looked up on a servo tick of the
        walk, else evaluated (the same bits either way)."""
        k = int(round(t / self._dt))
        if 0 <= k < len(self._positions) and k * self._dt == t:
            return self._positions[k], self._velocities[k]
        pos, vel, _, _ = self._pattern.com([t])
        return pos[0], vel[0]

    def deviation(self, t: float, measured) -> float:
        """:func:`dcm_distance` of ``measured`` from the pattern at ``t``, its COG looked up."""
        return dcm_distance(measured, *self.at(t), self._pattern.w)


def off_foothold(xy, planned, tolerance: float) -> bool:
    """Whether the measured sole ``xy`` lies more than ``tolerance`` [m] from the plan's ``planned`` (x, y first)."""
    return bool(np.hypot(xy[0] - planned[0], xy[1] - planned[1]) > tolerance)


def foothold_loaded(feet, side: str, foothold_ticks: int) -> bool:
    """Whether ``side``'s sole of the estimated ``feet`` (``[x_l, y_l, x_r, y_r, ticks_l, ticks_r]``) has been
    loaded ``foothold_ticks`` ticks: where it stands is a foothold (one in the air, or just down, is not yet)."""
    return bool(feet[4 + SIDES.index(side)] >= foothold_ticks)


def next_sole_stage(stage: float, *, airborne: bool, loaded: bool, unloaded: bool, off: bool) -> float:
    """A sole's stage (``SOLE_*``) after one tick.

    ``airborne``: the plan has the sole in the air; ``loaded``: it has been
    loaded ``foothold_ticks`` ticks; ``unloaded``: it bears no load this
    tick; ``off``: it lies more than the tolerance from the plan's foothold
    (:func:`off_foothold`). A standing sole that lifts off the floor and is
    loaded again off its foothold has re-landed (the move from
    ``SOLE_LIFTED`` to ``SOLE_RELANDED``); a re-landed sole is standing
    again once a plan stands on it.
    """
    if airborne:
        return SOLE_AWAY
    if stage == SOLE_AWAY and loaded:
        return SOLE_STANDING
    if stage in (SOLE_STANDING, SOLE_RELANDED) and unloaded:
        return SOLE_LIFTED
    if stage == SOLE_LIFTED and loaded:
        return SOLE_RELANDED if off else SOLE_STANDING
    if stage == SOLE_RELANDED and not off:  # a plan stands on it now
        return SOLE_STANDING
    return stage


def relanded_soles(stages, feet, planned, foothold_ticks: int, tolerance: float):
    """One tick of :func:`next_sole_stage` for both soles (``SIDES`` order): ``stages`` (2) the soles' stages,
    ``feet`` the estimated soles (``[x_l, y_l, x_r, y_r, ticks_l, ticks_r]``: loaded ticks), ``planned`` the
    plan's feet at the tick (``{side: (x, y, lift)}``). Returns the new stages, ``{side: xy}`` of the soles
    re-landed more than ``tolerance`` [m] off their foothold, and whether one re-landed on this tick."""
    stages = np.array(stages, dtype=float)
    relanded, fresh = {}, False
    for k, side in enumerate(SIDES):
        xy = np.array(feet[2 * k:2 * k + 2], dtype=float)
        stage = next_sole_stage(stages[k], airborne=planned[side][2] > 1e-9,
                                loaded=foothold_loaded(feet, side, foothold_ticks),
                                unloaded=feet[4 + k] == 0.0, off=off_foothold(xy, planned[side], tolerance))
        fresh = fresh or (stages[k] == SOLE_LIFTED and stage == SOLE_RELANDED)
        stages[k] = stage
        if stage == SOLE_RELANDED:
            relanded[side] = xy
    return stages, relanded, fresh
