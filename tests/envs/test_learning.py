"""Proof the reach task can be learned: a test-speed learner goes from near 0 to >= 80 % success on held-out seeds."""

from __future__ import annotations

import importlib.util

import gymnasium as gym
import numpy as np

import mjkin.envs  # noqa: F401
from conftest import ROOT

PATH = ROOT / "examples" / "clone_reach.py"
spec = importlib.util.spec_from_file_location("clone_reach", PATH)
clone_reach = importlib.util.module_from_spec(spec)
spec.loader.exec_module(clone_reach)


def test_behaviour_cloning_learns_planar_reach_on_held_out_seeds():
    env = gym.make("mjkin/PlanarReach-v0")
    held_out = range(1_000_000, 1_000_100)  # never seen while learning
    untrained = clone_reach.success_rate(env, lambda obs: np.zeros(3), held_out)
    student = clone_reach.clone(env, rounds=3, episodes=30)
    learned = clone_reach.success_rate(env, student, held_out)
    assert untrained <= 0.05 and learned >= 0.8, (untrained, learned)
    # the student acts from the observation alone: its actions differ from the teacher's, yet it succeeds
    obs, _ = env.reset(seed=5)
    teacher = clone_reach.teacher(env.unwrapped)
    assert not np.array_equal(student(obs), teacher(obs))
    np.testing.assert_allclose(student(obs), teacher(obs), atol=0.05)


def test_a_student_fitted_on_too_little_data_does_not_pass():
    """The bar can fail: one short round of 2 episodes with 4 features is not enough."""
    env = gym.make("mjkin/PlanarReach-v0")
    weak = clone_reach.clone(env, rounds=1, episodes=2, features=4)
    assert clone_reach.success_rate(env, weak, range(1_000_000, 1_000_050)) < 0.8
