"""Contact manifolds of rounded shapes and half-spaces against closed forms.

Each scenario builds configurations in a's local frame whose manifold is known by hand (a
sphere over a face, edge or corner; a capsule lying on a face or tilted onto it; parallel and
crossing capsules; stacked rounded boxes; shapes resting on a half-space, whose contacts are
their lowest vertices), moves each configuration by a random rigid motion, and compares
`contacts` (batched, one compile per scenario and dtype) with the expected points, depths,
validity and normal in the world. Valid points are compared as sets (slot order is the
library's choice).
"""

from __future__ import annotations

import dataclasses

import harness
import jax
import jax.numpy as jnp
import numpy as np
import oracle
import pytest

import jaxsat

TOLERANCE = {np.float64: 1e-9, np.float32: 2e-5}
"""Length tolerance relative to the configuration's size."""

MARGIN = 0.05


@dataclasses.dataclass
class Config:
    """One pair in a's local frame and its manifold."""

    a: object
    b: object
    rotation_b: np.ndarray
    """b's orientation in a's frame: an angle (2D) or a quaternion (3D)."""
    translation_b: np.ndarray
    points: np.ndarray
    """(k, D) expected valid points in a's frame (k = 0: no valid point)."""
    depths: np.ndarray
    """(k,) their depths."""
    normal: np.ndarray
    """(D,) the contact normal in a's frame, from a towards b."""
    plane_second: bool = False
    """The pair is given as (b, a): a (a half-space) goes second."""


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _quaternion_between(u, v) -> np.ndarray:
    """A unit quaternion (w, x, y, z) rotating unit u onto unit v (u != -v)."""
    half = _unit(_unit(u) + _unit(v))
    return np.concatenate([[np.dot(_unit(u), half)], np.cross(_unit(u), half)])


def _clip_to_rectangle(start, end, half):
    """Liang-Barsky: the parameter interval of the 2D segment start + t (end - start),
    t in [0, 1], inside [-half, half]; None if empty."""
    low, high = 0.0, 1.0
    step = end - start
    for k in range(2):
        for sign in (1.0, -1.0):
            # sign * (start + t step) <= half
            p, q = sign * step[k], half[k] - sign * start[k]
            if p == 0:
                if q < 0:
                    return None
            elif p > 0:
                high = min(high, q / p)
            else:
                low = max(low, q / p)
    return (low, high) if low <= high else None


# --------------------------------------------------------------------------------------------
# Scenarios (3D), each a list of Configs in a's frame.
# --------------------------------------------------------------------------------------------


def _depth(rng, deepest):
    """A depth from -2 margins (no valid point) to `deepest` (an overlap)."""
    return float(rng.uniform(-2 * MARGIN, deepest))


def sphere_on_box(rng, count):
    """A sphere over a face, an edge or a corner of a box (its closest point known), or
    centred inside it (the least-deep face)."""
    configs = []
    for i in range(count):
        half = rng.uniform(0.3, 1.0, 3)
        radius = rng.uniform(0.1, 0.6)
        box, ball = jaxsat.box(half), jaxsat.sphere(radius)
        if i % 4 == 3:  # centre inside: pushed out through the nearest face
            centre = rng.uniform(-0.5, 0.5, 3) * half
            k = int(np.argmin(half - np.abs(centre)))
            normal = np.zeros(3)
            normal[k] = 1.0 if centre[k] >= 0 else -1.0
            depth = radius + half[k] - abs(centre[k])
            on_box = centre.copy()
            on_box[k] = normal[k] * half[k]
            point = (on_box + centre - radius * normal) / 2
            configs.append(Config(box, ball, harness.IDENTITY, centre, point[None],
                                  np.array([depth]), normal))
            continue
        # The closest box point: on a face (1 free coordinate sign), edge (2) or corner (3).
        fixed = i % 3 + 1
        axes = rng.permutation(3)[:fixed]
        signs = rng.choice([-1.0, 1.0], fixed)
        closest = rng.uniform(-0.9, 0.9, 3) * half
        closest[axes] = signs * half[axes]
        normal = np.zeros(3)
        normal[axes] = signs * rng.uniform(0.2, 1.0, fixed)
        normal = _unit(normal)
        depth = _depth(rng, 0.5 * radius)
        centre = closest + (radius - depth) * normal
        point = (closest + centre - radius * normal) / 2
        valid = depth >= -MARGIN
        configs.append(Config(box, ball, harness.IDENTITY, centre,
                              point[None] if valid else np.zeros((0, 3)),
                              np.array([depth] if valid else []), normal))
    return configs


