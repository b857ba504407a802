"""Meshcat views of the emergency stop: traces, markers, support polygon, phase.

The robot itself is drawn by Drake's ``MeshcatVisualizer``.  A Meshcat
recording keeps ``SetTransform`` / ``SetProperty`` calls only (``SetObject``
and ``SetLine`` go straight to the scene), so :class:`StopVisualizer` draws
all geometry once and animates it with transforms and visibility:

* nominal COG (blue) and ZMP (green) traces and nominal footsteps (grey),
  drawn at initialization;
* the planned stop's COG (orange) and ZMP (red) traces and the footsteps it
  takes (red), drawn when the plan appears and hidden in the recording before
  the latch;
* the support polygon: one line loop per distinct polygon, only the current
  one visible;
* spheres for the current COG (and its floor projection) and ZMP, moved every
  publish;
* the current phase as a text plate (a textured quad per phase, generated
  with matplotlib), only the current one visible;
* the one-step indicator (input ``one_step_feasible``): a sphere above the
  robot's head and a plate under the phase plate, green "stop now: one step"
  when a stop signal at this tick would stop within one step, amber "stop
  now: next step" when it would finish the step first (III.C); after the
  latch, the latched stop's case.

:func:`make_meshcat` opens a Meshcat server with a clear error when the port
is taken; :func:`write_replay` writes a self-contained HTML replay.
"""

from __future__ import annotations

import base64
import hashlib
import ipaddress
import os
import re
import tempfile
import warnings
from pathlib import Path

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import Box, Cylinder, Mesh, Meshcat, MeshcatParams, Rgba, Sphere
from pydrake.math import RigidTransform
from pydrake.systems.framework import EventStatus, LeafSystem

from drake_estop.planning.planner import PHASES

PREFIX = "/estop"
_COG_RGBA = Rgba(0.1, 0.3, 0.9, 1.0)
_ZMP_RGBA = Rgba(0.1, 0.7, 0.2, 1.0)
_PLAN_COG_RGBA = Rgba(1.0, 0.55, 0.0, 1.0)
_PLAN_ZMP_RGBA = Rgba(0.9, 0.1, 0.1, 1.0)
_NOMINAL_FOOT_RGBA = Rgba(0.55, 0.55, 0.55, 1.0)
_TAKEN_FOOT_RGBA = Rgba(0.9, 0.1, 0.1, 1.0)
_POLYGON_RGBA = Rgba(0.85, 0.1, 0.85, 1.0)
# walking is teal, not blue: the replay-render test finds the robot by its blue material
_PHASE_COLOURS = {"walking": "#00838f", "landing": "#e08a00", "transition": "#c2185b",
                  "slowdown": "#d32f2f", "halt": "#6a1b9a", "stopped": "#2e7d32"}
_TRACE_Z = 0.002  # lines slightly above the floor
#: one-step indicator: value of the ``one_step_feasible`` input -> (name, plate text, colour)
ONE_STEP_INDICATOR = {True: ("one_step", "stop now: one step", "#2e7d32"),
                      False: ("next_step", "stop now: next step", "#cc7a00")}
#: [m] the indicator sphere above the robot's head (drake_estop.robots.parameters.standing_height)
INDICATOR_CLEARANCE = 0.08
_INDICATOR_HEIGHT = 1.62  # [m] the sphere's default height, over the default humanoid's head (1.54 m tall)


# --------------------------------------------------------------------------
# Meshcat server and replay files.


