"""GJK: the point of the Minkowski difference B - A closest to the origin, for one pair of
vertex sets, in a fixed-size form that `vmap` batches.

Gilbert, Johnson and Keerthi's algorithm keeps a simplex W of points of B - A, each the
difference b_j - a_i of two vertices (so W is kept as vertex pairs), and the point v of
conv(W) closest to the origin. Each step adds the support point w = b_j - a_i with b_j the
vertex of b lowest along v and a_i the vertex of a highest along it, and replaces W by the
face of conv(W + w) nearest to the origin; that face holds w whenever v . w < v . v. The
distance lies between the gap along v, v . w / |v|, and |v|: the loop stops when the two
are within `tolerance`, when v reaches the origin (the sets touch or overlap), or when a step
brings v closer by less than the tolerance. The result is v as barycentric weights on vertex
pairs, which are also weights on a's and b's vertices: the witness points p = sum w_k a_{i_k}
and q = sum w_k b_{j_k}, with q - p = v.

The nearest face is found without branches: every face holding w (in 3D: w itself, 3 edges,
3 triangles, the tetrahedron) gives the projection of the origin on its affine hull, and the
nearest one that projects inside its face wins, the smaller face first at ties. Degenerate
faces (coincident points, collinear triangles, flat tetrahedra) fail the inside test and
leave the answer to their sub-faces, so no division by a vanishing size happens (double
`where`, see `_kernels`).

Form, for XLA's CPU backend under `vmap` (see `_kernels` for the rules):

* every per-pair quantity is a scalar (vectors are tuples of D scalars), so each is one (N,)
  array vectorised along the batch; (4, 3) arrays per pair put the tiny axes innermost and
  ran 8-30x slower;
* a value that feeds several stored outputs is recomputed inside each of them, so each step
  ends in single stored integers: the support step in one int (the new vertex pair and
  whether to stop), the face search in one int (the face and whether it made progress); the
  loop state (D vertex pairs, D weights) is then cheap to write. Carrying the face search's
  weights directly repeated the search once per output and ran 4x slower.

The loop is a `lax.while_loop`: under `vmap` it runs until every pair of the batch has
stopped, with finished pairs frozen.
"""

from __future__ import annotations

import itertools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxsat import _kernels as k
from jaxsat._kernels import Vec

__all__ = ["Simplex", "closest_point_gjk"]


class Simplex(NamedTuple):
    """The final GJK simplex: S = D + 1 slots of vertex pairs and the barycentric weights of
    the closest point (unused slots: pair 0 and weight 0). All D + 1 slots are used only when
    the origin is inside (the sets overlap; they touch after the minimum translation)."""

    index_a: jax.Array
    """(S,) int32: the vertex a_i of each point b_j - a_i."""
    index_b: jax.Array
    """(S,) int32: the vertex b_j of each point."""
    weights: jax.Array
    """(S,) float: barycentric weights of the closest point (they sum to 1)."""
    iterations: jax.Array
    """() int32: support steps taken."""
    closest: jax.Array | None = None
    """(D,) float: v = q - p, the closest point of B - A, from the stored simplex points (no
    gather of the vertices); None where the search does not keep them."""


class _State(NamedTuple):
    pairs: tuple[jax.Array, ...]
    """D + 1 int32 scalars: i * V_b + j for each point b_j - a_i, -1 for an empty slot (the
    used slots come first; the last is used only by a final simplex holding the origin)."""
    points: tuple[Vec, ...]
    """D + 1 points b_j - a_i (an empty slot repeats slot 0). Stored, not gathered again from the
    vertices, which would read every vertex coordinate once more per point. Their weights
    are the barycentric coordinates of the origin's projection on their affine hull,
    recomputed where needed: a small solve, cheaper than D more stored outputs."""
    iterations: jax.Array
    stopped: jax.Array


