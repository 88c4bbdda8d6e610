"""Skipping work: what each skip in jaxsat's SAT saves, and that it changes no result.

Each comparison runs the same fixed, seeded float32 pairs through a variant that skips some
work and through one that does not, using only the public API (`import jaxsat`):

  levels       `intersects` vs `penetration` vs `contacts` on 2D 8-gons, boxes, 20-point hulls
  unique axes  boxes and 2D rectangles / centrally symmetric 8-gons built with unique face
               normals and edge directions vs `unique_axes=False` (one per face and per edge),
               and the latter with `prune=False` (every edge-direction pair)
  Gauss map    20-point hulls, `penetration(prune=True)` (only the edge pairs that form a
               Minkowski face) vs `prune=False` (every pair of edge directions, by projection)
  AABB check   single jitted unbatched `intersects` calls (world AABBs first, the SAT skipped
               by `lax.cond` when they are disjoint) vs the same query batched as a vmap of one
               (no pre-check) and vs `penetration(...).depth >= 0`, on far-apart and on near
               pairs, each call's answer read back to the host; the variants are called in
               turn on each pair and the median per-call time is reported, next to the "call
               floor" (a jitted call on the same arguments that does no query)
  broad phase  a scene of 2,000 boxes with about 1% touching another: `collide(...,
               level="intersects")` (hashed-grid broad phase, then the SAT on the pairs whose
               AABBs overlap) vs `query_pairs(intersects, ...)` over all N(N-1)/2 pairs
  2D vs 3D     2D 8-gons vs the same 8-gons extruded into tall prisms (3D, posed in the plane),
               whose z axis is never the answer: same depths, and the 2D kernel skips the
               edge-edge axes

Batched variants run as `jax.jit` of `jaxsat.query_batch(query, ..., chunk_size=2**14)`,
compiled ahead of time (the compile column); the variants of one comparison are then called
in turn (interleaved, so that the load of the shared machine hits them alike), one warm-up
call each and `--repeats` timed rounds (at least MIN_ROUNDS, fewer than `--repeats` once a
comparison has run BUDGET_S); the median is reported. "same results" compares each row with
the row it is timed against: booleans must be equal, depths equal within DEPTH_TOLERANCE, and
normals equal within NORMAL_TOLERANCE except at ties (pairs where both normals certify the
same depth within DEPTH_TOLERANCE, checked in float64 NumPy from the world vertices).

Usage (from the repository root):
    python benchmarks/skipping.py                   # ~9 min on 2 loaded cores; writes results/
    python benchmarks/skipping.py --quick --no-save  # smoke run, 1-3 minutes
    python benchmarks/skipping.py --only "Gauss map" --no-save
Exit status 1 if any comparison finds different results.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import os
import pathlib
import statistics
import sys
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

import jaxsat

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from machine import load_average, machine_info  # noqa: E402

RESULTS_DIR = pathlib.Path(__file__).resolve().parent / "results"
RESULT_NAME = "skipping-cpu-2core"
CHUNK = 2**14
POOL = 256
PRISM_HALF_HEIGHT = 4.0
"""Prisms are 8 tall; shapes are at most 1.6 across, so the z axis (depth >= 8) never wins."""
DEPTH_TOLERANCE = 1e-5
"""Absolute depth tolerance (float32, shapes about unit size)."""
NORMAL_TOLERANCE = 1e-4
F32 = np.float32


# ----------------------------------------------------------------------------- shapes


def ellipse_polygon(rng: np.random.Generator, count: int = 8) -> np.ndarray:
    """`count` vertices on a random ellipse (strictly convex, no two edges parallel)."""
    gaps = rng.uniform(0.5, 1.5, count)
    angles = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.cumsum(gaps) / gaps.sum()
    axes = rng.uniform(0.3, 0.8, 2)
    return np.stack([axes[0] * np.cos(angles), axes[1] * np.sin(angles)], axis=1)


def symmetric_octagon(rng: np.random.Generator) -> np.ndarray:
    """A centrally symmetric 8-gon on a random ellipse: 4 pairs of parallel edges, so 4
    unique normals of 8."""
    gaps = rng.uniform(0.5, 1.5, 4)
    angles = rng.uniform(0, np.pi) + np.pi * (np.cumsum(gaps) - gaps[0]) / gaps.sum()
    axes = rng.uniform(0.3, 0.8, 2)
    ring = np.stack([axes[0] * np.cos(angles), axes[1] * np.sin(angles)], axis=1)
    return np.concatenate([ring, -ring])


def hull_points(rng: np.random.Generator, count: int = 20) -> np.ndarray:
    """`count` points on a random ellipsoid: every point is a hull vertex."""
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return directions * rng.uniform(0.3, 0.8, 3)


def prism(polygon: np.ndarray) -> np.ndarray:
    """The 2D polygon extruded to z in [-PRISM_HALF_HEIGHT, PRISM_HALF_HEIGHT]."""
    rows = len(polygon)
    return np.concatenate([np.column_stack([polygon, np.full(rows, z)])
                           for z in (-PRISM_HALF_HEIGHT, PRISM_HALF_HEIGHT)])


RAW_SHAPES = {
    "8-gons": lambda rng: ellipse_polygon(rng),
    "rectangles": lambda rng: rng.uniform(0.15, 0.6, 2),
    "symmetric 8-gons": symmetric_octagon,
    "boxes": lambda rng: rng.uniform(0.15, 0.6, 3),
    "hulls": lambda rng: hull_points(rng),
}
"""Raw parameters of one random shape of each kind (box kinds: half extents)."""

DIMS = {"8-gons": 2, "rectangles": 2, "symmetric 8-gons": 2, "boxes": 3, "hulls": 3,
        "8-gon prisms": 3}


def build(kind: str, raw: np.ndarray, unique_axes: bool = True) -> jaxsat.Polytope:
    """One float32 shape of `kind` from its raw parameters."""
    if kind in ("rectangles", "boxes"):
        return jaxsat.box(raw, dtype=F32, unique_axes=unique_axes)
    if kind == "hulls":
        return jaxsat.polyhedron(raw, max_vertices=20, dtype=F32, unique_axes=unique_axes)
    if kind == "8-gon prisms":
        return jaxsat.polyhedron(prism(raw), dtype=F32, unique_axes=unique_axes)
    return jaxsat.polygon(raw, dtype=F32, unique_axes=unique_axes)


@dataclasses.dataclass
class Pairs:
    """`count` pairs indexing two pools of raw shapes, with float32 pose parameters."""

    kind: str
    raw: list
    index_a: np.ndarray
    index_b: np.ndarray
    centres: np.ndarray
    """(N, 2 or 3) a's positions; b's are centres + offsets (z = 0 for planar poses)."""
    offsets: np.ndarray
    angles: np.ndarray
    """(2, N) rotation angles about z for planar poses."""
    quaternions: np.ndarray
    """(2, N, 4) rotations in 3D."""

    def __len__(self) -> int:
        return len(self.index_a)


def make_pairs(kind: str, count: int, seed: int, spread=(0.0, 1.8)) -> Pairs:
    """Random pairs: b's origin `spread` from a's (uniform), random rotations; about half of
    the pairs of unit-size shapes collide with the default spread."""
    rng = np.random.default_rng(seed)
    raw = [RAW_SHAPES[kind](rng) for _ in range(POOL)]
    dim = DIMS[kind]
    directions = rng.normal(size=(count, dim))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return Pairs(kind, raw, rng.integers(0, POOL, count), rng.integers(0, POOL, count),
                 rng.uniform(-1, 1, (count, dim)).astype(F32),
                 (directions * rng.uniform(*spread, (count, 1))).astype(F32),
                 rng.uniform(-np.pi, np.pi, (2, count)).astype(F32),
                 rng.normal(size=(2, count, 4)).astype(F32))


def batch(pairs: Pairs, kind: str | None = None, unique_axes: bool = True):
    """(a, pose_a, b, pose_b) batched over the pairs; `kind` rebuilds the same raw shapes as
    another kind ("8-gon prisms": 3D prisms posed in the plane)."""
    kind = kind or pairs.kind
    pool = jaxsat.stack([build(kind, raw, unique_axes) for raw in pairs.raw])
    take = lambda index: jax.tree.map(lambda leaf: leaf[jnp.asarray(index)], pool)  # noqa: E731
    centres_b = pairs.centres + pairs.offsets
    if kind == "8-gon prisms":
        poses = [planar_pose3(c, angle) for c, angle in zip((pairs.centres, centres_b),
                                                            pairs.angles, strict=True)]
    elif DIMS[kind] == 2:
        poses = [jax.vmap(jaxsat.pose2)(c[:, 0], c[:, 1], angle)
                 for c, angle in zip((pairs.centres, centres_b), pairs.angles, strict=True)]
    else:
        poses = [jax.vmap(jaxsat.pose3)(c, q)
                 for c, q in zip((pairs.centres, centres_b), pairs.quaternions, strict=True)]
    return take(pairs.index_a), poses[0], take(pairs.index_b), poses[1]


def planar_pose3(centres_2d: np.ndarray, angles: np.ndarray) -> jaxsat.Pose:
    """3D poses at (x, y, 0) rotated by `angles` about z, like pose2(x, y, angle)."""
    translations = np.column_stack([centres_2d, np.zeros(len(angles), F32)])
    half = angles.astype(np.float64) / 2
    quaternions = np.column_stack([np.cos(half), 0 * half, 0 * half, np.sin(half)]).astype(F32)
    return jax.vmap(jaxsat.pose3)(translations, quaternions)


# ----------------------------------------------------------------------------- timing


@dataclasses.dataclass
class Variant:
    """One timed way of answering the same pairs."""

    name: str
    candidates: str
    """The work per pair, in words (axes tested)."""
    call: Callable[[], object]
    """Answers every pair (or runs the scene query) once."""
    compile_s: float
    items: int
    """Pairs (or single calls) answered by one call."""
    times: list = dataclasses.field(default_factory=list)
    output: object = None
    one: Callable | None = None
    """Single-call variants: the call for one pair."""


def batched_variant(name: str, candidates: str, query, args) -> Variant:
    """`query` over the batch `args`, compiled ahead of time."""
    run = jax.jit(lambda *xs: jaxsat.query_batch(query, *xs, chunk_size=CHUNK))
    start = time.perf_counter()
    compiled = run.lower(*args).compile()
    return Variant(name, candidates, lambda: compiled(*args), time.perf_counter() - start,
                   len(args[1].translation))


def single_call_variant(name: str, candidates: str, query, pair_list) -> Variant:
    """One jitted unbatched call per pair, each read back to the host (as a program that
    branches on the answer would), for every pair of `pair_list`."""
    run = jax.jit(query)
    start = time.perf_counter()
    compiled = run.lower(*pair_list[0]).compile()
    compile_s = time.perf_counter() - start
    one = lambda pair: bool(compiled(*pair))  # noqa: E731
    return Variant(name, candidates, lambda: np.array([one(pair) for pair in pair_list]),
                   compile_s, 1, one=one)


def time_single_calls(variants: list[Variant], pair_list: list, repeats: int) -> None:
    """Per-call wall times: after a warm-up pass, `repeats` passes over the pairs, calling
    every variant on each pair in turn (so that bursts of load hit all variants alike)."""
    for variant in variants:
        variant.output = variant.call()
    for _ in range(repeats):
        for pair in pair_list:
            for variant in variants:
                start = time.perf_counter()
                variant.one(pair)
                variant.times.append(time.perf_counter() - start)


BUDGET_S = 45.0
"""Timed rounds stop early (after at least MIN_ROUNDS) once a comparison has taken this long."""
MIN_ROUNDS = 3


def time_interleaved(variants: list[Variant], repeats: int) -> None:
    """Warm up each variant, then time up to `repeats` rounds calling each variant once per
    round (fewer, but at least MIN_ROUNDS, past BUDGET_S)."""
    for variant in variants:
        variant.output = jax.block_until_ready(variant.call())
    for round_ in range(repeats):
        if round_ >= MIN_ROUNDS and sum(sum(v.times) for v in variants) > BUDGET_S:
            break
        for variant in variants:
            start = time.perf_counter()
            jax.block_until_ready(variant.call())
            variant.times.append(time.perf_counter() - start)


def median_s(variant: Variant) -> float:
    return statistics.median(variant.times)


# ----------------------------------------------------------------------------- checks


def world_vertices(shapes: jaxsat.Polytope, poses: jaxsat.Pose, index: np.ndarray):
    """float64 world vertices (n, V, D) of batch entries `index` (padding repeats a vertex)."""
    local = np.asarray(shapes.vertices[index], np.float64)
    rotation = np.asarray(poses.rotation[index], np.float64)
    translation = np.asarray(poses.translation[index], np.float64)
    return np.einsum("nrk,nvk->nvr", rotation, local) + translation[:, None]


def support_gaps(normals: np.ndarray, world_a: np.ndarray, world_b: np.ndarray) -> np.ndarray:
    """max over a of n . a - min over b of n . b: the depth each normal certifies."""
    normals = np.asarray(normals, np.float64)
    return (np.einsum("nvk,nk->nv", world_a, normals).max(axis=1)
            - np.einsum("nvk,nk->nv", world_b, normals).min(axis=1))


def compare(reference, other, args, booleans_only=False) -> dict:
    """Booleans, depths and normals of `other` against `reference`, each a dict with "hit" and
    optionally "depth" (N,) and "normal" (N, D); `args` is the batch both answered (for ties).
    """
    hit_ref, hit = np.asarray(reference["hit"]), np.asarray(other["hit"])
    result = {"pairs": int(len(hit)), "colliding": int(hit_ref.sum()),
              "booleans_differ": int(np.sum(hit_ref != hit))}
    if booleans_only or "depth" not in other or "depth" not in reference:
        result["same"] = result["booleans_differ"] == 0
        return result
    depth_ref, depth = np.asarray(reference["depth"]), np.asarray(other["depth"])
    difference = np.abs(depth - depth_ref)
    result.update(depth_max_difference=float(difference.max()),
                  depths_differ=int(np.sum(difference > DEPTH_TOLERANCE)))
    normal_ref, normal = np.asarray(reference["normal"]), np.asarray(other["normal"])
    dim = normal_ref.shape[1]
    normal = normal[:, :dim]  # a 3D prism's normal against a 2D one: xy part (z checked apart)
    differ = np.flatnonzero(np.max(np.abs(normal - normal_ref), axis=1) > NORMAL_TOLERANCE)
    ties = 0
    if len(differ):
        a, pose_a, b, pose_b = args
        world_a, world_b = world_vertices(a, pose_a, differ), world_vertices(b, pose_b, differ)
        gap_ref = support_gaps(normal_ref[differ], world_a, world_b)
        gap = support_gaps(normal[differ], world_a, world_b)
        ties = int(np.sum(np.abs(gap - gap_ref) <= DEPTH_TOLERANCE))
    result.update(normals_differ=int(len(differ)), normal_ties=ties)
    result["same"] = (result["booleans_differ"] == 0 and result["depths_differ"] == 0
                      and ties == len(differ))
    return result


def describe(check: dict | None) -> str:
    """The "same results" cell."""
    if check is None:
        return "(reference)"
    if isinstance(check, str):
        return check
    parts = [f"booleans {'equal' if not check['booleans_differ'] else 'DIFFER'}"
             + (f" ({check['booleans_differ']})" if check["booleans_differ"] else "")]
    if "depth_max_difference" in check:
        parts.append(f"depth max diff {check['depth_max_difference']:.1e}"
                     + (f" ({check['depths_differ']} over tol)" if check["depths_differ"] else ""))
        ties = f" ({check['normal_ties']} ties)" if check["normal_ties"] else ""
        untied = check["normals_differ"] - check["normal_ties"]
        parts.append(f"normals equal{ties}" if not untied else f"{untied} normals DIFFER{ties}")
    for note in check.get("notes", []):
        parts.append(note)
    return ("yes: " if check["same"] else "NO: ") + ", ".join(parts)


def outputs(result, kind: str) -> dict:
    """The comparable parts of a query's batched result."""
    if kind == "intersects":
        return {"hit": result}
    if kind == "contacts":
        return {"hit": np.asarray(result.valid).any(axis=-1), "normal": result.normal}
    return {"hit": np.asarray(result.depth) >= 0, "depth": result.depth,
            "normal": result.normal}


