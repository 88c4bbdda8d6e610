"""Run time against error of `jaxsat.signed_distance`: exact (float32, float64) and smooth
(float64 and float32, a sweep of smoothing lengths tau), for values and for pose gradients.

One fixed, seeded data set per case, the same for every variant:

* `2d-octagons`: random convex 8-gons (8 vertices on a random ellipse), `polygon(...)`;
* `3d-boxes`: random boxes, `box(half_extents)`;
* `3d-hulls`: hulls of 20 random points on random ellipsoids, `polyhedron(points, 20)`.

Pairs index a pool of random shapes, with random poses around the origin: about half of them
overlap. Pose parameters are (x, y, angle) per shape in 2D and (translation, quaternion w x y z)
per shape in 3D; gradients are taken with respect to both shapes' parameters (6 numbers per
pair in 2D, 14 in 3D).

For every variant the script compiles two kernels ahead of time (the compile columns), the
value `jax.jit(vmap(signed_distance))` and the value and gradient
`jax.jit(vmap(jax.value_and_grad(...)))`, then times each on the whole data set: one warm-up
call, then the best of `--repeats` calls ended by `jax.block_until_ready`. Large batches run in
chunks of a fixed size per case (`jax.lax.map` over chunks, `jax.vmap` inside), which bounds
memory; every variant of a case uses the same chunks. The smooth variants pass tau as a traced
argument, so one compiled kernel per dtype serves the whole tau sweep (its compile time is
repeated on each row).

Errors are against float64 references that share no code with jaxsat:

* values: the SciPy Minkowski-difference oracle of `tests/oracle.py` (distance from the origin
  to the hull of A - B when apart, minus the penetration depth when overlapping), on every pair;
* gradients: central finite differences of that oracle with respect to the pose parameters, on
  a subsample of `--grad-pairs` pairs per case, at two step sizes; pairs where the two disagree
  (a kink of the exact signed distance within a step: non-unique closest features or
  penetration axis) are skipped and counted. The error of a gradient is the Euclidean norm of
  its difference from the reference (the reference has norm >= sqrt(2): its translation part
  is +-the unit normal for each shape).

The hull smooth variants are expensive, so they run on the first `--hull-smooth-pairs` pairs of
the hull data set (values) and the subsample pairs among them (gradients).

Usage (from the repository root, after `pip install -e ".[dev]"`):
    python benchmarks/runtime_vs_error.py                      # full run, several minutes
    python benchmarks/runtime_vs_error.py --quick --json /tmp/x.json --png /tmp/x.png
    python benchmarks/runtime_vs_error.py \
        --json benchmarks/results/runtime_vs_error-cpu-2core.json \
        --png benchmarks/results/runtime_vs_error-cpu-2core.png
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import os
import pathlib
import statistics
import sys
import time

import jax

# float64 is measured too; float32 variants build float32 shapes and poses explicitly.
jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import jaxsat  # noqa: E402

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "tests"))
import oracle  # noqa: E402  (tests/oracle.py: NumPy/SciPy only, no jaxsat)
from machine import load_average, machine_info  # noqa: E402
from throughput import random_hull_points  # noqa: E402

CASES = {
    "2d-octagons": "random convex 8-gons, polygon(vertices)",
    "3d-boxes": "random boxes, box(half_extents)",
    "3d-hulls": "hulls of 20 random points, polyhedron(points, max_vertices=20)",
}
SIZE = 0.5
"""Typical shape radius (ellipse and ellipsoid semi-axes 0.3-0.8, box half extents
0.15-0.6): the smoothing lengths are tau = fraction * SIZE."""
TAU_FRACTIONS = (1e-4, 1e-3, 1e-2, 3e-2, 1e-1)
CHUNK = {"2d-octagons": 4096, "3d-boxes": 2048, "3d-hulls": 128}
FD_STEPS = (1e-4, 1e-5)
"""Central-difference steps in the pose parameters; the smaller one is the reference."""
FD_AGREEMENT = 1e-5
"""Pairs whose two finite-difference gradients differ by more (Euclidean norm) are skipped."""
ERROR_FLOOR = 1e-17
"""Zero errors are drawn at this value on the log axis."""


# ----------------------------------------------------------------------------- data set


@dataclasses.dataclass
class DataSet:
    case: str
    dim: int
    points: list[np.ndarray]
    """Raw float64 points of every pool shape (what the oracle sees)."""
    pools: dict[str, jaxsat.Polytope]
    """The pool built from those points, per dtype name ("float32", "float64")."""
    pick_a: np.ndarray
    pick_b: np.ndarray
    params_a: np.ndarray
    """(N, P) float64 pose parameters of a (P = 3 in 2D, 7 in 3D)."""
    params_b: np.ndarray

    @property
    def pairs(self) -> int:
        return len(self.pick_a)


def random_octagon(rng: np.random.Generator) -> np.ndarray:
    """8 vertices on a random ellipse: always strictly convex."""
    gaps = rng.uniform(0.5, 1.5, 8)
    angles = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.cumsum(gaps) / gaps.sum()
    axes = rng.uniform(0.3, 0.8, 2)
    return np.stack([axes[0] * np.cos(angles), axes[1] * np.sin(angles)], axis=1)


def box_corners(half: np.ndarray) -> np.ndarray:
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    return signs * half


def build_shape(case: str, points: np.ndarray, dtype) -> jaxsat.Polytope:
    if case == "2d-octagons":
        return jaxsat.polygon(points, max_vertices=8, dtype=dtype)
    if case == "3d-boxes":
        return jaxsat.box(points[-1], dtype=dtype)  # the last corner is (+, +, +) half
    return jaxsat.polyhedron(points, max_vertices=20, dtype=dtype)


def make_data_set(case: str, pairs: int, pool_size: int, rng: np.random.Generator) -> DataSet:
    dim = 2 if case.startswith("2d") else 3
    if case == "2d-octagons":
        points = [random_octagon(rng) for _ in range(pool_size)]
    elif case == "3d-boxes":
        points = [box_corners(rng.uniform(0.15, 0.6, 3)) for _ in range(pool_size)]
    else:
        points = [random_hull_points(rng, 20) for _ in range(pool_size)]
    pools = {name: jaxsat.stack([build_shape(case, p, dtype) for p in points])
             for name, dtype in (("float32", np.float32), ("float64", np.float64))}
    pick_a, pick_b = (rng.integers(0, pool_size, pairs) for _ in range(2))
    centres = rng.uniform(-1.0, 1.0, (pairs, dim))
    directions = rng.normal(size=(pairs, dim))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    ends = centres + directions * rng.uniform(0.0, 1.8, (pairs, 1))
    if dim == 2:
        angles = rng.uniform(-np.pi, np.pi, (2, pairs, 1))
        params_a = np.concatenate([centres, angles[0]], axis=1)
        params_b = np.concatenate([ends, angles[1]], axis=1)
    else:
        quaternions = rng.normal(size=(2, pairs, 4))
        params_a = np.concatenate([centres, quaternions[0]], axis=1)
        params_b = np.concatenate([ends, quaternions[1]], axis=1)
    return DataSet(case, dim, points, pools, pick_a, pick_b, params_a, params_b)


def batch_inputs(data: DataSet, dtype: str, count: int):
    """(params_a, params_b, a, b) for the first `count` pairs, as device arrays of `dtype`."""
    pool = data.pools[dtype]
    take = lambda pick: jax.tree.map(lambda leaf: leaf[jnp.asarray(pick[:count])], pool)  # noqa: E731
    return (jnp.asarray(data.params_a[:count], dtype), jnp.asarray(data.params_b[:count], dtype),
            take(data.pick_a), take(data.pick_b))


# ----------------------------------------------------------------------------- oracle


def oracle_rotation(dim: int, params: np.ndarray) -> np.ndarray:
    return oracle.rotation_2d(params[2]) if dim == 2 else oracle.rotation_3d(params[3:])


def oracle_value(dim: int, points_a, params_a, points_b, params_b) -> float:
    """Exact float64 signed distance: the distance apart, minus the depth when overlapping."""
    world_a = oracle.to_world(points_a, oracle_rotation(dim, params_a), params_a[:dim])
    world_b = oracle.to_world(points_b, oracle_rotation(dim, params_b), params_b[:dim])
    result = oracle.evaluate(world_a, world_b)
    return result.distance if result.depth < 0 else -result.depth


def oracle_values(data: DataSet, count: int) -> np.ndarray:
    return np.array([oracle_value(data.dim, data.points[data.pick_a[i]], data.params_a[i],
                                  data.points[data.pick_b[i]], data.params_b[i])
                     for i in range(count)])


def oracle_gradient(data: DataSet, index: int) -> tuple[np.ndarray, bool]:
    """Central differences w.r.t. (params_a, params_b) at the steps FD_STEPS: (the gradient at
    the smaller step, whether the two steps agree within FD_AGREEMENT)."""
    points_a, points_b = data.points[data.pick_a[index]], data.points[data.pick_b[index]]
    params = np.concatenate([data.params_a[index], data.params_b[index]])
    half = len(params) // 2

    def value(x):
        return oracle_value(data.dim, points_a, x[:half], points_b, x[half:])

    gradients = []
    for step in FD_STEPS:
        gradient = np.empty(len(params))
        for k in range(len(params)):
            shift = np.zeros(len(params))
            shift[k] = step
            gradient[k] = (value(params + shift) - value(params - shift)) / (2 * step)
        gradients.append(gradient)
    return gradients[-1], bool(np.linalg.norm(gradients[0] - gradients[1]) <= FD_AGREEMENT)


# ----------------------------------------------------------------------------- kernels


def make_pose(params):
    if params.shape[-1] == 3:
        return jaxsat.pose2(params[0], params[1], params[2])
    return jaxsat.pose3(params[:3], params[3:])


def make_kernel(smooth: bool, gradient: bool, chunk: int):
    """jit(f)(tau, params_a, params_b, a, b) over a batch: the values, or (values, (N, 2P)
    gradients w.r.t. both poses' parameters). Batches longer than `chunk` (a multiple of it)
    run as a `lax.map` over chunks of `chunk` pairs."""

    def one(params_a, params_b, a, b, tau):
        smoothing = tau if smooth else None
        return jaxsat.signed_distance(a, make_pose(params_a), b, make_pose(params_b),
                                      smoothing=smoothing)

    def pair(params_a, params_b, a, b, tau):
        if not gradient:
            return one(params_a, params_b, a, b, tau)
        value, grads = jax.value_and_grad(one, argnums=(0, 1))(params_a, params_b, a, b, tau)
        return value, jnp.concatenate(grads)

    def batch(tau, *inputs):
        vmapped = jax.vmap(lambda *xs: pair(*xs, tau))
        count = inputs[0].shape[0]
        if count <= chunk:
            return vmapped(*inputs)
        split = lambda leaf: leaf.reshape(count // chunk, chunk, *leaf.shape[1:])  # noqa: E731
        merge = lambda leaf: leaf.reshape(count, *leaf.shape[2:])  # noqa: E731
        out = jax.lax.map(lambda xs: vmapped(*xs), jax.tree.map(split, inputs))
        return jax.tree.map(merge, out)

    return jax.jit(batch)


def compile_kernel(kernel, arguments):
    """(executable, compile seconds), compiled ahead of time for these arguments' shapes."""
    start = time.perf_counter()
    compiled = kernel.lower(*arguments).compile()
    return compiled, time.perf_counter() - start


def time_kernel(compiled, arguments, repeats: int, budget_s: float):
    """(best s, median s, number of timed calls, outputs of the warm-up call)."""
    outputs = jax.block_until_ready(compiled(*arguments))
    times: list[float] = []
    # At least `repeats` calls (fewer past the budget); cheap kernels repeat up to 20 times
    # within a second, which makes the best call less sensitive to other load.
    while times == [] or (len(times) < repeats and sum(times) <= budget_s) or (
            len(times) < 20 and sum(times) < 1.0):
        start = time.perf_counter()
        jax.block_until_ready(compiled(*arguments))
        times.append(time.perf_counter() - start)
    return min(times), statistics.median(times), len(times), outputs


# ----------------------------------------------------------------------------- variants


def variants(smooth_dtypes) -> list[dict]:
    rows = [{"variant": f"exact-{dtype}", "dtype": dtype, "smooth": False, "tau_fraction": 0.0}
            for dtype in ("float32", "float64")]
    for dtype in smooth_dtypes:
        rows += [{"variant": f"smooth-{dtype}", "dtype": dtype, "smooth": True,
                  "tau_fraction": fraction} for fraction in TAU_FRACTIONS]
    return rows


def stats(errors: np.ndarray) -> tuple[float, float]:
    return float(np.max(errors)), float(np.median(errors))


def run_case(case: str, args, rng: np.random.Generator, echo) -> tuple[dict, list[dict]]:
    hulls = case == "3d-hulls"
    pairs = args.hull_pairs if hulls else args.pairs
    smooth_pairs = min(args.hull_smooth_pairs if hulls else args.smooth_pairs, pairs)
    chunk = CHUNK[case]
    for count in (pairs, smooth_pairs):
        if count > chunk and count % chunk:
            raise SystemExit(f"{case}: {count} pairs is not a multiple of the chunk {chunk}")
    start = time.perf_counter()
    data = make_data_set(case, pairs, args.pool, rng)
    reference = oracle_values(data, pairs)
    oracle_s = time.perf_counter() - start
    start = time.perf_counter()
    subsample = np.sort(rng.choice(smooth_pairs, min(args.grad_pairs, smooth_pairs),
                                   replace=False))
    fd = [oracle_gradient(data, int(i)) for i in subsample]
    kept = np.array([ok for _, ok in fd], bool)
    grad_index, grad_reference = subsample[kept], np.array([g for g, ok in fd if ok])
    fd_s = time.perf_counter() - start
    info = {"case": case, "description": CASES[case], "pairs": pairs,
            "smooth_pairs": smooth_pairs, "chunk": chunk, "pool": args.pool,
            "overlapping_fraction": float(np.mean(reference < 0)),
            "oracle_values_s": oracle_s, "grad_subsample": len(subsample),
            "grad_skipped_kinks": int(np.sum(~kept)), "oracle_gradients_s": fd_s,
            "load_average_1_5_15": list(os.getloadavg())}
    echo(f"# {case}: {CASES[case]}; {pairs} pairs ({smooth_pairs} for smooth)"
         f", {info['overlapping_fraction']:.0%} overlapping; oracle values {oracle_s:.1f}s; "
         f"gradient subsample {len(subsample)} pairs, {info['grad_skipped_kinks']} skipped "
         f"(finite differences disagree: kinks), {fd_s:.1f}s")

    kernels: dict = {}
    rows = []
    bound = None
    for variant in variants(args.smooth_dtypes):
        count = smooth_pairs if variant["smooth"] else pairs
        dtype = variant["dtype"]
        tau = variant["tau_fraction"] * SIZE
        inputs = batch_inputs(data, dtype, count)
        arguments = (jnp.asarray(tau, dtype), *inputs)
        row = {"case": case, **variant, "tau": tau, "pairs": count}
        for kind in ("value", "grad"):
            key = (variant["smooth"], kind, dtype, count)
            if key not in kernels:  # one compiled kernel serves the whole tau sweep
                kernels[key] = compile_kernel(
                    make_kernel(variant["smooth"], kind == "grad", chunk), arguments)
            compiled, compile_s = kernels[key]
            best, median, calls, outputs = time_kernel(compiled, arguments, args.repeats,
                                                       args.budget_seconds)
            row[f"{kind}_compile_s"] = compile_s
            row[f"{kind}_best_s"] = best
            row[f"{kind}_median_s"] = median
            row[f"{kind}_timed_calls"] = calls
            row[f"{kind}_pairs_per_second"] = count / best
            if kind == "value":
                values = np.asarray(outputs, np.float64)
            else:
                gradients = np.asarray(outputs[1], np.float64)
                grad_values = np.asarray(outputs[0], np.float64)
        value_errors = np.abs(values - reference[:count])
        grad_errors = np.linalg.norm(gradients[grad_index] - grad_reference, axis=1)
        row["value_error_max"], row["value_error_median"] = stats(value_errors)
        row["grad_error_max"], row["grad_error_median"] = stats(grad_errors)
        # Pair indices into the case's data set (reproduce with --seed and the same sizes).
        row["value_error_worst_pair"] = int(np.argmax(value_errors))
        row["grad_error_worst_pair"] = int(grad_index[np.argmax(grad_errors)])
        row["grad_error_over_1e-3_fraction"] = float(np.mean(grad_errors > 1e-3))
        half = gradients.shape[1] // 2
        moves = np.r_[0:data.dim, half:half + data.dim]  # the translation components
        row["grad_translation_error_max"] = float(np.max(np.linalg.norm(
            gradients[grad_index][:, moves] - grad_reference[:, moves], axis=1)))
        row["grad_pairs"] = len(grad_index)
        row["value_grad_kernel_value_error_max"] = float(np.max(np.abs(grad_values - values)))
        row["nonfinite"] = int(np.sum(~np.isfinite(values)) + np.sum(~np.isfinite(gradients)))
        if variant["smooth"]:
            if bound is None:
                a, b = (jax.tree.map(lambda leaf, p=pick: leaf[jnp.asarray(p)],
                                     data.pools["float64"]) for pick in (data.pick_a, data.pick_b))
                bound = np.asarray(jaxsat.smoothing_error_bound(a, b), np.float64)
            allowed = bound[:count] * tau
            row["bound_max"] = float(np.max(allowed))
            # A little slack for rounding: float32 carries ~1e-7 relative error in the inputs.
            slack = 1e-12 if dtype == "float64" else 1e-5
            row["bound_violations"] = int(np.sum(value_errors > allowed + slack))
        rows.append(row)
        echo(markdown_row(row))
        del inputs, arguments
    return info, rows


# ----------------------------------------------------------------------------- output


def source_info() -> dict:
    """Where jaxsat was imported from, so that a result can be tied to the code it measured
    (the commit is `machine_info`'s)."""
    return {"jaxsat_path": str(pathlib.Path(jaxsat.__file__).resolve().parent)}


HEADER = ("| case | variant | tau / size | pairs | compile value / grad (s) | value pairs/s | "
          "value+grad pairs/s | value error max | median | grad error max | median | "
          "bound c tau (max) |\n"
          "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")


def markdown_row(row: dict) -> str:
    tau = f"{row['tau_fraction']:g}" if row["smooth"] else "-"
    bound = f"{row['bound_max']:.1e}" if row["smooth"] else "-"
    if row.get("bound_violations"):
        bound += f" ({row['bound_violations']} over)"
    return (f"| {row['case']} | {row['variant']} | {tau} | {row['pairs']} | "
            f"{row['value_compile_s']:.1f} / {row['grad_compile_s']:.1f} | "
            f"{row['value_pairs_per_second']:.2g} | {row['grad_pairs_per_second']:.2g} | "
            f"{row['value_error_max']:.1e} | {row['value_error_median']:.1e} | "
            f"{row['grad_error_max']:.1e} | {row['grad_error_median']:.1e} | {bound} |")


STYLES = {"exact-float32": ("^", "tab:red"), "exact-float64": ("s", "tab:blue"),
          "smooth-float64": ("o", None), "smooth-float32": ("D", None)}


def plot(rows: list[dict], cases: list[str], path: pathlib.Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker
    from matplotlib.lines import Line2D

    colours = plt.get_cmap("viridis")
    figure, axes = plt.subplots(2, len(cases), figsize=(max(5 * len(cases), 10), 9), squeeze=False)
    for column, case in enumerate(cases):
        for line, (kind, label) in enumerate((("value", "value"), ("grad", "value + gradient"))):
            axis = axes[line, column]
            for row in (r for r in rows if r["case"] == case):
                marker, colour = STYLES[row["variant"]]
                if colour is None:
                    position = TAU_FRACTIONS.index(row["tau_fraction"]) / (len(TAU_FRACTIONS) - 1)
                    colour = colours(0.9 * position)
                x = row[f"{kind}_pairs_per_second"]
                high = max(row[f"{kind}_error_max"], ERROR_FLOOR)
                low = max(row[f"{kind}_error_median"], ERROR_FLOOR)
                axis.plot([x, x], [low, high], color=colour, lw=0.8, alpha=0.6)
                axis.plot(x, high, marker=marker, color=colour, ms=8, ls="none")
                axis.plot(x, low, marker=marker, mfc="none", color=colour, ms=6, ls="none")
            axis.set_xscale("log")
            axis.set_yscale("log")
            axis.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
            axis.grid(True, which="major", alpha=0.3)
            error = "|value - oracle|" if kind == "value" else "|grad - finite differences|"
            axis.set_title(f"{case}: {label}")
            axis.set_xlabel(f"{label} pairs/s")
            axis.set_ylabel(error)
    handles = [Line2D([], [], marker=STYLES[name][0], ls="none",
                      color=STYLES[name][1] or "grey", label=name) for name in STYLES]
    handles += [Line2D([], [], marker="o", ls="none", color=colours(0.9 * i / 4),
                       label=f"tau = {fraction:g} x size") for i, fraction in
                enumerate(TAU_FRACTIONS)]
    handles += [Line2D([], [], marker="o", ls="none", color="k", label="max error (filled)"),
                Line2D([], [], marker="o", mfc="none", ls="none", color="k",
                       label="median error (open)")]
    figure.legend(handles=handles, loc="lower center", ncol=5, fontsize=8, frameon=False)
    figure.suptitle(title, fontsize=10)
    figure.tight_layout(rect=(0, 0.08, 1, 0.95))
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)
    plt.close(figure)


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", type=int, default=None,
                        help="pairs of 2D octagons and of 3D boxes, exact variants: the data "
                             "set (default: 8192, --quick: 512)")
    parser.add_argument("--smooth-pairs", type=int, default=None,
                        help="the first pairs of that data set that the smooth variants run "
                             "on (default: 2048, --quick: 256)")
    parser.add_argument("--hull-pairs", type=int, default=None,
                        help="pairs of 3D hulls, exact variants (default: 2048, --quick: 128)")
    parser.add_argument("--hull-smooth-pairs", type=int, default=None,
                        help="the first hull pairs that the smooth variants run on "
                             "(default: 256, --quick: 128)")
    parser.add_argument("--grad-pairs", type=int, default=None,
                        help="pairs per case (among the smooth ones) for the finite-difference "
                             "gradient check (default: 200, --quick: 10)")
    parser.add_argument("--cases", nargs="+", choices=list(CASES), default=None,
                        help="cases to run (default: all; --quick: 2d-octagons)")
    parser.add_argument("--smooth-dtypes", nargs="+", choices=["float64", "float32"],
                        default=None, help="dtypes of the smooth variants (default: both, "
                        "--quick: float64)")
    parser.add_argument("--repeats", type=int, default=None,
                        help="timed calls after a warm-up, the best reported (default: 3, "
                             "--quick: 1); fewer once they add up to --budget-seconds")
    parser.add_argument("--budget-seconds", type=float, default=6.0,
                        help="stop repeating a kernel once its timed calls add up to this "
                             "(default: %(default)s)")
    parser.add_argument("--pool", type=int, default=None,
                        help="distinct random shapes per case (default: 256, --quick: 16)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    parser.add_argument("--quick", action="store_true",
                        help="a smoke run (under a minute): small sizes, and unless given "
                        "otherwise 2D only and float64 smooth variants only")
    parser.add_argument("--json", metavar="PATH", help="write machine info and rows as JSON")
    parser.add_argument("--png", metavar="PATH", help="write the error against speed plot")
    args = parser.parse_args(argv)
    defaults = {"pairs": (8192, 512), "smooth_pairs": (2048, 256), "hull_pairs": (2048, 128),
                "hull_smooth_pairs": (256, 128), "grad_pairs": (200, 10), "repeats": (3, 1),
                "pool": (256, 16), "cases": (list(CASES), ["2d-octagons"]),
                "smooth_dtypes": (["float64", "float32"], ["float64"])}
    for name, (full, quick) in defaults.items():
        if getattr(args, name) is None:
            setattr(args, name, quick if args.quick else full)
    if min(args.pairs, args.smooth_pairs, args.hull_pairs, args.hull_smooth_pairs,
           args.grad_pairs, args.repeats, args.pool) < 1:
        parser.error("sizes, --repeats and --pool must be positive")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    started = time.perf_counter()
    info = {**machine_info(), **source_info()}

    def echo(text: str) -> None:
        print(text, flush=True)

    title = (f"jaxsat {info['versions']['jaxsat']} signed_distance: run time against error\n"
             f"{info['cpu_model']}, {info['cpu_count']} CPUs, jax {info['versions']['jax']} "
             f"({info['backend']}), {info['date_utc'][:10]}")
    echo(title.replace("\n", "; "))
    echo(f"jaxsat from {info['jaxsat_path']}, git commit {info['git_commit']}")
    echo(f"load average {info['load_average_start']}; tau = fraction x size, size = {SIZE}; "
         "pairs/s: best of the timed calls after a warm-up, compile excluded")
    echo("")
    echo(HEADER)
    rng = np.random.default_rng(args.seed)
    cases, rows = [], []
    for case in args.cases:
        case_info, case_rows = run_case(case, args, rng, echo)
        cases.append(case_info)
        rows.extend(case_rows)
    echo("")
    echo(HEADER)
    for row in rows:
        echo(markdown_row(row))
    total = time.perf_counter() - started
    info["load_average_end"] = load_average()
    echo(f"\ntotal {total:.0f}s, load average at the end {info['load_average_end']}")

    if args.png:
        plot(rows, args.cases, pathlib.Path(args.png), title)
        echo(f"wrote {args.png}")
    if args.json:
        path = pathlib.Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        config = {key: value for key, value in vars(args).items() if key not in ("json", "png")}
        config.update(size=SIZE, tau_fractions=list(TAU_FRACTIONS), fd_steps=list(FD_STEPS),
                      fd_agreement=FD_AGREEMENT, chunk=CHUNK, total_s=total,
                      date=datetime.datetime.now(datetime.timezone.utc).isoformat(
                          timespec="seconds"))
        path.write_text(json.dumps({"machine": info, "config": config, "cases": cases,
                                    "results": rows}, indent=2) + "\n")
        echo(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
