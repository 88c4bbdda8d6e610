"""Concave meshes as compounds (`mesh_compound`, `load_mesh`; the `mesh` extra), against SciPy.

The mesh: an L-shaped prism (the L of 2 x 2 minus its 1 x 1 corner, 1 high), written out
triangle by triangle, so its solid and its notch are known by hand.
"""

from __future__ import annotations

import sys

import numpy as np
import oracle
import pytest
from scipy.spatial import ConvexHull

import jaxsat

pytest.importorskip("coacd")

RING = np.array([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], float)
L_VERTICES = np.concatenate([np.c_[RING, np.zeros(6)], np.c_[RING, np.ones(6)]])
_CAP = [(0, 1, 2), (0, 2, 3), (0, 3, 4), (0, 4, 5)]  # a fan from the convex corner 0
L_FACES = np.array([tuple(reversed(t)) for t in _CAP] + [tuple(i + 6 for i in t) for t in _CAP]
                   + [f for i in range(6) for f in ((i, (i + 1) % 6, (i + 1) % 6 + 6),
                                                    (i, (i + 1) % 6 + 6, i + 6))])


def _piece_hulls(shape: jaxsat.Compound) -> list[ConvexHull]:
    pieces = shape.pieces
    return [ConvexHull(np.asarray(pieces.vertices[i])[np.asarray(pieces.vertex_mask[i])])
            for i in range(len(shape.piece_mask)) if shape.piece_mask[i]]


@pytest.fixture(scope="module")
def l_prism() -> jaxsat.Compound:
    return jaxsat.mesh_compound(L_VERTICES, L_FACES, max_vertices=12)


COVER_TOLERANCE = 1e-3 * 2.0
"""CoACD's parts cover the mesh up to its own approximation (see `mesh_compound`): 1e-3 of
the mesh's size (2); measured 1e-4 on this mesh."""


def test_pieces_cover_the_mesh_and_leave_its_notch_empty(l_prism):
    """At least two convex pieces of at most 12 vertices; every mesh vertex and the centre of
    each arm lie in some piece (up to CoACD's approximation); the notch's centre lies at least
    0.3 from every piece."""
    hulls = _piece_hulls(l_prism)
    assert len(hulls) >= 2
    assert all(len(hull.vertices) <= 12 for hull in hulls)
    for point in [*L_VERTICES, [1.5, 0.5, 0.5], [0.5, 1.5, 0.5], [0.5, 0.5, 0.5]]:
        assert min(oracle.distance_to_hull(hull, point) for hull in hulls) <= COVER_TOLERANCE, point
    assert min(oracle.distance_to_hull(hull, [1.6, 1.6, 0.5]) for hull in hulls) >= 0.3


def test_compound_queries_see_the_concave_shape(l_prism):
    upright = np.array([1.0, 0.0, 0.0, 0.0])
    small = jaxsat.box([0.2, 0.2, 0.2])
    for position, expected in (([1.6, 1.6, 0.5], False), ([1.5, 0.5, 0.5], True),
                               ([0.5, 1.5, 0.5], True)):
        hit = jaxsat.compound_intersects(l_prism, jaxsat.pose3(np.zeros(3), upright), small,
                                         jaxsat.pose3(np.array(position), upright))
        assert bool(hit) == expected, position


def test_load_mesh_reads_what_trimesh_writes(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    path = tmp_path / "l.obj"
    trimesh.Trimesh(L_VERTICES, L_FACES, process=False).export(path)
    vertices, faces = jaxsat.load_mesh(path)
    assert faces.shape == L_FACES.shape
    np.testing.assert_allclose(np.sort(vertices, axis=0), np.sort(L_VERTICES, axis=0))


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"faces": np.array([[0, 1]])}, "faces must be an"),
    ({"faces": np.array([[0, 1, 99]])}, "faces index vertices"),
    ({"faces": L_FACES.astype(float)}, "faces must be an"),
    ({"threshold": 0.0}, "threshold"),
])
def test_mesh_compound_rejects_bad_input(kwargs, match):
    arguments = {"vertices": L_VERTICES, "faces": L_FACES, **kwargs}
    with pytest.raises(ValueError, match=match):
        jaxsat.mesh_compound(**arguments)


def test_a_missing_extra_says_how_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "coacd", None)
    with pytest.raises(ImportError, match=r"jaxsat\[mesh\]"):
        jaxsat.mesh_compound(L_VERTICES, L_FACES)
