"""Make the README's pictures in docs/assets/.

Usage (from the repository root, with the dev environment: pip install -e ".[dev]"):

    python docs/assets/make_pictures.py                    # all of them, about 2 minutes on 2 cores
    python docs/assets/make_pictures.py runtime_vs_error   # only the named ones

Pictures (PICTURES maps each file name to the function that writes it):

- demo.png: the picture of `python -m jaxsat demo --pairs 1024 --repeats 1` (the demo's own
  command and code; 30-40 s on 2 cores, mostly compiling).
- runtime_vs_error.png: time per pair against the largest value error of
  `jaxsat.signed_distance`, drawn from the committed benchmark results
  benchmarks/results/runtime_vs_error-cpu-2core.json (no benchmark runs; under 5 s).
- trajectory.png and trajectory_2d.png: image outputs of notebooks/trajectory_optimisation.ipynb,
  executed with nbclient on a kernel that runs this interpreter (about 90 s on 2 cores;
  the notebook file is not modified). The cells are found by their tags,
  "picture:trajectory" (the 3D arm among obstacles) and "picture:trajectory_2d" (the 2D
  path), so that editing the notebook does not silently pick another figure.

Figures are saved at 90 dpi; each file stays under about 300 KB.
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import pathlib
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[2]
ASSETS = pathlib.Path(__file__).resolve().parent
DPI = 90
RUNTIME_VS_ERROR = ROOT / "benchmarks" / "results" / "runtime_vs_error-cpu-2core.json"
NOTEBOOK = ROOT / "notebooks" / "trajectory_optimisation.ipynb"
NOTEBOOK_PICTURES = {"picture:trajectory": "trajectory.png",
                     "picture:trajectory_2d": "trajectory_2d.png"}
"""Cell tag in the trajectory notebook -> picture written from that cell's image output."""


def make_demo(assets: pathlib.Path) -> list[pathlib.Path]:
    """The demo's picture, by the demo's own command line."""
    from jaxsat.__main__ import main

    path = assets / "demo.png"
    if main(["demo", "--pairs", "1024", "--repeats", "1", "--output", str(path)]) != 0:
        raise RuntimeError("python -m jaxsat demo failed")
    return [path]


VARIANTS = {  # variant -> (label, colour, marker)
    "exact-float64": ("exact, float64", "#1f77b4", "s"),
    "exact-float32": ("exact, float32", "#17becf", "D"),
    "smooth-float64": ("smooth, float64", "#d62728", "o"),
    "smooth-float32": ("smooth, float32", "#ff7f0e", "^"),
}


def make_runtime_vs_error(assets: pathlib.Path) -> list[pathlib.Path]:
    """Time per pair against the largest value error, one panel per case, from the committed
    benchmark results."""
    from matplotlib.figure import Figure

    data = json.loads(RUNTIME_VS_ERROR.read_text())
    machine, config = data["machine"], data["config"]
    cases = [case["case"] for case in data["cases"]]
    descriptions = {case["case"]: case for case in data["cases"]}
    figure = Figure(figsize=(13, 4.6), layout="constrained")
    panels = figure.subplots(1, len(cases), sharey=True)
    for axes, case in zip(panels, cases, strict=True):
        rows = [row for row in data["rows"] if row["case"] == case]
        for variant, (label, colour, marker) in VARIANTS.items():
            chosen = sorted((row for row in rows if row["variant"] == variant),
                            key=lambda row: row["tau_fraction"])
            if not chosen:
                continue
            errors = [row["value_error_max"] for row in chosen]
            microseconds = [1e6 * row["value_best_s"] / row["pairs"] for row in chosen]
            axes.plot(errors, microseconds, color=colour, marker=marker, markersize=7,
                      lw=1.2, label=label)
        info = descriptions[case]
        axes.set_title(f"{case} ({info['pairs']:,} pairs)", fontsize=11)
        axes.set(xscale="log", yscale="log", xlabel="largest value error (length units)")
        axes.grid(True, which="major", alpha=0.3)
        axes.set_xlim(1e-17, 1.0)
    panels[0].set_ylabel("time per pair (microseconds)")
    handles, labels = panels[0].get_legend_handles_labels()
    figure.legend(handles, labels, loc="outside lower center", ncol=4, frameon=False)
    cores, cpu = machine["cpu_count"], machine["cpu_model"]
    fractions = ", ".join(f"{fraction:g}" for fraction in data["tau_fractions"])
    figure.suptitle(
        f"jaxsat.signed_distance (value only): run time against error, {cores}-core {cpu} "
        f"CPU, JAX {machine['versions']['jax']}, jit(vmap), best of {config['repeats']}\n"
        f"error: largest |value - oracle| over the pairs (shapes about 1 unit across); "
        f"smooth: smoothing=tau, tau = {fractions} x size {data['size']} from left to "
        f"right", fontsize=11)
    path = assets / "runtime_vs_error.png"
    figure.savefig(path, dpi=DPI)
    return [path]


