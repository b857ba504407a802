"""Per-servo-tick compute time of the controller's own LeafSystems (instrumentation).

:class:`TickTimer` wraps event callbacks when a system declares them
(``DeclarePeriodicDiscreteUpdateEvent(period, 0, timer.wrap(self._update))``)
and adds each callback's wall time and CPU time to the servo tick it ran on. It is a
profiler, like Drake's own timing statistics: it observes the run from
outside the Context and changes nothing in it.

:func:`frozen_heap` keeps Python's cyclic garbage collector off the servo
loop's long-lived heap, as real-time Python control loops do.
"""

from __future__ import annotations

import gc
import time
from collections import defaultdict
from contextlib import contextmanager

import numpy as np


class TickTimer:
    """Time of wrapped callbacks, summed per servo tick: wall-clock [s] and the thread's CPU [s].

    The wall clock is what a servo deadline sees on this machine, preemption by
    other processes included; the thread's CPU time (``time.thread_time``) is the
    controller's own work alone, what a core of its own would take.

    Each callback's own share (its time less the timed and excluded callbacks it
    ran) is also kept per label (:meth:`breakdown`), a per-block profile of the
    controller: the label is the callback's ``__qualname__`` (``"WholeBodyIK._update"``).
    """

    CLOCKS = ("wall", "cpu")

    def __init__(self, servo_period: float):
        if not servo_period > 0:
            raise ValueError(f"servo_period must be positive, got {servo_period!r}")
        self._period = float(servo_period)
        self._totals = {clock: defaultdict(float) for clock in self.CLOCKS}
        self._blocks = {clock: defaultdict(float) for clock in self.CLOCKS}  # (tick, label) -> own time
        self._frames = []  # per running timed callback: [wall, CPU] of the callbacks it ran
        self._excluded = [0.0, 0.0]  # wall, CPU [s] of excluded callbacks inside the outermost one
        self._excluding = [False]  # an excluded callback is running

    def wrap(self, callback, label: str | None = None):
        """``callback(context, *args)`` timed into the tick of ``context.get_time()``.

        Also for cache entries and output ports whose work is the controller's (the state
        estimate): Drake computes those where first evaluated, which may be a logger's publish
        outside every update. A wrapped callback run inside another one is counted once in the
        tick (in the outer one) and in its own label's share of :meth:`breakdown`. ``label``
        defaults to the callback's ``__qualname__``."""
        label = label or getattr(callback, "__qualname__", repr(callback))
        wall_totals, cpu_totals = self._totals["wall"], self._totals["cpu"]
        wall_blocks, cpu_blocks = self._blocks["wall"], self._blocks["cpu"]
        frames, excluded = self._frames, self._excluded

        def timed(context, *args):
            outermost = not frames
            if outermost:
                excluded[:] = [0.0, 0.0]
            frame = [0.0, 0.0]
            frames.append(frame)
            wall, cpu = time.perf_counter(), time.thread_time()
            try:
                status = callback(context, *args)
            finally:
                cpu = time.thread_time() - cpu
                wall = time.perf_counter() - wall
                frames.pop()
            tick = round(context.get_time() / self._period)
            wall_blocks[tick, label] += wall - frame[0]
            cpu_blocks[tick, label] += cpu - frame[1]
            if outermost:
                wall_totals[tick] += wall - excluded[0]
                cpu_totals[tick] += cpu - excluded[1]
            else:
                frames[-1][0] += wall
                frames[-1][1] += cpu
            return status
        return timed

    def exclude(self, callback):
        """``callback`` with its time left out of the timed callback it runs inside: the simulated
        robot's own work that a controller's evaluation pulls in (its sensors: contact forces
        summed into the feet's force/torque readings, noise), which a real controller receives
        instead of computing. Outside a timed callback it is simply called."""
        frames, excluded, excluding = self._frames, self._excluded, self._excluding

        def untimed(context, *args):
            if not frames or excluding[0]:  # not timed, or already inside an excluded callback
                return callback(context, *args)
            excluding[0] = True
            wall, cpu = time.perf_counter(), time.thread_time()
            try:
                return callback(context, *args)
            finally:
                excluding[0] = False
                wall, cpu = time.perf_counter() - wall, time.thread_time() - cpu
                excluded[0] += wall
                excluded[1] += cpu
                frames[-1][0] += wall  # not the running callback's own share either
                frames[-1][1] += cpu
        return untimed

    def _ticks(self, since: float, clock: str):
        """``(tick indices, compute times)`` of the ticks at or after ``since`` [s], by ``clock``."""
        if clock not in self.CLOCKS:
            raise ValueError(f"clock must be one of {self.CLOCKS}, got {clock!r}")
        first = round(since / self._period) if np.isfinite(since) else None
        totals = self._totals[clock]
        ticks = sorted(k for k in totals if first is None or k >= first)
        return ticks, np.array([totals[k] for k in ticks])

    def per_tick(self, since: float = -np.inf, clock: str = "wall") -> np.ndarray:
        """Compute time of each tick at or after ``since`` [s], by ``clock`` ("wall" or "cpu")."""
        return self._ticks(since, clock)[1]

    def summary(self, since: float = -np.inf, clock: str = "wall") -> dict:
        """``{median, p99, max, mean, ticks, max_at}`` of :meth:`per_tick` (seconds; ``max_at``: the
        time [s] of the slowest tick, to find it in the run's log)."""
        ticks, values = self._ticks(since, clock)
        if not ticks:
            return {"median": None, "p99": None, "max": None, "mean": None, "ticks": 0, "max_at": None}
        slowest = int(np.argmax(values))
        return {"median": float(np.median(values)), "p99": float(np.percentile(values, 99)),
                "max": float(values[slowest]), "mean": float(np.mean(values)), "ticks": len(values),
                "max_at": ticks[slowest] * self._period}

    def breakdown(self, since: float = -np.inf, clock: str = "cpu") -> dict:
        """Each label's own time per tick [s], the mean over the ticks at or after ``since`` that
        ran a timed callback, largest first: where a tick's work goes. The shares add up to the
        mean of :meth:`per_tick`."""
        ticks, _ = self._ticks(since, clock)
        if not ticks:
            return {}
        first = ticks[0]
        shares = defaultdict(float)
        for (tick, label), seconds in self._blocks[clock].items():
            if tick >= first:
                shares[label] += seconds
        return dict(sorted(((label, total / len(ticks)) for label, total in shares.items()),
                           key=lambda item: -item[1]))

    def slowest(self, since: float = -np.inf, clock: str = "cpu", count: int = 3) -> list:
        """The ``count`` slowest ticks at or after ``since``, slowest first, each
        ``{"t": time [s], "total": seconds, "blocks": {label: own seconds, largest first}}``: what
        the worst ticks spent their time on. A slow tick whose blocks all took longer than their
        mean points at the machine (preemption, a busy sibling core); one block far over its mean
        at that block's own work (a re-plan)."""
        if count < 1:
            raise ValueError(f"count must be at least 1, got {count!r}")
        ticks, values = self._ticks(since, clock)
        order = np.argsort(-values, kind="stable")[:count]
        chosen = {ticks[i]: {} for i in order}
        for (tick, label), seconds in self._blocks[clock].items():
            if tick in chosen:
                chosen[tick][label] = seconds
        return [{"t": ticks[i] * self._period, "total": float(values[i]),
                 "blocks": dict(sorted(chosen[ticks[i]].items(), key=lambda item: -item[1]))} for i in order]


