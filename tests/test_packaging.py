"""Packaging: the model ships in the wheel, and nothing needs the network.

``DRAKE_ALLOW_NETWORK=meshcat`` is Drake's setting for machines without
downloads; with it, Drake's default PackageMap (remote ``drake_models``) makes
a plain ``Parser`` throw.  The wheel test builds with pip (build isolation
fetches setuptools, so it needs the package index, as the install does).
"""

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from pydrake.multibody.plant import MultibodyPlant

import drake_estop
from drake_estop.model import MODEL_PATH, load_humanoid, offline_parser
from drake_estop.planning.lipm import GRAVITY

ROOT = Path(drake_estop.__file__).resolve().parents[1]
OFFLINE = "meshcat"


def test_load_humanoid_with_network_denied(monkeypatch):
    monkeypatch.setenv("DRAKE_ALLOW_NETWORK", OFFLINE)
    plant = MultibodyPlant(0.0)
    assert offline_parser(plant).package_map().size() == 0
    load_humanoid(plant)
    plant.Finalize()
    assert plant.num_actuators() == 30
    assert list(plant.gravity_field().gravity_vector()) == [0.0, 0.0, -GRAVITY]
    # the variable is back as the user set it (lifted only while the Parser is made)
    assert os.environ["DRAKE_ALLOW_NETWORK"] == OFFLINE


def test_simulate_command_with_network_denied(tmp_path):
    """A short diagram run (parses the humanoid) in a fresh process, from another folder."""
    env = dict(os.environ, DRAKE_ALLOW_NETWORK=OFFLINE,
               PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    summary = tmp_path / "summary.json"
    done = subprocess.run(
        [sys.executable, "-m", "drake_estop.cli", "simulate", "--num-steps", "3", "--estop-time", "1.2",
         "--after-halt", "1", "--summary", str(summary)],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "PackageMap" not in done.stderr
    assert "whole-body IK" in done.stdout
    assert json.loads(summary.read_text())["ik"]


def test_model_found_in_the_checkout():
    assert MODEL_PATH.is_file()
    assert MODEL_PATH.parent.name == "models"
    assert (MODEL_PATH.parent / "README.md").is_file()


def test_wheel_contains_the_model(tmp_path):
    """``pip wheel .`` puts models/ into the wheel as drake_estop/models/.

    Built from a copy of the sources, so that no stale ``build/`` folder of the
    checkout leaks into the wheel and the checkout gets none.
    """
    source = tmp_path / "source"
    skip = shutil.ignore_patterns("__pycache__", "*.pyc")
    for folder in ("drake_estop", "models"):
        shutil.copytree(ROOT / folder, source / folder, ignore=skip)
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, source / name)
    done = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", str(source), "--no-deps", "-q", "-w", str(tmp_path / "dist")],
        capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    (wheel,) = (tmp_path / "dist").glob("drake_estop-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    assert {"drake_estop/models/humanoid.urdf", "drake_estop/models/README.md"} <= names
    assert "drake_estop/model.py" in names
    # the campaign subpackage and its default config (package data, read through importlib.resources)
    assert {"drake_estop/campaign/runner.py", "drake_estop/campaign/default.yaml"} <= names
    urdf = zipfile.ZipFile(wheel).read("drake_estop/models/humanoid.urdf")
    assert urdf == MODEL_PATH.read_bytes()


@pytest.mark.parametrize("name", ["package://", "file://", "<mesh"])
def test_model_references_no_other_file(name):
    """The wheel ships only humanoid.urdf (and README.md): the model must need nothing else."""
    assert name not in MODEL_PATH.read_text()
