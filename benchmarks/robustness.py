"""Robustness of the online stop controller in physics: the stride sweep, the perturbation matrix and
the push-recovery table, each run an independent `run_online` simulation (ROBUSTNESS.md); and, with
``--ablation``, the matrix again with one setting of the controller or the plant changed per row.

    python benchmarks/robustness.py [--workers 2] [--out benchmarks/ROBUSTNESS.md] [--quick]
                                    [--controller-option NAME=VALUE] [--time-step S]
    python benchmarks/robustness.py --ablation [--workers 2] [--cells CELL] [--phases PHASE] [--changes KEY]

* **Stride sweep**: a stop signal every 20 ms over the third step (single then double support).
* **Matrix**: every perturbation cell (pushes of 17 N s over 0.1 s at the signal in four
  directions, mass x0.9 / x1.1, torso COM +-2 cm, friction 0.5, latency 1 tick, sensor noise) at
  signal times spread over the stride (early, mid and late single support, double support).
* **Push recovery**: per direction and signal phase, the largest impulse (0.1 s push at the signal)
  that still meets every criterion, searched on a 5 N s grid; and the target, 29 N s (0.5 m/s),
  run in every direction and phase.
* **Ablation** (``--ablation``): the matrix (44 runs) with the defaults, then with each feature of the
  online controller changed in turn (:data:`ABLATION`: foot compliance, swing tilt, measured footholds,
  braked landing, re-landed footholds, recovery step, capture landing, reference fallback and the feet's
  force control off; the re-plan's solves a tick unbounded; the foothold re-plan, the whole-body walk, the
  hip strategy, the crossover step, the touchdown by contact, the late landing's re-timing, and both on;
  one step at most) and with the plant at a 2 ms step: 880 runs, about 7 s of CPU each (about 50 min on 2
  workers). Each row: the matrix's passes,
  its falls and the cells that fail.
  ``--cells`` / ``--phases`` / ``--changes`` run a part of it; a part with every cell and phase
  (``--changes KEY``) replaces its rows in the committed table and keeps the others.

ROBUSTNESS.md holds the main report and, under its own heading between the :data:`ABLATION_BEGIN` and
:data:`ABLATION_END` markers, the ablation; each kind of run rewrites its own part and keeps the other
(ROBUSTNESS.json likewise: the main run's rows, and the ablation's rows under ``"ablation"``).

Runs are spread over ``--workers`` processes; the numbers are those of this machine (2 cores).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import yaml

MATRIX_CELLS = {
    "push forward 17 N s": {"push": (170.0, 0.0)},
    "push backward 17 N s": {"push": (-170.0, 0.0)},
    "push left 17 N s": {"push": (0.0, 170.0)},
    "push right 17 N s": {"push": (0.0, -170.0)},
    "mass x0.9": {"mass_scale": 0.9},
    "mass x1.1": {"mass_scale": 1.1},
    "torso COM +2 cm": {"torso_com_offset": 0.02},
    "torso COM -2 cm": {"torso_com_offset": -0.02},
    "friction 0.5": {"friction": 0.5},
    "latency 1 tick": {"latency_ticks": 1},
    "sensor noise": {"sensor_noise": True, "seed": 1},
}
#: signal phases: early / mid / late single support and double support of the third step [s after its liftoff]
PHASES = {"early single support": 0.10, "mid single support": 0.30, "late single support": 0.52,
          "double support": 0.70}
PUSH_PHASES = ("early single support", "late single support", "double support")
DIRECTIONS = {"forward": (1.0, 0.0), "backward": (-1.0, 0.0), "left": (0.0, 1.0), "right": (0.0, -1.0)}
PUSH_DURATION = 0.1  # [s]
#: the push-recovery target: 0.5 m/s on the 58 kg robot, forward and backward (all four directions run)
TARGET_IMPULSE = 29.0  # [N s]

#: The ablation's rows: the defaults, then one change each, as a scenario file says it (section: fields, a
#: dotted name inside a sub-section; the controller section is
#: drake_estop.physics.controller_options.ControllerOptions: null turns a reflex off, {} on).
ABLATION = (
    {},
    {"controller": {"foot_compliance": None}},
    {"controller": {"swing_tilt": None}},
    {"controller": {"planner.measured_footholds": False}},
    {"controller": {"braked_landing": False}},
    {"controller": {"planner.relanded_footholds": False}},
    {"controller": {"planner.recovery_step": False}},
    {"controller": {"planner.capture_landing": False}},
    {"controller": {"planner.reference_fallback": False}},
    {"controller": {"planner.foothold_replan": True}},
    {"controller": {"foot_force": None}},
    {"controller": {"foot_force.planned_support": True}},
    {"controller": {"planner.max_replan_solves": None}},
    {"controller": {"whole_body_walk": True}},
    {"controller": {"hip_strategy": {}}},
    {"controller": {"planner.max_steps": 1}},
    {"controller": {"planner.crossover_step": True}},
    {"controller": {"touchdown": None}},
    {"controller": {"planner.late_landing": True}},
    {"controller": {"planner.halt_footholds": True}},
    {"plant": {"time_step": 0.002}},
)
#: The lines around the ablation's section of the report: each kind of run keeps the other's part.
ABLATION_BEGIN = "<!-- ablation: written by `python benchmarks/robustness.py --ablation`; other runs keep it -->"
ABLATION_END = "<!-- end of ablation -->"


def settings(*, controller=None, time_step=None, stop_overrides=None) -> dict:
    """What a run changes from the default controller and plant: ControllerOptions fields by dotted name
    (:meth:`~drake_estop.physics.controller_options.ControllerOptions.with_changes`), the plant's time step
    [s], StopParameters over the controller's."""
    return {"controller": dict(controller or {}), "time_step": time_step, "stop_overrides": dict(stop_overrides or {})}


