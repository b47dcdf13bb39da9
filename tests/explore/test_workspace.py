"""Workspaces by batched FK against the closed forms of planar two- and three-link arms (Polish lecture notes)."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

import mjkin
from conftest import tree_of
from mjkin.apps.cli import main
from mjkin.kinematics import build


@pytest.mark.parametrize("lengths", [(1.0, 0.7), (0.6, 1.1), (2.0, 0.5, 0.3), (15.0, 10.0, 5.0)])
def test_planar_annulus_matches_the_closed_form(lengths):
    tree = tree_of(build.planar_chain(list(lengths)))
    ws = mjkin.workspace(tree, "ee", 20_000)
    L = np.array(lengths)
    outer, inner = L.sum(), max(0.0, 2 * L.max() - L.sum())  # |L1 - L2| for two links
    assert ws.planar and ws.points.shape == (20_000, 3)
    np.testing.assert_allclose(np.abs(ws.normal), [0, 0, 1])
    assert outer * (1 - 2e-3) <= ws.outer <= outer * (1 + 1e-12)  # sampling never overshoots
    assert inner - 1e-12 <= ws.inner <= inner + 0.02 * outer
    r = np.linalg.norm(ws.plane_coords(), axis=-1)
    assert np.all((r >= inner - 1e-9) & (r <= outer + 1e-9))
    np.testing.assert_allclose(ws.points, tree.pose(tree.random_q(np.random.default_rng(0), 20_000), "ee")[:, :3, 3])


@pytest.mark.parametrize("lengths", [(3.0, 2.0, 0.5), (15.0, 10.0, 5.0), (1.0, 0.7), (0.6, 1.1)])
def test_dexterous_part_agrees_with_the_closed_form(lengths):
    """Every orientation is reachable iff the wrist circle (radius L3) fits the two-link annulus:
    ``|L1 - L2| + L3 <= r <= L1 + L2 - L3``; a two-link arm has no such point (one orientation per elbow).
    Pooling orientations from nearby samples labelled 54 % dexterous on the 15/10/5 arm against the closed
    form's 40.6 %, out to r = 21.35 and in a disc at the base."""
    ws = mjkin.workspace(tree_of(build.planar_chain(list(lengths))), "ee", 10_000)
    r = np.linalg.norm(ws.plane_coords(), axis=-1)
    if len(lengths) == 2:
        assert not ws.dexterous.any()
        return
    L1, L2, L3 = lengths
    closed = (r >= abs(L1 - L2) + L3) & (r <= L1 + L2 - L3)
    assert abs(ws.dexterous.mean() - closed.mean()) <= 0.01
    assert (ws.dexterous != closed).mean() <= 0.01  # point by point, not only in total
    assert np.all(ws.dexterity[ws.dexterous] == 1.0)  # the IK test only runs where pooling saw every bin
    lo, hi = abs(L1 - L2) + L3, L1 + L2 - L3
    assert lo - 0.02 * hi <= r[ws.dexterous].min() and r[ws.dexterous].max() <= hi * 1.005  # no disc, no halo


def test_dexterous_fraction_asks_for_part_of_the_orientations():
    tree = tree_of(build.planar_chain([3.0, 2.0, 0.5]))
    every, half = mjkin.workspace(tree, "ee", 5_000), mjkin.workspace(tree, "ee", 5_000, dexterous_fraction=0.5)
    assert np.all(half.dexterous >= every.dexterous) and half.dexterous.mean() > every.dexterous.mean() + 0.1


def test_3d_workspace_and_errors(tmp_path):
    tree = tree_of("arm7")
    ws = mjkin.workspace(tree, "ee", 5_000)
    assert not ws.planar and ws.normal is None
    d = np.linalg.norm(ws.points - ws.base, axis=-1)
    assert ws.outer == pytest.approx(d.max()) and ws.outer <= 0.24 + 0.2 + 0.2 + 0.2 + 0.19 + 0.02 + 0.08 + 1e-9
    np.testing.assert_allclose(ws.lo, ws.points.min(0))
    with pytest.raises(mjkin.MjkinError, match="unknown site or body 'hand'"):
        mjkin.workspace(tree, "hand", 10)
    with pytest.raises(mjkin.InputError, match="at least 2 samples"):
        mjkin.workspace(tree, "ee", 1)


def test_cli_workspace_plot(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    out = tmp_path / "ws.png"
    assert main(["workspace", "planar_2link", "--frame", "tip", "--samples", "3000", "-o", str(out)]) == 0
    assert out.stat().st_size > 5000 and "annulus 0.3 <= r <= 1.7" in capsys.readouterr().out
    assert main(["workspace", "planar_3link", "-o", str(tmp_path / "tip.png"), "--samples", "500"]) == 0
    assert "annulus" in capsys.readouterr().out  # the last site (the tip) by default
    assert main(["workspace", "arm7", "--frame", "nope", "-o", str(tmp_path / "x.png")]) == 2
    assert "unknown site or body 'nope'" in capsys.readouterr().err and not (tmp_path / "x.png").exists()


def test_cli_workspace_checks_the_output_before_sampling(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(importlib.import_module("mjkin.explore.workspace"), "workspace",
                        lambda *a, **k: pytest.fail("sampling ran before the output was checked"))
    (tmp_path / "dir.png").mkdir()
    for out, text in (("dir.png", "--output '{}' is a folder; give a file name"), ("ws.mp4", "must end in .png"),
                      ("no/ws.png", "folder '{}' does not exist")):
        path = tmp_path / out
        assert main(["workspace", "arm7", "-o", str(path)]) == 2
        err = capsys.readouterr().err
        assert text.format(path if out == "dir.png" else path.parent) in err and err.count("\n") == 1
    assert [p.name for p in tmp_path.iterdir()] == ["dir.png"]
