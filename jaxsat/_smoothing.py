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
where two penetration directions tie the gradient switches between them (a kink, measured in
benchmarks/README.md).

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

from jaxsat._closest import exact_distance
from jaxsat._kernels import dot, safe_divide, safe_normalize
from jaxsat._narrowphase import sat_candidates
from jaxsat._pair import PairFrame
from jaxsat._shapes import Polytope

__all__ = ["NEWTON_STEPS", "smooth_signed_distance", "smoothing_error_bound"]

NEWTON_STEPS = 12
"""Trust-region Newton steps from the exact axis (see benchmarks/README.md for the residual
after each)."""

_FIRST_RADIUS = 4.0
"""The first trust radius, in units of tau / (the pair's extent): the angle over which the
soft extremes change their weights (capped at _MAX_RADIUS)."""

_MAX_RADIUS = 1.0
"""The largest trust radius, in radians."""

_SECOND_START_ANGLE = 4.0
"""The second start is at least this many tau / (the pair's extent) radians from the first
(at least 1e-3, at most 0.5): nearer axes lie in the first one's soft basin."""


class _Moments(NamedTuple):
    """soft_gap and its first two derivatives in the axis, at one axis (a's frame)."""

    value: jax.Array
    """() soft_gap(u)."""
    gradient: jax.Array
    """(D,) q - p: soft-argmin point of b minus soft-argmax point of a."""
    spread: jax.Array
    """(D, D) covariance of a's softmax weights plus that of b's: the Hessian is -spread/tau."""


def _soft_max(projections, mask, tau):
    """(tau log sum exp(x / tau), softmax weights) over the real entries."""
    top = jnp.max(jnp.where(mask, projections, -jnp.inf))
    # Padding never reaches exp (double where): no inf * 0 in any gradient.
    terms = jnp.where(mask, jnp.exp((jnp.where(mask, projections, top) - top) / tau), 0.0)
    total = jnp.sum(terms)
    return top + tau * jnp.log(total), terms / total


def _moments(axis, a_vertices, a_mask, b_vertices, b_mask, tau, centres) -> _Moments:
    """soft_gap and its derivatives at `axis`. Vertices are centred (centres: one point per
    shape) before the second moments, so that far-apart shapes lose no digits to cancellation."""
    soft_a, weights_a = _soft_max(dot(a_vertices, axis), a_mask, tau)
    soft_b, weights_b = _soft_max(-dot(b_vertices, axis), b_mask, tau)
    centred_a, centred_b = a_vertices - centres[0], b_vertices - centres[1]
    mean_a = weights_a @ centred_a
    mean_b = weights_b @ centred_b
    spread = ((weights_a[:, None] * centred_a).T @ centred_a - jnp.outer(mean_a, mean_a)
              + (weights_b[:, None] * centred_b).T @ centred_b - jnp.outer(mean_b, mean_b))
    return _Moments(value=-soft_b - soft_a, gradient=(mean_b + centres[1]) - (mean_a + centres[0]),
                    spread=spread)


def _tangent_basis(axis):
    """(D - 1, D) orthonormal basis of the plane across a unit axis."""
    if axis.shape[0] == 2:
        return jnp.stack([-axis[1], axis[0]])[None]
    helper = jnp.where(jnp.abs(axis[0]) < 0.6, jnp.array([1.0, 0.0, 0.0], axis.dtype),
                       jnp.array([0.0, 1.0, 0.0], axis.dtype))
    first = safe_normalize(jnp.cross(axis, helper), 0.0)[0]
    return jnp.stack([first, jnp.cross(axis, first)])


