"""The reach task as batched array functions, shared by the single env and the native vector env.

Everything here takes a leading batch axis ``B``: configurations ``q (B, nq)``,
actions ``(B, n_act)``, goals ``(B, 3)`` (position) or ``(B, 7)`` (pose
``[x, y, z, qw, qx, qy, qz]``, ``qw >= 0``). The single env calls it with
``B = 1``, the vector env with ``B = num_envs``, so both compute the same
numbers the same way.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from gymnasium import spaces
from numpy.typing import ArrayLike, NDArray

import mjkin
from mjkin import goals as G
from mjkin import spatial
from mjkin.kinematics.frames import Frames, forward
from mjkin.kinematics.tree import bundled_models
from mjkin.motion.follow import speed_step
from mjkin.runtime.checks import check_choice, check_flag, check_number, shown
from mjkin.runtime.jit import njit
from mjkin.scene import Scene

Array = NDArray[np.float64]

START_NOISE_MAX = np.pi  # rad (or m): ±π reaches every angle of a hinge; wider noise is clipped into limits anyway
OBSTACLE_RGBA = (0.85, 0.25, 0.2, 0.6)
TABLE_RGBA = (0.55, 0.42, 0.3, 1.0)


@njit
def joint_move(q: Array, a: Array, step: float, lo: Array, hi: Array, wrap: NDArray[np.bool_], out: Array) -> None:
    """``out = q + clip(a, -1, 1) * step`` (``(B, nq)``) clipped into ``[lo, hi]``; ``wrap`` entries into [-π, π)."""
    for b in range(q.shape[0]):
        for i in range(q.shape[1]):
            x = q[b, i] + min(max(a[b, i], -1.0), 1.0) * step
            if wrap[i]:
                x = (x + np.pi) % (2.0 * np.pi) - np.pi
            out[b, i] = min(max(x, lo[i]), hi[i])


@njit
def site_points(rot: Array, pos: Array, body: int, o: Array, out: Array) -> None:
    """``out (B, 3)``: the point ``o`` of ``body`` in the world, from body frames ``rot (B, nbody, 3, 3)``, ``pos``."""
    for b in range(rot.shape[0]):
        for i in range(3):
            out[b, i] = pos[b, body, i] + (rot[b, body, i, 0] * o[0] + rot[b, body, i, 1] * o[1]
                                           + rot[b, body, i, 2] * o[2])


@njit
def goal_measures(achieved: Array, desired: Array, hit: Array, tol: float, rot_tol: float, bonus: float,
                  penalty: float, sparse: bool, distance: Array, angle: Array, ok: NDArray[np.bool_],
                  reward: Array) -> None:
    """Per row of goals ``(B, 3|7)``: distance, angle, success and reward (the env docstring's formulas)."""
    for b in range(achieved.shape[0]):
        dx, dy, dz = desired[b, 0] - achieved[b, 0], desired[b, 1] - achieved[b, 1], desired[b, 2] - achieved[b, 2]
        d2, big = dx * dx + dy * dy + dz * dz, max(abs(dx), abs(dy), abs(dz))
        if d2 == np.inf and big < np.inf:  # squares past 1.8e308 (a target 1e300 m away): scaled, a finite distance
            distance[b] = big * np.sqrt((dx / big) ** 2 + (dy / big) ** 2 + (dz / big) ** 2)
        else:
            distance[b] = np.sqrt(d2)
        angle[b] = 0.0
        if achieved.shape[1] == 7:
            dot = abs(achieved[b, 3] * desired[b, 3] + achieved[b, 4] * desired[b, 4]
                      + achieved[b, 5] * desired[b, 5] + achieved[b, 6] * desired[b, 6])
            angle[b] = 2.0 * np.arccos(min(dot, 1.0))
        ok[b] = distance[b] < tol and (achieved.shape[1] == 3 or angle[b] < rot_tol)
        success = 1.0 if ok[b] else 0.0
        if sparse:
            reward[b] = success - 1.0
        else:
            reward[b] = bonus * success - (distance[b] + (tol / rot_tol) * angle[b])
        if penalty != 0.0:
            reward[b] -= penalty * hit[b]


def model_spec(model: str, obstacles: Sequence[tuple[Array, float]], table: float | None,
               extent: float) -> mujoco.MjSpec | str:
    """The model with obstacle spheres (and a table top at height ``table``) added as world geoms through MjSpec."""
    if not obstacles and table is None:
        return model
    bundled = bundled_models()
    if Path(model).is_file() or model in bundled:
        spec = mujoco.MjSpec.from_file(str(bundled.get(model, Path(model)) if model in bundled else model))
    else:
        spec = mujoco.MjSpec.from_string(model)
    world = spec.worldbody
    for i, (center, radius) in enumerate(obstacles):
        world.add_geom(name=f"obstacle{i}", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[radius, 0, 0], pos=center,
                       rgba=OBSTACLE_RGBA, contype=1, conaffinity=1)
    if table is not None:
        world.add_geom(name="table", type=mujoco.mjtGeom.mjGEOM_BOX, size=[extent, extent, 0.02 * extent],
                       pos=[0.0, 0.0, table - 0.02 * extent], rgba=TABLE_RGBA, contype=1, conaffinity=1)
    return spec


def motion_plane(tree: mjkin.Tree, frame: str, samples: int = 8) -> tuple[Array | None, bool]:
    """The plane a planar arm's ``frame`` moves in: its unit normal ``(3,)`` (else None), and whether it turns about it.

    From the frame's Jacobian at ``samples`` random configurations (seeded): the origin
    is planar when the linear columns span a plane (rank 2 to 1e-9 of the largest
    singular value); it turns about the normal only when every angular column is along it.
    """
    J = tree.jacobian(tree.random_q(np.random.default_rng(0), samples), frame)  # (samples, 6, nv)
    u, s, _ = np.linalg.svd(np.moveaxis(J[:, :3], 1, 0).reshape(3, -1))
    if not s[2] <= 1e-9 * s[0]:
        return None, False
    n = u[:, 2]
    angular = np.moveaxis(J[:, 3:], 1, 0).reshape(3, -1)
    return n, bool(np.abs(angular - np.outer(n, n @ angular)).max() <= 1e-9 * max(np.abs(angular).max(), 1.0))


def info_column(info: Any, key: str) -> Array:
    """``info[key]`` as an array over the batch, from a dict, a dict of arrays, or a list/array of dicts."""
    if isinstance(info, Mapping):
        return np.asarray(info[key])
    return np.array([i[key] for i in np.ravel(np.asarray(info, dtype=object))])


class ReachTask:
    """The reach task's constants and its batched math (see :class:`mjkin.envs.ReachEnv` for the meaning)."""

    def __init__(self, model: str, frame: str, action_type: str, goal_type: str, step_size: float | None,
                 rot_step: float, success_tol: float | None, rot_tol: float, success_bonus: float, sparse: bool,
                 collision_penalty: float, obstacles: Sequence[tuple[ArrayLike, float]] | None,
                 table: float | None, target_region: tuple[ArrayLike, ArrayLike] | None, start_noise: float,
                 goal_conditioned: bool, max_joint_speed: ArrayLike | None = None, dt: float = 1.0 / 30) -> None:
        self.action_type = check_choice(action_type, "action_type", ("joint", "cartesian"))
        self.goal_type = check_choice(goal_type, "goal_type", ("position", "pose"))
        self.goal_conditioned = check_flag(goal_conditioned, "goal_conditioned")
        self.sparse = check_flag(sparse, "sparse")
        self.rot_step = check_number(rot_step, "rot_step", 0.0, strict=True)
        self.rot_tol = check_number(rot_tol, "rot_tol", 0.0, strict=True)
        self.success_bonus = check_number(success_bonus, "success_bonus", 0.0)
        self.collision_penalty = check_number(collision_penalty, "collision_penalty", 0.0)
        self.start_noise = check_number(start_noise, "start_noise", 0.0)
        if self.start_noise > START_NOISE_MAX:
            raise mjkin.InputError(f"start_noise must be a finite number from 0 to pi ({START_NOISE_MAX:.6g}) rad "
                                   f"(or m), got {shown(start_noise)}")
        self.table = None if table is None else check_number(table, "table")
        self.obstacles = check_obstacles(obstacles)
        self.target_region = None if target_region is None else check_region(target_region)
        if step_size is not None:
            check_number(step_size, "step_size", 0.0, strict=True)
        if success_tol is not None:
            check_number(success_tol, "success_tol", 0.0, strict=True)
        if not isinstance(model, (str, os.PathLike)):
            raise mjkin.InputError(f"model must be a bundled model name, an MJCF path or an XML string, "
                                   f"not {shown(model)}")
        base = mjkin.load(model)
        extent = float(base.model.stat.extent) or 1.0
        self.tree = mjkin.load(model_spec(model, self.obstacles, table, extent)) \
            if self.obstacles or table is not None else base
        if not isinstance(frame, str):
            raise mjkin.InputError(f"frame must be a site or body name (a string), not {shown(frame)}")
        self.frame = frame
        self.site_kind, self.site_id = self.tree.frame(frame)  # unknown names fail here, with the list of names
        body, r, o = self.tree.kinematics(self.tree.qpos0).local_frame(self.site_kind, self.site_id)
        self.site_local = (body, np.array(r), np.array(o))  # writable copies: one compiled signature
        self._move: mjkin.Problem | None = None  # the cartesian step's IK, made at the first step
        # a planar arm's cartesian actions keep to its plane (and its rotations to the plane's normal)
        self.plane, self.plane_turns = motion_plane(self.tree, frame) if action_type == "cartesian" else (None, False)
        # the largest joint change per step (njnt,) at max_joint_speed, or None
        self.max_step = None if max_joint_speed is None else speed_step(self.tree, max_joint_speed, 1.0 / dt)
        self._expert: dict[tuple[str, ...], mjkin.Problem] = {}
        self.extent = extent
        self.step_size = float(step_size if step_size is not None else
                               (0.1 if action_type == "joint" else 0.05 * extent))
        self.success_tol = float(success_tol if success_tol is not None else 0.02 * extent)
        m = self.tree.model
        self.home = m.key_qpos[0].copy() if m.nkey else self.tree.qpos0.copy()
        if self.table is not None:
            self._check_table(self.table)
        self.scene = Scene(self.tree)
        self.goal_dim = 3 if goal_type == "position" else 7
        lay = self.tree.layout
        # hinges and slides only (every arm here): q arithmetic is a sum and a clip
        self.scalar = self.tree.nq == self.tree.nv == len(lay.scalar_q)
        self.wrap = lay.scalar_q[lay.scalar_hinge & ~np.isfinite(lay.scalar_hi)]  # unlimited hinges
        self.wrap_mask = np.isin(np.arange(self.tree.nq), self.wrap)
        self.q_lo, self.q_hi = self._q_bounds()
        self.spaces()

    def _check_table(self, table: float) -> None:
        """The table top must leave the arm's lowest moving body (at home) and the target region above it."""
        moving = np.flatnonzero(self.tree.model.body_dofnum > 0)
        z = self.tree.kinematics(self.home[None]).pos[0, moving, 2]
        low = int(np.argmin(z))
        if table > z[low]:
            name = self.tree.model.body(int(moving[low])).name
            raise mjkin.InputError(f"table must be at most {z[low]:.6g} (the height of the arm's lowest moving body "
                                   f"{name!r} at home), got {table!r}")
        if self.target_region is not None and self.target_region[1][2] < table:
            raise mjkin.InputError(f"target_region must reach above the table: its high z is "
                                   f"{self.target_region[1][2]:g}, the table is at {table:g}")

    # --------------------------------------------------------------- spaces
    def _q_bounds(self) -> tuple[Array, Array]:
        lay, e = self.tree.layout, self.extent
        lo, hi = np.full(self.tree.nq, -1.0), np.full(self.tree.nq, 1.0)  # quaternions
        lo[lay.scalar_q] = np.where(np.isfinite(lay.scalar_lo), lay.scalar_lo, -10 * e)
        hi[lay.scalar_q] = np.where(np.isfinite(lay.scalar_hi), lay.scalar_hi, 10 * e)
        lo[self.wrap], hi[self.wrap] = -np.pi, np.pi
        lo[lay.free_q[:, :3].ravel()], hi[lay.free_q[:, :3].ravel()] = -10 * e, 10 * e
        return lo, hi

    def spaces(self) -> None:
        """Set ``action_space`` and ``observation_space`` (bounds in the env docstring)."""
        pose = self.goal_type == "pose"
        n_act = self.tree.nv if self.action_type == "joint" else (6 if pose else 3)
        self.action_space = spaces.Box(-1.0, 1.0, (n_act,), dtype=np.float32)
        far = 4.0 * self.extent
        g_lo = np.concatenate([np.full(3, -far), [0.0, -1, -1, -1]])[:self.goal_dim]
        g_hi = np.concatenate([np.full(3, far), np.ones(4)])[:self.goal_dim]
        err = np.concatenate([np.full(3, 2 * far), np.full(3, np.pi)])[:3 if not pose else 6]
        self.observation_space: spaces.Space
        if self.goal_conditioned:
            goal = spaces.Box(g_lo, g_hi, dtype=np.float64)
            self.observation_space = spaces.Dict({"observation": spaces.Box(self.q_lo, self.q_hi, dtype=np.float64),
                                                  "achieved_goal": goal, "desired_goal": goal})
        else:
            self.observation_space = spaces.Box(np.concatenate([self.q_lo, g_lo, g_lo, -err]),
                                                np.concatenate([self.q_hi, g_hi, g_hi, err]), dtype=np.float64)

    # ------------------------------------------------------------ kinematics
    def achieved(self, q: Array) -> tuple[Array, Array | None, Frames]:
        """One FK: the effector goal ``(B, 3|7)`` at ``q (B, nq)``, its world rotation ``(B, 3, 3)``, all frames.

        The rotation is computed for pose goals only (cartesian pose actions and the quaternion need it);
        the frames serve the contact check.
        """
        frames = forward(self.tree, q)  # q is valid: the env made it, or checked it
        body, r, o = self.site_local
        p = np.empty((len(q), 3))
        site_points(frames.rot, frames.pos, body, o, p)
        if self.goal_type == "position":
            return p, None, frames
        R = frames.rot[:, body] @ r
        quat = spatial.mat_to_quat(R)
        quat *= np.where(quat[:, :1] < 0, -1.0, 1.0)
        return np.concatenate([p, quat], axis=1), R, frames

    def tidy(self, q: Array) -> Array:
        """``q (B, nq)`` clipped into the limits, unlimited hinges wrapped into [-π, π]."""
        if self.scalar:
            out = np.empty_like(q)
            joint_move(q, np.zeros_like(q), 0.0, self.q_lo, self.q_hi, self.wrap_mask, out)
            return out
        q = self.tree.clip(q)
        if len(self.wrap):
            q[:, self.wrap] = np.remainder(q[:, self.wrap] + np.pi, 2 * np.pi) - np.pi
        return q

    def move(self, q: Array, action: Array, R: Array | None, achieved: Array) -> Array:
        """The configurations ``(B, nq)`` after actions ``(B, n_act)`` in [-1, 1] (clipped) from ``q``."""
        if self.action_type == "joint" and self.scalar:
            out = np.empty_like(q)
            joint_move(q, action, self.step_size, self.q_lo, self.q_hi, self.wrap_mask, out)
            return out
        a = np.minimum(np.maximum(action, -1.0), 1.0)
        if self.action_type == "joint":
            return self.tidy(self.tree.integrate(q, a * self.step_size))
        d = a[:, :3] * self.step_size
        if self.plane is not None:  # what leaves the plane the effector moves in: no IK step can follow it
            d = d - np.outer(d @ self.plane, self.plane)
        p = achieved[:, :3] + d
        if self.goal_type == "position":
            goal: G.Goal = G.Position(self.frame, p)
        else:  # a twist: translation, then rotation vector in world axes
            assert R is not None
            w = a[:, 3:] * self.rot_step
            if self.plane is not None and self.plane_turns:
                w = np.outer(w @ self.plane, self.plane)
            T = np.zeros((len(q), 4, 4))
            T[:, :3, :3] = spatial.rotvec_to_mat(w) @ R
            T[:, :3, 3], T[:, 3, 3] = p, 1.0
            goal = G.Pose(self.frame, T)
        goals = [goal] if self.max_step is None else [goal, G.StepLimit(q, self.max_step)]
        if self._move is None:
            self._move = mjkin.Problem(self.tree, goals, max_iters=30, restarts=0)
        return self.tidy(self._move.solve(q, goals).q.reshape(q.shape))

    @property
    def cluttered(self) -> bool:
        """The world has obstacles or a table."""
        return bool(self.obstacles) or self.table is not None

    def expert_problem(self, goals: Sequence[G.Goal]) -> mjkin.Problem:
        """The IK problem of the expert's goals (made once per goal structure; a local one takes no restarts)."""
        key = tuple(type(g).__name__ for g in goals)
        if key not in self._expert:
            local: dict[str, Any] = {"restarts": 0, "max_iters": 30} if len(goals) > 1 else {}
            self._expert[key] = mjkin.Problem(self.tree, list(goals), tol=0.1 * self.success_tol,
                                              rot_tol=0.1 * self.rot_tol, **local)
        return self._expert[key]

    # -------------------------------------------------------------- measures
    def measure(self, achieved: Array, desired: Array, hit: Array) -> tuple[Array, Array, NDArray[np.bool_], Array]:
        """Distance ``(B,)`` (m), angle ``(B,)`` (rad, 0 for positions), success and reward for goals ``(B, 3|7)``.

        ``hit (B,)``: in collision (used when ``collision_penalty`` is set). One compiled loop, shared by
        ``step`` and :meth:`compute_reward`, so both give the same numbers.
        """
        B = achieved.shape[0]
        distance, angle, reward = np.empty(B), np.empty(B), np.empty(B)
        ok = np.empty(B, dtype=np.bool_)
        goal_measures(achieved, desired, hit, self.success_tol, self.rot_tol, self.success_bonus,
                      self.collision_penalty, self.sparse, distance, angle, ok, reward)
        return distance, angle, ok, reward

    def goals(self, achieved_goal: ArrayLike, desired_goal: ArrayLike) -> tuple[Array, Array]:
        """The goal-env methods' goals as arrays: the same shape ``(..., 3|7)``, finite; else a one-line error."""
        want = f"(..., {self.goal_dim}) for goal_type={self.goal_type!r}"
        try:
            achieved = np.asarray(achieved_goal, dtype=np.float64)
            desired = np.asarray(desired_goal, dtype=np.float64)
        except (TypeError, ValueError):
            raise mjkin.InputError(f"achieved_goal and desired_goal must be arrays of numbers {want}, got "
                                   f"{shown(achieved_goal, 40)} and {shown(desired_goal, 40)}") from None
        if achieved.shape != desired.shape or achieved.shape[-1:] != (self.goal_dim,):
            raise mjkin.InputError(f"achieved_goal and desired_goal must have one shape {want}, got "
                                   f"{achieved.shape} and {desired.shape}")
        if not (np.isfinite(achieved).all() and np.isfinite(desired).all()):
            raise mjkin.InputError("achieved_goal and desired_goal must be finite; they contain NaN or inf")
        return achieved, desired

    def _flat(self, achieved_goal: ArrayLike, desired_goal: ArrayLike, info: Any
              ) -> tuple[tuple[int, ...], tuple[Array, Array, NDArray[np.bool_], Array]]:
        """Measures of goals with any leading shape, flattened; and that shape."""
        achieved, desired = self.goals(achieved_goal, desired_goal)
        shape = achieved.shape[:-1]
        a = np.ascontiguousarray(achieved).reshape(-1, self.goal_dim)
        d = np.ascontiguousarray(desired).reshape(-1, self.goal_dim)
        hit = np.zeros(len(a)) if not self.collision_penalty else self._hit(info, shape)
        return shape, self.measure(a, d, hit)

    def _hit(self, info: Any, shape: tuple[int, ...]) -> Array:
        """``info``'s ``in_collision`` for goals of leading ``shape``, flat, as floats."""
        try:
            return np.broadcast_to(info_column(info, "in_collision"), shape).reshape(-1).astype(np.float64)
        except (KeyError, TypeError, ValueError, IndexError):
            raise mjkin.InputError(f"info must give 'in_collision' for goals of batch shape {shape} (collision_penalty "
                                   f"is set), got {shown(info, 60)}") from None

    def compute_reward(self, achieved_goal: ArrayLike, desired_goal: ArrayLike, info: Any) -> Array | float:
        """Reward for goals ``(..., 3|7)``; ``info`` supplies ``in_collision`` when a collision penalty is set."""
        shape, (_, _, _, reward) = self._flat(achieved_goal, desired_goal, info)
        return float(reward[0]) if shape == () else reward.reshape(shape)

    def compute_terminated(self, achieved_goal: ArrayLike, desired_goal: ArrayLike, info: Any) -> Any:
        """An episode ends when the goal is met (both tolerances)."""
        shape, (_, _, ok, _) = self._flat(achieved_goal, desired_goal, info)
        return bool(ok[0]) if shape == () else ok.reshape(shape)

    def compute_truncated(self, achieved_goal: ArrayLike, desired_goal: ArrayLike, info: Any) -> Any:
        """Never by the goals; the time limit truncates."""
        shape = self.goals(achieved_goal, desired_goal)[0].shape[:-1]
        return False if shape == () else np.zeros(shape, dtype=bool)

    def contacts(self, q: Array, frames: Frames | None = None) -> NDArray[np.int64]:
        """MuJoCo contacts ``(B,)`` at valid ``q (B, nq)`` (adjacent bodies excluded).

        Given the FK ``frames`` of ``q`` and more than a few envs, configurations whose geoms are
        all apart skip MuJoCo (the same counts, less work); one env is cheaper without.
        """
        return self.scene.counts(q, frames if len(q) > 4 else None)

    def outcome(self, q: Array, achieved: Array, desired: Array,
                frames: Frames | None = None) -> tuple[dict[str, NDArray], Array]:
        """Per-env ``info`` arrays ``(B,)`` (distance, is_success, contacts, in_collision[, angle]) and rewards."""
        contacts = self.contacts(q, frames)
        hit = contacts > 0
        distance, angle, ok, reward = self.measure(achieved, desired, hit.astype(np.float64))
        out: dict[str, NDArray] = {"distance": distance, "is_success": ok, "contacts": contacts, "in_collision": hit}
        if self.goal_dim == 7:
            out["angle"] = angle
        return out, reward

    def observe(self, q: Array, achieved: Array, desired: Array) -> Any:
        """Observations of a batch: ``(B, n_obs)``, or a dict of such arrays when goal-conditioned."""
        if self.goal_conditioned:
            return {"observation": q.copy(), "achieved_goal": achieved.copy(), "desired_goal": desired.copy()}
        err = desired[:, :3] - achieved[:, :3]
        if self.goal_type == "pose":
            R_a = spatial.quat_to_mat(achieved[:, 3:])
            R_d = spatial.quat_to_mat(desired[:, 3:])
            err = np.concatenate([err, spatial.mat_to_rotvec(R_d @ np.swapaxes(R_a, -1, -2))], axis=1)
        return np.concatenate([q, achieved, desired, err], axis=1)

    # ----------------------------------------------------------------- start
    def start(self, rng: np.random.Generator, options: Mapping[str, Any] | None) -> tuple[Array, Array]:
        """An episode's start ``q (nq,)`` and goal ``(3|7,)``: from ``options`` or drawn from ``rng``."""
        options = dict(options or {})
        unknown = set(options) - {"q", "target"}
        if unknown:
            raise mjkin.InputError(f"reset options are 'q' and 'target', not {sorted(unknown)}")
        if options.get("q") is not None:
            q = self.tidy(self.tree.check_q(options["q"], "options['q']").reshape(1, -1).copy())[0]
        else:
            noise = rng.uniform(-self.start_noise, self.start_noise, self.tree.nv)
            q = self.tidy(self.tree.integrate(self.home, noise)[None])[0]
        if options.get("target") is not None:
            return q, self.goal(options["target"])
        return q, self.sample_goal(rng)

    def goal(self, target: ArrayLike) -> Array:
        """A user's target: ``(3,)`` position, or for pose goals ``(7,)`` position + quaternion (normalised)."""
        g = _vector(target, self.goal_dim, "options['target']" + (" [x, y, z, qw, qx, qy, qz]"
                                                                    if self.goal_dim == 7 else " [x, y, z]"))
        if self.goal_dim == 7:
            g[3:] = spatial.quat_normalize(g[3:]) * (1.0 if g[3] >= 0 else -1.0)
        return g

    def sample_goal(self, rng: np.random.Generator) -> Array:
        """The effector goal of a random in-limit, collision-free configuration (so always reachable)."""
        for _ in range(1000):
            q = self.tree.random_q(rng)[None]
            goal = self.achieved(q)[0][0]
            p = goal[:3]
            inside = self.target_region is None or bool(np.all((p >= self.target_region[0])
                                                               & (p <= self.target_region[1])))
            if inside and all(np.linalg.norm(p - c) > r for c, r in self.obstacles) \
                    and not self.contacts(q)[0]:
                return goal
        region = None if self.target_region is None else [side.tolist() for side in self.target_region]
        raise mjkin.InputError(f"no reachable, collision-free target found in 1000 draws inside target_region="
                               f"{region}, above table={self.table} and outside the "
                               f"{len(self.obstacles)} obstacles; widen target_region or move the obstacles")


def check_action(action: Any, space: spaces.Space[Any], what: str) -> Array:
    """``action`` as a finite float64 array of ``space``'s shape; else a one-line error naming ``what``, the space."""
    def want() -> str:  # made only for an error: str(dtype) alone costs more than the checks (~10 µs)
        return f"{what} must be an array of numbers of shape {space.shape}, dtype {space.dtype} (the action space)"

    try:
        raw = np.asarray(action)
    except (TypeError, ValueError):  # ragged nested lists
        raise mjkin.InputError(f"{want()}, got {shown(action)}") from None
    if raw.dtype.kind not in "biuf":  # strings, None, objects: numpy would parse "1" as 1 or fail with its own error
        raise mjkin.InputError(f"{want()}, got {shown(action)}")
    if raw.shape != space.shape:
        raise mjkin.InputError(f"{want()}, got shape {raw.shape}")
    a = raw.astype(np.float64)
    if not np.isfinite(a).all():
        raise mjkin.InputError(f"{what} must be finite; it contains NaN or inf")
    return a


# m: MuJoCo's mjMAXVAL, the bound of an obstacle's centre coordinates and radius (MuJoCo's collision of a sphere
# 1e300 m across, 1e300 m away, fails: "mju_makeFrame: xaxis of contact frame undefined")
OBSTACLE_REACH = 1e10


def check_obstacles(obstacles: Any) -> list[tuple[Array, float]]:
    """``obstacles``: None or a list of ``(center [x, y, z], radius > 0)`` pairs, within :data:`OBSTACLE_REACH`."""
    if obstacles is None:
        return []
    if isinstance(obstacles, (str, bytes, Mapping)) or not isinstance(obstacles, (Sequence, np.ndarray)):
        raise mjkin.InputError(f"obstacles must be a list of (center [x, y, z], radius) pairs, got {shown(obstacles)}")
    out = []
    for i, item in enumerate(obstacles):
        try:
            center, radius = item
        except (TypeError, ValueError):
            raise mjkin.InputError(f"obstacles[{i}] must be a (center [x, y, z], radius) pair, got {shown(item)} "
                                   "(obstacles is a list of such pairs)") from None
        c, r = _vector(center, 3, f"obstacles[{i}] center"), check_number(radius, f"obstacles[{i}] radius", 0.0,
                                                                          strict=True)
        if np.abs(c).max() > OBSTACLE_REACH or r > OBSTACLE_REACH:
            raise mjkin.InputError(f"obstacles[{i}] must have its center's coordinates and its radius within "
                                   f"{OBSTACLE_REACH:g} m (MuJoCo's largest value), got center {c.tolist()}, "
                                   f"radius {r:g}")
        out.append((c, r))
    return out


def check_region(region: Any) -> tuple[Array, Array]:
    """``target_region``: a ``(low [x, y, z], high [x, y, z])`` box with low < high on every axis."""
    try:
        low, high = region
    except (TypeError, ValueError):
        raise mjkin.InputError(f"target_region must be a (low [x, y, z], high [x, y, z]) pair, "
                               f"got {shown(region)}") from None
    lo, hi = _vector(low, 3, "target_region low"), _vector(high, 3, "target_region high")
    bad = [axis for axis, a, b in zip("xyz", lo, hi, strict=True) if not a < b]
    if bad:
        raise mjkin.InputError(f"target_region low must be below high on every axis, not on {', '.join(bad)}: "
                               f"low {lo.tolist()}, high {hi.tolist()}")
    return lo, hi


def _vector(value: ArrayLike, n: int, what: str) -> Array:
    """``value`` as a finite ``(n,)`` array; else a one-line error naming ``what``."""
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise mjkin.InputError(f"{what} must be {n} numbers, got {shown(value)}") from None
    if a.shape != (n,) or not np.isfinite(a).all():
        raise mjkin.InputError(f"{what} must be {n} finite numbers, got {shown(value)}")
    return a
