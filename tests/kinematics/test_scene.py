"""Scene: MuJoCo's contacts filtered once, the same answers single and batched."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st

import mjkin
from conftest import tree_of
from mjkin.scene import Scene, _segment_gap

# a chain whose parent-child pair MuJoCo would report: an explicit <pair>, and filterparent disabled
LINK = ('<body name="{name}" pos="{x} 0 0"><joint name="j{name}" type="hinge" axis="0 1 0" range="-2.8 2.8"/>'
        '<geom name="g{name}" type="capsule" fromto="0 0 0 .5 0 0" size=".08"/>')
OVERLAPPING = ('<mujoco><compiler angle="radian"/><option><flag filterparent="{flag}"/></option><worldbody>'
               '<geom name="ground" type="plane" size="2 2 .1" pos="0 0 -0.5"/>'
               + LINK.format(name="a", x=0) + LINK.format(name="b", x=0.5) + LINK.format(name="c", x=0.5)
               + '</body></body></body></worldbody>{pair}</mujoco>')


def segment_distance(c1, h1, c2, h2) -> float:
    """Distance between segments ``c1 ± h1`` and ``c2 ± h2`` by the broad phase's compiled test."""
    return _segment_gap(np.array([c1, c2], float), np.array([h1, h2], float), 0, 1, np.empty((4, 3)))


def reference_contacts(tree, q, exclude_adjacent=True):
    """The plain definition: every contact MuJoCo reports, minus same-weld and parent-child body pairs."""
    m = tree.model
    d = mujoco.MjData(m)
    d.qpos[:] = q
    mujoco.mj_forward(m, d)
    out = []
    for c in d.contact[: d.ncon]:
        w1, w2 = (int(m.body_weldid[m.geom_bodyid[g]]) for g in (c.geom1, c.geom2))
        p1, p2 = int(m.body_weldid[m.body_parentid[w1]]), int(m.body_weldid[m.body_parentid[w2]])
        adjacent = w1 == w2 or (w1 != 0 and w2 != 0 and (p1 == w2 or p2 == w1))
        if not (exclude_adjacent and adjacent):
            out.append((sorted((int(c.geom1), int(c.geom2))), float(c.dist)))
    return out


@pytest.mark.parametrize("flag,pair", [("enable", ""), ("disable", ""),
                                       ("enable", '<contact><pair geom1="ga" geom2="gb"/></contact>')])
@pytest.mark.parametrize("exclude_adjacent", [True, False])
def test_contacts_equal_the_plain_definition(flag, pair, exclude_adjacent):
    tree = mjkin.load(OVERLAPPING.format(flag=flag, pair=pair))
    scene = Scene(tree, exclude_adjacent=exclude_adjacent)
    qs = tree.random_q(0, 200)
    seen_adjacent = 0
    for q in qs:
        ref = reference_contacts(tree, q, exclude_adjacent)
        got = scene.contacts(q)
        ids = [sorted(mujoco.mj_name2id(tree.model, mujoco.mjtObj.mjOBJ_GEOM, g) for g in (c.geom1, c.geom2))
               for c in got]
        assert ids == [r[0] for r in ref] and [c.distance for c in got] == [r[1] for r in ref]
        assert scene.count(q) == len(ref)
        seen_adjacent += any(abs(a - b) == 1 and 0 not in (a, b) for a, b in ids)
    # without the mask, MuJoCo's own adjacent reports come through exactly when the model lets them
    lets_through = flag == "disable" or pair != ""
    assert (seen_adjacent > 0) == (lets_through and not exclude_adjacent)


@pytest.mark.parametrize("model", ["arm7", "primate"])
def test_batched_in_collision_equals_single_calls(model):
    tree = tree_of(model)
    scene = Scene(tree)
    qs = tree.random_q(1, 64)
    batched = scene.in_collision(qs)
    assert batched.shape == (64,) and batched.dtype == bool
    single = [scene.in_collision(q) for q in qs]
    assert all(isinstance(s, bool) for s in single)
    np.testing.assert_array_equal(batched, single)
    assert 0 < batched.sum() < 64  # the sample has both kinds, so the test can fail
    counts = scene.count(qs.reshape(8, 8, -1))
    assert counts.shape == (8, 8) and np.array_equal(counts.ravel() > 0, batched)
    np.testing.assert_array_equal(scene.in_collision(qs, margin=-0.01), [scene.in_collision(q, -0.01) for q in qs])


def test_collision_query_leaves_drawing_state_alone():
    tree = tree_of("arm7")
    scene = Scene(tree)
    scene.set(tree.qpos0)
    cam = scene.data.cam_xpos.copy(), scene.data.light_xpos.copy()
    scene.in_collision(tree.random_q(2, 5))
    np.testing.assert_array_equal(scene.data.cam_xpos, cam[0])  # no mj_camlight for a collision query
    np.testing.assert_array_equal(scene.data.light_xpos, cam[1])


