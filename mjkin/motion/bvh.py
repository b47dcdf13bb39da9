"""Reading BVH motion capture: the skeleton, its channels and frames, and forward kinematics of every frame.

A BVH file (Biovision Hierarchy) holds a tree of joints, each with an ``OFFSET``
from its parent and ``CHANNELS`` (any of ``Xposition Yposition Zposition
Xrotation Yrotation Zrotation`` in any order, usually 3 or 6), ``End Site``
leaves with an offset only, then ``Frames:``, ``Frame Time:`` and one line of
channel values per frame (the frame time in seconds, from 1e-4 to 10: ``FRAME_TIME``;
joints may nest to any depth). A joint's local transform is ``Trans(t) @ R``: ``t`` is
its offset, with each axis that has a position channel taken from that channel
(so 6-channel joints whose channels repeat the offset read the same as 3-channel
ones); ``R`` is the product of the rotation channels in the order listed
(``Zrotation Xrotation Yrotation`` is ``Rz @ Rx @ Ry``, degrees), acting on column
vectors. World poses are ``T_parent @ T_local``; positions stay in the file's
units and axes (usually y up).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .. import spatial
from ..errors import InputError, MjkinIOError
from ..runtime import files

Array = NDArray[np.float64]
CHANNELS = ("xposition", "yposition", "zposition", "xrotation", "yrotation", "zrotation")
END = "_End"  # an End Site is named after its joint with this suffix
MAX_FRAMES = 100_000_000  # frames a file may hold (over a day at 1000 Hz; 'Frames: 1e300' ended in StopIteration)
CHUNK = 4096  # frames whose transforms Clip.positions makes at once (16 MB for 30 joints)
FRAME_TIME = (1e-4, 10.0)  # the Frame Time: a file may give, seconds (10000 to 0.1 frames per second)


class BvhError(MjkinIOError):
    """A BVH file cannot be read or is malformed (the message names the file and line)."""


@dataclass(frozen=True)
class Clip:
    """A parsed BVH clip: ``J`` joints (End Sites included, parents before children) and ``F`` frames.

    ``names (J,)``, ``parents (J,)`` (-1 for a root), ``offsets (J, 3)`` in file units,
    ``channels`` per joint (lower-case channel names, End Sites none), ``ends (J,)`` true for End Sites,
    ``columns (J,)`` each joint's first column in ``values (F, C)`` (degrees for
    rotations), ``frame_time`` seconds per frame.
    """

    names: tuple[str, ...]
    parents: NDArray[np.int64]
    offsets: Array
    channels: tuple[tuple[str, ...], ...]
    columns: NDArray[np.int64]
    values: Array
    frame_time: float
    ends: NDArray[np.bool_]
    source: str = ""

    @property
    def frames(self) -> int:
        """Number of frames ``F``."""
        return int(self.values.shape[0])

    @property
    def fps(self) -> float:
        """Frames per second."""
        return 1.0 / self.frame_time

    def index(self, name: str) -> int:
        """Index of joint ``name``.

        Raises:
            InputError: no joint of that name (the message lists them).
        """
        try:
            return self.names.index(name)
        except ValueError:
            raise InputError(f"BVH {self.source or 'clip'} has no joint {name!r}; it has: "
                             f"{', '.join(self.names)}") from None

    def local(self, frames: slice | NDArray[np.int64] | None = None, rest: bool = False) -> Array:
        """Local transforms ``(F, J, 4, 4)`` of each joint in its parent.

        ``rest``: the rest pose ``(1, J, 4, 4)``: rotations zero, every joint at its offset (its position channels
        unread: LAFAN1 gives every joint position channels, which zero would put at its parent).
        """
        values = np.zeros((1, self.values.shape[1])) if rest else self.values[slice(None) if frames is None else frames]
        F, J = len(values), len(self.names)
        T = np.broadcast_to(np.eye(4), (F, J, 4, 4)).copy()
        T[:, :, :3, 3] = self.offsets
        turns: dict[str, tuple[list[int], list[list[int]]]] = {}  # Euler sequence -> joints, their angle columns
        for j, chans in enumerate(self.channels):
            rot = [(c[0], k) for k, c in enumerate(chans) if c.endswith("rotation")]
            for k, c in enumerate(chans):
                if c.endswith("position") and not rest:
                    T[:, j, "xyz".index(c[0]), 3] = values[:, self.columns[j] + k]
            if rot:
                cols = [self.columns[j] + k for _, k in rot]
                seq = "".join(a for a, _ in rot).upper()  # upper case: intrinsic, in the listed order
                if len(seq) < 3:  # fewer than three rotation channels: pad with zero turns about unused axes
                    pad = "".join(a for a in "XYZ" if a not in seq)[: 3 - len(seq)]
                    cols += [-1] * len(pad)
                    seq += pad
                joints, columns = turns.setdefault(seq, ([], []))
                joints.append(j)
                columns.append(cols)
        padded = np.concatenate([np.deg2rad(values), np.zeros((F, 1))], axis=1)  # column -1: a zero turn
        for seq, (joints, columns) in turns.items():  # one conversion per sequence, all its joints at once
            T[:, joints, :3, :3] = spatial.euler_to_mat(padded[:, columns], seq)
        return T

    def world(self, frames: slice | NDArray[np.int64] | None = None, rest: bool = False) -> Array:
        """World transforms ``(F, J, 4, 4)`` of every joint (file units and axes); ``rest`` as in :meth:`local`."""
        T = self.local(frames, rest)
        for j, p in enumerate(self.parents):
            if p >= 0:
                T[:, j] = T[:, p] @ T[:, j]
        return T

    def positions(self, frames: slice | NDArray[np.int64] | None = None, rest: bool = False) -> Array:
        """World positions ``(F, J, 3)`` of every joint and End Site (file units and axes).

        Made :data:`CHUNK` frames at a time: every frame's transforms at once took 15x the room of the positions.
        """
        if rest:
            return self.world(rest=True)[..., :3, 3].copy()
        which = np.arange(self.frames)[slice(None) if frames is None else frames]
        out = np.empty((*which.shape, len(self.names), 3))
        for a in range(0, len(which), CHUNK):
            out[a:a + CHUNK] = self.world(which[a:a + CHUNK])[..., :3, 3]
        return out


def read(path: str | os.PathLike[str]) -> Clip:
    """Parse the BVH file at ``path``.

    Raises:
        BvhError: missing or unreadable file, or malformed content (file and line named).
    """
    text = files.read_input_text(path, "BVH file", files.LIMITS["bvh"], BvhError, errors="replace")
    try:
        return parse(text, str(path))
    except MemoryError:
        raise BvhError(f"BVH file {str(path)!r} is too big to read in the memory there is ({len(text) / files.MB:.0f} "
                       "MB of text)") from None


SHOWN = 40  # characters of a token an error message quotes


def shown(token: str) -> str:
    """``token`` quoted for a message, cut to :data:`SHOWN` characters."""
    return repr(token if len(token) <= SHOWN else token[:SHOWN] + "...")


_TOKEN = re.compile(r"\S+")  # whitespace as str.split's
_BREAK = re.compile(r"\r\n|[\n\r\v\f\x1c-\x1e\x85\u2028\u2029]")  # line breaks as str.splitlines's


def _line(text: str, at: int) -> int:
    """The line number (from 1) of character ``at`` of ``text``."""
    return 1 + sum(1 for _ in _BREAK.finditer(text, 0, at))


class _Tokens:
    """The whitespace tokens of the text, read one at a time (the motion block is never split into tokens)."""

    def __init__(self, text: str, source: str) -> None:
        self.text = text
        self.source = source
        self._tokens = _TOKEN.finditer(text)
        self._next = next(self._tokens, None)
        self._last: re.Match[str] | None = None  # the token taken last

    @property
    def end(self) -> int:
        """Where the last token taken ends in the text (0 before any)."""
        return self._last.end() if self._last else 0

    def error(self, what: str) -> BvhError:
        at = self._next or self._last
        return BvhError(f"BVH {self.source!r} line {_line(self.text, at.start()) if at else 1}: {what}")

    def peek(self) -> str | None:
        return self._next.group() if self._next else None

    def take(self, expected: str | None = None, what: str = "more") -> str:
        """The next token; with ``expected``, it must be that word (any case)."""
        tok = self.peek()
        if tok is None:
            raise self.error(f"file ends early; expected {expected or what}")
        if expected is not None and tok.upper() != expected.upper():
            raise self.error(f"expected {expected!r}, got {shown(tok)}")
        self._last, self._next = self._next, next(self._tokens, None)
        return tok

    def rest_of_line(self, what: str) -> str:
        """The tokens left on the current token's line, joined by spaces (a name may hold spaces), without ``{``."""
        if self._next is None:
            raise self.error(f"file ends early; expected {what}")
        words = [self.take()] if self._next.group() != "{" else []
        while (self._next is not None and self._next.group() != "{" and words
               and not _BREAK.search(self.text, self.end, self._next.start())):
            words.append(self.take())
        if not words:
            raise self.error(f"expected {what}")
        return " ".join(words)

    def number(self, what: str, between: tuple[float, float] | None = None, unit: str = "") -> float:
        """The next token as a finite number; with ``between``, one in that closed range (of ``unit``)."""
        tok = self.peek()
        if tok is None:
            raise self.error(f"file ends early; expected {what}")
        try:
            value = float(tok)
        except ValueError:
            raise self.error(f"expected a number ({what}), got {shown(tok)}") from None
        if between is not None and not between[0] <= value <= between[1]:  # nan and inf fail too
            raise self.error(f"{what} must be a finite number of {unit} from {between[0]:g} to {between[1]:g}, "
                             f"got {shown(tok)}")
        if not np.isfinite(value):
            raise self.error(f"{what} must be finite, got {shown(tok)}")
        self.take()
        return value


