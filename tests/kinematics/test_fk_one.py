"""One configuration's short path (``tree.pose(q, frame)``, ``tree.fk(q)``): the batched path's bits, MuJoCo's poses.

The short path runs the FK over the frame's ancestors only (:mod:`mjkin.kinematics.chain`);
it must give exactly the batched path's numbers, and the batched path's errors for bad input,
both through the C module ``_posecall`` and through numba's entry (installs without a compiler).
"""

from __future__ import annotations

import contextlib
import pickle
import shutil
from collections.abc import Iterator

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import mjkin
from conftest import FK_TOL, GYM_ASSETS, mujoco_state, tree_of
from mjkin.kinematics import chain
from mjkin.kinematics import tree as tree_module
from mjkin.kinematics.chain import MAX_BODIES, chain_pose, chain_poses

# hinge arms, slides, ball chains, free roots (primate, the humanoid, the ant)
MODELS = ["arm7", "panda", "primate", "ball_chain", "planar_prismatic", GYM_ASSETS / "humanoid.xml",
          GYM_ASSETS / "ant.xml"]


def frames_of(tree: mjkin.Tree) -> list[tuple[str, str]]:
    """Every named site and body as ``(name, kind)``."""
    return [(n, k) for k in ("site", "body") for n in tree.names(k) if n]  # type: ignore[arg-type]


@contextlib.contextmanager
def short_path(path: str) -> Iterator[None]:
    """``Tree.pose`` and ``Tree.fk`` through the C module ("c", as installed) or numba's entry ("numba")."""
    saved = tree_module.pose_of, tree_module.poses_of
    if path == "numba":
        tree_module.pose_of, tree_module.poses_of = chain.pose_numba, chain.poses_numba
    try:
        yield
    finally:
        tree_module.pose_of, tree_module.poses_of = saved


PATHS = st.sampled_from(["c", "numba"])


def test_the_c_call_path_is_built_where_a_compiler_is():
    if not (shutil.which("cc") or shutil.which("gcc")):
        pytest.skip("no C compiler: the package installs without _posecall")
    assert chain.pose_of is not chain.pose_numba and chain.poses_of is not chain.poses_numba
    assert tree_module.pose_of is chain.pose_of


@given(model=st.sampled_from(MODELS), seed=st.integers(0, 2**32 - 1), path=PATHS, data=st.data())
def test_one_q_equals_the_batch_bit_for_bit_and_mujoco(model, seed, path, data):
    with short_path(path):
        one_q_equals_the_batch_and_mujoco(tree_of(model), seed, data)


def one_q_equals_the_batch_and_mujoco(tree: mjkin.Tree, seed: int, data: st.DataObject) -> None:
    name, kind = data.draw(st.sampled_from(frames_of(tree)), label="frame")
    q = tree.random_q(seed)
    T = tree.pose(q, name, kind)
    np.testing.assert_array_equal(T, tree.pose(q[None], name, kind)[0])
    np.testing.assert_array_equal(T, tree.kinematics(q).pose(*tree.frame(name, kind)))
    unaligned = np.frombuffer(b"\0" + q.tobytes(), dtype=np.float64, offset=1)
    for other in (list(q), q.astype(">f8"), np.repeat(q, 2)[::2], q.copy(), unaligned, np.ma.array(q)):
        if isinstance(other, np.ndarray) and other.flags.c_contiguous:  # the checked path, or read-only: same bits
            other.setflags(write=False)
        np.testing.assert_array_equal(tree.pose(other, name, kind), T)
        np.testing.assert_array_equal(tree.fk(other), tree.fk(q))
    np.testing.assert_array_equal(tree.pose(q, name, None if kind == "site" else kind), T)
    B = tree.fk(q)
    np.testing.assert_array_equal(B, tree.fk(q[None])[0])
    d = mujoco_state(tree.model, q)
    i = tree.id(name, kind)  # type: ignore[arg-type]
    pos, mat = (d.site_xpos, d.site_xmat) if kind == "site" else (d.xpos, d.xmat)
    np.testing.assert_allclose(T[:3, 3], pos[i], atol=FK_TOL, rtol=0)
    np.testing.assert_allclose(T[:3, :3], mat[i].reshape(3, 3), atol=FK_TOL, rtol=0)
    np.testing.assert_allclose(B[:, :3, 3], d.xpos, atol=FK_TOL, rtol=0)
    np.testing.assert_allclose(B[:, :3, :3], d.xmat.reshape(-1, 3, 3), atol=FK_TOL, rtol=0)
    np.testing.assert_array_equal(B[:, 3], np.broadcast_to([0.0, 0.0, 0.0, 1.0], (tree.nbody, 4)))
    np.testing.assert_array_equal(T[3], [0.0, 0.0, 0.0, 1.0])


