"""Geom pairs and signed distances against MuJoCo (mj_collision's pairs, mj_geomDistance)."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mjkin
from conftest import ALL_MODELS, FD_TOL, bundled, model_id, shared, tree_of
from mjkin.apps.bench.report import shared_models_dir
from mjkin.kinematics import distance as D
from mjkin.kinematics import geoms as G
from mjkin.kinematics.frames import forward
from mjkin.kinematics.geoms import BOX, CAPSULE, CYLINDER, ELLIPSOID, PLANE, SPHERE, contact_pairs, native_pairs

DIST_TOL = 1e-6  # against mj_geomDistance
# pairs whose penetration depth MuJoCo computes exactly (others: capsule-box contacts at the capsule's ends, or
# MuJoCo's iterative convex solver)
EXACT_DEPTH = {(SPHERE, SPHERE), (SPHERE, CAPSULE), (CAPSULE, CAPSULE), (SPHERE, BOX), (BOX, BOX), (PLANE, SPHERE),
               (PLANE, CAPSULE), (PLANE, BOX), (PLANE, CYLINDER), (PLANE, ELLIPSOID)}


def mujoco_pairs(model: mujoco.MjModel, qs: np.ndarray) -> set[tuple[int, int]]:
    """Geom pairs MuJoCo's collision reports at any of ``qs`` with every geom's margin huge (so all it tests)."""
    m = model.__copy__()
    m.geom_margin[:] = 1e3
    m.pair_margin[:] = 1e3
    m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_MIDPHASE  # its bounding volumes ignore the margin
    d = mujoco.MjData(m)
    seen: set[tuple[int, int]] = set()
    for q in qs:
        d.qpos[:] = q
        mujoco.mj_forward(m, d)
        seen |= {(min(a, b), max(a, b)) for a, b in d.contact.geom.tolist()}
    return seen


def as_set(pairs: np.ndarray) -> set[tuple[int, int]]:
    return {(min(a, b), max(a, b)) for a, b in pairs.tolist()}


def distance_jacobians(tree: mjkin.Tree, q: np.ndarray, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed distances ``(P,)`` of the geom pairs ``(P, 2)`` at one ``q`` and their gradients ``(P, nv)``.

    mjkin's compiled :func:`~mjkin.kinematics.distance.pair_distance_jacobian` where it measures the pair, else
    :func:`~mjkin.kinematics.distance.fallback_distance` (as ``Tree.distances`` does).
    """
    f = forward(tree, np.asarray(q, float).reshape(1, -1))
    d, J = np.empty(len(pairs)), np.empty((len(pairs), tree.nv))
    for k, (g1, g2) in enumerate(pairs):
        d[k] = D.pair_distance_jacobian(tree.kin, tree.geoms, f.rot, f.pos, f.inner_rot, f.inner_pos, int(g1),
                                        int(g2), J[k])
    for k in np.flatnonzero(~native_pairs(tree.geoms, pairs)):
        d[k], J[k] = D.fallback_distance(tree, q, int(pairs[k, 0]), int(pairs[k, 1]))
    return d, J


@pytest.mark.parametrize("path", ALL_MODELS, ids=model_id)
def test_contact_pairs_are_mujocos(path, rng):
    """Every pair MuJoCo tests is listed once; each listed pair MuJoCo reports when within its margin.

    Box-box pairs are the exception of the second half: with a huge margin MuJoCo drops box-box contacts
    that lie outside both boxes.
    """
    tree = tree_of(path)
    m = tree.model
    ours = contact_pairs(tree)
    assert ours.dtype == np.int64 and ours.shape[1:] == (2,) and len(as_set(ours)) == len(ours)
    theirs = mujoco_pairs(m, tree.random_q(rng, 5))
    assert theirs <= as_set(ours)
    for a, b in as_set(ours) - theirs:
        assert m.geom_type[a] == m.geom_type[b] == BOX


FILTERS = """<mujoco><option><flag filterparent="{fp}"/></option><worldbody>
  <geom name="floor" type="plane" size="1 1 .1"/>
  <geom name="post" type="sphere" size=".1" pos="1 1 1"/>
  <body name="base"><geom name="base" size=".1"/>
    <body name="a"><joint/><geom name="a" size=".1"/>
      <body name="b"><joint/><geom name="b" size=".1"/>
        <body name="c" pos="0 0 .5"><geom name="c" size=".1"/></body>
        <body name="d"><joint/><geom name="d" size=".1" contype="2" conaffinity="2"/>
          <body name="e"><joint/><geom name="e" size=".1" contype="4" conaffinity="2"/></body></body>
      </body></body></body>
  <body name="free"><freejoint/><geom name="free" size=".1"/></body>
</worldbody><contact><exclude body1="a" body2="free"/>{pair}</contact></mujoco>"""


