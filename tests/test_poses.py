"""Tests for rigid poses: pose2, pose3 and the Pose methods."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

import jaxsat

angles = st.floats(-10.0, 10.0)
coordinates = st.floats(-100.0, 100.0)
quaternions = st.lists(st.floats(-10.0, 10.0), min_size=4, max_size=4).filter(
    lambda q: np.linalg.norm(q) > 1e-3)
translations = st.lists(coordinates, min_size=3, max_size=3)


def scipy_rotation(quaternion_wxyz) -> np.ndarray:
    w, x, y, z = quaternion_wxyz
    return Rotation.from_quat([x, y, z, w]).as_matrix()  # scipy: (x, y, z, w), normalised


def assert_rotation(matrix, atol):
    matrix = np.asarray(matrix, np.float64)
    np.testing.assert_allclose(matrix @ matrix.T, np.eye(len(matrix)), atol=atol)
    assert np.linalg.det(matrix) == pytest.approx(1.0, abs=atol)


# --------------------------------------------------------------------------------------------
# Rotations against SciPy.
# --------------------------------------------------------------------------------------------


@pytest.mark.slow
@given(x=coordinates, y=coordinates, angle=angles)
def test_pose2_matches_scipy(x, y, angle):
    pose = jaxsat.pose2(x, y, angle)
    assert pose.dim == 2
    assert pose.rotation.shape == (2, 2) and pose.translation.shape == (2,)
    assert_rotation(pose.rotation, 1e-12)
    expected = Rotation.from_euler("z", angle).as_matrix()[:2, :2]
    np.testing.assert_allclose(pose.rotation, expected, atol=1e-12)
    np.testing.assert_array_equal(pose.translation, [x, y])


@given(translation=translations, quaternion=quaternions)
def test_pose3_matches_scipy(translation, quaternion):
    pose = jaxsat.pose3(np.array(translation), np.array(quaternion))
    assert pose.dim == 3
    assert pose.rotation.shape == (3, 3) and pose.translation.shape == (3,)
    assert_rotation(pose.rotation, 1e-12)
    np.testing.assert_allclose(pose.rotation, scipy_rotation(quaternion), atol=1e-12)
    np.testing.assert_array_equal(pose.translation, translation)


@given(quaternion=quaternions, factor=st.floats(1e-3, 1e3), negate=st.booleans())
def test_pose3_normalises_the_quaternion(quaternion, factor, negate):
    """Any non-zero multiple of a quaternion (including -q) gives the same rotation."""
    quaternion = np.array(quaternion)
    unit = quaternion / np.linalg.norm(quaternion)
    scaled = (-factor if negate else factor) * quaternion
    rotation = jaxsat.pose3(np.zeros(3), scaled).rotation
    np.testing.assert_allclose(rotation, jaxsat.pose3(np.zeros(3), unit).rotation, atol=1e-12)
    assert_rotation(rotation, 1e-12)


def test_known_rotations():
    """Quarter turns, written out by hand."""
    np.testing.assert_allclose(jaxsat.pose2(0.0, 0.0, np.pi / 2).rotation, [[0, -1], [1, 0]],
                               atol=1e-15)
    half = np.sqrt(0.5)
    about_z = jaxsat.pose3(np.zeros(3), np.array([half, 0, 0, half])).rotation
    np.testing.assert_allclose(about_z, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)
    about_x = jaxsat.pose3(np.zeros(3), np.array([half, half, 0, 0])).rotation
    np.testing.assert_allclose(about_x, [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-15)


@pytest.mark.slow
def test_zero_quaternion_gives_identity_and_finite_gradient():
    pose = jaxsat.pose3(np.ones(3), np.zeros(4))
    np.testing.assert_array_equal(pose.rotation, np.eye(3))
    weights = jnp.arange(9.0).reshape(3, 3)

    def objective(quaternion):
        return jnp.sum(jaxsat.pose3(jnp.zeros(3), quaternion).rotation * weights)

    gradient = jax.grad(objective)(jnp.zeros(4))
    assert np.all(np.isfinite(gradient))
    gradient = jax.jit(jax.grad(objective))(jnp.zeros(4))
    assert np.all(np.isfinite(gradient))


@pytest.mark.slow
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_pose_dtypes_follow_the_inputs(dtype):
    pose = jaxsat.pose2(dtype(1.0), dtype(2.0), dtype(0.5))
    assert pose.translation.dtype == dtype and pose.rotation.dtype == dtype
    pose = jaxsat.pose3(np.ones(3, dtype), np.array([1, 2, 3, 4], dtype))
    assert pose.translation.dtype == dtype and pose.rotation.dtype == dtype
    assert_rotation(pose.rotation, 1e-6 if dtype == np.float32 else 1e-12)
    identity = jaxsat.Pose.identity(3, dtype)
    assert identity.rotation.dtype == dtype
    # Python numbers and integers give the default float (float64 in these tests).
    assert jaxsat.pose2(1, 2, 0).rotation.dtype == jnp.float64
    assert jaxsat.pose3([1, 2, 3], [1, 0, 0, 0]).rotation.dtype == jnp.float64


# --------------------------------------------------------------------------------------------
# Gradients.
# --------------------------------------------------------------------------------------------


@pytest.mark.slow
@given(angle=angles)
def test_gradient_through_angle(angle):
    """d/dangle of R(angle) p, against the analytic derivative."""
    point = jnp.array([0.3, -1.2])

    def rotated(theta):
        return jaxsat.pose2(0.0, 0.0, theta).apply(point)

    jacobian = jax.jacobian(rotated)(angle)
    cos, sin = np.cos(angle), np.sin(angle)
    expected = np.array([[-sin, -cos], [cos, -sin]]) @ np.asarray(point)
    np.testing.assert_allclose(jacobian, expected, atol=1e-12)
    assert np.linalg.norm(jacobian) > 0


@pytest.mark.slow
@given(quaternion=quaternions)
def test_gradient_through_quaternion(quaternion):
    """The Jacobian of R(q) p in q is finite, non-zero and matches central differences."""
    quaternion = np.array(quaternion)
    point = np.array([0.3, -1.2, 0.8])

    def rotated(q):
        return jaxsat.pose3(jnp.zeros(3), q).apply(jnp.asarray(point))

    jacobian = np.asarray(jax.jacobian(rotated)(jnp.asarray(quaternion)))
    assert np.all(np.isfinite(jacobian)) and np.linalg.norm(jacobian) > 0
    step = 1e-6 * np.linalg.norm(quaternion)
    numeric = np.stack([
        (scipy_rotation(quaternion + step * e) @ point - scipy_rotation(quaternion - step * e)
         @ point) / (2 * step) for e in np.eye(4)], axis=1)
    scale = 1.0 / np.linalg.norm(quaternion)  # the Jacobian scales like 1 / |q|
    np.testing.assert_allclose(jacobian, numeric, atol=1e-6 * scale * np.linalg.norm(point))
    # Scaling q does not rotate anything: the Jacobian is orthogonal to q.
    np.testing.assert_allclose(jacobian @ quaternion, 0.0, atol=1e-9)


@pytest.mark.slow
def test_gradient_of_penetration_through_pose_parameters():
    """Gradients reach the pose parameters through a collision query."""
    square = jaxsat.box([1.0, 1.0])
    cube = jaxsat.box([1.0, 1.0, 1.0])

    def depth_2d(params):
        x, y, angle = params
        return jaxsat.penetration(square, jaxsat.pose2(0.0, 0.0, 0.0), square,
                                  jaxsat.pose2(x, y, angle)).depth

    def depth_3d(translation, quaternion):
        return jaxsat.penetration(cube, jaxsat.pose3(jnp.zeros(3), jnp.array([1.0, 0, 0, 0])),
                                  cube, jaxsat.pose3(translation, quaternion)).depth

    # b pushed out along +x: d depth / dx = -1; turning b sticks its corners out: non-zero.
    gradient = jax.jit(jax.grad(depth_2d))(jnp.array([1.5, 0.2, 0.3]))
    assert np.all(np.isfinite(gradient))
    assert gradient[0] == pytest.approx(-1.0) and gradient[1] == pytest.approx(0.0, abs=1e-12)
    assert abs(gradient[2]) > 0
    translation, quaternion = jnp.array([1.5, 0.2, 0.1]), jnp.array([1.0, 0.1, 0.2, 0.3])
    g_translation, g_quaternion = jax.jit(jax.grad(depth_3d, argnums=(0, 1)))(translation,
                                                                             quaternion)
    assert np.all(np.isfinite(g_translation)) and np.all(np.isfinite(g_quaternion))
    # Translating b along the normal reduces the depth one for one.
    normal = jaxsat.penetration(cube, jaxsat.pose3(jnp.zeros(3), jnp.array([1.0, 0, 0, 0])),
                                cube, jaxsat.pose3(translation, quaternion)).normal
    np.testing.assert_allclose(g_translation, -normal, atol=1e-12)
    assert np.linalg.norm(g_quaternion) > 0


# --------------------------------------------------------------------------------------------
# apply, inverse, compose.
# --------------------------------------------------------------------------------------------


@given(translation=translations, quaternion=quaternions, seed=st.integers(0, 2**31 - 1))
def test_apply_inverse_compose_round_trip(translation, quaternion, seed):
    rng = np.random.default_rng(seed)
    first = jaxsat.pose3(np.array(translation), np.array(quaternion))
    second = jaxsat.pose3(rng.normal(size=3), rng.normal(size=4))
    points = rng.normal(size=(5, 3))
    tol = 1e-12 * (1 + np.linalg.norm(translation))
    # apply is R p + t, for a batch of points and a single point.
    expected = points @ scipy_rotation(quaternion).T + np.array(translation)
    np.testing.assert_allclose(first.apply(points), expected, atol=tol)
    np.testing.assert_allclose(first.apply(points[0]), expected[0], atol=tol)
    np.testing.assert_allclose(first.apply(points[None]), expected[None], atol=tol)
    # inverse undoes apply, both ways round.
    inverse = first.inverse()
    np.testing.assert_allclose(inverse.apply(first.apply(points)), points, atol=tol)
    np.testing.assert_allclose(first.apply(inverse.apply(points)), points, atol=tol)
    # compose applies the right pose first.
    composed = first.compose(second)
    np.testing.assert_allclose(composed.apply(points), first.apply(second.apply(points)),
                               atol=tol * 10)
    assert_rotation(composed.rotation, 1e-12)
    identity = first.compose(inverse)
    np.testing.assert_allclose(identity.rotation, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(identity.translation, np.zeros(3), atol=tol)


@given(x=coordinates, y=coordinates, angle=angles, other=angles)
def test_apply_inverse_compose_2d(x, y, angle, other):
    first, second = jaxsat.pose2(x, y, angle), jaxsat.pose2(1.0, -2.0, other)
    points = np.array([[0.0, 0.0], [1.0, 2.0], [-3.0, 0.5]])
    tol = 1e-12 * (1 + abs(x) + abs(y))
    rotation = Rotation.from_euler("z", angle).as_matrix()[:2, :2]
    np.testing.assert_allclose(first.apply(points), points @ rotation.T + [x, y], atol=tol)
    np.testing.assert_allclose(first.inverse().apply(first.apply(points)), points, atol=tol)
    composed = first.compose(second)
    np.testing.assert_allclose(composed.apply(points), first.apply(second.apply(points)),
                               atol=tol * 10)
    # Composing planar rotations adds their angles.
    np.testing.assert_allclose(composed.rotation, jaxsat.pose2(0.0, 0.0, angle + other).rotation,
                               atol=1e-12)


def test_identity_pose():
    for dim in (2, 3):
        pose = jaxsat.Pose.identity(dim)
        np.testing.assert_array_equal(pose.translation, np.zeros(dim))
        np.testing.assert_array_equal(pose.rotation, np.eye(dim))
        points = np.arange(2.0 * dim).reshape(2, dim)
        np.testing.assert_array_equal(pose.apply(points), points)


@pytest.mark.slow
def test_batched_poses_by_vmap():
    rng = np.random.default_rng(0)
    translations, quaternions = rng.normal(size=(6, 3)), rng.normal(size=(6, 4))
    poses = jax.vmap(jaxsat.pose3)(translations, quaternions)
    assert poses.translation.shape == (6, 3) and poses.rotation.shape == (6, 3, 3)
    for i in range(6):
        np.testing.assert_allclose(poses.rotation[i], scipy_rotation(quaternions[i]), atol=1e-12)
    planar = jax.vmap(jaxsat.pose2)(*rng.normal(size=(3, 5)))
    assert planar.translation.shape == (5, 2) and planar.rotation.shape == (5, 2, 2)


# --------------------------------------------------------------------------------------------
# Validation.
# --------------------------------------------------------------------------------------------


def test_pose2_rejects_arrays():
    with pytest.raises(ValueError, match="scalars"):
        jaxsat.pose2(np.zeros(2), 0.0, 0.0)
    with pytest.raises(ValueError, match="scalars"):
        jaxsat.pose2(0.0, 0.0, np.zeros(3))
    with pytest.raises(ValueError, match="scalars"):
        jaxsat.pose2(0.0, np.zeros((1, 1)), 0.0)


@pytest.mark.parametrize(("translation", "quaternion"), [
    (np.zeros(2), np.ones(4)), (np.zeros(4), np.ones(4)), (np.zeros(3), np.ones(3)),
    (np.zeros(3), np.ones(5)), (np.zeros((2, 3)), np.ones((2, 4))), (np.zeros(()), np.ones(4)),
    (np.zeros(3), np.ones((1, 4))),
])
def test_pose3_rejects_bad_shapes(translation, quaternion):
    with pytest.raises(ValueError, match="pose3"):
        jaxsat.pose3(translation, quaternion)


@pytest.mark.parametrize("as_array", [jnp.asarray, np.asarray], ids=["jax", "numpy"])
@pytest.mark.parametrize(("translation_shape", "rotation_shape"), [
    ((3,), (2, 2)), ((2,), (3, 3)), ((4,), (4, 4)), ((1,), (1, 1)), ((), (2, 2)),
    ((3,), (3,)), ((2,), (2, 3)),
])
def test_pose_rejects_bad_shapes(translation_shape, rotation_shape, as_array):
    with pytest.raises(ValueError, match="Pose needs"):
        jaxsat.Pose(as_array(np.zeros(translation_shape)), as_array(np.ones(rotation_shape)))


def test_identity_rejects_bad_dimension():
    for dim in (0, 1, 4):
        with pytest.raises(ValueError, match="dim"):
            jaxsat.Pose.identity(dim)


def test_apply_on_a_batch_of_poses_maps_each_through_its_own_pose():
    """Regression: `.T` on a (N, D, D) rotation stack reversed every axis instead of
    transposing each matrix, and batched poses mapped points to garbage without an error."""
    import jaxsat

    poses = jax.vmap(jaxsat.pose2)(jnp.array([0.0, 1.0]), jnp.zeros(2), jnp.array([0.0, 1.0]))
    shared = jnp.array([[1.0, 0.0], [0.0, 2.0]])
    per_pose = jax.vmap(lambda pose: pose.apply(shared))(poses)
    np.testing.assert_allclose(poses.apply(shared), per_pose, atol=1e-12)
    np.testing.assert_allclose(poses.apply(jnp.stack([shared, shared])), per_pose, atol=1e-12)
    np.testing.assert_allclose(per_pose[1, 0], [1.0 + np.cos(1.0), np.sin(1.0)], atol=1e-12)
