"""Progress bars for long CLI work (on a terminal only), and a note on stderr while numba compiles.

The first run compiles mjkin's kernels (minutes on a small machine; later
runs load them from the disk cache). numba announces every real compilation
(a cache miss, never a cache hit) as a ``"numba:compile"`` event; the first such
event prints :data:`COMPILING` on stderr, on a terminal or not, so a run
that sits still for minutes (in CI, or piped into ``tee``) is explained: from the
CLI as ``mjkin: ...``, from Python through the ``mjkin`` logger (a warning, which
Python prints on stderr unless logging is set up otherwise). A compile that starts
:data:`QUIET` seconds or more after that line says so again (a script's second
long step compiles kernels of its own). On a terminal, from the CLI or from Python,
a compile that lasts over 5 s shows its seconds as it goes. Bars show no rate or
ETA until their first item is done, since that item may include the compilation
and would make the estimate for the rest hours long; then the clock starts afresh.
"""

from __future__ import annotations

import logging
import math
import sys
import threading
import time
from collections.abc import Iterable, Iterator, Sized
from typing import Any, TypeVar

T = TypeVar("T")

COMPILING = "compiling kernels this run needs now (cached for later runs; a minute or two)..."
TICK = 5.0  # seconds of compiling after which a terminal shows the time it has taken
QUIET = 60.0  # seconds after the compile notice past which a compile that starts says so again

_enabled = False
_said: set[str] = set()  # the notices printed in this process


def shown() -> bool:
    """Progress is enabled (the CLI) and stderr is a terminal."""
    return _enabled and sys.stderr.isatty()


def _ticking() -> bool:
    """A long compile shows its seconds: stderr is a terminal, and the CLI or the ``mjkin`` logger speaks there."""
    return sys.stderr.isatty() and (_enabled or logging.getLogger("mjkin").isEnabledFor(logging.WARNING))


def notice(text: str) -> bool:
    """Print ``mjkin: text`` on stderr once per process while enabled, terminal or not; True if it printed now."""
    if text in _said or not _enabled:
        return False
    _said.add(text)
    if shown():
        from tqdm import tqdm

        tqdm.write(f"mjkin: {text}", file=sys.stderr)  # above any bar being drawn
    else:
        print(f"mjkin: {text}", file=sys.stderr, flush=True)
    return True


def compiling_notice() -> bool:
    """:func:`notice` of :data:`COMPILING`."""
    return notice(COMPILING)


def warn(text: str) -> None:
    """:func:`notice` of ``text``, or a warning of the ``mjkin`` logger where notices are off (used from Python).

    Once per process either way.
    """
    if _enabled:
        notice(text)
    elif text not in _said:
        _said.add(text)
        logging.getLogger("mjkin").warning("mjkin: %s", text)


class _CompileListener:
    """Says that numba compiles (once), and on a terminal how long the outermost compile of ``fn`` has taken."""

    def __init__(self) -> None:
        self.depth = 0
        self.stop: threading.Event | None = None
        self.said = -math.inf  # time.monotonic() of the last notice

    def on_start(self, fn: Any) -> None:
        if (getattr(fn, "__module__", "") or "").startswith("numba"):  # not numba's own helpers (0.1 s, warm too)
            return
        self.depth += 1
        if self.depth > 1:
            return
        if COMPILING not in _said or time.monotonic() - self.said >= QUIET:
            self.said = time.monotonic()
            _said.discard(COMPILING)
            warn(COMPILING)
        if _ticking():
            self.stop = threading.Event()
            threading.Thread(target=_ticker, args=(self.stop, getattr(fn, "__name__", "")), daemon=True).start()

    def on_end(self, fn: Any) -> None:
        if (getattr(fn, "__module__", "") or "").startswith("numba") or not self.depth:
            return
        self.depth -= 1
        if not self.depth and self.stop is not None:
            self.stop.set()
            self.stop = None


def _ticker(stop: threading.Event, name: str) -> None:
    """Past :data:`TICK` seconds, a line on the terminal that counts the seconds until ``stop`` is set."""
    if stop.wait(TICK):
        return
    from tqdm import tqdm

    start = time.monotonic() - TICK
    with tqdm(total=None, desc=f"{name}: {TICK:.0f} s", bar_format="mjkin: compiling {desc}", leave=False,
              file=sys.stderr) as line:
        while not stop.wait(1.0 - (time.monotonic() - start) % 1.0):
            line.set_description_str(f"{name}: {time.monotonic() - start:.0f} s")


_listener = _CompileListener()
compile_started, compile_ended = _listener.on_start, _listener.on_end  # numba_private calls them around compiles


def enable(on: bool = True) -> None:
    """Let notices print, and :func:`track` draw bars when stderr is a terminal (the CLI turns this on)."""
    global _enabled
    _enabled = bool(on)


_END = object()


def track(items: Iterable[T], desc: str, total: int | None = None) -> Iterator[T]:
    """Iterate over ``items``, with a tqdm bar on stderr when :func:`shown`.

    The bar says ``[starting]`` until the caller has finished the first item;
    rate and ETA are measured from then on.
    """
    if not shown():
        yield from items
        return
    from tqdm import tqdm

    if total is None and isinstance(items, Sized):
        total = len(items)
    it = iter(items)
    with tqdm(total=total, desc=desc, leave=False, dynamic_ncols=True,
              bar_format="{desc}: {n_fmt}/{total_fmt} [starting]"):
        first = next(it, _END)
        if first is _END:
            return
        yield first  # type: ignore[misc]
    yield from tqdm(it, desc=desc, total=total, initial=1, leave=False, dynamic_ncols=True)
