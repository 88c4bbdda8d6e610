"""Non-finite input is never a plausible answer: NaN quaternions, checkify errors naming the
argument, scenes that flag a non-finite shape instead of losing other pairs, and float64
asked for without 64-bit JAX. (Every query's NaN values and gradients for NaN or inf in any
pose, vertex, plane or radius are a generic property: test_properties.py,
`test_non_finite_inputs_give_nan_values_and_gradients`.)"""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from harness import FAST_COMPILE
from jax.experimental import checkify

import jaxsat

UPRIGHT = np.array([1.0, 0.0, 0.0, 0.0])


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_a_non_finite_quaternion_gives_a_nan_rotation_not_the_identity(bad):
    for k in range(4):
        quaternion = UPRIGHT.copy()
        quaternion[k] = bad
        rotation = np.asarray(jaxsat.pose3(np.zeros(3), quaternion).rotation)
        assert np.any(np.isnan(rotation)), (k, rotation)
    np.testing.assert_array_equal(jaxsat.pose3(np.zeros(3), np.zeros(4)).rotation, np.eye(3))


def test_a_nan_quaternion_gives_a_nan_distance_and_gradient():
    """The issue's case: a NaN quaternion became the identity, and signed_distance returned
    a finite 0.5 with gradient [0, 0, 0, 0]."""
    cube = jaxsat.box([0.5, 0.5, 0.5])
    origin = jaxsat.pose3(np.zeros(3), UPRIGHT)

    def distance(quaternion):
        return jaxsat.signed_distance(cube, origin, cube, jaxsat.pose3(np.array([1.5, 0, 0]),
                                                                       quaternion))

    value_and_grad = jax.jit(jax.value_and_grad(distance), compiler_options=FAST_COMPILE)
    value, gradient = value_and_grad(jnp.array([np.nan, 0.0, 0.0, 0.0]))
    assert np.isnan(value) and np.all(np.isnan(gradient))
    value, gradient = value_and_grad(jnp.asarray(UPRIGHT))
    np.testing.assert_allclose(value, 0.5, atol=1e-6)
    assert np.all(np.isfinite(gradient))


@pytest.mark.slow  # a hull distance's gradient compiled: the fast subset stays under 2 minutes
def test_a_non_finite_vertex_of_a_large_hull_gives_nan_values_and_vertex_gradients():
    """A 20-vertex hull's vertices (60 entries, more than the guard takes one by one: a
    reduction, `_kernels._ENTRY_BY_ENTRY`): one NaN or inf coordinate, in any of its 60
    places, makes the signed distance and every entry of its vertex gradient NaN; the finite
    hull gives a finite value and gradient."""
    from jaxsat._kernels import _ENTRY_BY_ENTRY

    rng = np.random.default_rng(5)
    points = rng.normal(size=(200, 3))
    points = 0.5 * points / np.linalg.norm(points, axis=1, keepdims=True)
    hull = jaxsat.polyhedron(points[:20])
    assert hull.vertices.size > _ENTRY_BY_ENTRY
    pose_a, pose_b = jaxsat.pose3(np.zeros(3), UPRIGHT), jaxsat.pose3(
        np.array([1.2, 0.1, 0.0]), UPRIGHT)

    def distance(vertices):
        return jaxsat.signed_distance(dataclasses.replace(hull, vertices=vertices), pose_a,
                                      hull, pose_b)

    value_and_grad = jax.jit(jax.value_and_grad(distance), compiler_options=FAST_COMPILE)
    value, gradient = value_and_grad(hull.vertices)
    assert np.isfinite(value) and np.all(np.isfinite(gradient))
    for spot, bad in ((0, np.nan), (31, np.inf), (hull.vertices.size - 1, -np.inf)):
        vertices = np.array(hull.vertices).reshape(-1)
        vertices[spot] = bad
        value, gradient = value_and_grad(vertices.reshape(hull.vertices.shape))
        assert np.isnan(value) and np.all(np.isnan(gradient)), (spot, value)


def _square_pair():
    square = jaxsat.box([0.5, 0.5])
    return square, jaxsat.pose2(0.0, 0.0, 0.0), square, jaxsat.pose2(0.7, 0.2, 0.3)


QUERIES = {
    "intersects": jaxsat.intersects,
    "penetration": jaxsat.penetration,
    "signed_distance": jaxsat.signed_distance,
    "smooth signed_distance": lambda a, pa, b, pb: jaxsat.signed_distance(a, pa, b, pb,
                                                                          smoothing=0.01),
    "closest_points": jaxsat.closest_points,
    "contacts": jaxsat.contacts,
    "compound_intersects": jaxsat.compound_intersects,
    "compound_penetration": jaxsat.compound_penetration,
}


@pytest.mark.parametrize("name", [pytest.param(name, marks=() if name == "signed_distance"
                                                else pytest.mark.slow) for name in QUERIES])