def parse(text: str, source: str = "<string>") -> Clip:
    """Parse BVH ``text``; ``source`` names it in error messages.

    Raises:
        BvhError: malformed content: the message gives the line and what was expected.
    """
    tk = _Tokens(text, source)
    if (tk.peek() or "").upper() != "HIERARCHY":  # not a BVH file: what it holds may be private (a link to a secret)
        raise tk.error("a BVH file starts with HIERARCHY; this one does not")
    tk.take("HIERARCHY")
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []
    ends: list[bool] = []

    def joint(parent: int, end: bool) -> tuple[int, str, bool]:
        """Read a joint's name, OFFSET and CHANNELS (up to its children) and add it; its index, name, kind."""
        name = f"{names[parent]}{END}" if end else tk.rest_of_line("a joint name")
        if name in names:
            raise tk.error(f"joint name {name!r} appears twice")
        names.append(name)
        parents.append(parent)
        ends.append(end)
        tk.take("{")
        tk.take("OFFSET")
        offsets.append([tk.number("OFFSET x"), tk.number("OFFSET y"), tk.number("OFFSET z")])
        chans: tuple[str, ...] = ()
        if not end and (tk.peek() or "").upper() == "CHANNELS":
            tk.take("CHANNELS")
            n = tk.number("the number of channels")
            if n != int(n) or not 0 <= n <= 6:
                raise tk.error(f"CHANNELS count must be a whole number 0..6, got {n:g}")
            chans = tuple(tk.take(what="a channel name").lower() for _ in range(int(n)))
            bad = [c for c in chans if c not in CHANNELS]
            if bad:
                raise tk.error(f"unknown channel {bad[0]!r} of joint {name!r}; channels are Xposition, Yposition, "
                               "Zposition, Xrotation, Yrotation, Zrotation")
            if len(set(chans)) != len(chans):
                raise tk.error(f"joint {name!r} lists a channel twice: {' '.join(chans)}")
        channels.append(chans)
        return len(names) - 1, name, end

    while (tk.peek() or "").upper() == "ROOT":
        tk.take("ROOT")
        open_joints = [joint(-1, False)]  # a stack, not recursion: hierarchies of any depth
        while open_joints:
            me, name, end = open_joints[-1]
            word = (tk.peek() or "}").upper()  # at the end of the file, take("}") says what is missing
            if word == "}":
                tk.take("}")
                open_joints.pop()
            elif word in ("JOINT", "END") and not end:
                tk.take()
                if word == "END":
                    tk.take("Site")
                open_joints.append(joint(me, word == "END"))
            else:
                raise tk.error(f"expected JOINT, End Site or '}}' in joint {name!r}, got {shown(tk.peek() or '')}")
    if not names:
        raise tk.error("expected ROOT after HIERARCHY")
    tk.take("MOTION")
    tk.take("Frames:")
    n_frames = tk.number("the number of frames")
    if not (n_frames == int(n_frames) and 1 <= n_frames <= MAX_FRAMES):
        raise tk.error(f"Frames: must be a whole number from 1 to {MAX_FRAMES:,}, got {n_frames:g}")
    tk.take("Frame")
    tk.take("Time:")
    frame_time = tk.number("Frame Time:", FRAME_TIME, "seconds")
    counts = np.array([len(c) for c in channels], dtype=np.int64)
    n_cols = int(counts.sum())
    values = _values(text, tk.end, int(n_frames), n_cols, source)
    if not np.isfinite(values).all():
        raise BvhError(f"BVH {source!r}: channel values must be finite numbers (found nan or inf)")
    columns = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    return Clip(names=tuple(names), parents=np.array(parents, dtype=np.int64), offsets=np.array(offsets),
                channels=tuple(channels), columns=columns, values=values, frame_time=float(frame_time),
                ends=np.array(ends, dtype=np.bool_), source=source)


