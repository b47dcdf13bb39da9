"""Ray, when the ``ray`` extra is installed: joining a session, and results whose mjkin errors keep their type."""

from __future__ import annotations

import importlib
import importlib.util
from typing import Any

from ..errors import MjkinError


def module() -> Any:
    """The ``ray`` module, or None without the extra: imported when first asked for, never by ``import mjkin``
    (it takes a second and 100 MB). Typed Any: mypy sees the same with Ray installed or not.
    """  # noqa: D205
    return importlib.import_module("ray") if importlib.util.find_spec("ray") else None


def connect(address: str | None) -> None:
    """Attach to the running Ray session, else to ``address``, else start a local cluster."""
    ray = module()
    if ray is None:
        raise MjkinError('mjkin.distributed needs Ray: pip install "mjkin[ray]"')
    if not ray.is_initialized():
        ray.init(address=address, include_dashboard=False, log_to_driver=False)


def unwrap(ref: Any) -> Any:
    """``ray.get(ref)``, re-raising an mjkin error from the worker with its own type."""
    ray = module()
    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as e:
        cause = getattr(e, "cause", None)
        if isinstance(cause, MjkinError):
            raise cause from None
        raise
