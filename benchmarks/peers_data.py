"""Data sets and the float64 reference for `peers.py` (NumPy/SciPy only: no jaxsat, no peer).

One fixed, seeded data set per case: a pool of random shapes, pairs of pool indices and world
poses. Every number in it is a float32 value stored as float64, so float32 methods and the
float64 oracle see exactly the same configuration. Poses are kept as rotation matrices (float64,
computed from the float32 angle or quaternion) plus translations: every method gets the same
matrices, cast to its own dtype.

The reference is `tests/oracle.py` (convex hull of the Minkowski difference, SciPy), and its
central finite differences for gradients.
"""

from __future__ import annotations

import dataclasses
import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent / "tests"))
import oracle  # noqa: E402  (tests/oracle.py: NumPy/SciPy only, shares no code with jaxsat)

CASES = {
    "2d-small": "random convex polygons, 3-4 vertices (jax2d's limit)",
    "2d-polygons": "random convex polygons, 4-8 vertices",
    "3d-boxes": "random boxes, half extents 0.15-0.6",
    "3d-hulls": "convex hulls of 20 random points on ellipsoids (semi-axes 0.3-0.8)",
}
VERTEX_RANGE = {"2d-small": (3, 4), "2d-polygons": (4, 8)}
FD_STEPS = (1e-4, 1e-5)
"""Central-difference steps in b's translation; the smaller one is the reference."""
FD_AGREEMENT = 1e-6
"""Pairs whose two finite-difference gradients differ by more (norm) are kinks: skipped."""
OVERLAP_TOLERANCE = 1e-6
"""Pairs with |oracle depth| below this are touching: left out of overlap/depth statistics."""


