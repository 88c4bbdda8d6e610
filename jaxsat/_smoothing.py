"""Smooth signed distance: the exact max-over-axes formula with log-sum-exp in place of max.

The exact signed distance is sd = max over unit axes u of gap(u), gap(u) = min_b u.b - max_a
u.a (see `_distance`). Here both levels are softened with temperature tau (a length):

* soft gap: min over b's vertices and max over a's vertices become log-sum-exp, so
  gap(u) - tau log(n_a n_b) <= soft_gap(u) <= gap(u) (n_a, n_b: real vertex counts);
* soft max over a fixed family of candidate axes, each of which depends smoothly on the poses
  and vertices and gives a lower bound: both senses of every face normal, (3D) both senses of
  every cross product of edge directions, the direction from every vertex of a to every vertex
  of b, and (3D) the perpendicular from every vertex to every edge line of the other shape.

The family contains a maximiser of gap in every configuration (face normals and edge-edge
axes when the shapes overlap; vertex-face, edge-edge, vertex-edge or vertex-vertex directions
when apart), so the soft max is within tau log(#axes) above and tau log(n_a n_b) below sd.
Directions that vanish (parallel edges, coincident vertices, a vertex on an edge line) are
faded out by a C1 gate on their length, which keeps the value and gradient continuous; where a
gate cuts in, the configuration is within a gate radius of touching through that feature, and
the face and edge axes are then within 2 gate radii of sd. The gate radii are tau / 4 (and an
angle of tau / (4 R) for edge pairs, R the shapes' radii), which costs at most 1.5 tau more.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from jaxsat._narrowphase import _project, _relative_pose, _rotate
from jaxsat._shapes import Polytope

__all__ = ["smoothing_error_bound"]


def _smoothstep(x):
    """C1 ramp from 0 (x <= 0) to 1 (x >= 1)."""
    x = jnp.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _soft_max(values, mask, tau):
    """tau log sum exp(values / tau) over the real entries of the last axis."""
    top = jax.lax.stop_gradient(jnp.max(jnp.where(mask, values, -jnp.inf), axis=-1,
                                        keepdims=True))
    # Mask before exp: padding entries never reach exp, so no inf * 0 in any gradient.
    terms = jnp.where(mask, jnp.exp((jnp.where(mask, values, top) - top) / tau), 0.0)
    return top[..., 0] + tau * jnp.log(jnp.sum(terms, axis=-1))


def _soft_gaps(axes, a_vertices, a_mask, b_vertices, b_mask, tau):
    """soft min_b u.b - soft max_a u.a for (C, D) axes, (C,)."""
    low_b = -_soft_max(-_project(axes, b_vertices), b_mask, tau)
    return low_b - _soft_max(_project(axes, a_vertices), a_mask, tau)


def _gated_soft_max(values, gates, tau):
    """tau log sum gate exp(value / tau) over candidates with gate > 0 (at least one is 1)."""
    alive = gates > 0
    log_gates = jnp.log(jnp.where(alive, gates, 1.0))
    shifted = jnp.where(alive, values / tau + log_gates, -jnp.inf)
    top = jax.lax.stop_gradient(jnp.max(shifted))
    terms = jnp.where(alive, jnp.exp(jnp.where(alive, shifted, top) - top), 0.0)
    return tau * (top + jnp.log(jnp.sum(terms)))


def _gated_directions(vectors, radius_squared):
    """Unit directions of (C, D) vectors and a C1 gate that is 0 for |v| <= ~0 and 1 for
    |v| >= radius; vectors too short to normalise safely get gate exactly 0."""
    squared = jnp.sum(vectors**2, axis=-1)
    eps = jnp.finfo(squared.dtype).eps
    ratio = squared / radius_squared
    valid = ratio > eps
    # Double where: the invalid branch never divides by a vanishing norm.
    units = vectors / jnp.sqrt(jnp.where(valid, squared, 1.0))[:, None]
    gates = jnp.where(valid, _smoothstep((ratio - eps) / (1.0 - eps)), 0.0)
    return units, gates


def _radius(vertices, mask):
    """sqrt(sum |v - centroid|^2) over real vertices: a smooth bound on the radius."""
    weights = mask.astype(vertices.dtype)
    centroid = jnp.sum(vertices * weights[:, None], axis=0) / jnp.sum(weights)
    squared = jnp.sum(weights * jnp.sum((vertices - centroid) ** 2, axis=-1))
    return jnp.sqrt(jnp.where(squared > 0, squared, 1.0))


def _edge_lines(shape: Polytope, vertices):
    """Point and unit direction of every hull edge (3D), (K, 3) each."""
    start = vertices[shape.edge_endpoints[:, 0]]
    delta = vertices[shape.edge_endpoints[:, 1]] - start
    length = jnp.sqrt(jnp.sum(delta**2, axis=-1, keepdims=True))
    return start, delta / jnp.where(length > 0, length, 1.0)


def _perpendiculars(points, line_starts, line_directions):
    """From every point to its foot on every line, (P L, D): (foot - point)."""
    offset = line_starts[None, :, :] - points[:, None, :]
    along = jnp.sum(offset * line_directions[None, :, :], axis=-1, keepdims=True)
    return (offset - along * line_directions[None, :, :]).reshape(-1, points.shape[-1])


def _candidates(a: Polytope, b: Polytope, b_vertices, rotation, tau, radius):
    """(axes (C, D), gates (C,)) of the candidate family, in a's frame."""
    dtype = b_vertices.dtype
    normals = jnp.concatenate([a.face_normals, _rotate(rotation, b.face_normals)])
    face_mask = jnp.concatenate([a.face_mask, b.face_mask]).astype(dtype)
    axes, gates = [normals, -normals], [face_mask, face_mask]
    eps = jnp.finfo(dtype).eps
    length_squared = (tau / 4) ** 2 + (64 * eps * radius) ** 2
    pair_mask = (a.vertex_mask[:, None] & b.vertex_mask[None, :]).reshape(-1)
    units, pair_gates = _gated_directions(
        (b_vertices[None, :, :] - a.vertices[:, None, :]).reshape(-1, a.dim), length_squared)
    axes.append(units)
    gates.append(pair_gates * pair_mask)
    if a.dim == 3:
        edge_axes, edge_gates = _edge_pair_candidates(a, b, rotation, tau, radius)
        axes += [edge_axes, -edge_axes]
        gates += [edge_gates, edge_gates]
        for perpendicular, gate in _vertex_edge_candidates(a, b, b_vertices, length_squared):
            axes.append(perpendicular)
            gates.append(gate)
    return jnp.concatenate(axes), jnp.concatenate(gates)


