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


def _segments(shape: Polytope, vertices):
    """(start, end) of every edge, (K, D) each. A 2D polygon's edges join consecutive
    vertices; padding repeats vertex 0, so padded edges shrink to that (real) point."""
    if shape.dim == 2:
        return vertices, jnp.roll(vertices, -1, axis=0)
    endpoints = shape.edge_endpoints
    return vertices[endpoints[:, 0]], vertices[endpoints[:, 1]]


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


def _closest_segment_pair(a: Polytope, a_vertices, b: Polytope, b_vertices):
    """The closest pair of points over all (edge of a, edge of b) pairs, (D,) each, and
    whether it was found.

    Every coordinate stays a separate (K_a, K_b) array so XLA fuses the whole search. Ties are
    averaged instead of picked by argmin (slow on CPU): closest pairs of convex sets share one
    difference vector, so the average of tied pairs is a closest pair too."""
    start_a, end_a = _segments(a, a_vertices)
    start_b, end_b = _segments(b, b_vertices)
    column = lambda x: [x[:, k][:, None] for k in range(a.dim)]  # noqa: E731
    row = lambda x: [x[:, k][None, :] for k in range(a.dim)]  # noqa: E731
    origin_a, delta_a = column(start_a), column(end_a - start_a)
    origin_b, delta_b = row(start_b), row(end_b - start_b)
    s, t = _segment_parameters(origin_a, delta_a, origin_b, delta_b)
    points_a = [o + s * d for o, d in zip(origin_a, delta_a, strict=True)]
    points_b = [o + t * d for o, d in zip(origin_b, delta_b, strict=True)]
    squared = _dot(*([[q - p for p, q in zip(points_a, points_b, strict=True)]] * 2))
    # Near-ties count as ties: XLA may recompute the squares inside each fusion with other
    # roundings. A pair within 64 eps of the minimum has a difference vector within
    # sqrt(64 eps) of the closest one (|d|^2 is strongly convex), which moves the gap along its
    # axis only to second order; if no entry qualifies, the SAT axis stands in.
    eps = jnp.finfo(squared.dtype).eps
    smallest = jnp.min(squared)
    closest = squared <= smallest + 64 * eps * smallest
    count = jnp.sum(closest)
    safe_count = jnp.maximum(count, 1).astype(squared.dtype)
    mean = lambda x: jnp.sum(jnp.where(closest, x, 0.0)) / safe_count  # noqa: E731
    return (jnp.stack([mean(jnp.broadcast_to(x, squared.shape)) for x in points_a]),
            jnp.stack([mean(jnp.broadcast_to(x, squared.shape)) for x in points_b]), count > 0)


def _exact_parts(a: Polytope, pose_a: Pose, b: Polytope, pose_b: Pose):
    """Everything in a's frame: the two candidate axes' gaps (differentiable), the axes, the
    closest segment pair, and b's vertices."""
    rotation, translation = _relative_pose(pose_a, pose_b)
    b_vertices = _rotate(rotation, b.vertices) + translation
    frozen = jax.lax.stop_gradient((a, pose_a, b, pose_b))
    _, sat_axis = _best_axis(_candidate_groups(*frozen)[0])
    point_a, point_b, _ = _closest_segment_pair(a, frozen[0].vertices, b,
                                                jax.lax.stop_gradient(b_vertices))
    segment_axis, valid = _safe_normalize(point_b - point_a, 0.0)
    # Touching or crossing edges give no direction; the SAT axis stands in (any unit axis is
    # a lower bound, so the stand-in can never raise the result).
    segment_axis = jnp.where(valid, segment_axis, sat_axis)
    axes = jnp.stack([sat_axis, segment_axis])
    gaps = _gap(axes, a.vertices, a.vertex_mask, b_vertices, b.vertex_mask)
    return gaps, axes, (point_a, point_b), b_vertices


def _exact_signed_distance(a, pose_a, b, pose_b) -> jax.Array:
    gaps, _, _, _ = _exact_parts(a, pose_a, b, pose_b)
    return jnp.max(gaps)


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
        for how to pick tau. A traced tau always takes the smooth path.

    Returns:
      () float in the common dtype of the inputs. Gradients with respect to poses and to
      `Polytope.vertices` are finite everywhere; with respect to vertices the stored face
      normals and edge directions are held fixed (for the exact value that is the true
      derivative wherever it exists, by Danskin's theorem).
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


def _touching_witnesses(a: Polytope, b: Polytope, rotation, translation, b_vertices, axis,
                        distance):
    """A pair (p in a, q in b) with q - p = distance * axis, in a's frame, given the exact
    signed distance and its axis (distance >= 0 here: the shapes are apart or touching).

    The closest segment pair serves when its gap is the distance (vertex-edge, vertex-vertex
    and edge-edge features). Otherwise a vertex of one shape faces a face of the other: its
    support vertex along the axis, moved across by the distance, lands inside the other shape;
    whichever of the two constructions lands inside (least outside) is the pair."""
    point_a, point_b, found = _closest_segment_pair(a, a.vertices, b, b_vertices)
    segment_gap = jnp.sqrt(jnp.sum((point_b - point_a) ** 2))
    scale = jnp.max(jnp.abs(a.vertices)) + jnp.max(jnp.abs(b_vertices)) + distance
    tolerance = jnp.sqrt(jnp.finfo(distance.dtype).eps) * scale
    support_a = a.vertices[jnp.argmax(jnp.where(a.vertex_mask, a.vertices @ axis, -jnp.inf))]
    support_b = b_vertices[jnp.argmin(jnp.where(b.vertex_mask, b_vertices @ axis, jnp.inf))]
    onto_b, onto_a = support_a + distance * axis, support_b - distance * axis
    to_b_frame = lambda x: _rotate(rotation.T, x - translation)  # noqa: E731
    a_faces_b = _outside(to_b_frame(onto_b)[None], b) <= _outside(onto_a[None], a)
    face_a = jnp.where(a_faces_b, support_a, onto_a)
    face_b = jnp.where(a_faces_b, onto_b, support_b)
    use_segments = found & (segment_gap <= distance + tolerance)
    return jnp.where(use_segments, point_a, face_a), jnp.where(use_segments, point_b, face_b)


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
    gaps, axes, _, b_vertices = _exact_parts(a, pose_a, b, pose_b)
    distance = jnp.max(gaps)
    axis = axes[jnp.argmax(gaps)]
    # Overlapping: move b out along the axis until the shapes touch, find the touching
    # points there, and move b's point back. Apart: the shift is zero.
    shift = jnp.maximum(-distance, 0.0) * axis
    rotation, translation = _relative_pose(pose_a, pose_b)
    point_a, point_b = _touching_witnesses(a, b, rotation, translation + shift,
                                           b_vertices + shift, axis, jnp.maximum(distance, 0))
    to_world = lambda x: _rotate(pose_a.rotation, x) + pose_a.translation  # noqa: E731
    return ClosestPoints(signed_distance=distance, point_a=to_world(point_a),
                         point_b=to_world(point_b - shift),
                         normal=_rotate(pose_a.rotation, axis))
