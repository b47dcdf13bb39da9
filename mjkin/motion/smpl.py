"""Reading AMASS / SMPL / SMPL-H / SMPL-X motion (``.npz``) as a BVH :class:`~mjkin.motion.bvh.Clip`.

A clip file holds ``poses (F, 3 J)`` (each joint's turn in its parent as a rotation vector, radians, in
the body model's joint order), ``trans (F, 3)`` (metres), ``betas (K,)`` (the body's shape) and
``mocap_framerate`` or ``mocap_frame_rate`` (frames per second). Without ``poses`` (AMASS's SMPL-X "stage-ii"
files and newer SMPL-H ones), the turns are read split into parts (:data:`PARTS`): ``root_orient (F, 3)``,
``pose_body (F, 63)``, then for SMPL-X ``pose_jaw (F, 3)`` and ``pose_eye (F, 6)``, and ``pose_hand (F, 90)``;
a part the file lacks, other than the first two, is at rest. The skeleton comes from the user's own
body-model file (an ``.npz``: the models are licensed by their authors, so mjkin ships none): its
joints at rest are ``J_regressor (J, V) @ (v_template (V, 3) + shapedirs (V, 3, S) @ betas)``, its tree
``kintree_table (2, J)``. SMPL (24 joints), SMPL-H (52: body and hands) and SMPL-X (55: body, jaw,
eyes and hands) are read; face expressions are not.

A clip or body model is read as a hostile file could be: only a regular file (not a FIFO or device), a clip of
at most 256 MB and a body model of at most 1 GB (:data:`mjkin.runtime.files.LIMITS`), only the arrays named
above decompressed, each only after its header declared numbers of at most :data:`MAX_ARRAY_BYTES` (256 MB:
about 215,000 frames of SMPL-H ``poses``), so a zip bomb or a header declaring 1e12 values is one line.

The clip's joints are named as Mixamo's and LAFAN1's (:data:`SKELETONS`), so the retargeting roles
find them by name (SMPL's own ``left_foot`` is the toe, its ``left_shoulder`` the upper arm). Each joint
has the channels ``Zrotation Yrotation Xrotation`` (degrees: :func:`euler_channels`), the root also
``Xposition Yposition Zposition``; offsets are the shaped rest joints' (metres, the model's y-up
frame, facing +z, as BVH's). AMASS's world is z-up: the clip's world is it turned y-up
(:data:`Y_UP`), which :func:`mjkin.retarget` turns back.
"""

from __future__ import annotations

import contextlib
import math
import os
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .. import spatial
from ..errors import InputError, MjkinIOError
from ..runtime import files
from . import bvh

Array = NDArray[np.float64]
SEQ = "ZYX"  # the clip's Euler sequence: intrinsic, R = Rz @ Ry @ Rx
ROTATION = ("zrotation", "yrotation", "xrotation")
POSITION = ("xposition", "yposition", "zposition")
Y_UP = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])  # AMASS (x, y, z up) -> BVH (z, x, y up)
FRAME_RATES = ("mocap_framerate", "mocap_frame_rate")  # AMASS's SMPL-H files use the first, its SMPL-X files the second
# the split form's parts, with their joints, in each model's joint order; SMPL's two hand joints have none (at rest)
PARTS = {"SMPL": (("root_orient", 1), ("pose_body", 21)),
         "SMPL-H": (("root_orient", 1), ("pose_body", 21), ("pose_hand", 30)),
         "SMPL-X": (("root_orient", 1), ("pose_body", 21), ("pose_jaw", 1), ("pose_eye", 2), ("pose_hand", 30))}
REQUIRED_PARTS = ("root_orient", "pose_body")  # the split form's parts a clip must have; the others default to rest
SMPLX_SHAPES = 300  # SMPL-X's shapedirs hold 300 shape then 100 expression directions (10 and 10 in its 2019 files)

_BODY = (("Hips", -1), ("LeftUpLeg", 0), ("RightUpLeg", 0), ("Spine", 0), ("LeftLeg", 1), ("RightLeg", 2),
         ("Spine1", 3), ("LeftFoot", 4), ("RightFoot", 5), ("Spine2", 6), ("LeftToeBase", 7), ("RightToeBase", 8),
         ("Neck", 9), ("LeftShoulder", 9), ("RightShoulder", 9), ("Head", 12), ("LeftArm", 13), ("RightArm", 14),
         ("LeftForeArm", 16), ("RightForeArm", 17), ("LeftHand", 18), ("RightHand", 19))
