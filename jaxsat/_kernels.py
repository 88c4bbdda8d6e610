"""Kernel layer: small-vector maths and safe numerics that every query is built from.

Every query is written for one pair and batched with `jax.vmap`, so each array here is tiny
(a few vertices, D = 2 or 3 coordinates) and gains a long leading batch axis. What is fast
then is decided by how XLA's CPU backend fuses the batched program, which gives the rules
below. Each was measured on the kernels (benchmarks/README.md, "Performance to the limit"
and "Distance"); breaking one typically costs 2x or more.

1. **Component form.** Write small products out as sums over the D coordinates
   (`project`, `rotate`, `dot`, `cross`) instead of `@`, `jnp.dot`, `jnp.einsum` or
   `jnp.linalg`: a batched (V, 3) @ (3, 3) becomes a `dot_general` that XLA does not fuse
   with its neighbours, while the spelled-out sums are elementwise and fuse into one pass.
   Where many axes meet few points, keep the axes as D separate arrays (C,) rather than one
   stacked (C, D) array, so every step stays elementwise. Take the components with
   `columns` (one operation, and one in a gradient) rather than a slice each: compile time
   grows with the operation count.
2. **Few reductions over long axes.** A reduce op is a separate pass that its consumers do
   not fuse with. Over a handful of entries, a Python loop of selects (`extremes`,
   `support_index`) fuses; a 2-D array of depths is reduced row by row and then once more.
   Outside loops, a value read once a pair over many entries takes a reduction or a gather
   instead (an extent or a witness point over more than `SELECT_CHAIN_POINTS` points, the
   non-finite guard over a leaf of more than `_ENTRY_BY_ENTRY` entries: a 20-vertex hull):
   the chains were kernels of hundreds of lines, compiled in every query.
3. **Select, not maximum, at ties.** `jnp.maximum` splits a gradient between tied entries,
   and under `jit` XLA may recompute the tied values with different roundings in the
   backward pass, so that the shares no longer sum to 1. A select (`where(p > best, ...)`)
   sends the whole gradient to one entry.
4. **Double `where` for every guarded division, square root or logarithm.** The untaken
   branch of a select is still differentiated: `where(ok, x / y, 0)` has a NaN
   gradient where y = 0. The safe functions here replace the bad input first
   (`where(ok, y, 1)`) and say which NaN they prevent.
5. **Materialise values with many consumers.** XLA's CPU backend does not fuse one
   computation into several outputs: a value feeding several stored results (the outputs of a
   loop step, the weights of a simplex) is recomputed inside each of them, and a cheap
   elementwise producer is recomputed per consumer element. `materialize` stores it once
   (optimisation barriers are dropped before fusion on CPU, so they cannot). End an
   expensive stage in one stored value (an index, a code packing several decisions, one
   reduction's array) and derive the outputs from it cheaply. A stack of several results
   is no exception: each stacked entry recomputes what it reads (the smooth search's first
   moments, K sums over shared exponentials, computed each exponential K times), and so
   does a pick among candidates (a select over twelve computed parameters recomputed all
   twelve): store the shared values, or pick the inputs and compute once.
6. **Trace each select and each product once.** `jnp.where` is itself a jitted function:
   every call adds a nested jit that is traced again under `vmap` and again under `grad`,
   and a distance query makes about 800 of them. `where` here is the same select written
   directly. So are the operators `+`, `-` and `*` on traced arrays (jnp's ufuncs): the
   component-form sums and products (`add`, `sub`, `mul`, `total` and the `Vec` functions)
   take `lax` directly where both operands are arrays of one shape and dtype.
7. **Count the passes.** Every fusion is a pass over the whole batch, and XLA keeps an
   expensive operation (divide, square root, exponential) that has several users in a pass of
   its own rather than repeat it; a loop step of scalar algebra can so become 100 passes.
   Iterative per-pair code is written in scalar form (`Vec`), so that everything between two
   stored values fuses, and so is its loop state: a per-pair (K,) array whose entries are
   read one at a time can send the whole array through the cache for every reader (the smooth
   search's moments as one (2, K + 1) array a pair: box pairs 1.2x slower, `_smoothing`).
8. **Hand a loop columns, split them inside.** Each array a loop body reads from outside is
   computed by a kernel of its own before the loop, and every kernel costs compile time
   (LLVM compiles them one by one). Points a body reads entry by entry enter it as D
   columns (V,) and become `Vec`s inside (`vecs_of_columns`), where the slices fuse into
   their readers: GJK's V x D coordinates of two 20-vertex hulls were 120 kernels, 0.85 s of
   LLVM time in a hull distance's compile, at no gain in run time.

Nothing here imports from the rest of the package: the pair frame (`_pair`) and every query
module stand on this one.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "SELECT_CHAIN_POINTS",
    "add",
    "chord",
    "columns",
    "cross",
    "cross2",
    "dot",
    "extremes",
    "explicit_float_dtype",
    "inline_non_finite_poison",
    "largest_magnitude",
    "materialize",
    "mul",
    "orthonormal_basis",
    "project",
    "propagate_non_finite",
    "rotate",
    "safe_divide",
    "safe_normalize",
    "safe_sqrt",
    "segment_closest_parameters",
    "store_cotangent",
    "sub",
    "support_index",
    "take_vec",
    "total",
    "transposed_product",
    "Vec",
    "as_vec",
    "as_vecs",
    "vadd",
    "vcross",
    "vcross2",
    "vdot",
    "vecs_of_columns",
    "vrotate",
    "vrotate_back",
    "vscale",
    "vselect",
    "vsub",
    "vsum",
    "where",
]


def explicit_float_dtype(dtype) -> jnp.dtype:
    """A float dtype a caller asked for by name, as JAX will store it.

    Raises ValueError for a non-float dtype, and for float64 while 64-bit JAX is off: JAX
    would silently store float32, and the caller would get half the precision they asked
    for."""
    requested = jnp.dtype(dtype)
    if not jnp.issubdtype(requested, jnp.floating):
        raise ValueError(f"dtype must be a floating dtype, got {requested}")
    stored = jax.dtypes.canonicalize_dtype(requested)
    if stored != requested:
        raise ValueError(f"dtype {requested} needs 64-bit JAX, which is off (JAX would store "
                         f"{stored}): call jax.config.update('jax_enable_x64', True) first, or "
                         "set JAX_ENABLE_X64=1")
    return stored


def _one_form(x, y) -> bool:
    """Whether x and y are arrays of one shape and dtype, which `lax` combines as they are
    (a Python scalar, a broadcast or a promotion goes through jnp's operator instead)."""
    return (isinstance(x, jax.Array) and isinstance(y, jax.Array) and x.shape == y.shape
            and x.dtype == y.dtype)


def add(x, y):
    """x + y, as one `lax.add` where the operands have one form (rule 6)."""
    return jax.lax.add(x, y) if _one_form(x, y) else x + y


def sub(x, y):
    """x - y, as one `lax.sub` where the operands have one form (rule 6)."""
    return jax.lax.sub(x, y) if _one_form(x, y) else x - y


def mul(x, y):
    """x * y, as one `lax.mul` where the operands have one form (rule 6)."""
    return jax.lax.mul(x, y) if _one_form(x, y) else x * y


def total(terms):
    """The sum of the terms, added left to right from the first (Python's `sum` starts from
    the integer 0, an extra add of a constant for each sum; rule 6). Raises ValueError for
    no terms."""
    terms = list(terms)
    if not terms:
        raise ValueError("total needs at least one term")
    result = terms[0]
    for term in terms[1:]:
        result = add(result, term)
    return result


def columns(x) -> list[jax.Array]:
    """The D components of (..., D) arrays, (...) each: one `unstack`, whose derivative is one
    `stack`, where D slices take a slice and a squeeze each and their derivative a pad per
    component and the adds between them (compile time grows with the operation count)."""
    return list(jnp.unstack(x, axis=-1))


def where(condition, x, y):
    """jnp.where(condition, x, y) as one `lax.select` (rule 6), with jnp.where's dtype and
    broadcasting rules: a Python scalar takes the other operand's dtype, and two Python
    scalars of one kind stay weakly typed."""
    x, y = jnp.asarray(x), jnp.asarray(y)
    if x.dtype != y.dtype:
        dtype = jnp.result_type(x, y)
        x, y = x.astype(dtype), y.astype(dtype)
    condition = jnp.asarray(condition)
    if not condition.shape == x.shape == y.shape:  # jnp.broadcast_arrays is a nested jit too
        condition, x, y = jnp.broadcast_arrays(condition, x, y)
    return jax.lax.select(condition, x, y)


def propagate_non_finite(outputs, inputs):
    """`outputs` with every float leaf NaN and every bool leaf False where some float entry of
    `inputs` is NaN or inf, and NaN derivatives with respect to every input entry there;
    exactly `outputs` (values and derivatives) where all inputs are finite.

    Prevents a plausible answer from non-finite input. Queries choose among candidates by
    comparisons, and a comparison with NaN is False, so a NaN pose or vertex loses every
    choice and leaves a finite, wrong value: a NaN quaternion gave a distance of 0.5 with a
    zero gradient. The guard adds p = sum(0 * x) over every input entry x to float outputs: 0,
    or NaN as soon as one entry is NaN or inf (0 * inf is NaN), and no finite input can
    overflow it. Its derivative with respect to each entry is defined as p: 0, or NaN.
    Written entry by entry (rule 2: a reduction would be a pass of its own over the inputs)
    and stored once (rule 5), it costs the SAT about 5-30% on 2D polygons and boxes (1e5
    pairs, interleaved runs), against 30-130% as a reduction per input; only a leaf of more
    entries than `_ENTRY_BY_ENTRY` (a large hull's vertices) takes a reduction. A kernel that reads
    every input entry in one of its own passes can fold the guard into it instead
    (`inline_non_finite_poison`)."""
    floats = [leaf for leaf in map(jnp.asarray, jax.tree.leaves(inputs))
              if jnp.issubdtype(leaf.dtype, jnp.floating)]
    if not floats:
        return outputs
    poison = _non_finite_poison(*floats)
    finite = ~jnp.isnan(poison)

    def guard(leaf):
        leaf = jnp.asarray(leaf)
        if jnp.issubdtype(leaf.dtype, jnp.floating):
            return leaf + poison.astype(leaf.dtype)
        if leaf.dtype == jnp.bool_:
            return leaf & finite
        return leaf

    return jax.tree.map(guard, outputs)


@jax.jit
def _non_finite_poison(*floats):
    """The guard of `propagate_non_finite`: one jitted call, so that an eager gradient (which
    runs a query op by op) dispatches it once rather than two operations per input entry."""
    with jax.numpy_dtype_promotion("standard"):  # a float64 smoothing with float32 shapes
        dtype = jnp.result_type(*floats)
    return _nan_if_non_finite(*[leaf.astype(dtype) for leaf in floats])


_ENTRY_BY_ENTRY = 32
"""The most entries of a leaf that `_zero_times_every_entry` takes one by one; a larger leaf
(a hull's vertices) takes a reduction."""


def _zero_times_every_entry(leaves) -> jax.Array:
    """sum(0 * x) over every entry of the leaves: 0, or NaN once one is NaN or inf (0 * inf
    is NaN), and no finite input can overflow it. Entry by entry (rule 2) for a leaf of up
    to `_ENTRY_BY_ENTRY` entries; a larger one by a reduction, since each entry's slice is
    an operation to compile: pairs of 20-vertex hulls (60 entries a shape) compiled their
    exact value and gradient 0.15-0.25 s faster and ran it 0.95x the time (1e4 pairs, 2-core
    AMD EPYC)."""
    zero = jnp.zeros((), leaves[0].dtype)
    small = [entry for leaf in leaves if leaf.size <= _ENTRY_BY_ENTRY
             for entry in jnp.unstack(leaf.reshape(-1))]
    large = [jnp.sum(leaf * zero) for leaf in leaves if leaf.size > _ENTRY_BY_ENTRY]
    return total([mul(entry, zero) for entry in small] + large)


@jax.custom_jvp
def _nan_if_non_finite(*leaves):
    """`_zero_times_every_entry`, stored once (rule 5)."""
    return materialize(_zero_times_every_entry(leaves))


@_nan_if_non_finite.defjvp
def _nan_if_non_finite_jvp(primals, tangents):
    # d poison / d x = poison for every entry x: 0, or NaN. A rule rather than a second
    # chain of products in the value (stop_gradient(p) * tiny * x): one chain, stored once.
    poison = _nan_if_non_finite(*primals)
    return poison, _poison_tangent(poison, tangents)


def _poison_tangent(poison, tangents):
    # Whole leaves, not entries: a gradient then spreads the cotangent over each leaf in one
    # broadcast, where slicing entries out of a leaf takes a pad and an add per entry.
    return poison * total(jnp.sum(tangent) for tangent in tangents)


@jax.custom_jvp
def inline_non_finite_poison(*leaves):
    """The guard of `propagate_non_finite` (0, or NaN where some entry of the leaves is NaN or
    inf, with the derivative 0, or NaN, in every entry), not stored: for a kernel that adds it
    to a value it stores anyway, in a pass that already reads every entry of the leaves, so
    that its query needs no guard pass of its own over the inputs (`_pair.Guarded`). The box
    kernel adds it to its depth: box `penetration` and `intersects` then take 0.8x the time
    on 1e5 pairs (0.9x on 1e4; 2-core AMD EPYC), the guard's own pass having read all 72
    input entries of a pair once more."""
    return _zero_times_every_entry(leaves)


@inline_non_finite_poison.defjvp
def _inline_non_finite_poison_jvp(primals, tangents):
    poison = inline_non_finite_poison(*primals)
    return poison, _poison_tangent(poison, tangents)


def project(axes, points):
    """(C, D) axes . (V, D) points -> (C, V), in component form (rule 1)."""
    return total(axis[:, None] * coordinate[None, :]
                 for axis, coordinate in zip(columns(axes), columns(points), strict=True))


def transposed_product(x, y):
    """x^T y for two (D, D) matrices, entry by entry from their scalar entries (rule 1):
    `vrotate_back` by x of each column of y. Not `project(x.T, y.T)`: its outer products
    broadcast, and a gradient turns each broadcast into a reduction, a pass of its own (four
    in a 2D exact distance's value and gradient, which took 1.1-1.2x as long with them)."""
    x_rows, y_rows = as_vecs(x), as_vecs(y)
    return jnp.stack([jnp.stack(vrotate_back(x_rows, tuple(row[j] for row in y_rows)))
                      for j in range(len(y_rows))], axis=-1)


def rotate(rotation, points):
    """rotation @ p for (..., D) points, in component form (rule 1): `vrotate` on the
    points' columns."""
    return jnp.stack(vrotate(as_vecs(rotation), tuple(columns(points))), axis=-1)


def dot(x, y):
    """x . y over the last axis, (...)."""
    return total(mul(a, b) for a, b in zip(columns(x), columns(y), strict=True))


def cross(x, y):
    """3D cross product over the last axis, (..., 3)."""
    return jnp.stack(vcross(columns(x), columns(y)), axis=-1)


def cross2(x, y):
    """2D cross product (a scalar per pair of vectors) over the last axis, (...)."""
    return vcross2(columns(x), columns(y))


def chord(x, y):
    """|x - y| for unit vectors: about the angle between them, resolved down to rounding
    (1 - x . y rounds to 0 below 3e-4 radians in float32)."""
    difference = x - y
    return jnp.sqrt(dot(difference, difference))


def safe_divide(numerator, denominator, ok):
    """numerator / denominator where `ok`, else 0. Prevents the NaN gradient of x / 0 in the
    untaken branch (rule 4)."""
    return where(ok, numerator / where(ok, denominator, 1.0), 0.0)


def safe_sqrt(x):
    """sqrt(max(x, 0)) with a zero gradient at 0 instead of the infinite d sqrt / dx (whose
    product with a zero cotangent is NaN)."""
    positive = x > 0
    return where(positive, jnp.sqrt(where(positive, x, 1.0)), 0.0)


def safe_normalize(vectors, min_squared_norm):
    """(unit vectors, valid) for (..., D) vectors: vectors whose squared norm is at most
    `min_squared_norm` give zeros and False. Prevents the NaN of 0 / 0 (and its gradient)."""
    squared = jnp.sum(vectors**2, axis=-1, keepdims=True)
    valid = squared > min_squared_norm
    safe_squared = where(valid, squared, 1.0)
    return where(valid, vectors * jax.lax.rsqrt(safe_squared), 0.0), valid[..., 0]


def segment_closest_parameters(offset: Vec, along_a: Vec, along_b: Vec):
    """(s, t, crossing) for two segments a0 + s along_a and b0 + t along_b, offset = a0 - b0
    (component form): s, t in [0, 1] minimise |a(s) - b(t)|, and `crossing` says that the
    segments are not parallel within rounding.

    A minimising pair is found from a start s by t = the t closest to a(s), then s = the s
    closest to b(t), each clamped to [0, 1]: from the stationary s (clamped) that is exact for
    this convex quadratic on the unit square. Segments parallel within a few eps (no
    stationary s) take the better of the starts s = 0 and s = 1: the two ends of the stretch
    where the segments lie side by side, one of which is closest. A segment that is a point
    keeps parameter 0.

    The products are divided by |along_a|^2 + |along_b|^2 first, so that none carries the
    shapes' scale: raw, their products are lengths to the fourth, and the derivative of a
    division by one (its square) underflows to 0 in float32 for shapes of size 1e-6, giving
    inf * 0 = NaN."""
    aa, bb, ab = vdot(along_a, along_a), vdot(along_b, along_b), vdot(along_a, along_b)
    a_offset, b_offset = vdot(along_a, offset), vdot(along_b, offset)
    total = aa + bb
    aa, bb, ab, a_offset, b_offset = (safe_divide(x, total, total > 0)
                                      for x in (aa, bb, ab, a_offset, b_offset))
    eps = jnp.finfo(aa.dtype).eps

    def descend(s):
        t = jnp.clip(safe_divide(ab * s + b_offset, bb, bb > 0), 0.0, 1.0)
        s = jnp.clip(safe_divide(ab * t - a_offset, aa, aa > 0), 0.0, 1.0)
        gap = vsub(vadd(offset, vscale(s, along_a)), vscale(t, along_b))
        return s, t, vdot(gap, gap)

    # The stationary s from cross products, n = along_a x along_b (Lagrange's identity: aa bb
    # - ab^2 = |n|^2): each component of n rounds to eps |along_a| |along_b|, where aa bb -
    # ab^2 keeps only eps aa bb, so that segments down to a few eps from parallel keep
    # digits. Divided by aa + bb as above.
    scale = safe_divide(1.0, total, total > 0)
    if len(offset) == 3:
        normal = vscale(scale, vcross(along_a, along_b))
        normal_squared = vdot(normal, normal)
        numerator = vdot(normal, vscale(scale, vcross(along_b, offset)))
    else:
        normal = scale * vcross2(along_a, along_b)
        normal_squared = normal * normal
        numerator = normal * scale * vcross2(along_b, offset)
    crossing = normal_squared > 16 * eps * aa * bb
    stationary = safe_divide(numerator, normal_squared, normal_squared > (16 * eps) ** 2 * aa * bb)
    s_first, t_first, first = descend(jnp.clip(stationary, 0.0, 1.0))
    s_second, t_second, second = descend(jnp.ones_like(aa))
    use_second = second < first
    return (where(use_second, s_second, s_first), where(use_second, t_second, t_first),
            crossing)


def orthonormal_basis(normal):
    """Two unit vectors completing a unit 3D `normal` to a right-handed orthonormal basis
    (Duff et al. 2017: branch-free; continuous except where normal's z changes sign)."""
    x, y, z = normal[0], normal[1], normal[2]
    sign = where(z >= 0, 1.0, -1.0).astype(normal.dtype)
    scale = -1.0 / (sign + z)
    mixed = x * y * scale
    first = jnp.stack([1.0 + sign * x * x * scale, sign * mixed, -sign * x])
    second = jnp.stack([mixed, sign + y * y * scale, -y])
    return first, second


def extremes(axes: list[jax.Array], points):
    """(min, max) over points of axis . point, (C,) each, for axes given as D component
    arrays (C,): a select chain over the few points (rules 1-3), so a tie sends the whole
    gradient to one point."""
    low = high = None
    rows = as_vecs(points)
    for v in range(points.shape[0]):
        p = total(mul(axis, coordinate) for axis, coordinate in zip(axes, rows[v],
                                                                  strict=True))
        low = p if low is None else where(p < low, p, low)
        high = p if high is None else where(p > high, p, high)
    return low, high


SELECT_CHAIN_POINTS = 10
"""`largest_magnitude` takes a select chain over at most this many points, a reduction over
more."""


def largest_magnitude(points):
    """() max over the points (V, D) of |coordinate|: a shape's extent, for tolerances. By a
    select chain over at most `SELECT_CHAIN_POINTS` points (rule 2: no reduction pass over
    the vertex axis), by a reduction over more: a chain over two 20-vertex hulls' 120
    coordinates was a 600-line kernel, compiled in every hull distance."""
    if points.shape[0] > SELECT_CHAIN_POINTS:
        return jnp.max(jnp.abs(points))
    largest = None
    rows = as_vecs(points)
    for v in range(points.shape[0]):
        for k in range(points.shape[1]):
            size = jnp.abs(rows[v][k])
            largest = size if largest is None else where(size > largest, size, largest)
    return largest


# --------------------------------------------------------------------------------------------
# Scalar form: a vector as a tuple of D scalars. Under `vmap` every scalar is one (N,) array,
# so iterative per-pair code (GJK, Newton steps) runs at the full vector width along the
# batch; small (S, D) arrays per pair would put the tiny axes innermost instead.
# --------------------------------------------------------------------------------------------

Vec = tuple
"""A vector as a tuple of D scalar arrays."""


def as_vec(vector) -> Vec:
    """A (D,) array as a Vec. Sliced rather than `columns`: a search's loop state goes
    through here every step, and there the unstack ran the 2D smooth search 5-10% slower."""
    return tuple(vector[i] for i in range(vector.shape[-1]))


def as_vecs(points) -> list[Vec]:
    """(V, D) points as a list of V Vecs."""
    return vecs_of_columns(columns(points))


def vecs_of_columns(point_columns) -> list[Vec]:
    """The V Vecs of points given as D columns (V,) each (rule 8)."""
    return [tuple(row) for row in zip(*(jnp.unstack(column) for column in point_columns),
                                      strict=True)]


def vadd(x: Vec, y: Vec) -> Vec:
    return tuple(add(a, b) for a, b in zip(x, y, strict=True))


def vsub(x: Vec, y: Vec) -> Vec:
    return tuple(sub(a, b) for a, b in zip(x, y, strict=True))


def vscale(s, x: Vec) -> Vec:
    return tuple(mul(s, a) for a in x)


def vsum(vectors: list[Vec]) -> Vec:
    total = vectors[0]
    for vector in vectors[1:]:
        total = vadd(total, vector)
    return total


def vdot(x: Vec, y: Vec):
    return total(mul(a, b) for a, b in zip(x, y, strict=True))


def vcross(x: Vec, y: Vec) -> Vec:
    return (sub(mul(x[1], y[2]), mul(x[2], y[1])), sub(mul(x[2], y[0]), mul(x[0], y[2])),
            sub(mul(x[0], y[1]), mul(x[1], y[0])))


def vcross2(x: Vec, y: Vec):
    """2D cross product, a scalar."""
    return sub(mul(x[0], y[1]), mul(x[1], y[0]))


def vrotate(rows: list[Vec], x: Vec) -> Vec:
    """R x for a rotation given by its rows as Vecs (`as_vecs(rotation)`)."""
    return tuple(vdot(row, x) for row in rows)


def vrotate_back(rows: list[Vec], x: Vec) -> Vec:
    """R^T x for a rotation given by its rows as Vecs: the inverse of `vrotate`."""
    return tuple(total(mul(row[k], component) for row, component in zip(rows, x, strict=True))
                 for k in range(len(x)))


def vselect(condition, x: Vec, y: Vec) -> Vec:
    return tuple(where(condition, a, b) for a, b in zip(x, y, strict=True))


def support_index(direction: Vec, points: list[Vec]):
    """Index () int32 of the first of `points` with the largest projection on `direction`,
    by a select chain (rules 2-3); padding rows, which repeat row 0, never win over it.
    Materialised (rule 5): at a tie, two fused copies of the chain could round differently
    and pick different points, so every consumer must read this one value."""
    best_index = jnp.zeros((), jnp.int32)
    best = vdot(direction, points[0])
    for v in range(1, len(points)):
        p = vdot(direction, points[v])
        better = p > best
        best = where(better, p, best)
        best_index = where(better, v, best_index)
    return materialize(best_index)


def take_vec(points: list[Vec], index) -> Vec:
    """points[index] by a select chain over the few points (elementwise; a batched gather is
    not)."""
    chosen = points[0]
    for v in range(1, len(points)):
        chosen = vselect(index == v, points[v], chosen)
    return chosen


def materialize(tree):
    """The same values, computed once and stored (rule 5): each leaf goes through a window
    maximum of itself and one padding entry holding the smallest value, a pass XLA does not
    fuse into the consumers. (A plain reduction over a stack of two is rewritten into an
    elementwise maximum when the leaf is a scalar, as in an unbatched program, and its
    producer is then copied into every consumer: `tests/test_kernels.py`.) Exact, NaN
    included. Each leaf is stored on its own: store one decision (an index, a code) and
    derive the other outputs from it, since two leaves computed by two chains can round a
    tie differently."""
    def stored(leaf):
        if leaf.dtype == jnp.bool_:
            return stored(leaf.astype(jnp.int8)).astype(jnp.bool_)
        if jnp.issubdtype(leaf.dtype, jnp.floating):
            return _stored_float(leaf)
        return _window_of_one(leaf, jnp.asarray(jnp.iinfo(leaf.dtype).min, leaf.dtype),
                              jax.lax.max)
    return jax.tree.map(stored, tree)


def _window_of_one(leaf, padding, operation):
    """`operation` of the leaf and `padding` (its identity): the same values, written by a
    window pass XLA does not fuse into the consumers. The window covers the leaf and the
    padding before it along a new axis of length 1, so the stored array is the leaf's size.
    (A running maximum over a stack of two stores twice that and copies the half that is read
    into a pass of its own.)"""
    ndim = jnp.ndim(leaf)
    return jax.lax.reduce_window(leaf[None], padding, operation, (2,) + (1,) * ndim,
                                 (1,) * (ndim + 1), ((1, 0),) + ((0, 0),) * ndim)[0]


@jax.custom_jvp
def _stored_float(leaf):
    return _window_of_one(leaf, jnp.asarray(-jnp.inf, leaf.dtype), jax.lax.max)


@_stored_float.defjvp
def _stored_float_jvp(primals, tangents):
    # The identity's derivative. JAX would differentiate the window maximum with a window
    # pass of its own (select_and_gather_add) per stored leaf in every linearised program;
    # the stored value's derivative needs none.
    return _stored_float(primals[0]), tangents[0]


def store_cotangent(tree):
    """The same values; in reverse mode each leaf's cotangent is stored (summed in a window
    pass of its own, as `materialize` stores values: rule 5 for the gradient), so that
    everything the gradient builds from it reads the stored cotangent instead of recomputing
    it. Without it XLA fused the box kernel's whole cotangent graph (about 600 operations)
    into the pass that writes each pose's 3 x 3 rotation gradient, evaluated once per entry:
    the gradient of box `penetration` took 101 ms on 1e4 pairs, 1.6 ms with the rotation's
    entries, the axis and b's axis stored (`_sat._parallelepiped_search`; 2-core AMD EPYC).
    Forward mode gets the same values, the tangent stored by that window sum too."""
    return jax.tree.map(_cotangent_stored, tree)


@jax.custom_jvp
def _cotangent_stored(leaf):
    return leaf


@_cotangent_stored.defjvp
def _cotangent_stored_jvp(primals, tangents):
    # A window sum (its padding a concrete NumPy zero, so that JAX takes its transposable
    # sum primitive): linear, and its transpose stores the cotangent the same way.
    tangent = tangents[0]
    return primals[0], _window_of_one(tangent, np.zeros((), tangent.dtype), jax.lax.add)