# ----------------------------------------------------------------------------- comparisons


def candidates_text(a: jaxsat.Polytope, prune: bool = True) -> str:
    """Axes a query between two shapes like `a` (batched) tests, from the padded sizes."""
    faces, directions, hull_edges = (a.face_normals.shape[1], a.edge_directions.shape[1],
                                     a.edge_endpoints.shape[1])
    if a.dim == 2:
        return f"{faces}+{faces} face normals"
    if prune and directions > 3:
        return f"{faces}+{faces} faces, {hull_edges}x{hull_edges} edge pairs (Gauss map)"
    return f"{faces}+{faces} faces, {directions}x{directions} edge pairs (projection)"


def unpruned(a, pose_a, b, pose_b):
    return jaxsat.penetration(a, pose_a, b, pose_b, prune=False)


def levels(kind: str, count: int, seed: int, repeats: int) -> dict:
    args = batch(make_pairs(kind, count, seed))
    axes = candidates_text(args[0])
    variants = [batched_variant("contacts", "penetration + face clipping",
                                jaxsat.contacts, args),
                batched_variant("penetration", axes, jaxsat.penetration, args),
                batched_variant("intersects", axes + ", no normal", jaxsat.intersects, args)]
    time_interleaved(variants, repeats)
    manifold, pen, hits = (outputs(v.output, v.name) for v in variants)
    contact_check = compare(manifold, pen, args, booleans_only=True)
    normal_difference = float(np.max(np.abs(np.asarray(manifold["normal"]) - pen["normal"])))
    contact_check["notes"] = [f"contact normal = penetration normal (max diff "
                              f"{normal_difference:.0e})"]
    contact_check["same"] &= normal_difference == 0.0
    return rows_of("levels", kind, variants, references=[[], [0], [1, 0]],
                   checks=[None, contact_check, compare(pen, hits, args)])