def _horizontal_capsule(rng, half_length):
    """A quaternion turning the capsule's z axis horizontal at a random heading, with a random
    roll about its own axis; and that heading."""
    heading = rng.uniform(-np.pi, np.pi)
    direction = np.array([np.cos(heading), np.sin(heading), 0.0])
    roll = harness.quaternion([0.0, 0.0, 1.0], rng.uniform(-np.pi, np.pi))
    return harness.quaternion_product(_quaternion_between([0, 0, 1], direction), roll), direction


def capsule_on_box(rng, count):
    """A capsule lying on a box's top face, partly overhanging (two points: the ends of the
    segment clipped to the face), or tilted onto it by its lower end (the ends of the clipped
    segment that are within the margin)."""
    configs = []
    for i in range(count):
        half = rng.uniform(0.4, 1.0, 3)
        half_length, radius = rng.uniform(0.2, 1.0), rng.uniform(0.1, 0.4)
        box, pill = jaxsat.box(half), jaxsat.capsule(half_length, radius)
        depth = _depth(rng, 0.5 * radius)
        if i % 3 == 2:  # tilted: the lower end over the face, the upper one higher
            low_end = np.append(rng.uniform(-0.8, 0.8, 2) * half[:2], half[2] + radius - depth)
            direction = _unit(np.append(rng.normal(size=2), 0.0))
            axis = _unit(direction * 2 * half_length + np.array([0.0, 0.0, 0.5]))
            high_end = low_end + 2 * half_length * axis
            turn = _quaternion_between([0, 0, 1], axis)
            # Points at the ends of the segment clipped to the face (seen from above), where
            # within the margin.
            low, high = _clip_to_rectangle(low_end[:2], high_end[:2], half[:2])
            points, depths = [], []
            for t in sorted({low, high}):
                core = low_end + t * (high_end - low_end)
                if radius - (core[2] - half[2]) >= -MARGIN:
                    points.append(np.append(core[:2], (half[2] + core[2] - radius) / 2))
                    depths.append(radius - (core[2] - half[2]))
            configs.append(Config(box, pill, turn, (low_end + high_end) / 2,
                                  np.array(points).reshape(-1, 3), np.array(depths),
                                  np.array([0, 0, 1.0])))
            continue
        turn, direction = _horizontal_capsule(rng, half_length)
        centre_xy = rng.uniform(-0.9, 0.9, 2) * half[:2]
        height = half[2] + radius - depth
        ends = [centre_xy - half_length * direction[:2], centre_xy + half_length * direction[:2]]
        low, high = _clip_to_rectangle(ends[0], ends[1], half[:2])
        points = []
        for t in sorted({low, high}):
            xy = ends[0] + t * (ends[1] - ends[0])
            points.append(np.append(xy, (half[2] + height - radius) / 2))
        valid = depth >= -MARGIN
        configs.append(Config(box, pill, turn, np.append(centre_xy, height),
                              np.array(points) if valid else np.zeros((0, 3)),
                              np.full(len(points) if valid else 0, depth),
                              np.array([0, 0, 1.0])))
    return configs


def capsule_pairs(rng, count):
    """Two capsules side by side, parallel (two points: the ends of their overlap) or crossing
    at an angle (one point between the segments' closest points)."""
    configs = []
    for i in range(count):
        half_a, half_b = rng.uniform(0.3, 1.0, 2)
        radius_a, radius_b = rng.uniform(0.1, 0.4, 2)
        a, b = jaxsat.capsule(half_a, radius_a), jaxsat.capsule(half_b, radius_b)
        depth = _depth(rng, 0.5 * min(radius_a, radius_b))
        across = _unit(np.append(rng.normal(size=2), 0.0))  # perpendicular to a's axis
        gap = radius_a + radius_b - depth
        valid = depth >= -MARGIN
        middle = (radius_a + gap - radius_b) / 2 * across
        if i % 2 == 0:  # parallel, b shifted along the axis so that they overlap
            shift = rng.uniform(-0.9, 0.9) * (half_a + half_b)
            ends = [max(-half_a, shift - half_b), min(half_a, shift + half_b)]
            points = [middle + np.array([0, 0, z]) for z in sorted(set(ends))]
            roll = harness.quaternion([0.0, 0.0, 1.0], rng.uniform(-np.pi, np.pi))
            configs.append(Config(a, b, roll, gap * across + np.array([0, 0, shift]),
                                  np.array(points) if valid else np.zeros((0, 3)),
                                  np.full(len(points) if valid else 0, depth), across))
            continue
        height = rng.uniform(-0.8, 0.8) * half_a
        turn = harness.quaternion(across, rng.choice([-1, 1]) * rng.uniform(0.3, np.pi / 2))
        point = middle + np.array([0, 0, height])
        configs.append(Config(a, b, turn, gap * across + np.array([0, 0, height]),
                              point[None] if valid else np.zeros((0, 3)),
                              np.array([depth] if valid else []), across))
    return configs


