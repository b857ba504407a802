"""The controller's per-tick timing instrumentation and the frozen heap of the servo loop."""

import gc
import time

import numpy as np
import pytest

from drake_estop.timing import TickTimer, frozen_heap


class _Context:
    def __init__(self, t):
        self._t = t

    def get_time(self):
        return self._t


def test_tick_timer_sums_callbacks_per_tick_and_summarises_after_since():
    timer = TickTimer(0.005)
    calls = []
    callback = timer.wrap(lambda context, *args: calls.append(args) or "status")
    for t in (0.0, 0.005, 0.005, 0.010):
        assert callback(_Context(t), "state") == "status"
    assert calls == [("state",)] * 4
    assert len(timer.per_tick()) == 3  # two callbacks of tick 1 summed into one entry
    assert len(timer.per_tick(since=0.005)) == 2
    summary = timer.summary(since=0.005)
    assert summary["ticks"] == 2 and 0.0 <= summary["median"] <= summary["p99"] <= summary["max"]
    slow = TickTimer(0.005)
    for t, work in ((0.0, 0), (0.005, 300000), (0.010, 0)):
        slow.wrap(lambda context, n=work: sum(range(n)))(_Context(t))
    assert slow.summary(clock="cpu")["max_at"] == pytest.approx(0.005)  # the slowest tick's time
    assert TickTimer(0.005).summary() == {"median": None, "p99": None, "max": None, "mean": None, "ticks": 0,
                                          "max_at": None}
    with pytest.raises(ValueError, match="clock"):
        timer.per_tick(clock="gpu")


def test_tick_timer_cpu_clock_leaves_out_time_the_thread_did_not_run():
    """A callback that sleeps (the thread descheduled, as when another process preempts it) counts on the
    wall clock, not in the CPU time; one that computes counts on both."""
    import time

    timer = TickTimer(0.005)
    sleeping = timer.wrap(lambda context: time.sleep(0.02))
    working = timer.wrap(lambda context: sum(i * i for i in range(200000)))
    sleeping(_Context(0.0))
    working(_Context(0.005))
    wall, cpu = timer.per_tick(clock="wall"), timer.per_tick(clock="cpu")
    assert wall[0] >= 0.02 and cpu[0] < 0.005
    assert cpu[1] > 0.0 and cpu[1] <= wall[1] * 1.05 + 1e-4
    with pytest.raises(ValueError, match="servo_period"):
        TickTimer(0.0)


def test_tick_timer_counts_a_timed_callback_run_inside_another_once():
    """A timed cache computation evaluated inside a timed update adds to the tick once (in the outer
    callback), and on its own when something untimed (a logger's publish) evaluates it first."""
    import time

    timer = TickTimer(0.005)
    inner = timer.wrap(lambda context: time.sleep(0.01))
    outer = timer.wrap(lambda context: inner(context))
    outer(_Context(0.0))
    inner(_Context(0.005))
    wall = timer.per_tick(clock="wall")
    assert len(wall) == 2
    assert 0.01 <= wall[0] < 0.02  # once, not twice (two sleeps would be >= 0.02)
    assert wall[1] >= 0.01

    def failing(context):
        raise RuntimeError("boom")
    with pytest.raises(RuntimeError, match="boom"):
        timer.wrap(failing)(_Context(0.010))
    outer(_Context(0.015))  # the failure left the timer usable: this tick is counted
    assert len(timer.per_tick()) == 3


def test_tick_timer_leaves_excluded_work_out_of_the_tick():
    """The simulated sensors' work that a timed update pulls in is left out of the tick (wall and CPU),
    once even when nested; outside a timed callback an excluded one simply runs."""
    import time

    timer = TickTimer(0.005)

    def spin(seconds):
        end = time.thread_time() + seconds
        while time.thread_time() < end:
            pass
    sensors = timer.exclude(lambda context: spin(0.02))
    nested = timer.exclude(lambda context: sensors(context))
    update = timer.wrap(lambda context: (spin(0.005), nested(context)) and "status")
    assert update(_Context(0.0)) == "status"
    cpu, wall = timer.per_tick(clock="cpu"), timer.per_tick(clock="wall")
    assert 0.004 <= cpu[0] < 0.015 and 0.004 <= wall[0] < 0.015  # the 5 ms update, not the 20 ms sensors
    nested(_Context(0.005))  # alone: runs, adds no tick
    assert len(timer.per_tick()) == 1
    update(_Context(0.005))  # the exclusion of one tick does not carry into the next
    assert 0.004 <= timer.per_tick(clock="cpu")[1] < 0.015


class _Estimator:
    def estimate(self, context):
        end = time.thread_time() + 0.004
        while time.thread_time() < end:
            pass


