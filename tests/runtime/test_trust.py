"""Code runs only from where it must: the compile child never reads the working folder, no cache file another user
can write is loaded, an install warmed by root serves every user without writing, and an edit made while a kernel
compiles never stores the old code under the new source's stamp."""

import contextlib
import errno
import os
import pickle
import py_compile
import shutil
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import numba
import pytest
from test_jit import _HELP, _RUN, _package

from mjkin.runtime import cache
from mjkin.runtime.progress import COMPILING

NOBODY = 65534


def _run(root: Path, cache_dir: Path | None) -> tuple[float, int]:
    """The kernel's answer, and whether it came from a cache (1) or was compiled (0); cached under ``cache_dir``,
    or beside the source when None."""
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env.update(MJKIN_COMPILE="wait", **({"NUMBA_CACHE_DIR": str(cache_dir)} if cache_dir else {}))
    out = subprocess.run([sys.executable, "-c", _RUN, str(root)], capture_output=True, text=True, timeout=300,
                         env=env, check=True).stdout.split()
    return float(out[0]), int(out[1])


def test_the_compile_child_never_runs_a_file_of_the_working_folder(tmp_path):
    """A ``numpy.py`` where the user runs mjkin (a downloaded dataset) is not imported by the background child."""
    (tmp_path / "src").mkdir()
    (tmp_path / "src" / "tiered.py").write_text("from mjkin.runtime.jit import njit\n\n\n@njit\ndef triple(x):\n"
                                                "    return 3.0 * x\n")
    work, marker = tmp_path / "dataset", tmp_path / "ran"
    work.mkdir()
    (work / "numpy.py").write_text(f"open({str(marker)!r}, 'w').close()\nraise ImportError('planted')\n")
    script = tmp_path / "scripts" / "first_call.py"  # run as a script: its folder, not the working one, is on its path
    script.parent.mkdir()
    script.write_text(textwrap.dedent(f"""
        import sys, time
        import numpy as np
        sys.path.insert(0, {str(tmp_path / "src")!r})
        from mjkin.runtime import tier
        from tiered import triple
        x = np.arange(3.0)
        call = tier.first_use(triple)
        first = call(x)  # interpreted: a child compiles it
        sig = (triple.typeof_pyval(x),)
        deadline = time.monotonic() + 240
        while tier._COMPILER.status([(triple, sig)], submit=False) != "done" and time.monotonic() < deadline:
            time.sleep(0.1)
        second = call(x)
        print(tier._COMPILER.status([(triple, sig)], submit=False), second.tolist(),
              sum(triple._cache_hits.values()))
    """))
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env.update(MJKIN_COMPILE="background", NUMBA_CACHE_DIR="cache")  # relative: the child must not lose it
    out = subprocess.run([sys.executable, str(script)], cwd=work, capture_output=True, text=True, env=env,
                         timeout=300, check=True).stdout.split("\n")[-2]
    assert not marker.exists()
    assert out == "done [0.0, 3.0, 6.0] 1"  # the child compiled it; this process loaded what it wrote
    assert list((work / "cache").rglob("tiered.triple*.nbi"))


def test_the_child_is_given_the_parents_path_but_not_its_working_folder(monkeypatch, tmp_path):
    from mjkin.runtime import tier

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "path", ["", str(tmp_path / "lib"), "relative", *sys.path[1:]])
    monkeypatch.setattr(sys, "orig_argv", [sys.executable, "-c", "..."])
    paths = tier._child_path()
    assert "" not in paths and str(tmp_path / "lib") in paths and str(tmp_path / "relative") in paths
    monkeypatch.setattr(sys, "path", [str(tmp_path), str(tmp_path / "lib"), str(tmp_path)])
    monkeypatch.setattr(sys, "orig_argv", [sys.executable, "-m", "mjkin"])
    assert tier._child_path() == [str(tmp_path / "lib"), str(tmp_path)]  # the one Python put first goes


