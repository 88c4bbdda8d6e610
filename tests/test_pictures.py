"""The README's pictures: every file docs/assets/make_pictures.py makes is committed there as
a PNG of modest size, and the notebook cells it takes pictures from are still tagged.

Cheap checks only: the script itself (about 2 minutes) is not run here.
"""

from __future__ import annotations

import importlib.util
import json
import pathlib
import struct

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
ASSETS = ROOT / "docs" / "assets"
SCRIPT = ASSETS / "make_pictures.py"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def script():
    """docs/assets/make_pictures.py as a module (its top level imports the standard library
    only, and makes nothing)."""
    assert SCRIPT.is_file(), f"{SCRIPT} is missing"
    spec = importlib.util.spec_from_file_location("make_pictures", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _png_size(data: bytes) -> tuple[int, int]:
    """(width, height) from a PNG's header chunk."""
    assert data[:8] == PNG_SIGNATURE, "not a PNG"
    assert data[12:16] == b"IHDR", "no IHDR chunk first"
    return struct.unpack(">II", data[16:24])


def test_the_script_makes_the_readme_pictures(script):
    assert {"demo.png", "runtime_vs_error.png", "trajectory.png"} <= set(script.PICTURES)
    assert script.ASSETS == ASSETS


def test_every_picture_is_committed_as_a_modest_png(script):
    for name in script.PICTURES:
        path = ASSETS / name
        assert path.is_file(), f"{path} is missing: python docs/assets/make_pictures.py"
        data = path.read_bytes()
        width, height = _png_size(data)
        assert 400 <= width <= 2000 and 300 <= height <= 1200, (name, width, height)
        assert len(data) < 400_000, f"{name} is {len(data) / 1e3:.0f} KB"


def test_every_notebook_picture_comes_from_one_tagged_code_cell(script):
    notebook = json.loads(script.NOTEBOOK.read_text())
    for tag, name in script.NOTEBOOK_PICTURES.items():
        assert name in script.PICTURES, name
        cells = [cell for cell in notebook["cells"]
                 if tag in cell.get("metadata", {}).get("tags", [])]
        assert len(cells) == 1, f"{script.NOTEBOOK.name}: {len(cells)} cells tagged {tag!r}"
        assert cells[0]["cell_type"] == "code"
        assert "plt.show()" in "".join(cells[0]["source"]), "the cell draws no figure"


def test_png_size_reads_the_header():
    """The header check can fail: a wrong signature is refused, a real header read."""
    header = PNG_SIGNATURE + struct.pack(">I", 13) + b"IHDR" + struct.pack(">II", 640, 480)
    assert _png_size(header) == (640, 480)
    with pytest.raises(AssertionError, match="not a PNG"):
        _png_size(b"GIF89a" + header[6:])


def test_the_run_time_picture_reads_the_committed_results(script):
    """make_runtime_vs_error reads the committed benchmark record as runtime_vs_error.py now
    writes it: every field it plots is there, for every case and variant it draws."""
    data = json.loads(script.RUNTIME_VS_ERROR.read_text())
    assert {"machine", "config", "cases", "rows", "tau_fractions", "size"} <= set(data)
    assert {"cpu_count", "cpu_model", "versions"} <= set(data["machine"])
    assert "repeats" in data["config"]
    for case in data["cases"]:
        rows = [row for row in data["rows"] if row["case"] == case["case"]]
        assert {row["variant"] for row in rows} == set(script.VARIANTS), case["case"]
        for row in rows:
            assert row["value_best_s"] > 0 and row["pairs"] > 0, row
            assert row["value_error_max"] >= 0 and "tau_fraction" in row, row
