"""The `python -m jaxsat demo` job: random scenes, float32 throughput and accuracy, a picture.

Only the public API (`import jaxsat`) is used, so this file doubles as a worked example.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

import jaxsat

__all__ = ["CASES", "DemoResult", "Scene", "make_scene", "plot_scenes", "run_case", "run_demo"]

CASES: dict[str, str] = {
    "2d-polygons": "random convex polygons, 3-8 vertices padded to 8",
    "3d-boxes": "random boxes (cuboids)",
    "3d-hulls": "hulls of 20 random points on ellipsoids, padded to 20 vertices",
}
"""Demo case name -> description."""

POOL_SIZE = 64
"""Distinct shapes per case; pairs index into this pool (building shapes is eager NumPy work)."""


@dataclasses.dataclass(frozen=True)
class Scene:
    """A batch of pairs: shapes `a`, `b` and poses with a leading batch axis."""

    case: str
    a: jaxsat.Polytope
    pose_a: jaxsat.Pose
    b: jaxsat.Polytope
    pose_b: jaxsat.Pose

    @property
    def pairs(self) -> int:
        return int(self.pose_a.translation.shape[0])

    def astype(self, dtype) -> Scene:
        """The same scene with every float array cast to `dtype` (masks and indices kept)."""
        def cast(tree):
            return jax.tree.map(
                lambda leaf: leaf.astype(dtype) if jnp.issubdtype(leaf.dtype, jnp.floating)
                else leaf, tree)
        return Scene(self.case, cast(self.a), cast(self.pose_a), cast(self.b), cast(self.pose_b))

    def arguments(self) -> tuple:
        return self.a, self.pose_a, self.b, self.pose_b


@dataclasses.dataclass(frozen=True)
class DemoResult:
    """Measurements for one case."""

    case: str
    pairs: int
    colliding: int
    """Pairs with float64 depth > 0."""
    sign_mismatches: int
    """Pairs where float32 and float64 disagree on depth > 0."""
    compile_f32_s: float
    compile_f64_s: float
    run_f32_s: float
    """Best wall time of one batched float32 call, after a warm-up."""
    max_depth_error: float
    """max |depth_f32 - depth_f64| over all pairs."""
    max_depth_error_colliding: float
    """max |depth_f32 - depth_f64| over pairs with float64 depth > 0."""
    max_normal_angle: float
    """Largest angle (rad) between float32 and float64 normals among pairs colliding in both."""
    depth_f64: np.ndarray
    normal_f64: np.ndarray

    @property
    def pairs_per_second(self) -> float:
        return self.pairs / self.run_f32_s


def _random_polygon(rng: np.random.Generator) -> np.ndarray:
    """3-8 vertices on a random ellipse (always strictly convex), counter-clockwise."""
    count = int(rng.integers(3, 9))
    gaps = rng.uniform(0.5, 1.5, count)
    angles = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.cumsum(gaps) / gaps.sum()
    axes = rng.uniform(0.3, 0.8, 2)
    tilt = rng.uniform(0, np.pi)
    ring = np.stack([axes[0] * np.cos(angles), axes[1] * np.sin(angles)], axis=1)
    rotation = np.array([[np.cos(tilt), -np.sin(tilt)], [np.sin(tilt), np.cos(tilt)]])
    return ring @ rotation.T


def _random_hull_points(rng: np.random.Generator, count: int = 20) -> np.ndarray:
    """`count` random points on a random ellipsoid: every one is a hull vertex."""
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return directions * rng.uniform(0.3, 0.8, 3)


def _shape_pool(case: str, rng: np.random.Generator, size: int) -> jaxsat.Polytope:
    if case == "2d-polygons":
        shapes = [jaxsat.polygon(_random_polygon(rng), max_vertices=8) for _ in range(size)]
    elif case == "3d-boxes":
        shapes = [jaxsat.box(rng.uniform(0.15, 0.6, 3)) for _ in range(size)]
    elif case == "3d-hulls":
        shapes = [jaxsat.polyhedron(_random_hull_points(rng), max_vertices=20)
                  for _ in range(size)]
    else:
        raise ValueError(f"unknown case {case!r}; choose from {sorted(CASES)}")
    return jaxsat.stack(shapes)


def _random_poses(case: str, rng: np.random.Generator, pairs: int):
    """Poses of a near the origin and of b at a random offset (about half the pairs overlap)."""
    dim = 2 if case.startswith("2d") else 3
    centres = rng.uniform(-1.0, 1.0, (pairs, dim))
    directions = rng.normal(size=(pairs, dim))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    offsets = directions * rng.uniform(0.0, 1.8, (pairs, 1))
    if dim == 2:
        make = jax.vmap(jaxsat.pose2)
        angles = rng.uniform(-np.pi, np.pi, (2, pairs))
        pose_a = make(centres[:, 0], centres[:, 1], angles[0])
        pose_b = make(centres[:, 0] + offsets[:, 0], centres[:, 1] + offsets[:, 1], angles[1])
    else:
        make = jax.vmap(jaxsat.pose3)
        quaternions = rng.normal(size=(2, pairs, 4))
        pose_a = make(jnp.asarray(centres), jnp.asarray(quaternions[0]))
        pose_b = make(jnp.asarray(centres + offsets), jnp.asarray(quaternions[1]))
    return pose_a, pose_b


def make_scene(case: str, pairs: int, seed: int = 0, pool_size: int = POOL_SIZE) -> Scene:
    """`pairs` random pairs for `case`, in float64 (needs `jax_enable_x64`).

    Shapes are drawn from a pool of `pool_size` distinct shapes by random indices.
    """
    if not jax.config.read("jax_enable_x64"):
        raise RuntimeError('make_scene needs jax.config.update("jax_enable_x64", True)')
    rng = np.random.default_rng([seed, sorted(CASES).index(case) if case in CASES else 99])
    pool = _shape_pool(case, rng, min(pool_size, 2 * pairs))
    count = pool.vertices.shape[0]
    pick_a, pick_b = rng.integers(0, count, (2, pairs))
    a = jax.tree.map(lambda leaf: leaf[pick_a], pool)
    b = jax.tree.map(lambda leaf: leaf[pick_b], pool)
    pose_a, pose_b = _random_poses(case, rng, pairs)
    return Scene(case, a, pose_a, b, pose_b)


def _normal_angles(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Angles (rad) between rows of unit vectors, accurate for tiny angles."""
    dot = np.sum(first * second, axis=-1)
    if first.shape[-1] == 2:
        cross = np.abs(first[:, 0] * second[:, 1] - first[:, 1] * second[:, 0])
    else:
        cross = np.linalg.norm(np.cross(first, second), axis=-1)
    return np.arctan2(cross, dot)


