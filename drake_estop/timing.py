"""Per-servo-tick compute time of the controller's own LeafSystems (instrumentation).

:class:`TickTimer` wraps event callbacks when a system declares them
(``DeclarePeriodicDiscreteUpdateEvent(period, 0, timer.wrap(self._update))``)
and adds each callback's wall time to the servo tick it ran on. It is a
profiler, like Drake's own timing statistics: it observes the run from
outside the Context and changes nothing in it.
"""

from __future__ import annotations

import time
from collections import defaultdict

import numpy as np


class TickTimer:
    """Wall time [s] of wrapped callbacks, summed per servo tick."""

    def __init__(self, servo_period: float):
        if not servo_period > 0:
            raise ValueError(f"servo_period must be positive, got {servo_period!r}")
        self._period = float(servo_period)
        self._totals = defaultdict(float)

    def wrap(self, callback):
        """``callback(context, *args)`` timed into the tick of ``context.get_time()``."""
        def timed(context, *args):
            start = time.perf_counter()
            status = callback(context, *args)
            self._totals[round(context.get_time() / self._period)] += time.perf_counter() - start
            return status
        return timed

    def per_tick(self, since: float = -np.inf) -> np.ndarray:
        """Compute time of each tick at or after ``since`` [s]."""
        first = round(since / self._period) if np.isfinite(since) else None
        return np.array([v for k, v in sorted(self._totals.items()) if first is None or k >= first])

    def summary(self, since: float = -np.inf) -> dict:
        """``{median, p99, max, ticks}`` of :meth:`per_tick` (seconds)."""
        values = self.per_tick(since)
        if len(values) == 0:
            return {"median": None, "p99": None, "max": None, "ticks": 0}
        return {"median": float(np.median(values)), "p99": float(np.percentile(values, 99)),
                "max": float(values.max()), "ticks": int(len(values))}


def timed(callback, timer: TickTimer | None):
    """``callback`` wrapped by ``timer``, or unchanged without one."""
    return callback if timer is None else timer.wrap(callback)
