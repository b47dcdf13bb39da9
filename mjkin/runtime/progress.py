"""Progress bars for long CLI work (on a terminal only), and a note on stderr while numba compiles.

The first run compiles mjkin's kernels (minutes on a small machine; later
runs load them from the disk cache). numba announces every real compilation
(a cache miss, never a cache hit) as a ``"numba:compile"`` event; while enabled
(the CLI), the first such event prints :data:`COMPILING` once on stderr, on a
terminal or not, so a run that sits still for minutes (in CI, or piped into
``tee``) is explained. Bars show no rate or ETA until their first item is done,
since that item may include the compilation and would make the estimate for
the rest hours long; then the clock starts afresh.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator, Sized
from typing import TypeVar

from numba.core import event

T = TypeVar("T")

COMPILING = "compiling kernels for their first use (cached for later runs; a minute or two)..."

_enabled = False
_said: set[str] = set()  # the notices printed in this process


def shown() -> bool:
    """Progress is enabled (the CLI) and stderr is a terminal."""
    return _enabled and sys.stderr.isatty()


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


class _CompileListener(event.Listener):
    def on_start(self, event: event.Event) -> None:
        fn = getattr(event.data.get("dispatcher"), "py_func", None)
        if not (getattr(fn, "__module__", "") or "").startswith("numba"):  # not numba's own helpers (0.1 s, warm too)
            compiling_notice()

    def on_end(self, event: event.Event) -> None:
        pass


_listener = _CompileListener()


def enable(on: bool = True) -> None:
    """Let the compile notice print, and :func:`track` draw bars when stderr is a terminal (the CLI turns this on)."""
    global _enabled
    if bool(on) != _enabled:
        (event.register if on else event.unregister)("numba:compile", _listener)
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
