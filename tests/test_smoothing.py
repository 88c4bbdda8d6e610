"""Tests for the smooth signed distance (smoothing=tau > 0) and jaxsat.smoothing_error_bound.

The contract, each property a test here:

* bound: exact - c tau <= smooth <= exact with c = smoothing_error_bound(a, b), over 1e4 random
  pairs per dimension (float64, and float32 with float32 rounding) and the degenerate ones;
* gradient: norm 1 in either shape's translation on every pair (the value is 1-Lipschitz in
  translation), rotation and vertex gradients bounded by the shapes' size;
* smooth where the shapes are apart: gradients equal central finite differences (float64,
  relative 1e-6), second derivatives equal finite differences of the gradient;
* continuous everywhere: 1-Lipschitz along translation paths through contact and deep
  overlap; where two penetration directions tie the gradient has a kink (documented), and
  where b's closest corner switches while apart it turns smoothly.

Exact references come from the independent oracle (`oracle.py`), never from jaxsat's exact
path. Shapes, pairs and the batched runner come from the shared harness (`harness.py`). Every
batched function is jitted once and called in chunks of BATCH pairs, with tau a batched argument, so
that each size class compiles once for every tau. Finite-difference gradients re-evaluate
the same compiled value function on perturbed inputs (shapes keep their stored face normals
and edge directions, as the documented vertex gradient does).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import oracle
import pytest
from harness import (
    BATCH,
    CUBE,
    FAST_COMPILE,
    IDENTITY,
    SQUARE,
    Pairs,
    hand_built_pairs,
    hand_pool,
    inner_jaxprs,
    make_pool,
    make_pose,
    pool,
    quaternion,
    quaternion_product,
    random_pairs,
    references,
    run_batched,
    take,
    translations,
    world_points,
)
from scipy.spatial.transform import Rotation

import jaxsat
from jaxsat import _smoothing as smoothing
from jaxsat._closest import exact_distance, support_gap
from jaxsat._pair import pair_frame
from jaxsat._sat import sat_runner_up

# --------------------------------------------------------------------------------------------
# The smooth value as a function of vertices and pose parameters, batched and jitted.
# --------------------------------------------------------------------------------------------


def _smooth(vertices_a, params_a, vertices_b, params_b, a, b, tau):
    """Smooth signed distance with the shapes' vertices and the pose parameters as inputs
    (a Polytope also holds boolean masks, so gradients go through its vertices only)."""
    a = dataclasses.replace(a, vertices=vertices_a)
    b = dataclasses.replace(b, vertices=vertices_b)
    return jaxsat.signed_distance(a, make_pose(params_a), b, make_pose(params_b), smoothing=tau)


# Compiled with FAST_COMPILE: these kernels dominate the suite's compile time; the default
# build is exercised by test_traced_tau_under_jit and the other files' kernels.
smooth_batch = jax.jit(jax.vmap(_smooth), compiler_options=FAST_COMPILE)
forward_batch = jax.jit(jax.vmap(jax.jacfwd(_smooth, argnums=(0, 1, 2, 3))),
                        compiler_options=FAST_COMPILE)
value_and_gradient_batch = jax.jit(
    jax.vmap(jax.value_and_grad(_smooth, argnums=(0, 1, 2, 3))), compiler_options=FAST_COMPILE)


def smooth_inputs(pairs: Pairs, taus):
    """The batched arguments of `_smooth` for `pairs` and per-pair taus."""
    a, params_a, b, params_b = pairs.inputs()
    return (np.asarray(a.vertices), params_a, np.asarray(b.vertices), params_b, a, b,
            np.asarray(taus, pairs.dtype))


def smooth_values(pairs: Pairs, taus) -> np.ndarray:
    values = run_batched(smooth_batch, len(pairs), *smooth_inputs(pairs, taus))
    assert values.dtype == pairs.dtype
    return values


def sizes_of(refs) -> np.ndarray:
    return np.array([r.size for r in refs])


def exact_values(refs) -> np.ndarray:
    return np.array([r.value for r in refs])


bound_of = jax.jit(jaxsat.smoothing_error_bound)
"""Jitted: eager calls compile every primitive anew for each new combination of shapes."""


def bounds(pairs: Pairs) -> np.ndarray:
    a, _, b, _ = pairs.inputs()
    return np.asarray(bound_of(a, b))


def repeat(pairs: Pairs, times: int) -> Pairs:
    """Each pair `times` times in a row (one per tau)."""
    return pairs.subset(np.repeat(np.arange(len(pairs)), times))


# --------------------------------------------------------------------------------------------
# The bound exact - c tau <= smooth <= exact.
# --------------------------------------------------------------------------------------------

TAU_FACTORS = np.array([1e-3, 1e-2, 1e-1, 0.5])
"""tau relative to the pair's size (the larger bounding radius)."""

ROUNDING = {np.float64: 1e-9, np.float32: 2e-5}
"""Slack for rounding, relative to the pair's size: float32 inputs are the float64 ones
rounded, and float32 arithmetic on top (the oracle is always float64)."""


def check_within_bound(pairs: Pairs, tau_factors=TAU_FACTORS, refs=None) -> np.ndarray:
    """Every pair at every tau = factor * size: exact - c tau <= smooth <= exact (plus
    rounding), c = smoothing_error_bound. Returns (exact - smooth) / (c tau), (pairs, taus)."""
    refs = references(pairs) if refs is None else refs
    count, per = len(pairs), len(tau_factors)
    size = np.repeat(sizes_of(refs), per)
    taus = np.tile(tau_factors, count) * size
    values = smooth_values(repeat(pairs, per), taus).astype(np.float64)
    lost = np.repeat(exact_values(refs), per) - values
    limit = np.repeat(bounds(pairs), per) * taus
    slack = ROUNDING[pairs.dtype] * size
    worst = int(np.argmax(np.maximum(lost - limit, -lost)))
    assert np.all(lost <= limit + slack) and np.all(lost >= -slack), (
        f"pair {worst // per}: exact - smooth = {lost[worst]!r}, bound {limit[worst]!r} "
        f"at tau {taus[worst]!r}")
    return (lost / limit).reshape(count, per)


MANY = {2: [("poly8", 10_000)], 3: [("box", 5_000), ("hull", 5_000)]}
"""At least 1e4 random pairs per dimension: padded 2D polygons; boxes, and hulls of 8 and of
20 points (and boxes) padded to 20 vertices."""