def unique_axes(kind: str, count: int, seed: int, repeats: int) -> dict:
    pairs = make_pairs(kind, count, seed)
    unique, every = batch(pairs), batch(pairs, unique_axes=False)
    variants = [batched_variant("unique_axes=False", candidates_text(every[0]),
                                jaxsat.penetration, every),
                batched_variant("unique axes", candidates_text(unique[0]),
                                jaxsat.penetration, unique)]
    references = [[], [0]]
    if DIMS[kind] == 3:  # the textbook SAT first: every face and every edge-direction pair
        variants.insert(0, batched_variant("unique_axes=False, prune=False",
                                           candidates_text(every[0], prune=False), unpruned,
                                           every))
        references = [[], [0], [0, 1]]
    time_interleaved(variants, repeats)
    results = [outputs(v.output, "penetration") for v in variants]
    checks = [None] + [compare(results[0], r, unique) for r in results[1:]]
    return rows_of("unique axes", kind, variants, references, checks)


def gauss_map(kind: str, count: int, seed: int, repeats: int) -> dict:
    args = batch(make_pairs(kind, count, seed))
    variants = [batched_variant("prune=False", candidates_text(args[0], prune=False),
                                unpruned, args),
                batched_variant("prune=True", candidates_text(args[0]), jaxsat.penetration,
                                args)]
    time_interleaved(variants, repeats)
    full, pruned = (outputs(v.output, "penetration") for v in variants)
    colliding = np.asarray(pruned["hit"])
    check = compare(_select(full, colliding), _select(pruned, colliding),
                    jax.tree.map(lambda leaf: leaf[jnp.asarray(colliding)], args))
    check["booleans_differ"] = int(np.sum(pruned["hit"] != full["hit"]))
    check["same"] &= check["booleans_differ"] == 0
    gain = np.asarray(pruned["depth"])[~colliding] - np.asarray(full["depth"])[~colliding]
    gain = np.append(gain, 0.0)  # (no separated pair at all in a tiny run)
    larger = gain > DEPTH_TOLERANCE
    check["separated_larger_gap"] = int(larger.sum())
    check["notes"] = [f"depths and normals on the {colliding.sum():,} colliding pairs; on "
                      f"{larger.sum():,} of {len(gain) - 1:,} separated pairs prune=False finds a "
                      f"larger gap (by up to {gain.max():.2g})"]
    return rows_of("Gauss map", kind, variants, [[], [0]], [None, check])


