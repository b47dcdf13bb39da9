"""The IK loop compiled with a problem's goal kinds.

numba resolves the functions a kernel calls when it compiles it, so the loop
(:mod:`mjkin.ik.loop`) is written out once per set of goal kinds, with a dispatch
branch per kind, to a module in a folder no other user can write
(:func:`mjkin.runtime.cache.generated_file`), named by a digest of its text, and imported
from there. A problem compiles the loop of the kinds it holds and the common ones
(:func:`loop_kinds`): a Pose problem compiles no Clearance or CenterOfMass code,
and shares its loop with every problem of frame, line, plane and joint goals (the
ten common kinds cost ~15 % more compile time than Pose alone). The costlier kinds
(Clearance, the centre of mass's two) come as one group: a problem holding any of
them compiles the loop of all three (92 s on 2 cores against 76-80 s for one alone,
and each other mix of them is then compiled already; the common loop takes 60 s).
Each loop is cached
on disk like every kernel, stamped with the files it imports (:mod:`mjkin.runtime.cache`),
those of its kinds' residuals among them.
"""

from __future__ import annotations

import hashlib
import inspect
import sys
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

from ..goals import registry
from ..runtime.cache import PACKAGE, generated_file

PREFIX = "mjkin_loop_"  # the generated modules' names
_LOADED: dict[tuple, ModuleType] = {}
_BRANCH = ("        {kw} ga.kind[i] == {code}:\n"
           "            _k{code}(kin, ga, ws, rot, pos, irot, ipos, i, b, q, g, J, ga.row[i], err)\n")


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
    source = hashlib.sha256(inspect.getsource(fn).encode()).hexdigest()[:16]
    return f"_k{code} = residual_of({code})  # {cls.__module__}.{cls.__qualname__}, source {source}\n"


def source(codes: Sequence[int]) -> str:
    """The loop module's source with a branch for each kind code in ``codes``."""
    template = (PACKAGE / "ik" / "loop.py").read_text()
    marker = "        pass  # DISPATCH: mjkin.ik.compiled puts one branch per registered kind here\n"
    branches = "".join(_BRANCH.format(kw="if" if k == 0 else "elif", code=c) for k, c in enumerate(codes))
    imports = "from mjkin.goals.registry import residual_of\n" + "".join(_binding(c) for c in codes)
    head, rest = template.split("# BEGIN evaluate_goals", 1)
    return head + imports + "\n\n# BEGIN evaluate_goals" + rest.replace(marker, branches)


def loop_kinds(codes: Sequence[int]) -> tuple[int, ...]:
    """The kinds the loop for a problem with the kinds ``codes`` is compiled with: those, every
    :attr:`~mjkin.goals.Goal.common` one (cheap residuals, so most problems share one cached loop),
    and, when any :attr:`~mjkin.goals.Goal.grouped` kind is among them, every grouped one.
    """  # noqa: D205
    kinds = {int(c) for c in codes} | {c for c, k in enumerate(registry.KINDS) if k.common}
    grouped = {c for c, k in enumerate(registry.KINDS) if k.grouped}
    return tuple(sorted(kinds | grouped if kinds & grouped else kinds))


def kernels(codes: Sequence[int]) -> ModuleType:
    """The compiled loop for problems with the goal kinds ``codes`` (registry codes; see :func:`loop_kinds`)."""
    key = loop_kinds(codes)
    if key in _LOADED:
        return _LOADED[key]
    text = source(key)
    name = f"{PREFIX}{hashlib.sha256(text.encode()).hexdigest()[:16]}.py"
    module = _import(generated_file("generated", name, text), text)
    _LOADED[key] = module
    return module


def _import(path: Path, text: str) -> ModuleType:
    """The module of ``text``, written at ``path``: compiled from the text itself, never from a ``.pyc`` beside it."""
    module = ModuleType(path.stem)
    module.__file__ = str(path)
    sys.modules[path.stem] = module
    exec(compile(text, str(path), "exec"), module.__dict__)
    return module
