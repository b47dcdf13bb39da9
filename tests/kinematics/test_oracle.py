"""mjkin's FK and Jacobians against MuJoCo (mj_kinematics, mj_jac*) on every model we can find."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import ALL_MODELS, FD_TOL, FK_TOL, bundled, model_id, mujoco_jacobian, mujoco_state, shared, tree_of

N_Q = 100


def test_model_lists_are_not_empty():
    assert len(bundled()) >= 6
    assert len(ALL_MODELS) > len(bundled())


@pytest.mark.parametrize("path", ALL_MODELS, ids=model_id)
def test_fk_equals_mujoco(path, rng):
    tree = tree_of(path)
    m = tree.model
    Q = tree.random_q(rng, N_Q)
    T = tree.fk(Q)
    frames = tree.kinematics(Q)
    sites = [frames.pose("site", s) for s in range(m.nsite)]
    for k in range(N_Q):
        d = mujoco_state(m, Q[k])
        np.testing.assert_allclose(T[k, :, :3, 3], d.xpos, atol=FK_TOL, rtol=0)
        np.testing.assert_allclose(T[k, :, :3, :3], d.xmat.reshape(-1, 3, 3), atol=FK_TOL, rtol=0)
        for s in range(m.nsite):
            np.testing.assert_allclose(sites[s][k, :3, 3], d.site_xpos[s], atol=FK_TOL, rtol=0)
            np.testing.assert_allclose(sites[s][k, :3, :3], d.site_xmat[s].reshape(3, 3), atol=FK_TOL, rtol=0)


@pytest.mark.parametrize("path", ALL_MODELS, ids=model_id)
def test_jacobians_equal_mujoco(path, rng):
    tree = tree_of(path)
    m = tree.model
    Q = tree.random_q(rng, N_Q)
    frames = tree.kinematics(Q)
    ours = {("body", b): frames.jacobian("body", b) for b in range(1, m.nbody)}
    ours.update({("site", s): frames.jacobian("site", s) for s in range(m.nsite)})
    for k in range(N_Q):
        d = mujoco_state(m, Q[k])
        for (kind, i), J in ours.items():
            np.testing.assert_allclose(J[k], mujoco_jacobian(m, d, kind, i), atol=FK_TOL, rtol=0,
                                       err_msg=f"{kind} {i}")


@pytest.mark.parametrize("path", bundled()[:3] + shared()[:2], ids=model_id)
def test_jacobian_at_offset_equals_mj_jac_at_point(path, rng):
    import mujoco

    tree = tree_of(path)
    m = tree.model
    offset = np.array([0.03, -0.02, 0.05])
    for q in tree.random_q(rng, 10):
        d = mujoco_state(m, q)
        for b in range(1, m.nbody):
            point = d.xpos[b] + d.xmat[b].reshape(3, 3) @ offset
            jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
            mujoco.mj_jac(m, d, jp, jr, point, b)
            J = tree.kinematics(q).jacobian("body", b, offset)
            np.testing.assert_allclose(J, np.vstack([jp, jr]), atol=FK_TOL, rtol=0)


@pytest.mark.parametrize("name", ["arm7", "primate", "ball_chain", "planar_prismatic"])
def test_jacobian_matches_finite_differences(name, rng):
    """Columns are derivatives along MuJoCo's velocity (local angular velocity for balls/free)."""
    tree = tree_of(name)
    site = tree.names("site")[-1]
    h = 1e-6
    for q in tree.random_q(rng, 5):
        J = tree.jacobian(q, site)
        T0 = tree.pose(q, site)
        for i in range(tree.nv):
            e = np.zeros(tree.nv)
            e[i] = h
            Tp, Tm = tree.pose(tree.integrate(q, e), site), tree.pose(tree.integrate(q, -e), site)
            dp = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
            dR = (Tp[:3, :3] - Tm[:3, :3]) / (2 * h) @ T0[:3, :3].T  # = skew(omega)
            omega = np.array([dR[2, 1], dR[0, 2], dR[1, 0]])
            np.testing.assert_allclose(J[:3, i], dp, atol=FD_TOL)
            np.testing.assert_allclose(J[3:, i], omega, atol=FD_TOL)


@pytest.mark.parametrize("name", ["arm7", "primate"])
def test_batched_equals_per_q(name, rng):
    tree = tree_of(name)
    Q = tree.random_q(rng, 24).reshape(2, 3, 4, tree.nq)
    site = tree.names("site")[0]
    T, J, P = tree.fk(Q), tree.jacobian(Q, site), tree.pose(Q, site)
    assert T.shape == (2, 3, 4, tree.nbody, 4, 4) and J.shape == (2, 3, 4, 6, tree.nv) and P.shape == (2, 3, 4, 4, 4)
    for idx in np.ndindex(2, 3, 4):
        np.testing.assert_array_equal(T[idx], tree.fk(Q[idx]))
        np.testing.assert_array_equal(J[idx], tree.jacobian(Q[idx], site))
        np.testing.assert_array_equal(P[idx], tree.pose(Q[idx], site))


def test_shared_real_robots_are_found():
    if not shared():
        pytest.skip("../shared/models not found (set MJKIN_SHARED_MODELS); real-robot checks did not run")
    names = {p.stem for p in shared()}
    assert {"panda_nohand", "ur5e", "iiwa14", "gen3", "xarm7_nohand", "g1"} <= names
