"""The gymnasium reach environments: gymnasium's checks, seeding, goal-env contract, vector envs, the expert."""

from __future__ import annotations

import pickle
import re
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from hypothesis import given, settings
from hypothesis import strategies as st

import mjkin
import mjkin.envs
from conftest import ROOT
from mjkin import spatial
from mjkin.envs import ReachVectorEnv, ik_expert

IDS = list(mjkin.envs.IDS)
VARIANTS = [{}, {"action_type": "cartesian"}, {"goal_type": "pose"}, {"goal_conditioned": True},
            {"goal_conditioned": True, "goal_type": "pose", "action_type": "cartesian", "sparse": True},
            {"obstacles": [([0.3, 0.3, 0.5], 0.1)], "table": 0.0, "collision_penalty": 1.0}]


def variant_id(kw):
    return ",".join(f"{k}={v}" for k, v in kw.items() if k != "obstacles") or "default"


@pytest.mark.parametrize("kwargs", VARIANTS, ids=variant_id)
@pytest.mark.parametrize("env_id", IDS)
def test_check_env_without_warnings(env_id, kwargs):
    env = gym.make(env_id, render_mode="rgb_array", width=160, height=120, **kwargs)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)
    frame = env.unwrapped.render()
    assert frame.shape == (120, 160, 3) and frame.std() > 5
    env.close()


@pytest.mark.parametrize("kwargs", [{}, VARIANTS[4]], ids=variant_id)
@pytest.mark.parametrize("env_id", IDS)
def test_same_seed_same_rollout(env_id, kwargs):
    def rollout(seed):
        env = gym.make(env_id, **kwargs)
        obs, _ = env.reset(seed=seed)
        env.action_space.seed(seed)
        out = [gym.spaces.flatten(env.observation_space, obs)]
        for _ in range(10):
            out.append(gym.spaces.flatten(env.observation_space, env.step(env.action_space.sample())[0]))
        return np.array(out)

    np.testing.assert_array_equal(rollout(3), rollout(3))
    assert not np.array_equal(rollout(3), rollout(4))


@pytest.mark.parametrize("env_id", IDS)
def test_pickle_round_trip_continues_identically(env_id):
    env = gym.make(env_id, goal_type="pose").unwrapped
    env.reset(seed=0)
    copy = pickle.loads(pickle.dumps(env))
    action = env.action_space.sample()
    a, b = env.step(action), copy.step(action)
    np.testing.assert_array_equal(a[0], b[0])
    assert a[1:4] == b[1:4] and a[4] == b[4]


def expert_episodes(env, seeds, check=lambda info: None) -> int:
    """Episodes the scripted expert wins, one per seed (at most 100 steps each)."""
    wins = 0
    for episode in seeds:
        env.reset(seed=episode)
        for _ in range(100):
            _, _, term, trunc, info = env.step(ik_expert(env.unwrapped))
            if term or trunc:
                break
        wins += info["is_success"]
        check(info)
    return wins


@pytest.mark.parametrize("env_id", IDS[:2])
def test_expert_solves_almost_every_episode(env_id):
    wins = expert_episodes(gym.make(env_id), range(200))
    assert wins >= 198, wins


@pytest.mark.parametrize("kwargs", [{"goal_type": "pose"}, {"goal_type": "pose", "action_type": "cartesian"}],
                         ids=variant_id)
def test_expert_meets_pose_goals_on_the_panda(kwargs):
    env = gym.make("mjkin/PandaReach-v0", **kwargs)

    def check(info):
        assert not info["is_success"] or (info["distance"] < env.unwrapped.success_tol and info["angle"] < 0.1)

    wins = expert_episodes(env, range(20), check)
    # the greedy cartesian expert moves in a straight line and can stall at a joint limit; the joint one cannot
    assert wins >= (19 if kwargs.get("action_type") != "cartesian" else 15), wins


def test_bad_actions_raise_and_change_nothing():
    env = gym.make("mjkin/Reach-v0").unwrapped
    env.reset(seed=0)
    before = env.q.copy()
    for bad in (np.full(7, np.nan), np.zeros(3), np.zeros((7, 1))):
        with pytest.raises(mjkin.InputError, match="action"):
            env.step(bad)
    np.testing.assert_array_equal(env.q, before)


