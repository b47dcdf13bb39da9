"""Benchmarks report what they measured: small runs, checked for content, never for speed."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

import mjkin
from mjkin.bench import bench_ik, mink_loop, pose_errors


def test_bench_ik_reports_mjkin_beside_its_baseline():
    (rows,) = bench_ik(n=8).values()
    arms = {r["arm"] for r in rows} - {"-"}
    assert "arm7" in arms
    for arm in arms:
        by = {r["solver"]: r for r in rows if r["arm"] == arm}
        assert {"mjkin", "mjkin batched", "mujoco DLS loop"} <= set(by)
        assert by["mjkin"]["success %"] == by["mjkin batched"]["success %"] == 100.0
        assert by["mujoco DLS loop"]["solves/s vs baseline"] == 1.0


@pytest.mark.skipif(importlib.util.find_spec("mink") is None, reason="mink is the optional bench extra")
def test_mink_baseline_reaches_easy_targets():
    tree = mjkin.load("arm7")
    home = tree.model.key_qpos[0]
    near = tree.pose(home + 0.05 * np.random.default_rng(0).standard_normal((5, 7)), "ee")
    reached, times = mink_loop(tree.model, "ee", "site", near, home, 1e-4, 1e-3)
    ep, er = pose_errors(reached, near)
    assert (ep <= 1e-4).all() and (er <= 1e-3).all() and (times > 0).all()
