"""The pair frame: one query's inputs checked, cast to one dtype, and b placed in a's frame.

Every pair query (SAT, distance, smoothing, contacts) works in a's local frame, where a's
vertices are the stored ones and b's are moved by the relative pose. `pair_frame` does that
preparation once per query; `check_pair` runs the static checks (shapes and types only, so
they hold under `jit` and `vmap` too) and raises the errors users see.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax.experimental import checkify

from jaxsat._kernels import propagate_non_finite, rotate, transposed_product
from jaxsat._poses import Pose
from jaxsat._shapes import Polytope

__all__ = ["Guarded", "PairFrame", "cast_pair", "check_one_pair", "check_pair", "compiled_query",
           "pair_frame", "relative_pose"]


def check_pair(a: Polytope, pose_a: Pose, b: Polytope, pose_b: Pose) -> None:
    """Raise TypeError unless a and b are Polytopes and the poses Poses; ValueError unless
    they are unbatched and of one dimension."""
    for name, value, kind in (("a", a, Polytope), ("b", b, Polytope),
                              ("pose_a", pose_a, Pose), ("pose_b", pose_b, Pose)):
        if not isinstance(value, kind):
            raise TypeError(f"{name} must be a jaxsat.{kind.__name__}, got {type(value).__name__}")
    check_one_pair(a, pose_a, b, pose_b)


def check_one_pair(a, pose_a: Pose, b, pose_b: Pose) -> None:
    """Unbatched inputs of one dimension; a and b: anything with batch_shape and dim (so
    compounds share the check)."""
    pose_a_batch, pose_b_batch = pose_a.translation.shape[:-1], pose_b.translation.shape[:-1]
    if a.batch_shape or b.batch_shape or pose_a_batch or pose_b_batch:
        raise ValueError("queries take one pair; batch them with jax.vmap (got batched inputs: "
                         f"a {a.batch_shape}, b {b.batch_shape}, pose_a {pose_a_batch}, "
                         f"pose_b {pose_b_batch})")
    dims = {a.dim, b.dim, pose_a.dim, pose_b.dim}
    if len(dims) != 1:
        raise ValueError(f"a, pose_a, b, pose_b must share one dimension, got {a.dim}D shape a, "
                         f"{b.dim}D shape b, {pose_a.dim}D pose_a, {pose_b.dim}D pose_b")


def cast_pair(a, pose_a, b, pose_b):
    """The four inputs as JAX arrays, every float leaf in their common dtype (outputs follow
    it). NumPy leaves (shapes sliced with np.asarray, say) become JAX arrays, so that traced
    indices can index them."""
    # Mixed float32/float64 pairs are promoted on purpose, also under a user's strict
    # promotion setting (where jnp.result_type would raise).
    with jax.numpy_dtype_promotion("standard"):
        dtype = jnp.result_type(a.dtype, b.dtype, pose_a.translation, pose_b.translation)
    cast = lambda tree: jax.tree.map(  # noqa: E731
        lambda leaf: jnp.asarray(leaf, dtype if jnp.issubdtype(leaf.dtype, jnp.floating)
                                 else None), tree)
    return cast(a), cast(pose_a), cast(b), cast(pose_b)


def relative_pose(pose_a: Pose, pose_b: Pose) -> tuple[jax.Array, jax.Array]:
    """(rotation, translation) mapping b's local coordinates into a's local frame."""
    return (transposed_product(pose_a.rotation, pose_b.rotation),
            rotate(pose_a.rotation.T, pose_b.translation - pose_a.translation))


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class PairFrame:
    """One pair in a's local frame, in the common dtype."""

    a: Polytope
    """a, cast."""
    b: Polytope
    """b, cast (its fields stay in b's own frame)."""
    pose_a: Pose
    """a's pose, cast: maps results back to the world."""
    rotation: jax.Array
    """(D, D) float: b's local directions in a's frame."""
    translation: jax.Array
    """(D,) float: b's local origin in a's frame."""
    b_vertices: jax.Array
    """(V_b, D) float: b's vertices in a's frame."""

    @property
    def dim(self) -> int:
        return self.a.dim

    @property
    def dtype(self):
        return self.a.vertices.dtype

    @property
    def is_rounded(self) -> bool:
        """Static: either shape carries a radius (the query then measures the cores' signed
        distance and subtracts the radii)."""
        return self.a.is_rounded or self.b.is_rounded

    @property
    def radius_a(self) -> jax.Array:
        """() float: a's radius (0 for a sharp shape)."""
        return jnp.zeros((), self.dtype) if self.a.radius is None else self.a.radius

    @property
    def radius_b(self) -> jax.Array:
        """() float: b's radius (0 for a sharp shape)."""
        return jnp.zeros((), self.dtype) if self.b.radius is None else self.b.radius

    def to_world(self, points):
        """(..., D) points of a's frame in world coordinates."""
        return rotate(self.pose_a.rotation, points) + self.pose_a.translation

    def direction_to_world(self, directions):
        """(..., D) directions of a's frame in world coordinates."""
        return rotate(self.pose_a.rotation, directions)