@pytest.mark.parametrize("vector", [False, True], ids=["single", "vector"])
@pytest.mark.parametrize("bad", ["a string", None, ["0"] * 7, [[0.0], [0.0, 0.0]], {"a": 1}, np.zeros(7, complex)],
                         ids=["string", "None", "strings", "ragged", "dict", "complex"])
def test_a_non_numeric_action_raises_one_line_naming_the_action_space(bad, vector):
    env = gym.make_vec("mjkin/Reach-v0", 2, vectorization_mode="vector_entry_point") if vector else \
        gym.make("mjkin/Reach-v0").unwrapped
    env.reset(seed=0)
    before = env.q.copy()
    want = r"^actions? must be an array of numbers of shape " + (r"\(2, 7\)" if vector else r"\(7,\)")
    with pytest.raises(mjkin.InputError, match=want + r", dtype float32 \(the action space\), got ") as err:
        env.step(bad)
    assert isinstance(err.value, ValueError) and "\n" not in str(err.value)  # gymnasium's kind for a bad action
    np.testing.assert_array_equal(env.q, before)


def test_observation_layout_reward_and_info():
    env = gym.make("mjkin/Reach-v0", sparse=True).unwrapped
    obs, info = env.reset(seed=1)
    ee = env.tree.pose(obs[:7], "ee")[:3, 3]
    np.testing.assert_allclose(obs[7:10], ee, atol=1e-12)
    np.testing.assert_allclose(obs[13:16], obs[10:13] - obs[7:10], atol=1e-12)
    _, reward, _, _, info = env.step(np.zeros(7, np.float32))
    assert reward == -1.0 and info["distance"] > env.success_tol and not info["is_success"]
    assert {"distance", "is_success", "contacts", "in_collision", "reward_distance"} <= set(info)
    dense = gym.make("mjkin/Reach-v0").unwrapped
    dense.reset(seed=1)
    _, reward, _, _, info = dense.step(np.zeros(7, np.float32))
    assert reward == pytest.approx(-info["distance"], abs=1e-15)


def test_pose_observation_and_success_need_both_tolerances():
    env = gym.make("mjkin/Reach-v0", goal_type="pose").unwrapped
    obs, _ = env.reset(seed=2)
    q = obs[:7]
    T = env.tree.pose(q, "ee")
    achieved = obs[7:14]
    np.testing.assert_allclose(achieved[:3], T[:3, 3], atol=1e-12)
    np.testing.assert_allclose(spatial.quat_to_mat(achieved[3:]), T[:3, :3], atol=1e-12)
    assert achieved[3] >= 0
    R_err = spatial.rotvec_to_mat(obs[24:27]) @ T[:3, :3]
    np.testing.assert_allclose(R_err, spatial.quat_to_mat(obs[17:21]), atol=1e-9)
    np.testing.assert_allclose(obs[21:24], obs[14:17] - obs[7:10], atol=1e-12)
    # the target exactly at the effector, turned by 0.3 rad: in place but not a success
    turned = spatial.quat_mul(spatial.quat_from_axis_angle([0, 0, 1], 0.3), achieved[3:])
    env.reset(seed=2, options={"q": q, "target": np.concatenate([achieved[:3], turned])})
    _, reward, term, _, info = env.step(np.zeros(7, np.float32))
    assert info["distance"] < 1e-12 and info["angle"] == pytest.approx(0.3, abs=1e-9) and not term
    assert reward == pytest.approx(-(env.success_tol / env.rot_tol) * 0.3, abs=1e-9)
    env.reset(seed=2, options={"q": q, "target": achieved})
    assert env.step(np.zeros(7, np.float32))[2]


def test_cartesian_twist_moves_the_effector_as_commanded():
    env = gym.make("mjkin/PandaReach-v0", goal_type="pose", action_type="cartesian").unwrapped
    obs, _ = env.reset(seed=0, options={"q": env.home})
    before = env.tree.pose(env.q, "flange")
    action = np.array([0.5, -0.3, 0.2, 0.0, 0.0, 0.4], np.float32)
    env.step(action)
    after = env.tree.pose(env.q, "flange")
    np.testing.assert_allclose(after[:3, 3] - before[:3, 3], action[:3] * env.step_size, atol=1e-4)
    turn = spatial.mat_to_rotvec(after[:3, :3] @ before[:3, :3].T)
    np.testing.assert_allclose(turn, action[3:] * env.task.rot_step, atol=1e-3)


