"""Numerical stability of jaxsat.signed_distance and of its derivatives.

The named catalogue of degenerate configurations in `harness.py` (identical shapes, exact
contacts of every feature type, parallel and nearly parallel edges, padding, tiny and huge
scales, shapes far from the origin, zero quaternions, nested shapes, large angles) is checked
in float32 and float64, exact (smoothing=None) and smooth (smoothing=tau > 0), for:

* finite values, and finite reverse-mode (what jax.grad evaluates) and forward-mode (what
  jax.jacfwd evaluates) derivatives with respect to the pose parameters (pose2's x, y, angle;
  pose3's translation and quaternion), reverse mode also to the local vertices of both shapes
  (`dataclasses.replace(shape, vertices=v)`), both from one linearization (`_everything`);
* forward mode == reverse mode (the JVP rules against their transposes);
* the exact value against the independent SciPy oracle (`oracle.py`), the smooth value within
  smoothing_error_bound * tau of it, and the sign against jaxsat.intersects;
* float32 against float64 (same float32-representable inputs), relative to the shapes' size;
* (float64) the smooth gradient against central finite differences.

Random configurations add: the exact gradient against central finite differences (where the
value is locally smooth), and hypothesis properties (finite values and derivatives, sign
consistency with intersects, the oracle, invariance under a common rigid motion).

Compile time dominates this module, so every check reuses a few jitted functions: one
derivative function (`_everything`) per size class and dtype (2D polygons padded to 8
vertices, 3D boxes, 3D hulls padded to 8 vertices) and one vmapped value function per size
class for finite differences. They are compiled with XLA's backend optimisations off
(`FAST_COMPILE`), which compiles about 3x faster; the traced computation is the same
(benchmarks/stability.py runs the default, optimised compile on 100,000+ configurations).
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from harness import (
    CATALOGUE,
    CLASSES,
    DTYPE_IDS,
    DTYPES,
    FAST_COMPILE,
    HUGE,
    NAMES,
    TINY,
    Config,
    apply_motion,
    build,
    corners,
    oracle_reference,
    random_motion,
    reference,
)
from hypothesis import given
from hypothesis import strategies as st

import jaxsat

pytestmark = pytest.mark.slow  # the fast subset is -m "not slow"

TAU = 0.1
"""Smoothing length, relative to a configuration's length unit."""

VALUE_TOLERANCE = {np.float64: 1e-9, np.float32: 2e-5}
"""Value tolerance relative to the configuration's size (shape radii plus their distance)."""

DERIVATIVE_TOLERANCE = {np.float64: 1e-9, np.float32: 1e-4}
"""jacfwd vs grad, relative to the largest entry of the group (or its unit)."""


# --------------------------------------------------------------------------------------------
# The jitted functions.
# --------------------------------------------------------------------------------------------


def _distance(params_a, params_b, vertices_a, vertices_b, a, b, smoothing):
    a = dataclasses.replace(a, vertices=vertices_a)
    b = dataclasses.replace(b, vertices=vertices_b)
    pose_a, pose_b = _poses(params_a, params_b)
    return jaxsat.signed_distance(a, pose_a, b, pose_b, smoothing=smoothing)


GROUPS = ("params_a", "params_b", "vertices_a", "vertices_b")
"""The inputs of `_distance` that reverse mode differentiates, in order."""
POSE_ARGNUMS = (0, 1)
"""The inputs that forward mode differentiates: the poses' parameters."""


def _poses(params_a, params_b):
    if len(params_a) == 3:
        return (jaxsat.pose2(params_a[0], params_a[1], params_a[2]),
                jaxsat.pose2(params_b[0], params_b[1], params_b[2]))
    return jaxsat.pose3(params_a[:3], params_a[3:]), jaxsat.pose3(params_b[:3], params_b[3:])


