"""Eager NumPy geometry used by the shape constructors (never traced by JAX).

Everything here runs in float64 on concrete arrays: it validates user input, orders polygon
vertices, builds 3D convex hulls and extracts the unique axes the SAT kernels need.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

# Relative tolerance (times the point cloud's size) below which geometry is treated as flat.
RELATIVE_TOLERANCE = 1e-9


def as_point_array(points, dim: int | None, name: str) -> np.ndarray:
    """Validate a (N, D) array of finite coordinates and return it as float64.

    Raises:
      TypeError: non-numeric input.
      ValueError: wrong shape, NaN or inf entries.
    """
    try:
        array = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise TypeError(f"{name} must be a numeric array, got {type(points).__name__}") from error
    expected = "(N, 2) or (N, 3)" if dim is None else f"(N, {dim})"
    wrong_dim = dim is not None and array.ndim == 2 and array.shape[1] != dim
    if array.ndim != 2 or wrong_dim or array.shape[1] not in (2, 3):
        raise ValueError(f"{name} must have shape {expected}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        bad = np.argwhere(~np.isfinite(array))[0]
        index = tuple(int(i) for i in bad)
        raise ValueError(f"{name} contains NaN or inf (first at index {index})")
    return array


def tolerance_for(points: np.ndarray) -> float:
    """Absolute length tolerance for a point cloud: relative tolerance times its extent."""
    extent = float(np.max(np.ptp(points, axis=0))) if len(points) else 0.0
    return RELATIVE_TOLERANCE * max(extent, np.finfo(np.float64).tiny)


def distinct_points(points: np.ndarray) -> np.ndarray:
    """Drop exact duplicates, keeping first occurrences in their original order."""
    _, first = np.unique(points, axis=0, return_index=True)
    return points[np.sort(first)]


def _parallel(u: np.ndarray, v: np.ndarray, angle_tolerance: float) -> bool:
    """Whether unit vectors u and v are parallel or anti-parallel within `angle_tolerance`.

    The sine (norm of the cross product, or 2D determinant) resolves tiny angles, unlike
    1 - |cos|, which float64 rounds to zero below about 1e-8 radians."""
    if len(u) == 2:
        return abs(u[0] * v[1] - u[1] * v[0]) <= angle_tolerance
    # Plain float arithmetic: np.cross on 3-vectors costs more than the whole test.
    x, y, z = u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]
    return x * x + y * y + z * z <= angle_tolerance * angle_tolerance


def unique_directions(directions: np.ndarray, angle_tolerance: float = 1e-12) -> np.ndarray:
    """Unit directions with parallel and anti-parallel duplicates removed.

    Only directions equal up to rounding are merged (the default tolerance is 1e-12 radians),
    so a merged axis stays exact to well below the float64 test tolerance.

    Args:
      directions: (K, D) unit vectors.
    Returns:
      (U, D) unit vectors, U <= K, each canonicalised so its first non-zero component is positive.
    """
    kept: list[np.ndarray] = []
    for direction in directions:
        if any(_parallel(direction, other, angle_tolerance) for other in kept):
            continue
        kept.append(direction)
    result = np.array(kept).reshape(-1, directions.shape[1])
    leading = np.argmax(np.abs(result) > 1e-12, axis=1)
    signs = np.sign(result[np.arange(len(result)), leading])
    return result * signs[:, None]


def convex_polygon(vertices: np.ndarray) -> np.ndarray:
    """Counter-clockwise vertices of a convex polygon given in either winding order.

    Consecutive duplicates (including a repeated closing vertex) and vertices lying on the
    straight line between their neighbours are dropped; they do not change the shape.

    Raises:
      ValueError: fewer than 3 distinct points, all points collinear, non-convex or
        self-intersecting polygon.
    """
    ring = vertices[np.any(vertices != np.roll(vertices, 1, axis=0), axis=1)]
    distinct = len(distinct_points(ring))
    if distinct < 3:
        raise ValueError(f"a polygon needs at least 3 distinct vertices, got {distinct}")
    tolerance = tolerance_for(ring)
    following = np.roll(ring, -1, axis=0)
    signed_area = 0.5 * np.sum(ring[:, 0] * following[:, 1] - following[:, 0] * ring[:, 1])
    if abs(signed_area) <= tolerance * max(float(np.max(np.ptp(ring, axis=0))), tolerance):
        centred = ring - ring.mean(axis=0)
        if np.linalg.svd(centred, compute_uv=False)[1] <= tolerance * np.sqrt(len(ring)):
            raise ValueError("polygon vertices are collinear: the polygon has zero area")
        raise ValueError("polygon is self-intersecting (its signed area is zero)")
    if signed_area < 0:
        ring = ring[::-1]
    ring = _drop_straight_vertices(ring, tolerance)
    incoming = ring - np.roll(ring, 1, axis=0)
    outgoing = np.roll(ring, -1, axis=0) - ring
    turns = incoming[:, 0] * outgoing[:, 1] - incoming[:, 1] * outgoing[:, 0]
    lengths = np.linalg.norm(incoming, axis=1) * np.linalg.norm(outgoing, axis=1)
    if np.any(turns < -tolerance * lengths / max(float(np.max(np.ptp(ring, axis=0))), 1e-300)):
        raise ValueError("polygon is not convex (a vertex turns the wrong way); split concave "
                         "shapes into convex pieces first")
    winding = np.sum(np.arctan2(turns, np.sum(incoming * outgoing, axis=1))) / (2 * np.pi)
    if abs(winding - 1.0) > 1e-6:
        raise ValueError(f"polygon is self-intersecting (its boundary winds {winding:.0f} times)")
    return ring


def _drop_straight_vertices(ring: np.ndarray, tolerance: float) -> np.ndarray:
    """Remove vertices that lie on the segment between their neighbours (180-degree turns)."""
    changed = True
    while changed and len(ring) > 3:
        previous, following = np.roll(ring, 1, axis=0), np.roll(ring, -1, axis=0)
        incoming, outgoing = ring - previous, following - ring
        cross = incoming[:, 0] * outgoing[:, 1] - incoming[:, 1] * outgoing[:, 0]
        chord = np.linalg.norm(following - previous, axis=1)
        straight = (np.abs(cross) <= tolerance * chord) & (np.sum(incoming * outgoing, axis=1) > 0)
        changed = bool(np.any(straight))
        if changed:
            ring = np.delete(ring, int(np.argmax(straight)), axis=0)
    return ring


def polygon_edge_normals(ring: np.ndarray) -> np.ndarray:
    """Outward unit normals of the edges of a counter-clockwise polygon, (N, 2)."""
    edges = np.roll(ring, -1, axis=0) - ring
    normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1)
    return normals / np.linalg.norm(normals, axis=1, keepdims=True)


@dataclass(frozen=True)
class Hull3D:
    """A 3D convex hull with coplanar triangles merged into faces.

    Attributes:
      vertices: (V, 3) hull vertices.
      face_normals: (F, 3) outward unit normals, one per merged face.
      edges: (E, 2) vertex indices of each hull edge between two different faces.
      edge_faces: (E, 2) indices into face_normals of the faces left and right of each edge.
    """

    vertices: np.ndarray
    face_normals: np.ndarray
    edges: np.ndarray
    edge_faces: np.ndarray


def convex_hull_3d(points: np.ndarray) -> Hull3D:
    """Convex hull of a 3D point cloud by incremental construction.

    Raises:
      ValueError: fewer than 4 distinct points, or all points collinear or coplanar.
    """
    points = distinct_points(points)
    if len(points) < 4:
        raise ValueError(f"a polyhedron needs at least 4 distinct points, got {len(points)}")
    tolerance = tolerance_for(points)
    simplex = _initial_simplex(points, tolerance)
    hull = _merge_coplanar(points, _incremental_hull(points, simplex, tolerance))
    # A point taken in early can end up inside a face or an edge once later points arrive.
    # True corners touch at least 3 faces; rebuilding from those alone drops the others.
    faces_at = [set() for _ in range(len(hull.vertices))]
    for (start, end), faces in zip(hull.edges, hull.edge_faces, strict=True):
        faces_at[start].update(faces.tolist())
        faces_at[end].update(faces.tolist())
    corners = np.array([len(faces) >= 3 for faces in faces_at])
    if np.all(corners):
        return hull
    return convex_hull_3d(hull.vertices[corners])


def _initial_simplex(points: np.ndarray, tolerance: float) -> list[int]:
    """Four affinely independent point indices, chosen to be far apart for stability."""
    first = int(np.argmin(points[:, 0]))
    second = int(np.argmax(np.linalg.norm(points - points[first], axis=1)))
    line = points[second] - points[first]
    offsets = points - points[first]
    line_distance = np.linalg.norm(np.cross(offsets, line), axis=1) / np.linalg.norm(line)
    third = int(np.argmax(line_distance))
    if line_distance[third] <= tolerance:
        raise ValueError("polyhedron points are collinear: they span no volume")
    normal = np.cross(line, points[third] - points[first])
    plane_distance = np.abs(offsets @ normal) / np.linalg.norm(normal)
    fourth = int(np.argmax(plane_distance))
    if plane_distance[fourth] <= tolerance:
        raise ValueError("polyhedron points are coplanar: they span no volume")
    return [first, second, third, fourth]


def _incremental_hull(points: np.ndarray, simplex: list[int], tolerance: float) -> np.ndarray:
    """Outward-oriented hull triangles (T, 3) as point indices."""
    centre = points[simplex].mean(axis=0)
    triangles = []
    for skip in range(4):
        triangle = [index for position, index in enumerate(simplex) if position != skip]
        triangles.append(_orient_outward(points, triangle, centre))
    for index in range(len(points)):
        if index in simplex:
            continue
        normals, offsets = _triangle_planes(points, triangles)
        visible = normals @ points[index] - offsets > tolerance
        if not np.any(visible):
            continue
        horizon = _horizon_edges([t for t, v in zip(triangles, visible, strict=True) if v])
        triangles = [t for t, v in zip(triangles, visible, strict=True) if not v]
        triangles += [[a, b, index] for a, b in horizon]
    return np.array(triangles)


def _orient_outward(points: np.ndarray, triangle: list[int], centre: np.ndarray) -> list[int]:
    a, b, c = points[triangle]
    return triangle if np.cross(b - a, c - a) @ (a - centre) > 0 else triangle[::-1]


def _triangle_planes(points: np.ndarray, triangles) -> tuple[np.ndarray, np.ndarray]:
    corners = points[np.asarray(triangles)]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return normals, np.einsum("td,td->t", normals, corners[:, 0])


def _horizon_edges(visible_triangles) -> list[tuple[int, int]]:
    """Directed edges of the visible region's boundary, in the visible triangles' winding."""
    directed = {(t[k], t[(k + 1) % 3]) for t in visible_triangles for k in range(3)}
    return [edge for edge in directed if (edge[1], edge[0]) not in directed]


def _merge_coplanar(points: np.ndarray, triangles: np.ndarray) -> Hull3D:
    """Group triangles by outward normal into faces; keep edges between different faces."""
    used = np.unique(triangles)
    remap = -np.ones(len(points), dtype=np.int64)
    remap[used] = np.arange(len(used))
    vertices, triangles = points[used], remap[triangles]
    normals, _ = _triangle_planes(vertices, triangles)
    face_of_triangle, face_normals = _cluster_normals(vertices, triangles, normals)
    edge_faces: dict[tuple[int, int], list[int]] = {}
    for triangle, face in zip(triangles, face_of_triangle, strict=True):
        for k in range(3):
            a, b = int(triangle[k]), int(triangle[(k + 1) % 3])
            edge_faces.setdefault((min(a, b), max(a, b)), []).append(int(face))
    edges = [(e, f) for e, f in edge_faces.items() if f[0] != f[1]]
    return Hull3D(
        vertices=vertices,
        face_normals=face_normals,
        edges=np.array([e for e, _ in edges], dtype=np.int64).reshape(-1, 2),
        edge_faces=np.array([f for _, f in edges], dtype=np.int64).reshape(-1, 2),
    )


def _cluster_normals(vertices, triangles, normals, angle_tolerance: float = 1e-10):
    """Face index of each triangle, and each face's normal refitted from all its vertices.

    Triangles whose outward normals agree within `angle_tolerance` radians lie in one plane of
    the hull (a convex hull has one supporting plane per outward normal) and form one face."""
    face_of_triangle = -np.ones(len(triangles), dtype=np.int64)
    representatives: list[np.ndarray] = []
    for t, normal in enumerate(normals):
        for f, other in enumerate(representatives):
            if normal @ other > 0 and _parallel(normal, other, angle_tolerance):
                face_of_triangle[t] = f
                break
        else:
            face_of_triangle[t] = len(representatives)
            representatives.append(normal)
    face_normals = np.array(
        [_fit_normal(vertices[np.unique(triangles[face_of_triangle == f])], representative)
         for f, representative in enumerate(representatives)]
    )
    return face_of_triangle, face_normals


def _fit_normal(face_points: np.ndarray, guess: np.ndarray) -> np.ndarray:
    """Least-squares plane normal through a face's points (exact for exactly planar faces)."""
    if len(face_points) == 3:
        a, b, c = face_points
        normal = np.cross(b - a, c - a)
    else:
        centred = face_points - face_points.mean(axis=0)
        normal = np.linalg.svd(centred)[2][-1]
    normal = normal / np.linalg.norm(normal)
    return normal if normal @ guess > 0 else -normal