_FINGERS = ("Index", "Middle", "Pinky", "Ring", "Thumb")  # SMPL-H's and SMPL-X's order, three joints each


def _hand(side: str, wrist: int, first: int) -> tuple[tuple[str, int], ...]:
    """A hand's 15 finger joints (name, parent), the first at index ``first``, knuckles on joint ``wrist``."""
    return tuple((f"{side}Hand{finger}{k}", wrist if k == 1 else first + 3 * n + k - 2)
                 for n, finger in enumerate(_FINGERS) for k in (1, 2, 3))


def _skeleton(*parts: tuple[tuple[str, int], ...]) -> tuple[tuple[str, ...], tuple[int, ...]]:
    joints = sum(parts, ())
    return tuple(n for n, _ in joints), tuple(p for _, p in joints)


# joint count -> (model kind, joint names, parents), in the models' joint order
SKELETONS: dict[int, tuple[str, tuple[str, ...], tuple[int, ...]]] = {
    24: ("SMPL", *_skeleton(_BODY, (("LeftFingers", 20), ("RightFingers", 21)))),
    52: ("SMPL-H", *_skeleton(_BODY, _hand("Left", 20, 22), _hand("Right", 21, 37))),
    55: ("SMPL-X", *_skeleton(_BODY, (("Jaw", 15), ("LeftEye", 15), ("RightEye", 15)), _hand("Left", 20, 25),
                              _hand("Right", 21, 40))),
}


class SmplError(MjkinIOError):
    """An AMASS/SMPL clip or body model cannot be read or is malformed (the message names the file and key)."""


@dataclass(frozen=True)
class BodyModel:
    """What a clip needs of a body model: its skeleton at rest and how the body's shape moves it.

    ``kind`` (SMPL, SMPL-H, SMPL-X), joint ``parents (J,)`` (-1: root), the rest joints ``template (J, 3)``
    and their shape directions ``shapes (J, 3, S)`` (metres, the model's y-up frame), ``source`` its file.
    """

    kind: str
    parents: NDArray[np.int64]
    template: Array
    shapes: Array
    source: str = ""

    def joints(self, betas: Array) -> Array:
        """Rest joint positions ``(J, 3)`` of the body of shape ``betas (K,)``: the first ``S`` used, missing ones 0."""
        n = min(len(betas), self.shapes.shape[2])
        return self.template + self.shapes[:, :, :n] @ betas[:n]


def euler_channels(q: Array) -> Array:
    """``Zrotation Yrotation Xrotation`` channel values ``(..., 3)``, degrees, of unit quaternions ``(..., 4)``.

    Read from the quaternion (:func:`mjkin.spatial.quat_to_euler`): exact to rounding up to gimbal lock.
    """
    return np.rad2deg(spatial.quat_to_euler(q, SEQ))


MAX_ARRAY_BYTES = 256 * files.MB  # the most one array of a clip or body model may hold (SMPL-X's shapedirs: 100 MB)
MAX_MEMBERS = 1000  # arrays an archive may list (AMASS's hold ~10, the body models ~20)


