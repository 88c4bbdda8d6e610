"""Kernel throughput per data set and size (`jit(vmap(query))` and `query_batch` in chunks),
XLA's cost per pair against this machine's ceilings, and `query_pairs` in chunks on a very
large batch (float32). See benchmarks/README.md.

Usage (from the repository root):
    python benchmarks/kernels.py                 # writes results/kernels-cpu-2core.{json,md}
    python benchmarks/kernels.py --quick
    python benchmarks/kernels.py --query intersects   # results/kernels-intersects-cpu-2core
    XLA_FLAGS=--xla_force_host_platform_device_count=4 python benchmarks/kernels.py \
        --query-pairs 10000000 --devices 4 --cases 3d-boxes --sizes 1000 --no-save
"""

from __future__ import annotations

import math
import os
import pathlib
import resource
import sys

import jax
import jax.numpy as jnp
import numpy as np

import jaxsat

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import core  # noqa: E402

CASES = ["2d-small", "2d-polygons", "3d-boxes", "3d-hulls"]
KERNELS = ("vmap", "chunked")
FMA_CHAIN = 64

def best_seconds(function, *arguments, repeats: int) -> float:
    compiled = core.compile_aot(function, *arguments).call
    return core.time_calls({"": lambda: compiled(*arguments)}, repeats, 5.0)[""].best

def ceilings(repeats: int) -> dict:
    """Fused FMA GFLOP/s, nominal peak GFLOP/s (from /proc/cpuinfo) and copy GB/s."""
    def chain(x):
        for _ in range(FMA_CHAIN):
            x = x * np.float32(0.999) + np.float32(0.001)
        return x
    x, mhz = jnp.ones(1 << 22, jnp.float32), float(core.read_proc("/proc/cpuinfo", "cpu MHz") or 0)
    copy = [8 * size / best_seconds(lambda x: x + 1, jnp.ones(size, jnp.float32),
                                    repeats=repeats) / 1e9 for size in (1 << 24, 1 << 18)]
    return {"fma_gflops": 2 * FMA_CHAIN * x.size / best_seconds(chain, x, repeats=repeats) / 1e9,
            "mhz": mhz, "nominal_gflops": os.cpu_count() * mhz * 64e-3 or None,
            "copy_gbytes_per_s": copy[0], "cache_copy_gbytes_per_s": copy[1]}

def large_batch(args) -> dict:
    shapes, poses = core.make_data("3d-boxes", 1000, pool=1000, seed=args.seed).inputs()[:2]
    poses = jaxsat.Pose(poses.translation * 0.6, poses.rotation)  # about half overlap
    pairs = jnp.asarray(np.random.default_rng(args.seed).integers(
        0, 1000, (args.query_pairs, 2), dtype=np.int32))
    options = {"chunk_size": args.chunk or None, "devices": args.devices or None}
    run = lambda: jaxsat.query_pairs(jaxsat.penetration, shapes, poses, pairs, **options)  # noqa: E731
    peak_rss_mib = lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # noqa: E731
    before = peak_rss_mib()
    depth, first = core.timed(lambda: jax.block_until_ready(run()).depth)
    timing = core.time_calls({"": run}, args.repeats, args.budget_seconds)[""]
    return {"pairs": args.query_pairs, **options, "compile_and_first_s": first,
            "best_s": timing.best, "pairs_per_s": args.query_pairs / timing.best,
            "overlapping": float(jnp.mean(depth >= 0)), "peak_rss_mib_before": before,
            "peak_rss_mib": peak_rss_mib()}

def run_case(case: str, args) -> list[dict]:
    data = core.make_data(case, max(args.sizes), args.pool, args.seed)
    query, chunk = core.QUERIES[args.query], core.CHUNKS[case]
    functions = {"vmap": jax.vmap(query),
                 "chunked": lambda *x: jaxsat.query_batch(query, *x, chunk_size=chunk)}
    rows, per_pair = [], {}
    for n in sorted(args.sizes):
        row = {"case": case, "pairs": n, "chunk_size": chunk}
        spec = core.abstract(data.inputs(slice(0, 1)), n)
        compiled = {name: core.compile_aot(f, *spec) for name, f in functions.items()}
        vmap, calls = compiled["vmap"], {}
        row.update(flops_per_pair=vmap.flops / n, bytes_per_pair=vmap.bytes_accessed / n)
        for name, c in compiled.items():
            row[f"{name}_compile_s"], row[f"{name}_memory_bytes"] = c.seconds, c.memory_bytes
            if skipped := core.too_big(args, c.memory_bytes, per_pair.get(name, 0) * n):
                row[f"{name}_skipped"] = skipped
            else:
                calls[name] = c.call
        if calls:
            inputs = data.inputs(slice(0, n))
            timings = core.time_calls({k: lambda c=c, x=inputs: c(*x) for k, c in calls.items()},
                                      args.repeats, args.budget_seconds, min_rounds=2)
            for name, timing in timings.items():
                per_pair[name] = timing.best / n
                row.update({f"{name}_pairs_per_s": n / timing.best, f"{name}_best_s": timing.best,
                            f"{name}_median_s": timing.median, f"{name}_calls": len(timing.times)})
            out = timing.output  # of the last kernel timed
            row["colliding"] = float(np.mean(out.depth > 0 if args.query == "penetration" else out))
            del inputs, timings
        rows.append(row)
        print(f"{case} {n:.0e}: " + ", ".join(
            f"{name} {row.get(f'{name}_pairs_per_s', 0):.3g} pairs/s" for name in KERNELS),
              file=sys.stderr, flush=True)
    return rows

