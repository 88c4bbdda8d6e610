"""Cost of the differentiable distance queries against `penetration` on the same pairs, in one
process (float32), their memory and gradient norms, and eager latency of every public query.
See benchmarks/README.md.

Usage (from the repository root):
    python benchmarks/distance.py          # ~5 min; writes results/distance-cpu-2core.*
    python benchmarks/distance.py --quick  # 1e3 pairs
"""

from __future__ import annotations

import functools
import pathlib
import sys

import jax
import numpy as np

import jaxsat

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import core  # noqa: E402

CASES = ["2d-polygons", "3d-boxes", "3d-hulls"]
TAU = 0.005
"""Smoothing length: 1% of the typical shape radius (0.5)."""
TARGETS = {"exact": {"2d-polygons": 3.0, "3d-boxes": 3.0, "3d-hulls": 3.0},
           "smooth": {"2d-polygons": 5.0, "3d-boxes": 5.0, "3d-hulls": 3.0}}
"""Largest allowed cost, as a multiple of penetration's on the same pairs."""
EXACT, SMOOTH = (functools.partial(jaxsat.signed_distance, smoothing=s) for s in (None, TAU))
KERNELS = {"penetration": lambda a, pa, b, pb: jaxsat.penetration(a, pa, b, pb).depth,
           "exact": jax.value_and_grad(EXACT, argnums=(1, 3)),
           "smooth": jax.value_and_grad(SMOOTH, argnums=(1, 3))}
"""One pair: the depth, or the value and gradient with respect to both poses."""

def measure(data: core.DataSet, pairs: int, rounds: int) -> dict:
    batch = data.inputs(slice(0, pairs))
    compiled = {name: core.compile_aot(jax.vmap(k), *batch) for name, k in KERNELS.items()}
    timings = core.time_calls({name: lambda c=c: c.call(*batch) for name, c in compiled.items()},
                              rounds, burst=10, burst_s=1.0)
    row = {"case": data.name, "pairs": pairs}
    for name, c in compiled.items():
        best = timings[name].best
        row[name] = {"pairs_per_s": pairs / best, "compile_s": c.seconds, "bytes": c.memory_bytes,
                     "temp_bytes": c.temp_bytes, "ratio": best / timings["penetration"].best,
                     "page_faults": core.page_faults(lambda c=c: c.call(*batch))}
        if name != "penetration":
            _, grads = timings[name].output
            row[name]["max_translation_gradient"] = float(max(np.linalg.norm(np.asarray(
                g.translation, np.float64), axis=-1).max() for g in grads))
    return row

def eager_latency(data: core.DataSet) -> dict:
    """First (compiling) and best warm eager call of each public query on one pair."""
    a, pa, b, pb = jax.tree.map(lambda leaf: leaf[0], data.inputs(slice(0, 1)))
    queries = {"intersects": jaxsat.intersects, "penetration": jaxsat.penetration,
               "signed_distance": jaxsat.signed_distance, "signed_distance(smoothing)": SMOOTH,
               "closest_points": jaxsat.closest_points, "contacts": jaxsat.contacts}
    out = {}
    for name, query in queries.items():
        first = core.timed(lambda q=query: jax.block_until_ready(q(a, pa, b, pb)))[1]
        warm = core.time_calls({"": lambda q=query: q(a, pa, b, pb)}, 1, burst=20, burst_s=1.0)
        out[name] = {"first_s": first, "warm_ms": 1e3 * warm[""].best}
    return out

def markdown(rows: list[dict], eager: dict) -> str:
    def ratio(row, kind):
        r, target = row[kind]["ratio"], TARGETS[kind][row["case"]]
        return (f"{row[kind]['pairs_per_s']:.3g}, {r:.2f}x ({target}x, "
                f"{'met' if r <= target else 'not met'})")
    table = [[row["case"], f"{row['pairs']:.0e}", f"{row['penetration']['pairs_per_s']:.3g}",
              ratio(row, "exact"), ratio(row, "smooth"),
              " / ".join(f"{row[k]['compile_s']:.1f}" for k in KERNELS),
              f"{row['exact']['bytes'] / 2**20:.0f} ({row['exact']['temp_bytes'] / 2**20:.0f})",
              " / ".join(core.num(row[k]["page_faults"]) for k in KERNELS),
              f"{row['exact']['max_translation_gradient']:.6f} / "
              f"{row['smooth']['max_translation_gradient']:.6f}"] for row in rows]
    return (f"float32, tau = {TAU}, best of interleaved rounds. Exact MiB: what the compiled "
            "exact value+grad kernel needs (inputs, outputs, temporaries); in brackets its "
            "temporaries alone. Page faults: per call, where memory is touched for the first "
            "time (glibc maps temporaries over 32 MB anew on every call; benchmarks/README.md).\n\n"
            + core.markdown_table(
                ["data set", "pairs", "penetration pairs/s", "exact value+grad: pairs/s, "
                 "x penetration (target)", "smooth value+grad: pairs/s, x penetration (target)",
                 "compile s (pen / exact / smooth)", "exact MiB",
                 "page faults per call (pen / exact / smooth)", "max translation grad"], table)
            + "\nEager calls of the public queries on one pair (first call compiles; warm: "
            "best of 20).\n\n" + core.markdown_table(
                ["data set", "query", "first call s", "warm ms"],
                [[case, name, f"{c['first_s']:.2f}", f"{c['warm_ms']:.3f}"]
                 for case, queries in eager.items() for name, c in queries.items()]))

def main(argv=None) -> int:
    args = core.parse(argv, __doc__, {"sizes": ([10_000, 100_000], [1_000]), "repeats": (5, 2)},
                      CASES)
    info, rows, eager = core.machine_info(), [], {}
    for case in args.cases:
        data = core.make_data(case, max(args.sizes), args.pool, args.seed)
        for pairs in args.sizes:
            rows.append(row := measure(data, pairs, args.repeats))
            print(f"{case} {pairs:.0e}: penetration {row['penetration']['pairs_per_s']:.3g}/s, "
                  f"exact {row['exact']['ratio']:.2f}x, smooth {row['smooth']['ratio']:.2f}x",
                  file=sys.stderr, flush=True)
        eager[case] = eager_latency(data)
    core.save(args, "distance", "Distance queries against penetration", info,
              {"tau": TAU, "targets": TARGETS, "rows": rows, "eager": eager}, markdown(rows, eager))
    return 0

if __name__ == "__main__":
    sys.exit(main())
