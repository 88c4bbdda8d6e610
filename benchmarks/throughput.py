"""Throughput of `jax.jit(jax.vmap(jaxsat.penetration))` (or `intersects`), in pairs per second
(float32).

Cases: random convex polygons padded to 8 vertices (2D), random boxes (3D) and convex hulls of
20 random points padded to `max_vertices=20` (3D). Each batch indexes a pool of random shapes
(stacked once with `jaxsat.stack`) with random indices, with random poses around the origin
chosen so that about half of the pairs collide.

Every (case, size) is compiled ahead of time from abstract shapes (that is the compile time
reported), its memory need is read from the compiled executable, and then it is timed on real
inputs: one warm-up call, then the best of `--repeats` calls with `jax.block_until_ready`.
A size is skipped, with the reason printed, when a call is estimated (from the previous size)
to take more than `--max-call-seconds`, or to need more memory than is available.

Usage (from the repository root):
    python benchmarks/throughput.py
    python benchmarks/throughput.py --sizes 1000 10000 --cases 3d-boxes --repeats 3
    python benchmarks/throughput.py --json            # also writes benchmarks/results/*.json
"""

from __future__ import annotations

import argparse
import datetime
import json
import pathlib
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxsat

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from machine import available_memory_bytes, machine_info  # noqa: E402

CASES = {
    "2d-polygons": "random convex polygons, 3-8 vertices, polygon(..., max_vertices=8)",
    "3d-boxes": "random boxes, box(half_extents)",
    "3d-hulls": "hulls of 20 random points, polyhedron(points, max_vertices=20)",
}
DEFAULT_SIZES = (1_000, 10_000, 100_000, 1_000_000)
RESULTS_DIR = pathlib.Path(__file__).resolve().parent / "results"


# ----------------------------------------------------------------------------- scenes


def random_polygon(rng: np.random.Generator) -> np.ndarray:
    """3-8 vertices on a random ellipse: always strictly convex."""
    count = int(rng.integers(3, 9))
    gaps = rng.uniform(0.5, 1.5, count)
    angles = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.cumsum(gaps) / gaps.sum()
    axes = rng.uniform(0.3, 0.8, 2)
    return np.stack([axes[0] * np.cos(angles), axes[1] * np.sin(angles)], axis=1)


def random_hull_points(rng: np.random.Generator, count: int = 20) -> np.ndarray:
    """`count` random points on a random ellipsoid, so every point is a hull vertex."""
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return directions * rng.uniform(0.3, 0.8, 3)


def make_pool(case: str, rng: np.random.Generator, size: int) -> jaxsat.Polytope:
    """`size` random float32 shapes of one case, stacked (leading batch axis)."""
    f32 = np.float32
    if case == "2d-polygons":
        shapes = [jaxsat.polygon(random_polygon(rng), max_vertices=8, dtype=f32)
                  for _ in range(size)]
    elif case == "3d-boxes":
        shapes = [jaxsat.box(rng.uniform(0.15, 0.6, 3), dtype=f32) for _ in range(size)]
    elif case == "3d-hulls":
        shapes = [jaxsat.polyhedron(random_hull_points(rng), max_vertices=20, dtype=f32)
                  for _ in range(size)]
    else:
        raise ValueError(f"unknown case {case!r}")
    return jaxsat.stack(shapes)


