"""Batched one-pair queries in bounded memory: chunks of one vmap, optionally over devices.

`query_batch` and `query_pairs` apply any one-pair query (a, pose_a, b, pose_b) -> pytree,
such as `penetration`, `intersects` or `signed_distance`, to many pairs. Each call runs one
compiled program (cached per query object, argument structure, chunk size and devices) that

1. with devices: pads the batch to a multiple of the device count by repeating entry 0, shards
   it over a 1-D mesh (the other arguments are replicated) and trims the padding at the end;
2. on each device: loops (`jax.lax.fori_loop`) over chunks of `chunk_size` entries, each chunk
   one `jax.vmap` of the query written into the result in place. A chunk slices its entries
   (and `query_pairs` gathers their shapes and poses), so only one chunk's copies and
   intermediates exist at a time. The last chunk ends at the last entry and overlaps the one
   before, which spares padding the inputs and copying the results to trim them.

Each pair goes through the same vmapped computation whatever the chunk size and devices, and
the results equal those of one `jax.vmap` over all pairs up to rounding: XLA may compile a
query differently for different batch sizes (`signed_distance` in float32 differed by an ulp
between batches of 16 and 37 pairs; `penetration` and `intersects` matched exactly in the
tests). With a chunk size below each device's share, every device runs the very chunk program
that one device runs, and the results were bit-identical to one device's in the tests.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh
from jax.sharding import PartitionSpec as P

from jaxsat._poses import Pose

__all__ = ["query_batch", "query_pairs"]

PAIR_AXIS = "pairs"
"""Name of the mesh axis the pairs are sharded over."""

_ARGUMENT_NAMES = ("a", "pose_a", "b", "pose_b")

# jax.shard_map is public from jax 0.6; older releases (pyproject allows 0.4.30) have it in
# jax.experimental, where the replication check is called check_rep. The check is off because
# queries may hold constants that it would reject: `intersects` traces a lax.cond whose
# constant branch it reads as not varying over the devices.
if hasattr(jax, "shard_map"):
    _shard_map = functools.partial(jax.shard_map, check_vma=False)
else:  # pragma: no cover - depends on the installed jax
    from jax.experimental.shard_map import shard_map as _experimental_shard_map

    _shard_map = functools.partial(_experimental_shard_map, check_rep=False)


def query_batch(query: Callable, a, pose_a, b, pose_b, *, chunk_size: int | None = None,
                devices: int | Sequence[jax.Device] | None = None):
    """Apply a one-pair query to a batch of pairs, like `jax.vmap` with in_axes 0 or None.

    Args:
      query: any function (a, pose_a, b, pose_b) -> pytree of arrays, e.g. `jaxsat.penetration`,
        `jaxsat.intersects`, `jaxsat.signed_distance`. Bind keyword arguments with
        functools.partial, e.g. `functools.partial(jaxsat.signed_distance, smoothing=0.01)`;
        the compiled program is cached per query object, so build the partial once and reuse it.
      a: the first shapes (anything with a `batch_shape`, like `Polytope`). Each of a,
        pose_a, b and pose_b is either batched, with one leading axis of length N
        (`jaxsat.stack` for shapes), or unbatched and then shared by all N pairs. At least
        one must be batched.
      pose_a: the `Pose`s of a.
      b: the second shapes.
      pose_b: the `Pose`s of b.
      chunk_size: None runs one vmap over all N pairs. A positive int runs `jax.lax.map` over
        chunks of that many pairs, so that peak memory follows the chunk, not N; `2**14` is a
        good start on CPU (for 1e6 box pairs, `2**12` to `2**16` also ran faster than one vmap).
        At least N (per device) is the same as None. Static under jit.
      devices: None runs on the default device. An int k uses the first k of jax.devices(); a
        sequence of devices uses those. The N pairs are sharded over them (the shared arguments
        are replicated), each device running the chunks of its share. Static under jit.

    Returns:
      The query's pytree, every leaf with a leading axis of length N. N = 0 gives empty leaves
      of the right shapes and dtypes. With devices, the leaves are sharded over them when N is
      a multiple of their number, else replicated (JAX arrays cannot be sharded unevenly).

    Raises:
      TypeError: query not callable, an argument neither a shape nor a Pose, a chunk_size
        that is not None or an int, or devices that are not None, an int or jax devices.
      ValueError: more than one batch axis, batch lengths that differ, no batched argument,
        a chunk_size below 1, or a device count or list that does not fit.
    """
    _check_query(query)
    chunk_size, mesh = _check_chunk_size(chunk_size), _mesh(devices)
    arguments = (a, pose_a, b, pose_b)
    lengths = [_batch_length(arg, name)
               for arg, name in zip(arguments, _ARGUMENT_NAMES, strict=True)]
    size = _common_length(lengths)
    batched = tuple(length is not None for length in lengths)
    items = tuple(arg for arg, is_batched in zip(arguments, batched, strict=True) if is_batched)
    shared = tuple(arg for arg, is_batched in zip(arguments, batched, strict=True)
                   if not is_batched)
    return _map_items(_BatchQuery(query, batched), items, shared, size, chunk_size, mesh)


def query_pairs(query: Callable, shapes, poses: Pose, pairs, *, chunk_size: int | None = None,
                devices: int | Sequence[jax.Device] | None = None):
    """Apply a one-pair query to index pairs into one batch of shapes and poses.

    Returns query(shapes[i], poses[i], shapes[j], poses[j]) for every row (i, j) of `pairs`.
    Shapes and poses are gathered per chunk, so memory follows the chunk size, not the number
    of pairs P.

    Args:
      query: as in `query_batch` (use functools.partial for keyword arguments).
      shapes: a batch of N shapes, e.g. from `jaxsat.stack` (leading axis N).
      poses: a batch of N poses (translation (N, D), rotation (N, D, D)).
      pairs: (P, 2) integer array-like of indices into the N shapes; negative indices count
        from the end, as in NumPy. Out-of-range indices raise when `pairs` is concrete; under
        jit they cannot be checked and JAX clamps them.
      chunk_size: as in `query_batch`.
      devices: as in `query_batch`.

    Returns:
      The query's pytree, every leaf with a leading axis of length P (P = 0 gives empty leaves;
      with devices, sharded as in `query_batch`).

    Raises:
      ValueError: as in `query_batch`, and for `pairs` that is not a (P, 2) integer array or
        holds an index outside [-N, N), or shapes and poses that are not batched alike.
    """
    _check_query(query)
    chunk_size, mesh = _check_chunk_size(chunk_size), _mesh(devices)
    lengths = [_batch_length(shapes, "shapes"), _batch_length(poses, "poses")]
    if None in lengths:
        raise ValueError("query_pairs needs batched shapes and poses (a leading axis of length "
                         f"N); got batch lengths {lengths} for shapes, poses")
    count = _common_length(lengths)
    pairs = _check_pairs(pairs, count)
    return _map_items(_PairQuery(query), pairs, (shapes, poses), pairs.shape[0], chunk_size,
                      mesh)


# ----------------------------------------------------------------------- per-item functions


@dataclasses.dataclass(frozen=True)
class _BatchQuery:
    """One pair of `query_batch` from its batched items and shared arguments (hashable, so
    that it can be a static argument of the compiled program)."""

    query: Callable
    batched: tuple[bool, ...]
    """For each of (a, pose_a, b, pose_b): True if it comes from the batched items."""

    def __call__(self, items, shared):
        items, shared = iter(items), iter(shared)
        return self.query(*[next(items) if is_batched else next(shared)
                            for is_batched in self.batched])


@dataclasses.dataclass(frozen=True)
class _PairQuery:
    """One pair of `query_pairs`: gather both entries of an index pair, then query."""

    query: Callable

    def __call__(self, pair, shared):
        (shape_i, pose_i), (shape_j, pose_j) = _take(shared, pair[0]), _take(shared, pair[1])
        return self.query(shape_i, pose_i, shape_j, pose_j)


def _take(tree, index):
    return jax.tree.map(lambda leaf: leaf[index], tree)


# ----------------------------------------------------------------------- the mapped program


def _map_items(apply, items, shared, size: int, chunk_size: int | None, mesh: Mesh | None):
    """apply(item, shared) for each of the `size` entries along axis 0 of `items`."""
    if size == 0:
        return _empty_result(apply, items, shared)
    per_device = -(-size // (1 if mesh is None else mesh.size))
    if chunk_size is not None and chunk_size >= per_device:
        chunk_size = None  # one chunk is a plain vmap: share its compiled program
    try:
        hash(apply)
    except TypeError:  # an unhashable query cannot key the compile cache: trace it each call
        return _run(apply, items, shared, chunk_size=chunk_size, mesh=mesh)
    return _run_compiled(apply, items, shared, chunk_size=chunk_size, mesh=mesh)


def _run(apply, items, shared, *, chunk_size: int | None, mesh: Mesh | None):
    map_chunks = functools.partial(_map_chunks, apply, chunk_size=chunk_size)
    if mesh is None:
        return map_chunks(items, shared)
    size = _leading_length(items)
    sharded = _shard_map(map_chunks, mesh=mesh, in_specs=(P(PAIR_AXIS), P()),
                         out_specs=P(PAIR_AXIS))
    return _trim(sharded(_pad_to_multiple(items, mesh.size), shared), size)


_run_compiled = jax.jit(_run, static_argnames=("apply", "chunk_size", "mesh"))


def _map_chunks(apply, items, shared, *, chunk_size: int | None):
    """apply over every entry of `items` (on one device), `chunk_size` entries at a time."""
    size = _leading_length(items)
    vmapped = jax.vmap(apply, in_axes=(0, None))
    if chunk_size is None or size <= chunk_size:
        return vmapped(items, shared)

    def chunk_from(start):
        return vmapped(jax.tree.map(
            lambda leaf: jax.lax.dynamic_slice_in_dim(leaf, start, chunk_size), items), shared)

    def one_chunk(index, results):
        # The last chunk ends at the last entry, overlapping the one before: recomputing those
        # few entries spares padding the inputs and trimming (copying) the results.
        start = jnp.minimum(index * chunk_size, size - chunk_size)
        return jax.tree.map(lambda result, chunk: jax.lax.dynamic_update_slice_in_dim(
            result, chunk, start, 0), results, chunk_from(start))

    shapes = jax.eval_shape(chunk_from, 0)
    results = jax.tree.map(lambda leaf: jnp.zeros((size, *leaf.shape[1:]), leaf.dtype), shapes)
    return jax.lax.fori_loop(0, -(-size // chunk_size), one_chunk, results)


def _leading_length(items) -> int:
    return jax.tree.leaves(items)[0].shape[0]


def _trim(tree, size: int):
    return jax.tree.map(lambda leaf: leaf[:size], tree)


def _pad_to_multiple(items, multiple: int):
    """Pad axis 0 to a multiple of `multiple` by repeating entry 0 (the padding is trimmed)."""
    extra = -_leading_length(items) % multiple
    if extra == 0:
        return items
    return jax.tree.map(
        lambda leaf: jnp.concatenate([leaf, jnp.repeat(leaf[:1], extra, axis=0)]), items)


def _empty_result(apply, items, shared):
    """Zero-length leaves with the shapes and dtypes one item's result would have."""
    one_item = jax.tree.map(lambda leaf: jax.ShapeDtypeStruct(leaf.shape[1:], leaf.dtype), items)
    result = jax.eval_shape(apply, one_item, shared)
    return jax.tree.map(lambda leaf: jnp.zeros((0, *leaf.shape), leaf.dtype), result)


