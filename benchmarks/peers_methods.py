"""The methods `peers.py` compares: jaxsat and its peers, each behind one small interface.

A `Method` says what it computes (level), where it applies (cases), what it needs (modules) and
how to build a `Prepared` run on the first n pairs of a `CaseData`: `run()` is what is timed,
`decode(out)` turns its output into (depth, normal, found) NumPy arrays for the error columns.
Peers are imported only inside `prepare` (and `available`), so this module imports with NumPy
alone; a missing peer becomes a note in the table.

Conventions of the decoded output: depth > 0 means overlap (the penetration depth), normal is a
world unit vector from a towards b (moving b by depth * normal separates them), found[i] says
whether the method reports anything for pair i (contact-level methods report only pairs in
contact; depth-level methods report every pair).
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.util
import sys
import time
from collections.abc import Callable

import numpy as np
from peers_data import CaseData, numpy_sat_2d, padded_polygons

DEPTH = "depth+normal"
CONTACTS = "contacts"
DISTANCE = "signed distance+normal"


@dataclasses.dataclass
class Prepared:
    run: Callable[[], object]
    """The timed call: computes the result for the prepared pairs (blocks until done)."""
    decode: Callable[[object], tuple[np.ndarray, ...]]
    """Output of `run` -> (depth (n,), normal (n, D), found (n,) bool[, overlap (n,) bool]),
    float64; overlap, the method's own overlap decision, defaults to found & (depth > 0)."""
    setup_s: float
    """Compile time (JAX) or build time of the objects / model the run needs."""
    memory_bytes: int | None = None
    """Memory the compiled executable needs (JAX), when known."""


@dataclasses.dataclass(frozen=True)
class Method:
    name: str
    cases: tuple[str, ...]
    level: str
    precision: str
    modules: tuple[str, ...]
    """Importable modules this method needs."""
    install: str
    """What to pip install when a module is missing."""
    prepare: Callable[[CaseData, int], Prepared]
    gradient: Callable[[CaseData, np.ndarray], np.ndarray] | None = None
    """(data, pair indices) -> (k, D) d depth / d translation of b, or None (no gradients)."""
    loop: bool = False
    """A Python loop over pairs: timed on at most --loop-pairs pairs."""
    setup: str = "compile"
    """What the setup time measures."""
    note: str = ""

    def missing(self) -> list[str]:
        return [name for name in self.modules if not _importable(name)]


def _importable(module: str) -> bool:
    if module in sys.modules:  # None there means "not importable" (as `import` treats it)
        return sys.modules[module] is not None
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


def _timed(build):
    start = time.perf_counter()
    value = build()
    return value, time.perf_counter() - start


