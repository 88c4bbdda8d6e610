"""Convex decomposition of simple polygons: ear clipping, then Hertel-Mehlhorn merging.

Eager NumPy in float64 (never traced by JAX). Ear clipping triangulates the polygon with
diagonals between its own vertices; Hertel-Mehlhorn then deletes every diagonal whose removal
leaves a convex piece. Each remaining diagonal is essential at a reflex vertex, and a reflex
vertex keeps at most two of them, so a polygon with r reflex vertices gives at most 2r + 1
pieces, at most 4 times the optimum without Steiner points (Hertel and Mehlhorn, 1983).
"""

from __future__ import annotations

import numpy as np

from jaxsat import _geometry as geometry

__all__ = ["decompose"]

MERGE_SINE_TOLERANCE = 1e-10
"""A merged corner may turn the wrong way by at most this sine and still count as convex: far
below what `jaxsat.polygon` rejects (1e-9), so every piece it returns passes that check."""

ROW_CHUNK = 64
"""Edges tested at a time by the O(N^2) self-intersection test, to bound its memory."""


def decompose(polygon_vertices) -> list[np.ndarray]:
    """Split a simple, possibly concave polygon into convex pieces.

    Args:
      polygon_vertices: (N, 2) array-like of the polygon's vertices in either winding order.
        A repeated closing vertex, consecutive duplicates and vertices on a straight edge are
        dropped.

    Returns:
      A list of (M_i, 2) float64 arrays, each a convex piece with counter-clockwise vertices
      taken from the polygon's own vertices (no Steiner points) and no straight vertices. The
      pieces tile the polygon: they cover it and overlap only along shared edges. A convex
      polygon gives one piece; a polygon with r reflex vertices gives at most 2r + 1 pieces
      (at most 4 times the fewest possible). Pass them to `jaxsat.compound`, or use
      `jaxsat.concave_polygon`, which does both.

    Raises:
      TypeError: non-numeric vertices.
      ValueError: wrong shape, NaN/inf, fewer than 3 distinct vertices, zero area (collinear
        vertices), or a self-intersecting (or self-touching) boundary.
    """
    ring = _counter_clockwise_ring(geometry.as_point_array(polygon_vertices, 2,
                                                           "polygon vertices"))
    tolerance = geometry.tolerance_for(ring)
    _check_simple(ring, tolerance)
    if np.all(_turns(ring) > 0):
        return [ring.copy()]
    pieces = _merge_convex(ring, _ear_clip(ring, tolerance))
    return [_drop_straight(ring[piece], tolerance) for piece in pieces]


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """2D cross product u x v over the last axis."""
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def _turns(ring: np.ndarray) -> np.ndarray:
    """Cross product of the incoming and outgoing edge at each vertex (> 0: convex corner)."""
    return _cross(ring - np.roll(ring, 1, axis=0), np.roll(ring, -1, axis=0) - ring)


def _counter_clockwise_ring(points: np.ndarray) -> np.ndarray:
    """The boundary without consecutive duplicates or straight vertices, counter-clockwise."""
    ring = points[np.any(points != np.roll(points, 1, axis=0), axis=1)]
    distinct = len(geometry.distinct_points(ring))
    if distinct < 3:
        raise ValueError(f"a polygon needs at least 3 distinct vertices, got {distinct}")
    tolerance = geometry.tolerance_for(ring)
    centred = ring - ring.mean(axis=0)
    if np.linalg.svd(centred, compute_uv=False)[1] <= tolerance * np.sqrt(len(ring)):
        raise ValueError("polygon vertices are collinear: the polygon has zero area")
    ring = _drop_straight(ring, tolerance)
    area = 0.5 * np.sum(_cross(ring, np.roll(ring, -1, axis=0)))
    extent = float(np.max(np.ptp(ring, axis=0)))
    if abs(area) <= tolerance * extent:
        raise ValueError("polygon has zero area (its boundary is self-intersecting or doubles "
                         "back on itself)")
    return ring if area > 0 else ring[::-1].copy()


def _drop_straight(ring: np.ndarray, tolerance: float) -> np.ndarray:
    """Remove vertices lying on the segment between their neighbours (180-degree turns).

    Vertices where the boundary reverses (0-degree turns) stay: `_check_simple` rejects them.
    Each pass drops every other vertex of each straight run, so that every dropped vertex was
    tested against the neighbours it really had (a gentle curve is not flattened by the
    tolerance piling up)."""
    while len(ring) > 3:
        previous, following = np.roll(ring, 1, axis=0), np.roll(ring, -1, axis=0)
        incoming, outgoing = ring - previous, following - ring
        chord = np.linalg.norm(following - previous, axis=1)
        straight = ((np.abs(_cross(incoming, outgoing)) <= tolerance * chord)
                    & (np.sum(incoming * outgoing, axis=1) > 0))
        if not np.any(straight) or np.all(straight):
            break
        drop = np.roll(_every_other_in_runs(np.roll(straight, -int(np.argmin(straight)))),
                       int(np.argmin(straight)))
        if len(ring) - np.count_nonzero(drop) < 3:
            break
        ring = ring[~drop]
    return ring