def _select(result: dict, mask: np.ndarray) -> dict:
    return {key: np.asarray(value)[mask] for key, value in result.items()}


def two_d_vs_3d(count: int, seed: int, repeats: int) -> dict:
    pairs = make_pairs("8-gons", count, seed)
    flat, tall = batch(pairs), batch(pairs, kind="8-gon prisms")
    variants = [batched_variant("3D prisms", candidates_text(tall[0]), jaxsat.penetration,
                                tall),
                batched_variant("2D polygons", candidates_text(flat[0]), jaxsat.penetration,
                                flat)]
    time_interleaved(variants, repeats)
    prisms, polygons = (outputs(v.output, "penetration") for v in variants)
    check = compare(polygons, prisms, flat)
    z_max = float(np.max(np.abs(np.asarray(prisms["normal"])[:, 2])))
    check["notes"] = [f"3D normal z at most {z_max:.0e}"]
    check["same"] &= z_max <= NORMAL_TOLERANCE
    return rows_of("2D vs 3D", "8-gons / prisms", variants, [[], [0]], [None, check])


def aabb_single_calls(kind: str, count: int, seed: int, repeats: int, spread) -> dict:
    pairs = make_pairs(kind, count, seed, spread=spread)
    args = batch(pairs)
    host = jax.tree.map(np.asarray, args)
    pair_list = [jax.device_put(jax.tree.map(lambda leaf, i=i: leaf[i], host))
                 for i in range(count)]
    vmap_of_one = lambda *xs: jax.vmap(jaxsat.intersects)(  # noqa: E731
        *jax.tree.map(lambda leaf: leaf[None], xs))[0]
    variants = [
        single_call_variant("penetration depth >= 0", "SAT depth and normal",
                            lambda *xs: jaxsat.penetration(*xs).depth >= 0, pair_list),
        single_call_variant("intersects as a vmap of 1", "SAT minimum, no AABB check",
                            vmap_of_one, pair_list),
        single_call_variant("intersects", "world AABBs, then the SAT minimum under lax.cond",
                            jaxsat.intersects, pair_list),
        single_call_variant("call floor", "no query: reads one entry of every argument",
                            call_floor, pair_list)]
    time_single_calls(variants, pair_list, repeats)
    hits = [{"hit": v.output} for v in variants[:3]]
    where = "far apart (AABBs disjoint)" if spread[0] > 2 else "near (about half collide)"
    return rows_of("AABB check", f"{kind}, {where}, single calls", variants,
                   [[], [0], [1, 0], []],
                   [None] + [compare(hits[0], h, args) for h in hits[1:]]
                   + ["- (dispatch and read-back cost of any call)"], unit="us/call")