@pytest.mark.parametrize("goal_type", ["position", "pose"])
def test_a_planar_arms_cartesian_actions_keep_to_its_plane(goal_type):
    env = gym.make("mjkin/PlanarReach-v0", goal_type=goal_type, action_type="cartesian").unwrapped
    task = env.task
    assert task.plane is not None and abs(task.plane[2]) == pytest.approx(1.0, abs=1e-12) and task.plane_turns
    env.reset(seed=0, options={"q": [0.3, 0.5, 0.4]})
    before = env.tree.pose(env.q, "tip")
    statuses = []
    env.step(np.zeros(env.action_space.shape, np.float32))  # the step's IK is made at the first step
    real = task._move.solve

    def spy(q, goals):  # type: ignore[no-untyped-def]
        res = real(q, goals)
        statuses.extend(np.atleast_1d(res.status))
        return res

    task._move.solve = spy
    action = np.array([0.5, -0.3, 0.8, 0.4, -0.2, 0.3][:env.action_space.shape[0]], np.float32)
    env.step(action)
    after = env.tree.pose(env.q, "tip")
    # the z of the displacement and the turns about x and y are dropped: the IK reaches what is left
    assert statuses == ["converged"]
    np.testing.assert_allclose(after[:3, 3] - before[:3, 3], [0.5 * env.step_size, -0.3 * env.step_size, 0],
                               atol=1e-4 * env.extent)
    if goal_type == "pose":
        turn = spatial.mat_to_rotvec(after[:3, :3] @ before[:3, :3].T)
        np.testing.assert_allclose(turn, [0, 0, 0.3 * env.task.rot_step], atol=1e-4)
    plain = gym.make("mjkin/Reach-v0", action_type="cartesian").unwrapped.task
    assert plain.plane is None and not plain.plane_turns


def test_reset_options_set_start_and_target():
    env = gym.make("mjkin/Reach-v0").unwrapped
    q = env.tree.random_q(7)
    target = [0.3, 0.2, 0.6]
    obs, info = env.reset(seed=0, options={"q": q, "target": target})
    np.testing.assert_allclose(obs[:7], q)
    np.testing.assert_array_equal(obs[10:13], target)
    assert info["distance"] == pytest.approx(np.linalg.norm(env.effector(q) - target))
    with pytest.raises(mjkin.InputError, match="target"):
        env.reset(options={"target": [0.3, 0.2]})
    with pytest.raises(mjkin.InputError, match="options"):
        env.reset(options={"goal": target})
    with pytest.raises(mjkin.InputError, match="shape"):
        env.reset(options={"q": [0.0] * 3})


def test_obstacles_are_in_mujoco_s_model_frames_contacts_and_reward():
    center, radius = np.array([0.35, 0.0, 0.55]), 0.12
    region = ([0.2, -0.3, 0.3], [0.6, 0.3, 0.9])
    env = gym.make("mjkin/Reach-v0", target_region=region, obstacles=[(center, radius)], table=0.0,
                   collision_penalty=5.0, render_mode="rgb_array", width=160, height=120).unwrapped
    plain = gym.make("mjkin/Reach-v0", render_mode="rgb_array", width=160, height=120).unwrapped
    assert {"obstacle0", "table"} <= {env.tree.model.geom(i).name for i in range(env.tree.model.ngeom)}
    for seed in range(10):
        env.reset(seed=seed)
        assert np.all((env.target >= region[0]) & (env.target <= region[1]))
        assert np.linalg.norm(env.target - center) > radius
    # put the effector inside the sphere: MuJoCo reports the contact, the reward pays the penalty
    goal = mjkin.goals.Position("ee", center)
    q = mjkin.solve(plain.tree, goal, q0=env.home, avoid_collisions=True).q  # clear of everything but the sphere
    env.reset(seed=0, options={"q": q, "target": center + [0, 0, 0.3]})
    _, reward, _, _, info = env.step(np.zeros(7, np.float32))
    assert info["in_collision"] and info["contacts"] >= 1
    assert reward == pytest.approx(-info["distance"] - 5.0)
    names = {c.geom2 for c in env.scene.contacts(env.q)} | {c.geom1 for c in env.scene.contacts(env.q)}
    assert "obstacle0" in names
    plain.reset(seed=0, options={"q": q, "target": center + [0, 0, 0.3]})
    assert not plain.step(np.zeros(7, np.float32))[4]["in_collision"]
    assert (env.render() != plain.render()).any(axis=-1).sum() > 50  # the sphere and the table are drawn


