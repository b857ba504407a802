"""The campaign report: ``report.html`` (self-contained, figures embedded) and its PNGs.

* ``push_recovery_map.png``: success rate over push impulse and direction (polar; forward up, left left).
* ``success_vs_phase.png``: success rate over the signal's phase in the stride.
* ``success_vs_model_error.png``: success rate over each model error, the friction, latency and noise.

The page also tables where the runs that stayed up let the centre of pressure leave the planned support
(:func:`cop_exit_counts`: the stop's phase and the loaded sole's edge), where the feet stood against the
plan's (:func:`sole_deviation_counts`), and lists each failure's command.

Rates count every run: an error or timeout row is not a success. Error
bars and the headline interval are 95 % Wilson score intervals.
"""

from __future__ import annotations

import base64
import html
import json
import math
from pathlib import Path

import numpy as np

from drake_estop.campaign.storage import CRITERIA, atomic_write

FIGURES = ("push_recovery_map.png", "success_vs_phase.png", "success_vs_model_error.png")
#: Share of the stride in single support (the gait's double_support_ratio is 0.2): lift-off to landing.
SINGLE_SUPPORT_SHARE = 0.8


def wilson(successes: int, total: int, z: float = 1.96) -> tuple:
    """95 % Wilson score interval (low, high) of a success rate; (nan, nan) for no runs."""
    if total == 0:
        return (math.nan, math.nan)
    p = successes / total
    centre = (p + z * z / (2 * total)) / (1 + z * z / total)
    half = z * math.sqrt(p * (1 - p) / total + z * z / (4 * total * total)) / (1 + z * z / total)
    # exact at the ends (rounding put the bound of 0/11 at 1e-17 and of 6/6 under 1)
    low = 0.0 if successes == 0 else max(0.0, centre - half)
    high = 1.0 if successes == total else min(1.0, centre + half)
    return (low, high)


def _columns(table) -> dict:
    data = {}
    for name in table.column_names:
        values = table.column(name).to_pylist()
        if name in ("outcome", "error", "case", "support", "command", "cop_exit_phase", "cop_exit_edge"):
            data[name] = np.array(["" if v is None else v for v in values], dtype=object)
        else:
            data[name] = np.array([np.nan if v is None else float(v) for v in values])
    data["success"] = data["success"] == 1.0
    return data


def _binned_rate(values, success, edges):
    """Per bin of ``edges``: (centres, rate, low, high, counts)."""
    index = np.clip(np.digitize(values, edges) - 1, 0, len(edges) - 2)
    rows = []
    for k in range(len(edges) - 1):
        mask = index == k
        n, s = int(mask.sum()), int(success[mask].sum())
        low, high = wilson(s, n)
        rows.append((0.5 * (edges[k] + edges[k + 1]), s / n if n else np.nan, low, high, n))
    return [np.array(column) for column in zip(*rows)]


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _save(plt, fig, path):
    """Save ``fig`` as a PNG at ``path`` (atomic) and close it."""
    fig.tight_layout()
    atomic_write(path, lambda handle: fig.savefig(handle, format="png", dpi=110))
    plt.close(fig)


