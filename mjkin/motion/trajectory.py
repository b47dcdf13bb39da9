"""Trajectories as script files: configurations over time with what made them, saved and read back checked."""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InputError, MjkinIOError
from ..kinematics.qspace import BALL, HINGE, SLIDE
from ..kinematics.tree import Tree, fingerprint
from ..runtime import files
from ..runtime.checks import check_array
from ..runtime.files import as_path, write_text
from . import journal

Array = NDArray[np.float64]
FORMAT = journal.TRAJECTORY_FORMAT


LIMIT_TOL = 1e-9  # rad or m past a limit before a value counts as outside


def outside_limits(tree: Tree, q: ArrayLike) -> str | None:
    """One line naming the joints of ``q (nq,)`` or ``(T, nq)`` outside their limits (and where), or None.

    Hinges and slides outside their range, and limited ball joints turned past
    their cone; unlimited joints are never outside. For ``(T, nq)`` each joint is
    named once, with its first frame outside and how many frames are.
    """
    qs = tree.check_q(q)
    frames = qs.ndim == 2
    qs = np.atleast_2d(qs)
    lay, names = tree.layout, tree.names("joint")
    parts = []
    for j in range(tree.njnt):
        kind, a, lo, hi = int(tree.jnt_type[j]), int(tree.jnt_qadr[j]), lay.jnt_lo[j], lay.jnt_hi[j]
        if kind in (HINGE, SLIDE):
            value = qs[:, a]
            out = (value < lo - LIMIT_TOL) | (value > hi + LIMIT_TOL)
        elif kind == BALL and np.isfinite(hi):
            quat = qs[:, a:a + 4]
            value = 2 * np.arctan2(np.linalg.norm(quat[:, 1:], axis=-1), np.abs(quat[:, 0]))  # q and -q alike
            out = value > hi + LIMIT_TOL
        else:
            continue
        if not out.any():
            continue
        k, n = int(np.argmax(out)), int(out.sum())
        where = (f" at frame {k}" + (f" (and {n - 1} more frame{'s' * (n > 2)})" if n > 1 else "")) if frames else ""
        name = names[j] or str(j)
        parts.append(f"joint {name} turns {value[k]:.4g} rad, beyond its {hi:.4g} rad cone{where}" if kind == BALL
                     else f"joint {name} = {value[k]:.4g} is outside its range [{lo:.4g}, {hi:.4g}]{where}")
    return "; ".join(parts) or None


def _array(value: object, ndim: int, kind: type) -> NDArray | None:
    """``value`` (parsed JSON) as an ``ndim``-deep array of numbers (``kind`` float) or booleans; None if it is not.

    Only JSON numbers count as numbers and only ``true``/``false`` as booleans (numpy
    would read ``"no"`` as true and ``"1.5"`` as a number); the nesting is walked
    level by level, without recursion.
    """
    items: list[object] = [value]
    for _ in range(ndim):
        lists = [v for v in items if isinstance(v, list)]
        if len(lists) != len(items):
            return None
        items = [x for v in lists for x in v]
    leaf = (bool,) if kind is bool else (int, float)
    if not all(type(x) in leaf for x in items):
        return None
    try:
        a: NDArray = np.array(value, dtype=kind)
    except (ValueError, OverflowError):  # ragged lists; an integer beyond float range
        return None
    return a if a.ndim == ndim else None