_LINE = re.compile(r"[^\n\r\v\f\x1c-\x1e\x85\u2028\u2029]+")  # a line's text, as str.splitlines's


def _values(text: str, start: int, F: int, n_cols: int, source: str) -> Array:
    """The channel values ``(F, n_cols)``: the first ``F * n_cols`` numbers of ``text`` from character ``start``.

    Parsed in bulk by numpy (8 bytes a value beside the text); a block numpy cannot read whole (a word that is
    no number, non-ASCII spaces, words after the last frame) is read again a line at a time, to its first word
    that is no number (named with its line) or its last value needed.

    Raises:
        BvhError: fewer numbers than needed, or a word that is no number among them.
    """
    need = F * n_cols
    try:
        flat = np.fromstring(text[start:], sep=" ")
    except ValueError:
        flat = _values_by_line(text, start, need, source)
    if flat.size < need:
        have = flat.size // n_cols if n_cols else 0
        raise BvhError(f"BVH {source!r}: 'Frames: {F}' with {n_cols} channels needs {need} numbers, "
                       f"found {flat.size} (about {have} frames)")
    return (flat if flat.size == need else flat[:need].copy()).reshape(F, n_cols)


def _values_by_line(text: str, start: int, need: int, source: str) -> Array:
    """:func:`_values`'s numbers from ``start``, read a line (or else a word) at a time, at most ``need``."""
    parts, have = [], 0
    for line in _LINE.finditer(text, start):
        if have >= need:
            break
        try:
            part = np.fromstring(line.group(), sep=" ")
        except ValueError:
            words = list(_TOKEN.finditer(line.group()))
            bad = next((w for w in words if not _is_number(w.group())), None)
            if bad is not None and have + words.index(bad) < need:
                raise BvhError(f"BVH {source!r} line {_line(text, line.start())}: expected a channel value (a "
                               f"number), got {shown(bad.group())}") from None
            part = np.array([float(w.group()) for w in words[: words.index(bad) if bad else None]])
        parts.append(part)
        have += part.size
    return np.concatenate(parts) if parts else np.zeros(0)