def call_floor(*pair) -> jax.Array:
    """A jitted call on the same arguments that does (almost) nothing."""
    return sum(jnp.ravel(leaf)[0].astype(jnp.float32) for leaf in jax.tree.leaves(pair)) > 0


def scene_vs_brute_force(count: int, seed: int, repeats: int) -> dict:
    """`collide(level="intersects")` vs `query_pairs(intersects)` over all N(N-1)/2 pairs."""
    rng = np.random.default_rng(seed)
    pool = jaxsat.stack([jaxsat.box(rng.uniform(0.25, 0.5, 3), dtype=F32) for _ in range(64)])
    shapes = jax.tree.map(lambda leaf: leaf[jnp.asarray(rng.integers(0, 64, count))], pool)
    quaternions = jnp.asarray(rng.normal(size=(count, 4)), jnp.float32)
    unit_positions = rng.uniform(0, 1, (count, 3))
    capacity = 1 << max(count.bit_length() + 1, 8)
    scene = jax.jit(functools.partial(jaxsat.collide, capacity=capacity, level="intersects"))
    side = 40.0 * (count / 5000) ** (1 / 3)
    for _ in range(3):  # cube side giving about 1% of the boxes touching another
        poses = jax.vmap(jaxsat.pose3)(jnp.asarray(unit_positions * side, jnp.float32),
                                       quaternions)
        touching = touching_fraction(scene(shapes, poses), count)
        side *= (max(touching, 1e-3) / 0.01) ** (1 / 3)
    poses = jax.vmap(jaxsat.pose3)(jnp.asarray(unit_positions * side, jnp.float32), quaternions)
    jax.clear_caches()  # the calibration compiled the scene query: compile it again, timed
    rows, cols = np.triu_indices(count, 1)
    every = jnp.asarray(np.stack([rows, cols], axis=1).astype(np.int32))
    brute = jax.jit(lambda s, p, q: jaxsat.query_pairs(jaxsat.intersects, s, p, q,
                                                       chunk_size=2**16))
    variants = [timed_scene_variant("brute force, all pairs", f"{len(rows):,} pairs x SAT",
                                    brute, (shapes, poses, every)),
                timed_scene_variant("broad phase (collide)", "hashed grid, then SAT on "
                                    "AABB-overlapping pairs", scene, (shapes, poses))]
    time_interleaved(variants, repeats)
    found = set(map(tuple, np.asarray(every)[np.asarray(variants[0].output)].tolist()))
    result = variants[1].output
    kept = np.asarray(result.pairs)[np.asarray(result.colliding)]
    check = {"pairs": len(rows), "colliding": len(found), "same": set(map(tuple, kept.tolist()))
             == found and int(result.overflow) == 0, "booleans_differ": len(
                 found.symmetric_difference(map(tuple, kept.tolist()))),
             "broad_phase_pairs": int(result.count),
             "notes": [f"{int(result.count)} AABB pairs kept, {len(found)} colliding, "
                       f"{100 * touching_fraction(result, count):.1f}% of boxes touching"]}
    return rows_of("broad phase", f"scene of {count:,} boxes", variants, [[], [0]],
                   [None, check], unit="s/query")


