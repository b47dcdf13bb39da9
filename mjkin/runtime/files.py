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
import json
import math
import os
import re
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
