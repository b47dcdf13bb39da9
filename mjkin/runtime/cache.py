"""Where compiled kernels and generated code are kept, whom to trust there, and when a kept kernel is stale.

A kernel is kept under a :func:`stamp` of its package's sources and mjkin's, as this process loaded
them. Nothing is loaded from a folder or file another user can write (:func:`secure`,
:func:`trusted_file`): numba's cache files are pickles, and a planted one would run as code. A
process that compiles a kernel holds its compile lock (:func:`locked`), so that processes compile
it once between them. numba's side of the cache is in :mod:`.numba_private`.
"""

from __future__ import annotations

import atexit
import contextlib
import fcntl
import functools
import grp
import hashlib
import os
import shutil
import stat
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from ..errors import MjkinIOError
from . import progress

PACKAGE = Path(__file__).resolve().parent.parent  # mjkin/

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


# ---- when a kept kernel is stale

_LOADED: dict[str, tuple[list, str]] = {}  # a package's folder -> its sources' (file, mtime, size) as loaded, digest


@functools.cache
def _top(path: str) -> str:
    """The folder of the top-level package that holds the source file ``path``; ``path`` itself when none does."""
    top = os.path.realpath(path)
    while os.path.isfile(os.path.join(folder := os.path.dirname(top), "__init__.py")):
        top = folder
    return top


def _state(top: str) -> list[tuple[str, int, int]]:
    """The (file, mtime, size) of the module ``top``, or of the ``.py`` files of the package folder ``top``."""
    files = [top] if os.path.isfile(top) else []
    for folder, subfolders, names in os.walk(top):
        subfolders[:] = sorted(d for d in subfolders if d != "__pycache__")  # (generated modules live there)
        files += [os.path.join(folder, name) for name in sorted(names) if name.endswith(".py")]
    state = []
    for file in files:
        with contextlib.suppress(OSError):
            st = os.stat(file)
            state.append((file, st.st_mtime_ns, st.st_size))
    return state


def loaded(path: str | os.PathLike[str]) -> str:
    """The folder of ``path``'s package; its sources' sizes and times are noted when first asked (no file is read).

    Asked when a kernel is defined, and for mjkin when it is imported: before the code a kernel compiles is loaded.
    """
    top = _top(str(path))
    if top not in _LOADED:
        _LOADED[top] = (_state(top), "")
    return top


def _digest(top: str) -> str:
    """The digest of the sources of ``top`` as noted by :func:`loaded`, read when first asked.

    A file changed since it was noted (its size or time) makes a digest no process shares: this process compiles
    the code it loaded, which is not what the disk holds now.
    """
    state, digest = _LOADED[top]
    if not digest:
        h = hashlib.sha256()
        for file, _, _ in state:
            with contextlib.suppress(OSError):
                h.update(f"{os.path.relpath(file, top)}\0".encode() + Path(file).read_bytes() + b"\0")
        if _state(top) != state:
            h.update(f"changed since loaded: {os.getpid()} {time.time_ns()}".encode())
        _LOADED[top] = (state, digest := h.hexdigest())
    return digest


def stamp(path: str | os.PathLike[str]) -> str:
    """What a kernel of the source file ``path`` is kept under: its package's sources and mjkin's, as loaded.

    A kernel carries the code of the kernels it calls (inlined or linked in), from its package and from mjkin, so
    an edit of any of those files recompiles it (numba's own stamp, the kernel's file alone, would not).
    """
    return hashlib.sha256(f"{_digest(loaded(path))} {_digest(loaded(__file__))}".encode()).hexdigest()


loaded(__file__)  # mjkin as imported


# ---- the compile lock: processes that need a kernel compile it once between them

_HELD: set[str] = set()  # the compile locks this process holds (under numba's compiler lock: one thread at a time)
LOCK_WAIT = 600.0  # seconds to wait for another process's compile of a kernel (the IK loop: 1-3 min) before our own


@contextlib.contextmanager
def locked(path: str | None, wait: bool = True) -> Iterator[bool]:
    """Hold the compile lock ``path``: another process that needs the kernel waits, then loads what this one wrote.

    An advisory ``flock``: the system drops it when the process ends, so a killed compile never blocks the next.
    No lock where ``path`` is None or cannot be made. A wait longer than :data:`LOCK_WAIT` seconds (a process that
    hangs) ends with the compile done here all the same, and says so. Yields whether the lock is held (or there is
    none); False at once with ``wait=False`` when another process holds it.
    """
    fd = -1
    if path is not None and path not in _HELD:  # (held already: a kernel that calls itself)
        with contextlib.suppress(OSError):
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
    if path is None or fd < 0:
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


