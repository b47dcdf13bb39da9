"""Reading a motion clip by its file suffix: BVH (:mod:`~mjkin.motion.bvh`) or AMASS / SMPL-H / SMPL-X ``.npz``."""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import InputError
from . import bvh, smpl

CLIP_SUFFIXES = (".bvh", ".npz")  # the clip files :func:`read_clip` reads


def read_clip(path: str | os.PathLike[str], body_model: str | os.PathLike[str] | None = None) -> bvh.Clip:
    """The clip at ``path``: a ``.bvh`` file, or an AMASS/SMPL ``.npz`` read with the ``body_model`` file.

    Raises:
        InputError: a suffix other than :data:`CLIP_SUFFIXES`, or a body model given for a BVH.
        MjkinIOError: the file cannot be read (see :func:`mjkin.motion.bvh.read`, :func:`mjkin.motion.smpl.read`).
    """
    suffix = Path(path).suffix.lower()
    if suffix == ".bvh":
        if body_model is not None:
            raise InputError(f"a body model is for .npz (AMASS/SMPL) clips, not the BVH {str(path)!r}; leave it out")
        return bvh.read(path)
    if suffix == ".npz":
        return smpl.read(path, body_model)
    raise InputError(f"clip {str(path)!r} must be a {' or '.join(CLIP_SUFFIXES)} file, got {suffix or 'no suffix'!r}")
