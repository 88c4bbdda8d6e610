"""Run time against error of `jaxsat.signed_distance`, exact (float32, float64) and smooth
(float64, float32, a sweep of tau), for values and pose gradients, against the oracle of
tests/oracle.py and its finite differences. See benchmarks/README.md.

Usage (from the repository root):
    python benchmarks/runtime_vs_error.py    # writes results/runtime_vs_error-cpu-2core.*
    python benchmarks/runtime_vs_error.py --quick --output /tmp/rve   # 2D only, under a minute
"""

from __future__ import annotations

import pathlib
import sys

import jax

jax.config.update("jax_enable_x64", True)  # float64 variants; float32 ones are explicit

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import jaxsat  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import core  # noqa: E402

CASES = ["2d-octagons", "3d-boxes", "3d-hulls"]
SIZE = 0.5
"""Typical shape radius: the smoothing lengths are tau = fraction * SIZE."""
TAU_FRACTIONS = (1e-4, 1e-3, 1e-2, 3e-2, 1e-1)
CHUNK = {"2d-octagons": 4096, "3d-boxes": 2048, "3d-hulls": 128}
FD_AGREEMENT = 1e-5
"""Pairs whose two finite-difference gradients differ by more are skipped (kinks)."""

def make_kernel(smooth: bool, gradient: bool, chunk: int):
    """f(tau, params_a, params_b, a, b) over a batch: values, or (values, (N, 2P) gradients);
    batches longer than `chunk` (a multiple of it) run as a lax.map over chunks."""
    def one(params_a, params_b, a, b, tau):
        return jaxsat.signed_distance(a, core.pose(params_a), b, core.pose(params_b),
                                      smoothing=tau if smooth else None)
    def pair(*xs):
        if not gradient:
            return one(*xs)
        value, grads = jax.value_and_grad(one, argnums=(0, 1))(*xs)
        return value, jnp.concatenate(grads)
    def batch(tau, *inputs):  # batch_size 0: one vmap
        return jax.lax.map(lambda xs: pair(*xs, tau), inputs,
                           batch_size=chunk if inputs[0].shape[0] > chunk else 0)
    return batch

def variants(smooth_dtypes) -> list[dict]:
    rows = [{"variant": f"exact-{d}", "dtype": d, "smooth": False, "tau_fraction": 0.0}
            for d in ("float32", "float64")]
    return rows + [{"variant": f"smooth-{d}", "dtype": d, "smooth": True, "tau_fraction": f}
                   for d in smooth_dtypes for f in TAU_FRACTIONS]

