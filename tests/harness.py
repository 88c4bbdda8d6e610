"""The shared test harness: dtypes and tolerances, named shapes and rotations, random shape
generators by size class, pools and pairs with their oracle world points, hand-built closest
features, the catalogue of degenerate configurations, and the decorator that runs a property
over every public query, size class and dtype.

NumPy and SciPy (through `oracle.py`) build every configuration; jaxsat is called only to
build shapes and poses through its public constructors. `benchmarks/stability.py` imports the
generators, rigid motions and catalogue from here, so the stress benchmark and the tests see
the same configurations.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import numpy as np
import oracle
import pytest
from scipy.spatial import ConvexHull

import jaxsat
from jaxsat._pair import eager_compiler_options

BATCH = 64
"""Every batched call uses this many pairs (the last chunk is padded), so nothing recompiles."""

RELATIVE_TOLERANCE = {np.float64: 1e-9, np.float32: 1e-4}
"""Tolerance on distances and points, relative to the shapes' size (larger bounding radius)."""

UNIT_TOLERANCE = {np.float64: 1e-12, np.float32: 1e-5}
"""Tolerance on |normal| - 1."""

NORMAL_TOLERANCE = {np.float64: 1e-7, np.float32: 1e-3}
"""Tolerance on the normal, compared only where the oracle's optimal facet is unique."""

DTYPES = [np.float64, np.float32]
DTYPE_IDS = ["float64", "float32"]

FAST_COMPILE = eager_compiler_options(jax.default_backend())
"""XLA's cheaper CPU settings (those of eager calls; None, XLA's defaults, on a GPU), for test
kernels that batch many pairs with their derivatives (about half their compile time). Not what
a user's own jit runs: the oracle tests of test_sat and test_distance, the scene tests and the
benchmarks use the default build. These settings have produced NaN Hessian entries and,
combined, a wrong GJK simplex where the default build did not, so a failure seen only under
them is checked against the default build first."""


# --------------------------------------------------------------------------------------------
# Named shapes (raw local points) and rotations.
# --------------------------------------------------------------------------------------------


def inner_jaxprs(eqn):
    """The jaxprs an equation holds in its parameters (loop bodies, branches, custom rules,
    nested jits), as open jaxprs: what `jax.extend.core.jaxprs_in_params` gives on newer JAX
    (jax 0.6, the floor, lacks it)."""
    for param in eqn.params.values():
        for sub in param if isinstance(param, (tuple, list)) else (param,):
            inner = getattr(sub, "jaxpr", None)
            if inner is not None:
                yield getattr(inner, "jaxpr", inner)


def f32(values) -> np.ndarray:
    """Values rounded to float32 and back: inputs both dtypes see exactly."""
    return np.asarray(values, np.float64).astype(np.float32).astype(np.float64)


def corners(half) -> np.ndarray:
    """Corners of the centred rectangle or cuboid with half extents `half` (ring order in 2D)."""
    half = np.asarray(half, np.float64)
    if len(half) == 2:
        return np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], np.float64) * half
    return np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)],
                    np.float64) * half


def quaternion(axis, angle) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of the turn by `angle` about `axis`."""
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis])


def quaternion_product(p, q) -> np.ndarray:
    """Hamilton product of quaternions (..., 4) (w, x, y, z), broadcasting."""
    w1, x1, y1, z1 = np.moveaxis(np.asarray(p, np.float64), -1, 0)
    w2, x2, y2, z2 = np.moveaxis(np.asarray(q, np.float64), -1, 0)
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2],
                    -1)


def rotation_matrices(dim: int, turns) -> np.ndarray:
    """Rotation matrices (N, dim, dim) of angles (N,) in 2D or quaternions (N, 4) in 3D, by the
    oracle's SciPy rotations (a zero quaternion gives the identity, as `pose3` does)."""
    if dim == 2:
        return np.stack([oracle.rotation_2d(float(angle)) for angle in turns])
    return np.stack([oracle.rotation_3d(q) if np.any(q) else np.eye(3) for q in turns])


IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
SQUARE = corners([1.0, 1.0])
RECT = corners([1.0, 0.5])
CUBE = corners([1.0, 1.0, 1.0])
BRICK = corners([1.0, 0.5, 0.25])
PENTAGON = np.array([[0.9, 0.0], [0.3, 0.8], [-0.6, 0.55], [-0.7, -0.4], [0.2, -0.75]])
TRIANGLE = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
DIAMOND = np.array([[0.0, 0.0], [1.0, 1.0], [0.0, 2.0], [-1.0, 1.0]])
"""Bottom tip at its origin."""
DISPHENOID = np.array([[-1.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, -1.0, 0.0], [0.0, 1.0, 0.0]])
"""Tetrahedron: top edge along x at z = 1, bottom edge along y at z = 0."""
SPIKE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 1.0], [-0.5, 0.75, 1.0], [-0.5, -0.75, 1.0]])
"""Tetrahedron with its apex at its origin, pointing down."""
OCTAHEDRON = np.concatenate([np.eye(3), -np.eye(3)])
HULL7 = np.array([[0.8, 0.1, 0.0], [-0.5, 0.6, 0.2], [-0.3, -0.7, 0.1], [0.1, 0.2, 0.9],
                  [0.2, -0.1, -0.8], [0.6, 0.5, 0.5], [-0.4, -0.2, -0.6]])
"""An irregular hull with 7 vertices (padded to 8 in hull8)."""
Q_GENERIC = quaternion([1.0, 2.0, 3.0], 0.7)
Q_OTHER = quaternion([-2.0, 0.5, 1.0], 2.1)


def random_motion(dim: int, count: int, rng: np.random.Generator, unit: float = 1.0):
    """`count` random rigid motions: (angles (N,) or unit quaternions (N, 4), shifts (N, dim))
    with shifts in [-2, 2] * unit."""
    shift = rng.uniform(-2, 2, (count, dim)) * unit
    if dim == 2:
        return rng.uniform(-np.pi, np.pi, count), shift
    turn = rng.normal(size=(count, 4))
    return turn / np.linalg.norm(turn, axis=1, keepdims=True), shift


def apply_motion(params: np.ndarray, dim: int, motion) -> np.ndarray:
    """Pose parameter rows (N, 3) (x, y, angle) or (N, 7) (translation, quaternion) after the
    rigid motions `motion` (one per row), applied in the world frame."""
    turn, shift = motion
    moved = np.einsum("nij,nj->ni", rotation_matrices(dim, turn), params[:, :dim]) + shift
    if dim == 2:
        return np.concatenate([moved, params[:, 2:] + turn[:, None]], axis=1)
    return np.concatenate([moved, quaternion_product(turn, params[:, 3:])], axis=1)

# --------------------------------------------------------------------------------------------
# Random shapes: every generator returns (raw local points, factory(dtype)).
# --------------------------------------------------------------------------------------------


def _ellipse_polygon(rng: np.random.Generator, count: int, scale: float) -> np.ndarray:
    """`count` vertices on a random off-centre ellipse (strictly convex, no flat vertex)."""
    while True:
        angles = np.sort(rng.uniform(0, 2 * np.pi, count))
        if np.min(np.diff(np.append(angles, angles[0] + 2 * np.pi))) > 0.2:
            break
    circle = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    stretch = np.diag(rng.uniform(0.3, 1.0, 2)) @ oracle.rotation_2d(rng.uniform(0, 2 * np.pi))
    return (circle @ stretch.T + rng.uniform(-0.3, 0.3, 2)) * scale


def _polygon8(rng: np.random.Generator, scale: float):
    """3 to 8 vertices padded to 8: a box, a regular polygon or a random (either winding)."""
    kind = rng.integers(4)
    if kind == 0:
        half = rng.uniform(0.2, 1.0, 2) * scale
        corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half
        return corners, lambda dtype: jaxsat.box(half.astype(dtype), max_vertices=8)
    if kind == 1:
        sides = int(rng.integers(3, 9))
        radius = float(rng.uniform(0.3, 1.0)) * scale
        angles = 2 * np.pi * np.arange(sides) / sides
        corners = radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)
        return corners, lambda dtype: jaxsat.regular_polygon(sides, radius, 8, dtype=dtype)
    points = _ellipse_polygon(rng, int(rng.integers(3, 9)), scale)
    if kind == 3:
        points = points[::-1]
    return points, lambda dtype: jaxsat.polygon(points.astype(dtype), 8)


def _hexagon(rng: np.random.Generator, scale: float):
    """A random hexagon without padding (every vertex real)."""
    points = _ellipse_polygon(rng, 6, scale)
    return points, lambda dtype: jaxsat.polygon(points.astype(dtype))


def _box(rng: np.random.Generator, scale: float, max_vertices=None):
    half = rng.uniform(0.2, 1.0, 3) * scale
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    return signs * half, lambda dtype: jaxsat.box(half.astype(dtype), max_vertices, dtype=dtype)