def pair_frame(a: Polytope, pose_a: Pose, b: Polytope, pose_b: Pose) -> PairFrame:
    """Check, cast and place b in a's frame (the first step of every pair query)."""
    check_pair(a, pose_a, b, pose_b)
    a, pose_a, b, pose_b = cast_pair(a, pose_a, b, pose_b)
    rotation, translation = relative_pose(pose_a, pose_b)
    b_vertices = rotate(rotation, b.vertices) + translation
    return PairFrame(a, b, pose_a, rotation, translation, b_vertices)


EAGER_COMPILER_OPTIONS = {
    "xla_cpu_use_fusion_emitters": False,
    "xla_backend_optimization_level": 0,
    "xla_llvm_disable_expensive_passes": True,
}
"""XLA's cheaper CPU settings, for the one-pair programs of eager calls: they compile a first
call 2-2.7x faster (box pair, exact distance: 2.5 -> 1.4 s on 2 cores) and a warm call stays
under a millisecond (0.05-0.75 ms on a 2-core Xeon, pairs of 20-vertex hulls the slowest). A
user's own `jit` keeps its options: JAX takes compiler options only from the outermost jit.
CPU only: other backends reject these option names."""


def eager_compiler_options(backend: str) -> dict | None:
    """`EAGER_COMPILER_OPTIONS` on the CPU backend, None (XLA's defaults) on any other: a GPU
    compiler fails on the CPU option names."""
    return dict(EAGER_COMPILER_OPTIONS) if backend == "cpu" else None


_CHECKED_FIELDS = ("pieces", "vertices", "radius", "translation", "rotation", "normal", "offset")
"""The fields of an input that the non-finite guard reads: a shape's vertices and radius (its
face normals and other derived fields follow from them), a pose, a half-space's plane, and a
compound's pieces."""


def _checked_leaves(value) -> list:
    """The float arrays of one query argument that must be finite (see `_CHECKED_FIELDS`)."""
    if dataclasses.is_dataclass(value):
        return [leaf for field in _CHECKED_FIELDS if getattr(value, field, None) is not None
                for leaf in _checked_leaves(getattr(value, field))]
    leaves = [jnp.asarray(leaf) for leaf in jax.tree.leaves(value)]
    return [leaf for leaf in leaves if jnp.issubdtype(leaf.dtype, jnp.floating)]


class Guarded(NamedTuple):
    """A query's outputs that already hold the non-finite guard (`guard_non_finite` then
    returns them as they are): every float output NaN, with NaN derivatives in every input
    entry, and every boolean output False, where an input entry is NaN or inf. A query returns
    this only where its kernel folded `_kernels.inline_non_finite_poison` over all the inputs
    into a value every output reads (the box kernel's depth)."""

    outputs: object
    """The query's outputs (any pytree)."""


def guard_non_finite(name: str, signature: inspect.Signature, function, args, kwargs,
                     named_errors: bool = True):
    """`function(*args, **kwargs)` with NaN float outputs (and NaN derivatives, and False
    boolean outputs) where a pose, vertex, radius, plane or scalar argument is NaN or inf
    (`propagate_non_finite`; a `Guarded` result already holds that guard). With
    `named_errors`, under `jax.experimental.checkify.checkify` such an argument raises an
    error naming it (`checkify.debug_check`, a no-op elsewhere)."""
    bound = signature.bind(*args, **kwargs)
    inputs = []
    for argument, value in bound.arguments.items():
        leaves = _checked_leaves(value)
        if leaves:
            if named_errors:
                finite = functools.reduce(jnp.logical_and,
                                          [jnp.all(jnp.isfinite(x)) for x in leaves])
                checkify.debug_check(finite,
                                     f"jaxsat.{name}: argument '{argument}' holds NaN or inf")
            inputs.extend(leaves)
    outputs = function(*args, **kwargs)
    if isinstance(outputs, Guarded):
        return outputs.outputs
    return propagate_non_finite(outputs, inputs)


