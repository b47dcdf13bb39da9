"""Atomic file writes (a temporary file in the same folder, then a rename), and checking a path before the work."""

from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import tempfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from .errors import InputError, MjkinIOError


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
        fd, probe = tempfile.mkstemp(prefix=f".{target.name}.", dir=folder)
    except OSError as e:  # /proc answers "no such file": say only that it is not writable
        reason = "" if e.errno == errno.ENOENT else f" ({e.strerror or e})"
        raise MjkinIOError(f"cannot write {str(target)!r}: folder {str(folder)!r} is not writable{reason}") from None
    os.close(fd)
    os.unlink(probe)
    return target


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it over ``path``, else delete it.

    The temporary name keeps the suffix, so writers that choose a format by
    extension (imageio) still work. Raises :class:`MjkinIOError` when the folder
    cannot be written.
    """
    target = Path(path)
    folder = target.parent if str(target.parent) else Path(".")
    if not folder.is_dir():
        raise MjkinIOError(f"cannot write {str(target)!r}: folder {str(folder)!r} does not exist")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=target.suffix, dir=folder)
    except OSError as e:
        raise MjkinIOError(f"cannot write {str(target)!r}: {e.strerror}") from None
    os.close(fd)
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