def is_loopback_host(host):
    """True when ``host`` names this machine only ("localhost", 127.0.0.0/8, ::1)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def make_meshcat(port=None, *, host="localhost"):
    """A Meshcat server listening on ``host`` (this machine only, by default).

    Parameters
    ----------
    port : int, optional
        TCP port (no physical units); None lets Drake pick a free one
        (7000-7099).
    host : str, optional
        Interface to listen on: "localhost" (default) serves this machine
        only; "*" or an address opens the live view, and its "Emergency stop"
        button, to the network, with a warning.

    Returns
    -------
    pydrake.geometry.Meshcat
        The server; ``web_url()`` is its address.

    Raises
    ------
    RuntimeError
        Naming the port when it is already in use.

    Notes
    -----
    ``DRAKE_ALLOW_NETWORK=meshcat`` is set only while the server is created
    and restored afterwards: in Drake 1.51 a process-wide "meshcat" value
    also disables the PackageMap, which makes every default ``Parser`` throw
    (drake_models remote), even for a local file.  The humanoid itself loads
    either way (:func:`drake_estop.model.offline_parser`).
    """
    if not isinstance(host, str) or not host:
        raise ValueError(f"host must be a non-empty host name or address, got {host!r}")
    if not is_loopback_host(host):
        warnings.warn(f"Meshcat listens on {host!r}, not only on this machine: anyone who can reach it can "
                      "watch the robot and press its emergency-stop button", UserWarning, stacklevel=2)
    previous = os.environ.get("DRAKE_ALLOW_NETWORK")
    os.environ.setdefault("DRAKE_ALLOW_NETWORK", "meshcat")
    try:
        return Meshcat(MeshcatParams(host=host, port=port)) if port else Meshcat(MeshcatParams(host=host))
    except RuntimeError as error:
        where = f"port {port}" if port else "any port in 7000-7099"
        raise RuntimeError(
            f"could not start Meshcat on host {host!r}, {where} ({error}); is another "
            "Meshcat/drake-estop already running? Close it or pass a free "
            "port (or none, to let Drake choose)") from error
    finally:
        if previous is None:
            os.environ.pop("DRAKE_ALLOW_NETWORK", None)


def start_recording(meshcat, frames_per_second=64.0):
    """Start recording transforms and properties (SetObject is not recorded)."""
    meshcat.StartRecording(frames_per_second=frames_per_second,
                           set_visualizations_while_recording=True)


def write_replay(meshcat, path):
    """Stop the recording, publish it and write ``meshcat.StaticHtml()``.

    The HTML is self-contained (scripts and scene inlined) and opens offline.
    Returns the path.
    """
    meshcat.StopRecording()
    meshcat.PublishRecording()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(meshcat.StaticHtml())
    return path


def html_scene_bytes(html):
    """Decoded scene commands (msgpack bytes) embedded in a StaticHtml page."""
    blobs = re.findall(r"data:application/octet-binary;base64,([A-Za-z0-9+/=]+)", html)
    return [base64.b64decode(blob) for blob in blobs]


def html_mentions(html, names):
    """Names among ``names`` that appear in the HTML's embedded scene commands."""
    scene = b"\n".join(html_scene_bytes(html))
    return {name for name in names if name.encode() in scene}


# --------------------------------------------------------------------------
# Geometry helpers.


def _line(points_xy, z=_TRACE_Z):
    """3xN vertices of an xy polyline at height ``z``."""
    pts = np.asarray(points_xy, float)
    return np.vstack([pts[:, 0], pts[:, 1], np.full(len(pts), z)])


def _loop(vertices_xy, z=_TRACE_Z):
    """Closed polyline of a polygon's vertices."""
    pts = np.asarray(vertices_xy, float)
    return _line(np.vstack([pts, pts[:1]]), z)


def _sole_loop(sole, ankle_xy, side, yaw=0.0):
    """Outline of a sole rectangle (gait.Sole corners, side 'left'/'right', heading ``yaw`` [rad])."""
    return _loop(sole.corners(ankle_xy, side, yaw), 0.003)


def _phase_plate(directory, phase):
    """OBJ file of a quad textured with the phase name (matplotlib PNG)."""
    return _text_plate(directory, phase, phase, _PHASE_COLOURS[phase], 44)


