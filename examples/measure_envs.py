"""Steps per second of mjkin's reach envs beside gymnasium's Reacher-v5, measured in one process.

    python examples/measure_envs.py [--steps 3000] [--repeats 5] [--num-envs 256]

Every env steps with pre-drawn random actions (action sampling is not timed),
resets when an episode ends (timed, as in training), and reports its best of
``--repeats`` interleaved runs. Single envs come from ``gym.make`` (with its
wrappers, like Reacher-v5); the vector rows from ``gym.make_vec(...,
vectorization_mode="vector_entry_point")``, counting ``num_envs`` steps per call.
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym

import mjkin.envs  # noqa: F401  (registers the ids)


def single_rate(env: gym.Env, steps: int, seed: int = 0) -> float:
    """Steps per second of one env over ``steps`` random actions."""
    env.reset(seed=seed)
    env.action_space.seed(seed)
    actions = [env.action_space.sample() for _ in range(steps)]
    start = time.perf_counter()
    for a in actions:
        _, _, term, trunc, _ = env.step(a)
        if term or trunc:
            env.reset()
    return steps / (time.perf_counter() - start)


def vector_rate(envs: gym.vector.VectorEnv, steps: int, seed: int = 0) -> float:
    """Env steps per second (``num_envs`` per call) of a vector env (it autoresets itself)."""
    envs.reset(seed=seed)
    envs.action_space.seed(seed)
    actions = [envs.action_space.sample() for _ in range(steps)]
    start = time.perf_counter()
    for a in actions:
        envs.step(a)
    return steps * envs.num_envs / (time.perf_counter() - start)


def main() -> None:
    """Print a table: env, steps/s, ratio to Reacher-v5."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=3000, help="steps per single-env run")
    ap.add_argument("--repeats", type=int, default=5, help="interleaved runs; the best counts")
    ap.add_argument("--num-envs", type=int, default=256, help="N of the vector rows (0: none)")
    ap.add_argument("--ids", nargs="*", default=["mjkin/Reach-v0", "mjkin/PlanarReach-v0", "mjkin/PandaReach-v0"])
    args = ap.parse_args()
    makers = {"Reacher-v5 (gymnasium)": lambda: gym.make("Reacher-v5")}
    for env_id in args.ids:
        makers[env_id] = lambda env_id=env_id: gym.make(env_id)
    envs = {name: make() for name, make in makers.items()}
    best = dict.fromkeys(envs, 0.0)
    vec_steps = max(args.steps // max(args.num_envs, 1) * 8, 10)
    vecs = {f"{i} x{args.num_envs} (vector)": gym.make_vec(i, num_envs=args.num_envs,
                                                            vectorization_mode="vector_entry_point")
            for i in args.ids} if args.num_envs else {}
    best.update(dict.fromkeys(vecs, 0.0))
    for _ in range(args.repeats):
        for name, env in envs.items():
            best[name] = max(best[name], single_rate(env, args.steps))
        for name, venv in vecs.items():
            best[name] = max(best[name], vector_rate(venv, vec_steps))
    base = best["Reacher-v5 (gymnasium)"]
    print(f"{'env':40s} {'steps/s':>12s} {'vs Reacher-v5':>14s}")
    for name, rate in best.items():
        print(f"{name:40s} {rate:12,.0f} {rate / base:13.2f}x")


if __name__ == "__main__":
    main()