def _barycentric(corners: list[Vec]):
    """(weights, inside) of the projection of the origin onto the affine hull of 1 to 4
    `corners` (in 2D at most 3): the weights sum to 1; `inside` when none is negative and the
    corners are not degenerate (coincident, collinear, coplanar) within rounding."""
    dtype = corners[0][0].dtype
    eps = jnp.finfo(dtype).eps
    one = jnp.ones((), dtype)
    if len(corners) == 1:
        return (one,), jnp.ones((), bool)
    edges = [k.vsub(c, corners[0]) for c in corners[1:]]
    offset = k.vscale(-1.0, corners[0])
    lengths = [k.vdot(e, e) for e in edges]
    if len(corners) == 2:
        ok = lengths[0] > 0
        mus = [k.safe_divide(k.vdot(offset, edges[0]), lengths[0], ok)]
    elif len(corners) == 3 and len(offset) == 2:
        area = k.vcross2(edges[0], edges[1])
        ok = area * area > (16 * eps) ** 2 * lengths[0] * lengths[1]
        mus = [k.safe_divide(k.vcross2(offset, edges[1]), area, ok),
               k.safe_divide(k.vcross2(edges[0], offset), area, ok)]
    elif len(corners) == 3:
        normal = k.vcross(edges[0], edges[1])
        area_squared = k.vdot(normal, normal)
        ok = area_squared > (16 * eps) ** 2 * lengths[0] * lengths[1]
        mus = [k.safe_divide(k.vdot(k.vcross(offset, edges[1]), normal), area_squared, ok),
               k.safe_divide(k.vdot(k.vcross(edges[0], offset), normal), area_squared, ok)]
    else:
        volume = k.vdot(edges[0], k.vcross(edges[1], edges[2]))
        ok = volume * volume > (16 * eps) ** 2 * lengths[0] * lengths[1] * lengths[2]
        mus = [k.safe_divide(k.vdot(offset, k.vcross(edges[1], edges[2])), volume, ok),
               k.safe_divide(k.vdot(edges[0], k.vcross(offset, edges[2])), volume, ok),
               k.safe_divide(k.vdot(edges[0], k.vcross(edges[1], offset)), volume, ok)]
    weights = (k.sub(one, k.total(mus)), *mus)
    inside = ok
    for weight in weights:
        inside = inside & (weight >= 0)
    return weights, inside


def _faces_with_new_point(dim: int) -> list[tuple[int, ...]]:
    """Faces of the simplex {new point (-1), slots 0 .. D - 1} that hold the new point, as
    tuples of slots (-1 first), smaller faces first."""
    return [(-1, *others) for count in range(dim + 1)
            for others in itertools.combinations(range(dim), count)]


