"""The seeds' reproducible examples (worked examples of the sources): their shape, not hard-coded numbers."""

from __future__ import annotations

import numpy as np
import pytest

import mjkin
from mjkin.apps.demo import seeds

GAP = np.hypot(35.0, 5.0) - 30.0  # how close a 30-unit arm gets to (-35, 5)


def test_pseudoinverse_walks_onto_the_goal_within_20_frames():
    res = seeds.three_link("pinv", seeds.REACHABLE)
    assert res.status == "converged" and res.iterations <= 20
    e = res.history.error[: res.iterations + 1, 0]
    assert e[5] < e[0] and e[10] < e[5]  # it walks: the error falls frame by frame, no jump


@pytest.mark.parametrize("method", ["transpose", "ccd", "dls", "reach"])
def test_other_methods_reach_the_same_goal(method):
    res = seeds.three_link(method, seeds.REACHABLE, frames=300)
    assert res.status == "converged"
    tip = mjkin.load("planar_3link").pose(res.q, "tip")[:3, 3]
    np.testing.assert_allclose(tip, seeds.REACHABLE, atol=1e-6)


def test_unreachable_pinv_blows_up_dls_stays_smooth_and_stretches():
    pinv, dls = seeds.three_link("pinv", seeds.UNREACHABLE), seeds.three_link("dls", seeds.UNREACHABLE)
    p_steps, d_steps = seeds.joint_steps(pinv), seeds.joint_steps(dls)
    assert p_steps.max() > 3 * d_steps.max()  # the singular stretched pose makes pinv's steps jump
    assert p_steps[-5:].max() > 2 * p_steps[:5].max()  # and the jump comes as the arm straightens
    e = dls.history.error[: dls.iterations + 1, 0]
    assert np.all(np.diff(e) <= 1e-9)  # damped: monotone
    long = seeds.three_link("dls", seeds.UNREACHABLE, frames=100)
    assert long.error[0] == pytest.approx(GAP, abs=1e-3)  # ends stretched toward the goal
    assert not long.success


def test_ccd_converges_linearly_and_faster_with_more_links():
    e3 = seeds.ccd_convergence(3)
    ratios = e3[1:] / e3[:-1]
    assert np.all(ratios < 0.5)  # contracts every sweep
    assert ratios.max() / ratios.min() < 3  # by a roughly constant factor: linear convergence
    assert e3[-1] < 1e-3 * e3[0]
    medians = {n: np.median([seeds.ccd_convergence(n, seed=s) for s in range(8)], axis=0) for n in (3, 20)}
    assert medians[20][3] < 1e-3 * medians[3][3]  # more links, faster
    assert medians[20][-1] < 1e-13  # down to machine precision


def test_two_link_analytic():
    q, ok = seeds.two_link(np.array([0.9, 0.8, 0.0]))
    assert ok
    tip = mjkin.load("planar_2link").pose(q, "tip")[:, :3, 3]
    np.testing.assert_allclose(tip, [[0.9, 0.8, 0.0]] * 2, atol=1e-12)
    assert not seeds.two_link(np.array([2.0, 0.0, 0.0]))[1]


def test_bench_seeds_writes_figures(tmp_path):
    pytest.importorskip("matplotlib")
    files = seeds.figures(tmp_path)
    assert len(files) == 4 + len(seeds.METHODS) and all(f.stat().st_size > 1000 for f in files)
    assert {f.name for f in files} >= {f"seed1_convergence_{m}.png" for m in seeds.METHODS}
    assert not list(tmp_path.glob(".*"))  # no temporary files left behind
