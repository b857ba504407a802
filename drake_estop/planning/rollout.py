"""Servo-tick rollout of a stop plan (kinematic reference), pure numpy.

Produces the per-tick log that ``drake-estop simulate`` writes and the tests
check: COG, COG velocity, ZMP, phase, feet and upper body, one row per servo
tick, SI units, world frame (x forward, y left, z up).
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drake_estop.planning.arms import DEFAULT_ARM_JOINTS
from drake_estop.planning.lipm import GRAVITY
from drake_estop.planning.planner import StopPlan

LOG_COLUMNS = ("t", "com_x", "com_y", "com_z", "com_vx", "com_vy", "com_vz", "com_ax", "com_ay",
               "zmp_x", "zmp_y", "phase", "left_x", "left_y", "left_z", "right_x", "right_y", "right_z",
               "left_yaw", "right_yaw")


@dataclass
class Rollout:
    """Arrays over servo ticks (``times``) plus per-tick phase labels."""

    times: np.ndarray
    com: np.ndarray  # (n, 3)
    com_vel: np.ndarray  # (n, 3)
    com_acc: np.ndarray  # (n, 3)
    zmp: np.ndarray  # (n, 2)
    phases: list
    feet: dict  # side -> (n, 3) ankle x, y, lift
    upper_body: np.ndarray  # (n, len(arm_joints))
    feet_yaw: dict | None = None  # side -> (n,) heading [rad]; None: level soles heading along x
    arm_joints: tuple = DEFAULT_ARM_JOINTS  # the joints of upper_body's columns (the gait's arms.joints)

    def rows(self):
        yaw = self.feet_yaw or {side: np.zeros(len(self.times)) for side in ("left", "right")}
        for i, t in enumerate(self.times):
            yield {
                "t": round(float(t), 9),
                "com_x": self.com[i, 0], "com_y": self.com[i, 1], "com_z": self.com[i, 2],
                "com_vx": self.com_vel[i, 0], "com_vy": self.com_vel[i, 1], "com_vz": self.com_vel[i, 2],
                "com_ax": self.com_acc[i, 0], "com_ay": self.com_acc[i, 1],
                "zmp_x": self.zmp[i, 0], "zmp_y": self.zmp[i, 1], "phase": self.phases[i],
                "left_x": self.feet["left"][i, 0], "left_y": self.feet["left"][i, 1],
                "left_z": self.feet["left"][i, 2], "right_x": self.feet["right"][i, 0],
                "right_y": self.feet["right"][i, 1], "right_z": self.feet["right"][i, 2],
                "left_yaw": yaw["left"][i], "right_yaw": yaw["right"][i],
                **{f"qref_{name}": self.upper_body[i, k] for k, name in enumerate(self.arm_joints)},
            }


def servo_ticks(start: float, end: float, servo_period: float) -> np.ndarray:
    count = int(math.floor((end - start) / servo_period + 1e-9)) + 1
    return start + servo_period * np.arange(count)


def stride_ticks(pattern, params, step_index: int = 2) -> np.ndarray:
    """Every servo tick of one stride of ``pattern`` (see :meth:`NominalPattern.stride`)."""
    start, end = pattern.stride(step_index)
    return start + params.servo_period * np.arange(int(round((end - start) / params.servo_period)))


def rollout(plan: StopPlan, *, after_halt: float = 1.0, start: float = 0.0) -> Rollout:
    """Sample ``plan`` at every servo tick from ``start`` to ``after_halt`` past the halt end."""
    end = max(plan.halt_end, plan.signal_time) + after_halt
    times = servo_ticks(start, end, plan.params.servo_period)
    pos, vel, acc, zmp = plan.com(times)
    z, zd, zdd = plan.com_height(times)
    feet = {side: np.zeros((len(times), 3)) for side in ("left", "right")}
    yaw = {side: np.zeros(len(times)) for side in ("left", "right")}
    arm_joints = plan.pattern.params.arms.joints
    upper = np.zeros((len(times), len(arm_joints)))
    phases = []
    for i, t in enumerate(times):
        for side, value in plan.feet(t).items():
            feet[side][i] = value
        for side, value in plan.feet_yaw(t)[0].items():
            yaw[side][i] = value
        upper[i] = plan.upper_body(t)[0]
        phases.append(plan.phase(t))
    return Rollout(times, np.column_stack([pos, z]), np.column_stack([vel, zd]),
                   np.column_stack([acc, zdd]), zmp, phases, feet, upper, yaw, arm_joints)


def write_log(path, data: Rollout, extra_columns: dict | None = None):
    """CSV, one row per servo tick; ``extra_columns`` name -> (n,) array appended."""
    extra_columns = extra_columns or {}
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    rows = list(data.rows())
    header = list(rows[0].keys()) + list(extra_columns)
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=header)
        writer.writeheader()
        for i, row in enumerate(rows):
            row.update({name: values[i] for name, values in extra_columns.items()})
            writer.writerow({k: (f"{v:.9g}" if isinstance(v, float) else v) for k, v in row.items()})


def write_summary(path, summary: dict):
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w") as handle:
        json.dump(_jsonable(summary), handle, indent=2, sort_keys=True)


def _jsonable(value):
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    return value


def stop_metrics(plan: StopPlan, data: Rollout) -> dict:
    """Numbers a user checks after a stop (added to the summary)."""
    dt = plan.params.servo_period
    after = data.times >= plan.halt_end - 1e-9
    speed = np.linalg.norm(data.com_vel[:, :2], axis=1)
    signal = data.times >= plan.signal_time - 1e-9
    midpoint = 0.5 * (plan.final_feet["left"] + plan.final_feet["right"])
    metrics = {
        "time_to_rest_s": plan.halt_end - plan.signal_time,
        "cog_travel_after_signal_m": float(np.sum(np.linalg.norm(np.diff(data.com[signal, :2], axis=0), axis=1))),
        "final_cog_speed_mps": float(speed[-1]),
        "max_cog_speed_after_halt_mps": float(speed[after].max()) if np.any(after) else None,
        "final_cog_offset_from_midpoint_m": float(np.linalg.norm(data.com[-1, :2] - midpoint)),
        "sagittal_velocity_at_slowdown_end_mps": float(plan.com([plan.slowdown_end])[1][0, 0])
        if plan.x is not None else 0.0,
        "servo_period_s": dt,
    }
    if plan.x is not None:
        # eq. 5: ZMP error the crouch introduces (angular momentum neglected)
        z, _, zdd = plan.com_height(data.times)
        crouch_error = np.abs(data.com_acc[:, 0] * ((plan.pattern.params.com_height) * zdd
                                                     - (z - plan.pattern.params.com_height) * GRAVITY)
                              / (GRAVITY * (zdd + GRAVITY)))
        metrics["crouch_zmp_error_max_m"] = float(crouch_error.max())
    return metrics