# --------------------------------------------------------------------------------------------
# Capping a hull's vertex count by dropping face planes (the result contains the hull).
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Faces:
    normals: np.ndarray
    """(F, 3) outward unit normals."""
    offsets: np.ndarray
    """(F,) max of normal . vertex: the face planes are normal . x = offset."""
    areas: np.ndarray
    """(F,) face areas."""
    corners: list
    """F sets of vertex indices, the corners of each face."""


def _faces(hull: Hull3D) -> _Faces:
    vertices = hull.vertices
    tolerance = 1e3 * tolerance_for(vertices)
    heights = vertices @ hull.face_normals.T  # (V, F)
    offsets = heights.max(axis=0)
    areas, corners = [], []
    for face, normal in enumerate(hull.face_normals):
        on_face = np.nonzero(heights[:, face] >= offsets[face] - tolerance)[0]
        points = vertices[on_face]
        centre = points.mean(axis=0)
        first = points[0] - centre
        first /= np.linalg.norm(first)
        angles = np.arctan2((points - centre) @ np.cross(normal, first), (points - centre) @ first)
        ring = points[np.argsort(angles)] - centre
        areas.append(0.5 * float(np.sum(np.cross(ring, np.roll(ring, -1, axis=0)) @ normal)))
        corners.append(set(on_face.tolist()))
    return _Faces(hull.face_normals, offsets, np.array(areas), corners)


