"""Joint-velocity limits of the stop, through the whole-body IK, over a stride of signals.

Run from the repository root:

    PYTHONPATH=. python benchmarks/bench_joint_velocity.py [--every 1] [--times 3.4 3.5]

For every ``--every``-th servo tick of ``NominalPattern.stride()`` (or the
given ``--times``) it plans the stop, rolls out the kinematic reference from
the tick before the signal to ``--after-halt`` past the halt, solves the
whole-body IK tick by tick (warm-started from the nominal walk's IK at the
tick before the signal, exactly what the Drake diagram does) and counts the
ticks where a joint's finite-difference speed ``|q_k - q_(k-1)| / servo_period``
exceeds its URDF ``<limit velocity=...>``. The plant and the IK solver are
built once; the nominal walk's IK is solved once.

Prints one row per signal with violations (joint, phase, time after the
signal, peak speed, knee angle of that leg, swing-ankle speed) and a summary:
ticks with violations, signals with violations, worst speed / limit, one-step
share, time-to-rest median, plan compute-time median.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pydrake.multibody.plant import MultibodyPlant  # noqa: E402

from drake_estop.model import ALL_JOINTS, joint_position_indices, joint_velocity_indices, load_humanoid  # noqa: E402
from drake_estop.physics.offline import _solve_tick, initial_configuration, nominal_rollout
from drake_estop.planning.gait import GaitParameters, NominalPattern  # noqa: E402
from drake_estop.planning.planner import StopParameters, plan_stop, warm_up  # noqa: E402
from drake_estop.planning.rollout import rollout, stride_ticks  # noqa: E402
from drake_estop.systems.ik import WholeBodyIkSolver  # noqa: E402


class JointVelocityChecker:
    """Plant, IK solver and the nominal walk's IK, built once; :meth:`check` per signal."""

    def __init__(self, gait: GaitParameters | None = None, params: StopParameters | None = None):
        self.pattern = NominalPattern(gait or GaitParameters())
        self.params = params or StopParameters()
        self.dt = self.params.servo_period
        plant = MultibodyPlant(0.0)
        load_humanoid(plant)
        plant.Finalize()
        self.plant = plant
        self.solver = WholeBodyIkSolver(plant)
        self.q_idx = joint_position_indices(plant, ALL_JOINTS)
        v_idx = joint_velocity_indices(plant, ALL_JOINTS)
        self.limit = np.minimum(-plant.GetVelocityLowerLimits()[v_idx], plant.GetVelocityUpperLimits()[v_idx])
        self._nominal = None

    def nominal(self, end: float):
        """IK of the uninterrupted walk, ticks 0..end (extended on demand)."""
        if self._nominal is None or self._nominal[0][-1] < end - 1e-9:
            ro = nominal_rollout(self.pattern, end + 0.5, self.dt)
            q = initial_configuration(self.plant, ro)
            qs = np.empty((len(ro.times), self.plant.num_positions()))
            for i in range(len(ro.times)):
                q = _solve_tick(self.solver, q, ro, i).q
                qs[i] = q
            self._nominal = (ro.times, qs)
        return self._nominal

    def speeds(self, qs):
        """Joint speeds (n-1, joints) by finite differences at the servo period."""
        return np.abs(np.diff(qs[:, self.q_idx], axis=0)) / self.dt

    def nominal_violations(self, start: float, end: float) -> int:
        times, qs = self.nominal(end)
        k0, k1 = int(round(start / self.dt)), int(round(end / self.dt))
        return int(np.sum(np.any(self.speeds(qs[k0:k1 + 1]) > self.limit * (1 + 1e-9), axis=1)))

    def check(self, signal_time: float, *, after_halt: float = 0.05, plan=None) -> dict:
        """Plan the stop at ``signal_time``, solve the IK per tick, count joint-speed violations.

        Counted over the ticks from the signal to ``after_halt`` past the halt end
        (q of the tick before the signal from the nominal walk's IK)."""
        plan = plan or plan_stop(self.pattern, signal_time, self.params)
        t0 = plan.signal_time
        times_nom, q_nom = self.nominal(t0 + self.dt)
        k_before = int(round(t0 / self.dt)) - 1
        ro = rollout(plan, after_halt=after_halt, start=(k_before) * self.dt)
        qs = np.empty((len(ro.times), self.plant.num_positions()))
        qs[0] = q_nom[k_before]
        q = qs[0]
        worst_ik = 0.0
        for i in range(1, len(ro.times)):
            result = _solve_tick(self.solver, q, ro, i)
            q = qs[i] = result.q
            worst_ik = max(worst_ik, result.com_error, result.foot_position_error)
        speed = self.speeds(qs)  # row i: tick i -> i+1 of ro
        ratio = speed / self.limit
        over = ratio > 1 + 1e-9
        events = []
        for row in np.flatnonzero(np.any(over, axis=1)):
            tick = row + 1
            t = float(ro.times[tick])
            for j in np.flatnonzero(over[row]):
                name = ALL_JOINTS[j]
                side = {"l": "left", "r": "right"}.get(name[0])
                knee = float(qs[tick, self.q_idx[ALL_JOINTS.index(f"{name[0]}_knee")]]) if side else float("nan")
                foot_speed = (float(np.linalg.norm(ro.feet[side][tick] - ro.feet[side][tick - 1]) / self.dt)
                              if side else float("nan"))
                events.append({"t": t, "after_signal": t - t0, "joint": name, "speed": float(speed[row, j]),
                               "limit": float(self.limit[j]), "phase": ro.phases[tick], "knee": knee,
                               "foot_speed": foot_speed, "lift": float(ro.feet[side][tick][2]) if side else 0.0})
        return {"signal": t0, "case": plan.case, "support": plan.support, "plan": plan,
                "violation_ticks": int(np.sum(np.any(over, axis=1))), "joint_ticks": int(over.sum()), "events": events,
                "worst_ratio": float(ratio.max()), "worst_joint": ALL_JOINTS[int(np.argmax(ratio.max(axis=0)))],
                "worst_speed": float(speed.max(axis=0)[int(np.argmax(ratio.max(axis=0)))]),
                "time_to_rest": plan.halt_end - plan.signal_time, "compute": plan.compute_time,
                "ik_error_max": worst_ik, "landing": plan.landing_time - plan.start_time}


