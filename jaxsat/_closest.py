"""The exact signed distance of a prepared pair: its value, axis and witness weights.

The signed distance of convex shapes A and B is sd = max over unit axes u of gap(u), where
gap(u) = min_b u.b - max_a u.a (u points from a towards b). It is the Euclidean distance when
the shapes are apart and minus the penetration depth when they overlap; every gap(u) is a
lower bound of it. Two searches find a maximiser:

* the SAT (`_narrowphase.sat_search`) gives the penetration depth and axis, a maximiser
  whenever the shapes overlap or touch, and when the closest features are a vertex and a face
  or two crossing edges;
* GJK (`_gjk`) finds the closest points of the shapes with b moved out along the SAT axis by
  the penetration depth (by nothing when they are apart): the closest points when apart, the
  touching points after the minimum translation when they overlap. Their direction is the
  maximiser when apart.

So sd = max(gap(SAT axis), gap(GJK axis)), with no case split and no tolerance: an axis that
is not the maximiser only gives a smaller lower bound. GJK reports its points as weights on
a's and b's vertices, which the gradient needs.

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

from jaxsat._gjk import closest_point_gjk
from jaxsat._kernels import as_vecs, dot, safe_normalize, take_vec, vscale, vsum
from jaxsat._narrowphase import sat_search
from jaxsat._pair import PairFrame

__all__ = ["ExactDistance", "exact_distance", "signed_distance_of_witnesses", "support_gap",
           "witness"]

GJK_TOLERANCE = 4
"""GJK stops once the distance is known to within this many ulps of the pair's extent."""

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
    rows picked by select chains (`_kernels.take_vec`), not a gather and a matrix product."""
    points = as_vecs(vertices)
    return jnp.stack(vsum([vscale(weights[s], take_vec(points, indices[s]))
                           for s in range(weights.shape[0])]))


def support_gap(axis, a_vertices, b_vertices):
    """gap(axis) = min over b of axis . b - max over a of axis . a (padding rows repeat a
    real row, so they change neither extreme)."""
    return jnp.min(dot(b_vertices, axis)) - jnp.max(dot(a_vertices, axis))


def exact_distance(frame: PairFrame) -> ExactDistance:
    """The exact signed distance of a prepared pair, its axis and witness weights (see the
    module docstring). Call it on a stop_gradient'ed frame: it is a search, not a formula."""
    a_vertices, b_vertices = frame.a.vertices, frame.b_vertices
    sat = sat_search(frame)
    shift = jnp.maximum(sat.depth, 0.0) * sat.axis
    moved_b = b_vertices + shift
    eps = jnp.finfo(frame.dtype).eps
    extent = jnp.max(jnp.abs(a_vertices)) + jnp.max(jnp.abs(moved_b))
    simplex = closest_point_gjk(a_vertices, moved_b, sat.axis, GJK_TOLERANCE * eps * extent,
                                GJK_MAX_ITERATIONS)
    witness_a = witness(simplex.weights, a_vertices, simplex.index_a)
    witness_b = witness(simplex.weights, moved_b, simplex.index_b)
    gjk_axis, found = safe_normalize(witness_b - witness_a, 0.0)
    gjk_axis = jnp.where(found, gjk_axis, sat.axis)
    sat_gap, gjk_gap = -sat.depth, support_gap(gjk_axis, a_vertices, b_vertices)
    use_gjk = gjk_gap > sat_gap
    return ExactDistance(distance=jnp.where(use_gjk, gjk_gap, sat_gap),
                         axis=jnp.where(use_gjk, gjk_axis, sat.axis),
                         index_a=simplex.index_a, index_b=simplex.index_b,
                         weights=simplex.weights)


def signed_distance_of_witnesses(frame: PairFrame, found: ExactDistance):
    """found.distance, differentiable in the frame: the value of axis . (q - p) with the axis
    and the witness weights held fixed (the envelope theorem), straight through."""
    witness_a = witness(found.weights, frame.a.vertices, found.index_a)
    witness_b = witness(found.weights, frame.b_vertices, found.index_b)
    gap = dot(found.axis, witness_b - witness_a)
    return found.distance + (gap - jax.lax.stop_gradient(gap))