_SETTINGS_KERNEL = "from mjkin.runtime.jit import njit\n\n\n@njit\ndef tolerance(st):\n    return st.tol\n"
_SPAWN = textwrap.dedent("""
    import mjkin, numba
    from mjkin.ik.kernel import settings
    from mjkin.probe import tolerance
    from mjkin.runtime import numba_private, tier
    sig = (numba.typeof(settings(1e-6, 1e-6, 1e-3)),)  # a NamedTuple of mjkin's: the child imports mjkin to unpickle it
    child = tier._spawn([(tier._address(tolerance), sig)])
    print(mjkin.__file__, child.wait(), numba_private.load(tolerance, sig))
""")


def test_the_child_compiles_for_the_copy_of_mjkin_this_process_runs(tmp_path):
    """A copy of mjkin run beside an installed one: the child compiles the copy's kernels where this process loads them.

    The child unpickled its jobs, whose types name mjkin's classes, before it set its path: it imported the
    installed mjkin, and kept its compile under that one's folder and stamp (the IK loop was never found on disk).
    """
    shutil.copytree(cache.PACKAGE, tmp_path / "mjkin", ignore=shutil.ignore_patterns("__pycache__"))
    (tmp_path / "mjkin" / "probe.py").write_text(_SETTINGS_KERNEL)
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env.update(PYTHONPATH=str(tmp_path), XDG_CACHE_HOME=str(tmp_path / "xdg"))
    out = subprocess.run([sys.executable, "-c", _SPAWN], cwd=tmp_path, capture_output=True, text=True, env=env,
                         timeout=300, check=True).stdout.split()
    assert out == [str(tmp_path / "mjkin" / "__init__.py"), "0", "True"]  # this copy; the child's compile loaded


def _plant_index(index: Path, marker: Path) -> None:
    """An index file whose unpickling opens ``marker`` for writing (a stand-in for any code)."""

    class Planted:
        def __reduce__(self):
            return open, (str(marker), "w")

    index.write_bytes(pickle.dumps(numba.__version__) + pickle.dumps(Planted()))


def _as_another_user(path: Path) -> None:
    """``path`` made another user's (as root), or, as anyone else, writable by every user."""
    if os.getuid() == 0:
        os.chown(path, NOBODY, NOBODY)
    else:
        path.chmod(0o666)


@pytest.mark.parametrize("in_cache_dir", [True, False], ids=["NUMBA_CACHE_DIR", "beside the source"])
def test_an_index_file_another_user_planted_is_never_loaded(tmp_path, in_cache_dir):
    """numba's index is a pickle: one another user could have written is ignored, not run, and the kernel compiles."""
    pkg = _package(tmp_path / "src")
    cache_dir = tmp_path / "cache" if in_cache_dir else None
    assert _run(tmp_path / "src", cache_dir) == (4.0, 0)
    assert _run(tmp_path / "src", cache_dir) == (4.0, 1)
    index = next((cache_dir or pkg / "__pycache__").rglob("kern.kernel*.nbi"))
    marker = tmp_path / "ran"
    _plant_index(index, marker)
    _as_another_user(index)
    assert _run(tmp_path / "src", cache_dir) == (4.0, 0)
    assert not marker.exists()


def test_a_cache_folder_others_may_write_is_neither_read_nor_written(tmp_path):
    """A shared NUMBA_CACHE_DIR open to every user (a lab machine's): its kernels are not loaded, and nothing of
    ours goes there; the kernel is cached where only we write."""
    _package(tmp_path / "src")
    shared = tmp_path / "shared"
    assert _run(tmp_path / "src", shared) == (4.0, 0)
    assert _run(tmp_path / "src", shared) == (4.0, 1)
    for folder in [shared, *shared.rglob("*")]:
        if folder.is_dir():
            folder.chmod(0o777)
    before = sorted(p.name for p in shared.rglob("*"))
    assert _run(tmp_path / "src", shared) == (4.0, 0)  # compiled: what is there is not read
    assert sorted(p.name for p in shared.rglob("*")) == before


