"""Scene queries: every colliding pair among N posed shapes, broad phase then narrow phase.

The broad phase (`broad_phase`, a hashed uniform grid over world AABBs) keeps the pairs whose
boxes overlap, in a static number of slots; the narrow phase runs on those slots only, at the
level of work the caller asks for: a yes/no answer, depth and normal, or full contacts.
"""

from __future__ import annotations

import dataclasses
import functools

import jax

from jaxsat import _batching, _contacts, _queries
from jaxsat._broadphase import broad_phase, world_aabbs
from jaxsat._poses import Pose
from jaxsat._shapes import Polytope

__all__ = ["SceneCollisions", "collide"]

LEVELS = ("intersects", "penetration", "contacts")
"""Levels of work, cheapest first; each one skips the work of the next."""


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


def _check_scene(shapes, poses, level):
    if not isinstance(shapes, Polytope) or not isinstance(poses, Pose):
        raise TypeError("collide takes a stacked jaxsat.Polytope and batched jaxsat.Pose")
    if len(shapes.batch_shape) != 1:
        raise ValueError("collide needs shapes stacked along exactly one leading axis (N, ...), "
                         f"got batch shape {shapes.batch_shape}")
    if level not in LEVELS:
        raise ValueError(f"level must be one of {LEVELS}, got {level!r}")


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
            chunk_size: int | None = None, devices=None) -> SceneCollisions:
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

    Returns:
      SceneCollisions. The function is jitted: capacity, level, candidate_capacity,
      chunk_size and devices are static, so changing them recompiles.
    """
    _check_scene(shapes, poses, level)
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
    return SceneCollisions(pairs=candidates.pairs, valid=candidates.valid,
                           colliding=candidates.valid & touching, depth=depth, normal=normal,
                           contacts=contact_set, count=candidates.count,
                           overflow=candidates.overflow)
