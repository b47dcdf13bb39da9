"""Atomic file writes (a temporary file in the same folder, then a rename), and checking a path before the work.

A temporary file is named ``.NAME.mjkin-tmp-PID-XXXXXXXX.SUFFIX`` beside its
target ``NAME`` (``PID`` the writing process, ``XXXXXXXX`` :func:`tempfile.mkstemp`'s
random part). A write that is killed leaves it behind; the next write into the
same folder removes such leftovers: our pattern only, only those last changed
before this process started (imported mjkin: :data:`STARTED`), and only when the
process that wrote them is gone (a live writer may be between two writes).
"""

from __future__ import annotations

import contextlib
import errno
import io
import json
import math
import os
import re
import stat
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from functools import lru_cache
from pathlib import Path
from typing import Any, TypeVar

from ..errors import InputError, MjkinIOError

T = TypeVar("T")
TEMP_MARK = "mjkin-tmp"
STARTED = time.time()  # when this process imported mjkin: leftovers must be older than this
_TEMP = re.compile(rf"\.(?P<name>.+)\.{TEMP_MARK}-(?P<pid>\d+)-[a-z0-9_]{{8}}(?P<suffix>(\.[^.]*)?)")


def _temp_file(target: Path, folder: Path) -> str:
    """Create this process's temporary file for ``target`` in ``folder`` (mkstemp: exclusive, mode 0600); its path."""
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.{TEMP_MARK}-{os.getpid()}-", suffix=target.suffix, dir=folder)
    os.close(fd)
    return tmp


def _running(pid: int) -> bool:
    """Whether process ``pid`` exists (on POSIX; elsewhere every process counts as running)."""
    if os.name != "posix":
        return True
    try:
        os.kill(pid, 0)  # signal 0: only the existence check
    except ProcessLookupError:
        return False
    except OSError:  # another user's process (EPERM): running
        return True
    return True


def remove_stale_temps(folder: str | os.PathLike[str]) -> list[Path]:
    """Delete the temporary files that killed mjkin writes left in ``folder``; returns those deleted.

    Only names of our pattern (``.NAME.mjkin-tmp-PID-XXXXXXXX.SUFFIX`` with SUFFIX the
    suffix of NAME), last modified before this process started, whose process
    ``PID`` is gone. A file that cannot be deleted is left alone.
    """
    gone: list[Path] = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return gone
    for entry in entries:
        m = _TEMP.fullmatch(entry.name)
        if m is None or Path(m["name"]).suffix != m["suffix"] or _running(int(m["pid"])):
            continue
        try:
            if entry.is_file(follow_symlinks=False) and entry.stat(follow_symlinks=False).st_mtime < STARTED:
                os.unlink(entry.path)
                gone.append(Path(entry.path))
        except OSError:
            continue
    return gone


def check_writable(path: str | os.PathLike[str], suffixes: Sequence[str] = (), what: str = "output") -> Path:
    """Check, before any work, that ``path`` can be written: suffix, folder, permission.

    ``suffixes`` (e.g. ``(".mp4", ".png")``, case-insensitive) are the allowed
    endings, any when empty. The folder's permission is probed by creating and
    removing a temporary file there, so read-only mounts and ``/proc`` are caught
    as well as missing folders; nothing is left behind.

    Raises:
        InputError: the suffix is not allowed, or ``path`` is a folder.
        MjkinIOError: the folder does not exist or cannot be written.
    """
    target = Path(path)
    if suffixes and target.suffix.lower() not in suffixes:
        raise InputError(f"{what} must end in {', '.join(suffixes)}; got {str(target)!r}")
    if target.is_dir():
        raise InputError(f"{what} {str(target)!r} is a folder; give a file name")
    folder = target.parent if str(target.parent) else Path(".")
    if not folder.is_dir():
        raise MjkinIOError(f"cannot write {str(target)!r}: folder {str(folder)!r} does not exist")
    try:
        probe = _temp_file(target, folder)
    except OSError as e:  # /proc answers "no such file": say only that it is not writable
        reason = "" if e.errno == errno.ENOENT else f" ({e.strerror or e})"
        raise MjkinIOError(f"cannot write {str(target)!r}: folder {str(folder)!r} is not writable{reason}") from None
    os.unlink(probe)
    return target


