"""Laws of rotations and rigid transforms, checked on random samples (hypothesis)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from mjkin import spatial as sp

finite = st.floats(-10, 10, allow_nan=False, allow_infinity=False)
vec3 = arrays(np.float64, 3, elements=finite)
quat_raw = arrays(np.float64, 4, elements=st.floats(-1, 1, allow_nan=False)).filter(lambda q: np.linalg.norm(q) > 0.1)
unit_quat = quat_raw.map(sp.quat_normalize)
rotvec = arrays(np.float64, 3, elements=st.floats(-3, 3, allow_nan=False)).filter(lambda r: np.linalg.norm(r) < 3.1)
SEQS = ["xyz", "xzy", "yxz", "yzx", "zxy", "zyx", "xyx", "xzx", "yxy", "yzy", "zxz", "zyz"]
SEQS += [s.upper() for s in SEQS]


def same_rotation(q1, q2, tol=1e-9):
    return sp.quat_distance(q1, q2) < tol


@given(unit_quat)
def test_quat_to_mat_is_a_rotation(q):
    R = sp.quat_to_mat(q)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)


@given(unit_quat, unit_quat)
def test_product_is_composition(a, b):
    np.testing.assert_allclose(sp.quat_to_mat(sp.quat_mul(a, b)), sp.quat_to_mat(a) @ sp.quat_to_mat(b), atol=1e-12)


@given(unit_quat, unit_quat, unit_quat)
def test_product_is_associative_with_identity_and_inverse(a, b, c):
    np.testing.assert_allclose(sp.quat_mul(sp.quat_mul(a, b), c), sp.quat_mul(a, sp.quat_mul(b, c)), atol=1e-12)
    np.testing.assert_allclose(sp.quat_mul(a, [1, 0, 0, 0]), a, atol=0)
    assert same_rotation(sp.quat_mul(a, sp.quat_conj(a)), np.array([1.0, 0, 0, 0]))


@given(unit_quat, vec3)
def test_rotate_equals_matrix(q, v):
    np.testing.assert_allclose(sp.quat_rotate(q, v), sp.quat_to_mat(q) @ v, atol=1e-11)


@given(unit_quat)
def test_mat_to_quat_round_trip(q):
    assert same_rotation(sp.mat_to_quat(sp.quat_to_mat(q)), q, 1e-7)
    np.testing.assert_allclose(sp.quat_to_mat(sp.mat_to_quat(sp.quat_to_mat(q))), sp.quat_to_mat(q), atol=1e-12)


def test_mat_to_quat_near_half_turn():
    for axis in np.eye(3):
        q = sp.quat_from_axis_angle(axis, np.pi - 1e-12)
        np.testing.assert_allclose(sp.quat_to_mat(sp.mat_to_quat(sp.quat_to_mat(q))), sp.quat_to_mat(q), atol=1e-12)


@given(rotvec)
def test_exp_log_round_trip(r):
    np.testing.assert_allclose(sp.quat_to_rotvec(sp.rotvec_to_quat(r)), r, atol=1e-10)
    np.testing.assert_allclose(sp.mat_to_rotvec(sp.rotvec_to_mat(r)), r, atol=1e-9)


@given(vec3.filter(lambda a: np.linalg.norm(a) > 1e-3), st.floats(-3, 3))
def test_axis_angle_forms_agree(axis, angle):
    axis = axis / np.linalg.norm(axis)
    np.testing.assert_allclose(sp.axis_angle_to_mat(axis, angle), sp.quat_to_mat(sp.quat_from_axis_angle(axis, angle)),
                               atol=1e-12)
    u, a = sp.quat_to_axis_angle(sp.quat_from_axis_angle(axis, angle))
    assert same_rotation(sp.quat_from_axis_angle(u, a), sp.quat_from_axis_angle(axis, angle))


@pytest.mark.parametrize("seq", SEQS)
@settings(max_examples=40)
@given(q=unit_quat)
def test_euler_matches_scipy_and_round_trips(seq, q):
    R = sp.quat_to_mat(q)
    angles = sp.mat_to_euler(R, seq)
    np.testing.assert_allclose(sp.euler_to_mat(angles, seq), R, atol=1e-9)
    np.testing.assert_allclose(Rotation.from_euler(seq, angles).as_matrix(), R, atol=1e-9)


@pytest.mark.parametrize("seq", ["xyz", "ZYX", "zxz", "YXY"])
def test_euler_gimbal_lock(seq):
    middle = 0.0 if seq[0].lower() == seq[2].lower() else np.pi / 2
    R = sp.euler_to_mat([0.3, middle, -0.7], seq)
    np.testing.assert_allclose(sp.euler_to_mat(sp.mat_to_euler(R, seq), seq), R, atol=1e-12)


@pytest.mark.parametrize("seq", ["xy", "xxz", "xYz", "abc"])
def test_euler_rejects_bad_sequences(seq):
    with pytest.raises(ValueError, match="Euler sequence"):
        sp.euler_to_mat([0, 0, 0], seq)


@given(rotvec, vec3)
def test_se3_exp_log_and_inverse(w, v):
    xi = np.concatenate([v, w])
    T = sp.se3_exp(xi)
    np.testing.assert_allclose(sp.se3_log(T), xi, atol=1e-8)
    np.testing.assert_allclose(T @ sp.transform_inverse(T), np.eye(4), atol=1e-10)
    np.testing.assert_allclose(sp.se3_exp(-xi), sp.transform_inverse(T), atol=1e-10)


@given(unit_quat, unit_quat, st.floats(0, 1))
def test_slerp(a, b, t):
    s = sp.slerp(a, b, t)
    assert np.linalg.norm(s) == pytest.approx(1.0, abs=1e-12)
    assert same_rotation(sp.slerp(a, b, 0.0), a, 1e-7) and same_rotation(sp.slerp(a, b, 1.0), b, 1e-7)
    total = sp.quat_distance(a, b)  # constant angular speed along the shorter arc
    assert sp.quat_distance(a, s) == pytest.approx(t * total, abs=1e-6)


@given(arrays(np.float64, (3, 3), elements=st.floats(-1e-3, 1e-3)), unit_quat)
def test_orthonormalize_recovers_a_drifted_rotation(noise, q):
    R = sp.quat_to_mat(q)
    Rn = sp.orthonormalize(R + noise)
    np.testing.assert_allclose(Rn @ Rn.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(Rn) == pytest.approx(1.0)
    assert np.abs(Rn - R).max() < 1e-2


def test_batched_shapes():
    rng = np.random.default_rng(0)
    q = sp.quat_normalize(rng.normal(size=(2, 5, 4)))
    assert sp.quat_to_mat(q).shape == (2, 5, 3, 3)
    assert sp.mat_to_euler(sp.quat_to_mat(q), "XYZ").shape == (2, 5, 3)
    T = sp.make_transform(sp.quat_to_mat(q), rng.normal(size=(2, 5, 3)))
    assert sp.se3_log(T).shape == (2, 5, 6)
    np.testing.assert_allclose(sp.transform_apply(T, np.zeros(3)), T[..., :3, 3])
