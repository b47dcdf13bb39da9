"""The task-priority step of the Jacobian methods (``mjkin.ik.kernel.priority_step``) against its definition.

The first level's projector is the diagonal of the unlocked dofs: the step takes the
unlocked columns as they are instead of multiplying by it, so what is checked here
is what the product would give — locked dofs stay put, a damped level solves its
normal equations over the free dofs, a lower level leaves a higher one's rows alone.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from mjkin.ik.kernel import DLS, LM, PINV, priority_step, step_scratch


def problem(seed: int, m: int, nv: int, n_locked: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    locked = np.zeros(nv, dtype=np.bool_)
    locked[rng.choice(nv, size=n_locked, replace=False)] = True
    return rng.normal(size=(m, nv)), rng.normal(size=m), locked


def step(J, g, level_rows, locked, method, lam2, clamp=np.inf):  # type: ignore[no-untyped-def]
    dq = np.full(J.shape[1], np.nan)
    priority_step(J, g, np.asarray(level_rows, dtype=np.int64), locked, method, np.asarray(lam2, dtype=np.float64), 0.0,
                  1.0, clamp, step_scratch(J.shape[0], J.shape[1]), dq, False)
    return dq


@given(seed=st.integers(0, 2**32 - 1), m=st.integers(1, 8), nv=st.integers(1, 9), data=st.data(),
       method=st.sampled_from([DLS, LM]), lam=st.floats(1e-4, 1.0))
def test_a_damped_level_solves_its_normal_equations_over_the_free_dofs(seed, m, nv, data, method, lam):
    J, g, locked = problem(seed, m, nv, data.draw(st.integers(0, nv), label="locked"))
    dq = step(J, g, [0, m], locked, method, [lam**2])
    assert np.all(dq[locked] == 0.0)
    A = J[:, ~locked]
    x = dq[~locked]
    # min |A x + g|^2 + lam^2 |x|^2  <=>  (A^T A + lam^2 I) x = -A^T g, to the rounding its condition allows
    M = A.T @ A + lam**2 * np.eye(A.shape[1])
    cond = (np.linalg.norm(A, 2) ** 2 + lam**2) / lam**2 if A.size else 1.0
    np.testing.assert_allclose(M @ x, -A.T @ g, atol=1e-13 * cond * (1 + np.abs(A.T @ g).max(initial=0)), rtol=0)


@given(seed=st.integers(0, 2**32 - 1), nv=st.integers(4, 9), data=st.data())
def test_a_lower_level_leaves_the_first_levels_rows_alone(seed, nv, data):
    n_locked = data.draw(st.integers(0, nv - 3), label="locked")
    m0 = data.draw(st.integers(1, nv - n_locked - 1), label="rows of the first level")  # a null space is left
    J, g, locked = problem(seed, m0 + 3, nv, n_locked)
    dq = step(J, g, [0, m0, m0 + 3], locked, PINV, [0.0, 0.0])
    first = step(J[:m0], g[:m0], [0, m0], locked, PINV, [0.0])
    assert np.all(first[locked] == 0.0)
    np.testing.assert_allclose(dq[locked], 0.0, atol=1e-15)  # the SVD's basis has rounding in the locked columns
    np.testing.assert_allclose(J[:m0] @ dq, -g[:m0], atol=1e-8, rtol=0)  # full row rank: met exactly
    np.testing.assert_allclose(J[:m0] @ first, -g[:m0], atol=1e-8, rtol=0)
    # the second level moves only within the first level's null space, toward its own target
    free = ~locked
    N = np.eye(free.sum()) - np.linalg.pinv(J[:m0, free]) @ J[:m0, free]
    lower = J[m0:, free] @ N
    np.testing.assert_allclose(lower.T @ (J[m0:] @ dq + g[m0:]), 0.0, atol=1e-8, rtol=0)


def test_the_goal_step_clamps_a_far_levels_residual():
    J, g, locked = problem(7, 3, 5, 1)
    far = 100.0 * g / np.linalg.norm(g)
    near = step(J, 0.01 * far, [0, 3], locked, LM, [1e-6])
    clamped = step(J, far, [0, 3], locked, LM, [1e-6], clamp=1.0)
    np.testing.assert_allclose(clamped, near, atol=1e-12, rtol=1e-10)  # |far| = 100: aims at 1/100 of it


def test_a_damping_whose_square_underflows_steps_nowhere_along_a_zero_singular_value():
    """Found by hypothesis (``dls``, damping 2.2e-309): λ² = 0 made ``s / (s² + λ²)`` 0 / 0 for s = 0, a
    ZeroDivisionError in compiled code. A Jacobian with a zero row is still solved along its other rows."""
    J = np.zeros((2, 3))
    J[0] = [1.0, 2.0, 0.0]
    g = np.array([0.5, 0.7])
    locked = np.zeros(3, dtype=np.bool_)
    for method in (DLS, LM):
        dq = step(J, g, [0, 2], locked, method, [2.225073858507203e-309 ** 2])
        np.testing.assert_allclose(J @ dq, [-0.5, 0.0], atol=1e-12)  # the first row met, nothing along the zero one