def as_path(path: Any, what: str = "path") -> Path:
    """``path`` (text or an ``os.PathLike`` of text) as a :class:`Path`; :class:`InputError` for anything else."""
    if isinstance(path, str) or (isinstance(path, os.PathLike) and isinstance(os.fspath(path), str)):
        return Path(path)
    raise InputError(f"{what} must be a file path (str or pathlib.Path), got {type(path).__name__}")


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it over ``path``, else delete it.

    The temporary name keeps the suffix, so writers that choose a format by
    extension still work. Leftovers of killed writes in the folder are removed
    first (:func:`remove_stale_temps`). Raises :class:`MjkinIOError` when the
    folder cannot be written.
    """
    target = as_path(path)
    folder = target.parent if str(target.parent) else Path(".")
    if not folder.is_dir():
        raise MjkinIOError(f"cannot write {str(target)!r}: folder {str(folder)!r} does not exist")
    remove_stale_temps(folder)
    try:
        tmp = _temp_file(target, folder)
    except OSError as e:
        raise MjkinIOError(f"cannot write {str(target)!r}: {e.strerror}") from None
    umask = os.umask(0)
    os.umask(umask)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; the result should look like any new file
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` to ``path`` atomically; returns the path."""
    return write_with(path, lambda p: p.write_text(text))


def write_with(path: str | os.PathLike[str], writer: Callable[[Path], object]) -> Path:
    """Call ``writer(tmp_path)`` and move the result to ``path`` atomically."""
    with atomic_path(path) as tmp:
        try:
            writer(tmp)
        except OSError as e:
            raise MjkinIOError(f"cannot write {str(path)!r}: {e}") from None
    return Path(path)


def strict_json(data: Any, indent: int | None = None) -> str:
    """JSON text of ``data`` that every parser takes: non-finite numbers (an infinite error, say) become null."""
    return json.dumps(_finite(data), indent=indent, allow_nan=False)


