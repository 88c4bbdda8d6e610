"""The exact signed distance of a prepared pair: its value, axis and witness weights.

The signed distance of convex shapes A and B is sd = max over unit axes u of gap(u), where
gap(u) = min_b u.b - max_a u.a (u points from a towards b). It is the Euclidean distance when
the shapes are apart and minus the penetration depth when they overlap; every gap(u) is a
lower bound of it. Two searches find a maximiser:

* the SAT (`_sat.sat_search`) gives the penetration depth and axis, a maximiser
  whenever the shapes overlap or touch, and when the closest features are a vertex and a face
  or two crossing edges;
* a closest-pair search on the shapes with b moved out along the SAT axis by the penetration
  depth (by nothing when they are apart) gives the closest points when apart and the touching
  points after the minimum translation when they overlap. Their direction is the maximiser
  when apart. In 3D the search is GJK (`_gjk`). In 2D it is closed form
  (`closest_pair_of_support_faces`): the closest points lie on the two shapes' support
  faces along the SAT axis.

So sd = max(gap(SAT axis), gap(witness axis)), with no case split and no tolerance: an axis
that is not the maximiser only gives a smaller lower bound. Apart, the value is then read as
|q - p| for the witness points p, q (see `exact_distance`), which the axis' rounding error
does not reach. Both searches report their points
as weights on a's and b's vertices, which the gradient needs.

Gradients follow the envelope theorem for sd = max over u of min over p in A, q in B of
u.(q - p): with the points written as fixed weights on the vertices, the derivative is that of
u.(q - p) at the saddle point, axis and weights held fixed (the search runs under
stop_gradient). That is the exact derivative wherever the maximiser is unique, never divides
by a vanishing norm, and has norm 1 in b's translation. Holding only the axis fixed would not
do: along a face normal the face's vertices tie, and the one a min picks does not move like
the witness point.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxsat import _kernels as k
from jaxsat._gjk import Simplex, closest_point_gjk
from jaxsat._pair import PairFrame
from jaxsat._sat import sat_search
from jaxsat._shapes import ring_neighbours

__all__ = ["ExactDistance", "closest_pair_of_segments", "closest_pair_of_support_faces",
           "exact_distance", "signed_distance_of_witnesses", "support_gap", "witness"]

GJK_TOLERANCE = 4
"""GJK stops once the distance is known to within this many ulps of the pair's extent, and
gaps that close are ties."""

GJK_MAX_ITERATIONS = 32
"""A cap well above the most steps seen (10, on 20-vertex hulls): under `vmap` every pair
runs as many steps as the slowest pair of the batch, so the cap only guards degenerate input."""



class ExactDistance(NamedTuple):
    """The exact search's answer for one pair, in a's frame (values only)."""

    distance: jax.Array
    """() float: the signed distance."""
    axis: jax.Array
    """(D,) float: its unit axis, from a towards b."""
    index_a: jax.Array
    """(D + 1,) int32: vertices of a holding the witness point p."""
    index_b: jax.Array
    """(D + 1,) int32: vertices of b holding the witness point q."""
    weights: jax.Array
    """(D + 1,) float: p = sum weights * a[index_a] and q = sum weights * b[index_b], with
    q - p = distance * axis (up to GJK's tolerance)."""


def witness(weights, vertices, indices):
    """(D,) sum over slots of weights[s] * vertices[indices[s]], in component form with the
    rows picked by select chains (`_kernels.take_vec`), not a gather and a matrix product;
    over more than `_kernels.SELECT_CHAIN_POINTS` vertices by a gather: a chain over 20
    vertices per slot and side made a hull distance's program compile 0.2 s longer (2.81 ->
    2.63 s, 2-core AMD EPYC; run time within 1.5%), and the witness is read once a pair."""
    slots = range(weights.shape[0])
    if vertices.shape[0] > k.SELECT_CHAIN_POINTS:
        gathered = vertices[indices]
        rows = [k.as_vec(gathered[s]) for s in slots]
    else:
        points = k.as_vecs(vertices)
        rows = [k.take_vec(points, indices[s]) for s in slots]
    return jnp.stack(k.vsum([k.vscale(weights[s], rows[s]) for s in slots]))


def support_gap(axis, a_vertices, b_vertices):
    """gap(axis) = min over b of axis . b - max over a of axis . a (padding rows repeat a
    real row, so they change neither extreme), by select chains over the vertices (`_kernels`
    rule 2: a `jnp.min` over them doubled the cost of an exact 2D distance)."""
    axes = [axis[i] for i in range(axis.shape[-1])]
    return k.extremes(axes, b_vertices)[0] - k.extremes(axes, a_vertices)[1]


@jax.jit
def exact_distance(frame: PairFrame) -> ExactDistance:
    """The exact signed distance of a prepared pair, its axis and witness weights (see the
    module docstring). Call it on a stop_gradient'ed frame: it is a search, not a formula.
    Point and segment cores in 3D (spheres and capsules) take `closest_pair_of_segments`.

    Jitted so that its trace is kept: a query that needs the search several times (a value,
    its gradient and forward derivatives; the smooth distance's start) traces it once, and
    `vmap` batches the traced program instead of running the Python code again (lowering a
    box pair's value, gradient and Jacobian 5.2-5.5 -> 3.3-4.1 s). XLA inlines the call."""
    a_vertices, b_vertices = frame.a.vertices, frame.b_vertices
    if frame.dim == 3 and a_vertices.shape[0] <= 2 and b_vertices.shape[0] <= 2:
        return closest_pair_of_segments(a_vertices, b_vertices)
    sat = sat_search(frame)
    shift = jnp.maximum(sat.depth, 0.0) * sat.axis
    moved_b = b_vertices + shift
    eps = jnp.finfo(frame.dtype).eps
    # Stored (`_kernels` rule 5): the search and every choice after it read it, and XLA
    # copied its select chains over the vertices into each reader (five copies in a batched
    # hull distance's program).
    rounding = k.materialize(GJK_TOLERANCE * eps * (k.largest_magnitude(a_vertices)
                                                    + k.largest_magnitude(moved_b)))
    if frame.dim == 2:
        simplex = closest_pair_of_support_faces(a_vertices, frame.a.num_real_vertices,
                                                moved_b, frame.b.num_real_vertices, sat.axis)
        difference = (witness(simplex.weights, moved_b, simplex.index_b)
                      - witness(simplex.weights, a_vertices, simplex.index_a))
    else:
        simplex = closest_point_gjk(a_vertices, moved_b, sat.axis, rounding, GJK_MAX_ITERATIONS)
        difference = simplex.closest
    witness_axis, found = k.safe_normalize(difference, 0.0)
    witness_axis = k.where(found, witness_axis, sat.axis)
    sat_gap, witness_gap = -sat.depth, support_gap(witness_axis, a_vertices, b_vertices)
    # Apart, at a near-tie (a closest-feature switch) the gap is flat in the axis, so a gap
    # within rounding of the best can come from an axis sqrt(rounding) off: prefer the
    # witness axis there, whose direction is accurate to rounding (the gradient uses it).
    use_witness = witness_gap > sat_gap - k.where(sat.depth < 0, rounding, 0.0)
    # Apart, once the search has converged, |q - p| is the distance up to the rounding of
    # the points (from above: p and q are points of the shapes), while the gap along the
    # witness axis loses the axis' error times the shapes' extent: in float32 that error is
    # about eps x size / distance in angle, so 3e-4 of the size lost on a vertex pair 3e-3
    # apart. Overlapping, the SAT gap is exact.
    length = k.dot(witness_axis, difference)  # 0 where the points coincide
    converged = simplex.iterations < GJK_MAX_ITERATIONS
    by_length = use_witness & (sat.depth < 0) & converged
    distance = k.where(by_length, jnp.maximum(witness_gap, length),
                         k.where(use_witness, witness_gap, sat_gap))
    # One truth at contact: the sign follows the SAT (overlap iff its depth >= 0, as
    # `intersects`, `penetration` and `contacts` decide). This moves the value by rounding
    # only: apart, the SAT gap is a lower bound on the distance; overlapping, it is -depth.
    distance = k.where(sat.depth >= 0, jnp.minimum(distance, 0.0),
                       jnp.maximum(distance, sat_gap))
    return ExactDistance(distance=distance,
                         axis=k.where(use_witness, witness_axis, sat.axis),
                         index_a=simplex.index_a, index_b=simplex.index_b,
                         weights=simplex.weights)


def closest_pair_of_segments(a_vertices, b_vertices) -> ExactDistance:
    """The distance of two 3D segments (or points: one vertex, or two equal ones), their
    closest pair and its axis, in closed form (no SAT, no GJK).

    In 3D two segments never overlap with a positive depth (a translation along their common
    perpendicular, however small, separates them), so the signed distance of the cores is
    their Euclidean distance. The closest pair minimises |a(s) - b(t)|^2 over the unit
    square (`_kernels.segment_closest_parameters`). Where the segments touch (|q - p| = 0)
    the axis is their common perpendicular, or any direction across a's segment if they are
    parallel, or x for two points.

    The witness is written as D + 1 shared weights on vertex pairs, as GJK's simplex: with
    s >= t the pairs (a0, b0), (a1, b0), (a1, b1) with weights 1 - s, s - t, t (else
    (a0, b0), (a0, b1), (a1, b1) with 1 - t, t - s, s), all >= 0, so that p = (1 - s) a0 +
    s a1 and q = (1 - t) b0 + t b1."""
    dtype = a_vertices.dtype
    a0, a1 = k.as_vec(a_vertices[0]), k.as_vec(a_vertices[-1])
    b0, b1 = k.as_vec(b_vertices[0]), k.as_vec(b_vertices[-1])
    along_a, along_b, offset = k.vsub(a1, a0), k.vsub(b1, b0), k.vsub(a0, b0)
    aa, bb = k.vdot(along_a, along_a), k.vdot(along_b, along_b)
    s, t, crossing = k.segment_closest_parameters(offset, along_a, along_b)
    # Stored once, as one leaf (rule 5 of `_kernels`): every output reads s and t, and the
    # choice between the two starts must be the same in all of them.
    s, t = k.materialize(jnp.stack([s, t]))
    eps = jnp.finfo(dtype).eps
    has_a, has_b = aa > 0, bb > 0
    p = k.vadd(a0, k.vscale(s, along_a))
    q = k.vadd(b0, k.vscale(t, along_b))
    gap = k.vsub(q, p)
    distance_squared = k.vdot(gap, gap)
    scale = jnp.maximum(jnp.maximum(aa, bb), k.vdot(offset, offset))
    # Written so that NaN counts as apart: non-finite input then gives a NaN distance and
    # axis, never the plausible 0 of touching cores.
    apart = ~(distance_squared <= (eps * eps) * scale)
    perpendicular = k.vcross(along_a, along_b)
    across_a = k.vcross(along_a, k.vselect(jnp.abs(along_a[0]) <= jnp.abs(along_a[1]),
                                           (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)))
    fallback = k.vselect(crossing & has_a & has_b, perpendicular,
                         k.vselect(has_a, across_a, (1.0, 0.0, 0.0)))
    # The common perpendicular's sense: from a towards b's middle.
    towards = k.vdot(fallback, k.vsub(k.vadd(b0, k.vscale(0.5, along_b)),
                                      k.vadd(a0, k.vscale(0.5, along_a))))
    fallback = k.vscale(k.where(towards < 0, -1.0, 1.0).astype(dtype), fallback)
    direction = k.vselect(apart, gap, fallback)
    distance = k.where(apart, jnp.sqrt(k.where(apart, distance_squared, 1.0)), 0.0)
    axis = k.where(jnp.isnan(distance), jnp.nan, k.safe_normalize(jnp.stack(direction), 0.0)[0])
    last_a, last_b = a_vertices.shape[0] - 1, b_vertices.shape[0] - 1
    a_first = s >= t
    index_a = jnp.stack([jnp.zeros((), jnp.int32), k.where(a_first, last_a, 0).astype(jnp.int32),
                         jnp.full((), last_a, jnp.int32), jnp.zeros((), jnp.int32)])
    index_b = jnp.stack([jnp.zeros((), jnp.int32), k.where(a_first, 0, last_b).astype(jnp.int32),
                         jnp.full((), last_b, jnp.int32), jnp.zeros((), jnp.int32)])
    weights = jnp.stack([1.0 - jnp.maximum(s, t), jnp.abs(s - t), jnp.minimum(s, t),
                         jnp.zeros((), dtype)])
    return ExactDistance(distance=distance, axis=axis, index_a=index_a, index_b=index_b,
                         weights=weights)


def signed_distance_of_witnesses(frame: PairFrame, found: ExactDistance):
    """found.distance, differentiable in the frame: the value of axis . (q - p) with the axis
    and the witness weights held fixed (the envelope theorem), straight through.

    q is formed in b's own frame and then moved into a's, so that the derivative flows back
    through one point rather than through all of b's moved vertices (the same value: the map
    is affine). `found` is stored once (`_kernels` rule 5): it feeds the value and every
    gradient. So are p and q in their shapes' frames: every gradient reads them, and without
    it XLA gave each comparison of a stored index with a vertex number a pass of its own (78
    in a 20-vertex hull pair's value and gradient, 30 for boxes). Stored, box pairs' exact
    value and gradient took 0.69x / 0.78x the time at 1e4 / 1e5 pairs and hulls' 0.92x, and
    the hull program compiled in 3.0 s instead of 3.9 s (2-core AMD EPYC)."""
    found = k.materialize(found)
    witness_a, local_b = k.materialize((witness(found.weights, frame.a.vertices, found.index_a),
                                        witness(found.weights, frame.b.vertices, found.index_b)))
    witness_b = k.rotate(frame.rotation, local_b) + frame.translation
    gap = k.dot(found.axis, witness_b - witness_a)
    return found.distance + (gap - jax.lax.stop_gradient(gap))


def closest_pair_of_support_faces(a_vertices, a_count, b_vertices, b_count, axis) -> Simplex:
    """The closest points of two convex polygons, given the SAT axis: exact when they are apart
    or touching, in a fixed handful of operations (no iteration).

    Why it suffices: with the origin outside M = B - A, gap(u) = min over m in M of u . m is
    positively homogeneous and concave, so on the circle its superlevel sets above 0 are arcs
    and it is unimodal there. Between two consecutive edge normals of M, gap is |m_k| cos(theta
    - phi_k) for one vertex m_k of M. The SAT axis is the edge normal with the largest gap, so
    the maximiser lies on that edge of M or at one of its two end vertices: the closest points
    are on a's support face along the axis (a vertex or an edge) and b's support face along
    minus the axis. Each face lies within one ring step of the first support vertex, so the
    search measures every vertex of those three-vertex windows against every edge of the
    other window (12 point-segment distances). Pairs outside the support faces are real
    point pairs too, so they are never closer than the true closest pair and cannot win.

    Args:
      a_vertices, b_vertices: (V_a, 2), (V_b, 2) polygon rings (either winding; padding rows
        repeat row 0), one frame.
      a_count, b_count: () int, the real vertex counts.
      axis: (2,) unit SAT axis from a towards b.

    Returns:
      A Simplex in GJK's form (slots: the point, then the segment's ends as weights 1 - t
      and t; the third slot is unused), iterations 0.
    """
    dtype = a_vertices.dtype
    direction = k.as_vec(axis)
    windows = []
    for points, count, sense in ((k.as_vecs(a_vertices), a_count, direction),
                                 (k.as_vecs(b_vertices), b_count, k.vscale(-1.0, direction))):
        centre = k.support_index(sense, points)
        previous, following = ring_neighbours(centre, count)
        indices = (previous, centre, following)
        windows.append((indices, [k.take_vec(points, index) for index in indices]))
    (indices_a, points_a), (indices_b, points_b) = windows
    candidates = []  # (side, edge start, point): side 0 puts a's points on b's edges
    best_squared = best_code = None
    for side, (points, ring) in enumerate(((points_a, points_b), (points_b, points_a))):
        for edge in range(2):
            start = ring[edge]
            along = k.vsub(ring[edge + 1], start)
            squared_length = k.vdot(along, along)
            inverse = k.safe_divide(1.0, squared_length, squared_length > 0)
            for point in range(3):
                offset = k.vsub(points[point], start)
                t = jnp.clip(k.vdot(offset, along) * inverse, 0.0, 1.0)
                miss = k.vsub(offset, k.vscale(t, along))
                squared = k.vdot(miss, miss)
                if best_squared is None:
                    best_squared, best_code = squared, jnp.zeros((), jnp.int32)
                else:
                    better = squared < best_squared
                    best_squared = k.where(better, squared, best_squared)
                    best_code = k.where(better, len(candidates), best_code)
                candidates.append((side, edge, point))
    # One stored decision, and everything read from it: a vertex-vertex closest pair is
    # found by several candidates at once (a point at an edge's end, t = 0 or 1), and a
    # second chain for t, fused apart, could round such a tie the other way and pair one
    # candidate's edge with another's t.
    best_code = k.materialize(best_code)

    def chosen(values):
        picked = values[0]
        for code in range(1, len(values)):
            picked = k.where(best_code == code, values[code], picked)
        return picked

    # t is measured again for the chosen candidate only, its point and edge picked by the
    # stored code: picking one of the twelve t's made XLA recompute all twelve in the pass
    # that stores the witness (without them the exact 2D distance takes 0.8x the time).
    windows_by_side = ((points_a, points_b), (points_b, points_a))
    lone = k.take_vec([windows_by_side[side][0][p] for side, edge, p in candidates], best_code)
    start = k.take_vec([windows_by_side[side][1][edge] for side, edge, p in candidates],
                       best_code)
    end = k.take_vec([windows_by_side[side][1][edge + 1] for side, edge, p in candidates],
                     best_code)
    along = k.vsub(end, start)
    squared_length = k.vdot(along, along)
    best_t = jnp.clip(k.vdot(k.vsub(lone, start), along)
                      * k.safe_divide(1.0, squared_length, squared_length > 0), 0.0, 1.0)

    slots_a, slots_b = [], []
    for side, edge, point in candidates:
        point_slots, edge_slots = (point, point, point), (edge, edge + 1, edge)
        slots_a.append(edge_slots if side else point_slots)
        slots_b.append(point_slots if side else edge_slots)
    index_a = jnp.stack([chosen([indices_a[slots[s]] for slots in slots_a]) for s in range(3)])
    index_b = jnp.stack([chosen([indices_b[slots[s]] for slots in slots_b]) for s in range(3)])
    weights = jnp.stack([1.0 - best_t, best_t, jnp.zeros((), dtype)])
    index_a, index_b, weights = k.materialize((index_a, index_b, weights))
    return Simplex(index_a, index_b, weights, jnp.zeros((), jnp.int32))
