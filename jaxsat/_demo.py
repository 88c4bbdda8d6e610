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

__all__ = ["CASES", "DemoResult", "PairDrawing", "Panel", "Scene", "choose_panels", "draw_scenes",
           "make_scene", "pair_drawing", "plot_scenes", "run_case", "run_demo"]

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


@dataclasses.dataclass(frozen=True)
class PairDrawing:
    """What the picture draws for one pair (world coordinates, float64 NumPy).

    Colliding (penetration depth > 0): an arrow from `start`, the point of b deepest inside
    a, to `end` = start + depth * normal, on a's surface: the smallest translation of b
    that separates the pair (moving b by `end - start` leaves the two touching). Separated:
    `start` and `end` are the closest points of a and b (`jaxsat.closest_points`), and
    `value` is their Euclidean distance, which the SAT gap of `penetration` can under-state.
    """

    colliding: bool
    value: float
    """The depth (colliding) or the distance (separated), >= 0."""
    start: np.ndarray
    """(D,): colliding: the tail of the arrow, on b; separated: the closest point of a."""
    end: np.ndarray
    """(D,): colliding: the head of the arrow, on a; separated: the closest point of b."""

    @property
    def label(self) -> str:
        return f"{'depth' if self.colliding else 'distance'} {self.value:.3f}"

    @property
    def shift(self) -> np.ndarray:
        """How far the picture moves b for its dotted outline: the arrow (zero if separated)."""
        return self.end - self.start if self.colliding else np.zeros_like(self.start)


def pair_drawing(a: jaxsat.Polytope, pose_a: jaxsat.Pose, b: jaxsat.Polytope,
                 pose_b: jaxsat.Pose) -> PairDrawing:
    """The arrow or the closest points to draw for one (unbatched) pair; see `PairDrawing`."""
    closest = jaxsat.closest_points(a, pose_a, b, pose_b)
    distance = float(closest.signed_distance)
    point_a, point_b = (np.asarray(point, np.float64) for point in (closest.point_a,
                                                                   closest.point_b))
    if distance < 0:
        # Overlapping, point_b is b's point deepest inside a and point_a = point_b + depth *
        # normal (the penetration normal): the arrow from one to the other is the move.
        return PairDrawing(True, -distance, point_b, point_a)
    return PairDrawing(False, distance, point_a, point_b)


@dataclasses.dataclass(frozen=True)
class Panel:
    """One panel of the picture: pair `index` of the scene of `case`, in row `row` (0: a
    colliding pair, 1: a separated one) and column `column`."""

    row: int
    column: int
    case: str
    index: int | None
    """None when the scene has no pair of the kind wanted (the panel says so)."""


def _candidates(depths: np.ndarray, colliding: bool) -> np.ndarray:
    """Pair indices worth drawing, readable ones first: a visible but modest overlap, or a
    gap (SAT, so the distance is at least as large) neither tiny nor far beyond the shapes."""
    if colliding:
        preferred, fallback = (depths > 0.05) & (depths < 0.25), depths > 0
    else:
        preferred, fallback = (depths < -0.08) & (depths > -0.4), depths < 0
    return np.concatenate([np.flatnonzero(preferred), np.flatnonzero(fallback & ~preferred)])


def choose_panels(results: dict[str, DemoResult]) -> list[Panel]:
    """The panels of `plot_scenes`: row 0 colliding pairs, row 1 separated pairs; two columns
    of 2D pairs (three without 3D cases), then one column per 3D case."""
    three_d = [case for case in ("3d-boxes", "3d-hulls") if case in results]
    columns = [("2d-polygons", slot) for slot in range(3 if not three_d else 2)
               if "2d-polygons" in results] + [(case, 0) for case in three_d]
    panels = []
    for row in (0, 1):
        for column, (case, slot) in enumerate(columns):
            picks = _candidates(results[case].depth_f64, colliding=row == 0)
            index = int(picks[slot]) if slot < len(picks) else None
            panels.append(Panel(row, column, case, index))
    return panels


def _item(tree, index: int):
    """Entry `index` of a batched Polytope or Pose."""
    return jax.tree.map(lambda leaf: leaf[index], tree)


def _world_vertices(shape: jaxsat.Polytope, pose: jaxsat.Pose) -> np.ndarray:
    """The real vertices of an unbatched shape, in the world frame (in ring order in 2D)."""
    world = np.asarray(pose.apply(shape.vertices), np.float64)
    return world[np.asarray(shape.vertex_mask)]


