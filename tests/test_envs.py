"""The gymnasium reach environments: gymnasium's checks, seeding, vector envs, the scripted expert."""

from __future__ import annotations

import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import mjkin
import mjkin.envs
from mjkin.envs import ik_expert

IDS = ["mjkin/Reach-v0", "mjkin/PlanarReach-v0"]
ACTIONS = ["joint", "cartesian"]


@pytest.mark.parametrize("action_type", ACTIONS)
@pytest.mark.parametrize("env_id", IDS)
def test_check_env_without_warnings(env_id, action_type):
    env = gym.make(env_id, action_type=action_type, render_mode="rgb_array")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)
    frame = env.unwrapped.render()
    assert frame.shape == (360, 480, 3) and frame.std() > 5
    env.close()


@pytest.mark.parametrize("env_id", IDS)
def test_same_seed_same_rollout(env_id):
    def rollout(seed):
        env = gym.make(env_id)
        obs, _ = env.reset(seed=seed)
        env.action_space.seed(seed)
        out = [obs]
        for _ in range(10):
            out.append(env.step(env.action_space.sample())[0])
        return np.array(out)

    np.testing.assert_array_equal(rollout(3), rollout(3))
    assert not np.array_equal(rollout(3), rollout(4))


@pytest.mark.parametrize("vectorization_mode", ["sync", "async"])
def test_vector_envs_step(vectorization_mode):
    envs = gym.make_vec("mjkin/Reach-v0", num_envs=2, vectorization_mode=vectorization_mode)
    obs, _ = envs.reset(seed=0)
    assert obs.shape == (2, 7 + 9)
    for _ in range(3):
        obs, reward, term, trunc, info = envs.step(envs.action_space.sample())
    assert obs.shape == (2, 16) and reward.shape == (2,) and np.isfinite(obs).all()
    envs.close()


@pytest.mark.parametrize("env_id", IDS)
def test_expert_solves_almost_every_episode(env_id):
    env = gym.make(env_id)
    wins = 0
    for episode in range(200):
        env.reset(seed=episode)
        for _ in range(100):
            _, _, term, trunc, info = env.step(ik_expert(env.unwrapped))
            if term or trunc:
                break
        wins += info["is_success"]
    assert wins >= 198, wins


def test_bad_actions_raise_and_change_nothing():
    env = gym.make("mjkin/Reach-v0").unwrapped
    env.reset(seed=0)
    before = env.q.copy()
    for bad in (np.full(7, np.nan), np.zeros(3), np.zeros((7, 1))):
        with pytest.raises(mjkin.InputError, match="action"):
            env.step(bad)
    np.testing.assert_array_equal(env.q, before)


def test_observation_layout_reward_and_info():
    env = gym.make("mjkin/Reach-v0", sparse=True).unwrapped
    obs, info = env.reset(seed=1)
    ee = env.tree.pose(obs[:7], "ee")[:3, 3]
    np.testing.assert_allclose(obs[7:10], ee, atol=1e-12)
    np.testing.assert_allclose(obs[13:16], obs[10:13] - obs[7:10], atol=1e-12)
    _, reward, _, _, info = env.step(np.zeros(7, np.float32))
    assert reward == -1.0 and info["distance"] > env.success_tol and not info["is_success"]
    assert {"distance", "is_success", "contacts", "in_collision"} <= set(info)


def test_obstacles_and_region():
    region = ([0.2, -0.3, 0.3], [0.6, 0.3, 0.9])
    env = gym.make("mjkin/Reach-v0", target_region=region, obstacles=[([0.0, 0.0, 0.7], 0.15)],
                   collision_penalty=5.0).unwrapped
    for seed in range(10):
        env.reset(seed=seed)
        assert np.all((env.target >= region[0]) & (env.target <= region[1]))
        assert np.linalg.norm(env.target - [0.0, 0.0, 0.7]) > 0.15


def test_pickle_round_trip():
    env = gym.make("mjkin/PlanarReach-v0").unwrapped
    env.reset(seed=0)
    copy = pickle.loads(pickle.dumps(env))
    np.testing.assert_array_equal(copy.q, env.q)


def test_bad_options():
    with pytest.raises(mjkin.InputError, match="action_type"):
        gym.make("mjkin/Reach-v0", action_type="torque")
    with pytest.raises(mjkin.UnknownNameError, match="hand"):
        gym.make("mjkin/Reach-v0", site="hand")