def change_settings(change: dict) -> dict:
    """The :func:`settings` of an :data:`ABLATION` row."""
    return settings(controller=change.get("controller"), time_step=change.get("plant", {}).get("time_step"))


def change_key(change: dict) -> str:
    """``"defaults"``, or the field an :data:`ABLATION` row changes: ``"controller.planner.recovery_step"``."""
    return ", ".join(f"{section}.{name}" for section, fields in change.items() for name in fields) or "defaults"


def change_label(change: dict) -> str:
    """The row's change as a scenario file writes it: ``controller.swing_tilt: null``."""
    return ", ".join(f"{section}.{name}: {json.dumps(value)}" for section, fields in change.items()
                     for name, value in fields.items()) or "defaults"


def _run(job):
    """One online physics stop: ``job`` = (signal time, perturbation keywords, :func:`settings`). Returns a row."""
    from dataclasses import replace

    from drake_estop.physics.controller_options import ControllerOptions
    from drake_estop.physics.online import controller_stop_parameters, run_online
    from drake_estop.physics.perturbations import Perturbations, Push
    from drake_estop.physics.plant import PhysicsParameters
    from drake_estop.planning.gait import NominalPattern
    from drake_estop.planning.planner import StopParameters

    t, options, setup = job
    options = dict(options)
    push = options.pop("push", None)
    pushes = (Push(t, push[0], push[1], PUSH_DURATION),) if push else ()
    start = time.perf_counter()
    physics = PhysicsParameters() if setup["time_step"] is None else PhysicsParameters(time_step=setup["time_step"])
    controller = ControllerOptions().with_changes(setup["controller"])
    stop_params = controller_stop_parameters(replace(StopParameters(), **setup["stop_overrides"]),
                                             braked_landing=controller.braked_landing)
    try:
        result = run_online(estop_time=t, pattern=NominalPattern(), controller=controller, stop_params=stop_params,
                            perturbations=Perturbations(pushes=pushes, **options), physics=physics)
    except Exception as error:  # noqa: BLE001 - a run that raises is a failed row, not a stopped benchmark
        return {"t": t, "options": job[1], "success": False, "error": f"{type(error).__name__}: {error}"}
    numbers = result.numbers()
    airborne = int(np.count_nonzero(~np.isfinite(result.cop_margin_plan[1:])))
    return {"t": t, "options": job[1], "success": bool(result.success),
            "numbers": {"tilt": numbers["torso_tilt_max_rad"], "slip": max(result.slip.values()),
                        "rest_after_halt": numbers["rest_after_halt_s"], "offset": numbers["final_cog_offset_m"],
                        "cop_margin": numbers["cop_margin_plan_min_m"], "airborne_ticks": airborne},
            "failed": [k for k, v in result.criteria.items() if not v], "case": result.plan.plans[0].case,
            "replans": result.online["replans"],
            "joint_velocity_violations": result.online["joint_velocity_violations"],
            "tick_compute": result.online["tick_compute"], "tick_compute_cpu": result.online["tick_compute_cpu"],
            "tick_compute_by_block": result.online["tick_compute_by_block"],
            "tick_compute_slowest": result.online["tick_compute_slowest"],
            "torso_tilt_max": numbers["torso_tilt_max_rad"],
            "final_offset": numbers["final_cog_offset_m"], "realtime_factor": numbers["realtime_factor"],
            "wall": time.perf_counter() - start,
            "cpu_realtime_factor": result.online["cpu_realtime_factor"]}


