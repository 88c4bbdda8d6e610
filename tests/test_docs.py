"""The documentation site and the notebooks it renders.

`mkdocs build --strict` (mkdocs.yml) executes every notebook in notebooks/ through
mkdocs-jupyter, so one build checks that the notebooks run, that every docstring of the API
reference parses and matches its signature, and that every link between pages resolves.
"""

from __future__ import annotations

import json
import os
import pathlib
import re
import subprocess
import sys

import pytest

import jaxsat

nbformat = pytest.importorskip("nbformat")

ROOT = pathlib.Path(__file__).resolve().parents[1]
NOTEBOOK_DIR = ROOT / "notebooks"
NOTEBOOKS = sorted(NOTEBOOK_DIR.glob("*.ipynb"))
API_PAGES = sorted((ROOT / "docs" / "api").glob("*.md"))


@pytest.fixture
def python3_kernel(tmp_path, monkeypatch) -> str:
    """A `python3` kernelspec that runs this interpreter, first on JUPYTER_PATH.

    Without it, `python3` could resolve to a kernel registered for another Python (the user's
    or the system's) that lacks jaxsat or has different versions installed.
    """
    spec_dir = tmp_path / "kernels" / "python3"
    spec_dir.mkdir(parents=True)
    spec = {
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "Python 3 (jaxsat tests)",
        "language": "python",
    }
    (spec_dir / "kernel.json").write_text(json.dumps(spec))
    paths = [str(tmp_path), *filter(None, [os.environ.get("JUPYTER_PATH")])]
    monkeypatch.setenv("JUPYTER_PATH", os.pathsep.join(paths))
    return "python3"


def test_there_are_notebooks():
    assert NOTEBOOKS, f"no notebooks found in {NOTEBOOK_DIR}"


def test_kernel_runs_this_interpreter(python3_kernel):
    pytest.importorskip("ipykernel")
    from jupyter_client.kernelspec import KernelSpecManager

    assert KernelSpecManager().get_kernel_spec(python3_kernel).argv[0] == sys.executable


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda path: path.name)
def test_notebook_is_saved_without_outputs(path):
    notebook = nbformat.read(path, as_version=4)
    for index, cell in enumerate(notebook.cells):
        if cell.cell_type == "code":
            assert not cell.outputs and cell.execution_count is None, (
                f"{path.name} cell {index} has saved outputs; clear them before committing")


def test_every_public_name_has_one_api_entry():
    entries = [name for page in API_PAGES
               for name in re.findall(r"^::: jaxsat\.(\w+)$", page.read_text(), re.MULTILINE)]
    assert sorted(entries) == sorted(jaxsat.__all__), (
        "docs/api/*.md should hold one '::: jaxsat.NAME' line per name of jaxsat.__all__")


def test_every_notebook_is_in_the_site_navigation():
    config = (ROOT / "mkdocs.yml").read_text()
    for path in NOTEBOOKS:
        assert f": notebooks/{path.name}" in config, f"{path.name} is missing from mkdocs.yml nav"


def test_readme_says_how_to_build_and_serve_the_docs():
    readme = (ROOT / "README.md").read_text()
    assert "mkdocs build --strict" in readme
    assert "mkdocs serve" in readme


@pytest.mark.slow  # executes every notebook: about two minutes on 2 cores
def test_site_builds_strictly_with_executed_notebooks(tmp_path, python3_kernel):
    for module in ("mkdocs", "mkdocstrings_handlers.python", "mkdocs_jupyter", "ipykernel"):
        pytest.importorskip(module)
    site = tmp_path / "site"
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
        cwd=ROOT, capture_output=True, text=True, timeout=900, check=False,
        env={**os.environ, "MPLBACKEND": "Agg", "NO_MKDOCS_2_WARNING": "1"})
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-8000:]

    # The notebooks ran: their pages hold outputs, and each one's figures as images.
    for path in NOTEBOOKS:
        page = (site / "notebooks" / path.stem / "index.html").read_text()
        assert 'class="jp-OutputArea' in page, f"{path.name} rendered without outputs"
        assert "data:image/png;base64," in page, f"{path.name} rendered without a figure"
    # The API reference comes from the docstrings, and the README is the home page.
    queries = (site / "api" / "queries" / "index.html").read_text()
    assert jaxsat.penetration.__doc__.splitlines()[0].split(":")[0] in queries
    home = (site / "index.html").read_text()
    assert "Quickstart" in home
    # mkdocs --strict lets a link to an excluded file through: check the pictures directly.
    pictures = re.findall(r'<img [^>]*src="([^"]+)"', home)
    assert len(pictures) >= 3, pictures
    for source in pictures:
        assert (site / source).is_file(), f"the home page shows {source}, not in the site"
    assert "On a GPU" in (site / "gpu" / "index.html").read_text()
