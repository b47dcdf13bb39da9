"""Interpreted first, compiled behind: a cold kernel's first small calls run as Python while a child compiles it.

From an empty cache numba spends ~50 s on the IK loop. With ``MJKIN_COMPILE=background`` (the default), a
small call within :func:`first_use` of a kernel neither in memory nor on disk runs the kernel's own Python
source (:func:`interpreted`), and a child process compiles the kernel into the disk cache; the first call after
that loads it. The child runs at low priority and outlives this process, so a short script leaves the cache warm.
Large calls, ``MJKIN_COMPILE=wait`` (tests, benchmarks) and a kernel a child cannot import (defined in
``__main__``) compile here first, as numba does; ``MJKIN_COMPILE=interpret`` compiles nothing for those calls.
Interpreted answers may differ from compiled ones in the last bits, and more under a ``timeout``
(docs/concepts/results.md, "Time limits and the first run").
"""

from __future__ import annotations

import atexit
import contextlib
import functools
import importlib
import importlib.util
import os
import pickle
import subprocess
import sys
import threading
import time
import types as pytypes
from collections.abc import Callable, Iterator
from typing import Any, ParamSpec, TypeVar

import numpy as np

from ..errors import InputError
from . import numba_private, progress
from .cache import PACKAGE

MODES = ("background", "wait", "interpret")
SMALL = 10_000  # a call interprets only if every array it passes holds at most this many numbers
SMALL_BATCH = 64  # a solve interprets only if it has at most this many targets
_local = threading.local()
P = ParamSpec("P")
R = TypeVar("R")


def mode() -> str:
    """``$MJKIN_COMPILE``: ``background`` (the default), ``wait``, or ``interpret`` (see the module).

    Raises:
        InputError: another value (the message names the three).
    """
    value = os.environ.get("MJKIN_COMPILE", "background")
    if value not in MODES:
        raise InputError(f"MJKIN_COMPILE must be one of {', '.join(MODES)}, got {value!r}")
    return "interpret" if numba_private.DISABLE_JIT else value


@contextlib.contextmanager
def waiting() -> Iterator[None]:
    """Within it, ``MJKIN_COMPILE=wait`` (and in the processes started meanwhile): for timings and ``mjkin warmup``."""
    before = os.environ.get("MJKIN_COMPILE")
    os.environ["MJKIN_COMPILE"] = "wait"
    try:
        yield
    finally:
        if before is None:
            del os.environ["MJKIN_COMPILE"]
        else:
            os.environ["MJKIN_COMPILE"] = before


def first_use(fn: Callable[P, R]) -> Callable[P, R]:
    """``fn`` with small calls of kernels not yet compiled run interpreted within it (this thread; see the module).

    A plain counter, not a context manager: a warm single solve passes through it (~0.1 µs, not ~1 µs).
    """

    @functools.wraps(fn)
    def call(*args: P.args, **kwargs: P.kwargs) -> R:
        _local.depth = getattr(_local, "depth", 0) + 1
        try:
            return fn(*args, **kwargs)
        finally:
            _local.depth -= 1

    return call


def _small(value: Any) -> bool:
    """Whether ``value`` is a number, a string, or an array or tuple of them no larger than :data:`SMALL`."""
    if isinstance(value, np.ndarray):
        return value.size <= SMALL
    if isinstance(value, tuple):
        return all(_small(v) for v in value)
    return isinstance(value, (int, float, bool, str, np.generic)) or value is None


# ---- the Python versions of kernels


PYTHON: dict[int, Any] = {}  # id of a numba-only object (an intrinsic, a StructRef class) -> its Python stand-in
_KEEP: list[Any] = []  # those objects, so that their ids stay theirs
_TWINS: dict[int, Callable] = {}
_GLOBALS: dict[int, dict] = {}


def python_version(obj: Any, stand_in: Any) -> None:
    """Run ``stand_in`` wherever interpreted code names ``obj`` (an intrinsic or type only compiled code can call)."""
    _KEEP.append(obj)
    PYTHON[id(obj)] = stand_in


def _stand_in(value: Any) -> Any:
    if id(value) in PYTHON:
        return PYTHON[id(value)]
    return interpreted(value) if numba_private.is_kernel(value) else value


def interpreted(kernel: Any) -> Callable:
    """``kernel``'s Python source as a function whose calls of other kernels are interpreted too (nothing compiles).

    Its globals are a copy of its module's with every kernel in it interpreted (made once per module, filled lazily).
    """
    twin = _TWINS.get(id(kernel))
    if twin is None:
        fn = kernel.py_func
        if (names := _GLOBALS.get(id(fn.__globals__))) is None:
            names = _GLOBALS[id(fn.__globals__)] = {}
            names.update({k: _stand_in(v) for k, v in fn.__globals__.items()})
        closure = fn.__closure__ and tuple(pytypes.CellType(_stand_in(c.cell_contents)) for c in fn.__closure__)
        twin = _TWINS[id(kernel)] = pytypes.FunctionType(fn.__code__, names, fn.__name__, fn.__defaults__, closure)
        twin.__kwdefaults__ = fn.__kwdefaults__
    return twin


