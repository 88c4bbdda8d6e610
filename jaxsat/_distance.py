"""Exact signed distance and closest points for one pair of convex shapes.

The signed distance of convex shapes A and B is sd = max over unit axes u of gap(u), where
gap(u) = min_b u.b - max_a u.a (u points from a towards b). It is the Euclidean distance when
the shapes are apart and minus the penetration depth when they overlap. Every gap(u) is a lower
bound of sd, so sd is the largest gap over any set of axes that contains a maximiser:

* overlapping or touching: the SAT candidates (face normals, and edge-edge axes in 3D) do;
* separated: the closest features are vertex-face (a face normal: a SAT candidate), edge-edge
  with crossing interiors (an edge-edge SAT axis), or a vertex against an edge or a vertex. The
  last two are caught by the closest pair of points over all pairs of edges (segments): the
  axis through that pair is then the maximiser.

So sd = max(gap(SAT winner), gap(axis through the closest segment pair)), with no case split
and no tolerance: whichever axis is not the maximiser only gives a smaller lower bound.
Gradients follow Danskin's theorem: the winning axis is held fixed (its search runs under
stop_gradient) and only the projections are differentiated, which is the exact derivative
wherever the maximiser is unique, and never divides by a vanishing norm.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from jaxsat._narrowphase import (
    _best_axis,
    _candidate_groups,
    _cast_pair,
    _check_pair,
    _project,
    _relative_pose,
    _rotate,
    _safe_normalize,
)
from jaxsat._poses import Pose
from jaxsat._shapes import Polytope

__all__ = ["ClosestPoints", "closest_points", "signed_distance"]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ClosestPoints:
    """Result of `closest_points` for one pair (fields gain leading axes under `vmap`)."""

    signed_distance: jax.Array
    """() float: distance when apart (> 0), minus the penetration depth when overlapping."""
    point_a: jax.Array
    """(D,) float: world point of a; when apart, the point of a closest to b."""
    point_b: jax.Array
    """(D,) float: world point of b, equal to point_a + signed_distance * normal."""
    normal: jax.Array
    """(D,) float: unit world axis from a towards b (the penetration normal when overlapping)."""


def _masked_extreme(values, mask, lowest: bool):
    """Min (or max) over real entries only: padding must not receive a gradient share."""
    if lowest:
        return jnp.min(jnp.where(mask, values, jnp.inf), axis=-1)
    return jnp.max(jnp.where(mask, values, -jnp.inf), axis=-1)


def _gap(axes, a_vertices, a_mask, b_vertices, b_mask):
    """gap(u) = min_b u.b - max_a u.a for (C, D) axes (same frame as the vertices), (C,)."""
    low_b = _masked_extreme(_project(axes, b_vertices), b_mask, lowest=True)
    high_a = _masked_extreme(_project(axes, a_vertices), a_mask, lowest=False)
    return low_b - high_a


def _segment_indices(shape: Polytope):
    """Vertex indices (start, end) of every edge, (K,) each. A 2D polygon's edges join
    consecutive vertices; padding repeats vertex 0, so padded indices are mapped to 0: padded
    edges shrink to that point, the closing edge ends there, and witness weights (hence
    gradients) land on the real vertex, never on a padding row."""
    if shape.dim == 2:
        first = jnp.arange(shape.vertices.shape[0])
        real = lambda index: jnp.where(shape.vertex_mask[index], index, 0)  # noqa: E731
        return real(first), real(jnp.roll(first, -1))
    return shape.edge_endpoints[:, 0], shape.edge_endpoints[:, 1]


def _dot(x, y):
    return sum(x_k * y_k for x_k, y_k in zip(x, y, strict=True))


def _segment_parameters(start_a, delta_a, start_b, delta_b):
    """Parameters (s, t) in [0, 1] of the closest points start + s delta of two segments,
    given as lists of coordinate arrays (broadcasting).

    The closest pair of the lines, clamped: t is re-optimised for the clamped s and s again
    for the clamped t, which is exact for a convex quadratic on the unit square. Zero-length
    segments and parallel ones (a tiny determinant relative to the lengths) take s = 0."""
    offset = [a_k - b_k for a_k, b_k in zip(start_a, start_b, strict=True)]
    aa, bb, ab = _dot(delta_a, delta_a), _dot(delta_b, delta_b), _dot(delta_a, delta_b)
    a_off, b_off = _dot(delta_a, offset), _dot(delta_b, offset)
    determinant = aa * bb - ab * ab
    eps = jnp.finfo(determinant.dtype).eps
    crossing = determinant > 16 * eps * aa * bb
    safe = lambda x, ok: jnp.where(ok, x, 1.0)  # noqa: E731  (double where: no 0/0)
    s = jnp.where(crossing, (ab * b_off - a_off * bb) / safe(determinant, crossing), 0.0)
    s = jnp.clip(s, 0.0, 1.0)
    t = jnp.where(bb > 0, (ab * s + b_off) / safe(bb, bb > 0), 0.0)
    t = jnp.clip(t, 0.0, 1.0)
    s = jnp.where(aa > 0, (ab * t - a_off) / safe(aa, aa > 0), 0.0)
    return jnp.clip(s, 0.0, 1.0), t


def _segment_candidates(a: Polytope, a_vertices, b: Polytope, b_vertices):
    """Candidate closest pairs from the edges: for every edge of a, its closest pair to any
    edge of b, and for every edge of b, its closest pair to any edge of a.

    Returns points (C, D) on a and on b and their weights on a's and b's vertices ((C, V_a),
    (C, V_b)), C = K_a + K_b. Whatever the closest features (vertex-vertex, vertex-edge,
    edge-edge), the edge holding a closest point in its interior (or any edge at a closest
    vertex) has the true closest pair as its own minimum; a single global minimum could
    instead land, within rounding, on a neighbouring pair pointing elsewhere, and the gap
    along an axis is only Lipschitz in the axis. Within one edge, ties (within rounding) are
    averaged: pairs on one edge that tie share the closest point of that edge. Every
    coordinate stays a separate (K_a, K_b) array so XLA fuses the search."""
    start_a, end_a = _segment_indices(a)
    start_b, end_b = _segment_indices(b)
    column = lambda x: [x[:, k][:, None] for k in range(a.dim)]  # noqa: E731
    row = lambda x: [x[:, k][None, :] for k in range(a.dim)]  # noqa: E731
    origin_a = column(a_vertices[start_a])
    delta_a = column(a_vertices[end_a] - a_vertices[start_a])
    origin_b = row(b_vertices[start_b])
    delta_b = row(b_vertices[end_b] - b_vertices[start_b])
    s, t = _segment_parameters(origin_a, delta_a, origin_b, delta_b)
    points_a = [o + s * d for o, d in zip(origin_a, delta_a, strict=True)]
    points_b = [o + t * d for o, d in zip(origin_b, delta_b, strict=True)]
    squared = _dot(*([[q - p for p, q in zip(points_a, points_b, strict=True)]] * 2))
    eps = jnp.finfo(squared.dtype).eps
    one_hot = lambda index, size: (index[:, None] == jnp.arange(size)).astype(s.dtype)  # noqa: E731
    starts_a, ends_a = one_hot(start_a, a.vertices.shape[0]), one_hot(end_a, a.vertices.shape[0])
    starts_b, ends_b = one_hot(start_b, b.vertices.shape[0]), one_hot(end_b, b.vertices.shape[0])
    candidates = []
    for axis in (1, 0):
        smallest = jnp.min(squared, axis=axis, keepdims=True)
        # A slack of a few ulps, as XLA may recompute the squares inside a fusion with other
        # roundings; if nothing qualifies, the candidate is a zero-weight dummy whose zero
        # direction the SAT axis replaces.
        share = jnp.where(squared <= smallest + 4 * eps * smallest, 1.0, 0.0).astype(s.dtype)
        share = share / jnp.maximum(jnp.sum(share, axis=axis, keepdims=True), 1.0)
        mean = lambda x, ax=axis, w=share: jnp.sum(w * x, axis=ax)  # noqa: E731
        if axis == 1:  # one candidate per edge of a
            weights_a = mean(1 - s)[:, None] * starts_a + mean(s)[:, None] * ends_a
            weights_b = (share * (1 - t)) @ starts_b + (share * t) @ ends_b
        else:  # one candidate per edge of b
            weights_a = (share * (1 - s)).T @ starts_a + (share * s).T @ ends_a
            weights_b = mean(1 - t)[:, None] * starts_b + mean(t)[:, None] * ends_b
        candidates.append((jnp.stack([mean(x) for x in points_a], axis=-1),
                           jnp.stack([mean(x) for x in points_b], axis=-1),
                           weights_a, weights_b))
    return tuple(jnp.concatenate(parts) for parts in zip(*candidates, strict=True))


def _exact_parts(a: Polytope, pose_a: Pose, b: Polytope, pose_b: Pose):
    """Values only, in a's frame: the gaps (C + 1,) along the SAT winner and along every
    segment candidate's axis, those axes (C + 1, D), b's vertices, and the relative pose
    (rotation, translation) that maps b's local coordinates into a's frame."""
    rotation, translation = _relative_pose(pose_a, pose_b)
    b_vertices = _rotate(rotation, b.vertices) + translation
    _, sat_axis = _best_axis(_candidate_groups(a, pose_a, b, pose_b)[0])
    points_a, points_b, _, _ = _segment_candidates(a, a.vertices, b, b_vertices)
    segment_axes, valid = _safe_normalize(points_b - points_a, 0.0)
    # Touching or crossing edges give no direction; the SAT axis stands in (any unit axis is
    # a lower bound, so the stand-in can never raise the result).
    segment_axes = jnp.where(valid[:, None], segment_axes, sat_axis)
    axes = jnp.concatenate([sat_axis[None], segment_axes])
    gaps = _gap(axes, a.vertices, a.vertex_mask, b_vertices, b.vertex_mask)
    return gaps, axes, b_vertices, (rotation, translation)


def _one_hot(index, size, dtype):
    return (jnp.arange(size) == index).astype(dtype)


def _plane_basis(axis):
    """Two unit vectors spanning the plane orthogonal to a unit 3D axis."""
    helper = jnp.where(jnp.abs(axis[0]) < 0.6, jnp.array([1.0, 0, 0], axis.dtype),
                       jnp.array([0, 1.0, 0], axis.dtype))
    first = _safe_normalize(jnp.cross(axis, helper), 0.0)[0]
    return first, jnp.cross(axis, first)


def _segment_weights(vertices, first, last, point):
    """Weights on vertices `first`, `last` of the point of segment [first, last] nearest to
    `point`, (V,)."""
    start, delta = vertices[first], vertices[last] - vertices[first]
    length = jnp.sum(delta**2)
    t = jnp.clip(jnp.sum((point - start) * delta) / jnp.where(length > 0, length, 1.0), 0, 1)
    size, dtype = vertices.shape[0], vertices.dtype
    return (1 - t) * _one_hot(first, size, dtype) + t * _one_hot(last, size, dtype)


def _face_weights(vertices, mask, axis, point, lowest: bool):
    """Weights (V,) on the vertices of the face of a shape that is extreme along `axis`
    (lowest or highest), reproducing `point` of that face: its barycentric coordinates in
    a triangle of a fan over the face (an edge's or a vertex's when the face is one)."""
    projections = jnp.where(mask, vertices @ axis, jnp.inf if lowest else -jnp.inf)
    extreme = jnp.min(projections) if lowest else jnp.max(projections)
    scale = jnp.max(jnp.abs(vertices)) + jnp.abs(extreme)
    on_face = mask & (jnp.abs(projections - extreme) <= 1e3 * jnp.finfo(scale.dtype).eps * scale)
    size = vertices.shape[0]
    if vertices.shape[-1] == 2:
        first, last = jnp.argmax(on_face), size - 1 - jnp.argmax(on_face[::-1])
        return _segment_weights(vertices, first, last, point)
    # Order the face's vertices by angle around their centroid, in the face plane.
    u, v = _plane_basis(axis)
    weights = on_face.astype(vertices.dtype)
    centroid = weights @ vertices / jnp.sum(weights)
    plane = jnp.stack([(vertices - centroid) @ u, (vertices - centroid) @ v], axis=-1)
    target = jnp.stack([(point - centroid) @ u, (point - centroid) @ v])
    order = jnp.argsort(jnp.where(on_face, jnp.arctan2(plane[:, 1], plane[:, 0]), jnp.inf))
    count = jnp.sum(on_face)
    corner, second, third = order[0], order[1:-1], order[2:]
    edge1, edge2 = plane[second] - plane[corner], plane[third] - plane[corner]
    offset = target - plane[corner]
    area = edge1[:, 0] * edge2[:, 1] - edge1[:, 1] * edge2[:, 0]
    real = (jnp.arange(2, size) < count) & (jnp.abs(area) > 0)
    safe_area = jnp.where(real, area, 1.0)
    beta = (offset[0] * edge2[:, 1] - offset[1] * edge2[:, 0]) / safe_area
    gamma = (edge1[:, 0] * offset[1] - edge1[:, 1] * offset[0]) / safe_area
    alpha = 1 - beta - gamma
    fit = jnp.where(real, jnp.minimum(jnp.minimum(alpha, beta), gamma), -jnp.inf)
    best = jnp.argmax(fit)
    coords = jnp.clip(jnp.stack([alpha[best], beta[best], gamma[best]]), 0, None)
    coords = coords / jnp.sum(coords)
    corners = jnp.stack([corner, second[best], third[best]])
    fan = coords @ (corners[:, None] == jnp.arange(size)).astype(vertices.dtype)
    # A face of one or two vertices (a vertex or an edge) has no triangle.
    return jnp.where(count >= 3, fan, _segment_weights(vertices, order[0],
                                                        jnp.where(count >= 2, order[1], order[0]),
                                                        point))


def _touching_witnesses(a: Polytope, b: Polytope, rotation, translation, b_vertices, axis,
                        distance):
    """A pair (p in a, q in b) with q - p = distance * axis, in a's frame, given the exact
    signed distance and its axis (distance >= 0 here: the shapes are apart or touching),
    and the pair as weights on a's and b's vertices ((V_a,), (V_b,)).

    Two constructions: the closest segment pair (right for vertex-edge, vertex-vertex and
    edge-edge features), and a support vertex moved across by the distance onto the other
    shape's face (right for vertex-face features; of the two senses, the one landing least
    outside the other shape). The pair that better satisfies q - p = distance * axis wins:
    its residual is |q - p - distance * axis| for the segments and how far the moved vertex
    lands outside for the face."""
    points_a, points_b, candidate_a, candidate_b = _segment_candidates(a, a.vertices, b,
                                                                        b_vertices)
    residuals = jnp.sum((points_b - points_a - distance * axis) ** 2, axis=-1)
    residuals = jnp.where(jnp.sum(candidate_a, axis=-1) > 0.5, residuals, jnp.inf)  # dummies
    best = jnp.argmin(residuals)
    point_a, point_b = points_a[best], points_b[best]
    segment_a, segment_b = candidate_a[best], candidate_b[best]
    index_a = jnp.argmax(jnp.where(a.vertex_mask, a.vertices @ axis, -jnp.inf))
    index_b = jnp.argmin(jnp.where(b.vertex_mask, b_vertices @ axis, jnp.inf))
    support_a, support_b = a.vertices[index_a], b_vertices[index_b]
    onto_b, onto_a = support_a + distance * axis, support_b - distance * axis
    to_b_frame = lambda x: _rotate(rotation.T, x - translation)  # noqa: E731
    outside_b, outside_a = _outside(to_b_frame(onto_b)[None], b)[0], _outside(onto_a[None], a)[0]
    a_faces_b = outside_b <= outside_a
    face_residual = jnp.maximum(jnp.minimum(outside_a, outside_b), 0.0)
    segment_residual = jnp.sqrt(residuals[best])
    dtype = distance.dtype
    face_weights_a = jnp.where(a_faces_b, _one_hot(index_a, a.vertices.shape[0], dtype),
                               _face_weights(a.vertices, a.vertex_mask, axis, onto_a, False))
    face_weights_b = jnp.where(a_faces_b,
                               _face_weights(b_vertices, b.vertex_mask, axis, onto_b, True),
                               _one_hot(index_b, b.vertices.shape[0], dtype))
    use_segments = segment_residual <= face_residual
    pick = lambda x, y: jnp.where(use_segments, x, y)  # noqa: E731
    return (pick(point_a, jnp.where(a_faces_b, support_a, onto_a)),
            pick(point_b, jnp.where(a_faces_b, onto_b, support_b)),
            pick(segment_a, face_weights_a), pick(segment_b, face_weights_b))


def _witnesses(a: Polytope, pose_a: Pose, b: Polytope, pose_b: Pose):
    """Values only, in a's frame: signed distance, axis, witness points (b's moved back) and
    their weights on the vertices.

    Overlapping: move b out along the axis until the shapes touch, find the touching points
    there, and move b's point back (b's weights need no change: the move is a translation).
    Apart: the move is zero."""
    gaps, axes, b_vertices, (rotation, translation) = _exact_parts(a, pose_a, b, pose_b)
    distance = jnp.max(gaps)
    axis = axes[jnp.argmax(gaps)]
    shift = jnp.maximum(-distance, 0.0) * axis
    point_a, point_b, weights_a, weights_b = _touching_witnesses(
        a, b, rotation, translation + shift, b_vertices + shift, axis, jnp.maximum(distance, 0))
    return distance, axis, point_a, point_b - shift, weights_a, weights_b


def _exact_signed_distance(a, pose_a, b, pose_b) -> jax.Array:
    """The exact value, with the derivative of the witness pair's gap along the axis.

    By the envelope theorem for sd = max over axes u of min over points p in a, q in b of
    u.(q - p), with the points written as weights on the vertices (sets that do not move with
    the poses or vertices), the derivative is that of u.(q - p) at the saddle point: axis and
    weights held fixed. Holding only the axis fixed is not enough: along a face normal the
    face's vertices tie, and the one a min picks does not move like the witness point."""
    frozen = jax.lax.stop_gradient((a, pose_a, b, pose_b))
    distance, axis, _, _, weights_a, weights_b = _witnesses(*frozen)
    rotation, translation = _relative_pose(pose_a, pose_b)
    b_vertices = _rotate(rotation, b.vertices) + translation
    gap = axis @ (weights_b @ b_vertices - weights_a @ a.vertices)
    return distance + (gap - jax.lax.stop_gradient(gap))


