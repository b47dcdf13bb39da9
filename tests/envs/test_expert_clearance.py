"""The reach envs' expert among obstacles: every pose it steps to keeps clear (a hard Clearance in its IK)."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np

import mjkin.envs  # noqa: F401  (registers the ids)
from mjkin.envs import ik_expert
from mjkin.envs.reach import EXPERT_CLEARANCE

CENTER, RADIUS = np.array([0.35, 0.0, 0.55]), 0.12  # a ball between the home pose and the targets
REGION = ([0.2, -0.3, 0.3], [0.6, 0.3, 0.9])
SEEDS = range(8)  # before the expert kept clear it touched in 2 of these (seeds 1 and 7: 26 and 2 steps in contact)


def least_distance(env, q: np.ndarray) -> float:
    """MuJoCo's least ``mj_geomDistance`` over the pairs ``mj_collision`` proposes within 5 cm, at ``q``."""
    m = env.tree.model.__copy__()
    m.geom_margin[:] = 0.05
    d = mujoco.MjData(m)
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    mujoco.mj_collision(m, d)
    pairs = {(int(c.geom1), int(c.geom2)) for c in d.contact[:d.ncon]}
    return min((mujoco.mj_geomDistance(m, d, a, b, 1.0, None) for a, b in pairs), default=1.0)


def test_expert_steps_stay_clear_of_the_ball_and_the_table():
    env = gym.make("mjkin/Reach-v0", target_region=REGION, obstacles=[(CENTER, RADIUS)], table=0.0)
    wins = 0
    for seed in SEEDS:
        env.reset(seed=seed)
        for _ in range(60):
            _, _, term, trunc, info = env.step(ik_expert(env.unwrapped))
            assert info["contacts"] == 0 and not info["in_collision"]
            assert least_distance(env.unwrapped, env.unwrapped.q) >= EXPERT_CLEARANCE - 1e-6
            if term or trunc:
                break
        wins += bool(info["is_success"])
    assert wins >= len(SEEDS) - 1, wins  # it still reaches (a ball in the way could trap a greedy expert)
