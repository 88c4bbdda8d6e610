"""Scene queries: `collide` must equal the brute-force all-pairs narrow phase."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from harness import FAST_COMPILE

import jaxsat


def _scene_3d(rng, count, kind, world, dtype=np.float64):
    """`count` random boxes or 12-point hulls (sizes 0.2 to 1) in a cube of side `world`."""
    if kind == "boxes":
        shapes = [jaxsat.box(rng.uniform(0.1, 0.5, 3), dtype=dtype) for _ in range(count)]
    else:
        shapes = [jaxsat.polyhedron(rng.normal(size=(12, 3)) * rng.uniform(0.1, 0.3),
                                    max_vertices=12, dtype=dtype) for _ in range(count)]
    positions = rng.uniform(0, world, (count, 3)).astype(dtype)
    poses = jax.vmap(jaxsat.pose3)(jnp.asarray(positions), jnp.asarray(rng.normal(size=(count, 4))
                                                                        .astype(dtype)))
    return jaxsat.stack(shapes), poses


def _scene_2d(rng, count, world, dtype=np.float64):
    """`count` random regular polygons (3 to 8 sides) padded to 8 vertices."""
    shapes = [jaxsat.regular_polygon(int(rng.integers(3, 9)), rng.uniform(0.1, 0.5), 8,
                                     dtype=dtype) for _ in range(count)]
    xy = rng.uniform(0, world, (count, 2)).astype(dtype)
    angles = rng.uniform(-np.pi, np.pi, count).astype(dtype)
    return jaxsat.stack(shapes), jax.vmap(jaxsat.pose2)(xy[:, 0], xy[:, 1], angles)


def _every_pair(shapes, poses):
    """(rows, cols, a, pose_a, b, pose_b): every pair i < j of the scene, batched."""
    rows, cols = np.triu_indices(poses.translation.shape[0], 1)
    take = lambda tree, index: jax.tree.map(lambda x: x[index], tree)  # noqa: E731
    return rows, cols, take(shapes, rows), take(poses, rows), take(shapes, cols), take(poses, cols)


def _brute_force(shapes, poses, keep=None):
    """Penetration of every pair i < j (vmap over all of them) -> {(i, j): (depth, normal)}.
    The reference is built with `harness.FAST_COMPILE` (the test is of `collide`, which is
    compiled as a user's call compiles it)."""
    rows, cols, *batch = _every_pair(shapes, poses)
    hits = jax.jit(jax.vmap(jaxsat.penetration), compiler_options=FAST_COMPILE)(*batch)
    depth, normal = np.asarray(hits.depth), np.asarray(hits.normal)
    colliding = depth >= 0
    if keep is not None:
        colliding &= keep[rows, cols]
    return {(int(rows[k]), int(cols[k])): (depth[k], normal[k]) for k in np.nonzero(colliding)[0]}


def _colliding(result):
    """{(i, j): slot} of the colliding slots of a SceneCollisions."""
    slots = np.nonzero(np.asarray(result.colliding))[0]
    pairs = np.asarray(result.pairs)
    found = {(int(pairs[s, 0]), int(pairs[s, 1])): int(s) for s in slots}
    assert len(found) == len(slots), "a pair was reported twice"
    return found


SCENES = {
    "2d-polygons": lambda rng, dtype: _scene_2d(rng, 200, 8.0, dtype),
    "3d-boxes": lambda rng, dtype: _scene_3d(rng, 200, "boxes", 6.0, dtype),
    "3d-hulls": lambda rng, dtype: _scene_3d(rng, 80, "hulls", 3.5, dtype),
}


@pytest.mark.slow
@pytest.mark.parametrize("name,dtype", [("2d-polygons", np.float64), ("3d-boxes", np.float64),
                                        ("3d-hulls", np.float64), ("3d-boxes", np.float32)])
def test_collide_equals_brute_force(name, dtype):
    shapes, poses = SCENES[name](np.random.default_rng(len(name)), dtype)
    truth = _brute_force(shapes, poses)
    assert len(truth) >= 10, "the scene should have some collisions"
    result = jaxsat.collide(shapes, poses, capacity=1024)
    assert int(result.overflow) == 0
    found = _colliding(result)
    assert set(found) == set(truth)
    # Same kernel, compiled in another program: equal up to rounding (sizes are about 1).
    tolerance = 1e-12 if dtype == np.float64 else 1e-5
    for pair, slot in found.items():
        np.testing.assert_allclose(result.depth[slot], truth[pair][0], atol=tolerance)
        np.testing.assert_allclose(result.normal[slot], truth[pair][1], atol=tolerance)
    assert result.depth.dtype == dtype and result.pairs.dtype == jnp.int32


@pytest.mark.slow
def test_levels_agree_and_skip_work():
    shapes, poses = SCENES["3d-boxes"](np.random.default_rng(2), np.float64)
    by_level = {level: jaxsat.collide(shapes, poses, capacity=512, level=level)
                for level in ("intersects", "penetration")}
    assert by_level["intersects"].depth is None and by_level["intersects"].contacts is None
    assert by_level["penetration"].contacts is None
    np.testing.assert_array_equal(by_level["intersects"].colliding,
                                  by_level["penetration"].colliding)
    np.testing.assert_array_equal(by_level["intersects"].pairs, by_level["penetration"].pairs)


@pytest.mark.slow
def test_filters_equal_brute_force():
    rng = np.random.default_rng(4)
    shapes, poses = _scene_2d(rng, 200, 6.0)
    groups = rng.choice([1, 2, 4], 200).astype(np.int32)
    masks = rng.choice([7, 3, 6], 200).astype(np.int32)
    body_ids = np.arange(200) // 3  # consecutive triples are parts of one body
    keep = (((groups[:, None] & masks[None]) != 0) & ((groups[None] & masks[:, None]) != 0)
            & (body_ids[:, None] != body_ids[None]))
    truth = _brute_force(shapes, poses, keep)
    result = jaxsat.collide(shapes, poses, capacity=1024, groups=groups, masks=masks,
                            body_ids=body_ids)
    assert set(_colliding(result)) == set(truth) and len(truth) >= 10


@pytest.mark.slow
def test_overflow_is_reported():
    shapes, poses = SCENES["2d-polygons"](np.random.default_rng(9), np.float64)
    truth = _brute_force(shapes, poses)
    full = jaxsat.collide(shapes, poses, capacity=1024)
    small = jaxsat.collide(shapes, poses, capacity=8)
    assert int(small.overflow) == int(full.count) - 8 > 0
    assert set(_colliding(small)) <= set(truth)


@pytest.mark.slow
def test_collide_vmaps_over_scenes():
    rng = np.random.default_rng(6)
    scenes = [_scene_2d(rng, 100, 5.0) for _ in range(2)]
    # Pad both scenes' shapes to one size class so that they stack.
    shapes = jax.tree.map(lambda *xs: jnp.stack(xs), *[s for s, _ in scenes])
    poses = jax.tree.map(lambda *xs: jnp.stack(xs), *[p for _, p in scenes])
    batched = jax.vmap(lambda s, p: jaxsat.collide(s, p, capacity=256))(shapes, poses)
    for k, (scene_shapes, scene_poses) in enumerate(scenes):
        one = jax.tree.map(lambda x, k=k: x[k], batched)
        assert set(_colliding(one)) == set(_brute_force(scene_shapes, scene_poses))


@pytest.mark.slow
def test_collide_with_half_spaces():
    """A ground and a wall given as planes: every shape against each at every level, equal to
    the deepest world vertex below each plane (NumPy); the shape pairs and the broad-phase
    count are those of the scene without planes (the planes never enter the grid)."""
    rng = np.random.default_rng(8)
    shapes, poses = _scene_3d(rng, 40, "boxes", 4.0)
    lowered = poses.translation.at[:, 2].multiply(0.1)  # near the ground
    poses = jaxsat.Pose(lowered, poses.rotation)
    normals = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])
    offsets = np.array([0.0, -3.5])  # the ground z <= 0, the wall x >= 3.5
    planes = [jaxsat.halfspace(n, o) for n, o in zip(normals, offsets, strict=True)]
    world = (np.einsum("nij,nvj->nvi", np.asarray(poses.rotation), np.asarray(shapes.vertices))
             + np.asarray(poses.translation)[:, None])
    expected = np.max(offsets[None, None] - world @ normals.T, axis=1)  # (N, P)
    plain = jaxsat.collide(shapes, poses, capacity=256)
    assert plain.planes is None
    for level in ("intersects", "penetration", "distance", "contacts"):
        result = jaxsat.collide(shapes, poses, capacity=256, level=level, planes=planes)
        np.testing.assert_array_equal(result.planes.colliding, expected >= 0)
        assert int(result.count) == int(plain.count)
        assert set(_colliding(result)) == set(_colliding(plain))
        if level == "intersects":
            assert result.planes.depth is None
            continue
        np.testing.assert_allclose(result.planes.depth, expected, atol=1e-9)
        if level == "distance":
            np.testing.assert_allclose(result.planes.signed_distance, -expected, atol=1e-9)
            np.testing.assert_array_equal(result.planes.near, expected >= 0)
        np.testing.assert_allclose(result.planes.normal,
                                   np.broadcast_to(-normals, (40, 2, 3)), atol=1e-12)
        if level == "contacts":
            touching = np.asarray(result.planes.contacts.valid).any(axis=-1)
            np.testing.assert_array_equal(touching, expected >= 0)
    assert 5 <= np.sum(expected[:, 0] >= 0) < 40 and np.sum(expected[:, 1] >= 0) >= 1
    # One batched HalfSpace with explicit poses gives the same answer.
    stacked = jax.tree.map(lambda *leaves: jnp.stack(leaves), *planes)
    identity = jax.vmap(jaxsat.pose3)(jnp.zeros((2, 3)), jnp.tile(jnp.array([1.0, 0, 0, 0]),
                                                                   (2, 1)))
    again = jaxsat.collide(shapes, poses, capacity=256, planes=stacked, plane_poses=identity)
    np.testing.assert_allclose(again.planes.depth, expected, atol=1e-9)