def _timed(kernel: Callable, arguments: tuple, repeats: int):
    """(result, first-call seconds, best later-call seconds) of `kernel(*arguments)`."""
    start = time.perf_counter()
    result = jax.block_until_ready(kernel(*arguments))
    first = time.perf_counter() - start
    best = math.inf
    for _ in range(repeats):
        start = time.perf_counter()
        result = jax.block_until_ready(kernel(*arguments))
        best = min(best, time.perf_counter() - start)
    return result, first, best


def run_case(scene64: Scene, repeats: int = 3) -> DemoResult:
    """Run `jax.vmap(jaxsat.penetration)` on a float64 scene and on its float32 copy.

    The float32 inputs are the float64 scene rounded to float32, and the float64 reference
    runs on exactly those rounded inputs, so the errors measure float32 arithmetic only.
    """
    scene32 = scene64.astype(jnp.float32)
    reference = scene32.astype(jnp.float64)

    # Compile time: the first call (trace + compile + run) minus a warm call.
    kernel = jax.jit(jax.vmap(jaxsat.penetration))
    result32, first32, run32 = _timed(kernel, scene32.arguments(), max(1, repeats))
    result64, first64, run64 = _timed(kernel, reference.arguments(), 1)

    depth32 = np.asarray(result32.depth, np.float64)
    depth64 = np.asarray(result64.depth)
    normal32 = np.asarray(result32.normal, np.float64)
    normal64 = np.asarray(result64.normal)
    both = (depth32 > 0) & (depth64 > 0)
    angles = _normal_angles(normal32[both], normal64[both])
    errors = np.abs(depth32 - depth64)
    return DemoResult(
        case=scene64.case,
        pairs=scene64.pairs,
        colliding=int(np.sum(depth64 > 0)),
        sign_mismatches=int(np.sum((depth32 > 0) != (depth64 > 0))),
        compile_f32_s=max(first32 - run32, 0.0),
        compile_f64_s=max(first64 - run64, 0.0),
        run_f32_s=run32,
        max_depth_error=float(np.max(errors)),
        max_depth_error_colliding=float(np.max(errors[depth64 > 0], initial=0.0)),
        max_normal_angle=float(np.max(angles)) if angles.size else 0.0,
        depth_f64=depth64,
        normal_f64=normal64,
    )


