"""Scene queries: every colliding pair among N posed shapes, broad phase then narrow phase.

The broad phase (`broad_phase`, a hashed uniform grid over world AABBs) keeps the pairs whose
boxes overlap, in a static number of slots; the narrow phase runs on those slots only, at the
level of work the caller asks for: a yes/no answer, depth and normal, or full contacts.

Half-spaces (a ground, walls) have no bounding box: they never enter the grid (one would make
it as coarse as the scene), and every shape is tested against every one of them instead, in
one dense (N, P) batch, at the same level.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp

from jaxsat import _batching, _contacts, _queries
from jaxsat._broadphase import broad_phase, world_aabbs
from jaxsat._halfspace import HalfSpace
from jaxsat._poses import Pose
from jaxsat._shapes import Polytope

__all__ = ["PlaneCollisions", "SceneCollisions", "collide"]

LEVELS = ("intersects", "penetration", "contacts")
"""Levels of work, cheapest first; each one skips the work of the next."""


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class PlaneCollisions:
    """Every shape of a scene against every half-space given to `collide`: (N, P) entries,
    shape i as a and half-space p as b."""

    colliding: jax.Array
    """(N, P) bool: shape i overlaps or touches half-space p."""
    depth: jax.Array | None
    """(N, P) float: penetration depth (minus the signed distance); None at level
    "intersects"."""
    normal: jax.Array | None
    """(N, P, D) float: unit normal from the shape towards the half-space (minus the plane's
    outward normal); None at level "intersects"."""
    contacts: _contacts.Contacts | None
    """Contacts with leading (N, P) axes; None below level "contacts"."""


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SceneCollisions:
    """Result of `collide`: one slot per broad-phase pair (C = capacity).

    Entries of slots that are not `valid` were computed on a placeholder pair: ignore them.
    """

    pairs: jax.Array
    """(C, 2) int32: shape indices (i, j), i < j, of each slot."""
    valid: jax.Array
    """(C,) bool: the slot holds a pair whose AABBs overlap (and that passed the filters)."""
    colliding: jax.Array
    """(C,) bool: valid, and the two shapes overlap or touch."""
    depth: jax.Array | None
    """(C,) float: penetration depth of each pair (see `penetration`); None at level
    "intersects"."""
    normal: jax.Array | None
    """(C, D) float: unit normal from shape i towards shape j; None at level "intersects"."""
    contacts: _contacts.Contacts | None
    """Contacts with a leading (C,) axis; None below level "contacts"."""
    count: jax.Array
    """() int32: number of broad-phase pairs, including any that did not fit."""
    overflow: jax.Array
    """() int32: broad-phase pairs that did not fit in `capacity`; 0 means nothing was missed."""
    non_finite: jax.Array
    """(N,) bool: shape i has a NaN or infinite pose, vertex or radius. It is in no pair slot
    (its results would be NaN), the other shapes pair as they would without it, and its rows
    of `planes` are NaN (not colliding)."""
    non_finite_count: jax.Array
    """() int32: how many shapes are `non_finite`; 0 means every shape took part."""
    planes: PlaneCollisions | None = None
    """Every shape against every half-space; None when `collide` was given none."""


def _check_scene(shapes, poses, level):
    if not isinstance(shapes, Polytope) or not isinstance(poses, Pose):
        raise TypeError("collide takes a stacked jaxsat.Polytope and batched jaxsat.Pose")
    if len(shapes.batch_shape) != 1:
        raise ValueError("collide needs shapes stacked along exactly one leading axis (N, ...), "
                         f"got batch shape {shapes.batch_shape}")
    if level not in LEVELS:
        raise ValueError(f"level must be one of {LEVELS}, got {level!r}")


def _as_planes(planes, plane_poses, dim: int, dtype) -> tuple[HalfSpace, Pose]:
    """The half-spaces and their poses stacked to (P,): from one HalfSpace (batched or not)
    or a list of them; poses likewise, or None for identity poses (planes in the world)."""
    def stacked(value, kind, name):
        if isinstance(value, kind):
            batched = value.translation.ndim > 1 if kind is Pose else bool(value.batch_shape)
            return value if batched else jax.tree.map(lambda leaf: leaf[None], value)
        if isinstance(value, (list, tuple)) and value and all(
                isinstance(entry, kind) for entry in value):
            return jax.tree.map(lambda *leaves: jnp.stack(leaves), *value)
        raise TypeError(f"{name} must be a jaxsat.{kind.__name__} or a list of them, got "
                        f"{type(value).__name__}")

    planes = stacked(planes, HalfSpace, "planes")
    if len(planes.batch_shape) != 1:
        raise ValueError(f"planes must be stacked along one axis (P,), got {planes.batch_shape}")
    if planes.dim != dim:
        raise ValueError(f"planes are {planes.dim}D and shapes {dim}D")
    count = planes.batch_shape[0]
    if plane_poses is None:
        identity = Pose.identity(dim, dtype)
        plane_poses = jax.tree.map(lambda leaf: jnp.broadcast_to(leaf, (count, *leaf.shape)),
                                   identity)
    plane_poses = stacked(plane_poses, Pose, "plane_poses")
    if plane_poses.translation.shape != (count, dim):
        raise ValueError(f"plane_poses must be {count} {dim}D poses, one per half-space, got "
                         f"translations of shape {plane_poses.translation.shape}")
    return planes, plane_poses


def _plane_phase(level, shapes, poses, planes, plane_poses) -> PlaneCollisions:
    """Every shape against every half-space at `level`, in one dense batch."""
    query = {"intersects": _queries.intersects, "penetration": _queries.penetration,
             "contacts": _penetration_and_contacts}[level]
    per_plane = jax.vmap(query, in_axes=(None, None, 0, 0))
    result = jax.vmap(per_plane, in_axes=(0, 0, None, None))(shapes, poses, planes, plane_poses)
    if level == "intersects":
        return PlaneCollisions(colliding=result, depth=None, normal=None, contacts=None)
    hit, contact_set = (result, None) if level == "penetration" else result
    return PlaneCollisions(colliding=hit.depth >= 0, depth=hit.depth, normal=hit.normal,
                           contacts=contact_set)


def _penetration_and_contacts(a, pose_a, b, pose_b):
    # Both share the SAT; under jit XLA computes it once.
    return (_queries.penetration(a, pose_a, b, pose_b),
            _contacts.contacts(a, pose_a, b, pose_b))


def _narrow_phase(level, shapes, poses, pairs, chunk_size, devices):
    """Per-slot results at `level` for the candidate pairs."""
    query = {"intersects": _queries.intersects, "penetration": _queries.penetration,
             "contacts": _penetration_and_contacts}[level]
    return _batching.query_pairs(query, shapes, poses, pairs, chunk_size=chunk_size,
                                 devices=devices)


@functools.partial(jax.jit, static_argnames=("capacity", "candidate_capacity", "level",
                                             "chunk_size", "devices"))
def collide(shapes: Polytope, poses: Pose, *, capacity: int, level: str = "penetration",
            candidate_capacity: int | None = None, groups=None, masks=None, body_ids=None,
            chunk_size: int | None = None, devices=None, planes=None,
            plane_poses=None) -> SceneCollisions:
    """Every colliding pair of a scene of N shapes, equal to the brute-force all-pairs answer.

    Args:
      shapes: Polytope stacked to (N, ...) (see `stack`), all of one dimension.
      poses: Pose batched to (N,).
      capacity: static number of pair slots; `overflow` > 0 says it was too small.
      level: "intersects" (yes/no only), "penetration" (+ depth and normal) or "contacts"
        (+ contact manifolds, see `contacts`).
      candidate_capacity, groups, masks, body_ids: see `broad_phase`.
      chunk_size, devices: how the narrow phase runs over the slots (see `query_pairs`);
        `devices` is an int or a tuple of devices (hashable: it is static).
      planes: half-spaces (a ground, walls): one HalfSpace, batched (P,) or not, or a list of
        them. They stay out of the broad phase; every shape is tested against each one at
        `level` (the result's `planes` field; groups and masks do not apply to them).
      plane_poses: their poses, as one Pose (batched or not) or a list; None places them in
        the world frame as given.

    Returns:
      SceneCollisions. The function is jitted: capacity, level, candidate_capacity,
      chunk_size and devices are static, so changing them recompiles.
    """
    _check_scene(shapes, poses, level)
    plane_result = None
    if planes is not None:
        planes, plane_poses = _as_planes(planes, plane_poses, shapes.dim, shapes.dtype)
        plane_result = _plane_phase(level, shapes, poses, planes, plane_poses)
    elif plane_poses is not None:
        raise ValueError("plane_poses given without planes")
    low, high = world_aabbs(shapes, poses)
    candidates = broad_phase(low, high, capacity=capacity, candidate_capacity=candidate_capacity,
                             groups=groups, masks=masks, body_ids=body_ids)
    result = _narrow_phase(level, shapes, poses, candidates.pairs, chunk_size, devices)
    depth = normal = contact_set = None
    if level == "intersects":
        touching = result
    else:
        hit, contact_set = (result, None) if level == "penetration" else result
        depth, normal, touching = hit.depth, hit.normal, hit.depth >= 0
    non_finite = _non_finite_shapes(shapes, poses)
    return SceneCollisions(pairs=candidates.pairs, valid=candidates.valid,
                           colliding=candidates.valid & touching, depth=depth, normal=normal,
                           contacts=contact_set, count=candidates.count,
                           overflow=candidates.overflow, non_finite=non_finite,
                           non_finite_count=jnp.sum(non_finite, dtype=jnp.int32),
                           planes=plane_result)


def _non_finite_shapes(shapes: Polytope, poses: Pose) -> jax.Array:
    """(N,) bool: a NaN or inf in shape i's vertices, radius, translation or rotation."""
    leaves = [shapes.vertices, poses.translation, poses.rotation]
    leaves += [] if shapes.radius is None else [shapes.radius]
    finite = [jnp.all(jnp.isfinite(leaf).reshape(leaf.shape[0], -1), axis=1) for leaf in leaves]
    return ~functools.reduce(jnp.logical_and, finite)
