"""Real-time figures of the online stop controller, one run at a time.

Run from the repository root, with the machine otherwise idle:

    python benchmarks/bench_online.py [--repeats 3] [--out FILE.md] [--parts-only] [--profile]

Imports the installed ``drake_estop`` (``pip install -e .``). For each
scenario (the paper's stops at 3.4 and 3.5 s; a 17 N s push to the right at
2.95 s, which re-plans; sensor noise with one tick of latency at 3.15 s) it
runs the default ``simulate --physics`` diagram ``--repeats`` times, after one
warm-up run, and prints:

* the real-time factor: simulated seconds per wall-clock second of
  ``Simulator.AdvanceTo`` (walk, stop and rest; plant, contact and controller),
  and per CPU second of the process;
* the controller's CPU time per servo tick after the signal (its own work:
  estimator, planner, IK, compliance, swing tilt; the simulated sensors left
  out): the median over runs of each run's median, and the largest p99 and
  max of any run;
* where that time goes, block by block (``TickTimer.breakdown``; the run
  with the median real-time factor);
* the machine's speed at the time: the humanoid's plant alone (standing on
  both feet, servos holding the walk's start pose, no controller), CPU per
  5 ms tick, measured before and after the scenarios. On this shared machine
  every figure above follows the hour; this one says which hour it was.
* the profile of one run (:func:`profile_run`, cProfile over the paper's 3.4 s
  stop): the functions with the most time of their own, Drake's C++ (the
  plant, contact and the framework's dispatch) counted where Python calls it;
* where the loop's time goes (:func:`loop_parts`, the paper's 3.4 s stop,
  walk, stop and rest): the controller's own work, the simulated robot alone
  walking the same motion (the run's servo commands replayed into the plant,
  nothing else in the diagram) and the rest between them (Drake's event
  dispatch and cache invalidation over the diagram's systems, the simulated
  sensors and CoP, the servo interpolation, the loggers), and the real-time
  factor that the other two leave a controller of no cost. All three follow
  the hour, the Python-heavy controller and rest more than the plant
  (measured: the plant 1.8-2.4 ms a tick, the controller and
  the rest together 2.7-6.2 ms).

The robustness benchmark (``benchmarks/robustness.py``) times 168 runs two at
a time on the two cores; this one runs them one at a time, as a robot's single
controller would. These machines are shared virtual machines: a tick's
maximum includes time the host took the core away (the thread's CPU clock
counts it), so quote medians and repeat.
"""

import argparse
import cProfile
import os
import pstats
import statistics
import time

from drake_estop.physics.online import build_online_diagram, controller_stop_parameters, online_simulator, run_online
from drake_estop.physics.perturbations import Perturbations, Push
from drake_estop.planning.gait import NominalPattern

#: The controller's servo period [s] (5 ms, HRP-2's): every figure here is per tick of it.
SERVO_PERIOD = controller_stop_parameters().servo_period

SCENARIOS = {
    "paper stop, 3.4 s": (3.4, Perturbations()),
    "paper stop, 3.5 s": (3.5, Perturbations()),
    "17 N s right at 2.95 s": (2.95, Perturbations(pushes=(Push(2.95, 0.0, -170.0, 0.1),))),
    "noise + 1 tick latency, 3.15 s": (3.15, Perturbations(sensor_noise=True, latency_ticks=1, seed=1)),
}


def plant_alone(seconds: float = 2.0, servo_period: float = SERVO_PERIOD) -> float:
    """CPU seconds per servo tick of the humanoid's plant alone: the online run's plant (1 ms SAP
    step, contact, PD servos) standing on both feet with its servos holding the walk's start pose,
    no controller, no sensors, for ``seconds`` of simulated time after a 0.1 s warm-up."""
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder

    from drake_estop.physics.plant import PhysicsParameters, add_physics_plant, add_pose_hold
    from drake_estop.systems.diagram import initial_configuration
    from drake_estop.systems.ik import shared_ik

    builder = DiagramBuilder()
    plant, _, instance, _ = add_physics_plant(builder, PhysicsParameters())
    q0 = initial_configuration(shared_ik()[0], NominalPattern())
    add_pose_hold(builder, plant, instance, q0)
    simulator = Simulator(builder.Build())
    plant.SetPositions(plant.GetMyMutableContextFromRoot(simulator.get_mutable_context()), q0)
    simulator.AdvanceTo(0.1)
    start = time.process_time()
    simulator.AdvanceTo(0.1 + seconds)
    return (time.process_time() - start) / seconds * servo_period


