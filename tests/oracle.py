"""Independent NumPy/SciPy oracle for the penetration depth of two convex shapes.

Nothing here imports jaxsat: the oracle works on plain point clouds (the raw points the shapes
were built from, mapped to the world frame with rotations computed by SciPy), so that it shares
no code with the library under test.

Definitions. For world point sets A and B, let D = {a - b} be their Minkowski difference. For a
unit direction u, the support gap s(u) = max_a u.a - min_b u.b is the support function of D;
moving B by s(u) u makes the projections of A and B on u just touch. With the convex hull of D
written as facets {x : n.x + c <= 0}:

* if the origin is inside D (the shapes overlap), the exact penetration depth (minimum
  translation distance) is min over facets of -c, attained at the facet normal n, which points
  from A towards B;
* if the origin is outside D (the shapes are separated), the same min(-c) is negative and is
  minus the largest facet gap, and the Euclidean distance between A and B is the distance from
  the origin to the hull of D.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation


def rotation_2d(angle: float) -> np.ndarray:
    """Counter-clockwise 2D rotation matrix (float64)."""
    cos, sin = np.cos(angle), np.sin(angle)
    return np.array([[cos, -sin], [sin, cos]])


def rotation_3d(quaternion_wxyz) -> np.ndarray:
    """3D rotation matrix of a (not necessarily unit) quaternion in (w, x, y, z) order, by SciPy.

    SciPy expects (x, y, z, w) order and normalises the quaternion itself.
    """
    w, x, y, z = np.asarray(quaternion_wxyz, dtype=np.float64)
    return Rotation.from_quat([x, y, z, w]).as_matrix()


def to_world(points, rotation, translation) -> np.ndarray:
    """World coordinates R p + t of local (N, D) points, in float64."""
    points = np.asarray(points, dtype=np.float64)
    return points @ np.asarray(rotation, np.float64).T + np.asarray(translation, np.float64)


def minkowski_difference(world_a: np.ndarray, world_b: np.ndarray) -> np.ndarray:
    """All pairwise differences a - b, (N_a N_b, D)."""
    return (world_a[:, None, :] - world_b[None, :, :]).reshape(-1, world_a.shape[1])


def support_gap(normal, world_a, world_b) -> float:
    """max(A . n) - min(B . n): the depth that the axis `normal` certifies."""
    normal = np.asarray(normal, np.float64)
    return float(np.max(world_a @ normal) - np.min(world_b @ normal))


def _segment_distances(p, start, end):
    """Distances from point p to segments [start, end] (arrays (K, D))."""
    direction = end - start
    length_squared = np.sum(direction**2, axis=1)
    safe = np.where(length_squared > 0, length_squared, 1.0)
    t = np.clip(np.sum((p - start) * direction, axis=1) / safe, 0.0, 1.0)
    closest = start + t[:, None] * direction
    return np.linalg.norm(p - closest, axis=1)


def _triangle_distances(p, a, b, c):
    """Distances from point p to solid triangles (a, b, c) (arrays (T, 3))."""
    normal = np.cross(b - a, c - a)
    normal_squared = np.sum(normal**2, axis=1)
    ok = normal_squared > 0
    safe = np.where(ok, normal_squared, 1.0)
    height = np.sum((p - a) * normal, axis=1) / safe
    projected = p - height[:, None] * normal
    inside = ok.copy()
    for start, end in ((a, b), (b, c), (c, a)):
        inside &= np.sum(np.cross(end - start, projected - start) * normal, axis=1) >= 0
    plane = np.where(inside, np.abs(height) * np.sqrt(normal_squared), np.inf)
    edges = np.minimum.reduce([_segment_distances(p, a, b), _segment_distances(p, b, c),
                               _segment_distances(p, c, a)])
    return np.minimum(plane, edges)


def distance_to_hull(hull: ConvexHull, point=None) -> float:
    """Euclidean distance from `point` (default: origin) to a 2D or 3D hull, 0 if inside."""
    dim = hull.points.shape[1]
    point = np.zeros(dim) if point is None else np.asarray(point, np.float64)
    if np.all(hull.equations[:, :dim] @ point + hull.equations[:, dim] <= 0):
        return 0.0
    corners = hull.points[hull.simplices]
    if dim == 2:
        return float(np.min(_segment_distances(point, corners[:, 0], corners[:, 1])))
    return float(np.min(_triangle_distances(point, corners[:, 0], corners[:, 1], corners[:, 2])))


@dataclasses.dataclass(frozen=True)
class Oracle:
    """Exact reference values for one pair of world point clouds."""

    depth: float
    """min over facets of D of -c: the exact depth if >= 0; minus the largest facet gap if < 0."""
    normal: np.ndarray
    """Unit outward normal of a facet of D attaining `depth` (from A towards B)."""
    normal_is_unique: bool
    """True when every facet within `tie_tolerance` of the minimum has (almost) this normal."""
    distance: float
    """Euclidean distance between the shapes (0 when they overlap or touch)."""
    size: float
    """Larger bounding radius of the two shapes about their own centroids."""


def bounding_radius(world: np.ndarray) -> float:
    return float(np.max(np.linalg.norm(world - world.mean(axis=0), axis=1)))


def evaluate(world_a, world_b, tie_tolerance: float = 0.0) -> Oracle:
    """Oracle values for world point clouds A and B (any points; interior ones are harmless)."""
    world_a = np.asarray(world_a, np.float64)
    world_b = np.asarray(world_b, np.float64)
    dim = world_a.shape[1]
    hull = ConvexHull(minkowski_difference(world_a, world_b))
    normals, offsets = hull.equations[:, :dim], hull.equations[:, dim]
    depths = -offsets
    best = int(np.argmin(depths))
    near = depths <= depths[best] + tie_tolerance
    unique = bool(np.all(normals[near] @ normals[best] > 1.0 - 1e-9))
    distance = distance_to_hull(hull) if depths[best] < 0 else 0.0
    return Oracle(depth=float(depths[best]), normal=normals[best].copy(), normal_is_unique=unique,
                  distance=distance, size=max(bounding_radius(world_a), bounding_radius(world_b)))


def inside_polygon(points: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """Even-odd rule by horizontal ray casting, for any simple polygon."""
    x, y = points[:, 0:1], points[:, 1:2]
    x0, y0 = ring[None, :, 0], ring[None, :, 1]
    x1, y1 = np.roll(ring, -1, axis=0)[None, :, 0], np.roll(ring, -1, axis=0)[None, :, 1]
    straddles = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        crossing_x = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return np.sum(straddles & (x < crossing_x), axis=1) % 2 == 1


def segment_closest_points(p0, p1, q0, q1) -> tuple[np.ndarray, np.ndarray]:
    """A closest pair of points (x on [p0, p1], y on [q0, q1]) of two segments (2D or 3D; a
    segment may be a point): the minimum of |p0 + s u - q0 - t v|^2 over the unit square, a
    convex quadratic, taken over its stationary point inside the square (if any) and each
    side's clamped minimum, which together contain the minimiser."""
    p0, p1, q0, q1 = (np.asarray(x, np.float64) for x in (p0, p1, q0, q1))
    u, v, w = p1 - p0, q1 - q0, p0 - q0
    a, b, c, d, e = u @ u, u @ v, v @ v, u @ w, v @ w

    def squared(s, t):
        gap = w + s * u - t * v
        return float(gap @ gap)

    def clamped(numerator, denominator):
        return float(np.clip(numerator / denominator, 0.0, 1.0)) if denominator > 0 else 0.0

    candidates = []
    for s in (0.0, 1.0):  # t minimising |w + s u - t v|^2
        candidates.append((s, clamped(e + s * b, c)))
    for t in (0.0, 1.0):  # s minimising |w - t v + s u|^2
        candidates.append((clamped(t * b - d, a), t))
    # The stationary point by Cramer's rule with the determinant a c - b^2 written as |u x v|^2
    # (Lagrange's identity), and both numerators as cross-product dot products: a c - b^2
    # itself cancels to rounding for nearly parallel segments.
    if len(u) == 3:
        normal = np.cross(u, v)
        determinant = float(normal @ normal)
        numerators = (float(normal @ np.cross(v, w)), float(normal @ np.cross(u, w)))
    else:
        normal = float(u[0] * v[1] - u[1] * v[0])
        determinant = normal * normal
        numerators = (normal * float(v[0] * w[1] - v[1] * w[0]),
                      normal * float(u[0] * w[1] - u[1] * w[0]))
    if determinant > 1e-28 * max(a * c, 1e-300):
        s, t = numerators[0] / determinant, numerators[1] / determinant
        if 0.0 <= s <= 1.0 and 0.0 <= t <= 1.0:
            candidates.append((s, t))
    s, t = min(candidates, key=lambda st: squared(*st))
    return p0 + s * u, q0 + t * v


def segment_distance(p0, p1, q0, q1) -> float:
    """Euclidean distance between segments [p0, p1] and [q0, q1] (see segment_closest_points)."""
    x, y = segment_closest_points(p0, p1, q0, q1)
    return float(np.linalg.norm(x - y))