def _finite(data: Any) -> Any:
    if isinstance(data, float):
        return data if math.isfinite(data) else None
    if isinstance(data, dict):
        return {k: _finite(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return [_finite(v) for v in data]
    return data


def per_file(maxsize: int) -> Callable[[Callable[[str], T]], Callable[[str | os.PathLike[str]], T]]:
    """Decorate ``load(path)`` so a file is read once while it stays the same (its mtime and size).

    The decorated function takes any path; ``load`` gets it resolved. The ``maxsize`` latest files are kept.
    """
    def decorate(load: Callable[[str], T]) -> Callable[[str | os.PathLike[str]], T]:
        @lru_cache(maxsize=maxsize)
        def kept(path: str, mtime_ns: int, size: int) -> T:
            return load(path)

        def read(path: str | os.PathLike[str]) -> T:
            resolved = str(Path(path).resolve())
            st = os.stat(resolved)
            return kept(resolved, st.st_mtime_ns, st.st_size)

        read.__doc__ = load.__doc__
        return read

    return decorate


# ------------------------------------------------------------------ reading what the user gives
MB = 1 << 20
# the most mjkin reads of each kind of file (bytes): a sane file is far smaller; a bigger one (or /dev/zero, a
# file still growing) is refused by a one-line error before it fills the memory
LIMITS = {
    "bvh": 64 * MB,  # parsing takes ~10x the text: 64 MB is ~300k frames of a 60-joint skeleton
    "npz clip": 256 * MB,  # AMASS clips are a few MB; only the arrays read are decompressed, each checked first
    "body model": 1024 * MB,  # SMPL-X's .npz is ~0.5 GB (unused arrays are never decompressed)
    "json": 256 * MB,  # trajectories, journals, poses
    "mapping": 1 * MB,  # a few dozen names
    "report": 256 * MB,  # report.csv: ~0.5 kB a clip
    "model": 256 * MB,  # an MJCF/URDF file (MuJoCo reads it): a few kB, more with meshes written inline
}
_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def _size(n: int) -> str:
    return f"{n / MB:g} MB" if n >= MB else f"{n} bytes"


def _too_big(what: str, name: str, limit: int, hint: str) -> str:
    hint = "is it the right file?" if hint == "give the file itself" else hint
    return f"{what} {name} is over {_size(limit)}, the most mjkin reads of a {what}; {hint}"


def kind_of(path: str | os.PathLike[str]) -> str | None:
    """What ``path`` is when it is no regular file (links followed): "a FIFO (named pipe)", "a folder", ...

    None for a regular file or a path that does not exist.
    """
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return None
    return None if stat.S_ISREG(mode) else next((k for test, k in _KINDS if test(mode)), "not a regular file")


@contextlib.contextmanager
def open_input(path: str | os.PathLike[str], what: str, limit: int, error: type[MjkinIOError] = MjkinIOError,
               hint: str = "give the file itself") -> Iterator[io.BufferedReader]:
    """The regular file at ``path`` opened for reading (binary); ``what`` names it in errors ("BVH file", ...).

    A FIFO, a device, a socket or a folder is refused without being read (opened non-blocking, so a FIFO
    never waits for a writer), and so is a file over ``limit`` bytes; symlinks are followed. The messages
    say what is wrong with the file, never what it holds.

    Raises:
        error: (a :class:`MjkinIOError`) missing, not a regular file, over ``limit``, or unreadable.
    """
    name = repr(os.fspath(path))
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | getattr(os, "O_NOCTTY", 0))
    except FileNotFoundError:
        raise error(f"{what} not found: {name}") from None
    except OSError as e:
        if e.errno == errno.ENXIO:  # a socket (or a FIFO with no reader on some systems)
            raise error(f"{what} {name} is a socket, not a regular file; {hint}") from None
        raise error(f"cannot read {what} {name}: {e.strerror or e}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            kind = next((k for test, k in _KINDS if test(st.st_mode)), "not a regular file")
            raise error(f"{what} {name} is {kind}, not a regular file; {hint}")
        if st.st_size > limit:
            raise error(_too_big(what, name, limit, hint))
        os.set_blocking(fd, True)
        f = os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise
    with f:
        yield f


def check_input(path: str | os.PathLike[str], what: str, limit: int, error: type[MjkinIOError] = MjkinIOError,
                hint: str = "give the file itself") -> None:
    """Check that ``path`` is a regular file of at most ``limit`` bytes that can be read, reading none of it.

    For a file another library reads itself (MuJoCo a model or a scene): a FIFO given there would hang it.

    Raises:
        error: (a :class:`MjkinIOError`) as :func:`open_input`'s.
    """
    with open_input(path, what, limit, error, hint):
        pass


def read_input(path: str | os.PathLike[str], what: str, limit: int, error: type[MjkinIOError] = MjkinIOError,
               hint: str = "give the file itself") -> bytes:
    """The bytes of the regular file at ``path``, at most ``limit`` (see :func:`open_input`).

    A file that grows past ``limit`` while read (or says it is empty, as ``/proc`` files do, but is not) is
    refused as well: no more than ``limit + 1`` bytes are ever read.

    Raises:
        error: (a :class:`MjkinIOError`) missing, not a regular file, over ``limit``, or unreadable.
    """
    with open_input(path, what, limit, error, hint) as f:
        try:
            data = _read_at_most(f, limit + 1, os.fstat(f.fileno()).st_size)
        except OSError as e:
            raise error(f"cannot read {what} {os.fspath(path)!r}: {e.strerror or e}") from None
    if len(data) > limit:
        raise error(_too_big(what, repr(os.fspath(path)), limit, hint))
    return data


def _read_at_most(f: io.BufferedReader, most: int, size: int) -> bytes:
    """Up to ``most`` bytes of ``f``, a file that says it holds ``size`` (a guess: /proc's say 0, a file may grow).

    Read in one piece of ``size`` and a byte when that is right: a buffer of ``most`` bytes would be allocated
    whole, however small the file.
    """
    chunks = [f.read(min(size + 1, most))]
    have = len(chunks[0])
    while chunks[-1] and have < most:
        chunks.append(f.read(min(MB, most - have)))
        have += len(chunks[-1])
    return chunks[0] if len(chunks) <= 2 and not chunks[-1] else b"".join(chunks)


def read_input_text(path: str | os.PathLike[str], what: str, limit: int, error: type[MjkinIOError] = MjkinIOError,
                    errors: str = "strict", hint: str = "give the file itself") -> str:
    """:func:`read_input` decoded as UTF-8 (``errors`` as :meth:`bytes.decode`'s; strict: a one-line error)."""
    data = read_input(path, what, limit, error, hint)
    try:
        return data.decode("utf-8", errors)
    except UnicodeDecodeError as e:
        raise error(f"cannot read {what} {os.fspath(path)!r}: it is not UTF-8 text (byte {e.start}); "
                    f"{hint}") from None
