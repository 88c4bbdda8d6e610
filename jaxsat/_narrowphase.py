"""Exact Separating Axis Theorem queries for one pair of convex shapes.

Conventions. For a unit axis u, moving b by s(u) * u makes the two shapes' projections on u
just touch, where s(u) = max_a(u . a) - min_b(u . b). The penetration depth is min_u s(u):
positive when the shapes overlap (then it is the exact minimum translation distance, because
the minimum over all directions is attained at a facet normal of the Minkowski difference,
and every such normal is among the candidate axes), and minus the largest gap otherwise.

Candidate axes: in 2D the edge normals of both shapes; in 3D the face normals of both shapes
and the cross products of edge directions. Everything is computed in a's local frame. Face
normals (and, for boxes, the edge cross products) are measured by projecting both shapes'
vertices; hull edge pairs go through the Gauss map, which tests only the pairs that can bound
the Minkowski difference (see `_projection_group` and `_edge_axes_by_gauss_map`, and
benchmarks/README.md, "Performance to the limit", for why they are written as they are).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxsat._kernels import cross, dot, extremes, project, rotate, safe_normalize
from jaxsat._pair import PairFrame, cast_pair, check_pair, compiled_query, pair_frame
from jaxsat._poses import Pose
from jaxsat._shapes import Polytope

__all__ = ["Penetration", "SatAxis", "intersects", "penetration", "sat_runner_up", "sat_search"]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Penetration:
    """Result of `penetration` for one pair (fields gain leading axes under `vmap`)."""

    depth: jax.Array
    """() float: minimum translation distance if > 0; minus the largest axis gap if <= 0."""
    normal: jax.Array
    """(D,) float: unit world-frame axis from a towards b; moving b by depth * normal separates."""


def _interval_depths(a_min, a_max, b_min, b_max):
    """The better sense of each axis: depth min(b pushed along +n, along -n), and its sign."""
    plus, minus = a_max - b_min, b_max - a_min
    return jnp.minimum(plus, minus), jnp.where(plus <= minus, 1.0, -1.0).astype(plus.dtype)


def _projection_group(a: Polytope, b: Polytope, b_vertices_in_a, rotation, with_edges: bool):
    """Candidates measured by projecting both shapes' vertices: the face normals of both and,
    with_edges, the cross product of every pair of unique edge directions (cheapest for boxes:
    3 x 3 axes). Returns depths (C,) and `axis_of` (index -> signed unit axis in a's frame).

    The axes are kept as D component arrays (C,), so that every step is elementwise on them
    and XLA fuses the group into a few passes (stacked (C, D) axes ran box pairs 2x slower).
    Faces come first, so the first of equally deep axes is a face normal."""
    normals_b = rotate(rotation, b.face_normals)
    axes = [jnp.concatenate([a.face_normals[:, k], normals_b[:, k]]) for k in range(a.dim)]
    squared = jnp.ones_like(axes[0])
    if with_edges:
        crosses = cross(a.edge_directions[:, None, :],
                         rotate(rotation, b.edge_directions)[None, :, :]).reshape(-1, 3)
        axes = [jnp.concatenate([axis, crosses[:, k]]) for k, axis in enumerate(axes)]
        crosses_squared = crosses[:, 0] ** 2 + crosses[:, 1] ** 2 + crosses[:, 2] ** 2
        squared = jnp.concatenate([squared, crosses_squared])
    eps = jnp.finfo(squared.dtype).eps
    valid = squared > eps * eps  # parallel edges give no axis
    # Double `where`: the invalid branch never reaches rsqrt(0), so no NaN in any gradient.
    inverse_norm = jax.lax.rsqrt(jnp.where(valid, squared, 1.0))
    depths, signs = _interval_depths(*extremes(axes, a.vertices),
                                     *extremes(axes, b_vertices_in_a))
    depths = jnp.where(valid, depths * inverse_norm, jnp.inf)

    def axis_of(index):
        return signs[index] * inverse_norm[index] * jnp.stack([axis[index] for axis in axes])

    def cosine_to(unit):
        """(C,) cosines between each candidate's signed unit axis and `unit`."""
        return sum(axis * unit[k] for k, axis in enumerate(axes)) * inverse_norm * signs

    return depths, axis_of, cosine_to


def _hull_edge_frames(shape: Polytope, rotation=None, translation=None):
    """Per hull edge: a point on it, unit direction (b x a), adjacent face normals a and b."""
    points = shape.vertices[shape.edge_endpoints[:, 0]]
    normals = shape.edge_face_normals
    if rotation is not None:
        points = rotate(rotation, points) + translation
        normals = rotate(rotation, normals)
    first, second = normals[:, 0], normals[:, 1]
    directions, _ = safe_normalize(cross(second, first), 0.0)
    return points, directions, first, second


def _edge_axes_by_gauss_map(a: Polytope, b: Polytope, rotation, translation):
    """Edge-edge candidates only for hull-edge pairs that form a Minkowski face.

    Two edges can give the penetration axis only if their arcs on the Gauss map cross (the
    arc of a's edge and the arc of b's edge with b's normals negated); for those pairs the
    supporting points are the edges themselves, so the depth needs no scan over vertices:
    with n = e_a x e_b and Plucker moments m = e x p it is n . (p_a - p_b) / |n| =
    -(e_b . m_a + e_a . m_b) / |n|, signed so the axis points out of a. Other pairs are
    skipped: their axes never give the minimum. (The moment form cancels digits in float32;
    `penetration` measures the winner again by projection, so that only affects near-ties.)
    Returns (depths (K_a, K_b), what `_gauss_map_axis` needs to build a winner's axis)."""
    points_a, dir_a, na1, na2 = _hull_edge_frames(a)
    points_b, dir_b, nb1, nb2 = _hull_edge_frames(b, rotation, translation)
    cba, dba = -project(dir_a, nb1), -project(dir_a, nb2)
    adc, bdc = project(na1, dir_b), project(na2, dir_b)
    minkowski_face = (cba * dba < 0) & (adc * bdc < 0) & (cba * bdc > 0)
    # |e_a x e_b| from the cross product itself: 1 - cos^2 rounds (near-)parallel edges to
    # noise, and noise must not pass for a Minkowski face. Components stay separate arrays so
    # that XLA fuses them instead of materialising a (K_a, K_b, 3) stack.
    ax, ay, az = (dir_a.T[k][:, None] for k in range(3))
    bx, by, bz = (dir_b.T[k][None, :] for k in range(3))
    sine_squared = (ay * bz - az * by) ** 2 + (az * bx - ax * bz) ** 2 + (ax * by - ay * bx) ** 2
    min_sine = 1000 * jnp.finfo(sine_squared.dtype).eps
    valid = minkowski_face & (sine_squared > min_sine * min_sine)
    # The Gauss-map arcs fix the orientation: the axis e_a x e_b points out of a iff BDC > 0.
    orientation = jnp.where(bdc > 0, 1.0, -1.0).astype(sine_squared.dtype)
    inverse_sine = jax.lax.rsqrt(jnp.where(valid, sine_squared, 1.0))
    moment_a, moment_b = cross(dir_a, points_a), cross(dir_b, points_b)
    numerator = -project(moment_a, dir_b) - project(dir_a, moment_b)
    depths = jnp.where(valid, numerator * orientation * inverse_sine, jnp.inf)
    return depths, (dir_a, dir_b, na2)


def _gauss_map_axis(index, dir_a, dir_b, normals_a):
    """The unit axis of flattened edge pair `index`, built only for the winner (its sign is
    the orientation rule of `_edge_axes_by_gauss_map`, BDC > 0)."""
    row, col = jnp.divmod(index, dir_b.shape[0])
    crossed = cross(dir_a[row], dir_b[col])
    sign = jnp.where(jnp.dot(normals_a[row], dir_b[col]) > 0, 1.0, -1.0)
    return sign * safe_normalize(crossed, 0.0)[0]


def _use_gauss_map(a: Polytope, b: Polytope) -> bool:
    """Static choice of the edge-edge method from the padded sizes.

    Projection tries every pair of unique edge directions; that is cheapest for boxes, and a
    polyhedron with at most 3 edge directions is a parallelepiped, for which every such pair
    is a Minkowski face. Any other shape goes through the Gauss map. Both methods then try
    the same axes, so padding (which only repeats edges) never changes a result, separated
    gaps included."""
    max_directions = 3
    return max(a.edge_directions.shape[0], b.edge_directions.shape[0]) > max_directions


def _candidate_groups(frame: PairFrame, prune: bool = True):
    """The candidate axes of one query, in groups of (depths (C,), axis_of). `axis_of` maps
    an index of the group to its unit axis in a's frame, so that a costly group builds only
    its winner's axis; groups stay apart because concatenating them would make XLA
    materialise every depth. prune=False tests every edge-direction pair by projection,
    Gauss map or not."""
    a, b = frame.a, frame.b
    gauss_map = a.dim == 3 and prune and _use_gauss_map(a, b)
    with_edges = a.dim == 3 and not gauss_map
    groups = [_projection_group(a, b, frame.b_vertices, frame.rotation, with_edges)]
    if gauss_map:
        edge_depths, edge_data = _edge_axes_by_gauss_map(a, b, frame.rotation,
                                                         frame.translation)
        groups.append((edge_depths, lambda index: _gauss_map_axis(index, *edge_data), None))
    return groups


def _winner(depths: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(min, flat argmin) of one group's depths, in the forms XLA runs fastest on CPU.

    A flat group takes jnp.argmin and reads the minimum at that index (a separate min
    reduction measured slower). A 2-D group (the Gauss-map edge pairs, K_a x K_b) is reduced
    to its row minima, then the argmin of those and of the winning row: a flat argmin over
    the K_a K_b depths (XLA's variadic reduce) took 60% of a 20-vertex hull query."""
    if depths.ndim == 1:
        index = jnp.argmin(depths)
        return depths[index], index
    row_minima = jnp.min(depths, axis=1)
    row = jnp.argmin(row_minima)
    return row_minima[row], row * depths.shape[1] + jnp.argmin(depths[row])


def _smallest(candidates):
    """(depth, axis) of the smallest depth among (depth, axis) pairs, the first at ties."""
    best_depth, best_axis = candidates[0]
    for depth, axis in candidates[1:]:
        better = depth < best_depth
        best_depth = jnp.where(better, depth, best_depth)
        best_axis = jnp.where(better, axis, best_axis)
    return best_depth, best_axis


def _best_axis(groups):
    """The smallest depth over all groups and its unit axis (in a's frame)."""
    candidates = []
    for depths, axis_of, _ in groups:
        depth, index = _winner(depths)
        candidates.append((depth, axis_of(index)))
    return _smallest(candidates)


class SatAxis(NamedTuple):
    """The SAT's answer for one pair, in a's frame (see the module docstring)."""

    depth: jax.Array
    """() float: min over candidate axes of the depth; > 0 iff the shapes overlap."""
    axis: jax.Array
    """(D,) float: unit axis of that depth, from a towards b, in a's frame."""


def sat_search(frame: PairFrame, prune: bool = True) -> SatAxis:
    """The deepest-separating candidate axis of a prepared pair and its depth.

    With Gauss-map edge pairs, the winner's depth is measured again by projecting both
    shapes on its unit axis: exactly the depth its normal gives (the Gauss-map shortcut loses
    float32 digits). Projected axes need no such fix."""
    groups = _candidate_groups(frame, prune)
    depth, axis = _best_axis(groups)
    if len(groups) > 1:
        # Both senses, as the projected groups measure them: the Gauss-map sense comes from
        # the sign of a dot product that vanishes where edges meet at a vertex, and XLA may
        # round it differently in `_gauss_map_axis` than in the depth (it did for batches
        # over about 1,400 pairs), which turned the axis around and gave the depth
        # s(-u) = width + gap instead of s(u).
        along = _support(axis, frame.a.vertices) + _support(-axis, frame.b_vertices)
        against = _support(-axis, frame.a.vertices) + _support(axis, frame.b_vertices)
        turned = against < along
        depth = jnp.where(turned, against, along)
        axis = jnp.where(turned, -axis, axis)
    return SatAxis(depth, axis)


def sat_runner_up(frame: PairFrame, min_angle) -> jax.Array:
    """(D,) unit axis (a's frame) of the best candidate more than `min_angle` radians (may be
    traced) from the winner: where two penetration directions tie, the other one. Projected
    candidates near the winner are masked (padding repeats a face normal, and parallel faces
    of a and b give one direction); a Gauss-map group offers its best pair unless that is near
    the winner. With no such candidate, the winner's own axis."""
    groups = _candidate_groups(frame)
    _, winner = _best_axis(groups)
    min_cosine = jnp.cos(min_angle)
    candidates = []
    for depths, axis_of, cosine_to in groups:
        if cosine_to is not None:
            depths = jnp.where(cosine_to(winner) >= min_cosine, jnp.inf, depths)
        depth, index = _winner(depths)
        axis = axis_of(index)
        if cosine_to is None:
            depth = jnp.where(dot(axis, winner) >= min_cosine, jnp.inf, depth)
        candidates.append((depth, axis))
    best_depth, best_axis = _smallest(candidates)
    return jnp.where(jnp.isfinite(best_depth), best_axis, winner)


def _check_penetration(a, pose_a, b, pose_b, *, prune=True) -> None:
    check_pair(a, pose_a, b, pose_b)
    if not isinstance(prune, bool):
        raise ValueError(f"prune must be True or False, got {prune!r}")


@compiled_query(_check_penetration, static_argnames=("prune",))
def penetration(a: Polytope, pose_a: Pose, b: Polytope, pose_b: Pose, *,
                prune: bool = True) -> Penetration:
    """Exact SAT penetration depth and axis for one pair of convex shapes.

    Args:
      a, b: shapes of the same dimension D (unbatched; use jax.vmap for batches).
      pose_a, pose_b: their poses.
      prune: in 3D, skip the edge pairs whose arcs do not cross on the Gauss map (they do not
        bound the Minkowski difference, so they never give the answer). False tests every
        pair of edge directions, as a textbook SAT does: the same result for overlapping
        shapes, only slower (see benchmarks/skipping.py); for separated shapes the extra axes
        may find a larger gap, still within the bounds stated below. Static.

    Returns:
      Penetration(depth, normal) in the common dtype of the inputs. depth > 0: the shapes
      overlap and depth is the exact minimum translation distance; moving b by depth * normal
      leaves them touching. depth <= 0: separated, and -depth is the largest gap found on a
      candidate axis: at least the largest gap over the facet normals of the Minkowski
      difference and at most the distance between the shapes. normal is a world-frame unit
      vector pointing from a towards b.
    """
    frame = pair_frame(a, pose_a, b, pose_b)
    found = sat_search(frame, prune)
    return Penetration(depth=found.depth, normal=frame.direction_to_world(found.axis))


def _support(axis, points):
    """max over points of axis . point, read at its argmax so that the gradient reaches one
    point with weight 1. A chain of jnp.maximum spreads it over ties, and under jit XLA may
    recompute the tied values with different roundings in the backward pass, so that the
    weights no longer summed to 1 (a depth gradient of norm 1.4 for a box pair)."""
    projections = sum(axis[k] * points[:, k] for k in range(points.shape[-1]))
    return projections[jnp.argmax(projections)]


def _world_aabb(shape: Polytope, pose: Pose) -> tuple[jax.Array, jax.Array]:
    world = pose.apply(shape.vertices)
    return world.min(axis=0), world.max(axis=0)


def _min_depth(a, pose_a, b, pose_b) -> jax.Array:
    groups = _candidate_groups(pair_frame(a, pose_a, b, pose_b))
    return functools.reduce(jnp.minimum, [jnp.min(depths) for depths, _, _ in groups])


@compiled_query(check_pair)
def intersects(a: Polytope, pose_a: Pose, b: Polytope, pose_b: Pose) -> jax.Array:
    """True where the two shapes overlap or touch (penetration depth >= 0).

    A single call compares the world AABBs first and skips the SAT when they are disjoint.
    Under jax.vmap that skip would not pay (both branches of a batched cond run), so the
    batched query goes straight to the SAT minimum; the answer is the same either way.
    """
    a, pose_a, b, pose_b = cast_pair(a, pose_a, b, pose_b)
    # A boolean has no derivative; stopping gradients here keeps `custom_vmap` (which has no
    # reverse-mode rule) out of any gradient of a function that merely calls `intersects`.
    return _intersects_pair(*jax.lax.stop_gradient((a, pose_a, b, pose_b)))


def _sat_intersects(a, pose_a, b, pose_b) -> jax.Array:
    return _min_depth(a, pose_a, b, pose_b) >= 0


@jax.custom_batching.custom_vmap
def _intersects_pair(a, pose_a, b, pose_b) -> jax.Array:
    low_a, high_a = _world_aabb(a, pose_a)
    low_b, high_b = _world_aabb(b, pose_b)
    boxes_overlap = jnp.all((low_a <= high_b) & (low_b <= high_a))
    return jax.lax.cond(boxes_overlap, _sat_intersects, lambda *_: jnp.array(False),
                        a, pose_a, b, pose_b)


@_intersects_pair.def_vmap
def _intersects_batched(axis_size, in_batched, a, pose_a, b, pose_b):
    del axis_size  # the batch size comes with the batched arguments
    in_axes = jax.tree.map(lambda batched: 0 if batched else None, tuple(in_batched))
    return jax.vmap(_sat_intersects, in_axes=in_axes)(a, pose_a, b, pose_b), True