def _every_other_in_runs(flags: np.ndarray) -> np.ndarray:
    """The 1st, 3rd, 5th, ... entry of every run of True in `flags` (whose entry 0 is False)."""
    positions = np.arange(len(flags))
    run_starts = flags & ~np.roll(flags, 1)
    start_of_run = np.maximum.accumulate(np.where(run_starts, positions, 0))
    return flags & ((positions - start_of_run) % 2 == 0)


def _check_simple(ring: np.ndarray, tolerance: float) -> None:
    """Raise unless no two edges meet except adjacent ones at their shared vertex.

    O(N^2) segment tests, vectorised over chunks of edges. Edges closer than `tolerance` count
    as meeting, so a vertex touching another edge is rejected too (ear clipping needs a
    polygon that is simple by a margin)."""
    count = len(ring)
    starts, ends = ring, np.roll(ring, -1, axis=0)
    incoming, outgoing = ring - np.roll(ring, 1, axis=0), ends - ring
    reversals = (np.abs(_cross(incoming, outgoing)) <= tolerance * np.linalg.norm(
        incoming, axis=1)) & (np.sum(incoming * outgoing, axis=1) < 0)
    if np.any(reversals):
        where = ring[int(np.argmax(reversals))].tolist()
        raise ValueError(f"polygon is self-intersecting: its boundary doubles back on itself at "
                         f"{where}")
    index = np.arange(count)
    for first in range(0, count, ROW_CHUNK):
        rows = index[first:first + ROW_CHUNK, None]
        # Pairs (i, j) with j > i + 1, and not the closing pair (0, N - 1): non-adjacent edges.
        candidates = (index[None, :] > rows + 1) & ~((rows == 0) & (index[None, :] == count - 1))
        distances = _segment_distances(starts[rows], ends[rows], starts[None], ends[None])
        meeting = candidates & (distances <= tolerance)
        if np.any(meeting):
            i, j = np.argwhere(meeting)[0]
            edges = [[starts[k].tolist(), ends[k].tolist()] for k in (first + i, j)]
            raise ValueError(f"polygon is self-intersecting: edges {edges[0]} and {edges[1]} "
                             "meet")


def _segment_distances(p0, p1, q0, q1) -> np.ndarray:
    """Distances between segments [p0, p1] and [q0, q1] (broadcast (..., 2) arrays)."""
    d_p, d_q = p1 - p0, q1 - q0
    side_q0, side_q1 = _cross(d_p, q0 - p0), _cross(d_p, q1 - p0)
    side_p0, side_p1 = _cross(d_q, p0 - q0), _cross(d_q, p1 - q0)
    crossing = (side_q0 * side_q1 < 0) & (side_p0 * side_p1 < 0)
    endpoint = np.minimum(np.minimum(_point_segment(p0, q0, q1), _point_segment(p1, q0, q1)),
                          np.minimum(_point_segment(q0, p0, p1), _point_segment(q1, p0, p1)))
    return np.where(crossing, 0.0, endpoint)


def _point_segment(point, start, end) -> np.ndarray:
    """Distance from points to segments [start, end] (broadcast (..., 2) arrays)."""
    direction = end - start
    length_squared = np.sum(direction**2, axis=-1)
    along = np.sum((point - start) * direction, axis=-1) / np.maximum(length_squared, 1e-300)
    closest = start + np.clip(along, 0.0, 1.0)[..., None] * direction
    return np.linalg.norm(point - closest, axis=-1)


def _ear_clip(ring: np.ndarray, tolerance: float) -> list[tuple[int, int, int]]:
    """Counter-clockwise triangles (vertex index triples) of a simple counter-clockwise ring.

    A doubly linked list of the remaining vertices; only the two neighbours of a clipped ear
    change status, so the whole triangulation costs O(N^2)."""
    count = len(ring)
    previous, following = np.roll(np.arange(count), 1), np.roll(np.arange(count), -1)
    alive = np.ones(count, bool)
    is_ear = np.array([_is_ear(ring, alive, previous[i], i, following[i], tolerance)
                       for i in range(count)])
    triangles, current = [], 0
    for _ in range(count - 3):  # each clip removes one vertex; the last 3 form the last ear
        current = _next_ear(ring, alive, is_ear, previous, following, current, tolerance)
        before, after = previous[current], following[current]
        triangles.append((int(before), int(current), int(after)))
        alive[current] = is_ear[current] = False
        following[before], previous[after] = after, before
        for vertex in (before, after):
            is_ear[vertex] = _is_ear(ring, alive, previous[vertex], vertex, following[vertex],
                                     tolerance)
        current = after
    first = int(np.argmax(alive))
    triangles.append((int(previous[first]), first, int(following[first])))
    return triangles


