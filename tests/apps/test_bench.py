"""Benchmarks report what they measured: small runs, checked for content and honesty, never for speed."""

from __future__ import annotations

import importlib.util
import json
import sys

import mujoco
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import mjkin
from mjkin.apps import cli
from mjkin.apps.bench import peers, startup
from mjkin.apps.bench import play as play_bench
from mjkin.apps.bench import suite as bench
from mjkin.apps.bench.ik import (
    TRAC_IK_ARMS,
    TRAC_IK_SOURCE,
    Run,
    arms,
    bench_ik,
    bench_trac_ik,
    error_components,
    frame_errors,
    mid_range,
    mink_ik,
    mujoco_dls,
    past_limits,
    row,
    success,
    targets_for,
)
from mjkin.apps.bench.report import shared_models_dir
from mjkin.kinematics import build
from mjkin.kinematics.build import dh_fk
from mjkin.spatial import axis_angle_to_mat

HAS_MINK = importlib.util.find_spec("mink") is not None
ARM7 = arms(["arm7"])[0]
PANDA = arms(["panda"])[0]
PEER_MODULES = ("mink", "roboticstoolbox", "trac_ik", "pytracik", "pinocchio")


def easy_targets(n: int = 4, spread: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Configurations near home and their poses (targets a single start reaches)."""
    q = ARM7.home + spread * np.random.default_rng(0).standard_normal((n, ARM7.tree.nq))
    q = ARM7.tree.clip(q)
    return q, ARM7.tree.pose(q, ARM7.frame, ARM7.kind)


def test_bench_ik_rows_name_every_solver_with_the_json_columns():
    report = bench_ik(["arm7"], targets=6, peers=())
    (rows,) = report.tables.values()
    by = {r["solver"]: r for r in rows}
    assert set(by) == {"mjkin", "mjkin.solve", "mjkin-single-start", "mujoco-dls"}
    for r in rows:
        assert r["model"] == "arm7"
        assert {"success", "median_ms", "p95_ms", "iterations_mean", "restarts_mean", "batched_per_s"} <= set(r)
        assert 0.0 <= r["success"] <= 100.0 and r["median_ms"] > 0 and r["p95_ms"] >= r["median_ms"]
    assert by["mjkin"]["success"] == by["mjkin"]["batched_success"] == by["mjkin.solve"]["success"] == 100.0
    assert by["mjkin.solve"]["iterations_mean"] == by["mjkin"]["iterations_mean"]  # the same solves, another entry
    assert by["mjkin-single-start"]["restarts_mean"] == 0.0
    assert by["mujoco-dls"]["batched_per_s"] is None and by["mjkin"]["batched_per_s"] > 0
    assert report.settings["iters"] == 200 and report.settings["targets"] == 6


def test_single_start_rows_keep_the_iteration_budget():
    report = bench_ik(["arm7"], targets=5, iters=3, peers=())
    (rows,) = report.tables.values()
    for r in rows:
        if r["solver"] not in ("mjkin", "mjkin.solve"):
            assert r["iterations_mean"] <= 3, r
            assert r["restarts_mean"] == 0.0


def test_success_is_recounted_by_mujoco_not_taken_from_the_solver():
    q, targets = easy_targets()
    right = Run(q, np.full(len(q), 1e-3), np.ones(len(q)), np.zeros(len(q)))
    assert row(ARM7, "oracle", right, targets, 1e-9, 1e-9)["success"] == 100.0
    wrong = Run(q[::-1].copy(), right.seconds, right.iterations, right.restarts)  # answers swapped
    assert row(ARM7, "liar", wrong, targets, 1e-4, 1e-3)["success"] == 0.0
    nudged = q.copy()
    nudged[0, 0] += 1e-3  # one answer slightly off: counted as one failure
    assert row(ARM7, "close", Run(nudged, *list(vars(right).values())[1:]), targets, 1e-5, 1e-5)["success"] == 75.0


@given(angle=st.floats(1e-8, 3.1), axis=st.integers(0, 2), pos=st.floats(0.0, 0.5))
def test_recheck_measures_distances_exactly(angle, axis, pos):
    q, targets = easy_targets(1)
    moved = targets.copy()
    moved[0, :3, :3] = targets[0, :3, :3] @ axis_angle_to_mat(np.eye(3)[axis], angle)
    moved[0, :3, 3] += [pos, 0.0, 0.0]
    ep, er = frame_errors(ARM7.tree.model, ARM7.frame, ARM7.kind, q, moved)
    assert ep[0] == pytest.approx(pos, abs=1e-12)
    assert er[0] == pytest.approx(angle, rel=1e-7, abs=1e-12)


def test_mujoco_dls_reaches_easy_targets_and_stops_at_its_budget():
    q, targets = easy_targets()
    run = mujoco_dls(ARM7, targets, ARM7.home, 1e-6, 1e-6, max_iters=200)
    assert row(ARM7, "dls", run, targets, 1e-6, 1e-6)["success"] == 100.0
    short = mujoco_dls(ARM7, targets, ARM7.home, 1e-12, 1e-12, max_iters=2)
    assert (short.iterations == 2).all() and (short.seconds > 0).all()


@pytest.mark.skipif(not HAS_MINK, reason="mink is the optional bench extra")
def test_mink_reaches_easy_targets_by_its_own_error_and_stops_at_its_budget():
    q, targets = easy_targets(3)
    run = mink_ik(ARM7, targets, ARM7.home, 1e-5, 1e-5, max_iters=200)
    assert row(ARM7, "mink", run, targets, 1e-5, 1e-5)["success"] == 100.0
    assert (run.iterations >= 1).all() and (run.seconds > 0).all()
    assert (mink_ik(ARM7, targets, ARM7.home, 1e-12, 1e-12, max_iters=2).iterations == 2).all()


def test_models_take_names_and_files(tmp_path):
    path = mjkin.bundled_models()["arm7"]
    (arm,) = arms([str(path)])
    assert (arm.name, arm.frame, arm.kind) == ("arm7", "ee", "site")
    renamed = tmp_path / "two.xml"  # the last site is the frame, whatever its name
    renamed.write_text(build.planar_chain([1.0, 0.5]).replace('<site name="ee"', '<site name="hand"'))
    assert arms([str(renamed)])[0].frame == "hand"
    with pytest.raises(mjkin.InputError, match="neither"):
        arms(["no_such_arm"])


def test_mid_range_is_the_middle_of_every_limited_joint():
    tree = ARM7.tree
    q = mid_range(tree)
    for j in range(tree.njnt):
        lo, hi = tree.jnt_range[j]
        assert q[tree.jnt_qadr[j]] == pytest.approx(0.5 * (lo + hi) if tree.jnt_limited[j] else tree.qpos0[j])


def test_trac_ik_protocol_rows_and_published_figures_kept_apart(tmp_path):
    report = bench_trac_ik(["arm7"], targets=4, peers=())
    (rows,) = report.tables.values()
    assert [r["solver"] for r in rows] == ["mjkin single", "mjkin batched"]
    assert all(r["mean_ms"] > 0 and 0 <= r["success"] <= 100 for r in rows)
    assert report.settings["tol_m"] == report.settings["rot_tol_rad"] == 1e-5
    assert report.settings["start"].startswith("mid-range")
    assert report.extra == {"published": [], "skipped": []}  # TRAC-IK published no arm7 figure


@pytest.mark.parametrize("name", TRAC_IK_ARMS)
def test_trac_ik_success_criterion_on_the_real_arms(name):
    """The protocol's solve (mid-range start, 1e-5 m and rad, TRAC-IK's restart-until-done budget) meets
    >= 99.9 % of 300 targets per arm, as MuJoCo re-checks them. No time limit here: it would make the
    count depend on the machine's load; ``timeout=`` has its own tests."""
    found = arms(None, default=(name,))
    if not found:
        pytest.skip(f"{name}: ../shared/models not available")
    arm = found[0]
    T, q0 = targets_for(arm, 300, seed=1), mid_range(arm.tree)
    res = mjkin.solve(arm.tree, mjkin.goals.Pose(arm.frame, T=T, kind=arm.kind), q0, tol=1e-5, rot_tol=1e-5,
                      restarts=1000)
    ok = success(arm, res.q, T, 1e-5, 1e-5)
    assert (ok == res.success).all()  # mjkin's own count agrees with MuJoCo's
    assert ok.mean() >= 0.999, f"{name}: {np.sum(~ok)} of 300 failed ({set(res.status[~ok])})"


