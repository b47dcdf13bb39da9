"""Reading a recording's journal: the JSON Lines file ``mjkin play`` appends a take's samples to while it records.

A header line (format, model name and source, fingerprint, effector frames,
method, goal), then one line per sample (``t`` seconds since the start, ``q``,
the target points). A last line cut off mid-write (a crash) is left out. The
playground writes journals (:mod:`mjkin.apps.play.journal`); the library reads
them, so ``mjkin replay BASE.journal.jsonl`` works without the playground.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError, MjkinIOError
from ..runtime import files

FORMAT = "mjkin-play-journal"
SUFFIX = ".journal.jsonl"
TRAJECTORY_FORMAT = "mjkin-trajectory"  # what script() returns (mjkin.motion.trajectory.FORMAT)
Sample = tuple[float, NDArray[np.float64], NDArray[np.float64]]  # (seconds since the start, q (nq,), points (n, 3))


def read(path: str | os.PathLike[str]) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The header and the sample lines of a journal; a last line cut off mid-write is left out.

    Raises:
        MjkinIOError: the file is missing or unreadable, or not a journal.
        InputError: a line other than the last is not a JSON object (the message gives its number).
    """
    name = repr(str(path))
    try:
        lines = files.read_input_text(path, "recording journal", files.LIMITS["json"]).splitlines()
    except ValueError as e:
        raise MjkinIOError(f"cannot read recording journal {name}: {e}") from None
    docs: list[Any] = []
    for k, line in enumerate(lines, 1):
        try:
            docs.append(json.loads(line))
        except (ValueError, RecursionError):
            if k == len(lines) and k > 1:
                break  # the line being written when the process died
            raise InputError(f"recording journal {name}: line {k} is not JSON") from None
        if not isinstance(docs[-1], dict):
            raise InputError(f"recording journal {name}: line {k} is not a JSON object")
    if not docs or docs[0].get("format") != FORMAT:
        raise MjkinIOError(f"{name} is not an mjkin play journal (its first line has no \"format\": \"{FORMAT}\")")
    header, samples = docs[0], docs[1:]
    for k, s in enumerate(samples, 2):
        if not {"t", "q", "targets"} <= set(s):
            raise InputError(f"recording journal {name}: line {k} needs \"t\", \"q\" and \"targets\"")
    return header, samples


def columns(samples: Sequence[Sample]) -> tuple[NDArray, NDArray, NDArray | None]:
    """A take's samples as arrays: times from 0 ``(T,)``, ``q (T, nq)``, points ``(T, n, 3)``.

    The points are None when the number of targets changed during the take.
    """
    times = np.array([s[0] for s in samples], float)
    counts = {len(s[2]) for s in samples}
    targets = np.array([s[2] for s in samples], float).reshape(len(samples), -1, 3) if len(counts) == 1 else None
    return times - times[0], np.array([s[1] for s in samples], float), targets


def script(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The trajectory script (the JSON document :meth:`mjkin.motion.Trajectory.save` writes) a journal holds.

    Raises:
        MjkinIOError: see :func:`read`.
        InputError: a line is malformed, the journal holds no sample, or the samples' shapes disagree.
    """
    header, lines = read(path)
    if not lines:
        raise InputError(f"recording journal {str(path)!r} holds no sample (the take was cut short at once)")
    try:
        times, q, targets = columns([(line["t"], line["q"], line["targets"]) for line in lines])
    except (TypeError, ValueError):
        raise InputError(f"recording journal {str(path)!r}: each sample needs a time, q (nq numbers) and "
                         "targets (x, y, z points), the same nq in every line") from None
    frames = header.get("frames") or []
    play = {k: header.get(k) for k in ("frames", "method", "goal")}
    return {"format": TRAJECTORY_FORMAT, "version": 1, "model": header.get("model", ""), "source": header.get("source"),
            "fingerprint": header.get("fingerprint"), "frame": frames[0] if frames else None,
            "times": times.tolist(), "qpos": q.tolist(), "targets": None if targets is None else targets.tolist(),
            "success": None, "meta": {"play": play}}
