"""MkDocs hooks for the docs build (``mkdocs.yml``: ``hooks``): the pictures that live outside ``docs/``.

The pictures live beside what made them (``models/*.png`` beside the MJCF, as in MuJoCo Menagerie, and
``examples/*.png``), and the pages link them by their path in the repository (``../../models/play.png`` from
``docs/guides/``), which GitHub shows as they are. The site gets a copy of each at ``models/`` and ``examples/``
under its root, and the links are rewritten to point there.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parent.parent
FOLDERS = ("models", "examples")


def on_files(files: Files, config: Any) -> Files:
    """Add ``models/*.png`` and ``examples/*.png`` to the site."""
    for folder in FOLDERS:
        for png in sorted((ROOT / folder).glob("*.png")):
            files.append(File(f"{folder}/{png.name}", str(ROOT), config["site_dir"], config["use_directory_urls"]))
    return files


def on_page_markdown(markdown: str, page: Any, config: Any, files: Files) -> str:
    """Point a page's links to ``../…/models/x.png`` (the repository's path) at the site's copy."""
    depth = page.file.src_uri.count("/")
    outside, inside = "../" * (depth + 1), "../" * depth
    pattern = r"\]\(" + re.escape(outside) + "(" + "|".join(FOLDERS) + ")/"
    return re.sub(pattern, lambda m: f"]({inside}{m.group(1)}/", markdown)