@given(model=st.sampled_from(MODELS), seed=st.integers(0, 2**32 - 1), path=PATHS, data=st.data())
def test_a_few_rows_are_the_batch_bit_for_bit_and_a_bad_row_its_error(model, seed, path, data):
    """Up to ``chain.SMALL_ROWS`` rows take the short path row by row (one more: the batched path)."""
    tree = tree_of(model)
    name, kind = data.draw(st.sampled_from(frames_of(tree)), label="frame")
    n = data.draw(st.integers(1, chain.SMALL_ROWS + 1), label="rows")
    Q = tree.random_q(np.random.default_rng(seed), n)
    with short_path(path):
        tree.pose(Q[0], name, kind)  # the frame's chain is made (else its first small batch makes it)
        batch = tree.kinematics(Q)
        np.testing.assert_array_equal(tree.fk(Q), batch.poses())
        np.testing.assert_array_equal(tree.pose(Q, name, kind), batch.pose(*tree.frame(name, kind)))
        # the short path answers those (not the batched one behind it)
        assert (chain.rows_of(tree_module.poses_of, tree.bodies_chain, Q) is not None) == (n <= chain.SMALL_ROWS)
        row, at = data.draw(st.integers(0, n - 1), label="bad row"), data.draw(st.integers(0, tree.nq - 1), label="at")
        Q[row, at] = np.nan
        expected = _error(lambda: tree.check_q(Q))
        assert _error(lambda: tree.fk(Q)) == expected and _error(lambda: tree.pose(Q, name, kind)) == expected


def _error(call):  # type: ignore[no-untyped-def]
    with pytest.raises(mjkin.MjkinError) as info:
        call()
    return type(info.value), str(info.value)


@given(model=st.sampled_from(["arm7", "primate", "ball_chain"]), seed=st.integers(0, 2**32 - 1), path=PATHS,
       data=st.data())
def test_bad_q_gets_the_checked_paths_error(model, seed, path, data):
    with short_path(path):
        bad_q_gets_the_checked_paths_error(tree_of(model), seed, data)


def bad_q_gets_the_checked_paths_error(tree: mjkin.Tree, seed: int, data: st.DataObject) -> None:
    name, kind = frames_of(tree)[-1]
    tree.pose(tree.qpos0.copy(), name, kind)  # the frame's chain is made: the short path is taken below
    q = tree.random_q(seed)
    how = data.draw(st.sampled_from(["nan", "inf", "zero quaternion", "short", "long", "2-d"]), label="bad")
    if how in ("nan", "inf"):
        q[data.draw(st.integers(0, tree.nq - 1), label="at")] = np.nan if how == "nan" else -np.inf
    elif how == "zero quaternion":
        if not len(tree.layout.quats):
            return
        q[tree.layout.quats[data.draw(st.integers(0, len(tree.layout.quats) - 1), label="which")]] = 0.0
    elif how in ("short", "long"):
        q = q[:-1] if how == "short" else np.append(q, 0.0)
    else:
        q = q[:, None]
    expected = _error(lambda: tree.check_q(q))
    assert "\n" not in expected[1]
    assert _error(lambda: tree.pose(q, name, kind)) == expected
    assert _error(lambda: tree.fk(q)) == expected
    assert _error(lambda: tree.pose(list(q), name, kind)) == expected


