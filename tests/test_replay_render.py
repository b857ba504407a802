"""The HTML replay rendered in headless Chromium shows the robot (issue: Meshcat replay).

Needs Debian's chromium (``.ci/run`` installs it); without it these tests are
skipped with that reason.
"""

import warnings

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