def test_trac_ik_passes_the_time_limit_to_solve(monkeypatch):
    from mjkin.apps.bench import ik as bench_ik
    seen = []
    real_solve, real_problem = bench_ik.solve, bench_ik.Problem

    def bounded(*args, timeout=None, **kwargs):
        seen.append(timeout)
        return real_solve(*args, timeout=timeout, **kwargs)

    def problem(*args, timeout=None, **kwargs):
        seen.append(timeout)
        return real_problem(*args, timeout=timeout, **kwargs)

    monkeypatch.setattr(bench_ik, "solve", bounded)
    monkeypatch.setattr(bench_ik, "Problem", problem)
    report = bench_trac_ik(["arm7"], targets=2, time_limit=0.004, peers=())
    assert seen and set(seen) == {0.004}
    assert report.settings["time limit"] == "mjkin.solve(timeout=...)"
    assert all(r["timeouts"] == 0 for r in next(iter(report.tables.values())))


def test_trac_ik_published_rows_are_labelled_and_not_measured(tmp_path, monkeypatch):
    from mjkin.apps.bench import ik as bench_ik

    monkeypatch.setattr(bench_ik, "arms", lambda names, default=(): [bench_ik.Arm("panda", ARM7.tree, "ee", "site")])
    report = bench_trac_ik(["panda"], targets=2, peers=())
    doc = report.as_json()
    assert {r["solver"] for r in doc["rows"]} == {"mjkin single", "mjkin batched"}
    assert {r["solver"] for r in doc["published"]} == {"TRAC-IK (published)", "KDL (published)"}
    assert all(r["source"] == TRAC_IK_SOURCE and "not measured here" in r["source"] for r in doc["published"])
    assert len(report.tables) == 2 and TRAC_IK_SOURCE in report.tables


