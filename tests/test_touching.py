"""One truth at contact (`harness.TOUCHING`): on shapes that touch at a vertex, an edge or a
face, in integer coordinates at scales 1e-3 to 1e3, placed exactly, moved by a common rigid
motion and nudged by 4 ulps either way, the queries agree pair by pair:
`intersects` iff `penetration(...).depth >= 0` iff `signed_distance <= 0` iff
`closest_points(...).signed_distance <= 0` iff `contacts` has a valid point; batched and
eager alike."""

from __future__ import annotations

import jax
import numpy as np
import pytest
from harness import (
    DTYPE_IDS,
    DTYPES,
    FAST_COMPILE,
    TOUCHING,
    TOUCHING_SCALES,
    make_pose,
    take,
    touching_pairs,
)

import jaxsat


def _answers(a, pose_a, b, pose_b):
    """Each query's overlap verdict for one pair, in one row."""
    return (jaxsat.intersects(a, pose_a, b, pose_b),
            jaxsat.penetration(a, pose_a, b, pose_b).depth >= 0,
            jaxsat.signed_distance(a, pose_a, b, pose_b) <= 0,
            jaxsat.closest_points(a, pose_a, b, pose_b).signed_distance <= 0,
            jax.numpy.any(jaxsat.contacts(a, pose_a, b, pose_b).valid))


_batched = jax.jit(jax.vmap(lambda a, pa, b, pb: _answers(a, make_pose(pa), b, make_pose(pb))),
                   compiler_options=FAST_COMPILE)


@pytest.mark.parametrize("dim", [2, pytest.param(3, marks=pytest.mark.slow)])
@pytest.mark.parametrize("dtype", [pytest.param(dtype, id=DTYPE_IDS[k], marks=(
    () if dtype == np.float32 else pytest.mark.slow)) for k, dtype in enumerate(DTYPES)])
def test_queries_agree_on_touching_shapes(dim, dtype):
    names, placed, a, params_a, b, params_b = touching_pairs(dim, dtype)
    verdicts = np.stack([np.asarray(v) for v in _batched(a, params_a, b, params_b)])
    disagree = np.any(verdicts != verdicts[:1], axis=0)
    assert not disagree.any(), (
        f"{disagree.sum()} of {len(names)} pairs disagree: "
        + ", ".join(f"{names[i]} {verdicts[:, i].tolist()}" for i in np.nonzero(disagree)[0][:5]))
    # Placed exactly, every configuration touches, and every query says so.
    assert placed.sum() == len(TOUCHING[dim]) * len(TOUCHING_SCALES)
    assert verdicts[:, placed].all(), names[placed][~verdicts[0, placed]]
    assert set(names) == set(TOUCHING[dim])


@pytest.mark.slow
@pytest.mark.parametrize("dim", [2, 3])
def test_eager_calls_agree_on_touching_shapes(dim):
    """The single-pair path of `intersects` (a world AABB test before the SAT) agrees too."""
    names, _, a, params_a, b, params_b = touching_pairs(dim, np.float32, motions=1)
    for i in range(0, len(names), 3):
        verdict = [bool(v) for v in _answers(take(a, i), make_pose(take(params_a, i)),
                                             take(b, i), make_pose(take(params_b, i)))]
        assert len(set(verdict)) == 1, (names[i], i, verdict)
