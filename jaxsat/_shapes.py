"""Convex shapes as fixed-size padded pytrees, and their eager constructors."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxsat import _geometry as geometry
from jaxsat._kernels import Vec, as_vecs, explicit_float_dtype, mul, vdot, vscale, vsum, where

__all__ = ["CappedHull", "Polytope", "SizeClass", "box", "cap_hull", "capsule", "circle",
           "float_dtype", "moved", "pad_and_stack", "parallelepiped_frame", "polygon",
           "polyhedron", "regular_polygon", "ring_neighbours", "rounded", "size_class_for",
           "sphere", "stack"]


class SizeClass(NamedTuple):
    """The padded sizes of a Polytope's fields: shapes of one size class (and dimension and
    dtype) share every compiled kernel."""

    vertices: int
    """V: rows of `vertices` and `vertex_mask`."""
    faces: int
    """F: rows of `face_normals`, `face_extents` and `face_mask`."""
    edge_directions: int
    """E: rows of `edge_directions` and `edge_mask` (0 in 2D)."""
    hull_edges: int
    """K: rows of `edge_endpoints`, `edge_face_normals` and `hull_edge_mask` (0 in 2D)."""


def size_class_for(dim: int, max_vertices: int) -> SizeClass:
    """The size class `polygon` or `polyhedron` pads to for `max_vertices`: a polygon has as
    many edges as vertices; a convex polyhedron with V vertices has at most 2V - 4 faces and
    3V - 6 edges (Euler's formula with triangular faces)."""
    if dim == 2:
        return SizeClass(max_vertices, max_vertices, 0, 0)
    most_edges = max(3 * max_vertices - 6, 1)
    return SizeClass(max_vertices, max(2 * max_vertices - 4, 1), most_edges, most_edges)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Polytope:
    """A convex polygon (D = 2) or polyhedron (D = 3) in its own local frame.

    Every array is padded to a fixed size (its `size_class`) so that one compiled kernel
    serves every shape of a size class. The padding rule: padding rows repeat row 0 (masks pad
    with False). So padding never changes a minimum or a maximum over rows, and extremes,
    supports and SAT depths need no mask; the masks are needed only where a row is counted or
    weighted (soft extremes, the real vertex count of a polygon ring, contact slots). Build
    instances with `polygon`, `polyhedron`, `box`, `regular_polygon`, `sphere`, `circle`,
    `capsule` and `rounded`, and batch them with `stack` (which adds a leading batch axis).

    Edges. In 2D the real vertices come first, counter-clockwise, and edge i joins vertex i and
    vertex i + 1 of the ring of `num_real_vertices` (`ring_neighbours`); because padding
    repeats vertex 0, rolling the padded array by one also closes the ring, with zero-length
    edges at the padding. In 3D `edge_endpoints` lists the hull edges.

    Rounded shapes (`radius` not None) may have a degenerate core: one point (`sphere`,
    `circle`) or one segment (`capsule`). Such a core carries, as its face normals, axes that
    complete the SAT's candidates without being faces (any axis gives a valid bound): the
    coordinate axes for a point; for a segment its direction and the normals across it. A
    3D segment's hull edges are four copies of the segment, one per quarter of its Gauss-map
    circle (the directions across it), so that the Gauss-map SAT sees it like a thin prism.
    """

    vertices: jax.Array
    """(V, D) float: vertex coordinates in the local frame (counter-clockwise in 2D)."""
    vertex_mask: jax.Array
    """(V,) bool: True for real vertices, False for padding."""
    face_normals: jax.Array
    """(F, D) float: unit face (2D: edge) normals, unique up to sign (a box has D of them)."""
    face_extents: jax.Array
    """(F, 2) float: [min, max] of the shape's own vertices projected on each face normal."""
    face_mask: jax.Array
    """(F,) bool: True for real face normals."""
    edge_directions: jax.Array
    """(E, D) float: unit edge directions, unique up to sign; 3D only (E = 0 in 2D)."""
    edge_mask: jax.Array
    """(E,) bool: True for real edge directions."""
    edge_endpoints: jax.Array
    """(K, 2) int32: vertex indices of every hull edge; 3D only (K = 0 in 2D)."""
    edge_face_normals: jax.Array
    """(K, 2, D) float: outward unit normals of the two faces meeting at each hull edge."""
    hull_edge_mask: jax.Array
    """(K,) bool: True for real hull edges."""
    radius: jax.Array | None = None
    """() float, or None: the rounding radius r >= 0. A rounded shape is the set of points
    within r of its core, the polytope the other fields describe (`sphere`, `capsule`,
    `rounded`); None for a sharp polytope. Whether a shape is rounded is static (None or an
    array), so that sharp pairs keep the SAT kernels and rounded pairs take the distance
    kernels, each compiled for the kinds it sees."""

    @property
    def dim(self) -> int:
        """Spatial dimension, 2 or 3 (static)."""
        return self.vertices.shape[-1]

    @property
    def batch_shape(self) -> tuple[int, ...]:
        """Leading batch axes (empty for a single shape)."""
        return self.vertices.shape[:-2]

    @property
    def dtype(self) -> jnp.dtype:
        return self.vertices.dtype

    @property
    def size_class(self) -> SizeClass:
        """The padded sizes of the fields (static)."""
        return SizeClass(self.vertices.shape[-2], self.face_normals.shape[-2],
                         self.edge_directions.shape[-2], self.edge_endpoints.shape[-2])

    @property
    def is_parallelepiped(self) -> bool:
        """Static: a 3D shape with at most 3 (padded) unique edge directions, which only a
        parallelepiped (a box, possibly sheared) has. Its faces have 4 edges, and every pair
        of its edge directions with another parallelepiped's bounds their Minkowski
        difference, so the SAT projects on all 9 cross products instead of using the Gauss
        map."""
        return self.dim == 3 and self.edge_directions.shape[-2] <= 3

    @property
    def has_parallelepiped_frame(self) -> bool:
        """Static: a sharp parallelepiped padded to nothing (8 vertices, 3 face normals, 3
        edge directions), so that every entry of a batch of it is a whole parallelepiped and
        `parallelepiped_frame` describes it exactly. (A rounded batch may hold a point or
        segment core padded to 8 vertices, so rounded shapes never qualify.)"""
        return (self.dim == 3 and self.radius is None and self.vertices.shape[-2] == 8
                and self.face_normals.shape[-2] == 3 and self.edge_directions.shape[-2] == 3)

    @property
    def is_rounded(self) -> bool:
        """Static: the shape carries a radius (it may be 0)."""
        return self.radius is not None

    @property
    def num_real_vertices(self) -> jax.Array:
        """() int32 (batch shape): how many vertices are real (traced)."""
        return jnp.sum(self.vertex_mask, axis=-1, dtype=jnp.int32)


def parallelepiped_frame(shape: Polytope) -> tuple[Vec, list[Vec]]:
    """(centre, three half-edge vectors e_m), as Vecs, of an unbatched shape with
    `has_parallelepiped_frame`: its points are centre + sum_m s_m e_m for s in [-1, 1]^3, so
    its support along any axis u is u . centre + sum_m |u . e_m|.

    From the face normals n_m, extents [lo_m, hi_m] (the shape is the set of x with
    lo_m <= n_m . x <= hi_m) and edge directions d_j: each edge direction lies in two of the
    three face planes, so of t_m = n_m . d_j only one, t_m*, is nonzero, and along d_j the
    shape's half edge is half_m* / |t_m*| and its centre's coordinate mid_m* / t_m*. Written
    as sum_m half_m |t_m| / sum_m t_m^2 and sum_m mid_m t_m / sum_m t_m^2, that needs no
    matching of edges to faces. Read from the same face and edge data as the box kernel's
    choice, so it is computed in the choice's own pass (the frame from cross products of the
    normals, w_m = n_(m+1) x n_(m+2) over n_0 . w_0, took six passes of its own, and box
    `penetration` took 1.06x as long). Not differentiable in a useful way (the face data are
    fixed by the vertices at construction): for choosing, not for measuring."""
    normals = as_vecs(shape.face_normals)
    extents = shape.face_extents
    mids = [0.5 * (extents[m, 0] + extents[m, 1]) for m in range(3)]
    halves = [0.5 * (extents[m, 1] - extents[m, 0]) for m in range(3)]
    centres, half_edges = [], []
    for direction in as_vecs(shape.edge_directions):
        along = [vdot(normal, direction) for normal in normals]
        inverse = 1.0 / vdot(along, along)
        length = mul(vdot(halves, [jnp.abs(x) for x in along]), inverse)
        offset = mul(vdot(mids, along), inverse)
        half_edges.append(vscale(length, direction))
        centres.append(vscale(offset, direction))
    return vsum(centres), half_edges


def ring_neighbours(index, count):
    """(previous, next) vertex index of a polygon ring of `count` real vertices (padding rows
    come after them, so the ring closes at count - 1, not at the padded end)."""
    count = jnp.asarray(count)
    index = jnp.asarray(index, count.dtype)
    previous = where(index == 0, count - 1, index - 1)
    following = where(index + 1 >= count, 0, index + 1)
    return previous, following


def float_dtype(source: np.ndarray | None, dtype) -> jnp.dtype:
    """The JAX dtype a constructor stores: `dtype`, else the input's float dtype, else default.

    An input's float64 becomes float32 while 64-bit JAX is off, as for any JAX array; an
    explicit dtype=float64 then raises ValueError (`explicit_float_dtype`)."""
    if dtype is not None:
        return explicit_float_dtype(dtype)
    is_float = source is not None and np.issubdtype(source.dtype, np.floating)
    return jax.dtypes.canonicalize_dtype(source.dtype if is_float else float)


def _pad_rows(rows: np.ndarray, size: int, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Pad `rows` along axis 0 to `size` by repeating row 0; return (padded, mask)."""
    count = len(rows)
    if count > size:
        raise ValueError(f"shape has {count} {name}, more than the {size} allowed")
    if count == 0:
        return np.zeros((size, *rows.shape[1:]), rows.dtype), np.zeros(size, bool)
    padding = np.repeat(rows[:1], size - count, axis=0)
    return np.concatenate([rows, padding]), np.arange(size) < count


def _maybe_unique(directions: np.ndarray, unique_axes: bool) -> np.ndarray:
    if not isinstance(unique_axes, bool):
        raise TypeError(f"unique_axes must be True or False, got {unique_axes!r}")
    return geometry.unique_directions(directions) if unique_axes else directions


def _check_max_vertices(max_vertices: int | None, count: int, dim: int) -> int:
    if max_vertices is None:
        return count
    if int(max_vertices) != max_vertices or max_vertices < 1:
        raise ValueError(f"max_vertices must be a positive integer, got {max_vertices!r}")
    if count > max_vertices:
        hint = (" (jaxsat.cap_hull simplifies a 3D hull to fewer)"
                if dim == 3 and max_vertices >= 4 else "")
        raise ValueError(f"shape has {count} vertices, more than max_vertices={max_vertices}"
                         + hint)
    return int(max_vertices)


def _build(vertices, face_normals, edge_directions, edge_endpoints, edge_face_normals,
           sizes: SizeClass, dtype) -> Polytope:
    """Pad NumPy geometry to `sizes` and convert it to a Polytope of `dtype`."""
    num_vertices, num_faces, num_edges, num_hull_edges = sizes
    extents = vertices @ face_normals.T
    face_extents = np.stack([extents.min(axis=0), extents.max(axis=0)], axis=1)
    padded_vertices, vertex_mask = _pad_rows(vertices, num_vertices, "vertices")
    padded_normals, face_mask = _pad_rows(face_normals, num_faces, "face normals")
    padded_extents, _ = _pad_rows(face_extents, num_faces, "face normals")
    padded_edges, edge_mask = _pad_rows(edge_directions, num_edges, "edge directions")
    padded_endpoints, hull_edge_mask = _pad_rows(edge_endpoints, num_hull_edges, "hull edges")
    padded_edge_normals, _ = _pad_rows(edge_face_normals, num_hull_edges, "hull edges")
    as_float = lambda array: jnp.asarray(array, dtype=dtype)  # noqa: E731
    return Polytope(
        vertices=as_float(padded_vertices),
        vertex_mask=jnp.asarray(vertex_mask),
        face_normals=as_float(padded_normals),
        face_extents=as_float(padded_extents),
        face_mask=jnp.asarray(face_mask),
        edge_directions=as_float(padded_edges),
        edge_mask=jnp.asarray(edge_mask),
        edge_endpoints=jnp.asarray(padded_endpoints, dtype=jnp.int32),
        edge_face_normals=as_float(padded_edge_normals),
        hull_edge_mask=jnp.asarray(hull_edge_mask),
    )


def polygon(vertices, max_vertices: int | None = None, *, dtype=None,
            unique_axes: bool = True) -> Polytope:
    """A convex polygon from its vertices, given in either winding order.

    Args:
      vertices: (N, 2) array-like of vertex coordinates in the local frame. A repeated closing
        vertex, duplicates and vertices on a straight edge are dropped.
      max_vertices: pad to this many vertices (and face normals) so that polygons of different
        vertex counts share one compiled kernel. Default: no padding.
      dtype: float dtype of the result; default: the input's float dtype, else JAX's default.
        An explicit float64 needs 64-bit JAX (`jax_enable_x64`): ValueError otherwise.
      unique_axes: keep one face normal per direction (a rectangle tests 2 axes, not 4).
        False keeps one per edge, as a textbook SAT does: the same answers, more work.

    Raises:
      TypeError: non-numeric vertices, or a unique_axes that is not a bool.
      ValueError: wrong shape, NaN/inf, fewer than 3 distinct vertices, collinear vertices,
        non-convex or self-intersecting polygon, or more than `max_vertices` vertices.
    """
    points = geometry.as_point_array(vertices, 2, "polygon vertices")
    ring = geometry.convex_polygon(points)
    size = _check_max_vertices(max_vertices, len(ring), 2)
    normals = _maybe_unique(geometry.polygon_edge_normals(ring), unique_axes)
    sizes = (size_class_for(2, size) if max_vertices is not None
             else SizeClass(size, len(normals), 0, 0))
    return _build(ring, normals, np.zeros((0, 2)), np.zeros((0, 2), np.int64),
                  np.zeros((0, 2, 2)), sizes,
                  float_dtype(np.asarray(vertices), dtype))


def polyhedron(points, max_vertices: int | None = None, *, dtype=None,
               unique_axes: bool = True) -> Polytope:
    """The convex hull of a 3D point cloud, with coplanar triangles merged into faces.

    Args:
      points: (N, 3) array-like of points in the local frame; interior points are ignored.
      max_vertices: pad to this many hull vertices, and faces and edges to the most a convex
        polyhedron with that many vertices can have (2V - 4 faces, 3V - 6 edges), so that every
        hull of the size class shares one compiled kernel. Default: no padding.
      dtype: float dtype of the result; default: the input's float dtype, else JAX's default.
        An explicit float64 needs 64-bit JAX (`jax_enable_x64`): ValueError otherwise.
      unique_axes: keep face normals and edge directions unique up to sign (a box: 3 and 3).
        False keeps one per face and one per edge (a box: 6 and 12), as a textbook SAT does:
        the same answers, more work (see benchmarks/scene.py).

    Raises:
      TypeError: non-numeric points, or a unique_axes that is not a bool.
      ValueError: wrong shape, NaN/inf, fewer than 4 distinct points, collinear or coplanar
        points, or more hull vertices than `max_vertices`.
    """
    cloud = geometry.as_point_array(points, 3, "polyhedron points")
    hull = geometry.convex_hull_3d(cloud)
    normals = _maybe_unique(hull.face_normals, unique_axes)
    segments = hull.vertices[hull.edges[:, 1]] - hull.vertices[hull.edges[:, 0]]
    lengths = np.linalg.norm(segments, axis=1, keepdims=True)
    directions = _maybe_unique(segments / lengths, unique_axes)
    size = _check_max_vertices(max_vertices, len(hull.vertices), 3)
    sizes = (size_class_for(3, size) if max_vertices is not None
             else SizeClass(size, len(normals), len(directions), len(hull.edges)))
    return _build(hull.vertices, normals, directions, hull.edges,
                  hull.face_normals[hull.edge_faces], sizes,
                  float_dtype(np.asarray(points), dtype))


def _as_radius(radius, name: str = "radius") -> float:
    if isinstance(radius, (bool, np.bool_)) or not isinstance(
            radius, (int, float, np.number, np.ndarray, jax.Array)):
        raise TypeError(f"{name} must be a number, got {type(radius).__name__}")
    value = np.asarray(radius)
    if value.shape != () or not np.issubdtype(value.dtype, np.number):
        raise TypeError(f"{name} must be a scalar number, got shape {value.shape}")
    if not (np.isfinite(value) and value >= 0):
        raise ValueError(f"{name} must be finite and >= 0, got {radius!r}")
    return float(value)


def _core(vertices: np.ndarray, axes: np.ndarray, quarters: np.ndarray, dtype) -> Polytope:
    """A degenerate core: 1 point or 2 (a segment); `axes` its SAT face normals; in 3D,
    `quarters` (4, 2, 3) the face-normal pairs of a segment's hull edges (empty for a point)."""
    dim = vertices.shape[1]
    segment = vertices[1:] - vertices[:1]
    length = np.linalg.norm(segment)
    # A zero-length segment has no direction (a zero row gives no SAT axis).
    direction = segment / length if length > 0 else np.zeros((0, dim))
    if dim == 2:
        return _build(vertices, axes, np.zeros((0, 2)), np.zeros((0, 2), np.int64),
                      np.zeros((0, 2, 2)), SizeClass(len(vertices), len(axes), 0, 0), dtype)
    endpoints = np.zeros((len(quarters), 2), np.int64)
    endpoints[:, 1] = 1
    sizes = SizeClass(len(vertices), len(axes), 1, max(len(quarters), 1))
    return _build(vertices, axes, direction, endpoints, quarters, sizes, dtype)


def _ball(radius, dim: int, dtype) -> Polytope:
    """A ball (3D) or disc (2D) of `radius` about the origin: a rounded one-point core."""
    r = _as_radius(radius)
    dtype = float_dtype(np.asarray(radius), dtype)
    core = _core(np.zeros((1, dim)), np.eye(dim), np.zeros((0, 2, dim)), dtype)
    return dataclasses.replace(core, radius=jnp.asarray(r, dtype))


def sphere(radius, *, dtype=None) -> Polytope:
    """A 3D ball of `radius` about the origin (a rounded shape whose core is one point).

    Raises:
      TypeError: a radius that is not a scalar number.
      ValueError: a radius that is not finite and >= 0.
    """
    return _ball(radius, 3, dtype)


def circle(radius, *, dtype=None) -> Polytope:
    """A 2D disc of `radius` about the origin (a rounded shape whose core is one point).

    Raises: as `sphere`.
    """
    return _ball(radius, 2, dtype)


def capsule(half_length, radius, dim: int = 3, *, dtype=None) -> Polytope:
    """A capsule: the points within `radius` of the segment from -half_length to +half_length
    along local z (3D) or local x (2D, a stadium).

    Raises:
      TypeError: a half_length or radius that is not a scalar number.
      ValueError: a half_length or radius that is not finite and >= 0, or a dim other than
        2 or 3.
    """
    half, r = _as_radius(half_length, "half_length"), _as_radius(radius)
    if dim not in (2, 3) or isinstance(dim, bool):
        raise ValueError(f"dim must be 2 or 3, got {dim!r}")
    dtype = float_dtype(np.zeros((), np.result_type(np.asarray(half_length), np.asarray(radius))),
                        dtype)
    if dim == 2:
        core = _core(np.array([[-half, 0.0], [half, 0.0]]), np.array([[0.0, 1.0], [1.0, 0.0]]),
                     np.zeros((0, 2, 2)), dtype)
    else:
        x, y = np.eye(3)[0], np.eye(3)[1]
        # Consecutive pairs (n1, n2) with n2 x n1 = -z: each hull edge runs along the segment.
        quarters = np.array([[x, y], [y, -x], [-x, -y], [-y, x]])
        core = _core(np.array([[0.0, 0.0, -half], [0.0, 0.0, half]]), np.eye(3), quarters, dtype)
    return dataclasses.replace(core, radius=jnp.asarray(r, dtype))


def rounded(shape: Polytope, radius) -> Polytope:
    """`shape` with every point within `radius` of it added: a rounded box or polygon (on a
    rounded shape, the radii add).

    Raises:
      TypeError: shape is not an unbatched Polytope, or a radius that is not a scalar number.
      ValueError: a radius that is not finite and >= 0.
    """
    if not isinstance(shape, Polytope):
        raise TypeError(f"shape must be a jaxsat.Polytope, got {type(shape).__name__}")
    if shape.batch_shape:
        raise TypeError(f"shape must be unbatched, got batch shape {shape.batch_shape}")
    r = _as_radius(radius)
    total = r if shape.radius is None else r + float(shape.radius)
    return dataclasses.replace(shape, radius=jnp.asarray(total, shape.dtype))


def moved(shape: Polytope, pose) -> Polytope:
    """`shape` with its geometry moved by the rigid motion `pose` (each point x to R x + t):
    the same shape described in another frame, e.g. a piece placed in a compound's frame
    (`compound([moved(sphere(0.3), pose3(...)), ...])`). Eager, on concrete values.

    Raises:
      TypeError: shape is not an unbatched Polytope, or pose is not an unbatched Pose of the
        shape's dimension.
    """
    if not isinstance(shape, Polytope) or shape.batch_shape:
        raise TypeError(f"shape must be an unbatched jaxsat.Polytope, got {type(shape).__name__}"
                        + (f" with batch shape {shape.batch_shape}"
                           if isinstance(shape, Polytope) else ""))
    rotation = np.asarray(getattr(pose, "rotation", None), dtype=np.float64)
    translation = np.asarray(getattr(pose, "translation", None), dtype=np.float64)
    if rotation.shape != (shape.dim, shape.dim) or translation.shape != (shape.dim,):
        raise TypeError(f"pose must be an unbatched {shape.dim}D jaxsat.Pose, got "
                        f"{type(pose).__name__}")
    dtype = shape.dtype
    turn = lambda rows: jnp.asarray(np.asarray(rows, np.float64) @ rotation.T, dtype)  # noqa: E731
    normals = np.asarray(shape.face_normals, np.float64) @ rotation.T
    # Each face's extent moves by the translation's component along its normal.
    extents = np.asarray(shape.face_extents, np.float64) + (normals @ translation)[:, None]
    return dataclasses.replace(
        shape,
        vertices=jnp.asarray(np.asarray(shape.vertices, np.float64) @ rotation.T + translation,
                             dtype),
        face_normals=jnp.asarray(normals, dtype), face_extents=jnp.asarray(extents, dtype),
        edge_directions=turn(shape.edge_directions),
        edge_face_normals=turn(shape.edge_face_normals))


class CappedHull(NamedTuple):
    """A convex polytope with at most a given number of vertices that contains a point cloud's
    hull (`cap_hull`), and how much larger it is."""

    vertices: np.ndarray
    """(V, 3) float64: its vertices, V <= max_vertices; pass them to `polyhedron`."""
    volume: float
    """Volume of the original hull."""
    added_volume: float
    """Volume added by capping (>= 0, 0 when the hull already fits)."""

    @property
    def relative_added_volume(self) -> float:
        """added_volume / volume."""
        return self.added_volume / self.volume


def cap_hull(points, max_vertices: int) -> CappedHull:
    """A hull of at most `max_vertices` vertices that contains the hull of `points`, so that any
    point cloud or mesh fits a size class (`polyhedron` raises instead when its hull has more
    vertices than `max_vertices`).

    The result is bounded by a subset of the hull's own face planes: every one supports the
    original hull, so the capped polytope contains it (unlike a hull of a subset of the
    points, as MuJoCo's vertex cap builds, which cuts corners off). Faces are dropped smallest
    first, which keeps the added volume small; it is reported, as a collision margin would be.
    Eager, in NumPy (about 2 s for a 162-vertex icosphere capped at 32).

    Example:
      capped = jaxsat.cap_hull(mesh_vertices, 32)
      shape = jaxsat.polyhedron(capped.vertices, max_vertices=32)

    Raises:
      TypeError: non-numeric points.
      ValueError: as `polyhedron` for the points; a `max_vertices` below 4; or a hull that
        its own face planes cannot bound with so few vertices (possible below 6 vertices).
    """
    cloud = geometry.as_point_array(points, 3, "cap_hull points")
    if int(max_vertices) != max_vertices or max_vertices < 4:
        raise ValueError(f"max_vertices must be an integer >= 4 (a tetrahedron), got "
                         f"{max_vertices!r}")
    original, capped = geometry.cap_hull_3d(cloud, int(max_vertices))
    volume = geometry.hull_volume(original)
    added = 0.0 if capped is original else max(geometry.hull_volume(capped) - volume, 0.0)
    return CappedHull(capped.vertices.copy(), volume, added)


def box(half_extents, max_vertices: int | None = None, *, dtype=None,
        unique_axes: bool = True) -> Polytope:
    """An axis-aligned box centred on the origin: a rectangle (2 values) or a cuboid (3 values).

    `max_vertices`, `dtype` and `unique_axes` are as in `polygon` and `polyhedron`.

    Raises:
      ValueError: not 2 or 3 values, or a half extent that is not finite and positive.
    """
    half = np.asarray(half_extents, dtype=np.float64)
    if half.shape not in ((2,), (3,)):
        raise ValueError(f"half_extents must have 2 or 3 entries, got shape {half.shape}")
    if not np.all(np.isfinite(half)) or np.any(half <= 0):
        raise ValueError(f"half_extents must be finite and positive, got {half.tolist()}")
    dtype = float_dtype(np.asarray(half_extents), dtype)
    if len(half) == 2:
        corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=np.float64) * half
        return polygon(corners, max_vertices, dtype=dtype, unique_axes=unique_axes)
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64)
    return polyhedron(signs * half, max_vertices, dtype=dtype, unique_axes=unique_axes)