def rounded_boxes(rng, count, dim=3):
    """A rounded box on a rounded box, axis-aligned (b turned by a multiple of 90 degrees about
    the vertical): the corners of the overlap of the two faces (4 in 3D, 2 in 2D)."""
    configs = []
    up = np.eye(dim)[dim - 1]
    for _ in range(count):
        half_a, half_b = rng.uniform(0.3, 1.0, dim), rng.uniform(0.3, 1.0, dim)
        radius_a, radius_b = rng.uniform(0.0, 0.3, 2)
        a = jaxsat.rounded(jaxsat.box(half_a), radius_a)
        b = jaxsat.rounded(jaxsat.box(half_b), radius_b)
        quarter = int(rng.integers(4))
        if dim == 3:
            turn = harness.quaternion([0.0, 0.0, 1.0], quarter * np.pi / 2)
            flat_b = half_b[:2] if quarter % 2 == 0 else half_b[1::-1]
        else:
            turn, flat_b = np.pi * (quarter % 2), half_b[:1]
        shift = rng.uniform(-0.8, 0.8, dim - 1) * (half_a[:-1] + flat_b)
        low = np.maximum(-half_a[:-1], shift - flat_b)
        high = np.minimum(half_a[:-1], shift + flat_b)
        # The cores overlap by at most 0.03, less than across (so the normal stays vertical).
        depth = _depth(rng, radius_a + radius_b + 0.03)
        centre_height = half_a[-1] + radius_a + radius_b + half_b[-1] - depth
        top_a, bottom_b = half_a[-1] + radius_a, centre_height - half_b[-1] - radius_b
        corners = (np.array([[x, y] for x in (low[0], high[0]) for y in (low[1], high[1])])
                   if dim == 3 else np.array([[low[0]], [high[0]]]))
        points = np.concatenate([corners, np.full((len(corners), 1), (top_a + bottom_b) / 2)],
                                axis=1)
        valid = depth >= -MARGIN
        configs.append(Config(a, b, turn, np.append(shift, centre_height),
                              points if valid else np.zeros((0, dim)),
                              np.full(len(points) if valid else 0, depth), up))
    return configs


def on_halfspace(rng, count, dim=3, plane_second=False):
    """Shapes above a half-space (random normal and offset): the lowest vertices, each with
    depth radius - height, and the midpoint between the plane and the shape's surface. Half the
    shapes rest a face flat on the plane (a box: 4 points, 2 in 2D); the others are turned at
    random (about one point)."""
    configs = []
    for i in range(count):
        normal = _unit(rng.normal(size=dim))
        offset = rng.uniform(-0.5, 0.5)
        plane = jaxsat.halfspace(normal, offset)
        kind = i % 4
        radius = rng.uniform(0.1, 0.4) if kind in (1, 2, 3) else 0.0
        if kind == 2:
            half = rng.uniform(0.2, 1.0)
            shape = jaxsat.capsule(half, radius, dim)
            core = np.zeros((2, dim))
            core[:, dim - 1 if dim == 3 else 0] = [-half, half]
        elif kind == 3:
            shape, core = (jaxsat.sphere(radius) if dim == 3 else jaxsat.circle(radius),
                           np.zeros((1, dim)))
        else:
            half = rng.uniform(0.3, 1.0, dim)
            shape = jaxsat.box(half) if kind == 0 else jaxsat.rounded(jaxsat.box(half), radius)
            core = harness.corners(half)
        flat = i % 8 < 4
        if dim == 2:
            angle = (np.arctan2(normal[1], normal[0]) - np.pi / 2 if flat
                     else rng.uniform(-np.pi, np.pi))
            rotation, turn = oracle.rotation_2d(angle), angle
        else:
            down = -np.eye(3)[2] if kind != 2 else np.eye(3)[0]  # a face, or the capsule's side
            turn = (_quaternion_between(down, -normal) if flat else
                    _unit(rng.normal(size=4)))
            rotation = oracle.rotation_3d(turn)
        local = core @ rotation.T
        depth = _depth(rng, 0.2)
        lowest = np.min(local @ normal)
        translation = normal * (offset - lowest + radius - depth)
        translation += _unit(rng.normal(size=dim)) * 0.3
        translation -= (translation @ normal - (offset - lowest + radius - depth)) * normal
        world = local + translation
        heights = world @ normal - offset
        depths = radius - heights
        near = depths >= -MARGIN
        points = world[near] - ((heights[near] + radius) / 2)[:, None] * normal
        configs.append(Config(plane, shape, turn, translation, points, depths[near], normal,
                              plane_second))
    return configs