def make_batch(case: str, pool: jaxsat.Polytope, pairs: int, rng: np.random.Generator):
    """(a, pose_a, b, pose_b) with a leading axis of length `pairs`, all float32."""
    dim = 2 if case.startswith("2d") else 3
    count = pool.vertices.shape[0]
    pick_a, pick_b = (jnp.asarray(rng.integers(0, count, pairs)) for _ in range(2))
    a = jax.tree.map(lambda leaf: leaf[pick_a], pool)
    b = jax.tree.map(lambda leaf: leaf[pick_b], pool)
    centres = rng.uniform(-1.0, 1.0, (pairs, dim)).astype(np.float32)
    directions = rng.normal(size=(pairs, dim))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    offsets = (directions * rng.uniform(0.0, 1.8, (pairs, 1))).astype(np.float32)
    if dim == 2:
        angles = rng.uniform(-np.pi, np.pi, (2, pairs)).astype(np.float32)
        make = jax.vmap(jaxsat.pose2)
        pose_a = make(centres[:, 0], centres[:, 1], angles[0])
        pose_b = make(centres[:, 0] + offsets[:, 0], centres[:, 1] + offsets[:, 1], angles[1])
    else:
        quaternions = rng.normal(size=(2, pairs, 4)).astype(np.float32)
        make = jax.vmap(jaxsat.pose3)
        pose_a = make(centres, quaternions[0])
        pose_b = make(centres + offsets, quaternions[1])
    return a, pose_a, b, pose_b


def abstract_batch(case: str, pool: jaxsat.Polytope, pairs: int):
    """jax.ShapeDtypeStruct stand-ins for `make_batch(case, pool, pairs, ...)`."""
    dim = 2 if case.startswith("2d") else 3
    spec = lambda leaf: jax.ShapeDtypeStruct((pairs, *leaf.shape[1:]), leaf.dtype)  # noqa: E731
    shape = jax.tree.map(spec, pool)
    pose = jaxsat.Pose(jax.ShapeDtypeStruct((pairs, dim), jnp.float32),
                       jax.ShapeDtypeStruct((pairs, dim, dim), jnp.float32))
    return shape, pose, shape, pose


# ----------------------------------------------------------------------------- timing


QUERIES = {"penetration": jaxsat.penetration, "intersects": jaxsat.intersects}


def compile_kernel(case: str, pool: jaxsat.Polytope, pairs: int, query: str):
    """(executable, compile seconds, bytes needed or None), compiled from abstract inputs."""
    kernel = jax.jit(jax.vmap(QUERIES[query]))
    start = time.perf_counter()
    compiled = kernel.lower(*abstract_batch(case, pool, pairs)).compile()
    seconds = time.perf_counter() - start
    try:
        stats = compiled.memory_analysis()
        needed = (stats.argument_size_in_bytes + stats.output_size_in_bytes
                  + stats.temp_size_in_bytes)
    except Exception:  # noqa: BLE001 - memory_analysis is optional per backend
        needed = None
    return compiled, seconds, needed


def time_calls(executable, arguments, repeats: int, budget_s: float) -> list[float]:
    """Wall times of `repeats` calls after one warm-up call; stops early past `budget_s`."""
    jax.block_until_ready(executable(*arguments))
    times: list[float] = []
    while len(times) < repeats:
        start = time.perf_counter()
        jax.block_until_ready(executable(*arguments))
        times.append(time.perf_counter() - start)
        if len(times) >= 2 and sum(times) > budget_s:
            break
    return times


def run_case(case: str, sizes: list[int], args, rng: np.random.Generator, echo) -> list[dict]:
    start = time.perf_counter()
    pool = make_pool(case, rng, args.pool)
    echo(f"# {case}: {CASES[case]}; pool of {args.pool} shapes built in "
         f"{time.perf_counter() - start:.1f}s")
    rows: list[dict] = []
    seconds_per_pair = None
    for pairs in sorted(sizes):
        row = {"case": case, "pairs": pairs}
        rows.append(row)
        if seconds_per_pair is not None and seconds_per_pair * pairs > args.max_call_seconds:
            row["skipped"] = (f"estimated {seconds_per_pair * pairs:.0f}s per call > "
                              f"--max-call-seconds {args.max_call_seconds:g}")
            echo(format_row(row))
            continue
        executable, compile_s, needed = compile_kernel(case, pool, pairs, args.query)
        row["compile_s"] = compile_s
        row["memory_needed_bytes"] = needed
        available = available_memory_bytes()
        if needed is not None and available is not None and needed > 0.8 * available:
            row["skipped"] = (f"needs {needed / 2**30:.1f} GiB, {available / 2**30:.1f} GiB "
                              "available")
            echo(format_row(row))
            continue
        arguments = make_batch(case, pool, pairs, rng)
        times = time_calls(executable, arguments, args.repeats, args.budget_seconds)
        result = executable(*arguments)
        hits = result.depth > 0 if args.query == "penetration" else result
        del arguments
        best = min(times)
        seconds_per_pair = best / pairs
        row.update(best_s=best, median_s=statistics.median(times), repeats=len(times),
                   pairs_per_second=pairs / best,
                   colliding_fraction=float(jnp.mean(hits)))
        echo(format_row(row))
    return rows