def _stride():
    from drake_estop.planning.gait import NominalPattern
    return NominalPattern().stride()


def _phase_times() -> dict:
    """Signal time [s] of each of :data:`PHASES` on the default walk."""
    start, _ = _stride()
    return {name: round(start + offset, 3) for name, offset in PHASES.items()}


def _parser():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default=str(Path(__file__).with_name("ROBUSTNESS.md")))
    parser.add_argument("--quick", action="store_true", help="10 sweep signals and a coarse push search")
    parser.add_argument("--controller-option", action="append", default=[], metavar="NAME=VALUE",
                        help="a field of the scenario's controller section (ControllerOptions) for every run, "
                             "dotted inside a section, the value in YAML, e.g. foot_compliance=null or "
                             "planner.landed_replan_threshold=0.065 (repeatable)")
    parser.add_argument("--stop-parameter", action="append", default=[], metavar="NAME=VALUE",
                        help="a StopParameters setting over the controller's, e.g. max_swing_acceleration=15 "
                             "(repeatable; the braked landing: drake_estop.physics.online.BRAKED_LANDING)")
    parser.add_argument("--time-step", type=float, default=None,
                        help="the plant's discrete step [s] (default: PhysicsParameters' own)")
    parser.add_argument("--recheck-only", metavar="JSON",
                        help="no new runs: re-check the slow runs of an earlier run's JSON (same settings) and "
                             "write its report again")
    parser.add_argument("--no-recheck", action="store_true",
                        help="do not re-run alone the runs whose controller tick (CPU) had a p99 over 5 ms or a "
                             "max over 10 ms")
    ablation = parser.add_argument_group("ablation")
    ablation.add_argument("--ablation", action="store_true",
                          help="the perturbation matrix with the defaults and with each ABLATION change in turn: "
                               "the ablation table of --out (its own section; the main report is kept)")
    ablation.add_argument("--cells", action="append", choices=list(MATRIX_CELLS), metavar="CELL",
                          help="with --ablation: only this matrix cell (repeatable; default every cell)")
    ablation.add_argument("--phases", action="append", choices=list(PHASES), metavar="PHASE",
                          help="with --ablation: only this signal phase (repeatable; default every phase)")
    ablation.add_argument("--changes", action="append", choices=[change_key(c) for c in ABLATION], metavar="KEY",
                          help="with --ablation: only this row, 'defaults' or the field it changes, e.g. "
                               "controller.swing_tilt (repeatable; default every row)")
    return parser


def _controller_options(parser, items) -> dict:
    """``--controller-option NAME=VALUE`` items as ControllerOptions changes by dotted name (values read as
    YAML), checked."""
    from drake_estop.physics.controller_options import ControllerOptions

    changes = {}
    for item in items:
        name, _, value = item.partition("=")
        if not value or name == "kind":
            parser.error(f"--controller-option: NAME=VALUE with NAME a field of ControllerOptions (dotted inside "
                         f"a section: planner.recovery_step=false), got {item!r}")
        changes[name] = yaml.safe_load(value)
    try:
        ControllerOptions().with_changes(changes)
    except (TypeError, ValueError) as error:
        parser.error(f"--controller-option: {error}")
    return changes