def _hull(rng: np.random.Generator, scale: float, count: int):
    """Hull of `count` points: on a stretched sphere, Gaussian (some interior), or a box."""
    if rng.integers(4) == 0:
        return _box(rng, scale, max_vertices=count)
    points = rng.normal(size=(count, 3))
    if rng.integers(2) == 0:
        points /= np.linalg.norm(points, axis=1, keepdims=True)
    else:
        points /= np.max(np.linalg.norm(points, axis=1))
    stretch = np.diag(rng.uniform(0.3, 1.0, 3)) @ oracle.rotation_3d(rng.normal(size=4))
    points = (points @ stretch.T + rng.uniform(-0.3, 0.3, 3)) * scale
    return points, lambda dtype: jaxsat.polyhedron(points.astype(dtype), count, dtype=dtype)


def _mixed_hull(rng: np.random.Generator, scale: float):
    """A hull of 8 or of 20 points (or a box), padded to the 20-vertex size class."""
    points, _ = _hull(rng, scale, int(rng.choice([8, 20])))
    return points, lambda dtype: jaxsat.polyhedron(points.astype(dtype), 20, dtype=dtype)


def point_or_segment_core(rng: np.random.Generator, scale: float, dim: int, radius: float,
                          segment: bool):
    """(raw core points, dtype -> shape) of a sphere (a circle in 2D), or with `segment` of a
    capsule along local z (x in 2D) whose half length is up to `scale`, and 0 one time in ten."""
    if not segment:
        ball = jaxsat.sphere if dim == 3 else jaxsat.circle
        return np.zeros((1, dim)), lambda dtype: ball(np.asarray(radius, dtype))
    half = float(f32(rng.uniform(0.0, 1.0) * scale)) if rng.uniform() > 0.1 else 0.0
    ends = np.zeros((2, dim))
    ends[:, dim - 1 if dim == 3 else 0] = [-half, half]
    return ends, lambda dtype: jaxsat.capsule(np.asarray(half, dtype),
                                              np.asarray(radius, dtype), dim)


def _sphere_or_capsule(rng: np.random.Generator, scale: float):
    """A sphere or a capsule along local z (radius 0.05-0.6), either at random: raw points are
    the core's (one point, or the segment's two ends)."""
    radius = float(f32(rng.uniform(0.05, 0.6) * scale))
    return point_or_segment_core(rng, scale, 3, radius, segment=rng.integers(2) != 0)


def _rounded_or_sharp(rng: np.random.Generator, scale: float):
    """A sphere, a capsule, a rounded box (radius 0.05-0.6) or a sharp box: stacked together
    they are the rounded kind in the box size class. Raw points are the core's."""
    if rng.integers(2) == 0:
        return _sphere_or_capsule(rng, scale)
    corners, box = _box(rng, scale)
    if rng.integers(2) == 0:
        return corners, box
    radius = float(f32(rng.uniform(0.05, 0.6) * scale))
    return corners, lambda dtype: jaxsat.rounded(box(dtype), np.asarray(radius, dtype))


def _circle_capsule_or_polygon(rng: np.random.Generator, scale: float):
    """2D: a circle, a capsule along local x (radius 0.05-0.6), a rounded polygon or a sharp
    one (`_polygon8`), at random: stacked together they are the rounded kind in the 8-vertex
    polygon class. Raw points are the core's."""
    radius = float(f32(rng.uniform(0.05, 0.6) * scale))
    kind = rng.integers(4)
    if kind < 2:
        return point_or_segment_core(rng, scale, 2, radius, segment=kind == 1)
    points, polygon = _polygon8(rng, scale)
    if kind == 2:
        return points, polygon
    return points, lambda dtype: jaxsat.rounded(polygon(dtype), np.asarray(radius, dtype))


GENERATORS = {
    "poly8": (2, _polygon8),
    "hexagon": (2, _hexagon),
    "box": (3, _box),
    "hull8": (3, functools.partial(_hull, count=8)),
    "hull20": (3, functools.partial(_hull, count=20)),
    "hull": (3, _mixed_hull),
    "segment": (3, _sphere_or_capsule),
    "rounded": (3, _rounded_or_sharp),
    "rounded2d": (2, _circle_capsule_or_polygon),
}


@dataclasses.dataclass
class Pool:
    """A few shapes of one size class, stacked, with their raw points (rounded to the dtype)."""

    dim: int
    points: list[np.ndarray]
    """Each shape's raw local points: its vertices, or its core's for a rounded shape; for a
    half-space one row, its normal then its offset."""
    shapes: jaxsat.Polytope
    planes: bool = False
    """The shapes are half-spaces (`jaxsat.HalfSpace`, stacked)."""

    @property
    def radii(self) -> np.ndarray:
        """(N,) float64 radius of each shape (0 for sharp ones and half-spaces), as the
        queries see it."""
        if getattr(self.shapes, "radius", None) is None:
            return np.zeros(len(self.points))
        return np.asarray(self.shapes.radius, np.float64)

    def concatenate(self, other: Pool) -> Pool:
        """This pool's shapes, then `other`'s (same dimension and size class)."""
        assert self.dim == other.dim and self.planes == other.planes
        return Pool(self.dim, self.points + other.points,
                    jax.tree.map(lambda x, y: np.concatenate([np.asarray(x), np.asarray(y)]),
                                 self.shapes, other.shapes), self.planes)


def make_pool(name: str, dtype, rng: np.random.Generator, scale: float = 1.0,
              size: int = 12) -> Pool:
    dim, generate = GENERATORS[name]
    points, shapes = [], []
    for _ in range(size):
        raw, factory = generate(rng, scale)
        shape = factory(dtype)
        assert shape.dtype == dtype
        points.append(raw.astype(dtype).astype(np.float64))
        shapes.append(shape)
    return Pool(dim, points, jaxsat.stack(shapes))


@functools.cache
def pool(name: str, dtype, scale: float = 1.0, seed: int = 0) -> Pool:
    return make_pool(name, dtype, np.random.default_rng([seed, len(name)]), scale)


def plane_pool(normals, offsets, dtype) -> Pool:
    """Half-spaces normal . x <= offset (normals need not be unit), stacked."""
    planes = [jaxsat.halfspace(f32(n), f32(o), dtype=dtype)
              for n, o in zip(normals, offsets, strict=True)]
    rows = [np.concatenate([np.asarray(h.normal, np.float64),
                            [float(np.asarray(h.offset, np.float64))]])[None] for h in planes]
    return Pool(len(rows[0][0]) - 1, rows, jax.tree.map(lambda *x: np.stack(x), *planes), True)


@functools.cache
def pools(name: str, dtype) -> tuple[Pool, Pool]:
    """The pools a and b of the property suite's size class `name`: one pool for both, but
    for "halfspace" random half-spaces (a) against boxes (b)."""
    if name != "halfspace":
        return pool(name, dtype), pool(name, dtype)
    rng = np.random.default_rng([11, len(name)])
    return (plane_pool(rng.normal(size=(12, 3)), rng.uniform(-0.5, 0.5, 12), dtype),
            pool("box", dtype))


def hand_pool(dim: int, shapes_and_points) -> Pool:
    """A pool of hand-made (shape, raw points) entries."""
    shapes, points = zip(*shapes_and_points, strict=True)
    return Pool(dim, [np.asarray(p, np.float64) for p in points], jaxsat.stack(list(shapes)))


# --------------------------------------------------------------------------------------------
# Pairs of shapes and pose parameters, world points for the oracle, batched evaluation.
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass
class Pairs:
    pool_a: Pool
    pool_b: Pool
    index_a: np.ndarray
    index_b: np.ndarray
    params_a: tuple[np.ndarray, ...]
    """2D: (x, y, angle) arrays; 3D: (translations (N, 3), quaternions (N, 4))."""
    params_b: tuple[np.ndarray, ...]
    dtype: type

    @property
    def dim(self) -> int:
        return self.pool_a.dim

    def __len__(self) -> int:
        return len(self.index_a)

    def replace(self, **changes) -> Pairs:
        return dataclasses.replace(self, **changes)

    def subset(self, keep) -> Pairs:
        keep = np.asarray(keep)
        return Pairs(self.pool_a, self.pool_b, self.index_a[keep], self.index_b[keep],
                     tuple(p[keep] for p in self.params_a),
                     tuple(p[keep] for p in self.params_b), self.dtype)

    def swapped(self) -> Pairs:
        return Pairs(self.pool_b, self.pool_a, self.index_b, self.index_a, self.params_b,
                     self.params_a, self.dtype)

    def inputs(self):
        """(a, params_a, b, params_b) with a leading batch axis, for the batched functions."""
        return (take(self.pool_a.shapes, self.index_a), self.params_a,
                take(self.pool_b.shapes, self.index_b), self.params_b)

    def concatenate(self, other: Pairs) -> Pairs:
        """These pairs, then `other`'s, over concatenated pools (so that one compiled function
        serves both)."""
        join = lambda x, y: tuple(np.concatenate(p) for p in zip(x, y, strict=True))  # noqa: E731
        return Pairs(self.pool_a.concatenate(other.pool_a), self.pool_b.concatenate(other.pool_b),
                     np.concatenate([self.index_a, other.index_a + len(self.pool_a.points)]),
                     np.concatenate([self.index_b, other.index_b + len(self.pool_b.points)]),
                     join(self.params_a, other.params_a), join(self.params_b, other.params_b),
                     self.dtype)

    def moved(self, motion) -> Pairs:
        """Both shapes of every pair moved by one rigid motion (turn, shift) in the world frame
        (computed in float64, then rounded to the pairs' dtype)."""
        motions = tuple(np.repeat(np.asarray(m)[None], len(self), axis=0) for m in motion)
        move = lambda params: param_columns(apply_motion(  # noqa: E731
            param_rows(params).astype(np.float64), self.dim, motions), self.dtype)
        return self.replace(params_a=move(self.params_a), params_b=move(self.params_b))