def interpreted_call(kernel: Any, *args: Any) -> Any:
    """``interpreted(kernel)(*args)`` without numpy's floating-point warnings (compiled code has none)."""
    with np.errstate(all="ignore"):
        return interpreted(kernel)(*args)


# ---- the child that compiles


def _address(kernel: Any) -> tuple[str, str, str] | None:
    """(module name, file, qualified name) by which a child process finds ``kernel``; None if it cannot."""
    fn = kernel.py_func
    path = getattr(sys.modules.get(fn.__module__), "__file__", None)
    if fn.__module__ == "__main__" or path is None or "<locals>" in fn.__qualname__:
        return None
    return fn.__module__, str(path), fn.__qualname__


class _Compiler:
    """Compiles kernels in one child process at a time, in the order asked; a killed child is started once more.

    A kernel another process is compiling (it holds the kernel's compile lock: another run's child) is not asked
    for while it does: its small calls run interpreted, then load what that process wrote.
    """

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.state: dict[tuple, str] = {}  # (id(kernel), signature) -> queued, running, done, failed
        self.queue: list[tuple] = []  # (key, address, signature) for the next child
        self.child: subprocess.Popen | None = None
        self.running: list[tuple] = []  # the child's (key, address, signature)
        self.retried = False  # whether a child that died was started again
        self.since: float | None = None  # when the first child started
        self.took: float | None = None  # seconds from then until the last child ended

    def status(self, jobs: list[tuple[Any, tuple]], submit: bool = True) -> str:
        """The least advanced state of ``jobs`` (kernel, argument types), asked for in a child if ``submit``.

        ``elsewhere``: another process compiles one; ``failed``: a child cannot import one, or failed;
        ``unknown``: never asked for.
        """
        with self.lock:
            for kernel, sig in jobs if submit else ():
                key = (id(kernel), sig)
                if key not in self.state and not numba_private.busy(kernel):
                    address = _address(kernel)
                    self.state[key] = "failed" if address is None else "queued"
                    if address is not None:
                        self.queue.append((key, address, sig))
                        progress.notice(BACKGROUND)
            self._advance()
            states = {self.state.get((id(k), s)) or ("elsewhere" if numba_private.busy(k) else "unknown")
                      for k, s in jobs}
        if "elsewhere" in states:
            progress.notice(ELSEWHERE)
        return next((s for s in ("failed", "unknown", "queued", "elsewhere", "running") if s in states), "done")

    def _advance(self) -> None:
        """Note what a child that ended did, and start one for the queue if none runs."""
        if self.child is not None:
            if self.child.poll() is None:
                return
            if self.child.returncode and not self.retried:  # killed: once more, rather than compile here
                self.retried = True
                self.queue[:0] = self.running
            else:
                for key, _, _ in self.running:
                    self.state[key] = "failed" if self.child.returncode else "done"
            self.child, self.running = None, []
            if not self.queue and self.since is not None:
                self.took = time.monotonic() - self.since
                progress.notice(f"kernels compiled in the background in {self.took:.0f} s")
        if self.queue:
            self.since = self.since or time.monotonic()
            self.child, self.running, self.queue = _spawn([(a, s) for _, a, s in self.queue]), self.queue, []
            for key, _, _ in self.running:
                self.state[key] = "running"
            threading.Thread(target=self._reap, args=(self.child,), daemon=True).start()

    def _reap(self, child: subprocess.Popen) -> None:
        """Wait for ``child`` to end, then note it (no zombie under a long-lived process)."""
        child.wait()
        with self.lock:
            self._advance()

    def settle(self) -> float | None:
        """Wait until no child runs; the seconds the children took (None: none ran)."""
        while True:
            with self.lock:
                self._advance()
                if self.child is None:
                    return self.took
            time.sleep(0.05)

    def flush(self) -> None:
        """At exit: a child for what is still queued, beside the one at work (we are ending); say that one goes on."""
        with self.lock:
            self._advance()
            if self.queue:
                _spawn([(address, sig) for _, address, sig in self.queue])
                self.queue = []
            if self.child is not None and self.child.poll() is None:
                progress.notice(f"a background process (pid {self.child.pid}, low priority) goes on compiling "
                                "kernels for later runs")


_COMPILER = _Compiler()
atexit.register(_COMPILER.flush)
settle = _COMPILER.settle
flush = _COMPILER.flush  # the CLI calls it as a command ends, while its notices still print