def _trust_region_step(gradient, hessian, radius):
    """The step d (m,) maximising the model g . d + d' H d / 2 over |d| <= radius, for m = 1
    or 2 (the tangent plane of the sphere in 2D or 3D), and the model's increase.

    Newton's step when H is negative definite and the step fits; otherwise the step on the
    boundary with (H - mu I) d = -g, mu >= max(0, largest eigenvalue), found by Newton's
    method on 1 / |d(mu)| - 1 / radius (Moré and Sorensen), with the eigenvector of the
    largest eigenvalue added where g has no part along it (the "hard case", as at a saddle
    between two corners touching, where the soft gap rises on both sides)."""
    dtype = gradient.dtype
    eps = jnp.finfo(dtype).eps
    tiny = jnp.finfo(dtype).tiny
    if gradient.shape[0] == 1:
        curvature, slope = hessian[0, 0], gradient[0]
        newton = -safe_divide(slope, curvature, curvature < 0)
        fits = (curvature < 0) & (jnp.abs(newton) <= radius)
        sense = jnp.where(slope < 0, -1.0, 1.0).astype(dtype)
        step = jnp.where(fits, newton, sense * radius)[None]
    else:
        # Eigen-decomposition of the symmetric 2 x 2 Hessian: values low <= high.
        half_trace = 0.5 * (hessian[0, 0] + hessian[1, 1])
        half_gap = jnp.sqrt(0.25 * (hessian[0, 0] - hessian[1, 1]) ** 2 + hessian[0, 1] ** 2)
        high = half_trace + half_gap
        low = half_trace - half_gap
        scale = jnp.max(jnp.abs(hessian)) + tiny
        first, found = safe_normalize(jnp.stack([hessian[0, 1], high - hessian[0, 0]]),
                                      (eps * scale) ** 2)
        second, _ = safe_normalize(jnp.stack([high - hessian[1, 1], hessian[0, 1]]),
                                   (eps * scale) ** 2)
        top = jnp.where(found, first, second)
        top = jnp.where(jnp.any(top != 0), top, jnp.array([1.0, 0.0], dtype))
        bottom = jnp.stack([-top[1], top[0]])
        along_top, along_bottom = dot(top, gradient), dot(bottom, gradient)
        # d(mu) = g_top / (mu - high) top + g_bottom / (mu - low) bottom, for mu > high.
        newton = -safe_divide(along_top, high, high < 0) * top - safe_divide(
            along_bottom, low, low < 0) * bottom
        fits = (high < 0) & (jnp.sqrt(dot(newton, newton)) <= radius)
        floor = jnp.maximum(high, 0.0)
        mu = floor + jnp.abs(along_top) / radius + eps * scale
        for _ in range(4):
            inverse_top = safe_divide(1.0, mu - high, mu > high)
            inverse_bottom = safe_divide(1.0, mu - low, mu > low)
            squared = along_top**2 * inverse_top**2 + along_bottom**2 * inverse_bottom**2
            length = jnp.sqrt(squared + tiny)
            # phi(mu) = 1/|d| - 1/radius is nearly linear in mu; phi' = (sum g_i^2 / (mu -
            # l_i)^3) / |d|^3.
            derivative = (along_top**2 * inverse_top**3 + along_bottom**2 * inverse_bottom**3
                          ) / (length**3)
            mu = jnp.maximum(mu - safe_divide(1.0 / length - 1.0 / radius, derivative,
                                              derivative > 0), floor)
        inverse_top = safe_divide(1.0, mu - high, mu > high)
        inverse_bottom = safe_divide(1.0, mu - low, mu > low)
        boundary = along_top * inverse_top * top + along_bottom * inverse_bottom * bottom
        # Hard case: too short even as mu reaches the largest eigenvalue (g has (almost) no
        # part along its eigenvector): add that eigenvector up to the boundary.
        short = radius**2 - dot(boundary, boundary)
        sense = jnp.where(along_top < 0, -1.0, 1.0).astype(dtype)
        boundary = boundary + sense * jnp.sqrt(jnp.maximum(short, 0.0)) * top
        step = jnp.where(fits, newton, boundary)
    gain = dot(gradient, step) + 0.5 * dot(step, hessian @ step)
    return step, gain


def _riemannian(axis, moments: _Moments, tau):
    """(tangent basis (m, D), gradient (m,), Hessian (m, m)) of soft_gap on the sphere."""
    basis = _tangent_basis(axis)
    gradient = basis @ moments.gradient
    # The Euclidean Hessian -spread / tau in the tangent plane, minus the normal derivative
    # (u . gradient) times the identity (the sphere's curvature).
    hessian = -(basis @ moments.spread @ basis.T) / tau - dot(axis, moments.gradient) * jnp.eye(
        basis.shape[0], dtype=axis.dtype)
    return basis, gradient, hessian