def hull_volume(hull: Hull3D) -> float:
    """Volume of a convex hull: faces times their heights above an interior point, over 3."""
    faces = _faces(hull)
    centre = hull.vertices.mean(axis=0)
    return float(np.sum(faces.areas * (faces.offsets - faces.normals @ centre)) / 3.0)


def _intersect_halfspaces(normals, offsets, centre) -> Hull3D | None:
    """The polytope {x : normals . x <= offsets}, around an interior `centre`, or None when
    it is unbounded. By polarity about the centre, each plane n . x = d is the point
    n / (d - n . c), and each face of those points' hull (m . y = h) the vertex c + m / h;
    the polytope is bounded exactly when the centre is inside that hull (every h > 0)."""
    dual = normals / (offsets - normals @ centre)[:, None]
    try:
        dual_hull = convex_hull_3d(dual)
    except ValueError:  # fewer than 4 planes, or all through one direction: unbounded
        return None
    heights = np.max(dual_hull.vertices @ dual_hull.face_normals.T, axis=0)
    if np.min(heights) <= 1e3 * tolerance_for(dual_hull.vertices):
        return None
    corners = centre + dual_hull.face_normals / heights[:, None]
    # Four or more planes through one corner can give dual faces a rounding apart, hence
    # corners a rounding apart: keep one of each such cluster (the hull needs distinct points).
    merge = 1e3 * tolerance_for(corners)
    kept: list[np.ndarray] = []
    for corner in corners:
        if not kept or np.min(np.linalg.norm(np.array(kept) - corner, axis=1)) > merge:
            kept.append(corner)
    return convex_hull_3d(np.array(kept))


