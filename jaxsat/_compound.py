"""Compound shapes: unions of convex pieces, queried piece pair by piece pair.

A concave shape is the union of convex pieces sharing one local frame and one pose. In 2D,
`concave_polygon` splits a simple polygon into pieces with `jaxsat.decompose`. In 3D the
decomposition is left to the user: approximate convex decomposition tools such as CoACD or
V-HACD return a list of convex hulls, and each hull's vertex array can be passed to `compound`
as it is (or built with `jaxsat.polyhedron` first).

The queries run the convex narrow phase on every pair of pieces (vmapped over the P_a x P_b
pairs) and reduce: the shapes intersect iff some pair does, and the reported penetration is
the deepest pair's. Padding pieces (piece_mask False) repeat piece 0, so they are valid
geometry that computes finite values, and are masked out of both reductions.

Pieces may be rounded (spheres, capsules, rounded polytopes; a compound of them is rounded,
its sharp pieces with radius 0), and either side of a query may be a half-space, which
counts as a single piece.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxsat import _shapes as shapes
from jaxsat._decompose import decompose
from jaxsat._halfspace import HalfSpace
from jaxsat._kernels import where
from jaxsat._pair import check_one_pair, compiled_query
from jaxsat._poses import Pose
from jaxsat._queries import intersects, penetration
from jaxsat._shapes import Polytope

__all__ = ["Compound", "CompoundPenetration", "compound", "concave_polygon", "stack_compounds",
           "compound_intersects", "compound_penetration"]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Compound:
    """A union of convex pieces in one local frame, padded to a fixed number of pieces.

    Build instances with `compound` or `concave_polygon` and batch them with `stack_compounds`
    (which adds a leading batch axis in front of the piece axis).
    """

    pieces: Polytope
    """Polytope whose fields have a leading (P,) piece axis: the pieces in the compound's local
    frame, padded to common sizes as `jaxsat.stack` pads shapes."""
    piece_mask: jax.Array
    """(P,) bool: True for real pieces, False for padding pieces (which repeat piece 0)."""

    @property
    def dim(self) -> int:
        """Spatial dimension, 2 or 3 (static)."""
        return self.pieces.dim

    @property
    def num_pieces(self) -> int:
        """P, the padded number of pieces (static)."""
        return self.piece_mask.shape[-1]

    @property
    def batch_shape(self) -> tuple[int, ...]:
        """Leading batch axes (empty for a single compound)."""
        return self.piece_mask.shape[:-1]

    @property
    def dtype(self) -> jnp.dtype:
        return self.pieces.dtype


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class CompoundPenetration:
    """Result of `compound_penetration` for one pair (fields gain leading axes under `vmap`)."""

    depth: jax.Array
    """() float: the largest penetration depth over real piece pairs (negative: separated)."""
    normal: jax.Array
    """(D,) float: that pair's unit world-frame axis from a towards b."""
    piece_a: jax.Array
    """() int32: index of a's piece in that pair (0 when a is a plain Polytope)."""
    piece_b: jax.Array
    """() int32: index of b's piece in that pair (0 when b is a plain Polytope)."""


def _as_piece(piece, index: int, max_vertices: int | None) -> Polytope:
    """A Polytope piece as it is, or one built from a vertex array (polygon or polyhedron)."""
    if isinstance(piece, Polytope):
        if piece.batch_shape:
            raise ValueError(f"piece {index} is a batched Polytope; pass unbatched pieces")
        return piece
    if isinstance(piece, Compound):
        raise TypeError(f"piece {index} is a Compound; pass its convex pieces instead")
    points = np.asarray(piece)
    if points.ndim != 2 or points.shape[-1] not in (2, 3):
        raise ValueError(f"piece {index} must be a jaxsat.Polytope or an (N, 2) or (N, 3) "
                         f"vertex array, got shape {points.shape}")
    build = shapes.polygon if points.shape[-1] == 2 else shapes.polyhedron
    return build(piece, max_vertices)