def param_rows(params) -> np.ndarray:
    """Pose parameter columns, (x, y, angle) or (translations, quaternions), as rows (N, 3) or
    (N, 7)."""
    if len(params) == 3:
        return np.stack(params, axis=1)
    return np.concatenate(params, axis=1)


def param_columns(rows, dtype) -> tuple[np.ndarray, ...]:
    """Rows (N, 3) or (N, 7) of pose parameters as the columns `Pairs` holds, in `dtype`."""
    rows = np.asarray(rows, np.float64).astype(dtype)
    if rows.shape[1] == 3:
        return rows[:, 0], rows[:, 1], rows[:, 2]
    return rows[:, :3], rows[:, 3:]


def random_params(dim: int, count: int, rng: np.random.Generator, dtype, spread: float = 2.0):
    """Random pose parameters: positions in [-spread, spread], any rotation."""
    if dim == 2:
        x, y = rng.uniform(-spread, spread, (2, count))
        return tuple(v.astype(dtype) for v in (x, y, rng.uniform(-np.pi, np.pi, count)))
    quaternions = rng.normal(size=(count, 4)) * rng.uniform(0.5, 2.0, (count, 1))
    return (rng.uniform(-spread, spread, (count, 3)).astype(dtype), quaternions.astype(dtype))


def random_pairs(pool_a: Pool, pool_b: Pool, count: int, rng: np.random.Generator, dtype,
                 distance=(0.0, 2.5), scale: float = 1.0) -> Pairs:
    """Random pairs whose origins are `distance` * scale apart (uniform), any rotations."""
    dim = pool_a.dim
    params_a = random_params(dim, count, rng, dtype, spread=2.0 * scale)
    directions = rng.normal(size=(count, dim))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    offsets = directions * rng.uniform(*distance, (count, 1)) * scale
    fresh = random_params(dim, count, rng, dtype)
    if dim == 2:
        params_b = ((params_a[0] + offsets[:, 0]).astype(dtype),
                    (params_a[1] + offsets[:, 1]).astype(dtype), fresh[2])
    else:
        params_b = ((params_a[0] + offsets).astype(dtype), fresh[1])
    return Pairs(pool_a, pool_b, rng.integers(len(pool_a.points), size=count),
                 rng.integers(len(pool_b.points), size=count), params_a, params_b, dtype)


def make_pose(params) -> jaxsat.Pose:
    """One pose from its parameters: (x, y, angle) in 2D, (translation, quaternion) in 3D."""
    return jaxsat.pose2(*params) if len(params) == 3 else jaxsat.pose3(*params)


def take(tree, index):
    """Entries `index` of every leaf, in NumPy: eager JAX indexing would compile a gather for
    every new combination of shapes, which costs more than the queries themselves."""
    return jax.tree.map(lambda leaf: np.asarray(leaf)[index], tree)


def rotations(dim: int, params) -> np.ndarray:
    """Rotation matrices of pose parameter tuples (the angles, or the quaternions)."""
    return rotation_matrices(dim, params[2] if dim == 2 else params[1])


def translations(dim: int, params) -> np.ndarray:
    if dim == 2:
        return np.stack([params[0], params[1]], axis=1).astype(np.float64)
    return np.asarray(params[0], np.float64)


def world_points(pairs: Pairs):
    """(world A, world B) float64 point lists, from raw points and SciPy rotations."""
    world = []
    for shapes, index, params in ((pairs.pool_a, pairs.index_a, pairs.params_a),
                                  (pairs.pool_b, pairs.index_b, pairs.params_b)):
        place = _world_plane if shapes.planes else oracle.to_world
        world.append([place(shapes.points[i], r, t) for i, r, t in
                      zip(index, rotations(pairs.dim, params), translations(pairs.dim, params),
                          strict=True)])
    return world[0], world[1]


def _world_plane(row, rotation, translation) -> np.ndarray:
    """A half-space's (normal, offset) row moved by a pose: the world normal R n and offset
    offset + R n . t."""
    normal = rotation @ row[0, :-1]
    return np.concatenate([normal, [row[0, -1] + normal @ translation]])[None]


@dataclasses.dataclass
class Reference:
    """Oracle values for one pair."""

    value: float
    """Exact signed distance: the distance when apart, minus the depth when overlapping."""
    depth: float
    normal: np.ndarray
    """The oracle's facet normal attaining the (cores') depth (`oracle.Oracle.normal`)."""
    normal_is_unique: bool
    """Where the shapes overlap, whether their penetration normal is unique."""
    size: float
    world_a: np.ndarray
    """a's world points (its core's, for a rounded shape)."""
    world_b: np.ndarray
    radius_a: float = 0.0
    radius_b: float = 0.0
    plane_a: bool = False
    """a is a half-space: `world_a` is its world (normal, offset) row."""
    plane_b: bool = False

    def surface_gap(self, side: int, point) -> float:
        """How far `point` is from the surface of a (side 0) or b (side 1); 0 inside a sharp
        shape."""
        world, radius = ((self.world_a, self.radius_a) if side == 0 else
                         (self.world_b, self.radius_b))
        if (self.plane_a, self.plane_b)[side]:
            return abs(world[0, :-1] @ point - world[0, -1])
        return abs(distance_to_core(point, world) - radius)


def distance_to_core(point, world_core) -> float:
    """Distance from `point` to a shape's core given by its world points: a point or a segment
    (at most two points: spheres, circles, capsules), else their convex hull (0 inside)."""
    if len(world_core) <= 2:
        return oracle.segment_distance(point, point, world_core[0], world_core[-1])
    return oracle.distance_to_hull(ConvexHull(world_core), point)


def segments_in_closed_form(world_a, world_b) -> bool:
    """Whether two cores are points or segments whose Minkowski difference is flat (always in
    3D; parallel segments or a point and a segment in 2D): it touches the origin at most, so
    the closed form of the segments' distance is their signed distance, and the hull oracle
    cannot take it. Two crossing segments in 2D overlap by a depth, which only the oracle
    gives."""
    if len(world_a) > 2 or len(world_b) > 2:
        return False
    if len(world_a[0]) == 3:
        return True
    difference = oracle.minkowski_difference(world_a, world_b)
    spread = np.linalg.svd(difference - difference.mean(axis=0), compute_uv=False)
    return bool(spread[-1] <= 1e-9 * max(spread[0], 1e-300))


def core_signed_distance(world_a, world_b) -> float:
    """The exact signed distance of two cores given by their world points: the
    Minkowski-difference oracle, or the closed form of two points or segments where that
    difference is flat (`segments_in_closed_form`)."""
    if segments_in_closed_form(world_a, world_b):
        return oracle.segment_distance(world_a[0], world_a[-1], world_b[0], world_b[-1])
    found = oracle.evaluate(world_a, world_b)
    return found.distance if found.depth < 0 else -found.depth


