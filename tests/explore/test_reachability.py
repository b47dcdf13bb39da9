"""Capability maps and base placement: against IK and FK, the cache, and the two commands."""

from __future__ import annotations

import importlib
import json

import numpy as np
import pytest

import mjkin
from mjkin import goals as G
from mjkin.apps.bench.arms import mjcf
from mjkin.apps.cli import main
from mjkin.explore.reachability import orientation_set

SMALL = {"resolution": 0.3, "orientations": 6, "samples": 4000}  # a coarse map: a second or two


@pytest.fixture(scope="module")
def ur() -> mjkin.Tree:
    return mjkin.load(mjcf("ur"))


@pytest.fixture(scope="module")
def ur_map(ur, tmp_path_factory):
    return mjkin.reachability(ur, "ee", cache=tmp_path_factory.mktemp("maps"), **SMALL)


def test_orientation_set_is_rotations_spread_over_the_sphere():
    R = orientation_set(50)
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), (50, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1, atol=1e-12)
    assert abs(R[:, :, 2].mean(0)).max() < 0.05  # z axes balanced over the sphere


def test_map_agrees_with_ik_and_the_reach_bound(ur, ur_map):
    m = ur_map
    assert m.reached.shape == m.shape + (6,) and m.share.min() >= 0 and m.share.max() == 1
    centres = m.centres().reshape(-1, 3)
    far = np.linalg.norm(centres - [0, 0, 0.1625], axis=-1) > 0.425 + 0.3922 + 0.1333 + 0.0997 + 0.0996 + 1e-9
    assert far.any() and not m.reached.reshape(len(centres), -1)[far].any()  # beyond the links' reach: never
    rng = np.random.default_rng(0)
    cells, k = rng.integers(0, len(centres), 60), rng.integers(0, 6, 60)
    brute = mjkin.solve(ur, [G.Position("ee", centres[cells]), G.Orientation("ee", m.orientations[k], axes="z")],
                        tol=1e-4, rot_tol=1e-3, restarts=48)
    assert np.mean(brute.success == m.reached.reshape(len(centres), -1)[cells, k]) >= 0.95
    assert m.at(centres[cells]).shape == (60,) and m.at([100.0, 0, 0]) == 0


def test_whole_orientations_from_quaternions(ur, ur_map):
    """Quaternions ask for whole orientations: never more reached than their z axes alone would be."""
    quats = mjkin.spatial.mat_to_quat(ur_map.orientations)
    full = mjkin.reachability(ur, "ee", **{**SMALL, "orientations": quats})
    assert full.axes == "xyz" and ur_map.axes == "z" and full.reached.shape == ur_map.reached.shape
    assert full.reached.sum() < ur_map.reached.sum()
    assert np.mean(full.reached <= ur_map.reached) > 0.99


def test_a_missing_cache_folder_is_refused_before_any_work(ur, tmp_path, monkeypatch):
    """It computed the whole map (minutes for a fine one), then raised that the folder does not exist."""
    def work(*args, **kwargs):
        raise RuntimeError("the map was computed")

    monkeypatch.setattr(importlib.import_module("mjkin.explore.reachability"), "solve", work)
    with pytest.raises(mjkin.MjkinIOError, match="the reachability cache folder .* does not exist: create it"):
        mjkin.reachability(ur, "ee", cache=tmp_path / "missing", **SMALL)


@pytest.mark.parametrize("region, step", [([-1e6, -1e6, 1e6, 1e6], None), ([0, 0, 1e308, 1e308], 1e-300),
                                          ([0, 0, 1000, 1000], 0.1)])
def test_a_base_grid_past_its_bound_is_one_line_not_a_memory_error(ur, ur_map, region, step):
    """A region of 2e6 m tried to allocate a 22.7 PiB grid (MemoryError)."""
    poses = ur.pose(ur.random_q(np.random.default_rng(0), 2), "ee")
    with pytest.raises(mjkin.InputError, match=r"base placements \(x, y, yaw\), more than 1,000,000: a smaller"):
        mjkin.place_base(ur, "ee", poses, region, step=step, capability=ur_map)


@pytest.mark.parametrize("n, verify, text", [
    (10**6, 10, r"target points to score \(placements x poses\), more than 20,000,000"),
    (200_000, 10, r"IK solves to verify \(verify x poses\), more than 1,000,000"),
])
def test_poses_past_their_bound_are_one_line_not_minutes_and_gigabytes(ur, ur_map, n, verify, text):
    """place_base with a million poses grew to 13.4 GB in 151 s: the work it would do is refused first, in one line."""
    poses = np.broadcast_to(ur.pose(ur.qpos0, "ee"), (n, 4, 4))
    with pytest.raises(mjkin.InputError, match=text) as info:
        mjkin.place_base(ur, "ee", poses, (0, 0, 1, 1), step=0.5, yaws=8, verify=verify, capability=ur_map)
    assert "\n" not in str(info.value)


def test_cache_round_trip(ur, ur_map, tmp_path, monkeypatch):
    first = mjkin.reachability(ur, "ee", cache=tmp_path, **SMALL)
    assert len(list(tmp_path.glob("reachability-*.npz"))) == 1
    def rebuilt(*args, **kwargs):
        raise RuntimeError("the cached map was rebuilt")

    # the module, not the function
    monkeypatch.setattr(importlib.import_module("mjkin.explore.reachability"), "solve", rebuilt)
    again = mjkin.reachability(ur, "ee", cache=tmp_path, **SMALL)
    np.testing.assert_array_equal(again.reached, first.reached)
    np.testing.assert_array_equal(again.origin, first.origin)
    np.testing.assert_array_equal(first.reached, ur_map.reached)  # same parameters, same map
    with pytest.raises(RuntimeError):  # other parameters are another file
        mjkin.reachability(ur, "ee", cache=tmp_path, **{**SMALL, "orientations": 4})
    assert not list(tmp_path.glob(".*mjkin-tmp*"))


