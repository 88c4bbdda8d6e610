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

__all__ = ["PlaneCollisions", "SceneCollisions", "collide", "collide_capacity"]

LEVELS = ("intersects", "penetration", "distance", "contacts")
"""Levels of work: a yes/no answer, the SAT's depth and normal, the exact (or smooth) signed
distance with witness points, contact manifolds. Each of the first two skips the work of the
others."""


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
    near: jax.Array
    """(N, P) bool: within `margin` of the half-space (as `SceneCollisions.near`)."""
    signed_distance: jax.Array | None
    """(N, P) float: signed distance (exact, or smooth with `smoothing`); level "distance"
    only."""
    witness_points: jax.Array | None
    """(N, P, 2, D) float: the closest points of the shape and of the half-space (when
    overlapping, the deepest pair); level "distance" only."""


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
    """(C,) float: penetration depth of each pair (see `penetration`; at level "distance",
    minus the exact signed distance); None at level "intersects"."""
    normal: jax.Array | None
    """(C, D) float: unit normal from shape i towards shape j; None at level "intersects"."""
    contacts: _contacts.Contacts | None
    """Contacts with a leading (C,) axis; None below level "contacts"."""
    near: jax.Array
    """(C,) bool: valid, and the pair is within `margin` (colliding when margin = 0). Level
    "distance": signed distance <= margin, exactly. "contacts": a valid contact point (depth
    >= -margin). "penetration": depth >= -margin, where -depth is the largest SAT gap, at most
    the distance: every pair within margin, and possibly a few slightly beyond it."""
    signed_distance: jax.Array | None
    """(C,) float: signed distance of each pair, exact (`closest_points`) or with
    `smoothing` the smooth one (`signed_distance(..., smoothing=)`); level "distance" only."""
    witness_points: jax.Array | None
    """(C, 2, D) float: the exact closest points of shape i and shape j (`closest_points`);
    level "distance" only."""
    count: jax.Array
    """() int32: number of broad-phase pairs, including any that did not fit."""
    overflow: jax.Array
    """() int32: broad-phase pairs that did not fit in `capacity`; 0 means nothing was missed."""
    non_finite: jax.Array
    """(N,) bool: shape i has a NaN or infinite pose, vertex or radius (its world AABB is not
    finite). It is in no pair slot (its results would be NaN), the other shapes pair as they
    would without it, and its rows of `planes` are NaN (not colliding)."""
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


def _check_margin_and_smoothing(level, margin, smoothing):
    """Concrete margins and smoothings are checked before `collide` traces them; traced ones
    are the caller's business."""
    _contacts.check_margin(margin)
    if not isinstance(margin, jax.core.Tracer):
        if level == "intersects" and float(margin) > 0:
            raise ValueError("level 'intersects' has no distance to compare with a margin: use "
                             "level 'penetration', 'distance' or 'contacts'")
    if smoothing is not None:
        if level != "distance":
            raise ValueError(f"smoothing applies to level 'distance', not {level!r}")
        _queries.check_smoothing(smoothing)


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


def _level_query(level, margin, smoothing):
    """The one-pair query of a level (for shape pairs and shape-plane pairs alike)."""
    if level == "intersects":
        return _queries.intersects
    if level == "penetration":
        return _queries.penetration
    if level == "contacts":
        return functools.partial(_penetration_and_contacts, margin=margin)
    return functools.partial(_closest_and_distance, smoothing=smoothing)


def _level_fields(level, result, margin) -> dict:
    """The result fields of a level from its query's answers (any leading axes); None for
    what the level does not compute."""
    empty = {"depth": None, "normal": None, "contacts": None, "signed_distance": None,
             "witness_points": None}
    if level == "intersects":
        return {**empty, "colliding": result, "near": result}
    if level == "distance":
        closest, distance = result
        return {**empty, "colliding": closest.signed_distance <= 0,
                "depth": -closest.signed_distance, "normal": closest.normal,
                "near": distance <= margin, "signed_distance": distance,
                "witness_points": jnp.stack([closest.point_a, closest.point_b], axis=-2)}
    hit, contact_set = (result, None) if level == "penetration" else result
    near = (hit.depth >= -margin if contact_set is None
            else jnp.any(contact_set.valid, axis=-1))
    return {**empty, "colliding": hit.depth >= 0, "depth": hit.depth, "normal": hit.normal,
            "contacts": contact_set, "near": near}


def _plane_phase(query, level, margin, shapes, poses, planes, plane_poses) -> PlaneCollisions:
    """Every shape against every half-space at `level`, in one dense batch."""
    per_plane = jax.vmap(query, in_axes=(None, None, 0, 0))
    result = jax.vmap(per_plane, in_axes=(0, 0, None, None))(shapes, poses, planes, plane_poses)
    return PlaneCollisions(**_level_fields(level, result, margin))


def _penetration_and_contacts(a, pose_a, b, pose_b, margin=0.0):
    # Both share the SAT; under jit XLA computes it once.
    return (_queries.penetration(a, pose_a, b, pose_b),
            _contacts.contacts(a, pose_a, b, pose_b, margin=margin))


def _closest_and_distance(a, pose_a, b, pose_b, smoothing=None):
    closest = _queries.closest_points(a, pose_a, b, pose_b)
    if smoothing is None:
        return closest, closest.signed_distance
    return closest, _queries.signed_distance(a, pose_a, b, pose_b, smoothing=smoothing)


def _narrow_phase(query, shapes, poses, pairs, chunk_size, devices):
    """Per-slot results of `query` for the candidate pairs."""
    return _batching.query_pairs(query, shapes, poses, pairs, chunk_size=chunk_size,
                                 devices=devices)


