"""Bookkeeping of a stop's plans: the plan state of the stop planner system and the plans as one.

* :class:`PlanHandle` holds the plan in force, its re-plans and their
  counters in :class:`drake_estop.systems.stop_controller.StopPlannerSystem`'s
  abstract state.
* :class:`PlanSequence` evaluates a stop plan and its re-plans as one plan,
  each in force from its start time.
"""

from __future__ import annotations

import math

import numpy as np


class PlanHandle:
    """Holder of an immutable StopPlan inside a ``Value[object]``.

    Drake clones abstract state (``copy.deepcopy`` for Python objects) every
    time the Simulator prepares an unrestricted update; a plan is never
    mutated after it is made, so sharing it is safe and keeps the tick cheap.
    """

    __slots__ = ("plan", "wall_time", "replans", "replan_failures", "max_wall_time", "blend", "history",
                 "last_try", "pending", "latch_fallback")

    def __init__(self, plan=None, wall_time=float("nan"), replans=0, replan_failures=0, max_wall_time=None,
                 blend=None, history=None, last_try=-math.inf, pending=None, latch_fallback=None):
        self.plan = plan
        # why the latch planned from the reference although the measured state had left it (the
        # InfeasibleStop message of the plan from the measured state), or None
        self.latch_fallback = latch_fallback
        self.last_try = last_try  # time of the last re-plan attempt's first tick
        # (support, next_try) of a re-plan whose tries go on next tick (planner.ReplanPending), or None
        self.pending = pending
        self.history = history if history is not None else ((plan,) if plan is not None else ())
        self.blend = blend  # (start, dp (2), dv (2), duration[, dfeet (2, 3)]): reference.blended_reference
        self.wall_time = wall_time
        self.replans = replans
        self.replan_failures = replan_failures
        self.max_wall_time = wall_time if max_wall_time is None else max_wall_time

    def replaced(self, **changes) -> PlanHandle:
        """A copy with ``changes`` (field: value)."""
        return PlanHandle(**{**{name: getattr(self, name) for name in self.__slots__}, **changes})

    def __deepcopy__(self, memo):
        return self

    def __copy__(self):
        return self


class AheadPlan:
    """Holder of the stop planned ahead of the latch (``StopPlannerSystem``'s ``plan_ahead``): the signal
    time [s] it was planned for and the plan, or None (none planned, or no stop)."""

    __slots__ = ("signal_time", "plan")

    def __init__(self, signal_time=-math.inf, plan=None):
        self.signal_time = signal_time
        self.plan = plan

    def plan_for(self, signal_time):
        """The plan if it was made for a signal at ``signal_time`` (the same servo tick), else None."""
        return self.plan if abs(self.signal_time - signal_time) < 1e-9 else None

    def __deepcopy__(self, memo):
        return self

    def __copy__(self):
        return self


class PlanSequence:
    """A stop plan and its re-plans, evaluated as one plan: each in force from its start time.

    Offers what :func:`drake_estop.physics.plant.analyse` reads of a
    :class:`drake_estop.planning.planner.StopPlan` (``com``, ``com_height``,
    ``feet``, ``support_sides``, ``phase``; the last plan's end state).
    """

    def __init__(self, plans):
        self.plans = tuple(plans)
        self._starts = np.array([p.start_time for p in self.plans[1:]])

    def __getattr__(self, name):  # the final plan's attributes (halt_end, final_feet, pattern, ...)
        return getattr(self.plans[-1], name)

    @property
    def signal_time(self):
        return self.plans[0].signal_time

    def _index(self, t):
        return int(np.searchsorted(self._starts, t + 1e-12, side="right"))

    def _at(self, t):
        return self.plans[self._index(t)]

    def _stitched(self, method, times):
        """``plan.method(times)`` of the plan in force at each time, stitched back in time order."""
        times = np.atleast_1d(np.asarray(times, float))
        index = np.searchsorted(self._starts, times + 1e-12, side="right")
        out = None
        for k in np.unique(index):
            mask = index == k
            values = getattr(self.plans[k], method)(times[mask])
            if out is None:
                out = [np.zeros((len(times),) + np.shape(v)[1:]) for v in values]
            for o, v in zip(out, values):
                o[mask] = v
        return tuple(out)

    def com(self, times):
        return self._stitched("com", times)

    def com_height(self, times):
        return self._stitched("com_height", times)

    def feet(self, t):
        return self._at(t).feet(t)

    def support_sides(self, t, feet=None):
        return self._at(t).support_sides(t, feet)

    def polygon(self, t):
        return self._at(t).polygon(t)

    def phase(self, t):
        return self._at(t).phase(t)

    def upper_body(self, t):
        return self._at(t).upper_body(t)

    def summary(self) -> dict:
        """The last plan's summary, with the signal of the first and the number of re-plans."""
        summary = self.plans[-1].summary()
        # a re-plan after the landing starts in double support: the landing is the last plan that made one
        landed = [p for p in self.plans if p.landing_foot is not None] or self.plans[:1]
        summary["phase_times"]["landing_end"] = landed[-1].landing_time
        made = _made(self.plans)
        # every landing after the signal and why: the walk's own before the stop, then the landings made
        summary["steps"] = self.plans[0].walk_landings + [p.stop_landing for p in made]
        summary["steps_after_signal"] = len(summary["steps"])
        summary.update(estop_time=self.signal_time, support=self.plans[0].support, replans=len(self.plans) - 1,
                       recovery_steps=sum(p.recovery_step for p in made),
                       capture_landings=sum(p.capture_landing for p in made),
                       first_plan={"case": self.plans[0].case, "step_length": self.plans[0].step_length,
                                   "zmp_max": self.plans[0].zmp_max,
                                   "halt_end": self.plans[0].halt_end})
        return summary


def _made(plans) -> list:
    """The plans whose landing is made: once no later re-plan replaced it before its touchdown, nor re-timed it
    after (a landing sole late for it: :func:`~drake_estop.planning.late_landing.late_landing_stop`)."""
    return [p for p, nxt in zip(plans, tuple(plans[1:]) + (None,))
            if p.landing_foot is not None and (nxt is None or (nxt.start_time >= p.landing_time - 1e-9
                                                               and not _retimes(nxt, p)))]


def _retimes(new, old) -> bool:
    """Whether the plan ``new`` re-times the landing of ``old``: the same foot, late since a touchdown no
    later than ``old``'s."""
    return (new.late_since is not None and new.landing_foot == old.landing_foot
            and old.landing_time >= new.late_since - 1e-9)


def landings_made(history, t: float) -> int:
    """The landings after the signal of a stop's plans ``history`` (oldest first) touched down by ``t`` [s]:
    the walk's own before the stop and the stop's (as :meth:`PlanSequence.summary` counts them)."""
    if not history:
        return 0
    walk = sum(step["time"] <= t + 1e-9 for step in history[0].walk_landings)
    return walk + sum(p.landing_time <= t + 1e-9 for p in _made(history))


def last_landing(history):
    """The last plan of ``history`` with a landing (None for none)."""
    return next((plan for plan in reversed(history) if plan.landing_foot is not None), None)
