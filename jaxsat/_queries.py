"""Public pair queries: `intersects`, `penetration`, `signed_distance` (exact or smooth) and
`closest_points`.

Each checks its inputs, prepares the pair frame, picks its path statically and runs it compiled
(see `_pair.compiled_query`). The paths: the SAT (`_sat`) for the overlap queries on sharp
shapes; the exact distance search (`_closest`: the SAT, then GJK in 3D or the support faces in
2D); the smooth one (`_smoothing`).

Half-spaces (`_halfspace`) against any other shape need no search: the lowest vertex of
the other shape's core. Rounded shapes (a radius on either shape, static) go through the
distance search on their cores: the signed distance of two rounded shapes is that of their
cores minus r_a + r_b, in both regimes, with the cores' axis and the witness points moved
out along it by the radii.
So `penetration` of a rounded pair is minus that signed distance (the exact value also when
apart), and `intersects` is signed distance <= 0.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxsat._closest import exact_distance, signed_distance_of_witnesses, witness
from jaxsat._halfspace import check_kinds, is_plane_pair, plane_query
from jaxsat._kernels import rotate
from jaxsat._pair import (
    Guarded,
    PairFrame,
    cast_pair,
    check_one_pair,
    compiled_query,
    pair_frame,
)
from jaxsat._poses import Pose
from jaxsat._sat import sat_search, takes_box_kernel
from jaxsat._shapes import Polytope
from jaxsat._smoothing import smooth_signed_distance

__all__ = ["ClosestPoints", "Penetration", "check_pair", "check_smoothing", "closest_points",
           "intersects", "penetration", "signed_distance"]


def check_pair(a, pose_a: Pose, b, pose_b: Pose) -> None:
    """Raise TypeError unless a and b are Polytopes (or one a HalfSpace) and the poses Poses;
    ValueError for two half-spaces, batched inputs or mixed dimensions."""
    check_kinds(a, b)
    for name, value in (("pose_a", pose_a), ("pose_b", pose_b)):
        if not isinstance(value, Pose):
            raise TypeError(f"{name} must be a jaxsat.Pose, got {type(value).__name__}")
    check_one_pair(a, pose_a, b, pose_b)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Penetration:
    """Result of `penetration` for one pair (fields gain leading axes under `vmap`)."""

    depth: jax.Array
    """() float: minimum translation distance if > 0; minus the largest axis gap if <= 0."""
    normal: jax.Array
    """(D,) float: unit world-frame axis from a towards b; moving b by depth * normal separates."""





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


@compiled_query(check_pair, name="signed_distance")
def _exact_signed_distance(a, pose_a, b, pose_b) -> jax.Array:
    if is_plane_pair(a, b):
        return plane_query(a, pose_a, b, pose_b).signed_distance
    return _exact_value(pair_frame(a, pose_a, b, pose_b))[0]


def _exact_value(frame: PairFrame):
    """(the exact signed distance of a prepared pair, differentiable (rounded: the cores'
    minus the radii); the search's answer, values only)."""
    found = jax.lax.stop_gradient(exact_distance(jax.lax.stop_gradient(frame)))
    core = signed_distance_of_witnesses(frame, found)
    return (core - frame.radius_a - frame.radius_b if frame.is_rounded else core), found


@compiled_query(lambda a, pose_a, b, pose_b, smoothing: check_pair(a, pose_a, b, pose_b),
                name="signed_distance")
def _smooth_signed_distance(a, pose_a, b, pose_b, smoothing) -> jax.Array:
    if is_plane_pair(a, b):
        return plane_query(a, pose_a, b, pose_b, smoothing).signed_distance
    frame = pair_frame(a, pose_a, b, pose_b)
    core = smooth_signed_distance(frame, jnp.asarray(smoothing, frame.dtype))
    return core - frame.radius_a - frame.radius_b if frame.is_rounded else core


def check_smoothing(smoothing) -> None:
    """None or a scalar number; a concrete one must be finite and > 0 (a traced value is
    taken as given: the smooth path floors it)."""
    if smoothing is None or isinstance(smoothing, jax.core.Tracer):
        return
    if isinstance(smoothing, (bool, np.bool_)) or not isinstance(
            smoothing, (int, float, np.number, np.ndarray, jax.Array)):
        raise TypeError("smoothing must be None (exact) or a number (a length tau > 0), got "
                        f"{type(smoothing).__name__}")
    value = np.asarray(smoothing)
    if value.shape != () or not np.issubdtype(value.dtype, np.number):
        raise TypeError(f"smoothing must be a scalar number, got an array of shape {value.shape}"
                        f" and dtype {value.dtype}")
    if not (np.isfinite(value) and value > 0):
        raise ValueError("smoothing must be a finite length > 0 (use smoothing=None for the "
                         f"exact distance), got {smoothing!r}")


def signed_distance(a: Polytope, pose_a: Pose, b: Polytope, pose_b: Pose, *,
                    smoothing: float | jax.Array | None = None) -> jax.Array:
    """Signed distance between two convex shapes: > 0 apart, < 0 overlapping.

    Args:
      a: the first shape, unbatched (use jax.vmap for batches): a Polytope, sharp or
        rounded, or a HalfSpace.
      pose_a: the pose of a.
      b: the second shape, of the same dimension D as a; at most one of a and b is a
        HalfSpace.
      pose_b: the pose of b.
      smoothing: None (the default) for the exact value: the Euclidean distance when the
        shapes are apart, minus the exact penetration depth when they overlap. A length
        tau > 0 for a smooth approximation that satisfies
        exact - smoothing_error_bound(a, b) * tau <= smooth <= exact; see
        `smoothing_error_bound` for how to pick tau. The choice is static: any number,
        concrete or traced, takes the smooth path (a traced tau is floored at a few ulps of
        the shapes' size, so a traced 0 gives the exact value up to rounding, not NaN).

    Returns:
      () float in the common dtype of the inputs. Gradients with respect to poses and to
      `Polytope.vertices` are finite everywhere, and both versions are 1-Lipschitz in either
      shape's translation (the gradient there is a unit vector). The exact gradient is the
      derivative of the witness pair's gap (envelope theorem): the true derivative wherever
      one exists, with respect to vertices that of the distance between the hulls of the
      moved vertices (as if the shape were rebuilt). The smooth gradient is that of the soft
      gap along its best axis (see `_smoothing`): continuous wherever the shapes are apart.

    Raises:
      TypeError: a or b is neither a Polytope nor a HalfSpace, a pose is not a Pose, or
        smoothing is neither None nor a scalar number.
      ValueError: two half-spaces, batched inputs, mixed dimensions, or a concrete smoothing
        that is not a finite number > 0.
    """
    check_pair(a, pose_a, b, pose_b)
    check_smoothing(smoothing)
    if smoothing is None:
        return _exact_signed_distance(a, pose_a, b, pose_b)
    return _smooth_signed_distance(a, pose_a, b, pose_b, smoothing)


@compiled_query(check_pair)
def closest_points(a: Polytope, pose_a: Pose, b: Polytope, pose_b: Pose) -> ClosestPoints:
    """Exact signed distance with its witness points and axis, for one pair of shapes.

    When the shapes are apart, point_a and point_b are a closest pair (one of them, if the
    closest features are parallel). When they overlap, point_b = point_a - depth * normal
    and moving b by depth * normal makes the two points meet: they are where the shapes
    touch after the minimum translation. Values only: the search is not differentiated
    (differentiate `signed_distance`, whose value equals the `signed_distance` field here).
    """
    if is_plane_pair(a, b):
        found = jax.lax.stop_gradient(plane_query(a, pose_a, b, pose_b))
        return ClosestPoints(signed_distance=found.signed_distance, point_a=found.point_a,
                             point_b=found.point_b, normal=found.normal)
    frame = jax.lax.stop_gradient(pair_frame(a, pose_a, b, pose_b))
    found = exact_distance(frame)
    point_a = witness(found.weights, frame.a.vertices, found.index_a)
    distance = found.distance
    if frame.is_rounded:
        point_a = point_a + frame.radius_a * found.axis
        distance = distance - frame.radius_a - frame.radius_b
    point_b = point_a + distance * found.axis
    return ClosestPoints(signed_distance=distance, point_a=frame.to_world(point_a),
                         point_b=frame.to_world(point_b),
                         normal=rotate(frame.pose_a.rotation, found.axis))


def _check_penetration(a, pose_a, b, pose_b, *, prune=True) -> None:
    check_pair(a, pose_a, b, pose_b)
    if not isinstance(prune, bool):
        raise TypeError(f"prune must be True or False, got {prune!r}")


@compiled_query(_check_penetration, static_argnames=("prune",))
def penetration(a: Polytope, pose_a: Pose, b: Polytope, pose_b: Pose, *,
                prune: bool = True) -> Penetration:
    """Exact SAT penetration depth and axis for one pair of convex shapes.

    Args:
      a: the first shape, unbatched (use jax.vmap for batches): a Polytope, sharp or
        rounded, or a HalfSpace.
      pose_a: the pose of a.
      b: the second shape, of the same dimension D as a; at most one of a and b is a
        HalfSpace.
      pose_b: the pose of b.
      prune: in 3D, skip the edge pairs whose arcs do not cross on the Gauss map (they do not
        bound the Minkowski difference, so they never give the answer). False tests every
        pair of edge directions, as a textbook SAT does: the same result for overlapping
        shapes, only slower (see benchmarks/scene.py); for separated shapes the extra axes
        may find a larger gap, still within the bounds stated below. Static.

    Returns:
      Penetration(depth, normal) in the common dtype of the inputs. depth > 0: the shapes
      overlap and depth is the exact minimum translation distance; moving b by depth * normal
      leaves them touching. depth <= 0: separated, and -depth is the largest gap found on a
      candidate axis: at least the largest gap over the facet normals of the Minkowski
      difference and at most the distance between the shapes. normal is a world-frame unit
      vector pointing from a towards b.
    """
    if is_plane_pair(a, b):
        found = plane_query(a, pose_a, b, pose_b)
        return Penetration(depth=-found.signed_distance, normal=found.normal)
    frame = pair_frame(a, pose_a, b, pose_b)
    if frame.is_rounded:
        # One search gives both the value and the axis.
        value, found = _exact_value(frame)
        return Penetration(depth=-value, normal=frame.direction_to_world(found.axis))
    found = sat_search(frame, prune, box_kernel=True)
    normal = frame.direction_to_world(found.axis)
    if takes_box_kernel(frame.a, frame.b):
        # The box kernel's depth holds the non-finite guard; the normal takes it from the
        # stored depth (0 * depth: 0, or NaN), not from a pass over the inputs.
        return Guarded(Penetration(depth=found.depth, normal=normal + 0 * found.depth))
    return Penetration(depth=found.depth, normal=normal)



def _world_aabb(shape: Polytope, pose: Pose) -> tuple[jax.Array, jax.Array]:
    world = pose.apply(shape.vertices)
    return world.min(axis=0), world.max(axis=0)


@compiled_query(check_pair)
def intersects(a: Polytope, pose_a: Pose, b: Polytope, pose_b: Pose) -> jax.Array:
    """True where the two shapes overlap or touch (penetration depth >= 0).

    A single call compares the world AABBs first and skips the SAT when they are disjoint.
    Under jax.vmap that skip would not pay (both branches of a batched cond run), so the
    batched query goes straight to the SAT minimum; the answer is the same either way.
    """
    if is_plane_pair(a, b):
        return jax.lax.stop_gradient(plane_query(a, pose_a, b, pose_b).signed_distance) <= 0
    if a.is_rounded or b.is_rounded:
        frame = jax.lax.stop_gradient(pair_frame(a, pose_a, b, pose_b))
        found = exact_distance(frame)
        return found.distance <= frame.radius_a + frame.radius_b
    a, pose_a, b, pose_b = cast_pair(a, pose_a, b, pose_b)
    # A boolean has no derivative; stopping gradients here keeps `custom_vmap` (which has no
    # reverse-mode rule) out of any gradient of a function that merely calls `intersects`.
    overlap = _intersects_pair(*jax.lax.stop_gradient((a, pose_a, b, pose_b)))
    # With the box kernel, non-finite input gives False already: the SAT's depth is NaN
    # (`takes_box_kernel`), and the single call's box test compares NaN corners.
    return Guarded(overlap) if takes_box_kernel(a, b) else overlap


def _sat_intersects(a, pose_a, b, pose_b) -> jax.Array:
    # The winning axis' depth as `penetration` measures it (by projection), not the raw
    # minimum over candidates: a Gauss-map edge depth loses float32 digits, and two shapes
    # touching at a point got -2e-8 here against +1.2e-7 from `penetration`.
    return sat_search(pair_frame(a, pose_a, b, pose_b), box_kernel=True).depth >= 0


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