def timed_scene_variant(name, candidates, function, args) -> Variant:
    start = time.perf_counter()
    compiled = function.lower(*args).compile()
    return Variant(name, candidates, lambda: compiled(*args), time.perf_counter() - start, 1)


def touching_fraction(result, count: int) -> float:
    pairs = np.asarray(result.pairs)[np.asarray(result.colliding)]
    return len(np.unique(pairs)) / count


# ----------------------------------------------------------------------------- report


def rows_of(skip, case, variants, references, checks, unit="pairs/s") -> dict:
    """Table rows: speed-ups of each variant against the variants listed in its `references`
    (indices), and its `checks` (each against the row its comparison names)."""
    rows = []
    for variant, refs, check in zip(variants, references, checks, strict=True):
        seconds = median_s(variant)
        times = (variant.times if len(variant.times) <= 20 else
                 {"calls": len(variant.times), "quantiles_10_50_90_s": np.quantile(
                     variant.times, [0.1, 0.5, 0.9]).tolist()})
        row = {"variant": variant.name, "candidates": variant.candidates,
               "compile_s": variant.compile_s, "median_s": seconds, "times_s": times,
               "items_per_call": variant.items, "items_per_s": variant.items / seconds,
               "speedup": {variants[r].name: median_s(variants[r]) / seconds for r in refs},
               "check": check}
        rows.append(row)
    return {"skip": skip, "case": case, "unit": unit, "rows": rows,
            "load_average_after": os.getloadavg()}