def plot_push_map(data: dict, path, *, sectors: int = 12, impulse_step: float = 5.0):
    """Polar map of the success rate per push direction sector and impulse ring; the runs as dots."""
    plt = _plt()
    impulse, direction, success = data["push_impulse"], np.radians(data["push_direction"]), data["success"]
    top = max(impulse_step, impulse_step * math.ceil(np.nanmax(impulse) / impulse_step)) if len(impulse) else 1.0
    r_edges = np.arange(0.0, top + 1e-9, impulse_step)
    width = 2 * math.pi / sectors
    theta_edges = np.arange(sectors + 1) * width - width / 2  # sector 0 centred on forward
    rate = np.full((sectors, len(r_edges) - 1), np.nan)
    sector = np.floor((direction + width / 2) / width).astype(int) % sectors
    ring = np.clip(np.digitize(impulse, r_edges) - 1, 0, len(r_edges) - 2)
    for i in range(sectors):
        for j in range(len(r_edges) - 1):
            mask = (sector == i) & (ring == j)
            if mask.any():
                rate[i, j] = success[mask].mean()
    fig = plt.figure(figsize=(7, 6.2))
    ax = fig.add_subplot(projection="polar")
    ax.set_theta_zero_location("N")
    mesh = ax.pcolormesh(theta_edges, r_edges, rate.T, cmap="RdYlGn", vmin=0, vmax=1, shading="flat")
    ax.scatter(direction[success], impulse[success], s=6, c="k", marker="o", label="success", alpha=0.6)
    ax.scatter(direction[~success], impulse[~success], s=10, c="k", marker="x", label="failure", alpha=0.6)
    beyond = _not_capturable(data)
    if beyond.any():  # the pushes no controller catches in three steps (the capturability verdict)
        ax.scatter(direction[beyond], impulse[beyond], s=40, facecolors="none", edgecolors="b", linewidths=0.8,
                   label="not capturable (N <= 3)")
    ax.set_xticks(np.radians([0, 90, 180, 270]), ["forward", "left", "backward", "right"])
    ax.set_rlabel_position(112)
    ax.set_title(f"Push recovery: success rate per {360 / sectors:g} deg sector and {impulse_step:g} N s ring\n"
                 "(radius: push impulse [N s]; 17 N s = 0.3 m/s on the 58 kg robot)", fontsize=10)
    fig.colorbar(mesh, ax=ax, shrink=0.7, pad=0.1, label="success rate")
    ax.legend(loc="lower left", bbox_to_anchor=(-0.15, -0.12), fontsize=8)
    _save(plt, fig, path)


def _rate_axes(ax, values, success, edges, label, **style):
    centres, rate, low, high, counts = _binned_rate(values, success, edges)
    keep = counts > 0
    # the Wilson bounds of a rate of 0 or 1 can sit 1e-17 inside it: clip the bar lengths at 0
    below, above = np.maximum(rate[keep] - low[keep], 0.0), np.maximum(high[keep] - rate[keep], 0.0)
    ax.errorbar(centres[keep], rate[keep], yerr=[below, above], capsize=3, marker="o", label=label, **style)
    ax.set_ylim(-0.03, 1.03)


