"""Cost of the differentiable distance queries against `penetration`, on the same pairs, in one
process (float32): the targets of the distance issue are ratios, so they are measured as such.

For each data set of `throughput.py` (`2d-polygons`: convex 3-8-gons padded to 8 vertices,
`3d-boxes`, `3d-hulls`: hulls of 20 points padded to 20) and each batch size:

* `penetration`: `jit(vmap(penetration))`, the depth (the baseline);
* `exact`: value and gradient (with respect to both poses) of `signed_distance`;
* `smooth`: the same with `smoothing=TAU`.

Each kernel is compiled ahead of time from abstract inputs (the compile column) and its memory
need read from the executable; then the kernels are called in interleaved rounds and each keeps
its best time, so that load on this shared machine affects them alike. The largest translation
gradient norm of each distance over the batch is reported too (the signed distance is
1-Lipschitz in translation: it must not exceed 1).

Last, every public query is called eagerly on one pair of each data set: the first call
(compiles) and the best of a few warm calls.

Usage (from the repository root):
    python benchmarks/distance.py                       # about 5 minutes
    python benchmarks/distance.py --quick               # 1e3 pairs, seconds
    python benchmarks/distance.py --output benchmarks/results/distance-cpu-2core
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

import jax
import numpy as np

import jaxsat

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from machine import machine_info  # noqa: E402
from throughput import abstract_batch, make_batch, make_pool, time_calls  # noqa: E402

CASES = ("2d-polygons", "3d-boxes", "3d-hulls")
TAU = 0.005
"""Smoothing length: 1% of the typical shape radius (0.5) of the data sets."""
TARGETS = {"exact": {"2d-polygons": 3.0, "3d-boxes": 3.0, "3d-hulls": 3.0},
           "smooth": {"2d-polygons": 5.0, "3d-boxes": 5.0, "3d-hulls": 3.0}}
"""Largest allowed cost, as a multiple of penetration's on the same pairs."""
CALLS_PER_ROUND, ROUND_BUDGET_S = 10, 1.0
"""Each kernel's turn in a round: up to this many calls, stopping past this many seconds (a
2D batch of 1e4 runs in under a millisecond, where one call is at the mercy of the scheduler).
"""
MEMORY_TARGET = 2 * 2**30
"""1e5 hull pairs of exact value+gradient in one vmap must fit in this many bytes."""


def _distance(smoothing):
    def value(a, pose_a, b, pose_b):
        return jaxsat.signed_distance(a, pose_a, b, pose_b, smoothing=smoothing)
    return jax.value_and_grad(value, argnums=(1, 3))


KERNELS = {
    "penetration": lambda a, pa, b, pb: jaxsat.penetration(a, pa, b, pb).depth,
    "exact": _distance(None),
    "smooth": _distance(TAU),
}


def compile_all(case: str, pool, pairs: int) -> dict:
    compiled = {}
    for name, kernel in KERNELS.items():
        start = time.perf_counter()
        executable = jax.jit(jax.vmap(kernel)).lower(*abstract_batch(case, pool, pairs)).compile()
        seconds = time.perf_counter() - start
        stats = executable.memory_analysis()
        needed = (stats.argument_size_in_bytes + stats.output_size_in_bytes
                  + stats.temp_size_in_bytes, stats.temp_size_in_bytes)
        compiled[name] = (executable, seconds, needed)
    return compiled


def measure(case: str, pairs: int, args, rng) -> dict:
    pool = make_pool(case, rng, 64)
    batch = make_batch(case, pool, pairs, rng)
    compiled = compile_all(case, pool, pairs)
    best = {name: np.inf for name in KERNELS}
    outputs = {}
    for _ in range(args.rounds):
        for name, (executable, _, _) in compiled.items():
            times = time_calls(executable, batch, CALLS_PER_ROUND, ROUND_BUDGET_S)
            best[name] = min(best[name], min(times))
            outputs[name] = executable(*batch)
    row = {"case": case, "pairs": pairs}
    for name, (_, seconds, needed) in compiled.items():
        row[name] = {"pairs_per_s": pairs / best[name], "compile_s": seconds,
                     "bytes": needed[0], "temp_bytes": needed[1],
                     "ratio": best[name] / best["penetration"]}
        if name != "penetration":
            _, (grad_a, grad_b) = outputs[name]
            norms = [np.linalg.norm(np.asarray(g.translation, np.float64), axis=-1)
                     for g in (grad_a, grad_b)]
            row[name]["max_translation_gradient"] = float(max(n.max() for n in norms))
    return row


