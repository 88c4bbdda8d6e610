"""Numerical stability of `jaxsat.signed_distance` (exact and smooth) and of its pose gradients
on random and degenerate configurations (the catalogue of tests/harness.py) in float32 and
float64, against the SciPy oracle and jaxsat's float64 exact values. See benchmarks/README.md.
Exit status 1 on any NaN or inf.

Usage (from the repository root):
    python benchmarks/stability.py           # 110,000 configurations; results/stability-cpu-2core
    python benchmarks/stability.py --quick   # 3,000, for a smoke test
"""

from __future__ import annotations

import pathlib
import sys

import jax
import jax.numpy as jnp
import numpy as np

import jaxsat

jax.config.update("jax_enable_x64", True)

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import core  # noqa: E402
import harness  # noqa: E402  (tests/harness.py: the tests' generators, motions and catalogue)

SHARES = {"2d-polygons": 0.5, "3d-boxes": 0.4, "3d-hulls8": 0.1}
"""Share of the configurations per class (hulls are the slowest, smooth ones most of all)."""
KIND = {"2d-polygons": "poly8", "3d-boxes": "box", "3d-hulls8": "hull8"}
"""The harness's size class (and catalogue kind) of each row class."""
SOURCES = {"degenerate": (0.4, None), "random 1e-3": (0.15, 1e-3), "random 1": (0.15, 1.0),
           "random 1e3": (0.15, 1e3), "random 1e-6": (0.075, 1e-6), "random 1e6": (0.075, 1e6)}
"""Source: (share of a class's configurations, length scale); 1e-6 and 1e6: float64 only."""
FLOAT64_ONLY = {"random 1e-6", "random 1e6"}
TAU = 1e-3
"""Smoothing length relative to the configuration's length scale."""
POOL = 128
"""Shapes per pool (every pool of a class has this many, so one compile serves them all)."""
CHUNK = {"2d-polygons": 4096, "3d-boxes": 2048, "3d-hulls8": 512}
DTYPES = ("float64", "float32")

def degenerate_set(case, count, rng):
    """Catalogue entries under random rigid motions, most with their poses slightly perturbed."""
    dim = harness.CLASSES[KIND[case]]
    entries = [c for c in harness.CATALOGUE.values() if c.kind == KIND[case]]
    points = [e.points_a for e in entries] + [e.points_b for e in entries]
    pick = rng.integers(0, len(entries), count)
    motion = harness.random_motion(dim, count, rng)
    params = [harness.apply_motion(np.array([getattr(entries[i], side) for i in pick], np.float64),
                                   dim, motion) for side in ("params_a", "params_b")]
    zero = np.array([entries[i].zero_quaternion for i in pick])
    size = rng.choice([0.0, 1e-12, 1e-9, 1e-6, 1e-3], count)
    for side in params:
        noise = rng.normal(size=side.shape) * size[:, None]
        noise[zero, dim:] = 0.0  # keep zero quaternions zero
        side += noise
    return points, pick, pick + len(entries), *params, np.array([entries[i].unit for i in pick])

def random_set(case, count, rng, scale):
    """Random shapes of the harness's generators at a length scale, about half overlapping."""
    dim, generate = harness.GENERATORS[KIND[case]]
    points = [generate(rng, scale)[0] for _ in range(POOL)]
    index_a, index_b = rng.integers(0, POOL, count), rng.integers(0, POOL, count)
    direction = rng.normal(size=(count, dim))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    centre = rng.uniform(-1, 1, (count, dim)) * scale
    offset = direction * rng.uniform(0.0, 2.5, (count, 1)) * scale
    turn_a, turn_b = np.split(rng.uniform(-np.pi, np.pi, (count, 2)) if dim == 2 else
                              rng.normal(size=(count, 8)), 2, axis=1)
    return (points, index_a, index_b, np.concatenate([centre, turn_a], axis=1),
            np.concatenate([centre + offset, turn_b], axis=1), np.full(count, scale))

def _one(pool, index_a, index_b, params_a, params_b, tau):
    a, b = (jax.tree.map(lambda x, i=i: x[i], pool) for i in (index_a, index_b))
    out = {"bound": jaxsat.smoothing_error_bound(a, b)}
    for name, smoothing in (("exact", None), ("smooth", tau)):
        f = lambda pa, pb, s=smoothing: jaxsat.signed_distance(  # noqa: E731
            a, core.pose(pa), b, core.pose(pb), smoothing=s)
        out[name], grads = jax.value_and_grad(f, argnums=(0, 1))(params_a, params_b)
        out[name + "_grad_finite"] = jnp.all(jnp.isfinite(jnp.concatenate(grads)))
    return out

KERNEL = jax.jit(jax.vmap(_one, in_axes=(None, 0, 0, 0, 0, 0)))