def format_report(results: list[DemoResult]) -> str:
    header = (f"{'case':<12} {'pairs':>6} {'collide':>7} {'compile f32':>11} {'compile f64':>11} "
              f"{'f32 pairs/s':>11} {'max|depth err|':>14} {'(colliding)':>11} "
              f"{'max normal angle':>16}")
    lines = [header, "-" * len(header)]
    for r in results:
        lines.append(
            f"{r.case:<12} {r.pairs:>6} {r.colliding:>7} {r.compile_f32_s:>10.2f}s "
            f"{r.compile_f64_s:>10.2f}s {r.pairs_per_second:>11.3g} {r.max_depth_error:>14.2e} "
            f"{r.max_depth_error_colliding:>11.2e} {r.max_normal_angle:>12.2e} rad")
    lines += [
        "",
        "collide: float64 depth > 0.  compile: first call minus a warm call.  f32 pairs/s: one",
        "jax.jit(jax.vmap(jaxsat.penetration)) call on the whole batch, best of repeats after a"
        " warm-up.",
        "max|depth err|: float32 against float64 on the same float32-rounded inputs, over all"
        " pairs and",
        "over colliding pairs; max normal angle: over pairs colliding in both (shapes are ~1 unit"
        " across).",
    ]
    mismatches = [f"{r.case}: {r.sign_mismatches}" for r in results if r.sign_mismatches]
    if mismatches:
        lines.append("pairs where float32 and float64 disagree on collision (touching within "
                     "float32 rounding): " + ", ".join(mismatches))
    return "\n".join(lines)