def loop_parts(pattern, estop_time: float = 3.4, after_halt: float = 2.5) -> dict:
    """CPU seconds per servo tick of one online run's loop (the default ``simulate --physics`` diagram,
    no perturbation; walk, stop and rest), split into ``controller`` (its own work every tick: the
    :class:`drake_estop.timing.TickTimer`'s blocks), ``plant`` (the simulated robot alone walking the same
    motion: the IK's positions of every tick, logged in the run, replayed through a first-order hold and
    its derivative, a native ``TrajectorySource``, as the plant's ``desired_state``; no controller, sensors
    or logs) and ``rest`` (the loop less those two). Also ``loop``, ``ticks`` and ``replay_pelvis_z`` (the
    replayed robot's final pelvis height [m]: it walked, it did not fall, so its contacts were the run's)."""
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import TrajectorySource
    from pydrake.trajectories import PiecewisePolynomial

    from drake_estop.physics.plant import actuated_indices, add_physics_plant, run_through_stop

    handles = build_online_diagram(pattern, controller_stop_parameters(), estop_time)
    simulator = online_simulator(handles)
    context = simulator.get_mutable_context()
    start = time.process_time()
    run_through_stop(simulator, handles.planner, estop_time, SERVO_PERIOD, after_halt, handles.planner.plans)
    loop = time.process_time() - start
    end = context.get_time()
    ticks = end / SERVO_PERIOD
    controller = float(handles.timer.per_tick(clock="cpu").sum())

    log = handles.loggers["ik_q"].FindLog(context)
    q_idx, _ = actuated_indices(handles.plant)
    # the servo interpolator's first-order hold runs one tick behind the IK's positions
    commands = PiecewisePolynomial.FirstOrderHold(log.sample_times() + SERVO_PERIOD, log.data()[q_idx])
    builder = DiagramBuilder()
    plant, _, instance, _ = add_physics_plant(builder, handles.physics)  # the run's plant settings
    source = builder.AddSystem(TrajectorySource(commands, output_derivative_order=1))
    builder.Connect(source.get_output_port(), plant.get_desired_state_input_port(instance))
    replay = Simulator(builder.Build())
    plant_context = plant.GetMyMutableContextFromRoot(replay.get_mutable_context())
    plant.SetPositions(plant_context, handles.initial_q)
    replay.Initialize()
    start = time.process_time()
    replay.AdvanceTo(end)
    plant_alone_walking = time.process_time() - start
    return {"loop": loop / ticks, "controller": controller / ticks, "plant": plant_alone_walking / ticks,
            "rest": (loop - controller - plant_alone_walking) / ticks, "ticks": int(round(ticks)),
            "replay_pelvis_z": float(plant.GetPositions(plant_context)[6])}