def test_checkify_names_the_non_finite_argument(name):
    """Under jax.experimental.checkify, a NaN pose or vertex raises an error that names the
    query and the argument; finite input raises none."""
    query = jax.jit(checkify.checkify(QUERIES[name]), compiler_options=FAST_COMPILE)
    a, pose_a, b, pose_b = _square_pair()
    public_name = name.split()[-1]
    error, _ = query(a, pose_a, b, pose_b)
    assert error.get() is None
    nan_pose = jaxsat.Pose(pose_b.translation.at[1].set(jnp.nan), pose_b.rotation)
    error, _ = query(a, pose_a, b, nan_pose)
    assert f"jaxsat.{public_name}: argument 'pose_b' holds NaN or inf" in error.get()
    with pytest.raises(checkify.JaxRuntimeError, match="'pose_b'"):
        error.throw()
    nan_shape = dataclasses.replace(a, vertices=a.vertices.at[2, 0].set(jnp.inf))
    error, _ = query(nan_shape, pose_a, b, pose_b)
    assert "argument 'a' holds NaN or inf" in error.get()


def test_checkify_names_a_non_finite_smoothing():
    query = jax.jit(checkify.checkify(lambda a, pa, b, pb, tau: jaxsat.signed_distance(
        a, pa, b, pb, smoothing=tau)), compiler_options=FAST_COMPILE)
    error, value = query(*_square_pair(), jnp.nan)
    assert "argument 'smoothing' holds NaN or inf" in error.get()
    assert np.isnan(value)


def _boxes_scene(count=60, seed=3):
    rng = np.random.default_rng(seed)
    shapes = jaxsat.stack([jaxsat.box(rng.uniform(0.2, 0.6, 3)) for _ in range(count)])
    return shapes, rng.uniform(-3.0, 3.0, (count, 3)), rng.normal(size=(count, 4))


def _pairs(result) -> set:
    pairs = np.asarray(result.pairs)[np.asarray(result.colliding)]
    return {tuple(int(k) for k in pair) for pair in pairs}


@pytest.mark.slow
@pytest.mark.parametrize("where", ["translation", "quaternion", "vertex"])
def test_collide_flags_a_non_finite_shape_and_keeps_every_other_pair(where):
    """One NaN shape made the grid's cell size NaN and put every box into one cell: all N^2/2
    pairs became candidates, overflowed the candidate buffer, and other pairs went missing.
    Now it is flagged and counted, it is in no pair, and every other pair is found as without
    it; its rows against a plane are NaN."""
    shapes, translations, quaternions = _boxes_scene()
    ground = jaxsat.halfspace([0.0, 0.0, 1.0], -1.0)
    run = jax.jit(lambda shapes, t, q: jaxsat.collide(
        shapes, jax.vmap(jaxsat.pose3)(t, q), capacity=256, candidate_capacity=1200,
        planes=ground))
    before = run(shapes, translations, quaternions)
    assert int(before.overflow) == 0 and int(before.non_finite_count) == 0
    bad = 7
    if where == "translation":
        translations = translations.copy()
        translations[bad, 2] = np.nan
    elif where == "quaternion":
        quaternions = quaternions.copy()
        quaternions[bad, 0] = np.inf
    else:
        vertices = np.array(shapes.vertices)
        vertices[bad, 3, 1] = np.nan
        shapes = dataclasses.replace(shapes, vertices=vertices)
    after = run(shapes, translations, quaternions)
    expected = {pair for pair in _pairs(before) if bad not in pair}
    assert len(expected) >= 20
    assert _pairs(after) == expected
    assert int(after.overflow) == 0
    assert int(after.non_finite_count) == 1
    np.testing.assert_array_equal(np.nonzero(np.asarray(after.non_finite))[0], [bad])
    slots = np.asarray(after.pairs)[np.asarray(after.valid)]
    assert not np.any(slots == bad)
    assert np.isnan(after.planes.depth[bad]).all() and not after.planes.colliding[bad].any()
    others = np.arange(len(translations)) != bad
    np.testing.assert_array_equal(after.planes.depth[others], before.planes.depth[others])


def test_explicit_float64_without_x64_is_an_error():
    """Without 64-bit JAX, asking for float64 by name raises instead of silently storing
    float32; float64 NumPy input keeps JAX's usual behaviour (float32)."""
    script = """
import numpy as np, jax, jaxsat
assert not jax.config.jax_enable_x64
for build in (lambda: jaxsat.box([1.0, 1.0, 1.0], dtype=np.float64),
              lambda: jaxsat.polygon([[0, 0], [1, 0], [0, 1]], dtype="float64"),
              lambda: jaxsat.sphere(1.0, dtype=np.float64),
              lambda: jaxsat.Pose.identity(3, np.float64)):
    try:
        build()
    except ValueError as error:
        assert "jax_enable_x64" in str(error), error
    else:
        raise AssertionError("no error")
assert jaxsat.box(np.ones(3)).dtype == np.float32
assert jaxsat.box([1.0, 1.0, 1.0], dtype=np.float32).dtype == np.float32
print("ok")
"""
    env = {"JAX_ENABLE_X64": "0", "JAX_PLATFORMS": "cpu", "PATH": ""}
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          env=env, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr
