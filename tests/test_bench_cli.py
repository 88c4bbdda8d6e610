"""`python -m jaxsat bench`, benchmarks/peers.py, kernels.py and distance.py on tiny cases,
without any peer package.

Peers (MJX, MuJoCo, Coal, jax2d, pymunk, collision) come with the `bench` extra, which CI does
not install: these tests force a peer to look missing and check that it is reported as skipped,
and run only jaxsat and the script's own NumPy SAT against the SciPy oracle.
"""

from __future__ import annotations

import json
import pathlib
import sys

import pytest

from jaxsat.__main__ import PEERS_SCRIPT, main, run_bench

pytestmark = pytest.mark.slow  # the fast subset is -m "not slow"

pytest.importorskip("scipy")  # the oracle of benchmarks/peers.py
BENCHMARKS = pathlib.Path(__file__).resolve().parent.parent / "benchmarks"
TINY = ["--cases", "2d-small", "--sizes", "64", "--error-pairs", "64", "--grad-pairs", "4",
        "--loop-pairs", "64", "--repeats", "1", "--pool", "16"]


@pytest.fixture
def peers(monkeypatch):
    """benchmarks/peers.py as a module, with pymunk made to look not installed."""
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    monkeypatch.setitem(sys.modules, "pymunk", None)
    import peers as module

    return module


def test_bench_help_explains_the_command(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["bench", "--help"])
    assert exit_.value.code == 0
    text = capsys.readouterr().out
    assert "peers" in text and "--full" in text and ".[bench]" in text


def test_bench_script_is_found_in_the_checkout():
    assert PEERS_SCRIPT == BENCHMARKS / "peers.py"
    assert PEERS_SCRIPT.is_file()


def test_bench_without_checkout_says_what_to_do(tmp_path, capsys):
    assert run_bench(False, [], script=tmp_path / "benchmarks" / "peers.py") == 2
    error = capsys.readouterr().err
    assert "not found" in error and 'pip install -e ".[bench]"' in error


@pytest.fixture
def fake_peers(tmp_path, monkeypatch):
    """A stand-in for benchmarks/peers.py that records the arguments it is given and runs
    nothing; returns the list of argument lists it received."""
    script = tmp_path / "fake_peers.py"
    script.write_text("RECEIVED = []\n\ndef main(argv):\n    RECEIVED.append(list(argv))\n"
                      "    return 0\n")
    monkeypatch.setattr("jaxsat.__main__.PEERS_SCRIPT", script)
    monkeypatch.setitem(sys.modules, "jaxsat_bench_peers", None)  # removed again after
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)

    def received():
        return sys.modules["jaxsat_bench_peers"].RECEIVED

    return received


def _output_prefix(argv):
    return pathlib.Path(argv[argv.index("--output") + 1]) if "--output" in argv else None


@pytest.mark.parametrize("options, directory, name", [
    (["--full"], ".", "peers-full"),                     # full run: the cwd by default
    (["--full", "--output-dir", "out"], "out", "peers-full"),
    (["--output-dir", "out/quick"], "out/quick", "peers-quick"),
    (["--cases", "2d-small", "--output-dir", "out"], "out", "peers-quick"),
])
def test_bench_writes_under_the_output_directory(fake_peers, options, directory, name):
    assert main(["bench", *options]) == 0
    (argv,) = fake_peers()
    assert ("--quick" in argv) == ("--full" not in options)
    prefix = _output_prefix(argv)
    assert prefix is not None and prefix.is_absolute()
    assert prefix == pathlib.Path.cwd().resolve() / directory / name
    assert not prefix.is_relative_to(BENCHMARKS)  # never benchmarks/results/ of the checkout


def test_quick_bench_writes_nothing_unless_asked(fake_peers):
    assert main(["bench", "--cases", "2d-small"]) == 0
    assert fake_peers() == [["--quick", "--cases", "2d-small"]]


def test_bench_passes_the_users_own_prefix_on(fake_peers, capsys):
    assert main(["bench", "--full", "--output", "mine/run"]) == 0
    assert fake_peers() == [["--output", "mine/run"]]  # as given: peers.py resolves it
    with pytest.raises(SystemExit) as exit_:
        main(["bench", "--output-dir", "out", "--output", "mine/run"])
    assert exit_.value.code == 2
    assert "not both" in capsys.readouterr().err


def test_other_commands_still_reject_unknown_arguments(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["demo", "--no-such-option"])
    assert exit_.value.code == 2
    assert "unrecognized arguments" in capsys.readouterr().err


def test_list_reports_a_missing_peer(peers, capsys):
    assert peers.main(["--list"]) == 0
    lines = {line.split()[0]: line for line in capsys.readouterr().out.splitlines()[1:]}
    assert set(peers.METHODS) <= set(lines)
    assert "missing pymunk (pip install pymunk)" in lines["pymunk"]
    assert lines["jaxsat"].endswith("installed")


