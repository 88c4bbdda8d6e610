"""The exact Separating Axis Theorem search for one prepared pair of convex shapes (the public
`penetration` and `intersects` that stand on it are in `_queries`).

Conventions. For a unit axis u, moving b by s(u) * u makes the two shapes' projections on u
just touch, where s(u) = max_a(u . a) - min_b(u . b). The penetration depth is min_u s(u):
positive when the shapes overlap (then it is the exact minimum translation distance, because
the minimum over all directions is attained at a facet normal of the Minkowski difference,
and every such normal is among the candidate axes), and minus the largest gap otherwise.

Candidate axes: in 2D the edge normals of both shapes; in 3D the face normals of both shapes
and the cross products of edge directions. Everything is computed in a's local frame. Face
normals (and, for parallelepipeds, the edge cross products) are measured by projecting both
shapes' vertices; hull edge pairs go through the Gauss map, which tests only the pairs that
can bound the Minkowski difference (see `ProjectedAxes` and `_edge_axes_by_gauss_map`, and
benchmarks/README.md, "Performance to the limit", for why they are written as they are).
Two sharp parallelepipeds (boxes) take the box kernel: the winner of their 15 candidates
chosen in closed form, then measured by projection (`_parallelepiped_search`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxsat._kernels import (
    Vec,
    as_vec,
    as_vecs,
    columns,
    cross,
    dot,
    extremes,
    inline_non_finite_poison,
    materialize,
    project,
    rotate,
    safe_normalize,
    store_cotangent,
    total,
    vadd,
    vcross,
    vdot,
    vrotate,
    vrotate_back,
    vscale,
    vselect,
    vsub,
    where,
)
from jaxsat._pair import PairFrame
from jaxsat._shapes import Polytope, parallelepiped_frame

__all__ = ["EDGE_PAIR", "FACE_OF_A", "FACE_OF_B", "Candidates", "GaussMapAxes", "ProjectedAxes",
           "SatAxis", "candidates", "sat_runner_up", "sat_search", "takes_box_kernel"]


class ProjectedAxes(NamedTuple):
    """Candidates measured by projecting both shapes' vertices on them (face normals of both
    shapes, and for parallelepipeds every pair of edge directions), in a's frame.

    The axes are kept as D component arrays (C,), so that every step is elementwise on them
    and XLA fuses the group into a few passes (stacked (C, D) axes ran box pairs 2x slower).
    Faces come first (a's, then b's), so the first of equally deep axes is a face normal."""

    depths: jax.Array
    """(C,) float: the depth s(u) along each candidate's better sense; inf for no axis."""
    groups: tuple[tuple[jax.Array, ...], ...]
    """The candidates' unnormalised axes, in order, as groups of D arrays (C_g,), component
    by component: a's face normals and b's (in b's frame, see `turns`), or with edge pairs
    one group of all, in a's frame. The two face groups are not concatenated: a
    concatenation has two readers, the depths and the winner's pick, so XLA stored it (2D
    polygons: 13 MB of temporaries at 1e5 pairs, which lifted the exact distance's over
    glibc's 32 MB mmap threshold, to page faults on every call; apart, exact value and
    gradient 0.56x the time, penetration 0.79-0.85x, on a 2-core AMD EPYC)."""
    turns: tuple[jax.Array | None, ...]
    """Per group, None or the rotation (D, D) that takes its axes into a's frame: b's face
    normals are kept in b's frame and a picked one is turned, so that the turned normals have
    one reader, the depths, and XLA does not store them (2D polygons at 1e5 pairs: 6.4 MB)."""
    inverse_norm: jax.Array
    """(C,) float: 1 / |axis| (1 where the axis is degenerate)."""
    signs: jax.Array
    """(C,) float: +1 or -1, the sense that gives `depths` (from a towards b)."""
    num_faces_a: int
    """Static: candidates [0, num_faces_a) are a's face normals."""
    num_faces: int
    """Static: candidates [num_faces_a, num_faces) are b's; the rest are edge pairs."""

    def axis(self, index) -> jax.Array:
        """(D,) the signed unit axis of candidate `index`."""
        picked, start = None, 0
        for group, turn in zip(self.groups, self.turns, strict=True):
            size = group[0].shape[0]
            inside = jnp.clip(index - start, 0, size - 1)
            entry = [component[inside] for component in group]
            if turn is not None:
                entry = list(vrotate(as_vecs(turn), tuple(entry)))
            picked = entry if picked is None else [where(index >= start, e, p)
                                                   for e, p in zip(entry, picked, strict=True)]
            start += size
        return self.signs[index] * self.inverse_norm[index] * jnp.stack(picked)

    def cosines_to(self, unit) -> jax.Array:
        """(C,) cosines between each candidate's signed unit axis and `unit`."""
        unit = as_vec(unit)

        def along(group, turn):
            return vdot(group, unit if turn is None else vrotate_back(as_vecs(turn), unit))

        return (jnp.concatenate([along(group, turn) for group, turn in zip(
            self.groups, self.turns, strict=True)]) * self.inverse_norm * self.signs)

    def feature(self, index) -> jax.Array:
        """() int32: which `SatAxis.feature` candidate `index` is."""
        return _feature(index, self.num_faces_a, self.num_faces)


