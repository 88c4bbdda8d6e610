"""Scenes and skipped work: what the broad phase (`collide` against all pairs) and each skip in
jaxsat's SAT (levels, unique axes, Gauss map, AABB check, 2D vs 3D) save, and that the results
do not change (float32). See benchmarks/README.md. Exit status 1 if results differ.

Usage (from the repository root):
    python benchmarks/scene.py          # writes results/scene-cpu-2core.{json,md}
    python benchmarks/scene.py --quick
    python benchmarks/scene.py --only "Gauss map" scene --sizes 1000 --no-save
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import pathlib
import sys
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

import jaxsat

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import core  # noqa: E402

CHUNK, BUDGET_S, MIN_ROUNDS = 2**14, 45.0, 3
DEPTH_TOLERANCE, NORMAL_TOLERANCE = 1e-5, 1e-4
SIDES = {"3d-boxes": 135.0, "3d-hulls": 118.0}
"""Cube side with about 1% of 5,000 shapes touching another (calibrated: side *= (touching /
1%)^(1/3), four times); N shapes fill a cube of side SIDES x (N / 5000)^(1/3)."""
PRISM_HALF_HEIGHT = 4.0
"""Prisms are 8 tall; shapes are at most 1.6 across, so the z axis never wins."""
F32 = np.float32
UNPRUNED = functools.partial(jaxsat.penetration, prune=False)

@dataclasses.dataclass
class Variant:
    """A way to answer the same pairs: `items` per call, `seconds` the median (or extrapolated)."""
    name: str
    work: str
    call: Callable | None
    compile_s: float
    items: int
    seconds: float | None = None

def batched(name: str, work: str, query, args) -> Variant:
    compiled = core.compile_aot(lambda *x: jaxsat.query_batch(query, *x, chunk_size=CHUNK), *args)
    return Variant(name, work, lambda: compiled.call(*args), compiled.seconds,
                   len(args[1].translation))

def timed(variants: list[Variant], rounds: int, **options) -> list:
    options = options or {"budget_s": BUDGET_S, "min_rounds": MIN_ROUNDS}
    timings = core.time_calls({v.name: v.call for v in variants if v.call}, rounds, **options)
    for v in variants:
        v.seconds = timings[v.name].median if v.call else v.seconds
    return [outputs(t.output) for t in timings.values()]

def candidates(a, prune: bool = True) -> str:
    """The axes a query between two shapes like `a` tests, from the padded sizes."""
    faces, directions, edges = (a.face_normals.shape[1], a.edge_directions.shape[1],
                                a.edge_endpoints.shape[1])
    if a.dim == 2:
        return f"{faces}+{faces} face normals"
    if prune and directions > 3:
        return f"{faces}+{faces} faces, {edges}x{edges} edge pairs (Gauss map)"
    return f"{faces}+{faces} faces, {directions}x{directions} edge pairs (projection)"

def outputs(result) -> dict:
    if hasattr(result, "valid"):  # contacts
        return {"hit": np.asarray(result.valid).any(axis=-1), "normal": result.normal}
    if hasattr(result, "depth"):
        return {"hit": np.asarray(result.depth) >= 0, "depth": result.depth,
                "normal": result.normal}
    return {"hit": result}

def compare(reference: dict, other: dict, args, booleans_only: bool = False) -> dict:
    """Booleans, depths and normals of `other` against `reference` on the batch `args`."""
    hit_ref, hit = np.asarray(reference["hit"]), np.asarray(other["hit"])
    check = {"pairs": len(hit), "colliding": int(hit_ref.sum()),
             "booleans_differ": int(np.sum(hit_ref != hit))}
    check["same"] = check["booleans_differ"] == 0
    if booleans_only or "depth" not in other or "depth" not in reference:
        return check
    difference = np.abs(np.asarray(other["depth"]) - np.asarray(reference["depth"]))
    normal_ref = np.asarray(reference["normal"], np.float64)
    normal = np.asarray(other["normal"], np.float64)[:, :normal_ref.shape[1]]  # prisms: xy
    differ = np.flatnonzero(np.max(np.abs(normal - normal_ref), axis=1) > NORMAL_TOLERANCE)
    a, pose_a, b, pose_b = (jax.tree.map(lambda leaf: np.asarray(leaf)[differ], x) for x in args)
    world = [np.einsum("nrk,nvk->nvr", np.asarray(p.rotation, np.float64), np.asarray(
        s.vertices, np.float64)) + np.asarray(p.translation, np.float64)[:, None]
             for s, p in ((a, pose_a), (b, pose_b))]
    gap = [np.einsum("nvk,nk->nv", world[0], n[differ]).max(1)
           - np.einsum("nvk,nk->nv", world[1], n[differ]).min(1) for n in (normal_ref, normal)]
    ties = int(np.sum(np.abs(gap[0] - gap[1]) <= DEPTH_TOLERANCE))
    check.update(depth_max_difference=float(difference.max()),
                 depths_differ=int(np.sum(difference > DEPTH_TOLERANCE)),
                 normals_differ=len(differ), normal_ties=ties)
    check["same"] &= check["depths_differ"] == 0 and ties == len(differ)
    return check

def describe(check) -> str:
    """The "same results" cell."""
    if check is None or isinstance(check, str):
        return check or "(reference)"
    if "same" not in check:
        return "not compared (brute force extrapolated): " + ", ".join(check["notes"])
    parts = [f"booleans {'equal' if not check['booleans_differ'] else 'DIFFER'}"
             + (f" ({check['booleans_differ']})" if check["booleans_differ"] else "")]
    if "depth_max_difference" in check:
        parts.append(f"depth max diff {check['depth_max_difference']:.1e}"
                     + (f" ({check['depths_differ']} over tol)" if check["depths_differ"] else ""))
        ties = f" ({check['normal_ties']} ties)" if check["normal_ties"] else ""
        untied = check["normals_differ"] - check["normal_ties"]
        parts.append(f"normals equal{ties}" if not untied else f"{untied} normals DIFFER{ties}")
    return ("yes: " if check["same"] else "NO: ") + ", ".join(parts + check.get("notes", []))

def rows_of(skip, case, variants, references, checks, unit="pairs/s") -> dict:
    """Rows: each variant's speed-up over the variants in its `references` and its check."""
    return {"skip": skip, "case": case, "unit": unit, "load_average": core.load_average(),
            "rows": [{"variant": v.name, "work": v.work, "compile_s": v.compile_s,
                      "median_s": v.seconds, "items_per_s": v.items / v.seconds,
                      "speedup": {variants[r].name: variants[r].seconds / v.seconds for r in refs},
                      "check": check}
                     for v, refs, check in zip(variants, references, checks, strict=True)]}

