"""mjkin.distributed on a local 2-CPU Ray cluster: the same answers as one process, errors with their type."""

from __future__ import annotations

import numpy as np
import pytest

ray = pytest.importorskip("ray", reason='Ray is not installed (pip install "mjkin[ray]"): distributed tests skipped')

import mjkin  # noqa: E402
from mjkin import distributed, motion  # noqa: E402
from mjkin import goals as G  # noqa: E402
from mjkin.distributed import PoseSolver, pose_matrices, random_poses, render_many, solve_many  # noqa: E402

FIELDS = ("q", "success", "error", "iterations", "status", "goal_errors", "restarts")


@pytest.fixture(scope="module", autouse=True)
def cluster():
    from mjkin.apps.warmup import warmup

    warmup()  # workers load the kernels this compiles from the same cache
    ray.shutdown()  # a session another test of this process left (a no-op without one)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    yield
    ray.shutdown()


@pytest.fixture(scope="module")
def arm():
    return mjkin.load("arm7")


def targets(tree, n, seed=7, unreachable=0):
    """Poses of ``ee`` at random configurations; the first ``unreachable`` moved out of reach."""
    T = tree.pose(tree.random_q(np.random.default_rng(seed), n), "ee")
    T[:unreachable, :3, 3] += 5.0
    return T


def assert_same(got, want):
    for name in FIELDS:
        a, b = getattr(got, name), getattr(want, name)
        assert a.shape == b.shape and a.dtype == b.dtype, name
        assert np.array_equal(a, b), name
    assert got.method == want.method and len(got.goals) == len(want.goals)
    for g, w in zip(got.goals, want.goals, strict=True):
        assert type(g) is type(w) and g.batch() == w.batch() and g.priority == w.priority


@pytest.mark.parametrize("chunk, n, unreachable, options", [
    (1, 40, 2, dict(restarts=2)),
    (97, 300, 3, dict(restarts=3)),
    (5000, 5003, 0, dict(restarts=0)),
])
def test_solve_many_equals_solve_bit_for_bit(arm, chunk, n, unreachable, options):
    T = targets(arm, n, unreachable=unreachable)
    goals = [G.Pose("ee", T=T), G.Rest(arm.qpos0, weight=0.01, priority=1)]
    want = mjkin.solve(arm, goals, **options)
    got = solve_many("arm7", goals, chunk=chunk, progress=False, **options)
    assert_same(got, want)
    assert got.tree is not None and got.tree.name == "arm7"
    np.testing.assert_array_equal(got.goals[0].T, T)
    if unreachable:
        assert (got.restarts[:unreachable] == options["restarts"]).all() and not got.success[:unreachable].any()


def test_per_target_q0_and_an_mjmodel_source(arm):
    T = targets(arm, 50, seed=3)
    q0 = arm.random_q(np.random.default_rng(4), 50)
    want = mjkin.solve(arm, G.Pose("ee", T=T), q0, method="dls", max_iters=30)
    got = solve_many(arm.model, G.Pose("ee", T=T), q0, chunk=7, method="dls", max_iters=30, progress=False)
    assert_same(got, want)
    unbatched = solve_many(arm.model, G.Position("ee", T[0, :3, 3]), q0[0], progress=False)
    assert_same(unbatched, mjkin.solve(arm, G.Position("ee", T[0, :3, 3]), q0[0]))


def test_history_is_joined(arm):
    T = targets(arm, 9, seed=5)
    want = mjkin.solve(arm, G.Pose("ee", T=T), restarts=0, history=True)
    got = solve_many("arm7", G.Pose("ee", T=T), chunk=4, restarts=0, history=True, progress=False)
    assert_same(got, want)
    np.testing.assert_array_equal(got.history.q, want.history.q)
    np.testing.assert_array_equal(got.history.error, want.history.error)


def test_unknown_frame_raised_in_the_driver_before_any_work(arm, monkeypatch):
    def no_workers(*args, **kwargs):
        raise AssertionError("workers were started")

    monkeypatch.setattr(distributed, "_actors", no_workers)
    with pytest.raises(mjkin.UnknownNameError, match="'hand'"):
        solve_many("arm7", G.Position("hand", np.zeros((10, 3))), progress=False)
    with pytest.raises(mjkin.InputError, match=r"q0 has shape \(3, 7\)"):
        solve_many("arm7", G.Position("ee", np.zeros((10, 3))), np.zeros((3, 7)), progress=False)


