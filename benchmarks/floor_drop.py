"""A floor lower than the plan's: the stop's landing spot on a patch of floor DEPTH lower (``--floor-drop``), with
the touchdown by contact off, the default controller (it on), and that with the late landing's re-timing.

    python benchmarks/floor_drop.py [--workers 2]        # run and write benchmarks/FLOOR_DROP.md

Each run is one ``run_online`` stop of the default walk at a signal in single support, the floor lowered under
a 0.4 m x 0.18 m patch centred on the stop's planned landing point. A cell is the verdict (``stop``: every
criterion met; ``upright``: no fall, the criteria missed; ``fall``) and how long after the plan's touchdown the
landing sole first carried 50 N [ms].
"""

from __future__ import annotations

import argparse
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

RESULT = Path(__file__).resolve().parent / "FLOOR_DROP.md"
SIGNALS = (3.2, 3.4)  # [s] early and late in the third step's single support
DEPTHS = (0.005, 0.01, 0.0125, 0.015, 0.02)  # [m]
#: Column title -> the controller's changes (ControllerOptions.with_changes).
CONTROLLERS = {"touchdown off": {"touchdown": None}, "default": {},
               "late landing on": {"planner.late_landing": True}}
PATCH = (0.2, 0.09)  # [m] half-length and half-width of the lowered patch around the landing point
LOADED = 50.0  # [N] a sole carrying weight


def drop_under_landing(signal: float, depth: float):
    """The :class:`~drake_estop.physics.plant.FloorDrop` under the landing point of the stop at ``signal``
    [s] (the default walk and stop parameters), and that plan."""
    from drake_estop.physics.plant import FloorDrop
    from drake_estop.planning.gait import NominalPattern
    from drake_estop.planning.planner import StopParameters, plan_stop

    plan = plan_stop(NominalPattern(), signal, StopParameters())
    x, y = plan.landing_position
    return FloorDrop(x - PATCH[0], x + PATCH[0], y - PATCH[1], y + PATCH[1], depth), plan


def run(job) -> dict:
    """One stop: ``job`` is ``(signal, depth, column)``."""
    from drake_estop.physics.controller_options import ControllerOptions
    from drake_estop.physics.online import run_online
    from drake_estop.physics.perturbations import Perturbations

    signal, depth, column = job
    drop, plan = drop_under_landing(signal, depth)
    result = run_online(estop_time=signal, perturbations=Perturbations(floor_drop=drop),
                        controller=ControllerOptions().with_changes(CONTROLLERS[column]))
    side = plan.landing_foot
    after = result.times > plan.landing_time - 0.05
    loaded = result.times[after & (result.foot_forces[side] > LOADED)]
    return {"signal": signal, "depth": depth, "column": column, "verdict": verdict(result.criteria),
            "failed": [name for name, ok in result.criteria.items() if not ok],
            "late_ms": float((loaded[0] - plan.landing_time) * 1e3) if loaded.size else None}


def verdict(criteria: dict) -> str:
    """``stop``, ``upright`` or ``fall`` from a run's criteria."""
    if all(criteria.values()):
        return "stop"
    return "upright" if criteria["no_fall"] else "fall"


def cell(row: dict) -> str:
    """A table cell: the verdict, the criteria missed by an upright run, and the landing's lateness."""
    text = row["verdict"]
    if row["verdict"] == "upright":
        text += f" ({', '.join(row['failed'])})"
    if row["late_ms"] is not None:
        text += f", loaded {row['late_ms']:+.0f} ms"
    return text


def report(rows: list, wall: float, workers: int) -> str:
    """FLOOR_DROP.md from the runs' rows."""
    lines = ["# A floor lower than planned", "",
             f"Made by `python benchmarks/floor_drop.py` in {wall / 60:.1f} min on {workers} workers. The default "
             "walk's stop at a signal in single support, the floor lowered by the depth under a "
             f"{2 * PATCH[0]:.2f} m x {2 * PATCH[1]:.2f} m patch around the planned landing point "
             "(`--floor-drop`). A cell: the verdict (stop: every criterion; upright: no fall, the criteria "
             "missed; fall), and when the landing sole first carried 50 N after the plan's touchdown. Columns: "
             "`touchdown: null` (the touchdown by contact off), the default controller (it on), and that "
             "with `planner.late_landing: true` (a late landing re-times the stop).", ""]
    for signal in SIGNALS:
        lines += [f"## Signal at {signal:g} s", "", "| drop [mm] | " + " | ".join(CONTROLLERS) + " |",
                  "| --- |" + " --- |" * len(CONTROLLERS)]
        for depth in DEPTHS:
            found = {row["column"]: row for row in rows if row["signal"] == signal and row["depth"] == depth}
            lines.append(f"| {depth * 1e3:g} | " + " | ".join(cell(found[c]) for c in CONTROLLERS) + " |")
        lines.append("")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(argv)
    jobs = [(signal, depth, column) for signal in SIGNALS for depth in DEPTHS for column in CONTROLLERS]
    wall = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        rows = list(pool.map(run, jobs))
    wall = time.perf_counter() - wall
    text = report(rows, wall, args.workers)
    RESULT.write_text(text + "\n")
    print(text)
    counts = {column: sum(row["verdict"] == "stop" for row in rows if row["column"] == column)
              for column in CONTROLLERS}
    print("stops per column:", counts, f"of {len(SIGNALS) * len(DEPTHS)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
