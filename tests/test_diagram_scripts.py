"""The diagrams/ scripts use the public API only: ``from drake_estop import ...``, no
``sys.path`` set-up, no machine paths; one paper scenario runs end to end."""

import ast
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted((ROOT / "diagrams").glob("*.py"))
MACHINE_PATH = re.compile(r"(/work/|/home/|/root/|/Users/|\.venv/bin|site-packages)")


def _drake_estop_imports(tree):
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "drake_estop":
            yield node.module
        elif isinstance(node, ast.Import):
            yield from (a.name for a in node.names if a.name.split(".")[0] == "drake_estop")


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_scripts_import_the_public_api_only(script):
    source = script.read_text()
    tree = ast.parse(source)
    private = [m for m in _drake_estop_imports(tree) if m != "drake_estop"]
    assert not private, f"{script.name} imports {private}; use `from drake_estop import ...`"
    assert not [n for n in ast.walk(tree) if isinstance(n, ast.Attribute) and n.attr == "path"
                and isinstance(n.value, ast.Name) and n.value.id == "sys"], f"{script.name} touches sys.path"
    assert not MACHINE_PATH.search(source), f"{script.name} names a machine path"


def test_the_check_sees_a_private_import():
    tree = ast.parse("from drake_estop.systems.diagram import simulate_diagram\nimport drake_estop.planning.planner\n")
    assert list(_drake_estop_imports(tree)) == ["drake_estop.systems.diagram", "drake_estop.planning.planner"]


def test_double_support_scenario_runs(tmp_path):
    """As a user runs it: ``python diagrams/double_support_stop.py OUT`` from another folder."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    done = subprocess.run([sys.executable, str(ROOT / "diagrams" / "double_support_stop.py"), str(tmp_path)],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "(double support) -> one-step" in done.stdout
    assert (tmp_path / "double_support_stop.html").stat().st_size > 100_000
    assert (tmp_path / "double_support_cog_zmp.png").is_file()