def _check_smoothing(smoothing):
    """A Python number must be finite and >= 0; a traced value is taken as given."""
    if isinstance(smoothing, jax.core.Tracer):
        return smoothing
    value = float(smoothing)
    if not value >= 0.0 or value == float("inf"):
        raise ValueError(f"smoothing must be a finite length >= 0, got {smoothing!r}")
    return value


def signed_distance(a: Polytope, pose_a: Pose, b: Polytope, pose_b: Pose, *,
                    smoothing: float | jax.Array = 0.0) -> jax.Array:
    """Signed distance between two convex shapes: > 0 apart, < 0 overlapping.

    Args:
      a, b: shapes of the same dimension D (unbatched; use jax.vmap for batches).
      pose_a, pose_b: their poses.
      smoothing: tau, a length >= 0. 0 gives the exact value: the Euclidean distance when the
        shapes are apart, minus the exact penetration depth when they overlap. tau > 0 gives
        a smooth approximation (continuous gradients in poses and vertices) that satisfies
        |smooth - exact| <= smoothing_error_bound(a, b) * tau; see `smoothing_error_bound`
        for how to pick tau. A traced tau always takes the smooth path, floored at a few ulps
        of the shapes' size (so a traced 0 gives the exact value up to rounding, not NaN).

    Returns:
      () float in the common dtype of the inputs. Gradients with respect to poses and to
      `Polytope.vertices` are finite everywhere. The exact gradient is the derivative of the
      witness pair's gap (envelope theorem): the true derivative wherever one exists, with
      respect to vertices that of the distance between the hulls of the moved vertices (as
      if the shape were rebuilt). The smooth value reads the stored face normals and edge
      directions as constants, so its vertex gradient holds them fixed.
    """
    _check_pair(a, pose_a, b, pose_b)
    smoothing = _check_smoothing(smoothing)
    a, pose_a, b, pose_b = _cast_pair(a, pose_a, b, pose_b)
    if isinstance(smoothing, float) and smoothing == 0.0:
        return _exact_signed_distance(a, pose_a, b, pose_b)
    from jaxsat._smoothing import _smooth_signed_distance

    return _smooth_signed_distance(a, pose_a, b, pose_b, jnp.asarray(smoothing, a.dtype))


