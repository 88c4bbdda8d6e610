"""jaxsat next to its peers: speed and error of every method on the same pairs, in one run.

Cases (one fixed, seeded data set each; every method sees the same pairs):
  2d-small     random convex polygons with 3-4 vertices (jax2d's limit)
  2d-polygons  random convex polygons with 4-8 vertices
  3d-boxes     random boxes
  3d-hulls     convex hulls of 20 random points
Methods: jaxsat (penetration; closest_points as "jaxsat-distance"), a vectorised NumPy SAT
(float32, float64), jax2d, pymunk, collision (SAT.js port), MJX, MuJoCo C (mj_collision,
mj_geomDistance) and Coal. A method whose package is missing is listed as skipped. Each row
says its level: depth+normal, signed distance+normal, or contacts (a contact manifold, whose
deepest contact gives the depth and normal compared here).

For each method and case: pairs/s at each size (best of --repeats calls after a warm-up;
Python loops are timed on at most --loop-pairs pairs), setup time (JAX compile, MuJoCo model
build, or object building), errors in depth and normal against the float64 oracle of
tests/oracle.py on the first --error-pairs pairs, wrong overlap decisions, distance errors on
separated pairs (distance-level rows), and, where the method has gradients, the error of
d depth / d translation of b against central finite differences of the oracle on up to
--grad-pairs overlapping pairs.

Writes PREFIX.md (table), PREFIX.json (rows, machine, versions, load, git commit) and
PREFIX.png (error against pairs/s), PREFIX defaulting to benchmarks/results/peers-<UTC time>.

Usage (from the repository root, with `pip install -e ".[bench]"`):
    python benchmarks/peers.py --quick                 # a few minutes
    python benchmarks/peers.py                         # full run, 1e3-1e5 pairs
    python benchmarks/peers.py --cases 3d-boxes --methods jaxsat mjx mujoco-collision
    python benchmarks/peers.py --list                  # methods and whether they are installed
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import pathlib
import statistics
import sys
import time

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from machine import available_memory_bytes, load_average, machine_info  # noqa: E402
from peers_data import CASES, Reference, gradient_pairs, make_case, reference  # noqa: E402
from peers_methods import CONTACTS, DISTANCE, METHODS, Method  # noqa: E402

RESULTS_DIR = HERE / "results"
FULL = {"sizes": [1_000, 10_000, 100_000], "error_pairs": 2000, "grad_pairs": 200,
        "loop_pairs": 20_000, "repeats": 5, "max_call_seconds": 60.0}
QUICK = {"sizes": [1_000, 10_000], "error_pairs": 500, "grad_pairs": 20, "loop_pairs": 1000,
         "repeats": 2, "max_call_seconds": 10.0}
DISTRIBUTIONS = ("jax", "jaxlib", "jaxsat", "numpy", "scipy", "mujoco", "mujoco-mjx", "jax2d",
                 "pymunk", "collision", "coal", "tqdm", "matplotlib")
DEPTH_FLOOR = 1e-17
ANGLE_FLOOR = 1e-15
"""Zero errors are drawn at these values on the log axes of the plot."""


# ----------------------------------------------------------------------------- progress


class Progress:
    """tqdm (or rich-free plain printing) over (case, method) tasks."""

    def __init__(self, total: int, enabled: bool):
        self.bar = None
        if enabled:
            try:
                from tqdm import tqdm

                self.bar = tqdm(total=total, unit="task", dynamic_ncols=True, file=sys.stderr)
            except ImportError:
                pass

    def describe(self, text: str) -> None:
        if self.bar is not None:
            self.bar.set_description(text)
        else:
            print(f"... {text}", file=sys.stderr, flush=True)

    def echo(self, text: str) -> None:
        if self.bar is not None:
            self.bar.write(text)
        else:
            print(text, flush=True)

    def step(self) -> None:
        if self.bar is not None:
            self.bar.update(1)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


# ----------------------------------------------------------------------------- errors


def angle_degrees(normal: np.ndarray, reference_normal: np.ndarray) -> np.ndarray:
    """Angle between each normal and the reference (atan2: accurate near 0); 180 for zero."""
    cosine = np.sum(normal * reference_normal, axis=1)
    if normal.shape[1] == 2:
        sine = np.abs(normal[:, 0] * reference_normal[:, 1] - normal[:, 1] * reference_normal[:, 0])
    else:
        sine = np.linalg.norm(np.cross(normal, reference_normal), axis=1)
    zero = np.linalg.norm(normal, axis=1) == 0
    return np.where(zero, 180.0, np.degrees(np.arctan2(sine, cosine)))


def error_stats(method: Method, ref: Reference, depth, normal, found, says_overlap=None) -> dict:
    """Errors of one method's decoded output on the reference pairs.

    Depth and normal errors are over the pairs that overlap (oracle depth > 1e-6) and that the
    method reports (contact-level methods report only pairs in contact; a missed pair counts as
    a wrong overlap decision instead); normals only where the oracle normal is unique.
    """
    overlap, separated = ref.overlapping, ref.separated
    if says_overlap is None:
        says_overlap = found & (depth > 0)
    measured = overlap & found
    stats = {
        "pairs": int(len(depth)),
        "overlapping": int(overlap.sum()),
        "wrong_overlap": int(np.sum((overlap & ~says_overlap) | (separated & says_overlap))),
        "missed": int(np.sum(overlap & ~found)),
    }
    depth_error = np.abs(depth - ref.depth)[measured]
    angles = angle_degrees(normal, ref.normal)[measured & ref.normal_is_unique]
    if len(depth_error):
        stats.update(depth_error_max=float(depth_error.max()),
                     depth_error_median=float(np.median(depth_error)),
                     worst_depth_pair=int(np.flatnonzero(measured)[np.argmax(depth_error)]))
    if len(angles):
        stats.update(normal_error_max_deg=float(angles.max()),
                     normal_error_median_deg=float(np.median(angles)),
                     normals_over_1deg=float(np.mean(angles > 1.0)), normals_compared=len(angles))
    if method.level == DISTANCE and separated.any():
        distance_error = np.abs(-depth - ref.distance)[separated]
        stats.update(distance_error_max=float(distance_error.max()),
                     distance_error_median=float(np.median(distance_error)))
    return stats


def gradient_stats(method: Method, data, indices, expected) -> dict:
    if method.gradient is None or len(indices) == 0:
        return {}
    gradient = method.gradient(data, indices)
    error = np.linalg.norm(gradient - expected, axis=1)
    finite = np.isfinite(error)
    return {"grad_pairs": int(len(indices)), "grad_error_max": float(np.max(error[finite]))
            if finite.any() else math.inf, "grad_error_median": float(np.median(error[finite]))
            if finite.any() else math.inf, "grad_nonfinite": int(np.sum(~finite))}


# ----------------------------------------------------------------------------- timing


def time_calls(run, repeats: int, budget_s: float):
    """(wall times of up to `repeats` calls after a warm-up, last output)."""
    out = run()
    times: list[float] = []
    while len(times) < repeats:
        start = time.perf_counter()
        out = run()
        times.append(time.perf_counter() - start)
        if sum(times) > budget_s:
            break
    return times, out


def measure(method: Method, data, ref: Reference, grads, args, progress: Progress) -> dict:
    """One row: pairs/s per size, setup time, errors and gradient errors."""
    started = time.perf_counter()
    row = measure_row(method, data, ref, grads, args, progress)
    row["wall_s"] = round(time.perf_counter() - started, 1)
    return row


def measure_row(method: Method, data, ref: Reference, grads, args, progress: Progress) -> dict:
    row = {"case": data.case, "method": method.name, "level": method.level,
           "precision": method.precision, "gradients": "jax.grad" if method.gradient else "no",
           "note": method.note, "setup": method.setup, "sizes": {}}
    missing = method.missing()
    if missing:
        row["skipped"] = f"not installed: {', '.join(missing)} (pip install {method.install})"
        return row
    seconds_per_pair, previous, decoded = None, None, None
    error_count = len(ref.depth)
    for n in args.sizes:
        k = min(n, args.loop_pairs) if method.loop else n
        progress.describe(f"{data.case} {method.name} n={n:,}")
        if previous is not None and previous["timed_pairs"] == k:
            row["sizes"][n] = dict(previous)
            continue
        if seconds_per_pair is not None and seconds_per_pair * k > args.max_call_seconds:
            row["sizes"][n] = {"skipped": f"~{seconds_per_pair * k:.0f} s per call "
                                          f"> --max-call-seconds {args.max_call_seconds:g}"}
            continue
        try:
            prepared = method.prepare(data, k)
            available = available_memory_bytes()
            if (prepared.memory_bytes and available
                    and prepared.memory_bytes > args.memory_fraction * available):
                row["sizes"][n] = {"skipped": f"needs {prepared.memory_bytes / 2**30:.1f} GiB"}
                break
            times, out = time_calls(prepared.run, args.repeats, args.budget_seconds)
            if decoded is None and k >= error_count:
                decoded = [x[:error_count] for x in prepared.decode(out)]
            del out
        except Exception as error:  # noqa: BLE001 - a failing peer is reported, not fatal
            row["sizes"][n] = {"failed": f"{type(error).__name__}: {error}"[:300]}
            break
        best = min(times)
        seconds_per_pair = best / k
        previous = {"timed_pairs": k, "pairs_per_second": k / best, "best_s": best,
                    "median_s": statistics.median(times), "calls": len(times),
                    "setup_s": prepared.setup_s, "memory_bytes": prepared.memory_bytes}
        row["sizes"][n] = previous
        row.setdefault("setup_s", prepared.setup_s)
    try:
        if decoded is None:
            progress.describe(f"{data.case} {method.name} errors")
            prepared = method.prepare(data, error_count)
            decoded = prepared.decode(prepared.run())
            row.setdefault("setup_s", prepared.setup_s)
        row["errors"] = error_stats(method, ref, *decoded)
        progress.describe(f"{data.case} {method.name} gradients")
        row["errors"].update(gradient_stats(method, data, *grads))
    except Exception as error:  # noqa: BLE001
        row["errors_failed"] = f"{type(error).__name__}: {error}"[:300]
    return row


# ----------------------------------------------------------------------------- output


def _g(value, digits: int = 2) -> str:
    if value is None:
        return "-"
    if value == 0:
        return "0"
    return f"{value:.{digits}g}" if abs(value) >= 1e-3 and abs(value) < 1e5 else \
        f"{value:.{digits - 1}e}"


def size_cell(cell: dict | None) -> str:
    if not cell:
        return "-"
    if "skipped" in cell:
        return "skipped"
    if "failed" in cell:
        return "failed"
    return f"{cell['pairs_per_second']:.2g}"


def row_notes(row: dict) -> str:
    notes = []
    if "skipped" in row:
        return row["skipped"]
    timed = {cell.get("timed_pairs") for n, cell in row["sizes"].items()
             if cell.get("timed_pairs") not in (None, n)}
    if timed:
        notes.append(f"loop timed on first {min(timed):,} pairs")
    for n, cell in row["sizes"].items():
        for key in ("skipped", "failed"):
            if key in cell:
                notes.append(f"{n:,}: {key} ({cell[key]})")
    errors = row.get("errors", {})
    if errors.get("missed"):
        notes.append(f"{errors['missed']} overlapping pairs without contact")
    if "errors_failed" in row:
        notes.append(f"errors failed: {row['errors_failed']}")
    return "; ".join(notes)


def markdown(rows: list[dict], info: dict, args) -> str:
    sizes = args.sizes
    head = ["case", "method", "level", "dtype", *[f"pairs/s {n:.0e}".replace("+0", "")
                                                  for n in sizes],
            "setup s", "depth err max / median", "normal err max (deg)", "normals > 1 deg",
            "wrong overlap", "distance err max (apart)", "grad", "grad err max / median",
            "notes"]
    lines = [
        f"jaxsat peers benchmark, {info['date_utc']}, git {info['git_commit']}",
        "",
        f"Machine: {info['cpu_model']}, {info['cpu_count']} CPUs, {info['platform']}; load "
        f"average (1, 5, 15 min) {info['load_average_start']} at start, "
        f"{info.get('load_average_end')} at end. Versions: "
        + ", ".join(f"{k} {v}" for k, v in info["versions"].items() if v) + ".",
        "",
        f"Errors on the first {args.error_pairs} pairs of each case against the float64 "
        "oracle (depth and normal on overlapping pairs the method reports; normal as the "
        "angle to the oracle's); gradients: d depth / d translation of b against central "
        f"finite differences of the oracle on up to {args.grad_pairs} overlapping pairs "
        "(error = norm of the difference). Setup: JAX compile, MuJoCo model build, or object "
        "building.",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    for row in rows:
        errors = row.get("errors", {})
        cells = [row["case"], row["method"], row["level"], row["precision"],
                 *[size_cell(row["sizes"].get(n)) for n in sizes],
                 _g(row.get("setup_s")),
                 f"{_g(errors.get('depth_error_max'))} / {_g(errors.get('depth_error_median'))}"
                 if "depth_error_max" in errors else "-",
                 _g(errors.get("normal_error_max_deg")),
                 f"{errors['normals_over_1deg']:.1%}" if "normals_over_1deg" in errors else "-",
                 f"{errors['wrong_overlap']} / {errors['pairs']}" if errors else "-",
                 _g(errors.get("distance_error_max")), row["gradients"],
                 f"{_g(errors.get('grad_error_max'))} / {_g(errors.get('grad_error_median'))}"
                 if "grad_error_max" in errors else "-",
                 row_notes(row)]
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    return "\n".join(lines) + "\n"


def rate_for_plot(row: dict) -> float | None:
    """pairs/s at the largest size measured."""
    rates = [cell["pairs_per_second"] for _, cell in sorted(row["sizes"].items())
             if "pairs_per_second" in cell]
    return rates[-1] if rates else None


def plot(rows: list[dict], path: pathlib.Path, info: dict) -> bool:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    markers = dict(zip(METHODS, "o^sv<>DPXph*d8H", strict=False))
    colours = dict(zip(CASES, ("tab:blue", "tab:orange", "tab:green", "tab:red"), strict=True))
    figure, axes = plt.subplots(1, 2, figsize=(13, 5.5))
    panels = (("depth_error_max", DEPTH_FLOOR, "largest depth error"),
              ("normal_error_max_deg", ANGLE_FLOOR, "largest normal error (degrees)"))
    for axis, (key, floor, label) in zip(axes, panels, strict=True):
        for row in rows:
            rate, errors = rate_for_plot(row), row.get("errors", {})
            if rate is None or key not in errors:
                continue
            axis.scatter(rate, max(errors[key], floor), marker=markers.get(row["method"], "o"),
                         color=colours.get(row["case"], "k"), s=60,
                         edgecolors="k" if row["level"] == CONTACTS else "none")
        axis.set_xscale("log")
        axis.set_yscale("log")
        axis.set_xlabel("pairs/s (largest size measured)")
        axis.set_ylabel(f"{label} (0 drawn at {floor:g})")
        axis.grid(True, which="major", alpha=0.3)
    handles = [plt.Line2D([], [], marker=m, linestyle="", color="grey", label=name)
               for name, m in markers.items() if any(r["method"] == name for r in rows)]
    handles += [plt.Line2D([], [], marker="s", linestyle="", color=c, label=case)
                for case, c in colours.items() if any(r["case"] == case for r in rows)]
    axes[1].legend(handles=handles, fontsize=8, loc="best")
    figure.suptitle(f"jaxsat and peers: error against pairs/s ({info['cpu_model']}, "
                    f"{info['cpu_count']} CPUs, load {info['load_average_start']}); "
                    "black edge: contact-level rows", fontsize=9)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return True


# ----------------------------------------------------------------------------- main


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog="Cases: " + "; ".join(f"{k}: {v}" for k, v in CASES.items()))
    parser.add_argument("--quick", action="store_true",
                        help=f"smaller run: sizes {QUICK['sizes']}, {QUICK['error_pairs']} error "
                             f"pairs, {QUICK['grad_pairs']} gradient pairs, loops on "
                             f"{QUICK['loop_pairs']} pairs, {QUICK['repeats']} repeats, calls "
                             f"of at most {QUICK['max_call_seconds']:g} s")
    parser.add_argument("--cases", nargs="+", choices=list(CASES), default=list(CASES))
    parser.add_argument("--methods", nargs="+", choices=list(METHODS), default=list(METHODS))
    parser.add_argument("--sizes", type=int, nargs="+",
                        help=f"pairs per timed call (default {FULL['sizes']})")
    parser.add_argument("--error-pairs", type=int,
                        help=f"pairs compared with the oracle (default {FULL['error_pairs']})")
    parser.add_argument("--grad-pairs", type=int,
                        help=f"overlapping pairs for gradients (default {FULL['grad_pairs']})")
    parser.add_argument("--loop-pairs", type=int,
                        help=f"most pairs a Python loop is timed on (default "
                             f"{FULL['loop_pairs']})")
    parser.add_argument("--repeats", type=int,
                        help=f"timed calls after a warm-up, best reported (default "
                             f"{FULL['repeats']})")
    parser.add_argument("--budget-seconds", type=float, default=20.0,
                        help="stop repeating once the timed calls add up to this "
                             "(default: %(default)s)")
    parser.add_argument("--max-call-seconds", type=float,
                        help="skip a size whose call is estimated from the previous size to "
                             f"take longer (default {FULL['max_call_seconds']:g}, quick "
                             f"{QUICK['max_call_seconds']:g})")
    parser.add_argument("--memory-fraction", type=float, default=0.3,
                        help="skip a size whose compiled kernel needs more than this fraction "
                             "of the available memory (default: %(default)s)")
    parser.add_argument("--pool", type=int, default=256,
                        help="random shapes per case (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    parser.add_argument("--output", metavar="PREFIX",
                        help="write PREFIX.md, PREFIX.json, PREFIX.png (default: "
                             "benchmarks/results/peers[-quick]-<UTC time>)")
    parser.add_argument("--no-plot", action="store_true", help="do not draw the PNG")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--list", action="store_true",
                        help="list the methods, their cases and whether they are installed")
    args = parser.parse_args(argv)
    for key, value in (QUICK if args.quick else FULL).items():
        if getattr(args, key) is None:
            setattr(args, key, value)
    args.sizes = sorted(set(args.sizes))
    if min(args.sizes) < 1 or min(args.error_pairs, args.loop_pairs, args.repeats) < 1:
        parser.error("sizes, --error-pairs, --loop-pairs and --repeats must be positive")
    return args


def list_methods() -> str:
    lines = [f"{'method':<17} {'level':<23} {'dtype':<8} {'cases':<45} status"]
    for method in METHODS.values():
        missing = method.missing()
        status = (f"missing {', '.join(missing)} (pip install {method.install})" if missing
                  else "installed")
        lines.append(f"{method.name:<17} {method.level:<23} {method.precision:<8} "
                     f"{' '.join(method.cases):<45} {status}")
    return "\n".join(lines)


def default_prefix(quick: bool) -> pathlib.Path:
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    return RESULTS_DIR / f"peers{'-quick' if quick else ''}-{stamp}"


def main(argv=None) -> int:
    args = parse_args(argv)
    if args.list:
        print(list_methods())
        return 0
    info = machine_info(DISTRIBUTIONS)
    tasks = [(case, METHODS[name]) for case in args.cases for name in args.methods
             if case in METHODS[name].cases]
    progress = Progress(len(tasks) + len(args.cases), enabled=not args.no_progress)
    progress.echo(f"jaxsat peers benchmark: {info['cpu_model']}, {info['cpu_count']} CPUs, "
                  f"load {info['load_average_start']}, sizes {args.sizes}, "
                  f"{args.error_pairs} error pairs")
    rows: list[dict] = []
    started = time.perf_counter()
    for case in args.cases:
        progress.describe(f"{case}: data and oracle")
        data = make_case(case, max(max(args.sizes), args.error_pairs), args.pool, args.seed)
        ref = reference(data, args.error_pairs)
        grads = gradient_pairs(data, ref, args.grad_pairs)
        progress.step()
        for method_case, method in tasks:
            if method_case != case:
                continue
            row = measure(method, data, ref, grads, args, progress)
            rows.append(row)
            progress.echo(f"{case:<12} {method.name:<17} "
                          + "  ".join(f"{n:.0e}: {size_cell(row['sizes'].get(n))}"
                                      for n in args.sizes)
                          + f"  depth err {_g(row.get('errors', {}).get('depth_error_max'))}"
                          + (f"  [{row_notes(row)}]" if row_notes(row) else ""))
            progress.step()
    progress.close()
    info["load_average_end"] = load_average()
    info["run_seconds"] = round(time.perf_counter() - started, 1)

    prefix = pathlib.Path(args.output) if args.output else default_prefix(args.quick)
    prefix.parent.mkdir(parents=True, exist_ok=True)

    def suffixed(suffix: str) -> pathlib.Path:
        return prefix.parent / (prefix.name + suffix)

    table = markdown(rows, info, args)
    config = {k: v for k, v in vars(args).items() if k not in ("output", "list")}
    suffixed(".md").write_text(table)
    suffixed(".json").write_text(json.dumps(
        {"machine": info, "config": config, "results": rows}, indent=1, default=str) + "\n")
    written = [suffixed(".md"), suffixed(".json")]
    if not args.no_plot and plot(rows, suffixed(".png"), info):
        written.append(suffixed(".png"))
    print()
    print(table)
    print(f"run took {info['run_seconds']} s; wrote " + ", ".join(str(p) for p in written))
    return 0


if __name__ == "__main__":
    sys.exit(main())