def test_the_c_and_numba_calls_agree_and_refuse_the_same_q():
    """The two short calls themselves: the same bits, None for what the checked path must take."""
    tree = tree_of("primate")
    q = tree.random_q(7)
    body, local = tree.frame_body("right_hand")
    frame = chain.chain_of(tree, chain.ancestors(tree, body), local)
    for ours, numbas, c in ((chain.pose_of, chain.pose_numba, frame), (chain.poses_of, chain.poses_numba,
                                                                         tree.bodies_chain)):
        T = numbas(c, q)
        assert T is not None and T.flags.c_contiguous and T.flags.writeable
        np.testing.assert_array_equal(ours(c, q), T)
        assert ours(c, q) is not ours(c, q)  # a new array each call
        zero = q.copy()
        zero[tree.layout.quats[0]] = 0.0
        for other in (list(q), q.astype(np.float32), q[:-1], np.append(q, 0.0), q[None], q[:, None], zero,
                      np.where(np.arange(tree.nq) == 3, np.nan, q), np.repeat(q, 2)[::2], q.astype(">f8")):
            assert ours(c, other) is None and numbas(c, other) is None


def test_the_c_call_refuses_what_is_no_chain():
    posecall = pytest.importorskip("mjkin.kinematics._posecall", reason="built only where a C compiler is")
    tree = tree_of("arm7")
    frame, q = tree.bodies_chain, tree.random_q(2)
    for bad in ((), (frame,), (frame, q, q), (list(frame), q), (frame.astype(np.float32), q), (frame[:3], q),
                (frame[::2], q)):
        for call in (posecall.pose, posecall.poses):
            with pytest.raises(TypeError, match="takes"):
                call(*bad)
    for bad, error in (((None, None), TypeError), ((0, 0), ValueError), ((1,), TypeError)):
        with pytest.raises(error):
            posecall.bind(*bad)
    np.testing.assert_array_equal(posecall.poses(frame, q), chain.poses_numba(frame, q))  # still bound as it was


def test_an_unknown_frame_is_named_before_and_after_the_frames_seen():
    tree = mjkin.load("arm7")
    for _ in range(2):
        with pytest.raises(mjkin.UnknownNameError, match="'hand'.*'ee'"):
            tree.pose(tree.qpos0.copy(), "hand")
        tree.pose(tree.qpos0.copy(), "ee")
    with pytest.raises(mjkin.InputError, match="kind"):
        tree.pose(tree.qpos0.copy(), "ee", "geom")  # type: ignore[arg-type]


def test_other_dtypes_take_the_checked_path_without_compiling():
    tree = tree_of("arm7")
    q = tree.random_q(3)
    T = tree.pose(q, "ee")
    versions = len(chain_pose.signatures), len(chain_poses.signatures)
    for other in (q.astype(np.float32), np.round(q).astype(np.int64), q.astype(np.float16)):
        np.testing.assert_array_equal(tree.pose(other, "ee"), tree.pose(other.astype(np.float64), "ee"))
        np.testing.assert_array_equal(tree.fk(other), tree.fk(other.astype(np.float64)))
    np.testing.assert_array_equal(tree.pose(q, "ee"), T)
    assert (len(chain_pose.signatures), len(chain_poses.signatures)) == versions == (1, 1)  # float64 (read-only too)


def test_the_cache_is_the_trees_own_and_not_pickled():
    tree = mjkin.load("arm7")
    assert tree.chains == {}
    q = tree.random_q(5)
    T = tree.pose(q, "ee")
    assert list(tree.chains) == [("ee", None)]
    back = pickle.loads(pickle.dumps(tree))
    assert back.chains == {} and tree.chains
    np.testing.assert_array_equal(back.pose(q, "ee"), T)


def test_more_bodies_than_the_stack_takes_go_the_batched_way():
    """MuJoCo nests at most ~1000 bodies deep: only ``fk`` of a wide tree has a chain over :data:`MAX_BODIES`."""
    xml = "<mujoco><worldbody>" + "".join(f"<body name='b{i}' pos='0.01 0 0'><joint axis='0 1 0'/><geom size='.01'/>"
                                          "</body>" for i in range(MAX_BODIES + 1)) + "</worldbody></mujoco>"
    tree = mjkin.load(xml)
    assert tree.nbody > MAX_BODIES
    q = np.linspace(-1.0, 1.0, tree.nq)
    T = tree.fk(q)
    np.testing.assert_array_equal(T, tree.fk(q[None])[0])
    d = mujoco_state(tree.model, q)
    np.testing.assert_allclose(T[:, :3, :3], d.xmat.reshape(-1, 3, 3), atol=FK_TOL, rtol=0)
    np.testing.assert_array_equal(tree.pose(q, f"b{MAX_BODIES}", "body"), T[-1])