def _world_faces(shape: jaxsat.Polytope, pose: jaxsat.Pose) -> list[tuple[np.ndarray, np.ndarray]]:
    """(vertex loop, outward unit normal) of every face of an unbatched 3D shape, in the world
    frame. The shape stores one normal per face direction (`face_normals`, unique up to sign),
    so both signs are tried: a face is the set of vertices extreme along a normal, if it has
    at least three."""
    corners = _world_vertices(shape, pose)
    rotation = np.asarray(pose.rotation, np.float64)
    normals = np.asarray(shape.face_normals, np.float64)[np.asarray(shape.face_mask)] @ rotation.T
    tolerance = 1e-6 * (np.abs(corners - corners.mean(axis=0)).max() + 1e-12)
    faces = []
    for normal in np.concatenate([normals, -normals]):
        heights = corners @ normal
        loop = corners[heights >= heights.max() - tolerance]
        if len(loop) >= 3:
            offsets = loop - loop.mean(axis=0)
            first = offsets[np.argmax(np.linalg.norm(offsets, axis=1))]
            first = first / np.linalg.norm(first)
            angles = np.arctan2(offsets @ np.cross(normal, first), offsets @ first)
            faces.append((loop[np.argsort(angles)], normal))
    return faces


COLOURS = {"a": "#1f77b4", "b": "#ff7f0e"}
"""Shape a blue, shape b orange, in every panel."""
ROW_COLOURS = ("#b2182b", "#1b7837")
"""Panel titles: colliding red, separated green."""


def _shaded(colour: str, normal: np.ndarray, light: np.ndarray) -> tuple[float, ...]:
    """`colour` lit by a directional light: ambient plus Lambert."""
    from matplotlib.colors import to_rgb

    brightness = 0.5 + 0.5 * max(float(normal @ light), 0.0)
    return tuple(min(1.0, channel * brightness + 0.15 * (1 - brightness)) for channel in
                 to_rgb(colour))


def _camera(normal: np.ndarray) -> tuple[float, float, np.ndarray]:
    """(elevation, azimuth) in degrees of a view across `normal` (so that the arrow or the
    witness segment lies nearly in the picture plane), and the unit view vector."""
    elevation = 18.0
    azimuth = np.degrees(np.arctan2(normal[1], normal[0])) - 90.0
    if np.hypot(normal[0], normal[1]) < 0.3:  # nearly vertical: look from the side, a bit lower
        elevation, azimuth = 8.0, -60.0
    e, z = np.radians(elevation), np.radians(azimuth)
    return elevation, azimuth, np.array([np.cos(e) * np.cos(z), np.cos(e) * np.sin(z),
                                         np.sin(e)])


def _title(panel: Panel, drawing: PairDrawing | None) -> tuple[str, str]:
    """(title, colour) of a panel: the kind of pair its drawing shows (not its row, should a
    pair near contact fall on the other side in float64), and the depth or distance."""
    what = {"2d-polygons": "2D polygons", "3d-boxes": "3D boxes",
            "3d-hulls": "3D hulls"}.get(panel.case, panel.case)
    colliding = panel.row == 0 if drawing is None else drawing.colliding
    kind, colour = ("colliding", ROW_COLOURS[0]) if colliding else ("separated", ROW_COLOURS[1])
    if drawing is None:
        return f"{what}: no {kind} pair", colour
    return f"{what}, {kind} (pair {panel.index})\n{drawing.label}", colour


def _draw_2d(axes, a_points, b_points, drawing: PairDrawing) -> None:
    from matplotlib.patches import Polygon

    for name, points in (("a", a_points), ("b", b_points)):
        axes.add_patch(Polygon(points, closed=True, facecolor=COLOURS[name], alpha=0.45,
                               edgecolor=COLOURS[name], lw=2))
        axes.text(*points.mean(axis=0), name, ha="center", va="center", fontsize=13,
                  fontweight="bold", color="0.15")
    if drawing.colliding:
        axes.add_patch(Polygon(b_points + drawing.shift, closed=True, fill=False,
                               edgecolor="k", lw=1.2, linestyle=":"))
        axes.annotate("", xy=drawing.end, xytext=drawing.start,
                      arrowprops={"arrowstyle": "-|>", "color": "k", "lw": 2.2,
                                  "mutation_scale": 20, "shrinkA": 0, "shrinkB": 0})
    else:
        segment = np.stack([drawing.start, drawing.end])
        axes.plot(*segment.T, color="k", lw=1.5, marker="o", markersize=6)
    points = np.concatenate([a_points, b_points, b_points + drawing.shift])
    low, high = points.min(axis=0), points.max(axis=0)
    middle, half = (low + high) / 2, 0.55 * (high - low).max()
    axes.set(xlim=(middle[0] - half, middle[0] + half), ylim=(middle[1] - half, middle[1] + half),
             aspect="equal", xticks=[], yticks=[])