def test_human_render_without_display_warns_and_does_not_crash(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.warns(UserWarning, match="display"):
        env = gym.make("mjkin/PlanarReach-v0", render_mode="human")
    assert "human" not in gym.make("mjkin/PlanarReach-v0").unwrapped.metadata["render_modes"]  # checks skip it
    env.reset(seed=0)
    env.step(env.action_space.sample())
    assert env.render() is None
    env.close()


def test_bad_options():
    with pytest.raises(mjkin.InputError, match="action_type"):
        gym.make("mjkin/Reach-v0", action_type="torque")
    with pytest.raises(mjkin.InputError, match="goal_type"):
        gym.make("mjkin/Reach-v0", goal_type="orientation")
    with pytest.raises(mjkin.UnknownNameError, match="hand"):
        gym.make("mjkin/Reach-v0", frame="hand")
    with pytest.warns(DeprecationWarning, match="frame"), pytest.raises(mjkin.UnknownNameError, match="hand"):
        gym.make("mjkin/Reach-v0", site="hand")  # the name before 0.2
    with pytest.raises(mjkin.InputError, match="radius"):
        gym.make("mjkin/Reach-v0", obstacles=[([0, 0, 1], -0.1)])
    for far in ([([1e300, 0, 0], 1e300)], [([0, 0, 1], 2e10)], [([0, -1.1e10, 0], 0.1)]):  # MuJoCo's collision
        with pytest.raises(mjkin.InputError, match=r"obstacles\[0\] must have .* within 1e\+10 m"):  # fails past it
            gym.make("mjkin/Reach-v0", obstacles=far)
    gym.make("mjkin/Reach-v0", obstacles=[([1e10, 0, 0], 1e10)])  # at the bound: made (its reset says no target fits)
    with pytest.raises(mjkin.InputError, match="num_envs"):
        gym.make_vec("mjkin/Reach-v0", num_envs=0, vectorization_mode="vector_entry_point")


# ------------------------------------------------------------------- the goal-env contract (HER)
class FakeHerBuffer:
    """What a HER buffer keeps per transition, and how it asks the env for rewards of relabelled goals."""

    def __init__(self):
        self.achieved, self.desired, self.infos, self.rewards, self.terminated = [], [], [], [], []

    def add(self, next_obs, reward, terminated, info):
        self.achieved.append(next_obs["achieved_goal"])
        self.desired.append(next_obs["desired_goal"])
        self.infos.append(info)
        self.rewards.append(reward)
        self.terminated.append(terminated)


@pytest.mark.parametrize("kwargs", [{}, {"sparse": True}, {"goal_type": "pose", "collision_penalty": 2.0},
                                    {"goal_type": "pose", "sparse": True, "collision_penalty": 0.5}],
                         ids=variant_id)
def test_batched_compute_reward_equals_step_rewards_on_1000_transitions(kwargs):
    env = gym.make("mjkin/Reach-v0", goal_conditioned=True, step_size=0.3, success_tol=0.3, rot_tol=2.0,
                   **kwargs)
    base = env.unwrapped
    buf = FakeHerBuffer()
    obs, _ = env.reset(seed=0)
    env.action_space.seed(0)
    while len(buf.rewards) < 1000:
        action = ik_expert(base) if len(buf.rewards) % 3 else env.action_space.sample()
        obs, reward, term, trunc, info = env.step(action)
        buf.add(obs, reward, term, info)
        if term or trunc:
            obs, _ = env.reset()
    achieved, desired = np.array(buf.achieved), np.array(buf.desired)
    rewards = np.array(buf.rewards)
    assert 0 < np.sum(buf.terminated) < 1000 and len(set(rewards.tolist())) > 1  # both outcomes occur
    if kwargs.get("collision_penalty"):
        assert any(i["in_collision"] for i in buf.infos)
    for infos in (buf.infos, np.array(buf.infos, dtype=object)):
        np.testing.assert_array_equal(base.compute_reward(achieved, desired, infos), rewards)
    np.testing.assert_array_equal(base.compute_terminated(achieved, desired, buf.infos), buf.terminated)
    assert not base.compute_truncated(achieved, desired, buf.infos).any()
    # relabelled goals (HER's "future" strategy): the batch equals one call per transition
    future = achieved[np.minimum(np.arange(1000) + 3, 999)]
    batched = base.compute_reward(achieved, future, np.array(buf.infos, dtype=object))
    single = [base.compute_reward(a, f, i) for a, f, i in zip(achieved, future, buf.infos, strict=True)]
    np.testing.assert_array_equal(batched, single)
    assert batched.shape == (1000,) and isinstance(single[0], float)
    # a (2, 500) batch, as a vectorised caller may pass it
    info_2d = {"in_collision": np.array([i["in_collision"] for i in buf.infos]).reshape(2, 500)}
    np.testing.assert_array_equal(base.compute_reward(achieved.reshape(2, 500, -1), future.reshape(2, 500, -1),
                                                      info_2d), batched.reshape(2, 500))


# ------------------------------------------------------------------- the native vector env
def assert_same_step(a, b):
    for x, y in zip(a[:4], b[:4], strict=True):
        if isinstance(x, dict):
            assert x.keys() == y.keys()
            for k in x:
                np.testing.assert_array_equal(x[k], y[k])
        else:
            np.testing.assert_array_equal(x, y)
    for key in ("distance", "is_success", "contacts", "in_collision"):
        np.testing.assert_array_equal(a[4][key], b[4][key])


@pytest.mark.parametrize("env_id,kwargs", [
    ("mjkin/Reach-v0", {"success_tol": 0.25, "step_size": 0.3, "max_episode_steps": 15}),
    ("mjkin/PlanarReach-v0", {"success_tol": 6.0, "max_episode_steps": 15}),
    ("mjkin/PandaReach-v0", {"goal_conditioned": True, "goal_type": "pose", "success_tol": 0.3, "rot_tol": 2.5,
                             "step_size": 0.3, "max_episode_steps": 12}),
    ("mjkin/Reach-v0", {"action_type": "cartesian", "max_episode_steps": 9, "success_tol": 0.3}),
], ids=["reach", "planar", "panda-goal-pose", "reach-cartesian"])
def test_vector_env_equals_single_envs_step_by_step_across_autoresets(env_id, kwargs):
    n = 5
    ref = gym.make_vec(env_id, num_envs=n, vectorization_mode="sync", **kwargs)
    nat = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **kwargs)
    assert isinstance(nat, gym.vector.VectorEnv) and isinstance(nat.unwrapped, ReachVectorEnv)
    assert nat.metadata["autoreset_mode"] == ref.metadata["autoreset_mode"] == gym.vector.AutoresetMode.NEXT_STEP
    assert nat.observation_space == ref.observation_space and nat.action_space == ref.action_space
    a, b = ref.reset(seed=11), nat.reset(seed=11)
    assert_same_step((a[0], 0, 0, 0, a[1]), (b[0], 0, 0, 0, b[1]))
    rng = np.random.default_rng(0)
    ended = {"terminated": 0, "truncated": 0}
    for _ in range(60):
        actions = rng.uniform(-1, 1, ref.action_space.shape).astype(np.float32)
        a, b = ref.step(actions), nat.step(actions)
        assert_same_step(a, b)
        assert nat.observation_space.contains(b[0])
        ended["terminated"] += a[2].sum()
        ended["truncated"] += a[3].sum()
    assert ended["terminated"] > 0 and ended["truncated"] > 0, ended  # autoresets of both kinds were compared
    ref.close()
    nat.close()


