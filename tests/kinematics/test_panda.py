"""The bundled Panda: its flange is the published modified-DH product, and the shipped file is the builder's."""

from __future__ import annotations

import importlib.util

import numpy as np

import mjkin
from conftest import ROOT
from mjkin.kinematics.build import dh_fk
from mjkin.scene import Scene


def builder():
    spec = importlib.util.spec_from_file_location("build_panda", ROOT / "examples" / "build_panda.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_flange_is_the_dh_product_and_limits_and_home_are_franka_s():
    b = builder()
    tree = mjkin.load("panda")
    qs = tree.random_q(0, 500)
    flange = np.eye(4)
    flange[2, 3] = 0.107
    expected = dh_fk(b.DH, qs, convention="modified") @ flange
    np.testing.assert_allclose(tree.pose(qs, "flange"), expected, atol=1e-9, rtol=0)
    lo, hi = tree.layout.scalar_lo, tree.layout.scalar_hi
    np.testing.assert_array_equal(np.stack([lo, hi], 1), b.LIMITS)
    home = tree.model.key_qpos[tree.model.key("home").id]
    np.testing.assert_array_equal(home, [0, -np.pi / 4, 0, -3 * np.pi / 4, 0, np.pi / 2, np.pi / 4])
    # at home the flange hangs over the table in front of the base, pointing down
    T = tree.pose(home, "flange")
    np.testing.assert_allclose(T[:3, 3], [0.3069, 0.0, 0.5903], atol=1e-4)
    np.testing.assert_allclose(T[:3, 2], [0, 0, -1], atol=1e-9)


def test_geometry_is_clear_at_home_and_mostly_clear_elsewhere():
    tree = mjkin.load("panda")
    scene = Scene(tree)
    assert scene.contacts(tree.model.key_qpos[0]) == []
    assert scene.in_collision(tree.random_q(1, 500)).mean() < 0.1


def test_shipped_model_is_what_the_builder_writes(tmp_path):
    out = tmp_path / "panda.xml"
    import sys

    argv = sys.argv
    sys.argv = ["build_panda.py", "-o", str(out)]
    try:
        builder().main()
    finally:
        sys.argv = argv
    assert out.read_text() == (ROOT / "models" / "panda.xml").read_text()
