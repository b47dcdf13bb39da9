"""Chains built in code: DH tables and link records round-trip through MJCF and mjkin's FK."""

from __future__ import annotations

import numpy as np
import pytest

import mjkin
from mjkin.kinematics import build

UR5E_DH = [[0, np.pi / 2, 0.1625, 0], [-0.425, 0, 0, 0], [-0.3922, 0, 0, 0],
           [0, np.pi / 2, 0.1333, 0], [0, -np.pi / 2, 0.0997, 0], [0, 0, 0.0996, 0]]


@pytest.mark.parametrize("convention", ["standard", "modified"])
@pytest.mark.parametrize("joints", ["RRRRRR", "PRRPRR", "RPRRRP"])
def test_dh_round_trip(convention, joints, rng):
    rows = rng.normal(size=(6, 4))
    ranges = [(-1.0, 1.0)] * 6
    tree = mjkin.load(build.dh_chain(rows, joints, convention, ranges=ranges))
    names = mjkin.kinematics.qspace.JOINT_NAMES
    assert [names[k] for k in tree.jnt_type] == ["hinge" if c == "R" else "slide" for c in joints]
    np.testing.assert_array_equal(tree.jnt_range, ranges)
    Q = tree.random_q(rng, 100)
    np.testing.assert_allclose(tree.pose(Q, "ee"), build.dh_fk(rows, Q, joints, convention), atol=1e-12)


def test_dh_ur5e_zero_pose():
    """The published UR5e DH table: the flange at q = 0 sits at (-0.8172, -0.2329, 0.0628)."""
    tree = mjkin.load(build.dh_chain(UR5E_DH))
    np.testing.assert_allclose(tree.pose(np.zeros(6), "ee")[:3, 3], [-0.8172, -0.2329, 0.0628], atol=1e-12)


def test_planar_chain_tip():
    tree = mjkin.load(build.planar_chain([15, 10, 5]))
    np.testing.assert_allclose(tree.pose([0, 0, 0], "ee")[:3, 3], [30, 0, 0], atol=1e-12)
    np.testing.assert_allclose(tree.pose([np.pi / 2, 0, 0], "ee")[:3, 3], [0, 30, 0], atol=1e-12)
    q = np.array([0.3, -0.5, 1.1])
    angles = np.cumsum(q)
    expected = [np.sum([15, 10, 5] * np.cos(angles)), np.sum([15, 10, 5] * np.sin(angles)), 0]
    np.testing.assert_allclose(tree.pose(q, "ee")[:3, 3], expected, atol=1e-12)
    assert tree.names("site") == ["link1_tip", "link2_tip", "link3_tip", "ee"]


def test_links_make_a_tree_with_every_joint_kind():
    L = build.Link
    links = [L("torso", joint="ball", length=0.5, direction=(0, 0, 1), range=(0, 0.5)),
             L("arm", "torso", joint="hinge", axis=(0, 1, 0), length=0.4, direction=(0, 0, -1), at=(0, 0.2, 0.5)),
             L("slider", "torso", joint="slide", axis=(1, 0, 0), length=0.3, range=(0, 0.2)),
             L("head", "torso", joint="fixed", length=0.2, direction=(0, 0, 1))]
    tree = mjkin.load(build.links_mjcf(links, ee="arm"))
    assert tree.nq == 4 + 1 + 1 and tree.nv == 3 + 1 + 1
    np.testing.assert_allclose(tree.pose(tree.qpos0, "ee")[:3, 3], [0, 0.2, 0.1], atol=1e-12)
    np.testing.assert_allclose(tree.pose(tree.qpos0, "head_tip")[:3, 3], [0, 0, 0.7], atol=1e-12)
    q = tree.qpos0.copy()
    q[tree.jnt_qadr[1]] = np.pi / 2  # arm turns about y: the tip swings from -z to -x
    np.testing.assert_allclose(tree.pose(q, "arm_tip")[:3, 3], [-0.4, 0.2, 0.5], atol=1e-12)


@pytest.mark.parametrize("call, text", [
    (lambda: build.links_mjcf([]), "at least one"),
    (lambda: build.links_mjcf([build.Link("a", parent="b")]), "parent 'b' is not listed"),
    (lambda: build.links_mjcf([build.Link("a"), build.Link("a")]), "used twice"),
    (lambda: build.links_mjcf([build.Link("a", joint="screw")]), "joint must be 'hinge' or 'slide'"),
    (lambda: build.links_mjcf([build.Link("a", axis=(0, 0, 0))]), "axis must be a non-zero"),
    (lambda: build.links_mjcf([build.Link("a")], ee="b"), "ee link 'b'"),
    (lambda: build.planar_chain([]), "at least one"),
    (lambda: build.dh_chain(np.zeros((2, 3))), r"\(n, 4\)"),
    (lambda: build.dh_chain(np.zeros((2, 4)), "RX"), "one letter R"),
    (lambda: build.dh_chain(np.zeros((2, 4)), convention="craig"), "convention"),
])
def test_builder_errors(call, text):
    with pytest.raises(mjkin.InputError, match=text):
        call()