def _draw_3d(axes, shapes, drawing: PairDrawing) -> None:
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    direction = drawing.end - drawing.start
    elevation, azimuth, view = _camera(direction / max(np.linalg.norm(direction), 1e-12))
    light = view + np.array([0.0, 0.0, 0.8])
    light = light / np.linalg.norm(light)
    loops, colours, corners = [], [], []
    for name, (shape, pose) in zip("ab", shapes, strict=True):
        for loop, normal in _world_faces(shape, pose):
            loops.append(loop)
            colours.append((*_shaded(COLOURS[name], normal, light), 0.55))
        corners.append(_world_vertices(shape, pose))
    # One collection for both shapes, so that matplotlib depth-sorts all their faces together.
    axes.add_collection3d(Poly3DCollection(loops, facecolors=colours, edgecolors=(0, 0, 0, 0.35),
                                           linewidths=0.4))
    axes.computed_zorder = False  # the arrow and the points stay on top of the faces
    if drawing.colliding:
        axes.quiver(*drawing.start, *direction, color="k", lw=2.5, arrow_length_ratio=0.4,
                    zorder=5)
        axes.scatter(*drawing.start, color="k", s=12, zorder=5, depthshade=False)
    else:
        segment = np.stack([drawing.start, drawing.end])
        axes.plot(*segment.T, color="k", lw=1.5, zorder=5)
        axes.scatter(*segment.T, color="k", s=30, zorder=6, depthshade=False)
    for name, points in zip("ab", corners, strict=True):
        axes.text(*points.mean(axis=0), name, fontsize=13, fontweight="bold", color="0.1",
                  ha="center", va="center", zorder=7)
    points = np.concatenate(corners)
    low, high = points.min(axis=0), points.max(axis=0)
    middle, half = (low + high) / 2, 0.5 * (high - low).max()
    axes.set(xlim=(middle[0] - half, middle[0] + half), ylim=(middle[1] - half, middle[1] + half),
             zlim=(middle[2] - half, middle[2] + half))
    axes.set_box_aspect((1, 1, 1), zoom=1.3)
    axes.view_init(elev=elevation, azim=azimuth)
    axes.set_axis_off()


def draw_scenes(scenes: dict[str, Scene], results: dict[str, DemoResult]):
    """The demo's picture as a `matplotlib.figure.Figure` (see `plot_scenes`); needs
    matplotlib. Each panel's title ends with its `PairDrawing.label`."""
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    panels = choose_panels(results)
    columns = max(panel.column for panel in panels) + 1 if panels else 1
    figure = Figure(figsize=(max(4 * columns, 9), 9.2 if columns >= 3 else 10),
                    layout="constrained")
    figure.suptitle("jaxsat: a few pairs of the demo's random scenes\nTop row: colliding pairs "
                    "(jaxsat.penetration); bottom row: separated pairs (jaxsat.closest_points)",
                    fontsize=12)
    for panel in panels:
        three_d = not panel.case.startswith("2d")
        axes = figure.add_subplot(2, columns, panel.row * columns + panel.column + 1,
                                  projection="3d" if three_d else None)
        drawing = None
        if panel.index is not None:
            scene = scenes[panel.case]
            shapes = [(_item(scene.a, panel.index), _item(scene.pose_a, panel.index)),
                      (_item(scene.b, panel.index), _item(scene.pose_b, panel.index))]
            drawing = pair_drawing(*shapes[0], *shapes[1])
            if three_d:
                _draw_3d(axes, shapes, drawing)
            else:
                _draw_2d(axes, *(_world_vertices(*shape) for shape in shapes), drawing)
        else:
            axes.set_axis_off()
        title, colour = _title(panel, drawing)
        axes.set_title(title, color=colour, fontsize=11)
    handles = [
        Patch(facecolor=COLOURS["a"], alpha=0.6, label="shape a"),
        Patch(facecolor=COLOURS["b"], alpha=0.6, label="shape b"),
        Line2D([], [], color="k", lw=2, marker=">", markevery=[1],
               label="arrow: the smallest move of b that separates the pair (length = depth)"),
        Line2D([], [], color="k", lw=1.2, linestyle=":",
               label="dotted: b after that move (touching a)"),
        Line2D([], [], color="k", lw=1.5, marker="o",
               label="dots: closest points of a and b (segment length = distance)"),
    ]
    figure.legend(handles=handles, loc="outside lower center", ncol=3 if columns >= 3 else 1,
                  fontsize=10,
                  frameon=False)
    return figure


def plot_scenes(path: str, scenes: dict[str, Scene], results: dict[str, DemoResult]) -> str:
    """Draw a few pairs of each scene and save the picture; return the path written. Needs
    matplotlib.

    Top row, colliding pairs: the arrow, from b's deepest point in a, is the smallest
    translation of b that separates the pair (length: the penetration depth), and a dotted
    outline (2D) shows b moved by it. Bottom row, separated pairs: the closest points of a
    and b, joined by a segment whose length, the Euclidean distance, the title gives.
    """
    draw_scenes(scenes, results).savefig(path, dpi=90)
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