def main(argv=None):
    parser = _parser()
    args = parser.parse_args(argv)
    if args.ablation:
        return ablation_main(parser, args)
    if args.cells or args.phases or args.changes:
        parser.error("--cells, --phases and --changes select a part of the ablation: only with --ablation")
    start, end = _stride()
    every = 0.08 if args.quick else 0.02
    sweep_times = [round(start + every * k, 3) for k in range(int(round((end - start) / every)))]
    phase_times = _phase_times()
    jobs = [(t, {}) for t in sweep_times]
    jobs += [(t, options) for options in MATRIX_CELLS.values() for t in phase_times.values()]
    impulses = [10.0, 20.0, 30.0] if args.quick else [10.0, 15.0, 20.0, 25.0, 30.0, 35.0]
    jobs += [(phase_times[p], _push(d, i)) for p in PUSH_PHASES for d in DIRECTIONS.values()
             for i in [*impulses, TARGET_IMPULSE]]
    setup = settings(controller=_controller_options(parser, args.controller_option), time_step=args.time_step,
                     stop_overrides={k: float(v) for k, v in (item.split("=", 1) for item in args.stop_parameter)})
    jobs = [(t, options, setup) for t, options in jobs]
    if args.recheck_only:
        data = json.loads(Path(args.recheck_only).read_text())
        rows, wall, args.workers = data["rows"], data["wall_s"], data.get("workers", args.workers)
        if not _same([[r["t"], r["options"]] for r in rows], [list(job[:2]) for job in jobs]):
            parser.error("--recheck-only: the JSON's runs are not this benchmark's (other settings or --quick)")
        for row, job in zip(rows, jobs):
            row["options"] = job[1]  # the options as the report looks them up (JSON made tuples lists)
    else:
        wall = time.perf_counter()
        with ProcessPoolExecutor(args.workers) as pool:
            rows = list(pool.map(_run, jobs))
        wall = time.perf_counter() - wall
    if not args.no_recheck:
        recheck(rows, jobs)
    data = {"sweep": rows[:len(sweep_times)], "rows": rows, "wall_s": wall, "workers": args.workers}
    text = report(rows, sweep_times, phase_times, impulses, wall, args.workers)
    notes = settings_notes(setup)
    if notes:
        text = text.replace("\n\n", "\n\n" + " ".join(notes) + "\n\n", 1)
    write_main(args.out, text, data)
    print(Path(args.out).read_text())


def settings_notes(setup: dict) -> list:
    """The report's sentences on what a run changed from the default controller and plant."""
    notes = []
    if setup["controller"]:
        notes.append("Controller settings changed from the defaults (the scenario's controller section): "
                     + ", ".join(f"{name}: {json.dumps(value)}" for name, value in setup["controller"].items()) + ".")
    if setup["stop_overrides"]:
        notes.append(f"Stop-planner settings over the controller's: {setup['stop_overrides']}.")
    if setup["time_step"] is not None:
        notes.append(f"Plant time step: {setup['time_step'] * 1e3:g} ms.")
    return notes


# -- the ablation ----------------------------------------------------------------------------------------


def ablation_main(parser, args):
    """Run the ablation (the selected rows, cells and phases) and write its section and JSON rows."""
    if args.quick or args.recheck_only or args.controller_option or args.stop_parameter or args.time_step is not None:
        parser.error("--ablation runs the matrix with the defaults and ABLATION's changes: no --quick, "
                     "--recheck-only, --controller-option, --stop-parameter or --time-step")
    changes = [c for c in ABLATION if args.changes is None or change_key(c) in args.changes]
    cells = [c for c in MATRIX_CELLS if args.cells is None or c in args.cells]
    phase_times = {p: t for p, t in _phase_times().items() if args.phases is None or p in args.phases}
    jobs = [(t, MATRIX_CELLS[cell], change_settings(change)) for change in changes for cell in cells
            for t in phase_times.values()]
    wall = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        rows = list(pool.map(_run, jobs))
    wall = time.perf_counter() - wall
    per_change = len(cells) * len(phase_times)
    table = [ablation_row(change, rows[k * per_change:(k + 1) * per_change], cells, phase_times)
             for k, change in enumerate(changes)]
    data = {"rows": table, "cells": cells, "phases": phase_times, "runs": len(rows), "wall_s": wall,
            "workers": args.workers}
    previous = json.loads(_read(Path(args.out).with_suffix(".json"), "{}")).get("ablation")
    data = with_previous_rows(data, previous)
    write_ablation(args.out, ablation_section(data), data)
    print(ablation_section(data))