@pytest.mark.slow
@pytest.mark.parametrize("dim", [2, 3])
def test_bound_and_gradient_norms_over_many_pairs(dim):
    """1e4 random pairs per dimension, from deep overlap to clear separation, tau from 1e-3 to
    0.3 of the size, float64 and the same pairs rounded to float32:

    * exact - c tau <= smooth <= exact, and the bound is not vacuous (the smoothing moves the
      value by a sizeable fraction of it somewhere);
    * the gradient in either shape's translation has norm 1 (the value is 1-Lipschitz there);
    * each shape's vertex gradients are a convex combination of one unit vector (norms sum
      to 1, padding gets 0) and its rotation gradient is at most its radius."""
    for name, count in MANY[dim]:
        rng = np.random.default_rng([71, dim, len(name)])
        pairs64 = random_pairs(pool(name, np.float64), pool(name, np.float64, seed=1), count,
                               rng, np.float64)
        refs = references(pairs64)
        factors = np.array([1e-3, 1e-2, 0.1, 0.3])[np.arange(count) % 4]
        taus = factors * sizes_of(refs)
        limits = bounds(pairs64) * taus
        for dtype in (np.float64, np.float32):
            pairs = pairs64 if dtype == np.float64 else dataclasses.replace(
                pairs64, pool_a=pool(name, np.float32), pool_b=pool(name, np.float32, seed=1),
                params_a=tuple(p.astype(np.float32) for p in pairs64.params_a),
                params_b=tuple(p.astype(np.float32) for p in pairs64.params_b),
                dtype=np.float32)
            inputs = smooth_inputs(pairs, taus)
            values, (g_vertices_a, g_params_a, g_vertices_b, g_params_b) = run_batched(
                value_and_gradient_batch, count, *inputs)
            assert values.dtype == dtype
            slack = ROUNDING[dtype] * sizes_of(refs)
            lost = exact_values(refs) - values.astype(np.float64)
            label = f"{name} {np.dtype(dtype).name}"
            assert np.all(lost <= limits + slack), (label, np.max(lost - limits - slack))
            assert np.all(lost >= -slack), (label, np.min(lost + slack))
            assert np.max(lost / limits) > 0.3, label
            # Translation: (x, y) in 2D, the translation in 3D; norm 1 up to rounding.
            unit_tolerance = 1e-9 if dtype == np.float64 else 1e-5
            for params in (g_params_a, g_params_b):
                translation = (np.stack(params[:2], axis=1) if dim == 2 else params[0])
                norms = np.linalg.norm(translation.astype(np.float64), axis=1)
                np.testing.assert_allclose(norms, 1.0, atol=unit_tolerance, err_msg=label)
            a, _, b, _ = pairs.inputs()
            for gradient, shape in ((g_vertices_a, a), (g_vertices_b, b)):
                norms = np.linalg.norm(gradient.astype(np.float64), axis=2)
                np.testing.assert_allclose(norms.sum(axis=1), 1.0, atol=unit_tolerance,
                                           err_msg=label)
                assert np.all(norms[~np.asarray(shape.vertex_mask)] == 0.0), label
            if dim == 2:  # d/d angle: the lever arm of a soft support point about the origin
                for params, shape in ((g_params_a, a), (g_params_b, b)):
                    radius = np.max(np.linalg.norm(np.asarray(shape.vertices, np.float64),
                                                   axis=2), axis=1)
                    assert np.all(np.abs(params[2]) <= radius * (1 + unit_tolerance)), label


BOUND_CASES = [("poly8", 1.0), ("box", 1.0), ("hull8", 1.0), ("poly8", 1e-3), ("hull8", 1e3)]


@pytest.mark.slow
@pytest.mark.parametrize(("name", "scale"), BOUND_CASES,
                         ids=[f"{n}-{s:g}" for n, s in BOUND_CASES])
def test_error_within_bound(name, scale):
    """Random pairs (8-gons and smaller polygons, boxes, hulls of 8 points), apart and
    overlapping, every tau of the sweep, at sizes 1e-3 to 1e3: within the bound."""
    rng = np.random.default_rng([51, len(name), int(np.log10(scale)) + 3])
    shapes = make_pool(name, np.float64, rng, scale=scale, size=8)
    pairs = random_pairs(shapes, shapes, 48, rng, np.float64, scale=scale)
    refs = references(pairs)
    overlapping = np.array([r.depth > 0 for r in refs])
    assert 0.1 < overlapping.mean() < 0.9
    ratio = check_within_bound(pairs, refs=refs)
    assert np.max(ratio) > 0.05  # the bound is not vacuous


@pytest.mark.slow
@pytest.mark.parametrize(("dim", "label"), [(2, "padded"), (3, "padded"), (3, "box")])
def test_error_within_bound_on_ties(dim, label):
    """The hand-built contacts of test_distance (vertex-vertex, vertex-edge, edge-edge,
    face-face, ...) and the same shapes overlapping (negative gaps), where many vertices and
    axes tie exactly: the worst cases for log-sum-exp. The oracle checks the analytic values."""
    pairs, _ = hand_built_pairs(dim, label, (1e-3, 0.1, -1e-3, -0.1), motions=1,
                                max_vertices=20)
    check_within_bound(pairs)


@pytest.mark.slow
def test_identical_shapes_at_identical_poses():
    """Each shape against itself at one pose: every face normal ties for the deepest axis."""
    rng = np.random.default_rng(52)
    for name in ("poly8", "box", "hull8"):
        shapes = pool(name, np.float64)
        pairs = random_pairs(shapes, shapes, 16, rng, np.float64, distance=(0.0, 0.0))
        pairs = dataclasses.replace(pairs, index_b=pairs.index_a, params_b=pairs.params_a)
        refs = references(pairs)
        assert all(r.depth > 0 for r in refs)
        check_within_bound(pairs, refs=refs)


# Delicate configurations, built in the poly8 (2D) and box (3D) size classes. a is the square
# or cube [-1, 1]^D at the identity (optionally moved with b by a common rigid motion).

_CORNER_POLYGON = np.array([[0.0, 0.0], [1.0, 0.3], [0.8, 1.1], [0.2, 0.9]])
"""A quadrilateral whose vertex 0 is its unique lowest point along (1, 1)."""


def _delicate_2d(s: float):
    """{name: (b, b's raw points, b's pose parameters, exact value or None)}: b apart by s
    (s < 0: overlapping by -s) through one feature pair."""
    half = 0.5 * SQUARE
    small = jaxsat.box([0.5, 0.5], max_vertices=8)
    corner = _CORNER_POLYGON
    return {
        # Vertex to vertex: b's corner s away from a's corner along the diagonal.
        "vertex-vertex": (jaxsat.polygon(corner, 8), corner,
                          (1.0 + s / np.sqrt(2), 1.0 + s / np.sqrt(2), 0.0), s),
        # Corner to corner with every edge parallel (two axes tie, four vertices nearly so).
        "corner-corner": (small, half, (1.5 + s / np.sqrt(2), 1.5 + s / np.sqrt(2), 0.0), s),
        # Edge on edge (face-face in 2D), overlapping in x.
        "edge-edge": (small, half, (0.3, 1.5 + s, 0.0), s),
        # The same flush with a's corner: two vertex pairs coincide at s = 0.
        "flush": (small, half, (0.5, 1.5 + s, 0.0), s),
        # Edge on edge, nearly parallel (tilted by 1e-7).
        "tilted": (small, half, (0.3, 1.5 + s, 1e-7), None),
    }


_YZ = np.array([0.0, 1.0, 1.0]) / np.sqrt(2)
_CROSSING = np.roll(Rotation.from_matrix(
    np.array([[0.0, 1.0, -1.0], [0.0, 1.0, 1.0], [np.sqrt(2), 0.0, 0.0]]).T / np.sqrt(2)
    @ np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 1.0], [0.0, -1.0, 1.0]]) / np.array(
        [[1.0], [np.sqrt(2)], [np.sqrt(2)]])).as_quat(), 1)
"""(w, x, y, z) of the rotation taking x to (0, 1, -1) / sqrt 2 and (0, 1, 1) to itself."""


