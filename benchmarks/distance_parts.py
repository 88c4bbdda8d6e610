"""Where the differentiable distance's time goes: each stage of `signed_distance`, exact and
smooth, compiled on its own, as a multiple of `penetration` on the same pairs in one process
(float32). See benchmarks/README.md.

The smooth value is the maximum over unit axes of the soft gap (`_smoothing`): it starts at
the exact maximiser (the exact search), takes search passes of trust-region Newton steps
(a second search from the SAT runner-up where it could end higher) and differentiates the
soft gap at the maximising axis (the envelope theorem). The `floor` row is the soft gap's
value and pose gradient at the SAT axis, with no search at all: what any maximiser of the
soft gap pays at least, beyond finding its axis.

Usage (from the repository root):
    python benchmarks/distance_parts.py          # ~4 min; writes results/distance_parts-cpu-2core.*
    python benchmarks/distance_parts.py --quick  # 1e3 pairs
"""

from __future__ import annotations

import pathlib
import sys

import jax
import jax.numpy as jnp

import jaxsat
from jaxsat import _smoothing as smoothing
from jaxsat._closest import exact_distance
from jaxsat._pair import pair_frame
from jaxsat._sat import sat_runner_up, sat_search

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import core  # noqa: E402
import distance  # noqa: E402

CASES = distance.CASES
TAU = distance.TAU


def _frozen(a, pa, b, pb):
    return jax.lax.stop_gradient(pair_frame(a, pa, b, pb))


def _soft_gap_value_and_gradient(a, pa, b, pb, axis):
    """soft_gap at a fixed axis, and its gradient with respect to both poses."""
    return jax.value_and_grad(lambda pa, pb: smoothing.soft_gap(
        pair_frame(a, pa, b, pb), axis, jnp.asarray(TAU, axis.dtype)), argnums=(0, 1))(pa, pb)


PARTS = {
    "penetration": lambda a, pa, b, pb, axis: jaxsat.penetration(a, pa, b, pb).depth,
    "SAT": lambda a, pa, b, pb, axis: sat_search(_frozen(a, pa, b, pb)).axis,
    "exact search": lambda a, pa, b, pb, axis: exact_distance(_frozen(a, pa, b, pb)).axis,
    "SAT runner-up": lambda a, pa, b, pb, axis: sat_runner_up(_frozen(a, pa, b, pb), axis,
                                                              0.01)[0],
    "search pass": lambda a, pa, b, pb, axis: smoothing._search(
        _frozen(a, pa, b, pb), jnp.asarray(TAU, axis.dtype), axis, jnp.zeros((), axis.dtype))[0],
    "soft gap value+grad": _soft_gap_value_and_gradient,
    "floor": lambda a, pa, b, pb, axis: _soft_gap_value_and_gradient(
        a, pa, b, pb, sat_search(_frozen(a, pa, b, pb)).axis),
    "exact value+grad": lambda a, pa, b, pb, axis: distance.KERNELS["exact"](a, pa, b, pb),
    "smooth value+grad": lambda a, pa, b, pb, axis: distance.KERNELS["smooth"](a, pa, b, pb),
}
"""One pair and the exact maximising axis (a's frame): each stage, with no gradient unless
named."""

MEANING = {
    "exact value+grad": "signed_distance and its pose gradient, as in distance.py",
    "smooth value+grad": f"signed_distance(..., smoothing={TAU}) and its pose gradient",
    "SAT": "the SAT search alone (all candidates, as the distance runs it)",
    "exact search": "exact_distance: the SAT, then GJK (3D) or the support faces (2D); the "
                    "smooth search's first start",
    "SAT runner-up": "the second start",
    "search pass": f"one pass of {smoothing.NEWTON_STEPS} Newton steps from the exact axis",
    "soft gap value+grad": "at the exact axis held fixed: the envelope gradient",
    "floor": "soft gap value+grad at the SAT axis, nothing searched",
}


def measure(data: core.DataSet, pairs: int, rounds: int) -> dict:
    batch = data.inputs(slice(0, pairs))
    axes = jax.jit(jax.vmap(lambda *x: exact_distance(_frozen(*x)).axis))(*batch)
    compiled = {name: core.compile_aot(jax.vmap(part), *batch, axes)
                for name, part in PARTS.items()}
    timings = core.time_calls({name: lambda c=c: c.call(*batch, axes)
                               for name, c in compiled.items()}, rounds, burst=10, burst_s=1.0)
    base = timings["penetration"].best
    return {"case": data.name, "pairs": pairs,
            "ratio": {name: t.best / base for name, t in timings.items()},
            "penetration_pairs_per_s": pairs / base}


def markdown(rows: list[dict]) -> str:
    head = ["part", "what", *(f"{row['case']} {row['pairs']:.0e}" for row in rows)]
    table = [[name, MEANING.get(name, ""), *(f"{row['ratio'][name]:.2f}x" for row in rows)]
             for name in PARTS]
    table.append(["penetration, pairs/s", "", *(core.num(row["penetration_pairs_per_s"], 3)
                                                for row in rows)])
    return (f"float32, tau = {TAU}; each part compiled on its own (jit of vmap), best of "
            "interleaved rounds, as a multiple of penetration's time on the same pairs.\n\n"
            + core.markdown_table(head, table))


def main(argv=None) -> int:
    args = core.parse(argv, __doc__, {"sizes": ([10_000], [1_000]), "repeats": (7, 2)}, CASES)
    info, rows = core.machine_info(), []
    for case in args.cases:
        data = core.make_data(case, max(args.sizes), args.pool, args.seed)
        for pairs in args.sizes:
            rows.append(row := measure(data, pairs, args.repeats))
            print(f"{case} {pairs:.0e}: " + ", ".join(
                f"{name} {ratio:.2f}x" for name, ratio in row["ratio"].items()),
                file=sys.stderr, flush=True)
    core.save(args, "distance_parts", "Distance queries part by part against penetration",
              info, {"tau": TAU, "rows": rows}, markdown(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
