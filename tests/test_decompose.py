"""Tests for jaxsat.decompose (convex decomposition of simple polygons).

Every decomposition is checked by independent NumPy/SciPy code that shares nothing with the
library: shoelace areas, convexity by cross products and by SciPy's convex hull, pairwise
overlap areas by exact convex clipping (Sutherland-Hodgman), coverage by sampling with an
even-odd point-in-polygon test, and the Hertel-Mehlhorn property (no two pieces sharing an
edge have a convex union) by SciPy hull areas.
"""

from __future__ import annotations

import numpy as np
import oracle
import pytest
from scipy.spatial import ConvexHull

import jaxsat

# --------------------------------------------------------------------------------------------
# Independent geometry
# --------------------------------------------------------------------------------------------


def area(ring: np.ndarray) -> float:
    """Signed shoelace area (> 0 counter-clockwise), about the centroid to keep digits."""
    ring = ring - ring.mean(axis=0)
    following = np.roll(ring, -1, axis=0)
    return 0.5 * float(np.sum(ring[:, 0] * following[:, 1] - following[:, 0] * ring[:, 1]))


def turns(ring: np.ndarray) -> np.ndarray:
    incoming, outgoing = ring - np.roll(ring, 1, axis=0), np.roll(ring, -1, axis=0) - ring
    return incoming[:, 0] * outgoing[:, 1] - incoming[:, 1] * outgoing[:, 0]


def reflex_count(ring: np.ndarray) -> int:
    """Reflex vertices of a polygon without straight vertices, in either winding."""
    signs = np.sign(area(ring)) * turns(ring)
    return int(np.sum(signs < 0))


def clip_convex(subject: np.ndarray, clip: np.ndarray) -> np.ndarray:
    """Sutherland-Hodgman: the intersection of two counter-clockwise convex polygons."""
    output = subject
    for start, end in zip(clip, np.roll(clip, -1, axis=0), strict=True):
        if len(output) == 0:
            break
        edge = end - start
        side = edge[0] * (output[:, 1] - start[1]) - edge[1] * (output[:, 0] - start[0])
        kept = []
        for k in range(len(output)):
            current, following = output[k], output[(k + 1) % len(output)]
            s_current, s_following = side[k], side[(k + 1) % len(output)]
            if s_current >= 0:
                kept.append(current)
            if (s_current >= 0) != (s_following >= 0):
                t = s_current / (s_current - s_following)
                kept.append(current + t * (following - current))
        output = np.array(kept).reshape(-1, 2)
    return output