def references(pairs: Pairs, tie_factor: float = 10.0) -> list[Reference]:
    """The oracle's answer for each pair: the Minkowski difference of the world points (of
    the cores, minus the radii, for rounded shapes), or for two points or segments whose
    difference is flat (`segments_in_closed_form`) the closed form of the cores' closest
    points minus the radii."""
    world_a, world_b = world_points(pairs)
    radii_a = pairs.pool_a.radii[pairs.index_a]
    radii_b = pairs.pool_b.radii[pairs.index_b]
    refs = []
    if pairs.pool_a.planes or pairs.pool_b.planes:
        return [_plane_reference(a, b, ra, rb, pairs.pool_a.planes)
                for a, b, ra, rb in zip(world_a, world_b, radii_a, radii_b, strict=True)]
    for a, b, ra, rb in zip(world_a, world_b, radii_a, radii_b, strict=True):
        size = max(oracle.bounding_radius(a) + ra, oracle.bounding_radius(b) + rb)
        tie = tie_factor * RELATIVE_TOLERANCE[pairs.dtype] * size
        if segments_in_closed_form(a, b):
            p, q = oracle.segment_closest_points(a[0], a[-1], b[0], b[-1])
            gap = float(np.linalg.norm(q - p))
            value = gap - ra - rb
            normal = (q - p) / gap if gap > 0 else np.zeros(pairs.dim)
            refs.append(Reference(value, -value, normal, gap > tie, size, a, b, ra, rb))
            continue
        o = oracle.evaluate(a, b, tie)
        value = o.distance if o.depth < 0 else -o.depth
        if ra == rb == 0 and len(a) > 2 and len(b) > 2:
            refs.append(Reference(value, o.depth, o.normal, o.normal_is_unique, size, a, b))
            continue
        # A rounded pair (or a sphere or capsule against a polytope): the cores' signed
        # distance minus the radii. The queries' normal is the cores' penetration axis where
        # they overlap, else their closest direction, which is unique once they are clear of
        # touching (the stored normal stays the oracle's facet normal).
        unique = o.normal_is_unique if o.depth >= 0 else o.distance > tie
        value -= ra + rb
        refs.append(Reference(value, -value, o.normal, unique, size, a, b, ra, rb))
    return refs


def _plane_reference(a, b, radius_a, radius_b, plane_is_a: bool) -> Reference:
    """A half-space and a shape, by hand: the signed distance is the lowest height of the
    shape's world points above the plane minus its radius, along the plane's normal (from a to
    b: the normal when the half-space is a, minus it when it is b)."""
    plane, points, radius = (a, b, radius_b) if plane_is_a else (b, a, radius_a)
    normal = plane[0, :-1]
    value = float(np.min(points @ normal - plane[0, -1])) - radius
    size = oracle.bounding_radius(points) + radius
    return Reference(value, -value, normal if plane_is_a else -normal, True, size, a, b,
                     radius_a, radius_b, plane_is_a, not plane_is_a)