def _delicate_3d(s: float):
    """As `_delicate_2d`, for unpadded boxes."""
    half = 0.5 * CUBE
    small = jaxsat.box([0.5, 0.5, 0.5])
    diagonal = np.ones(3) / np.sqrt(3)
    # Turning b about the diagonal through its corner keeps that corner b's lowest point.
    about_diagonal = quaternion(diagonal, 0.4)
    return {
        "vertex-vertex": (small, half, (np.ones(3) + (s + 0.5 * np.sqrt(3)) * diagonal,
                                        about_diagonal), s),
        "corner-corner": (small, half, (np.full(3, 1.5) + s * diagonal, IDENTITY), s),
        "face-face": (small, half, (np.array([0.3, 0.2, 1.5 + s]), IDENTITY), s),
        "face-face-flush": (small, half, (np.array([0.5, 0.5, 1.5 + s]), IDENTITY), s),
        # Edge along x on a's edge along x (parallel edges, every cross product vanishes).
        "edge-edge-parallel": (small, half,
                               (np.array([0.2, 1.5, 1.5]) + s * np.array([0, 1, 1]) / np.sqrt(2),
                                IDENTITY), s),
        # The same with b's edges turned by 1e-7 and by 1e-3 about z: nearly parallel.
        "edge-edge-1e-7": (small, half, (np.array([0.2, 1.5 + s, 1.5 + s]),
                                         quaternion([0, 0, 1], 1e-7)), None),
        "edge-edge-1e-3": (small, half, (np.array([0.2, 1.5 + s, 1.5 + s]),
                                         quaternion([0, 0, 1], 1e-3)), None),
        # b's edge along (0, 1, -1) crossing a's edge along x at (0, 1, 1) + s (0, 1, 1) / sqrt 2
        # at a right angle, b's edge-on cross-section pointing at it.
        "edge-edge-crossing": (small, half,
                               (np.array([0.0, 1.0, 1.0]) + (s + 0.5 * np.sqrt(2)) * _YZ,
                                _CROSSING), s),
    }


def delicate_pairs(dim: int, gaps, motion=None):
    """Every delicate case at every gap; `motion` (2D (turn, shift), 3D (quaternion, shift))
    moves both shapes. Returns (pairs, names, gaps, analytic values)."""
    if dim == 2:
        unit = (jaxsat.box([1.0, 1.0], max_vertices=8), SQUARE)
        cases = _delicate_2d
    else:
        unit = (jaxsat.box([1.0, 1.0, 1.0]), CUBE)
        cases = _delicate_3d
    shapes_b, params_a, params_b, names, used, values = [], [], [], [], [], []
    for s in gaps:
        for name, (shape, points, params, value) in cases(s).items():
            if dim == 2:
                turn, shift = motion if motion is not None else (0.0, np.zeros(2))
                position = oracle.rotation_2d(turn) @ np.array(params[:2]) + shift
                params_a.append((shift[0], shift[1], turn))
                params_b.append((position[0], position[1], params[2] + turn))
            else:
                turn, shift = motion if motion is not None else (IDENTITY, np.zeros(3))
                params_a.append((shift, turn))
                params_b.append((oracle.rotation_3d(turn) @ params[0] + shift,
                                 quaternion_product(turn, params[1])))
            shapes_b.append((shape, points))
            names.append(name)
            used.append(s)
            values.append(value)
    count = len(names)
    column = lambda side, k: np.array([p[k] for p in side], np.float64)  # noqa: E731
    width = 3 if dim == 2 else 2
    pairs = Pairs(hand_pool(dim, [unit]), hand_pool(dim, shapes_b), np.zeros(count, int),
                  np.arange(count), tuple(column(params_a, k) for k in range(width)),
                  tuple(column(params_b, k) for k in range(width)), np.float64)
    return pairs, names, np.array(used), values


@pytest.mark.slow
@pytest.mark.parametrize("dim", [2, 3])
def test_error_within_bound_near_degenerate(dim):
    """Vertex-vertex nearly touching, face-face touching and flush, (nearly) parallel and
    crossing edges, apart by 1e-3 tau, touching, and overlapping by 1e-3 tau, at every tau,
    also under a common rigid motion, float64 and float32."""
    motion = ((0.7, np.array([0.3, -1.2])) if dim == 2
              else (np.array([0.9, -0.2, 0.4, 0.3]), np.array([0.3, -1.2, 0.5])))
    for factor in TAU_FACTORS:
        tau = factor * 1.8  # about the pairs' size (the cube's bounding radius is sqrt(3))
        for moved in (None, motion):
            pairs, names, gaps, values = delicate_pairs(dim, (1e-3 * tau, 0.0, -1e-3 * tau),
                                                        moved)
            refs = references(pairs)
            for name, s, value, ref in zip(names, gaps, values, refs, strict=True):
                if value is not None and s >= 0:
                    assert ref.value == pytest.approx(value, abs=1e-12), name
                elif value is not None:
                    assert s - 1e-12 <= ref.value < 0, name
            check_within_bound(pairs, np.array([tau]) / sizes_of(refs)[0], refs=refs)
            check_within_bound(as_float32(pairs), np.array([tau]) / sizes_of(refs)[0],
                               refs=refs)


def as_float32(pairs: Pairs) -> Pairs:
    """The same pairs in float32 (shapes cast field by field, pose parameters rounded)."""
    cast = lambda p: dataclasses.replace(p, shapes=jax.tree.map(  # noqa: E731
        lambda x: np.asarray(x).astype(np.float32) if np.asarray(x).dtype == np.float64
        else np.asarray(x), p.shapes))
    return dataclasses.replace(pairs, pool_a=cast(pairs.pool_a), pool_b=cast(pairs.pool_b),
                               params_a=tuple(p.astype(np.float32) for p in pairs.params_a),
                               params_b=tuple(p.astype(np.float32) for p in pairs.params_b),
                               dtype=np.float32)


@pytest.mark.slow
def test_convergence_as_tau_shrinks():
    """The largest error over many pairs falls linearly with tau: from tau = 1e-2 size to
    1e-4 size it shrinks by more than 20 (0.05), and each decade by a factor of at least 3;
    and every error stays within the bound."""
    rng = np.random.default_rng(53)
    factors = np.array([1e-1, 1e-2, 1e-3, 1e-4, 1e-5])
    for name in ("poly8", "box", "hull8"):
        shapes = pool(name, np.float64)
        pairs = random_pairs(shapes, shapes, 32, rng, np.float64)
        refs = references(pairs)
        ratio = check_within_bound(pairs, factors, refs=refs)
        errors = ratio * bounds(pairs)[:, None] * factors[None, :]  # |error| / size
        worst = np.max(errors, axis=0)
        assert worst[0] > 1e-3, worst  # the smoothing is visible at tau = 0.1 size
        assert worst[3] < 0.05 * worst[1], worst
        assert np.all(worst[1:] <= worst[:-1] / 3 + 1e-12), worst


def _maximisers(pairs: Pairs, tau: float, monkeypatch, steps: int) -> np.ndarray:
    """The smooth distance's maximising axes (a's frame) after `steps` Newton steps."""
    monkeypatch.setattr(smoothing, "NEWTON_STEPS", steps)
    search = jax.jit(jax.vmap(lambda a, pa, b, pb: smoothing._maximiser(
        pair_frame(a, make_pose(pa), b, make_pose(pb)), np.asarray(tau, pairs.dtype))),
        compiler_options=FAST_COMPILE)  # a new function: traced with `steps`
    return np.asarray(search(*pairs.inputs()), np.float64)


@pytest.mark.slow  # two searches compiled per case: the fast subset stays under 2 minutes
@pytest.mark.parametrize("name", ["poly8", "box"])
def test_the_newton_steps_reach_the_maximiser_of_a_long_search(name, monkeypatch):
    """float32, tau = 0.5% of the size, 4096 random pairs: on the pairs that are apart (where
    the maximiser is unique; overlapping, two maxima can tie and either may win), the
    NEWTON_STEPS steps from each start end within 2e-6 rad of where 40 steps end. (A
    stretched step that overshot the maximum once left pairs up to 1e-4 rad away.)"""
    shapes = pool(name, np.float32)
    pairs = random_pairs(shapes, shapes, 4096, np.random.default_rng(71), np.float32)
    apart = ~np.asarray(jax.jit(jax.vmap(lambda a, pa, b, pb: jaxsat.intersects(
        a, make_pose(pa), b, make_pose(pb))))(*pairs.inputs()))
    assert apart.mean() > 0.4
    found = _maximisers(pairs, 0.005, monkeypatch, smoothing.NEWTON_STEPS)
    reference = _maximisers(pairs, 0.005, monkeypatch, 40)
    gaps = np.linalg.norm(found - reference, axis=1)[apart]
    assert np.max(gaps) < 2e-6, (np.max(gaps), int(np.sum(gaps >= 2e-6)))


