"""``mjkin play``: the playground in a browser — drag a target, watch each IK method work.

:mod:`mjkin.apps.play.core` is the pure part (camera rays, drags, the warm-started
solve), :mod:`mjkin.apps.play.session` the live state and its render thread,
:mod:`mjkin.apps.play.journal` a recording's journal on disk (what survives a crash),
:mod:`mjkin.apps.play.server` the HTTP server and its JSON API, :mod:`mjkin.apps.bench.play`
the frame-rate and latency measurement (``mjkin bench play``).
"""

from __future__ import annotations

from typing import Any

__all__ = ["serve"]

# the web server's packages are the play extra; the rest of the playground (and mjkin) imports without them
NEEDS_PLAY_EXTRA = "mjkin play needs the play extra (no module {missing!r}): pip install 'mjkin[play]'"


def __getattr__(name: str) -> Any:
    """``serve``, imported when first asked for: reading a journal (``mjkin replay``) needs no web server."""
    if name == "serve":
        from .server import serve

        return serve
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
