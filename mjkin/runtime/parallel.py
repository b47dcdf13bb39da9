"""How many threads the compiled solvers use, and splitting a batch across them.

The count is, in order: :func:`set_threads`, ``MJKIN_NUM_THREADS``,
``OMP_NUM_THREADS`` (what schedulers such as Ray or Slurm set for a worker; its
first level when it lists several, ignored when it is not a count), else the
cores this process may run on. A batch of targets is cut into chunks, large
first and small last, that threads take as they go; the compiled code releases the GIL.
The threads are kept between calls (starting and joining two cost ~0.5 ms a call).
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor, wait
from contextlib import contextmanager

import numpy as np

from ..errors import InputError

_threads: int | None = None
_pool: tuple[int, ThreadPoolExecutor] | None = None  # the kept threads (_executor) and their count
_pool_lock = threading.Lock()
_worker = threading.local()  # .busy: this thread is one of the pool's


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


def chunk_edges(n: int, workers: int, min_chunk: int = 32) -> list[int]:
    """Edges ``[0, ..., n]`` of chunks that shrink as the batch runs out ("guided" scheduling, as OpenMP's).

    Each chunk is ``1 / (2 workers)`` of what is left, at least ``min_chunk`` (a smaller rest joins the
    last chunk): large chunks while there is plenty of work, small ones at the end, so that no thread
    finishes one long chunk while the others wait idle.
    """
    edges = [0]
    while edges[-1] < n:
        left = n - edges[-1]
        size = max(min_chunk, -(-left // (2 * workers)))
        edges.append(n if left - size < min_chunk else edges[-1] + size)
    return edges


def parallel_chunks(run: Callable[[int, int], None], n: int, min_chunk: int = 32) -> None:
    """Call ``run(lo, hi)`` over ``range(n)`` split across :func:`threads` threads.

    Each thread takes the next chunk (:func:`chunk_edges`) when it is done with one: targets
    differ in cost (restarts), and equal halves would leave one core idle while the other works.
    """
    count = threads()
    workers = 1 if n < 2 * min_chunk else min(count, n // min_chunk)
    if workers <= 1 or getattr(_worker, "busy", False):  # a chunk that splits again runs in its own thread
        run(0, n)
        return
    edges = chunk_edges(n, workers, min_chunk)
    pool = _executor(count)
    futures = [pool.submit(run, a, b) for a, b in zip(edges[:-1], edges[1:], strict=True)]
    wait(futures)  # every chunk done (none still writing the caller's arrays) before an error is raised
    for f in futures:
        f.result()


def _executor(count: int) -> ThreadPoolExecutor:
    """The kept pool of ``count`` threads; a new one when the count changed.

    The old pool's threads end once no call holds it any more.
    """
    global _pool
    with _pool_lock:
        if _pool is None or _pool[0] != count:
            _pool = count, ThreadPoolExecutor(count, thread_name_prefix="mjkin-solver", initializer=_mark_worker)
        return _pool[1]


def _mark_worker() -> None:
    _worker.busy = True


def _forget_pool() -> None:
    """In a forked child: the parent's threads do not exist there, nor may its lock be held."""
    global _pool, _pool_lock
    _pool, _pool_lock = None, threading.Lock()


os.register_at_fork(after_in_child=_forget_pool)