def run_batched(function, count: int, *args):
    """function(*args) over a leading axis of length `count`, in chunks of exactly BATCH
    (the last one padded by repetition), as NumPy arrays."""
    padded = np.resize(np.arange(count), -(-count // BATCH) * BATCH)
    chunks = [function(*take(args, padded[start:start + BATCH]))
              for start in range(0, len(padded), BATCH)]
    return jax.tree.map(lambda *leaves: np.concatenate(leaves)[:count], *chunks)



# --------------------------------------------------------------------------------------------
# Closest features built by hand, with analytic distances and witness points.
# --------------------------------------------------------------------------------------------


_DIAGONAL_2 = np.array([1.0, 1.0]) / np.sqrt(2)
_DIAGONAL_3 = np.array([1.0, 1.0, 1.0]) / np.sqrt(3)
XY = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)


@dataclasses.dataclass
class Case:
    """b's raw points at its pose (translation, rotation) against the square or cube
    [-1, 1]^D at the identity; value, and the witness points where they are unique."""

    points_b: np.ndarray
    translation: np.ndarray
    rotation: float | np.ndarray
    """2D: angle; 3D: quaternion."""
    value: float
    point_a: np.ndarray | None
    point_b: np.ndarray | None
    sat_is_exact: bool
    """Whether some SAT axis (face normal, edge-edge cross product) attains the value."""


def _triangle_vertex_towards(corner_direction, distance_to_vertex, radius):
    """Regular triangle of `radius` turned so that vertex 0 points along -corner_direction,
    placed with that vertex `distance_to_vertex` beyond the square's corner (1, 1)."""
    corners = radius * np.stack([np.cos(2 * np.pi * np.arange(3) / 3),
                                 np.sin(2 * np.pi * np.arange(3) / 3)], axis=1)
    angle = np.arctan2(-corner_direction[1], -corner_direction[0])
    tip = np.array([1.0, 1.0]) + distance_to_vertex * corner_direction
    return corners, tip + radius * corner_direction, angle, tip


def cases_2d(s: float) -> dict[str, Case]:
    corners, centre, angle, tip = _triangle_vertex_towards(_DIAGONAL_2, s, 0.8)
    half = 0.5 * SQUARE
    return {
        # Corner (1, 1) against corner (1 + s, 1 + s): SAT sees only s, the distance is s sqrt 2.
        "vertex-vertex squares": Case(half, np.array([1.5 + s, 1.5 + s]), 0.0, s * np.sqrt(2),
                                      np.array([1.0, 1.0]), np.array([1.0 + s, 1.0 + s]), False),
        # A triangle's tip s beyond the corner along the diagonal; its edges run at 15 and 75
        # degrees, inside the corner's normal cone, so the tip is the closest point.
        "vertex-vertex triangle": Case(corners, centre, angle, s, np.array([1.0, 1.0]), tip,
                                       False),
        # A triangle's tip s beyond the middle of the edge x = 1.
        "vertex-edge": Case(corners, np.array([1.0 + s + 0.8, 0.3]), np.pi, s,
                            np.array([1.0, 0.3]), np.array([1.0 + s, 0.3]), True),
        "edge-edge": Case(half, np.array([1.5 + s, 0.7]), 0.0, s, None, None, True),
    }


def _tetrahedron(tip, spokes):
    return np.vstack([np.zeros(3), spokes]), np.asarray(tip, float)


def cases_3d(s: float) -> dict[str, Case]:
    cases = {}
    # Corner against corner along the body diagonal.
    cases["vertex-vertex cubes"] = Case(0.5 * CUBE, (1.5 + s) * np.ones(3), IDENTITY,
                                        s * np.sqrt(3), np.ones(3), (1 + s) * np.ones(3), False)
    # A tetrahedron's tip s beyond the corner (1, 1, 1); its other vertices lie further out in
    # every coordinate, so the whole tetrahedron sits in the corner's normal cone.
    points, tip = _tetrahedron(np.ones(3) + s * _DIAGONAL_3,
                               [[1.0, 0.3, 0.2], [0.2, 1.2, 0.4], [0.5, 0.6, 1.1]])
    cases["vertex-vertex tetrahedron"] = Case(points, tip, IDENTITY, s, np.ones(3), tip, False)
    # A tip s beyond the middle of the edge {x = y = 1}; the spokes move away in x and y, and no
    # edge of the tetrahedron is perpendicular to (1, 1, 0), so no SAT axis is (1, 1, 0).
    points, tip = _tetrahedron(np.array([1.0, 1.0, 0.25]) + s * XY,
                               [[1.0, 0.3, 0.2], [0.2, 1.3, -0.4], [0.8, 0.9, 0.9]])
    cases["vertex-edge"] = Case(points, tip, IDENTITY, s, np.array([1.0, 1.0, 0.25]), tip,
                                False)
    # The same with the foot of the tip 1e-8 from the end of the edge: the vertex-vertex pair
    # to the cube's corner is then longer than the closest pair by a relative (1e-8 / s)^2 only.
    points, tip = _tetrahedron(np.array([1.0, 1.0, 1.0 - 1e-8]) + s * XY,
                               [[1.0, 0.3, -0.2], [0.2, 1.3, -0.4], [0.8, 0.9, -0.9]])
    cases["vertex-edge near the end"] = Case(points, tip, IDENTITY, s,
                                             np.array([1.0, 1.0, 1.0 - 1e-8]), tip, False)
    # A tip s beyond the face x = 1.
    points, tip = _tetrahedron(np.array([1.0 + s, 0.2, 0.3]),
                               [[1.0, 0.3, 0.2], [0.6, -0.8, 0.5], [0.7, 0.4, -0.9]])
    cases["vertex-face"] = Case(points, tip, IDENTITY, s, np.array([1.0, 0.2, 0.3]), tip, True)
    # Skew edges: b's edge along (1, -1, 0) crosses the edge {x = y = 1} at z = 0.2 in
    # projection, s away along (1, 1, 0); the rest of b lies further along (1, 1, 0).
    across = np.array([1.0, -1.0, 0.0]) / np.sqrt(2)
    middle = np.array([1.0, 1.0, 0.2]) + s * XY
    points = np.array([0.7 * across, -0.7 * across, 0.9 * XY + [0, 0, 0.6],
                       0.9 * XY - [0, 0, 0.6]])
    cases["edge-edge skew"] = Case(points, middle, IDENTITY, s, np.array([1.0, 1.0, 0.2]),
                                   middle, True)
    # Parallel edges {x = y = 1} and {x = y = 1 + s}: distance s sqrt 2, any z in the overlap.
    cases["edge-edge parallel"] = Case(0.5 * CUBE, np.array([1.5 + s, 1.5 + s, 0.2]),
                                       IDENTITY, s * np.sqrt(2), None, None, False)
    # Parallel faces x = 1 and x = 1 + s, offset sideways.
    cases["face-face offset"] = Case(0.5 * CUBE, np.array([1.5 + s, 0.4, -0.3]),
                                     quaternion([1, 0, 0], 0.3), s, None, None, True)
    return cases


def moved_params(dim: int, case: Case, motion):
    """Pose parameters of a (identity) and b after the common rigid motion (turn, shift)."""
    turn, shift = motion
    if dim == 2:
        rotation = oracle.rotation_2d(turn)
        position = rotation @ case.translation + shift
        return (shift[0], shift[1], turn), (position[0], position[1], turn + case.rotation)
    rotation = oracle.rotation_3d(turn)
    return ((shift, turn),
            (rotation @ case.translation + shift, quaternion_product(turn, case.rotation)))


def _columns(params, side: int):
    """Per-pair parameter tuples to a tuple of batched arrays."""
    return tuple(np.array([p[side][k] for p in params], np.float64)
                 for k in range(len(params[0][side])))


def hand_built_pairs(dim: int, label: str, gaps, motions: int = 3, seed: int = 36,
                     max_vertices: int = 8):
    """Every hand-built case for every gap s, each under `motions` + 1 common rigid motions
    (the identity first), against the unit square or cube. `label` picks the size classes:
    "padded" (8-gons; in 3D hulls padded to `max_vertices`) or "box" (unpadded cuboids: the
    cube cases only). Returns (pairs, entries (name, s, case, motion))."""
    rng = np.random.default_rng(seed)
    if dim == 2:
        moves = [(0.0, np.zeros(2))] + [(rng.uniform(-np.pi, np.pi), rng.normal(size=2))
                                        for _ in range(motions)]
        unit = (jaxsat.box([1.0, 1.0], max_vertices=8), SQUARE)
        make_b = lambda points: jaxsat.polygon(points, max_vertices=8)  # noqa: E731
    else:
        moves = [(IDENTITY, np.zeros(3))] + [(rng.normal(size=4), rng.normal(size=3))
                                             for _ in range(motions)]
        if label == "padded":
            unit = (jaxsat.box([1.0, 1.0, 1.0], max_vertices=max_vertices), CUBE)
            make_b = lambda points: jaxsat.polyhedron(points, max_vertices)  # noqa: E731
        else:
            unit = (jaxsat.box([1.0, 1.0, 1.0]), CUBE)
            make_b = None
    entries, shapes_b = [], []
    for s in gaps:
        for name, case in (cases_2d if dim == 2 else cases_3d)(s).items():
            is_cube = case.points_b.shape == (8, 3) and np.array_equal(case.points_b, 0.5 * CUBE)
            if make_b is None and not is_cube:
                continue  # the unpadded box class holds cuboids only
            shape_b = jaxsat.box([0.5] * 3) if make_b is None else make_b(case.points_b)
            for motion in moves:
                entries.append((name, s, case, motion))
                shapes_b.append((shape_b, case.points_b))
    params = [moved_params(dim, case, motion) for _, _, case, motion in entries]
    count = len(entries)
    pairs = Pairs(hand_pool(dim, [unit]), hand_pool(dim, shapes_b), np.zeros(count, int),
                  np.arange(count), _columns(params, 0), _columns(params, 1), np.float64)
    return pairs, entries


# --------------------------------------------------------------------------------------------
# The catalogue of degenerate configurations (contacts and coincidences by name).
# --------------------------------------------------------------------------------------------

TINY, HUGE = 2.0**-20, 2.0**20
"""~1e-6 and ~1e6; powers of two, so that scaled contacts stay exact in both dtypes."""

CLASSES = {"poly8": 2, "box": 3, "hull8": 3}
"""Size classes: 2D polygons padded to 8 vertices, 3D boxes (unpadded, the projection path of
the SAT search), 3D hulls padded to 8 vertices (the Gauss-map path)."""

PROPERTY_CLASSES = {**CLASSES, "segment": 3, "rounded": 3, "rounded2d": 2, "halfspace": 3}
"""The generic properties' size classes: also spheres and capsules stacked alone (cores of at
most 2 vertices, the closed form of `_closest.closest_pair_of_segments`), spheres, capsules,
rounded and sharp boxes stacked together (the rounded kind: every pair of those kinds), the
same in 2D with circles, capsules and polygons, and half-spaces against boxes (`pools`)."""



def _pose(values, turn=None) -> np.ndarray:
    """2D: (x, y, angle). 3D: translation, then the quaternion (w, x, y, z); `_pair` adds the
    identity quaternion to a bare 3D translation."""
    extra = [] if turn is None else list(turn)
    return np.asarray(list(values) + extra, np.float64)


@dataclasses.dataclass(frozen=True)
class Config:
    """One pair: size class, local points of a and b, pose parameters, length unit; points and
    parameters rounded to float32-representable values, so that both dtypes see them."""

    kind: str
    points_a: np.ndarray
    params_a: np.ndarray
    points_b: np.ndarray
    params_b: np.ndarray
    unit: float = 1.0
    """Length unit: tau = TAU * unit, finite-difference steps scale with it."""
    zero_quaternion: bool = False
    """The distance is discontinuous in the quaternion at 0: no finite differences there."""
    radius_a: float = 0.0
    """Radius of a rounded a (a sphere or a capsule: `points_a` is its core)."""
    radius_b: float = 0.0

    def __post_init__(self):
        for name in ("points_a", "points_b", "params_a", "params_b", "radius_a", "radius_b"):
            object.__setattr__(self, name, f32(getattr(self, name)))
        assert len(self.params_a) == len(self.params_b) == (3 if self.dim == 2 else 7)

    @property
    def dim(self) -> int:
        return PROPERTY_CLASSES[self.kind]

    def scaled(self, factor: float) -> Config:
        """Lengths (points, translations) times factor; rotations unchanged."""
        dim = self.dim
        scale = lambda p: np.concatenate([p[:dim] * factor, p[dim:]])  # noqa: E731
        return dataclasses.replace(
            self, points_a=self.points_a * factor, points_b=self.points_b * factor,
            params_a=scale(self.params_a), params_b=scale(self.params_b),
            unit=self.unit * factor, radius_a=self.radius_a * factor,
            radius_b=self.radius_b * factor)

    def moved(self, offset) -> Config:
        """Both translations plus `offset`."""
        offset = np.asarray(offset, np.float64)
        dim = self.dim
        move = lambda p: np.concatenate([p[:dim] + offset, p[dim:]])  # noqa: E731
        return dataclasses.replace(self, params_a=move(self.params_a),
                                   params_b=move(self.params_b))


def _pair(kind, points_a, pose_a, points_b, pose_b, **extra) -> Config:
    if PROPERTY_CLASSES[kind] == 3:
        identity = [1.0, 0.0, 0.0, 0.0]
        pose_a, pose_b = (p if len(p) == 7 else np.concatenate([p, identity])
                          for p in (pose_a, pose_b))
    return Config(kind, points_a, pose_a, points_b, pose_b, **extra)


def _catalogue() -> dict[str, Config]:
    c = {}
    p, b, h = "poly8", "box", "hull8"
    # Identical shapes at identical poses.
    c["identical-2d-box"] = _pair(p, RECT, _pose([0.3, -0.2, 0.4]), RECT, _pose([0.3, -0.2, 0.4]))
    c["identical-2d-hull"] = _pair(p, PENTAGON, _pose([0.3, -0.2, 0.4]), PENTAGON,
                                   _pose([0.3, -0.2, 0.4]))
    c["identical-3d-box"] = _pair(b, BRICK, _pose([0.1, 0.2, 0.3], Q_GENERIC), BRICK,
                                  _pose([0.1, 0.2, 0.3], Q_GENERIC))
    c["identical-3d-hull"] = _pair(h, HULL7, _pose([0.1, 0.2, 0.3], Q_GENERIC), HULL7,
                                   _pose([0.1, 0.2, 0.3], Q_GENERIC))
    # Exact contacts.
    c["face-face-2d"] = _pair(p, RECT, _pose([0, 0, 0]), SQUARE * 0.5, _pose([1.5, 0.25, 0]))
    c["face-face-3d"] = _pair(b, CUBE, _pose([0, 0, 0]), CUBE * 0.5, _pose([1.5, 0.25, -0.375]))
    c["edge-edge-3d"] = _pair(h, DISPHENOID, _pose([0, 0, 0]), DISPHENOID, _pose([0, 0, 1]))
    # Crossed boxes: a's top edge along y (a turned 45 degrees about y) on b's bottom edge
    # along x (b turned 45 degrees about x); touching up to the float32 rounding of sqrt(2).
    c["crossed-boxes-3d"] = _pair(b, CUBE, _pose([0, 0, 0], quaternion([0, 1, 0], np.pi / 4)),
                                  CUBE, _pose([0, 0, 2 * np.sqrt(2)],
                                              quaternion([1, 0, 0], np.pi / 4)))
    c["vertex-on-face-2d"] = _pair(p, RECT, _pose([0, 0, 0]), DIAMOND, _pose([0.25, 0.5, 0]))
    c["vertex-on-face-3d"] = _pair(h, CUBE, _pose([0, 0, 0]), SPIKE, _pose([0.25, -0.5, 1]))
    c["vertex-vertex-2d"] = _pair(p, SQUARE, _pose([0, 0, 0]), SQUARE, _pose([2, 2, 0]))
    c["vertex-vertex-2d-tips"] = _pair(p, DIAMOND, _pose([0, 0, 0]), DIAMOND, _pose([0, 2, 0]))
    c["vertex-vertex-3d"] = _pair(b, CUBE, _pose([0, 0, 0]), CUBE, _pose([2, 2, 2]))
    # b turned 45 degrees about x: its lowest edge (along x) lies on a's top face, touching up
    # to the float32 rounding of sqrt(2).
    c["edge-on-face-3d"] = _pair(b, CUBE, _pose([0, 0, 0]), CUBE,
                                 _pose([0.5, 0, 1 + np.sqrt(2)], quaternion([1, 0, 0], np.pi / 4)))
    c["vertex-vertex-3d-tips"] = _pair(h, OCTAHEDRON, _pose([0, 0, 0]), OCTAHEDRON,
                                       _pose([2, 0, 0]))
    # Parallel edges: translated copies, boxes side by side (faces offset, edges collinear,
    # edges parallel and apart).
    c["translated-copy-2d"] = _pair(p, PENTAGON, _pose([0.1, 0.2, 0.3]), PENTAGON,
                                    _pose([0.5, 0.45, 0.3]))
    c["translated-copy-apart-2d"] = _pair(p, PENTAGON, _pose([0.1, 0.2, 0.3]), PENTAGON,
                                          _pose([2.6, 1.45, 0.3]))
    c["translated-copy-3d"] = _pair(h, HULL7, _pose([0, 0, 0], Q_GENERIC), HULL7,
                                    _pose([0.3, -0.2, 0.25], Q_GENERIC))
    c["side-by-side-3d"] = _pair(b, CUBE, _pose([0, 0, 0]), CUBE, _pose([2, 0.5, 0.25]))
    c["collinear-edges-3d"] = _pair(b, CUBE, _pose([0, 0, 0]), CUBE, _pose([2, 2, 0.5]))
    c["parallel-edges-apart-3d"] = _pair(b, CUBE, _pose([0, 0, 0]), CUBE, _pose([2.5, 2.5, 0.25]))
    # Padding: shapes with fewer vertices than the class holds.
    c["padded-2d"] = _pair(p, SQUARE, _pose([0, 0, 0]), TRIANGLE, _pose([0.8, 0.1, 0.0]))
    c["padded-3d"] = _pair(h, CUBE, _pose([0, 0, 0], Q_OTHER), SPIKE,
                           _pose([0.4, 0.3, 0.5], Q_GENERIC))
    # Scales ~1e-6 and ~1e6 (exact powers of two) of contacts and generic pairs.
    c["tiny-face-face-2d"] = c["face-face-2d"].scaled(TINY)
    c["huge-vertex-vertex-2d"] = c["vertex-vertex-2d"].scaled(HUGE)
    c["tiny-edge-edge-3d"] = c["edge-edge-3d"].scaled(TINY)
    c["huge-side-by-side-3d"] = c["side-by-side-3d"].scaled(HUGE)
    c["tiny-generic-3d"] = _pair(h, HULL7, _pose([0, 0, 0], Q_GENERIC), SPIKE,
                                 _pose([1.2, 0.3, -0.4], Q_OTHER)).scaled(TINY)
    c["huge-generic-2d"] = _pair(p, PENTAGON, _pose([0, 0, 0.2]), TRIANGLE,
                                 _pose([1.1, -0.3, 2.0])).scaled(HUGE)
    # Far from the origin: both poses near (1e4, 1e4[, 1e4]).
    c["far-2d"] = _pair(p, RECT, _pose([0, 0, 0.3]), PENTAGON, _pose([1.25, 0.5, -0.2])).moved(
        [1e4, 1e4])
    c["far-touching-2d"] = c["face-face-2d"].moved([1e4, 1e4])
    c["far-3d"] = _pair(b, BRICK, _pose([0, 0, 0], Q_GENERIC), CUBE * 0.5,
                        _pose([1.25, 0.5, 0.25], Q_OTHER)).moved([1e4, 1e4, 1e4])
    c["far-hull-3d"] = c["edge-edge-3d"].moved([1e4, 1e4, 1e4])
    # Zero quaternions (pose3 then gives the identity rotation).
    zero = [0.0, 0.0, 0.0, 0.0]
    c["zero-quaternion-box"] = _pair(b, BRICK, _pose([0, 0, 0], zero), CUBE * 0.5,
                                     _pose([1.25, 0.5, 0.0], zero), zero_quaternion=True)
    c["zero-quaternion-hull"] = _pair(h, HULL7, _pose([0.1, 0, 0], zero), SPIKE,
                                      _pose([0.2, 0.1, 0.7], Q_GENERIC), zero_quaternion=True)
    # Nearly parallel edges and faces: one shape turned by 1e-8.
    tilt = 1e-8
    c["nearly-parallel-2d"] = _pair(p, RECT, _pose([0, 0, 0]), RECT, _pose([2, 0.5, tilt]))
    c["nearly-parallel-faces-3d"] = _pair(b, CUBE, _pose([0, 0, 0]), CUBE,
                                          _pose([2, 0.5, 0.25], quaternion([0, 0, 1], tilt)))
    c["nearly-parallel-edges-3d"] = _pair(b, CUBE, _pose([0, 0, 0]), CUBE,
                                          _pose([2, 2, 0.5], quaternion([1, 0, 0], tilt)))
    c["nearly-parallel-hull-3d"] = _pair(h, DISPHENOID, _pose([0, 0, 0]), DISPHENOID,
                                         _pose([0, 0, 1], quaternion([0, 0, 1], np.pi / 2
                                                                      + tilt)))
    # One shape inside the other: concentric (ties between opposite faces) and off-centre.
    c["nested-concentric-2d"] = _pair(p, SQUARE * 2, _pose([0.5, 0.5, 0]), RECT * 0.25,
                                      _pose([0.5, 0.5, 0]))
    c["nested-2d"] = _pair(p, PENTAGON * 3, _pose([0, 0, 0.1]), TRIANGLE * 0.5,
                           _pose([0.3, -0.2, 1.0]))
    c["nested-concentric-3d"] = _pair(b, CUBE * 2, _pose([0, 0, 0]), CUBE * 0.25,
                                      _pose([0, 0, 0]))
    c["nested-3d"] = _pair(h, HULL7 * 4, _pose([0, 0, 0], Q_GENERIC), SPIKE * 0.5,
                           _pose([0.2, 0.1, -0.1], Q_OTHER))
    # Large rotation angles: |angle| ~ 1e4 rad in 2D; nearly full turns and a long, negative
    # quaternion in 3D.
    c["large-angle-2d"] = _pair(p, PENTAGON, _pose([0, 0, 1e4 + 0.3]), RECT,
                                _pose([1.2, 0.4, -3e4]))
    c["large-angle-3d"] = _pair(h, HULL7, _pose([0, 0, 0], quaternion([1, 1, 0],
                                                                       2 * np.pi - 1e-3)),
                                BRICK, _pose([0.9, 0.8, 0.1], -1e3 * Q_OTHER))
    return c


CATALOGUE = _catalogue()
NAMES = list(CATALOGUE)


def _capsule_core(half: float) -> np.ndarray:
    return np.array([[0.0, 0.0, -half], [0.0, 0.0, half]])


def _rounded_catalogue() -> dict[str, Config]:
    """Spheres and capsules (kind "segment"): coincident, collinear, parallel, crossing, end to
    end, zero length, far from the origin and at tiny and huge scales. With rounded and sharp
    boxes (kind "rounded"): touching face to face, on an edge, at a corner, a capsule lying
    on a face, a sphere at a box's centre (a six-way tie), identical, nearly parallel, far,
    tiny and huge. In 2D (kind "rounded2d"): the same with circles, capsules and squares, and
    two crossing capsules."""
    c, s, point = {}, "segment", np.zeros((1, 3))
    rod = _capsule_core(1.0)
    quarter_x = quaternion([1, 0, 0], np.pi / 2)
    pair = lambda *args, radius_a=0.25, radius_b=0.25: _pair(  # noqa: E731
        s, *args, radius_a=radius_a, radius_b=radius_b)
    c["coincident-spheres"] = pair(point, _pose([0, 0, 0]), point, _pose([0, 0, 0]),
                                   radius_a=0.5)
    c["sphere-centre-on-capsule-axis"] = pair(rod, _pose([0, 0, 0]), point, _pose([0, 0, 0.5]))
    c["touching-spheres"] = pair(point, _pose([0, 0, 0]), point, _pose([0, 0.5, 0]))
    c["collinear-capsules"] = pair(rod, _pose([0, 0, 0]), rod, _pose([0, 0, 0.5]))
    c["parallel-capsules"] = pair(rod, _pose([0, 0, 0]), rod, _pose([1, 0, 0.5]))
    c["crossing-capsules"] = pair(rod, _pose([0, 0, 0]), rod, _pose([0, 0, 0], quarter_x))
    c["end-to-end-capsules"] = pair(rod, _pose([0, 0, 0]), rod, _pose([0, 0, 2.5]))
    c["zero-length-capsule"] = pair(_capsule_core(0.0), _pose([0.3, 0, 0]), rod,
                                    _pose([0, 0, 0], Q_GENERIC))
    c["nearly-parallel-capsules"] = pair(rod, _pose([0, 0, 0]), rod, _pose(
        [0.4, 0, 0.3], quaternion([0, 1, 0], 1e-8)))
    c["far-capsules"] = c["parallel-capsules"].moved([1e4, 1e4, 1e4])
    c["tiny-crossing-capsules"] = c["crossing-capsules"].scaled(TINY)
    c["huge-parallel-capsules"] = c["parallel-capsules"].scaled(HUGE)
    # The rounded kind: rounded and sharp boxes with spheres and capsules.
    r = "rounded"
    c["rounded-boxes-face-to-face"] = _pair(r, CUBE, _pose([0, 0, 0]), CUBE,
                                            _pose([2.5, 0.25, -0.5]), radius_a=0.25,
                                            radius_b=0.25)
    c["rounded-box-on-a-box-edge"] = _pair(r, CUBE, _pose([0, 0, 0]), CUBE, _pose(
        [0.3, 0, 1.25 + np.sqrt(2)], quaternion([1, 0, 0], np.pi / 4)), radius_a=0.25)
    c["sphere-at-a-rounded-box-corner"] = _pair(r, CUBE, _pose([0, 0, 0]), point, _pose(
        np.ones(3) * (1 + 0.5 / np.sqrt(3))), radius_a=0.25, radius_b=0.25)
    c["capsule-lying-on-a-rounded-box"] = _pair(r, CUBE, _pose([0, 0, 0]), rod, _pose(
        [0.2, 0.1, 1.3], quaternion([0, 1, 0], np.pi / 2)), radius_a=0.1, radius_b=0.25)
    c["sphere-at-a-rounded-box-centre"] = _pair(r, CUBE, _pose([0, 0, 0]), point,
                                                _pose([0, 0, 0]), radius_a=0.2, radius_b=0.1)
    c["identical-rounded-boxes"] = _pair(r, BRICK, _pose([0.1, 0.2, 0.3], Q_GENERIC), BRICK,
                                         _pose([0.1, 0.2, 0.3], Q_GENERIC), radius_a=0.2,
                                         radius_b=0.2)
    c["nearly-parallel-rounded-boxes"] = _pair(
        r, CUBE, _pose([0, 0, 0]), CUBE, _pose([2.5, 0.5, 0.25], quaternion([0, 0, 1], 1e-8)),
        radius_a=0.25, radius_b=0.25)
    c["far-rounded-boxes"] = c["rounded-boxes-face-to-face"].moved([1e4, 1e4, 1e4])
    c["tiny-sphere-at-a-corner"] = c["sphere-at-a-rounded-box-corner"].scaled(TINY)
    # The same in 2D: circles, capsules along x, rounded and sharp polygons.
    r2, dot, stick = "rounded2d", np.zeros((1, 2)), np.array([[-1.0, 0.0], [1.0, 0.0]])
    c["rounded-squares-side-by-side"] = _pair(r2, SQUARE, _pose([0, 0, 0]), SQUARE,
                                              _pose([2.5, 0.25, 0]), radius_a=0.25,
                                              radius_b=0.25)
    corner = 1 + 0.5 / np.sqrt(2)
    c["circle-at-a-rounded-corner"] = _pair(r2, SQUARE, _pose([0, 0, 0]), dot,
                                            _pose([corner, corner, 0]), radius_a=0.25,
                                            radius_b=0.25)
    c["capsule-on-a-rounded-square"] = _pair(r2, SQUARE, _pose([0, 0, 0]), stick,
                                             _pose([0.2, 1.3, 0]), radius_a=0.1,
                                             radius_b=0.25)
    c["crossing-2d-capsules"] = _pair(r2, stick, _pose([0, 0, 0]), stick,
                                      _pose([0.2, 0.1, np.pi / 2]), radius_a=0.1, radius_b=0.2)
    c["circle-at-a-square-centre"] = _pair(r2, SQUARE, _pose([0, 0, 0]), dot, _pose([0, 0, 0]),
                                           radius_a=0.2, radius_b=0.1)
    c["identical-rounded-pentagons"] = _pair(r2, PENTAGON, _pose([0.1, 0.2, 0.3]), PENTAGON,
                                             _pose([0.1, 0.2, 0.3]), radius_a=0.2,
                                             radius_b=0.2)
    c["far-rounded-squares"] = c["rounded-squares-side-by-side"].moved([1e4, 1e4])
    c["huge-capsule-on-a-square"] = c["capsule-on-a-rounded-square"].scaled(HUGE)
    c["huge-capsule-on-a-box"] = c["capsule-lying-on-a-rounded-box"].scaled(HUGE)
    return c


ROUNDED_CATALOGUE = _rounded_catalogue()
"""Degenerate configurations of the rounded size class (apart from `CATALOGUE`, which the
stability tests run through the polytope oracle)."""


def build(kind: str, points: np.ndarray, dtype, radius: float = 0.0) -> jaxsat.Polytope:
    """A configuration's shape from its raw points (a core's, with `radius`): in the
    "segment" and rounded kinds one point is a sphere (a circle in 2D) and two ends on local
    z (x in 2D) a capsule; centred box corners are a box, other 2D points a polygon (rounded
    where the radius is positive)."""
    if kind in ("segment", "rounded", "rounded2d") and len(points) <= 2:
        radius, dim = np.asarray(radius, dtype), len(points[0])
        if len(points) == 1:
            return jaxsat.sphere(radius) if dim == 3 else jaxsat.circle(radius)
        return jaxsat.capsule(np.asarray(points[1, dim - 1 if dim == 3 else 0], dtype), radius,
                              dim=dim)
    if kind in ("poly8", "rounded2d"):
        shape = jaxsat.polygon(points, 8, dtype=dtype)
        return jaxsat.rounded(shape, np.asarray(radius, dtype)) if radius > 0 else shape
    if kind in ("box", "rounded"):
        half = np.max(np.abs(points), axis=0)
        assert np.allclose(np.abs(points), half), "box configurations use centred box corners"
        shape = jaxsat.box(half, dtype=dtype)
        return jaxsat.rounded(shape, np.asarray(radius, dtype)) if radius > 0 else shape
    return jaxsat.polyhedron(points, 8, dtype=dtype)


def world(config: Config):
    """World points of a and b in float64, from rotations computed by SciPy (oracle.py)."""
    result = []
    for points, params in ((config.points_a, config.params_a),
                           (config.points_b, config.params_b)):
        if config.dim == 2:
            rotation, translation = oracle.rotation_2d(params[2]), params[:2]
        else:
            quaternion = params[3:]
            rotation = (np.eye(3) if not np.any(quaternion) else
                        oracle.rotation_3d(quaternion))
            translation = params[:3]
        result.append(oracle.to_world(points, rotation, translation))
    return result


def catalogue_pairs(size_class: str, dtype) -> Pairs:
    """Every catalogue configuration of a size class, as pairs over one pool (a of entry k is
    shape 2k, b is shape 2k + 1)."""
    if size_class == "halfspace":
        return _halfspace_catalogue_pairs(dtype)
    entries = [c for c in [*CATALOGUE.values(), *ROUNDED_CATALOGUE.values()]
               if c.kind == size_class]
    points = [p for c in entries for p in (c.points_a, c.points_b)]
    radii = [r for c in entries for r in (c.radius_a, c.radius_b)]
    shapes = Pool(PROPERTY_CLASSES[size_class], points, jaxsat.stack(
        [build(size_class, p, dtype, r) for p, r in zip(points, radii, strict=True)]))
    index = 2 * np.arange(len(entries))
    return Pairs(shapes, shapes, index, index + 1,
                 param_columns([c.params_a for c in entries], dtype),
                 param_columns([c.params_b for c in entries], dtype), dtype)


def _halfspace_catalogue_pairs(dtype) -> Pairs:
    """The ground z <= 0 under a unit cube resting on a face, on an edge and on a corner
    (touching exactly, up to float32's sqrt 2 and 3), sunk halfway, just apart, far from the
    origin, and at tiny and huge scales; a tilted plane through the cube's centre."""
    edge, corner = quaternion([1, 0, 0], np.pi / 4), quaternion([1, -1, 0], np.arctan(np.sqrt(
        2)))
    cases = [  # (plane normal, offset, cube centre, cube turn, length scale)
        ([0, 0, 1], 0.0, [0, 0, 1], IDENTITY, 1.0),
        ([0, 0, 1], 0.0, [0.3, 0, np.sqrt(2)], edge, 1.0),
        ([0, 0, 1], 0.0, [0, 0.2, np.sqrt(3)], corner, 1.0),
        ([0, 0, 1], 0.0, [0, 0, 0.5], IDENTITY, 1.0),
        ([0, 0, 1], 0.0, [0, 0, 1 + 1e-3], IDENTITY, 1.0),
        ([0, 0, 1], 1e4, [1e4, 1e4, 1e4 + 1], IDENTITY, 1.0),
        ([0, 0, 1], 0.0, [0, 0, 1], IDENTITY, TINY),
        ([0, 0, 1], 0.0, [0, 0, 1], IDENTITY, HUGE),
        ([1, 1, 1], 0.0, [0, 0, 0], Q_OTHER, 1.0),
    ]
    planes = plane_pool([c[0] for c in cases], [c[1] * c[4] for c in cases], dtype)
    cubes = Pool(3, [CUBE * c[4] for c in cases],
                 jaxsat.stack([build("box", CUBE * c[4], dtype) for c in cases]))
    index = np.arange(len(cases))
    identity = np.tile(np.concatenate([np.zeros(3), IDENTITY]), (len(cases), 1))
    params_b = [np.concatenate([np.asarray(c[2]) * c[4], c[3]]) for c in cases]
    return Pairs(planes, cubes, index, index, param_columns(identity, dtype),
                 param_columns(params_b, dtype), dtype)


@functools.cache
def reference(name: str):
    """(exact signed distance by the SciPy oracle, size) for a catalogue configuration."""
    return oracle_reference(CATALOGUE[name])


def oracle_reference(config: Config):
    """(exact signed distance by the SciPy oracle, size) for a configuration."""
    world_a, world_b = world(config)
    result = oracle.evaluate(world_a, world_b)
    exact = -result.depth if result.depth >= 0 else result.distance
    size = result.size + abs(exact)
    return exact, size


# --------------------------------------------------------------------------------------------
# Generic properties: every public query x size class x dtype.
# --------------------------------------------------------------------------------------------

QUERIES = {
    "intersects": jaxsat.intersects,
    "penetration": jaxsat.penetration,
    "signed_distance": functools.partial(jaxsat.signed_distance, smoothing=None),
    "smooth_signed_distance": functools.partial(jaxsat.signed_distance, smoothing=0.05),
    "closest_points": jaxsat.closest_points,
    "contacts": jaxsat.contacts,
}
"""Every public pair query, by name (the distance in both of its modes)."""

FAST_COMBINATIONS = {("box", np.float32)}
"""The (size class, dtype) combinations of the fast subset; the others are marked slow."""


def every_query_class_dtype(test):
    """Run `test(query, size_class, dtype)` for every public query, size class
    (`PROPERTY_CLASSES`) and dtype; all but `FAST_COMBINATIONS` are marked slow. The parameters
    have module scope, so pytest runs a module's tests combination by combination (every test
    of one combination, then the next), and a module can release one combination's compiled
    programs before the next combination's are built."""
    cases = [pytest.param(query, size_class, dtype, id=f"{query}-{size_class}-{dtype.__name__}",
                          marks=() if (size_class, dtype) in FAST_COMBINATIONS
                          else pytest.mark.slow)
             for query in QUERIES for size_class in PROPERTY_CLASSES for dtype in DTYPES]
    return pytest.mark.parametrize(("query", "size_class", "dtype"), cases, scope="module")(test)


# --------------------------------------------------------------------------------------------
# Shapes touching exactly, in integer coordinates: where the queries must agree.
# --------------------------------------------------------------------------------------------

_CUBE2 = np.array([[x, y, z] for x in (0, 2) for y in (0, 2) for z in (0, 2)])
_RIDGE_X = np.array([[-1, 0, 0], [1, 0, 0], [0, 1, -1], [0, -1, -1]])
"""A tetrahedron below z = 0 whose top edge runs along x through the origin."""

TOUCHING = {
    3: {
        # b is a's point reflection through a's vertex 0: they share that vertex only.
        "vertex-vertex": (np.array([[0, 0, 0], [2, 1, 0], [1, 2, 1], [0, 1, 2]]), None),
        "vertex-edge": (_RIDGE_X, np.array([[0, 0, 0], [1, 1, 1], [-1, 1, 1], [0, -1, 1]])),
        "edge-edge": (_RIDGE_X, np.array([[0, -1, 0], [0, 1, 0], [1, 0, 1], [-1, 0, 1]])),
        "vertex-face": (_CUBE2, np.array([[1, 1, 2], [0, 0, 3], [2, 0, 3], [1, 2, 3]])),
        "edge-face": (_CUBE2, np.array([[0, 1, 2], [2, 1, 2], [1, 0, 3], [1, 2, 3]])),
        "face-face": (_CUBE2, np.array([[1, 1, 2], [3, 1, 2], [1, 3, 2], [1, 1, 3]])),
    },
    2: {
        "vertex-vertex": (np.array([[0, 0], [2, 1], [1, 2]]), None),
        "vertex-edge": (np.array([[0, 0], [2, 0], [2, 2], [0, 2]]),
                        np.array([[1, 2], [2, 3], [0, 3]])),
        "edge-edge": (np.array([[0, 0], [2, 0], [2, 2], [0, 2]]),
                      np.array([[1, 2], [3, 2], [3, 4], [1, 4]])),
        "edge-edge-full": (np.array([[0, 0], [2, 0], [2, 2], [0, 2]]),
                           np.array([[2, 0], [4, 0], [4, 2], [2, 2]])),
    },
}
"""Pairs of convex shapes (vertex rows, a then b) that touch exactly in their own frame,
named by the touching features; b = None means a's point reflection through a's vertex 0."""

TOUCHING_SCALES = (1e-3, 1.0, 1e3)


def touching_pairs(dim: int, dtype, motions: int = 5, seed: int = 0):
    """Every `TOUCHING` configuration at every scale of `TOUCHING_SCALES`, as placed (both
    shapes at the identity pose) and under `motions` random common rigid motions (touching
    up to the rounding of the poses), each also with b moved by +-4 ulps of the scale along a
    random direction. Returns (names, placed, a, params_a, b, params_b): names (N,), placed
    (N,) bool (the pairs at the identity pose and not nudged, which touch exactly) and the
    batched inputs of a (Polytope stack, pose parameters) and b, in `dtype`."""
    rng = np.random.default_rng(seed)
    names, placed, shapes_a, shapes_b, params_a, params_b = [], [], [], [], [], []
    ulp = float(np.finfo(dtype).eps)
    for name, (rows_a, rows_b) in TOUCHING[dim].items():
        rows_a = np.asarray(rows_a, np.float64)
        rows_b = 2 * rows_a[0] - rows_a if rows_b is None else np.asarray(rows_b, np.float64)
        for scale in TOUCHING_SCALES:
            build = jaxsat.polygon if dim == 2 else jaxsat.polyhedron
            a, b = (build((rows * scale).astype(dtype), max_vertices=8, dtype=dtype)
                    for rows in (rows_a, rows_b))
            turns, shifts = random_motion(dim, motions, rng, scale)
            turns = np.concatenate([[0.0] if dim == 2 else [IDENTITY], turns])
            shifts = np.concatenate([np.zeros((1, dim)), shifts])
            for motion, (turn, shift) in enumerate(zip(turns, shifts, strict=True)):
                for nudge in (0.0, 4.0, -4.0):
                    direction = rng.normal(size=dim)
                    moved = shift + nudge * ulp * scale * direction / np.linalg.norm(direction)
                    names.append(name)
                    placed.append(motion == 0 and nudge == 0.0)
                    shapes_a.append(a)
                    shapes_b.append(b)
                    # 2D: (x, y, angle); 3D: translation then quaternion.
                    params_a.append(_pose(shift, np.atleast_1d(turn)))
                    params_b.append(_pose(moved, np.atleast_1d(turn)))
    params_a, params_b = np.asarray(params_a), np.asarray(params_b)
    split = (lambda p: (p[:, 0], p[:, 1], p[:, 2])) if dim == 2 else \
        (lambda p: (p[:, :3], p[:, 3:]))
    cast = lambda parts: tuple(np.asarray(part, dtype) for part in parts)  # noqa: E731
    return (np.array(names), np.array(placed), jaxsat.stack(shapes_a), cast(split(params_a)),
            jaxsat.stack(shapes_b), cast(split(params_b)))
