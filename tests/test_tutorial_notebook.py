"""CI executes diagrams/tutorial.ipynb: every cell runs, in a fresh kernel, as written."""

import os
import time
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOK = ROOT / "diagrams" / "tutorial.ipynb"


def test_the_tutorial_is_committed_without_outputs():
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    stale = [i for i, cell in enumerate(notebook.cells)
             if cell.cell_type == "code" and (cell.outputs or cell.execution_count)]
    assert not stale, f"cells {stale} carry outputs; clear them before committing"


@pytest.mark.slow
def test_the_tutorial_runs(tmp_path, monkeypatch):
    # the kernel imports this checkout (as pytest's pythonpath does), from a scratch folder
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    monkeypatch.setenv("MPLBACKEND", "module://matplotlib_inline.backend_inline")
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    start = time.perf_counter()
    NotebookClient(notebook, timeout=240, kernel_name="python3",
                   resources={"metadata": {"path": str(tmp_path)}}).execute()
    elapsed = time.perf_counter() - start
    print(f"tutorial executed in {elapsed:.1f} s")
    outputs = [out for cell in notebook.cells if cell.cell_type == "code" for out in cell.outputs]
    assert not [out for out in outputs if out.output_type == "error"]
    images = [out for out in outputs if "image/png" in out.get("data", {})]
    assert len(images) >= 3, "the walk, the four phases and the stop map should each draw a figure"
    text = "".join(out.get("text", "") for out in outputs)
    assert "-> one-step" in text and "stop within one step" in text
    assert any("text/html" in out.get("data", {}) and "<iframe srcdoc=" in out["data"]["text/html"]
               for out in outputs), "the Meshcat replay is not shown inline"


@pytest.mark.parametrize("broken", ["raise RuntimeError('boom')"])
def test_a_failing_cell_fails_the_run(tmp_path, broken):
    from nbclient.exceptions import CellExecutionError

    notebook = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(broken)])
    with pytest.raises(CellExecutionError, match="boom"):
        NotebookClient(notebook, timeout=60, kernel_name="python3",
                       resources={"metadata": {"path": str(tmp_path)}}).execute()
