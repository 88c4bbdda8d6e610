"""Scene queries against the brute-force all-pairs narrow phase (float32, 3D).

Scenes: N = 1,000 / 10,000 / 100,000 random boxes or 20-point hulls, randomly rotated and
placed uniformly in a cube whose side is chosen so that about 1% of the shapes touch another
(calibrated once on a 5,000-shape scene, then scaled as N^(1/3) to keep the density).

For each scene:
  * the scene query `jax.jit(jaxsat.collide)` at level "penetration": compile time, the median
    of `--repeats` timed calls, broad-phase pairs kept, colliding pairs, shapes touching;
  * the brute-force narrow phase on all N(N-1)/2 pairs, `jaxsat.query_pairs(penetration, ...)`
    in chunks. It runs in full where it takes under `--brute-force-budget` seconds (estimated
    from a timed sample); otherwise its time is extrapolated from a sample of `--sample`
    random pairs, and the table says so. When it runs in full, the colliding pairs of both
    methods are compared and must be equal.

Usage (from the repository root):
    python benchmarks/scene.py                       # everything, writes benchmarks/results/
    python benchmarks/scene.py --sizes 1000 --kinds boxes --no-save
"""

from __future__ import annotations

import argparse
import functools
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
from machine import load_average, machine_info  # noqa: E402

RESULTS_DIR = pathlib.Path(__file__).resolve().parent / "results"
POOL_SIZE = 64
CHUNK = 2**16
TARGET_TOUCHING = 0.01


def shape_pool(kind: str, rng: np.random.Generator) -> jaxsat.Polytope:
    """POOL_SIZE random shapes of about unit size, stacked (scenes index into this pool)."""
    if kind == "boxes":
        shapes = [jaxsat.box(rng.uniform(0.25, 0.5, 3), dtype=np.float32)
                  for _ in range(POOL_SIZE)]
    else:
        shapes = [jaxsat.polyhedron(rng.normal(size=(20, 3)) * 0.3, max_vertices=20,
                                    dtype=np.float32) for _ in range(POOL_SIZE)]
    return jaxsat.stack(shapes)


def make_scene(pool: jaxsat.Polytope, count: int, side: float, seed: int):
    """`count` shapes from the pool at uniform random positions and rotations."""
    rng = np.random.default_rng(seed)
    ids = jnp.asarray(rng.integers(0, POOL_SIZE, count))
    shapes = jax.tree.map(lambda field: field[ids], pool)
    positions = jnp.asarray(rng.uniform(0, side, (count, 3)), jnp.float32)
    quaternions = jnp.asarray(rng.normal(size=(count, 4)), jnp.float32)
    return shapes, jax.vmap(jaxsat.pose3)(positions, quaternions)


def capacity_for(pairs: int) -> int:
    """A power of two with room for twice the expected broad-phase pairs."""
    return 1 << max(int(2 * pairs + 63).bit_length(), 8)


def scene_query(shapes, poses, capacity: int):
    """Compiled scene query at a capacity with no overflow: (compiled, result, capacity)."""
    while True:
        compiled = jax.jit(functools.partial(jaxsat.collide, capacity=capacity)).lower(
            shapes, poses).compile()
        result = jax.block_until_ready(compiled(shapes, poses))
        if int(result.overflow) == 0:
            return compiled, result, capacity
        capacity = capacity_for(int(result.count))


def touching_fraction(result, count: int) -> float:
    pairs = np.asarray(result.pairs)[np.asarray(result.colliding)]
    return len(np.unique(pairs)) / count


def calibrate_side(pool, rng_seed: int, count: int = 5000) -> float:
    """Cube side giving about TARGET_TOUCHING of `count` shapes in contact."""
    side = 40.0
    for _ in range(4):
        shapes, poses = make_scene(pool, count, side, rng_seed)
        _, result, _ = scene_query(shapes, poses, capacity_for(count))
        fraction = max(touching_fraction(result, count), 1e-4)
        # For a sparse scene the touching fraction scales as density, i.e. as side^-3.
        side *= (fraction / TARGET_TOUCHING) ** (1 / 3)
    return side


def all_pairs(count: int) -> np.ndarray:
    rows, cols = np.triu_indices(count, 1)
    return np.stack([rows, cols], axis=1).astype(np.int32)


@functools.partial(jax.jit, static_argnames="chunk")
def brute_force(shapes, poses, pairs, chunk: int):
    hits = jaxsat.query_pairs(jaxsat.penetration, shapes, poses, pairs, chunk_size=chunk)
    return hits.depth >= 0


def time_call(function, *args, repeats: int = 1) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        out = jax.block_until_ready(function(*args))
        times.append(time.perf_counter() - start)
    return statistics.median(times), out