def named_pairs(xml: str) -> set[tuple[str, ...]]:
    """The pairs of a model of spheres and a plane, by geom names; MuJoCo reports exactly these."""
    tree = mjkin.load(xml)
    name = [mujoco.mj_id2name(tree.model, mujoco.mjtObj.mjOBJ_GEOM, g) for g in range(tree.model.ngeom)]
    assert mujoco_pairs(tree.model, tree.random_q(0, 3)) == as_set(contact_pairs(tree))
    return {tuple(sorted((name[a], name[b]))) for a, b in contact_pairs(tree).tolist()}


def test_filters_as_mujoco():
    pairs = named_pairs(FILTERS.format(fp="enable", pair=""))
    # floor, post and base are welded to the world: together one body, which collides with every other (the
    # parent filter skips the world); c is welded to b; a-b, a-c (child's weld) and d-e are parent and child;
    # d and e have no contype/conaffinity bit in common with the rest; a and free are excluded
    world = ("base", "floor", "post")
    assert pairs == {tuple(sorted((w, g))) for w in world for g in ("a", "b", "c", "free")} | {
        ("b", "free"), ("c", "free")}


def test_filterparent_disabled_keeps_parent_child():
    pairs = named_pairs(FILTERS.format(fp="disable", pair=""))
    assert {("a", "b"), ("a", "c"), ("d", "e")} <= pairs
    assert ("b", "c") not in pairs  # welded together all the same


def test_explicit_pairs_are_added_once():
    pairs = named_pairs(FILTERS.format(fp="enable", pair='<pair geom1="a" geom2="b"/><pair geom1="c" geom2="b"/>'
                                       '<pair geom1="floor" geom2="b"/>'))
    assert {("a", "b"), ("b", "c")} <= pairs
    tree = mjkin.load(FILTERS.format(fp="enable", pair='<pair geom1="floor" geom2="b"/>'))
    assert len(contact_pairs(tree)) == len(as_set(contact_pairs(tree)))


def world_state(tree: mjkin.Tree, q: np.ndarray) -> mujoco.MjData:
    d = mujoco.MjData(tree.model)
    d.qpos[:] = q
    mujoco.mj_kinematics(tree.model, d)
    return d


def by_gjk(model: mujoco.MjModel, pairs: np.ndarray) -> np.ndarray:
    """Which pairs mjkin measures by GJK (ellipsoids, cylinder-cylinder, cylinder-box): accurate to ~1e-10 only."""
    t = np.sort(np.asarray(model.geom_type)[pairs], axis=1)
    return ((t == ELLIPSOID).any(1) | ((t[:, 0] == CYLINDER) & (t[:, 1] >= CYLINDER))) & (t[:, 0] != PLANE)


def sampled_capsule_box(m: mujoco.MjModel, d: mujoco.MjData, cap: int, box: int) -> float:
    """Least signed distance of a capsule from a box over 10001 points of its axis (MuJoCo's geom frames)."""
    R, c, s = d.geom_xmat[box].reshape(3, 3), d.geom_xpos[box], m.geom_size[box]
    axis = d.geom_xmat[cap].reshape(3, 3)[:, 2] * m.geom_size[cap, 1]
    pts = d.geom_xpos[cap] + np.linspace(-1, 1, 10001)[:, None] * axis
    q = np.abs((pts - c) @ R) - s
    outside = np.linalg.norm(np.maximum(q, 0), axis=1)
    return float(np.min(np.where(outside > 0, outside, q.max(1))) - m.geom_size[cap, 0])


def check_against_mujoco(tree: mjkin.Tree, qs: np.ndarray, pairs: np.ndarray) -> None:
    m = tree.model.__copy__()
    m.opt.ccd_tolerance, m.opt.ccd_iterations = 1e-12, 500  # MuJoCo's convex solver to the last digits
    ours = tree.distances(qs, pairs)
    assert ours.shape == (len(qs), len(pairs))
    for k, q in enumerate(qs):
        d = world_state(tree, q)  # (same data layout: m is a copy with other solver options)
        for i, (a, b) in enumerate(pairs.tolist()):
            ref = mujoco.mj_geomDistance(m, d, a, b, 100.0, None)
            kind = tuple(sorted((int(m.geom_type[a]), int(m.geom_type[b]))))
            msg = f"geoms {a}, {b} (types {kind}) at q #{k}"
            if kind == (CAPSULE, BOX) and ref > 0 > ours[k, i]:
                # MuJoCo reports a capsule through a box, both ends outside, as apart: sample its axis instead
                assert sampled_capsule_box(m, d, *((a, b) if m.geom_type[a] == CAPSULE else (b, a))) < 0, msg
                continue
            if ref > 0 or kind in EXACT_DEPTH:
                assert abs(ours[k, i] - ref) < DIST_TOL, msg
            elif abs(ref) > DIST_TOL:
                assert np.sign(ours[k, i]) == np.sign(ref), msg


