"""The IK loop of a problem that holds a goal kind the user registered: a copy of :mod:`mjkin.ik.loop` with its branch.

numba resolves the functions a kernel calls when it compiles it, so a kind registered
after the built-in ones (:func:`mjkin.goals.register`) gets a branch in a copy of the
loop's source: written to a folder no other user can write
(:func:`mjkin.runtime.cache.generated_file`), named by a digest of its text, and
imported from there. The copy has a branch for every kind registered so far, so one
copy serves every problem until another kind is registered; it is cached on disk like
every kernel (:mod:`mjkin.runtime.cache`), and its text names each registered kind's
residual (its module, or a digest of its source). Problems of built-in kinds alone run
:mod:`mjkin.ik.loop` itself.
"""

from __future__ import annotations

import hashlib
import inspect
import sys
from pathlib import Path
from types import ModuleType

from ..goals import registry
from ..runtime.cache import PACKAGE, generated_file
from . import loop

PREFIX = "mjkin_loop_"  # the generated modules' names
MARKER = "        # REGISTERED KINDS: mjkin.ik.generated adds a branch here for each kind registered after these\n"
_BRANCH = ("        elif code == {code}:\n"
           "            _k{code}(kin, ga, ws, rot, pos, irot, ipos, i, b, q, g, J, r0, err)\n")
_LOADED: dict[tuple[int, ...], ModuleType] = {}


def built_in(codes: tuple[int, ...]) -> bool:
    """Whether every goal kind of ``codes`` (registry codes, ascending) is built in: its problems run :mod:`.loop`."""
    return not codes or codes[-1] < loop.BUILT_IN


def loop_for(codes: tuple[int, ...]) -> ModuleType:
    """The loop module for a problem with the goal kinds ``codes`` (registry codes, ascending).

    :mod:`mjkin.ik.loop` when every kind is built in; else the copy with a branch for each registered one.
    """
    if built_in(codes):
        return loop
    registered = tuple(range(loop.BUILT_IN, len(registry.KINDS)))
    module = _LOADED.get(registered)
    if module is None:
        text = source(registered)
        name = f"{PREFIX}{hashlib.sha256(text.encode()).hexdigest()[:16]}.py"
        module = _LOADED[registered] = _import(generated_file("generated", name, text), text)
    return module


def _binding(code: int) -> str:
    """The line that names kind ``code``'s residual ``_k<code>`` in the generated module.

    Imported from its own module where that works, so the module's imports (and so its cache
    stamp) name the residual's file; otherwise (a kind defined in ``__main__``) through the
    registry, with a digest of the residual's source in the text.
    """
    residual, cls = registry.RESIDUALS[code], registry.KINDS[code]
    fn = residual.py_func  # type: ignore[attr-defined]
    module = sys.modules.get(fn.__module__)
    if fn.__module__ != "__main__" and getattr(module, fn.__name__, None) is residual:
        return f"from {fn.__module__} import {fn.__name__} as _k{code}  # {cls.__qualname__}\n"
    digest = hashlib.sha256(inspect.getsource(fn).encode()).hexdigest()[:16]
    return f"_k{code} = residual_of({code})  # {cls.__module__}.{cls.__qualname__}, source {digest}\n"


def source(codes: tuple[int, ...]) -> str:
    """The source of :mod:`mjkin.ik.loop` with a branch in ``evaluate_goals`` for each kind of ``codes``."""
    text = (PACKAGE / "ik" / "loop.py").read_text()
    branches = "".join(_BRANCH.format(code=c) for c in codes)
    imports = "from mjkin.goals.registry import residual_of\n" + "".join(_binding(c) for c in codes)
    head, rest = text.split("\n\n\n", 1)  # the docstring and imports, then the code
    return head + "\n" + imports + "\n\n" + rest.replace(MARKER, branches)


def _import(path: Path, text: str) -> ModuleType:
    """The module of ``text``, written at ``path``: compiled from the text itself, never from a ``.pyc`` beside it."""
    module = ModuleType(path.stem)
    module.__file__ = str(path)
    sys.modules[path.stem] = module
    exec(compile(text, str(path), "exec"), module.__dict__)
    return module