def _everything(params_a, params_b, a, b, tau):
    """Values and derivatives of the exact and the smooth signed distance, and intersects:
    reverse mode with respect to both poses' parameters and both shapes' vertices, and
    forward mode with respect to both poses' parameters.

    Both from one `jax.linearize` per distance: forward mode is its JVP along each basis
    vector of a pose's parameters (what `jax.jacfwd` evaluates), reverse mode the JVP's
    transpose (what `jax.grad` evaluates: JAX's reverse mode is the transposed
    linearization). The searches are then traced and compiled once per distance, where the
    value, `jax.grad` and `jax.jacfwd` each traced them: a 3D class's program compiles in
    0.44x the time (box, float64: 11.5 -> 5.1 s on a 2-core AMD EPYC), with the same values
    and derivatives up to rounding."""
    inputs = (params_a, params_b, a.vertices, b.vertices)
    out = {}
    for name, smoothing in (("exact", None), ("smooth", tau)):
        value, linear = jax.linearize(
            functools.partial(_distance, a=a, b=b, smoothing=smoothing), *inputs)
        zeros = [jnp.zeros_like(x) for x in inputs]

        def along(tangent, argnum, zeros=zeros, linear=linear):
            return linear(*(tangent if k == argnum else zero for k, zero in enumerate(zeros)))

        out[name] = {
            "value": value,
            "grad": jax.linear_transpose(linear, *inputs)(jnp.ones_like(value)),
            "jacfwd": tuple(jax.vmap(functools.partial(along, argnum=k))(
                jnp.eye(inputs[k].shape[0], dtype=inputs[k].dtype)) for k in POSE_ARGNUMS),
        }
    pose_a, pose_b = _poses(params_a, params_b)
    out["intersects"] = jaxsat.intersects(a, pose_a, b, pose_b)
    return out


def _smooth_values(params_a, params_b, vertices_a, vertices_b, a, b, tau):
    """The smooth value with the vertices replaced (stored normals and edges held fixed)."""
    return _distance(params_a, params_b, vertices_a, vertices_b, a, b, tau)


def _exact_values(params_a, params_b, a, b):
    """The exact value of (rebuilt) shapes."""
    return _distance(params_a, params_b, a.vertices, b.vertices, a, b, None)


FD_BATCH = 128
"""Finite differences evaluate perturbed inputs in batches of this many (one compile)."""

REBUILT = {"poly8": "poly8", "box": "hull8", "hull8": "hull8"}
"""Size class of the shapes rebuilt from perturbed vertices: a perturbed box is a hull."""


def _example(kind: str, dtype):
    """Arguments of the right shapes for one size class (to compile ahead of time)."""
    config = next(c for c in CATALOGUE.values() if c.kind == kind)
    a, b = build(kind, config.points_a, dtype), build(kind, config.points_b, dtype)
    return (jnp.asarray(config.params_a, dtype), jnp.asarray(config.params_b, dtype), a, b,
            jnp.asarray(TAU, dtype))


def _compile(key):
    what, kind, dtype = key
    params_a, params_b, a, b, tau = _example(kind, dtype)
    batch = lambda x: jnp.broadcast_to(x, (FD_BATCH, *x.shape))  # noqa: E731
    if what == "everything":
        function = jax.jit(_everything, compiler_options=FAST_COMPILE)
        return function.lower(params_a, params_b, a, b, tau).compile()
    if what == "exact":
        function = jax.jit(jax.vmap(_exact_values), compiler_options=FAST_COMPILE)
        return function.lower(batch(params_a), batch(params_b), jax.tree.map(batch, a),
                              jax.tree.map(batch, b)).compile()
    function = jax.jit(jax.vmap(_smooth_values, in_axes=(0, 0, 0, 0, None, None, None)),
                       compiler_options=FAST_COMPILE)
    return function.lower(batch(params_a), batch(params_b), batch(a.vertices),
                          batch(b.vertices), a, b, tau).compile()


KEYS = ([("everything", kind, dtype) for kind in CLASSES for dtype in DTYPES]
        + [("smooth", kind, np.float64) for kind in CLASSES]
        + [("exact", kind, np.float64) for kind in ("poly8", "hull8")])
_EXECUTABLES: dict = {}


@pytest.fixture(scope="module", autouse=True)
def _compile_ahead():
    """Compile the module's executables (one per size class and dtype, and one value function
    per size class for finite differences) on two threads: XLA compiles without the GIL."""
    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        _EXECUTABLES.update(zip(KEYS, pool.map(_compile, KEYS), strict=True))
    yield