def test_collide_rejects_bad_input():
    shapes, poses = _scene_2d(np.random.default_rng(0), 4, 1.0)
    with pytest.raises(ValueError, match="level"):
        jaxsat.collide(shapes, poses, capacity=8, level="everything")
    with pytest.raises(ValueError, match="one leading axis"):
        jaxsat.collide(jaxsat.box([1.0, 1.0]), jaxsat.pose2(0.0, 0.0, 0.0), capacity=8)
    with pytest.raises(ValueError, match="capacity"):
        jaxsat.collide(shapes, poses, capacity=-1)
    with pytest.raises(TypeError, match="Polytope"):
        jaxsat.collide(poses, shapes, capacity=8)
    ground = jaxsat.halfspace([0.0, 1.0])
    with pytest.raises(TypeError, match="planes must be a jaxsat.HalfSpace"):
        jaxsat.collide(shapes, poses, capacity=8, planes=[jaxsat.box([1.0, 1.0])])
    with pytest.raises(ValueError, match="planes are 3D and shapes 2D"):
        jaxsat.collide(shapes, poses, capacity=8, planes=jaxsat.halfspace([0.0, 0.0, 1.0]))
    with pytest.raises(ValueError, match="plane_poses given without planes"):
        jaxsat.collide(shapes, poses, capacity=8, plane_poses=jaxsat.pose2(0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="one per half-space"):
        jaxsat.collide(shapes, poses, capacity=8, planes=[ground, ground],
                       plane_poses=jaxsat.pose2(0.0, 0.0, 0.0))


@pytest.mark.slow
def test_collide_sharded_over_four_devices_equals_one_device():
    from multidevice import run_on_devices

    output = run_on_devices('''
        import jax, numpy as np
        import jaxsat
        from test_scene import _scene_3d, _colliding
        shapes, poses = _scene_3d(np.random.default_rng(1), 150, "boxes", 5.0)
        one = jaxsat.collide(shapes, poses, capacity=510)
        for options in ({"devices": 4}, {"devices": tuple(jax.devices()[1:3])}):
            many = jaxsat.collide(shapes, poses, capacity=510, **options)
            assert _colliding(many) == _colliding(one) and len(_colliding(one)) > 5
            # A different batch size per device may round differently, by an ulp or so.
            np.testing.assert_allclose(many.depth, one.depth, rtol=0, atol=1e-14)
            np.testing.assert_allclose(many.normal, one.normal, rtol=0, atol=1e-14)
        # The same chunks give bit-identical results whatever the number of devices.
        chunked = jaxsat.collide(shapes, poses, capacity=510, chunk_size=32)
        sharded = jaxsat.collide(shapes, poses, capacity=510, chunk_size=32, devices=4)
        np.testing.assert_array_equal(chunked.depth, sharded.depth)
        np.testing.assert_array_equal(chunked.normal, sharded.normal)
        print("ok", len(_colliding(one)))
    ''')
    assert output.startswith("ok")


def _signed_distances(shapes, poses, smoothing=None):
    """Signed distance of every pair i < j (vmap over all of them, `harness.FAST_COMPILE` as
    in `_brute_force`) -> {(i, j): distance}."""
    rows, cols, *batch = _every_pair(shapes, poses)
    query = jax.vmap(lambda a, pa, b, pb: jaxsat.signed_distance(a, pa, b, pb,
                                                                 smoothing=smoothing))
    values = np.asarray(jax.jit(query, compiler_options=FAST_COMPILE)(*batch))
    return {(int(i), int(j)): value for i, j, value in zip(rows, cols, values, strict=True)}


def _near(result) -> set:
    return {tuple(int(k) for k in pair) for pair in np.asarray(result.pairs)[result.near]}


@pytest.mark.slow
def test_collide_with_a_margin_returns_every_pair_within_it():
    """Level "distance" with a margin: exactly the pairs whose brute-force signed distance is
    at most the margin, with that distance and the closest points; smooth, the pairs whose
    smooth distance is; levels "penetration" and "contacts" flag a superset (their SAT gap is
    at most the distance). The capacity comes from `collide_capacity`."""
    rng = np.random.default_rng(12)
    shapes, poses = _scene_3d(rng, 50, "boxes", 5.0)
    margin = 0.4
    capacity = jaxsat.collide_capacity(shapes, poses, margin=margin)
    exact = _signed_distances(shapes, poses)
    within = {pair for pair, value in exact.items() if value <= margin}
    result = jaxsat.collide(shapes, poses, capacity=capacity, level="distance", margin=margin)
    assert int(result.overflow) == 0 and int(result.count) == capacity
    assert _near(result) == within
    assert 10 <= len(within) and len({p for p, v in exact.items() if v <= 0}) < len(within)
    colliding = {tuple(int(k) for k in p) for p in np.asarray(result.pairs)[result.colliding]}
    assert colliding == {pair for pair, value in exact.items() if value <= 0}
    for slot in np.nonzero(np.asarray(result.valid))[0]:
        i, j = (int(k) for k in result.pairs[slot])
        np.testing.assert_allclose(result.signed_distance[slot], exact[i, j], atol=1e-12)
        one = jaxsat.closest_points(jax.tree.map(lambda x, i=i: x[i], shapes),
                                    jax.tree.map(lambda x, i=i: x[i], poses),
                                    jax.tree.map(lambda x, j=j: x[j], shapes),
                                    jax.tree.map(lambda x, j=j: x[j], poses))
        np.testing.assert_allclose(result.witness_points[slot], [one.point_a, one.point_b],
                                   atol=1e-9)
        if slot > 12:
            break
    smooth = _signed_distances(shapes, poses, smoothing=0.02)
    soft = jaxsat.collide(shapes, poses, capacity=capacity, level="distance", margin=margin,
                          smoothing=0.02)
    assert _near(soft) == {pair for pair, value in smooth.items() if value <= margin}
    for level in ("penetration", "contacts"):
        loose = jaxsat.collide(shapes, poses, capacity=capacity, level=level, margin=margin)
        assert within <= _near(loose), level


@pytest.mark.slow
def test_collide_capacity_sizes_a_dense_scene():
    """A dense scene overflows a guessed capacity; `collide_capacity` gives the exact count,
    and with it nothing overflows and every colliding pair is found."""
    shapes, poses = _scene_3d(np.random.default_rng(13), 150, "boxes", 2.5)
    guessed = jaxsat.collide(shapes, poses, capacity=64)
    assert int(guessed.overflow) > 0
    capacity = jaxsat.collide_capacity(shapes, poses)
    # count is an upper bound when the candidate buffer overflowed too
    assert 64 < capacity <= int(guessed.count)
    result = jaxsat.collide(shapes, poses, capacity=capacity)
    assert int(result.overflow) == 0 and bool(result.valid.all())
    assert set(_colliding(result)) == set(_brute_force(shapes, poses))


def test_collide_rejects_a_bad_margin_or_smoothing():
    shapes, poses = _scene_2d(np.random.default_rng(0), 4, 1.0)
    for margin in (-0.1, np.nan, np.inf):
        with pytest.raises(ValueError, match="margin"):
            jaxsat.collide(shapes, poses, capacity=8, level="distance", margin=margin)
    with pytest.raises(TypeError, match="margin"):
        jaxsat.collide(shapes, poses, capacity=8, margin="wide")
    with pytest.raises(ValueError, match="intersects"):
        jaxsat.collide(shapes, poses, capacity=8, level="intersects", margin=0.1)
    with pytest.raises(ValueError, match="smoothing applies to level 'distance'"):
        jaxsat.collide(shapes, poses, capacity=8, smoothing=0.1)
    with pytest.raises(ValueError, match="smoothing"):
        jaxsat.collide(shapes, poses, capacity=8, level="distance", smoothing=0.0)
    with pytest.raises(ValueError, match="margin"):
        jaxsat.collide_capacity(shapes, poses, margin=-1.0)