def with_previous_rows(data: dict, previous: dict | None) -> dict:
    """``data`` (an ablation run of some :data:`ABLATION` rows) with the ``previous`` ablation's other rows,
    in ABLATION's order, where both ran the same cells and phases: a run of one changed row (``--changes``)
    completes the table instead of replacing it. Runs and wall time [s] are then the rows' sums."""
    if not previous or previous.get("cells") != data["cells"] or previous.get("phases") != data["phases"]:
        return data
    order = [change_label(change) for change in ABLATION]
    rows = {row["label"]: row for row in previous["rows"] if row["label"] in order}
    rows.update({row["label"]: row for row in data["rows"]})
    table = sorted(rows.values(), key=lambda row: order.index(row["label"]))
    kept = [row for row in previous["rows"] if row["label"] in rows and rows[row["label"]] is row]
    return {**data, "rows": table, "runs": sum(row["runs"] for row in table),
            "wall_s": data["wall_s"] + previous["wall_s"] * sum(r["runs"] for r in kept) / max(previous["runs"], 1)}


def ablation_row(change: dict, rows: list, cells: list, phase_times: dict) -> dict:
    """One row of the table: ``rows`` are the runs of ``cells`` x ``phase_times`` (that order) with ``change``."""
    places = [(cell, phase, t) for cell in cells for phase, t in phase_times.items()]
    failed = [{"cell": cell, "phase": phase, "t": t, "result": _failures(row)}
              for (cell, phase, t), row in zip(places, rows) if not row["success"]]
    return {"change": change, "label": change_label(change), "passed": sum(r["success"] for r in rows),
            "runs": len(rows), "falls": sum("no_fall" in r.get("failed", ()) for r in rows),
            "errors": sum("error" in r for r in rows), "failed": failed}


def ablation_section(data: dict) -> str:
    """The ablation's part of the report, markers included: one row per change."""
    cells, phases, rows = data["cells"], data["phases"], data["rows"]
    whole = len(cells) == len(MATRIX_CELLS) and len(phases) == len(PHASES)
    part = "" if whole else (f" Only part of the matrix: {', '.join(cells)} at {', '.join(phases)}.")
    lines = [ABLATION_BEGIN, "## Ablation: the perturbation matrix with one setting changed", "",
             f"Measured by `python benchmarks/robustness.py --ablation` on this 2-core machine, {data['runs']} runs on "
             f"{data['workers']} workers in {data['wall_s'] / 60:.1f} min: the perturbation matrix "
             f"({len(cells)} cells x {len(phases)} signal phases) with the defaults, then with one setting changed "
             "per row, written as a scenario file sets it (the `controller` section: "
             "`drake_estop.physics.controller_options.ControllerOptions`; `plant.time_step` [s])." + part
             + " Falls: runs that fail `no_fall`; a failing cell shows its failed criteria (as in the matrix above).",
             "", "| change | passes | falls | failing cells |", "| --- | --- | --- | --- |"]
    for row in rows:
        failing = "; ".join(f"{f['cell']}, {f['phase']}: {f['result']}" for f in row["failed"]) or "-"
        label = row["label"] if row["label"] == "defaults" else f"`{row['label']}`"
        lines.append(f"| {label} | {row['passed']}/{row['runs']} | {row['falls']} | {failing} |")
    return "\n".join([*lines, ABLATION_END]) + "\n"


def _section_span(text: str):
    """(start, end) of the ablation's section in ``text`` (markers included), or None."""
    begin = text.find(ABLATION_BEGIN)
    end = text.find(ABLATION_END, begin) if begin >= 0 else -1
    return (begin, end + len(ABLATION_END)) if end >= 0 else None


def with_ablation(text: str, section: str) -> str:
    """``text`` with its ablation section replaced by ``section``, or with ``section`` at its end."""
    span = _section_span(text)
    if span:
        return text[:span[0]] + section.rstrip("\n") + text[span[1]:]
    return (text.rstrip("\n") + "\n\n" if text.strip() else "") + section


def ablation_of(text: str):
    """The ablation's section of ``text`` (markers included), or None."""
    span = _section_span(text)
    return text[span[0]:span[1]] + "\n" if span else None


def _read(path: Path, empty):
    return path.read_text() if path.exists() else empty


