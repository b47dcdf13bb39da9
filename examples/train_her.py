"""SAC + Hindsight Experience Replay on the goal-conditioned, sparse ``mjkin/PandaReach-v0``.

    pip install -e ".[rl]"     # stable-baselines3, torch (the CPU build is enough), matplotlib
    python examples/train_her.py --seeds 0 1 2 --steps 8000 --out curve.png --json curve.json

The env hands stable-baselines3 its ``Dict`` observation and batched
``compute_reward`` unchanged; ``HerReplayBuffer`` relabels 4 of every 5 sampled
transitions with a goal achieved later in the same episode ("future"). Every
``--eval-every`` steps the deterministic policy runs ``--eval-episodes`` episodes
on a separate eval env whose seeds (from 10 000 on) no training episode uses;
the share that ends at the target is the success rate. The curve (success vs
env steps, one line per seed and their mean) and the numbers behind it are
written atomically to ``--out`` (PNG) and ``--json``.

Task settings (:data:`ENV_KWARGS`), those of panda-gym's ``PandaReach-v3``, so
that under 10 000 steps suffice: the action moves the flange (``cartesian``, 3
numbers, 5 cm per unit, solved by mjkin IK), so the policy need not learn the
arm's inverse kinematics from sparse rewards; targets are drawn in a 30 cm cube
around the flange's start; success within 5 cm; episodes of 50 steps (a target
is about 26 cm away at most, 6 full-size steps).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any

import gymnasium as gym
import numpy as np

import mjkin.envs  # noqa: F401  (registers the ids)
from mjkin.errors import MjkinError
from mjkin.runtime.files import check_writable, write_text, write_with

ENV_ID = "mjkin/PandaReach-v0"
ENV_KWARGS: dict[str, Any] = {
    "goal_conditioned": True, "sparse": True, "action_type": "cartesian", "step_size": 0.05,
    "success_tol": 0.05, "target_region": ([0.15, -0.15, 0.42], [0.45, 0.15, 0.72]), "max_episode_steps": 50,
}
SAC_KWARGS: dict[str, Any] = {  # rl-zoo's settings for panda-gym reach, a smaller batch
    "learning_rate": 1e-3, "batch_size": 256, "gamma": 0.95, "tau": 0.05, "learning_starts": 200,
    "policy_kwargs": {"net_arch": [64, 64]},
}
HER_KWARGS: dict[str, Any] = {"goal_selection_strategy": "future", "n_sampled_goal": 4}
EVAL_SEED0 = 10_000  # eval episodes use seeds EVAL_SEED0 + i; training resets draw from the training seed's stream


def make_env() -> gym.Env:
    """The goal-conditioned, sparse Panda reach task with :data:`ENV_KWARGS`."""
    return gym.make(ENV_ID, **ENV_KWARGS)


def success_rate(model: Any, env: gym.Env, episodes: int) -> float:
    """Share of held-out episodes (seeds ``EVAL_SEED0 + i``) that the deterministic policy ends at the target."""
    wins = 0
    for i in range(episodes):
        obs, _ = env.reset(seed=EVAL_SEED0 + i)
        done = False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
        wins += bool(info["is_success"])
    return wins / episodes


def train(seed: int, steps: int, eval_every: int, eval_episodes: int) -> dict[str, Any]:
    """Train SAC + HER for ``steps`` env steps; success rate at 0, ``eval_every``, ... steps (and at the end)."""
    import torch
    from stable_baselines3 import SAC, HerReplayBuffer
    from stable_baselines3.common.callbacks import BaseCallback

    torch.set_num_threads(1)  # 2 shared cores: more threads only oversubscribe them
    eval_env = make_env()
    curve: list[tuple[int, float]] = []
    start = time.perf_counter()

    def evaluate(model: Any) -> None:
        curve.append((model.num_timesteps, success_rate(model, eval_env, eval_episodes)))
        print(f"seed {seed}: {curve[-1][0]:>6d} steps  success {curve[-1][1]:.0%}  "
              f"({time.perf_counter() - start:.0f} s)", flush=True)

    class Evaluate(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps % eval_every == 0:
                evaluate(self.model)
            return True

    env = make_env()
    model = SAC("MultiInputPolicy", env, replay_buffer_class=HerReplayBuffer, replay_buffer_kwargs=HER_KWARGS,
                seed=seed, device="cpu", verbose=0, **SAC_KWARGS)
    evaluate(model)
    model.learn(total_timesteps=steps, callback=Evaluate())
    if curve[-1][0] != model.num_timesteps:
        evaluate(model)
    return {"seed": seed, "steps": [s for s, _ in curve], "success": [r for _, r in curve],
            "seconds": time.perf_counter() - start}


def plot(runs: list[dict[str, Any]], path: str) -> None:
    """Success vs env steps, one thin line per seed and their mean, as a 600×400 PNG written atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4), dpi=100)
    for run in runs:
        ax.plot(run["steps"], np.multiply(run["success"], 100), lw=1, alpha=0.6, label=f"seed {run['seed']}")
    ax.plot(runs[0]["steps"], np.mean([r["success"] for r in runs], axis=0) * 100, lw=2.5, color="k", label="mean")
    ax.set(xlabel="env steps", ylabel="success on held-out targets (%)", ylim=(-3, 103),
           title="SAC + HER on mjkin/PandaReach-v0 (sparse, goal-conditioned)")
    ax.title.set_fontsize(10)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    write_with(path, lambda p: fig.savefig(p, format="png"))
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    """Train one run per seed, then write the JSON and the PNG."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="one training run per seed")
    p.add_argument("--steps", type=int, default=8000, help="env steps per run")
    p.add_argument("--eval-every", type=int, default=500, help="env steps between evaluations")
    p.add_argument("--eval-episodes", type=int, default=50, help="held-out episodes per evaluation")
    p.add_argument("--out", default="curve.png", help="learning curve PNG")
    p.add_argument("--json", default="curve.json", help="the numbers behind the curve")
    args = p.parse_args(argv)
    for name, value in [("--steps", args.steps), ("--eval-every", args.eval_every),
                        ("--eval-episodes", args.eval_episodes)]:
        if value < 1:
            p.exit(2, f"error: {name} must be a positive integer, got {value}\n")
    try:
        check_writable(args.out, (".png",), "--out")
        check_writable(args.json, (".json",), "--json")
        import stable_baselines3  # noqa: F401
    except ImportError:
        p.exit(2, 'error: stable-baselines3 is missing; pip install -e ".[rl]"\n')
    except MjkinError as e:  # bad path: one line, no traceback
        p.exit(2, f"error: {e}\n")

    runs = [train(seed, args.steps, args.eval_every, args.eval_episodes) for seed in args.seeds]
    target_region = [list(map(float, box)) for box in ENV_KWARGS["target_region"]]
    config = {"env": ENV_ID, "env_kwargs": {**ENV_KWARGS, "target_region": target_region}, "sac": SAC_KWARGS,
              "her": HER_KWARGS, "eval_episodes": args.eval_episodes, "eval_seeds_from": EVAL_SEED0,
              "command": " ".join(["python", "examples/train_her.py", *sys.argv[1:]])}
    write_text(args.json, json.dumps({"config": config, "runs": runs}, indent=1) + "\n")
    plot(runs, args.out)
    final = ", ".join(f"seed {r['seed']}: {r['success'][-1]:.0%}" for r in runs)
    print(f"final success {final}; {sum(r['seconds'] for r in runs):.0f} s in all; wrote {args.out}, {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