# --------------------------------------------------------------------------------------------
# 2D scenarios.
# --------------------------------------------------------------------------------------------


def circle_on_rectangle(rng, count):
    configs = []
    for i in range(count):
        half, radius = rng.uniform(0.3, 1.0, 2), rng.uniform(0.1, 0.6)
        if i % 2 == 0:  # over an edge
            k, sign = int(rng.integers(2)), rng.choice([-1.0, 1.0])
            closest = rng.uniform(-0.9, 0.9, 2) * half
            closest[k] = sign * half[k]
            normal = np.eye(2)[k] * sign
        else:  # over a corner
            signs = rng.choice([-1.0, 1.0], 2)
            closest = signs * half
            normal = _unit(signs * rng.uniform(0.2, 1.0, 2))
        depth = _depth(rng, 0.5 * radius)
        centre = closest + (radius - depth) * normal
        point = (closest + centre - radius * normal) / 2
        valid = depth >= -MARGIN
        configs.append(Config(jaxsat.box(half), jaxsat.circle(radius), 0.0, centre,
                              point[None] if valid else np.zeros((0, 2)),
                              np.array([depth] if valid else []), normal))
    return configs


def stadium_on_rectangle(rng, count):
    """A 2D capsule lying on a rectangle's top edge, partly overhanging: two points."""
    configs = []
    for _ in range(count):
        half = rng.uniform(0.3, 1.0, 2)
        half_length, radius = rng.uniform(0.2, 1.0), rng.uniform(0.1, 0.4)
        depth = _depth(rng, 0.5 * radius)
        centre_x = rng.uniform(-0.9, 0.9) * half[0]
        height = half[1] + radius - depth
        ends = sorted({max(-half[0], centre_x - half_length), min(half[0], centre_x + half_length)})
        points = np.array([[x, (half[1] + height - radius) / 2] for x in ends])
        valid = depth >= -MARGIN
        configs.append(Config(jaxsat.box(half), jaxsat.capsule(half_length, radius, dim=2),
                              np.pi * rng.integers(2), np.array([centre_x, height]),
                              points if valid else np.zeros((0, 2)),
                              np.full(len(points) if valid else 0, depth), np.array([0, 1.0])))
    return configs


SCENARIOS = {
    "sphere-box": (3, sphere_on_box),
    "capsule-box": (3, capsule_on_box),
    "capsule-capsule": (3, capsule_pairs),
    "rounded-boxes": (3, rounded_boxes),
    "halfspace-shapes": (3, on_halfspace),
    "shapes-halfspace": (3, lambda rng, n: on_halfspace(rng, n, plane_second=True)),
    "circle-rectangle": (2, circle_on_rectangle),
    "stadium-rectangle": (2, stadium_on_rectangle),
    "rounded-rectangles": (2, lambda rng, n: rounded_boxes(rng, n, dim=2)),
    "line-shapes": (2, lambda rng, n: on_halfspace(rng, n, dim=2)),
}

COUNT = 24


def _stack_planes(planes, dtype):
    return jaxsat.HalfSpace(jnp.asarray(np.stack([p.normal for p in planes]), dtype),
                            jnp.asarray(np.stack([p.offset for p in planes]), dtype))


def _cast(shape, dtype):
    return jax.tree.map(lambda leaf: jnp.asarray(leaf, dtype)
                        if jnp.issubdtype(leaf.dtype, jnp.floating) else leaf, shape)