class _Archive:
    """An ``.npz`` archive whose arrays are read one by one, each only after its header passed the checks.

    Nothing is decompressed but the arrays asked for, and an array's declared dtype and shape are checked
    (numbers only, at most :data:`MAX_ARRAY_BYTES`) before any of its data is read: a zip bomb or a header
    declaring 1e12 values is refused with one line, never allocated. There is no check of the compression
    ratio: an array of zeros (a hand at rest) legitimately compresses a thousandfold; what is read is bounded
    by the declared size, which is checked.
    """

    def __init__(self, path: str | os.PathLike[str], what: str, limit: int) -> None:
        self.name = f"{what} {str(path)!r}"
        self._stack = contextlib.ExitStack()
        f = self._stack.enter_context(files.open_input(path, what, limit, SmplError))
        try:
            if f.read(6) == b"\x93NUMPY":
                raise SmplError(f"{self.name} is a single .npy array; expected an .npz archive of named arrays")
            f.seek(0)
            end = zipfile._EndRecData(f)  # type: ignore[attr-defined] # the count, before the directory is read
            if end and end[zipfile._ECD_ENTRIES_TOTAL] > MAX_MEMBERS:  # type: ignore[attr-defined]
                raise SmplError(f"{self.name} lists {end[zipfile._ECD_ENTRIES_TOTAL]} arrays; an .npz clip or "  # type: ignore[attr-defined]
                                f"body model holds a few dozen (at most {MAX_MEMBERS} are read)")
            f.seek(0)
            self.zip = self._stack.enter_context(zipfile.ZipFile(f))
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, zipfile.LargeZipFile) as e:
            self._stack.close()
            raise SmplError(f"cannot read {self.name} as an .npz archive: {e}") from None
        except BaseException:
            self._stack.close()
            raise
        self.files = [n[:-4] for n in self.zip.namelist() if n.endswith(".npy")]

    def __enter__(self) -> _Archive:
        return self

    def __exit__(self, *exc: object) -> None:
        self._stack.close()

    def array(self, key: str, what: str, expect: str) -> NDArray[Any]:
        """The array ``key``; :class:`SmplError` (naming ``what`` and what to ``expect``) when it cannot be."""
        try:
            info = self.zip.getinfo(f"{key}.npy")
            with self.zip.open(info) as m:
                version = np.lib.format.read_magic(m)
                if version not in ((1, 0), (2, 0)):
                    raise ValueError(f"the .npy format version {version} is not read")
                header = (np.lib.format.read_array_header_1_0 if version == (1, 0) else
                    np.lib.format.read_array_header_2_0)
                shape, fortran, dtype = header(m)
                if dtype.hasobject or dtype.kind not in "biuf":
                    kind = "object" if dtype.hasobject else str(dtype)
                    raise SmplError(f"{what}: {key!r} holds {kind} values; expected {expect}")
                size = math.prod(shape) * dtype.itemsize
                if size > MAX_ARRAY_BYTES:
                    raise SmplError(f"{what}: {key!r} declares {tuple(shape)} {dtype.name} values "
                                    f"({size / files.MB:.0f} MB); mjkin reads arrays of at most "
                                    f"{MAX_ARRAY_BYTES // files.MB} MB; expected {expect}")
                if info.file_size > MAX_ARRAY_BYTES + files.MB:  # what unpacking all of it would give (unread)
                    raise SmplError(f"{what}: {key!r} unpacks to {info.file_size / files.MB:.0f} MB; mjkin reads "
                                    f"arrays of at most {MAX_ARRAY_BYTES // files.MB} MB; expected {expect}")
                data = m.read(size)  # no more than declared, whatever the zip says
            if len(data) < size:
                raise ValueError(f"it holds {len(data)} of its {size} bytes")
            return np.frombuffer(data, dtype).reshape(shape, order="F" if fortran else "C")
        except SmplError:
            raise
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as e:
            raise SmplError(f"{what}: cannot read {key!r} ({e}); expected {expect}") from None


def _npz(path: str | os.PathLike[str], what: str) -> _Archive:
    """The ``.npz`` archive at ``path`` (no pickles: loading cannot run code; see :class:`_Archive`)."""
    return _Archive(path, what, files.LIMITS["body model" if what == "body model" else "npz clip"])


def _numbers(data: _Archive, key: str, what: str, expect: str) -> Array:
    """The finite numbers of ``data[key]`` as float64; ``expect`` describes them for the message."""
    if key not in data.files:
        raise SmplError(f"{what} has no {key!r}; expected {expect}")
    a = data.array(key, what, expect).astype(np.float64)
    if not np.isfinite(a).all():
        raise SmplError(f"{what}: {key!r} holds nan or inf; expected {expect}")
    return a


def _shaped(a: Array, shape: tuple[int | None, ...], key: str, what: str, expect: str) -> Array:
    """``a`` if its shape matches ``shape`` (None: any size)."""
    if a.ndim != len(shape) or any(n is not None and n != m for n, m in zip(shape, a.shape, strict=True)):
        raise SmplError(f"{what}: {key!r} has shape {a.shape}; expected {expect}")
    return a


