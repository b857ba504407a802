"""The push suite: about 30 physics stops drawn from the campaign's failure classes and the robustness
matrix's hardest pushes, to iterate on the controller in minutes instead of the campaign's 40.

    python benchmarks/push_suite.py [--workers 2]        # run, print each verdict and what changed
    python benchmarks/push_suite.py --update             # ... and keep this run as benchmarks/PUSH_SUITE.json
    python benchmarks/push_suite.py --controller planner.crossover_step=true   # every case with a controller option

The cases come from the committed campaign (``docs/campaign/results.parquet``, seed 0), chosen by a fixed
rule so that the suite is the same on every machine: every fourth fall by impulse, the halt's CoP exits, the
other upright failures, and the strongest stops that met every criterion (to see what a change breaks); and
the robustness benchmark's 29 N s (0.5 m/s) sideways pushes at the signal in three phases, and a 35 N s
backward push at mid stance. Each case is one ``drake-estop simulate --physics`` command, run in the
campaign's run processes. A case's verdict is ``stop`` (every criterion met), ``upright`` (no fall, a
criterion missed) or ``fall``; ``changed`` compares it with the committed result in ``PUSH_SUITE.json``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import shlex
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
CAMPAIGN = ROOT / "docs" / "campaign" / "results.parquet"
RESULT = Path(__file__).resolve().parent / "PUSH_SUITE.json"
TIMEOUT = 900.0  # [s] a run, on a shared machine



def _robustness():
    """``benchmarks/robustness.py``, whose signal phases, push directions, duration and target impulse the
    matrix cases are."""
    spec = importlib.util.spec_from_file_location("robustness", Path(__file__).resolve().parent / "robustness.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


ROBUSTNESS = _robustness()


def campaign_cases(rows: list) -> list:
    """``[(name, class, argv)]`` from the campaign's rows (dicts with ``run``, ``outcome``, ``no_fall``,
    ``push_impulse``, ``cop_exit_phase`` and ``command``), by the suite's fixed rule."""
    finished = [row for row in rows if row["outcome"] in ("success", "failure")]
    falls = sorted((row for row in finished if not row["no_fall"]), key=lambda row: (row["push_impulse"], row["run"]))
    upright = [row for row in finished if row["no_fall"] and not row["success"]]
    halt = [row for row in upright if row["cop_exit_phase"] == "halt"]
    other = [row for row in upright if row["cop_exit_phase"] != "halt"]
    strong = sorted((row for row in finished if row["success"]), key=lambda row: (-row["push_impulse"], row["run"]))
    chosen = [("fall", row) for row in falls[::4]] + [("halt CoP exit", row) for row in halt[::8]]
    chosen += [("upright failure", row) for row in other[::8]] + [("strong stop", row) for row in strong[:5]]
    return [(f"campaign run {row['run']}", kind, shlex.split(row["command"])[1:]) for kind, row in chosen]


def matrix_cases(liftoff: float) -> list:
    """The robustness benchmark's target pushes (29 N s) sideways at the signal in its push phases, both
    ways, and a 35 N s backward push at mid stance, on the default walk whose third step lifts off at
    ``liftoff`` [s]."""
    cases = []
    for phase in ROBUSTNESS.PUSH_PHASES:
        for side in ("left", "right"):
            cases.append((f"{ROBUSTNESS.TARGET_IMPULSE:g} N s {side}, {phase}", "matrix push",
                          _pushed_at(liftoff, phase, side, ROBUSTNESS.TARGET_IMPULSE)))
    cases.append(("35 N s backward, mid single support", "matrix push",
                  _pushed_at(liftoff, "mid single support", "backward", 35.0)))
    return cases


def _pushed_at(liftoff: float, phase: str, direction: str, impulse: float) -> list:
    """``simulate --physics`` with the signal and a push of ``impulse`` [N s] along ``direction`` at ``phase``."""
    t = round(liftoff + ROBUSTNESS.PHASES[phase], 3)
    duration = ROBUSTNESS.PUSH_DURATION
    fx, fy = (component * impulse / duration for component in ROBUSTNESS.DIRECTIONS[direction])
    return ["simulate", "--physics", "--estop-time", f"{t}", "--push", f"{t}", f"{fx}", f"{fy}", f"{duration}"]


def suite() -> list:
    """Every case of the suite: ``[(name, class, argv)]``."""
    import pyarrow.parquet as pq

    from drake_estop.planning.gait import NominalPattern

    start, _ = NominalPattern().stride()
    return campaign_cases(pq.read_table(CAMPAIGN).to_pylist()) + matrix_cases(start)


def verdict(outcome: dict) -> str:
    """``stop``, ``upright``, ``fall`` or ``error`` of a run's outcome columns."""
    if outcome["outcome"] not in ("success", "failure"):
        return "error"
    return "stop" if outcome["success"] else "upright" if outcome["no_fall"] else "fall"


def with_controller(cases: list, options: list) -> list:
    """``cases`` with the controller ``options`` (``KEY=VALUE`` strings, the key dotted inside a section, the
    value in YAML) in each command, as its scenario's controller section."""
    from drake_estop.physics.controller_options import as_section

    if not options:
        return cases
    changes = {key: yaml.safe_load(value) for key, _, value in (option.partition("=") for option in options)}
    section = json.dumps({"controller": as_section(changes)})
    return [(name, kind, [*argv, "--scenario-text", section]) for name, kind, argv in cases]


def run_case(case) -> dict:
    from drake_estop.campaign.runner import _process, outcome_from_reply

    name, kind, argv = case
    start = time.perf_counter()
    outcome = outcome_from_reply(_process().run(argv, TIMEOUT))
    return {"name": name, "class": kind, "command": shlex.join(["drake-estop", *argv]), "verdict": verdict(outcome),
            "steps": outcome.get("steps"), "capture_margin": outcome.get("capture_margin"),
            "wall_s": round(time.perf_counter() - start, 1)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--update", action="store_true", help="keep this run as the committed result")
    parser.add_argument("--controller", action="append", default=[], metavar="KEY=VALUE",
                        help="a controller option for every case (ControllerOptions field, dotted inside a "
                             "section: planner.crossover_step=true, hip_strategy={}), repeatable")
    args = parser.parse_args(argv)
    if args.update and args.controller:
        parser.error("--update keeps the default controller's result: not with --controller")
    cases = with_controller(suite(), args.controller)
    before = {case["name"]: case["verdict"] for case in json.loads(RESULT.read_text())["cases"]} \
        if RESULT.exists() else {}
    start = time.perf_counter()
    with ThreadPoolExecutor(args.workers) as pool:
        results = list(pool.map(run_case, cases))
    wall = time.perf_counter() - start
    changed = 0
    for result in results:
        was = before.get(result["name"])
        mark = "" if was in (None, result["verdict"]) else f"  (was {was})"
        changed += bool(mark)
        print(f"{result['verdict']:8s} {result['class']:16s} {result['name']}{mark}")
    counts = {v: sum(r["verdict"] == v for r in results) for v in ("stop", "upright", "fall", "error")}
    print(f"{len(results)} runs in {wall / 60:.1f} min on {args.workers} workers: "
          + ", ".join(f"{n} {v}" for v, n in counts.items()) + f"; {changed} changed against {RESULT.name}")
    if args.update:
        RESULT.write_text(json.dumps({"counts": counts, "wall_min": round(wall / 60, 1), "workers": args.workers,
                                      "cases": results}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