def test_vector_reset_seeds_env_i_with_seed_plus_i_and_reset_mask():
    nat = gym.make_vec("mjkin/Reach-v0", num_envs=4, vectorization_mode="vector_entry_point")
    obs, info = nat.reset(seed=40)
    for i in range(4):
        single, _ = gym.make("mjkin/Reach-v0").reset(seed=40 + i)
        np.testing.assert_array_equal(obs[i], single)
    assert info["_distance"].all()
    again, info = nat.reset(seed=[None, 7, None, None], options={"reset_mask": np.array([False, True, False, False])})
    np.testing.assert_array_equal(again[[0, 2, 3]], obs[[0, 2, 3]])
    np.testing.assert_array_equal(again[1], gym.make("mjkin/Reach-v0").reset(seed=7)[0])
    assert info["_distance"].tolist() == [False, True, False, False]


def test_vector_render_get_attr_and_call():
    nat = gym.make_vec("mjkin/PlanarReach-v0", num_envs=3, vectorization_mode="vector_entry_point",
                       render_mode="rgb_array", width=96, height=64)
    nat.reset(seed=0)
    frames = nat.render()
    assert len(frames) == 3 and all(f.shape == (64, 96, 3) for f in frames)
    assert not np.array_equal(frames[0], frames[1])  # different targets and starts
    targets = nat.unwrapped.get_attr("target")
    np.testing.assert_array_equal(np.stack(targets), nat.unwrapped.target)
    effectors = nat.unwrapped.call("effector")
    np.testing.assert_allclose(np.stack(effectors), nat.unwrapped.achieved, atol=1e-12)
    single = gym.make("mjkin/PlanarReach-v0", render_mode="rgb_array", width=96, height=64)
    single.reset(seed=2)
    np.testing.assert_array_equal(frames[2], single.render())
    nat.close()