def _search(frame: PairFrame, tau, start):
    """The axis maximising soft_gap, from `start` (values only): trust-region Newton steps on
    the sphere, each accepted only if soft_gap rises; the region grows when the model predicted
    the rise well and shrinks when it did not."""
    a, b_vertices = frame.a, frame.b_vertices
    centres = _centres(frame)

    def moments_at(axis):
        return _moments_of(frame, axis, tau)

    def step(_, state):
        axis, moments, radius, boost = state
        basis, gradient, hessian = _riemannian(axis, moments, tau)
        move, predicted = _trust_region_step(gradient, hessian, radius)
        # On an exponential tail of the soft extremes (far from the maximum across a range of
        # equally good axes) Newton's step is only about tau / extent and the rise exceeds
        # the model's: there the step is stretched by `boost`, doubled after each success.
        length = jnp.sqrt(dot(move, move))
        stretched = jnp.minimum(boost * length, _MAX_RADIUS)
        move = move * safe_divide(stretched, length, length > 0)
        trial = safe_normalize(axis + move @ basis, 0.0)[0]
        trial_moments = moments_at(trial)
        rise = trial_moments.value - moments.value
        ratio = safe_divide(rise, predicted, predicted > 0)
        plain = boost == 1.0
        radius = jnp.where(~plain, radius,
                           jnp.where(ratio < 0.25, 0.25 * length,
                                     jnp.where((ratio > 0.75) & (length > 0.99 * radius),
                                               2.0 * radius, radius)))
        radius = jnp.clip(radius, 16 * jnp.finfo(axis.dtype).eps, _MAX_RADIUS)
        # Near the maximum the rise (about g^2 / |H|) drops below the value's rounding before
        # the gradient g is small: there, a step that shrinks the gradient is taken too.
        steeper = dot(gradient, gradient) <= dot(*(_riemannian(trial, trial_moments,
                                                               tau)[1],) * 2)
        better = (rise > 0) | ((rise >= -rounding) & ~steeper)
        tail = plain & (ratio > 1.1) & (length < 0.99 * radius)
        boost = jnp.where(better & (tail | ~plain), jnp.minimum(2.0 * boost, 64.0), 1.0)
        keep = lambda new, old: jnp.where(better, new, old)  # noqa: E731
        return (keep(trial, axis), jax.tree.map(keep, trial_moments, moments), radius,
                boost.astype(radius.dtype))

    extent = jnp.max(jnp.abs(a.vertices)) + jnp.max(jnp.abs(b_vertices - centres[1]))
    rounding = 16 * jnp.finfo(frame.dtype).eps * (extent + jnp.max(jnp.abs(b_vertices)))
    radius = jnp.minimum(_FIRST_RADIUS * tau / extent, _MAX_RADIUS)
    state = (start, moments_at(start), radius, jnp.ones((), frame.dtype))
    return jax.lax.fori_loop(0, NEWTON_STEPS, step, state)[0]


def soft_gap(frame: PairFrame, axis, tau):
    """soft_gap(axis) for a prepared pair (differentiable in the frame)."""
    soft_a, _ = _soft_max(dot(frame.a.vertices, axis), frame.a.vertex_mask, tau)
    soft_b, _ = _soft_max(-dot(frame.b_vertices, axis), frame.b.vertex_mask, tau)
    return -soft_b - soft_a


def _centres(frame: PairFrame):
    return frame.a.vertices[0], frame.b_vertices[0]


def _moments_of(frame: PairFrame, axis, tau) -> _Moments:
    return _moments(axis, frame.a.vertices, frame.a.vertex_mask, frame.b_vertices,
                    frame.b.vertex_mask, tau, _centres(frame))