@pytest.mark.parametrize(("name", "chunk_size"), [
    ("box", None), pytest.param("hull8", None, marks=pytest.mark.slow),
    pytest.param("box", 2, marks=pytest.mark.slow)],
    ids=["box-sixteenth", "hull8-sixteenth", "box-capped"])
def test_batched_searches_equal_single_calls(name, chunk_size, monkeypatch):
    """In 3D, `vmap` of the searches runs every first search and only the wanted second ones,
    in passes from a queue, in chunks of 1/16 of the batch's pairs or `SEARCH_CHUNK_SIZE`, the
    smaller: a search that is not done after a pass goes back to the queue's end, and a first
    search that is done appends its pair's second where that is wanted. On 37 pairs, with no
    least chunk size (chunks of 3, or of 2 with the size capped at 2: neither divides 37),
    with 2 Newton steps a pass (so that most searches take several passes, the queue's ring
    comes round, and some end out of passes), half of the second searches from the
    runner-up, half skipped: the batched results equal single calls (`_passes` in a loop), a
    skipped search gives its start with loss and slope inf.
    (Axes and losses equal to 1e-6: the two programs are fused differently, and a search that
    ends unconverged carries that rounding along its steps to about 1e-7. A search written to
    the wrong slot would be off by the distance between two axes, of order 1.)"""
    if chunk_size is not None:
        monkeypatch.setattr(smoothing, "SEARCH_CHUNK_SIZE", {2: chunk_size, 3: chunk_size})
    monkeypatch.setattr(smoothing, "SMALLEST_SEARCH_CHUNK", 1)
    monkeypatch.setattr(smoothing, "NEWTON_STEPS", 2)
    shapes = pool(name, np.float64)
    pairs = random_pairs(shapes, shapes, 37, np.random.default_rng(72), np.float64)
    kind = np.random.default_rng(73).integers(0, 2, 37)  # runner-up, skipped
    tau = np.float64(0.01)

    def one(a, params_a, b, params_b, kind):
        frame = pair_frame(a, make_pose(params_a), b, make_pose(params_b))
        first = exact_distance(frame).axis
        starts = jnp.stack([first, sat_runner_up(frame, first, 0.05)[0]])
        rival = jnp.where(kind == 0, jnp.inf, -jnp.inf)
        return starts, smoothing._searches(frame, tau, starts, np.bool_(True), rival,
                                           np.float64(0.0))

    starts, batched = jax.jit(jax.vmap(one), compiler_options=FAST_COMPILE)(*pairs.inputs(), kind)
    single = jax.jit(one, compiler_options=FAST_COMPILE)
    a, params_a, b, params_b = pairs.inputs()
    for i in range(len(pairs)):
        _, alone = single(take(a, i), take(params_a, i), take(b, i), take(params_b, i),
                          kind[i])
        for got, expected in zip(batched[:2], alone[:2], strict=True):  # axes, losses
            np.testing.assert_allclose(got[i], expected, rtol=0, atol=1e-6)
    skipped = kind == 1
    np.testing.assert_array_equal(batched[0][skipped, 1], starts[skipped, 1])
    assert np.all(np.isinf(batched[1][skipped, 1])) and np.all(np.isinf(batched[2][skipped, 1]))
    assert np.all(np.isfinite(batched[1][~skipped, 1])) and np.all(np.isfinite(batched[1][:, 0]))


@pytest.mark.parametrize(("name", "count", "chunk"), [
    ("poly8", 40960, 2048), ("box", 12288, 512), ("poly8", 4480, 280), ("box", 1000, 125),
    ("box", 100, 100)], ids=["2d-capped", "box-capped", "2d-sixteenth", "box-least", "box-one"])
def test_searches_run_in_chunks_sized_by_the_batch(name, count, chunk, monkeypatch):
    """On the CPU, the smooth distance's searches run in chunks of 1/16 of the batch's pairs
    (`SEARCH_CHUNKS`; 280 of 4,480), at most `SEARCH_CHUNK_SIZE` (40,960 2D pairs in chunks
    of 2,048, not 2,560; 12,288 box pairs in chunks of 512, not 768) and at least
    `SMALLEST_SEARCH_CHUNK` unless the batch is smaller (1,000 pairs in 8 chunks of 125, not
    16 of 63; 100 pairs in one): the Newton steps inside the chunk loop carry that many
    searches."""
    assert (smoothing.SEARCH_CHUNKS, smoothing.SMALLEST_SEARCH_CHUNK) == (16, 128)
    assert smoothing.SEARCH_CHUNK_SIZE == {2: 2048, 3: 512}
    monkeypatch.setattr(jax, "default_backend", lambda: "cpu")
    shapes = pool(name, np.float32)
    pairs = random_pairs(shapes, shapes, count, np.random.default_rng(76), np.float32)

    def value(a, params_a, b, params_b):
        return jaxsat.signed_distance(a, make_pose(params_a), b, make_pose(params_b),
                                      smoothing=0.01)

    def nested_loops(jaxpr, inside=False):
        """The loops inside another loop: the Newton steps (a `fori_loop` of a static count,
        a scan) inside the chunk loop."""
        for eqn in jaxpr.eqns:
            if eqn.primitive.name in ("while", "scan") and inside:
                yield eqn
            for inner in inner_jaxprs(eqn):
                yield from nested_loops(inner, inside or eqn.primitive.name == "while")

    closed = jax.make_jaxpr(jax.vmap(value))(*pairs.inputs())
    loops = list(nested_loops(closed.jaxpr))
    assert len(loops) == 1
    assert {var.aval.shape[0] for var in loops[0].outvars if var.aval.shape} == {chunk}