def levels(kind: str, count: int, seed: int, options) -> dict:
    args = core.make_data(kind, count, options.pool, seed=seed).inputs()
    axes = candidates(args[0])
    variants = [batched("contacts", "penetration + face clipping", jaxsat.contacts, args),
                batched("penetration", axes, jaxsat.penetration, args),
                batched("intersects", axes + ", no normal", jaxsat.intersects, args)]
    manifold, pen, hits = timed(variants, options.repeats)
    contact = compare(manifold, pen, args, booleans_only=True)
    normal = float(np.max(np.abs(np.asarray(manifold["normal"]) - np.asarray(pen["normal"]))))
    contact["notes"] = [f"contact normal = penetration normal (max diff {normal:.0e})"]
    contact["same"] &= normal == 0.0
    return rows_of("levels", kind, variants, [[], [0], [1, 0]],
                   [None, contact, compare(pen, hits, args)])

def unique_axes(kind: str, count: int, seed: int, options) -> dict:
    data = core.make_data(kind, count, options.pool, seed=seed)
    unique, every = data.inputs(), data.inputs(unique_axes=False)
    variants = [batched("unique_axes=False", candidates(every[0]), jaxsat.penetration, every),
                batched("unique axes", candidates(unique[0]), jaxsat.penetration, unique)]
    references = [[], [0]]
    if data.dim == 3:  # the textbook SAT first: every face and every edge-direction pair
        variants.insert(0, batched("unique_axes=False, prune=False",
                                   candidates(every[0], prune=False), UNPRUNED, every))
        references = [[], [0], [0, 1]]
    results = timed(variants, options.repeats)
    return rows_of("unique axes", kind, variants, references,
                   [None] + [compare(results[0], r, unique) for r in results[1:]])

