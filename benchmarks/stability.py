"""Numerical stability of `jaxsat.signed_distance` (exact and smooth) and of its pose gradients
on many random and degenerate configurations, in float32 and float64.

Configurations, for three size classes (2D polygons padded to 8 vertices, 3D boxes, 3D hulls
of up to 8 points padded to 8 vertices):

* degenerate: a catalogue of contacts and coincidences (identical shapes at identical poses,
  face-face, edge-edge, vertex-face and vertex-vertex contacts, parallel and nearly parallel
  edges, padding, nested shapes, zero quaternions, large angles, poses near 1e4), each moved
  by a random rigid motion (applied to both poses) and, for most, a random perturbation of
  the pose parameters of size 0 (exactly degenerate up to the motion's rounding), 1e-12,
  1e-9, 1e-6 or 1e-3 (relative to the configuration's length);
* random pairs of random shapes at length scales 1e-3, 1 and 1e3 (both dtypes) and 1e-6 and
  1e6 (float64 only), about half of them overlapping.

Every input is rounded to float32 first, so both dtypes see the same configuration. For every
configuration, the exact (smoothing=None) and smooth (smoothing = TAU x scale) values and their
gradients with respect to both poses' parameters are computed with `jax.jit(jax.vmap(...))`
in chunks, in float32 and float64.

References. The float64 exact values are checked against an independent SciPy oracle
(tests/oracle.py: the convex hull of the Minkowski difference of the world point clouds) on a
random subsample of every row; every other value (float32 exact, smooth in both dtypes) is
compared with the float64 exact value of jaxsat on every configuration. Errors are divided by
the configuration's length scale. The smooth error is also reported as a fraction of its
bound `smoothing_error_bound(a, b) * tau` (at most 1 expected).

Usage (from the repository root):
    python benchmarks/stability.py                       # about 100,000 configurations
    python benchmarks/stability.py --quick               # a few thousand, for a smoke test
    python benchmarks/stability.py --json benchmarks/results/stability-cpu-2core.json
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxsat

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from machine import machine_info  # noqa: E402

jax.config.update("jax_enable_x64", True)

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests"))
import oracle  # noqa: E402  (tests/oracle.py: NumPy/SciPy only, shares no code with jaxsat)

CLASSES = {"2d-polygons": 2, "3d-boxes": 3, "3d-hulls": 3}
SHARES = {"2d-polygons": 0.5, "3d-boxes": 0.4, "3d-hulls": 0.1}
"""Share of the configurations per class (hulls are the slowest, smooth ones most of all)."""
SOURCES = {"degenerate": 0.4, "random 1e-3": 0.15, "random 1": 0.15, "random 1e3": 0.15,
           "random 1e-6": 0.075, "random 1e6": 0.075}
"""Share of a class's configurations per source; the 1e-6 and 1e6 rows run in float64 only."""
SCALES = {"random 1e-3": 1e-3, "random 1": 1.0, "random 1e3": 1e3, "random 1e-6": 1e-6,
          "random 1e6": 1e6}
FLOAT64_ONLY = {"random 1e-6", "random 1e6"}
TAU = 1e-3
"""Smoothing length relative to the configuration's length scale."""
POOL = 128
"""Shapes per pool (every pool of a class has this many, so one compile serves them all)."""
CHUNK = {"2d-polygons": 4096, "3d-boxes": 2048, "3d-hulls": 512}


# ----------------------------------------------------------------------------- shapes


def _f32(values) -> np.ndarray:
    return np.asarray(values, np.float64).astype(np.float32).astype(np.float64)


def corners(half) -> np.ndarray:
    half = np.asarray(half, np.float64)
    if len(half) == 2:
        return np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], np.float64) * half
    return np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * half


def build(case: str, points, dtype) -> jaxsat.Polytope:
    if case == "2d-polygons":
        return jaxsat.polygon(points, 8, dtype=dtype)
    if case == "3d-boxes":
        return jaxsat.box(np.max(np.abs(points), axis=0), dtype=dtype)
    return jaxsat.polyhedron(points, 8, dtype=dtype)