@pytest.mark.slow
def test_off_the_cpu_both_3d_searches_run_and_give_the_same_answer(monkeypatch):
    """Off the CPU (`jax.default_backend()` other than "cpu", where the skipping batching
    rule's sequential chunks cost more than they save), the 3D smooth distance runs both
    searches as one vmap, as in 2D. On 48 box pairs, float64: the same values and pose
    gradients as the CPU's skipping path, and the program lacks the queue over the chunks."""
    shapes = pool("box", np.float64)
    pairs = random_pairs(shapes, shapes, 48, np.random.default_rng(75), np.float64)

    def value_and_gradients(a, params_a, b, params_b):
        def value(pa, pb):
            return jaxsat.signed_distance(a, make_pose(pa), b, make_pose(pb), smoothing=0.01)
        return jax.value_and_grad(value, argnums=(0, 1))(params_a, params_b)

    def run():  # a fresh jit each time, so each traces with the backend it sees
        kernel = jax.jit(jax.vmap(value_and_gradients), compiler_options=FAST_COMPILE)
        return kernel.lower(*pairs.inputs()).as_text(), kernel(*pairs.inputs())

    # Both backends named, so that the test compares the two paths on any machine (on a GPU,
    # the first run would otherwise take the GPU path too).
    monkeypatch.setattr(jax, "default_backend", lambda: "cpu")
    cpu_program, on_cpu = run()
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    program, elsewhere = run()
    # The queue: a ring of 2 slots a pair and one chunk (48 pairs are fewer than
    # `SMALLEST_SEARCH_CHUNK`: all of them) more.
    queue = f"tensor<{2 * 48 + 48}xi32>"
    assert queue in cpu_program and queue not in program
    for got, expected in zip(jax.tree.leaves(elsewhere), jax.tree.leaves(on_cpu), strict=True):
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["box", "hull8", pytest.param("poly8", marks=pytest.mark.slow)])
def test_where_the_second_search_is_skipped_it_cannot_win(name):
    """The search skips its second start where it cannot end higher than the first
    (`_smoothing._maximiser`): where the exact distance exceeds c tau =
    `smoothing_error_bound` * tau (soft_gap is then positive at the first start and has no
    other maximum as high), and where no maximum of gap outside the first's basin reaches the
    first search's end: the runner-up SAT axis's gap and gap(-axis) + extent * apart (the
    worse senses of the candidates near the first axis) are both below it. On 1024 random
    pairs, float64, tau = 0.5% of the size: wherever either holds, searches from the
    runner-up and from the opposite of the first axis end no higher than the first (up to
    rounding; each search run until done, as `_searches` does).
    The rules skip the second search on most pairs, and where they do not, it wins on some
    box and hull pairs (so a rule that skipped every search would fail)."""
    shapes = pool(name, np.float64)
    pairs = random_pairs(shapes, shapes, 1024, np.random.default_rng(74), np.float64)
    apart = 0.05

    def searches(a, params_a, b, params_b):
        frame = pair_frame(a, make_pose(params_a), b, make_pose(params_b))
        extent = jnp.max(jnp.abs(frame.a.vertices)) + jnp.max(jnp.abs(frame.b_vertices))
        tau = np.float64(0.005) * extent
        exact = exact_distance(frame)
        second, second_gap = sat_runner_up(frame, exact.axis, apart)
        opposite_gap = support_gap(-exact.axis, frame.a.vertices, frame.b_vertices)
        return (exact.distance - jaxsat.smoothing_error_bound(a, b) * tau,
                jnp.maximum(second_gap, opposite_gap + extent * apart),
                *(-smoothing._passes(frame, tau, start)[1]
                  for start in (exact.axis, second, -exact.axis)))

    lowest, rival, first, second, opposite = (np.asarray(x) for x in jax.jit(
        jax.vmap(searches), compiler_options=FAST_COMPILE)(*pairs.inputs()))
    clear = lowest > 0
    below = ~clear & (rival < first)
    assert clear.mean() > 0.3 and below.mean() > 0.2, (clear.mean(), below.mean())
    assert np.all(first[clear] > 0)
    for skipped in (clear, below):
        for other in (second, opposite):
            assert np.all(other[skipped] <= first[skipped] + 1e-12), np.max(
                other[skipped] - first[skipped])
    if name != "poly8":  # 2D polygons' second searches won on none of these pairs
        searched = ~clear & ~below
        assert np.any(np.maximum(second, opposite)[searched] > first[searched] + 1e-9)