@dataclasses.dataclass
class CaseData:
    """One case: pool shapes and N pairs with their world poses (all float64)."""

    case: str
    dim: int
    points: list[np.ndarray]
    """Local vertices of every pool shape, (V_i, D); 2D polygons counter-clockwise."""
    half_extents: np.ndarray | None
    """(P, 3) half extents of the pool boxes (3d-boxes only)."""
    pick_a: np.ndarray
    """(N,) pool index of shape a of every pair."""
    pick_b: np.ndarray
    rotation_a: np.ndarray
    """(N, D, D) world rotation of a."""
    rotation_b: np.ndarray
    translation_a: np.ndarray
    """(N, D) world translation of a."""
    translation_b: np.ndarray
    angle_a: np.ndarray | None
    """(N,) rotation angle of a (2D only), the angle the rotation matrix was built from."""
    angle_b: np.ndarray | None

    @property
    def pairs(self) -> int:
        return len(self.pick_a)

    @property
    def max_vertices(self) -> int:
        return max(len(p) for p in self.points)

    def world(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """World vertices of pair `index`, float64."""
        a = oracle.to_world(self.points[self.pick_a[index]], self.rotation_a[index],
                            self.translation_a[index])
        b = oracle.to_world(self.points[self.pick_b[index]], self.rotation_b[index],
                            self.translation_b[index])
        return a, b


def f32(values) -> np.ndarray:
    """Round to float32, keep as float64."""
    return np.asarray(values, np.float64).astype(np.float32).astype(np.float64)


def random_polygon(rng: np.random.Generator, low: int, high: int) -> np.ndarray:
    """low..high vertices on a random ellipse, counter-clockwise: always strictly convex."""
    count = int(rng.integers(low, high + 1))
    gaps = rng.uniform(0.5, 1.5, count)
    angles = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.cumsum(gaps) / gaps.sum()
    axes = rng.uniform(0.3, 0.8, 2)
    return f32(np.stack([axes[0] * np.cos(angles), axes[1] * np.sin(angles)], axis=1))


def random_hull_points(rng: np.random.Generator, count: int = 20) -> np.ndarray:
    """`count` random points on a random ellipsoid, so every point is a hull vertex."""
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return f32(directions * rng.uniform(0.3, 0.8, 3))


def box_corners(half: np.ndarray) -> np.ndarray:
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    return signs * half


def rotations_2d(angles: np.ndarray) -> np.ndarray:
    cos, sin = np.cos(angles), np.sin(angles)
    return np.stack([np.stack([cos, -sin], -1), np.stack([sin, cos], -1)], -2)


def rotations_3d(quaternions: np.ndarray) -> np.ndarray:
    """(N, 3, 3) from (N, 4) (w, x, y, z) quaternions, normalised here, in float64."""
    w, x, y, z = (quaternions / np.linalg.norm(quaternions, axis=1, keepdims=True)).T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def make_case(case: str, pairs: int, pool_size: int, seed: int) -> CaseData:
    """The fixed data set of `case`: same seed and sizes give the same pairs."""
    rng = np.random.default_rng([seed, list(CASES).index(case)])
    dim = 2 if case.startswith("2d") else 3
    half_extents = None
    if dim == 2:
        points = [random_polygon(rng, *VERTEX_RANGE[case]) for _ in range(pool_size)]
    elif case == "3d-boxes":
        half_extents = f32(rng.uniform(0.15, 0.6, (pool_size, 3)))
        points = [box_corners(half) for half in half_extents]
    else:
        points = [random_hull_points(rng) for _ in range(pool_size)]
    pick_a, pick_b = (rng.integers(0, pool_size, pairs) for _ in range(2))
    centres = f32(rng.uniform(-1.0, 1.0, (pairs, dim)))
    directions = rng.normal(size=(pairs, dim))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    ends = f32(centres + directions * rng.uniform(0.0, 1.8, (pairs, 1)))
    angle_a = angle_b = None
    if dim == 2:
        angle_a, angle_b = f32(rng.uniform(-np.pi, np.pi, (2, pairs)))
        rotation_a, rotation_b = rotations_2d(angle_a), rotations_2d(angle_b)
    else:
        quaternions = f32(rng.normal(size=(2, pairs, 4)))
        rotation_a, rotation_b = rotations_3d(quaternions[0]), rotations_3d(quaternions[1])
    return CaseData(case, dim, points, half_extents, pick_a, pick_b, rotation_a, rotation_b,
                    centres, ends, angle_a, angle_b)


# ----------------------------------------------------------------------------- reference


@dataclasses.dataclass
class Reference:
    """Oracle values on the first `count` pairs of a case."""

    depth: np.ndarray
    """(n,) exact penetration depth when > 0; minus the largest Minkowski facet gap otherwise."""
    normal: np.ndarray
    """(n, D) unit normal from a towards b of the facet attaining `depth`."""
    normal_is_unique: np.ndarray
    """(n,) bool: no other facet within 1e-9 of the depth has a different normal."""
    distance: np.ndarray
    """(n,) Euclidean distance (0 when overlapping)."""

    @property
    def overlapping(self) -> np.ndarray:
        return self.depth > OVERLAP_TOLERANCE

    @property
    def separated(self) -> np.ndarray:
        return self.depth < -OVERLAP_TOLERANCE


def reference(data: CaseData, count: int) -> Reference:
    results = [oracle.evaluate(*data.world(i), tie_tolerance=1e-9) for i in range(count)]
    return Reference(depth=np.array([r.depth for r in results]),
                     normal=np.array([r.normal for r in results]),
                     normal_is_unique=np.array([r.normal_is_unique for r in results]),
                     distance=np.array([r.distance for r in results]))


def depth_gradient(data: CaseData, index: int) -> tuple[np.ndarray, bool]:
    """Central differences of the oracle depth w.r.t. b's translation: (gradient at the
    smaller step, whether the two steps agree within FD_AGREEMENT)."""
    world_a, world_b = data.world(index)
    estimates = []
    for step in FD_STEPS:
        gradient = np.zeros(data.dim)
        for axis in range(data.dim):
            shift = np.zeros(data.dim)
            shift[axis] = step
            plus = oracle.evaluate(world_a, world_b + shift).depth
            minus = oracle.evaluate(world_a, world_b - shift).depth
            gradient[axis] = (plus - minus) / (2 * step)
        estimates.append(gradient)
    return estimates[-1], bool(np.linalg.norm(estimates[0] - estimates[-1]) <= FD_AGREEMENT)


def gradient_pairs(data: CaseData, ref: Reference, count: int) -> tuple[np.ndarray, np.ndarray]:
    """(indices, reference gradients (k, D)) of the first `count` overlapping pairs with a
    unique normal whose finite differences agree (no kink within the steps)."""
    indices, gradients = [], []
    for index in np.flatnonzero(ref.overlapping & ref.normal_is_unique):
        gradient, smooth = depth_gradient(data, int(index))
        if smooth:
            indices.append(int(index))
            gradients.append(gradient)
        if len(indices) == count:
            break
    return np.array(indices, dtype=int), np.array(gradients).reshape(-1, data.dim)


# ----------------------------------------------------------------------------- NumPy SAT


def padded_polygons(data: CaseData, pick: np.ndarray, dtype) -> np.ndarray:
    """(n, V, 2) counter-clockwise vertices, padded by repeating vertex 0."""
    size = data.max_vertices
    out = np.empty((len(pick), size, 2), dtype)
    table = np.stack([np.concatenate([p, np.repeat(p[:1], size - len(p), 0)])
                      for p in data.points]).astype(dtype)
    out[:] = table[pick]
    return out


def numpy_sat_2d(local_a, rotation_a, translation_a, local_b, rotation_b, translation_b):
    """Vectorised exact SAT for batches of 2D convex polygons (any float dtype).

    local_*: (n, V, 2) counter-clockwise, padded by repeating vertex 0 (a zero-length padding
    edge gives a zero axis, which is masked). Returns (depth (n,), normal (n, 2)), normal from a
    towards b. The edge normals of both polygons are the facet normals of the Minkowski
    difference, so the smallest support gap over them is the exact depth.
    """
    world_a = np.einsum("nij,nvj->nvi", rotation_a, local_a) + translation_a[:, None]
    world_b = np.einsum("nij,nvj->nvi", rotation_b, local_b) + translation_b[:, None]
    axes = np.concatenate([_edge_normals(world_a), -_edge_normals(world_b)], axis=1)
    length = np.linalg.norm(axes, axis=-1)
    valid = length > 0
    axes = axes / np.where(valid, length, 1)[..., None]
    high_a = np.einsum("nkd,nvd->nkv", axes, world_a).max(-1)
    low_b = np.einsum("nkd,nvd->nkv", axes, world_b).min(-1)
    gaps = np.where(valid, high_a - low_b, np.inf)
    best = np.argmin(gaps, axis=1)
    rows = np.arange(len(best))
    return gaps[rows, best], axes[rows, best]


def _edge_normals(world: np.ndarray) -> np.ndarray:
    """Outward (unnormalised) normals of counter-clockwise edges, (n, V, 2)."""
    edges = np.roll(world, -1, axis=1) - world
    return np.stack([edges[..., 1], -edges[..., 0]], axis=-1)