_ROW_BLOCK = 8
"""Rows of Gauss-map edge-pair depths computed and reduced at a time (`GaussMapAxes`)."""

_LOOP_ROWS = 24
"""Hulls with more edges than this (20-vertex hulls have 54; 8-vertex hulls at most 18) take
the Gauss-map row minima in a loop of `_ROW_BLOCK` rows."""


class GaussMapAxes(NamedTuple):
    """Edge-edge candidates of two hulls, one per pair of hull edges (K_a, K_b), with depths
    from Plucker moments (see `_gauss_map_depths`), computed where needed; only a winner's
    axis is built."""

    edges_a: tuple
    """a's hull edges (`_hull_edge_frames`): points (K_a, D), unit directions (K_a, D), and
    the two face normals at each (K_a, D) each."""
    edges_b: tuple
    """b's, in a's frame."""

    @property
    def directions_a(self) -> jax.Array:
        return self.edges_a[1]

    @property
    def directions_b(self) -> jax.Array:
        return self.edges_b[1]

    @property
    def depths(self) -> jax.Array:
        """(K_a, K_b) float: depth of each edge pair that forms a Minkowski face; inf
        otherwise."""
        return _gauss_map_depths(self.edges_a, self.edges_b)

    def row_minima(self) -> jax.Array:
        """(K_a,) the smallest depth of each row; for more than _LOOP_ROWS rows, computed
        _ROW_BLOCK rows at a time in a loop: XLA hands a large min reduction to a library
        call that stores its whole input (all K_a x K_b depths of 1e5 pairs of 20-vertex
        hulls take 1.1 GB), and blocks outside a loop would all be stored at once."""
        count = self.edges_a[0].shape[0]
        if count <= _LOOP_ROWS:  # small enough to store; a loop costs compile time
            return jnp.min(self.depths, axis=1)
        blocks = -(-count // _ROW_BLOCK)
        # Padded by repeating row 0 (its depths again), cut off at the end.
        padded = tuple(jnp.concatenate([part, jnp.broadcast_to(
            part[:1], (blocks * _ROW_BLOCK - count, *part.shape[1:]))]) for part in self.edges_a)

        def block(index, minima):
            start = index * _ROW_BLOCK
            rows = tuple(jax.lax.dynamic_slice_in_dim(part, start, _ROW_BLOCK)
                         for part in padded)
            found = jnp.min(_gauss_map_depths(rows, self.edges_b), axis=1)
            return jax.lax.dynamic_update_slice_in_dim(minima, found, start, 0)

        dtype = self.edges_a[0].dtype
        # Written from the edges (0 * an entry is 0) so that under `vmap` the loop state is
        # batched from the start and the batching rule traces the body once less.
        minima = jnp.zeros((blocks * _ROW_BLOCK,), dtype) + 0 * padded[0][0, 0]
        return jax.lax.fori_loop(0, blocks, block, minima)[:count]

    def row(self, index) -> jax.Array:
        """(K_b,) row `index` of `depths`, computed again from the edges (not read from a
        stored matrix: see `row_minima`)."""
        edges_a = tuple(part[index][None] for part in self.edges_a)
        return _gauss_map_depths(edges_a, self.edges_b)[0]

    def axis(self, index) -> jax.Array:
        """(D,) the unit axis of flattened edge pair `index`, its sense given by the
        orientation rule of `_gauss_map_depths` (BDC > 0)."""
        row, col = jnp.divmod(index, self.directions_b.shape[0])
        crossed = cross(self.directions_a[row], self.directions_b[col])
        sign = where(jnp.dot(self.edges_a[3][row], self.directions_b[col]) > 0, 1.0, -1.0)
        return sign * safe_normalize(crossed, 0.0)[0]


class Candidates(NamedTuple):
    """Every candidate axis of one pair, in two groups that stay apart: concatenating them
    would make XLA materialise every depth."""

    projected: ProjectedAxes
    gauss_map: GaussMapAxes | None
    """None unless the Gauss map tests the hull edge pairs (3D, not both parallelepipeds)."""


FACE_OF_A, FACE_OF_B, EDGE_PAIR = 0, 1, 2
"""Values of `SatAxis.feature`: which kind of candidate gave the axis."""


def _feature(index, num_faces_a: int, num_faces: int) -> jax.Array:
    """() int32 `SatAxis.feature` of candidate `index` in the projected order: a's face
    normals, then b's (up to `num_faces`), then edge pairs."""
    return where(index < num_faces_a, FACE_OF_A,
                 where(index < num_faces, FACE_OF_B, EDGE_PAIR)).astype(jnp.int32)


def _interval_depths(a_min, a_max, b_min, b_max, store: bool = False, poison=None):
    """The better sense of each axis: depth min(b pushed along +n, along -n), and its sign
    (+1 at a tie). By a select, so that at a tie the whole gradient follows the chosen sense
    (`_kernels` rule 3). With `store`, the decision and the depth are stored (rule 5), the
    decision first so that every reader turns the axis alike. A `poison`
    (`inline_non_finite_poison`) is added to both senses' depths, in the pass that computes
    them."""
    along, against = a_max - b_min, b_max - a_min
    if poison is not None:
        along, against = along + poison, against + poison
    turned = against < along
    if store:
        turned = materialize(turned)
    depth = where(turned, against, along)
    if store:
        depth = materialize(depth)
    return depth, where(turned, -1.0, 1.0).astype(depth.dtype)


def _projected_axes(a: Polytope, b: Polytope, b_vertices_in_a, rotation,
                    with_edges: bool) -> ProjectedAxes:
    """The face normals of both shapes and, with_edges, the cross product of every pair of
    unique edge directions (cheapest for boxes: 3 x 3 axes), measured by projection."""
    normals_b = rotate(rotation, b.face_normals)
    groups = [tuple(columns(a.face_normals)), tuple(columns(normals_b))]
    kept, turns = [groups[0], tuple(columns(b.face_normals))], [None, rotation]
    squares = [jnp.ones_like(group[0]) for group in groups]  # unit face normals
    if with_edges:
        # Each component its own (E_a E_b,) array: stacked as (E_a, E_b, 3) and sliced, they
        # took a pass of their own over the batch.
        crosses = [c.reshape(-1) for c in vcross(
            tuple(c[:, None] for c in columns(a.edge_directions)),
            tuple(c[None, :] for c in columns(rotate(rotation, b.edge_directions))))]
        # A parallelepiped pair's 15 axes in one group: in three, box pairs' exact distance
        # took 1.16x the time.
        groups = [tuple(jnp.concatenate([*(group[k] for group in groups), crosses[k]])
                        for k in range(3))]
        squares = [jnp.concatenate([*squares, crosses[0] ** 2 + crosses[1] ** 2
                                    + crosses[2] ** 2])]
        kept, turns = groups, [None]
    depths, signs, inverse_norms = [], [], []
    for axes, squared in zip(groups, squares, strict=True):
        eps = jnp.finfo(squared.dtype).eps
        valid = squared > eps * eps  # parallel edges give no axis
        # Double `where`: the invalid branch never reaches rsqrt(0), so no NaN in any gradient.
        inverse_norm = jax.lax.rsqrt(where(valid, squared, 1.0))
        group_depths, group_signs = _interval_depths(*extremes(list(axes), a.vertices),
                                                     *extremes(list(axes), b_vertices_in_a))
        depths.append(where(valid, group_depths * inverse_norm, jnp.inf))
        signs.append(group_signs)
        inverse_norms.append(inverse_norm)
    num_faces_a = a.face_normals.shape[0]
    return ProjectedAxes(jnp.concatenate(depths), tuple(kept), tuple(turns),
                         jnp.concatenate(inverse_norms),
                         jnp.concatenate(signs), num_faces_a,
                         num_faces_a + b.face_normals.shape[0])


def _hull_edge_frames(shape: Polytope, rotation=None, translation=None):
    """Per hull edge: a point on it, unit direction (b x a), adjacent face normals a and b."""
    points = shape.vertices[shape.edge_endpoints[:, 0]]
    normals = shape.edge_face_normals
    if rotation is not None:
        points = rotate(rotation, points) + translation
        normals = rotate(rotation, normals)
    first, second = normals[:, 0], normals[:, 1]
    directions, _ = safe_normalize(cross(second, first), 0.0)
    return points, directions, first, second


def _edge_axes_by_gauss_map(a: Polytope, b: Polytope, rotation, translation) -> GaussMapAxes:
    """Edge-edge candidates only for hull-edge pairs that form a Minkowski face
    (`_gauss_map_depths`)."""
    edges_a = _hull_edge_frames(a)
    edges_b = _hull_edge_frames(b, rotation, translation)
    return GaussMapAxes(edges_a, edges_b)


def _gauss_map_depths(edges_a, edges_b) -> jax.Array:
    """(K_a, K_b) depths of hull-edge pairs (edges as `_hull_edge_frames` gives them), inf
    for pairs that form no Minkowski face.

    Two edges can give the penetration axis only if their arcs on the Gauss map cross (the
    arc of a's edge and the arc of b's edge with b's normals negated); for those pairs the
    supporting points are the edges themselves, so the depth needs no scan over vertices:
    with n = e_a x e_b and Plucker moments m = e x p it is n . (p_a - p_b) / |n| =
    -(e_b . m_a + e_a . m_b) / |n|, signed so the axis points out of a. Other pairs are
    skipped: their axes never give the minimum. (The moment form cancels digits in float32;
    `sat_search` measures the winner again by projection, so that only affects near-ties.)"""
    points_a, dir_a, na1, na2 = edges_a
    points_b, dir_b, nb1, nb2 = edges_b
    cba, dba = -project(dir_a, nb1), -project(dir_a, nb2)
    adc, bdc = project(na1, dir_b), project(na2, dir_b)
    minkowski_face = (cba * dba < 0) & (adc * bdc < 0) & (cba * bdc > 0)
    # |e_a x e_b| from the cross product itself: 1 - cos^2 rounds (near-)parallel edges to
    # noise, and noise must not pass for a Minkowski face. Components stay separate arrays so
    # that XLA fuses them instead of materialising a (K_a, K_b, 3) stack.
    ax, ay, az = (dir_a.T[k][:, None] for k in range(3))
    bx, by, bz = (dir_b.T[k][None, :] for k in range(3))
    sine_squared = (ay * bz - az * by) ** 2 + (az * bx - ax * bz) ** 2 + (ax * by - ay * bx) ** 2
    min_sine = 1000 * jnp.finfo(sine_squared.dtype).eps
    valid = minkowski_face & (sine_squared > min_sine * min_sine)
    # The Gauss-map arcs fix the orientation: the axis e_a x e_b points out of a iff BDC > 0.
    orientation = where(bdc > 0, 1.0, -1.0).astype(sine_squared.dtype)
    inverse_sine = jax.lax.rsqrt(where(valid, sine_squared, 1.0))
    moment_a, moment_b = cross(dir_a, points_a), cross(dir_b, points_b)
    numerator = -project(moment_a, dir_b) - project(dir_a, moment_b)
    depths = where(valid, numerator * orientation * inverse_sine, jnp.inf)
    return depths


def _use_gauss_map(a: Polytope, b: Polytope) -> bool:
    """Static choice of the edge-edge method from the padded sizes.

    Projection tries every pair of unique edge directions; that is cheapest for boxes, and a
    polyhedron with at most 3 edge directions is a parallelepiped (`Polytope.is_parallelepiped`),
    for which every such pair is a Minkowski face. Any other shape goes through the Gauss map.
    Both methods then try the same axes, so padding (which only repeats edges) never changes
    a result, separated gaps included."""
    return not (a.is_parallelepiped and b.is_parallelepiped)


def candidates(frame: PairFrame, prune: bool = True) -> Candidates:
    """The candidate axes of one prepared pair. prune=False tests every edge-direction pair
    by projection, Gauss map or not."""
    a, b = frame.a, frame.b
    gauss_map = a.dim == 3 and prune and _use_gauss_map(a, b)
    projected = _projected_axes(a, b, frame.b_vertices, frame.rotation,
                                with_edges=a.dim == 3 and not gauss_map)
    edges = (_edge_axes_by_gauss_map(a, b, frame.rotation, frame.translation) if gauss_map
             else None)
    return Candidates(projected, edges)


def _winner(depths: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(min, flat argmin) of one group's depths: jnp.argmin, and the minimum read at that
    index (a separate min reduction measured slower)."""
    index = jnp.argmin(depths)
    return depths[index], index


def _gauss_map_winner(gauss_map: GaussMapAxes) -> tuple[jax.Array, jax.Array]:
    """(min, flat argmin) of the Gauss-map edge pairs' depths: the argmin of the row minima,
    then the argmin of the winning row. A flat argmin over the K_a K_b depths (XLA's variadic
    reduce) took 60% of a 20-vertex hull query."""
    row_minima = gauss_map.row_minima()
    row = jnp.argmin(row_minima)
    return row_minima[row], row * gauss_map.directions_b.shape[0] + jnp.argmin(
        gauss_map.row(row))


def _smallest(entries):
    """The entry (a tuple whose first element is a depth) of smallest depth, the first at
    ties, selected element by element."""
    best = entries[0]
    for entry in entries[1:]:
        better = entry[0] < best[0]
        best = tuple(where(better, new, old) for new, old in zip(entry, best, strict=True))
    return best


def _winners(found: Candidates, exclude_near=None, min_cosine=None):
    """(depth, axis, feature) of each group's best candidate; with `exclude_near`, candidates
    whose axis is within arccos(min_cosine) of that unit axis are left out."""
    projected = found.projected
    depths = projected.depths
    if exclude_near is not None:
        depths = where(projected.cosines_to(exclude_near) >= min_cosine, jnp.inf, depths)
    depth, index = _winner(depths)
    entries = [(depth, projected.axis(index), projected.feature(index))]
    if found.gauss_map is not None:
        depth, index = _gauss_map_winner(found.gauss_map)
        axis = found.gauss_map.axis(index)
        if exclude_near is not None:
            depth = where(dot(axis, exclude_near) >= min_cosine, jnp.inf, depth)
        entries.append((depth, axis, jnp.asarray(EDGE_PAIR, jnp.int32)))
    return entries


class SatAxis(NamedTuple):
    """The SAT's answer for one pair, in a's frame (see the module docstring)."""

    depth: jax.Array
    """() float: min over candidate axes of s(u), measured by projecting both shapes' vertices
    on the axis; > 0 iff the shapes overlap."""
    axis: jax.Array
    """(D,) float: unit axis of that depth, from a towards b, in a's frame."""
    feature: jax.Array
    """() int32: FACE_OF_A, FACE_OF_B or EDGE_PAIR: the kind of candidate that gave the axis."""


def _parallelepiped_axes(frame: PairFrame, rows) -> list[Vec]:
    """The 15 unnormalised candidate axes (Vecs in a's frame) of two parallelepipeds
    (`Polytope.has_parallelepiped_frame`), in `ProjectedAxes`' order: a's 3 face normals,
    b's 3, then d_i x d'_j for a's edge i and b's edge j (candidate 6 + 3 i + j). `rows`:
    the rotation's rows as Vecs."""
    edges_a = as_vecs(frame.a.edge_directions)
    edges_b = [vrotate(rows, edge) for edge in as_vecs(frame.b.edge_directions)]
    return (as_vecs(frame.a.face_normals)
            + [vrotate(rows, normal) for normal in as_vecs(frame.b.face_normals)]
            + [vcross(edges_a[i], edges_b[j]) for i in range(3) for j in range(3)])


def _parallelepiped_winner(frame: PairFrame) -> jax.Array:
    """() int32: the index of the smallest depth among `_parallelepiped_axes`, the first
    at ties, with the depths in closed form: a parallelepiped's support along u is
    u . centre + sum_m |u . e_m| (`parallelepiped_frame`), so the depth along u is
    (w_a + w_b - |u . (c_b - c_a)|) / |u| with w = sum_m |u . e_m| (a shape's width along its
    own face normal m is half its extent there): about 40 operations a candidate, in one pass
    with no (15,) arrays, where projecting the 16 vertices on every candidate costs twice the
    operations and three stored arrays of axis components.

    Only the choice, so no gradient: `_parallelepiped_search` measures the winner by
    projection, and values and gradients are the general path's."""
    frame = jax.lax.stop_gradient(frame)
    a, b = frame.a, frame.b
    centre_a, edges_a = parallelepiped_frame(a)
    centre_b, edges_b = parallelepiped_frame(b)
    rows = as_vecs(frame.rotation)
    edges_b = [vrotate(rows, edge) for edge in edges_b]
    offset = vsub(vadd(vrotate(rows, centre_b), as_vec(frame.translation)), centre_a)
    half_widths = [0.5 * (shape.face_extents[m, 1] - shape.face_extents[m, 0])
                   for shape in (a, b) for m in range(3)]
    eps = jnp.finfo(frame.dtype).eps
    best = best_index = None
    for index, axis in enumerate(_parallelepiped_axes(frame, rows)):
        width_a = (half_widths[index] if index < 3 else
                   total(jnp.abs(vdot(axis, edge)) for edge in edges_a))
        width_b = (half_widths[index] if 3 <= index < 6 else
                   total(jnp.abs(vdot(axis, edge)) for edge in edges_b))
        depth = width_a + width_b - jnp.abs(vdot(axis, offset))
        if index >= 6:  # an edge pair: the face normals are unit
            squared = vdot(axis, axis)
            valid = squared > eps * eps  # parallel edges give no axis
            depth = where(valid, depth * jax.lax.rsqrt(where(valid, squared, 1.0)), jnp.inf)
        if best is None:
            best, best_index = depth, jnp.zeros((), jnp.int32)
        else:
            better = depth < best
            best = where(better, depth, best)
            best_index = where(better, index, best_index)
    return best_index


def _parallelepiped_search(frame: PairFrame) -> SatAxis:
    """`sat_search` for two parallelepipeds: the winner of the closed form
    (`_parallelepiped_winner`), stored, and its axis built from it alone and measured by
    projecting both shapes' vertices (so depth, sense and gradients are the general path's).

    The depth holds the non-finite guard (`inline_non_finite_poison`), computed in the pass
    that projects the vertices, over every input it depends on: both shapes' vertices, a's
    rotation (the normal is turned by it), b's axis R^T u (a NaN or inf anywhere in either
    rotation makes one of its components NaN or inf: NaN * 0 and inf * 0 are NaN) and
    u . t (so does one in either translation)."""
    index = materialize(_parallelepiped_winner(frame))
    # The winner's inputs picked first (a's normal or edge, b's normal or edge in b's frame:
    # 6 choices a side), then turned and crossed once, rather than all 15 axes built and one
    # picked. Picked by indexing: each of the axis' three component passes then reads the
    # picked vectors, where a select chain over the six read all of them (0.93x the time of
    # box penetration at 1e5 pairs, 0.97x at 1e4; same results, bit for bit).
    row, column = (index - 6) // 3, (index - 6) % 3
    of_a = where(index < 3, index, where(index >= 6, 3 + row, 0))
    of_b = where(index < 3, 0, where(index < 6, index - 3, 3 + column))
    picked = [as_vec(where(choice < 3, shape.face_normals[choice % 3],
                           shape.edge_directions[choice % 3]))
              for shape, choice in ((frame.a, of_a), (frame.b, of_b))]
    picked_a = picked[0]
    # The gradient reads the stored cotangents of the rotation's entries and of both axes
    # (`_kernels.store_cotangent`).
    rows = store_cotangent(as_vecs(frame.rotation))
    turned_b = vrotate(rows, picked[1])
    axis = vselect(index < 3, picked_a, vselect(index < 6, turned_b, vcross(picked_a, turned_b)))
    # The winner is never degenerate: a face normal (unit) beats every invalid edge pair.
    squared = vdot(axis, axis)
    unit = store_cotangent(materialize(vscale(jax.lax.rsqrt(where(squared > 0, squared, 1.0)),
                                              axis)))
    # b projected in its own frame on the axis turned back (R^T u), plus u . t: the same
    # values as projecting b's vertices moved into a's frame, without storing them.
    unit_in_b = store_cotangent(vrotate_back(rows, unit))
    shift = vdot(unit, as_vec(frame.translation))
    b_min, b_max = extremes(list(unit_in_b), frame.b.vertices)
    poison = inline_non_finite_poison(frame.a.vertices, frame.b.vertices,
                                      frame.pose_a.rotation, jnp.stack(unit_in_b), shift)
    depth, sign = _interval_depths(*extremes(list(unit), frame.a.vertices),
                                   b_min + shift, b_max + shift, store=True, poison=poison)
    return SatAxis(depth, sign * jnp.stack(unit), _feature(index, 3, 6))


def takes_box_kernel(a: Polytope, b: Polytope) -> bool:
    """Static: `sat_search(..., box_kernel=True)` takes the box kernel for this pair (two sharp
    parallelepipeds, `Polytope.has_parallelepiped_frame`). Its depth then holds the
    non-finite guard, NaN where any input entry is NaN or inf (`_parallelepiped_search`)."""
    return a.has_parallelepiped_frame and b.has_parallelepiped_frame


def sat_search(frame: PairFrame, prune: bool = True, box_kernel: bool = False) -> SatAxis:
    """The deepest-separating candidate axis of a prepared pair and its depth.

    A Gauss-map winner's depth is measured again by projecting both shapes on its unit axis
    (the moment form loses float32 digits), so every returned depth is a projection's.
    Projected candidates need no such step. With `box_kernel` (static), two sharp
    parallelepipeds take a closed-form choice of the winner (`_parallelepiped_search`),
    measured by projection too: `penetration` and `intersects` take 0.35x the time on 1e5 box
    pairs (0.7x on 1e4) on a 2-core CPU. Its depth holds the non-finite guard
    (`takes_box_kernel`), so the queries that use it skip the guard's own pass. The distance
    and contact queries leave it off: there the SAT is a small part (3% faster with it) and
    it added 0.3-0.4 s to their compile times."""
    if box_kernel and takes_box_kernel(frame.a, frame.b):
        return _parallelepiped_search(frame)
    found = candidates(frame, prune)
    depth, axis, feature = _smallest(_winners(found))
    if found.gauss_map is not None:
        # Both senses, as the projected group measures them: the Gauss-map sense comes from
        # the sign of a dot product that vanishes where edges meet at a vertex, and XLA may
        # round it differently in `GaussMapAxes.axis` than in the depth (it did for batches
        # over about 1,400 pairs), which turned the axis around and gave the depth
        # s(-u) = width + gap instead of s(u).
        # Stored: every later stage reads the depth and the axis, and would otherwise
        # recompute both select chains in each of its passes.
        axes = columns(axis)
        depth, sign = _interval_depths(*extremes(axes, frame.a.vertices),
                                       *extremes(axes, frame.b_vertices), store=True)
        axis = sign * axis
    return SatAxis(depth, axis, feature)


def sat_runner_up(frame: PairFrame, first, min_angle) -> tuple[jax.Array, jax.Array]:
    """((D,) unit axis (a's frame), () its gap) of the best candidate more than `min_angle`
    radians (may be traced) from the unit axis `first` (a penetration direction found by
    another search): where two penetration directions tie, the other one. The gap is
    min_b u.b - max_a u.a along the axis (minus its depth). Projected candidates near
    `first` are masked (padding repeats a face normal, and parallel faces of a and b give
    one direction); a Gauss-map group offers its best pair unless that is near `first`.
    With no such candidate, (`first`, -inf).

    Measured from `first`, not from this search's own winner: where the directions tie
    exactly (identical shapes at one pose tie u and -u), the two searches may break the tie
    differently, and the winner's rival would then lie next to `first`."""
    found = candidates(frame)
    best_depth, best_axis, _ = _smallest(_winners(found, first, jnp.cos(min_angle)))
    return where(jnp.isfinite(best_depth), best_axis, first), -best_depth