def gauss_map(count: int, seed: int, options) -> dict:
    args = core.make_data("3d-hulls", count, options.pool, seed=seed).inputs()
    variants = [batched("prune=False", candidates(args[0], prune=False), UNPRUNED, args),
                batched("prune=True", candidates(args[0]), jaxsat.penetration, args)]
    full, pruned = timed(variants, options.repeats)
    hit = np.asarray(pruned["hit"])
    select = lambda r: {k: np.asarray(v)[hit] for k, v in r.items()}  # noqa: E731
    check = compare(select(full), select(pruned), jax.tree.map(lambda x: x[hit], args))
    check["booleans_differ"] = int(np.sum(hit != np.asarray(full["hit"])))
    check["same"] &= check["booleans_differ"] == 0
    gain = np.append(np.asarray(pruned["depth"] - full["depth"])[~hit], 0.0)
    check["separated_larger_gap"] = int(np.sum(gain > DEPTH_TOLERANCE))
    check["notes"] = [f"depths and normals on the {hit.sum():,} colliding pairs; on "
                      f"{check['separated_larger_gap']:,} of {len(gain) - 1:,} separated pairs "
                      f"prune=False finds a larger gap (by up to {gain.max():.2g})"]
    return rows_of("Gauss map", "3d-hulls", variants, [[], [0]], [None, check])

def two_d_vs_3d(count: int, seed: int, options) -> dict:
    data = core.make_data("2d-octagons", count, options.pool, seed=seed)
    flat = data.inputs()
    pool = jaxsat.stack([jaxsat.polyhedron(np.concatenate([
        np.c_[p, np.full(len(p), z)] for z in (-PRISM_HALF_HEIGHT, PRISM_HALF_HEIGHT)]),
        dtype=F32) for p in data.points])
    rotation = np.zeros((2, count, 3, 3))
    rotation[..., :2, :2], rotation[..., 2, 2] = data.rotation, 1.0
    translation = np.concatenate([data.translation, np.zeros((2, count, 1))], axis=-1)
    tall = jax.device_put(tuple(x for s in (0, 1) for x in (
        jax.tree.map(lambda leaf, s=s: leaf[data.pick[s]], pool),
        jaxsat.Pose(translation[s].astype(F32), rotation[s].astype(F32)))))
    variants = [batched("3D prisms", candidates(tall[0]), jaxsat.penetration, tall),
                batched("2D polygons", candidates(flat[0]), jaxsat.penetration, flat)]
    prisms, polygons = timed(variants, options.repeats)
    check = compare(polygons, prisms, flat)
    z_max = float(np.max(np.abs(np.asarray(prisms["normal"])[:, 2])))
    check["notes"] = [f"3D normal z at most {z_max:.0e}"]
    check["same"] &= z_max <= NORMAL_TOLERANCE
    return rows_of("2D vs 3D", "2d-octagons / prisms", variants, [[], [0]], [None, check])

def call_floor(*pair):
    """A jitted call on the same arguments that does (almost) nothing."""
    return sum(jnp.ravel(leaf)[0].astype(jnp.float32) for leaf in jax.tree.leaves(pair)) > 0