@jax.custom_jvp
def _maximiser(frame: PairFrame, tau):
    """The unit axis (a's frame) maximising soft_gap: the better of the searches from two
    starts. The first is the exact maximiser, so that the result is within the bound. The
    second is the SAT candidate with the largest soft_gap more than a few tau / extent
    radians from the first (nearer ones share its basin): where penetration directions
    compete, the local maximum near the best other one is found too, and taking the larger
    keeps the value continuous when they swap."""
    frozen, tau = jax.lax.stop_gradient((frame, tau))
    first = exact_distance(frozen).axis
    candidates, valid = sat_candidates(frozen)
    extent = jnp.max(jnp.abs(frozen.a.vertices)) + jnp.max(jnp.abs(frozen.b_vertices))
    apart = jnp.clip(_SECOND_START_ANGLE * tau / extent, 1e-3, 0.5)
    screened = jax.vmap(soft_gap, in_axes=(None, 0, None))(frozen, candidates, tau)
    screened = jnp.where(valid & (candidates @ first < jnp.cos(apart)), screened, -jnp.inf)
    best = jnp.argmax(screened)
    second = jnp.where(jnp.isfinite(screened[best]), candidates[best], first)
    axes = jax.vmap(_search, in_axes=(None, None, 0))(frozen, tau, jnp.stack([first, second]))
    values = jax.vmap(soft_gap, in_axes=(None, 0, None))(frozen, axes, tau)
    return jnp.where(values[1] > values[0], axes[1], axes[0])


@_maximiser.defjvp
def _maximiser_jvp(primals, tangents):
    """How the maximiser moves (implicit function theorem): the tangent gradient of soft_gap
    stays 0, so H_R d + E (d grad) = 0 for the step d in the tangent basis E, with H_R the
    Riemannian Hessian and d grad the change of the Euclidean gradient at the fixed axis.
    Only second and higher derivatives of the smooth value reach this rule."""
    frame, tau = primals
    axis = _maximiser(frame, tau)
    basis, _, hessian = _riemannian(axis, _moments_of(frame, axis, tau), tau)
    _, moved = jax.jvp(lambda f, t: _moments_of(f, axis, t).gradient, primals, tangents)
    right = -(basis @ moved)
    if basis.shape[0] == 1:
        step = safe_divide(right, hessian[0, 0], hessian[0, 0] != 0)
    else:
        determinant = hessian[0, 0] * hessian[1, 1] - hessian[0, 1] ** 2
        inverse = jnp.stack([jnp.stack([hessian[1, 1], -hessian[0, 1]]),
                             jnp.stack([-hessian[0, 1], hessian[0, 0]])])
        step = safe_divide(inverse @ right, determinant, determinant != 0)
    return axis, step @ basis


@jax.custom_jvp
def _smooth_value(frame: PairFrame, tau):
    return soft_gap(frame, _maximiser(frame, tau), tau)


@_smooth_value.defjvp
def _smooth_value_jvp(primals, tangents):
    """The envelope theorem: the derivative of soft_gap with its maximising axis held fixed
    (the axis's own motion changes soft_gap only to second order)."""
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
    return _smooth_value(frame, jnp.where(tau > floor, tau, floor))


def smoothing_error_bound(a: Polytope, b: Polytope) -> jax.Array:
    """The constant c with exact - c * tau <= signed_distance(..., smoothing=tau) <= exact.

    c = log(n_a n_b), with n_a, n_b the real vertex counts: log-sum-exp over n values exceeds
    their maximum by at most tau log n (see `_smoothing`'s docstring). About 4.2 for two boxes
    or two 8-gons, 6.0 for two 20-vertex hulls. To keep the smooth value within a length
    `tolerance` of the exact one, pick tau = tolerance / c; tau of 1% to 10% of the shapes'
    size gives gradients that see features a few tau away. Works on single shapes and on
    batches (broadcasting).
    """
    if not isinstance(a, Polytope) or not isinstance(b, Polytope):
        raise ValueError("a and b must be jaxsat.Polytope shapes")
    if a.dim != b.dim:
        raise ValueError(f"a and b must share one dimension, got {a.dim}D and {b.dim}D")
    vertex_pairs = jnp.sum(a.vertex_mask, axis=-1) * jnp.sum(b.vertex_mask, axis=-1)
    return jnp.log(vertex_pairs.astype(a.dtype))
