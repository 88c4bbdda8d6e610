"""How close jaxsat's penetration kernels come to this machine's limits.

For each case of the peers benchmark (same seeded pairs), `jax.jit(jax.vmap(jaxsat.penetration))`
is compiled and XLA's cost analysis of the compiled kernel gives the floating-point operations
and the bytes read and written per pair. Timing the kernel then gives the achieved GFLOP/s and
GB/s, which are set against three ceilings:

- an elementwise FMA ceiling measured here: a long chain of multiply-adds that XLA fuses into one
  vectorised loop over 4 million floats, the fastest arithmetic XLA's CPU code reaches;
- a nominal peak: cores x clock x 64 float32 flops per cycle, assuming two 512-bit FMA units per
  core (an assumption: the virtual machine does not say how many units it has);
- a copy bandwidth measured here: `x + 1` over 64 MiB arrays (bytes read plus written).

It also reports the compile time of each kernel and the throughput at each size, both as a plain
vmap and through `jaxsat.query_batch` in chunks (the chunk sizes of the peers benchmark, which
keep a chunk's intermediates in cache). A plain vmap whose compiled kernel would need more than
`--memory-fraction` of the available memory is skipped: a million 20-vertex hull pairs would
hold 11 GiB of edge-pair depths, and chunks are how a user runs them.

Usage (from the repository root):
    python benchmarks/roofline.py                  # sizes 1e4, 1e5, 1e6; writes results/
    python benchmarks/roofline.py --quick          # sizes 1e3, 1e4; prints only
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxsat

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from machine import available_memory_bytes, load_average, machine_info  # noqa: E402
from peers import time_calls  # noqa: E402
from peers_data import CASES, make_case  # noqa: E402
from peers_methods import CHUNK_SIZES, _jaxsat_inputs  # noqa: E402

RESULTS_DIR = HERE / "results"
FMA_CHAIN = 64


def best_seconds(run, repeats: int, budget_s: float) -> float:
    """Best wall time of up to `repeats` calls after a warm-up (as in the peers benchmark)."""
    return min(time_calls(lambda: jax.block_until_ready(run()), repeats, budget_s)[0])


def fma_ceiling(repeats: int) -> float:
    """GFLOP/s of a fused chain of FMA_CHAIN multiply-adds over 4M float32."""
    x = jnp.asarray(np.random.default_rng(0).random(1 << 22, np.float32))

    def chain(x):
        for _ in range(FMA_CHAIN):
            x = x * np.float32(0.999) + np.float32(0.001)
        return x

    compiled = jax.jit(chain).lower(x).compile()
    return 2 * FMA_CHAIN * x.size / best_seconds(lambda: compiled(x), repeats, 5.0) / 1e9


def copy_bandwidth(repeats: int, size: int = 1 << 24) -> float:
    """GB/s (read + written) of x + 1 over float32 arrays of `size` (default 64 MiB)."""
    x = jnp.ones(size, jnp.float32)
    compiled = jax.jit(lambda x: x + 1).lower(x).compile()
    return 2 * x.nbytes / best_seconds(lambda: compiled(x), repeats, 5.0) / 1e9


def nominal_peak() -> tuple[float | None, float | None]:
    """(GFLOP/s, MHz) from the clock in /proc/cpuinfo: cores x MHz x 64 float32 flops."""
    try:
        lines = pathlib.Path("/proc/cpuinfo").read_text().splitlines()
        mhz = float(next(line for line in lines if line.startswith("cpu MHz")).split(":")[1])
    except (OSError, StopIteration, ValueError):
        return None, None
    return os.cpu_count() * mhz * 1e6 * 64 / 1e9, mhz


def kernel_costs(case: str, pool: int, seed: int) -> dict:
    """Compile time, flops, bytes and temporary memory per pair, from a 1e5-pair compile."""
    n = 100_000
    args = _jaxsat_inputs(make_case(case, n, pool, seed), np.arange(n))
    start = time.perf_counter()
    compiled = jax.jit(jax.vmap(jaxsat.penetration)).lower(*args).compile()
    compile_s = time.perf_counter() - start
    cost = compiled.cost_analysis()
    cost = cost[0] if isinstance(cost, list) else cost
    memory = compiled.memory_analysis()
    return {"compile_s": compile_s, "flops_per_pair": cost["flops"] / n,
            "bytes_per_pair": cost["bytes accessed"] / n,
            "temp_bytes_per_pair": getattr(memory, "temp_size_in_bytes", 0) / n}


def time_size(case: str, n: int, costs: dict, args) -> dict:
    """pairs/s at n pairs: a plain vmap (unless its memory would not fit) and query_batch in
    chunks of CHUNK_SIZES[case]."""
    data = make_case(case, n, args.pool, args.seed)
    inputs = jax.device_put(_jaxsat_inputs(data, np.arange(n)))
    chunk = CHUNK_SIZES[case]
    result = {"pairs": n, "chunk_size": chunk, "vmap_pairs_per_s": None}
    if n * costs["temp_bytes_per_pair"] <= args.memory_fraction * available_memory_bytes():
        compiled = jax.jit(jax.vmap(jaxsat.penetration)).lower(*inputs).compile()
        seconds = best_seconds(lambda: compiled(*inputs), args.repeats, args.budget_seconds)
        result["vmap_pairs_per_s"] = n / seconds
    seconds = best_seconds(
        lambda: jaxsat.query_batch(jaxsat.penetration, *inputs, chunk_size=chunk),
        args.repeats, args.budget_seconds)
    result["chunked_pairs_per_s"] = n / seconds
    return result


def run_case(case: str, args, ceilings: dict) -> dict:
    costs = kernel_costs(case, args.pool, args.seed)
    sizes = [time_size(case, n, costs, args) for n in args.sizes]
    for size in sizes:
        size["best_pairs_per_s"] = max(size["chunked_pairs_per_s"], size["vmap_pairs_per_s"] or 0)
    rates = [size["best_pairs_per_s"] for size in sizes]
    at = next((s for s in sizes if s["pairs"] == 100_000), sizes[-1])
    best = at["best_pairs_per_s"]
    gflops = costs["flops_per_pair"] * best / 1e9
    row = {"case": case, **costs, "sizes": sizes, "flatness": max(rates) / min(rates),
           "reference_pairs": at["pairs"], "best_pairs_per_s": best, "gflops": gflops,
           "gbytes_per_s": costs["bytes_per_pair"] * best / 1e9,
           "fraction_of_fma_ceiling": gflops / ceilings["fma_gflops"]}
    if ceilings["nominal_gflops"]:
        row["fraction_of_nominal_peak"] = gflops / ceilings["nominal_gflops"]
    return row


def _rate(value: float | None) -> str:
    return "-" if value is None else f"{value:.3g}"


def markdown(rows: list[dict], ceilings: dict, info: dict, sizes: list[int]) -> str:
    nominal = ceilings["nominal_gflops"]
    lines = [
        f"jaxsat roofline, {info['date_utc']}, git {info['git_commit']}",
        "",
        f"Machine: {info['cpu_model']}, {info['cpu_count']} CPUs; load average "
        f"{info['load_average_start']} at start, {load_average()} at end; jax "
        f"{info['versions'].get('jax')}.",
        f"Ceilings: fused FMA chain {ceilings['fma_gflops']:.1f} GFLOP/s (measured); nominal "
        + (f"{nominal:.0f} GFLOP/s ({info['cpu_count']} cores x {ceilings['mhz']:.0f} MHz x 64, "
           "assumed)" if nominal else "unknown")
        + f"; copy {ceilings['copy_gbytes_per_s']:.1f} GB/s from memory, "
        f"{ceilings['cache_copy_gbytes_per_s']:.1f} GB/s in cache (measured).",
        "",
        "Flops and bytes per pair: XLA's cost analysis of `jit(vmap(penetration))` for 1e5 "
        "float32 pairs. pairs/s: plain vmap / `query_batch` in chunks of C pairs (- where the "
        "vmap would not fit in memory). GFLOP/s, GB/s and fractions at 1e5 pairs, the faster "
        "of the two. Flatness: fastest over slowest pairs/s across the sizes (the faster of "
        "the two at each size). XLA counts every elementwise operation (compares and selects "
        "too) as a flop.",
        "",
        "| case | compile s | flops/pair | bytes/pair | C | "
        + " | ".join(f"pairs/s {n:.0e}" for n in sizes)
        + " | flatness | GFLOP/s | of FMA ceiling | of nominal | GB/s |",
        "|---" * (10 + len(sizes)) + "|",
    ]
    for row in rows:
        cells = [f"{_rate(s['vmap_pairs_per_s'])} / {_rate(s['chunked_pairs_per_s'])}"
                 for s in row["sizes"]]
        of_nominal = row.get("fraction_of_nominal_peak")
        lines.append(
            f"| {row['case']} | {row['compile_s']:.2f} | {row['flops_per_pair']:.3g} | "
            f"{row['bytes_per_pair']:.3g} | {row['sizes'][0]['chunk_size']} | "
            + " | ".join(cells) + f" | {row['flatness']:.2f} | {row['gflops']:.2f} | "
            f"{row['fraction_of_fma_ceiling']:.1%} | "
            + (f"{of_nominal:.2%}" if of_nominal is not None else "-")
            + f" | {row['gbytes_per_s']:.1f} |")
    return "\n".join(lines) + "\n"


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="sizes 1e3 and 1e4, 3 repeats, "
                        "no files written")
    parser.add_argument("--cases", nargs="+", choices=list(CASES), default=list(CASES))
    parser.add_argument("--sizes", nargs="+", type=int, default=None,
                        help="pairs per timed call (default 10000 100000 1000000)")
    parser.add_argument("--repeats", type=int, default=None, help="timed calls (default 7)")
    parser.add_argument("--budget-seconds", type=float, default=20.0,
                        help="stop repeating a size once its calls add up to this")
    parser.add_argument("--memory-fraction", type=float, default=0.3,
                        help="run a size in chunks when a plain vmap needs more than this "
                        "fraction of the available memory (default 0.3)")
    parser.add_argument("--pool", type=int, default=256, help="random shapes per case")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--output", type=pathlib.Path, default=RESULTS_DIR / "roofline-cpu-2core",
                        help="prefix of the .json and .md written (not with --quick)")
    args = parser.parse_args(argv)
    if args.sizes is None:
        args.sizes = [1_000, 10_000] if args.quick else [10_000, 100_000, 1_000_000]
    if args.repeats is None:
        args.repeats = 3 if args.quick else 7
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    info = machine_info()
    nominal, mhz = nominal_peak()
    ceilings = {"fma_gflops": fma_ceiling(args.repeats), "nominal_gflops": nominal, "mhz": mhz,
                "copy_gbytes_per_s": copy_bandwidth(args.repeats),
                "cache_copy_gbytes_per_s": copy_bandwidth(args.repeats, 1 << 18)}
    rows = []
    for case in args.cases:
        print(f"{case} ...", file=sys.stderr, flush=True)
        rows.append(run_case(case, args, ceilings))
    table = markdown(rows, ceilings, info, args.sizes)
    print(table)
    if not args.quick:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        record = {"machine": info, "ceilings": ceilings, "rows": rows,
                  "load_average_end": load_average(), "sizes": args.sizes}
        args.output.with_suffix(".json").write_text(json.dumps(record, indent=2) + "\n")
        args.output.with_suffix(".md").write_text(table)
        print(f"wrote {args.output}.json and .md", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