def _text_plate(directory, name, text, colour, fontsize):
    """OBJ file ``name.obj`` of a quad textured with ``text`` (matplotlib PNG).

    Draws on a bare ``Figure`` (Agg canvas): no pyplot, so the user's
    matplotlib backend (e.g. a notebook's inline one) is left alone.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    png = Path(directory) / f"{name}.png"
    fig = Figure(figsize=(4, 1), dpi=100)
    FigureCanvasAgg(fig)
    fig.patch.set_facecolor("white")
    fig.text(0.5, 0.5, text, ha="center", va="center", fontsize=fontsize, color=colour, weight="bold")
    fig.savefig(png, facecolor="white")
    (Path(directory) / f"{name}.mtl").write_text(
        f"newmtl plate\nKa 1 1 1\nKd 1 1 1\nmap_Kd {png.name}\n")
    obj = Path(directory) / f"{name}.obj"
    # 0.6 m x 0.15 m plate in the x-z plane facing -y (the side camera).
    obj.write_text(
        f"mtllib {name}.mtl\n"
        "v -0.3 0 0\nv 0.3 0 0\nv 0.3 0 0.15\nv -0.3 0 0.15\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 -1 0\nusemtl plate\n"
        "f 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/3/1 4/4/1\n")
    return obj


def pattern_polygon(pattern, t):
    """Support polygon vertices of the nominal pattern at ``t`` (ground feet)."""
    from drake_estop.planning.geometry import SupportPolygon

    sole = pattern.params.sole
    feet = pattern.feet_at(t)[0]
    yaw = pattern.feet_yaw_at(t)[0]
    support, _, side = pattern.support_at(t)
    sides = [side] if support == "single" else ["left", "right"]
    corners = np.vstack([sole.corners(feet[s][:2], s, yaw[s]) for s in sides])
    return SupportPolygon(corners).vertices


def support_vertices(pattern, plan, t):
    """Current support polygon vertices (plan if there is one, else nominal)."""
    if plan is not None and plan.x is not None:
        return plan.polygon(t).vertices
    return pattern_polygon(pattern, t)


def _polygon_key(vertices):
    rounded = np.round(np.asarray(vertices, float), 4)
    return hashlib.md5(rounded.tobytes()).hexdigest()[:12]


# --------------------------------------------------------------------------
# The visualizer system.


class StopVisualizer(LeafSystem):
    """Publishes the stop's traces, markers, polygon and phase to Meshcat.

    .. pydrake_system::

        name: StopVisualizer
        input_ports:
        - com
        - zmp
        - phase
        - plan
        - one_step_feasible

    ``plan`` is the StopPlannerSystem's abstract ``plan`` output;
    ``one_step_feasible`` its output of that name (optional: unconnected, no
    one-step indicator is drawn).  Publishes
    every ``publish_period`` with the context time as the recording time.
    Everything it needs to remember lives in the Meshcat scene (paths that
    exist), never in Python attributes.

    Parameters
    ----------
    meshcat : pydrake.geometry.Meshcat
        Where to draw.
    pattern : NominalPattern
        The nominal walk (its traces and footsteps are drawn at initialization).
    publish_period : float, optional
        Publish period [s] (default 1/64 s).
    prefix : str, optional
        Meshcat path of the drawings (default "/estop").
    follow : tuple of str, optional
        Meshcat paths slid along -x by the COG's travel at every publish, so
        that a fixed camera (:func:`set_follow_camera`) keeps the robot framed
        (recorded into replays); see :func:`follow_camera_paths`. Empty: no
        follow camera.
    indicator_height : float, optional
        Height of the one-step indicator's sphere above the floor [m]
        (default 1.62: over the default humanoid's head); the follow camera
        scales with it.

    Notes
    -----
    Inputs: ``com`` (3) [m], ``zmp`` (2) [m], ``phase`` (1) index into
    ``PHASES``, ``plan`` (abstract), ``one_step_feasible`` (1, > 0.5: a stop
    now stops in one step). The indicator lives under ``<prefix>/one_step``:
    ``one_step`` (green) or ``next_step`` (amber) visible, the other hidden.
    """

    def __init__(self, *, meshcat, pattern, publish_period=1.0 / 64.0, prefix=PREFIX, follow=(),
                 indicator_height=_INDICATOR_HEIGHT):
        super().__init__()
        if not (np.isfinite(indicator_height) and indicator_height > 0):
            raise ValueError(f"indicator_height must be a positive height [m], got {indicator_height!r}")
        self._indicator_height = float(indicator_height)
        self._meshcat = meshcat
        self._follow = tuple(follow)
        self._pattern = pattern
        ends = np.array([step["end"][1] for step in pattern.steps])
        self._pattern_lateral = bool(np.ptp(ends) > pattern.params.step_width + 0.1)
        self._period = publish_period
        self._prefix = prefix
        self.com_port = self.DeclareVectorInputPort("com", 3)
        self.zmp_port = self.DeclareVectorInputPort("zmp", 2)
        self.phase_port = self.DeclareVectorInputPort("phase", 1)
        self.plan_port = self.DeclareAbstractInputPort("plan", AbstractValue.Make(None))
        self.one_step_feasible_port = self.DeclareVectorInputPort("one_step_feasible", 1)
        self._plates = tempfile.mkdtemp(prefix="estop_phase_")
        self.DeclareInitializationPublishEvent(self._initialize)
        self.DeclarePeriodicPublishEvent(publish_period, 0.0, self._publish)

    # -- drawn once ---------------------------------------------------------

    def _initialize(self, context):
        """Draw the nominal traces, footsteps, markers and phase plates."""
        m, p, pattern = self._meshcat, self._prefix, self._pattern
        m.Delete(p)
        times = np.arange(0.0, pattern.end_time + 0.5, 0.01)
        pos, _, _, zmp = pattern.com(times)
        m.SetLine(f"{p}/nominal/cog", _line(pos), 2.0, _COG_RGBA)
        m.SetLine(f"{p}/nominal/zmp", _line(zmp), 2.0, _ZMP_RGBA)
        sole = pattern.params.sole
        for side, xy in pattern.initial_feet.items():
            m.SetLine(f"{p}/nominal/feet/initial_{side}", _sole_loop(sole, xy, side),
                      1.5, _NOMINAL_FOOT_RGBA)
        for k, step in enumerate(pattern.steps):
            m.SetLine(f"{p}/nominal/feet/step{k}", _sole_loop(sole, step["end"], step["swing"], step["end_yaw"]),
                      1.5, _NOMINAL_FOOT_RGBA)
        if self._follow:
            set_follow_camera(m, pattern, scale=self._indicator_height / _INDICATOR_HEIGHT)
        m.SetObject(f"{p}/markers/cog", Sphere(0.03), _COG_RGBA)
        m.SetObject(f"{p}/markers/cog_floor", Cylinder(0.02, 0.004), _COG_RGBA)
        m.SetObject(f"{p}/markers/zmp", Sphere(0.02), _ZMP_RGBA)
        for phase in PHASES:
            path = f"{p}/phase/{phase}"
            m.SetObject(path, Mesh(str(_phase_plate(self._plates, phase))))
            m.SetProperty(path, "visible", False, 0.0)
        if self.one_step_feasible_port.HasValue(context):
            for name, text, colour in ONE_STEP_INDICATOR.values():
                path = f"{p}/one_step/{name}"
                m.SetObject(f"{path}/plate", Mesh(str(_text_plate(self._plates, name, text, colour, 24))))
                m.SetObject(f"{path}/sphere", Sphere(0.04), Rgba(*_rgb(colour), 1.0))
                m.SetProperty(path, "visible", False, 0.0)
        return EventStatus.Succeeded()

    def _draw_plan(self, plan):
        """Planned stop traces and taken footsteps; hidden before the latch."""
        m, p = self._meshcat, f"{self._prefix}/plan"
        times = np.arange(plan.start_time, plan.halt_end + 0.5, 0.01)
        pos, _, _, zmp = plan.com(times)
        m.SetLine(f"{p}/cog", _line(pos, 0.004), 3.0, _PLAN_COG_RGBA)
        m.SetLine(f"{p}/zmp", _line(zmp, 0.004), 3.0, _PLAN_ZMP_RGBA)
        sole = self._pattern.params.sole
        for side, xy in plan.final_feet.items():
            m.SetLine(f"{p}/feet/{side}", _sole_loop(sole, xy, side, plan.final_yaw[side]), 3.0, _TAKEN_FOOT_RGBA)
        m.SetProperty(p, "visible", False, 0.0)
        m.SetProperty(p, "visible", True, plan.signal_time)

    # -- every publish --------------------------------------------------------

    def _publish(self, context):
        """Move the markers, switch the support polygon and the phase plate."""
        t = context.get_time()
        plan = self.plan_port.Eval(context)
        plan = getattr(plan, "plan", plan)
        if plan is not None and not self._meshcat.HasPath(f"{self._prefix}/plan/cog") \
                and plan.x is not None:
            self._draw_plan(plan)
        self._move_markers(context, t)
        self._switch_polygon(plan, t)
        self._switch_phase(context, plan, t)
        self._show_one_step(context, t)
        return EventStatus.Succeeded()

    def _move_markers(self, context, t):
        com = self.com_port.Eval(context)
        zmp = self.zmp_port.Eval(context)
        m, p = self._meshcat, f"{self._prefix}/markers"
        m.SetTransform(f"{p}/cog", RigidTransform(com), t)
        m.SetTransform(f"{p}/cog_floor", RigidTransform([com[0], com[1], 0.002]), t)
        m.SetTransform(f"{p}/zmp", RigidTransform([zmp[0], zmp[1], 0.01]), t)
        plate = [com[0] - 0.55, -0.3, 1.3] if self._follow else [com[0], -0.35, 1.75]  # in the camera's view
        m.SetTransform(f"{self._prefix}/phase", RigidTransform(plate), t)
        if self.one_step_feasible_port.HasValue(context):  # plate under the phase plate, sphere over the head
            m.SetTransform(f"{self._prefix}/one_step", RigidTransform([plate[0], plate[1], plate[2] - 0.17]), t)
            sphere = RigidTransform([com[0] - plate[0], com[1] - plate[1],
                                     self._indicator_height - plate[2] + 0.17])
            for name, _, _ in ONE_STEP_INDICATOR.values():
                m.SetTransform(f"{self._prefix}/one_step/{name}/sphere", sphere, t)
        if self._follow:
            start = self._pattern.com([0.0])[0][0]
            lateral = start[1] - com[1] if self._pattern_lateral else 0.0  # turning / side-stepping walks
            shift = RigidTransform([start[0] - com[0], lateral, 0.0])
            for path in self._follow:
                m.SetTransform(path, shift, t)

    def _switch_polygon(self, plan, t):
        """Show the polygon of ``t``; hide the one of the previous publish."""
        m = self._meshcat
        vertices = support_vertices(self._pattern, plan, t)
        path = f"{self._prefix}/support/{_polygon_key(vertices)}"
        if not m.HasPath(path):
            m.SetLine(path, _loop(vertices, 0.005), 3.0, _POLYGON_RGBA)
            m.SetProperty(path, "visible", False, 0.0)
        if t > 0.0:
            previous = support_vertices(self._pattern, plan, t - self._period)
            old = f"{self._prefix}/support/{_polygon_key(previous)}"
            if old != path:
                m.SetProperty(old, "visible", False, t)
        m.SetProperty(path, "visible", True, t)

    def _show_one_step(self, context, t):
        """Show the indicator of the ``one_step_feasible`` input, hide the other."""
        if not self.one_step_feasible_port.HasValue(context):
            return
        feasible = bool(self.one_step_feasible_port.Eval(context)[0] > 0.5)
        for value, (name, _, _) in ONE_STEP_INDICATOR.items():
            self._meshcat.SetProperty(f"{self._prefix}/one_step/{name}", "visible", value == feasible, t)

    def _switch_phase(self, context, plan, t):
        phase = PHASES[int(round(self.phase_port.Eval(context)[0]))]
        previous = plan.phase(t - self._period) if plan is not None and t > 0 else "walking"
        m, p = self._meshcat, f"{self._prefix}/phase"
        if previous != phase:
            m.SetProperty(f"{p}/{previous}", "visible", False, t)
        m.SetProperty(f"{p}/{phase}", "visible", True, t)


def _rgb(colour):
    """(r, g, b) in [0, 1] of a "#rrggbb" colour."""
    return tuple(int(colour[i:i + 2], 16) / 255.0 for i in (1, 3, 5))


def set_side_camera(meshcat, x_center=1.2):
    """Look at the walk from the robot's right side, slightly above."""
    meshcat.SetCameraPose(np.array([x_center, -3.6, 1.6]), np.array([x_center, 0.0, 0.7]))


def follow_camera_paths(robot_prefix="robot", prefix=PREFIX):
    """Meshcat paths a follow camera slides: the robot, the stop's drawings and the grid."""
    return (f"/drake/{robot_prefix}", prefix, "/Grid")


def set_follow_camera(meshcat, pattern, *, scale=1.0):
    """Frame the robot at its start, from the front right and slightly above; ``scale`` (dimensionless):
    the robot's height over the default humanoid's (the camera's distance and heights scale with it)."""
    x0 = float(pattern.com([0.0])[0][0, 0])
    meshcat.SetCameraPose(np.array([x0 + 0.6 * scale, -1.3 * scale, 1.05 * scale]), np.array([x0, 0.0, 0.74 * scale]))


def add_floor(meshcat, length=4.0, prefix=PREFIX, *, width=1.5, center_y=0.0):
    """A thin floor plate under the walk (for contrast in replays): from x = -0.5 m, ``length``
    long and ``width`` wide around ``center_y`` [m]."""
    meshcat.SetObject(f"{prefix}/floor", Box(length, width, 0.01), Rgba(0.93, 0.93, 0.9, 1.0))
    meshcat.SetTransform(f"{prefix}/floor", RigidTransform([length / 2 - 0.5, center_y, -0.006]))


def add_floor_under(meshcat, pattern, prefix=PREFIX):
    """:func:`add_floor` sized to cover every footstep of ``pattern`` (turning walks included)."""
    ends = np.array([step["end"] for step in pattern.steps] + list(pattern.initial_feet.values()))
    low, high = ends.min(axis=0), ends.max(axis=0)
    add_floor(meshcat, length=high[0] + 1.5 - min(low[0], 0.0), prefix=prefix,
              width=max(1.5, high[1] - low[1] + 1.0), center_y=0.5 * (low[1] + high[1]))


# --------------------------------------------------------------------------
# Paper-style figures (matplotlib, Agg).


def _phase_lines(ax, plan):
    """Dotted verticals at the signal and the phase boundaries."""
    ax.axvline(plan.signal_time, color="k", lw=1.0, ls="--", label="stop signal")
    for t in (plan.landing_time, plan.transition_end, plan.slowdown_end, plan.halt_end):
        ax.axvline(t, color="0.6", lw=0.8, ls=":")


def _pyplot():
    """``matplotlib.pyplot`` on the Agg backend (files, no display)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(plt, fig, path):
    """Lay ``fig`` out, write it to ``path`` (PNG, 120 dpi), close it; returns ``path``."""
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_cog_zmp(times, com, zmp, plan, path, title):
    """COG and ZMP against time, x and y, with the signal and the phase boundaries (paper Fig. 9 / Fig. 12).

    Parameters
    ----------
    times : numpy.ndarray
        (n,) [s].
    com, zmp : numpy.ndarray
        (n, 2) COG and ZMP, x and y [m].
    plan : StopPlan
        Its signal and phase boundaries are drawn.
    path : str or pathlib.Path
        The PNG written.
    title : str
        The figure's title.

    Returns
    -------
    str or pathlib.Path
        ``path``.
    """
    plt = _pyplot()
    fig, axes = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    for axis, ax in enumerate(axes):
        ax.plot(times, com[:, axis], "b-", label="COG")
        ax.plot(times, zmp[:, axis], "r--", label="ZMP")
        _phase_lines(ax, plan)
        ax.set_ylabel(f"{'xy'[axis]} [m]")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper left")
    axes[0].set_title(title)
    axes[1].set_xlabel("time [s]")
    return _save(plt, fig, path)


def plot_knees(knees: dict, plan, path, title):
    """Knee angles of both legs for several runs (paper Fig. 10).

    Parameters
    ----------
    knees : dict
        A run's label -> ``(times [s], {"left": angles, "right": angles})``, the angles [rad].
    plan : StopPlan
        Its signal and phase boundaries are drawn.
    path : str or pathlib.Path
        The PNG written.
    title : str
        The figure's title.

    Returns
    -------
    str or pathlib.Path
        ``path``.
    """
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
    styles = {"left": "-", "right": "--"}
    for label, (times, angles) in knees.items():
        for side in ("left", "right"):
            ax.plot(times, np.degrees(angles[side]), styles[side], label=f"{side} knee, {label}")
    _phase_lines(ax, plan)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("knee angle [deg]")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _save(plt, fig, path)


def describe(result):
    """One-paragraph text summary of a DiagramResult (for scripts)."""
    plan, errors = result.plan, result.error_summary()
    return (f"signal {plan.signal_time:.3f} s ({plan.support} support) -> {plan.case}; "
            f"landing {plan.landing_time:.3f}, transition {plan.transition_end:.3f}, "
            f"slowdown {plan.slowdown_end:.3f}, halt {plan.halt_end:.3f} s; "
            f"latch {result.plan_wall_time * 1e3:.2f} ms in the diagram (plan {plan.compute_time * 1e3:.2f} ms); "
            f"IK max COG {errors['ik_com_err_max_m'] * 1e3:.3f} mm, foot "
            f"{errors['ik_foot_err_max_m'] * 1e3:.3f} mm / {errors['ik_foot_rot_err_max_rad']:.1e} rad, "
            f"ticks over bounds {errors['ik_ticks_over_bounds']}, velocity-limit violations "
            f"{errors['velocity_limit_violations']}; whole-body ZMP margin {_mm(errors['multibody_zmp_margin_min_m'])} "
            f"(stop {_mm(errors['stop_multibody_zmp_margin_min_m'])}); real-time factor {result.realtime_factor:.1f}")


def _mm(value) -> str:
    return "n/a" if value is None else f"{value * 1e3:.1f} mm"
