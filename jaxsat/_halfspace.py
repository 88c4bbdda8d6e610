"""Half-spaces: the points x with normal . x <= offset in the half-space's local frame.

A half-space against a convex shape needs no search: the shape's signed distance to the plane
is the least height of its core's vertices above the plane minus its radius, and the
direction is the plane's normal. The smooth version softens that minimum with log-sum-exp at
temperature tau, so that exact - tau log n <= smooth <= exact (n: the shape's real vertex
count) and its translation gradient is the normal times a convex combination of weights: norm
1, as the exact one.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxsat import _kernels as k
from jaxsat._pair import cast_pair, relative_pose
from jaxsat._shapes import Polytope, float_dtype

__all__ = ["HalfSpace", "PlaneQuery", "check_kinds", "halfspace", "is_plane_pair",
           "plane_query"]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class HalfSpace:
    """The points x with normal . x <= offset, in the half-space's own frame (place it with a
    pose, as any shape): a ground plane, a wall. Build with `halfspace`."""

    normal: jax.Array
    """(D,) float: unit outward normal (pointing out of the solid side)."""
    offset: jax.Array
    """() float: the boundary plane's distance from the local origin along the normal."""

    @property
    def dim(self) -> int:
        return self.normal.shape[-1]

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return self.normal.shape[:-1]

    @property
    def dtype(self):
        return self.normal.dtype


def halfspace(normal, offset=0.0, *, dtype=None) -> HalfSpace:
    """The half-space normal . x <= offset (2D or 3D); the normal need not be unit (it and the
    offset are divided by its length).

    Example: `halfspace([0, 0, 1])` is the ground below z = 0.

    Raises:
      TypeError: a non-numeric normal or offset.
      ValueError: a normal of other than 2 or 3 entries, a zero or non-finite normal, or a
        non-finite or non-scalar offset.
    """
    try:
        direction = np.asarray(normal, dtype=np.float64)
        level = np.asarray(offset, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise TypeError(f"normal and offset must be numbers: {error}") from None
    if direction.shape not in ((2,), (3,)):
        raise ValueError(f"normal must have 2 or 3 entries, got shape {direction.shape}")
    length = np.linalg.norm(direction)
    if not np.all(np.isfinite(direction)) or length == 0:
        raise ValueError(f"normal must be finite and non-zero, got {direction.tolist()}")
    if level.shape != () or not np.isfinite(level):
        raise ValueError(f"offset must be one finite number, got {offset!r}")
    dtype = float_dtype(np.asarray(normal) if np.asarray(normal).dtype.kind == "f"
                        else None, dtype)
    return HalfSpace(jnp.asarray(direction / length, dtype), jnp.asarray(level / length, dtype))


class PlaneQuery(NamedTuple):
    """A half-space pair's answer, in the world frame, in the order the pair was given."""

    signed_distance: jax.Array
    """() float: differentiable (exact or smooth)."""
    normal: jax.Array
    """(D,) float: unit axis from a towards b (values only)."""
    point_a: jax.Array
    """(D,) float: a's witness point (values only; exact path)."""
    point_b: jax.Array
    """(D,) float: b's witness point, point_a + signed_distance * normal."""


def plane_query(a, pose_a, b, pose_b, tau=None) -> PlaneQuery:
    """Signed distance of a pair in which one shape is a HalfSpace and the other a Polytope
    (sharp or rounded), exact (tau None) or smooth, with the axis and witness points."""
    a, pose_a, b, pose_b = cast_pair(a, pose_a, b, pose_b)
    plane_first = isinstance(a, HalfSpace)
    plane, plane_pose, shape, shape_pose = (a, pose_a, b, pose_b) if plane_first else (
        b, pose_b, a, pose_a)
    rotation, translation = relative_pose(plane_pose, shape_pose)
    vertices = k.rotate(rotation, shape.vertices) + translation  # in the plane's frame
    heights = k.dot(vertices, plane.normal) - plane.offset
    # The lowest vertex, chosen without a gradient: the derivative then reaches that one
    # vertex with weight 1 (a min over tied vertices would spread it).
    lowest = jnp.argmin(jax.lax.stop_gradient(heights))
    if tau is None:
        core = heights[lowest]
    else:
        extent = jax.lax.stop_gradient(jnp.max(jnp.abs(heights)))
        tau = jnp.asarray(tau, heights.dtype)
        tau = k.where(tau > 16 * jnp.finfo(heights.dtype).eps * extent, tau,
                      16 * jnp.finfo(heights.dtype).eps * extent + jnp.finfo(heights.dtype).tiny)
        low = jax.lax.stop_gradient(heights[lowest])
        # Padding never reaches exp (double where): no inf * 0 in any gradient.
        shifted = k.where(shape.vertex_mask, heights - low, 0.0)
        terms = k.where(shape.vertex_mask, jnp.exp(-shifted / tau), 0.0)
        # low is a constant shift of the log-sum-exp: the derivative is the softmin
        # weights' combination of the heights' derivatives.
        core = low - tau * jnp.log(jnp.sum(terms))
    radius = jnp.zeros((), heights.dtype) if shape.radius is None else shape.radius
    signed = core - radius
    found = jax.lax.stop_gradient((vertices[lowest], heights[lowest], radius))
    on_shape = found[0] - found[2] * plane.normal
    on_plane = found[0] - found[1] * plane.normal
    world = lambda point: k.rotate(plane_pose.rotation, point) + plane_pose.translation  # noqa: E731
    outward = jax.lax.stop_gradient(k.rotate(plane_pose.rotation, plane.normal))
    if plane_first:
        return PlaneQuery(signed, outward, world(on_plane), world(on_shape))
    return PlaneQuery(signed, -outward, world(on_shape), world(on_plane))


def is_plane_pair(a, b) -> bool:
    """Static: one of the two is a HalfSpace."""
    return isinstance(a, HalfSpace) or isinstance(b, HalfSpace)


def check_kinds(a, b) -> None:
    """Raise unless a and b are Polytopes or one of them a HalfSpace."""
    for name, value in (("a", a), ("b", b)):
        if not isinstance(value, (Polytope, HalfSpace)):
            raise TypeError(f"{name} must be a jaxsat.Polytope or jaxsat.HalfSpace, got "
                            f"{type(value).__name__}")
    if isinstance(a, HalfSpace) and isinstance(b, HalfSpace):
        raise ValueError("a and b are both half-spaces; their distance is -inf unless their "
                         "planes are parallel, so no query takes two")