def random_points(case: str, rng: np.random.Generator) -> np.ndarray:
    if case == "2d-polygons":
        count = int(rng.integers(3, 9))
        gaps = rng.uniform(0.5, 1.5, count)
        angles = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.cumsum(gaps) / gaps.sum()
        axes = rng.uniform(0.3, 1.0, 2)
        return np.stack([axes[0] * np.cos(angles), axes[1] * np.sin(angles)], axis=1)
    if case == "3d-boxes":
        return corners(rng.uniform(0.2, 1.0, 3))
    count = int(rng.integers(4, 9))
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return directions * rng.uniform(0.3, 1.0, 3)


def quaternion(axis, angle) -> np.ndarray:
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis])


# ----------------------------------------------------------------------------- catalogue


SQUARE, RECT = corners([1.0, 1.0]), corners([1.0, 0.5])
CUBE, BRICK = corners([1.0, 1.0, 1.0]), corners([1.0, 0.5, 0.25])
PENTAGON = np.array([[0.9, 0.0], [0.3, 0.8], [-0.6, 0.55], [-0.7, -0.4], [0.2, -0.75]])
TRIANGLE = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
DIAMOND = np.array([[0.0, 0.0], [1.0, 1.0], [0.0, 2.0], [-1.0, 1.0]])
DISPHENOID = np.array([[-1.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, -1.0, 0.0], [0.0, 1.0, 0.0]])
SPIKE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 1.0], [-0.5, 0.75, 1.0], [-0.5, -0.75, 1.0]])
OCTAHEDRON = np.concatenate([np.eye(3), -np.eye(3)])
HULL7 = np.array([[0.8, 0.1, 0.0], [-0.5, 0.6, 0.2], [-0.3, -0.7, 0.1], [0.1, 0.2, 0.9],
                  [0.2, -0.1, -0.8], [0.6, 0.5, 0.5], [-0.4, -0.2, -0.6]])
Q1, Q2 = quaternion([1.0, 2.0, 3.0], 0.7), quaternion([-2.0, 0.5, 1.0], 2.1)
I4, ZERO4 = [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]
TILT = 1e-8


