"""Concave triangle meshes as compounds of convex pieces (the optional `mesh` extra).

CoACD (Wei et al., SIGGRAPH 2022; `coacd` on the package index) splits a mesh into
approximately convex parts; each part's hull is capped at `max_vertices` with `cap_hull` (so
that the pieces share one size class, and each still contains its part), and the pieces become
a `Compound`. trimesh (also optional) loads mesh files. Both are imported only when called:
the core package needs neither.
"""

from __future__ import annotations

import numpy as np

from jaxsat._compound import Compound, compound
from jaxsat._geometry import as_point_array
from jaxsat._shapes import cap_hull, polyhedron

__all__ = ["load_mesh", "mesh_compound"]

_INSTALL_HINT = 'pip install "jaxsat[mesh]"'


def _import(name: str):
    try:
        return __import__(name)
    except ImportError:
        raise ImportError(f"{name} is needed for meshes: {_INSTALL_HINT}") from None


def load_mesh(path) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (N, 3) float64, faces (M, 3) int64) of a mesh file (any format trimesh reads;
    a scene's geometries are merged)."""
    trimesh = _import("trimesh")
    mesh = trimesh.load(path, force="mesh")
    return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)


def mesh_compound(vertices, faces, *, max_vertices: int = 16, max_pieces: int | None = None,
                  threshold: float = 0.05, seed: int = 0) -> Compound:
    """A Compound of convex pieces covering a (possibly concave) closed triangle mesh.

    CoACD's parts are approximate: they cover the mesh up to its own tolerance (1e-4 of the
    size on an L-shaped prism, where a mesh vertex lay that far outside every part), and each
    part's cap only grows it (see `cap_hull`). Where an exact cover matters, add that much
    margin to the queries.

    Args:
      vertices: (N, 3) mesh vertices; faces: (M, 3) vertex indices of its triangles.
      max_vertices: every piece is capped at this many vertices (`cap_hull`: the capped piece
        contains the part's hull) and padded to this size class.
      max_pieces: pad the compound to this many pieces (default: as many as found); more
        pieces than this raise.
      threshold: CoACD's concavity threshold, relative to the mesh size: lower gives more,
        tighter pieces.
      seed: CoACD's random seed (its search is randomised).

    Raises:
      ImportError: coacd is not installed (`pip install "jaxsat[mesh]"`).
      ValueError: bad vertices or faces, a threshold not in (0, 1], or more pieces than
        max_pieces.
    """
    points = as_point_array(vertices, 3, "mesh vertices")
    triangles = np.asarray(faces)
    if (triangles.ndim != 2 or triangles.shape[1] != 3
            or not np.issubdtype(triangles.dtype, np.integer)):
        raise ValueError(f"faces must be an (M, 3) integer array, got {triangles.dtype} "
                         f"{triangles.shape}")
    if triangles.size and (triangles.min() < 0 or triangles.max() >= len(points)):
        raise ValueError(f"faces index vertices 0..{len(points) - 1}, got "
                         f"{triangles.min()}..{triangles.max()}")
    if not 0 < threshold <= 1:
        raise ValueError(f"threshold must be in (0, 1], got {threshold!r}")
    coacd = _import("coacd")
    coacd.set_log_level("error")
    parts = coacd.run_coacd(coacd.Mesh(points, triangles.astype(np.int64)),
                            threshold=float(threshold), seed=int(seed))
    pieces = []
    for part_vertices, _ in parts:
        capped = cap_hull(np.asarray(part_vertices, np.float64), max_vertices)
        pieces.append(polyhedron(capped.vertices, max_vertices=max_vertices))
    return compound(pieces, max_pieces=max_pieces)
