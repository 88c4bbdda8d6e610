"""jaxsat next to its peers (a NumPy SAT, jax2d, pymunk, collision, MJX, MuJoCo, Coal): speed,
setup time, errors against tests/oracle.py and gradient errors of every method on the same
pairs, in one run; a missing package is skipped. See benchmarks/README.md.

Usage (from the repository root, with `pip install -e ".[bench]"`):
    python benchmarks/peers.py --quick        # a few minutes; `python -m jaxsat bench`
    python benchmarks/peers.py                # 1e3-1e5 pairs; results/peers-cpu-2core.*
    python benchmarks/peers.py --cases 3d-boxes --methods jaxsat mjx mujoco-collision
    python benchmarks/peers.py --list         # methods and whether they are installed
"""

from __future__ import annotations

import dataclasses
import functools
import importlib.util
import math
import pathlib
import sys
from collections.abc import Callable
from types import SimpleNamespace

import jax
import numpy as np

import jaxsat

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import core  # noqa: E402

CASES = ["2d-small", "2d-polygons", "3d-boxes", "3d-hulls", "3d-spheres", "3d-capsules",
         "3d-sphere-box"]
DEFAULTS = {"sizes": ([1_000, 10_000, 100_000], [1_000, 10_000]), "error_pairs": (2000, 500),
            "grad_pairs": (200, 20), "loop_pairs": (20_000, 1000), "budget_seconds": (20, 20),
            "repeats": (5, 2), "max_call_seconds": (60.0, 10.0), "memory_fraction": (0.3, 0.3)}
DISTRIBUTIONS = ("jax", "jaxlib", "jaxsat", "numpy", "scipy", "mujoco", "mujoco-mjx", "jax2d",
                 "pymunk", "collision", "coal")
DEPTH, CONTACTS, DISTANCE = "depth+normal", "contacts", "signed distance+normal"
FD_AGREEMENT = 1e-6
"""Pairs whose two finite-difference gradients differ by more are kinks: skipped."""

@dataclasses.dataclass
class Prepared:
    """run(): the timed call; decode(its output) -> (depth, normal, found[, overlap]) float64:
    depth > 0 overlaps, normal from a to b, found: reported, overlap: the method's decision
    (default found & depth > 0); setup_s: compile or build time."""
    run: Callable[[], object]
    decode: Callable[[object], tuple]
    setup_s: float
    memory_bytes: int | None = None

@dataclasses.dataclass(frozen=True)
class Method:
    """prepare(data, n) -> Prepared; gradient(data, indices) -> d depth / d translation of b;
    module: what it imports (pip install `install` or `module`); loop: a Python loop."""
    name: str
    cases: tuple
    level: str
    precision: str
    module: str | None
    prepare: Callable[[core.DataSet, int], Prepared]
    gradient: Callable | None = None
    loop: bool = False
    install: str | None = None
    pip = property(lambda self: f"{self.module} (pip install {self.install or self.module})")
    def missing(self) -> bool:
        """Whether `module` cannot be imported (None in sys.modules: not, as for `import`)."""
        if self.module in sys.modules:
            return sys.modules[self.module] is None
        try:
            return self.module is not None and importlib.util.find_spec(self.module) is None
        except (ImportError, ValueError):
            return True

def _unit(vector):
    norm = np.linalg.norm(vector)
    return np.asarray(vector, np.float64) / (norm if norm > 0 else 1)

def _memo(data: core.DataSet, key: str, build):
    memo = data.__dict__.setdefault("memo", {})
    return memo[key] if key in memo else memo.setdefault(key, build())

def _jax(function, arguments, decode) -> Prepared:
    arguments = jax.device_put(arguments)
    compiled = core.compile_aot(function, *arguments)
    return Prepared(lambda: jax.block_until_ready(compiled.call(*arguments)), decode,
                    compiled.seconds, compiled.memory_bytes)

def _loop(build, query, decode_one) -> Prepared:
    """A Python loop: build() -> one object per pair (the setup), query(object) -> raw result
    (timed), decode_one(raw) -> (depth, normal, found, overlap)."""
    objects, seconds = core.timed(build)
    return Prepared(lambda: [query(o) for o in objects], lambda out: tuple(
        map(np.array, zip(*map(decode_one, out), strict=True))), seconds)

def _penetration(out, sign=1):
    depth = sign * np.asarray(out.depth if sign > 0 else out.signed_distance, np.float64)
    return depth, np.asarray(out.normal, np.float64), np.ones(depth.shape, bool)

