"""Reach: move an effector onto a target; kinematics by mjkin, contacts and pictures by MuJoCo."""

from __future__ import annotations

import os
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

import mjkin
from mjkin import goals as G
from mjkin.render import Overlay, Painter, default_camera
from mjkin.scene import Scene

Array = NDArray[np.float64]


class ReachEnv(gym.Env):
    """Reach a random target with an arm's effector site.

    The configuration ``q`` is the arm's MuJoCo ``qpos``; every step the action
    changes it through mjkin, the result is clipped into the joint limits,
    written to MuJoCo for contacts, and observed.

    ## Action space
    ``Box(-1, 1)``, scaled by ``step_size``:

    | action_type | shape | meaning |
    |---|---|---|
    | ``"joint"`` | ``(nv,)`` | joint position change, ``step_size`` rad (or m) per unit |
    | ``"cartesian"`` | ``(3,)`` | effector displacement in world axes, ``step_size`` m per unit, solved by mjkin IK |

    ## Observation space
    ``Box(-inf, inf, (nq + 9,))``, float64:

    | index | meaning |
    |---|---|
    | ``0 : nq`` | joint configuration ``q`` (qpos; unlimited hinges wrapped into [-π, π]) |
    | ``nq : nq+3`` | effector position (world, m) |
    | ``nq+3 : nq+6`` | target position (world, m) |
    | ``nq+6 : nq+9`` | target minus effector |

    ## Rewards
    Dense (default): ``-distance + success_bonus · success - collision_penalty · in_collision``.
    Sparse: ``success_bonus · success - 1 · (not success)``. The terms are in ``info``.

    ## Starting state
    ``q`` is the model's first keyframe (else ``qpos0``) plus uniform noise of
    ``start_noise`` rad, clipped into the limits; the target is the effector
    position of a random in-limit configuration (always reachable) inside
    ``target_region`` when given (``(low, high)`` boxes, resampled until inside).

    ## Episode end
    ``terminated`` when the distance is below ``success_tol``; ``truncated`` by
    the ``TimeLimit`` of the registration (``max_episode_steps``).

    ## Arguments
    ``model`` (bundled name or path), ``site``, ``action_type``, ``step_size``,
    ``success_tol`` (m), ``success_bonus``, ``sparse``, ``collision_penalty``,
    ``obstacles`` (list of ``(center, radius)`` spheres: a target inside one is
    resampled, and touching one counts as a collision), ``target_region``,
    ``start_noise``, ``render_mode`` (``"rgb_array"``; ``"human"`` only with a
    display), ``width``, ``height``.

    ## Version history
    v0: first version.
    """

    # "human" is offered only where a display exists: gymnasium's checks open every listed mode
    metadata = {"render_modes": ["rgb_array", "human"] if os.environ.get("DISPLAY") else ["rgb_array"],
                "render_fps": 30}

    def __init__(self, model: str = "arm7", site: str = "ee", action_type: str = "joint",
                 step_size: float | None = None, success_tol: float | None = None, success_bonus: float = 1.0,
                 sparse: bool = False, collision_penalty: float = 0.0,
                 obstacles: list[tuple[Any, float]] | None = None,
                 target_region: tuple[Any, Any] | None = None, start_noise: float = 0.1,
                 render_mode: str | None = None, width: int = 480, height: int = 360) -> None:
        if action_type not in ("joint", "cartesian"):
            raise mjkin.InputError(f"action_type must be 'joint' or 'cartesian', not {action_type!r}")
        if render_mode not in (None, "rgb_array", "human"):
            raise mjkin.InputError(f"render_mode must be None, 'rgb_array' or 'human', not {render_mode!r}")
        if render_mode == "human" and not os.environ.get("DISPLAY"):
            raise mjkin.InputError("render_mode='human' needs a display; use render_mode='rgb_array' on a headless "
                                   "machine")
        self.tree = mjkin.load(model)
        self.site = site
        self.tree.frame(site)  # unknown names fail here, with the list of names
        extent = float(self.tree.model.stat.extent) or 1.0
        self.action_type = action_type
        default_step = 0.1 if action_type == "joint" else 0.05 * extent
        self.step_size = float(step_size if step_size is not None else default_step)
        self.success_tol = float(success_tol if success_tol is not None else 0.02 * extent)
        self.success_bonus, self.sparse, self.collision_penalty = float(success_bonus), bool(sparse), \
            float(collision_penalty)
        self.obstacles = [(np.asarray(c, dtype=np.float64), float(r)) for c, r in (obstacles or [])]
        self.target_region = None if target_region is None else (np.asarray(target_region[0], dtype=np.float64),
                                                                   np.asarray(target_region[1], dtype=np.float64))
        self.start_noise = float(start_noise)
        self.render_mode, self.width, self.height = render_mode, width, height
        m = self.tree.model
        self.home = m.key_qpos[0].copy() if m.nkey else self.tree.qpos0.copy()
        self.scene = Scene(self.tree)
        n_act = self.tree.nv if action_type == "joint" else 3
        self.action_space = spaces.Box(-1.0, 1.0, (n_act,), dtype=np.float32)
        lay = self.tree.layout
        self._wrap = lay.scalar_q[lay.scalar_hinge & ~np.isfinite(lay.scalar_hi)]  # unlimited hinges
        q_lo, q_hi = np.full(self.tree.nq, -1.0), np.full(self.tree.nq, 1.0)  # quaternions
        q_lo[lay.scalar_q] = np.where(np.isfinite(lay.scalar_lo), lay.scalar_lo, -10 * extent)
        q_hi[lay.scalar_q] = np.where(np.isfinite(lay.scalar_hi), lay.scalar_hi, 10 * extent)
        q_lo[self._wrap], q_hi[self._wrap] = -np.pi, np.pi
        q_lo[lay.free_q[:, :3].ravel()], q_hi[lay.free_q[:, :3].ravel()] = -10 * extent, 10 * extent
        far = np.full(9, 4.0 * extent)
        self.observation_space = spaces.Box(np.concatenate([q_lo, -far]), np.concatenate([q_hi, far]),
                                            dtype=np.float64)
        self.q = self.home.copy()
        self.target = np.zeros(3)
        self._painter: Painter | None = None
        self._camera: Any = None

    # ------------------------------------------------------------------ state
    def effector(self, q: Array | None = None) -> Array:
        """World position of the effector site at ``q`` (default: now)."""
        return self.tree.pose(self.q if q is None else q, self.site)[:3, 3]

    def _set(self, q: Array) -> None:
        q = self.tree.clip(q)
        q[self._wrap] = np.angle(np.exp(1j * q[self._wrap]))
        self.q = q

    def _obs(self, ee: Array) -> Array:
        return np.concatenate([self.q, ee, self.target, self.target - ee])

    def _sample_target(self) -> Array:
        for _ in range(1000):
            p = self.effector(self.tree.random_q(self.np_random))
            inside = self.target_region is None or bool(np.all((p >= self.target_region[0])
                                                               & (p <= self.target_region[1])))
            clear = all(np.linalg.norm(p - c) > r for c, r in self.obstacles)
            if inside and clear:
                return p
        raise mjkin.InputError("no reachable target found inside target_region and outside the obstacles")

    def _touching_obstacle(self) -> bool:
        if not self.obstacles:
            return False
        points = self.tree.fk(self.q)[1:, :3, 3]
        return any(np.any(np.linalg.norm(points - c, axis=-1) < r) for c, r in self.obstacles)

    # ---------------------------------------------------------------- gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[Array, dict]:
        """Start an episode: a new target and a start near the home pose."""
        super().reset(seed=seed)
        noise = self.np_random.uniform(-self.start_noise, self.start_noise, self.tree.nv)
        self._set(self.tree.integrate(self.home, noise))
        self.target = self._sample_target()
        self._camera = None
        ee = self.effector()
        return self._obs(ee), self._info(ee)

    def step(self, action: Any) -> tuple[Array, float, bool, bool, dict]:
        """Apply an action (see the class docstring); bad actions raise and change nothing."""
        a = np.asarray(action, dtype=np.float64)
        if a.shape != self.action_space.shape:
            raise mjkin.InputError(f"action has shape {a.shape}; expected {self.action_space.shape}")
        if not np.isfinite(a).all():
            raise mjkin.InputError("action contains NaN or inf")
        a = np.clip(a, -1.0, 1.0) * self.step_size
        if self.action_type == "joint":
            self._set(self.tree.integrate(self.q, a))
        else:
            goal = G.Position(self.site, self.effector() + a)
            self._set(mjkin.solve(self.tree, goal, q0=self.q, max_iters=30, restarts=0).q)
        ee = self.effector()
        info = self._info(ee)
        reward = (self.success_bonus if info["is_success"] else -1.0) if self.sparse else \
            -info["distance"] + self.success_bonus * info["is_success"]
        reward -= self.collision_penalty * info["in_collision"]
        info["reward_distance"] = -info["distance"]
        return self._obs(ee), float(reward), bool(info["is_success"]), False, info

    def _info(self, ee: Array) -> dict:
        distance = float(np.linalg.norm(self.target - ee))
        contacts = self.scene.contacts(self.q)
        return {"distance": distance, "is_success": distance < self.success_tol, "contacts": len(contacts),
                "in_collision": bool(contacts) or self._touching_obstacle()}

    def render(self) -> NDArray[np.uint8] | None:
        """An RGB frame with the target drawn (``rgb_array``); ``human`` shows it in a window."""
        if self.render_mode is None:
            return None
        if self._painter is None:
            self._painter = Painter(self.tree, self.width, self.height)
        if self._camera is None:
            self._camera = default_camera(self.tree, np.stack([self.home, self.q]), self.target[None])
        obstacles = [c for c, _ in self.obstacles]
        frame = self._painter.draw(self.q, self._camera, [self.target, *obstacles], overlay=Overlay(point_size=0.03))
        if self.render_mode == "human":  # pragma: no cover - needs a display
            import matplotlib.pyplot as plt

            plt.imshow(frame)
            plt.pause(1.0 / self.metadata["render_fps"])
            return None
        return frame

    def close(self) -> None:
        """Free the renderer."""
        if self._painter is not None:
            self._painter.close()
            self._painter = None


def ik_expert(env: ReachEnv) -> NDArray[np.float32]:
    """A scripted expert: the action that moves toward mjkin's IK solution for the current target."""
    if env.action_type == "cartesian":
        return np.clip((env.target - env.effector()) / env.step_size, -1, 1).astype(np.float32)
    res = mjkin.solve(env.tree, G.Position(env.site, env.target), q0=env.q, tol=0.1 * env.success_tol)
    return np.clip(env.tree.difference(res.q, env.q) / env.step_size, -1, 1).astype(np.float32)