def aabb_single_calls(kind: str, count: int, seed: int, options, spread) -> dict:
    args = core.make_data(kind, count, options.pool, seed=seed, spread=spread).inputs()
    pairs = [jax.tree.map(lambda leaf, i=i: leaf[i], args) for i in range(count)]
    one = lambda *xs: jax.vmap(jaxsat.intersects)(  # noqa: E731
        *jax.tree.map(lambda leaf: leaf[None], xs))[0]
    variants, answers = [], []
    for name, work, query in (
            ("penetration depth >= 0", "SAT depth and normal",
             lambda *xs: jaxsat.penetration(*xs).depth >= 0),
            ("intersects as a vmap of 1", "SAT minimum, no AABB check", one),
            ("intersects", "world AABBs, then the SAT minimum under lax.cond", jaxsat.intersects),
            ("call floor", "no query: reads one entry of every argument", call_floor)):
        compiled = core.compile_aot(query, *pairs[0])
        cycle = itertools.cycle(pairs)
        variants.append(Variant(name, work, lambda c=compiled.call, it=cycle: bool(c(*next(it))),
                                compiled.seconds, 1))
        answers.append({"hit": np.array([bool(compiled.call(*p)) for p in pairs])})
    timed(variants, options.repeats * count, block=False)
    where = "far apart (AABBs disjoint)" if spread[0] > 2 else "near (about half collide)"
    return rows_of("AABB check", f"{kind}, {where}, single calls", variants, [[], [0], [1, 0], []],
                   [None, *(compare(answers[0], h, args) for h in answers[1:3]),
                    "- (dispatch and read-back cost of any call)"], unit="us/call")

def capacity_for(pairs: int) -> int:
    """A power of two with room for twice the expected broad-phase pairs."""
    return 1 << max(int(2 * pairs + 63).bit_length(), 8)