HEADER = (f"{'case':<12} {'pairs':>9} {'compile':>8} {'best call':>10} {'pairs/s':>10} "
          f"{'collide':>8}")


def format_row(row: dict) -> str:
    prefix = f"{row['case']:<12} {row['pairs']:>9,}"
    if "skipped" in row:
        return f"{prefix}  skipped: {row['skipped']}"
    return (f"{prefix} {row['compile_s']:>7.2f}s {row['best_s']:>9.4f}s "
            f"{row['pairs_per_second']:>10.3g} {row['colliding_fraction']:>7.0%}")


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=list(DEFAULT_SIZES),
                        help="batch sizes in pairs (default: %(default)s)")
    parser.add_argument("--cases", nargs="+", choices=list(CASES), default=list(CASES),
                        help="cases to run (default: all)")
    parser.add_argument("--repeats", type=int, default=5,
                        help="timed calls per size after a warm-up; the best is reported "
                             "(default: %(default)s)")
    parser.add_argument("--budget-seconds", type=float, default=30.0,
                        help="stop repeating a size once its timed calls add up to this, "
                             "after at least 2 (default: %(default)s)")
    parser.add_argument("--max-call-seconds", type=float, default=60.0,
                        help="skip a size whose single call is estimated, from the previous "
                             "size, to take longer (default: %(default)s)")
    parser.add_argument("--pool", type=int, default=256,
                        help="distinct random shapes per case (default: %(default)s)")
    parser.add_argument("--query", choices=list(QUERIES), default="penetration",
                        help="the query timed: depth and normal, or the boolean only "
                        "(default: %(default)s)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    parser.add_argument("--json", nargs="?", const="", default=None, metavar="PATH",
                        help="also write the results and machine info as JSON to PATH "
                             "(default when PATH is omitted: benchmarks/results/"
                             "throughput-<UTC date and time>.json)")
    args = parser.parse_args(argv)
    if min(args.sizes) < 1 or args.repeats < 1 or args.pool < 1:
        parser.error("--sizes, --repeats and --pool must be positive")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    info = machine_info()

    def echo(text: str) -> None:
        print(text, flush=True)

    echo(f"jaxsat {info['versions']['jaxsat']} throughput, float32, "
         f"jax.jit(jax.vmap(jaxsat.{args.query}))")
    echo(f"{info['cpu_model']}, {info['cpu_count']} CPUs, {info['platform']}, jax "
         f"{info['versions']['jax']} ({info['backend']}), load average "
         f"{info['load_average_start']}, {info['date_utc']}, git {info['git_commit']}")
    echo("compile: ahead-of-time compile of the batch; best call: best of the timed calls "
         "after a warm-up")
    echo("")
    echo(HEADER)
    rows: list[dict] = []
    rng = np.random.default_rng(args.seed)
    for case in args.cases:
        rows.extend(run_case(case, args.sizes, args, rng, echo))

    if args.json is not None:
        path = pathlib.Path(args.json) if args.json else RESULTS_DIR / (
            "throughput-" + datetime.datetime.now(datetime.timezone.utc).strftime(
                "%Y%m%dT%H%M%SZ") + ".json")
        path.parent.mkdir(parents=True, exist_ok=True)
        config = {key: value for key, value in vars(args).items() if key != "json"}
        path.write_text(json.dumps({"machine": info, "config": config, "results": rows},
                                   indent=2) + "\n")
        echo(f"\nwrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