@pytest.mark.parametrize("path", bundled() + shared(), ids=model_id)
def test_distances_equal_mj_geomDistance(path, rng):
    tree = tree_of(path)
    pairs = contact_pairs(tree)
    pairs = pairs[native_pairs(tree.geoms, pairs)]
    check_against_mujoco(tree, tree.random_q(rng, 10), pairs)


SHAPES = {SPHERE: "sphere", CAPSULE: "capsule", BOX: "box", CYLINDER: "cylinder", ELLIPSOID: "ellipsoid"}
NATIVE_KINDS = [(PLANE, SPHERE), (PLANE, CAPSULE), (PLANE, BOX), (PLANE, CYLINDER), (PLANE, ELLIPSOID),
                (SPHERE, SPHERE), (SPHERE, CAPSULE), (CAPSULE, CAPSULE), (SPHERE, BOX), (CAPSULE, BOX),
                (SPHERE, CYLINDER), (CAPSULE, CYLINDER), (BOX, BOX), (CYLINDER, CYLINDER), (CYLINDER, BOX),
                (SPHERE, ELLIPSOID), (CAPSULE, ELLIPSOID), (ELLIPSOID, ELLIPSOID), (ELLIPSOID, CYLINDER),
                (ELLIPSOID, BOX)]


def two_geoms(k1: int, k2: int, s1, s2) -> mjkin.Tree:
    """Two geoms on free bodies (a plane in the world): q places them."""
    g1 = '<geom type="plane" size="1 1 .1"/>' if k1 == PLANE else (
        f'<body><freejoint/><geom type="{SHAPES[k1]}" size="{s1[0]} {s1[1]} {s1[2]}"/></body>')
    return mjkin.load(f"""<mujoco><worldbody>{g1}<body><freejoint/>
        <geom type="{SHAPES[k2]}" size="{s2[0]} {s2[1]} {s2[2]}"/></body></worldbody></mujoco>""")


sizes = st.tuples(*[st.floats(0.02, 0.5)] * 3)
poses = st.lists(st.floats(-1, 1), min_size=14, max_size=14)


def placed(tree: mjkin.Tree, pose: list[float]) -> np.ndarray:
    """Free bodies placed by ``pose`` (7 numbers each): near the origin, so that they often touch."""
    q = np.array(pose[:tree.nq])
    for k in range(0, tree.nq, 7):
        q[k:k + 3] *= 0.6
        n = np.linalg.norm(q[k + 3:k + 7])
        q[k + 3:k + 7] = q[k + 3:k + 7] / n if n > 1e-3 else [1, 0, 0, 0]
    return q


@settings(max_examples=150)
@given(st.sampled_from(NATIVE_KINDS), sizes, sizes, poses)
def test_primitive_pairs_equal_mj_geomDistance(kinds, s1, s2, pose):
    tree = two_geoms(*kinds, s1, s2)
    q = placed(tree, pose)
    check_against_mujoco(tree, q[None], np.array([[0, 1]]))
    check_against_mujoco(tree, q[None], np.array([[1, 0]]))


def fd_check(tree: mjkin.Tree, q: np.ndarray, pairs: np.ndarray, tol: float = FD_TOL, kinks: bool = False,
             h: float = 1e-6) -> None:
    """Gradients against central differences; ``kinks=True`` skips where the one-sided ones disagree."""
    d, J = distance_jacobians(tree, q, pairs)
    np.testing.assert_array_equal(d, tree.distances(q, pairs))
    for i in range(tree.nv):
        e = np.zeros(tree.nv)
        e[i] = h
        up, down = tree.distances(tree.integrate(q, e), pairs), tree.distances(tree.integrate(q, -e), pairs)
        smooth = np.abs((up - d) - (d - down)) / h < 1e-3 + 1e-9 / h**2 if kinks else np.ones(len(d), bool)
        np.testing.assert_allclose(J[smooth, i], ((up - down) / (2 * h))[smooth], atol=tol, err_msg=f"dof {i}")