def scene(kind: str, count: int, args) -> dict:
    """`count` shapes of a 64-shape pool at uniform random positions and rotations in a cube:
    `collide` (compiled at a capacity with no overflow) against the brute force."""
    data = core.make_data(kind, count, pool=64, seed=count)
    shapes, poses = data.inputs()[:2]
    side = SIDES[kind] * (count / 5000) ** (1 / 3)
    poses = jaxsat.Pose(jnp.asarray((data.translation[0] + 1) / 2 * side, F32), poses.rotation)
    start, capacity = time.perf_counter(), capacity_for(count // 16)
    while True:
        compiled = core.compile_aot(functools.partial(
            jaxsat.collide, capacity=capacity, level=args.level), shapes, poses).call
        result = jax.block_until_ready(compiled(shapes, poses))
        if int(result.overflow) == 0:
            break
        capacity = capacity_for(int(result.count))
    query = Variant("broad phase (collide)", "hashed grid, then SAT on AABB-overlapping pairs",
                    lambda: compiled(shapes, poses), time.perf_counter() - start, 1)
    total = count * (count - 1) // 2
    sample = jnp.asarray(np.random.default_rng(count).integers(
        0, count, (min(args.sample, total), 2)), jnp.int32)
    brute = functools.partial(jaxsat.query_pairs, core.QUERIES[args.level], chunk_size=2**16)
    sampled = core.compile_aot(brute, shapes, poses, sample)
    estimate = core.time_calls({"": lambda: sampled.call(shapes, poses, sample)}, 1)[
        ""].best * total / len(sample)
    found, kept = None, np.asarray(result.pairs)[np.asarray(result.colliding)]
    if estimate <= args.brute_force_budget:
        every = jnp.asarray(np.stack(np.triu_indices(count, 1), axis=1).astype(np.int32))
        jax.clear_caches()  # the sample may have had this shape
        full = core.compile_aot(brute, shapes, poses, every)
        brute_force = Variant("brute force, all pairs", f"{total:,} pairs x SAT",
                              lambda: full.call(shapes, poses, every), full.seconds, 1)
        hits = timed([brute_force, query], args.repeats, budget_s=BUDGET_S)[0]["hit"]
        found = set(map(tuple, np.asarray(every)[np.asarray(hits)].tolist()))
    else:
        brute_force = Variant("brute force, all pairs", f"{total:,} pairs x SAT, extrapolated "
                              f"from {len(sample):,}", None, sampled.seconds, 1, seconds=estimate)
        timed([query], args.repeats, budget_s=BUDGET_S)
    check = {"capacity": int(result.pairs.shape[0]), "broad_phase_pairs": int(result.count),
             "colliding_pairs": len(kept), "touching_fraction": len(np.unique(kept)) / count}
    check["notes"] = [f"{check['broad_phase_pairs']:,} broad-phase pairs, {len(kept):,} "
                      f"colliding, {100 * check['touching_fraction']:.2f}% touching"]
    if found is not None:  # else "not compared" (describe)
        check["booleans_differ"] = len(found.symmetric_difference(map(tuple, kept.tolist())))
        check["same"] = check["booleans_differ"] == 0
    return rows_of("scene", f"{count:,} {kind}", [brute_force, query], [[], [0]],
                   [None, check], unit="s/query")

def plan(args) -> list[tuple[str, Callable[[], dict]]]:
    """(label, run) of every comparison, in order."""
    n, p = args.pairs, functools.partial
    jobs = [(f"scene {kind} {count}", p(scene, kind, count, args=args))
            for kind in args.cases for count in args.sizes]
    jobs += [(f"levels {kind}", p(levels, kind, args.hull_pairs if "hulls" in kind else n, 1, args))
             for kind in ("2d-octagons", "3d-boxes", "3d-hulls")]
    jobs += [(f"unique axes {kind}", p(unique_axes, kind, n, 2, args))
             for kind in ("2d-rectangles", "2d-symmetric8", "3d-boxes")]
    jobs += [("Gauss map 3d-hulls", p(gauss_map, args.gauss_pairs, 3, args))]
    jobs += [(f"AABB check {kind} {where}", p(aabb_single_calls, kind, args.single_calls, 4,
                                             args, spread)) for kind in ("3d-boxes", "3d-hulls")
             for where, spread in (("far", (3.0, 6.0)), ("near", (0.0, 1.8)))]
    return jobs + [("2D vs 3D", p(two_d_vs_3d, n, 6, args))]

def markdown(comparisons: list[dict]) -> str:
    def speed(c, row):
        return {"pairs/s": f"{row['items_per_s']:.3g} pairs/s",
                "us/call": f"{1e6 * row['median_s']:.3g} us/call"}.get(
                    c["unit"], f"{row['median_s']:.3g} s/query")
    return core.markdown_table(["skip", "shapes", "variant", "work per pair", "compile",
                                "speed (median)", "speed-up", "same results"],
        [[c["skip"], c["case"], row["variant"], row["work"], f"{row['compile_s']:.2g} s",
          speed(c, row), ", ".join(f"{v:.2g}x vs {k}" for k, v in row["speedup"].items())
          or "-", describe(row["check"])] for c in comparisons for row in c["rows"]])

def main(argv=None) -> int:
    args = core.parse(argv, __doc__, {
        "sizes": ([1_000, 10_000, 100_000], [1000]), "repeats": (5, 2), "pairs": (100_000, 2000),
        "hull_pairs": (100_000, 1000), "gauss_pairs": (20_000, 500), "single_calls": (500, 50)},
        ["3d-boxes", "3d-hulls"], "shapes per scene", options={
            "--level": {"choices": list(core.QUERIES), "default": "penetration",
                        "help": "scene query level and brute-force query"},
            "--sample": {"type": int, "default": 2**20,
                         "help": "pairs timed to extrapolate a brute force that is too long"},
            "--brute-force-budget": {"type": float, "default": 120.0, "help":
                                     "run the brute force in full when estimated under this (s)"},
            "--pairs": "pairs per batched comparison", "--hull-pairs": "pairs of the hull levels",
            "--gauss-pairs": "hull pairs of the Gauss-map comparison",
            "--single-calls": "unbatched calls per AABB-check variant", "--only": {
                "nargs": "+", "metavar": "TEXT",
                "help": "only the comparisons whose label contains one of these"}})
    info, comparisons = core.machine_info(), []
    for label, run in plan(args):
        if args.only and not any(text in label for text in args.only):
            continue
        began = time.perf_counter()
        jax.clear_caches()  # each compile column counts a full compile
        comparisons.append(run())
        print(f"\n{label} ({time.perf_counter() - began:.0f} s):\n"
              + markdown(comparisons[-1:]).split("\n", 2)[2], file=sys.stderr, flush=True)
    core.save(args, "scene", "jaxsat scenes and skipped work", info, {"comparisons": comparisons,
              "tolerances": [DEPTH_TOLERANCE, NORMAL_TOLERANCE]}, markdown(comparisons))
    return int(not all(not isinstance(row["check"], dict) or row["check"].get("same", True)
                       for c in comparisons for row in c["rows"]))

if __name__ == "__main__":
    sys.exit(main())