def plot_phase(data: dict, path, *, bins: int = 10):
    """Success rate per tenth of the stride at the signal: every run, and the runs pushed under 10 N s."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.5, 4))
    edges = np.linspace(0.0, 1.0, bins + 1)
    phase, success = data["signal_phase"], data["success"]
    _rate_axes(ax, phase, success, edges, f"every run ({len(phase)})")
    light = data["push_impulse"] < 10.0
    _rate_axes(ax, phase[light], success[light], edges, f"push < 10 N s ({int(light.sum())})", linestyle="--")
    ax.axvspan(SINGLE_SUPPORT_SHARE, 1.0, color="0.9", zorder=0, label="double support")
    ax.set_xlabel("stop signal: share of the stride (lift-off, single support, double support)")
    ax.set_ylabel("success rate")
    ax.legend(fontsize=8)
    ax.set_title("Success rate against the signal's phase in the stride (95 % Wilson intervals)", fontsize=10)
    _save(plt, fig, path)


#: (column, axis label) of the model-error panels; integer / boolean columns are plotted per value.
MODEL_PANELS = (("mass_scale", "mass scale"), ("torso_mass_scale", "torso mass scale"),
                ("torso_com_offset", "torso COM offset [m]"), ("friction", "foot-ground friction"),
                ("latency", "sensor latency [ticks]"), ("sensor_noise", "sensor noise (0 off, 1 on)"))


def plot_model_error(data: dict, path, *, bins: int = 5):
    """Success rate against each model error (and friction, latency, noise), one panel each."""
    plt = _plt()
    fig, axes = plt.subplots(2, 3, figsize=(11, 6), sharey=True)
    for ax, (name, label) in zip(axes.flat, MODEL_PANELS):
        values = data[name]
        levels = np.unique(values[np.isfinite(values)])
        if name in ("latency", "sensor_noise") or len(levels) <= 1:
            edges = np.concatenate([levels - 0.5, [levels[-1] + 0.5]]) if len(levels) else np.array([0.0, 1.0])
        else:
            edges = np.linspace(levels[0], levels[-1], bins + 1)
        _rate_axes(ax, values, data["success"], edges, None)
        ax.set_xlabel(label)
    for ax in axes[:, 0]:
        ax.set_ylabel("success rate")
    fig.suptitle("Success rate against the simulated robot's model error (the controller keeps the nominal "
                 "model), 95 % Wilson intervals", fontsize=10)
    _save(plt, fig, path)


def _failed_criteria(table_row: dict) -> str:
    if table_row["error"]:
        return f"{table_row['outcome']}: {table_row['error']}"
    return ", ".join(name for name in CRITERIA if table_row[name] is False)


def _failure_rows(table) -> str:
    rows = []
    for row in table.to_pylist():
        if row["success"]:
            continue
        rows.append("<tr>" + "".join(f"<td>{html.escape(str(v))}</td>" for v in (
            row["run"], row["seed"], f"{row['signal_phase']:.3f}", f"{row['push_impulse']:.1f}",
            f"{row['push_direction']:.0f}", row["case"] or "", _failed_criteria(row)))
            + f"<td><code>{html.escape(row['command'])}</code></td></tr>")
    return "\n".join(rows)


#: The stop's phases in the order of :meth:`drake_estop.planning.planner.StopPlan.phase`.
PHASES = ("walking", "landing", "transition", "slowdown", "halt", "stopped")


def cop_exit_counts(data: dict) -> dict:
    """Runs that stayed up but whose CoP left the planned support, counted by where: {(phase, edge): n}
    (phase of the stop and sole edge, :meth:`drake_estop.physics.criteria.PhysicsResult.cop_exit`); empty
    for a table without those columns."""
    if "cop_exit_phase" not in data:
        return {}
    counts = {}
    upright = (data["no_fall"] == 1.0) & (data["cop_in_support"] == 0.0)
    for phase, edge in zip(data["cop_exit_phase"][upright], data["cop_exit_edge"][upright]):
        if phase:
            counts[(phase, edge)] = counts.get((phase, edge), 0) + 1
    return counts


def _cop_exit_table(data: dict) -> str:
    counts = cop_exit_counts(data)
    if not counts:
        return "<p>No run that stayed up left its support (or the table predates these columns).</p>"
    phases = [p for p in PHASES if any(key[0] == p for key in counts)]
    edges = sorted({edge for _, edge in counts}, key=lambda e: -sum(n for (_, x), n in counts.items() if x == e))
    head = "<tr><th>phase / edge</th>" + "".join(f"<th>{html.escape(e)}</th>" for e in edges) + "<th>all</th></tr>"
    rows = [f"<tr><td>{p}</td>" + "".join(f"<td>{counts.get((p, e), '')}</td>" for e in edges)
            + f"<td>{sum(n for (q, _), n in counts.items() if q == p)}</td></tr>" for p in phases]
    return "<table>" + head + "".join(rows) + "</table>"


#: The run classes of :func:`sole_deviation_counts`, in the report's order.
RUN_CLASSES = ("met every criterion", "stayed up, missed a criterion", "fell")
#: A loaded sole farther than this [m] from the plan's foothold counts as off the plan (:func:`sole_deviation_counts`).
OFF_PLAN = 0.01


def sole_deviation_counts(data: dict) -> dict:
    """Where the loaded soles stood against the plan's feet, per run class (:data:`RUN_CLASSES`) that has runs:
    ``{"runs", "off_plan_median" [m], "turn_median" [rad], "off_plan_runs"}`` (runs with a sole over
    :data:`OFF_PLAN` off), from the ``sole_off_plan_max`` and ``sole_turn_max`` columns (before any fall); empty
    for a table without them."""
    if "sole_off_plan_max" not in data or not np.any(np.isfinite(data["sole_off_plan_max"])):
        return {}
    fell = data["no_fall"] == 0.0
    masks = {RUN_CLASSES[0]: data["success"], RUN_CLASSES[1]: ~data["success"] & (data["no_fall"] == 1.0),
             RUN_CLASSES[2]: fell}
    counts = {}
    for name, mask in masks.items():
        off, turn = data["sole_off_plan_max"][mask], data["sole_turn_max"][mask]
        measured = np.isfinite(off)
        if np.any(measured):
            counts[name] = {"runs": int(np.sum(measured)), "off_plan_median": float(np.median(off[measured])),
                            "turn_median": float(np.nanmedian(turn[measured])),
                            "off_plan_runs": int(np.sum(off[measured] > OFF_PLAN))}
    return counts


def _sole_deviation_table(data: dict) -> str:
    counts = sole_deviation_counts(data)
    if not counts:
        return "<p>Not measured (the table predates these columns).</p>"
    head = (f"<tr><th>runs</th><th>n</th><th>sole off the plan's foothold, median [mm]</th><th>sole turned, "
            f"median [rad]</th><th>a sole over {OFF_PLAN * 1e3:.0f} mm off</th></tr>")
    rows = [f"<tr><td>{name}</td><td>{c['runs']}</td><td>{c['off_plan_median'] * 1e3:.1f}</td>"
            f"<td>{c['turn_median']:.3f}</td><td>{c['off_plan_runs']}</td></tr>" for name, c in counts.items()]
    return "<table>" + head + "".join(rows) + "</table>"


#: How a run's push meets the walk (:func:`push_side`), in the report's order.
PUSH_SIDES = ("towards the stance foot", "towards the swing foot", "sagittal", "both feet down", "no push")


def push_side(pattern, push_time: float, force_x: float, force_y: float) -> str:
    """How a push of ``(force_x, force_y)`` [N] (world frame; the campaign's walks head along x) starting at
    ``push_time`` [s] meets the walk ``pattern``: one of :data:`PUSH_SIDES`.

    "both feet down" where the pattern has both feet on the floor at ``push_time`` (double support, or
    standing); else "sagittal" within 45 deg of the walking axis, and otherwise "towards the stance foot"
    (the side of the foot standing alone: its sole's outer edge is the ankle's last hold, and only a crossover
    step lands beyond it) or "towards the swing foot" (the side a capture landing steps to).
    """
    if not (math.isfinite(force_x) and math.isfinite(force_y)) or (force_x == 0.0 and force_y == 0.0):
        return "no push"
    kind, _, stance = pattern.support_at(push_time)
    if kind != "single":
        return "both feet down"
    if abs(force_y) <= abs(force_x):
        return "sagittal"
    return "towards the stance foot" if (force_y > 0.0) == (stance == "left") else "towards the swing foot"


def push_sides(data: dict, robot=None) -> np.ndarray:
    """:func:`push_side` of every run of the report's ``data`` (:func:`_columns`), on the walk each run took:
    ``robot``'s gait (a description, a name or None: the default humanoid) with the run's step length,
    time and width. A run without a push time is "no push"."""
    from drake_estop.planning.gait import NominalPattern
    from drake_estop.robots import gait_parameters
    from drake_estop.robots.parameters import as_robot

    description, patterns, sides = as_robot(robot), {}, []
    for length, period, width, onset, fx, fy in zip(*(data[name] for name in (
            "step_length", "step_time", "step_width", "push_time", "push_fx", "push_fy"))):
        if not math.isfinite(onset):
            sides.append("no push")
            continue
        key = (length, period, width)
        if key not in patterns:
            patterns[key] = NominalPattern(gait_parameters(description, step_length=length, step_time=period,
                                                           step_width=width))
        sides.append(push_side(patterns[key], onset, fx, fy))
    return np.array(sides, dtype=object)


def push_side_counts(data: dict, robot=None) -> dict:
    """Per :data:`PUSH_SIDES` entry that has runs: ``{"runs", "success", "falls"}`` (counts)."""
    sides = push_sides(data, robot)
    fell = data["no_fall"] == 0.0
    return {side: {"runs": int(np.sum(sides == side)), "success": int(np.sum(data["success"] & (sides == side))),
                   "falls": int(np.sum(fell & (sides == side)))} for side in PUSH_SIDES if np.any(sides == side)}


def _push_side_table(data: dict, robot) -> str:
    try:
        counts = push_side_counts(data, robot)
    except (KeyError, ValueError, OSError) as error:  # a robot this install cannot load, or an older table
        return f"<p>Not tabled: {html.escape(str(error))}</p>"
    head = "<tr><th>push</th><th>runs</th><th>met every criterion</th><th>falls</th></tr>"
    rows = [f"<tr><td>{side}</td><td>{c['runs']}</td><td>{c['success']} ({100 * c['success'] / c['runs']:.0f} %)"
            f"</td><td>{c['falls']}</td></tr>" for side, c in counts.items()]
    return "<table>" + head + "".join(rows) + "</table>"


def _not_capturable(data: dict) -> np.ndarray:
    """Runs whose measured state no N <= 3 steps captured (``capture_steps`` -1; null counts as capturable)."""
    return data.get("capture_steps", np.full(len(data["success"]), np.nan)) == -1.0


def capturability_counts(data: dict) -> dict:
    """Success among the runs the capturability verdict says can be caught (``capture_steps`` >= 0) and among
    those it says cannot: ``{"capturable" | "not capturable": {"runs", "success", "falls"}}`` (classes with
    runs); empty for a table without the column."""
    steps = data.get("capture_steps")
    if steps is None or not np.any(np.isfinite(steps)):
        return {}
    fell = data["no_fall"] == 0.0
    masks = {"capturable": steps >= 0.0, "not capturable": steps == -1.0}
    return {name: {"runs": int(mask.sum()), "success": int(data["success"][mask].sum()),
                   "falls": int(fell[mask].sum())} for name, mask in masks.items() if mask.any()}


def _summary_lines(data: dict) -> list:
    n, wins = len(data["success"]), int(data["success"].sum())
    low, high = wilson(wins, n)
    lines = [f"<b>{wins}/{n} runs met every criterion: {100 * wins / n:.1f} %</b> "
             f"(95 % interval {100 * low:.1f}-{100 * high:.1f} %)" if n else "no runs"]
    outcomes = {k: int(np.sum(data["outcome"] == k)) for k in ("success", "failure", "error", "timeout")}
    lines.append("outcomes: " + ", ".join(f"{k} {v}" for k, v in outcomes.items()))
    ran = data["outcome"] != "error"
    ran &= data["outcome"] != "timeout"
    lines.append("criteria missed (runs that completed): " + ", ".join(
        f"{name} {int(np.sum(data[name][ran] == 0.0))}" for name in CRITERIA))
    for push in ((0.0, 10.0), (10.0, 20.0), (20.0, math.inf)):
        mask = (data["push_impulse"] >= push[0]) & (data["push_impulse"] < push[1])
        k, m = int(data["success"][mask].sum()), int(mask.sum())
        if m:
            lines.append(f"push {push[0]:g}-{push[1]:g} N s: {k}/{m} ({100 * k / m:.0f} %)")
    for column, label in (("capture_landings", "a capture landing"), ("recovery_steps", "a recovery step")):
        took = np.nan_to_num(data.get(column, np.zeros(n))) > 0  # (tables written before these columns lack them)
        if took.any():
            lines.append(f"runs with {label}: {int(took.sum())}, of which {int(data['success'][took].sum())} "
                         "met every criterion")
    for name, c in capturability_counts(data).items():
        lines.append(f"{name} at the signal or the push's end (N <= 3 steps): {c['runs']} runs, {c['success']} "
                     f"met every criterion ({100 * c['success'] / c['runs']:.0f} %), {c['falls']} fell")
    wall = data["wall_time"][np.isfinite(data["wall_time"])]
    if len(wall):
        lines.append(f"wall time per run: median {np.median(wall):.1f} s, max {np.max(wall):.1f} s")
    return lines


def _image(path: Path) -> str:
    encoded = base64.b64encode(path.read_bytes()).decode()
    return f'<p><img alt="{path.stem}" src="data:image/png;base64,{encoded}" style="max-width:100%"></p>'


def write_report(table, folder, *, manifest: dict | None = None) -> Path:
    """Write the three PNGs and ``report.html`` (figures embedded as base64) into ``folder``; its path."""
    folder = Path(folder)
    data = _columns(table)
    paths = [folder / name for name in FIGURES]
    if len(data["success"]):
        plot_push_map(data, paths[0])
        plot_phase(data, paths[1])
        plot_model_error(data, paths[2])
    sessions = (manifest or {}).get("sessions", [])
    page = [
        "<!doctype html><html><head><meta charset='utf-8'><title>drake-estop robustness campaign</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:auto}td,th{border:1px solid #ccc;"
        "padding:2px 5px;font-size:12px;vertical-align:top}table{border-collapse:collapse}"
        "code{font-size:11px}</style></head><body>",
        "<h1>Robustness campaign: randomised emergency stops in physics</h1>",
        "<p>Each run is one <code>drake-estop simulate --physics</code> command (online controller) with a "
        "sampled signal phase, gait, push, model error, friction, latency and sensor noise; success is every "
        "criterion of the physics check (no fall, no slip, comes to rest, rests at the midpoint, CoP in the "
        "support polygon).</p>",
        "<ul>" + "".join(f"<li>{line}</li>" for line in _summary_lines(data)) + "</ul>" if len(data["success"])
        else "<p>No finished runs.</p>",
        "<h2>Push recovery map</h2>", *(_image(p) for p in paths[:1] if p.exists()),
        "<h2>Signal phase in the stride</h2>", *(_image(p) for p in paths[1:2] if p.exists()),
        "<h2>Model error</h2>", *(_image(p) for p in paths[2:] if p.exists()),
        "<h2>Where the push came from</h2>",
        "<p>Runs by how the push met the walk at its onset (<code>drake_estop.campaign.report.push_side</code>): "
        "with both feet down, within 45 deg of the walking axis, or sideways towards the foot standing alone "
        "(beyond its sole's outer edge only a crossover step lands) or towards the swinging one.</p>",
        _push_side_table(data, (manifest or {}).get("robot")) if len(data["success"]) else "",
        "<h2>Where the CoP left the support</h2>",
        "<p>Runs that did not fall but whose centre of pressure left the planned support, by the stop's phase "
        "and the loaded sole's edge at the least margin (within 1 cm of it or past it; \"inside\": more than "
        "1 cm inside the measured sole, outside the planned one).</p>", _cop_exit_table(data),
        "<h2>Where the feet stood</h2>",
        "<p>How far a loaded sole the plan stands on lay from the plan's foothold, and how far it turned from "
        "the plan's heading, largest over the run (before any fall): a pushed sole on its edge slides and spins, "
        "and the CoP criterion measures against the plan's feet.</p>", _sole_deviation_table(data),
        "<h2>Failures and how to reproduce them</h2>",
        "<table><tr><th>run</th><th>seed</th><th>phase</th><th>impulse [N s]</th><th>direction [deg]</th>"
        "<th>case</th><th>missed</th><th>reproduce</th></tr>", _failure_rows(table), "</table>",
        "<h2>Campaign</h2>",
        f"<p>robot {html.escape(str((manifest or {}).get('robot', 'default')))}; "
        f"seed {html.escape(str((manifest or {}).get('seed')))}; sessions (start, runs asked, code, workers): "
        + "; ".join(html.escape(f"{s['started']} {s['runs']} {s['code']} {s['workers']}") for s in sessions)
        + "</p>",
        "<pre>" + html.escape(json.dumps((manifest or {}).get("config"), indent=1)) + "</pre>",
        "</body></html>",
    ]
    path = folder / "report.html"
    atomic_write(path, lambda handle: handle.write("\n".join(page).encode()))
    return path