def load_model(path: str | os.PathLike[str]) -> BodyModel:
    """The body model at ``path`` (an SMPL, SMPL-H or SMPL-X ``.npz``), kept while the file stays the same.

    Raises:
        SmplError: missing, a ``.pkl``, not an ``.npz``, a key missing or malformed, an unknown skeleton.
    """
    p = Path(path)
    if p.suffix.lower() == ".pkl":
        raise SmplError(f"body model {str(path)!r} is a pickle, which mjkin does not load (it can run code); give the "
                        "model's .npz (SMPL-X and AMASS's SMPL+H are published as .npz)")
    kind = files.kind_of(p)
    if kind:  # said of the path given (the file is read by its resolved path)
        raise SmplError(f"body model {str(path)!r} is {kind}, not a regular file; give the file itself")
    try:
        return _load_model(p)
    except FileNotFoundError:
        raise SmplError(f"body model not found: {str(path)!r}") from None


@files.per_file(maxsize=4)
def _load_model(path: str) -> BodyModel:
    """:func:`load_model` of the file ``path``."""
    what = f"body model {path!r}"
    with _npz(path, "body model") as data:
        kintree = _numbers(data, "kintree_table", what, "(2, joints) integers: each joint's parent, then itself")
        J = _shaped(kintree, (2, None), "kintree_table", what, "(2, joints)").shape[1]
        if J not in SKELETONS:
            raise SmplError(f"{what} has {J} joints; expected " + ", ".join(
                f"{n} ({kind})" for n, (kind, _, _) in SKELETONS.items()))
        kind, _, parents = SKELETONS[J]
        got = np.where((kintree[0] < 0) | (kintree[0] >= J), -1, kintree[0]).astype(np.int64)
        wrong = np.flatnonzero(got != parents)
        if wrong.size:
            j = int(wrong[0])
            raise SmplError(f"{what}: kintree_table gives joint {j} the parent {got[j]}; {kind}'s is {parents[j]}")
        regressor = _shaped(_numbers(data, "J_regressor", what, f"({J}, vertices) joint regressor"),
                            (J, None), "J_regressor", what, f"({J}, vertices)")
        V = regressor.shape[1]
        template = _shaped(_numbers(data, "v_template", what, f"({V}, 3) rest vertices (m)"), (V, 3), "v_template",
                           what, f"({V}, 3): one row per J_regressor column")
        dirs = _shaped(_numbers(data, "shapedirs", what, f"({V}, 3, shapes) shape directions"), (V, 3, None),
                       "shapedirs", what, f"({V}, 3, shapes)")
    S = dirs.shape[2]
    n = (SMPLX_SHAPES if S >= SMPLX_SHAPES + 100 else min(S, 10)) if kind == "SMPL-X" else S  # not the expressions
    arrays = np.array(parents, dtype=np.int64), regressor @ template, np.tensordot(regressor, dirs[:, :, :n], (1, 0))
    for a in arrays:  # shared by every read of the file
        a.setflags(write=False)
    return BodyModel(kind, *arrays, source=path)


def _poses(data: _Archive, model: BodyModel, what: str) -> tuple[Array, str]:
    """The clip's turns ``(F, 3 J)`` (rotation vectors, rad) in ``model``'s joint order, and the key they count from.

    From ``poses``, or else from its parts (:data:`PARTS`; a part the clip lacks is at rest).
    """
    J, parts = len(model.parents), PARTS[model.kind]
    if "poses" in data.files:
        poses = _shaped(_numbers(data, "poses", what, "(frames, 3 x joints) rotation vectors (rad)"), (None, None),
                        "poses", what, "(frames, 3 x joints)")
        if len(poses) and poses.shape[1] != 3 * J:
            kinds = {3 * n: kind for n, (kind, _, _) in SKELETONS.items()}
            kind = f" ({kinds[poses.shape[1]]})" if poses.shape[1] in kinds else ""
            raise SmplError(f"{what}: 'poses' has {poses.shape[1]} values a frame{kind} but the {model.kind} body "
                            f"model {model.source!r} has {J} joints ({3 * J} values); give the model the clip was made "
                            "with")
        return poses, "poses"
    if not any(k in data.files for k in REQUIRED_PARTS):
        raise SmplError(f"{what} has neither 'poses' nor its parts; expected 'poses' (frames, {3 * J}) or "
                        + ", ".join(f"{k!r} (frames, {3 * n})" for k, n in parts)
                        + f" (rotation vectors, rad; those after {REQUIRED_PARTS[-1]!r} optional)")
    other = [k for k in dict.fromkeys(k for kind in PARTS.values() for k, _ in kind)
             if k in data.files and k not in dict(parts)]
    if other:
        raise SmplError(f"{what} has {', '.join(map(repr, other))} but the {model.kind} body model {model.source!r} "
                        "has no such joints; give the model the clip was made with")
    first = parts[0][0]  # the root's turn, one joint
    root = _shaped(_numbers(data, first, what, "(frames, 3) rotation vectors (rad)"), (None, 3), first, what,
                   "(frames, 3)")
    F = len(root)
    poses = np.zeros((F, 3 * J))
    poses[:, :3] = root
    at = 1  # the joint the next part starts at
    for key, n in parts[1:]:
        if key in data.files or key in REQUIRED_PARTS:
            poses[:, 3 * at:3 * (at + n)] = _shaped(
                _numbers(data, key, what, f"({F}, {3 * n}) rotation vectors (rad)"), (F, 3 * n), key, what,
                f"({F}, {3 * n}): one row per frame of {first!r}")
        at += n
    return poses, first


