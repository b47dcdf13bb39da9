"""Where compiled kernels are kept on disk, and when a kept kernel is stale.

numba keeps a compiled function beside its source (``__pycache__``), under
``$NUMBA_CACHE_DIR`` when that is set, or else per user, and stamps it with its
own source file only. But a kernel carries the code of the kernels it calls from
other files (inlined or linked in), so an edit of ``fk.py`` alone would leave the
IK loop running the old FK. :class:`KernelCache` stamps each kernel instead with
:func:`stamp`: a digest of its file and of every file it imports, transitively,
within the package. An edit recompiles the kernels that depend on it and no
others, wherever the cache lives.

A kernel is saved only if the files of its stamp are still those this process
loaded (:func:`unchanged`): an edit or an upgrade while a kernel compiles must not
store the old code under the new source's stamp.

A cache folder that cannot be written (a read-only install or a Docker layer
warmed with ``mjkin warmup``) is still read: new versions go to the next
writable place, as numba chooses it, or nowhere when no place can be written
(computed in memory each run).

Nothing is loaded from a folder or file that another user can write
(:func:`secure`): numba's index and data files are pickles, and a planted one
would run as code. Generated source (the IK loop of a set of goal kinds,
:mod:`mjkin.ik.compiled`) is imported only from such a folder
(:func:`generated_file`): written where no other user can write, or found with
the same text where it was written ahead (a read-only install warmed by root).
Arrays that cost more to make than to read (:func:`stored_array`) are kept the same way.
"""

from __future__ import annotations

import ast
import atexit
import contextlib
import fcntl
import grp
import hashlib
import os
import shutil
import stat
import tempfile
import time
from collections.abc import Callable, Iterator
from functools import cache
from pathlib import Path
from typing import Any

import numba
import numpy as np
from numba.core import caching, config

from . import progress

PACKAGE = Path(__file__).resolve().parent.parent  # mjkin/
NUMBA = ((0, 68), (0, 69))  # the numba releases this module's use of numba's private caching API is tested with


def numba_unsupported(version: str) -> str | None:
    """Why numba ``version`` cannot run mjkin's kernel cache (one line), or None when it is in :data:`NUMBA`."""
    release = tuple(int(p) for p in version.split(".")[:2] if p.isdigit())
    (low, high) = NUMBA
    if low <= release < high:
        return None
    return (f"mjkin's kernel cache is tested with numba >={low[0]}.{low[1]},<{high[0]}.{high[1]} and this is numba "
            f"{version}: pip install 'numba>={low[0]}.{low[1]},<{high[0]}.{high[1]}'")


if (_why := numba_unsupported(numba.__version__)) is not None:
    raise ImportError(_why)


def _locator(*names: str) -> Any:
    """The locator class of numba's named one of ``names`` (0.61 dropped their leading underscore), or None."""
    return next((getattr(caching, n) for n in names if hasattr(caching, n)), None)


_PROVIDED = _locator("UserProvidedCacheLocator", "_UserProvidedCacheLocator")
_IN_TREE = _locator("InTreeCacheLocator", "_InTreeCacheLocator")
_USER_WIDE = _locator("UserWideCacheLocator", "_UserWideCacheLocator")

# ---- whom to trust: a file or folder no other user can write


def _owners() -> tuple[int, ...]:
    """The users whose files we may load: ourselves, root, and mjkin's owner (who could change our code anyway)."""
    return (os.getuid(), 0, os.stat(__file__).st_uid)


def _group_private(gid: int) -> bool:
    """Whether group ``gid`` is our own primary group with no other members (a user private group)."""
    if gid != os.getgid():
        return False
    try:
        return not set(grp.getgrgid(gid).gr_mem) - {os.environ.get("USER", "")}
    except KeyError:
        return True  # a group with no entry has no named members


def _writable_by_others(st: os.stat_result) -> bool:
    return bool(st.st_mode & 0o002 or st.st_mode & 0o020 and not _group_private(st.st_gid))


