"""The files an MJCF file names (includes, meshes, textures, height fields, skins), checked before MuJoCo reads them.

MuJoCo reads a model's includes and assets itself, and a FIFO among them would make it wait for ever (a device,
read to its end). :func:`check_named_files` finds every ``file`` attribute of the model and of its includes and
refuses, in one line, one that exists but is no regular file, reading none of them; a missing file is left to
MuJoCo's own message. Paths are looked up where MuJoCo looks: beside the main file, and under the ``<compiler>``'s
``meshdir``, ``texturedir`` and ``assetdir``.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

from ..errors import MjkinIOError
from ..runtime import files

MAX_INCLUDES = 1000  # include files followed at most (a loop of includes is MuJoCo's to report)


def check_named_files(path: str | os.PathLike[str], what: str = "model file") -> None:
    """Refuse ``path``'s named files that are FIFOs, devices, sockets or folders (see the module).

    A file that is not MJCF (URDF, or XML that does not parse) is left to MuJoCo.

    Raises:
        MjkinIOError: a named file is no regular file (the message names both files and what the named one is).
    """
    main = Path(path)
    home = main.parent
    todo: list[Path] = [main]
    seen: set[Path] = set()
    while todo and len(seen) < MAX_INCLUDES:
        current = todo.pop()
        if current in seen:
            continue
        seen.add(current)
        try:
            root = ET.fromstring(files.read_input(current, what, files.LIMITS["model"]))
        except (ET.ParseError, MjkinIOError, ValueError):
            continue  # MuJoCo says what is wrong with it
        if current == main and root.tag != "mujoco":
            return
        compiler = {k: v for c in root.iter("compiler") for k, v in c.attrib.items()}
        dirs = [home] + [home / compiler[k] for k in ("meshdir", "texturedir", "assetdir") if k in compiler]
        for element in root.iter():
            name = element.get("file")
            if not name:
                continue
            for place in ([home] if element.tag == "include" else dirs):
                found = place / name
                kind = files.kind_of(found)
                if kind is not None:
                    raise MjkinIOError(f"{what} {str(main)!r} names {name!r} ({element.tag}), which is {kind}, not "
                                       "a regular file; give the file itself")
                if element.tag == "include" and found.is_file():
                    todo.append(found)