def run_brute_force(shapes, poses, count, sample: int, budget: float, seed: int) -> dict:
    """Time the all-pairs narrow phase, in full if it fits the budget, else by a sample."""
    total = count * (count - 1) // 2
    rng = np.random.default_rng(seed)
    sample = min(sample, total)
    rows = rng.integers(0, count, (sample, 2)).astype(np.int32)
    sample_pairs = jnp.asarray(rows)
    brute_force(shapes, poses, sample_pairs, CHUNK).block_until_ready()  # compile
    sample_time, _ = time_call(brute_force, shapes, poses, sample_pairs, CHUNK)
    estimate = sample_time * total / sample
    if estimate > budget:
        return {"seconds": estimate, "full": False, "sampled_pairs": sample, "colliding": None}
    pairs = jnp.asarray(all_pairs(count))
    brute_force(shapes, poses, pairs, CHUNK).block_until_ready()  # compile for this size
    seconds, colliding = time_call(brute_force, shapes, poses, pairs, CHUNK)
    found = np.asarray(pairs)[np.asarray(colliding)]
    return {"seconds": seconds, "full": True, "sampled_pairs": total,
            "colliding": set(map(tuple, found.tolist()))}


def run_case(kind, count, side, args) -> dict:
    pool = shape_pool(kind, np.random.default_rng(0))
    shapes, poses = make_scene(pool, count, side * (count / 5000) ** (1 / 3), seed=count)
    start = time.perf_counter()
    compiled, result, capacity = scene_query(shapes, poses, capacity_for(count // 16))
    compile_s = time.perf_counter() - start
    scene_s, result = time_call(compiled, shapes, poses, repeats=args.repeats)
    colliding = np.asarray(result.pairs)[np.asarray(result.colliding)]
    brute = run_brute_force(shapes, poses, count, args.sample, args.brute_force_budget, count)
    row = {"kind": kind, "shapes": count, "capacity": capacity,
           "broad_phase_pairs": int(result.count), "colliding_pairs": len(colliding),
           "touching_fraction": touching_fraction(result, count),
           "scene_seconds": scene_s, "scene_compile_seconds": compile_s,
           "brute_force_seconds": brute["seconds"], "brute_force_full": brute["full"],
           "brute_force_pairs_timed": brute["sampled_pairs"],
           "speedup": brute["seconds"] / scene_s}
    if brute["full"]:
        row["equal_to_brute_force"] = set(map(tuple, colliding.tolist())) == brute["colliding"]
    return row


def markdown(rows) -> str:
    lines = ["| shapes | N | broad-phase pairs | colliding pairs | touching | scene query | "
             "compile | brute force | speed-up |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        brute = f"{r['brute_force_seconds']:.3g} s"
        if not r["brute_force_full"]:
            brute += f" (extrapolated from {r['brute_force_pairs_timed']:.0e} pairs)"
        if r.get("equal_to_brute_force") is not None:
            brute += ", same pairs" if r["equal_to_brute_force"] else ", DIFFERENT pairs"
        lines.append(f"| {r['kind']} | {r['shapes']:,} | {r['broad_phase_pairs']:,} | "
                     f"{r['colliding_pairs']:,} | {100 * r['touching_fraction']:.2f}% | "
                     f"{1e3 * r['scene_seconds']:.3g} ms | {r['scene_compile_seconds']:.2g} s | "
                     f"{brute} | {r['speedup']:,.0f}x |")
    return "\n".join(lines)


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1_000, 10_000, 100_000])
    parser.add_argument("--kinds", nargs="+", default=["boxes", "hulls"],
                        choices=["boxes", "hulls"])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--sample", type=int, default=2**20,
                        help="pairs timed to extrapolate a brute force that is too long")
    parser.add_argument("--brute-force-budget", type=float, default=120.0,
                        help="run the brute force in full when estimated under this (s)")
    parser.add_argument("--no-save", action="store_true")
    return parser.parse_args(argv)


def main(argv=None) -> None:
    args = parse_args(argv)
    info, rows = machine_info(), []
    print(f"{info['cpu_model']}, {info['cpu_count']} cores, {info['devices'][0]}, "
          f"jax {info['versions']['jax']}, git {info['git_commit']}")
    for kind in args.kinds:
        side = calibrate_side(shape_pool(kind, np.random.default_rng(0)), rng_seed=1)
        for count in args.sizes:
            rows.append(run_case(kind, count, side, args))
            print(markdown(rows[-1:]).splitlines()[-1], flush=True)
    info["load_average_end"] = load_average()
    table = markdown(rows)
    print(table)
    if not args.no_save:
        RESULTS_DIR.mkdir(exist_ok=True)
        (RESULTS_DIR / "scene-cpu-2core.json").write_text(
            json.dumps({"machine": info, "rows": rows}, indent=2) + "\n")
        (RESULTS_DIR / "scene-cpu-2core.md").write_text(table + "\n")


if __name__ == "__main__":
    main()