def _next_ear(ring, alive, is_ear, previous, following, start: int, tolerance: float) -> int:
    """The first ear at or after `start` along the remaining boundary.

    A simple polygon always has two ears, but the safety margin `tolerance` can hide them all
    where sharp corners crowd each other; then the ears are looked for again without it."""
    ear = _first_flagged(is_ear, following, start, np.count_nonzero(alive))
    if ear is None:
        for vertex in np.flatnonzero(alive):
            is_ear[vertex] = _is_ear(ring, alive, previous[vertex], vertex, following[vertex], 0.0)
        ear = _first_flagged(is_ear, following, start, np.count_nonzero(alive))
    if ear is None:
        raise ValueError("polygon could not be triangulated: it is too close to degenerate (a "
                         "vertex lies almost on a non-adjacent edge)")
    return ear


def _first_flagged(flags, following, start: int, count: int) -> int | None:
    """The first vertex at or after `start`, following the linked list, whose flag is set."""
    vertex = start
    for _ in range(count):
        if flags[vertex]:
            return vertex
        vertex = following[vertex]
    return None


def _is_ear(ring, alive, before: int, vertex: int, after: int, tolerance: float) -> bool:
    """Whether the triangle (before, vertex, after) is a strictly convex corner (its apex more
    than `tolerance` off the chord) containing no other remaining vertex, not even within
    `tolerance` of its boundary (such a vertex would lie on the new diagonal)."""
    a, b, c = ring[before], ring[vertex], ring[after]
    if _cross(b - a, c - a) <= tolerance * np.linalg.norm(c - a):
        return False
    others = alive.copy()
    others[[before, vertex, after]] = False
    points = ring[others]
    # Signed distances of the points from each side's line, positive inside.
    inside = np.ones(len(points), bool)
    for start, end in ((a, b), (b, c), (c, a)):
        side = end - start
        inside &= _cross(side, points - start) >= -tolerance * np.linalg.norm(side)
    return not np.any(inside)


def _merge_convex(ring: np.ndarray, triangles) -> list[list[int]]:
    """Hertel-Mehlhorn: merge the triangles across every diagonal whose removal keeps the
    merged piece convex. Pieces are counter-clockwise vertex index cycles."""
    pieces = {piece: list(triangle) for piece, triangle in enumerate(triangles)}
    owner = {}  # directed edge (u, v) -> piece that has it on its boundary
    for piece, cycle in pieces.items():
        for u, v in zip(cycle, np.roll(cycle, -1).tolist(), strict=True):
            owner[(u, v)] = piece
    diagonals = [(u, v) for (u, v) in owner if u < v and (v, u) in owner]
    for u, v in diagonals:
        left, right = owner[(u, v)], owner[(v, u)]
        merged = _joined(pieces[left], pieces[right], u, v)
        if not _convex_at(ring, merged, (u, v)):
            continue
        del pieces[right]
        pieces[left] = merged
        del owner[(u, v)], owner[(v, u)]
        for edge in zip(merged, merged[1:] + merged[:1], strict=True):
            owner[edge] = left
    return list(pieces.values())


def _joined(left: list[int], right: list[int], u: int, v: int) -> list[int]:
    """The cycle of two pieces glued along the diagonal: `left` has edge u -> v, `right` v -> u."""
    start = left.index(v)
    left_path = left[start:] + left[:start]  # v ... u
    start = right.index(u)
    right_path = right[start:] + right[:start]  # u ... v
    return left_path + right_path[1:-1]


def _convex_at(ring: np.ndarray, cycle: list[int], vertices) -> bool:
    """Whether the piece `cycle` turns left (or goes straight) at each of `vertices`."""
    for vertex in vertices:
        position = cycle.index(vertex)
        before, after = ring[cycle[position - 1]], ring[cycle[(position + 1) % len(cycle)]]
        incoming, outgoing = ring[vertex] - before, after - ring[vertex]
        scale = np.linalg.norm(incoming) * np.linalg.norm(outgoing)
        if _cross(incoming, outgoing) < -MERGE_SINE_TOLERANCE * scale:
            return False
    return True
