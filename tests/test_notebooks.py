"""The notebooks of docs/notebooks run from top to bottom (nbclient, the virtual environment's ``python3``
kernel), each in a folder of its own, as a user opening it would; their cells' asserts are part of the test.
None is committed with outputs."""
import nbformat
import pytest

from opalflow.resources import ROOT

NOTEBOOKS = sorted((ROOT / "docs" / "notebooks").glob("*.ipynb"))


def test_every_notebook_is_on_the_notebooks_page():
    page = (ROOT / "docs" / "tutorials" / "notebooks.md").read_text()
    assert NOTEBOOKS and all(f"<../notebooks/{p.name}>" in page for p in NOTEBOOKS)


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs_to_the_end(path, tmp_path):
    from nbclient import NotebookClient

    nb = nbformat.read(path, as_version=4)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert not [c for c in code if c.outputs or c.execution_count], f"{path.name} is committed with outputs"
    NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}).execute()
    assert all(c.execution_count for c in code)
    assert not [o for c in code for o in c.outputs if o.output_type == "error"]
    pictures = [o for c in code for o in c.outputs if "image/png" in o.get("data", {})]
    assert pictures, f"{path.name} drew no picture"
    assert list(tmp_path.glob("runs/*/summary.json")) or list(tmp_path.glob("runs/*/*/summary.json"))