def test_bad_q_is_one_clear_error():
    scene = Scene(tree_of("arm7"))
    with pytest.raises(mjkin.InputError, match="shape"):
        scene.in_collision(np.zeros(3))
    with pytest.raises(mjkin.InputError, match="NaN"):
        scene.in_collision(np.full((2, 7), np.nan))


@pytest.mark.parametrize("model", ["arm7", "primate", "panda", "exclude", "pair", "noparent"])
def test_counts_with_fk_frames_skip_only_configurations_without_contacts(model):
    """The batched broad phase (bounding spheres from mjkin's FK) never changes a count."""
    src = {"exclude": OVERLAPPING.format(flag="enable", pair='<contact><exclude body1="world" body2="c"/></contact>'),
           "pair": OVERLAPPING.format(flag="enable", pair='<contact><pair geom1="ga" geom2="gb"/></contact>'),
           "noparent": OVERLAPPING.format(flag="disable", pair="")}.get(model, model)
    tree = tree_of(src) if src == model else mjkin.load(src)
    for exclude_adjacent in (True, False):
        scene = Scene(tree, exclude_adjacent=exclude_adjacent)
        qs = tree.random_q(3, 300)
        plain = scene.counts(qs)
        np.testing.assert_array_equal(scene.counts(qs, tree.kinematics(qs)), plain)
        assert plain.any() and (not exclude_adjacent or not plain.all())  # both kinds are compared
        np.testing.assert_array_equal(plain, [len(scene.contacts(q)) for q in qs])
    if model in ("arm7", "panda"):  # the shortcut is taken: far fewer MuJoCo calls than configurations
        assert scene._prefilter and np.count_nonzero(scene._near(tree.kinematics(qs))) < len(qs)


@pytest.mark.parametrize("model", ["arm7", "primate", "panda"])
def test_near_is_any_pair_within_reach_by_its_segments_or_its_plane(model):
    """The compiled broad phase (which skips pairs whose centres are far apart) equals the test written out."""
    tree = tree_of(model)
    scene = Scene(tree)
    f = tree.kinematics(tree.random_q(5, 200))
    (pairs, reach), (other, normal, offset, radius) = scene._spheres, scene._planes
    rot = f.rot[:, scene._geom_body]
    centre = f.pos[:, scene._geom_body] + np.einsum("bgij,gj->bgi", rot, scene._geom_pos)
    axis = scene._half[:, None] * np.einsum("bgij,gj->bgi", rot, scene._geom_axis)
    want = [any(segment_distance(c[i], h[i], c[j], h[j]) <= r for (i, j), r in zip(pairs, reach, strict=True))
            or any(c[g] @ n - o - abs(h[g] @ n) <= r for g, n, o, r in zip(other, normal, offset, radius, strict=True))
            for c, h in zip(centre, axis, strict=True)]
    near = scene._near(f)
    np.testing.assert_array_equal(near, want)
    assert near.any() and not near.all()  # both answers are compared


segment_distance([0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1])  # load the compiled kernel outside hypothesis' clock
vec3 = st.lists(st.floats(-2, 2, allow_nan=False), min_size=3, max_size=3).map(np.array)


@given(vec3, vec3, vec3, vec3, st.sampled_from(["free", "point1", "point2", "parallel", "touching"]))
# two segments crossing at a hair's angle came out 1.2e-7 apart (hypothesis found it)
@example(np.zeros(3), np.array([0.0, 1.192092896e-07, 1.0]), np.zeros(3), np.array([0.0, 0.0, 1.0]), "free")
# and two meeting at the origin, 6e-8 rad apart, 1.6e-9 (A E - B² cancelled; found exploring)
@example(np.zeros(3), np.array([0.9375, 0.0, -5.96e-08]), np.zeros(3), np.array([1.0, 0.0, -1.19e-07]), "free")
def test_segment_distance_is_the_closest_approach(c1, h1, c2, h2, case):
    """Never above a dense sampling of both segments, and below it by at most the sampling step."""
    if case == "point1":
        h1 = 0 * h1
    elif case == "point2":
        h2 = 0 * h2
    elif case == "parallel":
        h2 = -1.5 * h1
    elif case == "touching":
        c2 = c1 + 0.5 * h1
    d = segment_distance(c1, h1, c2, h2)
    t = np.linspace(-1, 1, 201)
    a, b = c1 + t[:, None] * h1, c2 + t[:, None] * h2
    brute = np.sqrt(((a[:, None] - b[None]) ** 2).sum(-1)).min()
    step = (np.linalg.norm(h1) + np.linalg.norm(h2)) / 100
    assert brute - step - 1e-9 <= d <= brute + 1e-9