def catalogue() -> dict[str, list]:
    """Per class: (name, points a, params a, points b, params b, length unit)."""
    p2 = [("identical-box", RECT, [0.3, -0.2, 0.4], RECT, [0.3, -0.2, 0.4]),
          ("identical-hull", PENTAGON, [0.3, -0.2, 0.4], PENTAGON, [0.3, -0.2, 0.4]),
          ("face-face", RECT, [0, 0, 0], SQUARE * 0.5, [1.5, 0.25, 0]),
          ("vertex-on-face", RECT, [0, 0, 0], DIAMOND, [0.25, 0.5, 0]),
          ("vertex-vertex", SQUARE, [0, 0, 0], SQUARE, [2, 2, 0]),
          ("vertex-vertex-tips", DIAMOND, [0, 0, 0], DIAMOND, [0, 2, 0]),
          ("translated-copy", PENTAGON, [0.1, 0.2, 0.3], PENTAGON, [0.5, 0.45, 0.3]),
          ("padded", SQUARE, [0, 0, 0], TRIANGLE, [0.8, 0.1, 0.0]),
          ("nearly-parallel", RECT, [0, 0, 0], RECT, [2, 0.5, TILT]),
          ("nested-concentric", SQUARE * 2, [0.5, 0.5, 0], RECT * 0.25, [0.5, 0.5, 0]),
          ("nested", PENTAGON * 3, [0, 0, 0.1], TRIANGLE * 0.5, [0.3, -0.2, 1.0]),
          ("large-angle", PENTAGON, [0, 0, 1e3 + 0.3], RECT, [1.2, 0.4, -3e3]),
          ("far", RECT, [1e4, 1e4, 0], SQUARE * 0.5, [1e4 + 1.5, 1e4 + 0.25, 0])]
    boxes = [("identical", BRICK, [0.1, 0.2, 0.3, *Q1], BRICK, [0.1, 0.2, 0.3, *Q1]),
             ("face-face", CUBE, [0, 0, 0, *I4], CUBE * 0.5, [1.5, 0.25, -0.375, *I4]),
             ("vertex-vertex", CUBE, [0, 0, 0, *I4], CUBE, [2, 2, 2, *I4]),
             ("side-by-side", CUBE, [0, 0, 0, *I4], CUBE, [2, 0.5, 0.25, *I4]),
             ("collinear-edges", CUBE, [0, 0, 0, *I4], CUBE, [2, 2, 0.5, *I4]),
             ("vertex-on-edge", CUBE, [0, 0, 0, *I4], CUBE,
              [2, 0, 1 + np.sqrt(2), *quaternion([1, 0, 0], np.pi / 4)]),
             ("nearly-parallel", CUBE, [0, 0, 0, *I4], CUBE,
              [2, 2, 0.5, *quaternion([1, 0, 0], TILT)]),
             ("nested-concentric", CUBE * 2, [0, 0, 0, *I4], CUBE * 0.25, [0, 0, 0, *I4]),
             ("zero-quaternion", BRICK, [0, 0, 0, *ZERO4], CUBE * 0.5, [1.25, 0.5, 0, *ZERO4]),
             ("far", BRICK, [1e4, 1e4, 1e4, *Q1], CUBE * 0.5,
              [1e4 + 1.25, 1e4 + 0.5, 1e4 + 0.25, *Q2])]
    hulls = [("identical", HULL7, [0.1, 0.2, 0.3, *Q1], HULL7, [0.1, 0.2, 0.3, *Q1]),
             ("edge-edge", DISPHENOID, [0, 0, 0, *I4], DISPHENOID, [0, 0, 1, *I4]),
             ("vertex-on-face", CUBE, [0, 0, 0, *I4], SPIKE, [0.25, -0.5, 1, *I4]),
             ("vertex-vertex", OCTAHEDRON, [0, 0, 0, *I4], OCTAHEDRON, [2, 0, 0, *I4]),
             ("translated-copy", HULL7, [0, 0, 0, *Q1], HULL7, [0.3, -0.2, 0.25, *Q1]),
             ("padded", CUBE, [0, 0, 0, *Q2], SPIKE, [0.4, 0.3, 0.5, *Q1]),
             ("nearly-parallel", DISPHENOID, [0, 0, 0, *I4], DISPHENOID,
              [0, 0, 1, *quaternion([0, 0, 1], np.pi / 2 + TILT)]),
             ("nested", HULL7 * 4, [0, 0, 0, *Q1], SPIKE * 0.5, [0.2, 0.1, -0.1, *Q2]),
             ("zero-quaternion", HULL7, [0.1, 0, 0, *ZERO4], SPIKE, [0.2, 0.1, 0.7, *Q1]),
             ("large-angle", HULL7, [0, 0, 0, *quaternion([1, 1, 0], 2 * np.pi - 1e-3)],
              BRICK, [0.9, 0.8, 0.1, *(-1e3 * Q2)]),
             ("far", DISPHENOID, [1e4, 1e4, 1e4, *I4], DISPHENOID, [1e4, 1e4, 1e4 + 1, *I4])]
    return {"2d-polygons": p2, "3d-boxes": boxes, "3d-hulls": hulls}


# ----------------------------------------------------------------------------- rigid motions


def rotation_2d(angle):
    cos, sin = np.cos(angle), np.sin(angle)
    return np.stack([np.stack([cos, -sin], -1), np.stack([sin, cos], -1)], -2)


def quaternion_product(p, q):
    w1, x1, y1, z1 = np.moveaxis(p, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(q, -1, 0)
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2],
                    -1)