def _edge_pair_candidates(a: Polytope, b: Polytope, rotation, tau, radius):
    """Cross products of every pair of unique edge directions, gated by their sine."""
    b_edges = _rotate(rotation, b.edge_directions)
    crosses = jnp.cross(a.edge_directions[:, None, :], b_edges[None, :, :]).reshape(-1, 3)
    eps = jnp.finfo(crosses.dtype).eps
    # Rotating a shape by angle s moves every gap by at most s R: the gate angle tau / (4 R)
    # keeps the loss from fading near-parallel pairs below tau / 2.
    sine_squared = (tau / (4 * radius)) ** 2 + (64 * eps) ** 2
    units, gates = _gated_directions(crosses, sine_squared)
    mask = (a.edge_mask[:, None] & b.edge_mask[None, :]).reshape(-1)
    return units, gates * mask


def _vertex_edge_candidates(a: Polytope, b: Polytope, b_vertices, length_squared):
    """Perpendiculars from b's vertices to a's edge lines and from a's vertices to b's, each
    pointing from a towards b, with gates on their lengths."""
    a_starts, a_directions = _edge_lines(a, a.vertices)
    b_starts, b_directions = _edge_lines(b, b_vertices)
    from_b = -_perpendiculars(b_vertices, a_starts, a_directions)
    from_a = _perpendiculars(a.vertices, b_starts, b_directions)
    mask_b = (b.vertex_mask[:, None] & a.hull_edge_mask[None, :]).reshape(-1)
    mask_a = (a.vertex_mask[:, None] & b.hull_edge_mask[None, :]).reshape(-1)
    units_b, gates_b = _gated_directions(from_b, length_squared)
    units_a, gates_a = _gated_directions(from_a, length_squared)
    return (units_b, gates_b * mask_b), (units_a, gates_a * mask_a)