def secure(path: str | os.PathLike[str]) -> bool:
    """Whether no other user can change what ``path`` holds.

    It and every folder above it are owned by :func:`_owners` and writable by no one else, but for sticky
    folders such as ``/tmp`` above it.
    """
    try:
        real = Path(os.path.realpath(path))
        owners = _owners()
        for i, part in enumerate((real, *real.parents)):
            st = os.lstat(part)
            if st.st_uid not in owners or _writable_by_others(st) and not (i and st.st_mode & stat.S_ISVTX):
                return False
    except OSError:
        return False
    return True


def trusted_file(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is a regular file (not a link) in a :func:`secure` folder that only its owners can write."""
    try:
        st = os.lstat(path)
    except OSError:
        return False
    return (stat.S_ISREG(st.st_mode) and st.st_uid in _owners() and not _writable_by_others(st)
            and secure(os.path.dirname(os.path.abspath(path))))


@cache
def _read(path: str, mtime_ns: int, size: int) -> tuple[str, tuple[str, ...]]:
    """A source file's own digest and the files it imports (keyed by its mtime and size: an edit reads it again)."""
    text = Path(path).read_bytes()
    found: list[str] = []
    try:
        tree = ast.parse(text)
    except SyntaxError:
        tree = ast.Module(body=[], type_ignores=[])
    here = Path(path).parent
    top = here
    while (top.parent / "__init__.py").is_file():
        top = top.parent
    root = top if top.name == PACKAGE.name and (top / "__init__.py").is_file() else PACKAGE  # the package it is in
    for node in _statements(tree.body):
        if isinstance(node, ast.ImportFrom):
            if node.level:  # relative: from its own folder upwards
                base = here
                for _ in range(node.level - 1):
                    base = base.parent
                found += _module_files(base, (node.module or "").split("."), [a.name for a in node.names])
            elif node.module and node.module.split(".")[0] == PACKAGE.name:
                found += _module_files(root, node.module.split(".")[1:], [a.name for a in node.names])
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] == PACKAGE.name:
                    found += _module_files(root, a.name.split(".")[1:], [])
    return hashlib.sha256(text).hexdigest(), tuple(sorted(set(found)))


def _statements(body: list[ast.stmt]) -> Iterator[ast.stmt]:
    """Every statement in ``body`` and in the blocks nested in it.

    Imports are statements, so no expression (most of a module's nodes) is entered.
    """
    for node in body:
        yield node
        for field in ("body", "orelse", "finalbody", "handlers", "cases"):
            inner = getattr(node, field, None)
            if isinstance(inner, list):
                yield from _statements(inner)


def _module_files(base: Path, parts: list[str], names: list[str]) -> list[str]:
    """The files of module ``parts`` under ``base`` and of those of ``names`` that are its submodules.

    A package's ``__init__`` counts only when some name is not a submodule (it may define or re-export it).
    """
    folder = base.joinpath(*[p for p in parts if p])
    subs = [f for n in names if (f := folder / f"{n}.py").is_file() or (f := folder / n / "__init__.py").is_file()]
    own = [folder.with_suffix(".py")] if folder.with_suffix(".py").is_file() else (
        [folder / "__init__.py"] if len(subs) < len(names) or not names else [])
    return [str(f) for f in own + subs if f.is_file()]


def _file_info(path: str) -> tuple[str, tuple[str, ...]]:
    st = os.stat(path)
    return _read(path, st.st_mtime_ns, st.st_size)


def _closure(path: str | os.PathLike) -> dict[str, str]:
    """The digest of the source file ``path`` and of every package file it imports, transitively, by file."""
    seen: dict[str, str] = {}
    todo = [str(Path(path).resolve())]
    while todo:
        p = todo.pop()
        if p in seen:
            continue
        own, imports = _file_info(p)
        seen[p] = own
        todo += imports  # built from resolved folders (_read): already whole paths
    return seen


def stamp(path: str | os.PathLike) -> str:
    """Digest of the source file ``path`` and of every package file it imports, transitively.

    Imports are read from the source (``from ..kinematics.fk import ...``, ``import mjkin.runtime.jit``),
    ``TYPE_CHECKING`` ones included: a superset of what a kernel compiles in, never less.
    """
    seen = _closure(path)
    h = hashlib.sha256()
    for p in sorted(seen):
        h.update(f"{Path(p).name}:{seen[p]}\n".encode())
    return h.hexdigest()


