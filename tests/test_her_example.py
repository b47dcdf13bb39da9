"""Smoke test of examples/train_her.py: stable-baselines3's HerReplayBuffer takes the env unchanged and SAC learns.

Needs the ``rl`` extra (stable-baselines3, torch); skipped with the reason when it is missing (CI).
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3", reason="stable-baselines3 not installed (extra [rl])")
torch = pytest.importorskip("torch", reason="torch not installed (extra [rl])")

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "train_her.py"


@pytest.fixture(scope="module")
def her():
    spec = importlib.util.spec_from_file_location("train_her", EXAMPLE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["train_her"] = module
    spec.loader.exec_module(module)
    return module


def test_sac_her_learns_200_steps_on_the_unchanged_env(her):
    from stable_baselines3 import SAC, HerReplayBuffer

    torch.set_num_threads(1)
    env = her.make_env()
    model = SAC("MultiInputPolicy", env, replay_buffer_class=HerReplayBuffer, replay_buffer_kwargs=her.HER_KWARGS,
                seed=0, device="cpu", **{**her.SAC_KWARGS, "learning_starts": 100, "batch_size": 32})
    before = [p.detach().clone() for p in model.actor.parameters()]
    model.learn(total_timesteps=200)
    assert model.num_timesteps == 200
    assert any(not torch.equal(b, p) for b, p in zip(before, model.actor.parameters(), strict=True))  # it trained
    buffer = model.replay_buffer
    assert isinstance(buffer, HerReplayBuffer) and buffer.size() > 0
    # relabelled samples carry the env's own reward for their new goal
    batch = buffer.sample(64)
    ach, des = batch.next_observations["achieved_goal"].numpy(), batch.observations["desired_goal"].numpy()
    want = env.unwrapped.compute_reward(ach, des, [{}] * len(ach))
    np.testing.assert_array_equal(batch.rewards.numpy().ravel(), want)
    assert 0.0 <= her.success_rate(model, her.make_env(), 2) <= 1.0