def test_bench_runs_quick_peers_and_skips_missing_ones(peers, tmp_path, capsys):
    prefix = tmp_path / "peers"
    argv = ["bench", *TINY, "--methods", "numpy-sat-f32", "numpy-sat-f64", "pymunk",
            "--output", str(prefix)]
    assert main(argv) == 0
    table = capsys.readouterr().out
    assert "| 2d-small | numpy-sat-f64 | depth+normal | float64 |" in table
    assert "not installed: pymunk" in table
    result = json.loads(prefix.with_name("peers.json").read_text())
    assert result["config"]["quick"] is True
    assert len(result["machine"]["load_average_start"]) == 3
    rows = {row["method"]: row for row in result["rows"]}
    assert "skipped" in rows["pymunk"]
    exact, single = rows["numpy-sat-f64"]["errors"], rows["numpy-sat-f32"]["errors"]
    assert exact["overlapping"] > 10 and exact["wrong_overlap"] == 0
    assert exact["depth_error_max"] < 1e-12 and exact["normal_error_max_deg"] < 1e-9
    assert single["depth_error_max"] < 1e-5
    assert rows["numpy-sat-f64"]["sizes"]["64"]["pairs_per_second"] > 0
    assert (tmp_path / "peers.md").read_text().count("| 2d-small |") == 3


def test_jaxsat_rows_match_the_oracle_with_gradients(peers, tmp_path):
    prefix = tmp_path / "jaxsat"
    assert peers.main([*TINY, "--methods", "jaxsat", "--output", str(prefix)]) == 0
    row = json.loads(prefix.with_name("jaxsat.json").read_text())["rows"][0]
    errors = row["errors"]
    assert row["precision"] == "float32" and row["gradients"] == "jax.grad"
    assert errors["wrong_overlap"] == 0 and errors["depth_error_max"] < 1e-5
    assert errors["normal_error_max_deg"] < 1e-3
    assert errors["grad_pairs"] == 4 and errors["grad_error_max"] < 1e-4
    assert row["setup_s"] > 0


def test_chunked_jaxsat_row_matches_the_oracle(peers, tmp_path):
    # 64 pairs in chunks of 8192 are one plain vmap; 3d-hulls chunks by 256, so use 300 pairs.
    prefix = tmp_path / "chunked"
    argv = [*TINY, "--methods", "jaxsat-chunked", "--output", str(prefix)]
    argv[argv.index("--cases") + 1] = "3d-hulls"
    argv[argv.index("--sizes") + 1] = "300"
    argv[argv.index("--error-pairs") + 1] = "300"
    assert peers.main(argv) == 0
    row = json.loads(prefix.with_name("chunked.json").read_text())["rows"][0]
    errors = row["errors"]
    assert errors["overlapping"] > 10 and errors["wrong_overlap"] == 0
    assert errors["depth_error_max"] < 1e-5 and errors["normal_error_max_deg"] < 1e-3
    assert row["sizes"]["300"]["pairs_per_second"] > 0


@pytest.fixture
def kernels(monkeypatch):
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    import kernels as module

    return module


def test_kernels_report_costs_ceilings_and_rates(kernels, capsys):
    argv = ["--quick", "--cases", "2d-small", "3d-boxes", "--sizes", "64", "128",
            "--repeats", "1", "--pool", "16", "--query-pairs", "0"]
    assert kernels.main(argv) == 0
    lines = capsys.readouterr().out.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("| case | compile s |"))
    assert lines[start].startswith("| case | compile s | flops/pair | bytes/pair | C |")
    table = lines[start + 2:lines.index("", start)]  # the roofline table, one row per case
    rows = {line.split(" | ")[0][2:]: line.split(" | ") for line in table}
    assert set(rows) == {"2d-small", "3d-boxes"}
    for cells in rows.values():
        compile_s, flops, bytes_ = (float(cell) for cell in cells[1:4])
        assert compile_s > 0 and flops > 100 and bytes_ > 100
        assert all("/" in cell for cell in cells[5:7])  # vmap / chunked pairs/s per size
        assert float(cells[7]) >= 1.0  # flatness: fastest over slowest
    # A 3D box pair costs more operations than a pair of 3-4-gons.
    assert float(rows["3d-boxes"][2]) > float(rows["2d-small"][2])


def test_distance_benchmark_reports_ratios_and_unit_gradients(monkeypatch, tmp_path):
    """benchmarks/distance.py on 2D polygons at 1e3 pairs: it writes its JSON and table, the
    distance kernels cost at least penetration's, and their translation gradients have norm
    at most 1 (the signed distance is 1-Lipschitz in translation)."""
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    import distance

    prefix = tmp_path / "distance"
    assert distance.main(["--quick", "--cases", "2d-polygons", "--output", str(prefix)]) == 0
    record = json.loads(prefix.with_suffix(".json").read_text())
    (row,) = record["rows"]
    assert row["case"] == "2d-polygons" and row["pairs"] == 1000
    for kind in ("exact", "smooth"):
        assert row[kind]["ratio"] > 1.0
        assert 0.99 < row[kind]["max_translation_gradient"] <= 1.0 + 1e-5
    assert set(record["eager"]["2d-polygons"]) >= {"penetration", "signed_distance"}
    assert "x penetration" in prefix.with_suffix(".md").read_text()


def test_rounded_row_matches_the_closed_form(peers, tmp_path):
    """Spheres against boxes (b drawn from a pool of its own; jaxsat's distance search on a
    rounded pair) against the oracle's closed form: the centre clamped to the box."""
    prefix = tmp_path / "rounded"
    argv = [*TINY, "--methods", "jaxsat", "--output", str(prefix)]
    argv[argv.index("--cases") + 1] = "3d-sphere-box"
    assert peers.main(argv) == 0
    errors = json.loads(prefix.with_name("rounded.json").read_text())["rows"][0]["errors"]
    assert errors["overlapping"] > 10 and errors["wrong_overlap"] == 0
    assert errors["depth_error_max"] < 1e-5 and errors["normal_error_max_deg"] < 1e-2
    assert errors["grad_pairs"] == 4 and errors["grad_error_max"] < 1e-4