_AS_LOADED: dict[str, tuple[int, int]] = {}  # source file -> (mtime, size) when this process loaded it


def _signature(path: str) -> tuple[int, int]:
    st = os.stat(path)
    return st.st_mtime_ns, st.st_size


def loaded(path: str | os.PathLike) -> None:
    """Note ``path`` as this process has it now: a kernel's file when the kernel is defined (its module imported)."""
    with contextlib.suppress(OSError):
        _AS_LOADED.setdefault(os.path.realpath(path), _signature(os.path.realpath(path)))


def unchanged(path: str | os.PathLike) -> bool:
    """Whether every file of ``path``'s :func:`stamp` is as this process loaded it, so what it compiled is that.

    A file first seen after it was loaded counts as loaded then.
    """
    try:
        return all(_AS_LOADED.setdefault(p, sig) == sig for p in _closure(path) if (sig := _signature(p)))
    except OSError:
        return False


for _folder, _subfolders, _files in os.walk(PACKAGE):  # the package as imported (~1 ms)
    _subfolders[:] = [d for d in _subfolders if d != "__pycache__"]
    for _name in _files:
        if _name.endswith(".py"):
            loaded(os.path.join(_folder, _name))


class _Stamped:
    """A numba locator stamped by :func:`stamp` (its file and what it imports), in a :func:`secure` folder."""

    _py_file: str

    def get_source_stamp(self) -> str:
        return stamp(self._py_file)

    def ensure_cache_path(self) -> None:
        super().ensure_cache_path()  # type: ignore[misc]  # numba's: made, and writable
        if not secure(self.get_cache_path()):  # type: ignore[attr-defined]
            raise PermissionError(f"{self.get_cache_path()} can be written by another user")  # type: ignore


class _Nowhere(_Stamped):
    """The last resort, where no folder can be written: kernels compile in memory, saved nowhere."""

    def __init__(self, py_func: Any, py_file: str) -> None:
        self._py_file = py_file
        self._lineno = py_func.__code__.co_firstlineno

    @classmethod
    def from_function(cls, py_func: Any, py_file: str) -> _Nowhere | None:
        return cls(py_func, py_file) if os.path.exists(py_file) else None

    def ensure_cache_path(self) -> None:
        raise PermissionError("no folder to write compiled kernels to")

    def get_cache_path(self) -> str:
        return os.path.join(os.path.dirname(self._py_file), "__pycache__")

    def get_disambiguator(self) -> str:
        return str(self._lineno)


# stamped where a kernel has a source file; numba's own for a notebook cell or a zipped module (a goal kind
# written in a notebook is cached as numba caches it)
_LOCATORS: list[Any] = [*(type(f"Stamped{base.__name__.lstrip('_')}", (_Stamped, base), {})
                          for base in (_PROVIDED, _IN_TREE, _USER_WIDE) if base is not None),
                        *(b for b in (_locator("IPythonCacheLocator", "_IPythonCacheLocator"),
                                      _locator("ZipCacheLocator", "_ZipCacheLocator")) if b is not None),
                        _Nowhere]


class _TrustedFile(caching.IndexDataCacheFile):
    """numba's index and data files, read only where :func:`trusted_file` (they are pickles: they run as code)."""

    def _load_index(self) -> dict:
        if os.path.lexists(self._index_path) and not trusted_file(self._index_path):
            return {}
        return super()._load_index()

    def _load_data(self, name: str) -> Any:
        if not trusted_file(self._data_path(name)):
            raise PermissionError(f"{self._data_path(name)} is not a file of ours")  # load() takes it as absent
        return super()._load_data(name)


class _Impl(caching.CompileResultCacheImpl):
    _locator_classes = _LOCATORS


