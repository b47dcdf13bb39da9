"""A recording's journal: its samples appended to a JSON Lines file while it runs, so a crash loses at most a second.

While ``mjkin play`` records, every sample (seconds since the start, ``q``, the
target points) goes to ``BASE.journal.jsonl`` in the recordings folder: a header
line (format, model name and source, fingerprint, effector frames, method, goal),
then one line per sample. A writer thread of its own appends them, flushes the file
and has it put on disk every :data:`FLUSH_SECONDS`, so the render thread never waits for
the disk and a crash (``kill -9``, a power cut) loses at most the samples of the last second.
Stop & save writes the script and the video under the same BASE and removes the journal.

A journal no running process holds (each writer keeps an exclusive ``flock`` on
its file until it ends) is a take cut short: :func:`leftovers` finds them, :func:`recover`
writes the trajectory script it holds (``BASE.json``) and removes it, and
:meth:`mjkin.motion.Trajectory.load` reads one directly (``mjkin replay BASE.journal.jsonl``).
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import threading
from datetime import datetime, timezone
from pathlib import Path
from typing import IO, Any

import numpy as np

from ... import motion
from ...errors import MjkinIOError
from ...motion.journal import FORMAT, SUFFIX, Sample, read

try:
    import fcntl
except ImportError:  # Windows: no flock; every journal found at the start counts as left over
    fcntl = None  # type: ignore[assignment]

FLUSH_SECONDS = 0.5  # the writer's period: samples reach the disk at least this often


def base_name(folder: Path, model: str) -> Path:
    """``folder/mjkin-play-MODEL-STAMP`` (UTC, to the second; ``-2``, ``-3``... after it when taken)."""
    stamp = datetime.now(timezone.utc).strftime("%Y%m%d-%H%M%S")
    for k in range(1, 1000):
        base = folder / f"mjkin-play-{model}-{stamp}{'' if k == 1 else f'-{k}'}"
        if not any(base.with_name(base.name + s).exists() for s in (".json", ".mp4", SUFFIX)):
            return base
    raise MjkinIOError(f"no free recording name for {model!r} in {str(folder)!r} this second; try again")


def path_of(base: Path) -> Path:
    """The journal of the recording ``base``."""
    return base.with_name(base.name + SUFFIX)


def script_of(journal: Path) -> Path:
    """Where the script of ``journal``'s recording goes: ``BASE.json`` beside it."""
    return journal.with_name(journal.name.removesuffix(SUFFIX) + ".json")


class Journal:
    """The journal of one recording being taken (see the module docstring); :meth:`add` from any thread."""

    def __init__(self, base: Path, header: dict[str, Any]) -> None:
        self.base, self.path = base, path_of(base)
        try:
            self._file: IO[str] = open(self.path, "x", encoding="utf-8")  # held until close()
            if fcntl is not None:
                with contextlib.suppress(OSError):  # a folder without flock (some network mounts): no lock to hold
                    fcntl.flock(self._file, fcntl.LOCK_EX | fcntl.LOCK_NB)
            self._file.write(json.dumps({"format": FORMAT, "version": 1, **header}) + "\n")
            self._file.flush()
        except OSError as e:
            raise MjkinIOError(f"cannot start the recording's journal {str(self.path)!r}: {e.strerror or e}; "
                               "recordings need a folder that exists and can be written (--out)") from None
        self._queue: queue.SimpleQueue[str] = queue.SimpleQueue()
        self._closing = threading.Event()
        self.error: OSError | None = None  # why the journal stopped being written, if it did
        self._thread = threading.Thread(target=self._write_loop, name="mjkin-play-journal")
        self._thread.start()

    def add(self, sample: Sample) -> None:
        """Queue one sample ``(t, q, points)``; the writer thread appends it."""
        t, q, points = sample
        self._queue.put(json.dumps({"t": float(t), "q": np.asarray(q, float).tolist(),
                                    "targets": np.asarray(points, float).reshape(-1, 3).tolist()}))

    def close(self) -> None:
        """Write what is queued, flush, close the file (kept on disk; idempotent)."""
        self._closing.set()
        self._thread.join()

    def remove(self) -> None:
        """Close and delete the journal: its recording is written."""
        self.close()
        self.path.unlink(missing_ok=True)

    def _write_loop(self) -> None:
        with self._file:
            closing = False
            while not closing:
                closing = self._closing.wait(FLUSH_SECONDS)
                lines: list[str] = []
                with contextlib.suppress(queue.Empty):
                    while True:
                        lines.append(self._queue.get_nowait())
                if not lines or self.error is not None:
                    continue
                try:
                    self._file.write("".join(f"{x}\n" for x in lines))
                    self._file.flush()
                    os.fsync(self._file.fileno())
                except OSError as e:  # disk full, say: the take stays in memory, Stop & save still writes it
                    self.error = e


def live(path: Path) -> bool:
    """A running process writes the journal ``path`` (it holds the file's lock)."""
    if fcntl is None:
        return False
    try:
        with open(path, "rb") as f:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:
        return False
    return False


def leftovers(folder: str | os.PathLike[str]) -> list[Path]:
    """Journals in ``folder`` that no running process writes: recordings cut short, oldest first."""
    return sorted(p for p in Path(folder).glob(f"mjkin-play-*{SUFFIX}") if p.is_file() and not live(p))


def recover(path: Path) -> Path | None:
    """Write the script of the take in journal ``path`` (``BASE.json``) and remove the journal.

    Returns the script's path, or None when the journal held no sample (it is removed too).

    Raises:
        MjkinError: the journal cannot be read or the script not written (the journal is kept).
    """
    if not read(path)[1]:
        path.unlink()
        return None
    saved = script_of(path)
    if not saved.exists():  # else the take was saved and only the journal's removal was cut short
        motion.Trajectory.load(path).save(saved)
    path.unlink()
    return saved
