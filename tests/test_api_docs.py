"""The API reference builds clean: the documented pdoc command, warnings as errors."""

import os
import subprocess
import sys
from pathlib import Path

import drake_estop

ROOT = Path(__file__).resolve().parents[1]
# the command README.md documents (with the output folder moved to the test's)
COMMAND = [sys.executable, "-W", "error", "-m", "pdoc", "-d", "numpy", "-o"]


def _pdoc(module, out, cwd):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(cwd), os.environ.get("PYTHONPATH", "")]))
    return subprocess.run([*COMMAND, str(out), module], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=300)


def test_readme_documents_the_command():
    assert "python -W error -m pdoc -d numpy -o docs/api drake_estop" in (ROOT / "README.md").read_text()


def test_api_reference_builds_without_warnings(tmp_path):
    done = _pdoc("drake_estop", tmp_path / "api", ROOT)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "Warn" not in done.stderr, done.stderr[-3000:]
    page = (tmp_path / "api" / "drake_estop.html").read_text()
    for name in drake_estop.__all__:
        assert f'id="{name}"' in page, f"{name} missing from the API reference"
    assert ".. pydrake_system::" in page and "name: StopPlannerSystem" in page


def test_a_warning_fails_the_build(tmp_path):
    """The control: a module whose __all__ names something missing makes pdoc warn, and the build fail."""
    (tmp_path / "broken_api.py").write_text('"""Broken."""\n__all__ = ["missing"]\n')
    done = _pdoc("broken_api", tmp_path / "api", tmp_path)
    assert done.returncode != 0 and "does not resolve" in done.stderr