def test_a_pyc_planted_beside_the_generated_loop_never_runs(tmp_path, monkeypatch):
    """The loop generated for a registered kind is compiled from its own text, never from a ``.pyc`` beside it."""
    from mjkin.goals import Position, registry
    from mjkin.goals.position import residual
    from mjkin.ik import generated, loop

    place = tmp_path / "generated"
    place.mkdir()
    monkeypatch.setattr(cache, "_places", lambda name: (place,))
    monkeypatch.setattr(generated, "_LOADED", {})
    monkeypatch.setattr(registry, "KINDS", [*registry.KINDS, type("Beacon", (Position,), {})])
    monkeypatch.setattr(registry, "RESIDUALS", [*registry.RESIDUALS, residual])
    text = generated.source((loop.BUILT_IN,))
    name = f"{generated.PREFIX}{__import__('hashlib').sha256(text.encode()).hexdigest()[:16]}"
    real = place / f"{name}.py"
    real.write_text(text)
    marker = tmp_path / "ran"
    evil = tmp_path / "evil.py"
    body = f"open({str(marker)!r}, 'w').close()\n"
    evil.write_text(body + "#" * (len(text.encode()) - len(body.encode()) - 1) + "\n")  # the same size
    st = os.stat(real)
    os.utime(evil, ns=(st.st_atime_ns, st.st_mtime_ns))  # and time: Python's check of a .pyc would take it
    py_compile.compile(str(evil), cfile=str(place / "__pycache__" / f"{name}.{sys.implementation.cache_tag}.pyc"),
                       doraise=True)
    saved = sys.modules.get(name)
    try:
        module = generated.loop_for((Position.code, loop.BUILT_IN))
    finally:
        if saved is not None:
            sys.modules[name] = saved
    assert not marker.exists() and hasattr(module, "solve_packed") and module is not loop


def test_an_edit_while_a_kernel_compiles_is_not_stored_under_the_new_stamp(tmp_path):
    """The process compiled the helper it imported; the file changed meanwhile: that code is not cached as the new
    file's, so the next run compiles the new helper and answers with it."""
    pkg = _package(tmp_path / "src")
    env = {**os.environ, "MJKIN_COMPILE": "wait", "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    script = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(tmp_path / "src")!r})
        from kpkg.kern import kernel  # imported: shift adds 1
        open({str(pkg / "help.py")!r}, "w").write({_HELP.format(k=5.0)!r})  # edited before it compiles
        print(kernel(1.0))
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=300,
                         check=True).stdout.split()
    assert out == ["4.0"]  # the code it imported
    assert _run(tmp_path / "src", tmp_path / "cache") == (12.0, 0)  # the new helper, compiled
    assert _run(tmp_path / "src", tmp_path / "cache") == (12.0, 1)


def test_secure_folders(tmp_path):
    assert cache.secure(tmp_path) and not cache.secure(tmp_path / "missing")
    open_folder = tmp_path / "open"
    open_folder.mkdir()
    open_folder.chmod(0o777)
    (open_folder / "inner").mkdir()
    assert not cache.secure(open_folder) and not cache.secure(open_folder / "inner")  # renamed away by anyone
    sticky = tmp_path / "sticky"
    sticky.mkdir()
    sticky.chmod(0o1777)
    (sticky / "ours").mkdir(mode=0o755)
    assert cache.secure(sticky / "ours") and not cache.secure(sticky)  # /tmp's way: our folder in it is ours
    (sticky / "ours" / "f").write_text("x")
    assert cache.trusted_file(sticky / "ours" / "f")
    (sticky / "ours" / "f").chmod(0o666)
    assert not cache.trusted_file(sticky / "ours" / "f")
    (sticky / "ours" / "link").symlink_to(sticky / "ours" / "f")
    assert not cache.trusted_file(sticky / "ours" / "link")


# ---- as another user: an install warmed by root