def _check_alike(items: Sequence, kind: str) -> None:
    """Raise if `items` (pieces or compounds) mix dimensions or dtypes."""
    if len({item.dim for item in items}) > 1:
        raise ValueError(f"{kind} cannot mix 2D and 3D shapes")
    dtypes = {item.dtype for item in items}
    if len(dtypes) > 1:
        raise ValueError(f"{kind} cannot mix dtypes, got {sorted(str(d) for d in dtypes)}")


def _check_count(name: str, value: int | None, count: int, what: str) -> int:
    """`value` (the requested padded size) if it holds `count` items; `count` if None."""
    if value is None:
        return count
    if int(value) != value or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    if count > value:
        raise ValueError(f"{count} {what}, more than {name}={value}")
    return int(value)


def _assemble(pieces: Sequence[Polytope], sizes: shapes.SizeClass, num_pieces: int) -> Compound:
    return Compound(pieces=shapes.pad_and_stack(pieces, sizes, num_pieces),
                    piece_mask=jnp.asarray(np.arange(num_pieces) < len(pieces)))


def _common_size_class(pieces: Sequence[Polytope]) -> shapes.SizeClass:
    """The smallest size class that holds every piece."""
    return shapes.SizeClass(*(max(column) for column in
                              zip(*(piece.size_class for piece in pieces), strict=True)))


def compound(pieces: Sequence[Polytope | np.ndarray], max_pieces: int | None = None,
             max_vertices: int | None = None) -> Compound:
    """A compound shape from convex pieces given in its local frame.

    Args:
      pieces: convex pieces, each an unbatched `jaxsat.Polytope` or an (N, 2) / (N, 3) vertex
        array (built with `jaxsat.polygon` / `jaxsat.polyhedron`, keeping the array's float
        dtype). In 3D, pass e.g. the convex hulls of a CoACD or V-HACD decomposition. The
        pieces may overlap; only their union matters to `compound_intersects`.
      max_pieces: pad the piece axis to this many pieces, so that compounds with different
        piece counts share one compiled kernel. Default: no padding.
      max_vertices: pad every piece to the sizes `polygon` / `polyhedron` give for this many
        vertices (pieces built here from vertex arrays use it directly). Default: pad to the
        largest piece only.

    Raises:
      TypeError: a piece that is a Compound, or a non-numeric vertex array.
      ValueError: no pieces, a vertex array that is not (N, 2) or (N, 3) (or that `polygon` /
        `polyhedron` rejects), pieces mixing 2D and 3D or dtypes, more pieces than
        `max_pieces`, or a piece with more (padded) vertices than `max_vertices`.
    """
    pieces = [pieces] if isinstance(pieces, Polytope) else list(pieces)
    if not pieces:
        raise ValueError("compound needs at least one piece")
    num_pieces = _check_count("max_pieces", max_pieces, len(pieces), "pieces")
    built = [_as_piece(piece, index, max_vertices) for index, piece in enumerate(pieces)]
    _check_alike(built, "compound")
    sizes = _common_size_class(built)
    if max_vertices is not None:
        _check_count("max_vertices", max_vertices, sizes.vertices, "vertices in a piece")
        sizes = shapes.SizeClass(*map(max, sizes,
                                      shapes.size_class_for(built[0].dim, int(max_vertices))))
    return _assemble(built, sizes, num_pieces)


def concave_polygon(vertices, max_pieces: int | None = None, max_vertices: int | None = None,
                    *, dtype=None) -> Compound:
    """A simple, possibly concave polygon as a compound of the convex pieces of `decompose`.

    Piece i of the compound (as `compound_penetration` reports it) is `decompose(vertices)[i]`.

    Args:
      vertices: (N, 2) array-like of the polygon's vertices, in either winding order.
      max_pieces: padding, as in `compound`.
      max_vertices: padding, as in `compound`.
      dtype: float dtype of the result; default: the input's float dtype, else JAX's default.
        An explicit float64 needs 64-bit JAX (`jax_enable_x64`): ValueError otherwise.

    Raises:
      ValueError: everything `decompose` rejects, and too many pieces or piece vertices for
        `max_pieces` / `max_vertices`.
    """
    dtype = shapes.float_dtype(np.asarray(vertices), dtype)
    pieces = decompose(vertices)
    if max_vertices is not None:
        largest = max(len(piece) for piece in pieces)
        _check_count("max_vertices", max_vertices, largest, "vertices in a convex piece")
    return compound([shapes.polygon(piece, max_vertices, dtype=dtype) for piece in pieces],
                    max_pieces, max_vertices)