def busy(path: str) -> bool:
    """Whether another process holds the compile lock ``path``: it is compiling that kernel now."""
    try:
        fd = -1 if path in _HELD else os.open(path, os.O_RDWR | os.O_CLOEXEC)  # no file: no one compiled here
    except OSError:
        return False
    try:
        return fd >= 0 and not _flock(fd, 0.0, "")  # free: the close below gives it back
    finally:
        if fd >= 0:
            os.close(fd)


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


# ---- generated code and stored arrays


def ours(folder: str | os.PathLike[str]) -> bool:
    """Whether ``folder`` exists (made if need be, readable by all as warmed installs are), secure, ours to write."""
    try:
        os.makedirs(folder, mode=0o755, exist_ok=True)
        return os.lstat(folder).st_uid == os.getuid() and secure(folder) and os.access(folder, os.W_OK)
    except OSError:
        return False


def _places(name: str) -> tuple[Path, ...]:
    """The folders for generated files ``name``, in order.

    Under ``$NUMBA_CACHE_DIR`` when set, beside the package's caches, in the user's cache folder.
    """
    root = os.environ.get("NUMBA_CACHE_DIR")
    xdg = Path(os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"))
    return (*([Path(root) / "mjkin" / name] if root else []), PACKAGE / "__pycache__" / name, xdg / "mjkin" / name)


_TEMPORARY: list[Path] = []


def _temporary() -> Path:
    """A fresh folder of this process's own (mkdtemp makes it 0700), removed at exit."""
    if not _TEMPORARY:
        _TEMPORARY.append(Path(tempfile.mkdtemp(prefix="mjkin-")))
        atexit.register(shutil.rmtree, _TEMPORARY[0], True)
    return _TEMPORARY[0]


def _writable(name: str) -> Path | None:
    """The first of :func:`_places` that only this user can write (None: none)."""
    return next((folder for folder in _places(name) if ours(folder)), None)


def private_folder(name: str) -> Path:
    """The first of :func:`_places` that only this user can write, else :func:`_temporary`."""
    return _writable(name) or _temporary()


def _kept(folder: str, name: str) -> Iterator[Path]:
    """The files ``name`` in the folders ``folder`` of :func:`_places` that we may read (:func:`trusted_file`)."""
    return (path for place in _places(folder) if trusted_file(path := place / name))


def _save(folder: Path, name: str, write: Callable[[Path], object]) -> Path | None:
    """``write(tmp)``, then ``tmp`` renamed to ``folder / name``; that path, or None if the disk would not take it."""
    tmp = folder / f".{name}.{os.getpid()}.tmp{Path(name).suffix}"
    try:
        write(tmp)
        return tmp.replace(folder / name)
    except OSError as e:  # a full disk, a quota, a read-only file system: said once, never raised
        progress.warn(f"could not save {name} in {folder} ({e.strerror})")
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        return None


def generated_file(folder: str, name: str, text: str) -> Path:
    """The file ``name`` holding ``text`` in a trusted folder ``folder`` of :func:`_places`, written if none has it.

    A file that is already there with this text is used where it is, read-only too (an install warmed by
    ``mjkin warmup`` in a Docker image, run as another user or on a read-only file system); else the text is
    written, atomically, into :func:`private_folder` (a temporary folder where that disk is full).
    """
    for path in _kept(folder, name):
        with contextlib.suppress(OSError, UnicodeDecodeError):
            if path.read_text() == text:
                return path
    place = private_folder(folder)
    saved = _save(place, name, lambda tmp: tmp.write_text(text))
    if saved is None and place != _temporary():  # (its disk is full): this process's temporary folder
        saved = _save(_temporary(), name, lambda tmp: tmp.write_text(text))
    if saved is None:
        raise MjkinIOError(f"cannot write the generated module {name}: neither {place} nor {_temporary()} takes it")
    return saved


def stored_array(folder: str, key: str, make: Callable[[], np.ndarray]) -> np.ndarray:
    """``make()``, kept as ``<digest of key>.npy`` in a trusted folder of :func:`_places` for later processes.

    ``key`` must name everything the array depends on (versions, inputs, the :func:`stamp` of its source). A file
    found where no other user can write is read as it is (read-only too); else the array is made and written,
    atomically, into the first folder ours to write (or nowhere).
    """
    name = hashlib.sha256(key.encode()).hexdigest()[:32] + ".npy"
    for path in _kept(folder, name):
        with contextlib.suppress(OSError, ValueError):
            return np.load(path, allow_pickle=False)
    array = make()
    if (place := _writable(folder)) is not None:
        _save(place, name, lambda tmp: np.save(tmp, array, allow_pickle=False))
    return array