def cap_hull_3d(points: np.ndarray, max_vertices: int) -> tuple[Hull3D, Hull3D]:
    """(original hull, capped hull): a convex polytope with at most `max_vertices` vertices
    that contains the hull of `points`, bounded by a subset of the hull's own face planes.

    Greedy: each round drops the smallest-area faces that share no vertex (about a third of
    the excess vertex count of them; dropping a triangle merges its 3 corners into 1), and
    intersects the remaining face planes; a round whose planes no longer bound a polytope
    drops one face at a time instead, smallest first. Every remaining plane supports the
    original hull, so the result contains it; small faces first keeps the added volume small.

    Raises:
      ValueError: the greedy rounds reach no bounded polytope with at most `max_vertices`
        vertices (a tetrahedron needs 4 of the hull's planes that bound one, which a smooth
        shape may not have: possible for `max_vertices` below 6).
    """
    original = convex_hull_3d(points)
    if len(original.vertices) <= max_vertices:
        return original, original
    # Work about the hull's centre: corners are then computed without the rounding of a
    # large offset (a small shape far from its frame's origin).
    origin = original.vertices.mean(axis=0)
    current = dataclasses.replace(original, vertices=original.vertices - origin)
    while len(current.vertices) > max_vertices:
        faces = _faces(current)
        centre = current.vertices.mean(axis=0)
        order = np.argsort(faces.areas)
        wanted = max(1, (len(current.vertices) - max_vertices) // 3)
        batch, touched = [], set()
        for face in order:
            if not faces.corners[face] & touched:
                batch.append(face)
                touched |= faces.corners[face]
            if len(batch) == wanted:
                break
        attempts = [batch] + [[face] for face in order]
        for dropped in attempts:
            keep = np.ones(len(faces.normals), bool)
            keep[dropped] = False
            candidate = _intersect_halfspaces(faces.normals[keep], faces.offsets[keep], centre)
            if candidate is not None:
                break
        else:
            raise ValueError(f"cannot cap this hull at {max_vertices} vertices with its own "
                             f"face planes (stuck at {len(current.vertices)})")
        current = candidate
    return original, dataclasses.replace(current, vertices=current.vertices + origin)
