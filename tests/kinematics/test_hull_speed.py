"""The short cuts that make mesh clearance fast keep its answers: hull supports started from a direction table,
GJK stopped past a cutoff, and the broad phase, against brute force and MuJoCo's mj_geomDistance."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

import mjkin
from conftest import tree_of
from mjkin import goals as G
from mjkin.apps.bench.report import shared_models_dir
from mjkin.goals.clearance import clearance_rows
from mjkin.goals.program import compile_goals
from mjkin.ik.evaluate import evaluate_program
from mjkin.kinematics import distance as D
from mjkin.kinematics.distance import geom_frames
from mjkin.kinematics.frames import forward
from mjkin.kinematics.geoms import DIRS, MESH, cell_centres, direction_cell, near_pairs
from mjkin.kinematics.gjk import hull_support
from mjkin.motion.retarget import SELF_CLEARANCE, SELF_REACH, self_pairs

MODELS = shared_models_dir() or Path("../shared/models")
ROBOTS = {"gmr_g1": MODELS / "gmr_unitree_g1" / "g1_mocap_29dof.xml",
          "gmr_t1": MODELS / "gmr_booster_t1" / "t1_mocap.xml"}

BALL_MESH = """<mujoco><asset><mesh name="m" vertex="{}"/></asset><worldbody>
  <body><freejoint/><geom type="mesh" mesh="m"/></body><body pos="1 0 0"><freejoint/><geom size=".1"/></body>
</worldbody></mujoco>"""


def robot(name: str) -> mjkin.Tree:
    if not ROBOTS[name].is_file():
        pytest.skip(f"{name} is not here ({ROBOTS[name]})")
    return tree_of(ROBOTS[name])


def near_rest(tree: mjkin.Tree, rng: np.random.Generator, n: int) -> np.ndarray:
    """Poses a retargeted clip takes: ``n`` random ones and ``n`` a random step (up to 0.6 rad a joint) from rest."""
    step = rng.uniform(-0.6, 0.6, (n, tree.nv))
    return np.vstack([tree.random_q(rng, n), tree.clip(tree.integrate(np.tile(tree.qpos0, (n, 1)), step))])


def test_direction_cells_hold_their_centres():
    centres = cell_centres()
    assert centres.shape == (DIRS, 3)
    assert [direction_cell(*c) for c in centres] == list(range(DIRS))
    assert [direction_cell(*(3.0 * c)) for c in centres] == list(range(DIRS))  # any length


@pytest.mark.parametrize("name", ["ball", "gmr_g1"])
def test_hull_support_is_the_farthest_vertex_from_any_start(name, rng):
    """The climb from the direction table's vertex (or a given start) ends at the farthest of all the hull's
    vertices, for any direction and any geom rotation."""
    if name == "ball":  # a hull of 400 points on a sphere: many vertices, each with a few neighbours
        p = rng.normal(size=(400, 3))
        tree = tree_of(BALL_MESH.format(" ".join(map(str, (p / np.linalg.norm(p, axis=1, keepdims=True)).ravel()))))
    else:
        tree = robot("gmr_g1")
    gs = tree.geoms
    meshes = [g for g in range(tree.model.ngeom) if gs.type[g] == MESH and gs.hull_num[g] > 0
              and gs.hull_nbr_adr[gs.hull_adr[g] + gs.hull_num[g]] > gs.hull_nbr_adr[gs.hull_adr[g]]]
    assert meshes
    z = np.empty(3)
    for g in meshes:
        a, n = gs.hull_adr[g], gs.hull_num[g]
        for _ in range(20):
            R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
            c, v = rng.normal(size=3), rng.normal(size=3)
            v /= np.linalg.norm(v)
            start = int(rng.integers(a - 1, a + n))
            k = hull_support(gs, g, R, c, v, z, start)
            along = gs.hull_vert[a:a + n] @ (R.T @ v)
            assert a <= k < a + n
            assert along[k - a] >= along.max() - 1e-12, (g, k)
            np.testing.assert_allclose(z, c + R @ gs.hull_vert[k], atol=1e-12)


@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_a_cut_off_distance_is_a_lower_bound_and_exact_within(name, rng):
    """A pair measured with a cutoff reads its exact distance when within it, else a lower bound past it: never
    farther than it is; and MuJoCo finds no pair within the cutoff that the cut-off measure puts past it."""
    tree = robot(name)
    pairs = np.array(self_pairs(tree, SELF_CLEARANCE))
    cutoff = SELF_CLEARANCE + SELF_REACH
    m = tree.model.__copy__()
    m.opt.ccd_tolerance, m.opt.ccd_iterations = 1e-12, 500
    p1, p2, n = np.empty(3), np.empty(3), np.empty(3)
    within = 0
    for q in near_rest(tree, rng, 4):
        f = forward(tree, q[None])
        d = mujoco.MjData(m)
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        for a, b in pairs.tolist():
            full = D.pair_distance_normal(tree.geoms, f.rot, f.pos, a, b, p1, p2, n, np.inf)
            cut = D.pair_distance_normal(tree.geoms, f.rot, f.pos, a, b, p1, p2, n, cutoff)
            assert cut <= full + 1e-12, (a, b)
            if cut <= cutoff:
                within += 1
                assert cut == full
            else:
                assert full > cutoff
                assert mujoco.mj_geomDistance(m, d, a, b, 1.0, None) > cutoff - 1e-6, (a, b)
    assert within > 0


@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_clearance_rows_are_mujocos_nearest_pairs(name, rng):
    """Issue 55 (speed): the retarget's self-clearance, broad phase and cutoffs included, gives a row to every
    pair MuJoCo finds within its reach, at MuJoCo's distance where apart, and to none beyond it."""
    tree = robot(name)
    pairs = np.array(self_pairs(tree, SELF_CLEARANCE))
    reach = SELF_CLEARANCE + SELF_REACH
    goal = G.Clearance(SELF_CLEARANCE, pairs=pairs, reach=SELF_REACH, closest=len(pairs))
    prog = compile_goals(tree, [goal])
    m = tree.model.__copy__()
    m.opt.ccd_tolerance, m.opt.ccd_iterations = 1e-12, 500
    out, low = np.empty(len(pairs), np.int64), np.empty(len(pairs))
    for q in near_rest(tree, rng, 4):
        d = mujoco.MjData(m)
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        ref = np.array([mujoco.mj_geomDistance(m, d, a, b, 1.0, None) for a, b in pairs.tolist()])
        f = forward(tree, q[None])
        near = set(out[:near_pairs(tree.geoms, f.rot, f.pos, pairs, reach, out, low)].tolist())
        assert set(np.flatnonzero(ref <= reach).tolist()) <= near  # the broad phase skips none of them
        rows = evaluate_program(tree, prog, q[None])[0][0] + SELF_CLEARANCE
        live = np.sort(rows[rows < reach])
        assert len(live) == int((ref <= reach).sum())
        apart = np.sort(ref[ref <= reach])
        np.testing.assert_allclose(live[apart > 0], apart[apart > 0], atol=1e-6)
        assert (live[apart <= 0] <= 1e-9).all()