@pytest.mark.slow
def test_scale_covariance():
    """Scaling shapes, positions and tau by k scales the smooth value by k."""
    values = []
    for scale in (1e-3, 1.0, 1e3):
        rng = np.random.default_rng(54)  # the same draws at every scale
        shapes = make_pool("hull8", np.float64, rng, scale=scale, size=6)
        pairs = random_pairs(shapes, shapes, 32, rng, np.float64, scale=scale)
        values.append(smooth_values(pairs, np.full(32, 0.05 * scale)) / scale)
    np.testing.assert_allclose(values[0], values[1], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(values[2], values[1], rtol=1e-9, atol=1e-12)


# --------------------------------------------------------------------------------------------
# Gradients: central finite differences, forward mode against reverse mode.
# --------------------------------------------------------------------------------------------

FD_STEP = 1e-6


def _flat(tree_leaves) -> np.ndarray:
    return np.concatenate([np.ravel(x) for x in tree_leaves])


def _split(vector: np.ndarray, template):
    """A flat vector back into arrays shaped like the leaves of `template` (a list)."""
    pieces, start = [], 0
    for leaf in template:
        size = int(np.prod(np.shape(leaf)))
        pieces.append(vector[start:start + size].reshape(np.shape(leaf)))
        start += size
    return pieces


def check_finite_differences(pairs: Pairs, taus, rng: np.random.Generator, label="",
                             step=FD_STEP, tolerance=1e-6):
    """The reverse-mode gradient of the smooth value with respect to (vertices of a, pose
    parameters of a, vertices of b, pose parameters of b) against central finite differences
    (float64): along every pose parameter (pose2 x, y, angle; pose3 translation and
    quaternion components) and along random unit directions in the vertices of a, in those
    of b, and in everything at once: |fd - g.d| <= tolerance max(1, |g.d|). Padding vertices
    get exactly zero gradient. Returns the largest |g.d|."""
    inputs = smooth_inputs(pairs, taus)
    _, gradients = run_batched(value_and_gradient_batch, len(pairs), *inputs)
    count, nparams = len(pairs), len(inputs[1])

    def leaves(tree, i):
        vertices_a, params_a, vertices_b, params_b = tree[:4]
        return [vertices_a[i], *(p[i] for p in params_a), vertices_b[i],
                *(p[i] for p in params_b)]

    template = leaves(inputs, 0)
    sizes = [int(np.prod(np.shape(x))) for x in template]
    size = sum(sizes)
    starts = np.cumsum([0, *sizes])
    block_a = np.arange(starts[0], starts[1])  # vertices of a
    block_b = np.arange(starts[1 + nparams], starts[2 + nparams])  # vertices of b
    pose = np.setdiff1d(np.arange(size), np.concatenate([block_a, block_b]))
    directions = [np.eye(size)[k] for k in pose]
    for block in (block_a, block_b, np.arange(size)):
        direction = np.zeros(size)
        direction[block] = rng.normal(size=len(block))
        directions.append(direction / np.linalg.norm(direction))
    directions = np.array(directions)
    ndir = len(directions)
    perturbed = []
    for i in range(count):
        flat = _flat(leaves(inputs, i))
        for direction in directions:
            perturbed += [flat + step * direction, flat - step * direction]
    owners = np.repeat(np.arange(count), 2 * ndir)
    pieces = [_split(v, template) for v in perturbed]
    stacked = [np.stack([p[j] for p in pieces]) for j in range(len(template))]
    fd_inputs = (stacked[0], tuple(stacked[1:1 + nparams]), stacked[1 + nparams],
                 tuple(stacked[2 + nparams:]), take(inputs[4], owners), take(inputs[5], owners),
                 inputs[6][owners])
    values = run_batched(smooth_batch, len(perturbed), *fd_inputs).reshape(count, ndir, 2)
    finite = (values[..., 0] - values[..., 1]) / (2 * step)
    analytic = np.stack([_flat(leaves(gradients, i)) for i in range(count)]) @ directions.T
    assert np.all(np.isfinite(analytic)), label
    error = np.abs(finite - analytic) / np.maximum(1.0, np.abs(analytic))
    worst = np.unravel_index(np.argmax(error), error.shape)
    assert np.max(error) <= tolerance, (f"{label} pair {worst[0]} direction {worst[1]}: finite "
                                   f"difference {finite[worst]!r}, gradient {analytic[worst]!r}")
    # Padding vertices do not take part: zero gradient.
    a, _, b, _ = pairs.inputs()
    for gradient, mask in ((gradients[0], a.vertex_mask), (gradients[2], b.vertex_mask)):
        assert np.all(gradient[~np.asarray(mask)] == 0.0), label
    return np.max(np.abs(analytic))


FD_CLASSES = ["poly8", "box"]
"""Each compiles its own gradient (hull8 would cost as much as both together)."""


@pytest.mark.slow
@pytest.mark.parametrize("name", FD_CLASSES)
def test_gradients_match_finite_differences(name):
    """Random pairs, apart and overlapping, tau = 0.01, 0.05 and 0.2 size (padded polygons
    included in 2D)."""
    rng = np.random.default_rng([55, len(name)])
    shapes = pool(name, np.float64)
    pairs = random_pairs(shapes, shapes, 24, rng, np.float64, distance=(0.0, 2.0))
    refs = references(pairs)
    overlapping = np.array([r.depth > 0 for r in refs])
    assert 0.1 < overlapping.mean() < 0.9
    taus = np.array([0.01, 0.05, 0.2])[np.arange(len(pairs)) % 3] * sizes_of(refs)
    assert check_finite_differences(pairs, taus, rng, name) > 0.1  # not trivially zero
    if name == "poly8":
        a, _, b, _ = pairs.inputs()
        assert not np.all(a.vertex_mask) and not np.all(b.vertex_mask)


@pytest.mark.slow
@pytest.mark.parametrize("dim", [2, 3])
def test_gradients_match_finite_differences_at_degenerate_features_apart(dim):
    """The delicate feature pairs (vertex-vertex, corner to corner with every edge parallel,
    face-face flush, (nearly) parallel and crossing edges) apart by tau and 3 tau, where the
    smooth value is differentiable, at the identity and under a common rigid motion; and
    face-face contacts touching and overlapping, where tied vertices keep it smooth.

    Touching through two vertices (or a vertex and an edge, or parallel edges) is a kink of
    the smooth value too: log-sum-exp smooths where vertices tie in projection, and no other
    vertex of either shape is within tau there (see jaxsat/_smoothing.py)."""
    rng = np.random.default_rng([61, dim])
    motion = ((0.7, np.array([0.3, -1.2])) if dim == 2
              else (np.array([0.9, -0.2, 0.4, 0.3]), np.array([0.3, -1.2, 0.5])))
    for tau in (0.05, 0.2):
        for moved in (None, motion):
            label = f"{dim}D tau {tau}{' moved' if moved else ''}"
            pairs, names, _, _ = delicate_pairs(dim, (tau, 3 * tau), moved)
            check_finite_differences(pairs, np.full(len(pairs), tau), rng, label + " apart")
            pairs, names, _, _ = delicate_pairs(dim, (0.0, -0.3 * tau), moved)
            flat = np.array([name.startswith("face-face") or name == "edge-edge"
                             for name in names])
            check_finite_differences(pairs.subset(flat), np.full(int(flat.sum()), tau), rng,
                                     label + " face contact")


@pytest.mark.slow
def test_forward_mode_matches_reverse_mode():
    """jacfwd and grad (reverse mode) of the smooth value agree (vertices and pose
    parameters), at random and at degenerate configurations."""
    rng = np.random.default_rng(56)
    shapes = pool("poly8", np.float64)
    pairs = random_pairs(shapes, shapes, 32, rng, np.float64)
    delicate, _, _, _ = delicate_pairs(2, (0.0, 1e-4))
    for group in (pairs, delicate):
        inputs = smooth_inputs(group, np.full(len(group), 0.1))
        forward = run_batched(forward_batch, len(group), *inputs)
        _, reverse = run_batched(value_and_gradient_batch, len(group), *inputs)
        for f, r in zip(jax.tree.leaves(forward), jax.tree.leaves(reverse), strict=True):
            assert np.all(np.isfinite(f))
            np.testing.assert_allclose(f, r, rtol=1e-10, atol=1e-12)


def _flat_pose_value(theta, a, b, tau):
    """The smooth value as a function of both shapes' pose parameters in one flat vector:
    (x, y, angle) each in 2D, (translation, quaternion) each in 3D."""
    width = 3 if a.dim == 2 else 7
    split = (lambda p: (p[0], p[1], p[2])) if a.dim == 2 else (lambda p: (p[:3], p[3:]))
    return jaxsat.signed_distance(a, make_pose(split(theta[:width])), b,
                                  make_pose(split(theta[width:])), smoothing=tau)


flat_gradient_batch = jax.jit(jax.vmap(jax.grad(_flat_pose_value)), compiler_options=FAST_COMPILE)
# The default build, as a user's jit compiles it: second derivatives are checked in the
# build an optimiser runs (on these pairs the eager settings give the same Hessians, finite,
# within 5e-14).
flat_hessian_batch = jax.jit(jax.vmap(jax.hessian(_flat_pose_value)))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["poly8", "box"])
def test_second_derivatives_match_finite_differences(name):
    """Apart, the smooth value is infinitely differentiable: its Hessian in the pose
    parameters (autodiff through the maximising axis, by the implicit function theorem)
    equals central finite differences of its gradient, on random separated pairs."""
    rng = np.random.default_rng([63, len(name)])
    shapes = pool(name, np.float64)
    pairs = random_pairs(shapes, shapes, 48, rng, np.float64, distance=(1.0, 2.5))
    refs = references(pairs)
    apart = np.flatnonzero([r.value > 0.05 * r.size for r in refs])[:16]
    pairs, refs = pairs.subset(apart), [refs[i] for i in apart]
    taus = 0.05 * sizes_of(refs)
    a, params_a, b, params_b = pairs.inputs()
    theta = np.concatenate([np.reshape(p, (len(pairs), -1))
                            for p in (*params_a, *params_b)], axis=1)
    hessian = run_batched(flat_hessian_batch, len(pairs), theta, a, b, taus)
    step = 1e-5
    finite = np.zeros_like(hessian)
    for k in range(theta.shape[1]):
        shifted = [run_batched(flat_gradient_batch, len(pairs),
                               theta + sign * step * np.eye(theta.shape[1])[k], a, b, taus)
                   for sign in (1.0, -1.0)]
        finite[:, :, k] = (shifted[0] - shifted[1]) / (2 * step)
    error = np.abs(hessian - finite) / np.maximum(1.0, np.abs(hessian))
    assert np.max(error) <= 1e-5, np.max(error)
    assert np.max(np.abs(hessian)) > 0.1  # curvature is really there


# --------------------------------------------------------------------------------------------
# Continuity: along paths through contact and overlap, and through switches of the axis.
# --------------------------------------------------------------------------------------------


def _path_pairs(shape_a, points_a, shape_b, points_b, params_a, params_b) -> Pairs:
    count = len(params_b[0])
    return Pairs(hand_pool(shape_a.dim, [(shape_a, points_a)]),
                 hand_pool(shape_b.dim, [(shape_b, points_b)]), np.zeros(count, int),
                 np.zeros(count, int), params_a, params_b, np.float64)


@pytest.mark.parametrize("name", ["poly8", *(pytest.param(name, marks=pytest.mark.slow)
                                            for name in ("box", "hull8"))])
