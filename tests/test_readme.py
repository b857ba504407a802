"""Every ```python block of README.md runs exactly as written."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def python_blocks(text):
    """The bodies of the fenced ```python blocks of a Markdown text, in order."""
    return re.findall(r"^```python\n(.*?)^```", text, flags=re.S | re.M)


def test_the_block_finder_finds_fenced_python_only():
    text = "intro\n```python\nx = 1\n```\n```bash\nls\n```\n```python\ny = 2\n```\n"
    assert python_blocks(text) == ["x = 1\n", "y = 2\n"]


BLOCKS = python_blocks((ROOT / "README.md").read_text())


def test_the_readme_has_a_python_block():
    assert BLOCKS, "README.md has no ```python block"


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(BLOCKS)))
def test_readme_python_block_runs(index, tmp_path):
    # in a fresh interpreter from another folder: the block may import only what a user has installed
    script = tmp_path / f"readme_block_{index}.py"
    script.write_text(BLOCKS[index])
    done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True,
                          timeout=300, env=_env())
    assert done.returncode == 0, f"README block {index} failed:\n{done.stdout}\n{done.stderr}"


def _env():
    """The test's environment, with this checkout first on the path (as pytest's pythonpath)."""
    import os

    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return env


def test_the_readme_robot_description_loads_measures_and_stops(tmp_path):
    """The worked description of README.md: it loads, the joints it leaves out stand still in the reach
    measurement (the default humanoid's reach, whose description names every joint), and the diagram stops
    it at the paper's 3.4 s with the IK within 1 mm and no joint over its speed limit."""
    import json

    from drake_estop.cli import main
    from drake_estop.robots import as_robot, load_robot
    from drake_estop.robots.measure import measure_reach

    (block,) = [b for b in re.findall(r"^```yaml\n(.*?)^```", (ROOT / "README.md").read_text(), flags=re.S | re.M)
                if b.startswith("name: my_robot")]
    path = tmp_path / "my_robot.yaml"
    path.write_text(block)
    robot = load_robot(path)
    assert len(robot.upper_body_joints) < len(as_robot("default").upper_body_joints)
    mine, default = measure_reach(robot), measure_reach(as_robot("default"))
    assert mine.fore == pytest.approx(default.fore, abs=2e-3) and mine.rear == pytest.approx(default.rear, abs=2e-3)
    summary = tmp_path / "summary.json"
    assert main(["simulate", "--robot", str(path), "--summary", str(summary)]) == 0
    data = json.loads(summary.read_text())
    assert data["case"] == "one-step" and data["ik"]["ik_com_err_max_m"] < 1e-3
    assert data["ik"]["velocity_limit_violations"] == 0


def test_the_readmes_controller_section_is_the_default_controller():
    """The controller section README.md shows loads as a scenario and is ``ControllerOptions()``: every value
    it lists is the benchmarked default."""
    from drake_estop.physics.controller_options import ControllerOptions
    from drake_estop.scenario import load_scenario

    (block,) = [b for b in re.findall(r"^```yaml\n(.*?)^```", (ROOT / "README.md").read_text(), flags=re.S | re.M)
                if b.startswith("controller:")]
    assert load_scenario(text=block).controller == ControllerOptions()