def regular_polygon(num_sides: int, radius: float = 1.0, max_vertices: int | None = None, *,
                    dtype=None) -> Polytope:
    """A regular polygon with `num_sides` vertices on a circle of `radius` about the origin.

    Raises:
      ValueError: fewer than 3 sides, or a radius that is not finite and positive.
    """
    if int(num_sides) != num_sides or num_sides < 3:
        raise ValueError(f"num_sides must be an integer >= 3, got {num_sides!r}")
    if not np.isfinite(radius) or radius <= 0:
        raise ValueError(f"radius must be finite and positive, got {radius!r}")
    angles = 2 * np.pi * np.arange(int(num_sides)) / int(num_sides)
    corners = radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    return polygon(corners, max_vertices, dtype=dtype)


_FIELD_SIZES = {
    "vertices": "vertices", "vertex_mask": "vertices", "face_normals": "faces",
    "face_extents": "faces", "face_mask": "faces", "edge_directions": "edge_directions",
    "edge_mask": "edge_directions", "edge_endpoints": "hull_edges",
    "edge_face_normals": "hull_edges", "hull_edge_mask": "hull_edges",
}
"""Which `SizeClass` entry each Polytope field's first axis follows."""


def _padded_fields(shape: Polytope, sizes: SizeClass) -> dict[str, np.ndarray]:
    """Every field of an unbatched shape as NumPy, padded to `sizes` by the padding rule.
    NumPy keeps this fast: eager jnp ops made stacking 256 boxes take 2 s."""
    fields = {}
    for name, size_name in _FIELD_SIZES.items():
        field, size = np.asarray(getattr(shape, name)), getattr(sizes, size_name)
        if field.dtype == bool:
            fields[name] = np.concatenate([field, np.zeros(size - len(field), bool)])
        else:
            fields[name] = _pad_rows(field, size, name)[0]
    return fields