def boundary_distance(points: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """Distance from each point to the polygon's boundary."""
    start, end = ring[None], np.roll(ring, -1, axis=0)[None]
    direction = end - start
    t = np.clip(np.sum((points[:, None] - start) * direction, axis=-1)
                / np.sum(direction**2, axis=-1), 0.0, 1.0)
    closest = start + t[..., None] * direction
    return np.min(np.linalg.norm(points[:, None] - closest, axis=-1), axis=1)


def shared_edge(first: np.ndarray, second: np.ndarray) -> bool:
    """Whether the two pieces have an edge with the same two endpoints (a diagonal)."""
    edges = {(tuple(p), tuple(q)) for p, q in zip(first, np.roll(first, -1, axis=0), strict=True)}
    return any((tuple(q), tuple(p)) in edges
               for p, q in zip(second, np.roll(second, -1, axis=0), strict=True))


def check_decomposition(polygon: np.ndarray, pieces: list[np.ndarray], corners: np.ndarray,
                        rng: np.random.Generator, samples: int = 4000,
                        check_merges: bool = True) -> None:
    """Assert that `pieces` is a Hertel-Mehlhorn convex decomposition of `polygon`.

    `corners` are the polygon's vertices that are not on a straight edge: every piece vertex
    must be one of them. `check_merges`: also assert that no two pieces sharing a diagonal
    have a convex union (by hull area, which cannot resolve corners within ~1e-8 of straight)."""
    scale = float(np.max(np.ptp(polygon, axis=0)))
    tolerance = 1e-9 * scale**2
    total = abs(area(corners))
    assert 1 <= len(pieces) <= len(corners) - 2
    assert len(pieces) <= 2 * reflex_count(corners) + 1  # Hertel-Mehlhorn bound
    corner_set = {tuple(c) for c in corners}
    for piece in pieces:
        assert piece.dtype == np.float64 and piece.ndim == 2 and piece.shape[1] == 2
        assert len(piece) >= 3 and area(piece) > 0  # counter-clockwise, not degenerate
        assert np.all(turns(piece) > 0), "piece is not strictly convex"
        assert {tuple(p) for p in piece} <= corner_set, "piece has a vertex off the polygon"
        hull = ConvexHull(piece - piece.mean(axis=0))
        assert hull.volume == pytest.approx(area(piece), rel=1e-9, abs=tolerance)
        assert len(hull.vertices) == len(piece)
    assert sum(area(piece) for piece in pieces) == pytest.approx(total, rel=1e-9, abs=tolerance)
    for i, first in enumerate(pieces):
        for second in pieces[i + 1:]:
            overlap = clip_convex(first, second)
            assert len(overlap) < 3 or abs(area(overlap)) <= tolerance
            if check_merges and shared_edge(first, second):
                union_area = ConvexHull(np.concatenate([first, second])).volume
                assert union_area > area(first) + area(second) + tolerance, \
                    "two pieces sharing a diagonal could be merged into one convex piece"
    _check_coverage(corners, pieces, rng, samples, scale)


def _check_coverage(corners, pieces, rng, samples: int, scale: float) -> None:
    """Sample points: inside the polygon means inside exactly one piece (away from edges)."""
    low, high = corners.min(axis=0), corners.max(axis=0)
    points = rng.uniform(low, high, (samples, 2))
    margin = 1e-7 * scale
    near_any = boundary_distance(points, corners) <= margin
    for piece in pieces:
        near_any |= boundary_distance(points, piece) <= margin
    points = points[~near_any]
    in_polygon = oracle.inside_polygon(points, corners)
    hits = np.sum([oracle.inside_polygon(points, piece) for piece in pieces], axis=0)
    np.testing.assert_array_equal(hits, in_polygon.astype(int))
    assert np.count_nonzero(in_polygon) > 0


# --------------------------------------------------------------------------------------------
# Polygons
# --------------------------------------------------------------------------------------------

L_SHAPE = np.array([(0, 0), (2, 0), (2, 1), (1, 1), (1, 2), (0, 2)], float)
U_SHAPE = np.array([(0, 0), (3, 0), (3, 3), (2, 3), (2, 1), (1, 1), (1, 3), (0, 3)], float)


def star(points: int, inner: float = 0.4) -> np.ndarray:
    angles = np.pi / 2 + np.pi * np.arange(2 * points) / points
    radii = np.where(np.arange(2 * points) % 2 == 0, 1.0, inner)
    return np.stack([radii * np.cos(angles), radii * np.sin(angles)], axis=1)


def comb(teeth: int) -> np.ndarray:
    """A base 1 high with `teeth` teeth 1 wide and 2 high, 1 apart."""
    width = 2 * teeth - 1
    corners = [(0, 0), (width, 0)]
    for i in reversed(range(teeth)):
        corners += [(2 * i + 1, 3), (2 * i, 3)]
        if i > 0:
            corners += [(2 * i, 1), (2 * i - 1, 1)]
    return np.array(corners, float)


def crescent(count: int = 12) -> np.ndarray:
    """Half an annulus: a convex outer arc and a reflex chain along the inner arc."""
    angles = np.linspace(0, np.pi, count)
    outer = 2 * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    inner = np.stack([np.cos(angles), np.sin(angles)], axis=1)[::-1]
    return np.concatenate([outer, inner])


def spiral(turns_: float = 2.0, count: int = 60, width: float = 0.5) -> np.ndarray:
    """A thick spiral strip: long reflex chain on its inner side."""
    angles = np.linspace(0, 2 * np.pi * turns_, count)
    radius = 1 + angles / np.pi
    outer = (radius + width / 2)[:, None] * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    inner = (radius - width / 2)[:, None] * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    return np.concatenate([outer, inner[::-1]])


def random_star_shaped(rng: np.random.Generator, count: int, spiky: bool) -> np.ndarray:
    """Sorted angles about the origin with random radii; `spiky`: log-radius random walk."""
    gaps = rng.uniform(0.3, 1.0, count)  # no two angles closer than 0.3 / count of a turn
    angles = 2 * np.pi * np.cumsum(gaps) / np.sum(gaps) + rng.uniform(0, 2 * np.pi)
    if spiky:
        radii = np.exp(np.cumsum(rng.normal(0, 0.6, count)))
        radii = radii / radii.max() + 0.05 * (np.arange(count) % 2)
    else:
        radii = rng.uniform(0.2, 1.0, count)
    return radii[:, None] * np.stack([np.cos(angles), np.sin(angles)], axis=1)


def _segments_cross(p, q, r, s) -> bool:
    def orient(a, b, c):
        return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    return (orient(p, q, r) * orient(p, q, s) < 0) and (orient(r, s, p) * orient(r, s, q) < 0)


def random_two_opt(rng: np.random.Generator, count: int) -> np.ndarray:
    """A random simple polygon (not star-shaped in general): random points in random order,
    untangled by 2-opt moves (each removes a crossing and shortens the tour, so it ends)."""
    ring = rng.uniform(-1, 1, (count, 2))
    changed = True
    while changed:
        changed = False
        for i in range(count):
            for j in range(i + 2, count if i > 0 else count - 1):
                if _segments_cross(ring[i], ring[i + 1], ring[j], ring[(j + 1) % count]):
                    ring[i + 1:j + 1] = ring[i + 1:j + 1][::-1].copy()
                    changed = True
    return ring


NAMED = {
    "L": L_SHAPE, "U": U_SHAPE, "star3": star(3), "star5": star(5), "star8": star(8),
    "comb2": comb(2), "comb5": comb(5), "crescent": crescent(), "spiral": spiral(),
}


# --------------------------------------------------------------------------------------------
# Tests
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", sorted(NAMED))
@pytest.mark.parametrize("winding", [1, -1], ids=["ccw", "cw"])
def test_named_polygons(name, winding):
    polygon = NAMED[name][::winding]
    check_decomposition(polygon, jaxsat.decompose(polygon), polygon, np.random.default_rng(0))


@pytest.mark.parametrize("shift", range(6))
@pytest.mark.parametrize("winding", [1, -1], ids=["ccw", "cw"])
def test_known_piece_counts(shift, winding):
    """Counts for every starting vertex and both windings: optimal where the optimum is known
    (L: 2, U: 3, star with k points: at least k, since no convex piece holds two tips)."""
    def count(polygon):
        return len(jaxsat.decompose(np.roll(polygon, shift, axis=0)[::winding]))
    assert count(L_SHAPE) == 2
    assert count(U_SHAPE) == 3
    for points in (3, 5, 8):
        assert points <= count(star(points)) <= 2 * points + 1
    for teeth in (2, 3, 5):
        # Tips of different teeth cannot share a convex piece; r = 2 (teeth - 1) reflex corners.
        assert teeth <= count(comb(teeth)) <= 4 * teeth - 3


@pytest.mark.parametrize("sides", [3, 4, 7, 32])
def test_convex_polygon_is_one_piece(sides):
    angles = 2 * np.pi * np.arange(sides) / sides
    ring = np.stack([np.cos(angles), np.sin(angles)], axis=1) * 3 + [5, -2]
    for polygon in (ring, ring[::-1]):
        pieces = jaxsat.decompose(polygon)
        assert len(pieces) == 1
        assert area(pieces[0]) == pytest.approx(area(ring))
        assert {tuple(p) for p in pieces[0]} == {tuple(p) for p in ring}


def test_drops_closing_duplicate_and_straight_vertices():
    """Midpoints on edges, repeated vertices and a closing vertex change nothing: pieces use
    only true corners (and reflex corners on an inserted straight run stay reflex)."""
    rng = np.random.default_rng(1)
    for corners in (L_SHAPE, U_SHAPE, comb(3)):
        noisy = []
        for p, q in zip(corners, np.roll(corners, -1, axis=0), strict=True):
            noisy += [p, p] + [p + t * (q - p) for t in np.sort(rng.uniform(0.1, 0.9, 2))]
        noisy.append(corners[0])
        noisy = np.array(noisy)
        for winding in (1, -1):
            pieces = jaxsat.decompose(noisy[::winding])
            check_decomposition(corners, pieces, corners, rng)


def test_checker_rejects_bad_decompositions():
    """The independent checks have teeth: a bare triangulation, overlapping pieces, a missing
    piece and a non-convex piece all fail."""
    rng = np.random.default_rng(0)
    a, b, c, d, e, f = L_SHAPE
    triangles = [np.array(t) for t in ([a, b, c], [a, c, d], [a, d, f], [d, e, f])]
    overlapping = [np.array([a, b, c, d]), np.array([a, b, d, e, f])]
    missing = [np.array([a, b, c, d])]
    for pieces in (triangles, overlapping, missing, [L_SHAPE]):
        with pytest.raises(AssertionError):
            check_decomposition(L_SHAPE, pieces, L_SHAPE, rng)


@pytest.mark.parametrize("bump", [1e-4, 1e-7, 1e-8, 3e-9, 1e-12])
def test_nearly_straight_zigzag(bump):
    """Top and bottom edges zig-zag by `bump` (relative): reflex vertices almost straight.
    Below the straightness tolerance (1e-9) they are dropped and the square is one piece."""
    x = np.linspace(0, 1, 21)
    y = np.where(np.arange(21) % 2 == 0, 0.0, bump)
    polygon = np.concatenate([np.stack([x, y], 1), np.stack([x, 1 + y], 1)[::-1]])
    pieces = jaxsat.decompose(polygon)
    corners = polygon if bump > 1e-9 else np.array([[0, 0], [1, 0], [1, 1], [0, 1.0]])
    check_decomposition(polygon, pieces, corners, np.random.default_rng(0),
                        check_merges=bump > 1e-6)
    assert len(pieces) == (1 if bump < 1e-9 else 20)


def test_ear_clipping_falls_back_to_a_zero_margin():
    """The ear test keeps a safety margin; when the margin hides every ear (forced here with a
    huge one), ear clipping looks again without it and still tiles the polygon."""
    from jaxsat._decompose import _ear_clip

    ring = spiral()  # counter-clockwise, no straight vertices
    triangles = _ear_clip(ring, tolerance=0.3)
    assert len(triangles) == len(ring) - 2
    areas = [area(ring[list(triangle)]) for triangle in triangles]
    assert min(areas) > 0 and sum(areas) == pytest.approx(area(ring), rel=1e-12)


def test_list_and_integer_input():
    pieces = jaxsat.decompose([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]])
    assert len(pieces) == 2 and all(piece.dtype == np.float64 for piece in pieces)