def test_place_base_finds_where_the_poses_were_made(ur, ur_map):
    """Poses made by FK with the base at (1.0, 0.5), turned 90°: the chosen base reaches all, checked by FK."""
    rng = np.random.default_rng(4)
    B = np.array([[0.0, -1, 0, 1.0], [1, 0, 0, 0.5], [0, 0, 1, 0], [0, 0, 0, 1]])
    q = rng.uniform(-2, 2, (6, ur.nq))
    poses = B @ ur.pose(q, "ee")
    p = mjkin.place_base(ur, "ee", poses, (0.4, 0.0, 1.3, 0.9), capability=ur_map, yaws=4, verify=8,
                     step=0.1)
    assert p.count[0] == 6 and np.all(np.diff(p.count) <= 0)
    world = p.base(0) @ ur.pose(p.q[0], "ee")
    np.testing.assert_allclose(world, poses, atol=1e-3)
    assert p.heat.shape == (len(p.grid_x), len(p.grid_y))


@pytest.mark.parametrize("args, text", [
    ({"poses": np.zeros((3, 3))}, "poses must be"),
    ({"region": (1.0, 0.0, 0.0, 1.0)}, "region must be"),
    ({"region": (0.0, 0.0, 1.0)}, "region must be"),
    ({"yaws": 0}, "yaws must be"),
])
def test_place_base_bad_input_is_one_line(ur, ur_map, args, text):
    call = {"poses": np.broadcast_to(np.eye(4), (2, 4, 4)), "region": (0, 0, 1, 1), **args}
    with pytest.raises(mjkin.InputError, match=text) as info:
        mjkin.place_base(ur, "ee", call.pop("poses"), call.pop("region"), capability=ur_map, **call)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("bad, text", [
    ({"resolution": 0}, "resolution"),
    ({"orientations": np.zeros((2, 3))}, "orientations"),
    ({"frame": "nope"}, "nope"),
])
def test_reachability_bad_input_is_one_line(ur, bad, text):
    args = {"frame": "ee", **SMALL, **bad}
    with pytest.raises(mjkin.MjkinError, match=text) as info:
        mjkin.reachability(ur, args.pop("frame"), **args)
    assert "\n" not in str(info.value)


def test_ik_command_says_what_is_proven(capsys):
    assert main(["ik", "arm7", "--frame", "ee", "--pos", "3,0,0.5", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["reason"] == "out_of_reach"
    assert main(["ik", "arm7", "--frame", "ee", "--pos", "3,0,0.5"]) == 0
    assert "proven out of reach" in capsys.readouterr().out


def test_commands_write_their_plots(tmp_path, capsys):
    model = tmp_path / "ur.xml"
    model.write_text(mjcf("ur"))
    png = tmp_path / "map.png"
    cache = ["--cache", str(tmp_path), "--resolution", "0.3", "--orientations", "6"]
    assert main(["reachability", str(model), "--frame", "ee", "-o", str(png), *cache, "--slice", "z=0.3"]) == 0
    assert png.stat().st_size > 1000 and "reachable" in capsys.readouterr().out
    tree = mjkin.load(str(model))
    T = tree.pose(tree.random_q(np.random.default_rng(1), 3), "ee")
    rows = [[*t[:3, 3], *mjkin.spatial.mat_to_quat(t[:3, :3])] for t in T]
    poses = tmp_path / "poses.json"
    poses.write_text(json.dumps({"poses": rows}))
    heat = tmp_path / "heat.png"
    assert main(["place-base", str(model), "--frame", "ee", "--poses", str(poses), "--region", "-0.2,-0.2,0.2,0.2",
                 "--step", "0.1", "-o", str(heat), *cache]) == 0
    assert heat.stat().st_size > 1000 and "3/3 poses" in capsys.readouterr().out


@pytest.mark.parametrize("argv, text", [
    (["reachability", "arm7", "--frame", "nope"], "nope"),
    (["reachability", "arm7", "--frame", "ee", "-o", "map.txt"], "--output must end in"),
    (["reachability", "arm7", "--frame", "ee", "--resolution", "0.5", "--slice", "w=1"], "--slice must be"),
    (["place-base", "arm7", "--frame", "ee", "--poses", "missing.json", "--region", "0,0,1,1"],
     "--poses file not found"),
    (["place-base", "arm7", "--frame", "ee", "--poses", "POSES", "--region", "0,0,1"], "--region must be"),
    (["place-base", "arm7", "--frame", "ee", "--poses", "BAD", "--region", "0,0,1,1"], "must hold a list"),
])
def test_command_mistakes_exit_2_with_one_line(argv, text, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "POSES").write_text(json.dumps([[0.3, 0, 0.3, 1, 0, 0, 0]]))
    (tmp_path / "BAD").write_text(json.dumps({"poses": [[1, 2, 3]]}))
    assert main([*argv, "--cache", "none"]) == 2
    err = capsys.readouterr().err.strip()
    assert text in err and "\n" not in err and "Traceback" not in err


def test_a_full_cache_disk_never_fails_the_map(ur, tmp_path, monkeypatch):
    """``OSError: [Errno 28] No space left on device`` writing the cache threw away the map just built."""
    import errno

    import numpy as np

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(np, "savez_compressed", full)
    with pytest.warns(UserWarning, match=r"cannot write the reachability cache .*No space left on device; the map is "
                                         r"kept, not cached"):
        m = mjkin.reachability(ur, "ee", cache=tmp_path, **SMALL)
    assert m.reached.size and not list(tmp_path.iterdir())