def rotation_3d(q):
    """Rotation matrices of unit quaternions (..., 4) (w, x, y, z)."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)


def move(params, dim, rng, unit):
    """A random rigid motion (one per row) applied to (N, P) pose parameters."""
    count = len(params)
    shift = rng.uniform(-2, 2, (count, dim)) * unit
    if dim == 2:
        angle = rng.uniform(-np.pi, np.pi, count)
        moved = np.einsum("nij,nj->ni", rotation_2d(angle), params[:, :2]) + shift
        return np.concatenate([moved, params[:, 2:] + angle[:, None]], axis=1), (angle, shift)
    q = rng.normal(size=(count, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    moved = np.einsum("nij,nj->ni", rotation_3d(q), params[:, :3]) + shift
    return np.concatenate([moved, quaternion_product(q, params[:, 3:])], axis=1), (q, shift)


def apply_motion(params, dim, motion):
    rotation, shift = motion
    if dim == 2:
        moved = np.einsum("nij,nj->ni", rotation_2d(rotation), params[:, :2]) + shift
        return np.concatenate([moved, params[:, 2:] + rotation[:, None]], axis=1)
    moved = np.einsum("nij,nj->ni", rotation_3d(rotation), params[:, :3]) + shift
    return np.concatenate([moved, quaternion_product(rotation, params[:, 3:])], axis=1)


# ----------------------------------------------------------------------------- configurations


def pool_of(case, point_sets, dtype):
    """Stacked shapes, repeated up to POOL entries."""
    shapes = [build(case, points, dtype) for points in point_sets]
    return jaxsat.stack([shapes[i % len(shapes)] for i in range(POOL)])


def degenerate_set(case, count, rng):
    """Catalogue entries moved by random rigid motions, most with a small random perturbation
    of the pose parameters."""
    dim = CLASSES[case]
    entries = catalogue()[case]
    points = [e[1] for e in entries] + [e[3] for e in entries]
    pick = rng.integers(0, len(entries), count)
    index_a, index_b = pick, pick + len(entries)
    params_a = np.array([entries[i][2] for i in pick], np.float64)
    params_b = np.array([entries[i][4] for i in pick], np.float64)
    zero = np.array([not np.any(entries[i][2][3:]) if dim == 3 else False for i in pick])
    params_a, motion = move(params_a, dim, rng, 1.0)
    params_b = apply_motion(params_b, dim, motion)
    size = rng.choice([0.0, 1e-12, 1e-9, 1e-6, 1e-3], count)
    for params in (params_a, params_b):
        noise = rng.normal(size=params.shape) * size[:, None]
        noise[zero, dim:] = 0.0  # keep zero quaternions zero
        params += noise
    return points, index_a, index_b, params_a, params_b, np.ones(count)


def random_set(case, count, rng, scale):
    dim = CLASSES[case]
    points = [random_points(case, rng) * scale for _ in range(POOL)]
    index_a, index_b = rng.integers(0, POOL, count), rng.integers(0, POOL, count)
    direction = rng.normal(size=(count, dim))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    centre = rng.uniform(-1, 1, (count, dim)) * scale
    offset = direction * rng.uniform(0.0, 2.5, (count, 1)) * scale
    if dim == 2:
        params_a = np.concatenate([centre, rng.uniform(-np.pi, np.pi, (count, 1))], axis=1)
        params_b = np.concatenate([centre + offset, rng.uniform(-np.pi, np.pi, (count, 1))],
                                  axis=1)
    else:
        params_a = np.concatenate([centre, rng.normal(size=(count, 4))], axis=1)
        params_b = np.concatenate([centre + offset, rng.normal(size=(count, 4))], axis=1)
    return points, index_a, index_b, params_a, params_b, np.full(count, scale)


# ----------------------------------------------------------------------------- kernels


def _pose(params):
    if params.shape[-1] == 3:
        return jaxsat.pose2(params[0], params[1], params[2])
    return jaxsat.pose3(params[:3], params[3:])


def _one(pool, index_a, index_b, params_a, params_b, tau):
    a = jax.tree.map(lambda x: x[index_a], pool)
    b = jax.tree.map(lambda x: x[index_b], pool)
    out = {}
    for name, smoothing in (("exact", None), ("smooth", tau)):
        f = lambda pa, pb, s=smoothing: jaxsat.signed_distance(  # noqa: E731
            a, _pose(pa), b, _pose(pb), smoothing=s)
        value, (grad_a, grad_b) = jax.value_and_grad(f, argnums=(0, 1))(params_a, params_b)
        out[name] = value
        out[name + "_grad_finite"] = jnp.all(jnp.isfinite(grad_a)) & jnp.all(jnp.isfinite(grad_b))
    out["bound"] = jaxsat.smoothing_error_bound(a, b)
    return out


KERNEL = jax.jit(jax.vmap(_one, in_axes=(None, 0, 0, 0, 0, 0)))


def evaluate(case, pool, index_a, index_b, params_a, params_b, tau, dtype):
    """Values, smooth bounds and whether the gradients are finite, by chunks (NumPy)."""
    chunk = CHUNK[case]
    results = []
    for start in range(0, len(index_a), chunk):
        stop = min(start + chunk, len(index_a))
        rows = np.minimum(np.arange(start, start + chunk), stop - 1)  # last chunk: repeats
        take = lambda x, rows=rows: x[rows]  # noqa: E731
        out = KERNEL(pool, take(index_a), take(index_b), jnp.asarray(take(params_a), dtype),
                     jnp.asarray(take(params_b), dtype), jnp.asarray(take(tau), dtype))
        results.append({k: np.asarray(v)[:stop - start] for k, v in out.items()})
    return {k: np.concatenate([r[k] for r in results]) for k in results[0]}


# ----------------------------------------------------------------------------- oracle


def world(points, params):
    if len(params) == 3:
        return oracle.to_world(points, oracle.rotation_2d(params[2]), params[:2])
    q = params[3:]
    rotation = np.eye(3) if not np.any(q) else oracle.rotation_3d(q)
    return oracle.to_world(points, rotation, params[:3])


def oracle_value(points_a, params_a, points_b, params_b) -> float:
    result = oracle.evaluate(world(points_a, params_a), world(points_b, params_b))
    return -result.depth if result.depth >= 0 else result.distance


# ----------------------------------------------------------------------------- main


def summary(errors):
    errors = np.asarray(errors, np.float64)
    if errors.size == 0:
        return None, None
    return float(np.max(errors)), float(np.median(errors))


def run_row(case, source, count, rng, oracle_samples, echo):
    if source == "degenerate":
        points, ia, ib, pa, pb, unit = degenerate_set(case, count, rng)
    else:
        points, ia, ib, pa, pb, unit = random_set(case, count, rng, SCALES[source])
    points = [_f32(p) for p in points]
    pa, pb = _f32(pa), _f32(pb)
    tau = TAU * unit
    dtypes = [np.float64] if source in FLOAT64_ONLY else [np.float64, np.float32]
    out, seconds = {}, {}
    for dtype in dtypes:
        pool = pool_of(case, points, dtype)
        start = time.perf_counter()
        out[dtype] = evaluate(case, pool, ia, ib, pa, pb, tau, dtype)
        seconds[np.dtype(dtype).name] = time.perf_counter() - start
    reference = out[np.float64]["exact"].astype(np.float64)
    sample = rng.choice(count, min(oracle_samples, count), replace=False)
    start = time.perf_counter()
    truth = np.array([oracle_value(points[ia[i] % len(points)], pa[i],
                                   points[ib[i] % len(points)], pb[i]) for i in sample])
    oracle_seconds = time.perf_counter() - start
    row = {"class": case, "source": source, "configurations": count,
           "seconds": seconds, "oracle_seconds": oracle_seconds}
    row["oracle_samples"] = len(sample)
    row["float64_exact_vs_oracle_max"], row["float64_exact_vs_oracle_median"] = summary(
        np.abs(reference[sample] - truth) / unit[sample])
    for dtype, result in out.items():
        name = np.dtype(dtype).name
        bad_values = sum(int(np.sum(~np.isfinite(result[k]))) for k in ("exact", "smooth"))
        bad_grads = sum(int(np.sum(~result[k])) for k in ("exact_grad_finite",
                                                           "smooth_grad_finite"))
        row[f"{name}_nonfinite_values"], row[f"{name}_nonfinite_grads"] = bad_values, bad_grads
        for part in ("exact", "smooth"):
            if part == "exact" and dtype == np.float64:
                continue
            error = np.abs(result[part].astype(np.float64) - reference) / unit
            row[f"{name}_{part}_max"], row[f"{name}_{part}_median"] = summary(error)
        ratio = (np.abs(result["smooth"].astype(np.float64) - reference)
                 / (result["bound"].astype(np.float64) * tau))
        row[f"{name}_smooth_over_bound_max"] = float(np.max(ratio))
    echo(format_row(row))
    return row


def _fmt(value):
    if value is None:
        return "-"
    if isinstance(value, int):
        return str(value)
    return f"{value:.1e}"


HEADER = ("| class | source | configs | NaN/inf values (f64, f32) | NaN/inf grads (f64, f32) "
          "| f64 exact vs oracle, max / median (samples) | f32 exact vs f64, max / median "
          "| f64 smooth vs f64 exact, max / median | f32 smooth vs f64 exact, max / median "
          "| smooth error / bound, max |")


def format_row(row) -> str:
    def pair(prefix):
        return f"{_fmt(row.get(prefix + '_max'))} / {_fmt(row.get(prefix + '_median'))}"

    nonfinite = lambda kind: ", ".join(  # noqa: E731
        _fmt(row.get(f"{d}_nonfinite_{kind}")) for d in ("float64", "float32"))
    ratio = max(row.get(f"{d}_smooth_over_bound_max", 0.0) for d in ("float64", "float32"))
    return (f"| {row['class']} | {row['source']} | {row['configurations']} "
            f"| {nonfinite('values')} | {nonfinite('grads')} "
            f"| {pair('float64_exact_vs_oracle')} ({row['oracle_samples']}) "
            f"| {pair('float32_exact')} | {pair('float64_smooth')} | {pair('float32_smooth')} "
            f"| {_fmt(ratio)} |")


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--configs", type=int, default=110_000,
                        help="configurations in all, split over classes and sources "
                             "(default: %(default)s)")
    parser.add_argument("--quick", action="store_true",
                        help="a smoke test: 3,000 configurations, 100 oracle samples per row")
    parser.add_argument("--oracle-samples", type=int, default=2000,
                        help="oracle checks per row (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    parser.add_argument("--json", default=None, metavar="PATH", help="also write JSON here")
    return parser.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    if args.quick:
        args.configs, args.oracle_samples = 3000, 100
    rng = np.random.default_rng(args.seed)
    echo = lambda text: print(text, flush=True)  # noqa: E731
    info = machine_info()
    echo(f"# jaxsat {info['versions']['jaxsat']}, JAX {info['versions']['jax']} "
         f"({info['backend']}), {info['cpu_model']} x {info['cpu_count']}, git "
         f"{info['git_commit']}")
    echo(f"# tau = {TAU} x scale; errors divided by the length scale; reference: jaxsat "
         f"float64 exact, itself checked against the SciPy oracle on a subsample")
    echo(HEADER)
    echo("|" + "---|" * HEADER.count(" | ") + "---|")
    rows, start = [], time.perf_counter()
    for case, share in SHARES.items():
        for source, fraction in SOURCES.items():
            count = max(int(round(args.configs * share * fraction)), 1)
            rows.append(run_row(case, source, count, rng, args.oracle_samples, echo))
    total = sum(row["configurations"] for row in rows)
    bad = sum(row.get(f"{d}_nonfinite_{k}", 0) for row in rows for d in ("float64", "float32")
              for k in ("values", "grads"))
    echo(f"# {total} configurations, {bad} non-finite values or gradients, "
         f"{time.perf_counter() - start:.0f} s")
    if args.json:
        path = pathlib.Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        config = {key: value for key, value in vars(args).items() if key != "json"}
        config.update(tau=TAU, pool=POOL, shares=SHARES, sources=SOURCES)
        path.write_text(json.dumps({"machine": info, "config": config, "results": rows},
                                   indent=2) + "\n")
        echo(f"# wrote {path}")
    return 0 if bad == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