@pytest.mark.parametrize("seed", range(6))
def test_random_star_shaped_polygons(seed):
    rng = np.random.default_rng(seed)
    for spiky in (False, True):
        polygon = random_star_shaped(rng, int(rng.integers(5, 40)), spiky)
        polygon = (polygon + rng.uniform(-100, 100, 2)) * 10.0 ** rng.uniform(-3, 3)
        for winding in (1, -1):
            check_decomposition(polygon[::winding], jaxsat.decompose(polygon[::winding]),
                                polygon, rng, samples=2000)


@pytest.mark.parametrize("seed", range(6))
def test_random_simple_polygons(seed):
    rng = np.random.default_rng(100 + seed)
    polygon = random_two_opt(rng, int(rng.integers(6, 30)))
    for winding in (1, -1):
        check_decomposition(polygon[::winding], jaxsat.decompose(polygon[::winding]), polygon,
                            rng, samples=2000)


def test_large_polygon_is_fast():
    rng = np.random.default_rng(7)
    polygon = random_star_shaped(rng, 400, spiky=False)
    pieces = jaxsat.decompose(polygon)
    assert sum(area(piece) for piece in pieces) == pytest.approx(area(polygon), rel=1e-9)
    assert len(pieces) <= 2 * reflex_count(polygon) + 1


