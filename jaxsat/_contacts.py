"""Contact manifolds: up to 2 (2D) or 4 (3D) contact points per pair, by face clipping.

Method (as in Box2D and Bullet, in a fixed-size, vmap-friendly form). The contact normal n is
`penetration`'s normal. Each shape contributes one face: a's face whose outward normal is best
aligned with +n and b's face best aligned with -n, among the faces at the shape's support
vertices along that direction (so that the face holds the deepest point). The reference face
is a's, unless b's is better aligned by a clear tolerance; the incident face is the other one.
Both faces are projected along n onto a plane across n, where clipping one against the other's
side planes leaves the overlap polygon of the two projections. Its corners are found without
sequential clipping, from a fixed candidate set: each face's corners inside the other face, and
the crossings of their edges. At each candidate the depth is the distance along n from the
incident face up to the reference face (positive where they overlap) and the reported point is
the midpoint between the two faces there. The depth is linear over the polygon, so its largest
value, at a corner, is the penetration depth for face contacts. Candidates are then reduced to
at most 4 that span the largest area.

Depth and midpoint are symmetric in the two faces, so the manifold does not depend on which one
is the reference: a reference that flips between frames (equal boxes resting on each other,
whose normal comes out of either shape's face with rounding) moves no point.

Everything is computed in a's local frame and mapped to the world at the end.

Rounded shapes. A rounded shape's surface is its core's surface moved out by the radius, so
the manifold is the cores' manifold along the rounded pair's normal (the cores' exact distance
axis, as `penetration` uses), every depth larger by r_a + r_b and every point moved by
(r_a - r_b) / 2 along the normal, to the midpoint between the two rounded surfaces. A
segment core (a capsule) offers its segment as a two-sided face: its ends and its crossings
with the other face's edges clip it, and two segments that are parallel seen along the normal
overlap on an interval (two points). A point core (a sphere) offers no face: its single
point is the midpoint of the exact witness points. The deepest point's depth is the exact
penetration depth (minus the signed distance). At the other points the depth is the cores'
gap along the normal there plus r_a + r_b: the local overlap of the rounded surfaces where
both cores' surfaces are across the normal there (parallel faces, a capsule parallel to a
face, parallel capsules); where a core's surface is tilted away from the normal, the rounded
surface lies farther out than r along the normal, and the reported point is inside it.

Half-spaces. A shape on a half-space touches it at its lowest core vertices: every real
vertex within the margin of the plane (its depth is the radius minus its height) is a
candidate, reduced like a clipped face (3D: to 4 spanning the largest area; 2D: the deepest
and the farthest from it).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxsat._closest import exact_distance, witness
from jaxsat._halfspace import HalfSpace, is_plane_pair
from jaxsat._kernels import (
    as_vec,
    chord,
    cross,
    cross2,
    dot,
    materialize,
    orthonormal_basis,
    rotate,
    safe_divide,
    segment_closest_parameters,
    total,
    where,
)
from jaxsat._pair import PairFrame, cast_pair, compiled_query, pair_frame, relative_pose
from jaxsat._poses import Pose
from jaxsat._queries import check_pair
from jaxsat._sat import sat_search
from jaxsat._shapes import Polytope

__all__ = ["Contacts", "check_margin", "contacts"]

_FACE_ANGLE = 0.02
"""3D: a face whose normal is within this angle (radians, as the chord |N - n|) of the contact
normal counts as aligned with it. If neither shape has one, the contact is edge-edge (a single
point). Well above rounding, so resting contacts with small tilts keep their full manifold."""

_TIE_ANGLE = 1e-3
"""b's face becomes the reference only if it is better aligned than a's by this angle (chord);
in the reduction to 4 points, depths that differ by less than such a tilt across the contact
count as equal."""

_LENGTH_TOLERANCE = 64
"""Length tolerance, in units of eps times the shapes' size (largest local coordinate)."""

_MIN_SLOPE = 1e-3
"""A face with |N . n| below this is seen edge-on along n: its plane gives no heights."""

_KEY = (0.8, 0.6)
"""A fixed direction across n that breaks ties between equally deep points, so that the first
point (and so the whole reduced set) does not hop between frames with rounding."""


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Contacts:
    """Result of `contacts` for one pair (fields gain leading axes under `vmap`).

    P, the number of point slots, is static: 2 in 2D and 4 in 3D.
    """

    points: jax.Array
    """(P, D) float: world-frame contact points, each the midpoint between the incident face
    and the reference face along `normal`. Invalid slots hold a copy of slot 0."""
    depths: jax.Array
    """(P,) float: penetration depth at each point along `normal` (> 0 overlapping, down to
    -margin for near points). Invalid slots hold a copy of slot 0."""
    normal: jax.Array
    """(D,) float: unit world-frame contact normal from a towards b, exactly
    `penetration(a, pose_a, b, pose_b).normal`."""
    valid: jax.Array
    """(P,) bool: True for real contact points."""