def _unit(vectors: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(vectors, axis=-1, keepdims=True)
    return vectors / np.where(norm > 0, norm, 1)


# ----------------------------------------------------------------------------- JAX helpers


def _compile(function, arguments):
    """(compiled executable, seconds, bytes needed or None): ahead-of-time jit compile."""
    import jax

    start = time.perf_counter()
    compiled = jax.jit(function).lower(*arguments).compile()
    seconds = time.perf_counter() - start
    try:
        stats = compiled.memory_analysis()
        needed = (stats.argument_size_in_bytes + stats.output_size_in_bytes
                  + stats.temp_size_in_bytes)
    except Exception:  # noqa: BLE001 - optional per backend
        needed = None
    return compiled, seconds, needed


def _jax_prepared(function, arguments, decode) -> Prepared:
    import jax

    arguments = jax.device_put(arguments)
    compiled, seconds, needed = _compile(function, arguments)
    return Prepared(run=lambda: jax.block_until_ready(compiled(*arguments)), decode=decode,
                    setup_s=seconds, memory_bytes=needed)


# ----------------------------------------------------------------------------- jaxsat


_JAXSAT_POOLS: dict[tuple, object] = {}


def _jaxsat_pool(data: CaseData):
    """The pool as stacked float32 jaxsat shapes (cached per data set)."""
    import jaxsat

    key = (id(data), data.case)
    if key not in _JAXSAT_POOLS:
        f32 = np.float32
        if data.dim == 2:
            shapes = [jaxsat.polygon(p, max_vertices=data.max_vertices, dtype=f32)
                      for p in data.points]
        elif data.half_extents is not None:
            shapes = [jaxsat.box(h, dtype=f32) for h in data.half_extents]
        else:
            shapes = [jaxsat.polyhedron(p, max_vertices=20, dtype=f32) for p in data.points]
        _JAXSAT_POOLS.clear()
        _JAXSAT_POOLS[key] = jaxsat.stack(shapes)
    return _JAXSAT_POOLS[key]


def _jaxsat_inputs(data: CaseData, indices: np.ndarray):
    import jax

    import jaxsat

    pool = _jaxsat_pool(data)
    take = lambda pick: jax.tree.map(lambda leaf: np.asarray(leaf)[pick], pool)  # noqa: E731
    pose = lambda r, t: jaxsat.Pose(np.asarray(t[indices], np.float32),  # noqa: E731
                                    np.asarray(r[indices], np.float32))
    return (take(data.pick_a[indices]), pose(data.rotation_a, data.translation_a),
            take(data.pick_b[indices]), pose(data.rotation_b, data.translation_b))


def _decode_penetration(out):
    return (np.asarray(out.depth, np.float64), np.asarray(out.normal, np.float64),
            np.ones(out.depth.shape, bool))


def jaxsat_prepare(data: CaseData, n: int) -> Prepared:
    import jax

    import jaxsat

    return _jax_prepared(jax.vmap(jaxsat.penetration), _jaxsat_inputs(data, np.arange(n)),
                         _decode_penetration)


# Chunk sizes for `query_batch`, measured with benchmarks/roofline.py on the 2-core CPU: the
# largest chunk whose intermediates stay in cache (boxes 3.2 kB per pair, hulls 65 kB).
CHUNK_SIZES = {"2d-small": 8192, "2d-polygons": 8192, "3d-boxes": 8192, "3d-hulls": 256}


def jaxsat_chunked_prepare(data: CaseData, n: int) -> Prepared:
    import jaxsat

    chunk = CHUNK_SIZES[data.case]
    return _jax_prepared(
        lambda *pairs: jaxsat.query_batch(jaxsat.penetration, *pairs, chunk_size=chunk),
        _jaxsat_inputs(data, np.arange(n)), _decode_penetration)


def jaxsat_gradient(data: CaseData, indices: np.ndarray) -> np.ndarray:
    import jax

    import jaxsat

    def depth(translation_b, a, pose_a, b, rotation_b):
        return jaxsat.penetration(a, pose_a, b, jaxsat.Pose(translation_b, rotation_b)).depth

    a, pose_a, b, pose_b = _jaxsat_inputs(data, indices)
    grad = jax.jit(jax.vmap(jax.grad(depth)))
    return np.asarray(grad(pose_b.translation, a, pose_a, b, pose_b.rotation), np.float64)


def jaxsat_contacts_prepare(data: CaseData, n: int) -> Prepared:
    """`contacts` (margin 0): the manifold; its deepest valid point gives the depth."""
    import jax

    import jaxsat

    def decode(out):
        valid = np.asarray(out.valid)
        depths = np.where(valid, np.asarray(out.depths, np.float64), -np.inf)
        found = valid.any(axis=1)
        return (np.where(found, depths.max(axis=1), 0.0), np.asarray(out.normal, np.float64),
                found)

    return _jax_prepared(jax.vmap(jaxsat.contacts), _jaxsat_inputs(data, np.arange(n)), decode)


def jaxsat_distance_gradient(data: CaseData, indices: np.ndarray) -> np.ndarray:
    import jax

    import jaxsat

    def depth(translation_b, a, pose_a, b, rotation_b):
        pose_b = jaxsat.Pose(translation_b, rotation_b)
        return -jaxsat.signed_distance(a, pose_a, b, pose_b)

    a, pose_a, b, pose_b = _jaxsat_inputs(data, indices)
    grad = jax.jit(jax.vmap(jax.grad(depth)))
    return np.asarray(grad(pose_b.translation, a, pose_a, b, pose_b.rotation), np.float64)


def jaxsat_distance_prepare(data: CaseData, n: int) -> Prepared:
    """`closest_points`: exact signed distance and axis (like coal.distance, mj_geomDistance)."""
    import jax

    import jaxsat

    def decode(out):
        depth = -np.asarray(out.signed_distance, np.float64)
        return depth, np.asarray(out.normal, np.float64), np.ones(depth.shape, bool)

    return _jax_prepared(jax.vmap(jaxsat.closest_points), _jaxsat_inputs(data, np.arange(n)),
                         decode)


# ----------------------------------------------------------------------------- NumPy SAT


def numpy_sat_prepare(dtype) -> Callable[[CaseData, int], Prepared]:
    def prepare(data: CaseData, n: int) -> Prepared:
        def build():
            return (padded_polygons(data, data.pick_a[:n], dtype),
                    data.rotation_a[:n].astype(dtype), data.translation_a[:n].astype(dtype),
                    padded_polygons(data, data.pick_b[:n], dtype),
                    data.rotation_b[:n].astype(dtype), data.translation_b[:n].astype(dtype))

        arguments, seconds = _timed(build)

        def decode(out):
            depth, normal = out
            return depth.astype(np.float64), normal.astype(np.float64), np.ones(len(depth), bool)

        return Prepared(run=lambda: numpy_sat_2d(*arguments), decode=decode, setup_s=seconds)

    return prepare


# ----------------------------------------------------------------------------- jax2d


def _jax2d_bodies(data: CaseData, indices: np.ndarray):
    """(a, b) jax2d RigidBody batches: clockwise vertices padded with zeros to 4."""
    from jax2d.sim_state import RigidBody

    table = np.zeros((len(data.points), 4, 2), np.float32)
    counts = np.array([len(p) for p in data.points], np.int32)
    for i, points in enumerate(data.points):
        table[i, : len(points)] = points[::-1]  # jax2d wants clockwise

    def bodies(pick, angle, translation):
        n = len(indices)
        zeros, ones = np.zeros(n, np.float32), np.ones(n, np.float32)
        return RigidBody(
            position=translation[indices].astype(np.float32), rotation=angle[indices].astype(
                np.float32), velocity=np.zeros((n, 2), np.float32), angular_velocity=zeros,
            inverse_mass=ones, inverse_inertia=ones, friction=ones, restitution=zeros,
            collision_mode=np.ones(n, np.int32), active=np.ones(n, bool),
            n_vertices=counts[pick[indices]], vertices=table[pick[indices]], radius=zeros)

    return (bodies(data.pick_a, data.angle_a, data.translation_a),
            bodies(data.pick_b, data.angle_b, data.translation_b))


def _jax2d_empty_manifolds():
    from jax2d.sim_state import CollisionManifold

    return CollisionManifold(normal=np.zeros((2, 2), np.float32), penetration=np.zeros(
        2, np.float32), collision_point=np.zeros((2, 2), np.float32), active=np.zeros(2, bool),
        acc_impulse_normal=np.zeros(2, np.float32), acc_impulse_tangent=np.zeros(2, np.float32),
        restitution_velocity_target=np.zeros(2, np.float32))


def jax2d_prepare(data: CaseData, n: int) -> Prepared:
    import jax
    from jax2d.collision import generate_manifolds_polygon_polygon

    # As jax2d's engine does: vmap the pair function over polygon pairs.
    batched = jax.vmap(generate_manifolds_polygon_polygon, in_axes=(0, 0, None))
    a, b = _jax2d_bodies(data, np.arange(n))

    def decode(out):
        found = np.asarray(out.active[:, 0])
        return (np.asarray(out.penetration[:, 0], np.float64),
                np.asarray(out.normal[:, 0], np.float64), found)

    return _jax_prepared(batched, (a, b, _jax2d_empty_manifolds()), decode)


def jax2d_gradient(data: CaseData, indices: np.ndarray) -> np.ndarray:
    import jax
    from jax2d.collision import generate_manifolds_polygon_polygon

    def depth(position_b, a, b, manifolds):
        return generate_manifolds_polygon_polygon(
            a, b.replace(position=position_b), manifolds).penetration[0]

    a, b = _jax2d_bodies(data, indices)
    grad = jax.jit(jax.vmap(jax.grad(depth), in_axes=(0, 0, 0, None)))
    return np.asarray(grad(b.position, a, b, _jax2d_empty_manifolds()), np.float64)


# ----------------------------------------------------------------------------- pymunk


def pymunk_prepare(data: CaseData, n: int) -> Prepared:
    import pymunk

    def shape(pick, angle, translation, i):
        body = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
        body.position = tuple(translation[i])
        body.angle = float(angle[i])
        poly = pymunk.Poly(body, [tuple(p) for p in data.points[pick[i]]])
        poly.cache_bb()  # shapes_collide reads the cached world vertices
        return poly

    def build():
        return [(shape(data.pick_a, data.angle_a, data.translation_a, i),
                 shape(data.pick_b, data.angle_b, data.translation_b, i)) for i in range(n)]

    pairs, seconds = _timed(build)

    def collide(a, b):
        try:
            return a.shapes_collide(b)
        except AssertionError:  # pymunk 7.3 asserts on a contact set with no point (apart)
            return None

    def run():
        return [collide(a, b) for a, b in pairs]

    def decode(out):
        depth, normal, found = np.zeros(n), np.zeros((n, 2)), np.zeros(n, bool)
        for i, points in enumerate(out):
            if points is not None and points.points:
                found[i] = True
                depth[i] = -min(p.distance for p in points.points)
                normal[i] = tuple(points.normal)
        return depth, normal, found

    return Prepared(run=run, decode=decode, setup_s=seconds)


PYMUNK_SPACING = 8.0
"""Grid spacing of the pairs in the pymunk Space (shapes are < 2 across, centres within 3)."""


def pymunk_space_prepare(data: CaseData, n: int) -> Prepared:
    """All pairs in one pymunk Space, each pair in its own cell of a grid so that only its two
    shapes meet; timed: `Space.step` (broad phase, narrow phase, contact solver; no gravity,
    1 solver iteration, a step of 1e-9 s so nothing moves). a is static, b dynamic."""
    import pymunk

    columns = int(np.ceil(np.sqrt(n)))
    cells = PYMUNK_SPACING * np.stack([np.arange(n) % columns, np.arange(n) // columns], 1)

    def build():
        space = pymunk.Space()
        space.iterations = 1
        shapes_b = {}
        for i in range(n):
            a_body = pymunk.Body(body_type=pymunk.Body.STATIC)
            b_body = pymunk.Body(1.0, 1.0)
            for body, side in ((a_body, "a"), (b_body, "b")):
                body.position = tuple(getattr(data, f"translation_{side}")[i] + cells[i])
                body.angle = float(getattr(data, f"angle_{side}")[i])
                points = data.points[getattr(data, f"pick_{side}")[i]]
                shape = pymunk.Poly(body, [tuple(p) for p in points])
                space.add(body, shape)
                if side == "b":
                    shapes_b[shape] = i
        return space, shapes_b

    (space, shapes_b), seconds = _timed(build)

    def run():
        space.step(1e-9)

    def decode(_):
        depth, normal, found = np.zeros(n), np.zeros((n, 2)), np.zeros(n, bool)
        for shape, i in shapes_b.items():
            def read(arbiter, i=i, shape=shape):
                points = arbiter.contact_point_set
                if points.points:
                    found[i] = True
                    depth[i] = -min(p.distance for p in points.points)
                    sign = -1.0 if arbiter.shapes[0] is shape else 1.0  # normal: a to b
                    normal[i] = sign * np.array(tuple(points.normal))
            shape.body.each_arbiter(read)
        return depth, normal, found

    return Prepared(run=run, decode=decode, setup_s=seconds)


# ----------------------------------------------------------------------------- collision


def collision_prepare(data: CaseData, n: int) -> Prepared:
    import collision

    def poly(pick, angle, translation, i):
        points = [collision.Vector(*p) for p in data.points[pick[i]]]
        return collision.Poly(collision.Vector(*translation[i]), points, float(angle[i]))

    def build():
        return [(poly(data.pick_a, data.angle_a, data.translation_a, i),
                 poly(data.pick_b, data.angle_b, data.translation_b, i)) for i in range(n)]

    pairs, seconds = _timed(build)

    def run():
        out = []
        for a, b in pairs:
            response = collision.Response()
            hit = collision.collide(a, b, response)
            out.append((hit, response.overlap, response.overlap_n.x, response.overlap_n.y))
        return out

    def decode(out):
        hit = np.array([o[0] for o in out], bool)
        depth = np.array([o[1] if o[0] else 0.0 for o in out], np.float64)
        normal = np.array([o[2:] for o in out], np.float64).reshape(-1, 2)
        return depth, normal, np.ones(n, bool), hit  # the overlap decision is `hit`

    return Prepared(run=run, decode=decode, setup_s=seconds)


# ----------------------------------------------------------------------------- MuJoCo models


_MUJOCO_POOLS: dict[tuple, object] = {}


def _mujoco_pool(data: CaseData):
    """A compiled MjModel with one mesh per pool hull (None for boxes), cached.

    MuJoCo re-centres a mesh on its centre of mass and principal axes; the geom's pos/quat in a
    body at the origin give the offset, so the original shape at world pose (R, t) is the geom
    at (R quat, R pos + t): what the world rotation and translation of each geom are set to.
    """
    import mujoco

    key = (id(data), data.case)
    if key in _MUJOCO_POOLS:
        return _MUJOCO_POOLS[key]
    _MUJOCO_POOLS.clear()
    if data.half_extents is not None:
        _MUJOCO_POOLS[key] = None
        return None
    spec = mujoco.MjSpec()
    for k, points in enumerate(data.points):
        mesh = spec.add_mesh()
        mesh.name = f"hull{k}"
        mesh.uservert = points.flatten().tolist()
        geom = spec.worldbody.add_body(mocap=True).add_geom()
        geom.type = mujoco.mjtGeom.mjGEOM_MESH
        geom.meshname = f"hull{k}"
    _MUJOCO_POOLS[key] = spec.compile()
    return _MUJOCO_POOLS[key]


def _geom_frames(data: CaseData, pool, side: str, indices: np.ndarray):
    """World (positions (n, 3), rotation matrices (n, 3, 3)) of the geoms of one side."""
    pick = getattr(data, f"pick_{side}")[indices]
    rotation = getattr(data, f"rotation_{side}")[indices]
    translation = getattr(data, f"translation_{side}")[indices]
    if pool is None:
        return translation, rotation
    import mujoco

    offsets = np.zeros((pool.ngeom, 9))
    for g in range(pool.ngeom):
        mujoco.mju_quat2Mat(offsets[g], pool.geom_quat[g])
    offset_rotation = offsets.reshape(-1, 3, 3)[pick]
    position = np.einsum("nij,nj->ni", rotation, pool.geom_pos[pick]) + translation
    return position, rotation @ offset_rotation


MUJOCO_CHUNK = 10_000
"""Pairs per MuJoCo model: compiling explicit pairs costs time quadratic in their number
(0.6 s for 8,000 pairs, minutes for 100,000), so larger runs use several models."""


def _mujoco_pairs_model(data: CaseData, start: int, stop: int):
    """(model, data) holding the explicit geom pairs (i, k + i) for the k = stop - start pairs
    from `start`: all a geoms in one mocap body, all b geoms in another (one body per geom
    would make mj_collision allocate a bodies x bodies matrix), dynamic (contype) collisions
    off, world poses written to geom_xpos / geom_xmat."""
    import mujoco

    pool = _mujoco_pool(data)
    spec = mujoco.MjSpec()
    if pool is not None:
        for k, points in enumerate(data.points):
            mesh = spec.add_mesh()
            mesh.name = f"hull{k}"
            mesh.uservert = points.flatten().tolist()
    count = stop - start
    spec.memory = 2**22 + count * 8 * 1024  # room for up to 8 contacts per pair
    for side in "ab":
        body = spec.worldbody.add_body(mocap=True)
        for i in range(start, stop):
            geom = body.add_geom()
            geom.name = f"{side}{i}"
            geom.contype = geom.conaffinity = 0
            k = int(getattr(data, f"pick_{side}")[i])
            if pool is None:
                geom.type = mujoco.mjtGeom.mjGEOM_BOX
                geom.size = data.half_extents[k]
            else:
                geom.type = mujoco.mjtGeom.mjGEOM_MESH
                geom.meshname = f"hull{k}"
    for i in range(start, stop):
        pair = spec.add_pair()
        pair.geomname1, pair.geomname2 = f"a{i}", f"b{i}"
    model = spec.compile()
    assert model.geom(count).name == f"b{start}"  # a geoms first, then b geoms
    state = mujoco.MjData(model)
    indices = np.arange(start, stop)
    for side, first in (("a", 0), ("b", count)):
        position, rotation = _geom_frames(data, pool, side, indices)
        state.geom_xpos[first:first + count] = position
        state.geom_xmat[first:first + count] = rotation.reshape(count, 9)
    return model, state


def _mujoco_models(data: CaseData, n: int):
    return [(start, *_mujoco_pairs_model(data, start, min(n, start + MUJOCO_CHUNK)))
            for start in range(0, n, MUJOCO_CHUNK)]


def mujoco_collision_prepare(data: CaseData, n: int) -> Prepared:
    import mujoco

    models, seconds = _timed(lambda: _mujoco_models(data, n))

    def run():
        for _, model, state in models:
            mujoco.mj_collision(model, state)
        return [state.ncon for _, _, state in models]

    def decode(counts):
        depth, normal, found = np.full(n, -np.inf), np.zeros((n, 3)), np.zeros(n, bool)
        for (start, _, state), count in zip(models, counts, strict=True):
            contact = state.contact
            geom1, geom2 = np.asarray(contact.geom1[:count]), np.asarray(contact.geom2[:count])
            dist, frame = np.asarray(contact.dist[:count]), np.asarray(contact.frame[:count])
            flip = np.where(geom1 > geom2, -1.0, 1.0)  # frame normal points from geom1 to geom2
            for c, pair in enumerate(start + np.minimum(geom1, geom2)):
                found[pair] = True
                if -dist[c] > depth[pair]:
                    depth[pair], normal[pair] = -dist[c], flip[c] * frame[c, :3]
        return np.where(found, depth, 0.0), normal, found

    return Prepared(run=run, decode=decode, setup_s=seconds)


def mujoco_distance_prepare(data: CaseData, n: int) -> Prepared:
    import mujoco

    models, seconds = _timed(lambda: _mujoco_models(data, n))
    fromto = np.zeros(6)

    def run():
        out = np.empty((n, 7))
        for start, model, state in models:
            count = model.ngeom // 2
            for i in range(count):
                out[start + i, 0] = mujoco.mj_geomDistance(model, state, i, count + i, 10.0,
                                                           fromto)
                out[start + i, 1:] = fromto
        return out

    def decode(out):
        distance = out[:, 0]
        # fromto goes from geom1's point to geom2's: from a to b when apart, from b into a
        # when they overlap.
        normal = _unit(out[:, 4:7] - out[:, 1:4]) * np.where(distance < 0, -1.0, 1.0)[:, None]
        return -distance, normal, np.ones(n, bool)

    return Prepared(run=run, decode=decode, setup_s=seconds)


# ----------------------------------------------------------------------------- MJX


_MJX_MESHES: dict[tuple, tuple] = {}


def _mjx_meshes(data: CaseData, pool) -> tuple[np.ndarray, ...]:
    """Stacked ConvexMesh fields (vert, face, face_normal, edge, edge_face_normal) of the pool
    hulls from MJX's own mesh processing, padded to common sizes by repeating entries."""
    key = (id(data), data.case)
    if key in _MJX_MESHES:
        return _MJX_MESHES[key]
    from mujoco.mjx._src import mesh

    meshes = [mesh.convex(pool, k) for k in range(pool.nmesh)]
    stacked = []
    for field in ("vert", "face", "face_normal", "edge", "edge_face_normal"):
        arrays = [np.asarray(getattr(m, field)) for m in meshes]
        if field == "face":  # pad every face to the most vertices, as the driver does
            width = max(a.shape[1] for a in arrays)
            arrays = [np.pad(a, ((0, 0), (0, width - a.shape[1]), (0, 0)), "edge")
                      for a in arrays]
        rows = max(a.shape[0] for a in arrays)
        arrays = [np.concatenate([a, np.repeat(a[:1], rows - len(a), 0)]) for a in arrays]
        array = np.stack(arrays)
        stacked.append(array.astype(np.float32) if array.dtype.kind == "f" else array)
    _MJX_MESHES.clear()
    _MJX_MESHES[key] = tuple(stacked)
    return _MJX_MESHES[key]


def _mjx_arguments(data: CaseData, indices: np.ndarray) -> tuple:
    """((pos, mat, size) of a, the same of b[, mesh fields of a, of b]) per pair, float32."""
    boxes = data.half_extents is not None
    pool = None if boxes else _mujoco_pool(data)
    geoms, meshes = [], []
    for side in "ab":
        position, rotation = _geom_frames(data, pool, side, indices)
        pick = getattr(data, f"pick_{side}")[indices]
        size = data.half_extents[pick] if boxes else np.zeros_like(position)
        geoms.append(tuple(np.asarray(x, np.float32) for x in (position, rotation, size)))
        if not boxes:
            meshes.append(tuple(field[pick] for field in _mjx_meshes(data, pool)))
    return (*geoms, *meshes)


def _mjx_batched(boxes: bool):
    """MJX's collider for box_box or convex_convex without the Model/Data plumbing: build the
    ConvexInfo of each side (mesh.box for boxes) and vmap the pair function over pairs.
    Returns distances (n, 4), points (n, 4, 3) and contact frames (n, 4, 3, 3)."""
    import jax
    from mujoco.mjx._src import collision_convex, math, mesh
    from mujoco.mjx._src.collision_types import ConvexInfo, GeomInfo

    def framed(collide):
        def pair(info_a, info_b):
            dist, pos, normal = collide(info_a, info_b)
            return dist, pos, jax.vmap(math.make_frame)(normal)
        return pair

    def batched(geom_a, geom_b, mesh_a=(), mesh_b=()):
        if boxes:
            infos = [mesh.box(GeomInfo(*geom)) for geom in (geom_a, geom_b)]
            axes = jax.tree.map(lambda x: None, infos[0]).replace(
                pos=0, mat=0, size=0, face=0, vert=0)
            return jax.vmap(framed(collision_convex._box_box), in_axes=(axes, axes))(*infos)
        infos = [ConvexInfo(*geom_a, *mesh_a), ConvexInfo(*geom_b, *mesh_b)]
        return jax.vmap(framed(collision_convex._convex_convex))(*infos)

    return batched


def _decode_mjx(out):
    dist, _, frame = (np.asarray(x, np.float64) for x in out)
    best = np.argmin(dist, axis=1)
    rows = np.arange(len(best))
    depth = -dist[rows, best]
    return depth, frame[rows, best, 0], depth > 0


def mjx_prepare(data: CaseData, n: int) -> Prepared:
    batched = _mjx_batched(data.half_extents is not None)
    return _jax_prepared(batched, _mjx_arguments(data, np.arange(n)), _decode_mjx)


def mjx_gradient(data: CaseData, indices: np.ndarray) -> np.ndarray:
    import jax
    import jax.numpy as jnp

    batched = _mjx_batched(data.half_extents is not None)
    geom_a, geom_b, *meshes = _mjx_arguments(data, indices)

    def total_depth(position_b, geom_a, rest_b, meshes):
        # pairs are independent: the gradient of the sum is the gradient of each pair
        dist, _, _ = batched(geom_a, (position_b, *rest_b), *meshes)
        return -jnp.sum(jnp.min(dist, axis=1))

    gradient = jax.jit(jax.grad(total_depth))(geom_b[0], geom_a, geom_b[1:], tuple(meshes))
    return np.asarray(gradient, np.float64)


# ----------------------------------------------------------------------------- Coal


def _coal_geometry(data: CaseData, k: int):
    import coal

    if data.half_extents is not None:
        return coal.Box(*(2 * data.half_extents[k]))
    points = coal.StdVec_Vec3s()
    for point in data.points[k]:
        points.append(np.asarray(point, np.float64))
    return coal.Convex.convexHull(points, False, "")


def coal_prepare(data: CaseData, n: int) -> Prepared:
    import coal

    def build():
        shapes = [_coal_geometry(data, k) for k in range(len(data.points))]
        frames = [(shapes[data.pick_a[i]], coal.Transform3s(data.rotation_a[i],
                                                             data.translation_a[i]),
                   shapes[data.pick_b[i]], coal.Transform3s(data.rotation_b[i],
                                                             data.translation_b[i]))
                  for i in range(n)]
        return shapes, frames

    (_, frames), seconds = _timed(build)
    request = coal.DistanceRequest()
    request.enable_signed_distance = True

    def run():
        out = np.empty((n, 4))
        result = coal.DistanceResult()
        for i, (shape_a, frame_a, shape_b, frame_b) in enumerate(frames):
            result.clear()
            out[i, 0] = coal.distance(shape_a, frame_a, shape_b, frame_b, request, result)
            out[i, 1:] = result.normal
        return out

    def decode(out):
        return -out[:, 0], _unit(out[:, 1:]), np.ones(n, bool)

    return Prepared(run=run, decode=decode, setup_s=seconds)


# ----------------------------------------------------------------------------- registry


TWO_D = ("2d-small", "2d-polygons")
THREE_D = ("3d-boxes", "3d-hulls")
ALL = TWO_D + THREE_D

METHODS: dict[str, Method] = {m.name: m for m in (
    Method("jaxsat", ALL, DEPTH, "float32", ("jaxsat",), "jaxsat", jaxsat_prepare,
           gradient=jaxsat_gradient, note="jax.jit(jax.vmap(jaxsat.penetration))"),
    Method("jaxsat-chunked", ALL, DEPTH, "float32", ("jaxsat",), "jaxsat",
           jaxsat_chunked_prepare, note="jaxsat.query_batch(penetration, chunk_size=C), C per "
           "case in CHUNK_SIZES (8192; hulls 256)"),
    Method("jaxsat-distance", ALL, DISTANCE, "float32", ("jaxsat",), "jaxsat",
           jaxsat_distance_prepare, gradient=jaxsat_distance_gradient,
           note="jax.jit(jax.vmap(jaxsat.closest_points)): exact distance when apart"),
    Method("jaxsat-contacts", ALL, CONTACTS, "float32", ("jaxsat",), "jaxsat",
           jaxsat_contacts_prepare, note="jax.jit(jax.vmap(jaxsat.contacts)), margin 0"),
    Method("numpy-sat-f32", TWO_D, DEPTH, "float32", (), "numpy", numpy_sat_prepare(np.float32),
           setup="array building", note="vectorised NumPy SAT over edge normals (this script)"),
    Method("numpy-sat-f64", TWO_D, DEPTH, "float64", (), "numpy", numpy_sat_prepare(np.float64),
           setup="array building", note="vectorised NumPy SAT over edge normals (this script)"),
    Method("jax2d", ("2d-small",), CONTACTS, "float32", ("jax2d",), "jax2d", jax2d_prepare,
           gradient=jax2d_gradient,
           note="jit(vmap(generate_manifolds_polygon_polygon)); 4 vertices at most"),
    Method("pymunk", TWO_D, CONTACTS, "float64", ("pymunk",), "pymunk", pymunk_prepare,
           loop=True, setup="shape building", note="Shape.shapes_collide in a Python loop"),
    Method("pymunk-space", TWO_D, CONTACTS, "float64", ("pymunk",), "pymunk",
           pymunk_space_prepare, setup="space building",
           note="Space.step with every pair in one Space (broad phase + narrow phase + solver)"),
    Method("collision", TWO_D, DEPTH, "float64", ("collision",), "collision",
           collision_prepare, loop=True, setup="shape building",
           note="collision.collide (SAT.js port) in a Python loop"),
    Method("mjx", THREE_D, CONTACTS, "float32", ("mujoco.mjx",), "mujoco-mjx", mjx_prepare,
           gradient=mjx_gradient,
           note="jit(vmap(_box_box / _convex_convex + make_frame)), as MJX's collider"),
    Method("mujoco-collision", THREE_D, CONTACTS, "float64", ("mujoco",), "mujoco",
           mujoco_collision_prepare, setup="model build",
           note="mj_collision on a model of n explicit pairs"),
    Method("mujoco-distance", THREE_D, DISTANCE, "float64", ("mujoco",), "mujoco",
           mujoco_distance_prepare, loop=True, setup="model build",
           note="mj_geomDistance in a Python loop"),
    Method("coal", THREE_D, DISTANCE, "float64", ("coal",), "coal", coal_prepare, loop=True,
           setup="shape building", note="coal.distance (GJK/EPA) in a Python loop"),
)}
