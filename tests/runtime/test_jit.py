"""The numba set-up: the kernel cache (stamped by what a kernel imports, read where it cannot write), borrowed views."""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numba
import numpy as np

import mjkin
from conftest import tree_of
from mjkin.goals import Position
from mjkin.ik.packed import FIELDS, Packed
from mjkin.runtime.numba_ext import borrowed, borrowed_fields, keep_alive
from mjkin.runtime.numba_private import entry

# a package of two files: a kernel in kern.py that inlines a helper from help.py (as the IK loop inlines FK)
_HELP = "from mjkin.runtime.jit import njit_inline\n\n\n@njit_inline\ndef shift(x):\n    return x + {k}\n"
_KERN = ("from mjkin.runtime.jit import njit\n\nfrom .help import shift\n\n\n"
         "@njit\ndef kernel(x):\n    return shift(x) * 2.0\n")
_RUN = ("import sys; sys.path.insert(0, sys.argv[1]); from kpkg.kern import kernel; "
        "print(kernel(1.0), kernel.stats.cache_hits.get(kernel.signatures[0], 0) if kernel.signatures else 0)")


def _package(root, k=1.0):
    pkg = root / "kpkg"
    pkg.mkdir(parents=True, exist_ok=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "help.py").write_text(_HELP.format(k=k))
    (pkg / "kern.py").write_text(_KERN)
    return pkg


def _run(root, **env):
    import os
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _RUN, str(root)], capture_output=True, text=True, timeout=300,
                         env={**os.environ, **env}, check=True).stdout.split()
    return float(out[0]), int(out[1])  # the answer, and whether it came from a cache (1) or was compiled (0)


def test_a_kernel_is_stamped_with_its_packages_sources_as_this_process_loaded_them(tmp_path, monkeypatch):
    """An edit of any file of the package (not the kernel's own alone, as numba stamps) gives a new stamp in the next
    process; within this one the stamp stays that of the sources it loaded, which is what it compiled."""
    from mjkin.runtime import cache

    pkg = _package(tmp_path)
    before = cache.stamp(pkg / "kern.py")
    assert cache.stamp(pkg / "help.py") == before  # one package, one stamp
    (pkg / "help.py").write_text(_HELP.format(k=2.0))  # another file than the kernel's
    assert cache.stamp(pkg / "kern.py") == before  # as loaded: what this process compiles
    monkeypatch.setattr(cache, "_LOADED", {})  # a new process
    after = cache.stamp(pkg / "kern.py")
    assert after != before
    (pkg / "notes.py").write_text("# a module no kernel imports\n")
    monkeypatch.setattr(cache, "_LOADED", {})
    assert cache.stamp(pkg / "kern.py") != after


def test_importing_mjkin_reads_no_source_file_for_its_stamps():
    """The stamp notes the sources' sizes and times at import; it reads them at a process's first compile only."""
    script = textwrap.dedent("""
        import sys
        read = []
        def hook(event, args):  # opens by code that is not the import system's
            if event == "open" and str(args[0]).endswith(".py") and "/mjkin/" in str(args[0]) \\
                    and not sys._getframe(1).f_code.co_filename.startswith("<frozen"):
                read.append(str(args[0]))
        sys.addaudithook(hook)
        import mjkin
        print(len(read))
    """)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300, check=True)
    assert run.stdout.split() == ["0"]


def test_a_source_edited_after_its_import_is_not_stamped_as_the_new_file(tmp_path, monkeypatch):
    """The sources are read when the first kernel is saved, not at import: a file changed in between (its size or
    time) gives a stamp no process shares, so the code this process loaded is never found under the new file's."""
    from mjkin.runtime import cache

    pkg = _package(tmp_path)
    monkeypatch.setattr(cache, "_LOADED", {})
    cache.loaded(pkg / "kern.py")  # its kernel defined: the package noted as loaded
    (pkg / "help.py").write_text(_HELP.format(k=2.0))
    later = os.stat(pkg / "help.py").st_mtime_ns + 10**9  # a second on: a coarse clock's tick cannot hide it
    os.utime(pkg / "help.py", ns=(later, later))
    edited = cache.stamp(pkg / "kern.py")
    assert cache.stamp(pkg / "kern.py") == edited  # one stamp for the process
    monkeypatch.setattr(cache, "_LOADED", {})  # a new process, which loads the edited file
    assert cache.stamp(pkg / "kern.py") != edited