def pad_and_stack(shapes: Sequence[Polytope], sizes: SizeClass | None = None,
                  length: int | None = None) -> Polytope:
    """Unbatched shapes padded to `sizes` (default: the smallest class that holds them all)
    and stacked on a new leading axis of `length` entries (default: one per shape; missing
    entries repeat shape 0). Eager, in NumPy; the caller checks the shapes are alike."""
    if sizes is None:
        sizes = SizeClass(*(max(column) for column in
                            zip(*(shape.size_class for shape in shapes), strict=True)))
    padded = [_padded_fields(shape, sizes) for shape in shapes]
    if any(shape.is_rounded for shape in shapes):
        # Sharp shapes join a rounded batch with radius 0 (the same shape).
        dtype = np.asarray(shapes[0].vertices).dtype
        for fields, shape in zip(padded, shapes, strict=True):
            fields["radius"] = np.asarray(0.0 if shape.radius is None else shape.radius, dtype)
    padded += [padded[0]] * ((length or len(padded)) - len(padded))
    return Polytope(**{name: jnp.asarray(np.stack([fields[name] for fields in padded]))
                       for name in padded[0]})


def stack(shapes: Sequence[Polytope]) -> Polytope:
    """Stack shapes of one dimension into a batch, padding them to common sizes.

    Returns:
      A Polytope whose fields have a leading batch axis of length len(shapes), ready for
      `jax.vmap`. If any shape is rounded, so is the batch (sharp entries get radius 0).

    Raises:
      TypeError: an entry that is not a Polytope.
      ValueError: an empty sequence, a batched entry, or a mix of 2D and 3D shapes or of
        dtypes.
    """
    shapes = list(shapes)
    if not shapes:
        raise ValueError("stack needs at least one shape")
    for index, shape in enumerate(shapes):
        if not isinstance(shape, Polytope):
            raise TypeError(f"stack entry {index} is a {type(shape).__name__}, not a "
                            "jaxsat.Polytope")
        if shape.batch_shape:
            raise ValueError(f"stack entry {index} is batched {shape.batch_shape}")
    dims = {shape.dim for shape in shapes}
    if len(dims) > 1:
        raise ValueError("stack cannot mix 2D and 3D shapes")
    dtypes = {shape.dtype for shape in shapes}
    if len(dtypes) > 1:
        raise ValueError(f"stack cannot mix dtypes, got {sorted(str(d) for d in dtypes)}")
    return pad_and_stack(shapes)
