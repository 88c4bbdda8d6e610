"""jaxsat.cap_hull: a hull of at most K vertices that contains a point cloud's hull, with its
added volume, checked against scipy's ConvexHull (an independent hull and volume)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull

import jaxsat


def fibonacci_sphere(count: int) -> np.ndarray:
    """`count` points spread over the unit sphere, every one a hull vertex."""
    index = np.arange(count) + 0.5
    polar = np.arccos(1 - 2 * index / count)
    azimuth = np.pi * (1 + 5**0.5) * index
    return np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar),
                     np.cos(polar)], axis=1)


CLOUDS = {
    "sphere42-to-16": (fibonacci_sphere(42), 16),
    "gaussian200-to-12": (np.random.default_rng(0).normal(size=(200, 3)), 12),
    "ellipsoid300-to-20": (fibonacci_sphere(300) * [3.0, 1.0, 0.2], 20),
    "tiny-far-sphere60-to-8": (1e-3 * fibonacci_sphere(60) + [1e3, 0.0, 0.0], 8),
    "sphere162-to-32": (fibonacci_sphere(162), 32),
}


@pytest.mark.parametrize("name", [pytest.param(name, marks=pytest.mark.slow)
                                  if name in ("sphere162-to-32", "ellipsoid300-to-20") else name
                                  for name in CLOUDS])
def test_capped_hull_fits_contains_the_points_and_reports_its_added_volume(name):
    points, max_vertices = CLOUDS[name]
    capped = jaxsat.cap_hull(points, max_vertices)
    assert 4 <= len(capped.vertices) <= max_vertices
    size = np.max(np.ptp(points, axis=0))
    hull = ConvexHull(capped.vertices)
    outside = points @ hull.equations[:, :3].T + hull.equations[:, 3]
    assert np.max(outside) <= 1e-9 * size, np.max(outside)
    original = ConvexHull(points).volume
    np.testing.assert_allclose(capped.volume, original, rtol=1e-9)
    np.testing.assert_allclose(capped.added_volume, hull.volume - original, rtol=1e-6,
                               atol=1e-12 * size**3)
    assert capped.added_volume > 0
    assert jaxsat.polyhedron(capped.vertices, max_vertices=max_vertices).size_class == \
        jaxsat.polyhedron(fibonacci_sphere(4), max_vertices=max_vertices).size_class


def test_a_hull_that_fits_is_returned_unchanged():
    points = np.random.default_rng(1).normal(size=(40, 3))
    hull = ConvexHull(points)
    capped = jaxsat.cap_hull(points, len(hull.vertices))
    assert capped.added_volume == 0.0
    np.testing.assert_allclose(capped.volume, hull.volume, rtol=1e-9)
    assert {tuple(v) for v in capped.vertices} == {tuple(v) for v in points[hull.vertices]}


def test_polyhedron_points_to_cap_hull_when_a_hull_does_not_fit():
    with pytest.raises(ValueError, match="cap_hull"):
        jaxsat.polyhedron(fibonacci_sphere(42), max_vertices=16)
    with pytest.raises(ValueError, match=r"max_vertices=8$"):  # no 2D cap_hull to point to
        jaxsat.regular_polygon(12, max_vertices=8)


@pytest.mark.parametrize(("points", "max_vertices", "error", "message"), [
    (fibonacci_sphere(20), 3, ValueError, "max_vertices must be an integer >= 4"),
    (fibonacci_sphere(20), 6.5, ValueError, "max_vertices must be an integer >= 4"),
    (np.full((5, 3), np.nan), 8, ValueError, "NaN or inf"),
    (np.zeros((5, 2)), 8, ValueError, r"shape \(N, 3\)"),
    ([["a", "b", "c"]], 8, TypeError, "numeric"),
    (np.eye(3), 8, ValueError, "at least 4 distinct points"),
], ids=["below-a-tetrahedron", "not-an-integer", "nan", "2d", "strings", "too-few-points"])
def test_bad_input_raises_a_clear_error(points, max_vertices, error, message):
    with pytest.raises(error, match=message):
        jaxsat.cap_hull(points, max_vertices)