# ----------------------------------------------------------------------- argument checks


def _check_query(query) -> None:
    if not callable(query):
        raise TypeError("query must be a callable (a, pose_a, b, pose_b) -> pytree, got "
                         f"{type(query).__name__}; bind keyword arguments with functools.partial")


def _is_int(value) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _check_chunk_size(chunk_size) -> int | None:
    if chunk_size is None:
        return None
    if not _is_int(chunk_size):
        raise TypeError(f"chunk_size must be None or a positive int, got {chunk_size!r}")
    if chunk_size < 1:
        raise ValueError(f"chunk_size must be None or a positive int, got {chunk_size!r}")
    return int(chunk_size)


def _mesh(devices) -> Mesh | None:
    """The 1-D mesh over the requested devices, or None for the default device."""
    if devices is None:
        return None
    available = jax.devices()
    if _is_int(devices):
        if not 1 <= devices <= len(available):
            raise ValueError(f"devices must be between 1 and the {len(available)} available "
                             f"devices, got {devices}")
        return Mesh(np.array(available[: int(devices)]), (PAIR_AXIS,))
    if isinstance(devices, np.ndarray):  # e.g. an existing mesh's `devices`
        devices = list(devices.flat)
    if isinstance(devices, (str, bytes)) or not isinstance(devices, Sequence):
        raise TypeError("devices must be None, an int or a sequence of jax devices, got "
                         f"{type(devices).__name__}")
    chosen = list(devices)
    if not all(isinstance(device, jax.Device) for device in chosen):
        raise TypeError(f"devices must be a sequence of jax devices, got {devices!r}")
    if not chosen:
        raise ValueError("devices must not be empty")
    if len(set(chosen)) != len(chosen):
        raise ValueError(f"devices must not repeat a device, got {chosen}")
    return Mesh(np.array(chosen), (PAIR_AXIS,))


