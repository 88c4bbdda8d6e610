"""Smooth signed distance: the exact max-over-axes formula with soft extremes over vertices.

The exact signed distance is sd = max over unit axes u of gap(u), gap(u) = min_b u.b -
max_a u.a (see `_closest`). The smooth one softens the two extremes over vertices with
log-sum-exp at temperature tau (a length) and keeps the maximum over axes exact:

    soft_gap(u) = -tau log sum_b exp(-u.b / tau) - tau log sum_a exp(u.a / tau),
    smooth = max over unit u of soft_gap(u).

Bounds. Log-sum-exp exceeds the maximum by at most tau log n, so for every u
gap(u) - tau log(n_a n_b) <= soft_gap(u) <= gap(u) (n_a, n_b: real vertex counts). The search
below starts at the exact maximiser u* and only ever accepts steps that raise soft_gap, so

    sd - tau log(n_a n_b) <= soft_gap(u*) <= smooth <= max over u of gap(u) = sd.

Gradient. soft_gap is smooth in the axis, the poses and the vertices. By the envelope theorem
the gradient of the smooth value is that of soft_gap at the maximising axis held fixed:
(soft-argmin point of b) - (soft-argmax point of a) projected on u, a convex combination of
vertices. Its derivative with respect to b's translation is exactly u (norm 1, so the value
is 1-Lipschitz in translation, as the exact signed distance is), and with respect to
rotations and vertices it is bounded by the shapes' size. Away from contact the maximiser is
unique and depends smoothly on the inputs (soft_gap = -H(u) with H the soft support function
of A - B, convex, and the origin outside A - B makes the maximum over the sphere the maximum
over the ball: a strictly concave problem), so the smooth value is infinitely differentiable
there. When the shapes overlap, soft_gap can have several local maxima on the sphere (one near
each penetration direction); the search follows the one at the exact penetration axis, and
where two penetration directions tie the gradient switches between them (a kink, stated in
the README's contract).

Search. Newton's method on the sphere (in the tangent plane at u: the Riemannian gradient and
Hessian of soft_gap), with a trust region: a step is taken only if it raises soft_gap, and the
region grows after a success and shrinks after a failure. Each step needs, per shape, the
softmax weights of the projections and their first and second moments; the loop keeps those
moments as its state, so every quantity XLA stores is computed once (see `_kernels`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxsat import _kernels as kernels
from jaxsat._closest import exact_distance, support_gap
from jaxsat._halfspace import HalfSpace, check_kinds
from jaxsat._kernels import Vec, dot, materialize, mul, safe_divide, sub, where
from jaxsat._pair import PairFrame
from jaxsat._sat import sat_runner_up
from jaxsat._shapes import Polytope

__all__ = ["NEWTON_STEPS", "smooth_signed_distance", "smoothing_error_bound"]

NEWTON_STEPS = 4
"""Trust-region Newton steps in one pass of a search. After a pass, a search whose Newton
step is short enough (`_converged`) takes that step unchecked and is done; the others go on
for another pass, up to `SEARCH_PASSES`. On the benchmarks' random pairs (tau = 0.005, 1% of
the shapes' size, float32), one pass leaves 6.5% of 2D polygon searches, 17% of box and 21%
of 20-vertex hull searches not done, two passes 0.1%, 1.3% and 1.9%. The fixed 10 steps from
every start this replaced gave values and gradients equal to these within 2e-7 and 1.1e-5
(float64: 5e-16 and 2e-14) and took 1.09-1.18x the CPU time at 1e4 pairs (20-vertex hulls,
2D polygons, boxes), 1.15x (boxes) and 1.41x (2D) at 1e5, on a 2-core AMD EPYC. Passes of 3
and 5 steps ran about as many steps in all, in more or in fuller chunks."""

SEARCH_PASSES = 5
"""The most passes of `NEWTON_STEPS` a search takes: one hull pair's maximum lay 29 degrees
from the exact axis and needed 13 steps."""

UNROLLED_VERTICES = 10
"""Shapes of at most this many vertices (padding included) take a step's moments, and the
soft extremes, in component form; larger ones by reductions (`_side_moments`). Value and
gradient of the smooth distance on a 2-core AMD EPYC, component form over reductions: 2D
polygons 0.53-0.63x at 4-11 vertices, but 1.4x at 12 (XLA then splits a step into more
passes); boxes 0.6x; 3D hulls 0.84x at 10 vertices, 0.81x at 12, 1.09x at 20. Compiling
takes about 1.5x longer."""

_FIRST_RADIUS = 4.0
"""The first trust radius, in units of tau / (the pair's extent): the angle over which the
soft extremes change their weights (capped at _MAX_RADIUS)."""

_MAX_RADIUS = 1.0
"""The largest trust radius, in radians."""

_SECOND_START_ANGLE = 4.0
"""The second start is at least this many tau / (the pair's extent) radians from the first
(at least 1e-3, at most 0.5): nearer axes lie in the first one's soft basin."""


class _Moments(NamedTuple):
    """soft_gap and its first two derivatives in the axis, at one axis (a's frame), in
    scalar form (see `_kernels`): every entry one scalar per pair."""

    value: jax.Array
    """() soft_gap(u)."""
    gradient: Vec
    """D scalars: q - p, the soft-argmin point of b minus the soft-argmax point of a."""
    spread: tuple[Vec, ...]
    """D x D scalars: covariance of a's softmax weights plus b's; the Hessian is -spread/tau."""


def _soft_max(projections, mask, tau):
    """tau log sum exp(x / tau) over the real entries (component form up to
    `UNROLLED_VERTICES` entries, as `_side_moments`)."""
    if projections.shape[0] > UNROLLED_VERTICES:
        top = jnp.max(where(mask, projections, -jnp.inf))
        # Padding never reaches exp (double where): no inf * 0 in any gradient.
        terms = where(mask, jnp.exp((where(mask, projections, top) - top) / tau), 0.0)
        return top + tau * jnp.log(jnp.sum(terms))
    entries, real = jnp.unstack(projections), jnp.unstack(mask)
    # The shift is held fixed, since the result does not depend on it, so that no rounding
    # residue of its derivative (1 - sum of the weights) reaches the vertex it came from.
    top = jax.lax.stop_gradient(_largest_real(entries, real))
    summed = kernels.total(where(m, jnp.exp((where(m, x, top) - top) / tau), 0.0)
                           for x, m in zip(entries, real, strict=True))
    return top + tau * jnp.log(summed)


def _largest_real(entries, real):
    """The largest of the entries whose `real` flag is set, by a select chain (`_kernels`
    rules 2-3). Entry 0 is real (padding repeats it), and a padding copy, which XLA may round
    1 ulp differently in another fusion, never wins."""
    top = entries[0]
    for entry, m in zip(entries[1:], real[1:], strict=True):
        top = where(m & (entry > top), entry, top)
    return top


class _Side(NamedTuple):
    """What the search needs of one shape's vertices, set up once: the vertices centred on one
    of them (b's negated, so that both soft extremes are soft maxima) and per vertex the
    features [1, x, x x'] whose softmax-weighted sums give every moment in one pass."""

    points: jax.Array
    """(V, D) float: the vertices minus the centre (b: minus that)."""
    offset: jax.Array
    """(D,) float: the centre (b: minus it); projections add axis . offset."""
    features: jax.Array
    """(V, K) float: 1, the point's coordinates, the upper triangle of x x'."""
    mask: jax.Array
    """(V,) bool: real vertices."""
    coordinates: tuple[jax.Array, ...]
    """D arrays (V,): the points' coordinates, split once outside the search's loop."""


class _Summary(NamedTuple):
    """Both shapes' `_Side`s: a's, and b's negated."""

    a: _Side
    b: _Side

    @property
    def offsets(self) -> jax.Array:
        """(2, D) float: a's centre and minus b's centre."""
        return jnp.stack([self.a.offset, self.b.offset])

    @property
    def extent(self) -> jax.Array:
        """() float: the largest centred coordinate of either shape."""
        return jnp.maximum(jnp.max(jnp.abs(self.a.points)), jnp.max(jnp.abs(self.b.points)))


def _side(vertices, mask, sign: float) -> _Side:
    # Centred on one vertex, so that far-apart shapes lose no digits in the moments.
    centre = vertices[0]
    points = sign * (vertices - centre)
    dim = points.shape[-1]
    features = jnp.stack([jnp.ones_like(points[:, 0]), *(points[:, k] for k in range(dim)),
                          *(points[:, k] * points[:, m] for k, m in _upper(dim))], axis=-1)
    return _Side(points, sign * centre, features, mask, tuple(kernels.columns(points)))


def _summary(frame: PairFrame) -> _Summary:
    return _Summary(_side(frame.a.vertices, frame.a.vertex_mask, 1.0),
                    _side(frame.b_vertices, frame.b.vertex_mask, -1.0))


def _upper(dim: int) -> list[tuple[int, int]]:
    return [(k, m) for k in range(dim) for m in range(k, dim)]


def _side_moments(side: _Side, axis: Vec, tau, store_weights: bool = False
                  ) -> jax.Array:
    """(K + 1,): the side's soft extreme (tau log sum exp of its projections) and the
    softmax-weighted sums of its features [1, x, x x'], the moments a step needs.

    Up to `UNROLLED_VERTICES` vertices, in component form: the maximum a select chain, each
    sum a Python sum over the vertices, so everything is elementwise and fuses into the
    step's few passes (`_kernels` rules 1, 2 and 7). Above, as reductions over the vertex axis:
    three passes over a batch (the maximum, the weights, stored because every sum reads them,
    and the sums in one reduction).

    `store_weights` stores the component-form weights first (`_kernels` rule 5). The search's
    first moments, outside its loop, need it: each of the K + 1 sums there recomputed every
    exponential (2D at 1e5 pairs: 0.77x the smooth value+grad's time). So does the loop step,
    now that the searches run in cache-sized chunks (`SEARCH_CHUNK_SIZE`): smooth value+grad
    0.93-0.95x the time at 1e4 pairs and 0.96x at 1e5, 2D polygons and boxes (over one vmap
    of the whole batch, storing them had cost 1.06x)."""
    dim = len(axis)
    offset = kernels.vdot(kernels.as_vec(side.offset), axis)
    if side.points.shape[0] > UNROLLED_VERTICES:
        projections = kernels.total(side.points[:, k] * axis[k] for k in range(dim))
        top = jnp.max(where(side.mask, projections, -jnp.inf))
        shifted = where(side.mask, projections - top, 0.0)
        weights = materialize(where(side.mask, jnp.exp(shifted / tau), 0.0))
        sums = jnp.sum(weights[:, None] * side.features, axis=0)
        return jnp.concatenate([(top + tau * jnp.log(sums[0]) + offset)[None], sums])
    rows = list(zip(*(jnp.unstack(c) for c in side.coordinates), strict=True))
    real = jnp.unstack(side.mask)
    projections = [kernels.vdot(row, axis) for row in rows]
    top = _largest_real(projections, real)
    weights = [where(m, jnp.exp((p - top) / tau), 0.0) for p, m in zip(projections, real,
                                                                        strict=True)]
    if store_weights:
        weights = jnp.unstack(materialize(jnp.stack(weights)))
    total = kernels.total(weights)
    firsts = [kernels.total(mul(w, row[k]) for w, row in zip(weights, rows, strict=True))
              for k in range(dim)]
    seconds = [kernels.total(mul(mul(w, row[k]), row[m]) for w, row in zip(weights, rows,
                                                                            strict=True))
               for k, m in _upper(dim)]
    return jnp.stack([top + tau * jnp.log(total) + offset, total, *firsts, *seconds])


def _packed_moments(summary: _Summary, axis: Vec, tau, store_weights: bool = False
                    ) -> tuple[tuple[jax.Array, ...], tuple[jax.Array, ...]]:
    """`_side_moments` of a (row 0) and of b negated (row 1), each taken apart into K + 1
    scalars (`Vec` form), so that a search's loop state holds them as separate arrays, each
    contiguous over the batch. As one (2, K + 1) array a pair, every reader of one entry (a
    loop step has about ten) streamed the whole array through the cache: box pairs' smooth
    value and gradient took 1.2x as long (2D polygons and 20-vertex hulls 1.01x), on a
    2-core AMD EPYC. Carrying the combined moments instead (soft_gap, its gradient and the
    spread's upper triangle: 6 scalars in 2D, 10 in 3D), with the totals inverted once,
    halved a 2D step's passes (69 to 33), yet the smooth value and gradient took 1.05-1.07x
    as long (2D polygons, 1e4 pairs, one core)."""
    return (tuple(jnp.unstack(_side_moments(summary.a, axis, tau, store_weights))),
            tuple(jnp.unstack(_side_moments(summary.b, axis, tau, store_weights))))


def _unpack(summary: _Summary, packed) -> _Moments:
    """The scalar-form _Moments of soft_gap from `_packed_moments`' output."""
    dim = summary.a.points.shape[-1]
    total = (packed[0][1], packed[1][1])
    mean = [[packed[s][2 + k] / total[s] for k in range(dim)] for s in (0, 1)]
    spread = [[None] * dim for _ in range(dim)]
    for index, (k, m) in enumerate(_upper(dim)):
        entry = kernels.total(sub(packed[s][2 + dim + index] / total[s],
                                  mul(mean[s][k], mean[s][m])) for s in (0, 1))
        spread[k][m] = spread[m][k] = entry
    # Row 0 is a as it is, row 1 is b negated: b's soft minimum is minus row 1's soft
    # maximum, and b's soft-argmin point is minus its row's mean.
    gradient = tuple(-(mean[1][k] + summary.offsets[1, k]) - (mean[0][k] + summary.offsets[0, k])
                     for k in range(dim))
    return _Moments(value=-packed[1][0] - packed[0][0], gradient=gradient,
                    spread=tuple(tuple(row) for row in spread))


def _tangent_basis(axis: Vec) -> list[Vec]:
    """D - 1 orthonormal vectors across a unit axis."""
    if len(axis) == 2:
        return [(-axis[1], axis[0])]
    one, zero = jnp.ones_like(axis[0]), jnp.zeros_like(axis[0])
    use_x = jnp.abs(axis[0]) < 0.6
    helper = kernels.vselect(use_x, (one, zero, zero), (zero, one, zero))
    first = kernels.vcross(axis, helper)
    first = kernels.vscale(jax.lax.rsqrt(jnp.maximum(kernels.vdot(first, first), jnp.finfo(
        axis[0].dtype).tiny)), first)
    return [first, kernels.vcross(axis, first)]


def _riemannian(axis: Vec, moments: _Moments, tau):
    """(tangent basis, gradient (m scalars), Hessian (m x m scalars)) of soft_gap on the
    sphere: the Euclidean Hessian -spread / tau in the tangent plane, minus the normal
    derivative (u . gradient) times the identity (the sphere's curvature)."""
    basis = _tangent_basis(axis)
    gradient = tuple(kernels.vdot(e, moments.gradient) for e in basis)
    spread_times = [tuple(kernels.vdot(row, e) for row in moments.spread) for e in basis]
    normal = kernels.vdot(axis, moments.gradient)
    hessian = tuple(tuple(-kernels.vdot(basis[i], spread_times[j]) / tau
                          - (normal if i == j else 0.0) for j in range(len(basis)))
                    for i in range(len(basis)))
    return basis, gradient, hessian


def _trust_region_step(gradient, hessian, radius):
    """The step d (m scalars) maximising the model g . d + d' H d / 2 over |d| <= radius, for
    m = 1 or 2 (the tangent plane of the sphere in 2D or 3D), and the model's increase.

    Newton's step when H is negative definite and the step fits; otherwise the step on the
    boundary with (H - mu I) d = -g, mu >= max(0, largest eigenvalue), found by Newton's
    method on 1 / |d(mu)| - 1 / radius (Moré and Sorensen), with the eigenvector of the
    largest eigenvalue added where g has no part along it (the "hard case", as at a saddle
    between two corners touching, where the soft gap rises on both sides)."""
    dtype = radius.dtype
    eps = jnp.finfo(dtype).eps
    tiny = jnp.finfo(dtype).tiny
    if len(gradient) == 1:
        curvature, slope = hessian[0][0], gradient[0]
        newton = -safe_divide(slope, curvature, curvature < 0)
        fits = (curvature < 0) & (jnp.abs(newton) <= radius)
        sense = where(slope < 0, -1.0, 1.0).astype(dtype)
        step = (where(fits, newton, sense * radius),)
        return step, slope * step[0] + 0.5 * curvature * step[0] ** 2
    (h00, h01), (_, h11) = hessian
    # Eigen-decomposition of the symmetric 2 x 2 Hessian: values low <= high.
    half_trace = 0.5 * (h00 + h11)
    half_gap = jnp.sqrt(0.25 * (h00 - h11) ** 2 + h01**2)
    high, low = half_trace + half_gap, half_trace - half_gap
    scale = jnp.maximum(jnp.maximum(jnp.abs(h00), jnp.abs(h11)), jnp.abs(h01)) + tiny
    first = (h01, high - h00)
    second = (high - h11, h01)
    first_squared, second_squared = kernels.vdot(first, first), kernels.vdot(second, second)
    use_first = first_squared >= second_squared
    chosen = kernels.vselect(use_first, first, second)
    chosen_squared = where(use_first, first_squared, second_squared)
    found = chosen_squared > (eps * scale) ** 2
    norm = jax.lax.rsqrt(where(found, chosen_squared, 1.0))
    top = (where(found, chosen[0] * norm, 1.0), where(found, chosen[1] * norm, 0.0))
    bottom = (-top[1], top[0])
    along_top, along_bottom = kernels.vdot(top, gradient), kernels.vdot(bottom, gradient)
    # d(mu) = g_top / (mu - high) top + g_bottom / (mu - low) bottom, for mu > high.
    newton_top = -safe_divide(along_top, high, high < 0)
    newton_bottom = -safe_divide(along_bottom, low, low < 0)
    fits = (high < 0) & (newton_top**2 + newton_bottom**2 <= radius**2)
    floor = jnp.maximum(high, 0.0)
    mu = floor + jnp.abs(along_top) / radius + eps * scale
    for _ in range(4):
        inverse_top = safe_divide(1.0, mu - high, mu > high)
        inverse_bottom = safe_divide(1.0, mu - low, mu > low)
        length = jnp.sqrt(along_top**2 * inverse_top**2 + along_bottom**2 * inverse_bottom**2
                          + tiny)
        # phi(mu) = 1/|d| - 1/radius is nearly linear in mu; phi' = (sum g_i^2 / (mu -
        # l_i)^3) / |d|^3.
        derivative = (along_top**2 * inverse_top**3 + along_bottom**2 * inverse_bottom**3
                      ) / length**3
        mu = jnp.maximum(mu - safe_divide(1.0 / length - 1.0 / radius, derivative,
                                          derivative > 0), floor)
    boundary_top = along_top * safe_divide(1.0, mu - high, mu > high)
    boundary_bottom = along_bottom * safe_divide(1.0, mu - low, mu > low)
    # Hard case: too short even as mu reaches the largest eigenvalue (g has (almost) no part
    # along its eigenvector): add that eigenvector up to the boundary.
    short = radius**2 - boundary_top**2 - boundary_bottom**2
    sense = where(along_top < 0, -1.0, 1.0).astype(dtype)
    boundary_top = boundary_top + sense * jnp.sqrt(jnp.maximum(short, 0.0))
    step_top = where(fits, newton_top, boundary_top)
    step_bottom = where(fits, newton_bottom, boundary_bottom)
    step = kernels.vadd(kernels.vscale(step_top, top), kernels.vscale(step_bottom, bottom))
    gain = (along_top * step_top + along_bottom * step_bottom
            + 0.5 * (high * step_top**2 + low * step_bottom**2))
    return step, gain


def _search(frame: PairFrame, tau, start, radius):
    """One pass of a search for the axis maximising soft_gap (values only): `NEWTON_STEPS`
    trust-region Newton steps on the sphere from `start`, each accepted only if soft_gap
    rises; the region (first radius `radius`, or where that is 0 `_FIRST_RADIUS`) grows when
    the model predicted the rise well and shrinks when it did not. The loop carries the axis,
    the radius, the step stretch and the axis's moments (`_packed_moments`), and everything
    between two packed moments is scalar arithmetic, so a step is a few passes over a batch.

    Returns the axis, minus soft_gap there (as tracked by the loop), the squared norm of
    soft_gap's gradient on the sphere there, the radius, and whether the search is done: its
    Newton step is shorter than `_converged`'s length, and the axis returned has taken it
    (unchecked: from there Newton's method lands within rounding of the maximum)."""
    summary = _summary(frame)
    extent = summary.extent
    rounding = 16 * jnp.finfo(frame.dtype).eps * (extent + jnp.max(jnp.abs(summary.offsets)))
    eps = jnp.finfo(frame.dtype).eps

    def step(_, state):
        axis, packed, radius, boost = state
        axis = kernels.as_vec(axis)
        moments = _unpack(summary, packed)
        basis, gradient, hessian = _riemannian(axis, moments, tau)
        move, predicted = _trust_region_step(gradient, hessian, radius)
        # On an exponential tail of the soft extremes (far from the maximum across a range of
        # equally good axes) Newton's step is only about tau / extent and the rise exceeds
        # the model's: there the step is stretched by `boost`, doubled after each success.
        length = jnp.sqrt(kernels.vdot(move, move))
        stretch = safe_divide(jnp.minimum(boost * length, _MAX_RADIUS), length, length > 0)
        trial = _turned(axis, basis, [stretch * m for m in move])
        # Stored once (rule 5 of `_kernels`): the trial's moments, and the decisions, read by
        # every output below.
        trial = kernels.materialize(trial)
        trial_packed = _packed_moments(summary, trial, tau, store_weights=True)
        trial_moments = _unpack(summary, trial_packed)
        rise = trial_moments.value - moments.value
        ratio = safe_divide(rise, predicted, predicted > 0)
        plain = boost == 1.0
        # Near the maximum the rise (about g^2 / |H|) drops below the value's rounding before
        # the gradient g is small: there, a step that shrinks the gradient is taken too.
        trial_gradient = _riemannian(trial, trial_moments, tau)[1]
        steeper = kernels.vdot(gradient, gradient) <= kernels.vdot(trial_gradient, trial_gradient)
        better = (rise > 0) | ((rise >= -rounding) & ~steeper)
        tail = plain & (ratio > 1.1) & (length < 0.99 * radius)
        shrink = plain & (ratio < 0.25)
        grow = plain & (ratio > 0.75) & (length > 0.99 * radius)
        # Stretching goes on only while soft_gap still rises along the way at the trial (its
        # gradient there has a positive part along the travel, in the tangent plane): past
        # the maximum, a stretched step would overshoot further and be rejected.
        travel = kernels.vsub(trial, axis)
        ahead = (kernels.vdot(trial_moments.gradient, travel) - kernels.vdot(travel, trial)
                 * kernels.vdot(trial_moments.gradient, trial)) > 0
        bits = [flag.astype(jnp.int32) for flag in (better, better & (tail | ~plain) & ahead,
                                                     shrink, grow)]
        code = kernels.materialize(bits[0] + 2 * bits[1] + 4 * bits[2] + 8 * bits[3])
        better, stretch_more = code % 2 == 1, (code // 2) % 2 == 1
        shrink, grow = (code // 4) % 2 == 1, (code // 8) % 2 == 1
        radius = where(shrink, 0.25 * length, where(grow, 2.0 * radius, radius))
        radius = jnp.clip(radius, 16 * eps, _MAX_RADIUS)
        boost = where(stretch_more, jnp.minimum(2.0 * boost, 64.0), 1.0)
        return (where(better, jnp.stack(trial), jnp.stack(axis)),
                jax.tree.map(lambda new, old: where(better, new, old), trial_packed, packed),
                radius, boost.astype(radius.dtype))

    # The radius and the boost are written from the start (0 * start is 0) so that under
    # `vmap` (over pairs, and over the two starts) the whole state is batched from the start:
    # each loop batching rule then traces the step once less.
    zero = 0 * start[0]
    radius = where(radius > 0, radius, jnp.minimum(_FIRST_RADIUS * tau / extent, _MAX_RADIUS)
                   ) + zero
    state = (start, _packed_moments(summary, kernels.as_vec(start), tau, store_weights=True),
             radius, 1 + zero)
    axis, packed, radius, _ = jax.lax.fori_loop(0, NEWTON_STEPS, step, state)
    axis = kernels.as_vec(axis)
    basis, gradient, hessian = _riemannian(axis, _unpack(summary, packed), tau)
    move, done = _newton_step(gradient, hessian, _converged(tau, extent))
    return (jnp.stack(kernels.vselect(done, _turned(axis, basis, move), axis)),
            packed[1][0] + packed[0][0], kernels.vdot(gradient, gradient), radius, done)


def _converged(tau, extent):
    """The squared length (rad^2) of a Newton step below which a search is done.

    soft_gap's k-th derivative in the axis is of order extent^k / tau^(k-1), so a Newton
    step from an axis e radians off the maximum lands about (extent / tau) e^2 off it: within
    eps radians where e^2 <= eps tau / extent (float32 at tau = 1% of the extent: 3.5e-5 rad;
    float64 1.5e-9)."""
    return jnp.finfo(tau.dtype).eps * tau / extent


def _newton_step(gradient, hessian, longest):
    """Newton's step d = -H^-1 g (m scalars, m = 1 or 2) on the tangent plane, and whether it
    leads to a maximum and its squared length is at most `longest` (H negative definite)."""
    determinant = _determinant(hessian)
    definite = determinant < 0 if len(gradient) == 1 else (hessian[0][0] < 0) & (
        determinant > 0)
    step = tuple(-d for d in _solve(hessian, gradient, definite))
    return step, definite & (kernels.vdot(step, step) <= longest)


def _determinant(hessian):
    """det H of the tangent-plane Hessian (m x m scalars, m = 1 or 2)."""
    if len(hessian) == 1:
        return hessian[0][0]
    (h00, h01), (_, h11) = hessian
    return h00 * h11 - h01**2


def _solve(hessian, right, valid):
    """H^-1 right (m scalars, m = 1 or 2): the adjugate's product over det H, divided only
    where `valid` (safe_divide: no 0/0 where H is singular), else 0."""
    determinant = _determinant(hessian)
    if len(right) == 1:
        return (safe_divide(right[0], determinant, valid),)
    (h00, h01), (_, h11) = hessian
    return (safe_divide(h11 * right[0] - h01 * right[1], determinant, valid),
            safe_divide(h00 * right[1] - h01 * right[0], determinant, valid))


def _tangent(move, basis) -> Vec:
    """The tangent vector with coordinates `move` in the tangent `basis`."""
    return kernels.vsum([kernels.vscale(m, e) for m, e in zip(move, basis, strict=True)])


def _turned(axis, basis, move) -> Vec:
    """The unit axis at axis + `move` (tangent coordinates), back on the sphere."""
    moved = kernels.vadd(axis, _tangent(move, basis))
    return kernels.vscale(jax.lax.rsqrt(kernels.vdot(moved, moved)), moved)


def soft_gap(frame: PairFrame, axis, tau):
    """soft_gap(axis) for a prepared pair (differentiable in the frame)."""
    soft_a = _soft_max(dot(frame.a.vertices, axis), frame.a.vertex_mask, tau)
    soft_b = _soft_max(-dot(frame.b_vertices, axis), frame.b.vertex_mask, tau)
    return -soft_b - soft_a


def _passes(frame: PairFrame, tau, start):
    """A whole search from `start`: passes of `_search` until one is done or
    `SEARCH_PASSES` have run; its (axis, loss, slope)."""
    def one_more(state):
        axis, _, _, radius, _, count = state
        return (*_search(frame, tau, axis, radius), count + 1)

    zero = 0 * start[0]
    inf = jnp.inf + zero
    state = (start, inf, inf, zero, zero > 0, jnp.zeros((), jnp.int32))
    return jax.lax.while_loop(lambda state: ~state[4] & (state[5] < SEARCH_PASSES), one_more,
                              state)[:3]


@jax.custom_batching.custom_vmap
def _searches(frame: PairFrame, tau, starts, needed, rival, margin):
    """A whole search (`_passes`) from the first of the (2, D) `starts`, then from the second
    where `_second_start` wants one, else (the second start, inf, inf): a result that never
    wins the comparison in `_maximiser`. Under `vmap` the searches' passes run from a queue,
    and only the wanted second searches run (`_searches_vmap`)."""
    def search(wanted, index):
        found = _passes(frame, tau, starts[index])
        return where(index == 0, _second_start(needed, rival, margin, found[1]), wanted), found

    # A scan of two, so that the search is traced once (as under `vmap`).
    wanted, (axes, losses, slopes) = jax.lax.scan(search, needed, jnp.arange(2))
    wanted = jnp.stack([jnp.ones_like(needed), wanted])
    inf = jnp.asarray(jnp.inf, losses.dtype)
    return (where(wanted[:, None], axes, starts), where(wanted, losses, inf),
            where(wanted, slopes, inf))


def _second_start(needed, rival, margin, loss):
    """Whether the search from the runner-up runs, after the first search has ended at minus
    soft_gap `loss`: where it could end higher (`needed`, and `rival`, a bound on the maxima
    outside the first's basin, reaches the first's end; see `_maximiser`)."""
    return needed & (rival >= -loss - margin)


SEARCH_CHUNK_SIZE = {2: 2048, 3: 512}
"""The most search passes in one chunk, by dimension. Chunks keep a batch's search data in
the cache: 2D polygons' smooth value and gradient took 0.67-0.79x the time at 1e5 pairs in
chunks of 2,048 (0.85-0.89x at 1e4; 0.99x at 1e3) against one vmap over all searches.
Smaller chunks cost more passes (about 10 us a chunk in 2D, 80 us in 3D); since only the
wanted searches run, they also waste less on the last chunk, which those fill only in part:
box pairs, against chunks of 1/8 of the batch alone, 0.98x at 4,480 pairs, 0.89x at
1e4, 0.95x at 1e5; 20-vertex hulls 0.95x at 1e4 (a 2-core AMD EPYC). Half these sizes (1,024
and 256; same process, one core, both orders) gained nothing: 2D polygons 0.91x / 1.07x at
1e5 pairs, boxes 1.05x / 0.99x at 1e4 and 0.98x / 1.14x at 1e5, 20-vertex hulls 1.03x at 1e4."""

SEARCH_CHUNKS = 16
"""The fewest chunks of first searches, unless they would hold fewer than
`SMALLEST_SEARCH_CHUNK` pairs: a small batch's then fill all but the last. Against 8 chunks,
smooth value and gradient, same process, both orders: 2D polygons 0.92x / 0.93x the time at
1e4 pairs (chunks of 625 instead of 1,250), 0.97x / 0.99x at 4,480; boxes 0.94x / 0.95x and
20-vertex hulls 0.98x / 0.99x at 4,480 (a 2-core AMD EPYC, one core). The queue's tail (the
repeat passes and second searches after the first searches) fills its chunks only in part:
a second loop for it, in chunks of 1/8 the size once fewer than a chunk wait, took 0.87x /
0.94x the time for 2D polygons at 1e4 pairs, 0.98x / 0.99x for boxes, 1.03x for 2D at 1e3,
but its second copy of the search made compiling 1.5-1.6x as long: not kept."""

SMALLEST_SEARCH_CHUNK = 128
"""The fewest first searches a chunk holds when a batch is cut into `SEARCH_CHUNKS` for its
own sake (a batch of fewer pairs is one chunk): 16 chunks of 63 took 1.03-1.14x the time of
8 chunks of 125 on 1e3 2D pairs, the passes' fixed cost outweighing the shorter last chunk."""


@_searches.def_vmap
def _searches_vmap(axis_size, in_batched, frame, tau, starts, needed, rival, margin):
    """The batched `_searches`: the search passes (`_search`) run in chunks from a queue of
    (pair, start) slots. The queue starts with every pair's first start; after each chunk a
    search that is not done (and has passes left) goes back to the queue's end from where it
    stopped, and a first search that is done appends its pair's second search where
    `_second_start` wants one; other second searches give (the second start, inf, inf)
    without a search. A plain `vmap` would run every search for as many passes as the
    slowest needs, since a batched loop runs until its last member ends."""
    def batched(x, is_batched):
        return x if is_batched else jnp.broadcast_to(x, (axis_size, *jnp.shape(x)))

    frame, tau, starts, needed, rival, margin = jax.tree.map(
        batched, (frame, tau, starts, needed, rival, margin), tuple(in_batched))
    pairs, slots = axis_size, 2 * axis_size
    chunks = max(-(-pairs // SEARCH_CHUNK_SIZE[frame.dim]),
                 min(SEARCH_CHUNKS, -(-pairs // SMALLEST_SEARCH_CHUNK)))
    chunk = max(1, -(-pairs // chunks))
    # A ring: a slot is in the queue at most once at a time, so `slots` places hold every
    # waiting one and the chunk being read; read places are emptied as the ring comes round.
    size = slots + chunk
    starts = starts.reshape(slots, -1)
    # Slot 2 p + k is pair p's start k; `slots` marks an empty place (dropped when written).
    queue = jnp.full((size,), slots, jnp.int32).at[:pairs].set(
        2 * jnp.arange(pairs, dtype=jnp.int32))

    def search_chunk(state):
        done, length, queue, found = state
        places = (done + jnp.arange(chunk, dtype=jnp.int32)) % size
        picked = queue[places]
        queue = queue.at[places].set(slots)
        slot = jnp.minimum(picked, slots - 1)
        pair = slot // 2
        pair_frames, pair_taus = jax.tree.map(lambda x: x[pair], (frame, tau))
        # A waiting slot holds where it goes on from (at first, its start) in `found`.
        axis, loss, slope, radius, finished = jax.vmap(_search)(
            pair_frames, pair_taus, found[0][slot], found[3][slot])
        count = found[4][slot] + 1
        found = tuple(old.at[picked].set(new, mode="drop") for old, new in zip(
            found, (axis, loss, slope, radius, count), strict=True))
        real = picked < slots
        again = real & ~finished & (count < SEARCH_PASSES)
        second = real & ~again & (slot % 2 == 0) & jax.vmap(_second_start)(
            needed[pair], rival[pair], margin[pair], loss)
        entry = where(again, slot, where(second, slot + 1, slots))
        # Appended in order after every waiting slot (`jnp.nonzero` would trace a nested
        # `jnp.where`); places this chunk read are past, even where it read beyond the end.
        end = jnp.maximum(length, done + chunk)
        queued = entry < slots
        rank = jnp.cumsum(queued, dtype=jnp.int32) - 1
        queue = queue.at[where(queued, (end + rank) % size, size)].set(entry, mode="drop")
        return done + chunk, end + jnp.sum(queued, dtype=jnp.int32), queue, found

    inf = jnp.full((slots,), jnp.inf, starts.dtype)
    found = (starts, inf, inf, jnp.zeros((slots,), starts.dtype), jnp.zeros((slots,), jnp.int32))
    state = (jnp.zeros((), jnp.int32), jnp.full((), pairs, jnp.int32), queue, found)
    axes, losses, slopes = jax.lax.while_loop(lambda state: state[0] < state[1],
                                              search_chunk, state)[3][:3]
    return ((axes.reshape(pairs, 2, -1), losses.reshape(pairs, 2),
             slopes.reshape(pairs, 2)), (True, True, True))


@jax.custom_jvp
def _maximiser(frame: PairFrame, tau):
    """The unit axis (a's frame) maximising soft_gap: the better of the searches from two
    starts. The first is the exact maximiser, so that the result is within the bound. The
    second is the best SAT candidate more than a few tau / extent radians from the first
    (nearer ones share its basin): where two penetration directions tie, the local maximum
    near each is found, and taking the larger keeps the value continuous when they swap.
    Between values that tie within rounding, the axis where soft_gap is flatter wins. The
    second search runs only where it could end higher than the first (see below); under
    `vmap` on the CPU the others skip it, and each search runs only as many passes of
    `NEWTON_STEPS` as it needs (`_searches_vmap`). Skipping it where the exact distance
    exceeds c tau: box pairs' value and gradient 0.63x the time at 1e5 pairs (0.95x at 1e4),
    20-vertex hulls 0.92x; where no maximum outside the first's basin reaches sd - c tau,
    0.89-0.92x more for boxes (1e4, 1e5), 2D polygons 0.87x at 1e4 and 0.78x at 1e5 (which
    searched twice everywhere); where none reaches the first search's end, 0.82x / 0.85x
    more for 2D polygons (1e4 / 1e5), boxes 0.93x / 0.97x, 20-vertex hulls 0.97x, on a
    2-core AMD EPYC."""
    frozen, tau = jax.lax.stop_gradient((frame, tau))
    extent = jnp.max(jnp.abs(frozen.a.vertices)) + jnp.max(jnp.abs(frozen.b_vertices))
    apart = jnp.clip(_SECOND_START_ANGLE * tau / extent, 1e-3, 0.5)
    exact = exact_distance(frozen)
    runner_up, runner_up_gap = sat_runner_up(frozen, exact.axis, apart)
    starts = jnp.stack([exact.axis, runner_up])
    # The second search is needed only where it could end higher than the first (on the
    # CPU, which skips the others). Two cases where it cannot:
    # * The exact distance exceeds c tau (c = log(n_a n_b), `smoothing_error_bound`): then
    #   soft_gap > 0 at the first start already, and a positive maximum is the only one as
    #   high: where soft_gap > 0, gap > 0 too and soft_gap rises along every ray (each
    #   u.m > 0), so for two axes with soft_gap >= t > 0, concavity holds soft_gap >= t on
    #   the segment between them, and the rise along rays on the arc above it. A second
    #   maximum at least as high would be joined to the first by an arc that never dips
    #   below it.
    # * No maximum of gap outside the first's basin reaches the first search's end: the
    #   maxima of gap other than the first (below 0) are facet normals of the Minkowski
    #   difference, SAT candidates in one sense or the other, and soft_gap <= gap, so a
    #   maximum of soft_gap outside the first's basin ends no higher than the largest of
    #   them: the runner-up's gap (the candidates' better senses, away from the first
    #   axis), or the worse sense of a candidate near the first axis, within `apart` of its
    #   opposite, whose gap is at most gap(-axis) + extent * apart (gap is extent-Lipschitz
    #   on the sphere: |u.m - v.m| <= |m| |u - v|). In deep overlaps of near-symmetric pairs
    #   that opposite sense ties with the first (a box pair's soft maximum there was 1.5e-4
    #   higher). The first search's end is known only after it: `_searches` reads it, and
    #   before, the prefilter uses its lower bound soft_gap(exact axis) >= sd - c tau.
    #   Random 2D polygon pairs search twice at 4% (29% with the lower bound alone, 56%
    #   without), boxes 13% (30%), 20-vertex hulls 27% (50%).
    if jax.default_backend() == "cpu":
        # On the CPU the searches run in chunks (`_searches_vmap`), which keep their data in
        # the cache, and only the wanted second searches run.
        bound = smoothing_error_bound(frozen.a, frozen.b) * tau
        margin = 64 * jnp.finfo(frozen.dtype).eps * extent
        opposite_gap = support_gap(-exact.axis, frozen.a.vertices, frozen.b_vertices)
        rival = jnp.maximum(runner_up_gap, opposite_gap + extent * apart)
        needed = (exact.distance <= bound + margin) & (
            rival >= exact.distance - bound - margin)
        axes, losses, slopes = _searches(frozen, tau, starts, needed, rival, margin)
    else:
        # Off the CPU both searches run as one vmap over the two starts: on an H100 the
        # skipping batching rule's chunks (then each 1/8 of the batch's searches, run one after
        # another) left box pairs' value and gradient 2.6x slower at 1e5 pairs (1.34e7
        # against 3.45e7 pairs/s) and no faster at 1e6 (benchmarks/results/gpu-nvidia-h100.md).
        axes, losses, slopes = jax.vmap(_passes, in_axes=(None, None, 0))(frozen, tau, starts)
    # Near a maximum soft_gap changes only to second order, so an axis 1e-8 off the maximum
    # (a search that ran out of steps) has a value equal to the maximum up to rounding, but
    # a gradient off by 1e-8: between values that tie within rounding, the flatter axis wins.
    rounding = 64 * jnp.finfo(frozen.dtype).eps * (extent + jnp.abs(losses[0]))
    second = (losses[1] < losses[0] - rounding) | (
        (losses[1] <= losses[0] + rounding) & (slopes[1] < slopes[0]))
    # Stored once (`_kernels` rule 5): at a tie the decision rests on rounding, and every
    # component of the axis, in every consumer, must take the same one. Recomputed per
    # consumer it can differ between them and mix the two axes (a's soft extreme along one
    # mixture, b's along another), which puts the value far outside the bound.
    return where(materialize(second), axes[1], axes[0])


@_maximiser.defjvp
def _maximiser_jvp(primals, tangents):
    """How the maximiser moves (implicit function theorem): the tangent gradient of soft_gap
    stays 0, so H_R d + E (d grad) = 0 for the step d in the tangent basis E, with H_R the
    Riemannian Hessian and d grad the change of the Euclidean gradient at the fixed axis.
    Only second and higher derivatives of the smooth value reach this rule."""
    frame, tau = primals
    axis = _maximiser(frame, tau)

    def moments(frame, tau):
        summary = _summary(frame)
        return _unpack(summary, _packed_moments(summary, kernels.as_vec(axis), tau))

    basis, _, hessian = _riemannian(kernels.as_vec(axis), moments(frame, tau), tau)
    _, moved = jax.jvp(lambda f, t: moments(f, t).gradient, primals, tangents)
    right = [-kernels.vdot(e, moved) for e in basis]
    step = _solve(hessian, right, _determinant(hessian) != 0)
    return axis, jnp.stack(_tangent(step, basis))


@jax.custom_jvp
def _smooth_value(frame: PairFrame, tau):
    return soft_gap(frame, _maximiser(frame, tau), tau)


@_smooth_value.defjvp
def _smooth_value_jvp(primals, tangents):
    """The envelope theorem: the derivative of soft_gap with its maximising axis held fixed
    (the axis's own motion changes soft_gap only to second order).

    The derivative goes through b's moved vertices, so the poses' derivatives are sums over
    the vertices (reductions, which XLA's CPU backend hands to YNNPACK). Writing it instead
    through two points, u . (dq - dp) with p and q the softmax-weighted vertices (q formed
    in b's own frame, as `signed_distance_of_witnesses` does), removed those reductions but
    no time: the smooth value and gradient took 1.014x (2D polygons) and 1.007x (boxes) as
    long, 1e4 pairs on one core of a 2-core AMD EPYC. Measured alone, the pose gradient of
    the sum of b's projections on a fixed axis did take 7x as long with YNNPACK's reductions
    as with XLA's own (3.7 against 0.5 ms at 1e4 pairs)."""
    frame, tau = primals
    axis = _maximiser(frame, tau)
    return jax.jvp(lambda f, t: soft_gap(f, axis, t), primals, tangents)


def smooth_signed_distance(frame: PairFrame, tau) -> jax.Array:
    """Smooth signed distance of a prepared pair (see the module docstring)."""
    # A traced tau can be 0 (or negative): floor it at a few ulps of the pair's extent, which
    # gives the exact value up to rounding instead of 0/0 (double where: no NaN in gradients).
    extent = jax.lax.stop_gradient(jnp.max(jnp.abs(frame.a.vertices))
                                   + jnp.max(jnp.abs(frame.b_vertices)))
    floor = 16 * jnp.finfo(frame.dtype).eps * extent
    return _smooth_value(frame, where(tau > floor, tau, floor))


def smoothing_error_bound(a: Polytope, b: Polytope) -> jax.Array:
    """The constant c with exact - c * tau <= signed_distance(..., smoothing=tau) <= exact.

    c = log(n_a n_b), with n_a, n_b the real vertex counts (1 for a half-space): log-sum-exp
    over n values exceeds their maximum by at most tau log n (see `_smoothing`'s docstring).
    About 4.2 for two boxes or two 8-gons, 6.0 for two 20-vertex hulls. To keep the smooth value
    within a length `tolerance` of the exact one, pick tau = tolerance / c; tau of 1% to 10% of
    the shapes' size gives gradients that see features a few tau away. Works on single shapes
    and on batches (broadcasting).
    """
    check_kinds(a, b)
    if a.dim != b.dim:
        raise ValueError(f"a and b must share one dimension, got {a.dim}D and {b.dim}D")

    def count(shape):  # a half-space's signed distance softens no maximum of its own
        if isinstance(shape, HalfSpace):
            return jnp.ones(shape.batch_shape, jnp.int32)
        return jnp.sum(shape.vertex_mask, axis=-1, dtype=jnp.int32)

    return jnp.log((count(a) * count(b)).astype(a.dtype))