def test_episode_example_reaches_targets_in_a_row(tmp_path, monkeypatch, capsys):
    import importlib.util
    import sys

    path = ROOT / "examples" / "episode.py"
    spec = importlib.util.spec_from_file_location("episode", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    out = tmp_path / "reach.mp4"  # (a GIF's palette per frame took a third more; write_video's tests cover GIFs)
    monkeypatch.setattr(sys, "argv", ["episode.py", "-o", str(out), "--targets", "3"])
    module.main()
    assert "3/3 targets reached" in capsys.readouterr().out
    import imageio.v3 as imageio

    frames = imageio.imread(out)
    assert len(frames) > 45  # several targets, more than a second and a half at 30 fps
    assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).mean() > 1


@pytest.mark.parametrize("env_id", IDS)
def test_docstring_states_the_extent_that_sets_the_bounds(env_id):
    env = gym.make(env_id).unwrapped
    assert f"{env.tree.name}: {env.extent:g}" in " ".join(type(env).__doc__.split())
    assert env.observation_space.high[env.tree.nq] == pytest.approx(4 * env.extent)


# ------------------------------------------------------------------- argument checks
NAN, INF = float("nan"), float("inf")
NON_FINITE = st.sampled_from([NAN, INF, -INF])
NOT_NUMBERS = st.sampled_from(["0.1", True, [0.1], {"x": 1}, 1j, b"1"])
NEGATIVE = st.floats(max_value=-1e-9, allow_infinity=False)


def positive_bad(optional: bool) -> st.SearchStrategy:
    """Bad values of a number that must be > 0 (None is the default of optional ones)."""
    return st.floats(max_value=0.0, allow_infinity=False, allow_nan=False) | NON_FINITE | NOT_NUMBERS | \
        (st.nothing() if optional else st.none())


def choice_bad(choices: tuple) -> st.SearchStrategy:
    return st.text(max_size=12).filter(lambda s: s not in choices) | st.sampled_from([1, ["joint"], b"joint"])


@st.composite
def non_finite_vectors(draw: st.DrawFn, n: int = 3) -> list:
    """``n`` numbers, one of them NaN or inf."""
    v = draw(st.lists(st.floats(-2, 2), min_size=n, max_size=n))
    v[draw(st.integers(0, n - 1))] = draw(NON_FINITE)
    return v


def vector_bad(n: int = 3) -> st.SearchStrategy:
    """Bad ``[x, y, z]``: wrong length, NaN/inf entries, not numbers."""
    return st.lists(st.floats(-2, 2), max_size=5).filter(lambda v: len(v) != n) | non_finite_vectors(n) | \
        st.sampled_from(["abc", None, [[0.0, 0.0, 0.0]]])


@st.composite
def inverted_regions(draw: st.DrawFn) -> tuple:
    """A box whose low is not below its high on at least one axis."""
    lo = draw(st.lists(st.floats(-1, 1), min_size=3, max_size=3))
    gap = draw(st.lists(st.floats(0.01, 1), min_size=3, max_size=3))
    for axis in draw(st.sets(st.integers(0, 2), min_size=1)):
        gap[axis] = -draw(st.floats(0, 1))
    return lo, [a + g for a, g in zip(lo, gap, strict=True)]