def test_an_edit_of_the_goal_helpers_restamps_the_ik_loop(tmp_path, monkeypatch):
    """An edit of position_rows (goals/residuals.py) restamps the loop and Position's residual that inline it: no
    stale code. Every kernel of the package is restamped with them (the price of a stamp read in ~5 ms)."""
    import shutil

    from mjkin.runtime import cache

    copy = tmp_path / "mjkin"
    shutil.copytree(cache.PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__", "*.so"))
    files = [copy / "ik" / "loop.py", copy / "goals" / "position.py"]
    before = [cache.stamp(f) for f in files]
    helpers = copy / "goals" / "residuals.py"
    helpers.write_text(helpers.read_text().replace("w * (pt[0, a] - ga.data[b, i, a])",
                                                   "w * (pt[0, a] + 0.1 - ga.data[b, i, a])"))
    monkeypatch.setattr(cache, "_LOADED", {})
    assert all(cache.stamp(f) != b for f, b in zip(files, before, strict=True))


def test_an_edited_helper_recompiles_its_caller_under_numba_cache_dir(tmp_path):
    """The stale-code case: with NUMBA_CACHE_DIR a kernel whose inlined helper changed is compiled again."""
    pkg = _package(tmp_path / "src")
    env = {"NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    assert _run(tmp_path / "src", **env) == (4.0, 0)  # compiled
    assert _run(tmp_path / "src", **env) == (4.0, 1)  # loaded from the cache
    (pkg / "help.py").write_text(_HELP.format(k=5.0))
    assert _run(tmp_path / "src", **env) == (12.0, 0)  # the new helper, compiled in: no stale answer
    assert not (pkg / "__pycache__").exists() or not list((pkg / "__pycache__").glob("*.nbi"))  # all under the dir


def test_a_cache_warmed_elsewhere_is_read_where_it_cannot_be_written(tmp_path):
    """Kernels compiled beside the sources (a warmed install) are used when numba must write elsewhere."""
    _package(tmp_path / "src")
    assert _run(tmp_path / "src") == (4.0, 0)  # warmed in the tree
    # another place to write (as when the tree is read-only): the kernel still comes from the tree's cache
    assert _run(tmp_path / "src", NUMBA_CACHE_DIR=str(tmp_path / "elsewhere")) == (4.0, 1)


def test_generated_code_is_never_taken_from_a_folder_another_user_can_write(tmp_path, monkeypatch):
    """A folder planted by another user (or writable by others) is refused; the code goes to a private one."""
    import os

    from mjkin.runtime import cache

    planted = tmp_path / "xdg" / "mjkin" / "generated"
    planted.mkdir(parents=True)
    marker = tmp_path / "ran"
    (planted / "mjkin_loop_0.py").write_text(f"open({str(marker)!r}, 'w').write('x')\n")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.setattr(cache, "PACKAGE", tmp_path / "readonly-package")
    (tmp_path / "readonly-package").write_text("")  # a file: no folder can be made under it
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setattr(cache, "_TEMPORARY", [])
    if os.getuid() == 0:
        os.chown(planted, 65534, 65534)  # another user's folder
    else:
        planted.chmod(0o777)  # one that every user may write to
    chosen = cache.private_folder("generated")
    assert chosen != planted and chosen.is_dir() and not (chosen / "mjkin_loop_0.py").exists()
    assert os.stat(chosen).st_uid == os.getuid() and not os.stat(chosen).st_mode & 0o022
    planted.chmod(0o700)
    if os.getuid() == 0:
        os.chown(planted, 0, 0)
    assert cache.private_folder("generated") == planted  # once it is private and ours, it is used
    assert not marker.exists()


def test_generated_code_written_ahead_is_read_where_it_cannot_be_written(tmp_path, monkeypatch):
    """A warmed install (the loop's module written by root, read-only at run time) is used as it is; the same text
    in a folder others may write to is not."""
    import os

    from mjkin.runtime import cache

    warmed, open_to_all, ours = tmp_path / "warmed", tmp_path / "open", tmp_path / "ours"
    for folder in (warmed, open_to_all):
        folder.mkdir(mode=0o700)
        (folder / "loop.py").write_text("x = 1\n")
    open_to_all.chmod(0o777)
    monkeypatch.setattr(cache, "_places", lambda name: (open_to_all, warmed))
    assert cache.generated_file("generated", "loop.py", "x = 1\n") == warmed / "loop.py"
    monkeypatch.setattr(cache, "_places", lambda name: (open_to_all, ours))
    made = cache.generated_file("generated", "loop.py", "x = 1\n")  # not the open folder's copy: a new one
    assert made == ours / "loop.py" and made.read_text() == "x = 1\n" and not os.stat(ours).st_mode & 0o022


def test_stored_arrays_are_made_once_and_never_read_from_a_folder_others_may_write(tmp_path, monkeypatch):
    import os

    from mjkin.runtime import cache

    ours, open_to_all = tmp_path / "ours", tmp_path / "open"
    open_to_all.mkdir()
    open_to_all.chmod(0o777)  # every user may write here: never read, never written
    made = []

    def make():
        made.append(1)
        return np.arange(6.0).reshape(2, 3)

    monkeypatch.setattr(cache, "_places", lambda name: (open_to_all, ours))
    kept = cache.stored_array("starts", "key", make).copy()
    saved = list(ours.glob("*.npy"))
    assert len(saved) == 1 and not os.stat(ours).st_mode & 0o022 and not list(ours.glob(".*"))  # no temp left
    assert not list(open_to_all.iterdir())
    np.testing.assert_array_equal(cache.stored_array("starts", "key", make), kept)
    assert len(made) == 1  # the second came from the file
    np.save(open_to_all / saved[0].name, -kept)  # planted where every user may write, first in the search
    np.testing.assert_array_equal(cache.stored_array("starts", "key", make), kept)
    assert len(cache.stored_array("starts", "another key", make)) == 2 and len(made) == 2


def test_a_warm_process_draws_no_restarts_its_starts_are_read_with_the_same_bits(tmp_path):
    """A first solve used to import scipy.stats (~0.4 s) for the Sobol restarts; a later process reads them."""
    import json
    import os
    import subprocess
    import sys

    script = ("import json, sys, numpy as np, mjkin; from mjkin.ik.problem import seeded_starts; "
              "from mjkin.kinematics import qspace; tree = mjkin.load('arm7'); s = seeded_starts(tree, 190733, 11); "
              "scipy_stats = 'scipy.stats' in sys.modules; "
              "same = np.array_equal(s, qspace.random(tree, np.random.default_rng(190733), 11, spread=True)); "
              "print(json.dumps([scipy_stats, same, s.shape]))")
    # a seed and count no other test uses: the package's own cache folder is searched too
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path), "NUMBA_CACHE_DIR": str(tmp_path / "numba")}

    def run():
        return json.loads(subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300,
                                         env=env, check=True).stdout)

    assert run() == [True, True, [11, 7]]  # drawn: scipy's Sobol
    assert run() == [False, True, [11, 7]]  # read: scipy.stats not imported until the check after it