def executable(what: str, kind: str, dtype):
    key = (what, kind, dtype)
    if key not in _EXECUTABLES:
        _EXECUTABLES[key] = _compile(key)
    return _EXECUTABLES[key]


@dataclasses.dataclass
class Evaluated:
    """What `_everything` returns, as NumPy (float64) arrays."""

    exact: dict
    smooth: dict
    intersects: bool
    tau: float


def evaluate(config: Config, dtype) -> Evaluated:
    a = build(config.kind, config.points_a, dtype)
    b = build(config.kind, config.points_b, dtype)
    tau = TAU * config.unit
    out = executable("everything", config.kind, dtype)(
        jnp.asarray(config.params_a, dtype), jnp.asarray(config.params_b, dtype), a, b,
        jnp.asarray(tau, dtype))
    for name in ("exact", "smooth"):
        assert out[name]["value"].dtype == dtype
    out = jax.tree.map(lambda x: np.asarray(x, np.float64), out)
    return Evaluated(out["exact"], out["smooth"], bool(out["intersects"]), tau)


@functools.cache
def evaluate_named(name: str, dtype) -> Evaluated:
    return evaluate(CATALOGUE[name], dtype)


# --------------------------------------------------------------------------------------------
# Checks shared by the catalogue and the random configurations.
# --------------------------------------------------------------------------------------------


def check_finite_and_consistent(result: Evaluated, dtype, unit: float, label: str):
    """Finite value and derivatives; jacfwd == grad (pose parameters), entrywise
    within a tolerance relative to the group's largest entry (at least max(1, unit): angle
    and quaternion derivatives scale with the length unit)."""
    tolerance = DERIVATIVE_TOLERANCE[dtype]
    floor = max(1.0, unit)
    for name in ("exact", "smooth"):
        part = getattr(result, name)
        assert np.isfinite(part["value"]), f"{label} {name}: value {part['value']}"
        for transform in ("grad", "jacfwd"):
            for group, array in zip(GROUPS, part[transform], strict=False):
                assert np.all(np.isfinite(array)), f"{label} {name} {transform} {group}: {array}"
        for index, group in enumerate(GROUPS[:2]):
            reverse = part["grad"][index]
            scale = max(np.max(np.abs(reverse)), floor)
            np.testing.assert_allclose(
                part["jacfwd"][index], reverse, rtol=0, atol=tolerance * scale,
                err_msg=f"{label} {name} jacfwd != grad ({group})")


def check_values(result: Evaluated, exact: float, size: float, dtype, label: str,
                 bound: float):
    """Exact value vs the oracle, smooth within bound * tau of it, sign vs intersects."""
    tolerance = VALUE_TOLERANCE[dtype] * size
    value = result.exact["value"]
    assert abs(value - exact) <= tolerance, f"{label}: exact {value!r} != oracle {exact!r}"
    smooth = result.smooth["value"]
    assert abs(smooth - value) <= bound * result.tau + tolerance, (
        f"{label}: smooth {smooth!r} vs exact {value!r}, bound {bound} * tau {result.tau}")
    if result.intersects:
        assert value <= tolerance, f"{label}: intersects but signed distance {value!r}"
    else:
        assert value >= -tolerance, f"{label}: apart but signed distance {value!r}"


def error_bound(config: Config) -> float:
    a = build(config.kind, config.points_a, np.float64)
    b = build(config.kind, config.points_b, np.float64)
    return float(jaxsat.smoothing_error_bound(a, b))


# --------------------------------------------------------------------------------------------
# Central finite differences (float64).
# --------------------------------------------------------------------------------------------


def _steps(config: Config, vertex_count: int, relative: float) -> np.ndarray:
    """Per-parameter step: relative * unit for lengths, relative for 2D angles, relative * |q|
    for quaternion entries (0 where the quaternion is zero: not differentiated there)."""
    steps = []
    for params in (config.params_a, config.params_b):
        if config.dim == 2:
            steps.append([relative * config.unit] * 2 + [relative])
        else:
            norm = np.linalg.norm(params[3:])
            quaternion_step = 0.0 if config.zero_quaternion else relative * norm
            steps.append([relative * config.unit] * 3 + [quaternion_step] * 4)
    return np.concatenate([*map(np.asarray, steps),
                           np.full(vertex_count, relative * config.unit)])


