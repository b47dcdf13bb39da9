"""The IK loop compiled with the registered goal kinds.

numba resolves the functions a kernel calls when it compiles it, so the loop
(:mod:`mjkin.ik.loop`) is written out once per set of kinds, with a dispatch
branch per kind, to a module in the kernel cache (named by a digest of the kinds'
sources, so numba's disk cache stays valid), and imported from there.
"""

from __future__ import annotations

import hashlib
import importlib.util
import inspect
import os
import sys
import tempfile
from pathlib import Path
from types import ModuleType

from ..goals import registry
from ..jit import PACKAGE, cache_dir

PREFIX = "mjkin_loop_"  # the generated modules' names
_LOADED: dict[tuple, ModuleType] = {}
_BRANCH = ("        {kw} ga.kind[i] == {code}:\n"
           "            _k{code}(kin, ga, ws, rot, pos, irot, ipos, i, b, q, g, J, ga.row[i], err)\n")


def source() -> str:
    """The loop module's source for the kinds registered now."""
    template = (PACKAGE / "ik" / "loop.py").read_text()
    marker = "        pass  # DISPATCH: mjkin.ik.compiled puts one branch per registered kind here\n"
    branches = "".join(_BRANCH.format(kw="if" if c == 0 else "elif", code=c) for c in range(len(registry.KINDS)))
    imports = "from mjkin.goals.registry import residual_of\n\n" + "".join(
        f"_k{c} = residual_of({c})  # {cls.__module__}.{cls.__qualname__}\n" for c, cls in enumerate(registry.KINDS))
    head, rest = template.split("# BEGIN evaluate_goals", 1)
    return head + imports + "\n\n# BEGIN evaluate_goals" + rest.replace(marker, branches)


def kernels() -> ModuleType:
    """The compiled loop for the kinds registered now (written and imported once per set of kinds)."""
    key = tuple(registry.KINDS)
    if key in _LOADED:
        return _LOADED[key]
    text = source()
    sources = [inspect.getsource(r.py_func) for r in registry.RESIDUALS]  # type: ignore[attr-defined]
    digest = hashlib.sha256("".join([text, *sources]).encode()).hexdigest()[:16]
    for folder in (cache_dir() / "__pycache__" / "generated", Path(tempfile.gettempdir()) / f"mjkin-{os.getuid()}"):
        path = folder / f"{PREFIX}{digest}.py"
        try:
            if not path.is_file() or path.read_text() != text:
                folder.mkdir(parents=True, exist_ok=True)
                tmp = folder / f".{path.name}.{os.getpid()}.tmp"
                tmp.write_text(text)
                tmp.replace(path)
            break
        except OSError:  # a read-only install without NUMBA_CACHE_DIR: the user's temporary folder
            continue
    module = _import(path)
    _LOADED[key] = module
    return module


def _import(path: Path) -> ModuleType:
    spec = importlib.util.spec_from_file_location(path.stem, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[path.stem] = module
    spec.loader.exec_module(module)
    return module