def test_value_is_one_lipschitz_along_translation_paths(name):
    """b slides along a straight line from clear separation through contact into deep
    overlap (its vertex centroid through a's) and out, in steps of 0.02: the smooth value
    changes by at most the step (it is 1-Lipschitz in translation, so continuous), including
    where the maximising axis swaps, at tau = 0.003 and 0.01 of the size.

    At larger tau (0.03 to 0.1 of the size) the two starts of the search can miss the global
    maximum in deep overlaps where three or more penetration directions compete, and the
    value jumps by up to 0.5 tau there (on 2-13% of such paths; stated in README.md,
    "Signed distance, closest points and smooth gradients")."""
    rng = np.random.default_rng([64, len(name)])
    shapes = pool(name, np.float64)
    base = random_pairs(shapes, shapes, 8, rng, np.float64)
    dim = shapes.dim
    count, step = 256, 0.02
    t = step * (np.arange(count) - count // 2)  # 2.5 either side
    world_a, world_b = world_points(base)
    for tau in (0.003, 0.01):
        for i in range(len(base)):
            direction = rng.normal(size=dim)
            direction /= np.linalg.norm(direction)
            # b's translation that puts its vertex centroid on a's.
            offset = world_b[i].mean(axis=0) - translations(dim, base.params_b)[i]
            centre = world_a[i].mean(axis=0) - offset
            path = centre[None, :] + t[:, None] * direction[None, :]
            one = base.subset(np.full(count, i))
            params_b = ((path[:, 0], path[:, 1], one.params_b[2]) if dim == 2
                        else (path, one.params_b[1]))
            values = smooth_values(dataclasses.replace(one, params_b=params_b),
                                   np.full(count, tau))
            assert np.max(np.abs(np.diff(values))) <= step * (1 + 1e-9), (name, i, tau)
            assert values.min() < 0 < values.max()  # the path crosses contact


def _check_smooth_along(pairs: Pairs, step: float, tau: float):
    """Along a path sampled every `step` (a unit-speed motion of b across a switch of the
    exact winning axis, over several tau): the slope of the oracle's exact value jumps (a
    kink), while the smooth value's slope and its whole gradient in the pose parameters
    change by at most a few step / tau per step, and by far less than the exact slope jumps."""
    refs = references(pairs)
    exact = exact_values(refs)
    inputs = smooth_inputs(pairs, np.full(len(pairs), tau))
    values, gradients = run_batched(value_and_gradient_batch, len(pairs), *inputs)
    pose_gradient = np.concatenate([np.reshape(g, (len(pairs), -1))
                                    for g in (*gradients[1], *gradients[3])], axis=1)
    exact_jump = np.max(np.abs(np.diff(exact, 2))) / step
    smooth_jump = np.max(np.abs(np.diff(values, 2))) / step
    gradient_jump = np.max(np.abs(np.diff(pose_gradient, axis=0)))
    assert np.max(np.abs(np.diff(values))) <= 2.0 * step
    assert exact_jump > 0.2, exact_jump
    assert smooth_jump <= step / tau, smooth_jump
    assert smooth_jump <= 0.1 * exact_jump, (smooth_jump, exact_jump)
    assert gradient_jump <= 3.0 * step / tau, gradient_jump
    lost = exact - values
    assert np.all((lost >= -1e-12) & (lost <= bounds(pairs) * tau + 1e-12))
    return values, exact


def test_continuity_through_closest_feature_switch_2d():
    """Apart: a small square above a big one's top edge turns through the angle where its
    edge is parallel to it; the closest feature of b switches from one corner to the other,
    and the exact value 0.7 - 0.5 (cos t + |sin t|) has a kink at t = 0, which the smooth
    value rounds off (the two corners tie in projection there)."""
    step, tau = 1e-3, 0.01
    turn = step * (np.arange(BATCH) - BATCH // 2)
    zeros = np.zeros(BATCH)
    pairs = _path_pairs(jaxsat.box([1.0, 1.0], max_vertices=8), SQUARE,
                        jaxsat.box([0.5, 0.5], max_vertices=8), 0.5 * SQUARE,
                        (zeros, zeros, zeros), (np.full(BATCH, 0.3), np.full(BATCH, 1.7), turn))
    _, exact = _check_smooth_along(pairs, step, tau)
    np.testing.assert_allclose(exact, 0.7 - 0.5 * (np.cos(turn) + np.abs(np.sin(turn))),
                               atol=1e-12)


def _check_kink_along(pairs: Pairs, step: float, tau: float):
    """Along a path where two penetration directions swap: the smooth value is continuous
    (1-Lipschitz, as b moves at unit speed) and within the bound, and its gradient jumps once,
    by at most 2 in b's translation (it switches between two unit vectors) -- the kink that
    jaxsat/_smoothing.py and the README document."""
    refs = references(pairs)
    inputs = smooth_inputs(pairs, np.full(len(pairs), tau))
    values, gradients = run_batched(value_and_gradient_batch, len(pairs), *inputs)
    assert np.max(np.abs(np.diff(values))) <= step * (1 + 1e-9)
    lost = exact_values(refs) - values
    assert np.all((lost >= -1e-12) & (lost <= bounds(pairs) * tau + 1e-12))
    translation = (np.stack(gradients[3][:2], axis=1) if pairs.dim == 2 else gradients[3][0])
    jumps = np.linalg.norm(np.diff(translation, axis=0), axis=1)
    assert 0.1 < np.max(jumps) <= 2.0
    assert np.sum(jumps > 0.1) == 1  # one switch, not a chatter
    return jumps


def test_kink_where_penetration_directions_tie_2d():
    """A small square slides through a big one near its top edge: the exact penetration
    direction switches from the x axis to the y axis at |x| = 0.7; the smooth value stays
    continuous and its gradient switches once, near there."""
    step, tau = 1e-3, 0.01
    x = 0.7 + step * (np.arange(BATCH) - BATCH // 2)
    zeros = np.zeros(BATCH)
    pairs = _path_pairs(jaxsat.box([1.0, 1.0], max_vertices=8), SQUARE,
                        jaxsat.box([0.5, 0.5], max_vertices=8), 0.5 * SQUARE,
                        (zeros, zeros, zeros), (x, np.full(BATCH, 0.7), zeros))
    jumps = _check_kink_along(pairs, step, tau)
    assert abs(np.argmax(jumps) - BATCH // 2) <= 8  # within a few tau of the exact switch
    np.testing.assert_allclose(exact_values(references(pairs)), -np.minimum(0.8, 1.5 - np.abs(x)),
                               atol=1e-12)


@pytest.mark.slow  # the 2D kink stays in the fast subset
def test_kink_where_penetration_directions_tie_3d():
    """A small box turning about a fixed axis while overlapping a cube near its corner: a
    coarse sweep with the oracle finds where the exact normal switches, bisection pins it
    down, then b slides along a straight line across it: continuous value, one gradient
    switch."""
    half = np.array([0.3, 0.5, 0.7])
    axis = np.array([0.3, -0.5, 0.8])
    base = quaternion([1.0, 2.0, 0.5], 0.7)

    def pairs_at(angles, shift=None):
        count = len(angles)
        quaternions = np.array([quaternion_product(quaternion(axis, t), base) for t in angles])
        position = np.tile([1.05, 0.9, 0.4], (count, 1)) + (0 if shift is None else shift)
        return _path_pairs(jaxsat.box([1.0, 1.0, 1.0]), CUBE, jaxsat.box(half), CUBE * half,
                           (np.zeros((count, 3)), np.tile(IDENTITY, (count, 1))),
                           (position, quaternions))

    coarse = np.linspace(0.0, np.pi, 91)
    normals = np.array([r.normal for r in references(pairs_at(coarse))])
    switches = np.flatnonzero(np.max(np.abs(np.diff(normals, axis=0)), axis=1) > 0.1)
    assert len(switches) > 0
    low, high = coarse[switches[0]], coarse[switches[0] + 1]
    start = references(pairs_at([low]))[0].normal
    for _ in range(30):
        middle = 0.5 * (low + high)
        if np.max(np.abs(references(pairs_at([middle]))[0].normal - start)) > 0.1:
            high = middle
        else:
            low = middle
    step, tau = 1e-3, 0.01
    # Slide b (at the switch angle) along the bisector of the two penetration normals.
    before = references(pairs_at([low]))[0].normal
    after = references(pairs_at([high]))[0].normal
    direction = (after - before) / np.linalg.norm(after - before)
    along = step * (np.arange(BATCH) - BATCH // 2)
    pairs = pairs_at(np.full(BATCH, 0.5 * (low + high)), along[:, None] * direction[None, :])
    _check_kink_along(pairs, step, tau)
    assert np.all(exact_values(references(pairs)) < 0)  # overlapping all along


# --------------------------------------------------------------------------------------------
# smoothing_error_bound, and tau as a traced value.
# --------------------------------------------------------------------------------------------


def test_bound_values():
    """The bound is log(n_a n_b): it grows with the vertex count, ignores padding, is
    symmetric, and has the documented sizes (about 4.2 for two 8-gons or two boxes, 6 for
    two 20-vertex hulls). (Jitted, and mostly on shapes padded to one size.)"""
    square = jaxsat.box([1.0, 1.0], max_vertices=8)
    polygons = [jaxsat.regular_polygon(n, 1.0, max_vertices=8) for n in range(3, 9)]
    values = [float(bound_of(p, square)) for p in polygons]
    assert np.all(np.diff(values) > 0)
    for n, p in zip(range(3, 9), polygons, strict=True):
        assert float(bound_of(square, p)) == pytest.approx(values[n - 3])
        assert values[n - 3] == pytest.approx(np.log(4 * n))
    unpadded = float(bound_of(jaxsat.regular_polygon(5, 2.0), jaxsat.box([1.0, 1.0])))
    assert unpadded == pytest.approx(values[2])
    octagons = float(bound_of(polygons[-1], polygons[-1]))
    boxes = float(bound_of(jaxsat.box([1.0, 2, 3]), jaxsat.box([1.0, 1, 1])))
    rng = np.random.default_rng(57)
    hulls = []
    for count in (8, 20):
        sphere = rng.normal(size=(count, 3))
        hulls.append(jaxsat.polyhedron(sphere / np.linalg.norm(sphere, axis=1, keepdims=True),
                                       max_vertices=20))
        assert int(np.sum(hulls[-1].vertex_mask)) == count  # every point is a hull vertex
    padded_box = jaxsat.box([1.0, 2, 3], max_vertices=20)
    hull8, hull20 = hulls
    twenties = float(bound_of(hull20, hull20))
    assert octagons == pytest.approx(np.log(64)) and boxes == pytest.approx(np.log(64))
    assert twenties == pytest.approx(np.log(400))
    assert float(bound_of(hull8, hull8)) < twenties
    assert float(bound_of(padded_box, jaxsat.box([1.0, 1, 1], max_vertices=20))) == \
        pytest.approx(boxes)


def test_bound_on_batches():
    """Stacked shapes give one bound per pair (eagerly too); a single shape broadcasts; vmap
    agrees."""
    rng = np.random.default_rng(58)
    for name in ("poly8", "hull8"):
        shapes = make_pool(name, np.float64, rng, size=5).shapes
        singles = [take(shapes, i) for i in range(5)]
        each = np.array([float(bound_of(x, y))
                         for x, y in zip(singles, singles[::-1], strict=True)])
        reversed_stack = take(shapes, np.arange(5)[::-1])
        stacked = np.asarray(jaxsat.smoothing_error_bound(shapes, reversed_stack))
        assert stacked.shape == (5,)
        np.testing.assert_allclose(stacked, each, rtol=1e-12)
        mapped = jax.jit(jax.vmap(jaxsat.smoothing_error_bound))(shapes, reversed_stack)
        np.testing.assert_allclose(mapped, each, rtol=1e-12)
        broadcast = np.asarray(bound_of(singles[0], shapes))
        np.testing.assert_allclose(broadcast, [float(bound_of(singles[0], y))
                                               for y in singles], rtol=1e-12)
    shapes32 = make_pool("box", np.float32, rng, size=2).shapes
    assert bound_of(shapes32, shapes32).dtype == np.float32


def test_bound_rejects_mismatched_shapes():
    """Shapes of different dimensions: ValueError; something other than a Polytope:
    TypeError."""
    square, cube = jaxsat.box([1.0, 1.0]), jaxsat.box([1.0, 1.0, 1.0])
    for a, b in ((square, cube), (cube, square)):
        with pytest.raises(ValueError, match="dimension"):
            jaxsat.smoothing_error_bound(a, b)
    with pytest.raises(TypeError, match="Polytope"):
        jaxsat.smoothing_error_bound(square, np.zeros((4, 2)))


@pytest.mark.slow
def test_traced_tau_under_jit():
    """tau as a traced argument of jit gives the eager value with a Python tau and the value
    of the batched function; one compiled function serves every tau."""
    rng = np.random.default_rng(59)
    shapes = pool("poly8", np.float64)
    pairs = random_pairs(shapes, shapes, 1, rng, np.float64)
    a, params_a, b, params_b = take(pairs.inputs(), 0)
    pose_a, pose_b = make_pose(params_a), make_pose(params_b)
    traced = jax.jit(lambda t: jaxsat.signed_distance(a, pose_a, b, pose_b, smoothing=t))
    eager = jaxsat.signed_distance(a, pose_a, b, pose_b, smoothing=0.05)
    assert float(traced(0.05)) == pytest.approx(float(eager), abs=1e-12)
    taus = [0.5, 0.1, 0.05, 0.01]
    values = [float(traced(t)) for t in taus]
    batched = smooth_values(pairs.subset([0] * len(taus)), taus)
    np.testing.assert_allclose(values, batched, atol=1e-12)
    assert traced._cache_size() == 1
    exact = references(pairs)[0].value
    bound = float(bound_of(a, b))
    for t, v in zip(taus, values, strict=True):
        assert abs(v - exact) <= bound * t + 1e-9


def _zero_smoothing(a, params_a, b, params_b):
    return jaxsat.signed_distance(a, make_pose(params_a), b, make_pose(params_b))


zero_batch = jax.jit(jax.vmap(_zero_smoothing), compiler_options=FAST_COMPILE)


@pytest.mark.slow
def test_zero_smoothing_is_exact():
    """smoothing=None is the exact value (the oracle's); a small tau is close to it, and
    differs from it for most pairs (for some, every term but the largest underflows)."""
    rng = np.random.default_rng(62)
    shapes = pool("poly8", np.float64)
    pairs = random_pairs(shapes, shapes, BATCH, rng, np.float64)
    refs = references(pairs)
    default = run_batched(zero_batch, len(pairs), *pairs.inputs())
    np.testing.assert_allclose(default, exact_values(refs), rtol=0, atol=1e-9)
    smooth = smooth_values(pairs, np.full(len(pairs), 1e-6))
    assert np.mean(smooth != default) > 0.5
    assert np.all(np.abs(smooth - default) <= bounds(pairs) * 1e-6 + 1e-9)


@pytest.mark.slow
def test_float32():
    """float32 shapes, poses and tau: float32 values within the bound (plus float32 error)."""
    rng = np.random.default_rng(60)
    shapes = pool("poly8", np.float32)
    pairs = random_pairs(shapes, shapes, BATCH, rng, np.float32)
    refs = references(pairs)
    taus = np.where(np.arange(BATCH) % 2 == 0, 0.01, 0.1) * sizes_of(refs)
    values = smooth_values(pairs, taus.astype(np.float32))
    assert values.dtype == np.float32
    errors = np.abs(values.astype(np.float64) - exact_values(refs))
    assert np.all(errors <= bounds(pairs) * taus + 1e-4 * sizes_of(refs))


@pytest.mark.slow
def test_traced_zero_smoothing_is_finite_and_exact_up_to_rounding():
    """Regression: a traced tau of 0 divided by zero (NaN); it is now floored at a few ulps."""
    square = jaxsat.box([1.0, 1.0])
    origin = jaxsat.pose2(0.0, 0.0, 0.0)

    def smooth(tau, x):
        return jaxsat.signed_distance(square, origin, square, jaxsat.pose2(x, 3.0, 0.0),
                                      smoothing=tau)

    value = jax.jit(smooth)(0.0, 3.0)
    assert abs(float(value) - 2**0.5) < 1e-9
    grads = jax.jit(jax.grad(smooth, argnums=(0, 1)))(0.0, 3.0)
    assert all(np.isfinite(g) for g in grads)
    assert abs(float(grads[1]) - 0.5**0.5) < 1e-6