BAD_ARGS = {
    "model": st.sampled_from([3, None, 1.5, ["arm7"]]),
    "frame": st.sampled_from([3, None, ["ee"]]),
    "action_type": choice_bad(("joint", "cartesian")),
    "goal_type": choice_bad(("position", "pose")),
    # plain strings only: gym.make itself fails on other types (and on '%' in its warning) before the env is
    # made (ReachEnv's own check: below); it turns "rgb_array_list" into a wrapper around "rgb_array"
    "render_mode": st.text("abcdefghijklmnopqrstuvwxyz_ -", max_size=12)
    .filter(lambda s: s not in ("rgb_array", "human") and not s.endswith("_list")),
    "goal_conditioned": st.sampled_from(["no", "True", 1, 0, None, 1.0]),
    "sparse": st.sampled_from(["no", "True", 1, 0, None, 1.0]),
    "step_size": positive_bad(optional=True),
    "success_tol": positive_bad(optional=True),
    "rot_step": positive_bad(optional=False),
    "rot_tol": positive_bad(optional=False),
    "success_bonus": NEGATIVE | NON_FINITE | NOT_NUMBERS | st.none(),
    "collision_penalty": NEGATIVE | NON_FINITE | NOT_NUMBERS | st.none(),
    "start_noise": NEGATIVE | NON_FINITE | NOT_NUMBERS | st.none()
    | st.floats(min_value=np.pi, exclude_min=True, allow_infinity=False),
    "table": NON_FINITE | NOT_NUMBERS | st.floats(2.0, 1e9),  # every arm's lowest moving body is below 2
    "obstacles": st.sampled_from([0.1, "sphere", {"center": [0, 0, 1], "radius": 0.1}, ([0.3, 0.0, 0.5], 0.1)])
    | vector_bad().map(lambda c: [(c, 0.1)])
    | (positive_bad(optional=False) | st.none()).map(lambda r: [([0.3, 0.0, 0.5], r)])
    | st.sampled_from([[[0.3, 0.0, 0.5]], [([0.3, 0.0, 0.5], 0.1, 2)], [None]]),
    "target_region": inverted_regions() | vector_bad().map(lambda v: (v, [1.0, 1.0, 1.0]))
    | vector_bad().map(lambda v: ([-1.0, -1.0, -1.0], v)) | st.sampled_from([0.5, "box", [[0, 0, 0]], ([0] * 3,) * 3]),
    "width": st.integers(max_value=0) | st.sampled_from([160.0, "160", True, None, NAN]),
    "height": st.integers(max_value=0) | st.sampled_from([120.0, "120", True, None, NAN]),
}
VECTOR_ARGS = {"num_envs": st.integers(max_value=0) | st.sampled_from([2.5, "2", True, None]),
               "max_episode_steps": st.integers(max_value=0) | st.sampled_from([2.5, "100", True, NAN])}


def make(env_id: str, vector: bool, **kwargs):
    if vector:
        return gym.make_vec(env_id, **{"num_envs": 2, **kwargs}, vectorization_mode="vector_entry_point")
    return gym.make(env_id, **kwargs)


@pytest.mark.parametrize("name", [*BAD_ARGS, *VECTOR_ARGS])
@settings(max_examples=25)
@given(data=st.data())
def test_every_bad_argument_raises_one_line_naming_it_at_construction(name, data):
    value = data.draw({**BAD_ARGS, **VECTOR_ARGS}[name], label=name)
    env_id = data.draw(st.sampled_from(IDS), label="env_id")
    vector = name in VECTOR_ARGS or data.draw(st.booleans(), label="vector")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # gymnasium warns of a render_mode outside the metadata
        with pytest.raises(mjkin.InputError) as err:
            make(env_id, vector, **{name: value})
    message = str(err.value)
    assert name in message and "\n" not in message, message


def test_render_mode_of_another_type_is_refused_by_the_env():
    with pytest.raises(mjkin.InputError, match=r"^render_mode must be None or 'rgb_array' or 'human', not 1$"):
        mjkin.envs.ReachEnv(render_mode=1)