def roofline(rows: list[dict], limits: dict) -> dict:
    """Per case: the faster kernel at each size, flatness (from 1e4 pairs up, where there are
    such sizes), GFLOP/s and GB/s at the reference size."""
    timed = [(r, v) for r in rows if (v := max(r.get(f"{k}_pairs_per_s", 0) for k in KERNELS))]
    if not timed:
        return {}
    at, best = next(((r, v) for r, v in timed if r["pairs"] == 100_000), timed[-1])
    gflops = at["flops_per_pair"] * best / 1e9
    rates = [v for r, v in timed if r["pairs"] >= 10_000] or [v for _, v in timed]
    return {"reference_pairs": at["pairs"], "compile_s": at["vmap_compile_s"],
            "flops_per_pair": at["flops_per_pair"], "bytes_per_pair": at["bytes_per_pair"],
            "best_pairs_per_s": best, "flatness": max(rates) / min(rates), "gflops": gflops,
            "gbytes_per_s": at["bytes_per_pair"] * best / 1e9,
            "fraction_of_fma_ceiling": gflops / limits["fma_gflops"],
            "fraction_of_nominal_peak": gflops / (limits["nominal_gflops"] or math.nan)}

def markdown(cases: dict, limits: dict, large: dict | None, args) -> str:
    def rate(row, kernel):
        return f"{row[f'{kernel}_pairs_per_s']:.3g}" if f"{kernel}_pairs_per_s" in row else "-"
    text = [f"`jit(vmap({args.query}))` (vmap) and `query_batch` in chunks of C (chunked), "
            f"float32. Ceilings: fused FMA chain {limits['fma_gflops']:.1f} GFLOP/s, nominal "
            f"{limits['nominal_gflops'] or math.nan:.0f} GFLOP/s (cores x {limits['mhz']:.0f} "
            f"MHz x 64, assumed), copy {limits['copy_gbytes_per_s']:.1f} GB/s from memory and "
            f"{limits['cache_copy_gbytes_per_s']:.1f} GB/s in cache. Flops and bytes per pair: "
            "XLA's cost analysis of the vmap (compares and selects count as flops); GFLOP/s, GB/s "
            "and fractions at 1e5 pairs (or the largest), faster kernel; flatness from 1e4 up.", ""]
    head = ["case", "compile s", "flops/pair", "bytes/pair", "C",
            *[f"pairs/s {n:,} vmap / chunked" for n in sorted(args.sizes)],
            "flatness", "GFLOP/s", "of FMA ceiling", "of nominal", "GB/s", "notes"]
    text.append(core.markdown_table(head, [
        [case, f"{s['compile_s']:.2f}", f"{s['flops_per_pair']:.3g}", f"{s['bytes_per_pair']:.3g}",
         core.CHUNKS[case], *[f"{rate(r, 'vmap')} / {rate(r, 'chunked')}" for r in rows],
         f"{s['flatness']:.2f}", f"{s['gflops']:.2f}", f"{s['fraction_of_fma_ceiling']:.1%}",
         f"{s['fraction_of_nominal_peak']:.2%}", f"{s['gbytes_per_s']:.1f}",
         "; ".join(f"{r['pairs']:,} {k}: skipped, {r[f'{k}_skipped']}" for r in rows
                   for k in KERNELS if f"{k}_skipped" in r)]
        for case, (rows, s) in cases.items() if s]))
    if large:
        text.append(f"`query_pairs(penetration)`, {large['pairs']:,} box pairs, chunks of "
                    f"{large['chunk_size']}, devices {large['devices']}: compile and first call "
                    f"{large['compile_and_first_s']:.1f} s, best {large['best_s']:.2f} s "
                    f"({large['pairs_per_s']:.3g} pairs/s), {large['overlapping']:.0%} "
                    f"overlapping, peak RSS {large['peak_rss_mib']:.0f} MiB (before: "
                    f"{large['peak_rss_mib_before']:.0f} MiB).\n")
    return "\n".join(text)

def main(argv=None) -> int:
    args = core.parse(argv, __doc__, {
        "sizes": ([1_000, 10_000, 100_000, 1_000_000], [1_000, 10_000]), "repeats": (7, 3),
        "query_pairs": (10_000_000, 100_000), "budget_seconds": (30, 30),
        "max_call_seconds": (60, 60), "memory_fraction": (0.5, 0.5)}, CASES, limits=core.LIMITS,
        options={"--query": {"choices": list(core.QUERIES), "default": "penetration"},
                 "--query-pairs": "pairs of the large batch (0: none)",
                 "--chunk": {"type": int, "default": 2**14, "help": "its chunk (0: one vmap)"},
                 "--devices": {"type": int, "default": 0, "help": "its devices (0: default)"}})
    info, large = core.machine_info(), large_batch(args) if args.query_pairs else None
    limits = ceilings(args.repeats)
    cases = {case: (rows := run_case(case, args), roofline(rows, limits)) for case in args.cases}
    payload = {"ceilings": limits, "large_batch": large,
               "cases": {case: {"rows": rows, "roofline": s} for case, (rows, s) in cases.items()}}
    core.save(args, "kernels" + "-intersects" * (args.query == "intersects"),
              f"jaxsat kernels ({args.query})", info, payload, markdown(cases, limits, large, args))
    return 0

if __name__ == "__main__":
    sys.exit(main())