def _kernel_spec_dir(directory: pathlib.Path) -> None:
    """A `python3` kernelspec in `directory`/kernels that runs this interpreter (as in
    tests/test_docs.py): first on JUPYTER_PATH, it wins over any other python3 kernel."""
    spec_dir = directory / "kernels" / "python3"
    spec_dir.mkdir(parents=True)
    spec = {"argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
            "display_name": "Python 3 (jaxsat pictures)", "language": "python"}
    (spec_dir / "kernel.json").write_text(json.dumps(spec))
    os.environ["JUPYTER_PATH"] = os.pathsep.join(
        [str(directory), *filter(None, [os.environ.get("JUPYTER_PATH")])])


def make_trajectory(assets: pathlib.Path) -> list[pathlib.Path]:
    """Execute the trajectory notebook in memory and save the PNG output of each tagged cell."""
    import nbclient
    import nbformat

    notebook = nbformat.read(NOTEBOOK, as_version=4)
    tagged = {tag: [cell for cell in notebook.cells if tag in cell.metadata.get("tags", [])]
              for tag in NOTEBOOK_PICTURES}
    for tag, cells in tagged.items():
        if len(cells) != 1 or cells[0].cell_type != "code":
            raise RuntimeError(f"{NOTEBOOK.name}: expected one code cell tagged {tag!r}, "
                               f"found {len(cells)}")
    # The inline backend's resolution, set before the notebook's first cell (in memory only).
    notebook.cells.insert(0, nbformat.v4.new_code_cell(
        f'%config InlineBackend.print_figure_kwargs = {{"bbox_inches": "tight", "dpi": {DPI}}}'))
    with tempfile.TemporaryDirectory() as directory:
        _kernel_spec_dir(pathlib.Path(directory))
        nbclient.NotebookClient(notebook, kernel_name="python3", timeout=600,
                                resources={"metadata": {"path": str(NOTEBOOK.parent)}}).execute()
    written = []
    for tag, name in NOTEBOOK_PICTURES.items():
        images = [output["data"]["image/png"] for output in tagged[tag][0].outputs
                  if "image/png" in output.get("data", {})]
        if len(images) != 1:
            raise RuntimeError(f"cell tagged {tag!r} gave {len(images)} PNG outputs, not 1")
        path = assets / name
        path.write_bytes(base64.b64decode(images[0]))
        written.append(path)
    return written


PICTURES = {
    "demo.png": make_demo,
    "runtime_vs_error.png": make_runtime_vs_error,
    "trajectory.png": make_trajectory,
    "trajectory_2d.png": make_trajectory,
}
"""File in docs/assets -> the function that writes it (and maybe others)."""


def main(argv: list[str] | None = None) -> int:
    jobs = {name.removesuffix(".png"): job for name, job in PICTURES.items()}
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("pictures", nargs="*", metavar="PICTURE",
                        help=f"which to make (default: all of {', '.join(jobs)})")
    args = parser.parse_args(argv)
    unknown = sorted(set(args.pictures) - set(jobs))
    if unknown:
        parser.error(f"unknown pictures {unknown}; choose from {', '.join(jobs)}")
    chosen = args.pictures or list(jobs)
    done = set()
    for name in chosen:
        job = jobs[name]
        if job in done:
            continue
        done.add(job)
        start = time.perf_counter()
        for path in job(ASSETS):
            print(f"wrote {path.relative_to(ROOT)} ({path.stat().st_size / 1024:.0f} KB, "
                  f"{time.perf_counter() - start:.0f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