def _perturbed(theta: np.ndarray, steps: np.ndarray):
    """Central perturbations of every parameter: (2 N, N) rows (plus, then minus), and the
    steps as rounded."""
    plus, minus = theta + np.diag(steps), theta - np.diag(steps)
    return np.concatenate([plus, minus]), np.diagonal(plus) - np.diagonal(minus)


def _central(values: np.ndarray, steps: np.ndarray, actual: np.ndarray) -> np.ndarray:
    count = len(steps)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(steps > 0, (values[:count] - values[count:]) / actual, np.nan)


def _batches(rows: np.ndarray):
    """`rows` in FD_BATCH-sized chunks (the last one filled up by repetition)."""
    padded = np.resize(rows, (-(-len(rows) // FD_BATCH) * FD_BATCH, *rows.shape[1:]))
    return [padded[start:start + FD_BATCH] for start in range(0, len(padded), FD_BATCH)]


@functools.cache
def smooth_finite_differences(name: str, relative: float = 1e-6):
    """(central, forward, backward) differences of the smooth value (float64) of catalogue
    entry `name` in every pose parameter and stored vertex coordinate (padding included), the
    vertices replaced in the built shapes (NaN where not differentiated)."""
    config = CATALOGUE[name]
    a = build(config.kind, config.points_a, np.float64)
    b = build(config.kind, config.points_b, np.float64)
    theta = np.concatenate([config.params_a, config.params_b,
                            np.asarray(a.vertices).ravel(), np.asarray(b.vertices).ravel()])
    steps = _steps(config, a.vertices.size + b.vertices.size, relative)
    rows, actual = _perturbed(theta, steps)
    rows = np.concatenate([rows, theta[None]])
    p, va, vb = len(config.params_a), a.vertices.shape, b.vertices.shape
    function = executable("smooth", config.kind, np.float64)
    tau = jnp.asarray(TAU * config.unit)
    values = []
    for chunk in _batches(rows):
        pa, pb, flat_a, flat_b = np.split(chunk, np.cumsum([p, p, int(np.prod(va))]), axis=1)
        values.append(np.asarray(function(pa, pb, flat_a.reshape(-1, *va),
                                          flat_b.reshape(-1, *vb), a, b, tau)))
    values = np.concatenate(values)[:len(rows)]
    count, centre = len(steps), values[-1]
    with np.errstate(invalid="ignore", divide="ignore"):
        forward = np.where(steps > 0, (values[:count] - centre) / (actual / 2), np.nan)
        backward = np.where(steps > 0, (centre - values[count:2 * count]) / (actual / 2), np.nan)
    return _central(values[:-1], steps, actual), forward, backward


def _between_one_sided(gradient: np.ndarray, name: str) -> bool:
    _, forward, backward = smooth_finite_differences(name)
    used = np.isfinite(forward)
    slack = 1e-4 * max(np.max(np.abs(gradient[used])), 1.0)
    return bool(np.all(gradient[used] <= forward[used] + slack)
                and np.all(gradient[used] >= backward[used] - slack))


def check_between_one_sided(gradient: np.ndarray, name: str, label: str):
    """At a kink the smooth value is a maximum over branches, so along every coordinate its
    gradient (one branch's) lies between the backward and the forward difference."""
    assert _between_one_sided(gradient, name), label
    _, forward, backward = smooth_finite_differences(name)
    used = np.isfinite(forward)
    slack = 1e-4 * max(np.max(np.abs(gradient[used])), 1.0)
    assert np.any(forward[used] - backward[used] > 10 * slack), f"{label}: no kink here"


def _raw(shape: jaxsat.Polytope) -> np.ndarray:
    return np.asarray(shape.vertices)[np.asarray(shape.vertex_mask)]


def _rebuild(dim: int, points: np.ndarray) -> jaxsat.Polytope:
    shape = (jaxsat.polygon(points, 8) if dim == 2 else jaxsat.polyhedron(points, 8))
    # The constructors keep the order of points that are all hull vertices (CCW in 2D).
    np.testing.assert_allclose(_raw(shape), points, rtol=0, atol=0)
    return shape


def exact_finite_differences(config: Config, relative: float):
    """Central differences of the exact value (float64) in every pose parameter and real
    vertex coordinate, the shapes REBUILT from the perturbed vertices (polygon/polyhedron):
    the exact vertex gradient is that of the distance between the hulls of moved vertices.
    Also which entries sit at a kink: forward and backward differences disagree (a planar
    face of a box, split along one diagonal or the other as a corner moves out or in, is
    one)."""
    a = build(config.kind, config.points_a, np.float64)
    b = build(config.kind, config.points_b, np.float64)
    raw_a, raw_b = _raw(a), _raw(b)
    theta = np.concatenate([config.params_a, config.params_b, raw_a.ravel(), raw_b.ravel()])
    steps = _steps(config, raw_a.size + raw_b.size, relative)
    rows, actual = _perturbed(theta, steps)
    rows = np.concatenate([rows, theta[None]])
    p = len(config.params_a)
    function = executable("exact", REBUILT[config.kind], np.float64)
    values = []
    for chunk in _batches(rows):
        pa, pb, flat_a, flat_b = np.split(chunk, np.cumsum([p, p, raw_a.size]), axis=1)
        shapes_a = jaxsat.stack([_rebuild(config.dim, x.reshape(raw_a.shape)) for x in flat_a])
        shapes_b = jaxsat.stack([_rebuild(config.dim, x.reshape(raw_b.shape)) for x in flat_b])
        values.append(np.asarray(function(pa, pb, shapes_a, shapes_b)))
    values = np.concatenate(values)[:len(rows)]
    count, centre = len(steps), values[-1]
    central = _central(values[:-1], steps, actual)
    with np.errstate(invalid="ignore", divide="ignore"):
        forward = (values[:count] - centre) / (actual / 2)
        backward = (centre - values[count:2 * count]) / (actual / 2)
    scale = max(np.nanmax(np.abs(central)), 1.0)
    kink = np.abs(forward - backward) > 1e-4 * scale
    return central, kink & np.isfinite(central)


def folded_exact_gradient(config: Config, part: dict) -> np.ndarray:
    """The exact grad in the layout of `exact_finite_differences`: padding rows repeat
    vertex 0 (and move with it when the shape is rebuilt), so their gradient adds to it."""
    grads = [np.ravel(part["grad"][0]), np.ravel(part["grad"][1])]
    for points, gradient in ((config.points_a, part["grad"][2]),
                             (config.points_b, part["grad"][3])):
        shape = build(config.kind, points, np.float64)
        mask = np.asarray(shape.vertex_mask)
        folded = np.array(gradient)[mask]
        folded[0] += np.sum(np.asarray(gradient)[~mask], axis=0)
        grads.append(folded.ravel())
    return np.concatenate(grads)


def flat_gradient(part: dict) -> np.ndarray:
    return np.concatenate([np.ravel(g) for g in part["grad"]])


def relative_error(gradient: np.ndarray, fd: np.ndarray) -> float:
    used = np.isfinite(fd)
    return float(np.linalg.norm(gradient[used] - fd[used])
                 / max(np.linalg.norm(gradient[used]), 1e-300))


# --------------------------------------------------------------------------------------------
# The catalogue.
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("dtype", DTYPES, ids=DTYPE_IDS)
@pytest.mark.parametrize("name", NAMES)
def test_catalogue(name, dtype):
    """Finite values and derivatives, jacfwd == grad, exact value against the
    oracle, smooth value within its bound, sign against intersects."""
    config = CATALOGUE[name]
    result = evaluate_named(name, dtype)
    check_finite_and_consistent(result, dtype, config.unit, name)
    exact, size = reference(name)
    check_values(result, exact, size, dtype, name, error_bound(config))


KINKS = {
    "identical-2d-box": "identical shapes: opposite penetration directions tie",
    "identical-2d-hull": "identical shapes: opposite penetration directions tie",
    "identical-3d-box": "identical shapes: opposite penetration directions tie",
    "identical-3d-hull": "identical shapes: opposite penetration directions tie",
    "nested-concentric-2d": "concentric nesting: opposite penetration directions tie",
    "nested-concentric-3d": "concentric nesting: opposite penetration directions tie",
    "vertex-vertex-2d": "contact through two corners",
    "huge-vertex-vertex-2d": "contact through two corners",
    "vertex-vertex-3d": "contact through two corners",
    "collinear-edges-3d": "contact through two collinear edges",
    "nearly-parallel-edges-3d": "contact through two nearly parallel edges",
}
"""Catalogue entries where the smooth value has a kink, as documented (jaxsat/_smoothing.py,
README): where two penetration directions tie, and at contact through features whose normal
cone is a whole range of axes with no vertex within tau to smooth it (two vertices, a vertex
and an edge, parallel edges). The smooth gradient there is one branch's: it must lie
between the one-sided derivatives."""


@pytest.mark.parametrize("name", NAMES)
def test_catalogue_float32_matches_float64(name):
    """Same (float32-representable) inputs: float32 values within a float32 tolerance of the
    float64 ones relative to the configuration's size; smooth gradients close, or at a kink
    (where rounding may pick the other branch) between the one-sided derivatives."""
    f32, f64 = evaluate_named(name, np.float32), evaluate_named(name, np.float64)
    _, size = reference(name)
    tolerance = VALUE_TOLERANCE[np.float32] * size
    for part in ("exact", "smooth"):
        value32, value64 = getattr(f32, part)["value"], getattr(f64, part)["value"]
        assert abs(value32 - value64) <= tolerance, f"{part}: {value32!r} vs {value64!r}"
    if name in KINKS:
        gradient = flat_gradient(f32.smooth)
        if name.startswith("identical-"):
            # Identical shapes at identical poses tie exactly between u and -u, which the
            # searches tell apart by rounding alone: float32 may take the other branch, whose
            # gradient is this one with the roles of a and b swapped.
            params_a, params_b, vertices_a, vertices_b = f32.smooth["grad"]
            swapped = np.concatenate([np.ravel(g) for g in (params_b, params_a, vertices_b,
                                                            vertices_a)])
            if _between_one_sided(swapped, name):
                gradient = swapped
        check_between_one_sided(gradient, name, f"{name} float32")
        return
    for group, g32, g64 in zip(GROUPS, f32.smooth["grad"], f64.smooth["grad"], strict=True):
        scale = max(np.max(np.abs(g64)), 1.0)
        np.testing.assert_allclose(g32, g64, rtol=0, atol=1e-3 * scale,
                                   err_msg=f"smooth gradient ({group})")


@pytest.mark.parametrize("name", NAMES)
def test_catalogue_smooth_gradient_matches_finite_differences(name):
    """Central differences everywhere the smooth value is differentiable; at the documented
    kinks (KINKS), the gradient lies between the one-sided differences."""
    gradient = flat_gradient(evaluate_named(name, np.float64).smooth)
    if name in KINKS:
        check_between_one_sided(gradient, name, name)
        return
    central, _, _ = smooth_finite_differences(name)
    error = relative_error(gradient, central)
    assert error <= 1e-5, f"relative error {error:.3g}"


# --------------------------------------------------------------------------------------------
# Random configurations.
# --------------------------------------------------------------------------------------------


def random_points(kind: str, rng: np.random.Generator) -> np.ndarray:
    if kind == "poly8":
        count = int(rng.integers(3, 9))
        gaps = rng.uniform(0.5, 1.5, count)
        angles = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.cumsum(gaps) / gaps.sum()
        axes = rng.uniform(0.3, 1.0, 2)
        points = np.stack([axes[0] * np.cos(angles), axes[1] * np.sin(angles)], axis=1)
        return points + rng.uniform(-0.2, 0.2, 2)
    if kind == "box":
        return corners(rng.uniform(0.2, 1.0, 3))
    count = int(rng.integers(4, 9))
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return directions * rng.uniform(0.3, 1.0, 3) + rng.uniform(-0.2, 0.2, 3)


def random_config(kind: str, rng: np.random.Generator, unit: float = 1.0,
                  distance=(0.0, 2.5)) -> Config:
    dim = CLASSES[kind]
    direction = rng.normal(size=dim)
    direction /= np.linalg.norm(direction)
    centre = rng.uniform(-1, 1, dim)
    offset = direction * rng.uniform(*distance)
    if dim == 2:
        params_a = [*centre, rng.uniform(-np.pi, np.pi)]
        params_b = [*(centre + offset), rng.uniform(-np.pi, np.pi)]
    else:
        params_a = [*centre, *rng.normal(size=4)]
        params_b = [*(centre + offset), *rng.normal(size=4)]
    config = Config(kind, random_points(kind, rng), params_a, random_points(kind, rng),
                    params_b)
    return config.scaled(unit) if unit != 1.0 else config


@pytest.mark.parametrize("kind", list(CLASSES))
def test_exact_gradient_matches_finite_differences(kind):
    """Generic random pairs (float64): the exact gradient equals central finite differences
    to 1e-6 wherever the value is locally smooth (forward and backward differences agree);
    few derivatives of generic pairs are at a kink."""
    rng = np.random.default_rng([21, len(kind)])
    failures, kinks, total = [], 0, 0
    for index in range(6):
        config = random_config(kind, rng)
        fd, kink = exact_finite_differences(config, 1e-6)
        gradient = folded_exact_gradient(config, evaluate(config, np.float64).exact)
        used = np.isfinite(fd) & ~kink
        kinks, total = kinks + int(np.sum(kink)), total + int(np.sum(np.isfinite(fd)))
        error = relative_error(gradient[used], fd[used])
        if error > 1e-6:
            failures.append(f"pair {index}: relative error {error:.3g}")
    assert not failures, "\n".join(failures)
    # Generic pairs: few derivatives at a kink (box corners on a touching face can be).
    assert kinks <= 0.15 * total, f"{kinks} of {total} derivatives at a kink"


SCALES = [TINY, 1e-3, 1.0, 1e3, HUGE]


@given(kind=st.sampled_from(list(CLASSES)), dtype=st.sampled_from(DTYPES),
       scale=st.sampled_from(SCALES), far=st.booleans(), seed=st.integers(0, 2**32 - 1))
def test_random_pairs(kind, dtype, scale, far, seed):
    """Random shapes and poses at several scales (optionally 1e4 units from the origin):
    finite values and derivatives, jacfwd == grad, the exact value against the
    oracle, smooth within its bound, sign consistent with intersects."""
    rng = np.random.default_rng(seed)
    config = random_config(kind, rng, unit=scale)
    if far:
        config = config.moved(np.full(config.dim, 1e4 * scale))
    result = evaluate(config, dtype)
    label = f"{kind} scale {scale} far {far} seed {seed}"
    check_finite_and_consistent(result, dtype, config.unit, label)
    exact, size = oracle_reference(config)
    check_values(result, exact, size, dtype, label, error_bound(config))


@given(name=st.sampled_from([n for n in NAMES if not CATALOGUE[n].zero_quaternion]),
       dtype=st.sampled_from(DTYPES), seed=st.integers(0, 2**32 - 1))
def test_catalogue_under_common_rigid_motion(name, dtype, seed):
    """Moving both shapes by one random rigid motion keeps the signed distance (up to the
    rounding of the moved inputs) and every derivative finite."""
    config = CATALOGUE[name]
    motion = random_motion(config.dim, 1, np.random.default_rng(seed), unit=config.unit)
    move = lambda params: apply_motion(params[None], config.dim, motion)[0]  # noqa: E731
    moved = dataclasses.replace(config, params_a=move(config.params_a),
                                params_b=move(config.params_b))
    result = evaluate(moved, dtype)
    check_finite_and_consistent(result, dtype, moved.unit, f"{name} moved (seed {seed})")
    exact, size = oracle_reference(moved)
    # The moved inputs are rounded to float32: the oracle sees the same rounded inputs.
    check_values(result, exact, size, dtype, f"{name} moved", error_bound(moved))