def test_tick_timer_breakdown_gives_each_block_its_own_share():
    """Per label: a callback's time less the timed and excluded callbacks it ran; the shares of the
    ticks since ``since`` add up to the mean tick (``summary``'s ``mean``)."""
    import time

    def spin(seconds):
        end = time.thread_time() + seconds
        while time.thread_time() < end:
            pass

    timer = TickTimer(0.005)
    estimate = timer.wrap(_Estimator().estimate)  # label: the method's qualified name
    sensors = timer.exclude(lambda context: spin(0.006))
    planner = timer.wrap(lambda context: (spin(0.002), estimate(context), sensors(context)), label="planner")
    planner(_Context(0.0))
    planner(_Context(0.005))
    estimate(_Context(0.010))  # alone (a logger's publish): its tick is its own work
    shares = timer.breakdown(clock="cpu")
    assert list(shares) == ["_Estimator.estimate", "planner"]  # largest first
    assert 0.004 <= shares["_Estimator.estimate"] < 0.008  # 3 x 4 ms over 3 ticks
    # the planner's own 2 x 2 ms over 3 ticks: without the estimator's (4 ms) and the sensors' (6 ms) time
    assert 2 * 0.002 / 3 <= shares["planner"] < 0.003
    cpu = timer.summary(clock="cpu")
    assert sum(shares.values()) == pytest.approx(cpu["mean"], rel=1e-9)
    later = timer.breakdown(since=0.010, clock="cpu")
    assert list(later) == ["_Estimator.estimate"] and 0.004 <= later["_Estimator.estimate"] < 0.008
    assert TickTimer(0.005).breakdown() == {}
    with pytest.raises(ValueError, match="clock"):
        timer.breakdown(clock="gpu")


def test_tick_timer_slowest_names_the_worst_ticks_and_their_blocks():
    """The slowest ticks since ``since``, slowest first, each with its blocks' own time: a tick where the
    planner spun 6 ms is first and its largest block is the planner's, not the estimator's."""
    import time

    def spin(seconds):
        end = time.thread_time() + seconds
        while time.thread_time() < end:
            pass

    timer = TickTimer(0.005)
    estimate = timer.wrap(_Estimator().estimate)  # 4 ms a call
    planner = timer.wrap(lambda context, seconds: (spin(seconds), estimate(context)), label="planner")
    for t, seconds in ((0.0, 0.009), (0.005, 0.0), (0.010, 0.006), (0.015, 0.001)):
        planner(_Context(t), seconds)
    worst = timer.slowest(clock="cpu", count=2)
    assert [round(entry["t"], 3) for entry in worst] == [0.0, 0.010]
    assert list(worst[1]["blocks"]) == ["planner", "_Estimator.estimate"]  # largest first
    assert 0.006 <= worst[1]["blocks"]["planner"] < 0.010 <= worst[1]["total"]
    assert worst[1]["total"] == pytest.approx(sum(worst[1]["blocks"].values()), rel=1e-9)
    assert worst[0]["total"] == pytest.approx(timer.summary(clock="cpu")["max"], rel=1e-12)
    later = timer.slowest(since=0.005, clock="cpu", count=10)
    assert [round(entry["t"], 3) for entry in later] == [0.010, 0.015, 0.005]  # every tick since, at most count
    assert TickTimer(0.005).slowest() == []
    with pytest.raises(ValueError, match="count"):
        timer.slowest(count=0)
    with pytest.raises(ValueError, match="clock"):
        timer.slowest(clock="gpu")


def test_frozen_heap_freezes_the_live_objects_for_the_block_and_unfreezes_after():
    assert gc.get_freeze_count() == 0
    kept = [np.zeros(3) for _ in range(10)]
    with frozen_heap():
        assert gc.get_freeze_count() > len(kept)  # everything alive at entry, these lists included
    assert gc.get_freeze_count() == 0
    with pytest.raises(RuntimeError), frozen_heap():
        raise RuntimeError("the block failed")
    assert gc.get_freeze_count() == 0  # unfrozen on the error path too


def test_run_through_stop_advances_inside_the_frozen_heap():
    """The servo loop (``Simulator.AdvanceTo``) runs with the heap frozen; unfrozen afterwards."""
    from drake_estop.physics.plant import run_through_stop

    seen = {}

    class Plan:
        halt_end, signal_time = 0.1, 0.05

    class Simulator:
        def get_mutable_context(self):
            return self

        def get_system(self):
            return self

        def get_time(self):
            return seen.get("time", 0.0)

        def set_monitor(self, monitor):
            pass

        def clear_monitor(self):
            pass

        def AdvanceTo(self, t):
            seen["frozen"] = gc.get_freeze_count()
            seen["time"] = t

    class Planner:
        def GetMyContextFromRoot(self, context):
            return context

    plan, wall = run_through_stop(Simulator(), Planner(), 0.05, 0.005, 0.2, lambda context: Plan())
    assert isinstance(plan, Plan) and wall >= 0.0
    assert seen["frozen"] > 0
    assert gc.get_freeze_count() == 0
