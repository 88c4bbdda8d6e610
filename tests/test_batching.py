"""Tests for jaxsat.query_batch and jaxsat.query_pairs (chunked and sharded batched queries).

The oracle is a plain `jax.vmap` of the same one-pair query (the query itself is tested against
SciPy elsewhere): chunking and sharding must not change what is computed. Every 2D scene pads
its polygons to 6 vertices and every 3D scene holds boxes, so equal batch sizes share compiled
programs across tests; compiling dominates the run time. The multi-device checks run in one
subprocess with 4 CPU devices (see multidevice.py).
"""

from __future__ import annotations

import functools
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from multidevice import run_on_devices
from scipy.spatial.transform import Rotation

import jaxsat

CHUNK = 16

SMOOTH_DISTANCE = functools.partial(jaxsat.signed_distance, smoothing=0.05)
"""A query with a keyword argument, bound with functools.partial as the docs say."""


def _scene(dim: int, count: int, dtype, seed: int = 0):
    """`count` random shapes (stacked) and poses in a 2 x 2 (x 2) box, so that many pairs of two
    scenes overlap and many do not. 2D: boxes and regular polygons padded to 6 vertices; 3D:
    boxes. Poses are built in NumPy (eager JAX ops would compile one by one)."""
    rng = np.random.default_rng(seed)
    if dim == 2:
        shapes = [jaxsat.box(rng.uniform(0.2, 1.0, 2), max_vertices=6, dtype=dtype)
                  if index % 2 else
                  jaxsat.regular_polygon(int(rng.integers(3, 7)), rng.uniform(0.3, 1.0),
                                         max_vertices=6, dtype=dtype)
                  for index in range(count)]
        cos, sin = np.cos(angles := rng.uniform(-np.pi, np.pi, count)), np.sin(angles)
        rotations = np.stack([np.stack([cos, -sin], -1), np.stack([sin, cos], -1)], -2)
    else:
        shapes = [jaxsat.box(rng.uniform(0.2, 1.0, 3), dtype=dtype) for _ in range(count)]
        rotations = Rotation.random(count, random_state=rng).as_matrix()
    translations = rng.uniform(-1.0, 1.0, (count, dim))
    poses = jaxsat.Pose(jnp.asarray(translations, dtype), jnp.asarray(rotations, dtype))
    return jaxsat.stack(shapes), poses


def _batch(dim: int, count: int, dtype):
    """(a, pose_a, b, pose_b), each batched with `count` entries."""
    return (*_scene(dim, count, dtype, seed=1), *_scene(dim, count, dtype, seed=2))


def _entry(tree, index):
    return jax.tree.map(lambda leaf: leaf[index], tree)


def _assert_same(actual, expected, exact: bool = True):
    """Same tree, shapes and dtypes; values bit-identical, or within a few ulps (XLA may
    round a query differently for different compiled batch sizes)."""
    assert jax.tree.structure(actual) == jax.tree.structure(expected)
    for got, want in zip(jax.tree.leaves(actual), jax.tree.leaves(expected), strict=True):
        assert got.shape == want.shape and got.dtype == want.dtype
        if exact:
            np.testing.assert_array_equal(got, want)
        else:
            tolerance = 8 * np.finfo(want.dtype).eps
            np.testing.assert_allclose(got, want, rtol=tolerance, atol=tolerance)


@pytest.mark.slow
@pytest.mark.parametrize("query, dim, dtype, exact", [
    pytest.param(jaxsat.penetration, 2, np.float64, True, id="penetration-2d-float64"),
    pytest.param(jaxsat.penetration, 3, np.float32, True, id="penetration-3d-float32"),
    pytest.param(jaxsat.intersects, 3, np.float64, True, id="intersects-3d-float64"),
    pytest.param(jaxsat.signed_distance, 2, np.float32, False, id="signed_distance-2d-float32"),
    pytest.param(SMOOTH_DISTANCE, 3, np.float64, False, id="smooth_distance-3d-float64"),
])
def test_chunked_equals_unchunked(query, dim, dtype, exact):
    """37 pairs in chunks of 16: two chunks, then a third that overlaps the second by 11
    pairs to end at the last one. (intersects in 2D is in
    test_mixed_batched_and_shared_arguments.)"""
    pairs = _batch(dim, 37, dtype)
    whole = jaxsat.query_batch(query, *pairs)
    _assert_same(jaxsat.query_batch(query, *pairs, chunk_size=CHUNK), whole, exact)
    expected_dtype = bool if query is jaxsat.intersects else dtype
    assert all(leaf.dtype == expected_dtype and leaf.shape[0] == 37
               for leaf in jax.tree.leaves(whole))


