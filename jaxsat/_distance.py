"""Public distance queries: `signed_distance` (exact or smooth) and `closest_points`.

The exact search is `_closest` (the SAT, then GJK in 3D or the support faces in 2D), the
smooth one `_smoothing`; this module checks the inputs, picks the path (statically, from
whether `smoothing` is None) and runs it compiled (see `_pair.compiled_query`).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxsat._closest import exact_distance, signed_distance_of_witnesses, witness
from jaxsat._kernels import rotate
from jaxsat._pair import check_pair, compiled_query, pair_frame
from jaxsat._poses import Pose
from jaxsat._shapes import Polytope
from jaxsat._smoothing import smooth_signed_distance

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


@compiled_query(check_pair)
def _exact_signed_distance(a, pose_a, b, pose_b) -> jax.Array:
    frame = pair_frame(a, pose_a, b, pose_b)
    found = exact_distance(jax.lax.stop_gradient(frame))
    return signed_distance_of_witnesses(frame, jax.lax.stop_gradient(found))


@compiled_query(lambda a, pose_a, b, pose_b, tau: check_pair(a, pose_a, b, pose_b))
def _smooth_signed_distance(a, pose_a, b, pose_b, tau) -> jax.Array:
    frame = pair_frame(a, pose_a, b, pose_b)
    return smooth_signed_distance(frame, jnp.asarray(tau, frame.dtype))


def _check_smoothing(smoothing) -> None:
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
      a, b: shapes of the same dimension D (unbatched; use jax.vmap for batches).
      pose_a, pose_b: their poses.
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
      TypeError: a or b is not a Polytope, a pose is not a Pose, or smoothing is neither
        None nor a scalar number.
      ValueError: batched inputs, mixed dimensions, or a concrete smoothing that is not a
        finite number > 0.
    """
    check_pair(a, pose_a, b, pose_b)
    _check_smoothing(smoothing)
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
    frame = jax.lax.stop_gradient(pair_frame(a, pose_a, b, pose_b))
    found = exact_distance(frame)
    point_a = witness(found.weights, frame.a.vertices, found.index_a)
    point_b = point_a + found.distance * found.axis
    return ClosestPoints(signed_distance=found.distance, point_a=frame.to_world(point_a),
                         point_b=frame.to_world(point_b),
                         normal=rotate(frame.pose_a.rotation, found.axis))