def run_case(case: str, args) -> tuple[dict, list[dict]]:
    pairs, smooth_pairs = ((args.hull_pairs, args.hull_smooth_pairs) if case == "3d-hulls"
                           else (args.pairs, args.smooth_pairs))
    smooth_pairs, chunk = min(smooth_pairs, pairs), CHUNK[case]
    if any(count > chunk and count % chunk for count in (pairs, smooth_pairs)):
        raise SystemExit(f"{case}: pairs must be multiples of the chunk {chunk}")
    data = core.make_data(case, pairs, args.pool, args.seed)
    reference = core.reference(data, pairs).signed
    fd_pairs = np.sort(np.random.default_rng(args.seed).choice(
        smooth_pairs, min(args.grad_pairs, smooth_pairs), False))
    grad_index, grad_reference = core.oracle_gradients(
        data, fd_pairs, range(data.params.shape[-1] * 2), FD_AGREEMENT)
    info = {"case": case, "pairs": pairs, "smooth_pairs": smooth_pairs,
            "overlapping_fraction": float(np.mean(reference < 0)), "grad_pairs": len(grad_index),
            "grad_skipped_kinks": len(fd_pairs) - len(grad_index)}
    print(f"# {info}", file=sys.stderr, flush=True)
    kernels, rows = {}, []
    bound = np.asarray(jaxsat.smoothing_error_bound(*data.shapes(dtype=np.float64)), np.float64)
    moves = np.r_[0:data.dim, data.params.shape[-1]:data.params.shape[-1] + data.dim]
    for variant in variants(args.smooth_dtypes):
        count, dtype = smooth_pairs if variant["smooth"] else pairs, variant["dtype"]
        tau = variant["tau_fraction"] * SIZE
        arguments = (jnp.asarray(tau, dtype), *jnp.asarray(data.params[:, :count], dtype),
                     *data.shapes(slice(0, count), np.dtype(dtype)))
        row, outputs = {"case": case, **variant, "tau": tau, "pairs": count}, {}
        for kind in ("value", "grad"):
            key = (variant["smooth"], kind, dtype, count)
            if key not in kernels:  # one compiled kernel serves the whole tau sweep
                kernels[key] = core.compile_aot(make_kernel(variant["smooth"], kind == "grad",
                                                            chunk), *arguments)
            compiled = kernels[key]
            timing = core.time_calls({"": lambda c=compiled, x=arguments: c.call(*x)}, args.repeats,
                                     args.budget_seconds, burst=20, burst_s=0.5)[""]
            row.update({f"{kind}_compile_s": compiled.seconds, f"{kind}_best_s": timing.best,
                        f"{kind}_median_s": timing.median, f"{kind}_timed_calls": len(timing.times),
                        f"{kind}_pairs_per_second": count / timing.best})
            outputs[kind] = jax.tree.map(lambda x: np.asarray(x, np.float64), timing.output)
        values, (grad_values, gradients) = outputs["value"], outputs["grad"]
        value_errors = np.abs(values - reference[:count])
        grad_errors = gradients[grad_index] - grad_reference
        row.update(**core.stats("value_error", value_errors),
                   **core.stats("grad_error", np.linalg.norm(grad_errors, axis=1)),
                   grad_translation_error_max=float(np.max(np.linalg.norm(
                       grad_errors[:, moves], axis=1))),
                   value_grad_kernel_value_error_max=float(np.max(np.abs(grad_values - values))),
                   nonfinite=int(np.sum(~np.isfinite(values)) + np.sum(~np.isfinite(gradients))))
        if variant["smooth"]:
            allowed = bound[:count] * tau
            slack = 1e-12 if dtype == "float64" else 1e-5  # rounding of the inputs
            row.update(bound_max=float(allowed.max()),
                       bound_violations=int(np.sum(value_errors > allowed + slack)))
        rows.append(row)
        print(" | ".join(map(str, cells(row))), file=sys.stderr, flush=True)
    return info, rows

HEAD = ["case", "variant", "tau / size", "pairs", "compile value / grad (s)", "value pairs/s",
        "value+grad pairs/s", "value error max", "median", "grad error max", "median",
        "bound c tau (max)"]

def cells(row: dict) -> list:
    bound = f"{row['bound_max']:.1e}" if row["smooth"] else "-"
    if row.get("bound_violations"):
        bound += f" ({row['bound_violations']} over)"
    return [row["case"], row["variant"], f"{row['tau_fraction']:g}" if row["smooth"] else "-",
            row["pairs"], f"{row['value_compile_s']:.1f} / {row['grad_compile_s']:.1f}",
            *(f"{row[f'{k}_pairs_per_second']:.2g}" for k in ("value", "grad")),
            *(f"{row[f'{k}_error_{s}']:.1e}" for k in ("value", "grad") for s in ("max", "median")),
            bound]

def main(argv=None) -> int:
    args = core.parse(argv, __doc__, {
        "pairs": (8192, 512), "smooth_pairs": (2048, 256), "hull_pairs": (2048, 128),
        "hull_smooth_pairs": (256, 128), "grad_pairs": (200, 10), "repeats": (3, 1),
        "pool": (256, 16), "cases": (CASES, ["2d-octagons"]),
        "smooth_dtypes": (["float64", "float32"], ["float64"]), "budget_seconds": (6, 6)},
        CASES, sizes=None, limits=["--budget-seconds"], options={
            "--pairs": "pairs of the 2D and box data sets (exact variants)",
            "--smooth-pairs": "their first pairs the smooth variants run on",
            "--hull-pairs": "pairs of 3D hulls (exact variants)",
            "--hull-smooth-pairs": "the first hull pairs for smooth variants",
            "--grad-pairs": "pairs per case for the finite-difference check",
            "--smooth-dtypes": {"nargs": "+", "choices": ["float64", "float32"]}})
    info, results = core.machine_info(), [run_case(case, args) for case in args.cases]
    cases, rows = [c for c, _ in results], [row for _, case_rows in results for row in case_rows]
    core.save(args, "runtime_vs_error", "jaxsat signed_distance: run time against error", info,
              {"size": SIZE, "tau_fractions": TAU_FRACTIONS, "fd_steps": core.FD_STEPS,
               "fd_agreement": FD_AGREEMENT, "chunk": CHUNK, "cases": cases, "rows": rows},
              core.markdown_table(HEAD, [cells(row) for row in rows]))
    return 0

if __name__ == "__main__":
    sys.exit(main())
