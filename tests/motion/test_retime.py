"""Time-optimal retiming: no limit exceeded between samples, one nearly reached (optimal), the frames kept."""

from __future__ import annotations

import numpy as np
import pytest

import mjkin
from mjkin.errors import InputError
from mjkin.kinematics.tree import fingerprint
from mjkin.motion import Trajectory, interpolate, retime
from mjkin.motion.retime import path_coordinates


def divided(x: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean velocities between samples and the second divided differences (x2: mean accelerations)."""
    v = np.diff(x, axis=0) / np.diff(t)[:, None]
    a = 2 * np.diff(v, axis=0) / (t[2:] - t[:-2])[:, None]
    return v, a


@pytest.fixture(scope="module")
def primate_traj() -> tuple[mjkin.Tree, Trajectory]:
    tree = mjkin.load("primate")
    keys = tree.random_q(np.random.default_rng(3), 5)
    keys[:, :7] = tree.qpos0[:7]  # the free root stays: ball joints and hinges move
    t = np.linspace(0, 4, 41)
    q = interpolate(tree, np.arange(5.0), keys, t, smooth=True)
    return tree, Trajectory(times=t, q=q, fingerprint=fingerprint(tree), model=tree.name, source="primate")


@pytest.mark.parametrize(("vmax", "amax"), [(2.0, 5.0), (0.5, 20.0), (6.0, 1.0)])
def test_limits_hold_between_samples_and_are_reached(primate_traj: tuple, vmax: float, amax: float) -> None:
    tree, traj = primate_traj
    out = retime(traj, vmax, amax)
    np.testing.assert_array_equal(out.q, traj.q)  # same frames, new times
    assert np.all(np.diff(out.times) > 0) and out.times[0] == traj.times[0]
    v, a = divided(path_coordinates(tree, out.q), out.times)
    assert np.abs(v).max() <= vmax * (1 + 1e-9) and np.abs(a).max() <= amax * (1 + 1e-9)
    # time-optimal: one limit or the other is nearly reached somewhere (samples only see means)
    assert max(np.abs(v).max() / vmax, np.abs(a).max() / amax) > 0.8
    assert out.meta["retime"]["duration"] == pytest.approx(out.times[-1] - out.times[0])


def test_per_dof_limits_and_a_hinge_chain() -> None:
    tree = mjkin.load("planar_3link")
    t = np.linspace(0, 2, 21)
    q = np.stack([np.sin(t), 0.5 * t, np.zeros_like(t)], 1)[:, : tree.nq]
    traj = Trajectory(times=t, q=q, fingerprint=fingerprint(tree), model=tree.name)
    vmax, amax = np.array([1.0, 0.2, 1.0])[: tree.nv], 3.0
    out = retime(traj, vmax, amax, tree=tree)
    v, a = divided(out.q, out.times)
    assert np.all(np.abs(v) <= vmax * (1 + 1e-9)) and np.abs(a).max() <= amax * (1 + 1e-9)
    assert out.times[-1] >= 1.0 / 0.2  # joint 2 must travel 1 rad at 0.2 rad/s at most


def test_bad_input(primate_traj: tuple) -> None:
    tree, traj = primate_traj
    with pytest.raises(InputError, match="max_velocity must be a positive number"):
        retime(traj, 0.0, 1.0)
    with pytest.raises(InputError, match="max_acceleration"):
        retime(traj, 1.0, [1.0, 2.0])
    still = Trajectory(times=traj.times[:3], q=traj.q[:1].repeat(3, 0), fingerprint=traj.fingerprint,
                       model=tree.name, source="primate")
    with pytest.raises(InputError, match="does not move"):
        retime(still, 1.0, 1.0)
    with pytest.raises(InputError, match="not on"):
        retime(traj, 1.0, 1.0, tree=mjkin.load("arm7"))