@pytest.mark.parametrize("path", [p for p in bundled() + shared() if p.stem in {"arm7", "primate", "right_hand",
                                                                               "g1", "panda"}], ids=model_id)
def test_distance_jacobians_match_finite_differences(path, rng):
    tree = tree_of(path)
    pairs = contact_pairs(tree)
    pairs = pairs[native_pairs(tree.geoms, pairs) & ~by_gjk(tree.model, pairs)]  # GJK's: with the primitives
    for q in tree.random_q(rng, 3):
        fd_check(tree, q, pairs)


@settings(max_examples=60)
@given(st.sampled_from(NATIVE_KINDS), sizes, sizes, poses)
def test_primitive_distance_jacobians_match_finite_differences(kinds, s1, s2, pose):
    tree = two_geoms(*kinds, s1, s2)
    q = placed(tree, pose)
    # off the poses where features tie exactly (as identical boxes one inside the other): no derivative there
    q[-7:-4] += [0.0123, -0.0071, 0.0049]
    q[-4:] = mjkin.spatial.quat_mul(q[-4:], mjkin.spatial.quat_normalize([1.0, 0.013, -0.021, 0.008]))
    d, _ = distance_jacobians(tree, q, np.array([[0, 1]]))
    # at contact the distance has a kink, and so have penetration depths where two faces tie (skipped by kinks=True),
    # where a capsule's deepest point is as far from a cylinder's side as from its cap, or where the cores of two
    # capsules cross (left out)
    rounded = kinds[0] in (SPHERE, CAPSULE) and kinds[1] in (SPHERE, CAPSULE)
    cores_meet = rounded and d[0] + s1[0] + s2[0] < 1e-4
    gjk = by_gjk(tree.model, np.array([[0, 1]]))[0]  # its distances stop within 1e-10: coarser differences
    if d[0] > 1e-4 or (d[0] < -1e-4 and kinds in EXACT_DEPTH and not cores_meet):
        fd_check(tree, q, np.array([[0, 1]]), tol=1e-4 if gjk else 1e-5, kinks=True, h=1e-4 if gjk else 1e-6)


def test_fallback_is_mujocos_from_mjkin_fk(rng):
    """The fallback (for pairs mjkin does not compute itself: height fields, SDFs) is MuJoCo's distance at mjkin's
    geom frames, and its gradient; mjkin's own of a mesh pair (its hull) agrees with it wherever they are apart."""
    tree = mjkin.load("""<mujoco><asset><mesh name="tet" vertex="0 0 0  .2 0 0  0 .2 0  0 0 .2"/></asset>
        <worldbody>
        <body><joint type="ball"/><geom type="ellipsoid" size=".1 .2 .3" pos="0 0 .2"/></body>
        <body pos=".5 0 0"><joint axis="0 1 0"/><joint axis="1 0 0"/><geom type="cylinder" size=".1 .2"/></body>
        <body pos="0 .5 0"><joint axis="0 0 1"/><geom type="mesh" mesh="tet"/></body>
        </worldbody></mujoco>""")
    pairs = contact_pairs(tree)
    assert pairs.tolist() == [[0, 1], [0, 2], [1, 2]] and native_pairs(tree.geoms, pairs).all()
    for q in tree.random_q(rng, 5):
        d = world_state(tree, q)
        ours = tree.distances(q)
        for k, (g1, g2) in enumerate(pairs.tolist()):
            ref = mujoco.mj_geomDistance(tree.model, d, g1, g2, 10.0, None)
            dist, grad = D.fallback_distance(tree, q, g1, g2)
            assert abs(dist - ref) < 1e-9 and (abs(ours[k] - ref) < DIST_TOL if ref > 0 else ours[k] < DIST_TOL)
            h = 1e-4  # MuJoCo's convex solver stops at ~1e-6: a coarse difference
            for i in range(tree.nv):
                e = np.zeros(tree.nv)
                e[i] = h
                fd = (D.fallback_distance(tree, tree.integrate(q, e), g1, g2)[0]
                      - D.fallback_distance(tree, tree.integrate(q, -e), g1, g2)[0]) / (2 * h)
                assert abs(grad[i] - fd) < 1e-2, (g1, g2, i)