def test_cli_writes_the_json_schema(tmp_path, capsys):
    out = tmp_path / "ik.json"
    assert cli.main(["bench", "ik", "--models", "arm7", "--targets", "3", "--iters", "50", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert set(doc) >= {"rows", "settings"} and doc["settings"]["iters"] == 50
    for r in doc["rows"]:
        assert {"model", "solver", "success", "median_ms", "p95_ms", "iterations_mean", "restarts_mean",
                "batched_per_s"} <= set(r)
    assert "mjkin-single-start" in capsys.readouterr().out
    assert [p.name for p in tmp_path.iterdir()] == ["ik.json"]  # written atomically, nothing left behind


@pytest.mark.parametrize("argv", [
    ["bench", "ik", "--targets", "0"],
    ["bench", "ik", "--tol", "-1"],
    ["bench", "ik", "--models", "no_such_arm"],
    ["bench", "ik", "--json", "/no/such/folder/x.json"],
    ["bench", "ik", "--json", "out.txt"],
    ["bench", "realtime", "--plot", "out.jpg"],
])
def test_cli_rejects_bad_settings_before_any_work(argv, capsys):
    with pytest.raises(SystemExit) as e:
        raise SystemExit(cli.main(argv))
    assert e.value.code == 2
    assert "Traceback" not in capsys.readouterr().err


def test_seeds_out_is_an_existing_folder_or_a_new_one_inside_one(tmp_path):
    parse = cli.build_parser().parse_args
    (tmp_path / "old").mkdir()
    for out in (tmp_path / "old", tmp_path / "new"):  # both fine, and nothing is created by the check
        bench.check_paths(parse(["bench", "seeds", "--out", str(out)]))
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["old"]
    (tmp_path / "file").write_text("")
    for out, text in ((tmp_path / "file", "is a file; give a folder"), (tmp_path / "no" / "new", "does not exist")):
        with pytest.raises(mjkin.MjkinError, match=text):
            bench.check_paths(parse(["bench", "seeds", "--out", str(out)]))


def test_fk_baselines_do_the_same_work_as_mjkin():
    tree = ARM7.tree
    Q = tree.random_q(np.random.default_rng(1), 3)
    np.testing.assert_allclose(bench.mujoco_fk_loop(tree.model, Q)(), tree.fk(Q), atol=1e-10)
    pos, quat = bench.mujoco_user_loop(tree.model, Q)()  # the user's loop: every body's xpos and xquat
    np.testing.assert_allclose(pos, tree.fk(Q)[..., :3, 3], atol=1e-10)
    np.testing.assert_allclose(mjkin.spatial.quat_to_mat(quat), tree.fk(Q)[..., :3, :3], atol=1e-10)
    site = tree.model.nsite - 1
    np.testing.assert_allclose(bench.mujoco_site_pose(tree.model, Q[0], site)(),
                               tree.pose(Q[0], tree.names("site")[site], "site"), atol=1e-10)
    # the row without the C call computes the same pose as tree.pose
    assert np.array_equal(bench.pose_without_c(tree, tree.names("site")[site], Q[1])(),
                          tree.pose(Q[1], tree.names("site")[site], "site"))
    report = bench.bench_fk(["arm7"], sizes=[2], min_time=1e-3)
    batched, single = list(report.tables.values())[:2]
    assert [r["batch"] for r in batched] == [2] and single[0]["model"] == "arm7"
    assert [r["library"] for r in single][:3] == ["mjkin", "mjkin without its C call", "mujoco"]
    assert single[0]["ratio"] == 1.0 and "_posecall" in report.settings["tree.pose"]
    assert all(r["ratio"] > 0 for r in batched + single) and all(r["ratio_4x4_loop"] > 0 for r in batched)


@pytest.mark.skipif(shared_models_dir() is None, reason="the shared real robot models are not here")
def test_fk_bench_has_rows_for_the_shared_real_robots():
    real = ["panda_menagerie", "ur5e", "iiwa14", "gen3", "xarm7", "g1"]
    assert [name for name, _ in bench.fk_models()] == ["arm7", "primate", "panda", *real]  # the default list
    report = bench.bench_fk(real[:-1], sizes=[2], min_time=1e-3)
    batched = list(report.tables.values())[0]
    assert [r["model"] for r in batched] == real[:-1] and all(r["ratio"] > 0 for r in batched)
    for name, tree in bench.fk_models(real[:-1]):  # the baseline computes what mjkin does, on each
        Q = tree.random_q(np.random.default_rng(2), 3)
        np.testing.assert_allclose(bench.mujoco_fk_loop(tree.model, Q)(), tree.fk(Q), atol=1e-10, err_msg=name)


def test_realtime_reports_chains_and_trees_warm_and_cold(tmp_path):
    pytest.importorskip("matplotlib")
    plot = tmp_path / "rt.png"
    before = mjkin.threads()
    report = bench.run(cli.build_parser().parse_args(
        ["bench", "realtime", "--dofs", "2", "6", "--frames", "3", "--plot", str(plot)]))
    assert mjkin.threads() == before and report.settings["threads"].startswith("mjkin.set_threads(1)")
    rows, largest = report.tables.values()
    models = {(r["model"], r["start"]) for r in rows}
    assert {("chain 2", "warm"), ("chain 6", "cold")} <= models
    assert any(m.startswith("primate") for m, _ in models) and any(m.startswith("4-arm") for m, _ in models)
    assert {r["dof"] for r in rows if str(r["model"]).startswith("chain")} == {2, 6}
    assert [r["rate"] for r in largest] == ["60 Hz", "1 kHz"] and largest[0]["largest_measured"] == 6
    for r in largest:  # every chain up to N fits, so N itself fits
        for clock in ("wall", "cpu"):
            assert r[f"all_up_to_{clock}"] is None or r[f"largest_dof_{clock}"] >= r[f"all_up_to_{clock}"]
    assert plot.stat().st_size > 1000 and [p.name for p in tmp_path.iterdir()] == ["rt.png"]


def test_render_bench_compares_the_same_frames():
    (rows,) = bench.bench_render(frames_n=2, width=64, height=48, repeat=1).tables.values()
    assert [r["model"] for r in rows] == ["arm7", "primate"]
    for r in rows:
        assert r["size"] == "64x48" and r["ratio"] == pytest.approx(r["mjkin_frames_per_s"] / r["mujoco_frames_per_s"])


def test_play_bench_times_a_take_it_recorded_and_leaves_no_file(tmp_path, monkeypatch):
    """The save figure is of a real take (0.5 s of drags sampled at 30 Hz), saved in a temporary folder, removed."""
    monkeypatch.chdir(tmp_path)
    (rows,) = play_bench.measure(("arm7",), 96, 72, seconds=0.5, drags=2).values()
    (row,) = rows
    assert row["take s"] >= 0.5 - 2 / 30 and 0 < row["save s per take s"] < np.inf
    assert row["stream frames/s"] > 0 and row["latency median ms"] > 0
    assert not list(tmp_path.iterdir())


def test_startup_bench_runs_an_entry_cold_then_warm_in_a_fresh_copy():
    """Its child imports the package as a user's process does (it once named a module that had moved, and failed)."""
    report = startup.bench_startup(("pose",))
    (rows,) = report.tables.values()
    assert [(r["entry"], r["cache"], r["ok"]) for r in rows] == [("pose", "empty", True), ("pose", "warm", True)]
    assert all(r["import_s"] > 0 and r["peak_mb"] > 0 for r in rows)


def test_env_bench_measures_reacher_beside_reach():
    report = bench.bench_env(steps=5, num_envs=2)
    (rows,) = report.tables.values()
    envs = [r["env"] for r in rows]
    assert envs[0] == "Reacher-v5 (gymnasium)" and "mjkin/Reach-v0" in envs
    vector = [(r["action"], r["envs"]) for r in rows if "make_vec" in r["env"]]
    assert vector == [("joint", 2), ("cartesian", 2)]
    reacher = rows[0]["steps_per_s"]
    for r in rows:
        assert r["ratio"] == pytest.approx(r["steps_per_s"] / reacher)


def test_report_json_drops_nan_and_keeps_published_apart():
    pub = [{"model": "x", "solver": "quoted"}]
    report = bench.Report({"measured": [{"a": float("nan")}], "quoted": pub}, {"s": 1}, {"published": pub})
    assert report.as_json() == {"rows": [{"a": None}], "settings": {"s": 1}, "published": pub}


def test_mjkin_solve_still_meets_what_bench_ik_counts():
    q, targets = easy_targets(2)
    res = mjkin.solve(ARM7.tree, mjkin.goals.Pose(ARM7.frame, T=targets), q0=ARM7.home, tol=1e-5, rot_tol=1e-5)
    ep, er = frame_errors(ARM7.tree.model, ARM7.frame, ARM7.kind, res.q, targets)
    assert (ep <= 1e-5).all() and (er <= 1e-5).all() and res.success.all()


def test_every_bench_option_has_help():
    import argparse

    parser = argparse.ArgumentParser()
    bench.add_arguments(parser)
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert sub.help and all(c.help for c in sub._choices_actions)
    for name, command in sub.choices.items():
        for action in command._actions:
            assert action.help, f"mjkin bench {name} {'/'.join(action.option_strings)} has no help"


def test_timed_loops_pause_the_garbage_collector_and_restore_it():
    import gc

    assert gc.isenabled()
    with bench.gc_paused():
        assert not gc.isenabled()
    assert gc.isenabled()
    with pytest.raises(RuntimeError), bench.gc_paused():
        raise RuntimeError("a failing benchmark")
    assert gc.isenabled()  # restored on the way out of an error too
    gc.disable()
    try:
        with bench.gc_paused():
            pass
        assert not gc.isenabled()  # a caller's own choice is kept
    finally:
        gc.enable()


# ------------------------------------------------------------------------------- peers: the chains they get


def no_peers(monkeypatch):
    """Make every peer library unimportable, as where the bench extra is not installed."""
    for name in PEER_MODULES:
        monkeypatch.setitem(sys.modules, name, None)


def test_the_panda_of_bench_ik_is_the_bundled_dh_model():
    assert (PANDA.frame, PANDA.kind) == ("flange", "site")
    assert PANDA.tree.model.nbody == mjkin.load("panda").model.nbody
    np.testing.assert_array_equal(PANDA.home, mjkin.load("panda").model.key_qpos[0])


def test_chain_check_refuses_an_fk_that_differs_beyond_1e_12():
    tree = PANDA.tree
    exact = peers.check_fk(lambda q: tree.pose(q, "flange"), tree, "flange", "site", "itself")
    assert exact == 0.0

    def shifted(q):
        T = tree.pose(q, "flange")
        T[0, 3] += 1e-9
        return T

    with pytest.raises(peers.Unavailable, match=r"a peer's FK differs from tree.pose\(q, 'flange'\) by 1.0e-09"):
        peers.check_fk(shifted, tree, "flange", "site", "a peer")


@pytest.mark.parametrize("model, frame, kind", [("panda", "flange", "site"), ("panda", "link7", "body"),
                                                ("arm7", "ee", "site")])
def test_urdf_of_the_chain_loaded_by_mujoco_gives_the_same_frame_pose(model, frame, kind):
    tree = mjkin.load(model)
    urdf = mujoco.MjModel.from_xml_string(peers.chain_urdf(tree, frame, kind))
    np.testing.assert_array_equal(urdf.jnt_range, tree.model.jnt_range)
    data = mujoco.MjData(urdf)
    tip = mujoco.mj_name2id(urdf, mujoco.mjtObj.mjOBJ_BODY, frame)
    Q = tree.random_q(np.random.default_rng(3), 50)
    for q, T in zip(Q, tree.pose(Q, frame, kind), strict=True):
        data.qpos[:] = q
        mujoco.mj_kinematics(urdf, data)
        np.testing.assert_allclose(data.xpos[tip], T[:3, 3], atol=1e-12, rtol=0)
        np.testing.assert_allclose(data.xmat[tip].reshape(3, 3), T[:3, :3], atol=1e-12, rtol=0)


def test_urdf_writer_refuses_what_a_urdf_chain_cannot_say():
    with pytest.raises(peers.Unavailable, match="'root' is not a hinge"):
        peers.chain_urdf(mjkin.load("primate"), "right_hand", "site")
    fork = mjkin.load(build.links_mjcf([build.Link("a"), build.Link("b", "a"), build.Link("c", "a")]))
    with pytest.raises(peers.Unavailable, match="not a serial chain: the model has 3 joints, 2 of them"):
        peers.chain_urdf(fork, "b", "body")
    still = mjkin.load(build.links_mjcf([build.Link("a", joint="fixed")]))
    with pytest.raises(peers.Unavailable, match="no joint"):
        peers.mdh_table(still, "a", "body")


def test_modified_dh_table_read_from_the_panda_is_its_published_table():
    rows, base, tool = peers.mdh_table(PANDA.tree, "flange", "site")
    Q = PANDA.tree.random_q(np.random.default_rng(4), 200)
    np.testing.assert_allclose(base @ dh_fk(rows, Q, convention="modified") @ tool, PANDA.tree.pose(Q, "flange"),
                               atol=1e-12, rtol=0)
    np.testing.assert_allclose(rows[:, [0, 2]], [[0, 0.333], [0, 0], [0, 0.316], [0.0825, 0], [-0.0825, 0.384],
                                                 [0, 0], [0.088, 0]], atol=1e-15)
    np.testing.assert_allclose(rows[:, 1], np.pi / 2 * np.array([0, -1, 1, 1, -1, 1, 1]), atol=1e-15)
    np.testing.assert_allclose(tool[:3, 3], [0, 0, 0.107], atol=1e-15)
    with pytest.raises(peers.Unavailable, match="turns about .* not its body's z"):
        peers.mdh_table(ARM7.tree, "ee", "site")  # arm7's second hinge turns about y


@given(dx=st.floats(-1e-4, 1e-4), angle=st.floats(-1e-3, 1e-3), axis=st.integers(0, 2))
def test_error_components_are_in_the_target_axes_as_trac_ik_judges(dx, angle, axis):
    q, targets = easy_targets(1)
    reached = targets.copy()  # reached = target moved along / about its own axes
    reached[0, :3, 3] += targets[0, :3, axis] * dx
    reached[0, :3, :3] = targets[0, :3, :3] @ axis_angle_to_mat(np.eye(3)[axis], angle)
    # q reaches ``targets``; judged against ``reached`` its error is minus that motion, along / about that axis
    e = error_components(ARM7.tree.model, ARM7.frame, ARM7.kind, q, reached)[0]
    expect = np.zeros(6)
    expect[axis], expect[3 + axis] = -dx, -angle
    np.testing.assert_allclose(e, expect, atol=1e-12)


def test_past_limits_measures_how_far_an_answer_leaves_its_range():
    tree = PANDA.tree
    q = np.stack([PANDA.home, PANDA.home])
    q[1, 5] = tree.jnt_range[5, 1] + 5.7e-8
    np.testing.assert_allclose(past_limits(tree, q), [0.0, 5.7e-8], rtol=1e-6)


def test_peers_that_are_not_installed_get_a_reason_instead_of_a_row(monkeypatch, capsys, tmp_path):
    no_peers(monkeypatch)
    report = bench_ik(["panda"], targets=2)
    rows = next(iter(report.tables.values()))
    assert [r["solver"] for r in rows] == ["mjkin", "mjkin.solve", "mjkin-single-start", "mujoco-dls"]
    skipped = report.extra["skipped"]
    assert [(r["model"], r["solver"]) for r in skipped] == [("panda", "mink"), ("panda", "rtb-ik_LM"),
                                                            ("panda", "trac-ik")]
    for r, package in zip(skipped, ("mink", "roboticstoolbox-python", "pytracik"), strict=True):
        assert r["reason"].startswith(f"{package} is not installed (pip install 'mjkin[bench]')")
    doc = report.as_json()
    assert doc["skipped"] == skipped and len(doc["rows"]) == 4  # reasons are kept apart from the measured rows
    out = tmp_path / "ik.json"
    assert cli.main(["bench", "ik", "--protocol", "trac-ik", "--models", "panda", "--targets", "2",
                     "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "peers without a row (the reason)" in printed and "pytracik is not installed" in printed
    assert [r["solver"] for r in json.loads(out.read_text())["skipped"]] == ["rtb-ik_LM", "trac-ik"]


def test_fk_bench_without_pinocchio_says_why(monkeypatch):
    no_peers(monkeypatch)
    report = bench.bench_fk(["panda", "primate"], sizes=[1], min_time=1e-3)
    single = list(report.tables.values())[1]
    assert {r["library"] for r in single} == {"mjkin", "mjkin without its C call", "mujoco"}
    assert [(r["model"], r["reason"].split(" (")[0]) for r in report.extra["skipped"]] == [
        ("panda", "pin is not installed"), ("primate", "pin is not installed")]


def test_fk_bench_refuses_pinocchio_on_a_chain_it_cannot_take(monkeypatch):
    pytest.importorskip("pinocchio", reason="pinocchio (pip install pin) is in the bench extra")
    report = bench.bench_fk(["primate"], sizes=[1], min_time=1e-3)
    (reason,) = [r["reason"] for r in report.extra["skipped"]]
    assert "is not a hinge" in reason


def test_time_limited_rows_count_late_answers_as_failures():
    q, targets = easy_targets()
    run = Run(q, np.array([1e-3, 9e-3, 1e-3, 1e-3]), np.ones(4), np.zeros(4))
    assert row(ARM7, "late", run, targets, 1e-9, 1e-9, within=run.seconds <= 5e-3)["success"] == 75.0


def test_table_columns_each_keep_one_number_format():
    rows = [{"us": 0.342, "per_s": 2_927_954.0, "err": 4.96e-9, "success": 100.0},
            {"us": 2.7, "per_s": 9870.0, "err": 0.0, "success": 88.25},
            {"us": 12.5, "per_s": 598.0, "err": 3e-8, "success": None},
            {"us": 1234.5, "per_s": 1e4, "err": 1.0, "success": 99.94}]
    lines = bench.format_table(rows).splitlines()
    cols = list(zip(*(line.split() for line in lines[2:]), strict=True))
    assert cols[0] == ("0.342", "2.700", "12.500", "1,234.500")
    assert cols[1] == ("2,927,954", "9,870", "598", "10,000")
    assert cols[2] == ("4.96e-09", "0.00e+00", "3.00e-08", "1.00e+00")
    assert cols[3] == ("100.0", "88.2", "-", "99.9")


# ------------------------------------------------------------------------- peers: with the bench extra installed


def needs(module: str, package: str):
    return pytest.importorskip(module, reason=f"{package} is in the bench extra (pip install 'mjkin[bench]')")


def test_rtb_chain_is_the_panda_to_1e_12():
    needs("roboticstoolbox", "roboticstoolbox-python")
    ets = peers.rtb_ets(PANDA.tree, "flange", "site")
    Q = PANDA.tree.random_q(np.random.default_rng(5), 20)
    for q, T in zip(Q, PANDA.tree.pose(Q, "flange"), strict=True):
        np.testing.assert_allclose(ets.fkine(q).A, T, atol=1e-12, rtol=0)


def test_trac_ik_and_pinocchio_chains_are_the_panda_to_1e_12():
    needs("trac_ik", "pytracik")
    pin = needs("pinocchio", "pin")
    solver = peers.trac_ik_solver(PANDA.tree, "flange", "site", 0.005, 1e-5)
    model, data, fid = peers.pinocchio_model(PANDA.tree, "flange", "site")
    Q = PANDA.tree.random_q(np.random.default_rng(6), 20)
    for q, T in zip(Q, PANDA.tree.pose(Q, "flange"), strict=True):
        pos, rot = solver.fk(q)
        np.testing.assert_allclose(pos, T[:3, 3], atol=1e-12, rtol=0)
        np.testing.assert_allclose(rot, T[:3, :3], atol=1e-12, rtol=0)
        pin.forwardKinematics(model, data, q)
        np.testing.assert_allclose(pin.updateFramePlacement(model, data, fid).homogeneous, T, atol=1e-12, rtol=0)


@pytest.mark.parametrize("protocol", ["default", "trac-ik"])
def test_peer_rows_carry_the_json_keys_and_are_rechecked_by_mujoco(protocol, tmp_path):
    needs("roboticstoolbox", "roboticstoolbox-python")
    needs("trac_ik", "pytracik")
    out = tmp_path / "ik.json"
    assert cli.main(["bench", "ik", "--protocol", protocol, "--models", "panda", "--targets", "4",
                     "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    by = {r["solver"]: r for r in doc["rows"]}
    assert {"rtb-ik_LM", "trac-ik"} <= set(by) and doc["skipped"] == []
    for name in ("rtb-ik_LM", "trac-ik"):
        r = by[name]
        assert {"model", "success", "median_ms", "p95_ms", "mean_ms", "median_ratio", "mean_ratio", "solver_says",
                "past_limits", "past_limit_max"} <= set(r)
        assert 0 <= r["success"] <= 100 and r["median_ms"] > 0 and r["p95_ms"] >= r["median_ms"]
    assert 0 <= by["trac-ik"]["success_per_component"] <= 100
    ref = by["mjkin" if protocol == "default" else "mjkin single"]
    assert ref["median_ratio"] == 1.0
    assert by["rtb-ik_LM"]["median_ratio"] == pytest.approx(by["rtb-ik_LM"]["median_ms"] / ref["median_ms"])
    if protocol == "trac-ik":
        assert by["rtb-ik_LM"]["timeouts"] >= 0


def test_rtb_answers_are_counted_by_mujoco_not_by_its_own_flag():
    needs("roboticstoolbox", "roboticstoolbox-python")
    from mjkin.apps.bench.ik import rtb_ik_lm

    T = targets_for(PANDA, 5, seed=2)
    run, said = rtb_ik_lm(PANDA, T, PANDA.home, 1e-5, 1e-5, slimit=25)
    ok = success(PANDA, run.q, T, 1e-5, 1e-5)
    assert (ok == said).all()  # its E < 0.5 min(tol, rot_tol)^2 keeps both errors within the norms
    assert (past_limits(PANDA.tree, run.q) == 0).all()  # it rejects answers outside the limits
