"""Bounded memory for very large batches: `jaxsat.query_pairs(penetration)` on random box pairs.

A pool of 1,000 random boxes (float32) in a small cube (about half the random pairs overlap);
`--pairs` random index pairs into it run through `query_pairs` in chunks of `--chunk` pairs
(0 = one vmap over everything). Prints the compile + first call time, the best of `--repeats`
calls, pairs per second and the process's peak resident memory (ru_maxrss).

Usage (from the repository root):
    python benchmarks/chunked.py --pairs 10000000 --chunk 16384
    XLA_FLAGS=--xla_force_host_platform_device_count=4 python benchmarks/chunked.py --devices 4
"""

from __future__ import annotations

import argparse
import resource
import time

import jax
import jax.numpy as jnp
import numpy as np
from scipy.spatial.transform import Rotation

import jaxsat


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", type=int, default=10_000_000)
    parser.add_argument("--chunk", type=int, default=2**14, help="0: no chunking")
    parser.add_argument("--devices", type=int, default=0, help="0: the default device")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--pool", type=int, default=1000)
    return parser.parse_args(argv)


def peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main(argv=None) -> None:
    args = parse_args(argv)
    rng = np.random.default_rng(0)
    shapes = jaxsat.stack([jaxsat.box(rng.uniform(0.15, 0.6, 3), dtype=np.float32)
                           for _ in range(args.pool)])
    poses = jaxsat.Pose(jnp.asarray(rng.uniform(-0.6, 0.6, (args.pool, 3)), jnp.float32),
                        jnp.asarray(Rotation.random(args.pool, random_state=1).as_matrix(),
                                    jnp.float32))
    pairs = jnp.asarray(rng.integers(0, args.pool, (args.pairs, 2), dtype=np.int32))
    options = {"chunk_size": args.chunk or None, "devices": args.devices or None}
    before = peak_rss_mib()
    start = time.perf_counter()
    depth = jaxsat.query_pairs(jaxsat.penetration, shapes, poses, pairs, **options).depth
    first = time.perf_counter() - start + 0 * float(depth[0])
    times = []
    for _ in range(args.repeats):
        start = time.perf_counter()
        jax.block_until_ready(jaxsat.query_pairs(jaxsat.penetration, shapes, poses, pairs,
                                                 **options))
        times.append(time.perf_counter() - start)
    print(f"pairs={args.pairs:,} chunk={options['chunk_size']} devices={options['devices']} "
          f"overlapping={float(jnp.mean(depth >= 0)):.2f} compile+first={first:.1f}s "
          f"best={min(times):.2f}s ({args.pairs / min(times):.3g} pairs/s) "
          f"peak RSS {peak_rss_mib():.0f} MiB (before the query: {before:.0f} MiB)")


if __name__ == "__main__":
    main()
