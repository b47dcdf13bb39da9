"""Loading models, names, configuration-space arithmetic, and bad input."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import mjkin
from conftest import GYM_ASSETS, tree_of
from mjkin.kinematics.qspace import BALL, HINGE, SLIDE
from mjkin.kinematics.tree import ReversedRangeWarning

TWO_LINK = """<mujoco><worldbody><body name="a"><joint name="j1" axis="0 0 1"/><geom size=".1"/>
<body name="b" pos="1 0 0"><joint name="j2" axis="0 0 1" range="-1 1"/><geom size=".1"/>
<site name="tip" pos="0.5 0 0"/></body></body></worldbody></mujoco>"""

URDF = """<robot name="r"><link name="base"/><link name="l1">
<visual><geometry><box size="0.1 0.1 0.1"/></geometry></visual>
<inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
<joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.5"/><axis xyz="0 1 0"/>
<limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>"""


def test_load_every_kind_of_source(tmp_path):
    path = tmp_path / "two.xml"
    path.write_text(TWO_LINK)
    urdf = tmp_path / "r.urdf"
    urdf.write_text(URDF)
    model = mujoco.MjModel.from_xml_string(TWO_LINK)
    trees = [mjkin.load(path), mjkin.load(str(path)), mjkin.load(TWO_LINK), mjkin.load(model),
             mjkin.load(mujoco.MjSpec.from_string(TWO_LINK))]
    for t in trees:
        assert (t.nq, t.nv) == (2, 2)
        np.testing.assert_allclose(t.pose([0.0, np.pi / 2], "tip")[:3, 3], [1.0, 0.5, 0.0], atol=1e-15)
    assert mjkin.load(urdf).names("joint") == ["j1"]
    assert mjkin.load("arm7").nq == 7


def test_loading_a_model_that_warns_leaves_no_mujoco_log(tmp_path, monkeypatch, mujoco_log):
    """MuJoCo appends compiler warnings to MUJOCO_LOG.TXT in the working folder; the tests send them elsewhere."""
    monkeypatch.chdir(tmp_path)
    mjkin.load(GYM_ASSETS / "half_cheetah.xml")  # deprecated 'settotalmass': a compiler warning
    assert list(tmp_path.iterdir()) == []
    if hasattr(mujoco, "MjLogConfig"):
        assert "settotalmass" in mujoco_log.read_text()


def test_names_and_frames():
    t = mjkin.load(TWO_LINK)
    assert t.names("body") == ["world", "a", "b"]
    assert t.names("joint") == ["j1", "j2"] and t.names("site") == ["tip"]
    assert t.frame("tip") == ("site", 0) and t.frame("b") == ("body", 2)
    np.testing.assert_array_equal(t.pose(t.qpos0, "b", "body"), t.fk(t.qpos0)[2])


@pytest.mark.parametrize("src, error, text", [
    ("/no/such/model.xml", mjkin.MjkinIOError, "model file not found"),
    ("<mujoco><worldbody><body>", mjkin.ModelError, "cannot compile"),
    ("<mujoco><worldbody><body><joint type='bogus'/></body></worldbody></mujoco>", mjkin.ModelError, "bogus"),
    (42, mjkin.InputError, "not int"),
])
def test_load_errors_are_one_line(src, error, text):
    with pytest.raises(error, match=text) as info:
        mjkin.load(src)
    assert "\n" not in str(info.value)
    assert isinstance(info.value, mjkin.MjkinError)


def test_unknown_names_list_the_known_ones():
    t = mjkin.load(TWO_LINK)
    with pytest.raises(mjkin.UnknownNameError, match="'tip'.*'b'") as info:
        t.pose(t.qpos0, "hand")
    assert "hand" in str(info.value) and "\n" not in str(info.value)
    with pytest.raises(mjkin.UnknownNameError, match="'tip'"):
        t.jacobian(t.qpos0, "tpi", "site")
    with pytest.raises(mjkin.InputError, match="kind"):
        t.pose(t.qpos0, "tip", "geom")  # type: ignore[arg-type]


not_a_name = st.one_of(st.none(), st.integers(), st.floats(), st.binary(), st.lists(st.text(max_size=3), max_size=2),
                       st.dictionaries(st.text(max_size=2), st.integers(), max_size=1), st.tuples(st.text(max_size=2)))


@given(not_a_name, st.sampled_from([None, "site", "body"]), st.booleans())
def test_a_frame_name_that_is_not_a_string_is_an_unknown_name(name, kind, batch):
    """Found by reading: an unhashable name (a list) got Python's raw TypeError from the frame cache's lookup."""
    t = mjkin.load(TWO_LINK)
    q = t.qpos0[None] if batch else t.qpos0
    listed = {"site": "'tip'", "body": "'b'", None: "'tip'.*'b'"}[kind]  # the names that exist
    for call in (lambda: t.pose(q, name, kind), lambda: t.jacobian(q, name, kind)):
        with pytest.raises(mjkin.UnknownNameError, match=listed) as info:
            call()
        assert "\n" not in str(info.value)
    with pytest.raises(mjkin.InputError, match="kind"):
        t.pose(q, "tip", [kind])  # type: ignore[arg-type]
    with pytest.raises(mjkin.InputError, match="kind"):
        t.id("tip", [kind])  # type: ignore[arg-type]


@pytest.mark.parametrize("q, text", [
    (np.zeros(3), r"shape \(3,\).*\(\.\.\., 2\)"),
    (np.zeros((4, 1)), "shape"),
    (np.array([0.0, np.nan]), "NaN"),
    (np.array([np.inf, 0.0]), "NaN or inf"),
    ("zero", "array of numbers"),
    (3.0, "shape"),
])
def test_bad_q(q, text):
    t = mjkin.load(TWO_LINK)
    with pytest.raises(mjkin.InputError, match=text):
        t.fk(q)


def test_zero_quaternion_is_rejected():
    t = tree_of("ball_chain")
    q = t.qpos0.copy()
    q[4:8] = 0.0
    with pytest.raises(mjkin.InputError, match="zero quaternion"):
        t.pose(q, "tip")


def test_bad_offset():
    t = tree_of("arm7")
    with pytest.raises(mjkin.InputError, match="offset"):
        t.jacobian(t.qpos0, "ee", offset=[1.0, 2.0])


@pytest.mark.parametrize("name", ["arm7", "primate", "ball_chain", "planar_prismatic"])
def test_random_q_respects_limits_and_is_seeded(name):
    t = tree_of(name)
    Q = t.random_q(7, 500)
    assert Q.shape == (500, t.nq)
    np.testing.assert_array_equal(Q, t.random_q(np.random.default_rng(7), 500))
    np.testing.assert_allclose(t.clip(Q), Q, atol=1e-12)  # already inside
    for j in range(t.njnt):
        a = t.jnt_qadr[j]
        if t.jnt_limited[j] and t.jnt_type[j] in (HINGE, SLIDE):
            lo, hi = t.jnt_range[j]
            assert np.all((Q[:, a] >= lo) & (Q[:, a] <= hi))
        if t.jnt_type[j] == BALL:
            angle = mjkin.spatial.quat_distance(Q[:, a:a + 4], [1, 0, 0, 0])
            assert np.all(angle <= t.jnt_range[j, 1] + 1e-12) if t.jnt_limited[j] else np.all(angle <= np.pi)


def test_random_q_takes_a_shape_and_refuses_bad_counts():
    t = tree_of("primate")
    Q = t.random_q(3, (2, 5))
    assert Q.shape == (2, 5, t.nq)
    np.testing.assert_array_equal(Q.reshape(10, t.nq), t.random_q(3, 10))  # the same draws, shaped
    assert t.random_q(3, 0).shape == (0, t.nq) and t.random_q(3).shape == (t.nq,)
    for bad in (-1, 2.5, True, (2, -1), "3"):
        with pytest.raises(mjkin.InputError, match="n must be a count >= 0"):
            t.random_q(3, bad)


@pytest.mark.parametrize("name", ["primate", "ball_chain", "arm7"])
def test_integrate_and_difference_match_mujoco(name, rng):
    t = tree_of(name)
    m = t.model
    for q in t.random_q(rng, 20):
        v = rng.normal(size=t.nv)
        expected = q.copy()
        mujoco.mj_integratePos(m, expected, v, 1.0)
        ours = t.integrate(q, v)
        np.testing.assert_allclose(t.fk(ours), t.fk(expected), atol=1e-10)
        diff = np.zeros(t.nv)
        mujoco.mj_differentiatePos(m, diff, 1.0, q, ours)
        np.testing.assert_allclose(t.difference(ours, q), diff, atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(arrays(np.float64, 37, elements=st.floats(-5, 5, allow_nan=False)))
@example(np.where(np.arange(37) == 13, -0.5, 0.0))  # found in a README test run: w -0.5 + 0.5, a zero quaternion
def test_clip_lands_inside_limits(q):
    t = tree_of("primate")
    q = q.copy()
    w = t.layout.quats[:, 0]
    q[w] = np.abs(q[w]) + 0.5  # keep quaternions away from zero (the input check refuses those, as it should)
    c = t.clip(q)
    np.testing.assert_allclose(t.clip(c), c, atol=1e-12)  # idempotent
    lay = t.layout
    assert np.all((c[lay.scalar_q] >= lay.scalar_lo) & (c[lay.scalar_q] <= lay.scalar_hi))
    np.testing.assert_allclose(np.linalg.norm(c[lay.quats], axis=-1), 1.0, atol=1e-12)
    angles = mjkin.spatial.quat_distance(c[lay.ball_q], [1, 0, 0, 0])
    assert np.all(angles <= lay.ball_max + 1e-9)


def test_tree_arrays_are_read_only():
    t = tree_of("arm7")
    with pytest.raises(ValueError):
        t.qpos0[0] = 1.0
    with pytest.raises(ValueError):
        t.jnt_range[0, 0] = 1.0


def test_public_names_exist():
    for name in mjkin.__all__:
        assert hasattr(mjkin, name), name


# ------------------------------------------------------------------ a model without joints
ZERO_DOF = """<mujoco model="zero"><worldbody><body name="b" pos="0 0 1" quat="0.7071068 0 0 0.7071068">
<geom size=".1"/><site name="s" pos="0.1 0 0"/></body></worldbody></mujoco>"""


def test_a_model_without_joints_has_kinematics():
    """Zero DoF is a legal model (a fixed fixture): FK, poses, Jacobians (6, 0) and random q (n, 0) work."""
    t = mjkin.load(ZERO_DOF)
    assert (t.nq, t.nv, t.njnt) == (0, 0, 0)
    d = mujoco.MjData(t.model)
    mujoco.mj_kinematics(t.model, d)
    np.testing.assert_allclose(t.pose(t.qpos0, "s")[:3, 3], d.site_xpos[0], atol=1e-12)  # was an IndexError
    np.testing.assert_allclose(t.fk(t.qpos0)[:, :3, 3], d.xpos, atol=1e-12)
    assert t.jacobian(t.qpos0, "s").shape == (6, 0)
    Q = t.random_q(3, 4)
    assert Q.shape == (4, 0) and t.random_q(3).shape == (0,)
    assert t.fk(Q).shape == (4, 2, 4, 4) and t.pose(Q.reshape(2, 2, 0), "s").shape == (2, 2, 4, 4)
    assert t.jacobian(Q, "s").shape == (4, 6, 0) and t.clip(Q).shape == (4, 0)


def test_the_cli_on_a_model_without_joints(tmp_path, capsys):
    from mjkin.apps.cli import main

    path = tmp_path / "zero_dof.xml"
    path.write_text(ZERO_DOF)
    assert main(["fk", str(path), "--q", "random"]) == 0  # was a ValueError traceback
    assert "site s" in capsys.readouterr().out
    assert main(["ik", str(path), "--frame", "s", "--pos", "0.1,0,1"]) == 2
    assert capsys.readouterr().err == "mjkin: error: no joint moves 's': the model has no joints\n"


# ------------------------------------------------------------------ NaN and inf in a model
NUMBERS = dict(axis="0 0 1", ref="0", range="-1 1", quat="1 0 0 0", pos="1 0 0", site="0.5 0 0", geom="0 0 0")
FINITE_MODEL = """<mujoco><compiler angle="radian"/><worldbody>
<body name="link1" quat="{quat}"><joint name="j1" axis="{axis}" ref="{ref}" range="{range}"/><geom size=".1"/>
<body name="link2" pos="{pos}"><joint name="j2" axis="0 0 1"/><geom name="g2" size=".1" pos="{geom}"/>
<site name="tip" pos="{site}"/></body></body></worldbody></mujoco>"""


@pytest.mark.parametrize("field, value, text", [
    ("axis", "nan 0 1", "joint 'j1' has a non-finite axis"),
    ("axis", "inf 0 1", "joint 'j1' has a non-finite axis"),
    ("pos", "nan 0 0", "body 'link2' has a non-finite pos"),
    ("pos", "0 -inf 0", "body 'link2' has a non-finite pos"),
    ("quat", "nan 1 0 0", "body 'link1' has a non-finite quat"),
    ("ref", "nan", r"joint 'j1' has a non-finite reference position \(qpos0\)"),
    ("range", "-inf 1", "joint 'j1' has a non-finite range"),
    ("site", "nan 0 0", "site 'tip' has a non-finite pos"),
    ("geom", "0 inf 0", "geom 'g2' has a non-finite pos"),
])
def test_non_finite_numbers_in_a_model_are_refused_at_load(field, value, text):
    """MuJoCo compiles NaN and inf with a warning only; FK then gave NaN and solve numpy's LinAlgError."""
    xml = FINITE_MODEL.format(**{**NUMBERS, field: value})
    for src in (xml, mujoco.MjModel.from_xml_string(xml)):
        with pytest.raises(mjkin.ModelError, match=text) as info:
            mjkin.load(src)
        assert "\n" not in str(info.value)
    mjkin.load(FINITE_MODEL.format(**NUMBERS))  # the same model with finite numbers loads


