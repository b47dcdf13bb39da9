"""Reach: move an effector onto a target; kinematics by mjkin, contacts and pictures by MuJoCo."""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import ArrayLike, NDArray

from mjkin import goals as G
from mjkin import spatial
from mjkin.render import Overlay, Painter, default_camera
from mjkin.runtime.checks import check_choice, check_count

from .task import ReachTask, check_action

EXPERT_CLEARANCE = 0.005  # m: what the expert keeps between every pair MuJoCo would collide, with obstacles
MARKER = 0.03  # the target marker's least radius, as a fraction of the model's extent (E)

Array = NDArray[np.float64]


def has_display() -> bool:
    """Whether a window can be opened (X11 or Wayland)."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


class ReachEnv(gym.Env):
    """Reach a random target with an arm's effector site.

    The configuration ``q`` is the arm's MuJoCo ``qpos``; every step the action
    changes it through mjkin, the result is clipped into the joint limits (an
    unlimited hinge is wrapped into [-π, π]), written to MuJoCo for contacts,
    and observed. One mjkin FK per step gives the effector for the observation,
    the reward and ``info``.

    ## Action space
    ``Box(-1, 1, (n,), float32)``; values outside are clipped, then scaled:

    | action_type | goal_type | n | meaning |
    |---|---|---|---|
    | ``"joint"`` | any | ``nv`` | joint position change, ``step_size`` rad (or m) per unit |
    | ``"cartesian"`` | ``"position"`` | 3 | effector displacement, world axes, ``step_size`` m per unit |
    | ``"cartesian"`` | ``"pose"`` | 6 | twist: displacement (``step_size`` m per unit), rotation vector |
    | | | | (world axes, ``rot_step`` rad per unit); the new pose is solved by mjkin IK |

    An arm whose effector moves in one plane (``PlanarReach-v0``: the world's x-y plane)
    drops what leaves it: a cartesian displacement keeps its part in the plane, a
    rotation its part about the plane's normal, so each step's IK gets a target the
    arm can reach (``env.unwrapped.task.plane``: the normal, else None).

    ## Observation space
    A goal ``g`` is the effector position ``[x, y, z]`` (``goal_type="position"``,
    3 numbers) or its pose ``[x, y, z, qw, qx, qy, qz]`` (``"pose"``, 7 numbers,
    ``qw >= 0``). With ``E = MjModel.stat.extent`` (arm7: 1.43 m, planar_3link:
    30, panda: 1.2 m; ``env.unwrapped.extent``), float64 ``Box`` with these bounds:

    | index | meaning | bounds |
    |---|---|---|
    | ``0 : nq`` | joint configuration ``q`` (qpos) | joint limits; unlimited hinges [-π, π]; unlimited slides ±10 E |
    | next 3 or 7 | achieved goal: effector position (m) [and quaternion] | position ±4 E; qw [0, 1], qx..qz [-1, 1] |
    | next 3 or 7 | desired goal (the target) | as the achieved goal |
    | next 3 or 6 | target minus effector position [, rotation vector effector → target, world axes] | ±8 E [; ±π] |

    With ``goal_conditioned=True`` the observation is instead a ``Dict`` as in
    gymnasium-robotics: ``observation`` = ``q`` (bounds as above),
    ``achieved_goal`` and ``desired_goal`` = the goals (bounds as above).

    ## Rewards
    With ``d`` the position distance (m), ``θ`` the rotation angle to the
    target's orientation (rad, 0 for position goals), ``success = d < success_tol
    and θ < rot_tol`` and ``c = info["in_collision"]``:

    - dense (default): ``-(d + (success_tol / rot_tol) θ) + success_bonus · success - collision_penalty · c``
    - sparse: ``-1 + success - collision_penalty · c`` (−1 until the goal is met, then 0, as gymnasium-robotics)

    ``env.unwrapped.compute_reward(achieved_goal, desired_goal, info)`` is that
    function, vectorised over a leading batch axis (``info``: a dict, a dict of
    arrays, or a list/array of dicts); ``step`` calls it, so replayed (HER)
    transitions get the reward the env gave. ``info`` holds ``distance``,
    ``is_success``, ``contacts`` (MuJoCo contacts, adjacent bodies excluded),
    ``in_collision``, ``reward_distance`` (``-d``) and, for pose goals, ``angle``.

    ## Starting state
    ``q`` is the model's first keyframe (else ``qpos0``) moved by uniform noise in
    ``[-start_noise, start_noise]`` rad (or m) per dof (``start_noise`` from 0 to π), clipped into the limits.
    The target is the effector goal of a random in-limit configuration that is
    free of contacts (so always reachable), inside ``target_region`` (``(low,
    high)`` boxes, world m) when given and outside every obstacle; resampled
    until so. ``reset(options={"q": q, "target": g})`` sets either instead (``q`` clipped into the limits;
    ``options={"q": env.unwrapped.q}`` keeps the arm where it is for a new target).

    ## Episode end
    ``terminated`` when ``success``; ``truncated`` by the registration's
    ``TimeLimit`` (``max_episode_steps=100``).

    ## Arguments
    | argument | default | meaning |
    |---|---|---|
    | ``model`` | per id | bundled model name, MJCF path or XML string |
    | ``frame`` | per id | the effector frame (site, else body; ``site=`` before 0.2) |
    | ``action_type`` | ``"joint"`` | ``"joint"`` or ``"cartesian"`` |
    | ``goal_type`` | ``"position"`` | ``"position"`` or ``"pose"`` |
    | ``goal_conditioned`` | ``False`` | Dict observations and the goal-env methods' contract |
    | ``step_size`` | 0.1 rad (joint), 0.05 E (cartesian) | scale of one action unit |
    | ``rot_step`` | 0.1 | rad per unit of a cartesian pose action's rotation |
    | ``success_tol`` | 0.02 E | position tolerance (m) |
    | ``rot_tol`` | 0.1 | angle tolerance (rad) of pose goals |
    | ``success_bonus`` | 1.0 | dense reward bonus on success |
    | ``sparse`` | ``False`` | −1/0 rewards |
    | ``collision_penalty`` | 0.0 | subtracted while in contact |
    | ``obstacles`` | none | ``[(center, radius), ...]`` spheres added to the MuJoCo model (contacts, frames, penalty) |
    | ``table`` | ``None`` | height (world z, m) of a table top added under the arm |
    | ``target_region`` | anywhere | ``(low, high)`` box the targets are drawn in |
    | ``start_noise`` | 0.1 | start noise around the keyframe (0 to π) |
    | ``max_joint_speed`` | ``None`` | cartesian actions: joint speed limit (rad/s, m/s; per joint or one) per step |
    | ``render_mode`` | ``None`` | ``"rgb_array"``; ``"human"``: a window where a display exists (else a warning) |
    | ``width``, ``height`` | 480, 360 | frame size |

    Every argument is checked when the env is made: a bad one raises a one-line :class:`mjkin.InputError`
    naming it (numbers finite, sizes and tolerances positive, ``start_noise`` at most π, ``target_region``
    low < high on every axis, the ``table`` no higher than the arm's lowest moving body at home nor than the top
    of ``target_region``). A bad action (not numbers, another shape, NaN or inf) raises one at ``step``.

    ``max_joint_speed`` is a hard :class:`mjkin.goals.StepLimit` of ``max_joint_speed / render_fps``
    in each cartesian step's IK: no joint changes more than that from one step to the next.

    ## Version history
    v0: first version (goal-conditioned and pose variants, MuJoCo obstacles, reset options, sparse −1/0);
    a planar arm's cartesian actions keep to its plane (before, the part out of it was asked of the IK,
    which ended each step at the closest pose it could prove: the same pose, at several times the cost).
    """

    # gym.make reads the class's modes: with "human" listed it never wraps the env in pygame's HumanRendering;
    # an instance lists "human" only where a display exists (or it was asked for): gymnasium's checks open every
    # listed mode
    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 30}

    def __init__(self, model: str = "arm7", frame: str = "ee", action_type: str = "joint",
                 goal_type: str = "position", goal_conditioned: bool = False, step_size: float | None = None,
                 rot_step: float = 0.1, success_tol: float | None = None, rot_tol: float = 0.1,
                 success_bonus: float = 1.0, sparse: bool = False, collision_penalty: float = 0.0,
                 obstacles: Sequence[tuple[ArrayLike, float]] | None = None, table: float | None = None,
                 target_region: tuple[ArrayLike, ArrayLike] | None = None, start_noise: float = 0.1,
                 render_mode: str | None = None, width: int = 480, height: int = 360, site: str | None = None,
                 max_joint_speed: ArrayLike | None = None) -> None:
        if site is not None:  # the name before 0.2
            warnings.warn("ReachEnv(site=...) is now frame=...", DeprecationWarning, stacklevel=2)
            frame = site
        check_choice(render_mode, "render_mode", (None, "rgb_array", "human"))
        width, height = check_count(width, "width"), check_count(height, "height")
        self.task = ReachTask(model, frame, action_type, goal_type, step_size, rot_step, success_tol, rot_tol,
                              success_bonus, sparse, collision_penalty, obstacles, table, target_region, start_noise,
                              goal_conditioned, max_joint_speed, 1.0 / ReachEnv.metadata["render_fps"])
        t = self.task
        self.tree, self.frame, self.scene, self.home = t.tree, frame, t.scene, t.home
        self.action_type, self.goal_type, self.goal_conditioned = t.action_type, t.goal_type, t.goal_conditioned
        self.step_size, self.success_tol, self.rot_tol, self.extent = t.step_size, t.success_tol, t.rot_tol, t.extent
        self.action_space, self.observation_space = t.action_space, t.observation_space
        self.render_mode, self.width, self.height = render_mode, width, height
        human = has_display() or render_mode == "human"
        self.metadata = {**ReachEnv.metadata, "render_modes": ["rgb_array", "human"] if human else ["rgb_array"]}
        if render_mode == "human" and not has_display():
            warnings.warn("render_mode='human' needs a display; this machine has none, so nothing is shown "
                          "(use render_mode='rgb_array' for frames)", stacklevel=2)
        self.q = self.home.copy()
        self.target = t.achieved(self.q[None])[0][0]
        self._achieved, self._R = self.target.copy(), t.achieved(self.q[None])[1]  # R: (1, 3, 3) or None
        self._painter: Painter | None = None
        self._camera: Any = None
        # the target's ball: MARKER E in radius (arm7: 4.3 cm, PlanarReach: 0.9; a fixed 3 cm showed no pixel in the
        # planar arm's world 30 units wide), or the success tolerance when that is larger
        self._marker = Overlay(point_size=max(self.success_tol, MARKER * self.extent))

    # ------------------------------------------------------------------ state
    @property
    def site(self) -> str:
        """The effector frame (deprecated: use ``frame``)."""
        warnings.warn("env.site is now env.frame", DeprecationWarning, stacklevel=2)
        return self.frame

    def effector(self, q: Array | None = None) -> Array:
        """World position ``(3,)`` of the effector site at ``q`` (default: now)."""
        if q is None:
            return self._achieved[:3].copy()
        return self.task.achieved(self.tree.check_q(q).reshape(1, -1))[0][0, :3]

    def compute_reward(self, achieved_goal: ArrayLike, desired_goal: ArrayLike, info: Any) -> Any:
        """The step reward for goals ``(..., 3|7)`` (see the class docstring); batched over leading axes."""
        return self.task.compute_reward(achieved_goal, desired_goal, info)

    def compute_terminated(self, achieved_goal: ArrayLike, desired_goal: ArrayLike, info: Any) -> Any:
        """Whether the goals are met, batched like :meth:`compute_reward`."""
        return self.task.compute_terminated(achieved_goal, desired_goal, info)

    def compute_truncated(self, achieved_goal: ArrayLike, desired_goal: ArrayLike, info: Any) -> Any:
        """Never by the goals (the time limit truncates), batched like :meth:`compute_reward`."""
        return self.task.compute_truncated(achieved_goal, desired_goal, info)

    def _observe(self) -> Any:
        if self.goal_type == "position" and not self.goal_conditioned:  # the common case, without a batch axis
            return np.concatenate((self.q, self._achieved, self.target, self.target - self._achieved))
        obs = self.task.observe(self.q[None], self._achieved[None], self.target[None])
        return {k: v[0] for k, v in obs.items()} if self.goal_conditioned else obs[0]

    def _settle(self, q: Array) -> tuple[dict[str, Any], float]:
        """Make ``q (1, nq)`` current: one FK for the effector, MuJoCo for contacts; ``info`` and the reward."""
        achieved, R, _ = self.task.achieved(q)
        self.q, self._achieved, self._R = q[0], achieved[0], R
        out, reward = self.task.outcome(q, achieved, self.target[None])
        distance = float(out["distance"][0])
        info = {"distance": distance, "is_success": bool(out["is_success"][0]), "contacts": int(out["contacts"][0]),
                "in_collision": bool(out["in_collision"][0]), "reward_distance": -distance}
        if "angle" in out:
            info["angle"] = float(out["angle"][0])
        return info, float(reward[0])

    # ---------------------------------------------------------------- gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[Any, dict]:
        """Start an episode: a start near the home pose and a new target, or those in ``options``."""
        super().reset(seed=seed)
        q, self.target = self.task.start(self.np_random, options)
        info, _ = self._settle(q[None])
        return self._observe(), info

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        """Apply an action (see the class docstring); bad actions raise and change nothing."""
        a = check_action(action, self.action_space, "action")
        info, reward = self._settle(self.task.move(self.q[None], a[None], self._R, self._achieved[None]))
        return self._observe(), reward, info["is_success"], False, info

    def render(self) -> NDArray[np.uint8] | None:
        """An RGB frame with the target drawn (``rgb_array``); ``human`` shows it in a window where one exists.

        The target is a red ball of radius ``max(success_tol, 0.03 E)``; the arm is staged as :mod:`mjkin.render`
        stages every model (sky, checker floor, lights).
        """
        if self.render_mode is None or (self.render_mode == "human" and not has_display()):
            return None
        if self._painter is None:
            self._painter = Painter(self.tree, self.width, self.height)
        if self._camera is None:  # one camera for the whole workspace, so consecutive episodes make one video
            region = self.task.target_region
            reach = self.task.achieved(self.tree.random_q(0, 64))[0][:, :3] if region is None else \
                np.stack(region)  # where targets can be
            self._camera = default_camera(self.tree, self.home[None], reach)
        frame = self._painter.draw(self.q, self._camera, [self.target[:3]], overlay=self._marker)
        if self.render_mode == "human":  # pragma: no cover - needs a display
            show(frame, self.metadata["render_fps"])
            return None
        return frame

    def close(self) -> None:
        """Free the renderer."""
        if self._painter is not None:
            self._painter.close()
            self._painter = None

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_painter"] = None  # a GL context does not pickle; the copy makes its own
        return state


def show(frame: NDArray[np.uint8], fps: float) -> None:  # pragma: no cover - needs a display
    """Show a frame in a matplotlib window (warns once, shows nothing, when matplotlib is missing)."""
    try:
        import matplotlib.pyplot as plt
    except ImportError:
        warnings.warn("render_mode='human' needs matplotlib (pip install 'mjkin[plot]')", stacklevel=3)
        return
    plt.imshow(frame)
    plt.pause(1.0 / fps)
    plt.clf()


def ik_expert(env: ReachEnv) -> NDArray[np.float32]:
    """A scripted expert: the action that moves toward mjkin's IK solution for the current target.

    The solution is solved from ``qpos0``, not from the arm's pose, so every step of an episode aims at the
    same one: from a nearly straight arm, solves warm-started at each step can land on alternate elbow branches,
    and moving toward each in turn (the short way round, as solve wraps unlimited hinges) can cycle forever.
    With obstacles or a table (joint actions), each step is its own IK from the arm's pose instead: the goal
    with a hard :class:`~mjkin.goals.Clearance` of :data:`EXPERT_CLEARANCE` from every pair MuJoCo would collide
    and a :class:`~mjkin.goals.StepLimit` of one action, so every pose the expert steps to is clear.
    """
    p, target = env.effector(), env.target
    if env.action_type == "cartesian":
        step = (target[:3] - p) / env.step_size
        if env.goal_type == "pose":
            R_t = spatial.quat_to_mat(target[3:])
            R = spatial.quat_to_mat(env._achieved[3:])
            step = np.concatenate([step, spatial.mat_to_rotvec(R_t @ R.T) / env.task.rot_step])
        return np.clip(step, -1, 1).astype(np.float32)
    if env.goal_type == "pose":
        T = spatial.make_transform(spatial.quat_to_mat(target[3:]), target[:3])
        goal: G.Goal = G.Pose(env.frame, T)
    else:
        goal = G.Position(env.frame, target)
    if env.task.cluttered:  # a step at a time, each kept clear: a straight line to a far answer may cut an obstacle
        goals = [goal, G.Clearance(EXPERT_CLEARANCE), G.StepLimit(env.q, env.step_size)]
        res = env.task.expert_problem(goals).solve(env.q, goals)
    else:
        res = env.task.expert_problem([goal]).solve(env.tree.qpos0, [goal])
    step = env.tree.difference(res.q, env.q, periodic=True)  # unlimited hinges the short way round
    return np.clip(step / env.step_size, -1, 1).astype(np.float32)