def _jaxsat(query, decode=_penetration, chunked=False):
    def prepare(data, n):
        function = functools.partial(jaxsat.query_batch, query,
                                     chunk_size=core.CHUNKS.get(data.name, 8192))
        return _jax(function if chunked else jax.vmap(query), data.inputs(slice(0, n)), decode)
    return prepare

def _jaxsat_gradient(depth):
    def gradient(data, indices):
        a, pose_a, b, pose_b = data.inputs(indices)
        grad = jax.jit(jax.vmap(jax.grad(lambda t, a, pa, b, r: depth(a, pa, b,
                                                                     jaxsat.Pose(t, r)))))
        return np.asarray(grad(pose_b.translation, a, pose_a, b, pose_b.rotation), np.float64)
    return gradient

def _contacts(out):
    valid = np.asarray(out.valid)
    found, depths = valid.any(axis=1), np.where(valid, np.asarray(out.depths, np.float64), -np.inf)
    return np.where(found, depths.max(axis=1), 0.0), np.asarray(out.normal, np.float64), found

def numpy_sat_2d(local_a, rotation_a, translation_a, local_b, rotation_b, translation_b):
    """Exact vectorised 2D SAT in any float dtype: local_* (n, V, 2) counter-clockwise, padded
    by repeating vertex 0 (zero axes, masked). The edge normals are the Minkowski difference's
    facet normals; the least support gap over them is the depth. Returns (depth, normal a to b)."""
    world_a, world_b = (np.einsum("nij,nvj->nvi", r, v) + t[:, None] for v, r, t in (
        (local_a, rotation_a, translation_a), (local_b, rotation_b, translation_b)))
    edges = [np.roll(w, -1, axis=1) - w for w in (world_a, world_b)]
    axes = np.concatenate([np.stack([e[..., 1], -e[..., 0]], -1) * sign
                           for e, sign in zip(edges, (1, -1), strict=True)], axis=1)
    length = np.linalg.norm(axes, axis=-1)
    axes = axes / np.where(length > 0, length, 1)[..., None]
    gaps = np.where(length > 0, np.einsum("nkd,nvd->nkv", axes, world_a).max(-1)
                    - np.einsum("nkd,nvd->nkv", axes, world_b).min(-1), np.inf)
    best, rows = np.argmin(gaps, axis=1), np.arange(len(gaps))
    return gaps[rows, best], axes[rows, best]

def numpy_sat(dtype):
    def prepare(data, n):
        def build():
            size = 4 if data.name == "2d-small" else 8
            table = np.stack([np.concatenate([p, np.repeat(p[:1], size - len(p), 0)])
                              for p in data.points]).astype(dtype)
            return [x[s, :n].astype(dtype) for s in (0, 1) for x in (
                table[data.pick], data.rotation, data.translation)]
        arguments, seconds = core.timed(build)
        return Prepared(lambda: numpy_sat_2d(*arguments), lambda out: (
            out[0].astype(np.float64), out[1].astype(np.float64), np.ones(n, bool)), seconds)
    return prepare

def _jax2d_inputs(data, indices):
    """(a, b, manifolds): jax2d bodies (clockwise vertices, zero-padded to 4), no contacts."""
    from jax2d.sim_state import CollisionManifold, RigidBody
    table = np.zeros((len(data.points), 4, 2), np.float32)
    for i, points in enumerate(data.points):
        table[i, :len(points)] = points[::-1]  # jax2d wants clockwise
    counts = np.array([len(p) for p in data.points], np.int32)
    n, z = len(indices), lambda *shape: np.zeros(shape, np.float32)
    ones = np.ones(n, np.float32)
    return [*(RigidBody(
        position=data.translation[s, indices].astype(np.float32),
        rotation=data.angle[s, indices].astype(np.float32), velocity=z(n, 2),
        angular_velocity=z(n), inverse_mass=ones, inverse_inertia=ones, friction=ones,
        restitution=z(n), collision_mode=np.ones(n, np.int32), active=np.ones(n, bool),
        n_vertices=counts[data.pick[s, indices]], vertices=table[data.pick[s, indices]],
        radius=z(n)) for s in (0, 1)), CollisionManifold(
        normal=z(2, 2), penetration=z(2), collision_point=z(2, 2), active=np.zeros(2, bool),
        acc_impulse_normal=z(2), acc_impulse_tangent=z(2), restitution_velocity_target=z(2))]

