"""Broad phase: world AABBs and a hashed uniform grid that finds every overlapping AABB pair.

The grid's cell is at least as large as the largest AABB, and each box is filed under the cell
of its centre, so two overlapping boxes sit in the same or in adjacent cells. Each box looks in
its own cell and in half of its 3^D - 1 neighbours (the other half look back at it), so every
pair is found once. Cells are hashed into a table of static size (a sparse world needs no
memory for empty cells); a hash collision only adds a candidate that the exact cell check then
drops. The candidates are a ragged list (a count per box and neighbour cell); they are
enumerated into a fixed buffer through a prefix sum, tested for AABB overlap and the pair
filters, and the survivors are compacted into `capacity` slots. Everything has static shapes,
so the broad phase runs under `jax.jit`; what does not fit is counted, never dropped silently.
"""

from __future__ import annotations

import dataclasses
import itertools

import jax
import jax.numpy as jnp
import numpy as np

from jaxsat._kernels import total, where
from jaxsat._poses import Pose
from jaxsat._shapes import Polytope

__all__ = ["CandidatePairs", "broad_phase", "world_aabbs"]

_SATURATION = 2**30 - 1
"""Running counts saturate here so that int32 prefix sums never wrap around."""

_MAX_CELLS_PER_AXIS = 2**20
"""Cell coordinates stay below this, so float32 centres still give exact integer cells."""


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class CandidatePairs:
    """Pairs of shapes whose world AABBs overlap, in a fixed number of slots."""

    pairs: jax.Array
    """(capacity, 2) int32: shape indices (i, j) with i < j; unused slots hold (0, 0)."""
    valid: jax.Array
    """(capacity,) bool: True for the slots that hold a pair."""
    count: jax.Array
    """() int32: number of overlapping pairs found, including those that did not fit."""
    overflow: jax.Array
    """() int32: pairs (or unexamined grid candidates) that did not fit; 0 = complete."""
    non_finite: jax.Array
    """(N,) bool: box i has a NaN or infinite corner; it is in no pair."""


def world_aabbs(shapes: Polytope, poses: Pose) -> tuple[jax.Array, jax.Array]:
    """World-frame axis-aligned bounding boxes of posed shapes.

    Args:
      shapes: a Polytope, unbatched or stacked with leading batch axes (...).
      poses: poses with the same leading batch axes (...).

    Returns:
      (low, high), each (..., D): the exact AABBs of the posed vertices (padding repeats a
      real vertex, so it never widens a box), grown by the radius of rounded shapes.
    """
    if not isinstance(shapes, Polytope) or not isinstance(poses, Pose):
        raise TypeError("world_aabbs takes a jaxsat.Polytope and a jaxsat.Pose")
    pose_batch = poses.translation.shape[:-1]
    if shapes.batch_shape != pose_batch or shapes.dim != poses.dim:
        raise ValueError(f"shapes (batch {shapes.batch_shape}, {shapes.dim}D) and poses (batch "
                         f"{pose_batch}, {poses.dim}D) must have the same batch shape and dim")
    rotation, translation = poses.rotation, poses.translation
    # R v + t, spelled out per coordinate: a batched matmul of (V, D) by (D, D) is slow on CPU.
    world = jnp.stack([total(rotation[..., None, r, k] * shapes.vertices[..., k]
                             for k in range(shapes.dim)) for r in range(shapes.dim)], axis=-1)
    world = world + translation[..., None, :]
    low, high = world.min(axis=-2), world.max(axis=-2)
    if shapes.radius is None:
        return low, high
    radius = shapes.radius[..., None]
    return low - radius, high + radius


def _forward_offsets(dim: int) -> np.ndarray:
    """(S, D) int32: the own cell (0, ..., 0) and the neighbour offsets lexicographically > 0."""
    offsets = [o for o in itertools.product((-1, 0, 1), repeat=dim) if o > (0,) * dim]
    return np.array([(0,) * dim, *offsets], dtype=np.int32)


def _grid_cells(low, high):
    """Integer cell coordinates (N, D) of every box centre."""
    centres = (low + high) / 2
    origin = centres.min(axis=0)
    span = jnp.max(centres.max(axis=0) - origin)
    # Margins keep "|centre difference| <= cell" true after rounding; the cap on cells per axis
    # keeps coordinates exact integers in float32 however sparse the world is.
    cell = jnp.maximum(jnp.max(high - low) * 1.001, span / _MAX_CELLS_PER_AXIS)
    cell = jnp.maximum(cell, jnp.finfo(low.dtype).tiny)
    return jnp.floor((centres - origin) / cell).astype(jnp.int32)