def test_periodic_difference_takes_unlimited_hinges_the_short_way():
    """solve returns unlimited hinges in (-π, π]: a step from -3.1 to 3.1 rad is -0.08 rad, not 6.2."""
    t = tree_of("planar_3link")  # unlimited hinges
    q1, q0 = np.array([3.1, -3.1, 1.0]), np.array([-3.1, 3.1, 0.5])
    short = 6.2 - 2 * np.pi  # from -3.1 on past -π to 3.1
    np.testing.assert_allclose(t.difference(q1, q0, periodic=True), [short, -short, 0.5], atol=1e-12)
    np.testing.assert_allclose(t.difference(q1, q0), [6.2, -6.2, 0.5], atol=1e-12)  # as mj_differentiatePos
    arm = tree_of("arm7")  # limited hinges: their values are never wrapped, their differences never either
    a, b = arm.random_q(0, 2)
    np.testing.assert_array_equal(arm.difference(a, b, periodic=True), arm.difference(a, b))


def test_a_reversed_joint_range_warns_once_naming_the_joint():
    """``range="1 -1"`` compiles unlimited in MuJoCo, silently: ik then returned q = 1.57 for that joint."""
    xml = ('<mujoco><worldbody><body><joint name="elbow" type="hinge" range="1 -1"/><geom size="0.1"/>'
           '<body pos="0 0 1"><joint name="ok" type="hinge" range="-1 1"/><geom size="0.1"/></body></body>'
           '</worldbody></mujoco>')
    with pytest.warns(ReversedRangeWarning) as seen:
        tree = mjkin.load(xml)
    assert len(seen) == 1 and "'elbow' (1 -1)" in str(seen[0].message) and "'ok'" not in str(seen[0].message)
    assert not tree.jnt_limited[0]  # as MuJoCo compiled it: the warning says so, mjkin does not guess