def jax2d_prepare(data, n):
    from jax2d.collision import generate_manifolds_polygon_polygon as collide
    # As jax2d's engine does: vmap the pair function over polygon pairs.
    return _jax(jax.vmap(collide, in_axes=(0, 0, None)), _jax2d_inputs(data, np.arange(n)),
                lambda out: (np.asarray(out.penetration[:, 0], np.float64),
                             np.asarray(out.normal[:, 0], np.float64),
                             np.asarray(out.active[:, 0])))

def jax2d_gradient(data, indices):
    from jax2d.collision import generate_manifolds_polygon_polygon as collide
    def depth(position_b, a, b, manifolds):
        return collide(a, b.replace(position=position_b), manifolds).penetration[0]
    a, b, manifolds = _jax2d_inputs(data, indices)
    grad = jax.jit(jax.vmap(jax.grad(depth), in_axes=(0, 0, 0, None)))
    return np.asarray(grad(b.position, a, b, manifolds), np.float64)

def _pymunk_poly(data, s, i, body, offset=0.0):
    """The polygon of side s of pair i on `body`, at its pose moved by `offset`."""
    import pymunk
    body.position, body.angle = tuple(data.translation[s, i] + offset), float(data.angle[s, i])
    return pymunk.Poly(body, [tuple(p) for p in data.points[data.pick[s, i]]])

def _pymunk_contacts(points, flip=1.0):
    if points is None or not points.points:
        return 0.0, (0.0, 0.0), False, False
    depth = -min(p.distance for p in points.points)
    return depth, flip * np.array(tuple(points.normal)), True, depth > 0

def pymunk_prepare(data, n):
    import pymunk
    def poly(s, i):
        shape = _pymunk_poly(data, s, i, pymunk.Body(body_type=pymunk.Body.KINEMATIC))
        shape.cache_bb()  # shapes_collide reads the cached world vertices
        return shape
    def collide(pair):
        try:
            return pair[0].shapes_collide(pair[1])
        except AssertionError:  # pymunk 7.3 asserts on a contact set with no point (apart)
            return None
    return _loop(lambda: [(poly(0, i), poly(1, i)) for i in range(n)], collide, _pymunk_contacts)

PYMUNK_SPACING = 8.0
"""Grid spacing of the pairs in the pymunk Space (shapes < 2 across, centres within 3)."""