def closest_point_gjk(a_vertices, b_vertices, direction, tolerance, max_iterations: int):
    """The point of conv(b_vertices) - conv(a_vertices) closest to the origin.

    Args:
      a_vertices, b_vertices: (V_a, D), (V_b, D) float, one frame. Padding rows that repeat
        row 0 need no mask (they never win a support search over row 0).
      direction: (D,) float, a first guess of the direction from a towards b (the closer,
        the fewer steps); need not be unit.
      tolerance: () float, a length: stop when the distance is known to within it.
      max_iterations: static cap on the support steps.

    Returns:
      The final Simplex: the closest point is v = sum weights (b[index_b] - a[index_a]).
    """
    dim = a_vertices.shape[-1]
    count_b = b_vertices.shape[0]
    dtype = a_vertices.dtype
    # The loop reads the vertices as columns, split into points where it reads them
    # (`_kernels` rule 8).
    a_columns, b_columns = k.columns(a_vertices), k.columns(b_vertices)
    faces = _faces_with_new_point(dim)

    def point_of(pair) -> Vec:
        """b_j - a_i for pair = i * V_b + j (-1, an empty slot, reads pair 0)."""
        a_points, b_points = k.vecs_of_columns(a_columns), k.vecs_of_columns(b_columns)
        pair = jnp.maximum(pair, 0)
        return k.vsub(k.take_vec(b_points, pair % count_b), k.take_vec(a_points, pair // count_b))

    def support_pair(v: Vec):
        """i * V_b + j of the support point of B - A along -v."""
        a_points, b_points = k.vecs_of_columns(a_columns), k.vecs_of_columns(b_columns)
        return (k.support_index(v, a_points) * count_b
                + k.support_index(k.vscale(-1.0, v), b_points))

    def closest(points: list[Vec], weights) -> Vec:
        return k.vsum([k.vscale(w, p) for w, p in zip(weights, points, strict=True)])

    def simplex_weights(points: list[Vec], pairs):
        """Weights of the stored simplex (its used slots come first)."""
        count = k.total((pair >= 0).astype(jnp.int32) for pair in pairs)
        weights = [jnp.zeros((), dtype)] * (dim + 1)
        for size in range(1, dim + 2):
            face_weights, _ = _barycentric(points[:size])
            weights = [k.where(count == size, face_weights[s], w) if s < size else
                       k.where(count == size, 0.0, w) for s, w in enumerate(weights)]
        return weights

    def step(state: _State) -> _State:
        points = list(state.points)
        v = closest(points, simplex_weights(points, state.pairs))
        squared = k.vdot(v, v)
        # One stored int: the new support pair, negative (-1 - pair) when the distance is
        # already known: |v| - v.w / |v| bounds its error, and |v|^2 - v.w is that times |v|.
        new_pair = support_pair(v)
        w = k.materialize(point_of(new_pair))
        known = (squared - k.vdot(v, w) <= tolerance * jnp.sqrt(squared)) | (
            squared <= tolerance * tolerance)
        new_pair = k.materialize(k.where(known, -1 - new_pair, new_pair))
        known, new_pair = new_pair < 0, k.where(new_pair < 0, -1 - new_pair, new_pair)
        # One stored int: the nearest face holding w (its index in `faces`), -1 when it
        # brings v closer by less than the tolerance (rounding: stop, or it may cycle).
        used = [pair >= 0 for pair in state.pairs[:dim]]
        best_squared, best_face = None, None
        for index, face in enumerate(faces):
            corners = [w if s < 0 else points[s] for s in face]
            weights, valid = _barycentric(corners)
            for s in face[1:]:
                valid = valid & used[s]
            face_squared = (jnp.zeros((), dtype) if len(face) == dim + 1
                            else k.vdot(*(closest(corners, weights),) * 2))
            face_squared = k.where(valid, face_squared, jnp.inf)
            if best_squared is None:
                best_squared, best_face = face_squared, jnp.zeros((), jnp.int32)
            else:
                better = face_squared < best_squared
                best_squared = k.where(better, face_squared, best_squared)
                best_face = k.where(better, index, best_face)
        # Encoded with the face: whether to take it (else keep the old simplex), and whether
        # it shortens v by more than the tolerance (else stop after it: rounding, which could
        # cycle). A face no longer than v within the tolerance is taken: w's gap says v is not
        # optimal (not `known`), so a face holding w gives a better direction even when |v|
        # shrinks only to second order, as when a vertex gives way to a nearby edge point.
        slack = 2 * tolerance * jnp.sqrt(squared)
        closer = best_squared < squared + slack
        progress = squared - best_squared > slack
        coded = k.materialize(k.where(closer, best_face, -1) * 2 + progress.astype(jnp.int32))
        best_face, progress = coded // 2, coded % 2 == 1
        keep = known | (best_face < 0)
        # The full simplex holds the origin (the sets overlap or touch): stop after it too.
        stop = keep | ~progress | (best_face == len(faces) - 1)
        # The new simplex: the chosen face's vertex pairs and points, the new point first.
        pairs, new_points = [], []
        for slot in range(dim + 1):
            pair, point = jnp.full((), -1, jnp.int32), points[0]
            for index, face in enumerate(faces):
                if slot < len(face):
                    chosen = best_face == index
                    if face[slot] < 0:
                        pair, point = k.where(chosen, new_pair, pair), k.vselect(chosen, w,
                                                                                    point)
                    else:
                        pair = k.where(chosen, state.pairs[face[slot]], pair)
                        point = k.vselect(chosen, points[face[slot]], point)
            pairs.append(k.where(keep, state.pairs[slot], pair))
            new_points.append(k.vselect(keep, points[slot], point))
        return _State(tuple(pairs), tuple(new_points), state.iterations + 1, stop)

    def going(state: _State):
        return ~state.stopped & (state.iterations < max_iterations)

    first = support_pair(k.as_vec(direction))
    first_point = point_of(first)
    # Written from `first` (0 * first is 0) so that under `vmap` every part of the state is
    # batched from the start: the loop's batching rule then traces the body once less.
    zero = 0 * first
    state = _State((first,) + (zero - 1,) * dim, (first_point,) * (dim + 1), zero, zero > 0)
    state = jax.lax.while_loop(going, step, state)
    weights = simplex_weights(list(state.points), state.pairs)
    pairs = jnp.stack([jnp.maximum(pair, 0) for pair in state.pairs])
    return Simplex(pairs // count_b, pairs % count_b, jnp.stack(weights), state.iterations,
                   jnp.stack(closest(list(state.points), weights)))
