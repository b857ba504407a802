"""The paper-style figures (drake_estop.plot_cog_zmp, plot_knees): each writes a PNG of its size at 120 dpi and
returns its path."""

import struct

import numpy as np
import pytest

from drake_estop import plot_cog_zmp, plot_knees
from drake_estop.planning.gait import NominalPattern
from drake_estop.planning.planner import plan_stop


@pytest.fixture(scope="module")
def plan():
    return plan_stop(NominalPattern(), 3.4)


def _png_size(path):
    header = path.read_bytes()[:24]
    assert header[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", header[16:24])


def test_the_cog_zmp_figure_is_two_axes_at_120_dpi(plan, tmp_path):
    times = np.linspace(3.0, 4.5, 50)
    pos, _, _, zmp = plan.com(times)
    path = tmp_path / "cog_zmp.png"
    assert plot_cog_zmp(times, pos, zmp, plan, path, "stop at 3.4 s") == path
    assert _png_size(path) == (840, 720)  # 7 x 6 in


def test_the_knee_figure_takes_several_runs(plan, tmp_path):
    times = np.linspace(3.0, 4.5, 50)
    knees = {label: (times, {"left": np.full(50, 0.3 + k), "right": np.full(50, 0.4)})
             for k, label in enumerate(("diagram", "physics"))}
    path = tmp_path / "knees.png"
    assert plot_knees(knees, plan, path, "knees") == path
    assert _png_size(path) == (840, 480)  # 7 x 4 in