def _inflated_aabbs(shapes, poses, margin):
    """World AABBs grown by margin / 2 on every side: two shapes within `margin` of each other
    have overlapping boxes (their gap along any axis is at most their distance)."""
    low, high = world_aabbs(shapes, poses)
    half = jnp.asarray(margin, low.dtype) / 2
    return low - half, high + half


def collide(shapes: Polytope, poses: Pose, *, capacity: int, level: str = "penetration",
            margin=0.0, smoothing=None, candidate_capacity: int | None = None, groups=None,
            masks=None, body_ids=None, chunk_size: int | None = None, devices=None,
            planes=None, plane_poses=None) -> SceneCollisions:
    """Every colliding (or near) pair of a scene of N shapes, equal to the brute-force
    all-pairs answer.

    Args:
      shapes: Polytope stacked to (N, ...) (see `stack`), all of one dimension.
      poses: Pose batched to (N,).
      capacity: static number of pair slots; `overflow` > 0 says it was too small.
        `collide_capacity` computes the exact number needed.
      level: "intersects" (yes/no only), "penetration" (+ depth and normal), "distance"
        (+ signed distance and witness points, see `closest_points`) or "contacts" (+ contact
        manifolds, see `contacts`).
      margin: a distance >= 0 (may be traced): the broad phase keeps every pair within it
        (AABBs grown by margin / 2), and `near` flags the pairs within it (see
        `SceneCollisions.near`); contacts keep points down to depth -margin. Not with level
        "intersects".
      smoothing: None, or a length tau > 0 for level "distance": `signed_distance` is then
        the smooth one (`signed_distance(..., smoothing=tau)`), `near` compares it with the
        margin, and the witness points stay exact.
      candidate_capacity: see `broad_phase`.
      groups: see `broad_phase`.
      masks: see `broad_phase`.
      body_ids: see `broad_phase`.
      chunk_size: how the narrow phase runs over the slots (see `query_pairs`).
      devices: an int or a tuple of devices (hashable: it is static), see `query_pairs`.
      planes: half-spaces (a ground, walls): one HalfSpace, batched (P,) or not, or a list of
        them. They stay out of the broad phase; every shape is tested against each one at
        `level` (the result's `planes` field; groups and masks do not apply to them).
      plane_poses: their poses, as one Pose (batched or not) or a list; None places them in
        the world frame as given.

    Returns:
      SceneCollisions. The function is jitted: capacity, level, candidate_capacity,
      chunk_size and devices are static, so changing them recompiles (so does switching
      smoothing between None and a number).
    """
    _check_margin_and_smoothing(level, margin, smoothing)
    return _collide(shapes, poses, capacity=capacity, level=level, margin=margin,
                    smoothing=smoothing, candidate_capacity=candidate_capacity, groups=groups,
                    masks=masks, body_ids=body_ids, chunk_size=chunk_size, devices=devices,
                    planes=planes, plane_poses=plane_poses)


@functools.partial(jax.jit, static_argnames=("capacity", "candidate_capacity", "level",
                                             "chunk_size", "devices"))
def _collide(shapes, poses, *, capacity, level, margin, smoothing, candidate_capacity, groups,
             masks, body_ids, chunk_size, devices, planes, plane_poses) -> SceneCollisions:
    _check_scene(shapes, poses, level)
    query = _level_query(level, margin, smoothing)
    plane_result = None
    if planes is not None:
        planes, plane_poses = _as_planes(planes, plane_poses, shapes.dim, shapes.dtype)
        plane_result = _plane_phase(query, level, margin, shapes, poses, planes, plane_poses)
    elif plane_poses is not None:
        raise ValueError("plane_poses given without planes")
    low, high = _inflated_aabbs(shapes, poses, margin)
    candidates = broad_phase(low, high, capacity=capacity, candidate_capacity=candidate_capacity,
                             groups=groups, masks=masks, body_ids=body_ids)
    fields = _level_fields(level, _narrow_phase(query, shapes, poses, candidates.pairs,
                                                chunk_size, devices), margin)
    fields["colliding"] = candidates.valid & fields["colliding"]
    fields["near"] = candidates.valid & fields["near"]
    return SceneCollisions(pairs=candidates.pairs, valid=candidates.valid, **fields,
                           count=candidates.count, overflow=candidates.overflow,
                           non_finite=candidates.non_finite,
                           non_finite_count=jnp.sum(candidates.non_finite, dtype=jnp.int32),
                           planes=plane_result)


def collide_capacity(shapes: Polytope, poses: Pose, *, margin=0.0, groups=None, masks=None,
                     body_ids=None) -> int:
    """The exact number of broad-phase pairs `collide` finds (with the same margin and
    filters): pass it, or more, as `capacity` and `overflow` is 0. Eager (not traceable): it
    calls the broad phase with growing buffers until none overflows, each size compiling
    once. The narrow phase is not run.

    Example: `scene = collide(shapes, poses, capacity=collide_capacity(shapes, poses))`. In a
    loop whose scene changes, size it once with headroom and watch `overflow`."""
    _check_scene(shapes, poses, "penetration")
    _check_margin_and_smoothing("penetration", margin, None)
    low, high = _inflated_aabbs(shapes, poses, margin)
    capacity = max(16, 4 * low.shape[0])
    while True:
        found = _counted_broad_phase(low, high, groups, masks, body_ids, capacity=capacity)
        if int(found.overflow) == 0:
            return int(found.count)
        capacity = max(2 * capacity, int(found.count))


@functools.partial(jax.jit, static_argnames=("capacity",))
def _counted_broad_phase(low, high, groups, masks, body_ids, *, capacity):
    return broad_phase(low, high, capacity=capacity, groups=groups, masks=masks,
                       body_ids=body_ids)

