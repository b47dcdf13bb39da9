"""How many threads the compiled solvers use, and splitting a batch across them.

The count is, in order: :func:`set_threads`, ``MJKIN_NUM_THREADS``,
``OMP_NUM_THREADS`` (what schedulers such as Ray or Slurm set for a worker; its
first level when it lists several, ignored when it is not a count), else the
cores this process may run on. A batch of targets is cut into chunks
that threads take as they go; the compiled code releases the GIL.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import numpy as np

from .errors import InputError

_threads: int | None = None


def set_threads(n: int | None) -> None:
    """Use ``n`` solver threads per process from now on (``None``: back to the environment's choice).

    Raises:
        InputError: ``n`` is not a positive integer.
    """
    global _threads
    if n is not None and (isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1):
        raise InputError(f"threads must be a positive integer (or None for the default), got {n!r}")
    _threads = None if n is None else int(n)


@contextmanager
def threads_set(n: int) -> Iterator[None]:
    """Run a block with ``n`` solver threads, then put the previous *setting* back.

    An environment variable or the default applies again afterwards, not the number they gave before.
    """
    global _threads
    before = _threads
    set_threads(n)
    try:
        yield
    finally:
        _threads = before


def threads() -> int:
    """The number of solver threads this process uses (see the module docstring)."""
    if _threads is not None:
        return _threads
    text = os.environ.get("MJKIN_NUM_THREADS", "").strip()
    if text:  # mjkin's own setting: a mistake in it is an error
        if not (text.isdigit() and int(text) >= 1):
            raise InputError(f"MJKIN_NUM_THREADS must be a positive integer, got {text!r}")
        return int(text)
    first = os.environ.get("OMP_NUM_THREADS", "").split(",")[0].strip()  # OpenMP's: "4,2" nests levels
    if first.isdigit() and int(first) >= 1:  # another library's variable: used when it says a count, else ignored
        return int(first)
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def parallel_chunks(run: Callable[[int, int], None], n: int, min_chunk: int = 32, per_worker: int = 8) -> None:
    """Call ``run(lo, hi)`` over ``range(n)`` split across :func:`threads` threads.

    Each thread takes the next chunk when it is done with one: hard targets (restarts)
    come in clusters, and equal halves would leave one core idle while the other works.
    """
    workers = 1 if n < 2 * min_chunk else min(threads(), n // min_chunk)
    if workers <= 1:
        run(0, n)
        return
    chunks = min(workers * per_worker, max(workers, n // min_chunk))
    edges = np.linspace(0, n, chunks + 1).astype(int)
    with ThreadPoolExecutor(workers) as pool:
        for f in [pool.submit(run, int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]:
            f.result()
