"""numba's private API, in this module alone: the kernels' dispatcher and their disk cache.

mjkin asks more of numba than it documents: a dispatcher whose first small calls may run
interpreted (:mod:`.tier`), and a disk cache stamped by the kernel's package (:mod:`.cache`),
read from every folder we trust and written to the first that is ours (``$NUMBA_CACHE_DIR``,
beside the source, the user's cache folder; none: compiled in memory each run). Those
subclass numba's internals, so the release is checked here when mjkin is imported.
"""

from __future__ import annotations

import contextlib
import functools
import os
from collections.abc import Callable
from typing import Any

import numba
from numba.core import caching, config, event, sigutils
from numba.core.ccallback import CFunc
from numba.core.compiler_lock import global_compiler_lock
from numba.core.dispatcher import Dispatcher
from numba.core.registry import CPUDispatcher

from . import cache, progress

NUMBA = (0, 68)  # the numba release this module is tested with (pyproject.toml asks for it; tests/project checks)


def numba_unsupported(version: str) -> str | None:
    """Why numba ``version`` cannot run mjkin (one line), or None when it is the :data:`NUMBA` release."""
    if tuple(int(p) for p in version.split(".")[:2] if p.isdigit()) == NUMBA:
        return None
    return (f"mjkin drives numba {NUMBA[0]}.{NUMBA[1]}'s internals and this is numba {version}: "
            f"pip install 'numba=={NUMBA[0]}.{NUMBA[1]}.*'")


if (_why := numba_unsupported(numba.__version__)) is not None:
    raise ImportError(_why)

DISABLE_JIT = bool(getattr(config, "DISABLE_JIT", 0))  # numba's switch for debuggers and coverage


class _Locator(caching._CacheLocator):
    """Where a kernel of a source file is kept: the first folder ours to write (:func:`cache.ours`), if any."""

    def __init__(self, py_func: Any, py_file: str) -> None:
        self.py_file, self.line = py_file, py_func.__code__.co_firstlineno
        user = os.path.join(os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "numba")
        sub = self.get_suitable_cache_subpath(py_file)
        root = getattr(config, "CACHE_DIR", "")  # numba's reading of $NUMBA_CACHE_DIR
        self.folders = [*([os.path.join(root, sub)] if root else []),
                        os.path.join(os.path.dirname(py_file), "__pycache__"),
                        os.path.join(user, sub)] if os.path.isfile(py_file) else []  # none for code run from text
        self.writable = next((f for f in self.folders if cache.ours(f)), None)

    @classmethod
    def from_function(cls, py_func: Any, py_file: str) -> _Locator:
        return cls(py_func, py_file)

    def get_cache_path(self) -> str:
        return self.writable or next(iter(self.folders), "")

    def get_source_stamp(self) -> str:
        return cache.stamp(self.py_file) if self.folders else ""

    def get_disambiguator(self) -> str:
        return str(self.line)


class _TrustedFile(caching.IndexDataCacheFile):
    """numba's index and data files, read only where :func:`cache.trusted_file` (they are pickles: they run as code)."""

    def _load_index(self) -> dict:
        if os.path.lexists(self._index_path) and not cache.trusted_file(self._index_path):
            return {}
        return super()._load_index()

    def _load_data(self, name: str) -> Any:
        if not cache.trusted_file(self._data_path(name)):
            raise PermissionError(f"{self._data_path(name)} is not a file of ours")  # load() takes it as absent
        return super()._load_data(name)


class _Impl(caching.CompileResultCacheImpl):
    _locator_classes = [caching.IPythonCacheLocator, _Locator]  # a notebook's cells as numba keeps them


class KernelCache(caching.FunctionCache):
    """numba's per-function disk cache, stamped by :func:`cache.stamp`, read from every trusted folder."""

    _impl_class = _Impl

    def __init__(self, py_func: Any) -> None:
        super().__init__(py_func)
        locator, base = self._impl.locator, self._impl.filename_base
        self._cache_file = _TrustedFile(self._cache_path, base, locator.get_source_stamp())
        self._files = [self._cache_file, *(_TrustedFile(f, base, locator.get_source_stamp())
                                           for f in getattr(locator, "folders", ())
                                           if f != self._cache_path and os.path.isdir(f) and cache.secure(f))]

    def _load_overload(self, sig: Any, target_context: Any) -> Any:
        key = self._index_key(sig, target_context.codegen())
        payload = next((p for f in self._files if (p := f.load(key)) is not None), None)
        return None if payload is None else self._impl.rebuild(target_context, payload)

    def _save_overload(self, sig: Any, data: Any) -> None:
        """Save as numba does where there is a folder to write to.

        A full disk (or a quota, or a read-only one) costs the next runs a compile, not this one its answer.
        """
        if getattr(self._impl.locator, "writable", True):
            try:
                super()._save_overload(sig, data)
            except OSError as e:
                progress.warn(f"could not save compiled kernels in {self._cache_path} ({e.strerror}); they are "
                              "compiled again in later runs")

    def lock_path(self) -> str:
        """The file whose ``flock`` is this kernel's compile lock (:func:`cache.locked`)."""
        return os.path.join(self._cache_path, f"{self._impl.filename_base}.lock")

    def compiling(self, wait: bool = True) -> contextlib.AbstractContextManager[bool]:
        """:func:`cache.locked` on :meth:`lock_path`; no lock without a folder to write."""
        return cache.locked(self.lock_path() if getattr(self._impl.locator, "writable", True) else None, wait)

    def busy(self) -> bool:
        """Whether another process holds this kernel's compile lock: it is compiling the kernel now."""
        return bool(getattr(self._impl.locator, "writable", True)) and cache.busy(self.lock_path())


