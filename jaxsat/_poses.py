"""Rigid poses (rotation + translation) as pytrees, differentiable in their parameters."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxsat._kernels import explicit_float_dtype, where

__all__ = ["Pose", "pose2", "pose3"]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Pose:
    """A rigid transform taking local coordinates to world coordinates: x -> R x + t."""

    translation: jax.Array
    """(D,) float: position of the local origin in the world frame."""
    rotation: jax.Array
    """(D, D) float: rotation matrix whose columns are the local axes in the world frame."""

    def __post_init__(self):
        translation, rotation = self.translation, self.rotation
        arrays = (jax.Array, np.ndarray)
        if not isinstance(translation, arrays) or not isinstance(rotation, arrays):
            return  # pytree utilities rebuild poses around placeholders (axis specs, ArgInfo)
        dim = translation.shape[-1] if translation.ndim else None
        if dim not in (2, 3) or rotation.shape[-2:] != (dim, dim):
            raise ValueError("Pose needs translation (D,) and rotation (D, D) with D = 2 or 3, "
                             f"got {translation.shape} and {rotation.shape}")

    @property
    def dim(self) -> int:
        return self.translation.shape[-1]

    @classmethod
    def identity(cls, dim: int, dtype=None) -> Pose:
        """The identity pose in `dim` = 2 or 3 dimensions."""
        if dim not in (2, 3):
            raise ValueError(f"dim must be 2 or 3, got {dim!r}")
        dtype = (jax.dtypes.canonicalize_dtype(float) if dtype is None
                 else explicit_float_dtype(dtype))
        return cls(jnp.zeros(dim, dtype), jnp.eye(dim, dtype=dtype))

    def apply(self, points: jax.Array) -> jax.Array:
        """Map local points to world coordinates.

        A single pose maps (..., D) points. A batch of poses (batch shape S) maps (*S, N, D)
        points, or (N, D) points shared by the whole batch, each through its own pose."""
        if self.rotation.ndim == 2:
            return points @ self.rotation.T + self.translation
        rotation_t = jnp.swapaxes(self.rotation, -1, -2)
        return jnp.matmul(points, rotation_t) + self.translation[..., None, :]

    def inverse(self) -> Pose:
        """The pose taking world coordinates back to local ones."""
        rotation_t = jnp.swapaxes(self.rotation, -1, -2)
        return Pose(-(rotation_t @ self.translation[..., None])[..., 0], rotation_t)

    def compose(self, other: Pose) -> Pose:
        """self * other: apply `other` first, then `self`."""
        return Pose(self.apply(other.translation), self.rotation @ other.rotation)


def _as_float(*values):
    arrays = [jnp.asarray(value) for value in values]
    # Integers and Python numbers become the default float, float arrays keep their dtype:
    # standard promotion on purpose, also under a user's strict setting (where it would raise).
    with jax.numpy_dtype_promotion("standard"):
        dtype = jnp.result_type(float, *arrays)
    return [array.astype(dtype) for array in arrays]


def pose2(x, y, angle) -> Pose:
    """A 2D pose from a position and a counter-clockwise rotation angle in radians."""
    x, y, angle = _as_float(x, y, angle)
    if x.shape or y.shape or angle.shape:
        raise ValueError("pose2 takes scalars x, y, angle; use jax.vmap for batches, got shapes "
                         f"{x.shape}, {y.shape}, {angle.shape}")
    cos, sin = jnp.cos(angle), jnp.sin(angle)
    rotation = jnp.stack([jnp.stack([cos, -sin]), jnp.stack([sin, cos])])
    return Pose(jnp.stack([x, y]), rotation)


def pose3(translation, quaternion_wxyz) -> Pose:
    """A 3D pose from a translation and a rotation quaternion (w, x, y, z).

    The quaternion need not be normalised; it is divided by its norm (a zero quaternion gives
    the identity rotation, with finite gradients). A NaN or infinite entry gives a NaN
    rotation, which every query turns into NaN outputs.
    """
    translation, quaternion = _as_float(translation, quaternion_wxyz)
    if translation.shape != (3,) or quaternion.shape != (4,):
        raise ValueError("pose3 needs translation (3,) and quaternion_wxyz (4,), got "
                         f"{translation.shape} and {quaternion.shape}")
    squared_norm = jnp.sum(quaternion**2)
    # Written so that NaN counts as nonzero: a NaN quaternion must not become the identity.
    nonzero = ~(squared_norm <= jnp.finfo(quaternion.dtype).tiny)
    # Double `where`: the untaken branch must not divide by zero, or its gradient is NaN.
    safe = where(nonzero, quaternion, jnp.array([1, 0, 0, 0], quaternion.dtype))
    # One unstack and one stack, not an index per entry and jnp.array of scalars: fewer
    # operations in every 3D query's program (a batched pose gradient: 169 instead of 211).
    w, x, y, z = jnp.unstack(safe / jnp.sqrt(jnp.sum(safe**2)))
    rotation = jnp.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ]).reshape(3, 3)
    return Pose(translation, rotation)