def parts_report(parts: list) -> str:
    """The markdown table of :func:`loop_parts` runs: the parts of the run with the median loop time (they
    add up to its loop), the spread of each part over the runs, and the real-time factor that the plant and
    the rest alone leave (what a controller of no cost would reach)."""
    tick = SERVO_PERIOD * 1e3  # [ms]
    rows = [("the simulated robot alone, walking the run's motion (plant, contact, PD servos)", "plant"),
            ("the controller's own work (estimator, planner, IK, compliance, swing tilt)", "controller"),
            ("the rest: Drake's event dispatch and cache invalidation over the diagram's systems, the "
             "simulated sensors and CoP, the servo interpolation, the loggers", "rest")]
    median = sorted(parts, key=lambda p: p["loop"])[(len(parts) - 1) // 2]
    lines = [f"Where the loop's time goes (the paper's 3.4 s stop, walk, stop and rest; CPU per {tick:g} ms tick: "
             f"the run with the median loop time of {len(parts)}, and each part's range over the runs):", "",
             "| part | CPU per tick | share of the loop | range over the runs |", "| --- | --- | --- | --- |"]
    for label, key in rows + [("the loop", "loop")]:
        low, high = min(p[key] for p in parts), max(p[key] for p in parts)
        lines.append(f"| {label} | {median[key] * 1e3:.2f} ms | {median[key] / median['loop']:.0%} "
                     f"| {low * 1e3:.2f}-{high * 1e3:.2f} ms |")
    without = median["plant"] + median["rest"]
    lines += ["", f"Without the controller's work that loop would take {without * 1e3:.2f} ms a tick (real-time "
              f"factor {SERVO_PERIOD / without:.2f}); real time leaves the controller "
              f"{(SERVO_PERIOD - without) * 1e3:.2f} ms a tick at this hour."]
    return "\n".join(lines)


def profile_run(pattern, estop_time: float = 3.4) -> tuple:
    """cProfile over one online run (the default ``simulate --physics`` diagram, built and run):
    ``(rows, total)``, each row ``(function, calls, own seconds, cumulative seconds)`` and ``total`` the
    profiled seconds. The profiler's own cost inflates Python against C++: read the shares, not the
    times."""
    profiler = cProfile.Profile()
    profiler.runcall(run_online, estop_time=estop_time, pattern=pattern, stop_params=controller_stop_parameters())
    stats = pstats.Stats(profiler)
    rows = [(_function_name(key), calls, own, cumulative)
            for key, (_, calls, own, cumulative, _) in stats.stats.items()]
    return rows, stats.total_tt


def _function_name(key) -> str:
    """``module.py:function`` for a profiled function (``key``: pstats' ``(file, line, name)``), the
    package's files relative to it; a built-in (Drake's C++, numpy) as its name alone."""
    file, _, name = key
    if file == "~":
        return name.strip("<>").replace("built-in method ", "")
    parts = file.replace(os.sep, "/").split("/")
    tail = "/".join(parts[parts.index("drake_estop"):]) if "drake_estop" in parts else parts[-1]
    return f"{tail}:{name}"


def profile_report(rows, total: float, top: int = 12) -> str:
    """The markdown table of :func:`profile_run`'s ``rows``: the ``top`` functions by their own time, each
    with its share of the profiled ``total``, its calls and its cumulative time."""
    lines = [f"The profile of one run (cProfile, the paper's 3.4 s stop built and run; {total:.1f} s profiled; "
             "the profiler slows Python more than C++, so read the shares):", "",
             "| function | own time | share | calls | with callees |", "| --- | --- | --- | --- | --- |"]
    for name, calls, own, cumulative in sorted(rows, key=lambda row: -row[2])[:top]:
        lines.append(f"| `{name}` | {own:.2f} s | {own / total:.0%} | {calls} | {cumulative:.2f} s |")
    modules = {}
    for name, _, own, _ in rows:
        module = name.split(":")[0] if name.startswith("drake_estop/") else "outside the package"
        modules[module] = modules.get(module, 0.0) + own
    lines += ["", "Own time summed by module (the package's; everything else, Drake's C++ with its dispatch, "
              "numpy and Python's own, together):", "", "| module | own time | share |", "| --- | --- | --- |"]
    for module, own in sorted(modules.items(), key=lambda item: -item[1])[:top]:
        lines.append(f"| `{module}` | {own:.2f} s | {own / total:.0%} |")
    return "\n".join(lines)


def run(estop_time, perturbations, pattern):
    """One online run: ``{rtf, cpu_rtf, tick (CPU summary), blocks (breakdown), success, replans}``."""
    result = run_online(estop_time=estop_time, perturbations=perturbations, pattern=pattern,
                        stop_params=controller_stop_parameters())
    online = result.online
    return {"rtf": result.numbers()["realtime_factor"], "cpu_rtf": online["cpu_realtime_factor"],
            "tick": online["tick_compute_cpu"], "blocks": online["tick_compute_by_block"],
            "success": result.success, "replans": online["replans"]}


def report(results: dict, repeats: int, wall: float, plant_ticks=None) -> str:
    """The markdown report of ``results`` (scenario name -> that scenario's runs, as :func:`run` returns
    them): medians over runs, the worst p99 and max of any run, and the block breakdown of the run with
    the median real-time factor. ``plant_ticks``: :func:`plant_alone` before and after the runs [s]."""
    lines = [f"Online controller, one run at a time, {repeats} runs per scenario after a warm-up.", "",
             "| scenario | success | re-plans | real-time factor (wall) | real-time factor (CPU) "
             "| tick CPU median | worst p99 | worst max |", "| --- |" + " --- |" * 7]
    breakdowns = []
    for name, runs in results.items():
        rtfs = [r["rtf"] for r in runs]
        median_run = sorted(runs, key=lambda r: r["rtf"])[len(runs) // 2]
        lines.append(
            f"| {name} | {sum(r['success'] for r in runs)}/{len(runs)} | {median_run['replans']} "
            f"| {statistics.median(rtfs):.2f} ({min(rtfs):.2f}-{max(rtfs):.2f}) "
            f"| {statistics.median(r['cpu_rtf'] for r in runs):.2f} "
            f"| {statistics.median(r['tick']['median'] for r in runs) * 1e3:.2f} ms "
            f"| {max(r['tick']['p99'] for r in runs) * 1e3:.2f} ms "
            f"| {max(r['tick']['max'] for r in runs) * 1e3:.2f} ms |")
        breakdowns.append((name, median_run["blocks"]))
    lines += ["", "CPU per tick by block (mean over the ticks after the signal; the median run):", "",
              "| block | " + " | ".join(name for name, _ in breakdowns) + " |", "| --- |" + " --- |" * len(breakdowns)]
    labels = sorted({label for _, blocks in breakdowns for label in blocks},
                    key=lambda label: -max(blocks.get(label, 0.0) for _, blocks in breakdowns))
    for label in labels:
        lines.append(f"| {label} | " + " | ".join(f"{blocks.get(label, 0.0) * 1e3:.2f} ms" for _, blocks in breakdowns)
                     + " |")
    mean_tick = statistics.median(sum(blocks.values()) for _, blocks in breakdowns)
    lines += ["", f"Against a 1 ms servo: the mean tick of the median scenario is {mean_tick * 1e3:.2f} ms of CPU"
              + (", so this Python controller does not fit one." if mean_tick > 1e-3 else ", inside one.")]
    if plant_ticks:
        loop = statistics.median(r["cpu_rtf"] for runs in results.values() for r in runs)
        tick = SERVO_PERIOD * 1e3  # [ms]
        lines += ["", f"The machine at the time: the plant alone (standing, no controller) took "
                  f"{plant_ticks[0] * 1e3:.2f} ms of CPU per {tick:g} ms tick before the runs and "
                  f"{plant_ticks[-1] * 1e3:.2f} ms after; the whole loop took {tick / loop:.2f} ms a tick "
                  f"(the runs' median CPU real-time factor {loop:.2f})."]
    lines += ["", f"Benchmark wall time {wall:.0f} s."]
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", help="also write the report (markdown) to this file")
    parser.add_argument("--parts-only", action="store_true",
                        help="only where the loop's time goes (loop_parts, --repeats runs): the quick A/B of a "
                             "speed change, about 25 s a run")
    parser.add_argument("--profile", action="store_true", help="only the profile of one run (profile_run)")
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error(f"--repeats must be >= 1, got {args.repeats}")
    pattern = NominalPattern()
    start = time.perf_counter()
    run(3.4, Perturbations(), pattern)  # warm-up: the IK plant, the planner's tables, first-call costs
    if args.parts_only:
        text = parts_report([loop_parts(pattern) for _ in range(args.repeats)])
    elif args.profile:
        text = profile_report(*profile_run(pattern))
    else:
        before = plant_alone()
        results = {name: [run(estop_time, perturbations, pattern) for _ in range(args.repeats)]
                   for name, (estop_time, perturbations) in SCENARIOS.items()}
        parts = [loop_parts(pattern) for _ in range(args.repeats)]
        text = report(results, args.repeats, time.perf_counter() - start, plant_ticks=(before, plant_alone()))
        text += "\n\n" + parts_report(parts) + "\n\n" + profile_report(*profile_run(pattern))
    print(text)
    if args.out:
        with open(args.out, "w") as out:
            out.write(text + "\n")


if __name__ == "__main__":
    main()