@pytest.mark.filterwarnings("error::mjkin.kinematics.tree.ReversedRangeWarning")
def test_no_bundled_model_has_a_reversed_range():
    for name in mjkin.bundled_models():
        mjkin.load(name)


def test_read_only_or_broadcast_arrays_compile_no_second_version_of_a_kernel():
    """A read-only ``q``, a broadcast one, an offset: the same compiled version of each kernel (~1 s of compile
    each otherwise: the cold suite compiled the one-frame Jacobian four times)."""
    from mjkin.kinematics.fk import fk_kernel
    from mjkin.kinematics.jacobian import frame_jacobian_one
    from mjkin.kinematics.qspace import difference_kernel, integrate_kernel

    tree = tree_of("primate")  # hinges, balls and a free joint
    q = tree.random_q(np.random.default_rng(0), 3)
    ro = q.copy()
    ro.setflags(write=False)
    v = np.zeros(tree.nv)
    for a in (q, ro):
        tree.jacobian(a[0], "head"), tree.jacobian(a[0], "head", offset=[0.0, 0.1, 0.0]), tree.fk(a)
        tree.kinematics(a[:2]), tree.difference(a, a[0]), tree.difference(a[0], a), tree.difference(a, a)
        tree.integrate(a, v), tree.integrate(a[0], np.zeros((3, tree.nv)))
    for kernel in (frame_jacobian_one, fk_kernel, difference_kernel, integrate_kernel):
        assert len(kernel.signatures) == 1, (kernel.__name__, kernel.signatures)
    np.testing.assert_array_equal(tree.jacobian(ro[1], "head"), tree.jacobian(q[1], "head"))


@pytest.mark.parametrize("model", ["arm7", "primate", "ball_chain", "planar_prismatic"])
@pytest.mark.parametrize("n_threads", [1, 2])
def test_a_batch_fk_is_the_frames_kernel_written_into_4x4s_in_chunks_and_threads(model, n_threads):
    """tree.fk of a batch writes the poses in blocks of FK_ROWS over the threads: the frames kernel's numbers."""
    from mjkin.kinematics.fk import FK_ROWS
    from mjkin.kinematics.frames import POSES_CHUNK, forward
    from mjkin.runtime.parallel import threads_set

    tree = tree_of(model)
    Q = tree.random_q(np.random.default_rng(5), 2 * POSES_CHUNK + FK_ROWS + 3)  # several chunks, a short block
    with threads_set(n_threads):
        T = tree.fk(Q)
    np.testing.assert_array_equal(T, forward(tree, Q).poses())
    np.testing.assert_array_equal(tree.fk(Q.reshape(3, -1, tree.nq)), T.reshape(3, -1, tree.nbody, 4, 4))
    assert T.shape == (len(Q), tree.nbody, 4, 4) and T.flags.c_contiguous
