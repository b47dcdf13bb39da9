"""The native vector env: N reach envs as arrays, stepped with one batched FK (or IK) and batched contacts."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from numpy.typing import NDArray

import mjkin
from mjkin.runtime.checks import check_count

from .reach import ReachEnv
from .task import check_action

Array = NDArray[np.float64]


class ReachVectorEnv(VectorEnv):
    """``num_envs`` copies of :class:`~mjkin.envs.ReachEnv` (same arguments), stepped together.

    The state of all envs is kept as arrays (``q (N, nq)``, targets ``(N, 3|7)``);
    a step moves all of them with one batched call (joint arithmetic, or one
    batched mjkin IK for cartesian actions), takes one batched FK and asks
    MuJoCo for each env's contacts. Env ``i`` behaves exactly as a single env:

    - ``reset(seed=s)`` seeds env ``i`` with ``s + i`` (a list gives one seed per
      env); ``options`` as the single env's (``q``/``target`` for all envs), plus
      gymnasium's ``reset_mask`` to reset some envs only;
    - episodes are truncated after ``max_episode_steps`` (the registration's 100);
    - autoreset is gymnasium's ``AutoresetMode.NEXT_STEP``: the step after an
      episode ends resets that env (its action is ignored) and returns the first
      observation with reward 0 and no termination;
    - ``info`` holds the single env's keys as arrays, each with its ``_key`` mask;
    - ``render()`` gives a tuple of every env's frame; ``get_attr(name)`` and
      ``call(name, ...)`` give a tuple with the value for each env.
    """

    def __init__(self, num_envs: int = 1, max_episode_steps: int | None = 100, render_mode: str | None = None,
                 **kwargs: Any) -> None:
        self.num_envs = check_count(num_envs, "num_envs")
        self.max_episode_steps = None if max_episode_steps is None else \
            check_count(max_episode_steps, "max_episode_steps")
        self.env = ReachEnv(render_mode=render_mode, **kwargs)  # the template: settings, spaces, painter
        self.task = self.env.task
        self.render_mode = render_mode
        self.metadata = {**self.env.metadata, "autoreset_mode": AutoresetMode.NEXT_STEP}
        self.single_action_space = self.task.action_space
        self.single_observation_space = self.task.observation_space
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        n, t = self.num_envs, self.task
        self.q = np.tile(t.home, (n, 1))
        self.target, R, _ = t.achieved(self.q)
        self.achieved, self.R = self.target.copy(), R
        self.elapsed = np.zeros(n, dtype=np.int64)
        self.autoreset = np.zeros(n, dtype=bool)
        self.rngs: list[np.random.Generator | None] = [None] * n

    # ----------------------------------------------------------------- state
    def _start(self, i: int, seed: int | None, options: dict | None) -> None:
        """Reset env ``i`` as a single env's ``reset(seed=seed, options=options)`` would."""
        rng = self.rngs[i]
        if seed is not None or rng is None:
            rng = self.rngs[i] = seeding.np_random(seed)[0]
        self.q[i], self.target[i] = self.task.start(rng, options)
        self.elapsed[i] = 0

    def _settle(self) -> tuple[Any, NDArray[np.float64], dict[str, Any]]:
        """One FK for all envs, MuJoCo's contacts for each; observations, rewards and ``info``."""
        self.achieved, self.R, frames = self.task.achieved(self.q)
        out, reward = self.task.outcome(self.q, self.achieved, self.target, frames)
        out["reward_distance"] = -out["distance"]
        return self.task.observe(self.q, self.achieved, self.target), reward, out

    def _info(self, out: dict[str, Any], mask: NDArray[np.bool_]) -> dict[str, Any]:
        info: dict[str, Any] = {}
        for key, value in out.items():
            info[key], info[f"_{key}"] = value, mask.copy()
        return info

    # ---------------------------------------------------------- gymnasium API
    def reset(self, *, seed: int | list[int | None] | None = None,
              options: dict | None = None) -> tuple[Any, dict[str, Any]]:
        """Reset every env (or those in ``options["reset_mask"]``); env ``i`` gets ``seed + i``."""
        n = self.num_envs
        if seed is None:
            seeds: list[int | None] = [None] * n
        elif isinstance(seed, (int, np.integer)):
            seeds = [int(seed) + i for i in range(n)]
        else:
            seeds = list(seed)
            if len(seeds) != n:
                raise mjkin.InputError(f"reset(seed=...) got {len(seeds)} seeds for {n} envs")
        options = dict(options or {})
        mask = np.asarray(options.pop("reset_mask", np.ones(n, dtype=bool)), dtype=bool)
        if mask.shape != (n,) or not mask.any():
            raise mjkin.InputError(f"options['reset_mask'] must be {n} booleans with at least one True")
        for i in np.flatnonzero(mask).tolist():
            self._start(i, seeds[i], options)
        self.autoreset[mask] = False
        obs, _, out = self._settle()
        return obs, self._info(out, mask)

    def step(self, actions: Any) -> tuple[Any, Array, NDArray[np.bool_], NDArray[np.bool_], dict[str, Any]]:
        """Step all envs; those whose episode ended on the previous step are reset instead."""
        a = check_action(actions, self.action_space, "actions")
        resetting = self.autoreset.copy()
        self.q = self.task.move(self.q, a, self.R, self.achieved)
        for i in np.flatnonzero(resetting).tolist():
            self._start(i, None, None)
        self.elapsed += ~resetting
        obs, reward, out = self._settle()
        terminated = out["is_success"] & ~resetting
        truncated = np.zeros(self.num_envs, dtype=bool) if self.max_episode_steps is None else \
            (self.elapsed >= self.max_episode_steps) & ~resetting
        reward[resetting] = 0.0
        self.autoreset = terminated | truncated
        return obs, reward, terminated, truncated, self._info(out, np.ones(self.num_envs, dtype=bool))

    # ------------------------------------------------------ per-env access
    def _load(self, i: int) -> ReachEnv:
        """The template env holding env ``i``'s state."""
        env = self.env
        env.q, env.target, env._achieved = self.q[i].copy(), self.target[i].copy(), self.achieved[i].copy()
        env._R = None if self.R is None else self.R[i:i + 1].copy()
        env._np_random = self.rngs[i]
        return env

    def _store(self, i: int) -> None:
        env = self.env
        self.q[i], self.target[i], self.achieved[i] = env.q, env.target, env._achieved
        if self.R is not None and env._R is not None:
            self.R[i] = env._R[0]
        self.rngs[i] = env._np_random

    def get_attr(self, name: str) -> tuple[Any, ...]:
        """The attribute ``name`` of each env (as a single env would have it)."""
        return tuple(getattr(self._load(i), name) for i in range(self.num_envs))

    def call(self, name: str, *args: Any, **kwargs: Any) -> tuple[Any, ...]:
        """Call method ``name`` of each env (or read the attribute when it is not callable)."""
        out = []
        for i in range(self.num_envs):
            value = getattr(self._load(i), name)
            out.append(value(*args, **kwargs) if callable(value) else value)
            self._store(i)
        return tuple(out)

    def render(self) -> tuple[Any, ...] | None:
        """Every env's frame (``rgb_array``), as a tuple."""
        if self.render_mode is None:
            return None
        return self.call("render")

    def close_extras(self, **kwargs: Any) -> None:
        """Free the renderer."""
        self.env.close()
