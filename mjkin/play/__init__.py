"""``mjkin play``: the playground in a browser — drag a target, watch each IK method work.

:mod:`mjkin.play.core` is the pure part (camera rays, drags, the warm-started
solve), :mod:`mjkin.play.session` the live state and its render thread,
:mod:`mjkin.play.server` the HTTP server and its JSON API, :mod:`mjkin.play.bench`
the frame-rate and latency measurement (``mjkin bench play``).
"""

from .server import serve

__all__ = ["serve"]
