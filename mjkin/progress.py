"""Progress bars for long CLI work: shown on a terminal, silent in tests and pipes."""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")

_enabled = False


def enable(on: bool = True) -> None:
    """Let :func:`track` draw bars (the CLI turns this on when stderr is a terminal)."""
    global _enabled
    _enabled = bool(on)


def track(items: Iterable[T], desc: str, total: int | None = None) -> Iterator[T]:
    """Iterate over ``items``, with a tqdm bar on stderr when enabled and stderr is a TTY."""
    if _enabled and sys.stderr.isatty():
        from tqdm import tqdm

        yield from tqdm(items, desc=desc, total=total, leave=False, dynamic_ncols=True)
    else:
        yield from items