@pytest.mark.parametrize("bad", [NAN, INF, -INF])
@pytest.mark.parametrize("env_id", IDS)
def test_non_finite_table_is_refused_when_made(env_id, bad):
    with pytest.raises(mjkin.InputError, match=r"^table must be a finite number, got (nan|inf|-inf)$"):
        gym.make(env_id, table=bad)


def test_table_must_leave_the_arm_and_the_target_region_above_it():
    with pytest.raises(mjkin.InputError, match=r"^table must be at most 0\.1 \(.*body 'link1' .*\), got 0\.5$"):
        gym.make("mjkin/Reach-v0", table=0.5)
    with pytest.raises(mjkin.InputError, match="target_region must reach above the table"):
        gym.make("mjkin/Reach-v0", table=0.0, target_region=([0.2, -0.4, -0.6], [0.6, 0.4, -0.1]))
    gym.make("mjkin/PlanarReach-v0", table=0.0).reset(seed=0)  # the planar arm lies on z = 0: allowed


def test_inverted_target_region_is_refused_when_made():
    with pytest.raises(mjkin.InputError, match=r"target_region low must be below high on every axis, not on x, y, z"):
        gym.make("mjkin/Reach-v0", target_region=([0.65, 0.4, 0.6], [0.25, -0.4, 0.1]))


def test_a_region_out_of_reach_names_the_settings_at_reset():
    env = gym.make("mjkin/Reach-v0", table=0.0, target_region=([5.0, 5.0, 5.0], [6.0, 6.0, 6.0]))
    with pytest.raises(mjkin.InputError, match=r"inside target_region=\[\[5\.0, 5\.0, 5\.0\], \[6\.0, 6\.0, 6\.0\]\], "
                                               r"above table=0\.0 and outside the 0 obstacles"):
        env.reset(seed=0)


@pytest.mark.parametrize("vector", [False, True], ids=["single", "vector"])
@pytest.mark.parametrize("bad", [1e308, 3.2, INF, NAN])
def test_start_noise_beyond_pi_is_refused_when_made(bad, vector):
    with pytest.raises(mjkin.InputError, match=r"^start_noise must be a finite number") as err:
        make("mjkin/Reach-v0", vector, start_noise=bad)
    if np.isfinite(bad):
        assert str(err.value) == f"start_noise must be a finite number from 0 to pi (3.14159) rad (or m), got {bad!r}"


def test_start_noise_of_pi_is_allowed():
    env = gym.make("mjkin/Reach-v0", start_noise=np.pi).unwrapped
    env.reset(seed=0)
    assert np.all((env.q >= env.task.q_lo) & (env.q <= env.task.q_hi))


@pytest.mark.parametrize("bad", [-1, 0, NAN, INF])
def test_bad_step_size_is_refused_when_made(bad):
    with pytest.raises(mjkin.InputError, match=r"^step_size must be a finite number > 0, got"):
        gym.make("mjkin/Reach-v0", step_size=bad)


@pytest.mark.parametrize("method", ["compute_reward", "compute_terminated", "compute_truncated"])
def test_goal_methods_check_shapes_with_one_line(method):
    env = gym.make("mjkin/Reach-v0", goal_type="pose", collision_penalty=1.0).unwrapped
    f = getattr(env, method)
    g = np.tile([0.3, 0.0, 0.5, 1.0, 0.0, 0.0, 0.0], (4, 1))
    info = {"in_collision": np.zeros(4, bool)}
    for achieved, desired, want in [(np.zeros((4, 7)), np.zeros((5, 7)), r"\(4, 7\) and \(5, 7\)"),
                                    (g, g[0], r"\(4, 7\) and \(7,\)"),  # no broadcasting
                                    (g[:, :3], g[:, :3], r"\(\.\.\., 7\) for goal_type='pose'"),
                                    ([[0, "a"]], g, "arrays of numbers"), (g * np.nan, g, "finite")]:
        with pytest.raises(mjkin.InputError, match="achieved_goal and desired_goal") as err:
            f(achieved, desired, info)
        assert re.search(want, str(err.value)) and "\n" not in str(err.value), str(err.value)
    if method != "compute_truncated":  # the collision penalty needs in_collision for every goal
        with pytest.raises(mjkin.InputError, match=r"info must give 'in_collision' for goals of batch shape \(4,\)"):
            f(g, g, [{}] * 4)
    assert f(g, g, info).shape == (4,)