def _as_compound(shape, name: str) -> Compound:
    """A Compound as it is; a Polytope as a one-piece compound."""
    if isinstance(shape, Compound):
        return shape
    if isinstance(shape, Polytope):
        # Plain indexing and a NumPy mask: no eager JAX op for concrete inputs.
        pieces = jax.tree.map(lambda leaf: leaf[None], shape)
        return Compound(pieces=pieces, piece_mask=np.ones(shape.batch_shape + (1,), bool))
    raise TypeError(f"{name} must be a jaxsat.Compound or jaxsat.Polytope, got "
                     f"{type(shape).__name__}")


def stack_compounds(compounds: Sequence[Compound | Polytope]) -> Compound:
    """Stack compounds of one dimension and dtype into a batch, padding them to common sizes.

    Every compound is padded to the largest piece count (padding pieces repeat its piece 0 and
    are masked out) and every piece to the largest vertex, face and edge counts. Plain
    Polytopes are taken as one-piece compounds.

    Returns:
      A Compound whose fields have a leading batch axis of length len(compounds), ready for
      `jax.vmap`.

    Raises:
      TypeError: an entry that is not a Compound or Polytope.
      ValueError: an empty sequence, a batched entry, or a mix of 2D and 3D or of dtypes.
    """
    compounds = [_as_compound(entry, f"stack_compounds entry {index}")
                 for index, entry in enumerate(compounds)]
    if not compounds:
        raise ValueError("stack_compounds needs at least one compound")
    for index, entry in enumerate(compounds):
        if entry.batch_shape:
            raise ValueError(f"stack_compounds entry {index} is batched {entry.batch_shape}")
    _check_alike(compounds, "stack_compounds")
    piece_lists = [_real_pieces(entry) for entry in compounds]
    sizes = _common_size_class([piece for pieces in piece_lists for piece in pieces])
    num_pieces = max(entry.num_pieces for entry in compounds)
    batch = [_assemble(pieces, sizes, num_pieces) for pieces in piece_lists]
    return jax.tree.map(lambda *leaves: jnp.asarray(np.stack(leaves)), *batch)


def _real_pieces(entry: Compound) -> list[Polytope]:
    """The real pieces of an unbatched compound, each as an unbatched Polytope.

    Padding pieces are dropped here and regenerated from piece 0, which keeps the rule that
    padding repeats piece 0. A hand-made compound whose piece 0 is padding keeps all its
    pieces (and mask) as they are."""
    mask = np.asarray(entry.piece_mask)
    keep = np.flatnonzero(mask) if mask[0] else np.arange(len(mask))
    return [jax.tree.map(lambda leaf, i=i: np.asarray(leaf)[i], entry.pieces) for i in keep]


def _check_query(a: Compound, pose_a: Pose, b: Compound, pose_b: Pose) -> None:
    """Static checks (shapes only), so they also run under jit and vmap."""
    for name, pose in (("pose_a", pose_a), ("pose_b", pose_b)):
        if not isinstance(pose, Pose):
            raise TypeError(f"{name} must be a jaxsat.Pose, got {type(pose).__name__}")
    check_one_pair(a, pose_a, b, pose_b)


def _as_side(shape, name: str) -> Compound:
    """A query's side as a compound; a half-space as a one-piece one (its fields gain a
    leading axis of 1, so that the piece pairs vmap over it like over any pieces)."""
    if isinstance(shape, HalfSpace):
        if shape.batch_shape:
            raise ValueError(f"{name} is a batched HalfSpace; use jax.vmap for batches")
        return Compound(pieces=jax.tree.map(lambda leaf: leaf[None], shape),
                        piece_mask=np.ones((1,), bool))
    return _as_compound(shape, name)


