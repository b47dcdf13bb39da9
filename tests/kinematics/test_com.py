"""The whole figure's centre of mass and its Jacobian against MuJoCo (subtree_com[0], mj_jacSubtreeCom)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import mjkin
from conftest import ALL_MODELS, FD_TOL, FK_TOL, model_id, mujoco_state, tree_of

N_Q = 20


@pytest.mark.parametrize("path", ALL_MODELS, ids=model_id)
def test_com_equals_mujoco(path, rng):
    tree = tree_of(path)
    m = tree.model
    Q = tree.random_q(rng, N_Q)
    C, J = tree.com(Q), tree.com_jacobian(Q)
    assert C.shape == (N_Q, 3) and J.shape == (N_Q, 3, tree.nv)
    for k in range(N_Q):
        d = mujoco_state(m, Q[k])
        jp = np.zeros((3, m.nv))
        mujoco.mj_jacSubtreeCom(m, d, jp, 0)
        np.testing.assert_allclose(C[k], d.subtree_com[0], atol=FK_TOL, rtol=0)
        np.testing.assert_allclose(J[k], jp, atol=FK_TOL, rtol=0)


def test_several_roots_weigh_every_body():
    tree = mjkin.load("""<mujoco><worldbody>
        <body pos="1 0 0"><freejoint/><geom size=".1" mass="1"/></body>
        <body pos="0 0 1"><joint type="hinge" axis="0 1 0"/><geom size=".1" mass="3" pos="1 0 0"/></body>
        <geom type="plane" size="1 1 1"/></worldbody></mujoco>""")
    q = tree.qpos0.copy()
    np.testing.assert_allclose(tree.com(q), [(1 * 1 + 3 * 1) / 4, 0, 3 / 4], atol=1e-15)
    q[-1] = np.pi / 2  # the heavy ball swings under its hinge, from x = 1 to z = 0
    np.testing.assert_allclose(tree.com(q), [1 / 4, 0, 0], atol=1e-15)


def test_massless_model_has_its_centre_at_the_origin():
    tree = mjkin.load("""<mujoco><worldbody><body pos="1 2 3"><geom size=".1" mass="0"/></body>
        </worldbody></mujoco>""")
    d = mujoco_state(tree.model, np.zeros(0))
    assert np.all(tree.com(np.zeros(0)) == d.subtree_com[0]) and tree.com_jacobian(np.zeros(0)).shape == (3, 0)


@pytest.mark.parametrize("name", ["arm7", "primate", "ball_chain", "planar_prismatic"])
def test_com_jacobian_matches_finite_differences(name, rng):
    tree = tree_of(name)
    h = 1e-6
    for q in tree.random_q(rng, 3):
        J = tree.com_jacobian(q)
        for i in range(tree.nv):
            e = np.zeros(tree.nv)
            e[i] = h
            dc = (tree.com(tree.integrate(q, e)) - tree.com(tree.integrate(q, -e))) / (2 * h)
            np.testing.assert_allclose(J[:, i], dc, atol=FD_TOL)


def test_batched_com_equals_per_q(rng):
    tree = tree_of("primate")
    Q = tree.random_q(rng, 6).reshape(2, 3, tree.nq)
    C, J = tree.com(Q), tree.com_jacobian(Q)
    assert C.shape == (2, 3, 3) and J.shape == (2, 3, 3, tree.nv)
    for idx in np.ndindex(2, 3):
        np.testing.assert_array_equal(C[idx], tree.com(Q[idx]))
        np.testing.assert_array_equal(J[idx], tree.com_jacobian(Q[idx]))
