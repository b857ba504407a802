"""The HTML replay rendered in headless Chromium shows the robot (issue: Meshcat replay).

Needs Debian's chromium (``.ci/run`` installs it); without it these tests are
skipped with that reason.
"""

import importlib.util
import warnings

import numpy as np
import pytest
from scripts import load_script

from drake_estop.planning.gait import GaitParameters
from drake_estop.planning.planner import StopParameters
from drake_estop.systems.diagram import simulate_diagram
from drake_estop.systems.visualization import add_floor, make_meshcat, write_replay


def _renderer():
    return load_script("diagrams/render_replay.py")


RENDER = _renderer()
CHROMIUM = RENDER.find_chromium()
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="Debian chromium not installed")


def test_replay_shows_the_robot(tmp_path):
    html = tmp_path / "replay.html"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        simulate_diagram(GaitParameters(), StopParameters(), 3.5, html=str(html), after_halt=1.0)
    png = tmp_path / "replay.png"
    RENDER.screenshot(html, png, chromium=CHROMIUM)
    assert RENDER.robot_pixels(png) >= 800


def test_empty_scene_is_not_taken_for_the_robot(tmp_path):
    meshcat = make_meshcat()
    add_floor(meshcat, length=3.0)
    meshcat.StartRecording()
    meshcat.StopRecording()
    html = write_replay(meshcat, tmp_path / "empty.html")
    png = tmp_path / "empty.png"
    RENDER.screenshot(html, png, chromium=CHROMIUM)
    assert RENDER.robot_pixels(png) < 800


# the trace and polygon colours of drake_estop.systems.visualization (0-255)
ZMP_TRACE_GREEN = (26, 179, 51)
POLYGON_MAGENTA = (217, 26, 217)


@pytest.fixture(scope="module")
def stop_replay(tmp_path_factory):
    """The replay `drake-estop simulate --html` writes for the paper's 3.4 s stop."""
    html = tmp_path_factory.mktemp("replay") / "replay.html"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        result = simulate_diagram(GaitParameters(), StopParameters(), 3.4, html=str(html), after_halt=1.0)
    assert result.times[-1] < 8.0  # the end screenshot below lets 10 s of virtual time play it out
    return html


@pytest.mark.parametrize("moment, budget_ms", [("start", 1000), ("end", 10000)])
def test_camera_frames_the_robot_at_the_start_and_the_end(stop_replay, tmp_path, moment, budget_ms):
    """The robot fills >= 40 % of the frame height as the replay opens and after it has played to the
    halt (1.3 m further on), and stays in the middle of the frame: the camera follows it. (Measured
    without the follow: at the end the robot has walked up to the camera, cut off at the top, its
    centre at 74 % of the frame width.) The COG/ZMP traces are in view; at the end, with the feet
    apart, so is the support polygon."""
    png = tmp_path / f"{moment}.png"
    # headless Chromium sometimes hangs (see screenshot()); a normal 10 s render takes 10-15 s here
    RENDER.screenshot(stop_replay, png, chromium=CHROMIUM, budget_ms=budget_ms, timeout=90, attempts=3)
    top, bottom, left, right = RENDER.robot_box(png)
    share, centre = bottom - top, 0.5 * (left + right)
    print(f"{moment}: robot (blue parts) {share:.1%} of the frame height, centred at {centre:.1%} of its width")
    assert share >= 0.40
    assert 0.35 <= centre <= 0.65
    assert RENDER.colour_pixels(png, ZMP_TRACE_GREEN) >= 50
    if moment == "end":
        assert RENDER.colour_pixels(png, POLYGON_MAGENTA) >= 30


def test_height_share_ignores_thin_blue_lines(tmp_path):
    import matplotlib.image as mpimg
    import numpy as np

    image = np.full((100, 100, 3), 0.8)
    image[10:90, 50, :] = (0.1, 0.3, 0.9)  # a 1 px blue line, like the COG trace
    image[40:60, 20:30, :] = (0.15, 0.3, 0.75)  # a 20 px tall blue limb
    mpimg.imsave(tmp_path / "synthetic.png", image)
    assert RENDER.robot_height_share(tmp_path / "synthetic.png") == pytest.approx(0.20)


def test_live_view_frames_the_robot(tmp_path):
    """The live Meshcat page (what --meshcat prints) opens on the robot too, here mid-stop."""
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder

    from drake_estop import AddEmergencyStop

    meshcat = make_meshcat()
    builder = DiagramBuilder()
    AddEmergencyStop(builder, estop_time=3.4, meshcat=meshcat, log=False)
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(3.75)  # the slowdown, 1.2 m from where the walk started
    png = tmp_path / "live.png"
    RENDER.screenshot(meshcat.web_url(), png, chromium=CHROMIUM, budget_ms=3000, timeout=90, attempts=3)
    share = RENDER.robot_height_share(png)
    print(f"live view: robot (blue parts) {share:.1%} of the frame height")
    assert share >= 0.40


@pytest.mark.skipif(importlib.util.find_spec("trimesh") is None, reason="the robots extra is not installed")
@pytest.mark.parametrize("robot, estop_time", [("g1", 3.37), ("talos", 3.4)])
def test_another_robot_s_replay_shows_its_meshes(tmp_path, robot, estop_time):
    """The G1's (TALOS's) replay rendered with its robot and with the robot deleted from the same scene: what
    differs in the middle of the frame (where the follow camera keeps the robot) is its meshes, a figure that
    spans over 40 % of the frame height. (Measured: G1 22,600 pixels over 86 % of the height, TALOS 53,900
    over 83 %, the one-step indicator over the head included.)"""
    meshcat = make_meshcat()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        simulate_diagram(estop_time=estop_time, robot=robot, html=str(tmp_path / f"{robot}.html"), meshcat=meshcat)
    meshcat.Delete("/drake/robot")
    (tmp_path / "bare.html").write_text(meshcat.StaticHtml())
    images = []
    for name in (robot, "bare"):
        RENDER.screenshot(tmp_path / f"{name}.html", tmp_path / f"{name}.png", chromium=CHROMIUM, budget_ms=1000,
                          timeout=90, attempts=3)
        images.append(RENDER._image(tmp_path / f"{name}.png"))
    differs = np.abs(images[0] - images[1]).max(axis=2) > 40
    height, width = differs.shape
    middle = differs[:, int(0.42 * width):int(0.62 * width)]
    rows = np.flatnonzero(middle.any(axis=1))
    print(f"{robot}: {middle.sum()} pixels differ in the middle, over {np.ptp(rows) / height:.0%} of the height")
    assert middle.sum() >= 8000 and np.ptp(rows) >= 0.4 * height