def test_pieces_build_polygons():
    """Every piece passes jaxsat.polygon's own convexity check, in float64 and float32."""
    for polygon in (spiral(), crescent(), star(8)):
        for piece in jaxsat.decompose(polygon):
            for dtype in (np.float64, np.float32):
                assert jaxsat.polygon(piece.astype(dtype)).dtype == dtype


BAD = {
    "3d points": (np.zeros((4, 3)), "shape"),
    "flat array": (np.zeros(6), "shape"),
    "nan": ([[0, 0], [1, 0], [np.nan, 1]], "NaN"),
    "inf": ([[0, 0], [1, 0], [np.inf, 1]], "NaN or inf"),
    "two points": ([[0, 0], [1, 0], [1, 0], [0, 0]], "at least 3 distinct"),
    "empty": (np.zeros((0, 2)), "at least 3 distinct"),
    "collinear": ([[0, 0], [1, 1], [2, 2], [3, 3]], "collinear"),
    "bowtie": ([[0, 0], [1, 1], [1, 0], [0, 1]], "self-intersecting"),
    "crossing": ([[0, 0], [4, 0], [4, 4], [1, -1], [0, 4]], "self-intersecting"),
    "figure eight": ([[0, 0], [1, 1], [2, 0], [2, 1], [1, 0], [0, 1]], "self-intersecting"),
    "pinched": ([[0, 0], [2, 0], [1, 1], [2, 2], [0, 2], [1, 1]], "self-intersecting"),
    "touching": ([[0, 0], [4, 0], [4, 4], [2, 0], [0, 4]], "self-intersecting"),
    "spike": ([[0, 0], [2, 0], [2, 2], [2, 1], [0, 2]], "self-intersecting"),
    "overlapping edges": ([[0, 0], [4, 0], [4, 1], [1, 0], [0, 1]], "self-intersecting"),
}


@pytest.mark.parametrize("name", sorted(BAD))
def test_bad_polygons_raise(name):
    vertices, message = BAD[name]
    with pytest.raises(ValueError, match=message):
        jaxsat.decompose(vertices)


def test_non_numeric_vertices_raise_type_error():
    with pytest.raises(TypeError, match="numeric"):
        jaxsat.decompose([["a", "b"], ["c", "d"], ["e", "f"]])