class KernelCache(caching.FunctionCache):
    """numba's per-function disk cache, stamped by :func:`stamp`, that also reads read-only caches.

    Loads look in the folder numba writes to, then in ``$NUMBA_CACHE_DIR`` and beside the
    source, which may have been warmed ahead and made read-only.
    """

    _impl_class = _Impl

    def __init__(self, py_func: Any) -> None:
        super().__init__(py_func)
        locator = self._impl.locator
        source = locator._py_file
        root = getattr(config, "CACHE_DIR", "")  # numba's reading of $NUMBA_CACHE_DIR
        folders = [*([os.path.join(root, _PROVIDED.get_suitable_cache_subpath(source))] if root else []),
                   os.path.join(os.path.dirname(source), "__pycache__")]
        fresh = locator.get_source_stamp()
        base = self._impl.filename_base
        self._cache_file = _TrustedFile(self._cache_path, base, fresh)
        self._read_only = [_TrustedFile(f, base, fresh) for f in folders
                           if f != self._cache_path and os.path.isdir(f) and secure(f)]

    def _save_overload(self, sig: Any, data: Any) -> None:
        """Save as numba does, unless there is nowhere to write or the sources changed since they were loaded."""
        if not isinstance(self._impl.locator, _Nowhere) and unchanged(self._impl.locator._py_file):
            super()._save_overload(sig, data)

    def _load_overload(self, sig: Any, target_context: Any) -> Any:
        data = super()._load_overload(sig, target_context)
        if data is None and self._enabled and self._read_only:
            key = self._index_key(sig, target_context.codegen())
            for cache in self._read_only:
                if (payload := cache.load(key)) is not None:
                    return self._impl.rebuild(target_context, payload)
        return data

    @contextlib.contextmanager
    def compiling(self, wait: bool = True) -> Iterator[bool]:
        """Hold this kernel's compile lock: a second process that needs it waits, then loads what this one wrote.

        Test workers, ``mjkin warmup``'s processes and a dataset's workers each compile a kernel once between
        them, not once each. An advisory ``flock`` on a file beside the cache: the system drops it when the
        process ends, so a killed compile never blocks the next. Without a writable cache folder, no lock.
        A wait longer than :data:`LOCK_WAIT` seconds (a process that hangs) ends with the compile done here
        all the same, and says so. Yields whether the lock is held (or there is none); False at once with
        ``wait=False`` when another process holds it.
        """
        path = self.lock_path()
        if path in _HELD:  # this process holds it already (a kernel that calls itself)
            yield True
            return
        try:
            self._impl.locator.ensure_cache_path()
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
        except OSError:
            yield True
            return
        try:
            held = _flock(fd, LOCK_WAIT if wait else 0.0, os.path.basename(path)[:-5])
            if held:
                _HELD.add(path)
            yield held or wait
        finally:
            _HELD.discard(path)
            os.close(fd)

    def lock_path(self) -> str:
        """The file whose ``flock`` is this kernel's compile lock (:meth:`compiling`)."""
        return os.path.join(self._cache_path, f"{self._impl.filename_base}.lock")

    def busy(self) -> bool:
        """Whether another process holds this kernel's compile lock: it is compiling the kernel now."""
        path = self.lock_path()
        if path in _HELD:
            return False
        try:
            fd = os.open(path, os.O_RDWR | os.O_CLOEXEC)  # no lock file: no one has compiled here
        except OSError:
            return False
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # free: the close below gives it back
        except BlockingIOError:
            return True
        finally:
            os.close(fd)
        return False


class LazyCache:
    """Mixin of a numba dispatcher or cfunc: its ``_cache``, a :class:`KernelCache`, is made on first use.

    The stamp reads the sources the kernel imports (0.3 s over the package's kernels), which a process
    that never calls the kernel (``import mjkin``) need not pay. ``del kernel._cache`` drops the cache
    numba's constructor set.
    """

    @property
    def _cache(self) -> Any:
        cache = self.__dict__.get("_disk_cache")
        if cache is None:
            cache = self.__dict__["_disk_cache"] = KernelCache(self.__wrapped__)  # type: ignore[attr-defined]
        return cache

    @_cache.setter
    def _cache(self, value: Any) -> None:  # numba's constructor (a NullCache) and enable_caching()
        self.__dict__["_disk_cache"] = value

    @_cache.deleter
    def _cache(self) -> None:
        self.__dict__.pop("_disk_cache", None)
        self.__dict__.pop("_cache", None)  # set by numba's constructor before the class was swapped for this one


_HELD: set[str] = set()  # the compile locks this process holds (under numba's compiler lock: one thread at a time)
LOCK_WAIT = 600.0  # seconds to wait for another process's compile of a kernel (the IK loop: 1-3 min) before our own