def write_main(out, text: str, data: dict):
    """Write the main report ``text`` to ``out`` and ``data`` to its JSON, keeping the ablation's section and
    rows there."""
    out, json_path = Path(out), Path(out).with_suffix(".json")
    section = ablation_of(_read(out, ""))
    out.write_text(text if section is None else with_ablation(text, section))
    previous = json.loads(_read(json_path, "{}"))
    if "ablation" in previous:
        data = {**data, "ablation": previous["ablation"]}
    json_path.write_text(json.dumps(data, indent=1, default=str))


def write_ablation(out, section: str, data: dict):
    """Write the ablation's ``section`` into ``out`` (in place of its last one, else at the end) and ``data``
    under ``"ablation"`` in its JSON, keeping the main report and its rows."""
    out, json_path = Path(out), Path(out).with_suffix(".json")
    out.write_text(with_ablation(_read(out, ""), section))
    json_path.write_text(json.dumps({**json.loads(_read(json_path, "{}")), "ablation": data}, indent=1, default=str))


#: a run's controller tick (CPU) over either bound is re-run alone: the p99 and max per tick asked of the controller [s]
SLOW_P99, SLOW_MAX = 5e-3, 10e-3


def slow_runs(rows) -> list:
    """Indices of the rows whose controller tick in CPU time had a p99 over ``SLOW_P99`` or a max over
    ``SLOW_MAX``."""
    return [i for i, r in enumerate(rows) if r.get("tick_compute_cpu", {}).get("median")
            and (r["tick_compute_cpu"]["p99"] > SLOW_P99 or r["tick_compute_cpu"]["max"] > SLOW_MAX)]


def recheck(rows, jobs):
    """Re-run each of :func:`slow_runs` alone (one worker, the other core idle) and keep its timing in
    the row's ``recheck``, with whether the run did the same (success, numbers, re-plans): a slow tick
    that is the controller's own work is slow again; one that two runs on two cores made slow is not."""
    slow = slow_runs(rows)
    if not slow:
        return
    with ProcessPoolExecutor(1) as pool:
        again = list(pool.map(_run, [jobs[i] for i in slow]))
    for i, row in zip(slow, again):
        rows[i]["recheck"] = {key: row.get(key) for key in ("tick_compute_cpu", "tick_compute_slowest")}
        rows[i]["recheck"]["same_run"] = all(_same(row.get(key), rows[i].get(key))
                                             for key in ("success", "numbers", "replans", "failed"))


def _same(a, b) -> bool:
    """Equal to the bit, NaN equal to NaN (a fallen run's rest time is NaN)."""
    return json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def recheck_lines(rows) -> list:
    """The report's lines on the slow runs: each one's slowest tick by block, and its figures alone."""
    slow = [rows[i] for i in slow_runs(rows)]
    if not slow:
        return []
    lines = ["", f"Runs with a tick (CPU) over {SLOW_P99 * 1e3:g} ms p99 or {SLOW_MAX * 1e3:g} ms max, and the "
             "same run again alone (one worker, the other core idle): the slowest tick's largest blocks show "
             "where it went.", "", "| run | p99 / max [ms] | slowest tick: its largest blocks [ms] | alone: "
             "p99 / max [ms] | alone: slowest tick | same run |", "| --- | --- | --- | --- | --- | --- |"]
    for r in slow:
        cpu, again = r["tick_compute_cpu"], r.get("recheck")
        alone = (f"{again['tick_compute_cpu']['p99'] * 1e3:.2f} / {again['tick_compute_cpu']['max'] * 1e3:.2f}"
                 f" | {_slowest(again.get('tick_compute_slowest'))} | {'yes' if again['same_run'] else 'NO'}"
                 if again and again.get("tick_compute_cpu") else "not re-run | - | -")
        lines.append(f"| {r['t']:.3f} s {_options(r['options'])} | {cpu['p99'] * 1e3:.2f} / {cpu['max'] * 1e3:.2f}"
                     f" | {_slowest(r.get('tick_compute_slowest'))} | {alone} |")
    return lines


def _slowest(slowest) -> str:
    """``t s: total ms (block ms, block ms)`` of a run's slowest tick (``tick_compute_slowest[0]``)."""
    if not slowest:
        return "-"
    worst = slowest[0]
    blocks = ", ".join(f"{label} {seconds * 1e3:.2f}"
                       for label, seconds in list(worst["blocks"].items())[:2])
    return f"{worst['t']:.3f} s: {worst['total'] * 1e3:.2f} ({blocks})"