def _is_number(token: str) -> bool:
    """Whether ``token`` is one number as the channel values are read (numpy's; not Python's ``1_0``)."""
    try:
        return np.fromstring(token, sep=" ").size == 1
    except ValueError:
        return False


UNITS = ((0.5, 3.0, 1.0, "m"), (3.0, 40.0, 1.0 / 12.0, "ft"), (40.0, 110.0, 0.0254, "in"),
         (110.0, 400.0, 0.01, "cm"), (400.0, 4000.0, 0.001, "mm"))  # skeleton height range -> metres per unit


def unit_scale(clip: Clip, up: int = 1) -> tuple[float, str]:
    """Metres per file unit, and the unit's name, guessed from the rest skeleton's height along axis ``up``.

    A human-sized figure stands 0.5–3 m, 40–110 in, 110–400 cm or 400–4000 mm tall
    (a child of 100 cm reads as inches: pass a scale then).

    Raises:
        InputError: the height fits none of those (say the scale instead).
    """
    p = clip.positions(rest=True)[0]
    height = float(p[:, up].max() - p[:, up].min())
    for lo, hi, scale, unit in UNITS:
        if lo <= height < hi:
            return scale, unit
    raise InputError(f"cannot tell the units of BVH {clip.source or 'clip'} from its height {height:g}; "
                     "give the scale in metres per unit (--scale, e.g. 0.01 for centimetres)")