@pytest.mark.parametrize("count", [5, 37])
def test_matches_vmap_for_batch_sizes(count):
    """Fewer pairs than one chunk (one plain vmap) and a last chunk that overlaps."""
    pairs = _batch(2, count, np.float64)
    expected = jax.jit(jax.vmap(jaxsat.penetration))(*pairs)
    _assert_same(jaxsat.query_batch(jaxsat.penetration, *pairs), expected)
    _assert_same(jaxsat.query_batch(jaxsat.penetration, *pairs, chunk_size=CHUNK), expected)


def _depth_and_hit(a, pose_a, b, pose_b):
    """A custom query returning a dict (any pytree works)."""
    return {"depth": jaxsat.penetration(a, pose_a, b, pose_b).depth,
            "hit": jaxsat.intersects(a, pose_a, b, pose_b)}


@pytest.mark.slow
def test_mixed_batched_and_shared_arguments():
    """Unbatched arguments are shared by all pairs, like vmap's in_axes=None."""
    shapes, poses = _scene(2, 21, np.float32, seed=3)
    one_shape, one_pose = _entry(shapes, 4), _entry(poses, 7)
    # a and pose_b batched, pose_a and b shared.
    expected = jax.jit(jax.vmap(_depth_and_hit, in_axes=(0, None, None, 0)))(
        shapes, one_pose, one_shape, poses)
    got = jaxsat.query_batch(_depth_and_hit, shapes, one_pose, one_shape, poses, chunk_size=8)
    _assert_same(got, expected)
    # Only pose_b batched: one shape swept through many poses.
    expected = jax.jit(jax.vmap(jaxsat.penetration, in_axes=(None, None, None, 0)))(
        one_shape, one_pose, one_shape, poses)
    got = jaxsat.query_batch(jaxsat.penetration, one_shape, one_pose, one_shape, poses)
    _assert_same(got, expected)


@pytest.mark.slow
def test_query_pairs_matches_vmap_over_gathered_shapes():
    """48 pairs: three whole chunks of 16 (the query_batch tests have overlapping ones)."""
    shapes, poses = _scene(2, 12, np.float32, seed=4)
    pairs = np.random.default_rng(5).integers(0, 12, (48, 2))
    first, second = _entry((shapes, poses), pairs[:, 0]), _entry((shapes, poses), pairs[:, 1])
    expected = jax.jit(jax.vmap(jaxsat.penetration))(*first, *second)
    _assert_same(jaxsat.query_pairs(jaxsat.penetration, shapes, poses, pairs), expected)
    chunked = jaxsat.query_pairs(jaxsat.penetration, shapes, poses, pairs, chunk_size=CHUNK)
    _assert_same(chunked, expected)
    # Negative indices count from the end, as in NumPy.
    _assert_same(jaxsat.query_pairs(jaxsat.penetration, shapes, poses, pairs - 12,
                                     chunk_size=CHUNK), expected)


@pytest.mark.slow
def test_inside_jit():
    """Under jit (chunk_size static) both functions give the eager results (the eager
    programs are those of the tests above, already compiled)."""
    pairs = _batch(2, 37, np.float64)
    shapes, poses = _scene(2, 12, np.float32, seed=4)
    indices = jnp.asarray(np.random.default_rng(5).integers(0, 12, (48, 2)))

    @jax.jit
    def both(pairs, shapes, poses, indices):
        return (jaxsat.query_batch(jaxsat.penetration, *pairs, chunk_size=CHUNK),
                jaxsat.query_pairs(jaxsat.penetration, shapes, poses, indices,
                                   chunk_size=CHUNK))

    batch, by_index = both(pairs, shapes, poses, indices)
    _assert_same(batch, jaxsat.query_batch(jaxsat.penetration, *pairs, chunk_size=CHUNK))
    _assert_same(by_index, jaxsat.query_pairs(jaxsat.penetration, shapes, poses, indices,
                                              chunk_size=CHUNK))