@pytest.mark.parametrize("name", ["primate", "arm7", "gmr_g1"])
def test_near_pairs_are_those_whose_bounding_spheres_and_boxes_come_within_reach(name, rng):
    """The broad phase keeps a pair when its bounding spheres and its boxes (geom_aabb, by separating axes) come
    within reach: never a pair whose geoms are within reach, and on GMR's G1 far fewer than the spheres alone."""
    if name == "gmr_g1" and not GMR_G1.is_file():
        pytest.skip(f"GMR's G1 is not here ({GMR_G1})")
    tree = tree_of(GMR_G1 if name == "gmr_g1" else name)
    pairs = contact_pairs(tree)
    gs = tree.geoms
    reach = 0.05
    out, low = np.empty(len(pairs), np.int64), np.empty(len(pairs))
    fewer = 0
    for q in tree.random_q(rng, 20):
        f = forward(tree, q[None])
        k = G.near_pairs(gs, f.rot, f.pos, pairs, reach, out, low)
        R, x = D.geom_frames(tree, f.rot, f.pos, np.arange(tree.model.ngeom))
        a, b = pairs[:, 0], pairs[:, 1]
        gap = np.linalg.norm(x[a] - x[b], axis=1) - gs.rbound[a] - gs.rbound[b]
        plane_a, plane_b = gs.type[a] == PLANE, gs.type[b] == PLANE
        gap[plane_a] = np.einsum("ij,ij->i", R[a, :, 2], x[b] - x[a])[plane_a] - gs.rbound[b][plane_a]
        gap[plane_b] = np.einsum("ij,ij->i", R[b, :, 2], x[a] - x[b])[plane_b] - gs.rbound[a][plane_b]
        near = set(out[:k].tolist())
        assert near <= set(np.flatnonzero(gap <= reach).tolist())
        d = tree.distances(q, pairs)
        assert set(np.flatnonzero(d <= reach)) <= near
        assert (low[:k] <= d[out[:k]]).all()  # each near pair's lower bound is one
        fewer += int((gap <= reach).sum()) - k
    assert fewer > 0 or name != "gmr_g1"


def test_batched_distances_equal_per_q(rng):
    tree = tree_of("primate")
    Q = tree.random_q(rng, 6).reshape(2, 3, tree.nq)
    D = tree.distances(Q)
    assert D.shape == (2, 3, len(contact_pairs(tree)))
    for idx in np.ndindex(2, 3):
        np.testing.assert_array_equal(D[idx], tree.distances(Q[idx]))


GMR_G1 = (shared_models_dir() or Path("../shared/models")) / "gmr_unitree_g1" / "g1_mocap_29dof.xml"
need_gmr_g1 = pytest.mark.skipif(not GMR_G1.is_file(), reason=f"GMR's G1 (collision meshes) is not here ({GMR_G1})")


@need_gmr_g1
def test_mesh_pairs_are_measured_on_their_hulls_as_mujoco_does(rng):
    """Issue 55: GMR's G1 collides mostly STL meshes. mjkin measures them itself, on their convex hulls (as
    MuJoCo does), to mj_geomDistance's figure wherever they are apart; a penetrating pair reads negative. (It
    used to measure none of them: a clearance kept their bounding spheres apart, 62 mm deep where MuJoCo found
    the pair 9.5 mm apart.)"""
    tree = tree_of(GMR_G1)
    pairs = contact_pairs(tree)
    assert native_pairs(tree.geoms, pairs).all()
    m = tree.model.__copy__()
    m.opt.ccd_tolerance, m.opt.ccd_iterations = 1e-12, 500
    qs = np.vstack([tree.qpos0, tree.random_q(rng, 2)])
    f = forward(tree, qs)
    p1, p2 = np.empty(3), np.empty(3)
    for k, q in enumerate(qs):
        d = world_state(tree, q)
        for a, b in pairs.tolist():
            ours = D.pair_distance(tree.geoms, f.rot[k:k + 1], f.pos[k:k + 1], a, b, p1, p2)
            ref = mujoco.mj_geomDistance(m, d, a, b, 100.0, None)
            if ref > 0:
                assert abs(ours - ref) < 1e-6, (a, b, k)
                assert abs(np.linalg.norm(p2 - p1) - ours) < 1e-9
            else:
                assert ours < 1e-9, (a, b, k)


@need_gmr_g1
def test_mesh_distance_jacobians_match_finite_differences(rng):
    tree = tree_of(GMR_G1)
    pairs = contact_pairs(tree)
    q = tree.random_q(rng, 1)[0]
    d = tree.distances(q, pairs)
    apart = pairs[(d > 1e-3) & (d < 0.05)][:40]  # near, where a clearance reads them; kinks (ties) skipped
    assert len(apart) >= 5
    fd_check(tree, q, apart, tol=1e-5, kinks=True, h=1e-5)
