"""The README's Python example runs and prints what its comments say."""

from __future__ import annotations

import pathlib
import re
import subprocess
import sys
import textwrap

import pytest

README = pathlib.Path(__file__).resolve().parents[1] / "README.md"


def _run_example(index: int, what: str) -> list[str]:
    """Run the README's python block `index` in a fresh interpreter; its output lines."""
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), re.DOTALL)
    assert len(blocks) > index, f"README.md has no {what} example"
    # A block inside a list item is indented; run it as written at the left margin.
    result = subprocess.run([sys.executable, "-c", textwrap.dedent(blocks[index])],
                            capture_output=True, text=True, timeout=300, check=False)
    assert result.returncode == 0, result.stderr
    return result.stdout.splitlines()


@pytest.mark.slow  # a fresh interpreter compiles the example's queries: about 12 s
def test_readme_example_runs():
    lines = _run_example(0, "python")
    assert lines[0].split()[0].startswith(("0.2", "0.19999")) and lines[0].endswith("[1. 0.]")
    assert re.fullmatch(r"\[\s*0\.75\s+0\.4045\d*\s+-1\.5\s*\]", lines[1]), lines[1]
    assert lines[2] == "-1.0"


@pytest.mark.slow
def test_readme_signed_distance_example_runs():
    lines = _run_example(1, "signed-distance")
    assert abs(float(lines[0]) - 2**0.5) < 1e-6
    assert float(lines[1]) == -1.0
    assert re.fullmatch(r"\[1\.\s+1\.\]\s+\[2\.\s+2\.\]", lines[2]), lines[2]
    assert abs(float(lines[3]) - 0.5**0.5) < 1e-6
    assert abs(float(lines[4]) - 0.48676717) < 1e-5
    assert lines[5] == "True"


@pytest.mark.slow
def test_readme_rounded_example_runs():
    distance, depth, overlap, points, resting = _run_example(2, "rounded-shapes")[0].split()
    assert abs(float(distance) - 1.25) < 1e-6 and abs(float(depth) - 0.1) < 1e-6
    assert overlap == "True"
    assert points == "2" and abs(float(resting) - 0.05) < 1e-6


def test_quickstart_commands():
    text = README.read_text()
    assert 'pip install -e ".[dev]" && python -m jaxsat demo' in text
    assert "python -m pytest" in text
    quickstart = text.split("## Quickstart", 1)[1].split("\n## ", 1)[0]
    assert "virtual environment" in quickstart and "python -m venv" in quickstart
    assert re.search(r"\d+-\d+ minutes", quickstart), "say how long the tests take"


@pytest.mark.slow
def test_readme_scene_example_runs():
    lines = _run_example(3, "scene")
    assert lines[0] == "4 [0.1 0.1 0.1 0.1] [0. 0. 1.]", lines[0]
    assert lines[1] == "0 25", lines[1]
    assert lines[2] == "2 False", lines[2]


@pytest.mark.slow
def test_readme_mesh_example_runs():
    pytest.importorskip("coacd")
    assert _run_example(4, "mesh")[-1] == "True False True"
