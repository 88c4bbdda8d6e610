"""Broad phase: world AABBs and the hashed grid, against brute-force NumPy AABB tests."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from harness import FAST_COMPILE
from scipy.spatial.transform import Rotation

import jaxsat


def _brute_force_pairs(low, high, keep=None):
    """Set of (i, j), i < j, whose boxes overlap (touching counts), by NumPy over all pairs."""
    low, high = np.asarray(low, np.float64), np.asarray(high, np.float64)
    overlap = np.all((low[:, None] <= high[None]) & (low[None] <= high[:, None]), axis=-1)
    if keep is not None:
        overlap &= keep
    rows, cols = np.nonzero(np.triu(overlap, 1))
    return set(zip(rows.tolist(), cols.tolist(), strict=True))


def _found(result):
    pairs = np.asarray(result.pairs)[np.asarray(result.valid)]
    as_set = set(map(tuple, pairs.tolist()))
    assert len(as_set) == len(pairs), "a pair was reported twice"
    return as_set


def _random_boxes(rng, count, dim, world, size_range, dtype=np.float64):
    centres = rng.uniform(0, world, (count, dim))
    half = rng.uniform(*size_range, (count, dim)) / 2
    return (centres - half).astype(dtype), (centres + half).astype(dtype)


# XLA's cheaper build: the broad phase sorts and compares, its outputs are integers and flags
# that no optimisation level changes, and every capacity compiles anew (half the file's time).
_jit_broad_phase = jax.jit(jaxsat.broad_phase, static_argnames=("capacity", "candidate_capacity"),
                           compiler_options=FAST_COMPILE)


@pytest.mark.slow
@pytest.mark.parametrize("dim,dtype,count,world,sizes", [
    (3, np.float64, 1, 1.0, (0.1, 0.2)),       # a single box: no pairs
    (2, np.float32, 2, 1.0, (0.9, 1.0)),       # two boxes that surely overlap
    (2, np.float64, 300, 10.0, (0.1, 1.0)),    # moderately dense, mixed sizes
    (3, np.float32, 300, 10.0, (0.1, 1.0)),
    (3, np.float32, 400, 1e4, (1e-3, 1e-2)),   # very sparse: tiny boxes in a huge world
    (2, np.float64, 200, 1.0, (0.5, 0.6)),     # dense: almost every pair overlaps
])
def test_broad_phase_equals_brute_force(dim, dtype, count, world, sizes):
    rng = np.random.default_rng(count + dim)
    low, high = _random_boxes(rng, count, dim, world, sizes, dtype)
    truth = _brute_force_pairs(low, high)
    result = _jit_broad_phase(jnp.asarray(low), jnp.asarray(high), capacity=max(len(truth), 1))
    assert int(result.overflow) == 0 and int(result.count) == len(truth)
    assert _found(result) == truth
    assert all(i < j for i, j in _found(result))


@pytest.mark.slow
def test_broad_phase_coincident_boxes_and_one_huge_box():
    """Degenerate layouts: every box in one cell, and one box spanning the world."""
    low = np.zeros((50, 3))
    high = np.ones((50, 3))
    result = _jit_broad_phase(jnp.asarray(low), jnp.asarray(high), capacity=50 * 49 // 2)
    assert _found(result) == _brute_force_pairs(low, high) and int(result.overflow) == 0
    rng = np.random.default_rng(3)
    low, high = _random_boxes(rng, 100, 3, 20.0, (0.2, 0.5))
    low[0], high[0] = -1.0, 21.0
    truth = _brute_force_pairs(low, high)
    result = _jit_broad_phase(jnp.asarray(low), jnp.asarray(high), capacity=len(truth))
    assert _found(result) == truth


@pytest.mark.slow
def test_touching_boxes_count_as_overlapping():
    low = jnp.array([[0.0, 0.0], [1.0, 0.0], [2.5, 0.0]])
    high = low + 1.0
    assert _found(_jit_broad_phase(low, high, capacity=4)) == {(0, 1)}


@pytest.mark.slow
def test_overflow_is_counted_never_silent():
    rng = np.random.default_rng(7)
    low, high = _random_boxes(rng, 300, 3, 5.0, (0.3, 1.0))
    truth = _brute_force_pairs(low, high)
    assert len(truth) > 20
    small = _jit_broad_phase(jnp.asarray(low), jnp.asarray(high), capacity=20,
                             candidate_capacity=14 * 300 * 300)
    assert int(small.count) == len(truth) and int(small.overflow) == len(truth) - 20
    assert _found(small) <= truth and len(_found(small)) == 20
    # Too few grid-candidate slots: the unexamined candidates are counted as overflow.
    starved = _jit_broad_phase(jnp.asarray(low), jnp.asarray(high), capacity=len(truth),
                               candidate_capacity=len(truth))
    assert int(starved.overflow) > 0 and int(starved.count) >= len(truth)
    assert _found(starved) <= truth


@pytest.mark.slow
@pytest.mark.parametrize("dim", [2, 3])
def test_filters_equal_brute_force(dim):
    rng = np.random.default_rng(11)
    count = 250
    low, high = _random_boxes(rng, count, dim, 6.0, (0.2, 1.0))
    groups = rng.choice([1, 2, 4], count).astype(np.int32)
    masks = rng.choice([7, 6, 5, 1], count).astype(np.int32)
    body_ids = rng.integers(0, 60, count).astype(np.int32)
    keep = (((groups[:, None] & masks[None]) != 0) & ((groups[None] & masks[:, None]) != 0)
            & (body_ids[:, None] != body_ids[None]))
    truth = _brute_force_pairs(low, high, keep)
    result = _jit_broad_phase(jnp.asarray(low), jnp.asarray(high), capacity=len(truth),
                              groups=jnp.asarray(groups), masks=jnp.asarray(masks),
                              body_ids=jnp.asarray(body_ids))
    assert _found(result) == truth and int(result.count) == len(truth)


@pytest.mark.slow
def test_broad_phase_vmaps_over_scenes():
    rng = np.random.default_rng(5)
    scenes = [_random_boxes(rng, 120, 3, 4.0, (0.2, 0.8)) for _ in range(3)]
    low = jnp.asarray(np.stack([s[0] for s in scenes]))
    high = jnp.asarray(np.stack([s[1] for s in scenes]))
    batched = jax.jit(jax.vmap(functools.partial(jaxsat.broad_phase, capacity=2000)))(low, high)
    for index, (scene_low, scene_high) in enumerate(scenes):
        one = jax.tree.map(lambda x, k=index: x[k], batched)
        assert _found(one) == _brute_force_pairs(scene_low, scene_high)


@pytest.mark.slow
@pytest.mark.parametrize("dim", [2, 3])
def test_world_aabbs_match_numpy(dim):
    rng = np.random.default_rng(dim)
    if dim == 2:
        shapes = [jaxsat.regular_polygon(n, r, max_vertices=8) for n, r in ((3, 1.0), (8, 0.5))]
        angles = rng.uniform(-np.pi, np.pi, 2)
        rotations = [Rotation.from_euler("z", a).as_matrix()[:2, :2] for a in angles]
        poses = jax.vmap(jaxsat.pose2)(*jnp.asarray(rng.normal(size=(2, 2)).T), angles)
    else:
        shapes = [jaxsat.box([1.0, 0.5, 0.2]), jaxsat.polyhedron(rng.normal(size=(12, 3)))]
        quaternions = rng.normal(size=(2, 4))
        rotations = [Rotation.from_quat(q[[1, 2, 3, 0]]).as_matrix() for q in quaternions]
        poses = jax.vmap(jaxsat.pose3)(jnp.asarray(rng.normal(size=(2, 3))), quaternions)
    low, high = jaxsat.world_aabbs(jaxsat.stack(shapes), poses)
    for k, shape in enumerate(shapes):
        real = np.asarray(shape.vertices)[np.asarray(shape.vertex_mask)]
        world = real @ rotations[k].T + np.asarray(poses.translation[k])
        np.testing.assert_allclose(low[k], world.min(axis=0), atol=1e-12)
        np.testing.assert_allclose(high[k], world.max(axis=0), atol=1e-12)
    single = jaxsat.world_aabbs(shapes[0], jax.tree.map(lambda x: x[0], poses))
    np.testing.assert_allclose(single[0], low[0])


def test_broad_phase_rejects_bad_input():
    low = jnp.zeros((4, 3))
    with pytest.raises(ValueError, match="capacity"):
        jaxsat.broad_phase(low, low + 1, capacity=0)
    with pytest.raises(ValueError, match="capacity"):
        jaxsat.broad_phase(low, low + 1, capacity=2.5)
    with pytest.raises(ValueError, match=r"\(N, 2\) or \(N, 3\)"):
        jaxsat.broad_phase(jnp.zeros((4, 4)), jnp.ones((4, 4)), capacity=4)
    with pytest.raises(ValueError, match="both groups and masks"):
        jaxsat.broad_phase(low, low + 1, capacity=4, groups=jnp.ones(4, jnp.int32))
    with pytest.raises(ValueError, match="body_ids"):
        jaxsat.broad_phase(low, low + 1, capacity=4, body_ids=jnp.ones(3, jnp.int32))
    with pytest.raises(ValueError, match="body_ids"):
        jaxsat.broad_phase(low, low + 1, capacity=4, body_ids=jnp.ones(4))
    with pytest.raises(TypeError, match="Polytope"):
        jaxsat.world_aabbs(low, low)
