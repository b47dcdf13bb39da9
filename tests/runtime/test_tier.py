"""Interpreted first, compiled behind (mjkin.runtime.tier): the Python versions solve as the compiled kernels do, a
child compiles into the disk cache, and the first call after it runs compiled, loaded, not compiled here."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import mjkin
import mjkin.goals as G
from conftest import GYM_ASSETS, tree_of
from mjkin.errors import InputError
from mjkin.runtime import tier

PANDA_T = np.array([[1, 0, 0, 0.4], [0, -1, 0, 0.1], [0, 0, -1, 0.5], [0, 0, 0, 1.0]])


def _goals(tree):
    """One problem per common goal kind (and their mixes, priorities, a hard constraint) on the Panda."""
    q = tree.qpos0
    return {
        "pose": [G.Pose("ee", PANDA_T)],
        "position+orientation": [G.Position("ee", [0.3, -0.2, 0.6]), G.Orientation("ee", quat=[0, 1, 0, 0])],
        "aim+line": [G.Aim("ee", axis=[0, 0, 1], point=[0.6, 0.0, 0.0]), G.Line("ee", point=[0.4, 0, 0.5])],
        "plane+rest": [G.Plane("ee", point=[0, 0, 0.4]), G.Rest(q, 0.01)],
        "halfspace (hard) under a priority": [G.Position("ee", [0.5, 0.1, 0.3]),
                                              G.HalfSpace("ee", point=[0, 0, 0.35], normal=[0, 0, 1]),
                                              G.Orientation("ee", quat=[0, 1, 0, 0], priority=1)],
        "coupling+steplimit": [G.Position("ee", [0.4, 0.2, 0.5]), G.Coupling({"j1": 1.0, "j3": -1.0}),
                               G.StepLimit(q, 2.0)],
    }


def _same(ran, want, converged_atol=1e-9):
    """The same outcome; the path may part in the last bits (numpy's sums and LAPACK, not LLVM's loops), which a
    run that stops unconverged (at max_iters, against a constraint) can carry to ~1e-6."""
    assert np.array_equal(ran.success, want.success)
    # an unmet run's status may turn on a row at a threshold (constraint or max_iterations), which rounding moves
    met = np.atleast_1d(want.success)
    assert np.array_equal(np.atleast_1d(ran.status)[met], np.atleast_1d(want.status)[met])
    assert np.all(np.abs(np.asarray(ran.iterations) - want.iterations) <= 2)
    np.testing.assert_allclose(ran.q, want.q, rtol=0, atol=converged_atol if np.all(want.success) else 1e-5)


def _both(monkeypatch, solve):
    """``solve()`` compiled (``wait``), then interpreted."""
    monkeypatch.setenv("MJKIN_COMPILE", "wait")
    want = solve()
    monkeypatch.setenv("MJKIN_COMPILE", "interpret")
    return solve(), want


@pytest.mark.parametrize("method", ["auto", "dls", "pinv", "transpose"])
@pytest.mark.parametrize("name", list(_goals(mjkin.load("panda"))))
def test_the_interpreted_loop_solves_as_the_compiled_one(monkeypatch, name, method):
    """The IK loop run as Python (no compile) solves as the compiled loop does."""
    tree = mjkin.load("panda")
    goals = _goals(tree)[name]
    for q0 in (tree.qpos0, tree.qpos0 + 0.1):
        _same(*_both(monkeypatch, lambda q0=q0: mjkin.Problem(tree, goals, method=method, max_iters=30).solve(q0)))


@pytest.mark.parametrize("model, frame, kind", [("primate", "left_hand", "site"), ("ball_chain", "tip", "site"),
                                               (GYM_ASSETS / "humanoid.xml", "left_lower_arm", "body")])
def test_the_interpreted_loop_solves_a_figure_as_the_compiled_one(monkeypatch, model, frame, kind):
    """Ball and free joints, and bodies with several joints (gymnasium's humanoid): the numpy stand-ins of the step,
    the frame rows and the Jacobian (what the first run's figures run as Python) solve as the compiled kernels do."""
    tree = tree_of(model)
    q = tree.random_q(np.random.default_rng(4), 1)[0]
    T = tree.pose(q, frame, kind)
    goals = [G.Position(frame, T[:3, 3], kind=kind), G.Orientation(frame, T[:3, :3], kind=kind, priority=1),
             G.Rest(tree.qpos0, priority=2)]
    # the rest level is never met: where the levels above converge it stops mid-way, and the rounding that parted
    # the paths moves along it (1e-9 on the ball chain, plain Python or numpy alike)
    _same(*_both(monkeypatch, lambda: mjkin.Problem(tree, goals, max_iters=30).solve(tree.qpos0)), 1e-7)


def test_a_small_batch_runs_interpreted_as_compiled(monkeypatch):
    tree = mjkin.load("panda")
    T = np.repeat(PANDA_T[None], 3, axis=0)
    T[:, :3, 3] += np.array([[0.0, 0, 0], [0.05, -0.1, 0.0], [-0.1, 0.1, 0.1]])
    _same(*_both(monkeypatch, lambda: mjkin.solve(tree, G.Pose("ee", T), seed=1)))


def test_interpret_mode_compiles_nothing_for_a_solve(monkeypatch):
    """MJKIN_COMPILE=interpret: a problem of a new goal mix solves with no numba compilation at all."""
    from numba.core.event import install_recorder

    monkeypatch.setenv("MJKIN_COMPILE", "interpret")
    tree = mjkin.load("planar_3link")
    with install_recorder("numba:compile") as rec:
        res = mjkin.solve(tree, [G.Position("tip", [0.5, 0.9, 0.0]), G.Plane("tip", point=[0, 0, 0])], seed=3)
    assert res.success and rec.buffer == []


def test_a_bad_mode_says_which_there_are(monkeypatch):
    monkeypatch.setenv("MJKIN_COMPILE", "later")
    with pytest.raises(InputError, match="MJKIN_COMPILE must be one of background, wait, interpret, got 'later'"):
        tier.mode()


def test_a_kernel_a_child_cannot_import_is_never_sent_to_one():
    from mjkin.runtime.jit import njit

    @njit
    def local(x):
        return x + 1.0

    assert tier._address(local) is None  # defined in a function: compiled in this process when it must be
    assert tier._address(mjkin.kinematics.qspace.clip_kernel)[2] == "clip_kernel"


_CHILD = textwrap.dedent("""
    import sys, time
    import numpy as np
    sys.path.insert(0, sys.argv[1])
    from mjkin.runtime import progress, tier
    from tiered import triple
    progress.enable(True)
    x = np.arange(3.0)
    call = tier.first_use(triple)
    first = call(x)  # interpreted: nothing compiled here
    compiled_here = len(triple.overloads)
    sig = (triple.typeof_pyval(x),)
    deadline = time.monotonic() + 240
    while tier._COMPILER.status([(triple, sig)], submit=False) != "done" and time.monotonic() < deadline:
        time.sleep(0.1)
    second = call(x)  # compiled, loaded from the cache the child wrote
    print(first.tolist(), second.tolist(), compiled_here, len(triple.overloads), sum(triple._cache_hits.values()))
""")


def _run_tiered(tmp_path: Path, script: str) -> subprocess.CompletedProcess:
    """Run ``script`` in a ``background``-mode process with a module ``tiered`` (a kernel ``triple``) and a cache of its
    own in ``tmp_path``."""
    (tmp_path / "tiered.py").write_text("from mjkin.runtime.jit import njit\n\n\n@njit\ndef triple(x):\n"
                                        "    return 3.0 * x\n")
    env = {**os.environ, "MJKIN_COMPILE": "background", "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    return subprocess.run([sys.executable, "-c", script, str(tmp_path)], capture_output=True, text=True, env=env,
                          timeout=300, check=True)


def test_a_cold_kernel_runs_interpreted_while_a_child_compiles_it_then_loads_it(tmp_path):
    run = _run_tiered(tmp_path, _CHILD)
    # the same answers; none compiled in the process before; one version after, loaded from the cache (a hit)
    assert run.stdout.strip() == "[0.0, 3.0, 6.0] [0.0, 3.0, 6.0] 0 1 1"
    notes = run.stderr.splitlines()
    assert notes[0] == f"mjkin: {tier.BACKGROUND}"
    assert notes[1].startswith("mjkin: kernels compiled in the background in ")
    assert len(notes) == 2


@pytest.mark.parametrize("model", ["panda", "arm7", "primate", "ball_chain", "planar_prismatic"])
def test_a_one_q_pose_interpreted_equals_the_compiled_one(model):
    """The one-q chain kernels as Python (what tree.pose runs while a child compiles them) give the same poses."""
    from mjkin.kinematics import chain as chains

    tree = mjkin.load(model)
    for q in tree.random_q(np.random.default_rng(2), 5):
        T = np.empty((tree.model.nbody, 4, 4))
        assert tier.interpreted_call(chains.chain_poses, tree.bodies_chain, q, T)
        np.testing.assert_allclose(T, tree.fk(q), rtol=0, atol=1e-14)
        site = tree.model.site(tree.model.nsite - 1).name
        one = np.empty((4, 4))
        assert tier.interpreted_call(chains.chain_pose, tree._chain(site, None), q, one)
        np.testing.assert_allclose(one, tree.pose(q, site), rtol=0, atol=1e-14)


def test_a_cold_pose_in_background_mode_compiles_nothing_here(tmp_path):
    """tree.pose and tree.fk of one q from an empty cache: answered at once, as Python, with no compile here."""
    script = ("import numpy as np, mjkin, mjkin.runtime.tier\nfrom numba.core.event import install_recorder\n"
              "tree = mjkin.load('arm7')\n"
              "with install_recorder('numba:compile') as rec:\n"
              "    T = tree.pose(tree.qpos0, 'ee'); F = tree.fk(tree.qpos0)\n"
              "print(len(rec.buffer), np.isfinite(T).all() and np.isfinite(F).all())\n"
              "mjkin.runtime.tier.settle()\n")  # the child done before its cache folder goes
    env = {**os.environ, "MJKIN_COMPILE": "background", "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=300,
                         check=True)
    assert run.stdout.split() == ["0", "True"]


_ELSEWHERE = textwrap.dedent("""
    import fcntl, os, subprocess, sys, time
    import numpy as np
    sys.path.insert(0, sys.argv[1])
    from mjkin.runtime import tier
    from tiered import triple
    x = np.arange(3.0)
    sig = (triple.typeof_pyval(x),)
    # another run's child at work on this kernel: it holds the kernel's compile lock
    other = subprocess.Popen([sys.executable, "-c", "import fcntl, os, sys, time; fd = os.open(sys.argv[1], os.O_RDWR "
                              "| os.O_CREAT); fcntl.flock(fd, fcntl.LOCK_EX); print(1, flush=True); time.sleep(60)",
                              triple._cache.lock_path()], stdout=subprocess.PIPE, text=True)
    other.stdout.readline()
    state = tier._COMPILER.status([(triple, sig)])
    no_child = tier._COMPILER.child is None
    first = tier.first_use(triple)(x)  # interpreted meanwhile
    other.kill(); other.wait()  # it stopped before writing this version: ours to ask for now
    deadline = time.monotonic() + 240
    while tier._COMPILER.status([(triple, sig)]) != "done" and time.monotonic() < deadline:
        time.sleep(0.1)
    print(state, no_child, first.tolist(), tier._COMPILER.status([(triple, sig)], submit=False))
""")


def test_a_kernel_another_process_compiles_starts_no_second_child(tmp_path):
    """Ten cold runs in a row no longer leave ten children: a run that finds a kernel at work waits for that one."""
    run = _run_tiered(tmp_path, _ELSEWHERE)
    assert run.stdout.strip() == "elsewhere True [0.0, 3.0, 6.0] done"


_KILLED = textwrap.dedent("""
    import os, signal, sys, time
    import numpy as np
    sys.path.insert(0, sys.argv[1])
    from numba.core.event import install_recorder
    from mjkin.runtime import tier
    from tiered import triple
    x = np.arange(3.0)
    sig = (triple.typeof_pyval(x),)
    call = tier.first_use(triple)
    call(x)
    first = tier._COMPILER.child
    os.kill(first.pid, signal.SIGKILL)
    deadline = time.monotonic() + 240
    while tier._COMPILER.status([(triple, sig)], submit=False) != "done" and time.monotonic() < deadline:
        time.sleep(0.1)
    with install_recorder("numba:compile") as rec:
        out = call(x)
    # reaped without another call: no zombie under this process
    while os.path.exists(f"/proc/{first.pid}") and time.monotonic() < deadline:
        time.sleep(0.1)
    print(tier._COMPILER.retried, len(rec.buffer), out.tolist(), os.path.exists(f"/proc/{first.pid}"))
""")


def test_a_killed_child_is_started_again_not_compiled_here_and_children_are_reaped(tmp_path):
    run = _run_tiered(tmp_path, _KILLED)
    assert run.stdout.strip() == "True 0 [0.0, 3.0, 6.0] False"


_REAPED = textwrap.dedent("""
    import os, sys, time
    import numpy as np
    sys.path.insert(0, sys.argv[1])
    from mjkin.runtime import tier
    from tiered import triple
    tier.first_use(triple)(np.arange(3.0))
    pid = tier._COMPILER.child.pid
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline:  # no call of ours: only a reaper can collect it
        try:
            with open(f"/proc/{pid}/stat") as f:
                if f.read().split()[2] == "Z":  # ended, not collected
                    time.sleep(1.0)
                    break
        except FileNotFoundError:  # collected
            break
        time.sleep(0.1)
    print(os.path.exists(f"/proc/{pid}"))
""")


def test_a_finished_child_leaves_no_zombie_under_a_long_lived_parent(tmp_path):
    run = _run_tiered(tmp_path, _REAPED)
    assert run.stdout.strip() == "False"


_STUCK = textwrap.dedent("""
    import fcntl, os, sys
    import numpy as np
    sys.path.insert(0, sys.argv[1])
    from mjkin.runtime import cache, progress
    from tiered import triple
    progress.enable(True)
    cache.LOCK_WAIT = 1.0
    holder = os.open(triple._cache.lock_path(), os.O_RDWR | os.O_CREAT)
    fcntl.flock(holder, fcntl.LOCK_EX)  # a process that hangs holding it (another open file: to flock, another one)
    print(triple(np.arange(3.0)).tolist())
""")


def test_a_compile_lock_held_too_long_is_waited_for_a_bounded_time_and_said(tmp_path):
    """MJKIN_COMPILE=wait behind a lock that is never given back: the kernel is compiled here after the bound."""
    (tmp_path / "tiered.py").write_text("from mjkin.runtime.jit import njit\n\n\n@njit\ndef triple(x):\n"
                                        "    return 3.0 * x\n")
    env = {**os.environ, "MJKIN_COMPILE": "wait", "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    run = subprocess.run([sys.executable, "-c", _STUCK, str(tmp_path)], capture_output=True, text=True, env=env,
                         timeout=120, check=True)
    assert run.stdout.strip() == "[0.0, 3.0, 6.0]"
    assert "another process held its compile lock for 1 s; compiling it here" in run.stderr


_NO_JIT = textwrap.dedent("""
    import json, numba, numpy as np, mjkin, mjkin.goals as G
    assert numba.config.DISABLE_JIT
    tree = mjkin.load("panda")
    q = tree.random_q(np.random.default_rng(3), 3)
    T = tree.pose(q[0], "flange")
    res = mjkin.solve(tree, [G.Pose("flange", T=tree.pose(q[1], "flange")), G.Clearance(0.0)], q0=q[2])
    print(json.dumps([T.tolist(), tree.fk(q).tolist(), tree.jacobian(q, "flange").tolist(), bool(res.success),
                      res.status]))
""")


def test_numbas_disable_jit_switch_imports_and_solves_as_python():
    """NUMBA_DISABLE_JIT=1 (debuggers, coverage): mjkin imports, and FK, Jacobians and a solve run as the compiled
    kernels do, slowly."""
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1"}
    run = subprocess.run([sys.executable, "-c", _NO_JIT], capture_output=True, text=True, env=env, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    T, F, J, success, status = json.loads(run.stdout)
    tree = mjkin.load("panda")
    q = tree.random_q(np.random.default_rng(3), 3)
    np.testing.assert_allclose(T, tree.pose(q[0], "flange"), rtol=0, atol=1e-14)
    np.testing.assert_allclose(F, tree.fk(q), rtol=0, atol=1e-14)
    np.testing.assert_allclose(J, tree.jacobian(q, "flange"), rtol=0, atol=1e-14)
    assert success and status == "converged"


_OUTLIVES = textwrap.dedent("""
    import sys
    import numpy as np
    sys.path.insert(0, sys.argv[1])
    from mjkin.runtime import progress, tier
    from tiered import triple
    progress.enable(True)
    tier.first_use(triple)(np.arange(3.0))  # a child starts compiling it
    tier.flush()  # as the CLI does when a command ends: the child is still at work
    progress.enable(False)
    tier.settle()  # (the child done before the test's cache folder goes)
""")


def test_a_child_that_outlives_its_command_says_so():
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        run = _run_tiered(Path(folder), _OUTLIVES)
    assert "a background process (pid " in run.stderr and "low priority" in run.stderr