def _cell_hash(cells, table_size: int):
    """Bucket in [0, table_size) of each cell (..., D); table_size is a power of 2."""
    primes = (73856093, 19349663, 83492791)
    key = jnp.zeros(cells.shape[:-1], jnp.uint32)
    for k in range(cells.shape[-1]):
        key = (key ^ cells[..., k].astype(jnp.uint32)) * jnp.uint32(primes[k])
    key = key ^ (key >> 15)
    return (key & jnp.uint32(table_size - 1)).astype(jnp.int32)


def _saturating_cumsum(counts):
    """Inclusive prefix sum of non-negative int32 counts, saturating at _SATURATION."""
    add = lambda x, y: jnp.minimum(x + y, _SATURATION)  # noqa: E731  both <= 2^30 - 1: no wrap
    return jax.lax.associative_scan(add, jnp.minimum(counts, _SATURATION))


def _grid_candidates(low, high):
    """For each box (in sorted order) and each forward offset: where its candidates start in
    the sorted order and how many there are. Returns (order, cells, starts, counts), the last
    two (N, S)."""
    num_boxes = low.shape[0]
    # A sparse table keeps hash collisions (false candidates from other cells) rare.
    table_size = 1 << max(int(8 * num_boxes - 1).bit_length(), 6)
    cells = _grid_cells(low, high)
    buckets = _cell_hash(cells, table_size)
    order = jnp.argsort(buckets).astype(jnp.int32)
    cells, buckets = cells[order], buckets[order]
    bucket_sizes = jnp.zeros(table_size, jnp.int32).at[buckets].add(1)
    bucket_ends = jnp.cumsum(bucket_sizes)
    offsets = jnp.asarray(_forward_offsets(low.shape[1]))
    neighbours = _cell_hash(cells[:, None, :] + offsets[None], table_size)
    starts = bucket_ends[neighbours] - bucket_sizes[neighbours]
    counts = bucket_sizes[neighbours]
    # In its own cell a box pairs only with the boxes after it in the sorted order.
    positions = jnp.arange(num_boxes, dtype=jnp.int32)
    starts = starts.at[:, 0].set(positions + 1)
    counts = counts.at[:, 0].set(bucket_ends[buckets] - positions - 1)
    return order, cells, starts, counts


def _pair_filter(i, j, groups, masks, body_ids):
    """Collision-group and body filters of pairs (i, j)."""
    keep = jnp.ones(i.shape, bool)
    if groups is not None:
        keep &= ((groups[i] & masks[j]) != 0) & ((groups[j] & masks[i]) != 0)
    if body_ids is not None:
        keep &= body_ids[i] != body_ids[j]
    return keep


def _enumerate(low, high, candidate_capacity: int):
    """Every grid candidate pair (sorted positions p < q or neighbour cells), in a fixed
    buffer: returns (p, q, real (C,) bool, total candidates (saturated))."""
    order, cells, starts, counts = _grid_candidates(low, high)
    num_offsets = counts.shape[1]
    ends = _saturating_cumsum(counts.reshape(-1))
    slots = jnp.arange(candidate_capacity, dtype=jnp.int32)
    segment = jnp.minimum(jnp.searchsorted(ends, slots, side="right"), ends.shape[0] - 1)
    first_slot = ends[segment] - counts.reshape(-1)[segment]
    p = segment // num_offsets
    q = jnp.minimum(starts.reshape(-1)[segment] + slots - first_slot, low.shape[0] - 1)
    offset = jnp.asarray(_forward_offsets(low.shape[1]))[segment % num_offsets]
    # The bucket holds every cell that hashes there; keep the one the offset points at.
    same_cell = jnp.all(cells[q] == cells[p] + offset, axis=-1)
    real = (slots < ends[-1]) & same_cell
    return order[p], order[q], real, ends[-1]


def _compact(values, keep, capacity: int, fill):
    """The entries of `values` (C, ...) where `keep`, moved to the front of `capacity` slots."""
    target = where(keep, jnp.cumsum(keep) - 1, capacity)
    empty = jnp.full((capacity, *values.shape[1:]), fill, values.dtype)
    return empty.at[target].set(values, mode="drop")