def _prepare(a, pose_a, b, pose_b) -> tuple[Compound, Compound, jax.Array]:
    """Both shapes as compounds, after the static checks, and the (P_a, P_b) real-pair mask."""
    if isinstance(a, HalfSpace) and isinstance(b, HalfSpace):
        raise ValueError("a and b are both half-spaces; no query takes two")
    a, b = _as_side(a, "a"), _as_side(b, "b")
    _check_query(a, pose_a, b, pose_b)
    return a, b, a.piece_mask[:, None] & b.piece_mask[None, :]


def _over_piece_pairs(query, a: Compound, pose_a: Pose, b: Compound, pose_b: Pose):
    """`query(piece_a, pose_a, piece_b, pose_b)` for every piece pair, leaves (P_a, P_b, ...)."""
    per_b = jax.vmap(query, in_axes=(None, None, 0, None))
    return jax.vmap(per_b, in_axes=(0, None, None, None))(a.pieces, pose_a, b.pieces, pose_b)


def _check_compound_query(a, pose_a, b, pose_b) -> None:
    _prepare(a, pose_a, b, pose_b)


@compiled_query(_check_compound_query)
def compound_intersects(a: Compound | Polytope, pose_a: Pose, b: Compound | Polytope,
                        pose_b: Pose) -> jax.Array:
    """True where some real piece of a overlaps or touches some real piece of b.

    Args:
      a: the first shape, unbatched (use jax.vmap for batches): a compound, or a plain
        Polytope (sharp or rounded, taken as a one-piece compound), or a HalfSpace.
      pose_a: the pose of a.
      b: the second shape, of the same dimension as a; at most one of a and b is a HalfSpace.
      pose_b: the pose of b.

    Returns:
      () bool.
    """
    a, b, real_pairs = _prepare(a, pose_a, b, pose_b)
    return jnp.any(real_pairs & _over_piece_pairs(intersects.uncompiled, a, pose_a, b, pose_b))


@compiled_query(_check_compound_query)
def compound_penetration(a: Compound | Polytope, pose_a: Pose, b: Compound | Polytope,
                         pose_b: Pose) -> CompoundPenetration:
    """The deepest penetration over all pairs of real pieces, with its axis and pieces.

    depth > 0 means some pair overlaps; it is that pair's minimum translation distance, which
    is a lower bound on how far b must move to clear a (moving it out of one piece can move it
    into another). When no pair overlaps, depth <= 0 is the largest (least negative) pair
    depth, as `jaxsat.penetration` defines it for that pair. Ties go to the first pair in
    row-major (piece_a, piece_b) order. Gradients flow through the winning pair only.

    Args:
      a: the first shape, unbatched (use jax.vmap for batches): a compound, or a plain
        Polytope (sharp or rounded, taken as a one-piece compound), or a HalfSpace.
      pose_a: the pose of a.
      b: the second shape, of the same dimension as a; at most one of a and b is a HalfSpace.
      pose_b: the pose of b.

    Returns:
      CompoundPenetration in the common dtype of the inputs; normal points from a towards b,
      and moving b by depth * normal separates the winning pair.
    """
    a, b, real_pairs = _prepare(a, pose_a, b, pose_b)
    pairs = _over_piece_pairs(penetration.uncompiled, a, pose_a, b, pose_b)
    # Padding pairs get -inf (never the maximum); the `where` passes them no gradient.
    depths = where(real_pairs, pairs.depth, -jnp.inf).reshape(-1)
    best = jnp.argmax(depths)
    piece_a, piece_b = jnp.divmod(best, b.num_pieces)
    return CompoundPenetration(depth=depths[best], normal=pairs.normal[piece_a, piece_b],
                               piece_a=piece_a.astype(jnp.int32),
                               piece_b=piece_b.astype(jnp.int32))