def _batch_shape(arg, name: str) -> tuple[int, ...]:
    if isinstance(arg, Pose):
        shape = arg.translation.shape[:-1]
        if arg.rotation.shape[:-2] != shape:
            raise ValueError(f"{name} has translation {arg.translation.shape} and rotation "
                             f"{arg.rotation.shape} with different batch shapes")
        return tuple(shape)
    if not hasattr(arg, "batch_shape"):
        raise TypeError(f"{name} must be a shape (with a batch_shape, like jaxsat.Polytope) or "
                         f"a jaxsat.Pose, got {type(arg).__name__}")
    return tuple(arg.batch_shape)


def _batch_length(arg, name: str) -> int | None:
    """N for an argument batched along one leading axis, None for an unbatched one."""
    shape = _batch_shape(arg, name)
    if len(shape) > 1:
        raise ValueError(f"{name} has batch shape {shape}; batched queries take one leading "
                         "batch axis (reshape to (N, ...) first)")
    if not shape:
        return None
    if any(jnp.ndim(leaf) == 0 or jnp.shape(leaf)[0] != shape[0]
           for leaf in jax.tree.leaves(arg)):
        raise ValueError(f"every array of {name} must have the leading batch axis {shape[0]}")
    return shape[0]


def _common_length(lengths: list[int | None]) -> int:
    found = {length for length in lengths if length is not None}
    if not found:
        raise ValueError("query_batch needs at least one batched argument (leading axis N); "
                         "for a single pair call the query directly")
    if len(found) > 1:
        raise ValueError(f"batched arguments must share one batch length, got {lengths} "
                         "(None: unbatched)")
    return found.pop()


def _check_pairs(pairs, count: int) -> jax.Array:
    """(P, 2) integer indices into `count` entries; their range is checked when concrete."""
    if not hasattr(pairs, "shape"):
        pairs = np.asarray(pairs)
    if pairs.ndim != 2 or pairs.shape[1] != 2 or not jnp.issubdtype(pairs.dtype, jnp.integer):
        raise ValueError("pairs must be a (P, 2) integer array, got shape "
                         f"{tuple(pairs.shape)} and dtype {pairs.dtype}")
    if not isinstance(pairs, jax.core.Tracer) and pairs.size:
        values = np.asarray(pairs)  # NumPy: an eager jnp.min would compile for every new P
        low, high = int(values.min()), int(values.max())
        if low < -count or high >= count:
            raise ValueError(f"pairs must index the {count} shapes (in [-{count}, {count})), "
                             f"got indices from {low} to {high}")
    return jnp.asarray(pairs)