def broad_phase(low: jax.Array, high: jax.Array, *, capacity: int,
                candidate_capacity: int | None = None, groups: jax.Array | None = None,
                masks: jax.Array | None = None, body_ids: jax.Array | None = None
                ) -> CandidatePairs:
    """Every pair of boxes whose AABBs overlap (touching counts), in `capacity` slots.

    Args:
      low: (N, D) lower AABB corners, D = 2 or 3 (e.g. from `world_aabbs`).
      high: (N, D) upper AABB corners.
      capacity: static number of output slots.
      candidate_capacity: static size of the grid-candidate buffer (pairs in the same or
        adjacent cells, before the AABB test); default 8 * capacity + 16 * N.
      groups: (N,) integer bit masks (physics-engine collision filtering): i and j pair
        only if groups[i] & masks[j] and groups[j] & masks[i] are both non-zero. Give both
        groups and masks, or neither.
      masks: (N,) integer bit masks, see `groups`.
      body_ids: (N,) integers: shapes with equal ids never pair (parts of one rigid body, or
        static shapes, which never move relative to each other).

    Returns:
      CandidatePairs. `overflow` > 0 means some pairs are missing: raise `capacity` (or
      `candidate_capacity`). The grid cell is the largest AABB's size, so one huge shape
      makes the grid coarse; give such shapes (floors, walls) their own query. A box with a
      NaN or infinite corner pairs with nothing, and the other boxes pair as they would
      without it.
    """
    low, high = jnp.asarray(low), jnp.asarray(high)
    _check_broad_phase(low, high, capacity, candidate_capacity, groups, masks, body_ids)
    if candidate_capacity is None:
        candidate_capacity = 8 * capacity + 16 * low.shape[0]
    # A NaN corner would make the grid's cell size and origin NaN and send every box into one
    # cell: such boxes become points on a finite box's corner, which leave the grid as it is.
    finite = jnp.all(jnp.isfinite(low) & jnp.isfinite(high), axis=-1)
    anchor = low[jnp.argmax(finite)]
    anchor = where(jnp.all(jnp.isfinite(anchor)), anchor, jnp.zeros_like(anchor))
    low, high = (where(finite[:, None], corner, anchor) for corner in (low, high))
    i, j, real, candidates = _enumerate(low, high, candidate_capacity)
    overlap = jnp.all((low[i] <= high[j]) & (low[j] <= high[i]), axis=-1)
    keep = real & overlap & finite[i] & finite[j] & _pair_filter(i, j, groups, masks, body_ids)
    pairs = jnp.stack([jnp.minimum(i, j), jnp.maximum(i, j)], axis=-1)
    count = jnp.sum(keep, dtype=jnp.int32)
    unexamined = jnp.maximum(candidates - candidate_capacity, 0)
    return CandidatePairs(pairs=_compact(pairs, keep, capacity, 0),
                          valid=jnp.arange(capacity, dtype=jnp.int32) < count,
                          count=count + unexamined,
                          overflow=jnp.maximum(count - capacity, 0) + unexamined,
                          non_finite=~finite)


def _check_broad_phase(low, high, capacity, candidate_capacity, groups, masks, body_ids):
    if low.ndim != 2 or low.shape != high.shape or low.shape[1] not in (2, 3):
        raise ValueError(f"low and high must both be (N, 2) or (N, 3), got {low.shape} and "
                         f"{high.shape}")
    if not jnp.issubdtype(low.dtype, jnp.floating) or low.shape[0] < 1:
        raise ValueError("low and high must be float arrays with at least one box")
    for name, value in (("capacity", capacity), ("candidate_capacity", candidate_capacity)):
        if value is not None and (not isinstance(value, int | np.integer) or value < 1):
            raise ValueError(f"{name} must be a positive int, got {value!r}")
    if (groups is None) != (masks is None):
        raise ValueError("give both groups and masks, or neither")
    for name, value in (("groups", groups), ("masks", masks), ("body_ids", body_ids)):
        if value is not None and (jnp.shape(value) != low.shape[:1]
                                  or not jnp.issubdtype(jnp.asarray(value).dtype, jnp.integer)):
            raise ValueError(f"{name} must be an integer array of shape ({low.shape[0]},), "
                             f"got {jnp.shape(value)} {jnp.asarray(value).dtype}")
