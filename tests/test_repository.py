"""The repository as a product: the files say what the software is and does, not how it came to be
(history lives in ``git log``); the README is a user's guide; modules stay by concern and readable."""

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README_LIMIT = 25_000  # [characters] a user's guide, not a record
MODULE_LIMIT = 700  # [lines] a module or test file beyond this mixes concerns
HISTORY = re.compile(r"\b(session|issue)s? ?#?\d+", re.I)
TEXT_SUFFIXES = {".py", ".md", ".yaml", ".yml", ".toml", ".json", ".csv", ".txt", ".ipynb", ".sh", ".dot", ".svg",
                 ".html", ""}


def tracked_files():
    try:
        listed = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout (an unpacked sdist or wheel has no history to check)")
    return [ROOT / name for name in listed.split("\n") if name]


def history_mentions(text: str) -> list:
    """The "session N" / "issue N" mentions of a text."""
    return [m.group(0) for m in HISTORY.finditer(text)]


def test_the_history_check_sees_a_mention():
    session, issue = "session", "Issue"  # spelled apart so that this file holds no mention itself
    text = f"as {session} 19's analysis found; {issue} 13 tracked both; {issue.lower()} #4"
    assert history_mentions(text) == [f"{session} 19", f"{issue} 13", f"{issue.lower()} #4"]
    assert history_mentions("the session's tests; an issue named the limit; 3 sessions") == []


def test_no_development_history_in_tracked_files():
    found = {}
    for path in tracked_files():
        if path.suffix not in TEXT_SUFFIXES or not path.is_file():
            continue
        mentions = history_mentions(path.read_text(errors="replace"))
        if mentions:
            found[str(path.relative_to(ROOT))] = mentions[:3]
    assert not found, f"development history in tracked files (it belongs in git log): {found}"


def test_the_readme_is_a_users_guide():
    text = (ROOT / "README.md").read_text()
    assert len(text) <= README_LIMIT, f"README.md has {len(text)} characters, over {README_LIMIT}"
    for heading in ("## Two commands", "## Results", "## Architecture", "## Known limits"):
        assert heading in text


def test_modules_and_test_files_stay_readable():
    files = sorted((ROOT / "drake_estop").rglob("*.py")) + sorted((ROOT / "tests").glob("*.py"))
    long = {str(p.relative_to(ROOT)): n for p in files if (n := len(p.read_text().splitlines())) > MODULE_LIMIT}
    assert not long, f"over {MODULE_LIMIT} lines: {long}"


#: The controller path: a function there longer than this is read in more than one screen.
CONTROLLER_FUNCTION_LIMIT = 80  # [lines], from its def to its last line, the docstring included


def test_no_function_in_the_controller_path_is_longer_than_a_screen():
    import ast

    paths = [*(ROOT / "drake_estop" / "physics").glob("*.py"), *(ROOT / "drake_estop" / "systems").glob("*.py"),
             *(ROOT / "drake_estop" / "planning" / name for name in (
                 "replan.py", "capture.py", "capture_landing.py", "crossover.py", "recovery.py", "capturability.py"))]
    long = {}
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef) and node.end_lineno - node.lineno + 1 > CONTROLLER_FUNCTION_LIMIT:
                long[f"{path.relative_to(ROOT)}:{node.name}"] = node.end_lineno - node.lineno + 1
    assert not long, f"over {CONTROLLER_FUNCTION_LIMIT} lines: {long}"