def _flock(fd: int, seconds: float, name: str) -> bool:
    """Whether ``fd``'s exclusive lock was taken within ``seconds``; a wait over 2 s is said on stderr (the CLI)."""
    start = time.monotonic()
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
        except BlockingIOError:
            waited = time.monotonic() - start
            if waited >= seconds:
                if seconds:
                    progress.notice(f"{name}: another process held its compile lock for {seconds:.0f} s; "
                                    "compiling it here")
                return False
            if waited > 2.0:
                progress.notice(f"waiting for another mjkin process that is compiling {name} (at most "
                                f"{seconds:.0f} s)...")
            time.sleep(0.05)


def _ours(folder: Path) -> bool:
    """Whether ``folder`` exists (made if need be, readable by all as warmed installs are), secure, ours to write."""
    try:
        folder.mkdir(mode=0o755, parents=True, exist_ok=True)
        return os.lstat(folder).st_uid == os.getuid() and secure(folder) and os.access(folder, os.W_OK)
    except OSError:
        return False


_TEMPORARY: list[Path] = []


def _places(name: str) -> tuple[Path, ...]:
    """The folders for generated source ``name``, in order.

    Under ``$NUMBA_CACHE_DIR`` when set, beside the package's caches, in the user's cache folder
    (``$XDG_CACHE_HOME/mjkin`` or ``~/.cache/mjkin``).
    """
    root = os.environ.get("NUMBA_CACHE_DIR")
    xdg = Path(os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"))
    return (*([Path(root) / "mjkin" / name] if root else []), PACKAGE / "__pycache__" / name, xdg / "mjkin" / name)


def _writable(name: str) -> Path | None:
    """The first of :func:`_places` that is ours to write and no other user's (None: none is)."""
    return next((folder for folder in _places(name) if _ours(folder)), None)


def private_folder(name: str) -> Path:
    """The first of :func:`_places` that only this user can write, else a new temporary one for this process."""
    found = _writable(name)
    if found is not None:
        return found
    if not _TEMPORARY:  # a fresh folder of our own (mkdtemp makes it 0700), removed at exit
        _TEMPORARY.append(Path(tempfile.mkdtemp(prefix="mjkin-")))
        atexit.register(shutil.rmtree, _TEMPORARY[0], True)
    return _TEMPORARY[0]


def _kept(folder: str, name: str) -> Iterator[Path]:
    """The files ``name`` in the folders ``folder`` of :func:`_places` that we may read (:func:`trusted_file`)."""
    return (path for place in _places(folder) if trusted_file(path := place / name))


def generated_file(folder: str, name: str, text: str) -> Path:
    """The file ``name`` holding ``text`` in a trusted folder ``folder`` of :func:`_places`, written if none has it.

    A file that is already there with this text is used where it is, read-only too (an install warmed by
    ``mjkin warmup`` in a Docker image, run as another user or on a read-only file system); else the text is
    written, atomically, into :func:`private_folder`.
    """
    for path in _kept(folder, name):
        with contextlib.suppress(OSError, UnicodeDecodeError):
            if path.read_text() == text:
                return path
    path = private_folder(folder) / name
    tmp = path.with_name(f".{name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    tmp.replace(path)
    return path


def stored_array(folder: str, key: str, make: Callable[[], np.ndarray]) -> np.ndarray:
    """``make()``, kept as ``<digest of key>.npy`` in a trusted folder of :func:`_places` for later processes.

    ``key`` must name everything the array depends on (versions, inputs, the :func:`stamp` of its source). A file
    found where no other user can write is read as it is (read-only too); else the array is made and written,
    atomically, into :func:`private_folder` (or not at all when no folder can be written).
    """
    name = hashlib.sha256(key.encode()).hexdigest()[:32] + ".npy"
    for path in _kept(folder, name):
        with contextlib.suppress(OSError, ValueError):
            return np.load(path, allow_pickle=False)
    array = make()
    place = _writable(folder)
    if place is None:
        return array
    path = place / name
    tmp = path.with_name(f".{name}.{os.getpid()}.tmp.npy")
    try:
        np.save(tmp, array, allow_pickle=False)
        tmp.replace(path)
    except OSError:
        tmp.unlink(missing_ok=True)
    return array
