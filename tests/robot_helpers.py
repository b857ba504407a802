"""Whether the robots extra (example-robot-data and trimesh: the G1 and TALOS models) is installed, and the
mark that skips a test without it, naming the extra."""

import importlib.metadata
import importlib.util

import pytest

try:
    importlib.metadata.distribution("example-robot-data")
    HAVE_ROBOTS = importlib.util.find_spec("trimesh") is not None
except importlib.metadata.PackageNotFoundError:
    HAVE_ROBOTS = False
needs_robots = pytest.mark.skipif(not HAVE_ROBOTS,
                                  reason="the robots extra is not installed (pip install -e '.[robots]')")
