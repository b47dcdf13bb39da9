"""The optimize method reports SciPy's own iteration counts."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize

import mjkin
from conftest import tree_of
from mjkin.goals import Position


@pytest.fixture
def nits(monkeypatch):
    """SciPy's iteration count of every minimize call the optimize method makes (it imports SciPy's on first use)."""
    calls: list[int] = []
    real = scipy.optimize.minimize

    def counting(*args, **kwargs):
        res = real(*args, **kwargs)
        calls.append(int(res.nit))
        return res

    monkeypatch.setattr(scipy.optimize, "minimize", counting)
    return calls


def test_iterations_are_scipys(nits):
    tree = tree_of("arm7")
    target = tree.pose(tree.random_q(3), "ee")[:3, 3]
    res = mjkin.solve(tree, Position("ee", target), q0=tree.qpos0, method="optimize")
    assert res.success
    assert res.iterations == sum(nits) > 1  # it was always 1


def test_iterations_sum_over_restarts_and_targets(nits):
    tree = tree_of("arm7")
    far = np.array([[3.0, 0.0, 0.5], [0.0, 3.0, 0.5]])  # out of reach: every restart runs
    res = mjkin.solve(tree, Position("ee", far), method="optimize", restarts=2, max_iters=20)
    assert not res.success.any() and (res.restarts <= 2).all()
    assert len(nits) >= 6  # 2 targets x 3 starts
    assert res.iterations.sum() == sum(nits) and (res.iterations > 3).all()