def _world(vertices: np.ndarray, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    return vertices @ rotation.T + translation


def _pair_arrays(scene: Scene, index: int):
    """World vertices (valid only) of a and b, plus the hull edges for 3D shapes."""
    out = []
    for shape, pose in ((scene.a, scene.pose_a), (scene.b, scene.pose_b)):
        vertices = np.asarray(shape.vertices[index])
        mask = np.asarray(shape.vertex_mask[index])
        world = _world(vertices, np.asarray(pose.rotation[index]),
                       np.asarray(pose.translation[index]))
        edges = np.asarray(shape.edge_endpoints[index])[np.asarray(shape.hull_edge_mask[index])]
        out.append((world[mask], world, edges))
    return out


def _pick(depths: np.ndarray, colliding: int, separated: int) -> list[int]:
    hits = np.flatnonzero(depths > 0.05)[:colliding]
    misses = np.flatnonzero(depths < -0.05)[:separated]
    return [int(i) for i in np.concatenate([hits, misses])]


def plot_scenes(path: str, scenes: dict[str, Scene], results: dict[str, DemoResult]) -> str:
    """Draw a few pairs with their normals; return the path written. Needs matplotlib."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Polygon

    colours = {True: ("#d62728", "#ff9896"), False: ("#2ca02c", "#98df8a")}
    figure = Figure(figsize=(16, 8), layout="constrained")
    has_3d = [case for case in ("3d-boxes", "3d-hulls") if case in scenes]
    columns = 3 + (1 if has_3d else 0)
    figure.suptitle("jaxsat.penetration: normal from a's centre, length |depth| "
                    "(red: colliding, dotted outline: b moved by depth*normal; green: separated)")

    if "2d-polygons" in scenes:
        scene, result = scenes["2d-polygons"], results["2d-polygons"]
        for slot, index in enumerate(_pick(result.depth_f64, 3, 3)):
            axes = figure.add_subplot(2, columns, (slot // 3) * columns + slot % 3 + 1)
            (a_pts, _, _), (b_pts, _, _) = _pair_arrays(scene, index)
            depth, normal = float(result.depth_f64[index]), result.normal_f64[index]
            edge, fill = colours[depth > 0]
            axes.add_patch(Polygon(a_pts, closed=True, facecolor=fill, edgecolor=edge, lw=2))
            axes.add_patch(Polygon(b_pts, closed=True, facecolor=fill, edgecolor=edge, lw=2,
                                   alpha=0.6, hatch="//"))
            if depth > 0:
                axes.add_patch(Polygon(b_pts + depth * normal, closed=True, fill=False,
                                       edgecolor="k", lw=1, linestyle=":"))
            centre = a_pts.mean(axis=0)
            axes.annotate("", xy=centre + abs(depth) * normal, xytext=centre,
                          arrowprops={"arrowstyle": "->", "color": "k", "lw": 2})
            axes.text(*a_pts.mean(axis=0), "a", ha="right", va="top")
            axes.text(*b_pts.mean(axis=0), "b", ha="right", va="top")
            axes.set_title(f"2D pair {index}: depth {depth:+.3f}", color=edge)
            axes.set_aspect("equal")
            axes.autoscale_view()
            axes.margins(0.15)

    for row, case in enumerate(has_3d[:2]):
        scene, result = scenes[case], results[case]
        index = _pick(result.depth_f64, 1, 0)
        if not index:
            continue
        index = index[0]
        axes = figure.add_subplot(2, columns, row * columns + columns, projection="3d")
        depth, normal = float(result.depth_f64[index]), result.normal_f64[index]
        edge, _ = colours[depth > 0]
        for (_, world, edges), style in zip(_pair_arrays(scene, index), ("-", "--"),
                                                strict=True):
            for start, end in edges:
                segment = world[[start, end]]
                axes.plot(*segment.T, color=edge, linestyle=style, lw=1.2)
        (a_pts, _, _), (b_pts, _, _) = _pair_arrays(scene, index)
        centre = a_pts.mean(axis=0)
        axes.quiver(*centre, *(abs(depth) * normal), color="k", lw=2)
        points = np.concatenate([a_pts, b_pts, [centre + abs(depth) * normal]])
        middle = (points.max(axis=0) + points.min(axis=0)) / 2
        half = (points.max(axis=0) - points.min(axis=0)).max() / 2
        axes.set(xlim=(middle[0] - half, middle[0] + half),
                 ylim=(middle[1] - half, middle[1] + half),
                 zlim=(middle[2] - half, middle[2] + half))
        axes.set_title(f"{case} pair {index}: depth {depth:+.3f}\n(a solid, b dashed)",
                       color=edge)
        axes.set_box_aspect((1, 1, 1))
    figure.savefig(path, dpi=90)
    return path


def run_demo(pairs: int, seed: int, output: str | None, repeats: int = 3,
             cases: list[str] | None = None, echo: Callable[[str], None] = print) -> list:
    """The whole demo; `output=None` skips the picture. Returns the per-case results."""
    cases = list(CASES) if cases is None else cases
    echo(f"jaxsat {jaxsat.__version__} demo: jax {jax.__version__}, backend "
         f"{jax.default_backend()} ({jax.device_count()} device(s)), {pairs} pairs per case, "
         f"seed {seed}")
    scenes, results = {}, {}
    for case in cases:
        start = time.perf_counter()
        scenes[case] = make_scene(case, pairs, seed)
        echo(f"  built {case}: {CASES[case]} ({time.perf_counter() - start:.1f}s)")
        results[case] = run_case(scenes[case], repeats)
    echo("")
    echo(format_report([results[case] for case in cases]))
    if output is not None:
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            echo('\nmatplotlib is not installed, so no picture was drawn; install it with '
                 'pip install "jaxsat[plot]" (or pip install -e ".[plot]" in a checkout).')
        else:
            echo(f"\nsaved picture: {plot_scenes(output, scenes, results)}")
    return [results[case] for case in cases]