def _translation_dot(a, pose_a, b, pose_b):
    """A query whose gradient is known: d/d t_a (t_a . t_b) = t_b."""
    del a, b
    return jnp.dot(pose_a.translation, pose_b.translation)


def test_gradient_through_chunks():
    """Reverse mode through the chunk loop, whose last chunk overlaps the one before: the
    overlapped pairs must count once. (A trivial query keeps the compile short.)"""
    a, pose_a, b, pose_b = _batch(2, 37, np.float64)

    def total(translations):
        moved = jaxsat.Pose(translations, pose_a.rotation)
        return jnp.sum(jaxsat.query_batch(_translation_dot, a, moved, b, pose_b,
                                          chunk_size=CHUNK))

    np.testing.assert_array_equal(jax.grad(total)(pose_a.translation), pose_b.translation)


class _UnhashableQuery:
    """A callable that cannot key jit's cache; query_batch then traces it on every call."""

    __hash__ = None

    def __call__(self, a, pose_a, b, pose_b):
        return jaxsat.penetration(a, pose_a, b, pose_b)


def test_unhashable_query():
    pairs = _batch(2, 37, np.float64)
    expected = jaxsat.query_batch(jaxsat.penetration, *pairs, chunk_size=CHUNK)
    _assert_same(jaxsat.query_batch(_UnhashableQuery(), *pairs, chunk_size=CHUNK), expected)


def test_empty_batches():
    """P = 0 (and N = 0) give empty results of the right shapes and dtypes, compiling nothing."""
    shapes, poses = _scene(3, 4, np.float32)
    no_pairs = np.zeros((0, 2), np.int32)
    hits = jaxsat.query_pairs(jaxsat.intersects, shapes, poses, no_pairs, chunk_size=8)
    assert hits.shape == (0,) and hits.dtype == bool
    none = _entry((shapes, poses), slice(0, 0))
    result = jaxsat.query_batch(jaxsat.penetration, *none, *none)
    assert result.depth.shape == (0,) and result.normal.shape == (0, 3)
    assert result.normal.dtype == np.float32


def test_vmap_over_no_pairs_fails_in_jax_as_the_readme_says():
    """Inside a `jax.jit`, `jax.vmap` of a query over 0 pairs raises JAX's IndexError (its
    checkify batching rule reads a batched check's first entry), which README.md states next
    to the advice to use `query_batch` there. When a JAX release lifts it, this fails: update
    the README. An eager `jax.vmap` runs the query's own jit, without the named checks, and
    returns empty results."""
    shapes, poses = _scene(3, 4, np.float32)
    none = _entry((shapes, poses), slice(0, 0))
    with pytest.raises(IndexError, match="size 0"):
        jax.jit(jax.vmap(jaxsat.penetration))(*none, *none)
    empty = jax.vmap(jaxsat.penetration)(*none, *none)
    assert empty.depth.shape == (0,) and empty.normal.shape == (0, 3)
    assert "a batch of 0 pairs fails under\n  `jax.vmap`" in (
        pathlib.Path(__file__).resolve().parents[1] / "README.md").read_text()


@pytest.fixture(scope="module")
def bad():
    """Arguments for the ValueError cases (small 2D float64 batches of 4)."""
    shapes, poses = _scene(2, 4, np.float64)
    three, _ = _scene(2, 3, np.float64)
    one_shape, one_pose = _entry(shapes, 0), _entry(poses, 0)
    two_axes = jax.tree.map(lambda leaf: leaf.reshape(2, 2, *leaf.shape[1:]), shapes)
    return dict(shapes=shapes, poses=poses, three=three, one_shape=one_shape,
                one_pose=one_pose, two_axes=two_axes, pairs=np.array([[0, 1], [2, 3]]),
                half_pose=jaxsat.Pose(poses.translation, one_pose.rotation))


def _batch_call(*names, query=jaxsat.penetration, **options):
    return lambda bad: jaxsat.query_batch(query, *(bad[name] for name in names), **options)


def _pairs_call(shapes="shapes", poses="poses", pairs=None, query=jaxsat.penetration,
                **options):
    return lambda bad: jaxsat.query_pairs(query, bad[shapes], bad[poses],
                                          bad["pairs"] if pairs is None else pairs, **options)