def test_clearance_measures_only_the_pairs_that_may_be_kept(rng):
    """Issue 55 (speed): the retarget's self-clearance on the G1's meshes measures its broad phase's pairs nearest
    lower bound first and stops at the k-th closest: its rows are those of measuring every pair, from far fewer
    GJK runs than the pairs whose bounding spheres come within its reach (each a GJK on two hulls of up to
    2 000 vertices)."""
    tree = robot("gmr_g1")
    pairs = np.array(self_pairs(tree, SELF_CLEARANCE))
    reach, k = SELF_CLEARANCE + SELF_REACH, 8
    ga = compile_goals(tree, [G.Clearance(SELF_CLEARANCE, pairs=pairs, reach=SELF_REACH, closest=k)]).arrays
    g, J = np.empty(k), np.empty((k, tree.nv))
    out, low = np.empty(len(pairs), np.int64), np.empty(len(pairs))
    measured, near, spheres = 0, 0, 0
    for q in near_rest(tree, rng, 5):
        f = forward(tree, q[None])
        measured += clearance_rows(tree.kin, ga.geoms, ga.bounded, ga.pairs, 0, f.rot, f.pos, f.inner_rot,
                                   f.inner_pos, SELF_CLEARANCE, reach, g, J, 0, k)
        n = near_pairs(tree.geoms, f.rot, f.pos, pairs, reach, out, low)
        near += n
        d = tree.distances(q, pairs)
        assert (low[:n] <= d[out[:n]]).all()  # lower bounds
        np.testing.assert_array_equal(np.sort(g), np.sort(np.minimum(d, reach))[:k] - SELF_CLEARANCE)
        R, x = geom_frames(tree, f.rot, f.pos, np.arange(tree.model.ngeom))
        rb = tree.geoms.rbound
        spheres += int((np.linalg.norm(x[pairs[:, 0]] - x[pairs[:, 1]], axis=1) - rb[pairs[:, 0]] - rb[pairs[:, 1]]
                        <= reach).sum())
    assert measured <= near < spheres
    assert measured < spheres / 3