@pytest.mark.parametrize("options, error, text", [
    (dict(method="newton"), mjkin.InputError, "unknown IK method 'newton'"),
    (dict(restarts=-1), mjkin.InputError, "restarts must be a whole number from 0 to 10,000"),
    (dict(joints=["nope"]), mjkin.UnknownNameError, "unknown joint 'nope'"),
])
def test_worker_errors_keep_their_type(options, error, text):
    with pytest.raises(error, match=text) as info:
        solve_many("arm7", G.Position("ee", np.full((6, 3), 0.3)), chunk=3, progress=False, **options)
    assert type(info.value) is error


def test_threads_per_worker_one_runs_one_solver_thread(arm):
    actors = distributed._actors(arm, None, 1, 10)
    try:
        assert len(actors) == 2  # one per CPU of the 2-CPU cluster
        assert ray.get([a.threads.remote() for a in actors]) == [1, 1]
    finally:
        for a in actors:
            ray.kill(a)
    (both,) = distributed._actors(arm, None, 2, 10)  # one worker holds both CPUs
    try:
        assert ray.get(both.threads.remote()) == 2
    finally:
        ray.kill(both)
    with pytest.raises(mjkin.InputError, match="threads_per_worker=3 but the Ray cluster has 2 CPUs"):
        distributed._actors(arm, None, 3, 10)


def test_render_many_writes_playable_clips(arm, tmp_path):
    import imageio.v3 as iio

    scripts = []
    for name, frames in (("wave", 6), ("reach", 9)):
        q = np.linspace(arm.qpos0, arm.random_q(np.random.default_rng(frames), 1)[0], frames)
        traj = motion.Trajectory(times=np.arange(frames) / 30.0, q=q, fingerprint=motion.fingerprint(arm),
                                 model="arm7", frame="ee")
        scripts.append(traj.save(tmp_path / f"{name}.json"))
    clips = render_many("arm7", scripts, tmp_path / "clips", width=96, height=64, progress=False)
    assert clips == [tmp_path / "clips" / "wave.mp4", tmp_path / "clips" / "reach.mp4"]
    for clip, frames in zip(clips, (6, 9), strict=True):
        video = iio.imread(clip)
        assert video.shape == (frames, 64, 96, 3)
        assert video.std() > 1.0  # a picture, not a blank frame
    other = motion.Trajectory(times=np.zeros(2), q=np.zeros((2, 2)), fingerprint="x", model="planar_2link")
    other.save(tmp_path / "other.json")
    with pytest.raises(mjkin.InputError, match="recorded on model 'planar_2link'"):
        render_many("arm7", [tmp_path / "other.json"], tmp_path / "clips", progress=False)


def test_ray_data_pipeline_writes_parquet_equal_to_solve(arm, tmp_path):
    pytest.importorskip("pyarrow", reason="pyarrow is not installed: the Ray Data test is skipped")
    import ray.data

    n, batch = 600, 200
    (ray.data.range(n, override_num_blocks=3)
        .map_batches(random_poses, fn_kwargs=dict(model="arm7", frame="ee", seed=1), batch_size=batch)
        .map_batches(PoseSolver, fn_constructor_kwargs=dict(model="arm7", frame="ee", restarts=0),
                     batch_size=batch, concurrency=1, num_cpus=1)
        .write_parquet(str(tmp_path / "ik")))
    assert len(list((tmp_path / "ik").glob("*.parquet"))) >= 2
    rows = ray.data.read_parquet(str(tmp_path / "ik")).take_batch(n + 1, batch_format="numpy")
    order = np.argsort(rows["id"])
    assert np.array_equal(rows["id"][order], np.arange(n))
    T = pose_matrices(rows["position"][order], rows["quaternion"][order])
    want = mjkin.solve(arm, G.Pose("ee", T=T), restarts=0)
    assert np.array_equal(np.stack(rows["q"][order]), want.q)
    assert np.array_equal(rows["success"][order], want.success) and want.success.mean() > 0.9