def read(path: str | os.PathLike[str], body_model: str | os.PathLike[str] | BodyModel | None) -> bvh.Clip:
    """The AMASS/SMPL clip at ``path`` as a :class:`~mjkin.motion.bvh.Clip` (metres, y up), with ``body_model``.

    Raises:
        InputError: no body model given.
        SmplError: the clip or model cannot be read, a key is missing or malformed (nan, wrong shape), neither
            ``poses`` nor its parts are there, or the model's joints do not match the clip's turns.
    """
    if body_model is None:
        raise InputError(f"the AMASS/SMPL clip {str(path)!r} needs its body model: give body_model= (--body-model "
                         "PATH), the SMPL-H or SMPL-X .npz the clip was made with")
    model = body_model if isinstance(body_model, BodyModel) else load_model(body_model)
    what = f"clip {str(path)!r}"
    with _npz(path, "AMASS/SMPL clip") as data:
        poses, turns_key = _poses(data, model, what)
        F, J = len(poses), len(model.parents)
        trans = _shaped(_numbers(data, "trans", what, f"({F}, 3) root translations (m)"), (F, 3), "trans", what,
                        f"({F}, 3): one row per frame of {turns_key!r}")
        betas = _numbers(data, "betas", what, "(shapes,) body shape coefficients")
        betas = _shaped(betas.reshape(-1) if betas.ndim == 2 and len(betas) == 1 else betas, (None,), "betas", what,
                        "(shapes,) or (1, shapes)")
        key = next((k for k in FRAME_RATES if k in data.files), FRAME_RATES[0])
        fps = _numbers(data, key, what, f"frames per second (one number; {' or '.join(FRAME_RATES)})")
    if F == 0:
        raise SmplError(f"{what}: {turns_key!r} has no frames; expected at least one")
    lo, hi = 1.0 / bvh.FRAME_TIME[1], 1.0 / bvh.FRAME_TIME[0]
    if fps.size != 1 or not lo <= float(fps.flat[0]) <= hi:
        raise SmplError(f"{what}: {key!r} must be one number of frames per second from {lo:g} to {hi:g}, got "
                        f"{fps.tolist()}")
    rest = model.joints(betas)
    offsets = rest.copy()
    offsets[1:] -= rest[model.parents[1:]]
    turns = spatial.rotvec_to_quat(poses.reshape(F, J, 3))
    turns[:, 0] = spatial.quat_mul(spatial.mat_to_quat(Y_UP), turns[:, 0])  # the z-up world turned y-up
    values = np.concatenate([(rest[0] + trans) @ Y_UP.T, euler_channels(turns).reshape(F, -1)], axis=1)
    _, names, _ = SKELETONS[J]
    return bvh.Clip(names=names, parents=model.parents.copy(), offsets=offsets,
                    channels=((*POSITION, *ROTATION), *(ROTATION,) * (J - 1)),
                    columns=np.array([0, *range(6, 3 * J + 3, 3)], dtype=np.int64), values=values,
                    frame_time=1.0 / float(fps.flat[0]), ends=np.zeros(J, dtype=np.bool_), source=str(path))