def rate_text(comparison: dict, row: dict) -> str:
    if comparison["unit"] == "pairs/s":
        return f"{row['items_per_s']:.3g} pairs/s"
    if comparison["unit"] == "us/call":
        return f"{1e6 * row['median_s']:.3g} us/call"
    return f"{row['median_s']:.3g} s/query"


def markdown(comparisons: list[dict]) -> str:
    lines = ["| skip | shapes | variant | work per pair | compile | speed (median) | speed-up "
             "| same results |", "|---|---|---|---|---|---|---|---|"]
    for comparison in comparisons:
        for row in comparison["rows"]:
            speedup = ", ".join(f"{value:.2g}x vs {name}"
                                for name, value in row["speedup"].items()) or "-"
            lines.append(f"| {comparison['skip']} | {comparison['case']} | {row['variant']} | "
                         f"{row['candidates']} | {row['compile_s']:.2g} s | "
                         f"{rate_text(comparison, row)} | {speedup} | "
                         f"{describe(row['check'])} |")
    return "\n".join(lines)


def plan(args) -> list[tuple[str, Callable[[], dict]]]:
    """(label, run) of every comparison, in order."""
    n, n_hulls, r = args.pairs, args.hull_pairs, args.repeats
    jobs = [(f"levels {kind}", functools.partial(levels, kind, count, 1, r))
            for kind, count in (("8-gons", n), ("boxes", n), ("hulls", n_hulls))]
    jobs += [(f"unique axes {kind}", functools.partial(unique_axes, kind, n, 2, r))
             for kind in ("rectangles", "symmetric 8-gons", "boxes")]
    jobs += [("Gauss map hulls", functools.partial(gauss_map, "hulls", args.gauss_pairs, 3, r))]
    jobs += [(f"AABB check {kind} {where}", functools.partial(
        aabb_single_calls, kind, args.single_calls, 4, r, spread))
        for kind in ("boxes", "hulls") for where, spread in (("far", (3.0, 6.0)),
                                                              ("near", (0.0, 1.8)))]
    jobs += [("broad phase", functools.partial(scene_vs_brute_force, args.scene, 5, r)),
             ("2D vs 3D", functools.partial(two_d_vs_3d, n, 6, r))]
    return jobs


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true",
                        help="small sizes and 2 repeats: a smoke run, not a measurement")
    parser.add_argument("--no-save", action="store_true",
                        help=f"do not write benchmarks/results/{RESULT_NAME}.{{json,md}}")
    parser.add_argument("--pairs", type=int, default=None,
                        help="pairs per batched comparison (default 100000, quick 2000)")
    parser.add_argument("--hull-pairs", type=int, default=None,
                        help="pairs for the hull levels (default 100000, quick 1000)")
    parser.add_argument("--gauss-pairs", type=int, default=None,
                        help="hull pairs for the Gauss-map comparison (default 20000, "
                             "quick 500)")
    parser.add_argument("--single-calls", type=int, default=None,
                        help="unbatched calls per AABB-check variant (default 500, quick 50)")
    parser.add_argument("--scene", type=int, default=None,
                        help="boxes in the broad-phase scene (default 2000, quick 300)")
    parser.add_argument("--only", nargs="+", default=None, metavar="TEXT",
                        help="run only the comparisons whose label contains one of these, "
                             "e.g. --only levels 'Gauss map' (labels are printed as they run)")
    parser.add_argument("--repeats", type=int, default=None,
                        help="timed calls per variant (default 5, quick 2)")
    args = parser.parse_args(argv)
    defaults = ({"pairs": 2000, "hull_pairs": 1000, "gauss_pairs": 500, "single_calls": 50,
                 "scene": 300, "repeats": 2} if args.quick else
                {"pairs": 100_000, "hull_pairs": 100_000, "gauss_pairs": 20_000,
                 "single_calls": 500, "scene": 2000, "repeats": 5})
    for name, value in defaults.items():
        if getattr(args, name) is None:
            setattr(args, name, value)
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    info = machine_info()
    print(f"{info['cpu_model']}, {info['cpu_count']} cores, {info['devices'][0]}, jax "
          f"{info['versions']['jax']}, git {info['git_commit']}, load average "
          f"{info['load_average_start']}", flush=True)
    start, comparisons = time.perf_counter(), []
    for label, run in plan(args):
        if args.only and not any(text in label for text in args.only):
            continue
        began = time.perf_counter()
        jax.clear_caches()  # each compile column counts a full compile
        comparisons.append(run())
        print(f"\n{label} ({time.perf_counter() - began:.0f} s):", flush=True)
        print("\n".join(markdown(comparisons[-1:]).splitlines()[2:]), flush=True)
    info["load_average_end"] = load_average()
    info["seconds"] = time.perf_counter() - start
    table = markdown(comparisons)
    print(f"\n{table}\n\nload average at the end {info['load_average_end']}, "
          f"{info['seconds']:.0f} s in all")
    if not args.no_save:
        RESULTS_DIR.mkdir(exist_ok=True)
        config = {key: value for key, value in vars(args).items() if key != "no_save"}
        config.update(chunk_size=CHUNK, pool=POOL, depth_tolerance=DEPTH_TOLERANCE,
                      normal_tolerance=NORMAL_TOLERANCE, budget_s=BUDGET_S,
                      min_rounds=MIN_ROUNDS)
        (RESULTS_DIR / f"{RESULT_NAME}.json").write_text(json.dumps(
            {"machine": info, "config": config, "comparisons": comparisons}, indent=2) + "\n")
        (RESULTS_DIR / f"{RESULT_NAME}.md").write_text(table + "\n")
        print(f"wrote {RESULTS_DIR / RESULT_NAME}.json and .md")
    all_same = all(not isinstance(row["check"], dict) or row["check"]["same"]
                   for comparison in comparisons for row in comparison["rows"])
    return 0 if all_same else 1


if __name__ == "__main__":
    sys.exit(main())