def _world_readable_copy() -> Path:
    """A copy of the package in a fresh folder every user can read (pytest's own tmp folders are root's only)."""
    root = Path(tempfile.mkdtemp(prefix="mjkin-install-"))
    root.chmod(0o755)
    skip = shutil.ignore_patterns("__pycache__", "*.so")
    shutil.copytree(cache.PACKAGE, root / "mjkin", ignore=skip)
    for folder in ("models", "envs"):  # installed as mjkin.models and mjkin.envs
        shutil.copytree(cache.PACKAGE.parent / folder, root / "mjkin" / folder, ignore=skip)
    return root


def _python_for_nobody() -> tuple[str, list[str]] | str:
    """A Python another user can run with this one's packages, and the folders to put on its path; else why not.

    This Python may sit in a folder only root can enter (pyenv under ``/root``): then the system's Python of the
    same version, given this one's site-packages.
    """
    if os.getuid() != 0:
        return "needs root to run a process as another user"
    version = f"python{sys.version_info.major}.{sys.version_info.minor}"
    sites = [p for p in sys.path if p.endswith("site-packages")]
    why = ""
    for python, extra in ((sys.executable, []), (f"/usr/bin/{version}", sites)):
        try:
            probe = subprocess.run([python, "-c", "import numpy, numba, mujoco, scipy"], user=NOBODY, group=NOBODY,
                                   capture_output=True, text=True, cwd="/", timeout=120,
                                   env={**os.environ, "HOME": "/nonexistent", "PYTHONPATH": os.pathsep.join(extra)})
        except OSError as e:
            why = f"another user cannot run {python}: {e.strerror}"
            continue
        if probe.returncode == 0:
            return python, extra
        why = f"another user cannot run {python} with numpy, numba and mujoco: {probe.stderr.strip()[-200:]}"
    return why


_SOLVE = ("import json, mjkin, mjkin.goals as G; tree = mjkin.load('arm7'); "
          "res = mjkin.solve(tree, G.Position('ee', tree.pose(tree.qpos0 + 0.2, 'ee')[:3, 3])); "
          "print(json.dumps([bool(res.success), res.q.tolist()]))")
_POSE = ("import mjkin; from numba.core.event import install_recorder; tree = mjkin.load('arm7')\n"
         "with install_recorder('numba:compile') as rec:\n"
         "    T = tree.fk(tree.qpos0 + 0.1)\n"
         "print(T[-1].tolist(), 'compiled' if rec.buffer else 'loaded')")


def test_an_install_warmed_by_root_serves_another_user_without_writing():
    """The Docker flow: root warms the install, a user with no writable home runs it, from what it holds."""
    found = _python_for_nobody()
    if isinstance(found, str):
        pytest.skip(found)
    python, sites = found
    root = _world_readable_copy()
    try:
        env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME")}

        def run(code, mode, **user):
            home, path = ("/nonexistent", [str(root), *sites]) if user else (str(root / "roothome"), [str(root)])
            out = subprocess.run([python if user else sys.executable, "-c", code], capture_output=True, text=True,
                                 timeout=600, cwd="/", env={**env, "MJKIN_COMPILE": mode, "HOME": home,
                                                            "PYTHONPATH": os.pathsep.join(path)}, **user)
            assert out.returncode == 0, out.stderr
            return out.stdout.split("\n")[-2]

        solved, posed = run(_SOLVE, "interpret"), run(_POSE, "wait")  # the starts stored, the FK kernel compiled
        files = sorted(str(p) for p in root.rglob("*"))
        assert (root / "mjkin" / "__pycache__" / "starts").is_dir() and posed.endswith("compiled")
        nobody = {"user": NOBODY, "group": NOBODY}
        assert run(_SOLVE, "interpret", **nobody) == solved
        assert run(_POSE, "wait", **nobody) == posed.replace("compiled", "loaded")  # root's cache, read
        assert sorted(str(p) for p in root.rglob("*")) == files  # nothing written by the other user
    finally:
        shutil.rmtree(root, ignore_errors=True)


# ---- a full disk: the kernels stay compiled in memory, and one line says what could not be saved, and where

