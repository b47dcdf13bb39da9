"""A visible reach episode: the scripted IK expert reaches several targets in a row, one video.

    python examples/episode.py [-o reach.mp4] [--env mjkin/PandaReach-v0] [--targets 6] [--seed 0]

The Panda's targets are drawn in a box in front of it (``target_region``).
After each success the env is reset with ``options={"q": <where the arm is>}``:
the arm continues from where it stopped and only the target is new, so the
episodes join into one continuous video.
"""

from __future__ import annotations

import argparse

import gymnasium as gym

import mjkin.envs  # noqa: F401  (registers the ids)
from mjkin.envs import ik_expert
from mjkin.render import write_video


def main() -> None:
    """Run the expert on consecutive targets and write the video."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--output", default="reach.mp4", help="video file (.mp4 or .gif)")
    ap.add_argument("--env", default="mjkin/PandaReach-v0", help="env id")
    ap.add_argument("--targets", type=int, default=6, help="targets in a row")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    region = {"target_region": ([0.25, -0.4, 0.1], [0.65, 0.4, 0.6])} if "Panda" in args.env else {}
    env = gym.make(args.env, render_mode="rgb_array", step_size=0.05, **region)
    obs, info = env.reset(seed=args.seed)
    frames, reached = [env.render()], 0
    for _ in range(args.targets):
        for _ in range(200):
            obs, reward, terminated, truncated, info = env.step(ik_expert(env.unwrapped))
            frames.append(env.render())
            if terminated or truncated:
                break
        reached += info["is_success"]
        frames += [frames[-1]] * 10  # hold the reached pose for a third of a second
        obs, info = env.reset(options={"q": env.unwrapped.q})  # same arm, new target
    write_video(frames, args.output, fps=env.metadata["render_fps"])
    print(f"{args.output}: {len(frames)} frames ({len(frames) / env.metadata['render_fps']:.1f} s), "
          f"{reached}/{args.targets} targets reached")


if __name__ == "__main__":
    main()