ALL_BATCHED = ("shapes", "poses", "shapes", "poses")
BAD_CALLS = {
    "query not callable": _batch_call(*ALL_BATCHED, query="penetration"),
    "query_pairs query not callable": _pairs_call(query=None),
    "chunk_size 0": _batch_call(*ALL_BATCHED, chunk_size=0),
    "chunk_size float": _batch_call(*ALL_BATCHED, chunk_size=2.0),
    "chunk_size bool": _pairs_call(chunk_size=True),
    "devices 0": _batch_call(*ALL_BATCHED, devices=0),
    "too many devices": _pairs_call(devices=len(jax.devices()) + 1),
    "no devices": _pairs_call(devices=[]),
    "devices not devices": _pairs_call(devices=["cpu"]),
    "repeated device": _pairs_call(devices=[jax.devices()[0]] * 2),
    "devices a string": _pairs_call(devices="cpu"),
    "no batched argument": _batch_call("one_shape", "one_pose", "one_shape", "one_pose"),
    "batch lengths differ": _batch_call("shapes", "poses", "three", "one_pose"),
    "two batch axes": _batch_call("two_axes", "one_pose", "one_shape", "one_pose"),
    "pose batch shapes differ": _batch_call("shapes", "half_pose", "shapes", "poses"),
    "argument not a shape": _batch_call("pairs", "poses", "shapes", "poses"),
    "pairs 1-D": _pairs_call(pairs=np.array([0, 1])),
    "pairs (P, 3)": _pairs_call(pairs=np.zeros((2, 3), int)),
    "pairs float": _pairs_call(pairs=np.zeros((2, 2))),
    "pairs out of range": _pairs_call(pairs=np.array([[0, 4]])),
    "pairs below -N": _pairs_call(pairs=np.array([[-5, 0]])),
    "unbatched shapes": _pairs_call(shapes="one_shape"),
    "unbatched poses": _pairs_call(poses="one_pose"),
    "shapes and poses differ": _pairs_call(shapes="three"),
}


WRONG_TYPES = {"query not callable", "query_pairs query not callable", "chunk_size float",
               "chunk_size bool", "devices not devices", "devices a string",
               "argument not a shape"}


@pytest.mark.parametrize("name", BAD_CALLS)
def test_bad_arguments_raise(name, bad):
    """TypeError for an argument of the wrong type, ValueError for a bad value."""
    with pytest.raises(TypeError if name in WRONG_TYPES else ValueError):
        BAD_CALLS[name](bad)


_SHARDED_SNIPPET = """
import numpy as np
import jax
import jaxsat
from test_batching import _batch, _scene, _assert_same

query = jaxsat.penetration
pairs = _batch(2, 37, np.float64)  # 37 = 4 x 10 - 3: padded to 40 over 4 devices
for chunk_size in (None, 8):  # 8: two chunks of the 10 per device, overlapping by 6
    one = jaxsat.query_batch(query, *pairs, chunk_size=chunk_size)
    four = jaxsat.query_batch(query, *pairs, chunk_size=chunk_size, devices=4)
    _assert_same(four, one)

shapes, poses = _scene(2, 12, np.float32, seed=4)
rng = np.random.default_rng(5)
for count, chunk_size in ((51, None), (52, 8)):  # 52 = 4 x 13: a sharded result; 13 = 8 + 5
    indices = rng.integers(0, 12, (count, 2))
    one = jaxsat.query_pairs(query, shapes, poses, indices, chunk_size=chunk_size)
    four = jaxsat.query_pairs(query, shapes, poses, indices, chunk_size=chunk_size,
                              devices=jax.devices())
    _assert_same(four, one)
assert len(four.depth.sharding.device_set) == 4, four.depth.sharding

under_jit = jax.jit(lambda indices: jaxsat.query_pairs(query, shapes, poses, indices,
                                                       chunk_size=8, devices=4))(indices)
_assert_same(under_jit, one)
print("sharded ok")
"""


@pytest.mark.slow
def test_sharded_over_four_devices_matches_one():
    """4 CPU devices give bit-identical results to 1, for both functions, with and without
    chunks, for pair counts that 4 does and does not divide, eagerly and under jit."""
    assert "sharded ok" in run_on_devices(_SHARDED_SNIPPET, num_devices=4)
