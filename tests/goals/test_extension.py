"""A new goal kind is one module and one registry line: here, the distance between two frames, in this file alone."""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest

import mjkin
from conftest import TESTS, tree_of
from mjkin import goals as G
from mjkin.goals.base import METRES, FrameGoal, Units
from mjkin.ik import evaluate, generated
from mjkin.kinematics.jacobian import jacobian_kernel
from mjkin.runtime.jit import njit_ir_inline


@dataclass(frozen=True)
class Distance(FrameGoal):
    """Keep the frame's origin ``length`` metres from the origin of the frame ``other``."""

    other: str = ""
    length: float = 0.0
    rows: ClassVar[int] = 1
    units: ClassVar[Units] = METRES

    def key(self) -> tuple:
        return super().key() + (self.other,)

    def static(self, tree):
        body, lrot, lpos, _, _ = super().static(tree)
        other, _ = tree.frame_body(self.other)
        return body, lrot, lpos, other, None

    def encode(self, tree, data, rest):
        data[:, 0] = self.length
        data[:, 1:4] = tree.frame_body(self.other)[1][:3, 3]  # the other frame's origin in its body


@njit_ir_inline
def residual(kin, ga, ws, rot, pos, irot, ipos, i, b, q, g, J, r0, err):
    """One row: ``|p - p_other| - length``."""
    J6, pt = ws[0], ws[1]
    nv = J.shape[1]
    ob = ga.aux[i]
    po = np.empty((1, 3))
    for a in range(3):
        po[0, a] = pos[0, ob, a] + (rot[0, ob, a, 0] * ga.data[b, i, 1] + rot[0, ob, a, 1] * ga.data[b, i, 2]
                                    + rot[0, ob, a, 2] * ga.data[b, i, 3])
    Jo = np.zeros((1, 6, nv))
    jacobian_kernel(rot, pos, irot, ipos, kin.body_dof_idx[kin.body_dof_ptr[ob]:kin.body_dof_ptr[ob + 1]],
                    kin.dof_body, kin.dof_inner, kin.dof_axis, kin.dof_world, kin.dof_rot, kin.dof_anchor, po, Jo)
    d = np.array([pt[0, 0] - po[0, 0], pt[0, 1] - po[0, 1], pt[0, 2] - po[0, 2]])
    L = max(np.sqrt(d @ d), 1e-12)
    w = ga.sqrt_w[i]
    g[r0] = w * (L - ga.data[b, i, 0])
    for j in range(nv):
        J[r0, j] = w * (d[0] * (J6[0, 0, j] - Jo[0, 0, j]) + d[1] * (J6[0, 1, j] - Jo[0, 1, j])
                        + d[2] * (J6[0, 2, j] - Jo[0, 2, j])) / L
    err[i, 0] = abs(L - ga.data[b, i, 0])


def check_distance_kind() -> None:
    """Register the kind, check its residual and Jacobian, and solve with it (in a process of its own).

    The residual and Jacobian come from the generated module's compiled evaluator (the kind compiles with the
    loop's code); the solve runs the generated loop as Python, as a user's first solve of a new kind does while a
    child compiles it (:mod:`mjkin.runtime.tier`): the loop's own compile is a minute of CPU that the suite's
    solves of the built-in kinds already cover.
    """
    G.register(Distance)
    tree = tree_of("primate")
    hands = Distance("left_hand", other="right_hand", length=0.25)
    q = tree.random_q(np.random.default_rng(0), 4)
    for k in range(len(q)):
        g, J, err = evaluate(tree, hands, q[k])
        gap = np.linalg.norm(tree.pose(q[k], "left_hand")[:3, 3] - tree.pose(q[k], "right_hand")[:3, 3])
        assert abs(g[0, 0] - (gap - 0.25)) <= 1e-12 and abs(err[0, 0, 0] - abs(gap - 0.25)) <= 1e-12
        fd = np.empty(tree.nv)
        for j in range(tree.nv):
            e = np.zeros(tree.nv)
            e[j] = 1e-6
            fd[j] = (evaluate(tree, hands, tree.integrate(q[k], e))[0][0, 0]
                     - evaluate(tree, hands, tree.integrate(q[k], -e))[0][0, 0]) / 2e-6
        np.testing.assert_allclose(J[0, 0], fd, atol=1e-6)  # the Jacobian against central differences
    assert mjkin.Problem(tree, hands).prepared.module.__name__.startswith(generated.PREFIX)  # the loop's copy
    os.environ["MJKIN_COMPILE"] = "interpret"
    res = mjkin.solve(tree, [hands, G.Position("head", tree.pose(tree.qpos0, "head")[:3, 3])], root="lower_torso")
    assert res.success and res.goal_errors[1, 0] <= 1e-6  # after the root's pose goal, the distance
    T = tree.pose(res.q, "left_hand"), tree.pose(res.q, "right_hand")
    assert abs(np.linalg.norm(T[0][:3, 3] - T[1][:3, 3]) - 0.25) <= 1e-6


# its own process: the registry is global, and the suite's other tests run on the built-in kinds' loop. Compiling
# the evaluator with the new kind takes half a minute, so conftest runs this test first: the other test workers go on.
FIRST = True


def test_a_kind_added_in_a_test_file_is_solved_and_its_jacobian_is_right():
    path = os.pathsep.join(filter(None, [str(TESTS), os.environ.get("PYTHONPATH")]))  # for ``conftest``
    run = subprocess.run([sys.executable, "-c", "import test_extension; test_extension.check_distance_kind()"],
                         cwd=Path(__file__).parent, env={**os.environ, "PYTHONPATH": path}, capture_output=True,
                         text=True, timeout=1800)
    assert run.returncode == 0, (run.stdout + run.stderr)[-3000:]


def test_a_kind_without_a_compiled_residual_is_refused():
    @dataclass(frozen=True)
    class Loose(FrameGoal):
        rows: ClassVar[int] = 1
        units: ClassVar[Units] = METRES

    with pytest.raises(mjkin.GoalError, match="residual must be a numba-compiled function"):
        G.register(Loose, residual=lambda *a: None)
    with pytest.raises(mjkin.GoalError, match="Loose is not registered"):
        mjkin.solve(tree_of("arm7"), Loose("ee"))
