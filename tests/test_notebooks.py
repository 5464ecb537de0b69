"""Every notebook in notebooks/ runs top to bottom (nbclient, .venv's python3 kernel, a few frames) and shows at
least one figure inline: a PNG in its outputs, which a matplotlib backend switched to Agg would never produce."""

import os
import sys
from pathlib import Path

import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


def _outputs(notebook) -> list:
    return [o for c in notebook.cells if c.cell_type == "code" for o in c.get("outputs", [])]


def _error_lines(outputs: list) -> list[str]:
    return [f"{o.ename}: {o.evalue}" for o in outputs if o.output_type == "error"]


def _images(outputs: list) -> list:
    return [o for o in outputs if o.output_type in ("display_data", "execute_result") and "image/png" in o.get("data", {})]


@pytest.mark.slow
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_executes_and_shows_a_figure(path, monkeypatch, request):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    monkeypatch.setenv("NOTEBOOK_FRAMES", "30")
    if request.config.getoption("--data-root"):  # the notebooks find it with mocap.find_data_root; absolute,
        # because the kernel runs in notebooks/ and `make test` passes a path relative to the repository
        monkeypatch.setenv("MVMOCAP_DATA_ROOT", str(Path(request.config.getoption("--data-root")).resolve()))
    # The kernel must be this interpreter (the venv with the editable install) and see the repo.
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(path.parents[1]), os.environ.get("PYTHONPATH", "")]))
    monkeypatch.setenv("PATH", os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")]))
    notebook = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(notebook, timeout=180, kernel_name="python3",
                                     resources={"metadata": {"path": str(path.parent)}})
    client.execute()
    outputs = _outputs(notebook)
    assert not _error_lines(outputs), _error_lines(outputs)
    assert _images(outputs), f"{path.name} ran but displayed no figure (no image/png output)"
