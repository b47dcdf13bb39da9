"""Smoke test of examples/train_her.py: stable-baselines3's HerReplayBuffer takes the env unchanged and SAC learns.

Needs the ``rl`` extra (stable-baselines3, torch); skipped with the reason when it is missing (CI).
It runs in a process of its own, as the example does: the CUDA build of torch brings triton, whose
LLVM crashes the process (a segfault on import) once numba's LLVM and MuJoCo's EGL are loaded, as
they are after the rest of the suite.
"""

from __future__ import annotations

import subprocess
import sys
from importlib.util import find_spec

import pytest

from conftest import ROOT

pytestmark = pytest.mark.skipif(find_spec("stable_baselines3") is None or find_spec("torch") is None,
                                reason="stable-baselines3 or torch not installed (extra [rl])")

EXAMPLE = ROOT / "examples" / "train_her.py"

CHECK = """
import importlib.util, sys
import numpy as np, torch
from stable_baselines3 import SAC, HerReplayBuffer

spec = importlib.util.spec_from_file_location("train_her", sys.argv[1])
her = importlib.util.module_from_spec(spec)
sys.modules["train_her"] = her
spec.loader.exec_module(her)
torch.set_num_threads(1)
env = her.make_env()
model = SAC("MultiInputPolicy", env, replay_buffer_class=HerReplayBuffer, replay_buffer_kwargs=her.HER_KWARGS,
            seed=0, device="cpu", **{**her.SAC_KWARGS, "learning_starts": 100, "batch_size": 32})
before = [p.detach().clone() for p in model.actor.parameters()]
model.learn(total_timesteps=200)
assert model.num_timesteps == 200
assert any(not torch.equal(b, p) for b, p in zip(before, model.actor.parameters(), strict=True)), "it did not train"
buffer = model.replay_buffer
assert isinstance(buffer, HerReplayBuffer) and buffer.size() > 0
batch = buffer.sample(64)  # relabelled samples carry the env's own reward for their new goal
ach, des = batch.next_observations["achieved_goal"].numpy(), batch.observations["desired_goal"].numpy()
np.testing.assert_array_equal(batch.rewards.numpy().ravel(), env.unwrapped.compute_reward(ach, des, [{}] * len(ach)))
rate = her.success_rate(model, her.make_env(), 2)
assert 0.0 <= rate <= 1.0, rate
print("ok")
"""


def test_sac_her_learns_200_steps_on_the_unchanged_env():
    run = subprocess.run([sys.executable, "-c", CHECK, str(EXAMPLE)], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0 and run.stdout.strip().endswith("ok"), run.stderr[-3000:]