def _world(configs, dim, rng):
    """World poses of a and b for each config (a random rigid motion of a's frame), and the
    motions as (rotation matrices, shifts)."""
    turns, shifts = harness.random_motion(dim, len(configs), rng)
    rotations = harness.rotation_matrices(dim, turns)
    rows_a, rows_b = [], []
    for config, turn, rotation, shift in zip(configs, turns, rotations, shifts, strict=True):
        if dim == 2:
            rows_a.append(np.array([*shift, turn]))
            rows_b.append(np.array([*(rotation @ config.translation_b + shift),
                                    turn + config.rotation_b]))
        else:
            rows_a.append(np.concatenate([shift, turn]))
            rows_b.append(np.concatenate([rotation @ config.translation_b + shift,
                                          harness.quaternion_product(turn, config.rotation_b)]))
    return np.array(rows_a), np.array(rows_b), rotations, shifts


def _poses(rows, dim, dtype):
    columns = harness.param_columns(rows, dtype)
    maker = jaxsat.pose2 if dim == 2 else jaxsat.pose3
    return jax.vmap(maker)(*columns)


def _contacts(a, pose_a, b, pose_b, margin):
    return jaxsat.contacts(a, pose_a, b, pose_b, margin=margin)


_batched_contacts = jax.jit(jax.vmap(_contacts), compiler_options=harness.FAST_COMPILE)


# The fast subset runs float32 (where rounding bites); float64 is in the full suite.
@pytest.mark.parametrize("dtype", [pytest.param(dtype, id=harness.DTYPE_IDS[k], marks=(
    pytest.mark.slow,) if dtype == np.float64 else ()) for k, dtype in enumerate(harness.DTYPES)])
@pytest.mark.parametrize("name", [  # one 2D scenario in the fast subset: they compile 3-8 s each
    name if name == "circle-rectangle" else pytest.param(name, marks=pytest.mark.slow)
    for name in SCENARIOS])
def test_manifolds_match_closed_forms(name, dtype):
    """Every valid point, its depth and the normal equal the hand-built manifold after a random
    rigid motion; there are no other valid points, and none where the depth is below -margin."""
    dim, scenario = SCENARIOS[name]
    rng = np.random.default_rng([11, len(name)])
    configs = scenario(rng, COUNT)
    rows_a, rows_b, rotations, shifts = _world(configs, dim, rng)
    planes = isinstance(configs[0].a, jaxsat.HalfSpace)
    a = (_stack_planes([c.a for c in configs], dtype) if planes
         else jaxsat.stack([_cast(c.a, dtype) for c in configs]))
    b = jaxsat.stack([_cast(c.b, dtype) for c in configs])
    pose_a, pose_b = _poses(rows_a, dim, dtype), _poses(rows_b, dim, dtype)
    margin = jnp.full(len(configs), MARGIN, dtype)
    if configs[0].plane_second:
        result = _batched_contacts(b, pose_b, a, pose_a, margin)
    else:
        result = _batched_contacts(a, pose_a, b, pose_b, margin)
    result = jax.tree.map(lambda leaf: np.asarray(leaf, np.float64)
                          if leaf.dtype != bool else np.asarray(leaf), result)
    assert result.points.dtype == np.float64 and result.valid.shape[1] == (2 if dim == 2 else 4)
    failures = []
    for i, config in enumerate(configs):
        rotation, shift = rotations[i], shifts[i]
        size = 2.0 + np.linalg.norm(config.translation_b)
        tol = TOLERANCE[dtype] * size
        sign = -1.0 if config.plane_second else 1.0
        expected_points = config.points @ rotation.T + shift
        expected_normal = sign * rotation @ config.normal
        valid = result.valid[i]
        got_points, got_depths = result.points[i][valid], result.depths[i][valid]
        problems = []
        if len(config.depths) and np.linalg.norm(result.normal[i] - expected_normal) > tol:
            problems.append(f"normal {result.normal[i]} != {expected_normal}")
        if len(got_depths) != len(config.depths):
            problems.append(f"{len(got_depths)} valid points, expected {len(config.depths)}")
        else:
            for point, depth in zip(expected_points, config.depths, strict=True):
                gaps = np.linalg.norm(got_points - point, axis=1)
                match = int(np.argmin(gaps))
                if gaps[match] > tol or abs(got_depths[match] - depth) > tol:
                    problems.append(f"expected point {point} depth {depth}: nearest "
                                    f"{got_points[match]} depth {got_depths[match]}")
        if problems:
            failures.append(f"config {i}: " + "; ".join(problems))
    assert not failures, f"{len(failures)} of {len(configs)} fail:\n" + "\n".join(failures[:6])
    assert 0 < np.mean([len(c.depths) > 0 for c in configs]) < 1  # both valid and none