def _smooth_signed_distance(a, pose_a, b, pose_b, tau) -> jax.Array:
    """Smooth signed distance (see the module docstring); inputs already checked and cast."""
    rotation, translation = _relative_pose(pose_a, pose_b)
    b_vertices = _rotate(rotation, b.vertices) + translation
    # The construction is homogeneous of degree 1 in lengths, so it runs in units of the
    # shapes' size (a constant factor: values and gradients are unchanged, and gates and
    # normalisations work on numbers near 1 at any scale).
    scale = jax.lax.stop_gradient(_radius(a.vertices, a.vertex_mask)
                                  + _radius(b_vertices, b.vertex_mask))
    a_vertices, b_vertices, tau = a.vertices / scale, b_vertices / scale, tau / scale
    # A traced tau can be 0 (or negative): floor it at a few ulps of the size, which makes the
    # value the exact one up to rounding instead of 0/0 (double where: no NaN in gradients).
    floor = 16 * jnp.finfo(tau.dtype).eps
    tau = jnp.where(tau > floor, tau, floor)
    a = dataclasses.replace(a, vertices=a_vertices)
    radius = _radius(a_vertices, a.vertex_mask) + _radius(b_vertices, b.vertex_mask)
    axes, gates = _candidates(a, b, b_vertices, rotation, tau, radius)
    values = _soft_gaps(axes, a_vertices, a.vertex_mask, b_vertices, b.vertex_mask, tau)
    return scale * _gated_soft_max(values, gates, tau)


def _candidate_count(a: Polytope, b: Polytope) -> jax.Array:
    """Number of candidate axes that can be alive for this pair (from the masks)."""
    count = lambda mask: jnp.sum(mask, axis=-1)  # noqa: E731
    n_a, n_b = count(a.vertex_mask), count(b.vertex_mask)
    total = 2 * (count(a.face_mask) + count(b.face_mask)) + n_a * n_b
    if a.dim == 3:
        total += 2 * count(a.edge_mask) * count(b.edge_mask)
        total += n_b * count(a.hull_edge_mask) + n_a * count(b.hull_edge_mask)
    return total


def smoothing_error_bound(a: Polytope, b: Polytope) -> jax.Array:
    """The constant c with |signed_distance(..., smoothing=tau) - exact| <= c * tau.

    c = max(log M, log(n_a n_b) + 1.5), with n_a, n_b the real vertex counts and M the number
    of candidate axes (see the module docstring; it grows with the vertex and edge counts:
    about 6 for two 8-gons or two boxes, about 9 for two 20-vertex hulls). To keep the smooth
    value within a length `tolerance` of the exact one, pick tau = tolerance / c; tau of 1% to
    10% of the shapes' size gives gradients that see features a few tau away. Works on single
    shapes and on batches (broadcasting).
    """
    if not isinstance(a, Polytope) or not isinstance(b, Polytope):
        raise ValueError("a and b must be jaxsat.Polytope shapes")
    if a.dim != b.dim:
        raise ValueError(f"a and b must share one dimension, got {a.dim}D and {b.dim}D")
    vertex_pairs = (jnp.sum(a.vertex_mask, axis=-1) * jnp.sum(b.vertex_mask, axis=-1))
    below = jnp.log(vertex_pairs.astype(a.dtype)) + 1.5
    above = jnp.log(_candidate_count(a, b).astype(a.dtype))
    return jnp.maximum(above, below)