try:  # JAX's private test whether a jaxpr is being built (in 0.6.0, the floor, and 0.10.2)
    from jax._src.core import unsafe_am_i_under_a_jit as _under_a_jit
except ImportError:  # pragma: no cover - depends on the JAX version
    _under_a_jit = None


def _tracing_a_program(traced: bool) -> bool:
    """Whether a jaxpr is being built (a user's `jit`, `checkify`, `make_jaxpr`, a loop's
    body ...), as opposed to an eager call or an eager transformation (`grad` or `vmap`
    outside any `jit`); `traced`: some argument is a tracer.

    Eager transformations run their primitives one at a time, each dispatched on its own, so
    a query traced into them directly costs a dispatch per primitive on every call: an eager
    `jax.grad` of a smooth box distance took 4.4 s a call, warm (0.16 s exact). And a query
    whose arguments are all concrete (closed over) can still be inside a user's `jit`, where
    a jit with compiler options is refused. JAX has no public test for this; where its
    private one is missing, `traced` stands in for it (right for plain calls and under
    `jit`; a query of concrete arguments inside a `jit` then fails as said, and an eager
    transformation runs primitive by primitive)."""
    return traced if _under_a_jit is None else _under_a_jit()


def compiled_query(check, static_argnames=(), name=None):
    """Decorator for a public pair query: the static checks `check(*args, **kwargs)` run in
    Python first (so bad input raises a clear error, never a tracing failure), then the query
    runs through `jax.jit`. An eager call compiles once per size class, dtype and static
    option and then costs one dispatch. Under a user's `jit` (or whatever else builds a jaxpr:
    `checkify`, `make_jaxpr`, a loop's body) the query is traced into theirs directly (a nested
    jit would be traced again by each transformation); under an eager `grad` or `vmap` it runs
    through a jit of its own with XLA's default settings (`_tracing_a_program`). Either way
    the outputs pass through `guard_non_finite` (under `name`, default the function's):
    non-finite input gives NaN, never a plausible number.

    Eager calls compile with `EAGER_COMPILER_OPTIONS` on the CPU (XLA's defaults elsewhere),
    one jitted function per backend: a query takes one pair, so its eager
    program runs in under a millisecond either way and compiling is what the user waits for.
    (`tests/test_distance.py::test_eager_calls_agree_with_the_oracle_on_a_flat_gjk_stop` holds
    a box pair on which these settings once changed GJK's answer.)"""
    def wrap(function):
        compiled_on = {}  # backend name -> jitted function, built at the first eager call
        signature = inspect.signature(function)

        def guard(named_errors: bool):
            @functools.wraps(function)  # keeps the signature, for jit's static_argnames
            def guarded(*args, **kwargs):
                return guard_non_finite(name or function.__name__, signature, function, args,
                                        kwargs, named_errors)
            return guarded

        # An eager call's jit is never under checkify (checkify traces, so its arguments
        # would be tracers): it leaves out `debug_check`, whose effect would send every call
        # through jit's Python path (0.3 ms a call instead of 0.05 for a box pair).
        guarded, guarded_eager = guard(named_errors=True), guard(named_errors=False)
        transformed = jax.jit(guarded_eager, static_argnames=static_argnames)

        @functools.wraps(function)
        def query(*args, **kwargs):
            check(*args, **kwargs)
            traced = any(isinstance(leaf, jax.core.Tracer)
                         for leaf in jax.tree.leaves((args, kwargs)))
            if _tracing_a_program(traced):
                return guarded(*args, **kwargs)
            if traced:
                # An eager grad or vmap: one jitted program, which that transformation turns
                # into its own (it takes no compiler options: it is not the outermost jit).
                return transformed(*args, **kwargs)
            backend = jax.default_backend()
            compiled = compiled_on.get(backend)
            if compiled is None:
                compiled = compiled_on[backend] = jax.jit(
                    guarded_eager, static_argnames=static_argnames,
                    compiler_options=eager_compiler_options(backend))
            return compiled(*args, **kwargs)

        @functools.wraps(function)
        def uncompiled(*args, **kwargs):
            """The query's own outputs, unguarded: for a caller that guards its own outputs
            (a compound query over its pieces)."""
            outputs = function(*args, **kwargs)
            return outputs.outputs if isinstance(outputs, Guarded) else outputs

        query.uncompiled = uncompiled
        query.eager_function = guarded_eager  # what an eager call jits (tests read its effects)
        return query

    return wrap