class _Lazy:
    """Mixin of a dispatcher or cfunc: its ``_cache``, a :class:`KernelCache`, made on first use (not at import)."""

    @property
    def _cache(self) -> KernelCache:
        if (made := self.__dict__.get("_disk_cache")) is None:
            made = self.__dict__["_disk_cache"] = KernelCache(self.__wrapped__)  # type: ignore[attr-defined]
        return made

    @_cache.setter
    def _cache(self, value: Any) -> None:  # numba's constructor sets a NullCache: ignored, ours is made when used
        if not isinstance(value, caching.NullCache):
            self.__dict__["_disk_cache"] = value


class Kernel(_Lazy, CPUDispatcher):
    """numba's dispatcher, but a call of a version not in memory asks :attr:`on_miss` first (:mod:`.tier`)."""

    def on_miss(self, args: tuple) -> Callable | None:
        """What to run instead of compiling for ``args`` (None: compile); set per kernel by :func:`kernel`."""
        return None

    def _compile_for_args(self, *args: Any, **kws: Any) -> Any:
        if not kws and (run := self.on_miss(args)) is not None:
            return run
        return super()._compile_for_args(*args, **kws)  # type: ignore[misc]  # numba's, not in its stubs

    def compile(self, sig: Any) -> Any:
        """Numba's compile, under the kernel's compile lock when it is not in memory yet.

        numba's own (in-process) compiler lock is taken first, so a thread never holds the file lock while it
        waits for numba's; kernels lock their callees only, so two processes never wait on each other.
        """
        if tuple(sigutils.normalize_signature(sig)[0]) in self.overloads:
            return super().compile(sig)
        with global_compiler_lock, self._cache.compiling():
            return super().compile(sig)


def kernel(fn: Callable, on_miss: Callable[[Kernel, tuple], Callable | None], **options: Any) -> Kernel:
    """``numba.njit(**options)(fn)``, made a :class:`Kernel`: cached on disk, and ``on_miss`` asked on a miss.

    Made so under ``NUMBA_DISABLE_JIT`` too (numba's ``njit`` would give ``fn``): ``on_miss`` runs its calls as Python.
    """
    made = Kernel(py_func=fn, locals={}, targetoptions={"nopython": True, **options})
    made.on_miss = functools.partial(on_miss, made)  # type: ignore[method-assign]
    return made


class _CFunc(_Lazy, CFunc):
    """numba's cfunc, cached like a kernel."""


def cfunc(fn: Callable, signature: Any) -> CFunc:
    """``numba.cfunc(signature)(fn)`` cached like a kernel; not compiled until its ``compile()`` is called."""
    return _CFunc(fn, sigutils.normalize_signature(signature), locals={}, options={})


def is_kernel(obj: Any) -> bool:
    """Whether ``obj`` is a numba dispatcher (a kernel, ours or numba's own)."""
    return isinstance(obj, Dispatcher)


def argument_types(kernel: Any, args: tuple) -> tuple:
    """The numba types of ``args`` as ``kernel`` would compile them."""
    return tuple(kernel.typeof_pyval(a) for a in args)


def load(kernel: Any, sig: tuple) -> bool:
    """Whether ``kernel`` has a version for ``sig`` in memory, after loading it from the disk cache if it is there."""
    if sig in kernel.overloads:
        return True
    if (cres := kernel._cache.load_overload(sig, kernel.targetctx)) is None:
        return False
    kernel._cache_hits[sig] += 1
    kernel.targetctx.insert_user_function(cres.entry_point, cres.fndesc, [cres.library])
    kernel.add_overload(cres)
    return True


def busy(kernel: Any) -> bool:
    """Whether another process is compiling ``kernel`` (it holds its compile lock)."""
    return isinstance(kernel, Kernel) and kernel._cache.busy()


def compiling(kernel: Any, wait: bool) -> contextlib.AbstractContextManager[bool]:
    """``kernel``'s compile lock (:meth:`KernelCache.compiling`); held at once if it has no disk cache."""
    return kernel._cache.compiling(wait) if isinstance(kernel, Kernel) else contextlib.nullcontext(True)


def entry(dispatcher: Any, *types_: Any) -> Callable:
    """The compiled code of ``dispatcher`` for arguments of these numba types, callable without numba's dispatch.

    A dispatcher types every argument of every call (~0.2 µs for three arrays, ~0.6 µs for a packed problem), a
    quarter of a one-q pose. The entry skips that and trusts its arguments: the caller must pass exactly these
    types (dtype, ndim, C-contiguity), or it reads memory wrongly. Compiles the version if needed.
    """
    sig = tuple(types_)
    if sig not in dispatcher.overloads:
        dispatcher.compile(sig)
    return getattr(dispatcher.overloads.get(sig), "entry_point", None) or dispatcher


class _Listener(event.Listener):
    def __init__(self, start: Callable[[Any], None], end: Callable[[Any], None]) -> None:
        self.start, self.end = start, end

    def on_start(self, event: event.Event) -> None:
        self.start(getattr(event.data.get("dispatcher"), "py_func", None))

    def on_end(self, event: event.Event) -> None:
        self.end(getattr(event.data.get("dispatcher"), "py_func", None))


def on_compile(start: Callable[[Any], None], end: Callable[[Any], None]) -> None:
    """Call ``start(fn)`` and ``end(fn)`` around every compile numba does of a function ``fn`` (not its cache loads)."""
    event.register("numba:compile", _Listener(start, end))



on_compile(progress.compile_started, progress.compile_ended)