@dataclass
class Trajectory:
    """Configurations over time: ``q (T, nq)`` at ``times (T,)`` (seconds), with what made them.

    ``model`` is the model's name; ``source`` where it was loaded from (an absolute
    MJCF/URDF path or a bundled model's name, '' when unknown), so a replay finds it.
    """

    times: Array
    q: Array
    fingerprint: str
    model: str = ""
    frame: str | None = None  # the frame that followed the targets (its trail is drawn)
    targets: Array | None = None  # (T, n, 3) goal points per frame, for overlays
    success: NDArray[np.bool_] | None = None
    meta: dict = field(default_factory=dict)
    source: str = ""

    def __post_init__(self) -> None:
        self.times, self.q = check_array(self.times, "trajectory times"), check_array(self.q, "trajectory q")
        if self.times.ndim != 1 or self.q.ndim != 2 or len(self.q) != len(self.times):
            raise InputError(f"a trajectory needs times (T,) and q (T, nq) of the same T, got {self.times.shape} "
                             f"and {self.q.shape}")

    @property
    def site(self) -> str | None:
        """The followed frame (deprecated: use ``frame``)."""
        warnings.warn("Trajectory.site is now Trajectory.frame", DeprecationWarning, stacklevel=2)
        return self.frame

    def jumps(self, tree: Tree) -> Array:
        """Largest joint change between consecutive frames ``(T-1,)`` (rad or m; unlimited hinges the short way)."""
        return np.abs(tree.difference(self.q[1:], self.q[:-1], periodic=True)).max(axis=-1)

    def discontinuities(self, tree: Tree, threshold: float = 0.5) -> NDArray[np.int64]:
        """Frames whose step from the previous one exceeds ``threshold`` (a flip to another IK branch)."""
        return np.flatnonzero(self.jumps(tree) > threshold) + 1

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the script as JSON (atomically)."""
        doc = {"format": FORMAT, "version": 1, "model": self.model, "source": self.source,
               "fingerprint": self.fingerprint, "frame": self.frame, "times": self.times.tolist(),
               "qpos": self.q.tolist(), "targets": None if self.targets is None else self.targets.tolist(),
               "success": None if self.success is None else self.success.tolist(), "meta": self.meta}
        return write_text(path, json.dumps(doc))

    def check(self, tree: Tree, path: str | os.PathLike[str] = "") -> None:
        """Raise :class:`InputError` unless this script was recorded on ``tree`` (same fingerprint, ``nq``).

        ``path`` names the script in the message.
        """
        name = f"trajectory {str(path)!r}" if str(path) else "the trajectory"
        if self.fingerprint != fingerprint(tree):
            raise InputError(f"{name} was recorded on model {self.model!r} (fingerprint {self.fingerprint}), "
                             f"not on {tree.name!r} ({fingerprint(tree)})")
        tree.check_q(self.q, "trajectory qpos")

    @classmethod
    def load(cls, path: str | os.PathLike[str], tree: Tree | None = None) -> Trajectory:
        """Read a script; with ``tree``, refuse one recorded on another model (fingerprint mismatch).

        Times must not decrease and, over two frames or more, must not all be equal.
        Joint values are read as recorded: :func:`outside_limits` says which are
        outside the joint limits, ``tree.clip`` clips them. A ``.jsonl`` file is read as
        the journal of a recording ``mjkin play`` took (:mod:`mjkin.motion.journal`).

        Raises:
            MjkinIOError: the file is missing, unreadable, not JSON, or nested too deeply.
            InputError: a key is missing, or a value has the wrong type, shape or order (the message names it).
        """
        path = as_path(path, "trajectory path")
        name = repr(str(path))
        try:
            doc = (journal.script(path) if Path(path).suffix == ".jsonl" else
                json.loads(files.read_input_text(path, "trajectory file", files.LIMITS["json"])))
        except RecursionError:
            raise MjkinIOError(f"cannot read trajectory {name}: its JSON is nested too deeply") from None
        except (OSError, ValueError) as e:
            raise MjkinIOError(f"cannot read trajectory {name}: {e}") from None
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            raise MjkinIOError(f"{name} is not an mjkin trajectory (no \"format\": \"{FORMAT}\")")

        def numbers(key: str, ndim: int, what: str, kind: type = float) -> NDArray:
            if key not in doc:
                raise InputError(f"trajectory {name} has no {key!r} ({what}); keys needed: times, qpos, fingerprint")
            a = _array(doc[key], ndim, kind)
            if a is None or (kind is float and not np.isfinite(a).all()):
                raise InputError(f"trajectory {name}: {key!r} must be {what}"
                                 + (" (finite numbers)" if kind is float else ""))
            return a

        times = numbers("times", 1, "a list of T times in seconds")
        q = numbers("qpos", 2, "a list of T configurations, each a list of nq numbers")
        fp = doc.get("fingerprint")
        if not isinstance(fp, str):
            raise InputError(f"trajectory {name}: 'fingerprint' must be a string (from the model it was recorded on)")
        if len(times) != len(q) or len(q) == 0:
            raise InputError(f"trajectory {name}: 'times' ({len(times)}) and 'qpos' ({len(q)}) must have the same "
                             "number of frames, at least one")
        targets = None if doc.get("targets") is None else numbers("targets", 3, "per frame a list of x,y,z points")
        success = None if doc.get("success") is None else numbers("success", 1, "one true/false per frame", bool)
        if targets is not None and (len(targets) != len(q) or targets.shape[-1] != 3):
            raise InputError(f"trajectory {name}: 'targets' must hold x,y,z points for each of the {len(q)} frames")
        if success is not None and len(success) != len(q):
            raise InputError(f"trajectory {name}: 'success' must hold one true/false for each of the {len(q)} frames")
        model, frame, meta = doc.get("model", ""), doc.get("frame", doc.get("site")), doc.get("meta") or {}
        source = doc.get("source") or ""
        if (not all(isinstance(v, str) for v in (model, source)) or not (frame is None or isinstance(frame, str))
                or not isinstance(meta, dict)):
            raise InputError(f"trajectory {name}: 'model', 'source' and 'site' must be strings (or site null), "
                             "'meta' an object")
        traj = cls(times=times, q=q, fingerprint=fp, model=model, frame=frame, targets=targets, success=success,
                   meta=dict(meta), source=source)
        if tree is not None:
            traj.check(tree, path)
        step = np.diff(times)
        if (step < 0).any():
            k = int(np.argmax(step < 0)) + 1
            raise InputError(f"trajectory {name}: 'times' must not decrease, but frame {k} is at {times[k]:g} s "
                             f"after {times[k - 1]:g} s")
        if len(times) > 1 and times[-1] == times[0]:
            raise InputError(f"trajectory {name}: 'times' are all {times[0]:g} s; they must increase over the "
                             f"{len(times)} frames")
        return traj