def evaluate(case, pool, index_a, index_b, params_a, params_b, tau, dtype):
    """Values, smooth bounds and whether the gradients are finite, by chunks (NumPy)."""
    chunk, results = CHUNK[case], []
    for start in range(0, len(index_a), chunk):
        stop = min(start + chunk, len(index_a))
        rows = np.minimum(np.arange(start, start + chunk), stop - 1)  # last chunk: repeats
        out = KERNEL(pool, index_a[rows], index_b[rows], jnp.asarray(params_a[rows], dtype),
                     jnp.asarray(params_b[rows], dtype), jnp.asarray(tau[rows], dtype))
        results.append({k: np.asarray(v)[:stop - start] for k, v in out.items()})
    return {k: np.concatenate([r[k] for r in results]) for k in results[0]}

def run_row(case, source, count, rng, oracle_samples):
    scale = SOURCES[source][1]
    points, ia, ib, pa, pb, unit = (random_set(case, count, rng, scale) if scale else
                                    degenerate_set(case, count, rng))
    points, pa, pb = [harness.f32(p) for p in points], harness.f32(pa), harness.f32(pb)
    tau = TAU * unit
    out = {dtype: evaluate(case, jaxsat.stack([
        harness.build(KIND[case], points[i % len(points)], dtype) for i in range(POOL)]),
        ia, ib, pa, pb, tau, dtype) for dtype in DTYPES[:1 if source in FLOAT64_ONLY else 2]}
    reference = out["float64"]["exact"].astype(np.float64)
    size = unit + np.abs(reference)  # as the tests define it: tiny shapes may be far apart
    sample = rng.choice(count, min(oracle_samples, count), replace=False)
    truth = np.array([harness.oracle_reference(harness.Config(
        KIND[case], points[ia[i] % len(points)], pa[i], points[ib[i] % len(points)], pb[i]))[0]
        for i in sample])
    row = {"class": case, "source": source, "configurations": count,
           "oracle_samples": len(sample), **core.stats(
               "float64_exact_vs_oracle", np.abs(reference[sample] - truth) / size[sample])}
    for dtype, result in out.items():
        row[f"{dtype}_nonfinite_values"] = sum(
            int(np.sum(~np.isfinite(result[k]))) for k in ("exact", "smooth"))
        row[f"{dtype}_nonfinite_grads"] = sum(
            int(np.sum(~result[k])) for k in ("exact_grad_finite", "smooth_grad_finite"))
        for part in ("exact", "smooth") if dtype == "float32" else ("smooth",):
            error = np.abs(result[part].astype(np.float64) - reference) / size
            row.update(core.stats(f"{dtype}_{part}", error))
        if dtype == "float64":  # the bound holds in exact arithmetic; f32 adds its rounding
            row["float64_smooth_over_bound_max"] = float(np.max(np.abs(result["smooth"].astype(
                np.float64) - reference) / (result["bound"].astype(np.float64) * tau)))
    return row

HEAD = ["class", "source", "configs", "NaN/inf values (f64, f32)", "NaN/inf grads (f64, f32)",
        "f64 exact vs oracle, max / median (samples)", "f32 exact vs f64, max / median",
        "f64 smooth vs f64 exact, max / median", "f32 smooth vs f64 exact, max / median",
        "f64 smooth error / bound, max"]

def cells(row) -> list:
    def pair(prefix):
        return f"{core.num(row.get(prefix + '_max'))} / {core.num(row.get(prefix + '_median'))}"
    def nonfinite(kind):
        return ", ".join(core.num(row.get(f"{d}_nonfinite_{kind}")) for d in DTYPES)
    return [row["class"], row["source"], row["configurations"], nonfinite("values"),
            nonfinite("grads"), f"{pair('float64_exact_vs_oracle')} ({row['oracle_samples']})",
            pair("float32_exact"), pair("float64_smooth"), pair("float32_smooth"),
            core.num(row["float64_smooth_over_bound_max"])]

def main(argv=None) -> int:
    args = core.parse(argv, __doc__, {"configs": (110_000, 3000), "oracle_samples": (2000, 100)},
                      sizes=None, timing=False, options={
                          "--configs": "configurations in all, split over classes and sources",
                          "--oracle-samples": "oracle checks per row"})
    rng, info, rows = np.random.default_rng(args.seed), core.machine_info(), []
    for case, share in SHARES.items():
        for source, (fraction, _) in SOURCES.items():
            count = max(int(round(args.configs * share * fraction)), 1)
            rows.append(run_row(case, source, count, rng, args.oracle_samples))
            print(" | ".join(map(str, cells(rows[-1]))), file=sys.stderr, flush=True)
    total = sum(row["configurations"] for row in rows)
    bad = sum(row.get(f"{d}_nonfinite_{k}", 0) for row in rows for d in DTYPES
              for k in ("values", "grads"))
    summary_line = (f"{total} configurations, {bad} non-finite values or gradients. tau = {TAU} "
                    "x scale; errors divided by the size (scale + |distance|); reference: jaxsat "
                    "float64 exact, itself checked against the SciPy oracle on a subsample.\n\n")
    core.save(args, "stability", "jaxsat stability", info,
              {"tau": TAU, "pool": POOL, "shares": SHARES, "sources": SOURCES, "results": rows},
              summary_line + core.markdown_table(HEAD, [cells(row) for row in rows]))
    return int(bad > 0)

if __name__ == "__main__":
    sys.exit(main())