_FULL = textwrap.dedent("""
    import builtins, io, os, sys
    cache_dir, code, src = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    real_open, real_os_open = builtins.open, os.open

    def refuse(path, mode):
        if str(os.fspath(path)).startswith(cache_dir) and any(c in mode for c in "wax+"):
            raise OSError(code, os.strerror(code), path)

    def full_open(file, mode="r", *args, **kwargs):
        if isinstance(file, (str, os.PathLike)):
            refuse(file, mode)
        return real_open(file, mode, *args, **kwargs)

    def full_os_open(path, flags, *args, **kwargs):
        if flags & os.O_CREAT:
            refuse(path, "w")
        return real_os_open(path, flags, *args, **kwargs)

    if code:  # else the disk is full for real (a small tmpfs)
        builtins.open = io.open = full_open
        os.open = full_os_open
    sys.path.insert(0, src)
    from kpkg.kern import kernel
    import mjkin, mjkin.goals as G
    from mjkin.runtime import cache
    cache.PACKAGE = cache.Path(cache_dir) / "package"  # the install's own generated loops: not found there
    answer = kernel(1.0)  # compiled here, not saved
    os.environ["MJKIN_COMPILE"] = "interpret"  # the generated loop module and the stored starts of a solve
    tree = mjkin.load("arm7")
    res = mjkin.solve(tree, G.Position("ee", tree.pose(tree.qpos0 + 0.1, "ee")[:3, 3]), seed=190734)
    print(answer, bool(res.success))
""")


def _full_disk(tmp_path: Path, cache_dir: Path, code: int) -> list[str]:
    _package(tmp_path / "src")
    env = {**os.environ, "MJKIN_COMPILE": "wait", "NUMBA_CACHE_DIR": str(cache_dir),
           "XDG_CACHE_HOME": str(cache_dir / "xdg")}
    run = subprocess.run([sys.executable, "-c", _FULL, str(cache_dir), str(code), str(tmp_path / "src")],
                         capture_output=True, text=True, env=env, timeout=600)
    assert run.returncode == 0 and "Traceback" not in run.stderr, run.stderr[-3000:]
    assert run.stdout.split() == ["4.0", "True"]
    return run.stderr.splitlines()


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EDQUOT, errno.EROFS], ids=["ENOSPC", "EDQUOT", "EROFS"])
def test_a_cache_that_cannot_be_written_costs_one_line_not_the_answer(tmp_path, code):
    """numba's cache save, the compile lock and the stored starts each fail to write (``OSError: [Errno 28]``, 25
    frames, before): the answers come, and each folder is named once. (The loop of built-in kinds is a package
    file: nothing is generated for it.)"""
    cache_dir = tmp_path / "cache"
    lines = _full_disk(tmp_path, cache_dir, code)
    said = [line for line in lines if "could not save" in line]
    assert any("kpkg" in line for line in said)  # the kernel's cache folder
    assert all(str(cache_dir) in line and os.strerror(code) in line for line in said)
    assert len(said) == len(set(said)), lines
    assert all(line in said or line == f"mjkin: {COMPILING}" for line in lines), lines  # nothing else is said


def test_a_full_tmpfs_costs_one_line_not_the_answer(tmp_path):
    """The same on a real full file system: a tmpfs of 64 KB, filled (as root; else skipped)."""
    disk = tmp_path / "disk"
    disk.mkdir()
    mount = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(disk)], capture_output=True,
                           text=True) if os.getuid() == 0 and shutil.which("mount") else None
    if mount is None or mount.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here ({mount.stderr.strip() if mount else 'needs root'})")
    try:
        with open(disk / "filler", "wb") as f:
            with contextlib.suppress(OSError):
                f.write(b"\0" * (1 << 20))
        lines = _full_disk(tmp_path, disk, 0)
        assert any("could not save" in line and "kpkg" in line for line in lines), lines
    finally:
        subprocess.run(["umount", str(disk)], check=False)