def describe(result) -> str:
    ev = result["events"]
    joints = sorted({e["joint"] for e in ev})
    phases = sorted({e["phase"] for e in ev})
    first, last = min(e["after_signal"] for e in ev), max(e["after_signal"] for e in ev)
    knee = min(e["knee"] for e in ev)
    return (f"{result['signal']:7.3f} {result['support']:6s} {result['case']:9s} {result['violation_ticks']:4d} "
            f"{result['worst_joint']:>14s} {result['worst_speed']:6.2f} {','.join(joints):24s} "
            f"{','.join(phases):20s} {first:5.3f}-{last:5.3f} {knee:5.2f} {result['landing']:5.3f}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--every", type=int, default=1, help="every n-th servo tick of the stride")
    parser.add_argument("--times", type=float, nargs="*", help="signal times instead of the stride")
    parser.add_argument("--after-halt", type=float, default=0.05)
    parser.add_argument("--param", nargs="*", default=[], metavar="NAME=VALUE",
                        help="StopParameters overrides, e.g. max_fore_reach=0.2")
    args = parser.parse_args(argv)
    params = StopParameters(**{k: float(v) for k, v in (item.split("=") for item in args.param)})
    wall = time.perf_counter()
    checker = JointVelocityChecker(params=params)
    warm_up(checker.pattern, params)
    start, end = checker.pattern.stride()
    signals = (list(args.times) if args.times else
               list(stride_ticks(checker.pattern, params)[::args.every]))
    nominal = checker.nominal_violations(start, end)
    print(f"nominal walk over the stride [{start:.3f}, {end:.3f}) s: {nominal} ticks over a joint-speed limit")
    print(f"{'signal':>7s} {'supp':6s} {'case':9s} {'over':>4s} {'worst joint':>14s} {'rad/s':>6s} "
          f"{'joints over':24s} {'phases':20s} {'after sig. s':11s} {'knee':>5s} {'t_land':>5s}")
    results = []
    for t in signals:
        result = checker.check(float(t), after_halt=args.after_halt)
        results.append(result)
        if result["violation_ticks"]:
            print(describe(result), flush=True)
    ticks = sum(r["violation_ticks"] for r in results)
    joint_ticks = sum(r["joint_ticks"] for r in results)
    worst = max(results, key=lambda r: r["worst_ratio"])
    one_step = sum(r["case"] == "one-step" for r in results)
    print(f"\nsignals {len(results)}; with violations {sum(r['violation_ticks'] > 0 for r in results)}; "
          f"ticks over a limit {ticks} (joint-ticks {joint_ticks}, the diagram's count)")
    print(f"worst: {worst['worst_joint']} {worst['worst_speed']:.2f} rad/s = {worst['worst_ratio']:.2f} x limit "
          f"(signal {worst['signal']:.3f} s)")
    print(f"one-step {one_step}/{len(results)}; time to rest median "
          f"{np.median([r['time_to_rest'] for r in results]):.3f} s, max "
          f"{max(r['time_to_rest'] for r in results):.3f} s; plan compute median "
          f"{1e3 * np.median([r['compute'] for r in results]):.2f} ms; IK error max "
          f"{max(r['ik_error_max'] for r in results) * 1e3:.3f} mm")
    print(f"wall {time.perf_counter() - wall:.1f} s")
    return results


if __name__ == "__main__":
    main()
