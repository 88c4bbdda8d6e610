"""The README's Python example runs and prints what its comments say."""

from __future__ import annotations

import pathlib
import re
import subprocess
import sys

README = pathlib.Path(__file__).resolve().parents[1] / "README.md"


def test_readme_example_runs():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), re.DOTALL)
    assert blocks, "README.md has no python example"
    result = subprocess.run([sys.executable, "-c", blocks[0]], capture_output=True, text=True,
                            timeout=300, check=False)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0].split()[0].startswith(("0.2", "0.19999")) and lines[0].endswith("[1. 0.]")
    assert re.fullmatch(r"\[\s*0\.75\s+0\.4045\d*\s+-1\.5\s*\]", lines[1]), lines[1]
    assert lines[2] == "-1.0"


def test_quickstart_commands():
    text = README.read_text()
    assert 'pip install -e ".[dev]" && python -m jaxsat demo' in text
    assert "python -m pytest" in text