def _options(options) -> str:
    return ", ".join(f"{k} {v}" for k, v in options.items()) if options else "(sweep)"


def _push(direction, impulse) -> dict:
    """The perturbation options of a ``PUSH_DURATION`` push of ``impulse`` [N s] along ``direction``."""
    return {"push": (direction[0] * impulse / PUSH_DURATION, direction[1] * impulse / PUSH_DURATION)}


def _find(rows, t, options):
    return next(r for r in rows if r["t"] == t and r["options"] == options)


def report(rows, sweep_times, phase_times, impulses, wall, workers) -> str:
    sweep = [_find(rows, t, {}) for t in sweep_times]
    ok = sum(r["success"] for r in sweep)
    lines = ["# Online stop controller: robustness (physics)", "",
             f"Measured by `python benchmarks/robustness.py` on this 2-core machine, {len(rows)} runs on "
             f"{workers} workers in {wall / 60:.1f} min. Every run: the default online controller "
             "(`simulate --physics`), success = every criterion of `physics.analyse`. " + _legend(), "",
             f"## Stride sweep: {ok}/{len(sweep)} stops meet every criterion", "",
             "| signal [s] | case | re-plans | result |", "| --- | --- | --- | --- |"]
    for r in sweep:
        lines.append(f"| {r['t']:.3f} | {r.get('case', '-')} | {r.get('replans', '-')} | "
                     f"{_cell(r)} |")
    ticks = [r["tick_compute"] for r in rows if r.get("tick_compute", {}).get("median")]
    if ticks:
        lines += ["", "Controller work per servo tick (the tick's two state estimates, the stop planner, the IK, "
                  "the foot-edge compliance, the swing-tilt compensation and the feet's force control; not the "
                  "simulated sensors' "
                  "readings) over all runs (median of the runs' medians / worst p99 / "
                  f"worst max), wall clock: {_tick_line(ticks)} (two runs share the two cores, and a run "
                  "preempted by another process counts the wait)."]
        cpu = [r["tick_compute_cpu"] for r in rows if r.get("tick_compute_cpu", {}).get("median")]
        if cpu:
            lines += ["", f"The same in the controller thread's CPU time (its own work, no preemption): "
                      f"{_tick_line(cpu)}."]
            lines += recheck_lines(rows)
        blocks = [r["tick_compute_by_block"] for r in rows if r.get("tick_compute_by_block")]
        if blocks:
            labels = sorted({label for b in blocks for label in b}, key=lambda label: -_median(
                [b.get(label, 0.0) for b in blocks]))
            shares = ", ".join(f"{label} {_median([b.get(label, 0.0) for b in blocks]) * 1e3:.2f} ms"
                               for label in labels)
            lines += ["", f"Where it goes, CPU per tick by block (median over the runs of each run's mean): {shares}."]
        lines += ["", "Joint-velocity violations: "
                  f"{sum(r.get('joint_velocity_violations', 0) > 0 for r in rows)} of {len(rows)} runs."]
    factors = [r["cpu_realtime_factor"] for r in rows if "cpu_realtime_factor" in r]
    if factors:
        lines += ["", "Real-time factor per run, simulated seconds per CPU second of the simulation loop "
                  "(plant, contact and controller on a core of their own; walk, stop and rest): median "
                  f"{_median(factors):.2f}, min {min(factors):.2f}, max {max(factors):.2f}. Wall-clock factors "
                  "with two runs on two busy cores: median "
                  f"{_median([r['realtime_factor'] for r in rows if 'realtime_factor' in r]):.2f}."]
    lines += ["", "## Perturbation matrix", "",
              "| cell | " + " | ".join(f"{name} ({t:.2f} s)" for name, t in phase_times.items()) + " |",
              "| --- |" + " --- |" * len(phase_times)]
    passed = total = 0
    for cell, options in MATRIX_CELLS.items():
        results = [_find(rows, t, options) for t in phase_times.values()]
        passed += sum(r["success"] for r in results)
        total += len(results)
        lines.append(f"| {cell} | " + " | ".join(_cell(r) for r in results) + " |")
    lines += ["", f"{passed}/{total} cells pass.", "", "## Push recovery (0.1 s push at the signal)", "",
              "Largest impulse that still meets every criterion, and every smaller one on the grid "
              f"({', '.join(f'{i:g}' for i in impulses)} N s; 17 N s is 0.3 m/s on the 58 kg robot):", "",
              "| phase | " + " | ".join(DIRECTIONS) + " |", "| --- |" + " --- |" * len(DIRECTIONS)]
    for phase in PUSH_PHASES:
        t = phase_times[phase]
        cells = []
        for d in DIRECTIONS.values():
            best = 0.0
            for i in impulses:
                r = _find(rows, t, _push(d, i))
                if not r["success"]:
                    break
                best = i
            cells.append(f"{best:g} N s ({best / 58.0:.2f} m/s)" if best else f"< {impulses[0]:g} N s")
        lines.append(f"| {phase} ({t:.2f} s) | " + " | ".join(cells) + " |")
    lines += ["", f"## The target: {TARGET_IMPULSE:g} N s ({TARGET_IMPULSE / 58.0:.2f} m/s) at the signal", "",
              "The target is 0.5 m/s forward and backward; every direction is run. A run passes when it meets "
              "every criterion (it does not need the smaller impulses to pass).", "",
              "| phase | " + " | ".join(DIRECTIONS) + " |", "| --- |" + " --- |" * len(DIRECTIONS)]
    for phase in PUSH_PHASES:
        t = phase_times[phase]
        cells = [_cell(_find(rows, t, _push(d, TARGET_IMPULSE))) for d in DIRECTIONS.values()]
        lines.append(f"| {phase} ({t:.2f} s) | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _legend():
    from drake_estop.physics.plant import PhysicsParameters

    p = PhysicsParameters()
    return (f"A failed criterion shows its number: torso tilt (limit {p.max_torso_tilt:g} rad, with the "
            f"pelvis height), sole slip (limit {p.max_slip * 1e3:g} mm), rest after the planned halt (limit "
            f"{p.rest_within:g} s), final COG offset from the feet's midpoint (limit {p.rest_offset * 1e3:g} mm), "
            f"least CoP margin in the planned support (at most {p.cop_tolerance * 1e3:g} mm outside; a tick with no "
            "contact has no CoP and fails it), ticks over a joint-speed limit.")


def _cell(row):
    return "ok" if row["success"] else "FAIL: " + _failures(row)


def _failures(row) -> str:
    """A failed run's criteria with their numbers, or its error."""
    return ", ".join(_failure(row, name) for name in row.get("failed", [])) or row.get("error", "")[:60]


def _failure(row, name):
    """A failed criterion with the number that failed it (how near the run came to passing)."""
    numbers = row.get("numbers")
    if not numbers:
        return name
    rest = numbers["rest_after_halt"]
    detail = {
        "no_fall": f"tilt {numbers['tilt']:.2f} rad",
        "no_slip": f"{numbers['slip'] * 1e3:.0f} mm",
        "comes_to_rest": "never" if not math.isfinite(rest) else f"{rest:.2f} s after the halt",
        "rests_at_midpoint": f"{numbers['offset'] * 1e3:.0f} mm off",
        "cop_in_support": (f"{numbers['cop_margin'] * 1e3:+.1f} mm" + (
            f", {numbers['airborne_ticks']} airborne ticks" if numbers["airborne_ticks"] else "")),
        "joint_speed_within_limits": f"{row.get('joint_velocity_violations', '?')} ticks",
    }.get(name)
    return f"{name} ({detail})" if detail else name


def _tick_line(ticks) -> str:
    """``median / worst p99 / worst max ms``, and the runs over 5 ms p99 and 10 ms max."""
    return (f"{_median([t['median'] for t in ticks]) * 1e3:.2f} / {max(t['p99'] for t in ticks) * 1e3:.2f} / "
            f"{max(t['max'] for t in ticks) * 1e3:.2f} ms; runs with a p99 over 5 ms: "
            f"{sum(t['p99'] > 5e-3 for t in ticks)}, with a max over 10 ms: {sum(t['max'] > 10e-3 for t in ticks)} "
            f"of {len(ticks)}")


def _median(values):
    values = sorted(values)
    n = len(values)
    return values[n // 2] if n % 2 else 0.5 * (values[n // 2 - 1] + values[n // 2])


if __name__ == "__main__":
    main()
