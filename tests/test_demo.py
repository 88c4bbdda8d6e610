"""The `python -m jaxsat demo` command: report, picture, and the command line itself."""

from __future__ import annotations

import re
import subprocess
import sys

import jax
import pytest

from jaxsat.__main__ import main

CASES = ("2d-polygons", "3d-boxes", "3d-hulls")
# case, pairs, collide, compile f32, compile f64, pairs/s, max|depth err| (all, colliding),
# max normal angle
ROW = re.compile(r"^(?P<case>\S+)\s+(?P<pairs>\d+)\s+(?P<collide>\d+)\s+[\d.]+s\s+[\d.]+s\s+"
                 r"(?P<rate>\S+)\s+(?P<depth_error>\S+)\s+(?P<hit_error>\S+)\s+(?P<angle>\S+) rad$",
                 re.MULTILINE)


@pytest.fixture(autouse=True)
def restore_x64():
    """The demo enables float64 globally; put the setting back for the other tests."""
    before = jax.config.read("jax_enable_x64")
    yield
    jax.config.update("jax_enable_x64", before)


@pytest.mark.slow
def test_demo_prints_every_case_and_saves_a_png(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    output = tmp_path / "demo.png"
    assert main(["demo", "--pairs", "64", "--repeats", "1", "--output", str(output)]) == 0
    report = capsys.readouterr().out

    assert output.is_file()
    assert output.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert f"saved picture: {output}" in report
    rows = {match["case"]: match for match in ROW.finditer(report)}
    assert set(rows) == set(CASES), report
    for case, row in rows.items():
        assert int(row["pairs"]) == 64, case
        assert 0 <= int(row["collide"]) <= 64, case
        assert float(row["rate"]) > 0, case
        # float32 against float64, shapes about 1 unit across
        assert float(row["depth_error"]) < 1e-3, case
        assert float(row["hit_error"]) < 1e-4, case
        assert float(row["angle"]) < 1e-2, case


def test_demo_without_matplotlib_explains_how_to_install_it(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # makes `import matplotlib` fail
    output = tmp_path / "demo.png"
    args = ["demo", "--pairs", "16", "--repeats", "1", "--cases", "2d-polygons",
            "--output", str(output)]
    assert main(args) == 0
    report = capsys.readouterr().out
    assert "2d-polygons" in report
    assert "jaxsat[plot]" in report
    assert not output.exists()


@pytest.mark.slow
def test_demo_no_plot_writes_nothing(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["demo", "--pairs", "16", "--repeats", "1", "--cases", "3d-boxes",
                 "--no-plot"]) == 0
    assert "3d-boxes" in capsys.readouterr().out
    assert not list(tmp_path.iterdir())


def test_no_command_prints_help(capsys):
    assert main([]) == 2
    assert "demo" in capsys.readouterr().out


@pytest.mark.parametrize("args", [["--help"], ["demo", "--help"]])
def test_help_from_the_command_line(args):
    result = subprocess.run([sys.executable, "-m", "jaxsat", *args], capture_output=True,
                            text=True, timeout=120, check=False)
    assert result.returncode == 0, result.stderr
    assert "demo" in result.stdout
    assert "usage" in result.stdout.lower()
