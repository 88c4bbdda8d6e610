"""What the benchmarks share: named data sets, the float64 oracle, one timing loop, compile
statistics, the machine record, command-line options and the record writer.

Scripts import it with `sys.path.insert(0, <this folder>)`, then `import core`.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import importlib.metadata
import itertools
import json
import math
import os
import pathlib
import platform
import statistics
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxsat

HERE = pathlib.Path(__file__).resolve().parent
STARTED = time.perf_counter()
sys.path.insert(0, str(HERE.parent / "tests"))
import oracle  # noqa: E402  (tests/oracle.py: NumPy/SciPy only, shares no code with jaxsat)


def ellipse(rng, count: int, symmetric: bool = False) -> np.ndarray:
    """`count` vertices on a random ellipse, counter-clockwise (strictly convex); symmetric:
    centrally symmetric, count/2 pairs of parallel edges."""
    half, span = (count // 2, np.pi) if symmetric else (int(count), 2 * np.pi)
    gaps = rng.uniform(0.5, 1.5, half)
    angles = rng.uniform(0, 2 * np.pi) + span * (np.cumsum(gaps) - gaps[0]) / gaps.sum()
    axes = rng.uniform(0.3, 0.8, 2)
    ring = np.stack([axes[0] * np.cos(angles), axes[1] * np.sin(angles)], axis=1)
    return np.concatenate([ring, -ring]) if symmetric else ring

@dataclasses.dataclass(frozen=True)
class Geom:
    """One pool shape: `kind` ("hull": of `points`, "box", "sphere", "capsule"), local `points`
    of its core (a sphere's centre, a capsule's segment along z) and `size` as MuJoCo's geoms
    take it (box: half extents; sphere: radius, 0, 0; capsule: radius, half length, 0)."""
    kind: str
    points: np.ndarray
    size: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    radius = property(lambda self: self.size[0] if self.kind in ("sphere", "capsule") else 0.0)
    def build(self, max_vertices, dtype, unique_axes=True):
        """The jaxsat shape (`max_vertices`: padding of hulls)."""
        sharp = {"dtype": dtype, "unique_axes": unique_axes}
        return {"sphere": lambda: jaxsat.sphere(self.size[0], dtype=dtype),
                "capsule": lambda: jaxsat.capsule(self.size[1], self.size[0], dtype=dtype),
                "box": lambda: jaxsat.box(self.size, **sharp)}.get(self.kind, lambda: (
                    jaxsat.polygon if self.points.shape[1] == 2 else jaxsat.polyhedron)(
                    self.points, max_vertices, **sharp))()

def box(half) -> Geom:
    corners = itertools.product((-1.0, 1.0), repeat=len(half))
    return Geom("box", np.array(list(corners)) * f32(half), f32(half))

def sphere(rng) -> Geom:
    return Geom("sphere", np.zeros((1, 3)), f32([rng.uniform(0.15, 0.6), 0, 0]))

def capsule(rng) -> Geom:
    size = f32([*rng.uniform([0.15, 0.1], 0.6), 0])  # radius, half length
    return Geom("capsule", np.outer([-1.0, 1.0], [0.0, 0.0, size[1]]), size)

def hull_points(rng, count: int = 20) -> np.ndarray:
    """`count` points on a random ellipsoid (semi-axes 0.3-0.8): every one a hull vertex."""
    directions = rng.normal(size=(count, 3))
    return directions / np.linalg.norm(directions, axis=1, keepdims=True) * rng.uniform(0.3, 0.8, 3)

SETS = {
    "2d-small": ("convex 3-4-gons (jax2d's limit), padded to 4",
                 lambda rng: ellipse(rng, rng.integers(3, 5))),
    "2d-polygons": ("convex 4-8-gons, padded to 8", lambda rng: ellipse(rng, rng.integers(4, 9))),
    "2d-octagons": ("convex 8-gons", lambda rng: ellipse(rng, 8)),
    "2d-symmetric8": ("centrally symmetric 8-gons", lambda rng: ellipse(rng, 8, True)),
    "2d-rectangles": ("rectangles, half extents 0.15-0.6",
                      lambda rng: box(rng.uniform(0.15, 0.6, 2))),
    "3d-boxes": ("boxes, half extents 0.15-0.6", lambda rng: box(rng.uniform(0.15, 0.6, 3))),
    "3d-hulls": ("hulls of 20 points on ellipsoids, padded to 20", hull_points),
    "3d-spheres": ("spheres, radius 0.15-0.6", sphere),
    "3d-capsules": ("capsules along z, radius 0.15-0.6, half length 0.1-0.6", capsule),
    "3d-sphere-box": ("a: spheres as above, b: boxes as above", sphere,
                      lambda rng: box(rng.uniform(0.15, 0.6, 3)))}
"""Name: (description, random pool shape: a Geom or local vertices[, b's, from its own pool])."""
CHUNKS = {"2d-small": 8192, "2d-polygons": 8192, "3d-boxes": 8192, "3d-hulls": 256}
"""`query_batch` chunks that stay in cache (a box pair needs 3.2 kB, a hull pair 65 kB)."""
QUERIES = {"penetration": jaxsat.penetration, "intersects": jaxsat.intersects}
"""The levels a kernel or scene can be timed at (--query, --level)."""
MAX_VERTICES = {"2d-small": 4, "2d-symmetric8": None, "3d-hulls": 20}
"""Padding of polygons and hulls (8 where not listed; None: as many as unique)."""

def f32(values) -> np.ndarray:
    """Round to float32, keep as float64: float32 methods and the oracle see the same input."""
    return np.asarray(values, np.float64).astype(np.float32).astype(np.float64)

def rotations(params: np.ndarray, dim: int) -> np.ndarray:
    """(..., D, D) float64 rotations from pose parameters (x, y, angle) or (t, w x y z)."""
    if dim == 2:
        c, s = np.cos(params[..., 2]), np.sin(params[..., 2])
        return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
    q = params[..., 3:] / np.linalg.norm(params[..., 3:], axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)

def pose(params) -> jaxsat.Pose:
    """The pose of parameters (x, y, angle) or (translation, quaternion w x y z) (JAX)."""
    return (jaxsat.pose2(params[0], params[1], params[2]) if params.shape[-1] == 3 else
            jaxsat.pose3(params[:3], params[3:]))

@dataclasses.dataclass
class DataSet:
    """`geoms`: every pool shape; `pick` (2, N): pool index of a and b (a from geoms[:split], b
    from geoms[split:] if split > 0); `params` (2, N, P): pose parameters, x y angle (2D) or
    translation and quaternion w x y z (3D). Every number is a float32 value held in float64."""
    name: str
    geoms: list
    pick: np.ndarray
    params: np.ndarray
    split: int = 0
    def __post_init__(self):
        self.points, self.pools = [g.points for g in self.geoms], {}
        self.dim = dim = self.points[0].shape[1]
        self.translation, self.rotation = self.params[..., :dim], rotations(self.params, dim)
        self.angle = self.params[..., 2] if dim == 2 else None
        self.kinds = tuple(self.geoms[self.pick[s, 0]].kind for s in (0, 1))  # one per side
        self.sides = (slice(0, self.split or None), slice(self.split, None))
    def pool(self, side=0, dtype=np.float32, unique_axes=True):
        """The pool shapes of a side, stacked (built once per pool, dtype and unique_axes)."""
        key = (self.sides[side].start, np.dtype(dtype).name, unique_axes)
        if key not in self.pools:
            self.pools[key] = jax.tree.map(np.asarray, jaxsat.stack([
                g.build(MAX_VERTICES.get(self.name, 8), dtype, unique_axes)
                for g in self.geoms[self.sides[side]]]))
        return self.pools[key]
    def shapes(self, index=slice(None), dtype=np.float32, unique_axes=True):
        """(a, b): the shapes of pairs `index`, batched on the device."""
        return tuple(jax.tree.map(lambda x, p=self.pick[s] - self.sides[s].start: jnp.asarray(
            x)[p[index]], self.pool(s, dtype, unique_axes)) for s in (0, 1))
    def inputs(self, index=slice(None), dtype=np.float32, unique_axes=True):
        """(a, pose_a, b, pose_b) of pairs `index` on the device."""
        a, b = self.shapes(index, dtype, unique_axes)
        pose = [jaxsat.Pose(jnp.asarray(self.translation[s][index], dtype),
                            jnp.asarray(self.rotation[s][index], dtype)) for s in (0, 1)]
        return a, pose[0], b, pose[1]
    def evaluate(self, i: int, params=None, tie_tolerance: float = 0.0) -> oracle.Oracle:
        """Oracle values of pair i (at pose parameters `params`, (2P,), if given): the Minkowski
        difference of the world vertices, or `rounded_oracle` for spheres and capsules."""
        params = self.params[:, i] if params is None else np.reshape(params, (2, -1))
        geoms, rotation = [self.geoms[k] for k in self.pick[:, i]], rotations(params, self.dim)
        world = [oracle.to_world(g.points, r, t) for g, r, t in zip(
            geoms, rotation, params[:, :self.dim], strict=True)]
        if geoms[0].radius == geoms[1].radius == 0:
            return oracle.evaluate(*world, tie_tolerance=tie_tolerance)
        return rounded_oracle(geoms, world, rotation, params[:, :self.dim], tie_tolerance)
    def signed(self, i: int, params=None) -> float:
        """Oracle signed distance of pair i: the distance apart, minus the depth overlapping."""
        found = self.evaluate(i, params)
        return found.distance if found.depth < 0 else -found.depth

def rounded_oracle(geoms, world, rotation, translation, tie_tolerance) -> oracle.Oracle:
    """Closed forms for a pair with a sphere or capsule: the cores' signed distance minus the
    radii (depth: minus that, also apart); the normal (a to b) along the cores' closest points
    (a sphere's core is its centre), for a sphere and a box from the centre clamped to the box
    to the centre, or for a centre inside out of the nearest face (unique unless faces tie)."""
    kinds = [g.kind for g in geoms]
    if "box" in kinds:  # the sphere's centre in the box's frame, how far outside, face gaps
        s, half = kinds.index("box"), geoms[kinds.index("box")].size
        local = rotation[s].T @ (world[1 - s][0] - translation[s])
        outside, gaps = local - np.clip(local, -half, half), half - np.abs(local)
        k, inside = np.argmin(gaps), not np.any(outside)
        core = -gaps[k] if inside else np.linalg.norm(outside)
        normal = rotation[s] @ (np.eye(3)[k] * np.copysign(1.0, local[k]) if inside else
                                outside) * (1 - 2 * s)  # box to sphere, flipped for a box b
        unique = not inside or np.sum(gaps <= gaps[k] + tie_tolerance) == 1
    else:
        x, y = oracle.segment_closest_points(world[0][0], world[0][-1], world[1][0], world[1][-1])
        core, normal, unique = np.linalg.norm(y - x), y - x, np.linalg.norm(y - x) > 1e-9
    signed = core - geoms[0].radius - geoms[1].radius
    return oracle.Oracle(-signed, normal / np.linalg.norm(normal), bool(unique), max(signed, 0.0),
                         np.nan)

def make_data(name: str, pairs: int, pool: int = 256, seed: int = 0, spread=(0.0, 1.8)):
    """Data set `name`: `pool` random shapes (per side if b has its own) and `pairs` random
    pairs of them, b's origin `spread` from a's (about half collide by default); reproducible."""
    rng = np.random.default_rng([seed, list(SETS).index(name)])
    makers = SETS[name][1:]
    geoms = [made if isinstance(made := make(rng), Geom) else Geom("hull", f32(made))
             for make in makers for _ in range(pool)]
    dim, split = geoms[0].points.shape[1], pool * (len(makers) - 1)
    pick = rng.integers(0, pool, (2, pairs)) + np.array([[0], [split]])
    centres, directions = rng.uniform(-1.0, 1.0, (pairs, dim)), rng.normal(size=(pairs, dim))
    ends = centres + directions / np.linalg.norm(directions, axis=1, keepdims=True) * rng.uniform(
        *spread, (pairs, 1))
    turns = rng.uniform(-np.pi, np.pi, (2, pairs, 1)) if dim == 2 else rng.normal(
        size=(2, pairs, 4))
    params = np.concatenate([np.stack([centres, ends]), turns], axis=-1)
    return DataSet(name, geoms, pick, f32(params), split)

OVERLAP_TOLERANCE = 1e-6
"""Pairs with |oracle depth| below this are touching: out of the overlap statistics."""
FD_STEPS = (1e-4, 1e-5)
"""Central-difference steps in the pose parameters; the smaller one is the reference."""

@dataclasses.dataclass
class Reference:
    """The oracle on the first pairs of a data set: depth (when < 0: minus the largest
    Minkowski facet gap, or for rounded shapes the distance), normal, normal_is_unique, distance."""
    depth: np.ndarray
    normal: np.ndarray
    normal_is_unique: np.ndarray
    distance: np.ndarray
    overlapping = property(lambda self: self.depth > OVERLAP_TOLERANCE)
    separated = property(lambda self: self.depth < -OVERLAP_TOLERANCE)
    signed = property(lambda self: np.where(self.depth < 0, self.distance, -self.depth))

def reference(data: DataSet, count: int) -> Reference:
    found = [data.evaluate(i, tie_tolerance=1e-9) for i in range(count)]
    return Reference(*(np.array([getattr(r, key) for r in found]) for key in
                       ("depth", "normal", "normal_is_unique", "distance")))

def oracle_gradients(data: DataSet, pairs, columns, agreement: float, count=None):
    """Central differences of the oracle signed distance in the pose parameters `columns` (a's
    then b's) at `pairs` where both steps agree within `agreement` (else a kink within a step),
    until `count` are kept: (the pairs kept, their gradients at the smaller step)."""
    kept, gradients = [], []
    for i in map(int, pairs):
        if len(kept) == count:
            break
        base = data.params[:, i].reshape(-1)
        coarse, fine = ([(data.signed(i, base + s) - data.signed(i, base - s)) / (2 * step)
                         for s in np.eye(len(base))[list(columns)] * step] for step in FD_STEPS)
        if np.linalg.norm(np.subtract(coarse, fine)) <= agreement:
            kept.append(i)
            gradients.append(fine)
    return np.array(kept, int), np.reshape(gradients, (len(kept), len(columns)))

@dataclasses.dataclass
class Timing:
    times: list
    output: object = None  # of the warm-up call
    best = property(lambda self: min(self.times))
    median = property(lambda self: statistics.median(self.times))

def time_calls(calls: dict, repeats: int, budget_s: float = math.inf, min_rounds: int = 1,
               burst: int = 1, burst_s: float = math.inf, block: bool = True) -> dict:
    """Time zero-argument `calls` (name -> function) interleaved, so that load on a shared
    machine hits them alike: a warm-up call each, then up to `repeats` rounds giving each a
    turn of up to `burst` calls (ended once the turn took `burst_s`); no new round once all
    timed calls took `budget_s` (after `min_rounds`). Returns name -> Timing."""
    finish = jax.block_until_ready if block else (lambda out: out)
    timings = {name: Timing([], finish(call())) for name, call in calls.items()}
    for round_ in range(repeats):
        if round_ >= min_rounds and sum(sum(t.times) for t in timings.values()) > budget_s:
            break
        for name, call in calls.items():
            for k in range(burst):
                start = time.perf_counter()
                finish(call())
                timings[name].times.append(time.perf_counter() - start)
                if sum(timings[name].times[-k - 1:]) > burst_s:
                    break
    return timings

@dataclasses.dataclass
class Compiled:
    """An executable compiled ahead of time: compile seconds, memory (arguments + outputs +
    temporaries) and XLA's cost analysis (None where the backend has none)."""
    call: object
    seconds: float
    memory_bytes: int | None = None
    temp_bytes: int | None = None
    flops: float | None = None
    bytes_accessed: float | None = None

def timed(function):
    """(function(), the seconds it took)."""
    start = time.perf_counter()
    return function(), time.perf_counter() - start

def page_faults(call, calls: int = 3) -> float | None:
    """Minor page faults per call: memory the call touches for the first time. glibc maps
    allocations over 32 MB afresh and unmaps them on free, so a program with temporaries that
    large faults them in, zeroed, on every call (4 KiB a fault; 2 MiB with huge pages)."""
    try:
        import resource
    except ImportError:  # not on Windows
        return None
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(calls):
        jax.block_until_ready(call())
    return (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / calls

def compile_aot(function, *arguments) -> Compiled:
    """`jax.jit(function)` compiled for these (real or abstract) arguments."""
    compiled = Compiled(*timed(lambda: jax.jit(function).lower(*arguments).compile()))
    try:
        stats, cost = compiled.call.memory_analysis(), compiled.call.cost_analysis()
        cost = cost[0] if isinstance(cost, list) else cost
        compiled.temp_bytes, compiled.memory_bytes = stats.temp_size_in_bytes, (
            stats.argument_size_in_bytes + stats.output_size_in_bytes + stats.temp_size_in_bytes)
        compiled.flops, compiled.bytes_accessed = cost.get("flops"), cost.get("bytes accessed")
    except Exception:  # noqa: BLE001 - optional per backend
        pass
    return compiled

def abstract(tree, n: int):
    """ShapeDtypeStruct stand-ins for `tree` with a leading axis of length n."""
    return jax.tree.map(lambda x: jax.ShapeDtypeStruct((n, *np.shape(x)[1:]), x.dtype), tree)

def read_proc(path: str, prefix: str) -> str | None:
    try:
        with open(path) as lines:
            return next((x.split(":", 1)[1].strip() for x in lines if x.startswith(prefix)), None)
    except OSError:
        return None

def load_average() -> list | None:
    return [round(x, 2) for x in os.getloadavg()] if hasattr(os, "getloadavg") else None

def available_memory_bytes() -> int | None:
    found = read_proc("/proc/meminfo", "MemAvailable")
    return int(found.split()[0]) * 1024 if found else None

def _git(*command) -> str | None:
    try:
        return subprocess.run(("git", "-C", str(HERE), *command), capture_output=True, text=True,
                              timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None

def machine_info(distributions=("jax", "jaxlib", "jaxsat", "numpy", "scipy")) -> dict:
    """Date, platform, CPU, load, memory, versions, git commit (+dirty if changed), devices."""
    commit, dirty = _git("rev-parse", "--short", "HEAD"), _git("status", "--porcelain")
    return {"date_utc": datetime.datetime.now(datetime.timezone.utc).isoformat("T", "seconds"),
            "platform": platform.platform(), "python": platform.python_version(),
            "cpu_model": read_proc("/proc/cpuinfo", "model name") or platform.processor(),
            "cpu_count": os.cpu_count(), "load_average_start": load_average(),
            "memory_available_bytes": available_memory_bytes(),
            "versions": {name: next((d.version for d in importlib.metadata.distributions(
                name=name)), None) for name in distributions},
            "git_commit": commit and commit + "+dirty" * bool(dirty),
            "allocator": " ".join(f"{k}={v}" for k, v in sorted(os.environ.items()) if k in (
                "GLIBC_TUNABLES", "LD_PRELOAD") or k.startswith("MALLOC_")) or "default",
            "backend": jax.default_backend(), "devices": [str(d) for d in jax.devices()]}

LIMITS = {"--budget-seconds": "stop repeating once the timed calls add up to this",
          "--max-call-seconds": "skip a call estimated to take longer",
          "--memory-fraction": "skip a call needing more of the available memory"}

def parse(argv, doc: str, defaults: dict, cases=None, sizes="pairs per timed call",
          timing: bool = True, limits=(), options: dict | None = None) -> argparse.Namespace:
    """Parse the options the scripts share (--repeats and --pool with `timing`, `limits` of
    LIMITS), then `options` (flag: add_argument's keywords, or the help of an integer option);
    fill each left unset from `defaults`, name: (full, quick) (--pool: 256, --cases: all)."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0], epilog="Usage:" + (
        doc.split("Usage")[-1].split(":", 1)[-1]), formatter_class=argparse.RawTextHelpFormatter)
    parser.add_argument("--quick", action="store_true",
                        help="a smoke run on small sizes; writes files only with --output")
    if cases:
        parser.add_argument("--cases", nargs="+", choices=cases, help=f"of {' '.join(cases)}")
    if sizes:
        parser.add_argument("--sizes", type=int, nargs="+", help=sizes)
    if timing:
        parser.add_argument("--repeats", type=int, help="timed calls or rounds after a warm-up")
        parser.add_argument("--pool", type=int, help="random shapes per data set (default 256)")
    for option in limits:
        parser.add_argument(option, type=float, help=LIMITS[option])
    parser.add_argument("--seed", type=int, default=0, help="random seed")
    parser.add_argument("--output", type=pathlib.Path, metavar="PREFIX", help="write PREFIX.json"
                        " and .md (default: benchmarks/results/<script>-cpu-2core, not --quick)")
    parser.add_argument("--no-save", action="store_true", help="print only")
    for flag, spec in (options or {}).items():
        parser.add_argument(flag, **{"type": int, "help": spec} if isinstance(spec, str) else spec)
    args = parser.parse_args(argv)
    for name, (full, quick) in {"pool": (256, 256), "cases": (cases, cases), **defaults}.items():
        if hasattr(args, name) and getattr(args, name) is None:
            setattr(args, name, quick if args.quick else full)
    counts = [*(getattr(args, "sizes", None) or []), getattr(args, "repeats", 1),
              getattr(args, "pool", 1)]
    if min(counts) < 1:
        parser.error("sizes, --repeats and --pool must be positive")
    return args

def save(args, name: str, title: str, info: dict, payload: dict, table: str):
    """Print the table; unless --no-save, write PREFIX.json (machine, config, `payload`), .md."""
    info["load_average_end"], info["run_seconds"] = load_average(), time.perf_counter() - STARTED
    versions = ", ".join(f"{k} {v}" for k, v in info["versions"].items() if v)
    text = ("{title}, {date_utc}, git {git_commit}\n\nMachine: {cpu_model}, {cpu_count} CPUs, "
            "{platform}, {backend}, allocator {allocator}; load average {load_average_start} at "
            "start, {load_average_end} at end; {run_seconds:.0f} s. Versions: {installed}."
            "\n\n").format(title=title, installed=versions, **info) + table
    print("\n" + text)
    prefix = args.output or (None if args.quick else HERE / "results" / f"{name}-cpu-2core")
    if prefix is None or args.no_save:
        return
    prefix.parent.mkdir(parents=True, exist_ok=True)
    prefix.with_name(prefix.name + ".json").write_text(json.dumps(
        {"machine": info, "config": vars(args), **payload}, indent=1,
        default=lambda x: getattr(x, "item", x.__str__)()))
    prefix.with_name(prefix.name + ".md").write_text(text)
    print(f"wrote {prefix}.json, .md", file=sys.stderr)

def too_big(args, memory_bytes=None, seconds: float = 0.0) -> str | None:
    """Why a call is skipped: it needs more than --memory-fraction of the available memory or
    is estimated to take over --max-call-seconds (None: neither)."""
    free = available_memory_bytes()
    if memory_bytes and free and memory_bytes > args.memory_fraction * free:
        return f"needs {memory_bytes / 2**30:.1f} GiB"
    if seconds > args.max_call_seconds:
        return f"~{seconds:.0f} s per call > --max-call-seconds {args.max_call_seconds:g}"

def stats(name: str, errors, unit: str = "") -> dict:
    """name_max and name_median of `errors` (nothing for none)."""
    return {f"{name}_max{unit}": float(np.max(errors)),
            f"{name}_median{unit}": float(np.median(errors))} if len(errors) else {}

def markdown_table(head: list, rows: list) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    return "\n".join(lines + ["| " + " | ".join(map(str, row)) + " |" for row in rows]) + "\n"

def num(value, digits: int = 2) -> str:
    """A table cell: "-" for None, integers as they are, else `digits` significant digits."""
    if value is None or isinstance(value, (int, np.integer)) or value == 0:
        return "-" if value is None else str(value)
    return f"{value:.{digits}g}" if 1e-3 <= abs(value) < 1e5 else f"{value:.{digits - 1}e}"