def eager_latency(case: str, rng) -> dict:
    """First (compiling) and best warm eager call of each public query on one pair."""
    pool = make_pool(case, rng, 2)
    a, pose_a, b, pose_b = (jax.tree.map(lambda leaf: leaf[0], x)
                            for x in make_batch(case, pool, 1, rng))
    queries = {
        "intersects": lambda: jaxsat.intersects(a, pose_a, b, pose_b),
        "penetration": lambda: jaxsat.penetration(a, pose_a, b, pose_b),
        "signed_distance": lambda: jaxsat.signed_distance(a, pose_a, b, pose_b),
        "signed_distance(smoothing)": lambda: jaxsat.signed_distance(a, pose_a, b, pose_b,
                                                                     smoothing=TAU),
        "closest_points": lambda: jaxsat.closest_points(a, pose_a, b, pose_b),
        "contacts": lambda: jaxsat.contacts(a, pose_a, b, pose_b),
    }
    out = {}
    for name, call in queries.items():
        start = time.perf_counter()
        jax.block_until_ready(call())
        first = time.perf_counter() - start
        warm = min(time_calls(lambda *_, call=call: call(), (), 20, 1.0))
        out[name] = {"first_s": first, "warm_ms": 1e3 * warm}
    return out


def markdown(rows: list[dict], eager: dict, info: dict) -> str:
    lines = [f"# Distance queries against penetration ({info['cpu_model']}, "
             f"{info['cpu_count']} cores, load {info['load_average_start']})", "",
             f"float32, tau = {TAU}, best of interleaved rounds; commit {info['git_commit']}. "
             f"Exact MiB: what the compiled exact value+grad kernel needs (inputs, outputs, "
             f"temporaries); in brackets its temporaries alone.", "",
             "| data set | pairs | penetration pairs/s | exact value+grad: pairs/s, "
             "x penetration (target) | smooth value+grad: pairs/s, x penetration (target) "
             "| compile s (pen / exact / smooth) | exact MiB | max translation grad |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for row in rows:
        pen, exact, smooth = row["penetration"], row["exact"], row["smooth"]
        case = row["case"]
        mark = lambda r, kind, case=case: (  # noqa: E731
            "met" if r <= TARGETS[kind][case] else "not met")
        lines.append(
            f"| {case} | {row['pairs']:.0e} | {pen['pairs_per_s']:.3g} | "
            f"{exact['pairs_per_s']:.3g}, {exact['ratio']:.2f}x ({TARGETS['exact'][case]}x, "
            f"{mark(exact['ratio'], 'exact')}) | {smooth['pairs_per_s']:.3g}, "
            f"{smooth['ratio']:.2f}x ({TARGETS['smooth'][case]}x, "
            f"{mark(smooth['ratio'], 'smooth')}) | {pen['compile_s']:.1f} / "
            f"{exact['compile_s']:.1f} / {smooth['compile_s']:.1f} | "
            f"{exact['bytes'] / 2**20:.0f} ({exact['temp_bytes'] / 2**20:.0f}) | "
            f"{exact['max_translation_gradient']:.6f} / "
            f"{smooth['max_translation_gradient']:.6f} |")
    lines += ["", "Eager calls of the public queries on one pair (first call compiles; warm: "
              "best of 20).", "",
              "| data set | query | first call s | warm ms |", "| --- | --- | --- | --- |"]
    for case, queries in eager.items():
        for name, cell in queries.items():
            lines.append(f"| {case} | {name} | {cell['first_s']:.2f} | "
                         f"{cell['warm_ms']:.3f} |")
    return "\n".join(lines) + "\n"


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000])
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=CASES)
    parser.add_argument("--rounds", type=int, default=5, help="interleaved timing rounds")
    parser.add_argument("--quick", action="store_true", help="1e3 pairs, 2 rounds")
    parser.add_argument("--output", type=pathlib.Path, help="write OUTPUT.json and OUTPUT.md")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if args.quick:
        args.sizes, args.rounds = [1_000], 2
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    info = machine_info()
    rng = np.random.default_rng(args.seed)
    rows = []
    for case in args.cases:
        for pairs in args.sizes:
            rows.append(measure(case, pairs, args, rng))
            row = rows[-1]
            print(f"{case} {pairs:.0e}: penetration {row['penetration']['pairs_per_s']:.3g}/s, "
                  f"exact {row['exact']['ratio']:.2f}x, smooth {row['smooth']['ratio']:.2f}x",
                  flush=True)
    eager = {case: eager_latency(case, rng) for case in args.cases}
    text = markdown(rows, eager, info)
    print(text)
    if args.output:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        payload = {"machine": info, "tau": TAU, "targets": TARGETS, "rows": rows,
                   "eager": eager, "memory_target_bytes": MEMORY_TARGET}
        args.output.with_suffix(".json").write_text(json.dumps(payload, indent=1))
        args.output.with_suffix(".md").write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
