"""A griffe extension for the docs build (``mkdocs.yml``: ``extensions``); the code is not changed by it.

- ``mjkin.envs`` lives in ``envs/`` (pyproject's package-dir mapping). Griffe finds a package's submodules in the
  package's own folder, so it cannot see it; ``envs/*.py`` are loaded as members of ``mjkin`` here.
- The docstrings cross-reference in Sphinx's roles (``:class:`~mjkin.Tree```), which Markdown does not know; they
  are shown as code (``Tree``) instead of as the role's raw text.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import griffe

ENVS = Path(__file__).resolve().parent.parent / "envs"
ROLE = re.compile(r":(?:py:)?(?:class|meth|func|mod|attr|data|exc|obj|const):`([^`]+)`")


def _shown(match: re.Match[str]) -> str:
    """A role's text as code: its title if it has one, its last name if it starts with ``~``."""
    text = match.group(1)
    titled = re.fullmatch(r"(.+?)\s*<[^>]+>", text)
    if titled:
        return f"`{titled.group(1)}`"
    return f"`{text[1:].rsplit('.', 1)[-1]}`" if text.startswith("~") else f"`{text}`"


def _plain(obj: griffe.Object, seen: set[int]) -> None:
    """Rewrite the roles in the docstrings of ``obj`` and everything it holds (aliases skipped)."""
    if id(obj) in seen:
        return
    seen.add(id(obj))
    if obj.docstring is not None:
        obj.docstring.value = ROLE.sub(_shown, obj.docstring.value)
    for member in obj.members.values():
        if not member.is_alias:
            _plain(member, seen)  # type: ignore[arg-type]


class MappedEnvs(griffe.Extension):
    """Load ``envs/`` as ``mjkin.envs``, and show Sphinx roles as code."""

    def on_package(self, *, pkg: griffe.Module, loader: griffe.GriffeLoader, **kwargs: Any) -> None:
        """When ``mjkin`` is loaded, load ``envs/__init__.py`` and its modules as ``mjkin.envs``; plain roles."""
        if pkg.name != "mjkin":
            return
        if "envs" not in pkg.members:
            loader._load_submodule(pkg, ("envs",), ENVS / "__init__.py")  # noqa: SLF001 (no public way to add one)
            for path in sorted(ENVS.glob("*.py")):
                if path.stem != "__init__":
                    loader._load_submodule(pkg, ("envs", path.stem), path)  # noqa: SLF001
        _plain(pkg, set())