def _child_path() -> list[str]:
    """This process's ``sys.path`` (absolute) but for the entry Python put first by itself, unless mjkin is there.

    That entry is the script's folder, or the working folder (``-c``, ``-m``).
    """
    argv = getattr(sys, "orig_argv", [])
    implicit = (None if sys.flags.safe_path else "" if "-c" in argv or not sys.argv or not sys.argv[0] else
                os.getcwd() if "-m" in argv else os.path.dirname(os.path.realpath(sys.argv[0])))
    out = []
    for entry in sys.path:
        if implicit is not None and entry == implicit and os.path.realpath(entry or ".") != str(PACKAGE.parent):
            implicit = None  # its first occurrence only: the same folder added on purpose later stays
        elif entry:
            out.append(os.path.abspath(entry))
    return out


# The child runs isolated (``-I``: no working folder on its path, no PYTHON* variables, no user site) in "/",
# with this process's path given explicitly; the site folders it lacks (a user site) are added with their .pth files.
# The jobs are unpickled only then: their argument types name mjkin's classes (a StructRef, a NamedTuple), and
# unpickling imports mjkin, which before would be whichever the isolated path finds (an installed one, not the copy
# this process runs), compiling into that one's cache folder under its stamp, where this process never looks
_BOOT = ("import pickle, site, sys\n"
         "paths, jobs = pickle.loads(sys.stdin.buffer.read())\n"
         "for p in paths:\n"
         "    if p not in sys.path and p.endswith('-packages'):\n"
         "        site.addsitedir(p)\n"
         "sys.path[:] = paths + [p for p in sys.path if p not in paths]\n"
         "from mjkin.runtime.tier import _main\n"
         "_main(pickle.loads(jobs))\n")


def _spawn(jobs: list[tuple]) -> subprocess.Popen:
    """A child process (its own session: it outlives this one) that compiles ``jobs`` into the disk cache."""
    env = {**os.environ, "MJKIN_COMPILE": "wait"}
    for name in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME", "HOME"):  # relative to this process's folder, not "/"
        if env.get(name):
            env[name] = os.path.abspath(env[name])
    child = subprocess.Popen([sys.executable, "-I", "-c", _BOOT], stdin=subprocess.PIPE, cwd="/",
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, start_new_session=True)
    assert child.stdin is not None
    child.stdin.write(pickle.dumps((_child_path(), pickle.dumps(jobs))))  # see _BOOT
    child.stdin.close()
    return child


BACKGROUND = ("compiling kernels for their first use in a background process (cached for later runs; a minute or "
              "two); running them interpreted until then...")
ELSEWHERE = "another mjkin process is compiling kernels this run needs; running them interpreted until it is done..."


def compiled(jobs: list[tuple[Any, tuple]], small: bool) -> bool:
    """Whether the caller should call ``jobs``' kernels compiled (True) or :func:`interpreted` (False).

    Each job is a kernel and the numba types of its arguments. True when all are in memory or on disk (loaded so),
    or else once they are compiled here, as numba would. False for a ``small`` call in ``background`` mode while
    a child (started if need be) or another process compiles them.
    """
    if mode() == "interpret":
        return False
    if all(numba_private.load(k, s) for k, s in jobs):
        return True
    if small and mode() == "background":
        state = _COMPILER.status(jobs)
        if state in ("queued", "elsewhere", "running"):
            return False
        if state == "done" and all(numba_private.load(k, s) for k, s in jobs):  # else the child could not save
            return True
    for kernel, sig in jobs:
        kernel.compile(sig)
    return True


def on_miss(kernel: Any, args: tuple) -> Callable | None:
    """What a kernel's call runs instead of a version not in memory: interpreted (see :func:`compiled`), or None.

    Under ``NUMBA_DISABLE_JIT=1`` (numba's switch for debuggers and coverage) every call runs interpreted.
    """
    if numba_private.DISABLE_JIT:
        return functools.partial(interpreted_call, kernel)
    if not getattr(_local, "depth", 0) or compiled([(kernel, numba_private.argument_types(kernel, args))],
                                                   all(_small(a) for a in args)):
        return None
    return functools.partial(interpreted_call, kernel)


def _main(jobs: list[tuple]) -> None:
    """The child: compile each (address, signature) of ``jobs`` into the disk cache.

    It claims every kernel's compile lock first, so that another run finds them at work and waits for this
    child rather than start its own; a kernel another process holds already is left to that process.
    """
    os.nice(10)  # in the background: the process that runs interpreted meanwhile comes first
    claimed = []
    for (name, path, qualname), sig in jobs:
        try:
            module = importlib.import_module(name)
        except ImportError:
            spec = importlib.util.spec_from_file_location(name, path)
            assert spec is not None and spec.loader is not None
            module = sys.modules[name] = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
        kernel: Any = functools.reduce(getattr, qualname.split("."), module)
        claim = contextlib.ExitStack()
        if claim.enter_context(numba_private.compiling(kernel, wait=False)):
            claimed.append((kernel, sig, claim))
        else:  # another process compiles it
            claim.close()
    for kernel, sig, claim in claimed:
        with claim:  # given back as soon as it is compiled: a process waiting for it loads it then
            kernel.compile(sig)