class _Details(NamedTuple):
    """What `_manifold` knows besides the contacts (world frame), for tests and debugging."""

    reference_is_b: jax.Array
    """() bool: b's face is the reference face."""
    face_normal_a: jax.Array
    """(D,) float: outward normal of a's contact face (the reference face unless
    reference_is_b)."""
    face_normal_b: jax.Array
    """(D,) float: outward normal of b's contact face."""
    single_point: jax.Array
    """() bool: one point from the closest points of two edges (3D edge-edge contact, or no
    overlap of the faces' projections) instead of face clipping."""
    depth: jax.Array
    """() float: the penetration depth."""


class _Face(NamedTuple):
    """One face in a's frame as M edge slots, counter-clockwise about its outward normal."""

    start: jax.Array
    """(M, D) float: first corner of each edge (each corner starts exactly one edge)."""
    end: jax.Array
    """(M, D) float: second corner of each edge."""
    valid: jax.Array
    """(M,) bool: real edges (unused slots hold the centroid)."""
    normal: jax.Array
    """(D,) float: outward unit normal."""
    centroid: jax.Array
    """(D,) float: a point inside the face (the mean of its edges' midpoints)."""


class _Candidates(NamedTuple):
    """Candidate contact points in a's frame."""

    points: jax.Array
    """(C, D) float: midpoints between the two faces."""
    depths: jax.Array
    """(C,) float: distance along n from the incident face up to the reference face."""
    valid: jax.Array
    """(C,) bool."""
    across: jax.Array
    """(C, D - 1) float: coordinates across n, for the reduction to the largest area."""


def _check_contacts(a, pose_a, b, pose_b, *, margin=0.0) -> None:
    check_pair(a, pose_a, b, pose_b)
    check_margin(margin)


@compiled_query(_check_contacts)
def contacts(a: Polytope, pose_a: Pose, b: Polytope, pose_b: Pose, *,
             margin=0.0) -> Contacts:
    """Contact manifold of one pair of convex shapes: up to 2 (2D) or 4 (3D) points.

    Takes sharp and rounded Polytopes and one HalfSpace (see the module docstring for rounded
    shapes and half-spaces): a sphere touches at 1 point, a capsule at up to 2, a rounded box
    or a shape on a half-space at up to 4 (3D).

    The normal is `penetration`'s. Faces: a's face whose outward normal is best aligned with
    +normal and b's face best aligned with -normal, each among the faces at that shape's
    deepest vertices. The reference face is a's, unless b's is better aligned by a clear
    tolerance (so that it does not flip between frames when the two faces tie, as for a box
    resting on an equal box); the other one is the incident face (most anti-parallel to the
    normal, and so to the reference normal up to that tolerance). The incident face is clipped
    against the side planes of the reference face, taken along the normal. Each point's depth
    is how far the incident face lies below the reference plane there, measured along the
    normal; the deepest point's depth is the penetration depth for face contacts.

    Each point is reported as the midpoint between the incident point and its projection
    along the normal onto the reference face: half its depth inside each shape's surface. It
    lies inside both shapes wherever each is at least depth/2 thick there along the normal
    (always for boxes), and within depth/2 of each shape otherwise (near a sharp rim).

    Depth and midpoint are symmetric in the two faces, so the result does not depend on
    which one is the reference. In 3D the clipped polygon is reduced to at most 4 points
    spanning the largest area: the deepest point, the farthest from it, the largest triangle,
    the largest added area. Coincident points count once. Depths within what a tilt of 1e-3
    radians across the shapes explains count as equally deep, so in near-flat contacts with
    more than 4 corners the deepest kept point can be shallower than the penetration depth by
    up to 2e-3 times the shapes' size (their largest local coordinate); this keeps the 4
    points at stable corners.

    When no face of either shape is aligned with the normal (3D edge-edge contact), the
    manifold is a single point: the midpoint of the closest points of the two edges, with the
    penetration depth. The same single point stands in if clipping finds nothing.

    Args:
      a: the first shape, unbatched (use jax.vmap for batches): a Polytope, sharp or
        rounded, or a HalfSpace.
      pose_a: the pose of a.
      b: the second shape, of the same dimension D as a; at most one of a and b is a
        HalfSpace.
      pose_b: the pose of b.
      margin: non-negative distance: points whose depth is at least -margin are valid, so that
        shapes up to `margin` apart already get (negative-depth) contacts. May be traced.

    Returns:
      Contacts in the common dtype of the inputs. No point is valid when the penetration depth
      is below -margin; a point is valid when its depth is at least -margin (within rounding).

    Raises:
      TypeError: a or b is neither a Polytope nor a HalfSpace, a pose is not a Pose, or
        margin is not a number.
      ValueError: two half-spaces, batched inputs, mixed dimensions, or a concrete margin
        that is negative, NaN or infinite.
    """
    return _manifold(a, pose_a, b, pose_b, margin)[0]