def timed(callback, timer: TickTimer | None, label: str | None = None):
    """``callback`` wrapped by ``timer`` (``label``: :meth:`TickTimer.wrap`'s), or unchanged without one."""
    return callback if timer is None else timer.wrap(callback, label)


def untimed(callback, timer: TickTimer | None):
    """``callback`` excluded from ``timer``'s ticks (:meth:`TickTimer.exclude`), or unchanged without one."""
    return callback if timer is None else timer.exclude(callback)


@contextmanager
def frozen_heap():
    """Collect once, then freeze every live object out of the cyclic collector (``gc.freeze``)
    for the block; unfrozen after it.

    A full (generation-2) collection walks the whole heap of the loaded plant,
    solvers and modules: 25-40 ms measured here, several servo periods. Where
    one fell inside a tick it would be that run's largest tick time. Frozen, a
    collection walks only what the loop itself allocated (well under 1 ms
    measured). Reference counting still frees everything as before; only
    reference cycles made inside the block wait for a collection.
    """
    gc.collect()
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


def per_tick(log, servo_period: float) -> np.ndarray:
    """A ``VectorLog`` of a system's per-tick output, by tick: row k is the value (the log's first entry; all
    of them, one a column, for a log of several) that the update of tick ``k * servo_period`` set, which the
    logger publishes at the next tick. NaN for a tick whose update had not run."""
    ticks = np.rint(log.sample_times() / servo_period).astype(int)
    data = log.data()
    out = np.full((int(ticks.max()) if len(ticks) else 0, data.shape[0]), np.nan)
    later = ticks >= 1
    out[ticks[later] - 1] = data[:, later].T
    return out[:, 0] if data.shape[0] == 1 else out