def _outside(points, shape: Polytope):
    """How far (D,) local points lie outside `shape`'s face slabs (<= 0 inside), (...)."""
    projections = _project(points.reshape(-1, points.shape[-1]), shape.face_normals)
    low, high = shape.face_extents[:, 0], shape.face_extents[:, 1]
    violation = jnp.maximum(low - projections, projections - high)
    return _masked_extreme(violation, shape.face_mask, lowest=False).reshape(points.shape[:-1])


def closest_points(a: Polytope, pose_a: Pose, b: Polytope, pose_b: Pose) -> ClosestPoints:
    """Exact signed distance with its witness points and axis, for one pair of shapes.

    When the shapes are apart, point_a and point_b are a closest pair (one of them, if the
    closest features are parallel). When they overlap, point_b = point_a - depth * normal
    and moving b by depth * normal makes the two points meet: they are where the shapes
    touch after the minimum translation. Values only: the search is not differentiated
    (differentiate `signed_distance`, whose value equals the `signed_distance` field here).
    """
    _check_pair(a, pose_a, b, pose_b)
    a, pose_a, b, pose_b = jax.lax.stop_gradient(_cast_pair(a, pose_a, b, pose_b))
    distance, axis, point_a, point_b, _, _ = _witnesses(a, pose_a, b, pose_b)
    to_world = lambda x: _rotate(pose_a.rotation, x) + pose_a.translation  # noqa: E731
    return ClosestPoints(signed_distance=distance, point_a=to_world(point_a),
                         point_b=to_world(point_b), normal=_rotate(pose_a.rotation, axis))