def check_margin(margin) -> None:
    """TypeError unless a number, ValueError unless finite and >= 0 (a traced margin passes)."""
    if isinstance(margin, jax.core.Tracer):
        return  # traced margins are the caller's business
    try:
        if margin is None or isinstance(margin, (str, bytes, bool, np.bool_)):
            raise TypeError
        value = np.asarray(margin, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise TypeError(f"margin must be a number, got {type(margin).__name__}") from error
    if value.shape != () or not np.isfinite(value) or value < 0:
        raise ValueError(f"margin must be a non-negative finite number, got {margin!r}")


class _Frame(NamedTuple):
    """What every step needs, in a's local frame."""

    normal: jax.Array
    """(D,) float: the contact normal n."""
    b_vertices: jax.Array
    """(V_b, D) float: b's vertices."""
    b_rotation: jax.Array
    """(D, D) float: rotation taking b's local directions into a's frame."""
    size: jax.Array
    """() float: the shapes' size (their largest local coordinate)."""
    tol: jax.Array
    """() float: length tolerance (a few eps times the size)."""
    margin: jax.Array
    """() float: the margin."""


def _manifold(a, pose_a: Pose, b, pose_b: Pose, margin=0.0) -> tuple[Contacts, _Details]:
    """`contacts` plus the faces it used (see `_Details`)."""
    check_margin(margin)
    if is_plane_pair(a, b):
        return _plane_manifold(a, pose_a, b, pose_b, margin)
    pair = pair_frame(a, pose_a, b, pose_b)
    if pair.is_rounded:
        # The cores' manifold along the rounded normal, within the margin plus the radii.
        found = materialize(exact_distance(jax.lax.stop_gradient(pair)))
        axis, core_depth = found.axis, -found.distance
        on_a = witness(found.weights, pair.a.vertices, found.index_a)
        single_point = on_a + (found.distance / 2) * axis
        radii = pair.radius_a + pair.radius_b
        frame = _frame(pair, axis, margin + radii, radii)
    else:
        found = materialize(sat_search(pair))
        axis, core_depth, single_point = found.axis, found.depth, None
        frame = _frame(pair, axis, margin, 0.0)
    clip = _polygon_contacts if pair.dim == 2 else _hull_contacts
    candidates, edges, edge_edge, face_a, face_b = clip(pair.a, pair.b, frame)
    if single_point is None:
        single_point = _closest_midpoint(*edges)
    points, depths, valid, single = _assemble(candidates, single_point, edge_edge, core_depth,
                                              frame)
    depth = core_depth
    if pair.is_rounded:
        points = points + ((pair.radius_a - pair.radius_b) / 2) * axis
        depths, depth = depths + radii, core_depth + radii
    to_world = pair.direction_to_world
    reference_is_b = (chord(face_b.normal, -frame.normal) + _TIE_ANGLE
                      < chord(face_a.normal, frame.normal))
    details = _Details(reference_is_b, to_world(face_a.normal), to_world(face_b.normal), single,
                       depth)
    return Contacts(points=pair.to_world(points), depths=depths,
                    normal=to_world(axis), valid=valid), details


def _plane_manifold(a, pose_a: Pose, b, pose_b: Pose, margin) -> tuple[Contacts, _Details]:
    """A shape on a half-space: its lowest core vertices, each with depth radius - height,
    reduced to the P slots; the lowest vertex alone when none is within the margin."""
    a, pose_a, b, pose_b = cast_pair(a, pose_a, b, pose_b)
    plane_first = isinstance(a, HalfSpace)
    plane, plane_pose, shape, shape_pose = (a, pose_a, b, pose_b) if plane_first else (
        b, pose_b, a, pose_a)
    rotation, translation = relative_pose(plane_pose, shape_pose)
    vertices = rotate(rotation, shape.vertices) + translation  # in the plane's frame
    heights = dot(vertices, plane.normal) - plane.offset
    radius = jnp.zeros((), heights.dtype) if shape.radius is None else shape.radius
    depths = radius - heights
    # Midway between the shape's surface (the vertex moved down by the radius) and the plane.
    points = vertices - ((heights + radius) / 2)[:, None] * plane.normal
    size = jnp.max(jnp.abs(vertices)) + jnp.abs(plane.offset) + radius
    tol = _LENGTH_TOLERANCE * jnp.finfo(heights.dtype).eps * size
    margin = jnp.asarray(margin, heights.dtype)
    near = shape.vertex_mask & (depths >= -margin - tol)
    if plane.dim == 2:
        across = dot(vertices, jnp.stack([-plane.normal[1], plane.normal[0]]))[:, None]
        chosen, kept = _two_widest(across[:, 0], depths, near, tol, size)
        candidates = _Candidates(points[chosen], depths[chosen], kept, across[chosen])
    else:
        first, second = orthonormal_basis(plane.normal)
        across = jnp.stack([dot(vertices, first), dot(vertices, second)], axis=-1)
        candidates = _reduce(_Candidates(points, depths, near, across), tol, size)
    lowest = jnp.argmax(where(shape.vertex_mask, depths, -jnp.inf))
    deepest = depths[lowest]
    slots = candidates.valid.shape[0]
    single = ~jnp.any(candidates.valid)
    first_slot = jnp.arange(slots) == 0
    points = where(single, points[lowest][None], candidates.points)
    valid = where(single, first_slot & (deepest >= -margin), candidates.valid)
    depths = where(single, deepest, candidates.depths)
    # Invalid slots copy slot 0, which always holds finite values.
    points = where(valid[:, None] | first_slot[:, None], points, points[0])
    depths = where(valid | first_slot, depths, depths[0])
    to_world = lambda point: rotate(plane_pose.rotation, point) + plane_pose.translation  # noqa: E731
    outward = rotate(plane_pose.rotation, plane.normal)
    normal = outward if plane_first else -outward
    details = _Details(jnp.array(not plane_first), normal, -normal, single, deepest)
    return Contacts(points=to_world(points), depths=depths, normal=normal, valid=valid), details


def _two_widest(across, depths, valid, tol, size):
    """2D reduction to 2 of many candidates: the deepest (depths within what a tilt of
    _TIE_ANGLE across the shapes explains count as equal, the tie going to the one farthest
    along the line) and the farthest from it; indices and which of the two are valid."""
    deepest = jnp.max(where(valid, depths, -jnp.inf))
    tied = valid & (depths >= deepest - tol - _TIE_ANGLE * 2 * size)
    first = jnp.argmax(where(tied, across, -jnp.inf))
    distance = where(valid, jnp.abs(across - across[first]), -1.0)
    second = jnp.argmax(distance)
    return jnp.stack([first, second]), jnp.stack([valid[first],
                                                  valid[first] & (distance[second] > tol)])


def _frame(pair: PairFrame, axis, margin, radii) -> _Frame:
    size = (jnp.maximum(jnp.max(jnp.abs(pair.a.vertices)), jnp.max(jnp.abs(pair.b.vertices)))
            + radii)
    tol = _LENGTH_TOLERANCE * jnp.finfo(pair.dtype).eps * size
    axis, b_vertices, size, tol = materialize((axis, pair.b_vertices, size, tol))
    return _Frame(axis, b_vertices, pair.rotation, size, tol, jnp.asarray(margin, pair.dtype))


def _polygon_contacts(a: Polytope, b: Polytope, frame: _Frame):
    """2D: the two contact edges, their clipped overlap (valid points first), the edges for a
    single point, and no edge-edge case."""
    face_a = _polygon_face(a.vertices, a.vertex_mask, frame.normal, frame.tol)
    face_b = _polygon_face(frame.b_vertices, b.vertex_mask, -frame.normal, frame.tol)
    candidates = _keep_near(_clip_segments(face_a, face_b, frame.normal, frame.tol), frame)
    edges = (face_a.start[0], face_a.end[0], face_b.start[0], face_b.end[0])
    return _valid_first(candidates), edges, jnp.array(False), face_a, face_b


def _hull_contacts(a: Polytope, b: Polytope, frame: _Frame):
    """3D: the two contact faces, their clipped overlap reduced to 4 points, the support edges
    for a single point, and whether the contact is edge-edge (no face aligned with n)."""
    b_normals = rotate(frame.b_rotation, b.edge_face_normals)
    (face_a, edge_a), (face_b, edge_b) = materialize((
        _hull_face(a, a.vertices, a.edge_face_normals, frame.normal, frame.tol),
        _hull_face(b, frame.b_vertices, b_normals, -frame.normal, frame.tol)))
    clipped = _clip_faces(face_a, face_b, frame.normal, frame.tol)
    parallel = _parallel_segments(face_a, face_b, frame.normal, frame.tol)
    clipped = jax.tree.map(lambda *groups: jnp.concatenate(groups), clipped, parallel)
    candidates = _reduce(materialize(_keep_near(clipped, frame)), frame.tol, frame.size)
    edge_edge = (jnp.minimum(chord(face_a.normal, frame.normal),
                             chord(face_b.normal, -frame.normal)) > _FACE_ANGLE
                 ) & ~jnp.any(parallel.valid)
    return candidates, (*edge_a, *edge_b), edge_edge, face_a, face_b


def _assemble(candidates: _Candidates, single_point, edge_edge, depth, frame: _Frame):
    """Points (a's frame), depths and validity of the P slots: the candidates, or
    `single_point` (edge-edge, or no candidate) with `depth`. Returns them and whether the
    single point was used."""
    single = edge_edge | ~jnp.any(candidates.valid)
    single_point, candidates = materialize((single_point, candidates))
    points = where(single, single_point[None], candidates.points)
    depths = where(single, depth, candidates.depths)
    first = jnp.arange(depths.shape[0]) == 0
    valid = where(single, first, candidates.valid) & (depth >= -frame.margin)
    # Invalid slots copy slot 0, which always holds finite values.
    points = where(valid[:, None] | first[:, None], points, points[0])
    depths = where(valid | first, depths, depths[0])
    return points, depths, valid, single


def _keep_near(candidates: _Candidates, frame: _Frame) -> _Candidates:
    """Candidates whose depth is at least -margin (within rounding) stay valid."""
    near = candidates.depths >= -frame.margin - frame.tol
    return candidates._replace(valid=candidates.valid & near)


# --------------------------------------------------------------------------------------------
# 2D: the contact edges and their clipping.
# --------------------------------------------------------------------------------------------


def _polygon_face(vertices, mask, direction, tol) -> _Face:
    """The edge of a counter-clockwise polygon whose outward normal is best aligned with
    `direction`, among the edges at its support vertices (within tol of the farthest along
    `direction`). Edge i joins vertex i and i + 1, the rolled vertices (see `Polytope`)."""
    ends = jnp.roll(vertices, -1, axis=0)
    support = dot(vertices, direction)
    near = support >= jnp.max(support) - tol
    edges = ends - vertices
    squared = dot(edges, edges)
    real = mask & (squared > 0)  # padding edges have zero length
    normals = jnp.stack([edges[:, 1], -edges[:, 0]], axis=-1)
    normals = normals * jax.lax.rsqrt(where(real, squared, 1.0))[:, None]
    at_support = real & (near | jnp.roll(near, -1))
    best = jnp.argmax(where(at_support, dot(normals, direction), -jnp.inf))
    start, end = vertices[best], ends[best]
    return _Face(start[None], end[None], jnp.ones(1, bool), normals[best], (start + end) / 2)


def _point_at(face: _Face, across, tangent, normal, deeper: float):
    """Points of a segment face at coordinates `across` (along `tangent`), clamped to the
    segment. A segment seen end-on (parallel to the normal) gives its endpoint farthest along
    deeper * normal, the end that touches the other shape first."""
    start, end = face.start[0], face.end[0]
    first, span = dot(start, tangent), dot(end - start, tangent)
    ok = jnp.abs(span) > 0
    fraction = jnp.clip(safe_divide(across - first, span, ok), 0.0, 1.0)
    end_on = where(deeper * dot(end - start, normal) > 0, 1.0, 0.0)
    fraction = where(ok, fraction, end_on)
    return start + fraction[:, None] * (end - start)


def _clip_segments(face_a: _Face, face_b: _Face, normal, tol) -> _Candidates:
    """Overlap of the two contact edges seen along the normal: its two ends, lifted onto each
    edge. (Clipping the incident edge against the reference edge's side planes gives the same
    interval.)"""
    tangent = jnp.stack([-normal[1], normal[0]])
    ends_a = dot(jnp.stack([face_a.start[0], face_a.end[0]]), tangent)
    ends_b = dot(jnp.stack([face_b.start[0], face_b.end[0]]), tangent)
    low = jnp.maximum(jnp.min(ends_a), jnp.min(ends_b))
    high = jnp.minimum(jnp.max(ends_a), jnp.max(ends_b))
    overlap = high >= low - tol
    middle = (low + high) / 2
    across = jnp.stack([jnp.minimum(low, middle), jnp.maximum(high, middle)])
    on_a = _point_at(face_a, across, tangent, normal, 1.0)
    on_b = _point_at(face_b, across, tangent, normal, -1.0)
    valid = overlap & jnp.stack([jnp.array(True), across[1] - across[0] > tol])
    return _Candidates(points=(on_a + on_b) / 2, depths=dot(on_a - on_b, normal), valid=valid,
                       across=across[:, None])


def _valid_first(candidates: _Candidates) -> _Candidates:
    """The two 2D candidates, swapped if only the second is valid."""
    order = where(candidates.valid[0], jnp.arange(2), jnp.arange(2)[::-1])
    return jax.tree.map(lambda field: field[order], candidates)


# --------------------------------------------------------------------------------------------
# 3D: the contact faces from the hull edges.
# --------------------------------------------------------------------------------------------


def _num_slots(shape: Polytope) -> int:
    """Static bound on the edges of one face: 4 for a parallelepiped (at most 3 unique edge
    directions), else one less than the vertex count (a face with every vertex would be flat)."""
    if shape.is_parallelepiped:
        return 4
    return max(min(shape.edge_endpoints.shape[0], shape.vertices.shape[0] - 1), 3)


def _first_true(mask, count: int):
    """Indices of the first `count` True entries of a 1D mask (0 past the last), and which of
    them exist. (jnp.nonzero, a cumsum and a scatter, measured faster on CPU than ranking by
    element-wise comparisons, even for a box's 12 edges.)"""
    index = jnp.nonzero(mask, size=count, fill_value=0)[0]
    return index, jnp.arange(count) < jnp.sum(mask.astype(jnp.int32))


def _hull_face(shape: Polytope, vertices, face_normals, direction, tol):
    """The face of a hull whose outward normal is best aligned with `direction`, among the
    faces at its support vertices, as edge slots counter-clockwise about that normal; and the
    hull edge farthest along `direction` (its two ends): the shape's edge in an edge-edge
    contact. vertices (V, 3) and face_normals (K, 2, 3) are in a's frame."""
    # One gather of every edge's ends; the rest is element-wise or gathers of a few rows.
    ends = vertices[shape.edge_endpoints]  # (K, 2, 3)
    support = dot(ends, direction)  # (K, 2)
    at_support = shape.hull_edge_mask & jnp.any(support >= jnp.max(support) - tol, axis=1)
    alignment = where(at_support[:, None], dot(face_normals, direction), -jnp.inf)
    best = jnp.argmax(alignment.reshape(-1))  # over (edge, side) pairs
    top = jnp.argmax(where(shape.hull_edge_mask, jnp.min(support, axis=1), -jnp.inf))
    face = _face_slots(shape, ends, best, face_normals.reshape(-1, 3)[best])
    return face, (ends[top, 0], ends[top, 1])


def _face_slots(shape: Polytope, ends, best, normal) -> _Face:
    """The face whose normal is stored at flattened (edge, side) `best`, as edge slots.

    A hull edge belongs to the face when exactly one of its two stored face normals equals the
    face's (both: an edge inside a face, which the constructors never store). The constructors
    store one value per face, so equal means identical; the test runs on the stored normals,
    before any rotation."""
    stored = shape.edge_face_normals
    difference = stored - stored.reshape(-1, 3)[best]
    eps = jnp.finfo(ends.dtype).eps
    same = dot(difference, difference) <= (16 * eps) ** 2
    on_face = shape.hull_edge_mask & (same[:, 0] != same[:, 1])
    index, valid = _first_true(on_face, _num_slots(shape))
    start, end = ends[index, 0], ends[index, 1]
    count = jnp.maximum(jnp.sum(valid), 1).astype(ends.dtype)
    centroid = jnp.sum(where(valid[:, None], start + end, 0.0), axis=0) / (2 * count)
    # Each edge runs counter-clockwise about the normal if its outward side faces away from
    # the centroid; swapping the others makes every corner start exactly one edge.
    outward = dot(cross(end - start, normal), start - centroid)
    # A segment core's face is its segment twice (a two-sided face): the centroid lies on
    # both edges, and they are made to run opposite ways by their order instead.
    length = jnp.sqrt(dot(end - start, end - start) * dot(start - centroid, start - centroid))
    on_line = jnp.abs(outward) <= 64 * jnp.finfo(ends.dtype).eps * length
    forward = where(on_line, jnp.arange(valid.shape[0]) % 2 == 0, outward > 0)[:, None]
    start, end = where(forward, start, end), where(forward, end, start)
    start = where(valid[:, None], start, centroid)
    end = where(valid[:, None], end, centroid)
    return _Face(start, end, valid, normal, centroid)


def _inside(face_start, face_edge, face: _Face, sense, points, tol):
    """(N,) whether 2D points lie inside a face projected across the normal: on the inner side
    of each real edge (within tol). `sense` is +1 if the projection keeps the face's
    counter-clockwise order (N . n > 0), else -1."""
    # Counter-clockwise edges have the inside on their left: a positive cross product.
    inward = sense * cross2(face_edge[None], points[:, None] - face_start[None])
    length = jnp.sqrt(dot(face_edge, face_edge))
    return jnp.all(~face.valid | (inward >= -tol * length), axis=1)


def _lift(face: _Face, points, normal):
    """Signed distance along the normal from points to a face's plane, and where it is defined
    (the face is not seen edge-on)."""
    slope = dot(face.normal, normal)
    ok = jnp.abs(slope) > _MIN_SLOPE
    return safe_divide(dot(face.normal, face.centroid - points), slope, ok), ok


def _clip_faces(face_a: _Face, face_b: _Face, normal, tol) -> _Candidates:
    """Corners of the overlap of the two faces seen along the normal, as fixed-size candidates:
    a's corners inside b's face, b's corners inside a's face, and crossings of their edges."""
    first, second = orthonormal_basis(normal)
    across = lambda p: jnp.stack([dot(p, first), dot(p, second)], axis=-1)  # noqa: E731
    start_a, start_b = across(face_a.start), across(face_b.start)
    edge_a, edge_b = across(face_a.end) - start_a, across(face_b.end) - start_b
    start_a, start_b, edge_a, edge_b = materialize((start_a, start_b, edge_a, edge_b))
    one = jnp.ones((), normal.dtype)
    corners_a = _corners_inside(face_a, start_a, face_b, start_b, edge_b, normal, tol, one)
    corners_b = _corners_inside(face_b, start_b, face_a, start_a, edge_a, normal, tol, -one)
    crossings = _crossings(face_a, face_b, start_a, edge_a, start_b, edge_b, normal)
    return jax.tree.map(lambda *groups: jnp.concatenate(groups), corners_a, corners_b, crossings)


def _corners_inside(face: _Face, start, other: _Face, other_start, other_edge, normal, tol,
                    side) -> _Candidates:
    """A face's corners (2D `start`) inside the other face seen along the normal, lifted onto
    the other face's plane. side = +1 for a's corners, -1 for b's (the depth is how far a's
    point is above b's along the normal)."""
    height, ok = _lift(other, face.start, normal)
    sense = where(dot(other.normal, normal) > 0, 1.0, -1.0)
    # Only a polygon (3 edges or more) has an inside: a segment core's two-sided face or a
    # point core's empty one contains no corner of the other face (where such a corner lies
    # on the segment, it is a crossing of the two faces' edges).
    polygon = jnp.sum(other.valid) >= 3
    valid = (face.valid & ok & polygon
             & _inside(other_start, other_edge, other, sense, start, tol))
    return _Candidates(points=face.start + (height / 2)[:, None] * normal,
                       depths=-side * height, valid=valid, across=start)


def _crossings(face_a: _Face, face_b: _Face, start_a, edge_a, start_b, edge_b,
               normal) -> _Candidates:
    """Every crossing of an edge of a's face with an edge of b's face, seen along the normal,
    (M_a M_b) candidates: the point on each edge, their midpoint and their distance."""
    denominator = cross2(edge_a[:, None], edge_b[None, :])
    offset = start_b[None, :] - start_a[:, None]
    eps = jnp.finfo(denominator.dtype).eps
    scale = dot(edge_a, edge_a)[:, None] * dot(edge_b, edge_b)[None, :]
    ok = denominator * denominator > (16 * eps) ** 2 * scale
    along_a = safe_divide(cross2(offset, edge_b[None, :]), denominator, ok)
    along_b = safe_divide(cross2(offset, edge_a[:, None]), denominator, ok)
    ok = (ok & (along_a >= 0) & (along_a <= 1) & (along_b >= 0) & (along_b <= 1)
          & face_a.valid[:, None] & face_b.valid[None, :])
    on_a = face_a.start[:, None] + along_a[..., None] * (face_a.end - face_a.start)[:, None]
    on_b = face_b.start[None, :] + along_b[..., None] * (face_b.end - face_b.start)[None, :]
    dim = on_a.shape[-1]
    return _Candidates(points=((on_a + on_b) / 2).reshape(-1, dim),
                       depths=dot(on_a - on_b, normal).reshape(-1), valid=ok.reshape(-1),
                       across=(start_a[:, None] + along_a[..., None] * edge_a[:, None])
                       .reshape(-1, 2))


def _parallel_segments(face_a: _Face, face_b: _Face, normal, tol) -> _Candidates:
    """Two candidates where both faces are segments (two-sided faces of capsule cores) that
    are parallel seen along the normal (within _FACE_ANGLE): the ends of the interval where
    they overlap, lifted onto each segment (as `_clip_segments` in 2D); none otherwise."""
    start_a, end_a, start_b, end_b = face_a.start[0], face_a.end[0], face_b.start[0], face_b.end[0]
    across_a = (end_a - start_a) - dot(end_a - start_a, normal) * normal
    across_b = (end_b - start_b) - dot(end_b - start_b, normal) * normal
    length_a = jnp.sqrt(dot(across_a, across_a))
    length_b = jnp.sqrt(dot(across_b, across_b))
    crossing = jnp.sqrt(dot(cross(across_a, across_b), cross(across_a, across_b)))
    segments = (jnp.sum(face_a.valid) == 2) & (jnp.sum(face_b.valid) == 2)
    parallel = segments & (crossing <= _FACE_ANGLE * length_a * length_b) & (length_a > tol)
    tangent = safe_divide(across_a, length_a, length_a > tol)
    ends_a = jnp.stack([dot(start_a, tangent), dot(end_a, tangent)])
    ends_b = jnp.stack([dot(start_b, tangent), dot(end_b, tangent)])
    low = jnp.maximum(jnp.min(ends_a), jnp.min(ends_b))
    high = jnp.minimum(jnp.max(ends_a), jnp.max(ends_b))
    middle = (low + high) / 2
    across = jnp.stack([jnp.minimum(low, middle), jnp.maximum(high, middle)])
    on_a = _point_at(face_a, across, tangent, normal, 1.0)
    on_b = _point_at(face_b, across, tangent, normal, -1.0)
    first, second = orthonormal_basis(normal)
    flat = lambda p: jnp.stack([dot(p, first), dot(p, second)], axis=-1)  # noqa: E731
    valid = parallel & (high >= low - tol) & jnp.stack([jnp.array(True),
                                                        across[1] - across[0] > tol])
    return _Candidates(points=(on_a + on_b) / 2, depths=dot(on_a - on_b, normal), valid=valid,
                       across=flat((on_a + on_b) / 2))


# --------------------------------------------------------------------------------------------
# 3D: reduction to 4 points, and the single point of an edge-edge contact.
# --------------------------------------------------------------------------------------------


def _reduce(candidates: _Candidates, tol, size) -> _Candidates:
    """At most 4 candidates spanning the largest area: the deepest, the farthest from it, the
    one making the largest triangle with those two, and the one adding the most area to that
    triangle. Depths within what a tilt of _TIE_ANGLE across the shapes (2 * size) explains
    count as equally deep, the tie going to the candidate farthest along a fixed direction. A
    step that adds no length or area beyond tol (coincident or collinear candidates) leaves
    its slot invalid."""
    valid, depths, across = candidates.valid, candidates.depths, candidates.across
    deepest = jnp.max(where(valid, depths, -jnp.inf))
    # Depths that a tilt of _TIE_ANGLE across the shapes explains count as equal: in a
    # near-flat contact the deepest point could be a sliver corner (where two nearly parallel
    # edges cross) that rounding or tiny tilts move from frame to frame.
    slack = tol + _TIE_ANGLE * 2 * size
    tied = valid & (depths >= deepest - slack)
    first = jnp.argmax(where(tied, _KEY[0] * across[:, 0] + _KEY[1] * across[:, 1],
                                 -jnp.inf))
    offset = across - across[first]
    distance = where(valid, dot(offset, offset), -1.0)
    second = jnp.argmax(distance)
    length = jnp.sqrt(jnp.maximum(distance[second], 0.0))
    third, fourth, has_third, has_fourth = _widest(across, valid, first, second, tol * length)
    chosen = jnp.stack([first, second, third, fourth])
    has_second = length > tol
    return _Candidates(points=candidates.points[chosen], depths=depths[chosen],
                       valid=jnp.stack([valid[first], has_second, has_second & has_third,
                                        has_second & has_third & has_fourth]),
                       across=across[chosen])


def _widest(across, valid, first, second, min_area):
    """The candidate making the largest triangle with `first` and `second`, the one adding the
    most area to that triangle (area as twice the area), and whether each adds over min_area."""
    p1, p2 = across[first], across[second]
    area = where(valid, jnp.abs(cross2(p2 - p1, across - p1)), -1.0)
    third = jnp.argmax(area)
    p3 = across[third]
    orientation = where(cross2(p2 - p1, p3 - p1) >= 0, 1.0, -1.0)
    # A point outside the triangle adds the triangles it forms with the edges it sees.
    added = total(jnp.maximum(-orientation * cross2(end - start, across - start), 0.0)
                  for start, end in ((p1, p2), (p2, p3), (p3, p1)))
    added = where(valid, added, -1.0)
    fourth = jnp.argmax(added)
    return third, fourth, area[third] > min_area, added[fourth] > min_area


def _closest_midpoint(start_1, end_1, start_2, end_2):
    """Midpoint of the closest points of two segments (`_kernels.segment_closest_parameters`)."""
    d1, d2, r = end_1 - start_1, end_2 - start_2, start_1 - start_2
    s, t, _ = segment_closest_parameters(as_vec(r), as_vec(d1), as_vec(d2))
    return (start_1 + s * d1 + start_2 + t * d2) / 2