def test_a_problem_of_common_kinds_compiles_no_code_of_the_others(tmp_path):
    """A Pose problem's goal arrays carry no geoms, and the loop's branch of the other kinds compiles to nothing for
    them: numba prunes it on the None argument, so no distance or balance code is typed (a process of its own, an
    empty cache: nothing is loaded from disk)."""
    script = textwrap.dedent("""
        import numba, numpy as np, mjkin
        from mjkin import goals as G
        from mjkin.goals.program import compile_goals
        from mjkin.goals.clearance import clearance_rows
        from mjkin.goals.com import balance_rows
        from mjkin.ik import loop
        tree = mjkin.load("arm7")
        prog = compile_goals(tree, G.Pose("ee", T=np.eye(4)))
        ga = prog.arrays
        assert ga.geoms is None and ga.pairs is None and ga.support is None
        f, i = numba.float64, numba.int64
        a1, a2, a3, a4 = (numba.types.Array(f, n, "C") for n in (1, 2, 3, 4))
        ws = numba.typeof(loop.scratch(tree.nv))
        loop.other_goal.compile((numba.typeof(tree.kin), numba.typeof(ga), numba.types.none, ws, a4, a3, a4, a3,
                                 i, i, i, a2, a1, a2, i, a2))
        print(len(loop.other_goal.signatures), len(clearance_rows.signatures), len(balance_rows.signatures))
    """)
    env = {**os.environ, "MJKIN_COMPILE": "wait", "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.split() == ["1", "0", "0"]
    from mjkin.goals import Clearance, Position, compile_goals

    tree = tree_of("arm7")
    both = compile_goals(tree, [Position("ee", (0.3, 0.0, 0.5)), Clearance(0.01)])
    assert both.arrays.geoms is tree.geoms and len(both.arrays.pairs)  # the other kinds' problems carry them


def test_the_loop_of_built_in_kinds_is_the_package_file_and_a_registered_kind_gets_a_copy(monkeypatch):
    """Built-in kinds run ``mjkin/ik/loop.py`` itself; a kind the user registers runs in a generated copy of it with
    one more branch, which imports the kind's residual from its module."""
    from mjkin.goals import Clearance, Pose, registry
    from mjkin.goals.position import residual as position_residual
    from mjkin.ik import generated, loop

    assert generated.loop_for((Pose.code,)) is loop and generated.loop_for((Pose.code, Clearance.code)) is loop
    assert generated.MARKER in Path(loop.__file__).read_text()
    monkeypatch.setattr(registry, "KINDS", [*registry.KINDS, type("Beacon", (Pose,), {})])
    monkeypatch.setattr(registry, "RESIDUALS", [*registry.RESIDUALS, position_residual])
    text = generated.source((loop.BUILT_IN,))
    assert text.count("elif code == ") == Path(loop.__file__).read_text().count("elif code == ") + 1
    assert f"from mjkin.goals.position import residual as _k{loop.BUILT_IN}" in text


def test_warmup_compiles_every_kernel_mjkin_runs():
    from mjkin.apps.warmup import warmup
    from mjkin.ik.loop import solve_packed
    from mjkin.kinematics.fk import fk_kernel

    seconds, _ = warmup(jobs=1)  # here, so this process holds what it compiled or loaded
    assert seconds > 0
    assert len(solve_packed.signatures) >= 2 and fk_kernel.signatures  # the loop of common kinds, and of the others


def test_borrowed_views_read_and_write_their_owners():
    """``borrowed`` views (no reference counts) see and change the arrays they were made from, nested tuples too."""
    @numba.njit
    def fill(a):
        own = (np.zeros(3), (np.ones((2, 2)), 7))
        z, (o, k) = borrowed(own)
        b = borrowed(a)
        for i in range(3):
            z[i] = b[i] * k
            b[i] += o[0, 0]
        total = z.sum() + o.sum()
        keep_alive(own)
        return total

    a = np.arange(3.0)
    assert fill(a) == 3 * 7 + 4.0
    assert np.array_equal(a, np.arange(3.0) + 1.0)


def test_borrowed_fields_are_the_structrefs_own_arrays():
    """A packed problem's fields, read without reference counts, are its arrays: what is written there is seen."""
    @numba.njit
    def first_q_plus_one(pk):
        fields = borrowed_fields(pk)
        q = fields[8]
        q[0, 0] += 1.0
        return fields[4], q[0, 0]

    problem = mjkin.Problem(mjkin.load("arm7"), Position("ee", (0.3, 0.1, 0.4)))
    problem.solve()
    packed, arrays = problem.prepared.one
    assert isinstance(packed, Packed) and FIELDS[8] == "q" and FIELDS[4] == "max_iters"
    before = arrays[1][0, 0]
    assert first_q_plus_one(packed) == (problem.prepared.max_iters, before + 1.0)
    assert arrays[1][0, 0] == before + 1.0


def test_an_entry_is_the_compiled_code_without_the_dispatch():
    @numba.njit
    def scaled(a, k):
        return a.sum() * k

    a = np.arange(4.0)
    direct = entry(scaled, numba.typeof(a), numba.float64)
    assert direct is not scaled and direct(a, 2.0) == scaled(a, 2.0) == 12.0
    assert len(scaled.signatures) == 1  # compiled once, for those types


def test_a_kernel_another_process_is_compiling_is_waited_for_and_loaded_not_compiled_again(tmp_path):
    """The compile lock: a second process (a test worker, a warmup process) waits, then reads the first's cache."""
    import os
    import subprocess
    import sys
    import time

    from numba.core.compiler_lock import global_compiler_lock

    _package(tmp_path / "src")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}  # both write beside the source
    sys.path.insert(0, str(tmp_path / "src"))
    try:
        from kpkg.kern import kernel

        with global_compiler_lock, kernel._cache.compiling():
            child = subprocess.Popen([sys.executable, "-c", _RUN, str(tmp_path / "src")], env=env, text=True,
                                     stdout=subprocess.PIPE)
            deadline = time.monotonic() + 120
            lock = kernel._cache.lock_path()
            while not _holds_open(child.pid, lock):  # the child has opened the lock file we hold: it waits on it
                assert child.poll() is None and time.monotonic() < deadline, "the child did not wait for the lock"
                time.sleep(0.05)
            time.sleep(0.5)  # past its first try
            assert kernel(1.0) == 4.0  # compiled here, under the lock, into the cache the child then reads
        out, _ = child.communicate(timeout=120)
    finally:
        sys.path.remove(str(tmp_path / "src"))
        for name in ("kpkg.kern", "kpkg.help", "kpkg"):
            sys.modules.pop(name, None)
    assert out.split() == ["4.0", "1"]  # loaded from the cache, not compiled a second time


def test_numba_outside_the_tested_range_is_refused_in_one_line():
    """numba 0.60 broke ``import mjkin`` with a StopIteration deep in the cache; the release is checked, and said."""
    from mjkin.runtime.numba_private import numba_unsupported

    assert numba_unsupported(numba.__version__) is None
    for version in ("0.60.0", "0.69.0rc1", "1.0.0"):
        why = numba_unsupported(version)
        assert why is not None and "\n" not in why and f"numba {version}" in why


def _holds_open(pid: int, path: str) -> bool:
    """Whether process ``pid`` has ``path`` open."""
    import os

    try:
        fds = os.listdir(f"/proc/{pid}/fd")
    except OSError:
        return False
    for fd in fds:
        try:
            if os.readlink(f"/proc/{pid}/fd/{fd}") == path:
                return True
        except OSError:
            pass
    return False
