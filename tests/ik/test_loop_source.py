"""The IK loop is the package's own source: run as Python it steps in its file, and runs each kernel's own source."""

from __future__ import annotations

import bdb
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np

import mjkin
from conftest import tree_of
from mjkin import goals as G
from mjkin.ik import generated, loop


class _Stops(bdb.Bdb):
    """A debugger that notes where it stopped and goes on."""

    def __init__(self) -> None:
        super().__init__()
        self.stops: list[tuple[str, int]] = []

    def user_line(self, frame) -> None:  # type: ignore[no-untyped-def]
        self.stops.append((self.canonic(frame.f_code.co_filename), frame.f_lineno))
        self.set_continue()


def test_an_interpreted_solve_stops_at_a_breakpoint_in_the_loops_file(monkeypatch):
    """Under ``MJKIN_COMPILE=interpret`` the solve runs ``mjkin/ik/loop.py`` itself: a breakpoint there fires, and no
    code the solve runs comes from a generated module."""
    monkeypatch.setenv("MJKIN_COMPILE", "interpret")
    tree = tree_of("arm7")
    T = tree.pose(tree.random_q(np.random.default_rng(4), 1)[0], "ee")
    path = Path(loop.__file__).resolve()
    line = path.read_text().splitlines().index("        fk_into_scratch(kin, qt, rot, pos, irot, ipos, fA, ft, fR)") + 1
    files: set[str] = set()

    def calls(frame, event, arg):  # type: ignore[no-untyped-def]
        files.add(frame.f_code.co_filename)

    debugger = _Stops()
    debugger.set_break(str(path), line)
    result = debugger.runcall(mjkin.solve, tree, G.Pose("ee", T=T), restarts=0)
    assert result.success
    assert (debugger.canonic(str(path)), line) in debugger.stops
    sys.setprofile(calls)
    try:
        mjkin.solve(tree, G.Pose("ee", T=T), restarts=0)
    finally:
        sys.setprofile(None)
    assert str(path) in files or loop.__file__ in files
    assert not [f for f in files if Path(f).name.startswith(generated.PREFIX)]


def test_a_problem_hands_its_solve_to_its_method_and_built_in_kinds_run_the_loops_own_module():
    """``Problem`` solves through ``method.run`` with what the method prepared for it: for the Jacobian methods a
    ``Loop`` whose targets run in :mod:`mjkin.ik.loop` itself (a generated copy serves only a kind the user
    registered)."""
    tree = tree_of("arm7")
    T = tree.pose(tree.random_q(np.random.default_rng(5), 1)[0], "ee")
    problem = mjkin.Problem(tree, G.Pose("ee", T=T))
    assert problem.prepared.module is loop and generated.built_in(problem.structure.codes)
    assert problem.solve().success
    assert mjkin.Problem(tree, G.Position("ee", T[:3, 3]), method="ccd").prepared is None


_PATCHED = """
import mujoco
import numpy as np
import mjkin
from mjkin import goals as G
from mjkin.goals import residuals
from mjkin.ik import kernel
from mjkin.kinematics import fk, jacobian

tree = mjkin.load("arm7")
data = mujoco.MjData(tree.model)  # the target by MuJoCo: no kernel of mjkin runs before the edits
data.qpos[:] = tree.random_q(np.random.default_rng(4), 1)[0]
mujoco.mj_kinematics(tree.model, data)
T = np.eye(4)
T[:3, :3], T[:3, 3] = data.site("ee").xmat.reshape(3, 3), data.site("ee").xpos
ran = set()


def patch(kernel, also=None):
    real = kernel.py_func

    def edited(*args):
        ran.add(real.__name__)
        out = real(*args)
        if also is not None:
            also(*args)
        return out

    kernel.py_func = edited


def off_by_a_metre(ga, ws, i, b, g, J, r0, err):
    err[i, 0] += 1.0


patch(residuals.position_rows, off_by_a_metre)
for k in (residuals.orientation_rows, fk.fk_kernel_in, jacobian.jacobian_kernel, kernel.damped_solve,
          kernel.priority_step):
    patch(k)
result = mjkin.solve(tree, G.Pose("ee", T=T), restarts=0)
print(" ".join(sorted(ran)), float(result.error[0]), bool(result.success))
"""


def test_an_edit_of_a_kernels_source_changes_the_interpreted_answer(tmp_path):
    """Interpreted, the loop runs each kernel's own Python source (no stand-in of it): an edit of ``position_rows``
    that reports every error a metre larger reaches the answer, and FK, the Jacobian and the step run as written.
    A process of its own: interpreted kernels are made once per process."""
    env = {**os.environ, "MJKIN_COMPILE": "interpret"}
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(_PATCHED)], capture_output=True, text=True, env=env,
                         timeout=600, cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    ran, error, success = out.stdout.split("\n")[-2].rsplit(" ", 2)
    assert ran.split() == sorted(["position_rows", "orientation_rows", "fk_kernel_in", "jacobian_kernel",
                                  "damped_solve", "priority_step"])
    assert float(error) >= 1.0 and success == "False"