def pymunk_space_prepare(data, n):
    """All pairs in one Space, each in its own grid cell; timed: `Space.step` (broad phase,
    narrow phase, solver; 1 iteration, a step of 1e-9 s). a is static, b dynamic."""
    import pymunk
    columns = int(np.ceil(np.sqrt(n)))
    cells = PYMUNK_SPACING * np.stack([np.arange(n) % columns, np.arange(n) // columns], 1)
    def build():
        space, shapes_b = pymunk.Space(), {}
        space.iterations = 1
        for i in range(n):
            for s, body in enumerate((pymunk.Body(body_type=pymunk.Body.STATIC),
                                      pymunk.Body(1.0, 1.0))):
                shape = _pymunk_poly(data, s, i, body, cells[i])
                space.add(body, shape)
                shapes_b.update({shape: i} if s else {})
        return space, shapes_b
    (space, shapes_b), seconds = core.timed(build)
    def decode(_):
        depth, normal, found = np.zeros(n), np.zeros((n, 2)), np.zeros(n, bool)
        for shape, i in shapes_b.items():
            def read(arbiter, i=i, shape=shape):
                flip = -1.0 if arbiter.shapes[0] is shape else 1.0  # normal: a to b
                depth[i], normal[i], found[i], _ = _pymunk_contacts(arbiter.contact_point_set, flip)
            shape.body.each_arbiter(read)
        return depth, normal, found
    return Prepared(lambda: space.step(1e-9), decode, seconds)

def collision_prepare(data, n):
    import collision
    def poly(s, i):
        return collision.Poly(collision.Vector(*data.translation[s, i]), [
            collision.Vector(*p) for p in data.points[data.pick[s, i]]], float(data.angle[s, i]))
    def collide(pair):
        response = collision.Response()
        hit = collision.collide(*pair, response)
        return hit, response.overlap, (response.overlap_n.x, response.overlap_n.y)
    return _loop(lambda: [(poly(0, i), poly(1, i)) for i in range(n)], collide,
                 lambda out: (out[1] if out[0] else 0.0, out[2], True, out[0]))

def _mesh_spec(data):
    import mujoco
    spec = mujoco.MjSpec()
    for k, geom in enumerate(data.geoms):
        if geom.kind == "hull":
            mesh = spec.add_mesh()
            mesh.name, mesh.uservert = f"hull{k}", geom.points.flatten().tolist()
    return spec

def _mujoco_pool(data):
    """A compiled MjModel with one mesh geom per pool hull (None without hulls)."""
    import mujoco
    def build():
        spec = _mesh_spec(data)
        for k in range(len(data.points)):
            geom = spec.worldbody.add_body(mocap=True).add_geom()
            geom.type, geom.meshname = mujoco.mjtGeom.mjGEOM_MESH, f"hull{k}"
        return spec.compile()
    return _memo(data, "mujoco", build) if "hull" in data.kinds else None

def _geom_frames(data, pool, s, indices):
    """World positions and rotations of side s's geoms. MuJoCo re-centres a mesh on its
    centre of mass and principal axes: the shape at (R, t) is the geom at (R quat, R pos + t)."""
    pick, rotation, translation = (x[s, indices] for x in (data.pick, data.rotation,
                                                           data.translation))
    if pool is None:
        return translation, rotation
    import mujoco
    offsets = np.zeros((pool.ngeom, 9))
    for g, quat in enumerate(pool.geom_quat):
        mujoco.mju_quat2Mat(offsets[g], quat)
    return (np.einsum("nij,nj->ni", rotation, pool.geom_pos[pick]) + translation,
            rotation @ offsets.reshape(-1, 3, 3)[pick])

MUJOCO_CHUNK = 10_000
"""Pairs per MuJoCo model: compiling explicit pairs costs time quadratic in their number."""

def _mujoco_models(data, n):
    """[(start, model, data)]: each model holds explicit geom pairs (i, k + i) for k pairs, all
    a geoms in one mocap body, all b geoms in another (one body per geom would make mj_collision
    allocate a bodies x bodies matrix), contype collisions off, world poses in geom_xpos/xmat."""
    import mujoco
    pool, models = _mujoco_pool(data), []
    for start in range(0, n, MUJOCO_CHUNK):
        stop = min(n, start + MUJOCO_CHUNK)
        count, spec = stop - start, _mesh_spec(data)
        spec.memory = 2**22 + count * 8 * 1024  # room for up to 8 contacts per pair
        for s, side in enumerate("ab"):
            body = spec.worldbody.add_body(mocap=True)
            for i in range(start, stop):
                geom, k = body.add_geom(), int(data.pick[s, i])
                geom.name, geom.contype, geom.conaffinity = f"{side}{i}", 0, 0
                hull, geom.size = data.kinds[s] == "hull", data.geoms[k].size
                geom.type = getattr(mujoco.mjtGeom, "mjGEOM_" + (
                    "MESH" if hull else data.kinds[s].upper()))
                geom.meshname = f"hull{k}" * hull
        for i in range(start, stop):
            pair = spec.add_pair()
            pair.geomname1, pair.geomname2 = f"a{i}", f"b{i}"
        model = spec.compile()
        assert model.geom(count).name == f"b{start}"  # a geoms first, then b geoms
        state = mujoco.MjData(model)
        for s in (0, 1):
            position, rotation = _geom_frames(data, pool, s, np.arange(start, stop))
            state.geom_xpos[s * count:(s + 1) * count] = position
            state.geom_xmat[s * count:(s + 1) * count] = rotation.reshape(count, 9)
        models.append((start, model, state))
    return models

def mujoco_collision_prepare(data, n):
    import mujoco
    models, seconds = core.timed(lambda: _mujoco_models(data, n))
    def run():
        for _, model, state in models:
            mujoco.mj_collision(model, state)
        return [state.ncon for _, _, state in models]
    def decode(counts):
        depth, normal, found = np.full(n, -np.inf), np.zeros((n, 3)), np.zeros(n, bool)
        for (start, _, state), count in zip(models, counts, strict=True):
            c = state.contact
            geom1, geom2 = np.asarray(c.geom1[:count]), np.asarray(c.geom2[:count])
            dist, frame = np.asarray(c.dist[:count]), np.asarray(c.frame[:count])
            flip = np.where(geom1 > geom2, -1.0, 1.0)  # frame normal: from geom1 to geom2
            for k, pair in enumerate(start + np.minimum(geom1, geom2)):
                found[pair] = True
                if -dist[k] > depth[pair]:
                    depth[pair], normal[pair] = -dist[k], flip[k] * frame[k, :3]
        return np.where(found, depth, 0.0), normal, found
    return Prepared(run, decode, seconds)

def mujoco_distance_prepare(data, n):
    import mujoco
    fromto = np.zeros(6)
    def distance(pair):
        return mujoco.mj_geomDistance(*pair, 10.0, fromto), fromto.copy()
    def decode_one(out):  # fromto: from a's point to b's apart, from b's into a's overlapping
        distance, fromto = out
        return (-distance, _unit(fromto[3:] - fromto[:3]) * (-1 if distance < 0 else 1), True,
                distance < 0)
    return _loop(lambda: [(model, state, i, model.ngeom // 2 + i) for _, model, state in
                          _mujoco_models(data, n) for i in range(model.ngeom // 2)],
                 distance, decode_one)

def _mjx_meshes(data, pool):
    """Stacked ConvexMesh fields (vert, face, face_normal, edge, edge_face_normal) of the pool
    hulls from MJX's own mesh processing, padded to common sizes by repeating entries."""
    def build():
        from mujoco.mjx._src import mesh
        meshes, stacked = [mesh.convex(pool, k) for k in range(pool.nmesh)], []
        for field in ("vert", "face", "face_normal", "edge", "edge_face_normal"):
            arrays = [np.asarray(getattr(m, field)) for m in meshes]
            if field == "face":  # every face padded to the most vertices, as the driver does
                width = max(a.shape[1] for a in arrays)
                arrays = [np.pad(a, ((0, 0), (0, width - a.shape[1]), (0, 0)), "edge")
                          for a in arrays]
            rows = max(a.shape[0] for a in arrays)
            array = np.stack([np.concatenate([a, np.repeat(a[:1], rows - len(a), 0)])
                              for a in arrays])
            stacked.append(array.astype(np.float32) if array.dtype.kind == "f" else array)
        return tuple(stacked)
    return _memo(data, "mjx", build)

def _mjx_arguments(data, indices):
    """((pos, mat, size) of a, the same of b[, mesh fields of a, of b]), float32."""
    pool, geoms, meshes = _mujoco_pool(data), [], []
    for s in (0, 1):
        position, rotation = _geom_frames(data, pool, s, indices)
        pick = data.pick[s, indices]
        geoms.append(tuple(np.asarray(x, np.float32) for x in (
            position, rotation, [data.geoms[k].size for k in pick])))
        if "hull" in data.kinds:
            meshes.append(tuple(field[pick] for field in _mjx_meshes(data, pool)))
    return (*geoms, *meshes)

def _mjx_batched(kinds):
    """MJX's function for the pair of kinds without the Model/Data plumbing, vmapped over pairs:
    distances (n, k), points (n, k, 3) and contact frames (n, k, 3, 3). Spheres and capsules:
    MJX's own vmapped collider, given stand-ins for Model and Data that hold the geoms."""
    from mujoco.mjx._src import collision_convex, collision_primitive, math, mesh
    from mujoco.mjx._src.collision_types import ConvexInfo, GeomInfo
    if "box" not in kinds and "hull" not in kinds:
        def primitive(geom_a, geom_b):
            n, (pos, mat, size) = len(geom_a[0]), map(jax.numpy.concatenate, zip(
                geom_a, geom_b, strict=True))
            out = getattr(collision_primitive, "_".join(kinds))(
                SimpleNamespace(geom_size=size), SimpleNamespace(geom_xpos=pos, geom_xmat=mat),
                None, np.stack([np.arange(n), n + np.arange(n)], 1))
            return jax.tree.map(lambda x: x[:, None], out)
        return primitive
    def pair(info_a, info_b):
        collide = {"box": collision_convex._box_box, "hull": collision_convex._convex_convex,
                   "sphere": collision_convex._sphere_convex}[kinds[0]]
        dist, pos, normal = collide(info_a, info_b)
        return dist.ravel(), pos.reshape(-1, 3), jax.vmap(math.make_frame)(normal.reshape(-1, 3))
    def batched(geom_a, geom_b, mesh_a=(), mesh_b=()):
        infos, axes = [], []
        for kind, geom, fields in zip(kinds, (geom_a, geom_b), (mesh_a, mesh_b), strict=True):
            infos.append(mesh.box(GeomInfo(*geom)) if kind == "box" else
                         ConvexInfo(*geom, *fields) if kind == "hull" else GeomInfo(*geom))
            axes.append(jax.tree.map(lambda x: None, infos[-1]).replace(
                pos=0, mat=0, size=0, face=0, vert=0) if kind == "box" else 0)
        return jax.vmap(pair, in_axes=axes)(*infos)
    return batched

def mjx_prepare(data, n):
    def decode(out):  # each pair's deepest contact
        dist, _, frame = (np.asarray(x, np.float64) for x in out)
        best, rows = np.argmin(dist, axis=1), np.arange(n)
        return -dist[rows, best], frame[rows, best, 0], dist[rows, best] < 0
    return _jax(_mjx_batched(data.kinds), _mjx_arguments(data, np.arange(n)), decode)

def mjx_gradient(data, indices):
    batched = _mjx_batched(data.kinds)
    geom_a, geom_b, *meshes = _mjx_arguments(data, indices)
    def total_depth(position_b, geom_a, rest_b, meshes):
        # pairs are independent: the gradient of the sum is each pair's gradient
        return -jax.numpy.sum(jax.numpy.min(batched(geom_a, (position_b, *rest_b),
                                                    *meshes)[0], axis=1))
    gradient = jax.jit(jax.grad(total_depth))(geom_b[0], geom_a, geom_b[1:], tuple(meshes))
    return np.asarray(gradient, np.float64)

def coal_prepare(data, n):
    import coal
    def geometry(geom):  # Capsule(radius, length of the segment)
        if geom.kind == "hull":
            vertices = coal.StdVec_Vec3s()
            vertices.extend(list(geom.points))
            return coal.Convex.convexHull(vertices, False, "")
        return {"box": lambda: coal.Box(*(2 * geom.size)),
                "sphere": lambda: coal.Sphere(geom.size[0]),
                "capsule": lambda: coal.Capsule(geom.size[0], 2 * geom.size[1])}[geom.kind]()
    def build():
        shapes = [geometry(geom) for geom in data.geoms]
        return [tuple(x for s in (0, 1) for x in (shapes[data.pick[s, i]], coal.Transform3s(
            data.rotation[s, i], data.translation[s, i]))) for i in range(n)]
    request, result = coal.DistanceRequest(), coal.DistanceResult()
    request.enable_signed_distance = True
    def distance(pair):
        result.clear()
        return coal.distance(*pair, request, result), tuple(result.normal)
    return _loop(build, distance, lambda out: (-out[0], _unit(out[1]), True, out[0] < 0))

TWO_D, THREE_D, ALL = ("2d-small", "2d-polygons"), tuple(CASES[2:]), tuple(CASES)
METHODS: dict[str, Method] = {m.name: m for m in (
    Method("jaxsat", ALL, DEPTH, "float32", "jaxsat", _jaxsat(jaxsat.penetration),
           _jaxsat_gradient(lambda *x: jaxsat.penetration(*x).depth)),
    Method("jaxsat-chunked", ALL, DEPTH, "float32", "jaxsat",
           _jaxsat(jaxsat.penetration, chunked=True)),
    Method("jaxsat-distance", ALL, DISTANCE, "float32", "jaxsat",
           _jaxsat(jaxsat.closest_points, lambda out: _penetration(out, -1)),
           _jaxsat_gradient(lambda *x: -jaxsat.signed_distance(*x))),
    Method("jaxsat-contacts", ALL, CONTACTS, "float32", "jaxsat",
           _jaxsat(jaxsat.contacts, _contacts)),
    *(Method(f"numpy-sat-f{bits}", TWO_D, DEPTH, f"float{bits}", None, numpy_sat(f"float{bits}"))
      for bits in (32, 64)),
    Method("jax2d", ("2d-small",), CONTACTS, "float32", "jax2d", jax2d_prepare, jax2d_gradient),
    Method("pymunk", TWO_D, CONTACTS, "float64", "pymunk", pymunk_prepare, loop=True),
    Method("pymunk-space", TWO_D, CONTACTS, "float64", "pymunk", pymunk_space_prepare),
    Method("collision", TWO_D, DEPTH, "float64", "collision", collision_prepare, loop=True),
    Method("mjx", THREE_D, CONTACTS, "float32", "mujoco.mjx", mjx_prepare, mjx_gradient,
           install="mujoco-mjx"),
    Method("mujoco-collision", THREE_D, CONTACTS, "float64", "mujoco", mujoco_collision_prepare),
    Method("mujoco-distance", THREE_D, DISTANCE, "float64", "mujoco", mujoco_distance_prepare,
           loop=True),
    Method("coal", THREE_D, DISTANCE, "float64", "coal", coal_prepare, loop=True))}
"""Every method, by name (`--list` prints them with their level, dtype and status)."""

def angle_degrees(normal, reference):
    """Angle between each normal and the reference (atan2: accurate near 0); 180 for zero."""
    cosine = np.sum(normal * reference, axis=1)
    sine = (np.abs(normal[:, 0] * reference[:, 1] - normal[:, 1] * reference[:, 0])
            if normal.shape[1] == 2 else np.linalg.norm(np.cross(normal, reference), axis=1))
    return np.where(np.linalg.norm(normal, axis=1) == 0, 180.0,
                    np.degrees(np.arctan2(sine, cosine)))

def error_stats(method, ref: core.Reference, depth, normal, found, says=None) -> dict:
    """Errors on the pairs that overlap and that the method reports (a missed pair counts as
    a wrong overlap decision); normals where the oracle's is unique."""
    overlap, apart = ref.overlapping, ref.separated
    says, measured = found & (depth > 0) if says is None else says, overlap & found
    angles = angle_degrees(normal, ref.normal)[measured & ref.normal_is_unique]
    depth_error = np.abs(depth - ref.depth)[measured]
    out = {"pairs": len(depth), "overlapping": int(overlap.sum()),
           "wrong_overlap": int(np.sum((overlap & ~says) | (apart & says))),
           "missed": int(np.sum(overlap & ~found)), **core.stats("depth_error", depth_error),
           **core.stats("normal_error", angles, "_deg"), **(core.stats("distance_error", np.abs(
               -depth - ref.distance)[apart]) if method.level == DISTANCE else {})}
    if len(angles):
        out.update(normals_over_1deg=float(np.mean(angles > 1.0)), normals_compared=len(angles))
    return out

def measure(method, data, ref, grads, args) -> dict:
    """One row: pairs/s per size, setup time, errors and gradient errors."""
    sizes, count = {}, len(ref.depth)
    row = {"case": data.name, "method": method.name, "level": method.level,
           "precision": method.precision, "gradients": "jax.grad" if method.gradient else "no",
           "sizes": sizes}
    if method.missing():
        row["skipped"] = f"not installed: {method.pip}"
        return row
    per_pair, decoded, timed = 0.0, None, {}
    for n in args.sizes:
        k = min(n, args.loop_pairs) if method.loop else n
        if k in timed or (why := core.too_big(args, seconds=per_pair * k)):
            sizes[n] = dict(timed.get(k) or {"skipped": why})
            continue
        try:
            prepared = method.prepare(data, k)
            if why := core.too_big(args, prepared.memory_bytes):
                sizes[n] = {"skipped": why}
                break
            timing = core.time_calls({"": prepared.run}, args.repeats, args.budget_seconds,
                                     block=False)[""]
            if decoded is None and k >= count:
                decoded = [x[:count] for x in prepared.decode(timing.output)]
        except Exception as error:  # noqa: BLE001 - a failing peer is reported, not fatal
            sizes[n] = {"failed": f"{type(error).__name__}: {error}"[:300]}
            break
        per_pair = timing.best / k
        sizes[n] = timed[k] = {"timed_pairs": k, "pairs_per_second": k / timing.best,
                               "best_s": timing.best, "median_s": timing.median,
                               "calls": len(timing.times), "setup_s": prepared.setup_s,
                               "memory_bytes": prepared.memory_bytes}
        row.setdefault("setup_s", prepared.setup_s)
    try:
        if decoded is None:
            prepared = method.prepare(data, count)
            decoded = prepared.decode(prepared.run())
            row.setdefault("setup_s", prepared.setup_s)
        row["errors"] = error_stats(method, ref, *decoded)
        if method.gradient is not None and len(grads[0]):
            error = np.linalg.norm(method.gradient(data, grads[0]) - grads[1], axis=1)
            finite = error[np.isfinite(error)]
            row["errors"].update(grad_pairs=len(error), grad_nonfinite=len(error) - len(finite),
                                 **core.stats("grad_error", finite) or {"grad_error_max": math.inf})
    except Exception as error:  # noqa: BLE001
        row["errors_failed"] = f"{type(error).__name__}: {error}"[:300]
    return row

def size_cell(cell: dict | None) -> str:
    return next((key for key in ("skipped", "failed") if key in cell),
                f"{cell.get('pairs_per_second', 0):.2g}") if cell else "-"

def row_notes(row: dict) -> str:
    if "skipped" in row:
        return row["skipped"]
    timed = [c["timed_pairs"] for n, c in row["sizes"].items() if c.get("timed_pairs", n) != n]
    notes = ([f"loop timed on first {min(timed):,} pairs"] if timed else []) + [
        f"{n:,}: {key} ({cell[key]})" for n, cell in row["sizes"].items()
        for key in ("skipped", "failed") if key in cell]
    if row.get("errors", {}).get("missed"):
        notes.append(f"{row['errors']['missed']} overlapping pairs without contact")
    if "errors_failed" in row:
        notes.append(f"errors failed: {row['errors_failed']}")
    return "; ".join(notes)

def markdown(rows: list[dict], args) -> str:
    def pair(e, key):
        return f"{core.num(e.get(key + '_max'))} / {core.num(e.get(key + '_median'))}" if (
            key + "_max") in e else "-"
    table = [[row["case"], row["method"], row["level"], row["precision"],
              *[size_cell(row["sizes"].get(n)) for n in args.sizes], core.num(row.get("setup_s")),
              pair(e, "depth_error"), core.num(e.get("normal_error_max_deg")),
              f"{e['normals_over_1deg']:.1%}" if "normals_over_1deg" in e else "-",
              f"{e['wrong_overlap']} / {e['pairs']}" if e else "-",
              core.num(e.get("distance_error_max")), row["gradients"], pair(e, "grad_error"),
              row_notes(row)] for row in rows for e in [row.get("errors", {})]]
    return (f"Errors on the first {args.error_pairs} pairs of each case against the float64 "
            "oracle (depth and normal on overlapping pairs the method reports; normal as the "
            "angle to the oracle's); gradients: d depth / d translation of b against central "
            f"finite differences of the oracle on up to {args.grad_pairs} overlapping pairs "
            "(error: norm of the difference). Setup: JAX compile, MuJoCo model build, or "
            "object building.\n\n" + core.markdown_table([
                "case", "method", "level", "dtype", *(f"pairs/s {n:.0e}".replace("+0", "")
                for n in args.sizes), "setup s", "depth err max / median", "normal err max (deg)",
                "normals > 1 deg", "wrong overlap", "distance err max (apart)", "grad",
                "grad err max / median", "notes"], table))

def main(argv=None) -> int:
    args = core.parse(argv, __doc__, DEFAULTS, CASES, limits=core.LIMITS, options={
        "--methods": {"nargs": "+", "choices": list(METHODS), "default": list(METHODS)},
        "--error-pairs": "pairs compared with the oracle",
        "--grad-pairs": "overlapping pairs for gradients",
        "--loop-pairs": "most pairs a Python loop is timed on", "--list": {
            "action": "store_true", "help": "list the methods and whether they are installed"}})
    args.sizes = sorted(set(args.sizes))
    if args.list:
        width = max(len(" ".join(m.cases)) for m in METHODS.values())
        print(f"{'method':<17} {'level':<23} {'dtype':<8} {'cases':<{width}} status")
        for m in METHODS.values():
            print(f"{m.name:<17} {m.level:<23} {m.precision:<8} {' '.join(m.cases):<{width}} "
                  + (f"missing {m.pip}" if m.missing() else "installed"))
        return 0
    info, rows = core.machine_info(DISTRIBUTIONS), []
    for case in args.cases:
        data = core.make_data(case, max(max(args.sizes), args.error_pairs), args.pool, args.seed)
        ref = core.reference(data, args.error_pairs)
        index, gradient = core.oracle_gradients(
            data, np.flatnonzero(ref.overlapping & ref.normal_is_unique),
            data.params.shape[-1] + np.arange(data.dim), FD_AGREEMENT, args.grad_pairs)
        grads = index, -gradient  # d depth / d translation of b (depth: minus the distance)
        for method in (METHODS[name] for name in args.methods if case in METHODS[name].cases):
            rows.append(row := measure(method, data, ref, grads, args))
            print(f"{case:<13} {method.name:<17} " + "  ".join(
                f"{n:.0e}: {size_cell(row['sizes'].get(n))}" for n in args.sizes)
                + f"  depth err {core.num(row.get('errors', {}).get('depth_error_max'))}",
                file=sys.stderr, flush=True)
    core.save(args, "peers", "jaxsat peers benchmark", info, {"rows": rows}, markdown(rows, args))
    return 0

if __name__ == "__main__":
    sys.exit(main())
